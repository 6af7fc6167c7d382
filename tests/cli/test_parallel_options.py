"""The --workers/--scheduler/--executor options (awr_denoise.cli.parallel_options)."""

from __future__ import annotations

import argparse
import concurrent.futures as cf

import pytest

from awr_denoise.cli.parallel_options import add_executor_arguments, executor_from_args, executor_requested


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
