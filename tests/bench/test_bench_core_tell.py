"""``benchmarks/bench_core.py --only tell``: the compiled merge against its numpy reference, timed alike."""

from __future__ import annotations

import json

import numpy as np
import pytest

from awr_denoise import fused
from awr_denoise.bench import noisy_buffer


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_core")


def test_each_timed_tell_merges_the_same_samples_with_its_backend(bench, monkeypatch):
    """The cases differ by the merge's backend alone: the same request, batch and merged bits; the backend
    chosen is the one in use during the call, and the choice before it is back afterwards."""
    buf = noisy_buffer((24, 40), smooth=0.0, noise=0.0)
    seen = []
    real = fused.backend
    before = real()
    monkeypatch.setattr(fused, "backend", lambda: seen.append(real()) or real())
    merged = []
    for kernels in fused.available():
        case = bench._TellKernels(buf, kernels)
        case()
        merged.append(case.sampler.buffer)
        assert seen and set(seen) == {kernels}, (kernels, seen)
        seen.clear()
        assert real() == before
    for other in merged[1:]:
        np.testing.assert_array_equal(other.mean.view(np.int64), merged[0].mean.view(np.int64))
        np.testing.assert_array_equal(other.variance.view(np.int64), merged[0].variance.view(np.int64))


def test_the_section_runs_and_records_its_ratios(bench, tmp_path):
    out = tmp_path / "core.json"
    assert bench.main(["--quick", "--only", "tell", "--output", str(out)]) == 0
    (row,) = json.loads(out.read_text())["tell"]
    assert row["size"] == "256x256" and row["kernels"] == fused.available()[-1]
    assert set(row["seconds"]) == {"floor", "numpy_1", "numpy_2", f"{row['kernels']}_1", f"{row['kernels']}_2"}
    assert row["compiled_x_numpy_1"] > 0 and row["compiled_x_numpy_2"] > 0
