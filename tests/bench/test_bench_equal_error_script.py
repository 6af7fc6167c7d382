"""``benchmarks/bench_equal_error.py``: AWR sampling's equal-error spp at 32 spp over render seeds."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("embreex", reason="the bundled tracer needs the extra `tracer` (embreex)")


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_equal_error")


@pytest.fixture(scope="module")
def run(bench, tmp_path_factory):
    out = tmp_path_factory.mktemp("equal_error") / "equal_error.json"
    argv = ["--scenes", "default", "--seeds", "0", "1", "--size", "16", "--uniform-max-spp", "128",
            "--output", str(out)]
    assert bench.main(argv) == 0
    return json.loads(out.read_text())["seeds"]


def test_each_seed_is_rendered_with_its_own_samples_and_uniform_curve(run):
    rows = run["rows"]
    assert [(r["scene"], r["seed"]) for r in rows] == [("default", 0), ("default", 1)]
    assert [s for s, _ in rows[0]["uniform_curve"]] == [4, 8, 16, 32, 64, 128]
    assert rows[0]["uniform_curve"] != rows[1]["uniform_curve"]
    assert rows[0]["default"]["relmse"] != rows[1]["default"]["relmse"]
    for row in rows:
        for sampler in ("default", "relative error alone"):
            assert 0 < row[sampler]["relmse"] and np.isfinite(row[sampler]["mse"])


def test_the_equal_error_spp_is_the_benchmarks_on_the_seeds_own_curve(bench, run):
    """The same floor-corrected interpolation as ``awr bench``: recomputed from the stored curve, it agrees."""
    from awr_denoise.bench.analysis import equal_error_spp, fit_noise_floor
    for row in run["rows"]:
        spps, errors = zip(*row["uniform_curve"])
        slope, floor = fit_noise_floor(spps, errors)
        assert (slope, floor) == pytest.approx((row["slope"], row["floor"]))
        expected, _ = equal_error_spp(row["default"]["relmse"] - floor, spps, [e - floor for e in errors], slope)
        assert row["default"]["equal_error_spp"] == pytest.approx(expected)


def test_the_table_gives_each_seed_and_the_means(bench):
    def row(seed, spp, alone, mse_ratio):
        return {"scene": "s", "seed": seed, "default": {"equal_error_spp": spp, "mse": 1.0},
                "relative error alone": {"equal_error_spp": alone, "mse": mse_ratio}}
    text = bench.table([row(0, 200.0, 210.0, 2.0), row(3, 100.0, 90.0, 4.0)])
    assert text.splitlines()[0].startswith("| scene | seed 0 | seed 3 | mean |")
    assert "| s | 200 (210) | 100 (90) | 150 | 150 | 3.00 |" in text


def test_a_uniform_curve_short_of_the_adaptive_spp_is_refused(bench, capsys):
    with pytest.raises(SystemExit) as err:
        bench.main(["--uniform-max-spp", "32"])
    assert err.value.code == 2 and "--uniform-max-spp must be at least 64" in capsys.readouterr().err


@pytest.fixture(scope="module")
def variant_rows(bench, run, tmp_path_factory):
    out = tmp_path_factory.mktemp("variants") / "equal_error.json"
    out.write_text(json.dumps({"seeds": run}))
    argv = ["--variants", "--scenes", "default", "--seeds", "0", "--size", "16", "--output", str(out)]
    assert bench.main(argv) == 0
    return json.loads(out.read_text())["variants"]["rows"]


def test_variants_try_every_option_on_the_stored_seeds_curve(bench, run, variant_rows):
    from awr_denoise.bench.analysis import equal_error_spp
    assert [r["variant"] for r in variant_rows] == (["default"] + list(bench.RECONSTRUCTIONS)
                                                    + list(bench.SAMPLERS_AROUND))
    stored = run["rows"][0]
    assert variant_rows[0]["relmse"] == pytest.approx(stored["default"]["relmse"], rel=1e-9)
    spps, errors = zip(*stored["uniform_curve"])
    for row in variant_rows:
        expected, _ = equal_error_spp(row["relmse"] - stored["floor"], spps, [e - stored["floor"] for e in errors],
                                      stored["slope"])
        assert row["equal_error_spp"] == pytest.approx(expected)
    # The options change the images: each its own error (stages=2 drops a Wiener stage, levels another model).
    by = {r["variant"]: r["relmse"] for r in variant_rows}
    assert by["stages=2"] != by["default"] != by["noise_model=levels"]


def test_variants_refuse_a_stored_run_of_other_samples(bench, run, tmp_path):
    out = tmp_path / "equal_error.json"
    out.write_text(json.dumps({"seeds": run}))
    with pytest.raises(SystemExit, match="default seed 0: the default's relMSE .* is not the stored"):
        bench.main(["--variants", "--scenes", "default", "--seeds", "0", "--size", "24", "--output", str(out)])


def test_variants_without_a_stored_run_are_refused(bench, tmp_path, capsys):
    with pytest.raises(SystemExit) as err:
        bench.main(["--variants", "--output", str(tmp_path / "none.json")])
    assert err.value.code == 2 and "holds no stored seed" in capsys.readouterr().err


def test_the_variants_table_gives_mean_spp_and_mse_over_the_defaults(bench):
    def row(variant, seed, spp, mse):
        kind = "default" if variant == "default" else "sampler"
        return {"scene": "s", "seed": seed, "kind": kind, "variant": variant, "equal_error_spp": spp, "mse": mse}
    text = bench.variants_table([row("default", 0, 200.0, 1.0), row("default", 1, 100.0, 2.0),
                                 row("x", 0, 220.0, 0.5), row("x", 1, 120.0, 3.0)])
    assert "| default | 150 (1.00) |" in text and "| x | 170 (1.00) |" in text


@pytest.fixture(scope="module")
def baseline_rows(bench, run, tmp_path_factory):
    if not bench.has_commit(bench.BASELINE):
        pytest.skip(f"the baseline commit {bench.BASELINE[:7]} is not in this checkout's history (a shallow clone)")
    out = tmp_path_factory.mktemp("baseline") / "equal_error.json"
    out.write_text(json.dumps({"seeds": run}))
    argv = ["--baseline", "--scenes", "default", "--seeds", "0", "1", "--size", "16", "--output", str(out)]
    assert bench.main(argv) == 0
    return json.loads(out.read_text())["baseline"]["rows"]


def test_the_baseline_runs_the_goals_version_on_the_stored_seeds_curves(bench, run, baseline_rows):
    """The goal's version samples and reconstructs (its own code: another error than this version's on the same
    seed), measured on each seed's stored curve, beside this version's stored figure."""
    from awr_denoise.bench.analysis import equal_error_spp
    assert [(r["scene"], r["seed"], r["commit"]) for r in baseline_rows] == [("default", 0, bench.BASELINE),
                                                                             ("default", 1, bench.BASELINE)]
    for row, stored in zip(baseline_rows, run["rows"]):
        assert row["this_version"] == stored["default"]["equal_error_spp"]
        assert row["relmse"] != pytest.approx(stored["default"]["relmse"], rel=1e-3)
        spps, errors = zip(*stored["uniform_curve"])
        expected, _ = equal_error_spp(row["relmse"] - stored["floor"], spps, [e - stored["floor"] for e in errors],
                                      stored["slope"])
        assert row["equal_error_spp"] == pytest.approx(expected)
    assert baseline_rows[0]["relmse"] != baseline_rows[1]["relmse"]


def test_the_baseline_table_gives_both_versions_and_their_ratios(bench):
    rows = [{"scene": "s", "seed": 0, "equal_error_spp": 100.0, "this_version": 200.0, "mse": 2.0,
             "this_version_mse": 1.0},
            {"scene": "s", "seed": 2, "equal_error_spp": 50.0, "this_version": 125.0, "mse": 1.0,
             "this_version_mse": 1.0}]
    text = bench.baseline_table(rows)
    assert text.splitlines()[0].startswith("| scene | seed 0 | seed 2 | mean | ratio of the means |")
    assert "| s | 100 -> 200 | 50 -> 125 | 75 -> 162 | 2.17 | 2.00-2.50 | 0.75 |" in text


def test_a_baseline_not_in_the_history_is_refused_by_name(bench, capsys):
    with pytest.raises(SystemExit) as err:
        bench.main(["--baseline", "0" * 40])
    assert err.value.code == 2 and f"--baseline: {'0' * 40} is not a commit" in capsys.readouterr().err
