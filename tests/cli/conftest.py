"""Fixtures of the command-line tests (helpers in cli_helpers.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cli_helpers import Work, make_work


@pytest.fixture
def work(tmp_path: Path) -> Work:
    """A folder with a dump, a batch, a reference, a request and three frames (cli_helpers.Work)."""
    pytest.importorskip("OpenEXR")
    return make_work(tmp_path)
