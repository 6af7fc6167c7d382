"""Exit statuses and the exceptions ``awr`` subcommands raise for them.

Kept free of heavy imports: :mod:`awr_denoise.cli.main` imports this module before numpy and
scipy load, so an interrupt during those imports is already handled.
"""

from __future__ import annotations

import contextlib
import re
import sys
import unicodedata
import warnings
from collections.abc import Iterator

from awr_denoise.errors import InputFileWarning, TimeBudgetWarning

__all__ = ["EXIT_OK", "EXIT_FAILURE", "EXIT_USAGE", "EXIT_INTERRUPTED", "EXIT_TERMINATED", "EXIT_HANGUP",
           "EXIT_BROKEN_PIPE", "UsageError", "RuntimeFailure", "one_line_warnings"]

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
"""Ctrl-C (SIGINT): 128 + 2, the status a shell gives a command stopped by it."""
EXIT_TERMINATED = 143
"""SIGTERM: 128 + 15."""
EXIT_HANGUP = 129
"""SIGHUP (the terminal closed): 128 + 1."""
EXIT_BROKEN_PIPE = 141
"""The reader of stdout went away (``awr info --json x | head``): 128 + SIGPIPE, as for ``cat``."""


class UsageError(ValueError):
    """A mistake in how the command was called (exit status 2)."""


class RuntimeFailure(RuntimeError):
    """The command ran but did not achieve its goal, e.g. an error above ``--maxerror`` (exit 1)."""


def shown(text: object, *, keep: str = "") -> str:
    r"""``text`` with the characters a terminal obeys escaped (``\x1b``, ``\r``; :func:`_obeyed`), but
    those in ``keep``: a file name is shown as it is named, and cannot rewrite the terminal's line (an
    escape sequence in a name erased an error line and printed a green "ok" over it).

    Examples
    --------
    >>> from awr_denoise.cli.errors import shown
    >>> print(shown("evil\x1b[2K\rok.exr"))
    evil\x1b[2K\rok.exr
    """
    return "".join(repr(c)[1:-1] if c not in keep and _obeyed(c) else c for c in str(text))


_BIDI_CONTROLS = frozenset("\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069")


def _obeyed(c: str) -> bool:
    """Whether a terminal acts on ``c`` rather than showing it: control characters (escape, carriage
    return, newline), line and paragraph separators, and the bidirectional controls that reorder what
    follows. Other spaces (U+3000, U+00A0) and joiners (an emoji's U+200D) are shown as they are."""
    return unicodedata.category(c) in ("Cc", "Zl", "Zp") or c in _BIDI_CONTROLS


def one_line(message: object) -> str:
    """``message`` on one line: obeyed characters escaped (:func:`shown`), its lines and runs of
    white space joined by single spaces (a library's multi-line report)."""
    # Runs of ASCII white space only: a name's own U+3000 or no-break space is part of it.
    return " ".join(part for part in re.split(r"[ \t\n]+", shown(message, keep="\n\t")) if part) or "unknown error"


@contextlib.contextmanager
def one_line_warnings() -> Iterator[None]:
    """Within the block, the library's input and time-budget warnings print as ``awr: warning: <message>``,
    one line each on stderr (never as exceptions or two-line Python warnings), whatever the caller's
    warning filters."""
    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001 - warnings' signature
        print(f"awr: warning: {one_line(message)}", file=sys.stderr)

    with warnings.catch_warnings():
        warnings.simplefilter("always", InputFileWarning)
        warnings.simplefilter("always", TimeBudgetWarning)
        warnings.showwarning = show
        yield
