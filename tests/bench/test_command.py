"""The benchmark's command line: python -m awr_denoise.bench and awr bench (awr_denoise.bench.command)."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import pytest

from awr_denoise.bench import BenchmarkConfig
from awr_denoise.bench.command import add_arguments, config_from_args, main


def _config(*argv: str) -> BenchmarkConfig:
    return config_from_args(add_arguments(argparse.ArgumentParser()).parse_args(list(argv)))


def test_options_map_onto_the_config():
    assert _config() == BenchmarkConfig()
    quick = _config("--quick", "--scenes", "a", "b", "--spp", "16", "4", "16", "--size", "64", "48",
                    "--overhead-sizes", "--no-oidn", "--reference-spp", "2048")
    assert quick == BenchmarkConfig.quick(scenes=("a", "b"), spps=(4, 16), width=64, height=48, overhead_sizes=(),
                                          oidn=False, reference_spp=2048)


def test_the_mitsuba_reference_folder_is_an_option(tmp_path):
    """In a checkout ``awr bench`` kept Mitsuba's references in data/cache/mitsuba, and nothing moved them."""
    assert _config("--mitsuba-references", str(tmp_path)).mitsuba_reference_dir == str(tmp_path)


def test_main_rejects_an_unknown_scene(tmp_path, capsys):
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    code = main(["--quick", "--scenes", "no_such_scene", "--output-dir", str(tmp_path), "--quiet", "--no-plots"])
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("awr: error: --scenes: 'no_such_scene' is not one of") and err.count("\n") == 1
    assert not (tmp_path / "benchmarks.md").exists()


def test_python_m_awr_denoise_bench_shows_its_help():
    proc = subprocess.run([sys.executable, "-m", "awr_denoise.bench", "--help"], capture_output=True, text=True,
                          check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: python -m awr_denoise.bench") and "--overhead-sizes" in proc.stdout


def test_awr_bench_subcommand_runs_the_benchmark(tmp_path, capsys):
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    from awr_denoise.cli.main import main as awr_main

    code = awr_main(["bench", "--quick", "--scenes", "default", "--size", "16", "16", "--spp", "4",
                     "--overhead-sizes", "--no-oidn", "--no-mitsuba", "--no-plots", "--quiet",
                     "--output-dir", str(tmp_path / "docs"),
                     "--results", str(tmp_path / "q.json")])
    assert code == 0
    assert "default" in capsys.readouterr().out
    assert json.loads((tmp_path / "q.json").read_text())["scenes"]["default"]["methods"]["uniform"]
    page = (tmp_path / "docs" / "benchmarks.md").read_text()
    assert "Headline" in page
    assert "Raw numbers: `q.json`" in page and str(tmp_path) not in page  # never a machine path
    assert awr_main(["bench", "--quick", "--scenes", "nowhere", "--quiet", "--no-plots",
                     "--output-dir", str(tmp_path / "other")]) == 2


_TINY = ["bench", "--quick", "--scenes", "default", "--size", "16", "16", "--spp", "4", "--overhead-sizes",
         "--no-oidn", "--no-mitsuba", "--quiet"]


@pytest.mark.parametrize("argv, option", [
    (["--spp", "0"], "--spp"), (["--spp", "1_0"], "--spp"), (["--spp", "99999999999999999999"], "--spp"),
    (["--size", "1", "1"], "--size"), (["--size", "16", "100000"], "--size"),
    (["--reference-spp", "-1"], "--reference-spp"),
    (["--output-dir", " "], "--output-dir"), (["--results", ""], "--results"),
    # Path drops the slash: the run wrote q.json (an attack pass).
    (["--results", "q.json/"], "--results"), (["--results", "q.json/."], "--results"),
    (["--results", "sub/q.json//"], "--results")])
def test_bad_values_are_refused_by_the_parser(argv, option, tmp_path, capsys):
    from awr_denoise.cli.main import main as awr_main

    assert awr_main(["bench", *argv, "--output-dir", str(tmp_path / "docs")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and option in err[0]
    assert not any(tmp_path.iterdir())


def _refused_before_the_run(tmp_path, monkeypatch, capsys, argv, needle):
    """``awr bench`` refuses ``argv`` with exit 2 and one line, before measuring and writing anything."""
    from awr_denoise.bench import runner
    from awr_denoise.cli.main import main as awr_main

    def no_run(*args, **kwargs):
        raise AssertionError("the run started")

    monkeypatch.setattr(runner, "scene_benchmark", no_run)
    before = sorted((p.relative_to(tmp_path), p.is_file() and p.read_bytes()) for p in tmp_path.rglob("*"))
    assert awr_main([*_TINY, *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0], err
    assert sorted((p.relative_to(tmp_path), p.is_file() and p.read_bytes()) for p in tmp_path.rglob("*")) == before


def test_an_output_that_is_a_reference_the_run_reads_is_refused(tmp_path, monkeypatch, capsys):
    """``--results q.json`` linked to the cached reference of a scene: the run read the reference and replaced
    it with its JSON (a red-team pass); by a link or by a hard link, it is refused before the run."""
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    from awr_denoise import tracer

    refs = tmp_path / "refs"
    refs.mkdir()
    reference = refs / "default.exr"
    reference.write_bytes(tracer.reference_path("default").read_bytes())
    monkeypatch.setenv("AWR_DENOISE_REFERENCE_DIR", str(refs))
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "q.json").symlink_to(reference)
    os.link(reference, tmp_path / "out" / "hard.json")
    for name in ("q.json", "hard.json"):
        _refused_before_the_run(tmp_path, monkeypatch, capsys, ["--no-plots", "--output-dir", str(tmp_path / "docs"),
                                                                "--results", str(tmp_path / "out" / name)],
                                f"is the reference {reference}, which the run reads")


def test_a_run_without_mitsuba_asks_nothing_of_its_reference_folder(tmp_path, monkeypatch):
    """The check of outputs against references asked where Mitsuba's are kept even for a run without Mitsuba, and an
    install without a home folder was refused whatever folder the tracer's references were given (a review)."""
    pytest.importorskip("embreex")
    from awr_denoise.bench import runner

    def no_folder():
        raise ValueError("XDG_CACHE_HOME: unset, and there is no home folder")

    monkeypatch.setattr(runner, "default_reference_dir", no_folder)
    monkeypatch.setenv("AWR_DENOISE_REFERENCE_DIR", str(tmp_path))
    config = BenchmarkConfig(scenes=("default",), mitsuba=False)
    runner._refuse_outputs_onto_references(tmp_path / "docs", None, ["default"], config)
    with pytest.raises(ValueError, match="no home folder"):
        runner._refuse_outputs_onto_references(tmp_path / "docs", None, ["default"],
                                               BenchmarkConfig(scenes=("default",), mitsuba=True))


def test_outputs_that_cannot_be_written_are_refused_before_the_run(tmp_path, monkeypatch, capsys):
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    pytest.importorskip("matplotlib")
    (tmp_path / "reference.exr").write_bytes(b"v/1\x01 an input")
    (tmp_path / "afile").write_text("x")
    (tmp_path / "docs" / "img").mkdir(parents=True)
    (tmp_path / "docs2").mkdir()
    (tmp_path / "docs2" / "img").write_text("a file where the figures go")
    (tmp_path / "docs3").mkdir()
    (tmp_path / "docs3" / "benchmarks.md").write_bytes(b"\xff\xfe\x00binary")
    (tmp_path / "q.json").mkdir()
    docs = ["--output-dir", str(tmp_path / "docs")]
    for argv, needle in (
            ([*docs, "--results", str(tmp_path / "reference.exr")], "--results"),  # an input, not a .json
            ([*docs, "--results", str(tmp_path / "q.json")], "--results"),  # a folder
            ([*docs, "--results", ""], "--results"),
            (["--output-dir", str(tmp_path / "afile"), "--results", str(tmp_path / "r.json")], "--output-dir"),
            (["--output-dir", str(tmp_path / "docs2"), "--results", str(tmp_path / "r.json")], "--output-dir"),
            (["--output-dir", str(tmp_path / "docs3"), "--results", str(tmp_path / "r.json")], "benchmarks.md"),
            ([*docs, "--results", str(tmp_path / "r.json"), "--scenes", "default", "default"], "given twice"),
            # Options the run would not read (a red-team pass): Mitsuba's scenes without Mitsuba, a reference
            # spp at a size whose reference is rendered on the spot.
            ([*docs, "--results", str(tmp_path / "r.json"), "--mitsuba-scenes", "nosuch"], "--mitsuba-scenes"),
            ([*docs, "--results", str(tmp_path / "r.json"), "--mitsuba-scenes", "cornell_box"],
             "--mitsuba-scenes: no Mitsuba scene runs with --no-mitsuba"),
            ([*docs, "--results", str(tmp_path / "r.json"), "--reference-spp", "4"],
             "--reference-spp: read at each scene's own size"),
            # Found only at the commit, after the whole run: a folder to create named as a staging folder, a FIFO
            # or a folder at a figure's name other than the one checked.
            (["--output-dir", str(tmp_path / "new" / ".awr-0123456789.tmp"), "--results", str(tmp_path / "r.json")],
             "would be named as awr's staging folders"),
            ([*docs, "--results", str(tmp_path / "new" / ".awr-0123456789.tmp" / "q.json")], "--results"),
            (["--output-dir", str(tmp_path / "docs4"), "--results", str(tmp_path / "r.json")], "bench_density.png"),
            # The results beside an output folder under a file: the folder given is named, not --results.
            (["--output-dir", str(tmp_path / "afile" / "sub")], "--output-dir: ")):
        if argv[1].endswith("docs4"):
            (tmp_path / "docs4" / "img" / "bench_density.png").mkdir(parents=True)
        _refused_before_the_run(tmp_path, monkeypatch, capsys, argv, needle)
    if __import__("os").path.isdir("/proc/self"):  # accepts mkdir from no one, root included
        _refused_before_the_run(tmp_path, monkeypatch, capsys, ["--output-dir", "/proc/awr-bench",
                                                               "--results", str(tmp_path / "r.json")], "--output-dir")


def test_a_mitsuba_reference_folder_that_cannot_be_or_is_not_read_is_refused_before_the_run(tmp_path, monkeypatch,
                                                                                           capsys):
    pytest.importorskip("embreex")
    pytest.importorskip("skimage")
    (tmp_path / "afile").write_text("x")
    docs = ["--no-plots", "--output-dir", str(tmp_path / "docs"), "--results", str(tmp_path / "r.json")]
    monkeypatch.setitem(globals(), "_TINY", [a for a in _TINY if a != "--no-mitsuba"])  # Mitsuba's folder asked
    _refused_before_the_run(tmp_path, monkeypatch, capsys,
                            [*docs, "--mitsuba-references", str(tmp_path / "afile" / "refs")],
                            "cannot be created")  # afile is not a folder
    monkeypatch.undo()
    _refused_before_the_run(tmp_path, monkeypatch, capsys, [*docs, "--mitsuba-references", str(tmp_path / "refs")],
                            "--mitsuba-references: no Mitsuba reference is read with --no-mitsuba")
