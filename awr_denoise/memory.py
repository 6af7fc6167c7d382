"""Keeping freed memory for the next arrays: glibc's ``mallopt``, opt-in for the process.

glibc hands each allocation above its mmap threshold (at most 32 MiB by default; a 1080p RGB plane
in float64 is 50 MB) to the kernel and back, so every whole-image temporary of a reconstruction or an
``ask()`` is a fresh mapping whose pages fault in, zero-filled, on first touch. Measured
(docs/performance.md, "Keeping freed memory"): a 1080p default reconstruction in 0.71x the time
from its second call on, for 13% more peak memory. :func:`keep_freed_memory` sets the threshold and
the trim threshold to :data:`KEEP_BELOW` so that the process' arrays come from the heap and are reused.

The library never calls it on import: the allocator is the whole process', and its host (a renderer,
a notebook) may want its own. The ``awr`` command calls it when it starts; a Python caller calls it
once, or sets ``MALLOC_MMAP_THRESHOLD_`` and ``MALLOC_TRIM_THRESHOLD_`` in the environment.
"""

from __future__ import annotations

import ctypes
import os

__all__ = ["KEEP_BELOW", "keep_freed_memory"]

KEEP_BELOW = 1 << 30
"""Bytes: blocks below this come from the heap and are kept for reuse when freed (1 GiB: an 8K RGB plane)."""

_M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters (malloc.h)
_M_MMAP_THRESHOLD = -3
_USERS_PREFIX = "MALLOC_"  # glibc's variables: MALLOC_MMAP_THRESHOLD_, MALLOC_MMAP_MAX_, MALLOC_ARENA_MAX, ...


def keep_freed_memory() -> bool:
    """Set glibc's thresholds to :data:`KEEP_BELOW` for this whole process; whether they were set.

    Left alone: other C libraries (macOS, musl, Windows), a user's own allocator settings (the
    ``MALLOC_*_`` variables, ``glibc.malloc`` tunables in ``GLIBC_TUNABLES``, a preloaded allocator) and an
    address-space limit (``ulimit -v``), under which memory kept by the heap is memory a later mapping
    cannot have. It changes no result, only the time of large arrays (the reconstruction of paper section
    5, Eq. 10-11, and the sampler's ``ask()``, section 4, at 1080p and above) and the peak memory.

    Examples
    --------
    Once, before the large images (docs/performance.md, "Keeping freed memory"):

    >>> from awr_denoise.memory import KEEP_BELOW, keep_freed_memory
    >>> KEEP_BELOW == 2**30  # blocks under 1 GiB come from the heap
    True
    >>> keep_freed_memory()  # doctest: +SKIP
    True

    (Skipped here: it would change the allocator of the process running the examples.)
    """
    try:
        if not os.confstr("CS_GNU_LIBC_VERSION").startswith("glibc"):  # type: ignore[union-attr]
            return False
    except (AttributeError, ValueError, OSError):  # not glibc (musl, macOS, Windows)
        return False
    users = any(name.startswith(_USERS_PREFIX) and value for name, value in os.environ.items())
    if users or "glibc.malloc" in os.environ.get("GLIBC_TUNABLES", ""):
        return False
    if os.environ.get("LD_PRELOAD"):  # jemalloc, tcmalloc: their own policy
        return False
    try:
        import resource

        if resource.getrlimit(resource.RLIMIT_AS)[0] != resource.RLIM_INFINITY:
            return False
        libc = ctypes.CDLL(None)  # the process' own symbols, glibc's among them (find_library runs ldconfig)
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, KEEP_BELOW)) and bool(libc.mallopt(_M_TRIM_THRESHOLD, KEEP_BELOW))
    except (ImportError, OSError, AttributeError):
        return False
