"""The bundled path tracer as the benchmark uses it: scenes, references and uniform renders.

The tracer needs embreex (extra ``tracer``), so it is imported when first used, with an
install hint; the rest of the bench package imports without it.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

from .._places import shown_path
from .._typing import FloatArray
from ..buffers import SampleBuffer
from ..requests import SampleRequest
from .config import BenchmarkConfig

__all__ = ["TRACER_HINT", "tracer_module", "reference_image", "make_tracer", "render_uniform"]

TRACER_HINT = 'the benchmark needs the bundled tracer; install it with pip install "awr-denoise[tracer]"'


def tracer_module() -> ModuleType:
    """:mod:`awr_denoise.tracer`, or an :class:`ImportError` with the install hint.

    Raises
    ------
    ImportError
        embreex (extra ``tracer``) is not installed.
    """
    try:
        from .. import tracer  # optional extra "tracer" (embreex), imported lazily
    except ImportError as exc:
        raise ImportError(TRACER_HINT) from exc
    return tracer


def reference_image(name: str, scene: Any, config: BenchmarkConfig) -> tuple[FloatArray, dict[str, Any]]:
    """The scene's reference image and where it came from.

    At the scene's own resolution, the cached reference of ``data/references/`` (re-rendered
    and cached first when below ``config.reference_spp``); at another resolution, a Sobol'
    render of ``config.inline_reference_spp`` made on the spot and not cached.

    Parameters
    ----------
    name
        Bundled scene name.
    scene
        The scene as loaded (possibly at another resolution).
    config
        The benchmark's configuration.

    Returns
    -------
    tuple
        ``(image, info)``: the reference, and its ``source``, ``spp``, ``sampler``, ``seed`` and
        ``render_seconds``.
    """
    tracer = tracer_module()
    from ..tracer.reference import REFERENCE_SEED, read_reference_header  # extra "tracer", as above

    default = tracer.load_scene(name)
    if (scene.height, scene.width) == (default.height, default.width):
        path = tracer.reference_path(name)
        if config.reference_spp is not None:
            image = tracer.load_reference(name, spp=config.reference_spp) if not (
                path.is_file() and int(read_reference_header(path).get("spp", 0)) >= config.reference_spp) \
                else tracer.load_reference(name)
        else:
            image = tracer.load_reference(name)
        header = read_reference_header(path)
        return image, {"source": shown_path(path), "spp": int(header.get("spp", 0)),
                       "sampler": header.get("sampler", "?"), "seed": int(header.get("seed", -1)),
                       "render_seconds": float(header.get("render_seconds", header.get("seconds", "nan")))}
    pt = tracer.PathTracer(scene, seed=REFERENCE_SEED, sampler="sobol", threads=config.threads)
    try:
        buffer = pt(SampleRequest.uniform(pt.shape, config.inline_reference_spp))
    finally:
        pt.close()
    return np.array(buffer.mean), {"source": "rendered inline (not cached)", "spp": config.inline_reference_spp,
                                   "sampler": "sobol", "seed": REFERENCE_SEED,
                                   "render_seconds": float(pt.stats["seconds"])}


def make_tracer(scene: Any, seed: int, threads: int) -> Any:
    """A :class:`awr_denoise.tracer.PathTracer` of ``scene`` (close it when done).

    Parameters
    ----------
    scene
        The scene.
    seed
        Render seed (the tracer's random numbers are addressed by seed, pixel and sample index).
    threads
        Tracer threads.
    """
    return tracer_module().PathTracer(scene, seed=seed, threads=threads)


def render_uniform(scene: Any, spp: int, seed: int, threads: int) -> SampleBuffer:
    """``spp`` samples at every pixel of ``scene`` in one request.

    Parameters
    ----------
    scene
        The scene.
    spp
        Samples per pixel.
    seed
        Render seed.
    threads
        Tracer threads.

    Returns
    -------
    SampleBuffer
        The statistics.
    """
    pt = make_tracer(scene, seed, threads)
    try:
        return pt(SampleRequest.uniform(pt.shape, int(spp)))
    finally:
        pt.close()
