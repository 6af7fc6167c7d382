"""Feature buffers (albedo, normal, depth): validation, exact merging, crops, samplers."""

from __future__ import annotations

import copy
import dataclasses
import pickle

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from awr_denoise import SampleBuffer, SampleRequest, UniformSampler
from awr_denoise.features import FEATURE_CHANNELS, FEATURE_NAMES, checked_features, feature_names

SHAPE = (5, 4)
# Chan's parallel update against the two-pass statistics of all samples at once (as test_buffers).
MERGE_RTOL = 1e-11
MERGE_ATOL = 1e-13


def _samples(rng, n=300, shape=SHAPE):
    """Flat pixels (each hit at least twice), RGB values and per-sample features."""
    h, w = shape
    pixels = np.concatenate([np.repeat(np.arange(h * w), 2), rng.integers(0, h * w, n - 2 * h * w)])
    values = rng.gamma(2.0, 0.5, (n, 3))
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    features = {"albedo": rng.uniform(0, 1, (n, 3)), "normal": normal, "depth": rng.uniform(1, 9, n)}
    return pixels, values, features


def _assert_same_stats(a: SampleBuffer, b: SampleBuffer, exact: bool = False) -> None:
    assert a.channels == b.channels
    assert_array_equal(a.count, b.count)
    assert_array_equal(a.variance_known, b.variance_known)
    if exact:
        assert_array_equal(a.mean, b.mean)
        assert_array_equal(a.variance, b.variance)
    else:
        assert_allclose(a.mean, b.mean, rtol=MERGE_RTOL, atol=MERGE_ATOL)
        assert_allclose(a.variance, b.variance, rtol=MERGE_RTOL, atol=MERGE_ATOL)


def test_feature_names_are_checked_and_ordered():
    assert feature_names(["depth", "normal"]) == ("normal", "depth")
    assert feature_names("normal, albedo") == ("albedo", "normal")
    assert feature_names("all") == FEATURE_NAMES == ("albedo", "normal", "depth")
    assert feature_names(()) == feature_names(None) == ()
    with pytest.raises(ValueError, match="features: 'Albedo' is not one of albedo, normal, depth"):
        feature_names(["Albedo"])
    with pytest.raises(ValueError, match="twice"):
        feature_names("depth,depth")
    with pytest.raises(TypeError, match="features"):
        feature_names(3)
    for left_out in ("albedo,", ",albedo", "albedo,,depth", " , "):  # a name left out is not tidied away
        with pytest.raises(ValueError, match="empty name between its commas"):
            feature_names(left_out)
    assert feature_names("") == feature_names("  ") == ()


def test_from_samples_features_equal_their_own_two_pass_statistics(rng):
    pixels, values, features = _samples(rng)
    buf = SampleBuffer.from_samples(pixels, values, SHAPE, features=features)
    assert tuple(buf.features) == FEATURE_NAMES
    for name, rows in features.items():
        alone = SampleBuffer.from_samples(pixels, rows, SHAPE, channels=FEATURE_CHANNELS[name])
        _assert_same_stats(buf.features[name], alone, exact=True)
        assert_array_equal(buf.features[name].count, buf.count)
    # Unit normals average to at most unit length; depth stays within the sampled range.
    assert (np.linalg.norm(buf.features["normal"].mean, axis=2) <= 1 + 1e-12).all()
    assert (buf.features["depth"].mean >= 1).all() and (buf.features["depth"].mean <= 9).all()


def test_merging_batches_with_features_equals_all_samples_at_once(rng):
    pixels, values, features = _samples(rng, n=400)
    whole = SampleBuffer.from_samples(pixels, values, SHAPE, features=features)
    cuts = [0, 37, 150, 151, 400]
    merged = SampleBuffer.empty(SHAPE)
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        part = {name: rows[lo:hi] for name, rows in features.items()}
        merged = merged.merge(SampleBuffer.from_samples(pixels[lo:hi], values[lo:hi], SHAPE, features=part))
    _assert_same_stats(merged, whole)
    assert tuple(merged.features) == FEATURE_NAMES
    for name in FEATURE_NAMES:
        _assert_same_stats(merged.features[name], whole.features[name])


def test_a_buffer_without_a_feature_holds_no_sample_of_it(rng):
    pixels, values, features = _samples(rng)
    with_depth = SampleBuffer.from_samples(pixels, values, SHAPE, features={"depth": features["depth"]})
    plain = SampleBuffer.from_samples(pixels, values, SHAPE)
    # Into an empty buffer: the features are taken bit for bit (a sampler's first round).
    first = SampleBuffer.empty(SHAPE).merge(with_depth)
    _assert_same_stats(first.features["depth"], with_depth.features["depth"], exact=True)
    # A later round without them: the radiance grows, the feature keeps its own counts.
    later = first.merge(plain)
    assert_array_equal(later.count, 2 * with_depth.count)
    assert_array_equal(later.features["depth"].count, with_depth.count)
    assert plain.merge(copy.deepcopy(plain)).features == {}


def test_crop_and_replace_carry_features(rng):
    pixels, values, features = _samples(rng)
    buf = SampleBuffer.from_samples(pixels, values, SHAPE, features=features)
    tile = buf.crop(slice(1, 4), slice(2, 4))
    for name in FEATURE_NAMES:
        assert_array_equal(tile.features[name].mean, buf.features[name].mean[1:4, 2:4])
    again = dataclasses.replace(buf, nonfinite=7)
    assert again.nonfinite == 7 and again.features["albedo"] is buf.features["albedo"]
    assert "features=('albedo', 'normal', 'depth')" in repr(buf)
    assert buf.nbytes > SampleBuffer.from_samples(pixels, values, SHAPE).nbytes
    back = pickle.loads(pickle.dumps(buf))   # buffers travel to worker processes
    assert tuple(back.features) == FEATURE_NAMES
    assert_array_equal(back.features["normal"].mean, buf.features["normal"].mean)


def test_from_moments_takes_feature_buffers():
    count = np.full((1, 2), 4)
    depth = SampleBuffer.from_moments(count, [[2.0, 3.0]], [[0.0, 0.0]], channels=["Z"],
                                      variance_known=np.zeros((1, 2), bool))
    buf = SampleBuffer.from_moments(count, np.ones((1, 2, 3)), np.ones((1, 2, 3)), features={"depth": depth})
    assert buf.features["depth"] is depth
    assert not buf.features["depth"].variance_known.any()   # a renderer's feature without a spread


@pytest.mark.parametrize("policy", ["drop", "zero"])
def test_a_non_finite_feature_makes_the_whole_sample_bad(policy):
    pixels = np.array([0, 0, 0])
    features = {"depth": np.array([1.0, np.inf, 3.0])}
    buf = SampleBuffer.from_samples(pixels, [1.0, 2.0, 3.0], (1, 1), features=features, nonfinite=policy)
    assert buf.nonfinite == 1
    if policy == "drop":
        assert buf.count[0, 0] == buf.features["depth"].count[0, 0] == 2
        assert buf.mean[0, 0, 0] == 2.0 and buf.features["depth"].mean[0, 0, 0] == 2.0
    else:
        assert buf.count[0, 0] == 3 and buf.features["depth"].mean[0, 0, 0] == pytest.approx(4 / 3)
    with pytest.raises(ValueError, match=r"features\[.depth.\]: 1 sample"):
        SampleBuffer.from_samples(pixels, [1.0, 2.0, 3.0], (1, 1), features=features)


def _depth(shape=(1, 2), channels=("Z",), **kw):
    n = len(channels)
    return SampleBuffer.from_moments(np.ones(shape, int), np.ones(shape + (n,)), np.zeros(shape + (n,)),
                                     channels=channels, **kw)


@pytest.mark.parametrize("features, error, message", [
    ({"Depth": _depth()}, ValueError, r"features: 'Depth' is not one of albedo, normal, depth"),
    ({"depth": np.ones((1, 2))}, TypeError, r"features\['depth'\]: expected a SampleBuffer, got ndarray"),
    ({"depth": _depth(shape=(2, 2))}, ValueError, r"features\['depth'\]: shape \(2, 2\) does not match"),
    ({"normal": _depth(channels=("R", "G", "B"))}, ValueError, r"features\['normal'\]: channels \('R', 'G', 'B'\), "
                                                              r"expected \('X', 'Y', 'Z'\)"),
    ({"depth": _depth(features={"depth": _depth()})}, ValueError, "cannot hold features of its own"),
    ([("depth", _depth())], TypeError, "features: expected a mapping"),
])
def test_bad_features_are_refused_naming_them(features, error, message):
    with pytest.raises(error, match=message):
        SampleBuffer.from_moments(np.ones((1, 2), int), np.ones((1, 2, 3)), np.zeros((1, 2, 3)), features=features)


def test_bad_per_sample_feature_rows_are_refused():
    with pytest.raises(ValueError, match=r"features\['albedo'\]: expected \(2, 3\) per-sample values"):
        SampleBuffer.from_samples(np.array([0, 0]), [1.0, 2.0], (1, 1), features={"albedo": np.ones((2, 2))})
    with pytest.raises(ValueError, match="'shade' is not one of"):
        SampleBuffer.from_samples(np.array([0, 0]), [1.0, 2.0], (1, 1), features={"shade": np.ones(2)})
    with pytest.raises(TypeError, match=r"features\['depth'\]: expected a numeric array"):
        SampleBuffer.from_samples(np.array([0, 0]), [1.0, 2.0], (1, 1), features={"depth": np.array(["a", "b"])})


def test_checked_features_is_read_only_and_ordered():
    owner = _depth()
    checked = checked_features(owner, {"depth": _depth(), "albedo": _depth(channels=("R", "G", "B"))})
    assert tuple(checked) == ("albedo", "depth")
    with pytest.raises(TypeError):
        checked["normal"] = owner  # type: ignore[index]


class _FeatureRenderer:
    """Radiance 1 + row, depth = column + 1 with noise: one feature row per sample."""

    def __init__(self, shape):
        self.shape = shape
        self.rng = np.random.default_rng(3)

    def __call__(self, request: SampleRequest) -> SampleBuffer:
        rows, cols, _ = request.pixel_list()
        values = (1.0 + rows)[:, None] * np.ones(3)
        depth = cols + 1.0 + self.rng.normal(0, 0.1, len(rows))
        return SampleBuffer.from_samples(np.stack([rows, cols], 1), values, self.shape, features={"depth": depth})


def test_sampler_tell_merges_the_renderers_features():
    renderer = _FeatureRenderer((4, 6))
    sampler = UniformSampler((4, 6))
    buffer = sampler.run(renderer, total_spp=12)
    depth = buffer.features["depth"]
    assert_array_equal(depth.count, buffer.count)
    assert_allclose(depth.mean[..., 0], np.arange(1, 7)[None, :] * np.ones((4, 1)), atol=0.1)
    assert depth.variance_known.all() and (depth.variance > 0).all()


@pytest.mark.parametrize("bad", [0, [], "", ()])
def test_features_that_are_not_a_mapping_are_refused_even_when_empty(bad):
    """`from_moments(features=0, [] or '')` was taken as no features (`features or {}`), where the same
    values anywhere else are refused (a red-team pass)."""
    with pytest.raises(TypeError, match="^features: expected a mapping"):
        SampleBuffer.from_moments(np.full((2, 2), 2), np.ones((2, 2, 3)), np.ones((2, 2, 3)), features=bad)


def test_a_features_merge_refusal_names_the_feature():
    """A depth whose merge passed float64, or one depth object shared by two batches, was refused naming
    `other` and "the same statistics" as if the radiance were at fault."""
    count = np.full((2, 2), 2)

    def with_depth(depth):
        return SampleBuffer.from_moments(count, np.ones((2, 2, 3)), np.ones((2, 2, 3)), features={"depth": depth})

    high, low = (SampleBuffer.from_moments(count, np.full((2, 2), v), np.zeros((2, 2)), channels=["Z"])
                 for v in (1.7e308, -1.7e308))
    with pytest.raises(ValueError, match=r"^features\['depth'\]: merged, the mean or variance of 4 pixel"):
        with_depth(high).merge(with_depth(low))
    with pytest.raises(ValueError, match=r"^features\['depth'\]: the same statistics"):
        with_depth(high).merge(with_depth(high))
