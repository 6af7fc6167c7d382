"""Unknown per-sample variances, borrowed from neighbours (paper section 3: never taken as zero).

A pixel's variance is unknown when it has fewer than two samples, or when the renderer said so
(pbrt-v4 writes 0 for pixels that only saw the environment). Taking such a variance as zero
would call the pixel exact and freeze it; instead it is pooled from the known pixels around it.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from ._typing import BoolArray, CountArray, FloatArray

__all__ = ["pooled_variance", "POOL_WINDOW", "JUMP_RATIO"]

POOL_WINDOW = 5
"""Window (pixels) over which an unknown per-sample variance is pooled from neighbours."""

JUMP_RATIO = 4.0
"""A pixel with a mean of its own borrows only from neighbours whose ``|mean|`` is at most this
many times its own: a renderer's "unknown" next to a light must not import the light's variance."""


def pooled_variance(count: CountArray, mean: FloatArray, variance: FloatArray, known: BoolArray) -> FloatArray:
    """(H, W, C) per-sample variance with the unknown entries pooled from known neighbours.

    Where ``known`` is False the variance is pooled from the known pixels in a
    :data:`POOL_WINDOW` square, ``sum(M2) / sum(n - 1)``, and from the whole image where the
    window has none. A pixel with two or more samples whose variance the renderer left unknown
    has a mean of its own: it pools only the neighbours whose ``|mean|`` is at most
    :data:`JUMP_RATIO` times its own (per channel), and with none takes the image's pooled
    relative variance ``sum(M2) / sum((n - 1) mean^2)`` times its own ``mean^2``. With no
    variance known anywhere the result is 0 (nothing is known to be noisy).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.pooling import pooled_variance
    >>> count = np.array([[4, 1, 4]])                              # the middle pixel: one sample
    >>> mean = np.ones((1, 3, 1)); variance = np.array([[[0.2], [0.0], [0.4]]])
    >>> pooled_variance(count, mean, variance, count >= 2)[0, :, 0].round(3)
    array([0.2, 0.3, 0.4])
    """
    if known.all():
        return np.array(variance)
    dof = np.where(known, count - 1, 0).astype(np.float64)
    m2 = variance * dof[..., None]
    if dof.sum() == 0:
        return np.zeros_like(variance)
    local_dof = ndimage.uniform_filter(dof, POOL_WINDOW, mode="nearest")
    pooled_global = m2.sum(axis=(0, 1)) / dof.sum()
    out = np.array(variance)
    missing = ~known
    for c in range(variance.shape[2]):
        local_m2 = ndimage.uniform_filter(m2[..., c], POOL_WINDOW, mode="nearest")
        with np.errstate(invalid="ignore", divide="ignore"):
            local = np.where(local_dof > 1e-12, local_m2 / local_dof, pooled_global[c])
        out[..., c][missing] = np.maximum(local[missing], 0.0)
    # Renderer-unknown pixels with samples enough for a mean of their own: pool only the
    # neighbours whose mean is at most JUMP_RATIO times theirs (no light's variance in a sky).
    own = missing & (count >= 2)
    if own.any():
        out[own] = _pool_below_jump(mean, m2, dof)[own]
    return out


def _pool_below_jump(mean: FloatArray, m2: FloatArray, dof: FloatArray) -> FloatArray:
    """Pooled variance from the 5x5 neighbours whose |mean| <= JUMP_RATIO x the pixel's;
    without such neighbours, the image's pooled relative variance times the pixel's mean^2."""
    h, w = mean.shape[:2]
    r = POOL_WINDOW // 2
    level = np.abs(mean)
    limit = JUMP_RATIO * level
    pad = ((r, r), (r, r), (0, 0))
    m2p = np.pad(m2, pad)
    dofp = np.pad(np.broadcast_to(dof[..., None], m2.shape), pad)
    levelp = np.pad(level, pad, constant_values=np.inf)
    sum_m2 = np.zeros_like(m2)
    sum_dof = np.zeros_like(m2)
    for dy in range(POOL_WINDOW):  # a loop over the 25 window offsets; pixels are vectorised
        for dx in range(POOL_WINDOW):
            ok = levelp[dy:dy + h, dx:dx + w] <= limit
            sum_m2 += np.where(ok, m2p[dy:dy + h, dx:dx + w], 0.0)
            sum_dof += np.where(ok, dofp[dy:dy + h, dx:dx + w], 0.0)
    weight = dof[..., None] * mean**2
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = m2.sum(axis=(0, 1)) / np.maximum(weight.sum(axis=(0, 1)), 1e-300)
        pooled = np.where(sum_dof > 1e-12, sum_m2 / sum_dof, rel * mean**2)
    return np.maximum(np.nan_to_num(pooled, nan=0.0, posinf=0.0), 0.0)
