"""The camera: a thin lens (depth of field) that degenerates to a pinhole, with a shutter.

pbrt-v4 conventions: camera space looks down +z with +y up; ``p_film`` is a continuous pixel
position (x to the right, y down, pixel ``(row, col)`` covers ``[col, col + 1) x [row, row + 1)``,
a box pixel filter); ``p_lens`` a point on the lens disk. The thin-lens model (pbrt
``PerspectiveCamera``) sends every ray through the point where the pinhole ray meets the plane
of focus, so objects at ``focus_distance`` stay sharp and the blur grows with the aperture.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import _checks
from .limits import check_reach, in_range, reach, refuse_unknown, shown, vector
from .meshes import cross, normalize

__all__ = ["ThinLensCamera", "concentric_disk", "parse_camera"]

_CAMERA_FIELDS = {"from", "to", "up", "fov", "aperture_radius", "focus_distance", "shutter"}


def concentric_disk(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Shirley-Chiu concentric map of [0, 1)^2 onto the unit disk (area preserving)."""
    a, b = 2.0 * u - 1.0, 2.0 * v - 1.0
    use_a = np.abs(a) > np.abs(b)
    safe_a = np.where(a == 0, 1.0, a)
    safe_b = np.where(b == 0, 1.0, b)
    r = np.where(use_a, a, b)
    phi = np.where(use_a, (np.pi / 4) * (b / safe_a), np.pi / 2 - (np.pi / 4) * (a / safe_b))
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)


@dataclass(frozen=True)
class ThinLensCamera:
    """A perspective camera with an optional thin lens and shutter interval.

    Parameters
    ----------
    look_from, look_at, up
        Position, target and up hint (world space) defining ``world_from_camera``.
    fov_degrees
        Full vertical field of view.
    width, height
        Image size in pixels.
    aperture_radius
        Lens radius; 0 makes a pinhole (no lens dimensions are drawn).
    focus_distance
        Distance along the view axis of the plane in focus.
    shutter_open, shutter_close
        Shutter interval; rays get times uniformly in it when the scene moves.
    """

    look_from: np.ndarray
    look_at: np.ndarray
    up: np.ndarray
    fov_degrees: float
    width: int
    height: int
    aperture_radius: float = 0.0
    focus_distance: float = 1.0
    shutter_open: float = 0.0
    shutter_close: float = 0.0

    @property
    def has_lens(self) -> bool:
        """True when the lens has a non-zero aperture (depth of field)."""
        return self.aperture_radius > 0

    @property
    def shutter_length(self) -> float:
        """Length of the shutter interval."""
        return self.shutter_close - self.shutter_open

    @property
    def world_from_camera(self) -> np.ndarray:
        """(3, 3) rotation whose columns are camera x (right), y (up), z (forward) in world space."""
        # Scaled into range first (by powers of two, exact; nothing for ordinary cameras): a from and a to
        # 1e-170 apart, or an up of 1e200, normalised to zero and rendered black.
        forward = normalize(in_range("camera.to", np.asarray(self.look_at, float) - np.asarray(self.look_from, float)))
        right = normalize(in_range("camera.up", cross(forward, in_range("camera.up", np.asarray(self.up, float)))))
        true_up = cross(right, forward)
        return np.stack([right, true_up, forward], axis=1)

    def generate_rays(self, p_film: np.ndarray, p_lens: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """World-space ray origins and unit directions for film points and lens samples.

        Parameters
        ----------
        p_film
            (N, 2) continuous pixel coordinates (x, y), y pointing down.
        p_lens
            (N, 2) uniform numbers in [0, 1)^2 mapped to the lens disk, or None for a pinhole.
        """
        tan_half = np.tan(np.radians(self.fov_degrees) / 2.0)
        aspect = self.width / self.height
        x = (2.0 * p_film[:, 0] / self.width - 1.0) * tan_half * aspect
        y = (1.0 - 2.0 * p_film[:, 1] / self.height) * tan_half
        d_camera = np.stack([x, y, np.ones_like(x)], axis=-1)
        o_camera = np.zeros_like(d_camera)
        if p_lens is not None and self.has_lens:
            lens = self.aperture_radius * concentric_disk(p_lens[:, 0], p_lens[:, 1])
            # d_camera has z = 1, so the pinhole ray meets the focal plane at focus_distance * d.
            p_focus = self.focus_distance * d_camera
            o_camera = np.stack([lens[:, 0], lens[:, 1], np.zeros(len(lens))], axis=-1)
            d_camera = p_focus - o_camera
        m = self.world_from_camera
        # Broadcast products instead of ``@``: a (N, 3) x (3, 3) matmul goes through BLAS,
        # whose worker threads compete with the tracer's own threads.
        origins = (o_camera[:, :1] * m[:, 0] + o_camera[:, 1:2] * m[:, 1] + o_camera[:, 2:] * m[:, 2]
                   + np.asarray(self.look_from, float))
        directions = normalize(d_camera[:, :1] * m[:, 0] + d_camera[:, 1:2] * m[:, 1] + d_camera[:, 2:] * m[:, 2])
        return origins, directions

    def time(self, u: np.ndarray) -> np.ndarray:
        """Ray times uniformly in the shutter interval."""
        return self.shutter_open + u * self.shutter_length


def parse_camera(spec: dict[str, Any], width: int, height: int) -> ThinLensCamera:
    """Build the camera of a scene spec, validating every field.

    Its position, target, lens radius and focus distance are lengths the rays start from or reach:
    each is bounded by :data:`~awr_denoise.tracer.limits.MAX_COORDINATE`, as the geometry is.
    """
    refuse_unknown("camera", spec, _CAMERA_FIELDS)
    look_from = vector(spec, "from", "camera", (0.0, 0.0, 0.0))
    look_at = vector(spec, "to", "camera", (0.0, 0.0, 1.0))
    up = vector(spec, "up", "camera", (0.0, 1.0, 0.0))
    check_reach("camera.from", reach(look_from))
    check_reach("camera.to", reach(look_at))
    if np.array_equal(look_from, look_at):  # not allclose: points 1 apart at 1e6 are a camera (a red-team pass)
        raise ValueError("camera.to: must differ from camera.from")
    # The up hint picks the image's vertical: exactly parallel to the view (looking straight up with the
    # default up) or zero it leaves none, and every pixel took one ray (Mitsuba refuses it too).
    if not np.any(np.cross(in_range("camera.to", look_at - look_from), in_range("camera.up", up))):
        raise ValueError(f"camera.up: {shown(spec.get('up', [0.0, 1.0, 0.0]))} is parallel to the view direction "
                         "from camera.from to camera.to; give an up vector across it")
    fov = _checks.real("camera.fov", spec.get("fov", 40.0))
    if not 0 < fov < 180:
        raise ValueError(f"camera.fov: {fov} is outside (0, 180) degrees")
    aperture = _checks.real("camera.aperture_radius", spec.get("aperture_radius", 0.0), minimum=0)
    check_reach("camera.aperture_radius", aperture)
    if "focus_distance" in spec:
        focus = _checks.real("camera.focus_distance", spec["focus_distance"], above=0)
        check_reach("camera.focus_distance", focus)
    else:
        focus = float(np.linalg.norm(look_at - look_from))
    shutter = spec.get("shutter", (0.0, 0.0))
    if not isinstance(shutter, (list, tuple, np.ndarray)) or len(shutter) != 2:
        raise ValueError(f"camera.shutter: expected [open, close], got {shutter!r:.40}")
    shutter = tuple(_checks.real("camera.shutter", s) for s in shutter)
    if shutter[1] < shutter[0]:
        raise ValueError(f"camera.shutter: expected [open, close] with close >= open, got {shutter}")
    return ThinLensCamera(look_from, look_at, up, fov, width, height, aperture, focus, shutter[0], shutter[1])
