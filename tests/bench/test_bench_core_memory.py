"""``benchmarks/bench_core.py --keep-freed-memory``: the sections in the memory setting of the ``awr`` command."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_core.py"


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_core")


def _glibc_unset() -> dict[str, str]:
    """The environment without a user's allocator settings, under which the setting applies on glibc."""
    return {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}


def _applies() -> bool:
    """Whether the setting can apply in a new process here (asked there: it would change this one's allocator)."""
    code = "from awr_denoise.memory import keep_freed_memory; print(keep_freed_memory())"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=_glibc_unset(), check=True)
    return run.stdout.strip() == "True"


@pytest.mark.parametrize("keep", [False, True])
def test_the_run_records_the_memory_setting_it_ran_in(tmp_path, keep):
    if keep and not _applies():
        pytest.skip("the memory setting does not apply here (not glibc, or an address-space limit)")
    out = tmp_path / "core.json"
    argv = [sys.executable, str(SCRIPT), "--quick", "--only", "fft_budget", "--output", str(out)]
    subprocess.run(argv + (["--keep-freed-memory"] if keep else []), capture_output=True, text=True,
                   env=_glibc_unset(), check=True, cwd=tmp_path)
    results = json.loads(out.read_text())
    assert results["keep_freed_memory"] is keep
    assert ("--keep-freed-memory" in results["command"]) is keep


def test_a_setting_that_cannot_apply_is_refused_not_recorded(tmp_path):
    out = tmp_path / "core.json"
    env = {**_glibc_unset(), "MALLOC_ARENA_MAX": "2"}  # a user's own allocator setting, which the function keeps
    run = subprocess.run([sys.executable, str(SCRIPT), "--quick", "--only", "fft_budget", "--output", str(out),
                          "--keep-freed-memory"], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert run.returncode == 2 and "--keep-freed-memory" in run.stderr and not out.exists()


def test_the_memory_children_run_in_the_same_setting(bench, monkeypatch):
    seen = []

    def run(argv, **kwargs):
        seen.append(argv)
        return SimpleNamespace(stdout=json.dumps({"maxrss": 1}))

    monkeypatch.setattr(bench.subprocess, "run", run)
    for kept in (False, True):
        monkeypatch.setitem(bench._KEPT, "kept", kept)
        bench._memory("256x256", "ask")
        assert ("--keep-freed-memory" in seen[-1]) is kept
        assert seen[-1][seen[-1].index("--memory-child") + 1:][:2] == ["256x256", "ask"]

