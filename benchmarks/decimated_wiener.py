"""The default reconstruction with its Wiener stages on the decimated transform, cycle-spun over a few shifts.

The reconstruction issue offered two ways to make the Wiener stages translation-invariant: cycle
spinning over a small set of shifts of the decimated transform, or the undecimated transform
(every shift at once), "chosen by measured quality per second". The library runs the undecimated
one (``awr_denoise.stationary``). This module builds the other, for
``benchmarks/bench_reconstruct.py`` to measure beside it: the same steps as the default (stage 1's
pilot, two relative Wiener stages with the exponents 0.75 and 0.4, the first one's energy floor,
the SURE guard, the pooled clamp, non-negativity, the image mean), each Wiener stage computed
on the decimated transform stage 1 uses (``awr_denoise.wavelets``, symmetric boundary, the exact
coefficient variance by its sparse operators; the energy floor's 5x5 window on each decimated
band) once per shift and averaged.

A shift ``(dy, dx)`` drops the first ``dy`` rows and ``dx`` columns before the transform, which
moves the decimation grid by that much without inventing pixels (a rolled or padded image would
duplicate some, and their noise would no longer be independent, which the exact variance
assumes); each pixel's result is the mean over the shifts that contain it. Every stage stays a
fixed linear map of the means for its factors, so the guard gets its exact diagonal: the mean
of the shifts' diagonals (``awr_denoise.wavelets.shrinkage_diagonal``).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from awr_denoise import SampleBuffer
from awr_denoise.finishing import clip_negative, pooled_clamp, restore_mean
from awr_denoise.prepare import Prepared, prepare
from awr_denoise.reconstruct import DEFAULT_DOMAIN, _wiener_levels, resolve_settings
from awr_denoise.sure import sure_blend
from awr_denoise.thresholding import threshold_stage
from awr_denoise.wavelets import coefficient_variance, forward, inverse, shrinkage_diagonal, wavelet_operators
from awr_denoise.wiener import stage_weights

__all__ = ["SHIFT_SETS", "decimated_wiener", "decimated_default"]

SHIFT_SETS = {1: ((0, 0),), 4: ((0, 0), (0, 1), (1, 0), (1, 1)),
              16: tuple((dy, dx) for dy in range(4) for dx in range(4))}
"""Shifts per count: none, the four of one level's grid, the sixteen of two levels'."""


def _factors(x: list, p: list, d2: list, floor: tuple[int, float] | None) -> list:
    """``P^2 / (P^2 + Delta^2)`` per detail coefficient (``P^2`` floored as in the library's first stage);
    the scale band kept (factor 1)."""
    out = [np.ones_like(x[0])]
    tiny = np.finfo(np.float64).tiny
    for xs, ps, ds in zip(x[1:], p[1:], d2[1:]):
        level = []
        for xb, pb, db in zip(xs, ps, ds):
            signal = pb * pb
            if floor is not None:  # the energy the means show beyond margin x their noise, window-averaged
                signal = np.maximum(signal, ndimage.uniform_filter(xb * xb - floor[1] * db, floor[0], mode="nearest"))
            signal = signal + tiny
            level.append(signal / (signal + np.maximum(db, 0.0)))
        out.append(tuple(level))
    return out


def decimated_wiener(x: np.ndarray, v: np.ndarray, pilot: np.ndarray, *, k: float, exponent: float, levels: int,
                     shifts: tuple, floor: tuple[int, float] | None = None,
                     leverage: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """One relative Wiener stage (the library's ``relative_wiener``) on the decimated transform, cycle-spun.

    ``x``, ``v``, ``pilot``: (H, W, C) means, their variances and the pilot at unit scale. Returns
    the stage's image and, with ``leverage``, its diagonal (H, W, C).
    """
    w = stage_weights(pilot, k, exponent)
    xs, vs, ps = x / w, v / w / w, pilot / w
    h, wd, channels = x.shape
    out = np.zeros_like(x)
    diag = np.zeros_like(x) if leverage else None
    cover = np.zeros((h, wd, 1))
    for dy, dx in shifts:
        region = (slice(dy, None), slice(dx, None))
        ops = wavelet_operators((h - dy, wd - dx), levels=levels)
        for c in range(channels):
            xc = forward(xs[region][..., c], levels=levels)
            factors = _factors(xc, forward(ps[region][..., c], levels=levels),
                               coefficient_variance(vs[region][..., c], operators=ops), floor)
            scaled = [xc[0]] + [tuple(f * b for f, b in zip(fl, bl)) for fl, bl in zip(factors[1:], xc[1:])]
            out[region + (c,)] += inverse(scaled, (h - dy, wd - dx))
            if diag is not None:
                diag[region + (c,)] += shrinkage_diagonal(factors, ops)
        cover[region] += 1
    out = out / cover * w  # the leverage needs no w: it cancels on the diagonal
    return out, None if diag is None else diag / cover


def _later(prepared: Prepared, pilot: np.ndarray, settings, levels: int, shifts: tuple) -> np.ndarray:
    """The default's steps after stage 1 with :func:`decimated_wiener` for its Wiener stages (channel mode)."""
    s, k, x, v = prepared.unit_scaled()
    out = pilot / s
    exponents = settings.exponents
    for i, exponent in enumerate(exponents[:-1]):
        out, _ = decimated_wiener(x, v, out, k=k, exponent=exponent, levels=levels, shifts=shifts,
                                  floor=settings.floor if i == 0 else None)
    out, lev = decimated_wiener(x, v, out, k=k, exponent=exponents[-1], levels=levels, shifts=shifts,
                                leverage=settings.guard)
    if settings.guard:
        out, _ = sure_blend(out, x, v, lev, k=k, window=settings.guard_window, tolerance=settings.guard_tolerance,
                            spared_beside=settings.guard_spared_beside)
    image = out * s
    if settings.pixel_clamp is not None:
        image, _ = pooled_clamp(image, prepared.mean, prepared.variance, settings.pixel_clamp,
                                count=prepared.count)
    if settings.nonnegative:
        image, _ = clip_negative(image, prepared.mean)
    if settings.preserve_mean:
        image, _ = restore_mean(image, prepared.mean, prepared.variance)
    return image


def decimated_default(shifts: int):
    """``buffer -> image``: the default reconstruction with decimated Wiener stages over ``shifts`` shifts."""
    def run(buffer: SampleBuffer) -> np.ndarray:
        settings = resolve_settings()
        prepared = prepare(buffer, DEFAULT_DOMAIN)
        ops = wavelet_operators(buffer.shape)
        stage = threshold_stage(prepared, ops, settings.c_s, pixel_clamp=settings.stage1_clamp,
                                precision=settings.precision)
        return _later(prepared, stage.image, settings, _wiener_levels(ops.levels), SHIFT_SETS[shifts])
    run.__name__ = f"decimated_wiener_{shifts}"
    return run
