"""Atomic, non-clobbering file writes.

Every writer in :mod:`awr_denoise.io` renders into a temporary file beside the target and
moves it into place with :func:`os.replace`, so a crash or a bad input never leaves a
half-written EXR, and an existing file is only replaced when the caller asked for it.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = ["atomic_write", "check_writable"]


def check_writable(path: str | os.PathLike[str], *, overwrite: bool) -> Path:
    """Refuse early when ``path`` exists and ``overwrite`` is False.

    Raises
    ------
    FileExistsError
        The target exists and ``overwrite`` is False; the message names the file.
    """
    target = Path(path)
    if not overwrite and target.exists():
        raise FileExistsError(f"{target}: already exists (pass overwrite=True / --overwrite to replace it)")
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"{target}: directory {parent} does not exist")
    return target


def _new_file_mode(target: Path) -> int:
    """Permissions a plainly created file would get (an existing target keeps its own).

    ``mkstemp`` creates files readable by the owner only; without this a render farm's
    other users could not read what was written.
    """
    try:
        return stat.S_IMODE(target.stat().st_mode)
    except OSError:
        pass
    try:
        with open("/proc/self/status") as fh:  # reads the umask without changing it
            for line in fh:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def atomic_write(path: str | os.PathLike[str], write: Callable[[str], None], *, overwrite: bool = False) -> Path:
    """Call ``write(tmp_path)`` and move the result to ``path`` in one step.

    Parameters
    ----------
    path
        Final file name. The temporary file lives in the same directory (so the final
        rename never crosses file systems) and keeps the suffix, because some writers pick
        the format from it.
    write
        Writes the complete file to the path it is given.
    overwrite
        Replace an existing ``path``; when False an existing file is never touched.

    Returns
    -------
    Path
        The written path.
    """
    target = check_writable(path, overwrite=overwrite)
    parent = target.parent if str(target.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp" + target.suffix, dir=parent)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, _new_file_mode(target))
        if overwrite:
            os.replace(tmp, target)
        else:
            # A hard link fails if the target appeared meanwhile, where a rename would clobber it.
            try:
                os.link(tmp, target)
            except FileExistsError:
                raise FileExistsError(
                    f"{target}: already exists (pass overwrite=True / --overwrite to replace it)") from None
            except OSError:
                if target.exists():
                    raise FileExistsError(
                        f"{target}: already exists (pass overwrite=True / --overwrite to replace it)") from None
                os.replace(tmp, target)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
    return target
