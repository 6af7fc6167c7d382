"""Image metrics: hand-checked values, edge cases and input validation."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose

from awr_denoise.metrics import METRICS, RELMSE_EPSILON, mean_error, mse, psnr, relmse, ssim, tonemap

EXACT = 1e-12


def test_mse_hand_checked():
    assert mse(np.array([0.0, 1.0, 2.0]), np.zeros(3)) == pytest.approx(5.0 / 3.0, rel=EXACT)
    assert mse(np.ones((2, 2, 3)), np.ones((2, 2, 3))) == 0.0


def test_relmse_hand_checked_with_epsilon_001():
    assert RELMSE_EPSILON == 0.01
    # (1.1 - 1)^2 / (1 + 0.01) and (0.1 - 0)^2 / (0 + 0.01), averaged.
    x, r = np.array([1.1, 0.1]), np.array([1.0, 0.0])
    assert relmse(x, r) == pytest.approx((0.01 / 1.01 + 1.0) / 2.0, rel=EXACT)
    assert relmse(np.array([3.0]), np.array([1.0]), eps=0.0) == pytest.approx(4.0, rel=EXACT)
    # Relative: scaling image and reference together leaves it unchanged when eps is negligible.
    assert relmse(1e3 * x[:1], 1e3 * r[:1]) == pytest.approx(0.01, rel=1e-6)


def test_psnr_hand_checked():
    ref = np.array([0.0, 2.0, 1.0, 1.0])
    x = ref + np.array([0.2, -0.2, 0.2, -0.2])  # MSE 0.04, peak 2: 10 log10(4 / 0.04) = 20 dB
    assert psnr(x, ref) == pytest.approx(20.0, rel=EXACT)
    assert psnr(x, ref, peak=0.2) == pytest.approx(0.0, abs=1e-12)
    assert psnr(ref, ref) == float("inf")
    assert psnr(np.ones(3), np.zeros(3)) == float("-inf")


def test_tonemap_hand_checked():
    v = tonemap(np.array([-1.0, 0.0, 0.002, 0.5, 1.0, 5.0]))
    assert_allclose(v, [0.0, 0.0, 12.92 * 0.002, 1.055 * 0.5 ** (1 / 2.4) - 0.055, 1.0, 1.0], rtol=EXACT)
    assert tonemap(np.array([0.25]), exposure=1.0)[0] == pytest.approx(tonemap(np.array([0.5]))[0], rel=EXACT)


def test_ssim_is_one_for_identical_images_and_below_otherwise(rng):
    ref = rng.random((32, 32, 3))
    assert ssim(ref, ref) == pytest.approx(1.0, abs=EXACT)
    noisy = ref + 0.05 * rng.standard_normal(ref.shape)
    worse = ref + 0.2 * rng.standard_normal(ref.shape)
    s1, s2 = ssim(noisy, ref), ssim(worse, ref)
    assert s2 < s1 < 1.0
    assert ssim(ref[..., 0], ref[..., 0]) == pytest.approx(1.0, abs=EXACT)  # single-channel images


def test_ssim_of_a_shifted_constant_is_hand_checked():
    # Constant images a and b: the structure term is 1 and SSIM is (2ab + c1) / (a^2 + b^2 + c1)
    # on the tonemapped values.
    a, b = tonemap(np.array([0.2]))[0], tonemap(np.array([0.4]))[0]
    expected = (2 * a * b + 1e-4) / (a * a + b * b + 1e-4)
    assert ssim(np.full((16, 16), 0.2), np.full((16, 16), 0.4)) == pytest.approx(expected, rel=1e-10)


def test_mean_error_hand_checked_per_channel():
    """The largest channel's change of mean: 1% on R, -4% on G, none on B (its errors cancel)."""
    ref = np.full((2, 2, 3), 0.5)
    image = ref.copy()
    image[..., 0] = 0.505
    image[..., 1] = 0.48
    image[0, :, 2], image[1, :, 2] = 0.4, 0.6
    assert mean_error(image, ref) == pytest.approx(0.04, rel=EXACT)
    assert mean_error(image[..., 0], ref[..., 0]) == pytest.approx(0.01, rel=EXACT)  # (H, W): one channel
    assert mean_error(image[..., 2], ref[..., 2]) == 0.0
    assert mean_error(np.array([0.25, 1.0]), np.array([0.5, 0.5])) == pytest.approx(0.25, rel=EXACT)
    # A negative mean (a difference image as reference) is a change relative to its magnitude.
    assert mean_error(np.array([-0.9]), np.array([-1.0])) == pytest.approx(0.1, rel=EXACT)
    assert METRICS["mean_error"] is mean_error


def test_mean_error_over_a_black_channel_is_zero_or_infinite():
    ref = np.zeros((2, 2, 3))
    assert mean_error(ref, ref) == 0.0
    image = ref.copy()
    image[0, 0, 1] = 1e-300
    assert mean_error(image, ref) == np.inf
    with warnings.catch_warnings():  # a subnormal reference against a normal image: inf without a warning
        warnings.simplefilter("error")
        assert mean_error(np.ones((2, 2)), np.full((2, 2), 1e-310)) == np.inf


@pytest.mark.parametrize("scale", [1.0, 1e-100, 1e-200, 1e-300, 1e-320, 1e150, 1e300, 1.7e308])
def test_mean_error_holds_at_every_scale(scale):
    """Means of values near 1e308 overflow a plain sum (inf / inf is NaN) and those near 1e-320 are
    subnormal (their sum's digits run out): the channel's largest value is divided out first."""
    ref = np.full((8, 8, 3), 0.5)
    image = ref.copy()
    image[0, 0] = 1.0  # +0.5 on one pixel of 64: +1/64 of the mean
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        value = mean_error(image * scale, ref * scale)
    assert value == pytest.approx(1 / 64, rel=1e-3 if scale < 1e-307 else EXACT)


@pytest.mark.parametrize("metric", [mse, relmse, mean_error, psnr, ssim])
def test_bad_inputs_are_refused(metric):
    with pytest.raises(ValueError, match=r"reference: shape \(3, 3\) does not match image \(3, 4\)"):
        metric(np.zeros((3, 4)), np.zeros((3, 3)))
    bad = np.zeros((4, 4))
    bad[0, :3] = np.nan
    with pytest.raises(ValueError, match=r"image: 3 value\(s\) are NaN or Inf"):
        metric(bad, np.zeros((4, 4)))
    with pytest.raises(ValueError, match=r"reference: 1 value\(s\) are NaN or Inf"):
        metric(np.zeros((4, 4)), np.where(np.eye(4, dtype=bool) & (np.arange(4) == 2), np.inf, 0.0))
    with pytest.raises(ValueError, match="image: empty"):
        metric(np.zeros((0, 3)), np.zeros((0, 3)))


def test_masked_entries_are_refused_not_compared():
    """``np.asarray`` drops a mask: the values under it were compared (red-team pass of the API's
    array layouts); a complex image lost its imaginary part in ``tonemap``."""
    image = np.ma.masked_greater(np.array([[0.5, 100.0]]), 1)
    with pytest.raises(TypeError, match="image: a masked array with 1 masked entries"):
        mse(image, np.full((1, 2), 0.5))
    with pytest.raises(TypeError, match="reference: a masked array"):
        relmse(np.full((1, 2), 0.5), image)
    with pytest.raises(TypeError, match="x: complex values are not supported"):
        tonemap(np.array([0.5 + 1j]))
    assert mse(np.ma.masked_array([[0.5, 1.0]]), np.full((1, 2), 0.5)) == pytest.approx(0.125)


@pytest.mark.parametrize("scale", [1.0, 1e-100, 1e-170, 1e-200, 1e-300, 1e150, 1e300])
def test_scale_free_metrics_hold_at_every_scale(scale):
    """PSNR and relMSE with ``eps = 0`` do not depend on the images' scale: near 1e-170 the squared error
    underflowed to 0 and read as none, PSNR inf and relMSE 0 (a red-team pass; near 1e300 the squares
    overflowed, fixed before)."""
    x, r = np.full((4, 4), 2 * scale), np.full((4, 4), scale)
    x[0, 0] = 4 * scale  # errors of two sizes: the scaled mean, not one term
    assert psnr(x, r) == pytest.approx(-10 * np.log10((15 + 9) / 16), rel=1e-12)
    assert relmse(x, r, eps=0) == pytest.approx((15 + 9) / 16, rel=1e-12)
    assert psnr(r, r) == np.inf and relmse(r, r, eps=0) == 0.0


def test_psnr_of_images_whose_difference_passes_float64():
    """1.7e308 against -1.7e308: each value is finite, their difference is not; PSNR was -inf, not -3 dB."""
    top = 1.7e308
    assert psnr(np.array([top, 0.0]), np.array([-top, 0.0])) == pytest.approx(-10 * np.log10(2.0), rel=1e-12)
    assert psnr(np.array([top, 0.0]), np.array([-top, 0.0])) == pytest.approx(
        psnr(np.array([1.7, 0.0]), np.array([-1.7, 0.0])), rel=1e-12)


@pytest.mark.parametrize("exposure", [0.0, -1e6, 2000.0])
def test_tonemap_shows_infinities_as_white_and_black_at_any_exposure(exposure):
    """Below an exposure of -1074 the scale is 0 and inf * 0 was NaN (a red-team pass)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        shown = tonemap(np.array([np.inf, -np.inf]), exposure=exposure)
    assert shown.tolist() == tonemap(np.array([1.0, 0.0])).tolist()


def test_relmse_without_epsilon_is_infinite_only_on_an_error_over_a_black_reference():
    assert relmse(np.array([1e-200, 0.0]), np.array([0.0, 0.0]), eps=0) == np.inf
    assert relmse(np.array([0.0, 1e-200]), np.array([0.0, 1e-200]), eps=0) == 0.0


def test_ssim_refuses_what_is_not_an_image_and_tonemap_refuses_nan():
    """A 1-D or 0-d input raised IndexError; ``tonemap`` passed NaN through (a red-team pass)."""
    for shape in [(8,), (), (2, 3, 4, 5)]:
        with pytest.raises(ValueError, match=r"image: expected \(H, W\) or \(H, W, C\)"):
            ssim(np.zeros(shape), np.zeros(shape))
    with pytest.raises(ValueError, match=r"x: 1 value\(s\) are NaN"):
        tonemap(np.array([np.nan, 0.5]))
    assert_allclose(tonemap(np.array([np.inf, -np.inf])), [1.0, 0.0])  # a viewer clips them
