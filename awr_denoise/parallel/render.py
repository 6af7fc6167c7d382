"""Tiled rendering: every round of an adaptive render split into pixel tiles over workers.

The sampler decides each round on the driver; the renderer is built *in the worker* from a
picklable factory (:class:`RendererSpec`, which goes through the renderer registry of
:mod:`awr_denoise.renderers`), tile statistics are assembled exactly, and with addressable
random numbers the result equals the serial render bit for bit.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import pickle
import threading
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Executor
from typing import Any

import numpy as np

from .._typing import Shape2D
from ..buffers import SampleBuffer
from ..renderers import create_renderer, renderer_names, renderer_scenes
from ..parts import render_in_parts, stitch
from ..requests import MAX_PART_SAMPLES, FeatureTracer, Renderer, SampleRequest, SampleTracer
from ..sampling import Sampler
from .executors import default_workers, executor_or_threads, submit, wait_first
from .tiles import tile_grid

__all__ = ["RendererSpec", "TiledRenderer", "render_tiled"]

_RENDERER_CACHE_SIZE = 4  # renderers kept alive per worker thread (a path tracer holds a BVH)

@dataclasses.dataclass(frozen=True)
class RendererSpec:
    """A picklable recipe for a renderer, built where it is used (in the worker).

    A path tracer holds native objects (an Embree scene) that cannot travel between
    processes; its spec (renderer name, scene, size, seed) can. Calling the spec builds the
    renderer through the registry (:func:`awr_denoise.renderers.create_renderer`).

    Parameters
    ----------
    kind
        A registered renderer name (:func:`awr_denoise.renderers.renderer_names`): ``"tracer"``,
        ``"synthetic"``, ``"mitsuba"`` or one another package declares.
    scene
        What the renderer loads: a bundled scene name, a scene file.
    shape
        (H, W); ``None`` keeps the scene's own size (required for synthetic scenes).
    seed
        Render seed.
    options
        Further keyword arguments of the renderer as ``(name, value)`` pairs, e.g.
        ``(("sampler", "sobol"), ("threads", 1))`` for the tracer.
    digest
        SHA-256 of the scene file's bytes; set from the file when ``scene`` names one (whose path is
        made absolute). A worker refuses a file of other bytes at that path, and one edited between two
        runs builds a new renderer: on a Dask cluster a relative name was read in each worker's own
        folder, and a worker kept the renderer of a file since edited, wrong images with exit 0 (an
        attack pass). Files the scene file refers to (an environment map, meshes) are not covered.

    Examples
    --------
    >>> from awr_denoise.parallel import RendererSpec
    >>> spec = RendererSpec.synthetic("edges", (16, 16), seed=1)
    >>> spec().shape
    (16, 16)
    """

    kind: str
    scene: str
    shape: tuple[int, int] | None = None
    seed: int = 0
    options: tuple[tuple[str, Any], ...] = ()
    digest: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in renderer_names():
            raise ValueError(f"kind: {self.kind!r} is not one of {', '.join(renderer_names())}")
        try:
            bundled = renderer_scenes(self.kind)
        except ImportError:  # the extra is missing: its own hint comes when a worker builds the renderer
            bundled = []
        # A bundled scene's name stays a name, though a file of that name lies here (the renderer reads it so).
        if isinstance(self.scene, os.PathLike):  # a Path: a file, as a str naming one
            object.__setattr__(self, "scene", os.fspath(self.scene))
        if isinstance(self.scene, str) and self.digest is None and os.path.isfile(self.scene) \
                and self.scene not in bundled:
            object.__setattr__(self, "scene", os.path.abspath(self.scene))
            object.__setattr__(self, "digest", _file_digest(self.scene))
        if self.kind == "synthetic" and self.shape is None:
            raise ValueError("shape: a synthetic scene needs its (H, W)")
        if isinstance(self.scene, str) and not os.path.exists(self.scene):  # a name: one the renderer bundles
            if bundled and self.scene not in bundled:  # else every tile failed on its worker, one by one
                raise ValueError(f"scene: {self.scene!r} is neither a scene the {self.kind} renderer bundles "
                                 f"({', '.join(bundled)}) nor a file")
        if self.shape is not None:
            object.__setattr__(self, "shape", (int(self.shape[0]), int(self.shape[1])))

    @classmethod
    def tracer(cls, scene: str, *, width: int | None = None, height: int | None = None, seed: int = 0,
               **options: Any) -> RendererSpec:
        """Spec of a :class:`~awr_denoise.tracer.PathTracer` on a bundled scene.

        ``options`` are keyword arguments of ``PathTracer`` (``sampler``, ``max_depth``,
        ``threads``, ``batch_size``). Give ``threads=1`` when every worker renders tiles
        already, so the workers do not oversubscribe the cores.
        """
        shape = None if width is None and height is None else (height or 0, width or 0)
        return cls("tracer", scene, shape, int(seed), tuple(sorted(options.items())))

    @classmethod
    def synthetic(cls, scene: str, shape: Shape2D, *, seed: int = 0) -> RendererSpec:
        """Spec of a :class:`~awr_denoise.synthetic.SyntheticRenderer` on a synthetic scene."""
        return cls("synthetic", scene, (int(shape[0]), int(shape[1])), int(seed))

    def __call__(self) -> Renderer:
        """Build the renderer."""
        if self.digest is not None and _file_digest(self.scene) != self.digest:
            raise ValueError(f"scene: {self.scene} here holds other bytes than the file the renderer was asked for "
                             "(edited since, or another file at that path on this machine): every worker must see "
                             "the same scene files")
        return create_renderer(self.kind, self.scene, shape=self.shape, seed=self.seed, **dict(self.options))


def _file_digest(path: str) -> str:
    """SHA-256 of a file's bytes (a scene file: a few kilobytes to megabytes), read in 1 MiB parts."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for part in iter(lambda: f.read(1 << 20), b""):
                h.update(part)
    except OSError as exc:
        raise ValueError(f"scene: {path}: {exc.strerror or exc}") from None
    return h.hexdigest()


_worker_state = threading.local()


def _cached_renderer(factory: Callable[[], Renderer]) -> Renderer:
    """The renderer ``factory`` builds, built once per worker thread (a few kept, newest first).

    One pushed out is let go, not closed: a factory may hand out a renderer its caller still uses
    (``lambda: renderer``); a path tracer's workers end when it is collected."""
    try:
        key: Any = pickle.dumps(factory)
    except Exception:  # an unpicklable factory only ever runs in this process
        key = ("object", id(factory))
    cache = getattr(_worker_state, "renderers", None)
    if cache is None:
        cache = _worker_state.renderers = OrderedDict()
    # The factory is kept with its renderer: an id is only unique while its object lives, and a
    # new lambda at a freed one's address took that one's renderer (another scene, another seed).
    if key in cache:
        cache.move_to_end(key)
        return cache[key][1]
    renderer = factory()
    cache[key] = (factory, renderer)
    while len(cache) > _RENDERER_CACHE_SIZE:
        cache.popitem(last=False)
    return renderer


def _render_tile(factory: Callable[[], Renderer], counts: np.ndarray, first_index: np.ndarray,
                 origin: tuple[int, int], image_shape: Shape2D, names: tuple[int, int] = (0, 0)) -> SampleBuffer:
    """Render one tile of a request with the worker's renderer (runs in a worker)."""
    return _render_tile_with(_cached_renderer(factory), counts, first_index, origin, image_shape, names)


def _render_tile_with(renderer: Renderer, counts: np.ndarray, first_index: np.ndarray, origin: tuple[int, int],
                      image_shape: Shape2D, names: tuple[int, int] = (0, 0)) -> SampleBuffer:
    """Render one tile of a request and return the tile's statistics.

    A :class:`~awr_denoise.requests.SampleTracer` is asked for exactly the tile's samples; any other
    renderer gets a full-size request with no samples outside the tile, named as the request was
    (``names``: its round and sampler id, which a renderer may read).
    """
    tile_request = SampleRequest(counts, first_index)
    r0, c0 = origin
    th, tw = counts.shape
    if isinstance(renderer, SampleTracer):
        if tuple(renderer.shape) != tuple(image_shape):  # its pixels addressed absolutely: a crop, else
            raise ValueError(f"request: shape {tuple(image_shape)} does not match the renderer's "
                             f"{tuple(renderer.shape)}")
        features_too = isinstance(renderer, FeatureTracer) and renderer.features

        def render_part(first_row: int, part: SampleRequest) -> SampleBuffer:
            rows, cols, sample_index = part.pixel_list()
            before, features = renderer.stats["nonfinite"], None
            if features_too:
                values, features = renderer.trace_features(rows + r0 + first_row, cols + c0, sample_index)
            else:
                values = renderer.trace_samples(rows + r0 + first_row, cols + c0, sample_index)
            told = SampleBuffer.from_samples(rows * tw + cols, np.asarray(values), part.shape,
                                             channels=renderer.channels, features=features)
            dropped = int(renderer.stats["nonfinite"] - before)
            return dataclasses.replace(told, nonfinite=dropped) if dropped else told

        # In parts, as the tracer renders a request: every sample of a part is held at once.
        return render_in_parts(tile_request, render_part, getattr(renderer, "max_part_samples", MAX_PART_SAMPLES))
    full_counts = np.zeros(image_shape, np.int64)
    full_first = np.zeros(image_shape, np.int64)
    window = (slice(r0, r0 + th), slice(c0, c0 + tw))
    full_counts[window] = counts
    full_first[window] = first_index
    full = renderer(SampleRequest(full_counts, full_first, *names))
    if tuple(full.shape) != tuple(image_shape):  # cropped, another size would pass for this one
        raise ValueError(f"request: shape {tuple(image_shape)} does not match the renderer's {tuple(full.shape)}")
    return dataclasses.replace(full.crop(*window), nonfinite=full.nonfinite)


class TiledRenderer:
    """A :class:`~awr_denoise.Renderer` that renders each request as pixel tiles on an executor.

    Every tile of a request becomes one task; the worker builds the renderer from
    ``renderer_factory`` (once per worker thread) and renders the tile's samples. Tiles do not
    overlap, so the request's statistics are the tiles' statistics put side by side, with no
    arithmetic: with a renderer whose random numbers are addressed by
    (seed, pixel, sample index, dimension) the result is bitwise the one-piece render (to rounding where
    one row of a request holds more than ``MAX_PART_SAMPLES``: docs/distributed.md).

    Parameters
    ----------
    renderer_factory
        Zero-argument callable returning the renderer, e.g. a :class:`RendererSpec`; it must
        be picklable for process and Dask executors.
    tile
        Tile side in pixels, or (height, width).
    executor
        Runs the tiles; ``None`` renders them one after the other in this thread.

    Notes
    -----
    A :class:`~awr_denoise.requests.SampleTracer` (the bundled path tracer, the synthetic renderer, the
    Mitsuba 3 adapter) is asked for exactly a tile's samples, so a task's memory follows the
    tile. Any other renderer receives a full-size request with zero
    samples outside the tile and its result is cropped: correct, but each task then holds
    full-frame arrays.
    """

    def __init__(self, renderer_factory: Callable[[], Renderer], *, tile: int | tuple[int, int] = 128,
                 executor: Executor | None = None) -> None:
        if not callable(renderer_factory):
            raise TypeError(f"renderer_factory: expected a callable that builds a renderer, got {renderer_factory!r}")
        tile_grid((1, 1), tile)  # validates the tile size now
        if executor is not None and not isinstance(executor, Executor):
            raise TypeError(f"executor: expected a concurrent.futures.Executor, got {type(executor).__name__}")
        self.renderer_factory = renderer_factory
        self.tile = tile
        self.executor = executor
        self._renderer: Renderer | None = None  # without an executor, built at the first request

    def __call__(self, request: SampleRequest) -> SampleBuffer:
        """Render ``request`` tile by tile and return its statistics."""
        if not isinstance(request, SampleRequest):
            raise TypeError(f"request: expected a SampleRequest, got {type(request).__name__}")
        shape = request.shape
        tiles = [t for t in tile_grid(shape, self.tile) if request.counts[t].any()] or tile_grid(shape, self.tile)[:1]
        args = [(self.renderer_factory, request.counts[t], request.first_index[t], (t[0].start, t[1].start), shape,
                 (request.round, request.sampler_id)) for t in tiles]
        if self.executor is None:  # this renderer's own, built once: no cache outlives it
            if self._renderer is None:
                self._renderer = self.renderer_factory()
            results = [_render_tile_with(self._renderer, *a[1:]) for a in args]
        else:
            futures = [submit(self.executor, _render_tile, *a) for a in args]
            try:
                remaining = set(futures)
                while remaining:  # a lost cluster is named, not waited on for ever (wait_first)
                    done = wait_first(self.executor, remaining)
                    remaining -= done
                    for f in done:
                        f.result()  # the first failed tile at once, as before
                results = [f.result() for f in futures]
            except BaseException:  # a failed tile, Ctrl-C: the round's other tiles are not rendered
                for f in futures:
                    f.cancel()
                raise
        return stitch(shape, tiles, results)


def render_tiled(renderer_factory: Callable[[], Renderer], sampler: Sampler, *, total_spp: float,
                 tile: int | tuple[int, int] = 128, executor: Executor | None = None, progress: bool = False,
                 callback: Callable[[SampleRequest, SampleBuffer], bool | None] | None = None) -> SampleBuffer:
    """Adaptive (or uniform) rendering with every round split into tiles over an executor.

    Exactly :meth:`Sampler.run <awr_denoise.Sampler.run>` with a :class:`TiledRenderer`: the
    sampler decides each round on the driver, the tiles of its request are rendered by the
    workers, and the merged statistics are told back. With addressable random numbers the
    result is bitwise identical to ``sampler.run(renderer_factory(), total_spp)`` (to rounding where one
    row of a round holds more than ``MAX_PART_SAMPLES``: docs/distributed.md).

    Parameters
    ----------
    renderer_factory
        Zero-argument picklable callable building the renderer in the worker, e.g.
        ``RendererSpec.tracer("cornell_gi", seed=3, threads=1)``; never the renderer itself
        (a path tracer's Embree scene cannot be pickled).
    sampler
        The ask/tell sampler (e.g. :class:`~awr_denoise.AdaptiveSampler`); it stays here.
    total_spp
        Average samples per pixel to reach.
    tile
        Tile side in pixels, or (height, width).
    executor
        Runs the tiles; default a thread pool (one thread per CPU) for this call.
    progress, callback
        As in :meth:`Sampler.run <awr_denoise.Sampler.run>`.

    Returns
    -------
    SampleBuffer
        The sampler's merged statistics.

    Examples
    --------
    >>> from awr_denoise import AdaptiveSampler
    >>> from awr_denoise.parallel import RendererSpec, render_tiled
    >>> spec = RendererSpec.synthetic("edges", (32, 32), seed=1)
    >>> buffer = render_tiled(spec, AdaptiveSampler((32, 32)), total_spp=8, tile=16)
    >>> buffer.total_samples
    8192
    """
    with executor_or_threads(executor, default_workers()) as pool:
        renderer = TiledRenderer(renderer_factory, tile=tile, executor=pool)
        return sampler.run(renderer, total_spp, progress=progress, callback=callback)
