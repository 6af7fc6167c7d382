"""Correctness tests of the bundled path tracer (needs the embreex extra)."""

from __future__ import annotations

import json
import logging
import os
import re
import subprocess
import sys
from pathlib import Path
from unittest import mock

import numpy as np
import pytest

pytest.importorskip("embreex")

from scipy import stats  # noqa: E402

from awr_denoise.buffers import SampleBuffer  # noqa: E402
from awr_denoise.requests import SampleRequest  # noqa: E402
from awr_denoise.tracer import PathTracer, list_scenes, load_scene, render  # noqa: E402
from awr_denoise.tracer.environment import (  # noqa: E402
    LatLongEnvironment, direction_to_uv, make_sky_envmap, uv_to_direction)
from awr_denoise.tracer.materials import parse_material  # noqa: E402
from awr_denoise.tracer.sampler import IndependentSampler, SobolSampler  # noqa: E402
from awr_denoise.tracer.scenes import BUNDLED_SCENES  # noqa: E402

pytestmark = pytest.mark.tracer

REPO = Path(__file__).resolve().parents[2]

EXPECTED_DIMENSIONS = {
    "default": ("pixel_x", "pixel_y", "light_u", "light_v"),
    "chess_dof": ("pixel_x", "pixel_y", "lens_u", "lens_v"),
    "rolling_balls": ("pixel_x", "pixel_y", "lens_u", "lens_v", "time"),
    "sky_objects": ("pixel_x", "pixel_y", "lens_u", "lens_v", "light_u", "light_v"),
    "soft_shadows": ("pixel_x", "pixel_y", "lens_u", "lens_v", "light_u", "light_v"),
    "cornell_gi": ("pixel_x", "pixel_y", "lens_u", "lens_v", "light_u", "light_v", "bounce0_u", "bounce0_v"),
}
STATED = {"chess_dof": 4, "rolling_balls": 5, "sky_objects": 6, "soft_shadows": 6, "cornell_gi": 8}


def _furnace_scene(max_depth: int = 0, material: dict | None = None) -> dict:
    return {
        "name": "furnace", "width": 24, "height": 24,
        "camera": {"from": [0, 0, 3], "to": [0, 0, 0], "fov": 45},
        "integrator": {"max_depth": max_depth},
        "materials": {"white": material or {"type": "diffuse", "albedo": 1.0}},
        "objects": [{"shape": "sphere", "center": [0, 0, 0], "radius": 1.0, "material": "white",
                     "segments": 24, "rings": 12}],
        "environment": {"type": "constant", "radiance": 1.0},
    }


def _standard_error(buffer: SampleBuffer, mask: np.ndarray) -> float:
    """Standard error of the average of the pixel means inside ``mask``."""
    v = buffer.variance[mask] / buffer.count[mask][:, None]
    return float(np.sqrt(v.sum(axis=0)).max() / mask.sum())


# ------------------------------------------------------------------ packaging and API
def test_import_without_embreex_raises_install_hint() -> None:
    code = ("import sys; sys.modules['embreex'] = None\n"
            "try:\n    import awr_denoise.tracer\nexcept ImportError as e:\n    print('HINT', e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True)
    assert 'pip install "awr-denoise[tracer]"' in out.stdout


def test_core_library_does_not_import_tracer() -> None:
    code = ("import sys, awr_denoise, awr_denoise.buffers, awr_denoise.requests\n"
            "print('awr_denoise.tracer' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True)
    assert out.stdout.strip() == "False"


def test_list_and_load_scenes() -> None:
    names = list_scenes()
    assert set(names) == set(EXPECTED_DIMENSIONS)
    for name in names:
        scene = load_scene(name, width=20, height=10)
        assert (scene.name, scene.width, scene.height) == (name, 20, 10)
        assert scene.description
        if name in STATED:
            assert scene.dimension == STATED[name]


def test_bad_input_names_the_parameter() -> None:
    with pytest.raises(ValueError, match="scene: 'nope' .*cornell_gi"):
        load_scene("nope")
    with pytest.raises(ValueError, match="sampler: 'halton' is not one of independent, sobol"):
        PathTracer("default", sampler="halton")
    spec = dict(BUNDLED_SCENES["default"], dimension=7)
    with pytest.raises(ValueError, match="dimension: the scene states 7 but its effects need 4"):
        load_scene(spec)
    bad = json.loads(json.dumps(BUNDLED_SCENES["default"]))
    bad["materials"]["red"]["type"] = "velvet"
    with pytest.raises(ValueError, match="materials.red.type: 'velvet' is not one of diffuse, glossy, mirror"):
        load_scene(bad)


def _scene_with(**changes) -> dict:
    """The default scene with ``changes`` at dotted paths (``objects.1.radius``), as JSON would give it."""
    spec = json.loads(json.dumps(BUNDLED_SCENES["default"]))
    for dotted, value in changes.items():
        *parents, last = dotted.split(".")
        node = spec
        for key in parents:
            node = node[int(key)] if isinstance(node, list) else node.setdefault(key, {})
        if isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value
    return spec


SPHERE = next(i for i, o in enumerate(BUNDLED_SCENES["default"]["objects"]) if o["shape"] == "sphere")
LIGHT_INDEX = next(i for i, o in enumerate(BUNDLED_SCENES["default"]["objects"]) if "emission" in o)
MALFORMED = [  # (change, the field the refusal names)
    ({"environment": "sky"}, "environment: expected an object"),
    ({"materials.red": 5}, "materials.red: expected an object"),
    ({"objects": {"a": 1}}, "objects: expected a list"),
    ({"objects.0": 5}, r"objects\[0\]: expected an object"),
    ({"camera": [1, 2]}, "camera: expected an object"),
    ({"integrator": 3}, "integrator: expected an object"),
    ({"lights": [7]}, r"lights\[0\]: expected an object"),
    ({"width": 2.7}, "width: must be a whole number, got 2.7"),
    ({"width": "abc"}, "width: expected a number, got str 'abc'"),
    ({"width": True}, "width: expected a number, got the bool True"),
    ({"width": 1e300}, r"width: must be <= 1048576, got 1e\+300"),
    ({"dimension": "four"}, "dimension: expected a number"),
    # Just past the bounds: 10**9 (a runaway allocation before the bounds) would take the machine with it.
    ({"integrator.max_depth": 257}, "integrator.max_depth: must be <= 256, got 257"),
    ({"integrator.max_specular_depth": -3}, "integrator.max_specular_depth: must be >= 0, got -3"),
    ({f"objects.{SPHERE}.segments": 1025}, rf"objects\[{SPHERE}\].segments: must be <= 1024, got 1025"),
    ({f"objects.{SPHERE}.rings": 0}, rf"objects\[{SPHERE}\].rings: must be >= 2, got 0"),
    ({f"objects.{SPHERE}.radius": float("nan")}, rf"objects\[{SPHERE}\].radius: must be a finite number"),
    ({f"objects.{SPHERE}.radius": float("inf")}, rf"objects\[{SPHERE}\].radius: must be a finite number"),
    ({f"objects.{SPHERE}.radius": -1}, rf"objects\[{SPHERE}\].radius: must be > 0, got -1"),
    ({"objects.0": {"shape": "mesh", "faces": [[0, 1, 2]]}}, r"objects\[0\].vertices: missing"),
    ({"objects.0": {"shape": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, float("nan"), 0]], "faces": [[0, 1, 2]]}},
     r"objects\[0\].vertices: must be finite"),
    ({"objects.0": {"shape": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 1.5]]}},
     r"objects\[0\].faces: must be whole"),
    ({"objects.0": {"shape": "lathe", "base": [0, 0, 0], "profile": [[1, 0]]}}, r"objects\[0\].profile"),
    ({"objects.0": {"shape": "lathe", "base": [0, 0, 0], "scale": float("nan")}}, r"objects\[0\].scale"),
    ({f"objects.{SPHERE}.motion": {"angular_velocity_degrees": float("nan")}}, "angular_velocity_degrees"),
    ({"environment": {"type": "constant", "radiance": [1, 1]}}, "environment.radiance: expected a number or 3"),
    ({"environment": {"type": "latlong"}}, "environment.path: expected a file name"),
    ({"environment": {"type": "latlong", "path": "sky.exr", "scale": float("inf")}}, "environment.scale"),
    # A light without a position was a KeyError, a zero direction a NaN light, a checker of scale 0 or a
    # camera's NaN shutter garbage: each is one line naming it.
    ({"lights": [{"type": "point"}]}, r"lights\[0\]\.position: missing"),
    ({"lights": [{"type": "directional", "direction": [0, 0, 0]}]}, r"lights\[0\]\.direction: must be non-zero"),
    ({"materials.floor.texture.scale": 0}, r"materials\.floor\.texture\.scale: must be > 0"),
    ({"materials.floor.texture": "checker"}, r"materials\.floor\.texture: expected an object"),
    ({"camera.fov": "wide"}, "camera.fov: expected a number, got str 'wide'"),
    ({"camera.shutter": [0, float("nan")]}, "camera.shutter: must be a finite number"),
    ({"camera.up": [0, 1]}, "camera.up: expected 3 finite numbers"),
    # The nineteenth pass: strings, booleans and integers past float64 in vectors, colours and meshes were
    # converted (or an internal OverflowError), numpy's words named no field, a degenerate camera or light
    # rendered without a word, a small file asked for tens of GB.
    ({"materials.red.albedo": ["0.5", "0.5", "0.5"]}, r"materials\.red\.albedo: expected a number or 3 numbers"),
    ({"materials.red.albedo": [1, 2]}, r"materials\.red\.albedo: expected a number or 3 numbers"),
    ({f"objects.{SPHERE}.center": [10**400, 0, 0]}, rf"objects\[{SPHERE}\]\.center: expected 3 finite numbers"),
    ({f"objects.{SPHERE}.center": [True, 0, 0]}, rf"objects\[{SPHERE}\]\.center: expected 3 finite numbers"),
    ({"objects.0": {"shape": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[False, True, 2]]}},
     r"objects\[0\]\.faces: expected \(N, 3\) lists of numbers"),
    ({"materials.red.roughness": None}, r"materials\.red\.roughness: expected a number"),
    ({"camera.to": [0.0, 10.0, 4.2]}, r"camera\.up: .* is parallel to the view direction"),
    ({"camera.up": [0, 0, 0]}, r"camera\.up: must be non-zero"),
    ({"materials.floor.texture.offset": [1e20, 0, 0]}, r"materials\.floor\.texture\.offset: beyond"),
    ({f"objects.{LIGHT_INDEX}.edge_v": [0, 0, 0]},
     rf"objects\[{LIGHT_INDEX}\]\.emission: an emissive object needs an area"),
    ({"lights": [{"type": "point", "position": [0, 2, 0]}] * 65}, r"lights: 65 lights, beyond the 64"),
    ({"objects": [{"shape": "sphere", "center": [0, 0, 0], "segments": 1024, "rings": 1024, "material": "red"}] * 3},
     r"objects\[2\]: the scene up to it has \d+ triangles, beyond the 4194304"),
    ({"objects.0": {"shape": "lathe", "base": [0, 0, 0], "segments": 1024, "profile": [[1, i] for i in range(3000)]}},
     r"objects\[0\]: its profile turned segments times makes up to 6141952 triangles"),
    ({"environment": {"type": "sky", "width": 100000}}, r"environment\.width: must be <= 4096"),
    ({"environment": {"type": "sky", "sun_radiance": 1e308}}, r"environment\.sun_radiance: must be <= 65504"),
    ({"environment": {"type": "sky", "sky_intensity": True}}, r"environment\.sky_intensity: expected a number"),
    ({"description": [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[["deep"]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]},
     "nested deeper than 32 levels"),
]


@pytest.mark.parametrize("changes, needle", MALFORMED, ids=[str(m[0])[:40] for m in MALFORMED])
def test_a_malformed_scene_is_refused_naming_the_field(changes, needle) -> None:
    """Every malformed field gives a ValueError (a TypeError for a wrong type) that names it: no
    KeyError, no truncation, no hang."""
    with pytest.raises((ValueError, TypeError), match=needle):
        load_scene(_scene_with(**changes))


LIGHT = next(i for i, o in enumerate(BUNDLED_SCENES["default"]["objects"]) if "emission" in o)
OBJECTS = BUNDLED_SCENES["default"]["objects"]
FAR = 1e39  # finite in float64, Inf in float32
BEYOND_FLOAT32 = [  # (change, the refusal naming the field): each rendered all black, or failed only at the write
    ({"objects": [*OBJECTS, {"shape": "sphere", "center": [FAR, 0, 0], "radius": 1, "material": "red"}]},
     rf"objects\[{len(OBJECTS)}\]: its geometry reaches 1e\+39, beyond the ±1e\+11 scene units the tracer traces "
     r"in \(float32\)"),
    ({f"objects.{SPHERE}.radius": 1e300}, rf"objects\[{SPHERE}\]: its geometry reaches 1e\+300, beyond the ±1e\+11"),
    ({"objects": [*OBJECTS, {"shape": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, FAR, 0]], "faces": [[0, 1, 2]],
                             "material": "red"}]}, rf"objects\[{len(OBJECTS)}\]: its geometry reaches 1e\+39"),
    # Past float64 while it is built (the lathe's profile times 1e308): refused, without numpy's overflow warnings.
    ({"objects.0": {"shape": "lathe", "base": [0, 0, 0], "scale": 1e308, "material": "red"}},
     r"objects\[0\]: its geometry reaches inf, beyond the ±1e\+11"),
    ({"camera.shutter": [0, 1], f"objects.{SPHERE}.motion": {"velocity": [FAR, 0, 0]}},
     rf"objects\[{SPHERE}\]\.motion: over the shutter \[0, 1\] its geometry reaches 1e\+39, beyond the ±1e\+11"),
    ({"camera.shutter": [0, 1e300], f"objects.{SPHERE}.motion": {"velocity": [1, 0, 0]}},
     rf"objects\[{SPHERE}\]\.motion: over the shutter \[0, 1e\+300\] its geometry reaches 1e\+300"),
    ({"camera.from": [0, FAR, 4]}, r"camera\.from: 1e\+39 is beyond the ±1e\+11 scene units"),
    ({"camera.to": [0, 0, -FAR]}, r"camera\.to: 1e\+39 is beyond the ±1e\+11"),
    ({"camera.aperture_radius": FAR}, r"camera\.aperture_radius: 1e\+39 is beyond the ±1e\+11"),
    ({"camera.aperture_radius": 0.1, "camera.focus_distance": FAR}, r"camera\.focus_distance: 1e\+39 is beyond"),
    ({"lights": [{"type": "point", "position": [FAR, 0, 0]}]}, r"lights\[0\]\.position: 1e\+39 is beyond the ±1e\+11"),
    ({"lights": [{"type": "point", "position": [0, 3, 0], "intensity": 1e30}]},
     r"lights\[0\]\.intensity: 1e\+30 is beyond the 1e\+15 a radiance may reach \(a sample's square, its variance, "
     r"must stay within float32\)"),
    ({"lights": [{"type": "directional", "direction": [0, -1, 0], "irradiance": [1, FAR, 1]}]},
     r"lights\[0\]\.irradiance: 1e\+39 is beyond the 1e\+15"),
    ({f"objects.{LIGHT}.emission": 1e30}, rf"objects\[{LIGHT}\]\.emission: 1e\+30 is beyond the 1e\+15"),
    ({"environment": {"type": "constant", "radiance": 1e35}}, r"environment\.radiance: 1e\+35 is beyond the 1e\+15"),
    ({"environment": {"type": "sky", "scale": 1e30}},
     r"environment\.scale: the sky's radiance times the scale 1e\+30 reaches .*e\+32, beyond the 1e\+15"),
]


@pytest.mark.parametrize("changes, needle", BEYOND_FLOAT32,
                         ids=[m[1].split(":")[0].replace("\\", "") for m in BEYOND_FLOAT32])
def test_a_scene_beyond_float32_is_refused_naming_the_field(changes, needle) -> None:
    """Finite in float64 is not enough: Embree traces in float32 (one vertex at Inf and every ray misses the
    whole BVH, exit 0 with a black image) and the buffers store a sample's square, which past 1e19 was refused
    only at the write, blaming the output file. The scene is refused instead, the field named first."""
    with np.errstate(over="raise", invalid="raise"):  # no overflow of the parser's own leaks as a warning
        with pytest.raises(ValueError, match="^" + needle):
            load_scene(_scene_with(**changes))


def _scaled_default(k: float) -> dict:
    """The default scene with every length times ``k`` (the checker too): the same image, lit by its area light."""
    spec = _scene_with(width=16, height=16)
    for obj in spec["objects"]:
        for key in ("center", "min", "max", "corner", "edge_u", "edge_v"):
            if key in obj:
                obj[key] = [k * x for x in obj[key]]
        if "radius" in obj:
            obj["radius"] *= k
    spec["camera"]["from"] = [k * x for x in spec["camera"]["from"]]
    spec["camera"]["to"] = [k * x for x in spec["camera"]["to"]]
    spec["materials"]["floor"]["texture"]["scale"] *= k
    return spec


def test_a_scene_reaching_the_coordinate_bound_renders_as_at_unit_scale() -> None:
    """The bound leaves Embree's float32 room: the default scene scaled until it reaches ±1e11 (its camera
    there) renders the image it does at its own scale, where ±2e12 already loses hits."""
    from awr_denoise.tracer.limits import MAX_COORDINATE

    k = 0.999 * MAX_COORDINATE / max(abs(x) for x in BUNDLED_SCENES["default"]["camera"]["from"])
    images = []
    for spec in (_scaled_default(1.0), _scaled_default(k)):
        tracer = PathTracer(load_scene(spec), seed=3, threads=1)
        images.append(tracer(SampleRequest.uniform(tracer.shape, 4)).mean)
    assert images[0].max() > 0.1
    np.testing.assert_allclose(images[1], images[0], rtol=1e-4, atol=1e-5)
    with pytest.raises(ValueError, match=r"camera\.from: 1\.0\d*e\+11 is beyond"):
        load_scene(_scaled_default(1.002 * k))


UNKNOWN_FIELDS = [  # (change, where, the unknown field, the field meant): a typo did nothing
    ({"integrator.max_dept": 3}, "integrator", "max_dept", "max_depth"),
    ({"lights": [{"type": "point", "position": [0, 3, 0], "intensty": 5}]}, r"lights\[0\]", "intensty", "intensity"),
    ({"lights": [{"type": "directional", "direction": [0, -1, 0], "irradience": 2}]}, r"lights\[0\]", "irradience",
     "irradiance"),
    ({"environment": {"type": "constant", "radince": 2}}, "environment", "radince", "radiance"),
    ({"environment": {"type": "latlong", "path": "sky.exr", "scal": 2}}, "environment", "scal", "scale"),
    ({"materials.floor.texture.scal": 2}, r"materials\.floor\.texture", "scal", "scale"),
    ({f"objects.{SPHERE}.motion": {"velocty": [1, 0, 0]}}, rf"objects\[{SPHERE}\]\.motion", "velocty", "velocity"),
    # Refused before, the same way: the message is one pattern wherever the typo is.
    ({"environment": {"type": "sky", "sun_elevation": 10}}, "environment", "sun_elevation", "sun_elevation_degrees"),
    ({"camera.fov_degrees": 30}, "camera", "fov_degrees", "fov"),
    ({"materials.red.albdo": 0.5}, r"materials\.red", "albdo", "albedo"),
    ({f"objects.{SPHERE}.radus": 2}, rf"objects\[{SPHERE}\]", "radus", "radius"),
    ({"lihgts": []}, "scene", "lihgts", "lights"),
]


@pytest.mark.parametrize("changes, where, unknown, meant", UNKNOWN_FIELDS,
                         ids=[f"{u[1]}.{u[2]}".replace("\\", "") for u in UNKNOWN_FIELDS])
def test_an_unknown_field_is_refused_naming_it_and_the_valid_ones(changes, where, unknown, meant) -> None:
    with pytest.raises(ValueError, match=rf"^{where}: unknown field\(s\) \['{unknown}'\]; valid: \[.*'{meant}'.*\]$"):
        load_scene(_scene_with(**changes))


def test_a_scene_file_beyond_float32_or_with_a_typo_names_the_file_and_the_field(tmp_path) -> None:
    path = tmp_path / "far.json"
    far = {"shape": "sphere", "center": [FAR, 0, 0], "radius": 1, "material": "red"}
    path.write_text(json.dumps(_scene_with(objects=[*OBJECTS, far])))
    named = re.escape(str(path))
    with pytest.raises(ValueError, match=rf"^{named}: objects\[{len(OBJECTS)}\]: its geometry reaches 1e\+39"):
        load_scene(path)
    path.write_text(json.dumps(_scene_with(**{"integrator.max_dept": 3})))
    with pytest.raises(ValueError, match=rf"^{named}: integrator: unknown field\(s\) \['max_dept'\]"):
        load_scene(path)


def test_a_field_given_twice_in_a_scene_file_is_refused(tmp_path) -> None:
    """JSON keeps the second of two equal keys: an invalid first material, or a first fov, did nothing."""
    path = tmp_path / "twice.json"
    text = json.dumps(_scene_with())
    path.write_text(text.replace('"fov": 38', '"fov": 179.9, "fov": 38'))
    with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}: the field 'fov' is given twice in one object"):
        load_scene(path)


def test_directions_far_from_length_one_keep_their_direction() -> None:
    """A light direction of 1e200 (its square past float64) was normalised to 0, the light dropped; an
    axis of 1e-170 (its square below the smallest float) was refused as zero; a camera 1 unit long at
    1e6 was refused as a camera of no length (np.allclose's relative tolerance)."""
    scene = load_scene(_scene_with(lights=[{"type": "directional", "direction": [0, -1e200, 0]}]))
    np.testing.assert_array_equal(scene.delta_lights[0].direction, [0.0, -1.0, 0.0])
    moving = load_scene(_scene_with(**{f"objects.{SPHERE}.motion": {"axis": [0, 1e-170, 0],
                                                                     "angular_velocity_degrees": 90},
                                       "camera.shutter": [0, 1], "dimension": 5}))
    np.testing.assert_array_equal(next(o.motion for o in moving.objects if o.motion is not None).axis, [0, 1, 0])
    load_scene(_scene_with(**{"camera.from": [1e6, 1, 1], "camera.to": [1e6 + 1, 1, 1]}))


def test_awr_render_refuses_a_scene_beyond_float32_and_writes_nothing(tmp_path) -> None:
    """The report: ``awr render far.json`` exited 0 with an all-black image; now exit 2, one line, no file."""
    path = tmp_path / "far.json"
    far = {"shape": "sphere", "center": [FAR, 0, 0], "radius": 1, "material": "red"}
    path.write_text(json.dumps(_scene_with(objects=[*OBJECTS, far])))
    script = Path(sys.executable).with_name("awr")
    command = [str(script)] if script.exists() else [sys.executable, "-m", "awr_denoise.cli.main"]
    out = subprocess.run([*command, "render", str(path), "--spp", "4", "--width", "16", "--height", "16",
                          "-o", str(tmp_path / "far.exr"), "-q"], capture_output=True, text=True, cwd=tmp_path,
                         timeout=300)
    assert out.returncode == 2, out.stderr
    assert out.stderr.strip().splitlines() == [f"awr: error: {path}: objects[{len(OBJECTS)}]: its geometry reaches "
                                               "1e+39, beyond the ±1e+11 scene units the tracer traces in (float32)"]
    assert not list(tmp_path.glob("far.*exr"))


def test_numpy_numbers_are_numbers_to_a_scene() -> None:
    """A caller's numpy integers and floats pass the checks that refuse strings and bools."""
    spec = _scene_with(**{f"objects.{SPHERE}.radius": np.float32(0.5), f"objects.{SPHERE}.segments": np.int64(12)})
    assert load_scene(spec, width=np.int64(20), height=np.int32(10)).shape == (10, 20)


def test_a_scene_file_names_itself_and_refuses_nan(tmp_path) -> None:
    path = tmp_path / "s.json"
    path.write_text(json.dumps(_scene_with(**{f"objects.{SPHERE}.radius": 1.0})).replace("1.0", "NaN", 1))
    with pytest.raises(ValueError, match=r"s\.json: NaN is not a number a scene may hold"):
        load_scene(path)
    path.write_text('{"width": }')
    with pytest.raises(ValueError, match=r"s\.json: not valid JSON"):
        load_scene(path)
    # Nested thousands deep, Python's reader raised RecursionError: an internal error of the command, exit 1
    # (a red-team pass); it is the file's.
    for deep in ("[" * 100_000 + "]" * 100_000, '{"a":' * 100_000 + "1" + "}" * 100_000):
        path.write_text(deep)
        with pytest.raises(ValueError, match=r"s\.json: not a scene: its JSON is nested deeper"):
            load_scene(path)
    path.write_text(json.dumps(_scene_with(width=0)))
    with pytest.raises(ValueError, match=r"s\.json: width: must be >= 1, got 0"):
        load_scene(path)
    path.write_text(json.dumps(_scene_with(width="abc")))  # a wrong type: a TypeError, named by the file too
    with pytest.raises(TypeError, match=r"s\.json: width: expected a number"):
        load_scene(path)


@pytest.mark.exr
def test_scene_files_lists_the_environment_map_and_a_fifo_is_never_opened(tmp_path) -> None:
    import os

    from awr_denoise.tracer import scene_files

    path = tmp_path / "s.json"
    path.write_text(json.dumps(_scene_with(environment={"type": "latlong", "path": "env.exr"})))
    assert scene_files(path) == [("environment.path", tmp_path / "env.exr")]
    assert scene_files("default") == [] and scene_files(tmp_path / "none.json") == []
    with pytest.raises(ValueError, match="environment.path: .*env.exr"):
        load_scene(path)  # missing
    os.mkfifo(tmp_path / "env.exr")
    with pytest.raises(ValueError, match="environment.path: .*env.exr is not a regular file"):
        load_scene(path)  # returns at once: a FIFO opened for reading would block here
    (tmp_path / "env.exr").unlink()
    (tmp_path / "env.exr").write_bytes(b"not an exr")
    with pytest.raises(ValueError, match="environment.path: .*env.exr: not an OpenEXR file"):
        load_scene(path)
    # Read with the OpenEXR bindings directly, a truncated map printed the C library's messages on stdout and
    # stderr and was refused as "environment.Invalid part index '0'" (a red-team pass): the project's reader.
    from awr_denoise.io import write_image

    (tmp_path / "env.exr").unlink()
    write_image(tmp_path / "full.exr", np.random.default_rng(0).random((32, 64, 3)))
    (tmp_path / "env.exr").write_bytes((tmp_path / "full.exr").read_bytes()[:2000])
    with pytest.raises(ValueError, match="environment.path: .*env.exr: truncated or corrupt EXR"):
        load_scene(path)


def test_json_scene_files_match_the_bundled_dicts() -> None:
    for name, spec in BUNDLED_SCENES.items():
        path = REPO / "data" / "scenes" / f"{name}.json"
        assert json.loads(path.read_text()) == json.loads(json.dumps(spec)), f"{path} is stale"
        assert load_scene(path).dimension == load_scene(name).dimension


# ------------------------------------------------------------------ dimensions
@pytest.mark.parametrize("name", list(EXPECTED_DIMENSIONS))
def test_dimensions_per_scene(name: str) -> None:
    scene = load_scene(name, width=16, height=16)
    tracer = PathTracer(scene, threads=1)
    assert tracer.dimensions == EXPECTED_DIMENSIONS[name]
    assert len(tracer.dimensions) == tracer.dimension == scene.dimension
    tracer(SampleRequest.uniform(tracer.shape, 4))
    # Every listed dimension was drawn, and nothing else was.
    assert tracer.dimensions_drawn == set(EXPECTED_DIMENSIONS[name])
    assert (scene.environment is not None) == (name == "sky_objects")


def test_static_scene_ignores_the_shutter() -> None:
    spec = json.loads(json.dumps(BUNDLED_SCENES["default"]))
    with_shutter = json.loads(json.dumps(spec))
    with_shutter["camera"]["shutter"] = [0.0, 1.0]
    a = PathTracer(load_scene(spec, width=24, height=24), threads=1)
    b = PathTracer(load_scene(with_shutter, width=24, height=24), threads=1)
    assert "time" not in b.dimensions and a.dimensions == b.dimensions
    request = SampleRequest.uniform(a.shape, 4)
    ra, rb = a(request), b(request)
    assert np.array_equal(ra.mean, rb.mean) and np.array_equal(ra.variance, rb.variance)


def test_moving_objects_blur_and_freeze_without_shutter() -> None:
    spec = json.loads(json.dumps(BUNDLED_SCENES["rolling_balls"]))
    spec["camera"]["aperture_radius"] = 0.0
    spec["dimension"] = 3
    moving = PathTracer(load_scene(spec, width=48, height=48), threads=1)
    frozen_spec = json.loads(json.dumps(spec))
    frozen_spec["camera"]["shutter"] = [0.0, 0.0]
    frozen_spec["dimension"] = 2
    frozen = PathTracer(load_scene(frozen_spec, width=48, height=48), threads=1)
    assert "time" in moving.dimensions and "time" not in frozen.dimensions
    request = SampleRequest.uniform(moving.shape, 64)
    blurred, sharp = moving(request).luminance(), frozen(request).luminance()
    # Motion smears edges: total variation along the direction of motion drops (4 x 4 block
    # means first, so pixel noise does not count as detail).
    blocks = lambda img: img.reshape(12, 4, 12, 4).mean(axis=(1, 3))  # noqa: E731
    tv = lambda img: np.abs(np.diff(blocks(img), axis=1)).sum()  # noqa: E731
    assert tv(blurred) < 0.9 * tv(sharp)


def test_motion_blur_equals_the_time_average_of_frozen_frames() -> None:
    # The shutter integral: a motion-blurred render must match the average of renders frozen
    # at stratified times (midpoint rule, 32 frames), pixel by pixel within the noise. This
    # checks the per-ray object transforms, including rotation of the rolling balls' textures.
    spec = json.loads(json.dumps(BUNDLED_SCENES["rolling_balls"]))
    spec["camera"]["aperture_radius"] = 0.0
    spec["dimension"] = 3
    size, frames = 32, 32
    blurred = PathTracer(load_scene(spec, width=size, height=size))(SampleRequest.uniform((size, size), 1024))
    means, variances = [], []
    for k in range(frames):
        frozen = json.loads(json.dumps(spec))
        frozen["camera"]["shutter"] = [(k + 0.5) / frames] * 2
        frozen["dimension"] = 2
        tracer = PathTracer(load_scene(frozen, width=size, height=size), seed=k + 1)
        b = tracer(SampleRequest.uniform((size, size), 32))
        means.append(b.mean)
        variances.append(b.variance / b.count[..., None])
    average = np.mean(means, axis=0)
    se = np.sqrt(blurred.variance / blurred.count[..., None] + np.sum(variances, axis=0) / frames**2)
    difference = blurred.mean - average
    assert np.abs(difference).mean() < 0.2 * np.abs(blurred.mean - means[0]).mean()
    assert np.abs(difference / np.maximum(se, 1e-12)).max() < 5.5
    assert abs(difference.sum() / np.sqrt((se**2).sum())) < 4


# ------------------------------------------------------------------ determinism
@pytest.mark.parametrize("sampler", ["independent", "sobol"])
def test_split_requests_trace_identical_samples(sampler: str) -> None:
    scene = load_scene("cornell_gi", width=12, height=10)
    tracer = PathTracer(scene, sampler=sampler, threads=2, batch_size=97)
    whole = tracer(SampleRequest.uniform(tracer.shape, 8))
    first = tracer(SampleRequest.uniform(tracer.shape, 4))
    second = tracer(SampleRequest.uniform(tracer.shape, 4, first_index=4))
    merged = first.merge(second)
    assert np.array_equal(merged.count, whole.count)
    np.testing.assert_allclose(merged.mean, whole.mean, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(merged.variance, whole.variance, rtol=1e-9, atol=1e-15)
    # The samples themselves are bit-identical, whatever the batch size, threads or grouping.
    rows, cols, index = SampleRequest.uniform(tracer.shape, 8).pixel_list()
    values = tracer.trace_samples(rows, cols, index)
    other = PathTracer(scene, sampler=sampler, threads=1, batch_size=100_000)
    order = np.random.default_rng(1).permutation(len(rows))
    shuffled = other.trace_samples(rows[order], cols[order], index[order])
    assert np.array_equal(values[order], shuffled)
    # The same split rendered by another tracer instance merges to bit-identical statistics.
    again = other(SampleRequest.uniform(tracer.shape, 4)).merge(
        other(SampleRequest.uniform(tracer.shape, 4, first_index=4)))
    assert np.array_equal(again.mean, merged.mean) and np.array_equal(again.variance, merged.variance)
    # Different seeds give different samples.
    assert not np.array_equal(PathTracer(scene, seed=1, sampler=sampler).trace_samples(rows, cols, index), values)


def test_a_large_request_is_traced_in_parts_with_the_same_statistics() -> None:
    """Every sample of a request was held at once (about 120 bytes each: a uniform 1080p render at 128 spp
    needed 32 GB); it is traced in parts of ``max_part_samples``. Bands of rows give the statistics bit
    for bit, runs of one pixel's samples to rounding; features and non-finite counts come through."""
    scene = load_scene("chess_dof", width=12, height=10)
    rng = np.random.default_rng(3)
    request = SampleRequest(rng.integers(0, 7, (10, 12)), rng.integers(0, 20, (10, 12)), round=2)
    tracer = PathTracer(scene, features="all", threads=2, batch_size=97)
    whole = tracer(request)
    traced, trace = [], tracer._trace
    tracer._trace = lambda rows, *args: traced.append(len(rows)) or trace(rows, *args)  # what one part holds
    for part_samples, exact in ((60, True), (5, False)):
        tracer.max_part_samples = part_samples
        traced.clear()
        parts = tracer(request)
        assert sum(traced) == request.total and max(traced) <= max(part_samples, 12) and len(traced) > 1
        assert np.array_equal(parts.count, whole.count) and parts.nonfinite == whole.nonfinite
        pairs = [("radiance", parts, whole)] + [(f, parts.features[f], whole.features[f]) for f in whole.features]
        for name, got, expected in pairs:  # the radiance's statistics and each feature's (SampleBuffers)
            for field in ("mean", "variance"):
                x, y = getattr(got, field), getattr(expected, field)
                if exact:
                    assert np.array_equal(x, y), (name, field)
                else:
                    np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-15, err_msg=f"{name} {field}")


def test_sobol_pairs_are_stratified_and_pixels_independent() -> None:
    sampler = SobolSampler(seed=3)
    index = np.arange(16)
    for pixel in (0, 1, 12345):
        key = sampler.start(np.full(16, pixel), index)
        x = sampler.get(key, 0, sample_index=index, group=(0, 1))
        y = sampler.get(key, 1, sample_index=index, group=(0, 1))
        for bits_x in range(5):  # every elementary interval of a (0, 4, 2)-net holds one point
            bits_y = 4 - bits_x
            cells = np.floor(x * 2**bits_x).astype(int) * 2**bits_y + np.floor(y * 2**bits_y).astype(int)
            assert len(np.unique(cells)) == 16
    a = sampler.get(sampler.start(np.zeros(16, int), index), 0, sample_index=index, group=(0, 1))
    b = sampler.get(sampler.start(np.ones(16, int), index), 0, sample_index=index, group=(0, 1))
    assert not np.array_equal(np.sort(a), np.sort(b))
    u = IndependentSampler(5).get(IndependentSampler(5).start(np.arange(100_000), np.zeros(100_000, int)), 2)
    assert stats.kstest(u, "uniform").pvalue > 1e-3


def test_sobol_indices_past_its_sequence_are_refused() -> None:
    """The Sobol' sampler reads indices as 32 bits: sample 2**32 + k was sample k again, a request at
    ``first_index=2**32`` rendered the first samples twice without a word (a red-team pass)."""
    tracer = PathTracer(load_scene("default", width=8, height=8), sampler="sobol", seed=1)
    tracer(SampleRequest.uniform(tracer.shape, 2, first_index=2**32 - 2))  # the last two points: fine
    with pytest.raises(ValueError, match=r"sample_index: 4294967296 is past the Sobol' sampler's 2\*\*32 points"):
        tracer(SampleRequest.uniform(tracer.shape, 1, first_index=2**32))
    independent = PathTracer(load_scene("default", width=8, height=8), sampler="independent", seed=1)
    assert independent(SampleRequest.uniform(independent.shape, 1, first_index=2**32)).total_samples == 64


# ------------------------------------------------------------------ radiometry
@pytest.mark.parametrize("max_depth", [0, 3])
def test_white_furnace(max_depth: int) -> None:
    tracer = PathTracer(load_scene(_furnace_scene(max_depth)), seed=2)
    buffer = tracer(SampleRequest.uniform(tracer.shape, 32))
    sphere = buffer.variance.max(axis=2) > 0  # background pixels see the environment exactly
    assert sphere.sum() > 100
    assert np.all(buffer.mean[~sphere] == 1.0)
    average = buffer.mean[sphere].mean(axis=0)
    se = _standard_error(buffer, sphere)
    assert np.all(np.abs(average - 1.0) < 4 * se + 1e-12), (average, se)
    # A darker albedo must show up as darker (the test can fail).
    grey = PathTracer(load_scene(_furnace_scene(max_depth, {"type": "diffuse", "albedo": 0.5})), seed=2)
    grey_buffer = grey(SampleRequest.uniform(grey.shape, 32))
    assert grey_buffer.mean[sphere].mean() < 0.75


def _rect_irradiance_term(x: np.ndarray, z: np.ndarray, h: float) -> np.ndarray:
    # Irradiance / radiance from a rectangle [0, x] x [0, z] parallel to the receiver at height
    # h above the corner (odd in x and in z, so signed corners add up for any position).
    rx, rz = np.sqrt(h * h + x * x), np.sqrt(h * h + z * z)
    return 0.5 * (x / rx * np.arctan(z / rx) + z / rz * np.arctan(x / rz))


def _plane_points(scene, size: int, sub: int = 8) -> np.ndarray:
    """Points of the plane y = 0 seen through a sub x sub grid in each pixel (pinhole camera)."""
    offsets = (np.arange(sub) + 0.5) / sub
    rows, cols = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    py = np.broadcast_to(rows[..., None, None] + offsets[:, None], (size, size, sub, sub)).ravel()
    px = np.broadcast_to(cols[..., None, None] + offsets[None, :], (size, size, sub, sub)).ravel()
    o, d = scene.camera.generate_rays(np.stack([px, py], -1), None)
    return o + (-o[:, 1] / d[:, 1])[:, None] * d


def _plane_spec(emitter: dict | None, lights: list | None = None) -> dict:
    return {
        "name": "plane", "width": 12, "height": 12,
        "camera": {"from": [0, 0.5, 0], "to": [0, 0, 0], "up": [0, 0, -1], "fov": 60},
        "materials": {"plane": {"type": "diffuse", "albedo": 0.5}},
        "objects": [{"shape": "quad", "corner": [-3, 0, 3], "edge_u": [6, 0, 0], "edge_v": [0, 0, -6],
                     "material": "plane"}] + ([emitter] if emitter else []),
        "lights": lights or [],
    }


def _assert_matches(buffer: SampleBuffer, expected: np.ndarray) -> None:
    got = buffer.mean[..., 1]
    se = np.sqrt(buffer.variance[..., 1] / buffer.count)
    # Per pixel, and for the image average (which catches small biases the pixels hide).
    np.testing.assert_array_less(np.abs(got - expected), 5 * se + 2e-3 * expected)
    z = (got - expected).sum() / np.sqrt((se**2).sum())
    assert abs(z) < 4, z


@pytest.mark.parametrize("max_depth", [0, 1])
def test_area_light_matches_closed_form(max_depth: int) -> None:
    # With max_depth = 1 the light is reached both by light sampling and by BSDF sampling and
    # MIS splits the estimate between them; the flat plane has no indirect light, so the sum
    # must still match the closed form.
    h, half, le, shift = 1.0, 0.1, 40.0, 0.15
    scene = load_scene(_plane_spec({"shape": "quad", "corner": [-half + shift, h, -half], "edge_u": [2 * half, 0, 0],
                                    "edge_v": [0, 0, 2 * half], "emission": le}))
    tracer = PathTracer(scene, seed=4, max_depth=max_depth)
    buffer = tracer(SampleRequest.uniform(tracer.shape, 256))
    assert (tracer.stats["bounce_rays"] > 0) == (max_depth == 1)
    p = _plane_points(scene, 12)
    x0, x1 = -half + shift - p[:, 0], half + shift - p[:, 0]
    z0, z1 = -half - p[:, 2], half - p[:, 2]
    e = le * (_rect_irradiance_term(x1, z1, h) - _rect_irradiance_term(x0, z1, h)
              - _rect_irradiance_term(x1, z0, h) + _rect_irradiance_term(x0, z0, h))
    expected = (0.5 / np.pi * e).reshape(12, 12, 64).mean(axis=2)
    assert expected.max() > 0.2
    _assert_matches(buffer, expected)


def test_point_and_directional_lights_match_closed_form() -> None:
    position, intensity = np.array([0.2, 0.8, -0.1]), 2.0
    direction, irradiance = np.array([0.3, -1.0, 0.2]), 1.5
    scene = load_scene(_plane_spec(None, [{"type": "point", "position": position.tolist(), "intensity": intensity},
                                          {"type": "directional", "direction": direction.tolist(),
                                           "irradiance": irradiance}]))
    buffer = PathTracer(scene, seed=6)(SampleRequest.uniform((12, 12), 64))
    p = _plane_points(scene, 12)
    to_light = position - p
    d2 = (to_light**2).sum(axis=1)
    e_point = intensity * to_light[:, 1] / np.sqrt(d2) / d2
    e_sun = irradiance * (-direction[1] / np.linalg.norm(direction))
    expected = (0.5 / np.pi * (e_point + e_sun)).reshape(12, 12, 64).mean(axis=2)
    _assert_matches(buffer, expected)


def test_environment_sampling_follows_its_pdf() -> None:
    env = LatLongEnvironment(make_sky_envmap(32, 16, sun_radius_degrees=12.0))
    rng = np.random.default_rng(11)
    n = 400_000
    wi, radiance, pdf = env.sample(rng.random(n), rng.random(n))
    np.testing.assert_allclose(pdf, env.pdf(wi), rtol=1e-9)
    np.testing.assert_array_equal(radiance, env.evaluate(wi))
    u, v = direction_to_uv(wi)
    cell = np.minimum((v * 16).astype(int), 15) * 32 + np.minimum((u * 32).astype(int), 31)
    observed = np.bincount(cell, minlength=512).astype(float)
    expected = (env.row_probability[:, None] * env.column_probability).ravel() * n
    keep = expected >= 5
    observed = np.append(observed[keep], observed[~keep].sum())
    expected = np.append(expected[keep], expected[~keep].sum())
    assert stats.chisquare(observed, expected * observed.sum() / expected.sum()).pvalue > 1e-3
    # The solid-angle pdf integrates to 1 over the sphere (midpoint rule on a grid finer
    # than the map: the pdf is constant per map pixel up to the sin(theta) factor).
    gu, gv = np.meshgrid((np.arange(1024) + 0.5) / 1024, (np.arange(512) + 0.5) / 512)
    w_grid = uv_to_direction(gu.ravel(), gv.ravel())
    d_omega = (2 * np.pi / 1024) * (np.pi / 512) * np.sin(np.pi * gv.ravel())
    assert abs((env.pdf(w_grid) * d_omega).sum() - 1.0) < 1e-3


@pytest.mark.parametrize("roughness", [0.05, 0.2, 0.5, 1.0])
def test_glossy_albedo_never_exceeds_one(roughness: float) -> None:
    rng = np.random.default_rng(5)
    n = 200_000
    for spec in ({"type": "glossy", "albedo": 0.0, "specular": 1.0, "roughness": roughness},
                 {"type": "glossy", "albedo": 0.5, "specular": 0.5, "roughness": roughness}):
        material = parse_material("m", spec)
        kd = np.broadcast_to(material.albedo, (n, 3))
        for cos_o in (1.0, 0.5, 0.1):
            wo = np.tile([np.sqrt(1 - cos_o**2), 0.0, cos_o], (n, 1))
            # Uniform hemisphere sampling: an estimator independent of the BSDF's own sampler.
            z = rng.random(n)
            phi = 2 * np.pi * rng.random(n)
            r = np.sqrt(1 - z * z)
            wi = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)
            est_u = material.evaluate(wo, wi, kd)[:, 0] * z * 2 * np.pi
            a_u, se_u = est_u.mean(), est_u.std() / np.sqrt(n)
            assert a_u <= 1.0 + 4 * se_u, (roughness, cos_o, a_u)
            # Importance sampling must agree with it (sample, f and pdf are consistent).
            wi_s, f, pdf = material.sample(wo, rng.random(n), rng.random(n), kd)
            est_s = np.where(pdf > 0, f[:, 0] * np.abs(wi_s[:, 2]) / np.where(pdf > 0, pdf, 1), 0.0)
            a_s, se_s = est_s.mean(), est_s.std() / np.sqrt(n)
            assert a_s <= 1.0 + 4 * se_s
            assert abs(a_s - a_u) < 5 * np.hypot(se_u, se_s) + 1e-3, (roughness, cos_o, a_s, a_u)
            np.testing.assert_allclose(pdf, material.pdf(wo, wi_s, kd), rtol=1e-9, atol=1e-12)


def test_focal_plane_stays_sharp_while_off_focus_blurs() -> None:
    def scene(aperture: float) -> dict:
        return {
            "name": "dof", "width": 64, "height": 32,
            "camera": {"from": [0, 0, 6], "to": [0, 0, 0], "fov": 30, "aperture_radius": aperture,
                       "focus_distance": 6.0},
            "materials": {"check": {"type": "diffuse", "texture": {"type": "checker", "scale": 0.15,
                                                                   "color_a": 0.9, "color_b": 0.05}}},
            "objects": [
                {"shape": "quad", "corner": [-1.4, -0.6, 0], "edge_u": [1.2, 0, 0], "edge_v": [0, 1.2, 0],
                 "material": "check"},                                          # in focus (distance 6)
                {"shape": "quad", "corner": [0.2 * 0.55, -0.6 * 0.55, 2.7], "edge_u": [1.2 * 0.55, 0, 0],
                 "edge_v": [0, 1.2 * 0.55, 0], "material": "check"},           # off focus (distance 3.3)
            ],
            "lights": [{"type": "directional", "direction": [0, 0, -1], "irradiance": 3.0}],
        }
    request = SampleRequest.uniform((32, 64), 64)
    lens = PathTracer(scene(0.3))(request).luminance()
    pinhole = PathTracer(scene(0.0))(request).luminance()
    left, right = np.s_[4:28, 6:28], np.s_[4:28, 36:58]
    in_focus = np.abs(lens[left] - pinhole[left]).mean()
    off_focus = np.abs(lens[right] - pinhole[right]).mean()
    assert off_focus > 5 * in_focus, (in_focus, off_focus)
    assert np.abs(np.diff(lens[right], axis=1)).mean() < 0.5 * np.abs(np.diff(pinhole[right], axis=1)).mean()


def test_nonfinite_radiance_is_replaced_counted_and_reported(monkeypatch: pytest.MonkeyPatch,
                                                             caplog: pytest.LogCaptureFixture) -> None:
    tracer = PathTracer(load_scene(_furnace_scene(0)), threads=1)
    original = tracer.environment.evaluate

    def poisoned(w: np.ndarray) -> np.ndarray:
        value = original(w)
        value[w[:, 0] > 0.5] = np.nan
        return value

    monkeypatch.setattr(tracer.environment, "evaluate", poisoned)
    with caplog.at_level(logging.WARNING, logger="awr_denoise.tracer.integrator"):
        buffer = tracer(SampleRequest.uniform(tracer.shape, 4))
    assert buffer.nonfinite > 0
    assert tracer.stats["nonfinite"] == buffer.nonfinite
    assert np.isfinite(buffer.mean).all() and buffer.total_samples == 24 * 24 * 4
    assert "NaN/Inf" in caplog.text


def test_render_returns_uniform_buffer() -> None:
    buffer = render(load_scene("default", width=16, height=8), spp=3, sampler="sobol")
    assert buffer.shape == (8, 16) and np.all(buffer.count == 3) and buffer.channels == ("R", "G", "B")
    with pytest.raises(ValueError, match="spp"):
        render("default", spp=0)


@pytest.mark.exr
def test_sky_map_file_matches_its_generator() -> None:
    pytest.importorskip("OpenEXR")
    from awr_denoise.tracer.environment import read_envmap_exr

    stored = read_envmap_exr(REPO / "data" / "envmaps" / "sky.exr")
    assert np.array_equal(stored, make_sky_envmap())


@pytest.mark.exr
def test_reference_is_rendered_cached_and_reloaded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("OpenEXR")
    from awr_denoise.tracer import load_reference
    from awr_denoise.tracer.reference import read_reference_header, reference_path

    monkeypatch.setenv("AWR_DENOISE_REFERENCE_DIR", str(tmp_path))
    image = load_reference("default", spp=2)
    assert image.shape == (128, 128, 3) and image.dtype == np.float64
    assert read_reference_header(reference_path("default"))["spp"] == "2"
    assert np.array_equal(load_reference("default", spp=2), image)
    with pytest.raises(ValueError, match="scene_name: 'x' is not one of"):
        load_reference("x")
    # Another scene's reference, or a sample dump, cached under this scene's name was used, exit 0, every error
    # against it wrong (an attack pass): refused, naming the file and what its header says it is.
    import shutil

    from awr_denoise import SampleBuffer
    from awr_denoise.io import write_sample_buffer

    shutil.copy(reference_path("default"), reference_path("soft_shadows"))
    with pytest.raises(ValueError, match=r"soft_shadows.exr: holds the reference of scene 'default' \(awr:scene\)"):
        load_reference("soft_shadows")
    reference_path("soft_shadows").unlink()
    write_sample_buffer(reference_path("soft_shadows"), SampleBuffer.from_moments(
        np.full((128, 128), 4), np.ones((128, 128, 3)), np.zeros((128, 128, 3))))
    with pytest.raises(ValueError, match="soft_shadows.exr: is a sample-statistics file .*not the reference image"):
        load_reference("soft_shadows")


def test_a_reference_dir_that_is_a_file_is_refused_before_any_render(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    from awr_denoise.tracer.reference import reference_path

    (tmp_path / "refs").write_text("a file")
    monkeypatch.setenv("AWR_DENOISE_REFERENCE_DIR", str(tmp_path / "refs"))
    with pytest.raises(ValueError, match="AWR_DENOISE_REFERENCE_DIR: .*refs is not a folder"):
        reference_path("default")
    monkeypatch.setenv("AWR_DENOISE_REFERENCE_DIR", str(tmp_path / "new"))  # to be created: fine
    assert reference_path("default") == tmp_path / "new" / "default.exr"
    # Empty, it read as unset and sent the references into a checkout's tracked data/references (an attack pass).
    for empty in ("", " "):
        monkeypatch.setenv("AWR_DENOISE_REFERENCE_DIR", empty)
        with pytest.raises(ValueError, match="AWR_DENOISE_REFERENCE_DIR: empty; unset it"):
            reference_path("default")


@pytest.mark.parametrize("where", ["dangling link", "below a file"])
def test_a_reference_dir_that_cannot_be_made_is_named_before_any_render(tmp_path: Path, where: str,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """A folder that cannot be made was an OS error naming no setting: "[Errno 17] File exists" for a dangling link,
    "Not a directory" and exit 1 below a file (an attack pass); now a ValueError naming the variable (exit 2)."""
    from awr_denoise.tracer.reference import render_reference

    if where == "dangling link":
        folder = tmp_path / "refs"
        folder.symlink_to(tmp_path / "missing" / "refs")
        why = "a link to .*missing/refs, which does not exist"
    else:
        (tmp_path / "file").write_text("a file")
        folder = tmp_path / "file" / "refs"
        why = "Not a directory"
    monkeypatch.setenv("AWR_DENOISE_REFERENCE_DIR", str(folder))
    with mock.patch("awr_denoise.tracer.reference._render_into") as render:
        with pytest.raises(ValueError, match=f"^AWR_DENOISE_REFERENCE_DIR: cannot make the folder .*refs \\({why}\\)$"):
            render_reference("default", spp=1)
    render.assert_not_called()
    assert not (tmp_path / "missing").exists()


def test_a_default_reference_dir_that_cannot_be_made_names_the_setting_that_moves_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An install's default folder, in the user's cache, under a read-only home: the OS's words alone, naming no way
    out (an attack pass); now with the variable that moves it, before any render."""
    from awr_denoise.tracer import reference as module

    (tmp_path / "file").write_text("a file")
    monkeypatch.delenv("AWR_DENOISE_REFERENCE_DIR", raising=False)
    monkeypatch.setattr(module, "reference_dir", lambda: tmp_path / "file" / "refs")
    with mock.patch("awr_denoise.tracer.reference._render_into") as render:
        with pytest.raises(NotADirectoryError, match=r"\(the references' folder: set AWR_DENOISE_REFERENCE_DIR to one "
                                                     r"that can be written\)") as caught:
            module.render_reference("default", spp=1)
    assert caught.value.filename == str(tmp_path / "file" / "refs")
    render.assert_not_called()


def test_a_cached_reference_that_is_a_fifo_is_refused_before_any_render(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    # awr demo rendered the reference for 21 s, then refused to write over the FIFO.
    from awr_denoise.tracer import load_reference
    from awr_denoise.tracer import reference as module

    os.mkfifo(tmp_path / "default.exr")
    monkeypatch.setenv("AWR_DENOISE_REFERENCE_DIR", str(tmp_path))
    monkeypatch.setattr(module, "PathTracer", None)  # any render would fail on this instead
    with pytest.raises(ValueError, match="default.exr: is a FIFO"):
        load_reference("default")


def test_a_reference_not_written_leaves_no_folder_it_made(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An interrupted or refused ``awr demo`` / ``awr bench`` left the folders made for the reference under
    AWR_DENOISE_REFERENCE_DIR; a folder to make named as a staging folder was made, then refused."""
    from awr_denoise.tracer import reference as module

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(module, "PathTracer", interrupted)
    (tmp_path / "kept").mkdir()
    with pytest.raises(KeyboardInterrupt):
        module.render_reference("default", spp=1, path=tmp_path / "kept" / "a" / "b" / "default.exr")
    assert [p.name for p in tmp_path.rglob("*")] == ["kept"]
    with pytest.raises(ValueError, match="would be named as awr's staging folders"):
        module.render_reference("default", spp=1, path=tmp_path / "new" / ".awr-0123456789.tmp" / "default.exr")
    assert [p.name for p in tmp_path.rglob("*")] == ["kept"]


@pytest.mark.exr
def test_committed_references_are_small_and_state_their_spp() -> None:
    pytest.importorskip("OpenEXR")
    from awr_denoise.tracer.reference import read_reference_header

    files = sorted((REPO / "data" / "references").glob("*.exr"))
    if not files:
        pytest.skip("no committed references")
    assert sum(f.stat().st_size for f in files) < 8 * 2**20
    for f in files:
        assert f.stat().st_size < 5 * 2**20
        assert int(read_reference_header(f)["spp"]) >= 256


@pytest.mark.exr
def test_committed_references_are_the_ones_the_tracer_page_lists() -> None:
    """Every benchmark's numbers are measured against these files: one replaced by another render (the `default`
    reference once went in at 5000 spp beside an unrelated change) breaks every figure quoted against it. The table
    of docs/tracer.md names each file's spp, sampler, seed and render time, from its header."""
    pytest.importorskip("OpenEXR")
    from awr_denoise.tracer.reference import read_reference_header

    rows = {}
    for line in (REPO / "docs" / "tracer.md").read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 6 and cells[0].startswith("`") and cells[2].isdigit():
            rows[cells[0].strip("`")] = cells
    files = {f.stem: f for f in (REPO / "data" / "references").glob("*.exr")}
    if not files:
        pytest.skip("no committed references")
    assert sorted(rows) == sorted(files)
    for name, (_, size, spp, sampler_seed, seconds, _) in rows.items():
        header = read_reference_header(files[name])
        assert (header["scene"], header["spp"], f"{header['sampler']}, {header['seed']}", header["seconds"]) == (
            name, spp, sampler_seed, seconds), name


@pytest.mark.exr
@pytest.mark.parametrize("name", ["default", "soft_shadows"])
def test_renders_converge_to_the_reference_and_sobol_beats_independent(name: str) -> None:
    pytest.importorskip("OpenEXR")
    from awr_denoise.tracer import load_reference
    from awr_denoise.tracer.reference import reference_path

    if not reference_path(name).is_file():
        pytest.skip("reference not rendered")
    reference = load_reference(name)
    errors = {}
    for sampler in ("independent", "sobol"):
        buffer = render(name, spp=16, sampler=sampler)
        errors[sampler] = float(((buffer.mean - reference) ** 2).mean())
        # Unbiased against the 4096-spp reference: the image-average difference is within
        # a few standard errors (half-float rounding of the reference is far below that).
        se = np.sqrt((buffer.variance / buffer.count[..., None]).sum(axis=(0, 1))) / buffer.count.size
        assert np.all(np.abs((buffer.mean - reference).mean(axis=(0, 1))) < 5 * se + 1e-4), sampler
    assert errors["sobol"] < 0.5 * errors["independent"], errors


@pytest.mark.exr
def test_latlong_environment_loads_the_sky_file() -> None:
    pytest.importorskip("OpenEXR")
    spec = json.loads(json.dumps(BUNDLED_SCENES["sky_objects"]))
    spec["environment"] = {"type": "latlong", "path": str(REPO / "data" / "envmaps" / "sky.exr")}
    from_file = load_scene(spec).environment
    procedural = load_scene("sky_objects").environment
    assert np.array_equal(from_file.image, procedural.image)
    np.testing.assert_array_equal(from_file.row_cdf, procedural.row_cdf)


def test_process_workers_trace_the_same_samples_as_threads() -> None:
    scene = load_scene("rolling_balls", width=16, height=16)
    request = SampleRequest.uniform(scene.shape, 4)
    threaded = PathTracer(scene, threads=2, batch_size=256)
    spawned = PathTracer(scene, threads=2, batch_size=256, workers="processes")
    try:
        a, b = threaded(request), spawned(request)
    finally:
        spawned.close()
    assert np.array_equal(a.mean, b.mean) and np.array_equal(a.variance, b.variance)
    assert spawned.dimensions_drawn == set(spawned.dimensions)
    assert spawned.stats["rays"] == threaded.stats["rays"] > 0
    with pytest.raises(ValueError, match="workers: 'gpu' is not one of threads, processes"):
        PathTracer(scene, workers="gpu")


LAMP_ON_BLACK = {
    "name": "lamp_on_black", "dimension": 4, "width": 48, "height": 48,
    "camera": {"from": [0.0, 0.0, 5.0], "to": [0.0, 0.0, 0.0], "fov": 30},
    "integrator": {"max_depth": 0},
    "materials": {"white": {"type": "diffuse", "albedo": [0.7, 0.7, 0.7]}},
    "objects": [
        {"name": "lamp", "shape": "sphere", "center": [-0.5, 0.2, 0.0], "radius": 0.15, "emission": [60.0, 55.0, 45.0]},
        {"name": "ball", "shape": "sphere", "center": [0.6, -0.2, 0.0], "radius": 0.5, "material": "white"},
    ],
}


@pytest.mark.parametrize("spp", [2, 4, 16])
def test_a_lamp_seen_directly_on_black_gets_no_halo(spp) -> None:
    """A lamp against an empty backdrop: its inside is exact (every sample its emission), its rim hits or misses it,
    the black beside it is exact. Before, the black borrowed the rim's spread (samples that all agreed at 0 are
    moderated towards their neighbours') and the Wiener stages spread the lamp into it, a halo (docs/reconstruction.md,
    "Samples that all agreed", "A light's rim"). The rim is now told from its samples (all at the two levels beside
    it) and lends nothing: the black stays black."""
    from awr_denoise import reconstruct
    from scipy import ndimage

    tracer = PathTracer(load_scene(LAMP_ON_BLACK), seed=3, threads=1)
    buffer = tracer(SampleRequest.uniform(tracer.shape, spp))
    lamp = (buffer.mean[..., 0] == 60.0) & (buffer.variance[..., 0] == 0)
    assert lamp.sum() >= 9
    beside = ndimage.binary_dilation(lamp, iterations=4) & (buffer.mean[..., 0] == 0) & buffer.variance_known
    assert beside.sum() > 20
    image = reconstruct(buffer)
    assert np.abs(image[beside]).max() < 1e-6 * 60.0
