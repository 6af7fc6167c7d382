"""Results files of the benchmarks (awr_denoise.bench.records)."""

from __future__ import annotations

import json
import math

import numpy as np

from awr_denoise.bench import command_line, json_ready, load_average, machine_info, update_section, write_json


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
