"""A request rendered in parts, and disjoint statistics put side by side (awr_denoise.parts)."""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose, assert_array_equal

from awr_denoise import SampleBuffer, SampleRequest
from awr_denoise.parts import render_in_parts, stitch
from awr_denoise.synthetic import SyntheticRenderer, make_scene


def _by_parts(renderer, seen):
    def render_part(first_row, part):
        seen.append((first_row, part.shape, part.total))
        rows, cols, index = part.pixel_list()
        values = renderer.trace_samples(rows + first_row, cols, index)
        return SampleBuffer.from_samples(rows * part.shape[1] + cols, values, part.shape)
    return render_part


def test_bands_are_the_whole_render_bit_for_bit_and_runs_to_rounding():
    renderer = SyntheticRenderer(make_scene("fireflies", (9, 6)), seed=3)
    rng = np.random.default_rng(0)
    counts = rng.integers(0, 12, (9, 6))
    counts[4] = 0  # a row without samples: no part asks for it
    request = SampleRequest(counts, rng.integers(0, 30, (9, 6)))
    whole = renderer(request)
    seen = []
    bands = render_in_parts(request, _by_parts(renderer, seen), max_samples=80)
    assert len(seen) > 1 and all(total <= 80 for *_, total in seen)
    for field in ("count", "mean", "variance", "variance_known"):
        assert_array_equal(getattr(bands, field), getattr(whole, field))
    seen.clear()
    runs = render_in_parts(request, _by_parts(renderer, seen), max_samples=4)  # every row in runs
    assert all(total <= 6 for *_, total in seen) and all(shape == (1, 6) for _, shape, _ in seen)
    assert_array_equal(runs.count, whole.count)
    assert_allclose(runs.mean, whole.mean, rtol=1e-13, atol=1e-15)
    assert_allclose(runs.variance, whole.variance, rtol=1e-10, atol=1e-15)


def test_stitch_puts_tiles_side_by_side_and_sums_what_they_dropped():
    left = SampleBuffer.from_moments(np.full((2, 1), 3), np.ones((2, 1, 3)), np.full((2, 1, 3), 0.5))
    right = SampleBuffer.from_moments(np.full((2, 2), 5), np.full((2, 2, 3), 2.0), np.zeros((2, 2, 3)))
    right = SampleBuffer(right.count, right.mean, right.variance, right.channels, right.variance_known, 4)
    both = stitch((3, 3), [(slice(0, 2), slice(0, 1)), (slice(1, 3), slice(1, 3))], [left, right])
    assert both.count.tolist() == [[3, 0, 0], [3, 5, 5], [0, 5, 5]] and both.nonfinite == 4
    assert both.mean[1, 0].tolist() == [1.0] * 3 and both.mean[2, 2].tolist() == [2.0] * 3
    assert both.variance[0, 1].tolist() == [0.0] * 3 and not both.variance_known[0, 1]


def test_a_wrong_answer_for_a_part_is_named_not_broadcast():
    """A part's statistics of another shape or channels, or none at all, gave numpy's "could not broadcast" or
    an AttributeError from the merge (a red-team pass)."""
    import pytest

    request = SampleRequest.uniform((4, 2), 2)

    def answer(make):
        return lambda first_row, part: make(part)

    wrong = [(lambda part: None, TypeError, r"^render_part: the part of rows 0-1 came back as NoneType"),
             (lambda part: SampleBuffer.empty((part.shape[0] + 1, 2)), ValueError,
              r"^render_part: the part of rows 0-1 came back with shape \(3, 2\), not the part's \(2, 2\)")]
    for make, error, message in wrong:
        with pytest.raises(error, match=message):
            render_in_parts(request, answer(make), max_samples=8)
    channels = iter([3, 1])
    with pytest.raises(ValueError, match=r"^render_part: the part of rows 2-3 came back with channels \('Y',\)"):
        render_in_parts(request, answer(lambda part: SampleBuffer.empty(part.shape, channels=next(channels))),
                        max_samples=8)
    with pytest.raises(TypeError, match=r"^render_part: the part of row 3 came back as int"):
        render_in_parts(request, lambda first_row, part: SampleBuffer.empty(part.shape) if first_row < 3 else 0,
                        max_samples=4)
    with pytest.raises(ValueError, match=r"^parts: 0 part\(s\) for 0 window\(s\)"):
        stitch((2, 2), [], [])
