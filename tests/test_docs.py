"""The docs held to the code: the commands they quote, the files and sections they name.

The docs give a command for every figure they quote and show the ``awr`` command line by example. An
option renamed or removed leaves those commands failing for the next reader, and a figure without a
command that regenerates it. Here every command that the README, ``docs/*.md`` and the benchmark scripts'
docstrings quote, in code blocks and in inline code, is checked against the parser of its program: ``awr``
(``build_parser``) and the scripts of ``benchmarks/`` and ``tests/data/`` (their own parsers, in a child
process, ``tests/data/script_parsers.py``). Every option word must be one the program, or the sub-command
given, defines. A whole command (from a code block, with no placeholder such as ``DUMP.exr`` or ``N``) must
also parse. So must the command each file of ``benchmarks/results/`` records as the one that made it (its
``command`` or ``commands``). And every repository path the docs and the sources name (a test, a script,
a page, a data file, ``file.py::test_name``) exists, and every section a reference quotes (``sampling.md,
"The noise gain"``) is a heading or a bold title of that page.
"""

from __future__ import annotations

import argparse
import ast
import json
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from awr_denoise.cli.errors import UsageError
from awr_denoise.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SCRIPTS = sorted((ROOT / "benchmarks").glob("*.py"))  # their module docstrings say how to run them

_START = re.compile(r"^(?:\.venv/bin/)?(?:awr(?:\s|$)|python3?\s+(?:benchmarks|tests/data)/\S+\.py)")
# A word the reader replaces (DUMP.exr, N, WxH, FILE[:plane], ...), or a synopsis' brackets and ellipses.
_PLACEHOLDER = re.compile(r"[A-Z]{2,}|^[A-Z]$|\.\.\.|[][|<>{}]|^\$")
_OPTION = re.compile(r"(?<![\w./'\"=-])(--?[A-Za-z][\w-]*)")


@dataclass(frozen=True)
class Quoted:
    """One command line quoted in a doc: where, what, and whether it is whole (a code block's, no placeholder)."""

    doc: str
    line: int
    text: str
    block: bool

    @property
    def words(self) -> list[str]:
        """The command's words, its shell comment and anything after a pipe left out."""
        text = re.split(r"\s#", self.text.replace("\\|", "|"), maxsplit=1)[0]  # not shot.####.exr's
        try:
            words = shlex.split(text)
        except ValueError:  # an unbalanced quote in a fragment: its option words are still checked
            words = text.split()
        if "|" in words:
            words = words[: words.index("|")]
        return words

    @property
    def whole(self) -> bool:
        return self.block and not any(_PLACEHOLDER.search(word) for word in self.words)

    @property
    def options(self) -> list[str]:
        """Every option word, placeholders' synopses included (``[--stages N]`` gives ``--stages``)."""
        text = re.split(r"\s#", self.text.replace("\\|", "|"), maxsplit=1)[0].split("|")
        found = []
        for part in text:
            found += _OPTION.findall(part)
        return found

    def __str__(self) -> str:
        return f"{self.doc}:{self.line}: {self.text}"


def _code(text: str) -> list[tuple[int, str, bool]]:
    """(line, text, from a block) of every code block line and inline code span of a markdown page."""
    lines = text.splitlines()
    found: list[tuple[int, str, bool]] = []
    fenced = False
    for number, line in enumerate(lines, 1):
        if line.strip().startswith("```"):
            fenced = not fenced
            continue
        if fenced or line.startswith("    "):
            found.append((number, line.strip(), True))
    for number, line in enumerate(lines, 1):
        found += [(number, span.strip(), False) for span in re.findall(r"`([^`]+)`", line)]
    return found


def _page(path: Path) -> str:
    """A markdown page, or a script's module docstring (line numbers then count from the docstring's)."""
    text = path.read_text(encoding="utf-8")
    return ast.get_docstring(ast.parse(text), clean=True) or "" if path.suffix == ".py" else text


def _pieces(code: list[tuple[int, str, bool]]) -> list[tuple[int, str, bool]]:
    """Shell lines cut at ``&&`` and ``;`` (the README's ``python3 -m venv .venv && ... && .venv/bin/awr demo``)."""
    return [(number, piece, block) for number, text, block in code
            for piece in re.split(r"\s+(?:&&|;)\s+", text)]


def quoted_commands(path: Path, root: Path = ROOT) -> list[Quoted]:
    """The ``awr`` and script command lines ``path`` quotes, continuation lines (``\\``) joined."""
    commands = []
    pending: tuple[int, str] | None = None
    for number, text, block in _pieces(_code(_page(path))):
        if pending is not None and block:
            pending = (pending[0], f"{pending[1]} {text}")
        elif _START.match(text):
            pending = (number, text)
        else:
            pending = None
            continue
        if pending[1].endswith("\\") and block:
            pending = (pending[0], pending[1][:-1].rstrip())
            continue
        commands.append(Quoted(path.relative_to(root).as_posix(), pending[0], pending[1], block))
        pending = None
    return commands


def _all_quoted() -> list[Quoted]:
    return [command for path in DOCS + SCRIPTS for command in quoted_commands(path)]


def recorded_commands(path: Path) -> list[Quoted]:
    """The commands a results file says made it (``command``/``commands`` at any depth), as whole commands."""

    def walk(node: object) -> list[str]:
        if isinstance(node, list):
            return [text for item in node for text in walk(item)]
        if not isinstance(node, dict):
            return []
        found = []
        for key, value in node.items():
            if key in ("command", "commands"):
                values = value.values() if isinstance(value, dict) else value if isinstance(value, list) else [value]
                found += [text for text in values if isinstance(text, str)]
            else:
                found += walk(value)
        return found

    commands = []
    for text in dict.fromkeys(walk(json.loads(path.read_text(encoding="utf-8")))):
        text = re.sub(r"^(?:\.venv/bin/)?python3? ", "", text.strip())
        commands.append(Quoted(path.relative_to(ROOT).as_posix(), 0, f"python {text}", True))
    return commands


def _program(command: Quoted) -> tuple[str, list[str]]:
    """``("awr", argv)`` or ``(script path, argv)``."""
    words = command.words
    first = words[0].removeprefix(".venv/bin/")
    if first == "awr":
        return "awr", words[1:]
    return words[1], words[2:]


def awr_problems(command: Quoted, parser: argparse.ArgumentParser) -> list[str]:
    """What ``awr``'s parser says against ``command``: unknown options, and its refusal of a whole command."""
    _, argv = _program(command)
    commands = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    name = argv[0] if argv and argv[0] in commands.choices else None
    if name is None:  # 'awr ... --nonfinite drop': the option of some command
        known = set(parser._option_string_actions).union(
            *(set(sub._option_string_actions) for sub in commands.choices.values()))
    else:
        known = set(parser._option_string_actions) | set(commands.choices[name]._option_string_actions)
    problems = [f"awr {name or ''} defines no option {option}".replace("  ", " ")
                for option in command.options if option not in known]
    if argv and argv[0] not in commands.choices and not argv[0].startswith("-") and argv[0] != "...":
        problems.append(f"awr has no command {argv[0]!r}")
    if command.whole and not problems and argv:
        try:
            parser.parse_args(argv)
        except UsageError as exc:
            problems.append(f"awr refuses it: {exc}")
    return problems


def script_problems(commands: list[Quoted]) -> list[str]:
    """The scripts' parsers against ``commands`` (a child process: importing a script may change its process)."""
    requests, checked = [], []
    problems = []
    for command in commands:
        script, argv = _program(command)
        if not (ROOT / script).is_file():
            problems.append(f"{command}\n    no such script: {script}")
            continue
        if "argparse" not in (ROOT / script).read_text(encoding="utf-8"):
            continue  # a script that takes positional words of its own (tests/data/generate/*.py)
        requests.append({"script": script, "argv": argv, "options": command.options, "whole": command.whole})
        checked.append(command)
    result = subprocess.run([sys.executable, str(ROOT / "tests" / "data" / "script_parsers.py")],
                            input=json.dumps(requests), capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert result.returncode == 0, result.stderr
    for index, problem in json.loads(result.stdout):
        problems.append(f"{checked[index]}\n    {problem}")
    return problems


def test_the_docs_quote_commands_of_every_program() -> None:
    """The extraction finds what it checks: the README's main job, cli.md's synopses, the benchmark commands."""
    quoted = _all_quoted()
    texts = {command.text for command in quoted}
    assert any(text.startswith(".venv/bin/awr demo") for text in texts)
    assert "awr denoise DUMP.exr -o OUT.exr" in texts
    scripts = {_program(command)[0] for command in quoted if _program(command)[0] != "awr"}
    assert {"benchmarks/bench_core.py", "benchmarks/bench_reconstruct.py", "benchmarks/bench_equal_error.py",
            "benchmarks/bench_mitsuba.py", "tests/data/regression_outputs.py"} <= scripts
    assert sum(command.whole for command in quoted) >= 50


def test_every_awr_command_the_docs_quote_is_one_awr_accepts() -> None:
    parser = build_parser()
    problems = [f"{command}\n    {problem}" for command in _all_quoted() if _program(command)[0] == "awr"
                for problem in awr_problems(command, parser)]
    assert not problems, "\n".join(problems)


def test_every_script_command_the_docs_quote_is_one_the_script_accepts() -> None:
    commands = [command for command in _all_quoted() if _program(command)[0] != "awr"]
    problems = script_problems(commands)
    assert not problems, "\n".join(problems)


def test_every_command_a_results_file_records_is_one_its_script_accepts() -> None:
    commands = [command for path in sorted((ROOT / "benchmarks" / "results").glob("*.json"))
                for command in recorded_commands(path)]
    assert len({command.doc for command in commands}) >= 20  # the files that record their command
    problems = script_problems(commands)
    assert not problems, "\n".join(problems)


_PATH = re.compile(r"(?<![\w./<-])((?:tests|benchmarks|docs|data|awr_denoise|cli)/[\w./-]*\.(?:py|md|json|exr|npz|png))"
                   r"(?:::(\w+))?")


def named_paths(text: str) -> list[tuple[int, str, str | None]]:
    """(line, path, test or other name after ``::``) of every repository path ``text`` names."""
    return [(number, match.group(1).rstrip("."), match.group(2)) for number, line in enumerate(text.splitlines(), 1)
            for match in _PATH.finditer(line)]


def missing_paths(text: str, root: Path = ROOT) -> list[str]:
    """The paths ``text`` names that do not exist under ``root``, and the ``file::name`` whose file defines no
    ``name``. A placeholder in capitals (``data/references/SCENE.exr``) names no file."""
    missing = []
    for number, path, name in named_paths(text):
        if re.search(r"/[A-Z_]+\.\w+$", path):
            continue
        target = root / path
        if not target.exists():
            missing.append(f"{number}: {path}")
        elif name and target.is_file() and not re.search(rf"^\s*(?:def|class) {name}\b",
                                                         target.read_text(encoding="utf-8"), re.MULTILINE):
            missing.append(f"{number}: {path}::{name}")
    return missing


def test_every_repository_path_the_docs_and_docstrings_name_exists() -> None:
    """A test, script, page or data file that the README, a page of docs/ or a source file names
    (``tests/io/test_io_cycles.py``, ``tests/test_wiener.py::test_name``) exists, and defines the name."""
    sources = [ROOT / "README.md", *DOCS[1:], *sorted(ROOT.glob("awr_denoise/**/*.py")), *sorted(ROOT.glob("cli/*.py")),
               *SCRIPTS, *sorted(ROOT.glob("tests/**/*.py"))]
    problems = [f"{path.relative_to(ROOT)}:{problem}" for path in sources if path.name != Path(__file__).name
                for problem in missing_paths(path.read_text(encoding="utf-8"))]
    assert not problems, "\n".join(problems)


_SECTION = re.compile(r"(\w+)\.md\)?(?:'s)?,? (?:sections? )?\"([^\"]+)\"")


def page_titles(page: Path) -> list[str]:
    """The headings and bold titles of a page, without their numbers (``3. Fireflies``) and code marks."""
    text = page.read_text(encoding="utf-8")
    titles = re.findall(r"^#+ (.+)$", text, re.MULTILINE) + re.findall(r"\*\*([^*]+)\*\*", text)
    return [re.sub(r"^\d+\. ", "", title.strip()).replace("`", "") for title in titles]


def missing_sections(text: str, docs: Path = ROOT / "docs") -> list[str]:
    """The ``page.md, "Section"`` references of ``text`` whose section no heading or bold title of the page
    begins with (``"Domains"`` finds ``Domains, and why the default is "log"``)."""
    missing, titles = [], {}
    for number, line in enumerate(text.splitlines(), 1):
        for match in _SECTION.finditer(line):
            page, section = docs / f"{match.group(1)}.md", match.group(2).rstrip(".").replace("`", "")
            if not page.is_file():
                continue
            if page not in titles:
                titles[page] = page_titles(page)
            if not any(title.startswith(section) for title in titles[page]):
                missing.append(f"{number}: {page.name}, \"{section}\"")
    return missing


def test_every_section_a_reference_quotes_is_on_its_page() -> None:
    sources = [ROOT / "README.md", *DOCS[1:], *sorted(ROOT.glob("awr_denoise/**/*.py")), *sorted(ROOT.glob("cli/*.py")),
               *SCRIPTS, *sorted(ROOT.glob("tests/**/*.py"))]
    found = [len(_SECTION.findall(path.read_text(encoding="utf-8"))) for path in sources]
    assert sum(found) >= 100  # the references this checks
    problems = [f"{path.relative_to(ROOT)}:{problem}" for path in sources if path.name != Path(__file__).name
                for problem in missing_sections(path.read_text(encoding="utf-8"))]
    assert not problems, "\n".join(problems)


def test_a_missing_section_is_found() -> None:
    text = '(docs/benchmarks.md, "How quality is measured"); [sampling.md](sampling.md), "The noise gain";\n' \
           'robustness.md, "Fireflies"'
    assert missing_sections(text) == ['1: benchmarks.md, "How quality is measured"']


def test_a_missing_path_is_found() -> None:
    text = "see tests/io/test_io_cycles.py and tests/io/test_cycles_files.py, tests/test_wiener.py::no_such_test\n" \
           "and data/references/SCENE.exr"
    assert missing_paths(text) == ["1: tests/io/test_cycles_files.py", "1: tests/test_wiener.py::no_such_test"]


@pytest.mark.parametrize("line, expected", [
    ("    awr denoise DUMP.exr -o OUT.exr --no-such-option", "defines no option --no-such-option"),
    ("    awr denoise in.exr -o out.exr --stages two", "refuses it"),
    ("Run `awr denoize in.exr` first.", "has no command 'denoize'"),
    ("    awr render --scene cornell_gi --spp 32 \\\n      --no-such-option -o out.exr", "--no-such-option"),
])
def test_a_stale_awr_command_is_found(tmp_path: Path, line: str, expected: str) -> None:
    page = tmp_path / "page.md"
    page.write_text(f"# A page\n\n{line}\n", encoding="utf-8")
    quoted = quoted_commands(page, root=tmp_path)
    assert len(quoted) == 1
    problems = awr_problems(quoted[0], build_parser())
    assert any(expected in problem for problem in problems), problems


@pytest.mark.parametrize("text, expected", [
    (".venv/bin/python benchmarks/bench_core.py --only speed --no-such-option", "defines no option"),
    (".venv/bin/python benchmarks/bench_core.py --only no_such_section", "refuses it"),
    (".venv/bin/python benchmarks/bench_guides.py ablations --cach DIR", "defines no option --cach"),
    (".venv/bin/python benchmarks/bench_reconstruct.py qualty --probes", "invalid choice: 'qualty'"),
    (".venv/bin/python benchmarks/bench_nothing.py", "no such script"),
])
def test_a_stale_script_command_is_found(text: str, expected: str) -> None:
    problems = script_problems([Quoted("page.md", 1, text, True)])
    assert any(expected in problem for problem in problems), problems

