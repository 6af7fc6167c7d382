"""The parallel layer on a local Dask cluster of two worker processes (loopback only).

The cluster is started once for the package (about 1-2 s) and the tests also run in the
default selection.
"""

from __future__ import annotations

import concurrent.futures as cf
import os

import pytest

from awr_denoise import AdaptiveSampler, reconstruct
from awr_denoise.parallel import (
    RendererSpec,
    denoise_frames,
    get_executor,
    reconstruct_tiled,
    render_tiled,
)
from awr_denoise.parallel.executors import submit
from parallel_helpers import (
    assert_same_buffer,
    assert_same_files,
    assert_tiled_close,
    noisy_buffer,
    serial_frames,
    serial_render,
)

distributed = pytest.importorskip("distributed")


# ---------------------------------------------------------------------------- on the Dask cluster
def test_cluster_render_tiled_equals_the_serial_render_bitwise(dask_executor):
    shape = (64, 80)
    spec = RendererSpec.synthetic("fireflies", shape, seed=11)
    expected = serial_render(spec, shape, 10)
    tiled = render_tiled(spec, AdaptiveSampler(shape, seed=2), total_spp=10, tile=32, executor=dask_executor)
    assert_same_buffer(tiled, expected)


def test_cluster_reconstruct_tiled_matches_whole_frame(dask_executor):
    buffer = noisy_buffer(shape=(120, 150))
    for mode in ("channels", "luminance"):
        whole = reconstruct(buffer, levels=3, mode=mode, precision="float64")
        assert_tiled_close(reconstruct_tiled(buffer, tile=48, levels=3, mode=mode, executor=dask_executor,
                                             precision="float64"), whole)


def test_cluster_denoise_frames_equals_the_serial_run_bitwise(tmp_path, dumps, dask_executor):
    serial = [tmp_path / f"serial.{i}.exr" for i in range(len(dumps))]
    serial_frames(dumps, serial, c_s=1.0)
    clustered = [tmp_path / f"cluster.{i}.exr" for i in range(len(dumps))]
    denoise_frames(dumps, clustered, executor=dask_executor, c_s=1.0)
    assert_same_files(clustered, serial)


_DASK_WRITES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "PYTHONHASHSEED", "__DASK_PARENT_PID",
                "MALLOC_TRIM_THRESHOLD_")
"""What starting a local Dask cluster writes into the starting process' environment."""


def test_a_local_cluster_leaves_the_environment_as_it_found_it(monkeypatch):
    """A local cluster left one BLAS and OpenMP thread (and Dask's malloc and hash settings) in the caller's
    environment after it had closed: every process started afterwards inherited them (a review of the library)."""
    pytest.importorskip("distributed")
    for name in _DASK_WRITES:  # (this package's own cluster, a fixture, may have written them already)
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")  # the caller's own: kept
    before = dict(os.environ)
    with get_executor("dask", workers=1) as executor:
        assert executor.submit(abs, -2).result() == 2
        written = {name: os.environ.get(name) for name in _DASK_WRITES}
        os.environ["AWR_TEST_SET_INSIDE"] = "1"  # the caller's, set meanwhile: kept
    assert written["MKL_NUM_THREADS"] == "1"  # what is undone (were Dask to stop writing it, this would say so)
    assert os.environ.pop("AWR_TEST_SET_INSIDE") == "1"
    assert dict(os.environ) == before


def test_a_cluster_start_cut_short_leaves_no_scratch_folder_behind(monkeypatch, tmp_path):
    """SIGTERM (or a failed nanny) while a local cluster started: its workers, still starting, made the scratch folder
    again after it had been removed, and $TMPDIR kept awr-dask-*/dask-scratch-space with its locks (an attack pass).
    The children started meanwhile are ended before the folder goes."""
    import multiprocessing
    import tempfile
    import time
    from pathlib import Path

    from parallel_helpers import remakes_scratch

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    started = []

    def cut_short(*args, local_directory, **kwargs):
        worker = multiprocessing.get_context("spawn").Process(target=remakes_scratch, args=(local_directory,),
                                                              daemon=True)
        worker.start()
        started.append(worker)
        end = time.monotonic() + 60
        while not (Path(local_directory) / "dask-scratch-space").exists() and time.monotonic() < end:
            time.sleep(0.01)
        raise RuntimeError("Nanny failed to start.")

    monkeypatch.setattr(distributed, "LocalCluster", cut_short)
    with pytest.raises(RuntimeError, match="Nanny failed to start"):
        with get_executor("dask", workers=1):
            pass
    assert len(started) == 1 and not started[0].is_alive()
    time.sleep(0.3)  # what a worker still running would make again
    assert list(tmp_path.iterdir()) == []


_STARTING_CLUSTER = r"""
import sys
import time

import distributed

from awr_denoise.cli import interrupts
from awr_denoise.parallel import get_executor

closed = []


class Starting:  # a local cluster that takes two seconds to start, as a real one about does
    def __init__(self, *args, **kwargs):
        print("starting", flush=True)
        time.sleep(2.0)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        closed.append(True)


distributed.LocalCluster = Starting
interrupts.raising()
try:
    with get_executor("dask", workers=1):
        print("ran", flush=True)
except KeyboardInterrupt:
    print("interrupted, cluster closed:", closed == [True], flush=True)
"""


@pytest.mark.skipif(os.name != "posix", reason="a terminal's process group is POSIX")
def test_a_ctrl_c_while_a_local_cluster_starts_stops_the_command():
    """A terminal's Ctrl-C (SIGINT to the process group) while a local cluster started was ignored for good: the
    workers must ignore it, so this process did too then, and the command went on and wrote its outputs (an attack
    pass). A sentinel child sees it now; it is raised once the cluster is in hand, and the cluster is closed."""
    import signal
    import subprocess
    import sys

    child = subprocess.Popen([sys.executable, "-c", _STARTING_CLUSTER], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert child.stdout.readline() == "starting\n"
        os.killpg(child.pid, signal.SIGINT)
        out, err = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
    assert out == "interrupted, cluster closed: True\n", err
    assert child.returncode == 0


def test_local_cluster_on_demand_runs_a_tiled_render():
    shape = (32, 48)
    spec = RendererSpec.synthetic("edges", shape, seed=4)
    environ_before = os.environ.get("MALLOC_TRIM_THRESHOLD_")
    with get_executor("dask", workers=2) as executor:
        tiled = render_tiled(spec, AdaptiveSampler(shape, seed=2), total_spp=6, tile=16, executor=executor)
        # Workers keep glibc's malloc tuning (Dask's trim threshold made numpy tasks 1.7x slower).
        assert executor.submit(os.environ.get, "MALLOC_TRIM_THRESHOLD_").result() is None
    assert os.environ.get("MALLOC_TRIM_THRESHOLD_") == environ_before
    assert_same_buffer(tiled, serial_render(spec, shape, 6))


@pytest.mark.slow
@pytest.mark.tracer
def test_cluster_render_tiled_with_the_path_tracer_equals_the_serial_render(dask_executor):
    tracer = pytest.importorskip("awr_denoise.tracer")
    name = "cornell_box" if "cornell_box" in tracer.list_scenes() else sorted(tracer.list_scenes())[0]
    spec = RendererSpec.tracer(name, width=48, height=40, seed=3, threads=1)
    shape = spec().shape
    expected = AdaptiveSampler(shape, seed=1).run(spec(), 8)
    tiled = render_tiled(spec, AdaptiveSampler(shape, seed=1), total_spp=8, tile=24, executor=dask_executor)
    assert_same_buffer(tiled, expected)


def test_tasks_are_never_answered_from_dask_cache(cluster, tmp_path):
    """Dask reuses the result of an identical pure task; ours have side effects and must all run."""
    with distributed.Client(cluster.scheduler_address) as client:
        executor = client.get_executor()  # a user's executor, pure by default
        target = tmp_path / "made"
        futures = [submit(executor, os.mkdir, str(target)) for _ in range(2)]
        cf.wait(futures)
        outcomes = sorted(type(f.exception()).__name__ for f in futures)
        # Both ran, so one found the directory made; pure tasks would have shared one result.
        assert outcomes == ["FileExistsError", "NoneType"]
        executor.shutdown()


def test_process_pool_gives_the_serial_results(tmp_path, dumps):
    shape = (40, 56)
    spec = RendererSpec.synthetic("hdr_source", shape, seed=9)
    buffer = noisy_buffer(shape=(80, 100))
    serial = [tmp_path / f"serial.{i}.exr" for i in range(len(dumps))]
    serial_frames(dumps, serial)
    pooled = [tmp_path / f"pool.{i}.exr" for i in range(len(dumps))]
    with get_executor("processes", workers=2) as executor:
        denoise_frames(dumps, pooled, executor=executor)
        tiled = render_tiled(spec, AdaptiveSampler(shape, seed=2), total_spp=6, tile=24, executor=executor)
        image = reconstruct_tiled(buffer, tile=40, levels=3, executor=executor, precision="float64")
    assert_same_files(pooled, serial)
    assert_same_buffer(tiled, serial_render(spec, shape, 6))
    assert_tiled_close(image, reconstruct(buffer, levels=3, precision="float64"))
