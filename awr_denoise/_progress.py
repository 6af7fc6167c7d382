"""tqdm's progress bars, imported in one place with its environment checked.

tqdm reads ``TQDM_*`` environment variables as overrides of its defaults when it is imported, and casts them with
``int()`` or ``float()``: ``TQDM_NCOLS=abc`` made ``import awr_denoise`` (and every ``awr`` command, ``--version``
too) fail with "invalid literal for int()", naming no variable (a red-team pass).
"""

from __future__ import annotations

import inspect
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
        shown = setting in _ON
    elif setting:
        raise ValueError(f"AWR_PROGRESS={os.environ['AWR_PROGRESS']!r}: expected 1, true, yes, on, 0, false, no or off")
    else:
        try:
            shown = sys.stderr.isatty()
        except (AttributeError, ValueError):  # replaced by an object without isatty, or closed
            shown = False
    if shown:
        _check_bar_format()
    return shown


def _check_bar_format() -> None:
    """Refuse a ``TQDM_BAR_FORMAT`` tqdm cannot draw, before any work: tqdm reads it only when it draws the first bar,
    where ``{bogus}`` was an internal error (KeyError) and ``{l_bar`` a message naming no variable (an attack pass).
    It is tried on a bar with a total and a rate and on one with neither, as the first bars are drawn. The format
    is tqdm's own default, which it took from the environment when imported (its later changes tqdm does not see)."""
    bar_format = inspect.signature(tqdm.__init__).parameters["bar_format"].default
    if bar_format is None:
        return
    try:
        tqdm.format_meter(1, 2, 0.5, bar_format=bar_format, ncols=80)
        tqdm.format_meter(0, None, 0.0, bar_format=bar_format, ncols=80)
    except Exception as exc:  # noqa: BLE001 - whatever tqdm's formatting raises is this setting's fault
        raise ValueError(f"TQDM_BAR_FORMAT={bar_format!r}: tqdm cannot draw a bar with it "
                         f"({type(exc).__name__}: {exc})") from None
