"""The one preparation of statistics (:mod:`awr_denoise.prepare`): pixels without samples, filled and named."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from awr_denoise import SampleBuffer
from awr_denoise.prepare import filled_mean, prepare


def _holed(rng: np.random.Generator) -> SampleBuffer:
    """8x8 RGB, counts 2-9, per-sample variances known, the first column without samples (each of its
    pixels has one nearest sampled pixel: the next column's)."""
    count = rng.integers(2, 10, (8, 8))
    count[:, 0] = 0
    return SampleBuffer.from_moments(count, rng.random((8, 8, 3)) + 0.5, rng.random((8, 8, 3)) + 0.1)


@pytest.mark.parametrize("luminance", [False, True])
def test_a_pixel_without_samples_is_its_neighbours_mean_and_one_pooled_sample(rng, luminance):
    buffer = _holed(rng)
    p = prepare(buffer, "linear", luminance=luminance)
    assert_array_equal(filled_mean(buffer)[:, 0], buffer.mean[:, 1])
    assert np.all(p.count[:, 0] == 1)  # as uncertain as one sample: the samplers rank it as unknown
    pooled = buffer.estimated_variance()[:, 0]
    assert np.all(pooled > 0)
    if not luminance:
        assert_array_equal(p.sample_variance[:, 0], pooled)


def test_the_sampled_pixels_are_named_where_some_have_none(rng):
    buffer = _holed(rng)
    for luminance in (False, True):
        assert_array_equal(prepare(buffer, luminance=luminance).sampled, buffer.count > 0)
    full = SampleBuffer.from_moments(rng.integers(1, 5, (6, 6)), rng.random((6, 6, 3)), rng.random((6, 6, 3)))
    assert prepare(full).sampled is None


def test_a_buffer_without_samples_is_refused():
    with pytest.raises(ValueError, match="buffer: no pixel has any sample"):
        prepare(SampleBuffer.empty((4, 4)))
