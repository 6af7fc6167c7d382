"""The layering of docs/architecture.md, read from the source: who may import whom.

Every import counts, at the top of a module or inside a function, absolute or relative, so a
lazy import cannot hide a dependency the layering forbids.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "awr_denoise"
CLI = ROOT / "cli"  # installed as awr_denoise.cli

# Subpackages of awr_denoise a part may never import, by part.
FORBIDDEN = {
    "core": {"tracer", "io", "bench", "parallel", "adapters", "cli"},
    "io": {"tracer", "bench", "parallel", "adapters", "cli"},
    "tracer": {"bench", "parallel", "adapters", "cli"},
    "adapters": {"tracer", "bench", "parallel", "cli"},
    "parallel": {"bench", "cli"},
    "bench": {"cli"},
}

CORE_MODULE_LINES = 550  # the most a core module may have (one concept per module)


def _module_name(path: Path) -> str:
    if path.is_relative_to(CLI):
        parts = ["awr_denoise", "cli", *path.relative_to(CLI).with_suffix("").parts]
    else:
        parts = ["awr_denoise", *path.relative_to(PACKAGE).with_suffix("").parts]
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _part(path: Path) -> str:
    """The part a file belongs to: ``core`` (``awr_denoise/*.py``), ``cli`` or a subpackage."""
    if path.is_relative_to(CLI):
        return "cli"
    relative = path.relative_to(PACKAGE).parts
    return "core" if len(relative) == 1 else relative[0]


def _sources() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py")) + sorted(CLI.rglob("*.py"))


def _is_package(path: Path) -> bool:
    return path.name == "__init__.py"


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file, relative ones resolved."""
    name = _module_name(path)
    package = name if _is_package(path) else name.rpartition(".")[0]
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.append((node.lineno, target))
            # ``from . import tracer`` imports a subpackage by name.
            found += [(node.lineno, f"{target}.{alias.name}") for alias in node.names]
    return [(line, module) for line, module in found if module.startswith("awr_denoise")]


def _subpackage(module: str) -> str | None:
    pieces = module.split(".")
    return pieces[1] if len(pieces) > 1 else None


def test_the_parts_import_only_what_the_layering_allows() -> None:
    violations = []
    for path in _sources():
        part = _part(path)
        forbidden = FORBIDDEN.get(part, set())
        for line, target in imported_modules(path):
            sub = _subpackage(target)
            if sub in forbidden:
                violations.append(f"{path.relative_to(ROOT)}:{line} ({part}) imports {target}")
    assert not violations, "\n".join(violations)


def test_the_import_reader_sees_every_kind_of_import(tmp_path) -> None:
    """The check above would be blind without this: inside functions, relative and aliased."""
    probe = PACKAGE / "io" / "_probe_for_test.py"
    probe.write_text("def f():\n    from ..tracer import scene\n    import awr_denoise.bench as b\n"
                     "from . import exr\n", encoding="utf-8")
    try:
        modules = {m for _, m in imported_modules(probe)}
    finally:
        probe.unlink()
    assert {"awr_denoise.tracer", "awr_denoise.bench", "awr_denoise.io.exr"} <= modules


@pytest.mark.parametrize("path", sorted(PACKAGE.glob("*.py")), ids=lambda p: p.name)
def test_core_modules_stay_small(path: Path) -> None:
    lines = len(path.read_text(encoding="utf-8").splitlines())
    assert lines <= CORE_MODULE_LINES, f"{path.name}: {lines} lines; split it by concept"
