"""Noise floor, equal-error spp and the summary (awr_denoise.bench.analysis)."""

from __future__ import annotations

import numpy as np
import pytest

from awr_denoise.bench import BenchmarkConfig, equal_error_spp, fit_noise_floor
from awr_denoise.bench.analysis import correct_for_noise_floor, headline_spp, summarize


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


def test_correct_for_noise_floor_removes_the_floor_from_every_row():
    n = [4, 8, 16, 32, 64]
    curve = [{"spp": s, "relmse": 0.2 / s + 1e-3} for s in n]
    methods = {"awr": [{"spp": 8, "relmse": 0.2 / 20 + 1e-3}], "below": [{"spp": 8, "relmse": 5e-4}]}
    a, f = correct_for_noise_floor(curve, methods)
    assert (a, f) == pytest.approx((0.2, 1e-3), rel=1e-6)
    assert [r["relmse_corrected"] for r in curve] == pytest.approx([0.2 / s for s in n], rel=1e-6)
    awr = methods["awr"][0]
    assert awr["equal_error_spp"] == pytest.approx(20.0, rel=1e-6) and not awr["equal_error_extrapolated"]
    # The raw curve holds the same point (both carry the floor); log-log interpolation of a curve
    # that is not a power law is off by a little.
    assert awr["equal_error_spp_uncorrected"] == pytest.approx(20.0, rel=0.02)
    below = methods["below"][0]
    assert below["relmse_corrected"] < 0 and below["equal_error_spp"] == float("inf")


def test_headline_spp_is_32_when_measured():
    assert headline_spp([4, 8, 32, 64]) == 32
    assert headline_spp([4, 8, 16, 64]) == 16


def _row(spp, relmse, cpu, mse=1.0):
    return {"spp": spp, "relmse": relmse, "mse": mse, "equal_error_spp": float(spp), "total_cpu_s": cpu, "render_s": 1.0,
            "render_cpu_s": 2.0, "sampler_s": 0.1, "sampler_cpu_s": 0.1, "reconstruct_s": 0.05,
            "reconstruct_cpu_s": 0.05, "rounds": 3}


def test_summarize_flags_a_reconstruction_worse_than_the_mean():
    scene = {"shape": [32, 32], "uniform_curve": [_row(4, 0.1, 1.0), _row(8, 0.05, 2.0), _row(16, 0.025, 4.0)],
             "methods": {"uniform": [_row(4, 0.1, 1.0), _row(8, 0.05, 2.0)],
                         "awr+awr": [_row(4, 0.04, 1.5), _row(8, 0.06, 2.5)]},
             "c_s_sweep": [{"domain": "log", "c_s": 1.0, "spp": 8, "relmse": 0.07, "worse_than_mean": True},
                           {"domain": "log", "c_s": 2.0, "spp": 8, "relmse": 0.03, "worse_than_mean": False}]}
    out = summarize({"scenes": {"s": scene}}, BenchmarkConfig(spps=(4, 8)))
    assert out["headline_spp"] == 8
    assert out["scenes"]["s"]["awr_vs_uniform_same_spp"] == pytest.approx(0.06 / 0.05)
    assert len(out["flags"]) == 2 and all(f.startswith("s: ") for f in out["flags"])
    assert "awr+awr at 8 spp" in out["flags"][0]
    assert out["best_c_s"]["s"] == {"log": 2.0}
    # Equal time: at 2.5 s of CPU uniform MC reaches 0.05 * (2 / 2.5) in log-log.
    et = out["scenes"]["s"]["equal_time"]["awr+awr"]
    assert et["uniform_relmse"] == pytest.approx(0.05 * 2.0 / 2.5, rel=1e-9)
    # Lower relMSE but higher MSE than the plain mean is flagged too (relMSE alone once hid it).
    scene["methods"]["awr+awr"] = [_row(4, 0.04, 1.5, mse=0.5), _row(8, 0.04, 2.5, mse=1.5)]
    scene["c_s_sweep"] = []
    assert summarize({"scenes": {"s": scene}}, BenchmarkConfig(spps=(4, 8)))["flags"] == [
        "s: awr+awr at 8 spp is worse than the plain mean (MSE 1.5 > 1)"]


def test_a_flag_checked_over_seeds_stands_only_if_the_summed_error_is_above_the_plain_means():
    """One render above the plain mean: confirmed when the error summed over the seeds is above
    it too, reported as not confirmed otherwise, with the per-seed spread either way."""
    scene = {"shape": [32, 32], "uniform_curve": [_row(4, 0.1, 1.0), _row(8, 0.05, 2.0)],
             "methods": {"uniform": [_row(4, 0.1, 1.0, mse=1.0), _row(8, 0.05, 2.0, mse=1.0)],
                         "uniform+awr": [_row(4, 0.05, 1.0, mse=1.2), _row(8, 0.02, 2.0, mse=1.1)]}}
    checks = [{"scene": "s", "method": "uniform+awr", "spp": 4, "seeds": [0, 1, 2], "relmse": [0.05, 0.05, 0.05],
               "mse": [1.2, 0.5, 0.6], "plain_relmse": [0.1, 0.1, 0.1], "plain_mse": [1.0, 1.0, 1.0]},
              {"scene": "s", "method": "uniform+awr", "spp": 8, "seeds": [0, 1, 2], "relmse": [0.02, 0.02, 0.02],
               "mse": [1.1, 1.3, 0.9], "plain_relmse": [0.05, 0.05, 0.05], "plain_mse": [1.0, 1.0, 1.0]}]
    out = summarize({"scenes": {"s": scene}, "flag_checks": checks}, BenchmarkConfig(spps=(4, 8)))
    assert out["flags"] == ["s: uniform+awr at 8 spp is worse than the plain mean (MSE 1.1 > 1); over seeds 0-2 the "
                            "summed MSE is 1.10x the plain mean's, above it on 2 of 3 (per seed 0.90-1.30x)"]
    assert out["flags_not_confirmed"] == [
        "s: uniform+awr at 4 spp is worse than the plain mean (MSE 1.2 > 1); over seeds 0-2 the summed MSE is 0.77x "
        "the plain mean's, above it on 1 of 3 (per seed 0.50-1.20x)"]
    # Without checks (flag_seeds=1, or results from before them) every flag stands as it is.
    plain = summarize({"scenes": {"s": scene}}, BenchmarkConfig(spps=(4, 8)))
    assert len(plain["flags"]) == 2 and plain["flags_not_confirmed"] == []


def test_a_default_that_moves_its_samples_image_mean_is_flagged_on_that_render():
    """The image mean is the third judged quantity: a reconstruction that lowers relMSE and MSE but moves
    its samples' mean by more than 0.5% (the reconstruction issue's bound) has changed the exposure. It
    is flagged as it stands, not re-rendered over seeds (``flag_candidates`` does not list it)."""
    from awr_denoise.bench.analysis import MEAN_CHANGE_BOUND, flag_candidates

    scene = {"shape": [32, 32], "uniform_curve": [_row(4, 0.1, 1.0), _row(8, 0.05, 2.0)],
             "methods": {"uniform": [_row(4, 0.1, 1.0), _row(8, 0.05, 2.0)],
                         "uniform+awr": [{**_row(4, 0.05, 1.0), "mean_change": 0.006},
                                         {**_row(8, 0.02, 2.0), "mean_change": MEAN_CHANGE_BOUND}],
                         "uniform+oidn": [{**_row(4, 0.05, 1.0), "mean_change": 0.05}]}}
    out = summarize({"scenes": {"s": scene}}, BenchmarkConfig(spps=(4, 8)))
    assert out["flags"] == ["s: uniform+awr at 4 spp moves the image mean of its samples by 0.60% (more than 0.5%)"]
    assert flag_candidates({"scenes": {"s": scene}}) == []
    # Results recorded before the image mean was (no ``mean_change``) raise no flag.
    del scene["methods"]["uniform+awr"][0]["mean_change"]
    assert summarize({"scenes": {"s": scene}}, BenchmarkConfig(spps=(4, 8)))["flags"] == []
