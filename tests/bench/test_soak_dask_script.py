"""``benchmarks/soak_dask_worker_loss.py``: frames on a Dask cluster whose worker is killed mid-run."""

from __future__ import annotations

import json

import pytest


def test_a_short_soak_runs_a_child_kills_a_worker_and_records_the_outcome(benchmark_script, tmp_path, capsys):
    pytest.importorskip("distributed")
    pytest.importorskip("psutil")
    soak = benchmark_script("soak_dask_worker_loss")
    out = tmp_path / "soak.json"
    assert soak.main(["--runs", "1", "--frames", "12", "--delay", "0.3", "--timeout", "120",
                      "--output", str(out)]) == 0
    record = json.loads(out.read_text())
    row = record["rows"][0]
    assert record["counts"] == {"ok": 1} and row["all_written"] and row["failed"] == []
    assert "1 runs: {'ok': 1}" in capsys.readouterr().out
