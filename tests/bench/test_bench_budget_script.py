"""``benchmarks/bench_budget.py``: ``awr render --seconds S`` run as a user runs it, its time against ``S``."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest

from awr_denoise.cli.parallel_options import threads_from_args
from awr_denoise.rounds import RESERVE_MARGIN


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_budget")


def test_a_case_runs_the_command_and_reads_the_times_it_printed(bench, tmp_path):
    out = tmp_path / "budget.json"
    assert bench.main(["--renderers", "synthetic", "--repeats", "1", "--output", str(out)]) == 0
    saved = json.loads(out.read_text())["budget"]
    (row,) = saved["rows"]
    assert saved["command"] == f"benchmarks/bench_budget.py --renderers synthetic --repeats 1 --output {out}"
    assert (row["renderer"], row["scene"], row["size"], row["seconds"]) == ("synthetic", "edges", [64, 64], 1.0)
    assert row["threads"] == threads_from_args(argparse.Namespace())  # the command's default, recorded
    (run,) = row["runs"]
    assert run["command"] == pytest.approx(run["rounds"] + run["finish"])
    assert row["command_over_budget"] == pytest.approx(run["command"] / 1.0)
    assert run["spp"] > 2 and 0 < run["rounds"] and 0 <= run["finish"] and run["wall"] > run["command"]
    assert 0 < row["startup"] and not run["warnings"]


def test_a_failing_command_is_an_error_not_a_row(bench):
    with pytest.raises(RuntimeError, match="exit 2"):
        bench.render("synthetic", "no_such_scene", (64, 64), 1.0, seed=0)


def _command_keeps_freed_memory() -> bool:
    """Whether ``awr``'s memory setting applies here, asked in a new process (it changes the process' allocator)."""
    done = subprocess.run([sys.executable, "-c", "from awr_denoise.memory import keep_freed_memory; "
                           "print(keep_freed_memory())"], capture_output=True, text=True, check=True)
    return done.stdout.strip() == "True"


@pytest.mark.parametrize("allocator", ["command", "glibc"])
def test_the_trial_compares_a_whole_reconstruction_with_its_quarters_and_the_files(bench, tmp_path, allocator):
    pytest.importorskip("embreex", reason="the trial renders the bundled tracer's scene (extra tracer)")
    out = tmp_path / "budget.json"
    assert bench.main(["--trial", "48x40", "160x144", "--repeats", "2", "--threads", "3", "--allocator", allocator,
                       "--output", str(out)]) == 0
    small, large = json.loads(out.read_text())["trial"]["rows"]
    kept = allocator == "command" and _command_keeps_freed_memory()
    for row, size in ((small, [48, 40]), (large, [160, 144])):
        assert row["size"] == size and all(len(row["runs"][key]) == 2 for key in row["runs"])
        assert row["threads"] == 3 and row["allocator"] == ("command" if kept else "glibc")
        assert row["whole_over_quarters"] == pytest.approx(row["whole"] / (4 * row["quarter"]))
        assert row["estimate_over_both"] == pytest.approx(row["estimate"] / (row["whole"] + row["files"]))
        assert row["whole"] > 0 and row["files"] > 0 and row["estimate"] > 0
    # The quarter is the reconstruction the estimate timed (whole below WHOLE_BELOW pixels, a quarter above), timed
    # again around the call: the estimate is about its time scaled to the image, times the margin (a pixel count
    # taken from the wrong buffer would be 4x off; the two clocks differ by the call's own overhead).
    for row in (small, large):
        assert row["estimate"] / RESERVE_MARGIN / 4 == pytest.approx(row["quarter"], rel=0.5)


@pytest.mark.parametrize("sizes", [["48"], ["48x"], ["8x8"], ["1x2x3"]])
def test_trial_sizes_are_checked(bench, sizes, capsys):
    with pytest.raises(SystemExit):
        bench.main(["--trial", *sizes])
    assert "--trial" in capsys.readouterr().err
