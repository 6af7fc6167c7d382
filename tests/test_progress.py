"""tqdm imported with its environment checked (awr_denoise._progress)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from awr_denoise.bench.measure import awr_command


@pytest.mark.parametrize(("variable", "value"), [("TQDM_NCOLS", "abc"), ("TQDM_MININTERVAL", "x")])
def test_a_tqdm_variable_it_cannot_read_is_named(variable, value):
    """tqdm casts its TQDM_* overrides when imported: the library's import and every command (--version too)
    failed with "invalid literal for int()", naming nothing (a red-team pass)."""
    env = dict(os.environ, TQDM_DISABLE="1", **{variable: value})  # a readable one beside it is not named
    library = subprocess.run([sys.executable, "-c", "import awr_denoise.rounds"], capture_output=True, text=True,
                             env=env, timeout=120)
    assert library.returncode == 1 and f"ValueError: {variable}: tqdm cannot read" in library.stderr
    assert "TQDM_DISABLE" not in library.stderr
    command = subprocess.run([*awr_command(), "--version"], capture_output=True, text=True, env=env, timeout=120)
    assert command.returncode == 2
    (line,) = command.stderr.strip().splitlines()
    assert line.startswith(f"awr: error: {variable}: tqdm cannot read this environment variable (") and value in line
