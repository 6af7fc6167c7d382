"""Executors of the parallel layer (awr_denoise.parallel.executors): threads, processes, Dask."""

from __future__ import annotations

import argparse
import asyncio
import concurrent.futures as cf
import contextlib
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from awr_denoise.cli.parallel_options import add_executor_arguments, executor_from_args
from awr_denoise.parallel import get_executor
from parallel_helpers import appears, environ_restored, runs_through_stop_points, runs_until_stopped


def test_get_executor_threads_and_processes_run_tasks():
    with get_executor("threads", workers=2) as threads:
        assert isinstance(threads, cf.ThreadPoolExecutor)
        assert list(threads.map(abs, [-3, 4])) == [3, 4]
    with get_executor("processes", workers=1) as processes:
        assert isinstance(processes, cf.ProcessPoolExecutor)
        assert processes.submit(abs, -5).result() == 5


def test_get_executor_defaults_to_threads_and_checks_its_arguments():
    with get_executor() as executor:
        assert isinstance(executor, cf.ThreadPoolExecutor)
    with pytest.raises(ValueError, match="kind"):
        with get_executor("ray"):
            pass
    with pytest.raises(ValueError, match="workers"):
        with get_executor("threads", workers=0):
            pass
    with pytest.raises(ValueError, match="scheduler"):
        with get_executor("threads", scheduler="tcp://127.0.0.1:8786"):
            pass
    # Refused before any connection is tried: a running scheduler's workers are those started there.
    with pytest.raises(ValueError, match="^workers: 3 given with a scheduler, whose workers are those started there$"):
        with get_executor(scheduler="tcp://127.0.0.1:1", workers=3):
            pass


def test_dask_is_optional_with_an_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(ImportError, match=r'pip install "awr-denoise\[dask\]"'):
        with get_executor("dask"):
            pass
    with get_executor("threads") as executor:  # nothing else needs Dask
        assert executor.submit(abs, -1).result() == 1


def test_dask_executor_from_a_scheduler_address_leaves_the_cluster_running(cluster):
    parser = argparse.ArgumentParser()
    add_executor_arguments(parser)
    args = parser.parse_args(["--scheduler", cluster.scheduler_address])
    with executor_from_args(args) as executor:
        assert isinstance(executor, cf.Executor)
        assert sorted(executor.map(abs, [-2, 1])) == [1, 2]
    assert len(cluster.scheduler_info["workers"]) == 2  # still up for the next client


def test_dask_executor_from_a_scheduler_file(cluster):
    assert cluster.scheduler_file_path.is_file()
    with get_executor(scheduler=cluster.scheduler_file_path) as executor:
        assert executor.submit(abs, -7).result() == 7


def test_a_scheduler_that_is_not_one_is_refused_naming_it(tmp_path):
    """Files and addresses are checked before connecting; a service that is not Dask fails at once."""
    pytest.importorskip("distributed")
    (tmp_path / "bad.json").write_text('{"garbage": true')
    (tmp_path / "empty.json").write_text('{"type": "Scheduler"}')
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)  # RecursionError: was an internal error
    (tmp_path / "scheduler-file").write_text('{"address": "tcp://127.0.0.1:8786"}')  # not named .json
    for scheduler, match in ((tmp_path / "bad.json", "bad.json: not a Dask scheduler file"),
                             (tmp_path / "deep.json", "deep.json: not a Dask scheduler file .its JSON is nested"),
                             (tmp_path / "empty.json", 'empty.json: not a Dask scheduler file .no "address"'),
                             (tmp_path / "missing.json", "missing.json: no such scheduler file"),
                             ("foo", r"'foo' is not a scheduler address \(.*\)$"),  # no file: no hint
                             (tmp_path / "scheduler-file", r"scheduler-file' is not a scheduler address .*\); a "
                                                           r"scheduler file's name ends in \.json$"),
                             ("tcp://127.0.0.1:notaport", "is not a scheduler address"),
                             ("tcp://[::1]:99999", r"port 99999 is outside 1..65535"),
                             ("http://127.0.0.1:1", "unknown address scheme 'http'"),
                             # Each of these waited Dask's 30 s or raised its own message (a red-team pass):
                             ("tcp://:0", "host '' is empty or holds a space"),
                             ("tcp://127.0.0.1:0", r"port 0 is outside 1..65535"),
                             ("tcp://999.1.1.1:80", "host 999.1.1.1 is no IPv4 address"),
                             ("tcp://a b:80", "host 'a b' is empty or holds a space"),
                             ("inproc://", "inproc:// does not reach a scheduler of another process"),
                             ("ucx://127.0.0.1:1", "ucx:// does not reach a scheduler of another process")):
        with pytest.raises(ValueError, match=f"scheduler: .*{match}"):
            with get_executor(scheduler=scheduler):
                pass
    # tls:// without certificates: Dask's own TypeError, which named no option (at a port something listens on).
    with _server(b"") as address:
        tls = address.replace("tcp://", "tls://")
        with pytest.raises(ValueError, match=rf"^scheduler: {tls}: cannot connect \(TLS expects"):
            with get_executor(scheduler=tls):
                pass
    # A server that answers with something else (an HTTP error): read as a Dask message length of
    # exabytes, it was reported as "out of memory".
    with _server(b"HTTP/1.0 400 Bad Request\r\n\r\n" * 4) as address:
        # (Which of the two depends on how the Dask version reads the reply; never a MemoryError.)
        with pytest.raises(ConnectionError, match=f"scheduler: {address}: (not a Dask|cannot connect)"):
            with get_executor(scheduler=address):
                pass


def test_a_port_nothing_listens_on_or_an_unknown_host_is_named_at_once():
    """Dask retried both for its 30 s and then said "Timed out trying to connect", which pointed at the
    network, not at a scheduler that is not running or a stale scheduler file."""
    with socket.socket() as free:  # a port of this machine that nothing listens on once it is closed
        free.bind(("127.0.0.1", 0))
        closed = f"tcp://127.0.0.1:{free.getsockname()[1]}"
    start = time.perf_counter()
    with pytest.raises(ConnectionError, match=rf"^scheduler: {closed}: connection refused \(is the scheduler running"):
        with get_executor(scheduler=closed):
            pass
    with pytest.raises(ConnectionError, match=r"^scheduler: tcp://no-such-host\.invalid:8786: unknown host "
                                              r"no-such-host\.invalid"):
        with get_executor(scheduler="tcp://no-such-host.invalid:8786"):
            pass
    assert time.perf_counter() - start < 20  # each took 31 s


def test_a_scheduler_file_that_is_no_regular_file_or_too_large_is_refused_unread(tmp_path):
    """A FIFO named ``x.json`` blocked in ``open()`` for ever and a link to ``/dev/zero`` was read until
    memory ran out, deaf to SIGTERM (a red-team pass): refused before it is opened, or after a scheduler
    file's size."""
    pytest.importorskip("distributed")
    os.mkfifo(tmp_path / "fifo.json")
    (tmp_path / "zero.json").symlink_to("/dev/zero")
    (tmp_path / "big.json").write_text('{"address": "tcp://127.0.0.1:1", "pad": "' + "x" * 2**20 + '"}')
    for name, match in (("fifo.json", "fifo.json: is a FIFO, not a regular file"),
                        ("zero.json", "zero.json: is a character device, not a regular file"),
                        ("big.json", "big.json: not a Dask scheduler file .larger than 1048576 bytes")):
        with pytest.raises(ValueError, match=f"scheduler: .*{match}"):
            with get_executor(scheduler=tmp_path / name):
                pass


@contextlib.contextmanager
def _server(reply: bytes | None):
    """A loopback TCP server's address: it sends ``reply`` to every connection and closes it, or
    with ``None`` accepts and says nothing until the block ends."""
    server = socket.create_server(("127.0.0.1", 0))
    silent = []

    def serve() -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = server.accept()
                if reply is None:
                    silent.append(conn)
                    continue
                with conn:
                    conn.sendall(reply)

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    finally:
        server.close()
        for conn in silent:
            conn.close()


def _sigint_ignored() -> bool:
    import signal

    return signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def test_a_local_dask_cluster_leaves_ctrl_c_to_the_parent():
    """Its workers ignore SIGINT (a terminal sends it to the whole group), and an interrupt in
    the parent cancels the work instead of waiting for it (it waited for ever once the workers
    had died of the same Ctrl-C)."""
    pytest.importorskip("distributed")
    import signal
    import time

    handler = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        with get_executor("dask", workers=1) as executor:
            assert executor.submit(_sigint_ignored).result() is True
            assert signal.getsignal(signal.SIGINT) is handler  # the parent's own is back
            pending = executor.submit(time.sleep, 20)
            raise KeyboardInterrupt
    assert pending.cancelled()


_DASK_VARIABLE_RUN = """
import sys
from awr_denoise.parallel import get_executor
try:
    with get_executor("dask", **({"scheduler": sys.argv[1]} if len(sys.argv) > 1 else {"workers": 1})) as executor:
        executor.submit(abs, -1).result()
except ValueError as exc:
    print(exc)
    sys.exit(2)
"""


@pytest.mark.parametrize("variable", ["DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=zz",
                                      "DASK_DISTRIBUTED__WORKER__MEMORY__TARGET=abc",
                                      "DASK_distributed__comm__timeouts__connect=zz"])  # Dask reads any case
def test_a_bad_dask_variable_is_named_where_a_local_cluster_starts(variable):
    """Dask reads a ``DASK_*`` value where it uses it and fails in its own words, deep inside (a ``KeyError``
    listing time units, "Nanny failed to start"): the command's internal error, naming nothing the user set."""
    pytest.importorskip("distributed")
    name, value = variable.split("=")
    done = subprocess.run([sys.executable, "-c", _DASK_VARIABLE_RUN], env={**os.environ, name: value},
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "a local Dask cluster did not start" in done.stdout and f"sets {name}, read by Dask" in done.stdout


def test_the_systems_own_failures_are_not_blamed_on_dask_variables():
    """No file descriptors left (``EMFILE``) was named as the variable's fault, exit 2 (a review of the change)."""
    from awr_denoise.parallel.executors import _blame_dask_variables

    environ = {"DASK_DISTRIBUTED__ADMIN__TICK__LIMIT": "3s", "PATH": "/usr/bin"}
    for exc in (OSError(24, "Too many open files"), ConnectionRefusedError(), KeyboardInterrupt()):
        assert _blame_dask_variables(exc, environ, "a local Dask cluster did not start") is None
    assert _blame_dask_variables(KeyError("x"), {"PATH": "/usr/bin", "DASK_INTERNAL_INHERIT_CONFIG": "e30="},
                                 "started") is None
    with pytest.raises(ValueError, match=r"^started \('x'\); the environment sets "
                                         r"DASK_DISTRIBUTED__ADMIN__TICK__LIMIT, read by Dask: a value Dask cannot use "
                                         r"is the likely cause; correct or unset it$"):
        _blame_dask_variables(KeyError("x"), environ, "started")


def test_a_bad_dask_variable_is_named_where_a_scheduler_is_connected_to(cluster):
    name = "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT"
    done = subprocess.run([sys.executable, "-c", _DASK_VARIABLE_RUN, cluster.scheduler_address],
                          env={**os.environ, name: "zz"}, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"{cluster.scheduler_address}: cannot connect" in done.stdout and f"sets {name}" in done.stdout


def test_a_service_that_never_answers_or_is_no_scheduler_is_refused(cluster, monkeypatch):
    """A port that accepts and stays silent (an HTTP server) held the client for ever; a worker's
    address was taken for a scheduler's."""
    pytest.importorskip("distributed")
    from awr_denoise.parallel import executors

    monkeypatch.setattr(executors, "_ANSWER_SECONDS", 0.5)
    with _server(None) as address:
        with pytest.raises(ConnectionError, match=r"no Dask answer within 1 s"):
            with get_executor(scheduler=address):
                pass
    worker = next(iter(cluster.scheduler_info["workers"]))
    with pytest.raises(ConnectionError, match="a Dask Worker, not a scheduler"):
        with get_executor(scheduler=worker):
            pass
    # A reply that announces one frame of 16 bytes and stops short of the frame lengths: "internal error:
    # unpack_from requires a buffer of at least 8 bytes" (an attack pass).
    import struct

    with _server(struct.pack("Q", 1) + struct.pack("Q", 16) + bytes(16)) as address:
        with pytest.raises(ConnectionError, match=r"not a Dask scheduler \(its reply is no Dask message\)"):
            with get_executor(scheduler=address):
                pass


_ORPHAN_SCRIPT = """
import os, sys, time
from awr_denoise.parallel import get_executor
with get_executor("processes", workers=2) as pool:
    pids = {f.result() for f in [pool.submit(os.getpid) for _ in range(8)]}
    futures = [pool.submit(time.sleep, 60) for _ in range(2)]
    print(" ".join(map(str, pids)), flush=True)
    os.kill(os.getpid(), 9)  # the parent dies without closing the pool (a farm's timeout, the OOM killer)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie waiting for init is gone for our purpose
        return f.read().rsplit(")", 1)[1].split()[0] != "Z"


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="needs /proc to see the workers")
def test_a_process_pool_left_by_its_caller_stops_its_running_tasks_at_their_stop_points(tmp_path):
    """``denoise --frames --executor processes``, told to stop, waited for each running frame's whole reconstruction
    (the workers ignore the signals; an attack pass). Leaving the pool on an exception stops what runs at its next
    stop point: the two-minute task ends with KeyboardInterrupt, within a minute even on a loaded machine."""
    started = tmp_path / "started"
    with pytest.raises(RuntimeError, match="the caller stops"):
        with get_executor("processes", workers=1) as pool:
            future = pool.submit(runs_through_stop_points, str(started), 120.0)
            assert appears(started)
            left = time.monotonic()
            raise RuntimeError("the caller stops")
    assert time.monotonic() - left < 60
    assert isinstance(future.exception(), KeyboardInterrupt)
    with get_executor("processes", workers=1) as pool:  # a pool left normally lets its tasks finish
        assert pool.submit(runs_through_stop_points, str(tmp_path / "again"), 0.2).result() > 0


def test_process_workers_end_when_their_parent_is_killed():
    # They stayed for good (parent 1), blocked on their pipes, with the pool's resource tracker.
    done = subprocess.run([sys.executable, "-c", _ORPHAN_SCRIPT], capture_output=True, text=True, timeout=120)
    pids = [int(p) for p in done.stdout.split()]
    assert len(pids) >= 1, done.stderr
    deadline = time.monotonic() + 20
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(_alive(p) for p in pids)


def test_a_scheduler_without_workers_is_refused_in_time(monkeypatch):
    """``--scheduler`` on a scheduler no worker had joined took the frames and waited for ever,
    silent (a red-team pass); a worker is now waited for (60 s), then refused naming the scheduler."""
    distributed = pytest.importorskip("distributed")
    from awr_denoise.parallel import executors

    monkeypatch.setattr(executors, "_WORKER_SECONDS", 1.0)
    with environ_restored(), distributed.LocalCluster(n_workers=0, processes=True, host="127.0.0.1",
                                                      dashboard_address=None,
                                                      scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}) as empty:
        address = empty.scheduler_address
        start = time.monotonic()
        with pytest.raises(ConnectionError, match=rf"^scheduler: {address}: no workers joined within 1 s$"):
            with get_executor(scheduler=address):
                pass
        assert time.monotonic() - start < 30


def test_a_cluster_that_loses_every_worker_mid_run_is_named_not_waited_on(monkeypatch):
    """A cluster whose workers all stopped mid-run (or never came back, a worker without the package) kept the
    command waiting for ever, without a word (an attack pass): the scheduler is asked while the tasks run, and one
    without a worker for ``_WORKER_SECONDS`` ends the wait, naming it."""
    distributed = pytest.importorskip("distributed")
    from awr_denoise.parallel import executors

    monkeypatch.setattr(executors, "_WORKER_SECONDS", 1.0)
    monkeypatch.setattr(executors, "_WATCH_SECONDS", 0.2)
    with environ_restored(), distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                                      host="127.0.0.1", dashboard_address=None,
                                                      scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}) as local:
        address = local.scheduler_address
        with pytest.raises(ConnectionError, match=rf"^scheduler: {address}: no workers for 1 s mid-run"):
            with get_executor(scheduler=address) as executor:
                future = executors.submit(executor, time.sleep, 120)
                local.scale(0)  # every worker gone, the task still the cluster's
                start = time.monotonic()
                executors.wait_first(executor, [future])
        assert time.monotonic() - start < 60


def test_a_scheduler_that_stops_answering_mid_run_is_named(monkeypatch, dask_executor):
    """A frozen scheduler (SIGSTOP, a hung host) held the wait for ever: not answering the watch's question within
    its time is a ConnectionError naming it."""
    from awr_denoise.parallel import executors

    def frozen(distributed, address, seconds):
        raise asyncio.TimeoutError

    monkeypatch.setattr(executors, "_WATCH_SECONDS", 0.2)
    monkeypatch.setattr(executors, "_identity", frozen)
    start = time.monotonic()
    assert executors.wait_first(dask_executor, []) == set()  # nothing to wait for: no question in a loop (a review)
    assert time.monotonic() - start < 5
    future = executors.submit(dask_executor, time.sleep, 5)
    with pytest.raises(ConnectionError, match=r"^scheduler: .*: no answer within 60 s mid-run "
                                              r"\(stopped or frozen\?\)$"):
        executors.wait_first(dask_executor, [future])
    future.cancel()


_FROZEN_SCHEDULER = """
import time, distributed
cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, host="127.0.0.1",
                                   protocol="tcp", dashboard_address=None,
                                   scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
print(cluster.scheduler_address, flush=True)
time.sleep(300)
"""


@pytest.mark.skipif(not hasattr(__import__("signal"), "SIGSTOP"), reason="needs SIGSTOP to freeze a scheduler")
def test_a_frozen_scheduler_ends_the_wait_and_the_executor_in_time(monkeypatch):
    """A scheduler frozen mid-run (SIGSTOP, a hung host) held the command for ever: the watch names it, and leaving
    the executor then asks nothing more of it that could hang (a review found the first form of the stop waiting
    on it there for ever)."""
    pytest.importorskip("distributed")
    import signal

    from awr_denoise.parallel import executors

    monkeypatch.setattr(executors, "_WATCH_SECONDS", 0.5)
    monkeypatch.setattr(executors, "_ANSWER_SECONDS", 1.0)
    with environ_restored():
        child = subprocess.Popen([sys.executable, "-c", _FROZEN_SCHEDULER], stdout=subprocess.PIPE, text=True)
    try:
        address = child.stdout.readline().strip()
        start = None
        with pytest.raises(ConnectionError, match=r"no answer within 2 s mid-run \(stopped or frozen\?\)"):
            with get_executor(scheduler=address) as executor:
                future = executors.submit(executor, time.sleep, 120)
                time.sleep(0.5)
                os.kill(child.pid, signal.SIGSTOP)
                start = time.monotonic()
                executors.wait_first(executor, [future])
        assert time.monotonic() - start < 45  # the wait and the way out of the executor
    finally:
        os.kill(child.pid, signal.SIGCONT)
        child.kill()
        child.wait()
        child.stdout.close()


def test_a_cluster_left_by_its_caller_stops_its_running_tasks_at_their_stop_points(cluster, tmp_path):
    """``denoise --frames --scheduler``, told to stop, left its running frames to run their whole reconstruction on
    the cluster, which outlives the command: leaving the executor on an exception cancels its tasks, and the
    two-minute task, seeing itself cancelled in its worker's books, ends at its next stop point, within a minute
    even on a loaded machine."""
    from awr_denoise.parallel import executors

    started, ended = tmp_path / "started", tmp_path / "ended"
    with pytest.raises(RuntimeError, match="the caller stops"):
        with get_executor(scheduler=cluster.scheduler_address) as executor:
            future = executors.submit(executor, runs_until_stopped, str(started), str(ended), 120.0)
            assert appears(started)
            left = time.monotonic()
            raise RuntimeError("the caller stops")
    assert appears(ended) and time.monotonic() - left < 60
    assert future.cancelled()
    with get_executor(scheduler=cluster.scheduler_address) as executor:  # an executor left normally: tasks finish
        assert executors.submit(executor, runs_until_stopped, str(tmp_path / "s2"), str(tmp_path / "e2"),
                                0.2).result() > 0


def test_a_worker_of_another_awr_denoise_is_refused_naming_it(monkeypatch, dask_executor):
    """A worker of another version, or one that imported the package before its files changed, gave other images
    with exit 0 (an attack pass): every task checks the worker's package (version and modules) against the
    command's."""
    from awr_denoise.parallel import executors

    own = executors.package_digest()
    assert executors.submit(dask_executor, abs, -3).result() == 3  # the cluster's workers run this package
    monkeypatch.setattr(executors, "package_digest", lambda: "0.0.9 0123456789abcdef")
    with pytest.raises(ConnectionError, match=r"^Dask worker tcp://127\.0\.0\.1:\d+ runs another awr-denoise "
                                              rf"\({own}\) than this command \(0\.0\.9 0123456789abcdef\)"):
        executors.submit(dask_executor, abs, -3).result()


def test_the_package_digest_is_the_same_from_a_checkout_and_from_a_wheels_layout(tmp_path, wheel_layout):
    """A wheel holds the command line's modules inside the package (``awr_denoise/cli``), a checkout beside it
    (``cli/``): hashed from the package folder alone, the same code had two digests, and a worker of an editable
    install refused a command of a wheel (an attack pass)."""
    from awr_denoise.parallel import executors

    site = wheel_layout
    code = ("import awr_denoise.cli; from awr_denoise.parallel.executors import package_digest; "
            "print(awr_denoise.cli.__file__); print(package_digest())")
    done = subprocess.run([sys.executable, "-c", code], env={**os.environ, "PYTHONPATH": str(site)}, cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    where, digest = done.stdout.strip().split("\n")
    assert Path(where).is_relative_to(site), done.stderr
    assert digest == executors.package_digest()


def test_the_package_digest_is_the_same_from_a_checkout_on_the_path_without_its_install(tmp_path):
    """A worker started with the checkout on ``PYTHONPATH`` (no install's mapping of ``awr_denoise.cli`` to ``cli/``)
    hashed no command-line module, and refused the command of the same code (a review of the change)."""
    import site

    import awr_denoise
    from awr_denoise.parallel import executors

    root = Path(awr_denoise.__file__).resolve().parents[1]
    if not (root / "cli").is_dir():
        pytest.skip("the tests run against an installed package, not a checkout")
    code = ("import importlib.util, awr_denoise; from awr_denoise.parallel.executors import package_digest; "
            "print(importlib.util.find_spec('awr_denoise.cli')); print(package_digest())")
    path = os.pathsep.join([str(root), *site.getsitepackages()])
    done = subprocess.run([sys.executable, "-S", "-c", code], env={**os.environ, "PYTHONPATH": path}, cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)  # -S: no .pth, so no install's mapping
    spec, digest = done.stdout.strip().split("\n")
    assert spec == "None", done.stderr
    assert digest == executors.package_digest()


class _Task:
    """A stand-in Dask future for :func:`executors._settle`: its status, and what gathering it gives."""

    def __init__(self, status, outcome):
        self.status, self.outcome, self.released = status, outcome, False

    def release(self):
        self.released = True


class _Client:
    async def _gather(self, task):
        if isinstance(task.outcome, BaseException):
            raise task.outcome
        return [task.outcome]

    def gather(self, tasks, asynchronous):
        assert asynchronous
        return self._gather(tasks[0])


@pytest.mark.parametrize("task, expected", [
    (_Task("finished", 7), 7),
    # A result lost with its worker, the task run again and failing (a frame finding the output its
    # first run wrote): Dask's ClientExecutor let this error escape and its future stayed pending
    # for ever, `awr denoise --frames` on Dask waiting on written frames (a red-team pass).
    (_Task("error", FileExistsError("f0048.exr: already exists")), FileExistsError),
    (_Task("lost", RuntimeError("an error of Dask's own while gathering")), RuntimeError),
    (_Task("cancelled", cf.CancelledError()), "cancelled"),
])
def test_every_outcome_of_a_dask_task_settles_its_future(task, expected):
    import asyncio

    from awr_denoise.parallel import executors

    answer = cf.Future()
    waiter = threading.Thread(target=cf.wait, args=([answer],))  # cf.wait must wake in every case
    waiter.start()
    asyncio.run(executors._settle(_Client(), task, answer))
    waiter.join(timeout=10)
    assert not waiter.is_alive() and answer.done() and task.released
    if expected == "cancelled":
        assert answer.cancelled()
    elif isinstance(expected, type):
        assert isinstance(answer.exception(), expected)
    else:
        assert answer.result() == expected


def test_a_local_dask_cluster_leaves_nothing_in_the_temporary_folder(tmp_path, monkeypatch):
    """Dask's workers left an empty ``dask-scratch-space`` in $TMPDIR after every run."""
    pytest.importorskip("distributed")
    import tempfile

    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(tempfile, "tempdir", None)  # read $TMPDIR again
    with get_executor("dask", workers=1) as executor:
        assert executor.submit(abs, -2).result(timeout=60) == 2
    assert list(tmp_path.iterdir()) == []


def test_a_dask_tasks_error_and_cancellation_reach_its_future():
    pytest.importorskip("distributed")
    from awr_denoise.parallel.executors import submit

    with get_executor("dask", workers=1) as executor:
        assert submit(executor, abs, -3).result(timeout=60) == 3
        failed = submit(executor, int, "not a number")
        assert isinstance(failed.exception(timeout=60), ValueError)
        slow = submit(executor, time.sleep, 30)
        queued = submit(executor, abs, -1)  # one worker thread: queued behind the sleep
        assert queued.cancel()
        done, _ = cf.wait([queued], timeout=30)
        assert queued in done and queued.cancelled()
        slow.cancel()


def test_a_future_cancelled_by_its_caller_after_the_task_finished_still_wakes_its_waiters():
    """The caller's cancel() succeeds until the answer is settled; settling it then failed quietly and
    cf.wait() never learnt of the cancellation (a review)."""
    import asyncio

    from awr_denoise.parallel import executors

    answer = cf.Future()
    waiter = threading.Thread(target=cf.wait, args=([answer],))
    waiter.start()
    assert answer.cancel()
    task = _Task("finished", 7)
    asyncio.run(executors._settle(_Client(), task, answer))
    waiter.join(timeout=10)
    assert not waiter.is_alive() and answer.cancelled() and task.released
