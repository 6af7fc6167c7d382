"""The benchmark's command line: python -m awr_denoise.bench and awr bench (awr_denoise.bench.command)."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest

from awr_denoise.bench import BenchmarkConfig
from awr_denoise.bench.command import add_arguments, config_from_args, main


def _config(*argv: str) -> BenchmarkConfig:
    return config_from_args(add_arguments(argparse.ArgumentParser()).parse_args(list(argv)))


def test_options_map_onto_the_config():
    assert _config() == BenchmarkConfig()
    quick = _config("--quick", "--scenes", "a", "b", "--spp", "16", "4", "16", "--size", "64", "48",
                    "--overhead-sizes", "--no-oidn", "--reference-spp", "2048")
    assert quick == BenchmarkConfig.quick(scenes=("a", "b"), spps=(4, 16), width=64, height=48, overhead_sizes=(),
                                          oidn=False, reference_spp=2048)


def test_main_rejects_an_unknown_scene(tmp_path, capsys):
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    code = main(["--quick", "--scenes", "no_such_scene", "--output-dir", str(tmp_path), "--quiet", "--no-plots"])
    assert code == 1
    assert "no_such_scene" in capsys.readouterr().err
    assert not (tmp_path / "benchmarks.md").exists()


def test_python_m_awr_denoise_bench_shows_its_help():
    proc = subprocess.run([sys.executable, "-m", "awr_denoise.bench", "--help"], capture_output=True, text=True,
                          check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: python -m awr_denoise.bench") and "--overhead-sizes" in proc.stdout


def test_awr_bench_subcommand_runs_the_benchmark(tmp_path, capsys):
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    from awr_denoise.cli.main import main as awr_main

    code = awr_main(["bench", "--quick", "--scenes", "default", "--size", "16", "16", "--spp", "4",
                     "--overhead-sizes", "--no-oidn", "--no-mitsuba", "--no-plots", "--quiet",
                     "--output-dir", str(tmp_path / "docs"),
                     "--results", str(tmp_path / "q.json")])
    assert code == 0
    assert "default" in capsys.readouterr().out
    assert json.loads((tmp_path / "q.json").read_text())["scenes"]["default"]["methods"]["uniform"]
    page = (tmp_path / "docs" / "benchmarks.md").read_text()
    assert "Headline" in page
    assert "Raw numbers: `q.json`" in page and str(tmp_path) not in page  # never a machine path
    assert awr_main(["bench", "--quick", "--scenes", "nowhere", "--quiet", "--no-plots",
                     "--output-dir", str(tmp_path / "other")]) == 1
