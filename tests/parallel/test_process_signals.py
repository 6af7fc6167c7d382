"""Terminating signals and ``--executor processes``: the parent alone reacts, at any moment of the run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from awr_denoise.parallel import get_executor

_AWR = "import sys; from awr_denoise.cli.main import main; sys.exit(main())"
_RENDER = ["render", "--spp", "4", "--width", "256", "--height", "256", "--tile", "32", "-o", "r.exr", "-q",
           "--workers", "2", "--executor", "processes"]


def _processes() -> dict[int, tuple[int, int, bytes]]:
    """Every live process: its parent, its process group and its command line."""
    found = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            with open(f"/proc/{name}/cmdline", "rb") as f:
                cmdline = f.read()
        except OSError:  # gone meanwhile
            continue
        if fields[0] != "Z":
            found[int(name)] = (int(fields[1]), int(fields[2]), cmdline)
    return found


def _workers(pid: int) -> list[int]:
    """The spawned pool workers of process ``pid`` (not its resource tracker)."""
    return [p for p, (parent, _, cmd) in _processes().items() if parent == pid and b"spawn_main" in cmd]


def _group(pgid: int) -> list[int]:
    return [p for p, (_, group, _) in _processes().items() if group == pgid]


def _wait_for(condition, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


@pytest.mark.skipif(not os.path.isdir("/proc") or not hasattr(os, "killpg"), reason="POSIX with /proc")
@pytest.mark.parametrize(("name", "status", "line", "waits"), [
    ("SIGINT", 130, "awr: interrupted", (0.1, 0.5)),
    ("SIGHUP", 129, "awr: hung up", (0.2,)),
    ("SIGTERM", 143, "awr: terminated", (0.2,)),
])
def test_a_signal_to_the_group_while_the_workers_start_ends_the_command_cleanly(tmp_path, name, status, line, waits,
                                                                             signals_at_default):
    """Ctrl-C at a terminal signals the whole process group. In the second a spawned worker spends
    importing the package, each worker printed a KeyboardInterrupt traceback (SIGTERM and SIGHUP killed
    it), the pool broke under the parent's cleanup ("InvalidStateError: CANCELLED") and the command
    then hung in 3 of 4 runs; SIGHUP also killed multiprocessing's resource tracker (its warning,
    KeyError tracebacks). Now: the signal's one line and exit status, soon, nothing left running."""
    pytest.importorskip("OpenEXR")
    for wait in waits:
        folder = tmp_path / f"{name}-{wait}"
        folder.mkdir()
        proc = subprocess.Popen([sys.executable, "-c", _AWR, *_RENDER], cwd=folder, stderr=subprocess.PIPE,
                                text=True, start_new_session=True, preexec_fn=signals_at_default)
        try:
            # The workers are spawned at the first tile; a signal sent then meets them importing.
            assert _wait_for(lambda: bool(_workers(proc.pid)) or proc.poll() is not None, 60)
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(wait)
            os.killpg(proc.pid, getattr(signal, name))
            try:
                code = proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                pytest.fail(f"{name} {wait} s after the workers started: still running 30 s later")
            err = proc.stderr.read()
            assert (code, err.strip()) == (status, line), err
            assert _wait_for(lambda: not _group(proc.pid), 10), "processes of the command left running"
            assert sorted(os.listdir(folder)) == []
        finally:
            for pid in _group(proc.pid):
                os.kill(pid, signal.SIGKILL)
            proc.stderr.close()
            proc.wait()


def _dispositions() -> list[object]:
    return [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)]


def _blocked() -> set[int]:
    return set(signal.pthread_sigmask(signal.SIG_BLOCK, []))


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signal masks")
def test_process_workers_ignore_the_terminating_signals_and_the_parent_keeps_its_own():
    """The workers leave SIGINT, SIGTERM and SIGHUP to the parent (none blocked: the pool can still
    end them); the parent's handlers and signal mask are as before."""
    handlers, mask = _dispositions(), _blocked()
    with get_executor("processes", workers=1) as pool:
        assert pool.submit(_dispositions).result() == [signal.SIG_IGN] * 3
        assert pool.submit(_blocked).result() == set()
        assert (_dispositions(), _blocked()) == (handlers, mask)
    assert (_dispositions(), _blocked()) == (handlers, mask)


_BROKEN_POOL = """
import os, signal, sys, time
from concurrent.futures.process import BrokenProcessPool
from awr_denoise.parallel import get_executor
try:
    with get_executor("processes", workers=2) as pool:
        busy = pool.submit(time.sleep, 120)  # one worker busy for long
        while not busy.running():
            time.sleep(0.01)
        other = pool.submit(os.getpid).result()  # the idle one
        os.kill(other, signal.SIGKILL)  # the OOM killer's choice
        busy.result()
except BrokenProcessPool:
    print("broken", flush=True)
"""


def test_a_pool_whose_worker_is_killed_closes_without_waiting_for_the_others():
    """Python ends the other workers of a broken pool with SIGTERM, which they ignore: it then waited
    for their tasks (or for ever, one blocked on a lock the dead worker held)."""
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-c", _BROKEN_POOL], capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stdout) == (0, "broken\n"), done.stderr
    assert time.monotonic() - started < 30
