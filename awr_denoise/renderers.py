"""Named renderer factories: how ``awr render --renderer NAME`` and tiled rendering find a renderer.

A factory builds a :class:`~awr_denoise.Renderer` from a scene and a few common options::

    factory(scene, *, shape=None, seed=0, **options) -> Renderer

``scene`` is whatever the renderer understands (a bundled scene name, a scene file, a scene
object); ``shape`` is the (H, W) to render at, ``None`` for the scene's own; ``options`` are
the renderer's own keyword arguments. Factories are looked up by name, in this order:

1. factories registered at run time with :func:`register_renderer`;
2. the built-in ones: ``"tracer"`` (the bundled path tracer, extra ``tracer``), ``"synthetic"``
   (analytic test scenes) and ``"mitsuba"`` (the Mitsuba 3 adapter, extra ``mitsuba``);
3. entry points of the group ``awr_denoise.renderers`` that other packages declare, e.g. in
   their ``pyproject.toml``::

       [project.entry-points."awr_denoise.renderers"]
       myrenderer = "my_package.awr:create_renderer"

A renderer's module may also define ``list_scenes() -> list[str]``, the scenes it bundles
(:func:`renderer_scenes`, ``awr render --renderer NAME --list-scenes``), and
``list_features() -> list[str]``, the feature buffers its factory renders with
``features=...`` (:func:`renderer_features`, ``awr render --features``).

Built-ins and entry points are named as ``"module:function"`` strings and imported only when
asked for, so this module imports no renderer: a missing optional extra shows up as an
``ImportError`` with its install hint when that renderer is created, not before.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

from .requests import Renderer

__all__ = ["ENTRY_POINT_GROUP", "RendererFactory", "create_renderer", "register_renderer", "renderer_factory",
           "renderer_names", "renderer_features", "renderer_scenes", "renderer_scene_files"]

ENTRY_POINT_GROUP = "awr_denoise.renderers"
"""Entry-point group in which other packages declare renderer factories."""

RendererFactory = Callable[..., Renderer]
"""``factory(scene, *, shape=None, seed=0, **options) -> Renderer``."""

_BUILTIN = {
    "tracer": "awr_denoise.tracer:create_renderer",
    "synthetic": "awr_denoise.synthetic:create_renderer",
    "mitsuba": "awr_denoise.adapters.mitsuba:create_renderer",
}

_registered: dict[str, RendererFactory] = {}


def _check_name(name: object) -> str:
    if not isinstance(name, str) or not name or ":" in name:
        raise ValueError(f"name: expected a non-empty renderer name without ':', got {name!r}")
    return name


def register_renderer(name: str, factory: RendererFactory, *, replace: bool = False) -> None:
    """Make ``factory`` available as renderer ``name``.

    Parameters
    ----------
    name
        The name ``awr render --renderer`` and :class:`~awr_denoise.parallel.RendererSpec` use.
    factory
        ``factory(scene, *, shape=None, seed=0, **options) -> Renderer``. It must be picklable
        (a module-level function) for process and Dask executors, which build the renderer in
        the worker.
    replace
        Replace a factory registered under the same name; otherwise that is an error.

    Examples
    --------
    >>> from awr_denoise.renderers import create_renderer, register_renderer
    >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
    >>> def edges(scene, *, shape=None, seed=0):
    ...     return SyntheticRenderer(make_scene("edges", shape or (8, 8)), seed=seed)
    >>> register_renderer("my-edges", edges, replace=True)
    >>> create_renderer("my-edges", None, shape=(4, 6)).shape
    (4, 6)
    """
    name = _check_name(name)
    if not callable(factory):
        raise TypeError(f"factory: expected a callable, got {factory!r}")
    if name in _registered and not replace:
        raise ValueError(f"name: a renderer {name!r} is registered already (pass replace=True)")
    _registered[name] = factory


def _declared() -> dict[str, str]:
    """Built-in and entry-point factories as ``module:function`` strings (entry points win)."""
    declared = dict(_BUILTIN)
    declared.update({ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)})
    return declared


def renderer_names() -> list[str]:
    """Names of every known renderer, sorted (their extras may still be missing).

    Examples
    --------
    >>> from awr_denoise.renderers import renderer_names
    >>> {"mitsuba", "synthetic", "tracer"} <= set(renderer_names())
    True
    """
    return sorted(set(_declared()) | set(_registered))


def renderer_factory(name: str) -> RendererFactory:
    """The factory of renderer ``name``, importing its module if needed.

    Raises
    ------
    ValueError
        No renderer has that name.
    ImportError
        The renderer's module (or its optional extra) cannot be imported; the message says
        what to install.

    Examples
    --------
    >>> from awr_denoise.renderers import renderer_factory
    >>> renderer_factory("synthetic").__name__
    'create_renderer'
    """
    name = _check_name(name)
    if name in _registered:
        return _registered[name]
    declared = _declared()
    if name not in declared:
        raise ValueError(f"renderer: {name!r} is not one of {', '.join(renderer_names())}")
    module_name, _, attribute = declared[name].partition(":")
    factory = getattr(importlib.import_module(module_name), attribute)
    if not callable(factory):
        raise TypeError(f"renderer {name!r}: {declared[name]} is not callable")
    return factory


def renderer_scenes(name: str) -> list[str]:
    """The scenes renderer ``name`` bundles: its module's ``list_scenes()``, or none.

    Raises
    ------
    ValueError, ImportError
        As :func:`renderer_factory`.

    Examples
    --------
    >>> from awr_denoise.renderers import renderer_scenes
    >>> "edges" in renderer_scenes("synthetic")
    True
    """
    return _listed(name, "list_scenes")


def renderer_features(name: str) -> list[str]:
    """The feature buffers renderer ``name`` renders on request: its module's ``list_features()``, or none.

    Raises
    ------
    ValueError, ImportError
        As :func:`renderer_factory`.

    Examples
    --------
    >>> from awr_denoise.renderers import renderer_features
    >>> renderer_features("synthetic")
    []
    """
    return _listed(name, "list_features")


def renderer_scene_files(name: str, scene: Any) -> list[tuple[str, Path]]:
    """The files a scene of renderer ``name`` reads besides itself, as ``(what, path)``.

    Its module's ``scene_files(scene)`` (a texture, a mesh, an environment map or an included
    file a scene file names), or none. A command checks them with its other inputs before
    anything is read or written: an output must never replace one, and a FIFO among them would
    block the render.

    Raises
    ------
    ValueError, ImportError
        As :func:`renderer_factory`; a ``ValueError`` for a scene file the module cannot read.

    Examples
    --------
    >>> from awr_denoise.renderers import renderer_scene_files
    >>> renderer_scene_files("synthetic", "edges"), renderer_scene_files("tracer", "default")
    ([], [])
    """
    found = getattr(importlib.import_module(_module(name)), "scene_files", None)
    return [(str(what), Path(path)) for what, path in found(scene)] if callable(found) else []


def _module(name: str) -> str:
    """The module declaring renderer ``name``'s factory."""
    factory = renderer_factory(name)
    # The module the factory is declared in (``module:function``), not the one defining it: a
    # package may re-export a factory written in a submodule.
    return factory.__module__ if name in _registered else _declared()[name].partition(":")[0]


def _listed(name: str, function: str) -> list[str]:
    """What the module declaring renderer ``name``'s factory lists with ``function()``, or nothing."""
    listed = getattr(importlib.import_module(_module(name)), function, None)
    return [str(item) for item in listed()] if callable(listed) else []


def create_renderer(name: str, scene: Any, *, shape: tuple[int, int] | None = None, seed: int = 0,
                    **options: Any) -> Renderer:
    """Build renderer ``name`` on ``scene``.

    Parameters
    ----------
    name
        A name of :func:`renderer_names`.
    scene
        What the renderer loads: a bundled scene name, a scene file, a scene object.
    shape
        (H, W) to render at; ``None`` keeps the scene's own size.
    seed
        Seed of the renderer's random numbers.
    **options
        The renderer's own keyword arguments.

    Examples
    --------
    >>> from awr_denoise import SampleRequest
    >>> from awr_denoise.renderers import create_renderer
    >>> renderer = create_renderer("synthetic", "edges", shape=(8, 8), seed=1)
    >>> renderer(SampleRequest.uniform((8, 8), 2)).total_samples
    128
    """
    return renderer_factory(name)(scene, shape=shape, seed=seed, **options)
