"""The ``awr`` command line: exit statuses, one-line errors, safe outputs, frames, the file-only loop."""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.exr
OpenEXR = pytest.importorskip("OpenEXR")

from awr_denoise import AdaptiveSampler, SampleBuffer, SampleRequest  # noqa: E402
from awr_denoise.cli.common import expand_frames, parse_frames  # noqa: E402
from awr_denoise.cli.main import main  # noqa: E402
from awr_denoise.cli.sampler_settings import CARRIED  # noqa: E402
from awr_denoise.io import (  # noqa: E402
    read_header,
    read_image,
    read_request,
    read_sample_dump,
    write_image,
    write_request,
    write_sample_buffer,
)
from awr_denoise.io.colour import MITSUBA_XYZ_TO_SRGB  # noqa: E402
from awr_denoise.io.provenance import provenance  # noqa: E402
from awr_denoise.io.request_map import request_attributes  # noqa: E402
from awr_denoise.metrics import relmse  # noqa: E402
from awr_denoise.sampling import DEFAULT_AWR_INITIAL_SPP  # noqa: E402

DATA = Path(__file__).parent / "data"
H, W = 24, 32


def _external():
    spec = importlib.util.spec_from_file_location("external_renderer", DATA / "external_renderer.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _dump(path, rng, shape=(H, W), spp=8) -> SampleBuffer:
    count = np.full(shape, spp)
    mean = 0.5 + 0.1 * rng.standard_normal(shape + (3,))
    buf = SampleBuffer.from_moments(count, np.abs(mean), np.full(shape + (3,), 0.04))
    write_sample_buffer(path, buf)
    return buf


def _write(path, planes, header=None):
    with OpenEXR.File(dict(header or {}), planes) as f:
        f.write(str(path))
    return path


def _one_error_line(capsys, *needles):
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("awr: error: ")
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


# ---------------------------------------------------------------- bad input, one line each

def _planes(shape=(H, W)):
    one = np.ones(shape, np.float32)
    return {c: one * 0.5 for c in "RGB"} | {f"variance.{c}": one * 0.1 for c in "RGB"} | {"sampleCount": one * 4}


def _with(channel, value, dtype=None):
    planes = _planes()
    a = planes[channel].astype(dtype or np.float32)
    a[3, 4] = value
    planes[channel] = a
    return planes


BAD_INPUTS = {
    "nan": (lambda p: _write(p, _with("G", np.nan)), ["G", "NaN"]),
    "inf": (lambda p: _write(p, _with("variance.R", np.inf)), ["variance.R", "Inf"]),
    "negative_variance": (lambda p: _write(p, _with("variance.B", -0.5)), ["variance.B", "negative"]),
    "negative_count": (lambda p: _write(p, _with("sampleCount", -1)), ["sampleCount", "negative"]),
    "half_overflow": (lambda p: _write(p, _with("R", np.float16(np.inf), np.float16)), ["R", "half-float overflow"]),
    "missing_channel": (lambda p: _write(p, {k: v for k, v in _planes().items() if k != "variance.G"},
                                         {"awr:channels": "R,G,B"}), ["variance.G", "missing"]),
    "ambiguous_layers": (lambda p: _write(p, {f"{layer}.Combined.{c}": np.ones((H, W), np.float32)
                                              for layer in ("A", "B") for c in "RGB"}), ["several view layers"]),
    "not_exr": (lambda p: p.write_bytes(b"P6\n2 2\n255\n" + bytes(12)), ["not an OpenEXR"]),
    "empty": (lambda p: p.write_bytes(b""), ["not an OpenEXR"]),
}


def _truncated(p):
    write_sample_buffer(p, SampleBuffer.from_moments(np.full((64, 64), 4), np.random.default_rng(0).random((64, 64, 3)),
                                                     np.full((64, 64, 3), 0.1)))
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])


def _corrupt(p):
    _truncated(p)
    write_sample_buffer(p, SampleBuffer.from_moments(np.full((64, 64), 4), np.random.default_rng(0).random((64, 64, 3)),
                                                     np.full((64, 64, 3), 0.1)), overwrite=True)
    data = bytearray(p.read_bytes())
    middle = len(data) // 2
    data[middle:middle + 200] = bytes(b ^ 0x5A for b in data[middle:middle + 200])
    p.write_bytes(bytes(data))


BAD_INPUTS["truncated"] = (_truncated, ["truncated or corrupt"])
BAD_INPUTS["corrupt"] = (_corrupt, ["truncated or corrupt"])
BAD_INPUTS["garbage_after_magic"] = (lambda p: p.write_bytes(b"\x76\x2f\x31\x01" + bytes(range(256)) * 4),
                                     ["truncated or corrupt"])


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, case):
    make, needles = BAD_INPUTS[case]
    src = tmp_path / "in.exr"
    make(src)
    before = src.read_bytes()
    rc = main(["denoise", str(src), "-o", str(tmp_path / "out.exr"), "-q"])
    assert rc == 2
    _one_error_line(capsys, "in.exr", *needles)
    assert sorted(os.listdir(tmp_path)) == ["in.exr"]  # no partial output, no temporary file
    assert src.read_bytes() == before


def test_size_mismatch_between_files(tmp_path, capsys):
    beauty = _write(tmp_path / "beauty.exr", {c: np.ones((H, W), np.float32) for c in "RGB"})
    _write(tmp_path / "var.exr", {f"v.{c}": np.ones((4, 4), np.float32) for c in "RGB"})
    rc = main(["denoise", str(beauty), "--color", "RGB", "--variance", f"{tmp_path / 'var.exr'}:v", "--spp", "4",
               "-o", str(tmp_path / "out.exr")])
    assert rc == 2
    _one_error_line(capsys, "var.exr", "v:", "does not match")
    assert not (tmp_path / "out.exr").exists()


def test_cycles_without_variance_is_explained(tmp_path, capsys):
    planes = {f"ViewLayer.Combined.{c}": np.ones((H, W), np.float32) for c in "RGBA"}
    src = _write(tmp_path / "c.exr", planes, {"cycles.ViewLayer.samples": "16"})
    assert main(["denoise", str(src), "-o", str(tmp_path / "o.exr"), "--preset", "cycles"]) == 2
    _one_error_line(capsys, "c.exr", "ViewLayer.Combined", "no variance pass")
    # info describes the file and says what is missing
    assert main(["info", str(src), "--preset", "cycles", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["preset"] == "cycles" and any("awr merge --independent" in m for m in info["missing"])


def test_info_does_not_call_a_dump_without_samples_ready(tmp_path, capsys):
    """Every count 0: awr denoise refuses it ("no pixel has any sample"), awr info said "ready to denoise"."""
    path = tmp_path / "none.exr"
    write_sample_buffer(path, SampleBuffer.empty((H, W)))
    assert main(["info", str(path), "--json"]) == 0
    assert "samples: no pixel has any sample" in json.loads(capsys.readouterr().out)["missing"]
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "ready to denoise" not in out and "no pixel has any sample" in out


def test_info_gives_the_readers_reason_for_a_count_plane_on_an_awr_dump(tmp_path, rng, capsys):
    """``--count`` on an awr dump: info described it through another layout ("variance none", asking for
    --variance), where denoise refuses it for what it is (a red-team pass)."""
    path = tmp_path / "d.exr"
    _dump(path, rng)
    assert main(["info", str(path), "--count", "sampleCount", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["preset"] == "awr" and len(info["missing"]) == 1, info["missing"]
    assert "count= / --count would be ignored: an awr dump counts its samples in sampleCount" in info["missing"][0]


def test_a_word_left_over_points_at_its_commands_help(capsys):
    """``awr merge a.exr -o m.exr b.exr`` (a batch after an option) pointed at ``awr --help``."""
    assert main(["merge", "a.exr", "-o", "m.exr", "b.exr"]) == 2
    _one_error_line(capsys, "unrecognized arguments: b.exr (see 'awr merge --help')")
    assert main(["info", "a.exr", "--bogus"]) == 2
    _one_error_line(capsys, "unrecognized arguments: --bogus (see 'awr info --help')")


def test_missing_input_and_usage_errors(tmp_path, capsys):
    assert main(["denoise", str(tmp_path / "nope.exr"), "-o", str(tmp_path / "o.exr")]) == 2
    _one_error_line(capsys, "nope.exr", "no such file")
    assert main(["denoise", "-o", str(tmp_path / "o.exr")]) == 2
    _one_error_line(capsys, "no input")
    assert main(["frobnicate"]) == 2
    _one_error_line(capsys, "invalid choice")
    assert main(["denoise", "x.exr", "-o", "y.exr", "--c-s", "abc"]) == 2
    _one_error_line(capsys, "--c-s")


def test_bad_option_value_is_usage_error(tmp_path, capsys, rng):
    src = tmp_path / "d.exr"
    _dump(src, rng)
    assert main(["denoise", str(src), "-o", str(tmp_path / "o.exr"), "--wavelet", "nonsense", "-q"]) == 2
    _one_error_line(capsys, "wavelet")
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.parametrize("twice", [["-o", "a.exr", "-o", "b.exr"], ["--c-s", "1", "--c-s", "4"],
                                   ["--stages", "1", "--stages", "3"]])
def test_an_option_given_twice_is_refused(tmp_path, rng, capsys, twice):
    """argparse kept the last of two: a wrapper that appended ``-o`` or a bound to a user's arguments got
    another output or setting with exit 0 (a red-team pass). Refused before anything is written."""
    src = tmp_path / "d.exr"
    _dump(src, rng)
    argv = ["denoise", str(src), *[str(tmp_path / a) if a.endswith(".exr") else a for a in twice], "-q"]
    if "-o" not in twice:
        argv += ["-o", str(tmp_path / "a.exr")]
    assert main(argv) == 2
    _one_error_line(capsys, twice[0], "given twice", f"(the second: {twice[2]} ")
    assert list(tmp_path.iterdir()) == [src]
    ref = tmp_path / "r.exr"
    write_image(ref, np.full((H, W, 3), 0.5))
    for option, values in (("-r", [str(ref), str(src)]), ("--maxerror", ["0.0001", "100"]),
                           ("--metric", ["mse", "psnr"])):
        argv = ["diff", str(ref)] + ([] if option == "-r" else ["-r", str(ref)])
        for value in values:
            argv += [option, value]
        assert main(argv) == 2
        _one_error_line(capsys, option, "given twice")
    # A flag given twice is still one choice, and one value each is not refused.
    assert main(["denoise", str(src), "-o", str(tmp_path / "a.exr"), "--c-s", "4", "-q", "-q"]) == 0


@pytest.mark.parametrize("argv, option", [
    (["denoise", "{d}", "-o", "{o}", "--alb", ""], "--alb"),
    (["denoise", "{d}", "-o", "{o}", "--nrm", ""], "--nrm"),
    (["plan", "{d}", "-o", "{o}", "--depth", ""], "--depth"),
    (["denoise", "{d}", "-o", "{o}", "--color", ""], "--color"),
    (["denoise", "{d}", "-o", "{o}", "--variance", ""], "--variance"),
    (["denoise", "{d}", "-o", "{o}", "--preview", ""], "--preview"),
    (["denoise", "{d}", "-o", ""], "-o/--output"),
    (["diff", "{d}", "-r", ""], "-r/--ref"),
    (["info", ""], "FILE.exr: an empty path"),
    (["merge", "{d}", "", "-o", "{o}"], "DUMP.exr: an empty path"),
])
def test_an_empty_name_is_refused_as_empty(tmp_path, rng, capsys, argv, option):
    """A script's unset variable (``--alb "$ALB"``) gave an empty name: the feature options took it as not
    given (exit 0, no albedo), the others refused it for something else (the folder '.', the default
    colour's variance); a red-team pass."""
    src = tmp_path / "d.exr"
    _dump(src, rng)
    assert main([a.format(d=src, o=tmp_path / "o.exr") for a in argv] + ([] if argv[0] == "info" else ["-q"])) == 2
    _one_error_line(capsys, option, "an empty")
    assert list(tmp_path.iterdir()) == [src]


@pytest.mark.parametrize("argv, option", [
    (["denoise", "{d}", "-o", "{o}", "--color", "{d}:RGB", "--variance", "{d}:"], "--variance"),
    (["denoise", "{d}", "-o", "{o}", "--alb", "{d}:"], "--alb"),
    (["plan", "{d}", "-o", "{o}", "--nrm", "{d}:"], "--nrm"),
    (["info", "{d}", "--color", "{d}:"], "--color"),
])
def test_an_empty_plane_after_the_files_colon_is_refused(tmp_path, rng, capsys, argv, option):
    """``--variance "$F:$PLANE"`` with PLANE unset named the file's R,G,B: the means were read as their
    own variance, the beauty as the albedo, exit 0 (a red-team pass)."""
    src = tmp_path / "d.exr"
    _dump(src, rng)
    assert main([a.format(d=src, o=tmp_path / "o.exr") for a in argv] + ([] if argv[0] == "info" else ["-q"])) == 2
    _one_error_line(capsys, option, "no plane name after the file's colon")
    assert list(tmp_path.iterdir()) == [src]


# ---------------------------------------------------------------- outputs are safe

def test_denoise_writes_image_with_provenance(tmp_path, rng, capsys):
    src = tmp_path / "d.exr"
    _dump(src, rng)
    out = tmp_path / "o.exr"
    assert main(["denoise", str(src), "-o", str(out), "--c-s", "1.5", "--wavelet", "haar", "--preview",
                 str(tmp_path / "o.png"), "-q"]) == 0
    img = read_image(out)
    assert img.shape == (H, W, 3) and np.isfinite(img).all()
    h = read_header(out)
    assert h["awr:c_s"] == 1.5 and h["awr:wavelet"] == "haar" and h["awr:input"] == "d.exr"
    assert {"awr:version", "awr:levels", "awr:domain", "awr:mode"} <= set(h)
    assert (tmp_path / "o.png").read_bytes()[:4] == b"\x89PNG"


def test_denoise_says_how_many_pixels_had_no_samples(tmp_path, rng, capsys):
    """Their values are estimates from the pixels around them: the summary says so, as ``awr info`` does (a
    dump of a border render, or of a sampler that skipped pixels, was denoised without a word)."""
    buf = _dump(tmp_path / "full.exr", rng)
    count = buf.count.copy()
    count[:, : W // 4] = 0
    write_sample_buffer(tmp_path / "d.exr", SampleBuffer.from_moments(count, buf.mean, buf.variance))
    said_here = f"{H * (W // 4)} pixel(s) without samples estimated from their surroundings"
    for name, said in (("full", None), ("d", said_here)):
        assert main(["denoise", str(tmp_path / f"{name}.exr"), "-o", str(tmp_path / f"{name}_out.exr")]) == 0
        err = capsys.readouterr().err
        assert ("without samples" in err) == (said is not None) and (said is None or said in err)


def test_output_refuses_to_overwrite_unless_asked(tmp_path, rng, capsys):
    src = tmp_path / "d.exr"
    _dump(src, rng)
    out = tmp_path / "o.exr"
    out.write_bytes(b"precious")
    assert main(["denoise", str(src), "-o", str(out), "-q"]) == 2
    _one_error_line(capsys, "o.exr", "already exists")
    assert out.read_bytes() == b"precious"
    assert main(["denoise", str(src), "-o", str(out), "-q", "--overwrite"]) == 0
    assert read_image(out).shape == (H, W, 3)


@pytest.mark.parametrize("alias", ["same", "dotted", "hardlink"])
def test_output_equal_to_input_refused(tmp_path, rng, capsys, alias):
    src = tmp_path / "d.exr"
    _dump(src, rng)
    before = src.read_bytes()
    out = {"same": src, "dotted": tmp_path / "." / "d.exr", "hardlink": tmp_path / "link.exr"}[alias]
    if alias == "hardlink":
        os.link(src, out)
    for argv in (["denoise", str(src), "-o", str(out), "--overwrite"],
                 ["merge", str(src), str(src), "-o", str(out), "--overwrite"],
                 ["plan", str(src), "-o", str(out), "--overwrite"]):
        assert main(argv + ["-q"]) == 2
        _one_error_line(capsys, "is the input")
        assert src.read_bytes() == before


# ---------------------------------------------------------------- frames

def test_parse_and_expand_frames():
    assert parse_frames("1-3") == [1, 2, 3]
    assert parse_frames("1-10x4,20") == [1, 5, 9, 20]
    assert expand_frames("shot.####.exr", 7) == "shot.0007.exr"
    assert expand_frames("a_##.exr", 123) == "a_123.exr"


def test_frame_pattern_denoise(tmp_path, rng, capsys):
    for f in (1, 2, 3):
        _dump(tmp_path / f"shot.{f:04d}.exr", rng)
    rc = main(["denoise", str(tmp_path / "shot.####.exr"), "--frames", "1-3", "-o", str(tmp_path / "den.####.exr"),
               "-q"])
    assert rc == 0
    for f in (1, 2, 3):
        assert read_header(tmp_path / f"den.{f:04d}.exr")["awr:input"] == f"shot.{f:04d}.exr"
    assert main(["denoise", str(tmp_path / "shot.####.exr"), "--frames", "1-3", "-o", str(tmp_path / "x.exr")]) == 2
    _one_error_line(capsys, "####")
    assert main(["denoise", str(tmp_path / "shot.####.exr"), "-o", str(tmp_path / "y.####.exr")]) == 2
    _one_error_line(capsys, "--frames")
    assert main(["denoise", str(tmp_path / "shot.####.exr"), "--frames", "3-1",
                 "-o", str(tmp_path / "y.####.exr")]) == 2
    _one_error_line(capsys, "--frames")
    # A frame listed twice was an output "written twice (-o/--output (frame 1))", naming no frame list.
    assert main(["denoise", str(tmp_path / "shot.####.exr"), "--frames", "1-3,2",
                 "-o", str(tmp_path / "y.####.exr")]) == 2
    _one_error_line(capsys, "--frames: '1-3,2' names frame 2 more than once")
    assert not list(tmp_path.glob("y.*"))


def test_frames_read_each_frames_own_plane_files(tmp_path, rng, capsys):
    """``--alb alb.####.exr`` with ``--frames``: each frame its own albedo, as a run per frame reads it (the
    placeholder was taken as a file name, "no such file"; a red-team pass). A plane file without one serves
    every frame; a placeholder without --frames is refused, as in an input's name."""
    for f in (1, 2):
        _dump(tmp_path / f"shot.{f:04d}.exr", rng)
        write_image(tmp_path / f"alb.{f:04d}.exr", rng.random((H, W, 3)))
    guided = ["--guide", "features", "-q"]
    assert main(["denoise", str(tmp_path / "shot.####.exr"), "--frames", "1-2", "-o", str(tmp_path / "den.####.exr"),
                 "--alb", str(tmp_path / "alb.####.exr"), *guided]) == 0
    for f in (1, 2):
        assert main(["denoise", str(tmp_path / f"shot.{f:04d}.exr"), "-o", str(tmp_path / f"one.{f}.exr"),
                     "--alb", str(tmp_path / f"alb.{f:04d}.exr"), *guided]) == 0
        assert (read_image(tmp_path / f"den.{f:04d}.exr") == read_image(tmp_path / f"one.{f}.exr")).all()
    assert main(["denoise", str(tmp_path / "shot.0002.exr"), "-o", str(tmp_path / "other.exr"),
                 "--alb", str(tmp_path / "alb.0001.exr"), *guided]) == 0
    assert not (read_image(tmp_path / "other.exr") == read_image(tmp_path / "den.0002.exr")).all()
    # One albedo for every frame, as before.
    assert main(["denoise", str(tmp_path / "shot.####.exr"), "--frames", "1-2", "-o", str(tmp_path / "all.####.exr"),
                 "--alb", str(tmp_path / "alb.0001.exr"), *guided]) == 0
    assert (read_image(tmp_path / "all.0001.exr") == read_image(tmp_path / "den.0001.exr")).all()
    # A frame's file of another size is named with its frame; nothing is written.
    write_image(tmp_path / "alb.0002.exr", rng.random((4, 4, 3)), overwrite=True)
    assert main(["denoise", str(tmp_path / "shot.####.exr"), "--frames", "1-2", "-o", str(tmp_path / "bad.####.exr"),
                 "--alb", str(tmp_path / "alb.####.exr"), *guided]) == 2
    _one_error_line(capsys, "alb.0002.exr")
    assert not list(tmp_path.glob("bad.*"))
    assert main(["denoise", str(tmp_path / "shot.0001.exr"), "-o", str(tmp_path / "bad.exr"),
                 "--alb", str(tmp_path / "alb.####.exr"), "-q"]) == 2
    _one_error_line(capsys, "--alb", "#### frame placeholder but no --frames")


def test_the_comparison_with_a_reference_is_a_result_on_stdout(tmp_path, rng, capsys):
    """``-r`` printed its relMSE only in the summary line on stderr, which ``-q`` silences (a docs audit)."""
    for f in (1, 2):
        _dump(tmp_path / f"shot.{f}.exr", rng)
        write_image(tmp_path / f"ref.{f}.exr", rng.random((H, W, 3)))
    assert main(["denoise", str(tmp_path / "shot.#.exr"), "--frames", "1-2", "-r", str(tmp_path / "ref.#.exr"),
                 "-o", str(tmp_path / "den.#.exr"), "-q"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    lines = out.splitlines()
    assert [line.split(": relMSE ")[0] for line in lines] == [str(tmp_path / f"den.{f}.exr") for f in (1, 2)]
    for f, line in zip((1, 2), lines):
        value = float(line.split("relMSE ")[1].split()[0])
        assert line.endswith(f"against {tmp_path / f'ref.{f}.exr'}")
        assert value == pytest.approx(relmse(read_image(tmp_path / f"den.{f}.exr"),
                                             read_image(tmp_path / f"ref.{f}.exr")), rel=1e-5)


def test_frames_compared_with_each_frames_own_reference(tmp_path, rng, capsys):
    """``-r ref.####.exr`` with --frames: each frame against its own (the placeholder was taken as a file name,
    "no such file"); --maxerror names the frame's reference; without --frames a placeholder is refused."""
    for f in (1, 2):
        _dump(tmp_path / f"shot.{f}.exr", rng)
        write_image(tmp_path / f"ref.{f}.exr", rng.random((H, W, 3)))
    common = [str(tmp_path / "shot.#.exr"), "--frames", "1-2", "-r", str(tmp_path / "ref.#.exr")]
    assert main(["denoise", *common, "-o", str(tmp_path / "den.#.exr")]) == 0
    printed = [line.split("relMSE ")[1] for line in capsys.readouterr().err.splitlines() if "relMSE" in line]
    for f in (1, 2):
        assert main(["denoise", str(tmp_path / f"shot.{f}.exr"), "-o", str(tmp_path / f"one.{f}.exr"),
                     "-r", str(tmp_path / f"ref.{f}.exr")]) == 0
        assert printed[f - 1] in capsys.readouterr().err
    assert main(["denoise", *common, "-o", str(tmp_path / "bad.#.exr"), "--maxerror", "1e-9", "-q"]) == 1
    _one_error_line(capsys, "bad.1.exr: relMSE", f"against {tmp_path / 'ref.1.exr'} exceeds")
    assert main(["denoise", str(tmp_path / "shot.1.exr"), "-o", str(tmp_path / "x.exr"),
                 "-r", str(tmp_path / "ref.#.exr"), "-q"]) == 2
    _one_error_line(capsys, "-r/--ref", "#### frame placeholder but no --frames")
    assert main(["denoise", *common, "-o", str(tmp_path / "ref.#.exr"), "--overwrite", "-q"]) == 2
    _one_error_line(capsys, "is the input", "-r/--ref (frame 1)")


def test_a_frames_own_plane_file_is_an_input_no_output_may_replace(tmp_path, rng, capsys):
    """``-o alb.####.exr --alb alb.####.exr --overwrite`` replaced every frame's albedo with its denoised image
    (exit 0), and frame 1's output could be frame 11's albedo: a frame's plane file was not an input of the
    command's path checks (a red-team pass). A missing one was the reader's "no such file", without the option."""
    for f in (1, 11):
        _dump(tmp_path / f"shot.{f}.exr", rng)
        write_image(tmp_path / f"alb.{f}.exr", rng.random((H, W, 3)))
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    common = [str(tmp_path / "shot.#.exr"), "--frames", "1,11", "--overwrite", "-q", "--guide", "features"]
    assert main(["denoise", *common, "-o", str(tmp_path / "alb.#.exr"), "--alb", str(tmp_path / "alb.#.exr")]) == 2
    _one_error_line(capsys, "-o/--output (frame 1) is the input", "--alb (frame 1)")
    assert main(["denoise", *common, "-o", str(tmp_path / "alb.1#.exr"), "--alb", str(tmp_path / "alb.#.exr")]) == 2
    _one_error_line(capsys, "alb.11.exr", "--alb (frame 11)")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    assert main(["denoise", *common, "-o", str(tmp_path / "o.#.exr"), "--alb", str(tmp_path / "none.#.exr")]) == 2
    _one_error_line(capsys, "--alb (frame 1)", "no such file")


# ---------------------------------------------------------------- info, diff, merge

def test_info_json(tmp_path, rng, capsys):
    src = tmp_path / "d.exr"
    _dump(src, rng, spp=6)
    capsys.readouterr()
    assert main(["info", str(src), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "samples" and info["preset"] == "awr"
    assert (info["width"], info["height"]) == (W, H)
    assert info["total_samples"] == 6 * H * W and info["spp"]["mean"] == 6


def test_info_json_writes_a_header_vector_holding_nan_as_text(tmp_path, rng, capsys):
    """A valid file whose ``awr:*`` vector attribute holds NaN: ``awr info --json`` failed with "Out of range
    float values are not JSON compliant", naming nothing (a red-team pass); numpy values are strict JSON now."""
    import OpenEXR

    src = tmp_path / "d.exr"
    _dump(src, rng, spp=2)
    with OpenEXR.File(str(src), separate_channels=True) as f:
        header = {k: v for k, v in f.header().items() if k.startswith("awr")}
        channels = {k: OpenEXR.Channel(k, v.pixels.copy()) for k, v in f.channels().items()}
    header.update(compression=OpenEXR.ZIP_COMPRESSION, type=OpenEXR.scanlineimage,
                  **{"awr:offset": np.array([np.nan, 1.0], dtype=np.float32)})
    with OpenEXR.File(header, channels) as out:
        out.write(str(tmp_path / "v.exr"))
    capsys.readouterr()
    assert main(["info", str(tmp_path / "v.exr"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["attributes"]["awr:offset"] == ["nan", 1.0]


def test_diff_metrics_maxerror_and_difference_image(tmp_path, capsys):
    ref = np.full((H, W, 3), 0.5)
    write_image(tmp_path / "ref.exr", ref)
    write_image(tmp_path / "img.exr", ref + 0.1)
    capsys.readouterr()
    assert main(["diff", str(tmp_path / "img.exr"), "-r", str(tmp_path / "ref.exr"), "--json",
                 "-o", str(tmp_path / "d.exr")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["mse"] == pytest.approx(0.01, rel=1e-5)
    assert res["relmse"] == pytest.approx(0.01 / 0.26, rel=1e-5)
    assert res["mean_error"] == pytest.approx(0.2, rel=1e-5)
    np.testing.assert_allclose(read_image(tmp_path / "d.exr"), 0.1, rtol=1e-6)
    assert main(["diff", str(tmp_path / "img.exr"), "-r", str(tmp_path / "ref.exr"), "--maxerror", "0.01"]) == 1
    _one_error_line(capsys, "img.exr", "relmse")
    assert main(["diff", str(tmp_path / "img.exr"), "-r", str(tmp_path / "ref.exr"), "--maxerror", "0.1"]) == 0
    # A negative bound on an error that is never negative is refused (it would fail every image) ...
    assert main(["diff", str(tmp_path / "img.exr"), "-r", str(tmp_path / "ref.exr"), "--maxerror", "-1"]) == 2
    _one_error_line(capsys, "--maxerror", "below 0")
    # ... and kept for SSIM, which can be negative
    assert main(["diff", str(tmp_path / "img.exr"), "-r", str(tmp_path / "ref.exr"), "--metric", "ssim",
                 "--maxerror", "-0.5"]) == 0
    # ... but not outside SSIM's range: above 1 every image failed, below -1 every image passed
    for bound in ("2", "-2"):
        assert main(["diff", str(tmp_path / "img.exr"), "-r", str(tmp_path / "ref.exr"), "--metric", "ssim",
                     "--maxerror", bound]) == 2
        _one_error_line(capsys, "--maxerror", "outside -1..1, the range of ssim")


def test_diff_checks_the_image_mean(tmp_path, capsys):
    """An exposure change relMSE and MSE hardly see: 0.8% on every pixel passes ``--maxerror 0.01`` of
    relMSE and fails ``--metric mean_error --maxerror 0.005``; errors that cancel keep the mean."""
    ref = np.full((H, W, 3), 0.5)
    write_image(tmp_path / "ref.exr", ref)
    write_image(tmp_path / "dark.exr", ref * 0.992)
    checkerboard = (np.indices((H, W)).sum(axis=0) % 2 * 2 - 1)[..., None] * 0.1
    write_image(tmp_path / "noisy.exr", ref + checkerboard)
    args = ["-r", str(tmp_path / "ref.exr")]
    capsys.readouterr()
    assert main(["diff", str(tmp_path / "dark.exr"), *args, "--maxerror", "0.01"]) == 0
    assert "mean error 0.8%" in capsys.readouterr().out
    assert main(["diff", str(tmp_path / "dark.exr"), *args, "--metric", "mean_error", "--maxerror", "0.005"]) == 1
    _one_error_line(capsys, "dark.exr", "mean_error 0.008")
    assert main(["diff", str(tmp_path / "noisy.exr"), *args, "--metric", "mean_error", "--maxerror", "0.005"]) == 0
    assert main(["diff", str(tmp_path / "noisy.exr"), *args, "--metric", "mean_error", "--maxerror", "-0.1"]) == 2
    _one_error_line(capsys, "--maxerror", "below 0, which mean_error never is")


def test_diff_options_that_would_do_nothing_or_be_blamed_on_the_other_file(tmp_path, capsys):
    """A red-team pass: ``--metric`` without ``--maxerror`` was accepted and did nothing; a list given as
    ``--ref-channels`` was refused as ``--channels``, which was not given; a channel count that differed named
    neither side."""
    write_image(tmp_path / "rgb.exr", np.full((H, W, 3), 0.5))
    base = ["diff", str(tmp_path / "rgb.exr"), "-r", str(tmp_path / "rgb.exr")]
    assert main([*base, "--metric", "ssim"]) == 2
    _one_error_line(capsys, "--metric: ssim is the metric --maxerror checks; give --maxerror")
    assert main([*base, "--ref-channels", "R,G,B,R"]) == 2
    _one_error_line(capsys, "--ref-channels: 'R,G,B,R' names a channel twice")
    assert main([*base, "--channels", "R"]) == 2
    _one_error_line(capsys, "3 channel(s) read from the reference, 1 from IMAGE", "--channels and --ref-channels")


def test_diff_pairs_channels_by_name_when_one_side_names_them(tmp_path, capsys):
    """``--channels B,G,R`` (the order ``awr info`` prints) paired the image's B with the reference's R by
    position: an image against itself came out with a relMSE of 0.14, exit 0 (a red-team pass)."""
    image = np.stack([np.full((H, W), v) for v in (0.2, 0.5, 0.9)], axis=-1)
    write_image(tmp_path / "img.exr", image)
    write_image(tmp_path / "layer.exr", image, channels=("a.R", "a.G", "a.B"))
    img, layer = str(tmp_path / "img.exr"), str(tmp_path / "layer.exr")
    for option in ("--channels", "--ref-channels"):
        assert main(["diff", img, "-r", img, option, "B,G,R", "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["mse"] == 0.0
    # The other file without those names: R,G,B in order pairs with its R,G,B; another order is refused.
    assert main(["diff", layer, "-r", img, "--channels", "a.R,a.G,a.B", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["mse"] == 0.0
    assert main(["diff", layer, "-r", img, "--channels", "a.B,a.G,a.R"]) == 2
    _one_error_line(capsys, "--channels: a.B,a.G,a.R would be paired by position", "give --ref-channels too")
    assert main(["diff", layer, "-r", img, "--channels", "a.B,a.G,a.R", "--ref-channels", "B,G,R", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["mse"] == 0.0


def test_a_sequence_s_references_are_checked_one_at_a_time(tmp_path, rng, monkeypatch):
    """``denoise --frames ... --ref ref.####.exr`` read every frame's reference to check its size and kept them all
    in memory until the frames began: a long 1080p sequence held gigabytes for a size check (a review)."""
    import weakref

    from awr_denoise.cli import denoise_cmd
    from awr_denoise.io.exr import read_windows

    refs, sources = [], []
    for k in range(3):
        sources.append(str(tmp_path / f"d{k}.exr"))
        _dump(sources[-1], rng)
        refs.append(str(tmp_path / f"ref{k}.exr"))
        write_image(refs[-1], rng.random((H, W, 3)))
    alive: set[int] = set()
    most = []
    real = denoise_cmd.read_image

    def tracked(path, *args, **kwargs):
        image = real(path, *args, **kwargs)
        alive.add(id(image))
        weakref.finalize(image, alive.discard, id(image))
        most.append(len(alive))
        return image

    monkeypatch.setattr(denoise_cmd, "read_image", tracked)
    denoise_cmd._check_references(refs, sources, [read_windows(path) for path in sources])
    assert most == [1, 1, 1]
    write_image(refs[1], rng.random((H, W + 1, 3)), overwrite=True)  # the size is still checked
    with pytest.raises(ValueError, match="ref1.exr: size 33x24 does not match 32x24 of "):
        denoise_cmd._check_references(refs, sources, [read_windows(path) for path in sources])


def test_merge_is_exact_chan_update(tmp_path, rng, capsys):
    shape = (H, W)
    pix_a = rng.integers(0, H * W, 4000)
    pix_b = rng.integers(0, H * W, 3000)
    val_a = rng.random((4000, 3))
    val_b = rng.random((3000, 3)) * 2
    a = SampleBuffer.from_samples(pix_a, val_a, shape)
    b = SampleBuffer.from_samples(pix_b, val_b, shape)
    write_sample_buffer(tmp_path / "a.exr", a)
    write_sample_buffer(tmp_path / "b.exr", b)
    assert main(["merge", str(tmp_path / "a.exr"), str(tmp_path / "b.exr"), "-o", str(tmp_path / "m.exr"), "-q"]) == 0
    merged = read_sample_dump(tmp_path / "m.exr").buffer
    # Reference: statistics of the float32 values the dumps hold, computed from all samples at once.
    a32 = SampleBuffer.from_moments(a.count, a.mean.astype(np.float32), a.variance.astype(np.float32))
    b32 = SampleBuffer.from_moments(b.count, b.mean.astype(np.float32), b.variance.astype(np.float32))
    expected = a32.merge(b32)
    np.testing.assert_array_equal(merged.count, a.count + b.count)
    np.testing.assert_allclose(merged.mean, expected.mean.astype(np.float32), rtol=0)
    np.testing.assert_allclose(merged.variance, expected.variance.astype(np.float32), rtol=0)
    direct = SampleBuffer.from_samples(np.concatenate([pix_a, pix_b]), np.concatenate([val_a, val_b]), shape)
    np.testing.assert_allclose(merged.mean, direct.mean, rtol=1e-6)
    np.testing.assert_allclose(merged.variance, direct.variance, rtol=2e-5, atol=1e-7)


BAD_RUN_SETTINGS = [("awr:strategy", "evil", "'evil' is not one of awr"), ("awr:initial_spp", 0, "outside 1.."),
                    ("awr:rare_paths", "evil", "'evil' is not one of even"),
                    ("awr:noise_model", "evil", "'evil' is not one of levels"),
                    ("awr:round_growth", "nan", "is not a number above 0"),
                    ("awr:round_growth", "1e7", "not a number above 0"),
                    ("awr:priority_wavelet", "dmey", "not a perfect-reconstruction"),
                    ("awr:priority_levels", 0, "outside 1.."),
                    ("awr:priority_levels", 9, "outside 1..4 for its image"),  # the 24x32 dump allows 4
                    ("awr:spp_max", "x", "not a whole number")]
"""Run settings of a dump that plan refuses (merge carries them, info warns), with what the refusal says."""


@pytest.mark.parametrize("attribute, value, needle", BAD_RUN_SETTINGS)
def test_merge_refuses_a_run_setting_plan_would_refuse(tmp_path, rng, capsys, attribute, value, needle):
    """merge carried a running dump's strategy and first round's spp into its output unchecked: exit 0, and the
    next plan refused the dump it wrote; plan's refusal of an initial spp of 0 named neither the file nor the
    attribute (a red-team pass)."""
    buf = _dump(tmp_path / "d.exr", rng)
    write_sample_buffer(tmp_path / "bad.exr", buf, header={attribute: value})
    for argv in (["merge", str(tmp_path / "bad.exr"), str(tmp_path / "d.exr"), "--allow-duplicates",
                  "-o", str(tmp_path / "m.exr")], ["plan", str(tmp_path / "bad.exr"), "-o", str(tmp_path / "r.exr")]):
        assert main(argv + ["-q"]) == 2
        _one_error_line(capsys, "bad.exr", attribute, needle)
    assert not (tmp_path / "m.exr").exists() and not (tmp_path / "r.exr").exists()


def test_merge_refuses_a_running_mark_that_is_not_0_or_1(tmp_path, rng, capsys):
    """``awr:running = maybe`` was read as "not running" without a word (a red-team pass)."""
    buf = _dump(tmp_path / "d.exr", rng)
    write_sample_buffer(tmp_path / "bad.exr", buf, header={"awr:running": "maybe", "awr:seed": 1, "awr:round": 2})
    assert main(["merge", str(tmp_path / "bad.exr"), str(tmp_path / "d.exr"), "--allow-duplicates",
                 "-o", str(tmp_path / "m.exr"), "-q"]) == 2
    _one_error_line(capsys, "bad.exr: awr:running: 'maybe' is not 0 or 1")
    assert not (tmp_path / "m.exr").exists()


@pytest.mark.parametrize("attribute, value, needle", BAD_RUN_SETTINGS + [("awr:seed", "x", "not a whole number"),
                                                                         ("awr:round", 0, "outside 1..")])
def test_info_says_which_run_setting_plan_refuses(tmp_path, rng, capsys, attribute, value, needle):
    """info said only "ready to denoise" (true: denoise reads the file) for a dump plan refuses as a running
    dump; it now warns, naming the attribute, on its lines and in --json. A valid dump gets no such warning."""
    buf = _dump(tmp_path / "d.exr", rng)
    write_sample_buffer(tmp_path / "bad.exr", buf, header={attribute: value})
    assert main(["plan", str(tmp_path / "bad.exr"), "-o", str(tmp_path / "r.exr"), "-q"]) == 2
    capsys.readouterr()
    assert main(["info", str(tmp_path / "bad.exr")]) == 0
    out = capsys.readouterr().out
    warning = [line for line in out.splitlines() if "awr plan refuses it" in line]
    assert len(warning) == 1 and attribute in warning[0] and needle in warning[0] and "ready to denoise" in out
    assert main(["info", str(tmp_path / "bad.exr"), "--json"]) == 0
    assert any(attribute in w for w in json.loads(capsys.readouterr().out)["warnings"])
    assert main(["info", str(tmp_path / "d.exr")]) == 0
    assert "awr plan refuses" not in capsys.readouterr().out


@pytest.mark.parametrize("attribute, value, needle", BAD_RUN_SETTINGS + [("awr:seed", "x", "not a whole number")])
def test_info_says_which_run_setting_of_a_request_merge_refuses(tmp_path, capsys, attribute, value, needle):
    """info checked the run settings of sample dumps only: a request map that ``merge --request`` refuses got no
    warning (a red-team pass). Its round is the request's own (0 for the first), which is no refusal."""
    assert main(["plan", "--size", f"{W}x{H}", "-o", str(tmp_path / "r.exr"), "-q"]) == 0
    assert _external().main([str(tmp_path / "r.exr"), str(tmp_path / "b.exr")]) == 0
    header = request_attributes(tmp_path / "r.exr")
    write_request(tmp_path / "bad.exr", read_request(tmp_path / "r.exr"), header={**header, attribute: value})
    assert main(["merge", str(tmp_path / "b.exr"), "--request", str(tmp_path / "bad.exr"), "-o",
                 str(tmp_path / "m.exr"), "-q"]) == 2
    _one_error_line(capsys, "bad.exr", attribute, needle)
    assert not (tmp_path / "m.exr").exists()
    assert main(["info", str(tmp_path / "bad.exr")]) == 0
    warning = [line for line in capsys.readouterr().out.splitlines() if "awr merge --request refuses it" in line]
    assert len(warning) == 1 and attribute in warning[0] and needle in warning[0]
    assert main(["info", str(tmp_path / "bad.exr"), "--json"]) == 0
    assert any(attribute in w for w in json.loads(capsys.readouterr().out)["warnings"])
    assert main(["info", str(tmp_path / "r.exr"), "--json"]) == 0
    assert "warnings" not in json.loads(capsys.readouterr().out)


def test_plan_refuses_a_first_round_above_the_cap_wherever_each_comes_from(tmp_path, rng, capsys):
    """A dump's ``awr:initial_spp`` above its ``awr:spp_max`` (or above ``--spp-max``) was clamped without a word
    and the request recorded the clamped value, where the same pair as options is refused (a red-team pass)."""
    buf = _dump(tmp_path / "d.exr", rng, spp=1)
    for header, given, needle in (({"awr:initial_spp": 100, "awr:spp_max": 64}, [],
                                   "bad.exr: awr:initial_spp 100 exceeds its awr:spp_max 64"),
                                  ({"awr:initial_spp": 100}, ["--spp-max", "50"],
                                   "bad.exr: awr:initial_spp 100 exceeds --spp-max 50"),
                                  ({"awr:spp_max": 64}, ["--initial-spp", "100"],
                                   "--initial-spp: 100 exceeds awr:spp_max 64 of ")):
        write_sample_buffer(tmp_path / "bad.exr", buf, header=header, overwrite=True)
        assert main(["plan", str(tmp_path / "bad.exr"), *given, "-o", str(tmp_path / "r.exr"), "-q"]) == 2
        _one_error_line(capsys, needle)
        assert not (tmp_path / "r.exr").exists()
    # Given both ways, the option's first round stands (the dump's is not read).
    assert main(["plan", str(tmp_path / "bad.exr"), "--initial-spp", "8", "-o", str(tmp_path / "r.exr"), "-q"]) == 0
    # A run whose every pixel is at its cap is said to be complete.
    write_sample_buffer(tmp_path / "full.exr", buf, header={"awr:spp_max": 1}, overwrite=True)
    assert main(["plan", str(tmp_path / "full.exr"), "-o", str(tmp_path / "f.exr"), "-q"]) == 2
    _one_error_line(capsys, "awr:spp_max 1 of ", "the 0 that spp_max still allows", "the run is complete")


def test_merge_independent_needs_two_renders_by_its_option(tmp_path, rng, capsys):
    """The library's refusal named its parameter ("paths: 1 file(s) given"; a red-team pass)."""
    _dump(tmp_path / "d.exr", rng)
    assert main(["merge", "--independent", str(tmp_path / "d.exr"), "-o", str(tmp_path / "m.exr"), "-q"]) == 2
    _one_error_line(capsys, "--independent: 1 render given; the spread of their means needs at least 2")
    assert not (tmp_path / "m.exr").exists()


def test_merge_independent_refuses_options_it_does_not_read(tmp_path, rng, capsys):
    """``--nonfinite`` and ``--allow-duplicates`` did nothing with --independent; ``--preset deep`` and an
    ``--spp`` past the counts' limit were named by the library's parameters (a red-team pass)."""
    renders = []
    for i in range(2):
        renders.append(str(tmp_path / f"r{i}.exr"))
        write_image(renders[-1], rng.random((H, W, 3)))
    base = ["merge", "--independent", *renders, "--color", "RGB", "-o", str(tmp_path / "m.exr"), "-q"]
    for extra, needle in ((["--spp", "4", "--nonfinite", "zero"], "--nonfinite: zero is not read with --independent"),
                          (["--spp", "4", "--allow-duplicates"], "--allow-duplicates: not read with --independent"),
                          (["--spp", "4", "--preset", "deep"], "--preset: deep is not read with --independent"),
                          (["--spp", "16777216"], "--spp: 16777216 per render, 2 renders, exceed 16777216")):
        assert main([*base, *extra]) == 2
        _one_error_line(capsys, needle)
    assert main([*base, "--spp", "4"]) == 0 and (tmp_path / "m.exr").exists()


def test_merge_size_mismatch(tmp_path, rng, capsys):
    _dump(tmp_path / "a.exr", rng)
    _dump(tmp_path / "b.exr", rng, shape=(H, W + 1))
    assert main(["merge", str(tmp_path / "a.exr"), str(tmp_path / "b.exr"), "-o", str(tmp_path / "m.exr")]) == 2
    _one_error_line(capsys, "b.exr", "does not match")
    assert not (tmp_path / "m.exr").exists()


# ---------------------------------------------------------------- the file-only loop

def test_file_only_loop(tmp_path, capsys):
    """plan -> external renderer -> merge -> ... -> denoise, through files only."""
    ext = _external()
    seed = 11
    assert ext.main(["--reference", str(W), str(H), str(tmp_path / "ref.exr")]) == 0
    assert main(["plan", "--size", f"{W}x{H}", "--initial-spp", "4", "--seed", str(seed),
                 "-o", str(tmp_path / "req0.exr"), "-q"]) == 0
    requests = []
    dump = None
    for k in range(4):
        req_path = tmp_path / f"req{k}.exr"
        if k > 0:
            assert main(["plan", str(dump), "--round-spp", "2", "-o", str(req_path), "-q"]) == 0
        requests.append(read_request(req_path))
        assert ext.main([str(req_path), str(tmp_path / f"batch{k}.exr")]) == 0
        new_dump = tmp_path / f"dump{k + 1}.exr"
        inputs = [str(tmp_path / f"batch{k}.exr")] if dump is None else [str(dump), str(tmp_path / f"batch{k}.exr")]
        assert main(["merge", *inputs, "--request", str(req_path), "-o", str(new_dump), "-q"]) == 0
        dump = new_dump
    final = read_sample_dump(dump)
    assert [r.round for r in requests] == [0, 1, 2, 3]
    assert int(str(final.attributes["awr:seed"])) == seed and final.attributes["awr:round"] == 4
    # Every round starts each pixel where the previous rounds stopped: no sample index is reused.
    issued = np.zeros((H, W), np.int64)
    for r in requests:
        np.testing.assert_array_equal(r.first_index, issued)
        issued += r.counts
    np.testing.assert_array_equal(final.buffer.count, issued)
    np.testing.assert_array_equal(final.issued, issued)
    assert final.buffer.total_samples == sum(r.total for r in requests)
    assert requests[1].counts.max() > requests[1].counts.min()  # adaptive rounds are not uniform
    # The merged statistics equal those of all samples at once (float32 storage aside).
    pixels, values = zip(*(ext.render_samples(r.counts, r.first_index, seed) for r in requests))
    direct = SampleBuffer.from_samples(np.concatenate(pixels), np.concatenate(values), (H, W))
    np.testing.assert_allclose(final.buffer.mean, direct.mean, rtol=1e-5)
    np.testing.assert_allclose(final.buffer.variance, direct.variance, rtol=1e-3, atol=1e-6)
    # Denoise and check against the analytic reference, oidnDenoise style.
    assert main(["denoise", str(dump), "-o", str(tmp_path / "final.exr"), "-r", str(tmp_path / "ref.exr"),
                 "--maxerror", "0.05", "-q"]) == 0
    capsys.readouterr()
    assert main(["diff", str(dump), "-r", str(tmp_path / "ref.exr"), "--json"]) == 0
    noisy = json.loads(capsys.readouterr().out)["relmse"]
    assert main(["diff", str(tmp_path / "final.exr"), "-r", str(tmp_path / "ref.exr"), "--json"]) == 0
    denoised = json.loads(capsys.readouterr().out)["relmse"]
    assert denoised < noisy
    # A stale batch (round 2's, told again with round 3's request) named its request: refused, nothing written.
    assert main(["merge", str(tmp_path / "dump3.exr"), str(tmp_path / "batch2.exr"), "--request",
                 str(tmp_path / "req3.exr"), "-o", str(tmp_path / "stale.exr"), "-q"]) == 2
    _one_error_line(capsys, "batch2.exr", "awr:request_round", "answers a request of round 2, not")
    assert not (tmp_path / "stale.exr").exists()
    # A batch whose header names another loop's seed (its renderer drew that loop's sequence) was merged as this
    # loop's round, exit 0, and its samples counted twice beside the other loop's own (an attack pass): refused.
    with OpenEXR.File(str(tmp_path / "batch3.exr")) as f:
        header, channels = dict(f.header()), {name: c.pixels.copy() for name, c in f.channels().items()}
    _write(tmp_path / "other.exr", channels, {**header, "awr:seed": str(seed + 1)})
    assert main(["merge", str(tmp_path / "dump3.exr"), str(tmp_path / "other.exr"), "--request",
                 str(tmp_path / "req3.exr"), "-o", str(tmp_path / "other_dump.exr"), "-q"]) == 2
    _one_error_line(capsys, "other.exr: awr:seed", f"seed {seed + 1}, not of", f"seed {seed}")
    assert not (tmp_path / "other_dump.exr").exists()
    _write(tmp_path / "same.exr", channels, {**header, "awr:seed": str(seed)})  # its own seed: merged
    assert main(["merge", str(tmp_path / "dump3.exr"), str(tmp_path / "same.exr"), "--request",
                 str(tmp_path / "req3.exr"), "-o", str(tmp_path / "same_dump.exr"), "-q"]) == 0


def test_a_uniform_run_through_files_stays_uniform(tmp_path):
    """The strategy was not carried into the merged dump and ``plan`` defaulted to awr: a uniform
    baseline run through files became adaptive after round 0 without a word (a red-team pass)."""
    ext = _external()
    assert main(["plan", "--size", f"{W}x{H}", "--strategy", "uniform", "-o", str(tmp_path / "r0.exr"), "-q"]) == 0
    assert ext.main([str(tmp_path / "r0.exr"), str(tmp_path / "b0.exr")]) == 0
    assert main(["merge", str(tmp_path / "b0.exr"), "--request", str(tmp_path / "r0.exr"), "-o",
                 str(tmp_path / "d1.exr"), "-q"]) == 0
    assert read_sample_dump(tmp_path / "d1.exr").attributes["awr:strategy"] == "uniform"
    assert main(["plan", str(tmp_path / "d1.exr"), "--round-spp", "2", "-o", str(tmp_path / "r1.exr"), "-q"]) == 0
    request = read_request(tmp_path / "r1.exr")
    assert request.counts.min() == request.counts.max() == 2
    assert main(["plan", str(tmp_path / "d1.exr"), "--round-spp", "2", "--strategy", "awr", "-o",
                 str(tmp_path / "r1a.exr"), "-q"]) == 0  # a strategy given is the one used
    assert read_request(tmp_path / "r1a.exr").counts.max() > 2
    # The first round's --initial-spp is carried too: the least a pixel is brought up to (a review).
    v = tmp_path / "v"
    v.mkdir()
    assert main(["plan", "--size", f"{W}x{H}", "--strategy", "variance", "--initial-spp", "2", "-o",
                 str(v / "r0.exr"), "-q"]) == 0
    assert ext.main([str(v / "r0.exr"), str(v / "b0.exr")]) == 0
    assert main(["merge", str(v / "b0.exr"), "--request", str(v / "r0.exr"), "-o", str(v / "d1.exr"), "-q"]) == 0
    for name, given in (("carried", []), ("given", ["--initial-spp", "2"])):
        assert main(["plan", str(v / "d1.exr"), "--budget", "800", *given, "-o", str(v / f"{name}.exr"), "-q"]) == 0
    assert np.array_equal(read_request(v / "carried.exr").counts, read_request(v / "given.exr").counts)


def test_running_dumps_of_one_seed_are_not_merged(tmp_path, capsys):
    """Two machines running the documented loop with the same ``--seed`` hold the same first samples
    at every pixel: ``merge A B`` counted them twice, exit 0 (a red-team pass). Refused unless
    ``--allow-duplicates``; loops of two seeds merge."""
    ext = _external()
    # b has another round: not a copy of a, the same first samples still
    a, b, c = (_file_loop(tmp_path / name, seed, rounds)[-1] for name, seed, rounds in (("a", 7, 0), ("b", 7, 1),
                                                                                        ("c", 8, 0)))
    assert main(["merge", a, b, "-o", str(tmp_path / "ab.exr"), "-q"]) == 2
    _one_error_line(capsys, "are running dumps of one sample sequence (awr:seed 7)", "--allow-duplicates")
    assert not (tmp_path / "ab.exr").exists()
    assert main(["merge", a, c, "-o", str(tmp_path / "ac.exr"), "-q"]) == 0
    assert main(["merge", a, b, "--allow-duplicates", "-o", str(tmp_path / "ab.exr"), "-q"]) == 0
    # A batch naming its seed and round (written by the library with provenance) is a batch, not a
    # running dump: told with its request, it merges (a review of this check).
    folder = tmp_path / "a"
    assert main(["plan", a, "--round-spp", "2", "-o", str(folder / "r1.exr"), "-q"]) == 0
    request = read_request(folder / "r1.exr")
    pixel, values = ext.render_samples(request.counts, request.first_index, 7)
    batch = SampleBuffer.from_samples(pixel, values, (H, W))
    write_sample_buffer(folder / "b1.exr", batch, header=provenance(seed=7, round=1))
    assert main(["merge", a, str(folder / "b1.exr"), "--request", str(folder / "r1.exr"), "-o",
                 str(folder / "d2.exr"), "-q"]) == 0


def _file_loop(folder, seed, rounds, *first):
    """A run through files with the stand-in renderer: the first round planned with ``first``'s options, then
    ``rounds`` more; the running dump after each round."""
    ext = _external()
    folder.mkdir()
    assert main(["plan", "--size", f"{W}x{H}", "--seed", str(seed), *first, "-o", str(folder / "r0.exr"), "-q"]) == 0
    assert ext.main([str(folder / "r0.exr"), str(folder / "b0.exr")]) == 0
    assert main(["merge", str(folder / "b0.exr"), "--request", str(folder / "r0.exr"), "-o", str(folder / "d1.exr"),
                 "-q"]) == 0
    dumps = [folder / "d1.exr"]
    for k in range(1, rounds + 1):
        assert main(["plan", str(dumps[-1]), "-o", str(folder / f"r{k}.exr"), "-q"]) == 0
        assert ext.main([str(folder / f"r{k}.exr"), str(folder / f"b{k}.exr")]) == 0
        assert main(["merge", str(dumps[-1]), str(folder / f"b{k}.exr"), "--request", str(folder / f"r{k}.exr"),
                     "-o", str(folder / f"d{k + 1}.exr"), "-q"]) == 0
        dumps.append(folder / f"d{k + 1}.exr")
    return [str(d) for d in dumps]


def test_plan_refuses_a_batch_for_the_running_dump(tmp_path, capsys):
    """A batch looks like a dump: planned from, it handed out sample indices the run had used (its own request's
    first_index on) and lost the run's seed, exit 0. ``plan`` refuses
    it naming the merge that makes the dump, ``info`` says what it is; the dump itself plans as before."""
    dumps = _file_loop(tmp_path / "run", 7, 1)
    batch = str(tmp_path / "run" / "b1.exr")
    assert main(["plan", batch, "-o", str(tmp_path / "x.exr")]) == 2
    _one_error_line(capsys, "b1.exr: a batch answering request round 1, not the running dump", "awr merge DUMP.exr")
    assert not (tmp_path / "x.exr").exists()
    assert main(["info", batch]) == 0
    assert "note: a batch answering request round 1" in capsys.readouterr().out
    assert main(["info", dumps[-1]]) == 0
    assert "a batch answering" not in capsys.readouterr().out
    assert main(["plan", dumps[-1], "-o", str(tmp_path / "y.exr"), "-q"]) == 0


def test_a_plain_merge_of_a_batch_the_dump_has_taken_in_warns(tmp_path, capsys):
    """``merge dump2.exr b1.exr`` (no --request) counted round 1's batch a second time without a word, though the
    batch names its round and the dump is past it. Warned, even with -q; not refused (a batch names no loop)."""
    dumps = _file_loop(tmp_path / "run", 7, 2)
    folder = tmp_path / "run"
    assert main(["merge", dumps[-1], str(folder / "b1.exr"), "-o", str(tmp_path / "again.exr"), "-q"]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("awr: warning: ")
    assert "b1.exr: answers request round 1, and the running dump " in err
    assert "d3.exr (next round 3) has taken that round in" in err
    assert main(["merge", dumps[0], str(folder / "b1.exr"), "-o", str(tmp_path / "next.exr"), "-q"]) == 0
    assert capsys.readouterr().err == ""  # round 1 is d1.exr's next: no warning
    # A batch that copied its request's header names its loop's seed: another loop's is not this dump's round.
    other = tmp_path / "other.exr"
    batch = read_sample_dump(folder / "b1.exr")
    write_sample_buffer(other, batch.buffer, header={**batch.attributes, "awr:seed": 9})
    assert main(["merge", dumps[-1], str(other), "-o", str(tmp_path / "loops.exr"), "-q"]) == 0
    assert "count twice" not in capsys.readouterr().err
    write_sample_buffer(tmp_path / "same.exr", batch.buffer, header={**batch.attributes, "awr:seed": 7})
    assert main(["merge", dumps[-1], str(tmp_path / "same.exr"), "-o", str(tmp_path / "again7.exr"), "-q"]) == 0
    assert "count twice" in capsys.readouterr().err


def test_plan_says_when_its_file_records_no_round_or_seed(tmp_path, capsys):
    """A batch written without the request it answers (its attributes only recommended) reads as a dump of a run
    of its own: planned from, with a note that says so and names the merge a batch needs; a running dump, or
    --round and --seed given, plan without it."""
    dumps = _file_loop(tmp_path / "run", 7, 1)
    plain = tmp_path / "plain.exr"
    write_sample_buffer(plain, read_sample_dump(tmp_path / "run" / "b1.exr").buffer)  # its header left behind
    assert main(["plan", str(plain), "-o", str(tmp_path / "x.exr")]) == 0
    err = capsys.readouterr().err
    assert "plain.exr records no awr:round or awr:seed: planned as a run of its own" in err
    assert "awr merge DUMP.exr BATCH.exr --request REQUEST.exr" in err
    assert main(["plan", str(plain), "--round", "2", "-o", str(tmp_path / "y.exr")]) == 0
    assert "records no awr:seed:" in capsys.readouterr().err
    assert main(["plan", str(plain), "--round", "2", "--seed", "7", "-o", str(tmp_path / "z.exr")]) == 0
    assert "records no" not in capsys.readouterr().err
    assert main(["plan", dumps[-1], "-o", str(tmp_path / "w.exr")]) == 0
    assert "records no" not in capsys.readouterr().err


def test_merge_with_the_batch_before_the_dump_says_how_the_inputs_go(tmp_path, capsys):
    """The batch given first and the dump last (a new user's slip): the request's refusal alone ("does not start
    where the samples so far stop") did not say what to do; it now names the order."""
    run = _file_loop(tmp_path / "run", 3, 1)
    folder = tmp_path / "run"
    assert main(["merge", str(folder / "b1.exr"), run[0], "--request", str(folder / "r1.exr"),
                 "-o", str(tmp_path / "x.exr")]) == 2
    _one_error_line(capsys, "r1.exr: request: round 1 does not start where the samples so far stop",
                    "give the running dump it was planned from first (none for round 0) and the one batch that "
                    "answers it last")
    assert not (tmp_path / "x.exr").exists()


def test_a_merge_of_two_seeds_loops_refuses_a_newer_dump_of_either(tmp_path, capsys):
    """Two machines' loops (two seeds) merged plainly kept the first one's ``awr:seed`` and stayed a running dump:
    merged again with the second machine's newer dump, which holds the same first samples, it counted them twice,
    exit 0, while the first machine's was refused (a red-team pass). The merge now records both seeds in
    ``awr:seeds`` and refuses a newer dump of either, in either order; a third seed's loop merges."""
    a, b, c = (_file_loop(tmp_path / name, seed, 1) for name, seed in (("a", 0), ("b", 1), ("c", 2)))
    ab = str(tmp_path / "ab.exr")
    assert main(["merge", a[0], b[0], "-o", ab]) == 0
    assert "the loops of seeds 0, 1" in capsys.readouterr().err  # said, not silently dropped
    merged = read_sample_dump(ab)
    assert merged.attributes["awr:seeds"] == "0 1" and "awr:seed" not in merged.attributes
    assert merged.attributes["awr:running"] == 0
    for newer, seed in ((a[1], 0), (b[1], 1)):
        for pair in ((ab, newer), (newer, ab)):
            assert main(["merge", *pair, "-o", str(tmp_path / "x.exr"), "-q"]) == 2
            _one_error_line(capsys, f"both hold the first samples of the sample sequences of awr:seed {seed} at")
    assert not (tmp_path / "x.exr").exists()
    assert main(["merge", ab, c[1], "-o", str(tmp_path / "abc.exr"), "-q"]) == 0
    assert read_sample_dump(tmp_path / "abc.exr").attributes["awr:seeds"] == "0 1 2"
    assert main(["merge", str(tmp_path / "abc.exr"), b[1], "-o", str(tmp_path / "x.exr"), "-q"]) == 2
    _one_error_line(capsys, "of awr:seed 1 at")
    # Planned and told from the merge, the loop goes on with a seed it records among the others.
    assert main(["plan", ab, "-o", str(tmp_path / "r.exr"), "-q"]) == 0
    assert _external().main([str(tmp_path / "r.exr"), str(tmp_path / "rb.exr")]) == 0
    assert main(["merge", ab, str(tmp_path / "rb.exr"), "--request", str(tmp_path / "r.exr"), "-o",
                 str(tmp_path / "told.exr"), "-q"]) == 0
    told = read_sample_dump(tmp_path / "told.exr").attributes
    assert told["awr:seeds"] == "0 1" and told["awr:seed"] == 0 and told["awr:running"] == 0
    assert main(["merge", str(tmp_path / "told.exr"), b[1], "-o", str(tmp_path / "x.exr"), "-q"]) == 2
    _one_error_line(capsys, "of awr:seed 1 at")
    # With a seed of its own, the loop's samples are a third sequence the merge holds from then on.
    assert main(["plan", ab, "--seed", "5", "-o", str(tmp_path / "r5.exr"), "-q"]) == 0
    assert _external().main([str(tmp_path / "r5.exr"), str(tmp_path / "rb5.exr")]) == 0
    assert main(["merge", ab, str(tmp_path / "rb5.exr"), "--request", str(tmp_path / "r5.exr"), "-o",
                 str(tmp_path / "told5.exr"), "-q"]) == 0
    assert read_sample_dump(tmp_path / "told5.exr").attributes["awr:seeds"] == "0 1 5"
    # Two merges of the same two loops share both sequences.
    assert main(["merge", a[1], b[1], "-o", str(tmp_path / "ab1.exr"), "-q"]) == 0
    assert main(["merge", ab, str(tmp_path / "ab1.exr"), "-o", str(tmp_path / "x.exr"), "-q"]) == 2
    _one_error_line(capsys, "both hold the first samples of the sample sequences of awr:seed 0, 1 at")
    for bad, needle in (("", "not a list of 1 to"), ("0 x", "not a whole number"), ("-1", "outside 0..")):
        write_sample_buffer(tmp_path / "bad.exr", merged.buffer, header={**merged.attributes, "awr:seeds": bad},
                            overwrite=True)
        assert main(["merge", str(tmp_path / "bad.exr"), c[0], "-o", str(tmp_path / "x.exr"), "-q"]) == 2
        _one_error_line(capsys, "bad.exr", "awr:seeds", needle)
    assert not (tmp_path / "x.exr").exists()


def test_a_loop_merged_with_other_samples_keeps_its_seed_for_the_duplicate_check(tmp_path, capsys, rng):
    """A plain merge of one loop's dump with samples of no loop (another renderer's, a batch merged by mistake) was
    marked as no running dump and recorded no seeds: merged again with the loop's newer dump, which holds the same
    first samples, it counted them twice, exit 0, in either order of the first merge (a review). It records the
    loop's seed now, whichever input the loop was, and its settings go with the loop's too."""
    a = _file_loop(tmp_path / "a", 3, 1, "--round-growth", "0.5")
    other = str(tmp_path / "other.exr")
    _dump(other, rng)  # statistics of no loop: no seed, no run settings
    for k, pair in enumerate(((a[0], other), (other, a[0]))):
        mixed = str(tmp_path / f"mixed{k}.exr")
        assert main(["merge", *pair, "-o", mixed, "-q"]) == 0
        attributes = read_sample_dump(mixed).attributes
        assert attributes["awr:seeds"] == "3" and attributes["awr:seed"] == 3 and attributes["awr:running"] == 0
        assert attributes["awr:round_growth"] == "0.5"  # the loop's settings, not the first input's (none)
        for later in ((mixed, a[1]), (a[1], mixed)):
            assert main(["merge", *later, "-o", str(tmp_path / "x.exr"), "-q"]) == 2
            _one_error_line(capsys, "running dumps of one sample sequence (awr:seed 3)")
    assert not (tmp_path / "x.exr").exists()
    # Such a merge beside another loop: the same settings and seeds in either order.
    u = _file_loop(tmp_path / "u", 4, 0, "--strategy", "uniform", "--round-growth", "1")
    outputs = []
    for k, pair in enumerate(((str(tmp_path / "mixed0.exr"), u[0]), (u[0], str(tmp_path / "mixed0.exr")))):
        outputs.append(tmp_path / f"m{k}.exr")
        assert main(["merge", *pair, "-o", str(outputs[-1]), "-q"]) == 0
    first, second = ({k: v for k, v in read_sample_dump(path).attributes.items() if k != "awr:version"}
                     for path in outputs)
    assert first == second and first["awr:seeds"] == "3 4" and "awr:round_growth" not in first
    # Told from such a merge, the loop's samples are still beside others: no running dump, the seed recorded.
    mixed = str(tmp_path / "mixed0.exr")
    assert main(["plan", mixed, "-o", str(tmp_path / "r.exr"), "-q"]) == 0
    assert _external().main([str(tmp_path / "r.exr"), str(tmp_path / "b.exr")]) == 0
    assert main(["merge", mixed, str(tmp_path / "b.exr"), "--request", str(tmp_path / "r.exr"), "-o",
                 str(tmp_path / "told.exr"), "-q"]) == 0
    told = read_sample_dump(tmp_path / "told.exr").attributes
    assert told["awr:running"] == 0 and told["awr:seeds"] == "3" and told["awr:seed"] == 3
    # A loop's setting that does not fit is refused wherever the loop stands among the inputs.
    loop = read_sample_dump(a[0])
    write_sample_buffer(tmp_path / "bad.exr", loop.buffer, header={**loop.attributes, "awr:noise_model": "evil"})
    for pair in ((other, str(tmp_path / "bad.exr")), (u[0], str(tmp_path / "bad.exr"))):
        assert main(["merge", *pair, "-o", str(tmp_path / "x.exr"), "-q"]) == 2
        _one_error_line(capsys, "bad.exr", "awr:noise_model")
    assert not (tmp_path / "x.exr").exists()


def test_a_plain_merge_of_loops_carries_the_same_settings_in_any_order(tmp_path, capsys):
    """Settings were compared only when both inputs carried ``awr:strategy``: after one merge had dropped a strategy
    that disagreed, the next took every setting and the seed of whichever input came first, and the two orders
    planned different rounds (a red-team pass)."""
    a = _file_loop(tmp_path / "a", 1, 0, "--round-growth", "0.5")
    u = _file_loop(tmp_path / "u", 2, 0, "--strategy", "uniform", "--round-growth", "0.5")
    v = _file_loop(tmp_path / "v", 3, 0, "--strategy", "variance", "--round-growth", "1")
    au = str(tmp_path / "au.exr")
    assert main(["merge", a[0], u[0], "-o", au, "-q"]) == 0
    outputs = []
    for k, pair in enumerate(((au, v[0]), (v[0], au))):
        outputs.append(tmp_path / f"m{k}.exr")
        assert main(["merge", *pair, "-o", str(outputs[-1])]) == 0
        assert "awr:strategy of " in capsys.readouterr().err
    first, second = ({k: v for k, v in read_sample_dump(path).attributes.items() if k != "awr:version"}
                     for path in outputs)
    assert first == second and first["awr:seeds"] == "1 2 3"
    assert "awr:strategy" not in first and "awr:round_growth" not in first
    plans = []
    for k, path in enumerate(outputs):
        assert main(["plan", str(path), "-o", str(tmp_path / f"p{k}.exr"), "-q"]) == 0
        plans.append(read_request(tmp_path / f"p{k}.exr").counts)
    np.testing.assert_array_equal(*plans)


def test_merge_request_does_not_check_the_dump_s_settings_the_request_replaces(tmp_path, capsys):
    """plan takes an option in place of a dump's setting that does not fit (a newer version's name), and merge
    then refused that dump for the setting after the renderer had run, though the request's replaces it in the
    output: a loop stuck (a red-team pass). A setting the request does not replace is still refused."""
    d = _file_loop(tmp_path / "a", 0, 0)[0]
    dump = read_sample_dump(d)
    ext = _external()
    for header, given in (({"awr:noise_model": "Levels"}, ["--noise-model", "levels"]),
                          ({"awr:rare_paths": "Even"}, ["--strategy", "uniform"])):
        write_sample_buffer(tmp_path / "odd.exr", dump.buffer, header={**dump.attributes, **header}, overwrite=True)
        assert main(["plan", str(tmp_path / "odd.exr"), *given, "-o", str(tmp_path / "r.exr"), "-q",
                     "--overwrite"]) == 0
        assert ext.main([str(tmp_path / "r.exr"), str(tmp_path / "b.exr")]) == 0
        assert main(["merge", str(tmp_path / "odd.exr"), str(tmp_path / "b.exr"), "--request", str(tmp_path / "r.exr"),
                     "-o", str(tmp_path / "m.exr"), "-q", "--overwrite"]) == 0, capsys.readouterr().err
        out = read_sample_dump(tmp_path / "m.exr").attributes
        key = next(iter(header))
        assert out.get(key) == request_attributes(tmp_path / "r.exr").get(key)  # the request's, or none
        assert main(["plan", str(tmp_path / "m.exr"), "-o", str(tmp_path / "r2.exr"), "-q", "--overwrite"]) == 0
    # A request from an older version records no sampler settings: the dump's stay, and are checked.
    request = read_request(tmp_path / "r.exr")
    old = {k: v for k, v in request_attributes(tmp_path / "r.exr").items() if k == "awr:seed" or k == "awr:round"}
    write_sample_buffer(tmp_path / "bad.exr", dump.buffer, header={**dump.attributes, "awr:noise_model": "Levels"},
                        overwrite=True)
    write_request(tmp_path / "old.exr", request, header=old)
    assert ext.main([str(tmp_path / "old.exr"), str(tmp_path / "b.exr")]) == 0
    assert main(["merge", str(tmp_path / "bad.exr"), str(tmp_path / "b.exr"), "--request", str(tmp_path / "old.exr"),
                 "-o", str(tmp_path / "x.exr"), "-q"]) == 2
    _one_error_line(capsys, "bad.exr", "awr:noise_model")
    assert not (tmp_path / "x.exr").exists()


def test_renders_old_dumps_and_merged_running_dumps_of_one_seed_are_running_dumps(tmp_path, capsys):
    """Marking only ``merge --request``'s outputs as running dumps let three copies through again (a
    review): two ``awr render`` dumps of one seed, a dump written before the mark (no ``awr:running``:
    judged by its round), and a plain merge of running dumps (it carries the mark). A plain merge of
    batches is marked 0, and names the request of tiles that all name the same one."""
    render = ["render", "--renderer", "synthetic", "--scene", "edges", "--width", "16", "--height", "12",
              "--seed", "7", "-q"]
    assert main([*render, "--spp", "4", "-o", str(tmp_path / "a.exr")]) == 0
    assert main([*render, "--spp", "8", "-o", str(tmp_path / "b.exr")]) == 0
    assert read_sample_dump(tmp_path / "b.exr").attributes["awr:running"] == 1
    assert main(["merge", str(tmp_path / "a.exr"), str(tmp_path / "b.exr"), "-o", str(tmp_path / "ab.exr"), "-q"]) == 2
    _one_error_line(capsys, "running dumps of one sample sequence (awr:seed 7)")
    dump = read_sample_dump(tmp_path / "a.exr")
    old = {k: v for k, v in dump.attributes.items() if k != "awr:running"}  # as an older version wrote it
    write_sample_buffer(tmp_path / "old.exr", dump.buffer, header=old)
    assert main(["merge", str(tmp_path / "old.exr"), str(tmp_path / "b.exr"), "-o", str(tmp_path / "ob.exr"),
                 "-q"]) == 2
    _one_error_line(capsys, "running dumps of one sample sequence")
    render[render.index("7")] = "8"
    assert main([*render, "--spp", "4", "-o", str(tmp_path / "c.exr")]) == 0
    assert main(["merge", str(tmp_path / "a.exr"), str(tmp_path / "c.exr"), "-o", str(tmp_path / "ac.exr"), "-q"]) == 0
    merged = read_sample_dump(tmp_path / "ac.exr").attributes  # two seeds' loops: no one seed's sequence
    assert merged["awr:running"] == 0 and merged["awr:seeds"] == "7 8" and "awr:seed" not in merged
    assert main(["merge", str(tmp_path / "ac.exr"), str(tmp_path / "b.exr"), "-o", str(tmp_path / "acb.exr"),
                 "-q"]) == 2
    # Tiles of one batch naming their request: their plain merge is not a running dump, and names it.
    request = SampleRequest.uniform((12, 16), 2, first_index=8, round=3)
    for name, rows in (("tA", slice(0, 6)), ("tB", slice(6, 12))):
        counts = np.zeros((12, 16), int)
        counts[rows] = 2
        rows_, cols, _ = SampleRequest(counts, request.first_index).pixel_list()
        tile = SampleBuffer.from_samples(np.stack([rows_, cols], 1), np.ones((rows_.size, 3)), (12, 16))
        write_sample_buffer(tmp_path / f"{name}.exr", tile,
                            header={"awr:request_round": 3, "awr:request_total": request.total})
    assert main(["merge", str(tmp_path / "tA.exr"), str(tmp_path / "tB.exr"), "-o", str(tmp_path / "t.exr"),
                 "-q"]) == 0
    merged = read_sample_dump(tmp_path / "t.exr").attributes
    assert merged["awr:running"] == 0 and merged["awr:request_round"] == 3
    assert merged["awr:request_total"] == request.total


def test_a_stale_batch_that_copied_its_requests_header_is_refused(tmp_path, capsys):
    """A renderer that copies its request's header into the batch (``awr:semantics = sample-request``,
    ``awr:round``, ``awr:total``) names the request it answers: told again with the next round's
    request it merged its samples twice, exit 0 (a review of the ``awr:request_round`` check)."""
    ext = _external()
    header = lambda path: {k: str(v) for k, v in read_header(path).items() if str(k).startswith("awr:")}  # noqa: E731
    assert main(["plan", "--size", f"{W}x{H}", "--strategy", "uniform", "-o", str(tmp_path / "r0.exr"), "-q"]) == 0
    dump = None
    for k in range(3):
        request_path = tmp_path / f"r{k}.exr"
        if k:
            assert main(["plan", str(dump), "--round-spp", "2", "-o", str(request_path), "-q"]) == 0
        request = read_request(request_path)
        pixel, values = ext.render_samples(request.counts, request.first_index, 0)
        ext.write_batch(str(tmp_path / f"b{k}.exr"), request.counts, pixel, values, header(request_path))
        if k < 2:
            inputs = [str(tmp_path / f"b{k}.exr")] if dump is None else [str(dump), str(tmp_path / f"b{k}.exr")]
            assert main(["merge", *inputs, "--request", str(request_path), "-o", str(tmp_path / f"d{k + 1}.exr"),
                         "-q"]) == 0
            dump = tmp_path / f"d{k + 1}.exr"
    assert main(["merge", str(dump), str(tmp_path / "b1.exr"), "--request", str(tmp_path / "r2.exr"), "-o",
                 str(tmp_path / "stale.exr"), "-q"]) == 2
    _one_error_line(capsys, "b1.exr: awr:round: it answers a request of round 1, not")
    assert main(["info", str(tmp_path / "b1.exr"), "--json"]) == 0  # samples, not a request ("counts: missing")
    assert json.loads(capsys.readouterr().out)["kind"] != "request"


def test_a_request_of_another_seed_is_refused_by_plan_and_merge(tmp_path, capsys):
    """A dump's samples continue one random sequence: a request planned for another seed is refused."""
    ext = _external()
    assert main(["plan", "--size", f"{W}x{H}", "--seed", "5", "-o", str(tmp_path / "req0.exr"), "-q"]) == 0
    assert ext.main([str(tmp_path / "req0.exr"), str(tmp_path / "batch0.exr")]) == 0
    dump = tmp_path / "dump1.exr"
    assert main(["merge", str(tmp_path / "batch0.exr"), "--request", str(tmp_path / "req0.exr"), "-o", str(dump),
                 "-q"]) == 0
    assert main(["plan", str(dump), "--seed", "6", "-o", str(tmp_path / "req1.exr"), "-q"]) == 2
    _one_error_line(capsys, "--seed: 6 differs from awr:seed 5 of", "dump1.exr")
    assert not (tmp_path / "req1.exr").exists()
    assert main(["plan", str(dump), "--seed", "5", "-o", str(tmp_path / "req1.exr"), "-q"]) == 0  # the same: fine
    # Another dump's request (seed 6, same size and round): merge refuses it, naming both files.
    other = tmp_path / "other"
    other.mkdir()
    assert main(["plan", "--size", f"{W}x{H}", "--seed", "6", "-o", str(other / "req0.exr"), "-q"]) == 0
    assert ext.main([str(other / "req0.exr"), str(other / "batch0.exr")]) == 0
    assert main(["merge", str(other / "batch0.exr"), "--request", str(other / "req0.exr"), "-o",
                 str(other / "dump1.exr"), "-q"]) == 0
    assert main(["plan", str(other / "dump1.exr"), "-o", str(other / "req1.exr"), "-q"]) == 0
    assert ext.main([str(other / "req1.exr"), str(other / "batch1.exr")]) == 0
    out = tmp_path / "dump2.exr"
    assert main(["merge", str(dump), str(other / "batch1.exr"), "--request", str(other / "req1.exr"), "-o",
                 str(out), "-q"]) == 2
    _one_error_line(capsys, "req1.exr: awr:seed 6 does not match awr:seed 5 of", "dump1.exr")
    assert not out.exists()


def test_merge_records_dropped_samples_as_issued(tmp_path, capsys):
    ext = _external()
    req = SampleRequest.uniform((H, W), 4)
    from awr_denoise.io import write_request

    write_request(tmp_path / "r.exr", req)
    counts = req.counts.copy()
    counts[0, 0] = 3  # the renderer dropped one NaN sample here
    pixel, values = ext.render_samples(counts, req.first_index, 0)
    ext.write_batch(str(tmp_path / "b.exr"), counts, pixel, values)
    assert main(["merge", str(tmp_path / "b.exr"), "--request", str(tmp_path / "r.exr"), "-o",
                 str(tmp_path / "d.exr"), "-q"]) == 0
    d = read_sample_dump(tmp_path / "d.exr")
    assert d.buffer.count[0, 0] == 3 and d.issued[0, 0] == 4
    # A batch with more samples than requested is refused.
    counts[0, 0] = 5
    pixel, values = ext.render_samples(counts, req.first_index, 0)
    ext.write_batch(str(tmp_path / "b2.exr"), counts, pixel, values)
    assert main(["merge", str(tmp_path / "b2.exr"), "--request", str(tmp_path / "r.exr"), "-o",
                 str(tmp_path / "d2.exr"), "-q"]) == 2
    _one_error_line(capsys, "b2.exr", "sampleCount", "more samples")


def test_a_deep_batch_whose_indices_are_not_the_requests_is_refused(tmp_path, capsys):
    """A deep batch records each sample's index (``sampleIndex``), but ``merge --request`` never read
    it: a renderer that ignored ``first_index`` (indices from 0 again: the dump's own samples a
    second time) or a deep batch of another round was merged, exit 0 (a red-team pass)."""
    from awr_denoise.io import write_deep_samples, write_request

    rng = np.random.default_rng(0)
    write_request(tmp_path / "r0.exr", SampleRequest.uniform((H, W), 4))
    write_deep_samples(tmp_path / "b0.exr", np.repeat(np.arange(H * W), 4), rng.random((4 * H * W, 3)), (H, W),
                       sample_index=np.tile([0, 1, 2, 3], H * W))
    assert main(["merge", str(tmp_path / "b0.exr"), "--request", str(tmp_path / "r0.exr"), "-o",
                 str(tmp_path / "d0.exr"), "-q"]) == 0
    write_request(tmp_path / "r.exr", SampleRequest.uniform((H, W), 2, first_index=4, round=1))
    pixel = np.repeat(np.arange(H * W), 2)
    values = rng.random((pixel.size, 3))
    for name, index in (("ok", np.tile([4, 5], H * W)), ("zero", np.tile([0, 1], H * W)),
                        ("late", np.tile([5, 6], H * W)), ("twice", np.tile([4, 4], H * W))):
        write_deep_samples(tmp_path / f"{name}.exr", pixel, values, (H, W), sample_index=index)
    assert main(["merge", str(tmp_path / "d0.exr"), str(tmp_path / "ok.exr"), "--request", str(tmp_path / "r.exr"),
                 "-o", str(tmp_path / "d.exr"), "-q"]) == 0
    assert read_sample_dump(tmp_path / "d.exr").buffer.total_samples == 6 * H * W
    # Read alone, a deep file may hold an index twice (two seeds' samples in one file): only a batch may not.
    assert read_sample_dump(tmp_path / "twice.exr").buffer.total_samples == 2 * H * W
    for name, why in (("zero", r"0\.\.1, issued 4\.\.5\): another round's batch, or a renderer that ignored "
                               r"first_index"),
                      ("late", r"5\.\.6, issued 4\.\.5\)"), ("twice", r"repeat an index of their pixel .*index 4\)")):
        assert main(["merge", str(tmp_path / "d0.exr"), str(tmp_path / f"{name}.exr"), "--request",
                     str(tmp_path / "r.exr"), "-o", str(tmp_path / f"{name}_d.exr"), "-q"]) == 2
        assert not (tmp_path / f"{name}_d.exr").exists()
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"awr: error: {tmp_path / name}.exr: sampleIndex: ") and "\n" not in err, err
        assert __import__("re").search(why, err), err


# ---------------------------------------------------------------- end to end through processes

def _awr(*args, cwd):
    return subprocess.run([sys.executable, "-m", "awr_denoise.cli.main", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=120)


def test_subprocess_loop_and_error(tmp_path):
    script = str(DATA / "external_renderer.py")
    r = _awr("plan", "--size", "16x12", "-o", "req.exr", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([sys.executable, script, "req.exr", "batch.exr"], cwd=tmp_path, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert _awr("merge", "batch.exr", "--request", "req.exr", "-o", "dump.exr", "-q", cwd=tmp_path).returncode == 0
    r = _awr("denoise", "dump.exr", "-o", "out.exr", "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    (tmp_path / "bad.exr").write_bytes(b"not an exr")
    r = _awr("denoise", "bad.exr", "-o", "x.exr", cwd=tmp_path)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["awr: error: bad.exr: not an OpenEXR file (bad magic number)"]
    assert not (tmp_path / "x.exr").exists()


# ---------------------------------------------------------------- render and demo (tracer stand-in)

@pytest.fixture
def fake_tracer(monkeypatch):
    """The tracer's interface backed by the synthetic renderer, so the CLI is tested without embreex."""
    import types

    import awr_denoise
    from awr_denoise.synthetic import SyntheticRenderer, make_scene

    tracer = types.ModuleType("awr_denoise.tracer")
    monkeypatch.setitem(sys.modules, "awr_denoise.tracer", tracer)
    monkeypatch.setattr(awr_denoise, "tracer", tracer, raising=False)

    class Scene:
        def __init__(self, width, height):
            self.shape = (height or H, width or W)

    class PathTracer:
        def __init__(self, scene, seed=0, sampler="independent", progress=False):
            self._renderer = SyntheticRenderer(make_scene("edges", scene.shape), seed=seed)

        @property
        def shape(self):
            return self._renderer.shape

        def __call__(self, request):
            return self._renderer(request)

    monkeypatch.setattr(tracer, "list_scenes", lambda: ["toy"], raising=False)
    monkeypatch.setattr(tracer, "load_scene", lambda name, width=None, height=None: Scene(width, height),
                        raising=False)
    monkeypatch.setattr(tracer, "PathTracer", PathTracer, raising=False)
    monkeypatch.setattr(tracer, "create_renderer",
                        lambda scene, shape=None, seed=0, **options: PathTracer(scene, seed=seed, **options),
                        raising=False)
    monkeypatch.setattr(tracer, "load_reference", lambda name: make_scene("edges", (H, W)).reference(), raising=False)
    monkeypatch.setattr(tracer, "DEFAULT_SCENE", "toy", raising=False)
    monkeypatch.setattr(tracer, "SAMPLER_NAMES", ("independent", "sobol"), raising=False)
    return tracer


@pytest.mark.parametrize("mode", ["--adaptive", "--uniform"])
def test_render_writes_dump_image_preview(tmp_path, fake_tracer, mode):
    out = tmp_path / "toy.exr"
    assert main(["render", "--scene", "toy", "--spp", "8", mode, "--seed", "3", "-o", str(out), "-q"]) == 0
    dump = read_sample_dump(out)
    assert dump.buffer.total_samples == 8 * H * W
    assert dump.attributes["awr:strategy"] == ("awr" if mode == "--adaptive" else "uniform")
    assert dump.attributes["awr:seed"] == 3
    assert read_image(tmp_path / "toy.denoised.exr").shape == (H, W, 3)
    assert (tmp_path / "toy.denoised.png").read_bytes()[:4] == b"\x89PNG"
    if mode == "--uniform":
        assert (dump.buffer.count == 8).all()


def test_render_names_an_unknown_sampler_as_its_option(tmp_path, fake_tracer, capsys):
    """The tracer's refusal named its parameter, "sampler:", not ``--sampler`` (an attack pass)."""
    assert main(["render", "--spp", "4", "--sampler", "bogus", "-o", str(tmp_path / "toy.exr"), "-q"]) == 2
    _one_error_line(capsys, "--sampler: 'bogus' is not one of independent, sobol")
    assert not os.listdir(tmp_path)


def test_render_refuses_existing_outputs_before_rendering(tmp_path, fake_tracer, capsys):
    (tmp_path / "toy.denoised.png").write_bytes(b"keep")
    assert main(["render", "--spp", "4", "-o", str(tmp_path / "toy.exr"), "-q"]) == 2
    _one_error_line(capsys, "toy.denoised.png", "already exists")
    assert sorted(os.listdir(tmp_path)) == ["toy.denoised.png"]
    assert main(["render", "--scene", "nope", "--spp", "4", "-o", str(tmp_path / "t.exr"), "-q"]) == 2
    _one_error_line(capsys, "nope")
    # A renderer without a scene file to keep the other side from: both sides or none, named
    for side, other in (("--width", "--height"), ("--height", "--width")):
        assert main(["render", "--renderer", "synthetic", "edges", side, "8", "-o", str(tmp_path / "s.exr"),
                     "-q"]) == 2
        _one_error_line(capsys, f"{other}: --renderer synthetic needs both")
    # ... and a synthetic scene, which has no size of its own, the two options, not the library's parameter
    for parallel in ([], ["--executor", "threads", "--workers", "2"]):
        assert main(["render", "--renderer", "synthetic", "edges", "-o", str(tmp_path / "s.exr"), "-q",
                     *parallel]) == 2
        _one_error_line(capsys, "--width/--height: --renderer synthetic: a synthetic scene needs its (H, W)")
    # ... and a scene it does not have, by the options that name it (it said "name:", a red-team pass)
    assert main(["render", "--renderer", "synthetic", "nope", "--width", "8", "--height", "8", "-o",
                 str(tmp_path / "s.exr"), "-q"]) == 2
    _one_error_line(capsys, "SCENE/--scene: --renderer synthetic: 'nope' is not one of edges")
    # ... with workers too, where the spec refuses it ("scene:", the library's parameter)
    assert main(["render", "--renderer", "synthetic", "nope", "--width", "8", "--height", "8", "-o",
                 str(tmp_path / "s.exr"), "-q", "--executor", "threads", "--workers", "2"]) == 2
    _one_error_line(capsys, "SCENE/--scene: --renderer synthetic: 'nope' is neither a scene the synthetic renderer")
    # ... and the tracer's Sobol' sequence, which another renderer ignored while its header recorded it
    assert main(["render", "--renderer", "synthetic", "edges", "--width", "8", "--height", "8", "--sampler", "sobol",
                 "-o", str(tmp_path / "s.exr"), "-q"]) == 2
    _one_error_line(capsys, "--sampler sobol: the bundled tracer's sequence; --renderer synthetic draws independent")
    assert sorted(os.listdir(tmp_path)) == ["toy.denoised.png"]


def test_demo_prints_three_methods(tmp_path, fake_tracer, capsys):
    assert main(["demo", "--out", str(tmp_path / "out"), "--spp", "8", "-q", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert set(res["results"]) == {"uniform_mean", "uniform_awr", "adaptive_awr"}
    for r in res["results"].values():
        assert r["relmse"] > 0 and Path(r["file"]).exists() and 0 <= r["mean_error"] < 1
    assert res["results"]["uniform_awr"]["relmse"] < res["results"]["uniform_mean"]["relmse"]
    # Running it again replaces its own files.
    assert main(["demo", "--out", str(tmp_path / "out"), "--spp", "8", "-q"]) == 0
    assert "adaptive_awr" in capsys.readouterr().out


def test_demo_threads_reach_the_library_and_leave_the_images_the_same(tmp_path, fake_tracer, capsys, monkeypatch):
    """``--threads``, as in ``awr render``: a pool for the adaptive rounds' ranking and both reconstructions, and the
    same images bit for bit on one thread and on two."""
    from awr_denoise.cli import demo_cmd
    from awr_denoise.io import read_image

    seen = []
    real_reconstruct, real_render = demo_cmd.reconstruct, demo_cmd.render_buffer

    def reconstruct(*args, **kwargs):
        seen.append(("reconstruct", kwargs.get("executor")))
        return real_reconstruct(*args, **kwargs)

    def render_buffer(*args, **kwargs):
        seen.append(("render" + ("_adaptive" if kwargs["adaptive"] else ""), kwargs.get("executor")))
        return real_render(*args, **kwargs)

    monkeypatch.setattr(demo_cmd, "reconstruct", reconstruct)
    monkeypatch.setattr(demo_cmd, "render_buffer", render_buffer)
    images = {}
    for threads in (1, 2):
        seen.clear()
        out = tmp_path / f"t{threads}"
        assert main(["demo", "--out", str(out), "--spp", "8", "-q", "--threads", str(threads)]) == 0
        pools = {kind: pool for kind, pool in seen if kind != "render"}
        assert set(pools) == {"reconstruct", "render_adaptive"} and len(seen) == 4
        assert all((pool is None) == (threads == 1) for kind, pool in seen if kind != "render")
        images[threads] = {p.name: read_image(p) for p in sorted(out.glob("*.exr"))}
    assert len(images[1]) == 3 and images[1].keys() == images[2].keys()
    for name in images[1]:
        np.testing.assert_array_equal(images[1][name], images[2][name], err_msg=name)
    capsys.readouterr()
    assert main(["demo", "--out", str(tmp_path / "t0"), "--spp", "8", "-q", "--threads", "0"]) == 2
    assert "--threads" in capsys.readouterr().err and not (tmp_path / "t0").exists()


def test_demo_without_the_exr_extra_is_refused_before_the_reference_is_rendered(tmp_path, fake_tracer, capsys,
                                                                                monkeypatch):
    """An install without the extra rendered the reference (minutes), then failed to write its first image."""
    from awr_denoise import tracer
    from awr_denoise.io import exr

    def missing():
        raise ImportError("EXR support needs the 'exr' extra: pip install 'awr-denoise[exr]'")

    monkeypatch.setattr(exr, "_openexr", missing)
    monkeypatch.setattr(tracer, "load_reference", lambda name: pytest.fail("rendered"), raising=False)
    assert main(["demo", "--out", str(tmp_path / "out"), "--spp", "8", "-q"]) == 1
    _one_error_line(capsys, "EXR support needs the 'exr' extra: pip install 'awr-denoise[exr]'")
    assert not (tmp_path / "out").exists()


def test_a_missing_tracer_extra_is_named_once(tmp_path, capsys, monkeypatch):
    """The tracer's own message names the extra; the command added it again in brackets."""
    import awr_denoise

    monkeypatch.setitem(sys.modules, "embreex", None)
    monkeypatch.delitem(sys.modules, "awr_denoise.tracer", raising=False)
    monkeypatch.delattr(awr_denoise, "tracer", raising=False)
    monkeypatch.chdir(tmp_path)
    for args in (["render", "-o", "x.exr", "-q"], ["demo", "--out", "out", "-q"]):
        assert main(args) == 1
        line = _one_error_line(capsys, "the bundled tracer is not available", "awr-denoise[tracer]")
        assert line.count("pip install") == 1, line
    assert not list(tmp_path.iterdir())


def test_demo_refuses_before_creating_its_folder(tmp_path, fake_tracer, capsys, monkeypatch):
    """A reference of the wrong size is refused before the renders, and --out is not left behind; nor
    is a folder under one that cannot be written."""
    from awr_denoise import tracer

    monkeypatch.setattr(tracer, "load_reference", lambda name: np.zeros((3, 4, 3)), raising=False)
    # Named by its file, which a user can remove (it named the scene alone; a red-team pass).
    monkeypatch.setattr(tracer, "reference_path", lambda name: tmp_path / f"{name}_ref.exr", raising=False)
    assert main(["demo", "--out", str(tmp_path / "new" / "sub"), "--spp", "8", "-q"]) == 2
    _one_error_line(capsys, f"{tmp_path / 'toy_ref.exr'}: the reference of toy is 4x3, the scene 32x24",
                    "remove it to render it again")
    assert not (tmp_path / "new").exists()
    (tmp_path / "file").write_bytes(b"")
    assert main(["demo", "--out", str(tmp_path / "file" / "sub"), "--spp", "8", "-q"]) == 2
    _one_error_line(capsys, "--out", "cannot be created")


def test_demo_refuses_an_output_that_is_its_cached_reference(tmp_path, fake_tracer, capsys, monkeypatch):
    """``out/toy_uniform_mean.exr`` linked to the cached reference: the demo read the reference and wrote the
    8-spp mean over it, exit 0 (a red-team pass). It is an input of the command, refused as an output."""
    reference = tmp_path / "ref" / "toy.exr"
    reference.parent.mkdir()
    write_image(reference, np.full((H, W, 3), 0.5))
    kept = reference.read_bytes()
    monkeypatch.setattr(fake_tracer, "reference_path", lambda name: tmp_path / "ref" / f"{name}.exr", raising=False)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "toy_uniform_mean.exr").symlink_to(reference)
    assert main(["demo", "--out", str(tmp_path / "out"), "--spp", "8", "-q"]) == 2
    _one_error_line(capsys, "toy_uniform_mean.exr: --out is the input", "(the cached reference)")
    assert reference.read_bytes() == kept and os.listdir(tmp_path / "out") == ["toy_uniform_mean.exr"]


def test_demo_stopped_before_its_commit_removes_the_folders_it_made(tmp_path, fake_tracer, capsys, monkeypatch):
    """SIGTERM in the demo's last moments (after `--out NEW/sub` was made, before the images were
    committed) left the empty folders behind (a red-team pass)."""
    from awr_denoise.cli import demo_cmd, interrupts

    real = demo_cmd.write_preview

    def terminated(*args, **kwargs):
        real(*args, **kwargs)
        interrupts._received.append(signal.SIGTERM)  # as the handler does
        raise interrupts.Terminated("SIGTERM")

    monkeypatch.setattr(demo_cmd, "write_preview", terminated)
    (tmp_path / "kept").mkdir()
    for out in (tmp_path / "new" / "sub", tmp_path / "kept" / "sub"):
        assert main(["demo", "--out", str(out), "--spp", "8", "-q"]) == 143
        assert capsys.readouterr().err.strip() == "awr: terminated"
    assert sorted(os.listdir(tmp_path)) == ["kept"] and os.listdir(tmp_path / "kept") == []


def test_demo_checks_its_outputs_before_rendering(tmp_path, fake_tracer, capsys, monkeypatch):
    """--out and the images under it are checked like every output, before the two renders: a name
    that is not UTF-8 created an empty folder and named no option, a loop of links was "[Errno 17]"."""
    from awr_denoise.cli import demo_cmd

    def no_render(*args, **kwargs):
        raise AssertionError("rendered before the outputs were checked")

    monkeypatch.setattr(demo_cmd, "render_buffer", no_render)
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--out", os.fsdecode(b"bad\xffdir"), "--spp", "8", "-q"]) == 2
    _one_error_line(capsys, "--out", "not valid UTF-8")
    os.symlink("loop2", "loop1")
    os.symlink("loop1", "loop2")
    assert main(["demo", "--out", "loop1", "--spp", "8", "-q"]) == 2
    _one_error_line(capsys, "--out", "loop1", "is not a directory")
    os.symlink("nowhere", "dangling")
    for parent in ("loop1", "dangling"):  # under a link that is not a folder
        assert main(["demo", "--out", f"{parent}/sub", "--spp", "8", "-q"]) == 2
        _one_error_line(capsys, "--out", f"{parent}/sub", "cannot be created")
    assert sorted(os.listdir(tmp_path)) == ["dangling", "loop1", "loop2"]
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "toy_uniform_awr.exr").mkdir()  # an image's name taken by a folder
    assert main(["demo", "--out", "out", "--spp", "8", "-q"]) == 2
    _one_error_line(capsys, "--out", "toy_uniform_awr.exr")


# ---------------------------------------------------------------- presets through the command line

def _preset_file(tmp_path, preset):
    one = np.ones((H, W), np.float32)
    if preset == "pbrt":
        planes = {c: one * 0.5 for c in "RGB"} | {f"Variance.{c}": one * 0.1 for c in "RGB"} | {"N.X": one}
        return _write(tmp_path / "p.exr", planes, {"samplesPerPixel": 16}), [], 16
    if preset == "cycles":
        planes = {f"View Layer.Combined.{c}": one * 0.5 for c in "RGBA"}
        planes["View Layer.Debug Sample Count.X"] = one * np.float32(1 / 4)
        planes |= {f"View Layer.Var.{c}": one * 0.1 for c in "RGB"}
        return (_write(tmp_path / "c.exr", planes, {"cycles.View Layer.samples": "32"}),
                ["--variance", "View Layer.Var"], 8)
    if preset == "renderman":
        planes = {f"Ci.{c}": one * 0.5 for c in "rgb"} | {f"mse.{c}": one * 0.01 for c in "rgb"}
        return _write(tmp_path / "r.exr", planes | {"sampleCount": one * 12}), [], 12
    # A colour: X = Y = Z would be a mono render's luminance.
    planes = {f"img.{c}": one * t for c, t in zip("XYZ", _XYZ)} | {f"m2_img.{c}": one * 0.5 for c in "XYZ"}
    return _write(tmp_path / "m.exr", planes), ["--spp", "6"], 6


_XYZ = (0.475, 0.5, 0.545)


@pytest.mark.parametrize("preset", ["pbrt", "cycles", "renderman", "mitsuba"])
def test_presets_detected_and_denoised(tmp_path, capsys, preset):
    src, extra, spp = _preset_file(tmp_path, preset)
    capsys.readouterr()
    assert main(["info", str(src), "--json", *extra]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["preset"] == preset and info["spp"]["mean"] == spp
    assert main(["denoise", str(src), "-o", str(tmp_path / "o.exr"), "-q", *extra]) == 0
    # Mitsuba's moments are CIE XYZ: a flat XYZ is the sRGB colour M @ XYZ.
    expected = MITSUBA_XYZ_TO_SRGB @ np.array(_XYZ) if preset == "mitsuba" else 0.5
    np.testing.assert_allclose(read_image(tmp_path / "o.exr"), np.broadcast_to(expected, (H, W, 3)), rtol=1e-4)


def test_info_on_plain_image_and_request(tmp_path, capsys):
    write_image(tmp_path / "img.exr", np.zeros((2, 3, 3)))
    capsys.readouterr()
    assert main(["info", str(tmp_path / "img.exr"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["kind"] == "image"
    assert main(["plan", "--size", "3x2", "-o", str(tmp_path / "r.exr"), "-q"]) == 0
    assert main(["info", str(tmp_path / "r.exr"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "request" and info["total"] == DEFAULT_AWR_INITIAL_SPP * 6
    # A request where samples belong (arguments swapped) is named as one, not "cannot detect the layout".
    for args in (["denoise", str(tmp_path / "r.exr"), "-o", str(tmp_path / "o.exr")],
                 ["merge", str(tmp_path / "r.exr"), str(tmp_path / "r.exr"), "--allow-duplicates", "-o",
                  str(tmp_path / "o.exr")], ["plan", str(tmp_path / "r.exr"), "-o", str(tmp_path / "o.exr")]):
        assert main(args) == 2
        _one_error_line(capsys, "r.exr: is a request map (awr plan's output: the samples to render), not samples")


def test_info_shows_a_single_precision_attribute_as_written(tmp_path, capsys):
    """EXR holds a float attribute in single precision: 1.2 was shown as 1.2000000476837158, 0.1 as
    0.10000000149011612; each is shown as written."""
    write_image(tmp_path / "img.exr", np.zeros((2, 3, 3)), header={"awr:guard_tolerance": 1.2, "awr:c_s": 0.1})
    capsys.readouterr()
    assert main(["info", str(tmp_path / "img.exr")]) == 0
    out = capsys.readouterr().out
    assert "awr:guard_tolerance = 1.2\n" in out and "awr:c_s = 0.1\n" in out, out


@pytest.mark.parametrize(("options", "spp"), [([], 2), (["--strategy", "uniform"], 4), (["--strategy", "variance"], 4),
                                              (["--initial-spp", "3"], 3), (["--strategy", "variance", "--initial-spp", "1"], 1)])
def test_plan_first_round_takes_the_strategy_s_initial_spp(tmp_path, options, spp):
    """Without --initial-spp the first round is the strategy's own default: 2 for awr, 4 (the paper's) otherwise."""
    assert main(["plan", "--size", "5x4", *options, "-o", str(tmp_path / "r.exr"), "-q"]) == 0
    counts = read_request(tmp_path / "r.exr").counts
    assert counts.shape == (4, 5) and (counts == spp).all()


def test_plan_usage_errors(tmp_path, capsys, rng):
    assert main(["plan", "-o", str(tmp_path / "r.exr")]) == 2
    _one_error_line(capsys, "--size")
    assert main(["plan", "--size", "10by4", "-o", str(tmp_path / "r.exr")]) == 2
    _one_error_line(capsys, "--size")
    _dump(tmp_path / "d.exr", rng)
    assert main(["plan", str(tmp_path / "d.exr"), "--budget", "-3", "-o", str(tmp_path / "r.exr")]) == 2
    _one_error_line(capsys, "--budget")
    assert not (tmp_path / "r.exr").exists()


@pytest.mark.parametrize("growth", [0.25, 1.0])
def test_plan_round_growth_sets_the_round_budget(tmp_path, capsys, rng, growth):
    buf = _dump(tmp_path / "d.exr", rng)
    assert main(["plan", str(tmp_path / "d.exr"), "--round-growth", str(growth), "-o", str(tmp_path / "r.exr"),
                 "-q"]) == 0
    assert read_request(tmp_path / "r.exr").total == int(growth * buf.total_samples)
    assert main(["plan", str(tmp_path / "d.exr"), "--round-growth", "0", "-o", str(tmp_path / "s.exr")]) == 2
    _one_error_line(capsys, "--round-growth")
    assert not (tmp_path / "s.exr").exists()


def test_plan_noise_model_reaches_the_sampler(tmp_path, capsys, rng):
    _dump(tmp_path / "d.exr", rng)
    counts = {}
    for model in ("levels", "reconstruction", "shrinkage", None):
        out = tmp_path / f"{model}.exr"
        option = [] if model is None else ["--noise-model", model]
        assert main(["plan", str(tmp_path / "d.exr"), *option, "-o", str(out), "-q"]) == 0
        counts[model] = read_request(out).counts
    dump = read_sample_dump(tmp_path / "d.exr")
    for model in ("levels", "reconstruction", "shrinkage"):
        expected = AdaptiveSampler.from_buffer(dump.buffer, round=1, issued=dump.issued, noise_model=model)
        np.testing.assert_array_equal(counts[model], expected.ask().counts)
    np.testing.assert_array_equal(counts[None], counts["shrinkage"])  # the default
    assert not np.array_equal(counts["levels"], counts["reconstruction"])
    assert not np.array_equal(counts["levels"], counts["shrinkage"])
    assert main(["plan", str(tmp_path / "d.exr"), "--strategy", "uniform", "--noise-model", "reconstruction",
                 "-o", str(tmp_path / "u.exr")]) == 2
    _one_error_line(capsys, "--noise-model")
    for option, value in (("--wavelet", "haar"), ("--levels", "2")):  # accepted and ignored before
        assert main(["plan", str(tmp_path / "d.exr"), "--strategy", "variance", option, value,
                     "-o", str(tmp_path / "u.exr")]) == 2
        _one_error_line(capsys, option, "only --strategy awr analyses the image in wavelets")
    assert not (tmp_path / "u.exr").exists()


def _rendered(tmp_path, spp, option, value, extra=()):
    """The dump of ``awr render --spp SPP OPTION VALUE`` (the fake tracer), checked for its total."""
    out = tmp_path / f"{option}{value}.exr"
    assert main(["render", "--spp", str(spp), option, value, *extra, "-o", str(out), "-q"]) == 0
    dump = read_sample_dump(out)
    assert dump.buffer.total_samples == spp * H * W
    return dump


def test_render_noise_model_reaches_the_sampler(tmp_path, capsys, fake_tracer):
    counts = {model: _rendered(tmp_path, 8, "--noise-model", model).buffer.count
              for model in ("levels", "reconstruction", "shrinkage")}
    assert not np.array_equal(counts["levels"], counts["reconstruction"])
    assert not np.array_equal(counts["levels"], counts["shrinkage"])
    default = _rendered(tmp_path, 8, "--initial-spp", "2").buffer.count  # no --noise-model: the shrinkage
    np.testing.assert_array_equal(default, counts["shrinkage"])
    # The adaptive rounds' settings with a uniform render would do nothing: refused, nothing written.
    for option, value in (("--noise-model", "reconstruction"), ("--initial-spp", "2"), ("--round-growth", "0.25")):
        assert main(["render", "--uniform", option, value, "-o", str(tmp_path / "u.exr")]) == 2
        _one_error_line(capsys, option, "a uniform render has no adaptive rounds")
        assert not (tmp_path / "u.exr").exists()


def _rare_paths_choices(monkeypatch):
    """The ``rare_paths`` every sampler round is evened with (recorded on the way through)."""
    from awr_denoise import sampling

    seen = []
    real = sampling.rare_path_evening
    monkeypatch.setattr(sampling, "rare_path_evening",
                        lambda b, choice="even", executor=None: seen.append(choice) or real(b, choice, executor))
    return seen


def test_render_rare_paths_reaches_the_sampler(tmp_path, capsys, fake_tracer, monkeypatch):
    seen = _rare_paths_choices(monkeypatch)
    for choice in ("ranked", "zeros"):
        _rendered(tmp_path, 8, "--rare-paths", choice)
        assert seen and set(seen) == {choice}
        seen.clear()
    _rendered(tmp_path, 8, "--initial-spp", "2")  # the default
    assert seen and set(seen) == {"even"}
    assert main(["render", "--uniform", "--rare-paths", "ranked", "-o", str(tmp_path / "u.exr")]) == 2
    _one_error_line(capsys, "--rare-paths", "a uniform render has no adaptive rounds")
    assert not (tmp_path / "u.exr").exists()


def test_plan_rare_paths_reaches_the_ranking_samplers(tmp_path, capsys, rng, monkeypatch):
    _dump(tmp_path / "d.exr", rng)
    seen = _rare_paths_choices(monkeypatch)
    for strategy in ("awr", "variance"):
        for choice in ("ranked", "zeros", None):
            option = [] if choice is None else ["--rare-paths", choice]
            out = tmp_path / f"{strategy}{choice}.exr"
            assert main(["plan", str(tmp_path / "d.exr"), "--strategy", strategy, *option, "-o", str(out), "-q"]) == 0
            assert seen == [choice or "even"], (strategy, choice, seen)
            seen.clear()
    assert main(["plan", str(tmp_path / "d.exr"), "--strategy", "uniform", "--rare-paths", "even",
                 "-o", str(tmp_path / "u.exr")]) == 2
    _one_error_line(capsys, "--rare-paths", "only the strategies that rank pixels")
    assert not (tmp_path / "u.exr").exists()


def test_render_records_the_sampler_settings_plan_continues(tmp_path, capsys, fake_tracer, monkeypatch):
    """A render's sampler settings were not in its dump: a plan continuing it ranked with the defaults, whatever
    the render had ranked with, without a word."""
    seen = _rare_paths_choices(monkeypatch)
    dump = _rendered(tmp_path, 8, "--rare-paths", "zeros", extra=["--noise-model", "levels", "--round-growth", "0.3"])
    attrs = dump.attributes
    assert (attrs["awr:rare_paths"], attrs["awr:noise_model"], attrs["awr:round_growth"]) == ("zeros", "levels", "0.3")
    assert attrs["awr:priority_wavelet"] == "bior4.4" and "awr:priority_levels" not in attrs  # automatic: unsaid
    assert "awr:spp_max" not in attrs
    seen.clear()
    source = tmp_path / "--rare-pathszeros.exr"
    assert main(["plan", str(source), "-o", str(tmp_path / "carried.exr"), "-q"]) == 0
    assert seen == ["zeros"]
    asked = request_attributes(tmp_path / "carried.exr")
    assert (asked["awr:rare_paths"], asked["awr:noise_model"], asked["awr:round_growth"]) == ("zeros", "levels", "0.3")
    # The round's size is the render's growth: 30% of the samples so far, not the default 25%.
    assert read_request(tmp_path / "carried.exr").total == round(0.3 * dump.buffer.total_samples)
    seen.clear()
    capsys.readouterr()
    assert main(["plan", str(source), "--rare-paths", "even", "-o", str(tmp_path / "given.exr")]) == 0
    assert seen == ["even"] and request_attributes(tmp_path / "given.exr")["awr:rare_paths"] == "even"
    # The status line names what the run carries beyond the defaults, which its user may have forgotten giving;
    # not what an option gave, and nothing with -q.
    out = capsys.readouterr()
    assert f"; --round-growth 0.3, --noise-model levels (the run's, from {source})" in out.out + out.err
    assert main(["plan", str(source), "--rare-paths", "ranked", "--round-growth", "0.5", "-o",
                 str(tmp_path / "options.exr")]) == 0
    out = capsys.readouterr()
    line = out.out + out.err
    assert f"; --noise-model levels (the run's, from {source})" in line and "ranked" not in line and "0.5" not in line
    assert main(["plan", str(source), "-o", str(tmp_path / "quiet.exr"), "-q"]) == 0
    assert capsys.readouterr() == ("", "")
    uniform = tmp_path / "u.exr"
    assert main(["render", "--uniform", "--spp", "2", "-o", str(uniform), "-q"]) == 0
    assert not {"awr:rare_paths", "awr:noise_model", "awr:round_growth"} & set(read_sample_dump(uniform).attributes)


def test_a_run_through_files_keeps_its_sampler_settings(tmp_path, capsys, monkeypatch):
    """``--rare-paths`` and ``--noise-model`` given to one plan held for that round only: the next plan without
    them ranked with the defaults. The request records them, merge carries them into the dump, plan continues
    them; an option given overrides them, and another strategy starts from its own defaults."""
    ext = _external()
    seen = _rare_paths_choices(monkeypatch)

    def loop(dump, request, batch, out):
        assert ext.main([str(tmp_path / request), str(tmp_path / batch)]) == 0
        inputs = [str(tmp_path / batch)] if dump is None else [str(tmp_path / dump), str(tmp_path / batch)]
        assert main(["merge", *inputs, "--request", str(tmp_path / request), "-o", str(tmp_path / out), "-q"]) == 0
        return read_sample_dump(tmp_path / out).attributes

    assert main(["plan", "--size", f"{W}x{H}", "--seed", "3", "-o", str(tmp_path / "r0.exr"), "-q"]) == 0
    assert loop(None, "r0.exr", "b0.exr", "d1.exr")["awr:rare_paths"] == "even"  # the first round's: the defaults
    assert main(["plan", str(tmp_path / "d1.exr"), "--rare-paths", "zeros", "--noise-model", "levels", "--round-spp",
                 "2", "-o", str(tmp_path / "r1.exr"), "-q"]) == 0
    attrs = loop("d1.exr", "r1.exr", "b1.exr", "d2.exr")
    assert (attrs["awr:rare_paths"], attrs["awr:noise_model"], attrs["awr:strategy"]) == ("zeros", "levels", "awr")
    seen.clear()
    for name, given in (("carried", []), ("given", ["--rare-paths", "zeros", "--noise-model", "levels"]),
                        ("defaults", ["--rare-paths", "even", "--noise-model", "shrinkage"])):
        assert main(["plan", str(tmp_path / "d2.exr"), "--budget", "800", *given, "-o", str(tmp_path / f"{name}.exr"),
                     "-q"]) == 0
    assert seen == ["zeros", "zeros", "even"]
    counts = {name: read_request(tmp_path / f"{name}.exr").counts for name in ("carried", "given", "defaults")}
    assert np.array_equal(counts["carried"], counts["given"])
    assert not np.array_equal(counts["carried"], counts["defaults"])  # the levels rank otherwise
    # Another strategy takes the settings it uses too (each means the same in both), and the awr run's settings it
    # does not use are not carried on.
    seen.clear()
    assert main(["plan", str(tmp_path / "d2.exr"), "--strategy", "variance", "--round-spp", "2", "-o",
                 str(tmp_path / "r2.exr"), "-q"]) == 0
    assert seen == ["zeros"]
    attrs = loop("d2.exr", "r2.exr", "b2.exr", "d3.exr")
    assert attrs["awr:strategy"] == "variance" and attrs["awr:rare_paths"] == "zeros"
    assert "awr:noise_model" not in attrs and "awr:priority_wavelet" not in attrs
    # --round-growth holds from its round on, where --budget and --round-spp size one round.
    assert main(["plan", str(tmp_path / "d3.exr"), "--round-growth", "0.5", "-o", str(tmp_path / "r3.exr"),
                 "-q"]) == 0
    attrs = loop("d3.exr", "r3.exr", "b3.exr", "d4.exr")
    total = read_sample_dump(tmp_path / "d4.exr").buffer.total_samples
    assert attrs["awr:round_growth"] == "0.5"
    assert main(["plan", str(tmp_path / "d4.exr"), "-o", str(tmp_path / "r4.exr"), "-q"]) == 0
    assert read_request(tmp_path / "r4.exr").total == round(0.5 * total)


def test_the_first_round_records_the_run_s_settings_and_a_cap_or_depth_can_be_lifted(tmp_path, capsys):
    """The first plan is where a run is set up: its settings were refused there ("act from round 1") and had to be
    given again to every later plan. A cap or a depth a dump carries is lifted by --spp-max none, --levels auto."""
    ext = _external()
    assert main(["plan", "--size", f"{W}x{H}", "--rare-paths", "zeros", "--wavelet", "haar", "--levels", "2",
                 "--spp-max", "64", "-o", str(tmp_path / "r0.exr"), "-q"]) == 0
    assert ext.main([str(tmp_path / "r0.exr"), str(tmp_path / "b0.exr")]) == 0
    assert main(["merge", str(tmp_path / "b0.exr"), "--request", str(tmp_path / "r0.exr"), "-o",
                 str(tmp_path / "d1.exr"), "-q"]) == 0
    attrs = read_sample_dump(tmp_path / "d1.exr").attributes
    assert (attrs["awr:rare_paths"], attrs["awr:priority_wavelet"], attrs["awr:priority_levels"],
            attrs["awr:spp_max"]) == ("zeros", "haar", 2, 64)
    assert main(["plan", str(tmp_path / "d1.exr"), "-o", str(tmp_path / "kept.exr"), "-q"]) == 0
    assert request_attributes(tmp_path / "kept.exr")["awr:priority_levels"] == 2
    assert main(["plan", str(tmp_path / "d1.exr"), "--spp-max", "none", "--levels", "auto", "-o",
                 str(tmp_path / "lifted.exr"), "-q"]) == 0
    lifted = request_attributes(tmp_path / "lifted.exr")
    assert "awr:spp_max" not in lifted and "awr:priority_levels" not in lifted
    assert lifted["awr:priority_wavelet"] == "haar"
    assert not np.array_equal(read_request(tmp_path / "kept.exr").counts, read_request(tmp_path / "lifted.exr").counts)
    # Told with the lifting request, the dump drops them too: its sampler left them automatic.
    assert ext.main([str(tmp_path / "lifted.exr"), str(tmp_path / "b1.exr")]) == 0
    assert main(["merge", str(tmp_path / "d1.exr"), str(tmp_path / "b1.exr"), "--request",
                 str(tmp_path / "lifted.exr"), "-o", str(tmp_path / "d2.exr"), "-q"]) == 0
    attrs = read_sample_dump(tmp_path / "d2.exr").attributes
    assert "awr:spp_max" not in attrs and "awr:priority_levels" not in attrs and attrs["awr:rare_paths"] == "zeros"
    # A request that records no settings (an older plan's) leaves the dump's as they are.
    old = tmp_path / "old.exr"
    request = read_request(tmp_path / "kept.exr")
    write_request(old, request, header={k: v for k, v in request_attributes(tmp_path / "kept.exr").items()
                                        if k not in {key for _, key, _, _ in CARRIED} | {"awr:version"}})
    assert ext.main([str(old), str(tmp_path / "b2.exr")]) == 0
    assert main(["merge", str(tmp_path / "d1.exr"), str(tmp_path / "b2.exr"), "--request", str(old), "-o",
                 str(tmp_path / "d3.exr"), "-q"]) == 0
    assert read_sample_dump(tmp_path / "d3.exr").attributes["awr:priority_levels"] == 2


def test_a_bad_setting_in_a_request_is_refused_by_merge(tmp_path, capsys):
    ext = _external()
    assert main(["plan", "--size", f"{W}x{H}", "-o", str(tmp_path / "r0.exr"), "-q"]) == 0
    assert ext.main([str(tmp_path / "r0.exr"), str(tmp_path / "b0.exr")]) == 0
    request = read_request(tmp_path / "r0.exr")
    for key, value, needle in (("awr:rare_paths", "evil", "is not one of even"),
                               ("awr:round_growth", "0", "not a number above 0"),
                               ("awr:priority_levels", 9, "outside 1..4 for its image")):
        header = {**request_attributes(tmp_path / "r0.exr"), key: value}
        header.pop("awr:version")
        write_request(tmp_path / "bad.exr", request, header=header, overwrite=True)
        assert main(["merge", str(tmp_path / "b0.exr"), "--request", str(tmp_path / "bad.exr"), "-o",
                     str(tmp_path / "d1.exr"), "-q"]) == 2
        _one_error_line(capsys, "bad.exr", key, needle)
        assert not (tmp_path / "d1.exr").exists()


def test_a_plain_merge_carries_the_settings_its_running_dumps_agree_on(tmp_path, capsys, fake_tracer):
    """A plain merge of running dumps took the first input's settings, so the result depended on their order."""
    for name, seed, extra in (("a", 1, ["--rare-paths", "ranked"]), ("b", 2, ["--rare-paths", "zeros"]),
                              ("c", 3, ["--rare-paths", "zeros"])):
        assert main(["render", "--spp", "4", "--seed", str(seed), *extra, "-o", str(tmp_path / f"{name}.exr"),
                     "-q"]) == 0
    for order in (("b", "c"), ("c", "b")):
        out = tmp_path / f"{''.join(order)}.exr"
        assert main(["merge", *(str(tmp_path / f"{n}.exr") for n in order), "-o", str(out), "-q"]) == 0
        assert read_sample_dump(out).attributes["awr:rare_paths"] == "zeros"
    capsys.readouterr()
    for order in (("a", "b"), ("b", "a")):
        out = tmp_path / f"{''.join(order)}.exr"
        assert main(["merge", *(str(tmp_path / f"{n}.exr") for n in order), "-o", str(out)]) == 0
        attrs = read_sample_dump(out).attributes
        assert "awr:rare_paths" not in attrs and attrs["awr:noise_model"] == "shrinkage"  # the two agree there
        err = capsys.readouterr().err
        assert "awr:rare_paths of" in err and "not carried" in err
    # A setting one of them leaves out is a setting too: no cap beside a cap of 64 is not carried either way.
    assert main(["render", "--spp", "4", "--seed", "4", "--rare-paths", "zeros", "-o", str(tmp_path / "d.exr"),
                 "-q"]) == 0
    capped = tmp_path / "capped.exr"
    write_sample_buffer(capped, read_sample_dump(tmp_path / "d.exr").buffer,
                        header={**read_sample_dump(tmp_path / "d.exr").attributes, "awr:spp_max": 64}, overwrite=True)
    for order in (("capped", "b"), ("b", "capped")):
        out = tmp_path / f"{''.join(order)}.exr"
        assert main(["merge", *(str(tmp_path / f"{n}.exr") for n in order), "-o", str(out)]) == 0
        assert "awr:spp_max" not in read_sample_dump(out).attributes
        assert "awr:spp_max of" in capsys.readouterr().err


def test_an_option_given_replaces_a_dump_s_setting_that_does_not_fit(tmp_path, rng, capsys):
    """plan reads only the settings it uses: an option given, or a strategy that does not use one, leaves the
    dump's value unread (a review found --noise-model refused over the awr:noise_model it replaces)."""
    buf = _dump(tmp_path / "d.exr", rng)
    write_sample_buffer(tmp_path / "bad.exr", buf, header={"awr:strategy": "awr", "awr:noise_model": "evil",
                                                           "awr:spp_max": 64})
    for given in (["--noise-model", "levels"], ["--strategy", "variance"]):
        assert main(["plan", str(tmp_path / "bad.exr"), *given, "-o", str(tmp_path / "r.exr"), "-q",
                     "--overwrite"]) == 0
        assert request_attributes(tmp_path / "r.exr")["awr:spp_max"] == 64  # what it uses still carried
    assert main(["plan", str(tmp_path / "bad.exr"), "-o", str(tmp_path / "r.exr"), "-q", "--overwrite"]) == 2
    _one_error_line(capsys, "bad.exr", "awr:noise_model")
    # The words that lift a cap or a depth are refused where the option itself would do nothing.
    assert main(["plan", str(tmp_path / "bad.exr"), "--strategy", "variance", "--levels", "auto", "-o",
                 str(tmp_path / "v.exr"), "-q"]) == 2
    _one_error_line(capsys, "--levels", "only --strategy awr")
    # --round-growth beside --budget: the budget sizes this round, the growth is recorded for the next.
    assert main(["plan", str(tmp_path / "d.exr"), "--budget", "500", "--round-growth", "1", "-o",
                 str(tmp_path / "g.exr"), "-q"]) == 0
    assert read_request(tmp_path / "g.exr").total == 500
    assert request_attributes(tmp_path / "g.exr")["awr:round_growth"] == "1.0"


def test_info_warns_about_the_settings_plan_reads_and_only_those(tmp_path, rng, capsys):
    buf = _dump(tmp_path / "d.exr", rng)
    for header, warned in (({"awr:strategy": "variance", "awr:noise_model": "evil"}, False),  # variance: unused
                           ({"awr:strategy": "awr", "awr:noise_model": "evil"}, True),
                           ({"awr:priority_levels": 9}, True)):  # deeper than the image allows
        write_sample_buffer(tmp_path / "s.exr", buf, header=header, overwrite=True)
        assert (main(["plan", str(tmp_path / "s.exr"), "-o", str(tmp_path / "r.exr"), "-q", "--overwrite"]) == 2) \
            == warned
        capsys.readouterr()
        assert main(["info", str(tmp_path / "s.exr"), "--json"]) == 0
        warnings = json.loads(capsys.readouterr().out).get("warnings", [])
        assert any("awr plan refuses it" in w for w in warnings) == warned, (header, warnings)


def test_plan_names_the_dump_s_setting_it_refuses(tmp_path, rng, capsys):
    """A carried setting that does not fit is refused naming the file and the attribute, not an option never given."""
    buf = _dump(tmp_path / "d.exr", rng)
    for header, given, needle in (({"awr:priority_levels": 9}, [], "bad.exr: awr:priority_levels: 9 is outside 1..4 "
                                   "for its image"),
                                  ({"awr:spp_max": 4}, ["--initial-spp", "8"], "exceeds awr:spp_max 4 of "),
                                  ({"awr:spp_max": 4}, [], "awr:spp_max 4 of "),
                                  ({"awr:spp_max": 4}, ["--budget", "99"], "--budget 99 beside awr:spp_max 4 of ")):
        write_sample_buffer(tmp_path / "bad.exr", buf, header=header, overwrite=True)
        assert main(["plan", str(tmp_path / "bad.exr"), *given, "-o", str(tmp_path / "r.exr"), "-q"]) == 2
        _one_error_line(capsys, "bad.exr", needle)
        assert not (tmp_path / "r.exr").exists()


def test_render_gain_refresh_reaches_the_sampler(tmp_path, capsys, fake_tracer, monkeypatch):
    from awr_denoise import noise_gain

    measured = []
    real = noise_gain.reconstruct_detailed
    monkeypatch.setattr(noise_gain, "reconstruct_detailed", lambda *a, **k: measured.append(1) or real(*a, **k))
    every = tmp_path / "every.exr"
    assert main(["render", "--spp", "16", "--noise-model", "reconstruction", "-o", str(every), "-q"]) == 0
    every_round = len(measured)
    measured.clear()
    dump = _rendered(tmp_path, 16, "--gain-refresh", "2", extra=["--noise-model", "reconstruction"])
    assert 0 < len(measured) < every_round  # 16 spp from 4: the gain of every round, or of every third or fourth
    assert not np.array_equal(dump.buffer.count, read_sample_dump(every).buffer.count)
    for bad in (["--gain-refresh", "1.5"], ["--gain-refresh", "0.5", "--noise-model", "reconstruction"],
                ["--gain-refresh", "nan", "--noise-model", "reconstruction"]):
        assert main(["render", *bad, "-o", str(tmp_path / "bad.exr")]) == 2
        _one_error_line(capsys, "--gain-refresh")
    assert not (tmp_path / "bad.exr").exists()


def test_render_seconds_leaves_the_denoising_the_time_its_trial_predicts(tmp_path, fake_tracer, monkeypatch, capsys):
    from awr_denoise.cli import render_cmd

    asked = []

    def predicted(buffer, reconstruct):
        asked.append((buffer.total_samples, reconstruct.keywords))
        return 100.0

    monkeypatch.setattr(render_cmd, "reconstruction_seconds", predicted)
    out = tmp_path / "d.exr"
    assert main(["render", "--seconds", "1", "--c-s", "0.7", "-o", str(out), "-q"]) == 0
    assert read_sample_dump(out).buffer.total_samples == 2 * H * W  # round 0 alone: the rest is the denoising's
    (total, settings), = asked  # asked once, on round 0's samples, with the command's settings
    assert total == 2 * H * W and settings["c_s"] == 0.7 and settings["variance_probes"] == 0
    warned = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(warned) == 1 and warned[0].startswith("awr: warning: seconds: "), warned
    kept = float(warned[0].split()[3])  # the denoising's and the files' share, and the setup's seconds
    assert (1 + render_cmd.WRITE_SHARE) * 100 <= kept < (1 + render_cmd.WRITE_SHARE) * 100 + 1, warned


def test_render_round_growth_takes_fewer_rounds(tmp_path, fake_tracer):
    rounds = {growth: int(_rendered(tmp_path, 16, "--round-growth", growth).attributes["awr:round"])
              for growth in ("0.25", "1.0")}
    # 2 spp, then rounds of 25% (or 100%) of the samples so far, each at least 1 spp
    assert rounds == {"0.25": 10, "1.0": 4}


def test_render_seconds_renders_adaptive_rounds_for_that_long_with_spp_as_a_cap(tmp_path, fake_tracer, capsys):
    timed = tmp_path / "timed.exr"
    assert main(["render", "--seconds", "1", "-o", str(timed), "-q"]) == 0
    dump = read_sample_dump(timed)
    assert dump.attributes["awr:strategy"] == "awr" and dump.attributes["awr:initial_spp"] == 2
    assert dump.buffer.total_samples > 16 * H * W  # the stand-in renders fast: past the default 16 spp in 1 s
    assert read_image(tmp_path / "timed.denoised.exr").shape == (H, W, 3)
    capsys.readouterr()
    short = tmp_path / "short.exr"
    assert main(["render", "--seconds", "1e-9", "-o", str(short), "-q"]) == 0  # the first round, and a warning
    assert read_sample_dump(short).buffer.total_samples == 2 * H * W
    warned = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(warned) == 1 and warned[0].startswith("awr: warning: seconds: the first round alone took"), warned
    capped = tmp_path / "capped.exr"
    assert main(["render", "--seconds", "100", "--spp", "4", "-o", str(capped), "-q"]) == 0
    assert read_sample_dump(capped).buffer.total_samples == 4 * H * W
    for bad in ("0", "-1", "nan", "inf", "1e10", "x"):
        assert main(["render", "--seconds", bad, "-o", str(tmp_path / "bad.exr")]) == 2
        _one_error_line(capsys, "--seconds")
    assert main(["render", "--uniform", "--seconds", "1", "-o", str(tmp_path / "u.exr")]) == 2
    _one_error_line(capsys, "--seconds", "a uniform render has no adaptive rounds")
    assert not (tmp_path / "bad.exr").exists() and not (tmp_path / "u.exr").exists()


def test_maxerror_failure_keeps_output_and_exits_1(tmp_path, capsys, rng):
    _dump(tmp_path / "d.exr", rng)
    write_image(tmp_path / "ref.exr", np.full((H, W, 3), 5.0))
    assert main(["denoise", str(tmp_path / "d.exr"), "-o", str(tmp_path / "o.exr"), "-r", str(tmp_path / "ref.exr"),
                 "--maxerror", "0.01", "-q"]) == 1
    _one_error_line(capsys, "o.exr", "exceeds --maxerror")


@pytest.mark.tracer
def test_render_with_the_bundled_tracer(tmp_path):
    pytest.importorskip("embreex")
    out = tmp_path / "d.exr"
    assert main(["render", "--uniform", "--spp", "2", "--width", "32", "--height", "24", "-o", str(out), "-q"]) == 0
    dump = read_sample_dump(out)
    assert dump.buffer.shape == (24, 32) and (dump.buffer.count == 2).all()
    assert dump.attributes["awr:scene"] == "default"



@pytest.mark.tracer
def test_render_over_workers_matches_the_serial_render(tmp_path):
    """--workers splits every round into tiles rendered by workers; addressable random numbers
    make the merged dump identical to the in-process render."""
    pytest.importorskip("embreex")
    common = ["render", "--spp", "6", "--width", "40", "--height", "24", "-q"]
    assert main(common + ["-o", str(tmp_path / "serial.exr")]) == 0
    assert main(common + ["-o", str(tmp_path / "tiled.exr"), "--workers", "2", "--tile", "16"]) == 0
    serial, tiled = read_sample_dump(tmp_path / "serial.exr"), read_sample_dump(tmp_path / "tiled.exr")
    np.testing.assert_array_equal(tiled.buffer.count, serial.buffer.count)
    np.testing.assert_array_equal(tiled.buffer.mean, serial.buffer.mean)
    np.testing.assert_array_equal(tiled.buffer.variance, serial.buffer.variance)


def test_denoise_frames_over_workers_matches_serial(tmp_path, rng):
    for frame in (1, 2, 3):
        _dump(tmp_path / f"d.{frame:04d}.exr", rng)
    pattern = str(tmp_path / "d.####.exr")
    assert main(["denoise", pattern, "--frames", "1-3", "-o", str(tmp_path / "s.####.exr"), "-q"]) == 0
    assert main(["denoise", pattern, "--frames", "1-3", "-o", str(tmp_path / "p.####.exr"), "-q",
                 "--workers", "2"]) == 0
    for frame in (1, 2, 3):
        np.testing.assert_array_equal(read_image(tmp_path / f"p.{frame:04d}.exr"),
                                      read_image(tmp_path / f"s.{frame:04d}.exr"))

def test_deep_sample_dump_through_the_cli(tmp_path, capsys, rng):
    from awr_denoise.io import write_deep_samples

    n = 5 * H * W
    pixels = rng.integers(0, H * W, n)
    write_deep_samples(tmp_path / "s.exr", pixels, 0.5 + 0.1 * rng.standard_normal((n, 3)), (H, W))
    capsys.readouterr()
    assert main(["info", str(tmp_path / "s.exr"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["deep"] and info["preset"] == "deep" and info["total_samples"] == n
    assert main(["denoise", str(tmp_path / "s.exr"), "-o", str(tmp_path / "o.exr"), "-q"]) == 0
    assert read_image(tmp_path / "o.exr").shape == (H, W, 3)


def test_help_version_and_missing_output_directory(tmp_path, capsys, rng):
    assert main(["--version"]) == 0
    assert "awr " in capsys.readouterr().out
    assert main(["denoise", "--help"]) == 0
    assert "--c-s" in capsys.readouterr().out
    _dump(tmp_path / "d.exr", rng)
    assert main(["denoise", str(tmp_path / "d.exr"), "-o", str(tmp_path / "no" / "o.exr"), "-q"]) == 2
    _one_error_line(capsys, "does not exist")


def test_merge_holds_one_input_at_a_time(tmp_path):
    """``awr merge`` read every input before merging: 40 inputs at 512x512 took 810 MB (a red-team pass).
    Each input is now read, checked and merged in turn: the peak of 12 inputs is that of 4 (traced
    allocations, numpy's included; the previous version's grew with the inputs, 1.9x here)."""
    import tracemalloc

    rng = np.random.default_rng(0)
    paths = []
    for i in range(12):
        buffer = SampleBuffer.from_moments(np.full((128, 128), 4), rng.random((128, 128, 3)), rng.random((128, 128, 3)))
        write_sample_buffer(tmp_path / f"b{i}.exr", buffer)
        paths.append(str(tmp_path / f"b{i}.exr"))
    peaks = []
    for n in (4, 12):
        tracemalloc.start()
        try:
            assert main(["merge", *paths[:n], "-o", str(tmp_path / f"m{n}.exr"), "-q"]) == 0
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    assert peaks[1] < 1.2 * peaks[0], peaks
    assert read_sample_dump(tmp_path / "m12.exr").buffer.total_samples == 12 * 4 * 128 * 128


@pytest.mark.parametrize("executor", ["processes", "dask"])
def test_frames_on_worker_processes_write_the_serial_runs_bytes(tmp_path, executor):
    """Every denoise on process or Dask workers was refused (exit 2, "its folder .awr-....tmp is named as awr's
    staging folders"): a worker process did not know its outputs were the command's own staged temporaries."""
    if executor == "dask":
        pytest.importorskip("distributed", reason="the dask extra")
    for i in (1, 2):
        write_sample_buffer(tmp_path / f"d.{i:04d}.exr", SampleBuffer.from_moments(
            np.full((16, 16), 4), np.random.default_rng(i).random((16, 16, 3)), np.full((16, 16, 3), 0.01)))
    common = [str(tmp_path / "d.####.exr"), "--frames", "1-2", "-q"]
    assert main(["denoise", *common, "-o", str(tmp_path / "s.####.exr"),
                 "--preview", str(tmp_path / "s.####.png")]) == 0
    assert main(["denoise", *common, "-o", str(tmp_path / "w.####.exr"), "--preview", str(tmp_path / "w.####.png"),
                 "--executor", executor, "--workers", "1"]) == 0
    assert main(["denoise", str(tmp_path / "d.0001.exr"), "-o", str(tmp_path / "one.exr"), "-q",
                 "--executor", executor, "--workers", "1"]) == 0
    for i in (1, 2):
        for kind in ("exr", "png"):
            assert (tmp_path / f"w.{i:04d}.{kind}").read_bytes() == (tmp_path / f"s.{i:04d}.{kind}").read_bytes()
    assert (tmp_path / "one.exr").read_bytes() == (tmp_path / "s.0001.exr").read_bytes()
    assert not list(tmp_path.glob(".awr-*"))


def test_a_frame_failing_on_a_worker_process_is_named_by_its_output(tmp_path, capsys):
    """A frame that failed on a process (or Dask) worker was reported under the staging folder's
    temporary name, which only the calling process can map to the output (a red-team pass)."""
    mean = np.full((16, 16, 3), 0.5)
    mean[4:8, 4:8] = 1e6  # past HALF's range: --half refuses it
    for i in (1, 2):
        write_sample_buffer(tmp_path / f"h.{i:04d}.exr",
                            SampleBuffer.from_moments(np.full((16, 16), 4), mean, np.full((16, 16, 3), 0.01)))
    out = tmp_path / "o.####.exr"
    assert main(["denoise", str(tmp_path / "h.####.exr"), "--frames", "1-2", "-o", str(out), "--half", "-q",
                 "--executor", "processes", "--workers", "1"]) == 2
    line = _one_error_line(capsys, "beyond the half-float maximum 65504")
    assert line.startswith(f"awr: error: {tmp_path / 'o.000'}") and ".awr-" not in line, line
    assert not list(tmp_path.glob("o.*")) and not list(tmp_path.glob(".awr-*"))
