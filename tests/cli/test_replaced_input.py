"""An input replaced by rename while ``awr denoise`` reads it (a renderer writing its next version):
every read of one input sees one version, or the command refuses naming the input, exit 2, with
nothing written. Before the fix the input was opened for its size, its samples and its windows
apart: outputs held one version's pixels in the other's data window (exit 0), or an error blamed
the output ("o.exr: dataWindow (0,0)-(15,23) is 16x24, the image 32x24").

The replacement is made deterministic by a reader that swaps the file once, right after it read it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("OpenEXR")

import awr_denoise.cli.denoise_cmd as denoise_cmd  # noqa: E402
import awr_denoise.io.exr as exr  # noqa: E402
import awr_denoise.io.presets as presets  # noqa: E402
from awr_denoise.cli.main import main  # noqa: E402
from awr_denoise.io import write_image, write_sample_buffer  # noqa: E402
from cli_helpers import H, W, dump_buffer, one_error_line  # noqa: E402

pytestmark = pytest.mark.exr

# The next version of the input: the same size in another data window (the silent mix), or another size
# (the error that named the output).
CROP = {"dataWindow": ((100, 200), (100 + W - 1, 200 + H - 1)), "displayWindow": ((0, 0), (1919, 1079))}
VERSIONS = {"window": (dump_buffer(5), CROP), "size": (dump_buffer(5, (H, W // 2)), None)}
ROUTES = {"serial": [], "threads": ["--workers", "2", "--executor", "threads"],
          "processes": ["--workers", "2", "--executor", "processes"]}


def _replace(target: Path, version: Path) -> None:
    """``target`` replaced by rename with a new link to ``version`` (its inode, size and times)."""
    new = version.with_name(version.name + ".new")
    os.link(version, new)
    os.replace(new, target)


def _after_first_read(monkeypatch, module, name: str, target: Path, then) -> list:
    """Make ``module.name`` (a reader taking a path) call ``then()`` once, after its first read of ``target``
    with pixels (header-only reads pass). Returns the list of the reads that triggered it (one, or none)."""
    real = getattr(module, name)
    fired: list = []

    def reader(path, *args, **kwargs):
        out = real(path, *args, **kwargs)
        if not fired and not kwargs.get("header_only") and Path(path).name == target.name:
            fired.append(path)
            then()
        return out

    monkeypatch.setattr(module, name, reader)
    return fired


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """``work/in.exr`` (a dump at the origin), and in ``versions/`` its next versions and a link keeping
    the original's inode (the work folder holds nothing else, so its listing shows what was written)."""
    work, versions = tmp_path / "work", tmp_path / "versions"
    work.mkdir()
    versions.mkdir()
    write_sample_buffer(work / "in.exr", dump_buffer(4))
    os.link(work / "in.exr", versions / "original.exr")
    for name, (buffer, header) in VERSIONS.items():
        write_sample_buffer(versions / f"{name}.exr", buffer, header=header)
    monkeypatch.chdir(work)
    return work, versions


def _refused(capsys, work: Path, before: list[str], *needles: str) -> str:
    line = one_error_line(capsys.readouterr().err, "changed while it was read", *needles)
    assert "o.exr" not in line and "o.0002.exr" not in line  # the input is named, never an output
    assert sorted(os.listdir(work)) == before  # no output, no staging folder left
    return line


# Which read is followed by the replacement: the samples' (the windows, read apart before the fix, came
# from the next version: pixels placed in its window, exit 0, or an error naming the output), or the
# checks' (the options and plane files checked in one version's windows, the frame denoising the next).
# The samples are read in the worker, where a patch of this process reaches threads only.
AFTER = {"the samples": (presets, "read_exr", ["serial", "threads"]),
         "the checks": (denoise_cmd, "read_windows", sorted(ROUTES))}


@pytest.mark.parametrize(("read", "route"), [(read, route) for read, (*_, routes) in AFTER.items() for route in routes])
@pytest.mark.parametrize("version", sorted(VERSIONS))
def test_input_replaced_after_a_read(folder, capsys, monkeypatch, version, read, route):
    work, versions = folder
    module, name, _ = AFTER[read]
    fired = _after_first_read(monkeypatch, module, name, work / "in.exr",
                              lambda: _replace(work / "in.exr", versions / f"{version}.exr"))
    before = sorted(os.listdir(work))
    assert main(["denoise", "in.exr", "-o", "o.exr", "-q", *ROUTES[route]]) == 2
    assert fired
    _refused(capsys, work, before, "in.exr")


@pytest.mark.parametrize("route", sorted(ROUTES))
@pytest.mark.parametrize("version", sorted(VERSIONS))
def test_input_replaced_and_put_back_while_read(folder, capsys, monkeypatch, version, route):
    """Replaced after the checks and put back (its own inode, size and time) before the end: the file's
    identity is the same at the first read and after the last, so only the frame, which compares the
    windows read with its samples to those checked, can see it (in a worker process too)."""
    work, versions = folder
    fired = _after_first_read(monkeypatch, denoise_cmd, "read_windows", work / "in.exr",
                              lambda: _replace(work / "in.exr", versions / f"{version}.exr"))
    real = denoise_cmd.denoise_frames

    def frames_then_put_back(*args, **kwargs):
        try:
            return real(*args, **kwargs)
        finally:
            _replace(work / "in.exr", versions / "original.exr")

    monkeypatch.setattr(denoise_cmd, "denoise_frames", frames_then_put_back)
    before = sorted(os.listdir(work))
    assert main(["denoise", "in.exr", "-o", "o.exr", "-q", *ROUTES[route]]) == 2
    assert fired
    line = _refused(capsys, work, before, "in.exr", "dataWindow")
    assert "with its samples" in line  # the frame's own check


@pytest.mark.parametrize(("option", "name", "module"), [
    ("--alb", "alb.exr", presets),  # a feature file, read with the samples
    ("-r", "ref.exr", exr),  # the reference, read by the checks and again by the frame
])
def test_a_feature_file_or_reference_replaced_while_read(folder, capsys, monkeypatch, option, name, module):
    work, versions = folder
    write_image(work / name, np.full((H, W, 3), 0.5))
    write_image(versions / name, np.full((H, W, 3), 0.25))  # its next version: the same size and window
    fired = _after_first_read(monkeypatch, module, "read_exr", work / name,
                              lambda: _replace(work / name, versions / name))
    before = sorted(os.listdir(work))
    assert main(["denoise", "in.exr", option, name, "-o", "o.exr", "-q"]) == 2
    assert fired
    _refused(capsys, work, before, name)


@pytest.mark.parametrize("route", ["serial", "threads"])
def test_a_frame_replaced_while_read_leaves_no_frame(folder, capsys, monkeypatch, route):
    """--frames: the second frame's dump replaced after its samples were read; no frame is written."""
    work, versions = folder
    for i in (1, 2, 3):
        write_sample_buffer(work / f"shot.{i:04d}.exr", dump_buffer(10 + i))
    fired = _after_first_read(monkeypatch, presets, "read_exr", work / "shot.0002.exr",
                              lambda: _replace(work / "shot.0002.exr", versions / "window.exr"))
    before = sorted(os.listdir(work))
    assert main(["denoise", "shot.####.exr", "--frames", "1-3", "-o", "o.####.exr", "-q", *ROUTES[route]]) == 2
    assert fired
    _refused(capsys, work, before, "shot.0002.exr")


def test_a_check_failing_on_the_next_version_names_the_change(folder, capsys, monkeypatch):
    """Replaced between two reads of the checks: the feature file's window check met the next version
    (another data window) and blamed the feature file; the replacement is the error."""
    work, versions = folder
    write_image(work / "alb.exr", np.full((H, W, 3), 0.5))  # in the first version's window
    fired = _after_first_read(monkeypatch, denoise_cmd, "read_windows", work / "in.exr",
                              lambda: _replace(work / "in.exr", versions / "window.exr"))
    before = sorted(os.listdir(work))
    assert main(["denoise", "in.exr", "--alb", "alb.exr", "-o", "o.exr", "-q"]) == 2
    assert fired
    _refused(capsys, work, before, "in.exr")


@pytest.mark.parametrize(("argv", "module"), [
    (["diff", "in.exr", "-r", "ref.exr", "-o", "o.exr"], exr),
    (["plan", "in.exr", "-o", "o.exr", "-q"], presets),
    (["merge", "in.exr", "batch.exr", "-o", "o.exr", "-q"], presets),
])
@pytest.mark.parametrize("version", sorted(VERSIONS))
def test_the_other_commands_refuse_an_input_replaced_while_read(folder, capsys, monkeypatch, argv, module, version):
    """``awr diff``, ``plan`` and ``merge`` read an input's windows apart from its pixels too (a review of the
    fix above): one replaced after its first read is refused by name before anything is written."""
    work, versions = folder
    write_image(work / "ref.exr", np.full((H, W, 3), 0.5))
    write_sample_buffer(work / "batch.exr", dump_buffer(6))
    fired = _after_first_read(monkeypatch, module, "read_exr", work / "in.exr",
                              lambda: _replace(work / "in.exr", versions / f"{version}.exr"))
    before = sorted(os.listdir(work))
    assert main(argv) == 2
    assert fired
    _refused(capsys, work, before, "in.exr")
