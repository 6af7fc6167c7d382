"""File input and output: EXR images, sample dumps, request maps, PNG previews.

All readers look channels up by name and raise :class:`~awr_denoise.errors.InputFileError`
with a one-line ``<file>: <channel>: <what>`` message; all writers are atomic and refuse to
replace an existing file unless ``overwrite=True``. See ``docs/io.md`` for the layouts.
"""

from __future__ import annotations

from .exr import read_header, read_image, write_image

__all__ = [
    "read_header",
    "read_image",
    "write_image",
]
