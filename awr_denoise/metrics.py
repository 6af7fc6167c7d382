"""Image error metrics for HDR renders (docs/benchmarks.md, its opening paragraphs).

relMSE is the mean over pixels and channels of ``(x - r)^2 / (r^2 + eps)`` with ``eps = 0.01``
(the usual damping, reported with every figure); SSIM is computed on a tonemapped image. Neither sees a
change of exposure spread thinly over the image, which :func:`mean_error` does: a denoiser must keep the
image mean (the reconstruction issue's bound: within 0.5%), and the three are judged together.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from . import _checks
from ._arrays import numeric
from ._typing import FloatArray

__all__ = ["mse", "relmse", "mean_error", "psnr", "ssim", "tonemap", "RELMSE_EPSILON", "METRICS", "HIGHER_IS_BETTER"]

RELMSE_EPSILON = 0.01


def _pair(x: FloatArray, reference: FloatArray) -> tuple[FloatArray, FloatArray]:
    a = numeric("image", x).astype(np.float64, copy=False)
    b = numeric("reference", reference).astype(np.float64, copy=False)
    if a.shape != b.shape:
        raise ValueError(f"reference: shape {b.shape} does not match image {a.shape}")
    if a.size == 0:
        raise ValueError("image: empty")
    for name, arr in (("image", a), ("reference", b)):
        if not np.isfinite(arr).all():
            raise ValueError(f"{name}: {int((~np.isfinite(arr)).sum())} value(s) are NaN or Inf")
    return a, b


def mse(x: FloatArray, reference: FloatArray) -> float:
    """Mean squared error over pixels and channels.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.metrics import mse
    >>> mse(np.array([1.0, 2.0]), np.array([1.0, 4.0]))
    2.0
    """
    a, b = _pair(x, reference)
    with np.errstate(over="ignore"):  # Inf: an error beyond float64 (values near 1e300)
        return float(np.mean((a - b) ** 2))


def relmse(x: FloatArray, reference: FloatArray, eps: float = RELMSE_EPSILON) -> float:
    """Relative MSE, ``mean((x - r)^2 / (r^2 + eps))``.

    Examples
    --------
    The same absolute error of 0.1 weighs 1 on a black reference pixel (``eps = 0.01``
    damps the division) and about 1% on a white one:

    >>> import numpy as np
    >>> from awr_denoise.metrics import relmse
    >>> round(relmse(np.array([0.1]), np.array([0.0])), 6), round(relmse(np.array([1.1]), np.array([1.0])), 6)
    (1.0, 0.009901)
    """
    a, b = _pair(x, reference)
    eps = _checks.real("eps", eps, minimum=0)
    with np.errstate(over="ignore", under="ignore", divide="ignore", invalid="ignore"):
        d = a - b
        num, den = d * d, b * b + eps
        # eps = 0 is exact where the reference is not 0; where it is, an exact pixel costs 0 and any
        # other an infinite relative error.
        ratio = np.where(d == 0, 0.0, num / den)
        # Values near 1e300 overflow the squares and values near 1e-170 underflow them (an error of 1e-170
        # read as none), where the ratio itself need do neither: those pixels again without the squares.
        black = (b == 0) & (eps == 0)
        redo = (d != 0) & ((num == 0) | (den == 0) | ~np.isfinite(ratio)) & ~black
        if redo.any():
            ratio[redo] = (d[redo] / np.hypot(b[redo], math.sqrt(eps))) ** 2
        ratio[black & (d != 0)] = np.inf
        return float(np.mean(ratio))


def mean_error(x: FloatArray, reference: FloatArray) -> float:
    """The largest relative change of a channel's image mean, ``max_c |mean(x_c) / mean(r_c) - 1|``.

    An image of shape (H, W, C) has C channels; any other shape is one. Where a channel of the
    reference averages to 0 the error is 0 if the image's does too, else ``inf``. The means are
    taken of the values divided by the channel's largest magnitude, so that images near 1e308 do not
    overflow their sums nor those near 1e-320 lose their digits.

    Examples
    --------
    A constant error of 0.01 on a reference of 0.5 is 2% of its mean; opposite errors that cancel
    leave the mean, which relMSE and MSE would not show:

    >>> import numpy as np
    >>> from awr_denoise.metrics import mean_error
    >>> round(mean_error(np.full((2, 2, 3), 0.51), np.full((2, 2, 3), 0.5)), 12)
    0.02
    >>> mean_error(np.array([[0.4, 0.6]]), np.array([[0.5, 0.5]]))
    0.0
    """
    a, b = _pair(x, reference)
    channels = a.shape[-1] if a.ndim == 3 else 1
    a, b = a.reshape(-1, channels), b.reshape(-1, channels)
    top = np.maximum(np.max(np.abs(a), axis=0), np.max(np.abs(b), axis=0))
    scale = np.where(top > 0, top, 1.0)
    mx, mr = np.mean(a / scale, axis=0), np.mean(b / scale, axis=0)
    # A subnormal reference mean against a normal image overflows the ratio: inf, as a black reference gives.
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = np.where(mx == mr, 0.0, np.abs(mx - mr) / np.abs(mr))
    return float(np.max(ratio))


def tonemap(x: FloatArray, *, exposure: float = 0.0) -> FloatArray:
    """Exposure, clamp to [0, 1] and the sRGB transfer curve: what a viewer shows.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.metrics import tonemap
    >>> np.round(tonemap(np.array([0.0, 0.001, 0.18, 1.0, 4.0])), 4)
    array([0.    , 0.0129, 0.4614, 1.    , 1.    ])
    >>> np.round(tonemap(np.array([0.18]), exposure=1.0), 4)        # one stop brighter
    array([0.6343])
    """
    exposure = _checks.real("exposure", exposure)
    x = numeric("x", x).astype(np.float64)
    if np.isnan(x).any():  # +-Inf is a value a viewer clips; NaN is none
        raise ValueError(f"x: {int(np.isnan(x).sum())} value(s) are NaN")
    with np.errstate(over="ignore", invalid="ignore"):  # 2**1023 already saturates every positive float
        v = np.clip(x * 2.0 ** min(exposure, 1023.0), 0.0, 1.0)
    if np.isinf(x).any():  # at an exposure below -1074 the scale is 0, and inf * 0 is NaN: +inf is white still
        v[np.isposinf(x)], v[np.isneginf(x)] = 1.0, 0.0
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1 / 2.4) - 0.055)


def psnr(x: FloatArray, reference: FloatArray, *, peak: float | None = None) -> float:
    """Peak signal-to-noise ratio in dB; ``peak`` defaults to the reference's maximum.

    Equal images give ``inf``; an all-zero reference without ``peak`` gives ``-inf`` (no peak to
    compare the error with): the limits of the formula, not a failure.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.metrics import psnr
    >>> round(float(psnr(np.array([0.9, 1.0]), np.array([1.0, 1.0]))), 4)   # 10 log10(1 / 0.005)
    23.0103
    >>> psnr(np.ones(2), np.ones(2))
    inf
    """
    a, b = _pair(x, reference)
    peak = _checks.real("peak", peak, above=0, none=True)
    top = float(np.max(np.abs(b))) if peak is None else peak
    with np.errstate(over="ignore"):
        d = a - b
    # Finite values whose difference passes float64 (1.7e308 against -1.7e308): halved first, exactly.
    halved = not np.isfinite(d).all()
    if halved:
        d = a * 0.5 - b * 0.5
    largest = float(np.max(np.abs(d)))
    if largest == 0:
        return float("inf")
    if top == 0:
        return float("-inf")
    # In logarithms, the error divided by its largest term: the squares overflow near 1e300 and underflow
    # near 1e-170 (an error read as none), the logarithm of the scaled mean does neither.
    with np.errstate(under="ignore"):
        scaled = float(np.mean((d / largest) ** 2))
    return 20.0 * (np.log10(top) - np.log10(largest) - halved * np.log10(2.0)) - 10.0 * np.log10(scaled)


def ssim(x: FloatArray, reference: FloatArray, *, exposure: float = 0.0, sigma: float = 1.5) -> float:
    """Structural similarity (Wang et al. 2004) of the tonemapped images, averaged over channels.

    Gaussian-weighted local statistics with ``sigma = 1.5`` and the usual constants
    ``(0.01 L)^2``, ``(0.03 L)^2`` for the [0, 1] range.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.metrics import ssim
    >>> ramp = np.tile(np.linspace(0.0, 1.0, 16), (16, 1))[..., None] * np.ones(3)
    >>> ssim(ramp, ramp)
    1.0
    >>> noisy = ramp + 0.1 * np.random.default_rng(0).standard_normal(ramp.shape)
    >>> 0.5 < ssim(noisy, ramp) < 0.8
    True
    """
    a, b = _pair(x, reference)
    if a.ndim not in (2, 3):
        raise ValueError(f"image: expected (H, W) or (H, W, C), got shape {a.shape}")
    sigma = _checks.real("sigma", sigma, above=0, maximum=1e4)
    a, b = tonemap(a, exposure=exposure), tonemap(b, exposure=exposure)
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    c1, c2 = 0.01**2, 0.03**2
    scores = []
    for c in range(a.shape[2]):
        f = lambda z: ndimage.gaussian_filter(z, sigma, mode="reflect")  # noqa: E731
        p, q = a[..., c], b[..., c]
        mu_p, mu_q = f(p), f(q)
        var_p = f(p * p) - mu_p**2
        var_q = f(q * q) - mu_q**2
        cov = f(p * q) - mu_p * mu_q
        s = ((2 * mu_p * mu_q + c1) * (2 * cov + c2)) / ((mu_p**2 + mu_q**2 + c1) * (var_p + var_q + c2))
        scores.append(float(np.mean(s)))
    return float(np.mean(scores))


METRICS = {"relmse": relmse, "mse": mse, "mean_error": mean_error, "psnr": psnr, "ssim": ssim}
"""The metrics by name, as the command line and the benchmark report them."""

HIGHER_IS_BETTER = frozenset({"psnr", "ssim"})
"""Metrics for which a larger value is the better image."""
