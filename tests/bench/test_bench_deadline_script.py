"""``benchmarks/bench_deadline.py``: AWR under a time budget against uniform sampling in the same time."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from awr_denoise import rounds


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_deadline")


@pytest.fixture(scope="module")
def rows(bench, tmp_path_factory):
    out = tmp_path_factory.mktemp("deadline") / "deadline.json"
    assert bench.main(["--renderers", "synthetic", "--spps", "1", "256", "--output", str(out)]) == 0
    return json.loads(out.read_text())["deadline"]["rows"]


def test_each_budget_is_the_uniform_renders_time_and_each_sizing_runs_within_reach_of_it(bench, rows):
    assert [(r["scene"], r["uniform_spp"]) for r in rows] == [("edges", 1), ("edges", 256)]
    short, long = rows
    # 1 spp renders in far less time than a reconstruction takes: nothing fits.
    assert short["seconds"] < short["reconstruction_seconds"] and short["awr"] == {}
    assert long["seconds"] > long["reconstruction_seconds"] and list(long["awr"]) == list(bench.SIZINGS)
    for run in long["awr"].values():
        assert len(run["repeats"]) == 3  # the default --repeats, their medians beside them
        assert run["relmse_ratio"] == sorted(r["relmse_ratio"] for r in run["repeats"])[1]
        assert run["rounds"] >= 1 and run["spp"] >= 2 and run["largest_round_spp"] <= run["spp"]
        assert run["run_seconds"] <= run["seconds"]
        assert math.isfinite(run["relmse_ratio"]) and math.isfinite(run["mse_ratio"]) and run["mse_ratio"] > 0
        assert 0 <= run["mean_error"] < 100
    assert long["uniform_relmse"] < short["uniform_relmse"]


def test_the_sizings_set_the_libraries_share_and_put_it_back(bench):
    library = rounds.ROUND_OVERHEAD
    for share in bench.SIZINGS.values():
        with bench.overhead_share(share):
            assert rounds.ROUND_OVERHEAD == (library if share is None else share)
        assert rounds.ROUND_OVERHEAD == library
    with pytest.raises(RuntimeError), bench.overhead_share(0.5):
        raise RuntimeError
    assert rounds.ROUND_OVERHEAD == library


def test_the_table_gives_every_sizing_or_na(bench):
    run = {"spp": 12.34, "rounds": 3, "seconds": 0.9, "relmse_ratio": 0.5, "mse_ratio": 0.25, "mean_error": 0.125}
    text = bench.table([
        {"renderer": "r", "scene": "s", "uniform_spp": 64, "seconds": 1.0, "uniform_mean_error": 1.5,
         "awr": {k: run for k in bench.SIZINGS}},
        {"renderer": "r", "scene": "s", "uniform_spp": 8, "seconds": 0.1, "uniform_mean_error": 2.0, "awr": {}}])
    assert "| r | s | 64 | 1.000 | 1.50 | 12.3, 3, 0.90, 0.50, 0.25, 0.12 |" in text
    assert "| r | s | 8 | 0.100 | 2.00 | " + " | ".join(["n/a"] * len(bench.SIZINGS)) + " |" in text


def test_the_mean_error_is_the_worst_channels_in_per_cent(bench):
    reference = np.ones((2, 2, 3))
    image = reference * np.array([1.0, 1.02, 0.97])
    assert bench.mean_error(image, reference) == pytest.approx(3.0)


def test_a_size_with_the_tracers_fixed_references_is_refused(bench, capsys):
    with pytest.raises(SystemExit) as err:
        bench.main(["--renderers", "tracer", "--size", "64"])
    assert err.value.code == 2 and "--size" in capsys.readouterr().err


def test_costs_time_round_0s_samples_the_ranked_ones_and_the_ranking(bench, tmp_path):
    out = tmp_path / "costs.json"
    assert bench.main(["--renderers", "synthetic", "--costs", "--repeats", "2", "--output", str(out)]) == 0
    (row,) = json.loads(out.read_text())["costs"]["rows"]
    assert (row["renderer"], row["scene"], row["shape"]) == ("synthetic", "edges", [32, 32])
    assert row["samples"] == 2 * 32 * 32  # round 0 at the sampler's 2 spp, and the ranked request of as many
    assert set(row["per_sample"]) == {"uniform", "ranked", "ranked, shuffled"}
    assert all(t > 0 for t in row["per_sample"].values())
    assert row["ranked_over_uniform"] == row["per_sample"]["ranked"] / row["per_sample"]["uniform"]
    assert row["ranking_seconds"] > 0 and row["round0_render_seconds"] > 0
    assert "| synthetic | edges | 32x32 | " in bench.costs_table([row])


def test_stages_reconstructs_with_them_and_reserves_their_time(bench, tmp_path, monkeypatch):
    seen = []
    real = bench.reconstruct
    monkeypatch.setattr(bench, "reconstruct", lambda buffer, **options: seen.append(options) or real(buffer, **options))
    out = tmp_path / "stages.json"
    assert bench.main(["--renderers", "synthetic", "--spps", "256", "--stages", "1", "--repeats", "1",
                       "--output", str(out)]) == 0
    (row,) = json.loads(out.read_text())["deadline"]["rows"]
    assert row["stages"] == 1 and row["awr"]
    assert seen and all(options == {"stages": 1} for options in seen)  # t_rec's three and every run's


@pytest.mark.parametrize("argv", [["--scenes", "defualt"], ["--costs", "--scenes", "defualt"],
                                  ["--renderers", "tracer", "--scenes", "cornell_box"]])
def test_a_scene_of_none_of_the_renderers_is_refused_up_front(bench, tmp_path, capsys, argv):
    """A misspelt scene printed an empty table, exit 0, or (``--costs``) failed after its work."""
    with pytest.raises(SystemExit) as stop:
        bench.main([*argv, "--output", str(tmp_path / "d.json")])
    assert stop.value.code == 2 and "--scenes: " in capsys.readouterr().err
    assert not (tmp_path / "d.json").exists()
