"""The fused float32 passes of stage 1: the numba kernels give the numpy reference's floats, bit for bit."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from awr_denoise import SampleRequest, fused, reconstruct
from awr_denoise.synthetic import SyntheticRenderer, make_scene

numba_missing = fused._compiled() is None
needs_numba = pytest.mark.skipif(numba_missing, reason="numba is not installed (extra 'fast')")


@pytest.fixture
def restore_backend():
    yield
    fused.set_backend(None)


def both(function, *arrays, **kwargs):
    """``function`` run with each backend on its own copies of ``arrays``: (result, the arrays after) per backend."""
    out = []
    for name in fused.BACKENDS:
        fused.set_backend(name)
        copies = [a.copy() if isinstance(a, np.ndarray) else a for a in arrays]
        out.append((function(*copies, **kwargs), [a for a in copies if isinstance(a, np.ndarray)]))
    fused.set_backend(None)
    return out


def assert_same(a, b):
    """Equal floats, the sign of zero included (``assert_array_equal`` takes -0.0 == 0.0)."""
    assert_array_equal(a, b)
    assert_array_equal(np.signbit(a), np.signbit(b))


def channel_planes(rng, shape=(37, 53), scale=1.0):
    """A channel of an (H, W, 3) mean and variance (strided views, as stage 1 passes them) and counts."""
    mean = scale * rng.standard_normal(shape + (3,)) * rng.lognormal(0.0, 2.0, shape + (3,))
    mean[0, :5, 1] = [0.0, -0.0, 1e-300, -1e-30, 5e-324]
    variance = scale * scale * rng.lognormal(0.0, 2.0, shape + (3,))
    variance[1, :3, 1] = 0.0
    count = rng.integers(1, 64, shape).astype(np.float32)
    return mean[:, :, 1], variance[:, :, 1], count


# -------------------------------------------------------------------------------- the choice
def test_the_reference_is_the_default_and_the_environment_or_set_backend_choose(monkeypatch, restore_backend):
    monkeypatch.delenv("AWR_DENOISE_KERNELS", raising=False)
    assert fused.backend() == "numpy"  # numba costs half a second per process: asked for, not assumed
    monkeypatch.setenv("AWR_DENOISE_KERNELS", " NumPy ")
    assert fused.backend() == "numpy"
    if not numba_missing:
        monkeypatch.setenv("AWR_DENOISE_KERNELS", "numba")
        assert fused.backend() == "numba"
        fused.set_backend("numpy")  # set_backend overrides the environment
        assert fused.backend() == "numpy"
        fused.set_backend(None)
        assert fused.backend() == "numba"
    monkeypatch.setenv("AWR_DENOISE_KERNELS", "cuda")
    with pytest.raises(ValueError, match="AWR_DENOISE_KERNELS: 'cuda' is not one of numpy, numba"):
        fused.backend()
    monkeypatch.setenv("AWR_DENOISE_KERNELS", " ")  # read as unset, it ran numpy where any other value is refused
    with pytest.raises(ValueError, match="AWR_DENOISE_KERNELS: '' is not one of numpy, numba"):
        fused.backend()
    with pytest.raises(ValueError, match="backend: 'cuda'"):
        fused.set_backend("cuda")
    assert fused.available() == (("numpy",) if numba_missing else ("numpy", "numba"))


def test_without_numba_asking_for_it_says_how_to_install(monkeypatch, restore_backend):
    monkeypatch.setattr(fused, "_compiled", lambda: None)  # as if numba were not installed
    assert fused.available() == ("numpy",)
    with pytest.raises(ImportError, match=r"awr-denoise\[fast\]"):
        fused.set_backend("numba")
    monkeypatch.setenv("AWR_DENOISE_KERNELS", "numba")
    with pytest.raises(ImportError, match=r"AWR_DENOISE_KERNELS: numba is not installed.*awr-denoise\[fast\]"):
        fused.backend()


@needs_numba
@pytest.mark.parametrize("variable, value", [("NUMBA_NUM_THREADS", ""), ("NUMBA_NUM_THREADS", "abc"),
                                             ("NUMBA_NUM_THREADS", "0"), ("NUMBA_NUM_THREADS", "-1"),
                                             ("NUMBA_OPT", "zz")])
def test_a_numba_variable_numba_cannot_read_is_named_before_any_work(tmp_path, variable, value):
    """With the compiled kernels asked for, numba reported an unreadable NUMBA_ variable in a warning holding a whole
    traceback and ran on (exit 0), or stopped naming no variable ("Number of threads specified must be > 0.", a
    red-team pass). One line naming it, exit 2, nothing written; asked again in the same process, the same error."""
    import os
    import subprocess
    import sys

    from awr_denoise import SampleBuffer
    from awr_denoise.io import write_sample_buffer

    dump = tmp_path / "d.exr"
    rng = np.random.default_rng(0)
    write_sample_buffer(dump, SampleBuffer.from_moments(np.full((8, 8), 4), rng.random((8, 8, 3)),
                                                        rng.random((8, 8, 3))))
    env = {**os.environ, "AWR_DENOISE_KERNELS": "numba", variable: value}
    command = [sys.executable, "-m", "awr_denoise.cli.main", "denoise", str(dump), "-o", str(tmp_path / "o.exr"), "-q"]
    run = subprocess.run(command, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert run.returncode == 2, run.stderr
    assert run.stderr.splitlines() == [run.stderr.strip()] and "Traceback" not in run.stderr
    assert f"{variable}={value!r}" in run.stderr and not (tmp_path / "o.exr").exists()
    code = ("from awr_denoise import fused\n"
            "for _ in range(2):\n"
            "    try:\n"
            "        fused.available()\n"
            "    except ValueError as exc:\n"
            "        print(exc)\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert run.stdout.count(f"{variable}={value!r}") == 2 and "Traceback" not in run.stderr, (run.stdout, run.stderr)


_RENDERER_WARNS_DURING_THE_IMPORT = """
import importlib.abc, sys, threading, warnings
warnings.filterwarnings("error", message="from the renderer")  # its caller's: a broken renderer is fatal
outcome = []

def renderer():
    try:
        warnings.warn("from the renderer")
        outcome.append("warned in its thread, not raised")
    except UserWarning:
        outcome.append("raised in its thread")

class WhileNumbaLoads(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name == "numba" and not outcome:
            thread = threading.Thread(target=renderer)
            thread.start()
            thread.join()
        return None

sys.meta_path.insert(0, WhileNumbaLoads())
from awr_denoise import fused
fused._numba()
print(outcome)
"""


@needs_numba
def test_another_threads_warning_while_numba_loads_stays_in_that_thread():
    """numba was imported inside ``warnings.catch_warnings(record=True)``, which replaces every thread's filters: a
    renderer thread's warning, which its caller's filter makes an error, was recorded instead and raised afterwards
    in the thread that asked for the kernels (an attack pass)."""
    import os
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-c", _RENDERER_WARNS_DURING_THE_IMPORT], capture_output=True, text=True,
                         env={**os.environ, "AWR_DENOISE_KERNELS": "numba"}, timeout=300)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "['raised in its thread']"


_ANOTHER_LIBRARY_AFTER_THE_REFUSAL = """
import warnings
from awr_denoise import fused
try:
    fused.set_backend("numba")
except ValueError as exc:
    print("refused")
with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # numba's own report of the variable, to its importer
    import numba
print(numba.njit(lambda x: x + 1)(1))
"""


@needs_numba
def test_a_refused_numba_variable_leaves_numba_whole_for_the_rest_of_the_process():
    """The refusal stopped numba's import half-way, and another library's ``import numba`` in the same process found
    a numba without its ``core`` (a review of the change)."""
    import os
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-c", _ANOTHER_LIBRARY_AFTER_THE_REFUSAL], capture_output=True, text=True,
                         env={**os.environ, "NUMBA_DISABLE_JIT": "zz"}, timeout=300)
    assert run.stdout.split() == ["refused", "2"], run.stderr


# ------------------------------------------------------------------------- kernel by kernel
@needs_numba
@pytest.mark.parametrize("k", [1e-3, 0.37, 1e4])
def test_log_plane_is_the_reference(rng, k):
    mean, variance, count = channel_planes(rng)
    (ref, _), (new, _) = both(fused.log_plane, mean, variance, count, k)
    assert new[0].dtype == new[1].dtype == np.float32
    assert_same(new[0], ref[0])
    assert_same(new[1], ref[1])


@needs_numba
@pytest.mark.parametrize("where", ["mean", "variance"])
def test_log_plane_refuses_what_float32_cannot_hold_like_the_reference(rng, where):
    mean, variance, count = channel_planes(rng)
    (mean if where == "mean" else variance)[3, 4] = 1e40  # beyond float32 once divided by k = 1
    (ref, _), (new, _) = both(fused.log_plane, mean, variance, count, 1.0)
    assert ref is None and new is None


@needs_numba
@pytest.mark.parametrize("c_s", [0.0, 0.5, 1.0, 3.0, 1e300])
def test_shrink_band_is_the_reference(rng, c_s):
    coeff = (rng.standard_normal((19, 27)) * rng.lognormal(0.0, 2.0, (19, 27))).astype(np.float32)
    coeff[0, :4] = [0.0, -0.0, 1e-38, -1e-38]
    variance = rng.lognormal(0.0, 2.0, (19, 27)).astype(np.float32)
    variance[1, :2] = 0.0
    (z_ref, (c_ref, t_ref)), (z_new, (c_new, t_new)) = both(fused.shrink_band, coeff, variance, c_s)
    assert z_new == z_ref
    assert_same(c_new, c_ref)
    assert_same(t_new, t_ref)
    if c_s == 1e300:  # infinite thresholds zero every coefficient but the exact ones (Delta = 0)
        assert_array_equal(c_new[variance > 0], 0.0)
        assert_same(c_new[variance == 0], coeff[variance == 0])


def test_shrink_band_on_a_strided_band_keeps_the_reference(rng, restore_backend):
    coeff = rng.standard_normal((12, 20)).astype(np.float32)
    variance = np.full((12, 20), 0.25, np.float32)
    expected, thresholds = np.sign(coeff) * np.maximum(np.abs(coeff) - 0.5, 0.0), np.full((12, 20), 0.5)
    for name in (("numpy",) if numba_missing else fused.BACKENDS):
        fused.set_backend(name)
        c, v = coeff.copy(), variance.copy()
        zeroed = fused.shrink_band(c[:, ::2], v[:, ::2], 1.0)  # non-contiguous: written in place all the same
        assert zeroed == int((np.abs(coeff[:, ::2]) <= 0.5).sum())
        np.testing.assert_allclose(c[:, ::2], expected[:, ::2], atol=1e-7)
        np.testing.assert_allclose(v[:, ::2], thresholds[:, ::2])
        assert_array_equal(c[:, 1::2], coeff[:, 1::2])


@needs_numba
@pytest.mark.parametrize("pixel_clamp", [None, 0.0, 2.0, 1e300])
@pytest.mark.parametrize("reach", ["ordinary", "overflowing"])
def test_finish_plane_is_the_reference(rng, pixel_clamp, reach):
    mean, variance, count = channel_planes(rng)
    fused.set_backend("numpy")
    y, var_y = fused.log_plane(mean, variance, count, 0.3)
    fused.set_backend(None)
    out = y + (0.3 * rng.standard_normal(y.shape)).astype(np.float32)
    if reach == "overflowing":  # |out| beyond float32 exp's range: the float64 expm1 path
        out[2, 2], out[3, 3] = 95.0, -750.0
        if pixel_clamp is not None:
            var_y[2, 2] = var_y[3, 3] = 1e30
    dest = np.full(mean.shape + (2,), np.nan)[:, :, 0]  # a strided float64 view, as stage 1 writes
    (_, ref), (_, new) = both(fused.finish_plane, dest, out, y, var_y, mean, 0.3, pixel_clamp)
    assert_same(new[0], ref[0])
    assert np.isfinite(new[0]).all()
    if pixel_clamp == 0.0:  # zero width everywhere: the means, bit for bit
        assert_same(new[0], mean)


# ------------------------------------------------------------------------------- end to end
@needs_numba
@pytest.mark.parametrize("spp", [1, 4, 64])
def test_stage_1_and_the_default_are_the_same_with_either_backend(spp, restore_backend):
    buffer = SyntheticRenderer(make_scene("edges", (45, 61)), seed=5)(SampleRequest.uniform((45, 61), spp))
    out = {}
    for name in fused.BACKENDS:
        fused.set_backend(name)
        out[name] = (reconstruct(buffer, stages=1), reconstruct(buffer, stages=1, pixel_clamp=None), reconstruct(buffer))
    for ref, new in zip(out["numpy"], out["numba"]):
        assert_same(new, ref)


@needs_numba
def test_kernels_run_on_two_threads(restore_backend):
    buffer = SyntheticRenderer(make_scene("gradient", (40, 48)), seed=2)(SampleRequest.uniform((40, 48), 8))
    fused.set_backend("numpy")
    ref = reconstruct(buffer, stages=1)
    fused.set_backend("numba")
    with ThreadPoolExecutor(2) as pool:
        assert_same(reconstruct(buffer, stages=1, executor=pool), ref)


@needs_numba
def test_kernels_compile_without_a_writable_cache(monkeypatch, restore_backend):
    import numba.core.dispatcher

    def refuse(self):
        raise RuntimeError("cannot cache function: no locator available")  # what numba says then

    monkeypatch.setattr(numba.core.dispatcher.Dispatcher, "enable_caching", refuse)
    fused._compiled.cache_clear()
    try:
        kernels = fused._compiled()
        coeff, variance = np.array([-3.0, 0.5], np.float32), np.array([1.0, 1.0], np.float32)
        assert kernels.shrink_band(coeff, variance, np.float32(1.0)) == 1
        assert_array_equal(coeff, [-2.0, 0.0])
    finally:
        fused._compiled.cache_clear()


def test_using_puts_back_the_choice_made_before_it_even_when_the_block_raises(restore_backend):
    fused.set_backend("numpy")
    with pytest.raises(ZeroDivisionError):
        with fused.using(fused.available()[-1]):
            assert fused.backend() == fused.available()[-1]
            1 / 0
    assert fused._chosen == "numpy"
    fused.set_backend(None)
    with fused.using("numpy"):
        pass
    assert fused._chosen is None  # the environment's choice again, not "numpy"


def test_another_threads_using_block_is_refused_while_one_runs(restore_backend):
    """Two threads' overlapping blocks each put back the other's choice, and the process kept one neither asked for."""
    import threading

    fused.set_backend("numpy")
    inside, leave, seen = threading.Event(), threading.Event(), []

    def holder():
        with fused.using(fused.available()[-1]):
            with fused.using("numpy"):  # nested in its own thread: fine
                pass
            inside.set()
            leave.wait(30)

    thread = threading.Thread(target=holder)
    thread.start()
    try:
        assert inside.wait(30)
        with pytest.raises(RuntimeError, match=r"^fused.using: another thread's block runs"):
            with fused.using("numpy"):
                seen.append("entered")
        with pytest.raises(RuntimeError, match=r"^fused.set_backend: another thread's block runs"):
            fused.set_backend(None)  # the block's end would put its own choice back over it
    finally:
        leave.set()
        thread.join()
    assert not seen and fused._chosen == "numpy" and fused._using is None
    with fused.using("numpy"):  # the block over, this thread's turn
        assert fused._using is not None
    assert fused._using is None


def test_a_loop_whose_cache_cannot_be_saved_is_compiled_again_without_it():
    """numba saves a loop's cache at its first call: a full disk there failed the command with "no space left on
    device", naming nothing (a red-team pass). The loop compiles again, uncached, and runs."""
    pytest.importorskip("numba")

    def twice(x):
        return 2.0 * x

    loop = fused.compile_loop(twice)

    def full_disk(*args):
        raise OSError(28, "No space left on device")
    loop.run = full_disk
    assert loop(1.5) == 3.0
    assert loop.run is not full_disk and loop(2.0) == 4.0
