"""The renderer boundary: a :class:`SampleRequest` goes out, a :class:`SampleBuffer` comes back.

A request is data, not a callback: per-pixel counts of new samples and, per pixel, the index
of the first new sample. A renderer that draws its random numbers as a function of
(seed, pixel, sample index, dimension) then produces the same samples however the work was
split into rounds, tiles or machines.

The renderer side is declared here as two protocols, checked with ``isinstance``:
:class:`Renderer` (a callable from request to statistics: all the samplers need) and
:class:`SampleTracer` (per-sample access, which tiled and distributed rendering use to ask a
worker for exactly a tile's samples). Renderers need not subclass either.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import secrets
import warnings
import weakref
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from . import _checks
from ._arrays import ReadOnlyArrays, check_count, frozen
from ._typing import CountArray, FloatArray, Shape2D
from .buffers import SampleBuffer
from .channels import adopted_channels

__all__ = ["SampleRequest", "Renderer", "SampleTracer", "FeatureTracer", "MAX_PART_SAMPLES", "LAST_ROUND"]

LAST_ROUND = 2**31 - 1
"""The last round a request may number (an int32 in a request map)."""

MAX_PART_SAMPLES = 2**22
"""Samples the bundled renderers hold at once (:meth:`SampleRequest.pieces`): about 0.5 GB at the tracer's
120 bytes a sample."""

# The batches each sampler was told, by identity, held weakly: a renderer that hands back one
# SampleBuffer object every round would otherwise have the same samples merged every round.
_TOLD: weakref.WeakKeyDictionary[SampleBuffer, dict[int, int]] = weakref.WeakKeyDictionary()

_sampler_ids: Iterator[int] = iter(())  # started by _renew_sampler_ids below


def _renew_sampler_ids() -> None:
    """Start this process' sampler ids at a random number below 2**30 (a request map's 32-bit header holds them).

    Counted from 1 in every process, a sampler restored from another process' pickle (a checkpoint) had the id of
    this process' first sampler, and took its requests (an attack pass). Now two processes' ids meet by a chance of
    about the number of samplers over 2**30; one process' never do."""
    global _sampler_ids
    _sampler_ids = itertools.count(secrets.randbelow(1 << 30) + 1)


_renew_sampler_ids()
if hasattr(os, "register_at_fork"):  # a forked child would go on from where its parent's ids stood
    os.register_at_fork(after_in_child=_renew_sampler_ids)


def _new_sampler_id() -> int:
    """The next sampler id of this process (:func:`_renew_sampler_ids`)."""
    return next(_sampler_ids)


@dataclass(frozen=True, eq=False)
class SampleRequest(ReadOnlyArrays):
    """Samples a renderer is asked to add in one round.

    Parameters
    ----------
    counts
        (H, W) int64, number of new samples at each pixel.
    first_index
        (H, W) int64, index of the first new sample of each pixel: the pixel's new samples
        are ``first_index, ..., first_index + counts - 1`` in its own sample sequence.
    round
        Round number within the sampler that issued it (0 is the uniform initial round).
    sampler_id
        Identifies the issuing sampler, so a request cannot be told to another one.

    Examples
    --------
    Two samples at every pixel, continuing each pixel's sequence at sample 4:

    >>> import numpy as np
    >>> from awr_denoise import SampleRequest
    >>> SampleRequest.uniform((2, 3), 2, first_index=4, round=1)
    SampleRequest(round=1, shape=(2, 3), total=12)

    A request as a sampler makes it, and the samples it stands for:

    >>> request = SampleRequest(counts=np.array([[2, 0], [0, 1]]), first_index=np.array([[4, 0], [0, 7]]))
    >>> rows, cols, sample_index = request.pixel_list()
    >>> rows.tolist(), cols.tolist(), sample_index.tolist()
    ([0, 0, 1], [0, 0, 1], [4, 5, 7])
    >>> request.crop(slice(1, 2), slice(0, 2)).counts     # the bottom row as a tile
    array([[0, 1]])
    """

    counts: CountArray
    first_index: CountArray
    round: int = 0
    sampler_id: int = 0

    def __post_init__(self) -> None:
        # check_count refuses NaN, fractions, masked entries and a uint64 past 2**62 (cast first, it read
        # as negative), naming the field; it returns a C-ordered int64 copy.
        counts = check_count(self.counts, "counts")
        first = check_count(self.first_index, "first_index", summed=False)  # indices: each within 2**62
        if counts.size == 0:
            raise ValueError(f"counts: empty image of shape {counts.shape}")
        if counts.shape != first.shape:
            raise ValueError(f"first_index: shape {first.shape} does not match counts {counts.shape}")
        # The total summed in float64 (an int64 sum would wrap to a negative number); last indices compared exactly.
        if counts.sum(dtype=np.float64) > 2**62 or (first > 2**62 - counts).any():
            raise ValueError("counts: more than 2**62 samples in all or at a pixel's last index (int64's safe range)")
        counts, first = frozen(counts), frozen(first)
        object.__setattr__(self, "counts", counts)
        object.__setattr__(self, "first_index", first)
        object.__setattr__(self, "round", _checks.whole("round", self.round, minimum=0, maximum=LAST_ROUND))
        object.__setattr__(self, "sampler_id", _checks.whole("sampler_id", self.sampler_id, minimum=0))

    @classmethod
    def uniform(cls, shape: Shape2D, spp: int, *, first_index: int = 0, round: int = 0) -> SampleRequest:
        """``spp`` samples at every pixel, starting at sample ``first_index``.

        Examples
        --------
        >>> from awr_denoise import SampleRequest
        >>> request = SampleRequest.uniform((2, 2), 3, first_index=8)
        >>> request.total, request.counts.tolist(), request.first_index.tolist()
        (12, [[3, 3], [3, 3]], [[8, 8], [8, 8]])
        """
        shape = _checks.shape2d("shape", shape, minimum=1)  # an empty image named as the shape, not the counts
        spp = _checks.whole("spp", spp, minimum=0, maximum=2**62)
        first_index = _checks.whole("first_index", first_index, minimum=0, maximum=2**62)
        counts = np.full(shape, spp, np.int64)
        return cls(counts, np.full(shape, first_index, np.int64), round)

    @property
    def shape(self) -> Shape2D:
        """(H, W) of the image."""
        return (int(self.counts.shape[0]), int(self.counts.shape[1]))

    @property
    def total(self) -> int:
        """Total number of samples requested."""
        return int(self.counts.sum())

    def pixel_list(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One row per requested sample: ``(rows, cols, sample_index)`` as int64 arrays.

        Samples of a pixel are consecutive and in increasing sample index; pixels are in
        row-major order.

        Examples
        --------
        >>> from awr_denoise import SampleRequest
        >>> rows, cols, sample_index = SampleRequest.uniform((1, 2), 2, first_index=4).pixel_list()
        >>> list(zip(rows.tolist(), cols.tolist(), sample_index.tolist()))
        [(0, 0, 4), (0, 0, 5), (0, 1, 4), (0, 1, 5)]
        """
        flat_counts = self.counts.ravel()
        pixel = np.repeat(np.arange(flat_counts.size, dtype=np.int64), flat_counts)
        starts = np.cumsum(flat_counts) - flat_counts
        offset = np.arange(pixel.size, dtype=np.int64) - np.repeat(starts, flat_counts)
        sample_index = self.first_index.ravel()[pixel] + offset
        rows, cols = np.divmod(pixel, self.counts.shape[1])
        return rows, cols, sample_index

    def pieces(self, max_samples: int) -> Iterator[tuple[int, SampleRequest]]:
        """The request in parts that together ask for exactly its samples, each of at most ``max_samples``
        where a row allows: ``(first row, part)``, the part covering that row and the ones below it, every
        column. Parts are bands of whole rows (bands without samples are left out); a row holding more
        samples alone is cut into runs of each pixel's sample sequence, of at most ``max_samples`` over
        the row's pixels with samples (at least one a pixel).

        For a renderer that holds every sample of a request at once (the bundled tracer holds about
        120 bytes a sample): a uniform 1080p round of 128 spp needed 30 GB in one part.
        :func:`~awr_denoise.parts.render_in_parts` renders them and puts the statistics together.

        Examples
        --------
        >>> import numpy as np
        >>> from awr_denoise import SampleRequest
        >>> request = SampleRequest(np.array([[3, 3], [0, 0], [1, 9]]), np.zeros((3, 2), int))
        >>> for row, part in request.pieces(6):   # row 0, then row 2 in runs of 3 samples a pixel
        ...     print(row, part.counts.tolist(), part.first_index.tolist())
        0 [[3, 3], [0, 0]] [[0, 0], [0, 0]]
        2 [[1, 3]] [[0, 0]]
        2 [[0, 3]] [[1, 3]]
        2 [[0, 3]] [[1, 6]]
        """
        max_samples = _checks.whole("max_samples", max_samples, minimum=1)
        if self.total <= max_samples:
            yield 0, self
            return
        h = self.shape[0]
        per_row = self.counts.sum(axis=1)
        reached = np.concatenate(([0], np.cumsum(per_row)))  # samples of the rows above each row
        start = 0
        while start < h:  # a step per band, not per pixel
            stop = max(start + 1, int(np.searchsorted(reached, reached[start] + max_samples, side="right")) - 1)
            if reached[stop] == reached[start]:  # rows without samples: no part
                start = stop
                continue
            if stop - start > 1 or per_row[start] <= max_samples:
                yield start, self.crop(slice(start, stop), slice(None))
            else:  # one row holding more: runs of each pixel's sequence, shared by the pixels with samples
                row, first = self.counts[start:stop], self.first_index[start:stop]
                run = max(1, max_samples // int(np.count_nonzero(row)))
                for done in range(0, int(row.max()), run):
                    yield start, SampleRequest(np.clip(row - done, 0, run), first + np.minimum(done, row),
                                               self.round, self.sampler_id)
            start = stop

    def crop(self, rows: slice, cols: slice) -> SampleRequest:
        """The part of the request inside a tile (same round and sampler).

        Examples
        --------
        >>> import numpy as np
        >>> from awr_denoise import SampleRequest
        >>> request = SampleRequest(np.arange(6).reshape(2, 3), np.zeros((2, 3), int), round=2)
        >>> tile = request.crop(slice(0, 2), slice(1, 3))
        >>> tile, tile.counts.tolist()
        (SampleRequest(round=2, shape=(2, 2), total=12), [[1, 2], [4, 5]])
        """
        _checks.tile(self.shape, rows, cols)
        return SampleRequest(self.counts[rows, cols], self.first_index[rows, cols], self.round, self.sampler_id)

    def check_answer(self, samples: SampleBuffer, channels: tuple[str, ...]) -> SampleBuffer:
        """``samples`` checked as the renderer's answer to this request, for an image of ``channels``.

        What :meth:`Sampler.tell <awr_denoise.sampling.Sampler.tell>` checks before it merges
        (paper section 4: each round adds the samples its request asked for): the image's shape and
        channels, no pixel with more samples than asked (in the radiance or a feature), and not the very
        buffer object told for another
        round of the same sampler (a renderer returning its one buffer every round). Fewer
        samples than asked warn (a renderer may drop some). Unnamed channels take ``channels``.

        Examples
        --------
        >>> import numpy as np
        >>> from awr_denoise import SampleBuffer, SampleRequest
        >>> request = SampleRequest.uniform((1, 2), 1)
        >>> batch = SampleBuffer.from_samples(np.array([0, 1]), np.array([0.5, 2.0]), (1, 2))
        >>> request.check_answer(batch, ("Y",)).channels
        ('Y',)
        >>> SampleRequest.uniform((1, 2), 0).check_answer(batch, ("Y",))
        Traceback (most recent call last):
            ...
        ValueError: samples: 2 pixel(s) hold more samples than requested
        """
        if not isinstance(samples, SampleBuffer):
            raise TypeError(f"samples: expected a SampleBuffer, got {type(samples).__name__}")
        if samples.shape != self.shape:
            raise ValueError(f"samples: shape {samples.shape} does not match the sampler's {self.shape}")
        if samples.n_channels != len(channels):
            raise ValueError(f"samples: {samples.n_channels} channel(s), the sampler expects {len(channels)}")
        told = _TOLD.setdefault(samples, {})
        # Another round of the same sampler: a renderer's one buffer again (a copy of the sampler, a
        # snapshot restored, may tell it for its own round once more). An empty buffer adds nothing.
        # Checked before the counts, which such a buffer usually exceeds: that message would hide the cause.
        if told.get(self.sampler_id, self.round) != self.round and samples.total_samples:
            raise ValueError(f"samples: the SampleBuffer told for round {told[self.sampler_id]} again: a renderer "
                             "must return a new buffer of new samples for every request")
        over = samples.count > self.counts
        if over.any():
            raise ValueError(f"samples: {int(over.sum())} pixel(s) hold more samples than requested")
        for name, feature in samples.features.items():  # one feature value per sample at most (a first hit's)
            over = feature.count > self.counts
            if over.any():  # merged as they were, a depth of 1000 samples a pixel beside radiance of 4 (an attack pass)
                raise ValueError(f"samples: features[{name!r}]: {int(over.sum())} pixel(s) hold more samples than "
                                 "requested")
        short = int((self.counts - samples.count).sum())
        if short:
            warnings.warn(f"samples: {short} requested sample(s) missing (dropped by the renderer?)", stacklevel=3)
        if samples.channels != channels:  # unnamed channels take the sampler's names; others must match
            samples = dataclasses.replace(samples, channels=adopted_channels(samples.channels, channels))
        return samples

    def mark_told(self, samples: SampleBuffer) -> None:
        """Remember ``samples`` (the object) as told for this request's round (:meth:`check_answer`)."""
        _TOLD.setdefault(samples, {})[self.sampler_id] = self.round

    def __repr__(self) -> str:
        return f"SampleRequest(round={self.round}, shape={self.shape}, total={self.total})"


@runtime_checkable
class Renderer(Protocol):
    """Anything that renders the samples of a request and returns their statistics.

    The returned buffer has the request's shape and, at every pixel, ``count`` equal to the
    request's ``counts`` (a renderer that had to drop non-finite samples may return fewer;
    the sampler warns). A renderer asked for features when it was made (the bundled tracer's
    ``features=``) returns them in the buffer's ``features``, one value per sample; requests
    are the same either way. Implementations need not subclass this protocol.

    Examples
    --------
    >>> from awr_denoise import Renderer, SampleRequest
    >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
    >>> renderer = SyntheticRenderer(make_scene("edges", (8, 8)))
    >>> isinstance(renderer, Renderer), isinstance("edges.exr", Renderer)
    (True, False)
    >>> renderer(SampleRequest.uniform((8, 8), 2)).total_samples
    128
    """

    def __call__(self, request: SampleRequest) -> SampleBuffer: ...


@runtime_checkable
class SampleTracer(Protocol):
    """A renderer that can also trace any list of individual samples.

    Tiled and distributed rendering (:mod:`awr_denoise.parallel`) ask such a renderer for
    exactly a tile's samples instead of a full-frame request; the ``awr render`` command reports
    its statistics and closes it. The bundled path tracer, the synthetic renderer and the
    Mitsuba 3 adapter implement it.

    Attributes
    ----------
    channels
        Names of the C channels :meth:`trace_samples` returns.
    shape
        (H, W) of the image.
    stats
        Running counters; at least ``"samples"``, ``"nonfinite"`` (samples whose value was not
        finite and was dropped or zeroed) and ``"seconds"``.

    Examples
    --------
    A plain function is a :class:`Renderer` but not a ``SampleTracer``:

    >>> import numpy as np
    >>> from awr_denoise.requests import Renderer, SampleTracer
    >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
    >>> tracer = SyntheticRenderer(make_scene("edges", (8, 8)))
    >>> isinstance(tracer, SampleTracer), isinstance(lambda request: None, SampleTracer)
    (True, False)
    >>> tracer.trace_samples(np.array([0, 7]), np.array([0, 7]), np.array([0, 0])).shape
    (2, 3)
    """

    channels: tuple[str, ...]
    stats: dict[str, float]

    @property
    def shape(self) -> Shape2D: ...

    def trace_samples(self, rows: np.ndarray, cols: np.ndarray, sample_index: np.ndarray) -> FloatArray:
        """(N, C) values of the samples ``(rows[i], cols[i], sample_index[i])``."""
        ...

    def close(self) -> None:
        """Release worker pools or native resources; the renderer is not used afterwards."""
        ...


@runtime_checkable
class FeatureTracer(SampleTracer, Protocol):
    """A :class:`SampleTracer` that can also return each sample's features (albedo, normal, depth).

    Tiled rendering asks it for a tile's samples with their features, so the tile's buffer
    carries them (:mod:`awr_denoise.features`).

    Attributes
    ----------
    features
        Names of the features :meth:`trace_features` returns (empty: none).

    Examples
    --------
    >>> from awr_denoise.requests import FeatureTracer
    >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
    >>> isinstance(SyntheticRenderer(make_scene("edges", (8, 8))), FeatureTracer)
    False
    """

    features: tuple[str, ...]

    def trace_features(self, rows: np.ndarray, cols: np.ndarray,
                       sample_index: np.ndarray) -> tuple[FloatArray, dict[str, FloatArray]]:
        """(N, C) values of the samples as :meth:`trace_samples`, and ``{name: (N, channels)}`` features."""
        ...
