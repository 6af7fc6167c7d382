"""SampleBuffer: per-pixel statistics, exact merging, validation and non-finite policies."""

from __future__ import annotations

import copy
import itertools
import warnings
from fractions import Fraction

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from awr_denoise.buffers import SampleBuffer
from awr_denoise.channels import default_channel_names, luminance_weights

# Two-pass float64 statistics against numpy's own: only rounding differs.
STATS_RTOL = {np.float64: 1e-12, np.float32: 1e-12}
# Chan's parallel update against the two-pass statistics of all samples at once.
MERGE_RTOL = 1e-11
MERGE_ATOL = 1e-13
# sum_sq - sum^2 / n cancels; on values of order one with few samples it stays close.
SUMS_RTOL = 1e-9

SHAPE = (6, 5)


def _random_samples(rng, shape=SHAPE, n=400, channels=3, dtype=np.float64):
    """Flat pixel indices (every pixel hit at least twice) and (n, C) values."""
    h, w = shape
    pixels = np.concatenate([np.repeat(np.arange(h * w), 2), rng.integers(0, h * w, n - 2 * h * w)])
    rng.shuffle(pixels)
    values = (rng.normal(1.0, 0.5, (n, channels)) * (1 + pixels[:, None] % 4)).astype(dtype)
    return pixels, values


def _numpy_stats(pixels, values, shape):
    h, w = shape
    count = np.zeros(h * w, np.int64)
    mean = np.zeros((h * w, values.shape[1]))
    var = np.zeros((h * w, values.shape[1]))
    for p in range(h * w):
        v = values[pixels == p].astype(np.float64)
        count[p] = len(v)
        if len(v):
            mean[p] = v.mean(axis=0)
        if len(v) > 1:
            var[p] = v.var(axis=0, ddof=1)
    return count.reshape(h, w), mean.reshape(h, w, -1), var.reshape(h, w, -1)


# ---------------------------------------------------------------------------- values
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_from_samples_matches_numpy_mean_and_unbiased_variance(rng, dtype):
    pixels, values = _random_samples(rng, dtype=dtype)
    buf = SampleBuffer.from_samples(pixels, values, SHAPE)
    count, mean, var = _numpy_stats(pixels, values, SHAPE)
    assert buf.mean.dtype == np.float64 and buf.variance.dtype == np.float64
    assert_array_equal(buf.count, count)
    assert_allclose(buf.mean, mean, rtol=STATS_RTOL[dtype])
    assert_allclose(buf.variance, var, rtol=STATS_RTOL[dtype])
    assert buf.variance_known.all()
    assert buf.total_samples == len(pixels)
    assert_allclose(buf.variance_of_mean(), var / count[..., None], rtol=STATS_RTOL[dtype])


def test_tiny_hand_checked_pixel():
    # Samples 1, 2, 6 at pixel (0, 1): mean 3, variance ((-2)^2 + (-1)^2 + 3^2) / 2 = 7.
    buf = SampleBuffer.from_samples(np.array([1, 1, 1]), np.array([1.0, 2.0, 6.0]), (1, 2))
    assert_array_equal(buf.count, [[0, 3]])
    assert buf.mean[0, 1, 0] == 3.0
    assert buf.variance[0, 1, 0] == 7.0
    assert buf.m2[0, 1, 0] == 14.0
    assert buf.channels == ("Y",)


def test_pixel_coordinates_and_flat_indices_agree(rng):
    pixels, values = _random_samples(rng)
    rows, cols = np.divmod(pixels, SHAPE[1])
    a = SampleBuffer.from_samples(pixels, values, SHAPE)
    b = SampleBuffer.from_samples(np.stack([rows, cols], axis=1), values, SHAPE)
    assert_array_equal(a.count, b.count)
    assert_array_equal(a.mean, b.mean)
    assert_array_equal(a.variance, b.variance)


def test_pixels_outside_the_image_are_refused():
    with pytest.raises(ValueError, match=r"pixels: 2 coordinate\(s\) fall outside"):
        SampleBuffer.from_samples(np.array([[0, 0], [3, 0], [0, -1]]), np.ones(3), (3, 3))
    with pytest.raises(ValueError, match=r"pixels: 1 index\(es\) fall outside"):
        SampleBuffer.from_samples(np.array([0, 9]), np.ones(2), (3, 3))


# ---------------------------------------------------------------------------- merging
def test_merge_equals_all_samples_at_once_in_any_order(rng):
    pixels, values = _random_samples(rng, n=600)
    whole = SampleBuffer.from_samples(pixels, values, SHAPE)
    cuts = [0, 37, 38, 250, 600]  # a batch of one sample, and uneven batches
    parts = [SampleBuffer.from_samples(pixels[a:b], values[a:b], SHAPE) for a, b in zip(cuts, cuts[1:])]
    for order in itertools.permutations(range(len(parts))):
        merged = parts[order[0]]
        for i in order[1:]:
            merged = merged.merge(parts[i])
        assert_array_equal(merged.count, whole.count)
        assert_allclose(merged.mean, whole.mean, rtol=MERGE_RTOL, atol=MERGE_ATOL)
        assert_allclose(merged.variance, whole.variance, rtol=MERGE_RTOL, atol=MERGE_ATOL)
        assert_array_equal(merged.variance_known, whole.variance_known)
    # Tree order too: (a + b) + (c + d).
    tree = parts[0].merge(parts[1]).merge(parts[2].merge(parts[3]))
    assert_allclose(tree.variance, whole.variance, rtol=MERGE_RTOL, atol=MERGE_ATOL)


def test_merge_of_single_samples_gives_known_variance():
    a = SampleBuffer.from_samples(np.array([0]), np.array([1.0]), (1, 1))
    b = SampleBuffer.from_samples(np.array([0]), np.array([4.0]), (1, 1))
    assert not a.variance_known.any() and not b.variance_known.any()
    ab = a.merge(b)
    assert ab.count[0, 0] == 2 and ab.variance_known[0, 0]
    assert ab.mean[0, 0, 0] == 2.5
    assert ab.variance[0, 0, 0] == pytest.approx(4.5, rel=1e-15)  # var([1, 4], ddof=1)


def test_merge_with_empty_is_identity(rng):
    pixels, values = _random_samples(rng)
    buf = SampleBuffer.from_samples(pixels, values, SHAPE)
    for merged in (buf.merge(SampleBuffer.empty(SHAPE)), SampleBuffer.empty(SHAPE).merge(buf)):
        assert_array_equal(merged.count, buf.count)
        assert_array_equal(merged.mean, buf.mean)
        assert_allclose(merged.variance, buf.variance, rtol=MERGE_RTOL)


def test_merge_refuses_other_shapes_and_channels():
    a = SampleBuffer.empty((2, 3))
    with pytest.raises(ValueError, match="other: shape"):
        a.merge(SampleBuffer.empty((3, 2)))
    with pytest.raises(ValueError, match="other: channels"):
        a.merge(SampleBuffer.empty((2, 3), channels=("X", "Y", "Z")))
    with pytest.raises(TypeError, match="other"):
        a.merge(np.zeros((2, 3)))


# ---------------------------------------------------------------------------- other constructors
def test_from_sums_and_all_variance_kinds_agree(rng):
    pixels, values = _random_samples(rng)
    ref = SampleBuffer.from_samples(pixels, values, SHAPE)
    n = ref.count
    h, w = SHAPE
    s1 = np.stack([np.bincount(pixels, values[:, c], h * w) for c in range(3)], -1).reshape(h, w, 3)
    s2 = np.stack([np.bincount(pixels, values[:, c] ** 2, h * w) for c in range(3)], -1).reshape(h, w, 3)
    built = {
        "sums": SampleBuffer.from_sums(n, s1, s2),
        "sample": SampleBuffer.from_moments(n, ref.mean, ref.variance, variance_kind="sample"),
        "mean": SampleBuffer.from_moments(n, ref.mean, ref.variance / n[..., None], variance_kind="mean"),
        "second_moment": SampleBuffer.from_moments(n, ref.mean, s2 / n[..., None], variance_kind="second_moment"),
    }
    for name, buf in built.items():
        assert_array_equal(buf.count, ref.count, err_msg=name)
        assert_allclose(buf.mean, ref.mean, rtol=SUMS_RTOL, err_msg=name)
        assert_allclose(buf.variance, ref.variance, rtol=SUMS_RTOL, err_msg=name)


def test_a_second_moment_below_the_squared_mean_is_refused_not_clamped():
    """E[x^2] >= mean^2: a plane far below it is not second moments (a variance given as one), while
    a float32 file's rounding (a deficit of 1e-7 of mean^2) is clamped at 0 as before."""
    mean = np.full((2, 3), 0.5)
    with pytest.raises(ValueError, match=r"variance: 6 pixel\(s\) hold a second moment below the squared mean"):
        SampleBuffer.from_moments(np.full((2, 3), 8), mean, np.full((2, 3), 0.01), variance_kind="second_moment")
    rounded = SampleBuffer.from_moments(np.full((2, 3), 8), mean, np.full((2, 3), 0.25 * (1 - 1e-7)),
                                        variance_kind="second_moment")
    assert_array_equal(rounded.variance, 0.0)


def test_second_moments_whose_squared_mean_overflows_are_refused():
    """A mean of 1e200 needs an E[x^2] of 1e400, which float64 cannot hold: 1e300 is not one (its
    variance came out 0 when mean^2 overflowed)."""
    with pytest.raises(ValueError, match="second moment below the squared mean"):
        SampleBuffer.from_moments(np.full((2, 2), 4), np.full((2, 2), 1e200), np.full((2, 2), 1e300),
                                  variance_kind="second_moment")


def test_a_variance_of_the_mean_past_float64_times_its_count_is_refused_by_name():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow warning on the way (a red-team pass)
        with pytest.raises(ValueError, match="variance: 1 pixel.*per-sample variance beyond float64"):
            SampleBuffer.from_moments([[2**62]], [[1.0]], [[1e300]], variance_kind="mean")


def test_independent_means_merge_as_the_definition(rng):
    """N renders known by counts and means: n = sum n_k, the weighted mean, and the spread of the means
    ``sum n_k (m_k - mean)^2 / (N' - 1)`` over the N' renders with samples, against a Fraction reference."""
    counts = rng.integers(0, 5, size=(4, 3, 5))
    means = rng.normal(size=(4, 3, 5, 2)) * 10.0 ** rng.integers(-3, 4, size=(4, 3, 5, 1))
    buf = SampleBuffer.from_independent_means(counts, means)
    for i, j, c in itertools.product(range(3), range(5), range(2)):
        n = [int(k) for k in counts[:, i, j]]
        m = [Fraction(float(x)) for x in means[:, i, j, c]]
        total = sum(n)
        mean = sum(nk * mk for nk, mk in zip(n, m)) / max(total, 1)
        renders = sum(nk > 0 for nk in n)
        spread = sum(nk * (mk - mean) ** 2 for nk, mk in zip(n, m)) / max(renders - 1, 1)
        assert buf.count[i, j] == total and bool(buf.variance_known[i, j]) == (renders >= 2)
        assert buf.mean[i, j, c] == pytest.approx(float(mean), rel=1e-14, abs=1e-300)
        assert buf.variance[i, j, c] == pytest.approx(float(spread), rel=1e-12, abs=1e-300)


def test_independent_means_at_the_edges_of_float64_and_int64():
    """Means near the float64 limit were refused as NaN or Inf (the weighted sum overflowed), counts were
    summed in float64 (2**53 + 1 samples came out 2**53), a total past int64 was "negative" (a red-team
    pass); renders that agree give their value and no spread at any magnitude."""
    def merged(counts, means):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            return SampleBuffer.from_independent_means(np.reshape(counts, (-1, 1, 1)), np.reshape(means, (-1, 1, 1)))

    for value in (1e308, -1.7e308, 0.1, 5e-324, 1e-300):
        buf = merged([4, 7, 3], [value] * 3)
        assert buf.mean.item() == value and buf.variance.item() == 0.0 and buf.count.item() == 14
    assert merged([2**53, 1], [1.0, 1.0]).count.item() == 2**53 + 1
    spread = merged([4, 4], [1e150, -1e150])
    assert spread.mean.item() == 0.0 and spread.variance.item() == pytest.approx(8e300)
    with pytest.raises(ValueError, match=r"counts: 1 pixel\(s\) would hold more than 2\*\*62 samples merged"):
        merged([2**62, 2**62], [1.0, 1.0])
    with pytest.raises(TypeError, match=r"^counts: expected an integer array, got dtype bool"):
        merged([True, True], [1.0, 1.0])
    with pytest.raises(ValueError, match=r"means: the spread of 1 pixel\(s\) over the renders is beyond float64"):
        merged([4, 4], [1e160, -1e160])
    # Each channel scaled on its own, from the renders with samples (a review: one scale for the pixel
    # zeroed a channel of 3e-300 beside one of 1e300, and a render without samples set the scale).
    two = SampleBuffer.from_independent_means(np.full((2, 1, 1), 4), np.array([[[[1e300, 3e-300]]]] * 2))
    assert two.mean.ravel().tolist() == [1e300, 3e-300] and two.variance.max() == 0.0
    assert merged([4, 4, 0], [3e-300, 5e-300, 1e300]).mean.item() == 4e-300


@pytest.mark.parametrize(("shape", "features", "error", "message"), [
    ((2.7, 1), None, ValueError, "shape: must be a whole number"),
    ((2, 1, 1), None, TypeError, r"shape: expected \(height, width\)"),
    ("ab", None, TypeError, r"shape: expected \(height, width\)"),
    (None, None, TypeError, r"shape: expected \(height, width\)"),
    ((2, 2), [1, 2], TypeError, "features: expected a mapping"),
])
def test_from_samples_checks_shape_and_features_like_the_other_constructors(shape, features, error, message):
    with pytest.raises(error, match=message):
        SampleBuffer.from_samples([0], [[1.0, 1.0, 1.0]], shape, features=features)


def test_from_moments_accepts_single_channel_planes():
    buf = SampleBuffer.from_moments(np.full((2, 2), 3), np.ones((2, 2)), np.full((2, 2), 0.5))
    assert buf.mean.shape == (2, 2, 1) and buf.channels == ("Y",)


def test_unknown_variance_kind_is_refused():
    with pytest.raises(ValueError, match="variance_kind"):
        SampleBuffer.from_moments(np.ones((2, 2), int), np.ones((2, 2)), np.ones((2, 2)), variance_kind="std")


# ---------------------------------------------------------------------------- unknown variance
def test_single_sample_pixels_pool_variance_from_neighbours(rng):
    h, w = 9, 9
    count = np.full((h, w), 8)
    count[4, 4] = 1
    count[0, 0] = 1
    variance = np.full((h, w, 3), 0.25)
    buf = SampleBuffer.from_moments(count, rng.random((h, w, 3)), variance)
    assert not buf.variance_known[4, 4] and not buf.variance_known[0, 0]
    assert buf.variance[4, 4].tolist() == [0.0, 0.0, 0.0]  # stored as 0, meaningless
    est = buf.estimated_variance()
    # Every neighbour has variance 0.25, so the pooled value is exactly that, never zero.
    assert_allclose(est[4, 4], 0.25, rtol=1e-12)
    assert_allclose(est[0, 0], 0.25, rtol=1e-12)
    assert_allclose(buf.variance_of_mean()[4, 4], 0.25, rtol=1e-12)


def test_renderer_unknown_variance_is_not_zero(rng):
    # pbrt writes variance 0 where it has no estimate; variance_known=False marks it.
    count = np.full((5, 5), 4)
    var = np.full((5, 5), 2.0)
    known = np.ones((5, 5), bool)
    known[2, 2] = False
    var[2, 2] = 0.0
    buf = SampleBuffer.from_moments(count, np.ones((5, 5)), var, variance_known=known)
    assert buf.estimated_variance()[2, 2, 0] == pytest.approx(2.0, rel=1e-12)


def test_single_sample_pixels_far_from_known_ones_use_the_global_pool():
    count = np.ones((12, 12), int)
    count[0, 0] = 3  # the only known variance, far from the opposite corner
    var = np.zeros((12, 12))
    var[0, 0] = 0.5
    buf = SampleBuffer.from_moments(count, np.zeros((12, 12)), var)
    est = buf.estimated_variance()
    assert est[11, 11, 0] == pytest.approx(0.5, rel=1e-12)
    assert (est > 0).all()


def test_no_known_variance_anywhere_gives_zero_estimate():
    buf = SampleBuffer.from_moments(np.ones((3, 3), int), np.ones((3, 3)), np.zeros((3, 3)))
    assert_array_equal(buf.estimated_variance(), 0.0)


def test_zero_count_pixels_have_infinite_variance_of_mean(rng):
    pixels, values = _random_samples(rng)
    keep = pixels != 7
    buf = SampleBuffer.from_samples(pixels[keep], values[keep], SHAPE)
    vm = buf.variance_of_mean()
    r, c = divmod(7, SHAPE[1])
    assert buf.count[r, c] == 0 and buf.mean[r, c].tolist() == [0.0, 0.0, 0.0]
    assert np.isposinf(vm[r, c]).all()
    assert np.isfinite(np.delete(vm.reshape(-1, 3), 7, axis=0)).all()


def test_empty_buffer():
    buf = SampleBuffer.empty((3, 4), channels=("R", "G", "B"))
    assert buf.total_samples == 0 and buf.shape == (3, 4) and buf.n_channels == 3
    assert np.isposinf(buf.variance_of_mean()).all()


# ---------------------------------------------------------------------------- luminance
def test_luminance_weights_and_grey_luminance_variance():
    assert_allclose(luminance_weights(("R", "G", "B")), [0.2126, 0.7152, 0.0722])
    assert_allclose(luminance_weights(("B", "G", "R", "A")), [0.0722, 0.7152, 0.2126, 0.0])
    assert_allclose(luminance_weights(("X", "Y")), [0.5, 0.5])
    assert default_channel_names(3) == ("R", "G", "B")
    # Grey samples: luminance equals the channel value and so does its variance (exact case).
    buf = SampleBuffer.from_moments(np.full((2, 2), 4), np.full((2, 2, 3), 0.5), np.full((2, 2, 3), 0.09))
    assert_allclose(buf.luminance(), 0.5, rtol=1e-12)
    assert_allclose(buf.luminance_variance(), 0.09, rtol=1e-12)


# ---------------------------------------------------------------------------- bad input
def _good(h=4, w=5, c=3):
    return np.full((h, w), 4), np.ones((h, w, c)), np.full((h, w, c), 0.1)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_means_and_variances_are_refused_with_pixel_count(bad):
    count, mean, var = _good()
    mean[0, 0, 1] = bad
    mean[2, 3, :] = bad  # one pixel, three channels: still one pixel
    mean[3, 4, 0] = bad
    with pytest.raises(ValueError, match=r"^mean: 3 pixel\(s\) hold NaN or Inf"):
        SampleBuffer.from_moments(count, mean, var)
    count, mean, var = _good()
    var[1, 1, 2] = bad
    with pytest.raises(ValueError, match=r"^variance: 1 pixel\(s\) hold NaN or Inf"):
        SampleBuffer.from_moments(count, mean, var)


def test_a_long_double_beyond_float64_is_refused_without_a_warning():
    """Finite long doubles of 1e400 let numpy's "overflow encountered in cast" warning escape before the refusal
    (an attack pass; an error under ``-W error``, which the tests run with), then called "NaN or Inf"."""
    if np.finfo(np.longdouble).max <= np.finfo(np.float64).max:
        pytest.skip("long double is float64 on this platform")
    count, mean, var = _good()
    mean = mean.astype(np.longdouble)
    mean[0, 0, 0] = np.longdouble(10) ** 400
    with pytest.raises(ValueError, match=r"^mean: 1 value\(s\) beyond float64's range \(long doubles"):
        SampleBuffer.from_moments(count, mean, var)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nonfinite_counts_are_refused_with_pixel_count(bad):
    count, mean, var = _good()
    count = count.astype(float)
    count[0, :2] = bad
    with pytest.raises(ValueError, match=r"^count: 2 pixel\(s\) hold NaN or Inf"):
        SampleBuffer.from_moments(count, mean, var)


def test_fractional_counts_are_refused():
    count, mean, var = _good()
    count = count.astype(float)
    count[1, 1] = 2.5
    with pytest.raises(ValueError, match=r"^count: 1 pixel\(s\) are not whole numbers"):
        SampleBuffer.from_moments(count, mean, var)


def test_negative_counts_and_variances_are_refused_with_pixel_count():
    count, mean, var = _good()
    count[0, 0] = -1
    count[3, 3] = -4
    with pytest.raises(ValueError, match=r"^count: 2 pixel\(s\) are negative"):
        SampleBuffer.from_moments(count, mean, var)
    count, mean, var = _good()
    var[1, 2, 0] = -1e-3
    var[2, 2, :] = -1.0
    var[3, 0, 1] = -5.0
    with pytest.raises(ValueError, match=r"^variance: 3 pixel\(s\) are negative"):
        SampleBuffer.from_moments(count, mean, var)


def test_mismatched_shapes_are_refused_naming_the_parameter():
    count, mean, var = _good()
    with pytest.raises(ValueError, match=r"^variance: shape \(4, 5, 2\) does not match mean \(4, 5, 3\)"):
        SampleBuffer.from_moments(count, mean, var[..., :2])
    with pytest.raises(ValueError, match=r"^mean: shape \(4, 4, 3\) does not match count \(4, 5\)"):
        SampleBuffer.from_moments(count, mean[:, :4], var[:, :4])
    with pytest.raises(ValueError, match=r"^count: expected shape \(H, W\)"):
        SampleBuffer.from_moments(count.ravel(), mean, var)
    with pytest.raises(ValueError, match=r"^sum/sum_sq: shapes"):
        SampleBuffer.from_sums(count, mean, var[:3])
    with pytest.raises(ValueError, match=r"^values: expected \(3, C\)"):
        SampleBuffer.from_samples(np.arange(3), np.ones(4), (2, 2))
    with pytest.raises(ValueError, match=r"^channels: 2 names given for 3 channel"):
        SampleBuffer.from_moments(count, mean, var, channels=("R", "G"))


def test_empty_images_are_refused():
    with pytest.raises(ValueError, match=r"^count: empty image"):
        SampleBuffer.from_moments(np.zeros((0, 5), int), np.zeros((0, 5, 3)), np.zeros((0, 5, 3)))
    with pytest.raises(ValueError, match=r"^count: empty image"):
        SampleBuffer.from_moments(np.ones((2, 2), int), np.zeros((2, 2, 0)), np.zeros((2, 2, 0)))
    with pytest.raises(ValueError, match=r"^shape: empty image"):
        SampleBuffer.from_samples(np.zeros(0, int), np.zeros(0), (0, 4))
    with pytest.raises(ValueError, match=r"empty image"):
        SampleBuffer.empty((3, 0))


def test_nonfinite_sums_are_refused_with_pixel_count():
    count, s1, s2 = _good()
    s2[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match=r"^sum_sq: 1 pixel\(s\) hold NaN or Inf"):
        SampleBuffer.from_sums(count, s1, s2)


def test_arrays_are_read_only(rng):
    pixels, values = _random_samples(rng)
    buf = SampleBuffer.from_samples(pixels, values, SHAPE)
    with pytest.raises(ValueError, match="read-only"):
        buf.mean[0, 0, 0] = 1.0


# ---------------------------------------------------------------------------- non-finite samples
def _samples_with_nonfinite():
    pixels = np.array([0, 0, 0, 1, 1, 1, 1])
    values = np.array([[1.0, 1.0], [np.nan, 2.0], [3.0, 3.0], [2.0, 2.0], [np.inf, 0.0], [4.0, -np.inf], [6.0, 6.0]])
    return pixels, values


def test_nonfinite_raise_reports_count():
    pixels, values = _samples_with_nonfinite()
    with pytest.raises(ValueError, match=r"^values: 3 sample\(s\) hold NaN or Inf"):
        SampleBuffer.from_samples(pixels, values, (1, 2))
    with pytest.raises(ValueError, match="nonfinite"):
        SampleBuffer.from_samples(pixels, values, (1, 2), nonfinite="clip")


def test_nonfinite_drop_leaves_samples_out_and_counts_them():
    pixels, values = _samples_with_nonfinite()
    buf = SampleBuffer.from_samples(pixels, values, (1, 2), nonfinite="drop")
    assert buf.nonfinite == 3
    assert_array_equal(buf.count, [[2, 2]])
    assert_allclose(buf.mean[0, :, 0], [2.0, 4.0])
    assert_allclose(buf.variance[0, :, 0], [2.0, 8.0])


def test_nonfinite_zero_counts_them_as_zero_in_every_channel():
    pixels, values = _samples_with_nonfinite()
    buf = SampleBuffer.from_samples(pixels, values, (1, 2), nonfinite="zero")
    assert buf.nonfinite == 3
    assert_array_equal(buf.count, [[3, 4]])
    assert_allclose(buf.mean[0, :, 0], [4.0 / 3.0, 2.0])
    assert_allclose(buf.mean[0, :, 1], [4.0 / 3.0, 2.0])
    # The count survives merging.
    assert buf.merge(copy.deepcopy(buf)).nonfinite == 6


def test_merge_with_an_empty_side_is_bit_exact(rng):
    """Round 0 and disjoint tiles merge into empty pixels: the result must be the other side's
    statistics bit for bit, not variance * (n - 1) / (n - 1) rounded (which differs for about
    one value in eight: the first assertion makes sure this data has such values)."""
    shape = (20, 30)
    count = rng.integers(2, 50, shape)
    variance = rng.random(shape + (3,))
    n1 = (count - 1)[..., None].astype(np.float64)
    assert ((variance * n1) / n1 != variance).any()
    buf = SampleBuffer.from_moments(count, rng.random(shape + (3,)), variance)
    for merged in (SampleBuffer.empty(shape).merge(buf), buf.merge(SampleBuffer.empty(shape))):
        assert_array_equal(merged.mean, buf.mean)
        assert_array_equal(merged.variance, buf.variance)
        assert_array_equal(merged.count, buf.count)


def test_merge_in_place_is_chans_formula_bit_for_bit(rng):
    """The merge works in place for memory and speed; it must still be Chan's update written out."""
    shape = (23, 29)
    a = SampleBuffer.from_moments(rng.integers(0, 5, shape), rng.lognormal(0, 3, shape + (3,)),
                                  rng.lognormal(0, 3, shape + (3,)))
    b = SampleBuffer.from_moments(rng.integers(0, 5, shape), rng.lognormal(0, 3, shape + (3,)),
                                  rng.lognormal(0, 3, shape + (3,)))
    na, nb = a.count[..., None].astype(np.float64), b.count[..., None].astype(np.float64)
    n = na + nb
    safe = np.maximum(n, 1.0)
    delta = b.mean - a.mean
    mean = a.mean + delta * (nb / safe)
    variance = (a.m2 + b.m2 + delta * delta * (na * nb / safe)) / np.maximum(n - 1.0, 1.0)
    mean = np.where(na == 0, b.mean, np.where(nb == 0, a.mean, mean))
    variance = np.where(na == 0, b.variance, np.where(nb == 0, a.variance, variance))
    merged = a.merge(b)
    assert_array_equal(merged.mean, mean)
    assert_array_equal(merged.variance, np.where(merged.variance_known[..., None], variance, 0.0))
    assert_array_equal(merged.count, a.count + b.count)


def test_pixels_without_samples_or_variance_are_zeroed_and_others_kept():
    """The constructor zeroes the mean of pixels without samples and the variance of pixels with
    fewer than two (or marked unknown); with none of either it writes nothing and keeps every value."""
    count = np.array([[0, 1, 2], [3, 4, 5]])
    mean = np.arange(1.0, 7.0).reshape(2, 3)
    variance = np.full((2, 3), 0.5)
    known = np.array([[True, True, True], [False, True, True]])
    buf = SampleBuffer.from_moments(count, mean, variance, variance_known=known)
    assert_array_equal(buf.mean[..., 0], [[0.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    assert_array_equal(buf.variance[..., 0], [[0.0, 0.0, 0.5], [0.0, 0.5, 0.5]])
    full = SampleBuffer.from_moments(count + 2, mean, variance)
    assert_array_equal(full.mean[..., 0], mean)
    assert full.variance_known.all()
    assert_array_equal(full.variance[..., 0], variance)


@pytest.mark.parametrize(("sums", "message"), [([[4 + 9j]], "sum: complex values are not supported"),
                                               ([["x"]], "sum: expected a numeric array")])
def test_from_sums_refuses_what_it_would_cast(sums, message):
    """Second red-team pass: a complex sum lost its imaginary part, strings failed without a name."""
    with pytest.raises(TypeError, match=message):
        SampleBuffer.from_sums([[2]], sums, [[10.0]])


def test_from_sums_refuses_sums_no_samples_have():
    """A negative sum of squares (or one far below sum^2 / n) was clamped to variance 0, and a pixel without
    samples holding a sum was zeroed without a word (a red-team pass); rounding's deficit is still clamped."""
    with pytest.raises(ValueError, match="sum_sq: 1 pixel"):
        SampleBuffer.from_sums([[2]], [[2.0]], [[-100.0]])
    with pytest.raises(ValueError, match="sum: 1 pixel"):
        SampleBuffer.from_sums([[0]], [[5.0]], [[30.0]])
    rounded = SampleBuffer.from_sums([[2]], [[2e8]], [[2e16 * (1 - 1e-12)]])  # equal samples, rounding below
    assert rounded.variance.item() == 0.0


def test_arrays_stay_read_only_through_pickle_and_deepcopy():
    """Buffers and requests go to worker processes pickled; their arrays came back writeable, so a
    count edited to -3 there was reconstructed without a check (red-team pass 5)."""
    import copy
    import pickle

    from awr_denoise import SampleRequest

    buffer = SampleBuffer.from_samples(np.array([0, 0, 1]), np.ones(3), (1, 2), features={"depth": np.ones(3)})
    request = SampleRequest.uniform((2, 2), 2)
    for clone in (pickle.loads(pickle.dumps(buffer)), copy.deepcopy(buffer)):
        for array in (clone.count, clone.mean, clone.variance, clone.variance_known, clone.features["depth"].mean):
            with pytest.raises(ValueError, match="read-only"):
                array[0, 0] = -3
        np.testing.assert_array_equal(clone.mean, buffer.mean)
    for clone in (pickle.loads(pickle.dumps(request)), copy.deepcopy(request)):
        with pytest.raises(ValueError, match="read-only"):
            clone.counts[0, 0] = -3


def test_masked_entries_are_refused_not_dropped():
    """``np.asarray`` drops a mask: a masked firefly was kept (and reached the reconstruction), a
    masked NaN reported as a NaN (red-team pass of the API's array layouts)."""
    mean = np.full((4, 4, 3), 0.5)
    mean[1, 1] = 1e6
    masked = np.ma.masked_array(mean, mask=mean > 1)
    count, variance = np.full((4, 4), 4), np.full((4, 4, 3), 0.01)
    with pytest.raises(TypeError, match="mean: a masked array with 3 masked entries"):
        SampleBuffer.from_moments(count, masked, variance)
    with pytest.raises(TypeError, match="count: a masked array"):
        SampleBuffer.from_moments(np.ma.masked_equal(count, 4), mean, variance)
    values = np.ma.masked_invalid(np.array([[0.5], [np.nan]]))
    with pytest.raises(TypeError, match="values: a masked array with 1 masked entries"):
        SampleBuffer.from_samples(np.array([0, 1]), values, (1, 2))
    with pytest.raises(TypeError, match="sum: a masked array"):
        SampleBuffer.from_sums(count, np.ma.masked_array(mean * 4, mask=mean > 1), mean * mean * 4)
    # A masked array that masks nothing is an array like any other.
    same = SampleBuffer.from_moments(count, np.ma.masked_array(mean), variance)
    assert_array_equal(same.mean, mean)


def test_buffers_are_c_ordered_and_stay_read_only():
    """A buffer kept its caller's memory order (a transposed array: results differed in their last
    bits, and every file writer depended on it), and its arrays owned their memory, so anyone could
    set ``writeable`` back and change a sampler's statistics."""
    rng = np.random.default_rng(3)
    mean = rng.random((5, 6, 3))
    variance = rng.random((5, 6, 3)) * 0.1
    count = rng.integers(2, 9, (5, 6))
    plain = SampleBuffer.from_moments(count, mean, variance)
    transposed = SampleBuffer.from_moments(np.ascontiguousarray(count.T).T, np.asfortranarray(mean),
                                           np.moveaxis(np.ascontiguousarray(np.moveaxis(variance, 2, 0)), 0, 2))
    for buffer in (plain, transposed, plain.merge(transposed)):
        for a in (buffer.count, buffer.mean, buffer.variance, buffer.variance_known):
            assert a.flags.c_contiguous and not a.flags.writeable
            with pytest.raises(ValueError):
                a.flags.writeable = True
    assert_array_equal(transposed.mean, plain.mean)


def test_select_keeps_the_statistics_and_features_of_the_channels_chosen():
    rng = np.random.default_rng(5)
    depth = SampleBuffer.from_moments(np.full((3, 4), 2), rng.random((3, 4)), np.zeros((3, 4)), channels=("Z",))
    buf = SampleBuffer.from_moments(rng.integers(0, 4, (3, 4)), rng.random((3, 4, 4)), rng.random((3, 4, 4)),
                                    variance_known=rng.random((3, 4)) > 0.5, features={"depth": depth})
    two = buf.select([3, 1])
    assert two.channels == ("A", "G")
    assert_array_equal(two.mean, buf.mean[..., [3, 1]])
    assert_array_equal(two.variance, buf.variance[..., [3, 1]])
    assert_array_equal(two.count, buf.count)
    assert_array_equal(two.variance_known, buf.variance_known)
    assert two.features["depth"] is buf.features["depth"]
    for bad, error in (([], ValueError), ([1, 1], ValueError), ([4], ValueError), ([0.5], ValueError)):
        with pytest.raises(error, match="channels"):
            buf.select(bad)
    # One index where a sequence belongs was "iteration over a 0-d array" or "'int' object is not
    # iterable", naming nothing; a set was taken in hash order (a red-team pass).
    for bad in (np.array(0), 0, {0, 1}, "RG", np.zeros((1, 2), int)):
        with pytest.raises(TypeError, match=r"^channels: expected a sequence of indices, got"):
            buf.select(bad)
    assert buf.select(np.array([3, 1])).channels == buf.select(i for i in (3, 1)).channels == ("A", "G")
    with pytest.raises(TypeError, match="variance_known: a masked array"):
        SampleBuffer(buf.count, buf.mean, buf.variance, buf.channels, np.ma.masked_array(buf.variance_known, True))


@pytest.mark.parametrize("bad, error", [(-5, ValueError), (1.5, ValueError), (True, TypeError), ("3", TypeError),
                                        (None, TypeError), (float("nan"), ValueError), (2**70, ValueError)])
def test_the_constructor_checks_nonfinite(bad, error):
    """`SampleBuffer(...)` took -5, 2**70, True and "3" as counts of dropped samples, truncated 1.5 and
    gave bare `int()` errors for NaN and None (a red-team pass)."""
    args = (np.full((1, 1), 2), np.ones((1, 1, 1)), np.ones((1, 1, 1)), ("Y",), np.ones((1, 1), bool))
    with pytest.raises(error, match="^nonfinite: "):
        SampleBuffer(*args, nonfinite=bad)
    assert SampleBuffer(*args, nonfinite=np.int64(3)).nonfinite == 3


@pytest.mark.parametrize("call", [
    lambda: SampleBuffer.from_moments([[1, 2], [3]], np.ones((2, 2, 1)), np.ones((2, 2, 1))),
    lambda: SampleBuffer.from_samples([[0], [1, 2]], [1.0, 2.0], (1, 2)),
    lambda: SampleBuffer.from_moments(np.full((1, 2), 2), [[[1.0], [2.0, 3.0]]], np.ones((1, 2, 1))),
], ids=["count", "pixels", "mean"])
def test_ragged_lists_are_refused_naming_the_argument(call):
    """numpy's "setting an array element with a sequence" named no argument (a red-team pass)."""
    with pytest.raises(TypeError, match=r"^\w+: not an array \(nested sequences of different lengths\?\)$"):
        call()


def test_select_keeps_the_buffer_kind():
    """Some channels of a buffer whose variances are final (prepare.EstimatedBuffer, a tile's) keep them final."""
    from awr_denoise.prepare import EstimatedBuffer
    buf = EstimatedBuffer(np.full((2, 2), 4), np.ones((2, 2, 4)), np.zeros((2, 2, 4)), ("R", "G", "B", "A"),
                          np.ones((2, 2), bool))
    assert type(buf.select([0, 1, 2])) is EstimatedBuffer
    assert type(SampleBuffer.from_moments(np.full((1, 1), 4), np.ones((1, 1, 2)), np.zeros((1, 1, 2))).select([0])) \
        is SampleBuffer


def test_a_crop_of_the_whole_image_keeps_its_nonfinite_count():
    """``crop()`` recorded no dropped samples even for the whole image (an attack pass); a tile cannot say how many
    of them were its own and records none."""
    buf = SampleBuffer.from_samples(np.array([0, 0, 1, 1, 3]), [1.0, 3.0, np.nan, 2.0, 5.0], (2, 2), nonfinite="drop")
    assert buf.nonfinite == 1
    assert buf.crop(slice(0, 2), slice(0, 2)).nonfinite == 1
    assert buf.crop(slice(0, 1), slice(0, 2)).nonfinite == 0
