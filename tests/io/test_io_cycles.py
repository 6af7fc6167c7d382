"""The divisor of Cycles' normalised sample-count pass (awr_denoise/io/cycles.py)."""

from __future__ import annotations

import numpy as np
import pytest

from awr_denoise.io.cycles import sample_count_scale


@pytest.mark.parametrize(("counts", "requested", "taken"), [
    ([48, 64, 64], 256, 64),          # converged early everywhere: the pass is normalised by 64
    ([48, 64, 96, 100], 100, 100),    # off the checks' grid: the last pixels stopped at 100 itself
    ([48, 64, 96, 112, 200], 200, 200),
    ([32, 48, 50], 50, 50),
    ([64, 100], 100, 100),            # one value below the top, on the grid at 100
])
def test_the_divisor_is_the_samples_the_render_took(counts, requested, taken):
    scale, how = sample_count_scale(np.array(counts) / max(counts), requested)
    assert scale == taken, how
    assert np.array_equal(np.rint(np.array(counts) / max(counts) * scale), counts)
    assert "guess" not in how


def test_a_divisor_the_pattern_does_not_fix_is_called_a_guess():
    """Counts 15 and 50 of 50 requested: not adaptive sampling's pattern; the smallest whole scale (5
    of 10) is taken, and said to be a guess so that the reader warns."""
    scale, how = sample_count_scale(np.array([0.3, 1.0]), 50)
    assert scale == 10 and "a guess (pass spp=" in how


def test_the_requested_count_is_taken_only_where_the_counts_are_whole_at_it():
    """Counts 16 and 17 of 256 requested (a time limit at 17): 256 was taken because 16 * (256 // 17)
    is on the grid, though 16/17 * 256 is not whole (a review of the off-grid rule)."""
    scale, how = sample_count_scale(np.array([16, 17]) / 17, 256)
    assert scale == 17 and "a guess" in how
