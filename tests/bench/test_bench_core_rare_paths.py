"""``benchmarks/bench_core.py --only rare_paths``: ask() with rare-path regions evened against ranked."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from awr_denoise.rare_paths import rare_path_mask


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_core")


def test_the_rare_path_buffer_is_lit_through_rare_paths_everywhere_with_its_stated_mean(bench):
    buf = bench._hit_or_zero_buffer((64, 96), spp=8, p=0.02)
    assert rare_path_mask(buf).mean() > 0.9
    assert abs(float(buf.mean.mean()) - 1.0) < 0.1  # hits of 1 / p: the image's mean is 1
    assert (buf.mean == 0).mean() > 0.8


def test_the_section_times_both_choices_on_both_buffers(bench):
    rows = bench.rare_paths_cost(["256x256"], repeats=1)
    assert [r["buffer"] for r in rows] == ["no rare paths", "rare paths everywhere"]
    for row in rows:
        assert set(row["seconds"]) == {"even", "ranked", "even_2threads", "ranked_2threads"}
        assert all(np.isfinite(row[k]) and row[k] > 0 for k in ("ratio", "ratio_2threads"))
    assert rows[0]["masked_share"] == 0.0 and rows[1]["masked_share"] > 0.9
    assert "rare_paths" in bench.SECTIONS


def test_the_two_cases_are_the_default_sampler_and_the_same_with_rare_paths_ranked(bench):
    buf = bench._hit_or_zero_buffer((32, 48))
    cases = bench._rare_path_cases(buf)
    assert cases["even"].sampler.rare_paths == "even" and cases["ranked"].sampler.rare_paths == "ranked"
    with ThreadPoolExecutor(2) as pool:  # the two-thread cases: the same samplers on the pool
        threaded = bench._rare_path_cases(buf, pool)
        assert {k: (c.sampler.rare_paths, c.sampler.executor) for k, c in threaded.items() if "2threads" in k} == {
            "even_2threads": ("even", pool), "ranked_2threads": ("ranked", pool)}
        assert np.array_equal(threaded["even_2threads"].sampler.ask().counts, cases["even"].sampler.ask().counts)
    # on a frame lit through rare paths they ask for different samples
    assert not np.array_equal(cases["even"].sampler.ask().counts, cases["ranked"].sampler.ask().counts)
