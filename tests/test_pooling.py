"""Variances borrowed from neighbours: unknown ones pooled, ones whose samples all agreed moderated."""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy import ndimage

from awr_denoise import AdaptiveSampler, SampleBuffer, fused, pooling, reconstruct, rims
from awr_denoise.pooling import AGREED_PRIOR, POOL_WINDOW, agreed_variance, estimated_variance
from awr_denoise.prepare import prepare

needs_numba = pytest.mark.skipif(fused._compiled() is None, reason="numba is not installed (extra 'fast')")


@pytest.fixture(autouse=True, params=["numpy", pytest.param("numba", marks=needs_numba)])
def kernels(request):
    """Every test with each backend: numpy's offset-by-offset moderation (the reference) and the compiled loop
    (``AWR_DENOISE_KERNELS=numba``), each against the pixel-by-pixel definition below."""
    with fused.using(request.param):
        yield request.param


def _reference(count, mean, variance, known, prior=AGREED_PRIOR):
    """agreed_variance written out pixel by pixel (the window's edges repeated, as ``mode="nearest"``); a light's
    rim lends nothing (``rims.coverage_edges``, held to its own definition in tests/test_rims.py)."""
    h, w, channels = mean.shape
    r = POOL_WINDOW // 2
    out = np.array(variance)
    known_pixels = np.asarray(known)[..., None]
    rim = rims.coverage_edges(count, mean, variance, known_pixels & (variance == 0),
                              known_pixels & (np.asarray(count)[..., None] >= 2) & (variance > 0),
                              window=POOL_WINDOW, jump_ratio=pooling.JUMP_RATIO)
    rim = np.zeros(mean.shape, bool) if rim is None else rim
    for i in range(h):
        for j in range(w):
            for c in range(channels):
                if not known[i, j] or variance[i, j, c] != 0:
                    continue
                num = den = 0.0
                for y in range(i - r, i + r + 1):
                    for x in range(j - r, j + r + 1):
                        yy, xx = min(max(y, 0), h - 1), min(max(x, 0), w - 1)
                        if not known[yy, xx] or rim[yy, xx, c]:
                            continue
                        s2, gap = variance[yy, xx, c], mean[yy, xx, c] - mean[i, j, c]
                        with np.errstate(over="ignore"):  # a gap past float64 is a chance of 0
                            z = s2 / (s2 + gap**2) if s2 > 0 else float(gap == 0)
                        weight = (count[yy, xx] - 1) * z ** count[i, j]
                        num, den = num + weight * s2, den + weight
                out[i, j, c] = prior * num / den / (count[i, j] - 1 + prior)
    return out


def _hit_or_zero(rng, shape=(12, 14), spp=3, p=0.15, channels=2):
    pixel = np.repeat(np.arange(shape[0] * shape[1]), spp)
    values = (rng.random((pixel.size, channels)) < p) * rng.uniform(1.0, 5.0, (pixel.size, channels))
    return SampleBuffer.from_samples(pixel, values, shape)


def test_matches_the_pixel_by_pixel_definition(rng):
    """Samples that are a hit or exactly 0, counts 1-5 (single samples unknown), two channels."""
    buf = _hit_or_zero(rng)
    count = rng.integers(1, 6, buf.shape)
    buf = SampleBuffer.from_moments(count, buf.mean, buf.variance)
    assert ((buf.variance == 0) & buf.variance_known[..., None]).sum() > 20
    got = agreed_variance(buf.count, buf.mean, buf.variance, buf.variance_known)
    assert_allclose(got, _reference(buf.count, buf.mean, buf.variance, buf.variance_known), rtol=1e-12, atol=0)
    assert (got[(buf.variance == 0) & buf.variance_known[..., None]] > 0).any()


def test_pixels_that_missed_among_hits_are_not_exact(rng):
    """Before: a pixel whose samples all missed had variance 0, held at 0 by every stage and the clamp."""
    buf = _hit_or_zero(rng, shape=(16, 16), spp=2, p=0.1, channels=1)
    missed = (buf.variance == 0)[..., 0] & buf.variance_known
    prepared = prepare(buf, "log")
    assert (prepared.variance[missed] > 0).mean() > 0.9
    lum = prepare(buf, "log", luminance=True)  # the luminance plane borrows as the channels do
    assert (lum.variance[missed] > 0).mean() > 0.9


def test_a_region_that_all_agreed_stays_exact():
    """Constant pixels (a black background, a flat emitter seen directly) with no spread anywhere near."""
    count = np.full((9, 9), 4)
    mean = np.zeros((9, 9, 3))
    mean[:, 5:] = 7.0
    variance = np.zeros_like(mean)
    assert agreed_variance(count, mean, variance, count >= 2) is variance
    variance[:, 8] = 0.5  # spread 3 or more pixels from the black ones: out of their window
    out = agreed_variance(count, mean, variance, count >= 2)
    assert_array_equal(out[:, :6], 0.0)
    assert (out[:, 6:8] > 0).all()


def test_a_steady_light_lends_next_to_nothing():
    """Zeros beside pixels that are never 0 (a light of 100, sd 10) borrow z^n of their spread,
    z = 100 / (100 + 100^2); beside pixels that are 0 half the time (z = 1/2) they borrow much more."""
    count = np.full((5, 6), 8)
    mean = np.zeros((5, 6, 1))
    variance = np.zeros_like(mean)
    mean[:, 3:], variance[:, 3:] = 100.0, 100.0
    steady = agreed_variance(count, mean, variance, count >= 2)[:, 2, 0]
    variance[:, 3:] = 100.0**2 * 8 / 7  # samples of 200 and 0, half each: mean 100
    sometimes = agreed_variance(count, mean, variance, count >= 2)[:, 2, 0]
    assert (steady > 0).all() and (steady < 1e-10).all()
    assert (sometimes > 1e7 * steady).all()


def _light_on_black(spp, seed=0, level=100.0, background=0.0, shape=(24, 24), radius=4.5):
    """A disc of ``level`` on an exact ``background`` whose samples land uniformly in each pixel: the rim's hit or
    miss, every other pixel exact (a light seen directly against an empty backdrop)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    pixel = np.repeat(np.arange(h * w), spp)
    y = pixel // w + rng.random(pixel.size)
    x = pixel % w + rng.random(pixel.size)
    inside = (y - h / 2 - 0.3) ** 2 + (x - w / 2 - 0.2) ** 2 < radius**2
    values = np.where(inside, level, background)[:, None] * np.ones((1, 3))
    return SampleBuffer.from_samples(pixel, values, shape)


@pytest.mark.parametrize("spp", [2, 4, 16])
def test_a_lights_rim_lends_the_exact_background_nothing(spp):
    """Before: the background's zeros borrowed the rim's spread (a rim pixel is 0 whenever its samples miss), and the
    stages spread the light into them (relMSE hundreds of times the plain mean's: benchmarks/bench_limits.py). Its
    samples are all at the inside's level or the background's: a coverage of the two, not noise."""
    buf = _light_on_black(spp)
    missed = buf.variance_known & (buf.mean[..., 0] == 0)
    rim = (buf.variance[..., 0] > 0) & buf.variance_known
    assert rim.sum() >= 8 and missed.sum() > 100
    out = agreed_variance(buf.count, buf.mean, buf.variance, buf.variance_known)
    assert_array_equal(out[missed], 0.0)
    assert_array_equal(out[rim], buf.variance[rim])  # the rim keeps its own
    assert_allclose(out, _reference(buf.count, buf.mean, buf.variance, buf.variance_known), rtol=1e-12, atol=0)
    image = reconstruct(buf)
    assert np.abs(image[missed & (np.abs(np.arange(24)[:, None] - 12) > 7)]).max() == 0.0
    assert image[missed].max() < 1e-6 * 100


def test_single_samples_beside_a_lights_rim_pool_none_of_its_spread():
    """A pixel of one sample has no variance of its own; pooled from its window, it took the rim's spread before
    (half the pixels of a ring beside a light of one sample: the halo again). The rim lends it nothing, as it
    lends the pixels whose samples all agreed nothing: the black beside the light stays black."""
    rng = np.random.default_rng(4)
    h = w = 24
    spp = 4
    pixel = np.repeat(np.arange(h * w), spp)
    y, x = pixel // w + rng.random(pixel.size), pixel % w + rng.random(pixel.size)
    values = np.where((y - 12.3) ** 2 + (x - 12.2) ** 2 < 4.5**2, 100.0, 0.0)
    distance = np.hypot(np.arange(h)[:, None] + 0.5 - 12.3, np.arange(w) + 0.5 - 12.2).ravel()
    single = (rng.random(h * w) < 0.5) & (distance > 5.3) & (distance < 6.3)  # a ring just outside the rim
    keep = ~single[pixel] | (np.arange(pixel.size) % spp == 0)
    buf = SampleBuffer.from_samples(pixel[keep], np.stack([values[keep]] * 3, axis=1), (h, w))
    black_single = (buf.count == 1) & (buf.mean[..., 0] == 0)
    near = ndimage.binary_dilation((buf.variance[..., 0] > 0) & buf.variance_known, iterations=2)
    assert (black_single & near).sum() >= 5
    v = estimated_variance(buf.count, buf.mean, buf.variance, buf.variance_known)
    assert_array_equal(v[black_single & near], 0.0)
    assert reconstruct(buf)[black_single & near].max() < 1e-6 * 100


def test_the_rim_is_found_on_the_variances_as_given():
    """A faint noisy pixel in the background lends its agreeing neighbours a little once moderated; the rim found
    on those moderated variances had no exact region beside it any more, and a pixel of one sample beside the
    rim pooled its spread again. It is found once, on the variances as given (a review's case)."""
    count = np.full((6, 10), 4)
    mean, variance = np.zeros((6, 10, 1)), np.zeros((6, 10, 1))
    mean[:, 5:] = 100.0
    mean[:, 4], variance[:, 4] = 25.0, 2500.0          # samples 0, 0, 0, 100
    mean[2, 1], variance[2, 1] = 0.5, 0.3              # faint noise in the background
    count[0, 2] = 1                                    # one sample, at 0
    known = count >= 2
    v = estimated_variance(count, mean, variance, known)
    assert 0 < v[0, 2, 0] <= 0.3  # the faint pixel's share of its pool, none of the rim's 2500
    assert_array_equal(v[:, 4], variance[:, 4])


def test_a_rim_between_close_levels_still_lends():
    """Two exact regions within JUMP_RATIO of each other (texels of a texture): the pixels between them may be
    either, so the agreeing ones beside them still borrow their spread."""
    buf = _light_on_black(4, level=3.0, background=1.0)
    agreed = buf.variance_known[..., None] & (buf.variance == 0)
    near_rim = agreed & ndimage.binary_dilation((buf.variance > 0).any(2), iterations=1)[..., None]
    out = agreed_variance(buf.count, buf.mean, buf.variance, buf.variance_known)
    assert (out[near_rim] > 0).all()


def test_a_pixel_whose_samples_all_hit_still_borrows():
    """One pixel whose samples all hit a small light (its level held by no region) beside pixels that hit or missed:
    not a rim's inside, so its neighbours lend it their spread as before."""
    count = np.full((7, 7), 2)
    mean, variance = np.zeros((7, 7, 1)), np.zeros((7, 7, 1))
    mean[2:5, 2:5], variance[2:5, 2:5] = 25.0, 1250.0   # samples 0 and 50 around ...
    mean[3, 3], variance[3, 3] = 50.0, 0.0              # ... samples 50 and 50
    out = agreed_variance(count, mean, variance, count >= 2)
    assert out[3, 3, 0] > 0
    assert (out[1, 1:6, 0] > 0).all()  # the background beside them too
    assert_allclose(out, _reference(count, mean, variance, count >= 2), rtol=1e-12, atol=0)


@pytest.mark.parametrize("spp", [2, 8, 64])
def test_the_prior_counts_as_its_degrees_of_freedom(spp):
    """``prior * s2_local / (n - 1 + prior)``: the neighbours' evidence fades as the pixel's own agreeing
    samples grow; ``prior=0`` leaves the variance as it was, the same array."""
    count = np.full((5, 5), spp)
    mean = np.zeros((5, 5, 1))
    variance = np.zeros_like(mean)
    mean[2, 2], variance[2, 2] = 1.0, 3.0
    one = agreed_variance(count, mean, variance, count >= 2, prior=1.0)
    three = agreed_variance(count, mean, variance, count >= 2, prior=3.0)
    assert_allclose(three[0, 0] / one[0, 0], 3.0 * spp / (spp + 2.0), rtol=1e-12)
    assert agreed_variance(count, mean, variance, count >= 2, prior=0.0) is variance


def _emitters(rng, shape=(12, 14)):
    """Samples that all agreed at levels other than 0 (a flat emitter's value) beside spread ones, random counts:
    every entry goes through the offset-by-offset path, none through the shared window sums."""
    count = rng.integers(2, 40, shape)
    mean = np.round(rng.uniform(1.0, 4.0, shape + (2,)), 1)
    variance = rng.random(shape + (2,)) * (rng.random(shape + (2,)) < 0.5)
    return SampleBuffer.from_moments(count, mean, variance)


def test_many_counts_at_0_match_the_definition(rng):
    """Pixels that missed at 40 different counts (an adaptive buffer): no count holds a sixteenth of the
    pixels, so every entry goes offset by offset."""
    buf = _hit_or_zero(rng, shape=(20, 24), spp=2)
    buf = SampleBuffer.from_moments(rng.integers(2, 42, buf.shape), buf.mean, buf.variance)
    got = agreed_variance(buf.count, buf.mean, buf.variance, buf.variance_known)
    assert_allclose(got, _reference(buf.count, buf.mean, buf.variance, buf.variance_known), rtol=1e-12, atol=0)
    assert (got[buf.variance == 0] > 0).mean() > 0.3


@pytest.mark.parametrize("share", [0, 10**9])
def test_both_paths_for_entries_at_0_match_the_definition(rng, monkeypatch, share):
    """Entries at 0 at scattered counts, weighed from their spread neighbours outward (share 0: always) or
    gathered offset by offset (share 10^9: never), on an image with edges, corners and a single row."""
    monkeypatch.setattr(pooling, "_SCATTER_SHARE", share)
    for shape in [(20, 24), (1, 9), (7, 1), (2, 3)]:
        buf = _hit_or_zero(rng, shape=shape, spp=2, p=0.3, channels=3)
        buf = SampleBuffer.from_moments(rng.integers(2, 42, buf.shape), buf.mean, buf.variance)
        got = agreed_variance(buf.count, buf.mean, buf.variance, buf.variance_known)
        assert_allclose(got, _reference(buf.count, buf.mean, buf.variance, buf.variance_known), rtol=1e-12, atol=0)


@pytest.mark.parametrize("level", [0.0, 2.5])
def test_few_entries_read_where_they_are_match_the_definition(rng, level):
    """A few entries that agreed (at 0, or at an emitter's level) among spread pixels, in corners, on edges and
    inside, at scattered counts: fewer window visits than values in the image, so each neighbour is read where
    it is (the edge pixel past an edge) and each chance taken at its visit, with no padded plane."""
    h, w = 30, 34
    count = rng.integers(2, 40, (h, w))
    mean = rng.uniform(0.5, 4.0, (h, w, 3))
    variance = rng.uniform(0.1, 2.0, (h, w, 3))
    spots = [(0, 0), (0, w - 1), (h - 1, 0), (h - 1, w - 1), (0, 7), (13, 0), (h - 2, 20), (15, 16), (1, 1)]
    for i, j in spots:
        mean[i, j, 1], variance[i, j, 1] = level, 0.0
    mean[15, 17, :], variance[15, 17, :] = level, 0.0  # next to an entry that agreed at the same level
    known = count >= 2
    assert len(spots) + 3 < mean.size // POOL_WINDOW**2
    got = agreed_variance(count, mean, variance, known)
    assert_allclose(got, _reference(count, mean, variance, known), rtol=1e-12, atol=0)
    assert (got[variance == 0] > 0).all()


def test_agreeing_levels_other_than_0_match_the_definition(rng):
    buf = _emitters(rng)
    got = agreed_variance(buf.count, buf.mean, buf.variance, buf.variance_known)
    assert_allclose(got, _reference(buf.count, buf.mean, buf.variance, buf.variance_known), rtol=1e-12, atol=0)
    assert (got[buf.variance == 0] > 0).mean() > 0.5


@pytest.mark.parametrize("make", [_hit_or_zero, _emitters])
@pytest.mark.parametrize("exponent", [-500, -40, 40, 500])
def test_the_same_bits_at_any_scale(rng, exponent, make):
    """Means times 2^k, variances times 4^k: the moderated variances times 4^k exactly, at 1e150 and 1e-150 too."""
    buf = make(rng)
    scale = np.ldexp(1.0, exponent)
    base = estimated_variance(buf.count, buf.mean, buf.variance, buf.variance_known)
    scaled = estimated_variance(buf.count, buf.mean * scale, buf.variance * scale**2, buf.variance_known)
    assert np.isfinite(scaled).all()
    normal = np.abs(base * scale**2) >= np.finfo(float).tiny  # below it (1e-308) float64 itself rounds coarser
    assert_array_equal(scaled[normal], (base * scale**2)[normal])
    assert_allclose(scaled[~normal], (base * scale**2)[~normal], rtol=0, atol=1e-322)


def test_huge_spreads_do_not_overflow():
    count = np.full((5, 5), 2**40)
    mean = np.zeros((5, 5, 1))
    variance = np.zeros_like(mean)
    mean[2, 2], variance[2, 2] = 1e150, 1e300
    out = agreed_variance(count, mean, variance, count >= 2)
    assert np.isfinite(out).all() and out[2, 2, 0] == 1e300


def test_the_buffer_and_the_preparation_agree(rng):
    buf = _hit_or_zero(rng)
    assert_array_equal(buf.estimated_variance(), prepare(buf, "linear").sample_variance)
    assert_array_equal(buf.variance_of_mean(), prepare(buf, "linear").variance)


def test_means_far_beyond_the_spread():
    """Levels of 1e10 beside spreads of 1e-300 (the scale follows the spread): the gaps overflow the scaled
    units, which is a chance of 0, not a NaN; a neighbour at the same level still lends its spread."""
    count = np.full((5, 6), 4)
    mean = np.full((5, 6, 1), 1e10)
    variance = np.zeros_like(mean)
    mean[:, 5], variance[:, 5] = -1e300, 1e-300       # far away: lends nothing
    variance[0, 0] = 1e-300                           # the same level: lends its spread
    out = agreed_variance(count, mean, variance, count >= 2)
    assert np.isfinite(out).all()
    assert_allclose(out, _reference(count, mean, variance, count >= 2), rtol=1e-12, atol=1e-320)
    assert out[1, 1, 0] > 0 and out[2, 3, 0] == 0.0


@pytest.mark.parametrize("prior", [-1.0, float("nan"), float("inf"), "1"])
def test_a_bad_prior_is_named(prior):
    count = np.full((3, 3), 2)
    with pytest.raises((TypeError, ValueError), match="prior"):
        agreed_variance(count, np.zeros((3, 3, 1)), np.zeros((3, 3, 1)), count >= 2, prior=prior)


def test_a_single_sample_beside_moderated_pixels_is_not_exact():
    """Pooling runs after the moderation: a pixel of one sample whose known neighbours all agreed at 0, one
    of them two pixels from a hit, pools their moderated variances (before: 0, read as exact)."""
    count = np.full((1, 9), 4)
    count[0, 3] = 1                          # its window, columns 1-5, holds no hit: only moderated zeros
    mean = np.zeros((1, 9, 1))
    variance = np.zeros_like(mean)
    mean[0, 0], variance[0, 0] = 1.0, 4 / 3  # samples 4, 0, 0, 0
    out = estimated_variance(count, mean, variance, count >= 2)
    assert out[0, 1, 0] > 0.01 and out[0, 2, 0] > 0.001
    assert out[0, 3, 0] > 0.001
    assert out[0, 8, 0] == 0.0  # out of every window that saw spread


@pytest.mark.parametrize("top", [60, 70, 400, 2**40])
def test_counts_past_the_compiled_loops_squaring_match_the_definition(rng, top):
    """Counts around and far past ``_SQUARING`` (where the compiled loop takes ``exp(n log z)`` instead of
    repeated squaring), at 0 and at an emitter's level, against the pixel-by-pixel definition. Half the spread
    neighbours lie a hair from a level (gaps of 1e-7 to 2e-6 beside spreads near 1): ``z**n`` stays well
    above 0 even at ``n = 2**40``."""
    shape = (14, 15)
    count = rng.integers(max(2, top - 20), top + 1, shape)
    level = np.where(rng.random(shape + (2,)) < 0.5, 0.0, 2.5)
    spread = rng.random(shape + (2,)) < 0.4
    gap = np.where(rng.random(shape + (2,)) < 0.5, rng.uniform(1e-7, 2e-6, shape + (2,)),
                   rng.uniform(0.1, 1.0, shape + (2,)))
    mean = level + spread * gap
    variance = spread * rng.uniform(0.5, 2.0, shape + (2,))
    got = agreed_variance(count, mean, variance, count >= 2)
    want = _reference(count, mean, variance, count >= 2)
    assert_allclose(got, want, rtol=1e-12, atol=0)
    assert_array_equal(got == 0, want == 0)
    assert (got[variance == 0] > 0).mean() > 0.5


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (4, 3), (9, 11), (6, 8, 3), (2, 13, 1)])
@pytest.mark.parametrize("share", [0.0, 0.02, 0.3, 1.0])
def test_near_is_scipys_maximum_filter_with_either_edge_mode(rng, shape, share):
    """The spread-neighbour mask by shifted ORs is the maximum filter the moderation used before (both edge modes
    it used), on planes narrower than the window too."""
    mask = rng.random(shape) < share
    size = (POOL_WINDOW, POOL_WINDOW) + (1,) * (len(shape) - 2)
    for mode in ("nearest", "constant"):
        assert_array_equal(pooling._near(mask), ndimage.maximum_filter(mask, size=size, mode=mode))
    assert not np.shares_memory(pooling._near(mask), mask)


@pytest.mark.parametrize("shape", [(0, 3, 2), (1, 1, 1), (4, 5, 3), (3, 7)])
def test_nonzero_is_numpys(rng, shape):
    mask = rng.random(shape) < 0.3
    for want, got in zip(np.nonzero(mask), pooling._nonzero(mask), strict=True):
        assert got.dtype == want.dtype
        assert_array_equal(got, want)


@pytest.mark.parametrize("share", [0.0, 0.5, 1.0])
def test_in_pixels_is_the_broadcast_and(rng, share):
    plane, pixels = rng.random((5, 6, 3)) < 0.5, rng.random((5, 6)) < share
    want = plane & pixels[..., None]
    got = pooling._in_pixels(plane, pixels)
    assert got is plane
    assert_array_equal(got, want)


@needs_numba
def test_the_compiled_loop_agrees_with_numpy_on_an_adaptive_buffer(rng):
    """The compiled loop against the numpy path it replaces, on an image of an adaptive run's scattered counts
    (entries at 0 weighed outward by numpy, gathered by the loop): to rounding, with the same zeros."""
    buf = _hit_or_zero(rng, shape=(90, 110), spp=2, p=0.1, channels=3)
    buf = SampleBuffer.from_moments(rng.integers(2, 40, buf.shape), buf.mean, buf.variance)
    out = {}
    for name in fused.BACKENDS:
        fused.set_backend(name)
        out[name] = estimated_variance(buf.count, buf.mean, buf.variance, buf.variance_known)
    moderated = (buf.variance == 0) & buf.variance_known[..., None]
    assert (out["numpy"][moderated] > 0).mean() > 0.5
    assert_allclose(out["numba"], out["numpy"], rtol=1e-13, atol=0)
    assert_array_equal(out["numba"] == 0, out["numpy"] == 0)


@pytest.mark.parametrize("dtype", [np.int32, np.uint64, np.int64])
def test_counts_of_any_integer_type(rng, dtype):
    """Counts as int32 or uint64 (the library takes any integer array): the same values as int64."""
    buf = _hit_or_zero(rng, shape=(20, 24), spp=2)
    count = rng.integers(2, 6, buf.shape)
    want = agreed_variance(count, buf.mean, buf.variance, count >= 2)
    assert_array_equal(agreed_variance(count.astype(dtype), buf.mean, buf.variance, count >= 2), want)


@pytest.mark.parametrize("values", [[], [5], [2, 2, 3, 9, 9, 9], [2, 2**40, 2**40, 7], list(range(2, 40)) * 3])
def test_frequent_counts_as_unique_counts_them(values):
    values = np.array(values, dtype=np.int64)
    for times in (1, 2, 3):
        groups, sizes = np.unique(values, return_counts=True)
        assert_array_equal(pooling._frequent(values, times), groups[sizes >= times])


@needs_numba
def test_the_default_and_a_round_of_requests_are_the_same_with_either_backend(rng):
    """End to end on scattered counts: the default reconstruction to rounding, and one ``ask()`` round's counts
    (the sampler's priorities go through the same moderation) the same."""
    buf = _hit_or_zero(rng, shape=(48, 64), spp=2, p=0.1, channels=3)
    buf = SampleBuffer.from_moments(rng.integers(2, 40, buf.shape), buf.mean, buf.variance)
    out = {}
    for name in fused.BACKENDS:
        fused.set_backend(name)
        out[name] = reconstruct(buf), AdaptiveSampler.from_buffer(buf, round=1).ask().counts
    image, counts = out["numpy"]
    assert_allclose(out["numba"][0], image, rtol=0, atol=1e-12 * np.abs(image).max())
    assert_array_equal(out["numba"][1], counts)


@needs_numba
def test_the_compiled_loop_runs_on_two_threads(rng):
    """Two threads moderating at once (a 2-thread executor's channels or two samplers): each gets its own
    result, the same as one thread's."""
    buffers = []
    for _ in range(4):
        buf = _hit_or_zero(rng, shape=(60, 70), spp=2, p=0.1, channels=3)
        buffers.append(SampleBuffer.from_moments(rng.integers(2, 40, buf.shape), buf.mean, buf.variance))
    fused.set_backend("numba")
    alone = [estimated_variance(b.count, b.mean, b.variance, b.variance_known) for b in buffers]
    with ThreadPoolExecutor(2) as pool:
        together = list(pool.map(lambda b: estimated_variance(b.count, b.mean, b.variance, b.variance_known), buffers))
    for a, t in zip(alone, together):
        assert_array_equal(t, a)


@needs_numba
def test_the_compiled_loops_chances_where_it_visits_are_numpys_plane(rng):
    """The compiled loop takes the chances at level 0 from numpy's plane (many entries) or where it visits
    (few): the same operations, the same floats, bit for bit, at ordinary and at extreme scales."""
    buf = _hit_or_zero(rng, shape=(30, 40), spp=2, p=0.2, channels=3)
    count = rng.integers(2, 80, buf.shape)
    for scale in (1.0, 1e-150, 1e150):
        mean, variance = buf.mean * scale, buf.variance * scale**2
        variance[0, :5] = 1e-300  # spreads far below the means: gaps past float64 over g
        known = count >= 2
        todo = known[..., None] & (variance == 0)
        g = math.ldexp(1.0, math.frexp(math.sqrt(float(variance.max())))[1])
        s2 = variance / g / g
        dof = np.where(known, count - 1, 0).astype(np.float64)
        dof /= dof.max()
        loop = pooling._compiled_moderation()
        out = []
        for chance0 in (np.zeros((0, 0, 0)), pooling._chance(s2, mean, g)):
            out.append(np.zeros_like(variance))
            loop(todo, count, mean, s2, dof, g, chance0, 1.0, out[-1])
        assert_array_equal(out[0], out[1])
        assert (out[0][todo] > 0).mean() > 0.3


@pytest.mark.parametrize("noisy", [1e8, 1e16])
def test_a_very_noisy_pixel_far_away_leaves_a_single_samples_pool_as_it_is(noisy):
    """A pixel of one sample pools the known variances of its own window, whatever lies beyond it: a running sum
    (scipy's uniform_filter) carried a noisy pixel's rounding error 25 columns along, and the pool came out 0, a
    single sample read as exact (a red-team pass; ._window_sums)."""
    count = np.full((1, 40), 4)
    count[0, 30] = 1
    mean = np.ones((1, 40, 1))
    variance = np.full((1, 40, 1), 0.01)
    variance[0, 30] = 0.0
    variance[0, 5] = noisy
    out = pooling.pooled_variance(count, mean, variance, count >= 2)
    assert out[0, 30, 0] == pytest.approx(0.01, rel=1e-12)


def test_variances_near_float64s_limit_pool_without_overflow(rng):
    """M2 = variance (n - 1), summed over a window, passed float64 where a known variance was near its limit: a
    one-sample pixel's pooled variance of 5e307 came out Inf, and the reconstruction and the sampler refused the
    buffer as beyond float64 (an attack pass). Pooled at a power of two below and scaled back: the same value as the
    buffer scaled down by a power of two gives, scaled up, and the known variances as they were."""
    count = np.array([[1, 3, 3]])
    mean = np.array([[[1.0], [1e154], [1.0]]])
    variance = np.array([[[0.0], [1e308], [0.25]]])
    buffer = SampleBuffer.from_moments(count, mean, variance)
    pooled = estimated_variance(count, mean, variance, buffer.variance_known)
    assert np.isfinite(pooled).all()
    assert pooled[0, 0, 0] == 1e308 / 2  # (2e308 + 0.5) / 4
    assert_array_equal(pooled[0, 1:], variance[0, 1:])
    f = 2.0**-600
    small = estimated_variance(count, mean * 2.0**-300, variance * f, buffer.variance_known)
    assert small[0, 0, 0] * 2.0**600 == pooled[0, 0, 0]
    assert np.isfinite(reconstruct(buffer)).all() and np.isfinite(reconstruct(buffer, domain="linear")).all()
    assert AdaptiveSampler.from_buffer(buffer).ask(4).counts.sum() == 4
    # Large variances beside tiny ones (1e-300) keep the tiny ones' pool: the shift is no larger than needed.
    count = np.full((4, 4), 3)
    count[0, 0] = 1
    variance = np.full((4, 4, 1), 1e-300)
    variance[3, 3] = 1e300
    mean = np.ones((4, 4, 1))
    pooled = estimated_variance(count, mean, variance, SampleBuffer.from_moments(count, mean, variance).variance_known)
    assert 0 < pooled[0, 0, 0] < 1e-299
