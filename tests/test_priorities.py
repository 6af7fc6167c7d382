"""Coefficient priorities, winning levels and sampling density (paper section 4)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy import ndimage

from awr_denoise import SampleBuffer, SampleRequest
from awr_denoise.domains import Domain
from awr_denoise.priorities import (coefficient_priorities, error_plane, pixel_levels, pooled_deviation,
                                    sampling_density)
from awr_denoise.synthetic import SyntheticRenderer, make_scene
from awr_denoise.noise_gain import shrinkage_gain
from awr_denoise.wavelets import coefficient_variance, forward, wavelet_operators

SHAPE = (64, 64)
SEEDS = range(3)
# PyWavelets' bior4.4 high-pass taps sum to ~1e-12, not 0: a flat image of level ~20 (in the log
# domain) leaves detail coefficients of ~1e-10, squares of ~1e-20.
FLAT_ATOL = 1e-16


def _grey_buffer(mean, var, count):
    return SampleBuffer.from_moments(count, np.repeat(mean[..., None], 3, axis=2), np.repeat(var[..., None], 3, axis=2))


def _scene_buffer(name, spp=8, seed=0):
    scene = make_scene(name, SHAPE)
    return scene, SyntheticRenderer(scene, seed=seed)(SampleRequest.uniform(SHAPE, spp))


def _near_edges(reference, radius=1):
    lum = reference[..., 1]
    edge = ndimage.maximum_filter(lum, 3) - ndimage.minimum_filter(lum, 3) > 0.05
    return ndimage.binary_dilation(edge, iterations=radius)


# ---------------------------------------------------------------------------- error plane
def test_error_plane_in_linear_domain_is_luminance(rng):
    count = rng.integers(2, 9, (8, 10))
    mean = rng.random((8, 10))
    var = rng.random((8, 10))
    buf = _grey_buffer(mean, var, count)
    y, var_mean, var_sample = error_plane(buf, "linear")
    assert_allclose(y, mean, rtol=1e-14)
    assert_allclose(var_sample, var, rtol=1e-14)  # grey: the correlated luminance variance is exact
    assert_allclose(var_mean, var / count, rtol=1e-14)


def test_error_plane_in_log_domain_uses_the_delta_method(rng):
    count = np.full((8, 10), 4)
    mean = rng.uniform(0.1, 2.0, (8, 10))
    var = rng.random((8, 10))
    buf = _grey_buffer(mean, var, count)
    bound = Domain("log").bound(mean)
    y, var_mean, var_sample = error_plane(buf, "log")
    assert_allclose(y, bound.forward(mean), rtol=1e-13)
    assert_allclose(var_sample, var / (mean + bound.k) ** 2, rtol=1e-13)
    assert_allclose(var_mean, var_sample / 4, rtol=1e-14)


def test_error_plane_fills_empty_pixels_and_refuses_an_empty_buffer(rng):
    count = np.full((8, 8), 4)
    count[3, 3] = 0
    buf = _grey_buffer(np.full((8, 8), 0.5), np.full((8, 8), 0.2), count)
    y, var_mean, var_sample = error_plane(buf, "linear")
    assert y[3, 3] == pytest.approx(0.5)
    assert var_sample[3, 3] == pytest.approx(0.2)  # pooled, as a single sample
    assert np.isfinite(var_mean).all()
    with pytest.raises(ValueError, match="buffer: no pixel has any sample"):
        error_plane(SampleBuffer.empty((8, 8)))


# ---------------------------------------------------------------------------- priorities
def test_priorities_layout():
    _, buf = _scene_buffer("edges")
    ops = wavelet_operators(SHAPE)
    prio = coefficient_priorities(buf, operators=ops)
    assert len(prio) == ops.levels + 1
    assert prio[0].shape == SHAPE
    for k in range(1, ops.levels + 1):
        assert prio[k].shape == (ops.rows.approx[k - 1].shape[0], ops.cols.approx[k - 1].shape[0])


@pytest.mark.parametrize("domain", ["linear", "log"])
def test_priorities_are_zero_where_variance_is_zero(domain):
    flat = _grey_buffer(np.full(SHAPE, 0.5), np.zeros(SHAPE), np.full(SHAPE, 4))
    for p in coefficient_priorities(flat, domain=domain):
        assert_allclose(p, 0.0, atol=FLAT_ATOL)
    # An edge with no noise: no variance to remove, so no coefficient asks for samples.
    step = np.where(np.arange(SHAPE[1]) < 30, 0.2, 0.9) * np.ones(SHAPE)
    for p in coefficient_priorities(_grey_buffer(step, np.zeros(SHAPE), np.full(SHAPE, 4)), domain=domain):
        assert (p <= FLAT_ATOL).all()


def test_priorities_of_pure_noise_are_weighted_scale_variances(rng, monkeypatch):
    """A flat noisy image: P_0 is the variance of each pixel mean and P_k = 4^k Var(S_k); to
    float32's precision by default (variances propagated in float32), exactly in float64."""
    from awr_denoise import priorities

    count = rng.integers(2, 12, SHAPE)
    var = rng.uniform(0.01, 0.5, SHAPE)
    buf = _grey_buffer(np.full(SHAPE, 0.5), var, count)
    levels = 3
    for rtol in (2e-6, 1e-12):
        prio = coefficient_priorities(buf, domain="linear", levels=levels)
        assert_allclose(prio[0], var / count, rtol=1e-13)
        for k in range(1, levels + 1):
            scale_variance = coefficient_variance(var / count, levels=k)[0]
            assert_allclose(prio[k], 4.0**k * scale_variance, rtol=rtol)
        monkeypatch.setattr(priorities, "_FLOAT32_SAFE", (np.inf, -np.inf))  # the float64 reference next


def test_smooth_noise_is_won_by_coarse_levels():
    """Talk: in smooth regions the variance grows fine to coarse while wavelets stay the same."""
    ops = wavelet_operators(SHAPE)
    for seed in SEEDS:
        _, buf = _scene_buffer("gradient", seed=seed)
        level = pixel_levels(coefficient_priorities(buf, operators=ops), ops)
        assert np.mean(level == ops.levels) > 0.9


def test_edges_are_won_by_finer_levels():
    """Talk: at edges the wavelets grow fine to coarse while the variance stays."""
    ops = wavelet_operators(SHAPE)
    for seed in SEEDS:
        scene, buf = _scene_buffer("edges", seed=seed)
        near = _near_edges(scene.reference())
        level = pixel_levels(coefficient_priorities(buf, operators=ops), ops)
        assert level[near].mean() < level[~near].mean() - 0.5
        assert np.mean(level[near] <= 1) > 2 * np.mean(level[~near] <= 1)


# ---------------------------------------------------------------------------- density
def _neighbour_mean(x):
    """Mean of the 8 neighbours of every pixel, edges mirrored (index -1 is index 1): the pixel itself left out."""
    h, w = x.shape
    out = np.zeros_like(x)
    for i in range(h):
        for j in range(w):
            values = [x[abs(i + di) if i + di < h else 2 * h - 2 - (i + di),
                        abs(j + dj) if j + dj < w else 2 * w - 2 - (j + dj)]
                      for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]
            out[i, j] = np.mean(values)
    return out


def test_density_without_levels_is_the_neighbours_pooled_standard_deviation(rng):
    """The relative (here: the domain's) error of the 8 neighbours, the pixel's own samples left out; the
    absolute term of 3x3 pixels, its own included (docs/sampling.md, "The pixel's own samples")."""
    count = np.full((12, 12), 4)
    var = rng.uniform(0.0, 1.0, (12, 12))
    buf = _grey_buffer(np.full((12, 12), 1.0), var, count)
    neighbours = _neighbour_mean(var)
    density = sampling_density(buf, domain="linear", level_weight=0.0, absolute_above=None, noise_model="levels")
    assert_allclose(density, np.sqrt(neighbours), rtol=1e-12)
    # In the linear domain the capped level adds the same error over 6 times the image's level (1).
    density = sampling_density(buf, domain="linear", level_weight=0.0, noise_model="levels")
    assert_allclose(density, np.sqrt(neighbours + ndimage.uniform_filter(var, 3, mode="nearest") / 36), rtol=1e-12)


def test_a_pixels_own_samples_do_not_rank_it_but_rank_its_neighbours():
    """One pixel whose samples caught a bright path: it gains nothing over its quiet neighbours' level; they do."""
    var = np.full((9, 9), 0.01)
    var[4, 4] = 4.0
    buf = _grey_buffer(np.full((9, 9), 1.0), var, np.full((9, 9), 4))
    s = pooled_deviation(buf, domain="linear", absolute_above=None)
    assert s[4, 4] == pytest.approx(0.1)  # its 8 neighbours' 0.01
    assert s[4, 5] == pytest.approx(np.sqrt((4.0 + 7 * 0.01) / 8))
    assert s[0, 0] == pytest.approx(0.1)


@pytest.mark.parametrize("noisy", [1e12, 1e20])
def test_a_very_noisy_pixel_leaves_its_neighbours_ranking_to_them(noisy):
    """Its 8 neighbours' error is added up from them, not taken as the 3x3 sum less its own value (which left 0 at
    1e20), and the pixels beyond its square are ranked as without it (a running sum carried its rounding error
    along the line)."""
    var = np.full((9, 9), 0.01)
    var[4, 4] = noisy
    s = pooled_deviation(_grey_buffer(np.full((9, 9), 1.0), var, np.full((9, 9), 4)), domain="linear",
                         absolute_above=None)
    assert s[4, 4] == pytest.approx(0.1, rel=1e-12)
    assert s[4, 7] == pytest.approx(0.1, rel=1e-12) and s[7, 4] == pytest.approx(0.1, rel=1e-12)


def test_a_pixel_far_brighter_than_the_image_is_ranked_by_its_absolute_error(rng):
    """pooled_deviation: below 6 times the image's level, the relative ranking; far above it, the absolute."""
    mean = np.full((24, 24), 1.0)
    mean[12, 12] = 300.0  # a small light: relative noise 0.5 like the rest, absolute 150
    buf = _grey_buffer(mean, (0.5 * mean) ** 2, np.full((24, 24), 4))
    relative = pooled_deviation(buf, absolute_above=None)
    capped = pooled_deviation(buf)
    level = 6 * mean.mean()
    assert capped[12, 12] / capped[2, 2] > 10 * relative[12, 12] / relative[2, 2]  # 12.6x here
    assert_allclose(capped[12, 12] ** 2, relative[12, 12] ** 2 + ndimage.uniform_filter(
        (0.5 * mean) ** 2 / level ** 2, 3, mode="nearest")[12, 12], rtol=1e-9)
    # Dark pixels far from the light keep their relative ranking to within the small absolute share.
    assert_allclose(capped[2, 2], relative[2, 2], rtol=0.01)
    # An all-black image (its level taken as 1, every pixel at 0): about one factor everywhere, the same
    # ranking (to 1e-4: the absolute term pools the pixel's own samples, the relative one its neighbours').
    black = _grey_buffer(np.zeros((8, 8)), rng.uniform(0.05, 0.2, (8, 8)), np.full((8, 8), 4))
    ratio = pooled_deviation(black) / pooled_deviation(black, absolute_above=None)
    assert_allclose(ratio, np.sqrt(1 + (0.1 / 6) ** 2), rtol=1e-4)


def test_density_is_higher_near_edges():
    for seed in SEEDS:
        scene, buf = _scene_buffer("edges", seed=seed)
        near = _near_edges(scene.reference())
        density = sampling_density(buf, level_weight=1.0, noise_model="levels")
        assert (density >= 0).all()
        assert density[near].mean() > 1.3 * density[~near].mean()


def test_the_shrinkage_gain_sees_edges_the_default_level_weight_barely_does():
    """The default model (the shrinkage's gain) puts more density near edges than the level term
    at the samplers' level weight of 0.25 (measured: 1.18-1.29x far from them, against 1.03-1.07x)."""
    for seed in SEEDS:
        scene, buf = _scene_buffer("edges", seed=seed)
        near = _near_edges(scene.reference())
        shrinkage = sampling_density(buf)
        levels = sampling_density(buf, level_weight=0.25, noise_model="levels")
        assert (shrinkage >= 0).all()
        assert shrinkage[near].mean() / shrinkage[~near].mean() > 1.1
        assert shrinkage[near].mean() / shrinkage[~near].mean() > levels[near].mean() / levels[~near].mean()


def test_the_shrinkage_density_is_the_pooled_deviation_times_the_root_of_the_pooled_gain():
    scene, buf = _scene_buffer("edges", seed=0)
    ops = wavelet_operators(buf.shape)
    mean_y, var_y, _ = error_plane(buf)
    gain = shrinkage_gain(forward(mean_y, levels=ops.levels), coefficient_variance(var_y, operators=ops), ops)
    expected = pooled_deviation(buf) * np.sqrt(ndimage.uniform_filter(gain, 3, mode="nearest"))
    # The sampler's variances are propagated in float32: the same density to float32 precision.
    assert_allclose(sampling_density(buf, noise_model="shrinkage"), expected, rtol=1e-5)
    # The same through a given gain: the measured gain's route.
    assert_allclose(sampling_density(buf, noise_gain=gain, noise_model="reconstruction"), expected, rtol=1e-12)


def test_the_noise_model_is_checked():
    _, buf = _scene_buffer("edges")
    with pytest.raises(ValueError, match="noise_model"):
        sampling_density(buf, noise_model="level")
    with pytest.raises(ValueError, match="noise_gain: noise_model='reconstruction' needs the measured gain"):
        sampling_density(buf, noise_model="reconstruction")
    for model in ("shrinkage", "levels"):  # a gain that would do nothing is refused, not ignored
        with pytest.raises(ValueError, match=f"noise_gain: a measured gain needs noise_model='reconstruction', "
                                             f"not '{model}'"):
            sampling_density(buf, noise_gain=np.ones(buf.shape), noise_model=model)


def test_a_measured_gain_of_another_kind_is_refused():
    """A masked gain's hidden values were used, a bool gain read as 0 and 1, a complex one cast with a
    warning (a review of the array-layout fixes)."""
    _, buf = _scene_buffer("edges")
    gain = np.ones(buf.shape)
    for bad, message in ((np.ma.masked_array(gain, mask=gain > 0), "noise_gain: a masked array"),
                         (gain > 0, "noise_gain: expected a numeric array, got dtype bool"),
                         (gain + 0j, "noise_gain: complex values")):
        with pytest.raises(TypeError, match=message):
            sampling_density(buf, noise_gain=bad, noise_model="reconstruction")


def test_density_is_zero_for_a_deterministic_image():
    buf = _grey_buffer(np.linspace(0, 1, 64).reshape(8, 8), np.zeros((8, 8)), np.full((8, 8), 4))
    assert_array_equal(sampling_density(buf), 0.0)


@pytest.mark.parametrize("scene", ["edges", "hdr_source", "fireflies", "gradient"])
def test_float32_variance_propagation_picks_the_float64_levels(scene, monkeypatch):
    """The priorities' variances are propagated in float32 (inside its safe range): every pixel's
    level is the one the float64 reference picks, and the priorities agree to float32 precision."""
    from awr_denoise import SampleRequest, priorities
    from awr_denoise.synthetic import SyntheticRenderer, make_scene
    from awr_denoise.wavelets import wavelet_operators

    shape = (48, 64)
    buf = SyntheticRenderer(make_scene(scene, shape), seed=2)(SampleRequest.uniform(shape, 4))
    ops = wavelet_operators(shape)
    single = priorities.coefficient_priorities(buf, operators=ops)
    monkeypatch.setattr(priorities, "_FLOAT32_SAFE", (np.inf, -np.inf))  # nothing is in range: float64
    double = priorities.coefficient_priorities(buf, operators=ops)
    for a, b in zip(single, double):
        assert a.dtype == np.float64
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * float(np.abs(b).max()))
    assert np.array_equal(priorities.pixel_levels(single, ops), priorities.pixel_levels(double, ops))
    assert not all(np.array_equal(a, b) for a, b in zip(single, double))  # float32 did run


def test_variances_outside_float32_range_are_propagated_in_float64():
    """A variance too small for float32's normal numbers next to ordinary ones: the float64 path."""
    from awr_denoise import priorities
    from awr_denoise.wavelets import wavelet_operators

    rng = np.random.default_rng(5)
    mean = rng.random((32, 32))
    var = rng.random((32, 32)) * 1e-3
    var[:4] = 1e-35  # below 2^-100: float32 would lose these pixels' digits
    ops = wavelet_operators((32, 32))
    plane = (mean, var, var * 4)
    got = priorities.coefficient_priorities(None, operators=ops, plane=plane)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(priorities, "_FLOAT32_SAFE", (np.inf, -np.inf))
        ref = priorities.coefficient_priorities(None, operators=ops, plane=plane)
    assert all(np.array_equal(a, b) for a, b in zip(got, ref))


def test_a_deviation_past_float64_stays_finite_and_ranks_first():
    """pooled_deviation holds a sum past float64 finite: allocate() reads +inf as no density."""
    mean = np.full((8, 8), 1.0)
    var = np.full((8, 8), 0.01)
    var[4, 4] = 1e308  # relative and absolute terms each near float64's limit: their sum overflows
    s = pooled_deviation(_grey_buffer(mean, var, np.full((8, 8), 4)), absolute_above=1e-5)
    assert np.isfinite(s).all()
    # Its own relative error ranks its 8 neighbours, its own absolute error it and them: all far above the rest.
    assert s[3:6, 3:6].min() > 1e100 * s[0, 0] and np.unravel_index(np.argmax(s), s.shape) != (4, 4)
    assert s[3:6, 3:6].max() == s.max()


def test_levels_are_the_masked_copies_levels():
    """_levels keeps a running maximum (fmax) and the largest winning level; the loop it replaced
    copied values and levels under a mask. The same levels, with ties, a NaN and infinities."""
    from awr_denoise.priorities import _expansion, _gather, _levels
    from awr_denoise.wavelets import wavelet_operators

    rng = np.random.default_rng(4)
    ops = wavelet_operators((45, 70))
    prio = [np.round(rng.random((45, 70)), 1)]  # few values: many ties between levels
    for k in range(1, ops.levels + 1):
        shape = ops.rows.approx[k - 1].shape[0], ops.cols.approx[k - 1].shape[0]
        prio.append(np.round(rng.random(shape) * 1.2 - 0.1, 1))
    prio[1][:2, :2], prio[2][:2, :2] = np.nan, 2.0  # a NaN is passed over: level 2 wins there
    prio[2][3, 3], prio[1][2, 3] = np.inf, -np.inf
    prio[0][20:22, 30:33] = np.nan  # a NaN never wins at level 0 either: it counts as -inf

    best, expected = np.where(np.isnan(prio[0]), -np.inf, prio[0]), np.zeros((45, 70), np.uint8)
    for k in range(1, len(prio)):
        key = (ops.wavelet, ops.boundary, ops.levels, k)
        at = _gather(prio[k], _expansion(45, *key), _expansion(70, *key))
        better = at > best
        best[better], expected[better] = at[better], k
    got = _levels(prio, ops)
    assert got.dtype == np.uint8 and len(np.unique(got)) == ops.levels + 1
    assert (got[20:22, 30:33] > 0).all()
    np.testing.assert_array_equal(got, expected)


def test_an_executor_gives_the_same_priorities_and_density():
    """The transform of the means and the pooled deviation on threads: bit for bit the serial result."""
    from concurrent.futures import ThreadPoolExecutor

    from awr_denoise import SampleRequest
    from awr_denoise.priorities import coefficient_priorities, sampling_density
    from awr_denoise.synthetic import SyntheticRenderer, make_scene

    shape = (40, 56)
    buf = SyntheticRenderer(make_scene("edges", shape), seed=3)(SampleRequest.uniform(shape, 4))
    with ThreadPoolExecutor(2) as pool:
        for a, b in zip(coefficient_priorities(buf), coefficient_priorities(buf, executor=pool)):
            np.testing.assert_array_equal(a, b)
        for options in ({}, {"noise_model": "levels"}, {"noise_model": "levels", "level_weight": 0.0},
                        {"noise_model": "reconstruction", "noise_gain": np.full(shape, 0.5)}):
            np.testing.assert_array_equal(sampling_density(buf, **options),
                                          sampling_density(buf, executor=pool, **options))
