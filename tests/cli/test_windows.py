"""EXR data and display windows: kept from input to output by every command, and two files
whose windows differ are never merged or compared pixel by pixel (the pixels do not line up)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("OpenEXR")

from awr_denoise.cli.main import main  # noqa: E402
from awr_denoise.io import read_image, write_image, write_sample_buffer  # noqa: E402
from awr_denoise.io.exr import read_windows  # noqa: E402
from awr_denoise.parallel import denoise_frame  # noqa: E402
from cli_helpers import H, W, dump_buffer, one_error_line  # noqa: E402

pytestmark = pytest.mark.exr

# A 32x24 crop at (100, 200) of a 1920x1080 frame.
CROP = {"dataWindow": ((100, 200), (100 + W - 1, 200 + H - 1)), "displayWindow": ((0, 0), (1919, 1079))}
# The same data window inside another display window (an overscan render).
OVERSCAN = {"dataWindow": ((100, 200), (100 + W - 1, 200 + H - 1)), "displayWindow": ((0, 0), (2047, 1151))}


@pytest.fixture
def crops(work):
    write_sample_buffer(work / "crop.exr", dump_buffer(20), header=CROP)
    write_sample_buffer(work / "crop2.exr", dump_buffer(21), header=CROP)
    write_sample_buffer(work / "over.exr", dump_buffer(22), header=OVERSCAN)
    write_image(work / "cropref.exr", dump_buffer(23).mean, header=CROP)
    return work


def test_windows_round_trip_through_the_writers(tmp_path):
    write_image(tmp_path / "a.exr", np.ones((H, W, 3)), header=CROP)
    assert read_windows(tmp_path / "a.exr") == CROP
    with pytest.raises(ValueError, match="dataWindow"):
        write_image(tmp_path / "b.exr", np.ones((H + 1, W, 3)), header=CROP)
    assert not (tmp_path / "b.exr").exists()


@pytest.mark.parametrize("args", [
    ["denoise", "crop.exr", "-o", "out.exr"],
    ["denoise", "crop.exr", "-o", "out.exr", "-r", "cropref.exr"],
    ["plan", "crop.exr", "-o", "out.exr"],
    ["merge", "crop.exr", "crop2.exr", "-o", "out.exr"],
    ["diff", "cropref.exr", "-r", "crop.exr", "-o", "out.exr"],
], ids=lambda a: a[0] + ("-ref" if "-r" in a and a[0] == "denoise" else ""))
def test_every_command_keeps_the_windows(crops, capsys, monkeypatch, args):
    monkeypatch.chdir(crops.root)
    assert main([*args, *(["-q"] if args[0] != "diff" else [])]) == 0, capsys.readouterr().err
    assert read_windows(crops / "out.exr") == CROP


def test_denoise_frame_keeps_the_windows(crops):
    denoise_frame(crops / "crop.exr", crops / "lib.exr")
    assert read_windows(crops / "lib.exr") == CROP


@pytest.mark.parametrize(("args", "first", "second"), [
    (["merge", "d.exr", "crop.exr", "-o", "m.exr"], "crop.exr", "d.exr"),
    (["merge", "crop.exr", "over.exr", "-o", "m.exr"], "over.exr", "crop.exr"),
    (["merge", "crop.exr", "crop2.exr", "--request", "req.exr", "-o", "m.exr"], "req.exr", "crop.exr"),
    (["diff", "cropref.exr", "-r", "ref.exr"], "ref.exr", "cropref.exr"),
    (["diff", "cropref.exr", "-r", "over.exr", "-o", "dd.exr"], "over.exr", "cropref.exr"),
    (["denoise", "crop.exr", "-o", "o.exr", "-r", "ref.exr"], "ref.exr", "crop.exr"),
])
def test_files_whose_windows_differ_are_refused_naming_both(crops, capsys, monkeypatch, args, first, second):
    monkeypatch.chdir(crops.root)
    before = crops.state()
    assert main(args) == 2
    line = one_error_line(capsys.readouterr().err, first, second)
    assert "window" in line
    assert crops.state() == before


def test_the_pixels_of_a_crop_stay_its_pixels(crops, capsys, monkeypatch):
    """The image written for a crop holds the crop's own pixels (not shifted to the origin)."""
    monkeypatch.chdir(crops.root)
    assert main(["denoise", "crop.exr", "-o", "out.exr", "--stages", "1", "--c-s", "0", "-q"]) == 0
    np.testing.assert_allclose(read_image(crops / "out.exr"), dump_buffer(20).mean, rtol=1e-6)


def test_a_plane_file_in_another_window_is_refused(crops, capsys, monkeypatch):
    """``--variance F:plane`` of the same size but another data window would pair wrong pixels."""
    monkeypatch.chdir(crops.root)
    generic = ["--preset", "generic", "--color", "RGB", "--count", "sampleCount"]
    for args in (["denoise", "d.exr", "-o", "o.exr"], ["plan", "d.exr", "-o", "o.exr"]):
        before = crops.state()
        assert main([*args, *generic, "--variance", "crop.exr:variance"]) == 2
        one_error_line(capsys.readouterr().err, "crop.exr", "d.exr", "window")
        assert crops.state() == before


def test_the_library_refuses_a_plane_file_in_another_window_as_the_command_line_does(crops):
    """``read_sample_dump(..., variance="other.exr:plane")`` or ``albedo="other.exr"`` took a plane of the
    same size in another data window without a word: values paired with other pixels (a red-team
    pass; the command line's own check did not cover the library)."""
    from awr_denoise.errors import InputFileError
    from awr_denoise.io import read_sample_dump

    write_image(crops / "alb.exr", np.full((H, W, 3), 0.5))  # data window at (0, 0)
    write_image(crops / "cropalb.exr", np.full((H, W, 3), 0.5), header=CROP)
    generic = dict(preset="generic", color="RGB", count="sampleCount")
    for kwargs in ({"variance": f"{crops / 'd.exr'}:variance", **generic}, {"albedo": str(crops / "alb.exr")},
                   {"albedo": f"{crops / 'alb.exr'}:RGB"}):
        with pytest.raises(InputFileError, match=r"data window \(0,0\)-.* does not match \(100,200\)-.*crop\.exr"):
            read_sample_dump(crops / "crop.exr", **kwargs)
    assert read_sample_dump(crops / "crop.exr", albedo=str(crops / "cropalb.exr")).buffer.features["albedo"].shape


def test_a_plane_file_is_checked_against_every_frame_not_only_the_first(crops, capsys, monkeypatch):
    """With ``--frames`` each frame may have its own data window: a plane file that lines up with
    the first frame but not with a later one is refused, as it is for that frame alone."""
    monkeypatch.chdir(crops.root)
    (crops / "d.exr").rename(crops / "shot.0001.exr")
    (crops / "crop.exr").rename(crops / "shot.0002.exr")
    write_sample_buffer(crops / "plane.exr", dump_buffer(24))  # the first frame's window, not the crop's
    generic = ["--preset", "generic", "--color", "RGB", "--count", "sampleCount", "--variance", "plane.exr:variance"]
    before = crops.state()
    assert main(["denoise", "shot.####.exr", "--frames", "1-2", "-o", "o.####.exr", *generic]) == 2
    one_error_line(capsys.readouterr().err, "plane.exr", "shot.0002.exr", "window")
    assert crops.state() == before


def test_info_shows_a_crop_and_its_json_holds_the_windows(crops, capsys, monkeypatch):
    import json

    monkeypatch.chdir(crops.root)
    assert main(["info", "crop.exr"]) == 0
    out = capsys.readouterr().out
    assert "data window (100, 200)-(131, 223) inside display window (0, 0)-(1919, 1079)" in out
    assert main(["info", "crop.exr", "--json"]) == 0
    windows = json.loads(capsys.readouterr().out)["windows"]
    assert windows == {"dataWindow": [[100, 200], [131, 223]], "displayWindow": [[0, 0], [1919, 1079]]}
    write_image(crops / "full.exr", np.ones((H, W, 3)))
    assert main(["info", "full.exr"]) == 0
    assert "window" not in capsys.readouterr().out  # a plain full frame gets no line
    # A data window beside the display window, or across its edge, was said to lie "inside" it (a red-team pass).
    for origin, where in (((5000, 200), "outside"), ((1900, 200), "overlapping"), ((-10, 0), "overlapping")):
        box = {**CROP, "dataWindow": (origin, (origin[0] + W - 1, origin[1] + H - 1))}
        write_image(crops / "odd.exr", np.ones((H, W, 3)), header=box, overwrite=True)
        assert main(["info", "odd.exr"]) == 0
        assert f"{where} display window (0, 0)-(1919, 1079)" in capsys.readouterr().out, where
