"""Every pixel's per-sample variance moderated towards its neighbours' before the default reconstruction.

At 4-32 spp each pixel's sample variance rests on 3-31 degrees of freedom, and the reconstruction takes it as
the pixel's noise (the exact per-coefficient standard error of Eq. 10, the Wiener stages' ``Delta``, the guard,
the clamp). The library moderates only the variances of samples that all agreed (``awr_denoise.pooling``,
``AGREED_PRIOR``); this module tries the empirical-Bayes moderation of every known variance, as a variant for
``benchmarks/bench_reconstruct.py quality --moderated`` and ``benchmarks/bench_equal_error.py --variants``:

    s2' = ((n - 1) s2 + d0 s2_local) / (n - 1 + d0)

``s2_local`` pools the known pixels of the 5x5 window, each weighted by its ``n - 1``, among those whose mean is
within a factor of 2 of the pixel's (in magnitude, channel by channel), so that a light's variance does not spread
into the dark beside it; ``d0`` is the prior's degrees of freedom. Pixels with fewer than two samples keep the
library's own treatment (their variance is pooled by it afterwards). docs/reconstruction.md, "Every variance
moderated", has what it measured.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from awr_denoise import SampleBuffer, reconstruct

WINDOW = 5
RATIO = 2.0
PRIORS = (2.0, 8.0)


def moderated(buffer: SampleBuffer, prior: float) -> SampleBuffer:
    """``buffer`` with every known per-sample variance moderated with ``prior`` degrees of freedom (docstring)."""
    dof = np.maximum(buffer.count - 1, 0).astype(np.float64)
    pad = WINDOW // 2
    h, w = buffer.shape
    out = np.array(buffer.variance)
    for c in range(buffer.mean.shape[2]):
        mean, var = buffer.mean[..., c], buffer.variance[..., c]
        level = np.abs(mean)
        padded = [np.pad(a, pad, mode="edge") for a in (level, var, dof)]
        num, den = np.zeros((h, w)), np.zeros((h, w))
        for dy in range(WINDOW):  # one whole-image pass per window offset, not a loop per pixel
            for dx in range(WINDOW):
                lj, sj, dj = (a[dy:dy + h, dx:dx + w] for a in padded)
                alike = (lj <= RATIO * level + 1e-300) & (level <= RATIO * lj + 1e-300)
                num += dj * alike * sj
                den += dj * alike
        local = np.divide(num, den, out=np.array(var), where=den > 0)
        out[..., c] = np.where(dof > 0, (dof * var + prior * local) / np.maximum(dof + prior, 1e-300), var)
    return SampleBuffer.from_moments(buffer.count, buffer.mean, out, channels=buffer.channels)


def reconstruct_moderated(prior: float) -> Any:
    """The default reconstruction of the buffer with its variances moderated (``prior`` degrees of freedom)."""
    def run(buffer: SampleBuffer) -> np.ndarray:
        return reconstruct(moderated(buffer, prior))
    return run


VARIANTS: dict[str, Any] = {f"variances moderated d0={d:g}": reconstruct_moderated(d) for d in PRIORS}
"""The variants the two scripts measure, by name."""
