"""Chunked listing of a request's samples and their exact per-pixel statistics (no renderer needed)."""

from __future__ import annotations

import numpy as np
import pytest

from awr_denoise import SampleBuffer, SampleRequest
from awr_denoise.adapters._samples import PixelStatistics, aligned_u32, sample_chunks


def _random_request(shape, rng, *, high=5) -> SampleRequest:
    return SampleRequest(rng.integers(0, high, shape), rng.integers(0, 50, shape))


def _chunk_lanes(chunk):
    """What the device computes for a chunk's lanes, in numpy: flat pixel and sample index."""
    lane = np.arange(chunk.size)
    pixel = np.searchsorted(chunk.ends, lane, side="right")
    return pixel, (chunk.base[pixel] + lane) % (1 << 32)


@pytest.mark.parametrize("batch", [1, 7, 64, 10_000])
def test_sample_chunks_list_the_request(batch, rng):
    request = _random_request((9, 13), rng, high=6)
    chunks = list(sample_chunks(request, batch))
    assert all(0 < c.size <= batch for c in chunks) and sum(c.size for c in chunks) == request.total
    pixel, index = (np.concatenate(a) for a in zip(*map(_chunk_lanes, chunks)))
    rows, cols, expected_index = request.pixel_list()
    np.testing.assert_array_equal(pixel, rows * 13 + cols)
    np.testing.assert_array_equal(index, expected_index)
    for c in chunks:  # per_pixel counts the chunk's own samples at every pixel
        np.testing.assert_array_equal(np.bincount(_chunk_lanes(c)[0], minlength=9 * 13), c.per_pixel)


@pytest.mark.parametrize("batch", [5, 37, 10_000])
def test_pixel_statistics_equal_from_samples(batch, rng):
    """Chunked two-pass statistics (Chan-merged at chunk boundaries) equal those of all samples at once."""
    request = _random_request((6, 7), rng, high=9)
    rows, cols, _ = request.pixel_list()
    values = (rng.standard_normal((3, request.total)) * 3 + 10).astype(np.float32)
    stats = PixelStatistics(42, 3)
    at = 0
    for c in sample_chunks(request, batch):
        stats.add(c.per_pixel, values[:, at:at + c.size])
        at += c.size
    got = stats.buffer((6, 7), ("R", "G", "B"))
    expected = SampleBuffer.from_samples(rows * 7 + cols, values.T.astype(np.float64), (6, 7))
    np.testing.assert_array_equal(got.count, expected.count)
    np.testing.assert_allclose(got.mean, expected.mean, rtol=1e-13)
    np.testing.assert_allclose(got.variance, expected.variance, rtol=1e-10)


def test_aligned_u32_is_64_byte_aligned(rng):
    for n in (1, 3, 1000):
        out = aligned_u32(rng.integers(0, 1 << 31, n))
        assert out.dtype == np.uint32 and out.ctypes.data % 64 == 0 and out.size == n


def test_empty_request_gives_no_chunk():
    assert list(sample_chunks(SampleRequest.uniform((3, 4), 0), 8)) == []
