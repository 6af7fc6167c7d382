"""awr_denoise: Adaptive Wavelet Rendering for Monte Carlo sample buffers.

Implements R. S. Overbeck, C. Donner, R. Ramamoorthi, "Adaptive Wavelet Rendering",
ACM Transactions on Graphics 28(5), 140 (SIGGRAPH Asia 2009): wavelet-coefficient priorities
that decide where a renderer's next samples go, and a reconstruction that soft-thresholds
wavelet coefficients by their propagated standard error (Eq. 10-11).

The public names below are imported on first use (PEP 562), so ``import awr_denoise`` costs
nothing: the ``awr`` command installs its interrupt handling before numpy and scipy load.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

from ._version import __version__
from .errors import AWRError, InputFileError, InputFileWarning, StaleRequestError, TimeBudgetWarning

if TYPE_CHECKING:  # what the lazy names resolve to, for type checkers and IDEs
    from .allocation import allocate
    from .buffers import SampleBuffer
    from .channels import luminance_weights
    from .domains import Domain
    from .reconstruct import Reconstruction, reconstruct, reconstruct_detailed
    from .requests import Renderer, SampleRequest
    from .sampling import AdaptiveSampler, Sampler, UniformSampler, VarianceSampler

_LAZY = {
    "SampleBuffer": "buffers",
    "luminance_weights": "channels",
    "Domain": "domains",
    "Reconstruction": "reconstruct",
    "reconstruct": "reconstruct",
    "reconstruct_detailed": "reconstruct",
    "Renderer": "requests",
    "SampleRequest": "requests",
    "allocate": "allocation",
    "AdaptiveSampler": "sampling",
    "Sampler": "sampling",
    "UniformSampler": "sampling",
    "VarianceSampler": "sampling",
}

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
    "TimeBudgetWarning",
    "luminance_weights",
    "__version__",
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """Keeps ``awr_denoise.reconstruct`` the function once the submodule of that name loads.

    Importing a submodule binds it as an attribute of its package; with eager imports the
    ``from .reconstruct import reconstruct`` above used to rebind the name to the function
    right after, and lazy loading must give the same answer.
    """

    def __setattr__(self, name: str, value: Any) -> None:
        if isinstance(value, types.ModuleType) and _LAZY.get(name) == name:
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
