"""The speed/accuracy benchmark on the bundled path-traced scenes (``awr bench``).

One call renders every bundled scene with the tracer (:mod:`awr_denoise.tracer`) and measures,
against each scene's high-spp reference (algorithm note, section 7):

- error (relMSE with ``eps = 0.01``, MSE, PSNR, SSIM on the tonemapped image) against the
  average sample count for uniform Monte Carlo, uniform sampling + AWR reconstruction, AWR
  adaptive sampling + AWR reconstruction (the paper, sections 4-5), per-pixel variance-driven
  sampling + AWR reconstruction, and peer denoisers on the same uniform buffers
  (scikit-image's ``denoise_wavelet`` with BayesShrink, and Intel Open Image Denoise when its
  Python bindings are installed);
- the equal-error sample count of every result: the uniform Monte Carlo spp that reaches the
  same relMSE, interpolated in log-log on a uniform curve rendered up to 1024 spp, after
  removing the reference's own noise floor (the paper's headline is "AWR at 32 spp is near
  Monte Carlo at 512 spp");
- error against wall time, with sampling (``ask``/``tell``) and reconstruction included;
- error, squared bias and variance (over several seeds) against the smoothing constant
  ``c_s`` for the linear domain and each stabilised domain, with crops of the artefacts;
- a sweep of the other defaults (levels, wavelet, mode, ``uniform_fraction``,
  ``level_weight``, round size) on the path-traced scenes;
- the overhead of the priority computation per round and of the reconstruction at 256x256,
  1080p and 4K, and how it grows with the number of levels.

It writes ``benchmarks/results/quality.json`` (raw numbers), PNG figures under
``docs/img/`` and ``docs/benchmarks.md``. Run it with::

    python -m awr_denoise.benchmark            # full run (see docs/benchmarks.md for its time)
    python -m awr_denoise.benchmark --quick    # a few minutes

Needs the ``tracer`` and ``bench`` extras (``pip install "awr-denoise[tracer,bench]"``).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from .buffers import SampleBuffer
from .domains import Domain
from .metrics import RELMSE_EPSILON, mse, psnr, relmse, ssim, tonemap
from .reconstruct import reconstruct
from .sampling import DEFAULT_ROUND_GROWTH, AdaptiveSampler, Sampler, UniformSampler, VarianceSampler

__all__ = ["BenchmarkConfig", "METHODS", "DOMAINS", "run_benchmark", "add_arguments", "main", "equal_error_spp",
           "fit_noise_floor", "skimage_denoise", "oidn_denoise", "oidn_available", "run_from_args"]

METHODS = ("uniform", "uniform+awr", "awr+awr", "variance+awr", "uniform+skimage", "uniform+oidn")
"""Methods compared at equal samples. ``sampler+reconstruction``; ``uniform`` is the plain mean."""

METHOD_LABELS = {
    "uniform": "uniform MC (mean)",
    "uniform+awr": "uniform + AWR reconstruction",
    "awr+awr": "AWR sampling + AWR reconstruction",
    "variance+awr": "variance sampling + AWR reconstruction",
    "uniform+skimage": "uniform + skimage BayesShrink",
    "uniform+oidn": "uniform + OIDN",
}

DOMAINS: dict[str, Domain] = {
    "linear": Domain("linear"),
    "log": Domain("log"),
    "gamma": Domain("gamma"),
    "log robust": Domain("log", robust=True),
}
"""Thresholding domains of the ``c_s`` sweep (the paper's linear domain and the stabilised ones)."""

_COLORS = {"uniform": "black", "uniform+awr": "tab:blue", "awr+awr": "tab:red", "variance+awr": "tab:orange",
           "uniform+skimage": "tab:green", "uniform+oidn": "tab:purple"}
_DOMAIN_COLORS = {"linear": "tab:gray", "log": "tab:blue", "gamma": "tab:green", "log robust": "tab:red"}
_PLOT_HINT = 'the benchmark plots need matplotlib; install it with pip install "awr-denoise[bench]"'
_SKIMAGE_HINT = 'the benchmark needs scikit-image; install it with pip install "awr-denoise[bench]"'
_TRACER_HINT = 'the benchmark needs the bundled tracer; install it with pip install "awr-denoise[tracer]"'
_NOTES_BEGIN = "<!-- notes: kept across runs -->"
_NOTES_END = "<!-- /notes -->"


@dataclass(frozen=True)
class BenchmarkConfig:
    """What :func:`run_benchmark` measures.

    Parameters
    ----------
    scenes
        Bundled scene names; ``None`` for all of them.
    spps
        Average samples per pixel at which every method is measured.
    uniform_max_spp
        The uniform Monte Carlo curve (for equal-error sample counts) is rendered at powers of
        two from 4 up to this.
    width, height
        Resolution override; ``None`` keeps each scene's default (128x128). At another
        resolution the reference is rendered on the fly (``inline_reference_spp``, not cached).
    reference_spp
        Minimum spp of the cached references; a cached reference below it is re-rendered (and
        cached) with :func:`awr_denoise.tracer.load_reference`. ``None`` uses the cached files
        as they are (rendering the tracer's default when one is missing).
    inline_reference_spp
        spp of references rendered on the fly at a non-default resolution.
    sweep_spp, sweep_seeds, c_s_values
        The ``c_s`` / domain sweep: uniform buffers at ``sweep_spp`` for ``sweep_seeds`` seeds.
    defaults_sweep, defaults_spp, defaults_seeds
        Sweep of the other defaults at ``defaults_spp`` over ``defaults_seeds`` seeds.
    overhead_sizes
        Image sizes of the overhead measurement (names of :data:`OVERHEAD_SIZES`).
    overhead_levels, overhead_levels_size
        Levels of the overhead-against-levels measurement, and the image size it uses.
    oidn
        Try Intel Open Image Denoise (skipped when its Python bindings are missing).
    threads
        Tracer threads.
    seed
        Seed of the main renders (every method uses the same one: common random numbers).
    """

    scenes: tuple[str, ...] | None = None
    spps: tuple[int, ...] = (4, 8, 16, 32, 64, 128)
    uniform_max_spp: int = 1024
    width: int | None = None
    height: int | None = None
    reference_spp: int | None = None
    inline_reference_spp: int = 1024
    sweep_spp: int = 16
    sweep_seeds: int = 4
    c_s_values: tuple[float, ...] = (0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0)
    defaults_sweep: bool = True
    defaults_spp: int = 32
    defaults_seeds: int = 2
    overhead_sizes: tuple[str, ...] = ("256x256", "1080p", "4K")
    overhead_levels: tuple[int, ...] = (1, 2, 3, 4, 5)
    overhead_levels_size: str = "1080p"
    oidn: bool = True
    threads: int = 2
    seed: int = 0

    @classmethod
    def quick(cls, **overrides: Any) -> BenchmarkConfig:
        """The quick mode: fewer sample counts, seeds and sizes (a few minutes)."""
        base = cls(spps=(4, 8, 32), uniform_max_spp=256, sweep_spp=8, sweep_seeds=3,
                   c_s_values=(0.25, 0.5, 1.0, 2.0, 4.0), defaults_sweep=False, overhead_sizes=("256x256", "1080p"),
                   overhead_levels=(1, 3, 5), overhead_levels_size="256x256")
        return replace(base, **overrides)


OVERHEAD_SIZES = {"256x256": (256, 256), "1080p": (1080, 1920), "4K": (2160, 3840)}


# ---------------------------------------------------------------------------------------- peers
def skimage_denoise(mean: np.ndarray) -> np.ndarray:
    """scikit-image's ``denoise_wavelet`` (BayesShrink, soft) applied to an HDR image.

    BayesShrink estimates one noise level per channel from the image itself (median absolute
    deviation of the finest diagonal band) and assumes it is the same everywhere, which holds
    for neither radiance nor its tonemapped version. The image is therefore denoised in the
    same log domain AWR uses by default, ``y = log(1 + x / k)`` with ``k = 0.1 * mean|x|``, where
    Monte Carlo noise is closer to homoscedastic, and mapped back with ``x = k (e^y - 1)``.
    Wavelet ``db1`` with scikit-image's default depth, ``rescale_sigma=True``.
    """
    try:
        from skimage.restoration import denoise_wavelet
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(_SKIMAGE_HINT) from exc
    x = np.maximum(np.asarray(mean, dtype=np.float64), 0.0)
    k = 0.1 * float(np.mean(x)) if np.mean(x) > 0 else 1.0
    y = np.log1p(x / k)
    out = denoise_wavelet(y, method="BayesShrink", mode="soft", wavelet="db1", channel_axis=-1, rescale_sigma=True)
    return k * np.expm1(np.maximum(out, 0.0))


def oidn_available() -> bool:
    """Whether Intel Open Image Denoise's Python bindings (``pyoidn``) import."""
    try:
        import pyoidn  # noqa: F401
    except Exception:  # noqa: BLE001 - any failure to load the native library means "skip"
        return False
    return True


def oidn_denoise(mean: np.ndarray) -> np.ndarray:
    """Intel Open Image Denoise (``pyoidn``, filter ``RT``, ``hdr=True``, quality ``high``).

    Colour only: the bundled tracer does not write albedo or normal buffers, which OIDN would
    use as auxiliary features; results with them would be better.
    """
    import pyoidn

    x = np.ascontiguousarray(np.maximum(mean, 0.0), dtype=np.float32)
    return np.asarray(pyoidn.denoise(x, hdr=True, quality="high"), dtype=np.float64)


# ---------------------------------------------------------------------------------------- metrics
def _metrics(image: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    return {"relmse": relmse(image, reference), "mse": mse(image, reference), "psnr": psnr(image, reference),
            "ssim": ssim(image, reference)}


def fit_noise_floor(spps: Sequence[float], errors: Sequence[float]) -> tuple[float, float]:
    """Fit ``error(N) = a / N + f`` to a uniform Monte Carlo curve; returns ``(a, f)``.

    The error of an unbiased estimate against a noisy reference is its own variance (``a / N``)
    plus the reference's (``f``, the noise floor, independent of ``N``). Least squares in
    relative terms; ``f`` is clipped to ``[0, 0.95 min(error)]``.
    """
    n = np.asarray(spps, dtype=np.float64)
    e = np.asarray(errors, dtype=np.float64)
    design = np.stack([1.0 / (n * e), 1.0 / e], axis=1)
    (a, f), *_ = np.linalg.lstsq(design, np.ones_like(e), rcond=None)
    f = float(np.clip(f, 0.0, 0.95 * e.min()))
    above = e > f
    # Refit a with f fixed, as the geometric mean of (e - f) N (relative least squares in log terms).
    a = float(np.exp(np.mean(np.log((e[above] - f) * n[above])))) if above.any() else 0.0
    return a, f


def equal_error_spp(error: float, spps: Sequence[float], uniform_errors: Sequence[float],
                    slope_a: float) -> tuple[float, bool]:
    """Uniform Monte Carlo spp reaching ``error`` (all floor-corrected); returns ``(spp, extrapolated)``.

    Interpolated in log-log on the uniform curve; outside its range the fitted ``a / N`` law is
    used and ``extrapolated`` is True. An error at or below zero (under the reference's noise
    floor) gives ``inf``.
    """
    if not error > 0:
        return float("inf"), True
    n = np.asarray(spps, dtype=np.float64)
    u = np.minimum.accumulate(np.asarray(uniform_errors, dtype=np.float64))  # monotone for interp
    ok = u > 0
    n, u = n[ok], u[ok]
    if n.size >= 2 and u[-1] <= error <= u[0]:
        lu, ln = np.log(u[::-1]), np.log(n[::-1])
        return float(np.exp(np.interp(np.log(error), lu, ln))), False
    return float(slope_a / error) if slope_a > 0 else float("nan"), True


# ---------------------------------------------------------------------------------------- rendering
@dataclass
class _Timing:
    render: float = 0.0
    sampler: float = 0.0
    rounds: int = 0
    render_cpu: float = 0.0
    sampler_cpu: float = 0.0

    def copy(self) -> _Timing:
        return replace(self)

    def fields(self) -> dict[str, float]:
        return {"render_s": self.render, "sampler_s": self.sampler, "rounds": self.rounds,
                "render_cpu_s": self.render_cpu, "sampler_cpu_s": self.sampler_cpu}


def _progressive(sampler: Sampler, renderer: Callable, targets: Sequence[int],
                 on_snapshot: Callable[[int, SampleBuffer, _Timing], None]) -> None:
    """Drive ``sampler`` with ask/tell up to each target spp in turn, timing render and sampler."""
    h, w = sampler.shape
    timing = _Timing()
    for target in sorted(targets):
        goal = int(round(target * h * w))
        while sampler.total_samples < goal:
            budget = min(sampler.default_budget(), goal - sampler.total_samples)
            t0, c0 = time.perf_counter(), time.process_time()
            request = sampler.ask(budget)
            t1, c1 = time.perf_counter(), time.process_time()
            samples = renderer(request)
            t2, c2 = time.perf_counter(), time.process_time()
            sampler.tell(request, samples)
            t3, c3 = time.perf_counter(), time.process_time()
            timing.render += t2 - t1
            timing.sampler += (t1 - t0) + (t3 - t2)
            timing.render_cpu += c2 - c1
            timing.sampler_cpu += (c1 - c0) + (c3 - c2)
            timing.rounds += 1
        on_snapshot(target, sampler.buffer, timing.copy())


def _tracer_module():
    try:
        from . import tracer
    except ImportError as exc:
        raise ImportError(_TRACER_HINT) from exc
    return tracer


def _reference(name: str, scene, config: BenchmarkConfig) -> tuple[np.ndarray, dict[str, Any]]:
    """The scene's reference image and where it came from."""
    tracer = _tracer_module()
    from .requests import SampleRequest
    from .tracer.reference import REFERENCE_SEED, read_reference_header

    default = tracer.load_scene(name)
    if (scene.height, scene.width) == (default.height, default.width):
        path = tracer.reference_path(name)
        if config.reference_spp is not None:
            image = tracer.load_reference(name, spp=config.reference_spp) if not (
                path.is_file() and int(read_reference_header(path).get("awr_spp", 0)) >= config.reference_spp) \
                else tracer.load_reference(name)
        else:
            image = tracer.load_reference(name)
        header = read_reference_header(path)
        return image, {"source": f"data/references/{name}.exr", "spp": int(header.get("awr_spp", 0)),
                       "sampler": header.get("awr_sampler", "?"), "seed": int(header.get("awr_seed", -1)),
                       "render_seconds": float(header.get("awr_seconds", "nan"))}
    pt = tracer.PathTracer(scene, seed=REFERENCE_SEED, sampler="sobol", threads=config.threads)
    try:
        buffer = pt(SampleRequest.uniform(pt.shape, config.inline_reference_spp))
    finally:
        pt.close()
    return np.array(buffer.mean), {"source": "rendered inline (not cached)", "spp": config.inline_reference_spp,
                                   "sampler": "sobol", "seed": REFERENCE_SEED,
                                   "render_seconds": float(pt.stats["seconds"])}


def _make_tracer(scene, seed: int, threads: int):
    return _tracer_module().PathTracer(scene, seed=seed, threads=threads)


def _render_uniform(scene, spp: int, seed: int, threads: int) -> SampleBuffer:
    from .requests import SampleRequest

    pt = _make_tracer(scene, seed, threads)
    try:
        return pt(SampleRequest.uniform(pt.shape, int(spp)))
    finally:
        pt.close()


def _timed(fn: Callable[[], np.ndarray]) -> tuple[np.ndarray, tuple[float, float]]:
    """``fn()``, and its (wall, CPU) seconds."""
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, (time.perf_counter() - t, time.process_time() - c)


def _time_fields(timing: _Timing, seconds: tuple[float, float]) -> dict[str, float]:
    return {**timing.fields(), "reconstruct_s": seconds[0], "reconstruct_cpu_s": seconds[1],
            "total_s": timing.render + timing.sampler + seconds[0],
            "total_cpu_s": timing.render_cpu + timing.sampler_cpu + seconds[1]}


# ---------------------------------------------------------------------------------------- one scene
def _scene_benchmark(name: str, config: BenchmarkConfig, use_oidn: bool, tick: Callable[[str], None]
                     ) -> tuple[dict[str, Any], dict[str, Any]]:
    """All measurements of one scene: (JSON-ready results, images kept for the figures)."""
    tracer = _tracer_module()
    scene = tracer.load_scene(name, width=config.width, height=config.height)
    shape = (scene.height, scene.width)
    reference, ref_info = _reference(name, scene, config)
    tick(f"{name}: reference")
    weight = 1.0 / (reference**2 + RELMSE_EPSILON)
    spps = sorted(set(int(s) for s in config.spps))
    show_spp = 32 if 32 in spps else spps[len(spps) // 2]
    images: dict[str, Any] = {"reference": reference, "show_spp": show_spp, "crops": {}, "density": {}}
    methods: dict[str, list[dict[str, Any]]] = {m: [] for m in METHODS if m != "uniform+oidn" or use_oidn}

    # Uniform: one progressive render (nested sample indices) up to uniform_max_spp.
    curve_spps = sorted(set([int(2**k) for k in range(2, int(np.log2(max(config.uniform_max_spp, 4))) + 1)]
                            + spps))
    uniform_curve: list[dict[str, Any]] = []
    uniform_buffers: dict[int, SampleBuffer] = {}
    renderer = _make_tracer(scene, config.seed, config.threads)

    def uniform_snapshot(spp: int, buffer: SampleBuffer, timing: _Timing) -> None:
        mean = np.array(buffer.mean)
        uniform_curve.append({"spp": spp, **_metrics(mean, reference), **_time_fields(timing, (0.0, 0.0))})
        if spp not in spps:
            return
        uniform_buffers[spp] = buffer
        outs = {"uniform": (mean, (0.0, 0.0))}
        outs["uniform+awr"] = _timed(lambda: reconstruct(buffer))
        outs["uniform+skimage"] = _timed(lambda: skimage_denoise(mean))
        if use_oidn:
            outs["uniform+oidn"] = _timed(lambda: oidn_denoise(mean))
        for method, (image, seconds) in outs.items():
            methods[method].append({"spp": spp, **_metrics(image, reference), **_time_fields(timing, seconds)})
            if spp == show_spp:
                images["crops"][method] = image

    try:
        _progressive(UniformSampler(shape, seed=config.seed), renderer, curve_spps, uniform_snapshot)
    finally:
        renderer.close()
    tick(f"{name}: uniform to {curve_spps[-1]} spp")

    for method, sampler_cls in (("awr+awr", AdaptiveSampler), ("variance+awr", VarianceSampler)):
        renderer = _make_tracer(scene, config.seed, config.threads)

        def snapshot(spp: int, buffer: SampleBuffer, timing: _Timing, method: str = method) -> None:
            image, seconds = _timed(lambda: reconstruct(buffer))
            methods[method].append({"spp": spp, **_metrics(image, reference), **_time_fields(timing, seconds),
                                    "plain_mean_relmse": relmse(buffer.mean, reference),
                                    "max_pixel_spp": int(buffer.count.max()),
                                    "min_pixel_spp": int(buffer.count.min())})
            if spp == show_spp:
                images["crops"][method] = image
                images["density"][method] = buffer.count / buffer.count.mean()

        try:
            _progressive(sampler_cls(shape, seed=config.seed), renderer, spps, snapshot)
        finally:
            renderer.close()
        tick(f"{name}: {method}")

    # Reference noise floor, from the uniform curve, and an upper bound from the per-sample variance.
    c_spps = [row["spp"] for row in uniform_curve]
    c_err = [row["relmse"] for row in uniform_curve]
    slope_a, floor = fit_noise_floor(c_spps, c_err)
    last = uniform_buffers.get(spps[-1])
    if last is not None and ref_info["spp"]:
        per_sample = last.estimated_variance()
        ref_info["floor_bound_independent"] = float(np.mean(per_sample / ref_info["spp"] * weight))
    ref_info["floor_fit"] = floor
    ref_info["uniform_relmse_1spp_fit"] = slope_a
    corrected_curve = [e - floor for e in c_err]
    for row, corr in zip(uniform_curve, corrected_curve):
        row["relmse_corrected"] = corr
    for rows in methods.values():
        for row in rows:
            row["relmse_corrected"] = row["relmse"] - floor
            eq, extrapolated = equal_error_spp(row["relmse_corrected"], c_spps, corrected_curve, slope_a)
            row["equal_error_spp"] = eq
            row["equal_error_extrapolated"] = extrapolated
            eq_raw, _ = equal_error_spp(row["relmse"], c_spps, c_err, slope_a)
            row["equal_error_spp_uncorrected"] = eq_raw

    result: dict[str, Any] = {"shape": list(shape), "dimension": getattr(scene, "dimension", None), "reference": ref_info, "uniform_curve": uniform_curve, "methods": methods}
    result["c_s_sweep"], images["domain_crops"] = _cs_sweep(scene, reference, weight, floor, config,
                                                            uniform_buffers.get(config.sweep_spp))
    tick(f"{name}: c_s sweep")
    if config.defaults_sweep:
        result["defaults_sweep"] = _defaults_sweep(scene, reference, config, uniform_buffers.get(config.defaults_spp))
        tick(f"{name}: defaults sweep")
    return result, images


def _cs_sweep(scene, reference: np.ndarray, weight: np.ndarray, floor: float, config: BenchmarkConfig,
              seed0: SampleBuffer | None) -> tuple[list[dict[str, Any]], dict[str, np.ndarray]]:
    """relMSE, squared bias and variance against c_s for every domain, over several seeds."""
    buffers = []
    for s in range(config.sweep_seeds):
        if s == 0 and seed0 is not None and config.seed == 0:
            buffers.append(seed0)
        else:
            buffers.append(_render_uniform(scene, config.sweep_spp, config.seed + s, config.threads))
    rows = []
    mean_err = [relmse(b.mean, reference) for b in buffers]
    rows.append({"domain": "mean", "c_s": 0.0, "spp": config.sweep_spp, "relmse": float(np.mean(mean_err))})
    outputs: dict[tuple[str, float], np.ndarray] = {}
    for dname, dom in DOMAINS.items():
        for c_s in config.c_s_values:
            outs = np.stack([reconstruct(b, c_s=float(c_s), domain=dom) for b in buffers])
            outputs[(dname, float(c_s))] = outs[0]
            errs = [relmse(o, reference) for o in outs]
            n = len(buffers)
            variance = float(np.mean(np.var(outs, axis=0, ddof=1) * weight[None])) if n > 1 else float("nan")
            bias_raw = float(np.mean((outs.mean(axis=0) - reference) ** 2 * weight))
            bias2 = bias_raw - (variance / n if n > 1 else 0.0) - floor
            rows.append({"domain": dname, "c_s": float(c_s), "spp": config.sweep_spp, "relmse": float(np.mean(errs)),
                         "relmse_std": float(np.std(errs)), "bias2": bias2, "variance": variance,
                         "worse_than_mean": bool(np.mean(errs) > np.mean(mean_err))})
    # Crop where the paper's linear domain goes most wrong (ringing, smeared fireflies).
    crops = {"mean": np.array(buffers[0].mean)}
    crops.update({f"{d} c_s={c:g}": img for (d, c), img in outputs.items()})
    return rows, crops


def _defaults_sweep(scene, reference: np.ndarray, config: BenchmarkConfig,
                    seed0: SampleBuffer | None) -> list[dict[str, Any]]:
    """relMSE of one default changed at a time (mean over seeds), at ``defaults_spp``."""
    from .wavelets import default_levels, max_levels

    shape = (scene.height, scene.width)
    spp = config.defaults_spp
    seeds = [config.seed + s for s in range(config.defaults_seeds)]
    uniform = [seed0 if (s == config.seed and seed0 is not None) else _render_uniform(scene, spp, s, config.threads)
               for s in seeds]
    rows = []

    def add(group: str, value: str, errors: list[float], default: bool, overhead: float | None = None) -> None:
        rows.append({"group": group, "value": value, "spp": spp, "relmse": float(np.mean(errors)),
                     "relmse_each": errors, "default": default, "sampler_cpu_share": overhead})

    add("plain mean", "uniform", [relmse(b.mean, reference) for b in uniform], False)
    lv_default = default_levels(shape)
    for lv in sorted(set(range(1, min(6, max_levels(shape)) + 1))):
        add("levels", str(lv), [relmse(reconstruct(b, levels=lv), reference) for b in uniform], lv == lv_default)
    for wav in ("bior4.4", "haar", "db2", "sym4"):
        add("wavelet", wav, [relmse(reconstruct(b, wavelet=wav), reference) for b in uniform], wav == "bior4.4")
    for mode in ("channels", "luminance"):
        add("mode", mode, [relmse(reconstruct(b, mode=mode), reference) for b in uniform], mode == "channels")
    variants = [("uniform_fraction", v, {"uniform_fraction": v}, v == 0.0) for v in (0.0, 0.1, 0.3)]
    variants += [("level_weight", v, {"level_weight": v}, v == 0.25) for v in (0.0, 0.25, 1.0)]
    variants += [("round_spp", v, {"round_spp": v}, False) for v in (0.25, 2.0, 8.0)]
    variants += [("round_growth", v, {"round_growth": v}, v == DEFAULT_ROUND_GROWTH) for v in (0.25, 0.5, 1.0)]
    cache: dict[tuple, tuple[list[float], float]] = {}
    for group, value, options, default in variants:
        key = tuple(sorted((k, v) for k, v in options.items() if not default))
        if key not in cache:
            errs, render_cpu, sampler_cpu = [], 0.0, 0.0
            for s in seeds:
                pt = _make_tracer(scene, s, config.threads)
                got: dict[str, Any] = {}
                try:
                    _progressive(AdaptiveSampler(shape, seed=s, **options), pt, [spp],
                                 lambda _spp, buf, timing: got.update(buffer=buf, timing=timing))
                finally:
                    pt.close()
                errs.append(relmse(reconstruct(got["buffer"]), reference))
                render_cpu += got["timing"].render_cpu
                sampler_cpu += got["timing"].sampler_cpu
            cache[key] = (errs, sampler_cpu / render_cpu if render_cpu > 0 else float("nan"))
        errs, share = cache[key]
        add(group, str(value), errs, default, share)
    return rows


# ---------------------------------------------------------------------------------------- overhead
def _noisy_buffer(shape: tuple[int, int], spp: int = 4, seed: int = 0) -> SampleBuffer:
    rng = np.random.default_rng(seed)
    h, w = shape
    base = ndimage.gaussian_filter(rng.uniform(0.0, 1.0, (h, w, 3)), (8, 8, 0))
    var = rng.uniform(0.0, 0.1, (h, w, 3))
    return SampleBuffer.from_moments(np.full((h, w), spp), base + rng.normal(0, 0.05, base.shape), var)


def _median_time(fn: Callable[[], Any], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def _overhead(config: BenchmarkConfig, tick: Callable[[str], None]) -> dict[str, Any]:
    """Time of one ``ask()`` round (priorities + allocation) and of ``reconstruct`` per size and level."""
    from .priorities import sampling_density

    sizes = []
    for name in config.overhead_sizes:
        shape = OVERHEAD_SIZES[name]
        buf = _noisy_buffer(shape)
        repeats = 5 if shape[0] * shape[1] < 1e6 else 2
        reconstruct(buf)  # warm the cached wavelet operators, as a render loop would
        t_rec = _median_time(lambda: reconstruct(buf), repeats)
        t_den = _median_time(lambda: sampling_density(buf), repeats)
        t_ask = _median_time(lambda: AdaptiveSampler.from_buffer(buf, round=1).ask(), repeats)
        mp = shape[0] * shape[1] / 1e6
        sizes.append({"size": name, "pixels": shape[0] * shape[1], "reconstruct_s": t_rec, "priorities_s": t_den,
                      "ask_s": t_ask, "reconstruct_s_per_mp": t_rec / mp, "ask_s_per_mp": t_ask / mp})
        tick(f"overhead {name}")
    levels = []
    lv_size = config.overhead_levels_size
    buf = _noisy_buffer(OVERHEAD_SIZES[lv_size])
    for lv in config.overhead_levels:
        reconstruct(buf, levels=lv)
        t_rec = _median_time(lambda: reconstruct(buf, levels=lv), 2)
        t_ask = _median_time(lambda: AdaptiveSampler.from_buffer(buf, round=1, levels=lv).ask(), 2)
        levels.append({"size": lv_size, "levels": lv, "reconstruct_s": t_rec, "ask_s": t_ask})
    tick("overhead levels")
    return {"sizes": sizes, "levels": levels}


# ---------------------------------------------------------------------------------------- the run
def run_benchmark(config: BenchmarkConfig | None = None, *, output_dir: str | Path | None = "docs",
                  results_path: str | Path | None = None, plots: bool = True, progress: bool = True,
                  mode_name: str | None = None) -> dict[str, Any]:
    """Run the benchmark; write the JSON, the figures and ``benchmarks.md``; return the results.

    Parameters
    ----------
    config
        What to measure; default :class:`BenchmarkConfig` (the full run).
    output_dir
        Directory of ``benchmarks.md`` and of the figures (in its ``img/``); ``None`` writes no
        document and no figure.
    results_path
        Where the raw numbers go as JSON; default ``benchmarks/results/quality.json`` beside
        ``output_dir``'s parent; ``None`` together with ``output_dir=None`` writes nothing.
    plots
        Draw the PNG figures (needs matplotlib).
    progress
        Show a progress bar (tqdm) on stderr.
    mode_name
        Label of the run in the outputs (``"full"``, ``"quick"``, ...).

    Returns
    -------
    dict
        The raw results (the JSON's content).
    """
    config = config or BenchmarkConfig()
    tracer = _tracer_module()
    scenes = list(config.scenes) if config.scenes else tracer.list_scenes()
    for name in scenes:
        if name not in tracer.list_scenes():
            raise ValueError(f"scenes: {name!r} is not one of {', '.join(tracer.list_scenes())}")
    try:
        import skimage  # noqa: F401
    except ImportError as exc:
        raise ImportError(_SKIMAGE_HINT) from exc
    if plots and output_dir is not None:
        _figure_module()  # fail early, with the install hint
    use_oidn = bool(config.oidn) and oidn_available()
    out_dir = None if output_dir is None else Path(output_dir)
    if results_path is None and out_dir is not None:
        results_path = out_dir.resolve().parent / "benchmarks" / "results" / "quality.json"

    stages = len(scenes) * (5 + int(config.defaults_sweep)) + len(config.overhead_sizes) + 1
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=stages, desc="awr bench", unit="stage", file=sys.stderr)

    def tick(label: str) -> None:
        if bar is not None:
            bar.set_postfix_str(label, refresh=False)
            bar.update(1)

    # Warm up the peers once (imports, device creation) so their first timing is not inflated.
    warm = np.random.default_rng(0).uniform(0.0, 1.0, (16, 16, 3))
    skimage_denoise(warm)
    if use_oidn:
        oidn_denoise(warm)
    started = time.perf_counter()
    results: dict[str, Any] = {
        "meta": {"mode": mode_name or "custom", "config": asdict(config),
                 "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
                 "python": sys.version.split()[0], "platform": platform.platform(),
                 "processor": platform.processor() or platform.machine(),
                 "oidn": "used" if use_oidn else ("not installed (pyoidn did not import)" if config.oidn
                                                  else "disabled"),
                 "relmse_epsilon": RELMSE_EPSILON},
        "scenes": {},
    }
    all_images: dict[str, Any] = {}
    try:
        for name in scenes:
            results["scenes"][name], all_images[name] = _scene_benchmark(name, config, use_oidn, tick)
        results["overhead"] = _overhead(config, tick) if config.overhead_sizes else {"sizes": [], "levels": []}
    finally:
        if bar is not None:
            bar.close()
    results["summary"] = _summary(results, config)
    results["meta"]["run_seconds"] = time.perf_counter() - started
    if results_path is not None:
        path = Path(results_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(_json_ready(results), indent=1) + "\n")
    if out_dir is not None:
        figures = _write_figures(results, all_images, out_dir / "img") if plots else {}
        _write_markdown(results, figures, out_dir / "benchmarks.md", results_path)
    return results


def _json_ready(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if np.isfinite(v) else str(v)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def _row_at(rows: list[dict[str, Any]], spp: int) -> dict[str, Any] | None:
    return next((r for r in rows if r["spp"] == spp), None)


def _summary(results: dict[str, Any], config: BenchmarkConfig) -> dict[str, Any]:
    """Headline numbers, goals and flags computed from the raw results."""
    spps = sorted(config.spps)
    head_spp = 32 if 32 in spps else spps[len(spps) // 2]
    out: dict[str, Any] = {"headline_spp": head_spp, "scenes": {}, "flags": []}
    for name, sc in results["scenes"].items():
        m = sc["methods"]
        row = {meth: _row_at(rows, head_spp) for meth, rows in m.items()}
        curve = {r["spp"]: r for r in sc["uniform_curve"]}
        u512 = curve.get(512)
        entry: dict[str, Any] = {"relmse": {k: v["relmse"] for k, v in row.items() if v},
                                 "equal_error_spp": {k: v["equal_error_spp"] for k, v in row.items() if v},
                                 "uniform_512_relmse": None if u512 is None else u512["relmse"]}
        awr = row.get("awr+awr")
        if awr is not None:
            entry["awr_vs_uniform_same_spp"] = awr["relmse"] / row["uniform"]["relmse"]
            if u512 is not None:
                entry["awr_at_or_below_uniform_512"] = awr["relmse"] <= u512["relmse"]
            sk = row.get("uniform+skimage")
            if sk is not None:
                entry["awr_better_than_skimage"] = awr["relmse"] < sk["relmse"]
            render = awr["render_s"]
            entry["overhead_share"] = (awr["sampler_s"] + awr["reconstruct_s"]) / render if render > 0 else None
            render_cpu = awr["render_cpu_s"]
            entry["overhead_share_cpu"] = ((awr["sampler_cpu_s"] + awr["reconstruct_cpu_s"]) / render_cpu
                                           if render_cpu > 0 else None)
            entry["overhead_split_s"] = {"render": render, "sampler": awr["sampler_s"],
                                         "reconstruct": awr["reconstruct_s"], "rounds": awr["rounds"]}
            big = next((r for r in results.get("overhead", {}).get("sizes", []) if r["size"] == "1080p"), None)
            if big is not None and render > 0:
                # The same loop at 1080p: tracer time scales with pixels, ask() and reconstruct as measured.
                pixels = sc["shape"][0] * sc["shape"][1]
                render_big = render_cpu * big["pixels"] / pixels
                entry["overhead_share_1080p_estimate"] = (awr["rounds"] * big["ask_s"] + big["reconstruct_s"]) / render_big
        # Equal time: uniform MC's relMSE at the same CPU time, interpolated in log-log.
        t_u = np.array([r["total_cpu_s"] for r in sc["uniform_curve"]])
        e_u = np.array([r["relmse"] for r in sc["uniform_curve"]])
        order = np.argsort(t_u)
        t_u, e_u = t_u[order], e_u[order]
        entry["equal_time"] = {}
        for meth, r in row.items():
            if r is None or meth == "uniform" or not (t_u[0] <= r["total_cpu_s"] <= t_u[-1]) or r["total_cpu_s"] <= 0:
                continue
            at = float(np.exp(np.interp(np.log(r["total_cpu_s"]), np.log(t_u), np.log(e_u))))
            entry["equal_time"][meth] = {"cpu_s": r["total_cpu_s"], "relmse": r["relmse"], "uniform_relmse": at,
                                         "ratio": r["relmse"] / at}
        out["scenes"][name] = entry
        for meth in ("uniform+awr", "awr+awr", "variance+awr"):
            for r in m.get(meth, []):
                u = _row_at(m["uniform"], r["spp"])
                if u is not None and r["relmse"] > u["relmse"]:
                    out["flags"].append(f"{name}: {meth} at {r['spp']} spp is worse than the plain mean "
                                        f"(relMSE {r['relmse']:.4g} > {u['relmse']:.4g})")
        for r in sc.get("c_s_sweep", []):
            if r["domain"] == "log" and r["c_s"] == 1.0 and r.get("worse_than_mean"):
                out["flags"].append(f"{name}: the default reconstruction (log, c_s=1) is worse than the plain mean "
                                    f"in the c_s sweep at {r['spp']} spp")
    # Best c_s per domain, per scene.
    best: dict[str, dict[str, float]] = {}
    for name, sc in results["scenes"].items():
        best[name] = {}
        for dname in DOMAINS:
            rows = [r for r in sc.get("c_s_sweep", []) if r["domain"] == dname]
            if rows:
                b = min(rows, key=lambda r: r["relmse"])
                best[name][dname] = b["c_s"]
    out["best_c_s"] = best
    return out


# ---------------------------------------------------------------------------------------- figures
def _figure_module():
    try:
        import matplotlib

        matplotlib.use("Agg", force=False)
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise ImportError(_PLOT_HINT) from exc
    return Figure


def _save(fig, path: Path, dpi: int = 80) -> str:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    return path.name


def _grid(n: int) -> tuple[int, int]:
    cols = min(3, n)
    return (n + cols - 1) // cols, cols


def _window(error_map: np.ndarray, size: int) -> tuple[slice, slice]:
    """The ``size`` x ``size`` window with the largest summed error."""
    h, w = error_map.shape
    size = min(size, h, w)
    local = ndimage.uniform_filter(error_map, size, mode="constant")
    half = size // 2
    inner = local[half:h - (size - half) + 1, half:w - (size - half) + 1]
    r, c = np.unravel_index(int(np.argmax(inner)), inner.shape)
    return slice(r, r + size), slice(c, c + size)


def _write_figures(results: dict[str, Any], images: dict[str, Any], img_dir: Path) -> dict[str, str]:
    Figure = _figure_module()
    img_dir.mkdir(parents=True, exist_ok=True)
    scenes = list(results["scenes"])
    rows_n, cols_n = _grid(len(scenes))
    figs: dict[str, str] = {}
    eps = RELMSE_EPSILON

    # Error against spp (log-log), floor-corrected uniform curve dashed.
    fig = Figure(figsize=(4.2 * cols_n, 3.3 * rows_n))
    for i, name in enumerate(scenes):
        ax = fig.add_subplot(rows_n, cols_n, i + 1)
        sc = results["scenes"][name]
        curve = sc["uniform_curve"]
        ax.loglog([r["spp"] for r in curve], [r["relmse"] for r in curve], color="black", lw=1, label="uniform MC")
        corr = [(r["spp"], r["relmse_corrected"]) for r in curve if r["relmse_corrected"] > 0]
        if corr:
            ax.loglog(*zip(*corr), color="black", lw=1, ls=":", label="uniform MC, floor removed")
        for meth, rows in sc["methods"].items():
            if meth == "uniform":
                continue
            ax.loglog([r["spp"] for r in rows], [r["relmse"] for r in rows], "o-", ms=3, color=_COLORS[meth],
                      label=METHOD_LABELS[meth])
        floor = sc["reference"]["floor_fit"]
        if floor > 0:
            ax.axhline(floor, color="gray", lw=0.8, ls="--", label="reference noise floor")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("average spp")
        ax.set_ylabel(f"relMSE (eps {eps:g})")
        ax.grid(True, which="both", alpha=0.3)
        if i == 0:
            ax.legend(fontsize=6.5)
    fig.tight_layout()
    figs["error_vs_spp"] = _save(fig, img_dir / "bench_error_vs_spp.png")

    # Error against wall time.
    fig = Figure(figsize=(4.2 * cols_n, 3.3 * rows_n))
    for i, name in enumerate(scenes):
        ax = fig.add_subplot(rows_n, cols_n, i + 1)
        sc = results["scenes"][name]
        curve = sc["uniform_curve"]
        ax.loglog([r["total_cpu_s"] for r in curve], [r["relmse"] for r in curve], color="black",
                  lw=1, label="uniform MC")
        for meth, rows in sc["methods"].items():
            if meth == "uniform":
                continue
            ax.loglog([r["total_cpu_s"] for r in rows], [r["relmse"] for r in rows], "o-", ms=3,
                      color=_COLORS[meth], label=METHOD_LABELS[meth])
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("CPU time: render + sampling + reconstruction (s)")
        ax.set_ylabel("relMSE")
        ax.grid(True, which="both", alpha=0.3)
        if i == 0:
            ax.legend(fontsize=6.5)
    fig.tight_layout()
    figs["error_vs_time"] = _save(fig, img_dir / "bench_error_vs_time.png")

    # Sample density of the adaptive samplers.
    dens_methods = [m for m in ("awr+awr", "variance+awr") if all(m in images[s]["density"] for s in scenes)]
    fig = Figure(figsize=(2.2 * (1 + len(dens_methods)), 2.2 * len(scenes)))
    for i, name in enumerate(scenes):
        ax = fig.add_subplot(len(scenes), 1 + len(dens_methods), i * (1 + len(dens_methods)) + 1)
        ax.imshow(tonemap(images[name]["reference"]), interpolation="nearest")
        ax.set_axis_off()
        ax.set_title(f"{name}", fontsize=8)
        for j, meth in enumerate(dens_methods):
            ax = fig.add_subplot(len(scenes), 1 + len(dens_methods), i * (1 + len(dens_methods)) + 2 + j)
            d = images[name]["density"][meth]
            im = ax.imshow(np.log2(np.maximum(d, 1e-3)), cmap="magma", vmin=-2, vmax=3, interpolation="nearest")
            ax.set_axis_off()
            ax.set_title(f"{meth}, max {d.max():.1f}x", fontsize=7)
        if i == 0 and dens_methods:
            cb = fig.colorbar(im, ax=ax, fraction=0.046)
            cb.set_label("log2(spp / mean spp)", fontsize=6)
            cb.ax.tick_params(labelsize=6)
    fig.tight_layout()
    figs["density"] = _save(fig, img_dir / "bench_density.png")

    # Side-by-side crops at the headline spp.
    crop_methods = ["reference"] + [m for m in METHODS if all(m in images[s]["crops"] for s in scenes)]
    fig = Figure(figsize=(1.9 * len(crop_methods), 2.05 * len(scenes)))
    for i, name in enumerate(scenes):
        ref = images[name]["reference"]
        size = max(16, min(ref.shape[:2]) // 3)
        err = np.mean((images[name]["crops"]["uniform"] - ref) ** 2 / (ref**2 + eps), axis=-1)
        win = _window(ndimage.gaussian_filter(err, 2), size)
        for j, meth in enumerate(crop_methods):
            img = ref if meth == "reference" else images[name]["crops"][meth]
            ax = fig.add_subplot(len(scenes), len(crop_methods), i * len(crop_methods) + j + 1)
            ax.imshow(tonemap(img[win]), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            label = meth if meth == "reference" else f"{meth}\n{relmse(img, ref):.4f}"
            ax.set_title(label, fontsize=6)
            if j == 0:
                ax.set_ylabel(name, fontsize=7)
    fig.suptitle(f"crops at {images[scenes[0]]['show_spp']} spp (titles: whole-image relMSE)", fontsize=8)
    fig.tight_layout()
    figs["crops"] = _save(fig, img_dir / "bench_crops.png", dpi=90)

    # c_s sweep: relMSE, bias and variance per domain.
    for key, fields, fname in (("cs_relmse", ("relmse",), "bench_cs_relmse.png"),
                               ("cs_bias_variance", ("bias2", "variance"), "bench_cs_bias_variance.png")):
        fig = Figure(figsize=(4.2 * cols_n, 3.3 * rows_n))
        for i, name in enumerate(scenes):
            ax = fig.add_subplot(rows_n, cols_n, i + 1)
            rows = results["scenes"][name]["c_s_sweep"]
            for dname in DOMAINS:
                dr = [r for r in rows if r["domain"] == dname]
                for fld, ls in zip(fields, ("-", ":")):
                    ys = [max(r[fld], 1e-7) for r in dr]
                    ax.loglog([r["c_s"] for r in dr], ys, ls, marker="o", ms=3, color=_DOMAIN_COLORS[dname],
                              label=f"{dname} {fld}" if len(fields) > 1 else dname)
            mean_row = next(r for r in rows if r["domain"] == "mean")
            if key == "cs_relmse":
                ax.axhline(mean_row["relmse"], color="black", lw=0.8, ls="--", label="plain mean")
            ax.set_title(f"{name} ({mean_row['spp']} spp)", fontsize=10)
            cs_ticks = sorted({r["c_s"] for r in rows if r["domain"] != "mean"})
            ax.minorticks_off()
            ax.set_xticks(cs_ticks)
            ax.set_xticklabels([f"{c:g}" for c in cs_ticks], fontsize=7)
            ax.set_xlabel("c_s")
            ax.set_ylabel("relMSE" if key == "cs_relmse" else "bias^2 (solid), variance (dotted)")
            ax.grid(True, which="both", alpha=0.3)
            if i == 0:
                ax.legend(fontsize=6)
        fig.tight_layout()
        figs[key] = _save(fig, img_dir / fname)

    # Domain crops: where the linear domain fails worst.
    cs_all = sorted({float(k.split("c_s=")[1]) for k in images[scenes[0]]["domain_crops"] if "c_s=" in k})
    lo, hi = (1.0 if 1.0 in cs_all else cs_all[0]), cs_all[-1]
    cols = ["reference", "mean", f"linear c_s={lo:g}", f"linear c_s={hi:g}", f"log c_s={lo:g}", f"log c_s={hi:g}",
            f"gamma c_s={lo:g}", f"log robust c_s={lo:g}"]
    fig = Figure(figsize=(1.5 * len(cols), 1.65 * len(scenes)))
    for i, name in enumerate(scenes):
        ref = images[name]["reference"]
        crops = images[name]["domain_crops"]
        size = max(16, min(ref.shape[:2]) // 4)
        err = np.mean((crops[f"linear c_s={lo:g}"] - ref) ** 2 / (ref**2 + eps), axis=-1)
        win = _window(ndimage.gaussian_filter(err, 1.5), size)
        for j, col in enumerate(cols):
            img = ref if col == "reference" else crops[col]
            ax = fig.add_subplot(len(scenes), len(cols), i * len(cols) + j + 1)
            ax.imshow(tonemap(img[win]), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(col if col == "reference" else f"{col}\n{relmse(img[win], ref[win]):.3f}", fontsize=5.5)
            if j == 0:
                ax.set_ylabel(name, fontsize=7)
    fig.suptitle("domain and c_s crops (window where linear c_s=1 errs most; titles: crop relMSE)", fontsize=8)
    fig.tight_layout()
    figs["domain_crops"] = _save(fig, img_dir / "bench_domain_crops.png", dpi=90)

    # Overhead against pixels and levels.
    ov = results.get("overhead", {})
    if ov.get("sizes"):
        fig = Figure(figsize=(8.4, 3.2))
        ax = fig.add_subplot(1, 2, 1)
        px = [r["pixels"] for r in ov["sizes"]]
        for fld, label in (("reconstruct_s", "reconstruct"), ("ask_s", "ask() round"),
                           ("priorities_s", "priorities only")):
            ax.loglog(px, [r[fld] for r in ov["sizes"]], "o-", label=label)
        ax.set_xlabel("pixels")
        ax.set_ylabel("seconds (one core)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
        ax = fig.add_subplot(1, 2, 2)
        lv = ov.get("levels", [])
        if lv:
            ax.plot([r["levels"] for r in lv], [r["reconstruct_s"] for r in lv], "o-", label="reconstruct")
            ax.plot([r["levels"] for r in lv], [r["ask_s"] for r in lv], "o-", label="ask() round")
            ax.set_xlabel(f"levels ({lv[0]['size']})")
            ax.set_ylabel("seconds")
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=7)
        fig.tight_layout()
        figs["overhead"] = _save(fig, img_dir / "bench_overhead.png")
    return figs


# ---------------------------------------------------------------------------------------- markdown
def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, str):
        return v
    if isinstance(v, bool):
        return "yes" if v else "no"
    v = float(v)
    if not np.isfinite(v):
        return "inf" if v > 0 else "n/a"
    if v == 0:
        return "0"
    if abs(v) >= 1000 or abs(v) < 10 ** -(digits - 1):
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}"


def _eq(row: dict[str, Any] | None) -> str:
    if row is None:
        return "-"
    v = row["equal_error_spp"]
    if not np.isfinite(v):
        return "below floor"
    return f"{v:.0f}" + ("*" if row["equal_error_extrapolated"] else "")


def _shown_path(path: Path) -> str:
    """``path`` relative to the working directory when inside it (no machine paths in the page)."""
    try:
        return path.resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return path.name


def _write_markdown(results: dict[str, Any], figures: dict[str, str], path: Path,
                    results_path: str | Path | None) -> None:
    meta, summary = results["meta"], results["summary"]
    cfg = meta["config"]
    head = summary["headline_spp"]
    scenes = list(results["scenes"])
    methods = [m for m in METHODS if all(m in results["scenes"][s]["methods"] for s in scenes)]
    notes = ""
    if path.is_file():
        old = path.read_text()
        if _NOTES_BEGIN in old and _NOTES_END in old:
            notes = old[old.index(_NOTES_BEGIN) + len(_NOTES_BEGIN):old.index(_NOTES_END)].strip("\n")
    L: list[str] = []
    add = L.append
    cmd = "awr bench" + (" --quick" if meta["mode"] == "quick" else "")
    raw = "not written" if results_path is None else f"`{_shown_path(Path(results_path))}`"
    add("# Benchmarks: the speed/accuracy trade on the bundled path-traced scenes\n")
    add(f"Generated by `{cmd}` (mode **{meta['mode']}**, {meta['date']}, Python {meta['python']}, "
        f"{meta['processor']}); the run took **{meta['run_seconds'] / 60:.1f} minutes** on this shared "
        f"2-core machine. Raw numbers: {raw}. Every figure on this page is "
        "written by that command; the text between the notes markers is kept across runs.\n")
    add(f"Scenes: {', '.join(scenes)}, at {results['scenes'][scenes[0]]['shape'][1]}x"
        f"{results['scenes'][scenes[0]]['shape'][0]} pixels. relMSE = mean of `(x - r)^2 / (r^2 + "
        f"{meta['relmse_epsilon']:g})` over pixels and channels; SSIM on the sRGB-tonemapped image. All methods "
        f"use render seed {cfg['seed']} (the tracer's addressable random numbers make this common random "
        "numbers: method differences are not seed noise). Reconstruction is `reconstruct(buffer)` with the "
        "library defaults unless stated.\n")
    add(f"Open Image Denoise: {meta['oidn']}.\n")
    if notes:
        add(_NOTES_BEGIN)
        add(notes)
        add(_NOTES_END + "\n")
    else:
        add(_NOTES_BEGIN + "\n" + _NOTES_END + "\n")

    add("## Reproduce\n")
    add("```\npython -m awr_denoise.tracer.reference all --spp 4096   # references (once; about 20 min)\n"
        "awr bench --quick                                        # a few minutes\n"
        "awr bench                                                # the full run\n```\n")
    add("`awr bench` is `python -m awr_denoise.benchmark`; it needs the `tracer` and `bench` extras, and "
        "`oidn` for the Open Image Denoise peer.\n")
    add("`--scenes a b` restricts the scenes, `--output-dir DIR` writes the page and figures elsewhere, "
        "`--reference-spp N` re-renders (and caches) any reference below N spp with the tracer's "
        "`load_reference`.\n")

    add("## References and their noise floor\n")
    add("A reference rendered with a finite number of samples has its own variance, which adds a constant "
        "`f` to every relMSE measured against it: `E[relMSE] = true relMSE + f`. `f` is estimated by fitting "
        "`a / N + f` to the uniform Monte Carlo curve (its true relMSE falls exactly as `1 / N`); the bound "
        "is what an independent-sampler reference with that spp would have (the references use the tracer's "
        "Owen-scrambled Sobol' sampler, which converges faster). Equal-error spp below are computed on "
        "floor-corrected errors; an error within the floor cannot be resolved.\n")
    add("| scene | reference spp | sampler | floor `f` (fit) | bound (independent) | uniform relMSE at 1 spp (`a`) | "
        f"uniform relMSE at {cfg['uniform_max_spp']} spp | floor share there |")
    add("|---|---|---|---|---|---|---|---|")
    for name in scenes:
        ref = results["scenes"][name]["reference"]
        last = results["scenes"][name]["uniform_curve"][-1]
        add(f"| {name} | {ref['spp']} | {ref['sampler']} | {_fmt(ref['floor_fit'])} | "
            f"{_fmt(ref.get('floor_bound_independent'))} | {_fmt(ref['uniform_relmse_1spp_fit'])} | "
            f"{_fmt(last['relmse'])} | {last['relmse'] and ref['floor_fit'] / last['relmse']:.0%} |")
    add("")

    add(f"## Headline: equal samples at {head} spp\n")
    add(f"relMSE at {head} spp average, and in parentheses the equal-error spp: the uniform Monte Carlo "
        "sample count with the same (floor-corrected) relMSE, interpolated in log-log on the uniform curve "
        f"(`*`: outside the rendered 4-{cfg['uniform_max_spp']} spp, extrapolated with the fitted `a / N`).\n")
    add("| scene | " + " | ".join(methods) + " | uniform at 512 spp |")
    add("|---" * (len(methods) + 2) + "|")
    for name in scenes:
        m = results["scenes"][name]["methods"]
        cells = []
        for meth in methods:
            r = _row_at(m[meth], head)
            cells.append("-" if r is None else f"{_fmt(r['relmse'])} ({_eq(r)})")
        u512 = _row_at(results["scenes"][name]["uniform_curve"], 512)
        add(f"| {name} | " + " | ".join(cells) + f" | {_fmt(u512['relmse']) if u512 else '-'} |")
    add("")
    if "error_vs_spp" in figures:
        add(f"![relMSE against spp](img/{figures['error_vs_spp']})\n")
    if "crops" in figures:
        add(f"![crops](img/{figures['crops']})\n")

    add("## Goals\n")
    add("| scene | AWR relMSE / uniform at equal spp | AWR at 32 spp <= uniform at 512 spp | AWR better than "
        "skimage | overhead / render time: CPU / wall / 1080p est. |")
    add("|---|---|---|---|---|")
    for name in scenes:
        s = summary["scenes"][name]
        share_big = s.get("overhead_share_1080p_estimate")
        share_cpu = s.get("overhead_share_cpu")
        add(f"| {name} | {_fmt(s.get('awr_vs_uniform_same_spp'), 3)} | {_fmt(s.get('awr_at_or_below_uniform_512'))} | "
            f"{_fmt(s.get('awr_better_than_skimage'))} | "
            f"{'-' if share_cpu is None else format(share_cpu, '.1%')} / "
            f"{'-' if s.get('overhead_share') is None else format(s['overhead_share'], '.1%')} / "
            f"{'-' if share_big is None else format(share_big, '.1%')} |")
    add("")
    add("Overhead share: (time in `ask`/`tell` over all rounds + one `reconstruct`) / tracer time, for AWR "
        f"sampling to {head} spp, as CPU time / wall time / estimated at 1080p. The tracer runs on "
        f"{cfg['threads']} threads, the library on one; CPU time is the robust figure on a shared machine. The "
        "1080p estimate scales the tracer's CPU time with the pixel count and takes the `ask()` and "
        "`reconstruct` times measured at 1080p (section Overhead), with the same number of rounds.\n")
    if summary["flags"]:
        add("### Flags: a default worse than the plain mean\n")
        add("**These are bugs by the project's own rule.**\n")
        for f in summary["flags"]:
            add(f"- {f}")
        add("")
    else:
        add("No method with library defaults was worse than the plain mean on any scene at any spp.\n")

    add("## All metrics\n")
    for name in scenes:
        m = results["scenes"][name]["methods"]
        add(f"### {name}\n")
        add("| method | spp | relMSE | MSE | PSNR (dB) | SSIM | equal-error spp | CPU time (s) | wall time (s) |")
        add("|---|---|---|---|---|---|---|---|---|")
        for meth in methods:
            for r in m[meth]:
                add(f"| {meth} | {r['spp']} | {_fmt(r['relmse'])} | {_fmt(r['mse'])} | {r['psnr']:.2f} | "
                    f"{r['ssim']:.4f} | {_eq(r)} | {r['total_cpu_s']:.2f} | {r['total_s']:.2f} |")
        add("")

    add("## Equal time\n")
    add("Time of the whole loop: tracer, `ask`/`tell` of every round and one reconstruction (or peer "
        "denoiser), as process CPU time (the tracer's two threads both count): wall time on this shared "
        "machine depends on what else runs, CPU time much less. Wall times are in the JSON and the tables "
        f"above. Below: relMSE at {head} spp and, in parentheses, the ratio to uniform Monte Carlo's relMSE at "
        "the same CPU time (interpolated in log-log on the uniform curve; below 1 wins at equal time).\n")
    add("| scene | " + " | ".join(x for x in methods if x != "uniform") + " |")
    add("|---" * len(methods) + "|")
    for name in scenes:
        et = summary["scenes"][name].get("equal_time", {})
        cells = [f"{_fmt(et[x]['relmse'])} ({et[x]['ratio']:.2f})" if x in et else "-"
                 for x in methods if x != "uniform"]
        add(f"| {name} | " + " | ".join(cells) + " |")
    add("")
    if "error_vs_time" in figures:
        add(f"![relMSE against time](img/{figures['error_vs_time']})\n")

    add("## Where the samples went\n")
    add(f"Samples per pixel relative to the mean, at {head} spp, for the two adaptive samplers.\n")
    if "density" in figures:
        add(f"![sample density](img/{figures['density']})\n")

    add("## Smoothing constant and domain\n")
    add(f"Uniform buffers at {cfg['sweep_spp']} spp for {cfg['sweep_seeds']} seeds, reconstructed with "
        "`reconstruct(buffer, c_s=..., domain=...)`. relMSE is the mean over seeds; variance is the "
        "per-pixel variance across seeds (relMSE-weighted); squared bias is the error of the seed-mean "
        "with the variance share and the reference floor removed (it can come out slightly negative where "
        "the bias is below what the seeds resolve).\n")
    add("| scene | plain mean | " + " | ".join(f"best c_s {d}" for d in DOMAINS) + " | " +
        " | ".join(f"{d} at c_s=1" for d in DOMAINS) + " |")
    add("|---" * (2 + 2 * len(DOMAINS)) + "|")
    for name in scenes:
        rows = results["scenes"][name]["c_s_sweep"]
        mean_row = next(r for r in rows if r["domain"] == "mean")
        best = []
        at1 = []
        for d in DOMAINS:
            dr = [r for r in rows if r["domain"] == d]
            b = min(dr, key=lambda r: r["relmse"])
            best.append(f"{b['c_s']:g} ({_fmt(b['relmse'])})")
            one = next((r for r in dr if r["c_s"] == 1.0), None)
            at1.append(_fmt(one["relmse"]) if one else "-")
        add(f"| {name} | {_fmt(mean_row['relmse'])} | " + " | ".join(best) + " | " + " | ".join(at1) + " |")
    add("")
    add("Squared bias / variance at each c_s (log domain, the default):\n")
    cs_vals = cfg["c_s_values"]
    add("| scene | " + " | ".join(f"c_s={c:g}" for c in cs_vals) + " |")
    add("|---" * (1 + len(cs_vals)) + "|")
    for name in scenes:
        rows = [r for r in results["scenes"][name]["c_s_sweep"] if r["domain"] == "log"]
        add(f"| {name} | " + " | ".join(f"{_fmt(r['bias2'], 2)} / {_fmt(r['variance'], 2)}" for r in rows) + " |")
    add("")
    for key, caption in (("cs_relmse", "relMSE against c_s"), ("cs_bias_variance", "bias and variance"),
                         ("domain_crops", "domain crops")):
        if key in figures:
            add(f"![{caption}](img/{figures[key]})\n")

    if any("defaults_sweep" in results["scenes"][s] for s in scenes):
        add("## The other defaults\n")
        first = next(results["scenes"][s]["defaults_sweep"] for s in scenes if "defaults_sweep" in results["scenes"][s])
        spp = first[0]["spp"]
        add(f"relMSE at {spp} spp, mean over {cfg['defaults_seeds']} seeds, one setting changed at a time "
            "(reconstruction settings on uniform buffers; sampler settings with `AdaptiveSampler` and the "
            "default reconstruction; in parentheses the sampler's CPU time as a share of the tracer's). "
            "**Bold**: the library default.\n")
        keys = [(r["group"], r["value"], r["default"]) for r in first]
        add("| setting | " + " | ".join(scenes) + " |")
        add("|---" * (1 + len(scenes)) + "|")
        for group, value, default in keys:
            label = f"{group} = {value}"
            label = f"**{label}**" if default else label
            cells = []
            for s in scenes:
                r = next((x for x in results["scenes"][s].get("defaults_sweep", [])
                          if x["group"] == group and x["value"] == value), None)
                cell = _fmt(r["relmse"]) if r else "-"
                if r and r.get("sampler_cpu_share") is not None:
                    cell += f" ({r['sampler_cpu_share']:.0%})"
                cells.append(cell)
            add(f"| {label} | " + " | ".join(cells) + " |")
        add("")

    ov = results.get("overhead", {})
    if ov.get("sizes"):
        add("## Overhead\n")
        add("One core, median of repeated runs after a warm-up that builds the cached wavelet operators; a "
            "synthetic 4-spp buffer. `ask()` is one adaptive round (priorities + allocation).\n")
        add("| size | reconstruct (s) | per megapixel (s) | ask() round (s) | per megapixel (s) | priorities only (s) |")
        add("|---|---|---|---|---|---|")
        for r in ov["sizes"]:
            add(f"| {r['size']} | {r['reconstruct_s']:.3f} | {r['reconstruct_s_per_mp']:.3f} | {r['ask_s']:.3f} | "
                f"{r['ask_s_per_mp']:.3f} | {r['priorities_s']:.3f} |")
        add("")
        if ov.get("levels"):
            add(f"Against the number of levels at {ov['levels'][0]['size']}:\n")
            add("| levels | reconstruct (s) | ask() round (s) |")
            add("|---|---|---|")
            for r in ov["levels"]:
                add(f"| {r['levels']} | {r['reconstruct_s']:.3f} | {r['ask_s']:.3f} |")
            add("")
        if "overhead" in figures:
            add(f"![overhead](img/{figures['overhead']})\n")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(L).rstrip() + "\n")


# ---------------------------------------------------------------------------------------- CLI
def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the benchmark's options to ``parser`` (shared by ``awr bench`` and ``python -m``)."""
    parser.add_argument("--quick", action="store_true", help="fewer sample counts, seeds and sizes (a few minutes)")
    parser.add_argument("--scenes", nargs="+", metavar="SCENE", default=None, help="bundled scenes (default: all)")
    parser.add_argument("--output-dir", type=Path, default=Path("docs"),
                        help="where benchmarks.md and img/ go (default: docs)")
    parser.add_argument("--results", type=Path, default=None,
                        help="JSON output (default: benchmarks/results/quality.json beside the output dir)")
    parser.add_argument("--reference-spp", type=int, default=None,
                        help="re-render (and cache) references below this spp with the tracer")
    parser.add_argument("--spp", type=int, nargs="+", default=None, help="average spp to measure at")
    parser.add_argument("--size", type=int, nargs=2, metavar=("WIDTH", "HEIGHT"), default=None,
                        help="override the scenes' resolution (references are then rendered on the fly)")
    parser.add_argument("--overhead-sizes", nargs="*", choices=tuple(OVERHEAD_SIZES), default=None, metavar="SIZE",
                        help=f"image sizes of the overhead measurement ({', '.join(OVERHEAD_SIZES)}; none to skip)")
    parser.add_argument("--no-oidn", action="store_true", help="skip Open Image Denoise even if installed")
    parser.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def _config_from_args(args: argparse.Namespace) -> BenchmarkConfig:
    overrides: dict[str, Any] = {}
    if args.scenes:
        overrides["scenes"] = tuple(args.scenes)
    if args.reference_spp is not None:
        overrides["reference_spp"] = args.reference_spp
    if args.spp:
        overrides["spps"] = tuple(sorted(set(args.spp)))
    if args.size:
        overrides["width"], overrides["height"] = args.size
    if args.overhead_sizes is not None:
        overrides["overhead_sizes"] = tuple(args.overhead_sizes)
    if args.no_oidn:
        overrides["oidn"] = False
    return BenchmarkConfig.quick(**overrides) if args.quick else replace(BenchmarkConfig(), **overrides)


def run_from_args(args: argparse.Namespace) -> int:
    """Run the benchmark with options parsed by :func:`add_arguments`; print the summary, return 0.

    Raises ``ValueError`` for inconsistent options (a usage error); a failure of the run itself
    (a missing extra, an unknown scene) prints one line and returns 1.
    """
    config = _config_from_args(args)
    try:
        results = run_benchmark(config, output_dir=args.output_dir, results_path=args.results,
                                plots=not args.no_plots, progress=not args.quiet,
                                mode_name="quick" if args.quick else "full")
    except (ImportError, ValueError) as exc:
        print(f"awr bench: {exc}", file=sys.stderr)
        return 1
    s = results["summary"]
    print(f"{'scene':<14} " + " ".join(f"{m:>16}" for m in s["scenes"][next(iter(s["scenes"]))]["relmse"]))
    for name, entry in s["scenes"].items():
        print(f"{name:<14} " + " ".join(f"{v:>16.5f}" for v in entry["relmse"].values()))
    print(f"relMSE at {s['headline_spp']} spp; OIDN: {results['meta']['oidn']}; "
          f"run time {results['meta']['run_seconds'] / 60:.1f} min")
    for flag in s["flags"]:
        print(f"FLAG: {flag}")
    if args.output_dir is not None:
        print(f"wrote {args.output_dir / 'benchmarks.md'}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``python -m awr_denoise.benchmark [--quick] [--scenes ...] [--output-dir docs]``."""
    parser = add_arguments(argparse.ArgumentParser(prog="python -m awr_denoise.benchmark",
                                                   description=__doc__.splitlines()[0]))
    args = parser.parse_args(argv)
    try:
        return run_from_args(args)
    except ValueError as exc:
        parser.error(str(exc))


if __name__ == "__main__":
    raise SystemExit(main())
