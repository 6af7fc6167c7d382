"""The Mitsuba 3 section of ``awr bench``: measured through the adapter, or skipped with the reason."""

from __future__ import annotations

import json

import pytest

from awr_denoise.bench import BenchmarkConfig
from awr_denoise.bench import mitsuba as bench_mitsuba
from awr_denoise.bench.report import _mitsuba


def test_scene_names_are_checked():
    assert bench_mitsuba.mitsuba_scene_names(BenchmarkConfig(mitsuba_scenes=("dof_checker",))) == ["dof_checker"]
    # the scenes lit through rare paths on request, not by default
    assert bench_mitsuba.mitsuba_scene_names(BenchmarkConfig(mitsuba_scenes=("fog_spot",))) == ["fog_spot"]
    assert "fog_spot" not in bench_mitsuba.mitsuba_scene_names(BenchmarkConfig())
    with pytest.raises(ValueError, match="mitsuba_scenes: 'nope'"):
        bench_mitsuba.mitsuba_scene_names(BenchmarkConfig(mitsuba_scenes=("nope",)))


def test_a_missing_mitsuba_skips_the_section_with_its_reason(monkeypatch):
    monkeypatch.setattr(bench_mitsuba, "mitsuba_status", lambda: "skipped: no Mitsuba here")
    result = bench_mitsuba.mitsuba_benchmark(BenchmarkConfig(), lambda label: None)
    assert result == {"status": "skipped: no Mitsuba here", "scenes": {}}
    page = "\n".join(_mitsuba({"mitsuba": result}))
    assert "Not measured: skipped: no Mitsuba here" in page


def test_the_section_measures_both_samplers_and_caches_the_reference(mi, tmp_path):
    config = BenchmarkConfig.quick(spps=(2, 8), mitsuba_size=16, mitsuba_reference_spp=64,
                                   mitsuba_scenes=("cornell_box",), mitsuba_reference_dir=str(tmp_path))
    ticks = []
    result = bench_mitsuba.mitsuba_benchmark(config, ticks.append)
    assert result["status"] == "measured" and ticks == ["mitsuba cornell_box"]
    scene = result["scenes"]["cornell_box"]
    assert scene["shape"] == [16, 16] and scene["reference"]["source"].startswith("rendered")
    for method in bench_mitsuba.MITSUBA_METHODS:
        assert [row["spp"] for row in scene["methods"][method]] == [2, 8]
        for row in scene["methods"][method]:
            assert row["relmse"] > 0 and row["mse"] > 0 and abs(row["mean_error"]) < 0.5
    # Uniform and adaptive sampling agree on AdaptiveSampler's first round (2 spp everywhere) and part after it.
    assert scene["methods"]["uniform"][0] == scene["methods"]["awr"][0]
    assert scene["methods"]["uniform"][1] != scene["methods"]["awr"][1]
    again = bench_mitsuba.mitsuba_benchmark(config, lambda label: None)
    assert again["scenes"]["cornell_box"]["reference"]["source"].startswith("cached")
    assert again["scenes"]["cornell_box"]["methods"] == scene["methods"]  # seeded: the same numbers
    # A reference cut short (a run killed while it saved it) is rendered again, not a reshape error for ever.
    (cached,) = [p for p in tmp_path.iterdir() if p.suffix == ".npy"]
    cached.write_bytes(cached.read_bytes()[:128])
    with pytest.warns(UserWarning, match=rf"{cached.name}: unreadable .*made again"):
        mended = bench_mitsuba.mitsuba_benchmark(config, lambda label: None)
    assert mended["scenes"]["cornell_box"]["reference"]["source"].startswith("rendered")
    assert mended["scenes"]["cornell_box"]["methods"] == scene["methods"]
    page = "\n".join(_mitsuba(json.loads(json.dumps({"mitsuba": result}))))
    assert "**cornell_box** (16x16" in page and "| 8 |" in page


def test_the_section_lists_a_reconstruction_that_moves_its_samples_image_mean():
    """Judged on relMSE, MSE and the image mean together: a reconstruction better in both errors but 1%
    brighter than its own samples is listed, one within 0.5% is not."""
    def row(spp, relmse, mse, mean_error):
        return {"spp": spp, "relmse": relmse, "mse": mse, "mean_error": mean_error}

    methods = {"uniform": [row(8, 0.1, 0.1, 0.002)], "uniform+awr": [row(8, 0.05, 0.05, 0.012)],
               "awr": [row(8, 0.1, 0.1, -0.01)], "awr+awr": [row(8, 0.05, 0.05, -0.006)]}
    result = {"status": "measured", "scenes": {"s": {"shape": [4, 4], "reference": {"spp": 64}, "methods": methods}}}
    assert _mitsuba({"mitsuba": result})[-1] == ("Reconstructions worse than the plain mean of their own samples "
                                                  "(relMSE or MSE), or that move its image mean by more than 0.5%: "
                                                  "s at 8 spp.\n")
    methods["uniform+awr"] = [row(8, 0.05, 0.05, 0.004)]
    assert _mitsuba({"mitsuba": result})[-1].endswith(": none.\n")
