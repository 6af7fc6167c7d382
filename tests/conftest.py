"""Shared test configuration: the slow marker, fixed seeds, tolerance constants, a started Mitsuba."""

from __future__ import annotations

import os

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
