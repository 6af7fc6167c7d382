"""SampleRequest: validation, the per-sample pixel list, cropping; the Renderer protocol."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from awr_denoise import Renderer, SampleBuffer, SampleRequest
from awr_denoise.synthetic import SyntheticRenderer, make_scene


def test_uniform_request():
    req = SampleRequest.uniform((3, 4), 5, first_index=7, round=2)
    assert req.shape == (3, 4) and req.total == 60 and req.round == 2
    assert_array_equal(req.first_index, 7)
    assert req.counts.dtype == np.int64


def test_pixel_list_hand_checked():
    counts = np.array([[2, 0], [1, 3]])
    first = np.array([[5, 9], [0, 1]])
    rows, cols, index = SampleRequest(counts, first).pixel_list()
    assert_array_equal(rows, [0, 0, 1, 1, 1, 1])
    assert_array_equal(cols, [0, 0, 0, 1, 1, 1])
    assert_array_equal(index, [5, 6, 0, 1, 2, 3])


def test_pixel_list_counts_match(rng):
    counts = rng.integers(0, 5, (7, 9))
    first = rng.integers(0, 100, (7, 9))
    rows, cols, index = SampleRequest(counts, first).pixel_list()
    assert rows.size == counts.sum()
    assert_array_equal(np.bincount(rows * 9 + cols, minlength=63), counts.ravel())
    # Every pixel's indices run first_index, first_index + 1, ...
    for r, c in [(0, 0), (3, 4), (6, 8)]:
        sel = (rows == r) & (cols == c)
        assert_array_equal(index[sel], first[r, c] + np.arange(counts[r, c]))


def test_crop_keeps_round_and_sampler():
    req = SampleRequest(np.arange(12).reshape(3, 4), np.ones((3, 4), int), round=3, sampler_id=11)
    tile = req.crop(slice(1, 3), slice(0, 2))
    assert tile.shape == (2, 2) and tile.round == 3 and tile.sampler_id == 11
    assert_array_equal(tile.counts, [[4, 5], [8, 9]])


def test_arrays_are_copied_and_read_only():
    counts = np.ones((2, 2), int)
    req = SampleRequest(counts, np.zeros((2, 2), int))
    counts[0, 0] = 5
    assert req.counts[0, 0] == 1
    with pytest.raises(ValueError, match="read-only"):
        req.counts[0, 0] = 2


def test_whole_float_counts_are_accepted():
    req = SampleRequest(np.full((2, 2), 3.0), np.zeros((2, 2)))
    assert req.counts.dtype == np.int64 and req.total == 12


@pytest.mark.parametrize(("counts", "first", "error", "message"), [
    (np.ones(4, int), np.zeros(4, int), ValueError, r"counts: expected shape \(H, W\)"),
    (np.ones((2, 2), int), np.zeros((2, 3), int), ValueError, r"first_index: shape \(2, 3\) does not match"),
    (np.array([[1, -1], [-2, 0]]), np.zeros((2, 2), int), ValueError, r"counts: 2 pixel\(s\) are negative"),
    (np.ones((2, 2), int), np.array([[0, -1], [0, 0]]), ValueError, r"first_index: 1 pixel\(s\) are negative"),
    # A fraction or NaN is a value error, named as the buffer's counts name it (it was a TypeError
    # naming the dtype, although whole float64 counts are accepted).
    (np.full((2, 2), 0.5), np.zeros((2, 2), int), ValueError, r"counts: 4 pixel\(s\) are not whole numbers"),
    (np.full((2, 2), np.nan), np.zeros((2, 2), int), ValueError, r"counts: 4 pixel\(s\) hold NaN"),
    # A uint64 past 2**63 was cast first and reported as negative.
    (np.full((2, 2), 2**63 + 5, np.uint64), np.zeros((2, 2), int), ValueError, r"counts: 4 pixel\(s\) exceed 2\*\*62"),
    (np.ones((2, 2), int), np.full((2, 2), 2**64 - 1, np.uint64), ValueError, r"first_index: 4 pixel\(s\) exceed"),
    (np.array(["1"] * 4).reshape(2, 2), np.zeros((2, 2), int), TypeError, "counts: expected an integer array"),
])
def test_bad_requests_are_refused(counts, first, error, message):
    with pytest.raises(error, match=message):
        SampleRequest(counts, first)


def test_renderer_protocol():
    scene = make_scene("edges", (8, 8))
    assert isinstance(SyntheticRenderer(scene), Renderer)
    assert isinstance(lambda request: SampleBuffer.empty(request.shape), Renderer)
    assert not isinstance(42, Renderer)


def test_totals_past_int64_are_refused_not_wrapped():
    """Per-pixel counts were bounded, their sums not: totals wrapped to negative numbers (second
    red-team pass)."""
    with pytest.raises(ValueError, match="counts: .* samples in all exceed 2\\*\\*62"):
        SampleRequest(np.full((1, 2), 2**62), np.zeros((1, 2), np.int64))
    with pytest.raises(ValueError, match="counts: more than 2\\*\\*62 samples"):
        SampleRequest(np.full((1, 1), 2**61), np.full((1, 1), 2**61 + 1))
    with pytest.raises(ValueError, match="count: .* samples in all exceed 2\\*\\*62"):
        SampleBuffer.from_moments(np.full((2, 3), 2**62), np.ones((2, 3, 3)), np.ones((2, 3, 3)))
    assert SampleRequest(np.full((1, 2), 2**61), np.zeros((1, 2), np.int64)).total == 2**62


def test_a_request_cannot_be_made_writeable_again():
    """``ask()`` hands out the request ``tell()`` checks the batch against: its arrays owned their
    memory, so a renderer could set ``writeable`` back, add samples in place, and ``tell()`` took
    them (red-team pass of the API's array layouts)."""
    request = SampleRequest(np.asfortranarray(np.full((3, 4), 2)), np.zeros((3, 4), int))
    for a in (request.counts, request.first_index):
        assert a.flags.c_contiguous and not a.flags.writeable
        with pytest.raises(ValueError):
            a.flags.writeable = True
    with pytest.raises(TypeError, match="counts: a masked array with 1 masked entries"):
        SampleRequest(np.ma.masked_equal(np.array([[1, 2]]), 2), np.zeros((1, 2), int))


def test_large_first_indices_are_per_pixel_not_summed():
    """The first indices are each within 2**62, not their sum: ``uniform(..., first_index=2**49)`` of
    a 128x128 image was refused as "samples in all exceed 2**62" (a review of this check)."""
    request = SampleRequest.uniform((128, 128), 4, first_index=2**49)
    assert int(request.first_index.max()) == 2**49 and request.total == 4 * 128 * 128
    with pytest.raises(ValueError, match="first_index: 1 pixel\\(s\\) exceed 2\\*\\*62"):
        SampleRequest(np.ones((1, 1), int), np.full((1, 1), 2**62 + 1, np.uint64))


@pytest.mark.parametrize("rows, message", [(slice(0, 4, 2), "step of 1, got 2"),
                                           (slice(None, None, -1), "step of 1, got -1"),
                                           (slice(None, None, 0), "step of 1, got 0"),
                                           (slice(0, 2.5), "expected an integer, got float 2.5"),
                                           (slice(2.0, 4), "expected an integer, got float 2.0"),
                                           (slice(0, 4, 1.0), "expected an integer, got float 1.0"),
                                           (slice(4, 9), "4:9 holds none of the image's 4 rows"),
                                           (slice(2, 2), "2:2 holds none of the image's 4 rows"),
                                           (slice(-9, -4), "-9:-4 holds none of the image's 4 rows")])
def test_a_crop_is_a_contiguous_tile(rows, message):
    """A step of 2 subsampled the image and -1 mirrored it; 0 and 2.5 gave Python's bare slice errors
    (a red-team pass); a tile holding no pixel was "count: empty image" (the tenth pass). Buffers and
    requests crop alike."""
    buffer = SampleBuffer.from_moments(np.full((4, 4), 2), np.ones((4, 4, 3)), np.ones((4, 4, 3)))
    for item in (buffer, SampleRequest.uniform((4, 4), 2)):
        with pytest.raises((ValueError, TypeError), match=f"^rows: .*{re.escape(message)}"):
            item.crop(rows, slice(0, 2))
    assert buffer.crop(slice(np.int64(1), 3), slice(None, None, None)).shape == (2, 4)


@pytest.mark.parametrize("max_samples", [1, 2, 5, 17, 40, 10**6])
def test_pieces_ask_for_every_sample_once_and_hold_at_most_their_share(max_samples):
    """Every sample of the request in exactly one part (the same pixel and sample index), parts of whole
    rows at most ``max_samples`` each where a row allows, a row's pixels with samples at one sample each
    otherwise; bands of rows keep each pixel in one part, and bands without samples are left out."""
    rng = np.random.default_rng(max_samples)
    counts = rng.integers(0, 9, (6, 7)) * (rng.random((6, 7)) < 0.8)
    counts[2] = 0
    request = SampleRequest(counts, rng.integers(0, 50, (6, 7)), round=3, sampler_id=4)
    parts = list(request.pieces(max_samples))
    assert all(p.shape[1] == 7 and (p.round, p.sampler_id) == (3, 4) and p.total > 0 for _, p in parts)
    asked = sorted(zip(*(a.tolist() for a in request.pixel_list())))
    got = [(r + row, c, i) for row, p in parts for r, c, i in zip(*(a.tolist() for a in p.pixel_list()))]
    assert sorted(got) == asked
    assert all(p.total <= max(max_samples, 7) for _, p in parts)
    if max_samples >= request.counts.sum(axis=1).max():  # bands of rows only: no row in two parts
        assert len({row for row, _ in parts}) == len(parts)
    assert len(parts) == 1 if max_samples >= request.total else len(parts) > 1


def test_one_pixels_many_samples_come_in_runs():
    """1e9 samples at one pixel: parts of the whole share (a renderer holding a part's samples at once
    raised MemoryError, a red-team pass), runs shared by the row's pixels with samples only (a review:
    runs of share / width made 2292 parts of 2184 samples of one pixel at 1080p)."""
    counts = np.zeros((1, 1920), np.int64)
    counts[0, 5] = 10**9
    parts = SampleRequest(counts, np.full((1, 1920), 7)).pieces(2**22)
    (row, first), (_, second) = next(parts), next(parts)
    assert (row, first.total, int(first.first_index[0, 5])) == (0, 2**22, 7)
    assert (second.total, int(second.first_index[0, 5])) == (2**22, 7 + 2**22)
    with pytest.raises(ValueError, match="max_samples"):
        next(SampleRequest(counts, counts).pieces(0))


def test_a_feature_with_more_samples_than_requested_is_refused():
    """A batch whose depth held 1000 samples a pixel beside radiance of 4 was told and merged as it was (an attack
    pass): one feature value per sample at most, as for the radiance."""
    request = SampleRequest.uniform((2, 2), 4)
    depth = SampleBuffer.from_moments(np.full((2, 2), 1000), np.ones((2, 2, 1)), np.zeros((2, 2, 1)),
                                      channels=("Z",))
    batch = SampleBuffer.from_moments(np.full((2, 2), 4), np.ones((2, 2, 3)), np.full((2, 2, 3), 0.1),
                                      features={"depth": depth})
    with pytest.raises(ValueError, match=r"^samples: features\['depth'\]: 4 pixel\(s\) hold more samples than "
                                         r"requested$"):
        request.check_answer(batch, ("R", "G", "B"))
    fewer = SampleBuffer.from_moments(np.full((2, 2), 4), np.ones((2, 2, 3)), np.full((2, 2, 3), 0.1),
                                      features={"depth": dataclasses.replace(depth, count=np.full((2, 2), 3))})
    assert request.check_answer(fewer, ("R", "G", "B")).features["depth"].count.max() == 3


def test_an_empty_uniform_request_names_its_shape():
    """``SampleRequest.uniform((0, 2), 2)`` was "counts: empty image", a parameter not given (an attack pass)."""
    with pytest.raises(ValueError, match=r"^shape: empty image \(0, 2\)$"):
        SampleRequest.uniform((0, 2), 2)
