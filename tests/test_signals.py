"""The stop points of long work on worker threads (:func:`awr_denoise._signals.stop_point`)."""

from __future__ import annotations

import concurrent.futures as cf

import numpy as np
import pytest

from awr_denoise import SampleRequest, reconstruct
from awr_denoise._signals import COMMIT_CHECKS, stop_point
from awr_denoise.synthetic import SyntheticRenderer, make_scene


@pytest.fixture
def checks():
    """COMMIT_CHECKS as the command line fills it (``awr_denoise.cli.interrupts.raising``), emptied after."""
    added: list = []
    yield lambda check: (added.append(check), COMMIT_CHECKS.append(check))
    for check in added:
        COMMIT_CHECKS.remove(check)


def _buffer(shape=(64, 96)):
    return SyntheticRenderer(make_scene("edges", shape), seed=1)(SampleRequest.uniform(shape, 4))


def _raise() -> None:
    raise KeyboardInterrupt


def test_a_stop_point_raises_what_a_check_raises_on_any_thread(checks):
    stop_point()  # no checks: nothing
    checks(_raise)
    with pytest.raises(KeyboardInterrupt):
        stop_point()
    with cf.ThreadPoolExecutor(1) as pool:
        with pytest.raises(KeyboardInterrupt):
            pool.submit(stop_point).result()


def test_a_reconstruction_on_a_worker_thread_stops_at_its_stop_points(checks):
    """``denoise --frames`` on threads, told to stop, waited for each running frame's whole reconstruction (tens of
    seconds at 4K; an attack pass). The default reconstruction passes a stop point before each of its steps and each
    band of its Wiener stages; a signal taken by the command line ends it at the next."""
    buffer = _buffer()
    calls: list[int] = []
    checks(lambda: calls.append(1))
    with cf.ThreadPoolExecutor(1) as pool:
        expected = pool.submit(reconstruct, buffer).result()
    assert len(calls) >= 12  # the Wiener bands of two stages and the steps around them
    np.testing.assert_array_equal(expected, reconstruct(buffer))  # the points change nothing

    seen: list[int] = []

    def third() -> None:
        seen.append(1)
        if len(seen) == 3:
            raise KeyboardInterrupt

    checks(third)
    with cf.ThreadPoolExecutor(1) as pool:
        with pytest.raises(KeyboardInterrupt):
            pool.submit(reconstruct, buffer).result()
    assert len(seen) == 3  # no point passed after it
