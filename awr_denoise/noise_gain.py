"""The noise gain: what reconstruction leaves of each pixel's noise, for the sampler.

:class:`~awr_denoise.AdaptiveSampler` spends a round's samples by ``n_p ~ s_p sqrt(g_p)``, where
``g_p`` is the share of pixel ``p``'s own noise that stays in the reconstructed image
(docs/sampling.md, "The noise gain"). Three models of ``g_p``:

- ``"levels"``, the paper's: a region averaged over ``4^l`` pixels keeps ``4^-l`` of it;
- ``"shrinkage"`` (the default): :func:`shrinkage_gain`, the exact diagonal of a Wiener shrinkage
  of the error plane's own wavelet coefficients (stage 1's soft threshold as its pilot), at
  7-20% more of the sampler's time than the level term;
- ``"reconstruction"``: the default reconstruction's own gain, measured (below).

Measured on both renderers (docs/sampling.md, "The noise gain"), the shrinkage's gain has 1.01-1.25x
lower relMSE than the level model on every scene and sample count, and is as good as the measured
gain on average. The measured gain (:attr:`~awr_denoise.Reconstruction.noise_gain`) costs one
reconstruction a round, twelve to 32 spp at the samplers' default round growth. Between two rounds the
image changes little, and the gain, a property of the image's structure (edges kept, smooth regions
averaged), changes less: :class:`MeasuredGain` measures it again only once the buffer's samples have
grown by a factor ``refresh`` since the last measurement. The default, 1, measures every round.
Measured on both renderers (docs/sampling.md, "Measuring the gain less often"): 1.5 (every other
round at the default round growth) halves the sampler's time and keeps most of the gain's advantage
over the level model, 2 keeps less of it at a third of the time.
"""

from __future__ import annotations

from concurrent.futures import Executor

import numpy as np

from . import _checks
from ._typing import FloatArray
from .buffers import SampleBuffer
from .reconstruct import DEFAULT_C_S, reconstruct_detailed
from .wavelets import WaveletOperators, shrinkage_diagonal

__all__ = ["MeasuredGain", "shrinkage_gain", "NOISE_MODELS", "DEFAULT_NOISE_MODEL", "DEFAULT_GAIN_REFRESH"]

NOISE_MODELS = ("levels", "shrinkage", "reconstruction")
"""``AdaptiveSampler``'s ``noise_model``: the paper's level term, the shrinkage's exact gain, the measured gain."""

DEFAULT_NOISE_MODEL = "shrinkage"
"""The samplers' default noise model: chosen on both renderers (docs/sampling.md, "The noise gain")."""

DEFAULT_GAIN_REFRESH = 1.0
"""Growth of the samples after which :class:`MeasuredGain` measures again: 1, every round (docs/sampling.md)."""


class MeasuredGain:
    """The noise gain of a growing buffer, measured again once its samples grow by ``refresh``.

    Parameters
    ----------
    refresh
        Factor, at least 1, by which the buffer's total samples must have grown since the last
        measurement before the gain is measured again; 1 measures it on every call.

    Examples
    --------
    A buffer of 4 samples per pixel, then the same with one more: with ``refresh=1.5`` the gain
    measured at 4 spp still serves at 5 spp (1.25 times the samples), and is measured again at
    6 spp:

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.noise_gain import MeasuredGain
    >>> rng = np.random.default_rng(0)
    >>> def buffer(spp):
    ...     return SampleBuffer.from_moments(np.full((32, 32), spp), rng.random((32, 32, 3)), np.full((32, 32, 3), 0.1))
    >>> gain = MeasuredGain(refresh=1.5)
    >>> first = gain(buffer(4))
    >>> first.shape, gain(buffer(5)) is first, gain(buffer(6)) is first, gain.measurements
    ((32, 32), True, False, 2)
    """

    def __init__(self, refresh: float = DEFAULT_GAIN_REFRESH) -> None:
        self.refresh = float(_checks.real("gain_refresh", refresh, minimum=1, maximum=1e6))  # type: ignore[arg-type]
        self.measurements = 0
        self._gain: FloatArray | None = None
        self._samples = 0

    def __call__(self, buffer: SampleBuffer, executor: Executor | None = None) -> FloatArray:
        """(H, W) gain ``g_p`` of ``buffer``: measured now, or the last measurement if the samples grew by less."""
        total = buffer.total_samples
        stale = (self._gain is None or self._gain.shape != buffer.shape or total < self._samples
                 or total >= self.refresh * self._samples)
        if stale:
            # Without the finishing steps: they leave the gain as it is.
            self._gain = reconstruct_detailed(buffer, variance_probes=0, pixel_clamp=None, preserve_mean=False,
                                              nonnegative=False, executor=executor).noise_gain
            self._samples = total
            self.measurements += 1
        assert self._gain is not None
        return self._gain


def shrinkage_gain(coeffs: list, variances: list, operators: WaveletOperators, *,
                   c_s: float = DEFAULT_C_S) -> FloatArray:
    """(H, W) share of each pixel's noise that a Wiener shrinkage of the plane's own coefficients keeps there.

    Every detail coefficient ``W~`` with standard error ``Delta`` (Eq. 10) is scaled by
    ``P^2 / (P^2 + Delta^2)``, with the pilot ``P = max(|W~| - c_s Delta, 0)`` the paper's soft
    threshold (Eq. 11, stage 1's ``c_s``); the scale band is kept. ``g_p`` is that map's diagonal
    (:func:`~awr_denoise.wavelets.shrinkage_diagonal`, exact): near 1 where an edge keeps the
    finest coefficients, near 0 where every detail is noise and a wide average remains. It is the
    default reconstruction's structure (a soft-thresholded pilot, then a Wiener stage) on the
    decimated transform the priorities compute anyway, at the cost of about one more variance
    propagation instead of a reconstruction (docs/sampling.md, "The noise gain").

    Parameters
    ----------
    coeffs, variances
        :func:`~awr_denoise.wavelets.forward` of the error plane and
        :func:`~awr_denoise.wavelets.coefficient_variance` of its means (same layout).
    operators
        The transform's :func:`~awr_denoise.wavelets.wavelet_operators`.
    c_s
        The pilot's threshold in standard errors.

    Examples
    --------
    A vertical edge in noise: the columns beside it keep more than three times the share of their
    own noise that the flat regions on either side keep (the shrinkage averages those):

    >>> import numpy as np
    >>> from awr_denoise.noise_gain import shrinkage_gain
    >>> from awr_denoise.wavelets import coefficient_variance, forward, wavelet_operators
    >>> rng = np.random.default_rng(0)
    >>> mean = np.where(np.arange(64) < 32, 0.0, 4.0)[None, :] + 0.1 * rng.standard_normal((64, 64))
    >>> ops = wavelet_operators(mean.shape)
    >>> gain = shrinkage_gain(forward(mean, levels=ops.levels), coefficient_variance(np.full((64, 64), 0.01)), ops)
    >>> [round(float(gain[:, cols].mean()), 2) for cols in (slice(8, 16), slice(30, 34), slice(48, 56))]
    [0.09, 0.31, 0.09]
    """
    c = float(_checks.real("c_s", c_s, minimum=0))
    factors: list = [np.ones(np.shape(coeffs[0]), np.float32)]
    for level in range(1, len(coeffs)):
        factors.append(tuple(_wiener_factor(w, var, c) for w, var in zip(coeffs[level], variances[level])))
    # Factors in [0, 1] need no float64: the diagonal in float32 (the sampler's density needs no more
    # digits), clipped at 0 (rounding, or the basis's overshoot, must not send a pixel no samples).
    return np.maximum(shrinkage_diagonal(factors, operators, precision="float32"), 0.0).astype(np.float64)


def _wiener_factor(w: FloatArray, var: FloatArray, c: float) -> FloatArray:
    """``P^2 / (P^2 + Delta^2)`` with ``P = max(|w| - c Delta, 0)`` in float64, returned in float32.

    ``P = Delta = 0``, an exact coefficient, gives 1 (kept). The plane is normalised before it is
    transformed (``priorities._normalised``), so ``P^2`` stays finite. (A float32 version was not
    faster at 1080p in an ad-hoc check, and it changed nothing in the counts there.)"""
    var = np.asarray(var, dtype=np.float64)
    pilot = np.maximum(np.abs(w) - c * np.sqrt(var), 0.0)
    pilot *= pilot
    total = pilot + var
    with np.errstate(invalid="ignore", divide="ignore"):  # 0 / 0: an exact coefficient, kept
        return np.where(total > 0, pilot / total, 1.0).astype(np.float32)
