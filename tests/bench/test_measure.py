"""Timing, memory and synthetic buffers shared by the benchmarks (awr_denoise.bench.measure)."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

from awr_denoise import AdaptiveSampler, UniformSampler
from awr_denoise.bench import median_time, noisy_buffer, peak_memory, timed
from awr_denoise.bench.measure import Timing, run_progressive
from awr_denoise.synthetic import SyntheticRenderer, make_scene


@pytest.fixture
def fake_clock(monkeypatch):
    """perf_counter steps 1, 2, 4, 8, ... ms; process_time 0.5 s per call."""
    steps = (2.0**k * 1e-3 for k in itertools.count())
    total = [0.0]

    def perf_counter():
        total[0] += next(steps)
        return total[0]

    cpu = itertools.count()
    monkeypatch.setattr(time, "perf_counter", perf_counter)
    monkeypatch.setattr(time, "process_time", lambda: 0.5 * next(cpu))


def test_median_time_is_the_median_of_the_calls(fake_clock):
    # Calls read the clock at 1, 3 | 7, 15 | 31, 63 ms: durations 2, 8 and 32 ms.
    assert median_time(lambda: None, 3) == pytest.approx(8e-3)


def test_timed_returns_the_value_and_wall_and_cpu_seconds(fake_clock):
    value, (wall, cpu) = timed(lambda: "x")
    # perf_counter reads 1 then 1 + 2 = 3 ms; process_time 0 then 0.5 s.
    assert value == "x" and wall == pytest.approx(2e-3) and cpu == pytest.approx(0.5)


def test_peak_memory_sees_a_temporary_array():
    _, peak = peak_memory(lambda: float(np.zeros(2_000_000).sum()))  # 16 MB, freed before returning
    assert 16e6 <= peak < 20e6
    value, small = peak_memory(lambda: 3)
    assert value == 3 and small < 1e5


@pytest.mark.parametrize("smooth, noise", [(8.0, 0.05), (0.0, 0.0)])
def test_noisy_buffer_is_reproducible_and_has_the_requested_statistics(smooth, noise):
    a = noisy_buffer((40, 56), spp=3, seed=5, smooth=smooth, noise=noise)
    b = noisy_buffer((40, 56), spp=3, seed=5, smooth=smooth, noise=noise)
    assert a.shape == (40, 56) and (a.count == 3).all()
    np.testing.assert_array_equal(a.mean, b.mean)
    assert 0.0 <= a.variance.min() and a.variance.max() < 0.1
    if smooth == 0 and noise == 0:
        # No blur, no noise: the means are the raw uniform draws of the seed.
        np.testing.assert_array_equal(a.mean, np.random.default_rng(5).uniform(0.0, 1.0, (40, 56, 3)))
    else:
        # Blurred by 8 pixels, the means vary far less than uniform draws (variance 1/12).
        assert np.var(a.mean) < 0.25 / 12


def test_run_progressive_stops_on_every_target_and_times_every_round():
    scene = make_scene("edges", (16, 16))
    seen = []
    run_progressive(AdaptiveSampler((16, 16), seed=1), SyntheticRenderer(scene, seed=1), [8, 2, 4],
                    lambda spp, buf, timing: seen.append((spp, buf.total_samples, timing)))
    assert [(s, n) for s, n, _ in seen] == [(2, 512), (4, 1024), (8, 2048)]
    rounds = [t.rounds for _, _, t in seen]
    assert rounds == sorted(rounds) and rounds[0] >= 1
    assert all(isinstance(t, Timing) and t.render >= 0 and t.sampler >= 0 for _, _, t in seen)
    assert seen[0][2] is not seen[1][2]  # snapshots are copies


def test_run_progressive_with_a_uniform_sampler_matches_one_uniform_run():
    scene = make_scene("gradient", (8, 8))
    got = {}
    run_progressive(UniformSampler((8, 8), seed=2), SyntheticRenderer(scene, seed=2), [4],
                    lambda spp, buf, timing: got.update(buffer=buf))
    direct = UniformSampler((8, 8), seed=2).run(SyntheticRenderer(scene, seed=2), 4)
    np.testing.assert_array_equal(got["buffer"].count, direct.count)
    np.testing.assert_allclose(got["buffer"].mean, direct.mean, rtol=1e-12)
