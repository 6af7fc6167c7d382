"""A light's rim: pixels whose samples are a coverage of two exact regions, not noise those regions share.

A light seen directly against an exact background (a lamp before an empty backdrop, an emitter before a constant
sky) has an exact inside (every sample its emission), an exact background, and between them a rim whose samples hit
or miss it. The background beside the rim agreed at 0, and a rim pixel is 0 whenever its samples miss: moderated
towards its neighbours (:func:`awr_denoise.pooling.agreed_variance`), the background would borrow the rim's spread
and the Wiener stages would spread the light into it, a halo. The rim is told from its statistics alone: values in
``[lo, hi]`` with mean ``m`` have a variance of at most ``(m - lo)(hi - m)`` (the Bhatia-Davis inequality), reached
only when every value is ``lo`` or ``hi`` (docs/reconstruction.md, "Samples that all agreed", "A light's rim").
"""

from __future__ import annotations

import numpy as np

from ._typing import BoolArray, CountArray, FloatArray

__all__ = ["coverage_edges", "EDGE_TOLERANCE", "EDGE_BLOCK"]

EDGE_TOLERANCE = 1e-5
"""Tolerance within which a pixel's samples count as all at two levels ``lo < hi``, in units of the gap
``hi - lo``: its population variance against the Bhatia-Davis bound ``(m - lo)(hi - m)``, both over the squared gap,
and its share of samples at ``hi``, ``n (m - lo) / (hi - lo)``, against a whole number (over ``n``), float32 files
included."""

EDGE_BLOCK = 2
"""Side of the square of agreeing pixels at one level that makes that level an exact region's: a light's inside, a
backdrop. Pixels that agreed by chance (two samples that both hit a light reached half the time) seldom fill one,
and a level held by no such square makes no rim."""


def coverage_edges(count: CountArray, mean: FloatArray, variance: FloatArray, agreed: BoolArray, spread: BoolArray,
                   *, window: int, jump_ratio: float) -> BoolArray | None:
    """(H, W, C) True at the spread entries that are a light's rim between two exact regions; None where none is.

    An exact region's level is one that fills an :data:`EDGE_BLOCK` square of agreeing entries (``agreed``: two or
    more samples, variance 0). An entry is a rim where its samples all lie at two such levels ``lo < hi``: the least
    and greatest of them in its ``window`` square (cut at the image's edges), further apart than ``jump_ratio``
    (texels of a texture side by side are not a rim). Its samples are all at ``lo`` or ``hi`` where ``(n - 1) / n`` of
    its unbiased variance reaches the Bhatia-Davis bound ``(m - lo)(hi - m)`` and ``n (m - lo) / (hi - lo)`` is a
    whole number of samples, each to :data:`EDGE_TOLERANCE` (in units of the gap).

    Parameters
    ----------
    count
        (H, W) samples per pixel.
    mean, variance
        (H, W, C) means and unbiased per-sample variances.
    agreed, spread
        (H, W, C) the entries whose samples all agreed, and those with a known variance above 0.
    window
        Side of the square searched for the two levels (odd).
    jump_ratio
        Two levels within this ratio of each other (same sign) make no rim.

    Examples
    --------
    A light of 100 two pixels wide on black; the columns beside it are hit by a share of their 4 samples:

    >>> import numpy as np
    >>> from awr_denoise.rims import coverage_edges
    >>> count = np.full((3, 8), 4)
    >>> mean = np.array([[0.0, 0.0, 25.0, 100.0, 100.0, 75.0, 0.0, 0.0]] * 3)[..., None]
    >>> variance = np.zeros_like(mean)
    >>> variance[:, 2], variance[:, 5] = 2500.0, 2500.0      # samples 0, 0, 0, 100 and 0, 100, 100, 100
    >>> agreed, spread = variance == 0, variance > 0
    >>> coverage_edges(count, mean, variance, agreed, spread, window=5, jump_ratio=4.0)[0, :, 0]
    array([False, False,  True, False, False,  True, False, False])
    >>> variance[:, 2] = 2000.0                              # spread inside the range: noise, not a coverage
    >>> coverage_edges(count, mean, variance, agreed, spread, window=5, jump_ratio=4.0)[0, :, 0]
    array([False, False, False, False, False,  True, False, False])
    """
    h, w, channels = mean.shape
    r = window // 2
    edges = None
    if EDGE_BLOCK > min(h, w):
        return None
    for c in range(channels):
        at = agreed[..., c]
        if np.count_nonzero(at) < 2 * EDGE_BLOCK**2:
            continue
        level = mean[..., c]
        other = np.logical_and(level != level.flat[np.argmax(at)], at)
        # A second region's square holds agreeing pixels at another level than the first one found (a light's inside
        # beside a black backdrop): none, no rim between two; the box around them bounds the work, not the image.
        square = other[:h - EDGE_BLOCK + 1, :w - EDGE_BLOCK + 1].copy()
        for i in range(EDGE_BLOCK):
            for j in range(EDGE_BLOCK):
                square &= other[i:h - EDGE_BLOCK + 1 + i, j:w - EDGE_BLOCK + 1 + j]
        if not square.any():
            continue
        lines, columns = np.flatnonzero(square.any(axis=1)), np.flatnonzero(square.any(axis=0))
        top, bottom = max(lines[0] - r, 0), min(lines[-1] + EDGE_BLOCK - 1 + r + 1, h)
        left, right = max(columns[0] - r, 0), min(columns[-1] + EDGE_BLOCK - 1 + r + 1, w)
        regions = _region_levels(level, at, top, bottom, left, right, r)
        lo = _window_extreme(regions, np.fmin, window, bottom - top, right - left)
        hi = _window_extreme(regions, np.fmax, window, bottom - top, right - left)
        box = level[top:bottom, left:right]
        with np.errstate(invalid="ignore"):  # NaN where the window holds no region: never a candidate
            candidate = np.less(lo, box) & np.less(box, hi) & spread[top:bottom, left:right, c]
        rows, cols = np.nonzero(candidate)
        if not rows.size:
            continue
        lo, hi, m = lo[rows, cols], hi[rows, cols], box[rows, cols]
        rows, cols = rows + top, cols + left
        n = count[rows, cols].astype(np.float64)
        with np.errstate(over="ignore", invalid="ignore"):  # a gap past float64 is no rim
            gap = hi - lo
            below, above = (m - lo) / gap, (hi - m) / gap
            population = variance[rows, cols, c] / gap / gap * ((n - 1.0) / n)
            hits = n * below
            # Two levels close to each other (a texture's neighbouring texels) leave the spread to share, as an
            # unknown variance may be borrowed within the jump ratio of a pixel's level.
            close = ((lo > 0) & (hi <= jump_ratio * lo)) | ((hi < 0) & (-lo <= -jump_ratio * hi))
            rim = (np.abs(population - below * above) <= EDGE_TOLERANCE) & ~close & np.isfinite(gap) \
                & (np.abs(hits - np.round(hits)) <= EDGE_TOLERANCE * n) & (hits > 0.5) & (hits < n - 0.5)
        if rim.any():
            if edges is None:
                edges = np.zeros(mean.shape, dtype=bool)
            edges[rows[rim], cols[rim], c] = True
    return edges


def _region_levels(level: FloatArray, at: BoolArray, top: int, bottom: int, left: int, right: int,
                   r: int) -> FloatArray:
    """The levels of the box ``[top, bottom) x [left, right)`` with a margin of ``r`` that fill an :data:`EDGE_BLOCK`
    square of agreeing pixels (an exact region's), NaN elsewhere and past the image."""
    h, w = level.shape
    k = EDGE_BLOCK
    # Agreeing levels over the box, a margin of r and the block's reach beyond it (NaN past the image).
    reach = r + k - 1
    padded = np.full((bottom - top + 2 * reach, right - left + 2 * reach), np.nan)
    inner = (slice(max(top - reach, 0), min(bottom + reach, h)), slice(max(left - reach, 0), min(right + reach, w)))
    np.copyto(padded[inner[0].start - top + reach:inner[0].stop - top + reach,
                     inner[1].start - left + reach:inner[1].stop - left + reach], level[inner], where=at[inner])
    ph, pw = padded.shape
    # A k x k square is uniform where its least and greatest levels are equal (NaN, a pixel that did not agree,
    # compares unequal): np.minimum and np.maximum carry NaN.
    low, high = padded[:ph - k + 1, :pw - k + 1].copy(), padded[:ph - k + 1, :pw - k + 1].copy()
    for i in range(k):
        for j in range(k):
            np.minimum(low, padded[i:ph - k + 1 + i, j:pw - k + 1 + j], out=low)
            np.maximum(high, padded[i:ph - k + 1 + i, j:pw - k + 1 + j], out=high)
    uniform = low == high
    block = np.zeros(padded.shape, dtype=bool)
    for i in range(k):
        for j in range(k):
            block[i:ph - k + 1 + i, j:pw - k + 1 + j] |= uniform
    # The box with a margin of r: what its windows read.
    cut = k - 1
    out = np.where(block, padded, np.nan)
    return out[cut:ph - cut, cut:pw - cut]


def _window_extreme(padded: FloatArray, extreme: np.ufunc, window: int, h: int, w: int) -> FloatArray:
    """``extreme`` (``np.fmin`` or ``np.fmax``: NaN where the window holds no value) over the ``window`` square of
    each pixel of ``padded`` (padded by the window's half with NaN), rows then columns."""
    down = padded[:h].copy()
    for i in range(1, window):
        extreme(down, padded[i:i + h], out=down)
    across = down[:, :w].copy()
    for j in range(1, window):
        extreme(across, down[:, j:j + w], out=across)
    return across
