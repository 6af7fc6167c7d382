"""Guides and features in the reconstruction: the measurements behind docs/guides.md.

Run from the repository root (each section updates its part of the JSON)::

    .venv/bin/python benchmarks/bench_guides.py quality     # bundled tracer + Mitsuba 3 scenes, 8-32 spp
    .venv/bin/python benchmarks/bench_guides.py samplers    # uniform vs AWR sampling, with and without OIDN
    .venv/bin/python benchmarks/bench_guides.py synthetic   # known clean images: good and wrong guides, gate on/off
    .venv/bin/python benchmarks/bench_guides.py ablations   # the gate and the a-trous passes on the tracer's scenes
    .venv/bin/python benchmarks/bench_guides.py avenues     # what else was tried, every scene at 32 spp
    .venv/bin/python benchmarks/bench_guides.py features    # what limits the features: noise-free ones, demodulation
    .venv/bin/python benchmarks/bench_guides.py rules       # the feature pilot's two rules, each scene and group
    .venv/bin/python benchmarks/bench_guides.py pbrt        # a third renderer: the pbrt-v4 files in tests/data
    .venv/bin/python benchmarks/bench_guides.py auxiliary   # OIDN's albedo and normal: prefiltered, as noisy, none
    .venv/bin/python benchmarks/bench_guides.py tolerance   # the guard's tolerance with a guide: scenes, wrong guides
    .venv/bin/python benchmarks/bench_guides.py stein       # Stein's estimate on rendered noise, per image
    .venv/bin/python benchmarks/bench_guides.py crops       # docs/img/guides_*.png
    .venv/bin/python benchmarks/bench_guides.py tables      # print the stored results

``quality`` renders every scene with uniform sampling and every feature (albedo, normal, depth)
in disjoint sample groups (renderer seeds 0, 1, ...; nested 8, 16, 32 spp; cached under
``--cache``) and compares, against the scene's reference: the plain mean, the default
reconstruction, the default with the feature pilot (``features=True``), the default with the
OIDN guide (``guide=guides.oidn``: Open Image Denoise with the albedo and normal) and OIDN alone:
relMSE, MSE and the image mean. The bundled tracer's scenes are 128x128 with their 4096-spp
references; the Mitsuba 3 scenes run through the ``mitsuba`` renderer (skipped with a notice when
it is not installed), 256x256 against the 1024-spp references ``bench_reconstruct.py`` caches
(the same ``--cache`` shares them). Results: ``benchmarks/results/guides.json`` (``--output``
another file and ``--images`` another folder, which a trial run keeps off the stored ones).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import itertools
import json
import os
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from awr_denoise import AdaptiveSampler, SampleBuffer, SampleRequest, UniformSampler, guided, guides, projection, reconstruct
from awr_denoise._checks import MAX_SPP, whole_option
from awr_denoise._window_sums import window_sum
from awr_denoise.bench import update_section
from awr_denoise.bench.records import results_file
from awr_denoise.io.png import write_preview
from awr_denoise.metrics import mean_error, mse, relmse
from awr_denoise.prepare import filled_mean
from awr_denoise.renderers import create_renderer
from awr_denoise.sure import DEFAULT_GUIDED_TOLERANCE, DEFAULT_WINDOW, sure_blend
from awr_denoise.synthetic import SyntheticRenderer, make_scene
from awr_denoise.wiener import chain, rademacher_probes

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_reconstruct import (MITSUBA_SCENES, MITSUBA_SHAPE, TRACER_SCENES, _mitsuba_available,  # noqa: E402
                              check_scenes, quality_scenes, recorded_command, reference,
                              unguided_guard, uniform_buffers)

ROOT = Path(__file__).resolve().parent
RESULTS = ROOT / "results" / "guides.json"
IMAGES = ROOT.parent / "docs" / "img"
SPPS = (8, 16, 32)
METHODS = ("plain", "default", "default + features", "default + OIDN guide", "default + OIDN guide, alpha 0.75", "OIDN")
CROP_METHODS = ("plain", "default", "default + features", "default + OIDN guide", "OIDN")
GUIDE_ALPHA = {"guide": guides.oidn, "wiener_exponents": (0.75, 0.75)}
"""The OIDN guide with a more relative last Wiener stage (``alpha`` 0.75 instead of 0.4)."""


def _image(method: str, buffer: SampleBuffer) -> np.ndarray:
    if method == "plain":
        return filled_mean(buffer)
    if method == "OIDN":
        return guides.oidn(buffer)
    options = {"default": {}, "default + features": {"features": True},
               "default + OIDN guide": {"guide": guides.oidn}, "default + OIDN guide, alpha 0.75": GUIDE_ALPHA}[method]
    return reconstruct(buffer, **options)


# ---------------------------------------------------------------------------- buffers
def feature_buffers(renderer: str, scene: str, shape: tuple[int, int] | None, spps: tuple[int, ...], group: int,
                    cache: Path) -> dict[int, SampleBuffer]:
    """Group ``group``'s buffers with every feature at every spp (seed ``group``, samples added in order)."""
    return uniform_buffers(renderer, scene, shape, spps, group, cache, prefix="guides_", features="all")


# ---------------------------------------------------------------------------- quality
def _measure(image: np.ndarray, x: np.ndarray, ref: np.ndarray, seconds: float) -> dict[str, Any]:
    return {"relmse": relmse(image, ref), "mse": mse(image, ref), "mean_error": mean_error(image, x),
            "seconds": seconds}


def _scene_buffers(scenes: list[tuple[str, str, tuple[int, int] | None]], spps: tuple[int, ...], groups: int,
                   cache: Path) -> Iterator[tuple[dict[str, Any], SampleBuffer, np.ndarray]]:
    """Every scene's buffers with every feature, group by group and spp by spp: a row's keys, the buffer and the
    scene's reference."""
    for renderer, scene, shape in scenes:
        ref = reference(renderer, scene, shape, cache)
        for g in range(groups):
            for spp, buffer in feature_buffers(renderer, scene, shape, spps, g, cache).items():
                yield {"renderer": renderer, "scene": scene, "spp": spp, "group": g}, buffer, ref
        print(f"{renderer} {scene}: done", flush=True)


def quality(scenes: list[tuple[str, str, tuple[int, int] | None]], spps: tuple[int, ...], groups: int,
            cache: Path) -> list[dict[str, Any]]:
    rows = []
    for keys, buffer, ref in _scene_buffers(scenes, spps, groups, cache):
        x = filled_mean(buffer)
        for method in METHODS:
            start = time.perf_counter()
            image = _image(method, buffer)
            rows.append({**keys, "method": method, **_measure(image, x, ref, time.perf_counter() - start)})
    return rows


_SHORT = {"default + features": "features", "default + OIDN guide": "guide",
          "default + OIDN guide, alpha 0.75": "guide alpha 0.75", "OIDN": "OIDN"}


def _mean(rows: list[dict], key: str, **where: Any) -> float:
    values = [r[key] for r in rows if all(r[k] == v for k, v in where.items())]
    return float(np.mean(values)) if values else float("nan")


def quality_tables(rows: list[dict]) -> None:
    """Markdown: relMSE of every method; relMSE and MSE against the default, the plain mean and OIDN."""
    methods = [m for m in METHODS if any(r["method"] == m for r in rows)]
    print("\n| renderer | scene | spp | " + " | ".join(f"relMSE {m}" for m in methods) + " |")
    print("|---|---|---|" + "---|" * len(methods))
    scenes = list(dict.fromkeys((r["renderer"], r["scene"]) for r in rows))
    for renderer, scene in scenes:
        for spp in sorted({r["spp"] for r in rows if r["scene"] == scene}):
            w = {"renderer": renderer, "scene": scene, "spp": spp}
            print(f"| {renderer} | {scene} | {spp} | "
                  + " | ".join(f"{_mean(rows, 'relmse', method=m, **w):.5f}" for m in methods) + " |")
    a = "default + OIDN guide, alpha 0.75"
    shown = [m for m in ("default + features", "default + OIDN guide", a, "OIDN") if m in methods]
    print("\n| scene | spp | features / default (relMSE, MSE) | guide / default (relMSE, MSE) | guide / OIDN relMSE "
          + ("| guide, alpha 0.75 / default (relMSE, MSE) | guide, alpha 0.75 / OIDN relMSE " if a in methods else "")
          + f"| MSE / plain (default, {', '.join(_SHORT[m] for m in shown)}) "
          + f"| worst mean error % ({', '.join(_SHORT[m] for m in shown)}) |")
    print("|---|---|---|---|---|---|---|" + ("---|---|" if a in methods else ""))
    for renderer, scene in scenes:
        for spp in sorted({r["spp"] for r in rows if r["scene"] == scene}):
            w = {"renderer": renderer, "scene": scene, "spp": spp}
            rel = {m: _mean(rows, "relmse", method=m, **w) for m in methods}
            sq = {m: _mean(rows, "mse", method=m, **w) for m in methods}
            worst = {m: max(r["mean_error"] for r in rows if r["method"] == m and all(r[k] == v for k, v in w.items()))
                     for m in methods}
            f, g, o = "default + features", "default + OIDN guide", "OIDN"
            alpha = (f"{rel[a] / rel['default']:.2f}, {sq[a] / sq['default']:.2f} | {rel[a] / rel[o]:.2f} | "
                     if a in methods else "")
            print(f"| {scene} | {spp} | {rel[f] / rel['default']:.2f}, {sq[f] / sq['default']:.2f} | "
                  f"{rel[g] / rel['default']:.2f}, {sq[g] / sq['default']:.2f} | {rel[g] / rel[o]:.2f} | " + alpha
                  + ", ".join(f"{sq[m] / sq['plain']:.2f}" for m in ("default", *shown))
                  + " | " + ", ".join(f"{100 * worst[m]:.2f}" for m in shown) + " |")


# ---------------------------------------------------------------------------- samplers
def samplers(scenes: tuple[str, ...], spps: tuple[int, ...], seed: int) -> list[dict[str, Any]]:
    """Equal samples, bundled tracer: uniform and AWR sampling, each reconstructed by default, with the
    OIDN guide, and by OIDN alone (does AWR's sampler help a neural prior?)."""
    from awr_denoise import tracer  # the bundled tracer's own cached references
    rows = []
    for scene in scenes:
        ref = np.asarray(tracer.load_reference(scene), dtype=np.float64)
        for kind, make in (("uniform", UniformSampler), ("awr", AdaptiveSampler)):
            renderer = create_renderer("tracer", scene, seed=seed, features="all")
            sampler = make(ref.shape[:2], seed=seed)
            for spp in sorted(spps):
                buffer = sampler.run(renderer, spp)
                for method in ("default", "default + OIDN guide", "OIDN"):
                    image = _image(method, buffer)
                    rows.append({"scene": scene, "sampler": kind, "spp": spp, "method": method,
                                 "relmse": relmse(image, ref), "mse": mse(image, ref)})
            getattr(renderer, "close", lambda: None)()
        print(f"{scene}: done", flush=True)
    return rows


def sampler_table(rows: list[dict]) -> None:
    methods = ("default", "default + OIDN guide", "OIDN")
    print("\n| scene | spp | " + " | ".join(f"uniform / awr relMSE, {m}" for m in methods)
          + " | uniform + OIDN / awr + guide (relMSE, MSE) |")
    print("|---|---|" + "---|" * (len(methods) + 1))
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for spp in sorted({r["spp"] for r in rows}):
            v = {(r["sampler"], r["method"]): r for r in rows if r["scene"] == scene and r["spp"] == spp}
            cells = [f"{v['uniform', m]['relmse'] / v['awr', m]['relmse']:.2f}" for m in methods]
            a, b = v["uniform", "OIDN"], v["awr", "default + OIDN guide"]
            print(f"| {scene} | {spp} | " + " | ".join(cells)
                  + f" | {a['relmse'] / b['relmse']:.2f}, {a['mse'] / b['mse']:.2f} |")


# ---------------------------------------------------------------------------- synthetic
class _Passes:
    """The feature pilot with ``iterations`` a-trous passes, for one measurement."""

    def __init__(self, iterations: int = guided.ATROUS_ITERATIONS) -> None:
        self.iterations = iterations

    def __enter__(self) -> None:
        self.saved = pilot = guided.feature_pilot
        guided.feature_pilot = lambda buffer, image: pilot(buffer, image, iterations=self.iterations)

    def __exit__(self, *exc: object) -> None:
        guided.feature_pilot = self.saved


def _ungated_share(candidate: np.ndarray, buffer: SampleBuffer) -> np.ndarray:
    """:func:`awr_denoise.guided.trust` replaced: every pilot fully trusted (no gate)."""
    return np.ones(candidate.shape[:2] + (1,))


def _per_pixel_share(candidate: np.ndarray, buffer: SampleBuffer) -> np.ndarray:
    """An earlier form of the gate: the mean of the per-pixel ratios ``(candidate - mean)^2 / v``
    over the neighbourhood, instead of :func:`awr_denoise.guided.trust`'s ratio of the sums."""
    x = filled_mean(buffer)
    v = buffer.estimated_variance() / np.maximum(buffer.count, 1)[..., None]
    z = np.where(v > 0, (candidate - x) ** 2 / np.where(v > 0, v, 1.0), np.where(candidate == x, 0.0, np.inf))
    r = ndimage.uniform_filter(np.minimum(z, 1e300).mean(axis=-1), size=guided.GATE_WINDOW, mode="nearest")
    return np.clip((guided.GATE_HIGH - r) / (guided.GATE_HIGH - guided.GATE_LOW), 0.0, 1.0)[..., None]


class _Projection:
    """The guide's projection (:func:`awr_denoise.projection.project`) with another interval radius,
    domain exponent or the means' scale band kept, for one measurement (its share of the result is
    ``guide_projection``)."""

    def __init__(self, radius: float = projection.DEFAULT_RADIUS, exponent: float = projection.DEFAULT_EXPONENT,
                 scale_band: bool = True) -> None:
        self.radius, self.exponent, self.scale_band = radius, exponent, scale_band

    def __enter__(self) -> None:
        self.saved = guided.project
        guided.project = functools.partial(projection.project, radius=self.radius, exponent=self.exponent,
                                           scale_band=self.scale_band)

    def __exit__(self, *exc: object) -> None:
        guided.project = self.saved


_RECONSTRUCT = sys.modules["awr_denoise.reconstruct"]  # the module: the package exports a function of that name


def _first_stage_only(buffer: SampleBuffer, stage1: np.ndarray, guide: np.ndarray | None,
                      features: bool) -> tuple[np.ndarray, float]:
    """:func:`awr_denoise.guided.pilots` as it was: the gated guide is the first Wiener stage's pilot only."""
    return guided.pilots(buffer, stage1, guide, features)[0], 0.0


def synthetic(names: tuple[str, ...], spps: tuple[int, ...], seeds: int) -> list[dict[str, Any]]:
    """Known clean images (64x64): the plain mean, the default, and guides that are right (the clean
    image) or wrong (edges moved 12 pixels, a flat image, noise), with the gate and the guard, without
    the gate, and without the guard."""
    rows = []
    for name in names:
        scene = make_scene(name, (64, 64))
        ref = scene.reference()
        wrong = {"clean": ref, "shifted": np.roll(ref, 12, axis=1),
                 "flat": np.broadcast_to(ref.mean(axis=(0, 1)), ref.shape)}
        for seed in range(seeds):
            wrong["noise"] = np.random.default_rng(seed).random(ref.shape) * ref.max()
            for spp in spps:
                buffer = SyntheticRenderer(scene, seed=seed)(SampleRequest.uniform(scene.shape, spp))
                images = {"plain": buffer.mean, "default": reconstruct(buffer)}
                for kind, guide in wrong.items():
                    images[kind] = reconstruct(buffer, guide=guide)
                    images[f"{kind}, no guard"] = reconstruct(buffer, guide=guide, guard=False)
                    saved = guided.trust
                    guided.trust = _ungated_share  # what the guide does without the gate
                    try:
                        images[f"{kind}, no gate"] = reconstruct(buffer, guide=guide)
                    finally:
                        guided.trust = saved
                for method, image in images.items():
                    rows.append({"scene": name, "spp": spp, "seed": seed, "method": method,
                                 "relmse": relmse(image, ref), "mse": mse(image, ref)})
        print(f"{name}: done", flush=True)
    return rows


def synthetic_table(rows: list[dict]) -> None:
    methods = [m for m in dict.fromkeys(r["method"] for r in rows) if m != "plain"]
    print("\n| scene | spp | " + " | ".join(f"{m} / plain" for m in methods) + " |")
    print("|---|---|" + "---|" * len(methods))
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for spp in sorted({r["spp"] for r in rows if r["scene"] == scene}):
            w = {"scene": scene, "spp": spp}
            rel = {m: _mean(rows, "relmse", method=m, **w) for m in ["plain", *methods]}
            sq = {m: _mean(rows, "mse", method=m, **w) for m in ["plain", *methods]}
            print(f"| {scene} | {spp} | " + " | ".join(f"{rel[m] / rel['plain']:.2f}, {sq[m] / sq['plain']:.2f}"
                                                        for m in methods) + " |")


# ---------------------------------------------------------------------------- ablations
def ablations(scenes: tuple[str, ...], spps: tuple[int, ...], cache: Path) -> list[dict[str, Any]]:
    """Bundled tracer, group 0: the OIDN guide with the gate, without it and with its per-pixel form, as
    the pilot of the first Wiener stage only, and without the SURE guard; the feature pilot with 3 and 5
    a-trous passes (and its time)."""
    from awr_denoise import tracer
    variants = {"OIDN guide": ({"guide": guides.oidn}, {}), "OIDN guide, no gate": ({"guide": guides.oidn}, None),
                "OIDN guide, per-pixel gate": ({"guide": guides.oidn}, "per-pixel"),
                "OIDN guide, first stage only": ({"guide": guides.oidn}, "first stage only"),
                "OIDN guide, no guard": ({"guide": guides.oidn, "guard": False}, {}),
                "features, 3 passes": ({"features": True}, {"iterations": 3}),
                "features, 5 passes": ({"features": True}, {"iterations": 5})}
    rows = []
    for scene in scenes:
        ref = np.asarray(tracer.load_reference(scene), dtype=np.float64)
        for spp, buffer in feature_buffers("tracer", scene, None, SPPS, 0, cache).items():
            if spp not in spps:
                continue
            base = reconstruct(buffer)
            for name, (options, setting) in variants.items():
                saved = guided.trust
                if setting is None or setting == "per-pixel":
                    guided.trust = _ungated_share if setting is None else _per_pixel_share
                if setting == "first stage only":
                    _RECONSTRUCT.pilots = _first_stage_only
                try:
                    with _Passes(**(setting if isinstance(setting, dict) else {})):
                        start = time.perf_counter()
                        image = reconstruct(buffer, **options)
                        seconds = time.perf_counter() - start
                finally:
                    guided.trust = saved
                    _RECONSTRUCT.pilots = guided.pilots
                rows.append({"scene": scene, "spp": spp, "variant": name, "seconds": seconds,
                             "relmse_ratio": relmse(image, ref) / relmse(base, ref),
                             "mse_ratio": mse(image, ref) / mse(base, ref)})
        print(f"{scene}: done", flush=True)
    return rows


def ablation_table(rows: list[dict]) -> None:
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    print("\n| scene | spp | " + " | ".join(f"{v} / default (relMSE, MSE)" for v in variants) + " |")
    print("|---|---|" + "---|" * len(variants))
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for spp in sorted({r["spp"] for r in rows}):
            v = {r["variant"]: r for r in rows if r["scene"] == scene and r["spp"] == spp}
            print(f"| {scene} | {spp} | " + " | ".join(f"{v[k]['relmse_ratio']:.3f}, {v[k]['mse_ratio']:.3f}"
                                                        for k in variants) + " |")
    for k in variants:
        print(f"{k}: median {np.median([r['seconds'] for r in rows if r['variant'] == k]):.2f} s")


# ---------------------------------------------------------------------------- what limits the features
def _scored(images: dict[str, np.ndarray], ref: np.ndarray, **where: Any) -> list[dict[str, Any]]:
    """One row per method of ``images``: ``where`` (renderer, scene, spp, group), relMSE and MSE against ``ref``."""
    return [{**where, "method": name, "relmse": relmse(image, ref), "mse": mse(image, ref)}
            for name, image in images.items()]


ORACLE_SPP = 256
ORACLE_GROUP = 1000  # the renderer seed of the feature render no compared buffer uses
DEMODULATION_FLOORS = (0.05, 0.1)  # albedos below which the radiance is not divided (sky, emitters)
RICHER = 4  # an albedo of this many times the radiance's samples (a renderer could render first hits apart)
RICHER_GROUP = 2000  # its render's seed: independent of the compared buffers, whose hits a renderer's would share


def feature_limits(scenes: list[tuple[str, str, tuple[int, int] | None]], spps: tuple[int, ...], groups: int,
                   cache: Path) -> list[dict[str, Any]]:
    """Does the features' own noise limit them? Each way of using them with the buffer's features and with
    the features of an :data:`ORACLE_SPP`-spp render of the same scene (nearly noise-free): the feature
    pilot (``features=True``) and the albedo-demodulated guide; and that guide with the albedo
    reconstructed first (:func:`_demodulated_reconstructed`), also without demodulating where that
    albedo is below each of :data:`DEMODULATION_FLOORS`; that guide chosen window by window against the
    default (:func:`_chosen_by_sure`); and demodulated by the reconstructed albedo of :data:`RICHER` times the
    samples (another render), what a renderer could hand over at the cost of extra first hits."""
    rows = []
    for renderer, scene, shape in scenes:
        ref = reference(renderer, scene, shape, cache)
        oracle = feature_buffers(renderer, scene, shape, (ORACLE_SPP,), ORACLE_GROUP, cache)[ORACLE_SPP].features
        for g in range(groups):
            for spp, buffer in feature_buffers(renderer, scene, shape, spps, g, cache).items():
                clean = dataclasses.replace(buffer, features=dict(oracle))
                images = {"plain": filled_mean(buffer), "default": reconstruct(buffer),
                          "feature pilot": reconstruct(buffer, features=True),
                          "feature pilot, 256-spp features": reconstruct(clean, features=True),
                          "demodulated guide": reconstruct(buffer, guide=_demodulated(buffer)),
                          "demodulated guide, albedo reconstructed first":
                              reconstruct(buffer, guide=_demodulated_reconstructed(buffer)),
                          **{f"the same, none where the albedo is below {t}":
                             reconstruct(buffer, guide=_demodulated_reconstructed(buffer, below=t))
                             for t in DEMODULATION_FLOORS},
                          "demodulated guide, 256-spp albedo":
                              reconstruct(buffer, guide=_demodulated(buffer, albedo=oracle["albedo"].mean))}
                below = DEMODULATION_FLOORS[0]
                images["the same as the 0.05 column, chosen by window by Monte-Carlo SURE"] = _chosen_by_sure(
                    buffer, images["default"], lambda b: _demodulated_reconstructed(b, below=below))
                images["the same, the albedo's noise taken as the radiance's"] = _chosen_by_sure(
                    buffer, images["default"], lambda b: _demodulated_reconstructed(b, below=below), rho=1.0)
                images["the same, 256-spp albedo, chosen by window"] = _chosen_by_sure(
                    buffer, images["default"], lambda b: _demodulated(b, albedo=oracle["albedo"].mean, below=below))
                # What a renderer could hand over: the albedo of more samples (first hits only), reconstructed.
                richer = reconstruct(feature_buffers(renderer, scene, shape, (RICHER * spp,), RICHER_GROUP,
                                                     cache)[RICHER * spp].features["albedo"])
                images[f"demodulated guide, albedo of {RICHER}x the samples"] = reconstruct(
                    buffer, guide=_demodulated(buffer, albedo=richer, below=below))
                images["the same, chosen by window"] = _chosen_by_sure(
                    buffer, images["default"], lambda b: _demodulated(b, albedo=richer, below=below))
                rows += _scored(images, ref, renderer=renderer, scene=scene, spp=spp, group=g)
        print(f"{renderer} {scene}: done", flush=True)
    return rows


def feature_limits_table(rows: list[dict]) -> None:
    """relMSE of each way over the default's per spp (mean over groups), and the worst MSE over the plain mean's."""
    names = [m for m in dict.fromkeys(r["method"] for r in rows) if m not in ("plain", "default")]
    spps = sorted({r["spp"] for r in rows})
    print(f"\nEach cell: relMSE / the default's at {' / '.join(map(str, spps))} spp; the worst MSE / the plain mean's.")
    print("\n| scene | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for renderer, scene in dict.fromkeys((r["renderer"], r["scene"]) for r in rows):
        w = {"renderer": renderer, "scene": scene}
        cells = []
        for m in names:
            rel = " / ".join(f"{_mean(rows, 'relmse', method=m, spp=s, **w) / base:.2f}" for s, base in
                             ((s, _mean(rows, "relmse", method="default", spp=s, **w)) for s in spps))
            worst = max(_mean(rows, "mse", method=m, spp=s, **w) / _mean(rows, "mse", method="plain", spp=s, **w)
                        for s in spps)
            cells.append(f"{rel}; {worst:.2f}")
        print(f"| {scene} | " + " | ".join(cells) + " |")


# ---------------------------------------------------------------------------- the feature pilot's rules
@contextlib.contextmanager
def _pilot_rules(smaller: bool, share: bool) -> Iterator[None]:
    """The feature pilot with or without its two rules (docs/guides.md, "How the feature pilot works"): the colour
    term's smaller variance of a tap's two (else their sum) and the share the features' noise allows (else 1)."""
    saved = guided._pair_variance, guided._feature_confidence
    if not smaller:
        guided._pair_variance = lambda v_p, v_q: v_p + v_q
    if not share:
        guided._feature_confidence = lambda features, shape: np.ones(shape)
    try:
        yield
    finally:
        guided._pair_variance, guided._feature_confidence = saved


RULES = {"feature pilot, neither rule": (False, False), "feature pilot, the smaller variance only": (True, False),
         "feature pilot": (True, True)}


def pilot_rules(scenes: list[tuple[str, str, tuple[int, int] | None]], spps: tuple[int, ...], groups: int,
                cache: Path) -> list[dict[str, Any]]:
    """The feature pilot as it was (the sum of a tap's two variances, every pixel filtered), with the smaller
    variance, and with both rules (the default), against the default reconstruction: every scene, group, spp."""
    rows = []
    for renderer, scene, shape in scenes:
        ref = reference(renderer, scene, shape, cache)
        for g in range(groups):
            for spp, buffer in feature_buffers(renderer, scene, shape, spps, g, cache).items():
                images = {"plain": filled_mean(buffer), "default": reconstruct(buffer)}
                for name, (smaller, share) in RULES.items():
                    with _pilot_rules(smaller, share):
                        images[name] = reconstruct(buffer, features=True)
                rows += _scored(images, ref, renderer=renderer, scene=scene, spp=spp, group=g)
        print(f"{renderer} {scene}: done", flush=True)
    return rows


def pilot_rules_table(rows: list[dict]) -> None:
    """Per scene as :func:`feature_limits_table`; then over every (scene, spp, group) the geometric mean and the
    worst of each version's relMSE over the default's."""
    feature_limits_table(rows)
    keys = sorted({(r["renderer"], r["scene"], r["spp"], r["group"]) for r in rows})
    by = {(r["renderer"], r["scene"], r["spp"], r["group"], r["method"]): r["relmse"] for r in rows}
    print()
    for name in RULES:
        ratios = np.array([by[k + (name,)] / by[k + ("default",)] for k in keys])
        print(f"{name}: geometric mean {np.exp(np.log(ratios).mean()):.3f}, worst {ratios.max():.3f}, "
              f"above 1 on {int((ratios > 1).sum())} of {ratios.size}")


# ---------------------------------------------------------------------------- avenues
def _demodulated(buffer: SampleBuffer, eps: float = 0.02, albedo: np.ndarray | None = None,
                 below: float | None = None) -> np.ndarray:
    """A guide without a network: the default reconstruction of the radiance over the albedo (+ ``eps``),
    multiplied back (albedo demodulation as a pilot, gated like any guide); ``albedo``: another albedo
    image than the buffer's albedo means; ``below``: no demodulation (a divisor of 1) where the albedo
    is below it (sky, emitters: no surface, or a black one)."""
    albedo = np.asarray(buffer.features["albedo"].mean if albedo is None else albedo, dtype=np.float64)
    albedo = albedo + eps if below is None else np.where(albedo < below, 1.0, albedo)
    # The renderer's own moments, pooled and moderated by the reconstruction of ``flat`` as of any buffer:
    # estimated variances given as known ones would be moderated a second time.
    flat = SampleBuffer.from_moments(buffer.count, buffer.mean / albedo, buffer.variance / albedo**2,
                                     variance_known=buffer.variance_known)
    return albedo * reconstruct(flat)


def _demodulated_reconstructed(buffer: SampleBuffer, below: float | None = None) -> np.ndarray:
    """:func:`_demodulated` by the albedo's own default reconstruction: its noise (the lens' and the
    pixel's sampling of the texture) taken out before it divides and multiplies the radiance."""
    return _demodulated(buffer, albedo=reconstruct(buffer.features["albedo"]), below=below)


SURE_EPS = 0.1  # the probe's step, in standard errors of the means


def _probed(buffer: SampleBuffer, rho: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, SampleBuffer]:
    """Monte-Carlo SURE's probe (Ramani, Blu and Unser 2008): the means ``x``, their variances ``v``, one
    Rademacher probe ``n`` scaled by their standard errors, and the buffer with its means moved by ``SURE_EPS n``;
    ``rho`` 1 moves the albedo's means with them, by ``n`` times the ratio of the standard errors (its noise
    taken as the radiance's, channel by channel: no buffer holds the cross moments)."""
    x = filled_mean(buffer)
    v = buffer.estimated_variance() / np.maximum(buffer.count, 1)[..., None]  # as guided.trust's
    n = next(rademacher_probes(v, 1, seed=1))[0]
    features = dict(buffer.features)
    if rho:
        albedo = buffer.features["albedo"]
        va = albedo.estimated_variance() / np.maximum(albedo.count, 1)[..., None]
        shift = SURE_EPS * rho * n * np.sqrt(np.divide(va, v, out=np.zeros_like(v), where=v > 0))
        features["albedo"] = SampleBuffer.from_moments(albedo.count, albedo.mean + shift, albedo.variance,
                                                       variance_known=albedo.variance_known)
    moved = SampleBuffer.from_moments(buffer.count, buffer.mean + SURE_EPS * n, buffer.variance,
                                      variance_known=buffer.variance_known, features=features)
    return x, v, n, moved


def _chosen_by_sure(buffer: SampleBuffer, default: np.ndarray, make_guide: Callable[[SampleBuffer], np.ndarray],
                    rho: float = 0.0) -> np.ndarray:
    """The default ``A`` and the demodulated guide's reconstruction ``C`` mixed window by window, ``A + mu (C - A)``,
    ``mu`` in [0, 1] least in Stein's risk estimate of the mix (the smaller of the squared and the relative
    criterion's, as the guard's; :mod:`awr_denoise.sure`):

        mu = -sum_N w [(A - x)(C - A) + d_C - d_A] / sum_N w (C - A)^2,

    with each map's divergence ``d_i = v_i df_i/dx_i`` from one Rademacher probe ``n`` of the means scaled by
    their standard errors (Monte-Carlo SURE, Ramani, Blu and Unser 2008: ``n (f(x + eps n) - f(x)) / eps``,
    the guide made again from the perturbed buffer, so its dependence on the means is counted; :func:`_probed`).
    The albedo comes from the same paths as the radiance, and its noise is not in the means' divergence: ``rho``
    1 also moves the albedo's means with the probe. Each window is the default guard's
    (:data:`awr_denoise.sure.DEFAULT_WINDOW`)."""
    x, _, n, moved = _probed(buffer, rho)
    chosen = reconstruct(buffer, guide=make_guide(buffer))
    d_default = n * (reconstruct(moved) - default) / SURE_EPS
    d_chosen = n * (reconstruct(moved, guide=make_guide(moved)) - chosen) / SURE_EPS
    change = chosen - default
    size = (DEFAULT_WINDOW, DEFAULT_WINDOW, 1)
    shares = []
    for w in (np.ones_like(x), 1.0 / (default * default + 0.01)):  # MSE's and relMSE's weights (its epsilon)
        num = ndimage.uniform_filter(w * ((default - x) * change + d_chosen - d_default), size=size, mode="reflect")
        den = ndimage.uniform_filter(w * change * change, size=size, mode="reflect")
        shares.append(np.clip(-num / np.maximum(den, 1e-300), 0.0, 1.0))
    return default + np.minimum(*shares) * change


def _features_then_guide(buffer: SampleBuffer, stage1: np.ndarray, guide: np.ndarray | None,
                         features: bool) -> tuple[np.ndarray, Any]:
    """The guide where the gate trusts it, the (gated) feature pilot where not, then stage 1."""
    fallback, _ = guided.pilots(buffer, stage1, None, True)
    return guided.pilots(buffer, fallback, guide, False)


def _features_every_stage(buffer: SampleBuffer, stage1: np.ndarray, guide: np.ndarray | None,
                          features: bool) -> tuple[np.ndarray, Any]:
    """The feature pilot kept by every Wiener stage, as a guide is."""
    candidate = guided.feature_pilot(buffer, stage1)
    share = guided.trust(candidate, buffer)
    return share * candidate + (1.0 - share) * stage1, share


class _RegressionPilot:
    """The feature pilot replaced by a first-order regression on the features, for one measurement:
    in every ``2 radius + 1`` square the means are fitted as ``a + b . f`` over the features ``f``
    (albedo, normal, log depth; the guided filter of He, Sun and Tang 2010 with a many-channel
    guide, its ridge ``eps`` plus each feature's own noise), and each fit is evaluated at its
    window's centre (averaging the fits, as the guided filter does, haloes across the horizon)."""

    def __init__(self, radius: int = 4, eps: float = 1e-3) -> None:
        self.radius, self.eps = radius, eps

    def __enter__(self) -> None:
        self.saved = guided.feature_pilot
        guided.feature_pilot = self.pilot

    def __exit__(self, *exc: object) -> None:
        guided.feature_pilot = self.saved

    def pilot(self, buffer: SampleBuffer, image: np.ndarray) -> np.ndarray:
        size = (2 * self.radius + 1,) * 2

        def box(a: np.ndarray) -> np.ndarray:
            return ndimage.uniform_filter(a, size=size + (1,) * (a.ndim - 2), mode="nearest")

        planes, noise = [], []
        for name in ("albedo", "normal", "depth"):
            if name not in buffer.features:
                continue
            feature = buffer.features[name]
            mean = np.asarray(feature.mean, np.float64)
            count = feature.count[..., None]
            var = np.where(count > 1, feature.variance, 0.0) / np.maximum(count, 1)
            if name == "depth":  # log depth, relative to the median hit; misses (0) at a far constant
                scale = float(np.median(mean[mean > 0])) if (mean > 0).any() else 1.0
                clipped = np.maximum(mean, 1e-6 * scale)
                mean, var = np.log(clipped / scale), var / clipped**2
            planes.append(mean)
            noise.append(var)
        f, fv = np.concatenate(planes, -1), np.concatenate(noise, -1)
        y = filled_mean(buffer)
        h, w, d = f.shape
        c = y.shape[-1]
        mf, my = box(f), box(y)
        cov_ff = box((f[..., :, None] * f[..., None, :]).reshape(h, w, d * d)).reshape(h, w, d, d)
        cov_ff -= mf[..., :, None] * mf[..., None, :]
        cov_fy = box((f[..., :, None] * y[..., None, :]).reshape(h, w, d * c)).reshape(h, w, d, c)
        cov_fy -= mf[..., :, None] * my[..., None, :]
        cov_ff += np.eye(d) * (self.eps + box(fv))[..., None, :]
        b = np.linalg.solve(cov_ff.reshape(-1, d, d), cov_fy.reshape(-1, d, c)).reshape(h, w, d, c)
        return my + np.einsum("hwdc,hwd->hwc", b, f - mf)


class _GuardTowardDefault:
    """For one measurement, the SURE guard of a guided reconstruction first blends towards the
    unguided Wiener stages' result (``u + lambda (g - u)``, both linear in the means for their
    fixed factors: Stein's estimate of the blend's risk, ``lambda`` per 9x9 window, the smaller of
    the squared and the relative criterion's), then towards the means as usual: a wrong guide falls
    back to the default rather than to the plain mean."""

    def __enter__(self) -> None:
        self.saved = (_RECONSTRUCT.pilots, _RECONSTRUCT._wiener_stages)
        _RECONSTRUCT.pilots, _RECONSTRUCT._wiener_stages = self._pilots, self._stages

    def __exit__(self, *exc: object) -> None:
        _RECONSTRUCT.pilots, _RECONSTRUCT._wiener_stages = self.saved

    def _pilots(self, buffer: SampleBuffer, stage1: np.ndarray, guide: Any, features: bool) -> tuple:
        self.stage1 = stage1
        return self.saved[0](buffer, stage1, guide, features)

    def _stages(self, prepared: Any, pilot: np.ndarray, exponents: tuple, **options: Any) -> tuple:
        guide, keep, window = options["guide"], options["keep"], options.get("window", 9)
        if guide is None or options["luminance"] is not None:
            return self.saved[1](prepared, pilot, exponents, **options)
        s, k, x, v = prepared.unit_scaled()
        t = _RECONSTRUCT.stationary_transform(prepared.mean.shape[:2], options["wavelet"], options["levels"],
                                              options["precision"])
        floor = options.get("floor", _RECONSTRUCT.DEFAULT_FLOOR)
        base = chain(t, x, v, self.stage1 / s, exponents, k=k, leverage=True, floor=floor)
        done = chain(t, x, v, pilot / s, exponents, k=k, leverage=True, floor=floor, keep=keep)
        g = np.where(keep > 0, guide, 0.0) / s
        out, lev, _ = guided.projected(t, x, v, g, done.image, done.leverage, keep, k=k,
                                       projection=options["projection"])
        lev_b = np.broadcast_to(base.leverage, out.shape)
        lev = np.broadcast_to(lev, out.shape)
        change = out - base.image
        lams = []
        for weight in (np.ones_like(out), 1.0 / (np.abs(out) + k) ** 2):
            size = (window, window, 1)
            num = ndimage.uniform_filter(-weight * ((base.image - x) * change + v * (lev - lev_b)), size, mode="nearest")
            den = ndimage.uniform_filter(weight * change * change, size, mode="nearest")
            with np.errstate(divide="ignore", invalid="ignore"):
                lams.append(np.clip(np.nan_to_num(np.where(den > 0, num / den, 1.0), nan=1.0), 0.0, 1.0))
        lam = np.minimum(*lams)
        out, lev = base.image + lam * change, lev_b + lam * (lev - lev_b)
        out, _ = sure_blend(out, x, v, lev, k=k, window=window)
        return out * s, None, None


class _ShareBySure:
    """For one measurement, the projection's share chosen per image by Stein's unbiased risk estimate of
    the *whole* guided reconstruction, OIDN included (Monte-Carlo SURE, Ramani, Blu and Unser 2008): the
    means perturbed by ``eps`` times one Rademacher probe ``n`` scaled by their standard errors, the
    divergence ``sum v_i df_i/dx_i`` estimated by ``n . (f(x + eps n) - f(x)) / eps`` (OIDN rerun on the
    perturbed means, so the guide's dependence on the samples is counted, which a fixed-guide SURE
    misses), and the share of :data:`SHARES` with the least relative risk kept. It costs two guided
    reconstructions and two OIDN runs per candidate share."""

    SHARES = (0.0, 0.25, 0.5, 0.75, 1.0)

    def image(self, buffer: SampleBuffer, options: dict[str, Any]) -> np.ndarray:
        x, v, n, perturbed = _probed(buffer)
        guide, guide_perturbed = guides.oidn(buffer), guides.oidn(perturbed)
        best = None
        for share in self.SHARES:
            f0 = reconstruct(buffer, guide=guide, guide_projection=share)
            f1 = reconstruct(perturbed, guide=guide_perturbed, guide_projection=share)
            w = 1.0 / (f0 * f0 + 0.01)  # relMSE's weights (its epsilon), the result standing in for the reference
            risk = float(np.sum(w * (f0 - x) ** 2) + 2 * np.sum(w * n * (f1 - f0)) / SURE_EPS - np.sum(w * v))
            if best is None or risk < best[0]:
                best = (risk, share, f0)
        assert best is not None
        print(f"  projection share by Monte-Carlo SURE: {best[1]}", flush=True)
        return best[2]


AVENUES: dict[str, tuple[dict[str, Any], Any]] = {
    "OIDN guide": ({"guide": guides.oidn}, None),
    "OIDN guide, first stage only": ({"guide": guides.oidn}, _first_stage_only),
    "OIDN guide, alpha 1": ({"guide": guides.oidn, "wiener_exponents": (0.75, 1.0)}, None),
    "OIDN guide, no guard": ({"guide": guides.oidn, "guard": False}, None),
    "OIDN guide, no projection": ({"guide": guides.oidn, "guide_projection": 0.0}, None),
    "OIDN guide, projection only": ({"guide": guides.oidn, "guide_projection": 1.0}, None),
    "OIDN guide, projection share 0.75": ({"guide": guides.oidn, "guide_projection": 0.75}, None),
    "OIDN guide, guard window 9": ({"guide": guides.oidn, "guard_window": 9}, None),
    "OIDN guide, radius 2": ({"guide": guides.oidn}, _Projection(radius=2.0)),
    "OIDN guide, projection exponent 1": ({"guide": guides.oidn}, _Projection(exponent=1.0)),
    "OIDN guide, scale band kept": ({"guide": guides.oidn}, _Projection(scale_band=False)),
    "OIDN guide + features where the gate closes": ({"guide": guides.oidn, "features": True}, _features_then_guide),
    "clean image as guide": ({"guide": "reference"}, None),
    "clean image as guide, alpha 1": ({"guide": "reference", "wiener_exponents": (0.75, 1.0)}, None),
    "features": ({"features": True}, None),
    "features, every stage": ({"features": True}, _features_every_stage),
    "demodulated guide": ({"guide": _demodulated}, None),
    "features, regression pilot": ({"features": True}, _RegressionPilot()),
    "OIDN guide, guard towards the default": ({"guide": guides.oidn}, _GuardTowardDefault()),
    "OIDN guide, projection share by Monte-Carlo SURE": ({}, _ShareBySure()),
}
"""What else was tried for the guide and the features: name -> (reconstruct options, replacement of
:func:`awr_denoise.guided.pilots`, a context that replaces a step for one measurement (:class:`_Projection`,
:class:`_RegressionPilot`, :class:`_GuardTowardDefault`), an object whose ``image(buffer, options)`` makes
the image itself (:class:`_ShareBySure`), or ``None``). ``"reference"`` stands for the
scene's reference image."""


def avenues(scenes: list[tuple[str, str, tuple[int, int] | None]], spp: int, groups: int,
            cache: Path) -> list[dict[str, Any]]:
    """Every scene at ``spp``: relMSE and MSE of each of :data:`AVENUES`, the default and OIDN alone."""
    rows = []
    for renderer, scene, shape in scenes:
        ref = reference(renderer, scene, shape, cache)
        for g in range(groups):
            buffer = feature_buffers(renderer, scene, shape, SPPS, g, cache)[spp]
            images = {"default": reconstruct(buffer), "OIDN": guides.oidn(buffer), "plain": filled_mean(buffer)}
            for name, (options, replacement) in AVENUES.items():
                options = {k: (ref if v == "reference" else v) for k, v in options.items()}
                if hasattr(replacement, "image"):
                    images[name] = replacement.image(buffer, options)
                    continue
                if hasattr(replacement, "__enter__"):
                    with replacement:
                        images[name] = reconstruct(buffer, **options)
                    continue
                if replacement is not None:
                    _RECONSTRUCT.pilots = replacement
                try:
                    images[name] = reconstruct(buffer, **options)
                finally:
                    _RECONSTRUCT.pilots = guided.pilots
            rows += _scored(images, ref, renderer=renderer, scene=scene, spp=spp, group=g)
        print(f"{renderer} {scene}: done", flush=True)
    return rows


def avenue_table(rows: list[dict]) -> None:
    """relMSE over OIDN's and over the default's, MSE over the plain mean's, of every avenue."""
    names = [m for m in dict.fromkeys(r["method"] for r in rows) if m not in ("default", "OIDN", "plain")]
    print("\nEach cell: relMSE / OIDN's, relMSE / the default's, MSE / the plain mean's.")
    print("\n| scene | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for renderer, scene in dict.fromkeys((r["renderer"], r["scene"]) for r in rows):
        w = {"renderer": renderer, "scene": scene}
        rel = {m: _mean(rows, "relmse", method=m, **w) for m in [*names, "default", "OIDN"]}
        sq = {m: _mean(rows, "mse", method=m, **w) for m in [*names, "plain"]}
        print(f"| {scene} | " + " | ".join(f"{rel[m] / rel['OIDN']:.2f}, {rel[m] / rel['default']:.2f}, "
                                           f"{sq[m] / sq['plain']:.2f}" for m in names) + " |")


# ---------------------------------------------------------------------------- pbrt-v4
PBRT = ROOT.parent / "tests" / "data" / "pbrt"
PBRT_METHODS = {"default": {}, "default + features": {"features": True}, "default + OIDN guide": {"guide": guides.oidn},
                "default + OIDN guide, no projection": {"guide": guides.oidn, "guide_projection": 0.0}}


def _pbrt_buffers() -> Iterator[tuple[Path, SampleBuffer, np.ndarray]]:
    """Each render pbrt-v4 wrote (GBufferFilm, 64x64, 16 spp; independent seeds), read, with the reference pbrt
    wrote beside them."""
    from awr_denoise.io import read_image, read_sample_buffer
    ref = np.asarray(read_image(PBRT / "pbrt_ref.exr", channels=("R", "G", "B")), np.float64)
    for path in [PBRT / "pbrt_gbuffer_fp32.exr", *sorted((PBRT / "seeds").glob("*.exr"))]:
        yield path, read_sample_buffer(path), ref


def pbrt() -> list[dict[str, Any]]:
    """Renders pbrt-v4 wrote against its reference."""
    rows = []
    for path, buffer, ref in _pbrt_buffers():
        images = {"plain": filled_mean(buffer), "OIDN": guides.oidn(buffer)}
        for name, options in PBRT_METHODS.items():
            images[name] = reconstruct(buffer, **options)
        rows += [{"file": path.name, "method": m, "relmse": relmse(i, ref), "mse": mse(i, ref)} for m, i in images.items()]
    return rows


def pbrt_table(rows: list[dict]) -> None:
    names = list(dict.fromkeys(r["method"] for r in rows))
    rel = {m: float(np.mean([r["relmse"] for r in rows if r["method"] == m])) for m in names}
    sq = {m: float(np.mean([r["mse"] for r in rows if r["method"] == m])) for m in names}
    files = len({r["file"] for r in rows})
    print(f"\n{files} renders; relMSE over the default's and over OIDN's, MSE over the plain mean's.")
    print("\n| | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    print("| relMSE | " + " | ".join(f"{rel[m]:.5f}" for m in names) + " |")
    print("| relMSE / default | " + " | ".join(f"{rel[m] / rel['default']:.2f}" for m in names) + " |")
    print("| relMSE / OIDN | " + " | ".join(f"{rel[m] / rel['OIDN']:.2f}" for m in names) + " |")
    print("| MSE / plain | " + " | ".join(f"{sq[m] / sq['plain']:.2f}" for m in names) + " |")


# ---------------------------------------------------------------------------- auxiliary images
AUXILIARY_METHODS = ("OIDN", "OIDN, features as noisy", "OIDN, no features", "guide", "guide, features as noisy",
                     "guide, no features")
"""OIDN and the OIDN guide with the albedo and normal prefiltered (the default), given as noisy, and left out."""


def _auxiliary_images(buffer: SampleBuffer) -> dict[str, tuple[np.ndarray, float]]:
    """Each of :data:`AUXILIARY_METHODS`, the default and the plain mean on ``buffer``, with OIDN's seconds."""
    out = {}
    for name, make in (("OIDN", lambda: guides.oidn(buffer)),
                       ("OIDN, features as noisy", lambda: guides.oidn(buffer, auxiliary="noisy")),
                       ("OIDN, no features", lambda: guides.oidn(buffer, auxiliary="none"))):
        start = time.perf_counter()
        image = make()
        out[name] = (image, time.perf_counter() - start)
        out[name.replace("OIDN", "guide")] = (reconstruct(buffer, guide=image), float("nan"))
    out["default"] = (reconstruct(buffer), float("nan"))
    out["plain"] = (filled_mean(buffer), float("nan"))
    return out


def auxiliary(scenes: list[tuple[str, str, tuple[int, int] | None]], spps: tuple[int, ...], groups: int,
              cache: Path) -> list[dict[str, Any]]:
    """The albedo and normal prefiltered, as noisy, or none: both renderers' scenes and pbrt-v4's files."""
    pbrt_files = (({"renderer": "pbrt", "scene": "pbrt_gbuffer", "spp": 16, "group": g}, buffer, ref)
                  for g, (_, buffer, ref) in enumerate(_pbrt_buffers()))
    rows = []
    for keys, buffer, ref in itertools.chain(_scene_buffers(scenes, spps, groups, cache), pbrt_files):
        x = filled_mean(buffer)
        rows += [{**keys, "method": m, **_measure(image, x, ref, seconds)}
                 for m, (image, seconds) in _auxiliary_images(buffer).items()]
    return rows


def auxiliary_table(rows: list[dict]) -> None:
    """Markdown: the guide and OIDN with the features prefiltered against given as noisy, and the summary."""
    print("\n| renderer | scene | spp | guide, relMSE / default: prefiltered, as noisy, none | guide prefiltered / as "
          "noisy (relMSE, MSE) | guide prefiltered: MSE / plain, worst mean error % | OIDN prefiltered / as noisy, "
          "none / as noisy (relMSE) | OIDN seconds: prefiltered, as noisy |")
    print("|---|---|---|---|---|---|---|---|")
    ratios, over_default = [], []
    for renderer, scene in dict.fromkeys((r["renderer"], r["scene"]) for r in rows):
        for spp in sorted({r["spp"] for r in rows if r["scene"] == scene}):
            w = {"renderer": renderer, "scene": scene, "spp": spp}
            rel = {m: _mean(rows, "relmse", method=m, **w) for m in (*AUXILIARY_METHODS, "default")}
            sq = {m: _mean(rows, "mse", method=m, **w) for m in ("guide", "guide, features as noisy", "plain")}
            sec = {m: _mean(rows, "seconds", method=m, **w) for m in ("OIDN", "OIDN, features as noisy")}
            worst = max(abs(r["mean_error"]) for r in rows if r["method"] == "guide"
                        and all(r[k] == v for k, v in w.items()))
            ratios.append(rel["guide"] / rel["guide, features as noisy"])
            over_default.append(rel["guide"] / rel["default"])
            print(f"| {renderer} | {scene} | {spp} | " + ", ".join(f"{rel[m] / rel['default']:.2f}" for m in (
                "guide", "guide, features as noisy", "guide, no features"))
                + f" | {ratios[-1]:.2f}, {sq['guide'] / sq['guide, features as noisy']:.2f} | "
                f"{sq['guide'] / sq['plain']:.2f}, {100 * worst:.4f} | "
                f"{rel['OIDN'] / rel['OIDN, features as noisy']:.2f}, "
                f"{rel['OIDN, no features'] / rel['OIDN, features as noisy']:.2f} | "
                f"{sec['OIDN']:.2f}, {sec['OIDN, features as noisy']:.2f} |")
    print(f"\nThe guide prefiltered over as noisy, relMSE: {min(ratios):.2f}-{max(ratios):.2f} (geometric mean "
          f"{float(np.exp(np.mean(np.log(ratios)))):.2f}) in {len(ratios)} cells; over the default: "
          f"{min(over_default):.2f}-{max(over_default):.2f}.")


# ---------------------------------------------------------------------------- crops
CROPS = {("tracer", "cornell_gi"): (40, 40), ("tracer", "chess_dof"): (40, 40),
         ("mitsuba", "glossy_glass"): (96, 96), ("mitsuba", "dof_checker"): (96, 96)}
CROP = 48
ZOOM = 3


def crops(spp: int, cache: Path, images: Path = IMAGES) -> list[str]:
    """One PNG per scene of :data:`CROPS` in ``images``: reference, mean, default, + features, + OIDN guide, OIDN."""
    written = []
    for (renderer, scene), (top, left) in CROPS.items():
        if renderer == "mitsuba" and not _mitsuba_available():
            continue
        shape = MITSUBA_SHAPE if renderer == "mitsuba" else None
        ref = reference(renderer, scene, shape, cache)
        buffer = feature_buffers(renderer, scene, shape, SPPS, 0, cache)[spp]
        tiles = [ref] + [_image(m, buffer) for m in CROP_METHODS]
        window = (slice(top, top + CROP), slice(left, left + CROP))
        row = np.concatenate([np.pad(t[window], ((0, 0), (0, 2), (0, 0)), constant_values=1.0) for t in tiles], 1)
        row = np.repeat(np.repeat(row, ZOOM, axis=0), ZOOM, axis=1)
        path = images / f"guides_{renderer}_{scene}_{spp}spp.png"
        write_preview(path, row, overwrite=True)
        shown = os.path.relpath(path, ROOT.parent)
        written.append(shown)
        print(f"wrote {shown}", flush=True)
    return written


# ---------------------------------------------------------------------------- the guard's tolerance
TOLERANCES = (1.0, 1.2, 1.5, 2.0)
"""The guard's tolerances with a guide compared (:data:`awr_denoise.sure.DEFAULT_GUIDED_TOLERANCE` among them)."""
GUIDED_WINDOWS = (9, 13, 25)
"""Guard windows compared with :data:`awr_denoise.sure.DEFAULT_GUIDED_WINDOW` (17), at the default tolerance."""


@contextlib.contextmanager
def _guided_tolerance(value: float) -> Iterator[None]:
    saved = _RECONSTRUCT.DEFAULT_GUIDED_TOLERANCE
    _RECONSTRUCT.DEFAULT_GUIDED_TOLERANCE = value
    try:
        yield
    finally:
        _RECONSTRUCT.DEFAULT_GUIDED_TOLERANCE = saved


def _guard_diagnosis(buffer: SampleBuffer, ref: np.ndarray, keys: dict[str, Any]) -> dict[str, Any]:
    """Where the strict guard (tolerance 1) keeps less than 0.9 of the OIDN guide's change: how many pixels, how the
    means' squared errors there compare with their variances (windowed as the guard's sums), and the guard's mean
    share there against the best one the reference gives."""
    seen: dict[str, Any] = {}

    def spy(out: np.ndarray, x: np.ndarray, v: np.ndarray, lev: np.ndarray, **kw: Any) -> tuple:
        result = sure_blend(out, x, v, lev, **kw)
        seen.update(out=out.copy(), x=x.copy(), v=v.copy(), lev=np.asarray(lev).copy(), window=kw["window"],
                    k=kw["k"], lam=result[1].copy())
        return result

    saved = _RECONSTRUCT.sure_blend
    _RECONSTRUCT.sure_blend = spy
    try:
        with _guided_tolerance(1.0):
            reconstruct(buffer, guide=guides.oidn(buffer))
    finally:
        _RECONSTRUCT.sure_blend = saved
    x, o, v, lam, w = seen["x"], seen["out"], seen["v"], seen["lam"], seen["window"]
    lev = seen["lev"] if seen["lev"].ndim == x.ndim else seen["lev"][..., None]
    mean = filled_mean(buffer)
    t = ref * float((x * x).sum() / (mean * x).sum())  # the reference in the guard's unit (the means scaled)
    low = lam < 0.9
    weight = 1.0 / (np.abs(o) + seen["k"]) ** 2  # the relative criterion's (awr_denoise.sure)

    def share(num: np.ndarray, den: np.ndarray) -> np.ndarray:
        return np.clip(window_sum(num, w) / window_sum(den, w), 0.0, 1.0)

    # Like with like: the guard takes the smaller of its two criteria's shares, the best the smaller of theirs.
    best = np.minimum(share((t - x) * (o - x), (o - x) ** 2), share(weight * (t - x) * (o - x), weight * (o - x) ** 2))
    squared = share(v * (1 - lev), (o - x) ** 2)  # the guard's squared-error criterion alone
    ratio = window_sum((x - t) ** 2, w) / window_sum(v, w)
    return {**keys, "renderer": "diagnosis", "method": "guard share below 0.9", "pixels": float(low.mean()),
            "error_over_variance": float(np.median(ratio[low])), "best_share": float(best[low].mean()),
            "guard_share": float(lam[low].mean()), "squared_share": float(squared[low].mean())}


def tolerance(scenes: list[tuple[str, str, tuple[int, int] | None]], spps: tuple[int, ...], groups: int,
              cache: Path, seeds: int = 4) -> list[dict[str, Any]]:
    """The OIDN guide at every tolerance of :data:`TOLERANCES` on both renderers' scenes and pbrt-v4's files, and
    the synthetic scenes' right and wrong guides (as ``synthetic``) at each, with the plain mean and the default."""
    pbrt_files = (({"renderer": "pbrt", "scene": "pbrt_gbuffer", "spp": 16, "group": g}, buffer, ref)
                  for g, (_, buffer, ref) in enumerate(_pbrt_buffers()))
    rows = []
    for keys, buffer, ref in itertools.chain(_scene_buffers(scenes, spps, groups, cache), pbrt_files):
        x, guide = filled_mean(buffer), guides.oidn(buffer)
        if (keys["scene"], keys["spp"], keys["group"]) == ("cornell_gi", 32, 0):
            rows.append(_guard_diagnosis(buffer, ref, keys))
        images = {"plain": x, "OIDN": guide}
        for t in TOLERANCES:
            with _guided_tolerance(t):
                images[f"guide, tolerance {t:g}"] = reconstruct(buffer, guide=guide)
            with unguided_guard(tolerance=t):
                images[f"default, tolerance {t:g}"] = reconstruct(buffer)
        for window in GUIDED_WINDOWS:
            images[f"guide, window {window}"] = reconstruct(buffer, guide=guide, guard_window=window)
        rows += [{**keys, "method": m, **_measure(image, x, ref, float("nan"))} for m, image in images.items()]
    for keys, buffer, ref in _synthetic_buffers(seeds):
        wrong = {"clean": ref, "shifted": np.roll(ref, 12, axis=1),
                 "flat": np.broadcast_to(ref.mean(axis=(0, 1)), ref.shape),
                 "noise": np.random.default_rng(keys["group"]).random(ref.shape) * ref.max()}
        images = {"plain": buffer.mean}
        for t in TOLERANCES:
            with _guided_tolerance(t):
                images.update({f"{kind}, tolerance {t:g}": reconstruct(buffer, guide=guide)
                               for kind, guide in wrong.items()})
            with unguided_guard(tolerance=t):
                images[f"default, tolerance {t:g}"] = reconstruct(buffer)
        rows += [{**keys, "method": m, "relmse": relmse(image, ref), "mse": mse(image, ref)}
                 for m, image in images.items()]
    return rows


def _synthetic_buffers(seeds: int) -> Iterator[tuple[dict[str, Any], SampleBuffer, np.ndarray]]:
    """The synthetic scenes' buffers next to which the guard's tolerance is judged (64x64, 4-256 spp, each seed
    its own render): a row's keys, the buffer and the scene's clean image."""
    for name in ("gradient", "edges", "hdr_source"):
        scene = make_scene(name, (64, 64))
        ref = scene.reference()
        for seed in range(seeds):
            for spp in (4, 16, 64, 256):
                buffer = SyntheticRenderer(scene, seed=seed)(SampleRequest.uniform(scene.shape, spp))
                yield {"renderer": "synthetic", "scene": name, "spp": spp, "group": seed}, buffer, ref
        print(f"synthetic {name}: done", flush=True)


STRICT = "tolerance 1"
"""The strict guard: tolerance 1 for both criteria (the default without a guide before the 10x form of
:data:`CRITERIA`); the criteria's baseline."""

CRITERIA: dict[str, dict[str, Any]] = {
    "tolerance 1.2": {"tolerance": 1.2}, "squared criterion 1.2": {"tolerance": (1.2, 1.0)},
    "relative criterion 1.2": {"tolerance": (1.0, 1.2)}, "squared criterion 1.5": {"tolerance": (1.5, 1.0)},
    "tolerance 1.2, rims spared (10x)": {"tolerance": 1.2, "spared_beside": 10.0},
    "tolerance 1.2, rims spared (3x)": {"tolerance": 1.2, "spared_beside": 3.0}}
"""The guard without a guide: its tolerance given to both criteria, or to one (``sure_blend``'s pair), or to both
but the relative criterion's beside a pixel that many times brighter (``spared_beside``; the default is the 10x
form: :data:`awr_denoise.sure.DEFAULT_TOLERANCE`, :data:`~awr_denoise.sure.DEFAULT_SPARED_BESIDE`)."""


def criteria(scenes: list[tuple[str, str, tuple[int, int] | None]], spps: tuple[int, ...], groups: int,
             cache: Path, seeds: int = 4) -> list[dict[str, Any]]:
    """The default without a guide with its guard at each of :data:`CRITERIA` against the strict guard (tolerance 1,
    the default before), on both renderers' scenes, and next to the synthetic small light (each seed kept: the
    rim's risk is a single seed's)."""
    def images(buffer: SampleBuffer, plain: np.ndarray) -> dict[str, np.ndarray]:
        out = {"plain": plain}
        for name, options in {STRICT: {"tolerance": 1.0}, **CRITERIA}.items():
            with unguided_guard(**options):
                out[name] = reconstruct(buffer)
        return out

    rows = []
    for keys, buffer, ref in _scene_buffers(scenes, spps, groups, cache):
        x = filled_mean(buffer)
        rows += [{**keys, "method": m, **_measure(image, x, ref, float("nan"))}
                 for m, image in images(buffer, x).items()]
    for keys, buffer, ref in _synthetic_buffers(seeds):
        rows += [{**keys, "method": m, "relmse": relmse(image, ref), "mse": mse(image, ref)}
                 for m, image in images(buffer, buffer.mean).items()]
    return rows


def criteria_table(rows: list[dict]) -> None:
    """Markdown: relMSE over the strict guard's and MSE over the plain mean's per scene and spp; the synthetic
    scenes' worst single seed over the plain mean."""
    names, base = list(CRITERIA), STRICT
    scored = [r for r in rows if r["renderer"] != "synthetic"]
    over: dict[str, list[float]] = {}
    print(f"\n| renderer | scene | spp | relMSE / {base}'s: " + ", ".join(names) + f" | MSE / plain: {base}, "
          + ", ".join(names) + " |")
    print("|---|---|---|---|---|")
    for renderer, scene in dict.fromkeys((r["renderer"], r["scene"]) for r in scored):
        for spp in sorted({r["spp"] for r in scored if r["scene"] == scene}):
            w = {"renderer": renderer, "scene": scene, "spp": spp}
            rel = {m: _mean(scored, "relmse", method=m, **w) for m in (base, *names)}
            sq = {m: _mean(scored, "mse", method=m, **w) / _mean(scored, "mse", method="plain", **w)
                  for m in (base, *names)}
            print(f"| {renderer} | {scene} | {spp} | " + ", ".join(f"{rel[n] / rel[base]:.3f}" for n in names)
                  + " | " + ", ".join(f"{sq[m]:.2f}" for m in (base, *names)) + " |")
            for n in names:
                over.setdefault(n, []).append(rel[n] / rel[base])
    print(f"\nrelMSE / {base}'s over every row: " + "; ".join(
        f"{n}: geometric mean {float(np.exp(np.mean(np.log(over[n])))):.3f}, most {max(over[n]):.3f}" for n in names))
    synthetic = [r for r in rows if r["renderer"] == "synthetic"]
    print(f"\n| synthetic scene | worst relMSE / plain, any one seed and spp: {base}, " + ", ".join(names)
          + " | worst MSE / plain, the same |")
    print("|---|---|---|")
    for scene in dict.fromkeys(r["scene"] for r in synthetic):
        worst = {}
        for key in ("relmse", "mse"):
            plain = {(r["spp"], r["group"]): r[key] for r in synthetic
                     if r["scene"] == scene and r["method"] == "plain"}
            worst[key] = {m: max(r[key] / plain[r["spp"], r["group"]] for r in synthetic
                                 if r["scene"] == scene and r["method"] == m) for m in (base, *names)}
        print(f"| {scene} | " + " | ".join(", ".join(f"{worst[key][m]:.3f}" for m in (base, *names))
                                          for key in ("relmse", "mse")) + " |")


def tolerance_table(rows: list[dict]) -> None:
    """Markdown: the guide over OIDN (relMSE) and over the plain mean (MSE) at each tolerance; the wrong guides'
    worst errors over the plain mean's."""
    names = [f"tolerance {t:g}" for t in TOLERANCES]
    print("\n| renderer | scene | spp | guide / OIDN, relMSE: " + ", ".join(names) + " | guide / plain, MSE: "
          + ", ".join(names) + " | worst mean error % |")
    print("|---|---|---|---|---|---|")
    scored = [r for r in rows if r["renderer"] not in ("synthetic", "diagnosis")]
    over = {n: [] for n in names}
    for renderer, scene in dict.fromkeys((r["renderer"], r["scene"]) for r in scored):
        for spp in sorted({r["spp"] for r in scored if r["scene"] == scene}):
            w = {"renderer": renderer, "scene": scene, "spp": spp}
            rel = {m: _mean(scored, "relmse", method=m, **w) for m in ("OIDN", *(f"guide, {n}" for n in names))}
            sq = {m: _mean(scored, "mse", method=m, **w) for m in ("plain", *(f"guide, {n}" for n in names))}
            worst = max(abs(r["mean_error"]) for r in scored if r["method"].startswith("guide")
                        and all(r[k] == v for k, v in w.items()))
            for n in names:
                over[n].append(rel[f"guide, {n}"] / rel["OIDN"])
            print(f"| {renderer} | {scene} | {spp} | " + ", ".join(f"{rel[f'guide, {n}'] / rel['OIDN']:.3f}"
                                                                  for n in names)
                  + " | " + ", ".join(f"{sq[f'guide, {n}'] / sq['plain']:.2f}" for n in names)
                  + f" | {100 * worst:.4f} |")
    print("\nguide / OIDN relMSE over every row: " + "; ".join(
        f"{n}: geometric mean {float(np.exp(np.mean(np.log(over[n])))):.3f}, most {max(over[n]):.3f}" for n in names))
    for r in (r for r in rows if r["renderer"] == "diagnosis"):
        print(f"\nThe strict guard on {r['scene']} at {r['spp']} spp (group {r['group']}): its share of the guide's "
              f"change is below 0.9 at {100 * r['pixels']:.0f}% of the pixels; there the means' squared errors are "
              f"{r['error_over_variance']:.2f}x their variances (median over the guard's windows), and the share "
              f"averages {r['guard_share']:.2f} ({r['squared_share']:.2f} by its squared-error criterion alone) where "
              f"the best one (from the reference, the smaller of the two criteria's) averages {r['best_share']:.2f}.")
    print("\n| renderer | scene | spp | without a guide, relMSE / tolerance 1's: " + ", ".join(names[1:])
          + " | without a guide, MSE / plain: " + ", ".join(names) + " |")
    print("|---|---|---|---|---|")
    for renderer, scene in dict.fromkeys((r["renderer"], r["scene"]) for r in scored):
        for spp in sorted({r["spp"] for r in scored if r["scene"] == scene}):
            w = {"renderer": renderer, "scene": scene, "spp": spp}
            rel = {n: _mean(scored, "relmse", method=f"default, {n}", **w) for n in names}
            sq = {n: _mean(scored, "mse", method=f"default, {n}", **w) / _mean(scored, "mse", method="plain", **w)
                  for n in names}
            print(f"| {renderer} | {scene} | {spp} | " + ", ".join(f"{rel[n] / rel[names[0]]:.3f}" for n in names[1:])
                  + " | " + ", ".join(f"{sq[n]:.2f}" for n in names) + " |")
    windows = [f"window {w}" for w in GUIDED_WINDOWS]
    default_name = f"tolerance {DEFAULT_GUIDED_TOLERANCE:g}"
    print(f"\n| renderer | scene | spp | guide / OIDN, relMSE, {default_name}: window 17 (the default), "
          + ", ".join(windows) + " | guide / plain, MSE: window 17, " + ", ".join(windows) + " |")
    print("|---|---|---|---|---|")
    for renderer, scene in dict.fromkeys((r["renderer"], r["scene"]) for r in scored):
        for spp in sorted({r["spp"] for r in scored if r["scene"] == scene}):
            w = {"renderer": renderer, "scene": scene, "spp": spp}
            methods = (f"guide, {default_name}", *(f"guide, {n}" for n in windows))
            oidn_relmse = _mean(scored, "relmse", method="OIDN", **w)
            plain_mse = _mean(scored, "mse", method="plain", **w)
            print(f"| {renderer} | {scene} | {spp} | "
                  + ", ".join(f"{_mean(scored, 'relmse', method=m, **w) / oidn_relmse:.3f}" for m in methods) + " | "
                  + ", ".join(f"{_mean(scored, 'mse', method=m, **w) / plain_mse:.2f}" for m in methods) + " |")
    synthetic_rows = [r for r in rows if r["renderer"] == "synthetic"]
    print("\n| synthetic scene | guide | worst relMSE / plain, mean of the seeds (any spp): " + ", ".join(names)
          + " | worst MSE / plain, the same: " + ", ".join(names) + " | worst relMSE / plain, any one seed: "
          + ", ".join(names) + " |")
    print("|---|---|---|---|---|")
    spps = sorted({r["spp"] for r in synthetic_rows})

    def worst(key: str, scene: str, method: str) -> float:  # the largest ratio to the plain mean over the spps
        return max(_mean(synthetic_rows, key, scene=scene, spp=spp, method=method)
                   / _mean(synthetic_rows, key, scene=scene, spp=spp, method="plain") for spp in spps)

    plain = {(r["scene"], r["spp"], r["group"]): r["relmse"] for r in synthetic_rows if r["method"] == "plain"}

    def worst_seed(scene: str, method: str) -> float:
        return max(r["relmse"] / plain[(scene, r["spp"], r["group"])] for r in synthetic_rows
                   if r["scene"] == scene and r["method"] == method)

    for scene in dict.fromkeys(r["scene"] for r in synthetic_rows):
        for kind in ("default (no guide)", "clean", "shifted", "flat", "noise"):
            method = kind.split(" ")[0]
            cells = [", ".join(f"{worst(key, scene, f'{method}, {n}'):.2f}" for n in names)
                     for key in ("relmse", "mse")]
            seeds = ", ".join(f"{worst_seed(scene, f'{method}, {n}'):.2f}" for n in names)
            print(f"| {scene} | {kind} | {cells[0]} | {cells[1]} | {seeds} |")


# ---------------------------------------------------------------------------- Stein's estimate on rendered noise
def _gaussian_clone(buffer: SampleBuffer, ref: np.ndarray, seed: int,
                    noise_of: SampleBuffer | None = None) -> SampleBuffer:
    """The buffer with its means replaced by the reference plus Gaussian noise of the variances its means are
    given (:func:`_probed`'s ``v``): the same counts, variances and features, the noise Stein's lemma assumes.
    With ``noise_of`` the noise has that buffer's variances instead (another render's of the same pixels), and
    the variances the clone states are estimates of it, as a buffer's are.

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> buffer = SampleBuffer.from_moments(np.full((2, 2), 4), np.ones((2, 2, 3)), np.full((2, 2, 3), 4.0))
    >>> clone = _gaussian_clone(buffer, np.zeros((2, 2, 3)), seed=0)
    >>> clone.count.tolist() == buffer.count.tolist(), bool(np.all(clone.variance == buffer.variance))
    (True, True)
    >>> bool(np.all(clone.mean != buffer.mean))
    True
    """
    source = buffer if noise_of is None else noise_of
    v = source.estimated_variance() / np.maximum(source.count, 1)[..., None]
    noise = np.random.default_rng(seed).standard_normal(v.shape)
    return SampleBuffer.from_moments(buffer.count, ref + np.sqrt(v) * noise, buffer.variance,
                                     variance_known=buffer.variance_known, features=buffer.features)


def _stein(buffer: SampleBuffer, features: bool, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reconstruction (with or without the feature pilot), its per-pixel Stein risk terms
    ``(f - x)^2 - v + 2 d`` with the divergence ``d`` from one Rademacher probe of the whole reconstruction
    (:func:`_probed`), and its true squared error against ``ref``."""
    x, v, n, moved = _probed(buffer)
    image = reconstruct(buffer, features=features)
    d = n * (reconstruct(moved, features=features) - image) / SURE_EPS
    return image, (image - x) ** 2 - v + 2 * d, (image - ref) ** 2


def stein(scenes: list[tuple[str, str, tuple[int, int] | None]], spps: tuple[int, ...], groups: int,
          cache: Path) -> list[dict[str, Any]]:
    """Stein's unbiased risk estimate of whole reconstructions (Monte-Carlo SURE, one probe of the means) on
    the renderers' buffers and on Gaussian clones of them, and the choice it makes per image between the default
    and the feature pilot (the features where both criteria, the squared and the relative, say they are lower),
    against the truth; every sum in relMSE's weights ``1 / (f^2 + 0.01)``, the default's ``f`` standing in for
    the reference (the relative criterion), or in none (the squared one). Also the default given the next group's
    variances (another render's of the same pixels, independent of the means: ``groups`` at least 2). Each image's
    relMSE, MSE (the plain mean's too) and image-mean error against the buffer's means."""
    rows = []
    for renderer, scene, shape in scenes:
        ref = reference(renderer, scene, shape, cache)
        for g in range(groups):
            others = feature_buffers(renderer, scene, shape, spps, (g + 1) % groups, cache)
            for spp, buffer in feature_buffers(renderer, scene, shape, spps, g, cache).items():
                default, est_a, true_a = _stein(buffer, False, ref)
                chosen, est_c, true_c = _stein(buffer, True, ref)
                _, est_clone, true_clone = _stein(_gaussian_clone(buffer, ref, seed=g), False, ref)
                _, est_stated, true_stated = _stein(_gaussian_clone(buffer, ref, seed=g, noise_of=others[spp]), False,
                                                    ref)
                swapped = SampleBuffer.from_moments(buffer.count, buffer.mean, others[spp].variance,
                                                    variance_known=buffer.variance_known)
                other_image, est_other, true_other = _stein(swapped, False, ref)
                row: dict[str, Any] = {"renderer": renderer, "scene": scene, "spp": spp, "group": g}
                for name, w in (("squared", np.ones_like(default)), ("relative", 1.0 / (default * default + 0.01))):
                    row[name] = {key: float(np.sum(w * term)) for key, term in
                                 (("default_estimated", est_a), ("default_true", true_a),
                                  ("features_estimated", est_c), ("features_true", true_c),
                                  ("clone_estimated", est_clone), ("clone_true", true_clone),
                                  ("swapped_estimated", est_other), ("swapped_true", true_other),
                                  ("stated_estimated", est_stated), ("stated_true", true_stated))}
                picked = all(row[name]["features_estimated"] < row[name]["default_estimated"]
                             for name in ("squared", "relative"))
                row["features_picked"] = picked
                x = filled_mean(buffer)
                row["mse_plain"] = mse(x, ref)
                for name, image in (("default", default), ("features", chosen), ("swapped", other_image)):
                    row.update({f"relmse_{name}": relmse(image, ref), f"mse_{name}": mse(image, ref),
                                f"mean_error_{name}": mean_error(image, x)})
                rows.append(row)
        print(f"{renderer} {scene}: done", flush=True)
    return rows


def stein_table(rows: list[dict]) -> None:
    """Per scene and spp, means over the groups: the default's risk estimated over its true risk on the buffer
    and on its Gaussian clone, the features' change of risk estimated and true (in the default's true risk), how
    many groups the estimate gives to the features, the relMSE of its choice and of the features over the
    default's, the default's with another render's variances, and every image's MSE over the plain mean's and its
    worst image-mean error."""
    print("\n| renderer | scene | spp | default's risk, estimated / true: buffer, Gaussian clone, Gaussian clone of "
          "another render's noise (relative; squared) "
          "| features' change of risk, estimated, true (relative) | features picked | relMSE / default's: picked, "
          "features | another render's variances: relMSE / default's; risk, estimated / true (relative) | MSE / plain: "
          "default, features, another render's variances | worst image-mean error % (the same three) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    keys = dict.fromkeys((r["renderer"], r["scene"], r["spp"]) for r in rows)
    for renderer, scene, spp in keys:
        group = [r for r in rows if (r["renderer"], r["scene"], r["spp"]) == (renderer, scene, spp)]

        def ratio(criterion: str, est: str, true: str) -> float:
            return float(np.mean([r[criterion][est] / r[criterion][true] for r in group]))

        change = [float(np.mean([(r["relative"][f"features_{k}"] - r["relative"][f"default_{k}"])
                                 / r["relative"]["default_true"] for r in group])) for k in ("estimated", "true")]
        picked = [r["relmse_features"] if r["features_picked"] else r["relmse_default"] for r in group]
        print(f"| {renderer} | {scene} | {spp} | {ratio('relative', 'default_estimated', 'default_true'):.2f}, "
              f"{ratio('relative', 'clone_estimated', 'clone_true'):.2f}, "
              f"{ratio('relative', 'stated_estimated', 'stated_true'):.2f}; "
              f"{ratio('squared', 'default_estimated', 'default_true'):.2f}, "
              f"{ratio('squared', 'clone_estimated', 'clone_true'):.2f}, "
              f"{ratio('squared', 'stated_estimated', 'stated_true'):.2f} | {100 * change[0]:+.1f}%, "
              f"{100 * change[1]:+.1f}% | {sum(r['features_picked'] for r in group)} of {len(group)} | "
              f"{np.mean(picked) / np.mean([r['relmse_default'] for r in group]):.3f}, "
              f"{_mean(group, 'relmse_features') / _mean(group, 'relmse_default'):.3f} | "
              f"{_mean(group, 'relmse_swapped') / _mean(group, 'relmse_default'):.3f}; "
              f"{ratio('relative', 'swapped_estimated', 'swapped_true'):.2f} | "
              + ", ".join(f"{_mean(group, f'mse_{n}') / _mean(group, 'mse_plain'):.2f}" for n in STEIN_IMAGES) + " | "
              + ", ".join(f"{100 * max(abs(r[f'mean_error_{n}']) for r in group):.2g}" for n in STEIN_IMAGES) + " |")


STEIN_IMAGES = ("default", "features", "swapped")
"""The images :func:`stein` scores: the default, with the feature pilot, and given another render's variances."""


# ---------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("section", choices=("quality", "samplers", "synthetic", "ablations", "avenues", "features",
                                            "rules", "pbrt", "auxiliary", "tolerance", "criteria", "stein", "crops",
                                            "tables"))
    parser.add_argument("--scenes", nargs="+", help="scenes (default: every bundled tracer and Mitsuba scene)")
    parser.add_argument("--spps", nargs="+", type=whole_option(minimum=1, maximum=MAX_SPP), default=list(SPPS))
    parser.add_argument("--groups", type=whole_option(minimum=1), default=2)
    parser.add_argument("--crop-spp", type=int, default=8, choices=SPPS, help="crops: spp shown (default 8)")
    parser.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "awr-denoise" / "reconstruct",
                        help="where rendered buffers and Mitsuba references are kept (default %(default)s)")
    parser.add_argument("--output", type=results_file, default=RESULTS,
                        help="results JSON (default benchmarks/results/guides.json); a trial run keeps the stored one")
    parser.add_argument("--images", type=Path, default=IMAGES, help="crops: folder of the PNGs (default docs/img)")
    args = parser.parse_args(argv)
    # samplers and ablations render the tracer's scenes alone; avenues the largest spp of SPPS; ablations, features,
    # rules and stein 8 and 32 spp (features and rules: both when neither is given)
    check_scenes(parser, args.scenes, TRACER_SCENES if args.section in ("samplers", "ablations")
                 else TRACER_SCENES + MITSUBA_SCENES)
    if args.section == "avenues" and max(args.spps) not in SPPS:
        parser.error(f"--spps: avenues measures the largest of {', '.join(map(str, args.spps))}, which is not one "
                     f"of {', '.join(map(str, SPPS))}")
    if args.section in ("ablations", "stein") and not {8, 32} & set(args.spps):
        parser.error(f"--spps: {args.section} measures 8 and 32 spp; none of them is given")
    if args.section != "tables" and not guides.oidn_available():
        print(f"bench_guides: {guides.OIDN_HINT}", file=sys.stderr)
        return 2
    command = recorded_command("bench_guides.py", argv, args)
    if args.section == "quality":
        rows = quality(quality_scenes(args.scenes), tuple(sorted(args.spps)), args.groups, args.cache)
        update_section(args.output, "quality", rows, command, "pyoidn")
        quality_tables(rows)
    elif args.section == "samplers":
        rows = samplers(tuple(args.scenes or TRACER_SCENES), tuple(s for s in args.spps if s >= 16) or (16, 32), 0)
        update_section(args.output, "samplers", rows, command, "pyoidn")
        sampler_table(rows)
    elif args.section == "synthetic":
        rows = synthetic(("gradient", "edges", "hdr_source"), (4, 16, 64, 256), 4)
        update_section(args.output, "synthetic", rows, command, "pyoidn")
        synthetic_table(rows)
    elif args.section == "ablations":
        rows = ablations(tuple(args.scenes or TRACER_SCENES), tuple(s for s in args.spps if s in (8, 32)), args.cache)
        update_section(args.output, "ablations", rows, command, "pyoidn")
        ablation_table(rows)
    elif args.section == "avenues":
        rows = avenues(quality_scenes(args.scenes), max(args.spps), args.groups, args.cache)
        update_section(args.output, "avenues", rows, command, "pyoidn")
        avenue_table(rows)
    elif args.section == "features":
        rows = feature_limits(quality_scenes(args.scenes), tuple(s for s in args.spps if s in (8, 32)) or (8, 32),
                              args.groups, args.cache)
        update_section(args.output, "features", rows, command, "pyoidn")
        feature_limits_table(rows)
    elif args.section == "rules":
        rows = pilot_rules(quality_scenes(args.scenes), tuple(s for s in args.spps if s in (8, 32)) or (8, 32),
                           args.groups, args.cache)
        update_section(args.output, "rules", rows, command, "pyoidn")
        pilot_rules_table(rows)
    elif args.section == "pbrt":
        rows = pbrt()
        update_section(args.output, "pbrt", rows, command, "pyoidn")
        pbrt_table(rows)
    elif args.section == "auxiliary":
        rows = auxiliary(quality_scenes(args.scenes), tuple(sorted(args.spps)), args.groups, args.cache)
        update_section(args.output, "auxiliary", rows, command, "pyoidn")
        auxiliary_table(rows)
    elif args.section == "tolerance":
        rows = tolerance(quality_scenes(args.scenes), tuple(sorted(args.spps)), args.groups, args.cache)
        update_section(args.output, "tolerance", rows, command, "pyoidn")
        tolerance_table(rows)
    elif args.section == "criteria":
        rows = criteria(quality_scenes(args.scenes), tuple(sorted(args.spps)), args.groups, args.cache)
        update_section(args.output, "criteria", rows, command, "pyoidn")
        criteria_table(rows)
    elif args.section == "stein":
        if args.groups < 2:
            parser.error("stein: --groups must be at least 2 (each group is given the next one's variances)")
        rows = stein(quality_scenes(args.scenes), tuple(s for s in args.spps if s in (8, 32)) or (8, 32),
                     args.groups, args.cache)
        update_section(args.output, "stein", rows, command, "pyoidn")
        stein_table(rows)
    elif args.section == "crops":
        update_section(args.output, "crops", crops(args.crop_spp, args.cache, args.images), command, "pyoidn")
    else:  # print the tables of the stored results
        data = json.loads(args.output.read_text())
        for section, show in (("quality", quality_tables), ("samplers", sampler_table),
                              ("synthetic", synthetic_table), ("ablations", ablation_table),
                              ("avenues", avenue_table), ("features", feature_limits_table),
                              ("rules", pilot_rules_table), ("pbrt", pbrt_table),
                              ("auxiliary", auxiliary_table), ("tolerance", tolerance_table),
                              ("criteria", criteria_table), ("stein", stein_table)):
            if section in data:
                print(f"\n## {section} ({data[section]['command']})")
                show(data[section]["rows"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
