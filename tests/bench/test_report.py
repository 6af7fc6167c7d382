"""The benchmark's page (awr_denoise.bench.report)."""

from __future__ import annotations

import pytest

from awr_denoise.bench.report import NOTES_BEGIN, NOTES_END, format_number, kept_notes, write_markdown

pytestmark = pytest.mark.tracer


def test_format_number():
    assert format_number(0.012345) == "0.01235"
    assert format_number(3.0e-5) == "3.000e-05"
    assert format_number(12345.0) == "1.234e+04"
    assert format_number(0.0) == "0"
    assert format_number(float("inf")) == "inf" and format_number(float("nan")) == "n/a"
    assert format_number(None) == "-" and format_number(False) == "no" and format_number("x") == "x"


def test_page_has_every_section_and_its_figures(tiny_run):
    _, out = tiny_run
    page = (out / "docs" / "benchmarks.md").read_text()
    for heading in ("# Benchmarks", "## Reproduce", "## References and their noise floor", "## Headline",
                    "## Goals", "## All metrics", "## Equal time", "## Where the samples went",
                    "## Smoothing constant and domain"):
        assert heading in page, heading
    assert "python -m awr_denoise.bench" in page
    assert "## Overhead" not in page and "## The other defaults" not in page  # neither was measured
    for link in page.split("](img/")[1:]:
        assert (out / "docs" / "img" / link.split(")")[0]).is_file()
    # The image mean beside relMSE and MSE: the plain mean changes nothing of its own samples' mean.
    assert "| image mean: error, change |" in page
    assert all(", 0.00% |" in line for line in page.splitlines() if line.startswith("| uniform | "))


def test_notes_survive_a_rewrite(tiny_run, tmp_path):
    results, _ = tiny_run
    path = tmp_path / "benchmarks.md"
    write_markdown(results, {}, path, None)
    first = path.read_text()
    assert f"{NOTES_BEGIN}\n{NOTES_END}" in first and "Raw numbers: not written" in first
    path.write_text(first.replace(f"{NOTES_BEGIN}\n{NOTES_END}", f"{NOTES_BEGIN}\nA reading by hand.\n{NOTES_END}"))
    write_markdown(results, {}, path, None)
    assert f"{NOTES_BEGIN}\nA reading by hand.\n{NOTES_END}" in path.read_text()
    assert "![" not in path.read_text()  # no figure drawn, none linked


@pytest.mark.parametrize("page", [f"# p\n{NOTES_BEGIN}\nMY NOTE\n", f"{NOTES_END}\nMY NOTE\n{NOTES_BEGIN}\n",
                                  f"{NOTES_BEGIN}\nA\n{NOTES_END}\n{NOTES_BEGIN}\nMY NOTE\n{NOTES_END}\n",
                                  f"MY NOTE\n{NOTES_END}\n"])
def test_notes_between_markers_that_are_not_one_pair_are_refused_not_dropped(tmp_path, page):
    """An opening marker alone, the two reversed or a second pair: the page was rewritten without the notes, exit 0
    (an attack pass). Refused, naming the page and the markers found, before anything is written."""
    path = tmp_path / "benchmarks.md"
    path.write_text(page)
    with pytest.raises(ValueError, match="benchmarks.md: its notes are not between one .* found"):
        kept_notes(path)
    path.write_text(f"x\n{NOTES_BEGIN}\nMY NOTE\n{NOTES_END}\n")
    assert kept_notes(path) == "MY NOTE"


def test_flags_not_confirmed_over_seeds_have_their_own_section(tiny_run, tmp_path):
    import copy

    results = copy.deepcopy(tiny_run[0])
    results["summary"]["flags"] = []
    results["summary"]["flags_not_confirmed"] = ["s: uniform+awr at 4 spp is worse than the plain mean (MSE 2 > 1)"]
    path = tmp_path / "benchmarks.md"
    write_markdown(results, {}, path, None)
    page = path.read_text()
    assert "### Flags not confirmed over seeds" in page and "- s: uniform+awr at 4 spp" in page
    assert "No flag stands" in page and "summed over 3 seeds" in page
    assert "### Flags: a default worse than the plain mean" not in page
