"""Arrays the benchmarks cache between runs: written whole or not at all, read back only when whole.

A benchmark renders its buffers and references once and reads them back on later runs. A run
stopped while it wrote one (Ctrl-C, a kill, a full disk) left a file that opened but held only the
arrays written so far, or one that did not open: later runs measured the partial buffer without a
word, or stopped with numpy's error naming no file. :func:`save_arrays` writes through a temporary
file replaced into place; :func:`load_arrays` returns nothing for a file that does not read whole or
that its caller's ``check`` refuses, with a warning naming it, so that the caller makes it again.
"""

from __future__ import annotations

import os
import warnings
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_write

__all__ = ["save_arrays", "load_arrays"]


def save_arrays(path: str | os.PathLike[str], arrays: np.ndarray | Mapping[str, np.ndarray]) -> Path:
    """Write ``arrays`` to ``path`` whole: an ``.npz`` of a mapping, an ``.npy`` of one array.

    The data goes to a temporary file beside ``path``, then replaced into place with the mode a new
    file gets (:func:`awr_denoise.io.atomic.atomic_write`): an interrupted write leaves the old file,
    or none, never a part.

    Parameters
    ----------
    path
        The cache file (its folder is created).
    arrays
        A mapping of names to arrays (``np.savez``) or one array (``np.save``).

    Returns
    -------
    pathlib.Path
        ``path``.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     out = save_arrays(Path(tmp) / "c" / "x.npz", {"mean": np.ones(2)})
    ...     sorted(p.name for p in out.parent.iterdir()), load_arrays(out)["mean"].tolist()
    (['x.npz'], [1.0, 1.0])
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)

    def write(temporary: str) -> None:
        with open(temporary, "wb") as f:  # a file object: numpy adds no suffix to it
            if isinstance(arrays, Mapping):
                np.savez(f, **arrays)
            else:
                np.save(f, np.asarray(arrays), allow_pickle=False)

    atomic_write(path, write, overwrite=True)
    return path


def load_arrays(path: str | os.PathLike[str],
                check: Callable[[np.ndarray | dict[str, np.ndarray]], str | None] | None = None
                ) -> np.ndarray | dict[str, np.ndarray] | None:
    """The arrays :func:`save_arrays` wrote to ``path``, or ``None`` when there are none to use.

    ``None`` when the file is missing; also, with a warning naming the file and what is wrong,
    when it does not read whole (truncated, not a numpy file) or ``check`` returns a reason
    (another scene's, size's or sample count's arrays under this name; an array missing). The
    caller then makes the file again.

    Parameters
    ----------
    path
        The cache file.
    check
        Given what was read (a dict for ``.npz``, the array for ``.npy``), the reason it cannot
        be used, or ``None``.

    Returns
    -------
    numpy.ndarray or dict of numpy.ndarray or None
        What the file holds, read into memory.

    Examples
    --------
    >>> import tempfile, warnings
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     out = save_arrays(Path(tmp) / "ref.npy", np.zeros((4, 4, 3)))
    ...     good = load_arrays(out, lambda a: None if a.shape == (4, 4, 3) else f"shape {a.shape}")
    ...     with warnings.catch_warnings(record=True) as caught:
    ...         warnings.simplefilter("always")
    ...         bad = load_arrays(out, lambda a: None if a.shape == (8, 8, 3) else f"shape {a.shape}")
    ...     _ = out.write_bytes(out.read_bytes()[:40])  # cut short, as a killed writer of old left it
    ...     with warnings.catch_warnings(record=True) as cut:
    ...         warnings.simplefilter("always")
    ...         gone = load_arrays(out)
    >>> good.shape, bad, gone, "shape (4, 4, 3)" in str(caught[0].message), "ref.npy" in str(cut[0].message)
    ((4, 4, 3), None, None, True, True)
    """
    path = Path(path)
    if not path.is_file():
        return None
    try:
        with open(path, "rb") as f:  # ours to close: numpy leaves a file it could not read open
            loaded = np.load(f, allow_pickle=False)
            if isinstance(loaded, np.lib.npyio.NpzFile):
                data: np.ndarray | dict[str, np.ndarray] = {name: loaded[name] for name in loaded.files}
            else:
                data = np.asarray(loaded)
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as error:
        reason: str | None = f"unreadable ({type(error).__name__}: {error})"
    else:
        try:  # a check written for one kind of file meets the other (an .npz under an .npy's name)
            reason = check(data) if check is not None else None
        except (AttributeError, KeyError, TypeError, ValueError) as error:
            reason = f"not what it should hold ({type(error).__name__}: {error})"
    if reason is not None:
        warnings.warn(f"{path}: {reason}; it is made again", stacklevel=2)
        return None
    return data
