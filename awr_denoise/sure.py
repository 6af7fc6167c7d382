"""A guard from Stein's unbiased risk estimate: keep only the part of a change that lowers the error.

A denoiser trades variance for bias. Where its bias outweighs what it removes, its result is
worse than the plain Monte Carlo mean: next to a small, very bright light, the rim pixels
borrow light from the light (relative error, which relMSE counts), and an isolated bright
pixel is pulled towards its darker surroundings (absolute error, which MSE counts).

For an estimate ``o`` made from the pixel means ``x`` (independent, variances ``v``) by a map
whose diagonal is ``L`` (each pixel's weight on its own mean, :mod:`awr_denoise.wiener`), the
blend ``x + lambda (o - x)`` with ``lambda`` fixed over a neighbourhood ``N`` has Stein's
unbiased risk estimate (Stein 1981, for Gaussian noise)

    SURE(lambda) = sum_N omega [v + 2 lambda v (L - 1) + lambda^2 (o - x)^2]

with weights ``omega``: 1 for the squared error (MSE), ``1 / (|o| + k)^2`` for the relative one
(relMSE, ``k`` like its epsilon). It is least at

    lambda = sum_N omega v (1 - L) / sum_N omega (o - x)^2,

clipped to [0, 1]; :func:`sure_blend` takes the smaller of the two criteria's ``lambda`` in
every window, so it keeps only as much of the change as lowers both kinds of error. Where the
estimate removes noise, ``(o - x)^2`` is about ``v (1 - L)`` and ``lambda`` is about 1; where it
adds bias, ``lambda`` falls towards 0 and the pixel returns towards its own mean. As the
samples grow, the blend tends to the mean wherever the estimate's bias does not vanish.

``lambda`` is a ratio of window sums, and their noise pulls it below 1 where the estimate is
right: with heavy-tailed radiance a window's sample variances often fall short of its means'
squared errors, so ``(o - x)^2`` there exceeds ``v (1 - L)`` and the guard puts back noise it
should have removed (measured on the tracer's global-illumination Cornell box at 32 spp with the
OIDN guide: in the 12% of pixels whose ``lambda`` fell below 0.9, the means' squared errors were
1.2x their variances; the true best ``lambda`` there averaged 0.93, the guard's 0.81;
docs/guides.md, "The guard's tolerance"). A ``tolerance`` ``t > 1`` keeps the change whole until
its squared size exceeds ``t`` times the noise it may remove,

    lambda = min(1, t sum_N omega v (1 - L) / sum_N omega (o - x)^2);

a biased change is still undone in proportion (bias ``b`` standard errors: ``lambda`` about
``t / (1 + b^2)``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import ndimage

from . import _checks
from ._typing import BoolArray, FloatArray
from ._window_sums import window_sum

__all__ = ["sure_blend", "DEFAULT_WINDOW", "DEFAULT_GUIDED_WINDOW", "DEFAULT_TOLERANCE", "DEFAULT_SPARED_BESIDE",
           "DEFAULT_GUIDED_TOLERANCE"]

DEFAULT_WINDOW = 9
"""Side of the square neighbourhood that shares one ``lambda``; ``reconstruct``'s ``guard_window``.

Wider windows measured better on most scenes and worse next to a small, very bright light
(docs/reconstruction.md, "The guard's window, measured"); 9 keeps the guard's protection there."""

DEFAULT_GUIDED_WINDOW = 17
"""``reconstruct``'s ``guard_window`` when a guide is given. A guided result is several times closer
to the truth than the means, so the noise of a 9x9 window's ``lambda`` costs it most: with the OIDN
guide 17 measured lower or level relMSE (within 0.2%) than 9 on all ten bundled and Mitsuba scenes
at 8-32 spp but one point (``glossy_glass`` at 16 spp, 1% higher; docs/guides.md), and
deliberately wrong guides stay below the plain mean's error (tests/test_guided.py)."""

DEFAULT_TOLERANCE = 1.2
"""``reconstruct``'s ``tolerance`` of :func:`sure_blend` without a guide, with :data:`DEFAULT_SPARED_BESIDE`.
Measured against 1 on both renderers (docs/reconstruction.md, "The guard's tolerance without a guide"):
lower relMSE on all ten bundled and Mitsuba scenes at 8-32 spp, MSE within 0.03 of 1's ratio to the
plain mean's."""

DEFAULT_SPARED_BESIDE = 10.0
"""``reconstruct``'s ``spared_beside`` without a guide: the relative criterion's tolerance stays 1 beside a
pixel ten times brighter, where a synthetic small light's rim measured above the plain mean's relMSE with
:data:`DEFAULT_TOLERANCE` alone (the same section)."""

DEFAULT_GUIDED_TOLERANCE = 1.2
"""``tolerance`` of :func:`sure_blend` when a guide is given (module docstring), no pixel spared: measured
on its own (docs/guides.md, "The guard's tolerance")."""


def sure_blend(estimate: FloatArray, mean: FloatArray, variance: FloatArray, leverage: FloatArray, *, k: float,
               window: int = DEFAULT_WINDOW, run: Callable | None = None,
               measured: BoolArray | None = None, tolerance: float | tuple[float, float] = 1.0,
               spared_beside: float | None = None) -> tuple[FloatArray, FloatArray]:
    """``mean + lambda (estimate - mean)`` with ``lambda`` from SURE (module docstring).

    Parameters
    ----------
    estimate
        (H, W, C) estimate ``o``, or (H, W): one plane (the reconstruction's luminance mode).
    mean, variance
        Pixel means ``x`` and the variances of the means ``v``, shaped as ``estimate``.
    leverage
        Diagonal ``L`` of the map that made ``estimate`` from ``mean``: shaped as ``estimate``, or (H, W).
    k
        Offset of the relative criterion's weights ``1 / (|o| + k)^2``; must be > 0.
    window
        Side of the neighbourhood sharing one ``lambda`` (odd, >= 1).
    run
        ``run(f, items)``, an executor's map: the two criteria's window sums on its threads (the
        same bits; two more whole arrays alive at once).
    measured
        (H, W) pixels whose ``mean`` measures them (``None``: all). The others (pixels without
        samples, their means copied from a neighbour: :func:`~awr_denoise.prepare.prepare`) have
        weight 0 in the sums, since the risk estimate needs unbiased means and a copy across an edge
        is off by the edge; and they keep ``estimate`` (``lambda`` 1): there is no mean of theirs to
        return to, and the copy is a worse guess than the estimate (docs/reconstruction.md, "Pixels
        without samples").
    tolerance
        How many times the noise it may remove a change's squared size may reach before it is
        undone in part (module docstring); >= 1. A pair gives the squared and the relative
        criterion their own (next to a small bright light the relative one's binds at the rim:
        docs/reconstruction.md, "The guard's tolerance without a guide").
    spared_beside
        With a relative tolerance above 1: ``r``, a pixel whose window holds one brighter than ``r``
        times its own ``|o| + k`` (a light's rim) keeps the relative criterion's tolerance at 1;
        ``None`` spares none.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        The blend and ``lambda``, shaped as ``estimate``.

    Notes
    -----
    Its own defaults are the strict guard (``tolerance=1``, no pixel spared). The reconstruction passes
    :data:`DEFAULT_TOLERANCE` and :data:`DEFAULT_SPARED_BESIDE` without a guide and
    :data:`DEFAULT_GUIDED_TOLERANCE` with a guide the gate trusts.

    Examples
    --------
    A flat image: an estimate that removes the noise is mostly kept (``lambda`` about
    ``1 - L`` on average, noisy over a window of 25 pixels), a biased one is mostly undone:

    >>> import numpy as np
    >>> from awr_denoise.sure import sure_blend
    >>> rng = np.random.default_rng(0)
    >>> truth = np.ones((32, 32, 1))
    >>> variance = np.full(truth.shape, 0.01)
    >>> mean = truth + 0.1 * rng.standard_normal(truth.shape)
    >>> lev = np.full(truth.shape, 0.05)                    # a smoothing that keeps 5% of each pixel
    >>> good, lam = sure_blend(truth, mean, variance, lev, k=0.1)
    >>> round(float(lam.mean()), 1)
    0.9
    >>> biased, lam = sure_blend(truth + 0.5, mean, variance, lev, k=0.1)
    >>> float(lam.max()) < 0.1, float(np.abs(biased - truth).mean()) < 0.1
    (True, True)
    """
    k = _checks.real("k", k, above=0)
    window = _checks.whole("window", window, minimum=1, maximum=1023)
    if spared_beside is not None:
        spared_beside = _checks.real("spared_beside", spared_beside, above=1)
    if isinstance(tolerance, tuple):
        if len(tolerance) != 2:
            raise ValueError(f"tolerance: a pair (squared, relative), got {len(tolerance)} values")
        squared_t, relative_t = (_checks.real("tolerance", t, minimum=1) for t in tolerance)
    else:
        squared_t = relative_t = _checks.real("tolerance", tolerance, minimum=1)
    if window % 2 == 0:  # type: ignore[operator]
        raise ValueError(f"window: must be odd, got {window}")
    o = np.asarray(estimate, np.float64)
    x = np.asarray(mean, np.float64)
    v = np.asarray(variance, np.float64)
    lev = np.asarray(leverage, np.float64)
    if lev.ndim == o.ndim - 1:
        lev = lev[..., None]
    unmeasured = None
    if measured is not None:
        unmeasured = ~np.asarray(measured, bool)
        if unmeasured.shape != o.shape[:2]:
            raise ValueError(f"measured: shape {unmeasured.shape} is not the image's {o.shape[:2]}")
    # Every full-size array below is float64 and the image may be 1080p or 4K: the sums are
    # pooled in place and buffers reused, so at most five whole arrays are alive (not ten).
    change = o - x

    def gain(tolerance: float) -> FloatArray:  # what the change may remove, in expectation: v (1 - L); times t
        out = 1.0 - lev
        if tolerance != 1.0:
            out *= tolerance
        if out.shape != v.shape:  # one leverage plane for every channel
            return v * out
        out *= v
        return out

    def share(num: FloatArray, den: FloatArray) -> FloatArray:
        """The sums' ratio clipped to [0, 1] (1 where it is undefined), into ``num``; ``den`` is spent."""
        if unmeasured is not None:  # no measurement, no term of the risk
            num[unmeasured] = 0.0
            den[unmeasured] = 0.0
        # Window sums of their own entries (._window_sums): a running sum carried a removed firefly's rounding
        # error along the line, and the share came out 0.2 off far from it.
        window_sum(num, window, out=num)
        window_sum(den, window, out=den)
        undefined = ~(den > 0)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            np.divide(num, den, out=num)
        num[undefined] = 1.0
        num[np.isnan(num) | np.isposinf(num)] = 1.0
        return np.clip(num, 0.0, 1.0, out=num)

    def relative_sums() -> tuple[FloatArray, FloatArray]:
        weights = np.abs(o)  # the relative criterion's weights 1 / (|o| + k)^2
        weights += k
        with np.errstate(over="ignore"):  # a k past 1e154 (a domain scale far above the image's): weights 0,
            np.square(weights, out=weights)  # the relative criterion undefined, the squared one decides
        np.divide(1.0, weights, out=weights)
        weighted_gain = gain(relative_t)
        if spared_beside is not None and relative_t != 1.0:
            # Dark pixels beside a light carry the relative criterion's weight, and the stages lend them its light:
            # a tolerance there let a rim through (docs/reconstruction.md, "The guard's tolerance without a guide").
            # A pixel's level: its largest |o| over the channels (luminance mode passes one plane, (H, W)), channel
            # by channel: numpy's reduction over a last axis of 3 took 5x as long at 1080p.
            level = np.abs(o[..., 0] if o.ndim == 3 else o)
            for c in range(1, o.shape[-1] if o.ndim == 3 else 1):
                np.maximum(level, np.abs(o[..., c]), out=level)
            brightest = ndimage.maximum_filter(level, size=window, mode="nearest")
            with np.errstate(over="ignore"):  # k near float64's top: Inf, no pixel spared (its weights are 0)
                level += k
                level *= spared_beside
            beside = brightest > level
            del level, brightest
            weighted_gain[beside] = (1.0 - lev[beside]) * v[beside]  # gain(1.0) there, without a whole array
        squared = change * change
        # Past float64 beside means of 0 (k tiny, a variance of 1e307): Inf, which share() reads.
        with np.errstate(over="ignore"):
            weighted_gain *= weights
            squared *= weights
        return weighted_gain, squared

    # The squared-error criterion's weights are 1: its sums need no product.
    if run is None:
        lam = share(gain(squared_t), change * change)
        np.minimum(lam, share(*relative_sums()), out=lam)
    else:
        pairs = [(gain(squared_t), change * change), relative_sums()]
        absolute, relative = run(lambda pair: share(*pair), pairs)
        del pairs
        lam = np.minimum(absolute, relative, out=absolute)
    if unmeasured is not None:
        lam[unmeasured] = 1.0
    change *= lam
    change += x
    return change, lam
