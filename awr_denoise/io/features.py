"""Where renderers write albedo, normal and depth, and how they become feature buffers.

=========  ================================  ==============================  =================================
preset     albedo                            normal                          depth
=========  ================================  ==============================  =================================
pbrt       ``Albedo.R/G/B``                  ``Ns.X/Y/Z`` (camera space)     ``P.Z`` (camera-space z)
cycles     ``<layer>.Denoising Albedo``      ``<layer>.Denoising Normal``    ``<layer>.Denoising Depth``
                                             (camera space)                  (distance along the ray)
mitsuba    ``<name>.albedo`` (``aov``)       ``<name>.normal``,              ``<name>.depth`` (``aov``
                                             ``.sh_normal`` or ``.nn``       ``depth``: distance along the ray)
                                             (world space)
awr        ``albedo.*`` (the dump layout, :mod:`awr_denoise.io.dump`)
=========  ================================  ==============================  =================================

The renderers average these over the pixel's samples and write no spread, so their feature
buffers have the radiance's counts and an unknown variance; Mitsuba's ``moment`` integrator
writes ``m2_<name>.<aov>`` second moments beside them, which give the exact per-sample variance.
Normals stay in the renderer's space (OIDN accepts world or camera space; an edge is an edge in
either). docs/io.md, "Features", has what each renderer's passes hold.
"""

from __future__ import annotations

import os
from collections.abc import Collection

import numpy as np

from ..buffers import SampleBuffer
from ..features import FEATURE_CHANNELS
from .exr import file_error

__all__ = ["AUTO_FEATURE_PLANES", "MITSUBA_AOV_NAMES", "auto_feature_planes", "feature_from_planes", "plane_present",
           "normal_warning", "albedo_warning", "NORMAL_LENGTH_LIMIT"]

AUTO_FEATURE_PLANES: dict[str, dict[str, str]] = {
    "pbrt": {"albedo": "Albedo", "normal": "Ns", "depth": "P.Z"},
    "cycles": {"albedo": "{layer}.Denoising Albedo", "normal": "{layer}.Denoising Normal",
               "depth": "{layer}.Denoising Depth"},
}
"""Plane names each preset knows for each feature (``{layer}``: the Cycles view layer)."""

MITSUBA_AOV_NAMES: dict[str, tuple[str, ...]] = {
    "albedo": ("albedo",),
    "normal": ("normal", "sh_normal", "nn"),
    "depth": ("depth",),
}
"""AOV names taken as features in a Mitsuba file (the ``aov`` integrator's ``name:type`` names)."""


_COMPONENTS = {"albedo": ({"R", "G", "B"},), "normal": ({"X", "Y", "Z"},), "depth": ({"Z"}, {"T"}, {"Y"})}


def plane_present(prefix: str, channels: Collection[str], name: str) -> bool:
    """Whether the plane ``prefix`` is a channel, or has every component the feature ``name`` needs.

    Examples
    --------
    >>> from awr_denoise.io.features import plane_present
    >>> plane_present("main.albedo", ["main.albedo.R", "main.albedo.G", "main.albedo.B"], "albedo")
    True
    >>> plane_present("main.albedo", ["main.albedo.R"], "albedo")       # one component is no albedo
    False
    """
    if prefix in channels:
        return True
    components = {c.rsplit(".", 1)[1] for c in channels if "." in c and c.rsplit(".", 1)[0] == prefix}
    return any(need <= components for need in _COMPONENTS[name])


def auto_feature_planes(preset: str, channels: Collection[str], *, layer: str | None = None,
                        colour: str | None = None) -> dict[str, tuple[str, str | None]]:
    """``{feature: (mean plane, second-moment plane or None)}`` found in a file of ``preset``.

    A plane counts only with all the feature's components (``Albedo.R`` alone is not an albedo).

    ``colour`` is the plane the radiance came from (a Mitsuba ``<name>`` or ``<name>.img``):
    its AOVs are looked for beside it.

    Examples
    --------
    >>> from awr_denoise.io.features import auto_feature_planes
    >>> auto_feature_planes("pbrt", ["R", "G", "B", "Albedo.R", "Albedo.G", "Albedo.B", "P.X", "P.Y", "P.Z"])
    {'albedo': ('Albedo', None), 'depth': ('P.Z', None)}
    >>> auto_feature_planes("mitsuba", ["main.X", "main.depth.T", "m2_main.depth.T"], colour="main")
    {'depth': ('main.depth', 'm2_main.depth')}
    """
    found: dict[str, tuple[str, str | None]] = {}
    if preset in AUTO_FEATURE_PLANES:
        for name, plane in AUTO_FEATURE_PLANES[preset].items():
            plane = plane.format(layer=layer)
            if plane_present(plane, channels, name):
                found[name] = (plane, None)
    elif preset == "mitsuba" and colour:
        base = colour[: -len(".img")] if colour.endswith(".img") else colour
        for name, aovs in MITSUBA_AOV_NAMES.items():
            for aov in aovs:
                plane = f"{base}.{aov}"
                if plane_present(plane, channels, name):
                    moment = f"m2_{plane}"
                    found[name] = (plane, moment if plane_present(moment, channels, name) else None)
                    break
    return found


def feature_from_planes(path: str | os.PathLike[str], name: str, label: str, mean: np.ndarray,
                        count: np.ndarray, second_moment: np.ndarray | None = None) -> SampleBuffer:
    """A feature buffer from a renderer's (H, W, c) mean, with the radiance's ``count``.

    Without ``second_moment`` the variance is unknown (the renderer wrote none); with it
    (Mitsuba's ``moment``), ``E[x^2]`` gives the per-sample variance. Alpha channels are left out
    by the caller; a wrong number of channels is named.
    """
    channels = FEATURE_CHANNELS[name]
    if mean.shape[-1] != len(channels):
        raise file_error(path, f"{mean.shape[-1]} channel(s), but {name} has {len(channels)} "
                               f"({', '.join(channels)})", label)
    try:
        if second_moment is None:
            return SampleBuffer.from_moments(count, mean, np.zeros_like(mean), channels=channels,
                                             variance_known=np.zeros(count.shape, bool))
        return SampleBuffer.from_moments(count, mean, second_moment, variance_kind="second_moment",
                                         channels=channels)
    except ValueError as exc:
        raise file_error(path, str(exc), label) from None


NORMAL_LENGTH_LIMIT = 1.05
"""Length above which a pixel's normal cannot be a mean of unit vectors (beyond a filter's overshoot)."""


def normal_warning(path: str | os.PathLike[str], label: str, mean: np.ndarray) -> str | None:
    """A warning when more than 5% of a normal plane's pixels are longer than :data:`NORMAL_LENGTH_LIMIT`.

    A normal pass holds each pixel's mean of unit vectors, of length at most 1 under a filter of
    non-negative weights; an albedo or a colour read as the normal (``--nrm FILE:Albedo``: 16-59% of
    the pixels in the three renderers' files), or normals encoded in [0, 1], are longer wherever
    they are bright, and so are normals under a pixel filter with negative lobes (Mitsuba's
    ``lanczos`` or ``catmullrom``) beside a texture's edges. A dark albedo is not told apart.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.io.features import normal_warning
    >>> normal_warning("a.exr", "N", np.dstack([np.zeros((4, 4)), np.zeros((4, 4)), np.ones((4, 4))])) is None
    True
    >>> normal_warning("a.exr", "Albedo", np.full((4, 4, 3), 0.8))
    'a.exr: Albedo as the normal: 100% of its pixels are longer than 1.05, where a normal is a mean of unit \
vectors (length at most 1): an albedo or a colour, normals encoded in [0, 1], or a pixel filter with negative lobes?'
    """
    lengths = np.sqrt(np.square(np.asarray(mean, np.float64)).sum(axis=-1))
    share = _flagged_share(lengths > NORMAL_LENGTH_LIMIT, np.isfinite(lengths))
    if share is None:
        return None
    return (f"{path}: {label} as the normal: {share:.0f}% of its pixels are longer than {NORMAL_LENGTH_LIMIT:g}, "
            "where a normal is a mean of unit vectors (length at most 1): an albedo or a colour, normals encoded "
            "in [0, 1], or a pixel filter with negative lobes?")


def albedo_warning(path: str | os.PathLike[str], label: str, mean: np.ndarray) -> str | None:
    """A warning when more than 5% of an albedo plane's pixels hold a component below -0.1.

    An albedo is a reflectance, never negative; a normal or a position read as the albedo
    (``--alb FILE:Ns``: 44-63% of the pixels in the three renderers' files) is negative wherever it
    points or lies away from an axis (OIDN would take it clipped to [0, 1], without a word). A pixel
    filter with negative lobes (Mitsuba's ``lanczos`` or ``catmullrom``) rings below 0 beside a
    texture's edges too, on fewer pixels and less far; past the limits it is named as well.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.io.features import albedo_warning
    >>> albedo_warning("a.exr", "Albedo", np.full((4, 4, 3), 0.5)) is None
    True
    >>> albedo_warning("a.exr", "Ns", np.dstack([np.zeros((4, 4)), np.zeros((4, 4)), -np.ones((4, 4))]))
    'a.exr: Ns as the albedo: 100% of its pixels hold a component below -0.1, where an albedo is a reflectance: \
a normal or a position, or a pixel filter with negative lobes?'
    """
    values = np.asarray(mean, np.float64)
    share = _flagged_share((values < -0.1).any(axis=-1), np.isfinite(values).all(axis=-1))
    if share is None:
        return None
    return (f"{path}: {label} as the albedo: {share:.0f}% of its pixels hold a component below -0.1, where an albedo "
            "is a reflectance: a normal or a position, or a pixel filter with negative lobes?")


def _flagged_share(flagged: np.ndarray, finite: np.ndarray) -> float | None:
    """The percentage of the finite pixels ``flagged``, or None at 5% or below (the feature checks' limit)."""
    total = int(finite.sum())
    share = 100.0 * int((flagged & finite).sum()) / max(total, 1)
    return share if share > 5.0 else None
