"""What the output of the Wiener stages is held to: the pixel clamp, non-negativity, the image mean.

Three per-image guarantees run after the last stage (:func:`~awr_denoise.reconstruct`):

1. :func:`pooled_clamp`: every pixel within ``z`` standard errors of its own mean, the standard
   error pooled with its 3x3 neighbours' (``max(s, median_3x3(s))``), so a pixel whose few
   samples agreed by chance is not pinned to its noisy mean while a precise pixel next to a
   light still is;
2. :func:`clip_negative`: no negative radiance in channels whose means are all non-negative;
3. :func:`match_mean`: every channel multiplied by one positive factor so that its image mean
   is the input's exactly. The clamp and the relative stages cut bright outliers unevenly
   (they lose up to 10% of a channel's energy on heavy-tailed scenes, docs/reconstruction.md); a
   denoiser that changes exposure is not usable. A large factor is applied only when the
   change is significant against the input mean's own noise (:data:`MEAN_SIGNIFICANCE`), so
   that a lone firefly removed by the stages does not brighten the whole image instead.
"""

from __future__ import annotations

import math

import numpy as np

from ._typing import FloatArray

__all__ = ["median3x3", "pooled_standard_error", "pooled_clamp", "clip_negative", "match_mean", "POOL", "MEAN_LIMIT",
           "MEAN_SIGNIFICANCE"]

POOL = 3
"""Side of the neighbourhood over which the clamp pools standard errors."""

MEAN_LIMIT = 0.05
"""Largest change of a channel's exposure :func:`match_mean` makes unless the change is significant (5%)."""

MEAN_SIGNIFICANCE = 2.0
"""Standard errors of the input's image mean beyond which :func:`match_mean` applies any factor.

On the scenes of docs/reconstruction.md the stages lose up to 10% of a channel's energy
(env_sun at 4 spp), always more than 2.5 standard errors of the input's mean; a lone firefly
of a million times the image's level loses 0.7 of one."""


# Paeth's 19 exchanges that leave the median of 9 values in the middle slot.
_MEDIAN9 = ((1, 2), (4, 5), (7, 8), (0, 1), (3, 4), (6, 7), (1, 2), (4, 5), (7, 8), (0, 3), (5, 8), (4, 7),
            (3, 6), (1, 4), (2, 5), (4, 7), (4, 2), (6, 4), (4, 2))


def median3x3(a: FloatArray) -> FloatArray:
    """Median of every pixel's 3x3 neighbourhood (edges repeated), per channel.

    ``scipy.ndimage.median_filter(a, size=(3, 3, ...), mode="nearest")``, which the tests compare
    it with, by a sorting network on shifted copies: about 3x faster on images.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.finishing import median3x3
    >>> median3x3(np.array([[0.0, 0.0, 0.0], [0.0, 9.0, 0.0], [0.0, 0.0, 0.0]]))[1, 1]   # a lone spike
    0.0
    """
    pad = ((1, 1), (1, 1)) + ((0, 0),) * (a.ndim - 2)
    p = np.pad(a, pad, mode="edge")
    h, w = a.shape[:2]
    v = [p[i:i + h, j:j + w].copy() for i in range(3) for j in range(3)]
    for i, j in _MEDIAN9:
        low = np.minimum(v[i], v[j])
        np.maximum(v[i], v[j], out=v[j])
        v[i] = low
    return v[4]


def pooled_standard_error(variance: FloatArray) -> FloatArray:
    """``max(s, median of s over the POOL x POOL neighbourhood)``, ``s = sqrt(variance)``, per channel."""
    s = np.sqrt(variance)
    return np.maximum(s, median3x3(s))


def pooled_clamp(image: FloatArray, mean: FloatArray, variance: FloatArray, z: float, *,
                 weights: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
    """Keep every pixel within ``z`` pooled standard errors of its mean.

    Parameters
    ----------
    image
        (H, W, C) estimate.
    mean, variance
        (H, W, C) pixel means and variances of the means; with ``weights``, (H, W) luminance.
    z
        Width of the interval in standard errors.
    weights
        Luminance weights: clamp luminance and scale every channel alike (hue is kept).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        The clamped image and a boolean (H, W, C) map of the pixels the clamp moved.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.finishing import pooled_clamp
    >>> mean, variance = np.full((4, 4, 1), 1.0), np.full((4, 4, 1), 0.01)
    >>> image = np.full((4, 4, 1), 1.1)
    >>> image[0, 0] = 2.0
    >>> out, moved = pooled_clamp(image, mean, variance, 2.5)
    >>> float(out[0, 0, 0]), float(out[1, 1, 0]), int(moved.sum())
    (1.25, 1.1, 1)
    """
    reach = z * pooled_standard_error(variance)
    if weights is None:
        out = np.clip(image, mean - reach, mean + reach)
        return out, out != image
    lum = image @ weights
    target = np.clip(lum, mean - reach, mean + reach)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(lum != 0, target / np.where(lum != 0, lum, 1.0), 1.0)
    moved = np.broadcast_to((ratio != 1.0)[..., None], image.shape)
    return image * ratio[..., None], moved


def clip_negative(image: FloatArray, mean: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Zero the negative pixels of every channel whose means are all >= 0.

    Returns the image and a boolean map of the pixels set to zero.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.finishing import clip_negative
    >>> image = np.array([[[-0.1, -0.1], [0.5, 0.5]]])
    >>> mean = np.array([[[0.0, -1.0], [1.0, 1.0]]])      # channel 1 has a negative mean: kept
    >>> clip_negative(image, mean)[0]
    array([[[ 0. , -0.1],
            [ 0.5,  0.5]]])
    """
    applies = (mean >= 0).all(axis=(0, 1))
    clipped = applies & (image < 0)
    return np.where(clipped, 0.0, image), clipped


def match_mean(image: FloatArray, mean: FloatArray, variance: FloatArray | None = None, *,
               limit: float = MEAN_LIMIT, significance: float = MEAN_SIGNIFICANCE) -> tuple[FloatArray, FloatArray]:
    """Scale every channel so that its image mean is ``mean``'s; returns the image and the factors.

    A channel whose input or output mean is not positive is left as it is (factor 1). A
    factor beyond ``[1 / (1 + limit), 1 + limit]`` is applied in full only when the change it
    makes is larger than ``significance`` standard errors of the input's image mean
    (``sqrt(sum(variance)) / N``, from ``variance``, the variances of the pixel means);
    otherwise it stops at the bound. The input's mean is then no better an estimate than the
    output's (a few samples carry much of the image's energy, as a firefly a million times the
    image's level does), and one outlier should not change the exposure of every pixel.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.finishing import match_mean
    >>> out, factors = match_mean(np.array([[[1.0], [2.0]]]), np.array([[[1.02], [2.04]]]))
    >>> out[..., 0], factors
    (array([[1.02, 2.04]]), array([1.02]))

    Twice as bright, but the input's mean is as uncertain as that: the factor stops at 1.05.
    Precise means: the whole factor.

    >>> image, mean = np.array([[[1.0], [2.0]]]), np.array([[[2.0], [4.0]]])
    >>> match_mean(image, mean, np.array([[[9.0], [9.0]]]))[1], match_mean(image, mean, 0.01 * mean)[1]
    (array([1.05]), array([2.]))
    """
    # Both divided by one power of two first: the plain sum of means near 1e308 overflows.
    top = max(float(np.abs(mean).max(initial=0.0)), float(np.abs(image).max(initial=0.0)))
    unit = math.ldexp(1.0, -max(-1000, min(1000, math.frexp(top)[1]))) if np.isfinite(top) and top > 0 else 1.0
    want, got = (mean * unit).mean(axis=(0, 1)), (image * unit).mean(axis=(0, 1))
    ok = (want > 0) & (got > 0) & np.isfinite(want) & np.isfinite(got)
    factors = np.where(ok, want / np.where(ok, got, 1.0), 1.0)
    bounded = np.clip(factors, 1.0 / (1.0 + limit), 1.0 + limit)
    if variance is None:
        significant = np.zeros(factors.shape, bool)
    else:
        pixels = mean.shape[0] * mean.shape[1]
        error = np.sqrt(np.sum(np.asarray(variance) * unit * unit, axis=(0, 1))) / pixels
        significant = np.abs(want - got) > significance * error
    factors = np.where(significant, factors, bounded)
    return image * factors, factors
