"""Start Mitsuba 3 in a JIT RGB variant, or say exactly why it cannot start.

Mitsuba is an optional extra: it is imported here, lazily, the first time an adapter needs it,
with an install hint when it is missing. Mitsuba keeps its active variant in global state;
:func:`variant_scope` switches to the adapter's variant only for the duration of a call and
restores the caller's.
"""

from __future__ import annotations

import contextlib
import sys
import threading
from collections.abc import Iterator
from types import ModuleType

from .._signals import deferred as _signals_deferred
from ..errors import BackendUnavailableError

__all__ = ["DEFAULT_VARIANT", "import_mitsuba", "variant_scope", "variant_of_scene"]

DEFAULT_VARIANT = "llvm_ad_rgb"
"""The fast path: Dr.Jit's LLVM backend, RGB colour (needs a shared libLLVM)."""

INSTALL_HINT = "pip install 'awr-denoise[mitsuba]' (or: pip install 'mitsuba>=3.9')"

LLVM_HINT = ("install a shared libLLVM (Debian/Ubuntu: apt-get install libllvm19; LLVM 14 is too old "
             "and LLVM 15 aborts while compiling) or point the environment variable "
             "DRJIT_LIBLLVM_PATH at one (e.g. /usr/lib/x86_64-linux-gnu/libLLVM-19.so)")


def _check_variant_name(variant: str) -> None:
    backend, _, colour = variant.partition("_")
    if backend not in ("llvm", "cuda") or not variant.endswith("_rgb") or "polarized" in variant:
        raise ValueError(
            f"variant: {variant!r} cannot be used; the adapter renders a request as one wavefront and "
            "returns linear sRGB, so it needs a JIT RGB variant such as 'llvm_ad_rgb' or 'cuda_ad_rgb' "
            "(scalar variants trace one ray at a time, about 3x slower and a Python loop per sample)")


def import_mitsuba(variant: str = DEFAULT_VARIANT) -> tuple[ModuleType, ModuleType]:
    """``(mitsuba, drjit)`` with ``variant`` known to work; the active variant is left unchanged
    unless none was set.

    Raises
    ------
    ImportError
        Mitsuba is not installed (the message gives the install command).
    ValueError
        ``variant`` is not a JIT RGB variant, or this Mitsuba build lacks it.
    BackendUnavailableError
        The variant's Dr.Jit backend cannot start (no usable libLLVM / no CUDA device); the message
        says what to install. The scalar variants are never used as a silent fallback.
    """
    _check_variant_name(variant)
    # Signals held while Mitsuba loads (_signals_deferred), then acted on: a signal's exception raised
    # inside the import (in a Python callback of nanobind's) or while Dr.Jit starts its backend
    # aborted the process ("terminate called after throwing nanobind::python_error") or crashed it
    # at exit with Dr.Jit's threads half started: SIGABRT or SIGSEGV instead of one line and 143.
    with _signals_deferred():
        return _load(variant)


def _load(variant: str) -> tuple[ModuleType, ModuleType]:
    """:func:`import_mitsuba` once the signals are held."""
    try:
        # Optional extra, imported lazily: the adapter is the only user of Mitsuba.
        import drjit as dr
        import mitsuba as mi
    except ImportError as exc:
        raise ImportError(f"the Mitsuba 3 adapter needs Mitsuba 3: {INSTALL_HINT}") from exc
    if variant not in mi.variants():
        raise ValueError(f"variant: {variant!r} is not in this Mitsuba build (it has {', '.join(mi.variants())})")
    backend = dr.JitBackend.LLVM if variant.startswith("llvm") else dr.JitBackend.CUDA
    if not dr.has_backend(backend):
        if backend == dr.JitBackend.LLVM:
            raise BackendUnavailableError(f"Mitsuba's {variant} variant cannot start: Dr.Jit found no usable "
                                          f"libLLVM; {LLVM_HINT}")
        raise BackendUnavailableError(f"Mitsuba's {variant} variant cannot start: Dr.Jit found no CUDA device; "
                                      "use variant='llvm_ad_rgb'")
    if mi.variant() is None:
        mi.set_variant(variant)
    return mi, dr


def _set_variant(mi: ModuleType, variant: str) -> None:
    """``mi.set_variant(variant)`` with the signals held, as in :func:`import_mitsuba`: the first
    switch to a variant imports its module and starts its Dr.Jit backend."""
    with _signals_deferred():
        mi.set_variant(variant)


_MITSUBA_LOCK = threading.RLock()
"""Held around every use of Mitsuba: the active variant is process-wide, and Dr.Jit launches from
several Python threads at once failed now and then (``jitc_var_rcp(): Invalid variable type``;
measured with ``awr render --renderer mitsuba --workers 2 --tile 8`` after a render in the main
thread). One launch already runs on every core (Dr.Jit's own thread pool), so nothing is lost."""


@contextlib.contextmanager
def variant_scope(mi: ModuleType, variant: str) -> Iterator[None]:
    """Make ``variant`` the active Mitsuba variant inside the block, then restore the caller's.

    The block holds a process-wide lock: Mitsuba is used by one Python thread at a time.
    """
    with _MITSUBA_LOCK:
        previous = mi.variant()
        if previous == variant:
            yield
            return
        try:  # a signal held during the switch raises after it: the caller's variant is restored
            _set_variant(mi, variant)
            yield
        finally:
            if previous is not None:
                _set_variant(mi, previous)


def variant_of_scene(mi: ModuleType, scene: object) -> str | None:
    """The variant whose ``Scene`` class ``scene`` is an instance of (None if it is no Mitsuba scene)."""
    for variant in mi.variants():
        # Only variants already imported can own a scene (importing others could fail: no GPU).
        module = sys.modules.get(f"mitsuba.{variant}")
        cls = getattr(module, "Scene", None) if module is not None else None
        if cls is not None and isinstance(scene, cls):
            return variant
    return None
