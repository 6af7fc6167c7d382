"""Parallel and distributed execution: frame sequences, tiled reconstruction, tiled rendering.

Everything here takes any :class:`concurrent.futures.Executor` through ``executor=``. Without
one, work runs on in-process threads (:class:`~concurrent.futures.ThreadPoolExecutor`), which
need neither a cluster nor Dask: numpy, PyWavelets and embreex release the GIL in their array
operations, and on two cores two threads were about as much faster than one as two Dask
worker processes (docs/distributed.md has the measurements).
:func:`get_executor` makes the other kinds on demand:

* ``"threads"``: a thread pool (the default);
* ``"processes"``: a process pool on this machine;
* ``"dask"``: with ``pip install "awr-denoise[dask]"``, a :class:`distributed.LocalCluster` of
  worker processes, or a connection to a running scheduler (``scheduler="tcp://host:8786"``
  or a scheduler file), which is how one spreads work over several machines.

Three kinds of work are offered, each split into independent tasks:

* :func:`denoise_frames`: one task per frame of a sequence. Tasks get file *paths*, read
  their sample dump, reconstruct and write the image themselves, so no pixel crosses the
  network; the result is bitwise identical to a serial run.
* :func:`reconstruct_tiled`: one task per tile of a large frame. Each task gets only its tile
  plus a halo wide enough for the wavelet support at every level (:func:`halo_width`), and the
  thresholding domain's scale is fixed globally, so the result matches the whole-frame
  reconstruction to rounding (docs/distributed.md derives the halo and the tolerance).
* :func:`render_tiled` / :class:`TiledRenderer`: every round of an adaptive render is split
  into pixel tiles rendered on the workers. The renderer is built *in the worker* from a
  picklable factory (:class:`RendererSpec`), tile statistics are assembled exactly, and with
  addressable random numbers the result equals the serial render bit for bit.

:func:`add_executor_arguments` and :func:`executor_from_args` give command-line tools the
``--workers``, ``--scheduler`` and ``--executor`` options.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import dataclasses
import functools
import os
import pickle
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

import numpy as np
import pywt

from ._typing import FloatArray, Shape2D
from .buffers import SampleBuffer, default_channel_names
from .domains import Domain, resolve_domain
from .errors import AWRError
from .reconstruct import DEFAULT_DOMAIN, _filled_mean, reconstruct
from .requests import Renderer, SampleRequest
from .sampling import Sampler
from .wavelets import default_levels, max_levels

__all__ = [
    "EXECUTOR_KINDS",
    "DASK_INSTALL_HINT",
    "FramesFailedError",
    "RendererSpec",
    "TiledRenderer",
    "add_executor_arguments",
    "denoise_frames",
    "executor_from_args",
    "executor_requested",
    "get_executor",
    "halo_width",
    "reconstruct_tiled",
    "render_tiled",
    "tile_grid",
]

EXECUTOR_KINDS = ("threads", "processes", "dask")
"""Kinds of executor :func:`get_executor` can make."""

DASK_INSTALL_HINT = 'pip install "awr-denoise[dask]"'
"""How to install the optional Dask dependency."""

_RENDERER_CACHE_SIZE = 4  # renderers kept alive per worker thread (a path tracer holds a BVH)


# ============================================================================ executors
def _default_workers() -> int:
    return max(1, os.cpu_count() or 1)


def _import_distributed() -> Any:
    try:
        import distributed
    except ImportError as exc:
        raise ImportError(f'executor "dask" needs Dask distributed: {DASK_INSTALL_HINT}') from exc
    return distributed


@contextlib.contextmanager
def _glibc_malloc_tuning() -> Iterator[None]:
    """Start Dask worker processes with glibc's own malloc tuning instead of Dask's.

    Dask starts workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (and writes it into this
    process's environment when it starts a local cluster). Setting it switches off glibc's
    adaptive mmap threshold, so every numpy temporary above 128 KiB is mapped afresh and
    page-faulted in: four reconstructions of a 512 x 512 frame took 0.59 s in such a worker
    against 0.35 s in the main process on the development machine (0.25 s of system time,
    about 190 000 minor page faults). Unsetting it for the workers this module starts removes the gap.
    """
    import dask

    saved = os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
            yield
    finally:
        if saved is not None:
            os.environ["MALLOC_TRIM_THRESHOLD_"] = saved


@contextlib.contextmanager
def get_executor(kind: str | None = None, *, workers: int | None = None,
                 scheduler: str | os.PathLike[str] | None = None) -> Iterator[Executor]:
    """An executor for the ``executor=`` parameters of this module, shut down on exit.

    Parameters
    ----------
    kind
        ``"threads"``, ``"processes"`` or ``"dask"`` (:data:`EXECUTOR_KINDS`). Default:
        ``"dask"`` when ``scheduler`` is given, else ``"threads"``.
    workers
        Threads, processes or Dask worker processes (one thread each) to start; default the
        number of CPUs. Ignored when connecting to a running scheduler, whose workers are
        whatever was started there.
    scheduler
        Address of a running Dask scheduler (``"tcp://host:8786"``) or path of the JSON
        scheduler file written by ``dask scheduler --scheduler-file``, dask-jobqueue or
        dask-mpi. Only the client is closed on exit; the cluster keeps running.

    Yields
    ------
    concurrent.futures.Executor
        A thread or process pool, or ``distributed.Client.get_executor()`` (a real
        ``concurrent.futures.Executor`` whose futures are ``concurrent.futures.Future``).

    Raises
    ------
    ImportError
        ``kind="dask"`` without Dask installed; the message says what to install.

    Notes
    -----
    Dask is imported only when asked for. The local cluster listens on the loopback interface
    only and starts no dashboard; its workers keep glibc's default malloc tuning rather than
    Dask's ``MALLOC_TRIM_THRESHOLD_``, which made numpy-heavy tasks 1.7x slower
    (docs/distributed.md). Process pools use the ``spawn`` start method, so they are
    safe to start from a program that already runs threads.

    Examples
    --------
    >>> from awr_denoise.parallel import get_executor
    >>> with get_executor("threads", workers=2) as executor:
    ...     list(executor.map(abs, [-1, 2]))
    [1, 2]
    """
    if kind is None:
        kind = "dask" if scheduler is not None else "threads"
    if kind not in EXECUTOR_KINDS:
        raise ValueError(f"kind: {kind!r} is not one of {', '.join(EXECUTOR_KINDS)}")
    if workers is not None and (isinstance(workers, bool) or int(workers) < 1):
        raise ValueError(f"workers: must be a whole number >= 1, got {workers!r}")
    if scheduler is not None and kind != "dask":
        raise ValueError(f"scheduler: a scheduler address needs kind='dask', got kind={kind!r}")
    n_workers = _default_workers() if workers is None else int(workers)
    if kind == "threads":
        with cf.ThreadPoolExecutor(max_workers=n_workers, thread_name_prefix="awr") as pool:
            yield pool
        return
    if kind == "processes":
        import multiprocessing

        with cf.ProcessPoolExecutor(max_workers=n_workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            yield pool
        return
    distributed = _import_distributed()
    with contextlib.ExitStack() as stack:
        if scheduler is None:
            stack.enter_context(_glibc_malloc_tuning())
            cluster = stack.enter_context(distributed.LocalCluster(
                n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                dashboard_address=None,
                # No dashboard; the scheduler's remaining HTTP routes take a free loopback port
                # instead of 8787, so several clusters can coexist without a port warning.
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}))
            client = stack.enter_context(distributed.Client(cluster))
        elif Path(scheduler).suffix == ".json" and Path(scheduler).is_file():
            client = stack.enter_context(distributed.Client(scheduler_file=str(scheduler)))
        else:
            client = stack.enter_context(distributed.Client(str(scheduler)))
        executor = client.get_executor(pure=False)
        try:
            yield executor
        finally:
            executor.shutdown(wait=True)


def add_executor_arguments(parser: argparse.ArgumentParser | argparse._ArgumentGroup, *,
                           tile_option: bool = False) -> None:
    """Add ``--workers N``, ``--scheduler ADDRESS`` and ``--executor KIND`` to a parser.

    Read them back with :func:`executor_from_args`; :func:`executor_requested` tells whether
    any was given.

    Parameters
    ----------
    parser
        An ``argparse`` parser (or argument group) of a subcommand.
    tile_option
        Also add ``--tile PIXELS`` (default 128), the tile side of :class:`TiledRenderer`.
    """
    group = parser.add_argument_group("parallel execution (see docs/distributed.md)") \
        if isinstance(parser, argparse.ArgumentParser) else parser
    group.add_argument("--workers", type=int, metavar="N",
                       help="parallel workers: threads, processes or local Dask workers (default: the CPUs)")
    group.add_argument("--scheduler", metavar="ADDRESS",
                       help="run on a Dask cluster: scheduler address (tcp://host:8786) or scheduler JSON "
                            f"file; implies --executor dask ({DASK_INSTALL_HINT})")
    group.add_argument("--executor", choices=EXECUTOR_KINDS,
                       help="in-process threads (default), local processes, or Dask (a local cluster "
                            "unless --scheduler is given)")
    if tile_option:
        group.add_argument("--tile", type=int, default=128, metavar="PIXELS",
                           help="tile side when the work is split over workers (default 128)")


def executor_requested(args: argparse.Namespace) -> bool:
    """Whether any of ``--workers``, ``--scheduler`` or ``--executor`` was given.

    Command-line tools can keep their plain serial path when none was.
    """
    return any(getattr(args, name, None) is not None for name in ("workers", "scheduler", "executor"))


def executor_from_args(args: argparse.Namespace) -> contextlib.AbstractContextManager[Executor]:
    """The :func:`get_executor` context manager the options of :func:`add_executor_arguments` ask for.

    Parameters
    ----------
    args
        Parsed arguments holding ``workers``, ``scheduler`` and ``executor`` (missing ones
        count as not given).

    Raises
    ------
    ValueError
        ``--scheduler`` with ``--executor threads`` or ``processes``, or ``--workers`` below 1.
    """
    workers = getattr(args, "workers", None)
    scheduler = getattr(args, "scheduler", None)
    kind = getattr(args, "executor", None)
    if scheduler is not None and kind not in (None, "dask"):
        raise ValueError(f"--scheduler: needs --executor dask, not --executor {kind}")
    if workers is not None and workers < 1:
        raise ValueError(f"--workers: must be >= 1, got {workers}")
    return get_executor(kind, workers=workers, scheduler=scheduler)


@contextlib.contextmanager
def _executor_or_threads(executor: Executor | None, tasks: int) -> Iterator[Executor]:
    """``executor`` itself, or a thread pool (at most one thread per task) for the call."""
    if executor is not None:
        if not isinstance(executor, Executor):
            raise TypeError(f"executor: expected a concurrent.futures.Executor, got {type(executor).__name__}")
        yield executor
        return
    with cf.ThreadPoolExecutor(max_workers=max(1, min(tasks, _default_workers())), thread_name_prefix="awr") as pool:
        yield pool


def _dask_client(executor: Executor) -> Any | None:
    """The ``distributed.Client`` behind a Dask ``ClientExecutor``, else None (no Dask import)."""
    if type(executor).__module__.startswith("distributed"):
        return getattr(executor, "_client", None)
    return None


def _executor_width(executor: Executor) -> int:
    """How many tasks the executor runs at once, as far as it tells (else the local CPUs)."""
    client = _dask_client(executor)
    if client is not None:
        return max(1, sum(client.nthreads().values()))
    return max(1, int(getattr(executor, "_max_workers", 0) or _default_workers()))


def _submit(executor: Executor, fn: Callable[..., Any], *args: Any) -> cf.Future:
    """``executor.submit(fn, *args)``, never answered from Dask's cache of earlier results.

    Dask treats tasks as pure by default: a task with the same function and arguments as one
    whose result it still holds is not run again. These tasks write files and render with
    side effects, so on Dask they are submitted with ``pure=False``.
    """
    if _dask_client(executor) is not None:
        return executor.submit(fn, *args, pure=False)
    return executor.submit(fn, *args)


# ============================================================================ frames
class FramesFailedError(AWRError):
    """Some frames of :func:`denoise_frames` failed; the others were written.

    Attributes
    ----------
    failures
        Input path to the exception its frame raised, in input order.
    """

    def __init__(self, failures: dict[str, BaseException], total: int) -> None:
        self.failures = dict(failures)
        lines = [f"{len(failures)} of {total} frame(s) failed:"]
        lines += [f"  {path}: {type(exc).__name__}: {exc}" for path, exc in failures.items()]
        super().__init__("\n".join(lines))


def _denoise_frame(source: str, target: str, overwrite: bool, half: bool, read_options: dict[str, Any],
                   reconstruct_options: dict[str, Any]) -> str:
    """One frame: read the dump, reconstruct, write the image atomically (runs in a worker)."""
    from . import __version__
    from .io import read_sample_buffer, write_image
    from .reconstruct import reconstruct_detailed

    buffer = read_sample_buffer(source, **read_options)
    result = reconstruct_detailed(buffer, variance_probes=0, **reconstruct_options)
    domain = result.domain
    header = {
        "awr:version": __version__,
        "awr:c_s": float(reconstruct_options.get("c_s", 1.0)),
        "awr:wavelet": str(reconstruct_options.get("wavelet", "bior4.4")),
        "awr:levels": int(result.levels),
        "awr:domain": domain.name,
        "awr:mode": str(reconstruct_options.get("mode", "channels")),
        "awr:input": os.path.basename(source),
        "awr:spp": float(buffer.total_samples / buffer.count.size),
        "awr:fraction_zeroed": float(result.fraction_zeroed),
    }
    write_image(target, result.image, channels=buffer.channels, header=header, half=half, overwrite=overwrite)
    return str(target)


def denoise_frames(inputs: Sequence[str | os.PathLike[str]], outputs: Sequence[str | os.PathLike[str]], *,
                   executor: Executor | None = None, overwrite: bool = False, half: bool = False,
                   read_options: dict[str, Any] | None = None, **reconstruct_options: Any) -> list[Path]:
    """Denoise a sequence of sample dumps, one task per frame.

    Each task receives two paths, reads the dump with
    :func:`~awr_denoise.io.read_sample_buffer`, runs :func:`~awr_denoise.reconstruct` and writes
    the image with :func:`~awr_denoise.io.write_image` (atomic: a failed frame leaves no partial
    file). The work in a task is the serial computation, so every image is bitwise identical to
    a serial run whatever the executor.

    Parameters
    ----------
    inputs
        Sample dumps, one per frame. With a Dask cluster the paths must be readable on every
        worker (a shared file system).
    outputs
        Image to write for each input, same length and order.
    executor
        Runs the frames; default a thread pool of up to one thread per CPU for this call.
    overwrite
        Replace existing outputs. Without it an existing output is refused before any frame
        is processed.
    half
        Write HALF channels (see :func:`~awr_denoise.io.write_image`).
    read_options
        Keyword arguments of :func:`~awr_denoise.io.read_sample_buffer` (``preset``,
        ``color``, ``variance``, ...).
    **reconstruct_options
        Keyword arguments of :func:`~awr_denoise.reconstruct` (``c_s``, ``wavelet``,
        ``levels``, ``domain``, ``mode``, ``boundary``). Each frame runs on one worker.

    Returns
    -------
    list of Path
        The written images, in input order.

    Raises
    ------
    FramesFailedError
        When frames failed; every other frame was still written. ``failures`` maps each
        failed input to its exception.
    FileExistsError
        An output exists and ``overwrite`` is False (checked before any work starts).
    ValueError
        Mismatched lengths, an output listed twice, or an output that is also an input.
    """
    from .io.atomic import check_writable

    sources = [str(p) for p in inputs]
    targets = [str(p) for p in outputs]
    if len(sources) != len(targets):
        raise ValueError(f"outputs: {len(targets)} given for {len(sources)} input(s)")
    resolved = [Path(t).resolve() for t in targets]
    if len(set(resolved)) != len(resolved):
        raise ValueError("outputs: the same file is listed more than once")
    collisions = set(resolved) & {Path(s).resolve() for s in sources}
    if collisions:
        raise ValueError(f"outputs: {sorted(map(str, collisions))[0]} is also an input")
    for target in targets:
        check_writable(target, overwrite=overwrite)
    if not sources:
        return []
    read_options = dict(read_options or {})
    with _executor_or_threads(executor, len(sources)) as pool:
        futures = [_submit(pool, _denoise_frame, s, t, overwrite, half, read_options, dict(reconstruct_options))
                   for s, t in zip(sources, targets)]
        cf.wait(futures)
    failures = {s: f.exception() for s, f in zip(sources, futures) if f.exception() is not None}
    if failures:
        raise FramesFailedError(failures, len(sources)) from next(iter(failures.values()))
    return [Path(f.result()) for f in futures]


# ============================================================================ tiles
def tile_grid(shape: Shape2D, tile: int | tuple[int, int]) -> list[tuple[slice, slice]]:
    """Row-major ``(rows, cols)`` slices that cover an (H, W) image with tiles of ``tile`` pixels.

    Parameters
    ----------
    shape
        (H, W) of the image.
    tile
        Tile side, or (height, width); the last row and column of tiles may be smaller.
    """
    th, tw = (tile, tile) if isinstance(tile, (int, np.integer)) else tile
    th, tw = int(th), int(tw)
    if th < 1 or tw < 1:
        raise ValueError(f"tile: must be >= 1 pixel, got {tile!r}")
    h, w = int(shape[0]), int(shape[1])
    return [(slice(r, min(r + th, h)), slice(c, min(c + tw, w)))
            for r in range(0, h, th) for c in range(0, w, tw)]


def halo_width(wavelet: str = "bior4.4", levels: int = 5) -> int:
    """Pixels of context a tile needs on each side for an exact wavelet reconstruction.

    A level-``k`` coefficient's equivalent analysis filter spans at most
    ``(F - 1)(2^k - 1) + 1`` pixels, ``F`` the longer of the wavelet's decomposition and
    reconstruction filters, and its synthesis filter as many around the same place, so an
    output pixel depends on input pixels at most ``(F - 1)(2^L - 1)`` away along each axis.
    Soft thresholding acts on each coefficient alone and adds no reach. The halo returned is
    the exact reach, computed once from the filters: for every coefficient of every band and
    level (away from the signal's ends), the farthest pair of an input pixel in its analysis
    support and an output pixel in its synthesis support. It equals the bound for orthogonal
    wavelets and is smaller where filters have zero taps (bior4.4: ``7 (2^L - 1)``, not
    ``9 (2^L - 1)``). docs/distributed.md has the derivation and the measured reach.

    Parameters
    ----------
    wavelet
        PyWavelets discrete wavelet.
    levels
        Decomposition depth.

    Examples
    --------
    >>> from awr_denoise.parallel import halo_width
    >>> halo_width("bior4.4", 5), halo_width("haar", 3), halo_width("db2", 2)
    (217, 7, 9)
    """
    if isinstance(levels, bool) or int(levels) < 1:
        raise ValueError(f"levels: must be >= 1, got {levels!r}")
    return _transform_reach(pywt.Wavelet(wavelet).name, int(levels))


def _support_ends(nonzero: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First and last True of every row, and whether the row has any."""
    first = np.argmax(nonzero, axis=1)
    last = nonzero.shape[1] - 1 - np.argmax(nonzero[:, ::-1], axis=1)
    return first, last, nonzero.any(axis=1)


@functools.lru_cache(maxsize=64)
def _transform_reach(wavelet: str, levels: int) -> int:
    """Exact reach of the ``levels``-deep transform of ``wavelet`` along one axis (see :func:`halo_width`)."""
    w = pywt.Wavelet(wavelet)
    bound = (max(w.dec_len, w.rec_len) - 1) * (2**levels - 1)
    n = 4 * bound + 2 ** (levels + 3)  # long enough for coefficients that never see an end
    reach = 0
    for k in range(1, levels + 1):
        # Row j of each band: the analysis filter of coefficient j (impulses through the DWT).
        analysis = pywt.wavedec(np.eye(n), w, mode="symmetric", level=k, axis=0)
        for band in (0, 1):  # the level-k approximation and detail, as one axis of a 2-D band
            rows = analysis[band]
            coeffs = [np.zeros((c.shape[0], rows.shape[0])) for c in analysis]
            coeffs[band] = np.eye(rows.shape[0])
            # Column j: the synthesis of a unit coefficient j.
            synthesis = pywt.waverec(coeffs, w, mode="symmetric", axis=0)[:n].T
            a_first, a_last, a_any = _support_ends(rows != 0)
            s_first, s_last, s_any = _support_ends(synthesis != 0)
            interior = a_any & s_any & (a_first >= bound) & (a_last <= n - 1 - bound)
            if interior.any():
                reach = max(reach, int(np.max(np.maximum(s_last - a_first, a_last - s_first)[interior])))
    return reach


def _window(core: slice, halo: int, align: int, length: int) -> slice:
    """``core`` grown by ``halo`` on both sides, its start moved down to a multiple of ``align``.

    The decimated transform is shift-variant: a window that starts on a multiple of ``2^L``
    puts its coefficients on the same grid as the whole image's.
    """
    start = max(0, core.start - halo)
    start -= start % align
    return slice(start, min(length, core.stop + halo))


def _global_domain(domain: str | Domain, filled_mean: FloatArray) -> Domain:
    """The domain with its scale fixed from the whole image, exactly as :meth:`Domain.bound` would."""
    dom = resolve_domain(domain)
    if dom.name == "linear" or dom.scale is not None:
        return dom
    return dataclasses.replace(dom, scale=dom.resolved_scale(filled_mean))


def _reconstruct_window(count: np.ndarray, mean: FloatArray, variance: FloatArray, channels: tuple[str, ...],
                        core: tuple[slice, slice], options: dict[str, Any]) -> FloatArray:
    """Reconstruct one tile+halo window and return the tile's pixels (runs in a worker)."""
    window = SampleBuffer(count, mean, variance, channels, np.ones(count.shape, bool))
    return reconstruct(window, **options)[core]


def reconstruct_tiled(buffer: SampleBuffer, *, tile: int | tuple[int, int] = 512, halo: int | None = None,
                      executor: Executor | None = None, c_s: float = 1.0, wavelet: str = "bior4.4",
                      levels: int | None = None, domain: str | Domain = DEFAULT_DOMAIN, mode: str = "channels",
                      boundary: str = "symmetric") -> FloatArray:
    """Reconstruct a frame tile by tile; equals :func:`~awr_denoise.reconstruct` to rounding.

    Each task receives one tile with a halo of :func:`halo_width` pixels on every side (its
    start aligned to ``2^levels`` so the wavelet grid matches the whole frame's), reconstructs
    it, and returns the tile's pixels. Everything that depends on the whole frame is fixed
    before the tiles leave: the number of levels, the domain's ``scale`` (the frame's mean
    absolute pixel value, which :class:`~awr_denoise.Domain` would otherwise take per tile),
    the fill of sample-less pixels and the pooled variance of pixels whose variance is unknown.

    Parameters
    ----------
    buffer
        Per-pixel sample statistics of the whole frame.
    tile
        Tile side in pixels, or (height, width). Each task holds about
        ``(tile + 2 * halo)^2 * (8 + 16 * C)`` bytes of input.
    halo
        Context on each side of a tile; default :func:`halo_width` ``(wavelet, levels)``
        (one more with a robust domain, whose 3x3 median reads one pixel further), the
        smallest that is exact. A smaller halo trades accuracy near tile borders for less
        work.
    executor
        Runs the tiles; default a thread pool for this call.
    c_s, wavelet, levels, domain, mode, boundary
        As in :func:`~awr_denoise.reconstruct`; ``levels`` defaults to the whole frame's
        :func:`~awr_denoise.wavelets.default_levels`.

    Returns
    -------
    numpy.ndarray
        (H, W, C) reconstructed image.

    Notes
    -----
    With the default halo, tile and whole-frame results differ only by floating-point
    rounding; the tests hold them to ``1e-12`` of the image's largest value
    (docs/distributed.md). Windows are cut only as earlier tasks finish (at most twice as
    many in flight as the executor has workers), so the caller holds the frame, three
    frame-sized working arrays and a few windows. Tiles are shipped to Dask workers with
    ``Client.scatter`` so they do not travel through the scheduler.
    """
    if not isinstance(buffer, SampleBuffer):
        raise TypeError(f"buffer: expected a SampleBuffer, got {type(buffer).__name__}")
    shape = buffer.shape
    levels = default_levels(shape) if levels is None else levels
    if isinstance(levels, bool) or not 1 <= int(levels) <= max_levels(shape):
        raise ValueError(f"levels: {levels} is outside 1..{max_levels(shape)} for an image of shape {shape}")
    levels = int(levels)
    if halo is None:
        # The robust domain's 3x3 median reads one pixel further than the transform does.
        halo = halo_width(wavelet, levels) + (1 if resolve_domain(domain).robust else 0)
    halo = int(halo)
    if halo < 0:
        raise ValueError(f"halo: must be >= 0, got {halo}")
    mean = _filled_mean(buffer)
    options = {"c_s": c_s, "wavelet": wavelet, "levels": levels, "domain": _global_domain(domain, mean),
               "mode": mode, "boundary": boundary}
    # Windows carry the frame's per-sample variance with unknown entries already pooled over the
    # whole frame, so every window pixel is "known". A pixel with fewer than two samples (whose
    # variance a window would pool again) travels as 2 samples of variance 2 s2: its variance
    # of the mean, s2 / max(n, 1), comes out the same (x2 and /2 are exact in floating point).
    few = buffer.count < 2
    count = np.where(few, 2, buffer.count)
    estimated = buffer.estimated_variance()
    per_sample = np.where(few[..., None], 2.0 * estimated, estimated)
    grid = tile_grid(shape, tile)
    image = np.empty(shape + (buffer.n_channels,))
    with _executor_or_threads(executor, len(grid)) as pool:
        client = _dask_client(pool)
        in_flight: dict[cf.Future, tuple[slice, slice]] = {}
        remaining = iter(grid)

        def submit_next() -> bool:
            """Cut the next tile's window and submit it; False when every tile is out."""
            tile_slices = next(remaining, None)
            if tile_slices is None:
                return False
            rows, cols = tile_slices
            wr = _window(rows, halo, 2**levels, shape[0])
            wc = _window(cols, halo, 2**levels, shape[1])
            if min(wr.stop - wr.start, wc.stop - wc.start) < 2**levels:
                wr, wc = slice(0, shape[0]), slice(0, shape[1])  # too small to decompose: use the frame
            core = (slice(rows.start - wr.start, rows.stop - wr.start),
                    slice(cols.start - wc.start, cols.stop - wc.start))
            crops: list[Any] = [np.ascontiguousarray(a[wr, wc]) for a in (count, mean, per_sample)]
            if client is not None:
                crops = client.scatter(crops, hash=False)
            in_flight[_submit(pool, _reconstruct_window, *crops, buffer.channels, core, options)] = (rows, cols)
            return True

        # Windows are cut as tasks finish, so the driver holds at most a few of them at once.
        limit = 2 * _executor_width(pool)
        while len(in_flight) < limit and submit_next():
            pass
        while in_flight:
            done, _ = cf.wait(in_flight, return_when=cf.FIRST_COMPLETED)
            for future in done:
                image[in_flight.pop(future)] = future.result()
                submit_next()
    return image


# ============================================================================ rendering
@dataclasses.dataclass(frozen=True)
class RendererSpec:
    """A picklable recipe for a renderer, built where it is used (in the worker).

    A path tracer holds native objects (an Embree scene) that cannot travel between
    processes; its spec (scene name, size, seed) can. Calling the spec builds the renderer.

    Parameters
    ----------
    kind
        ``"tracer"`` (:class:`awr_denoise.tracer.PathTracer`) or ``"synthetic"``
        (:class:`awr_denoise.synthetic.SyntheticRenderer`).
    scene
        Bundled scene name (a tracer scene, or one of :data:`awr_denoise.synthetic.SCENES`).
    shape
        (H, W); ``None`` keeps a tracer scene's own size (required for synthetic scenes).
    seed
        Render seed.
    options
        Further keyword arguments of the renderer as ``(name, value)`` pairs, e.g.
        ``(("sampler", "sobol"), ("threads", 1))`` for the tracer.

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

    def __post_init__(self) -> None:
        if self.kind not in ("tracer", "synthetic"):
            raise ValueError(f"kind: {self.kind!r} is not one of tracer, synthetic")
        if self.kind == "synthetic" and self.shape is None:
            raise ValueError("shape: a synthetic scene needs its (H, W)")
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
        if self.kind == "synthetic":
            from .synthetic import SyntheticRenderer, make_scene

            return SyntheticRenderer(make_scene(self.scene, self.shape), seed=self.seed)
        from .tracer import PathTracer, load_scene

        height, width = self.shape if self.shape is not None else (None, None)
        scene = load_scene(self.scene, width=width or None, height=height or None)
        return PathTracer(scene, seed=self.seed, **dict(self.options))


_worker_state = threading.local()


def _cached_renderer(factory: Callable[[], Renderer]) -> Renderer:
    """The renderer ``factory`` builds, built once per worker thread (a few kept, newest first)."""
    try:
        key: Any = pickle.dumps(factory)
    except Exception:  # an unpicklable factory only ever runs in this process
        key = ("object", id(factory))
    cache = getattr(_worker_state, "renderers", None)
    if cache is None:
        cache = _worker_state.renderers = OrderedDict()
    if key in cache:
        cache.move_to_end(key)
        return cache[key]
    renderer = factory()
    cache[key] = renderer
    while len(cache) > _RENDERER_CACHE_SIZE:
        cache.popitem(last=False)
    return renderer


def _render_tile(factory: Callable[[], Renderer], counts: np.ndarray, first_index: np.ndarray,
                 origin: tuple[int, int], image_shape: Shape2D) -> SampleBuffer:
    """Render one tile of a request and return the tile's statistics (runs in a worker).

    Renderers with ``trace_samples(rows, cols, sample_index)`` are asked for exactly the tile's
    samples; any other renderer gets a full-size request with no samples outside the tile.
    """
    renderer = _cached_renderer(factory)
    tile_request = SampleRequest(counts, first_index)
    r0, c0 = origin
    th, tw = counts.shape
    if hasattr(renderer, "trace_samples"):
        rows, cols, sample_index = tile_request.pixel_list()
        stats = getattr(renderer, "stats", None)
        before = stats.get("nonfinite", 0) if isinstance(stats, dict) else 0
        values = np.asarray(renderer.trace_samples(rows + r0, cols + c0, sample_index))
        after = stats.get("nonfinite", 0) if isinstance(stats, dict) else 0
        channels = getattr(renderer, "channels", None) or default_channel_names(values.shape[1] if values.ndim == 2
                                                                                 else 1)
        tile = SampleBuffer.from_samples(rows * tw + cols, values, (th, tw), channels=channels)
        if after != before:
            tile = SampleBuffer(tile.count, tile.mean, tile.variance, tile.channels, tile.variance_known,
                                int(after - before))
        return tile
    full_counts = np.zeros(image_shape, np.int64)
    full_first = np.zeros(image_shape, np.int64)
    window = (slice(r0, r0 + th), slice(c0, c0 + tw))
    full_counts[window] = counts
    full_first[window] = first_index
    full = renderer(SampleRequest(full_counts, full_first))
    return SampleBuffer(full.count[window], full.mean[window], full.variance[window], full.channels,
                        full.variance_known[window], full.nonfinite)


class TiledRenderer:
    """A :class:`~awr_denoise.Renderer` that renders each request as pixel tiles on an executor.

    Every tile of a request becomes one task; the worker builds the renderer from
    ``renderer_factory`` (once per worker thread) and renders the tile's samples. Tiles do not
    overlap, so the request's statistics are the tiles' statistics put side by side, with no
    arithmetic: with a renderer whose random numbers are addressed by
    (seed, pixel, sample index, dimension) the result is bitwise the one-piece render.

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
    Renderers offering ``trace_samples(rows, cols, sample_index) -> (N, C)`` (the bundled
    path tracer, the synthetic renderer) are asked for exactly a tile's samples, so a task's
    memory follows the tile. Any other renderer receives a full-size request with zero
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

    def __call__(self, request: SampleRequest) -> SampleBuffer:
        """Render ``request`` tile by tile and return its statistics."""
        if not isinstance(request, SampleRequest):
            raise TypeError(f"request: expected a SampleRequest, got {type(request).__name__}")
        shape = request.shape
        tiles = [t for t in tile_grid(shape, self.tile) if request.counts[t].any()] or tile_grid(shape, self.tile)[:1]
        args = [(self.renderer_factory, request.counts[t], request.first_index[t], (t[0].start, t[1].start), shape)
                for t in tiles]
        if self.executor is None:
            results = [_render_tile(*a) for a in args]
        else:
            futures = [_submit(self.executor, _render_tile, *a) for a in args]
            results = [f.result() for f in futures]
        first = results[0]
        count = np.zeros(shape, np.int64)
        mean = np.zeros(shape + (first.n_channels,))
        variance = np.zeros_like(mean)
        known = np.zeros(shape, bool)
        for t, part in zip(tiles, results):
            count[t], mean[t], variance[t], known[t] = part.count, part.mean, part.variance, part.variance_known
        return SampleBuffer(count, mean, variance, first.channels, known, sum(p.nonfinite for p in results))


def render_tiled(renderer_factory: Callable[[], Renderer], sampler: Sampler, *, total_spp: float,
                 tile: int | tuple[int, int] = 128, executor: Executor | None = None, progress: bool = False,
                 callback: Callable[[SampleRequest, SampleBuffer], bool | None] | None = None) -> SampleBuffer:
    """Adaptive (or uniform) rendering with every round split into tiles over an executor.

    Exactly :meth:`Sampler.run <awr_denoise.Sampler.run>` with a :class:`TiledRenderer`: the
    sampler decides each round on the driver, the tiles of its request are rendered by the
    workers, and the merged statistics are told back. With addressable random numbers the
    result is bitwise identical to ``sampler.run(renderer_factory(), total_spp)``.

    Parameters
    ----------
    renderer_factory
        Zero-argument picklable callable building the renderer in the worker, e.g.
        ``RendererSpec.tracer("cornell_box", seed=3, threads=1)``; never the renderer itself
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
    with _executor_or_threads(executor, _default_workers()) as pool:
        renderer = TiledRenderer(renderer_factory, tile=tile, executor=pool)
        return sampler.run(renderer, total_spp, progress=progress, callback=callback)
