"""Light sources: emissive triangles (area lights) and delta lights (point, directional).

Area lights are the triangles of emissive objects, sampled with probability proportional to
their area and uniformly inside each one, so the area density is ``1 / total_area`` everywhere
on the emitters; emission is one-sided, on the side of the triangle's geometric normal. Delta
lights draw no random numbers; they give hard shadows without adding integrand dimensions
(the 4D and 5D scenes are lit by them).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .limits import check_reach, in_range, reach, refuse_unknown, rgb_radiance, vector
from .meshes import cross, dot, normalize

__all__ = ["AreaLights", "PointLight", "DirectionalLight", "DELTA_LIGHT_KINDS", "parse_delta_light"]

DELTA_LIGHT_KINDS = ("point", "directional")
"""Valid values of a ``lights[i].type``."""

_LIGHT_FIELDS = {"point": {"type", "position", "intensity"}, "directional": {"type", "direction", "irradiance"}}


class AreaLights:
    """All emissive triangles of a scene, sampled by area.

    Parameters
    ----------
    triangles
        (T, 3, 3) world-space vertices.
    radiance
        (T, 3) emitted radiance of each triangle.
    """

    def __init__(self, triangles: np.ndarray, radiance: np.ndarray) -> None:
        self.triangles = np.asarray(triangles, np.float64)
        self.radiance = np.asarray(radiance, np.float64)
        e1 = self.triangles[:, 1] - self.triangles[:, 0]
        e2 = self.triangles[:, 2] - self.triangles[:, 0]
        n = cross(e1, e2)
        self.areas = 0.5 * np.sqrt(dot(n, n))
        self.normals = normalize(n)
        self.total_area = float(self.areas.sum())
        if self.total_area <= 0:
            raise ValueError("objects.emission: emissive objects have zero area")
        self.cdf = np.concatenate([[0.0], np.cumsum(self.areas) / self.total_area])
        self.cdf[-1] = 1.0

    @property
    def pdf_area(self) -> float:
        """Area density of :meth:`sample` on every emitter."""
        return 1.0 / self.total_area

    def sample(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points on the emitters from two uniform numbers: ``(p_light, n_light, radiance)``.

        ``u`` picks the triangle through the area CDF and is rescaled to [0, 1) inside it, so
        the sample uses two dimensions however many triangles there are.
        """
        index = np.clip(np.searchsorted(self.cdf, u, side="right") - 1, 0, len(self.areas) - 1)
        lo, hi = self.cdf[index], self.cdf[index + 1]
        u_in = np.clip((u - lo) / np.maximum(hi - lo, 1e-300), 0.0, 1.0)
        su = np.sqrt(u_in)
        b0, b1 = 1.0 - su, v * su
        tri = self.triangles[index]
        p = b0[:, None] * tri[:, 0] + b1[:, None] * tri[:, 1] + (1.0 - b0 - b1)[:, None] * tri[:, 2]
        return p, self.normals[index], self.radiance[index]


@dataclass(frozen=True)
class PointLight:
    """Isotropic point light of radiant ``intensity`` (W/sr per channel)."""

    position: np.ndarray
    intensity: np.ndarray


@dataclass(frozen=True)
class DirectionalLight:
    """Distant light arriving along ``direction`` (pointing from the light into the scene)."""

    direction: np.ndarray
    irradiance: np.ndarray


def parse_delta_light(index: int, spec: dict[str, Any]) -> PointLight | DirectionalLight:
    """Build a delta light from a scene-file entry, validating every field.

    A point light's position is bounded as the geometry is (:data:`~awr_denoise.tracer.limits.MAX_COORDINATE`),
    its intensity, or a directional light's irradiance, as radiances are
    (:data:`~awr_denoise.tracer.limits.MAX_RADIANCE`).
    """
    kind = spec.get("type")
    name = f"lights[{index}]"
    if kind not in DELTA_LIGHT_KINDS:
        raise ValueError(f"{name}.type: {kind!r} is not one of {', '.join(DELTA_LIGHT_KINDS)}")
    refuse_unknown(name, spec, _LIGHT_FIELDS[kind])
    if kind == "point":
        intensity = rgb_radiance(f"{name}.intensity", spec.get("intensity", 1.0))
        position = vector(spec, "position", name)
        check_reach(f"{name}.position", reach(position))
        return PointLight(position, intensity)
    irradiance = rgb_radiance(f"{name}.irradiance", spec.get("irradiance", 1.0))
    return DirectionalLight(normalize(in_range(f"{name}.direction", vector(spec, "direction", name))[None])[0],
                            irradiance)
