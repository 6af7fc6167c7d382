"""The docstring examples pytest's ``--doctest-modules`` does not collect.

``pyproject.toml`` collects ``tests`` and ``awr_denoise``; the ``awr`` command's package lives in
``cli/`` (installed as ``awr_denoise.cli``) and the benchmark scripts in ``benchmarks/``. Their
examples run here: the command's modules imported under their installed names, the scripts in a child
process (importing one may set its run's environment, which must not reach the other tests).
"""

from __future__ import annotations

import doctest
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CLI_MODULES = sorted(path.stem for path in (ROOT / "cli").glob("*.py") if path.stem != "__init__")
SCRIPTS_WITH_EXAMPLES = sorted(path for path in (ROOT / "benchmarks").glob("*.py")
                               if ">>> " in path.read_text(encoding="utf-8"))


@pytest.mark.parametrize("name", CLI_MODULES)
def test_the_command_modules_examples_run(name: str) -> None:
    module = importlib.import_module(f"awr_denoise.cli.{name}")
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False)
    assert result.failed == 0, f"cli/{name}.py: {result.failed} of {result.attempted} examples failed"


def test_the_command_and_the_scripts_have_examples_to_run() -> None:
    """So that the two tests here cannot pass on nothing."""
    attempted = sum(doctest.testmod(importlib.import_module(f"awr_denoise.cli.{name}"), verbose=False,
                                    report=False).attempted for name in CLI_MODULES)
    assert attempted >= 1
    assert SCRIPTS_WITH_EXAMPLES


@pytest.mark.parametrize("script", SCRIPTS_WITH_EXAMPLES, ids=lambda path: path.name)
def test_the_benchmark_scripts_examples_run(script: Path) -> None:
    result = subprocess.run([sys.executable, "-m", "doctest", "-o", "ELLIPSIS", str(script)], cwd=ROOT,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
