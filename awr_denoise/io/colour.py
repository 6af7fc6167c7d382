"""Colour-space conversion of per-pixel statistics (renderers that store CIE XYZ).

Mitsuba 3's ``moment`` integrator writes its first and second moments in CIE XYZ, and pbrt-v4's
GBufferFilm writes ``Variance`` of its sensor RGB, which is CIE XYZ for the default sensor, beside
means already converted to the output colour space. Both are brought to linear sRGB here: the
mean through the renderer's own XYZ-to-sRGB matrix ``M``, the per-sample variance through the
same linear map.

The variance of ``R = M[0] . (X, Y, Z)`` needs the covariances of X, Y and Z, which neither file
holds (only their variances). The conversion assumes the three are **fully correlated**, i.e.
every sample of a pixel has the same chromaticity, which makes the standard deviations combine
linearly::

    sd_rgb = | M @ sd_xyz |        var_rgb = sd_rgb ** 2

This is exact for samples of one colour (grey surfaces, one light) and errs where a pixel mixes
samples of different colours. Measured (docs/io.md): on Mitsuba 3's Cornell box it is within
2-8% of the exact RGB moments of the same samples; on the pbrt-v4 fixture scene, whose samples mix
a warm light and a blue sky, it underestimates the R variance about 2x at the median pixel (G and
B within 3%). Treating the channels as independent instead overestimates by 4-10x.
"""

from __future__ import annotations

import numpy as np

from .._typing import FloatArray

__all__ = ["MITSUBA_XYZ_TO_SRGB", "PBRT_XYZ_TO_SRGB", "COVARIANCE_MODELS", "xyz_statistics_to_rgb", "xyz_to_rgb"]

# Mitsuba 3's xyz_to_srgb (include/mitsuba/core/spectrum.h), checked against the R,G,B and
# nested X,Y,Z channels of one real moment render (least-squares fit agrees to 1e-5).
MITSUBA_XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                                [-0.969256, 1.875991, 0.041556],
                                [0.055648, -0.204043, 1.057311]])
"""CIE XYZ to linear sRGB as Mitsuba 3 applies it."""

# pbrt-v4 builds RGBColorSpace::sRGB from the sRGB primaries and the D65 white point; this is
# that matrix (the standard one, to the precision pbrt's float32 arithmetic carries).
PBRT_XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                             [-0.9692660, 1.8760108, 0.0415560],
                             [0.0556434, -0.2040259, 1.0572252]])
"""CIE XYZ to linear sRGB of pbrt-v4's default output colour space."""


def xyz_to_rgb(chromaticities: tuple[float, ...] | list[float] | FloatArray) -> FloatArray:
    """CIE XYZ to the linear RGB of an EXR ``chromaticities`` attribute: the (3, 3) matrix.

    The attribute holds the red, green and blue primaries and the white point as CIE xy
    (``rx, ry, gx, gy, bx, by, wx, wy``); RGB (1, 1, 1) is the white of luminance Y = 1, the
    derivation pbrt-v4's ``RGBColorSpace`` and OpenEXR's ``RGBtoXYZ`` make. pbrt-v4 writes the
    attribute for an output colour space other than sRGB, whose means are then in it (its
    ``Variance`` stays in sensor XYZ).

    Parameters
    ----------
    chromaticities
        Eight finite numbers.

    Raises
    ------
    ValueError
        Not eight finite numbers, a ``y`` of 0, or primaries that span no colour space (on a line).

    Examples
    --------
    The sRGB primaries and D65 give pbrt-v4's own matrix (paper section 5: the variances the
    thresholds of Eq. 10-11 use are carried through it):

    >>> import numpy as np
    >>> from awr_denoise.io.colour import PBRT_XYZ_TO_SRGB, xyz_to_rgb
    >>> srgb = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.31271, 0.32902)
    >>> bool(np.allclose(xyz_to_rgb(srgb), PBRT_XYZ_TO_SRGB, atol=1e-3))
    True
    """
    c = np.asarray(chromaticities, dtype=np.float64).ravel()
    if c.size != 8 or not np.isfinite(c).all():
        raise ValueError(f"chromaticities: expected 8 finite numbers (rx ry gx gy bx by wx wy), got {c.tolist()}")
    xy = c.reshape(4, 2)
    if (xy[:, 1] == 0).any():
        raise ValueError(f"chromaticities: a y of 0 has no colour ({c.tolist()})")
    # Rows r, g, b, w: each chromaticity's XYZ at Y = 1.
    xyz = np.stack([xy[:, 0] / xy[:, 1], np.ones(4), (1.0 - xy[:, 0] - xy[:, 1]) / xy[:, 1]], axis=1)
    primaries = xyz[:3].T  # columns: the primaries' XYZ at Y = 1
    if abs(np.linalg.det(primaries)) < 1e-9 * np.abs(primaries).max() ** 3:
        raise ValueError(f"chromaticities: the primaries lie on a line and span no colour space ({c.tolist()})")
    scale = np.linalg.solve(primaries, xyz[3])  # each primary's share of the white
    rgb_to_xyz = primaries * scale
    if abs(np.linalg.det(rgb_to_xyz)) < 1e-12 or not np.isfinite(rgb_to_xyz).all():
        raise ValueError(f"chromaticities: the white point is on the primaries' edge ({c.tolist()})")
    return np.linalg.inv(rgb_to_xyz)


COVARIANCE_MODELS = ("correlated", "independent")
"""How unknown channel covariances are filled: fully correlated (default) or zero."""


def xyz_statistics_to_rgb(mean: FloatArray | None, variance: FloatArray, matrix: FloatArray, *,
                          covariance: str = "correlated") -> tuple[FloatArray | None, FloatArray]:
    """Carry per-pixel means and per-sample variances through a 3x3 colour matrix.

    Parameters
    ----------
    mean
        (H, W, 3) means in the source space, or None to convert only the variance (pbrt-v4
        stores RGB means beside XYZ variances).
    variance
        (H, W, 3) per-sample variances of the source channels.
    matrix
        (3, 3) source-to-target matrix, e.g. :data:`MITSUBA_XYZ_TO_SRGB`.
    covariance
        ``"correlated"``: channels fully correlated, ``sd' = |M sd|`` (exact for samples of one
        chromaticity); ``"independent"``: ``var' = M**2 var`` (zero covariances).

    Returns
    -------
    tuple
        (converted mean or None, converted variance), float64.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.io.colour import MITSUBA_XYZ_TO_SRGB, xyz_statistics_to_rgb
    >>> white = np.linalg.solve(MITSUBA_XYZ_TO_SRGB, np.ones(3))   # XYZ of sRGB (1, 1, 1)
    >>> mean, var = xyz_statistics_to_rgb(white[None, None], (0.5 * white[None, None]) ** 2,
    ...                                   MITSUBA_XYZ_TO_SRGB)
    >>> np.round(mean.ravel(), 6).tolist(), np.round(var.ravel(), 6).tolist()
    ([1.0, 1.0, 1.0], [0.25, 0.25, 0.25])
    """
    if covariance not in COVARIANCE_MODELS:
        raise ValueError(f"covariance: {covariance!r} is not one of {', '.join(COVARIANCE_MODELS)}")
    m = np.asarray(matrix, dtype=np.float64)
    var = np.asarray(variance, dtype=np.float64)
    if m.shape != (3, 3) or var.shape[-1] != 3:
        raise ValueError(f"matrix/variance: expected a (3, 3) matrix and 3 channels, got {m.shape}, {var.shape}")
    if covariance == "correlated":
        out_var = (np.sqrt(np.maximum(var, 0.0)) @ m.T) ** 2
    else:
        out_var = np.maximum(var, 0.0) @ (m.T ** 2)
    out_mean = None if mean is None else np.asarray(mean, dtype=np.float64) @ m.T
    return out_mean, out_var
