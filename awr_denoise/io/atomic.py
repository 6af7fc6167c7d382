"""Atomic, all-or-nothing, non-clobbering file writes.

Every writer in :mod:`awr_denoise.io` writes into a temporary file and moves it into place in
one step, so a crash, an interrupt or a bad input never leaves a half-written file, and an
existing file is only replaced when the caller asked for it. :class:`OutputSet` extends this
to several files: a command that writes an image and its preview writes both or neither.

Where temporaries live
----------------------
Temporaries go into a *staging directory* beside the target, ``.awr-<10 hex digits>.tmp``,
under short names (``1.exr``), so a target name of up to the file system's limit (255 bytes)
still works. The staging directory holds a ``lock`` file that the writing process keeps
locked (``flock``) for as long as it runs; the kernel releases the lock when the process
dies, even by SIGKILL. The first write of a process into a directory removes the staging
directories there whose lock is free (their writer is dead) and those without a lock file
older than :data:`STALE_AFTER` seconds; staging directories of live writers (another process
writing into the same folder of a render farm) stay locked and are left alone. The lock file
names its host, and only staging directories of this host are judged by their lock (a
network mount may not share locks between hosts): another host's leftovers wait for a run
on that host. On file systems without working locks nothing is removed. A writability probe
(``.awr-probe-*.tmp``, empty, made and removed by :func:`check_writable`) that a killed process
left goes with its dead writer's staging directory, or, in a target's folder, once older than
:data:`STALE_AFTER`.

Outputs must be regular files, or not exist: a FIFO, a device, a socket or a directory is
refused even with ``overwrite=True`` (writing "over" ``/dev/null`` as root would replace it).
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import shutil
import socket
import stat
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from types import TracebackType

from .. import _checks
from .._signals import COMMIT_CHECKS
from .._signals import deferred as _signals_deferred

try:
    import fcntl
except ImportError:  # pragma: no cover - not on Windows: stale temporaries are then kept
    fcntl = None  # type: ignore[assignment]

__all__ = ["atomic_write", "check_writable", "check_readable", "check_utf8_name", "file_kind", "read_without_waiting",
           "same_file", "OutputSet", "folders_made", "check_creatable",
           "public_name", "standing_for", "remove_stale_temporaries", "STAGING_PREFIX", "STAGING_SUFFIX",
           "STAGING_NAME", "STALE_AFTER",
           "COMMIT_WAIT"]

STAGING_PREFIX = ".awr-"
STAGING_SUFFIX = ".tmp"
"""Staging directories are named ``.awr-<10 hex digits>.tmp``."""

STALE_AFTER = 600.0
"""Seconds after which a staging directory without a lock file counts as abandoned (a writer
creates its lock file within microseconds of the directory)."""

_LOCK = "lock"
# Only what this module creates is ever removed: its staging directories by their exact name, and
# inside one nothing but its lock, temporaries ("1.exr"), their backups ("1.exr.old") and the
# staging directory of a writer that stages again inside it.
STAGING_NAME = re.compile(r"\.awr-[0-9a-f]{10}\.tmp\Z")
"""The name of a staging directory (:data:`STAGING_PREFIX`, 10 hex digits, :data:`STAGING_SUFFIX`)."""
_LOCK_FLAGS = os.O_RDWR | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
# check_writable's probe, named by tempfile.mkstemp (8 random characters between these): a process killed between
# its creation and its removal leaves it, empty, in a staging directory (which must stay removable) or in a
# target's folder.
_PROBE_PREFIX, _PROBE_SUFFIX = ".awr-probe-", ".tmp"
_PROBE = re.escape(_PROBE_PREFIX) + "[a-z0-9_]{8}" + re.escape(_PROBE_SUFFIX)
_PROBE_NAME = re.compile(_PROBE + r"\Z")
_STAGED_NAME = re.compile(rf"(lock|lock\.new|[0-9]+(\.[^/]{{1,16}})?(\.old)?|{_PROBE})\Z", re.DOTALL)
_HOST = socket.gethostname()[:200]  # written into the lock file: whose lock it is
_MAX_SUFFIX = 16  # longer "suffixes" are not file types; the temporary goes without one


# Temporary path -> the target it stands for, while an OutputSet holds it: writers name the
# target in their messages, never the staging directory.
_PUBLIC: dict[str, str] = {}


def public_name(path: str | os.PathLike[str]) -> str:
    """The name to show for ``path``: the target an :class:`OutputSet` temporary stands for."""
    name = os.fspath(path)
    return _PUBLIC.get(name, name)


@contextlib.contextmanager
def standing_for(names: dict[str, str]) -> Iterator[None]:
    """Take ``names`` (temporary path -> the target it stands for) as :class:`OutputSet` temporaries here.

    For a worker process (a process pool's, a Dask worker's) writing into the staging folder of its caller's
    :class:`OutputSet`: its writes go in place, named as their targets, as the caller's own would (the folder
    is otherwise refused as a staging folder, whose files later writes remove). Names this process holds
    already (a thread of the caller's) stay as they are afterwards.
    """
    if not isinstance(names, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in names.items()):
        raise TypeError(f"names: expected a dict of temporary paths (str) to target names (str), got {names!r}")
    added = [tmp for tmp in names if tmp not in _PUBLIC]
    for tmp in added:
        _PUBLIC[tmp] = names[tmp]
    try:
        yield
    finally:
        for tmp in added:
            _PUBLIC.pop(tmp, None)


def file_kind(mode: int) -> str:
    """What a ``st_mode`` is, in words ("regular file", "FIFO", "directory", ...)."""
    for test, name in ((stat.S_ISREG, "regular file"), (stat.S_ISDIR, "directory"), (stat.S_ISFIFO, "FIFO"),
                       (stat.S_ISCHR, "character device"), (stat.S_ISBLK, "block device"),
                       (stat.S_ISSOCK, "socket"), (stat.S_ISLNK, "symbolic link")):
        if test(mode):
            return name
    return "special file"


def _name_max(directory: Path) -> int:
    try:
        return int(os.pathconf(directory, "PC_NAME_MAX"))
    except (AttributeError, OSError, ValueError):
        return 255


def check_utf8_name(path: str | os.PathLike[str]) -> None:
    """Refuse a name that is not UTF-8 (``ValueError``, the bad bytes shown escaped): Linux names
    are bytes, Python holds undecodable ones as surrogates, and neither OpenEXR nor a header can
    take them (OpenEXR's binding refused the name as "use write(path: str)", or the file was
    called corrupt).

    Examples
    --------
    >>> import os
    >>> from awr_denoise.io.atomic import check_utf8_name
    >>> check_utf8_name("ok.exr")
    >>> check_utf8_name(os.fsdecode(b"bad\\xff.exr"))
    Traceback (most recent call last):
    ...
    ValueError: bad\\xff.exr: the name is not valid UTF-8; rename the file
    """
    name = os.fspath(path)
    try:
        if isinstance(name, bytes):
            name.decode("utf-8")
            return
        if name.encode("utf-8") == os.fsencode(name):
            return
    except UnicodeError:
        pass
    try:
        raw = os.fsencode(name)
        shown = raw.decode("utf-8", "backslashreplace")
    except UnicodeError:  # a lone surrogate that no file name's bytes gave
        raw, shown = b"\xff", name.encode("utf-8", "backslashreplace").decode("utf-8")
    try:
        raw.decode("utf-8")
    except UnicodeError:
        raise ValueError(f"{shown}: the name is not valid UTF-8; rename the file") from None
    # UTF-8 bytes that this locale decodes otherwise (Latin-1, or ASCII under LC_ALL=POSIX):
    # OpenEXR opens the name's UTF-8 bytes, another file than the one named.
    raise ValueError(f"{shown}: file names are decoded as {sys.getfilesystemencoding()} here, and OpenEXR opens "
                     "them as UTF-8; run in a UTF-8 locale (LC_ALL=C.UTF-8)") from None


def check_readable(path: str | os.PathLike[str], *, what: str = "input") -> Path:
    """Refuse an input that is missing or not a regular file, without opening it.

    Opening a FIFO for reading blocks until a writer appears; this check never opens.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        It is a directory, FIFO, device or socket, or cannot be examined.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise FileNotFoundError(f"{p}: no such file") from None
    except NotADirectoryError:
        raise FileNotFoundError(f"{p}: no such file (a parent is not a directory)") from None
    except OSError as exc:
        raise ValueError(f"{p}: cannot read this {what}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ValueError(f"{p}: is a {file_kind(st.st_mode)}, not a regular file")
    if not os.access(p, os.R_OK):
        raise ValueError(f"{p}: permission denied (cannot read this {what})")
    # The folder the name lies in, and the one its file lies in (through links): the first write beside a killed
    # writer's staging folder removes it, this input with it, and then found it "changed while it was read" (a
    # red-team pass): refused before anything is read or removed.
    for folder in {os.path.realpath(p.parent), os.path.dirname(os.path.realpath(p))}:
        if STAGING_NAME.match(os.path.basename(folder)) and _holds_only_staged_files(folder):
            raise ValueError(f"{p}: its folder {os.path.basename(folder)} is a staging folder of an interrupted "
                             "write, which the next write beside it removes; move the file out first")
    return p


def read_without_waiting(path: str | os.PathLike[str], *, limit: int) -> bytes:
    """The bytes of a small file, up to ``limit`` + 1 (a caller refuses more), read without ever waiting.

    Opened non-blocking: a regular file reads as always, but one that only looks regular and waits for
    data (``/proc/kmsg``: a configuration file linked there hung the command, a red-team pass), or a FIFO
    put in its place after :func:`check_readable`, raises ``BlockingIOError`` (an ``OSError``).
    """
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    try:
        chunks: list[bytes] = []
        size = 0
        while size <= limit:
            chunk = os.read(fd, min(2**20, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        return b"".join(chunks)
    finally:
        os.close(fd)


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether two paths name one file: the same resolved path, or the same inode (hard links)."""
    pa, pb = Path(a), Path(b)
    try:
        if pa.resolve() == pb.resolve():
            return True
    except (OSError, RuntimeError):
        pass
    try:
        return os.path.samefile(pa, pb)
    except (OSError, ValueError):
        return False


def check_writable(path: str | os.PathLike[str], *, overwrite: bool) -> Path:
    """Refuse early an output that cannot or must not be written.

    Raises
    ------
    FileExistsError
        The target exists and ``overwrite`` is False; the message names the file.
    FileNotFoundError
        Its directory does not exist.
    ValueError
        The target exists and is not a regular file (refused even with ``overwrite``), its
        directory is not writable or accepts no new file (a probe is created and removed there),
        or its name is longer than the file system allows.
    """
    # A string or a number would be read as its truth: overwrite="no" replaced the file (a red-team pass).
    _checks.flag("overwrite", overwrite)
    _checks.file_path("path", path)  # a name (str, or a path of one), not empty
    check_utf8_name(path)
    target = Path(path)
    if os.fspath(target) in _PUBLIC:
        # An OutputSet's temporary, a new name in the staging folder the set made: its target was checked when it was
        # added. What fails now (a full disk, no inode left, the folder moved away) fails the write itself, which
        # names the target (an attack pass: the probe here named the hidden temporary, exit 2, after the work).
        return target
    # A link is written through (_install): the file it names is the one whose folder must take it.
    final = _through_links(target) if os.path.islink(target) else target
    parent = final.parent if str(final.parent) else Path(".")
    name = str(target) if final is target else f"{target} (a link to {final})"  # in every refusal below
    try:
        st = os.stat(target)
    except FileNotFoundError:
        st = None
        if os.path.lexists(target):
            raise ValueError(f"{name}: is a symbolic link to a missing file; remove it or write elsewhere") from None
    except NotADirectoryError:
        raise FileNotFoundError(f"{name}: {parent} is not a directory") from None
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            raise ValueError(f"{name}: file name too long for the file system") from None
        raise ValueError(f"{name}: cannot use as output: {exc.strerror or exc}") from None
    if st is not None:
        if not stat.S_ISREG(st.st_mode):
            raise ValueError(f"{name}: is a {file_kind(st.st_mode)}, not a regular file; "
                             "refusing to write over it")
        if final is not target and not _same_file(final, st):
            # /proc/self/fd/N of a deleted file: its link's text ("x.exr (deleted)") names no file, and
            # writing through it would create one under that name.
            raise ValueError(f"{name}: names a file that is in no folder (deleted, or another mount's); "
                             "write to a file by its path")
        if not overwrite:
            raise FileExistsError(f"{name}: already exists (pass overwrite=True / --overwrite to replace it)")
    if not parent.is_dir():
        raise FileNotFoundError(f"{name}: directory {parent} does not exist")
    folder = os.path.basename(os.path.realpath(parent))
    if STAGING_NAME.match(folder):  # (an OutputSet's own temporaries returned above)
        # The next write into the folder above would remove it as a killed writer's leftover, this output
        # with it, once it is STALE_AFTER old and holds no lock (a red-team pass): not a place for an output.
        raise ValueError(f"{name}: its folder {folder} is named as awr's staging folders, which later writes remove "
                         "as leftovers; write elsewhere")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{name}: directory {parent} is not writable")
    try:  # os.access answers for permissions only: /proc and /sys say yes to root, then refuse every file
        # Signals held while the probe exists (microseconds): a Ctrl-C or SIGTERM between its creation and
        # its removal left it in the user's folder, where an interrupted command must leave nothing (the
        # command line's signal sweep around Mitsuba's load found it, 1 run in 12).
        with _signals_deferred():
            fd, probe = tempfile.mkstemp(prefix=_PROBE_PREFIX, suffix=_PROBE_SUFFIX, dir=parent)
            os.close(fd)
            # Created 0600 less the umask (or as the folder's default ACL says): under umask 0577 no new file was
            # readable by its owner, and the read-back of each EXR written failed every command after its work
            # ("Permission denied", exit 1; an attack pass). os.access answers as the kernel would (root reads it).
            unreadable = None if os.access(probe, os.R_OK) else stat.S_IMODE(os.stat(probe).st_mode)
            try:
                os.unlink(probe)
            except OSError as exc:  # an append-only folder (chattr +a): awr's staging folders could not go either
                raise ValueError(f"{name}: directory {parent} lets no file be removed ({exc.strerror or exc}); the "
                                 f"probe {os.path.basename(probe)} stays there") from None
    except OSError as exc:
        raise ValueError(f"{name}: directory {parent} accepts no new file ({exc.strerror or exc})") from None
    if unreadable is not None:
        raise ValueError(f"{name}: a new file in {parent} gets mode {unreadable:04o} (the umask, or the folder's "
                         "default ACL), which its owner cannot read, and outputs are read back before they are "
                         "committed; set a umask that keeps the owner's read permission (umask 022)")
    limit = _name_max(parent)
    if len(os.fsencode(final.name)) > limit:
        raise ValueError(f"{name}: the file name is {len(os.fsencode(final.name))} bytes, "
                         f"the file system allows {limit}")
    return target


def _same_file(path: Path, st: os.stat_result) -> bool:
    """Whether ``path`` is the file ``st`` describes (both links followed)."""
    try:
        other = os.stat(path)
    except OSError:
        return False
    return (other.st_dev, other.st_ino) == (st.st_dev, st.st_ino)


def _default_acl(folder: Path) -> bool:
    """Whether ``folder`` has a POSIX default ACL (new files there take their permissions from it, not the umask)."""
    try:
        return bool(os.getxattr(folder, "system.posix_acl_default"))
    except (AttributeError, OSError):  # no xattrs on this platform or file system, or no default ACL
        return False


def _new_file_mode(target: Path) -> int:
    """Permissions a plainly created file would get (an existing target keeps its own).

    ``mkstemp``-style files are readable by the owner only; without this a render farm's
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


def _try_lock(fd: int) -> bool | None:
    """Take the exclusive lock without waiting: True taken, False held elsewhere, None unsupported."""
    if fcntl is None:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError:
        return None
    return True


COMMIT_WAIT = 2.0
"""Seconds a commit waits for another process' commit into the same folders before it moves its files anyway
(a commit takes milliseconds); a folder that made it wait that long is not waited for again by this process."""

_DIRECTORY_FLAGS = getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0)
_HELD_ELSEWHERE: set[Path] = set()  # folders locked by something that is not a commit (a wrapper's `flock DIR cmd`)
_HELD_LOCK = threading.Lock()  # commits of several threads (frames written side by side) read and add to it


@contextlib.contextmanager
def _folders_locked(directories: list[Path]) -> Iterator[None]:
    """Hold ``directories`` (their ``flock``) while an :class:`OutputSet` moves its files.

    Two commands writing the same outputs (two ``awr render --overwrite`` of one ``-o``) each moved their
    files all or none, but in turns: one run's dump could end up beside the other's image. Commits into
    the same folder now take turns as wholes, so the last one's files are all there. The locks are taken
    all at once or none is kept: a commit waiting for one folder holds no other, so two commits never
    wait for each other, whatever their folders' order or names (one folder by two paths, a bind mount,
    is locked once). A commit takes milliseconds; one that waited :data:`COMMIT_WAIT` in all (a folder
    something else keeps locked, as ``flock DIR awr ...`` does for the whole command) goes on with the
    locks it can take, as where locks are not supported, and later commits of this process do not wait
    for the others.
    """
    folders: dict[tuple[int, int], tuple[int, Path]] = {}
    try:
        with _HELD_LOCK:
            skipped = set(_HELD_ELSEWHERE)
        for directory in set(directories) - skipped:
            try:
                fd = os.open(directory, os.O_RDONLY | _DIRECTORY_FLAGS)
            except OSError:  # a folder that cannot be opened (no read permission): no lock
                continue
            try:
                st = os.fstat(fd)
            except OSError:
                st = None
            if st is None or (st.st_dev, st.st_ino) in folders:
                os.close(fd)  # the same folder by another path: a second descriptor would wait for the first
            else:
                folders[(st.st_dev, st.st_ino)] = (fd, directory)
        deadline = time.monotonic() + COMMIT_WAIT
        while True:
            busy = [directory for fd, directory in folders.values() if _try_lock(fd) is False]
            if not busy:
                break
            if time.monotonic() >= deadline:
                with _HELD_LOCK:
                    _HELD_ELSEWHERE.update(busy)  # go on with the locks taken in this last pass
                break
            for fd, _ in folders.values():
                _unlock(fd)
            time.sleep((2 + secrets.randbelow(6)) / 1000)  # apart: two commits do not retry in step
        yield
    finally:
        for fd, _ in folders.values():
            os.close(fd)  # the lock goes with its descriptor


def _unlock(fd: int) -> None:
    if fcntl is not None:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)


_SCANNED: set[Path] = set()
_SCANNED_LOCK = threading.Lock()


def remove_stale_temporaries(directory: str | os.PathLike[str]) -> list[Path]:
    """Remove the staging directories in ``directory`` that no live process holds.

    Called by every write (once per directory and process); returns what it removed. Only a
    directory named ``.awr-<10 hex digits>.tmp`` that holds nothing but what a staging directory
    holds is removed (a user's own ``.awr-notes.tmp`` is not ours), and its lock is read only if it
    is a regular file (a FIFO there must not block every write into the folder).
    """
    removed: list[Path] = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    for entry in entries:
        if _PROBE_NAME.match(entry.name):
            _remove_stale_probe(entry, removed)
            continue
        if not STAGING_NAME.match(entry.name):
            continue
        try:
            if not entry.is_dir(follow_symlinks=False) or not _holds_only_staged_files(entry.path):
                continue
            lock = os.path.join(entry.path, _LOCK)
            if not stat.S_ISREG(os.lstat(lock).st_mode):
                continue
            fd = os.open(lock, _LOCK_FLAGS)
        except FileNotFoundError:
            with contextlib.suppress(OSError):
                if time.time() - entry.stat(follow_symlinks=False).st_mtime > STALE_AFTER:
                    shutil.rmtree(entry.path, ignore_errors=True)
                    removed.append(Path(entry.path))
            continue
        except OSError:
            continue
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):  # replaced between the lstat and the open
                continue
            # Another host's lock says nothing here: on a network mount without lock sharing it
            # would look free while its writer runs. Those are left to a run on that host.
            owner = os.read(fd, 256).decode("utf-8", "replace")
            if (not owner or owner == _HOST) and _try_lock(fd):
                shutil.rmtree(entry.path, ignore_errors=True)
                removed.append(Path(entry.path))
        except OSError:
            continue
        finally:
            os.close(fd)
    return removed


def _remove_stale_probe(entry: os.DirEntry, removed: list[Path]) -> None:
    """Remove a writability probe a killed process left: an empty regular file, or an empty folder
    (:func:`check_creatable`'s), of the probe's name, untouched for :data:`STALE_AFTER` (a live one exists for
    microseconds; removing it under its writer would fail that write)."""
    with contextlib.suppress(OSError):
        st = entry.stat(follow_symlinks=False)
        if time.time() - st.st_mtime <= STALE_AFTER:
            return
        if stat.S_ISREG(st.st_mode) and st.st_size == 0:
            os.unlink(entry.path)
            removed.append(Path(entry.path))
        elif stat.S_ISDIR(st.st_mode):
            os.rmdir(entry.path)  # only an empty one: a folder holding anything fails here and stays
            removed.append(Path(entry.path))


def _holds_only_staged_files(path: str, depth: int = 0) -> bool:
    """Whether the directory ``path`` holds only names a staging directory holds (nested once at most),
    and no backup of a replaced file: a process killed between two moves of its commit leaves the
    only copy of a target's previous version there (``1.exr.old``), which is not removed."""
    try:
        with os.scandir(path) as entries:
            for entry in entries:
                if entry.is_dir(follow_symlinks=False):
                    if depth or not STAGING_NAME.match(entry.name) or not _holds_only_staged_files(entry.path, 1):
                        return False
                elif not _STAGED_NAME.match(entry.name) or entry.name.endswith(".old"):
                    return False
    except OSError:
        return False
    return True


class _Staging:
    """A private staging directory beside the targets, locked for as long as this process lives."""

    def __init__(self, directory: Path) -> None:
        key = directory.resolve()
        with _SCANNED_LOCK:
            fresh = key not in _SCANNED
            _SCANNED.add(key)
        if fresh:
            remove_stale_temporaries(directory)
        # Signals held from the folder's creation until it is locked (microseconds): a Ctrl-C in between
        # left a lock-less folder that only a run 10 minutes later removed (as it left a writability probe,
        # check_writable). One that came meanwhile is acted on here, the folder removed first.
        try:
            with _signals_deferred():
                self._create(directory)
        except BaseException:
            if getattr(self, "path", None) is not None:
                self.remove()
            raise

    def _create(self, directory: Path) -> None:
        self._folder_fd = _folder_fd(directory)
        for _ in range(8):
            path = directory / f"{STAGING_PREFIX}{secrets.token_hex(5)}{STAGING_SUFFIX}"
            try:
                os.mkdir(path, 0o700)
                break
            except FileExistsError:
                continue
            except BaseException:
                self._close_folder()
                raise
        else:  # pragma: no cover - 8 collisions of 40 random bits
            self._close_folder()
            raise FileExistsError(f"{directory}: cannot create a staging directory")
        self.path = path
        self._count = 0
        self._fd: int | None = None
        try:
            # The umask took bits off 0o700 (0222 left 0500): the lock and the temporaries could
            # not be made in it, and no later run could list it to clean it up.
            os.chmod(path, 0o700)
        except OSError:
            self.remove()
            raise
        try:
            # Locked under another name first, so a scanner never sees an unlocked "lock".
            fd = os.open(path / (_LOCK + ".new"), os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o600)
            self._fd = fd
            _try_lock(fd)
            os.write(fd, _HOST.encode())
            os.rename(path / (_LOCK + ".new"), path / _LOCK)
        except BaseException:
            self.remove()
            raise

    def new_name(self, target: Path) -> Path:
        self._count += 1
        suffix = target.suffix if len(os.fsencode(target.suffix)) <= _MAX_SUFFIX else ""
        return self.path / f"{self._count}{suffix}"

    def remove(self) -> None:
        if self._folder_fd is not None:
            # Through the output folder's descriptor: renamed while the command ran, the folder kept its staging
            # folder (with its lock) under the new name until a later run there found it stale (an attack pass).
            shutil.rmtree(self.path.name, dir_fd=self._folder_fd, ignore_errors=True)
        else:
            shutil.rmtree(self.path, ignore_errors=True)
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None
        self._close_folder()

    def _close_folder(self) -> None:
        if self._folder_fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._folder_fd)
            self._folder_fd = None


def _folder_fd(directory: Path) -> int | None:
    """A descriptor of ``directory`` to remove a staging folder through wherever the folder is moved; None where
    ``shutil.rmtree`` cannot take one (not POSIX) or no descriptor is left (the path is used then)."""
    if not (shutil.rmtree.avoids_symlink_attacks and hasattr(os, "O_DIRECTORY")):
        return None
    try:
        return os.open(directory, os.O_RDONLY | os.O_DIRECTORY | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None


def _through_links(target: Path) -> Path:
    """The file ``target`` names once its symbolic links are followed: an output that is a link is
    written through it, as a shell's ``>`` writes, and staged beside the file it names (a rename
    replaced the link itself, ``/dev/stdout`` included, and crossed file systems when the link did)."""
    return Path(os.path.realpath(target))


def _install(tmp: Path, target: Path, *, overwrite: bool) -> None:
    """Move a finished temporary to its target, through its links (never replacing one unless ``overwrite``); a
    failure (a busy mount point, another user's file in a sticky folder) names the target, not the temporary."""
    try:
        _move(tmp, target, overwrite=overwrite)
    except OSError as exc:
        if exc.filename is not None and os.fspath(exc.filename) in (os.fspath(tmp), os.fspath(_through_links(target))):
            raise OSError(exc.errno, exc.strerror, public_name(target)) from None
        raise


def _move(tmp: Path, target: Path, *, overwrite: bool) -> None:
    final = _through_links(target)
    if os.path.lexists(final) or not _default_acl(final.parent):
        os.chmod(tmp, _new_file_mode(final))
    # else the folder's default ACL gave the temporary what it gives a plain new file: a chmod to the umask's mode
    # narrowed the ACL's mask, and a collaborator the folder lets write could only read (a red-team pass).
    if overwrite:
        check_writable(target, overwrite=True)  # it may have become a FIFO meanwhile
        os.replace(tmp, final)
        return
    # A hard link fails if the target appeared meanwhile, where a rename would clobber it.
    try:
        os.link(tmp, final)
    except FileExistsError:
        raise FileExistsError(f"{target}: already exists (pass overwrite=True / --overwrite to replace it)") from None
    except OSError:
        if os.path.lexists(final):
            raise FileExistsError(
                f"{target}: already exists (pass overwrite=True / --overwrite to replace it)") from None
        os.replace(tmp, final)  # file systems without hard links


def _size(path: Path) -> int:
    try:
        return os.stat(path).st_size
    except OSError:
        return 0


def _copied(final: Path, backup: Path, target: Path) -> Path:
    """A copy of the file ``final`` at ``backup``, with its owner where the process may set it, to put back if the
    set fails; failing to make one fails the set before anything is moved, naming ``target``."""
    try:
        shutil.copy2(final, backup)
        st = os.stat(final)
        with contextlib.suppress(OSError):
            os.chown(backup, st.st_uid, st.st_gid)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot keep a copy of the file it would replace ({exc.strerror})",
                      public_name(target)) from None
    return backup


def _check_written(tmp: Path, target: Path) -> None:
    try:
        st = os.stat(tmp)
    except FileNotFoundError:
        raise FileNotFoundError(f"{target}: the writer produced no file") from None
    if not stat.S_ISREG(st.st_mode):
        raise ValueError(f"{target}: the writer produced a {file_kind(st.st_mode)}")


def atomic_write(path: str | os.PathLike[str], write: Callable[[str], None], *, overwrite: bool = False) -> Path:
    """Call ``write(tmp_path)`` and move the result to ``path`` in one step.

    Parameters
    ----------
    path
        Final file name. The temporary lives in a staging directory beside it (so the final
        rename never crosses file systems) and keeps its suffix, because some writers pick
        the format from it.
    write
        Writes the complete file to the path it is given.
    overwrite
        Replace an existing ``path`` (a regular file only); when False an existing file is
        never touched.

    Returns
    -------
    Path
        The written path.

    Examples
    --------
    >>> import os, tempfile
    >>> from pathlib import Path
    >>> from awr_denoise.io.atomic import atomic_write
    >>> target = os.path.join(tempfile.mkdtemp(), "note.txt")
    >>> _ = atomic_write(target, lambda tmp: Path(tmp).write_text("done"))
    >>> Path(target).read_text(), os.listdir(os.path.dirname(target))
    ('done', ['note.txt'])
    """
    target = check_writable(path, overwrite=overwrite)
    if os.fspath(target) in _PUBLIC:
        # An OutputSet's temporary, inside its staging directory already: written in place (the
        # set moves it, or removes it with its staging directory), not staged a second time.
        _write_named(write, target, target)
        _check_written(target, target)
        return target
    staging = _staging_for(target, _through_links(target))
    try:
        tmp = staging.new_name(target)
        _write_named(write, tmp, target)
        _check_written(tmp, target)
        for check in COMMIT_CHECKS:  # a signal whose exception was lost: no output after it
            check()
        with _signals_deferred():
            _install(tmp, target, overwrite=overwrite)
    finally:
        staging.remove()
    return target


def _write_named(write: Callable[[str], None], tmp: Path, target: Path) -> None:
    """``write(tmp)``; a full disk or a lost file system is reported naming the target, not the temporary."""
    try:
        write(os.fspath(tmp))
    except FileNotFoundError:  # the staging folder gone: an output not written (exit 1), not a missing input (2)
        raise OSError(errno.EIO, "its folder was moved or removed while it was written", public_name(target)) from None
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), public_name(target)) from None


def _staging_for(target: Path, final: Path) -> _Staging:
    """A staging directory beside ``final``, the file ``target`` names; failing to make one (a full
    disk) names the target."""
    try:
        return _Staging(final.parent)
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), public_name(target)) from None


def check_creatable(folder: str | os.PathLike[str], *, option: str) -> None:
    """Refuse a folder of outputs (``option``'s) that could not be made: its nearest existing parent must be a folder
    that takes a new one. Nothing is left: a probe folder is made there and removed (``os.access`` answers for
    permissions only, and /proc, /sys or a file system without free inodes were found only after the work)."""
    parent = Path(folder)
    while not os.path.lexists(parent):  # a broken link or a loop of links exists as a name, not a folder
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{option}: {folder} cannot be created ({parent} is not a writable folder)")
    try:
        with _signals_deferred():  # an interrupt between the two leaves nothing
            os.rmdir(tempfile.mkdtemp(prefix=_PROBE_PREFIX, suffix=_PROBE_SUFFIX, dir=parent))
    except OSError as exc:
        raise ValueError(f"{option}: {folder} cannot be created ({parent}: {exc.strerror or exc})") from None


@contextlib.contextmanager
def folders_made(*folders: str | os.PathLike[str]) -> Iterator[list[Path]]:
    """Create ``folders`` (and their missing parents) for the outputs of a ``with`` block; when the block
    is left by an exception (a failure, Ctrl-C, SIGTERM) the folders created here are removed again, those
    still empty, deepest first. Put it around the block's :class:`OutputSet`, whose staging folder goes
    first. ``awr demo --out NEW/sub`` and ``awr bench --output-dir NEW`` stopped before their commit left
    the new folders behind, empty (red-team passes).

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from awr_denoise.io.atomic import folders_made
    >>> root = Path(tempfile.mkdtemp())
    >>> try:
    ...     with folders_made(root / "new" / "sub"):
    ...         raise KeyboardInterrupt
    ... except KeyboardInterrupt:
    ...     pass
    >>> (root / "new").exists()
    False
    """
    made: list[Path] = []
    try:
        for folder in map(Path, folders):
            missing = folder
            while not os.path.lexists(missing) and missing != missing.parent:
                made.append(missing)
                missing = missing.parent
            folder.mkdir(parents=True, exist_ok=True)
        for folder in made:  # a umask of 0177 (0600 files) made folders its owner could not enter (a red-team pass)
            mode = stat.S_IMODE(os.stat(folder).st_mode)
            if mode & stat.S_IRWXU != stat.S_IRWXU:  # only then: a chmod clears a setgid folder's bit (the review)
                with contextlib.suppress(OSError):  # not this process's folder ('missing/..'): its writes will say
                    os.chmod(folder, mode | stat.S_IRWXU)
        yield made
    except BaseException:
        for folder in sorted(set(made), key=lambda p: len(p.parts), reverse=True):
            with contextlib.suppress(OSError):
                folder.rmdir()  # only an empty folder: anything put there meanwhile stays
        raise


class OutputSet:
    """Several output files written all or none.

    :meth:`add` checks a target and returns the temporary path to write it to; :meth:`commit`
    moves every temporary into place together. Leaving the ``with`` block without a commit
    (an exception, Ctrl-C) removes every temporary and leaves the targets as they were. A
    failure while moving (a file that appeared meanwhile, a full directory) puts back the
    targets already moved, including the files they replaced.

    Parameters
    ----------
    overwrite
        Replace existing targets (regular files only).

    Examples
    --------
    >>> import os, tempfile
    >>> from pathlib import Path
    >>> from awr_denoise.io.atomic import OutputSet
    >>> d = tempfile.mkdtemp()
    >>> with OutputSet() as outputs:
    ...     Path(outputs.add(os.path.join(d, "a.txt"))).write_text("a")
    ...     Path(outputs.add(os.path.join(d, "b.txt"))).write_text("b")
    ...     written = outputs.commit()
    1
    1
    >>> sorted(os.listdir(d))
    ['a.txt', 'b.txt']
    """

    def __init__(self, *, overwrite: bool = False) -> None:
        self.overwrite = _checks.flag("overwrite", overwrite)
        self._staged: dict[Path, Path] = {}
        self._resolved: dict[Path, Path] = {}
        self._inodes: dict[tuple[int, int], Path] = {}
        self._staging: dict[Path, _Staging] = {}
        self._done = False

    def add(self, path: str | os.PathLike[str]) -> Path:
        """Check ``path`` as an output and return the temporary path to write it to."""
        if self._done:
            raise RuntimeError("OutputSet: already committed or aborted")
        target = check_writable(path, overwrite=self.overwrite)
        resolved = _through_links(target)
        if resolved in self._resolved:
            raise ValueError(f"{target}: the same output is listed twice (also {self._resolved[resolved]})")
        with contextlib.suppress(OSError):
            st = os.stat(target)
            other = self._inodes.setdefault((st.st_dev, st.st_ino), target)
            if other != target:
                raise ValueError(f"{target}: the same file as the output {other}")
        directory = resolved.parent
        if directory not in self._staging:
            self._staging[directory] = _staging_for(target, resolved)
        tmp = self._staging[directory].new_name(target)
        self._staged[target] = tmp
        _PUBLIC[os.fspath(tmp)] = os.fspath(target)
        self._resolved[resolved] = target
        return tmp

    def temporary(self, path: str | os.PathLike[str]) -> Path:
        """The temporary path of an added target (named as it was added)."""
        try:
            return self._staged[Path(path)]
        except (KeyError, TypeError):
            raise ValueError(f"path: {path!r} was not added to this OutputSet") from None

    @property
    def targets(self) -> list[Path]:
        """The targets, in the order they were added."""
        return list(self._staged)

    def commit(self) -> list[Path]:
        """Move every written temporary into place; returns the targets.

        Raises
        ------
        FileNotFoundError
            A target was added but never written (nothing is moved then).
        FileExistsError
            A target appeared meanwhile and ``overwrite`` is False (nothing is left moved).
        """
        if self._done:
            raise RuntimeError("OutputSet: already committed or aborted")
        try:
            for target, tmp in self._staged.items():
                _check_written(tmp, target)
            for check in COMMIT_CHECKS:  # a signal whose exception was lost: no output after it
                check()
            with _folders_locked([_through_links(target).parent for target in self._staged]), _signals_deferred():
                self._move_all()
        finally:
            self.abort()
        return self.targets

    def _move_all(self) -> None:
        for resolved, target in self._resolved.items():
            # A target turned into a link meanwhile (to an input, say): written through it, the file it names now
            # would be replaced, unchecked (a red-team pass).
            if (now := _through_links(target)) != resolved:
                raise ValueError(f"{target}: now names {now}, not the file checked as the output (a link made or "
                                 "changed meanwhile); nothing was written")
        for target in self._staged:
            check_writable(target, overwrite=self.overwrite)
        # A file a target replaces is kept before the first move, so that a failure on a later move can put it back:
        # kept only as the moves went, one that could not be a hard link (no hard links there, or another user's
        # file under protected_hardlinks) was deleted by the rollback (a red-team pass). Hard links first; of the
        # files that cannot be linked, one is moved last, where nothing can fail after it, and the others copied.
        order = list(self._staged.items())
        backups: dict[Path, Path] = {}
        unlinked: list[tuple[Path, Path]] = []
        if self.overwrite and len(order) > 1:
            for target, tmp in order:
                final = _through_links(target)
                if os.path.lexists(final):
                    backup = tmp.with_name(tmp.name + ".old")
                    try:
                        os.link(final, backup)
                        backups[final] = backup
                    except OSError:
                        unlinked.append((target, tmp))
            # The largest goes last, uncopied (a sequence's frames, its previews copied); one that cannot be copied
            # takes its place, and the largest is copied instead.
            unlinked.sort(key=lambda item: _size(_through_links(item[0])), reverse=True)
            last = unlinked[0] if unlinked else None
            for target, tmp in unlinked[1:]:
                try:
                    backups[_through_links(target)] = _copied(_through_links(target), tmp.with_name(tmp.name + ".old"),
                                                              target)
                except OSError:
                    if last is not unlinked[0]:  # two that cannot be kept: one would be lost if a move failed
                        raise
                    biggest, its_tmp = unlinked[0]
                    backups[_through_links(biggest)] = _copied(_through_links(biggest),
                                                               its_tmp.with_name(its_tmp.name + ".old"), biggest)
                    last = (target, tmp)
            if last is not None:
                order = [item for item in order if item[0] != last[0]] + [last]
        moved: list[Path] = []
        try:
            for target, tmp in order:
                _install(tmp, target, overwrite=self.overwrite)
                moved.append(_through_links(target))
        except BaseException:
            for final in reversed(moved):
                with contextlib.suppress(OSError):
                    if final in backups:
                        os.replace(backups[final], final)
                    else:
                        os.unlink(final)
            raise

    def abort(self) -> None:
        """Remove every temporary; the targets stay as they were."""
        self._done = True
        for tmp in self._staged.values():
            _PUBLIC.pop(os.fspath(tmp), None)
        for staging in self._staging.values():
            staging.remove()

    def __enter__(self) -> OutputSet:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.abort()
