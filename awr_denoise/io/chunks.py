"""The raw layout of a single-part scanline OpenEXR file: its header, offset table and chunk headers.

Read with seeks, a few bytes per chunk, never the whole file: enough to tell that a file holds every chunk its
header promises (the OpenEXR bindings report no error when a small file's only write fails at close: a full disk
left an empty file behind, and awr committed it, a red-team pass) and what a deep file's chunks unpack to
(io.deep), without decompressing anything or reading gigabytes into memory. Layouts other than single-part
scanline (tiled, multi-part) are not described (None).
"""

from __future__ import annotations

import os
from typing import BinaryIO, NamedTuple

import numpy as np

__all__ = ["Layout", "layout", "chunk_headers", "is_complete"]

MAGIC = b"\x76\x2f\x31\x01"
_TILED, _LONG_NAMES, _DEEP, _MULTIPART = 0x200, 0x400, 0x800, 0x1000
# Scanlines per chunk of each compression (OpenEXR's file layout): NONE, RLE, ZIPS, ZIP, PIZ, PXR24, B44, B44A,
# DWAA, DWAB.
_LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}
_HEADER_READ = 1 << 16
_HEADER_LIMIT = 1 << 28  # a header past 256 MiB is not one this module reads


class Layout(NamedTuple):
    """A single-part scanline file's layout: its ``flags``, raw ``attributes`` (name to (type, value bytes)) and
    the ``offsets`` of its chunks (int64), one per chunk the header promises (empty where the table is cut; None
    for a compression whose chunk height this module does not know)."""

    flags: int
    attributes: dict[bytes, tuple[bytes, bytes]]
    offsets: np.ndarray | None

    @property
    def deep(self) -> bool:
        return bool(self.flags & _DEEP)


def layout(fh: BinaryIO) -> Layout | None:
    """The layout of the open file ``fh`` (a binary file object, read from its start), or None where it is not a
    single-part scanline file (or not an OpenEXR file, or cut inside its header)."""
    fh.seek(0)
    data = fh.read(_HEADER_READ)
    flags = _flags(data)
    if flags is None or flags & (_TILED | _MULTIPART):
        return None
    while True:
        parsed = _attributes(data)
        if parsed is not None:
            break
        if len(data) >= _HEADER_LIMIT:
            return None
        more = fh.read(len(data))  # the header goes on: read as much again
        if not more:
            return None  # cut inside the header
        data += more
    attributes, end = parsed
    try:
        y0, y1 = (int.from_bytes(attributes[b"dataWindow"][1][i:i + 4], "little", signed=True) for i in (4, 12))
        compression = attributes[b"compression"][1][0]
    except (KeyError, IndexError):
        return None
    lines = _LINES_PER_CHUNK.get(compression)
    if lines is None:
        return Layout(flags, attributes, None)
    count = max(0, -(-(y1 - y0 + 1) // lines))
    fh.seek(end)
    table = fh.read(8 * count)
    if len(table) < 8 * count:
        return Layout(flags, attributes, np.zeros(0, np.int64))  # cut inside the offset table
    return Layout(flags, attributes, np.frombuffer(table, "<u8").astype(np.int64))


def _flags(start: bytes) -> int | None:
    """The version field's flags of a file starting with ``start``, or None where it is no OpenEXR file."""
    return int.from_bytes(start[4:8], "little") if len(start) >= 8 and start[:4] == MAGIC else None


def _attributes(data: bytes) -> tuple[dict[bytes, tuple[bytes, bytes]], int] | None:
    """The header's attributes and where it ends (after its closing null byte), or None if ``data`` ends first."""
    attributes, at = {}, 8
    try:
        while data[at] != 0:
            name_end = data.index(b"\x00", at)
            type_end = data.index(b"\x00", name_end + 1)
            size = int.from_bytes(data[type_end + 1:type_end + 5], "little", signed=True)
            if type_end + 5 + size > len(data) or size < 0:
                return None
            attributes[data[at:name_end]] = (data[name_end + 1:type_end], data[type_end + 5:type_end + 5 + size])
            at = type_end + 5 + size
    except (IndexError, ValueError):
        return None
    return attributes, at + 1


def chunk_headers(fh: BinaryIO, found: Layout) -> list[tuple[int, ...]] | None:
    """Each chunk's header: ``(y, data size)``, or for a deep file ``(y, packed table size, packed data size,
    unpacked data size)``; None where a chunk lies past the end of the file or its header is cut."""
    if found.offsets is None:
        return None
    size = os.fstat(fh.fileno()).st_size
    width = 28 if found.deep else 8
    headers = []
    for offset in found.offsets.tolist():  # one read per chunk, not per pixel
        if not 0 < offset <= size - width:
            return None
        fh.seek(offset)
        raw = fh.read(width)
        fields = ((int.from_bytes(raw[0:4], "little", signed=True),) +
                  tuple(int.from_bytes(raw[i:i + 8], "little") for i in range(4, width, 8)) if found.deep else
                  (int.from_bytes(raw[0:4], "little", signed=True), int.from_bytes(raw[4:8], "little", signed=True)))
        payload = sum(fields[1:3]) if found.deep else fields[1]
        if payload < 0 or offset + width + payload > size:
            return None
        headers.append(fields)
    return headers


def is_complete(path: str | os.PathLike[str]) -> bool:
    """False where ``path`` is a single-part scanline file missing chunks its header promises (or empty, or cut
    inside its header); True otherwise, other layouts included (they are not checked)."""
    with open(path, "rb") as fh:
        flags = _flags(fh.read(8))
        if flags is None:
            return False
        if flags & (_TILED | _MULTIPART):
            return True
        found = layout(fh)
        if found is None:
            return False  # cut inside its header
        return found.offsets is None or (found.offsets.size > 0 and chunk_headers(fh, found) is not None)
