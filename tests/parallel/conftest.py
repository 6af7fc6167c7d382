"""Fixtures of the parallel tests: one local Dask cluster for the whole package."""

from __future__ import annotations

import contextlib

import pytest

from awr_denoise.parallel import get_executor
from parallel_helpers import environ_restored, write_dumps


@pytest.fixture(scope="package")
def cluster(tmp_path_factory):
    """A local Dask cluster: 2 worker processes, 1 thread each, loopback only, no dashboard.

    Its scheduler also writes a scheduler file, as ``dask scheduler --scheduler-file`` and
    dask-jobqueue do. ``dashboard_address=None`` turns the dashboard off, but the scheduler
    still serves its HTTP routes, by default on port 8787 with a warning when that port is
    taken; a free loopback port avoids both.
    """
    distributed = pytest.importorskip("distributed")
    scheduler_file = tmp_path_factory.mktemp("dask") / "scheduler.json"
    with contextlib.ExitStack() as stack:
        with environ_restored():  # at once: the package's fixtures are torn down at the session's end
            local = stack.enter_context(distributed.LocalCluster(
                n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0", "scheduler_file": str(scheduler_file)}))
        local.scheduler_file_path = scheduler_file
        yield local


@pytest.fixture
def dask_executor(cluster):
    with get_executor("dask", scheduler=cluster.scheduler_address) as executor:
        yield executor



@pytest.fixture
def dumps(tmp_path):
    pytest.importorskip("OpenEXR")
    return write_dumps(tmp_path)
