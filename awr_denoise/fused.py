"""Fused float32 passes of stage 1 (Eq. 10-11 and the pixel clamp): numpy, or numba on request.

Stage 1 in float32 (:mod:`awr_denoise.thresholding`) spends most of its time outside the wavelet
transforms in elementwise passes over whole planes: the log plane and its delta-method variance,
Eq. 11 on every detail band, the pixel clamp and the way back to linear radiance. In numpy each is
five to ten passes through memory; with numba (extra ``fast``) each is one compiled loop, which
made a 1080p ``reconstruct(stages=1)`` 3-18% faster once loaded (docs/performance.md).

Every function here has one signature and two implementations: the numpy one is the reference,
the numba one must give the same floats (tests/test_fused.py compares them bit for bit). The
transcendental functions (``log``, ``exp``) stay numpy's vectorised ones in both, so only
additions, multiplications, divisions and square roots are compiled, which IEEE 754 rounds
the same everywhere.

The numpy reference is the default: importing numba and loading the compiled code costs about
half a second per process, which only a process that runs stage 1 many times, or on very large
frames, wins back (a render loop, a sequence, a server; the default reconstruction spends a few
percent of its time in stage 1). ``AWR_DENOISE_KERNELS=numba`` in the environment, or
:func:`set_backend` (or :func:`using`, for a ``with`` block), chooses the compiled kernels;
:func:`backend` names the one in use.

The same choice runs loops of other modules compiled (:func:`compile_loop` compiles them with these
kernels' policy): the merge of two sets of sample statistics, every ``tell()`` (:mod:`awr_denoise.merging`,
bit for bit, tests/test_merging.py), and the moderation of samples that all agreed, at an adaptive run's
scattered counts (:mod:`awr_denoise.pooling`). That loop takes ``exp`` and powers in the compiled code, so it
agrees with its numpy reference to rounding rather than bit for bit (tests/test_pooling.py).
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import sys
import threading
import warnings
from collections.abc import Callable, Iterator
from functools import lru_cache
from types import ModuleType, SimpleNamespace

import numpy as np

from ._typing import FloatArray

__all__ = ["BACKENDS", "available", "backend", "set_backend", "using", "compile_loop", "log_plane", "shrink_band",
           "finish_plane"]

BACKENDS = ("numpy", "numba")
"""The implementations: ``"numpy"`` (the reference, always there) and ``"numba"`` (extra ``fast``)."""

_chosen: str | None = None  # set_backend's choice; None: the environment's, numpy by default
_using: tuple[int, int] | None = None  # the thread whose using() block runs, and how deep; None: no block
_using_lock = threading.Lock()
_F32_MAX = np.float32(np.finfo(np.float32).max)  # a global: numba takes it as a constant
_ENVIRONMENT = "AWR_DENOISE_KERNELS"


def set_backend(name: str | None) -> None:
    """Use ``name`` (one of :data:`BACKENDS`) from now on, or the environment's choice with ``None``.

    While another thread's :func:`using` block runs, a ``RuntimeError``: the block would put its own choice back as
    it ends, over this one.

    Examples
    --------
    >>> from awr_denoise import fused
    >>> fused.set_backend("numpy"); fused.backend()
    'numpy'
    >>> fused.set_backend(None)
    """
    with _using_lock:
        _refuse_beside_another_threads_block("set_backend")
        _set(name)


def _set(name: str | None) -> None:
    global _chosen
    _chosen = None if name is None else _runnable(name, "backend")


def _refuse_beside_another_threads_block(what: str) -> None:
    """Called under ``_using_lock``."""
    if _using is not None and _using[0] != threading.get_ident():
        raise RuntimeError(f"fused.{what}: another thread's block runs: the kernels are the process' choice, which "
                           "every thread follows; choose them once (set_backend), or one block at a time")


@contextlib.contextmanager
def using(name: str | None) -> Iterator[None]:
    """:func:`set_backend` ``name`` inside the ``with`` block, then the choice made before it again.

    The choice is the process' (the threads a reconstruction runs its bands on follow it): while one thread's block
    runs, another thread's, or its :func:`set_backend`, is a ``RuntimeError``. Two overlapping blocks each put back
    what the other had chosen, and the process kept a backend neither asked for (an attack pass). Blocks nest in
    one thread.

    Examples
    --------
    >>> from awr_denoise import fused
    >>> with fused.using("numpy"):
    ...     fused.backend()
    'numpy'
    """
    global _chosen, _using
    me = threading.get_ident()
    with _using_lock:
        _refuse_beside_another_threads_block("using")
        before, outer = _chosen, _using
        _set(name)
        _using = (me, 1 if outer is None else outer[1] + 1)
    try:
        yield
    finally:
        with _using_lock:
            _chosen, _using = before, outer


def backend() -> str:
    """The implementation in use: :func:`set_backend`'s choice, else the environment variable
    ``AWR_DENOISE_KERNELS`` (``numpy`` or ``numba``), else ``"numpy"``.

    Raises
    ------
    ValueError
        If ``AWR_DENOISE_KERNELS`` names no backend.
    ImportError
        If it names ``numba`` and numba is not installed.

    Examples
    --------
    >>> from awr_denoise.fused import BACKENDS, backend
    >>> backend() in BACKENDS
    True
    """
    if _chosen is not None:
        return _chosen
    # Empty is a value too (a job script's export of an unset name), refused as every other variable's empty value.
    return _runnable(os.environ.get(_ENVIRONMENT, "numpy").strip().lower(), _ENVIRONMENT)


def _runnable(name: str, what: str) -> str:
    """``name`` if it is a backend that can run here; else the error naming ``what`` set it."""
    if name not in BACKENDS:
        raise ValueError(f"{what}: {name!r} is not one of {', '.join(BACKENDS)}")
    if name == "numba" and _compiled() is None:
        raise ImportError(f"{what}: numba is not installed; pip install 'awr-denoise[fast]'")
    return name


def available() -> tuple[str, ...]:
    """The backends that can run here: ``("numpy",)``, and ``"numba"`` where it imports.

    Examples
    --------
    >>> from awr_denoise.fused import available
    >>> "numpy" in available()
    True
    """
    return BACKENDS if _compiled() is not None else ("numpy",)


# ------------------------------------------------------------------------------- the log plane
def log_plane(mean: FloatArray, sample_variance: FloatArray, count: FloatArray,
              k: float) -> tuple[FloatArray, FloatArray] | None:
    """One channel in the log domain in float32: ``y = sign(x) log(1 + |x| / k)`` and its
    delta-method variance ``(s2 / n) / (|x| + k)^2``, computed as ``(s2 / k^2 / n) / (1 + |x| / k)^2``
    (the log domain of :mod:`awr_denoise.domains`; Eq. 10's variances are those of this plane).

    ``mean`` and ``sample_variance`` are (H, W) float64 (views of a channel), ``count`` (H, W)
    float32. Returns ``None`` when ``|x| / k`` or ``s2 / k^2`` do not fit in float32 (the caller
    then takes the float64 path). ``log`` rather than ``log1p``: five times faster in float32,
    and the absolute error it adds near 0 (a float32 epsilon of ``1 + |x| / k``) is that of
    float32 ``y`` anyway.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.fused import log_plane
    >>> y, var_y = log_plane(np.array([[3.0, -1.0]]), np.array([[4.0, 4.0]]), np.full((1, 2), 4, np.float32), 1.0)
    >>> y.round(4), var_y                       # log(4), -log(2); 4 / 4 / 16, 4 / 4 / 4
    (array([[ 1.3863, -0.6931]], dtype=float32), array([[0.0625, 0.25  ]], dtype=float32))
    """
    kernels = _kernels()
    if kernels is None:
        return _log_plane_numpy(mean, sample_variance, count, k)
    u = np.empty(mean.shape, np.float32)
    a = np.empty(mean.shape, np.float32)
    var_y = np.empty(mean.shape, np.float32)
    if not kernels.log_plane(mean, sample_variance, count, k, u, a, var_y):
        return None
    np.log(a, out=a)  # numpy's vectorised float32 log, as in the reference
    np.copysign(a, u, out=a)
    return a, var_y


def _log_plane_numpy(mean: FloatArray, sample_variance: FloatArray, count: FloatArray,
                     k: float) -> tuple[FloatArray, FloatArray] | None:
    """:func:`log_plane` in numpy (the reference)."""
    u = np.empty(mean.shape, np.float32)
    var_y = np.empty(mean.shape, np.float32)
    with np.errstate(over="ignore"):  # checked below: an overflow sends the stage to float64
        # Times the reciprocals: float64 divisions slowed the compiled pass, and x * (1 / k)
        # is within a float64 epsilon of x / k, far below the float32 result's.
        np.multiply(mean, 1.0 / k, out=u, casting="unsafe")
        np.multiply(sample_variance, 1.0 / (k * k), out=var_y, casting="unsafe")
    a = np.abs(u)
    if not (np.isfinite(a.max()) and np.isfinite(var_y.max())):
        return None
    var_y /= count
    a += 1.0
    y = np.log(a)
    np.copysign(y, u, out=y)
    a *= a
    var_y /= a
    return y, var_y


def _log_plane_loop(mean, sample_variance, count, k, u, a, var_y):  # pragma: no cover (compiled)
    """The reference's arithmetic, pixel by pixel, before the ``log``; False on a float32 overflow."""
    finite = True
    inv_k, inv_k2 = 1.0 / k, 1.0 / (k * k)
    one = np.float32(1.0)
    for i in range(u.shape[0]):
        for j in range(u.shape[1]):
            ui = np.float32(mean[i, j] * inv_k)
            vi = np.float32(sample_variance[i, j] * inv_k2)
            ai = abs(ui)
            if not (ai <= _F32_MAX and vi <= _F32_MAX):
                finite = False
            ai = ai + one
            u[i, j] = ui
            a[i, j] = ai
            var_y[i, j] = (vi / count[i, j]) / (ai * ai)
    return finite


# ------------------------------------------------------------------------------------- Eq. 11
def shrink_band(coeff: FloatArray, variance: FloatArray, c_s: float) -> int:
    """Eq. 10-11 on one float32 detail band, in place; returns how many coefficients became 0.

    ``variance`` (the coefficients' ``Delta^2``) becomes the thresholds ``c_s * Delta``, and
    ``coeff`` becomes ``sign(W) max(|W| - c_s Delta, 0)``. Both are float32; ``c_s`` is taken
    in float32 (the largest float32 where it is beyond).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.fused import shrink_band
    >>> w, v = np.array([[-3.0, 0.5, 2.0]], np.float32), np.array([[1.0, 1.0, 4.0]], np.float32)
    >>> shrink_band(w, v, 1.0), w, v
    (2, array([[-2.,  0.,  0.]], dtype=float32), array([[1., 1., 2.]], dtype=float32))
    """
    kernels = _kernels()
    if kernels is None or not (coeff.flags.c_contiguous and variance.flags.c_contiguous):
        return _shrink_band_numpy(coeff, variance, c_s)
    return int(kernels.shrink_band(coeff.reshape(-1), variance.reshape(-1), _single(c_s)))


def _shrink_band_numpy(coeff: FloatArray, variance: FloatArray, c_s: float) -> int:
    """:func:`shrink_band` in numpy (the reference)."""
    t = np.sqrt(variance, out=variance)
    with np.errstate(over="ignore"):  # a huge c_s: infinite thresholds zero every coefficient
        t *= _single(c_s)
    shrunk = np.abs(coeff)  # Eq. 11 in place: sign(w) max(|w| - t, 0)
    shrunk -= t
    np.maximum(shrunk, 0.0, out=shrunk)
    zeroed = coeff.size - int(np.count_nonzero(shrunk))
    np.copysign(shrunk, coeff, out=coeff)
    return zeroed


def _shrink_band_loop(coeff, variance, c_s):  # pragma: no cover (compiled)
    """The reference's arithmetic, coefficient by coefficient, on flat views."""
    zeroed = 0
    zero = np.float32(0.0)
    for i in range(coeff.size):
        t = np.float32(math.sqrt(variance[i])) * c_s  # float32's sqrt, correctly rounded via float64
        variance[i] = t
        w = coeff[i]
        d = abs(w) - t
        if d > zero:
            coeff[i] = math.copysign(d, w)
        else:
            coeff[i] = math.copysign(zero, w)
            zeroed += 1
    return zeroed


# ------------------------------------------------------------------------- clamp and way back
def finish_plane(dest: FloatArray, out: FloatArray, y: FloatArray, var_y: FloatArray, mean: FloatArray,
                 k: float, pixel_clamp: float | None) -> None:
    """The pixel clamp in the log domain and the way back to radiance, into ``dest``.

    ``out`` (the synthesised float32 plane) is clamped to ``y +- pixel_clamp * sqrt(var_y)``
    (``None``: no clamp) and written to the float64 (H, W) view ``dest`` as
    ``sign(out) k (exp(|out|) - 1)``; where the clamp has zero width the pixel keeps ``mean``
    bit for bit. ``out``, ``y`` and ``var_y`` are overwritten. ``exp`` runs in float32 while
    ``|out|`` stays below its overflow; beyond, in float64 ``expm1`` capped at the largest float.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.fused import finish_plane
    >>> dest = np.empty((1, 3))
    >>> y, var = np.log(np.float32([[2.0, 3.0, 5.0]])), np.float32([[0.01, 0.0, 0.01]])
    >>> finish_plane(dest, np.float32([[0.7, 0.0, 9.0]]), y, var, np.array([[1.0, 2.0, 4.0]]), 1.0, 2.0)
    >>> dest.round(4)                           # e^0.7 - 1; the mean (zero width); e^(log 5 + 0.2) - 1
    array([[1.0138, 2.    , 5.107 ]])
    """
    kernels = _kernels()
    if kernels is None:
        _finish_plane_numpy(dest, out, y, var_y, mean, k, pixel_clamp)
        return
    clamp = pixel_clamp is not None
    c_p = _single(pixel_clamp) if clamp else np.float32(0.0)
    top = kernels.clamp_plane(out, y, var_y, c_p, clamp)  # y: the clamped plane; out: its magnitude
    if top < 88.0:  # exp(88) < 3.4e38: no float32 overflow
        np.exp(out, out=out)
        kernels.back_to_radiance(dest, out, y, var_y, mean, k, clamp)
        return
    _inverse_log_into(dest, y, k)
    if clamp:
        np.copyto(dest, mean, where=var_y == 0)


def _finish_plane_numpy(dest: FloatArray, out: FloatArray, y: FloatArray, var_y: FloatArray, mean: FloatArray,
                        k: float, pixel_clamp: float | None) -> None:
    """:func:`finish_plane` in numpy (the reference)."""
    if pixel_clamp is not None:
        reach = np.sqrt(var_y, out=var_y)
        with np.errstate(over="ignore"):  # a huge pixel_clamp: an infinite reach clamps nothing
            reach *= _single(pixel_clamp)
        bound = y + reach
        np.minimum(out, bound, out=out)
        np.subtract(y, reach, out=bound)
        np.maximum(out, bound, out=out)
    _inverse_log_into(dest, out, k)
    if pixel_clamp is not None:
        np.copyto(dest, mean, where=var_y == 0)  # a clamp of zero width: the mean, bit for bit


def _inverse_log_into(out: FloatArray, y: FloatArray, k: float) -> None:
    """``out = sign(y) k (exp(|y|) - 1)`` written into ``out`` (an (H, W) float64 view).

    float32 ``exp`` (vectorised, unlike ``expm1``) while ``|y|`` stays below its overflow;
    beyond, float64 ``expm1`` capped at the largest float, as the float64 path does."""
    a = np.abs(y)
    if float(a.max()) < 88.0:  # exp(88) < 3.4e38: no float32 overflow
        np.exp(a, out=a)
        a -= 1.0
        np.copysign(a, y, out=a)
        np.multiply(a, k, out=out, dtype=np.float64)
        return
    with np.errstate(over="ignore"):  # expm1 overflows past ~709: the largest finite float there
        e = np.expm1(a, dtype=np.float64)
    e *= k
    np.minimum(e, np.finfo(np.float64).max, out=out)
    np.copysign(out, y, out=out)


def _clamp_plane_loop(out, y, var_y, c_p, clamp):  # pragma: no cover (compiled)
    """The clamp of the reference; leaves the clamped plane in ``y``, its magnitude in ``out``,
    the reach in ``var_y``; returns the largest magnitude."""
    top = np.float32(0.0)
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            o = out[i, j]
            if clamp:
                r = np.float32(math.sqrt(var_y[i, j])) * c_p  # overflows to inf: clamps nothing
                var_y[i, j] = r
                hi = y[i, j] + r
                lo = y[i, j] - r
                o = min(o, hi)
                o = max(o, lo)
            y[i, j] = o
            m = abs(o)
            out[i, j] = m
            top = max(top, m)
    return top


def _back_to_radiance_loop(dest, e, y, reach, mean, k, clamp):  # pragma: no cover (compiled)
    """``dest = sign(y) k (e - 1)`` with ``e = exp(|y|)``; the mean where the reach is 0."""
    one = np.float32(1.0)
    zero = np.float32(0.0)
    for i in range(dest.shape[0]):
        for j in range(dest.shape[1]):
            if clamp and reach[i, j] == zero:
                dest[i, j] = mean[i, j]
            else:
                dest[i, j] = math.copysign(np.float32(e[i, j] - one), y[i, j]) * k


def _single(x: float) -> np.float32:
    """A non-negative setting as float32, the largest float32 where it is beyond (no overflow warning)."""
    return np.float32(min(x, float(_F32_MAX)))


# ------------------------------------------------------------------------------ the compiled set
def _kernels() -> SimpleNamespace | None:
    """The compiled kernels when the numba backend is in use, else ``None`` (the references)."""
    return _compiled() if backend() == "numba" else None


@lru_cache(maxsize=1)
def _compiled() -> SimpleNamespace | None:
    """The loops above compiled by numba (once; cached on disk), or ``None`` without numba."""
    loops = [compile_loop(f) for f in (_log_plane_loop, _shrink_band_loop, _clamp_plane_loop, _back_to_radiance_loop)]
    if loops[0] is None:
        return None
    return SimpleNamespace(log_plane=loops[0], shrink_band=loops[1], clamp_plane=loops[2], back_to_radiance=loops[3])


def compile_loop(loop: Callable) -> Callable | None:
    """``loop`` compiled by numba as this module's kernels are, or ``None`` without numba.

    Other modules' loops behind the same backend (:mod:`awr_denoise.merging`'s, :mod:`awr_denoise.pooling`'s)
    are compiled here, so that one policy holds for all: ``nogil``, no ``fastmath``, machine code cached on
    disk where it can be.

    Examples
    --------
    >>> from awr_denoise.fused import compile_loop
    >>> def twice(x):
    ...     return 2.0 * x
    >>> loop = compile_loop(twice)               # None where numba is not installed
    >>> loop is None or loop(1.5) == 3.0
    True
    """
    numba = _numba()
    if numba is None:
        return None
    # nogil: the channels of a 2-thread executor run at once; no fastmath: the reference's floats and their order.
    try:  # compiled once per machine: cached beside the loop's module, or in the user's cache directory
        return _Uncached(numba.njit(nogil=True, cache=True)(loop), loop)
    except RuntimeError:  # neither is writable: compile in every process instead (about 2 s)
        return numba.njit(nogil=True)(loop)


class _Uncached:
    """A cached loop that compiles again without its cache where the cache cannot be saved: numba saves it at the
    first call, and a full disk there failed the command with "no space left on device" (a red-team pass)."""

    def __init__(self, compiled: Callable, loop: Callable) -> None:
        self.run, self.loop = compiled, loop

    def __call__(self, *args: object) -> object:
        try:
            return self.run(*args)
        except OSError:  # no loop does I/O: only the cache's save can fail this way
            self.run = _numba().njit(nogil=True)(self.loop)
            return self.run(*args)


# numba's own report of a NUMBA_ variable it cannot parse: a RuntimeWarning holding a whole traceback, after which
# it runs on its default (a red-team pass: NUMBA_NUM_THREADS='' printed the traceback, exit 0).
_UNPARSED = re.compile(r"Environment variable '(NUMBA_\w+)' is defined but its associated value '(.*?)' could not be "
                       r"parsed", re.S)
_NUMBA: list = []  # [numba, or None where it is not installed], or [the ValueError of its environment], once asked
_NUMBA_LOCK = threading.Lock()  # one thread imports it: a second one's import went on from the first's failed one


def _numba() -> ModuleType | None:
    """numba (extra ``fast``), imported once, or ``None`` where it is not installed.

    Raises
    ------
    ValueError
        A ``NUMBA_`` variable numba cannot read (``NUMBA_NUM_THREADS`` empty, ``abc`` or below 1, ``NUMBA_OPT=zz``),
        named with its value, every time it is asked: numba reported the first with a traceback in a warning and
        ran on, and stopped on the last with "Number of threads specified must be > 0.", naming no variable.
    """
    with _NUMBA_LOCK:
        if not _NUMBA:
            try:
                _NUMBA.append(_import_numba())
            except ValueError as exc:
                _NUMBA.append(exc)
    if isinstance(_NUMBA[0], ValueError):
        raise ValueError(str(_NUMBA[0]))
    return _NUMBA[0]


def _import_numba() -> ModuleType | None:
    # numba's report of a variable it cannot read made an error for the import alone, by a filter that matches its
    # words and nothing else: warnings.catch_warnings(record=True) replaced every thread's filters while numba
    # loaded, and another thread's warnings were recorded here and raised in this thread (an attack pass).
    words = "Environment variable 'NUMBA_"
    warnings.filterwarnings("error", message=words, category=RuntimeWarning)
    added = ("error", re.compile(words, re.I), RuntimeWarning, None, 0)
    try:
        import numba  # optional extra "fast"
    except ImportError:
        return None
    except RuntimeWarning as exc:
        # The import stopped half-way: its modules loaded so far are let go, or every later `import numba` of the
        # process (another library's, a retry) found a numba without its `core` (a review of the change).
        for name in [name for name in list(sys.modules) if name == "numba" or name.startswith("numba.")]:
            del sys.modules[name]
        found = _UNPARSED.search(str(exc))
        if found is None:
            raise
        raise ValueError(f"{found[1]}={found[2]!r}: numba cannot read it (see numba's documentation of its "
                         "environment variables); set it to a valid value, or unset it") from None
    except ValueError as exc:  # its thread count, read at import
        value = os.environ.get("NUMBA_NUM_THREADS")
        if value is None or "thread" not in str(exc).lower():
            raise ValueError(f"numba could not be loaded: {exc}") from None
        raise ValueError(f"NUMBA_NUM_THREADS={value!r}: numba takes a whole number of threads above 0; set one, "
                         "or unset it") from None
    finally:
        with contextlib.suppress(ValueError):  # another thread's catch_warnings may have put its own list back
            warnings.filters.remove(added)
    return numba
