"""The bundled scenes, as Python dicts (the single source of truth).

``data/scenes/<name>.json`` files are written from these dicts by :func:`write_scene_files`
(``python -m awr_denoise.tracer.scenes``); they exist so the specs can be read and edited
without Python, and :func:`~awr_denoise.tracer.load_scene` accepts such a file path too. The
installed package needs no data files: it uses the dicts.

Each scene states the dimension of its pixel integrand (paper section 1; docs/concepts.md,
"The pixel integral": AA + DoF 4D, + motion blur 5D, + area or environment light 6D, + one
diffuse bounce 8D).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from .._places import checkout_data

__all__ = ["BUNDLED_SCENES", "list_scenes", "write_scene_files"]


def _room(width: float = 2.0, height: float = 2.0, depth: float = 2.0) -> list[dict[str, Any]]:
    hx, hz = width / 2, depth / 2
    return [
        {"name": "floor", "shape": "quad", "corner": [-hx, 0, hz], "edge_u": [width, 0, 0], "edge_v": [0, 0, -depth],
         "material": "white"},
        {"name": "ceiling", "shape": "quad", "corner": [-hx, height, -hz], "edge_u": [width, 0, 0],
         "edge_v": [0, 0, depth], "material": "white"},
        {"name": "back", "shape": "quad", "corner": [-hx, 0, -hz], "edge_u": [width, 0, 0], "edge_v": [0, height, 0],
         "material": "white"},
        {"name": "left", "shape": "quad", "corner": [-hx, 0, hz], "edge_u": [0, 0, -depth], "edge_v": [0, height, 0],
         "material": "red"},
        {"name": "right", "shape": "quad", "corner": [hx, 0, -hz], "edge_u": [0, 0, depth], "edge_v": [0, height, 0],
         "material": "green"},
    ]


_CHECKER_FLOOR = {"type": "diffuse", "texture": {"type": "checker", "axes": "xz", "scale": 0.5,
                                                  "color_a": [0.75, 0.75, 0.72], "color_b": [0.25, 0.25, 0.27]}}

BUNDLED_SCENES: dict[str, dict[str, Any]] = {
    "default": {
        "name": "default",
        "description": "Three objects on a checker floor under a square area light; pinhole camera, "
                       "direct lighting. The quick demo scene (pixel area + light sample).",
        "dimension": 4,
        "width": 128, "height": 128,
        "camera": {"from": [0.0, 1.6, 4.2], "to": [0.0, 0.5, 0.0], "fov": 38},
        "integrator": {"max_depth": 0},
        "materials": {
            "floor": _CHECKER_FLOOR,
            "red": {"type": "diffuse", "albedo": [0.75, 0.2, 0.15]},
            "gold": {"type": "glossy", "albedo": [0.1, 0.08, 0.02], "specular": [0.8, 0.6, 0.3], "roughness": 0.25},
            "blue": {"type": "diffuse", "albedo": [0.15, 0.3, 0.7]},
        },
        "objects": [
            {"name": "floor", "shape": "quad", "corner": [-4, 0, 4], "edge_u": [8, 0, 0], "edge_v": [0, 0, -8],
             "material": "floor"},
            {"name": "red_sphere", "shape": "sphere", "center": [-1.1, 0.5, 0.2], "radius": 0.5, "material": "red"},
            {"name": "gold_sphere", "shape": "sphere", "center": [0.25, 0.6, -0.4], "radius": 0.6, "material": "gold"},
            {"name": "blue_box", "shape": "box", "min": [0.9, 0.0, 0.3], "max": [1.6, 0.7, 1.0], "material": "blue"},
            {"name": "light", "shape": "quad", "corner": [-0.6, 3.0, -0.6], "edge_u": [1.2, 0, 0],
             "edge_v": [0, 0, 1.2], "emission": [14.0, 13.0, 11.5]},
        ],
    },
    "chess_dof": {
        "name": "chess_dof",
        "description": "Chess-like lathed pieces on a checkerboard with shallow focus on the middle piece; "
                       "lit by a point and a directional light (no light sampling). AA + DoF.",
        "dimension": 4,
        "width": 128, "height": 128,
        "camera": {"from": [0.35, 0.85, 3.9], "to": [0.0, 0.3, 0.0], "fov": 34, "aperture_radius": 0.08,
                   "focus_distance": 3.95},
        "integrator": {"max_depth": 0},
        "materials": {
            "board": {"type": "diffuse", "texture": {"type": "checker", "axes": "xz", "scale": 0.5,
                                                     "color_a": [0.8, 0.76, 0.66], "color_b": [0.12, 0.08, 0.06]}},
            "ivory": {"type": "glossy", "albedo": [0.7, 0.66, 0.58], "specular": 0.25, "roughness": 0.15},
            "ebony": {"type": "glossy", "albedo": [0.05, 0.04, 0.04], "specular": 0.5, "roughness": 0.1},
        },
        "objects": [
            {"name": "board", "shape": "box", "min": [-2.0, -0.15, -2.0], "max": [2.0, 0.0, 2.0], "material": "board"},
            {"name": "near_pawn", "shape": "lathe", "profile": "pawn", "base": [-0.55, 0.0, 1.25], "scale": 0.2,
             "material": "ebony"},
            {"name": "near_rook", "shape": "lathe", "profile": "rook", "base": [0.55, 0.0, 1.0], "scale": 0.2,
             "material": "ivory"},
            {"name": "king", "shape": "lathe", "profile": "king", "base": [0.0, 0.0, 0.0], "scale": 0.2,
             "material": "ivory"},
            {"name": "far_bishop", "shape": "lathe", "profile": "bishop", "base": [-0.75, 0.0, -1.0], "scale": 0.2,
             "material": "ebony"},
            {"name": "far_pawn", "shape": "lathe", "profile": "pawn", "base": [0.8, 0.0, -1.5], "scale": 0.2,
             "material": "ivory"},
        ],
        "lights": [
            {"type": "directional", "direction": [-0.5, -1.0, -0.6], "irradiance": [2.4, 2.3, 2.1]},
            {"type": "point", "position": [1.8, 2.0, 2.5], "intensity": [2.0, 2.1, 2.4]},
        ],
    },
    "rolling_balls": {
        "name": "rolling_balls",
        "description": "Checker-textured balls rolling (translating and spinning) across a table during an "
                       "open shutter; point and directional lights. AA + DoF + motion blur.",
        "dimension": 5,
        "width": 128, "height": 128,
        "camera": {"from": [0.0, 1.4, 3.6], "to": [0.0, 0.3, 0.0], "fov": 36, "aperture_radius": 0.04,
                   "focus_distance": 3.7, "shutter": [0.0, 1.0]},
        "integrator": {"max_depth": 0},
        "materials": {
            "table": {"type": "diffuse", "albedo": [0.35, 0.5, 0.3]},
            "ball_red": {"type": "diffuse", "texture": {"type": "checker", "scale": 0.12,
                                                        "color_a": [0.8, 0.15, 0.1], "color_b": [0.9, 0.85, 0.8]}},
            "ball_blue": {"type": "diffuse", "texture": {"type": "checker", "scale": 0.1,
                                                         "color_a": [0.1, 0.2, 0.8], "color_b": [0.85, 0.85, 0.8]}},
            "ball_glossy": {"type": "glossy", "albedo": [0.5, 0.45, 0.1], "specular": 0.4, "roughness": 0.2},
        },
        "objects": [
            {"name": "table", "shape": "box", "min": [-3.0, -0.1, -2.0], "max": [3.0, 0.0, 2.0], "material": "table"},
            {"name": "fast_ball", "shape": "sphere", "center": [-0.9, 0.3, 0.6], "radius": 0.3, "material": "ball_red",
             "motion": {"velocity": [0.6, 0.0, 0.0], "axis": [0, 0, -1], "angular_velocity_degrees": 114.6}},
            {"name": "slow_ball", "shape": "sphere", "center": [0.6, 0.25, -0.3], "radius": 0.25,
             "material": "ball_blue",
             "motion": {"velocity": [-0.2, 0.0, 0.2], "axis": [0.7071, 0, 0.7071], "angular_velocity_degrees": 64.8}},
            {"name": "still_ball", "shape": "sphere", "center": [0.1, 0.35, -1.2], "radius": 0.35,
             "material": "ball_glossy"},
        ],
        "lights": [
            {"type": "directional", "direction": [0.4, -1.0, -0.3], "irradiance": [2.6, 2.5, 2.3]},
            {"type": "point", "position": [-2.0, 2.5, 2.0], "intensity": [2.5, 2.5, 2.8]},
        ],
    },
    "sky_objects": {
        "name": "sky_objects",
        "description": "Diffuse, glossy and mirror objects on a ground plane under the procedural sky with "
                       "a sun (importance-sampled lat-long map). AA + DoF + environment light.",
        "dimension": 6,
        "width": 128, "height": 128,
        "camera": {"from": [0.0, 1.3, 5.6], "to": [0.0, 0.55, 0.0], "fov": 38, "aperture_radius": 0.06,
                   "focus_distance": 5.55},
        "integrator": {"max_depth": 0},
        "materials": {
            "ground": {"type": "diffuse", "texture": {"type": "checker", "axes": "xz", "scale": 1.0,
                                                      "color_a": [0.6, 0.6, 0.58], "color_b": [0.45, 0.45, 0.43]}},
            "clay": {"type": "diffuse", "albedo": [0.8, 0.45, 0.3]},
            "glossy": {"type": "glossy", "albedo": [0.1, 0.2, 0.35], "specular": 0.6, "roughness": 0.15},
            "mirror": {"type": "mirror", "specular": 0.9},
            "marble": {"type": "diffuse", "albedo": [0.85, 0.85, 0.82]},
        },
        "objects": [
            {"name": "ground", "shape": "quad", "corner": [-20, 0, 20], "edge_u": [40, 0, 0], "edge_v": [0, 0, -40],
             "material": "ground"},
            {"name": "clay_sphere", "shape": "sphere", "center": [-1.3, 0.55, 0.3], "radius": 0.55, "material": "clay"},
            {"name": "mirror_sphere", "shape": "sphere", "center": [0.0, 0.65, -0.5], "radius": 0.65,
             "material": "mirror"},
            {"name": "glossy_sphere", "shape": "sphere", "center": [1.3, 0.5, 0.4], "radius": 0.5,
             "material": "glossy"},
            {"name": "king", "shape": "lathe", "profile": "king", "base": [0.55, 0.0, 1.3], "scale": 0.22,
             "material": "marble"},
        ],
        "environment": {"type": "sky"},
    },
    "soft_shadows": {
        "name": "soft_shadows",
        "description": "Boxes and spheres casting soft shadows from one large square area light "
                       "(next-event estimation with MIS). AA + DoF + area light.",
        "dimension": 6,
        "width": 128, "height": 128,
        "camera": {"from": [0.0, 2.4, 4.6], "to": [0.0, 0.4, 0.0], "fov": 38, "aperture_radius": 0.04,
                   "focus_distance": 5.0},
        "integrator": {"max_depth": 0},
        "materials": {
            "floor": {"type": "diffuse", "albedo": [0.7, 0.7, 0.7]},
            "orange": {"type": "diffuse", "albedo": [0.8, 0.45, 0.15]},
            "teal": {"type": "glossy", "albedo": [0.1, 0.4, 0.4], "specular": 0.3, "roughness": 0.3},
            "grey": {"type": "diffuse", "albedo": [0.5, 0.5, 0.55]},
        },
        "objects": [
            {"name": "floor", "shape": "quad", "corner": [-5, 0, 5], "edge_u": [10, 0, 0], "edge_v": [0, 0, -10],
             "material": "floor"},
            {"name": "tall_box", "shape": "box", "min": [-1.4, 0.0, -0.6], "max": [-0.8, 1.3, 0.0], "material": "grey"},
            {"name": "sphere", "shape": "sphere", "center": [0.2, 0.45, 0.3], "radius": 0.45, "material": "orange"},
            {"name": "small_box", "shape": "box", "min": [0.9, 0.0, -0.8], "max": [1.5, 0.5, -0.2],
             "material": "teal"},
            {"name": "light", "shape": "quad", "corner": [-1.0, 3.2, -1.2], "edge_u": [2.0, 0, 0],
             "edge_v": [0, 0, 2.0], "emission": [4.2, 4.0, 3.6]},
        ],
    },
    "cornell_gi": {
        "name": "cornell_gi",
        "description": "A Cornell-like room with a ceiling light, lit directly and by one diffuse bounce "
                       "(colour bleeding). AA + DoF + area light + one-bounce GI.",
        "dimension": 8,
        "width": 128, "height": 128,
        "camera": {"from": [0.0, 1.0, 3.9], "to": [0.0, 1.0, 0.0], "fov": 30, "aperture_radius": 0.02,
                   "focus_distance": 3.7},
        "integrator": {"max_depth": 1},
        "materials": {
            "white": {"type": "diffuse", "albedo": [0.73, 0.73, 0.73]},
            "red": {"type": "diffuse", "albedo": [0.65, 0.06, 0.05]},
            "green": {"type": "diffuse", "albedo": [0.12, 0.45, 0.15]},
            "glossy": {"type": "glossy", "albedo": [0.3, 0.3, 0.3], "specular": 0.5, "roughness": 0.2},
        },
        "objects": _room() + [
            {"name": "tall_box", "shape": "box", "min": [-0.7, 0.0, -0.6], "max": [-0.1, 1.2, 0.0],
             "material": "white"},
            {"name": "short_box", "shape": "box", "min": [0.15, 0.0, 0.0], "max": [0.75, 0.6, 0.6],
             "material": "white"},
            {"name": "sphere", "shape": "sphere", "center": [0.45, 0.85, 0.3], "radius": 0.25, "material": "glossy"},
            {"name": "light", "shape": "quad", "corner": [-0.25, 1.99, -0.25], "edge_u": [0.5, 0, 0],
             "edge_v": [0, 0, 0.5], "emission": [34.0, 30.0, 24.0]},
        ],
    },
}
"""Bundled scene specs by name."""


def list_scenes() -> list[str]:
    """Names of the bundled scenes."""
    return list(BUNDLED_SCENES)


def write_scene_files(directory: str | Path | None = None) -> list[Path]:
    """Write every bundled scene as ``<name>.json`` (default: the repository's ``data/scenes`` in a checkout; an
    install has no default: ``directory`` is then needed)."""
    data = checkout_data()
    if directory is None and data is None:
        raise ValueError("directory: give the folder to write; the default, data/scenes, is a checkout's")
    directory = Path(directory) if directory is not None else data / "scenes"
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, spec in BUNDLED_SCENES.items():
        path = directory / f"{name}.json"
        path.write_text(json.dumps(spec, indent=1) + "\n")
        paths.append(path)
    return paths


if __name__ == "__main__":
    for written in write_scene_files(sys.argv[1] if len(sys.argv) > 1 else None):
        print(written)
