"""Executors for the parallel layer: in-process threads, local processes, or a Dask cluster.

Everything in :mod:`awr_denoise.parallel` takes any :class:`concurrent.futures.Executor` through
``executor=``. Without one, work runs on in-process threads, which need neither a cluster nor Dask:
numpy, PyWavelets and embreex release the GIL in their array operations; on two cores, over frames,
two threads were about as much faster than one as two Dask worker processes (docs/distributed.md).
:func:`get_executor` makes the other kinds on demand.
"""

from __future__ import annotations

import asyncio
import concurrent.futures as cf
import contextlib
import functools
import hashlib
import importlib.util
import ipaddress
import json
import logging
import multiprocessing
import multiprocessing.resource_tracker
import multiprocessing.spawn
import os
import signal
import socket
import struct
import subprocess
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

from .. import _checks
from .._version import __version__
from .._signals import COMMIT_CHECKS, TERMINATING_SIGNALS
from .._signals import deferred as _signals_deferred
from .._workers import exit_with_parent
from ..io.atomic import check_readable, read_without_waiting

__all__ = ["EXECUTOR_KINDS", "DASK_INSTALL_HINT", "get_executor", "executor_or_threads", "executor_width",
           "submit", "wait_first", "default_workers", "dask_client", "package_digest", "WorkerMismatchError"]

EXECUTOR_KINDS = ("threads", "processes", "dask")
"""Kinds of executor :func:`get_executor` can make."""

DASK_INSTALL_HINT = 'pip install "awr-denoise[dask]"'
"""How to install the optional Dask dependency."""

SCHEDULER_FILE_MAX = 2**20
"""The most bytes read of a ``--scheduler`` JSON file (Dask writes a few hundred)."""


def _leave_interrupts_to_the_parent(parent: int, stop: Any = None) -> None:
    """Worker processes ignore Ctrl-C, SIGTERM, SIGHUP and the other terminating signals: a terminal,
    a closed session or a batch scheduler sends them to the whole process group, and the parent,
    which owns the pool, cancels the work and closes the pool (no traceback per worker, no worker
    dead under a pool still in use). They end when the parent dies without closing the pool
    (SIGKILL): orphans stayed for good.

    ``stop``, the pool's event (:class:`_ProcessPool`): once the parent sets it, the task running here raises
    KeyboardInterrupt at its next stop point (:func:`awr_denoise._signals.stop_point`) and commits nothing.

    The workers start with these signals blocked (:func:`_children_spared_signals`): one that came
    while the worker imported the package is dropped here, once ignored.
    """
    for s in TERMINATING_SIGNALS:
        signal.signal(s, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, TERMINATING_SIGNALS)
    exit_with_parent(parent)
    if stop is not None:
        COMMIT_CHECKS.append(functools.partial(_stop_if_set, stop))


def _stop_if_set(stop: Any) -> None:
    """Raise KeyboardInterrupt if the pool's ``stop`` event is set (a worker's check, :data:`COMMIT_CHECKS`)."""
    if stop.is_set():
        raise KeyboardInterrupt


@contextlib.contextmanager
def _children_spared_signals() -> Iterator[None]:
    """Processes started inside begin with the terminating signals blocked; the caller's own are
    held, then acted on.

    A spawned worker spends its first second importing the package (numpy, scipy) before its
    initializer can ignore anything: a Ctrl-C to the process group in that second printed a
    KeyboardInterrupt traceback per worker, and SIGTERM or SIGHUP killed it, which broke the pool
    while the parent was cleaning up (the command then never exited). A blocked signal stays
    blocked across ``fork`` and ``exec``, whichever thread starts the process, until the worker's
    initializer has ignored it (:func:`_leave_interrupts_to_the_parent`). Multiprocessing's resource
    tracker is started (or started again) here too: it unblocks only the SIGINT and SIGTERM it
    ignores, so SIGHUP no longer kills it ("resource_tracker: process died unexpectedly", then
    KeyError tracebacks).

    In the main thread the handlers are also deferred (the mechanism of an output commit,
    :mod:`awr_denoise.io.atomic`): a signal's exception cannot land between a worker's start and
    the pool's record of it (a worker the pool would not know of); it is raised on the way out, at once.
    """
    with _signals_deferred():
        if not hasattr(signal, "pthread_sigmask"):  # not POSIX: no inherited mask to use
            yield
            return
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, TERMINATING_SIGNALS)
        try:
            multiprocessing.resource_tracker.ensure_running()  # a check when it runs already
            # Starting it unblocks SIGINT and SIGTERM in this thread on the way out: blocked again.
            signal.pthread_sigmask(signal.SIG_BLOCK, TERMINATING_SIGNALS)
            yield
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


class _ProcessPool(cf.ProcessPoolExecutor):
    """A ``spawn`` process pool whose workers leave every terminating signal to the parent, and stop their running
    tasks at the next stop point once :meth:`stop_running` is called."""

    def __init__(self, max_workers: int) -> None:
        context = multiprocessing.get_context("spawn")
        with _children_spared_signals():  # the pool's queues start the resource tracker
            self._stop = context.Event()
            super().__init__(max_workers=max_workers, mp_context=context,
                             initializer=_leave_interrupts_to_the_parent, initargs=(os.getpid(), self._stop))

    def stop_running(self) -> None:
        """The running tasks raise KeyboardInterrupt at their next stop point (a frame's reconstruction, between its
        steps and the bands of its Wiener stages): ``denoise --frames --executor processes``, told to stop, waited
        for every running frame's whole reconstruction (an attack pass). Nothing is cut mid-commit."""
        self._stop.set()

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future:
        """``ProcessPoolExecutor.submit``; the workers it starts (on demand) spare the signals."""
        with _children_spared_signals():
            return super().submit(fn, *args, **kwargs)


_SENTINEL_CODE = "import sys\nsys.stdin.buffer.read()"
"""The sentinel's program: it reads its stdin until this process closes it (or dies), and a Ctrl-C ends it."""

_SENTINEL_WAIT = 10.0
"""Seconds the sentinel has to end once its stdin is closed (it is killed after that, as seen no Ctrl-C)."""


def _interrupt_sentinel() -> subprocess.Popen[bytes] | None:
    """A child process in this process group that a terminal's Ctrl-C ends while this process ignores it.

    Started before SIGINT is ignored here, so that it keeps the default action (``exec`` resets this process'
    handler to it). It runs the interpreter the spawned workers run, not ``sys.executable``, which in an embedded
    Python is the host application. None where it cannot start (no POSIX process group, out of processes or file
    descriptors): the Ctrl-C is then not seen, as before there was one.
    """
    if os.name != "posix":
        return None
    try:
        return subprocess.Popen([multiprocessing.spawn.get_executable(), "-S", "-c", _SENTINEL_CODE],
                                stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except (OSError, ValueError):
        return None


def _ended_by_interrupt(sentinel: subprocess.Popen[bytes] | None) -> bool:
    """Whether a Ctrl-C ended ``sentinel``; it is ended (its stdin closed) and waited for either way."""
    if sentinel is None:
        return False
    with contextlib.suppress(OSError):
        sentinel.stdin.close()  # type: ignore[union-attr]  # EOF: it exits 0
    try:
        return sentinel.wait(timeout=_SENTINEL_WAIT) == -signal.SIGINT
    except subprocess.TimeoutExpired:
        sentinel.kill()
        sentinel.wait()
        return False


@contextlib.contextmanager
def _children_ignore_interrupts() -> Iterator[Callable[[], None]]:
    """Processes started inside ignore Ctrl-C, as :func:`_leave_interrupts_to_the_parent` makes a pool's; yields
    a function that delivers a Ctrl-C given meanwhile, to call once what was started is in the caller's hands.

    Dask's nannies start their worker processes themselves (no initializer to pass), but an ignored SIGINT is
    inherited through ``exec`` and Python keeps it ignored: the parent, which owns the cluster, stops the work and
    closes it, without a traceback per worker. This process ignores it meanwhile too, so a terminal's Ctrl-C to
    the process group is seen by a sentinel (:func:`_interrupt_sentinel`) that it ends; the returned function
    then raises SIGINT here, for this process' own handler (the command's: KeyboardInterrupt). It was ignored for
    good (an attack pass): the command went on and wrote its outputs. A SIGINT sent to this process alone while
    the cluster starts is still not seen. Only the main thread may set handlers; elsewhere nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield lambda: None
        return
    seen: list[bool] = []
    sentinel = _interrupt_sentinel()
    saved = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield lambda: signal.raise_signal(signal.SIGINT) if seen == [True] else None
    finally:
        # The sentinel is ended before the handler is put back: a Ctrl-C meanwhile still ends it (or it had ended).
        seen.append(_ended_by_interrupt(sentinel))
        signal.signal(signal.SIGINT, saved)


_START_GRACE = 5.0
"""Seconds the worker processes of a local cluster whose start was cut short have to exit on SIGTERM before SIGKILL."""


def _end_started(earlier: set[multiprocessing.process.BaseProcess]) -> None:
    """End this process' children started since ``earlier`` (a local cluster's workers, while it started): SIGTERM,
    then SIGKILL after :data:`_START_GRACE` seconds. Children started meanwhile (Dask starts each from a thread of its
    own) are looked for again until none is left."""
    deadline = time.monotonic() + _START_GRACE
    while True:
        started = [p for p in multiprocessing.active_children() if p not in earlier]
        if not started or time.monotonic() > deadline + _START_GRACE:  # none left, or one that no signal ends
            return
        for process in started:
            with contextlib.suppress(OSError, ValueError, AttributeError):
                if time.monotonic() < deadline:
                    process.terminate()
                else:
                    process.kill()
        for process in started:
            with contextlib.suppress(OSError, ValueError, AssertionError):
                process.join(timeout=max(0.05, deadline - time.monotonic()))


def _close(pool: cf.ProcessPoolExecutor, *, cancel: bool) -> None:
    """Shut ``pool`` down and wait for it; the workers of a broken pool are killed, not waited for.

    Parameters
    ----------
    pool
        The pool to close.
    cancel
        Cancel the tasks not started yet (else they run first).

    Notes
    -----
    When a worker dies abruptly (the OOM killer, SIGKILL), Python ends the others with SIGTERM,
    which they ignore (:func:`_leave_interrupts_to_the_parent`), then waits for them: one blocked on
    the task queue's lock, which the dead worker held, kept the command from exiting for ever. The
    wait runs on a helper thread so that this one can kill them instead. ``_broken`` and
    ``_processes`` are the pool's own attributes (Python 3.10 to 3.13); without them the wait is
    Python's alone.
    """
    workers = list((getattr(pool, "_processes", None) or {}).values())
    closing = threading.Thread(target=pool.shutdown, kwargs={"wait": True, "cancel_futures": cancel},
                               name="awr-pool-shutdown", daemon=True)
    closing.start()
    while closing.is_alive():
        closing.join(0.1)
        if getattr(pool, "_broken", False):
            for worker in workers:
                with contextlib.suppress(Exception):  # ended meanwhile, or closed
                    worker.kill()


def default_workers() -> int:
    """The number of CPUs this process may run on (at least 1): its CPU affinity where the system has one (a
    ``taskset`` or a batch scheduler's cgroup-pinned job), else the machine's CPUs."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity on this system (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def _import_distributed() -> Any:
    """Dask distributed, the optional ``dask`` extra, imported only when a Dask executor is asked for."""
    try:
        import distributed
    except ImportError as exc:
        raise ImportError(f'executor "dask" needs Dask distributed: {DASK_INSTALL_HINT}') from exc
    return distributed


@contextlib.contextmanager
def _glibc_malloc_tuning() -> Iterator[None]:
    """Start Dask worker processes with glibc's own malloc tuning instead of Dask's.

    Dask starts workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (and writes it into this process's
    environment when it starts a local cluster). Setting it switches off glibc's adaptive mmap
    threshold, so every numpy temporary above 128 KiB is mapped afresh and page-faulted in:
    reconstructions took markedly longer in such a worker than in the main process, the difference
    system time spent in page faults. Unsetting it for the workers this module starts removes the
    gap.
    """
    import dask  # the optional ``dask`` extra; only reached once distributed imported

    saved = os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
            yield
    finally:
        if saved is not None:
            os.environ["MALLOC_TRIM_THRESHOLD_"] = saved


def _environ_changes(before: dict[str, str]) -> dict[str, str | None]:
    """The variables of this process' environment that differ from ``before``, with their values now
    (``None``: removed)."""
    now = dict(os.environ)
    return {name: now.get(name) for name in before.keys() | now.keys() if before.get(name) != now.get(name)}


def _environ_put_back(before: dict[str, str], written: dict[str, str | None]) -> None:
    """Undo what a local cluster ``written`` into this process' environment, where it is still there.

    Starting a local cluster writes its workers' settings into the starting process' environment and
    leaves them there after the cluster has closed: ``OMP_NUM_THREADS``, ``MKL_NUM_THREADS`` and
    ``OPENBLAS_NUM_THREADS`` of 1, ``PYTHONHASHSEED``, ``__DASK_PARENT_PID``. Every process the caller
    started afterwards (a renderer, another ``awr``) ran its BLAS and OpenMP on one thread. A variable the
    caller set again meanwhile is the caller's, and stays."""
    for name, value in written.items():
        if os.environ.get(name) != value:
            continue
        if name in before:
            os.environ[name] = before[name]
        else:
            os.environ.pop(name, None)


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
        number of CPUs. Not with ``scheduler``: a running scheduler's workers are those started
        there.
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
    ValueError
        An unknown ``kind``, ``workers`` out of range or beside ``scheduler``, or ``scheduler``
        with another kind than ``"dask"``; a local cluster that did not start, or a scheduler not
        connected to, while ``DASK_*`` variables are set (they are named).

    Notes
    -----
    Dask is imported only when asked for. The local cluster listens on the loopback
    interface only and starts no dashboard; its workers keep glibc's default malloc tuning rather
    than Dask's ``MALLOC_TRIM_THRESHOLD_``, which made numpy-heavy tasks markedly slower
    (docs/distributed.md). What starting it writes into this process' environment (one BLAS and
    OpenMP thread for later processes, among others) is undone once it has closed. Process pools
    use the ``spawn`` start method, so they are safe to start from a program that already runs
    threads.

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
    workers = _checks.whole("workers", workers, minimum=1, maximum=1 << 16, none=True)
    if scheduler is not None and kind != "dask":
        raise ValueError(f"scheduler: a scheduler address needs kind='dask', got kind={kind!r}")
    if scheduler is not None and workers is not None:  # it was ignored without a word
        raise ValueError(f"workers: {workers} given with a scheduler, whose workers are those started there")
    n_workers = default_workers() if workers is None else int(workers)
    if kind == "threads":
        with cf.ThreadPoolExecutor(max_workers=n_workers, thread_name_prefix="awr") as pool:
            yield pool
        return
    if kind == "processes":
        pool = _ProcessPool(n_workers)
        try:
            yield pool
        except BaseException:
            # Ctrl-C, SIGTERM, a failed task: work not started never starts; the running tasks end
            # as on threads (the workers ignored the signal: none died under the pool). Cancelled
            # here, they also leave the pool's books, where Python 3.11 failed them again if the
            # pool broke meanwhile (a thread's "InvalidStateError: CANCELLED" traceback).
            pool.stop_running()
            _close(pool, cancel=True)
            raise
        _close(pool, cancel=False)
        return
    distributed = _import_distributed()
    import dask  # distributed's own dependency, there once it is

    with contextlib.ExitStack() as stack:
        if scheduler is None:
            before, written = dict(os.environ), {}
            stack.callback(_environ_put_back, before, written)  # last, once the cluster has closed
            stack.enter_context(_glibc_malloc_tuning())
            # The workers' scratch folder (Dask's "dask-scratch-space", left in $TMPDIR after the
            # cluster) in one of this run's own, removed once the cluster has closed.
            scratch = stack.enter_context(tempfile.TemporaryDirectory(prefix="awr-dask-"))
            stack.enter_context(dask.config.set({"temporary-directory": scratch}))  # the scheduler's
            earlier = set(multiprocessing.active_children())
            try:
                with _children_ignore_interrupts() as deliver_interrupt:
                    cluster = distributed.LocalCluster(
                        n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                        dashboard_address=None, local_directory=scratch,
                        # No dashboard; the scheduler's remaining HTTP routes take a free loopback port
                        # instead of 8787, so several clusters can coexist without a port warning.
                        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                        # Task errors reach the caller as exceptions; the workers' logs of them (a
                        # multi-line "Compute Failed" each), of a cancelled task or of a lost heartbeat
                        # while closing are noise on a terminal.
                        silence_logs=logging.CRITICAL)
                stack.enter_context(cluster)
            except BaseException as exc:
                # A start cut short (SIGTERM, a failed nanny): its workers still starting made the scratch folder again
                # once it had been removed, and left it in $TMPDIR (an attack pass). Ended first, before it goes.
                _end_started(earlier)
                _blame_dask_variables(exc, before, "a local Dask cluster did not start")
                raise
            finally:  # what starting it wrote, also when it failed to start
                written.update(_environ_changes(before))
            deliver_interrupt()  # a Ctrl-C while it started, now that the stack closes the cluster
            try:
                client = stack.enter_context(distributed.Client(cluster))
            except Exception as exc:
                _blame_dask_variables(exc, before, "the client of a local Dask cluster did not start")
                raise
        else:
            client = stack.enter_context(_connect(distributed, _scheduler_address(distributed, scheduler)))
        executor = client.get_executor(pure=False)
        try:
            yield executor
        except BaseException:
            # Ctrl-C reaches a local cluster's workers too (one process group): waiting for
            # their futures would wait for ever. Cancel them; closing the cluster ends the rest.
            # A cluster given by address keeps running: its running tasks see themselves cancelled
            # at their next stop point (:func:`_on_the_same_package`).
            executor.shutdown(wait=False)
            raise
        executor.shutdown(wait=True)


def _blame_dask_variables(exc: BaseException, environ: Mapping[str, str], what: str) -> None:
    """Raise a ``ValueError`` naming the ``DASK_*`` variables of ``environ`` when ``exc``, raised by Dask as it
    started or connected, may be theirs; return where none is set, or where ``exc`` is the system's.

    Dask reads every variable named ``DASK_...`` (the rest of the name in any case; ``DASK_INTERNAL_*`` are its own)
    and each value only where it uses it, failing then in its own words, deep inside:
    ``DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=zz`` a ``KeyError`` listing time units, a memory fraction of
    ``abc`` "Nanny failed to start". Those were internal errors of the command (an attack pass); the variables
    are the user's input, so they are named as the possible cause. An ``OSError`` (no file descriptors or ports
    left, a refused connection) is the system's and goes on as it is, as do Ctrl-C and SIGTERM."""
    if not isinstance(exc, Exception) or isinstance(exc, OSError):
        return
    named = sorted(name for name in environ if name.startswith("DASK_") and not name.startswith("DASK_INTERNAL"))
    if not named:
        return
    why = " ".join(str(exc).split()) or type(exc).__name__
    if len(why) > 160:  # a KeyError of Dask's lists every time unit it knows
        why = why[:157] + "..."
    raise ValueError(f"{what} ({why}); the environment sets {', '.join(named)}, read by Dask: a value Dask cannot "
                     f"use is the likely cause; correct or unset {'it' if len(named) == 1 else 'them'}") from exc


def _scheduler_file(text: str) -> Any:
    """The JSON of the scheduler file ``text``: checked to be a regular file before it is opened (a FIFO
    blocked in ``open()`` for ever, ``/dev/zero`` was read without end), and read up to a scheduler file's
    size (Dask writes a few hundred bytes)."""
    try:
        check_readable(text, what="scheduler file")
    except FileNotFoundError:
        raise ValueError(f"scheduler: {text}: no such scheduler file") from None
    except ValueError as exc:
        raise ValueError(f"scheduler: {exc}") from None
    try:
        raw = read_without_waiting(text, limit=SCHEDULER_FILE_MAX)
        if len(raw) > SCHEDULER_FILE_MAX:
            raise ValueError(f"larger than {SCHEDULER_FILE_MAX} bytes")
        return json.loads(raw.decode("utf-8"))
    except (OSError, ValueError) as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise ValueError(f"scheduler: {text}: not a Dask scheduler file ({exc})") from None
    except RecursionError:  # arrays or objects nested thousands deep: the file's fault, not an internal error
        raise ValueError(f"scheduler: {text}: not a Dask scheduler file (its JSON is nested too deeply)") from None


def _scheduler_address(distributed: Any, scheduler: str | os.PathLike[str]) -> str:
    """The address of ``scheduler`` (an address, or a scheduler file's ``"address"``), checked before connecting."""
    text = os.fspath(scheduler)
    if Path(text).suffix == ".json":
        info = _scheduler_file(text)
        address = info.get("address") if isinstance(info, dict) else None
        if not isinstance(address, str) or not address:
            raise ValueError(f"scheduler: {text}: not a Dask scheduler file (no \"address\")")
        text = address
    try:
        scheme, location = distributed.comm.parse_address(text)
        distributed.comm.registry.get_backend(scheme)  # an unknown scheme: ValueError
        if scheme not in ("tcp", "tls"):  # inproc is this process's own; ucx and ws need what is not given here
            raise ValueError(f"{scheme}:// does not reach a scheduler of another process; give tcp://HOST:PORT")
        host, port = distributed.comm.addressing.parse_host_port(location)
        _check_host(host)
        if not 1 <= int(port) <= 65535:  # Dask takes 99999 or 0, then waits its whole timeout to connect
            raise ValueError(f"port {port} is outside 1..65535")
    except ValueError as exc:
        # A file of another suffix (`dask scheduler --scheduler-file sched`) was only "missing port number".
        hint = "; a scheduler file's name ends in .json" if os.path.isfile(text) else ""
        raise ValueError(f"scheduler: {text!r} is not a scheduler address ({exc}){hint}") from None
    return text


def _check_host(host: str) -> None:
    """Refuse a host no connection can reach, at once: Dask looked each of these up and waited its timeout."""
    if not host or any(ch.isspace() or not ch.isprintable() for ch in host):
        raise ValueError(f"host {host!r} is empty or holds a space")
    labels = host.split(".")
    # A dotted quad of numbers must be an IPv4 address (999.1.1.1 is none; shorter forms such as 127.1 resolve).
    if len(labels) == 4 and all(label.isdigit() for label in labels):
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            raise ValueError(f"host {host} is no IPv4 address") from None


_ANSWER_SECONDS = 30.0
"""How long a scheduler has to say who it is (Dask's own connect timeout)."""

_WORKER_SECONDS = 60.0
"""How long a scheduler without workers is given for one to join (a cluster still starting)."""


def _identity(distributed: Any, address: str, seconds: float) -> Any:
    """What the service at ``address`` says it is (Dask's ``identity``), asked within ``seconds``.

    ``distributed.Client`` waits for the handshake without a limit: a service that accepts the
    connection and never answers (an HTTP server, as the dashboard's port) would hold it for
    ever. ``None`` inside a running event loop (a notebook's), where the Client is left to it.
    """

    async def ask() -> Any:
        comm = await distributed.comm.connect(address, timeout=seconds)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    try:
        asyncio.get_running_loop()
    except RuntimeError:
        # Past the connection's own timeout (an unreachable host is an OSError of its own first).
        return asyncio.run(asyncio.wait_for(ask(), 2 * seconds))
    return None


_PROBE_SECONDS = 5.0
"""How long the first plain connection to a scheduler's host and port may take before Dask's own is left to tell."""


def _probe(distributed: Any, address: str) -> None:
    """A host that does not resolve, or a port nothing listens on, named at once: Dask retries both for its
    whole timeout (30 s) and then calls either a time-out, which points at the network, not at a stale
    scheduler file or a scheduler that is not running."""
    host, port = distributed.comm.addressing.parse_host_port(distributed.comm.parse_address(address)[1])
    try:
        with socket.create_connection((host, int(port)), timeout=_PROBE_SECONDS):
            pass
    except socket.gaierror as exc:
        raise ConnectionError(f"scheduler: {address}: unknown host {host} ({exc.strerror})") from None
    except ConnectionRefusedError:
        raise ConnectionError(f"scheduler: {address}: connection refused (is the scheduler running, on that "
                              "port?)") from None
    except OSError:  # slow or unreachable: Dask's own connection says so, in its own time
        pass


def _connect(distributed: Any, address: str) -> Any:
    """A ``distributed.Client`` of ``address``; a service that is not a Dask scheduler is a ``ConnectionError``."""
    _probe(distributed, address)
    try:
        identity = _identity(distributed, address, _ANSWER_SECONDS)
        if identity is not None and (not isinstance(identity, dict) or identity.get("type") != "Scheduler"):
            kind = identity.get("type") if isinstance(identity, dict) else None
            raise ConnectionError(f"scheduler: {address}: a Dask {kind or 'service'}, not a scheduler")
        client = distributed.Client(address)
    except (asyncio.TimeoutError, TimeoutError):  # the same class from Python 3.11 on
        raise ConnectionError(f"scheduler: {address}: no Dask answer within {2 * _ANSWER_SECONDS:g} s (another "
                              "service on that port?)") from None
    except ConnectionError:
        raise
    except (MemoryError, struct.error):  # another service's reply, read as the length of a Dask message (exabytes),
        # or shorter than the frame lengths it announces
        raise ConnectionError(f"scheduler: {address}: not a Dask scheduler (its reply is no Dask message)") from None
    except OSError as exc:  # refused, timed out, closed (CommClosedError): nothing to run on
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise ConnectionError(f"scheduler: {address}: cannot connect ({why})") from None
    except (TypeError, ValueError) as exc:  # Dask's own refusal of what it cannot use (tls without certificates)
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise ValueError(f"scheduler: {address}: cannot connect ({why})") from None
    except Exception as exc:
        _blame_dask_variables(exc, os.environ, f"scheduler: {address}: cannot connect")
        raise
    try:  # a scheduler without workers (none started yet, all gone) would take the tasks and wait for ever
        client.wait_for_workers(1, timeout=_WORKER_SECONDS)
    except (asyncio.TimeoutError, TimeoutError):
        client.close()
        raise ConnectionError(f"scheduler: {address}: no workers joined within {_WORKER_SECONDS:g} s") from None
    return client


_WATCH_SECONDS = 10.0
"""How often a wait on a Dask cluster's tasks asks its scheduler whether it answers and has workers."""


def wait_first(executor: Executor, futures: Any) -> set[cf.Future]:
    """``concurrent.futures.wait(futures, return_when=FIRST_COMPLETED)``'s done set; on a Dask cluster the
    scheduler is asked every :data:`_WATCH_SECONDS` whether it still answers and has a worker.

    A cluster that lost every worker (stopped, or gone on an import error of their own), or whose scheduler
    froze, mid-run kept the command waiting for ever without a word (an attack pass): it now ends with a
    ``ConnectionError`` naming the scheduler, once it has had no worker for ``_WORKER_SECONDS`` or has not
    answered within twice ``_ANSWER_SECONDS``.

    Examples
    --------
    >>> from awr_denoise.parallel import get_executor
    >>> from awr_denoise.parallel.executors import wait_first
    >>> with get_executor("threads", workers=1) as pool:
    ...     [f.result() for f in wait_first(pool, [pool.submit(abs, -1)])]
    [1]
    """
    client = dask_client(executor)
    if client is None:
        return cf.wait(futures, return_when=cf.FIRST_COMPLETED)[0]
    if not futures:  # nothing to wait for: no question to the scheduler, in a loop
        return set()
    without_workers: float | None = None
    while True:
        done = cf.wait(futures, timeout=_WATCH_SECONDS, return_when=cf.FIRST_COMPLETED)[0]
        if done:
            return done
        without_workers = _watch(client, without_workers)


def _watch(client: Any, without_workers: float | None) -> float | None:
    """Ask ``client``'s scheduler who it is; raise if it does not answer or has had no worker for
    ``_WORKER_SECONDS``; return since when it has had none (None: it has)."""
    address = client.scheduler.address
    try:
        identity = _identity(_import_distributed(), address, _ANSWER_SECONDS)
    except (asyncio.TimeoutError, TimeoutError):
        raise ConnectionError(f"scheduler: {address}: no answer within {2 * _ANSWER_SECONDS:g} s mid-run (stopped "
                              "or frozen?)") from None
    except OSError as exc:
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise ConnectionError(f"scheduler: {address}: lost mid-run ({why})") from None
    if not isinstance(identity, dict) or identity.get("workers"):  # None: inside a running event loop, not asked
        return None
    now = time.monotonic()
    if without_workers is None:
        return now
    if now - without_workers >= _WORKER_SECONDS:
        raise ConnectionError(f"scheduler: {address}: no workers for {_WORKER_SECONDS:g} s mid-run (every worker "
                              "stopped, lost, or unable to start?)")
    return without_workers


@contextlib.contextmanager
def executor_or_threads(executor: Executor | None, tasks: int) -> Iterator[Executor]:
    """``executor`` itself (type-checked), or a thread pool of at most one thread per task, per CPU."""
    if executor is not None:
        if not isinstance(executor, Executor):
            raise TypeError(f"executor: expected a concurrent.futures.Executor, got {type(executor).__name__}")
        yield executor
        return
    with cf.ThreadPoolExecutor(max_workers=max(1, min(tasks, default_workers())), thread_name_prefix="awr") as pool:
        yield pool


def dask_client(executor: Executor) -> Any | None:
    """The ``distributed.Client`` behind a Dask ``ClientExecutor``, else None (no Dask import)."""
    if type(executor).__module__.startswith("distributed"):
        return getattr(executor, "_client", None)
    return None


def executor_width(executor: Executor) -> int:
    """How many tasks the executor runs at once, as far as it tells (else the local CPUs)."""
    client = dask_client(executor)
    if client is not None:
        return max(1, sum(client.nthreads().values()))
    return max(1, int(getattr(executor, "_max_workers", 0) or default_workers()))


def submit(executor: Executor, fn: Callable[..., Any], *args: Any) -> cf.Future:
    """``executor.submit(fn, *args)``, never answered from Dask's cache of earlier results, and
    always answered.

    Dask treats tasks as pure by default: a task with the same function and arguments as one
    whose result it still holds is not run again. These tasks write files and render with
    side effects, so on Dask they are submitted with ``pure=False``.

    On Dask the task goes to the client itself and its ``concurrent.futures`` future is settled
    here (:func:`_settle`), not by Dask's ``ClientExecutor``: when the worker holding a finished
    result dies before the client has fetched it, Dask runs the task again, and when that run
    fails (a frame finds the output its first run wrote) the error escaped the wrapper's callback,
    whose future then stayed pending for ever (docs/distributed.md, "A worker lost mid-run").
    """
    client = dask_client(executor)
    if client is None:
        return executor.submit(fn, *args)
    if getattr(executor, "_shutdown", False):
        raise RuntimeError("cannot schedule new futures after shutdown")
    # The executor's own options (workers=, resources=, retries=) as its submit passes them.
    # Named after the work (a frame, a tile), not the wrapper: on the dashboard and in Dask's messages.
    name = f"{getattr(fn, '__name__', 'task')}-{uuid.uuid4().hex}"
    task = client.submit(_on_the_same_package, package_digest(), fn, *args,
                         **{**getattr(executor, "_kwargs", {}), "pure": False, "key": name})
    with contextlib.suppress(AttributeError):
        executor._futures.add(task)  # what the executor's shutdown waits for, or cancels
    answer: cf.Future = cf.Future()

    def cancel_task(done: cf.Future) -> None:
        if done.cancelled() and task.status != "cancelled":
            task.cancel()

    answer.add_done_callback(cancel_task)
    client.loop.add_callback(_settle, client, task, answer)
    return answer


@functools.lru_cache(maxsize=1)
def package_digest() -> str:
    """This process' awr-denoise: its version and a SHA-256 of its modules' bytes (read once a process, cached).

    Examples
    --------
    >>> from awr_denoise.parallel.executors import package_digest
    >>> package_digest().startswith(__import__("awr_denoise").__version__ + " ")
    True
    """
    root = Path(__file__).resolve().parent.parent
    # The command line's modules wherever they are installed: a checkout keeps them in cli/ beside the package
    # (awr_denoise.cli maps there), a wheel inside it. Hashed from the package folder alone, the same code had two
    # digests, and a worker of an editable install refused a command of a wheel (an attack pass).
    spec = importlib.util.find_spec("awr_denoise.cli")
    if spec is not None and spec.submodule_search_locations:
        cli = Path(next(iter(spec.submodule_search_locations))).resolve()
    else:  # a checkout on sys.path without its install's mapping (a worker started with PYTHONPATH): cli/ beside it
        cli = root / "cli" if (root / "cli").is_dir() else root.parent / "cli"
    files = {path.relative_to(root).as_posix(): path for path in root.rglob("*.py")
             if not path.is_relative_to(root / "cli")}
    files.update({"cli/" + path.relative_to(cli).as_posix(): path for path in cli.rglob("*.py")})
    h = hashlib.sha256()
    for name in sorted(files):
        h.update(name.encode())
        h.update(files[name].read_bytes())
    return f"{__version__} {h.hexdigest()[:16]}"


class WorkerMismatchError(ConnectionError):
    """A Dask worker runs another awr-denoise than the caller (:func:`package_digest`)."""


_task_stop = threading.local()
_task_stop_registered = threading.Lock()

_STOPPED_STATES = frozenset({"cancelled", "released", "forgotten"})
"""A Dask worker's states of a task its client let go of (cancelled, or the client gone)."""


def _dask_stop_check() -> None:
    """A Dask worker's check at a stop point (:data:`COMMIT_CHECKS`): the running task's own state, in the worker's
    books (no request to the scheduler, so none can hang on one that froze); a task its client cancelled ends here
    with a RuntimeError (KeyboardInterrupt would end the worker)."""
    key = getattr(_task_stop, "key", None)
    if key is None:
        return
    try:
        task = _import_distributed().get_worker().state.tasks.get(key)
    except (AttributeError, ValueError):  # another Dask's books, or not in a worker: no check
        return
    if task is None or task.state in _STOPPED_STATES:
        raise RuntimeError("stopped: the command that submitted this task cancelled it")


def _on_the_same_package(digest: str, fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` on a Dask worker that runs the command's awr-denoise (:func:`package_digest`), else a
    :class:`WorkerMismatchError` naming the worker: a worker of another version, or of files edited since it started,
    gave other images without a word (an attack pass; a long-lived cluster kept the modules it had imported).

    The task stops at its next stop point (:func:`awr_denoise._signals.stop_point`), committing nothing, once its
    client has cancelled it: frames on a cluster given by address, told to stop, ran their whole reconstruction
    first (the command had ended; the workers went on)."""
    own = package_digest()
    if own != digest:
        try:
            where = f"worker {_worker_address()} "
        except Exception:  # noqa: BLE001 - not in a worker (a test calls it directly): no address to give
            where = "a worker "
        raise WorkerMismatchError(f"Dask {where}runs another awr-denoise ({own}) than this command ({digest}): "
                                  "start every worker from the same installation, and again after changing it")
    with _task_stop_registered:
        if _dask_stop_check not in COMMIT_CHECKS:
            COMMIT_CHECKS.append(_dask_stop_check)
    _task_stop.key = getattr(_import_distributed().worker.thread_state, "key", None)
    try:
        return fn(*args)
    finally:
        _task_stop.key = None


def _worker_address() -> str:
    """The address of the Dask worker running the calling task."""
    return str(_import_distributed().get_worker().address)


async def _settle(client: Any, task: Any, answer: cf.Future) -> None:
    """Give ``answer`` the outcome of the Dask future ``task``, on the client's event loop: gathering
    waits through a lost result's new run, and every way it ends (a value, the task's error, a
    cancellation, an error of Dask's own) settles ``answer``."""
    try:
        value = (await client.gather([task], asynchronous=True))[0]
    except BaseException as exc:  # handed to the caller waiting on the answer, never dropped
        if task.status == "cancelled":
            answer.cancel()
        else:
            with contextlib.suppress(cf.InvalidStateError):  # cancelled by the caller meanwhile
                answer.set_exception(exc)
    else:
        with contextlib.suppress(cf.InvalidStateError):  # cancelled by the caller meanwhile
            answer.set_result(value)
    finally:
        task.release()  # the result is the caller's now: the cluster need not keep it
    if answer.cancelled():  # by the caller or by Dask: cf.wait() learns it only from this call
        with contextlib.suppress(RuntimeError):  # notified already is fine
            answer.set_running_or_notify_cancel()
