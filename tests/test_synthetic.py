"""Synthetic renderer: addressable randomness, unbiased noise models and known references."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy import stats

from awr_denoise import SampleRequest
from awr_denoise.metrics import relmse
from awr_denoise.synthetic import SCENES, SyntheticRenderer, hash_uniform, make_scene

SHAPE = (24, 32)
# Statistics of rounds merged with Chan's update against one request of all samples.
SPLIT_RTOL = 1e-11
SPLIT_ATOL = 1e-13
# Midpoint quadrature over the two noise uniforms: the expectation of a sample is the clean value.
QUADRATURE_POINTS = 1000
QUADRATURE_RTOL = 1e-3


def test_hash_uniform_is_a_pure_function_in_unit_interval():
    pixel = np.arange(20000) % 97
    index = np.arange(20000) // 97
    u = hash_uniform(3, pixel, index, 0)
    assert ((u >= 0) & (u < 1)).all()
    assert_array_equal(u, hash_uniform(3, pixel, index, 0))
    for other in (hash_uniform(4, pixel, index, 0), hash_uniform(3, pixel, index, 1),
                  hash_uniform(3, pixel, index + 1, 0)):
        assert np.mean(u == other) < 1e-3


def test_hash_uniform_is_uniform():
    u = hash_uniform(0, np.arange(100000), np.zeros(100000, np.int64), 2)
    observed = np.bincount((u * 50).astype(int), minlength=50)
    p = stats.chisquare(observed).pvalue
    assert p > 1e-4
    assert abs(np.corrcoef(u[:-1], u[1:])[0, 1]) < 0.02


@pytest.mark.parametrize("name", sorted(SCENES))
def test_same_samples_however_the_request_is_split(name):
    scene = make_scene(name, SHAPE)
    renderer = SyntheticRenderer(scene, seed=7)
    whole = renderer(SampleRequest.uniform(SHAPE, 8))
    first = renderer(SampleRequest.uniform(SHAPE, 3))
    rest = renderer(SampleRequest.uniform(SHAPE, 5, first_index=3))
    merged = first.merge(rest)
    assert_array_equal(merged.count, whole.count)
    assert_allclose(merged.mean, whole.mean, rtol=SPLIT_RTOL, atol=SPLIT_ATOL)
    assert_allclose(merged.variance, whole.variance, rtol=SPLIT_RTOL, atol=SPLIT_ATOL)
    assert renderer.samples_rendered == 16 * SHAPE[0] * SHAPE[1]


def test_a_large_request_is_rendered_in_parts_with_the_same_statistics(monkeypatch):
    """Every sample of a request was held at once; in parts of ``MAX_PART_SAMPLES`` (bands of rows) the
    statistics are the same bit for bit, and each part holds at most that many samples."""
    import awr_denoise.synthetic as synthetic

    renderer = SyntheticRenderer(make_scene("edges", (20, 30)), seed=1)
    rng = np.random.default_rng(0)
    request = SampleRequest(rng.integers(0, 9, (20, 30)), rng.integers(0, 5, (20, 30)))
    whole = renderer(request)
    sizes, values = [], renderer._values
    monkeypatch.setattr(renderer, "_values", lambda rows, *rest: sizes.append(rows.size) or values(rows, *rest))
    monkeypatch.setattr(synthetic, "MAX_PART_SAMPLES", 300)
    parts = renderer(request)
    assert len(sizes) > 1 and max(sizes) <= 300 and sum(sizes) == request.total
    for field in ("count", "mean", "variance", "variance_known"):
        assert_array_equal(getattr(parts, field), getattr(whole, field))


def test_seeds_give_reproducible_and_different_samples():
    scene = make_scene("gradient", SHAPE)
    req = SampleRequest.uniform(SHAPE, 2)
    a = SyntheticRenderer(scene, seed=1).samples(req)[1]
    assert_array_equal(a, SyntheticRenderer(scene, seed=1).samples(req)[1])
    assert not np.allclose(a, SyntheticRenderer(scene, seed=2).samples(req)[1])


def test_request_of_another_shape_is_refused():
    renderer = SyntheticRenderer(make_scene("edges", SHAPE))
    with pytest.raises(ValueError, match="request: shape"):
        renderer(SampleRequest.uniform((4, 4), 1))


def test_unknown_scene_is_refused():
    with pytest.raises(ValueError, match="name: 'cornell'"):
        make_scene("cornell")


@pytest.mark.parametrize("name", sorted(SCENES))
def test_noise_has_the_clean_value_as_expectation(name):
    """Midpoint quadrature over the two uniforms the noise model reads."""
    scene = make_scene(name, SHAPE)
    g = (np.arange(QUADRATURE_POINTS) + 0.5) / QUADRATURE_POINTS
    u = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    for x, y in [(3.3, 4.1), (20.5, 11.7), (16.2, 9.6)]:
        xs, ys = np.full(len(u), x), np.full(len(u), y)
        clean = scene.image(xs, ys)
        values = scene.noise(clean, xs, ys, u)
        assert_allclose(values.mean(axis=0), clean[0], rtol=QUADRATURE_RTOL, atol=1e-9)
        assert values.std(axis=0).max() > 0.01 * clean[0].max()  # it is noisy


def test_reference_is_the_box_filtered_image():
    """The red channel of "gradient" is linear in x, so its box filter is the value at the centre."""
    scene = make_scene("gradient", SHAPE)
    ref = scene.reference()
    cols = np.arange(SHAPE[1])
    assert_allclose(ref[..., 0], np.broadcast_to(0.2 + 0.6 * (cols + 0.5) / SHAPE[1], SHAPE), rtol=1e-12)
    assert ref.shape == SHAPE + (3,)


def test_the_reference_sees_a_light_that_grazes_a_pixel():
    """The error of the plain mean falls like 1/N against the reference, also at the light's rim
    (an 8x8 sub-pixel grid missed slivers of the hdr_source light: the error stopped falling)."""
    scene = make_scene("hdr_source", (96, 96))
    ref = scene.reference()
    errors = [relmse(SyntheticRenderer(scene, seed=1)(SampleRequest.uniform(scene.shape, spp)).mean, ref)
              for spp in (64, 1024)]
    assert errors[1] < errors[0] / 8, errors


def test_uniform_rendering_converges_to_the_reference():
    scene = make_scene("edges", SHAPE)
    buf = SyntheticRenderer(scene, seed=0)(SampleRequest.uniform(SHAPE, 64))
    ref = scene.reference(supersampling=16)
    # Per pixel and channel, the error of the mean against its own standard error.
    z = (buf.mean - ref) / np.sqrt(buf.variance_of_mean())
    assert abs(z.mean()) < 0.05
    assert 0.8 < z.std() < 1.2


def test_scene_properties_the_tests_rely_on():
    hdr = make_scene("hdr_source", (64, 64)).reference()
    lum = hdr[..., 1]
    assert lum.max() >= 1000 * np.median(lum)  # a source 1000x brighter than its surroundings
    fire = make_scene("fireflies", (8, 8))
    x, y = np.full(4, 2.0), np.full(4, 3.0)
    clean = fire.image(x, y)
    spikes = fire.noise(clean, x, y, np.array([[0.001, 0.5], [0.003, 0.1], [0.5, 0.5], [0.9, 0.9]]))
    assert_allclose(spikes[:2] / clean[:2], 100.0)  # firefly samples are 100x the mean
    assert (spikes[2:] < 2 * clean[2:]).all()
