"""Domains in which wavelet coefficients are thresholded.

The paper thresholds pixel means in linear radiance (Eq. 11). On buffers with a high dynamic
range (a small bright light, a firefly) that smears the bright pixels' energy into dark
neighbours (docs/reconstruction.md, "Domains"). A variance-stabilising transform ``y = f(x)``
applied to the means first, with the variance carried through by the delta method
(``Var(y) ~ Var(x) f'(mean)^2``), and inverted after reconstruction, keeps Eq. 10-11 intact
while measuring error in relative terms.

Every transform here is odd (``f(-x) = -f(x)``), strictly increasing and defined for all
reals, so negative means are allowed. Offsets are relative to the image's mean absolute value
unless an absolute ``scale`` is given, which makes every domain scale-equivariant: scaling the
means by ``a`` and the variances by ``a^2`` scales the reconstruction by ``a``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from . import _checks
from ._typing import FloatArray

__all__ = ["Domain", "DOMAIN_NAMES", "resolve_domain"]

DOMAIN_NAMES = ("linear", "log", "gamma")

_SMALLEST = float(np.nextafter(0.0, 1.0))  # the smallest positive float64 (5e-324)
_LARGEST = float(np.finfo(np.float64).max)


def _log1p_ratio(a: FloatArray, k: float) -> FloatArray:
    """``log(1 + a / k)`` for ``a >= 0``, also where ``a / k`` passes float64 (a scale given far below
    the image's level): ``log(a) - log(k)`` there, ``a`` being that far above ``k``."""
    with np.errstate(over="ignore", divide="ignore"):
        out = np.log1p(np.divide(a, k))
        if np.isinf(out).any():
            out = np.where(np.isinf(out), np.log(a) - np.log(k), out)
    return out


def _k_expm1(k: float, t: FloatArray) -> FloatArray:
    """``k (exp(t) - 1)`` for ``t >= 0``, also where ``exp(t)`` passes float64 but the product does not;
    the largest float where the product itself would (the honest answer there)."""
    with np.errstate(over="ignore"):
        out = k * np.expm1(t)
        if np.isinf(out).any():
            out = np.where(np.isinf(out), np.minimum(np.exp(t + np.log(k)), _LARGEST), out)
    return out


@dataclass(frozen=True)
class Domain:
    """A variance-stabilising transform of the pixel means.

    Parameters
    ----------
    name
        ``"linear"`` (the paper, literally: identity), ``"log"``
        (``y = sign(x) log(1 + |x| / k)``, derivative ``1 / (|x| + k)``, so thresholds follow
        the *relative* error), or ``"gamma"`` (``y = sign(x) ((|x| + k)^(1/g) - k^(1/g))``).
    offset
        ``k`` relative to ``scale``; it sets where the log turns linear (dark pixels are judged
        by absolute error below ``k``, like relMSE's epsilon).
    gamma
        Exponent ``g`` of the ``"gamma"`` domain.
    scale
        Absolute reference level; ``None`` uses the mean absolute pixel value of the image
        being reconstructed. Give it explicitly to make tiles of one image agree.
    robust
        Firefly policy. The delta method needs ``f'`` at the true mean; by default it is taken
        at the pixel mean, which a firefly inflates, so the firefly's variance in the domain
        looks small and it survives. With ``robust=True`` ``f'`` is taken at whichever of the
        mean and the 3x3 median of the means has the smaller magnitude (``min(mean, median)``
        for non-negative images; negative spikes alike): isolated spikes get their full variance and are
        smoothed away. Measured on synthetic fireflies this lowers relMSE about 10x further, but
        it also smooths genuinely tiny bright features (a 1-pixel light) and made a small HDR
        source worse than the plain mean at 4 spp, so it is off by default
        (docs/reconstruction.md).

    Examples
    --------
    The log domain bound to an image whose mean absolute value is 2, so ``k = 0.1 * 2``:

    >>> import numpy as np
    >>> from awr_denoise import Domain
    >>> bound = Domain("log").bound(np.array([1.0, 3.0]))
    >>> bound.k
    0.2
    >>> x = np.array([0.0, 0.2, 2.0])
    >>> y = bound.forward(x)                     # log(1 + x / k)
    >>> np.round(y, 4), bool(np.allclose(bound.inverse(y), x))
    (array([0.    , 0.6931, 2.3979]), True)

    Variances are carried by the delta method, ``Var(x) / (|x| + k)^2``: the same absolute
    noise counts for much less next to a bright pixel (relative error):

    >>> np.round(bound.variance(np.array([0.2, 2.0]), np.array([0.01, 0.01])), 5)
    array([0.0625 , 0.00207])
    >>> Domain("linear").bound(x).forward(x)     # the paper's domain: the identity
    array([0. , 0.2, 2. ])
    """

    name: str = "log"
    offset: float = 0.1
    gamma: float = 2.2
    scale: float | None = None
    robust: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or self.name not in DOMAIN_NAMES:
            raise ValueError(f"domain: {self.name!r} is not one of {', '.join(DOMAIN_NAMES)}")
        _checks.real("domain offset", self.offset, above=0)
        _checks.real("domain gamma", self.gamma, minimum=1)
        _checks.real("domain scale", self.scale, above=0, none=True)
        _checks.flag("domain robust", self.robust)

    def bound(self, mean: FloatArray) -> _BoundDomain:
        """Fix the absolute offset for one image (``k = offset * scale``).

        Examples
        --------
        >>> import numpy as np
        >>> from awr_denoise import Domain
        >>> mean = np.array([[1.0, 3.0]])
        >>> Domain("log").bound(mean).k, Domain("log", offset=0.5, scale=10.0).bound(mean).k
        (0.2, 5.0)
        """
        if self.name == "linear":
            return _BoundDomain(self, 1.0)
        # Means near the smallest floats (1e-310) are valid: k may underflow, never to 0.
        scale = self.resolved_scale(mean)
        return _BoundDomain(self, max(self.offset * scale, _SMALLEST), scale)

    def resolved_scale(self, mean: FloatArray) -> float:
        """The absolute reference level used for ``mean``: :attr:`scale`, or the image's own.

        Tiles of one image agree with the whole image when they are given
        ``dataclasses.replace(domain, scale=domain.resolved_scale(whole_image_mean))``.

        Examples
        --------
        >>> import dataclasses
        >>> import numpy as np
        >>> from awr_denoise import Domain
        >>> image = np.array([[1.0, -3.0], [0.0, 4.0]])
        >>> Domain("log").resolved_scale(image)      # mean absolute value
        2.0
        >>> tile_domain = dataclasses.replace(Domain("log"), scale=Domain("log").resolved_scale(image))
        >>> tile_domain.resolved_scale(image[:1, :1])  # a tile keeps the whole image's level
        2.0
        """
        scale = self.scale
        if scale is None:
            magnitude = np.abs(mean)
            top = float(magnitude.max()) if magnitude.size else 0.0
            if np.isfinite(top) and top > 0:
                # Normalised first: the plain mean of values near the float64 limit overflows.
                if magnitude.dtype == np.float64:
                    magnitude /= top  # in place: the same values as magnitude / top, one array fewer
                else:
                    magnitude = magnitude / top
                scale = float(np.mean(magnitude)) * top
            else:
                scale = 0.0
            if not np.isfinite(scale) or scale <= 0:
                # An all-zero image: any positive k gives the same (zero) result.
                scale = 1.0
        return float(scale)


@dataclass(frozen=True)
class _BoundDomain:
    domain: Domain
    k: float
    scale: float | None = None  # the level k was fixed from (None: linear), kept so it is not computed again

    def forward(self, x: FloatArray) -> FloatArray:
        name, k = self.domain.name, self.k
        if name == "linear":
            return np.array(x, dtype=np.float64)
        a = np.abs(x)
        if name == "log":
            if not isinstance(a, np.ndarray) or a.dtype != np.float64:
                return np.sign(x) * _log1p_ratio(np.asarray(a, dtype=np.float64), k)
            # In place (the same operations and values as the line above, fewer whole-image arrays).
            with np.errstate(over="ignore"):
                a /= k
            np.log1p(a, out=a)
            if a.size and not np.isfinite(a.max()):  # |x| / k past float64 (a scale given far below the
                a = _log1p_ratio(np.abs(x), k)  # image's); a NaN, kept as NaN, must not hide an Inf beside it
            sign = np.sign(x)
            sign *= a
            return sign
        p = 1.0 / self.domain.gamma
        # (a + k)^p - k^p written as k^p (exp(p log(1 + a / k)) - 1): the difference cancelled to
        # nothing for pixels far below k (a light 1e18 times the background: the background was 3
        # or -288), and a + k overflowed for means near 1.7e308 (a red-team pass).
        return np.sign(x) * _k_expm1(k**p, p * _log1p_ratio(np.asarray(a, dtype=np.float64), k))

    def derivative(self, x: FloatArray) -> FloatArray:
        name, k = self.domain.name, self.k
        if name == "linear":
            return np.ones_like(x, dtype=np.float64)
        a = np.abs(x)
        if name == "log":
            with np.errstate(over="ignore"):  # Inf below ~1e-308: callers divide by it
                if not isinstance(a, np.ndarray) or a.dtype != np.float64:
                    return 1.0 / (a + k)
                a += k  # in place: the values of 1.0 / (a + k)
                if a.size and not np.isfinite(a.max()):  # |x| + k past float64 (means near 1.7e308): halved
                    a = np.abs(x) * 0.5 + k * 0.5
                    return np.divide(0.5, a, out=a)
                return np.divide(1.0, a, out=a)
        p = 1.0 / self.domain.gamma
        # p (a + k)^(p - 1) as p exp((p - 1) (log k + log(1 + a / k))): a + k overflows near 1.7e308.
        with np.errstate(over="ignore", under="ignore"):
            return p * np.exp((p - 1.0) * (np.log(k) + _log1p_ratio(np.asarray(a, dtype=np.float64), k)))

    def inverse(self, y: FloatArray) -> FloatArray:
        name, k = self.domain.name, self.k
        if name == "linear":
            return np.array(y, dtype=np.float64)
        a = np.abs(y)
        if name == "log":
            # expm1 overflows past ~709 where k times it may not (a k far below 1); past float64 the
            # largest finite float is the honest answer.
            return np.sign(y) * _k_expm1(k, np.asarray(a, dtype=np.float64))
        p = 1.0 / self.domain.gamma
        # ((a + k^p)^(1/p) - k) as k (exp(log(1 + a / k^p) / p) - 1): the forward's form, no cancellation.
        return np.sign(y) * _k_expm1(k, _log1p_ratio(np.asarray(a, dtype=np.float64), k**p) / p)

    def variance(self, mean: FloatArray, variance: FloatArray) -> FloatArray:
        """Delta-method variance in the transformed domain, ``Var(x) f'(mean)^2``."""
        at = mean
        if self.domain.robust and mean.ndim >= 2 and min(mean.shape[:2]) >= 3:
            size = (3, 3) + (1,) * (mean.ndim - 2)
            median = ndimage.median_filter(mean, size=size, mode="nearest")
            # The smaller *magnitude* (every domain is odd): min(mean, median) for non-negative
            # images, and a negative spike is treated like a positive one.
            at = np.where(np.abs(median) < np.abs(mean), median, mean)
        d = self.derivative(at)
        with np.errstate(over="ignore", invalid="ignore"):
            out = variance * d
            out *= d  # (variance * d) * d, in place
            # max() is NaN or Inf exactly when some value is (out >= 0 otherwise): no mask needed.
            if self.domain.name == "log" and out.size and not np.isfinite(out.max()):
                # f' overflows for means near the smallest floats (1e-310); its inverse does
                # not: Var / (|x| + k)^2 there (elsewhere the product, bit for bit as before).
                s = np.abs(at) + self.k
                out = np.where(np.isfinite(out), out, variance / s / s)
        np.copyto(out, 0.0, where=variance == 0)
        return out


def resolve_domain(domain: str | Domain) -> Domain:
    """Turn a domain name or :class:`Domain` into a :class:`Domain` (names use the defaults).

    Examples
    --------
    >>> from awr_denoise import Domain
    >>> from awr_denoise.domains import resolve_domain
    >>> resolve_domain("gamma")
    Domain(name='gamma', offset=0.1, gamma=2.2, scale=None, robust=False)
    >>> resolve_domain(Domain("log", robust=True)).robust
    True
    """
    if isinstance(domain, Domain):
        return domain
    if isinstance(domain, str):
        return Domain(domain)
    raise TypeError(f"domain: expected a name ({', '.join(DOMAIN_NAMES)}) or a Domain, got {_checks.described(domain)}")
