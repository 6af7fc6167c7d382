"""Check command lines of the repository's scripts against their own argument parsers, without running them.

Used by ``tests/test_docs.py`` in a child process (importing a benchmark script may set environment
variables or ``sys.path`` for its run, which must not leak into the test session)::

    echo '[{"script": "benchmarks/bench_core.py", "argv": ["--only", "speed"], "options": ["--only"],
            "whole": true}]' | python tests/data/script_parsers.py

Each script's ``main`` builds its parser and calls ``parse_args``; here ``parse_args`` stops ``main`` there and
hands the parser back, so nothing else of ``main`` runs. For each command line the child reports every option
of ``options`` the parser, or the parser of the sub-command ``argv`` names, does not define, and for a whole command
(``"whole": true``, no placeholders) the parser's own error when it refuses the line. It prints one JSON list of
``[index, problem]`` pairs.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import json
import sys
from pathlib import Path
from typing import Any


class _Captured(Exception):
    def __init__(self, parser: argparse.ArgumentParser) -> None:
        super().__init__("parser captured")
        self.parser = parser


def script_parser(path: Path) -> argparse.ArgumentParser:
    """The parser ``path``'s ``main`` builds, taken at its ``parse_args`` call."""
    spec = importlib.util.spec_from_file_location(f"_parsed_{path.stem}", path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    sys.path.insert(0, str(path.parent))
    spec.loader.exec_module(module)

    def capture(self: argparse.ArgumentParser, *args: Any, **kwargs: Any) -> argparse.Namespace:
        raise _Captured(self)

    original = argparse.ArgumentParser.parse_args
    argparse.ArgumentParser.parse_args = capture  # type: ignore[method-assign]
    saved_argv = sys.argv
    sys.argv = [str(path)]
    try:
        try:
            module.main() if _takes_no_arguments(module.main) else module.main([])
        except _Captured as captured:
            return captured.parser
    finally:
        argparse.ArgumentParser.parse_args = original  # type: ignore[method-assign]
        sys.argv = saved_argv
    raise RuntimeError(f"{path}: main() returned without parsing its arguments")


def _takes_no_arguments(function: Any) -> bool:
    return function.__code__.co_argcount == 0


def options_of(parser: argparse.ArgumentParser, argv: list[str]) -> set[str]:
    """The option strings ``parser`` defines, with those of the sub-command ``argv`` names first, if any."""
    options = set(parser._option_string_actions)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            command = next((word for word in argv if not word.startswith("-")), None)
            if command in action.choices:
                options |= set(action.choices[command]._option_string_actions)
    return options


def refusal(parser: argparse.ArgumentParser, argv: list[str]) -> str | None:
    """``parser``'s error for ``argv``, or None if it parses."""
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
        try:
            parser.parse_args(argv)
        except SystemExit as exc:
            if exc.code:
                return stderr.getvalue().strip().splitlines()[-1] if stderr.getvalue().strip() else str(exc)
    return None


def check(requests: list[dict[str, Any]], root: Path) -> list[tuple[int, str]]:
    """The problems of each request (``script``, ``argv``, ``options``, ``whole``), by the request's index."""
    parsers: dict[str, argparse.ArgumentParser] = {}
    problems: list[tuple[int, str]] = []
    for index, request in enumerate(requests):
        script, argv = request["script"], list(request["argv"])
        if script not in parsers:
            parsers[script] = script_parser(root / script)
        parser = parsers[script]
        known = options_of(parser, argv)
        for option in request["options"]:
            if option not in known:
                problems.append((index, f"{script} defines no option {option}"))
        if request["whole"]:
            refused = refusal(parser, argv)
            if refused is not None:
                problems.append((index, f"{script} refuses it: {refused}"))
    return problems


def main() -> int:
    requests = json.loads(sys.stdin.read())
    root = Path.cwd()
    json.dump(check(requests, root), sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
