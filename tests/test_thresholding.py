"""Stage 1, Eq. 10-11 (the end-to-end checks are in tests/test_reconstruct.py with ``stages=1``)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from awr_denoise import SampleBuffer, SampleRequest
from awr_denoise.prepare import prepare
from awr_denoise.synthetic import SyntheticRenderer, make_scene
from awr_denoise.thresholding import soft_threshold, threshold_stage
from awr_denoise.wavelets import wavelet_operators


def test_soft_threshold_is_eq_11():
    w = np.array([-3.0, -1.0, -0.5, 0.0, 0.5, 1.0, 3.0])
    assert_array_equal(soft_threshold(w, 1.0), [-2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0])
    assert_array_equal(soft_threshold(w, 0.0), w)


def test_stage_counts_what_it_zeroed_and_estimates_its_variance(rng):
    buf = SampleBuffer.from_moments(np.full((24, 20), 6), 0.5 + 0.1 * rng.standard_normal((24, 20, 3)),
                                    np.full((24, 20, 3), 0.06))
    stage = threshold_stage(prepare(buf, "linear"), wavelet_operators((24, 20)), 1.0)
    assert 0 < stage.zeroed < stage.total
    variance = stage.output_variance(8, 0)
    assert variance.shape == (24, 20, 3) and variance.mean() < 0.5 * buf.variance_of_mean().mean()


def test_luminance_mode_needs_the_luminance_plane(rng):
    buf = SampleBuffer.from_moments(np.full((8, 8), 4), rng.random((8, 8, 3)), np.full((8, 8, 3), 0.01))
    with pytest.raises(ValueError, match="luminance"):
        threshold_stage(prepare(buf), wavelet_operators((8, 8)), 1.0, mode="luminance")


# ---------------------------------------------------------------------------- float32 against float64
F32_TOLERANCE = 2e-5
"""float32 stage 1 against the float64 reference: within this share of ``|out| + k`` at every pixel
(float32's epsilon is 6e-8; the log domain's values reach ~20 and the transforms sum a few dozen
terms). Measured: at most 6e-6 on a 1080p buffer of random means, 7e-6 on the tracer's and Mitsuba 3's
buffers (``benchmarks/bench_core.py --only precision``)."""


def _stage(buffer, precision, **options):
    prepared = prepare(buffer, "log")
    return prepared, threshold_stage(prepared, wavelet_operators(buffer.shape), options.pop("c_s", 1.0),
                                     precision=precision, **options)


@pytest.mark.parametrize("scene", ["edges", "hdr_source", "fireflies", "gradient"])
@pytest.mark.parametrize("pixel_clamp", [2.5, None])
def test_float32_stage_is_the_float64_stage_to_float32_precision(scene, pixel_clamp):
    shape = (40, 56)
    buf = SyntheticRenderer(make_scene(scene, shape), seed=4)(SampleRequest.uniform(shape, 4))
    prepared, ref = _stage(buf, "float64", pixel_clamp=pixel_clamp)
    _, single = _stage(buf, "float32", pixel_clamp=pixel_clamp)
    assert single.image.dtype == np.float64
    error = np.abs(single.image - ref.image) / (np.abs(ref.image) + prepared.bound.k)
    assert error.max() < F32_TOLERANCE
    assert not np.array_equal(single.image, ref.image)  # the float32 path did run
    # The same coefficients zeroed, but for the few a float32 rounding puts on the other side.
    assert abs(single.zeroed - ref.zeroed) <= 1e-3 * ref.total and single.total == ref.total
    for t32, t64 in zip(single.thresholds[0][1:], ref.thresholds[0][1:]):
        for a, b in zip(t32, t64):
            assert np.allclose(a, b, rtol=1e-5, atol=1e-30)


def test_the_float32_stage_builds_no_float64_domain_variance(rng):
    """The check of a variance past float64 in the domain built ``variance_y``, a whole float64 array the float32
    path never reads, and the prepared statistics kept it: stage 1's peak memory went from 1.3x to 2.1x its buffer at
    1080p (docs/performance.md). It is built now only where a bound on it passes float64, and named as before."""
    buf = SampleBuffer.from_moments(np.full((24, 20), 6), 0.5 + 0.1 * rng.standard_normal((24, 20, 3)),
                                    np.full((24, 20, 3), 0.06))
    prepared, _ = _stage(buf, "float32")
    assert "variance_y" not in vars(prepared)  # a cached_property keeps what it built in the instance
    tiny = SampleBuffer.from_moments(np.full((4, 4), 4), np.zeros((4, 4, 3)), np.full((4, 4, 3), 1e307))
    with pytest.raises(ValueError, match=r"^buffer: the variance of 16 pixel\(s\) is beyond float64 in the log"):
        _stage(tiny, "float32")


def test_float32_output_variance_uses_the_factors_it_applied(rng):
    buf = SampleBuffer.from_moments(np.full((24, 20), 6), 0.5 + 0.1 * rng.standard_normal((24, 20, 3)),
                                    np.full((24, 20, 3), 0.06))
    _, ref = _stage(buf, "float64")
    _, single = _stage(buf, "float32")
    assert np.allclose(single.output_variance(4, 0), ref.output_variance(4, 0), rtol=1e-4)


def test_float32_keeps_the_mean_where_the_clamp_has_zero_width(rng):
    mean = np.exp(rng.normal(0.0, 1.0, (20, 28, 3)))
    variance = np.full_like(mean, 0.05)
    variance[:5] = 0.0  # exact pixels: pinned to their mean
    buf = SampleBuffer.from_moments(np.full((20, 28), 5), mean, variance)
    exact = prepare(buf, "log").sample_variance == 0  # rows 0-2; rows 3-4 borrow their neighbours' (pooling)
    assert exact[:3].all() and not exact[5:].any()
    _, single = _stage(buf, "float32")
    assert_array_equal(single.image[exact], mean[exact])
    _, closed = _stage(buf, "float32", pixel_clamp=0.0)
    assert_array_equal(closed.image, mean)


@pytest.mark.parametrize("scale", [1e-36, 1e36])
def test_float32_falls_back_to_float64_where_values_do_not_fit(rng, scale):
    """Means whose offset k lies outside float32's comfortable range: the float64 path, bit for bit."""
    mean = scale * np.exp(rng.normal(0.0, 1.0, (16, 16, 3)))
    buf = SampleBuffer.from_moments(np.full((16, 16), 4), mean, (0.1 * mean) ** 2)
    assert_array_equal(_stage(buf, "float32")[1].image, _stage(buf, "float64")[1].image)


@pytest.mark.parametrize("light", [1e10, 1e16, 1e25])
def test_float32_falls_back_to_float64_where_it_cannot_resolve_a_dim_background(rng, light):
    """A 4x4 light far above a dim background sets the log domain's offset k: the background's
    ``log(1 + x / k)`` rounds to 0 in float32 and came back as exactly 0 (a red-team pass), or its
    variance there underflowed float32 (1e25). The float64 path then, bit for bit; a light the
    rendered scenes' range keeps float32."""
    mean = 0.5 + 0.07 * rng.standard_normal((32, 32, 3))
    var = np.full((32, 32, 3), 0.04)
    mean[14:18, 14:18], var[14:18, 14:18] = light, (0.01 * light) ** 2
    buf = SampleBuffer.from_moments(np.full((32, 32), 8), mean, var)
    fast, exact = _stage(buf, "float32")[1].image, _stage(buf, "float64")[1].image
    assert_array_equal(fast, exact)
    assert (exact[:8, :8] > 0).all()
    mean[14:18, 14:18], var[14:18, 14:18] = 1e3, 1e2
    buf = SampleBuffer.from_moments(np.full((32, 32), 8), mean, var)
    assert not np.array_equal(_stage(buf, "float32")[1].image, _stage(buf, "float64")[1].image)


def test_float32_applies_to_the_log_domain_in_channel_mode_only(rng):
    buf = SampleBuffer.from_moments(np.full((16, 16), 4), rng.random((16, 16, 3)), np.full((16, 16, 3), 0.01))
    ops = wavelet_operators(buf.shape)
    for domain in ("linear", "gamma"):
        prepared = prepare(buf, domain)
        assert_array_equal(threshold_stage(prepared, ops, 1.0, precision="float32").image,
                           threshold_stage(prepared, ops, 1.0, precision="float64").image)
    with pytest.raises(ValueError, match="precision"):
        threshold_stage(prepare(buf), ops, 1.0, precision="float16")
