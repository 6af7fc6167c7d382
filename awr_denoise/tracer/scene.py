"""Scenes: parse a scene spec (a dict, a JSON file or a bundled name) into geometry and lights.

A scene spec is a plain dict (see :mod:`awr_denoise.tracer.scenes` for the bundled ones)::

    {"name": ..., "description": ..., "dimension": 6, "width": 128, "height": 128,
     "camera": {"from": [...], "to": [...], "fov": 40, "aperture_radius": 0.05,
                "focus_distance": 5, "shutter": [0, 1]},
     "integrator": {"max_depth": 1},
     "materials": {"red": {"type": "diffuse", "albedo": [0.7, 0.1, 0.1]}, ...},
     "objects": [{"shape": "sphere", "center": [...], "radius": 1, "material": "red",
                  "emission": [...], "motion": {"velocity": [...], "axis": [...],
                                                "angular_velocity_degrees": 90}}, ...],
     "lights": [{"type": "point", "position": [...], "intensity": [...]}, ...],
     "environment": {"type": "sky"} | {"type": "constant", "radiance": 1} | None}

Shapes: ``sphere`` (center, radius), ``box`` (min, max), ``quad`` (corner, edge_u, edge_v),
``lathe`` (profile: a name from :data:`CHESS_PROFILES` or (radius, height) pairs; base, scale)
and ``mesh`` (vertices, faces). The scene states its integrand ``dimension`` (paper section 1;
docs/concepts.md, "The pixel integral"); :func:`load_scene` checks it against the random
dimensions the path tracer will actually draw for the scene (:meth:`Scene.dimension_names`).

Every field is checked and a refusal is one ValueError naming it; a field the format does not
know is refused, not ignored (a typo did nothing). Numbers finite in float64 are also bounded
where float32 takes over (:mod:`~awr_denoise.tracer.limits`): the built geometry, over the
shutter, and the camera and point lights within ±``MAX_COORDINATE`` (Embree traces in float32),
radiances up to ``MAX_RADIANCE`` (the buffers store the variance, a sample squared, in float32).
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import _checks
from ..io.atomic import read_without_waiting
from .camera import ThinLensCamera, parse_camera
from .environment import ConstantEnvironment, LatLongEnvironment, parse_environment
from .lights import AreaLights, DirectionalLight, PointLight, parse_delta_light
from .limits import check_reach, in_range, numbers, reach, refuse_unknown, rgb_radiance, shown
from .limits import vector as _vec
from .materials import Material, parse_material
from .meshes import CHESS_PROFILES, box_mesh, lathe_mesh, quad_mesh, rotation_matrices, sphere_mesh

__all__ = ["Scene", "SceneObject", "Motion", "SHAPE_KINDS", "MAX_TRIANGLES", "MAX_DELTA_LIGHTS", "load_scene",
           "parse_scene", "dimension_names", "scene_files"]

SHAPE_KINDS = ("sphere", "box", "quad", "lathe", "mesh")
"""Valid values of ``objects[i].shape``."""

_DEFAULT_SPECULAR_DEPTH = 8
MAX_SIDE = 2**20  # pixels per side, as the command line allows
MAX_DEPTH = 256  # bounces: each adds two random dimensions, and memory and time grow with it
MAX_SEGMENTS = 1024  # tessellation of spheres and lathes: a mesh of up to about a million triangles
MAX_TRIANGLES = 2**22
"""Triangles of a whole scene. The tracer holds each in float64 with its normals and Embree's copy: a
file of a few kB of spheres of the largest tessellation asked for more memory than the machine had (a
red-team pass). The bundled scenes hold a few thousand."""
MAX_DELTA_LIGHTS = 64
"""Point and directional lights of a scene: each adds a shadow ray for every sample of a batch at every
bounce, all held at once (thousands of point lights ran out of memory on a small image)."""


@dataclass(frozen=True)
class Motion:
    """Rigid motion over time ``t``: ``x(t) = pivot + velocity t + R(axis, omega t) (x - pivot)``."""

    pivot: np.ndarray
    velocity: np.ndarray
    axis: np.ndarray
    angular_velocity: float  # radians per unit time

    @property
    def is_static(self) -> bool:
        """True when the motion does nothing."""
        return not np.any(self.velocity) and self.angular_velocity == 0.0

    def world_from_object(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-time rotations (N, 3, 3) and translations (N, 3) with ``x_world = R x + T``."""
        rotation = rotation_matrices(self.axis, self.angular_velocity * np.asarray(t, float))
        translation = self.pivot + self.velocity * np.asarray(t, float)[:, None] - np.einsum(
            "nij,j->ni", rotation, self.pivot)
        return rotation, translation


@dataclass
class SceneObject:
    """One triangle mesh with its material, emission and motion (object space = rest pose)."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    material: int
    emission: np.ndarray | None = None
    motion: Motion | None = None
    name: str = ""
    # (R, T) of a moving object frozen at the shutter time (vertices baked to R x + T):
    # textures are still looked up in the rest pose, so a frozen ball shows its rolled pattern.
    frozen_pose: tuple[np.ndarray, np.ndarray] | None = None


@dataclass
class Scene:
    """A parsed scene, ready for :class:`~awr_denoise.tracer.PathTracer`.

    Attributes
    ----------
    name, description
        Identification.
    width, height
        Image size in pixels.
    dimension
        Stated integrand dimension (number of random numbers per camera sample).
    """

    name: str
    description: str
    width: int
    height: int
    dimension: int
    camera: ThinLensCamera
    materials: list[Material]
    material_names: list[str]
    objects: list[SceneObject]
    delta_lights: list[PointLight | DirectionalLight]
    environment: ConstantEnvironment | LatLongEnvironment | None
    max_depth: int
    max_specular_depth: int = _DEFAULT_SPECULAR_DEPTH
    spec: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the image."""
        return (self.height, self.width)

    @property
    def has_motion(self) -> bool:
        """True when something moves while the shutter is open (a time dimension is drawn)."""
        return self.camera.shutter_length > 0 and any(
            o.motion is not None and not o.motion.is_static for o in self.objects)

    @property
    def area_lights(self) -> AreaLights | None:
        """The emissive triangles, or None."""
        tris, radiance = [], []
        for obj in self.objects:
            if obj.emission is not None and np.any(obj.emission > 0):
                tris.append(obj.vertices[obj.faces])
                radiance.append(np.tile(obj.emission, (len(obj.faces), 1)))
        if not tris:
            return None
        return AreaLights(np.concatenate(tris), np.concatenate(radiance))

    @property
    def has_sampled_lights(self) -> bool:
        """True when light sampling draws random numbers (area lights or an environment)."""
        return self.environment is not None or any(
            o.emission is not None and np.any(o.emission > 0) for o in self.objects)

    def dimension_names(self, max_depth: int | None = None) -> tuple[str, ...]:
        """Names of the random dimensions a camera sample draws, in dimension-index order."""
        return dimension_names(self, self.max_depth if max_depth is None else max_depth)

    def __repr__(self) -> str:
        return (f"Scene({self.name!r}, {self.width}x{self.height}, dimension={self.dimension}, "
                f"objects={len(self.objects)})")


def dimension_names(scene: Scene, max_depth: int) -> tuple[str, ...]:
    """The random dimensions drawn for ``scene`` at path depth ``max_depth``.

    Only effects the scene has get a dimension: ``pixel_x, pixel_y`` (box-filtered pixel
    area), ``lens_u, lens_v`` (thin lens), ``time`` (something moves during the shutter),
    ``light_u, light_v`` (area light or environment: one light sample per vertex, the same
    two numbers at every vertex of the path so the integrand dimension does not grow with
    next-event estimation), and ``bounce{k}_u, bounce{k}_v`` per diffuse/glossy bounce
    ``k < max_depth``. Mirror reflections and delta lights draw nothing.
    """
    names = ["pixel_x", "pixel_y"]
    if scene.camera.has_lens:
        names += ["lens_u", "lens_v"]
    if scene.has_motion:
        names.append("time")
    if scene.has_sampled_lights:
        names += ["light_u", "light_v"]
    for k in range(max_depth):
        names += [f"bounce{k}_u", f"bounce{k}_v"]
    return tuple(names)


def _mapping(value: Any, where: str) -> dict[str, Any]:
    """``value`` if it is a JSON object, else a ValueError naming the field."""
    if not isinstance(value, dict):
        raise ValueError(f"{where}: expected an object {{...}}, got {shown(value)}")
    return value


def _whole(spec: dict[str, Any], key: str, where: str, default: int, low: int, high: int) -> int:
    """The field ``where.key`` as a whole number in ``low..high`` (``_checks.whole``: no bool, no 2.7)."""
    return _checks.whole(f"{where}.{key}" if where else key, spec.get(key, default), minimum=low, maximum=high)


def _real(spec: dict[str, Any], key: str, where: str, default: float, *, positive: bool = False) -> float:
    """The field ``where.key`` as a finite number (``positive``: above 0)."""
    return _checks.real(f"{where}.{key}", spec.get(key, default), above=0 if positive else None)


def _area(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Total area of a mesh's triangles."""
    t = vertices[faces]
    return float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())


def _build_shape(spec: dict[str, Any], where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mesh of an object spec plus its pivot (the natural centre for rotations)."""
    shape = spec.get("shape")
    if shape == "sphere":
        center = _vec(spec, "center", where)
        radius = _real(spec, "radius", where, 1.0, positive=True)
        segments = _whole(spec, "segments", where, 48, 3, MAX_SEGMENTS)
        rings = _whole(spec, "rings", where, 24, 2, MAX_SEGMENTS)
        v, f, n = sphere_mesh(center, radius, segments=segments, rings=rings)
        return v, f, n, center
    if shape == "box":
        lo, hi = _vec(spec, "min", where), _vec(spec, "max", where)
        if np.any(hi <= lo):
            raise ValueError(f"{where}.max: must exceed min in every axis")
        v, f, n = box_mesh(lo, hi)
        return v, f, n, 0.5 * (lo + hi)
    if shape == "quad":
        corner = _vec(spec, "corner", where)
        eu, ev = _vec(spec, "edge_u", where), _vec(spec, "edge_v", where)
        v, f, n = quad_mesh(corner, eu, ev)
        return v, f, n, corner + 0.5 * (eu + ev)
    if shape == "lathe":
        profile = spec.get("profile", "pawn")
        if isinstance(profile, str):
            if profile not in CHESS_PROFILES:
                raise ValueError(f"{where}.profile: {profile!r} is not one of {', '.join(CHESS_PROFILES)}")
            profile = CHESS_PROFILES[profile]
        try:
            profile = np.asarray(profile, float)
        except (TypeError, ValueError):
            profile = np.empty(0)
        if profile.ndim != 2 or profile.shape[0] < 2 or profile.shape[1] != 2 or not np.all(np.isfinite(profile)):
            raise ValueError(f"{where}.profile: expected two or more finite (radius, height) pairs")
        base = _vec(spec, "base", where)
        segments = _whole(spec, "segments", where, 48, 3, MAX_SEGMENTS)
        # Counted before it is built: 100000 profile points turned 1024 times is 2e8 triangles.
        _check_triangles(where, 2 * segments * (len(profile) - 1), "its profile turned segments times makes up to")
        v, f, n = lathe_mesh(profile, base, _real(spec, "scale", where, 1.0, positive=True), segments=segments)
        return v, f, n, base
    if shape == "mesh":
        for key in ("vertices", "faces"):
            if key not in spec:
                raise ValueError(f"{where}.{key}: missing")
        what = "(N, 3) lists of numbers"
        v, f = numbers(f"{where}.vertices", spec["vertices"], what), numbers(f"{where}.faces", spec["faces"], what)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or not len(f):
            raise ValueError(f"{where}: mesh vertices and faces must be (N, 3)")
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{where}.vertices: must be finite")
        if not np.all(np.isfinite(f)) or np.any(f % 1):
            raise ValueError(f"{where}.faces: must be whole vertex indices")
        f = f.astype(np.int64)
        if f.min() < 0 or f.max() >= len(v):
            raise ValueError(f"{where}.faces: index out of range")
        e = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        n = np.zeros_like(v)
        for k in range(3):  # area-weighted vertex normals
            np.add.at(n, f[:, k], e)
        n /= np.maximum(np.linalg.norm(n, axis=1), 1e-30)[:, None]
        return v, f, n, v.mean(axis=0)
    raise ValueError(f"{where}.shape: {shape!r} is not one of {', '.join(SHAPE_KINDS)}")


_TOP_LEVEL = {"name", "description", "dimension", "width", "height", "camera", "integrator", "materials",
              "objects", "lights", "environment"}
_OBJECT_FIELDS = {"shape", "material", "emission", "motion", "name", "center", "radius", "segments", "rings",
                  "min", "max", "corner", "edge_u", "edge_v", "profile", "base", "scale", "vertices", "faces"}
_MOTION_FIELDS = {"velocity", "axis", "angular_velocity_degrees"}
_INTEGRATOR_FIELDS = {"max_depth", "max_specular_depth"}


def _check_triangles(where: str, count: int, what: str = "the scene has") -> None:
    """Refuse, naming ``where``, a triangle ``count`` beyond :data:`MAX_TRIANGLES`."""
    if count > MAX_TRIANGLES:
        raise ValueError(f"{where}: {what} {count} triangles, beyond the {MAX_TRIANGLES} a scene may hold "
                         "(memory: each is held in float64 with its normals and the ray tracer's copy)")


def _swept_reach(vertices: np.ndarray, motion: Motion, t0: float, t1: float) -> float:
    """A bound on the coordinates ``vertices`` reach moving by ``motion`` over the times ``[t0, t1]``.

    ``x(t) = (pivot + velocity t) + R(t) (x - pivot)``: the first term is linear in ``t`` (largest at an
    end of the interval) and the rotation keeps the length of the second.
    """
    with np.errstate(over="ignore", invalid="ignore"):  # a velocity or time past float64: inf, refused
        arm = float(np.sqrt(((vertices - motion.pivot) ** 2).sum(axis=1)).max())
        centre = max(reach(motion.pivot + motion.velocity * t) for t in (t0, t1))
        return centre + arm


def parse_scene(spec: dict[str, Any], *, width: int | None = None, height: int | None = None,
                base_dir: Path | None = None) -> Scene:
    """Build a :class:`Scene` from a spec dict (see the module docstring for the format)."""
    _check_depth(_mapping(spec, "scene"))  # before the copy, which recursed past Python's limit
    spec = copy.deepcopy(spec)
    refuse_unknown("scene", spec, _TOP_LEVEL)
    name = str(spec.get("name", "custom"))
    w = _whole({"width": width} if width is not None else spec, "width", "", 128, 1, MAX_SIDE)
    h = _whole({"height": height} if height is not None else spec, "height", "", 128, 1, MAX_SIDE)
    camera = parse_camera(_mapping(spec.get("camera", {}), "camera"), w, h)

    material_specs = _mapping(spec.get("materials", {}), "materials")
    material_names = list(material_specs)
    materials = [parse_material(n, _mapping(material_specs[n], f"materials.{n}")) for n in material_names]
    # Emitters reflect nothing; they share one black material.
    material_names.append("__emitter__")
    materials.append(parse_material("__emitter__", {"type": "diffuse", "albedo": 0.0}))

    objects: list[SceneObject] = []
    triangles = 0
    object_specs = spec.get("objects", [])
    if not isinstance(object_specs, list):
        raise ValueError(f"objects: expected a list [...], got {shown(object_specs)}")
    for i, obj in enumerate(object_specs):
        where = f"objects[{i}]"
        obj = _mapping(obj, where)
        refuse_unknown(where, obj, _OBJECT_FIELDS)
        # A shape past float64 (a lathe scaled by 1e308) overflows while it is built: refused by its reach.
        with np.errstate(over="ignore", invalid="ignore"):
            vertices, faces, normals, pivot = _build_shape(obj, where)
        check_reach(where, reach(vertices), "its geometry")
        triangles += len(faces)  # counted as built: at most one object's past the bound is ever held
        _check_triangles(where, triangles, "the scene up to it has")
        emission = rgb_radiance(f"{where}.emission", obj["emission"]) if "emission" in obj else None
        if emission is not None and not _area(vertices, faces) > 0:  # found only when the tracer was built
            raise ValueError(f"{where}.emission: an emissive object needs an area; its triangles have none")
        material_name = obj.get("material", "__emitter__" if emission is not None else None)
        if material_name not in material_names:
            raise ValueError(f"{where}.material: {material_name!r} is not one of {', '.join(material_names[:-1])}")
        motion = None
        if "motion" in obj:
            m = _mapping(obj["motion"], f"{where}.motion")
            refuse_unknown(f"{where}.motion", m, _MOTION_FIELDS)
            axis = in_range(f"{where}.motion.axis", _vec(m, "axis", f"{where}.motion", (0.0, 1.0, 0.0)))
            motion = Motion(pivot, _vec(m, "velocity", f"{where}.motion", (0.0, 0.0, 0.0)), axis / np.linalg.norm(axis),
                            np.radians(_real(m, "angular_velocity_degrees", f"{where}.motion", 0.0)))
            if emission is not None and not motion.is_static:
                raise ValueError(f"{where}.motion: emissive objects must be static")
            if motion.is_static:
                motion = None
            else:  # Embree traces the rest pose, the rays mapped into it: the swept positions must fit too.
                shutter = (camera.shutter_open, camera.shutter_close)
                check_reach(f"{where}.motion", _swept_reach(vertices, motion, *shutter),
                            f"over the shutter [{shutter[0]:g}, {shutter[1]:g}] its geometry")
        objects.append(SceneObject(vertices, faces, normals, material_names.index(material_name), emission,
                                   motion, str(obj.get("name", f"object{i}"))))
    if not objects:
        raise ValueError("objects: a scene needs at least one object")

    light_specs = spec.get("lights", [])
    if not isinstance(light_specs, list):
        raise ValueError(f"lights: expected a list [...], got {shown(light_specs)}")
    if len(light_specs) > MAX_DELTA_LIGHTS:
        raise ValueError(f"lights: {len(light_specs)} lights, beyond the {MAX_DELTA_LIGHTS} a scene may have "
                         "(each adds a shadow ray for every sample, all held at once); an emissive object is "
                         "sampled as one light whatever its triangles")
    delta_lights = [parse_delta_light(i, _mapping(lt, f"lights[{i}]")) for i, lt in enumerate(light_specs)]
    environment = spec.get("environment")
    environment = parse_environment(None if environment is None else _mapping(environment, "environment"), base_dir)
    integrator = _mapping(spec.get("integrator", {}), "integrator")
    refuse_unknown("integrator", integrator, _INTEGRATOR_FIELDS)
    max_depth = _whole(integrator, "max_depth", "integrator", 0, 0, MAX_DEPTH)
    max_specular_depth = _whole(integrator, "max_specular_depth", "integrator", _DEFAULT_SPECULAR_DEPTH, 0, MAX_DEPTH)

    # Objects that move while the shutter is closed are frozen at the opening time.
    if camera.shutter_length == 0:
        for obj in objects:
            if obj.motion is not None:
                rotation, translation = obj.motion.world_from_object(np.array([camera.shutter_open]))
                obj.vertices = obj.vertices @ rotation[0].T + translation[0]
                obj.normals = obj.normals @ rotation[0].T
                obj.frozen_pose = (rotation[0], translation[0])
                obj.motion = None

    scene = Scene(name, str(spec.get("description", "")), w, h, 0, camera, materials, material_names, objects,
                  delta_lights, environment, max_depth, max_specular_depth, spec)
    natural = len(scene.dimension_names())
    stated = _whole(spec, "dimension", "", natural, 0, 2 * MAX_DEPTH + 16)
    if stated != natural:
        raise ValueError(f"dimension: the scene states {stated} but its effects need {natural} "
                         f"({', '.join(scene.dimension_names())})")
    scene.dimension = stated
    return scene


def load_scene(scene: str | Path | dict[str, Any] | Scene, *, width: int | None = None,
               height: int | None = None) -> Scene:
    """Load a bundled scene by name, a JSON scene file, or a spec dict.

    Parameters
    ----------
    scene
        A name from :func:`~awr_denoise.tracer.list_scenes`, a path to a ``.json`` spec, a
        spec dict, or an already loaded :class:`Scene` (returned as is unless resized).
    width, height
        Override the scene's resolution.
    """
    if isinstance(scene, Scene):
        if width is None and height is None:
            return scene
        return parse_scene(scene.spec, width=width, height=height)
    if isinstance(scene, dict):
        return parse_scene(scene, width=width, height=height)
    from .scenes import BUNDLED_SCENES  # here: imported with the package, `python -m ...scenes` ran it twice

    text = str(scene)
    if text in BUNDLED_SCENES:
        return parse_scene(BUNDLED_SCENES[text], width=width, height=height)
    path = Path(text)
    if path.suffix == ".json" and path.is_file():
        try:
            return parse_scene(_read_json(path), width=width, height=height, base_dir=path.parent)
        except (TypeError, ValueError) as exc:
            raise type(exc)(f"{path}: {exc}") from None
    raise ValueError(f"scene: {text!r} is neither a JSON file nor one of {', '.join(BUNDLED_SCENES)}")


SCENE_FILE_MAX = 2**26
"""Bytes of the largest scene file read (64 MiB: a scene names its meshes and maps, it does not hold them)."""


def _read_json(path: Path) -> Any:
    """A scene file's JSON; NaN and Infinity, which Python's reader takes, are refused."""
    def refuse(constant: str) -> None:
        raise ValueError(f"{constant} is not a number a scene may hold")

    try:
        raw = read_without_waiting(path, limit=SCENE_FILE_MAX)
    except OSError as exc:  # a file that waits for data to be read (/proc/kmsg): refused, not waited on
        raise ValueError(f"cannot read this scene file ({exc.strerror or exc})") from None
    if len(raw) > SCENE_FILE_MAX:
        raise ValueError(f"larger than {SCENE_FILE_MAX} bytes; no scene file is")
    def once(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        """An object whose every field is given once: JSON keeps the last of two, the first ignored."""
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise ValueError(f"the field {shown(key)} is given twice in one object; the first would be "
                                 "ignored")
            seen.add(key)
        return dict(pairs)

    try:
        spec = json.loads(raw.decode("utf-8"), parse_constant=refuse, object_pairs_hook=once)
    except UnicodeDecodeError as exc:
        raise ValueError(f"not a JSON text file ({exc.reason})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"not valid JSON: {exc}") from None
    except RecursionError:  # arrays or objects nested thousands deep: the file's fault, not an internal error
        raise ValueError("not a scene: its JSON is nested deeper than Python's reader goes") from None
    return spec


MAX_NESTING = 32
"""Deepest nesting of a scene file's arrays and objects (a scene needs 5; copying one 500 deep ran out of
Python's recursion, an internal error)."""


def _check_depth(spec: Any) -> None:
    """Refuse JSON nested deeper than :data:`MAX_NESTING`, walked without recursion."""
    level = [spec]
    for depth in range(MAX_NESTING + 1):
        level = [child for node in level if isinstance(node, (dict, list))
                 for child in (node.values() if isinstance(node, dict) else node)]
        if not level:
            return
    raise ValueError(f"not a scene: its JSON is nested deeper than {MAX_NESTING} levels")


def scene_files(scene: str | Path) -> list[tuple[str, Path]]:
    """The files a JSON scene file reads besides itself, as ``(field, path)``: its environment map.

    A command checks them with its other inputs before anything is read or written (a FIFO
    would block the read; an output must never replace one). A bundled scene reads none.

    Examples
    --------
    >>> scene_files("default")
    []
    """
    from .scenes import BUNDLED_SCENES

    path = Path(scene)
    if str(scene) in BUNDLED_SCENES or path.suffix != ".json" or not path.is_file():
        return []
    try:
        spec = _read_json(path)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    environment = spec.get("environment") if isinstance(spec, dict) else None
    if isinstance(environment, dict) and environment.get("type") == "latlong" and "path" in environment:
        file = environment["path"]
        if not isinstance(file, str) or not file:
            raise ValueError(f"{path}: environment.path: expected a file name, got {shown(file)}")
        file = Path(file)
        return [("environment.path", file if file.is_absolute() else path.parent / file)]
    return []
