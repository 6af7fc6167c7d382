"""Nothing is written unless everything succeeds: a command that fails, at any step, leaves the
folder exactly as it was (no output, no partial set of outputs, no temporary), and a
multi-output command (``render``: dump, image, preview; ``denoise``: every frame and preview)
writes all its outputs or none.
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("OpenEXR")

from awr_denoise.cli import denoise_cmd, render_cmd  # noqa: E402
from awr_denoise.cli.main import main  # noqa: E402
from awr_denoise.io import write_image, write_sample_buffer  # noqa: E402
from cli_helpers import H, W, awr_command, dump_buffer, one_error_line  # noqa: E402

pytestmark = pytest.mark.exr


def _fails(work, capsys, args, status=2, *needles):
    before = work.state()
    got = main([str(a) for a in args])
    err = capsys.readouterr().err
    assert got == status, err
    line = one_error_line(err, *needles)
    assert work.state() == before, "the folder changed"
    return line


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


# ------------------------------------------------------------------ a later step fails

def _ref_wrong_size(work):
    write_image(work / "small.exr", np.ones((H // 2, W // 2, 3)))
    return ["-r", "small.exr"], "size"


def _ref_inf(work):
    import OpenEXR

    plane = np.ones((H, W), np.float32)
    bad = plane.copy()
    bad[2, 3] = np.inf
    with OpenEXR.File({}, {"R": bad, "G": plane, "B": plane}) as f:
        f.write(str(work / "inf.exr"))
    return ["-r", "inf.exr"], "Inf"


def _ref_other_window(work):
    write_image(work / "crop.exr", np.ones((H, W, 3)), header={"dataWindow": ((10, 20), (10 + W - 1, 20 + H - 1))})
    return ["-r", "crop.exr"], "data window"


def _existing_preview(work):
    (work / "p.png").write_bytes(b"keep me")
    return ["--preview", "p.png"], "already exists"


def _preview_in_missing_folder(work):
    return ["--preview", "nodir/p.png"], "nodir"


def _levels_too_deep(work):
    return ["--levels", "5"], "--levels"


LATER = [_ref_wrong_size, _ref_inf, _ref_other_window, _existing_preview, _preview_in_missing_folder,
         _levels_too_deep]


@pytest.mark.parametrize("make", LATER, ids=lambda f: f.__name__.strip("_"))
def test_denoise_checks_everything_before_writing(work, capsys, monkeypatch, make):
    monkeypatch.chdir(work.root)
    extra, needle = make(work)
    preview = [] if "--preview" in extra else ["--preview", "o.png"]  # a second output to hold back too
    _fails(work, capsys, ["denoise", "d.exr", "-o", "o.exr", "-q", *preview, *extra], 2, needle)


def test_frames_write_nothing_when_a_later_output_exists(work, capsys, monkeypatch):
    monkeypatch.chdir(work.root)
    (work / "out.0002.exr").write_bytes(b"old")
    _fails(work, capsys, ["denoise", "shot.####.exr", "--frames", "1-3", "-o", "out.####.exr", "-q"], 2,
           "out.0002.exr", "already exists")


@pytest.mark.parametrize("workers", [None, "2"])
@pytest.mark.parametrize("bad_frame", [1, 3])
def test_frames_write_all_or_none_when_a_frame_fails(work, capsys, monkeypatch, bad_frame, workers):
    """A corrupt frame found only while the frames run: no image and no preview of any frame."""
    monkeypatch.chdir(work.root)
    _truncate(work / f"shot.{bad_frame:04d}.exr")
    extra = ["--workers", workers] if workers else []
    _fails(work, capsys, ["denoise", "shot.####.exr", "--frames", "1-3", "-o", "out.####.exr",
                          "--preview", "p.####.png", "-q", *extra], 2, f"shot.{bad_frame:04d}.exr")


@pytest.mark.parametrize("failing", ["write_image", "write_preview"])
def test_render_writes_dump_image_and_preview_or_none(work, capsys, monkeypatch, failing):
    """The disk fills up (ENOSPC) at the image or the preview: the dump is not left behind."""
    monkeypatch.chdir(work.root)

    def full(path, *args, **kwargs):
        Path(path).write_bytes(b"partial")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(render_cmd, failing, full)
    _fails(work, capsys, ["render", "--renderer", "synthetic", "edges", "--width", "16", "--height", "12",
                          "--spp", "2", "-o", "r.exr", "-q"], 1, "No space left on device")


def test_denoise_frames_commit_together(work, capsys, monkeypatch):
    """All frames succeed: images and previews appear together, with no temporary left."""
    monkeypatch.chdir(work.root)
    seen = []
    real = denoise_cmd.OutputSet.commit

    def commit(self):
        seen.append(sorted(p.name for p in work.root.iterdir() if not p.name.startswith(".")))
        return real(self)

    monkeypatch.setattr(denoise_cmd.OutputSet, "commit", commit)
    assert main(["denoise", "shot.####.exr", "--frames", "1-3", "-o", "out.####.exr", "--preview", "p.####.png",
                 "-q"]) == 0
    assert not any(n.startswith(("out.", "p.")) for n in seen[0])  # nothing visible before the commit
    names = sorted(p.name for p in work.root.iterdir())
    assert [n for n in names if n.startswith(("out.", "p."))] == [
        "out.0001.exr", "out.0002.exr", "out.0003.exr", "p.0001.png", "p.0002.png", "p.0003.png"]
    assert work.temporaries() == []


def test_values_beyond_float32_are_refused_not_stored_as_inf(work, capsys, monkeypatch):
    monkeypatch.chdir(work.root)
    write_image(work / "big.exr", np.full((4, 4, 3), 3e38))
    write_image(work / "neg.exr", np.full((4, 4, 3), -3e38))
    _fails(work, capsys, ["diff", "big.exr", "-r", "neg.exr", "-o", "dd.exr"], 2, "dd.exr", "float32 range")


def test_a_batch_that_does_not_match_writes_nothing(work, capsys, monkeypatch):
    monkeypatch.chdir(work.root)
    write_sample_buffer(work / "small.exr", dump_buffer(3, (8, 8)))
    _fails(work, capsys, ["merge", "d.exr", "small.exr", "-o", "m.exr"], 2, "small.exr", "does not match", "d.exr")
    _fails(work, capsys, ["merge", "small.exr", "--request", "req.exr", "-o", "m.exr"], 2, "does not match")


# ------------------------------------------------------------------ a full disk

@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KiB tmpfs: writes beyond it fail with ENOSPC (needs root and mount permission)."""
    mount = tmp_path / f"full-{uuid.uuid4().hex[:6]}"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], capture_output=True)


def test_a_full_disk_is_one_line_exit_1_and_no_partial_file(work, capsys, monkeypatch, tiny_disk):
    monkeypatch.chdir(work.root)
    write_sample_buffer(work / "big.exr", dump_buffer(4, (96, 128)))
    status = main(["denoise", "big.exr", "-o", str(tiny_disk / "o.exr"), "--preview", str(tiny_disk / "o.png"), "-q"])
    err = capsys.readouterr().err
    assert status == 1, err
    one_error_line(err, "o.exr", "No space left on device")
    assert os.listdir(tiny_disk) == []  # no image, no preview, no temporary


# ------------------------------------------------------------------ the machine's limits

def _limited(limit: str, value: int):
    resource = pytest.importorskip("resource")  # POSIX

    def apply() -> None:  # in the child, before exec: the limit is the run's, not the test's
        resource.setrlimit(getattr(resource, limit), (value, value))
    return apply


def _run_limited(work, args, limit, value):
    return subprocess.run([*awr_command(), *args], cwd=work.root, capture_output=True, text=True, timeout=120,
                          preexec_fn=_limited(limit, value))


def test_a_file_size_limit_is_named_not_an_io_error(work):
    # ulimit -f: OpenEXR's "File too large" was reported as "Input/output error".
    done = _run_limited(work, ["denoise", "d.exr", "-o", "o.exr", "-q"], "RLIMIT_FSIZE", 4096)
    assert done.returncode == 1, done.stderr
    one_error_line(done.stderr, "o.exr", "File too large")
    assert not (work / "o.exr").exists()
    assert not list(work.root.glob(".awr-*"))


@pytest.mark.parametrize(("limit", "value", "needle"), [("RLIMIT_NOFILE", 6, "Too many open files"),
                                                         # OpenEXR's own open short of one: "Unable to open"
                                                         ("RLIMIT_NOFILE", 7, "Too many open files"),
                                                         ("RLIMIT_FSIZE", 0, "no temporary file")])
def test_a_resource_limit_is_not_a_corrupt_input(work, limit, value, needle):
    # Too few file descriptors, or no usable temporary folder: "truncated or corrupt EXR", exit 2.
    done = _run_limited(work, ["info", "d.exr"], limit, value)
    assert done.returncode == 1, done.stderr
    line = one_error_line(done.stderr, needle)
    assert "corrupt" not in line


def test_an_unreadable_thread_count_is_refused_before_any_work(work, capsys, monkeypatch):
    # ducc0 stops with a C++ assertion on OMP_NUM_THREADS='' (a job script's unset variable), after
    # a render's whole work.
    monkeypatch.chdir(work.root)
    monkeypatch.setenv("OMP_NUM_THREADS", "")
    assert main(["denoise", "d.exr", "-o", "o.exr", "-q"]) == 2
    one_error_line(capsys.readouterr().err, "OMP_NUM_THREADS=''")
    assert main(["render", "--renderer", "synthetic", "edges", "--width", "16", "--height", "16", "-o", "r.exr",
                 "-q"]) == 2
    one_error_line(capsys.readouterr().err, "OMP_NUM_THREADS=''")
    assert not (work / "o.exr").exists() and not (work / "r.exr").exists()
    assert main(["info", "d.exr"]) == 0  # no FFT there
    # plan runs one only for the measured noise model: the other routes plan, refused with it. A
    # fresh process: ducc0 reads the variable once, and this one's transforms are cached and ran.
    env = {k: v for k, v in os.environ.items() if k != "DUCC0_NUM_THREADS"} | {"OMP_NUM_THREADS": ""}
    plan = [*awr_command(), "plan", "d.exr", "--budget", "100", "--strategy", "awr", "-q"]
    done = subprocess.run([*plan, "-o", "q.exr"], cwd=work.root, env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    done = subprocess.run([*plan, "-o", "m.exr", "--noise-model", "reconstruction"], cwd=work.root, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    one_error_line(done.stderr, "OMP_NUM_THREADS=''")
    assert (work / "q.exr").exists() and not (work / "m.exr").exists()
    monkeypatch.setenv("DUCC0_NUM_THREADS", "1")  # ducc0 reads this one first
    assert main(["denoise", "d.exr", "-o", "o.exr", "-q"]) == 0


def test_one_blas_thread_under_an_address_space_limit(work):
    # ulimit -v: scipy's OpenBLAS retried its thread buffers' mmap for ever at import, deaf to SIGTERM.
    code = ("import os\nfrom awr_denoise.cli import main\nmain._one_blas_thread_under_a_memory_limit()\n"
            "print(os.environ.get('OPENBLAS_NUM_THREADS'))\n")
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    for value, expected in ((64 * 2**30, "1"), (None, "None")):
        preexec = _limited("RLIMIT_AS", value) if value else None
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                              preexec_fn=preexec)
        assert done.stdout.strip() == expected, done.stderr


def test_an_address_space_too_small_to_start_is_refused_not_spun_on(work):
    """At 130-150 MB scipy's import spun for ever in OpenBLAS' start-up even with one thread, deaf to SIGTERM (a
    red-team pass); below 192 MiB the command now ends at once, one line, exit 1, and writes nothing."""
    before = work.state()
    done = _run_limited(work, ["denoise", "d.exr", "-o", "o.exr"], "RLIMIT_AS", 140 * 2**20)
    assert done.returncode == 1, done.stderr
    one_error_line(done.stderr, "an address-space limit of 140 MiB (ulimit -v): awr needs at least 192 MiB")
    assert work.state() == before


def test_an_input_in_a_killed_writers_staging_folder_is_refused_and_left_there(work, capsys, monkeypatch):
    """The first write beside the folder removed it as a leftover, the command's own input with it, and then
    blamed the input for having changed (a red-team pass): refused before anything is read or removed."""
    monkeypatch.chdir(work.root)
    staging = work.root / ".awr-0123456789.tmp"
    staging.mkdir()
    (staging / "lock").write_text("another-host")
    os.replace(work / "d.exr", staging / "1.exr")
    old = 1_000_000_000
    os.utime(staging, (old, old))  # long past the age at which a lock-less staging folder counts as left over
    assert main(["denoise", str(staging / "1.exr"), "-o", "o.exr", "-q"]) == 2
    one_error_line(capsys.readouterr().err, "staging folder of an interrupted write", "move the file out first")
    assert sorted(p.name for p in staging.iterdir()) == ["1.exr", "lock"]
    assert not (work / "o.exr").exists()


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs Linux's /dev/full")
def test_a_report_printed_to_a_full_device_names_standard_output(work):
    """'no space left on device' named nothing: the line says it was the report on standard output (a red-team
    pass)."""
    with open("/dev/full", "w") as full:
        done = subprocess.run([*awr_command(), "info", "d.exr"], cwd=work.root, stdout=full, stderr=subprocess.PIPE,
                              text=True, timeout=120)
    assert done.returncode == 1
    one_error_line(done.stderr, "standard output: no space left on device")


def test_an_input_in_a_staging_folder_that_no_write_removes_is_read(work, capsys, monkeypatch):
    """The refusal above is for folders a later write removes (every name a staged one), reached through a link too;
    a folder so named that also holds other files stays, and its files are read (the review of a red-team fix)."""
    monkeypatch.chdir(work.root)
    staging = work.root / ".awr-0123456789.tmp"
    staging.mkdir()
    os.replace(work / "d.exr", staging / "beauty.exr")
    assert main(["info", str(staging / "beauty.exr")]) == 0
    os.replace(staging / "beauty.exr", staging / "1.exr")
    os.symlink(staging / "1.exr", work.root / "link.exr")
    assert main(["info", "link.exr"]) == 2
    one_error_line(capsys.readouterr().err, "staging folder of an interrupted write")
