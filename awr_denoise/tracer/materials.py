"""Materials and their BSDFs, evaluated and sampled for arrays of shading points.

All directions are in the local shading frame (``z`` = shading normal), pbrt-style: ``wo``
points towards the viewer, ``wi`` towards the light, both away from the surface.

Material kinds (see :data:`MATERIAL_KINDS`):

* ``diffuse``: Lambertian, ``f = albedo / pi``; the albedo may be a procedural checker texture.
* ``glossy``: a diffuse base plus a GGX microfacet reflection lobe (Walter et al. 2007) with
  the height-correlated Smith masking-shadowing term (Heitz 2014) and the Fresnel factor of a
  perfect conductor (1), ``f = kd / pi + ks * D G2 / (4 cos_o cos_i)``. With ``kd + ks <= 1`` per channel the
  albedo never exceeds 1 (each lobe alone reflects at most its weight).
* ``mirror``: a perfect specular reflector (a delta BSDF; it consumes no random numbers).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import _checks
from .limits import MAX_COORDINATE, numbers, refuse_unknown, shown, vector

__all__ = [
    "MATERIAL_KINDS",
    "Material",
    "CheckerTexture",
    "parse_material",
    "ggx_d",
    "smith_g1",
    "smith_g2",
    "glossy_eval",
    "glossy_pdf",
    "glossy_sample",
    "cosine_hemisphere_sample",
]

MATERIAL_KINDS = ("diffuse", "glossy", "mirror")
"""Valid values of a material's ``type``."""

_INV_PI = 1.0 / np.pi
# Roughness below this is clamped: GGX with alpha -> 0 is a delta and its pdf overflows.
_MIN_ALPHA = 1e-3
_CHECKER_FIELDS = {"type", "color_a", "color_b", "scale", "axes", "offset"}


@dataclass(frozen=True)
class CheckerTexture:
    """Procedural checkerboard: ``color_a`` where ``sum(floor(p / scale))`` is even, else ``color_b``.

    Evaluated in object space (so a rolling ball's pattern rolls with it) on the listed
    ``axes`` (``"xz"`` for a board lying in the ground plane, ``"xyz"`` for a solid checker).
    """

    color_a: np.ndarray
    color_b: np.ndarray
    scale: float = 1.0
    axes: str = "xyz"
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def evaluate(self, p_object: np.ndarray) -> np.ndarray:
        """(N, 3) albedo at object-space points (N, 3)."""
        index = np.floor((p_object - self.offset) / self.scale).astype(np.int64)
        parity = np.zeros(len(p_object), np.int64)
        for axis in self.axes:
            parity += index[:, "xyz".index(axis)]
        even = (parity % 2 == 0)[:, None]
        return np.where(even, self.color_a, self.color_b)


@dataclass(frozen=True)
class Material:
    """One material of a scene (see the module docstring for the kinds).

    Parameters
    ----------
    kind
        One of :data:`MATERIAL_KINDS`.
    albedo
        Diffuse reflectance ``kd`` (RGB, each in [0, 1]).
    specular
        Weight ``ks`` of the GGX lobe (``glossy``) or the mirror reflectance (``mirror``).
    roughness
        GGX ``alpha`` (``glossy`` only).
    texture
        Optional checker texture replacing ``albedo``.
    """

    kind: str
    albedo: np.ndarray
    specular: np.ndarray
    roughness: float = 0.2
    texture: CheckerTexture | None = None

    @property
    def is_specular(self) -> bool:
        """True for delta BSDFs (no random numbers, no light sampling)."""
        return self.kind == "mirror"

    def diffuse_albedo(self, p_object: np.ndarray) -> np.ndarray:
        """(N, 3) ``kd`` at object-space points."""
        if self.texture is not None:
            return self.texture.evaluate(p_object)
        return np.broadcast_to(self.albedo, (len(p_object), 3))

    def reflectance(self, p_object: np.ndarray) -> np.ndarray:
        """(N, 3) albedo as a denoiser's feature: ``kd`` (+ ``ks`` for glossy), a mirror's reflectance.

        The sum of the lobes' weights, each lobe reflecting at most its weight (OIDN's advice
        for layered surfaces); at most 1 by the energy check of :func:`parse_material`.
        """
        if self.kind == "mirror":
            return np.broadcast_to(self.specular, (len(p_object), 3))
        kd = self.diffuse_albedo(p_object)
        return kd + self.specular if self.kind == "glossy" else kd

    def lobe_probability(self, kd: np.ndarray) -> np.ndarray:
        """Probability of sampling the diffuse lobe, proportional to the lobe weights."""
        if self.kind != "glossy":
            return np.ones(len(kd))
        wd = kd.mean(axis=1)
        ws = float(np.mean(self.specular))
        total = wd + ws
        return np.where(total > 0, wd / np.where(total > 0, total, 1.0), 0.5)

    def evaluate(self, wo: np.ndarray, wi: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """(N, 3) BSDF value ``f(wo, wi)`` (zero below the shading hemisphere)."""
        upper = ((wo[:, 2] > 0) & (wi[:, 2] > 0))[:, None]
        f = kd * _INV_PI
        if self.kind == "glossy":
            f = f + glossy_eval(wo, wi, self.roughness, self.specular)
        return np.where(upper, f, 0.0)

    def pdf(self, wo: np.ndarray, wi: np.ndarray, kd: np.ndarray) -> np.ndarray:
        """Solid-angle pdf of :meth:`sample` choosing ``wi``."""
        upper = (wo[:, 2] > 0) & (wi[:, 2] > 0)
        p_diffuse = self.lobe_probability(kd)
        pdf = p_diffuse * np.maximum(wi[:, 2], 0.0) * _INV_PI
        if self.kind == "glossy":
            pdf = pdf + (1.0 - p_diffuse) * glossy_pdf(wo, wi, self.roughness)
        return np.where(upper, pdf, 0.0)

    def sample(self, wo: np.ndarray, u: np.ndarray, v: np.ndarray,
               kd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sample ``wi`` with two uniform numbers; returns ``(wi, f, pdf)``.

        The lobe is chosen with ``u`` against the diffuse probability and ``u`` is rescaled
        to [0, 1) afterwards, so the BSDF uses exactly two dimensions.
        """
        p_diffuse = self.lobe_probability(kd)
        if self.kind == "glossy":
            choose_diffuse = u < p_diffuse
            u_diffuse = u / np.where(p_diffuse > 0, p_diffuse, 1.0)
            u_glossy = (u - p_diffuse) / np.where(p_diffuse < 1, 1.0 - p_diffuse, 1.0)
            wi_d = cosine_hemisphere_sample(np.clip(u_diffuse, 0.0, 1.0), v)
            wi_g = glossy_sample(wo, np.clip(u_glossy, 0.0, 1.0), v, self.roughness)
            wi = np.where(choose_diffuse[:, None], wi_d, wi_g)
        else:
            wi = cosine_hemisphere_sample(u, v)
        return wi, self.evaluate(wo, wi, kd), self.pdf(wo, wi, kd)


def parse_material(name: str, spec: dict[str, Any]) -> Material:
    """Build a :class:`Material` from a scene-file entry, validating every field."""
    kind = spec.get("type", "diffuse")
    if kind not in MATERIAL_KINDS:
        raise ValueError(f"materials.{name}.type: {kind!r} is not one of {', '.join(MATERIAL_KINDS)}")
    refuse_unknown(f"materials.{name}", spec, {"type", "albedo", "specular", "roughness", "texture"})
    albedo = _rgb(f"materials.{name}.albedo", spec.get("albedo", 0.0 if kind == "mirror" else 0.8))
    specular = _rgb(f"materials.{name}.specular", spec.get("specular", 1.0 if kind == "mirror" else 0.0))
    if kind == "glossy" and np.any(albedo + specular > 1.0 + 1e-12):
        raise ValueError(f"materials.{name}: albedo + specular must be <= 1 per channel (energy conservation)")
    roughness = _checks.real(f"materials.{name}.roughness", spec.get("roughness", 0.2), above=0, maximum=1)
    texture = None
    if "texture" in spec:
        where = f"materials.{name}.texture"
        t = spec["texture"]
        if not isinstance(t, dict):
            raise ValueError(f"{where}: expected an object {{...}}, got {t!r:.40}")
        if t.get("type", "checker") != "checker":
            raise ValueError(f"{where}.type: {t.get('type')!r} is not one of checker")
        refuse_unknown(where, t, _CHECKER_FIELDS)
        axes = str(t.get("axes", "xyz"))
        if not axes or set(axes) - set("xyz"):
            raise ValueError(f"{where}.axes: {axes!r} must be letters from 'xyz'")
        # floor(p / scale) is cast to int64: a scale of 0 or NaN gave garbage parities, not a refusal.
        scale = _checks.real(f"{where}.scale", t.get("scale", 1.0), above=0)
        offset = vector(t, "offset", where, (0.0, 0.0, 0.0))
        # Past the scene's coordinates p - offset keeps none of p's digits: a pattern of noise, no word.
        if np.abs(offset).max() > MAX_COORDINATE:
            raise ValueError(f"{where}.offset: beyond the ±{MAX_COORDINATE:g} scene units the tracer traces in")
        texture = CheckerTexture(_rgb(f"{where}.color_a", t.get("color_a", 0.8)),
                                 _rgb(f"{where}.color_b", t.get("color_b", 0.1)), scale, axes, offset)
    return Material(kind, albedo, specular, roughness, texture)


def _rgb(name: str, value: Any) -> np.ndarray:
    try:
        rgb = np.broadcast_to(numbers(name, value, "a number or 3 numbers"), (3,)).copy()
    except ValueError:  # two or four numbers: numpy's words named nothing
        raise ValueError(f"{name}: expected a number or 3 numbers in [0, 1], got {shown(value)}") from None
    if not np.all(np.isfinite(rgb)) or np.any(rgb < 0) or np.any(rgb > 1):
        raise ValueError(f"{name}: reflectances must be finite and in [0, 1], got {value!r}")
    return rgb


# ---------------------------------------------------------------------------- GGX pieces
def ggx_d(cos_h: np.ndarray, alpha: float) -> np.ndarray:
    """GGX / Trowbridge-Reitz normal distribution ``D(h)`` for ``cos_h = n . h``."""
    a2 = alpha * alpha
    c2 = cos_h * cos_h
    denom = c2 * (a2 - 1.0) + 1.0
    return np.where(cos_h > 0, a2 / (np.pi * denom * denom), 0.0)


def _smith_lambda(cos_theta: np.ndarray, alpha: float) -> np.ndarray:
    c2 = np.clip(cos_theta * cos_theta, 1e-12, 1.0)
    tan2 = (1.0 - c2) / c2
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * tan2) - 1.0)


def smith_g1(cos_theta: np.ndarray, alpha: float) -> np.ndarray:
    """Smith masking ``G1`` for GGX."""
    return 1.0 / (1.0 + _smith_lambda(cos_theta, alpha))


def smith_g2(cos_o: np.ndarray, cos_i: np.ndarray, alpha: float) -> np.ndarray:
    """Height-correlated Smith masking-shadowing ``G2`` (Heitz 2014, eq. 99)."""
    return 1.0 / (1.0 + _smith_lambda(cos_o, alpha) + _smith_lambda(cos_i, alpha))


def glossy_eval(wo: np.ndarray, wi: np.ndarray, roughness: float, ks: np.ndarray) -> np.ndarray:
    """(N, 3) GGX reflection lobe ``ks * D G2 F / (4 cos_o cos_i)``, Fresnel ``F`` with ``f0 = 1``.

    ``ks`` scales the whole lobe, so its albedo is at most ``ks`` (Fresnel is 1 for a perfect
    conductor; the lobe loses energy only to masking).
    """
    alpha = max(roughness, _MIN_ALPHA)
    h = wo + wi
    h = h / np.maximum(np.linalg.norm(h, axis=1), 1e-30)[:, None]
    cos_o, cos_i = wo[:, 2], wi[:, 2]
    valid = (cos_o > 0) & (cos_i > 0)
    d = ggx_d(h[:, 2], alpha)
    g = smith_g2(cos_o, cos_i, alpha)
    denom = np.where(valid, 4.0 * cos_o * cos_i, 1.0)
    value = np.where(valid, d * g / denom, 0.0)
    return value[:, None] * ks


def glossy_pdf(wo: np.ndarray, wi: np.ndarray, roughness: float) -> np.ndarray:
    """Solid-angle pdf of :func:`glossy_sample`: ``D(h) cos_h / (4 |wo . h|)``."""
    alpha = max(roughness, _MIN_ALPHA)
    h = wo + wi
    h = h / np.maximum(np.linalg.norm(h, axis=1), 1e-30)[:, None]
    wo_h = np.einsum("ij,ij->i", wo, h)
    valid = (wo_h > 0) & (wi[:, 2] > 0)
    return np.where(valid, ggx_d(h[:, 2], alpha) * h[:, 2] / (4.0 * np.where(valid, wo_h, 1.0)), 0.0)


def glossy_sample(wo: np.ndarray, u: np.ndarray, v: np.ndarray, roughness: float) -> np.ndarray:
    """Sample a GGX half vector with density ``D(h) cos_h`` and reflect ``wo`` about it."""
    alpha = max(roughness, _MIN_ALPHA)
    tan2 = alpha * alpha * u / np.maximum(1.0 - u, 1e-12)
    cos_h = 1.0 / np.sqrt(1.0 + tan2)
    sin_h = np.sqrt(np.maximum(0.0, 1.0 - cos_h * cos_h))
    phi = 2.0 * np.pi * v
    h = np.stack([sin_h * np.cos(phi), sin_h * np.sin(phi), cos_h], axis=-1)
    wo_h = np.einsum("ij,ij->i", wo, h)
    return 2.0 * wo_h[:, None] * h - wo


def cosine_hemisphere_sample(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cosine-weighted directions about +z (Malley's method on a concentric disk)."""
    a, b = 2.0 * u - 1.0, 2.0 * v - 1.0
    use_a = np.abs(a) > np.abs(b)
    safe_a = np.where(a == 0, 1.0, a)
    safe_b = np.where(b == 0, 1.0, b)
    r = np.where(use_a, a, b)
    phi = np.where(use_a, (np.pi / 4) * (b / safe_a), np.pi / 2 - (np.pi / 4) * (a / safe_b))
    x, y = r * np.cos(phi), r * np.sin(phi)
    z = np.sqrt(np.maximum(0.0, 1.0 - x * x - y * y))
    return np.stack([x, y, z], axis=-1)
