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

__all__ = ["MITSUBA_XYZ_TO_SRGB", "PBRT_XYZ_TO_SRGB", "COVARIANCE_MODELS", "xyz_statistics_to_rgb"]

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
