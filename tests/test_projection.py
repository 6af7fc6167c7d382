"""Projection of the means on a guide within their confidence intervals: formula, limits, linear map."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from awr_denoise.projection import project
from awr_denoise.stationary import StationaryTransform

SHAPE = (24, 28)
FLOAT32_RTOL = 2e-5  # single-precision FFTs a few dozen operations deep, then a clip


@pytest.fixture
def transform():
    return StationaryTransform(SHAPE, levels=3)


def _scene(rng, channels=3):
    clean = 1.0 + 0.5 * np.sin(np.arange(SHAPE[1]) / 3.0)[None, :, None] * np.ones(SHAPE + (channels,))
    variance = rng.uniform(0.01, 0.05, clean.shape)
    return clean, clean + np.sqrt(variance) * rng.standard_normal(clean.shape), variance


def _by_hand(t, x, v, g, *, k, radius, exponent, scale_band=True):
    """The module's formula band by band through the public transform (float64)."""
    out = np.empty_like(x)
    for c in range(x.shape[2]):
        w = (np.abs(g[..., c]) + k) ** exponent
        xs, gs = t.forward(x[..., c] / w), t.forward(g[..., c] / w)
        var = t.variance(v[..., c] / w / w)
        reach = radius * np.sqrt(np.maximum(var[0], 0.0))
        bands = [xs[0] + np.clip(gs[0] - xs[0], -reach, reach) if scale_band else xs[0]]
        for lx, lg, lv in zip(xs[1:], gs[1:], var[1:]):
            r = [radius * np.sqrt(np.maximum(b, 0.0)) for b in lv]
            bands.append(tuple(bx + np.clip(bg - bx, -br, br) for bx, bg, br in zip(lx, lg, r)))
        out[..., c] = t.inverse(bands) * w
    return out


@pytest.mark.parametrize("scale_band", [True, False])
@pytest.mark.parametrize("exponent", [0.0, 0.5, 1.0])
def test_the_result_is_the_formula_band_by_band(rng, transform, exponent, scale_band):
    clean, noisy, variance = _scene(rng)
    guide = clean * 1.1
    got = project(transform, noisy, variance, guide, offset=0.05, radius=2.0, exponent=exponent,
                  scale_band=scale_band).image
    assert_allclose(got, _by_hand(transform, noisy, variance, guide, k=0.05, radius=2.0, exponent=exponent,
                                  scale_band=scale_band), rtol=1e-10, atol=1e-12)


def test_float32_matches_the_float64_reference(rng):
    clean, noisy, variance = _scene(rng)
    ref = project(StationaryTransform(SHAPE, levels=3), noisy, variance, clean, offset=0.05).image
    single = project(StationaryTransform(SHAPE, levels=3, dtype="float32"), noisy, variance, clean, offset=0.05).image
    assert_allclose(single, ref, rtol=FLOAT32_RTOL, atol=FLOAT32_RTOL)


def test_no_variance_or_no_radius_returns_the_means_exactly(rng, transform):
    clean, noisy, variance = _scene(rng)
    np.testing.assert_array_equal(project(transform, noisy, np.zeros_like(noisy), clean, offset=0.1).image, noisy)
    np.testing.assert_array_equal(project(transform, noisy, variance, clean, offset=0.1, radius=0.0).image, noisy)


def test_a_clean_guide_removes_the_detail_noise_and_a_distant_one_is_not_followed(rng, transform):
    clean, noisy, variance = _scene(rng)
    rms = lambda a: float(np.sqrt(np.mean((a - clean) ** 2)))  # noqa: E731
    followed = project(transform, noisy, variance, clean, offset=0.1).image
    assert rms(followed) < rms(project(transform, noisy, variance, clean, offset=0.1, scale_band=False).image)
    assert rms(followed) < rms(noisy) / 3
    # with the scale band kept only detail coefficients move: a guide offset by a constant changes
    # none, and in the linear domain (exponent 0) every channel's sum is the means' (zero-sum kernels)
    linear = project(transform, noisy, variance, clean, offset=0.1, exponent=0.0, scale_band=False).image
    shifted = project(transform, noisy, variance, clean + 5.0, offset=0.1, exponent=0.0, scale_band=False).image
    assert_allclose(shifted, linear, rtol=1e-10, atol=1e-12)
    assert_allclose(shifted.sum(axis=(0, 1)), noisy.sum(axis=(0, 1)), rtol=1e-12)
    # every coefficient moves by at most radius standard errors: far from a wrong guide
    wrong = np.where(np.arange(SHAPE[1])[None, :, None] % 8 < 4, 3.0, -1.0) * np.ones_like(clean)
    moved = project(transform, noisy, variance, wrong, offset=0.1).image
    distance = lambda a: float(np.sqrt(np.mean((a - noisy) ** 2)))  # noqa: E731
    assert distance(moved) < distance(wrong) / 4


def test_the_scale_band_moves_by_at_most_radius_standard_errors(rng, transform):
    """A guide offset by a constant far beyond the noise: the scale band moves by exactly r Delta of
    each scale coefficient (every one clipped), so the image mean moves by about that and no more."""
    clean, noisy, variance = _scene(rng)
    kept = project(transform, noisy, variance, clean + 5.0, offset=0.1, exponent=0.0, scale_band=False).image
    moved = project(transform, noisy, variance, clean + 5.0, offset=0.1, exponent=0.0, radius=3.0).image
    scale_sd = max(float(np.sqrt(transform.variance(variance[..., c])[0]).max()) for c in range(variance.shape[2]))
    shift = float(np.mean(moved - kept))
    assert 0 < shift <= 3.0 * scale_sd * (1 + 1e-9)
    assert shift < 5.0 / 10  # a small part of the guide's offset of 5: the samples contradict it
    # no variance: nothing moves, the scale band included
    np.testing.assert_array_equal(project(transform, noisy, np.zeros_like(noisy), clean + 5.0, offset=0.1).image,
                                  noisy)


def test_scale_band_must_be_a_flag(rng, transform):
    clean, noisy, variance = _scene(rng)
    with pytest.raises(TypeError, match="scale_band"):
        project(transform, noisy, variance, clean, offset=0.1, scale_band="yes")


@pytest.mark.parametrize("scale_band", [True, False])
def test_probes_and_the_leverage_are_those_of_the_map_with_the_clipping_held(rng, transform, scale_band):
    """The map is affine in the means once the clipping pattern is fixed: a tiny perturbation keeps
    the pattern, so finite differences give the probes' result and the diagonal."""
    clean, noisy, variance = _scene(rng, channels=2)
    guide = clean + 0.05
    options = {"offset": 0.1, "scale_band": scale_band}
    base = project(transform, noisy, variance, guide, leverage=True, **options)
    eps = 1e-7
    e = rng.standard_normal((2,) + noisy.shape)
    probed = project(transform, noisy, variance, guide, extra=e, **options).extra
    for n in range(2):
        moved = project(transform, noisy + eps * e[n], variance, guide, **options).image
        assert_allclose((moved - base.image) / eps, probed[n], rtol=1e-4, atol=1e-4)
    for pixel in ((5, 7, 1), (0, 0, 0), (12, 20, 1)):
        bump = np.zeros_like(noisy)
        bump[pixel] = eps
        moved = project(transform, noisy + bump, variance, guide, **options).image
        assert_allclose((moved[pixel] - base.image[pixel]) / eps, base.leverage[pixel], rtol=1e-4, atol=1e-4)
    # A diagonal of filters with negative taps: it may dip a hair below 0 where every band follows the guide.
    assert -1e-3 <= base.leverage.min() and base.leverage.max() <= 1.0 + 1e-12


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"offset": 0.0}, r"offset"),
    ({"offset": 0.1, "radius": -1.0}, r"radius"),
    ({"offset": 0.1, "exponent": 2.0}, r"exponent"),
])
def test_bad_parameters_are_refused(rng, transform, kwargs, message):
    clean, noisy, variance = _scene(rng)
    with pytest.raises(ValueError, match=message):
        project(transform, noisy, variance, clean, **kwargs)


def test_shapes_must_agree(rng, transform):
    clean, noisy, variance = _scene(rng)
    with pytest.raises(ValueError, match=r"x, variance, guide"):
        project(transform, noisy, variance[..., :1], clean, offset=0.1)
