"""Wavelet transforms and the exact propagation of pixel variance to coefficients, <v, K^2>."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import pywt
from numpy.testing import assert_allclose
from scipy import stats

from awr_denoise import SampleBuffer, reconstruct
from awr_denoise.wavelets import (
    coefficient_variance,
    default_levels,
    forward,
    inverse,
    max_levels,
    _edge,
    _sparse_operator,
    shrinkage_diagonal,
    wavelet_operators,
)

SHAPES = [(37, 53), (16, 16), (5, 7), (1, 17)]
WAVELETS = ["bior4.4", "haar"]

# Perfect reconstruction: float64 rounding through a few levels of filtering.
ROUND_TRIP_ATOL = 1e-10
# <v, K^2> against squared impulse responses: both are sums of a few products of taps.
IMPULSE_ATOL = 1e-13
IMPULSE_RTOL = 1e-10
# Monte Carlo check: N draws per coefficient, Bonferroni-corrected family-wise error rate.
MC_DRAWS = 3000
MC_FAMILY_ALPHA = 1e-3


def _flatten(coeffs) -> np.ndarray:
    """All coefficients of a forward()/coefficient_variance() list, flattened over the image axes."""
    parts = [coeffs[0]]
    for bands in coeffs[1:]:
        parts.extend(bands)
    return np.concatenate([p.reshape(-1, *p.shape[2:]) for p in parts], axis=0)


def _level_cases():
    for shape in SHAPES:
        for wavelet in WAVELETS:
            for levels in sorted({1, max_levels(shape)}):
                yield pytest.param(shape, wavelet, levels, id=f"{shape[0]}x{shape[1]}-{wavelet}-L{levels}")


# ---------------------------------------------------------------------------- levels
@pytest.mark.parametrize(("shape", "expected"), [((1024, 2048), 5), ((64, 64), 3), ((37, 53), 2),
                                                 ((16, 16), 1), ((5, 7), 1), ((1, 17), 1)])
def test_default_levels(shape, expected):
    assert default_levels(shape) == expected


@pytest.mark.parametrize(("shape", "expected"), [((37, 53), 5), ((16, 16), 4), ((5, 7), 2), ((1, 17), 1)])
def test_max_levels(shape, expected):
    assert max_levels(shape) == expected


def test_bad_levels_wavelet_and_boundary_are_refused():
    with pytest.raises(ValueError, match=r"levels: 5 is outside 1\.\.4"):
        forward(np.zeros((16, 16)), levels=5)
    with pytest.raises(ValueError, match="levels: 0"):
        wavelet_operators((16, 16), levels=0)
    with pytest.raises(TypeError, match="levels"):
        forward(np.zeros((16, 16)), levels=2.0)
    with pytest.raises(ValueError, match="wavelet: 'cdf97'"):
        forward(np.zeros((16, 16)), wavelet="cdf97")
    with pytest.raises(ValueError, match="boundary: 'mirror'"):
        forward(np.zeros((16, 16)), boundary="mirror")


@pytest.mark.parametrize("boundary", ["reflect", "antireflect"])
@pytest.mark.parametrize("shape", [(1, 40), (40, 1)])
def test_a_mode_that_needs_two_pixels_is_refused_by_name_on_a_thinner_image(boundary, shape):
    """PyWavelets' own error ("Input data length must be greater than 1") named no option (a red-team pass)."""
    message = f"boundary: '{boundary}' needs 2 pixels"
    with pytest.raises(ValueError, match=message):
        forward(np.zeros(shape), boundary=boundary)
    with pytest.raises(ValueError, match=message):
        wavelet_operators(shape, boundary=boundary)
    buffer = SampleBuffer.from_moments(np.full(shape, 4), np.ones(shape + (3,)), np.full(shape + (3,), 0.1))
    with pytest.raises(ValueError, match=message):
        reconstruct(buffer, boundary=boundary, stages=1)


# ---------------------------------------------------------------------------- transform
@pytest.mark.parametrize(("shape", "wavelet", "levels"), list(_level_cases()))
def test_inverse_undoes_forward(rng, shape, wavelet, levels):
    image = rng.random(shape + (2,))
    back = inverse(forward(image, wavelet=wavelet, levels=levels), shape, wavelet=wavelet)
    assert back.shape == image.shape
    assert_allclose(back, image, atol=ROUND_TRIP_ATOL)


def test_layout_is_pywavelets(rng):
    image = rng.random((64, 64))
    ours = forward(image, levels=2)
    theirs = pywt.wavedec2(image, "bior4.4", mode="symmetric", level=2)
    assert len(ours) == 3
    assert_allclose(ours[0], theirs[0], rtol=0, atol=0)
    for a, b in zip(ours[1:], theirs[1:]):
        for x, y in zip(a, b):
            assert_allclose(x, y, rtol=0, atol=0)


# ---------------------------------------------------------------------------- variance: deterministic
@pytest.mark.parametrize(("shape", "wavelet", "levels"), list(_level_cases()))
def test_variance_of_one_hot_equals_squared_impulse_response(rng, shape, wavelet, levels):
    """v = e_p gives Var(C) = K(p)^2, the square of the forward transform of a unit impulse at p."""
    h, w = shape
    n = h * w
    picks = np.unique(np.concatenate([[0, w - 1, n - w, n - 1, n // 2], rng.choice(n, min(n, 24), replace=False)]))
    impulses = np.zeros((h, w, picks.size))
    impulses.reshape(n, -1)[picks, np.arange(picks.size)] = 1.0
    expected = _flatten(forward(impulses, wavelet=wavelet, levels=levels)) ** 2
    got = _flatten(coefficient_variance(impulses, wavelet=wavelet, levels=levels))
    assert got.shape == expected.shape
    assert_allclose(got, expected, rtol=IMPULSE_RTOL, atol=IMPULSE_ATOL)
    assert (expected.sum(axis=0) > 0).all()  # every impulse reaches some coefficient


@pytest.mark.parametrize("value", [1e-46, 1e-40, 1e37, 1e39])
def test_float32_variances_beyond_its_range_are_refused_not_rounded(value):
    """Cast first, 1e39 became Inf (refused as "NaN, Inf") and 1e-46 became 0, an exact pixel (a red-team pass)."""
    v = np.full((16, 16), value)
    with pytest.raises(ValueError, match="beyond float32's range.*precision='float64'"):
        coefficient_variance(v, levels=2, precision="float32")
    assert np.isfinite(coefficient_variance(v, levels=2)[0]).all()  # float64 holds them
    ordinary = np.ones((16, 16))
    ordinary[0, 0] = 0.0  # an exact pixel beside ordinary ones is fine in float32
    assert coefficient_variance(ordinary, levels=2, precision="float32")[0].dtype == np.float32


@pytest.mark.parametrize(("shape", "wavelet", "levels"), list(_level_cases()))
def test_variance_is_linear_in_pixel_variance(rng, shape, wavelet, levels):
    v1, v2 = rng.random(shape), rng.random(shape)
    a = _flatten(coefficient_variance(2.0 * v1 + 3.0 * v2, wavelet=wavelet, levels=levels))
    b = 2.0 * _flatten(coefficient_variance(v1, wavelet=wavelet, levels=levels)) \
        + 3.0 * _flatten(coefficient_variance(v2, wavelet=wavelet, levels=levels))
    assert_allclose(a, b, rtol=1e-12, atol=1e-15)


def test_channels_are_propagated_independently(rng):
    v = rng.random((20, 24, 3))
    both = coefficient_variance(v, levels=2)
    for c in range(3):
        single = coefficient_variance(v[:, :, c], levels=2)
        assert_allclose(_flatten(both)[:, c], _flatten(single), rtol=1e-14)


def test_haar_on_powers_of_two_equals_cascaded_squared_filters(rng):
    """Haar's supports do not overlap, so squaring its one-level filters and cascading is exact."""
    v = rng.random((16, 16))
    h = pywt.Wavelet("haar")
    squared = pywt.Wavelet("haar_squared", filter_bank=[np.square(h.dec_lo), np.square(h.dec_hi), h.rec_lo, h.rec_hi])
    cascade = pywt.wavedec2(v, squared, mode="symmetric", level=4)
    assert_allclose(_flatten(coefficient_variance(v, wavelet="haar", levels=4)), _flatten(cascade), rtol=1e-12)


def test_operators_for_another_shape_are_refused():
    ops = wavelet_operators((16, 16), levels=2)
    with pytest.raises(ValueError, match="operators: built for shape"):
        coefficient_variance(np.ones((16, 17)), operators=ops)


# ---------------------------------------------------------------------------- variance: Monte Carlo
def _monte_carlo_z_bounds(n_coefficients: int) -> tuple[float, float]:
    """Acceptance interval of the ratio (empirical second moment / predicted variance).

    A coefficient of zero-mean Gaussian noise is Gaussian, so with the mean known (zero)
    ``N * m2 / sigma^2`` is chi-square with N degrees of freedom. Bonferroni over all
    coefficients keeps the family-wise false-alarm rate at MC_FAMILY_ALPHA.
    """
    alpha = MC_FAMILY_ALPHA / n_coefficients
    return (stats.chi2.ppf(alpha / 2, MC_DRAWS) / MC_DRAWS, stats.chi2.isf(alpha / 2, MC_DRAWS) / MC_DRAWS)


def _empirical_variance(v, wavelet, levels, rng):
    noise = np.sqrt(v)[..., None] * rng.standard_normal(v.shape + (MC_DRAWS,))
    coeffs = _flatten(forward(noise, wavelet=wavelet, levels=levels))
    return np.mean(coeffs * coeffs, axis=-1)


def _naive_cascade(v, wavelet, levels):
    """The wrong propagation: one-level squared filters applied level after level."""
    wv = pywt.Wavelet(wavelet)
    squared = pywt.Wavelet(wavelet + "_sq", filter_bank=[np.square(wv.dec_lo), np.square(wv.dec_hi),
                                                         wv.rec_lo, wv.rec_hi])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return _flatten(pywt.wavedec2(v, squared, mode="symmetric", level=levels))


@pytest.mark.parametrize(("shape", "wavelet", "levels"), list(_level_cases()))
def test_variance_matches_monte_carlo(rng, shape, wavelet, levels):
    """<v, K^2> for every scale and wavelet coefficient of every level against N noisy images."""
    v = rng.uniform(0.2, 3.0, shape)  # position-dependent per-pixel variance of the mean
    predicted = _flatten(coefficient_variance(v, wavelet=wavelet, levels=levels))
    empirical = _empirical_variance(v, wavelet, levels, rng)
    assert predicted.shape == empirical.shape
    # Haar on an odd length: the symmetric extension repeats the last pixel, so the last detail
    # coefficient is x - x, identically zero: K = 0, and its variance must be exactly zero.
    zero = predicted == 0
    assert not zero.all()
    assert_allclose(empirical[zero], 0.0, atol=1e-25)
    predicted, empirical = predicted[~zero], empirical[~zero]
    lo, hi = _monte_carlo_z_bounds(predicted.size)
    ratio = empirical / predicted
    bad = (ratio < lo) | (ratio > hi)
    assert not bad.any(), (f"{int(bad.sum())} of {ratio.size} coefficients outside [{lo:.3f}, {hi:.3f}]: "
                           f"ratios {ratio[bad][:5]}")


@pytest.mark.parametrize(("shape", "levels"), [((37, 53), 3), ((16, 16), 2)])
def test_monte_carlo_check_rejects_cascaded_squared_filters(rng, shape, levels):
    """The same check has the power to reject the plausible but wrong cascade for bior4.4."""
    v = rng.uniform(0.2, 3.0, shape)
    naive = _naive_cascade(v, "bior4.4", levels)
    exact = _flatten(coefficient_variance(v, wavelet="bior4.4", levels=levels))
    empirical = _empirical_variance(v, "bior4.4", levels, rng)
    lo, hi = _monte_carlo_z_bounds(naive.size)
    ratio = empirical / naive
    assert ((ratio < lo) | (ratio > hi)).sum() > naive.size // 10
    ratio = empirical / exact
    assert ((ratio >= lo) & (ratio <= hi)).all()


# ---------------------------------------------------------------------------- the diagonal of a shrinkage
def _random_factors(rng, shape, wavelet, levels, boundary):
    template = forward(np.zeros(shape), wavelet=wavelet, levels=levels, boundary=boundary)
    return [rng.random(template[0].shape)] + [tuple(rng.random(b.shape) for b in bands) for bands in template[1:]]


def _dense_diagonal(factors, shape, wavelet, levels, boundary):
    """The map's diagonal from its impulse responses: every pixel through forward, the factors, inverse."""
    h, w = shape
    impulses = np.eye(h * w).reshape(h, w, h * w)
    coeffs = forward(impulses, wavelet=wavelet, levels=levels, boundary=boundary)
    scaled = [coeffs[0] * factors[0][..., None]] + [tuple(b * f[..., None] for b, f in zip(bands, fs))
                                                     for bands, fs in zip(coeffs[1:], factors[1:])]
    out = inverse(scaled, shape, wavelet=wavelet, boundary=boundary).reshape(h * w, h * w)
    return np.diagonal(out).reshape(h, w)


@pytest.mark.parametrize(("shape", "wavelet", "levels", "boundary"), [
    ((13, 17), "bior4.4", 2, "symmetric"), ((16, 16), "bior4.4", None, "symmetric"), ((9, 11), "haar", 3, "periodization"),
    ((20, 7), "db2", 2, "zero"), ((1, 17), "bior4.4", 1, "symmetric")])
def test_shrinkage_diagonal_equals_the_impulse_responses(rng, shape, wavelet, levels, boundary):
    """Exact for odd sizes, other wavelets and boundary modes: the products S * A^T reproduce each
    pixel's weight on itself through forward, the factors and inverse (cropping included)."""
    ops = wavelet_operators(shape, wavelet=wavelet, levels=levels, boundary=boundary)
    factors = _random_factors(rng, shape, wavelet, ops.levels, boundary)
    expected = _dense_diagonal(factors, shape, wavelet, ops.levels, boundary)
    assert_allclose(shrinkage_diagonal(factors, ops), expected, rtol=0, atol=1e-14)
    # float32: the same to a few float32 epsilons of the largest value (factors in [0, 1]).
    single = shrinkage_diagonal(factors, ops, precision="float32")
    assert single.dtype == np.float32
    assert_allclose(single, expected, rtol=0, atol=8 * np.finfo(np.float32).eps * np.abs(expected).max())


def test_shrinkage_diagonal_of_the_identity_is_one_and_of_nothing_zero():
    ops = wavelet_operators((24, 40))
    template = forward(np.zeros((24, 40)), levels=ops.levels)
    ones = [np.ones_like(template[0])] + [tuple(np.ones_like(b) for b in bands) for bands in template[1:]]
    zeros = [np.zeros_like(template[0])] + [tuple(np.zeros_like(b) for b in bands) for bands in template[1:]]
    assert_allclose(shrinkage_diagonal(ones, ops), 1.0, atol=1e-13)
    assert_allclose(shrinkage_diagonal(zeros, ops), 0.0, atol=0)


def test_shrinkage_diagonal_refuses_wrong_factors_and_precision():
    ops = wavelet_operators((16, 16), levels=2)
    template = forward(np.zeros((16, 16)), levels=2)
    with pytest.raises(ValueError, match="factors: expected 3 entries"):
        shrinkage_diagonal(template[:2], ops)
    with pytest.raises(ValueError, match="precision"):
        shrinkage_diagonal(template, ops, precision="float16")


def _dense_matrix(apply, n_in):
    """The map's matrix the O(n^2) way: every impulse pushed through it."""
    return apply(np.eye(n_in))


@pytest.mark.parametrize("wavelet", ["bior4.4", "haar", "db4", "sym3"])
@pytest.mark.parametrize("boundary", sorted(pywt.Modes.modes))
def test_operators_built_from_templates_equal_every_impulse_pushed_through(wavelet, boundary):
    """The O(n) build (edge columns computed, interior ones shifted templates) is the dense matrix
    bit for bit: one DWT step, and a level-k band's synthesis, at lengths around the edges' reach."""
    w = pywt.Wavelet(wavelet)
    edge = _edge(w)
    for n in (2 * edge + 1, 2 * edge + 3, 3 * edge + 8, 301):
        for band in (0, 1):
            step = lambda x, band=band: pywt.dwt(x, w, mode=boundary, axis=0)[band]  # noqa: E731
            built = _sparse_operator(step, n, (2, 1), edge)
            assert np.array_equal(built.toarray(), _dense_matrix(step, n)), (n, band)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            lengths = [c.shape[0] for c in pywt.wavedec(np.zeros(n), w, mode=boundary, level=3)]

            def synthesis(x, lengths=lengths, n=n):
                coeffs = [np.zeros((m, x.shape[1])) for m in lengths]
                coeffs[1] = x
                return pywt.waverec(coeffs, w, mode=boundary, axis=0)[:n]
            built = _sparse_operator(synthesis, lengths[1], (1, 8), edge)
            assert np.array_equal(built.toarray(), _dense_matrix(synthesis, lengths[1])), n


def test_a_map_that_is_not_shift_invariant_is_built_column_by_column():
    """The random probes catch a map whose interior columns are not shifted templates."""
    weights = np.linspace(1.0, 2.0, 200)[:, None]
    tapered = lambda x: pywt.dwt(x * weights, "db2", mode="symmetric", axis=0)[0]  # noqa: E731
    built = _sparse_operator(tapered, 200, (2, 1), 12)
    assert_allclose(built.toarray(), _dense_matrix(tapered, 200), rtol=0, atol=1e-15)


def test_operators_of_a_long_side_are_built_in_linear_time():
    """Building a side's operator pushes a fixed number of impulses through the DWT, not one per
    sample (a 65536-sample side took minutes that way): the edges, two templates and the probes."""
    pushed = []

    def step(x):
        pushed.append(x.shape[1])
        return pywt.dwt(x, "bior4.4", mode="symmetric", axis=0)[1]
    edge = _edge(pywt.Wavelet("bior4.4"))
    built = _sparse_operator(step, 8192, (2, 1), edge)
    assert sum(pushed) == 2 * edge + 2 + 2  # both edges, a template per phase, two random probes
    assert built.shape == (4100, 8192) and built.nnz <= 8 * 8192



def test_levels_past_pywts_useful_depth_neither_warn_nor_touch_the_warnings_filters(rng, recwarn, monkeypatch):
    """The transform and the diagonals' operators at levels where every coefficient touches the boundary: no warning,
    and no change to the process' warnings filters. They silenced pywt's warning with ``warnings.catch_warnings``,
    whose filters are the whole process': entered and left on an executor's threads while another thread warned, the
    filters could be left ignoring the caller's warnings (``awr render --seconds``' TimeBudgetWarning was lost)."""
    from awr_denoise import wavelets

    def refused(*args, **kwargs):
        raise AssertionError("the process' warnings filters changed")

    shape = (37, 11)
    levels = max_levels(shape)  # 3, where pywt's useful depth of 11 samples with bior4.4 is 0
    assert levels > pywt.dwt_max_level(11, pywt.Wavelet("bior4.4").dec_len)
    image = rng.random(shape)
    wavelets._axis_operators.cache_clear()  # built again here, not taken from an earlier test
    wavelets._axis_diagonals.cache_clear()
    with monkeypatch.context() as patch:  # only around the calls: pytest's own reports use these
        for name in ("catch_warnings", "simplefilter", "filterwarnings", "resetwarnings"):
            patch.setattr(warnings, name, refused)
        coeffs = forward(image, levels=levels)
        ones = [np.ones_like(coeffs[0])] + [tuple(np.ones_like(b) for b in bands) for bands in coeffs[1:]]
        diagonal = shrinkage_diagonal(ones, wavelet_operators(shape, levels=levels))
    assert not recwarn.list, [str(w.message) for w in recwarn.list]
    assert_allclose(inverse(coeffs, shape), image, atol=1e-12)
    assert_allclose(diagonal, 1.0, atol=1e-12)  # every factor 1: the identity map, its diagonal all ones
