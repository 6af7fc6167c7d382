"""Wavelet-coefficient priorities: where the next samples do the most good (paper section 4).

The paper puts every scale coefficient in a priority queue keyed by "scale-coefficient variance
minus squared wavelet magnitudes" and sends samples into the support of the winner. Our form
(docs/sampling.md, "How AdaptiveSampler decides") for levels ``k = 0..L`` (level 0 = the pixels):

    P_k = 4^k * ( Var(S~_k) - sum_a max(0, W~^a_k^2 - (t Delta^a_k)^2) )

``Var(S~_k)`` and ``Delta`` are exact (:func:`~awr_denoise.wavelets.coefficient_variance`);
subtracting ``(t Delta)^2`` with ``t = 2`` removes the upward noise bias of ``W~^2``
(``E[W~^2] = W^2 + Delta^2``) so that pure noise does not look like an edge. In smooth regions
the variance grows fine to coarse while the wavelet term stays near zero, so a coarse level wins;
at edges the wavelet term grows with the level and a fine level wins (the talk's two cases).

The winning level ``l_p`` of each pixel then sets how much a sample there is worth. If the
reconstruction averages a smooth region over ``4^l`` pixels, one more sample at pixel ``p``
lowers the summed error by ``s2_p / (4^l n_p (n_p + 1))``; the allocation that spends a budget
best gives pixel ``p`` about ``n_p ~ s_p 2^-l_p`` samples (``s`` the per-sample standard
deviation): samples concentrate on edges and spread thinly over smooth noisy regions.
"""

from __future__ import annotations

from concurrent.futures import Executor
from functools import lru_cache, partial

import numpy as np

from . import _checks
from ._arrays import numeric
from ._typing import CountArray, FloatArray
from ._window_sums import neighbour_sum, window_sum
from .buffers import SampleBuffer
from .domains import Domain
from .noise_gain import DEFAULT_NOISE_MODEL, NOISE_MODELS, shrinkage_gain
from .prepare import Prepared, prepare
from .wavelets import (DEFAULT_WAVELET, WaveletOperators, _plane_variance, coefficient_variance, forward,
                       wavelet_operators)

__all__ = ["coefficient_priorities", "pixel_levels", "sampling_density", "error_plane", "pooled_deviation",
           "dropped_at_mean", "DEFAULT_ABSOLUTE_ABOVE"]

_SIGNIFICANCE = 2.0  # t: a detail coefficient counts as signal beyond t standard errors
_FLOAT32_SAFE = (2.0**-100, 2.0**100)  # variances propagated in float32 when all lie in this range (or are 0)
_FINITE_TOP = float(np.finfo(np.float64).max) / 16  # the largest pooled variance: a 3x3 mean of it stays finite

DEFAULT_ABSOLUTE_ABOVE = 6.0
"""The samplers' ``absolute_above``: a pixel's level counts up to 6 times the image's mean level.

Measured on both renderers (docs/sampling.md, "Relative and absolute error"): relMSE within a few
percent of the relative error alone, MSE up to 82 times lower next to a small, very bright source."""


def error_plane(buffer: SampleBuffer, domain: str | Domain = "log") -> tuple[FloatArray, FloatArray, FloatArray]:
    """The single plane priorities are computed on: luminance in the error domain.

    Returns
    -------
    mean_y, var_mean_y, var_sample_y
        (H, W) luminance mean, variance of that mean and per-sample variance, carried into the
        domain by the delta method (so ``"log"`` measures relative error, as relMSE does).
        Pixels without samples borrow their nearest neighbour's mean and the pooled variance.

    Examples
    --------
    White pixels of mean 1 from 4 samples of variance 0.5; the log domain's ``k`` is 0.1:

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.priorities import error_plane
    >>> buffer = SampleBuffer.from_moments(np.full((8, 8), 4), np.ones((8, 8, 3)), np.full((8, 8, 3), 0.5))
    >>> mean_y, var_mean_y, var_sample_y = error_plane(buffer)
    >>> mean_y.shape, round(float(mean_y[0, 0]), 4)                   # log(1 + 1 / 0.1)
    ((8, 8), 2.3979)
    >>> round(float(var_sample_y[0, 0]), 4), round(float(var_mean_y[0, 0]), 4)   # 0.5 / 1.1^2, and / 4
    (0.4132, 0.1033)
    """
    return _plane(prepare(buffer, domain, luminance=True))


def _plane(p: Prepared) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`error_plane` of a luminance plane already prepared."""
    return p.y, p.sample_variance_y / p.count, p.sample_variance_y


def pooled_deviation(buffer: SampleBuffer, domain: str | Domain = "log", *,
                     absolute_above: float | None = DEFAULT_ABSOLUTE_ABOVE,
                     prepared: Prepared | None = None) -> FloatArray:
    """(H, W) per-sample standard deviation ``s_p`` the samplers rank pixels by, pooled over neighbours.

    In the error domain (``"log"``: relative error, ``s / (mu + k)``, what relMSE counts), with
    each pixel's level capped near ``absolute_above`` times the image's mean level ``m``:
    ``s_p^2 = s_domain^2 + (s / (absolute_above m))^2``. A pixel far brighter than the image, a
    small light seen directly, is then ranked by its absolute error, what MSE counts, and not starved
    because its relative error is small; darker pixels keep their relative ranking. ``None`` ranks
    by the domain's error alone. Pooled because a variance from four samples is too noisy to rank on:
    the domain's term over the pixel's 8 neighbours, its own samples left out (so that they decide
    none of its next samples at first hand, which biased AWR sampling's image mean low, docs/sampling.md
    "The pixel's own samples"), the absolute term over 3x3 pixels, its own included.

    Examples
    --------
    Pixels of level 1 and a strip of level 100 with the same relative noise (the image's mean
    level is 12, the log domain's offset 1.2): relative error ranks a strip pixel about twice a dark
    one; past 6 times the mean level its absolute error counts too, and it ranks 3.7 times higher:

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.priorities import pooled_deviation
    >>> mean = np.ones((9, 18, 3)); mean[:, 16:] = 100.0
    >>> buffer = SampleBuffer.from_moments(np.full((9, 18), 4), mean, (0.5 * mean) ** 2)
    >>> s = pooled_deviation(buffer, absolute_above=None)
    >>> round(float(s[4, 17] / s[4, 2]), 2)                  # (50 / 101.2) / (0.5 / 2.2)
    2.17
    >>> s = pooled_deviation(buffer)
    >>> round(float(s[4, 17] / s[4, 2]), 2)
    3.75
    """
    p = prepare(buffer, domain, luminance=True) if prepared is None else prepared
    # Held finite (allocate() would read +inf as no density at all), and the pools' sums with them.
    s2_pooled = _neighbours(np.minimum(p.sample_variance_y, _FINITE_TOP))
    if absolute_above is not None:
        absolute_above = _checks.real("absolute_above", absolute_above, above=0)
        level = absolute_above * p.domain.resolved_scale(p.mean)
        if level > 0 and np.isfinite(level):  # an image whose level overflows keeps the domain's ranking
            with np.errstate(over="ignore"):
                s2_abs = np.minimum(p.sample_variance / level / level, _FINITE_TOP)
            # A light's own absolute error keeps ranking it: left out, a small light's pixels rank by their
            # darker neighbours and keep their first rounds' few samples.
            s2_pooled += window_sum(s2_abs, 3) / 9.0
    return np.sqrt(s2_pooled, out=s2_pooled)


def _neighbours(s2: FloatArray) -> FloatArray:
    """Mean of each pixel's 8 neighbours (edges mirrored, so that the pixel is not among them; a side one pixel
    thin has no neighbours across it and keeps the pixel's own copies there).

    A pixel ranked by its own samples' error takes more samples where its first ones caught a bright path (and
    is diluted back) and keeps its low mean where they missed it: AWR sampling's image mean came out low on
    heavy-tailed scenes, 0.5% (Mitsuba's Cornell box) to 1.4% (glossy and glass) at 8 spp. Ranked by its
    neighbours', its own samples decide none of its next ones at first hand (docs/sampling.md, "The pixel's
    own samples").
    """
    # Added up from the neighbours: a bright pixel's own value taken out of a sum with it left its rounding error
    # in its neighbours' mean (._window_sums).
    pooled = neighbour_sum(s2, mode="reflect")
    pooled /= 8.0
    return pooled


def coefficient_priorities(
    buffer: SampleBuffer,
    *,
    wavelet: str = DEFAULT_WAVELET,
    levels: int | None = None,
    domain: str | Domain = "log",
    boundary: str = "symmetric",
    operators: WaveletOperators | None = None,
    plane: tuple[FloatArray, FloatArray, FloatArray] | None = None,
    executor: Executor | None = None,
) -> list[FloatArray]:
    """Priority ``P_k`` of every scale coefficient at levels ``k = 0..L``.

    Parameters
    ----------
    buffer
        Sample statistics so far.
    wavelet, levels, boundary
        As in :func:`~awr_denoise.wavelets.forward`.
    domain
        Error domain (see :func:`error_plane`).
    operators
        Prebuilt operators for the buffer's shape.
    plane
        A precomputed :func:`error_plane` of ``buffer``.
    executor
        Optional ``concurrent.futures.Executor`` (threads): the transform of the means runs on it
        while the variances propagate in this thread; the same result as without.

    Returns
    -------
    list of ndarray
        ``[P_0 (H, W), P_1, ..., P_L]``, each on its level's coefficient grid.

    Examples
    --------
    On a flat, noisy image the scale variance grows from fine to coarse while the wavelet
    term stays near zero, so priorities grow with the level:

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.priorities import coefficient_priorities
    >>> flat = SampleBuffer.from_moments(np.full((32, 32), 4), np.ones((32, 32, 3)), np.full((32, 32, 3), 0.5))
    >>> priorities = coefficient_priorities(flat)
    >>> [p.shape for p in priorities]
    [(32, 32), (20, 20), (14, 14)]
    >>> [round(float(np.median(p)), 2) for p in priorities]
    [0.1, 0.45, 2.26]
    """
    (mean_y, var_y, _), c = _normalised(plane if plane is not None else error_plane(buffer, domain))
    ops = operators or wavelet_operators(buffer.shape, wavelet=wavelet, levels=levels, boundary=boundary)
    scale_variances: list = []
    coeffs, variances = _transformed(mean_y, var_y, ops, executor, scale_variances)
    priorities = [np.asarray(var_y, dtype=np.float64)]
    for k in range(1, ops.levels + 1):
        j = ops.levels - k + 1  # position of level k's detail bands in pywt's layout
        # sum_a max(0, W~^2 - (t Delta)^2), accumulated in place (the same operations, in order).
        detail_energy = np.zeros(scale_variances[k - 1].shape)
        for b in range(3):
            w, noise = coeffs[j][b], variances[j][b]
            energy = np.multiply(w, w)
            noise *= _SIGNIFICANCE**2
            energy -= noise
            np.maximum(energy, 0.0, out=energy)
            detail_energy += energy
        priority = np.subtract(scale_variances[k - 1], detail_energy, out=detail_energy)
        priority *= 4.0**k
        priorities.append(priority)
    if c != 1.0:
        with np.errstate(over="ignore"):  # Inf: a priority beyond float64 (means near 1e300)
            priorities = [p * c * c for p in priorities]
    return priorities


def _transformed(mean_y: FloatArray, var_y: FloatArray, ops: WaveletOperators, executor: Executor | None,
                 scales: list | None = None) -> tuple[list, list]:
    """The plane's coefficients and their exact variances (and every level's scale variance into ``scales``).

    The transform of the means runs on ``executor`` while the variances propagate in this thread.
    """
    executor = _checks.executor("executor", executor)
    transform = partial(forward, mean_y, wavelet=ops.wavelet, levels=ops.levels, boundary=ops.boundary)
    pending = None if executor is None else executor.submit(transform)
    coeffs = transform() if pending is None else None
    var_y = np.asarray(var_y, dtype=np.float64)
    if var_y.shape != ops.shape or not (np.isfinite(var_y.max(initial=0.0)) and var_y.min(initial=0.0) >= 0):
        coefficient_variance(var_y, operators=ops)  # raises the error that names the bad values
    # One pass of the squared operators gives the detail variances and every level's scale variance,
    # in float32 where every positive variance is a normal float32 number with room to spare (the
    # products then keep float32's 7 digits): a level changes only where two levels' priorities
    # agree to 1e-7, which none of the 2M pixels of a 1080p buffer did (docs/performance.md).
    smallest = float(np.min(var_y, where=var_y > 0, initial=np.inf))
    single = var_y.max(initial=0.0) < _FLOAT32_SAFE[1] and (smallest == np.inf or smallest > _FLOAT32_SAFE[0])
    variances = _plane_variance(var_y.astype(np.float32) if single else var_y, ops, scales=scales)
    return (coeffs if pending is None else _checks.outcome(pending, transform, executor)), variances


def _normalised(plane: tuple[FloatArray, FloatArray, FloatArray]) -> tuple[tuple[FloatArray, FloatArray, FloatArray],
                                                                          float]:
    """The plane divided by a power of two (exact) when squaring its values would overflow."""
    mean_y, var_y, s2 = plane
    top = max(float(np.abs(mean_y).max(initial=0.0)), float(np.sqrt(var_y.max(initial=0.0))),
              float(np.sqrt(s2.max(initial=0.0))))
    if not top > 2.0**500:
        return plane, 1.0
    c = float(np.ldexp(1.0, int(np.frexp(top)[1])))
    return (mean_y / c, var_y / c / c, s2 / c / c), c


@lru_cache(maxsize=64)
def _pixel_to_coefficient(n: int, wavelet: str, boundary: str, levels: int, level: int) -> np.ndarray:
    """For each of the n pixels of an axis, the level-k scale coefficient weighing it most."""
    op = wavelet_operators((n, n), wavelet=wavelet, levels=levels, boundary=boundary).rows.approx[level - 1]
    return np.asarray(abs(op).tocsc().argmax(axis=0)).ravel()


@lru_cache(maxsize=64)
def _expansion(n: int, wavelet: str, boundary: str, levels: int,
               level: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_pixel_to_coefficient` as a run-length expansion plus the few pixels it gets wrong.

    Away from the boundary the map is non-decreasing, so ``np.repeat`` with each coefficient's
    pixel count gathers it (several times faster than a fancy-index gather); near the boundary
    a few pixels map out of order and are gathered one by one: ``(counts, pixels, coefficients)``.
    """
    index = _pixel_to_coefficient(n, wavelet, boundary, levels, level)
    counts = np.bincount(index)
    wrong = np.flatnonzero(np.repeat(np.arange(counts.size), counts) != index)
    return counts, wrong, index[wrong]


def _gather(p: FloatArray, rows: tuple, cols: tuple) -> FloatArray:
    """``p[np.ix_(rows_index, cols_index)]`` from :func:`_expansion`'s runs; the same values."""
    expanded = np.repeat(p[:rows[0].size], rows[0], axis=0)
    expanded[rows[1]] = p[rows[2]]
    out = np.repeat(expanded[:, :cols[0].size], cols[0], axis=1)
    out[:, cols[1]] = expanded[:, cols[2]]
    return out


def pixel_levels(priorities: list[FloatArray], operators: WaveletOperators) -> np.ndarray:
    """(H, W) level ``l_p`` whose covering coefficient has the highest priority at each pixel.

    Examples
    --------
    A vertical edge between a dark and a bright half, with little noise: the pixels at the
    edge take the finest level, the smooth regions coarser ones (the paper's two cases,
    section 4):

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.priorities import coefficient_priorities, pixel_levels
    >>> from awr_denoise.wavelets import wavelet_operators
    >>> mean = np.where(np.arange(32) < 16, 0.1, 1.0)[None, :, None] * np.ones((32, 32, 3))
    >>> edge = SampleBuffer.from_moments(np.full((32, 32), 4), mean, np.full((32, 32, 3), 0.001))
    >>> ops = wavelet_operators(edge.shape)
    >>> pixel_levels(coefficient_priorities(edge, operators=ops), ops)[16, 10:22]
    array([1, 1, 1, 1, 0, 0, 0, 0, 1, 1, 1, 1])
    """
    return _levels(priorities, operators).astype(np.int64)


def _levels(priorities: list[FloatArray], operators: WaveletOperators) -> np.ndarray:
    """:func:`pixel_levels` as uint8, with in-place updates (the same comparisons, in order); a NaN
    priority never wins (at level 0 it counts as -inf)."""
    h, w = operators.shape
    best = priorities[0].copy()
    if np.isnan(best.max(initial=-np.inf)):  # one reduction finds a NaN (max propagates it)
        best[np.isnan(best)] = -np.inf
    level = np.zeros((h, w), np.uint8)
    better = np.empty((h, w), bool)
    step = np.empty((h, w), np.uint8)
    for k in range(1, len(priorities)):
        key = (operators.wavelet, operators.boundary, operators.levels, k)
        at_pixels = _gather(priorities[k], _expansion(h, *key), _expansion(w, *key))
        np.greater(at_pixels, best, out=better)
        # The last level that beat the best so far is the largest such k: a maximum, not a masked
        # copy. fmax takes the larger value where at_pixels is larger and ignores a NaN in it, as
        # the comparison does (best holds no NaN: level 0's were made -inf above).
        np.fmax(best, at_pixels, out=best)
        np.maximum(level, np.multiply(better, np.uint8(k), out=step), out=level)
    return level


def sampling_density(
    buffer: SampleBuffer,
    *,
    wavelet: str = DEFAULT_WAVELET,
    levels: int | None = None,
    domain: str | Domain = "log",
    boundary: str = "symmetric",
    level_weight: float = 1.0,
    noise_gain: FloatArray | None = None,
    absolute_above: float | None = DEFAULT_ABSOLUTE_ABOVE,
    executor: Executor | None = None,
    noise_model: str = DEFAULT_NOISE_MODEL,
) -> FloatArray:
    """(H, W) target sample density ``a_p = s_p * sqrt(g_p)`` (unnormalised).

    ``s_p`` is :func:`pooled_deviation` (the per-sample standard deviation in the error domain,
    pooled over 3x3 pixels, each pixel's level capped at ``absolute_above`` times the image's
    mean level). ``g_p``, the share of the pixel's noise that reconstruction leaves, is the noise
    model's (:mod:`awr_denoise.noise_gain`); ``n_p ~ s_p sqrt(g_p)`` spends a budget best:

    - ``"shrinkage"`` (the default): :func:`~awr_denoise.noise_gain.shrinkage_gain` of the same
      plane's transform, pooled over 3x3 pixels like ``s_p``;
    - ``"levels"``, the paper's: a region averaged over ``4^l`` pixels keeps ``4^-l`` of it,
      ``a_p = s_p * 2^(-level_weight * l_p)`` with ``l_p`` the winning level of
      :func:`pixel_levels` (``level_weight = 0``: per-pixel variance-driven sampling);
    - ``"reconstruction"``: ``noise_gain``, the share measured on a reconstruction
      (:attr:`~awr_denoise.Reconstruction.noise_gain`), pooled the same way; it is given with this
      model and with no other (refused, not ignored).

    With an ``executor`` (threads), ``s_p`` and the transform of the means are computed on it
    while the coefficient variances propagate in this thread: the same density, sooner on two
    cores (docs/performance.md, Threads).

    Examples
    --------
    The same edge as in :func:`pixel_levels`: the density peaks at the edge, and the dark
    half, noisier in relative terms, gets more than the bright one:

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.priorities import sampling_density
    >>> mean = np.where(np.arange(32) < 16, 0.1, 1.0)[None, :, None] * np.ones((32, 32, 3))
    >>> edge = SampleBuffer.from_moments(np.full((32, 32), 4), mean, np.full((32, 32, 3), 0.001))
    >>> density = sampling_density(edge)
    >>> row = density[16] / density[16].max()
    >>> int(np.argmax(row)), bool(row[:8].mean() > row[24:].mean())
    (14, True)

    A measured gain four times larger asks for twice the samples:

    >>> gain = np.where(np.arange(32) < 16, 0.1, 0.4)[:, None] * np.ones((32, 32))
    >>> flat = SampleBuffer.from_moments(np.full((32, 32), 4), np.ones((32, 32, 3)), np.full((32, 32, 3), 0.1))
    >>> density = sampling_density(flat, noise_gain=gain, noise_model="reconstruction")
    >>> round(float(density[28, 5] / density[3, 5]), 6)
    2.0
    """
    level_weight = _checks.real("level_weight", level_weight, minimum=0)
    executor = _checks.executor("executor", executor)
    noise_model = _checks.name("noise_model", noise_model, NOISE_MODELS)
    if noise_model == "reconstruction" and noise_gain is None:
        raise ValueError("noise_gain: noise_model='reconstruction' needs the measured gain (Reconstruction.noise_gain)")
    if noise_model != "reconstruction" and noise_gain is not None:
        raise ValueError(f"noise_gain: a measured gain needs noise_model='reconstruction', not {noise_model!r}")
    if noise_gain is not None:
        noise_gain = numeric("noise_gain", noise_gain).astype(np.float64)  # complex, bool, masked entries refused
        if noise_gain.shape != buffer.shape:
            raise ValueError(f"noise_gain: shape {noise_gain.shape} is not the buffer's {buffer.shape}")
    ops = wavelet_operators(buffer.shape, wavelet=wavelet, levels=levels, boundary=boundary)
    p = prepare(buffer, domain, luminance=True)  # once, for the deviation and the priorities
    plane = _plane(p)
    if not np.isfinite(plane[2].max(initial=0.0)):  # a finite variance the domain's derivative takes past 1.8e308
        raise ValueError(f"buffer: the per-sample variance of {int((~np.isfinite(plane[2])).sum())} pixel(s) is "
                         f"beyond float64 in the {p.domain.name} domain; sample it in domain='linear' (scaling "
                         "the radiance changes nothing: the domain's offset scales with it)")
    deviation = partial(pooled_deviation, buffer, domain, absolute_above=absolute_above, prepared=p)
    if noise_model == "shrinkage":
        # The gain takes the priorities' and levels' place; the plane is normalised as for them
        # (the shrinkage factors do not change when it is scaled, and its squares cannot overflow).
        pooled = None if executor is None else executor.submit(deviation)
        noise_gain = shrinkage_gain(*_transformed(*_normalised(plane)[0][:2], ops, None), ops)
        s_pooled = _checks.outcome(pooled, deviation, executor)
    elif noise_model == "reconstruction":
        s_pooled = deviation()
    if noise_gain is not None:
        # Pooled like s_p; a NaN or negative gain (none is expected) must not send samples nowhere.
        gain = np.nan_to_num(window_sum(noise_gain, 3) / 9.0, nan=1.0)
        s_pooled *= np.sqrt(np.maximum(gain, 0.0))
        return s_pooled
    if level_weight == 0:
        return deviation()
    pooled = None if executor is None else executor.submit(deviation)
    # Levels do not change when the plane is scaled: normalised, the priorities cannot overflow.
    prio = coefficient_priorities(buffer, domain=domain, operators=ops, plane=_normalised(plane)[0], executor=executor)
    level = _levels(prio, ops)
    s_pooled = _checks.outcome(pooled, deviation, executor)
    with np.errstate(under="ignore"):  # a large level_weight leaves coarse levels nothing
        # One power per level, looked up per pixel: the same values as the power of every pixel.
        factor = 2.0 ** (-level_weight * np.arange(ops.levels + 1))
        s_pooled *= factor[level]
        return s_pooled


def dropped_at_mean(density: FloatArray, count: CountArray, issued: CountArray) -> FloatArray:
    """``density`` with the pixels that were handed samples and returned none at the image's mean density.

    A renderer may drop every sample of a pixel (a NaN shader, a broken texture: ``nonfinite="drop"``).
    Ranked as it stands, on a neighbour's mean and one sample's pooled variance, such a pixel drew far more or
    far fewer samples than the average, round after round, where more samples bring nothing; at the mean, a
    pixel whose few samples all failed by chance still gets some (the samplers' ``ask()``, paper section 4).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.priorities import dropped_at_mean
    >>> density = np.array([[1.0, 3.0], [2.0, 9.0]])
    >>> count, issued = np.array([[4, 4], [4, 0]]), np.full((2, 2), 4)
    >>> dropped_at_mean(density, count, issued)
    array([[1., 3.],
           [2., 2.]])
    """
    dead = (count == 0) & (issued > 0)
    if not dead.any() or dead.all():
        return density
    density = np.array(density, dtype=np.float64)
    density[dead] = density[~dead].mean()
    return density
