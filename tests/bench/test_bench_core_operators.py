"""``benchmarks/bench_core.py --only operators``: the reference route it times builds the same
operators as the library's linear build, and the section reports both."""

from __future__ import annotations

import numpy as np
import pytest
import pywt

from awr_denoise import wavelets


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_core")


def test_the_reference_route_builds_the_library_operators(bench):
    step = lambda x: pywt.dwt(x, "bior4.4", mode="symmetric", axis=0)[1]  # noqa: E731
    edge = wavelets._edge(pywt.Wavelet("bior4.4"))
    reference = bench._every_impulse(step, 300)
    assert np.array_equal(reference.toarray(), wavelets._sparse_operator(step, 300, (2, 1), edge).toarray())


def test_the_section_times_both_routes_and_leaves_the_library_as_it_was(bench):
    linear = wavelets._sparse_operator
    (row,) = bench.operators({"tiny": (48, 64)}, repeats=1)
    assert row["size"] == "tiny" and row["linear_s"] > 0 and row["every_impulse_s"] > 0
    assert wavelets._sparse_operator is linear
    assert wavelets._axis_operators.cache_info().currsize == 0  # no operator of the reference route stays cached
