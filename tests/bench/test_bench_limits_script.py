"""``benchmarks/bench_limits.py``: the synthetic inputs where the default loses to the plain mean."""

from __future__ import annotations

import json

import numpy as np
import pytest


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_limits")


def test_each_case_makes_the_image_it_describes(bench):
    rng = np.random.default_rng(0)
    truth, buffer = bench.glints(4, rng)
    assert (truth > 4).all(axis=2).sum() == 30 and buffer.count.min() == 4
    truth, buffer = bench.hit_or_zero(0.1)(8, rng)
    assert (truth == 0.3).all() and set(np.unique(buffer.count)) == {8}
    assert abs(buffer.mean.mean() - 0.3) < 0.05  # hits of 3 in a tenth of the samples: unbiased
    truth, _ = bench.dark_line(10.0)(8, rng)
    assert (truth[:, 32] == 0.01).all() and (np.delete(truth, 32, axis=1) == 10.0).all()


def test_the_light_on_black_and_the_rims_lend_column(bench):
    """A disc of 100 on exact black whose rim is hit or missed; "rims lend" is the default before the rim stopped
    lending its spread (a halo in the black beside it), and puts ``rims.EDGE_BLOCK`` back."""
    from awr_denoise import reconstruct, rims
    truth, buffer = bench.light_on_black(0.0)(4, np.random.default_rng(0))
    assert truth.max() == 100.0 and truth.min() == 0.0 and ((truth > 0) & (truth < 100)).any()
    assert ((buffer.variance > 0) & (buffer.mean < 100)).any()  # a rim: hits and misses
    black = (buffer.mean[..., 0] == 0) & (buffer.variance[..., 0] == 0)
    assert reconstruct(buffer)[black].max() == 0.0
    assert bench.rims_lend(buffer)[black].max() > 1.0
    assert rims.EDGE_BLOCK == 2


def test_a_short_run_records_every_case_and_prints_its_table(bench, tmp_path, capsys):
    out = tmp_path / "limits.json"
    assert bench.main(["--seed-scale", "0.01", "--output", str(out)]) == 0
    rows = json.loads(out.read_text())["limits"]["rows"]
    assert {r["case"] for r in rows} == {name for name, *_ in bench.CASES}
    assert {r["method"] for r in rows} == {"plain", *bench.METHODS, *bench.CHANCES, "rims lend"}
    assert all(np.isfinite(r["mse"]) and np.isfinite(r["relmse"]) for r in rows)
    printed = capsys.readouterr().out
    assert all(f"| {name} |" in printed for name, *_ in bench.CASES)


def test_the_chance_columns_set_the_clamps_chance_and_put_it_back(bench, tmp_path, capsys):
    """"clamp pools every neighbour" is the default with ``finishing.POOL_CHANCE`` 0 (the form before); ``--chances``
    adds smaller chances; the module's value is the default's again afterwards."""
    from awr_denoise import finishing, reconstruct
    truth, buffer = bench.dark_line(100.0)(8, np.random.default_rng(0))
    assert np.array_equal(bench.at_chance(buffer, finishing.POOL_CHANCE), reconstruct(buffer))
    every = bench.at_chance(buffer, 0.0)
    assert finishing.POOL_CHANCE == 1e-3
    assert np.mean((every - truth) ** 2 / (truth**2 + 0.01)) > 10 * np.mean((reconstruct(buffer) - truth) ** 2
                                                                            / (truth**2 + 0.01))
    out = tmp_path / "limits.json"
    assert bench.main(["--seed-scale", "0.01", "--chances", "--output", str(out)]) == 0
    rows = json.loads(out.read_text())["limits"]["rows"]
    assert {r["method"] for r in rows} == {"plain", *bench.METHODS, *bench.CHANCES, *bench.MORE_CHANCES, "rims lend"}
    assert "pool chance 1e-5: MSE, relMSE / plain (worst render)" in capsys.readouterr().out


@pytest.mark.parametrize("scale", ["nan", "inf", "0", "-1", "x"])
def test_a_seed_scale_that_is_not_a_finite_number_above_0_is_refused_up_front(bench, tmp_path, capsys, scale):
    """NaN and infinity failed after the work with a traceback; -1 ran one seed a case, exit 0."""
    with pytest.raises(SystemExit) as stop:
        bench.main(["--seed-scale", scale, "--output", str(tmp_path / "l.json")])
    assert stop.value.code == 2 and "argument --seed-scale" in capsys.readouterr().err
    assert not (tmp_path / "l.json").exists()
