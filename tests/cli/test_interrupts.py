"""Interrupts with real signals on a real ``awr`` process (cli/interrupts.py, io/atomic.py).

* Ctrl-C, SIGTERM or SIGHUP while the heavy imports load: exit 130 / 143 / 129, one line, no traceback.
* Ctrl-C, SIGTERM or SIGHUP (a closed terminal) once outputs are being written: no output at all,
  no temporary.
* SIGKILL leaves a staging directory; the next run into that folder removes it, while the
  staging directory of a live writer stays.
* ``awr info --json x | head``: the reader goes away, ``awr`` exits 141 without a word.

The process is started the way a terminal starts it (SIGINT not ignored) through the installed
console script, and signals are sent at moments read from the process itself (the libraries
mapped into it, the files it has written), not after guessed delays.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("OpenEXR")

from awr_denoise import SampleBuffer  # noqa: E402
from awr_denoise.io import read_image, write_sample_buffer  # noqa: E402
from awr_denoise.io.atomic import STAGING_PREFIX  # noqa: E402
from cli_helpers import H, W, awr_command, one_error_line, run_awr  # noqa: E402

pytestmark = [pytest.mark.exr,
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/PID/maps")]


def _start(args, cwd: Path, preexec_fn, **kwargs) -> subprocess.Popen:
    """The command as from a terminal: ``preexec_fn`` is the ``signals_at_default`` fixture (tests/conftest.py)."""
    return subprocess.Popen([*awr_command(), *map(str, args)], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=preexec_fn, **kwargs)


def _wait_for(proc: subprocess.Popen, ready, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc.poll() is not None:
            pytest.fail(f"awr ended (status {proc.returncode}) before the moment to signal it: "
                        f"{proc.stderr.read() if proc.stderr else ''}")
        if ready():
            return
        time.sleep(0.001)
    proc.kill()
    pytest.fail("the moment to signal never came")


def _mapped(proc: subprocess.Popen, marker: str) -> bool:
    try:
        return marker in Path(f"/proc/{proc.pid}/maps").read_text()
    except OSError:
        return False


def _finish(proc: subprocess.Popen) -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=120)
    return proc.returncode, out, err


IMPORT_MARKERS = [("_multiarray_umath", signal.SIGINT), ("scipy", signal.SIGTERM), ("scipy", signal.SIGHUP),
                  pytest.param("pywt", signal.SIGINT, marks=pytest.mark.slow),
                  pytest.param("_multiarray_umath", signal.SIGTERM, marks=pytest.mark.slow)]


@pytest.mark.parametrize(("marker", "signum"), IMPORT_MARKERS)
def test_a_signal_while_imports_load_is_one_line(work, marker, signum, signals_at_default):
    proc = _start(["info", "d.exr"], work.root, signals_at_default)
    _wait_for(proc, lambda: _mapped(proc, marker))
    proc.send_signal(signum)
    status, out, err = _finish(proc)
    expected = {signal.SIGINT: (130, "awr: interrupted"), signal.SIGTERM: (143, "awr: terminated"),
                signal.SIGHUP: (129, "awr: hung up")}[signum]
    assert (status, err.strip()) == expected, err
    assert out == ""


@pytest.fixture
def frames(work):
    """Eight 384x384 frames: long enough to signal between the first written output and the last."""
    rng = np.random.default_rng(7)
    for i in range(1, 9):
        mean = np.abs(0.5 + 0.1 * rng.standard_normal((384, 384, 3)))
        write_sample_buffer(work / f"seq.{i:04d}.exr",
                            SampleBuffer.from_moments(np.full((384, 384), 8), mean, np.full((384, 384, 3), 0.04)))
    return ["denoise", "seq.####.exr", "--frames", "1-8", "-o", "out.####.exr", "--preview", "p.####.png", "-q"]


def _staged(root: Path) -> bool:
    """An output of the run is complete in its staging directory (not yet moved into place)."""
    return any(p.is_file() for d in root.glob(STAGING_PREFIX + "*") for p in d.glob("[0-9]*.*"))


def _outputs(root: Path) -> list[str]:
    return sorted(p.name for p in root.iterdir() if p.name.startswith(("out.", "p.", STAGING_PREFIX)))


@pytest.mark.parametrize(("signum", "status", "line"), [(signal.SIGINT, 130, "awr: interrupted"),
                                                        (signal.SIGTERM, 143, "awr: terminated"),
                                                        (signal.SIGHUP, 129, "awr: hung up"),
                                                        # a scheduler's warning or a CPU limit: killed
                                                        # without a word, the staging folder left
                                                        (signal.SIGUSR1, 138, "awr: terminated by SIGUSR1"),
                                                        (signal.SIGXCPU, 152, "awr: terminated by SIGXCPU"),
                                                        (signal.SIGPROF, 155, "awr: terminated by SIGPROF")])
def test_a_signal_after_the_first_output_leaves_no_partial_set(work, frames, signum, status, line, signals_at_default):
    proc = _start(frames, work.root, signals_at_default)
    _wait_for(proc, lambda: _staged(work.root))
    proc.send_signal(signum)
    got, _, err = _finish(proc)
    assert (got, err.strip()) == (status, line), err
    assert _outputs(work.root) == []


@pytest.mark.parametrize(("signum", "status", "line"), [(signal.SIGINT, 130, "awr: interrupted"),
                                                        (signal.SIGTERM, 143, "awr: terminated"),
                                                        (signal.SIGHUP, 129, "awr: hung up")])
def test_signals_after_the_commit_end_with_the_commands_status_and_line(work, signum, status, line, signals_at_default):
    # Signals, one after another, from the moment the output is in place until the process has ended: while the
    # command finishes, while Python joins its threads and unloads its modules. The command's work is done: it
    # ends as it would have (0, nothing said) or as the first signal had it (its status, its one line), never by
    # the signal's own action (-2, -15, -1) or with a traceback.
    proc = _start(["denoise", "d.exr", "-o", "out.exr", "-q"], work.root, signals_at_default)
    _wait_for(proc, lambda: (work.root / "out.exr").exists())
    while proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signum)
        time.sleep(0.0002)
    got, _, err = _finish(proc)
    assert (got, err.strip()) in {(0, ""), (status, line)}, (got, err)
    assert read_image(work / "out.exr").shape[:2] == (H, W)  # the whole image


def test_a_second_signal_ends_a_process_whose_line_nobody_reads(work, signals_at_default):
    # stderr is a pipe already full that nobody reads: the line of the first signal waits for ever; the second
    # ends the process at once with the first one's status (its default action ended it, -15, before).
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)
    with contextlib.suppress(BlockingIOError):
        while True:
            os.write(write_end, b"x" * 4096)
    os.set_blocking(write_end, True)
    proc = subprocess.Popen([*awr_command(), "info", "d.exr"], cwd=work.root, stdout=subprocess.DEVNULL,
                            stderr=write_end, preexec_fn=signals_at_default)
    try:
        _wait_for(proc, lambda: _mapped(proc, "_multiarray_umath"))
        proc.send_signal(signal.SIGTERM)
        # Waiting for stderr to take "awr: terminated": the kernel names where it sleeps (poll_schedule_timeout,
        # pipe_write for a plain write).
        _wait_for(proc, lambda: any(k in Path(f"/proc/{proc.pid}/wchan").read_text() for k in ("poll", "pipe")))
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 143
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(read_end)
        os.close(write_end)


@pytest.mark.slow
def test_a_second_ctrl_c_during_cleanup_changes_nothing(work, frames, signals_at_default):
    proc = _start(frames, work.root, signals_at_default)
    _wait_for(proc, lambda: _staged(work.root))
    proc.send_signal(signal.SIGINT)
    time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    got, _, err = _finish(proc)
    assert (got, err.strip()) == (130, "awr: interrupted"), err
    assert _outputs(work.root) == []


def test_temporaries_of_a_killed_run_are_removed_by_the_next_run(work, frames, signals_at_default):
    proc = _start(frames, work.root, signals_at_default)
    _wait_for(proc, lambda: _staged(work.root))
    proc.kill()
    _finish(proc)
    left = [p.name for p in work.root.glob(STAGING_PREFIX + "*")]
    assert left, "SIGKILL cannot clean up: its staging directory stays until the next run"
    assert not [p for p in work.root.iterdir() if p.name.startswith(("out.", "p."))]
    # A live writer's staging directory in the same folder must survive the next run.
    holder = subprocess.Popen([sys.executable, "-c",
                               "import sys, time; from pathlib import Path; "
                               "from awr_denoise.io.atomic import _Staging; "
                               "s = _Staging(Path('.')); print(s.path.name, flush=True); time.sleep(120)"],
                              cwd=work.root, stdout=subprocess.PIPE, text=True)
    try:
        live = holder.stdout.readline().strip()
        assert live.startswith(STAGING_PREFIX)
        done = run_awr(["denoise", "d.exr", "-o", "fresh.exr", "-q"], work.root)
        assert done.returncode == 0, done.stderr
        assert [p.name for p in work.root.glob(STAGING_PREFIX + "*")] == [live]
    finally:
        holder.kill()
        holder.communicate()
    done = run_awr(["denoise", "d.exr", "-o", "fresh2.exr", "-q"], work.root)
    assert done.returncode == 0, done.stderr
    assert list(work.root.glob(STAGING_PREFIX + "*")) == []


def test_a_closed_stdout_is_a_quiet_exit(work, signals_at_default):
    """``awr info --json d.exr | head -c 0``: the reader is gone before awr writes."""
    proc = _start(["info", "--json", "d.exr"], work.root, signals_at_default)
    proc.stdout.close()
    err = proc.stderr.read()
    proc.stderr.close()
    assert proc.wait(timeout=120) == 141, err
    assert err == ""


@pytest.mark.parametrize("closed", [1, 2])
def test_a_process_started_with_stdout_or_stderr_closed_reads_its_files(work, closed):
    """Cron and daemon launchers start programs with stdout or stderr closed (``>&-``): a valid
    file is still valid (it was called "truncated or corrupt"), and the command succeeds."""
    for args, made in ((["info", "d.exr"], None), (["denoise", "d.exr", "-o", "o.exr"], "o.exr")):
        done = subprocess.run([*awr_command(), *args], cwd=work.root, stdin=subprocess.DEVNULL, timeout=120,
                              pass_fds=(), close_fds=True, capture_output=False,
                              **{("stdout" if closed == 1 else "stderr"): subprocess.DEVNULL},
                              preexec_fn=lambda fd=closed: os.close(fd))
        assert done.returncode == 0, args
        assert made is None or (work.root / made).is_file()


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
@pytest.mark.parametrize("args", [["--help"], ["--version"], ["denoise", "--help"]])
def test_help_that_cannot_be_written_is_a_failure(work, args):
    """argparse passes over a failed write: ``awr --help > /dev/full`` exited 0 with nothing written."""
    with open("/dev/full", "w") as full:
        done = subprocess.run([*awr_command(), *args], cwd=work.root, stdout=full, stderr=subprocess.PIPE,
                              text=True, timeout=120)
    assert done.returncode == 1
    one_error_line(done.stderr, "no space left on device")


@pytest.mark.parametrize("args", [["denoise", "d.exr"],
                                  ["render", "--renderer", "synthetic", "edges", "--width", "32", "--height", "32",
                                   "--spp", "4"]], ids=["denoise", "render"])
def test_a_reader_gone_from_stderr_does_not_fail_the_command(work, args):
    """Notes and progress bars are not the command's result: a closed stderr pipe loses them, not
    the command's success (denoise exited 1 with its output written; render, whose progress bar
    writes during the work, exited 1 and kept nothing)."""
    read, write = os.pipe()
    proc = subprocess.Popen([*awr_command(), *args, "-o", "o.exr"], cwd=work.root,
                            stdout=subprocess.DEVNULL, stderr=write)
    os.close(write)
    os.close(read)
    assert proc.wait(timeout=120) == 0
    assert (work.root / "o.exr").is_file()


def test_a_full_stderr_does_not_fail_the_command_nor_change_a_refusals_status(work):
    """stderr on a full device: a render without -q failed at its first progress bar's write
    (exit 1, nothing kept), and a refusal exited 1, not 2 (a review of this pass)."""
    render = ["render", "--renderer", "synthetic", "edges", "--width", "32", "--height", "32", "--spp", "4"]
    with open("/dev/full", "w") as full:
        done = subprocess.run([*awr_command(), *render, "-o", "f.exr"], cwd=work.root, stdout=subprocess.DEVNULL,
                              stderr=full, timeout=120)
        assert done.returncode == 0 and (work.root / "f.exr").is_file()
        refused = subprocess.run([*awr_command(), "denoise", "d.exr", "-o", "d.exr"], cwd=work.root,
                                 stdout=subprocess.DEVNULL, stderr=full, timeout=120)
        assert refused.returncode == 2


def test_a_refusal_still_prints_one_line_through_the_console_script(work):
    done = run_awr(["denoise", "d.exr", "-o", "d.exr"], work.root)
    assert done.returncode == 2
    one_error_line(done.stderr, "is the input")


def test_main_called_in_a_program_puts_its_callers_handlers_back(work, capsys, monkeypatch):
    """Only the console script (``run``) keeps its handlers to the end; ``main(argv)`` in a program returns
    with the program's own handlers in place, the same for a command that failed."""
    from awr_denoise.cli.main import main

    monkeypatch.chdir(work.root)
    handlers = [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)]
    assert (main(["info", "d.exr"]), main(["info", "missing.exr"])) == (0, 2)
    assert [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)] == handlers


@pytest.mark.parametrize("command", ["info", "diff"])
def test_a_signal_swallowed_on_the_way_prints_no_report(work, capsys, monkeypatch, command):
    """A SIGTERM whose exception a C extension's import lost (interrupts.received() is set, nothing
    was raised): the command must not go on to print its report or write its output."""
    from awr_denoise.cli import diff_cmd, info_cmd, interrupts
    from awr_denoise.cli.main import main

    module, name = (info_cmd, "describe") if command == "info" else (diff_cmd, "read_image")
    original = getattr(module, name)

    def swallowed(*args, **kwargs):
        interrupts._received.append(signal.SIGTERM)
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, swallowed)
    monkeypatch.chdir(work.root)
    args = ["info", "d.exr"] if command == "info" else ["diff", "ref.exr", "-r", "ref.exr", "-o", "delta.exr"]
    before = sorted(os.listdir(work.root))
    status = main(args)
    out, err = capsys.readouterr()
    assert (status, err.strip(), out) == (143, "awr: terminated", "")
    assert sorted(os.listdir(work.root)) == before


@pytest.mark.parametrize("args", [["merge", "d.exr", "b.exr", "-o", "m.exr"], ["plan", "d.exr", "-o", "r.exr"],
                                  ["denoise", "d.exr", "-o", "o.exr", "-q"]], ids=lambda a: a[0])
def test_a_signal_swallowed_before_the_commit_writes_no_output(work, capsys, monkeypatch, args):
    """A SIGTERM raised where Python can only print it (a weakref callback of importlib's module locks)
    was lost: `merge` and `plan` (which had no check of their own) then wrote their output and exited
    143 with a traceback (a red-team pass). Every commit now asks first."""
    from awr_denoise.cli import interrupts
    from awr_denoise.cli.main import main
    from awr_denoise.io import atomic

    original = atomic.check_writable

    def swallowed(*a, **k):
        interrupts._received.append(signal.SIGTERM)
        return original(*a, **k)

    monkeypatch.setattr(atomic, "check_writable", swallowed)
    monkeypatch.chdir(work.root)
    before = sorted(os.listdir(work.root))
    status = main(args)
    out, err = capsys.readouterr()
    assert (status, err.strip()) == (143, "awr: terminated")
    assert sorted(os.listdir(work.root)) == before


def test_a_signal_raised_where_python_can_only_print_it_prints_nothing(monkeypatch):
    """`Exception ignored in: ... Terminated: SIGTERM` and its traceback were printed before `awr:
    terminated`; the signal is kept (interrupts.received) and acted on, not printed. Any other such
    exception still goes to the hook that was there before."""
    from awr_denoise.cli import interrupts

    reported = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: reported.append(type(u.exc_value).__name__))

    class Unlucky:
        def __init__(self, error):
            self.error = error

        def __del__(self):
            raise self.error

    previous = interrupts.raising()
    try:
        Unlucky(interrupts.Terminated("SIGTERM"))  # dropped at once: raised where Python can only report it
        Unlucky(KeyboardInterrupt())
        Unlucky(ZeroDivisionError())
    finally:
        interrupts.restore(previous)
    assert reported == ["ZeroDivisionError"]
    Unlucky(ValueError())  # the hook before is back
    assert reported == ["ZeroDivisionError", "ValueError"]


_PROFILED = """
import signal, sys
ticks = [0]
def sample(signum, frame):  # a sampling profiler's SIGPROF handler
    ticks[0] += 1
signal.signal(signal.SIGPROF, sample)
signal.setitimer(signal.ITIMER_PROF, 0.005, 0.005)
from awr_denoise.cli.main import main
status = main(["denoise", "d.exr", "-o", "out.exr", "-q"])
signal.setitimer(signal.ITIMER_PROF, 0)
print(status, ticks[0])
"""


@pytest.mark.skipif(not hasattr(signal, "setitimer"), reason="needs POSIX interval timers")
def test_a_profilers_signal_handler_is_left_to_it(work):
    """SIGPROF ends a command cleanly where nothing handles it; where a sampling profiler does, taken over, its
    first tick ended the command, 'terminated by SIGPROF' (the review of a red-team fix)."""
    done = subprocess.run([sys.executable, "-c", _PROFILED], cwd=work.root, capture_output=True, text=True,
                          timeout=300)
    status, ticks = map(int, done.stdout.split())
    assert status == 0, done.stderr
    assert ticks > 1 and (work.root / "out.exr").exists()


def test_a_profilers_tick_while_outputs_move_leaves_it_its_handler_and_a_ctrl_c_its_effect():
    """The commit's hold (``deferred``) held a profiler's SIGPROF like an end: its tick took the place of a Ctrl-C
    after it (lost), and its handler was called with no frame (the second review)."""
    from awr_denoise._signals import deferred
    from awr_denoise.cli import interrupts

    frames = []
    previous_handler = signal.signal(signal.SIGPROF, lambda signum, frame: frames.append(frame.f_code.co_name))
    previous = interrupts.raising()
    try:
        with pytest.raises(KeyboardInterrupt):
            with deferred():
                os.kill(os.getpid(), signal.SIGPROF)
                os.kill(os.getpid(), signal.SIGINT)
        assert len(frames) == 1
    finally:
        interrupts.restore(previous)
        signal.signal(signal.SIGPROF, previous_handler)
