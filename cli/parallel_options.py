"""``--workers``, ``--scheduler``, ``--executor`` and ``--threads``: the parallel options of ``awr`` subcommands.

The first three select an executor of :mod:`awr_denoise.parallel` (docs/distributed.md) for the work a subcommand
splits (frames, tiles); subcommands keep their plain serial path when none is given. ``--threads`` is the thread
pool of the command's own process that the library's calls take as their ``executor`` (docs/cli.md, "Threads").
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import logging
from collections.abc import Iterator
from concurrent.futures import Executor

from awr_denoise.parallel import DASK_INSTALL_HINT, EXECUTOR_KINDS, get_executor
from awr_denoise.parallel.executors import default_workers

from .values import MAX_SIDE, whole

__all__ = ["add_executor_arguments", "add_threads_argument", "executor_from_args", "executor_requested",
           "library_threads", "threads_from_args", "MAX_WORKERS", "MIN_TILE", "LOCAL_PROCESSES_PER_CPU",
           "DEFAULT_THREADS"]

MAX_WORKERS = 4096
"""Most workers one command starts."""

LOCAL_PROCESSES_PER_CPU = 4
"""Most local worker processes (``--executor processes`` or a local Dask cluster) per CPU."""

MIN_TILE = 8
"""The smallest ``--tile`` side the command line takes."""
DEFAULT_TILE = 128
"""``--tile``'s side when the work is split over workers and no ``--tile`` is given."""
DEFAULT_THREADS = 2
"""``--threads``' pool when not given (fewer where this process may run on fewer CPUs). The library splits its own
work at most two ways beside the calling thread (the Wiener stages' bands two at a time, the rare-path search and the
pooled deviation beside the density), so a larger pool would wait."""


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
    group.add_argument("--workers", type=whole(minimum=1, maximum=MAX_WORKERS), metavar="N",
                       help="parallel workers: threads, processes or local Dask workers (default: the CPUs)")
    group.add_argument("--scheduler", metavar="ADDRESS",
                       help="run on a Dask cluster: scheduler address (tcp://host:8786) or scheduler JSON "
                            f"file; implies --executor dask ({DASK_INSTALL_HINT})")
    group.add_argument("--executor", choices=EXECUTOR_KINDS,
                       help="in-process threads (default), local processes, or Dask (a local cluster "
                            "unless --scheduler is given)")
    if tile_option:
        # A tile is a task per round: below 8 pixels a side the tasks cost more than the pixels they share
        # (a 128x128 render took 34 s with tiles of 1); the library's TiledRenderer keeps any size.
        group.add_argument("--tile", type=whole(minimum=MIN_TILE, maximum=MAX_SIDE), metavar="PIXELS",
                           help=f"tile side when the work is split over workers (default {DEFAULT_TILE}, at least "
                                f"{MIN_TILE}; refused without them)")


def add_threads_argument(parser: argparse.ArgumentParser | argparse._ArgumentGroup, what: str) -> None:
    """Add ``--threads N``: the thread pool of this process the library's own work runs on (``what``).

    Read it back with :func:`threads_from_args`, and open the pool with :func:`library_threads`.
    """
    parser.add_argument("--threads", type=whole(minimum=1, maximum=MAX_WORKERS), metavar="N",
                        help=f"threads of this process for {what}, the same result on any number (default "
                             f"{DEFAULT_THREADS}, or 1 on one CPU; 1: this thread alone; docs/cli.md, \"Threads\")")


def threads_from_args(args: argparse.Namespace) -> int:
    """``--threads``, else :data:`DEFAULT_THREADS` capped at the CPUs this process may run on."""
    given = getattr(args, "threads", None)
    return min(DEFAULT_THREADS, default_workers()) if given is None else int(given)


@contextlib.contextmanager
def library_threads(threads: int) -> Iterator[Executor | None]:
    """A thread pool of ``threads`` for the library's ``executor=`` arguments, or None for one thread.

    On the way out, tasks not started yet are dropped (Ctrl-C while a reconstruction waits for its bands does not
    run the rest of them first); the running ones finish, since threads cannot be stopped.
    """
    if threads <= 1:
        yield None
        return
    pool = cf.ThreadPoolExecutor(max_workers=threads, thread_name_prefix="awr-library")
    try:
        yield pool
    except BaseException:
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


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
        ``--scheduler`` with ``--executor threads`` or ``processes``, ``--workers`` below 1 or beside
        ``--scheduler``, or more local processes than :data:`LOCAL_PROCESSES_PER_CPU` per CPU.
    """
    workers = getattr(args, "workers", None)
    scheduler = getattr(args, "scheduler", None)
    kind = getattr(args, "executor", None)
    if scheduler is not None and kind not in (None, "dask"):
        raise ValueError(f"--scheduler: needs --executor dask, not --executor {kind}")
    if workers is not None and workers < 1:
        raise ValueError(f"--workers: must be >= 1, got {workers}")
    if workers is not None and scheduler is not None:  # it was ignored without a word
        raise ValueError(f"--workers {workers}: not with --scheduler (the cluster's own workers run the work)")
    most = LOCAL_PROCESSES_PER_CPU * default_workers()
    if workers is not None and workers > most and kind in ("processes", "dask") and scheduler is None:
        # Each is a Python process with numpy (about 60-100 MB): thousands exhaust memory.
        raise ValueError(f"--workers: {workers} local processes where this process may run on {default_workers()} "
                         f"CPUs; at most {most} (threads, the default --executor, are not limited so)")
    executor = get_executor(kind, workers=workers, scheduler=scheduler)
    return _dask_quiet(executor) if scheduler is not None or kind == "dask" else executor


@contextlib.contextmanager
def _dask_quiet(executor: contextlib.AbstractContextManager[Executor]) -> Iterator[Executor]:
    """``executor``'s context with Dask's log records below critical dropped: when a scheduler is lost, its
    client logs every reconnection attempt with two tracebacks (35 lines) before the command's own line.

    A filter on each of Dask's loggers, not their levels: the levels stay the caller's, and contexts that
    overlap each remove their own filter."""
    quiet = logging.Filter()
    quiet.filter = lambda record: record.levelno >= logging.CRITICAL  # type: ignore[method-assign]
    loggers: list[logging.Logger] = []
    try:
        with executor as running:
            # Once Dask is imported and has made its loggers, until the client is closed (its last words come
            # as it closes).
            for name in dict.fromkeys(["distributed", *logging.root.manager.loggerDict]):
                if name.split(".")[0] == "distributed":
                    loggers.append(logging.getLogger(name))
                    loggers[-1].addFilter(quiet)
            yield running
    finally:
        for logger in loggers:
            logger.removeFilter(quiet)
