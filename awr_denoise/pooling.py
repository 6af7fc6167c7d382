"""Unknown per-sample variances, borrowed from neighbours (paper section 3: never taken as zero).

A pixel's variance is unknown when it has fewer than two samples, or when the renderer said so
(pbrt-v4 writes 0 for pixels that only saw the environment). Taking such a variance as zero
would call the pixel exact and freeze it; instead it is pooled from the known pixels around it.

A pixel whose samples all agreed (a sample variance of exactly 0, typically every path missed a
small light) is not known to be exact either: its variance is moderated towards its neighbours'
(:func:`agreed_variance`), as an empirical-Bayes prior of :data:`AGREED_PRIOR` degrees of freedom. A light's rim
seen against an exact background (samples all at the two exact levels beside it) lends nothing: it is a coverage of
the two, not noise they share.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache

import numpy as np

from . import _checks, fused, rims
from ._typing import BoolArray, CountArray, FloatArray
from ._window_sums import window_sum

__all__ = ["estimated_variance", "pooled_variance", "agreed_variance", "POOL_WINDOW", "JUMP_RATIO", "AGREED_PRIOR"]

POOL_WINDOW = 5
"""Window (pixels) over which an unknown per-sample variance is pooled from neighbours."""

JUMP_RATIO = 4.0
"""A pixel with a mean of its own borrows only from neighbours whose ``|mean|`` is at most this
many times its own: a renderer's "unknown" next to a light must not import the light's variance."""

AGREED_PRIOR = 1.0
"""Degrees of freedom the neighbours' pooled variance counts for in a pixel whose samples all agreed.

Such a pixel's per-sample variance becomes ``d0 s2_local / (n - 1 + d0)`` (the posterior of a scaled
inverse-chi-square prior of ``d0`` degrees of freedom centred on ``s2_local``, given ``n - 1`` of
zero spread): ``s2_local / n`` at ``d0 = 1``, the prior worth one sample, fading as the pixel's own
agreeing samples grow. Measured in docs/reconstruction.md, "Samples that all agreed": images of
samples that are a light's value or exactly 0 from up to 5.3x the plain mean's MSE to 0.16x at most
(``benchmarks/bench_limits.py``), the rendered scenes of both renderers within 0.4% or better in relMSE
(``bench_reconstruct.py quality --compare``), other ``d0`` beside 1 (``quality --priors``)."""


_Edges = Callable[[], "BoolArray | None"]
"""The rims of a buffer's variances, found by the first call (:func:`_rims`)."""

_SCATTER_SHARE = 2.0
"""Entries at 0 at least this many times the spread pixels (known, variance above 0) are weighed from those
outward (:func:`_scattered_at_zero`), fewer are gathered offset by offset: the same values, to rounding, and
the work of each path follows the number it loops over."""


def estimated_variance(count: CountArray, mean: FloatArray, variance: FloatArray, known: BoolArray, *,
                       copy: bool = True) -> FloatArray:
    """(H, W, C) per-sample variance to threshold with: entries whose samples all agreed moderated
    (:func:`agreed_variance`), then unknown entries pooled from the result (:func:`pooled_variance`).

    ``copy=False`` may return ``variance`` itself when neither applies (it is never written to).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.pooling import estimated_variance
    >>> count = np.full((5, 5), 4); mean = np.zeros((5, 5, 1)); variance = np.zeros((5, 5, 1))
    >>> mean[2, 2] = 1.0; variance[2, 2] = 4 / 3              # samples 4, 0, 0, 0 in the middle pixel
    >>> v = estimated_variance(count, mean, variance, count >= 2)  # moderated: agreed_variance
    >>> bool(0 < v[0, 0, 0] < v[2, 2, 0]), round(float(v[2, 2, 0]), 5)
    (True, 1.33333)
    """
    # Moderated first: an unknown variance is then pooled from its neighbours' moderated ones (a single
    # sample beside samples that all agreed at 0, beside a hit, is not exact either). A light's rim is found
    # once, on the variances as given: moderated, the exact regions beside it need not be exact any more.
    edges = _rims(count, mean, variance, known)
    out = _moderated(count, mean, variance, known, None, edges)
    out = out if known.all() else _pooled(count, mean, out, known, edges)
    return np.array(out) if copy and out is variance else out


def _rims(count: CountArray, mean: FloatArray, variance: FloatArray, known: BoolArray) -> _Edges:
    """A light's rims (:func:`.rims.coverage_edges`) in the variances as given, found when first asked for."""

    @lru_cache(maxsize=1)
    def edges() -> BoolArray | None:
        entries = np.asarray(known) & (np.asarray(count) >= 2)  # two samples or more: a spread to agree on
        return rims.coverage_edges(count, mean, variance, _in_pixels(variance == 0, entries),
                                   _in_pixels(variance > 0, entries), window=POOL_WINDOW, jump_ratio=JUMP_RATIO)
    return edges


def agreed_variance(count: CountArray, mean: FloatArray, variance: FloatArray, known: BoolArray,
                    prior: float | None = None) -> FloatArray:
    """Per-sample variance with the entries whose samples all agreed moderated towards their neighbours'.

    An entry is moderated where ``known`` holds (two or more samples) and the variance is exactly 0,
    every sample at the mean ``c``: to ``prior * s2_local / (n - 1 + prior)``, ``prior`` defaulting to
    :data:`AGREED_PRIOR` (0 leaves every entry as it is). ``s2_local`` pools the known pixels of the
    :data:`POOL_WINDOW` square around it, each weighted by its ``n - 1`` and by ``z^n``, where
    ``z = s2 / (s2 + (m - c)^2)`` bounds the chance that one sample of that neighbour's distribution
    (mean ``m``, variance ``s2``) lands on ``c`` (Cantelli's inequality): ``n`` samples at 0 next to
    pixels that are sometimes 0 (a small light reached now and then) borrow their spread, next to a
    steady light they borrow nearly nothing, and a region where every pixel agreed stays exact. A light's rim
    between two exact regions (every sample at one of their levels: :func:`.rims.coverage_edges`)
    lends nothing: the background beside a light seen directly keeps no halo (docs/reconstruction.md, "Samples
    that all agreed").
    Returns ``variance`` itself when no entry is moderated.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.pooling import agreed_variance
    >>> count = np.full((5, 5), 2); mean = np.zeros((5, 5, 1)); variance = np.zeros((5, 5, 1))
    >>> mean[2, 2], variance[2, 2] = 1.0, 2.0     # samples 0 and 2 in the middle, 0 and 0 elsewhere
    >>> v = agreed_variance(count, mean, variance, count >= 2)   # z = 2 / 3: 2 z^2 / (24 + z^2), over n = 2
    >>> round(float(v[0, 0, 0]), 6), float(v[2, 2, 0])
    (0.018182, 2.0)
    >>> variance[2, 2] = 0.02                     # samples 0.9 and 1.1: a steady neighbour, z = 0.02 / 1.02
    >>> bool(agreed_variance(count, mean, variance, count >= 2)[0, 0, 0] < 1e-5)
    True
    """
    return _moderated(count, mean, variance, known, prior, _rims(count, mean, variance, known))


def _moderated(count: CountArray, mean: FloatArray, variance: FloatArray, known: BoolArray, prior: float | None,
               edges: _Edges) -> FloatArray:
    """:func:`agreed_variance` with the rims of ``edges`` lending nothing."""
    prior = _checks.real("prior", AGREED_PRIOR if prior is None else prior, minimum=0.0)
    agreed = _in_pixels(variance == 0, known)
    if not prior or not agreed.any():
        return variance
    # Only entries with a spread neighbour (known, two or more samples, a variance above 0) can borrow anything:
    # a region that all agreed stays 0.
    dof = np.where(known, count - 1, 0).astype(np.float64)
    spread = _in_pixels(variance > 0, dof > 0)
    # A pixel whose samples are all at the levels of two exact regions beside it (the rim of a light seen directly
    # against an exact background) is a coverage of those regions, not noise they could share: no source.
    edges = edges()
    if edges is not None:
        spread &= ~edges
    todo = agreed & _near(spread)
    entries = np.count_nonzero(todo)
    if not entries:
        return variance
    # Means and standard deviations over one power of two near the largest deviation: exact, no overflow.
    g = math.ldexp(1.0, math.frexp(math.sqrt(float(variance.max())))[1])
    s2 = variance / g
    s2 /= g  # in place: at 1080p every whole temporary costs its page faults on each ask()
    if edges is not None:
        s2[edges] = 0.0  # a chance of 0 at any other level: no weight in any pool
    dof /= dof.max()
    out = np.array(variance)
    # Pixels of one count whose samples all missed (0) share their neighbours' weights, channel by channel:
    # where many are (a black background, hits now and then), two window sums over the plane instead of
    # 25 gathers per entry.
    often = -(-count.size // 16)
    for c in range(variance.shape[2]) if entries >= often else ():  # fewer entries in all: no count is frequent
        missed = todo[..., c] & (mean[..., c] == 0)
        big = _frequent(count[missed], often)
        if big.size:
            with np.errstate(over="ignore"):  # a level past float64 over g is a chance of 0
                chance = _chance(s2[..., c], mean[..., c], g)
        for samples in big:
            at = missed & (count == samples)
            weight = dof * chance ** float(samples)
            local = window_sum(weight * s2[..., c], POOL_WINDOW)[at] / window_sum(weight, POOL_WINDOW)[at]
            out[..., c][at] = prior * local * g * g / (samples - 1.0 + prior)
            todo[..., c] &= ~at
    if not todo.any():
        return out
    loop = _compiled_moderation() if fused.backend() == "numba" else None
    if loop is not None:
        # Many entries (more window visits than values in the image: an adaptive run's scattered counts) read the
        # chances at level 0 from one plane taken by numpy; few take each where they visit (the same floats).
        chance0 = s2[:0]
        if np.count_nonzero(todo) * POOL_WINDOW**2 >= s2.size:  # todo as the groups above left it
            with np.errstate(over="ignore"):  # a level past float64 over g is a chance of 0
                chance0 = _chance(s2, mean, g)
        loop(todo, count, mean, s2, dof, g, chance0, float(prior), out)
        return out
    rows, cols, chans = _nonzero(todo)
    local = _gathered_local(count, mean, g, s2, dof, (rows, cols, chans), np.count_nonzero(spread))
    out[rows, cols, chans] = prior * local * g * g / (count[rows, cols] - 1.0 + prior)
    return out


def _frequent(values: CountArray, times: int) -> CountArray:
    """The values (counts, 0 or more) that occur ``times`` times or more, ascending: counted by ``bincount`` where
    the largest is below the number of values (a sort of millions of counts cost more than the rest of an adaptive
    round's moderation), else by ``unique`` (a count past any array's length)."""
    if values.size and values.max() < values.size:
        frequency = np.bincount(values.astype(np.intp, copy=False))
        return np.flatnonzero(frequency >= times)
    groups, sizes = np.unique(values, return_counts=True)
    return groups[sizes >= times]


def _gathered_local(count: CountArray, mean: FloatArray, g: float, s2: FloatArray, dof: FloatArray,
                    where: tuple, spread: int) -> FloatArray:
    """:func:`agreed_variance`'s ``s2_local`` at the entries ``where`` (``s2`` the variances over ``g^2``), window
    offset by window offset: flat indices of each neighbour, the edge pixel past an edge (as ``mode="nearest"``);
    entries at 0 that outnumber the spread pixels by :data:`_SCATTER_SHARE`, from those outward
    (:func:`_scattered_at_zero`); ``spread`` the number of spread entries (known, ``dof`` and variance above 0)."""
    rows, cols, chans = where
    level = mean[where]
    num, den = np.zeros(rows.size), np.zeros(rows.size)
    # Where many missed beside few spread pixels (an adaptive run's scattered counts), the powers are taken once
    # per spread neighbour and entry, not 25 times per entry.
    at_zero = level == 0
    scatter = at_zero.any() and at_zero.sum() >= _SCATTER_SHARE * spread
    if scatter:
        num[at_zero], den[at_zero] = _scattered_at_zero(count, mean, g, s2, dof,
                                                        (rows[at_zero], cols[at_zero], chans[at_zero]))
    r = POOL_WINDOW // 2
    h, w, channels = s2.shape
    n = count[rows, cols].astype(np.float64)
    # Few entries (fewer visits than values in the image: most rounds of an adaptive run) read their neighbours
    # where they are and take each chance at its visit; many read planes padded by their edges, the chances at
    # level 0 taken once per pixel, in place. At 1080p each whole-image temporary costs its page faults: a few
    # thousand entries must not pay for the image.
    padded = rows.size * POOL_WINDOW**2 >= s2.size
    if padded:
        pad = ((r, r), (r, r), (0, 0))
        s2_flat = np.pad(s2, pad, mode="edge").ravel()
        mean_flat = np.pad(mean, pad, mode="edge").ravel() if not at_zero.all() else None
        dof_flat = np.pad(dof, r, mode="edge").ravel()
        width = w + 2 * r
    else:
        s2_flat, mean_flat, dof_flat = s2.ravel(), mean.ravel(), dof.ravel()
    for zero in (False,) if scatter else (True, False):
        part = np.flatnonzero(at_zero == zero)
        if not part.size:
            continue
        log_chance = None
        if zero and padded:
            # At level 0 (every sample missed) a neighbour's chance does not depend on the entry: its logarithm
            # is taken once per pixel, and the entry's weight is exp(n log z).
            with np.errstate(over="ignore", divide="ignore"):  # log 0 = -inf: a weight of 0
                log_chance = _chance(s2, mean, g)
                np.log(log_chance, out=log_chance)
            log_chance = np.pad(log_chance, pad, mode="edge").ravel()
        rr, cc, c, lv, k = rows[part], cols[part], chans[part], level[part], n[part]
        base = (rr + r) * width + (cc + r) if padded else None
        acc_num, acc_den = np.zeros(part.size), np.zeros(part.size)
        for dy in range(-r, r + 1):  # a loop over the 25 window offsets; entries are vectorised
            for dx in range(-r, r + 1):
                if base is not None:
                    near = base + (dy * width + dx)
                else:  # the edge pixel for a neighbour past the edge, as the padding repeats it
                    near = np.clip(rr + dy, 0, h - 1) * w + np.clip(cc + dx, 0, w - 1)
                at = near * channels + c
                spread = s2_flat.take(at)
                if zero:
                    if log_chance is None:
                        assert mean_flat is not None
                        with np.errstate(over="ignore", divide="ignore"):  # log 0 = -inf: a weight of 0
                            power = np.log(_chance(spread, mean_flat.take(at), g))
                    else:
                        power = log_chance.take(at)
                    power *= k
                    power = np.exp(power, out=power)
                else:
                    assert mean_flat is not None
                    with np.errstate(over="ignore"):  # a gap past float64 is a chance of 0
                        power = _chance(spread, mean_flat.take(at), g, level=lv) ** k
                weight = dof_flat.take(near) * power
                acc_num += weight * spread
                acc_den += weight
        num[part], den[part] = acc_num, acc_den
    return num / den


_SQUARING = 64
"""Counts up to which the compiled moderation takes ``z**n`` by repeated squaring (relative error at most about
``n`` float64 epsilons, the size of ``exp(n log z)``'s); above, ``exp`` keeps the error from growing with ``n``."""


def _moderation_loop(todo, count, mean, s2, dof, g, chance0, prior, out):  # pragma: no cover (compiled)
    """:func:`agreed_variance`'s offset-by-offset moderation of the entries ``todo``, written into ``out``, compiled
    by numba (``AWR_DENOISE_KERNELS=numba``): :func:`_gathered_local`'s sums entry by entry, offsets in its order,
    the edge pixel past an edge; ``chance0`` the chances at level 0 as a plane, or empty.

    Where numpy loops over 25 offsets with whole arrays of entries (and entries at 0 from the spread pixels
    outward), this reads each neighbour where it is, takes its chance there (:func:`_chance`'s operations, the
    same floats) unless ``chance0`` holds it, and a power only where the chance is strictly between 0 and 1 (a
    spread neighbour): ``z**n`` by repeated squaring for counts up to :data:`_SQUARING`, else ``exp(n log z)``
    and ``**`` from the C library. The values agree with numpy's to rounding (a few units of the last place),
    not bit for bit (tests/test_pooling.py runs both on every case)."""
    h, w, channels = s2.shape
    r = POOL_WINDOW // 2
    for y in range(h):
        for x in range(w):
            n = count[y, x]
            k = float(n)
            for c in range(channels):
                if not todo[y, x, c]:
                    continue
                level = mean[y, x, c]
                a = 0.0
                b = 0.0
                for dy in range(-r, r + 1):
                    yy = min(max(y + dy, 0), h - 1)
                    for dx in range(-r, r + 1):
                        xx = min(max(x + dx, 0), w - 1)
                        if level == 0.0 and chance0.shape[0]:
                            z = chance0[yy, xx, c]
                        else:
                            gap = abs(mean[yy, xx, c] - level) / g  # past float64: inf, a chance of 0 (as _chance)
                            total = gap * gap + s2[yy, xx, c]
                            z = s2[yy, xx, c] / total if total > 0.0 else 1.0
                        if z == 0.0:  # a weight of 0: nothing to add (numpy adds 0.0)
                            continue
                        if z == 1.0:  # 1**n exactly
                            power = 1.0
                        elif n <= _SQUARING:  # z**n by squaring: fewer roundings than n, no exp
                            power = 1.0
                            base = z
                            e = n
                            while e:
                                if e & 1:
                                    power *= base
                                base *= base
                                e >>= 1
                        elif level == 0.0:
                            power = math.exp(k * math.log(z))
                        else:
                            power = z**k
                        weight = dof[yy, xx] * power
                        a += weight * s2[yy, xx, c]
                        b += weight
                out[y, x, c] = prior * (a / b) * g * g / (k - 1.0 + prior)


@lru_cache(maxsize=1)
def _compiled_moderation() -> Callable | None:
    """:func:`_moderation_loop` compiled (once per process; its machine code cached on disk), ``None`` without numba."""
    return fused.compile_loop(_moderation_loop)


def _scattered_at_zero(count: CountArray, mean: FloatArray, g: float, s2: FloatArray, dof: FloatArray,
                       where: tuple) -> tuple[FloatArray, FloatArray]:
    """``s2_local``'s numerator and denominator at entries at level 0 (every sample missed).

    A neighbour that agreed weighs its ``n - 1`` where it agreed at 0 too (a chance of 1) and nothing elsewhere,
    whatever the entry's count: one window sum. A spread neighbour's chance does not depend on the entry but its
    power ``n`` does: each spread neighbour near such an entry is visited once per window offset and adds
    ``exp(n log z)`` to the entry it is an offset of. Where few pixels are spread (many missed, an adaptive run's
    scattered counts) that is far fewer powers than 25 per entry."""
    rows, cols, chans = where
    h, w, channels = s2.shape
    r = POOL_WINDOW // 2
    # Whole-image temporaries are few and made in place: at 1080p each costs its page faults on every ask().
    with np.errstate(over="ignore"):  # a level past float64 over g is a chance of 0
        chance = _chance(s2, mean, g)
    den = np.zeros(rows.size)
    for c in range(channels):
        on = chans == c
        if on.any():
            agreed_at_zero = dof * ((s2[..., c] == 0) & (chance[..., c] == 1))
            den[on] = window_sum(agreed_at_zero, POOL_WINDOW)[rows[on], cols[on]]
    # Entry numbers on a map padded by 2r (-1 elsewhere): a neighbour in the edge-padded planes (r each side) minus
    # any offset lands on it, never past it. Neighbours are found on the padded grid and read from the pixels their
    # places repeat (the planes themselves are not padded).
    pad = ((r, r), (r, r), (0, 0))
    entry = np.full((h + 4 * r, w + 4 * r, channels), -1, dtype=np.intp)  # int32 measured slower: converted per take
    entry[rows + 2 * r, cols + 2 * r, chans] = np.arange(rows.size)
    # Spread neighbours (known, s2 > 0) within the window of an entry.
    reach = np.zeros((h + 2 * r, w + 2 * r, channels), dtype=bool)
    reach[rows + r, cols + r, chans] = True
    reach = _near(reach)
    reach &= np.pad(_in_pixels(s2 > 0, dof > 0), pad, mode="edge")
    sr, sc, sch = _nonzero(reach)
    width = w + 4 * r
    at = ((sr + r) * width + (sc + r)) * channels + sch
    sr, sc = np.clip(sr - r, 0, h - 1, out=sr), np.clip(sc - r, 0, w - 1, out=sc)  # the pixel each place repeats
    spread, weight = s2[sr, sc, sch], dof[sr, sc]
    with np.errstate(divide="ignore"):  # log 0 = -inf: a weight of 0
        log_chance = np.log(chance[sr, sc, sch])
    # The last slot takes what lands on no entry (-1): no mask, no compress, in each of the 25 passes below.
    entries, n = entry.ravel(), np.append(count[rows, cols].astype(np.float64), 1.0)
    num, den = np.zeros(rows.size + 1), np.append(den, 0.0)
    for dy in range(-r, r + 1):  # a loop over the 25 window offsets; spread neighbours are vectorised
        for dx in range(-r, r + 1):
            target = entries.take(at - (dy * width + dx) * channels)
            share = weight * np.exp(n.take(target) * log_chance)
            # One offset maps distinct neighbours to distinct entries: no entry is added to twice.
            num[target] += share * spread
            den[target] += share
    num, den = num[:-1], den[:-1]
    return num, den


def _chance(s2: FloatArray, mean: FloatArray, g: float, level: FloatArray | float = 0.0) -> FloatArray:
    """Cantelli's bound on the chance that a sample of variance ``s2`` (over ``g^2``) with mean ``mean`` lands on
    ``level``: ``s2 / (s2 + gap^2)``, ``gap = |mean - level| / g``; 1 where both are 0 (a neighbour that agreed at
    the same value). One whole temporary, the gap, which takes the result."""
    with np.errstate(over="ignore", under="ignore"):
        total = np.abs(mean - level) if np.ndim(level) or level else np.abs(mean)
        total /= g
        np.square(total, out=total)
        total += s2
    positive = total > 0
    np.divide(s2, total, out=total, where=positive)
    total[~positive] = 1.0
    return total


def _in_pixels(plane: BoolArray, pixels: BoolArray) -> BoolArray:
    """``plane & pixels[..., None]``, written into ``plane``: channel by channel (numpy's broadcast of a last axis
    of 3 loops 3 entries at a time, twice as long at 1080p), and nothing to do where every pixel is in."""
    if not pixels.all():
        for c in range(plane.shape[2]):
            plane[..., c] &= pixels
    return plane


def _nonzero(mask: BoolArray) -> tuple[np.ndarray, ...]:
    """``np.nonzero(mask)`` by one flat scan and a division: of a 3-D mask at 1080p, numpy's takes 15 times as long."""
    return np.unravel_index(np.flatnonzero(mask), mask.shape)


def _near(mask: BoolArray) -> BoolArray:
    """True where the :data:`POOL_WINDOW` square around a pixel (rows and columns; cut at the edges) holds a True:
    ``ndimage.maximum_filter`` of a boolean, with either edge mode, as ORs of shifted slices, row then column.
    scipy's filter takes several times as long on a 1080p plane, and an adaptive round runs it on every ``ask()``."""
    r = POOL_WINDOW // 2
    down = mask.copy()
    for d in range(1, r + 1):
        down[d:] |= mask[:-d]
        down[:-d] |= mask[d:]
    near = down.copy()
    for d in range(1, r + 1):
        near[:, d:] |= down[:, :-d]
        near[:, :-d] |= down[:, d:]
    return near


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
    return _pooled(count, mean, variance, known, _rims(count, mean, variance, known))


def _pooled(count: CountArray, mean: FloatArray, variance: FloatArray, known: BoolArray, edges: _Edges) -> FloatArray:
    """:func:`pooled_variance` with the rims of ``edges`` lending nothing."""
    dof = np.where(known, count - 1, 0).astype(np.float64)
    if dof.sum() == 0:
        return np.zeros_like(variance)
    # The sums of M2 = variance (n - 1) over a window or the image pass float64 where variances near its limit are
    # known: a pooled variance of 5e307 came out Inf, and the buffer was refused as beyond float64 (an attack pass).
    # Pooled at a power of two below, exactly, and scaled back; only the pooled entries are taken from it.
    top = float(np.max(variance, where=known[..., None] & np.isfinite(variance), initial=0.0))
    shift = math.frexp(top)[1] + math.frexp(float(dof.max()) * dof.size)[1] - 1000  # the largest sum below 2**1000
    if shift > 0:
        scaled = _pooled(count, mean, np.ldexp(variance, -shift), known, edges)
        out = np.array(variance)
        with np.errstate(over="ignore"):
            out[~known] = np.ldexp(scaled[~known], shift)
        return out
    # A light's rim lends no unknown variance either (a single sample beside it, as samples that all agreed):
    # its entries count for nothing in the pools, channel by channel.
    entries = np.broadcast_to(dof[..., None], variance.shape)
    edges = edges()
    if edges is not None:
        entries = np.where(edges, 0.0, entries)
    m2 = variance * entries
    totals = entries.sum(axis=(0, 1))
    # Where every entry of a channel is a rim, nothing is pooled (0); an M2 past float64 stays Inf, as before.
    pooled_global = np.divide(m2.sum(axis=(0, 1)), totals, out=np.zeros_like(totals), where=totals > 0)
    out = np.array(variance)
    missing = ~known
    for c in range(variance.shape[2]):
        # Sums of the window's own entries: a running sum (uniform_filter's) carried a very noisy pixel's rounding
        # error along the line, and a pixel of one sample 25 columns away pooled a variance of 0 (._window_sums).
        local_dof = window_sum(entries[..., c], POOL_WINDOW)
        local_m2 = window_sum(m2[..., c], POOL_WINDOW)
        with np.errstate(invalid="ignore", divide="ignore"):
            local = np.where(local_dof > 0, local_m2 / local_dof, pooled_global[c])
        out[..., c][missing] = np.maximum(local[missing], 0.0)
    # Renderer-unknown pixels with samples enough for a mean of their own: pool only the
    # neighbours whose mean is at most JUMP_RATIO times theirs (no light's variance in a sky).
    own = missing & (count >= 2)
    if own.any():
        out[own] = _pool_below_jump(mean, m2, entries)[own]
    return out


def _pool_below_jump(mean: FloatArray, m2: FloatArray, dof: FloatArray) -> FloatArray:
    """Pooled variance from the 5x5 neighbours whose |mean| <= JUMP_RATIO x the pixel's;
    without such neighbours, the image's pooled relative variance times the pixel's mean^2.
    ``dof``: (H, W, C) degrees of freedom each entry counts for (0 where it lends nothing)."""
    h, w = mean.shape[:2]
    r = POOL_WINDOW // 2
    level = np.abs(mean)
    limit = JUMP_RATIO * level
    pad = ((r, r), (r, r), (0, 0))
    m2p = np.pad(m2, pad)
    dofp = np.pad(dof, pad)
    levelp = np.pad(level, pad, constant_values=np.inf)
    sum_m2 = np.zeros_like(m2)
    sum_dof = np.zeros_like(m2)
    for dy in range(POOL_WINDOW):  # a loop over the 25 window offsets; pixels are vectorised
        for dx in range(POOL_WINDOW):
            ok = levelp[dy:dy + h, dx:dx + w] <= limit
            sum_m2 += np.where(ok, m2p[dy:dy + h, dx:dx + w], 0.0)
            sum_dof += np.where(ok, dofp[dy:dy + h, dx:dx + w], 0.0)
    weight = dof * mean**2
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = m2.sum(axis=(0, 1)) / np.maximum(weight.sum(axis=(0, 1)), 1e-300)
        pooled = np.where(sum_dof > 1e-12, sum_m2 / sum_dof, rel * mean**2)
    return np.maximum(np.nan_to_num(pooled, nan=0.0, posinf=0.0), 0.0)
