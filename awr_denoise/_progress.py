"""tqdm's progress bars, imported in one place with its environment checked.

tqdm reads ``TQDM_*`` environment variables as overrides of its defaults when it is imported, and casts them with
``int()`` or ``float()``: ``TQDM_NCOLS=abc`` made ``import awr_denoise`` (and every ``awr`` command, ``--version``
too) fail with "invalid literal for int()", naming no variable (a red-team pass).
"""

from __future__ import annotations

import os

__all__ = ["tqdm", "auto_tqdm"]

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
