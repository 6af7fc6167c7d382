"""Benchmark scenes for the Mitsuba 3 adapter, built from Mitsuba's own plugins.

Four small scenes, each a Python scene dict (no files): Mitsuba's Cornell box
(``mi.cornell_box()``), a scene lit by an environment map with a sun in it, a glossy scene lit by
a small light with a glass sphere, and a textured scene seen through a thin lens. Every film uses
a box filter of radius 0.5, so Mitsuba's own film render of a scene is the uniform baseline the
adaptive loop is compared against (see docs/integrate_mitsuba.md).

Three more (:data:`HEAVY_TAILED_SCENES`) are lit through rare paths, so that a pixel's first samples
seldom show its variance: a room lit only by the patch of ceiling a spot light points at, a spot
light in fog, and a room lit by a point light in a lamp shade open at its top. Most of their samples
are exactly 0. They are where adaptive sampling's image
mean was found low (docs/sampling.md, "Rare paths"), and are named apart from :data:`SCENE_NAMES`,
the set every benchmark table of the defaults is made of.

Examples
--------
>>> from awr_denoise.adapters.mitsuba_scenes import HEAVY_TAILED_SCENES, SCENE_NAMES
>>> SCENE_NAMES
('cornell_box', 'envmap_sun', 'glossy_glass', 'dof_checker')
>>> HEAVY_TAILED_SCENES
('indirect_room', 'fog_spot', 'shaded_lamp')
>>> d = scene_dict("cornell_box", (32, 48))  # doctest: +SKIP
>>> d["sensor"]["film"]["width"], d["sensor"]["film"]["height"]  # doctest: +SKIP
(48, 32)
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from .._typing import Shape2D
from ._mitsuba_runtime import DEFAULT_VARIANT, import_mitsuba, variant_scope

__all__ = ["SCENE_NAMES", "HEAVY_TAILED_SCENES", "ALL_SCENES", "DEFAULT_SHAPE", "scene_dict", "write_scene_xml"]

SCENE_NAMES = ("cornell_box", "envmap_sun", "glossy_glass", "dof_checker")
"""Names of the bundled benchmark scenes, in the order benchmarks report them."""

HEAVY_TAILED_SCENES = ("indirect_room", "fog_spot", "shaded_lamp")
"""Bundled scenes lit through rare paths (most samples exactly 0), for the samplers' image mean."""

ALL_SCENES = SCENE_NAMES + HEAVY_TAILED_SCENES
"""Every bundled scene name."""

DEFAULT_SHAPE: Shape2D = (256, 256)
"""(H, W) of a bundled scene when no shape is given."""

_MAX_DEPTH = 8  # Mitsuba's Cornell box default; enough for the glass sphere's caustic paths


def _film(shape: Shape2D) -> dict[str, Any]:
    h, w = shape
    # A box filter of radius 0.5: every sample lands in exactly one pixel, as AWR needs and as the
    # uniform baseline (Mitsuba's own film render) must, to compare like with like.
    return {"type": "hdrfilm", "width": int(w), "height": int(h), "rfilter": {"type": "box"},
            "pixel_format": "rgb", "component_format": "float32"}


def _sampler() -> dict[str, Any]:
    return {"type": "independent", "sample_count": 16}


def _cornell_box(mi: Any, shape: Shape2D) -> dict[str, Any]:
    scene = mi.cornell_box()
    scene["sensor"]["film"] = _film(shape)
    scene["sensor"]["sampler"] = _sampler()
    return scene


def _sky(mi: Any, width: int = 512) -> Any:
    """A lat-long sky (Mitsuba's ``envmap`` layout, +Y up) with a small, bright sun in it.

    The sun covers 31 texels and gives 60% of the irradiance on a horizontal surface, so the
    scene is lit mostly through a small, bright part of an environment map.
    """
    height = width // 2
    theta = (np.arange(height) + 0.5) / height * math.pi          # 0 at the zenith
    phi = (np.arange(width) + 0.5) / width * 2.0 * math.pi
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    # Direction of each texel as Mitsuba's envmap maps (u, v) to the unit sphere.
    d = np.stack([np.sin(ph) * np.sin(th), np.cos(th), -np.cos(ph) * np.sin(th)], axis=-1)
    elevation = math.pi / 2 - th
    t = np.sqrt(np.clip(elevation / (math.pi / 2), 0.0, 1.0))[..., None]
    horizon, zenith = np.array([1.05, 1.1, 1.15]), np.array([0.25, 0.45, 0.95])
    ground = np.array([0.12, 0.11, 0.09])
    rgb = np.where(elevation[..., None] > 0, (1 - t) * horizon + t * zenith, ground)
    sun_elev, sun_azim, sun_radius = math.radians(35.0), math.radians(60.0), math.radians(2.0)
    sun = np.array([math.sin(sun_azim) * math.cos(sun_elev), math.sin(sun_elev),
                    -math.cos(sun_azim) * math.cos(sun_elev)])
    in_sun = (d @ sun) > math.cos(sun_radius)
    rgb[in_sun] = np.array([1.0, 0.92, 0.8]) * 1500.0
    return mi.Bitmap(rgb.astype(np.float32))


def _envmap_sun(mi: Any, shape: Shape2D) -> dict[str, Any]:
    T = mi.ScalarTransform4f
    h, w = shape
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": _MAX_DEPTH},
        "sensor": {"type": "perspective", "fov": 40.0, "fov_axis": "x" if w >= h else "y",
                   "to_world": T().look_at(origin=[0.0, 2.0, 7.0], target=[0.0, 0.6, 0.0], up=[0, 1, 0]),
                   "film": _film(shape), "sampler": _sampler()},
        "sky": {"type": "envmap", "bitmap": _sky(mi)},
        "ground": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(20.0),
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.45, 0.42, 0.38]}}},
        "red_sphere": {"type": "sphere", "center": [-1.5, 0.8, 0.0], "radius": 0.8,
                       "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.7, 0.15, 0.12]}}},
        "gold_sphere": {"type": "sphere", "center": [0.6, 0.6, 1.0], "radius": 0.6,
                        "bsdf": {"type": "roughconductor", "material": "Au", "alpha": 0.12}},
        "box": {"type": "cube", "to_world": T().translate([1.9, 0.7, -1.2]).rotate([0, 1, 0], 30).scale(0.7),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.25, 0.45, 0.7]}}},
    }


def _glossy_glass(mi: Any, shape: Shape2D) -> dict[str, Any]:
    T = mi.ScalarTransform4f
    h, w = shape
    white = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.7, 0.7, 0.7]}}

    def wall(transform: Any, bsdf: dict[str, Any]) -> dict[str, Any]:
        return {"type": "rectangle", "to_world": transform, "bsdf": bsdf}

    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": _MAX_DEPTH},
        "sensor": {"type": "perspective", "fov": 45.0, "fov_axis": "x" if w >= h else "y",
                   "to_world": T().look_at(origin=[0.0, 1.2, 4.6], target=[0.0, 0.8, 0.0], up=[0, 1, 0]),
                   "film": _film(shape), "sampler": _sampler()},
        # A glossy floor: the small light's highlight and the glass sphere's caustic land on it.
        "floor": wall(T().rotate([1, 0, 0], -90).scale(2.0),
                      {"type": "roughplastic", "distribution": "ggx", "alpha": 0.08,
                       "diffuse_reflectance": {"type": "rgb", "value": [0.35, 0.3, 0.25]}}),
        "ceiling": wall(T().translate([0, 2.5, 0]).rotate([1, 0, 0], 90).scale(2.0), white),
        "back": wall(T().translate([0, 1.25, -2.0]).scale([2.0, 1.25, 1.0]), white),
        "left": wall(T().translate([-2.0, 1.25, 0]).rotate([0, 1, 0], 90).scale([2.0, 1.25, 1.0]),
                     {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.25, 0.2]}}),
        "right": wall(T().translate([2.0, 1.25, 0]).rotate([0, 1, 0], -90).scale([2.0, 1.25, 1.0]),
                      {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.35, 0.6]}}),
        "glass_sphere": {"type": "sphere", "center": [-0.6, 0.55, 0.3], "radius": 0.55,
                         "bsdf": {"type": "dielectric", "int_ior": 1.5}},
        "copper_sphere": {"type": "sphere", "center": [0.8, 0.45, -0.5], "radius": 0.45,
                          "bsdf": {"type": "roughconductor", "material": "Cu", "alpha": 0.2}},
        # A small light (radius 0.06): most of the image is lit through it or through its images.
        "light": {"type": "sphere", "center": [0.3, 1.95, 0.2], "radius": 0.06,
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [900.0, 820.0, 700.0]}}},
    }


def _dof_checker(mi: Any, shape: Shape2D) -> dict[str, Any]:
    T = mi.ScalarTransform4f
    h, w = shape

    def ball(center: list[float], rgb: list[float]) -> dict[str, Any]:
        return {"type": "sphere", "center": center, "radius": 0.5,
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": rgb}}}

    origin, focus = np.array([0.0, 1.4, 6.0]), np.array([0.0, 0.5, 0.0])
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": _MAX_DEPTH},
        "sensor": {"type": "thinlens", "fov": 40.0, "fov_axis": "x" if w >= h else "y",
                   "aperture_radius": 0.12, "focus_distance": float(np.linalg.norm(origin - focus)),
                   "to_world": T().look_at(origin=origin.tolist(), target=focus.tolist(), up=[0, 1, 0]),
                   "film": _film(shape), "sampler": _sampler()},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.35, 0.4, 0.5]}},
        "sun": {"type": "directional", "direction": [-0.4, -1.0, -0.5],
                "irradiance": {"type": "rgb", "value": [2.6, 2.4, 2.1]}},
        # Mitsuba's procedural checkerboard: 20 x 20 squares over the 16 x 16 floor.
        "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90).scale(8.0),
                  "bsdf": {"type": "diffuse", "reflectance": {
                      "type": "checkerboard", "to_uv": mi.ScalarTransform4f().scale([10.0, 10.0, 1.0]),
                      "color0": {"type": "rgb", "value": [0.8, 0.8, 0.75]},
                      "color1": {"type": "rgb", "value": [0.08, 0.08, 0.1]}}}},
        "near": ball([-1.1, 0.5, 3.2], [0.75, 0.2, 0.15]),     # in front of the focal plane: blurred
        "focused": ball([0.0, 0.5, 0.0], [0.2, 0.6, 0.25]),    # on the focal plane: sharp
        "far": ball([1.4, 0.5, -4.5], [0.2, 0.3, 0.75]),       # behind it: blurred
    }


def _room(mi: Any, shape: Shape2D, integrator: str) -> dict[str, Any]:
    """A closed room of diffuse walls around a white ball, seen from its open side (no light yet)."""
    T = mi.ScalarTransform4f
    h, w = shape

    def wall(transform: Any, rgb: list[float]) -> dict[str, Any]:
        return {"type": "rectangle", "to_world": transform,
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": rgb}}}

    white = [0.7, 0.7, 0.7]
    return {
        "type": "scene",
        "integrator": {"type": integrator, "max_depth": _MAX_DEPTH},
        "sensor": {"type": "perspective", "fov": 45.0, "fov_axis": "x" if w >= h else "y",
                   "to_world": T().look_at(origin=[0.0, 1.2, 4.6], target=[0.0, 0.9, 0.0], up=[0, 1, 0]),
                   "film": _film(shape), "sampler": _sampler()},
        "floor": wall(T().rotate([1, 0, 0], -90).scale(2.0), [0.5, 0.45, 0.4]),
        "ceiling": wall(T().translate([0, 2.5, 0]).rotate([1, 0, 0], 90).scale(2.0), white),
        "back": wall(T().translate([0, 1.25, -2.0]).scale([2.0, 1.25, 1.0]), white),
        "left": wall(T().translate([-2.0, 1.25, 0]).rotate([0, 1, 0], 90).scale([2.0, 1.25, 1.0]), [0.6, 0.25, 0.2]),
        "right": wall(T().translate([2.0, 1.25, 0]).rotate([0, 1, 0], -90).scale([2.0, 1.25, 1.0]), [0.2, 0.35, 0.6]),
        "ball": {"type": "sphere", "center": [0.6, 0.45, -0.3], "radius": 0.45,
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": white}}},
    }


def _indirect_room(mi: Any, shape: Shape2D) -> dict[str, Any]:
    """The room lit only by the patch of ceiling a narrow spot light points up at.

    Every wall the camera sees is outside the spot's cone: a path brings light only when a bounce
    finds that patch, so most samples are exactly 0 (a room lit by a lamp shade's upward light)."""
    T = mi.ScalarTransform4f
    scene = _room(mi, shape, "path")
    scene["lamp"] = {"type": "spot", "cutoff_angle": 15.0, "beam_width": 10.0,
                     "to_world": T().look_at(origin=[-0.8, 1.0, -1.0], target=[-0.8, 2.5, -1.0], up=[0, 0, 1]),
                     "intensity": {"type": "rgb", "value": [60.0, 55.0, 45.0]}}
    return scene


def _fog_spot(mi: Any, shape: Shape2D) -> dict[str, Any]:
    """The room filled with fog (a homogeneous medium, albedo 0.9) around a spot light pointing down.

    A camera path scatters in the fog; it sees the light only from inside the cone, so outside the
    beam most samples are exactly 0 and the glow comes from rare multiply scattered paths."""
    T = mi.ScalarTransform4f
    scene = _room(mi, shape, "volpath")
    scene["lamp"] = {"type": "spot", "cutoff_angle": 20.0, "beam_width": 15.0,
                     "to_world": T().look_at(origin=[-0.5, 2.4, -0.5], target=[-0.3, 0.0, -0.3], up=[0, 0, 1]),
                     "intensity": {"type": "rgb", "value": [40.0, 38.0, 34.0]}}
    scene["fog"] = {"type": "homogeneous", "id": "fog", "sigma_t": 0.35,
                    "albedo": {"type": "rgb", "value": [0.9, 0.9, 0.9]}}
    scene["sensor"]["medium"] = {"type": "ref", "id": "fog"}  # the camera is inside the fog
    return scene


def _shaded_lamp(mi: Any, shape: Shape2D) -> dict[str, Any]:
    """The room lit by a point light in a lamp shade, a tube closed at its bottom and open at its top.

    The kind of room a red-team pass found AWR sampling's image mean low in (docs/robustness.md, "The
    twenty-first pass"), where ``indirect_room`` stands in with a spot light: the light leaves only upwards, so
    everything the camera sees but a disc of ceiling is lit through a bounce off that disc. The shade is a surface
    the camera sees from below, lit only indirectly, with the light's occlusion at its rim."""
    T = mi.ScalarTransform4f
    scene = _room(mi, shape, "path")
    x, z, radius = -0.8, -1.0, 0.22
    paper = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.55, 0.45]}}
    shade = {"type": "twosided", "bsdf": paper}  # lit inside by the lamp, outside by the room
    scene["shade"] = {"type": "cylinder", "p0": [x, 1.7, z], "p1": [x, 2.1, z], "radius": radius, "bsdf": shade}
    scene["shade_bottom"] = {"type": "disk", "bsdf": shade,
                             "to_world": T().translate([x, 1.7, z]).rotate([1, 0, 0], 90).scale(radius)}
    scene["lamp"] = {"type": "point", "position": [x, 1.9, z],
                     "intensity": {"type": "rgb", "value": [6.5, 6.0, 5.0]}}
    return scene


_BUILDERS = {"cornell_box": _cornell_box, "envmap_sun": _envmap_sun, "glossy_glass": _glossy_glass,
             "dof_checker": _dof_checker, "indirect_room": _indirect_room, "fog_spot": _fog_spot,
             "shaded_lamp": _shaded_lamp}


def scene_dict(name: str, shape: Shape2D | None = None, *, variant: str = DEFAULT_VARIANT) -> dict[str, Any]:
    """The Mitsuba scene dict of a bundled scene (pass it to ``mi.load_dict``).

    Parameters
    ----------
    name
        One of :data:`ALL_SCENES`.
    shape
        (H, W) of the film; default :data:`DEFAULT_SHAPE`.
    variant
        Mitsuba variant the dict's objects (transforms, the sky bitmap) are made for; it must be
        the active variant when the dict is loaded.
    """
    if name not in _BUILDERS:
        raise ValueError(f"scene: {name!r} is not a bundled Mitsuba scene ({', '.join(ALL_SCENES)})")
    h, w = DEFAULT_SHAPE if shape is None else (int(s) for s in shape)
    if h <= 0 or w <= 0:
        raise ValueError(f"shape: empty image {(h, w)}")
    mi, _ = import_mitsuba(variant)
    with variant_scope(mi, variant):
        return _BUILDERS[name](mi, (h, w))


def write_scene_xml(name: str, path: str | os.PathLike[str], shape: Shape2D | None = None, *,
                    variant: str = DEFAULT_VARIANT) -> Path:
    """Write a bundled scene as a Mitsuba XML file with Mitsuba's own writer.

    Data the dict holds in memory (the sky's bitmap) is written beside the XML file as EXR and
    referenced by a relative ``filename``. Returns the path written; existing files are replaced.
    """
    d = scene_dict(name, shape, variant=variant)
    mi, _ = import_mitsuba(variant)
    target = Path(path)
    with variant_scope(mi, variant):
        d = _bitmaps_to_files(mi, d, target)
        config = mi.parser.ParserConfig(variant)
        state = mi.parser.parse_dict(config, d)
        mi.parser.write_file(state, str(target))
    return target


def _bitmaps_to_files(mi: Any, d: dict[str, Any], target: Path, prefix: str = "") -> dict[str, Any]:
    """A copy of ``d`` whose in-memory bitmaps are EXR files beside ``target``, named after their key.

    Mitsuba's XML writer cannot write a bitmap object; a plugin that takes one (``envmap``,
    ``bitmap``) takes a ``filename`` instead, resolved relative to the XML file.
    """
    out: dict[str, Any] = {}
    for key, value in d.items():
        if isinstance(value, dict):
            out[key] = _bitmaps_to_files(mi, value, target, f"{prefix}{key}_")
        elif key == "bitmap" and isinstance(value, mi.Bitmap):
            filename = f"{target.stem}_{prefix.rstrip('_') or 'bitmap'}.exr"
            value.write(str(target.parent / filename))
            out["filename"] = filename
        else:
            out[key] = value
    return out
