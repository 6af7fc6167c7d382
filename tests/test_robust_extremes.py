"""Numerical behaviour at the extremes: tiny images, extreme magnitudes and parameters, budgets.

Deterministic companions of ``test_robust_properties.py`` (which explores the same ground with
hypothesis); each test here pins one documented behaviour of ``docs/robustness.md``.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from awr_denoise import AdaptiveSampler, Domain, SampleBuffer, UniformSampler, VarianceSampler, allocate, reconstruct
from awr_denoise.reconstruct import reconstruct_detailed
from awr_denoise.wavelets import max_levels

SEED = 20091216
DOMAINS = ("linear", "log", "gamma")


def noisy_buffer(shape, *, channels=3, spp=4, level=0.5, rel_sd=0.3, seed=SEED, dtype=np.float64):
    rng = np.random.default_rng(seed)
    h, w = shape
    var = (rel_sd * level) ** 2
    mean = level + math.sqrt(var / spp) * rng.standard_normal((h, w, channels))
    return SampleBuffer.from_moments(np.full((h, w), spp), mean.astype(dtype),
                                     np.full((h, w, channels), var, dtype=dtype))


# ---------------------------------------------------------------------------- budgets
class TestAllocateBudgets:
    """Regression: the secant water-filling stops within 0.1% of the budget, so the integer
    residual could exceed the number of pixels and ``np.argpartition`` raised
    ``kth(=276) out of bounds (30)`` (budget 406147 on a 6x5 tile). Above 2**53 float64 counts
    also lost samples."""

    @pytest.mark.parametrize("shape,budget", [((6, 5), 406_147), ((3, 5), 743_259), ((4, 1), 66_669),
                                              ((5, 7), 12_761_502), ((2, 2), 10**17), ((3, 5), 2**62)])
    def test_large_budget_is_exact(self, shape, budget):
        rng = np.random.default_rng(SEED)
        density = rng.random(shape) ** 8
        current = rng.integers(0, 50, shape)
        out = allocate(density, current, budget, rng=rng)
        assert out.dtype == np.int64
        assert int(out.sum()) == budget
        assert (out >= 0).all()

    def test_large_budget_with_capacity_is_exact(self):
        rng = np.random.default_rng(SEED)
        shape = (2, 3)
        capacity = rng.integers(0, 10**7, shape)
        budget = int(capacity.sum()) - 3
        out = allocate(rng.random(shape) ** 10, np.zeros(shape, np.int64), budget, capacity=capacity, rng=rng)
        assert int(out.sum()) == budget
        assert (out <= capacity).all() and (out >= 0).all()

    def test_random_budgets_exact(self):
        rng = np.random.default_rng(SEED)
        for _ in range(300):
            shape = tuple(int(s) for s in rng.integers(1, 8, 2))
            budget = int(10 ** rng.uniform(0, 9))
            capacity = None
            if rng.random() < 0.5:
                capacity = rng.integers(0, 10 ** int(rng.integers(1, 9)), shape)
                budget = min(budget, int(capacity.sum()))
            out = allocate(rng.random(shape) ** int(rng.integers(1, 20)), rng.integers(0, 50, shape), budget,
                           capacity=capacity, rng=rng)
            assert int(out.sum()) == budget
            if capacity is not None:
                assert (out <= capacity).all()

    def test_budget_beyond_int64_safety_is_refused(self):
        with pytest.raises(ValueError, match="budget"):
            allocate(np.ones((2, 2)), np.zeros((2, 2), np.int64), 2**62 + 1)

    @pytest.mark.parametrize("budget", [0, 1, 7, 10**9])
    @pytest.mark.parametrize("shape", [(1, 1), (1, 13), (13, 1), (7, 11)])
    def test_sampler_budgets_exact(self, shape, budget):
        sampler = AdaptiveSampler(shape, channels=1)
        first = sampler.ask()
        counts = first.counts
        rng = np.random.default_rng(SEED)
        sampler.tell(first, SampleBuffer.from_moments(counts, rng.random(shape), rng.random(shape)))
        request = sampler.ask(budget)
        assert request.total == budget
        assert (request.counts >= 0).all()

    def test_spp_max_that_cannot_be_met_raises(self):
        sampler = UniformSampler((3, 4), channels=1, initial_spp=2, spp_max=5)
        first = sampler.ask()
        sampler.tell(first, SampleBuffer.from_moments(first.counts, np.ones((3, 4)), np.ones((3, 4))))
        with pytest.raises(ValueError, match="spp_max"):
            sampler.ask(3 * 12 + 1)  # 3 samples of room per pixel, one too many
        ok = sampler.ask(3 * 12)  # exactly the room left
        assert ok.total == 36 and (ok.counts + first.counts <= 5).all()

    def test_adaptive_spp_max_that_cannot_be_met_raises(self):
        sampler = AdaptiveSampler((5, 7), channels=3, initial_spp=4, spp_max=4)
        first = sampler.ask()
        assert first.total == 4 * 35
        rng = np.random.default_rng(SEED)
        sampler.tell(first, SampleBuffer.from_moments(first.counts, rng.random((5, 7, 3)), rng.random((5, 7, 3))))
        assert sampler.ask(0).total == 0
        sampler.tell(1, SampleBuffer.empty((5, 7)))
        with pytest.raises(ValueError, match="spp_max"):
            sampler.ask(1)


# ---------------------------------------------------------------------------- float64 limits
class TestFloatLimits:
    """Regression: the log/gamma domains took ``np.mean(np.abs(mean))`` as their scale, which
    overflows (a RuntimeWarning, an error under ``-W error``) for means near 1e307; and the
    linear domain returned Inf silently for means near 1.8e308. Now the scale is computed
    normalised and a transform that overflows is a ValueError, never a non-finite image."""

    @pytest.mark.parametrize("magnitude", [1e300, 1e307, 1.7e308])
    @pytest.mark.parametrize("domain", ["log", "gamma"])
    def test_stabilised_domains_finite_up_to_float_max(self, magnitude, domain):
        rng = np.random.default_rng(SEED)
        buf = SampleBuffer.from_moments(np.full((16, 16), 4), magnitude * rng.random((16, 16, 1)),
                                        np.full((16, 16, 1), 1e300))
        out = reconstruct(buf, domain=domain)
        assert np.isfinite(out).all()
        request = AdaptiveSampler.from_buffer(buf).ask(100)
        assert request.total == 100

    @pytest.mark.parametrize("magnitude", [1e308, 1.7e308])
    def test_linear_overflow_is_a_clear_error(self, magnitude):
        buf = SampleBuffer.from_moments(np.full((8, 8), 4), np.full((8, 8, 1), magnitude), np.ones((8, 8, 1)))
        with pytest.raises(ValueError, match="overflows float64"):
            reconstruct(buf, domain="linear")

    def test_linear_finite_at_1e307(self):
        buf = SampleBuffer.from_moments(np.full((8, 8), 4), np.full((8, 8, 1), 1e307), np.ones((8, 8, 1)))
        assert np.isfinite(reconstruct(buf, domain="linear")).all()


class TestSamplerHostileStatistics:
    """Regressions found by test_robust_properties.py."""

    def test_density_with_huge_variance_next_to_tiny_is_finite(self):
        # uniform_filter's running sum leaves ~-1e-17 residues beside a 1e20 variance; their
        # square root was NaN (a RuntimeWarning, and a pixel silently given density 0).
        from awr_denoise.priorities import sampling_density

        rng = np.random.default_rng(0)
        h, w = (int(s) for s in rng.integers(3, 12, 2))
        var = np.zeros((h, w, 1))
        var[rng.integers(h), rng.integers(w)] = 10 ** rng.uniform(0, 30)
        var[rng.random((h, w, 1)) < 0.3] = rng.random() * 10 ** rng.uniform(-30, 0)
        buf = SampleBuffer.from_moments(np.full((h, w), 4), rng.random((h, w, 1)), var)
        for domain in ("linear", "log"):
            density = sampling_density(buf, domain=domain)
            assert np.isfinite(density).all() and (density >= 0).all()
        for cls in (AdaptiveSampler, VarianceSampler):
            sampler = cls.from_buffer(buf, domain="linear")
            assert sampler.ask(500).total == 500

    def test_budget_equal_to_a_capacity_above_2_53_does_not_hang(self):
        # The float64 sum of the capacities rounds below the exact integer budget, so the
        # bracket doubling never reached it (a hang without -W error, an overflow with it).
        rng = np.random.default_rng(766)
        capacity = rng.integers(0, 2**50 + 1, (7, 7))
        budget = int(capacity.sum())
        assert float(capacity.astype(np.float64).sum()) != budget  # the float sum is short
        out = allocate(np.ones((7, 7)), np.zeros((7, 7), np.int64), budget, capacity=capacity)
        assert int(out.sum()) == budget and (out <= capacity).all()
        with pytest.raises(ValueError, match="spp_max"):
            allocate(np.ones((7, 7)), np.zeros((7, 7), np.int64), budget + 1, capacity=capacity)
