"""Progress bars (``awr_denoise._progress.bars_shown``, cli/common.py ``progress``): drawn on a terminal, never
into a log or a pipe."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cli.main import main

ROOT = Path(__file__).resolve().parents[2]


class _Terminal(io.StringIO):
    """A stderr that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def _frames(work, monkeypatch, stderr: io.StringIO) -> str:
    monkeypatch.chdir(work.root)
    monkeypatch.setattr(sys, "stderr", stderr)
    assert main(["denoise", "shot.####.exr", "--frames", "1-3", "-o", "out.####.exr"]) == 0
    return stderr.getvalue()


def test_frames_draw_no_bar_into_a_log(work, monkeypatch):
    """stderr redirected to a file: the notes are whole lines, with no bar's carriage returns before them."""
    err = _frames(work, monkeypatch, io.StringIO())
    assert "\r" not in err and "frames:" not in err
    assert err.count("\n") == 3 and all(line.startswith("out.000") for line in err.splitlines()), err


def test_frames_draw_a_bar_on_a_terminal(work, monkeypatch):
    err = _frames(work, monkeypatch, _Terminal())
    assert "\r" in err and "frames:" in err


def test_render_draws_no_bar_into_a_log(work, monkeypatch):
    """The tracer's own bar (a uniform render) follows the same rule."""
    pytest.importorskip("embreex")
    monkeypatch.chdir(work.root)
    stderr = io.StringIO()
    monkeypatch.setattr(sys, "stderr", stderr)
    args = ["render", "--scene", "sky_objects", "--width", "16", "--height", "12", "--spp", "2", "--uniform",
            "-o", "r.exr"]
    assert main(args) == 0
    assert "\r" not in stderr.getvalue()


@pytest.mark.parametrize(("setting", "stderr", "drawn"), [("1", io.StringIO, True), ("on", io.StringIO, True),
                                                          ("0", _Terminal, False), ("off", _Terminal, False)])
def test_awr_progress_decides_where_it_is_set(work, monkeypatch, setting, stderr, drawn):
    """A CI log that wants its bars, a terminal that does not: ``AWR_PROGRESS`` overrides the terminal check."""
    monkeypatch.setenv("AWR_PROGRESS", setting)
    err = _frames(work, monkeypatch, stderr())
    assert ("frames:" in err) == drawn


def test_an_unreadable_awr_progress_is_named_before_any_work(work, monkeypatch, capsys):
    """Read where the first bar is drawn, it failed after a frame's work (the bar advances when one is done)."""
    from awr_denoise.parallel import frames

    monkeypatch.chdir(work.root)
    monkeypatch.setenv("AWR_PROGRESS", "maybe")
    monkeypatch.setattr(frames, "read_sample_dump", lambda *a, **k: pytest.fail("a frame was read"))
    assert main(["denoise", "shot.####.exr", "--frames", "1-3", "-o", "out.####.exr"]) == 2
    assert "awr: error: AWR_PROGRESS='maybe': expected 1, true, yes, on, 0, false, no or off" in capsys.readouterr().err
    assert not list(work.root.glob("out.*"))



def _with_bar_format(work, bar_format: str, *args: str, progress: str = "1") -> subprocess.CompletedProcess:
    """``awr ARGS`` in a process of its own: tqdm takes ``TQDM_*`` from the environment when it is imported."""
    env = {**os.environ, "TQDM_BAR_FORMAT": bar_format, "AWR_PROGRESS": progress,
           "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-c", "from cli.main import main; raise SystemExit(main())", *args],
                          cwd=work.root, env=env, capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize(("bar_format", "error"), [("{bogus}", "KeyError: 'bogus'"),
                                                   ("{l_bar", "ValueError: expected '}' before end of string"),
                                                   ("{rate:.2f}", "TypeError")])
def test_a_bar_format_tqdm_cannot_draw_is_named_before_any_work(work, bar_format, error):
    """tqdm reads ``TQDM_BAR_FORMAT`` at its first bar: ``{bogus}`` was an internal error (exit 1), ``{l_bar`` a
    message naming no variable (an attack pass); ``{rate:.2f}`` fails on the first bars, which have no rate yet."""
    done = _with_bar_format(work, bar_format, "denoise", "shot.####.exr", "--frames", "1-3", "-o", "out.####.exr")
    assert done.returncode == 2
    assert done.stderr.startswith(f"awr: error: TQDM_BAR_FORMAT={bar_format!r}: tqdm cannot draw a bar with it "
                                  f"({error}")
    assert done.stderr.count("\n") == 1 and not list(work.root.glob("out.*"))


def test_a_bar_format_is_read_only_where_a_bar_is_drawn(work):
    """Into a log no bar is drawn, so a format tqdm cannot draw is no error there; one it can draw is drawn."""
    done = _with_bar_format(work, "{bogus}", "denoise", "shot.0001.exr", "-o", "a.exr", progress="0")
    assert done.returncode == 0 and "TQDM_BAR_FORMAT" not in done.stderr
    done = _with_bar_format(work, "{desc}: {n}/{total}", "denoise", "shot.####.exr", "--frames", "1-3", "-o",
                            "out.####.exr")
    assert done.returncode == 0 and "frames: 0/3\n" in done.stderr  # the format's bar, not tqdm's default
