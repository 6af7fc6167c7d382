"""Shared test configuration: the slow marker, fixed seeds, tolerance constants, a started Mitsuba, a wheel's
layout of the package."""

from __future__ import annotations

import os
import signal
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

SEED = 20091216  # SIGGRAPH Asia 2009
FLOAT64_RTOL = 1e-12


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--runslow", action="store_true", default=False, help="also run tests marked slow")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(SEED)


def _signals_at_default() -> None:
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, signal.SIG_DFL)


@pytest.fixture
def signals_at_default() -> Callable[[], None]:
    """A ``preexec_fn`` for a child process a test signals: SIGINT, SIGTERM and SIGHUP at their default
    actions, as from a terminal. An ignored signal is inherited across ``exec``, and the command leaves an
    ignored signal ignored: without this, a test run from a shell's background job (SIGINT ignored) or
    under ``nohup`` (SIGHUP ignored) would see the command finish its work instead of stopping."""
    return _signals_at_default


def start_mitsuba():
    """``(mitsuba, drjit)`` in the default variant, or skip the test with the reason.

    Fails instead when ``AWR_REQUIRE_MITSUBA`` is set (as in CI), so a Mitsuba that cannot start
    there is not hidden as a skip.
    """
    from awr_denoise.adapters._mitsuba_runtime import import_mitsuba

    try:
        return import_mitsuba()
    except (ImportError, RuntimeError) as exc:
        if os.environ.get("AWR_REQUIRE_MITSUBA"):
            pytest.fail(f"AWR_REQUIRE_MITSUBA is set but Mitsuba cannot start: {exc}")
        pytest.skip(f"Mitsuba 3 cannot start here: {exc}")


@pytest.fixture(scope="session")
def mi():
    """The ``mitsuba`` module in its default variant (see :func:`start_mitsuba`)."""
    return start_mitsuba()[0]


@pytest.fixture
def wheel_layout(tmp_path: Path) -> Path:
    """A ``site-packages`` folder holding this package as a wheel installs it (the command line's modules inside
    it, no ``data`` or ``pyproject.toml`` beside it), for a Python started with it on ``PYTHONPATH``."""
    import importlib.util
    import shutil

    import awr_denoise

    package = Path(awr_denoise.__file__).parent
    cli = Path(next(iter(importlib.util.find_spec("awr_denoise.cli").submodule_search_locations)))
    site = tmp_path / "site-packages"
    shutil.copytree(package, site / "awr_denoise", ignore=shutil.ignore_patterns("__pycache__"))
    if not (site / "awr_denoise" / "cli").is_dir():  # a checkout: cli/ beside the package
        shutil.copytree(cli, site / "awr_denoise" / "cli", ignore=shutil.ignore_patterns("__pycache__"))
    return site
