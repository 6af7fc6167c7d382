"""The signals that end a run: what the command line turns into a clean exit, and what a commit
of output files holds until every file is in place (standard library only: imported before numpy).

SIGINT (Ctrl-C), SIGTERM, SIGHUP (a closed terminal) and the ones batch schedulers and shells send
to end or warn a job whose default action is also to terminate: SIGUSR1, SIGUSR2 (LSF, SGE and
Slurm's ``--signal``), SIGXCPU (a CPU-time limit), SIGALRM, SIGVTALRM and SIGPWR. Left at their
default they killed the process without a word and left a staging folder behind.
"""

from __future__ import annotations

import signal
from collections.abc import Callable

__all__ = ["TERMINATING_SIGNALS", "COMMIT_CHECKS"]

TERMINATING_SIGNALS: tuple[int, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP", "SIGUSR1", "SIGUSR2", "SIGXCPU", "SIGALRM",
                                       "SIGVTALRM", "SIGPWR") if hasattr(signal, name))
"""Signals whose first arrival ends a command cleanly (those the platform has)."""

COMMIT_CHECKS: list[Callable[[], None]] = []
"""Called, in order, before any output file moves into place (``awr_denoise.io.atomic``): the command
line raises there a signal whose exception was lost on the way (Python only prints an exception raised
in a weakref callback, as importlib's module locks run, and carries on), so no output of a terminated
command is committed."""
