"""Regions lit through rare paths, where the samplers spread their samples evenly (an extension of paper section 4).

Where most of a region's samples are exactly 0 and its light comes from the few that are not (a room lit by
the bounce off a small patch, fog around a spot light, the dark contact shadow under an object), a pixel's first
samples do not show its variance: ranked by them, the pixels whose early samples found a bright path take more
samples and are diluted back towards their mean, while those whose samples missed keep their low means. AWR
sampling's image mean came out 4-22% low on such scenes at 8-32 spp (docs/sampling.md, "Rare paths"). No
spatial pooling of the ranking took it off without costing the other scenes (the same section). In such a region
any unevenness of the samples is noise chased, not structure found, so the samplers give its pixels one density,
the mean of theirs (:func:`even_rare_paths`): their counts then depend on no pixel's own samples and the image
mean is kept. The rest of the image is ranked as before.

A pixel lies in such a region (:func:`rare_path_mask`) when, over the window of ``WINDOW`` x ``WINDOW`` blocks of
``BLOCK`` x ``BLOCK`` pixels around its block (20 pixels, aligned to the blocks),

- the per-sample variance pooled within pixels, over the squared mean pooled over their samples (zeros
  included), exceeds :data:`RARE_CV2` (for samples that are 0 or a value ``v``, ``(1 - p) / p`` with ``p`` the
  chance of ``v``: a chance below 1 in 17); steady pixels (:data:`STEADY`) are left out of both, so that a
  bright steady feature, a beam through the fog, does not hide the region around it; and
- the pixels' mean of ``min(CV2_i / min(n_i, OWN_COUNT), 1)`` exceeds :data:`RARE_SHARE`: a pixel's own squared
  coefficient of variation reaches its count ``n_i`` when one sample holds all of its mean, so most pixels hold
  about one hit (a pixel whose samples are all 0 counts 1). A small light seen directly fails this test: its
  pixels hit often.

Both are taken over the pixels that are lit or beside a lit one; a pixel of zeros inside an all-zero square of
:data:`BACKDROP` pixels (a black backdrop beside an object's silhouette) is left out, so that a backdrop's edge
is not read as a region of rare hits. A window holding a negative mean is never a region (signed data has no
rare paths; its means near 0 are not rare hits'). Samples with heavy tails and no exact zeros (most far below the
mean, a few far above) meet the same tests, and their regions are evened too.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from . import _checks
from ._typing import BoolArray, FloatArray
from ._window_sums import window_sum
from .buffers import SampleBuffer
from .channels import luminance_weights

__all__ = ["rare_path_mask", "even_rare_paths", "RARE_PATHS", "DEFAULT_RARE_PATHS", "RARE_CV2", "RARE_SHARE", "BLOCK",
           "WINDOW", "BACKDROP", "OWN_COUNT", "STEADY"]

RARE_PATHS = ("even", "ranked")
"""The samplers' ``rare_paths``: ``"even"`` (the default) spreads a rare-path region's samples evenly, ``"ranked"``
ranks its pixels like the rest (the previous behaviour: lower error there, and an image mean several % low)."""
DEFAULT_RARE_PATHS = "even"
"""The samplers' default ``rare_paths`` (docs/sampling.md, "Rare paths")."""
RARE_CV2 = 16.0
"""Least pooled per-sample squared coefficient of variation of a rare-path region (a hit chance below 1/17)."""
RARE_SHARE = 0.5
"""Least mean of ``min(CV2_i / n_i, 1)`` over a rare-path region's pixels: most of them hold about one hit."""
BLOCK = 4
"""Side of the blocks the window statistics are summed over (pixels)."""
WINDOW = 5
"""Side of the window of blocks around a pixel's block (20 pixels)."""
BACKDROP = 15
"""Side of the all-zero squares whose pixels of zeros are a backdrop, not a rare-path region's misses (hits 1 in 40
at 2 spp leave such a square in about one 10^5)."""
OWN_COUNT = 8
"""Most samples a pixel's squared coefficient of variation is divided by (:data:`RARE_SHARE`): past 8 samples a
pixel of rare hits keeps counting as one (its ``CV2_i`` near ``1 / p``), so a region stays found as samples grow."""
STEADY = 0.1
"""Pixels whose ``min(CV2_i / min(n_i, OWN_COUNT), 1)`` is below this are steady and left out of the pooled
variation (their level would dilute it: a beam through fog)."""


def rare_path_mask(buffer: SampleBuffer) -> BoolArray:
    """(H, W) pixels of regions lit through rare paths (see the module's description).

    Examples
    --------
    Samples that are 40 one time in 40 and 0 otherwise, beside a region of steady noise (4 spp):

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.rare_paths import rare_path_mask
    >>> rng = np.random.default_rng(0)
    >>> hits = rng.binomial(4, 1 / 40, size=(64, 64)).astype(float)
    >>> mean = hits * 40 / 4
    >>> variance = (hits * (40 - mean) ** 2 + (4 - hits) * mean**2) / 3
    >>> mean[:, 32:], variance[:, 32:] = 1.0, 0.25
    >>> mask = rare_path_mask(SampleBuffer.from_moments(np.full((64, 64), 4), mean[..., None], variance[..., None]))
    >>> float(mask[:, :24].mean()), float(mask[:, 40:].mean())
    (1.0, 0.0)
    """
    count = np.asarray(buffer.count, dtype=np.float64)
    weights = luminance_weights(buffer.channels)
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        mean = np.asarray(buffer.mean) @ weights
        # Fully correlated channels, as the samplers' luminance variance (channels.luminance_variance); an unknown
        # variance is stored as 0 (SampleBuffer) and counts no degrees of freedom below.
        deviation = np.sqrt(np.asarray(buffer.variance)) @ weights
    # In units of a power of two near the largest level, exactly (the tests are ratios): no square under- or
    # overflows for levels anywhere in float64's range.
    top = max(float(np.max(np.abs(mean), initial=0.0)), float(np.max(deviation, initial=0.0)))
    if not (np.isfinite(top) and top > 0):
        return np.zeros(count.shape, dtype=bool)
    unit = float(np.ldexp(1.0, int(np.frexp(top)[1]) - 1))  # at most top: finite
    mean, deviation = mean / unit, deviation / unit
    sample_var = np.square(deviation)
    lit = mean > 0
    # Pixels of zeros in an all-zero BACKDROP square: a pixel whose square holds no lit pixel, grown back to it.
    backdrop = ndimage.maximum_filter(~ndimage.maximum_filter(lit, size=BACKDROP, mode="nearest"), size=BACKDROP,
                                      mode="nearest")
    near = ndimage.maximum_filter(lit, size=3, mode="nearest")
    region = (lit | (near & ~backdrop)) & (count >= 2)
    if not region.any():
        return np.zeros(count.shape, dtype=bool)
    # A pixel's squared coefficient of variation over its count (capped at OWN_COUNT): 1 where one sample holds its
    # mean; a pixel of zeros counts 1. (mean is at most 2 here and lit means are above 0: the quotient is finite or
    # +inf, which the cap takes to 1.)
    own = np.ones(count.shape)
    with np.errstate(over="ignore", divide="ignore", under="ignore"):
        np.divide(sample_var, mean * mean * np.minimum(count, OWN_COUNT), out=own, where=lit)
    np.minimum(own, 1.0, out=own)
    # Steady pixels (a beam, a lit wall beside the fog) are left out of the pooled variation, which their level
    # would otherwise dilute: the region around them is judged by its own samples.
    varied = region & (own >= STEADY)
    dof = np.where(varied & np.asarray(buffer.variance_known), count - 1.0, 0.0)
    n = np.where(varied, count, 0.0)
    own[~region] = 0.0
    sums = [_blocks(x) for x in (n, n * mean, dof, dof * sample_var, region, own)]
    n_sum, nm_sum, dof_sum, var_sum, pixels, own_sum = (_window(s) for s in sums)
    negative = mean < 0  # any pixel's, in the region or not
    negative = _window(_blocks(negative)) if negative.any() else np.zeros_like(pixels)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        pooled_mean = nm_sum / n_sum
        cv2 = (var_sum / dof_sum) / (pooled_mean * pooled_mean)
        share = own_sum / pixels
        # Signed data (no radiance) has no rare paths to find: a mean near 0 is not a rare hit's.
        rare = (cv2 > RARE_CV2) & (share > RARE_SHARE) & np.isfinite(cv2) & (pooled_mean > 0) & (negative == 0)
    h, w = count.shape
    # Every pixel of a block so found: a pixel of zeros in it is a miss of the region's rare paths like the others.
    return np.repeat(np.repeat(rare, BLOCK, axis=0), BLOCK, axis=1)[:h, :w]


def even_rare_paths(density: FloatArray, buffer: SampleBuffer, rare_paths: str = DEFAULT_RARE_PATHS) -> FloatArray:
    """``density`` (float64) with each connected region of :func:`rare_path_mask` given the mean of its pixels'.

    ``rare_paths="ranked"`` returns it as it is. A region's summed density stays what it was, so the allocation
    still gives it its statistics' share of the samples; only their spread over its pixels is made even (the
    water-filling cannot take samples back from a pixel that has more than the region's level already). A pixel
    whose density is not finite keeps it and is left out of its region's mean.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.rare_paths import even_rare_paths, rare_path_mask
    >>> rng = np.random.default_rng(0)
    >>> hits = rng.binomial(4, 1 / 40, size=(64, 64)).astype(float)
    >>> mean = hits * 10.0
    >>> variance = (hits * (40 - mean) ** 2 + (4 - hits) * mean**2) / 3
    >>> buffer = SampleBuffer.from_moments(np.full((64, 64), 4), mean[..., None], variance[..., None])
    >>> density = rng.uniform(0, 2, size=(64, 64))
    >>> evened, mask = even_rare_paths(density, buffer), rare_path_mask(buffer)
    >>> round(float(mask.mean()), 2), np.unique(evened[mask]).size, bool(np.isclose(evened.sum(), density.sum()))
    (1.0, 1, True)
    """
    rare_paths = _checks.name("rare_paths", rare_paths, RARE_PATHS)
    density = np.asarray(density, dtype=np.float64)
    if density.shape != buffer.shape:
        raise ValueError(f"density: shape {density.shape} is not the buffer's {buffer.shape}")
    if rare_paths == "ranked":
        return density
    mask = rare_path_mask(buffer)
    if not mask.any():
        return density
    finite = mask & np.isfinite(density)
    labels, regions = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    index = np.arange(1, regions + 1)
    # Summed in units of the largest density (a power of two, exact): sums of densities near 1e308 stay finite.
    unit = float(np.ldexp(1.0, int(np.frexp(np.max(np.abs(density[finite]), initial=1.0))[1]) - 1))
    sums = ndimage.sum(np.where(finite, density / unit, 0.0), labels, index)
    counts = ndimage.sum(finite, labels, index)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.asarray(sums, dtype=np.float64) / np.asarray(counts, dtype=np.float64) * unit
    out = density.copy()
    out[finite] = means[labels[finite] - 1]
    return out


def _blocks(a: FloatArray | BoolArray) -> FloatArray:
    """Sums over the BLOCK x BLOCK blocks of ``a`` (its last blocks padded with zeros), in float64."""
    a = np.asarray(a, dtype=np.float64)
    h, w = a.shape
    if h % BLOCK or w % BLOCK:
        padded = np.zeros((-(-h // BLOCK) * BLOCK, -(-w // BLOCK) * BLOCK))
        padded[:h, :w] = a
        a, h, w = padded, *padded.shape
    # Rows of blocks first, then their columns: two reductions over contiguous runs.
    rows = a.reshape(h // BLOCK, BLOCK, w).sum(axis=1)
    return rows.reshape(h // BLOCK, w // BLOCK, BLOCK).sum(axis=2)


def _window(blocks: FloatArray) -> FloatArray:
    """Sums over the WINDOW x WINDOW blocks around each block (edges repeated; each window's own entries, so that a
    firefly's rounding error does not run along the line as in a running sum)."""
    return window_sum(blocks, WINDOW)
