"""Shared test configuration: the slow marker, fixed seeds and tolerance constants."""

from __future__ import annotations

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
