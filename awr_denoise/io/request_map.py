"""Request maps: a :class:`~awr_denoise.SampleRequest` as an EXR an external renderer can read.

Channels (FLOAT, whole numbers, exact up to 2**24)::

    counts        new samples to render at each pixel
    first_index   index of the first new sample of each pixel in its own sequence

Header: ``awr:semantics = "sample-request"``, ``awr:round``, ``awr:sampler_id``,
``awr:total`` (sum of ``counts``, a checksum), ``awr:version``, and whatever the caller adds
(``awr:seed``). The renderer renders samples ``first_index .. first_index + counts - 1`` of
each pixel and writes a dump in the layout of :mod:`awr_denoise.io.dump`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .. import _checks
from .._version import __version__
from ..requests import SampleRequest
from .dump import MAX_EXACT_COUNT, checked_header, exact_counts, header_count, whole_counts
from .exr import file_error, header_value, read_exr, write_exr

__all__ = ["COUNTS_CHANNEL", "FIRST_INDEX_CHANNEL", "SEMANTICS_REQUEST", "read_request", "write_request",
           "request_attributes", "MAX_ROUND"]

MAX_ROUND = 2**31 - 2
"""The largest round a request map or a dump may carry (``awr:round``): every tool reads what another
writes, and ``awr merge`` writes the round after the last (a 32-bit signed attribute holds one more)."""

COUNTS_CHANNEL = "counts"
FIRST_INDEX_CHANNEL = "first_index"
SEMANTICS_REQUEST = "sample-request"


def write_request(path: str | os.PathLike[str], request: SampleRequest, *, seed: int | None = None,
                  header: Mapping[str, Any] | None = None, overwrite: bool = False) -> Path:
    """Write a request map, atomically.

    Parameters
    ----------
    path
        Target EXR file.
    request
        The request; ``counts`` and ``first_index`` must stay below 2**24 (float32 exact).
    seed
        The run's seed (``awr:seed``), which a renderer reading the request draws its sequences from:
        the sampler's own (``AdaptiveSampler(..., seed=7)``). A request carries none of its own, so
        without it the file names none and such a renderer falls back to its default.
    header
        Extra attributes (``awr:`` names; ``awr:strategy``, ...); the layout's own (``awr:round``,
        ``awr:total``, ``awr:sampler_id``, ``awr:semantics``) are written from ``request`` and are
        refused here with another value (``ValueError``), as is a round beyond :data:`MAX_ROUND`.
    overwrite
        Replace an existing file.

    Examples
    --------
    >>> import tempfile, os
    >>> from awr_denoise import SampleRequest
    >>> from awr_denoise.io import write_request, read_request, request_attributes
    >>> f = os.path.join(tempfile.mkdtemp(), "req.exr")
    >>> _ = write_request(f, SampleRequest.uniform((2, 3), 4, first_index=8, round=1), seed=7)
    >>> r = read_request(f); (r.total, int(r.first_index[0, 0]), r.round)
    (24, 8, 1)
    >>> request_attributes(f)["awr:seed"]
    7
    """
    if not isinstance(request, SampleRequest):
        raise TypeError(f"request: expected a SampleRequest, got {type(request).__name__}")
    if seed is not None:
        seed = _checks.seed("seed", seed)
        if header and "awr:seed" in header and str(header["awr:seed"]).strip() != str(seed):  # stored as text past 2**31
            raise ValueError(f"seed: {seed} differs from the header's awr:seed {header['awr:seed']!r}")
    if request.round > MAX_ROUND:  # the reader's bound: a file no tool would read again is not written
        raise ValueError(f"request: round {request.round} is beyond the last a request map records ({MAX_ROUND})")
    # The last sample index must be exact too, so the renderer can trust first_index + counts.
    exact_counts("first_index + counts", request.first_index + request.counts)
    planes = {COUNTS_CHANNEL: exact_counts("counts", request.counts),
              FIRST_INDEX_CHANNEL: exact_counts("first_index", request.first_index)}
    attrs: dict[str, Any] = {
        "awr:semantics": SEMANTICS_REQUEST,
        "awr:round": int(request.round),
        "awr:sampler_id": int(request.sampler_id),
        "awr:total": int(request.total),
        "awr:version": __version__,
    }
    attrs.update(checked_header(header, attrs))
    if seed is not None:
        attrs["awr:seed"] = seed
    return write_exr(path, planes, attrs, overwrite=overwrite)


def read_request(path: str | os.PathLike[str]) -> SampleRequest:
    """Read a request map written by :func:`write_request` (or by any tool in that layout).

    Raises
    ------
    InputFileError
        Missing channels, fractional/negative/non-finite values, or counts whose sum
        disagrees with ``awr:total``.
    """
    p = Path(path)
    parts = [part for part in read_exr(p) if not part.deep and COUNTS_CHANNEL in part.channels]
    if not parts:
        raise file_error(p, "missing (not a request map)", COUNTS_CHANNEL)
    part = parts[0]
    if FIRST_INDEX_CHANNEL not in part.channels:
        raise file_error(p, "missing (not a request map)", FIRST_INDEX_CHANNEL)
    counts = whole_counts(p, COUNTS_CHANNEL, part.channels[COUNTS_CHANNEL])
    first = whole_counts(p, FIRST_INDEX_CHANNEL, part.channels[FIRST_INDEX_CHANNEL])
    attrs = {k: header_value(part.header, k) for k in part.header if str(k).startswith("awr:")}

    def _int(key: str, default: int, high: int = 2**62) -> int:
        return header_count(p, attrs, key, default, high)

    beyond = int((first.astype(np.int64) + counts.astype(np.int64) > MAX_EXACT_COUNT).sum())
    if beyond:  # as write_request refuses: the dump merged from it could not record the samples issued
        raise file_error(p, f"{beyond} pixel(s) would issue samples past index {MAX_EXACT_COUNT} (2**24), "
                            "beyond what a dump records exactly", COUNTS_CHANNEL)
    total = attrs.get("awr:total")
    if total is not None and _int("awr:total", 0) != int(counts.sum()):
        raise file_error(p, f"counts sum to {int(counts.sum())} but awr:total says {total}", COUNTS_CHANNEL)
    return SampleRequest(counts, first, _int("awr:round", 0, MAX_ROUND), _int("awr:sampler_id", 0))


def request_attributes(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The ``awr:*`` header attributes of a request map (seed, round, ...)."""
    parts = read_exr(path, header_only=True)
    return {k: header_value(parts[0].header, k) for k in parts[0].header if str(k).startswith("awr:")}

