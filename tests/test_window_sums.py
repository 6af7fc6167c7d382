"""Window sums made of their own entries (awr_denoise._window_sums) against sums written out pixel by pixel."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import ndimage

from awr_denoise._window_sums import neighbour_sum, window_sum

MODES = ("edge", "reflect", "wrap")


def _plain_sums(a, size, mode, *, centre=True):
    """Every window summed entry by entry over the padded image."""
    r = size // 2
    padded = np.pad(a, ((r, r), (r, r)) + ((0, 0),) * (a.ndim - 2), mode=mode)
    out = np.zeros(a.shape)
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            window = padded[i:i + size, j:j + size].copy()
            if not centre:
                window[r, r] = 0
            out[i, j] = window.sum(axis=(0, 1))
    return out


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (7, 1), (2, 3), (5, 4, 3), (9, 12)])
@pytest.mark.parametrize("size", [1, 3, 5, 9, 11, 17, 31])
def test_the_sums_are_the_windows_entries_summed(rng, mode, shape, size):
    a = rng.random(shape)
    assert_allclose(window_sum(a, size, mode=mode), _plain_sums(a, size, mode), rtol=1e-13)
    assert_allclose(neighbour_sum(a, mode=mode), _plain_sums(a, 3, mode, centre=False), rtol=1e-13, atol=1e-15)


def test_the_result_may_be_written_over_the_input(rng):
    a = rng.random((6, 8, 2))
    want = window_sum(a, 5)
    assert window_sum(a, 5, out=a) is a
    np.testing.assert_array_equal(a, want)


def test_a_huge_value_leaves_nothing_behind_in_windows_without_it():
    """A running sum (scipy's uniform_filter) carries 1e16's rounding error along the line: here the window sum of
    25 entries of 1 (the line repeated past the edges), 25 columns away, came out 0. Each window here sums its own
    entries."""
    a = np.ones((1, 40))
    a[0, 5] = 1e16
    running = ndimage.uniform_filter(a, 5, mode="nearest") * 25
    assert running[0, 30] != 25.0  # what the pooling and the guard had
    sums = window_sum(a, 5)
    np.testing.assert_array_equal(sums[0, 8:], 25.0)
    b = np.ones((3, 3))
    b[1, 1] = 1e20
    assert neighbour_sum(b)[1, 1] == 8.0  # not the square's sum less the entry: that is 0


def test_sums_past_the_range_are_inf_without_a_warning():
    a = np.full((3, 3), np.finfo(np.float64).max)
    assert np.isposinf(window_sum(a, 3)).all()
