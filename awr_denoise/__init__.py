"""awr_denoise: Adaptive Wavelet Rendering for Monte Carlo sample buffers.

Implements R. S. Overbeck, C. Donner, R. Ramamoorthi, "Adaptive Wavelet Rendering",
ACM Transactions on Graphics 28(5), 140 (SIGGRAPH Asia 2009): wavelet-coefficient priorities
that decide where a renderer's next samples go, and a reconstruction that soft-thresholds
wavelet coefficients by their propagated standard error (Eq. 10-11).
"""

from __future__ import annotations

from ._version import __version__
from .buffers import SampleBuffer
from .channels import luminance_weights
from .errors import AWRError, InputFileError, InputFileWarning, StaleRequestError
from .domains import Domain
from .reconstruct import Reconstruction, reconstruct, reconstruct_detailed
from .requests import Renderer, SampleRequest
from .allocation import allocate
from .sampling import AdaptiveSampler, Sampler, UniformSampler, VarianceSampler


__all__ = [
    "AWRError",
    "AdaptiveSampler",
    "Domain",
    "Reconstruction",
    "Sampler",
    "UniformSampler",
    "VarianceSampler",
    "allocate",
    "reconstruct",
    "reconstruct_detailed",
    "InputFileError",
    "InputFileWarning",
    "Renderer",
    "SampleBuffer",
    "SampleRequest",
    "StaleRequestError",
    "luminance_weights",
    "__version__",
]
