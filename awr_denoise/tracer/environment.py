"""Environment lighting: a constant environment and importance-sampled lat-long maps.

Direction convention (y up): ``theta`` is the angle from +y, ``phi`` the angle from +x towards
+z; the lat-long image has ``phi = 2 pi (col + 0.5) / W`` and ``theta = pi (row + 0.5) / H``
at pixel centres, row 0 at the zenith. Radiance is piecewise constant over pixels, which is
exactly the density the importance sampler follows (pbrt-v3 ``InfiniteAreaLight``): a marginal
CDF over rows and a conditional CDF over the columns of each row, both weighted by luminance
times ``sin(theta)``; ``pdf(w) = pdf(u, v) / (2 pi^2 sin(theta))``.

The bundled sky map (:func:`make_sky_envmap`) is procedural: a blue-to-white gradient sky, a
dim ground and a small bright sun, quantised to half floats so the generated array and the
EXR written by :func:`write_sky_envmap` hold identical values.
"""

from __future__ import annotations

import stat
from pathlib import Path
from typing import Any

import numpy as np

from .. import _checks
from .._places import checkout_data
from .limits import check_radiance, refuse_unknown, rgb_radiance

__all__ = [
    "ENVIRONMENT_KINDS",
    "ConstantEnvironment",
    "LatLongEnvironment",
    "direction_to_uv",
    "uv_to_direction",
    "make_sky_envmap",
    "write_sky_envmap",
    "read_envmap_exr",
    "parse_environment",
    "SKY_DEFAULTS",
]

ENVIRONMENT_KINDS = ("constant", "sky", "latlong")
"""Valid values of a scene's ``environment.type``."""

SKY_DEFAULTS: dict[str, Any] = {
    "width": 256,
    "height": 128,
    "sun_elevation_degrees": 35.0,
    "sun_azimuth_degrees": 60.0,
    "sun_radius_degrees": 2.5,
    "sun_radiance": 600.0,
    "sky_intensity": 1.0,
}
"""Parameters of the bundled procedural sky."""

_ENVIRONMENT_FIELDS = {"constant": {"type", "radiance"}, "sky": {"type", "scale", *SKY_DEFAULTS},
                       "latlong": {"type", "path", "scale"}}

_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
_HALF_MAX = float(np.finfo(np.float16).max)


def uv_to_direction(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Unit directions of lat-long coordinates ``u = phi / 2 pi``, ``v = theta / pi``."""
    phi, theta = 2.0 * np.pi * u, np.pi * v
    sin_theta = np.sin(theta)
    return np.stack([sin_theta * np.cos(phi), np.cos(theta), sin_theta * np.sin(phi)], axis=-1)


def direction_to_uv(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lat-long coordinates in [0, 1) x [0, 1] of unit directions (N, 3)."""
    theta = np.arccos(np.clip(w[:, 1], -1.0, 1.0))
    phi = np.arctan2(w[:, 2], w[:, 0])
    phi = np.where(phi < 0, phi + 2.0 * np.pi, phi)
    return phi / (2.0 * np.pi), theta / np.pi


class ConstantEnvironment:
    """Uniform radiance from every direction (the white-furnace environment).

    Sampled uniformly over the sphere; it builds no tables.
    """

    def __init__(self, radiance: np.ndarray) -> None:
        self.radiance = np.asarray(radiance, np.float64).reshape(3)

    def evaluate(self, w: np.ndarray) -> np.ndarray:
        """(N, 3) radiance arriving from directions ``w``."""
        return np.broadcast_to(self.radiance, (len(w), 3)).copy()

    def pdf(self, w: np.ndarray) -> np.ndarray:
        """Solid-angle density of :meth:`sample`."""
        return np.full(len(w), 1.0 / (4.0 * np.pi))

    def sample(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Directions uniform on the sphere: ``(wi, radiance, pdf)``."""
        z = 1.0 - 2.0 * u
        r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        phi = 2.0 * np.pi * v
        wi = np.stack([r * np.cos(phi), z, r * np.sin(phi)], axis=-1)
        return wi, self.evaluate(wi), self.pdf(wi)


class LatLongEnvironment:
    """A lat-long HDR map, importance-sampled with marginal/conditional CDFs.

    Parameters
    ----------
    image
        (H, W, 3) non-negative finite radiance.
    scale
        Multiplier applied to the radiance.
    """

    def __init__(self, image: np.ndarray, scale: float = 1.0) -> None:
        image = np.asarray(image, np.float64) * float(scale)
        if image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"environment.image: expected (H, W, 3), got shape {image.shape}")
        if not np.all(np.isfinite(image)) or np.any(image < 0):
            raise ValueError("environment.image: radiance must be finite and non-negative")
        self.image = image
        h, w = image.shape[:2]
        sin_theta = np.sin(np.pi * (np.arange(h) + 0.5) / h)
        weight = (image @ _LUMINANCE) * sin_theta[:, None]
        if weight.sum() <= 0:
            raise ValueError("environment.image: the map is black; nothing to sample")
        row_sum = weight.sum(axis=1)
        self.row_probability = row_sum / row_sum.sum()
        self.row_cdf = np.concatenate([[0.0], np.cumsum(self.row_probability)])
        self.row_cdf[-1] = 1.0
        safe_rows = np.where(row_sum > 0, row_sum, 1.0)
        # Rows with no energy are never chosen; give them a uniform conditional to stay finite.
        self.column_probability = np.where(row_sum[:, None] > 0, weight / safe_rows[:, None], 1.0 / w)
        column_cdf = np.concatenate([np.zeros((h, 1)), np.cumsum(self.column_probability, axis=1)], axis=1)
        column_cdf[:, -1] = 1.0
        self.column_cdf = column_cdf
        # Each row's CDF shifted by its row index makes one sorted array for all rows, so one
        # searchsorted call inverts every sample's conditional CDF at once.
        self._shifted_column_cdf = (column_cdf[:, :-1] + np.arange(h)[:, None]).ravel()

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the map."""
        return self.image.shape[0], self.image.shape[1]

    def _pixel(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        h, width = self.shape
        u, v = direction_to_uv(w)
        col = np.clip((u * width).astype(np.int64), 0, width - 1)
        row = np.clip((v * h).astype(np.int64), 0, h - 1)
        return row, col, v

    def evaluate(self, w: np.ndarray) -> np.ndarray:
        """(N, 3) radiance arriving from unit directions ``w`` (nearest pixel)."""
        row, col, _ = self._pixel(w)
        return self.image[row, col]

    def pdf(self, w: np.ndarray) -> np.ndarray:
        """Solid-angle density of :meth:`sample` at unit directions ``w``."""
        h, width = self.shape
        row, col, v = self._pixel(w)
        sin_theta = np.sin(np.pi * v)
        pdf_uv = self.row_probability[row] * self.column_probability[row, col] * h * width
        return np.where(sin_theta > 0, pdf_uv / (2.0 * np.pi * np.pi * np.where(sin_theta > 0, sin_theta, 1.0)), 0.0)

    def sample(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Importance-sample directions from two uniform numbers: ``(wi, radiance, pdf)``."""
        h, width = self.shape
        row = np.clip(np.searchsorted(self.row_cdf, u, side="right") - 1, 0, h - 1)
        p_row = self.row_probability[row]
        du = np.clip((u - self.row_cdf[row]) / np.where(p_row > 0, p_row, 1.0), 0.0, 1.0 - 1e-12)
        flat = np.searchsorted(self._shifted_column_cdf, row + v, side="right") - 1
        col = np.clip(flat - row * width, 0, width - 1)
        p_col = self.column_probability[row, col]
        dv = np.clip((v - self.column_cdf[row, col]) / np.where(p_col > 0, p_col, 1.0), 0.0, 1.0 - 1e-12)
        wi = uv_to_direction((col + dv) / width, (row + du) / h)
        sin_theta = np.sin(np.pi * (row + du) / h)
        pdf_uv = p_row * p_col * h * width
        pdf = np.where(sin_theta > 0, pdf_uv / (2.0 * np.pi * np.pi * np.maximum(sin_theta, 1e-300)), 0.0)
        return wi, self.image[row, col], pdf


def make_sky_envmap(width: int = SKY_DEFAULTS["width"], height: int = SKY_DEFAULTS["height"], *,
                    sun_elevation_degrees: float = SKY_DEFAULTS["sun_elevation_degrees"],
                    sun_azimuth_degrees: float = SKY_DEFAULTS["sun_azimuth_degrees"],
                    sun_radius_degrees: float = SKY_DEFAULTS["sun_radius_degrees"],
                    sun_radiance: float = SKY_DEFAULTS["sun_radiance"],
                    sky_intensity: float = SKY_DEFAULTS["sky_intensity"]) -> np.ndarray:
    """The bundled procedural sky as an (H, W, 3) float64 array of half-float values.

    A gradient from a white horizon to a blue zenith, a dim brown ground below the horizon, a
    sun disk with a soft halo. The sun's disk covers a few pixels, so its radiance stays below
    the half-float maximum and the map is small enough to commit.
    """
    if width < 4 or height < 2:
        raise ValueError(f"width, height: the sky map needs at least 4 x 2 pixels, got {width} x {height}")
    rows = (np.arange(height) + 0.5) / height
    cols = (np.arange(width) + 0.5) / width
    vv, uu = np.meshgrid(rows, cols, indexing="ij")
    w = uv_to_direction(uu.ravel(), vv.ravel())
    up = w[:, 1]
    zenith = np.array([0.20, 0.40, 0.95])
    horizon = np.array([0.95, 0.97, 1.00])
    ground = np.array([0.16, 0.13, 0.10])
    t = np.clip(up, 0.0, 1.0) ** 0.45
    sky = (1.0 - t)[:, None] * horizon + t[:, None] * zenith
    radiance = np.where((up >= 0)[:, None], sky, ground * (0.6 + 0.4 * np.clip(-up, 0, 1))[:, None]) * sky_intensity
    elevation, azimuth = np.radians(sun_elevation_degrees), np.radians(sun_azimuth_degrees)
    sun_dir = np.array([np.cos(elevation) * np.cos(azimuth), np.sin(elevation), np.cos(elevation) * np.sin(azimuth)])
    angle = np.degrees(np.arccos(np.clip(w @ sun_dir, -1.0, 1.0)))
    disk = np.clip((sun_radius_degrees - angle) / 0.5 + 0.5, 0.0, 1.0)  # half-degree soft edge
    halo = 4.0 * np.exp(-angle / 6.0) * (up > -0.05)
    sun_color = np.array([1.0, 0.93, 0.82])
    radiance = radiance + (disk * sun_radiance + halo)[:, None] * sun_color
    image = radiance.reshape(height, width, 3)
    with np.errstate(over="ignore"):  # half floats would hold Inf: numpy's warning, then a refusal naming "image"
        beyond = not np.isfinite(image.astype(np.float16)).all()
    if beyond:
        raise ValueError(f"sun_radiance, sky_intensity: the sky reaches {image.max():g}, beyond the half floats "
                         f"({_HALF_MAX:g}) its map is held in")
    return image.astype(np.float16).astype(np.float64)


def write_sky_envmap(path: str | Path | None = None, **parameters: Any) -> Path:
    """Regenerate the bundled sky map as a half-float EXR (default ``data/envmaps/sky.exr`` in a checkout; an
    install has no default: ``path`` is then needed)."""
    import OpenEXR  # the [exr] extra; only needed to write the file

    data = checkout_data()
    if path is None and data is None:
        raise ValueError("path: give the file to write; the default, data/envmaps/sky.exr, is a checkout's")
    path = Path(path) if path is not None else data / "envmaps" / "sky.exr"
    path.parent.mkdir(parents=True, exist_ok=True)
    params = {**SKY_DEFAULTS, **parameters}
    image = make_sky_envmap(**params).astype(np.float16)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "generator": "awr_denoise.tracer.environment.write_sky_envmap",
              "sky_parameters": " ".join(f"{k}={v}" for k, v in params.items())}
    channels = {c: np.ascontiguousarray(image[..., i]) for i, c in enumerate("RGB")}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))
    return path


def read_envmap_exr(path: str | Path) -> np.ndarray:
    """(H, W, 3) float64 radiance from an EXR with R, G, B channels.

    Read by the project's reader (:func:`awr_denoise.io.read_image`), as every other input file: the
    OpenEXR bindings read directly printed the C library's messages on stdout and stderr for a
    truncated map and allocated whatever size a header claimed (a 4 kB file claiming 30000x30000
    asked for 20 GiB), where the reader names the file and refuses the claim first (a red-team pass).
    """
    from ..io import read_image  # the file layer needs the [exr] extra; only a map read from a file does

    path = Path(path)
    try:
        kind = path.stat().st_mode
    except OSError as exc:
        raise ValueError(f"path: {path}: {exc.strerror}") from None
    if not stat.S_ISREG(kind):  # never opened: reading a FIFO would block
        raise ValueError(f"path: {path} is not a regular file")
    try:
        return np.asarray(read_image(path, channels=["R", "G", "B"]), np.float64)
    except ValueError as exc:  # InputFileError: the file named, and what it does not hold
        raise ValueError(f"path: {exc}") from None


def parse_environment(spec: dict[str, Any] | None, base_dir: Path | None = None
                      ) -> ConstantEnvironment | LatLongEnvironment | None:
    """Build the environment of a scene spec (``None`` when the scene has none), validating every field.

    Its radiance, after ``scale``, is bounded as every light's is (:data:`~awr_denoise.tracer.limits.MAX_RADIANCE`).
    """
    if spec is None:
        return None
    kind = spec.get("type")
    if kind not in ENVIRONMENT_KINDS:
        raise ValueError(f"environment.type: {kind!r} is not one of {', '.join(ENVIRONMENT_KINDS)}")
    refuse_unknown("environment", spec, _ENVIRONMENT_FIELDS[kind])
    if kind == "constant":
        return ConstantEnvironment(rgb_radiance("environment.radiance", spec.get("radiance", 1.0)))
    if kind == "sky":
        try:
            sky = make_sky_envmap(**_sky_parameters(spec))
        except ValueError as exc:  # its radiance past half floats: named as the scene's fields
            raise ValueError(f"environment.{exc}") from None
        return _scaled(sky, spec, "the sky's")
    if not isinstance(spec.get("path"), str) or not spec["path"]:
        raise ValueError(f"environment.path: expected a file name, got {spec.get('path')!r:.40}")
    path = Path(spec["path"])
    if not path.is_absolute() and base_dir is not None:
        path = base_dir / path
    _scale(spec)  # checked before the map is read
    try:
        image = read_envmap_exr(path)
    except ValueError as exc:
        raise ValueError(f"environment.{exc}") from None
    return _scaled(image, spec, "the map's")


MAX_SKY_WIDTH = 4096
"""Widest procedural sky map (its height at most half of it): 200 MB as float64, the whole sky sampled
from it. A width of 100000, unchecked, asked for tens of GB (a red-team pass)."""


def _sky_parameters(spec: dict[str, Any]) -> dict[str, Any]:
    """The sky's fields, each checked and named: none was (a string width was compared with an int,
    ``sky_intensity: true`` taken as 1, a sun of 1e308 a warning and a field the file does not have)."""
    where = "environment."
    params = {"width": _checks.whole(where + "width", spec.get("width", SKY_DEFAULTS["width"]),
                                     minimum=4, maximum=MAX_SKY_WIDTH),
              "height": _checks.whole(where + "height", spec.get("height", SKY_DEFAULTS["height"]),
                                      minimum=2, maximum=MAX_SKY_WIDTH // 2)}
    bounds = {"sun_elevation_degrees": (-90.0, 90.0), "sun_azimuth_degrees": (-1e6, 1e6),
              "sun_radius_degrees": (0.0, 90.0), "sun_radiance": (0.0, _HALF_MAX), "sky_intensity": (0.0, _HALF_MAX)}
    for key, (low, high) in bounds.items():
        params[key] = _checks.real(where + key, spec.get(key, SKY_DEFAULTS[key]), minimum=low, maximum=high)
    return params


def _scale(spec: dict[str, Any]) -> float:
    """``environment.scale``, a finite number >= 0."""
    return _checks.real("environment.scale", spec.get("scale", 1.0), minimum=0)


def _scaled(image: np.ndarray, spec: dict[str, Any], whose: str) -> LatLongEnvironment:
    """The lat-long environment of ``image`` times ``environment.scale``, its peak within the radiance bound.

    The field blamed is the scale when the scene gives one (a map of sane values scaled too far), else the
    map itself (``path``: an EXR may hold up to 3.4e38; the sky's parameters keep it in half floats).
    """
    scale = _scale(spec)
    with np.errstate(over="ignore", invalid="ignore"):  # an Inf or NaN in the map: refused by the constructor
        peak = float(np.max(image, initial=0.0) * scale) if np.all(np.isfinite(image)) else 0.0
    field = "scale" if "scale" in spec else "path" if "path" in spec else "type"
    said = f"{whose} radiance times the scale {scale:g}" if "scale" in spec else f"{whose} radiance"
    check_radiance(f"environment.{field}", peak, said)
    return LatLongEnvironment(image, scale)
