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

__all__ = ["coverage_edges", "EDGE_TOLERANCE", "EDGE_REGION"]

EDGE_TOLERANCE = 1e-5
"""Relative tolerance (of the squared gap between the two levels) within which a pixel's samples count as all at
two levels: the Bhatia-Davis bound ``(m - lo)(hi - m)`` on the variance of values in ``[lo, hi]``, reached only by
values all at ``lo`` or ``hi``, against ``(n - 1) / n`` of the unbiased sample variance (float32 files included)."""

EDGE_REGION = 2
"""Agreeing pixels at each of the two levels a rim's window must hold: regions, not a pixel whose few samples all
hit (which must still borrow its neighbours' spread)."""


def coverage_edges(count: CountArray, mean: FloatArray, variance: FloatArray, agreed: BoolArray, spread: BoolArray,
                   *, window: int, jump_ratio: float) -> BoolArray | None:
    """(H, W, C) True at the spread entries that are a light's rim between two exact regions; None where none is.

    An entry is a rim where its samples all lie at two levels ``lo < hi``: the least and greatest levels of the
    agreeing entries (``agreed``: two or more samples, variance 0) in its ``window`` square (cut at the image's
    edges), each held by at least :data:`EDGE_REGION` of them, and further apart than ``jump_ratio`` (texels of a
    texture side by side are not a rim). Its samples are all at ``lo`` or ``hi`` where ``(n - 1) / n`` of its
    unbiased variance reaches the Bhatia-Davis bound ``(m - lo)(hi - m)``, to :data:`EDGE_TOLERANCE` of
    ``(hi - lo)^2``.

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
    >>> count = np.full((3, 7), 4)
    >>> mean = np.array([[0.0, 0.0, 25.0, 100.0, 100.0, 75.0, 0.0]] * 3)[..., None]
    >>> variance = np.zeros_like(mean)
    >>> variance[:, 2], variance[:, 5] = 2500.0, 2500.0      # samples 0, 0, 0, 100 and 0, 100, 100, 100
    >>> agreed, spread = variance == 0, variance > 0
    >>> coverage_edges(count, mean, variance, agreed, spread, window=5, jump_ratio=4.0)[0, :, 0]
    array([False, False,  True, False, False,  True, False])
    >>> variance[:, 2] = 2000.0                              # spread inside the range: noise, not a coverage
    >>> coverage_edges(count, mean, variance, agreed, spread, window=5, jump_ratio=4.0)[0, :, 0]
    array([False, False, False, False, False,  True, False])
    """
    h, w, channels = mean.shape
    r = window // 2
    edges = None
    for c in range(channels):
        at = agreed[..., c]
        if np.count_nonzero(at) < 2 * EDGE_REGION:
            continue
        level = mean[..., c]
        other = np.logical_and(level != level.flat[np.argmax(at)], at)
        if not other.any():
            continue  # one level (a black background): no rim between two
        # A rim lies within the window of an agreeing pixel at another level than the first one found: the box
        # around those (a light's inside) bounds the work, not the image.
        lines, columns = np.flatnonzero(other.any(axis=1)), np.flatnonzero(other.any(axis=0))
        top, bottom = max(lines[0] - r, 0), min(lines[-1] + r + 1, h)
        left, right = max(columns[0] - r, 0), min(columns[-1] + r + 1, w)
        # Agreeing levels of the box and a margin of the window's half, NaN elsewhere and past the image.
        padded = np.full((bottom - top + 2 * r, right - left + 2 * r), np.nan)
        inner = (slice(max(top - r, 0), min(bottom + r, h)), slice(max(left - r, 0), min(right + r, w)))
        np.copyto(padded[inner[0].start - top + r:inner[0].stop - top + r,
                         inner[1].start - left + r:inner[1].stop - left + r], level[inner], where=at[inner])
        lo = _window_extreme(padded, np.fmin, window, bottom - top, right - left)
        hi = _window_extreme(padded, np.fmax, window, bottom - top, right - left)
        box = level[top:bottom, left:right]
        with np.errstate(invalid="ignore"):  # NaN where the window holds no agreeing pixel: never a candidate
            candidate = np.less(lo, box) & np.less(box, hi) & spread[top:bottom, left:right, c]
        rows, cols = np.nonzero(candidate)
        if not rows.size:
            continue
        lo, hi, m = lo[rows, cols], hi[rows, cols], box[rows, cols]
        rows, cols = rows + top, cols + left
        n = count[rows, cols].astype(np.float64)
        gap = hi - lo
        population = variance[rows, cols, c] * ((n - 1.0) / n)
        # Two levels close to each other (a texture's neighbouring texels) leave the spread to share, as an unknown
        # variance may be borrowed within the jump ratio of a pixel's level.
        close = ((lo > 0) & (hi <= jump_ratio * lo)) | ((hi < 0) & (-lo <= -jump_ratio * hi))
        keep = (np.abs(population - (m - lo) * (hi - m)) <= EDGE_TOLERANCE * gap * gap) & ~close
        rows, cols, lo, hi = rows[keep], cols[keep], lo[keep], hi[keep]
        at_lo, at_hi = np.zeros(rows.size, np.int64), np.zeros(rows.size, np.int64)
        for i in range(window):
            for j in range(window):
                neighbour = padded[rows - top + i, cols - left + j]
                at_lo += neighbour == lo
                at_hi += neighbour == hi
        rim = (at_lo >= EDGE_REGION) & (at_hi >= EDGE_REGION)
        if rim.any():
            if edges is None:
                edges = np.zeros(mean.shape, dtype=bool)
            edges[rows[rim], cols[rim], c] = True
    return edges


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
