"""``benchmarks/bench_cli_threads.py``: the command line on one thread and on a pool, timed as a user runs it."""

from __future__ import annotations

import json

import pytest


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_cli_threads")


def test_every_case_is_timed_on_both_and_the_ratios_are_of_the_medians(bench, tmp_path, capsys):
    pytest.importorskip("embreex", reason="the cases render the bundled tracer's scene (extra tracer)")
    out = tmp_path / "threads.json"
    assert bench.main(["--size", "40x24", "--spp", "4", "--repeats", "2", "--output", str(out)]) == 0
    saved = json.loads(out.read_text())
    assert saved["command"] == f"python benchmarks/bench_cli_threads.py --size 40x24 --spp 4 --repeats 2 --output {out}"
    assert (saved["size"], saved["spp"], saved["pool"], len(saved["floor_runs"])) == ("40x24", 4, 2, 2)
    assert [row["case"] for row in saved["rows"]] == ["denoise", "plan", "render"]
    for row in saved["rows"]:
        assert set(row["runs"]) == {"1", "2"} and all(len(times) == 2 for times in row["runs"].values())
        one, two = (sum(row["runs"][k]) / 2 for k in ("1", "2"))  # the median of two is their mean
        assert (row["one_thread"], row["threads"]) == pytest.approx((one, two))
        assert row["speed_up"] == pytest.approx(one / two)
        assert row["speed_up_above_the_floor"] == pytest.approx((one - saved["floor"]) / (two - saved["floor"]))
        assert row["timed"].startswith(f"awr {row['case']} " if row["case"] != "plan" else "python -c PLAN ")
        assert row["timed"].endswith(" --threads N")
    assert "| `plan` |" in capsys.readouterr().out


def test_a_failing_command_is_an_error_not_a_time(bench, tmp_path):
    with pytest.raises(RuntimeError, match=r"^awr denoise missing\.exr -o o\.exr: exit 2: awr: error: "):
        bench._run([*bench.awr_command(), "denoise", "missing.exr", "-o", "o.exr"], tmp_path)
    with pytest.raises(RuntimeError, match=r"(?s)^python -c PLAN running\.exr request\.exr --threads 2 \(benchmarks/bench_cli_threads\.py\): "
                                           r"exit 1: .*running\.exr: no such file"):
        bench._run([*bench._commands("40x24", 4)["plan"], "--threads", "2"], tmp_path)


@pytest.mark.parametrize("argv", [["--size", "48"], ["--size", "4x4"], ["--threads", "1"], ["--cases", "merge"]])
def test_arguments_are_checked(bench, argv, capsys):
    with pytest.raises(SystemExit):
        bench.main(argv)
    assert argv[0] in capsys.readouterr().err
