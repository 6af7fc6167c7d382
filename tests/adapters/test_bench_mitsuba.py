"""Smoke run of ``benchmarks/bench_mitsuba.py --quick`` (tiny images): the JSON it writes is complete."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest

from awr_denoise.sampling import DEFAULT_AWR_INITIAL_SPP

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_mitsuba.py"


@pytest.fixture(scope="module")
def bench(mi):
    spec = importlib.util.spec_from_file_location("bench_mitsuba", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_quick_run_writes_a_self_describing_json(bench, tmp_path, capsys):
    out = tmp_path / "mitsuba.json"
    args = ["--quick", "--cache", str(tmp_path / "cache"), "--output", str(out)]
    assert bench.main(args) == 0
    results = json.loads(out.read_text())
    assert {"description", "command", "machine", "settings", "scenes"} <= set(results)
    assert results["settings"]["library_defaults"]["AdaptiveSampler"]["initial_spp"] == DEFAULT_AWR_INITIAL_SPP
    (scene,) = results["scenes"]
    assert scene["scene"] == "cornell_box" and scene["reference"]["cached"] is False
    assert scene["throughput"]["ratio"] > 0
    assert [e["spp"] for e in scene["equal_samples"]] == [4, 8]
    for row in scene["equal_samples"]:
        for side in ("uniform", "awr", "awr_plain_mean"):
            assert math.isfinite(row[side]["relmse"]) and row[side]["mse"] > 0
    for run in scene["awr_runs"]:
        assert math.isclose(sum(run["shares"].values()), 1.0)
    # AWR's cheapest run is its first round alone (uniform, then the reconstruction), so equal time
    # has an AWR error from that run's time on, not only from the smallest uniform spp's half.
    assert [(run["spp"], run["rounds"]) for run in scene["awr_runs"]][:2] == [(DEFAULT_AWR_INITIAL_SPP, 1), (4, 3)]
    assert len(scene["equal_time"]) == 2
    assert "| cornell_box |" in capsys.readouterr().out
    # The reference is cached: a second run reads it instead of rendering it again.
    assert bench.main(args) == 0
    assert json.loads(out.read_text())["scenes"][0]["reference"]["cached"] is True
    # --report renders nothing and recomputes the derived tables from the stored points.
    capsys.readouterr()
    assert bench.main(["--report", "--output", str(out)]) == 0
    assert "| plain mean relMSE / MSE ratio |" in capsys.readouterr().out
    assert json.loads(out.read_text())["scenes"][0]["equal_time"][0]["uniform_spp"] == 4


def _quick(bench, tmp_path, *options: str) -> dict:
    """The results of a ``--quick`` run with ``options`` (references cached in ``tmp_path``)."""
    out = tmp_path / f"quick{'_'.join(options)}.json"
    assert bench.main(["--quick", "--cache", str(tmp_path / "cache"), "--output", str(out), *options]) == 0
    return json.loads(out.read_text())


def test_round_growth_reaches_the_sampler_and_is_recorded(bench, tmp_path):
    """``--round-growth`` makes fewer, larger rounds (to 8 spp on the tiny image: 2 at 1.0, 5 at the default)."""
    default, larger = _quick(bench, tmp_path), _quick(bench, tmp_path, "--round-growth", "1.0")
    assert default["settings"]["sampler_options"] == {}
    assert larger["settings"]["sampler_options"] == {"round_growth": 1.0}
    rounds = [{run["spp"]: run["rounds"] for run in r["scenes"][0]["awr_runs"]} for r in (default, larger)]
    assert rounds[1][8] < rounds[0][8]


def test_initial_spp_reaches_the_sampler_and_starts_the_awr_runs(bench, tmp_path):
    """``--initial-spp 4``: the AWR runs start at the sampler's first round of 4 spp (one round), and it is recorded."""
    results = _quick(bench, tmp_path, "--initial-spp", "4")
    assert results["settings"]["sampler_options"] == {"initial_spp": 4}
    assert [(run["spp"], run["rounds"]) for run in results["scenes"][0]["awr_runs"]] == [(4, 1), (8, 5)]
    # Runs are seeded by their spp, not by their place in the list of AWR sample counts (here 4, 8;
    # 2, 4, 8 by default): the uniform renders at 4 and 8 spp are the default run's, error for error.
    default = _quick(bench, tmp_path)
    assert [row["uniform"] for row in results["scenes"][0]["equal_samples"]] == \
        [row["uniform"] for row in default["scenes"][0]["equal_samples"]]


def test_uniform_fraction_reaches_the_sampler_and_is_recorded(bench, tmp_path):
    """``--uniform-fraction 0.3`` (docs/sampling.md, "The share and the image mean"): recorded, and other runs."""
    shared, default = _quick(bench, tmp_path, "--uniform-fraction", "0.3"), _quick(bench, tmp_path)
    assert shared["settings"]["sampler_options"] == {"uniform_fraction": 0.3}
    assert [run["awr"] for run in shared["scenes"][0]["equal_samples"]] != \
        [run["awr"] for run in default["scenes"][0]["equal_samples"]]


@pytest.mark.parametrize("option", [["--spp", "4", "12"], ["--hd-spp", "6"], ["--initial-spp", "3"],
                                    ["--initial-spp", "1"], ["--repeats", "0"], ["--repeats", "999"],
                                    ["--uniform-fraction", "1.5"]])
def test_sample_counts_that_cannot_be_seeded_by_their_spp_are_refused(bench, option, capsys):
    with pytest.raises(SystemExit) as exit_info:
        bench.main(["--quick", *option])
    assert exit_info.value.code == 2
    assert option[0] in capsys.readouterr().err


def test_stages_reach_the_reconstruction_and_are_recorded(bench, tmp_path):
    """``--stages 1``: the AWR runs' reconstruction is stage 1 alone, so their images differ from the default's."""
    default, stage1 = _quick(bench, tmp_path), _quick(bench, tmp_path, "--stages", "1")
    assert default["settings"]["reconstruct_options"] == {}
    assert stage1["settings"]["reconstruct_options"] == {"stages": 1}
    errors = [[(row["awr"]["relmse"], row["awr_plain_mean"]["relmse"]) for row in r["scenes"][0]["equal_samples"]]
              for r in (default, stage1)]
    # The same samples (the sampler does not depend on the reconstruction), other images.
    assert [e[1] for e in errors[0]] == [e[1] for e in errors[1]]
    assert [e[0] for e in errors[0]] != [e[0] for e in errors[1]]
