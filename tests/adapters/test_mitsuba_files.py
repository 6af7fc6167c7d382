"""The files a Mitsuba scene reads: found as Mitsuba 3's parser finds them, checked against Mitsuba."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from awr_denoise.adapters.mitsuba_files import scene_files
from awr_denoise.io import write_image

_SCENE = '<scene version="3.0.0">{}</scene>'
_TEXTURE = ('<bsdf type="diffuse"><texture type="bitmap" name="reflectance">'
            '<string name="filename" value="{}"/></texture></bsdf>')

# name: (files other than the texture, the scene, where Mitsuba reads the texture, decoys: the
# same name where a plausible but wrong lookup would find it)
CASES = {
    "parameter inside a name": ({"a.xml": _SCENE.format('<default name="t" value="img"/>'
                                                        + _TEXTURE.format("$t_x.exr"))}, "a.xml", "img_x.exr", []),
    "longest parameter first": ({"a.xml": _SCENE.format('<default name="t" value="img"/><default name="tx" value="o"/>'
                                                        + _TEXTURE.format("$tx.exr"))}, "a.xml", "o.exr", ["imgx.exr"]),
    "escaped dollar": ({"a.xml": _SCENE.format('<default name="t" value="img"/>' + _TEXTURE.format("\\$t.exr"))},
                       "a.xml", "$t.exr", ["img.exr"]),
    "default of a default": ({"a.xml": _SCENE.format('<default name="b" value="tex"/><default name="a" value="$b"/>'
                                                     + _TEXTURE.format("$a.exr"))}, "a.xml", "tex.exr", []),
    "default in an include": ({"e.xml": _SCENE.format('<include filename="sub/defs.xml"/>'
                                                      + _TEXTURE.format("sub/$t.exr")),
                               "sub/defs.xml": _SCENE.format('<default name="t" value="img"/>')},
                              "e.xml", "sub/img.exr", []),
    "name in an include": ({"f.xml": _SCENE.format('<include filename="sub/part.xml"/>'),
                            "sub/part.xml": _SCENE.format(_TEXTURE.format("tex.exr"))}, "f.xml", "tex.exr",
                           ["sub/tex.exr"]),
    "include of an include": ({"f.xml": _SCENE.format('<include filename="sub/part.xml"/>'),
                               "sub/part.xml": _SCENE.format('<include filename="deep.xml"/>'),
                               "sub/deep.xml": _SCENE.format(_TEXTURE.format("tex.exr"))}, "f.xml", "tex.exr",
                              ["sub/tex.exr"]),
    "path declared later": ({"f.xml": _SCENE.format(_TEXTURE.format("tex.exr") + '<path value="maps"/>')},
                            "f.xml", "maps/tex.exr", []),
    "path in an include": ({"f.xml": _SCENE.format('<include filename="sub/part.xml"/>' + _TEXTURE.format("tex.exr")),
                            "sub/part.xml": _SCENE.format('<path value="maps"/>'), "sub/maps/keep": ""},
                           "f.xml", "tex.exr", ["sub/maps/tex.exr"]),
    "scene in a folder": ({"sub/f.xml": _SCENE.format(_TEXTURE.format("tex.exr"))}, "sub/f.xml", "sub/tex.exr",
                          ["tex.exr"]),
    "working folder after the scene's": ({"sub/f.xml": _SCENE.format(_TEXTURE.format("tex.exr"))}, "sub/f.xml",
                                         "tex.exr", []),
}


def _write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)


def _texture(path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, np.full((2, 2, 3), 0.5))


@pytest.mark.parametrize("case", CASES)
def test_the_texture_listed_is_the_one_mitsuba_reads(mi, tmp_path, monkeypatch, case):
    """With decoys where a plausible lookup would look, Mitsuba loads the scene, and fails once the
    listed texture is not an image: it reads that file, as the walk says."""
    files, scene, read, decoys = CASES[case]
    monkeypatch.chdir(tmp_path)
    _write(tmp_path, files)
    for decoy in decoys:
        _texture(tmp_path / decoy)
    _texture(tmp_path / read)
    listed = [path for what, path in scene_files(scene) if not what.startswith("include")]
    assert [os.path.normpath(path) for path in listed] == [os.path.normpath(read)]
    mi.load_file(scene)
    (tmp_path / read).write_text("not an image")
    with pytest.raises(RuntimeError):
        mi.load_file(scene)


def test_a_spectrum_in_an_include_is_looked_up_from_the_including_file(mi, tmp_path, monkeypatch):
    """A ``filename`` attribute is read while parsing: beside the file holding the ``<include>``."""
    monkeypatch.chdir(tmp_path)
    _write(tmp_path, {"f.xml": _SCENE.format('<include filename="sub/part.xml"/>'),
                      "sub/part.xml": _SCENE.format('<bsdf type="diffuse"><spectrum name="reflectance" '
                                                    'filename="r.spd"/></bsdf>'),
                      "sub/r.spd": "400 0.5\n700 0.5\n"})
    assert scene_files("f.xml") == [("include sub/part.xml", Path("sub/part.xml")), ("filename r.spd", Path("r.spd"))]
    with pytest.raises(RuntimeError, match="r.spd"):
        mi.load_file("f.xml")
    (tmp_path / "r.spd").write_text("400 0.5\n700 0.5\n")
    mi.load_file("f.xml")


# ---------------------------------------------------------------------------- no Mitsuba needed
def test_an_undefined_parameter_stops_the_walk_as_it_stops_mitsuba(tmp_path):
    """Mitsuba refuses the scene while parsing: the files parsing read before are listed, those
    instantiation would read are not."""
    _write(tmp_path, {"a.xml": _SCENE.format(_TEXTURE.format("tex.exr") + '<spectrum name="s" filename="a.spd"/>'
                                             '<string name="filename" value="$nope.exr"/>'
                                             '<spectrum name="t" filename="b.spd"/>')})
    assert [what for what, _ in scene_files(tmp_path / "a.xml")] == ["filename a.spd"]


def test_render_parameters_take_precedence_over_defaults(tmp_path):
    _write(tmp_path, {"a.xml": _SCENE.format('<default name="t" value="img"/>' + _TEXTURE.format("$t.exr"))})
    assert [path.name for _, path in scene_files(tmp_path / "a.xml", params={"t": "given"})] == ["given.exr"]
    assert [path.name for _, path in scene_files(tmp_path / "a.xml")] == ["img.exr"]


def test_an_include_that_is_not_a_regular_file_is_listed_and_never_opened(tmp_path):
    os.mkfifo(tmp_path / "part.xml")  # opening it would block
    _write(tmp_path, {"a.xml": _SCENE.format('<include filename="part.xml"/>' + _TEXTURE.format("tex.exr"))})
    assert scene_files(tmp_path / "a.xml") == [("include part.xml", tmp_path / "part.xml")]


def test_an_include_loop_stops_at_mitsubas_depth(tmp_path):
    _write(tmp_path, {"loop.xml": _SCENE.format('<include filename="loop.xml"/>' + _TEXTURE.format("tex.exr"))})
    assert [what for what, _ in scene_files(tmp_path / "loop.xml")] == ["include loop.xml"] * 15


def test_a_byte_that_is_not_utf8_in_a_comment_is_read_as_mitsuba_reads_it(tmp_path):
    """pugixml does not check the encoding; expat refuses the byte, so the file is read again."""
    (tmp_path / "a.xml").write_bytes(b'<scene version="3.0.0"><!-- caf\xe9 -->'
                                     + _TEXTURE.format("tex.exr").encode() + b"</scene>")
    assert [what for what, _ in scene_files(tmp_path / "a.xml")] == ["filename tex.exr"]
    (tmp_path / "b.xml").write_text("<scene><unclosed></scene>")
    with pytest.raises(ValueError, match="b.xml: not a readable Mitsuba XML scene"):
        scene_files(tmp_path / "b.xml")


def test_a_bundled_name_or_a_dict_reads_nothing():
    assert scene_files("cornell_box") == [] and scene_files({"type": "scene"}) == []
