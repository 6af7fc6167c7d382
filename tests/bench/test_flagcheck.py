"""Flags checked over seeds (awr_denoise.bench.flagcheck) on tiny renders of the bundled tracer."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from awr_denoise.bench import BenchmarkConfig
from awr_denoise.bench.analysis import flag_candidates, summarize
from awr_denoise.bench.flagcheck import check_flags

pytestmark = pytest.mark.tracer


def test_a_flagged_method_is_rendered_again_on_the_next_seeds(tiny_run):
    """A row made worse than the plain mean by hand: its check holds the main run's seed as
    recorded and two new seeds, each with finite errors for the method and the plain mean, and the
    reconstruction below the plain mean on the new seeds (this scene is smooth: it always is)."""
    results, _ = tiny_run
    results = copy.deepcopy(results)
    config = BenchmarkConfig(**results["meta"]["config"])
    assert config.flag_seeds == 3
    name = next(iter(results["scenes"]))
    rows = results["scenes"][name]["methods"]
    row = next(r for r in rows["uniform+awr"] if r["spp"] == 4)
    plain = next(r for r in rows["uniform"] if r["spp"] == 4)
    row["mse"] = 2.0 * plain["mse"]
    assert flag_candidates(results) == [(name, "uniform+awr", 4)]
    checks = check_flags(results, config)
    assert len(checks) == 1
    check = checks[0]
    assert check["seeds"] == [0, 1, 2] and check["mse"][0] == row["mse"] and check["plain_mse"][0] == plain["mse"]
    for key in ("relmse", "mse"):
        assert np.all(np.isfinite(check[key])) and np.all(np.isfinite(check[f"plain_{key}"]))
        assert all(a < b for a, b in zip(check[key][1:], check[f"plain_{key}"][1:]))
    results["flag_checks"] = checks
    summary = summarize(results, config)
    assert summary["flags"] == [] and len(summary["flags_not_confirmed"]) == 1
    assert "over seeds 0-2" in summary["flags_not_confirmed"][0]


def test_the_main_run_checked_what_it_flagged(tiny_run):
    results, _ = tiny_run
    assert [(c["scene"], c["method"], c["spp"]) for c in results["flag_checks"]] == flag_candidates(results)
