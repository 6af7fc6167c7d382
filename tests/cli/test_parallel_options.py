"""The --workers/--scheduler/--executor options (awr_denoise.cli.parallel_options)."""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import functools
from pathlib import Path

import pytest

from awr_denoise.cli.parallel_options import (DEFAULT_THREADS, add_executor_arguments, add_threads_argument,
                                              executor_from_args, executor_requested, library_threads,
                                              threads_from_args)


def test_executor_arguments_round_trip():
    parser = argparse.ArgumentParser()
    add_executor_arguments(parser)
    args = parser.parse_args(["--workers", "2"])
    with executor_from_args(args) as executor:
        assert isinstance(executor, cf.ThreadPoolExecutor)
        assert executor._max_workers == 2
    args = parser.parse_args(["--executor", "processes", "--workers", "1"])
    with executor_from_args(args) as executor:
        assert isinstance(executor, cf.ProcessPoolExecutor)
    with pytest.raises(ValueError, match="--scheduler"):
        executor_from_args(parser.parse_args(["--executor", "threads", "--scheduler", "tcp://127.0.0.1:1"]))
    with pytest.raises(ValueError, match="--workers"):
        executor_from_args(argparse.Namespace(workers=0))
    with pytest.raises(SystemExit):  # refused where it is parsed
        parser.parse_args(["--workers", "0"])
    assert executor_from_args(argparse.Namespace()) is not None  # a parser without the options
    assert not executor_requested(parser.parse_args([]))
    assert executor_requested(parser.parse_args(["--executor", "threads"]))
    with_tile = argparse.ArgumentParser()
    add_executor_arguments(with_tile, tile_option=True)
    assert with_tile.parse_args([]).tile is None and with_tile.parse_args(["--tile", "64"]).tile == 64




def test_local_processes_are_limited_per_cpu(monkeypatch):
    """--workers 4096 --executor processes started hundreds of processes and exhausted memory."""
    from awr_denoise.cli import parallel_options

    monkeypatch.setattr(parallel_options, "default_workers", lambda: 2)
    parser = argparse.ArgumentParser()
    add_executor_arguments(parser)
    for argv in (["--executor", "processes", "--workers", "9"], ["--executor", "dask", "--workers", "4096"]):
        with pytest.raises(ValueError, match=r"--workers: \d+ local processes where this process may run on 2 CPUs; "
                                             r"at most 8"):
            executor_from_args(parser.parse_args(argv))
    with executor_from_args(parser.parse_args(["--workers", "9"])) as executor:  # threads are cheap
        assert executor._max_workers == 9
    with executor_from_args(parser.parse_args(["--executor", "processes", "--workers", "8"])) as executor:
        assert isinstance(executor, cf.ProcessPoolExecutor)


def test_the_cpus_counted_are_those_this_process_may_run_on(monkeypatch):
    """Under ``taskset -c 0`` the cap counted the machine's CPUs: 5 local processes were allowed on one (a
    red-team pass)."""
    import os

    from awr_denoise.parallel.executors import default_workers

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert default_workers() == 1
    monkeypatch.delattr(os, "sched_getaffinity", raising=False)
    assert default_workers() == max(1, os.cpu_count() or 1)


def test_workers_beside_a_scheduler_are_refused():
    """The cluster's own workers run the work: ``--workers 5`` beside ``--scheduler`` was ignored without a word."""
    parser = argparse.ArgumentParser()
    add_executor_arguments(parser)
    with pytest.raises(ValueError, match=r"^--workers 5: not with --scheduler \(the cluster's own workers"):
        executor_from_args(parser.parse_args(["--workers", "5", "--scheduler", "tcp://127.0.0.1:1"]))


def test_dask_logs_nothing_below_critical_until_its_client_is_closed():
    """A lost scheduler's client logged each reconnection attempt with two tracebacks, and its last words as it
    closed (35 lines before the command's one): dropped while the executor runs, the levels left as they are."""
    pytest.importorskip("distributed", reason="the Dask executor needs the extra dask")
    import logging

    parser = argparse.ArgumentParser()
    add_executor_arguments(parser)
    names = ("distributed", "distributed.client")
    before = [logging.getLogger(name).level for name in names]
    with executor_from_args(parser.parse_args(["--executor", "dask", "--workers", "1"])) as executor:
        for name in names:
            logger = logging.getLogger(name)
            assert not logger.filter(logger.makeRecord(name, logging.ERROR, __file__, 1, "lost", (), None))
            assert logger.filter(logger.makeRecord(name, logging.CRITICAL, __file__, 1, "fatal", (), None))
        assert executor.submit(sum, [1, 2]).result() == 3
    assert [logging.getLogger(name).level for name in names] == before  # the caller's levels, untouched
    for name in names:  # and nothing held back once the client is closed
        logger = logging.getLogger(name)
        assert logger.filter(logger.makeRecord(name, logging.ERROR, __file__, 1, "later", (), None))


def test_threads_default_to_two_or_the_cpus_this_process_may_use(monkeypatch):
    from awr_denoise.cli import parallel_options

    parser = argparse.ArgumentParser()
    add_threads_argument(parser, "the work")
    for cpus, expected in ((1, 1), (2, 2), (64, DEFAULT_THREADS)):
        monkeypatch.setattr(parallel_options, "default_workers", lambda cpus=cpus: cpus)
        assert threads_from_args(parser.parse_args([])) == expected
    assert threads_from_args(parser.parse_args(["--threads", "5"])) == 5  # given: as given, on any machine
    assert threads_from_args(argparse.Namespace()) == min(DEFAULT_THREADS, 64)  # a parser without the option
    for bad in ("0", "-1", "2.5", "many"):
        with pytest.raises(SystemExit):  # refused where it is parsed
            parser.parse_args(["--threads", bad])
    with library_threads(1) as none:
        assert none is None
    with library_threads(3) as pool:
        assert isinstance(pool, cf.ThreadPoolExecutor) and pool._max_workers == 3
        assert pool.submit(sum, [1, 2]).result() == 3
    with pytest.raises(RuntimeError):  # shut down on the way out
        pool.submit(sum, [1])


def test_library_threads_drop_the_tasks_not_started_when_the_command_is_interrupted():
    """Ctrl-C while the library waits for its tasks: the ones not started never run, and the running ones have
    finished once the pool's context is left (no thread of it is left working behind the command's cleanup)."""
    import threading
    import time

    ran, started = [], threading.Event()

    def task(i: int) -> None:
        started.set()
        time.sleep(0.05)
        ran.append(i)

    with pytest.raises(KeyboardInterrupt):
        with library_threads(2) as pool:
            for i in range(40):
                pool.submit(task, i)
            started.wait(10)
            raise KeyboardInterrupt
    assert all(not t.is_alive() for t in pool._threads)
    assert 1 <= len(ran) <= 4, ran  # those two threads had started (and at most one more each)
    time.sleep(0.2)
    assert len(ran) <= 4


def _spied(monkeypatch, module, name: str) -> list:
    """The ``executor`` of every call of ``module.name`` (a reconstruction), recorded."""
    given: list = []
    real = getattr(module, name)
    monkeypatch.setattr(module, name, functools.wraps(real)(lambda *a, **k: given.append(k.get("executor")) or
                                                           real(*a, **k)))  # wraps: its signature is checked
    return given


def test_render_and_denoise_run_the_library_on_their_threads_with_the_same_files(tmp_path, monkeypatch):
    """``--threads N`` gives the sampler's ranking and the reconstruction a pool of N threads (1: none), and every
    file written is the one-thread run's, bit for bit. ``awr plan`` has none: one ``ask()`` in a new process gained
    nothing measurable on a pool (docs/cli.md, "Threads")."""
    pytest.importorskip("OpenEXR")
    from awr_denoise import sampling
    from awr_denoise.cli import render_cmd
    from awr_denoise.cli.main import main
    from awr_denoise.parallel import frames

    samplers: list = []
    real_init = sampling.Sampler.__init__

    def init(self, *a, **k):
        real_init(self, *a, **k)
        samplers.append(self.executor)

    monkeypatch.setattr(sampling.Sampler, "__init__", init)
    rendered = _spied(monkeypatch, render_cmd, "reconstruct_detailed")
    denoised = _spied(monkeypatch, frames, "reconstruct_detailed")
    render = ["render", "--renderer", "synthetic", "--scene", "edges", "--width", "48", "--height", "32", "--spp", "6",
              "--adaptive", "-q"]
    for threads in ("1", "2"):
        samplers.clear(), rendered.clear(), denoised.clear()
        out = tmp_path / threads
        out.mkdir()
        assert main([*render, "-o", str(out / "r.exr"), "--threads", threads]) == 0
        assert main(["plan", str(out / "r.exr"), "-o", str(out / "q.exr"), "-q"]) == 0  # the same dump's plan
        assert main(["denoise", str(out / "r.exr"), "-o", str(out / "d.exr"), "-q", "--threads", threads]) == 0
        pools = [p for p in samplers + rendered + denoised[1:] if p is not None]  # denoised[0]: the options' trial
        if threads == "1":
            assert pools == []
        else:
            assert len(samplers) == 2 and len(rendered) == 1 and len(denoised) == 2  # render's sampler, plan's
            assert samplers[1] is None  # plan's
            assert len(pools) == 3 and all(isinstance(p, cf.ThreadPoolExecutor) and p._max_workers == 2 for p in pools)
    for name in ("r.exr", "r.denoised.exr", "r.denoised.png", "q.exr", "d.exr"):
        one, two = tmp_path / "1" / name, tmp_path / "2" / name
        if name.endswith(".png"):
            assert one.read_bytes() == two.read_bytes(), name
        else:
            assert _contents(one) == _contents(two), name


def _contents(path: Path) -> tuple:
    """A file's header but what tells one run from another (the seconds its render took, the id of the process'
    sampler that planned it), and its channels' pixels."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        header = {k: repr(v) for k, v in f.header().items() if k not in ("awr:render_seconds", "awr:sampler_id")}
        return header, {name: c.pixels.tobytes() for name, c in f.channels().items()}


@pytest.mark.parametrize(("args", "needles"), [
    (["denoise", "d.exr", "-o", "o.exr", "--executor", "processes", "--workers", "1", "--threads", "2"],
     ("--threads: the frame is reconstructed in a worker process, not in this one; leave --threads out",)),
    (["denoise", "shot.####.exr", "--frames", "1-3", "-o", "o.####.exr", "--threads", "2"],
     ("--threads: the 3 frames run side by side instead, each on one thread (--workers sets how many)",)),
])
def test_threads_that_would_do_nothing_are_refused_before_any_output(work, capsys, args, needles):
    """A setting that would do nothing is refused, not ignored: one line, exit 2, no file written."""
    from awr_denoise.cli.main import main
    from cli_helpers import one_error_line

    before = work.state()
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(work.root)
        assert main(args) == 2
    one_error_line(capsys.readouterr().err, *needles)
    assert work.state() == before
    # Left out, the default is no refusal: one thread where it would do nothing.
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(work.root)
        assert main([a for a in args if a not in ("--threads", "2")] + ["-q"]) == 0
