"""What the output of the Wiener stages is held to: the pixel clamp, non-negativity, the image mean.

Three per-image guarantees run after the last stage (:func:`~awr_denoise.reconstruct`):

1. :func:`pooled_clamp`: every pixel within ``z`` standard errors of its own mean, the standard
   error pooled with its 3x3 neighbours' (``max(s, median_3x3(s))``), so a pixel whose few
   samples agreed by chance is not pinned to its noisy mean while a precise pixel next to a
   light still is; given the sample counts, only the neighbours the pixel's samples could have
   come from pool (:data:`POOL_CHANCE`), so a dark line one pixel wide keeps its own interval, and
   what pools is a neighbour's per-sample deviation over the pixel's own count, so a pixel of many
   samples beside pixels of few keeps an interval of its own count;
2. :func:`clip_negative`: no negative radiance in channels whose means are all non-negative;
3. :func:`restore_mean`: the energy the stages took (or added) is given back where it was
   taken, so that every channel's image mean is the input's exactly. The clamp and the relative
   stages cut bright outliers unevenly (they lose up to 10% of a channel's energy on
   heavy-tailed scenes, docs/reconstruction.md); a denoiser that changes exposure is not
   usable. A change larger than :data:`MEAN_LIMIT` is made only when it is significant against
   the input mean's own noise (:data:`MEAN_SIGNIFICANCE`), so that a lone firefly removed by the
   stages does not come back.

:func:`match_mean` (one factor per channel) was the previous correction: scaling every pixel
scales the noise of the pixels the stages left at their means too, which costs
``(f^2 - 1) Var`` each; next to a small light those few pixels carry most of an image's squared
error, and the factor alone made the output's MSE exceed the plain mean's
(docs/reconstruction.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ._typing import FloatArray

__all__ = ["median3x3", "pooled_standard_error", "pooled_clamp", "clip_negative", "match_mean", "restore_mean", "POOL",
           "POOL_CHANCE", "MEAN_LIMIT", "MEAN_SIGNIFICANCE", "RESTORE_OFFSET", "RESTORE_SHARE"]

POOL = 3
"""Side of the neighbourhood over which the clamp pools standard errors."""

POOL_CHANCE = 1e-3
"""Least chance that a pixel's samples came from a neighbour's distribution for that neighbour to pool.

With the sample counts, a 3x3 neighbour (mean ``m``, per-sample standard deviation ``S``) pools into a
pixel's clamp (``n`` samples, mean ``c``, per-sample deviation ``s``) only where ``z^n`` is at least this,
``z = S^2 / (S^2 + g^2)`` Cantelli's bound on the chance that one sample of the neighbour's lands ``g`` or
further from ``m``, and ``g = |m - c| - s (n - 1) / sqrt(n)`` the least distance any of the pixel's samples
can have from ``m`` (Samuelson's inequality). A pixel whose samples missed a heavy tail its neighbours
caught still pools (``z`` near 1); a dark line one pixel wide in a bright field does not (relMSE 195x the
plain mean's in a field of 100 at 8 spp before, ``benchmarks/bench_limits.py``). Cantelli's bound is
nearly attained by two-point distributions (a pixel covered in part by an edge), so the test also
separates a few real pixels from their neighbours (1-3% more relMSE on the defocused ``chess_dof``):
the trade, and smaller chances, in docs/reconstruction.md, "The clamp's neighbours" (``bench_reconstruct.py
quality --compare`` and ``--chances``, ``bench_limits.py --chances``). 0 pools every neighbour (the form
before)."""

MEAN_LIMIT = 0.05
"""Largest change of a channel's image mean made unless the change is significant (5%)."""

RESTORE_OFFSET = 0.01
"""``k`` of :func:`restore_mean`'s weights ``|o| + k``, as a fraction of the channel's image mean."""

RESTORE_SHARE = 0.2
"""Most a pixel takes back from its own gap in :func:`restore_mean`, as a share of ``|o| + k``.

Measured (docs/reconstruction.md, ``benchmarks/bench_reconstruct.py finishing``, 12 renders per
row): without this cap the noise of the removed fireflies comes back on the synthetic
``fireflies`` scene (relMSE 0.46x the plain mean's at 4 spp instead of 0.02x). Chosen when 0.05
left the worst render of the Mitsuba ``glossy_glass`` scene at 4 spp at 1.056x the plain mean's
MSE and 0.2 at 0.996x (a real renderer's MSE, the rule every default is held to); since samples
that all agreed are moderated (:mod:`awr_denoise.pooling`) both give 0.995x there, 0.2 a lower
average MSE on that scene by up to 0.5% of the plain mean's, and 0.05 lower relMSE (``fireflies`` at
64 spp: 0.14x the plain mean's against 0.20x)."""

MEAN_SIGNIFICANCE = 2.0
"""Standard errors of the input's image mean beyond which a correction of any size is made.

On the scenes of docs/reconstruction.md the stages lose up to 10% of a channel's energy
(env_sun at 4 spp), always more than 2.5 standard errors of the input's mean; a lone firefly
of a million times the image's level loses 0.7 of one."""


def _median3(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """Elementwise median of three arrays: ``max(min(a, b), min(max(a, b), c))``."""
    return np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), c))


def median3x3(a: FloatArray) -> FloatArray:
    """Median of every pixel's 3x3 neighbourhood (edges repeated), per channel.

    ``scipy.ndimage.median_filter(a, size=(3, 3, ...), mode="nearest")``, which the tests compare
    it with, by sorted columns: each vertical triple is sorted once (shared by the three windows
    that hold it), and the median of nine values is exactly the median of the largest column
    minimum, the median of the column medians and the smallest column maximum (Paeth, Graphics
    Gems, "Median finding on a 3x3 grid"). About 15 elementwise passes instead of the 19
    exchanges of a sorting network on nine copies; the result is the same, bit for bit.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.finishing import median3x3
    >>> float(median3x3(np.array([[0.0, 0.0, 0.0], [0.0, 9.0, 0.0], [0.0, 0.0, 0.0]]))[1, 1])   # a lone spike
    0.0
    """
    pad = ((1, 1), (1, 1)) + ((0, 0),) * (a.ndim - 2)
    p = np.pad(a, pad, mode="edge")
    h, w = a.shape[:2]
    top, middle, bottom = p[:h], p[1:h + 1], p[2:h + 2]
    low, high = np.minimum(top, middle), np.maximum(top, middle)
    column_min = np.minimum(low, bottom)
    np.maximum(low, bottom, out=low)                      # low is now the larger of (low, bottom)
    column_mid = np.minimum(high, low)
    column_max = np.maximum(high, low, out=high)
    left, centre, right = slice(0, w), slice(1, w + 1), slice(2, w + 2)
    largest_min = np.maximum(np.maximum(column_min[:, left], column_min[:, centre]), column_min[:, right])
    smallest_max = np.minimum(np.minimum(column_max[:, left], column_max[:, centre]), column_max[:, right])
    mid_of_mids = _median3(column_mid[:, left], column_mid[:, centre], column_mid[:, right])
    return _median3(largest_min, mid_of_mids, smallest_max)


def pooled_standard_error(variance: FloatArray, mean: FloatArray | None = None,
                          count: FloatArray | None = None) -> FloatArray:
    """``max(s, median of s over the POOL x POOL neighbourhood)``, ``s = sqrt(variance)``, per channel.

    With ``mean`` and the (H, W) sample ``count``, the median is taken over the neighbours the pixel's
    samples could have come from (:data:`POOL_CHANCE`; the pixel itself always counts), the upper one of
    an even number, of their per-sample deviations over the pixel's own count (``S_j / sqrt(n)``: the
    standard error its mean would have with that neighbour's spread).

    Examples
    --------
    A pixel of 4096 samples beside pixels of 4, one per-sample variance (0.04) everywhere: each keeps the
    standard error of its own count.

    >>> import numpy as np
    >>> from awr_denoise.finishing import pooled_standard_error
    >>> count = np.full((3, 3), 4.0); count[1, 1] = 4096.0
    >>> variance = 0.04 / count[..., None]                 # of the means
    >>> s = pooled_standard_error(variance, np.ones((3, 3, 1)), count)
    >>> round(float(s[1, 1, 0]), 6), round(float(s[0, 0, 0]), 6)
    (0.003125, 0.1)
    """
    s = np.sqrt(variance)
    if mean is None or count is None:
        return np.maximum(s, median3x3(s))
    return np.maximum(s, _pooled_median_at(s, mean, count, np.nonzero(np.ones(s.shape, dtype=bool))).reshape(s.shape))


def pooled_clamp(image: FloatArray, mean: FloatArray, variance: FloatArray, z: float, *,
                 weights: FloatArray | None = None,
                 count: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
    """Keep every pixel within ``z`` pooled standard errors of its mean (:func:`pooled_standard_error`).

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
    count
        (H, W) sample counts (or (H, W, 1)): pool only the neighbours the pixel's samples could have
        come from (:data:`POOL_CHANCE`); without, every 3x3 neighbour pools.

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

    A dark line one pixel wide in a field of 100 (8 samples a pixel, 50% noise), smoothed towards the field:
    its bright neighbours' standard error would let it stay at 1.5; its own holds it near 0.01.

    >>> mean = np.full((3, 3, 1), 100.0); mean[:, 1] = 0.01
    >>> variance = (0.5 * mean) ** 2 / 8                     # of the means
    >>> image = np.where(mean < 1, 1.5, 100.0)
    >>> round(float(pooled_clamp(image, mean, variance, 2.5)[0][1, 1, 0]), 4)
    1.5
    >>> round(float(pooled_clamp(image, mean, variance, 2.5, count=np.full((3, 3), 8))[0][1, 1, 0]), 4)
    0.0144
    """
    s = np.sqrt(variance)
    reach = z * s
    value = image if weights is None else image @ weights
    low, high = mean - reach, mean + reach
    # Pooling only widens the interval (max(s, median) >= s): a value inside its own interval
    # stays, so the 3x3 medians are needed only where it lies outside, a few per cent of pixels.
    outside = np.nonzero((value < low) | (value > high))
    if outside[0].size:
        pooled = _median3x3_at(s, outside) if count is None else _pooled_median_at(s, mean, count, outside)
        reach_out = z * np.maximum(s[outside], pooled)
        low[outside] = mean[outside] - reach_out
        high[outside] = mean[outside] + reach_out
    if weights is None:
        out = image.copy()
        out[outside] = np.clip(image[outside], low[outside], high[outside])
        return out, out != image
    target = value.copy()
    target[outside] = np.clip(value[outside], low[outside], high[outside])
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(value != 0, target / np.where(value != 0, value, 1.0), 1.0)
    moved = np.broadcast_to((ratio != 1.0)[..., None], image.shape)
    return image * ratio[..., None], moved


def _median3x3_at(a: FloatArray, where: tuple) -> FloatArray:
    """:func:`median3x3` of ``a`` at the indices ``where`` only (``np.nonzero``'s form)."""
    h, w = a.shape[:2]
    rows, cols, rest = where[0], where[1], where[2:]
    values = np.stack([a[(np.clip(rows + i, 0, h - 1), np.clip(cols + j, 0, w - 1)) + rest]
                       for i in (-1, 0, 1) for j in (-1, 0, 1)])
    return np.partition(values, 4, axis=0)[4]


_SORT9 = ((0, 1), (3, 4), (6, 7), (1, 2), (4, 5), (7, 8), (0, 1), (3, 4), (6, 7), (0, 3), (3, 6), (0, 3), (1, 4),
          (4, 7), (1, 4), (2, 5), (5, 8), (2, 5), (1, 3), (5, 7), (2, 6), (4, 6), (2, 4), (2, 3), (5, 6))
"""A sorting network for nine values (25 compare-exchanges; tests check it on every input of 0s and 1s): elementwise
minima and maxima over whole rows, several times faster than ``np.sort`` along an axis of nine."""


def _pooled_median_at(s: FloatArray, mean: FloatArray, count: FloatArray, where: tuple) -> FloatArray:
    """The median of the standard errors ``s`` over the 3x3 neighbours at ``where`` that pass :data:`POOL_CHANCE`'s
    test (the upper median of an even number); every neighbour with ``POOL_CHANCE`` at 0."""
    if not POOL_CHANCE:
        return _median3x3_at(s, where)
    h, w = s.shape[:2]
    rows, cols = where[0], where[1]
    channels = s.shape[2] if s.ndim == 3 else 1
    chan = where[2] if s.ndim == 3 else 0
    # Flat indices into the planes padded by one pixel, edges repeated (as the median filter's mode="nearest").
    pad = ((1, 1), (1, 1), (0, 0))
    s_flat = np.pad(s.reshape(h, w, channels), pad, mode="edge").ravel()
    mean_flat = np.pad(mean.reshape(h, w, channels), pad, mode="edge").ravel()
    count_flat = np.pad(np.asarray(count, dtype=np.float64).reshape(h, w), 1, mode="edge").ravel()
    pixel = (rows + 1) * (w + 2) + (cols + 1)
    n, own_s, own_m = np.maximum(count_flat.take(pixel), 1.0), s[where], mean[where]  # a count of 0: one sample
    # z^n >= POOL_CHANCE with z = S^2 / (S^2 + g^2) is g <= S sqrt(expm1(-log(POOL_CHANCE) / n)): one root per
    # pixel, and a neighbour's test is a product and a comparison (no square of a value, so no overflow).
    # s is the standard error of a mean: the pixel's samples lie within s (n - 1) of their mean (Samuelson),
    # a neighbour's per-sample deviation S is its s sqrt(n).
    reach = np.sqrt(np.expm1(-math.log(POOL_CHANCE) / n))
    with np.errstate(invalid="ignore"):  # one sample: no spread about its mean, whatever its variance says
        near_edge = np.where(n > 1, own_s * (n - 1), 0.0)
    own_root = np.sqrt(n)
    values, kept = [], np.zeros(rows.size, dtype=np.intp)
    for i in (-1, 0, 1):
        for j in (-1, 0, 1):
            nb = pixel + (i * (w + 2) + j)
            at = nb * channels + chan
            value = s_flat.take(at)
            n_nb = count_flat.take(nb)
            gap = np.abs(mean_flat.take(at) - own_m) - near_edge
            with np.errstate(invalid="ignore"):  # an infinite deviation of no samples: inf * 0
                spread = value * np.sqrt(n_nb)  # the neighbour's per-sample deviation
            keep = gap <= spread * reach   # the pixel itself (gap <= 0) always
            # What pools is that deviation over this pixel's own count: the error its mean would have with that
            # spread. The neighbour's own standard error widened a pixel of many samples to a neighbour of few's (an
            # adaptive render's mix of 4 and 4096 samples a pixel: its error stayed at the few's, however many it
            # took; an attack pass). Equal counts pool the same value, bit for bit.
            values.append(np.where(keep, np.where(n_nb == n, value, spread / own_root), np.inf))
            kept += keep
    for i, j in _SORT9:
        low = np.minimum(values[i], values[j])
        np.maximum(values[i], values[j], out=values[j])
        values[i] = low
    return np.choose(kept // 2, values)


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

    The default used it until :func:`restore_mean` replaced it (module docstring); kept as the
    comparison ``benchmarks/bench_reconstruct.py finishing`` measures.

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
    error = None if variance is None else np.sqrt(np.sum(np.asarray(variance) * unit * unit, axis=(0, 1))) / (
        mean.shape[0] * mean.shape[1])
    change = _mean_change(want, got, error, limit, significance)
    factors = np.where(ok, (got + change) / np.where(ok, got, 1.0), 1.0)
    return image * factors, factors


def _mean_change(want: FloatArray, got: FloatArray, error: FloatArray | None, limit: float,
                 significance: float) -> FloatArray:
    """The change of every channel's image mean to make: ``want - got``, bounded unless significant."""
    change = want - got
    # In magnitudes: a channel of negative mean (restored as its mirror image) is bounded as its mirror is.
    mirror = np.where(got < 0, -1.0, 1.0)
    level = np.abs(got)
    bounded = mirror * np.clip(mirror * change, level * (1.0 / (1.0 + limit) - 1.0), level * limit)
    significant = np.zeros(change.shape, bool) if error is None else np.abs(change) > significance * error
    return np.where(significant, change, bounded)


_FILL_STEPS = 64
"""Steps of :func:`_fill`'s iteration before it sorts instead (each step fills at least one pixel)."""


def _fill(weight: FloatArray, cap: FloatArray, total: float, *, steps: int = _FILL_STEPS) -> FloatArray:
    """``min(mu * weight, cap)`` with ``mu`` such that the sum is ``total`` (``0 <= total <= sum(cap)``).

    Water-filling, exact. Start from ``mu = total / sum(weight)`` as if no pixel were full; the
    pixels it fills (``mu * weight >= cap``) take their caps and ``mu`` is solved again on the
    others. ``mu`` only grows (a filled pixel took at most ``mu * weight``), so a pixel once full
    stays full and the loop ends when none fills: a few whole-image passes on real images. After
    ``steps`` steps it sorts the pixels by the level at which each fills instead (:func:`_fill_sorted`).
    """
    room = (cap > 0) & (weight > 0)
    delta = np.where(room, cap, 0.0)                          # every pixel full, until shown otherwise
    if total <= 0:
        return np.zeros_like(cap)
    at = np.flatnonzero(room)                                 # the pixels not full yet, as a list
    a, c = weight.ravel()[at], cap.ravel()[at]
    full = 0.0
    for _ in range(steps):
        if at.size == 0:                                      # every pixel full: total == sum(cap)
            return delta
        mu = (total - full) / float(a.sum())
        filled = mu * a >= c
        if not filled.any():
            delta.ravel()[at] = mu * a
            return delta
        full += float(c[filled].sum())
        keep = ~filled
        at, a, c = at[keep], a[keep], c[keep]
    return _fill_sorted(weight, cap, total)


def _fill_sorted(weight: FloatArray, cap: FloatArray, total: float) -> FloatArray:
    """:func:`_fill` by sorting: sorted by the level ``cap / weight`` at which each pixel is full, the
    sum is piecewise linear in ``mu`` and the piece holding ``total`` gives ``mu``."""
    delta = np.zeros_like(cap)
    room = np.nonzero((cap > 0) & (weight > 0))
    if total <= 0 or room[0].size == 0:
        return delta
    c, a = cap[room], weight[room]
    level = c / a
    order = np.argsort(level, kind="stable")
    level, c, a = level[order], c[order], a[order]
    full = np.concatenate(([0.0], np.cumsum(c)))              # sum of the caps below each level
    open_ = np.concatenate((np.cumsum(a[::-1])[::-1], [0.0]))  # sum of the weights from each level on
    reached = full[1:] + level * open_[1:]                    # the sum at mu = level[j]
    j = int(np.searchsorted(reached, total))
    if j >= level.size:                                       # every pixel full (total == sum(cap))
        delta[room] = cap[room]
        return delta
    mu = (total - full[j]) / open_[j]
    delta[room] = np.minimum(mu * weight[room], cap[room])
    return delta


def restore_mean(image: FloatArray, mean: FloatArray, variance: FloatArray | None = None, *,
                 limit: float = MEAN_LIMIT, significance: float = MEAN_SIGNIFICANCE,
                 offset: float = RESTORE_OFFSET, share: float = RESTORE_SHARE,
                 run: Callable | None = None) -> tuple[FloatArray, FloatArray]:
    """Give every channel back the energy the stages took, where they took it; the image mean is exact.

    For a channel whose output ``o`` lost energy against its means ``x`` (``mean(x) > mean(o)``),
    pixel ``i`` gets back ``delta_i = min(mu a_i, x_i - o_i, share a_i)`` where ``x_i > o_i``
    (none elsewhere), ``a_i = |o_i| + k``, ``k`` = ``offset`` times the channel's mean, ``mu``
    chosen so that the channel's image mean becomes ``mean(x)``; a channel that gained energy is
    treated the other way round. Only when these caps leave some of the change over (the stages
    removed much more than noise, as on a scene of real fireflies) is the rest spread over every
    pixel in proportion to ``|o|``, as one factor would (where the channel gained energy, to its
    level after the capped move: no pixel is pushed below 0 where the capped image is not). So, by
    construction:

    - a pixel moves towards its own mean and never past it, by at most ``share`` of its level,
      unless that rest is spread;
    - a pixel the stages did not darken (brighten) is not touched: the noise of the pixels the
      stages kept at their means (a small light's edge, a caustic) is not scaled;
    - the energy goes, in proportion to their brightness, to the pixels that lost it.

    The image mean is then exact whenever the change is at most ``limit`` of it or significant
    (more than ``significance`` standard errors of the input's image mean,
    ``sqrt(sum(variance)) / N``); otherwise the change stops at ``limit``: the input's mean is no
    better an estimate than the output's then (a firefly a million times the image's level),
    and a removed firefly should not come back. A channel whose input and output means are both
    negative is restored as its mirror image (the map is odd); one whose means are 0, of opposite
    signs or not finite is left as it is.

    Parameters
    ----------
    image
        (H, W, C) output of the stages.
    mean, variance
        (H, W, C) pixel means and the variances of the means (``None``: no change counts as significant).
    limit, significance, offset, share
        See above.
    run
        ``run(f, items)``, an executor's ``map``: the channels on its threads (each channel is
        independent: the same result); default one after the other.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        The image and, per pixel, the share ``t`` (``0 <= t <= 1``) of the way from the stage
        output to the pixel's mean that the capped part moved it (``(1 - t) o + t x``), for the
        propagation of variances; the spread rest, one factor near 1, is left out of it.

    Examples
    --------
    The stages kept a bright pixel at its mean and cut another: the energy returns to the cut one.

    >>> import numpy as np
    >>> from awr_denoise.finishing import restore_mean
    >>> mean = np.array([[[1.0], [1.0], [100.0], [10.0]]])
    >>> image = np.array([[[1.0], [1.0], [100.0], [9.8]]])
    >>> out, share = restore_mean(image, mean, np.full(mean.shape, 1e-6))
    >>> out[..., 0], share[..., 0]
    (array([[  1.,   1., 100.,  10.]]), array([[0., 0., 0., 1.]]))
    """
    o = np.asarray(image, np.float64)
    x = np.asarray(mean, np.float64)
    # Both divided by one power of two first: the plain sum of means near 1e308 overflows.
    top = max(float(np.abs(x).max(initial=0.0)), float(np.abs(o).max(initial=0.0)))
    unit = math.ldexp(1.0, -max(-1000, min(1000, math.frexp(top)[1]))) if np.isfinite(top) and top > 0 else 1.0
    pixels = x.shape[0] * x.shape[1]
    want, got = (x * unit).mean(axis=(0, 1)), (o * unit).mean(axis=(0, 1))
    with np.errstate(over="ignore"):  # variances near 1e308 sum past float64: an infinite error changes nothing
        error = None if variance is None else np.sqrt(np.sum(np.asarray(variance) * unit * unit, axis=(0, 1))) / pixels
    change = _mean_change(want, got, error, limit, significance)
    out = o.copy()
    blend = np.zeros(o.shape)

    def channel(c: int) -> None:
        # A channel of negative mean (an AOV's) is restored as its mirror image: the map stays odd, rec(-x) = -rec(x)
        # (it was left as it was: 2% off its mean where the mirror image was exact; an attack pass).
        flip = -1.0 if want[c] < 0 and got[c] < 0 else 1.0
        if not (flip * want[c] > 0 and flip * got[c] > 0 and np.isfinite(want[c]) and np.isfinite(got[c])) \
                or change[c] == 0:
            return
        sign = 1.0 if flip * change[c] > 0 else -1.0
        oc = o[..., c] * (flip * unit)                          # contiguous planes from here on
        gap = x[..., c] * (flip * unit)
        gap -= oc
        if sign < 0:
            np.negative(gap, out=gap)
        np.maximum(gap, 0.0, out=gap)                           # room towards the pixel's own mean
        level = np.abs(oc)
        weight = level + offset * (flip * want[c])
        cap = weight * share
        np.minimum(cap, gap, out=cap)
        total, room = abs(change[c]) * pixels, float(cap.sum())
        delta = _fill(weight, cap, total) if total < room else cap
        rest = total - room if total > room * (1 + 1e-9) else 0.0  # not the rounding of sum(x - o)
        if rest > 0 and sign < 0:
            # One factor on the image the caps left, not on the stages' output: a pixel the caps brought down to
            # its own mean of 0 must not be pushed below it (the rest is less than the level left, whose mean is
            # the channel's target, so no pixel at or above 0 crosses it).
            level = np.abs(oc - delta)
        if rest > 0 and level.sum() > 0:
            delta = delta + rest * level / level.sum()
        out[..., c] = o[..., c] + (flip * sign) * delta / unit
        np.divide(delta, gap, out=blend[..., c], where=gap > 0)

    (run or (lambda f, items: [f(i) for i in items]))(channel, range(o.shape[2]))
    return out, np.minimum(blend, 1.0)
