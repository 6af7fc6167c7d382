"""The files a Mitsuba scene may read: a superset of what Mitsuba 3 reads, checked against Mitsuba itself."""

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
# same name where a plausible but wrong lookup would find it; the superset may list them too)
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


def _listed(scene) -> list[str]:
    return [os.path.normpath(path) for _, path in scene_files(scene)]


@pytest.mark.parametrize("case", CASES)
def test_the_file_mitsuba_reads_is_listed(mi, tmp_path, monkeypatch, case):
    """With decoys where a plausible lookup would look, Mitsuba loads the scene, and fails once the
    texture it is said to read is not an image: it reads that file, and the file is listed."""
    files, scene, read, decoys = CASES[case]
    monkeypatch.chdir(tmp_path)
    _write(tmp_path, files)
    for decoy in decoys:
        _texture(tmp_path / decoy)
    _texture(tmp_path / read)
    assert os.path.normpath(read) in _listed(scene)
    mi.load_file(scene)
    (tmp_path / read).write_text("not an image")
    with pytest.raises(RuntimeError):
        mi.load_file(scene)


@pytest.mark.parametrize("markup", [
    '<!DOCTYPE scene [<!ENTITY t "other">]><scene version="3.0.0">{}</scene>',  # an entity stays as written
    '<scene version="3.0.0">{}<bsdf type="diffuse" id="a&b"/></scene>',  # a bare &
    '<scene version="3.0.0"><!-- a -- b -->{}</scene>',  # -- inside a comment
    '<scene version="3.0.0">{}<bsdf type="diffuse" id="x<y"/></scene>',  # < inside an attribute
])
def test_markup_mitsuba_reads_and_expat_refuses_or_reads_otherwise(mi, tmp_path, monkeypatch, markup):
    """pugixml (Mitsuba's parser) leaves an unknown entity as written and tolerates malformed
    markup: the file it reads is listed, where a strict XML parser refused the scene or expanded
    the entity to another name."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a.xml").write_text(markup.format(_TEXTURE.format("&t;.exr")))
    _texture(tmp_path / "&t;.exr")
    _texture(tmp_path / "other.exr")
    assert "&t;.exr" in _listed("a.xml")
    mi.load_file("a.xml")
    (tmp_path / "&t;.exr").write_text("not an image")
    with pytest.raises(RuntimeError):
        mi.load_file("a.xml")


def test_a_latin1_byte_names_the_file_mitsuba_reads(mi, tmp_path, monkeypatch):
    """pugixml takes the bytes of a file declaring windows-1252 as UTF-8 (it converts only Latin-1):
    the name keeps its raw byte, as Mitsuba opens it (decoding it as windows-1252 named another file)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a.xml").write_bytes(b'<?xml version="1.0" encoding="windows-1252"?><scene version="3.0.0">'
                                     + _TEXTURE.format("t@.exr").encode("ascii").replace(b"@", b"\xe9")
                                     + b"</scene>")
    raw = os.fsdecode(b"t\xe9.exr")
    _texture(tmp_path / "decoy.exr")
    os.rename(tmp_path / "decoy.exr", tmp_path / raw)
    _texture(tmp_path / "t\u00e9.exr")  # what a decoder of windows-1252 would name
    assert raw in _listed("a.xml")
    mi.load_file("a.xml")
    (tmp_path / raw).write_text("not an image")
    with pytest.raises((RuntimeError, UnicodeDecodeError)):  # Mitsuba's message holds the raw byte
        mi.load_file("a.xml")


def test_a_spectrum_in_an_include_is_listed_where_mitsuba_reads_it(mi, tmp_path, monkeypatch):
    """A ``filename`` attribute is read while parsing, beside the file holding the ``<include>``."""
    monkeypatch.chdir(tmp_path)
    _write(tmp_path, {"f.xml": _SCENE.format('<include filename="sub/part.xml"/>'),
                      "sub/part.xml": _SCENE.format('<bsdf type="diffuse"><spectrum name="reflectance" '
                                                    'filename="r.spd"/></bsdf>'),
                      "sub/r.spd": "400 0.5\n700 0.5\n"})
    with pytest.raises(RuntimeError, match="r.spd"):
        mi.load_file("f.xml")
    (tmp_path / "r.spd").write_text("400 0.5\n700 0.5\n")
    mi.load_file("f.xml")
    assert {"r.spd", os.path.normpath("sub/part.xml")} <= set(_listed("f.xml"))


def test_every_value_a_default_may_take_is_followed(mi, tmp_path, monkeypatch):
    """Two includes of one name, one beside the scene and one in a ``<path>`` folder, each giving
    ``$t`` another default: which Mitsuba reads first decides, so both values are listed (the
    first one met named a file Mitsuba never reads; a review of this pass)."""
    monkeypatch.chdir(tmp_path)
    _write(tmp_path, {"scene.xml": _SCENE.format('<path value="sub"/><include filename="part.xml"/>'
                                                 + _TEXTURE.format("$t.exr")),
                      "part.xml": _SCENE.format('<default name="t" value="decoy"/>'),
                      "sub/part.xml": _SCENE.format('<default name="t" value="real"/>')})
    _texture(tmp_path / "decoy.exr")
    _texture(tmp_path / "real.exr")
    assert {"real.exr", "decoy.exr"} <= set(_listed("scene.xml"))
    mi.load_file("scene.xml")
    (tmp_path / "real.exr").write_text("not an image")
    with pytest.raises(RuntimeError):
        mi.load_file("scene.xml")


def test_a_conductors_data_beside_the_scene_is_listed_and_read(mi, tmp_path, monkeypatch):
    """Mitsuba looks up ``data/ior/<material>.eta.spd`` through the scene's resolver: a copy beside
    the scene wins, and ``-o`` could replace it (a review of this pass)."""
    monkeypatch.chdir(tmp_path)
    _write(tmp_path, {"a.xml": _SCENE.format('<bsdf type="conductor"><string name="material" value="Cu"/></bsdf>')})
    bundled = Path(mi.__file__).parent / "data" / "ior"
    (tmp_path / "data" / "ior").mkdir(parents=True)
    for name in ("Cu.eta.spd", "Cu.k.spd"):
        (tmp_path / "data" / "ior" / name).write_bytes((bundled / name).read_bytes())
    assert {os.path.normpath("data/ior/Cu.eta.spd"), os.path.normpath("data/ior/Cu.k.spd")} <= set(_listed("a.xml"))
    mi.load_file("a.xml")
    (tmp_path / "data" / "ior" / "Cu.eta.spd").write_text("not a spectrum")
    with pytest.raises(RuntimeError):
        mi.load_file("a.xml")


# ---------------------------------------------------------------------------- no Mitsuba needed
def test_markup_inside_a_value_hides_no_element(tmp_path):
    """``<!--`` in one attribute value and ``-->`` in a later one hid the texture between them."""
    (tmp_path / "tex.exr").write_text("")
    _write(tmp_path, {"a.xml": _SCENE.format('<bsdf type="diffuse" id="a<!--b"/>' + _TEXTURE.format("tex.exr")
                                             + '<bsdf type="diffuse" id="-->"/><bsdf type="diffuse" id="<?x"/>')})
    assert [path.name for _, path in scene_files(tmp_path / "a.xml")] == ["tex.exr"]


def test_a_default_after_the_include_that_uses_it_is_followed(tmp_path):
    (tmp_path / "tex.exr").write_text("")
    _write(tmp_path, {"a.xml": _SCENE.format('<include filename="$part.xml"/><default name="part" value="p"/>'),
                      "p.xml": _SCENE.format(_TEXTURE.format("tex.exr"))})
    assert [what for what, _ in scene_files(tmp_path / "a.xml")] == ["include p.xml", "filename tex.exr"]


def test_more_includes_than_checked_are_refused_not_half_checked(tmp_path):
    files = {f"p{i}.xml": _SCENE.format(f'<include filename="p{i + 1}.xml"/>') for i in range(1001)}
    _write(tmp_path, {"a.xml": _SCENE.format('<include filename="p0.xml"/>'), **files})
    with pytest.raises(ValueError, match="includes more than 1000 XML files"):
        scene_files(tmp_path / "a.xml")


def test_an_undefined_parameter_skips_only_its_own_value(tmp_path):
    """Mitsuba may never reach the element (a transform's grandchild): the rest is still listed."""
    for name in ("tex.exr", "a.spd"):
        (tmp_path / name).write_text("")
    _write(tmp_path, {"a.xml": _SCENE.format('<transform name="to_world"><translate x="1"><path value="$nope"/>'
                                             '</translate></transform>' + _TEXTURE.format("tex.exr")
                                             + '<spectrum name="s" filename="a.spd"/>'
                                             '<string name="filename" value="$nope.exr"/>')})
    assert [what for what, _ in scene_files(tmp_path / "a.xml")] == ["filename tex.exr", "filename a.spd"]


def test_render_parameters_take_precedence_over_defaults(tmp_path):
    for name in ("given.exr", "img.exr"):
        (tmp_path / name).write_text("")
    _write(tmp_path, {"a.xml": _SCENE.format('<default name="t" value="img"/>' + _TEXTURE.format("$t.exr"))})
    assert [path.name for _, path in scene_files(tmp_path / "a.xml", params={"t": "given"})] == ["given.exr"]
    assert [path.name for _, path in scene_files(tmp_path / "a.xml")] == ["img.exr"]


def test_special_files_are_listed_unopened_folders_and_missing_names_are_not(tmp_path):
    """A FIFO (an include or a texture) is listed, so the command refuses it, and never opened; a
    folder named like a value, or a name found nowhere, cannot be read as a file."""
    os.mkfifo(tmp_path / "part.xml")  # opening it would block
    os.mkfifo(tmp_path / "tex.exr")
    (tmp_path / "diffuse").mkdir()
    _write(tmp_path, {"a.xml": _SCENE.format('<include filename="part.xml"/>' + _TEXTURE.format("tex.exr")
                                             + _TEXTURE.format("missing.exr"))})
    assert scene_files(tmp_path / "a.xml") == [("include part.xml", tmp_path / "part.xml"),
                                               ("filename tex.exr", tmp_path / "tex.exr")]


def test_an_include_loop_ends(tmp_path):
    (tmp_path / "tex.exr").write_text("")
    _write(tmp_path, {"loop.xml": _SCENE.format('<include filename="loop.xml"/>' + _TEXTURE.format("tex.exr"))})
    assert [what for what, _ in scene_files(tmp_path / "loop.xml")] == ["include loop.xml", "filename tex.exr"]


def test_a_linked_scene_lists_the_files_beside_its_target_too(tmp_path):
    """``mi.load_file`` looks beside the link, a loader that resolves the name beside the target."""
    _write(tmp_path, {"real/a.xml": _SCENE.format(_TEXTURE.format("tex.exr"))})
    (tmp_path / "real" / "tex.exr").write_text("")
    (tmp_path / "tex.exr").write_text("")
    os.symlink(tmp_path / "real" / "a.xml", tmp_path / "a.xml")
    assert {path for _, path in scene_files(tmp_path / "a.xml")} == {tmp_path / "tex.exr",
                                                                      tmp_path / "real" / "tex.exr"}


def test_a_bundled_name_or_a_dict_reads_nothing():
    assert scene_files("cornell_box") == [] and scene_files({"type": "scene"}) == []


def test_plugin_libraries_beside_the_scene_are_listed_unopened(tmp_path):
    """Mitsuba loads ``plugins/<type>.so`` through the scene's resolver on first use: a FIFO there
    hung the render (a review of this pass)."""
    (tmp_path / "plugins").mkdir()
    os.mkfifo(tmp_path / "plugins" / "conductor.so")
    _write(tmp_path, {"a.xml": _SCENE.format('<bsdf type="conductor"/>')})
    assert scene_files(tmp_path / "a.xml") == [("resource plugins/conductor.so", tmp_path / "plugins" / "conductor.so")]


def test_a_chain_of_defaults_of_any_length_is_followed(tmp_path):
    """A name built through seven nested ``<default>`` values was not followed past four."""
    (tmp_path / "tex.exr").write_text("")
    chain = '<default name="d0" value="tex"/>' + "".join(f'<default name="d{i}" value="$d{i - 1}"/>'
                                                         for i in range(1, 7))
    _write(tmp_path, {"a.xml": _SCENE.format(chain + _TEXTURE.format("$d6.exr"))})
    assert [what for what, _ in scene_files(tmp_path / "a.xml")] == ["filename tex.exr"]
    loop = '<default name="a" value="$b"/><default name="b" value="$a"/>'  # Mitsuba refuses it; this ends
    _write(tmp_path, {"b.xml": _SCENE.format(loop + _TEXTURE.format("$a.exr") + _TEXTURE.format("tex.exr"))})
    assert [what for what, _ in scene_files(tmp_path / "b.xml")] == ["filename tex.exr"]


def test_a_value_of_too_many_readings_is_refused_not_cut_short(tmp_path):
    defaults = "".join(f'<default name="p{k}" value="{v}"/>' for k in range(9) for v in ("x", "y"))
    includes = "".join(f'<include filename="i{k}.xml"/>' for k in range(9))
    files = {f"i{k}.xml": _SCENE.format(f'<default name="p{k}" value="z"/>') for k in range(9)}
    name = "".join(f"$p{k}" for k in range(9)) + ".exr"  # 3**9 readings
    _write(tmp_path, {"a.xml": _SCENE.format(defaults + includes + _TEXTURE.format(name)), **files})
    with pytest.raises(ValueError, match="may read in more than 256 ways"):
        scene_files(tmp_path / "a.xml")

