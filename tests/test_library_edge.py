"""The library's edge (awr_denoise/_checks.py and every public function that uses it).

Public functions raise ``ValueError`` or ``TypeError`` whose message names the parameter for
bad values (NaN, Inf, out of range, not whole, bools or strings where numbers are expected),
never another exception, a hang, or a numpy warning (pytest runs with ``-W error``); valid
extremes (means near 1e-310 or 1e300) are accepted.

One table lists every numeric or named parameter with the kind of value it takes; hypothesis
draws bad values of that kind for each, and a fixed list of classic bad values runs on all.
"""

from __future__ import annotations

import math
import signal
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
import pywt
from numpy.testing import assert_array_equal
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from awr_denoise import (
    AdaptiveSampler,
    Domain,
    SampleBuffer,
    SampleRequest,
    UniformSampler,
    VarianceSampler,
    allocate,
    luminance_weights,
    reconstruct,
    reconstruct_detailed,
)
from awr_denoise import metrics, priorities, synthetic, wavelets
from awr_denoise.buffers import default_channel_names
from awr_denoise.io.png import tonemap_srgb
from awr_denoise.domains import DOMAIN_NAMES
from awr_denoise.parallel import get_executor, halo_width, reconstruct_tiled, tile_grid
from awr_denoise.prepare import prepare
from awr_denoise.projection import project
from awr_denoise.reconstruct import MODES, PRECISIONS
from awr_denoise.sampling import NOISE_MODELS
from awr_denoise.stationary import DTYPES, StationaryTransform
from awr_denoise.wavelets import WAVELET_NAMES
from awr_denoise.wiener import stage_weights

H, W = 16, 16
_rng = np.random.default_rng(0)
BUF = SampleBuffer.from_moments(np.full((H, W), 4), 0.5 + 0.1 * _rng.random((H, W, 3)), np.full((H, W, 3), 0.01))
_T = StationaryTransform((H, W), levels=2)
IMG = _rng.random((H, W, 3))


@dataclass(frozen=True)
class Param:
    """One parameter of one public call: ``call(value)`` runs it with that value."""

    name: str
    kind: str
    call: Callable[[object], object]
    none: bool = False  # None is a good value (a default)
    choices: tuple[str, ...] = ()  # the good values of a name

    def __repr__(self) -> str:
        return self.name


# Kinds: what a parameter accepts. Everything outside is bad.
#   real>=0 / real>0 / real: finite floats (non-negative, positive, any)
#   int>=0 / int>=1: whole numbers (floats only when whole) within 64 bits
#   size>=0 / size>=1: whole numbers of pixels, any size (a tile or halo beyond the image is the image)
#   seed: whole numbers 0..2**63-1
#   name: a str from a fixed list
#   flag: True or False
PARAMS = [
    Param("c_s", "real>=0", lambda v: reconstruct(BUF, c_s=v), none=True),
    Param("stages", "int>=1", lambda v: reconstruct(BUF, stages=v)),
    Param("wiener_exponents", "fraction", lambda v: reconstruct(BUF, stages=2, wiener_exponents=(v,))),
    Param("preserve_mean", "flag", lambda v: reconstruct(BUF, preserve_mean=v), none=True),
    Param("nonnegative", "flag", lambda v: reconstruct(BUF, nonnegative=v), none=True),
    Param("precision", "name", lambda v: reconstruct(BUF, stages=2, precision=v), choices=PRECISIONS),
    Param("dtype", "name", lambda v: StationaryTransform((8, 8), dtype=v), choices=DTYPES),
    Param("workers", "int>=1", lambda v: StationaryTransform((8, 8), workers=v)),
    Param("levels", "int>=1", lambda v: StationaryTransform((8, 8), levels=v), none=True),
    Param("k", "real>0", lambda v: stage_weights(np.ones(3), v, 1.0)),
    Param("exponent", "fraction", lambda v: stage_weights(np.ones(3), 1.0, v)),
    Param("pixel_clamp", "real>=0", lambda v: reconstruct(BUF, pixel_clamp=v), none=True),
    Param("levels", "int>=1", lambda v: reconstruct(BUF, levels=v), none=True),
    Param("variance_probes", "int>=0", lambda v: reconstruct_detailed(BUF, variance_probes=v)),
    Param("seed", "seed", lambda v: reconstruct_detailed(BUF, variance_probes=1, seed=v)),
    Param("wavelet", "name", lambda v: reconstruct(BUF, wavelet=v), choices=WAVELET_NAMES),
    Param("mode", "name", lambda v: reconstruct(BUF, mode=v), choices=MODES),
    Param("boundary", "name", lambda v: reconstruct(BUF, boundary=v), choices=tuple(pywt.Modes.modes)),
    Param("domain", "name", lambda v: reconstruct(BUF, domain=v), choices=DOMAIN_NAMES),
    Param("guide_projection", "fraction", lambda v: reconstruct(BUF, guide=BUF.mean, guide_projection=v), none=True),
    Param("offset", "real>0", lambda v: project(_T, BUF.mean, BUF.variance, BUF.mean, offset=v)),
    Param("radius", "real>=0", lambda v: project(_T, BUF.mean, BUF.variance, BUF.mean, offset=0.1, radius=v)),
    Param("exponent", "fraction", lambda v: project(_T, BUF.mean, BUF.variance, BUF.mean, offset=0.1, exponent=v)),
    Param("offset", "real>0", lambda v: Domain("log", offset=v)),
    Param("gamma", "real>=1", lambda v: Domain("gamma", gamma=v)),
    Param("scale", "real>0", lambda v: Domain("log", scale=v), none=True),
    Param("robust", "flag", lambda v: Domain("log", robust=v)),
    Param("initial_spp", "int>=0", lambda v: AdaptiveSampler((H, W), initial_spp=v)),
    Param("seed", "seed", lambda v: AdaptiveSampler((H, W), seed=v)),
    Param("spp_min", "int>=0", lambda v: UniformSampler((H, W), spp_min=v), none=True),
    Param("spp_max", "int>=1", lambda v: UniformSampler((H, W), spp_max=v), none=True),
    Param("round_spp", "real>0", lambda v: UniformSampler((H, W), round_spp=v), none=True),
    Param("round_growth", "real>0", lambda v: UniformSampler((H, W), round_growth=v)),
    Param("level_weight", "real>=0", lambda v: AdaptiveSampler((H, W), level_weight=v, noise_model="levels"),
          none=True),
    Param("noise_model", "name", lambda v: AdaptiveSampler((H, W), noise_model=v), choices=NOISE_MODELS),
    Param("absolute_above", "real>0", lambda v: AdaptiveSampler((H, W), absolute_above=v), none=True),
    Param("absolute_above", "real>0", lambda v: VarianceSampler((H, W), absolute_above=v), none=True),
    Param("absolute_above", "real>0", lambda v: priorities.pooled_deviation(BUF, absolute_above=v), none=True),
    Param("uniform_fraction", "fraction", lambda v: VarianceSampler((H, W), uniform_fraction=v)),
    Param("shape", "int>=1", lambda v: UniformSampler((v, W))),
    Param("budget", "int>=0", lambda v: UniformSampler.from_buffer(BUF).ask(v), none=True),
    Param("round", "int>=0", lambda v: UniformSampler.from_buffer(BUF, round=v)),
    Param("total_spp", "real>=0", lambda v: UniformSampler((4, 4)).run(
        synthetic.create_renderer("gradient", shape=(4, 4)), total_spp=v), none=True),
    Param("seconds", "real>0", lambda v: UniformSampler((4, 4)).run(
        synthetic.create_renderer("gradient", shape=(4, 4)), total_spp=8, seconds=v), none=True),
    Param("budget", "int>=0", lambda v: allocate(np.ones((H, W)), np.zeros((H, W), np.int64), v)),
    Param("spp", "int>=0", lambda v: SampleRequest.uniform((H, W), v)),
    Param("first_index", "int>=0", lambda v: SampleRequest.uniform((H, W), 1, first_index=v)),
    Param("round", "int>=0", lambda v: SampleRequest.uniform((H, W), 1, round=v)),
    Param("shape", "int>=1", lambda v: SampleBuffer.empty((v, W))),
    Param("channels", "int>=1", lambda v: SampleBuffer.empty((H, W), channels=v)),
    Param("n_channels", "int>=0", lambda v: default_channel_names(v)),
    Param("count", "int>=0", lambda v: SampleBuffer.from_moments(np.full((H, W), v), IMG, IMG)),
    Param("mean", "real", lambda v: SampleBuffer.from_moments(np.full((H, W), 4), np.full((H, W, 3), v), IMG)),
    Param("variance", "real>=0", lambda v: SampleBuffer.from_moments(np.full((H, W), 4), IMG, np.full((H, W, 3), v))),
    Param("values", "real", lambda v: SampleBuffer.from_samples(np.array([0, 1]), np.full(2, v), (1, 2))),
    Param("features", "real", lambda v: SampleBuffer.from_samples(np.array([0, 1]), np.ones(2), (1, 2),
                                                                  features={"depth": np.full(2, v)})),
    Param("eps", "real>=0", lambda v: metrics.relmse(IMG, IMG + 0.1, eps=v)),
    Param("peak", "real>0", lambda v: metrics.psnr(IMG, IMG + 0.1, peak=v), none=True),
    Param("exposure", "real", lambda v: metrics.ssim(IMG, IMG + 0.1, exposure=v)),
    Param("sigma", "real>0", lambda v: metrics.ssim(IMG, IMG + 0.1, sigma=v)),
    Param("exposure", "real", lambda v: metrics.tonemap(IMG, exposure=v)),
    Param("exposure", "real", lambda v: tonemap_srgb(IMG, exposure=v)),
    Param("image", "real", lambda v: metrics.mse(np.full((4, 4), v), np.ones((4, 4)))),
    Param("shape", "int>=0", lambda v: wavelets.max_levels((v, 8))),
    Param("shape", "int>=1", lambda v: wavelets.wavelet_operators((v, 8))),
    Param("image", "real", lambda v: wavelets.forward(np.full((8, 8), v))),
    Param("variance_of_mean", "real>=0", lambda v: wavelets.coefficient_variance(np.full((8, 8), v))),
    Param("level_weight", "real>=0", lambda v: priorities.sampling_density(BUF, level_weight=v)),
    Param("luminance", "flag", lambda v: prepare(BUF, luminance=v)),
    Param("shape", "int>=1", lambda v: synthetic.make_scene("gradient", (v, 8))),
    Param("supersampling", "int>=1", lambda v: synthetic.make_scene("gradient", (4, 4)).reference(v)),
    Param("seed", "seed", lambda v: synthetic.hash_uniform(v, np.arange(3), np.arange(3), 0)),
    Param("seed", "seed", lambda v: synthetic.create_renderer("gradient", shape=(4, 4), seed=v)),
    Param("workers", "int>=1", lambda v: get_executor("threads", workers=v).__enter__(), none=True),
    Param("tile", "size>=1", lambda v: tile_grid((16, 16), v)),
    Param("levels", "int>=1", lambda v: halo_width(levels=v)),
    Param("halo", "size>=0", lambda v: reconstruct_tiled(BUF, tile=8, halo=v), none=True),
    Param("channels", "names", lambda v: luminance_weights(v)),
]

# Classic bad values of each kind: NaN, infinities, signs, huge and fractional numbers, bools, strings, None.
CLASSIC = [float("nan"), float("inf"), -float("inf"), np.float64("nan"), -1, -1e-300, 1e300, 2**70, -(2**70), 1.5,
           True, False, "1", "", None, 1 + 2j]


def _acceptable(kind: str, v: object) -> bool:
    """Whether ``v`` is a good value of ``kind`` (the complement of what must be refused)."""
    if kind == "flag":
        return isinstance(v, (bool, np.bool_))
    if kind == "names":
        return False  # only lists of names are good; none is drawn
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
        return False
    x = float(v) if not isinstance(v, int) or abs(v) < 2**1000 else math.inf
    if not math.isfinite(x):
        return False
    if kind.startswith(("int", "size")) or kind == "seed":
        if x != math.floor(x):
            return False
        top = 2**63 - 1 if kind == "seed" else math.inf if kind.startswith("size") else 2**62
        low = 1 if kind.endswith(">=1") else 0
        return low <= x <= top
    low = {"real>=0": 0.0, "real>0": 0.0, "real>=1": 1.0, "fraction": 0.0}.get(kind, -math.inf)
    if kind == "real>0":
        return x > 0
    if kind == "fraction":
        return 0.0 <= x <= 1.0
    return x >= low


class _Hang(Exception):
    pass


def _refuses(param: Param, value: object) -> None:
    """``param.call(value)`` must raise ValueError or TypeError naming the parameter, in time."""
    def expired(signum, frame):
        raise _Hang(f"{param.name}={value!r}: no answer in 20 s")
    previous = signal.signal(signal.SIGALRM, expired)
    signal.alarm(20)
    try:
        with pytest.raises((ValueError, TypeError)) as caught:
            param.call(value)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    message = str(caught.value)
    named = param.name in message or (param.name == "name" and "domain" in message) or (
        param.name in ("offset", "gamma", "scale", "robust") and "domain" in message)
    assert named, f"{param.name}={value!r}: {type(caught.value).__name__}: {message}"
    assert "\n" not in message, f"{param.name}: a message of more than one line: {message!r}"


def _good(param: Param, value: object) -> bool:
    if param.kind == "name":
        return isinstance(value, str) and value in param.choices
    return (value is None and param.none) or _acceptable(param.kind, value)


CLASSIC_CASES = [(p, v) for p in PARAMS for v in CLASSIC if not _good(p, v)]


@pytest.mark.parametrize(("param", "value"), CLASSIC_CASES,
                         ids=[f"{i}-{p.name}-{v!r}"[:60] for i, (p, v) in enumerate(CLASSIC_CASES)])
def test_classic_bad_values_are_refused_naming_the_parameter(param, value):
    _refuses(param, value)


BAD_NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**80), max_value=2**80),
    st.booleans(),
    st.text(max_size=4),
    st.none(),
)


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(param=st.sampled_from([p for p in PARAMS if p.kind not in ("name", "names", "flag")]), value=BAD_NUMBERS)
def test_any_bad_number_is_refused_naming_the_parameter(param, value):
    if _good(param, value):
        return  # a good value: covered by the modules' own tests
    _refuses(param, value)


@settings(max_examples=100, deadline=None, derandomize=True)
@given(param=st.sampled_from([p for p in PARAMS if p.kind in ("name", "flag")]),
       value=st.one_of(st.text(max_size=6), st.integers(), st.floats(), st.none(), st.booleans()))
def test_any_bad_name_or_flag_is_refused_naming_the_parameter(param, value):
    if _good(param, value):
        return
    _refuses(param, value)


NUMBER_PARAMS = [p for p in PARAMS if p.kind not in ("name", "names", "flag")]
ARRAY_FILLED = {"count", "mean", "variance", "values", "features", "image", "variance_of_mean"}  # np.full(.., v)
_GOOD = {"real>=0": 0.5, "real>0": 0.5, "real": 0.5, "real>=1": 1.5, "fraction": 0.5, "int>=0": 2, "int>=1": 2,
         "size>=0": 2, "size>=1": 2, "seed": 2}


@pytest.mark.parametrize("param", NUMBER_PARAMS, ids=[f"{i}-{p.name}" for i, p in enumerate(NUMBER_PARAMS)])
def test_a_zero_dimensional_array_is_its_number(param):
    """``ask(np.array(16))`` was "expected an integer, got array(16)": a 0-d array (what np.asarray
    of a number or a reduction with ``out=`` gives) is taken as its number wherever one is taken, and
    a 0-d array of a bad value, a 1-element array and a masked number are refused in one line."""
    good = _GOOD[param.kind]
    param.call(np.array(good))
    bads = [np.array(np.nan), np.array(True), np.array(-(2**70))]
    for bad in bads + ([] if param.name in ARRAY_FILLED else [np.ones(100), np.ma.array(good)]):
        if not _good(param, bad[()] if bad.ndim == 0 and not np.ma.isMaskedArray(bad) else bad):
            _refuses(param, bad)


# ------------------------------------------------------------------ valid extremes

SCALES = [5e-324, 1e-318, 1e-310, 1e-300, 1e-30, 1.0, 1e30, 1e300, 1e307]
DOMAINS = ["log", "linear", "gamma", Domain("log", robust=True)]


def _extreme_buffer(scale: float, spread: float) -> SampleBuffer:
    rng = np.random.default_rng(3)
    mean = scale * (1 + 0.1 * rng.random((16, 16, 3)))
    with np.errstate(under="ignore", over="ignore"):
        variance = np.minimum(np.float64(scale * spread) ** 2, 1e308) * np.ones((16, 16, 3))
    return SampleBuffer.from_moments(np.full((16, 16), 4), mean, variance)


@pytest.mark.parametrize("spread", [0.1, 1e5, 0.0])
@pytest.mark.parametrize("scale", SCALES)
def test_extreme_magnitudes_are_accepted_without_warnings(scale, spread):
    """Means near the smallest and largest floats: reconstruction and sampling just work."""
    buf = _extreme_buffer(scale, spread)
    for domain in DOMAINS:
        out = reconstruct(buf, domain=domain)
        assert np.isfinite(out).all()
        detailed = reconstruct_detailed(buf, domain=domain, variance_probes=2)
        assert not np.isnan(detailed.variance).any()
        for cls in (AdaptiveSampler, VarianceSampler):
            assert cls.from_buffer(buf, domain=domain).ask(100).total == 100
    assert 0 <= metrics.relmse(buf.mean, buf.mean * 1.1) < 1
    assert metrics.mse(buf.mean, buf.mean * 1.1) >= 0
    assert not math.isnan(metrics.psnr(buf.mean, buf.mean * 1.1))


@pytest.mark.parametrize("name", ["log", "linear", "gamma"])
@pytest.mark.parametrize("scale", [1e-300, 1e-160, 1e100, 1e300])
def test_a_domain_scale_far_from_the_image_is_finite_or_refused(name, scale):
    """A ``Domain(scale=1e-300)`` beside means of 0.5 gave a NaN image with 37 warnings (the Wiener stages
    worked at the domain's scale, not the image's; a red-team pass), and a scale 1e400 times the image's
    level a black one (every mean 0 in the domain): finite, the image's mean kept, or refused."""
    for stages in (1, 3):
        out = reconstruct(_extreme_buffer(0.5, 0.1), domain=Domain(name, scale=scale), stages=stages)
        assert np.isfinite(out).all() and out.mean() == pytest.approx(0.5 * 1.05, rel=0.02)
    tiny = _extreme_buffer(1e-300, 0.1)
    if name != "linear" and scale >= 1e100:
        with pytest.raises(ValueError, match=r"domain scale: .* every mean underflows to 0"):
            reconstruct(tiny, domain=Domain(name, scale=scale), stages=1)
    else:
        assert np.isfinite(reconstruct(tiny, domain=Domain(name, scale=scale))).all()


@pytest.mark.parametrize("domain, level", [(Domain("linear", offset=2.0, scale=1e300), 1e-10),
                                           (Domain("log", offset=10.0, scale=1e8), 1e-300)])
def test_a_domain_offset_past_float64_at_the_images_level_is_capped(domain, level):
    """The domain's offset carried to the image's level passed float64 (``k: must be a finite number,
    got inf``, naming nothing the caller gave; a review of the nineteenth pass's fix): capped."""
    out = reconstruct(_extreme_buffer(level, 0.1), domain=domain)
    assert np.isfinite(out).all()


def test_a_huge_error_is_inf_not_a_warning():
    assert metrics.mse(np.full(4, 1e300), np.full(4, -1e300)) == math.inf
    assert metrics.psnr(np.full(4, 1e300), np.zeros(4), peak=1.0) == pytest.approx(-6000.0)  # in logarithms
    assert metrics.relmse(np.full(4, 1e300), np.full(4, 2e300)) == pytest.approx(0.25)
    assert metrics.tonemap(np.ones(2), exposure=1e6) == pytest.approx([1.0, 1.0])


@pytest.mark.parametrize("bad", ["threads", 2, object(), map, get_executor])
@pytest.mark.parametrize("call", [
    lambda e: reconstruct(BUF, executor=e),
    lambda e: AdaptiveSampler((H, W), executor=e),
    lambda e: UniformSampler((H, W), executor=e),
    lambda e: BUF.merge(BUF, executor=e),
    lambda e: priorities.sampling_density(BUF, executor=e),
    lambda e: priorities.coefficient_priorities(BUF, executor=e),
], ids=["reconstruct", "AdaptiveSampler", "UniformSampler", "merge", "sampling_density", "coefficient_priorities"])
def test_an_executor_that_is_not_one_is_refused_naming_it(call, bad):
    with pytest.raises(TypeError, match=r"^executor: expected a concurrent\.futures\.Executor"):
        call(bad)


@pytest.mark.parametrize("call", [
    lambda e: reconstruct(BUF, executor=e),
    lambda e: UniformSampler((H, W), executor=e),
    lambda e: BUF.merge(BUF, executor=e),
], ids=["reconstruct", "UniformSampler", "merge"])
def test_a_process_pool_is_refused_where_threads_share_the_arrays(call):
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1) as pool, pytest.raises(TypeError, match=r"^executor: a ProcessPoolExecutor"):
        call(pool)


def _renderer_of(shape):
    return synthetic.SyntheticRenderer(synthetic.make_scene("edges", shape))


@pytest.mark.parametrize("call", [
    lambda e: reconstruct(BUF, executor=e),
    lambda e: BUF.merge(SampleBuffer.empty((H, W), channels=BUF.channels), executor=e).mean,
    lambda e: priorities.sampling_density(BUF, executor=e),
    lambda e: AdaptiveSampler((H, W), executor=e).run(_renderer_of((H, W)), total_spp=4).mean,
], ids=["reconstruct", "merge", "sampling_density", "sampler"])
def test_an_executor_used_from_its_own_thread_runs_serially_not_a_hang(call):
    """``pool.submit(reconstruct, buf, executor=pool)`` on a one-thread pool waited for ever: its work
    queued behind the task that waits for it (a red-team pass). On the pool's own threads the work
    runs serially, the same bits. Two threads here and the work submitted from them counted: a
    regression fails at once instead of hanging."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    class Watched(ThreadPoolExecutor):
        nested = 0

        def submit(self, fn, /, *args, **kwargs):
            self.nested += threading.current_thread().name.startswith("watched")
            return super().submit(fn, *args, **kwargs)

    serial = call(None)
    with Watched(2, thread_name_prefix="watched") as pool:
        for _ in range(3):  # the first task runs before its thread is listed among the pool's
            assert_array_equal(pool.submit(call, pool).result(timeout=60), serial)
        assert pool.nested == 0
        assert_array_equal(call(pool), serial)  # from another thread, on the pool's threads


def test_tasks_of_an_executor_whose_futures_stay_pending_while_they_run_are_waited_for():
    """Dask's futures stay pending while they run, so they can always be cancelled: every task was taken back from
    the cluster and run again on the calling thread (a review of the change). Only a thread pool's are taken back."""
    import threading
    from concurrent.futures import Executor, Future

    from awr_denoise import _checks

    class Remote(Executor):  # runs each task on a thread of its own, its future pending until the result is in
        def submit(self, fn, /, *args, **kwargs):
            future = Future()
            threading.Thread(target=lambda: future.set_result(fn(*args, **kwargs)), name="remote").start()
            return future

    def where(x):
        return x, threading.current_thread().name

    assert _checks.mapped(Remote(), where, [1, 2, 3]) == [(1, "remote"), (2, "remote"), (3, "remote")]
    buffer = SampleBuffer.from_moments(np.full((24, 24), 4), np.random.default_rng(0).random((24, 24, 3)),
                                       np.full((24, 24, 3), 0.1))
    assert_array_equal(reconstruct(buffer, executor=Remote()), reconstruct(buffer))


def test_fourth_review_edges(tmp_path):
    """A mask of NaN or 0.5 was cast to True, an empty request accepted where every sampler refuses an
    empty image, and a deep dump of no samples (an empty round) gave numpy's reshape error."""
    from awr_denoise.io import read_deep_samples, write_deep_samples

    for bad in (np.full((2, 2), np.nan), np.full((2, 2), 0.5)):
        with pytest.raises(ValueError, match="variance_known: expected booleans"):
            SampleBuffer.from_moments(np.full((2, 2), 2), np.ones((2, 2, 3)), np.ones((2, 2, 3)), variance_known=bad)
    with pytest.raises(TypeError, match="variance_known: expected booleans"):
        SampleBuffer.from_moments(np.full((1, 1), 2), np.ones((1, 1, 3)), np.ones((1, 1, 3)), variance_known=[["x"]])
    ones = SampleBuffer.from_moments(np.full((1, 2), 2), np.ones((1, 2, 3)), np.ones((1, 2, 3)), variance_known=[[1, 0]])
    assert ones.variance_known.tolist() == [[True, False]]
    with pytest.raises(ValueError, match="counts: empty image"):
        SampleRequest(np.zeros((0, 0), int), np.zeros((0, 0), int), 0, 0)
    write_deep_samples(tmp_path / "empty.exr", np.zeros(0, int), np.zeros((0, 3)), (7, 7))
    assert read_deep_samples(tmp_path / "empty.exr").total_samples == 0


@pytest.mark.parametrize("call", [
    lambda v: reconstruct(BUF, wiener_exponents=v), lambda v: reconstruct(BUF, domain=v),
    lambda v: reconstruct(BUF, mode=v), lambda v: SampleBuffer.empty((4, 4), channels=v),
    lambda v: SampleBuffer.from_moments(np.full((H, W), 4), IMG, IMG, channels=v),
])
def test_an_array_where_a_name_or_a_list_belongs_is_refused_in_one_line(call):
    """A 40x40 array as ``mode`` was numpy's "truth value ... ambiguous", as ``domain`` or
    ``wiener_exponents`` its 300-character repr, as ``channels`` a 5109-character list of "names"
    (a review of the one-line messages)."""
    with pytest.raises((TypeError, ValueError)) as caught:
        call(np.ones((40, 40)))
    message = str(caught.value)
    assert "\n" not in message and len(message) < 160 and message.split(":")[0] in (
        "wiener_exponents", "domain", "mode", "channels"), message


def test_a_zero_dimensional_name_is_its_name():
    """``mode=np.array("luminance")`` was accepted before names were checked as names (a review): a 0-d
    array of a name is that name, as a 0-d array of a number is that number."""
    np.testing.assert_array_equal(reconstruct(BUF, mode=np.array("luminance")), reconstruct(BUF, mode="luminance"))
