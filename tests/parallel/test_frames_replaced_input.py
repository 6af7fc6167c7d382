"""denoise_frame keeps a dump's pixels and windows together when the file is replaced by rename while
it is read (a renderer writing its next version): the windows come from the read that gave the samples,
and a source read in other windows than the caller checked it in is refused by name."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

pytest.importorskip("OpenEXR")

import awr_denoise.io.presets as presets  # noqa: E402
from awr_denoise import SampleBuffer  # noqa: E402
from awr_denoise.errors import InputFileError  # noqa: E402
from awr_denoise.io import read_image, write_sample_buffer  # noqa: E402
from awr_denoise.io.exr import read_windows  # noqa: E402
from awr_denoise.parallel import FramesFailedError, denoise_frame, denoise_frames  # noqa: E402

pytestmark = pytest.mark.exr

H, W = 24, 32
CROP = {"dataWindow": ((100, 200), (100 + W - 1, 200 + H - 1)), "displayWindow": ((0, 0), (1919, 1079))}
ORIGIN = {"dataWindow": ((0, 0), (W - 1, H - 1)), "displayWindow": ((0, 0), (W - 1, H - 1))}


def _buffer(seed: int) -> SampleBuffer:
    rng = np.random.default_rng(seed)
    mean = np.abs(0.5 + 0.1 * rng.standard_normal((H, W, 3)))
    return SampleBuffer.from_moments(np.full((H, W), 8), mean, np.full((H, W, 3), 0.04))


@pytest.fixture
def versions(tmp_path):
    """``in.exr`` at the origin and ``next.exr``, another render of its size in another data window."""
    write_sample_buffer(tmp_path / "in.exr", _buffer(1))
    write_sample_buffer(tmp_path / "next.exr", _buffer(2), header=CROP)
    return tmp_path


def test_the_windows_are_those_of_the_read_that_gave_the_samples(versions, monkeypatch):
    """Replaced right after its samples were read: the image is that version's, pixels and windows
    (its windows were read apart, from the next version: the pixels written in the crop's window)."""
    expected = versions / "expected.exr"
    denoise_frame(versions / "in.exr", expected)  # the first version alone
    real = presets.read_exr
    swapped = []

    def read_then_replace(path, *args, **kwargs):
        parts = real(path, *args, **kwargs)
        if not swapped and os.path.basename(path) == "in.exr":
            swapped.append(path)
            os.link(versions / "next.exr", versions / "tmp.exr")
            os.replace(versions / "tmp.exr", versions / "in.exr")
        return parts

    monkeypatch.setattr(presets, "read_exr", read_then_replace)
    denoise_frame(versions / "in.exr", versions / "out.exr")
    assert swapped
    assert read_windows(versions / "out.exr") == read_windows(expected) == ORIGIN
    np.testing.assert_array_equal(read_image(versions / "out.exr"), read_image(expected))


def test_a_source_read_in_other_windows_than_checked_is_refused(versions):
    with pytest.raises(InputFileError, match=r"in\.exr: changed while it was read .*dataWindow \(100,200\)-"):
        denoise_frame(versions / "in.exr", versions / "out.exr", windows=CROP)
    assert not (versions / "out.exr").exists()
    denoise_frame(versions / "in.exr", versions / "out.exr", windows=ORIGIN)  # the windows it is in: denoised
    assert read_windows(versions / "out.exr") == ORIGIN


@pytest.mark.parametrize("executor", [None, "threads"])
def test_denoise_frames_passes_each_frame_its_windows(versions, executor):
    sources = [versions / "in.exr", versions / "next.exr"]
    outputs = [versions / "a.exr", versions / "b.exr"]
    pool = ThreadPoolExecutor(2) if executor else None
    try:
        with pytest.raises(FramesFailedError) as caught:
            denoise_frames(sources, outputs, windows=[ORIGIN, ORIGIN], executor=pool)  # the second: not in ORIGIN
        assert list(caught.value.failures) == [os.fspath(sources[1])]
        assert isinstance(caught.value.failures[os.fspath(sources[1])], InputFileError)
        assert not outputs[1].exists()
        assert read_windows(outputs[0]) == ORIGIN
    finally:
        if pool is not None:
            pool.shutdown()


def test_the_windows_argument_is_checked(versions):
    with pytest.raises(ValueError, match="windows: 1 given for 2 input"):
        denoise_frames([versions / "in.exr", versions / "next.exr"], [versions / "a.exr", versions / "b.exr"],
                       windows=[ORIGIN])
    with pytest.raises(TypeError, match="windows: expected one"):
        denoise_frames([versions / "in.exr"], [versions / "a.exr"], windows=ORIGIN)
    with pytest.raises(TypeError, match="windows: expected a dict"):
        denoise_frame(versions / "in.exr", versions / "a.exr", windows=[ORIGIN])
    assert not (versions / "a.exr").exists()
