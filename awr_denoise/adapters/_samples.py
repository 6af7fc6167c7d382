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


class PixelStatistics:
    """Exact float64 count, mean and M2 per pixel, from samples listed pixel by pixel.

    Each chunk's statistics are two-pass (the mean, then the squared deviations from it, summed
    per pixel with ``np.add.reduceat`` over the runs of consecutive samples), a block of about
    ``_BLOCK`` samples and one channel at a time, and chunks are combined with Chan's update where
    they share a pixel (only at chunk boundaries). Equal, to float64 rounding, to
    :meth:`SampleBuffer.from_samples` of all samples at once.
    """

    def __init__(self, n_pixels: int, n_channels: int) -> None:
        self.count = np.zeros(n_pixels, np.int64)
        self.mean = np.zeros((n_channels, n_pixels))
        self.m2 = np.zeros((n_channels, n_pixels))

    def add(self, per_pixel: np.ndarray, values: np.ndarray) -> None:
        """Add ``values`` (C, N): ``per_pixel[p]`` consecutive samples of each pixel ``p`` in turn."""
        index = np.flatnonzero(per_pixel)
        if index.size == 0:
            return
        n = per_pixel[index]
        ends = np.cumsum(n)
        starts = ends - n
        mean = np.empty((values.shape[0], index.size))
        m2 = np.empty_like(mean)
        # Blocks end at pixel boundaries, after about _BLOCK samples each.
        cuts = np.searchsorted(ends, np.arange(_BLOCK, int(ends[-1]), _BLOCK), side="left") + 1
        bounds = np.unique(np.concatenate([[0], cuts[cuts < index.size], [index.size]]))
        for a, b in zip(bounds[:-1], bounds[1:]):
            lo, hi = int(starts[a]), int(ends[b - 1])
            runs, run_starts = n[a:b], starts[a:b] - lo
            for c, row in enumerate(values[:, lo:hi]):
                mu = np.add.reduceat(row, run_starts, dtype=np.float64) / runs
                dev = np.repeat(mu, runs)
                np.subtract(row, dev, out=dev)
                np.square(dev, out=dev)
                mean[c, a:b] = mu
                m2[c, a:b] = np.add.reduceat(dev, run_starts)
        # Contiguous pixels (every pixel has samples: the usual case) go through a slice, not a gather.
        where: slice | np.ndarray = (slice(int(index[0]), int(index[-1]) + 1)
                                     if index[-1] - index[0] + 1 == index.size else index)
        seen = self.count[where] > 0
        if seen.any():
            # Chan et al.'s parallel update where an earlier chunk already had samples of the pixel.
            both, nb = index[seen], n[seen].astype(np.float64)
            na = self.count[both].astype(np.float64)
            total = na + nb
            delta = mean[:, seen] - self.mean[:, both]
            self.mean[:, both] += delta * (nb / total)
            self.m2[:, both] += m2[:, seen] + delta * delta * (na * nb / total)
            self.count[both] += n[seen]
            where, n, mean, m2 = index[~seen], n[~seen], mean[:, ~seen], m2[:, ~seen]
        self.count[where] = n
        self.mean[:, where] = mean
        self.m2[:, where] = m2

    def buffer(self, shape: Shape2D, channels: Sequence[str], nonfinite: int = 0) -> SampleBuffer:
        h, w = shape
        variance = self.m2 / np.maximum(self.count - 1, 1)
        return SampleBuffer(self.count.reshape(h, w), self.mean.T.reshape(h, w, -1), variance.T.reshape(h, w, -1),
                            tuple(channels), np.ones((h, w), bool), nonfinite)
