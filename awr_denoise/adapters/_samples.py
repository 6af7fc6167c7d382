"""Listing a request's samples in chunks, and their exact per-pixel statistics, for adapters.

A renderer that traces wavefronts needs the samples of a :class:`~awr_denoise.requests.SampleRequest`
as lanes, in :meth:`~awr_denoise.requests.SampleRequest.pixel_list` order (row-major pixels,
increasing sample index), and the per-pixel statistics of the values it gets back. Both are done
here without a Python loop per pixel or sample: :func:`sample_chunks` describes a chunk of lanes
with two per-pixel arrays (a device can list the lanes itself by a binary search), and
:class:`PixelStatistics` sums the values by runs of consecutive samples in float64, two-pass.

Examples
--------
>>> import numpy as np
>>> from awr_denoise import SampleRequest
>>> request = SampleRequest(np.array([[2, 0, 1]]), np.array([[0, 0, 5]]))
>>> (chunk,) = sample_chunks(request, batch_size=16)
>>> chunk.size, chunk.per_pixel.tolist()
(3, [2, 0, 1])
>>> stats = PixelStatistics(3, 1)
>>> stats.add(chunk.per_pixel, np.array([[1.0, 3.0, 7.0]], np.float32))
>>> buffer = stats.buffer((1, 3), ("Y",))
>>> buffer.mean[..., 0].tolist(), buffer.variance[..., 0].tolist()
([[2.0, 0.0, 7.0]], [[2.0, 0.0, 0.0]])
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import NamedTuple

import numpy as np

from .._typing import Shape2D
from ..buffers import SampleBuffer
from ..requests import SampleRequest

__all__ = ["Chunk", "PixelStatistics", "aligned_u32", "sample_chunks"]


def aligned_u32(values: np.ndarray) -> np.ndarray:
    """``values`` as uint32 in a 64-byte aligned buffer.

    Dr.Jit reads numpy memory in place and compiles the buffer's alignment into the kernel, so
    arrays at arbitrary addresses would make every call compile one of several kernel variants
    (about a second each); aligned inputs make every call reuse one kernel.
    """
    raw = np.empty(values.size + 16, np.uint32)
    start = (-raw.ctypes.data % 64) // raw.itemsize
    out = raw[start:start + values.size]
    out[...] = values
    return out


class Chunk(NamedTuple):
    """Samples ``lo, ..., lo + size - 1`` of a request's sample list (row-major pixels, increasing
    sample index), described per pixel of the image so that the lanes can be listed on the device.

    Lane ``i`` of the chunk belongs to the first pixel ``p`` with ``ends[p] > i`` and has sample
    index ``base[p] + i`` (``base`` is stored modulo 2**32; pixels without samples in the chunk are
    never looked up). ``per_pixel`` is the number of the chunk's samples at every pixel.
    """

    size: int
    ends: np.ndarray
    base: np.ndarray
    per_pixel: np.ndarray


def sample_chunks(request: SampleRequest, batch_size: int) -> Iterator[Chunk]:
    """The request's samples, at most ``batch_size`` at a time, as per-pixel arrays (O(pixels) each).

    The order is that of :meth:`SampleRequest.pixel_list`; no per-sample array is built here.
    """
    counts = request.counts.ravel()
    ends = np.cumsum(counts)
    starts = ends - counts
    first = request.first_index.ravel()
    total = int(ends[-1]) if ends.size else 0
    for lo in range(0, total, batch_size):
        size = min(batch_size, total - lo)
        local_ends = np.clip(ends - lo, 0, size)
        base = np.mod(first + lo - starts, 1 << 32)
        yield Chunk(size, local_ends, base, np.diff(local_ends, prepend=0))


_BLOCK = 1 << 15  # samples per block of the accumulation: its temporaries stay in the CPU's cache
# Longest run summed sample index by sample index in a block of equal runs: measured 3-6x faster than
# np.add.reduceat at 4 samples per pixel; from 32 on numpy's reduction along the runs is as fast.
_EQUAL_RUNS = 16


class PixelStatistics:
    """Exact float64 count, mean and M2 per pixel, from samples listed pixel by pixel.

    Each chunk's statistics are two-pass (the mean, then the squared deviations from it, summed
    per pixel), a block of about ``_BLOCK`` samples at a time, and chunks are combined with Chan's
    update where they share a pixel (only at chunk boundaries). Equal, to float64 rounding, to
    :meth:`SampleBuffer.from_samples` of all samples at once.

    A block whose pixels all have the same number ``r`` of samples (every block of a uniform
    request) is summed as an (C, pixels, r) array, ``r`` strided passes over the block when ``r``
    is small. Other blocks are summed per pixel by ``np.bincount`` over each sample's pixel, one
    channel at a time, in sample order like ``np.add.reduceat`` over the runs (the same bits), which
    it replaced: ``reduceat`` pays a fixed cost per run, three times ``bincount``'s time at 1-4
    samples per pixel. The statistics are kept pixel-major, as :class:`SampleBuffer` holds them,
    so that :meth:`buffer` hands its arrays over without a copy.
    """

    def __init__(self, n_pixels: int, n_channels: int) -> None:
        self.count: np.ndarray | None = np.zeros(n_pixels, np.int64)
        self.mean: np.ndarray | None = np.zeros((n_pixels, n_channels))
        self.m2: np.ndarray | None = np.zeros((n_pixels, n_channels))

    def add(self, per_pixel: np.ndarray, values: np.ndarray) -> None:
        """Add ``values`` (C, N): ``per_pixel[p]`` consecutive samples of each pixel ``p`` in turn."""
        if self.count is None or self.mean is None or self.m2 is None:
            raise RuntimeError("PixelStatistics: buffer() has taken the statistics; start a new one")
        index = np.flatnonzero(per_pixel)
        if index.size == 0:
            return
        n = per_pixel[index]
        ends = np.cumsum(n)
        starts = ends - n
        mean = np.empty((index.size, values.shape[0]))
        m2 = np.empty_like(mean)
        # Blocks end at pixel boundaries, after about _BLOCK samples each.
        cuts = np.searchsorted(ends, np.arange(_BLOCK, int(ends[-1]), _BLOCK), side="left") + 1
        bounds = np.unique(np.concatenate([[0], cuts[cuts < index.size], [index.size]]))
        for a, b in zip(bounds[:-1], bounds[1:]):
            lo, hi = int(starts[a]), int(ends[b - 1])
            runs = n[a:b]
            if runs[0] == runs[-1] and (runs == runs[0]).all():
                _equal_runs(values[:, lo:hi], int(runs[0]), mean[a:b], m2[a:b])
                continue
            pixel = np.repeat(np.arange(b - a), runs)  # each sample's pixel in the block
            for c, row in enumerate(values[:, lo:hi]):
                mu = np.bincount(pixel, weights=row, minlength=b - a)  # sums in sample order, float64
                mu /= runs
                dev = mu[pixel]
                np.subtract(row, dev, out=dev)
                np.square(dev, out=dev)
                mean[a:b, c] = mu
                m2[a:b, c] = np.bincount(pixel, weights=dev, minlength=b - a)
        # Contiguous pixels (every pixel has samples: the usual case) go through a slice, not a gather.
        where: slice | np.ndarray = (slice(int(index[0]), int(index[-1]) + 1)
                                     if index[-1] - index[0] + 1 == index.size else index)
        seen = self.count[where] > 0
        if seen.any():
            # Chan et al.'s parallel update where an earlier chunk already had samples of the pixel.
            both, nb = index[seen], n[seen, None].astype(np.float64)
            na = self.count[both, None].astype(np.float64)
            total = na + nb
            delta = mean[seen] - self.mean[both]
            self.mean[both] += delta * (nb / total)
            self.m2[both] += m2[seen] + delta * delta * (na * nb / total)
            self.count[both] += n[seen]
            where, n, mean, m2 = index[~seen], n[~seen], mean[~seen], m2[~seen]
        self.count[where] = n
        self.mean[where] = mean
        self.m2[where] = m2

    def buffer(self, shape: Shape2D, channels: Sequence[str], nonfinite: int = 0) -> SampleBuffer:
        """The statistics as a :class:`SampleBuffer`, which takes their arrays: this object is spent."""
        if self.count is None or self.mean is None or self.m2 is None:
            raise RuntimeError("PixelStatistics: buffer() has taken the statistics already")
        h, w = shape
        count, mean, variance = self.count, self.mean, self.m2
        self.count = self.mean = self.m2 = None
        variance /= np.maximum(count - 1, 1)[:, None]  # M2 -> the unbiased sample variance, in place
        return SampleBuffer._adopt(count.reshape(h, w), mean.reshape(h, w, -1), variance.reshape(h, w, -1),
                                   tuple(channels), np.ones((h, w), bool), nonfinite, {})


def _equal_runs(block: np.ndarray, r: int, mean: np.ndarray, m2: np.ndarray) -> None:
    """Two-pass statistics of a (C, pixels * r) block, ``r`` samples per pixel, into (pixels, C) ``mean``, ``m2``."""
    samples = block.reshape(block.shape[0], -1, r)
    if r > _EQUAL_RUNS:  # long runs: numpy's reduction along them is as fast, with fewer passes
        mu = np.add.reduce(samples, axis=2, dtype=np.float64)
        mu /= r
        dev = samples - mu[..., None]
        np.square(dev, out=dev)
        mean[...] = mu.T
        m2[...] = dev.sum(axis=2).T
        return
    # Short runs: one pass per sample index over the block (reductions along a short axis pay per run).
    total = samples[..., 0].astype(np.float64)
    for j in range(1, r):
        total += samples[..., j]
    total /= r
    dev = np.empty_like(total)
    squares = np.zeros_like(total)
    for j in range(r):
        np.subtract(samples[..., j], total, out=dev)
        np.square(dev, out=dev)
        squares += dev
    mean[...] = total.T
    m2[...] = squares.T
