"""Per-sample dumps in deep EXR: every Monte Carlo sample of every pixel.

Deep EXR was made for depth samples (``Z``, ``A``, composited with "over"); a Monte Carlo
dump reuses the container with other meaning, so it never has ``Z``/``A``/``ZBack``
channels (compositing tools would flatten it) and carries ``awr:semantics =
"mc-samples"``. Channels are the sample values (``R``, ``G``, ``B`` by default) and,
optionally, ``sampleIndex`` (FLOAT, the sample's index in its pixel's sequence). Deep parts
allow only NONE/RLE/ZIPS compression; ZIPS is used.

OpenEXR's Python bindings hold deep channels as (H, W) object arrays of per-pixel arrays;
samples are grouped and split with array operations, never per-sample Python code.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .._arrays import numeric
from .._typing import FloatArray, Shape2D
from ..buffers import NONFINITE_POLICIES, SampleBuffer
from ..requests import SampleRequest
from .._version import __version__
from .dump import exact_counts
from . import chunks
from .exr import ExrPart, checked_plane, file_error, header_value, read_exr, write_exr

__all__ = ["SEMANTICS_SAMPLES", "SAMPLE_INDEX_CHANNEL", "read_deep_samples", "write_deep_samples",
           "samples_from_deep_part", "sample_index_bounds", "check_answers", "IndexBounds"]

SEMANTICS_SAMPLES = "mc-samples"
SAMPLE_INDEX_CHANNEL = "sampleIndex"
_DEPTH_CHANNELS = frozenset({"Z", "ZBack", "A"})


def _object_grid(pieces: Sequence[np.ndarray], shape: Shape2D) -> np.ndarray:
    # fromiter never tries to stack equal-length pieces into a 2-D array.
    return np.fromiter(pieces, dtype=object, count=len(pieces)).reshape(shape)


def write_deep_samples(
    path: str | os.PathLike[str],
    pixels: np.ndarray,
    values: FloatArray,
    shape: Shape2D,
    *,
    channels: Sequence[str] = ("R", "G", "B"),
    sample_index: np.ndarray | None = None,
    header: Mapping[str, Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write raw samples to a deep EXR, atomically.

    Parameters
    ----------
    pixels
        (N, 2) ``(row, column)`` or (N,) flat row-major pixel of each sample.
    values
        (N, C) or (N,) finite sample values (stored as float32).
    shape
        (H, W) of the image.
    channels
        C channel names; ``Z``, ``ZBack`` and ``A`` are refused (depth-compositing meaning).
    sample_index
        Optional (N,) index of each sample in its pixel's sequence (exact below 2**24).
    header
        Extra attributes (``awr:seed``...).
    overwrite
        Replace an existing file.
    """
    h, w = (int(s) for s in shape)
    # Reuse SampleBuffer's validation of coordinates and values.
    check = SampleBuffer.from_samples(pixels, values, (h, w), channels=channels)
    names = check.channels
    bad = _DEPTH_CHANNELS.intersection(names) | ({SAMPLE_INDEX_CHANNEL} & set(names))
    if bad:
        raise ValueError(f"channels: {', '.join(sorted(bad))} would be read as depth data or clash; rename them")
    p = np.asarray(pixels)
    flat = (p[:, 0].astype(np.int64) * w + p[:, 1].astype(np.int64)) if p.ndim == 2 else p.astype(np.int64)
    vals = np.asarray(values, dtype=np.float64).reshape(flat.size, check.n_channels)  # also no samples at all
    order = np.argsort(flat, kind="stable")
    sizes = np.bincount(flat, minlength=h * w)
    bounds = np.cumsum(sizes)[:-1]
    planes: dict[str, np.ndarray] = {}
    for c, name in enumerate(names):  # a loop over channels; pixels and samples are vectorised
        planes[name] = _object_grid(np.split(vals[order, c].astype(np.float32), bounds), (h, w))
    if sample_index is not None:
        idx = numeric("sample_index", sample_index)
        if idx.shape != (flat.size,):
            raise ValueError(f"sample_index: expected shape ({flat.size},), got {idx.shape}")
        indices = exact_counts("sample_index", idx, what="sample indices", unit="sample(s)")
        planes[SAMPLE_INDEX_CHANNEL] = _object_grid(np.split(indices[order], bounds), (h, w))
    # The total lets the reader catch a count table that disagrees with the data: OpenEXR
    # tolerates surplus sample data, and its Python binding does not expose chunk sizes.
    attrs: dict[str, Any] = {"awr:semantics": SEMANTICS_SAMPLES, "awr:channels": ",".join(names),
                             "awr:version": __version__, "awr:samples": str(int(flat.size))}
    attrs.update(header or {})
    return write_exr(path, planes, attrs, overwrite=overwrite, deep=True)


_PIXEL_TYPE_BYTES = {0: 4, 1: 2, 2: 4}  # UINT, HALF, FLOAT


def _unpacked_sample_bytes(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    """(sum of the chunks' unpacked sample-data sizes, bytes per sample) of a single-part deep
    scanline file, read from the raw chunk headers (:mod:`.chunks`), or None where the layout is not that.

    Each deep scanline chunk starts with ``int32 y, uint64 packed table size, uint64 packed data
    size, uint64 unpacked data size`` (OpenEXR file layout), uncompressed, so the data the file
    really holds can be checked against the count table without decompressing anything. Read with
    seeks: the whole file read into memory made a valid dump of gigabytes "out of memory" (a red-team pass).
    """
    with open(path, "rb") as fh:
        found = chunks.layout(fh)
        if found is None or not found.deep or found.attributes.get(b"type", (b"", b""))[1].rstrip(b"\x00") != \
                b"deepscanline":
            return None
        headers = chunks.chunk_headers(fh, found)
    if headers is None:
        return None  # unreadable layout: the bindings' own checks have already run
    value, channels, i = found.attributes.get(b"channels", (b"", b"\x00"))[1], [], 0
    try:
        while value[i] != 0:
            i = value.index(b"\x00", i) + 1
            channels.append(int.from_bytes(value[i:i + 4], "little"))
            i += 16
        per_sample = sum(_PIXEL_TYPE_BYTES[t] for t in channels)
    except (IndexError, ValueError, KeyError):
        return None
    return sum(h[3] for h in headers), per_sample


def _sizes(grid: np.ndarray) -> np.ndarray:
    flat = grid.ravel()
    return np.fromiter(map(lambda a: 0 if a is None else a.size, flat), dtype=np.int64, count=flat.size)


def samples_from_deep_part(path: str | os.PathLike[str], part: ExrPart, *, nonfinite: str = "raise") -> SampleBuffer:
    """Statistics of the samples in a deep part marked ``awr:semantics = "mc-samples"``.

    ``nonfinite`` is the policy of :meth:`SampleBuffer.from_samples` for NaN/Inf samples:
    ``"raise"`` (an :class:`~awr_denoise.errors.InputFileError` naming the channel), ``"drop"``
    or ``"zero"`` (counted in the buffer's ``nonfinite``).
    """
    if nonfinite not in NONFINITE_POLICIES:
        raise ValueError(f"nonfinite: {nonfinite!r} is not one of {', '.join(NONFINITE_POLICIES)}")
    semantics = str(header_value(part.header, "awr:semantics")) if "awr:semantics" in part.header else None
    if semantics != SEMANTICS_SAMPLES:
        raise file_error(path, "deep EXR without awr:semantics = \"mc-samples\" (depth samples are not "
                               "Monte Carlo samples)", "awr:semantics")
    if "awr:channels" in part.header:
        names = [n for n in str(header_value(part.header, "awr:channels")).split(",") if n]
    else:
        names = sorted(n for n in part.channels if n not in _DEPTH_CHANNELS | {SAMPLE_INDEX_CHANNEL})
    if not names:
        held = ", ".join(sorted(part.channels)) or "none"
        what = ("names no channel" if "awr:channels" in part.header
                else "is not given, and no channel but the sample index and depth ones is held")
        raise file_error(path, f"{what}: no sample values to read (channels: {held})", "awr:channels")
    reserved = sorted((_DEPTH_CHANNELS | {SAMPLE_INDEX_CHANNEL}).intersection(names))
    if reserved:  # the sample's index or depth compositing's channels: never a sample's value
        raise file_error(path, f"names {', '.join(reserved)}, which a Monte Carlo sample dump reserves "
                               "(the sample's index, depth compositing): not sample values", "awr:channels")
    for name in names:
        if name not in part.channels:
            raise file_error(path, "missing", name)
    h, w = part.shape
    sizes = _sizes(part.channels[names[0]])
    chunk_bytes = _unpacked_sample_bytes(path)
    if chunk_bytes is not None and chunk_bytes[0] != int(sizes.sum()) * chunk_bytes[1]:
        raise file_error(path, f"the sample count tables hold {int(sizes.sum())} samples but the chunks "
                               f"hold {chunk_bytes[0] // max(chunk_bytes[1], 1)} (corrupt count table)")
    if "awr:samples" in part.header:
        declared = str(header_value(part.header, "awr:samples"))
        if not declared.isdigit() or int(declared) != int(sizes.sum()):
            # A tool that cropped or edited the file keeps the header: both said (an attack pass: "corrupt" alone).
            raise file_error(path, f"the sample count table holds {int(sizes.sum())} samples but the file "
                                   f"declares {declared}: a corrupt count table, or a header kept by a tool that "
                                   "cropped or edited the samples", "awr:samples")
    nonempty = sizes > 0
    columns = []
    for name in names:
        flat = part.channels[name].ravel()
        if not np.array_equal(_sizes(part.channels[name]), sizes):
            raise file_error(path, "sample counts differ from the other channels", name)
        data = np.concatenate(flat[nonempty]) if nonempty.any() else np.zeros(0, np.float32)
        if nonfinite == "raise":
            columns.append(checked_plane(path, name, data, unit="sample"))
        elif data.dtype.kind != "f":
            raise file_error(path, f"unsupported channel type {data.dtype}", name)
        else:
            columns.append(data.astype(np.float64))
    values = np.stack(columns, axis=-1)
    pixel = np.repeat(np.arange(h * w, dtype=np.int64), sizes)
    return SampleBuffer.from_samples(pixel, values, (h, w), channels=names, nonfinite=nonfinite)


def read_deep_samples(path: str | os.PathLike[str], *, nonfinite: str = "raise") -> SampleBuffer:
    """Read a deep per-sample dump into per-pixel statistics.

    ``nonfinite``: ``"raise"`` (default), ``"drop"`` or ``"zero"`` for NaN/Inf samples; dropped
    or zeroed samples are counted in the buffer's ``nonfinite``.

    Raises
    ------
    InputFileError
        Not a deep EXR, not marked ``awr:semantics = "mc-samples"``, missing channels,
        NaN/Inf samples.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from awr_denoise.io import write_deep_samples, read_deep_samples
    >>> f = os.path.join(tempfile.mkdtemp(), "s.exr")
    >>> _ = write_deep_samples(f, np.array([0, 0, 3]), np.ones((3, 3)), (2, 2))
    >>> read_deep_samples(f).count.tolist()
    [[2, 0], [0, 1]]
    """
    parts = read_exr(path)
    deep = [part for part in parts if part.deep]
    if not deep:
        raise file_error(path, "is not a deep EXR")
    return samples_from_deep_part(Path(path), deep[0], nonfinite=nonfinite)


class IndexBounds(NamedTuple):
    """Each pixel's recorded sample indices: the lowest and one past the highest (0 and 0 at pixels
    without samples), and the indices repeated within a pixel (their number, the first's row,
    column and index), which only a loop's batch must not have."""

    low: np.ndarray
    high: np.ndarray
    repeated: int = 0
    first_repeat: tuple[int, int, int] | None = None


def sample_index_bounds(path: str | os.PathLike[str], part: ExrPart) -> IndexBounds | None:
    """The :class:`IndexBounds` of a deep part's ``sampleIndex``, or ``None`` when it has none.

    Raises
    ------
    InputFileError
        Indices that are not whole, non-negative and exact in float32.
    """
    if SAMPLE_INDEX_CHANNEL not in part.channels:
        return None
    grid = part.channels[SAMPLE_INDEX_CHANNEL]
    sizes = _sizes(grid)
    flat = grid.ravel()
    nonempty = sizes > 0
    raw = np.concatenate(flat[nonempty]) if nonempty.any() else np.zeros(0, np.float32)
    try:
        index = exact_counts(SAMPLE_INDEX_CHANNEL, raw, what="sample indices", unit="sample(s)").astype(np.int64)
    except ValueError as exc:
        raise file_error(path, str(exc).split(": ", 1)[-1], SAMPLE_INDEX_CHANNEL) from None
    pixel = np.repeat(np.arange(sizes.size, dtype=np.int64), sizes)
    order = np.lexsort((index, pixel))
    index, pixel = index[order], pixel[order]
    repeated = (pixel[1:] == pixel[:-1]) & (index[1:] == index[:-1])
    first = None
    if repeated.any():
        row, col = divmod(int(pixel[1:][repeated][0]), part.shape[1])
        first = (row, col, int(index[1:][repeated][0]))
    low, high = np.zeros(sizes.size, np.int64), np.zeros(sizes.size, np.int64)
    ends = np.cumsum(sizes)
    low[nonempty] = index[(ends - sizes)[nonempty]]
    high[nonempty] = index[ends[nonempty] - 1] + 1
    return IndexBounds(low.reshape(part.shape), high.reshape(part.shape), int(repeated.sum()), first)


def check_answers(path: str | os.PathLike[str], bounds: IndexBounds | tuple[np.ndarray, np.ndarray],
                  request: SampleRequest) -> None:
    """Refuse a batch whose recorded sample indices are not the ones ``request`` issued.

    A pixel's samples must lie in ``first_index .. first_index + counts - 1``, each once: indices
    from 0 (a renderer that ignored ``first_index``) repeat the dump's samples, another round's
    batch answers another request, and an index twice is the same sample twice.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleRequest
    >>> request = SampleRequest.uniform((1, 2), 2, first_index=4, round=2)
    >>> check_answers("b.exr", (np.array([[4, 4]]), np.array([[6, 5]])), request)
    >>> check_answers("b.exr", IndexBounds(np.array([[0, 4]]), np.array([[2, 5]])), request)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    awr_denoise.errors.InputFileError: b.exr: sampleIndex: 1 pixel(s) hold samples outside ... issued 4..5): ...
    """
    bounds = IndexBounds(*bounds)  # a (low, high) pair too
    if bounds.repeated:
        row, col, index = bounds.first_repeat  # type: ignore[misc]
        raise file_error(path, f"{bounds.repeated} sample(s) repeat an index of their pixel (first at row {row}, "
                               f"column {col}: index {index}): the same sample twice", SAMPLE_INDEX_CHANNEL)
    low, high = bounds.low, bounds.high
    first = np.asarray(request.first_index, np.int64)
    end = first + np.asarray(request.counts, np.int64)
    outside = (high > low) & ((low < first) | (high > end))
    if outside.any():
        row, col = (int(i) for i in np.argwhere(outside)[0])
        raise file_error(path, f"{int(outside.sum())} pixel(s) hold samples outside the indices their request issued "
                               f"(first at row {row}, column {col}: {low[row, col]}..{high[row, col] - 1}, issued "
                               f"{first[row, col]}..{end[row, col] - 1}): another round's batch, or a renderer that "
                               "ignored first_index", SAMPLE_INDEX_CHANNEL)
