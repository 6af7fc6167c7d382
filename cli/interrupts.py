"""Ctrl-C, SIGTERM and SIGHUP as exceptions, raised once: the command unwinds, removes its
temporaries and exits with one line.

:func:`raising` is the first thing :func:`awr_denoise.cli.main.main` does, before the
subcommands (and numpy, scipy, OpenEXR) are imported. The first signal raises; later ones are
ignored while the command cleans up, so a second Ctrl-C cannot cut the cleanup short or print a
traceback. A signal that was ignored when the command started (a background job, ``nohup``)
stays ignored. SIGHUP (a closed terminal or a dropped ssh session) is a termination like SIGTERM:
left at its default it would kill the process in the middle of a write and leave the temporary.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import select
import signal
import sys
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

from awr_denoise._signals import COMMIT_CHECKS, SHARED_SIGNALS, TAKEN_OVER, TERMINATING_SIGNALS

__all__ = ["Terminated", "raising", "restore", "ending", "say", "received", "check"]

# SIGHUP, SIGUSR1... exist on POSIX only.
_SIGNALS = TERMINATING_SIGNALS

# The signal that arrived, kept even when the exception it raised was swallowed on the way up
# (an interrupt inside a C extension's import comes back as an ImportError, or not at all).
_received: list[int] = []
_hooks: list[Callable[[Any], None]] = []  # the unraisable hook :func:`raising` replaced
_line: list[str] = []  # the command's line, once the process ends with it: "waiting", "writing", "written"
_late: list[int] = []  # a signal that came after the command's end (:func:`ending`)
_exit_after_line: list[int] = []  # the status a late signal left to :func:`say` to exit with once the line is out


class Terminated(BaseException):
    """SIGTERM, SIGHUP or another terminating signal arrived (a BaseException like KeyboardInterrupt:
    only ``main`` catches it)."""


def _raise(signum: int, frame: FrameType | None) -> None:
    _received.append(signum)
    for s in TAKEN_OVER:  # the first one to come ignores them all
        signal.signal(s, signal.SIG_IGN)
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Terminated(signal.Signals(signum).name)


def raising() -> dict[int, Any] | None:
    """Make SIGINT raise KeyboardInterrupt, SIGTERM, SIGHUP and the other terminating signals
    :class:`Terminated` (first signal only).

    Returns the previous handlers for :func:`restore`, or None when called outside the main
    thread (only the main thread can set handlers; the caller's own handling then stays).
    """
    _received.clear()
    _line.clear()
    _late.clear()
    _exit_after_line.clear()
    if threading.current_thread() is not threading.main_thread():
        return None
    if check not in COMMIT_CHECKS:
        COMMIT_CHECKS.append(check)  # every output commit asks first (merge, plan, bench had no check of their own)
    if sys.unraisablehook is not _quiet_unraisable:
        _hooks[:] = [sys.unraisablehook]
        sys.unraisablehook = _quiet_unraisable
    previous: dict[int, Callable[..., Any] | int | None] = {}
    TAKEN_OVER.clear()
    for s in _SIGNALS:
        handler = signal.getsignal(s)
        if s in SHARED_SIGNALS and handler is not signal.SIG_DFL:
            continue  # a timer's or a profiler's (None: installed in C): left to it
        previous[s] = handler
        if handler is not signal.SIG_IGN:
            signal.signal(s, _raise)
            TAKEN_OVER.add(s)
    return previous


def restore(previous: dict[int, Any] | None) -> None:
    """Put back the handlers :func:`raising` replaced."""
    if previous is None:
        return
    for s, handler in previous.items():
        signal.signal(s, signal.SIG_DFL if handler is None else handler)
    TAKEN_OVER.clear()
    with contextlib.suppress(ValueError):
        COMMIT_CHECKS.remove(check)
    if _hooks:
        hook = _hooks.pop()
        if sys.unraisablehook is _quiet_unraisable:  # a hook set meanwhile by the command's own code stays
            sys.unraisablehook = hook


def ending(previous: dict[int, Any] | None, outcome: Callable[[], tuple[int, str | None]]) -> None:
    """The command's end when the process ends with it (the console script): the process ends with
    ``outcome()``'s status and line (:func:`say` prints it) whatever signal comes from now on; a first one lets
    Python finish, a second ends the process at once.

    :func:`restore` would put back the default actions: a signal that landed after a command had committed its
    outputs, while Python was still finishing (joining threads, unloading modules), ended the process by its own
    action (-2, -15 or -1: a shell's 130, 143 or 129) without the line, or printed a KeyboardInterrupt
    traceback. The command's work is over here, its outputs committed or removed, so a late signal decides
    nothing: ``outcome`` reads the signals that came before (:func:`received`), which a late one does not join.
    A second late signal stops the wait (threads still finishing the tasks of an interrupted command). Python's
    exit runs its exit functions with the signals ignored: after them it would put back the default actions of
    handlers like this one before it frees the modules (numpy's, scipy's: tens of milliseconds), and an ignored
    signal stays ignored.

    Parameters
    ----------
    previous
        What :func:`raising` returned (None: nothing was replaced, the caller's handling stays).
    outcome
        The exit status and the line to print, or None for none.
    """
    caught = [s for s, handler in (previous or {}).items() if handler is not signal.SIG_IGN]  # not nohup's

    def late(signum: int, frame: FrameType | None) -> None:
        status, line = outcome()
        state = _line[-1] if _line else None
        if state == "writing":
            # It came while :func:`say` writes the line, a write that does not wait (its descriptor was
            # writable): say ends the process once the line is out.
            _exit_after_line[:] = [status]
            return
        if state != "waiting" and not _late:
            # The first, and the line is not waiting for stderr to be read: Python finishes what is done (its
            # exit functions release a process pool's semaphores: skipped, multiprocessing's resource tracker
            # printed a "leaked semaphore objects" warning).
            _late.append(signum)
            return
        for s in caught:  # a further signal ends the process even if a write below waits
            signal.signal(s, lambda *_: os._exit(status))
        if line is not None and state != "written":
            # Not yet said, or waiting: written now if stderr takes it at once (the signal may have come between
            # say's steps), else (nobody reads it) the process ends without it.
            _write_line(line, wait=state is None)
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):  # closed, full, or in the flush this signal interrupted
                stream.flush()
        os._exit(status)

    for s in caught:
        signal.signal(s, late)
    # Registered last, run first: after the threads are joined (a late signal ended that wait), before the
    # exit functions registered at import (multiprocessing's, logging's), which finish what is already done.
    atexit.register(lambda: [signal.signal(s, signal.SIG_IGN) for s in caught])


def say(outcome: Callable[[], tuple[int, str | None]]) -> int:
    """``outcome()``'s status, its line printed unless :func:`ending`'s late signal has printed it."""
    status, line = outcome()
    if line is not None and not _line:
        with contextlib.suppress(OSError, ValueError):  # what the command wrote there goes first
            sys.stderr.flush()
        _write_line(line)
    if _exit_after_line:  # a second late signal came while the line was written
        with contextlib.suppress(Exception):
            sys.stdout.flush()
        os._exit(_exit_after_line[0])
    return status


def _write_line(line: str, wait: bool = True) -> None:
    """``line`` on stderr in one write of the descriptor once it can take it (at once only, without ``wait``),
    its state in ``_line`` for a late signal: "waiting" for stderr to be read (a late signal then writes it if
    it can, else ends the process: nobody reads the line), then "writing" (a write that does not wait), then
    "written". The descriptor, not Python's stream: a flush that a signal interrupted fails again in the
    handler (reentrant), and lost the line."""
    with contextlib.suppress(OSError, ValueError):  # stderr gone or closed: the status still says it
        fd = sys.stderr.fileno()
        _line.append("waiting")
        if hasattr(select, "poll"):
            ready = select.poll()
            ready.register(fd, select.POLLOUT)
            # Writable, or its reader gone (an error event): the write below does not wait.
            if not ready.poll(None if wait else 0):
                return
        _line.append("writing")
        os.write(fd, (line + "\n").encode("ascii", "backslashreplace"))
    _line.append("written")


def _quiet_unraisable(unraisable: Any) -> None:
    """A signal's exception raised where Python can only print it (a weakref callback of importlib's
    module locks) printed a traceback; it is kept (:func:`received`) and acted on, not printed."""
    if isinstance(unraisable.exc_value, (KeyboardInterrupt, Terminated)):
        return
    (_hooks[0] if _hooks else sys.__unraisablehook__)(unraisable)


def received() -> int | None:
    """The signal that arrived since :func:`raising`, if any (the first one)."""
    return _received[0] if _received else None


def check() -> None:
    """Raise now if a signal arrived whose exception was lost on the way (call before committing)."""
    signum = received()
    if signum is not None and signum != signal.SIGINT:
        raise Terminated(signal.Signals(signum).name)
    if signum is not None:
        raise KeyboardInterrupt
