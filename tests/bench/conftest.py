"""A tiny benchmark run shared by the tests of the runner, the figures and the page, and the loader of
the scripts in ``benchmarks/`` that the script tests import."""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from awr_denoise.bench import BenchmarkConfig

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def _load_script(name: str) -> ModuleType:
    """``benchmarks/<name>.py`` as a fresh module (the scripts put their own folder on ``sys.path``
    where they import a sibling)."""
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def benchmark_script() -> Callable[[str], ModuleType]:
    """The loader of a script in ``benchmarks/`` by name: ``benchmark_script("bench_core")``."""
    return _load_script


STORED = '{"quality": {"rows": [1]}}\n'
"""A results file's stored section, which a refused run must leave as it was."""


def refused_before_any_work(main: Callable[[list[str]], int], argv: list[str], message: str, tmp_path: Path,
                            capsys: pytest.CaptureFixture[str], stored: str = STORED) -> None:
    """A script's ``main(argv)`` with ``--output`` a results file holding ``stored`` and ``--cache`` a folder not
    yet made exits 2 with ``message`` on stderr, the results file as it was and no cache made."""
    results = tmp_path / "r.json"
    results.write_text(stored)
    with pytest.raises(SystemExit) as stop:
        main([*argv, "--output", str(results), "--cache", str(tmp_path / "cache")])
    assert stop.value.code == 2 and message in capsys.readouterr().err
    assert results.read_text() == stored and not (tmp_path / "cache").exists()


SMOOTH_SCENES = ("soft_shadows", "cornell_gi")
"""Smooth-dominated scenes (large smooth, noisy regions), where AWR gains the most in
docs/benchmarks.md: its relMSE must be below uniform Monte Carlo's there even at 32x32."""


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path]:
    """``run_benchmark`` at 32x32 and a few spp on the smooth scenes: (results, output directory)."""
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    pytest.importorskip("matplotlib")
    from awr_denoise.bench import run_benchmark

    out = tmp_path_factory.mktemp("bench")
    config = BenchmarkConfig.quick(scenes=SMOOTH_SCENES, width=32, height=32, spps=(4, 8), uniform_max_spp=32,
                                   inline_reference_spp=256, sweep_spp=8, sweep_seeds=2, c_s_values=(0.5, 1.0, 4.0),
                                   overhead_sizes=(), oidn=False, mitsuba=False)
    results = run_benchmark(config, output_dir=out / "docs", results_path=out / "results" / "quality.json",
                            progress=False, mode_name="test")
    return results, out
