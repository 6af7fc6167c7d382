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

import contextlib
import signal
import sys
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

from awr_denoise._signals import COMMIT_CHECKS, TERMINATING_SIGNALS

__all__ = ["Terminated", "raising", "restore", "received", "check"]

# SIGHUP, SIGUSR1... exist on POSIX only.
_SIGNALS = TERMINATING_SIGNALS

# The signal that arrived, kept even when the exception it raised was swallowed on the way up
# (an interrupt inside a C extension's import comes back as an ImportError, or not at all).
_received: list[int] = []
_hooks: list[Callable[[Any], None]] = []  # the unraisable hook :func:`raising` replaced


class Terminated(BaseException):
    """SIGTERM, SIGHUP or another terminating signal arrived (a BaseException like KeyboardInterrupt:
    only ``main`` catches it)."""


def _raise(signum: int, frame: FrameType | None) -> None:
    _received.append(signum)
    for s in _SIGNALS:
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
    if threading.current_thread() is not threading.main_thread():
        return None
    if check not in COMMIT_CHECKS:
        COMMIT_CHECKS.append(check)  # every output commit asks first (merge, plan, bench had no check of their own)
    if sys.unraisablehook is not _quiet_unraisable:
        _hooks[:] = [sys.unraisablehook]
        sys.unraisablehook = _quiet_unraisable
    previous: dict[int, Callable[..., Any] | int | None] = {}
    for s in _SIGNALS:
        previous[s] = signal.getsignal(s)
        if previous[s] is not signal.SIG_IGN:
            signal.signal(s, _raise)
    return previous


def restore(previous: dict[int, Any] | None) -> None:
    """Put back the handlers :func:`raising` replaced."""
    if previous is None:
        return
    for s, handler in previous.items():
        signal.signal(s, signal.SIG_DFL if handler is None else handler)
    with contextlib.suppress(ValueError):
        COMMIT_CHECKS.remove(check)
    if _hooks:
        hook = _hooks.pop()
        if sys.unraisablehook is _quiet_unraisable:  # a hook set meanwhile by the command's own code stays
            sys.unraisablehook = hook


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
