"""A terminating signal while Mitsuba loads is held until it has loaded, then acted on."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
import types
from collections.abc import Iterator

import pytest

from awr_denoise.adapters import _mitsuba_runtime

# A stand-in for ``import mitsuba`` that is hit by SIGTERM in the middle of its import.
_FAKE_MITSUBA = """
import os, signal
os.kill(os.getpid(), signal.SIGTERM)
for _ in range(1000):  # Python runs a signal's handler at the next bytecodes: they come here
    pass
LOADED = True
_active = None


def variants():
    return ["llvm_ad_rgb"]


def variant():
    return _active


def set_variant(name):
    global _active
    os.kill(os.getpid(), signal.SIGTERM)
    for _ in range(1000):
        pass
    _active = name
"""


class _Stop(BaseException):
    pass


@contextlib.contextmanager
def _sigterm_noted(seen: list[object], state) -> Iterator[None]:
    """SIGTERM raises after noting ``state()`` at its arrival; later ones are ignored (as on the command line)."""

    def handler(signum, frame):
        seen.append(state())
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise _Stop

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@pytest.fixture
def fake_mitsuba(tmp_path, monkeypatch):
    """``import mitsuba`` and ``drjit`` as stand-ins that signal the process while they load."""
    (tmp_path / "mitsuba.py").write_text(_FAKE_MITSUBA)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "mitsuba", raising=False)
    backend = types.SimpleNamespace(LLVM="llvm", CUDA="cuda")
    monkeypatch.setitem(sys.modules, "drjit", types.SimpleNamespace(JitBackend=backend, has_backend=lambda b: True))
    yield
    sys.modules.pop("mitsuba", None)


@pytest.mark.skipif(not hasattr(signal, "SIGTERM") or os.name != "posix", reason="POSIX signals")
def test_a_signal_while_mitsuba_is_imported_is_acted_on_once_it_has_loaded(fake_mitsuba):
    """The handler's exception was raised inside ``import mitsuba`` (a nanobind callback there) and
    ``set_variant``: the process aborted or crashed at exit instead of exiting 143 with one line."""
    seen: list[object] = []

    def state():
        module = sys.modules.get("mitsuba")
        return getattr(module, "LOADED", False) and module.variant()

    with _sigterm_noted(seen, state), pytest.raises(_Stop):
        _mitsuba_runtime.import_mitsuba()
    assert seen == ["llvm_ad_rgb"]  # imported, the variant set, then the one signal acted on


@pytest.mark.skipif(not hasattr(signal, "SIGTERM") or os.name != "posix", reason="POSIX signals")
def test_a_signal_while_the_variant_switches_is_acted_on_after_the_switch():
    seen: list[object] = []
    active = ["scalar_rgb"]

    def set_variant(name):
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):  # where the handler ran before
            pass
        active[0] = name

    mi = types.SimpleNamespace(variant=lambda: active[0], set_variant=set_variant)
    with _sigterm_noted(seen, lambda: active[0]), pytest.raises(_Stop):
        with _mitsuba_runtime.variant_scope(mi, "llvm_ad_rgb"):
            pass
    assert seen == ["llvm_ad_rgb"]
    assert active == ["scalar_rgb"]  # the caller's variant is back


_MESSAGES = {signal.SIGTERM: "awr: terminated", signal.SIGINT: "awr: interrupted"}


@pytest.mark.slow
@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_while_the_command_loads_mitsuba_exits_with_one_line(tmp_path, signum, mi, signals_at_default):
    """``awr render --renderer mitsuba`` signalled at moments around Mitsuba's import (380-510 ms
    after its start on the development machine, where 3 of 28 runs died of SIGABRT or SIGSEGV)."""
    command = [sys.executable, "-c", "import sys; from awr_denoise.cli.main import main; sys.exit(main())",
               "render", "--renderer", "mitsuba", "cornell_box", "--spp", "256", "-o", "r.exr", "-q"]
    bad = []
    for ms in range(300, 620, 20):
        proc = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.PIPE, text=True, preexec_fn=signals_at_default)
        time.sleep(ms / 1000)
        proc.send_signal(signum)
        code = proc.wait(timeout=120)
        err = proc.stderr.read()
        proc.stderr.close()
        if code == 0:  # finished before the signal: the sweep is past Mitsuba's load on this machine
            continue
        if (code, err.strip()) != (128 + signum, _MESSAGES[signum]):
            bad.append((ms, code, err[-500:]))
    assert bad == []
    # Nothing from a signalled run (no staging folder); the outputs of one that finished, all of them.
    assert sorted(os.listdir(tmp_path)) in ([], ["r.denoised.exr", "r.denoised.png", "r.exr"])
