"""The signals that end a run: what the command line turns into a clean exit, and what a commit
of output files holds until every file is in place (standard library only: imported before numpy).

SIGINT (Ctrl-C), SIGTERM, SIGHUP (a closed terminal) and the ones batch schedulers and shells send
to end or warn a job whose default action is also to terminate: SIGUSR1, SIGUSR2 (LSF, SGE and
Slurm's ``--signal``), SIGXCPU (a CPU-time limit), SIGALRM, SIGVTALRM, SIGPWR, SIGPROF, SIGIO and SIGSTKFLT.
Left at their default they killed the process without a word and left a staging folder behind (the last three
found by a red-team pass; the real-time signals stay at their default, as SIGKILL's outcome: nothing partial).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable, Iterator

__all__ = ["TERMINATING_SIGNALS", "SHARED_SIGNALS", "TAKEN_OVER", "COMMIT_CHECKS", "deferred", "stop_point"]

TERMINATING_SIGNALS: tuple[int, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP", "SIGUSR1", "SIGUSR2", "SIGXCPU", "SIGALRM",
                                       "SIGVTALRM", "SIGPWR", "SIGPROF", "SIGIO", "SIGSTKFLT") if hasattr(signal, name))
"""Signals whose first arrival ends a command cleanly (those the platform has)."""

SHARED_SIGNALS: tuple[int, ...] = tuple(
    getattr(signal, name) for name in ("SIGALRM", "SIGVTALRM", "SIGPROF", "SIGIO") if hasattr(signal, name))
"""The terminating signals timers and sampling profilers use: the command line takes them over only where their
disposition is the default (a profiler's handler stays: taken over, the first tick ended the command), and
:func:`deferred` holds them only then (held, a profiler's tick took the place of a Ctrl-C after it)."""

TAKEN_OVER: set[int] = set()
"""The signals the command line took over (``awr_denoise.cli.interrupts.raising``)."""

COMMIT_CHECKS: list[Callable[[], None]] = []
"""Called, in order, before any output file moves into place (``awr_denoise.io.atomic``): the command
line raises there a signal whose exception was lost on the way (Python only prints an exception raised
in a weakref callback, as importlib's module locks run, and carries on), so no output of a terminated
command is committed. :func:`stop_point` calls them too, on worker threads."""


def stop_point() -> None:
    """Raise here the signal the command line took, or its pool's stop (:data:`COMMIT_CHECKS`); else nothing.

    Python runs signal handlers in the main thread only, and a thread cannot be stopped from outside, nor a
    worker process that ignores the signals: ``awr denoise --frames`` on threads or worker processes, told to
    stop, waited for every running frame's whole reconstruction (seconds at 1080p, tens of them at 4K, past a
    container's grace period before SIGKILL). The long steps of a reconstruction call this between their parts (a
    band of the Wiener stages, a step between stages). Without the command line (no checks registered) it does
    nothing.
    """
    for check in COMMIT_CHECKS:
        check()


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Hold SIGINT, SIGTERM, SIGHUP and the other terminating signals meanwhile, then act on the first
    that came: while output files are moved into place (``awr_denoise.io.atomic``), while worker
    processes start (``awr_denoise.parallel.executors``), while Mitsuba loads (its import aborted the
    process when a signal's exception was raised inside it).

    Only the main thread can change handlers; elsewhere signals are not delivered to the
    calling thread anyway (Python runs handlers in the main thread).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    saved = {}
    for s in TERMINATING_SIGNALS:
        handler = signal.getsignal(s)
        if handler is signal.SIG_IGN or handler is None:
            continue
        if s in SHARED_SIGNALS and handler is not signal.SIG_DFL and s not in TAKEN_OVER:
            continue  # a timer's or a profiler's own handler: its ticks are not an end to hold
        saved[s] = handler
        signal.signal(s, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)
        for s in pending[:1]:
            if callable(saved[s]):
                saved[s](s, None)
            else:  # SIG_DFL: what would have happened, now that the held work is done
                os.kill(os.getpid(), s)
