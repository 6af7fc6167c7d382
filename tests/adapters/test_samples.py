"""Chunked listing of a request's samples and their exact per-pixel statistics (no renderer needed)."""

from __future__ import annotations

import numpy as np
import pytest

from awr_denoise import SampleBuffer, SampleRequest
from awr_denoise.adapters import _samples
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


def _statistics(request, values, batch):
    stats = PixelStatistics(request.counts.size, values.shape[0])
    at = 0
    for c in sample_chunks(request, batch):
        stats.add(c.per_pixel, values[:, at:at + c.size])
        at += c.size
    return stats


@pytest.mark.parametrize("spp", [1, 4, 16, 17, 40])
@pytest.mark.parametrize("batch", [3, 100, 10_000])
def test_pixel_statistics_of_equal_runs(spp, batch, rng, monkeypatch):
    """Uniform requests take the equal-runs path (sample by sample up to 16, a reduction above); chunk
    boundaries split pixels, and small blocks make several blocks per chunk: the same statistics."""
    monkeypatch.setattr(_samples, "_BLOCK", 64)
    calls = []
    equal_runs = _samples._equal_runs
    monkeypatch.setattr(_samples, "_equal_runs", lambda *a: (calls.append(a[1]), equal_runs(*a)))
    request = SampleRequest.uniform((5, 9), spp)
    rows, cols, _ = request.pixel_list()
    values = (rng.standard_normal((3, request.total)) * 3 + 10).astype(np.float32)
    got = _statistics(request, values, batch).buffer((5, 9), ("R", "G", "B"))
    expected = SampleBuffer.from_samples(rows * 9 + cols, values.T.astype(np.float64), (5, 9))
    assert calls  # the path ran; with whole pixels per chunk, at the full run length (past 16: the reduction)
    if batch > spp:
        assert spp in calls
    np.testing.assert_array_equal(got.count, expected.count)
    np.testing.assert_allclose(got.mean, expected.mean, rtol=1e-13)
    np.testing.assert_allclose(got.variance, expected.variance, rtol=1e-10, atol=1e-13)


def test_pixel_statistics_mixed_blocks(rng, monkeypatch):
    """A request half uniform, half random: blocks of equal and of unequal runs in one chunk."""
    monkeypatch.setattr(_samples, "_BLOCK", 32)
    counts = np.full((8, 8), 3)
    counts[4:] = rng.integers(0, 7, (4, 8))
    request = SampleRequest(counts, rng.integers(0, 50, (8, 8)))
    rows, cols, _ = request.pixel_list()
    values = rng.random((2, request.total)).astype(np.float32)
    got = _statistics(request, values, 10_000).buffer((8, 8), ("A", "B"))
    expected = SampleBuffer.from_samples(rows * 8 + cols, values.T.astype(np.float64), (8, 8))
    np.testing.assert_array_equal(got.count, expected.count)
    np.testing.assert_allclose(got.mean, expected.mean, rtol=1e-13)
    np.testing.assert_allclose(got.variance, expected.variance, rtol=1e-10, atol=1e-13)


def test_pixel_statistics_hand_over_their_arrays(rng):
    """buffer() gives its arrays to the SampleBuffer (no copy): the statistics cannot be used again."""
    request = SampleRequest.uniform((2, 3), 2)
    stats = _statistics(request, rng.random((3, request.total)).astype(np.float32), 100)
    mean = stats.mean
    buffer = stats.buffer((2, 3), ("R", "G", "B"))
    assert np.shares_memory(buffer.mean, mean) and not buffer.mean.flags.writeable
    (chunk,) = sample_chunks(request, 100)
    with pytest.raises(RuntimeError, match="buffer\\(\\) has taken"):
        stats.add(chunk.per_pixel, np.zeros((3, chunk.size), np.float32))
    with pytest.raises(RuntimeError, match="already"):
        stats.buffer((2, 3), ("R", "G", "B"))
