"""Empirical Wiener stages: factors, linearity in the means, shared factors, precision."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy import ndimage

from awr_denoise import wiener
from awr_denoise.stationary import StationaryTransform
from awr_denoise.wiener import relative_wiener, stage_weights, wiener_filter

SHAPE = (24, 28)
FLOAT32_RTOL = 2e-6  # as in test_stationary.py: single-precision FFTs a few dozen operations deep


@pytest.fixture
def transform():
    return StationaryTransform(SHAPE, levels=3)


def _scene(rng, channels=3):
    clean = 1.0 + np.sin(np.arange(SHAPE[1]) / 3.0)[None, :, None] * np.ones(SHAPE + (channels,))
    variance = rng.uniform(0.01, 0.05, clean.shape)
    return clean, clean + np.sqrt(variance) * rng.standard_normal(clean.shape), variance


def test_zero_variance_keeps_the_image(rng, transform):
    clean, noisy, _ = _scene(rng)
    assert_allclose(wiener_filter(transform, noisy, np.zeros_like(noisy), clean).image, noisy, rtol=1e-12, atol=1e-13)


def test_a_zero_pilot_keeps_only_the_scale_band(rng, transform):
    _, noisy, variance = _scene(rng)
    coeffs = transform.forward(noisy)
    coarse = transform.inverse([coeffs[0]] + [(0.0, 0.0, 0.0)] * transform.levels)
    assert_allclose(wiener_filter(transform, noisy, variance, np.zeros_like(noisy)).image, coarse, atol=1e-12)


def test_factors_are_those_of_the_formula(rng):
    """One level, Haar: every detail coefficient times P^2 / (P^2 + Delta^2), by hand."""
    t = StationaryTransform(SHAPE, wavelet="haar", levels=1)
    _, noisy, variance = _scene(rng, channels=1)
    pilot = noisy + 0.1 * rng.standard_normal(noisy.shape)
    x, p, v = t.forward(noisy), t.forward(pilot), t.variance(variance)
    shrunk = [x[0], tuple(xb * pb**2 / (pb**2 + vb) for xb, pb, vb in zip(x[1], p[1], v[1]))]
    assert_allclose(wiener_filter(t, noisy, variance, pilot).image, t.inverse(shrunk), rtol=1e-12)


def test_the_stage_is_linear_in_the_means_for_a_fixed_pilot(rng, transform):
    clean, noisy, variance = _scene(rng)
    a, b = noisy, rng.standard_normal(noisy.shape)
    stage = lambda x: relative_wiener(transform, x, variance, clean, k=0.1, exponent=1.0).image  # noqa: E731
    assert_allclose(stage(2.0 * a - 3.0 * b), 2.0 * stage(a) - 3.0 * stage(b), atol=1e-12)


def test_extra_planes_are_filtered_with_the_same_factors(rng, transform):
    clean, noisy, variance = _scene(rng)
    extra = rng.standard_normal((2,) + noisy.shape)
    result = relative_wiener(transform, noisy, variance, clean, k=0.1, exponent=0.5, extra=extra)
    alone = relative_wiener(transform, noisy, variance, clean, k=0.1, exponent=0.5)
    assert_allclose(result.image, alone.image, rtol=1e-12)
    assert alone.extra is None and alone.leverage is None
    for e, f in zip(extra, result.extra):
        assert_allclose(f, relative_wiener(transform, e, variance, clean, k=0.1, exponent=0.5).image, atol=1e-12)


@pytest.mark.parametrize("shared", [False, True])
def test_leverage_is_the_diagonal_of_the_stage(rng, shared):
    """Each pixel's weight on its own value, against the map applied to every unit impulse."""
    shape = (10, 12)
    t = StationaryTransform(shape, levels=2)
    clean, noisy, variance = (a[:10, :12] for a in _scene(rng, channels=2))
    v, p = (variance[..., 0], clean[..., 0]) if shared else (variance, clean)
    got = relative_wiener(t, noisy, v, p, k=0.1, exponent=0.5, leverage=True).leverage
    impulses = np.zeros((shape[0] * shape[1],) + shape + (2,))
    impulses.reshape(shape[0] * shape[1], -1, 2)[np.arange(shape[0] * shape[1]), np.arange(shape[0] * shape[1])] = 1.0
    mapped = relative_wiener(t, noisy, v, p, k=0.1, exponent=0.5, extra=impulses).extra
    diagonal = mapped.reshape(shape[0] * shape[1], -1, 2)[np.arange(shape[0] * shape[1]), np.arange(shape[0] * shape[1])]
    assert_allclose(got, diagonal.reshape(shape + (2,))[..., 0] if shared else diagonal.reshape(shape + (2,)),
                    atol=1e-12)


def test_zero_variance_leaves_every_pixel_its_own_value(rng, transform):
    clean, noisy, _ = _scene(rng)
    lev = wiener_filter(transform, noisy, np.zeros_like(noisy), clean, leverage=True).leverage
    assert_allclose(lev, 1.0, atol=1e-12)


def test_the_linear_stage_keeps_the_image_sum(rng, transform):
    clean, noisy, variance = _scene(rng)
    out = relative_wiener(transform, noisy, variance, clean, k=0.1, exponent=0.0).image
    assert_allclose(out.sum(axis=(0, 1)), noisy.sum(axis=(0, 1)), rtol=1e-12)


def test_one_plane_of_pilot_and_variance_shares_the_factors(rng, transform):
    """Channels proportional to each other stay proportional (one set of factors for all)."""
    clean, noisy, variance = _scene(rng, channels=1)
    x = noisy * np.array([1.0, 0.5, 2.0])
    out = relative_wiener(transform, x, variance[..., 0], clean[..., 0], k=0.1, exponent=1.0).image
    assert_allclose(out[..., 1], 0.5 * out[..., 0], rtol=1e-10)
    assert_allclose(out[..., 2], 2.0 * out[..., 0], rtol=1e-10)


def test_the_relative_stage_removes_noise(rng, transform):
    clean, noisy, variance = _scene(rng)
    out = relative_wiener(transform, noisy, variance, clean, k=0.1, exponent=1.0).image
    assert np.mean((out - clean) ** 2) < np.mean((noisy - clean) ** 2) / 4


def test_float32_matches_the_float64_reference(rng):
    clean, noisy, variance = _scene(rng)
    ref = relative_wiener(StationaryTransform(SHAPE, levels=3), noisy, variance, clean, k=0.1, exponent=0.5).image
    single = relative_wiener(StationaryTransform(SHAPE, levels=3, dtype="float32"), noisy, variance, clean, k=0.1,
                             exponent=0.5).image
    assert_allclose(single, ref, atol=FLOAT32_RTOL * np.abs(ref).max())


def test_stage_weights():
    p = np.array([-2.0, 0.0, 3.0])
    assert_allclose(stage_weights(p, 1.0, 1.0), [3.0, 1.0, 4.0])
    assert_allclose(stage_weights(p, 1.0, 0.0), 1.0)
    assert_allclose(stage_weights(p, 1.0, 0.25), [3.0**0.25, 1.0, 4.0**0.25])
    with pytest.raises(ValueError, match="k"):
        stage_weights(p, 0.0, 1.0)
    with pytest.raises(ValueError, match="exponent"):
        stage_weights(p, 1.0, 1.5)


def test_shapes_that_do_not_fit_are_refused(rng, transform):
    clean, noisy, variance = _scene(rng)
    with pytest.raises(ValueError, match="variance, pilot"):
        wiener_filter(transform, noisy, variance[..., :2], clean[..., :2])
    with pytest.raises(ValueError, match="variance, pilot"):
        wiener_filter(transform, noisy, variance, clean[..., 0])


def test_the_default_float32_stage_matches_the_float64_scipy_reference(rng):
    """The fast path (float32, ducc0) against the float64 scipy.fft reference, with leverage and probes."""
    clean, noisy, variance = _scene(rng)
    extra = rng.standard_normal((2,) + noisy.shape) * np.sqrt(variance)
    ref = relative_wiener(StationaryTransform(SHAPE, levels=3, backend="scipy"), noisy, variance, clean, k=0.1,
                          exponent=0.75, extra=extra, leverage=True)
    fast = relative_wiener(StationaryTransform(SHAPE, levels=3, dtype="float32"), noisy, variance, clean, k=0.1,
                           exponent=0.75, extra=extra, leverage=True)
    assert_allclose(fast.image, ref.image, rtol=0, atol=FLOAT32_RTOL * np.abs(ref.image).max())
    assert_allclose(fast.extra, ref.extra, rtol=0, atol=FLOAT32_RTOL * np.abs(ref.extra).max())
    assert_allclose(fast.leverage, ref.leverage, rtol=0, atol=FLOAT32_RTOL)


@pytest.mark.parametrize("channels", [1, 3])
def test_a_stage_leaves_its_inputs_alone(rng, channels):
    clean, noisy, variance = _scene(rng, channels)
    copies = [a.copy() for a in (clean, noisy, variance)]
    for dtype in ("float32", "float64"):
        relative_wiener(StationaryTransform(SHAPE, levels=2, dtype=dtype), noisy, variance, clean, k=0.1,
                        exponent=1.0, extra=noisy[None], leverage=True)
    for a, b in zip((clean, noisy, variance), copies):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("shared", [False, True])
def test_bands_on_threads_give_the_same_bits(rng, monkeypatch, shared):
    """With an executor the bands run two at a time on its threads and are summed in band order:
    image, probes and leverage the same bit for bit (the size threshold lowered so that this small
    image takes the threaded path; an odd band count leaves the last pair short)."""
    monkeypatch.setattr(wiener, "_PARALLEL_PIXELS", 1)
    t = StationaryTransform((40, 36), levels=3, dtype="float32")  # 9 detail bands
    x = rng.lognormal(0, 1, (40, 36, 3))
    v = rng.random((40, 36, 1 if shared else 3)) * 0.1
    pilot = x[..., :1] if shared else x
    extra = rng.standard_normal((2, 40, 36, 3))
    serial = relative_wiener(t, x, v, pilot, k=0.1, exponent=0.5, extra=extra, leverage=True)
    calls = []
    with ThreadPoolExecutor(2) as pool:
        def run(f, items):
            calls.append([band for band, _ in items])
            return list(pool.map(f, items))
        threaded = relative_wiener(t, x, v, pilot, k=0.1, exponent=0.5, extra=extra, leverage=True, run=run)
    assert calls == [[1, 2], [3, 4], [5, 6], [7, 8], [9]]
    for a, b in zip(serial, threaded):
        assert_array_equal(a.view(np.int64), b.view(np.int64))


def test_small_images_keep_their_bands_serial(rng):
    """Below 512x512 threads measured slower: ``run`` is not called."""
    t = StationaryTransform((32, 32), levels=2)
    x = rng.random((32, 32, 1))

    def run(f, items):
        raise AssertionError("run called")
    out = relative_wiener(t, x, x * 0.01, x, k=0.1, exponent=0.5, run=run)
    assert_array_equal(out.image, relative_wiener(t, x, x * 0.01, x, k=0.1, exponent=0.5).image)


# ---------------------------------------------------------------------------- the energy floor
def test_the_floor_is_the_local_evidence_formula(rng):
    """Two levels, bior4.4, exponent 0 (the linear domain): every detail coefficient times
    Q^2 / (Q^2 + Delta^2), Q^2 = max(P^2, box5(X^2 - 2 Delta^2)) on the periodic canvas, by hand."""
    t = StationaryTransform(SHAPE, levels=2)
    clean, noisy, variance = _scene(rng, channels=1)
    pilot = 0.5 * clean  # a pilot short of the signal, as a thresholded one is
    x, p, v = t.forward(noisy), t.forward(pilot), t.variance(variance)
    bands = []
    for level in range(1, 3):
        level_bands = []
        for xb, pb, vb in zip(x[level], p[level], v[level]):
            evidence = ndimage.uniform_filter(xb * xb - 2.0 * vb, 5, mode="wrap")
            q = np.maximum(pb * pb, evidence)
            level_bands.append(xb * q / (q + vb))
        bands.append(tuple(level_bands))
    want = t.inverse([x[0]] + bands)
    got = relative_wiener(t, noisy, variance, pilot, k=0.1, exponent=0.0, floor=(5, 2.0)).image
    assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    # The floor only ever raises a factor: without it the short pilot shrinks more.
    plain = relative_wiener(t, noisy, variance, pilot, k=0.1, exponent=0.0).image
    assert np.abs(got - noisy).mean() < np.abs(plain - noisy).mean()


def test_the_floor_needs_each_channels_own_factors(rng, transform):
    x = rng.random(SHAPE + (3,))
    with pytest.raises(ValueError, match="floor: needs one pilot and variance plane per channel"):
        relative_wiener(transform, x, x[..., 0] * 0.01, x[..., 0], k=0.1, exponent=0.5, floor=(5, 2.0))


def test_the_floor_on_threads_gives_the_same_bits(rng, monkeypatch):
    monkeypatch.setattr(wiener, "_PARALLEL_PIXELS", 1)
    t = StationaryTransform((40, 36), levels=3, dtype="float32")
    x = rng.lognormal(0, 1, (40, 36, 3))
    v = rng.random(x.shape) * 0.1
    serial = relative_wiener(t, x, v, 0.5 * x, k=0.1, exponent=0.5, leverage=True, floor=(5, 2.0))
    with ThreadPoolExecutor(2) as pool:
        threaded = relative_wiener(t, x, v, 0.5 * x, k=0.1, exponent=0.5, leverage=True, floor=(5, 2.0),
                                   run=lambda f, items: list(pool.map(f, items)))
    assert serial.extra is None and threaded.extra is None
    for a, b in ((serial.image, threaded.image), (serial.leverage, threaded.leverage)):
        assert_array_equal(a.view(np.int64), b.view(np.int64))


@pytest.mark.parametrize("exponents", [(0.75, 0.4), (0.75, 0.5, 0.4), (0.4,)])
def test_the_chain_floors_its_first_stage_only_and_only_when_stages_follow(rng, monkeypatch, exponents):
    calls = []
    original = wiener.relative_wiener

    def spy(*args, **kwargs):
        calls.append(kwargs.get("floor"))
        return original(*args, **kwargs)

    monkeypatch.setattr(wiener, "relative_wiener", spy)
    x = rng.random(SHAPE + (2,)) + 0.5
    wiener.chain(StationaryTransform(SHAPE, levels=2), x, x * 0.01, x, exponents, k=0.1, leverage=True,
                 probes=2, floor=(5, 2.0))
    floored = (5, 2.0) if len(exponents) > 1 else None
    assert calls == [floored] + [None] * (len(exponents) - 2 + 1 + 1)  # later stages, then the probes' call


def test_the_floor_beyond_single_precision_falls_back_to_no_floor(rng):
    """A band whose square overflows float32 gives no evidence: no NaN or Inf comes out (without
    the guard in ``_band`` the floored result holds NaN)."""
    t = StationaryTransform((32, 32), levels=2, dtype="float32")
    x = rng.random((32, 32, 1)) + 1.0
    x[10, 10] = 1e20  # its band coefficients square beyond float32
    pilot = np.zeros_like(x)
    with np.errstate(over="ignore", invalid="ignore"):
        plain = relative_wiener(t, x, x * 0.01, pilot, k=0.1, exponent=0.0).image
        floored = relative_wiener(t, x, x * 0.01, pilot, k=0.1, exponent=0.0, floor=(5, 2.0)).image
    assert np.isfinite(plain).all() and np.isfinite(floored).all()


@pytest.mark.parametrize("floor, message", [((0, 2.0), "floor window"), ((5, -1.0), "floor margin"),
                                            ((5,), "floor: expected"), ((5, float("nan")), "floor margin")])
def test_bad_floors_are_refused(rng, transform, floor, message):
    x = rng.random(SHAPE + (1,))
    with pytest.raises(ValueError, match=message):
        relative_wiener(transform, x, x * 0.01, x, k=0.1, exponent=0.5, floor=floor)


def _texture(rng, shape=(8, 10)):
    """Every pixel its own value (10^U(-1, 1)) with noise of one variance: where the stages follow the means most.

    One variance keeps each probe's noise on a pixel (the rest of the Jacobian's row, each neighbour's move
    over the pixel's own) the same everywhere, so one tolerance fits every pixel."""
    truth = 10.0 ** rng.uniform(-1, 1, shape + (1,))
    variance = np.full(truth.shape, 0.1)
    return truth + np.sqrt(variance) * rng.standard_normal(truth.shape), variance


def test_the_divergence_of_one_stage_on_a_fixed_pilot_is_its_diagonal(rng):
    """One stage on a pilot from outside is linear in the means: its probed divergence tends to its diagonal
    (each probe adds the rest of the Jacobian's row times random signs, which averages out)."""
    x, v = _texture(rng)
    t = StationaryTransform(x.shape[:2], levels=2)
    pilot = ndimage.uniform_filter(x, (3, 3, 1))
    one = wiener.chain(t, x, v, pilot, (0.4,), k=0.1, leverage=True, divergence_probes=400)
    assert_allclose(one.divergence, one.leverage, atol=0.08)
    assert abs(one.divergence.mean() - one.leverage.mean()) < 0.01
    assert wiener.chain(t, x, v, pilot, (0.4,), k=0.1, leverage=True).divergence is None


def test_the_divergence_counts_the_pilot_the_first_stage_makes(rng):
    """Two stages: the second's pilot is the first's result, made from the same means, so the chain follows a
    pixel's own mean more than the last stage's diagonal says. The probes match the Jacobian's diagonal taken
    one pixel at a time (each mean moved alone by the same step), not the diagonal."""
    x, v = _texture(rng)
    t = StationaryTransform(x.shape[:2], levels=2)
    pilot = ndimage.uniform_filter(x, (3, 3, 1))
    done = wiener.chain(t, x, v, pilot, (0.75, 0.4), k=0.1, leverage=True, divergence_probes=400)
    step = wiener.DIVERGENCE_STEP * np.sqrt(v)
    alone = np.zeros_like(x)
    for i, j in np.ndindex(x.shape[:2]):
        moved = x.copy()
        moved[i, j] += step[i, j]
        alone[i, j] = (wiener.chain(t, moved, v, pilot, (0.75, 0.4), k=0.1).image[i, j] - done.image[i, j]) / step[i, j]
    assert alone.mean() > 1.2 * done.leverage.mean()  # what the guard missed before it could probe
    assert_allclose(done.divergence, alone, atol=0.08)
    assert abs(done.divergence.mean() - alone.mean()) < 0.01


def test_pixels_without_variance_are_not_probed(rng):
    """A pixel whose mean is exact is not moved by a probe and has no divergence to report (the guard's gain
    ``v (1 - D)`` is 0 there whatever it is)."""
    x, v = _texture(rng)
    v[2:4, 3:6] = 0.0
    t = StationaryTransform(x.shape[:2], levels=2)
    done = wiener.chain(t, x, v, x, (0.75, 0.4), k=0.1, divergence_probes=3)
    assert_array_equal(done.divergence[2:4, 3:6], 0.0)
    assert np.all(np.isfinite(done.divergence)) and np.any(done.divergence != 0)


def test_a_float32_energy_floor_near_the_top_of_its_range_is_float64s(rng):
    """Band energies near float32's top: summed before the division, the window's sum overflowed to Inf and the
    floor was dropped there (0.31 of the largest value off float64's; the review of the window sums)."""
    x = np.zeros((32, 32))
    x[8:24, 8:24] = 1e19
    x += rng.standard_normal(x.shape) * 1e17
    out = {}
    for dtype in ("float32", "float64"):
        t = StationaryTransform((32, 32), levels=2, dtype=dtype)
        out[dtype] = relative_wiener(t, x, np.full(x.shape, 1e34), np.zeros_like(x), k=1.0, exponent=0.0,
                                     floor=(5, 2.0)).image
    assert np.abs(out["float32"] - out["float64"]).max() < 0.05 * np.abs(out["float64"]).max()
