"""Results files of the benchmarks (awr_denoise.bench.records)."""

from __future__ import annotations

import argparse
import json
import math
import os

import numpy as np
import pytest

from awr_denoise.bench import command_line, json_ready, load_average, machine_info, records, update_section, write_json


def test_json_ready_makes_numpy_and_non_finite_values_portable():
    data = {"a": np.float32(0.5), 2: (np.int64(3), np.bool_(False)), "x": [float("nan"), -np.inf, 1.0]}
    ready = json_ready(data)
    assert ready == {"a": 0.5, "2": [3, False], "x": ["nan", "-inf", 1.0]}
    assert type(ready["a"]) is float and type(ready["2"][0]) is int and type(ready["2"][1]) is bool
    text = json.dumps(ready, allow_nan=False)  # strict JSON: no NaN or Infinity tokens
    assert math.isnan(float(json.loads(text)["x"][0]))


def test_write_json_creates_the_directory_and_ends_with_a_newline(tmp_path):
    path = write_json(tmp_path / "a" / "b" / "r.json", {"spp": np.int64(4), "inf": float("inf")}, indent=2)
    text = path.read_text()
    assert text.endswith("}\n") and json.loads(text) == {"spp": 4, "inf": "inf"}
    assert text.startswith('{\n  "spp"')


def test_machine_info_names_the_software_versions():
    info = machine_info("numpy", "no-such-distribution-xyz")
    assert info["numpy"] == np.__version__
    assert info["no-such-distribution-xyz"] == "missing"
    assert info["cpus"] >= 1 and info["python"].count(".") == 2


def test_load_average_and_command_line():
    load = load_average()
    assert load is None or (len(load) == 3 and all(v >= 0 for v in load))
    assert command_line("benchmarks/bench_core.py", []) == "python benchmarks/bench_core.py"
    assert command_line("s.py", ["--quick", "--seed", "7"]) == "python s.py --quick --seed 7"


def test_a_section_goes_to_its_file_and_the_others_stay(tmp_path):
    """``bench_reconstruct.py`` and ``bench_guides.py --output FILE``: a trial run of one section
    rewrote the tracked results; each section is now replaced alone, in the file named."""
    stored = write_json(tmp_path / "stored.json", {"quality": {"command": "stored", "rows": [1]}})
    before = stored.read_bytes()
    trial = write_json(tmp_path / "trial.json", {"seeds": {"command": "kept", "rows": []}})
    update_section(trial, "quality", [{"scene": "s"}], "bench.py quality --output trial.json", "pyoidn")
    data = json.loads(trial.read_text())
    assert data["seeds"] == {"command": "kept", "rows": []}
    assert data["quality"]["rows"] == [{"scene": "s"}] and data["quality"]["command"].endswith("trial.json")
    assert "pyoidn" in data["quality"]["machine"] and stored.read_bytes() == before


def test_a_results_file_written_part_way_keeps_the_old_one(tmp_path, monkeypatch):
    """A run killed while it wrote its results left the file empty: every section of it lost."""
    path = records.write_json(tmp_path / "r.json", {"old": {"rows": [1]}})
    from awr_denoise.io import atomic
    monkeypatch.setattr(atomic, "_install", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        records.update_section(path, "new", [2], "bench.py new")
    assert json.loads(path.read_text()) == {"old": {"rows": [1]}}
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


@pytest.mark.parametrize("rows", [[], None, {}])
def test_a_section_of_no_rows_is_refused_and_the_stored_one_kept(tmp_path, rows):
    """A misspelt ``--scenes`` name measured nothing, and the stored section was replaced by none."""
    path = records.write_json(tmp_path / "r.json", {"quality": {"rows": [1, 2]}})
    with pytest.raises(ValueError, match=r"quality: nothing was measured; .*r\.json keeps its section"):
        records.update_section(path, "quality", rows, "bench.py quality --scenes defualt")
    assert json.loads(path.read_text()) == {"quality": {"rows": [1, 2]}}


@pytest.mark.parametrize("content, message", [
    ("[]", "not a results file"), ("{\"a\": ", "cannot be read as a results file"),
    (b"\xff\xfe", "cannot be read as a results file")])
def test_a_results_file_that_is_not_one_is_refused_before_the_run(tmp_path, content, message):
    path = tmp_path / "r.json"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(argparse.ArgumentTypeError, match=message):
        records.results_file(str(path))


def test_a_folder_or_a_file_as_its_folder_is_refused_and_a_new_file_taken(tmp_path):
    with pytest.raises(argparse.ArgumentTypeError, match="a folder, not a results file"):
        records.results_file(str(tmp_path))
    (tmp_path / "plain").write_text("x")
    with pytest.raises(argparse.ArgumentTypeError, match="is not a folder"):
        records.results_file(str(tmp_path / "plain" / "r.json"))
    assert records.results_file(str(tmp_path / "new" / "r.json")) == tmp_path / "new" / "r.json"
    assert records.results_file(str(records.write_json(tmp_path / "ok.json", {"a": 1}))).name == "ok.json"


def test_an_empty_file_is_a_new_results_file(tmp_path):
    """``--output $(mktemp)``: an empty file the script would simply have written."""
    path = tmp_path / "r.json"
    path.write_text("")
    assert records.results_file(str(path)) == path
    records.update_section(path, "new", [1], "bench.py new")
    assert json.loads(path.read_text())["new"]["rows"] == [1]


def test_results_and_caches_get_the_mode_of_a_new_file(tmp_path):
    """Written through a temporary of mode 0600, a results file other users read and a shared cache folder were
    closed to them."""
    from awr_denoise.bench import cache
    old = os.umask(0o022)
    try:
        written = [records.write_json(tmp_path / "r.json", {"a": 1}), cache.save_arrays(tmp_path / "c.npz", {"a": [1]}),
                   cache.save_arrays(tmp_path / "ref.npy", np.zeros(2))]
    finally:
        os.umask(old)
    assert [oct(p.stat().st_mode & 0o777) for p in written] == ["0o644"] * 3
