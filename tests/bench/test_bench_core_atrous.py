"""``benchmarks/bench_core.py --only atrous``: the direct a-trous routes it times compute the Wiener
stages' undecimated transform, so the timings compare like with like."""

from __future__ import annotations

import json

import numpy as np
import pytest
import pywt

from awr_denoise.stationary import stationary_transform


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_core")


def _same_up_to_a_circular_shift(a: np.ndarray, b: np.ndarray) -> bool:
    """``b`` is ``a`` rolled by some (dy, dx): found by the peak of their circular cross-correlation."""
    corr = np.fft.irfft2(np.fft.rfft2(b) * np.conj(np.fft.rfft2(a)), s=a.shape)
    shift = np.unravel_index(np.argmax(corr), a.shape)
    return bool(np.allclose(np.roll(a, shift, axis=(0, 1)), b, rtol=1e-5, atol=1e-5 * np.abs(b).max()))


@pytest.mark.parametrize("route", ["swt2", "ndimage"])
def test_the_direct_routes_give_the_fft_transforms_coefficients(bench, route):
    shape, levels = (64, 48), 3
    x = np.random.default_rng(5).random(shape)
    ours = stationary_transform(shape, levels=levels).forward(x)
    theirs = (pywt.swt2(x, "bior4.4", level=levels, trim_approx=True) if route == "swt2"
              else bench._atrous_ndimage(x, "bior4.4", levels))
    flat = [ours[0]] + [band for level in ours[1:] for band in level]
    other = [theirs[0]] + [band for level in theirs[1:] for band in level]
    assert len(flat) == len(other) == 3 * levels + 1
    for a, b in zip(flat, other):
        assert _same_up_to_a_circular_shift(a, b)


def test_a_wrong_filter_is_caught(bench):
    """The check above fails for a cascade with the wrong taps: it cannot pass by construction."""
    x = np.random.default_rng(6).random((32, 32))
    ours = stationary_transform((32, 32), levels=2).forward(x)
    wrong = bench._atrous_ndimage(x, "db2", 2)
    assert not _same_up_to_a_circular_shift(ours[1][0], wrong[1][0])


def test_the_section_runs_and_records_its_ratios(bench, tmp_path):
    out = tmp_path / "core.json"
    assert bench.main(["--quick", "--only", "atrous", "--output", str(out)]) == 0
    (row,) = json.loads(out.read_text())["atrous"]
    assert row["size"] == "256x256" and row["levels"] == 4 and row["bands"] == 13
    for key in ("swt2_x_fft", "iswt2_x_fft", "ndimage_x_fft"):
        assert row[key] > 0
