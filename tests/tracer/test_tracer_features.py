"""Features of the bundled path tracer: which hit they describe, and the radiance left unchanged."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("embreex")

from awr_denoise.features import FEATURE_NAMES  # noqa: E402
from awr_denoise.parallel import RendererSpec, TiledRenderer  # noqa: E402
from awr_denoise.requests import FeatureTracer, SampleRequest  # noqa: E402
from awr_denoise.tracer import PathTracer, load_scene  # noqa: E402

pytestmark = pytest.mark.tracer


def _scene(objects: list, materials: dict, camera: dict, environment: dict | None = None) -> dict:
    spec = {"name": "features", "width": 12, "height": 10, "camera": camera, "materials": materials,
            "objects": objects, "lights": [{"type": "directional", "direction": [0, -1, -1], "irradiance": 1.0}]}
    if environment:
        spec["environment"] = environment
    return spec


def _quad(z: float, half: float, material: str) -> dict:
    return {"shape": "quad", "corner": [-half, -half, z], "edge_u": [2 * half, 0, 0], "edge_v": [0, 2 * half, 0],
            "material": material}


def test_a_plane_seen_head_on_has_its_albedo_normal_and_depth():
    # Camera at z = 0 looking down -z at a diffuse quad at z = -3: every sample hits it.
    spec = _scene([_quad(-3.0, 10.0, "wall")], {"wall": {"type": "diffuse", "albedo": [0.2, 0.5, 0.7]}},
                  {"from": [0, 0, 0], "to": [0, 0, -1], "fov": 40})
    tracer = PathTracer(load_scene(spec), features="all")
    buffer = tracer(SampleRequest.uniform(tracer.shape, 3))
    assert tuple(buffer.features) == FEATURE_NAMES
    albedo, normal, depth = (buffer.features[n] for n in FEATURE_NAMES)
    np.testing.assert_allclose(albedo.mean, np.broadcast_to([0.2, 0.5, 0.7], albedo.mean.shape), atol=1e-12)
    np.testing.assert_allclose(normal.mean, np.broadcast_to([0, 0, 1], normal.mean.shape), atol=1e-9)
    np.testing.assert_allclose(depth.mean, 3.0, rtol=1e-9)   # camera-space z, not the ray length
    assert (albedo.variance < 1e-20).all() and (depth.variance < 1e-18).all()
    np.testing.assert_array_equal(albedo.count, buffer.count)


def test_albedo_and_normal_follow_a_mirror_and_depth_stays_on_it():
    # A mirror (reflectance 0.5) 2 units in front of the camera reflects the rays back onto a
    # diffuse wall (albedo 0.8) 2 units behind it: albedo 0.5 * 0.8, the wall's normal facing
    # the reflected ray (-z), depth 2 (the mirror: the surface the camera sees).
    spec = _scene([_quad(-2.0, 6.0, "mirror"), _quad(2.0, 20.0, "wall")],
                  {"mirror": {"type": "mirror", "specular": 0.5}, "wall": {"type": "diffuse", "albedo": 0.8}},
                  {"from": [0, 0, 0], "to": [0, 0, -1], "fov": 40})
    tracer = PathTracer(load_scene(spec), features="all")
    buffer = tracer(SampleRequest.uniform(tracer.shape, 2))
    np.testing.assert_allclose(buffer.features["albedo"].mean, 0.4, atol=1e-12)
    np.testing.assert_allclose(buffer.features["normal"].mean, np.broadcast_to([0, 0, -1], (10, 12, 3)), atol=1e-9)
    np.testing.assert_allclose(buffer.features["depth"].mean, 2.0, rtol=1e-9)


def test_misses_report_zero_and_hits_unit_normals():
    spec = _scene([{"shape": "sphere", "center": [0, 0, -4], "radius": 1.2, "material": "ball", "segments": 32,
                    "rings": 16}], {"ball": {"type": "glossy", "albedo": 0.5, "specular": 0.3, "roughness": 0.2}},
                  {"from": [0, 0, 0], "to": [0, 0, -1], "fov": 45}, environment={"type": "constant", "radiance": 1.0})
    tracer = PathTracer(load_scene(spec), features=("normal", "albedo", "depth"))
    buffer = tracer(SampleRequest.uniform(tracer.shape, 1))   # one sample: a pixel is a hit or a miss
    albedo, normal, depth = (buffer.features[n] for n in FEATURE_NAMES)
    hit = depth.mean[..., 0] > 0
    assert 0 < hit.sum() < hit.size
    np.testing.assert_allclose(np.linalg.norm(normal.mean[hit], axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(albedo.mean[hit], 0.8, atol=1e-12)      # kd + ks of a glossy surface
    assert (albedo.mean[~hit] == 0).all() and (normal.mean[~hit] == 0).all()
    # The normal faces the camera: its z component points back along the view axis.
    assert (normal.mean[hit][:, 2] > 0).all()


@pytest.mark.parametrize("name", ["sky_objects", "cornell_gi"])
def test_bundled_scenes_keep_the_conventions_and_the_radiance(name):
    scene = load_scene(name, width=40, height=32)
    request = SampleRequest.uniform(scene.shape, 1)
    with_features = PathTracer(scene, features="all", seed=3)(request)
    plain = PathTracer(scene, seed=3)(request)
    np.testing.assert_array_equal(with_features.mean, plain.mean)   # features draw no random numbers
    assert plain.features == {}
    albedo, normal, depth = (with_features.features[n].mean for n in FEATURE_NAMES)
    assert albedo.min() >= 0 and albedo.max() <= 1
    length = np.linalg.norm(normal, axis=2)
    assert np.all((np.abs(length - 1) < 1e-9) | (length == 0))
    assert depth.min() >= 0 and (depth > 0).mean() > 0.5


def test_tiles_and_process_workers_give_the_same_features():
    scene = load_scene("sky_objects", width=24, height=20)
    request = SampleRequest.uniform(scene.shape, 2)
    whole = PathTracer(scene, features="all", batch_size=200)
    assert isinstance(whole, FeatureTracer)
    reference = whole(request)
    spawned = PathTracer(scene, features="all", threads=2, batch_size=200, workers="processes")
    try:
        in_processes = spawned(request)
    finally:
        spawned.close()
    tiled = TiledRenderer(RendererSpec.tracer("sky_objects", width=24, height=20, threads=1, features="all"),
                          tile=8)(request)
    for other in (in_processes, tiled):
        np.testing.assert_array_equal(other.mean, reference.mean)
        for name in FEATURE_NAMES:
            np.testing.assert_array_equal(other.features[name].mean, reference.features[name].mean)
            np.testing.assert_array_equal(other.features[name].variance, reference.features[name].variance)
