"""The benchmark run end to end on tiny renders (awr_denoise.bench.runner).

Exercises the whole pipeline (tracer, samplers, reconstruction, peers, noise floor, equal-error
spp, JSON, figures and the markdown page) at 32x32 and a few spp, writing into a temporary
directory. Quality check: AWR's relMSE is below uniform Monte Carlo's at equal samples on the
smooth-dominated scenes. No timing assertions.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from awr_denoise.bench import BenchmarkConfig

from .conftest import SMOOTH_SCENES

pytestmark = pytest.mark.tracer


def test_benchmark_pipeline_on_tiny_scenes(tiny_run):
    results, out = tiny_run
    saved = json.loads((out / "results" / "quality.json").read_text())
    assert set(saved["scenes"]) == set(SMOOTH_SCENES)
    page = (out / "docs" / "benchmarks.md").read_text()
    assert "Headline" in page and "soft_shadows" in page
    for name in SMOOTH_SCENES:
        scene = results["scenes"][name]
        assert scene["reference"]["spp"] == 256
        assert [r["spp"] for r in scene["uniform_curve"]] == [4, 8, 16, 32]
        methods = scene["methods"]
        assert set(methods) == {"uniform", "uniform+awr", "awr+awr", "awr-levels+awr", "awr-gain+awr", "variance+awr",
                                "uniform+skimage"}
        for spp in (4, 8):
            mc = next(r for r in methods["uniform"] if r["spp"] == spp)
            for method in ("uniform+awr", "awr+awr", "awr-gain+awr"):
                row = next(r for r in methods[method] if r["spp"] == spp)
                assert row["relmse"] < mc["relmse"], (name, method, spp)
                assert np.isfinite(row["psnr"]) and 0 < row["ssim"] <= 1
            # The uniform curve and its own equal-error spp agree where it was rendered.
            assert mc["equal_error_spp"] == pytest.approx(spp, rel=0.15)
        domains = {r["domain"] for r in scene["c_s_sweep"]}
        assert domains == {"mean", "linear", "log", "gamma", "log robust"}


def test_json_holds_no_non_finite_numbers(tiny_run):
    _, out = tiny_run
    text = (out / "results" / "quality.json").read_text()
    json.loads(text, parse_constant=lambda name: pytest.fail(f"{name} in the JSON"))


def test_unknown_scene_is_a_value_error_naming_it(tmp_path):
    pytest.importorskip("embreex")
    from awr_denoise.bench import run_benchmark

    with pytest.raises(ValueError, match="no_such_scene"):
        run_benchmark(BenchmarkConfig(scenes=("no_such_scene",)), output_dir=tmp_path, progress=False)
    assert not any(tmp_path.iterdir())


def _interrupted_in_the_figures(monkeypatch) -> BenchmarkConfig:
    """The smallest run that writes the JSON, the figures and the page, with a Ctrl-C once the JSON and
    two figures are written (the third figure interrupted)."""
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    pytest.importorskip("matplotlib")
    from awr_denoise.bench import figures

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(figures, "_density", interrupted)
    return BenchmarkConfig.quick(scenes=("default",), width=16, height=16, spps=(4,), uniform_max_spp=8,
                                 inline_reference_spp=16, sweep_spp=4, sweep_seeds=2, c_s_values=(1.0,),
                                 overhead_sizes=(), oidn=False, mitsuba=False, flag_seeds=1)


def test_an_interrupt_while_the_outputs_are_written_leaves_the_old_ones(tmp_path, monkeypatch):
    """The JSON, the figures and the page are replaced together or not at all."""
    from awr_denoise.bench import run_benchmark

    kwargs = dict(output_dir=tmp_path / "docs", results_path=tmp_path / "q.json", progress=False)
    with monkeypatch.context() as undone:  # a first, whole run: the old outputs
        config = _interrupted_in_the_figures(undone)
    run_benchmark(config, **kwargs)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert len(before) >= 3
    _interrupted_in_the_figures(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        run_benchmark(dataclasses.replace(config, seed=1), **kwargs)
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before  # no temporary left either


def test_an_interrupt_while_the_outputs_are_written_removes_the_folders_it_made(tmp_path, monkeypatch):
    """New output folders (the results' and the page's, its img/) were left behind, empty, when the run
    stopped while writing into them (a red-team pass: 8 of 18 interrupts in that phase)."""
    from awr_denoise.bench import run_benchmark

    config = _interrupted_in_the_figures(monkeypatch)
    (tmp_path / "kept").mkdir()
    with pytest.raises(KeyboardInterrupt):
        run_benchmark(config, output_dir=tmp_path / "n1" / "docs", results_path=tmp_path / "n2" / "q.json",
                      progress=False)
    with pytest.raises(KeyboardInterrupt):
        run_benchmark(config, output_dir=tmp_path / "kept" / "docs", results_path=tmp_path / "kept" / "q.json",
                      progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept"] and not any((tmp_path / "kept").iterdir())
