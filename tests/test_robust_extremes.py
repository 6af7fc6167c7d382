"""Numerical behaviour at the extremes: tiny images, extreme magnitudes and parameters, budgets.

Deterministic companions of ``test_robust_properties.py`` (which explores the same ground with
hypothesis); each test here pins one documented behaviour of ``docs/robustness.md``.
"""

from __future__ import annotations

import copy
import math
import warnings
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


    @pytest.mark.parametrize("variance", [1e38, 1e300])
    @pytest.mark.parametrize("guided", [False, True])
    def test_a_channel_far_noisier_than_it_is_bright_stays_finite(self, variance, guided):
        """Regression: a variance of 1e38 beside means of 0.5 overflowed the float32 Wiener stages'
        (and the guide's projection's) FFTs: Inf, then NaN over the whole image. Capped where the
        sums would overflow, the image is the float64 route's to float32 rounding."""
        rng = np.random.default_rng(SEED)
        mean = 0.5 + 0.1 * rng.random((8, 12, 3))
        var = np.concatenate([np.full((8, 12, 1), variance), np.full((8, 12, 2), 0.04)], axis=2)
        buf = SampleBuffer.from_moments(np.full((8, 12), 8), mean, var)
        options = {"guide": np.full((8, 12, 3), 0.5)} if guided else {}
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            out = reconstruct(buf, **options)
        np.testing.assert_allclose(out, reconstruct(buf, precision="float64", **options), atol=1e-6)


class TestGuidedExtremes:
    """A guide (with the projection on it) at the float64 extremes, on tiny and prime shapes, and with
    zero variance: finite, no warning, the image mean kept."""

    @pytest.mark.parametrize("magnitude", [1e-300, 1e-30, 1e30, 1e300, 1e307])
    def test_extreme_magnitudes(self, magnitude):
        rng = np.random.default_rng(SEED)
        mean = magnitude * (0.5 + rng.random((16, 16, 3)))
        small = np.minimum(mean, 1e150)  # 30% noise, up to the largest variance float64 holds
        buf = SampleBuffer.from_moments(np.full((16, 16), 4), mean, np.where(mean > 1e150, 1e300, (0.3 * small) ** 2))
        with warnings.catch_warnings():  # numpy's default: overflow, invalid and division warn
            warnings.simplefilter("error")
            out = reconstruct(buf, guide=mean * 1.01)
        assert np.isfinite(out).all()
        # scaled first: a plain sum of 256 means near 1e307 overflows
        np.testing.assert_allclose((out / magnitude).mean(axis=(0, 1)), (mean / magnitude).mean(axis=(0, 1)), rtol=1e-9)

    @pytest.mark.parametrize("shape", [(1, 1), (1, 97), (3, 5), (13, 7)])
    def test_tiny_and_prime_shapes(self, shape):
        buf = noisy_buffer(shape)
        out = reconstruct(buf, guide=np.full(shape + (3,), 0.5))
        assert out.shape == shape + (3,) and np.isfinite(out).all()

    def test_zero_variance_returns_the_means_whatever_the_guide(self):
        rng = np.random.default_rng(SEED)
        mean = rng.random((12, 12, 3))
        buf = SampleBuffer.from_moments(np.full((12, 12), 4), mean, np.zeros((12, 12, 3)))
        np.testing.assert_allclose(reconstruct(buf, guide=mean[::-1]), mean, rtol=1e-6)


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


# ---------------------------------------------------------------------------- ringing bound
def _projection_matrix(shape, wavelet, levels):
    """The linear map of reconstruct at c_s -> inf (every detail zeroed): column j = response to pixel j."""
    from awr_denoise.wavelets import forward, inverse

    h, w = shape
    m = np.zeros((h * w, h * w))
    for j in range(h * w):
        e = np.zeros(h * w)
        e[j] = 1.0
        c = forward(e.reshape(h, w), wavelet=wavelet, levels=levels)
        c = [c[0]] + [tuple(np.zeros_like(b) for b in lvl) for lvl in c[1:]]
        m[:, j] = inverse(c, shape, wavelet=wavelet).ravel()
    return m


class TestRingingBound:
    """The documented bound ``r = 1`` (docs/robustness.md): the worst case of the
    detail-free reconstruction is exactly computable, and it is attained by reconstruct."""

    R = 1.0

    @pytest.mark.parametrize("domain", DOMAINS)
    def test_worst_two_level_pattern_attains_but_respects_the_bound(self, domain):
        shape, levels = (16, 16), 2
        m = _projection_matrix(shape, "bior4.4", levels)
        over = np.clip(m, 0, None).sum(axis=1) - 1.0  # overshoot of each output pixel for inputs in [0, 1]
        p = int(np.argmax(over))
        assert 0.8 < over[p] < self.R  # exact supremum for this shape: 0.856
        # Two levels in x are two levels in every domain, so the same pattern rings alike.
        pattern = (m[p] > 0).astype(float).reshape(shape)
        buf = SampleBuffer.from_moments(np.full(shape, 4), pattern[..., None], np.full(shape + (1,), 100.0))
        out = reconstruct(buf, domain=domain, c_s=1e6, levels=levels, pixel_clamp=None, stages=1)[..., 0]
        bound = Domain(domain).bound(buf.mean)
        y, y_out = bound.forward(pattern), bound.forward(out)
        r = (y_out.max() - y.max()) / (y.max() - y.min())
        assert r == pytest.approx(over[p], rel=1e-6)
        # The default pixel clamp (2.5 standard errors of each pixel) caps it in a noisy image.
        clamped = reconstruct(buf, domain=domain, c_s=1e6, levels=levels, stages=1)[..., 0]
        assert np.isfinite(clamped).all()

    def test_haar_detail_free_reconstruction_never_rings(self):
        m = _projection_matrix((12, 10), "haar", 2)
        assert (m >= -1e-12).all()  # block averages: a convex combination, no overshoot


# ---------------------------------------------------------------------------- variance accuracy
def _exact_variance(values) -> float:
    """Unbiased variance of float values in exact rational arithmetic."""
    xs = [Fraction(float(v)) for v in values]
    m = sum(xs) / len(xs)
    return float(sum((x - m) ** 2 for x in xs) / (len(xs) - 1))


class TestCancellation:
    """Mean 1e8 with unit variance: the naive ``E[x^2] - E[x]^2`` loses every digit
    (1e16 against 1); two-pass accumulation and Chan's merge must not."""

    def test_float64_samples_mean_1e8(self):
        rng = np.random.default_rng(SEED)
        values = 1e8 + rng.standard_normal(4000)
        pixels = np.zeros(4000, np.int64)
        whole = SampleBuffer.from_samples(pixels, values, (1, 1))
        exact = _exact_variance(values)
        assert whole.variance[0, 0, 0] == pytest.approx(exact, rel=1e-9)
        merged = SampleBuffer.from_samples(pixels[:7], values[:7], (1, 1))
        for start in range(7, 4000, 331):
            stop = min(4000, start + 331)
            merged = merged.merge(SampleBuffer.from_samples(pixels[start:stop], values[start:stop], (1, 1)))
        assert merged.count[0, 0] == 4000
        assert merged.variance[0, 0, 0] == pytest.approx(exact, rel=1e-8)
        assert merged.mean[0, 0, 0] == pytest.approx(float(sum(Fraction(float(v)) for v in values) / 4000), rel=1e-15)

    def test_float32_samples_mean_1e8(self):
        """float32 cannot hold 1e8 + N(0, 1): its spacing there is 8, so samples are 1e8 or
        1e8 +- 8. The reference is the exact variance of the float32 values as given."""
        rng = np.random.default_rng(SEED)
        values = (1e8 + 4 * rng.standard_normal(3000)).astype(np.float32)
        assert len(np.unique(values)) > 1
        pixels = np.zeros(3000, np.int64)
        exact = _exact_variance(values)
        buf = SampleBuffer.from_samples(pixels, values, (1, 1))
        assert buf.variance[0, 0, 0] == pytest.approx(exact, rel=1e-9)
        parts = [SampleBuffer.from_samples(pixels[i::3], values[i::3], (1, 1)) for i in range(3)]
        merged = parts[2].merge(parts[0]).merge(parts[1])
        assert merged.variance[0, 0, 0] == pytest.approx(exact, rel=1e-9)

    def test_float32_mean_1e4_unit_variance(self):
        rng = np.random.default_rng(SEED)
        values = (1e4 + rng.standard_normal(5000)).astype(np.float32)  # spacing 0.001: variance resolved
        buf = SampleBuffer.from_samples(np.zeros(5000, np.int64), values, (1, 1))
        assert buf.variance[0, 0, 0] == pytest.approx(_exact_variance(values), rel=1e-9)
        assert buf.variance[0, 0, 0] == pytest.approx(1.0, rel=0.1)

    def test_from_sums_documents_its_cancellation(self):
        """from_sums clamps at zero instead of going negative; its error at mean 1e8 is of the
        order eps * n * mean^2 (documented in its docstring: prefer from_samples/from_moments)."""
        rng = np.random.default_rng(SEED)
        values = 1e8 + rng.standard_normal(1000)
        buf = SampleBuffer.from_sums(np.array([[1000]]), np.array([[values.sum()]]), np.array([[(values**2).sum()]]))
        assert buf.variance[0, 0, 0] >= 0.0
        assert np.isfinite(buf.variance).all()


# ---------------------------------------------------------------------------- degenerate images
class TestDegenerateImages:
    @pytest.mark.parametrize("shape", [(1, 1), (1, 2), (2, 1), (1, 97), (97, 1), (3, 5), (13, 7)])
    @pytest.mark.parametrize("domain", DOMAINS)
    def test_every_level_of_tiny_and_prime_shapes(self, shape, domain):
        buf = noisy_buffer(shape)
        for levels in range(1, max_levels(shape) + 1):
            for wavelet in ("bior4.4", "haar"):
                out = reconstruct(buf, domain=domain, levels=levels, wavelet=wavelet)
                assert out.shape == shape + (3,) and np.isfinite(out).all()
        with pytest.raises(ValueError, match="levels"):
            reconstruct(buf, levels=max_levels(shape) + 1)
        with pytest.raises(ValueError, match="levels"):
            reconstruct(buf, levels=0)

    @pytest.mark.parametrize("domain", DOMAINS)
    @pytest.mark.parametrize("c_s", [0.0, 1.0, 1e6])
    def test_all_zero_image(self, domain, c_s):
        buf = SampleBuffer.from_moments(np.full((9, 7), 4), np.zeros((9, 7, 3)), np.zeros((9, 7, 3)))
        out = reconstruct(buf, domain=domain, c_s=c_s)
        assert np.array_equal(out, np.zeros_like(out))

    @pytest.mark.parametrize("domain", DOMAINS)
    @pytest.mark.parametrize("value", [1e-30, -3.5, 0.7, 1e30])
    @pytest.mark.parametrize("stages", [1, 3])
    def test_constant_image_with_noise_estimate_stays_constant(self, domain, value, stages):
        """In every stage; the Wiener stages in their float64 reference precision."""
        buf = SampleBuffer.from_moments(np.full((12, 9), 4), np.full((12, 9, 3), value),
                                        np.full((12, 9, 3), (0.5 * value) ** 2))
        out = reconstruct(buf, domain=domain, c_s=1.0, pixel_clamp=None, stages=stages, precision="float64")
        np.testing.assert_allclose(out, value, rtol=1e-9)

    @pytest.mark.parametrize("domain", DOMAINS)
    @pytest.mark.parametrize("c_s", [1e-12, 1.0, 1e6])
    def test_zero_variance_returns_the_mean_at_any_c_s(self, domain, c_s):
        """A deterministic image: every Delta is 0, nothing is thresholded."""
        rng = np.random.default_rng(SEED)
        mean = rng.random((10, 11, 3)) * 10.0 ** rng.integers(-5, 5, (10, 11, 1))
        buf = SampleBuffer.from_moments(np.full((10, 11), 8), mean, np.zeros_like(mean))
        out = reconstruct(buf, domain=domain, c_s=c_s, pixel_clamp=None)
        np.testing.assert_allclose(out, mean, rtol=1e-9, atol=1e-12 * np.abs(mean).max())

    def test_single_sample_everywhere_is_left_as_is(self):
        """One sample per pixel: no variance is known anywhere, so nothing is known to be noise
        and the output is the mean (documented: 1 spp is not denoised)."""
        buf = SampleBuffer.from_moments(np.ones((8, 8), np.int64), np.random.default_rng(SEED).random((8, 8, 3)),
                                        np.zeros((8, 8, 3)))
        assert not buf.variance_known.any()
        np.testing.assert_allclose(reconstruct(buf), buf.mean, rtol=1e-12)

    def test_single_sample_pixels_borrow_variance(self):
        buf = noisy_buffer((16, 16), spp=4)
        count = np.array(buf.count)
        count[::3, ::2] = 1
        mixed = SampleBuffer.from_moments(count, buf.mean, buf.variance)
        v = mixed.estimated_variance()
        assert (v[count == 1] > 0).all()  # never taken as zero variance
        assert np.isfinite(reconstruct(mixed)).all()

    @pytest.mark.parametrize("domain", DOMAINS)
    def test_zero_count_pixels_are_filled_from_neighbours(self, domain):
        buf = noisy_buffer((16, 16), spp=4)
        count = np.array(buf.count)
        count[5:9, 5:9] = 0
        holes = SampleBuffer.from_moments(count, buf.mean, buf.variance)
        out = reconstruct(holes, domain=domain)
        assert np.isfinite(out).all()
        assert np.abs(out[5:9, 5:9] - 0.5).max() < 0.5  # near the image level, not black

    def test_no_samples_at_all_is_a_clear_error(self):
        with pytest.raises(ValueError, match="no pixel has any sample"):
            reconstruct(SampleBuffer.empty((4, 4)))
        sampler = AdaptiveSampler((4, 4))
        assert sampler.ask().total == 2 * 16  # round 0 (2 spp) never needs statistics

    @pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64])
    def test_input_dtypes_agree(self, dtype):
        ref = noisy_buffer((9, 13), dtype=np.float64)
        buf = SampleBuffer.from_moments(ref.count, ref.mean.astype(dtype), ref.variance.astype(dtype))
        assert buf.mean.dtype == np.float64
        out, out_ref = reconstruct(buf), reconstruct(ref)
        tol = {np.float16: 5e-3, np.float32: 1e-6, np.float64: 1e-12}[dtype]
        np.testing.assert_allclose(out, out_ref, rtol=tol, atol=tol)

    @pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf"), True, "1"])
    def test_bad_c_s_is_refused(self, bad):
        with pytest.raises((ValueError, TypeError), match="c_s"):
            reconstruct(noisy_buffer((4, 4)), c_s=bad)

    @pytest.mark.parametrize("c_s", [0.0, 1e-12])
    def test_tiny_c_s_is_the_mean(self, c_s):
        """In float64 to 1e-9; in float32 (stage 1's default in the log domain for c_s > 0) to
        float32's precision."""
        buf = noisy_buffer((16, 12))
        np.testing.assert_allclose(reconstruct(buf, c_s=c_s, stages=1, precision="float64"), buf.mean, rtol=1e-9)
        np.testing.assert_allclose(reconstruct(buf, c_s=c_s, stages=1), buf.mean, rtol=1e-5)

    def test_huge_c_s_keeps_only_the_coarse_band(self):
        buf = noisy_buffer((32, 32))
        rec = reconstruct_detailed(buf, c_s=1e6, domain="linear", variance_probes=0, pixel_clamp=None)
        assert rec.fraction_zeroed == 1.0
        assert abs(rec.image.mean() - buf.mean.mean()) < 0.01


class TestOutputVariance:
    """Regression: ``reconstruct_detailed`` undid the domain on the output variance with
    ``var / (d * d)``; ``d * d`` overflows for means below ~1e-154 and underflows to 0 above
    ~1e154 (RuntimeWarning, then Inf or NaN variances). Now ``var / d / d``."""

    @pytest.mark.parametrize("magnitude", [1e-300, 1e-160, 1e-30, 1.0, 1e30, 1e160, 1e300])
    @pytest.mark.parametrize("domain", DOMAINS)
    def test_output_variance_is_finite(self, magnitude, domain):
        rng = np.random.default_rng(SEED)
        var = (0.1 * magnitude) ** 2 if magnitude < 1e150 else 1e300
        buf = SampleBuffer.from_moments(np.full((8, 8), 4), magnitude * rng.random((8, 8, 1)), np.full((8, 8, 1), var))
        rec = reconstruct_detailed(buf, domain=domain, variance_probes=4)
        assert np.isfinite(rec.image).all()
        assert np.isfinite(rec.variance).all() and (rec.variance >= 0).all()


@pytest.mark.parametrize("value", [0.1, 1e200, -3e250, 1e300, 5e-324])
@pytest.mark.parametrize("n", [3, 7, 101])
def test_samples_that_all_agree_have_their_value_and_no_variance(value, n):
    """The first mean's rounding (7 x 0.1 / 7 is not 0.1), squared, was a spread of samples that all agreed:
    near 1e200, scaled back, a variance beyond float64, and the buffer was refused."""
    buf = SampleBuffer.from_samples(np.zeros(n, int), np.full((n, 2), value), (1, 1))
    assert buf.mean[0, 0, 0] == value and buf.variance[0, 0, 0] == 0.0


@pytest.mark.parametrize("n, power", [(2**20, 510), pytest.param(2**24, 500, marks=pytest.mark.slow)])
def test_a_variance_within_float64_is_kept_whatever_its_sum_of_squares(n, power):
    """n samples of +-2**power: a variance of about 2**(2 power), within float64, and a sum of squared deviations
    of n times that, beyond it. The scaled sum was refused as a variance beyond float64 (2**20 samples of
    +-2**510), and at 2**500, below the scaling threshold, it overflowed unscaled (found by a review)."""
    values = np.where(np.arange(n) % 2 == 0, 2.0**power, -(2.0**power))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        buf = SampleBuffer.from_samples(np.zeros(n, int), values, (1, 1))
    assert buf.mean[0, 0, 0] == 0.0 and buf.variance[0, 0, 0] == 2.0 ** (2 * power) * (n / (n - 1))


def test_from_samples_near_the_float64_limit_scales_each_pixel_exactly():
    """Sums of samples near 1e308 overflow where their means do not: each pixel is scaled by a power
    of two of its own (exact), so a tiny pixel beside a huge one keeps its bits, and a scaled
    image's statistics are the unscaled ones times the scale, bit for bit."""
    rng = np.random.default_rng(3)
    pixels, base = rng.integers(0, 6, 400), 1.0 + rng.random((400, 3))
    plain = SampleBuffer.from_samples(pixels, base, (2, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        big = SampleBuffer.from_samples(pixels, base * 2.0**505, (2, 3))
        np.testing.assert_array_equal(big.mean, plain.mean * 2.0**505)
        np.testing.assert_array_equal(big.variance, plain.variance * 2.0**1010)
        equal = SampleBuffer.from_samples(np.zeros(200, int), np.full(200, 2.0**1000), (1, 1))  # the sum overflows
        assert equal.mean[0, 0, 0] == 2.0**1000 and equal.variance[0, 0, 0] == 0.0
        mixed = SampleBuffer.from_samples(np.array([0, 0, 1, 1]), np.array([1e153, 3e153, 1e-300, 3e-300]), (1, 2))
        np.testing.assert_allclose(mixed.mean[0, :, 0], [2e153, 2e-300], rtol=1e-15)
        denormal = SampleBuffer.from_samples(np.array([0, 0, 1, 1]), np.array([1e200, 1e200, 5e-324, 0.0]), (1, 2))
        assert denormal.mean[0, 1, 0] == (5e-324 + 0.0) / 2  # as unscaled float64 arithmetic rounds it
        zeros = SampleBuffer.from_samples(np.array([0, 1]), np.array([1e200, 0.0]), (1, 2))
        assert zeros.mean[0, 1, 0] == 0.0 and zeros.variance[0, 1, 0] == 0.0
        with pytest.raises(ValueError, match="values: the variance of 1 pixel"):
            SampleBuffer.from_samples(np.array([0, 0]), np.array([1e200, -1e200]), (1, 1))
        with pytest.raises(ValueError, match=r"features\['depth'\]: the variance of 1 pixel"):  # not "values"
            SampleBuffer.from_samples(np.array([0, 0]), np.array([1.0, 2.0]), (1, 1),
                                      features={"depth": np.array([-1e300, 1e300])})
        with pytest.raises(ValueError, match="sum_sq: a second moment beyond float64"):
            SampleBuffer.from_sums([[2]], [[1.7e308]], [[1e308]])


@pytest.mark.parametrize("variance", [5e307, 1e308, 1.7e308])
def test_variances_near_the_float64_limit(variance):
    """The reconstruction keeps such a buffer without a warning; the sampler, whose log domain takes the
    variance past float64, refuses it naming the buffer, not one of its internal arrays."""
    buffer = SampleBuffer.from_moments(np.full((8, 8), 4), np.full((8, 8, 3), 0.5), np.full((8, 8, 3), variance))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isfinite(reconstruct(buffer)).all()
        try:
            counts = AdaptiveSampler.from_buffer(buffer).ask(10).counts
        except ValueError as exc:
            assert str(exc).startswith("buffer: the per-sample variance of 64 pixel(s) is beyond float64")
            # The advice works (it said "scale the radiance down", which changes nothing in the log domain).
            assert "domain='linear'" in str(exc)
            counts = AdaptiveSampler.from_buffer(buffer, domain="linear").ask(10).counts
        assert counts.sum() == 10


@pytest.mark.parametrize("domain", ["linear", "log"])
def test_a_huge_variance_beside_means_of_zero_is_capped_in_the_wiener_stages_domain(domain):
    """The Wiener stages divide the variances by their weights squared, about k^1.5 beside means of 0:
    a variance of 5.7e36 went past float32's range there and overflowed in the factors (a warning;
    found by the documented exploration run, ``AWR_ROBUST_EXPLORE=2000``). The cap is in the stage's domain."""
    buffer = SampleBuffer.from_moments(np.array([[2, 0]]), np.zeros((1, 2)), np.array([[5.73e36, 0.0]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = reconstruct(buffer, domain=domain, c_s=0, levels=1, pixel_clamp=None)
    assert np.array_equal(out, np.zeros((1, 2, 1)))


@pytest.mark.parametrize("variance", [1e307, 1.7e308])
def test_a_variance_past_float64_in_the_log_domain_is_named_and_the_linear_domain_takes_it(variance):
    """Beside means of 0 the log domain divides a variance of 1e307 by k^2 (k tiny) past float64: the
    refusal named ``variance_of_mean``, an array the caller never passed; the linear domain leaked the
    guard's overflow warning (a review of the array-layout fixes)."""
    buffer = SampleBuffer.from_moments(np.full((8, 8), 4), np.zeros((8, 8, 3)), np.full((8, 8, 3), variance))
    with pytest.raises(ValueError, match=r"buffer: the variance of 64 pixel\(s\) is beyond float64 in the log "
                                         r"domain .* domain='linear'"):
        reconstruct(buffer)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for precision in ("float32", "float64"):
            assert np.array_equal(reconstruct(buffer, domain="linear", precision=precision), np.zeros((8, 8, 3)))


@pytest.mark.parametrize("level", [1e-200, 1e-300])
@pytest.mark.parametrize("options", [{}, {"mode": "luminance"}, {"guide": np.full((16, 16, 3), 0.5)}])
def test_means_far_below_their_noise_give_finite_variances_in_the_linear_domain(level, options):
    """Means of 0 but for a few of 1e-200 beside ordinary variances (an AOV whose samples cancel): the Wiener
    stages brought the image to its level, where the variances passed float64, and returned NaN variances
    with overflow warnings (the attack pass of the library's API). Now such an image is brought to its
    noise's scale; a power of two times the buffer is still that power times the reconstruction, bit for bit."""
    mean = np.zeros((16, 16, 3))
    mean[::5, ::7] = level
    buffer = SampleBuffer.from_moments(np.full((16, 16), 8), mean, np.full((16, 16, 3), 0.04))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = reconstruct_detailed(buffer, domain="linear", variance_probes=4, **options)
        scaled = SampleBuffer.from_moments(np.full((16, 16), 8), mean * 2.0**60, np.full((16, 16, 3), 0.04 * 2.0**120))
        options = {name: value * 2.0**60 if name == "guide" else value for name, value in options.items()}
        again = reconstruct_detailed(scaled, domain="linear", variance_probes=4, **options)
    assert np.isfinite(rec.variance).all() and (rec.variance >= 0).all()
    if "guide" not in options:  # the guide's 0.5 is inside the noise: it may be followed
        assert np.abs(rec.image).max() <= level
    np.testing.assert_array_equal(again.image, rec.image * 2.0**60)
    np.testing.assert_array_equal(again.variance, rec.variance * 2.0**120)


def test_one_pixel_of_huge_variance_leaves_the_image_at_its_level():
    """Only an image whose variances would pass float64 at its level is brought to its noise's scale: one pixel of
    variance 1e300 beside ordinary ones is not: its scale and offset are those of the image without it."""
    from awr_denoise.prepare import prepare
    rng = np.random.default_rng(SEED)
    mean = 0.5 + 0.1 * rng.standard_normal((16, 16, 3))
    variance = np.full((16, 16, 3), 0.05)
    plain = SampleBuffer.from_moments(np.full((16, 16), 8), mean, variance)
    variance[8, 8] = 1e300
    wild = SampleBuffer.from_moments(np.full((16, 16), 8), mean, variance)
    assert prepare(wild, "linear").unit_scaled()[:2] == prepare(plain, "linear").unit_scaled()[:2]


def test_counts_beyond_int64_are_named_as_such_not_negative():
    """Two buffers of 2**62 samples merged, or a uint64 count of 2**64-1, were "negative" (the int64
    sum or cast wrapped; red-team pass 5)."""
    one = SampleBuffer.from_moments(np.array([[2**62]]), np.ones((1, 1, 1)), np.ones((1, 1, 1)))
    with pytest.raises(ValueError, match="more than 2\\*\\*62 samples merged"):
        one.merge(copy.deepcopy(one))
    with pytest.raises(ValueError, match="count: 1 pixel\\(s\\) exceed 2\\*\\*62"):
        SampleBuffer.from_moments(np.array([[2**64 - 1]], dtype=np.uint64), np.ones((1, 1, 1)), np.ones((1, 1, 1)))
