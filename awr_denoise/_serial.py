"""Objects whose methods run one call at a time, whatever thread calls them (standard library only).

A sampler's state moves in steps (a request pending, told, the next asked). Two threads telling one
request at once each saw it pending: it was merged twice, counted twice and one batch was lost. A
class deriving from :class:`OneAtATime` runs its :func:`one_at_a_time` methods under the instance's
re-entrant lock; the lock is left out of pickles (a sampler travels to worker processes and into
checkpoints) and made anew when one is loaded.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["OneAtATime", "one_at_a_time"]


class OneAtATime:
    """Mixin: an instance lock (``_lock``) for :func:`one_at_a_time` methods, left out of pickles.

    Examples
    --------
    >>> import copy
    >>> from awr_denoise._serial import OneAtATime, one_at_a_time
    >>> class Counter(OneAtATime):
    ...     def __init__(self):
    ...         super().__init__()
    ...         self.n = 0
    ...     @one_at_a_time
    ...     def add(self):
    ...         self.n += 1
    ...         return self.n
    >>> counter = Counter(); counter.add()
    1
    >>> copy.deepcopy(counter).add()     # as pickle does: the state without the lock, a new lock
    2
    """

    def __init__(self) -> None:
        self._lock = threading.RLock()

    def __getstate__(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "_lock"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._lock = threading.RLock()


def one_at_a_time(method: Callable) -> Callable:
    """``method`` run under its instance's lock (:class:`OneAtATime`)."""
    @functools.wraps(method)
    def locked(self: OneAtATime, *args: Any, **kwargs: Any) -> Any:
        with self._lock:
            return method(self, *args, **kwargs)
    return locked
