"""The bundled reference path tracer (``pip install "awr-denoise[tracer]"``).

A batched (wavefront) path tracer in numpy on top of embreex that implements the
:class:`~awr_denoise.requests.Renderer` protocol: given a
:class:`~awr_denoise.requests.SampleRequest` it traces exactly the requested samples and returns
their per-pixel statistics as a :class:`~awr_denoise.buffers.SampleBuffer`. It exists to feed
the adaptive sampler and the benchmarks with scenes of known integrand dimension (4D to 8D,
Overbeck et al. 2009, section 1; docs/concepts.md, "The pixel integral"). The core library
never imports it.

Public API: :func:`list_scenes`, :func:`list_features`, :func:`load_scene`, :class:`PathTracer`, :func:`render`,
:func:`create_renderer` (the ``"tracer"`` entry of :mod:`awr_denoise.renderers`),
:func:`load_reference`, :func:`render_reference`.
"""

from __future__ import annotations

import importlib.util

if importlib.util.find_spec("embreex") is None:
    raise ImportError(
        "awr_denoise.tracer needs the embreex ray tracing kernels; install them with "
        'pip install "awr-denoise[tracer]"')

from typing import Any  # noqa: E402

from .integrator import PathTracer, create_renderer, render  # noqa: E402
from .sampler import SAMPLER_NAMES  # noqa: E402
from .scene import Scene, load_scene, scene_files  # noqa: E402
from ..features import FEATURE_NAMES  # noqa: E402

# Resolved on first use (PEP 562) so ``python -m awr_denoise.tracer.reference`` and
# ``python -m awr_denoise.tracer.scenes`` do not import their own module twice.
_LAZY = {"list_scenes": ".scenes", "load_reference": ".reference", "render_reference": ".reference",
         "reference_path": ".reference"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = ["PathTracer", "SAMPLER_NAMES", "Scene", "create_renderer", "list_features", "list_scenes", "load_scene",
           "render", "load_reference", "render_reference", "reference_path", "scene_files"]


def list_features() -> list[str]:
    """The features :func:`create_renderer` renders with ``features=...``: every one of the project's.

    Examples
    --------
    >>> from awr_denoise.tracer import list_features
    >>> list_features()
    ['albedo', 'normal', 'depth']
    """
    return list(FEATURE_NAMES)
