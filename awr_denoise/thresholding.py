"""Stage 1: variance-weighted wavelet soft thresholding (paper section 5, Eq. 10-11).

Each wavelet coefficient ``W~`` of the pixel-mean image is shrunk towards zero by ``c_s``
times its own standard error ``Delta = sqrt(<v, Psi^2>)`` (Eq. 10):

    W = sign(W~) * max(0, |W~| - c_s * Delta)            (Eq. 11)

and the image is synthesised back. Each coefficient takes the value nearest zero inside its
confidence interval, so the result is "the smoothest image consistent with the samples".
The coarsest scale band is kept as it is; every detail level and band is thresholded. It runs
on the decimated transform of :mod:`awr_denoise.wavelets`, in the domain of
:mod:`awr_denoise.domains`, and ends with the pixel clamp (docs/reconstruction.md).

:func:`~awr_denoise.reconstruct` runs this stage alone with ``stages=1``; otherwise its result
is the pilot of the Wiener stages (:mod:`awr_denoise.wiener`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from . import fused
from ._typing import FloatArray
from .prepare import Prepared
from .wavelets import WaveletOperators, _forward, _plane_variance, coefficient_variance, forward, inverse

__all__ = ["soft_threshold", "ThresholdStage", "threshold_stage", "PRECISIONS"]

PRECISIONS = ("float32", "float64")
"""Precisions of stage 1: ``"float64"`` (the reference) and ``"float32"`` (log domain, channel mode)."""

# float32 keeps about 7 digits: the log domain's values (at most ~89 there) lose nothing the
# noise has not, as long as the offset k itself is an ordinary float32 number.
_K_RANGE = (2.0**-100, 2.0**100)
# But float32 resolves y only to about its epsilon times max(1, |y|) (``log(1 + |x| / k)`` rounds
# ``1 + |x| / k`` first): a pixel darker than k by ~1e7, beside a light that sets k, is 0 there.
# Where that resolution is not below a quarter of the dimmer pixels' standard error in y (the
# 10th percentile of the positive ones, on a regular grid of pixels), stage 1 runs in float64 (every
# channel: one that cannot sends the whole stage there).
_RESOLUTION_SHARE = 0.25
_EPS32 = float(np.finfo(np.float32).eps)


def _float32_margin(y: FloatArray, mean: FloatArray, sample_variance: FloatArray, count: FloatArray,
                    k: float) -> float:
    """How far float32 ``y`` is from not resolving the plane's noise: a quarter (:data:`_RESOLUTION_SHARE`)
    of the dimmer pixels' standard error in y over float32's resolution there; below 1, stage 1 runs in
    float64 (a bright light far above a dim background left the background below float32's resolution
    near the light's level: it came back as exactly 0, a red-team pass). The noise is taken in float64
    (on a grid of pixels), where float32 may have underflowed it to 0; inf without noise."""
    step = max(1, min(mean.shape) // 128)  # some 16000 pixels or more: a percentile's worth
    on = (slice(None, None, step),) * 2
    with np.errstate(divide="ignore", invalid="ignore"):  # no samples: NaN (dropped) or Inf (a large noise)
        var_y = sample_variance[on] / count[on] / (np.abs(mean[on]) + k) ** 2
    positive = var_y[var_y > 0]
    if positive.size == 0:
        return float("inf")  # no noise to threshold: nothing for the rounding to change
    dim = float(np.sqrt(np.percentile(positive, 10)))
    resolution = _EPS32 * max(1.0, float(y.max()), -float(y.min()))  # max |y| without an |y| plane
    return _RESOLUTION_SHARE * dim / resolution


def soft_threshold(coeff: FloatArray, threshold: FloatArray) -> FloatArray:
    """Eq. 11: ``sign(W~) max(0, |W~| - t)``.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.thresholding import soft_threshold
    >>> soft_threshold(np.array([-3.0, -0.5, 0.2, 2.0]), 1.0)
    array([-2., -0.,  0.,  1.])
    """
    return np.sign(coeff) * np.maximum(np.abs(coeff) - threshold, 0.0)


class _PlaneResult(NamedTuple):
    coeffs: list  # thresholded coefficients
    thresholds: list  # c_s * Delta per detail band (None in luminance-driven channels)
    factors: list  # shrink factor of every detail coefficient (0 where zeroed)
    zeroed: int
    total: int


def _threshold_plane(y: FloatArray, var_y: FloatArray, c_s: float, ops: WaveletOperators,
                     shrink_from: list | None = None) -> _PlaneResult:
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
                shrunk = soft_threshold(w, t)
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


def _output_variance(var_y: FloatArray, factors: list, ops: WaveletOperators, probes: int, seed: int) -> FloatArray:
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


def _threshold_plane32(y: FloatArray, var_y: FloatArray, c_s: float,
                       ops: WaveletOperators) -> tuple[FloatArray, list, int, int]:
    """Eq. 10-11 on one float32 plane, in place where it can (:func:`~awr_denoise.fused.shrink_band`).

    Returns the synthesised plane (before the pixel clamp), the thresholds ``c_s * Delta``, and
    the zeroed and total detail coefficients. The shrink factors are not kept (see
    :func:`_factors32`).
    """
    coeffs = _forward(y, ops.wavelet, ops.levels, ops.boundary)  # y is finite: made and checked here
    variances = _plane_variance(var_y, ops)
    thresholds: list = [None]
    zeroed = total = 0
    for level in range(1, len(coeffs)):
        for b in range(3):  # Eq. 11 in place; the variances become the thresholds c_s * Delta
            zeroed += fused.shrink_band(coeffs[level][b], variances[level][b], c_s)
            total += coeffs[level][b].size
        thresholds.append(variances[level])
    return inverse(coeffs, ops.shape, wavelet=ops.wavelet, boundary=ops.boundary), thresholds, zeroed, total


def _factors32(y: FloatArray, thresholds: list, ops: WaveletOperators) -> list:
    """The shrink factors the float32 path applied: ``max(|w| - t, 0) / |w|`` (0 where ``w = 0``)."""
    coeffs = forward(y, wavelet=ops.wavelet, levels=ops.levels, boundary=ops.boundary)
    factors: list = [None]
    for level in range(1, len(coeffs)):
        band_f = []
        for b in range(3):
            a = np.abs(coeffs[level][b]).astype(np.float64)
            with np.errstate(divide="ignore", invalid="ignore"):
                band_f.append(np.where(a > 0, np.maximum(a - thresholds[level][b], 0.0) / np.where(a > 0, a, 1.0),
                                       0.0))
        factors.append(tuple(band_f))
    return factors


def _stage32(prepared: Prepared, ops: WaveletOperators, c_s: float, pixel_clamp: float | None,
             run: Callable) -> tuple[FloatArray, list, int, int, Callable[[int], FloatArray]] | None:
    """Stage 1 in float32 (log domain, channel mode); ``None`` if the buffer needs float64."""
    k = prepared.bound.k
    if not _K_RANGE[0] <= k <= _K_RANGE[1]:
        return None
    mean, s2 = prepared.mean, prepared.sample_variance
    count = prepared.count[:, :, 0].astype(np.float32)  # exact up to 2^24 samples, then within 6e-8
    image = np.empty(mean.shape, np.float64)

    def one_channel(c: int) -> tuple[list, int, int] | None:
        plane = fused.log_plane(mean[:, :, c], s2[:, :, c], count, k)
        if plane is None:
            return None
        y, var_y = plane
        if not _float32_margin(y, mean[:, :, c], s2[:, :, c], count, k) >= 1:
            return None
        out, thresholds, zeroed, total = _threshold_plane32(y, var_y, c_s, ops)
        fused.finish_plane(image[:, :, c], out, y, var_y, mean[:, :, c], k, pixel_clamp)
        return thresholds, zeroed, total

    results = run(one_channel, range(mean.shape[2]))
    if any(r is None for r in results):
        return None

    def factors(c: int) -> list:
        plane = fused.log_plane(mean[:, :, c], s2[:, :, c], count, k)
        assert plane is not None
        return _factors32(plane[0], results[c][0], ops)

    return image, [r[0] for r in results], sum(r[1] for r in results), sum(r[2] for r in results), factors


@dataclass(frozen=True, eq=False)
class ThresholdStage:
    """What stage 1 made: the image and what the thresholding did.

    Attributes
    ----------
    image
        (H, W, C) result in linear radiance.
    thresholds
        Per channel, ``c_s * Delta`` in :func:`~awr_denoise.wavelets.forward`'s layout, in the
        thresholding domain (``None`` for the scale band and for luminance-driven channels).
    zeroed, total
        Detail coefficients set to zero, and all detail coefficients, over the channels.
    output_variance
        ``output_variance(probes, seed)``: the (H, W, C) variance of :attr:`image`, linearised
        (shrink factors held fixed) and estimated with Rademacher probes.
    """

    image: FloatArray
    thresholds: list
    zeroed: int
    total: int
    output_variance: Callable[[int, int], FloatArray]


def threshold_stage(prepared: Prepared, ops: WaveletOperators, c_s: float, *, mode: str = "channels",
                    pixel_clamp: float | None = 2.5, luminance: Prepared | None = None,
                    weights: FloatArray | None = None, run: Callable | None = None,
                    precision: str = "float64") -> ThresholdStage:
    """Eq. 10-11 on every channel of a prepared buffer, then the pixel clamp.

    Parameters
    ----------
    prepared
        The buffer's planes (:func:`~awr_denoise.prepare.prepare`) in the thresholding domain.
    ops
        :func:`~awr_denoise.wavelets.wavelet_operators` of the image's shape.
    c_s
        Thresholds in standard errors (Eq. 11).
    mode
        ``"channels"``: each channel thresholded with its own Delta; ``"luminance"``: the
        shrink factors are decided on ``luminance`` and applied to every channel.
    pixel_clamp
        Output within ``pixel_clamp`` standard errors of each pixel's mean in the domain
        (``None``: off). In luminance mode luminance is clamped and every channel scaled alike.
    luminance, weights
        Luminance mode only: the luminance plane prepared with ``prepared.domain``, and the
        channels' luminance weights (:func:`~awr_denoise.luminance_weights`).
    run
        ``run(f, items)`` maps ``f`` over the channels (an executor's ``map``); default a loop.
    precision
        ``"float64"`` (the reference) or ``"float32"``: the transforms, the variance
        propagation, the thresholding and the clamp in float32, in channel mode in the log
        domain with ``c_s > 0`` (elsewhere, and when a buffer's values do not fit float32,
        float64 is used: ``c_s = 0`` returns the means to float64's rounding).
        The output stays float64; it differs from the reference by a few float32 epsilons
        relative to each pixel's level (tests/test_thresholding.py; docs/performance.md).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.prepare import prepare
    >>> from awr_denoise.thresholding import threshold_stage
    >>> from awr_denoise.wavelets import wavelet_operators
    >>> rng = np.random.default_rng(1)
    >>> buffer = SampleBuffer.from_moments(np.full((32, 32), 8), 0.5 + 0.1 * rng.standard_normal((32, 32, 3)),
    ...                                    np.full((32, 32, 3), 0.08))
    >>> stage = threshold_stage(prepare(buffer, "log"), wavelet_operators((32, 32)), 1.0)
    >>> stage.image.shape, round(stage.zeroed / stage.total, 2)
    ((32, 32, 3), 0.69)
    """
    run = run or (lambda f, items: [f(i) for i in items])
    if precision not in PRECISIONS:
        raise ValueError(f"precision: {precision!r} is not one of {', '.join(PRECISIONS)}")
    bound = prepared.bound
    # Var f'(mean)^2: a finite variance beside means of 0 overflows it. Bounded first by the largest variance at the
    # steepest slope (at 0 in every domain), so that the float32 path does not keep a whole float64 variance_y
    # (stage 1's peak 2.1x its buffer at 1080p, not 1.3x: docs/performance.md); built only where the bound overflows.
    largest = prepared.sample_variance.max(initial=0.0) / max(float(prepared.count.min(initial=1.0)), 1.0)
    if not np.isfinite(bound.variance(np.zeros(1), np.array([largest]))[0]) \
            and not np.isfinite(prepared.variance_y.max(initial=0.0)):
        bad = int((~np.isfinite(prepared.variance_y)).any(axis=-1).sum())
        raise ValueError(f"buffer: the variance of {bad} pixel(s) is beyond float64 in the {bound.domain.name} "
                         "domain (divided by the square of its slope there); reconstruct it in domain='linear'")
    # c_s = 0 is Eq. 11's identity: float64 returns the means to float64's rounding, as it promises.
    if precision == "float32" and c_s > 0 and mode == "channels" and bound.domain.name == "log" \
            and not bound.domain.robust:
        fast = _stage32(prepared, ops, c_s, pixel_clamp, run)
        if fast is not None:
            image, thresholds, zeroed, total, factors = fast

            def output_variance32(probes: int, seed: int) -> FloatArray:
                var_y = prepared.variance_y
                var_out_y = np.stack(run(lambda c: _output_variance(var_y[:, :, c], factors(c), ops, probes, seed + c),
                                         range(image.shape[2])), axis=-1)
                d = bound.derivative(image)
                return var_out_y / d / d

            return ThresholdStage(image, thresholds, zeroed, total, output_variance32)
    y, var_y = prepared.y, prepared.variance_y
    shrink_from = None
    if mode == "luminance":
        if luminance is None or weights is None:
            raise ValueError("luminance, weights: the luminance plane and weights are needed in luminance mode")
        shrink_from = _threshold_plane(luminance.y, luminance.variance_y, c_s, ops).factors

    def one_channel(c: int) -> _PlaneResult:
        return _threshold_plane(y[:, :, c], var_y[:, :, c], c_s, ops, shrink_from)

    results = run(one_channel, range(y.shape[2]))
    image_y = np.stack([inverse(r.coeffs, ops.shape, wavelet=ops.wavelet, boundary=ops.boundary) for r in results],
                       axis=-1)
    if pixel_clamp is not None and mode == "channels":
        reach = pixel_clamp * np.sqrt(var_y)
        image_y = np.clip(image_y, y - reach, y + reach)
    image = bound.inverse(image_y)
    if pixel_clamp is not None and mode == "luminance":
        assert luminance is not None
        # Clamp luminance to its own interval and scale every channel alike: hue is kept.
        lum_out = image @ weights
        reach = pixel_clamp * np.sqrt(luminance.variance_y)
        lum_new = bound.inverse(np.clip(bound.forward(lum_out), luminance.y - reach, luminance.y + reach))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(lum_out != 0, lum_new / np.where(lum_out != 0, lum_out, 1.0), 1.0)
        image = image * ratio[..., None]
    if not np.isfinite(image).all():
        # Only reachable with means near the float64 limit (~1.8e308) in the linear domain,
        # where the transform's gain of up to 2 per level overflows.
        raise ValueError(f"buffer: the wavelet transform overflows float64 (largest |mean| "
                         f"{float(np.abs(prepared.mean).max()):.3g}); rescale the input or use the log domain")

    def output_variance(probes: int, seed: int) -> FloatArray:
        var_out_y = np.stack(run(lambda c: _output_variance(var_y[:, :, c], results[c].factors, ops, probes, seed + c),
                                 range(y.shape[2])), axis=-1)
        d = bound.derivative(image)
        return var_out_y / d / d  # not d * d: that over/underflows for means beyond ~1e+-154

    return ThresholdStage(image, [r.thresholds for r in results], sum(r.zeroed for r in results),
                          sum(r.total for r in results), output_variance)
