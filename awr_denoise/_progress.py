"""tqdm's progress bars, imported in one place with its environment checked.

tqdm reads ``TQDM_*`` environment variables as overrides of its defaults when it is imported, and casts them with
``int()`` or ``float()``: ``TQDM_NCOLS=abc`` made ``import awr_denoise`` (and every ``awr`` command, ``--version``
too) fail with "invalid literal for int()", naming no variable (a red-team pass).
"""

from __future__ import annotations

import os
import sys

__all__ = ["tqdm", "auto_tqdm", "bars_shown"]

try:
    from tqdm import tqdm
    from tqdm.auto import tqdm as auto_tqdm
except (ValueError, TypeError) as exc:
    # The variables whose value the message quotes, or every TQDM_* one set where it quotes none.
    _named = [name for name, value in sorted(os.environ.items())
              if name.startswith("TQDM_") and repr(value) in str(exc)]
    _named = _named or sorted(name for name in os.environ if name.startswith("TQDM_"))
    _which = "this environment variable" if len(_named) == 1 else "one of these environment variables"
    raise ValueError(f"{', '.join(_named) or 'TQDM_*'}: tqdm cannot read {_which} ({exc})") from None


_ON, _OFF = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


def bars_shown(quiet: bool) -> bool:
    """Whether a command draws progress bars on stderr: never with ``quiet``; as ``AWR_PROGRESS`` says where it is
    set (1/true/yes/on or 0/false/no/off: a CI log that wants them, a terminal that does not); else only when
    stderr is a terminal, since a log file or a pipe keeps every carriage-return redraw before the next line."""
    if quiet:
        return False
    setting = os.environ.get("AWR_PROGRESS", "").strip().lower()
    if setting in _ON or setting in _OFF:
        return setting in _ON
    if setting:
        raise ValueError(f"AWR_PROGRESS={os.environ['AWR_PROGRESS']!r}: expected 1, true, yes, on, 0, false, no or off")
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced by an object without isatty, or closed
        return False
