"""The measured noise gain: what the default reconstruction leaves of each pixel's noise, for the sampler.

:class:`~awr_denoise.AdaptiveSampler` with ``noise_model="reconstruction"`` spends a round's
samples by ``n_p ~ s_p sqrt(g_p)``, where ``g_p`` is the default reconstruction's measured share of
pixel ``p``'s noise (:attr:`~awr_denoise.Reconstruction.noise_gain`; docs/sampling.md, "The measured
noise gain"). Measuring it costs one reconstruction a round, ten to 32 spp at the samplers' default
round growth. Between two rounds the image changes little, and the gain, a property of the image's
structure (edges kept, smooth regions averaged), changes less: :class:`MeasuredGain` measures it
again only once the buffer's samples have grown by a factor ``refresh`` since the last
measurement. The default, 1, measures every round. Measured on both renderers (docs/sampling.md,
"Measuring the gain less often"): 1.5 (every other round at the default round growth) halves the
sampler's time and keeps most of the gain's advantage over the level model, 2 keeps less of it at
a third of the time.
"""

from __future__ import annotations

from concurrent.futures import Executor

from . import _checks
from ._typing import FloatArray
from .buffers import SampleBuffer
from .reconstruct import reconstruct_detailed

__all__ = ["MeasuredGain", "NOISE_MODELS", "DEFAULT_GAIN_REFRESH"]

NOISE_MODELS = ("levels", "reconstruction")
"""``AdaptiveSampler``'s ``noise_model``: the paper's level term, or the default reconstruction's measured gain."""

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
