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
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from . import _checks
from ._typing import FloatArray

__all__ = ["sure_blend", "DEFAULT_WINDOW"]

DEFAULT_WINDOW = 9
"""Side of the square neighbourhood that shares one ``lambda`` (docs/reconstruction.md)."""


def sure_blend(estimate: FloatArray, mean: FloatArray, variance: FloatArray, leverage: FloatArray, *, k: float,
               window: int = DEFAULT_WINDOW) -> tuple[FloatArray, FloatArray]:
    """``mean + lambda (estimate - mean)`` with ``lambda`` from SURE (module docstring).

    Parameters
    ----------
    estimate
        (H, W, C) estimate ``o``.
    mean, variance
        (H, W, C) pixel means ``x`` and the variances of the means ``v``.
    leverage
        (H, W, C) or (H, W) diagonal ``L`` of the map that made ``estimate`` from ``mean``.
    k
        Offset of the relative criterion's weights ``1 / (|o| + k)^2``; must be > 0.
    window
        Side of the neighbourhood sharing one ``lambda`` (odd, >= 1).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        The blend and ``lambda`` (H, W, C).

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
    if window % 2 == 0:  # type: ignore[operator]
        raise ValueError(f"window: must be odd, got {window}")
    o = np.asarray(estimate, np.float64)
    x = np.asarray(mean, np.float64)
    v = np.asarray(variance, np.float64)
    lev = np.asarray(leverage, np.float64)
    if lev.ndim == o.ndim - 1:
        lev = lev[..., None]
    change = o - x
    gain = v * (1.0 - lev)  # what the change may remove, in expectation
    size = (window, window) + (1,) * (o.ndim - 2)

    def pooled(a: FloatArray) -> FloatArray:
        return ndimage.uniform_filter(a, size=size, mode="nearest")

    squared = change * change

    def share(num: FloatArray, den: FloatArray) -> FloatArray:
        num, den = pooled(num), pooled(den)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = np.where(den > 0, num / den, 1.0)
        return np.clip(np.nan_to_num(lam, nan=1.0, posinf=1.0), 0.0, 1.0)

    relative = 1.0 / (np.abs(o) + k) ** 2
    # The squared-error criterion's weights are 1: its sums need no product.
    lam = np.minimum(share(gain, squared), share(gain * relative, squared * relative))
    return x + lam * change, lam
