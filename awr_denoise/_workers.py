"""Worker processes that end with their parent (standard library only).

A process pool's workers block on their pipes to the parent. When the parent dies without closing
the pool (SIGKILL from a render farm's timeout or the OOM killer), they stayed for good, orphaned,
with the pool's resource tracker. :func:`exit_with_parent`, called in a worker's initializer,
watches the parent's process id and ends the worker once the parent is gone.
"""

from __future__ import annotations

import os
import threading

__all__ = ["exit_with_parent", "POLL_SECONDS"]

POLL_SECONDS = 1.0
"""How often a worker checks that its parent lives (a thread sleeping between checks)."""


def exit_with_parent(parent: int) -> None:
    """In a worker process: exit (status 1) within about :data:`POLL_SECONDS` of the parent's death.

    ``parent`` is the process id the pool's owner passed (``os.getpid()`` there, in the
    initializer's arguments): a worker still starting when its parent died would otherwise take
    its adoptive parent for the one to watch. An orphan is adopted by another process (init, or a
    subreaper), so its parent's id changes; that is what is watched, on a daemon thread, which
    needs no help from the blocked worker.

    Examples
    --------
    >>> import os
    >>> from awr_denoise._workers import exit_with_parent
    >>> exit_with_parent(os.getppid())  # in a pool's initializer; here the parent lives: nothing happens
    """

    def watch() -> None:
        while os.getppid() == parent:
            threading.Event().wait(POLL_SECONDS)
        os._exit(1)  # no cleanup to run: the parent that owned the work is gone

    threading.Thread(target=watch, name="awr-exit-with-parent", daemon=True).start()
