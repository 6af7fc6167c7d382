"""Paths and special files (cli/paths.py): no command writes over one of its inputs by any route,
reads or writes a non-regular file, or writes one file twice.

Every case runs the real command line in-process and checks the outcome the same way: exit 2,
one ``awr: error:`` line naming the option, and the folder exactly as it was (no output, no
temporary, inputs untouched, a FIFO still a FIFO).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import stat
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("OpenEXR")

from awr_denoise.cli.main import main  # noqa: E402
from awr_denoise.io import read_sample_dump, write_image, write_sample_buffer  # noqa: E402
from cli_helpers import awr_command, dump_buffer, one_error_line  # noqa: E402

pytestmark = pytest.mark.exr


@contextlib.contextmanager
def _deadline(seconds: int = 20):
    """Fail instead of hanging: opening a FIFO blocks until a writer comes."""
    def expired(signum, frame):
        raise TimeoutError("the command blocked (it opened a FIFO?)")
    previous = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _refused(work, capsys, args, *needles):
    before = work.state()
    with _deadline():
        status = main([str(a) for a in args])
    err = capsys.readouterr().err
    assert status == 2, err
    line = one_error_line(err, *needles)
    assert work.state() == before
    return line


# ------------------------------------------------------------------ an output that is an input

GENERIC = ["--preset", "generic", "--color", "RGB", "--count", "sampleCount"]

# (command line with {OUT} where an output goes, the input it is made to point at)
OUTPUT_IS_INPUT = [
    (["denoise", "d.exr", "-o", "{OUT}"], "d.exr"),
    (["denoise", "d.exr", "-o", "o.exr", "--preview", "{OUT}"], "d.exr"),
    (["denoise", "d.exr", "-o", "o.exr", "-r", "ref.exr", "--preview", "{OUT}"], "ref.exr"),
    (["denoise", "d.exr", "-o", "{OUT}", "-r", "ref.exr"], "ref.exr"),
    (["denoise", "d.exr", *GENERIC, "--variance", "b.exr:variance", "-o", "{OUT}"], "b.exr"),
    (["denoise", "d.exr", "--preset", "generic", "--color", "b.exr:RGB", "--variance", "variance",
      "--count", "sampleCount", "-o", "{OUT}"], "b.exr"),
    (["denoise", "d.exr", "--preset", "generic", "--color", "RGB", "--variance", "variance",
      "--count", "b.exr:sampleCount", "-o", "{OUT}"], "b.exr"),
    (["denoise", "shot.####.exr", "--frames", "1-3", "-o", "{OUT}"], "shot.####.exr"),
    (["plan", "d.exr", "-o", "{OUT}"], "d.exr"),
    (["plan", "d.exr", *GENERIC, "--variance", "ref.exr:RGB", "--spp", "4", "-o", "{OUT}"], "ref.exr"),
    (["merge", "d.exr", "b.exr", "-o", "{OUT}"], "d.exr"),
    (["merge", "d.exr", "b.exr", "-o", "{OUT}"], "b.exr"),
    (["merge", "d.exr", "b.exr", "--request", "req.exr", "-o", "{OUT}"], "req.exr"),
    (["merge", "d.exr", "b.exr", *GENERIC, "--variance", "ref.exr:RGB", "-o", "{OUT}"], "ref.exr"),
    (["diff", "ref.exr", "-r", "d.exr", "-o", "{OUT}"], "ref.exr"),
    (["diff", "ref.exr", "-r", "d.exr", "-o", "{OUT}"], "d.exr"),
]

ROUTES = ["same", "spelled", "symlink", "hardlink"]


def _route(work, victim: str, route: str) -> str:
    if route == "same":
        return victim
    if route == "spelled":
        (work / "sub").mkdir(exist_ok=True)
        return f"sub/../{victim}"
    if route == "symlink":
        os.symlink(victim, work / "alias.exr")
    else:
        os.link(work / victim, work / "alias.exr")
    return "alias.exr"


# A link stands for one file, not a frame pattern: patterns go by the first two routes only.
OUTPUT_IS_INPUT_CASES = [(t, v, r) for t, v in OUTPUT_IS_INPUT for r in ROUTES if "#" not in v or r in ROUTES[:2]]


@pytest.mark.parametrize(("template", "victim", "route"), OUTPUT_IS_INPUT_CASES,
                         ids=[f"{t[0]}-{v}-{r}-{i}" for i, (t, v, r) in enumerate(OUTPUT_IS_INPUT_CASES)])
def test_an_output_that_is_an_input_is_refused(work, capsys, monkeypatch, template, victim, route):
    monkeypatch.chdir(work.root)
    out = _route(work, victim, route)
    args = [out if a == "{OUT}" else a for a in template] + ["--overwrite"]
    _refused(work, capsys, args, "is the input")


# ------------------------------------------------------------------ outputs that are one file

OUTPUTS_COLLIDE = [
    (["denoise", "d.exr", "-o", "x.exr", "--preview", "x.exr"], "written twice"),
    (["denoise", "d.exr", "-o", "x.exr", "--preview", "./x.exr"], "written twice"),
    (["denoise", "shot.####.exr", "--frames", "1,1", "-o", "o.####.exr"],
     "--frames: '1,1' names frame 1 more than once"),
    (["denoise", "shot.####.exr", "--frames", "1-3", "-o", "o.####.exr", "--preview", "p.png"], "####"),
    (["denoise", "shot.####.exr", "--frames", "1-3", "-o", "o.####.exr", "--preview", "o.####.exr"], "written twice"),
    (["render", "--renderer", "synthetic", "edges", "--width", "8", "--height", "8", "-o", "r.exr",
      "--image", "r.exr"], "written twice"),
    (["render", "--renderer", "synthetic", "edges", "--width", "8", "--height", "8", "-o", "r.exr",
      "--preview", "r.denoised.exr"], "written twice"),
]


@pytest.mark.parametrize(("args", "needle"), OUTPUTS_COLLIDE)
def test_two_outputs_that_are_one_file_are_refused(work, capsys, monkeypatch, args, needle):
    monkeypatch.chdir(work.root)
    _refused(work, capsys, args + ["-q"], needle)


def test_hard_linked_outputs_are_one_file(work, capsys, monkeypatch):
    monkeypatch.chdir(work.root)
    (work / "x.exr").write_bytes(b"old")
    os.link(work / "x.exr", work / "y.png")
    _refused(work, capsys, ["denoise", "d.exr", "-o", "x.exr", "--preview", "y.png", "--overwrite"],
             "written twice")


def test_a_relative_name_in_a_deleted_current_folder_is_named(work, capsys, monkeypatch):
    gone = work.root / "gone"
    gone.mkdir()
    monkeypatch.chdir(gone)
    gone.rmdir()  # the shell's folder deleted under it: "[Errno 2] No such file or directory"
    assert main(["denoise", str(work / "d.exr"), "-o", "out.exr", "-q"]) == 2
    one_error_line(capsys.readouterr().err, "out.exr", "current folder no longer exists")
    assert main(["denoise", str(work / "d.exr"), "-o", str(work / "abs.exr"), "-q"]) == 0  # absolute: fine


# ------------------------------------------------------------------ special files

def _special(work, kind: str) -> str:
    path = work / ("special.png" if kind != "directory" else "special.dir")
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "directory":
        path.mkdir()
    else:  # a private character device like /dev/null (root only): never the real one
        try:
            os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
        except PermissionError:
            pytest.skip("creating a device node needs root")
    return path.name


KINDS = ["fifo", "directory", "device"]

OUTPUT_OPTIONS = [
    ["denoise", "d.exr", "-o", "{OUT}"],
    ["denoise", "d.exr", "-o", "o.exr", "--preview", "{OUT}"],
    ["plan", "d.exr", "-o", "{OUT}"],
    ["merge", "d.exr", "b.exr", "-o", "{OUT}"],
    ["diff", "ref.exr", "-r", "d.exr", "-o", "{OUT}"],
    ["render", "--renderer", "synthetic", "edges", "--width", "8", "--height", "8", "--spp", "2", "-o", "{OUT}"],
    ["render", "--renderer", "synthetic", "edges", "--width", "8", "--height", "8", "--spp", "2", "-o", "r.exr",
     "--image", "{OUT}"],
    ["render", "--renderer", "synthetic", "edges", "--width", "8", "--height", "8", "--spp", "2", "-o", "r.exr",
     "--preview", "{OUT}"],
]


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("template", OUTPUT_OPTIONS, ids=lambda t: f"{t[0]}-{t[t.index('{OUT}') - 1]}")
def test_a_special_file_is_never_an_output_even_with_overwrite(work, capsys, monkeypatch, template, kind):
    monkeypatch.chdir(work.root)
    name = _special(work, kind)
    mode = os.lstat(work / name).st_mode
    args = [name if a == "{OUT}" else a for a in template] + ["--overwrite"]
    _refused(work, capsys, args, "not a regular file")
    assert os.lstat(work / name).st_mode == mode


INPUT_OPTIONS = [
    ["info", "{IN}"],
    ["info", "{IN}", "--json"],
    ["denoise", "{IN}", "-o", "o.exr"],
    ["denoise", "--hdr", "{IN}", "-o", "o.exr"],
    ["denoise", "d.exr", "-o", "o.exr", "-r", "{IN}"],
    ["denoise", "d.exr", *GENERIC, "--variance", "{IN}:variance", "-o", "o.exr"],
    ["plan", "{IN}", "-o", "p.exr"],
    ["merge", "d.exr", "{IN}", "-o", "m.exr"],
    ["merge", "d.exr", "b.exr", "--request", "{IN}", "-o", "m.exr"],
    ["diff", "{IN}", "-r", "ref.exr"],
    ["diff", "ref.exr", "-r", "{IN}"],
]


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("template", INPUT_OPTIONS, ids=lambda t: "-".join(a for a in t if a != "-o")[:40])
def test_a_special_file_is_refused_as_input_without_blocking(work, capsys, monkeypatch, template, kind):
    monkeypatch.chdir(work.root)
    os.rename(work / _special(work, kind), work / "special.exr")
    name = "special.exr"
    args = [a.replace("{IN}", name) for a in template]
    line = _refused(work, capsys, args)
    assert "not a regular file" in line or "is a directory" in line, line


@pytest.mark.tracer
def test_a_scene_files_environment_map_is_an_input(work, capsys, monkeypatch):
    """The environment map a JSON scene names is checked like every input: never replaced by an
    output, never opened when it is a FIFO."""
    pytest.importorskip("embreex")
    from awr_denoise.tracer.scenes import BUNDLED_SCENES

    monkeypatch.chdir(work.root)
    spec = dict(BUNDLED_SCENES["default"], width=8, height=8, environment={"type": "latlong", "path": "env.exr"})
    (work / "s.json").write_text(json.dumps(spec))
    write_image(work / "env.exr", np.ones((4, 8, 3)))
    _refuses_scene_input(work, capsys, ["render", "s.json", "--spp", "2", "--uniform", "-q", "--overwrite"],
                         "env.exr", "environment.path")


def _refuses_scene_input(work, capsys, render, name, field):
    """``render`` reads ``name`` through its scene file (``field`` in the message): no output may
    replace it, and as a FIFO it is refused unopened."""
    _refused(work, capsys, render + ["-o", name], "is the input", field)
    _refused(work, capsys, render + ["-o", "r.exr", "--image", name], "--image", field)
    (work / name).unlink()
    os.mkfifo(work / name)
    _refused(work, capsys, render + ["-o", "r.exr"], field, "FIFO")


def test_the_files_a_mitsuba_scene_names_are_inputs(work, capsys, monkeypatch):
    """A texture (or an included file) a Mitsuba XML scene names is checked like every input, before
    Mitsuba is loaded: never replaced by an output, never opened when it is a FIFO."""
    monkeypatch.chdir(work.root)
    (work / "parts").mkdir()
    (work / "parts" / "more.xml").write_text('<scene version="3.0.0"><shape type="obj">'
                                              '<string name="filename" value="parts/mesh.obj"/></shape></scene>')
    (work / "parts" / "mesh.obj").write_text("v 0 0 0\n")
    (work / "scene.xml").write_text(
        '<scene version="3.0.0"><include filename="parts/more.xml"/><bsdf type="diffuse">'
        '<texture type="bitmap" name="reflectance"><string name="filename" value="tex.exr"/></texture></bsdf>'
        '</scene>')
    write_image(work / "tex.exr", np.ones((4, 4, 3)))
    render = ["render", "--renderer", "mitsuba", "scene.xml", "--spp", "2", "--uniform", "-q", "--overwrite"]
    _refused(work, capsys, render + ["-o", "parts/mesh.obj"], "is the input", "filename parts/mesh.obj")  # included
    _refuses_scene_input(work, capsys, render, "tex.exr", "filename tex.exr")


_TEXTURE = '<bsdf type="diffuse"><texture type="bitmap" name="reflectance">{}</texture></bsdf>'


_ROUTES = ["default parameter", "spectrum attribute", "any scene name", "search folder", "parameter inside a name",
           "default of a default", "default in an include", "name in an include"]


@pytest.mark.parametrize("route", _ROUTES)
def test_every_route_by_which_mitsuba_reads_a_file_makes_it_an_input(work, capsys, monkeypatch, route):
    """Mitsuba also reads a file through a ``$parameter``'s default, a ``filename`` attribute, a
    scene file not named .xml and a ``<path>`` search folder: each is an input like a plain one
    (an output never replaces it, a FIFO there is never opened: it would hang Mitsuba's loader).
    Names are substituted and looked up as Mitsuba 3.9's parser does: ``$t_x.exr`` with only ``t``
    defined reads ``tex_x.exr``, defaults are substituted in document order across includes, and a
    texture named in an included file is found beside the scene, not beside the include."""
    monkeypatch.chdir(work.root)
    name, scene, body = "tex.exr", "scene.xml", _TEXTURE.format('<string name="filename" value="tex.exr"/>')
    (work / "sub").mkdir()
    if route == "default parameter":
        body = '<default name="tx" value="tex.exr"/>' + _TEXTURE.format('<string name="filename" value="$tx"/>')
    elif route == "parameter inside a name":
        name, body = "tex_x.exr", '<default name="t" value="tex"/>' + _TEXTURE.format(
            '<string name="filename" value="$t_x.exr"/>')
    elif route == "default of a default":
        body = '<default name="b" value="tex"/><default name="a" value="$b"/>' + _TEXTURE.format(
            '<string name="filename" value="$a.exr"/>')
    elif route == "default in an include":
        (work / "sub" / "defs.xml").write_text('<scene version="3.0.0"><default name="t" value="tex"/></scene>')
        name, body = "sub/tex.exr", '<include filename="sub/defs.xml"/>' + _TEXTURE.format(
            '<string name="filename" value="sub/$t.exr"/>')
    elif route == "name in an include":
        (work / "sub" / "part.xml").write_text(f'<scene version="3.0.0">{body}</scene>')
        write_image(work / "sub" / "tex.exr", np.ones((4, 4, 3)))  # Mitsuba never reads this one
        body = '<include filename="sub/part.xml"/>'
    elif route == "spectrum attribute":
        name, body = "refl.spd", '<bsdf type="diffuse"><spectrum name="reflectance" filename="refl.spd"/></bsdf>'
    elif route == "any scene name":
        scene = "scene.mitsuba"
    else:
        (work / "maps").mkdir()
        name, body = "maps/tex.exr", '<path value="maps"/>' + body
    (work / scene).write_text(f'<scene version="3.0.0">{body}</scene>')
    write_image(work / name, np.ones((4, 4, 3)))
    render = ["render", "--renderer", "mitsuba", scene, "--spp", "2", "--uniform", "-q", "--overwrite"]
    field = "filename sub/tex.exr" if route == "default in an include" else f"filename {Path(name).name}"
    _refuses_scene_input(work, capsys, render, name, field)


def test_a_name_that_is_not_utf8_is_refused_before_any_work(work, capsys, monkeypatch):
    """Linux names are bytes: one that is not UTF-8 cannot reach OpenEXR or a header, so the file was
    written and then called corrupt, or a render failed after its work without naming the file."""
    monkeypatch.chdir(work.root)
    bad = os.fsdecode(b"bad\xff.exr")
    Path(bad).write_bytes((work / "d.exr").read_bytes())
    _refused(work, capsys, ["info", bad], "bad\\xff.exr", "not valid UTF-8")
    _refused(work, capsys, ["denoise", "d.exr", "-o", os.fsdecode(b"o\xfe.exr")], "-o/--output", "not valid UTF-8")
    _refused(work, capsys, ["render", "--renderer", "synthetic", "edges", "--width", "16", "--height", "16",
                            "-o", os.fsdecode(b"r\xfe.exr")], "-o/--output", "not valid UTF-8")


def test_a_name_the_terminal_cannot_show_is_escaped_not_an_error(work):
    """PYTHONIOENCODING=ascii: printing a valid file's non-ASCII name failed the command, exit 2."""
    (work / "réndu.exr").write_bytes((work / "d.exr").read_bytes())
    env = dict(os.environ, PYTHONIOENCODING="ascii")
    done = subprocess.run([*awr_command(), "info", "réndu.exr"], cwd=work.root, env=env, capture_output=True,
                          text=True, encoding="ascii", errors="strict", timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("r\\xe9ndu.exr: ")


def test_an_output_that_is_a_symbolic_link_loop_is_refused(work, capsys, monkeypatch):
    monkeypatch.chdir(work.root)
    os.symlink("loop2.exr", work / "loop1.exr")
    os.symlink("loop1.exr", work / "loop2.exr")
    _refused(work, capsys, ["denoise", "d.exr", "-o", "loop1.exr", "--overwrite"], "-o/--output", "loop1.exr")


def test_a_missing_input_names_its_option(work, capsys, monkeypatch):
    monkeypatch.chdir(work.root)
    _refused(work, capsys, ["denoise", "d.exr", "-o", "o.exr", "-r", "missing.exr"], "-r/--ref", "missing.exr")
    _refused(work, capsys, ["denoise", "shot.####.exr", "--frames", "1-4", "-o", "o.####.exr"],
             "frame 4", "shot.0004.exr")
    _refused(work, capsys, ["merge", "d.exr", "b.exr", "--request", "nope.exr", "-o", "m.exr"], "--request")


def test_an_unwritable_folder_is_refused_before_any_work(work, capsys, monkeypatch):
    monkeypatch.chdir(work.root)
    _refused(work, capsys, ["denoise", "d.exr", "-o", "o.exr", "--preview", "nodir/p.png"], "--preview", "nodir")
    _refused(work, capsys, ["denoise", "d.exr", "-o", "d.exr/o.exr"], "-o/--output")


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_a_folder_that_accepts_no_file_is_refused_before_any_work(work, capsys, monkeypatch):
    """/proc tells root it is writable (os.access) and then refuses every new file: the up-front
    check creates and removes a probe, so the refusal comes before the reconstruction, naming -o."""
    monkeypatch.chdir(work.root)
    _refused(work, capsys, ["denoise", "d.exr", "-o", "/proc/o.exr"], "-o/--output", "/proc")


# ------------------------------------------------------------------ merging a dump with itself

def _copy_route(work, route: str) -> str:
    if route == "same":
        return "d.exr"
    if route == "spelled":
        return "./d.exr"
    if route == "symlink":
        os.symlink("d.exr", work / "copy.exr")
    elif route == "hardlink":
        os.link(work / "d.exr", work / "copy.exr")
    elif route == "bytes":
        (work / "copy.exr").write_bytes((work / "d.exr").read_bytes())
    else:  # the same samples written again, with other header attributes (other bytes)
        write_sample_buffer(work / "copy.exr", dump_buffer(0), header={"awr:note": "re-saved"})
    return "copy.exr"


DUPLICATE_ROUTES = ["same", "spelled", "symlink", "hardlink", "bytes", "resaved"]


@pytest.mark.parametrize("route", DUPLICATE_ROUTES)
def test_merging_a_dump_with_itself_is_refused(work, capsys, monkeypatch, route):
    monkeypatch.chdir(work.root)
    other = _copy_route(work, route)
    _refused(work, capsys, ["merge", "d.exr", other, "-o", "m.exr"], "twice", "--allow-duplicates")
    _refused(work, capsys, ["merge", "d.exr", "b.exr", other, "-o", "m.exr"], "twice")


def test_allow_duplicates_merges_them(work, capsys, monkeypatch):
    monkeypatch.chdir(work.root)
    assert main(["merge", "d.exr", "d.exr", "-o", "m.exr", "--allow-duplicates", "-q"]) == 0
    merged = read_sample_dump(work / "m.exr").buffer
    np.testing.assert_array_equal(merged.count, 2 * read_sample_dump(work / "d.exr").buffer.count)


# ------------------------------------------------------------------ long names

@pytest.mark.parametrize("length", [238, 247, 255])
def test_output_names_up_to_255_bytes_work(work, capsys, monkeypatch, length):
    monkeypatch.chdir(work.root)
    image, preview = "i" * (length - 4) + ".exr", "p" * (length - 4) + ".png"
    assert main(["denoise", "d.exr", "-o", image, "--preview", preview, "-q"]) == 0, capsys.readouterr().err
    assert (work / image).is_file() and (work / preview).is_file()
    assert work.temporaries() == []


def test_an_output_name_beyond_255_bytes_is_refused_naming_the_option(work, capsys, monkeypatch):
    monkeypatch.chdir(work.root)
    _refused(work, capsys, ["denoise", "d.exr", "-o", "o.exr", "--preview", "p" * 252 + ".png"], "--preview")


def test_a_hash_in_a_folder_name_is_not_a_frame_placeholder(work, capsys, monkeypatch):
    """``take#1/shot.####.exr``: only the file name's run of ``#`` is the frame number."""
    monkeypatch.chdir(work.root)
    (work / "take#1").mkdir()
    (work / "out#1").mkdir()
    for frame in (1, 2):
        (work / "take#1" / f"shot.000{frame}.exr").write_bytes((work / "d.exr").read_bytes())
    assert main(["denoise", "take#1/shot.####.exr", "--frames", "1-2", "-o", "out#1/o.####.exr", "-q"]) == 0
    assert sorted(p.name for p in (work / "out#1").iterdir()) == ["o.0001.exr", "o.0002.exr"]
    _refused(work, capsys, ["denoise", "take#1/shot.####.exr", "--frames", "1", "-o", "out#1/o.exr"],
             "out#1/o.exr", "placeholder in its file name")
    _refused(work, capsys, ["denoise", "take#1/shot.0001.exr", "--frames", "1", "-o", "out#1/o.####.exr"],
             "take#1/shot.0001.exr", "placeholder in its file name")


@pytest.mark.parametrize("args, option", [
    (["denoise", "d.exr", "-o", "o.png"], "-o/--output"),
    (["denoise", "d.exr", "-o", "o.exr", "--preview", "p.exr"], "--preview"),
    (["plan", "d.exr", "-o", "r.tif"], "-o/--output"),
])
def test_an_output_named_as_another_image_type_is_refused(work, capsys, monkeypatch, args, option):
    """-o out.png wrote an EXR and --preview p.exr a PNG, files image viewers then refused."""
    monkeypatch.chdir(work.root)
    _refused(work, capsys, args, option, "this output is written as")


def test_info_shows_a_name_with_a_newline_on_one_line(work, capsys, monkeypatch):
    monkeypatch.chdir(work.root)
    Path("two\nlines.exr").write_bytes((work / "d.exr").read_bytes())
    assert main(["info", "two\nlines.exr"]) == 0
    assert capsys.readouterr().out.splitlines()[0].startswith("two\\nlines.exr: ")


@pytest.mark.parametrize("args, option", [
    (["denoise", "d.exr", "-o", "slash.exr/"], "-o/--output"),
    (["denoise", "d.exr", "-o", "slash.exr/."], "-o/--output"),
    (["render", "--renderer", "synthetic", "edges", "--width", "8", "--height", "8", "-o", "r.exr",
      "--image", "i.exr/.."], "--image"),
    (["denoise", "d.exr", "-o", "o#.exr/"], "-o/--output"),
    (["denoise", "shot.####.exr", "--frames", "1-2", "-o", "o.####.exr", "--preview", "out#2/"], "--preview"),
    (["plan", "d.exr", "-o", "req.exr/", "--budget", "100"], "-o/--output"),
    (["diff", "ref.exr", "-r", "ref.exr", "-o", "delta.exr/"], "-o/--output"),
    # render's image and preview names derive from the dump's: "PosixPath('.') has an empty name" (an attack pass)
    (["render", "--renderer", "synthetic", "edges", "--width", "8", "--height", "8", "-o", "."], "-o/--output"),
    (["render", "--renderer", "synthetic", "edges", "--width", "8", "--height", "8", "-o", "/"], "-o/--output"),
])
def test_an_output_name_ending_in_a_slash_is_refused(work, capsys, monkeypatch, args, option):
    """``-o out.exr/`` names a folder, yet a file ``out.exr`` was written (``Path`` drops the slash);
    with a ``#`` the frame checks read an empty file name and named the wrong problem."""
    monkeypatch.chdir(work.root)
    _refused(work, capsys, args, option, "which names a folder")  # nothing written


def test_frames_without_a_placeholder_in_the_input_are_refused(work, capsys, monkeypatch):
    """Every frame denoised the one dump again, N identical outputs, exit 0 (red-team pass 5)."""
    monkeypatch.chdir(work.root)
    _refused(work, capsys, ["denoise", "d.exr", "--frames", "1-3", "-o", "o.####.exr"], "d.exr",
             "the input needs a #### placeholder")


FORGED = "evil\x1b[2K\x1b[1G\x1b[32mawr: ok all fine\x1b[0m\rFAKE\nline"


def test_a_name_cannot_rewrite_the_terminal(work, capsys, monkeypatch):
    """File names were printed raw in error and status lines: an escape sequence in a name erased the
    error line and printed a green "ok" over it, a carriage return or newline forged lines (a red-team
    pass). Shown escaped, as `awr info` showed them."""
    monkeypatch.chdir(work.root)
    assert main(["denoise", FORGED + ".exr", "-o", "o.exr"]) == 2
    err = capsys.readouterr().err
    line = one_error_line(err, "evil\\x1b[2K", "\\r")
    assert not any(c in err for c in "\x1b\r") and err.count("\n") == 1, line
    assert main(["denoise", "d.exr", "-o", FORGED + ".exr"]) == 0  # status lines on stderr
    out, err = capsys.readouterr()
    assert "\x1b" not in err + out and "\r" not in err + out and "evil\\x1b[2K" in err
    # Names are shown as they are named otherwise: other spaces and joiners kept, a bidi override escaped (a review).
    assert main(["denoise", "東京\u3000夜景 é\u00a0🧑\u200d💻.exr", "-o", "o2.exr"]) == 2
    one_error_line(capsys.readouterr().err, "東京\u3000夜景 é\u00a0🧑\u200d💻.exr")
    assert main(["denoise", "a\u202egpj.exr", "-o", "o2.exr"]) == 2
    one_error_line(capsys.readouterr().err, "a\\u202egpj.exr")
    write_image(work / "hostile.exr", np.ones((4, 4, 3)), channels=["R\x1b[2K", "G", "B"])
    assert main(["info", "hostile.exr"]) == 0  # a channel named by the file
    out = capsys.readouterr().out
    assert "\x1b" not in out and "R\\x1b[2K" in out


@pytest.mark.parametrize("args", [["denoise", "d.exr", "-o", "-"],
                                  ["denoise", "d.exr", "-o", "o.exr", "--preview", "-"],
                                  ["merge", "d.exr", "b.exr", "-o", "-"], ["plan", "d.exr", "-o", "-"]],
                         ids=["denoise", "preview", "merge", "plan"])
def test_a_dash_is_not_taken_for_a_file_named_dash(work, capsys, monkeypatch, args):
    """`-o -` wrote a file named `-` where a shell user means standard output (a red-team pass)."""
    monkeypatch.chdir(work.root)
    before = sorted(os.listdir(work.root))
    assert main(args) == 2
    one_error_line(capsys.readouterr().err, "'-' would write a file named '-'")
    assert sorted(os.listdir(work.root)) == before
