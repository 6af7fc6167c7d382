"""Reconstruction by variance-weighted wavelet soft thresholding (paper section 5, Eq. 10-11).

Each wavelet coefficient ``W~`` of the pixel-mean image is shrunk towards zero by ``c_s``
times its own standard error ``Delta = sqrt(<v, Psi^2>)`` (Eq. 10):

    W = sign(W~) * max(0, |W~| - c_s * Delta)            (Eq. 11)

and the image is synthesised back. Each coefficient takes the value nearest zero inside its
confidence interval, so the result is "the smoothest image consistent with the samples".
The coarsest scale band is kept as it is; every detail level and band is thresholded.
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from . import _checks
from ._typing import FloatArray
from .buffers import SampleBuffer
from .channels import luminance_weights
from .domains import Domain
from .prepare import prepare
from .wavelets import DEFAULT_WAVELET, coefficient_variance, forward, inverse, wavelet_operators

__all__ = ["reconstruct", "reconstruct_detailed", "Reconstruction", "MODES", "DEFAULT_C_S", "DEFAULT_DOMAIN",
           "DEFAULT_MODE", "DEFAULT_PIXEL_CLAMP"]

MODES = ("channels", "luminance")
"""``"channels"``: each channel thresholded with its own Delta; ``"luminance"``: thresholds
decided on luminance, the same shrink factor applied to every channel (hue-preserving)."""

DEFAULT_MODE = MODES[0]
"""Default mode: every channel thresholded with its own Delta."""

DEFAULT_C_S = 1.0
"""Default smoothing constant ``c_s`` of Eq. 11: one standard error."""

DEFAULT_DOMAIN = "log"
"""Default thresholding domain; chosen by measurement (docs/reconstruction.md)."""

_MAX_PROBES = 100_000  # each probe is a transform pair per channel; more is never meant

DEFAULT_PIXEL_CLAMP = 2.5
"""Default pixel confidence clamp in standard errors; chosen by measurement (docs/reconstruction.md)."""


@dataclass(frozen=True, eq=False)
class Reconstruction:
    """Result of :func:`reconstruct_detailed`.

    Attributes
    ----------
    image
        (H, W, C) reconstructed image.
    thresholds
        Per channel, ``c_s * Delta`` in :func:`~awr_denoise.wavelets.forward`'s layout
        (detail bands only: ``[None, (tH, tV, tD)_L, ..., (tH, tV, tD)_1]``), in the
        thresholding domain.
    fraction_zeroed
        Fraction of detail coefficients set to zero, over all channels.
    variance
        (H, W, C) estimated variance of the output (see Notes of :func:`reconstruct_detailed`).
    levels
        Decomposition depth used.
    domain
        The domain the coefficients were thresholded in.
    parameters
        The settings that made it, resolved (``c_s``, ``wavelet``, ``levels``, ``domain``
        name, ``mode``, ``boundary``, ``pixel_clamp``): what a file's provenance records.

    Examples
    --------
    A flat grey image under noise of one standard error per pixel (8 samples of variance 0.08):

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer, reconstruct_detailed
    >>> rng = np.random.default_rng(1)
    >>> mean = 0.5 + 0.1 * rng.standard_normal((32, 32, 3))
    >>> buffer = SampleBuffer.from_moments(np.full((32, 32), 8), mean, np.full((32, 32, 3), 0.08))
    >>> result = reconstruct_detailed(buffer, variance_probes=4)
    >>> result.image.shape, result.levels, result.domain.name
    ((32, 32, 3), 2, 'log')
    >>> round(result.fraction_zeroed, 2)              # pure noise: most details are zeroed
    0.69
    >>> bool((result.variance < buffer.variance_of_mean()).all())
    True
    >>> {key: result.parameters[key] for key in ("c_s", "wavelet", "pixel_clamp")}
    {'c_s': 1.0, 'wavelet': 'bior4.4', 'pixel_clamp': 2.5}
    """

    image: FloatArray
    thresholds: list
    fraction_zeroed: float
    variance: FloatArray
    levels: int
    domain: Domain
    parameters: dict = field(default_factory=dict)


def _check_c_s(c_s: float) -> float:
    return _checks.real("c_s", c_s, minimum=0)  # type: ignore[return-value]


def _soft(coeff: FloatArray, threshold: FloatArray) -> FloatArray:
    """Eq. 11: ``sign(W~) max(0, |W~| - t)``."""
    return np.sign(coeff) * np.maximum(np.abs(coeff) - threshold, 0.0)


class _PlaneResult(NamedTuple):
    coeffs: list  # thresholded coefficients
    thresholds: list  # c_s * Delta per detail band (None in luminance-driven channels)
    factors: list  # shrink factor of every detail coefficient (0 where zeroed)
    zeroed: int
    total: int


def _threshold_plane(y: FloatArray, var_y: FloatArray, c_s: float, ops, shrink_from=None) -> _PlaneResult:
    """Eq. 10-11 on one plane.

    With ``shrink_from`` (a list of per-band shrink factors) the plane's coefficients are
    scaled by those factors instead of being thresholded by their own Delta.
    """
    coeffs = forward(y, wavelet=ops.wavelet, levels=ops.levels, boundary=ops.boundary)
    variances = coefficient_variance(var_y, operators=ops)
    out = [coeffs[0]]
    thresholds: list = [None]
    factors: list = [None]
    zeroed = total = 0
    for level in range(1, len(coeffs)):
        bands, band_t, band_f = [], [], []
        for b in range(3):
            w = coeffs[level][b]
            if shrink_from is None:
                t = c_s * np.sqrt(variances[level][b])
                shrunk = _soft(w, t)
                with np.errstate(divide="ignore", invalid="ignore"):
                    f = np.where(w != 0, shrunk / np.where(w != 0, w, 1.0), 0.0)
            else:
                f = shrink_from[level][b]
                t = None
                shrunk = w * f
            bands.append(shrunk)
            band_t.append(t)
            band_f.append(f)
            zeroed += int(np.count_nonzero(f == 0))
            total += f.size
        out.append(tuple(bands))
        thresholds.append(tuple(band_t))
        factors.append(tuple(band_f))
    return _PlaneResult(out, thresholds, factors, zeroed, total)


def _output_variance(var_y: FloatArray, factors: list, ops, probes: int, seed: int) -> FloatArray:
    """Variance of the thresholded plane, linearised around the kept coefficients.

    With the shrink factors held fixed, the reconstruction is a linear map ``T`` of the input
    plus a constant, so ``Var(out) = diag(T V T^T)``. Rademacher probes ``e = +-sqrt(v)`` give
    ``E[T(e)^2] = diag(T V T^T)`` (Hutchinson's estimator): unbiased, and exact when ``T`` is
    the identity (``c_s = 0``).
    """
    rng = np.random.default_rng(seed)
    acc = np.zeros(ops.shape)
    sd = np.sqrt(var_y)
    for _ in range(probes):
        e = sd * rng.choice((-1.0, 1.0), size=ops.shape)
        coeffs = forward(e, wavelet=ops.wavelet, levels=ops.levels, boundary=ops.boundary)
        shrunk = [coeffs[0]] + [tuple(coeffs[lv][b] * factors[lv][b] for b in range(3))
                                for lv in range(1, len(coeffs))]
        out = inverse(shrunk, ops.shape, wavelet=ops.wavelet, boundary=ops.boundary)
        with np.errstate(over="ignore"):  # Inf: an output variance beyond float64 (means near 1e300)
            acc += out * out
    return acc / probes


def reconstruct_detailed(
    buffer: SampleBuffer,
    *,
    c_s: float = DEFAULT_C_S,
    wavelet: str = DEFAULT_WAVELET,
    levels: int | None = None,
    domain: str | Domain = DEFAULT_DOMAIN,
    mode: str = DEFAULT_MODE,
    boundary: str = "symmetric",
    executor: Executor | None = None,
    pixel_clamp: float | None = DEFAULT_PIXEL_CLAMP,
    variance_probes: int = 16,
    seed: int = 0,
) -> Reconstruction:
    """Reconstruct an image from sample statistics and report what the thresholding did.

    Parameters
    ----------
    buffer
        Per-pixel sample statistics.
    c_s
        Smoothing constant of Eq. 11: thresholds are ``c_s`` standard errors. ``0`` returns
        the Monte Carlo mean; about 0.5-2 is useful.
    wavelet
        PyWavelets wavelet; ``"bior4.4"`` (CDF 9/7) by default, ``"haar"`` also common.
    levels
        Decomposition depth; default :func:`~awr_denoise.wavelets.default_levels`.
    domain
        ``"log"`` (default), ``"gamma"`` or ``"linear"`` (the paper, literally), or a
        :class:`~awr_denoise.domains.Domain`. See docs/reconstruction.md for the measurements
        behind the default.
    mode
        ``"channels"`` (default) or ``"luminance"`` (hue-preserving), see :data:`MODES`.
    boundary
        PyWavelets signal extension mode.
    executor
        Optional ``concurrent.futures.Executor`` over which the channels are processed
        (numpy, scipy and PyWavelets release the GIL, so threads help).
    pixel_clamp
        Keep every output pixel within ``pixel_clamp`` standard errors of its own mean, in the
        thresholding domain: Eq. 11 picks each *coefficient* inside its confidence interval,
        and this asks the same of each *pixel*. It stops the blur of a bright edge from
        leaking into dark pixels whose means are precise (their error is judged relatively),
        which otherwise made a small HDR source worse than the plain mean. ``None`` gives the
        paper's reconstruction unchanged. Default 2.5, see docs/reconstruction.md.
    variance_probes
        Random probes used to estimate :attr:`Reconstruction.variance`; each costs one
        transform pair per channel. ``0`` skips the estimate (the variance is then NaN).
    seed
        Seed of the probes.

    Notes
    -----
    Pixels without samples take their nearest sampled neighbour's mean and the variance of a
    single sample, so they are smoothed over rather than read as black. Unknown per-sample
    variances are pooled from neighbours (:meth:`SampleBuffer.estimated_variance`).

    The output variance is that of the reconstruction linearised around its result: the shrink
    factor of every coefficient is held fixed (soft thresholding has slope 1 where it keeps a
    coefficient, 0 where it zeroes one), its variance is estimated without bias by random
    probes, and the domain is undone by the delta method. It ignores the bias of thresholding
    and the pixel clamp.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer, reconstruct_detailed
    >>> rng = np.random.default_rng(1)
    >>> mean = 0.5 + 0.1 * rng.standard_normal((32, 32, 3))
    >>> buffer = SampleBuffer.from_moments(np.full((32, 32), 8), mean, np.full((32, 32, 3), 0.08))
    >>> result = reconstruct_detailed(buffer, c_s=1.0, domain="linear", variance_probes=0)
    >>> error = lambda image: float(np.abs(image - 0.5).mean())
    >>> error(result.image) < error(buffer.mean) / 2
    True

    One threshold list per channel, in :func:`~awr_denoise.wavelets.forward`'s layout: no
    threshold for the scale band, then ``(cH, cV, cD)`` from the coarsest level to the finest:

    >>> [None if t is None else [band.shape for band in t] for t in result.thresholds[0]]
    [None, [(14, 14), (14, 14), (14, 14)], [(20, 20), (20, 20), (20, 20)]]

    ``c_s = 0`` thresholds nothing and returns the Monte Carlo mean (Eq. 11):

    >>> exact = reconstruct_detailed(buffer, c_s=0, variance_probes=0)
    >>> exact.fraction_zeroed, bool(np.allclose(exact.image, buffer.mean, rtol=1e-10))
    (0.0, True)
    """
    if not isinstance(buffer, SampleBuffer):
        raise TypeError(f"buffer: expected a SampleBuffer, got {type(buffer).__name__}")
    if mode not in MODES:
        raise ValueError(f"mode: {mode!r} is not one of {', '.join(MODES)}")
    c_s = _check_c_s(c_s)
    pixel_clamp = _checks.real("pixel_clamp", pixel_clamp, minimum=0, none=True)
    if isinstance(variance_probes, (float, np.floating)):
        raise ValueError(f"variance_probes: must be an integer >= 0, got {variance_probes!r}")
    variance_probes = _checks.whole("variance_probes", variance_probes, minimum=0, maximum=_MAX_PROBES)
    seed = _checks.seed("seed", seed)
    prepared = prepare(buffer, domain)
    ops = wavelet_operators(buffer.shape, wavelet=wavelet, levels=levels, boundary=boundary)
    mean, bound, y, var_y = prepared.mean, prepared.bound, prepared.y, prepared.variance_y
    n_ch = buffer.n_channels
    run = (lambda f, items: list(executor.map(f, items))) if executor is not None else (lambda f, items: [f(i) for i in items])

    shrink_from = None
    if mode == "luminance":
        weights = luminance_weights(buffer.channels)
        lum = prepare(buffer, prepared.domain, luminance=True)
        shrink_from = _threshold_plane(lum.y, lum.variance_y, c_s, ops).factors

    def one_channel(c: int):
        return _threshold_plane(y[:, :, c], var_y[:, :, c], c_s, ops, shrink_from)

    results = run(one_channel, range(n_ch))
    image_y = np.stack([inverse(r.coeffs, buffer.shape, wavelet=wavelet, boundary=boundary) for r in results], axis=-1)
    if pixel_clamp is not None and mode == "channels":
        reach = pixel_clamp * np.sqrt(var_y)
        image_y = np.clip(image_y, y - reach, y + reach)
    image = bound.inverse(image_y)
    if pixel_clamp is not None and mode == "luminance":
        # Clamp luminance to its own interval and scale every channel alike: hue is kept.
        lum_out = image @ weights
        reach = pixel_clamp * np.sqrt(lum.variance_y)
        lum_new = bound.inverse(np.clip(bound.forward(lum_out), lum.y - reach, lum.y + reach))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(lum_out != 0, lum_new / np.where(lum_out != 0, lum_out, 1.0), 1.0)
        image = image * ratio[..., None]
    if not np.isfinite(image).all():
        # Only reachable with means near the float64 limit (~1.8e308) in the linear domain,
        # where the transform's gain of up to 2 per level overflows.
        raise ValueError(f"buffer: the wavelet transform overflows float64 (largest |mean| "
                         f"{float(np.abs(mean).max()):.3g}); rescale the input or use the log domain")
    zeroed = sum(r.zeroed for r in results)
    total = sum(r.total for r in results)
    if variance_probes:
        var_out_y = np.stack(run(lambda c: _output_variance(var_y[:, :, c], results[c].factors, ops, variance_probes,
                                                             seed + c), range(n_ch)), axis=-1)
        d = bound.derivative(image)
        out_var = var_out_y / d / d  # not d * d: that over/underflows for means beyond ~1e+-154
    else:
        out_var = np.full(image.shape, np.nan)
    return Reconstruction(image=image, thresholds=[r.thresholds for r in results],
                          fraction_zeroed=zeroed / total if total else 0.0,
                          variance=out_var, levels=ops.levels, domain=bound.domain,
                          parameters={"c_s": c_s, "wavelet": ops.wavelet, "levels": ops.levels,
                                      "domain": bound.domain.name, "mode": mode, "boundary": boundary,
                                      "pixel_clamp": pixel_clamp})


def reconstruct(
    buffer: SampleBuffer,
    *,
    c_s: float = DEFAULT_C_S,
    wavelet: str = DEFAULT_WAVELET,
    levels: int | None = None,
    domain: str | Domain = DEFAULT_DOMAIN,
    mode: str = DEFAULT_MODE,
    boundary: str = "symmetric",
    executor: Executor | None = None,
    pixel_clamp: float | None = DEFAULT_PIXEL_CLAMP,
) -> FloatArray:
    """Denoise the pixel means by variance-weighted wavelet soft thresholding (Eq. 10-11).

    Parameters are those of :func:`reconstruct_detailed`; this returns the (H, W, C) image only.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer, reconstruct
    >>> rng = np.random.default_rng(0)
    >>> count = np.full((32, 32), 8)
    >>> buf = SampleBuffer.from_moments(count, 0.5 + 0.1 * rng.standard_normal((32, 32, 3)),
    ...                                 np.full((32, 32, 3), 0.08))
    >>> out = reconstruct(buf)
    >>> bool(np.abs(out - 0.5).mean() < np.abs(buf.mean - 0.5).mean())
    True
    """
    return reconstruct_detailed(buffer, c_s=c_s, wavelet=wavelet, levels=levels, domain=domain,
                                mode=mode, boundary=boundary, executor=executor,
                                pixel_clamp=pixel_clamp, variance_probes=0).image
