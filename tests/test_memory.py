"""A process keeps freed memory for its next arrays when asked (awr_denoise/memory.py); the awr command asks."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from awr_denoise import memory

_GLIBC = hasattr(os, "confstr") and (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc")
pytestmark = pytest.mark.skipif(not _GLIBC, reason="mallopt is glibc's")

_SECOND_ARRAY_FAULTS = """
import resource, sys
import numpy as np
from awr_denoise import memory
if sys.argv[1] == "library":  # the library and the command's modules imported, nothing called
    import awr_denoise.cli.main, awr_denoise.io, awr_denoise.reconstruct, awr_denoise.sampling
print(memory.keep_freed_memory() if sys.argv[1] == "keep" else False)
np.ones(8 << 20).sum()  # 64 MiB, above glibc's default mmap threshold
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
np.ones(8 << 20).sum()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _second_array_faults(mode: str) -> tuple[str, int]:
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("MALLOC_") and k not in ("GLIBC_TUNABLES", "LD_PRELOAD")}
    out = subprocess.run([sys.executable, "-c", _SECOND_ARRAY_FAULTS, mode], capture_output=True, text=True, env=env,
                         check=True).stdout.split()
    return out[0], int(out[1])


def test_a_freed_whole_image_array_is_reused_not_mapped_afresh():
    """64 MiB freed and asked for again: mapped afresh, its 16384 pages (or 32 huge ones) fault in again."""
    kept, faults_kept = _second_array_faults("keep")
    default, faults_default = _second_array_faults("default")
    assert (kept, default) == ("True", "False")
    assert faults_kept < 16 <= faults_default


def test_importing_the_library_leaves_the_allocator_alone():
    """The allocator is the host process': only a call changes it (awr's main makes one, its import none)."""
    kept, faults = _second_array_faults("library")
    assert kept == "False" and faults >= 16


@pytest.mark.parametrize("setting", [("MALLOC_MMAP_THRESHOLD_", "65536"), ("MALLOC_MMAP_MAX_", "0"),
                                     ("LD_PRELOAD", "libjemalloc.so.2"),
                                     ("GLIBC_TUNABLES", "glibc.malloc.trim_threshold=0")])
def test_a_users_allocator_settings_are_left_alone(monkeypatch, setting):
    monkeypatch.setenv(*setting)
    assert memory.keep_freed_memory() is False


def test_an_address_space_limit_is_left_to_mappings(monkeypatch):
    resource = pytest.importorskip("resource")
    monkeypatch.setattr(resource, "getrlimit", lambda which: (1 << 33, resource.RLIM_INFINITY))
    assert memory.keep_freed_memory() is False
