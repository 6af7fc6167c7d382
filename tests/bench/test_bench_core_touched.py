"""``benchmarks/bench_core.py --only touched``: how much of the image an adaptive round changes, and the
wavelet coefficients that reach it."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_core")


def test_one_touched_pixel_reaches_the_coefficients_whose_support_holds_it(bench):
    """``touched``'s reach: one pixel in a 64x64 image is inside the 9-pixel support of 5 x 5 of the
    32 x 32 level-1 positions (stride 2), and the 25-pixel support of 6 x 6 of the 16 x 16 level-2 ones
    (stride 4: 20, 24, ..., 40 lie within 12 of 30)."""
    mask = np.zeros((64, 64), bool)
    mask[30, 30] = True
    assert bench._reach(mask, 1, 9) == 25 / 32**2
    assert bench._reach(mask, 2, 9) == 36 / 16**2


def test_touched_skips_the_uniform_first_round(bench):
    (row,) = bench.touched((("tracer", "default"),), 4)
    assert len(row["pixels"]) == row["rounds"] - 1 >= 1
    assert all(0 < x <= 1 for x in row["pixels"] + row["level1_coefficients"] + row["level2_coefficients"])
