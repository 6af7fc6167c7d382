"""A request rendered in parts, and the statistics of disjoint tiles put side by side.

A renderer that holds every sample of what it renders at once (the bundled tracer: about 120 bytes a
sample) renders a large request part by part (:meth:`~awr_denoise.SampleRequest.pieces`): bands of whole
rows, whose statistics are put side by side with no arithmetic (bit for bit those of the whole request),
and runs of one row's samples, merged exactly (Chan's update, to rounding).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ._typing import Shape2D
from .buffers import SampleBuffer
from .requests import MAX_PART_SAMPLES, SampleRequest

__all__ = ["render_in_parts", "stitch"]


def render_in_parts(request: SampleRequest, render_part: Callable[[int, SampleRequest], SampleBuffer],
                    max_samples: int = MAX_PART_SAMPLES) -> SampleBuffer:
    """The statistics of ``request``, rendered in parts of at most ``max_samples`` samples where a row allows.

    Parameters
    ----------
    request
        What to render.
    render_part
        ``render_part(first_row, part)``: the statistics of ``part`` (its own shape), whose row 0 is the
        image's row ``first_row``.
    max_samples
        The most samples of one part (:meth:`~awr_denoise.SampleRequest.pieces`).

    Returns
    -------
    SampleBuffer
        The request's statistics; non-finite counts summed over the parts.

    Examples
    --------
    >>> from awr_denoise import SampleBuffer, SampleRequest
    >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
    >>> renderer, request = SyntheticRenderer(make_scene("edges", (8, 8))), SampleRequest.uniform((8, 8), 4)
    >>> def rows(first_row, part):   # the part's samples, traced at their rows of the image
    ...     r, c, index = part.pixel_list()
    ...     values = renderer.trace_samples(r + first_row, c, index)
    ...     return SampleBuffer.from_samples(r * part.shape[1] + c, values, part.shape)
    >>> parts = render_in_parts(request, rows, max_samples=64)   # four bands of two rows
    >>> bool((parts.mean == renderer(request).mean).all()), parts.total_samples
    (True, 256)
    """
    bands: list[tuple[int, SampleBuffer]] = []
    for first_row, part in request.pieces(max_samples):
        told = _checked(render_part(first_row, part), part, first_row, bands[0][1] if bands else None)
        if bands and bands[-1][0] == first_row:  # the next run of one row's samples
            bands[-1] = (first_row, bands[-1][1].merge(told))
        else:
            bands.append((first_row, told))
    if len(bands) == 1 and bands[0][1].shape == request.shape:
        return bands[0][1]
    windows = [(slice(row, row + band.shape[0]), slice(None)) for row, band in bands]
    return stitch(request.shape, windows, [band for _, band in bands])


def _checked(told: object, part: SampleRequest, first_row: int, first: SampleBuffer | None) -> SampleBuffer:
    """``told`` if it is the statistics of ``part`` (its shape, the first part's channels), else a TypeError or
    ValueError naming the part: merged or stitched, a wrong answer gave numpy's broadcasting error."""
    last = first_row + part.shape[0] - 1
    rows = f"render_part: the part of row {first_row}" if last == first_row else \
        f"render_part: the part of rows {first_row}-{last}"
    if not isinstance(told, SampleBuffer):
        raise TypeError(f"{rows} came back as {type(told).__name__}, not a SampleBuffer")
    if told.shape != part.shape:
        raise ValueError(f"{rows} came back with shape {told.shape}, not the part's {part.shape}")
    if first is not None and told.channels != first.channels:
        raise ValueError(f"{rows} came back with channels {told.channels}, not the first part's {first.channels}")
    return told


def stitch(shape: Shape2D, windows: Sequence[tuple[slice, slice]], parts: Sequence[SampleBuffer]) -> SampleBuffer:
    """The statistics of disjoint ``parts`` put side by side in an image of ``shape`` (features too), with no
    arithmetic; pixels in no window hold no sample.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> top = SampleBuffer.from_moments(np.full((1, 3), 2), np.ones((1, 3)), np.zeros((1, 3)))
    >>> stitch((2, 3), [(slice(0, 1), slice(None))], [top]).count.tolist()
    [[2, 2, 2], [0, 0, 0]]
    """
    if not parts or len(parts) != len(windows):
        raise ValueError(f"parts: {len(parts)} part(s) for {len(windows)} window(s); at least one of each, as many")
    first = parts[0]
    count = np.zeros(shape, np.int64)
    mean = np.zeros(tuple(shape) + (first.n_channels,))
    variance = np.zeros_like(mean)
    known = np.zeros(shape, bool)
    for window, part in zip(windows, parts):
        count[window], mean[window], variance[window], known[window] = (part.count, part.mean, part.variance,
                                                                        part.variance_known)
    features = {name: stitch(shape, windows, [p.features[name] for p in parts]) for name in first.features}
    return SampleBuffer(count, mean, variance, first.channels, known, sum(p.nonfinite for p in parts), features)
