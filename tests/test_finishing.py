"""The output's guarantees: the pooled pixel clamp, non-negativity, the exact image mean."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from scipy import ndimage

from awr_denoise import SampleBuffer, finishing, reconstruct
from awr_denoise.finishing import (_FILL_STEPS, POOL_CHANCE, RESTORE_SHARE, _fill, clip_negative, match_mean,
                                   median3x3, pooled_clamp, pooled_standard_error, restore_mean)


@pytest.mark.parametrize("shape", [(1, 1), (1, 5), (2, 3, 1), (3, 3), (17, 11, 3), (64, 48, 2)])
def test_median3x3_is_scipys_median_filter(rng, shape):
    """Against the reference, with ties (small integers) and without (random floats)."""
    for a in (rng.random(shape), rng.integers(0, 3, shape).astype(float)):
        size = (3, 3) + (1,) * (a.ndim - 2)
        assert_array_equal(median3x3(a), ndimage.median_filter(a, size=size, mode="nearest"))


def test_pooled_standard_error_is_the_larger_of_own_and_neighbourhood_median():
    v = np.full((5, 5, 1), 4.0)
    v[2, 2] = 0.0  # a pixel whose few samples agreed by chance
    v[0, 0] = 100.0  # a lone noisy pixel does not widen its neighbours' intervals
    s = pooled_standard_error(v)
    assert s[2, 2, 0] == 2.0 and s[0, 0, 0] == 10.0 and s[0, 1, 0] == 2.0


def test_pooled_clamp_keeps_pixels_within_z_pooled_standard_errors(rng):
    mean = rng.random((6, 7, 3))
    variance = rng.uniform(0.0, 0.01, mean.shape)
    image = mean + rng.normal(0.0, 0.5, mean.shape)
    out, moved = pooled_clamp(image, mean, variance, 2.0)
    reach = 2.0 * pooled_standard_error(variance)
    assert (np.abs(out - mean) <= reach + 1e-15).all()
    assert_array_equal(out[~moved], image[~moved])
    assert moved.any() and not moved.all()


def _gated_pooled_error_by_definition(variance, mean, count):
    """POOL_CHANCE's definition, pixel by pixel: the upper median, over the 3x3 neighbours (edges repeated) with
    z^n >= POOL_CHANCE, z = S^2 / (S^2 + g^2), g = max(|m - c| - s_px (n - 1) / sqrt(n), 0), of the error S / sqrt(n)
    the pixel's mean would have with the neighbour's per-sample deviation S."""
    s = np.sqrt(variance)
    out = np.empty_like(s)
    h, w = s.shape[:2]
    for index in np.ndindex(s.shape):
        i, j, rest = index[0], index[1], index[2:]
        n, c, own = count[i, j], mean[index], s[index] * np.sqrt(count[i, j])  # per-sample deviations
        kept = []
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                a, b = min(max(i + di, 0), h - 1), min(max(j + dj, 0), w - 1)
                big_s2 = variance[(a, b) + rest] * count[a, b]
                g = max(abs(mean[(a, b) + rest] - c) - own * (n - 1) / np.sqrt(n), 0.0)
                z = 1.0 if big_s2 + g * g == 0 else big_s2 / (big_s2 + g * g)
                if z**n >= POOL_CHANCE:
                    kept.append(np.sqrt(big_s2 / n))
        out[index] = max(s[index], sorted(kept)[len(kept) // 2])
    return out


@pytest.mark.parametrize("shape", [(1, 1, 1), (2, 5, 1), (7, 6, 2), (9, 8)])
def test_pooled_standard_error_with_counts_pools_the_neighbours_the_samples_could_come_from(rng, shape):
    for _ in range(3):
        count = rng.integers(1, 20, shape[:2]).astype(float)
        mean = rng.choice([0.01, 0.5, 1.0, 100.0], shape) * rng.uniform(0.9, 1.1, shape)
        variance = (rng.uniform(0.0, 0.6, shape) * mean) ** 2 / count.reshape(count.shape + (1,) * (len(shape) - 2))
        variance[rng.random(shape) < 0.1] = 0.0
        expected = _gated_pooled_error_by_definition(variance, mean, count)
        assert_allclose(pooled_standard_error(variance, mean, count), expected, rtol=1e-12, atol=0)


def test_a_pixel_of_many_samples_keeps_its_own_interval_beside_neighbours_of_few():
    """An adaptive render's mix: pixels of 4 samples beside pixels of 4096 or 2**20, one distribution everywhere.
    What pools is a neighbour's per-sample deviation over the pixel's own count, so a precise pixel's interval stays
    its own: pooling the neighbours' standard errors held it at a 4-sample pixel's, 33 and 625 of its own standard
    errors from its mean in the reconstruction, its error not falling with its samples (an attack pass)."""
    count = np.full((3, 3), 4.0)
    count[1, 1] = 4096.0
    mean = np.full((3, 3, 1), 1.0)
    variance = 0.04 / count[..., None]              # the same per-sample variance, 0.04, everywhere
    pooled = pooled_standard_error(variance, mean, count)
    assert_allclose(pooled[1, 1], np.sqrt(variance[1, 1]), rtol=1e-15)
    assert_allclose(pooled[0, 0], np.sqrt(variance[0, 0]), rtol=1e-15)  # and the few's is their own too
    rng = np.random.default_rng(3)
    shape = (32, 32)
    clean = (0.5 + 0.3 * (np.arange(shape[1]) > 16))[None, :, None] * np.ones(shape + (3,))
    for many in (4096, 2**20):
        counts = np.where(rng.random(shape) < 0.5, 4, many)
        error = np.sqrt(0.04 / counts)[..., None]
        means = clean + error * rng.standard_normal(clean.shape)
        out = reconstruct(SampleBuffer.from_moments(counts, means, np.full(clean.shape, 0.04)))
        precise = counts == many
        assert np.abs(out - means)[precise].max() <= (2.5 + 1e-9) * error[precise].max()


def test_a_count_of_zero_from_a_direct_caller_counts_as_one_sample():
    """``pooled_clamp`` and ``pooled_standard_error`` are public: a count of 0 (the reconstruction passes at least 1)
    pooled an infinite error, so the pixel was never clamped, and an infinite variance beside it warned (a review)."""
    import warnings

    count = np.full((3, 3), 4.0)
    count[1, 1] = 0.0
    variance, mean = np.full((3, 3, 1), 0.01), np.ones((3, 3, 1))
    image = mean.copy()
    image[1, 1] = 5.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = pooled_standard_error(variance, mean, count)
        out = pooled_clamp(image, mean, variance, 2.5, count=count)[0]
        count[0, 0], variance[0, 0] = 0.0, np.inf
        pooled_standard_error(variance, mean, count)
    assert s[1, 1, 0] == 0.2  # the neighbours' per-sample deviation, 0.1 * sqrt(4), over one sample
    assert out[1, 1, 0] == 1.0 + 2.5 * 0.2


def test_the_nine_value_sorting_network_sorts_every_input():
    """By the 0-1 principle a comparator network that sorts every input of 0s and 1s sorts every input."""
    for bits in itertools.product((0, 1), repeat=9):
        values = list(bits)
        for i, j in finishing._SORT9:
            values[i], values[j] = min(values[i], values[j]), max(values[i], values[j])
        assert values == sorted(bits)


def test_a_dark_line_keeps_its_own_interval_a_pixel_that_missed_a_tail_does_not():
    """8 samples a pixel. A line of 0.01 (samples 0.01 +- 0.005) in a field of 1 with 50% noise: the field
    cannot have given those samples (Cantelli: 0.19^8 = 2e-6 < POOL_CHANCE), so the line's interval is its
    own. A pixel whose 8 samples all missed a tail of 20 that its neighbours caught now and then (samples
    0.2, or 20 with chance 0.05): z = 1 / (1 + 0.05) per sample, 0.68 for 8, so it pools as before."""
    count = np.full((3, 3), 8.0)
    mean = np.full((3, 3, 1), 1.0)
    mean[:, 1] = 0.01
    variance = (0.5 * mean) ** 2 / 8
    gated = pooled_standard_error(variance, mean, count)
    assert_array_equal(gated[:, 1], np.sqrt(variance[:, 1]))
    assert_array_equal(pooled_standard_error(variance)[:, 1], np.sqrt(variance[:, 0]))  # without counts
    tail = np.full((3, 3, 1), 0.2 + 0.05 * 19.8)  # mean 1.19, per-sample variance 0.05 * 0.95 * 19.8^2
    tail_variance = np.full((3, 3, 1), 0.05 * 0.95 * 19.8**2 / 8)
    tail[1, 1], tail_variance[1, 1] = 0.2, 0.0
    assert_array_equal(pooled_standard_error(tail_variance, tail, count)[1, 1], np.sqrt(tail_variance[0, 0]))


def test_pool_chance_zero_pools_every_neighbour(rng, monkeypatch):
    mean = rng.choice([0.01, 1.0, 100.0], (8, 9, 2))
    variance = (0.5 * mean) ** 2 / 8
    image = mean + rng.normal(0.0, 50.0, mean.shape)
    count = np.full((8, 9), 8.0)
    assert not np.array_equal(pooled_clamp(image, mean, variance, 2.5, count=count)[0],
                              pooled_clamp(image, mean, variance, 2.5)[0])
    monkeypatch.setattr(finishing, "POOL_CHANCE", 0.0)
    assert_array_equal(pooled_standard_error(variance, mean, count), pooled_standard_error(variance))
    assert_array_equal(pooled_clamp(image, mean, variance, 2.5, count=count)[0],
                       pooled_clamp(image, mean, variance, 2.5)[0])


def test_the_clamps_test_is_exact_under_power_of_two_scaling(rng):
    """Ratios of standard errors and gaps only: scaling every value by 2^k changes nothing but the scale, from
    1e-150 to 1e150 (no square of a value is formed)."""
    count = rng.integers(1, 16, (10, 12)).astype(float)
    mean = rng.choice([0.01, 1.0, 100.0], (10, 12, 1))
    variance = (rng.uniform(0.1, 0.6, mean.shape) * mean) ** 2 / count[..., None]
    image = mean * rng.uniform(0.0, 3.0, mean.shape)
    out = pooled_clamp(image, mean, variance, 2.5, count=count)[0]
    for k in (-498, 498):
        f = 2.0**k
        assert_array_equal(pooled_clamp(image * f, mean * f, variance * f * f, 2.5, count=count)[0], out * f)


def test_pooled_clamp_in_luminance_keeps_hue():
    weights = np.array([0.2, 0.7, 0.1])
    mean_rgb = np.full((4, 4, 3), [1.0, 2.0, 3.0])
    lum = mean_rgb @ weights
    image = 3.0 * mean_rgb
    out, moved = pooled_clamp(image, lum, np.full((4, 4), 0.01), 2.5, weights=weights)
    assert_allclose(out @ weights, lum + 0.25)
    assert_allclose(out / out[..., :1], mean_rgb / mean_rgb[..., :1])  # channel ratios kept
    assert moved.all()


def test_clip_negative_only_in_channels_without_negative_means():
    image = -np.ones((2, 2, 2))
    mean = np.zeros((2, 2, 2))
    mean[0, 0, 1] = -1.0
    out, clipped = clip_negative(image, mean)
    assert_array_equal(out[..., 0], 0.0)
    assert_array_equal(out[..., 1], -1.0)
    assert clipped[..., 0].all() and not clipped[..., 1].any()


@pytest.mark.parametrize("scale", [1e-300, 1e-3, 1.0, 1e300])
def test_match_mean_makes_every_channel_mean_exact(rng, scale):
    mean = scale * rng.random((8, 9, 3))
    image = mean * rng.uniform(0.9, 1.1, mean.shape)
    out, factors = match_mean(image, mean)
    assert_allclose(out.mean(axis=(0, 1)), mean.mean(axis=(0, 1)), rtol=1e-13)
    assert (factors > 0).all()


def test_match_mean_leaves_channels_without_a_positive_mean():
    mean = np.zeros((2, 2, 2))
    mean[..., 1] = -1.0
    image = np.ones((2, 2, 2))
    out, factors = match_mean(image, mean)
    assert_array_equal(out, image)
    assert_array_equal(factors, [1.0, 1.0])


def test_match_mean_changes_the_exposure_by_more_than_the_limit_only_when_significant(rng):
    mean = rng.random((8, 9, 2))
    image = mean * np.array([0.5, 3.0])
    assert_allclose(match_mean(image, mean)[1], [1.05, 1 / 1.05])  # no variances: never significant
    assert_allclose(match_mean(image, mean, np.full(mean.shape, 1e-6))[1], [2.0, 1 / 3])
    noisy = np.full(mean.shape, 100.0)  # the input's mean has a standard error of ~1.1
    assert_allclose(match_mean(image, mean, noisy)[1], [1.05, 1 / 1.05])
    assert_allclose(match_mean(mean * 0.8, mean, noisy, limit=0.5)[1], 1.25)


@pytest.mark.parametrize("shape", [(1, 1, 1), (1, 6, 2), (9, 1, 3), (23, 31, 3)])
def test_pooled_clamp_is_the_plain_clip_to_pooled_errors_bit_for_bit(rng, shape):
    """The clamp pools (3x3 medians) only where a value leaves its own interval; the result is the
    clip to ``z * pooled_standard_error`` everywhere, in channel and in luminance mode."""
    for _ in range(5):
        variance = rng.random(shape) ** 3 * (rng.random(shape) < 0.9)  # zeros: pixels whose samples agreed
        mean = rng.random(shape)
        image = mean + rng.normal(0.0, 1.0, shape) * np.sqrt(variance) * rng.uniform(0.0, 5.0, shape)
        count = rng.integers(1, 9, shape[:2]).astype(float)
        for counts in (None, count):
            reach = 2.5 * (pooled_standard_error(variance) if counts is None else
                           pooled_standard_error(variance, mean, counts))
            out, moved = pooled_clamp(image, mean, variance, 2.5, count=counts)
            expected = np.clip(image, mean - reach, mean + reach)
            assert_array_equal(out, expected)
            assert_array_equal(moved, expected != image)
        weights = rng.dirichlet(np.ones(shape[2]))
        lum, lum_variance = mean @ weights, variance @ weights
        reach = 2.5 * pooled_standard_error(lum_variance)
        target = np.clip(image @ weights, lum - reach, lum + reach)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(image @ weights != 0, target / (image @ weights), 1.0)
        out, moved = pooled_clamp(image, lum, lum_variance, 2.5, weights=weights)
        assert_array_equal(out, image * ratio[..., None])
        assert_array_equal(moved, np.broadcast_to((ratio != 1.0)[..., None], shape))


def _fill_by_bisection(weight, cap, total):
    """Reference for _fill: bisection on mu of sum(min(mu * weight, cap)) = total."""
    lo, hi = 0.0, 1.0
    while np.minimum(hi * weight, cap).sum() < total:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.minimum(mid * weight, cap).sum() < total else (lo, mid)
    return np.minimum(hi * weight, cap)


@pytest.mark.parametrize("steps", [_FILL_STEPS, 0], ids=["iterated", "sorted"])
@pytest.mark.parametrize("seed", range(6))
def test_fill_is_exact_water_filling(seed, steps):
    """Both ways (the iteration, and the sort it falls back to after ``steps``) against bisection."""
    rng = np.random.default_rng(seed)
    weight = rng.random((13, 7)) + 0.01
    cap = rng.random((13, 7)) ** 3 * (rng.random((13, 7)) < 0.7)
    for total in (0.0, 0.01 * cap.sum(), 0.5 * cap.sum(), 0.999 * cap.sum(), cap.sum()):
        delta = _fill(weight, cap, total, steps=steps)
        assert delta.sum() == pytest.approx(total, rel=1e-12, abs=1e-15)
        assert (delta >= 0).all() and (delta <= cap).all()
        if 0 < total < cap.sum():
            assert_allclose(delta, _fill_by_bisection(weight, cap, total), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("scale", [1e-300, 1e-3, 1.0, 1e300])
def test_restore_mean_makes_every_channel_mean_exact(rng, scale):
    mean = scale * rng.random((8, 9, 3))
    image = mean * rng.uniform(0.8, 1.15, mean.shape)
    out, t = restore_mean(image, mean, np.zeros(mean.shape))  # exact means: every change significant
    assert_allclose(out.mean(axis=(0, 1)), mean.mean(axis=(0, 1)), rtol=1e-12)
    assert ((t >= 0) & (t <= 1)).all()


def test_restore_mean_moves_only_the_pixels_that_lost_energy_and_never_past_their_mean(rng):
    """A bright, noisy pixel the stages left at its mean is not scaled (match_mean scaled it: its
    noise grew with the factor); the others move towards their own means, never past them."""
    mean = 1.0 + 0.02 * rng.standard_normal((16, 16, 1))  # every gap within RESTORE_SHARE of its level
    mean[8, 8] = 1000.0
    image = mean.copy()
    image[mean > 1.0] = 1.0 + 0.5 * (mean[mean > 1.0] - 1.0)  # the stages halved every upward deviation...
    image[8, 8] = 1000.0                                       # ...except the light's
    variance = np.full(mean.shape, 1e-6)
    out, _ = restore_mean(image, mean, variance)
    assert out.mean() == pytest.approx(mean.mean(), rel=1e-12)
    assert out[8, 8, 0] == 1000.0
    untouched = image >= mean
    assert_array_equal(out[untouched], image[untouched])
    low, high = np.minimum(image, mean), np.maximum(image, mean)
    assert ((out >= low) & (out <= high)).all()
    assert match_mean(image, mean, variance)[0][8, 8, 0] > 1000.0


def test_restore_mean_caps_each_pixel_and_spreads_the_rest_by_brightness():
    """Real energy removed (a pixel cut to a tenth): it takes back at most RESTORE_SHARE of its
    level; the rest goes to every pixel in proportion to its level."""
    mean = np.ones((4, 4, 1))
    mean[0, 0] = 50.0
    image = np.ones((4, 4, 1))
    image[0, 0] = 5.0
    out, _ = restore_mean(image, mean, np.full(mean.shape, 1e-9))
    assert out.mean() == pytest.approx(mean.mean(), rel=1e-12)
    ratio = out[..., 0] / image[..., 0]
    others = np.ones((4, 4), bool)
    others[0, 0] = False
    assert_allclose(ratio[others], ratio[others][0])           # one factor for the untouched pixels
    assert ratio[0, 0] > ratio[others][0]                       # and the cut pixel's capped share on top
    assert out[0, 0, 0] - image[0, 0, 0] > RESTORE_SHARE * 5.0


def test_restore_mean_never_pushes_a_brightened_channel_below_zero():
    """A channel the stages brightened far beyond its caps: its rest is taken from the image the caps left, so a
    pixel of mean 0 the stages lifted a little (its cap takes it back to 0) is not pushed below 0."""
    mean = np.zeros((4, 4, 1))
    mean[0, 0] = 1.0
    image = np.full((4, 4, 1), 0.5)
    image[0, 0] = 1.0
    image[3, 3] = 1e-7                                          # lifted a little: its whole gap is its cap
    out, _ = restore_mean(image, mean, np.full(mean.shape, 1e-9))
    assert out.mean() == pytest.approx(mean.mean(), rel=1e-12)
    assert out.min() >= 0.0
    moved = out[..., 0] / image[..., 0]
    assert_allclose(moved[1:3, 1:3], moved[1, 1])               # one factor over the pixels the caps left alike


def test_restore_mean_bounds_an_insignificant_change_and_leaves_channels_of_two_signs(rng):
    mean = rng.random((8, 9, 2))
    image = mean * np.array([0.5, 1.0])
    image[..., 1] = -image[..., 1]                              # a channel whose output mean is negative
    out, _ = restore_mean(image, mean, np.full(mean.shape, 100.0))
    assert out[..., 0].mean() == pytest.approx(1.05 * image[..., 0].mean(), rel=1e-12)
    assert_array_equal(out[..., 1], image[..., 1])
    out, _ = restore_mean(image, mean, np.full(mean.shape, 1e-6))
    assert out[..., 0].mean() == pytest.approx(mean[..., 0].mean(), rel=1e-12)


@pytest.mark.parametrize("variance", [1e-6, 100.0])
def test_restore_mean_restores_a_negative_channel_as_its_mirror_image(rng, variance):
    """A channel of negative mean (an AOV's) was left as it was, 2% off its image mean where the same image positive
    was exact (an attack pass); and the bound of an insignificant change, taken on the signed mean, was wrong for it.
    Now the map is odd, bit for bit, significant or bounded."""
    mean = rng.random((8, 9, 2)) + 0.1
    image = mean * np.array([0.9, 0.5])
    out, share = restore_mean(image, mean, np.full(mean.shape, variance))
    negated, negated_share = restore_mean(-image, -mean, np.full(mean.shape, variance))
    assert_array_equal(negated, -out)
    assert_array_equal(negated_share, share)
    assert not np.array_equal(negated, -image)
    if variance < 1:  # significant: exact
        np.testing.assert_allclose(negated.mean(axis=(0, 1)), -mean.mean(axis=(0, 1)), rtol=1e-12)
    else:  # not significant: 5% of the output's mean at most, in magnitude
        np.testing.assert_allclose(negated[..., 1].mean(), 1.05 * -image[..., 1].mean(), rtol=1e-12)


def test_restore_mean_on_threads_gives_the_same_bits():
    """The channels on an executor's threads: each channel is independent, so the same result."""
    from concurrent.futures import ThreadPoolExecutor

    from awr_denoise.finishing import restore_mean

    rng = np.random.default_rng(12)
    mean = rng.random((40, 30, 3)) + 0.1
    mean[..., 2] *= -1  # a channel it leaves as it is
    image = mean * (0.9 + 0.1 * rng.random(mean.shape))
    variance = np.full(mean.shape, 1e-4)
    serial = restore_mean(image, mean, variance)
    with ThreadPoolExecutor(2) as pool:
        threaded = restore_mean(image, mean, variance, run=lambda f, items: list(pool.map(f, items)))
    for a, b in zip(serial, threaded):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(serial[0][..., 0], image[..., 0])  # the energy came back to channel 0
