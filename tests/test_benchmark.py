"""Smoke test of the speed/accuracy benchmark (awr_denoise.benchmark) on tiny renders.

Exercises the whole pipeline (tracer, samplers, reconstruction, peers, noise floor, equal-error
spp, JSON, figures and the markdown page) at 32x32 and a few spp, writing into a temporary
directory. Quality check: AWR's relMSE is below uniform Monte Carlo's at equal samples on the
smooth-dominated scenes (soft_shadows and cornell_gi: large smooth, noisy regions; chosen from
docs/benchmarks.md, where AWR gains the most on them). No timing assertions.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from awr_denoise.benchmark import BenchmarkConfig, equal_error_spp, fit_noise_floor, main

SMOOTH_SCENES = ("soft_shadows", "cornell_gi")


def test_fit_noise_floor_recovers_a_and_f():
    n = np.array([4, 8, 16, 32, 64, 128, 256, 512, 1024], dtype=float)
    a, f = fit_noise_floor(n, 0.2 / n + 1e-4)
    assert a == pytest.approx(0.2, rel=1e-6)
    assert f == pytest.approx(1e-4, rel=1e-6)
    a, f = fit_noise_floor(n, 0.2 / n)
    assert f == pytest.approx(0.0, abs=1e-12)


def test_equal_error_spp_interpolates_in_log_log_and_extrapolates():
    n = np.array([4.0, 8.0, 16.0, 32.0])
    u = 0.4 / n
    spp, extrapolated = equal_error_spp(0.4 / 11.0, n, u, 0.4)
    assert spp == pytest.approx(11.0, rel=1e-9) and not extrapolated
    spp, extrapolated = equal_error_spp(0.4 / 100.0, n, u, 0.4)
    assert spp == pytest.approx(100.0) and extrapolated
    spp, extrapolated = equal_error_spp(-1e-5, n, u, 0.4)
    assert spp == float("inf") and extrapolated


@pytest.mark.tracer
def test_benchmark_pipeline_on_tiny_scenes(tmp_path):
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    pytest.importorskip("matplotlib")
    from awr_denoise.benchmark import run_benchmark

    config = BenchmarkConfig.quick(scenes=SMOOTH_SCENES, width=32, height=32, spps=(4, 8), uniform_max_spp=32,
                                   inline_reference_spp=256, sweep_spp=8, sweep_seeds=2, c_s_values=(0.5, 1.0, 4.0),
                                   overhead_sizes=(), oidn=False)
    results_path = tmp_path / "results" / "quality.json"
    results = run_benchmark(config, output_dir=tmp_path / "docs", results_path=results_path, progress=False,
                            mode_name="test")

    saved = json.loads(results_path.read_text())
    assert set(saved["scenes"]) == set(SMOOTH_SCENES)
    page = (tmp_path / "docs" / "benchmarks.md").read_text()
    assert "Headline" in page and "soft_shadows" in page
    for name in ("bench_error_vs_spp.png", "bench_error_vs_time.png", "bench_density.png", "bench_crops.png",
                 "bench_cs_relmse.png", "bench_domain_crops.png"):
        assert (tmp_path / "docs" / "img" / name).stat().st_size > 1000
    for name in SMOOTH_SCENES:
        scene = results["scenes"][name]
        assert scene["reference"]["spp"] == 256
        assert [r["spp"] for r in scene["uniform_curve"]] == [4, 8, 16, 32]
        methods = scene["methods"]
        assert set(methods) == {"uniform", "uniform+awr", "awr+awr", "variance+awr", "uniform+skimage"}
        for spp in (4, 8):
            mc = next(r for r in methods["uniform"] if r["spp"] == spp)
            for method in ("uniform+awr", "awr+awr"):
                row = next(r for r in methods[method] if r["spp"] == spp)
                assert row["relmse"] < mc["relmse"], (name, method, spp)
                assert np.isfinite(row["psnr"]) and 0 < row["ssim"] <= 1
            # The uniform curve and its own equal-error spp agree where it was rendered.
            assert mc["equal_error_spp"] == pytest.approx(spp, rel=0.15)
        domains = {r["domain"] for r in scene["c_s_sweep"]}
        assert domains == {"mean", "linear", "log", "gamma", "log robust"}


def test_main_rejects_an_unknown_scene(tmp_path, capsys):
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    code = main(["--quick", "--scenes", "no_such_scene", "--output-dir", str(tmp_path), "--quiet", "--no-plots"])
    assert code == 1
    assert "no_such_scene" in capsys.readouterr().err
    assert not (tmp_path / "benchmarks.md").exists()


def test_oidn_peer_denoises_a_noisy_hdr_image():
    from awr_denoise.benchmark import oidn_available, oidn_denoise

    if not oidn_available():
        pytest.skip("pyoidn is not installed (extra 'oidn')")
    rng = np.random.default_rng(3)
    y, x = np.mgrid[0:64, 0:64] / 64.0
    clean = np.stack([1.0 + x, 0.5 + 0.5 * y, 2.0 * np.ones_like(x)], axis=-1)
    noisy = clean * rng.gamma(4.0, 0.25, clean.shape)  # 4-sample-like multiplicative noise
    out = oidn_denoise(noisy)
    assert out.shape == clean.shape and out.dtype == np.float64 and np.isfinite(out).all()
    assert np.mean((out - clean) ** 2) < 0.25 * np.mean((noisy - clean) ** 2)


def test_awr_bench_subcommand_runs_the_benchmark(tmp_path, capsys):
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    from awr_denoise.cli.main import main as awr_main

    code = awr_main(["bench", "--quick", "--scenes", "default", "--size", "16", "16", "--spp", "4",
                     "--overhead-sizes", "--no-oidn", "--no-plots", "--quiet", "--output-dir", str(tmp_path / "docs"),
                     "--results", str(tmp_path / "q.json")])
    assert code == 0
    assert "default" in capsys.readouterr().out
    assert json.loads((tmp_path / "q.json").read_text())["scenes"]["default"]["methods"]["uniform"]
    page = (tmp_path / "docs" / "benchmarks.md").read_text()
    assert "Headline" in page
    assert "Raw numbers: `q.json`" in page and str(tmp_path) not in page  # never a machine path
    assert awr_main(["bench", "--quick", "--scenes", "nowhere", "--quiet", "--no-plots",
                     "--output-dir", str(tmp_path / "other")]) == 1
