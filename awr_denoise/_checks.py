"""Argument checks shared by the public functions: one line each, messages that name the parameter.

A bad value raises ``TypeError`` (not a number, a bool where a number is expected, a number
where a name is expected) or ``ValueError`` (NaN, Inf, out of range, not a whole number), and
the message starts with the parameter's name, as everywhere in the library.
"""

from __future__ import annotations

import argparse
import functools
import math
import numbers
import os
import re
import threading
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["MAX_SEED", "MAX_SPP", "MAX_SIDE", "MAX_LEVELS", "scalar", "described", "real", "whole", "whole_text",
           "whole_option", "path_option", "file_option", "folder_name", "flag",
           "seed", "shape2d", "name", "tile", "executor", "indices", "same_channels"]

MAX_SEED = 2**63 - 1
"""Seeds are whole numbers in 0..2**63-1 (they are hashed as 64-bit integers)."""

MAX_SPP = 2**24
"""Samples per pixel an option may ask for: counts are stored as float32, exact up to 2**24."""

MAX_SIDE = 2**31 - 1
"""Largest image side (EXR windows are 32-bit)."""

MAX_LEVELS = 31
"""Deepest wavelet decomposition of any image (each level halves a side of at most 2**31)."""


def scalar(value: Any) -> Any:
    """A 0-d array as its number (what ``np.asarray`` of a number or a reduction's ``out=`` gives);
    anything else as it is. A masked 0-d array stays an array (and is refused as one).

    Examples
    --------
    >>> isinstance(scalar(np.array(16)), np.ndarray), bool(scalar(np.array(16)) == 16), scalar([16])
    (False, True, [16])
    """
    if isinstance(value, np.ndarray) and value.ndim == 0 and not isinstance(value, np.ma.MaskedArray):
        return value[()]
    return value


def _number(param: str, value: Any) -> numbers.Real:
    value = scalar(value)
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{param}: expected a number, got the bool {value!r}")
    if not isinstance(value, numbers.Real):
        raise TypeError(f"{param}: expected a number, got {described(value)}")
    return value


def described(value: Any) -> str:
    """A value for a one-line message: an array by its type, shape and dtype, else its repr, cut.

    Examples
    --------
    >>> described(np.ones((2, 3))), described("abc")
    ('ndarray of shape (2, 3) and dtype float64', "str 'abc'")
    """
    if isinstance(value, np.ndarray):
        return f"{type(value).__name__} of shape {value.shape} and dtype {value.dtype}"
    shown = repr(value)
    if len(shown) > 60 or "\n" in shown:
        shown = shown.split("\n", 1)[0][:57] + "..."
    return f"{type(value).__name__} {shown}"


def _fmt(bound: float) -> str:
    return str(bound) if isinstance(bound, int) else f"{bound:.15g}"


def _bounds(param: str, value: float, minimum: float | None, maximum: float | None, above: float | None) -> None:
    shown = repr(value) if len(repr(value)) <= 40 else f"{value:.4g}"  # 1e300 as an int: not 301 digits
    if above is not None and not value > above:
        raise ValueError(f"{param}: must be > {_fmt(above)}, got {shown}")
    if minimum is not None and value < minimum:
        raise ValueError(f"{param}: must be >= {_fmt(minimum)}, got {shown}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{param}: must be <= {_fmt(maximum)}, got {shown}")


def real(param: str, value: Any, *, minimum: float | None = None, maximum: float | None = None,
         above: float | None = None, none: bool = False) -> float | None:
    """``value`` as a finite float within the bounds (``above`` is an open lower bound)."""
    if value is None and none:
        return None
    number = _number(param, value)
    try:
        result = float(number)
    except OverflowError:
        raise ValueError(f"{param}: {value!r} is beyond the float range") from None
    if not math.isfinite(result):
        raise ValueError(f"{param}: must be a finite number, got {value!r}")
    _bounds(param, result, minimum, maximum, above)
    return result


def whole(param: str, value: Any, *, minimum: int | None = None, maximum: int | None = None,
          none: bool = False, integral: bool = False) -> int | None:
    """``value`` as an int within the bounds; floats are accepted only when whole (4.0), and not
    at all with ``integral``."""
    if value is None and none:
        return None
    number = _number(param, value)
    if integral and not isinstance(number, numbers.Integral):
        raise TypeError(f"{param}: expected an integer, got {described(number)}")
    if isinstance(number, numbers.Integral):
        result = int(number)
    else:
        as_float = float(number)
        if not math.isfinite(as_float) or as_float != math.floor(as_float):
            raise ValueError(f"{param}: must be a whole number, got {value!r}")
        result = int(as_float)
    _bounds(param, result, minimum, maximum, None)
    return result


_INTEGER = re.compile(r"^\s*[+-]?[0-9]+\s*$")  # not Python's int(): no '1_0', no other scripts' digits


def whole_text(text: str, *, minimum: int | None = None, maximum: int | None = None,
               name: str = "whole number") -> int:
    """An integer written in ASCII digits (a command-line option), within the bounds.

    The message does not name the option: the command line's parser puts it in front.

    Examples
    --------
    >>> whole_text(" 12 ", minimum=1)
    12
    >>> whole_text("1_0")
    Traceback (most recent call last):
    ...
    ValueError: expected a whole number, got '1_0'
    """
    if not _INTEGER.match(text) or len(text.strip()) > 40:
        raise ValueError(f"expected a {name}, got {text!r}")
    value = int(text)
    if minimum is not None and value < minimum:
        raise ValueError(f"must be >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise ValueError(f"must be <= {maximum}, got {value}")
    return value


def whole_option(*, minimum: int | None = None, maximum: int | None = None,
                 name: str = "whole number") -> Callable[[str], int]:
    """An argparse type: an integer within bounds (``1.5``, ``1e3``, ``inf`` and ``1_0`` are refused).

    Examples
    --------
    >>> parser = argparse.ArgumentParser()
    >>> _ = parser.add_argument("--spp", type=whole_option(minimum=1))
    >>> parser.parse_args(["--spp", "4"]).spp
    4
    """

    def parse(text: str) -> int:
        try:
            return whole_text(text, minimum=minimum, maximum=maximum, name=name)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = name
    return parse


def path_option(text: str) -> Path:
    """An argparse type: a path, not empty (``''``, or spaces, would quietly mean the working directory).

    Examples
    --------
    >>> parser = argparse.ArgumentParser()
    >>> _ = parser.add_argument("--out", type=path_option)
    >>> str(parser.parse_args(["--out", "renders"]).out)
    'renders'
    """
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path (give . for this folder)")
    return Path(text)


def file_option(text: str) -> Path:
    """An argparse type: a file's path, not empty, and not ending in ``/``, ``/.`` or ``/..``, which name a folder
    (``Path`` drops the slash: ``--results q.json/`` wrote ``q.json``; an attack pass).

    Examples
    --------
    >>> parser = argparse.ArgumentParser()
    >>> _ = parser.add_argument("--results", type=file_option)
    >>> str(parser.parse_args(["--results", "q.json"]).results)
    'q.json'
    """
    path = path_option(text)
    why = folder_name(text)
    if why is not None:
        raise argparse.ArgumentTypeError(why)
    return path


def folder_name(text: str) -> str | None:
    """Why ``text`` names a folder where a file's name is due, or None: it ends in ``/``, ``/.`` or ``/..`` (or is
    ``.`` or ``..``), whatever the file system holds, though ``Path`` drops a trailing slash.

    Examples
    --------
    >>> [folder_name(t) is not None for t in ("out.exr", "out.exr/", "out/.", "..", "/")]
    [False, True, True, True, True]
    """
    if os.path.basename(text) not in ("", ".", ".."):
        return None
    return f"{text}: ends with {os.sep!r}, '.' or '..', which names a folder; give the file's name"


def flag(param: str, value: Any) -> bool:
    """``value`` as a bool; anything but True/False (a string, a number) is refused."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{param}: expected True or False, got {described(value)}")
    return bool(value)


def file_path(param: str, value: Any) -> str:
    """A file name (``str`` or ``os.PathLike`` of ``str``, not empty) as ``str``."""
    text = value.__fspath__() if isinstance(value, PathLike) else value
    if not isinstance(text, str):
        raise TypeError(f"{param}: expected a file name, got {described(value)}")
    if not text:  # a script's unset variable: refused, not read as "no file"
        raise ValueError(f"{param}: an empty file name")
    return text


def file_paths(param: str, value: Any) -> list[str]:
    """A list of file names (not one name, which would be read character by character)."""
    if isinstance(value, (str, bytes, PathLike)) or not isinstance(value, Iterable):
        raise TypeError(f"{param}: expected a list of file names, got {described(value)}")
    return [file_path(param, item) for item in value]


def seed(param: str, value: Any) -> int:
    """A seed: a whole number in 0..:data:`MAX_SEED`."""
    return whole(param, value, minimum=0, maximum=MAX_SEED)  # type: ignore[return-value]


def shape2d(param: str, value: Any, *, minimum: int = 1) -> tuple[int, int]:
    """An (H, W) image shape of whole numbers in ``minimum``..:data:`MAX_SIDE`."""
    value = scalar(value)
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or getattr(value, "ndim", 1) == 0 \
            or len(value) != 2:
        raise TypeError(f"{param}: expected (height, width), got {described(value)}")
    h, w = (whole(param, s, maximum=MAX_SIDE) for s in value)
    if min(h, w) < minimum:  # type: ignore[type-var]
        raise ValueError(f"{param}: empty image {(h, w)}" if min(h, w) >= 0 else
                         f"{param}: sides must be >= {minimum}, got {(h, w)}")
    return h, w  # type: ignore[return-value]


def name(param: str, value: Any, choices: tuple[str, ...] | None = None) -> str:
    """A name (a str, or a 0-d array of one), one of ``choices`` when given."""
    value = scalar(value)
    if not isinstance(value, str):
        raise TypeError(f"{param}: expected a name, got {described(value)}")
    if choices is not None and value not in choices:
        raise ValueError(f"{param}: {value!r} is not one of {', '.join(choices)}")
    return str(value)


def tile(shape: tuple[int, int], rows: Any, cols: Any) -> None:
    """Refuse anything but ``slice`` objects of whole bounds and a step of 1 that hold at least one of the
    ``shape`` (H, W) image's rows and columns (a tile's: a step of 2 subsampled the image, -1 mirrored it,
    0 or 2.5 gave Python's bare errors, a tile past the edge was "count: empty image")."""
    for param, value, size in (("rows", rows, shape[0]), ("cols", cols, shape[1])):
        if not isinstance(value, slice):
            raise TypeError(f"{param}: expected a slice, got {described(value)}")
        for bound in (value.start, value.stop, value.step):
            if bound is not None:
                whole(param, bound, integral=True)  # 2.0 too: Python's own words named nothing
        if value.step not in (None, 1):
            raise ValueError(f"{param}: a tile is contiguous; expected a step of 1, got {value.step!r}")
        if not len(range(size)[value]):
            bounds = ":".join("" if b is None else str(b) for b in (value.start, value.stop))
            raise ValueError(f"{param}: {bounds} holds none of the image's {size} "
                             f"{'rows' if param == 'rows' else 'columns'}")


def executor(param: str, value: Any, *, here: bool = True) -> Executor | None:
    """``value`` if it is an executor whose workers share this process' memory (threads), or None.

    The core's executors run closures over whole-image arrays: a process pool cannot take them
    (the parallel layer, :mod:`awr_denoise.parallel`, splits work for processes and Dask). ``here``:
    the executor is used now, on this thread; called on one of its own threads (a task of that pool)
    the work runs serially on it, ``None``: work waited for on a pool's own threads waits for itself
    once every thread does (with one thread, for ever). An object keeping the executor for later (a
    sampler) passes ``here=False``.
    """
    if value is not None and not isinstance(value, Executor):
        raise TypeError(f"{param}: expected a concurrent.futures.Executor, got {type(value).__name__}")
    if isinstance(value, ProcessPoolExecutor):
        raise TypeError(f"{param}: a ProcessPoolExecutor cannot share the image's arrays; pass a ThreadPoolExecutor "
                        "(awr_denoise.parallel splits work for processes)")
    if here and isinstance(value, ThreadPoolExecutor) and _on_own_thread(value):
        return None  # the same results: every use of an executor gives the serial bits
    return value


def outcome(pending: Future | None, work: Callable[[], Any], pool: Executor | None) -> Any:
    """``pending``'s result (a task ``work`` submitted to ``pool``), or ``work()`` run here: where ``pending`` is None,
    or where ``pool`` is a thread pool that has not started it yet.

    A task still queued when its result is needed is taken back and run on the thread that needs it, the same bits:
    waiting for it waited for ever where every thread of the pool waited for this one (a renderer telling a
    sampler from the sampler's own one-thread pool while another thread's ``density()`` held the sampler and
    waited for its search there: an attack pass). It is often taken back even from an idle pool, whose thread has
    not picked it up yet: this thread then works instead of waiting. Other executors' futures (Dask's, pending
    while they run) are waited for, as before: with a thread-based executor of another kind, the wait this takes
    away stays possible.

    Examples
    --------
    >>> from concurrent.futures import ThreadPoolExecutor
    >>> with ThreadPoolExecutor(1) as pool:
    ...     outcome(pool.submit(abs, -2), lambda: abs(-2), pool), outcome(None, lambda: 3, None)
    (2, 3)
    """
    if pending is None or (isinstance(pool, ThreadPoolExecutor) and pending.cancel()):
        return work()
    return pending.result()


def mapped(pool: Executor, work: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
    """``list(pool.map(work, items))``, a task not started when its result is needed run here (:func:`outcome`)."""
    items = list(items)
    pending = [pool.submit(work, item) for item in items]
    try:
        return [outcome(task, functools.partial(work, item), pool) for task, item in zip(pending, items)]
    finally:  # on an error, as map's own: the tasks not started are dropped
        for task in pending:
            task.cancel()


def _on_own_thread(pool: ThreadPoolExecutor) -> bool:
    """Whether this thread is one of ``pool``'s workers: its threads (a pool adds a new thread to them
    only after starting it, so a first task can run before), or the thread running the pool's queue."""
    current = threading.current_thread()
    queue = getattr(pool, "_work_queue", None)
    return current in getattr(pool, "_threads", ()) or any(a is queue for a in getattr(current, "_args", ()))


def indices(param: str, value: Any, n: int) -> list[int]:
    """Distinct whole numbers in ``0..n-1``, from a sequence in its order (a set, whose order is the
    hash's, a string, a mapping or a single number refused).

    Examples
    --------
    >>> indices("channels", (2, np.int64(0)), 3)
    [2, 0]
    >>> indices("channels", np.array(0), 3)
    Traceback (most recent call last):
        ...
    TypeError: channels: expected a sequence of indices, got ndarray of shape () and dtype int64
    """
    if (isinstance(value, (str, bytes, set, frozenset, Mapping)) or not isinstance(value, Iterable)
            or (isinstance(value, np.ndarray) and value.ndim != 1)):
        raise TypeError(f"{param}: expected a sequence of indices, got {described(value)}")
    items = [whole(param, i, minimum=0, maximum=n - 1) for i in value]
    if not items or len(set(items)) != len(items):
        raise ValueError(f"{param}: expected distinct indices, got {items}")
    return items


def same_channels(given: object, resolved: tuple[str, ...], held: tuple[str, ...]) -> None:
    """Refuse ``channels`` given (``resolved`` to names) for statistics named ``held`` otherwise; a count
    of theirs names nothing and is theirs.

    Examples
    --------
    >>> from awr_denoise._checks import same_channels
    >>> same_channels(3, ("R", "G", "B"), ("X", "Y", "Z"))
    >>> same_channels(("B", "G", "R"), ("B", "G", "R"), ("R", "G", "B"))
    Traceback (most recent call last):
    ...
    ValueError: channels: B, G, R given, but the buffer holds R, G, B
    """
    if tuple(resolved) != tuple(held) and not (type(given) is int and given == len(held)):
        raise ValueError(f"channels: {', '.join(resolved)} given, but the buffer holds {', '.join(held)}")
