"""Chan's parallel update of per-pixel sample statistics, whole images at a time.

Two sets of samples of one pixel, ``(n_a, mean_a, M2_a)`` and ``(n_b, mean_b, M2_b)``, merge
exactly (Chan, Golub and LeVeque 1979; the parallel form of Welford's algorithm):

    n = n_a + n_b,  d = mean_b - mean_a,  mean = mean_a + d n_b / n,
    M2 = M2_a + M2_b + d^2 n_a n_b / n,

so a buffer built from several rounds or tiles equals the buffer of all samples at once (paper
section 3: the sampler adds samples round by round). :meth:`SampleBuffer.merge
<awr_denoise.buffers.SampleBuffer.merge>` is this on every pixel and channel.

A sampler merges every round of a 1080p or 4K frame: the formulas are a dozen elementwise
passes, run here block by block of rows so that their temporaries stay in the processor's
cache rather than in memory: the same operations in the same order, so the same bits, and
``tell()`` went from 2.0x to 1.5x the PyWavelets floor at 1080p (``benchmarks/bench_core.py
--only speed``; docs/performance.md). With the compiled kernels (extra ``fast``,
``AWR_DENOISE_KERNELS=numba``: :mod:`awr_denoise.fused`) the same floats come from one loop over the
pixels, which reads each input once and makes no temporaries (tests/test_merging.py compares them bit
for bit: additions, multiplications and divisions in the same order, no fused multiply-add).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor
from functools import lru_cache

import numpy as np

from . import _checks, fused
from ._typing import CountArray, FloatArray

__all__ = ["merge_moments", "BLOCK_BYTES"]

BLOCK_BYTES = 2**19
"""Bytes of one (rows, W, C) float64 block (about 11 rows of a 1080p RGB frame): within a
processor's second-level cache with the formulas' temporaries."""


def merge_moments(count_a: CountArray, mean_a: FloatArray, variance_a: FloatArray, count_b: CountArray,
                  mean_b: FloatArray, variance_b: FloatArray, *,
                  executor: Executor | None = None) -> tuple[FloatArray, FloatArray]:
    """The mean and unbiased per-sample variance of the union of two pixels' samples (module docstring).

    Parameters
    ----------
    count_a, count_b
        (H, W) int64 sample counts.
    mean_a, variance_a, mean_b, variance_b
        (H, W, C) float64 means and per-sample variances ``M2 / (n - 1)`` (0 where ``n < 2``).
    executor
        Optional ``concurrent.futures.Executor`` (threads): the top and bottom halves of the rows
        are merged on two of its threads, block by block as without it: the same bits.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        (H, W, C) mean and variance of the merged samples (new arrays). Where one side has no
        samples they are the other side's, bit for bit.

    Examples
    --------
    Samples 1, 3 and 5 (mean 3, variance 4) and samples 7 and 9 (mean 8, variance 2) give the
    statistics of 1, 3, 5, 7, 9 (mean 5, variance 10):

    >>> import numpy as np
    >>> from awr_denoise.merging import merge_moments
    >>> mean, variance = merge_moments(np.array([[3]]), np.array([[[3.0]]]), np.array([[[4.0]]]),
    ...                                np.array([[2]]), np.array([[[8.0]]]), np.array([[[2.0]]]))
    >>> float(mean[0, 0, 0]), float(variance[0, 0, 0])
    (5.0, 10.0)
    """
    if count_a is count_b and mean_a is mean_b and variance_a is variance_b:  # b.merge(b)
        raise ValueError("other: the same statistics as the buffer merged into (the same arrays): merged, its "
                         "samples would count twice")
    h, w, c = mean_a.shape
    mean, variance = np.empty((h, w, c)), np.empty((h, w, c))
    rows = max(1, BLOCK_BYTES // (w * c * 8))
    loop = _compiled_merge() if fused.backend() == "numba" else None

    def merge_rows(span: tuple[int, int]) -> None:
        if loop is not None:  # one pass, no temporaries: no blocks needed (past float64 is refused below alike)
            block = slice(*span)
            loop(count_a[block], mean_a[block], variance_a[block], count_b[block], mean_b[block], variance_b[block],
                 mean[block], variance[block])
            return
        with np.errstate(over="ignore", invalid="ignore"):  # past float64: refused below, by name (per thread)
            for start in range(span[0], span[1], rows):
                block = slice(start, min(start + rows, span[1]))
                _merge_block(count_a[block], mean_a[block], variance_a[block], count_b[block], mean_b[block],
                             variance_b[block], mean[block], variance[block])

    # Each pixel's statistics depend on that pixel alone: the halves are independent, the same bits.
    half = (h // 2 // rows) * rows
    if executor is None or half == 0:
        merge_rows((0, h))
    else:
        _checks.mapped(executor, merge_rows, [(0, half), (half, h)])
    # Whole arrays first: a reduction over a last axis of 3 channels takes four times as long at 1080p.
    if np.isfinite(mean).all() and np.isfinite(variance).all():
        return mean, variance
    beyond = ~(np.isfinite(mean) & np.isfinite(variance)).all(axis=2)
    # The sums passed float64, not always the result: those pixels again, each scaled on its own.
    at = np.nonzero(beyond)
    with np.errstate(over="ignore", invalid="ignore"):
        mean[at], variance[at] = _merge_scaled(count_a[at], mean_a[at], variance_a[at], count_b[at], mean_b[at],
                                               variance_b[at])
    beyond = ~(np.isfinite(mean) & np.isfinite(variance)).all(axis=2)
    if beyond.any():
        raise ValueError(f"other: merged, the mean or variance of {int(beyond.sum())} pixel(s) is beyond float64 "
                         "(1.8e308): their samples spread that far (all of them at once are refused alike)")
    return mean, variance


def _merge_block(ca: CountArray, ma: FloatArray, va: FloatArray, cb: CountArray, mb: FloatArray, vb: FloatArray,
                 mean: FloatArray, variance: FloatArray) -> None:
    """Chan's update of one block of rows, into ``mean`` and ``variance``."""
    na = ca[..., None].astype(np.float64)
    nb = cb[..., None].astype(np.float64)
    n = na + nb
    safe = np.maximum(n, 1.0)
    # The degrees of freedom as floats before the products: an integer factor makes numpy convert it in a buffered
    # loop, about a quarter slower.
    m2 = va * np.maximum(ca - 1, 0).astype(np.float64)[..., None]
    m2 += vb * np.maximum(cb - 1, 0).astype(np.float64)[..., None]
    delta = mb - ma
    np.multiply(delta, nb / safe, out=mean)
    mean += ma
    delta *= delta
    delta *= na * nb / safe
    m2 += delta
    np.divide(m2, np.maximum(n - 1.0, 1.0), out=variance)
    # Where one side has no samples the other side's statistics are the answer: taken as they
    # are, so merging into an empty buffer (round 0, disjoint tiles) is bit-exact rather than
    # off by the rounding of variance * (n - 1) / (n - 1). The mask is repeated over the channels: copyto under
    # a mask broadcast over them took two fifths of the block's time at 1080p, twice what it takes so.
    for counts, (m, v) in ((cb, (ma, va)), (ca, (mb, vb))):
        empty = counts == 0
        if empty.any():
            where = np.repeat(empty, mean.shape[-1]).reshape(mean.shape)
            np.copyto(mean, m, where=where)
            np.copyto(variance, v, where=where)


def _merge_loop(ca: CountArray, ma: FloatArray, va: FloatArray, cb: CountArray, mb: FloatArray, vb: FloatArray,
                mean: FloatArray, variance: FloatArray) -> None:
    """:func:`_merge_block`'s floats one pixel and channel at a time, the same operations in the same order
    (compiled by :func:`_compiled_merge`; as Python it is the reference the tests read, far too slow to run)."""
    h, w, channels = mean.shape
    for i in range(h):
        for j in range(w):
            a, b = ca[i, j], cb[i, j]
            na, nb = float(a), float(b)
            n = na + nb
            safe = max(n, 1.0)
            dof_a, dof_b = float(max(a - 1, 0)), float(max(b - 1, 0))
            share, weight, dof = nb / safe, na * nb / safe, max(n - 1.0, 1.0)
            for k in range(channels):
                if a == 0:  # one side without samples: the other side's statistics as they are (both: b's)
                    mean[i, j, k], variance[i, j, k] = mb[i, j, k], vb[i, j, k]
                elif b == 0:
                    mean[i, j, k], variance[i, j, k] = ma[i, j, k], va[i, j, k]
                else:
                    delta = mb[i, j, k] - ma[i, j, k]
                    mean[i, j, k] = delta * share + ma[i, j, k]
                    m2 = va[i, j, k] * dof_a + vb[i, j, k] * dof_b
                    variance[i, j, k] = (m2 + delta * delta * weight) / dof


@lru_cache(maxsize=1)
def _compiled_merge() -> Callable | None:
    """:func:`_merge_loop` compiled (once per process; its machine code cached on disk), ``None`` without numba."""
    return fused.compile_loop(_merge_loop)


def _merge_scaled(ca: CountArray, ma: FloatArray, va: FloatArray, cb: CountArray, mb: FloatArray,
                  vb: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Chan's update of (P, C) pixels whose sums overflow, each pixel divided first by a power of two near its
    largest mean or standard deviation, so ``d^2`` and ``M2`` stay finite (samples of +-2**510 merged into a
    variance of 1.1e307, as all of them at once give, not a refusal); exact but for what falls 2**1074 below that
    largest value. Both sides have samples here."""
    top = np.maximum(np.maximum(np.abs(ma), np.abs(mb)), np.sqrt(np.maximum(va, vb))).max(axis=1)
    unit = np.ldexp(1.0, -np.frexp(top)[1])[:, None]
    mean, variance = np.empty(ma.shape), np.empty(ma.shape)
    _merge_block(ca, ma * unit, va * unit * unit, cb, mb * unit, vb * unit * unit, mean, variance)
    return mean / unit, variance / unit / unit
