"""Fixtures of the adapter tests: start Mitsuba, or skip (fail when AWR_REQUIRE_MITSUBA is set, as in CI)."""

from __future__ import annotations

import os

import pytest

from awr_denoise.adapters._mitsuba_runtime import import_mitsuba


def start_mitsuba():
    """``(mitsuba, drjit)`` in the default variant, or skip the test with the reason."""
    try:
        return import_mitsuba()
    except (ImportError, RuntimeError) as exc:
        if os.environ.get("AWR_REQUIRE_MITSUBA"):
            pytest.fail(f"AWR_REQUIRE_MITSUBA is set but Mitsuba cannot start: {exc}")
        pytest.skip(f"Mitsuba 3 cannot start here: {exc}")


@pytest.fixture(scope="session")
def mi():
    return start_mitsuba()[0]
