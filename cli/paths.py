"""Every path a command reads and writes, checked together before any work starts.

A command lists its inputs (the dump, ``-r/--ref``, plane files of ``--color/--variance/--count``,
``--request``, every frame of a pattern) and its outputs (``-o``, ``--preview``, ``--image``,
derived names) in a :class:`PathPlan`; :meth:`PathPlan.check` then refuses, with one line
naming the option and the file:

* an input that is missing or not a regular file (never opened: a FIFO would hang);
* an output that is an input (same resolved path, or the same file through a hard link);
* two outputs that are one file (two options, or two frames of a sequence);
* an output that exists without ``--overwrite``, or is not a regular file even with it
  (a FIFO, a device, a directory), or whose folder is missing or not writable.

It also records what each input is then; :meth:`PathPlan.check_unchanged`, called after the last read
and before anything is written, refuses an input replaced or rewritten meanwhile (a renderer writing
its next version): the reads may have met two versions of it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from awr_denoise._checks import folder_name
from awr_denoise.errors import InputFileError
from awr_denoise.io.atomic import check_readable, check_utf8_name, check_writable
from awr_denoise.io.exr import check_same_windows, read_windows
from awr_denoise.io.presets import feature_plane_file, plane_file

from .errors import UsageError

__all__ = ["PathPlan", "check_file_name", "check_plane_windows", "plane_options", "FEATURE_OPTIONS"]

FEATURE_OPTIONS = ("--alb", "--nrm", "--depth")
"""Options naming a feature plane, which may also be a whole image file (``--alb albedo.exr``)."""


def plane_options(args: Any) -> list[tuple[str | None, str]]:
    """``(spec, option)`` of every plane option of a command (layout planes, then features)."""
    return [(args.color, "--color"), (args.variance, "--variance"), (args.count, "--count"),
            (args.alb, "--alb"), (args.nrm, "--nrm"), (args.depth, "--depth")]


def _plane_file(spec: str, option: str) -> Path | None:
    """The file a plane option reads, or None for a plane of the main input."""
    return feature_plane_file(spec) if option in FEATURE_OPTIONS else plane_file(spec)


@dataclass
class _Entry:
    path: Path
    option: str
    kind: str | None = None  # what an output is written as ("exr", "png"), checked against its name


# Image file types a name can claim: an output whose name says another type than it is written in
# is refused (-o out.png held an EXR that image viewers then refused).
_IMAGE_SUFFIXES = {".exr": "exr", ".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".tif": "tiff", ".tiff": "tiff",
                   ".hdr": "hdr", ".bmp": "bmp", ".ppm": "ppm", ".pfm": "pfm", ".tga": "tga", ".webp": "webp"}


def _not_empty(path: str | os.PathLike[str], option: str) -> None:
    # Path("") is Path("."): an empty name (a script's unset variable) was refused as the folder "."
    if not os.fspath(path):
        raise UsageError(f"{option}: an empty path")


@dataclass
class PathPlan:
    """The reads and writes of one command.

    Parameters
    ----------
    overwrite
        ``--overwrite`` was given: existing regular files may be replaced.
    """

    overwrite: bool = False
    reads: list[_Entry] = field(default_factory=list)
    writes: list[_Entry] = field(default_factory=list)
    versions: dict[Path, tuple[int, ...] | None] = field(default_factory=dict)

    def read(self, path: str | os.PathLike[str] | None, option: str) -> None:
        """An input file (None is skipped)."""
        if path is not None:
            _not_empty(path, option)
            self.reads.append(_Entry(Path(path), option))

    def read_plane(self, spec: str | None, option: str, label: str | None = None) -> None:
        """The file of a ``file.exr:plane`` option (or a feature option's whole file), if it names one;
        ``label`` names it in messages instead of ``option`` (a frame's: "--alb (frame 3)")."""
        if spec is None:
            return
        try:
            file = _plane_file(spec, option)  # None: a plane of the main input
        except ValueError as exc:  # an empty plane name after the file's colon
            raise UsageError(f"{label or option}: {exc}") from None
        self.read(file, label or option)

    def write(self, path: str | os.PathLike[str] | None, option: str, kind: str = "exr") -> None:
        """An output file (None is skipped), written as ``kind`` (``"exr"`` or ``"png"``)."""
        if path is not None:
            check_file_name(path, option)
            self.writes.append(_Entry(Path(path), option, kind))

    def check_names(self) -> None:
        """Refuse a name the files cannot carry (:class:`UsageError`), without looking at the disk."""
        for entry in self.reads + self.writes:
            _check_name(entry)

    def check(self) -> None:
        """Refuse the plan (:class:`UsageError` or ``FileExistsError``) before anything is read."""
        self.check_names()
        for entry in self.reads:
            try:
                check_readable(entry.path)
            except (OSError, ValueError) as exc:
                raise UsageError(f"{entry.option}: {exc}") from None
        inputs: dict[tuple[int, int], _Entry] = {}
        resolved_inputs: dict[Path, _Entry] = {}
        self.versions = {entry.path: _version(entry.path) for entry in self.reads}
        for entry in self.reads:
            st = os.stat(entry.path)
            inputs.setdefault((st.st_dev, st.st_ino), entry)
            resolved_inputs.setdefault(_resolved(entry), entry)
        seen: dict[Path, _Entry] = {}
        seen_inodes: dict[tuple[int, int], _Entry] = {}
        for entry in self.writes:
            resolved = _resolved(entry)
            source = resolved_inputs.get(resolved)
            try:
                st = os.stat(entry.path)
            except OSError:
                st = None
            if source is None and st is not None:
                source = inputs.get((st.st_dev, st.st_ino))
            if source is not None:
                raise UsageError(f"{entry.path}: {entry.option} is the input {source.path} "
                                 f"({source.option}); write to a new file")
            other = seen.get(resolved)
            if other is None and st is not None:
                other = seen_inodes.get((st.st_dev, st.st_ino))
            if other is not None:
                both = entry.option if entry.option == other.option else f"{other.option} and {entry.option}"
                raise UsageError(f"{entry.path}: written twice ({both}); give each output its own name")
            seen[resolved] = entry
            if st is not None:
                seen_inodes[(st.st_dev, st.st_ino)] = entry
            try:
                check_writable(entry.path, overwrite=self.overwrite)
            except FileExistsError as exc:
                raise FileExistsError(f"{entry.option}: {exc}") from None
            except (OSError, ValueError) as exc:
                raise UsageError(f"{entry.option}: {exc}") from None
        for entry in self.writes:
            claimed = _IMAGE_SUFFIXES.get(entry.path.suffix.lower())
            if claimed is not None and entry.kind is not None and claimed != entry.kind:
                raise UsageError(f"{entry.option}: {entry.path}: this output is written as {entry.kind.upper()}, "
                                 f"but its name says {entry.path.suffix}; name it .{entry.kind}")

    def check_unchanged(self) -> None:
        """Refuse (:class:`~awr_denoise.errors.InputFileError`, naming it) an input that is no longer the
        file :meth:`check` found: its reads may have met two versions (one's pixels in the other's window,
        or an error blaming the output)."""
        for path, version in self.versions.items():
            if _version(path) != version:
                raise InputFileError(f"{path}: changed while it was read (replaced or rewritten during the "
                                     "command); nothing was written: run again once it is complete")


def _version(path: Path) -> tuple[int, ...] | None:
    """What tells one version of a file from the next: a renderer replacing it by rename makes a new inode,
    one rewriting it in place changes its size or modification time (None: gone)."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def check_file_name(path: str | os.PathLike[str], option: str) -> None:
    """Refuse an output name ending in ``/``, ``/.`` or ``/..``: it names a folder, yet ``Path``
    drops the slash, so a file was written under the name without it (``-o out.exr/`` wrote
    ``out.exr``)."""
    _not_empty(path, option)
    name = os.fspath(path)
    if name == "-":  # the shells' convention for standard output, which no command writes images to
        raise UsageError(f"{option}: '-' would write a file named '-', not standard output; give a file name "
                         "('./-' for that file)")
    why = folder_name(name)  # out.exr/, out.exr/. and out.exr/.. all name a folder
    if why is not None:
        raise UsageError(f"{option}: {why}")


def _check_name(entry: _Entry) -> None:
    """Refuse a name the EXR library and the files' headers cannot carry (bytes that are not UTF-8),
    and a relative name when the current folder is gone (said "[Errno 2] No such file or directory")."""
    try:
        check_utf8_name(entry.path)
    except ValueError as exc:
        raise UsageError(f"{entry.option}: {exc}") from None
    if not entry.path.is_absolute():
        try:
            os.getcwd()
        except FileNotFoundError:
            raise UsageError(f"{entry.option}: {entry.path}: the current folder no longer exists (deleted while "
                             "this shell was in it); cd to a folder, or give absolute paths") from None


def _resolved(entry: _Entry) -> Path:
    """``entry``'s path with every link followed; a loop of symbolic links is the user's to untie."""
    try:
        return entry.path.resolve()
    except (RuntimeError, OSError) as exc:  # Python 3.11 raises RuntimeError for a loop
        raise UsageError(f"{entry.option}: {entry.path}: {exc}") from None


def check_plane_windows(main: str | os.PathLike[str] | None, specs: list[tuple[str | None, str]]) -> None:
    """Refuse plane files (``--variance F:plane``...) whose windows differ from the main input's.

    Planes of the same size but another data window would be paired with the wrong pixels.
    """
    if main is None:
        return
    windows = None
    for spec, _option in specs:
        if spec is None:
            continue
        file = _plane_file(spec, _option)
        if file is None:
            continue  # a plane of the main input itself
        if windows is None:
            windows = read_windows(main)
        theirs = read_windows(file)
        if _size(theirs) == _size(windows):  # a size mismatch is the reader's to name, by channel
            check_same_windows(file, theirs, main, windows)


def _size(windows: dict) -> tuple[int, int] | None:
    if "dataWindow" not in windows:
        return None
    (x0, y0), (x1, y1) = windows["dataWindow"]
    return y1 - y0 + 1, x1 - x0 + 1
