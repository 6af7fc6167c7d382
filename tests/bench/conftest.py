"""A tiny benchmark run shared by the tests of the runner, the figures and the page."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from awr_denoise.bench import BenchmarkConfig

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
