"""The SURE guard: Stein's unbiased risk estimate decides how much of a change from the mean to keep."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy import ndimage

from awr_denoise._window_sums import window_sum
from awr_denoise.sure import sure_blend

SHAPE = (32, 32, 1)


def _flat(rng, sd=0.1):
    truth = np.ones(SHAPE)
    return truth, truth + sd * rng.standard_normal(SHAPE), np.full(SHAPE, sd * sd)


def test_sure_is_unbiased_for_the_blend_it_chooses_between(rng):
    """The risk the guard minimises, v + 2 l v (L - 1) + l^2 (o - x)^2, averaged over noise
    draws, is the blend's true squared error (a 3x3 box smoother, leverage 1/9)."""
    truth = np.linspace(0.0, 1.0, 32)[None, :, None] * np.ones(SHAPE)
    lam, sd = 0.6, 0.2
    sure, true = [], []
    for _ in range(400):
        x = truth + sd * rng.standard_normal(SHAPE)
        o = ndimage.uniform_filter(x, size=(3, 3, 1), mode="wrap")
        blend = x + lam * (o - x)
        sure.append(np.mean(sd**2 + 2 * lam * sd**2 * (1 / 9 - 1) + lam**2 * (o - x) ** 2))
        true.append(np.mean((blend - truth) ** 2))
    assert np.mean(sure) == pytest.approx(np.mean(true), rel=0.02)


def test_a_good_estimate_is_kept_and_a_biased_one_undone(rng):
    truth, mean, variance = _flat(rng)
    lev = np.full(SHAPE, 0.05)
    kept, lam = sure_blend(truth, mean, variance, lev, k=0.1)
    assert lam.mean() > 0.85
    assert np.mean((kept - truth) ** 2) < 0.25 * np.mean((mean - truth) ** 2)
    biased, lam = sure_blend(truth + 0.5, mean, variance, lev, k=0.1)
    assert lam.max() < 0.1
    assert np.mean((biased - truth) ** 2) < 2 * np.mean((mean - truth) ** 2)


def test_the_tolerance_keeps_a_right_change_whole_and_undoes_a_biased_one_in_proportion(rng):
    """Means whose errors run 1.1x their stated variances (a heavy tail's sample variances fall
    short): the clean image is kept whole with a tolerance of 1.2, partly undone without one; a
    change biased by 2 standard errors is still undone, to about ``t / (1 + b^2)``."""
    truth = np.ones(SHAPE)
    sd = 0.1
    mean = truth + sd * np.sqrt(1.1) * rng.standard_normal(SHAPE)
    variance, lev = np.full(SHAPE, sd * sd), np.zeros(SHAPE)
    undone, strict = sure_blend(truth, mean, variance, lev, k=0.1, window=31)
    kept, lam = sure_blend(truth, mean, variance, lev, k=0.1, window=31, tolerance=1.2)
    assert strict.mean() < 0.95 and lam.mean() > 0.99  # windows cut by the border hold fewer terms: noisier
    assert np.mean((kept - truth) ** 2) < 0.02 * np.mean((undone - truth) ** 2)
    _, biased = sure_blend(truth + 2 * sd, mean, variance, lev, k=0.1, window=31, tolerance=1.2)
    assert biased.mean() == pytest.approx(1.2 / (1 + 4 + 0.1), rel=0.1)


def _leak(rng, shape):
    """Dark ground of 0.01 beside a light of 100, the estimate leaking 0.5 onto four columns of the ground (within
    the light's noise, 5, and 50x the ground's level): the truth, the estimate, the means and their variances."""
    truth = np.full(shape, 0.01)
    truth[:, 16:] = 100.0
    variance = (0.05 * truth) ** 2
    mean = truth + np.sqrt(variance) * rng.standard_normal(shape)
    leak = truth.copy()
    leak[:, 12:16] += 0.5
    return truth, leak, mean, variance


def test_the_relative_criterion_protects_dark_pixels_next_to_a_light(rng):
    """A leak of a bright neighbour's light onto a dark ground: small in absolute terms (MSE
    keeps it), large relative to the ground (relMSE does not): the smaller share wins."""
    truth, leak, mean, variance = _leak(rng, SHAPE)
    out, lam = sure_blend(leak, mean, variance, np.full(SHAPE, 0.05), k=0.01)
    assert lam[:, 12:16].max() < 0.05
    assert np.abs(out[:, 12:16] - truth[:, 12:16]).max() < 0.01


def test_zero_variance_and_no_change_keep_the_mean(rng):
    truth, mean, _ = _flat(rng)
    out, lam = sure_blend(truth, mean, np.zeros(SHAPE), np.full(SHAPE, 0.5), k=0.1)
    assert_allclose(out, mean)  # nothing to remove: the change can only be bias
    out, lam = sure_blend(mean, mean, np.full(SHAPE, 0.01), np.full(SHAPE, 0.5), k=0.1)
    assert_allclose(out, mean) and (lam == 1.0).all()


def test_a_shared_leverage_plane_serves_every_channel(rng):
    truth, mean, variance = _flat(rng)
    three = lambda a: np.repeat(a, 3, axis=2)  # noqa: E731
    a, _ = sure_blend(three(truth), three(mean), three(variance), np.full(SHAPE[:2], 0.05), k=0.1)
    b, _ = sure_blend(truth, mean, variance, np.full(SHAPE, 0.05), k=0.1)
    assert_allclose(a, three(b))


def test_pixels_without_a_measurement_have_no_weight(rng):
    """Pixels whose means are copies (no samples of their own) are left out of the risk: a good estimate
    is kept whatever such a pixel's mean is off by; they keep the estimate themselves, and so does a window
    holding none."""
    truth, mean, variance = _flat(rng)
    lev = np.full(SHAPE, 0.05)
    measured = np.ones(SHAPE[:2], bool)
    measured[::2, ::2] = False  # a quarter of the pixels, scattered
    measured[:, 20:] = False  # and a hole
    copied = np.where(measured[..., None], mean, truth + 0.5)  # their means far off: an edge copied across
    kept, lam = sure_blend(truth, copied, variance, lev, k=0.1, measured=measured)
    assert lam[:, :12][measured[:, :12]].mean() > 0.85 and np.all(lam[~measured] == 1.0)
    assert_array_equal(kept[~measured], truth[~measured])
    _, counted = sure_blend(truth, copied, variance, lev, k=0.1)  # every mean taken as a measurement
    assert counted[:, :12].mean() < 0.5
    with pytest.raises(ValueError, match=r"measured: shape \(32, 32, 1\) is not the image's \(32, 32\)"):
        sure_blend(truth, mean, variance, lev, k=0.1, measured=measured[..., None])
    same, _ = sure_blend(truth, mean, variance, lev, k=0.1, measured=np.ones(SHAPE[:2], bool))
    assert_array_equal(same, sure_blend(truth, mean, variance, lev, k=0.1)[0])


@pytest.mark.parametrize(("kwargs", "message"), [({"k": 0.0}, "k"), ({"k": 0.1, "window": 4}, "window: must be odd"),
                                                 ({"k": 0.1, "window": 0}, "window"),
                                                 ({"k": 0.1, "tolerance": 0.9}, "tolerance: must be >= 1")])
def test_bad_arguments_are_refused(rng, kwargs, message):
    truth, mean, variance = _flat(rng)
    with pytest.raises(ValueError, match=message):
        sure_blend(truth, mean, variance, np.zeros(SHAPE), **kwargs)


def _plain_sure_blend(o, x, v, lev, k, window=9, tolerances=(1.0, 1.0), spared_beside=None):
    """The guard written out plainly (a new array per step): the in-place version's reference."""
    lev = lev[..., None] if lev.ndim == o.ndim - 1 else lev
    change, gain = o - x, v * (1.0 - lev)
    pooled = lambda a: window_sum(a, window)  # noqa: E731  (tests/test_window_sums.py holds it to plain sums)

    def share(num, den):
        num, den = pooled(num), pooled(den)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            lam = np.where(den > 0, num / den, 1.0)
        return np.clip(np.nan_to_num(lam, nan=1.0, posinf=1.0), 0.0, 1.0)

    squared, relative = change * change, 1.0 / (np.abs(o) + k) ** 2
    gain_s, gain_r = (gain if t == 1.0 else v * ((1.0 - lev) * t) for t in tolerances)
    if spared_beside is not None and tolerances[1] != 1.0:
        level = np.abs(o) if o.ndim == 2 else np.abs(o).max(axis=-1)
        brightest = np.array([[level[max(0, r - window // 2):r + window // 2 + 1,
                                     max(0, c - window // 2):c + window // 2 + 1].max()
                               for c in range(level.shape[1])] for r in range(level.shape[0])])
        beside = brightest > spared_beside * (level + k)
        gain_r = np.where(beside if o.ndim == 2 else beside[..., None], gain, gain_r)
    lam = np.minimum(share(gain_s, squared), share(gain_r * relative, squared * relative))
    return x + lam * change, lam


@pytest.mark.parametrize("shared_leverage", [False, True])
def test_the_in_place_guard_is_the_plain_formula_bit_for_bit(rng, shared_leverage):
    """Pooling in place and reusing buffers (for memory at 1080p and 4K) changes no bit, also where
    the sums are zero (no variance, no change) or overflow."""
    o = rng.lognormal(0.0, 2.0, (40, 36, 3))
    x = o * rng.uniform(0.5, 1.5, o.shape)
    v = rng.uniform(0.0, 0.5, o.shape) * o
    v[:12, :12] = 0.0
    x[20:32, 20:32] = o[20:32, 20:32]  # no change there
    v[30:, :4] = 1e300  # the ratio overflows
    lev = rng.uniform(0.0, 1.0, o.shape[:2] if shared_leverage else o.shape)
    got, lam = sure_blend(o, x, v, lev, k=0.05)
    want, want_lam = _plain_sure_blend(o, x, v, lev, 0.05)
    np.testing.assert_array_equal(lam, want_lam)
    np.testing.assert_array_equal(got, want)
    assert not np.shares_memory(got, x) and not np.shares_memory(got, o)


@pytest.mark.parametrize("tolerance", [1.2, (1.2, 1.0), (1.0, 1.5), (1.5, 1.2)])
def test_a_pair_of_tolerances_gives_each_criterion_its_own(rng, tolerance):
    """``tolerance=(squared, relative)``: the plain formula with each criterion's gain scaled by its own; one
    number is the pair of it twice. Next to a small bright light the relative criterion's tolerance lets a rim
    through that the squared one's does not (docs/reconstruction.md, "The guard's tolerance without a guide")."""
    o = rng.lognormal(0.0, 2.0, (40, 36, 3))
    x = o * rng.uniform(0.5, 1.5, o.shape)
    v = rng.uniform(0.0, 0.5, o.shape) * o
    lev = rng.uniform(0.0, 1.0, o.shape)
    pair = tolerance if isinstance(tolerance, tuple) else (tolerance, tolerance)
    got, lam = sure_blend(o, x, v, lev, k=0.05, tolerance=tolerance)
    want, want_lam = _plain_sure_blend(o, x, v, lev, 0.05, tolerances=pair)
    np.testing.assert_array_equal(lam, want_lam)
    np.testing.assert_array_equal(got, want)
    with pytest.raises(ValueError, match="tolerance: a pair"):
        sure_blend(o, x, v, lev, k=0.05, tolerance=(1.2, 1.2, 1.2))
    with pytest.raises(ValueError, match="tolerance: must be >= 1"):
        sure_blend(o, x, v, lev, k=0.05, tolerance=(1.2, 0.5))


@pytest.mark.parametrize("tolerance", [1.2, (1.0, 1.5), (1.5, 1.0)])
def test_a_rim_beside_a_light_keeps_the_strict_relative_criterion(rng, tolerance):
    """``spared_beside``: where a pixel's window holds one brighter than that many times its own level, the relative
    criterion's tolerance stays 1 (the plain formula, its window maximum written out); elsewhere, and without a
    relative tolerance, nothing changes."""
    o = rng.lognormal(0.0, 1.0, (30, 28, 3))
    o[10:13, 10:13] *= 1000.0  # a light
    x = o * rng.uniform(0.5, 1.5, o.shape)
    v = rng.uniform(0.0, 0.5, o.shape) * o
    lev = rng.uniform(0.0, 1.0, o.shape[:2])
    pair = tolerance if isinstance(tolerance, tuple) else (tolerance, tolerance)
    got, lam = sure_blend(o, x, v, lev, k=0.05, tolerance=tolerance, spared_beside=10.0)
    want, want_lam = _plain_sure_blend(o, x, v, lev, 0.05, tolerances=pair, spared_beside=10.0)
    np.testing.assert_array_equal(lam, want_lam)
    np.testing.assert_array_equal(got, want)
    if pair[1] == 1.0:
        np.testing.assert_array_equal(lam, sure_blend(o, x, v, lev, k=0.05, tolerance=tolerance)[1])
    with pytest.raises(ValueError, match="spared_beside: must be > 1"):
        sure_blend(o, x, v, lev, k=0.05, spared_beside=1.0)


@pytest.mark.parametrize(("shape", "leverage_shape"), [((32, 32), (32, 32)), ((32, 32, 3), (32, 32)),
                                                       ((32, 32, 3), (32, 32, 1)), ((32, 32, 3), (32, 32, 3))])
@pytest.mark.parametrize("extra", ["plain", "measured", "threads"])
def test_the_spared_guard_is_the_plain_formula_where_sparing_binds(rng, shape, leverage_shape, extra):
    """Beside a light, where sparing moves lambda: the in-place spared path is the plain formula bit for bit,
    for one plane (luminance mode: each pixel's own level, not a row's) and for channels with every leverage
    layout; unmeasured pixels keep lambda 1 and the criteria on threads give the same bits."""
    _, leak, mean, variance = _leak(rng, shape)
    if len(shape) == 3:
        leak, mean, variance = (a * np.array([1.0, 0.6, 1.4]) ** p for a, p in ((leak, 1), (mean, 1), (variance, 2)))
    lev = rng.uniform(0.0, 0.2, leverage_shape)
    options = {"k": 0.01, "tolerance": (1.0, 1.5)}
    got, lam = sure_blend(leak, mean, variance, lev, spared_beside=10.0, **options)
    unspared = sure_blend(leak, mean, variance, lev, **options)[1]
    assert not np.array_equal(lam, unspared)  # sparing binds here
    want, want_lam = _plain_sure_blend(leak, mean, variance, lev, 0.01, tolerances=(1.0, 1.5), spared_beside=10.0)
    np.testing.assert_array_equal(lam, want_lam)
    np.testing.assert_array_equal(got, want)
    if extra == "measured":
        measured = np.ones(shape[:2], bool)
        measured[::7, ::5] = False
        masked = sure_blend(leak, mean, variance, lev, spared_beside=10.0, measured=measured, **options)[1]
        assert (masked[~measured] == 1.0).all() and not np.array_equal(
            masked, sure_blend(leak, mean, variance, lev, measured=measured, **options)[1])
    if extra == "threads":
        with ThreadPoolExecutor(2) as pool:
            threaded = sure_blend(leak, mean, variance, lev, spared_beside=10.0,
                                  run=lambda f, items: list(pool.map(f, items)), **options)
        np.testing.assert_array_equal(threaded[1], lam)
        np.testing.assert_array_equal(threaded[0], got)


@pytest.mark.parametrize("shape", [SHAPE, SHAPE[:2]], ids=["channels", "one plane"])
def test_sparing_the_rim_undoes_more_of_a_leak_of_light_onto_dark_ground(rng, shape):
    """The leak of :func:`test_the_relative_criterion_protects_dark_pixels_next_to_a_light`: a relative tolerance
    of 1.5 keeps more of it; spared beside the light, less, and far from the light the share is the same. So too
    on one (H, W) plane, as the luminance mode's guard takes it."""
    _, leak, mean, variance = _leak(rng, shape)
    lev = np.full(shape, 0.05)
    strict = sure_blend(leak, mean, variance, lev, k=0.01)[1]
    tolerant = sure_blend(leak, mean, variance, lev, k=0.01, tolerance=(1.0, 1.5))[1]
    spared = sure_blend(leak, mean, variance, lev, k=0.01, tolerance=(1.0, 1.5), spared_beside=10.0)[1]
    assert tolerant[:, 12:16].mean() > strict[:, 12:16].mean()
    assert spared[:, 12:16].mean() < tolerant[:, 12:16].mean()
    np.testing.assert_array_equal(spared[:, :3], tolerant[:, :3])  # no light within the window: not spared


def test_the_criteria_on_threads_give_the_same_bits(rng):
    """With ``run`` the two criteria's window sums run side by side: blend and lambda unchanged."""
    x = rng.lognormal(0, 2, (30, 26, 3))
    v = rng.random(x.shape) * 0.3
    o = x * rng.uniform(0.7, 1.3, x.shape)
    lev = rng.uniform(0, 0.5, x.shape)
    serial = sure_blend(o, x, v, lev, k=0.05)
    with ThreadPoolExecutor(2) as pool:
        threaded = sure_blend(o, x, v, lev, k=0.05, run=lambda f, items: list(pool.map(f, items)))
    for a, b in zip(serial, threaded):
        assert_array_equal(a.view(np.int64), b.view(np.int64))


@pytest.mark.parametrize("firefly", [1e5, 1e8])
def test_a_firefly_leaves_the_share_outside_its_windows_as_it_is(rng, firefly):
    """Pixels whose window does not hold a removed firefly get the share they get without it: the running sums
    (scipy's uniform_filter) carried its rounding error along the lines, 0.2 off at 1e7 (a red-team pass)."""
    x = 0.5 + 0.05 * rng.standard_normal((48, 48, 1))
    v = np.full(x.shape, 0.0025)
    o = 0.5 + 0.01 * rng.standard_normal(x.shape)
    lev = np.full(x.shape[:2], 0.1)
    _, quiet = sure_blend(o, x, v, lev, k=0.05)
    x[10, 10], v[10, 10] = firefly, firefly**2 / 4
    _, lam = sure_blend(o, x, v, lev, k=0.05)
    far = np.ones(x.shape[:2], bool)
    far[6:15, 6:15] = False  # the windows of 9 that hold (10, 10)
    assert_allclose(lam[far], quiet[far], rtol=1e-12)
