"""The measured noise gain and when it is measured again (awr_denoise/noise_gain.py)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from awr_denoise import AdaptiveSampler, SampleBuffer, noise_gain
from awr_denoise.noise_gain import DEFAULT_GAIN_REFRESH, DEFAULT_NOISE_MODEL, NOISE_MODELS, MeasuredGain, shrinkage_gain
from awr_denoise.reconstruct import DEFAULT_C_S, reconstruct_detailed
from awr_denoise.wavelets import coefficient_variance, forward, inverse, shrinkage_diagonal, wavelet_operators
from awr_denoise.synthetic import SyntheticRenderer, make_scene


def _buffer(spp: int, shape: tuple[int, int] = (24, 24), seed: int = 0) -> SampleBuffer:
    rng = np.random.default_rng(seed)
    return SampleBuffer.from_moments(np.full(shape, spp), 0.5 + rng.random(shape + (3,)), np.full(shape + (3,), 0.2))


def test_the_gain_is_the_default_reconstructions():
    buffer = _buffer(4)
    expected = reconstruct_detailed(buffer, variance_probes=0, pixel_clamp=None, preserve_mean=False,
                                    nonnegative=False).noise_gain
    assert_array_equal(MeasuredGain()(buffer), expected)
    # The finishing steps do not change it: the default reconstruction reports the same gain.
    assert_array_equal(reconstruct_detailed(buffer, variance_probes=0).noise_gain, expected)


@pytest.mark.parametrize(("refresh", "spps", "measured"), [
    (1.0, [4, 4, 5, 6, 8], 5),       # every call
    (1.5, [4, 5, 6, 7, 9, 12], 3),   # at 4, 6 (1.5x), 9 (1.5x of 6)
    (2.0, [4, 5, 6, 7, 8, 15, 16], 3),
])
def test_the_gain_is_measured_again_once_the_samples_grow_by_refresh(refresh, spps, measured):
    gain = MeasuredGain(refresh)
    for spp in spps:
        gain(_buffer(spp))
    assert gain.measurements == measured


def test_another_image_or_fewer_samples_are_measured_anew():
    gain = MeasuredGain(1.5)
    first = gain(_buffer(8))
    assert gain(_buffer(8, shape=(24, 16))).shape == (24, 16)       # another shape
    assert gain(_buffer(4)) is not first and gain.measurements == 3   # fewer samples: another buffer


@pytest.mark.parametrize("bad", [0.5, 0.0, -1.0, float("nan"), float("inf"), "2", None])
def test_a_refresh_below_one_or_not_a_number_is_refused(bad):
    with pytest.raises((ValueError, TypeError), match="gain_refresh"):
        MeasuredGain(bad)


def test_the_sampler_takes_gain_refresh_only_with_the_measured_gain():
    with pytest.raises(ValueError, match="gain_refresh: 2.0 needs noise_model='reconstruction', not 'shrinkage'"):
        AdaptiveSampler((16, 16), gain_refresh=2.0)
    with pytest.raises(ValueError, match="gain_refresh"):
        AdaptiveSampler((16, 16), noise_model="reconstruction", gain_refresh=0.9)


@pytest.mark.parametrize(("refresh", "expected"), [(None, 12), (1.0, 12), (1.5, 7), (2.0, 4)])
def test_a_sampler_reconstructs_once_per_measurement(monkeypatch, refresh, expected):
    """To 32 spp from 2 at the default round growth (a quarter of the samples so far, at least 1 spp):
    twelve adaptive rounds, each measured by default; a refresh of 1.5 measures about every other one."""
    calls = []
    real = noise_gain.reconstruct_detailed

    def counted(*args, **kwargs):
        calls.append(args[0].total_samples)
        return real(*args, **kwargs)

    monkeypatch.setattr(noise_gain, "reconstruct_detailed", counted)
    scene = make_scene("edges", (32, 32))
    options = {} if refresh is None else {"gain_refresh": refresh}
    sampler = AdaptiveSampler(scene.shape, noise_model="reconstruction", **options)
    sampler.run(SyntheticRenderer(scene), total_spp=32)
    assert len(calls) == expected, calls
    assert DEFAULT_GAIN_REFRESH == 1.0


@pytest.mark.parametrize("refresh", [None, 1.0])
def test_refresh_one_gives_the_requests_of_a_gain_measured_every_round(refresh):
    """gain_refresh=1, the default, is the measurement of every round: each round's density from a
    fresh reconstruction, as a sampler made anew from the buffer gives."""
    scene = make_scene("edges", (32, 32))
    renderer = SyntheticRenderer(scene)
    options = {} if refresh is None else {"gain_refresh": refresh}
    sampler = AdaptiveSampler(scene.shape, noise_model="reconstruction", **options)
    sampler.tell(sampler.ask(), renderer(sampler.ask()))
    for _ in range(3):
        fresh = AdaptiveSampler.from_buffer(sampler.buffer, round=sampler.round, issued=sampler.issued,
                                            noise_model="reconstruction")
        request = sampler.ask()
        assert_array_equal(request.counts, fresh.ask().counts)
        sampler.tell(request, renderer(request))


# ---------------------------------------------------------------------------- the shrinkage's gain
def _wiener_of_soft(w, var, c_s):
    """The factor written out: P^2 / (P^2 + Delta^2), P = max(|w| - c_s Delta, 0); 1 where both are 0."""
    p = np.maximum(np.abs(w) - c_s * np.sqrt(var), 0.0)
    total = p**2 + var
    return np.divide(p**2, total, out=np.ones_like(total), where=total > 0)


def test_the_shrinkage_gain_is_the_diagonal_of_the_wiener_map_on_the_soft_pilot(rng):
    """Against the map built from impulses: each pixel's own weight through forward, the factors, inverse."""
    shape = (12, 14)
    mean = rng.random(shape) + np.where(np.arange(14) < 7, 0.0, 2.0)
    var = rng.uniform(0.0, 0.05, shape)
    ops = wavelet_operators(shape)
    coeffs, variances = forward(mean, levels=ops.levels), coefficient_variance(var, operators=ops)
    factors = [np.ones_like(coeffs[0])] + [tuple(_wiener_of_soft(w, v, DEFAULT_C_S) for w, v in zip(c, d))
                                           for c, d in zip(coeffs[1:], variances[1:])]
    impulses = np.eye(shape[0] * shape[1]).reshape(shape + (-1,))
    through = forward(impulses, levels=ops.levels)
    scaled = [through[0]] + [tuple(b * f[..., None] for b, f in zip(bands, fs)) for bands, fs in zip(through[1:], factors[1:])]
    dense = np.diagonal(inverse(scaled, shape).reshape(impulses.shape[2], -1)).reshape(shape)
    got = shrinkage_gain(coeffs, variances, ops)
    assert got.dtype == np.float64
    assert_allclose(got, np.maximum(dense, 0.0), rtol=0, atol=1e-6)  # computed in float32
    # A larger pilot threshold shrinks more: less of the noise stays on average (not at every
    # pixel: a pixel's weight on itself through a band can be negative).
    assert shrinkage_gain(coeffs, variances, ops, c_s=3.0).mean() < got.mean()


def test_exact_coefficients_are_kept_and_pure_noise_is_averaged(rng):
    shape = (32, 32)
    ops = wavelet_operators(shape)
    # No noise at all: every factor is 1 (0 / 0 is an exact coefficient, kept), the identity.
    flat = forward(np.ones(shape), levels=ops.levels)
    assert_allclose(shrinkage_gain(flat, coefficient_variance(np.zeros(shape), operators=ops), ops), 1.0, atol=1e-6)
    # A flat image under noise: its detail coefficients are 0, so every factor is 0 and the scale
    # band alone keeps a small share of each pixel (more at the corners, where the symmetric
    # extension reflects a pixel onto itself).
    gain = shrinkage_gain(flat, coefficient_variance(np.full(shape, 0.1), operators=ops), ops)
    scale_only = [np.ones_like(flat[0])] + [tuple(np.zeros_like(b) for b in bands) for bands in flat[1:]]
    assert_allclose(gain, shrinkage_diagonal(scale_only, ops), atol=1e-6)
    assert gain[8:-8, 8:-8].max() < 0.2 and gain.min() >= 0.0


def test_the_default_noise_model_is_the_shrinkage():
    assert DEFAULT_NOISE_MODEL == "shrinkage" and DEFAULT_NOISE_MODEL in NOISE_MODELS
    assert AdaptiveSampler((16, 16)).noise_model == "shrinkage"


@pytest.mark.parametrize("bad", [-1.0, float("nan"), "1"])
def test_a_bad_pilot_threshold_is_refused(bad):
    coeffs = forward(np.zeros((8, 8)), levels=1)
    with pytest.raises((ValueError, TypeError), match="c_s"):
        shrinkage_gain(coeffs, coeffs, wavelet_operators((8, 8), levels=1), c_s=bad)


def test_the_wiener_factor_matches_its_formula(rng):
    from awr_denoise.noise_gain import _wiener_factor

    w, var = rng.standard_normal(1000) * 3, rng.uniform(0, 2, 1000)
    for dtype in (np.float32, np.float64):  # the variances come in either precision
        got = _wiener_factor(w, var.astype(dtype), DEFAULT_C_S)
        assert got.dtype == np.float32
        assert_allclose(got, _wiener_of_soft(w, var.astype(dtype), DEFAULT_C_S), rtol=1e-6, atol=1e-7)
    # Exact coefficients (0 / 0) are kept, pure noise dropped, huge coefficients kept, silently.
    with np.errstate(all="raise"):
        edge = _wiener_factor(np.array([0.0, 0.0, 1e30, 1e150]), np.array([0.0, 1.0, 1.0, 1e150]), 1.0)
    assert_allclose(edge, [1.0, 0.0, 1.0, 1.0])


def test_the_sampler_takes_level_weight_only_with_the_level_model():
    """A setting that would do nothing is refused, not ignored: the level weight acts in the level term alone."""
    for model in ("shrinkage", "reconstruction"):
        with pytest.raises(ValueError, match=f"level_weight: 0.5 needs noise_model='levels', not '{model}'"):
            AdaptiveSampler((16, 16), level_weight=0.5, noise_model=model)
    assert AdaptiveSampler((16, 16), noise_model="levels").level_weight == 0.25
    assert AdaptiveSampler((16, 16), level_weight=1.0, noise_model="levels").level_weight == 1.0
