"""Outputs of reconstruct, the samplers and the ``awr`` command against stored outputs.

``tests/data/regression_outputs.npz`` holds them (docs/architecture.md); a change of structure
must leave every one of them as it is, to the tolerances of ``tests/data/regression_outputs.py``.
A change meant to alter results regenerates them with
``python tests/data/regression_outputs.py --write`` in the same commit.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from awr_denoise import reconstruct
from awr_denoise.reconstruct import DEFAULT_PILOT_C_S

DATA = Path(__file__).parent / "data"

pytest.importorskip("OpenEXR", reason="the command-line cases write EXR files (extra 'exr')")


def _outputs_module():
    spec = importlib.util.spec_from_file_location("regression_outputs", DATA / "regression_outputs.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("regression_outputs", module)
    spec.loader.exec_module(module)
    return module


def test_outputs_match_the_stored_outputs() -> None:
    module = _outputs_module()
    stored = module.load()
    computed = module.compute()
    assert set(computed) == set(stored)
    changed = [why for name in sorted(stored) if (why := module.deviation(name, computed[name], stored[name]))]
    assert not changed, "outputs changed: " + "; ".join(changed)


def test_the_comparison_catches_a_change_of_default() -> None:
    """A pilot threshold 10% off the default moves the staged output far beyond its tolerance."""
    module = _outputs_module()
    buffer = module._uniform("edges")
    stored = module.load()["stages_edges"]
    assert module.deviation("stages_edges", module.arrays(reconstruct(buffer)), stored) is None
    moved = module.arrays(reconstruct(buffer, c_s=1.1 * DEFAULT_PILOT_C_S))
    assert module.deviation("stages_edges", moved, stored) is not None
