"""Option values (cli/values.py): every numeric option refuses NaN, Inf, out-of-range and
malformed values where it is parsed, with one line naming the option and nothing written;
the extremes that make sense are accepted."""

from __future__ import annotations

import argparse
from concurrent.futures import CancelledError
from concurrent.futures.process import BrokenProcessPool
from types import SimpleNamespace

import pytest

pytest.importorskip("OpenEXR")

from awr_denoise.cli.main import main  # noqa: E402
from awr_denoise.cli import values  # noqa: E402
from awr_denoise.cli.values import MAX_SEED  # noqa: E402
from awr_denoise import fused  # noqa: E402
from awr_denoise import SampleRequest  # noqa: E402
from awr_denoise.io import read_image, read_request, write_request, write_sample_buffer  # noqa: E402
from awr_denoise.io.request_map import MAX_ROUND  # noqa: E402
from cli_helpers import dump_buffer, one_error_line, with_attribute  # noqa: E402

pytestmark = pytest.mark.exr

RENDER = ["render", "--renderer", "synthetic", "edges", "--width", "16", "--height", "12", "--spp", "2",
          "-o", "r.exr", "-q"]
RENDER_ANY_SPP = ["render", "--renderer", "synthetic", "edges", "--width", "16", "--height", "12", "-o", "r.exr", "-q"]
"""RENDER without its ``--spp``, for a case that gives its own (an option given twice is refused)."""
DENOISE = ["denoise", "d.exr", "-o", "o.exr", "-q"]
PLAN = ["plan", "d.exr", "-o", "p.exr", "-q"]
FIRST_PLAN = ["plan", "-o", "p.exr", "-q"]

# (base command, option, bad values)
BAD = [
    (DENOISE, "--exposure", ["nan", "inf", "-inf", "1100", "x", "3"]),  # 3: without --preview, nothing to expose
    (DENOISE + ["-r", "ref.exr"], "--maxerror", ["nan", "inf", "-1", "x"]),
    (DENOISE, "--c-s", ["nan", "inf", "-1", "1e400", "x", "1_0", "\u0663"]),  # \u0663: Arabic-Indic 3
    (DENOISE, "--levels", ["0", "-1", "100", "1.5", "nan", "5", "\u0663", "1_0"]),
    (DENOISE, "--wavelet", ["nope", "", "haar2"]),
    (DENOISE, "--frames", ["1-2000000000", "3-1", "x", "1-3x0", "\uff11-\uff13"]),  # full-width digits
    (DENOISE, "--workers", ["0", "-2", "1.5", "inf"]),
    (["denoise", "d.exr", "-o", "o.exr", "--preset", "generic", "--color", "RGB", "--variance", "variance"], "--spp",
     ["-1", "0", "inf", "1e30", "16777217", "2.5"]),
    (PLAN, "--round-spp", ["inf", "nan", "0", "-1", "1e30"]),
    (PLAN, "--round-growth", ["0", "-1", "inf", "nan"]),
    (PLAN, "--budget", ["-1", "1.5", "inf", str(2**62 + 1)]),
    (PLAN, "--seed", ["-1", "1180591620717411303424", "1.5", "nan"]),
    (PLAN, "--round", ["-1", "1.5", str(2**31), str(2**31 - 2)]),  # the last round merge could not number
    (PLAN, "--levels", ["0", "100", "5"]),
    (PLAN, "--initial-spp", ["0", "-1", "inf", "16777217"]),
    (PLAN, "--spp-max", ["0", "inf"]),
    (PLAN + ["--spp-max", "2"], "--initial-spp", ["3"]),  # more than any pixel may have: was cut to 2, unsaid
    (FIRST_PLAN + ["--size", "8x8", "--round-spp", "3"], "--initial-spp", ["2"]),  # two sizes of round 0
    (FIRST_PLAN + ["--size", "8x8", "--budget", "64"], "--initial-spp", ["2"]),
    (PLAN, "--wavelet", ["nope", "dmey"]),
    (PLAN, "--noise-model", ["nope", "", "Levels"]),
    (PLAN, "--rare-paths", ["off", "Even", ""]),
    (FIRST_PLAN, "--size", ["65536x65536", "0x10", "10x0", "10", "-5x5", "1e3x10", "\u0663x3"]),
    # The first round reads no dump and is uniform: what describes a dump or shapes later rounds did nothing.
    (FIRST_PLAN + ["--size", "8x8"], "--alb", ["a.exr"]), (FIRST_PLAN + ["--size", "8x8"], "--view", ["left"]),
    (FIRST_PLAN + ["--size", "8x8"], "--nonfinite", ["drop"]), (FIRST_PLAN + ["--size", "8x8"], "--spp", ["4"]),
    (FIRST_PLAN + ["--size", "8x8"], "--levels", ["4", "0", "none"]),  # 8x8 allows 3; the run's settings it records
    (PLAN, "--spp-max", ["auto", "None", ""]), (PLAN, "--levels", ["none", "Auto"]),  # each lifted by its own word
    (RENDER_ANY_SPP, "--spp", ["inf", "nan", "0", "-1", "1e30", "1e-9"]),
    (RENDER, "--seed", ["-1", "1180591620717411303424", "nan"]),
    (RENDER, "--width", ["0", "-1", "1.5", "2000000"]),
    (RENDER, "--exposure", ["nan", "inf", "1100"]),
    (RENDER, "--levels", ["100", "0", "5"]),
    (RENDER, "--c-s", ["-1", "nan"]),
    (RENDER, "--wavelet", ["nope"]),
    (RENDER, "--round-growth", ["0", "inf"]),
    (RENDER, "--seconds", ["0", "-1", "nan", "inf", "1e10", "x"]),
    (RENDER + ["--uniform"], "--seconds", ["1"]),  # a uniform render is one request: nothing to time
    (RENDER, "--noise-model", ["gain"]),
    (RENDER, "--rare-paths", ["uniform"]),
    (RENDER + ["--uniform"], "--rare-paths", ["ranked"]),  # a uniform render has no rounds to rank
    (RENDER, "--initial-spp", ["0", "inf"]),
    (RENDER, "--tile", ["0", "-1", "1", "7", "64"]),  # 64: no workers to split the work over
    (RENDER, "--initial-spp", ["3"]),  # above the render's --spp 2: was cut to it, unsaid
    (["diff", "ref.exr", "-r", "d.exr"], "--maxerror", ["nan", "inf", "x", "-1", "0_1"]),
    (["diff", "ref.exr", "-r", "d.exr"], "--metric", ["mse"]),  # without --maxerror it chooses nothing
    (["info", "req.exr"], "--spp", ["3"]),  # a request map or an image has no layout to describe
    (["info", "req.exr"], "--alb", ["ref.exr"]),
    (["info", "ref.exr"], "--variance-kind", ["sample"]),
    (["demo", "--out", "demo"], "--spp", ["0", "nan", "inf", "2.5"]),
    (["demo", "--out", "demo"], "--c-s", ["-1", "nan"]),
    (["demo", "--out", "demo"], "--exposure", ["nan"]),
    (["demo"], "--out", ["", " "]),  # '' wrote the demo's files into the working folder
]

BAD_CASES = [(base, option, value) for base, option, values in BAD for value in values]


@pytest.mark.parametrize(("base", "option", "value"), BAD_CASES,
                         ids=[f"{b[0]}{o}={v}" for b, o, v in BAD_CASES])
def test_a_bad_option_value_is_one_line_naming_it_and_writes_nothing(work, capsys, monkeypatch, base, option, value):
    monkeypatch.chdir(work.root)
    before = work.state()
    status = main([*base, option, value] if option != "--size" else [*base, f"--size={value}"])
    err = capsys.readouterr().err
    assert status == 2, err
    line = one_error_line(err)
    name = {"--width": "--width"}.get(option, option)
    assert name in line or "frames" in line, line
    assert "internal error" not in line
    assert "given twice" not in line, line  # the value refused, not the option's repetition
    assert work.state() == before


def test_a_huge_samples_per_pixel_header_is_refused_naming_it(work, capsys, monkeypatch):
    """pbrt's ``samplesPerPixel`` of inf or 1e30 was an internal OverflowError."""
    monkeypatch.chdir(work.root)
    import OpenEXR
    import numpy as np

    for raw in ("inf", "1e30", "nan"):
        planes = {c: np.full((4, 4), 0.5, np.float32) for c in "RGB"}
        planes |= {f"Variance.{c}": np.full((4, 4), 0.1, np.float32) for c in "RGB"}
        with OpenEXR.File({"samplesPerPixel": raw}, planes) as f:
            f.write(str(work / "pbrt.exr"))
        before = work.state()
        assert main(["denoise", "pbrt.exr", "--preset", "pbrt", "-o", "o.exr", "-q"]) == 2
        one_error_line(capsys.readouterr().err, "pbrt.exr", "samplesPerPixel")
        assert work.state() == before


def test_bad_dump_attributes_are_refused_naming_them(work, capsys, monkeypatch):
    monkeypatch.chdir(work.root)
    for key, value in (("awr:seed", "-3"), ("awr:seed", str(2**70)), ("awr:round", "x"), ("awr:round", "0"),
                       ("awr:seed", "1_0"), ("awr:seed", "\u0663"), ("awr:nonfinite", "lots"), ("awr:nonfinite", "-5")):
        # awr:nonfinite is the writer's own: a file giving it another value is another tool's.
        own = key == "awr:nonfinite"
        write_sample_buffer(work / "h.exr", dump_buffer(5), header=None if own else {key: value}, overwrite=True)
        if own:
            with_attribute(work / "h.exr", key, value)
        before = work.state()
        assert main(["plan", "h.exr", "-o", "p.exr", "-q"]) == 2
        one_error_line(capsys.readouterr().err, "h.exr", key)
        assert work.state() == before


def test_a_request_whose_round_has_no_successor_is_refused_before_merging(work, capsys, monkeypatch):
    """merge writes the request's round + 1: a request at the last round would give a dump that neither
    plan nor merge can read, so it is refused, naming the request and its awr:round."""
    monkeypatch.chdir(work.root)
    # The writer refuses that round (no tool would read the file); another tool may write it.
    write_request(work / "last.exr", SampleRequest.uniform(dump_buffer(0).shape, 8, first_index=8, round=MAX_ROUND))
    with_attribute(work / "last.exr", "awr:round", 2**31 - 1)
    before = work.state()
    assert main(["merge", "d.exr", "b.exr", "--request", "last.exr", "-o", "m.exr", "-q"]) == 2
    one_error_line(capsys.readouterr().err, "last.exr", "awr:round")
    assert work.state() == before
    # One round earlier: the request reads, but the dump merge would write (round MAX_ROUND + 1) is
    # refused before anything is written; every round a tool writes, another reads.
    write_request(work / "late.exr", SampleRequest.uniform(dump_buffer(0).shape, 8, first_index=8, round=MAX_ROUND))
    before = work.state()
    assert main(["merge", "d.exr", "b.exr", "--request", "late.exr", "-o", "m.exr", "-q"]) == 2
    one_error_line(capsys.readouterr().err, "next round would be", str(MAX_ROUND))
    assert work.state() == before
    assert main(["plan", "d.exr", "--round", str(MAX_ROUND + 1), "-o", "p.exr", "-q"]) == 2
    one_error_line(capsys.readouterr().err, "--round")


GOOD = [
    (DENOISE + ["--preview", "o.png"], "--exposure", "1000"),
    (DENOISE + ["--preview", "o.png"], "--exposure", "-1000"),
    (DENOISE, "--c-s", "0"),
    (DENOISE, "--c-s", "1e300"),
    (DENOISE, "--levels", "4"),
    (DENOISE, "--wavelet", "haar"),
    (PLAN, "--seed", str(MAX_SEED)),
    (PLAN, "--budget", "0"),
    (PLAN, "--round-spp", "0.001"),
    (FIRST_PLAN, "--size", "1x1"),
    (RENDER, "--seed", str(MAX_SEED)),
    (RENDER_ANY_SPP, "--spp", "0.5"),
]


@pytest.mark.parametrize(("base", "option", "value"), GOOD, ids=[f"{b[0]}{o}={v}" for b, o, v in GOOD])
def test_extreme_but_valid_values_are_accepted(work, capsys, monkeypatch, base, option, value):
    monkeypatch.chdir(work.root)
    args = [*base, option, value] if option != "--size" else [*base, f"--size={value}"]
    assert main(args) == 0, capsys.readouterr().err
    if base is PLAN and option == "--seed":
        assert read_request(work / "p.exr").total > 0


@pytest.mark.parametrize(("value", "missing_numba"), [("cuda", False), ("numba", True), ("", False)])
def test_a_bad_kernel_setting_is_one_line_naming_it_and_writes_nothing(work, capsys, monkeypatch, value,
                                                                        missing_numba):
    monkeypatch.chdir(work.root)
    monkeypatch.setenv("AWR_DENOISE_KERNELS", value)
    if missing_numba:
        monkeypatch.setattr(fused, "_compiled", lambda: None)  # as if the extra 'fast' were missing
    before = work.state()
    status = main(DENOISE)
    err = capsys.readouterr().err
    assert status == 2, err
    line = one_error_line(err)
    assert "AWR_DENOISE_KERNELS" in line and "internal error" not in line, line
    if missing_numba:
        assert "awr-denoise[fast]" in line
    assert work.state() == before


def test_the_compiled_kernels_give_the_same_file(work, capsys, monkeypatch):
    pytest.importorskip("numba", reason="numba is not installed (extra 'fast')")
    monkeypatch.chdir(work.root)
    outputs = {}
    for value in ("numpy", "numba"):
        monkeypatch.setenv("AWR_DENOISE_KERNELS", value)
        assert main(["denoise", "d.exr", "-o", f"{value}.exr", "-q", "--stages", "1"]) == 0, capsys.readouterr().err
        outputs[value] = read_image(f"{value}.exr")
    assert (outputs["numpy"] == outputs["numba"]).all()


@pytest.mark.parametrize("setting, shown", [(None, False), ("0", False), ("", False), ("no", False),
                                            ("1", True), ("true", True)])
def test_awr_traceback_shows_the_traceback_only_when_asked_for(setting, shown, monkeypatch, capsys):
    from awr_denoise.cli import info_cmd

    def bug(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr(info_cmd, "run", bug)
    if setting is None:
        monkeypatch.delenv("AWR_TRACEBACK", raising=False)
    else:
        monkeypatch.setenv("AWR_TRACEBACK", setting)
    if shown:
        with pytest.raises(RuntimeError, match="a bug"):
            main(["info", "x.exr"])
    else:
        assert main(["info", "x.exr"]) == 1
        assert "internal error: RuntimeError: a bug" in capsys.readouterr().err


@pytest.mark.parametrize(("args", "needles"), [
    (PLAN + ["--spp-max", "1"], ("--spp-max 1:", "spp_max still allows")),
    (PLAN + ["--round-spp", "16777216"], ("--round-spp 16777216:", "2**24")),
    (["merge", "d.exr", "b.exr", "-o", "m.exr", "--independent"], ("d.exr: an awr dump holds statistics",)),
])
def test_a_refusal_names_the_option_that_caused_it(work, capsys, monkeypatch, args, needles):
    """The sampler's refusals named its arguments (``budget``, ``first_index + counts``) where the
    user gave ``--spp-max`` or ``--round-spp``; ``--independent`` on awr dumps said "no sample
    count in the file" of a file that has one (red-team pass 5)."""
    monkeypatch.chdir(work.root)
    before = work.state()
    assert main(args) == 2
    one_error_line(capsys.readouterr().err, *needles)
    assert work.state() == before


@pytest.mark.parametrize(("args", "needles"), [
    (["render", "--scene", "", "--spp", "2", "-o", "e.exr"], ("--scene: an empty name",)),
    (["render", "", "--spp", "2", "-o", "e.exr"], ("SCENE: an empty name",)),
    (["render", " ", "--spp", "2", "-o", "e.exr"], ("SCENE: an empty name",)),
    (["demo", "--scene", "", "--spp", "2", "--out", "demo"], ("--scene: an empty name",)),
    (["render", "--renderer", "synthetic", "", "--spp", "2", "-o", "e.exr"], ("SCENE: an empty name",)),
    (["render", "--renderer", "mitsuba", " ", "--spp", "2", "-o", "e.exr"], ("SCENE: an empty name",)),
])
def test_an_empty_scene_name_is_refused_not_taken_as_the_default(work, capsys, monkeypatch, args, needles):
    """``--scene ""`` rendered the default scene, exit 0, where every other empty name is refused by its option."""
    pytest.importorskip("embreex")
    monkeypatch.chdir(work.root)
    before = work.state()
    assert main(args) == 2
    one_error_line(capsys.readouterr().err, *needles)
    assert work.state() == before


@pytest.mark.parametrize(("extra", "named"), [
    (["-o", "x.exr"], "--output"), (["chess_dof"], "SCENE"), (["--scene", "chess_dof"], "--scene"),
    (["--spp", "4", "-q"], "--spp, --quiet"), (["--workers", "2"], "--workers"),
    (["--uniform"], "--adaptive/--uniform"),
    (["--seed", "0"], "--seed"), (["--sampler", "independent"], "--sampler"),  # given at their defaults: given
    (["--adaptive"], "--adaptive/--uniform"),
])
def test_list_scenes_beside_other_options_is_refused_naming_them(work, capsys, monkeypatch, extra, named):
    """They were ignored without a word: ``--list-scenes -o x.exr`` printed the scenes, wrote nothing, exit 0."""
    monkeypatch.chdir(work.root)
    before = work.state()
    assert main(["render", "--list-scenes", *extra]) == 2
    one_error_line(capsys.readouterr().err, f"--list-scenes: prints the scenes and exits; not with {named}")
    assert work.state() == before
    assert main(["render", "--list-scenes"]) == 0
    assert "chess_dof" in capsys.readouterr().out.split()


def test_a_scene_files_own_size_is_named_as_the_file(work, capsys, monkeypatch):
    """A scene file declaring 200000x200000 pixels was refused naming --width/--height, which were not given."""
    import json

    pytest.importorskip("embreex")
    from awr_denoise.tracer.scenes import BUNDLED_SCENES

    monkeypatch.chdir(work.root)
    spec = json.loads(json.dumps(BUNDLED_SCENES["default"]))
    spec.update(width=200000, height=200000)
    (work.root / "big.json").write_text(json.dumps(spec))
    before = work.state()
    assert main(["render", "big.json", "--spp", "2", "-o", "o.exr"]) == 2
    line = one_error_line(capsys.readouterr().err, "SCENE big.json: 200000x200000 is 40000000000 pixels")
    assert "--width" not in line
    assert main(["render", "big.json", "--width", "2048", "--spp", "2", "-o", "o.exr"]) == 2
    one_error_line(capsys.readouterr().err, "SCENE big.json with --width: 2048x200000")
    assert work.state() == before


def test_a_dump_whose_counts_leave_no_room_for_the_next_round_is_named(work, capsys, monkeypatch):
    """Pixels already holding 2**24 - 1 samples: the default round's indices pass what a request map stores
    exactly, refused as "first_index + counts: ...", naming neither a file nor an option (a red-team pass)."""
    import numpy as np

    from awr_denoise import SampleBuffer

    monkeypatch.chdir(work.root)
    count = np.full((4, 5), 2**24 - 1)
    write_sample_buffer("full.exr", SampleBuffer.from_moments(count, np.ones((4, 5, 3)), np.ones((4, 5, 3))))
    before = work.state()
    assert main(["plan", "full.exr", "-o", "p.exr", "-q"]) == 2
    one_error_line(capsys.readouterr().err, "full.exr: its samples and the next round's:", "2**24")
    assert work.state() == before


@pytest.mark.parametrize("size, needle", [("1048577x1", "1048577x1: a side of 1048577 pixels; sides up to 1048576"),
                                          ("65536x65536", "65536x65536 is 4294967296 pixels; at most 268435456")])
def test_a_size_past_the_limits_names_what_is_past_them(work, capsys, monkeypatch, size, needle):
    """A side past the limit led with the pixel count, within the limit (1048577x1 is 1048577 pixels;
    a red-team pass): the side is named."""
    monkeypatch.chdir(work.root)
    before = work.state()
    assert main([*FIRST_PLAN, f"--size={size}"]) == 2
    one_error_line(capsys.readouterr().err, "--size", needle)
    assert work.state() == before


def test_a_first_round_larger_than_memory_is_refused_naming_size(work, capsys, monkeypatch):
    """``plan --size 16384x16384`` (within the size limits) was ended by the out-of-memory killer,
    exit 137 without a word (red-team pass 5)."""
    from awr_denoise.cli import common

    monkeypatch.chdir(work.root)
    monkeypatch.setattr(common, "available_memory", lambda: 2**30)
    before = work.state()
    assert main(["plan", "--size", "4096x4096", "-o", "p.exr"]) == 2
    one_error_line(capsys.readouterr().err, "--size", "needs about 1.8 GiB", "1.0 GiB are available")
    assert work.state() == before
    assert main(["plan", "--size", "64x64", "-o", "p.exr", "-q"]) == 0


def test_a_benchmark_larger_than_memory_is_refused_naming_its_size(work, capsys, monkeypatch):
    """``awr bench --size`` takes sizes up to 16384 a side, 110 GB of renders, and had no memory check before the
    run, as ``awr render`` has (an attack pass): refused before anything is rendered or written."""
    from awr_denoise.cli import common

    monkeypatch.chdir(work.root)
    monkeypatch.setattr(common, "available_memory", lambda: 2**30)
    before = work.state()
    assert main(["bench", "--quick", "--size", "4096", "4096", "--output-dir", "out"]) == 2
    one_error_line(capsys.readouterr().err, "--size: a benchmark at 4096x4096 needs about 6.4 GiB",
                   "1.0 GiB are available")
    assert work.state() == before


def test_a_render_larger_than_memory_is_refused_naming_its_size(work, capsys, monkeypatch):
    """A render within the size limits but beyond the memory available (a scene file of 1024x200000 pixels) was
    ended by the out-of-memory killer, exit 137 without a word (a review): refused before rendering."""
    pytest.importorskip("embreex")
    from awr_denoise.cli import common

    monkeypatch.chdir(work.root)
    monkeypatch.setattr(common, "available_memory", lambda: 2**30)
    before = work.state()
    big = ["render", "--scene", "default", "--width", "2048", "--height", "2048", "--spp", "1", "-o", "r.exr"]
    assert main([*big, "--threads", "1"]) == 2
    one_error_line(capsys.readouterr().err, "--width/--height: a render of 2048x2048 needs about 1.6 GiB",
                   "1.0 GiB are available")
    assert main([*big, "--threads", "2"]) == 2  # its Wiener stages filter two bands at once
    one_error_line(capsys.readouterr().err, "--width/--height: a render of 2048x2048 on 2 threads needs about 2.0 GiB",
                   "1.0 GiB are available")
    assert work.state() == before
    assert main(["render", "--scene", "default", "--width", "16", "--height", "16", "--spp", "1", "-o", "r.exr",
                 "-q"]) == 0


@pytest.mark.parametrize("error, words", [
    (BrokenProcessPool("A process in the process pool was terminated abruptly"), "a worker process died"),
    (CancelledError("frame-3 cancelled for reason: scheduler-connection-lost."), "cancelled from outside"),
])
def test_a_lost_worker_or_scheduler_is_one_line_not_an_internal_error(error, words, monkeypatch, capsys):
    """A process-pool worker killed mid-run, or a Dask scheduler stopped, was reported as "internal
    error: BrokenProcessPool" or "CancelledError", a bug of ours, where it is the machine's (a red-team
    pass; the parallel layer leaves nothing partial either way: tests/parallel)."""
    from awr_denoise.cli import info_cmd

    def lost(args):
        raise error

    monkeypatch.setattr(info_cmd, "run", lost)
    monkeypatch.delenv("AWR_TRACEBACK", raising=False)
    assert main(["info", "x.exr"]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert words in line and "internal error" not in line and str(error).split()[0] in line, line


def test_a_scheduler_connection_closed_mid_run_is_named(monkeypatch, capsys):
    """A scheduler killed mid-render printed Dask's "in <TCP (closed) ConnectionPool.gather local=... remote=...>:
    Stream is closed", naming its connection pool (an attack pass)."""
    comm = pytest.importorskip("distributed.comm.core")
    from awr_denoise.cli import info_cmd

    def lost(args):
        raise comm.CommClosedError("in <TCP (closed) ConnectionPool.gather local=tcp://127.0.0.1:1>: Stream is closed")

    monkeypatch.setattr(info_cmd, "run", lost)
    monkeypatch.delenv("AWR_TRACEBACK", raising=False)
    assert main(["info", "x.exr"]) == 1
    assert one_error_line(capsys.readouterr().err) == ("awr: error: the connection to the Dask scheduler closed "
                                                       "mid-run (the scheduler stopped or lost?)")


def test_a_frame_whose_worker_died_and_an_input_named_absolutely_read_as_given(tmp_path, monkeypatch, capsys):
    """Frames on Dask: a frame whose worker was killed on every worker that took it (its memory limit) was "internal
    error: KilledWorker: Attempted to run task '_frame_task-5f7b...'", naming a task key, not the frame; an input's
    error named the absolute path the workers are given, where the user named it relatively (an attack pass)."""
    distributed = pytest.importorskip("distributed")
    from awr_denoise.cli import denoise_cmd
    from awr_denoise.errors import InputFileError
    from awr_denoise.parallel import FramesFailedError

    monkeypatch.chdir(tmp_path)
    for i in (1, 2):
        write_sample_buffer(f"shot.{i:04d}.exr", dump_buffer(i))
    for error, status, expected in (
            (distributed.KilledWorker("_frame_task-5f7b", SimpleNamespace(address="tcp://127.0.0.1:1"), 3), 1,
             "awr: error: shot.0002.exr: the Dask worker denoising it died, on every worker that took it (out of "
             "memory, or past the workers' --memory-limit?)"),
            (InputFileError(f"{tmp_path / 'shot.0002.exr'}: truncated or corrupt EXR"), 2,
             "awr: error: shot.0002.exr: truncated or corrupt EXR")):
        def failed(*args, error=error, **kwargs):
            raise FramesFailedError({"shot.0002.exr": error}, 2)

        monkeypatch.setattr(denoise_cmd, "denoise_frames", failed)
        monkeypatch.delenv("AWR_TRACEBACK", raising=False)
        assert main(["denoise", "shot.####.exr", "--frames", "1-2", "-o", "out.####.exr", "-q"]) == status
        assert one_error_line(capsys.readouterr().err) == expected
        assert not list(tmp_path.glob("out*"))


def test_a_cancellation_without_words_adds_none(monkeypatch, capsys):
    """Dask cancels a lost scheduler's futures with an empty CancelledError: the line ended in "unknown error"."""
    from awr_denoise.cli import info_cmd

    def lost(args):
        raise CancelledError()

    monkeypatch.setattr(info_cmd, "run", lost)
    monkeypatch.delenv("AWR_TRACEBACK", raising=False)
    assert main(["info", "x.exr"]) == 1
    assert one_error_line(capsys.readouterr().err) == ("awr: error: the parallel work was cancelled from outside "
                                                       "(a Dask scheduler stopped or lost?)")


@pytest.mark.parametrize("text", ["albedo,", ",depth", "albedo,,normal", "", " ", "Albedo"])
def test_a_feature_list_with_a_name_left_out_is_refused(text):
    """``--features albedo,`` rendered the albedo alone, the comma's second name dropped without a word."""
    with pytest.raises(argparse.ArgumentTypeError):
        values.feature_list(text)
    assert values.feature_list("depth, albedo") == ("albedo", "depth")
