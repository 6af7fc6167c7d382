"""The undecimated transform: perfect reconstruction, PyWavelets' swt2, exact variances, precision."""

from __future__ import annotations

import numpy as np
import pytest
import pywt
from numpy.testing import assert_allclose
from scipy import stats

from awr_denoise import stationary
from awr_denoise.stationary import (BACKENDS, StationaryTransform, _plane_indices, check_fft_environment,
                                    stationary_transform)

MC_DRAWS = 3000
MC_FAMILY_ALPHA = 1e-3
# float32 FFTs: about 1e-7 relative rounding per operation, a few dozen operations deep.
FLOAT32_RTOL = 2e-6

CASES = [((24, 20), "bior4.4", 2), ((23, 29), "bior4.4", 3), ((16, 16), "haar", 4), ((31, 17), "db2", 2),
         ((1, 16), "haar", 1), ((40, 36), "dmey", 2)]  # dmey: 0.6% off a pure phase, refused before


def _flat(coeffs) -> list[np.ndarray]:
    return [coeffs[0]] + [band for level in coeffs[1:] for band in level]


@pytest.mark.parametrize(("shape", "wavelet", "levels"), CASES)
@pytest.mark.parametrize("channels", [None, 3])
def test_inverse_undoes_forward(rng, shape, wavelet, levels, channels):
    image = rng.standard_normal(shape if channels is None else shape + (channels,))
    t = StationaryTransform(shape, wavelet=wavelet, levels=levels)
    coeffs = t.forward(image)
    assert len(coeffs) == levels + 1 and all(b.shape == image.shape for b in _flat(coeffs))
    assert_allclose(t.inverse(coeffs), image, rtol=1e-12, atol=1e-12)


# dmey's high-pass filter sums to 1e-3, not 0: its detail bands carry a little of the sum (the mean's restoration
# keeps the image's).
@pytest.mark.parametrize(("shape", "wavelet", "levels"), [case for case in CASES if case[1] != "dmey"])
def test_detail_bands_carry_none_of_the_image_sum(rng, shape, wavelet, levels):
    image = rng.random(shape)
    t = StationaryTransform(shape, wavelet=wavelet, levels=levels)
    coeffs = t.forward(image)
    coarse_only = t.inverse([coeffs[0]] + [(0.0, 0.0, 0.0)] * levels)
    assert coarse_only.sum() == pytest.approx(image.sum(), rel=1e-12)
    for band in _flat(coeffs)[1:]:
        assert abs(band.sum()) < 1e-10 * np.abs(image).sum()


@pytest.mark.parametrize("wavelet", ["bior4.4", "haar", "db2", "sym4"])
def test_bands_are_pywavelets_swt2_up_to_a_circular_shift(rng, wavelet):
    shape, levels = (32, 48), 3
    image = rng.random(shape)
    ours = _flat(StationaryTransform(shape, wavelet=wavelet, levels=levels).forward(image))
    theirs = _flat(pywt.swt2(image, wavelet, level=levels, trim_approx=True, norm=False))
    for a, b in zip(ours, theirs):
        # The shift that best aligns the two: the peak of their circular cross-correlation.
        corr = np.fft.ifft2(np.fft.fft2(b) * np.conj(np.fft.fft2(a))).real
        shift = np.unravel_index(np.argmax(corr), shape)
        assert_allclose(np.roll(a, shift, axis=(0, 1)), b, atol=1e-12)


def _z_bounds(n_coefficients: int) -> tuple[float, float]:
    """Acceptance interval of (empirical second moment / predicted variance), as in test_wavelets.py."""
    alpha = MC_FAMILY_ALPHA / n_coefficients
    return stats.chi2.ppf(alpha / 2, MC_DRAWS) / MC_DRAWS, stats.chi2.isf(alpha / 2, MC_DRAWS) / MC_DRAWS


@pytest.mark.parametrize(("shape", "wavelet", "levels"), CASES[:4])
def test_variance_matches_monte_carlo(rng, shape, wavelet, levels):
    """<v, K_b^2> for every coefficient of every band against MC_DRAWS noisy images."""
    v = rng.uniform(0.2, 3.0, shape)
    t = StationaryTransform(shape, wavelet=wavelet, levels=levels)
    predicted = np.stack(_flat(t.variance(v)))
    noise = np.sqrt(v)[..., None] * rng.standard_normal(shape + (MC_DRAWS,))
    empirical = np.mean(np.stack(_flat(t.forward(noise))) ** 2, axis=-1)
    lo, hi = _z_bounds(predicted.size)
    ratio = empirical / predicted
    assert ((ratio >= lo) & (ratio <= hi)).all(), (ratio.min(), ratio.max(), lo, hi)


def test_monte_carlo_check_rejects_the_variance_of_a_shifted_kernel(rng):
    """The same check has the power to tell the exact variance from a plausible wrong one."""
    shape, levels = (24, 20), 2
    v = rng.uniform(0.2, 3.0, shape)
    t = StationaryTransform(shape, levels=levels)
    wrong = np.stack([np.roll(b, 1, axis=0) for b in _flat(t.variance(v))])
    noise = np.sqrt(v)[..., None] * rng.standard_normal(shape + (MC_DRAWS,))
    empirical = np.mean(np.stack(_flat(t.forward(noise))) ** 2, axis=-1)
    lo, hi = _z_bounds(wrong.size)
    ratio = empirical / wrong
    assert ((ratio < lo) | (ratio > hi)).sum() > wrong.size // 20


def test_variance_of_one_noisy_pixel_is_the_squared_kernel(rng):
    shape = (20, 24)
    t = StationaryTransform(shape, levels=2)
    v = np.zeros(shape)
    v[3, 17] = 2.5
    impulse = np.where(v > 0, 1.0, 0.0)
    for var, kernel in zip(_flat(t.variance(v)), _flat(t.forward(impulse))):
        assert_allclose(var, 2.5 * kernel**2, rtol=1e-10, atol=1e-13)


@pytest.mark.parametrize(("shape", "wavelet", "levels"), CASES)
def test_float32_matches_the_float64_reference(rng, shape, wavelet, levels):
    """Same transform in single precision: within FLOAT32_RTOL of the largest value."""
    image = rng.standard_normal(shape + (2,))
    ref = StationaryTransform(shape, wavelet=wavelet, levels=levels)
    single = StationaryTransform(shape, wavelet=wavelet, levels=levels, dtype="float32")
    for a, b in zip(_flat(single.forward(image)), _flat(ref.forward(image))):
        assert a.dtype == np.float64
        assert_allclose(a, b, atol=FLOAT32_RTOL * np.abs(image).max())
    v = image**2
    for a, b in zip(_flat(single.variance(v)), _flat(ref.variance(v))):
        assert_allclose(a, b, atol=FLOAT32_RTOL * v.max())
    assert_allclose(single.inverse(ref.forward(image)), image, atol=FLOAT32_RTOL * np.abs(image).max())


def test_cached_transforms_are_shared():
    assert stationary_transform((16, 16), levels=2) is stationary_transform((16, 16), levels=2)
    assert stationary_transform((16, 16), levels=2, dtype="float32") is not stationary_transform((16, 16), levels=2)


@pytest.mark.parametrize(("kwargs", "error", "message"), [
    ({"shape": (0, 4)}, ValueError, "shape"),
    ({"shape": (16, 16), "levels": 5}, ValueError, "levels"),
    ({"shape": (16, 16), "levels": 0}, ValueError, "levels"),
    ({"shape": (16, 16), "wavelet": "nope"}, ValueError, "wavelet"),
    ({"shape": (16, 16), "wavelet": "morl"}, ValueError, "wavelet"),
    ({"shape": (16, 16), "dtype": "float16"}, ValueError, "dtype"),
    ({"shape": (16, 16), "workers": 0}, ValueError, "workers"),
])
def test_bad_arguments_are_refused(kwargs, error, message):
    with pytest.raises(error, match=message):
        StationaryTransform(**kwargs)


def test_bad_planes_are_refused():
    t = StationaryTransform((8, 8), levels=1)
    with pytest.raises(ValueError, match="image"):
        t.forward(np.zeros((8, 9)))
    bad = np.zeros((8, 8))
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="image: 1 value"):
        t.forward(bad)
    bad[0, 0] = -1.0
    with pytest.raises(ValueError, match="variance_of_mean: 1 value"):
        t.variance(bad)
    with pytest.raises(ValueError, match="coeffs"):
        t.inverse([np.zeros((8, 8))])


@pytest.mark.parametrize(("shape", "wavelet", "levels"), CASES)
def test_ducc0_matches_the_scipy_reference(rng, shape, wavelet, levels):
    """The default FFT library against scipy.fft: rounding only in float64, FLOAT32_RTOL in float32."""
    image = rng.standard_normal(shape + (3,))
    v = rng.uniform(0.0, 2.0, shape + (3,))
    ref = StationaryTransform(shape, wavelet=wavelet, levels=levels, backend="scipy")
    for dtype, rtol in (("float64", 1e-12), ("float32", FLOAT32_RTOL)):
        t = StationaryTransform(shape, wavelet=wavelet, levels=levels, dtype=dtype)
        assert t.backend == "ducc0"
        for a, b in zip(_flat(t.forward(image)), _flat(ref.forward(image))):
            assert_allclose(a, b, rtol=0, atol=rtol * np.abs(image).max())
        for a, b in zip(_flat(t.variance(v)), _flat(ref.variance(v))):
            assert_allclose(a, b, rtol=0, atol=rtol * v.max())
        assert_allclose(t.inverse(t.forward(image)), image, rtol=0, atol=rtol * np.abs(image).max())


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_a_plane_transforms_alike_alone_or_in_a_batch(rng, dtype):
    """Bit for bit: so a channel reconstructs the same alone, with the others or on another thread."""
    t = StationaryTransform((30, 22), levels=2, dtype=dtype)
    planes = rng.standard_normal((3, 30, 22))
    batch = t.spectrum(planes)
    for c in range(3):
        np.testing.assert_array_equal(t.spectrum(planes[c]), batch[c])
        np.testing.assert_array_equal(t.planes(batch[c]), t.planes(batch)[c])


@pytest.mark.parametrize("backend", BACKENDS)
def test_out_buffers_give_the_same_planes(rng, backend):
    """``spectrum(out=)`` and ``planes(out=)`` (the Wiener stage's reused buffers) change no bit."""
    t = StationaryTransform((30, 22), levels=2, dtype="float32", backend=backend)
    planes = rng.standard_normal((2, 30, 22)).astype(np.float32)
    spec = np.empty((2, 30, 12), np.complex64)
    assert t.spectrum(planes, out=spec) is spec
    np.testing.assert_array_equal(spec, t.spectrum(planes))
    out = np.empty((2, 30, 22), np.float32)
    assert t.planes(spec.copy(), out=out, overwrite=True) is out
    np.testing.assert_array_equal(out, t.planes(spec))


def test_transfer_products_are_cached_all_or_none(rng, monkeypatch):
    """Small transforms keep every band's products; one too large for the budget keeps none
    (a stage would cycle through a partial cache) and gives the same bits."""
    small = StationaryTransform((32, 32), levels=3, dtype="float32")
    assert small._caching
    for b in range(len(small.bands)):
        small.analysis(b), small.synthesis(b), small.squared(b), small.diagonal(b)
    assert len(small._cache) == 4 * len(small.bands)
    monkeypatch.setattr(stationary, "_CACHE_BYTES", 1)
    large = StationaryTransform((32, 32), levels=3, dtype="float32")
    assert not large._caching
    for b in range(len(large.bands)):
        np.testing.assert_array_equal(large.squared(b), small.squared(b))
    assert large._cache == {}
    image = rng.standard_normal((32, 32, 2))
    for a, b in zip(_flat(large.forward(image)), _flat(small.forward(image))):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("leading", [(), (3,), (2, 3), (0,), (4, 0, 2)])
def test_plane_indices_are_ndindex_order(leading):
    # The planes of a batch are transformed one at a time in this order: the same as np.ndindex.
    assert list(_plane_indices(leading)) == list(np.ndindex(leading))


@pytest.mark.parametrize("domain", [{"offset": 1e39}, {"scale": 1e-38}])
def test_a_domain_beyond_float32_runs_its_stages_in_float64(domain):
    """A log domain's offset or scale that left ``k`` or the image beyond float32 gave NaN over the
    whole image, with warnings only (red-team pass 5): those stages run in float64."""
    import warnings

    from awr_denoise import Domain, SampleBuffer, reconstruct

    rng = np.random.default_rng(0)
    buffer = SampleBuffer.from_moments(np.full((32, 32), 4), 0.5 + 0.1 * rng.standard_normal((32, 32, 3)),
                                       np.full((32, 32, 3), 0.08))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = reconstruct(buffer, domain=Domain("log", **domain))
    reference = reconstruct(buffer, domain=Domain("log", **domain), precision="float64")
    np.testing.assert_allclose(out, reference, rtol=1e-12)


@pytest.mark.parametrize("value", ["", "4,2", "-1", "abc", "1e3", "9223372036854775808", "\u0663", "\uff19", "\u20034"])
def test_a_thread_count_ducc0_cannot_read_is_named(monkeypatch, value):
    # ducc0 stopped with a C++ assertion, "could not convert '' to desired data type", at its first FFT.
    monkeypatch.delenv("DUCC0_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", value)
    with pytest.raises(ValueError, match="OMP_NUM_THREADS"):
        StationaryTransform((8, 8))
    StationaryTransform((8, 8), backend="scipy")  # scipy.fft reads neither
    monkeypatch.setenv("DUCC0_NUM_THREADS", "0" * 5000 + "2")  # leading zeros are fine (not Python's digit limit)
    check_fft_environment()
    monkeypatch.setenv("DUCC0_NUM_THREADS", " 2 ")  # ducc0 reads it first; spaces are fine
    StationaryTransform((8, 8)).forward(np.ones((8, 8)))
