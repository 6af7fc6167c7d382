"""Atomic and all-or-nothing writes (awr_denoise/io/atomic.py): staging directories, stale
temporaries, long names, special files, rollback."""

from __future__ import annotations

import os
import signal
import stat
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from awr_denoise.io import atomic
from awr_denoise.io.atomic import (
    STAGING_PREFIX,
    STALE_AFTER,
    OutputSet,
    _signals_deferred,
    _Staging,
    atomic_write,
    check_readable,
    check_writable,
    remove_stale_temporaries,
)


def _listing(root: Path) -> list[str]:
    return sorted(p.name for p in root.iterdir())


def test_a_failing_writer_leaves_nothing(tmp_path):
    def broken(tmp):
        Path(tmp).write_bytes(b"half")
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError):
        atomic_write(tmp_path / "x.bin", broken)
    assert _listing(tmp_path) == []


def test_an_interrupted_writer_leaves_nothing(tmp_path):
    def interrupted(tmp):
        Path(tmp).write_bytes(b"half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(tmp_path / "x.bin", interrupted)
    assert _listing(tmp_path) == []


def test_an_existing_file_is_kept_without_overwrite(tmp_path):
    (tmp_path / "x.bin").write_bytes(b"old")
    with pytest.raises(FileExistsError, match="already exists"):
        atomic_write(tmp_path / "x.bin", lambda tmp: Path(tmp).write_bytes(b"new"))
    assert (tmp_path / "x.bin").read_bytes() == b"old"
    atomic_write(tmp_path / "x.bin", lambda tmp: Path(tmp).write_bytes(b"new"), overwrite=True)
    assert (tmp_path / "x.bin").read_bytes() == b"new"
    assert _listing(tmp_path) == ["x.bin"]


@pytest.mark.parametrize("length", [238, 250, 255])
def test_names_up_to_the_file_system_limit_work(tmp_path, length):
    name = "n" * (length - 4) + ".exr"
    atomic_write(tmp_path / name, lambda tmp: Path(tmp).write_bytes(b"x"))
    with OutputSet() as outputs:
        Path(outputs.add(tmp_path / ("m" * (length - 4) + ".png"))).write_bytes(b"y")
        outputs.commit()
    assert sorted(len(n) for n in _listing(tmp_path)) == [length, length]


def test_a_name_beyond_the_limit_is_refused_up_front(tmp_path):
    with pytest.raises(ValueError, match="too long|256 bytes"):
        check_writable(tmp_path / ("n" * 252 + ".exr"), overwrite=False)


def _fifo(path):
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("kind", ["fifo", "directory", "dangling symlink"])
def test_special_targets_are_refused_even_with_overwrite(tmp_path, kind):
    target = tmp_path / "t.exr"
    if kind == "fifo":
        _fifo(target)
    elif kind == "directory":
        target.mkdir()
    else:
        os.symlink(tmp_path / "missing", target)
    mode = os.lstat(target).st_mode
    with pytest.raises(ValueError, match="not a regular file|symbolic link"):
        atomic_write(target, lambda tmp: Path(tmp).write_bytes(b"x"), overwrite=True)
    assert os.lstat(target).st_mode == mode


def test_a_fifo_input_is_refused_without_opening_it(tmp_path):
    with pytest.raises(ValueError, match="FIFO"):
        check_readable(_fifo(tmp_path / "in.exr"))
    with pytest.raises(FileNotFoundError):
        check_readable(tmp_path / "missing.exr")


def test_an_output_set_writes_all_or_none(tmp_path):
    with pytest.raises(RuntimeError):
        with OutputSet() as outputs:
            Path(outputs.add(tmp_path / "a.txt")).write_text("a")
            Path(outputs.add(tmp_path / "b.txt")).write_text("b")
            raise RuntimeError("the third output failed")
    assert _listing(tmp_path) == []


def test_an_output_set_refuses_a_target_it_was_never_given(tmp_path):
    with OutputSet() as outputs:
        Path(outputs.add(tmp_path / "a.txt")).write_text("a")
        outputs.add(tmp_path / "b.txt")  # never written
        with pytest.raises(FileNotFoundError, match="b.txt"):
            outputs.commit()
    assert _listing(tmp_path) == []


def test_a_failure_while_moving_puts_the_old_files_back(tmp_path):
    for name in ("a.txt", "b.txt"):
        (tmp_path / name).write_text("old " + name)
    with OutputSet(overwrite=True) as outputs:
        Path(outputs.add(tmp_path / "a.txt")).write_text("new a")
        Path(outputs.add(tmp_path / "b.txt")).write_text("new b")
        (tmp_path / "b.txt").unlink()
        (tmp_path / "b.txt").mkdir()  # b becomes a directory between the checks and the move
        with pytest.raises(ValueError, match="not a regular file"):
            outputs.commit()
    assert (tmp_path / "a.txt").read_text() == "old a.txt"
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(STAGING_PREFIX)) == ["a.txt", "b.txt"]
    assert not list(tmp_path.glob(STAGING_PREFIX + "*"))


def _staged_set(tmp_path: Path, writer: str) -> OutputSet:
    outputs = OutputSet(overwrite=True)
    for name in ("image.exr", "dump.exr"):
        Path(outputs.add(tmp_path / name)).write_text(writer)
    return outputs


def test_two_commits_to_the_same_outputs_take_turns_as_wholes(tmp_path, monkeypatch):
    """Two runs of one command to one output (``awr render --overwrite -o``) moved their files in turns:
    one run's dump was left beside the other's image. Commits into one folder now take turns as wholes."""
    first, second = _staged_set(tmp_path, "first"), _staged_set(tmp_path, "second")
    install, other = atomic._install, threading.Thread(target=second.commit)

    def install_then_let_the_other_run(tmp, target, *, overwrite):
        install(tmp, target, overwrite=overwrite)
        if not other.is_alive() and other.ident is None:  # after the first run's first file
            other.start()
            other.join(0.5)  # unlocked, the whole other commit lands here, between the first run's files

    monkeypatch.setattr(atomic, "_install", install_then_let_the_other_run)
    first.commit()
    other.join(30)
    assert {(tmp_path / name).read_text() for name in ("image.exr", "dump.exr")} == {"second"}
    assert not list(tmp_path.glob(STAGING_PREFIX + "*"))


def test_a_folder_locked_by_someone_else_delays_one_commit_but_stops_none(tmp_path, monkeypatch):
    """``flock DIR awr ...`` holds the folder for the whole command: its first commit waits COMMIT_WAIT, later
    ones (the next frames) do not wait again."""
    monkeypatch.setattr(atomic, "COMMIT_WAIT", 0.3)
    monkeypatch.setattr(atomic, "_HELD_ELSEWHERE", set())
    held = _held(tmp_path)
    try:
        start = time.monotonic()
        _staged_set(tmp_path, "first").commit()
        waited = time.monotonic() - start
        start = time.monotonic()
        _staged_set(tmp_path, "second").commit()
        assert waited >= 0.3 > time.monotonic() - start
    finally:
        os.close(held)
    assert (tmp_path / "dump.exr").read_text() == "second"


def _held(folder: Path) -> int:
    """A descriptor holding ``folder``'s flock, as ``flock DIR cmd`` does."""
    fcntl = pytest.importorskip("fcntl", reason="folder locks need flock (POSIX)")
    fd = os.open(folder, os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)
    return fd


def test_a_commit_waits_at_most_commit_wait_whatever_its_folders(tmp_path, monkeypatch):
    """Three folders held elsewhere cost one COMMIT_WAIT, not one each (a red-team review)."""
    monkeypatch.setattr(atomic, "COMMIT_WAIT", 0.5)
    monkeypatch.setattr(atomic, "_HELD_ELSEWHERE", set())
    folders = [tmp_path / name for name in "abc"]
    outputs = OutputSet(overwrite=True)
    for folder in folders:
        folder.mkdir()
        Path(outputs.add(folder / "out.exr")).write_text("run")
    held = [_held(folder) for folder in folders]
    try:
        start = time.monotonic()
        outputs.commit()
        assert 0.5 <= time.monotonic() - start < 1.0  # 1.5 s, one wait per folder, before
    finally:
        for fd in held:
            os.close(fd)


def test_a_commit_waiting_for_one_folder_holds_no_other(tmp_path, monkeypatch):
    """A commit into a and b, b held by a wrapper, kept a locked while it waited: another commit into a
    timed out and took a for a folder held elsewhere, and stopped taking turns there (a red-team review)."""
    monkeypatch.setattr(atomic, "COMMIT_WAIT", 2.0)
    monkeypatch.setattr(atomic, "_HELD_ELSEWHERE", set())
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    waiting = OutputSet(overwrite=True)
    Path(waiting.add(a / "image.exr")).write_text("waiting")
    Path(waiting.add(b / "dump.exr")).write_text("waiting")
    held = _held(b)
    try:
        other = threading.Thread(target=waiting.commit)
        other.start()
        time.sleep(0.2)
        quick = OutputSet(overwrite=True)
        Path(quick.add(a / "frame.exr")).write_text("quick")
        start = time.monotonic()
        quick.commit()
        assert time.monotonic() - start < 1.0 and a not in atomic._HELD_ELSEWHERE  # about 1.8 s before
    finally:
        os.close(held)
        other.join(30)


def test_one_folder_by_two_paths_is_locked_once(tmp_path, monkeypatch):
    """A bind mount names one folder twice: two descriptors of it would wait for each other."""
    pytest.importorskip("fcntl", reason="folder locks need flock (POSIX)")
    monkeypatch.setattr(atomic, "COMMIT_WAIT", 0.5)
    monkeypatch.setattr(atomic, "_HELD_ELSEWHERE", set())
    (tmp_path / "alias").symlink_to(tmp_path, target_is_directory=True)  # resolved by commit(); not here
    start = time.monotonic()
    with atomic._folders_locked([tmp_path, tmp_path / "alias"]):
        pass
    assert time.monotonic() - start < 0.25 and not atomic._HELD_ELSEWHERE


def test_a_target_that_appears_meanwhile_is_not_clobbered(tmp_path):
    with OutputSet() as outputs:
        Path(outputs.add(tmp_path / "a.txt")).write_text("new a")
        Path(outputs.add(tmp_path / "b.txt")).write_text("new b")
        (tmp_path / "b.txt").write_text("someone else's")
        with pytest.raises(FileExistsError):
            outputs.commit()
    assert _listing(tmp_path) == ["b.txt"]
    assert (tmp_path / "b.txt").read_text() == "someone else's"


def test_writers_name_the_target_not_the_temporary(tmp_path):
    from awr_denoise.io import write_image

    with OutputSet() as outputs:
        with pytest.raises(ValueError, match=r"^.*out\.exr: R: .*float32 range"):
            write_image(outputs.add(tmp_path / "out.exr"), np.full((2, 2, 3), 1e39))


def test_stale_staging_directories_are_removed_and_live_ones_kept(tmp_path):
    live = _Staging(tmp_path)  # locked by this process
    dead = tmp_path / f"{STAGING_PREFIX}0123456789.tmp"  # a killed writer's: lock file, no lock
    dead.mkdir()
    (dead / "lock").write_bytes(b"")
    (dead / "1.exr").write_bytes(b"partial")
    young = tmp_path / f"{STAGING_PREFIX}aaaaaaaaaa.tmp"  # being created right now: no lock file yet
    young.mkdir()
    old = tmp_path / f"{STAGING_PREFIX}bbbbbbbbbb.tmp"  # abandoned before its lock file existed
    old.mkdir()
    past = time.time() - STALE_AFTER - 10
    os.utime(old, (past, past))
    other = tmp_path / ".awr-notes.txt"  # not a staging directory
    other.write_text("keep")
    foreign = tmp_path / f"{STAGING_PREFIX}cccccccccc.tmp"  # another host's: its lock means nothing here
    foreign.mkdir()
    (foreign / "lock").write_text("another-host.example")
    removed = remove_stale_temporaries(tmp_path)
    assert sorted(p.name for p in removed) == sorted([dead.name, old.name])
    assert live.path.exists() and young.exists() and other.exists() and foreign.exists()
    live.remove()
    assert not live.path.exists()


def test_a_signal_while_a_probe_or_a_staging_folder_is_made_leaves_nothing(tmp_path, monkeypatch):
    """SIGTERM between the probe's creation and its removal left ``.awr-probe-*.tmp`` in the user's folder
    after an interrupted command (the Mitsuba signal sweep, 1 run in 12): the signal is acted on once the
    probe is gone."""
    class Stop(BaseException):
        pass

    def stop(signum, frame):
        raise Stop

    real = tempfile.mkstemp

    def signalled(*args, **kwargs):
        made = real(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):  # the handler runs at the next bytecodes: here, without the hold
            pass
        return made

    monkeypatch.setattr(atomic.tempfile, "mkstemp", signalled)
    previous = signal.signal(signal.SIGTERM, stop)
    try:
        with pytest.raises(Stop):
            check_writable(tmp_path / "out.exr", overwrite=False)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert os.listdir(tmp_path) == []
    # The same between the staging folder's creation and its lock: a lock-less folder was left.
    monkeypatch.undo()
    chmod = os.chmod

    def chmod_signalled(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):
            pass
        return chmod(*args, **kwargs)

    monkeypatch.setattr(atomic.os, "chmod", chmod_signalled)
    previous = signal.signal(signal.SIGTERM, stop)
    try:
        with pytest.raises(Stop):
            atomic_write(tmp_path / "out.txt", lambda tmp: Path(tmp).write_text("x"))
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert os.listdir(tmp_path) == []


def test_no_output_goes_into_a_folder_named_as_a_staging_folder(tmp_path, monkeypatch):
    """An output written into ``.awr-<10 hex>.tmp/`` (named so by a user, or by an attacker) was removed with its
    folder by a later write beside it, as a leftover, once the folder was STALE_AFTER old (a red-team pass).
    Refused by name, by any route to that folder; an output set's own temporaries are written there as ever."""
    staged = tmp_path / f"{STAGING_PREFIX}abcdefabce.tmp"
    staged.mkdir()
    (tmp_path / "link").symlink_to(staged.name)
    monkeypatch.chdir(staged)
    for path in (staged / "1.exr", tmp_path / "link" / "1.exr", "1.exr"):
        with pytest.raises(ValueError, match=f"its folder {staged.name} is named as awr's staging folders"):
            check_writable(path, overwrite=False)
        with pytest.raises(ValueError, match="staging folders"):
            atomic_write(path, lambda tmp: Path(tmp).write_text("x"))
    assert os.listdir(staged) == []
    with OutputSet() as outputs:
        tmp = outputs.add(tmp_path / "a.txt")
        atomic_write(tmp, lambda path: Path(path).write_text("a"))  # in a staging folder: its own
        outputs.commit()
    assert (tmp_path / "a.txt").read_text() == "a"


@pytest.mark.parametrize("name", ["SIGINT", "SIGTERM", "SIGHUP"])
def test_a_signal_while_files_move_into_place_waits_for_them(name):
    """Ctrl-C, SIGTERM and SIGHUP (a closed terminal) are held while outputs are moved into place,
    then handled once: a set of outputs is never half installed by one of them."""
    if not hasattr(signal, name):
        pytest.skip(f"{name} does not exist on this platform")
    signum = getattr(signal, name)
    seen: list[int] = []
    previous = signal.signal(signum, lambda s, frame: seen.append(s))
    try:
        with _signals_deferred():
            os.kill(os.getpid(), signum)
            os.kill(os.getpid(), signum)
            time.sleep(0.01)  # Python runs handlers between bytecodes: a handler would have run by now
            assert seen == []
        assert seen == [signum]
    finally:
        signal.signal(signum, previous)


def test_a_users_folder_that_looks_like_a_staging_directory_is_kept(tmp_path):
    past = time.time() - STALE_AFTER - 10
    named = tmp_path / f"{STAGING_PREFIX}mydata.tmp"  # not 10 hex digits: never ours
    named.mkdir()
    (named / "important.txt").write_text("precious")
    os.utime(named, (past, past))
    unlocked = tmp_path / f"{STAGING_PREFIX}notes.tmp"  # a "lock" of its own does not make it ours
    unlocked.mkdir()
    (unlocked / "lock").write_bytes(b"")
    exact = tmp_path / f"{STAGING_PREFIX}0123456789.tmp"  # our name, but holding a file we never write
    exact.mkdir()
    (exact / "lock").write_bytes(b"")
    (exact / "mywork.txt").write_text("data")
    old = tmp_path / f"{STAGING_PREFIX}abcdefabcd.tmp"  # our name, no lock, old, a user's file inside
    old.mkdir()
    (old / "notes.txt").write_text("data")
    os.utime(old, (past, past))
    assert remove_stale_temporaries(tmp_path) == []
    assert (named / "important.txt").exists() and (unlocked / "lock").exists()
    assert (exact / "mywork.txt").exists() and (old / "notes.txt").exists()


def test_a_fifo_named_lock_does_not_block_the_scan(tmp_path):
    def expired(signum, frame):
        raise TimeoutError("the scan blocked on the FIFO")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.alarm(20)
    try:
        _scan_past_a_fifo_lock(tmp_path)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _scan_past_a_fifo_lock(tmp_path):
    trap = tmp_path / f"{STAGING_PREFIX}0123456789.tmp"
    trap.mkdir()
    os.mkfifo(trap / "lock")
    linked = tmp_path / f"{STAGING_PREFIX}abcdefabcd.tmp"  # a symbolic link as the lock: not followed
    linked.mkdir()
    (tmp_path / "elsewhere").write_bytes(b"")
    os.symlink(tmp_path / "elsewhere", linked / "lock")
    assert remove_stale_temporaries(tmp_path) == []
    assert trap.exists() and linked.exists()
    atomic_write(tmp_path / "out.txt", lambda tmp: Path(tmp).write_text("done"))  # a write there goes on
    assert (tmp_path / "out.txt").read_text() == "done"


def test_a_staging_directory_of_a_nested_writer_is_still_cleaned(tmp_path):
    dead = tmp_path / f"{STAGING_PREFIX}0123456789.tmp"  # a killed OutputSet writer's temporaries
    (dead / f"{STAGING_PREFIX}abcdefabcd.tmp").mkdir(parents=True)
    (dead / "lock").write_bytes(b"")
    (dead / "1.exr").write_bytes(b"partial")
    assert remove_stale_temporaries(tmp_path) == [dead]
    assert not dead.exists()


def test_a_killed_writers_probe_leaves_its_staging_directory_removable(tmp_path):
    """SIGKILL between ``check_writable``'s probe and its removal, while a temporary was checked inside the
    staging directory: the probe stayed there, the directory no longer held only what a staging directory
    holds, and no later run removed it (seen when `awr denoise --frames` was killed, now and then, on a loaded
    machine: tests/cli/test_interrupts.py's killed run)."""
    dead = tmp_path / f"{STAGING_PREFIX}0123456789.tmp"
    dead.mkdir()
    (dead / "lock").write_bytes(b"")
    (dead / "3.exr").write_bytes(b"partial")
    (dead / ".awr-probe-n3ytb2n0.tmp").write_bytes(b"")
    assert remove_stale_temporaries(tmp_path) == [dead]
    assert not dead.exists()


def test_probes_a_killed_process_left_are_removed_once_stale(tmp_path):
    """An empty probe (a file, or check_creatable's folder: a kill between its two steps left it for good, the
    second review) untouched for STALE_AFTER is a killed process's; a fresh one may be a live writer's (removing it
    would fail that write), and a file of data, a folder holding anything or another name is not a probe of ours."""
    past = time.time() - STALE_AFTER - 10
    stale, fresh, full = (tmp_path / f".awr-probe-{k}.tmp" for k in ("ab_c1234", "zz9_8765", "q1w2e3r4"))
    notes, folder = tmp_path / ".awr-probe-notes.tmp", tmp_path / ".awr-probe-f0lder00.tmp"
    held = tmp_path / ".awr-probe-h0lder00.tmp"
    for path in (stale, fresh, notes):
        path.write_bytes(b"")
    full.write_bytes(b"data")
    folder.mkdir()
    held.mkdir()
    (held / "mine.txt").write_text("x")
    for path in (stale, full, notes, folder, held):
        os.utime(path, (past, past))
    assert sorted(remove_stale_temporaries(tmp_path)) == sorted([stale, folder])
    assert not stale.exists() and fresh.exists() and full.exists() and notes.exists() and not folder.exists()
    assert (held / "mine.txt").exists()


def test_the_probes_check_writable_makes_are_the_names_cleaned_up(tmp_path):
    """The cleanup knows probes by the names ``tempfile.mkstemp`` gives them: checked on the names it makes here."""
    for _ in range(20):
        fd, probe = tempfile.mkstemp(prefix=atomic._PROBE_PREFIX, suffix=atomic._PROBE_SUFFIX, dir=tmp_path)
        os.close(fd)
        assert atomic._PROBE_NAME.match(os.path.basename(probe)), probe


def test_a_backup_of_a_replaced_file_is_never_removed(tmp_path):
    # SIGKILL between two moves of a commit: out.exr new, out.png old, and the old out.exr only as
    # the backup, which the next write into the folder removed.
    dead = tmp_path / f"{STAGING_PREFIX}0123456789.tmp"
    dead.mkdir()
    (dead / "lock").write_bytes(b"")
    (dead / "1.exr.old").write_bytes(b"the only copy")
    assert remove_stale_temporaries(tmp_path) == []
    assert (dead / "1.exr.old").read_bytes() == b"the only copy"


def test_a_umask_without_owner_bits_still_writes(tmp_path):
    # umask 0222 made the staging directory 0500: every write failed, "Permission denied", and a
    # umask of 0777 left a directory no later run could list.
    modes = []

    def write(tmp):
        modes.append(os.stat(Path(tmp).parent).st_mode & 0o777)  # root writes into 0o000 anyway: look
        Path(tmp).write_text("done")

    old = os.umask(0o777)
    try:
        atomic_write(tmp_path / "out.txt", write)
    finally:
        os.umask(old)
    assert modes == [0o700]
    assert (tmp_path / "out.txt").read_text() == "done"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(STAGING_PREFIX)]


def test_an_output_set_temporary_is_written_in_place_not_staged_again(tmp_path):
    seen = []
    with OutputSet() as outputs:
        tmp = outputs.add(tmp_path / "a.txt")
        atomic_write(tmp, lambda path: seen.append(sorted(os.listdir(Path(path).parent))) or Path(path).write_text("a"))
        outputs.commit()
    assert seen == [["lock"]]  # no staging directory inside the staging directory
    assert _listing(tmp_path) == ["a.txt"]


def test_a_staged_temporary_that_cannot_be_written_names_its_target_as_an_output_failure(tmp_path, monkeypatch):
    """Once an OutputSet has made its staging folder, a folder that takes no new file (no inode left) or is gone (the
    output folder renamed while the command ran) fails the write itself: an OSError (exit 1) naming the target. The
    check before the write named the hidden temporary and raised ValueError (exit 2), after the work (an attack
    pass). The renamed folder is left as it was."""
    from awr_denoise.io.exr import write_exr

    plane = {"Y": np.ones((4, 4), np.float32)}
    (tmp_path / "sub").mkdir()
    with OutputSet() as outputs:
        tmp = outputs.add(tmp_path / "sub" / "out.exr")

        def no_inode(*args, **kwargs):
            raise OSError(28, "No space left on device")

        with monkeypatch.context() as m:  # the probe of a folder that took no new file: none for a staged temporary
            m.setattr(tempfile, "mkstemp", no_inode)
            assert check_writable(tmp, overwrite=False) == tmp
        os.rename(tmp_path / "sub", tmp_path / "moved")
        (tmp_path / "sub").mkdir()
        text = (lambda: atomic_write(tmp, lambda path: Path(path).write_text("a")))
        for write in (lambda: write_exr(tmp, plane), text):
            with pytest.raises(OSError) as info:
                write()
            assert type(info.value) is OSError and not isinstance(info.value, (ValueError, FileNotFoundError))
            assert info.value.filename == str(tmp_path / "sub" / "out.exr") and STAGING_PREFIX not in str(info.value)
            assert "moved or removed" in str(info.value)
    assert _listing(tmp_path / "sub") == []
    # Its staging folder and lock went too, under the folder's new name; it stayed until a later run found it stale.
    assert _listing(tmp_path / "moved") == []


def test_a_umask_that_leaves_new_files_unreadable_by_their_owner_is_refused_before_any_work(tmp_path):
    """Under umask 0577 (0777) a new file is not readable by its owner, and the read-back of every EXR written failed
    each command after its work ("Permission denied", exit 1; an attack pass). Refused by the check, naming the
    mode; 0377 writes. Run as the kernel checks a user: as root, without the capabilities that bypass permissions."""
    import shutil
    import subprocess
    import sys

    prefix = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("root without setpriv: permissions do not apply to root")
        caps = "-dac_override,-dac_read_search,-fowner"
        prefix = ["setpriv", f"--inh-caps={caps}", f"--bounding-set={caps}"]
    code = ("import os, sys\n"
            "from awr_denoise.io.atomic import OutputSet, check_writable\n"
            "from awr_denoise.io.exr import write_exr\n"
            "import numpy as np\n"
            "os.umask(int(sys.argv[1], 8))\n"
            "try:\n"
            "    check_writable(sys.argv[2], overwrite=False)\n"
            "except ValueError as exc:\n"
            "    print('refused:', exc)\n"
            "else:\n"
            "    write_exr(sys.argv[2], {'Y': np.ones((2, 2), np.float32)})\n"
            "    print('written')\n")
    for mask, expected in (("0577", "mode 0200"), ("0777", "mode 0000"), ("0377", "written")):
        out = tmp_path / f"o{mask}.exr"
        run = subprocess.run([*prefix, sys.executable, "-c", code, mask, str(out)], capture_output=True, text=True,
                             timeout=120)
        assert run.returncode == 0 and expected in run.stdout, (mask, run.stdout, run.stderr)
        if expected == "written":
            assert out.is_file()
        else:
            assert "owner cannot read" in run.stdout and "umask 022" in run.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o0377.exr"]  # the probes gone


def test_no_room_for_the_staging_directory_names_the_target(tmp_path, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "mkdir", full)
    with pytest.raises(OSError, match="out.txt") as info:
        atomic_write(tmp_path / "out.txt", lambda tmp: Path(tmp).write_text("x"))
    assert STAGING_PREFIX not in str(info.value)
    with OutputSet() as outputs, pytest.raises(OSError, match="b.txt"):
        outputs.add(tmp_path / "b.txt")


@pytest.mark.parametrize("how", ["atomic_write", "OutputSet"])
def test_an_output_that_is_a_symbolic_link_is_written_through_it(tmp_path, how):
    """A rename replaced the link itself with a regular file, the file it named left as it was (as
    root, `-o /dev/stdout --overwrite` replaced the machine's /dev/stdout; a red-team pass). Written
    through, as a shell's `>` writes: the link stays, the file it names is replaced."""
    (tmp_path / "real").mkdir()
    real, link = tmp_path / "real" / "out.txt", tmp_path / "link.txt"
    real.write_text("old")
    os.chmod(real, 0o640)
    link.symlink_to(real)
    if how == "atomic_write":
        with pytest.raises(FileExistsError, match=r"link.txt \(a link to .*out.txt\): already exists"):
            atomic_write(link, lambda tmp: Path(tmp).write_text("new"))
        atomic_write(link, lambda tmp: Path(tmp).write_text("new"), overwrite=True)
    else:
        with OutputSet(overwrite=True) as outputs:
            Path(outputs.add(link)).write_text("new")
            outputs.commit()
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert real.read_text() == "new" and (real.stat().st_mode & 0o777) == 0o640
    assert _listing(tmp_path) == ["link.txt", "real"] and _listing(tmp_path / "real") == ["out.txt"]


def test_a_link_into_another_file_system_is_staged_beside_the_file_it_names(tmp_path):
    """Staged beside the link, the temporary could not be renamed onto the file it names on another
    file system: "Invalid cross-device link" naming the hidden temporary, after all the work."""
    other = Path("/dev/shm")
    if not other.is_dir() or not os.access(other, os.W_OK) or other.stat().st_dev == tmp_path.stat().st_dev:
        pytest.skip("no writable /dev/shm on another file system than the temporary folder")
    real = other / f"awr-test-{os.getpid()}-{tmp_path.name}.txt"
    try:
        real.write_text("old")
        (tmp_path / "link.txt").symlink_to(real)
        with OutputSet(overwrite=True) as outputs:
            Path(outputs.add(tmp_path / "link.txt")).write_text("new")
            Path(outputs.add(tmp_path / "plain.txt")).write_text("plain")
            outputs.commit()
        assert real.read_text() == "new" and (tmp_path / "plain.txt").read_text() == "plain"
        assert not list(other.glob(STAGING_PREFIX + "*")) and not list(tmp_path.glob(STAGING_PREFIX + "*"))
    finally:
        real.unlink(missing_ok=True)


@pytest.mark.skipif(not os.path.isfile("/proc/version"),
                    reason="needs /proc/version, a file in a folder that takes no new file")
def test_a_link_to_a_deleted_file_is_refused_not_written_under_its_text(tmp_path):
    """``-o /proc/self/fd/N`` of a deleted file: its link's text is "gone.exr (deleted)", and the output was
    written as a new file under that name, exit 0 (a red-team pass)."""
    with open(tmp_path / "gone.exr", "ab") as held:
        os.unlink(tmp_path / "gone.exr")
        target = Path(f"/proc/self/fd/{held.fileno()}")
        for overwrite in (True, False):
            with pytest.raises(ValueError, match=r"\(deleted\)\): names a file that is in no folder"):
                check_writable(target, overwrite=overwrite)
        with OutputSet(overwrite=True) as outputs, pytest.raises(ValueError, match="in no folder"):
            outputs.add(target)
    assert _listing(tmp_path) == []


def test_a_link_is_checked_in_the_folder_of_the_file_it_names(tmp_path):
    """The folder checks ran in the link's folder: a link to a file in a folder that takes no new file
    passed them, and the command failed after all its work (a review)."""
    (tmp_path / "link").symlink_to("/proc/version")
    with pytest.raises(ValueError, match=r"link \(a link to /proc/version\): directory /proc accepts no new file"):
        check_writable(tmp_path / "link", overwrite=True)
    with OutputSet(overwrite=True) as outputs, pytest.raises(ValueError, match="accepts no new file"):
        outputs.add(tmp_path / "link")
    assert _listing(tmp_path) == ["link"]


def test_read_without_waiting_reads_a_file_and_never_waits_on_one_that_would_block(tmp_path):
    """A scheduler or scene file linked to ``/proc/kmsg`` (a "regular file" that waits for data) hung the
    command (a red-team pass); a FIFO put in a file's place after it was checked would have too."""
    from awr_denoise.io.atomic import read_without_waiting

    (tmp_path / "a.json").write_bytes(b"x" * 10)
    assert read_without_waiting(tmp_path / "a.json", limit=100) == b"x" * 10
    assert read_without_waiting(tmp_path / "a.json", limit=4) == b"x" * 5   # the caller sees it is larger
    os.mkfifo(tmp_path / "fifo")
    assert read_without_waiting(tmp_path / "fifo", limit=100) == b""       # no writer: nothing, at once


def test_standing_for_takes_another_processes_temporaries_as_its_own_while_it_lasts(tmp_path):
    """A worker process writing into its caller's staging folder: written in place, named as the target;
    names this process held already stay held afterwards."""
    with atomic.OutputSet() as outputs:
        mine = outputs.add(tmp_path / "mine.exr")
        theirs = mine.with_name("frame-of-another-process.exr")  # in the same staging folder
        with pytest.raises(ValueError, match="named as awr's staging folders"):
            atomic.check_writable(theirs, overwrite=False)
        with atomic.standing_for({os.fspath(theirs): "out.exr", os.fspath(mine): "mine.exr"}):
            assert atomic.public_name(theirs) == "out.exr" and atomic.public_name(mine) == str(tmp_path / "mine.exr")
            atomic.atomic_write(theirs, lambda tmp: Path(tmp).write_text("frame"))
        assert theirs.read_text() == "frame" and sorted(p.name for p in theirs.parent.iterdir()) == [
            theirs.name, "lock"]  # in place: no staging folder inside the staging folder
        assert atomic.public_name(theirs) == os.fspath(theirs) and atomic.public_name(mine) != os.fspath(mine)
        mine.write_text("mine")
        outputs.commit()
    assert (tmp_path / "mine.exr").read_text() == "mine"


def test_flags_and_names_of_the_writers_are_checked(tmp_path):
    """``overwrite="no"`` and ``OutputSet(overwrite="False")`` replaced the file, ``half="no"`` wrote HALF
    channels (a red-team pass): a flag is True or False; a name is a str; a target not added is named."""
    from awr_denoise.io import write_image

    keep = tmp_path / "keep.exr"
    keep.write_bytes(b"precious")
    for call in (lambda: write_image(keep, np.ones((2, 2, 3)), overwrite="no"),
                 lambda: atomic.OutputSet(overwrite="False"),
                 lambda: atomic.check_writable(keep, overwrite=1)):
        with pytest.raises(TypeError, match="overwrite: expected True or False"):
            call()
    with pytest.raises(TypeError, match="half: expected True or False"):
        write_image(tmp_path / "h.exr", np.ones((2, 2, 3)), half="no")
    with pytest.raises(TypeError, match="path: expected a file name, got NoneType"):
        atomic.check_writable(None, overwrite=False)
    with pytest.raises(TypeError, match="names: expected a dict"):
        with atomic.standing_for({Path("x"): "y"}):
            pass
    with atomic.OutputSet() as outputs:
        outputs.add(tmp_path / "a.exr")
        with pytest.raises(ValueError, match="was not added"):
            outputs.temporary(tmp_path / "never.exr")
    assert keep.read_bytes() == b"precious" and not (tmp_path / "h.exr").exists()


@pytest.mark.parametrize("linkable", [True, False])
def test_a_failed_set_puts_back_every_file_it_replaced(tmp_path, monkeypatch, linkable):
    """The second target's move fails (a busy mount point, another user's file in a sticky folder). The first
    target, replaced already, is put back as it was, also where its backup could not be a hard link: it was
    deleted (a red-team pass). The error names the target, not the staging temporary."""
    first, second = tmp_path / "a.exr", tmp_path / "b.png"
    first.write_text("previous a")
    second.write_text("previous b")
    real_replace = os.replace
    if not linkable:
        def no_links(src, dst, *args, **kwargs):
            raise PermissionError(1, "Operation not permitted", os.fspath(src))
        monkeypatch.setattr(os, "link", no_links)

    def busy(src, dst, *args, **kwargs):
        if os.fspath(dst) == os.fspath(second):
            raise OSError(16, "Device or resource busy", os.fspath(src))
        return real_replace(src, dst, *args, **kwargs)
    monkeypatch.setattr(os, "replace", busy)
    with OutputSet(overwrite=True) as outputs:
        outputs.add(first).write_text("new a")
        outputs.add(second).write_text("new b")
        with pytest.raises(OSError, match="Device or resource busy") as raised:
            outputs.commit()
    assert raised.value.filename == str(second)
    assert first.read_text() == "previous a" and second.read_text() == "previous b"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr", "b.png"]


def test_a_folder_of_outputs_that_cannot_be_made_is_refused_before_the_work(tmp_path):
    """os.access says yes to root under /proc and /sys, and nothing of inodes: awr demo --out found out after both
    renders (a red-team pass). A probe folder is made and removed; nothing is left."""
    from awr_denoise.io.atomic import check_creatable

    check_creatable(tmp_path / "new" / "sub", option="--out")
    assert _listing(tmp_path) == []
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="--out: .* cannot be created"):
        check_creatable(tmp_path / "file" / "new", option="--out")
    if os.path.isdir("/proc/self"):
        with pytest.raises(ValueError, match="--out: /proc/awr-new cannot be created"):
            check_creatable("/proc/awr-new", option="--out")


def test_folders_made_under_a_tight_umask_can_be_entered(tmp_path):
    """umask 0177 (for 0600 files) made a 0600 folder its owner could not enter: refused after the work."""
    old = os.umask(0o177)
    try:
        with atomic.folders_made(tmp_path / "a" / "b"):
            (tmp_path / "a" / "b" / "out.txt").write_text("x")
    finally:
        os.umask(old)
    assert (tmp_path / "a" / "b" / "out.txt").read_text() == "x"
    assert stat.S_IMODE(os.stat(tmp_path / "a").st_mode) & 0o700 == 0o700


def test_a_folder_that_lets_no_file_be_removed_is_named_so(tmp_path, monkeypatch):
    """An append-only folder (chattr +a) took the probe and kept it: "accepts no new file" said the opposite of what
    happened (a red-team pass)."""
    real_unlink = os.unlink

    def append_only(path, *args, **kwargs):
        if os.path.basename(os.fspath(path)).startswith(".awr-probe-"):
            raise PermissionError(1, "Operation not permitted", os.fspath(path))
        return real_unlink(path, *args, **kwargs)
    monkeypatch.setattr(os, "unlink", append_only)
    with pytest.raises(ValueError, match="lets no file be removed .Operation not permitted.; the probe .awr-probe-"):
        check_writable(tmp_path / "out.exr", overwrite=False)


def test_an_output_in_a_folder_with_a_default_acl_gets_what_a_plain_new_file_gets(tmp_path):
    """The chmod to the umask's mode narrowed the ACL's mask: a collaborator the folder lets write got a file they
    could only read (a red-team pass)."""
    import struct

    def entries(raw):
        return sorted(struct.unpack("<HHI", raw[4 + 8 * i:12 + 8 * i]) for i in range((len(raw) - 4) // 8))
    folder = tmp_path / "shared"
    folder.mkdir()
    whole = 0xFFFFFFFF  # the owner's, the group's, the mask's and others' entries name no id
    default = struct.pack("<I", 2) + b"".join(struct.pack("<HHI", *entry) for entry in (
        (0x01, 7, whole), (0x02, 6, 1000), (0x04, 5, whole), (0x10, 7, whole), (0x20, 5, whole)))
    try:
        os.setxattr(folder, "system.posix_acl_default", default)
    except (AttributeError, OSError) as exc:
        pytest.skip(f"no POSIX ACLs here: {exc}")
    (folder / "plain.txt").write_text("plain")
    atomic_write(folder / "out.txt", lambda tmp: Path(tmp).write_text("out"))
    plain, out = (os.getxattr(folder / name, "system.posix_acl_access") for name in ("plain.txt", "out.txt"))
    assert entries(out) == entries(plain)
    assert stat.S_IMODE(os.stat(folder / "out.txt").st_mode) == stat.S_IMODE(os.stat(folder / "plain.txt").st_mode)


@pytest.mark.parametrize("names", [("a.exr",), ("a.exr", "b.png"), ("b.png", "a.exr")])
def test_a_replaced_file_that_can_be_neither_linked_nor_read_is_moved_last(tmp_path, monkeypatch, names):
    """Copying every replaced file first made an overwrite fail where the old file could be replaced but not read
    (another user's 0600 file in the user's folder, no hard links): it worked before (the review of a red-team
    fix). Only a file that must be put back is kept, and one that cannot be is moved last, after which nothing
    fails."""
    for name in names:
        (tmp_path / name).write_text("previous")

    def no_links(src, dst, *args, **kwargs):
        raise PermissionError(1, "Operation not permitted", os.fspath(src))

    def unreadable(src, dst, *args, **kwargs):
        if os.path.basename(os.fspath(src)) == "a.exr":
            raise PermissionError(13, "Permission denied", os.fspath(src))
        return real_copy(src, dst, *args, **kwargs)
    real_copy = atomic.shutil.copy2
    monkeypatch.setattr(os, "link", no_links)
    monkeypatch.setattr(atomic.shutil, "copy2", unreadable)
    with OutputSet(overwrite=True) as outputs:
        for name in names:
            outputs.add(tmp_path / name).write_text("new")
        outputs.commit()
    assert all((tmp_path / name).read_text() == "new" for name in names)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names)


def test_two_replaced_files_that_cannot_be_kept_fail_the_set_before_any_move(tmp_path, monkeypatch):
    for name in ("a.exr", "c.exr"):
        (tmp_path / name).write_text("previous")

    def no_links(src, dst, *args, **kwargs):
        raise PermissionError(1, "Operation not permitted", os.fspath(src))

    def unreadable(src, dst, *args, **kwargs):
        raise PermissionError(13, "Permission denied", os.fspath(src))
    monkeypatch.setattr(os, "link", no_links)
    monkeypatch.setattr(atomic.shutil, "copy2", unreadable)
    with OutputSet(overwrite=True) as outputs:
        for name in ("a.exr", "c.exr"):
            outputs.add(tmp_path / name).write_text("new")
        with pytest.raises(PermissionError, match="cannot keep a copy of the file it would replace"):
            outputs.commit()
    assert [(tmp_path / name).read_text() for name in ("a.exr", "c.exr")] == ["previous", "previous"]


def test_a_link_inside_a_staging_folder_is_refused_as_an_input(tmp_path):
    """The refusal looked at the folder of the link's file only: a link inside a removable staging folder got past,
    and the next write removed it (the second review)."""
    (tmp_path / "real.exr").write_bytes(b"x")
    staging = tmp_path / ".awr-0123456789.tmp"
    staging.mkdir()
    (staging / "1.exr").symlink_to(tmp_path / "real.exr")
    with pytest.raises(ValueError, match="staging folder of an interrupted write"):
        check_readable(staging / "1.exr")
    assert check_readable(tmp_path / "real.exr") == tmp_path / "real.exr"


def test_folders_made_are_chmod_ed_only_where_their_owner_lacks_a_right(tmp_path, monkeypatch):
    """A chmod of every new folder cleared a setgid project folder's bit from the folders made in it (files there
    then took the user's group), and failed on 'missing/..' in someone else's folder (the second review)."""
    calls = []
    real_chmod = os.chmod
    monkeypatch.setattr(os, "chmod", lambda path, mode, *a, **k: (calls.append(path), real_chmod(path, mode, *a, **k)))
    old = os.umask(0o022)
    try:
        with atomic.folders_made(tmp_path / "a" / "b"):
            pass
    finally:
        os.umask(old)
    assert calls == [] and (tmp_path / "a" / "b").is_dir()


def test_where_nothing_links_only_the_smaller_replaced_files_are_copied(tmp_path, monkeypatch):
    """Every replaced file but the last added was copied where hard links fail (a sequence's frames among them):
    the largest is moved last, uncopied (the second review)."""
    sizes = {"frame.exr": 100_000, "small.png": 10, "other.png": 20}
    for name, size in sizes.items():
        (tmp_path / name).write_bytes(b"x" * size)

    def no_links(src, dst, *args, **kwargs):
        raise PermissionError(1, "Operation not permitted", os.fspath(src))
    copied = []
    real_copy = atomic.shutil.copy2
    monkeypatch.setattr(os, "link", no_links)
    monkeypatch.setattr(atomic.shutil, "copy2", lambda src, dst: (copied.append(os.path.basename(src)),
                                                                 real_copy(src, dst))[1])
    with OutputSet(overwrite=True) as outputs:
        for name in sizes:
            outputs.add(tmp_path / name).write_text("new")
        outputs.commit()
    assert sorted(copied) == ["other.png", "small.png"]
    assert all((tmp_path / name).read_text() == "new" for name in sizes)


@pytest.mark.parametrize("existed", [True, False])
def test_a_target_turned_into_a_link_meanwhile_is_not_written_through(tmp_path, existed):
    """An output replaced by a link to an input while the outputs were made (``--overwrite``) was written through
    the link: the input held the output, exit 0. The commit now finds the target names another file and writes
    nothing."""
    source = tmp_path / "in.exr"
    source.write_text("input")
    target = tmp_path / "o.exr"
    if existed:
        target.write_text("old output")
    with OutputSet(overwrite=True) as outputs:
        Path(outputs.add(target)).write_text("new output")
        target.unlink(missing_ok=True)
        target.symlink_to(source)
        with pytest.raises(ValueError, match=r"o\.exr: now names .*in\.exr, not the file checked as the output"):
            outputs.commit()
    assert source.read_text() == "input"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.exr", "o.exr"]
