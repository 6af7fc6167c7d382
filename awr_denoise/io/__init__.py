"""File input and output: EXR images, sample dumps, request maps, PNG previews.

All readers look channels up by name and raise :class:`~awr_denoise.errors.InputFileError`
with a one-line ``<file>: <channel>: <what>`` message; all writers are atomic and refuse to
replace an existing file unless ``overwrite=True``. See ``docs/io.md`` for the layouts.
"""

from __future__ import annotations

from .deep import read_deep_samples, write_deep_samples
from .dump import SampleDump, write_sample_buffer
from .exr import read_header, read_image, write_image
from .png import write_preview
from .describe import describe_file
from .presets import PRESETS, detect_preset, read_independent_renders, read_sample_buffer, read_sample_dump
from .provenance import image_provenance, provenance, read_provenance
from .request_map import read_request, request_attributes, write_request

__all__ = [
    "PRESETS",
    "SampleDump",
    "describe_file",
    "detect_preset",
    "image_provenance",
    "provenance",
    "read_deep_samples",
    "read_provenance",
    "read_header",
    "read_image",
    "read_independent_renders",
    "read_request",
    "read_sample_buffer",
    "read_sample_dump",
    "request_attributes",
    "write_deep_samples",
    "write_image",
    "write_preview",
    "write_request",
    "write_sample_buffer",
]
