"""``benchmarks/bench_memory.py --commands``: the commands' peak memory per pixel, which they check a dump against."""

from __future__ import annotations

import json

import numpy as np
import pytest

from awr_denoise.cli.common import DUMP_BYTES_PER_PIXEL

pytest.importorskip("OpenEXR")


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_memory")


def test_each_command_s_check_is_at_least_its_stored_measurement(bench):
    """The figures the commands refuse a dump by are the measured peaks rounded up: a new measurement above them
    fails here until they are raised."""
    stored = json.loads(bench.COMMAND_RESULTS.read_text())["bytes_per_pixel"]
    assert set(DUMP_BYTES_PER_PIXEL) == set(bench.COMMANDS) <= set(stored)
    for command, per_pixel in DUMP_BYTES_PER_PIXEL.items():
        assert stored[command] <= per_pixel < 1.1 * stored[command], command


def test_the_commands_run_and_their_peaks_grow_with_the_pixels(bench):
    commands = {name: bench.COMMANDS[name] for name in ("info", "plan")}
    result = bench.command_peaks(sides=(16, 256), commands=commands)
    assert [(r["command"], r["side"]) for r in result["rows"]] == [
        ("info", 16), ("plan", 16), ("info", 256), ("plan", 256)]
    assert all(r["maxrss_bytes"] > 10 * 2**20 for r in result["rows"])  # an interpreter with numpy at least
    assert set(result["bytes_per_pixel"]) == set(commands)
    assert all(np.isfinite(v) for v in result["bytes_per_pixel"].values())
