"""Mitsuba 3 in the ask/tell loop: the adapter's throughput, and AWR against Mitsuba's uniform render.

For each scene (the bundled Mitsuba scenes at 256x256, and the Cornell box at 1920x1080):

- **throughput**: a uniform request through :class:`MitsubaRenderer` against ``mi.render`` of the
  same scene at the same spp, interleaved, medians of repeats after two warm-up calls each;
- **equal samples**: Mitsuba uniform at N spp through its own film (box filter) against AWR
  sampling (:class:`AdaptiveSampler`, library defaults) + :func:`reconstruct` through the adapter
  to the same N, and against the plain mean of the AWR buffer; relMSE, absolute MSE and the image
  mean against a high-spp Mitsuba reference (its own noise is reported as a floor);
- **equal time**: AWR's error interpolated (log-log) at the wall time the uniform render took
  (and at its process CPU time, steadier on a shared machine);
- **shares** of the AWR run's time spent in ``ask``, rendering, ``tell`` and ``reconstruct``.

References are rendered with ``mi.render`` in passes (seeds no other run uses) and cached under
``benchmarks/cache/mitsuba/`` (gitignored), keyed by the scene's content (its dict, bitmaps by their
pixels), Mitsuba's version, size and spp; ``--regenerate-references`` renders them again.
Compared runs are seeded by their spp and repeat (:func:`run_seed`), so runs of other settings
(``--initial-spp``, ``--stages``, ``--threads``) at the same spp render the same uniform images.

Usage (from the repository root)::

    nice -n 10 .venv/bin/python benchmarks/bench_mitsuba.py            # full run, about an hour on 2 cores
                                                                       # (40 minutes with cached references)
    .venv/bin/python benchmarks/bench_mitsuba.py --quick               # smoke run, tiny images, writes nothing
    .venv/bin/python benchmarks/bench_mitsuba.py --scenes cornell_box --no-hd --spp 8 32 --update
    .venv/bin/python benchmarks/bench_mitsuba.py --report           # tables of the results file, nothing rendered

Prints markdown tables and writes ``benchmarks/results/mitsuba.json`` (``--output`` elsewhere).
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import inspect
import json
import os
import platform
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from importlib.metadata import version
from pathlib import Path
from typing import Any

import numpy as np

from awr_denoise import AdaptiveSampler, SampleRequest, fused, reconstruct
from awr_denoise.adapters import mitsuba_scenes
from awr_denoise.adapters.mitsuba import MitsubaRenderer
from awr_denoise.bench.records import results_file
from awr_denoise.memory import keep_freed_memory
from awr_denoise.metrics import RELMSE_EPSILON, mse, relmse
from awr_denoise.reconstruct import DEFAULT_WIENER_EXPONENTS
from awr_denoise.sampling import DEFAULT_AWR_INITIAL_SPP

ROOT = Path(__file__).resolve().parent
RESULTS = ROOT / "results" / "mitsuba.json"
CACHE = ROOT / "cache" / "mitsuba"
REFERENCE_SEED = 1_000_000  # reference passes use seeds from here on; no compared run does
REFERENCE_PASS_SPP = 64


def _cli_line(argv: list[str]) -> str:
    return " ".join(["python benchmarks/bench_mitsuba.py", *argv])


def _load_average() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


# ---------------------------------------------------------------------------- reference
def _canonical(mi: Any, value: Any) -> str:
    """A text that changes exactly when the scene dict's content does (bitmaps by their pixels)."""
    if isinstance(value, dict):
        return "{" + ",".join(f"{k}:{_canonical(mi, value[k])}" for k in sorted(value)) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_canonical(mi, v) for v in value) + "]"
    if isinstance(value, mi.Bitmap):
        return "bitmap:" + hashlib.sha256(np.ascontiguousarray(np.array(value)).tobytes()).hexdigest()
    return repr(value)


def _reference_key(renderer: MitsubaRenderer, name: str, spp: int) -> str:
    mi = renderer._mi
    h, w = renderer.shape
    content = _canonical(mi, mitsuba_scenes.scene_dict(name, (h, w))) + version("mitsuba")
    digest = hashlib.sha256(content.encode()).hexdigest()[:12]
    return f"{name}_{h}x{w}_{spp}spp_{digest}"


def reference(renderer: MitsubaRenderer, name: str, spp: int, *, cache: Path, regenerate: bool) -> dict[str, Any]:
    """High-spp Mitsuba film render: mean image and the variance of that mean (from its passes)."""
    path = cache / f"{_reference_key(renderer, name, spp)}.npz"
    if path.exists() and not regenerate:
        data = np.load(path)
        return {"mean": data["mean"], "variance_of_mean": data["variance_of_mean"],
                "seconds": float(data["seconds"]), "cached": True, "spp": spp}
    mi = renderer._mi
    passes = max(2, spp // REFERENCE_PASS_SPP)
    pass_spp = spp // passes
    start = time.perf_counter()
    total = sq = None
    for k in range(passes):
        image = np.array(mi.render(renderer.scene, spp=pass_spp, seed=REFERENCE_SEED + k), dtype=np.float64)
        total = image if total is None else total + image
        sq = image * image if sq is None else sq + image * image
    seconds = time.perf_counter() - start
    mean = total / passes
    variance_of_mean = np.maximum(sq / passes - mean * mean, 0.0) * passes / (passes - 1) / passes
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, mean=mean, variance_of_mean=variance_of_mean, seconds=seconds)
    os.replace(tmp, path)
    return {"mean": mean, "variance_of_mean": variance_of_mean, "seconds": seconds, "cached": False,
            "spp": passes * pass_spp}


def _metrics(image: np.ndarray, ref: dict[str, Any]) -> dict[str, float]:
    r = ref["mean"]
    return {"relmse": relmse(image, r), "mse": mse(image, r), "image_mean": float(image.mean()),
            "mean_bias": float(image.mean() / r.mean() - 1.0)}


# ---------------------------------------------------------------------------- runs
def throughput(renderer: MitsubaRenderer, spp: int, repeats: int) -> dict[str, Any]:
    """Samples per second of the adapter and of ``mi.render`` on a uniform request, interleaved."""
    mi = renderer._mi
    request = SampleRequest.uniform(renderer.shape, spp)
    for k in range(3):  # compile (or load) both kernels before timing
        renderer(request)
        np.array(mi.render(renderer.scene, spp=spp, seed=k))
    ours, theirs, ours_cpu, theirs_cpu, launch = [], [], [], [], []
    for k in range(repeats):
        before = renderer.stats["seconds"]
        t, c = time.perf_counter(), time.process_time()
        renderer(request)
        ours.append(time.perf_counter() - t)
        ours_cpu.append(time.process_time() - c)
        launch.append(renderer.stats["seconds"] - before)
        t, c = time.perf_counter(), time.process_time()
        np.array(mi.render(renderer.scene, spp=spp, seed=100 + k))
        theirs.append(time.perf_counter() - t)
        theirs_cpu.append(time.process_time() - c)
    samples = request.total
    t_ours, t_theirs = statistics.median(ours), statistics.median(theirs)
    # The fixed cost of a call: 64 samples of one pixel, median of 20 calls.
    tiny = (np.zeros(64, np.int64), np.zeros(64, np.int64), np.arange(64))
    calls = []
    for _ in range(20):
        t = time.perf_counter()
        renderer.trace_samples(*tiny)
        calls.append(time.perf_counter() - t)
    return {"spp": spp, "samples": samples, "repeats": repeats,
            "adapter_seconds": t_ours, "mitsuba_seconds": t_theirs,
            "adapter_msamples_per_s": samples / t_ours / 1e6, "mitsuba_msamples_per_s": samples / t_theirs / 1e6,
            "call_ms_64_samples": 1000 * statistics.median(calls[2:]),
            "adapter_launch_seconds": statistics.median(launch),
            "host_share": 1.0 - statistics.median(x / y for x, y in zip(launch, ours)),
            "ratio": t_theirs / t_ours, "cpu_ratio": statistics.median(theirs_cpu) / statistics.median(ours_cpu),
            "adapter_all_seconds": ours, "mitsuba_all_seconds": theirs,
            "adapter_all_cpu_seconds": ours_cpu, "mitsuba_all_cpu_seconds": theirs_cpu}


def uniform_run(renderer: MitsubaRenderer, spp: int, seed: int) -> tuple[np.ndarray, float, float]:
    """Mitsuba's own render at ``spp`` through its film (box filter): image, wall and CPU seconds."""
    t, c = time.perf_counter(), time.process_time()
    image = np.array(renderer._mi.render(renderer.scene, spp=spp, seed=seed), dtype=np.float64)
    return image, time.perf_counter() - t, time.process_time() - c


def awr_run(renderer: MitsubaRenderer, spp: int, seed: int, *, executor: ThreadPoolExecutor | None = None,
            reconstruct_options: dict[str, Any] | None = None, **sampler_options: Any) -> dict[str, Any]:
    """AdaptiveSampler (library defaults, or ``sampler_options``) to ``spp`` through the adapter, then reconstruct
    (library defaults, or ``reconstruct_options``).

    The loop is :meth:`Sampler.run`'s, written out so each part is timed on its own. With
    ``executor`` (``--threads``) the sampler and the reconstruction use its threads between renders.
    """
    renderer.seed = seed
    sampler = AdaptiveSampler(renderer.shape, seed=seed, executor=executor, **sampler_options)
    goal = int(round(spp * renderer.shape[0] * renderer.shape[1]))
    seconds = {"ask": 0.0, "render": 0.0, "tell": 0.0, "reconstruct": 0.0}
    rounds = 0
    cpu = time.process_time()
    while sampler.total_samples < goal:
        t0 = time.perf_counter()
        request = sampler.ask(min(sampler.default_budget(), goal - sampler.total_samples))
        t1 = time.perf_counter()
        buffer = renderer(request)
        t2 = time.perf_counter()
        sampler.tell(request, buffer)
        t3 = time.perf_counter()
        seconds["ask"] += t1 - t0
        seconds["render"] += t2 - t1
        seconds["tell"] += t3 - t2
        rounds += 1
    t = time.perf_counter()
    image = reconstruct(sampler.buffer, executor=executor, **(reconstruct_options or {}))
    seconds["reconstruct"] = time.perf_counter() - t
    return {"image": image, "plain_mean": np.array(sampler.buffer.mean), "seconds": sum(seconds.values()),
            "cpu_seconds": time.process_time() - cpu, "parts": seconds, "rounds": rounds, "spp_max": int(sampler.buffer.count.max())}


def _interpolate_loglog(x: float, xs: list[float], ys: list[float]) -> float | None:
    """y at x on the piecewise log-log line through (xs, ys) sorted by xs; None outside their range."""
    order = np.argsort(xs)
    lx, ly = np.log(np.asarray(xs)[order]), np.log(np.asarray(ys)[order])
    if not lx[0] <= np.log(x) <= lx[-1]:
        return None
    return float(np.exp(np.interp(np.log(x), lx, ly)))


def equal_time(uniform: list[dict[str, Any]], awr: list[dict[str, Any]], key: str = "seconds") -> list[dict[str, Any]]:
    """AWR's error at the time (``key``: wall ``seconds`` or ``cpu_seconds``) of each uniform render,
    and the ratio to the uniform error."""
    rows = []
    times = [a[key] for a in awr]
    for u in uniform:
        row: dict[str, Any] = {"uniform_spp": u["spp"], key: u[key]}
        for metric in ("relmse", "mse"):
            at = _interpolate_loglog(u[key], times, [a["awr"][metric] for a in awr])
            row[f"awr_{metric}"] = at
            row[f"{metric}_ratio"] = None if at is None else at / u["uniform"][metric]
            # The AWR buffer's plain mean (no reconstruction; its time still counts the reconstruction).
            plain = _interpolate_loglog(u[key], times, [a["plain_mean"][metric] for a in awr])
            row[f"plain_mean_{metric}_ratio"] = None if plain is None else plain / u["uniform"][metric]
        row["awr_spp_at_time"] = _interpolate_loglog(u[key], times, [a["spp"] for a in awr])
        if row["awr_spp_at_time"] is None:
            row["note"] = ("AWR's cheapest run takes longer than this uniform render" if u[key] < min(times)
                           else "longer than AWR's longest run")
        rows.append(row)
    return rows


def awr_sample_counts(spps: list[int], initial_spp: int) -> list[int]:
    """The spp of the AWR runs: the uniform ones, half the smallest, and the sampler's first round alone.

    The first round (``initial_spp``, uniform, then a reconstruction) is AWR's cheapest run: the
    equal-time comparison has an AWR error only at times from that run's on (below it, "n/a").

    >>> awr_sample_counts([8, 16, 32], 2)
    [2, 4, 8, 16, 32]
    >>> awr_sample_counts([4, 8], 4)
    [4, 8]
    """
    half = min(spps) // 2
    return sorted({initial_spp, *spps} | ({half} if half > initial_spp else set()))


def run_seed(seed: int, spp: int, repeat: int) -> int:
    """The seed of a compared run, keyed by its spp (a power of two) and repeat.

    Runs of different settings (``--initial-spp``, ``--stages``, ...) at the same spp and repeat get
    the same seed, whatever other sample counts their run lists hold: their uniform renders are the
    same renders, and AWR runs whose samplers start alike draw the same first samples. The default
    list (2, 4, 8, ...) keeps the seeds of the versions that numbered runs by their place in it.

    >>> run_seed(1, 2, 0), run_seed(1, 32, 2)
    (1001, 5003)
    """
    if spp < 2 or spp & (spp - 1) or not 0 <= repeat < 999:
        raise ValueError(f"run_seed needs a power-of-two spp >= 2 and a repeat below 999, got {spp} and {repeat}")
    return seed + 1000 * (spp.bit_length() - 1) + repeat


def bench_scene(name: str, shape: tuple[int, int], *, spps: list[int], reference_spp: int, repeats: int,
                throughput_spp: int, cache: Path, regenerate: bool, seed: int,
                sampler_options: dict[str, Any] | None = None, reconstruct_options: dict[str, Any] | None = None,
                executor: ThreadPoolExecutor | None = None) -> dict[str, Any]:
    run_options = dict(sampler_options or {}, executor=executor, reconstruct_options=reconstruct_options)
    renderer = MitsubaRenderer(name, shape=shape, seed=seed)
    print(f"[{name} {shape[1]}x{shape[0]}] throughput at {throughput_spp} spp", flush=True)
    result: dict[str, Any] = {"scene": name, "shape": list(shape),
                              "throughput": throughput(renderer, throughput_spp, max(7, repeats))}
    print(f"[{name}] reference at {reference_spp} spp", flush=True)
    ref = reference(renderer, name, reference_spp, cache=cache, regenerate=regenerate)
    eps = RELMSE_EPSILON
    result["reference"] = {"spp": ref["spp"], "cached": ref["cached"], "seconds": ref["seconds"],
                           "image_mean": float(ref["mean"].mean()),
                           "mse_floor": float(ref["variance_of_mean"].mean()),
                           "relmse_floor": float((ref["variance_of_mean"] / (ref["mean"] ** 2 + eps)).mean())}
    awr_run(renderer, min(spps), seed + 999, **run_options)  # warm-up: kernels, wavelet operators
    awr_spps = awr_sample_counts(spps, run_options.get("initial_spp", DEFAULT_AWR_INITIAL_SPP))
    uniform_points, awr_points = [], []
    for spp in awr_spps:
        print(f"[{name}] {spp} spp x {repeats}", flush=True)
        runs_u, runs_a = [], []
        for r in range(repeats):
            seed_r = run_seed(seed, spp, r)
            if spp in spps:
                image, seconds, cpu = uniform_run(renderer, spp, seed_r)
                runs_u.append({"seconds": seconds, "cpu_seconds": cpu, **_metrics(image, ref)})
            run = awr_run(renderer, spp, seed_r, **run_options)
            runs_a.append({"seconds": run["seconds"], "cpu_seconds": run["cpu_seconds"], "parts": run["parts"],
                           "rounds": run["rounds"],
                           "spp_max": run["spp_max"], "awr": _metrics(run["image"], ref),
                           "plain_mean": _metrics(run["plain_mean"], ref)})
        if runs_u:
            uniform_points.append({"spp": spp, "seconds": statistics.median(x["seconds"] for x in runs_u),
                                   "cpu_seconds": statistics.median(x["cpu_seconds"] for x in runs_u),
                                   "uniform": {k: float(np.mean([x[k] for x in runs_u]))
                                               for k in ("relmse", "mse", "image_mean", "mean_bias")}})
        parts = {k: statistics.median(x["parts"][k] for x in runs_a) for k in runs_a[0]["parts"]}
        total = statistics.median(x["seconds"] for x in runs_a)
        awr_points.append({
            "spp": spp, "seconds": total, "cpu_seconds": statistics.median(x["cpu_seconds"] for x in runs_a),
            "rounds": runs_a[0]["rounds"], "spp_max": runs_a[0]["spp_max"],
            "parts_seconds": parts, "shares": {k: v / sum(parts.values()) for k, v in parts.items()},
            "awr": {k: float(np.mean([x["awr"][k] for x in runs_a])) for k in ("relmse", "mse", "image_mean", "mean_bias")},
            "plain_mean": {k: float(np.mean([x["plain_mean"][k] for x in runs_a]))
                           for k in ("relmse", "mse", "image_mean", "mean_bias")}})
    by_spp = {a["spp"]: a for a in awr_points}
    result["equal_samples"] = [
        {"spp": u["spp"], "uniform": u["uniform"], "awr": by_spp[u["spp"]]["awr"],
         "awr_plain_mean": by_spp[u["spp"]]["plain_mean"],
         "relmse_ratio": by_spp[u["spp"]]["awr"]["relmse"] / u["uniform"]["relmse"],
         "mse_ratio": by_spp[u["spp"]]["awr"]["mse"] / u["uniform"]["mse"],
         "uniform_seconds": u["seconds"], "awr_seconds": by_spp[u["spp"]]["seconds"]}
        for u in uniform_points]
    result["uniform_runs"] = uniform_points
    result["awr_runs"] = awr_points
    _derive(result)
    return result


def _derive(result: dict[str, Any]) -> None:
    """The equal-time comparisons, from a scene's stored uniform and AWR points."""
    result["equal_time"] = equal_time(result["uniform_runs"], result["awr_runs"])
    result["equal_cpu_time"] = equal_time(result["uniform_runs"], result["awr_runs"], "cpu_seconds")


# ---------------------------------------------------------------------------- report
def _fmt(x: float | None, spec: str = ".3g") -> str:
    return "n/a" if x is None else format(x, spec)


def markdown(results: dict[str, Any]) -> str:
    """The tables docs/integrate_mitsuba.md shows, from a results dict."""
    lines = ["| scene | size | spp | adapter Msamples/s | mi.render Msamples/s | ratio (wall) | ratio (CPU) "
             "| ms per call of 64 samples | host share of a call |", "|---|---|---|---|---|---|---|---|---|"]
    for s in results["scenes"]:
        t = s["throughput"]
        lines.append(f"| {s['scene']} | {s['shape'][1]}x{s['shape'][0]} | {t['spp']} | "
                     f"{t['adapter_msamples_per_s']:.2f} | {t['mitsuba_msamples_per_s']:.2f} | {t['ratio']:.2f} | "
                     f"{t['cpu_ratio']:.2f} | {_fmt(t.get('call_ms_64_samples'), '.1f')} | "
                     f"{_fmt(100 * t['host_share'] if 'host_share' in t else None, '.0f')}% |")
    lines += ["", "| scene | size | spp | relMSE uniform | relMSE AWR | ratio | MSE uniform | MSE AWR | ratio "
              "| MSE AWR plain mean | mean bias uniform / AWR / AWR plain mean |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in results["scenes"]:
        for e in s["equal_samples"]:
            lines.append(
                f"| {s['scene']} | {s['shape'][1]}x{s['shape'][0]} | {e['spp']} | {e['uniform']['relmse']:.4g} | "
                f"{e['awr']['relmse']:.4g} | {e['relmse_ratio']:.2f} | {e['uniform']['mse']:.4g} | "
                f"{e['awr']['mse']:.4g} | {e['mse_ratio']:.2f} | {e['awr_plain_mean']['mse']:.4g} | "
                f"{100 * e['uniform']['mean_bias']:+.2f}% / {100 * e['awr']['mean_bias']:+.2f}% / "
                f"{100 * e['awr_plain_mean']['mean_bias']:+.2f}% |")
    lines += ["", "| scene | size | uniform spp | wall s | AWR spp in that time | relMSE ratio | MSE ratio "
              "| plain mean relMSE / MSE ratio | CPU s | AWR spp in that CPU time | relMSE ratio | MSE ratio |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in results["scenes"]:
        for e, c in zip(s["equal_time"], s["equal_cpu_time"]):
            lines.append(f"| {s['scene']} | {s['shape'][1]}x{s['shape'][0]} | {e['uniform_spp']} | "
                         f"{e['seconds']:.2f} | {_fmt(e['awr_spp_at_time'], '.1f')} | {_fmt(e['relmse_ratio'], '.2f')} | "
                         f"{_fmt(e['mse_ratio'], '.2f')} | {_fmt(e['plain_mean_relmse_ratio'], '.2f')} / "
                         f"{_fmt(e['plain_mean_mse_ratio'], '.2f')} | {c['cpu_seconds']:.2f} | "
                         f"{_fmt(c['awr_spp_at_time'], '.1f')} | {_fmt(c['relmse_ratio'], '.2f')} | "
                         f"{_fmt(c['mse_ratio'], '.2f')} |")
    lines += ["", "| scene | size | spp | AWR seconds | ask | render | tell | reconstruct | rounds |",
              "|---|---|---|---|---|---|---|---|---|"]
    for s in results["scenes"]:
        for a in s["awr_runs"]:
            sh = a["shares"]
            lines.append(f"| {s['scene']} | {s['shape'][1]}x{s['shape'][0]} | {a['spp']} | {a['seconds']:.2f} | "
                         f"{100 * sh['ask']:.1f}% | {100 * sh['render']:.1f}% | {100 * sh['tell']:.1f}% | "
                         f"{100 * sh['reconstruct']:.1f}% | {a['rounds']} |")
    return "\n".join(lines)


def _defaults() -> dict[str, Any]:
    """The library defaults the AWR runs used (read from the signatures, not retyped)."""
    def kw(fn: Any) -> dict[str, Any]:
        return {k: p.default for k, p in inspect.signature(fn).parameters.items()
                if p.default is not inspect.Parameter.empty and isinstance(p.default, (int, float, str, type(None)))}
    return {"AdaptiveSampler": kw(AdaptiveSampler.__init__), "reconstruct": kw(reconstruct)}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="smoke run: tiny images, few spp, writes only with --output")
    parser.add_argument("--scenes", nargs="+", choices=mitsuba_scenes.ALL_SCENES, default=list(mitsuba_scenes.SCENE_NAMES))
    parser.add_argument("--size", type=int, nargs=2, metavar=("H", "W"), default=[256, 256])
    parser.add_argument("--spp", type=int, nargs="+", default=[8, 16, 32, 64, 128])
    parser.add_argument("--reference-spp", type=int, default=2048)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--throughput-spp", type=int, default=16)
    parser.add_argument("--no-hd", action="store_true", help="skip the Cornell box at 1920x1080")
    parser.add_argument("--hd-spp", type=int, nargs="+", default=[8, 16, 32])
    parser.add_argument("--hd-reference-spp", type=int, default=512)
    parser.add_argument("--hd-repeats", type=int, default=1)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--round-growth", type=float, default=None,
                        help="AdaptiveSampler's round_growth instead of its default (fewer, larger rounds when larger)")
    parser.add_argument("--initial-spp", type=int, default=None,
                        help="AdaptiveSampler's initial_spp (its uniform first round) instead of its default; "
                             "the AWR runs start there")
    parser.add_argument("--uniform-fraction", type=float, default=None,
                        help="AdaptiveSampler's uniform_fraction instead of its default (0): the share of every "
                             "round spread uniformly")
    parser.add_argument("--stages", type=int, default=None, choices=range(1, 2 + len(DEFAULT_WIENER_EXPONENTS)),
                        help="reconstruct()'s stages for the AWR runs instead of its default (2: one Wiener stage, "
                             "the cheaper trade of docs/reconstruction.md)")
    parser.add_argument("--threads", type=int, default=1,
                        help="threads of the executor the sampler and the reconstruction use between renders "
                             "(default 1: none; Mitsuba's own threads are unchanged)")
    parser.add_argument("--keep-freed-memory", action="store_true",
                        help="the memory setting awr makes when it starts (awr_denoise.memory.keep_freed_memory), "
                             "as awr render --renderer mitsuba runs; default: glibc's, as a Python caller has it")
    parser.add_argument("--cache", type=Path, default=CACHE)
    parser.add_argument("--regenerate-references", action="store_true")
    parser.add_argument("--update", action="store_true",
                        help="keep the other scenes of an existing results file; replace only those run now")
    parser.add_argument("--output", type=results_file, default=None, help=f"results JSON (default {RESULTS.name} in "
                        "benchmarks/results; --quick writes nothing unless given)")
    parser.add_argument("--report", action="store_true",
                        help="render nothing: recompute the derived comparisons of the results file and print its tables")
    args = parser.parse_args(argv)
    # Runs are seeded by their spp (run_seed): every compared sample count is a power of two.
    for option, values in (("--spp", args.spp), ("--hd-spp", args.hd_spp),
                           ("--initial-spp", [args.initial_spp] if args.initial_spp is not None else [])):
        if any(v < 2 or v & (v - 1) for v in values):
            parser.error(f"{option} takes powers of two from 2 on (runs are seeded by their spp), got {values}")
    if args.uniform_fraction is not None and not 0 <= args.uniform_fraction <= 1:
        parser.error(f"--uniform-fraction takes 0 to 1, got {args.uniform_fraction}")
    if not 1 <= min(args.repeats, args.hd_repeats) <= max(args.repeats, args.hd_repeats) < 999:
        parser.error("--repeats and --hd-repeats take 1 to 998")
    if args.report:
        path = args.output or RESULTS
        results = json.loads(path.read_text())
        for scene in results["scenes"]:
            _derive(scene)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(results, indent=1, default=float) + "\n")
        os.replace(tmp, path)
        print(markdown(results))
        return 0
    if args.quick:
        args.size, args.spp, args.reference_spp, args.repeats = [24, 32], [4, 8], 256, 1
        args.throughput_spp, args.no_hd = 4, True
        if args.scenes == list(mitsuba_scenes.SCENE_NAMES):
            args.scenes = ["cornell_box"]
    output = args.output if args.output is not None else (None if args.quick else RESULTS)
    kept = keep_freed_memory() if args.keep_freed_memory else False  # before any large array

    cases = [(name, tuple(args.size), args.spp, args.reference_spp, args.repeats) for name in args.scenes]
    if not args.no_hd:
        cases.append(("cornell_box", (1080, 1920), args.hd_spp, args.hd_reference_spp, args.hd_repeats))
    results: dict[str, Any] = {
        "description": (
            "Mitsuba 3 through the awr-denoise adapter. throughput: uniform request through MitsubaRenderer vs "
            "mi.render, same scene and spp, medians of interleaved repeats after warm-up; ratio = adapter "
            "throughput / mi.render throughput (cpu_ratio: the same from process CPU time); call_ms_64_samples: "
            "the adapter's fixed cost, one call of 64 samples; host_share: the share of an adapter call "
            "spent outside its Dr.Jit launches and read-back (listing, float64 accumulation, the buffer). equal_samples: Mitsuba uniform (its film, box filter) vs "
            "AdaptiveSampler + reconstruct through the adapter (library defaults) at the same spp; metrics "
            "against a high-spp mi.render reference: relMSE = mean((x-r)^2/(r^2+eps)), MSE, image mean and "
            "mean_bias = mean(x)/mean(r)-1, averaged over repeats; awr_plain_mean is the AWR buffer's mean "
            "without reconstruction. equal_time: AWR's error interpolated (log-log) at the uniform render's "
            "wall time (median of repeats); ratio < 1 means AWR wins; plain_mean_*_ratio: the same for the AWR "
            "buffer's plain mean (its time still includes the reconstruction); equal_cpu_time: the same at the process CPU "
            "time (all threads; steadier than wall time on a shared machine). awr_runs.shares: share of the AWR run's "
            "time in ask, render (the adapter), tell and reconstruct. reference.mse_floor/relmse_floor: the "
            "reference's own noise, included in every error figure."),
        "command": _cli_line(argv),
        "date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "load_average_1_5_15min": {"start": _load_average()},
        "machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0], "platform": platform.platform(),
                    "numpy": np.__version__, "mitsuba": version("mitsuba"), "drjit": version("drjit"),
                    "awr_denoise": version("awr-denoise")},
        "settings": {"relmse_eps": RELMSE_EPSILON, "variant": "llvm_ad_rgb", "seed": args.seed,
                     "kernels": fused.backend(),  # AWR_DENOISE_KERNELS: the compiled loops or numpy's
                     "reference_pass_spp": REFERENCE_PASS_SPP, "timing": "wall clock, median of repeats",
                     "library_defaults": _defaults(),
                     "sampler_options": {name: value for name, value in (("round_growth", args.round_growth),
                                                                         ("initial_spp", args.initial_spp),
                                                                         ("uniform_fraction", args.uniform_fraction))
                                         if value is not None},
                     "reconstruct_options": {} if args.stages is None else {"stages": args.stages},
                     "library_threads": args.threads, "keep_freed_memory": kept},
        "scenes": [],
    }
    pool = ThreadPoolExecutor(args.threads) if args.threads > 1 else None
    try:
        for name, shape, spps, reference_spp, repeats in cases:
            results["scenes"].append(bench_scene(
                name, shape, spps=spps, reference_spp=reference_spp, repeats=repeats,
                throughput_spp=args.throughput_spp if shape[0] * shape[1] <= 512 * 512 else 4,
                cache=args.cache, regenerate=args.regenerate_references, seed=args.seed,
                sampler_options=results["settings"]["sampler_options"],
                reconstruct_options=results["settings"]["reconstruct_options"], executor=pool))
    finally:
        if pool is not None:
            pool.shutdown()
    results["load_average_1_5_15min"]["end"] = _load_average()
    if args.update and output is not None and output.exists():
        previous = json.loads(output.read_text())
        ran = {(s["scene"], tuple(s["shape"])) for s in results["scenes"]}
        kept = [s for s in previous.get("scenes", []) if (s["scene"], tuple(s["shape"])) not in ran]
        for s in results["scenes"]:
            s["run"] = {k: results[k] for k in ("command", "date_utc", "load_average_1_5_15min")}
        results["scenes"] = kept + results["scenes"]
        results["command"] = "; ".join(dict.fromkeys([previous.get("command", ""), results["command"]]))
    for s in results["scenes"]:
        s.setdefault("run", {k: results[k] for k in ("command", "date_utc", "load_average_1_5_15min")})
    print(markdown(results))
    if output is not None:
        output.parent.mkdir(parents=True, exist_ok=True)
        tmp = output.with_suffix(".tmp")
        tmp.write_text(json.dumps(results, indent=1, default=float) + "\n")
        os.replace(tmp, output)
        print(f"wrote {output.relative_to(ROOT.parent) if output.is_relative_to(ROOT.parent) else output.name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
