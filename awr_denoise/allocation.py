"""Integer sample counts from a target density: the water-filling every sampler shares.

A sampler decides a density (where samples are worth most); :func:`allocate` turns it into whole
new-sample counts per pixel that sum to the round's budget exactly, respect per-pixel caps, and
bring each pixel's total towards ``alpha * density`` (paper section 4: samples go where the
priority is highest, spread over a coefficient's support).
"""

from __future__ import annotations

from fractions import Fraction
from functools import lru_cache

import numpy as np

from . import _checks
from ._arrays import as_float64, check_count, check_finite
from ._typing import CountArray, FloatArray

__all__ = ["allocate", "allocate_mixed", "MAX_BUDGET"]

MAX_BUDGET = 2**62
"""Largest budget :func:`allocate` accepts: counts are int64 and must never overflow."""


def allocate(density: FloatArray, current: CountArray, budget: int, *,
             capacity: CountArray | None = None, rng: np.random.Generator | None = None) -> CountArray:
    """Integer new-sample counts that sum to ``budget`` exactly and follow ``density``.

    Water-filling: find ``alpha`` with ``sum(clip(alpha * density - current, 0, capacity)) =
    budget``, so each pixel's total count approaches ``alpha * density`` (pixels already above
    it get nothing), then round to integers by largest remainder (ties broken by ``rng``).

    Parameters
    ----------
    density
        (H, W) non-negative target density (any scale).
    current
        (H, W) samples each pixel already has.
    budget
        Number of new samples, >= 0.
    capacity
        (H, W) most new samples each pixel may take (``spp_max - current``); unlimited if None.
    rng
        Random generator for tie-breaking.

    Raises
    ------
    ValueError
        If the budget exceeds the total capacity; if the arrays are not (H, W) of one shape, the
        density not finite and >= 0, or the counts and caps not whole and >= 0.
    TypeError
        ``rng`` is not a numpy Generator.

    Examples
    --------
    Totals approach ``alpha * density``: the pixel with three times the density gets three
    times the samples, and a pixel that already has its share gets none:

    >>> import numpy as np
    >>> from awr_denoise import allocate
    >>> allocate(np.array([[1.0, 3.0]]), np.array([[0, 0]]), 8)
    array([[2, 6]])
    >>> allocate(np.array([[1.0, 1.0]]), np.array([[4, 0]]), 4)
    array([[0, 4]])

    Caps hold, and the budget is still spent exactly:

    >>> allocate(np.array([[1.0, 3.0]]), np.array([[0, 0]]), 8, capacity=np.array([[8, 4]]))
    array([[4, 4]])
    >>> allocate(np.ones((1, 2)), np.zeros((1, 2), int), 5, capacity=np.array([[1, 1]]))
    Traceback (most recent call last):
        ...
    ValueError: budget: 5 samples exceed the 2 that spp_max still allows
    """
    density, current, capacity = _checked(density, current, capacity, rng)
    return _allocate(density, current, budget, capacity=capacity, rng=rng)


def _checked(density: FloatArray, current: CountArray, capacity: CountArray | None,
             rng: np.random.Generator | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The public functions' arguments checked: (H, W) arrays of one shape, a finite non-negative
    density, whole non-negative counts and caps, a numpy Generator. The samplers' own densities
    skip this: their NaN and +Inf (a sum past float64) mean "no information" there."""
    current = check_count(current, "current")
    density = as_float64("density", density, 2)
    if density.shape != current.shape:
        raise ValueError(f"density: shape {density.shape} does not match current's {current.shape}")
    check_finite("density", density[..., None])
    if (density < 0).any():
        raise ValueError(f"density: {int((density < 0).sum())} pixel(s) are negative")
    if capacity is not None:
        capacity = np.asarray(check_count(capacity, "capacity"))
        if capacity.shape != current.shape:
            raise ValueError(f"capacity: shape {capacity.shape} does not match current's {current.shape}")
    if rng is not None and not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: expected a numpy Generator, got {type(rng).__name__}")
    return density, current, capacity


def _allocate(density: FloatArray, current: CountArray, budget: int, *, capacity: CountArray | None = None,
              rng: np.random.Generator | None = None) -> CountArray:
    """:func:`allocate` without the argument checks: NaN and +Inf densities count as 0 (the samplers')."""
    budget = _checks.whole("budget", budget, minimum=0)
    if budget > MAX_BUDGET:
        raise ValueError(f"budget: {budget} exceeds {MAX_BUDGET} (2**62), the most samples int64 counts hold safely")
    shape = current.shape
    out = np.zeros(shape, np.int64)
    if budget == 0:
        return out
    # Without caps, the caps are one value broadcast (no whole-image arrays of infinities).
    cap = (np.broadcast_to(np.inf, shape) if capacity is None
           else np.maximum(capacity, 0).astype(np.float64))
    # Integer capacities, summed exactly (a float64 sum rounds above 2**53).
    cap_int = (np.broadcast_to(np.int64(MAX_BUDGET), shape) if capacity is None
               else np.minimum(np.maximum(np.asarray(capacity), 0), MAX_BUDGET).astype(np.int64))
    if capacity is not None and budget > int(cap_int.sum()):
        raise ValueError(f"budget: {budget} samples exceed the {int(cap_int.sum())} that spp_max still allows")
    a = np.array(density, dtype=np.float64)  # a copy: changed in place
    if not np.isfinite(a.max(initial=0.0)):  # NaN or +Inf somewhere (-Inf becomes 0 below either way)
        np.nan_to_num(a, copy=False, nan=0.0, posinf=0.0)
    np.maximum(a, 0.0, out=a)
    if capacity is not None:
        # Closed pixels take nothing whatever their density: left in, one far above the open ones overflowed the
        # scaling below and the water level refused a budget that fits.
        a[cap <= 0] = 0.0
    top = float(a.max(initial=0.0))  # no NaN is left: any density > 0 exactly when the largest is
    if not top > 0:
        a = np.ones(shape)  # nothing to rank on (a deterministic image): spread uniformly
    else:
        # Scaled by a power of two to a largest value in [0.5, 1): exact (the same counts at any scale) and
        # the water level's sums neither overflow (densities near 1e308) nor underflow (subnormal ones).
        exponent = int(np.frexp(top)[1])
        np.ldexp(a, -exponent, out=a)
        # A floor so no open pixel is unreachable: otherwise a budget larger than what the
        # positive-density pixels can absorb would have nowhere to go.
        np.maximum(a, 1e-9 * float(np.ldexp(top, -exponent)), out=a)
    n = current.astype(np.float64)
    alpha = _water_level(a, n, None if capacity is None else cap, budget)
    m = np.multiply(a, alpha)  # the values of max(alpha * a - n, 0), in place
    m -= n
    np.maximum(m, 0.0, out=m)
    if capacity is not None:
        np.minimum(m, cap, out=m)
    out[...] = _round_to_budget(m, cap_int, budget, rng or np.random.default_rng(0))
    return out


def allocate_mixed(density: FloatArray, current: CountArray, budget: int, uniform_fraction: float, *,
                   capacity: CountArray | None = None, rng: np.random.Generator | None = None) -> CountArray:
    """:func:`allocate` with ``uniform_fraction`` of the budget spread uniformly first, the rest by ``density``.

    The samplers' ``uniform_fraction``: insurance against variance estimates that are wrong
    (docs/sampling.md, "The uniform share, measured").

    Examples
    --------
    Half of 8 samples spread evenly, the other half where the density is:

    >>> import numpy as np
    >>> from awr_denoise.allocation import allocate_mixed
    >>> allocate_mixed(np.array([[0.0, 1.0]]), np.array([[0, 0]]), 8, 0.5)
    array([[2, 6]])
    """
    density, current, capacity = _checked(density, current, capacity, rng)
    return _allocate_mixed(density, current, budget, uniform_fraction, capacity=capacity, rng=rng)


def _allocate_mixed(density: FloatArray, current: CountArray, budget: int, uniform_fraction: float, *,
                    capacity: CountArray | None = None, rng: np.random.Generator | None = None) -> CountArray:
    """:func:`allocate_mixed` without the argument checks (the samplers')."""
    uniform_fraction = _checks.real("uniform_fraction", uniform_fraction, minimum=0, maximum=1)
    # In exact arithmetic: the float product rounds above 2**53 (2**53 + 3 at a fraction of 1 gave 2**53 + 4).
    uniform_part = min(budget, round(Fraction(uniform_fraction) * _checks.whole("budget", budget, minimum=0)))
    if uniform_part == 0:  # the samplers' default: no uniform share (allocate would draw nothing for it)
        return _allocate(density, current, budget, capacity=capacity, rng=rng)
    counts = _allocate(np.ones(current.shape), current, uniform_part, capacity=capacity, rng=rng)
    cap = None if capacity is None else capacity - counts
    return counts + _allocate(density, current + counts, budget - uniform_part, capacity=cap, rng=rng)


def _water_level(a: FloatArray, n: FloatArray, cap: FloatArray | None, budget: int) -> float:
    """``alpha`` with ``sum(clip(alpha * a - n, 0, cap))`` within 0.1% of ``budget`` (from above); no cap: ``None``."""
    shape = a.shape
    capped = cap is not None and bool(np.isfinite(cap).any())
    work = np.empty(shape)

    def spent(alpha: float) -> float:
        np.multiply(a, alpha, out=work)
        np.subtract(work, n, out=work)
        np.maximum(work, 0.0, out=work)
        if capped:
            np.minimum(work, cap, out=work)
        return float(work.sum())

    # spent() is monotone and piecewise linear in alpha: a bracketed secant search (Illinois
    # variant of regula falsi) needs a handful of passes over the image where bisection needs ~50.
    lo, hi = 0.0, (budget + n.sum()) / a.sum()
    f_lo, f_hi = -float(budget), spent(hi) - budget
    # Every pixel at its cap: spent() can grow no further (its float64 sum can fall short of the budget by
    # rounding above 2**53). Only then does the level stop rising short of the budget: a doubling that adds
    # nothing (the open pixels capped, the next one opening higher up) is no saturation (a red-team pass).
    full = float(cap.sum()) - budget if capped else np.inf
    while f_hi < 0 and f_hi < full:
        lo, f_lo = hi, f_hi
        hi *= 2.0
        f_hi = spent(hi) - budget
    side = 0
    # Rounding to integers below settles any residual, so stop within 0.1% of the budget.
    tolerance = max(0.5, 1e-3 * budget)
    for _ in range(100):
        if f_hi < tolerance or hi - lo <= 1e-12 * hi:
            break
        mid = hi - f_hi * (hi - lo) / (f_hi - f_lo)
        if not lo < mid < hi:
            mid = 0.5 * (lo + hi)
        f_mid = spent(mid) - budget
        if f_mid < 0:
            lo, f_lo = mid, f_mid
            if side == -1:
                f_hi *= 0.5
            side = -1
        else:
            hi, f_hi = mid, f_mid
            if side == 1:
                f_lo *= 0.5
            side = 1
    return hi


def _round_to_budget(m: FloatArray, cap_int: CountArray, budget: int, rng: np.random.Generator) -> CountArray:
    """Whole counts near ``m``, within ``cap_int``, summing to ``budget`` exactly (largest remainder).

    ``m`` is overwritten (its fractional parts are computed in place).
    """
    shape = m.shape
    floor_m = np.floor(m)
    frac = np.subtract(m, floor_m, out=m).ravel()  # m is not needed after this
    jitter = rng.random(shape).ravel()
    jitter *= 1e-6  # tie-break equal remainders without bias toward low indices
    # Integer arithmetic from here on: the search stops within 0.1% of the budget and float64
    # cannot hold every count above 2**53, so the residual may exceed the number of pixels.
    flat_cap = cap_int.reshape(-1)  # a view, also of a broadcast value
    flat_base = np.minimum(floor_m, float(MAX_BUDGET), out=floor_m).ravel().astype(np.int64)
    if flat_cap.strides != (0,):  # per-pixel caps (without, the cap is MAX_BUDGET, applied above)
        np.minimum(flat_base, flat_cap, out=flat_base)
    left = budget - int(flat_base.sum())
    while left > 0:
        room = flat_cap - flat_base
        open_pixels = int(np.count_nonzero(room > 0))
        if open_pixels == 0:
            raise ValueError(f"budget: {budget} samples exceed what spp_max still allows")
        if left >= open_pixels:  # spread whole samples over every open pixel first
            step = np.minimum(room, left // open_pixels)
            flat_base += step
            left -= int(step.sum())
            continue
        key = np.add(frac, jitter, out=jitter)  # -(frac + jitter) where there is room, +Inf where not
        np.negative(key, out=key)
        if open_pixels < key.size:
            key[room <= 0] = np.inf
        flat_base += _smallest(key, left)
        left = 0
    while left < 0:
        used = int(np.count_nonzero(flat_base > 0))
        if -left >= used:
            step = np.minimum(flat_base, (-left) // used)
            flat_base -= step
            left += int(step.sum())
            continue
        key = np.where(flat_base > 0, frac + jitter, np.inf)
        flat_base -= _smallest(key, -left)
        left = 0
    return flat_base.reshape(shape)


_SELECT_SHARE = 16  # one key in 16, drawn at fixed random places, estimates where the smallest ones end
_SELECT_DIRECT = 2**16  # below this many keys, one argpartition of them all is as fast


@lru_cache(maxsize=8)
def _sample_places(n: int) -> np.ndarray:
    """The fixed random places of :func:`_smallest`'s sample of ``n`` keys (one in :data:`_SELECT_SHARE`)."""
    return np.random.default_rng(n).integers(0, n, n // _SELECT_SHARE)


def _smallest(key: FloatArray, count: int) -> np.ndarray:
    """Boolean mask of the ``count`` smallest entries of the 1-D ``key`` (``0 < count < key.size``).

    The set ``np.argpartition(key, count - 1)[:count]`` selects (the two may differ only between
    exactly equal keys at the boundary), without partitioning the whole image: a sample of the
    keys at fixed random places (a stride would alias with a periodic image) brackets the key that
    decides, every key below the bracket is taken at once and only the keys inside it are
    partitioned. At 1080p the full partition was a tenth of an ``ask()`` (docs/performance.md).
    """
    n = key.size
    mask = np.zeros(n, bool)
    if n >= _SELECT_DIRECT:
        # Its own generator, not the caller's: the tie-breaking draws stay what they were.
        sample = key[_sample_places(n)]
        m = sample.size
        q = count / n
        # A bracket of about eight standard errors of the sample's quantile on either side.
        margin = 8.0 * np.sqrt(q * (1.0 - q) / m) + 4.0 / m
        i_lo = min(max(int((q - margin) * m), 0), m - 1)  # 0: no lower end (every key may be inside)
        i_hi = min(max(int(np.ceil((q + margin) * m)), 0), m - 1)  # m - 1: no upper end
        if i_lo > 0 or i_hi < m - 1:
            part = np.partition(sample, sorted({i_lo, i_hi}))
            lo = part[i_lo] if i_lo > 0 else -np.inf
            hi = part[i_hi] if i_hi < m - 1 else np.inf
            np.less(key, lo, out=mask)
            need = count - int(np.count_nonzero(mask))
            inside = np.flatnonzero((key >= lo) & (key <= hi)) if need > 0 else np.empty(0, np.intp)
            if 0 <= need <= inside.size:
                if need:
                    mask[inside[np.argpartition(key[inside], need - 1)[:need]]] = True
                return mask
            mask[:] = False  # the sample missed (it should not): the full partition below
    mask[np.argpartition(key, count - 1)[:count]] = True
    return mask


