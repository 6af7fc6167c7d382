"""Channel names and counts (awr_denoise.channels)."""

from __future__ import annotations

import numpy as np
import pytest

from awr_denoise import SampleBuffer
from awr_denoise.channels import channel_count, resolve_channels

ONES = np.ones((4, 4)), np.ones((4, 4, 3)), np.ones((4, 4, 3))


@pytest.mark.parametrize("names", [{"R", "G", "B"}, frozenset("RGB")])
def test_a_set_of_names_is_refused(names):
    """A set's order is its hashes' (random between runs for strings): ``channels={"R", "G", "B"}``
    named the data's channels in an arbitrary order, so R could be labelled B without a word."""
    for call in (lambda: SampleBuffer.from_moments(*ONES, channels=names),
                 lambda: SampleBuffer.empty((4, 4), channels=names), lambda: channel_count(names)):
        with pytest.raises(TypeError, match="channels: a set of names has no order"):
            call()


@pytest.mark.parametrize("given", [("B", "G", "R"), ["B", "G", "R"], np.array(["B", "G", "R"]),
                                   {"B": 0, "G": 1, "R": 2}])
def test_ordered_names_keep_their_order(given):
    assert resolve_channels(given, 3) == ("B", "G", "R")
    assert SampleBuffer.from_moments(*ONES, channels=given).channels == ("B", "G", "R")


@pytest.mark.parametrize("bad", [np.ma.array(3), np.array(True), 3.0, "RGB"])
def test_a_count_or_names_is_all_that_is_taken(bad):
    with pytest.raises(TypeError, match=r"^channels: expected a number of channels or their names, got [^\n]+$"):
        channel_count(bad)


def test_a_zero_dimensional_count_is_its_number():
    assert channel_count(np.array(4)) == 4
    assert SampleBuffer.empty((2, 2), channels=np.array(2)).n_channels == 2


def test_every_route_that_takes_channel_names_refuses_a_set(tmp_path):
    """``read_image(channels={"R", "G", "B"})`` returned the channels in hash order (it changes with
    PYTHONHASHSEED); ``luminance_weights``, ``channel_groups`` and ``colours`` took sets; a set as
    ``color=`` was Python's "unhashable type" (a review of the set refusal)."""
    pytest.importorskip("OpenEXR")
    from awr_denoise.channels import channel_groups, colours, luminance_weights
    from awr_denoise.io import read_image, read_sample_dump, write_image

    for call in (luminance_weights, channel_groups, colours):
        with pytest.raises(TypeError, match="channels: a set of names has no order"):
            call({"R", "G", "B"})
    write_image(tmp_path / "a.exr", np.ones((2, 2, 3)))
    with pytest.raises(TypeError, match="channels: expected a list or tuple of channel names"):
        read_image(tmp_path / "a.exr", channels={"R", "G", "B"})
    with pytest.raises(TypeError, match="channels: expected a list or tuple of names in the image's order, got set"):
        write_image(tmp_path / "b.exr", np.ones((2, 2, 3)), channels={"R", "G", "B"})
    assert not (tmp_path / "b.exr").exists()
    with pytest.raises(TypeError, match="color: expected a plane name or file.exr:plane, got set"):
        read_sample_dump(tmp_path / "a.exr", color={"R", "G", "B"})
    assert read_image(tmp_path / "a.exr", channels=["B", "G", "R"]).shape == (2, 2, 3)


def test_channel_names_are_strings_and_none_is_empty():
    """``channels=(None, b"G", nan)`` became the names 'None', "b'G'" and 'nan' (a red-team pass)."""
    from awr_denoise.channels import resolve_channels

    for names in ((None, "G", "B"), (b"R", "G", "B"), ("R", float("nan"), "B")):
        with pytest.raises(TypeError, match="channels: expected names"):
            resolve_channels(names, 3)
    with pytest.raises(ValueError, match="channels: an empty name"):
        resolve_channels(("",), 1)
    assert resolve_channels((np.str_("R"), "G", "B"), 3) == ("R", "G", "B")
