"""Low-level EXR access by channel name, and the plain image reader/writer.

Everything goes through OpenEXR's Python bindings (``OpenEXR.File``) with
``separate_channels=True`` so channels are looked up by name, never by position (EXR sorts
channels by name and OpenImageIO reorders them again). Integer channels keep their integer
type here, unlike OpenImageIO's float reads that normalise them to ``[0, 1]``.

Every failure on the way in is an :class:`~awr_denoise.errors.InputFileError` whose message
has the form ``<file>: <channel>: <what>`` (the channel is left out when no channel is at
fault), ready to be printed as one line.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
import sys
import tempfile
import threading
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

try:
    import resource
except ImportError:  # pragma: no cover - not on Windows
    resource = None  # type: ignore[assignment]

import numpy as np

from .. import _checks
from .._arrays import plain
from .._typing import FloatArray
from .._version import __version__
from ..channels import default_channel_names
from ..errors import InputFileError
from . import chunks
from .atomic import atomic_write, check_utf8_name, check_writable, file_kind, public_name, read_without_waiting
from .mitsuba import RAW_FILM

__all__ = [
    "ExrPart",
    "require_exr",
    "thread_list",
    "HALF_MAX",
    "read_exr",
    "write_exr",
    "file_error",
    "brief",
    "checked_plane",
    "read_image",
    "write_image",
    "read_header",
    "header_value",
    "chromaticities",
    "multi_views",
    "WINDOWS",
    "header_windows",
    "read_windows",
    "recorded_windows",
    "format_window",
    "check_same_windows",
]

HALF_MAX = 65504.0
"""Largest finite half float; larger values become Inf when stored as HALF."""


# Header attributes every EXR carries; callers never set these through ``header=`` (the data
# and display windows they may: see ``read_windows``).
_RESERVED = frozenset({"channels", "compression", "lineOrder",
                       "pixelAspectRatio", "screenWindowCenter", "screenWindowWidth", "type",
                       "tiles", "name", "version", "chunkCount"})


def file_error(path: str | os.PathLike[str], what: str, channel: str | None = None) -> InputFileError:
    """An :class:`InputFileError` reading ``<file>: <channel>: <what>``."""
    where = f"{os.fspath(path)}: {channel}: " if channel else f"{os.fspath(path)}: "
    return InputFileError(where + what)


def brief(value: object, most: int = 60) -> str:
    """``repr(value)``, cut to about ``most`` characters: a header's value in one error line (a 100-kB attribute was
    echoed whole)."""
    text = repr(value)
    return text if len(text) <= most else f"{text[:most]}... ({len(text)} characters)"


def _openexr() -> Any:
    """OpenEXR, the optional ``exr`` extra, imported on first use with an install hint."""
    try:
        import OpenEXR
    except ImportError as exc:  # pragma: no cover - exercised only without the extra
        raise ImportError("EXR support needs the 'exr' extra: pip install 'awr-denoise[exr]'") from exc
    return OpenEXR


def require_exr() -> None:
    """Raise the ``ImportError`` naming the ``exr`` extra now, where EXR files are written after long work.

    Examples
    --------
    >>> from awr_denoise.io.exr import require_exr
    >>> require_exr()  # the extra is installed: nothing to say
    """
    _openexr()


@dataclass
class ExrPart:
    """One part (subimage) of an EXR file, with its channels already in memory.

    Attributes
    ----------
    index
        Position of the part in the file.
    name
        The part's ``name`` attribute, or ``None`` for a single-part file without one.
    header
        The part's header attributes (OpenEXR.py types).
    channels
        Channel name to array: (H, W) float16/float32/uint32 for flat parts, (H, W) object
        arrays of per-pixel 1-D sample arrays (``None`` for empty pixels) for deep parts.
    deep
        True for deep scanline or deep tiled parts.
    """

    index: int
    name: str | None
    header: dict[str, Any]
    channels: dict[str, np.ndarray] = field(repr=False)
    deep: bool = False

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) from the data window."""
        lo, hi = self.header["dataWindow"]
        return (int(hi[1] - lo[1] + 1), int(hi[0] - lo[0] + 1))


def _check_magic(path: Path) -> None:
    try:
        check_utf8_name(path)
    except ValueError as exc:
        raise InputFileError(str(exc)) from None
    try:
        st = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        raise file_error(path, "no such file") from None
    except OSError as exc:
        raise file_error(path, f"cannot read: {exc.strerror or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise file_error(path, "is a directory, not an EXR file")
    if not stat.S_ISREG(st.st_mode):
        # Never opened: opening a FIFO would wait for a writer forever.
        raise file_error(path, f"is a {file_kind(st.st_mode)}, not a regular file")
    # Read without waiting: a file that only looks regular and waits for data (tracefs' trace_pipe, /proc/kmsg)
    # hung every command that read it (a red-team pass).
    try:
        magic = read_without_waiting(path, limit=3)[:4]
    except BlockingIOError:
        raise file_error(path, "not an OpenEXR file (a file that waits for data to be read)") from None
    except OSError as exc:
        raise file_error(path, f"cannot read: {exc.strerror or exc}") from None
    if magic != chunks.MAGIC:
        raise file_error(path, "not an OpenEXR file (bad magic number)")


class _Captured:
    text: str = ""  # what the C library printed while reading (OpenEXR's messages)


_CAPTURE_LOCK = threading.Lock()


def _exr_message(line: str, path: str) -> bool:
    """Whether a captured line is OpenEXR's report on the file being read.

    OpenEXR names the file (``<path>: (EXR_ERR_...) ...``) or the part it failed on
    (``Warning: Exception raised reading pixel data for part 0 - ...``).
    """
    return line.startswith(path + ": ") or "EXR_ERR_" in line or line.startswith("Warning: Exception raised")


@contextlib.contextmanager
def _pinned(path: Path) -> Iterator[str]:
    """The name to hand OpenEXR for ``path``: ``/proc/self/fd/N`` of a descriptor opened here, checked to be a regular
    file, on Linux; the path itself elsewhere.

    The bindings open the file by name, waiting for a writer if it is a FIFO: one renamed into the path after the
    checks (a race an attacker can win) held the command until a signal (an attack pass, 3 runs in 30). Opened here
    without waiting and checked, the file read is the one checked, whatever the path names meanwhile.
    """
    if not os.path.isdir("/proc/self/fd"):
        yield os.fspath(path)
        return
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except (FileNotFoundError, NotADirectoryError):
        raise file_error(path, "no such file (removed while it was read)") from None
    except OSError as exc:
        if exc.errno in _RESOURCE_ERRNOS:
            raise
        raise file_error(path, f"cannot read: {exc.strerror or exc}") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise file_error(path, f"is a {file_kind(mode)}, not a regular file (put in its place while it was read)")
        yield f"/proc/self/fd/{fd}"
    finally:
        os.close(fd)


@contextlib.contextmanager
def _captured_c_output(path: str | os.PathLike[str], opened_as: str | None = None) -> Iterator[_Captured]:
    """Collect what the C++ library prints on stdout/stderr about ``path`` instead of letting it through.

    OpenEXR reports corrupt chunks by printing (and then returning no parts); a command-line
    user must see one clean error line, so its text is captured and folded into the error.
    The redirection is process-wide, so reads are serialised by a lock: two threads
    redirecting at once would restore each other's sink and lose stdout for good (frames
    are read in threads by :func:`awr_denoise.parallel.denoise_frames`). Output of other
    threads during a read (a progress bar) lands in the capture too: it is not OpenEXR's,
    so it is written on to the stream it was meant for, and never read as a corruption report. ``opened_as``: the
    name the library was given for ``path`` (:func:`_pinned`), which its reports name and which they are told by.
    """
    captured, name = _Captured(), opened_as or os.fspath(path)
    with _CAPTURE_LOCK, _temporary(name) as out, _temporary(name) as err:
        for stream in (sys.stdout, sys.stderr):  # None when the process started with it closed
            if stream is not None:
                with contextlib.suppress(OSError, ValueError):  # the stream's own trouble is not the file's
                    stream.flush()
        # A closed stdout or stderr (a daemon, `>&-`) is left closed: nothing to restore, nothing lost.
        sinks = [(sink, fd) for sink, fd in ((out, 1), (err, 2)) if _is_open(fd) and sink.fileno() != fd]
        saved = [os.dup(fd) for _, fd in sinks]
        try:
            for sink, fd in sinks:
                os.dup2(sink.fileno(), fd)
            yield captured
        finally:
            for (_, fd), kept in zip(sinks, saved):
                os.dup2(kept, fd)
                os.close(kept)
            reports = []
            for sink, fd in sinks:
                sink.seek(0)
                passed = bytearray()
                for line in sink.read().splitlines(keepends=True):
                    text = line.decode("utf-8", "replace")
                    if _exr_message(text.rstrip("\r\n"), name):
                        reports.append(text)
                    else:
                        passed += line
                if passed:
                    with open(fd, "wb", closefd=False) as stream:  # the bytes as they were printed
                        stream.write(passed)
            captured.text = "".join(reports).replace(name, os.fspath(path))


def _temporary(name: str) -> Any:
    """A temporary file for the C library's messages; without one (no writable temporary folder,
    no file descriptor left) the reading fails for the machine's reason, not as a corrupt file."""
    try:
        return tempfile.TemporaryFile()
    except OSError as exc:
        raise OSError(exc.errno if exc.errno in _RESOURCE_ERRNOS else None,
                      f"{name}: no temporary file for OpenEXR's messages ({exc.strerror or exc}); "
                      "set TMPDIR to a writable folder") from None


# Failures of the machine, not of the file: kept as they are (exit 1), never called a corrupt EXR.
_RESOURCE_ERRNOS = (errno.EMFILE, errno.ENFILE, errno.ENOMEM, errno.ENOSPC, errno.EFBIG)


def _few_descriptors() -> bool:
    """Whether this process is within a few file descriptors of its limit (Linux's /proc; False elsewhere)."""
    if resource is None:
        return False
    try:
        return len(os.listdir("/proc/self/fd")) + 4 >= resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    except (OSError, ValueError):
        return False


def _is_open(fd: int) -> bool:
    try:
        os.fstat(fd)
    except OSError:
        return False
    return True


def read_exr(path: str | os.PathLike[str], *, header_only: bool = False) -> list[ExrPart]:
    """Read every part of an EXR file, channels by name.

    Parameters
    ----------
    path
        The file.
    header_only
        Read only the headers (cheap probing); ``channels`` are then empty.

    Raises
    ------
    InputFileError
        The file is missing, not an EXR, truncated or corrupt.
    """
    p = Path(path)
    _check_magic(p)
    OpenEXR = _openexr()
    deep_types = {OpenEXR.deepscanline, OpenEXR.deeptile}
    parts: list[ExrPart] = []
    source = os.fspath(p)
    try:
        with _pinned(p) as source, _captured_c_output(p, source) as captured, \
                OpenEXR.File(source, separate_channels=True, header_only=header_only) as f:
            for i, part in enumerate(f.parts):
                header = _checked_header(p, dict(f.header(i)))
                channels = {} if header_only else {name: ch.pixels for name, ch in f.channels(i).items()}
                name = header.get("name")
                parts.append(ExrPart(i, str(name) if name is not None else None, header, channels,
                                     header.get("type") in deep_types))
    except InputFileError:
        raise
    except MemoryError:
        if header_only:
            raise
        raise _out_of_memory(p) from None
    except OSError as exc:  # raised by this module's own calls (the capture), not by the bindings
        if exc.errno is None or exc.errno in _RESOURCE_ERRNOS:
            raise
        raise _unreadable(p, str(exc).replace(source, os.fspath(p)), header_only) from None
    except Exception as exc:  # the bindings raise RuntimeError/ValueError/... for corrupt data
        detail = str(exc).replace(source, os.fspath(p)).splitlines()[0] if str(exc) else type(exc).__name__
        if detail.startswith("Unable to open") and _few_descriptors():
            # OpenEXR says this of a corrupt header too, and of a file it could not open for want of a descriptor
            # (ulimit -n 7): then a valid input was called corrupt (a red-team pass).
            raise OSError(errno.EMFILE, f"OpenEXR could not open it ({os.strerror(errno.EMFILE)}: {detail})",
                          os.fspath(p)) from None
        raise _unreadable(p, detail, header_only) from None
    if not parts or (captured.text and not header_only):
        # The bindings report unreadable pixel data on the C streams and return no parts.
        detail = captured.text.strip().splitlines()[-1] if captured.text.strip() else "no readable parts"
        # The bindings' report names the file: a path holding their phrase must not be read as it.
        if _MEMORY_REPORT.search(captured.text.replace(os.fspath(p), "")):
            raise _out_of_memory(p)  # the bindings ran out of memory reading the pixels
        # Their report may have gone elsewhere; the headers' own read never asks (it would recurse).
        impossible = None if captured.text or header_only else _impossible_size(p)
        if impossible is not None:
            raise impossible
        if not captured.text and _python_stdout_elsewhere():
            # Not captured here (a global swap of sys.stdout would reach other threads): said where.
            detail += "; OpenEXR printed its reason to Python's sys.stdout"
        raise _unreadable(p, detail.replace(os.fspath(p) + ": ", ""), header_only)
    if not header_only:
        for part in parts:
            for name, arr in part.channels.items():
                if arr is None or (not part.deep and arr.shape != part.shape):
                    raise file_error(p, _subsampled(part, name) or "truncated or corrupt EXR (channel data missing)",
                                     name)
        log = getattr(_RECORDS, "items", None)
        if log is not None:
            log.append((os.fspath(p), header_windows(parts[0].header), chromaticities(parts[0].header)))
    return parts


# The reads of this thread a caller is recording (recorded_windows), or None.
_RECORDS = threading.local()


@contextlib.contextmanager
def thread_list(local: threading.local) -> Iterator[list]:
    """A new list as ``local.items`` for this thread within the block; the one before it (or none) put back after.

    Examples
    --------
    >>> import threading
    >>> local = threading.local()
    >>> with thread_list(local) as outer:
    ...     with thread_list(local) as inner:
    ...         local.items.append(1)
    ...     (outer, inner, local.items is outer)
    ([], [1], True)
    """
    outer = getattr(local, "items", None)
    local.items = found = []
    try:
        yield found
    finally:
        local.items = outer


@contextlib.contextmanager
def recorded_windows() -> Iterator[list[tuple[str, dict[str, Window], tuple[float, ...] | None]]]:
    """``(path, windows of part 0, its chromaticities or None)`` of each file :func:`read_exr` reads with its pixels
    in this thread meanwhile, in the order read.

    The windows are those of the very read that gave the pixels. A reader that returns pixels alone
    (``read_sample_buffer``) followed by :func:`read_windows` opens the path twice: a file replaced by
    rename in between (a renderer writing its next version) gave one version's pixels and the
    other's windows, the pixels written at the wrong place.
    """
    with thread_list(_RECORDS) as log:
        yield log


def _python_stdout_elsewhere() -> bool:
    """Whether Python's sys.stdout, where the bindings print their pixel-data report, is not file
    descriptor 1 (a notebook, a test runner, a caller's ``redirect_stdout``)."""
    try:
        return sys.stdout is not None and sys.stdout.fileno() != 1
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is both
        return True


# The bindings' own reports of running out of memory (Python's, the C++ allocator's, OpenEXR's),
# matched with the file's path removed so that a path holding their phrase is not taken for one.
# OpenEXR's EXR_ERR_OUT_OF_MEMORY alone is not one: it also reports corrupt compressed data
# ("Unable to decompress ... got 0"); only its failed allocation is.
_MEMORY_REPORT = re.compile(r"^Warning: Exception raised reading pixel data for part \d+ - "
                            r"(MemoryError|std::bad_alloc)\b|\(EXR_ERR_OUT_OF_MEMORY\) Unable to allocate\b", re.M)

# The most a compression can shrink a chunk of HALF samples (the claim below counts 2 bytes a
# sample; FLOAT and UINT take more, so their ratio is lower), with a margin of 1.5 or more: uncompressed 1;
# B44 a 4x4 block of 32 bytes to 14, B44A a flat block to 3 (other channel types are stored
# uncompressed); RLE 128 bytes to a 2-byte run; zlib (ZIP, ZIPS and PXR24's stage) about 1032:1.
# PIZ, DWAA, DWAB and ZSTD (32768:1 a run-length block) are held to _MAX_RATIO. HTJ2K (and any
# compression added later) keeps its per-chunk size almost constant as the chunk grows: no bound.
_MAX_RATIO = 2**20
_RATIOS = {"NO": 2, "B44": 4, "B44A": 16, "RLE": 128, "ZIPS": 2048, "ZIP": 2048, "PXR24": 2048,
           "PIZ": _MAX_RATIO, "DWAA": _MAX_RATIO, "DWAB": _MAX_RATIO, "ZSTD": _MAX_RATIO}
"""No bounded compression shrinks pixels by more than its ratio here (at most a millionfold): a
header claiming more than that many times the file's size is corrupt, whatever the machine's memory."""


def _claimed_bytes(path: Path) -> tuple[int, int | None]:
    """A lower bound on the bytes the headers' flat data windows claim (2 a sample: HALF; 0 if
    unknown), and the largest ratio any part's compression allows (``None``: no bound, as for deep
    parts, where a pixel may hold no sample)."""
    claimed, ratio = 0, 1
    with contextlib.suppress(InputFileError, OSError, MemoryError, KeyError, TypeError, ValueError):
        for part in read_exr(path, header_only=True):
            name = str(part.header.get("compression", "")).rsplit(".", 1)[-1].removesuffix("_COMPRESSION")
            bound = None if part.deep else _RATIOS.get(name)
            ratio = None if bound is None or ratio is None else max(ratio, bound)
            if part.deep:
                continue
            (x0, y0), (x1, y1) = header_windows(part.header)["dataWindow"]
            pixels = (x1 - x0 + 1) * (y1 - y0 + 1)
            for ch in part.header.get("channels", ()):
                claimed += 2 * pixels // max(1, int(ch.xSampling) * int(ch.ySampling))
        return claimed, ratio
    return 0, None


def _impossible_size(path: Path, claimed: tuple[int, int | None] | None = None) -> InputFileError | None:
    """The file's error if its headers claim more pixel data than its size could hold."""
    size, ratio = _claimed_bytes(path) if claimed is None else claimed
    with contextlib.suppress(OSError):
        if ratio is not None and size > ratio * max(path.stat().st_size, 1):
            return file_error(path, f"its data window claims {size / 2**30:.3g} GiB of pixels in a file of "
                                    f"{path.stat().st_size} bytes (truncated or corrupt header)")
    return None


def _out_of_memory(path: Path) -> Exception:
    """A read that ran out of memory: the file's error for a header no file of its size could
    hold (200000x200000 pixels in 600 bytes), else the machine's, naming the claimed size."""
    claimed = _claimed_bytes(path)
    impossible = _impossible_size(path, claimed)
    if impossible is not None:
        return impossible
    size = claimed[0]
    return MemoryError(f"reading {path}" + (f" (its pixels take {size / 2**30:.3g} GiB or more)" if size else ""))


def _subsampled(part: ExrPart, name: str) -> str | None:
    """Why channel ``name`` of a valid file has no full-size pixels: it is subsampled (the bindings read none of its
    data, which was called corrupt: an attack pass), or None."""
    channel = next((c for c in part.header.get("channels", ()) if getattr(c, "name", None) == name), None)
    sampling = (int(getattr(channel, "xSampling", 1)), int(getattr(channel, "ySampling", 1)))
    if sampling == (1, 1):
        return None
    return (f"subsampled {sampling[0]}x{sampling[1]} (a luminance-chroma image?), which is not read; write every "
            "channel at full resolution")


def _unreadable_attribute(path: Path) -> str | None:
    """A header attribute the bindings cannot read in a file that is otherwise valid, or None: a string that is not
    UTF-8 (the format's strings are bytes) or a rational whose denominator is 0 (both were called corrupt: an attack
    pass). Read from the raw header of a single-part scanline file (chunks.layout); other layouts are not looked at."""
    try:
        with open(path, "rb") as fh:
            found = chunks.layout(fh)
    except OSError:
        return None
    if found is None:
        return None
    for raw_name, (kind, value) in found.attributes.items():
        name = raw_name.decode("utf-8", "replace")
        if kind == b"string":
            try:
                value.decode("utf-8")
            except UnicodeDecodeError:
                return f"attribute {name}: a string that is not UTF-8 text, which the OpenEXR bindings cannot read"
        elif kind == b"rational" and len(value) == 8 and int.from_bytes(value[4:], "little") == 0:
            numerator = int.from_bytes(value[:4], "little", signed=True)
            return f"attribute {name}: the rational {numerator}/0, which the OpenEXR bindings cannot read"
    return None


def _unreadable(path: Path, detail: str, header_only: bool) -> InputFileError:
    """Why the pixels of ``path`` could not be read: a valid multi-level (mipmap, ripmap) tiled
    file, which the bindings cannot read, or a truncated or corrupt one."""
    if not header_only:
        try:
            for part in read_exr(path, header_only=True):
                mode = getattr(part.header.get("tiles"), "mode", None)
                if mode is not None and "LEVELS" in str(mode) and "ONE_LEVEL" not in str(mode):
                    return file_error(path, f"part {part.index} is a multi-level tiled EXR ({mode.name}), which "
                                            "is not read; write it with one level")
        except InputFileError:
            pass
    attribute = _unreadable_attribute(path)
    if attribute is not None:
        return file_error(path, f"{attribute}; rewrite the file without it (for example with oiiotool)")
    return file_error(path, f"truncated or corrupt EXR ({detail})")


def _checked_header(path: Path, header: dict[str, Any]) -> dict[str, Any]:
    """Refuse attributes the bindings cannot turn into text (a corrupt string attribute comes
    back as an opaque value whose ``str()`` raises UnicodeDecodeError later, far from the file)."""
    for key, value in header.items():
        if isinstance(value, (str, bytes, int, float, bool, tuple, list, np.ndarray, np.generic)) or value is None:
            continue
        try:
            str(value)
        except (UnicodeDecodeError, ValueError):
            raise file_error(path, f"header attribute {key!r} is not valid text (corrupt file)") from None
    return header


def read_header(path: str | os.PathLike[str], part: int = 0) -> dict[str, Any]:
    """Header attributes of one part of an EXR file (no pixel data is read)."""
    parts = read_exr(path, header_only=True)
    if not 0 <= part < len(parts):
        raise file_error(path, f"has {len(parts)} part(s), part {part} requested")
    return parts[part].header


def multi_views(parts: Sequence[ExrPart]) -> list[str]:
    """The views of a part that holds several (OpenEXR's ``multiView``: the first view's channels bare, the others'
    prefixed with their view's name, ``right.R``), in its order; [] for none."""
    views: list[str] = []
    for part in parts:
        for v in part.header["multiView"] if "multiView" in part.header else ():
            if str(v) not in views:
                views.append(str(v))
    return views


def chromaticities(header: Mapping[str, Any]) -> tuple[float, ...] | None:
    """The ``chromaticities`` attribute of a header (CIE xy of the red, green and blue primaries and the white), as
    eight floats, or None where it has none (sRGB, the format's default); kept from input to output by the
    commands that read pixels in them (``denoise``, ``merge``)."""
    if "chromaticities" not in header:
        return None
    try:
        values = tuple(float(v) for v in header["chromaticities"])
    except (TypeError, ValueError):
        return None  # not a chromaticities attribute: its reader says so, where it reads one
    return values if len(values) == 8 else None


def header_value(header: Mapping[str, Any], key: str) -> Any:
    """A header attribute as a plain Python value (bytes decoded, numpy scalars unwrapped)."""
    value = header[key]
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.generic):
        return value.item()
    return value


WINDOWS = ("dataWindow", "displayWindow")
"""The EXR header attributes that place the pixels: kept from input to output by every command."""

Window = tuple[tuple[int, int], tuple[int, int]]


def header_windows(header: Mapping[str, Any]) -> dict[str, Window]:
    """The data and display windows of a header as ``((xmin, ymin), (xmax, ymax))`` tuples."""
    out: dict[str, Window] = {}
    for key in WINDOWS:
        if key in header:
            lo, hi = header[key]
            out[key] = ((int(lo[0]), int(lo[1])), (int(hi[0]), int(hi[1])))
    return out


def read_windows(path: str | os.PathLike[str], part: int = 0) -> dict[str, Window]:
    """The data and display windows of one part of an EXR file (no pixel data is read).

    Pass them back through ``header=`` of the writers to keep a crop where it was.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from awr_denoise.io import write_image
    >>> from awr_denoise.io.exr import read_windows
    >>> f = os.path.join(tempfile.mkdtemp(), "crop.exr")
    >>> _ = write_image(f, np.ones((2, 3)), header={"dataWindow": ((100, 200), (102, 201)),
    ...                                             "displayWindow": ((0, 0), (1919, 1079))})
    >>> read_windows(f)
    {'dataWindow': ((100, 200), (102, 201)), 'displayWindow': ((0, 0), (1919, 1079))}
    """
    return header_windows(read_header(path, part))


def format_window(window: Window) -> str:
    """``(xmin,ymin)-(xmax,ymax)``."""
    (x0, y0), (x1, y1) = window
    return f"({x0},{y0})-({x1},{y1})"


def check_same_windows(path: str | os.PathLike[str], windows: Mapping[str, Window],
                       other_path: str | os.PathLike[str], other_windows: Mapping[str, Window]) -> None:
    """Refuse two files whose data or display windows differ (their pixels do not line up).

    Raises
    ------
    InputFileError
        Naming both files and both windows.
    """
    for key, label in (("dataWindow", "data window"), ("displayWindow", "display window")):
        a, b = windows.get(key), other_windows.get(key)
        if a is not None and b is not None and a != b:
            raise file_error(path, f"{label} {format_window(a)} does not match {format_window(b)} of "
                                   f"{os.fspath(other_path)}")


def _window(path: str | os.PathLike[str], key: str, value: Any, shape: tuple[int, int] | None) -> Any:
    """A window attribute for the bindings, checked against the pixel arrays' (H, W)."""
    try:
        (x0, y0), (x1, y1) = ((int(v) for v in corner) for corner in value)
    except (TypeError, ValueError):
        raise ValueError(f"header: {key} must be ((xmin, ymin), (xmax, ymax)), got {value!r}") from None
    if not all(-(2**30) <= v < 2**30 for v in (x0, y0, x1, y1)) or x1 < x0 or y1 < y0:
        raise ValueError(f"header: {key} {value!r} is not a valid window")
    if key == "dataWindow" and shape is not None and (y1 - y0 + 1, x1 - x0 + 1) != tuple(shape):
        raise ValueError(f"{public_name(path)}: dataWindow {format_window(((x0, y0), (x1, y1)))} is "
                         f"{x1 - x0 + 1}x{y1 - y0 + 1}, the image {shape[1]}x{shape[0]}")
    return (np.array([x0, y0], np.int32), np.array([x1, y1], np.int32))


def checked_plane(path: str | os.PathLike[str], name: str, array: np.ndarray, *,
                  nonnegative: bool = False, unit: str = "pixel", whole: bool = False) -> FloatArray:
    """A channel as float64, refusing NaN, Inf (half overflow named) and, optionally, negatives.

    A HALF channel's +-65504 (:data:`HALF_MAX`) is refused like Inf: Blender writes values above
    the half-float maximum as 65504 (clamped), not Inf, and the clamped value read as a mean is too
    small by an unknown factor (and, the same in every seed, of variance 0).

    ``unit`` names what the entries are in messages (``"pixel"``, or ``"sample"`` for deep data).
    ``whole``: the channel holds whole numbers (counts, masks), which a UINT channel may; a UINT
    channel of values is refused.
    """
    a = np.asarray(array)
    if a.dtype.kind not in "fiu":
        raise file_error(path, f"unsupported channel type {a.dtype}", name)
    if a.dtype.kind in "iu" and not whole:
        # Mitsuba's component_format="uint32" stores clamp(x, 0, 1) * 2**32: read as numbers these
        # are values 10**9 times too large, and clamped.
        raise file_error(path, "a UINT channel holds fixed-point or integer data, not floating-point values; "
                               "write HALF or FLOAT channels (Mitsuba: component_format float32)", name)
    out = a.astype(np.float64)
    half = a.dtype == np.float16
    if out.size and np.isfinite(out).all() and not nonnegative and not (half and (np.abs(out) == HALF_MAX).any()):
        return out
    nan = np.isnan(out)
    if nan.any():
        raise file_error(path, f"{int(nan.sum())} {unit}(s) hold NaN", name)
    inf = np.isinf(out)
    if half and not inf.any():
        # Blender clamps to the half maximum where pbrt writes Inf: the value is lost all the same.
        clamped = np.abs(out) == HALF_MAX
        if clamped.any():
            raise file_error(path, f"{int(clamped.sum())} {unit}(s) hold {HALF_MAX:g}, the half-float maximum: "
                                   f"half-float overflow (values above it do not fit; Blender writes them as "
                                   f"{HALF_MAX:g}); write FLOAT channels (Blender: Float (Full))", name)
    if inf.any():
        if half:
            raise file_error(path, f"{int(inf.sum())} {unit}(s) hold Inf: half-float overflow "
                                   f"(values above {HALF_MAX:g} do not fit; write FLOAT channels)", name)
        raise file_error(path, f"{int(inf.sum())} {unit}(s) hold Inf", name)
    if nonnegative:
        neg = out < 0
        if neg.any():
            raise file_error(path, f"{int(neg.sum())} {unit}(s) are negative", name)
    return out


def _attribute(key: str, value: Any) -> Any:
    if key in _RESERVED:
        raise ValueError(f"header: {key!r} is set by the writer and cannot be given")
    if key == "chromaticities":  # written as the format's own type (eight floats), which readers take as the space
        values = np.asarray(value, dtype=np.float64).ravel() if not isinstance(value, str) else np.array([])
        if values.size != 8 or not np.isfinite(values).all():
            raise ValueError(f"header: chromaticities: expected 8 finite numbers (rx ry gx gy bx by wx wy), got "
                             f"{brief(value)}")
        return tuple(float(v) for v in values)
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, (int, np.integer)):
        v = int(value)
        # EXR int attributes are 32-bit; larger values (seeds) are kept exact as text.
        return v if -(2**31) <= v < 2**31 else str(v)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, (str, np.ndarray)):
        return value
    if value is None:
        return "none"
    return str(value)


_WRITABLE = {np.dtype(np.float32), np.dtype(np.float16), np.dtype(np.uint32)}


def _plane_to_write(name: str, plane: object, deep: bool) -> np.ndarray:
    """A plane as the bindings take it: C-ordered, native byte order, FLOAT, HALF or UINT (object
    arrays of per-pixel samples for deep data); masked entries and other types refused, naming it."""
    a = plain(name, plane)
    if deep and a.dtype == object:
        return np.ascontiguousarray(a)
    native = a.dtype.newbyteorder("=")
    if native not in _WRITABLE:
        raise TypeError(f"{name}: a plane of dtype {a.dtype}; write float32 (FLOAT), float16 (HALF) or uint32 (UINT)")
    return np.ascontiguousarray(a, dtype=native)


def write_exr(path: str | os.PathLike[str], channels: Mapping[str, np.ndarray],
              header: Mapping[str, Any] | None = None, *, overwrite: bool = False,
              deep: bool = False) -> Path:
    """Write named channels to a single-part EXR, atomically.

    Parameters
    ----------
    channels
        Name to (H, W) array: float32 becomes FLOAT, float16 HALF, uint32 UINT; for
        ``deep=True``, (H, W) object arrays of per-pixel 1-D sample arrays.
    header
        Extra attributes (str, int, float, or numpy matrices); ints outside 32 bits are
        stored as text so nothing is truncated.
    overwrite
        Replace an existing file.
    deep
        Write a deep scanline file (ZIPS compression: deep data allows only NONE/RLE/ZIPS).
    """
    OpenEXR = _openexr()
    check_writable(path, overwrite=overwrite)
    attrs: dict[str, Any] = {
        "compression": OpenEXR.ZIPS_COMPRESSION if deep else OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.deepscanline if deep else OpenEXR.scanlineimage,
    }
    # The bindings write a plane's raw buffer and ignore its strides: a Fortran-ordered, transposed
    # or broadcast plane (counts a renderer stores (W, H) and hands over transposed) was written in
    # memory order, a permutation of its pixels. Each plane goes in as a C-ordered array.
    data = {name: _plane_to_write(name, plane, deep) for name, plane in channels.items()}
    shape = next((tuple(np.shape(a))[:2] for a in data.values()), None)
    for key, value in (header or {}).items():
        key = str(key)
        attrs[key] = _window(path, key, value, shape) if key in WINDOWS else _attribute(key, value)

    def _write(tmp: str) -> None:
        # OpenEXR.File adds dataWindow/displayWindow to the dict it is given: pass a copy.
        with OpenEXR.File(dict(attrs), data) as f:
            try:
                f.write(tmp)
            except RuntimeError as exc:  # the bindings report I/O errors (a full disk) this way
                code = (errno.ENOSPC if "No space left" in str(exc) else
                        errno.EFBIG if "File too large" in str(exc) else
                        # Its folder gone: atomic_write says so, as an output not written (exit 1).
                        errno.ENOENT if "No such file or directory" in str(exc) else errno.EIO)
                raise OSError(code, os.strerror(code), public_name(path)) from None
        # A file small enough to be written only when the stream closes reports no failure there: a full disk left
        # it empty and a file size limit cut it, and both were committed (a red-team pass). Its chunks are counted.
        if not chunks.is_complete(tmp):
            raise OSError(errno.EIO, "written short (a full disk or a file size limit?)", public_name(path))

    return atomic_write(path, _write, overwrite=overwrite)


def _find_rgb(path: Path, names: Sequence[str]) -> list[str]:
    if {"R", "G", "B"} <= set(names):
        return ["R", "G", "B"]
    layers = sorted({n.rsplit(".", 1)[0] for n in names if "." in n
                     if all(f"{n.rsplit('.', 1)[0]}.{c}" in names for c in "RGB")})
    if len(layers) == 1:
        return [f"{layers[0]}.{c}" for c in "RGB"]
    if len(layers) > 1:
        raise file_error(path, f"ambiguous colour channels: layers {', '.join(layers)} all have R,G,B "
                               "(choose one with channels= / awr diff --channels or --ref-channels)")
    if {"X", "Y", "Z"} <= set(names):  # Y alone was compared: a third of the image, without a word
        raise file_error(path, "holds CIE X,Y,Z, not R,G,B; compare it with another X,Y,Z image (channels= / "
                               "awr diff --channels X,Y,Z --ref-channels X,Y,Z)")
    if "Y" in names:
        return ["Y"]
    if len(names) == 1:
        return list(names)
    raise file_error(path, f"no R,G,B channels (found {', '.join(sorted(names))}); choose with channels= / "
                           "awr diff --channels or --ref-channels")


def read_image(path: str | os.PathLike[str], *, channels: Sequence[str] | None = None,
               view: str | None = None) -> FloatArray:
    """Read an image from an EXR file as an (H, W, C) float32 array.

    Parameters
    ----------
    path
        A flat (not deep) EXR file.
    channels
        Channel names to read, in this order. By default ``R, G, B``; else the ``R, G, B``
        of the only layer that has them (``ViewLayer.Combined.R``...); else ``Y``; else the
        single channel of a one-channel file.
    view
        The view to read of a multi-view file (stereo: ``left``, ``right``), whose views repeat
        the same channel names; parts without a view are read with any.

    Returns
    -------
    ndarray
        (H, W, C) float32 (half channels are promoted).

    Raises
    ------
    InputFileError
        Missing file or channel, ambiguous layers, a deep file, NaN or Inf values.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from awr_denoise.io import write_image, read_image
    >>> d = tempfile.mkdtemp(); f = os.path.join(d, "img.exr")
    >>> _ = write_image(f, np.ones((2, 3, 3)))
    >>> read_image(f).shape
    (2, 3, 3)
    """
    if channels is not None and (isinstance(channels, (str, bytes, set, frozenset))
                                 or not hasattr(channels, "__iter__")):
        raise TypeError(f"channels: expected a list or tuple of channel names in the image's order, got "
                        f"{type(channels).__name__}")
    p = Path(path)
    parts = [part for part in read_exr(p) if not part.deep]
    if not parts:
        raise file_error(p, "is a deep EXR, a per-sample dump, not an image (read it with read_deep_samples, "
                              "or denoise it first: awr denoise)")
    views = list(dict.fromkeys(str(header_value(part.header, "view")) for part in parts if "view" in part.header))
    # A single-part multi-view file (OpenEXR's multiView): the first view's channels bare, the others'
    # prefixed with their view's name (right.R).
    within = multi_views(parts)
    views += [v for v in within if v not in views]
    if view is not None:
        if view not in views:
            raise file_error(p, f"no view {view!r} (views: {', '.join(views) or 'none, a single-view file'})")
        parts = [part for part in parts if "view" not in part.header or str(header_value(part.header, "view")) == view]
    available: dict[str, tuple[ExrPart, np.ndarray]] = {}
    shared: set[str] = set()
    for part in parts:
        for name, arr in part.channels.items():
            if name in available:
                shared.add(name)  # two views (or parts) of one name: never pick one silently
            available.setdefault(name, (part, arr))
    wanted = list(channels) if channels is not None else _find_rgb(p, list(available))
    if view is not None and view in within[1:]:
        wanted = [f"{view}.{name}" for name in wanted]
    elif view is None and any(f"{v}.{name}" in available for v in within[1:] for name in wanted):
        raise file_error(p, f"holds views {', '.join(within)} in one part (the first's channels bare): choose one "
                            "with view=; awr diff: --view, --ref-view", wanted[0])
    writer = str(header_value(parts[0].header, "generatedBy")) if "generatedBy" in parts[0].header else ""
    if "W" in available and "." not in wanted[0] and writer.startswith("Mitsuba"):
        # Mitsuba's raw film: weighted sums beside their weights (a red-team pass: awr diff compared the sums)
        raise file_error(p, RAW_FILM, "W")
    first_window = header_windows(parts[0].header).get("dataWindow")
    planes = []
    shape = None
    for name in wanted:
        if name not in available:
            raise file_error(p, f"no such channel (found {', '.join(sorted(available))})", name)
        if name in shared:
            choose = f" (views {', '.join(views)}: choose one with view=; awr diff: --view, --ref-view)"
            raise file_error(p, "is in several parts" + (choose if len(views) > 1 and view is None else ""), name)
        part, arr = available[name]
        if header_windows(part.header).get("dataWindow") != first_window:
            # The writers copy the first part's windows: this channel would be placed elsewhere.
            raise file_error(p, "its part's data window differs from the first part's", name)
        if shape is not None and arr.shape != shape:
            raise file_error(p, f"size {arr.shape} differs from {shape} of the other channels", name)
        shape = arr.shape
        planes.append(checked_plane(p, name, arr).astype(np.float32))
    return np.stack(planes, axis=-1)


def _image_channels(image: np.ndarray, channels: Sequence[str]) -> tuple[np.ndarray, tuple[str, ...]]:
    a = plain("image", image)
    if a.dtype.kind not in "fiub":
        raise TypeError(f"image: expected a numeric array, got dtype {a.dtype}")
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"image: expected shape (H, W) or (H, W, C), got {np.shape(image)}")
    if isinstance(channels, (str, bytes, set, frozenset)):  # a set's order is its hashes'
        raise TypeError("channels: expected a list or tuple of names in the image's order, got "
                        f"{type(channels).__name__}")
    names = tuple(str(c) for c in channels)
    if len(names) != a.shape[2]:
        if tuple(names) == ("R", "G", "B"):
            names = default_channel_names(a.shape[2])
        else:
            raise ValueError(f"channels: {len(names)} names given for {a.shape[2]} channel(s)")
    if len(set(names)) != len(names):
        raise ValueError(f"channels: duplicate names in {names}")
    return a, names


def write_image(path: str | os.PathLike[str], image: np.ndarray, *,
                channels: Sequence[str] = ("R", "G", "B"), header: Mapping[str, Any] | None = None,
                half: bool = False, overwrite: bool = False) -> Path:
    """Write an (H, W, C) or (H, W) image to an EXR file, atomically.

    Parameters
    ----------
    path
        Target file; written beside it first, then renamed into place.
    image
        Finite pixel values (NaN/Inf are refused: a denoised image with them is a bug), within
        the range of the stored type (float32: 3.4e38, half: 65504); values that would be
        stored as Inf are refused rather than clamped.
    channels
        One name per channel; the default ``R, G, B`` adapts to 1 (``Y``) or 4 (``RGBA``)
        channels.
    header
        Extra attributes, e.g. provenance (``awr:c_s``, ``awr:wavelet``...), and the
        ``dataWindow``/``displayWindow`` of the input (:func:`read_windows`).
    half
        Store HALF channels; values beyond +-65504 are refused instead of becoming Inf.
    overwrite
        Replace an existing file.

    Returns
    -------
    Path
        The written file.
    """
    half = _checks.flag("half", half)  # half="no" wrote HALF channels
    a, names = _image_channels(image, channels)
    data = a.astype(np.float64)
    bad = ~np.isfinite(data)
    if bad.any():
        c = int(np.nonzero(bad.any(axis=(0, 1)))[0][0])
        raise ValueError(f"{public_name(path)}: {names[c]}: image has {int(bad[..., c].sum())} pixel(s) "
                         "holding NaN or Inf")
    dtype = np.float16 if half else np.float32
    # Finiteness is checked again after the conversion: values beyond the stored type's range
    # would become Inf in the file.
    with np.errstate(over="ignore"):
        stored = data.astype(dtype)
    over = ~np.isfinite(stored)
    if half:
        # Stored as the half maximum, a value reads back as Blender's clamp of a larger one, which the readers
        # refuse (checked_plane): refused here, so that no file of ours is one we cannot read.
        over |= np.abs(stored) == HALF_MAX
    if over.any():
        c = int(np.nonzero(over.any(axis=(0, 1)))[0][0])
        if half:
            raise ValueError(f"{public_name(path)}: {names[c]}: image has {int(over[..., c].sum())} pixel(s) at or "
                             f"beyond the half-float maximum {HALF_MAX:g}, which would be stored as {HALF_MAX:g} "
                             "(read back as a clamped value) or Inf (write FLOAT channels: half=False)")
        raise ValueError(f"{public_name(path)}: {names[c]}: image has {int(over[..., c].sum())} pixel(s) beyond "
                         f"the float32 range {float(np.finfo(np.float32).max):g}, which would be stored as Inf")
    # The other end: a channel whose every value is below the type's smallest would be stored black
    # (`--half` on means near 1e-40 wrote an all-zero image, exit 0; a red-team pass).
    lost = (data != 0).any(axis=(0, 1)) & ~(stored != 0).any(axis=(0, 1))
    if lost.any():
        c = int(np.nonzero(lost)[0][0])
        tiny = float(np.finfo(dtype).smallest_subnormal)
        raise ValueError(f"{public_name(path)}: {names[c]}: every value of the channel is below the "
                         f"{'half-float' if half else 'float32'} smallest {tiny:.3g} and would be stored as 0; "
                         "scale the image" + (" or write FLOAT channels (half=False)" if half else ""))
    planes = {name: np.ascontiguousarray(stored[..., i]) for i, name in enumerate(names)}
    attrs: dict[str, Any] = {"awr:version": __version__}
    attrs.update(header or {})
    return write_exr(path, planes, attrs, overwrite=overwrite)
