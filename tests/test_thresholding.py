"""Stage 1, Eq. 10-11 (the end-to-end checks are in tests/test_reconstruct.py with ``stages=1``)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from awr_denoise import SampleBuffer
from awr_denoise.prepare import prepare
from awr_denoise.thresholding import soft_threshold, threshold_stage
from awr_denoise.wavelets import wavelet_operators


def test_soft_threshold_is_eq_11():
    w = np.array([-3.0, -1.0, -0.5, 0.0, 0.5, 1.0, 3.0])
    assert_array_equal(soft_threshold(w, 1.0), [-2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0])
    assert_array_equal(soft_threshold(w, 0.0), w)


def test_stage_counts_what_it_zeroed_and_estimates_its_variance(rng):
    buf = SampleBuffer.from_moments(np.full((24, 20), 6), 0.5 + 0.1 * rng.standard_normal((24, 20, 3)),
                                    np.full((24, 20, 3), 0.06))
    stage = threshold_stage(prepare(buf, "linear"), wavelet_operators((24, 20)), 1.0)
    assert 0 < stage.zeroed < stage.total
    variance = stage.output_variance(8, 0)
    assert variance.shape == (24, 20, 3) and variance.mean() < 0.5 * buf.variance_of_mean().mean()


def test_luminance_mode_needs_the_luminance_plane(rng):
    buf = SampleBuffer.from_moments(np.full((8, 8), 4), rng.random((8, 8, 3)), np.full((8, 8, 3), 0.01))
    with pytest.raises(ValueError, match="luminance"):
        threshold_stage(prepare(buf), wavelet_operators((8, 8)), 1.0, mode="luminance")
