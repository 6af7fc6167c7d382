"""The raw chunk layout (awr_denoise.io.chunks) of files the library wrote, whole and cut."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

pytestmark = pytest.mark.exr
pytest.importorskip("OpenEXR")

from awr_denoise.io import chunks, write_image  # noqa: E402
from awr_denoise.io.deep import _unpacked_sample_bytes, write_deep_samples  # noqa: E402


def _deep(path, h=8, w=6, spp=3):
    n = h * w * spp
    write_deep_samples(path, np.repeat(np.arange(h * w), spp), np.random.default_rng(0).random((n, 3)), (h, w),
                       sample_index=np.tile(np.arange(spp), h * w))
    return n


@pytest.mark.parametrize("kind", ["scanline", "deep"])
def test_a_whole_file_is_complete_and_every_cut_one_is_not(tmp_path, kind):
    path = tmp_path / "a.exr"
    if kind == "deep":
        _deep(path)
    else:
        write_image(path, np.random.default_rng(0).random((40, 24, 3)).astype(np.float32))
    data = path.read_bytes()
    assert chunks.is_complete(path)
    cut = tmp_path / "cut.exr"
    for size in sorted({0, 4, 8, 40, len(data) // 3, len(data) // 2, len(data) - 1}):
        cut.write_bytes(data[:size])
        assert not chunks.is_complete(cut), size


def test_the_deep_chunks_unpack_to_their_samples_and_are_read_with_seeks(tmp_path):
    """The whole file read into memory made a dump with gigabytes of trailing bytes "out of memory"."""
    path = tmp_path / "d.exr"
    n = _deep(path)
    assert _unpacked_sample_bytes(path) == (n * 16, 16)  # three float channels and the sample index (uint)
    with open(path, "r+b") as fh:
        fh.truncate(2**30)  # a sparse gigabyte after the chunks: ignored by OpenEXR, never read here
    tracemalloc.start()
    try:
        assert _unpacked_sample_bytes(path) == (n * 16, 16)
        assert tracemalloc.get_traced_memory()[1] < 2**20
    finally:
        tracemalloc.stop()
