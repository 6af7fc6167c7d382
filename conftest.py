"""Collection rules for the docstring examples (``--doctest-modules`` in ``pyproject.toml``).

Every ``Examples`` section of the package runs as a doctest; files outside the package (the
tests, their helpers and data scripts) are collected as tests only. Modules whose examples need
an optional extra that is not installed are left out of collection instead of failing (the
header of the run names them); ``pip install -e ".[all]"`` collects everything. The extras
are looked up, never imported, so leaving a module out costs nothing.
"""

from __future__ import annotations

import importlib.util
from functools import lru_cache
from pathlib import Path

import pytest
from _pytest.doctest import DoctestModule  # the doctest plugin's collector, told apart from test modules

_ROOT = Path(__file__).resolve().parent
_PACKAGE = _ROOT / "awr_denoise"

# Path inside the repository (a module, or a package directory) -> the modules its examples need.
# A module is listed when importing it or running its examples needs the extra; io modules
# import OpenEXR lazily but their examples write and read EXR files.
_NEEDS: dict[str, tuple[str, ...]] = {
    "awr_denoise/tracer": ("embreex",),
    "awr_denoise/adapters/mitsuba.py": ("mitsuba",),
    "awr_denoise/adapters/mitsuba_scenes.py": ("mitsuba",),
    "awr_denoise/bench": ("matplotlib", "skimage"),
    "awr_denoise/io/deep.py": ("OpenEXR",),
    "awr_denoise/io/describe.py": ("OpenEXR",),
    "awr_denoise/io/dump.py": ("OpenEXR",),
    "awr_denoise/io/exr.py": ("OpenEXR",),
    "awr_denoise/io/request_map.py": ("OpenEXR",),
}


def _missing(modules: tuple[str, ...]) -> list[str]:
    return [name for name in modules if importlib.util.find_spec(name) is None]


@lru_cache(maxsize=1)  # asked once per collected path; the installed extras do not change
def _left_out() -> dict[str, list[str]]:
    """Listed paths whose extra is missing, with the missing modules."""
    out = {}
    for rel, modules in _NEEDS.items():
        missing = _missing(modules) if (_ROOT / rel).exists() else []
        if missing:
            out[rel] = missing
    return out


def pytest_report_header(config: pytest.Config) -> list[str]:
    left_out = _left_out()
    if not getattr(config.option, "doctestmodules", False) or not left_out:
        return []
    return ["doctests left out, extra not installed: "
            + "; ".join(f"{rel} (needs {', '.join(missing)})" for rel, missing in left_out.items())]


@pytest.hookimpl(wrapper=True)
def pytest_collect_file(file_path: Path, parent: pytest.Collector):
    collectors = yield
    if _PACKAGE in Path(file_path).resolve().parents:
        return collectors
    # Outside the package a doctest collector would import every test module a second time (and
    # report its skip twice) and import scripts such as tests/data/external_renderer.py, which
    # needs OpenEXR at the top. None of them holds examples.
    return [c for c in collectors if not isinstance(c, DoctestModule)]


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    if not getattr(config.option, "doctestmodules", False):
        return None
    path = Path(collection_path).resolve()
    # ``python -m`` entry points run a program when imported; they hold no examples.
    if path.name == "__main__.py":
        return True
    try:
        rel = path.relative_to(_ROOT).as_posix()
    except ValueError:
        return None
    for listed, missing in _left_out().items():
        if rel == listed or rel.startswith(listed + "/"):
            return True
    return None
