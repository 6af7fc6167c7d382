"""Outputs of reconstruct, the samplers and the ``awr`` command against stored digests.

The digests in ``tests/data/regression_digests.json`` were made before the package was
restructured (docs/architecture.md); a change of structure must leave every one of them as it
is. A change meant to alter results regenerates them with
``python tests/data/regression_digests.py --write`` in the same commit.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"

pytest.importorskip("OpenEXR", reason="the command-line cases write EXR files (extra 'exr')")


def _digests_module():
    spec = importlib.util.spec_from_file_location("regression_digests", DATA / "regression_digests.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("regression_digests", module)
    spec.loader.exec_module(module)
    return module


def test_outputs_match_the_stored_digests() -> None:
    module = _digests_module()
    stored = json.loads(module.DIGESTS.read_text(encoding="utf-8"))
    computed = module.compute()
    assert set(computed) == set(stored)
    changed = sorted(name for name in stored if computed[name] != stored[name])
    assert not changed, f"outputs changed: {', '.join(changed)}"
