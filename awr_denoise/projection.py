"""The pixel means moved towards a guide, coefficient by coefficient, within their confidence intervals.

A guide image ``g`` (a neural denoiser's output, say) and the pixel means ``x`` are compared on
the stationary transform (:class:`~awr_denoise.stationary.StationaryTransform`): for every
coefficient, ``D = G - X`` is how far the guide lies from the means, and ``Delta`` (Eq. 10 of the
paper, exact) how far the means may lie from the truth. The projection takes each coefficient to
the point of ``[X - r Delta, X + r Delta]`` nearest to the guide's,

    X + clip(G - X, -r Delta, r Delta),

in every detail band and, by default, in the scale band too (``scale_band=False`` keeps the
means' scale band, and with it, in the linear domain, the image sum). Where the guide is within
``r`` standard errors of the means it is followed exactly (its noise-free detail replaces the
noisy one); where the samples contradict it, the coefficient stops at the interval's edge. The
scale band's ``Delta`` averages many pixels' variances and is small, except where a few pixels
hold very large ones: the fireflies of a caustic, whose energy a denoiser spreads or drops and
which the means' scale band would otherwise keep as a bright blob. Measured with the OIDN guide
(docs/guides.md), projecting the scale band lowered relMSE by 12% on the glossy scene with caustics
(9-17% in earlier runs), by 2-3% on two more and changed the other seven by at most 1.2%; the guided
reconstruction restores the exact image mean afterwards (:func:`~awr_denoise.finishing.restore_mean`). As the samples grow, ``Delta`` falls
and the result tends to the means whatever the guide says. It runs in the domain ``x / w``,
``w = (|g| + k)^alpha`` (like :func:`~awr_denoise.wiener.relative_wiener`'s, the weights from the
guide): ``alpha = 1`` makes the intervals relative to the signal, ``alpha = 0`` absolute. In the
guided reconstruction the default 0.5 and 1 measured within 1% in relMSE at 32 spp on every scene
of docs/guides.md ("What else was tried"), 1 with up to 3% more MSE.

Because the synthesis is linear, the result is ``x + w * sum_b S_b(clip(D_b, -r Delta_b, r Delta_b))``:
only the guide's difference from the means and the variances are transformed. Each pixel's
weight on its own mean (the map's diagonal, with the clipping pattern held fixed) is
``1 - sum_b (u_b * h_b)``, ``u_b`` the band's unclipped coefficients (those follow the guide,
slope 0) and ``h_b`` its share of the diagonal (:meth:`StationaryTransform.diagonal`): the SURE
guard (:mod:`awr_denoise.sure`) needs it.
"""

from __future__ import annotations

import numpy as np

from . import _checks
from ._typing import FloatArray
from .stationary import StationaryTransform
from .wiener import WienerResult, _last, _planes

__all__ = ["project", "DEFAULT_RADIUS", "DEFAULT_EXPONENT"]

DEFAULT_RADIUS = 3.0
"""Half-width of the confidence interval, in standard errors ``Delta``. In the guided reconstruction 2
and 3 measured within 2% of each other at 32 spp on every scene of docs/guides.md ("What else was
tried"): the SURE guard that follows takes back what a wide interval lets through."""

DEFAULT_EXPONENT = 0.5
"""``alpha`` of the domain's weights ``(|guide| + k)^alpha`` (module docstring)."""


def project(transform: StationaryTransform, x: FloatArray, variance: FloatArray, guide: FloatArray, *,
            offset: float, radius: float = DEFAULT_RADIUS, exponent: float = DEFAULT_EXPONENT,
            extra: FloatArray | None = None, leverage: bool = False, scale_band: bool = True) -> WienerResult:
    """Move every detail coefficient of ``x`` towards ``guide``'s, by at most ``radius`` standard errors.

    Parameters
    ----------
    transform
        The stationary transform of the image's shape.
    x
        (H, W, C) pixel means.
    variance
        (H, W, C) variances of the means (independent pixels).
    guide
        (H, W, C) guide image.
    offset
        ``k`` of the domain's weights ``w = (|guide| + k)^exponent``; must be > 0.
    radius
        ``r``, the interval's half-width in standard errors; >= 0 (0 returns ``x``).
    exponent
        ``alpha`` in [0, 1] of the domain's weights.
    extra
        Optional (N, H, W, C) planes taken through the same linear map (clipping pattern held
        fixed): probes of its variance.
    leverage
        Also return the map's diagonal (one more FFT per band).
    scale_band
        Project the scale band as well (the default); ``False`` keeps the means' scale band.

    Returns
    -------
    WienerResult
        The projected image, the filtered ``extra`` and the leverage when asked for.

    Examples
    --------
    A step edge under noise. A clean guide is within the noise of the means and is followed:
    the error falls 8-fold with the means' scale band kept, almost to nothing when the scale band
    is projected too (the default). A flat guide contradicts the samples at the edge: the edge is
    kept, and the result is still no further from the truth than the means:

    >>> import numpy as np
    >>> from awr_denoise.stationary import StationaryTransform
    >>> from awr_denoise.projection import project
    >>> clean = np.ones((32, 32, 1))
    >>> clean[:, 16:] = 2.0
    >>> v = np.full(clean.shape, 0.01)
    >>> x = clean + 0.1 * np.random.default_rng(0).standard_normal(clean.shape)
    >>> t = StationaryTransform((32, 32), levels=3)
    >>> rms = lambda a: round(float(np.sqrt(np.mean((a - clean) ** 2))), 3)
    >>> details_only = project(t, x, v, clean, offset=0.1, scale_band=False).image
    >>> rms(x), rms(details_only), rms(project(t, x, v, clean, offset=0.1).image)
    (0.097, 0.012, 0.001)
    >>> flat = np.full(clean.shape, 1.5)
    >>> rms(flat), rms(project(t, x, v, flat, offset=0.1).image)
    (0.5, 0.089)

    The leverage is near 0 where the guide is followed in every band, higher where it is refused
    (with the scale band kept, the means' share through it stays):

    >>> lev = project(t, x, v, clean, offset=0.1, leverage=True).leverage
    >>> bool(abs(lev.min()) < 1e-3 and lev.max() < 0.3)
    True
    >>> lev = project(t, x, v, clean, offset=0.1, leverage=True, scale_band=False).leverage
    >>> bool(0 < lev.min() and lev.max() < 0.3)
    True
    """
    t = transform
    _checks.flag("scale_band", scale_band)
    offset = _checks.real("offset", offset, above=0)
    radius = _checks.real("radius", radius, minimum=0)
    exponent = _checks.real("exponent", exponent, minimum=0, maximum=1)
    if np.shape(x) != np.shape(variance) or np.shape(x) != np.shape(guide) or np.ndim(x) != 3:
        raise ValueError(f"x, variance, guide: expected three (H, W, C) arrays of one shape, got {np.shape(x)}, "
                         f"{np.shape(variance)} and {np.shape(guide)}")
    w = np.abs(_planes(guide, t.dtype, copy=True))
    w += max(np.asarray(offset, t.dtype), np.finfo(t.dtype).tiny)
    if exponent != 1.0:
        w **= exponent
    d = _planes(guide, t.dtype, copy=True)
    d -= _planes(x, t.dtype)
    d /= w
    vs = _planes(variance, t.dtype, copy=True)
    vs /= w
    vs /= w  # not w * w: that over/underflows first
    es = None
    if extra is not None:
        es = _planes(extra, t.dtype, copy=True)
        es /= w
    spec_d, spec_v = t.spectrum(d), t.spectrum(vs)
    del d, vs
    spec_e = None if es is None else t.spectrum(es)
    total = np.zeros_like(spec_d)
    total_e = None if spec_e is None else np.zeros_like(spec_e)
    total_u = np.zeros_like(spec_d) if leverage else None
    work = np.empty(spec_d.shape[-2:], spec_d.dtype)
    coeff, bound, unclipped = (np.empty(t.shape, t.dtype) for _ in range(3))
    for b in range(0 if scale_band else 1, len(t.bands)):
        # Each band's transfer functions once (above ~512x512 they are built on every call).
        a, s, squared = t.analysis(b), t.synthesis(b), t.squared(b)
        diagonal = None if total_u is None else t.diagonal(b)
        for c in range(spec_d.shape[0]):
            t.planes(np.multiply(spec_v[c], squared, out=work), overwrite=True, out=bound)
            np.maximum(bound, 0.0, out=bound)  # FFT rounding around exact zeros
            np.sqrt(bound, out=bound)
            bound *= radius
            t.planes(np.multiply(spec_d[c], a, out=work), overwrite=True, out=coeff)
            np.less_equal(np.abs(coeff), bound, out=unclipped, casting="unsafe")
            np.clip(coeff, -bound, bound, out=coeff)
            total[c] += np.multiply(t.spectrum(coeff, out=work), s, out=work)
            if total_u is not None:
                total_u[c] += np.multiply(t.spectrum(unclipped, out=work), diagonal, out=work)
            if spec_e is not None:
                for n in range(spec_e.shape[0]):  # the probes lose what the guide replaces
                    t.planes(np.multiply(spec_e[n, c], a, out=work), overwrite=True, out=coeff)
                    coeff *= unclipped
                    total_e[n, c] -= np.multiply(t.spectrum(coeff, out=work), s, out=work)  # type: ignore[index]
    # The moves back in the caller's layout, added to the means in float64: where every
    # coefficient is clipped to zero width (no variance) the result is the means to the bit.
    moves = t.planes(total, overwrite=True)
    moves *= w
    out_e = None
    if total_e is not None:
        out_e = t.planes(total_e, overwrite=True)
        out_e *= w
        out_e = _last(out_e, 3) + np.asarray(extra, np.float64)
    lev = None if total_u is None else 1.0 - _last(t.planes(total_u, overwrite=True), 3)
    return WienerResult(_last(moves, 3) + np.asarray(x, np.float64), out_e, lev)
