"""The reconstruction's measurements behind docs/reconstruction.md: quality, samplers, consistency, speed.

Run from the repository root (each section updates its part of the JSON)::

    .venv/bin/python benchmarks/bench_reconstruct.py quality      # bundled tracer (+ Mitsuba 3), 8-128 spp
    .venv/bin/python benchmarks/bench_reconstruct.py samplers     # samplers at equal samples (--caps)
    .venv/bin/python benchmarks/bench_reconstruct.py refresh      # the measured gain measured less often
    .venv/bin/python benchmarks/bench_reconstruct.py seeds        # the same per seed on the synthetic scenes
    .venv/bin/python benchmarks/bench_reconstruct.py synthetic    # known clean images, 4-1024 spp
    .venv/bin/python benchmarks/bench_reconstruct.py speed        # 128x128, 256x256, 1080p
    .venv/bin/python benchmarks/bench_reconstruct.py agreed       # the cost of moderating samples that agreed
    .venv/bin/python benchmarks/bench_reconstruct.py finishing    # the image mean's correction, compared
    .venv/bin/python benchmarks/bench_reconstruct.py empty        # pixels without samples, scattered or a half

``quality`` renders every scene with uniform sampling in four disjoint sample groups (renderer
seeds 0-3, nested 8..128 spp; cached under ``--cache``) and compares, against the scene's
reference, the plain mean, stage 1 alone (``stages=1``: the previous default) and the default
reconstruction: relMSE, MSE and the image mean. The bundled tracer's scenes are 128x128 with
their 4096-spp references; Mitsuba 3 scenes run through the ``mitsuba`` renderer when it is
installed (skipped with a notice otherwise), 256x256 against a 1024-spp render cached once.
``speed`` times every variant in interleaved rounds on the same buffer and reports medians and
ratios to stage 1 alone measured in the same rounds: on a shared machine only such ratios mean
much. Results: ``benchmarks/results/reconstruct.json`` (``--output`` another file, which a partial run
should use: a section is replaced whole).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import sys
import time
from functools import partial
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
from scipy import ndimage

from awr_denoise import AdaptiveSampler, SampleBuffer, SampleRequest, UniformSampler, VarianceSampler, reconstruct
from awr_denoise import finishing as finishing_steps
from awr_denoise import fused, pooling, rims
from awr_denoise._checks import MAX_SPP, whole_option
from awr_denoise.bench import update_section
from awr_denoise.bench.cache import load_arrays, save_arrays
from awr_denoise.bench.records import results_file
from awr_denoise.features import FEATURE_CHANNELS
from awr_denoise.finishing import RESTORE_SHARE, match_mean, restore_mean
from awr_denoise.metrics import mean_error, mse, relmse
from awr_denoise.prepare import prepare
from awr_denoise.reconstruct import DEFAULT_DOMAIN, _wiener_levels, later_stages, resolve_settings
from awr_denoise.renderers import create_renderer
from awr_denoise.sure import sure_blend
from awr_denoise.synthetic import SyntheticRenderer, list_scenes, make_scene
from awr_denoise.thresholding import threshold_stage
from awr_denoise.wavelets import wavelet_operators

sys.path.insert(0, str(Path(__file__).resolve().parent))
from decimated_wiener import SHIFT_SETS, decimated_default  # noqa: E402
from moderated_variances import VARIANTS as MODERATED  # noqa: E402

ROOT = Path(__file__).resolve().parent
RESULTS = ROOT / "results" / "reconstruct.json"
TRACER_SCENES = ("default", "chess_dof", "rolling_balls", "sky_objects", "soft_shadows", "cornell_gi")
MITSUBA_SCENES = ("cornell_box", "envmap_sun", "glossy_glass", "dof_checker")
MITSUBA_SHAPE = (256, 256)
MITSUBA_REFERENCE_SPP = 1024
SPPS = (8, 16, 32, 64, 128)
METHODS: dict[str, dict[str, Any] | None] = {"plain": None, "stage 1": {"stages": 1}, "default": {}}
SIZES = {"128x128": (128, 128), "256x256": (256, 256), "1080p": (1080, 1920)}


@contextlib.contextmanager
def unguided_guard(**options: Any) -> Iterator[None]:
    """The guard's ``sure_blend`` options without a guide set to ``options`` in place of the library's
    (``DEFAULT_TOLERANCE`` with ``DEFAULT_SPARED_BESIDE``), from the strict guard's (``tolerance=1``, none spared):
    no options is the strict guard, ``tolerance=1.2`` alone is 1.2 for both criteria with no pixel spared. A
    guide's guard (which spares no pixel) is left as it is."""
    def guarded(*args: Any, **kwargs: Any) -> Any:
        if kwargs.get("spared_beside") is None:  # a guide's guard: the library's
            return sure_blend(*args, **kwargs)
        return sure_blend(*args, **{**kwargs, "tolerance": 1.0, "spared_beside": None, **options})
    with mock.patch.object(sys.modules["awr_denoise.reconstruct"], "sure_blend", guarded):
        yield


def strict_guard(buffer: SampleBuffer) -> np.ndarray:
    """The default with the guard as it was before its tolerance without a guide (:func:`unguided_guard`)."""
    with unguided_guard():
        return reconstruct(buffer)


SPEED_VARIANTS: dict[str, Any] = {
    "stage 1 alone": {"stages": 1},
    "stage 1 alone, float64": {"stages": 1, "precision": "float64"},
    "default": {},
    "default, float64 FFTs": {"precision": "float64"},
    "default without the guard": {"guard": False},
    "three Wiener stages": {"stages": 4, "wiener_exponents": (0.75, 0.5, 0.4)},
    "one Wiener stage": {"stages": 2, "wiener_exponents": (0.4,)},
    "default with a guide": {"guide": "reference"},
    "default without the energy floor": "no energy floor",
    "one Wiener level fewer": "one Wiener level fewer",
    "default with the strict guard": strict_guard,
}
"""``speed``: reconstruct() options per variant, or a function of the buffer; ``"reference"`` stands for the
scene's clean image (a guide the gate trusts everywhere, so the projection on the guide runs on the whole image);
a string names a function of :data:`COMPARED` (an earlier form) or :data:`CHEAPER`; ``--shifts`` adds
:data:`SHIFTED`, ``--spun`` :data:`SPUN`."""


def fewer_wiener_levels(buffer: SampleBuffer) -> np.ndarray:
    """The default with its Wiener stages one undecimated level shallower; stage 1's depth unchanged."""
    settings = resolve_settings()
    target = _wiener_levels(wavelet_operators(buffer.shape).levels) - 1
    depth = target + 1 if target >= 3 else target  # later_stages takes stage 1's depth and derives the stages'
    assert _wiener_levels(depth) == target >= 1
    return _staged(buffer, settings, settings.stage1_clamp, depth)


CHEAPER: dict[str, Any] = {"one Wiener stage": SPEED_VARIANTS["one Wiener stage"],
                           "one Wiener stage, alpha 0.75": {"stages": 2, "wiener_exponents": (0.75,)},
                           "one Wiener level fewer": fewer_wiener_levels}
"""``quality --cheaper``: variants that trade quality for speed, measured beside the default (one Wiener stage
with the default's last exponent, and with its first; the Wiener stages one undecimated level shallower)."""


def _staged(buffer: SampleBuffer, settings: Any, stage1_clamp: float | None, depth: int | None = None) -> np.ndarray:
    """The default's steps from the library's stages, with ``settings`` and stage 1's clamp given; ``depth``:
    the stage-1 depth ``later_stages`` derives the Wiener stages' from (default: stage 1's own)."""
    prepared = prepare(buffer, DEFAULT_DOMAIN)
    ops = wavelet_operators(buffer.shape)
    stage = threshold_stage(prepared, ops, settings.c_s, pixel_clamp=stage1_clamp, precision=settings.precision)
    return later_stages(prepared, stage.image, None, settings, levels=ops.levels if depth is None else depth,
                        wavelet=ops.wavelet)[0]


PILOT_SHIFTS = ((0, 0), (1, 1), (0, 1), (1, 0))
"""``quality --spun``: the grid shifts stage 1 is averaged over as the pilot, in this order (2 shifts: the first
two)."""


def _shifted(prepared: Any, dy: int, dx: int) -> Any:
    """The prepared planes with ``dy`` rows and ``dx`` columns mirrored in front of them: stage 1's decimated grid
    moved by (dy, dx) against the image (the derived planes are computed again from the padded ones)."""
    def pad(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else np.pad(a, [(dy, 0), (dx, 0)] + [(0, 0)] * (a.ndim - 2), mode="symmetric")

    return dataclasses.replace(prepared, mean=pad(prepared.mean), sample_variance=pad(prepared.sample_variance),
                               count=pad(prepared.count), sampled=pad(prepared.sampled))


def spun_pilot(shifts: int) -> Any:
    """The default with its first Wiener stage's pilot cycle-spun: stage 1 (as the default runs it) averaged over
    the first ``shifts`` grid shifts of :data:`PILOT_SHIFTS`, each aligned back (Coifman and Donoho 1995)."""
    def run(buffer: SampleBuffer) -> np.ndarray:
        settings = resolve_settings()
        prepared = prepare(buffer, DEFAULT_DOMAIN)
        ops = wavelet_operators(buffer.shape)
        h, w = buffer.shape
        pilot = np.zeros(prepared.mean.shape)
        for dy, dx in PILOT_SHIFTS[:shifts]:
            moved = wavelet_operators((h + dy, w + dx), levels=ops.levels)
            pilot += threshold_stage(_shifted(prepared, dy, dx), moved, settings.c_s, pixel_clamp=settings.stage1_clamp,
                                     precision=settings.precision).image[dy:, dx:]
        return later_stages(prepared, pilot / shifts, None, settings, levels=ops.levels, wavelet=ops.wavelet)[0]
    return run


def clamped_pilot(buffer: SampleBuffer) -> np.ndarray:
    """The default as it was before its pilot ran unclamped: stage 1 clamped too, then the rest."""
    settings = resolve_settings()
    return _staged(buffer, settings, settings.pixel_clamp)


def with_floor(floor: tuple[int, float] | None) -> Any:
    """The default with the first Wiener stage's energy floor ``(window, margin)``, or none."""
    def run(buffer: SampleBuffer) -> np.ndarray:
        settings = dataclasses.replace(resolve_settings(), floor=floor)
        return _staged(buffer, settings, settings.stage1_clamp)
    return run


def with_constant(module: Any, name: str, value: Any) -> Any:
    """The default reconstruction with ``module.name`` at ``value`` (put back afterwards)."""
    def run(buffer: SampleBuffer) -> np.ndarray:
        with mock.patch.object(module, name, value):
            return reconstruct(buffer)
    return run


def with_agreed_prior(prior: float) -> Any:
    """The default with ``pooling.AGREED_PRIOR`` at ``prior``."""
    return with_constant(pooling, "AGREED_PRIOR", prior)


def agreed_held_exact(buffer: SampleBuffer) -> np.ndarray:
    """The default as it was before samples that all agreed were moderated: their zero variance taken as exact."""
    return with_agreed_prior(0.0)(buffer)


def with_pool_chance(chance: float) -> Any:
    """The default with ``finishing.POOL_CHANCE`` at ``chance``."""
    return with_constant(finishing_steps, "POOL_CHANCE", chance)


def clamp_pools_every_neighbour(buffer: SampleBuffer) -> np.ndarray:
    """The default as it was before the clamp's neighbours were tested: ``finishing.POOL_CHANCE`` at 0."""
    return with_pool_chance(0.0)(buffer)


COMPARED: dict[str, Any] = {"pilot clamped": clamped_pilot, "no energy floor": with_floor(None),
                             "pilot c_s 1.5": {"c_s": 1.5}, "agreed samples held exact": agreed_held_exact,
                             "clamp pools every neighbour": clamp_pools_every_neighbour}
"""``quality --compare``: earlier forms of the default, measured beside it."""
FLOORS: dict[str, Any] = {"energy floor 3x3": with_floor((3, 2.0)), "energy floor 7x7": with_floor((7, 2.0)),
                          "energy floor margin 1.5": with_floor((5, 1.5)), "energy floor margin 3": with_floor((5, 3.0))}
"""``quality --floors``: the first Wiener stage's energy floor at other windows and margins than (5, 2)."""
PILOTS: dict[str, Any] = {"pilot c_s 2.5": {"c_s": 2.5}, "pilot c_s 3": {"c_s": 3.0}}
"""``quality --pilots``: stage 1's threshold as the pilot at other values than the default (2); 1.5 is in COMPARED."""
SPUN: dict[str, Any] = {f"pilot spun over {n} shifts": spun_pilot(n) for n in (2, 4)}
"""``quality --spun`` and ``speed --spun``: the first Wiener stage's pilot cycle-spun over 2 and 4 shifts of stage 1's
decimated grid (:func:`spun_pilot`; the Wiener stages themselves are translation-invariant already)."""
SHIFTED: dict[str, Any] = {f"decimated Wiener stages, {n} shift{'s' * (n > 1)}": decimated_default(n)
                           for n in SHIFT_SETS}
"""``quality --shifts`` and ``speed --shifts``: the Wiener stages on the decimated transform, cycle-spun over
1, 4 and 16 shifts, against the default's undecimated transform (every shift at once; decimated_wiener.py)."""
PRIORS: dict[str, Any] = {f"agreed prior {d:g}": with_agreed_prior(d) for d in (0.5, 2.0, 4.0)}
"""``quality --priors``: the degrees of freedom of samples that all agreed (``pooling.AGREED_PRIOR``) beside the
default's 1 (0, the previous form, is in COMPARED)."""
CHANCES: dict[str, Any] = {"pool chance 1e-4": with_pool_chance(1e-4), "pool chance 1e-5": with_pool_chance(1e-5)}
"""``quality --chances``: the least chance for a neighbour to pool into the clamp (``finishing.POOL_CHANCE``) beside
the default's 1e-3 (0, the previous form, is in COMPARED)."""
WINDOWS: dict[str, Any] = {"guard window 13": {"guard_window": 13}, "guard window 17": {"guard_window": 17}}
"""``quality --windows`` and ``synthetic --windows``: the SURE guard's window at other sides than the default (9)."""
RIMS: dict[str, Any] = {"rims lend": with_constant(rims, "EDGE_BLOCK", sys.maxsize)}
"""``quality --rims``: the default as it was before a light's rim stopped lending its spread to the exact pixels
beside it (``rims.EDGE_BLOCK`` out of reach: no pixel is a rim; docs/reconstruction.md, "Samples that all
agreed")."""
PROBES: dict[str, Any] = {"guard probes 1": {"guard_probes": 1}}
"""``quality --probes``, ``synthetic --probes`` and ``speed --probes``: the guard given the Wiener stages'
divergence measured by one probe (``guard_probes``) instead of their diagonal (docs/reconstruction.md, "The
guard's divergence")."""


# ---------------------------------------------------------------------------- buffers
def _save(path: Path, buffer: SampleBuffer, render: str) -> None:
    """The buffer's arrays and ``render`` (what made them: :func:`_render_key`), written whole."""
    arrays = {"render": np.array(render), "count": buffer.count, "mean": buffer.mean, "variance": buffer.variance}
    for name, f in buffer.features.items():
        arrays.update({f"{name}_count": f.count, f"{name}_mean": f.mean, f"{name}_variance": f.variance})
    save_arrays(path, arrays)


def _render_key(renderer: str, scene: str, shape: tuple[int, int] | None, group: int, spp: int,
                options: dict[str, Any]) -> str:
    """What a cached buffer is: its renderer, scene, size, seed, samples and the renderer's options."""
    return json.dumps({"renderer": renderer, "scene": scene, "shape": shape, "group": group, "spp": spp,
                       "options": options}, sort_keys=True)


def _load(path: Path, render: str, spp: int) -> SampleBuffer | None:
    """The cached buffer of ``render`` at ``path``, or ``None`` (with a warning naming the file) when it is missing,
    does not read whole, or is another render's: another scene's, group's or spp's under this name, one cut short
    by an interrupted run of old (its features missing), or one made before the files said what they are."""
    wanted = json.loads(render)

    def check(d: Any) -> str | None:
        if not isinstance(d, dict) or "render" not in d:
            return "not a cached buffer that says what it is"
        if str(d["render"]) != render:
            return f"another render's buffer ({d['render']})"
        names = ["count", "mean", "variance"]
        if wanted["options"].get("features") == "all":
            names += [f"{n}_{k}" for n in FEATURE_CHANNELS for k in ("count", "mean", "variance")]
        missing = [n for n in names if n not in d]
        if missing:
            return f"arrays missing: {', '.join(missing)}"
        if int(d["count"].max(initial=0)) != spp:
            return f"not {spp} samples a pixel"
        return None

    d = load_arrays(path, check)
    if d is None:
        return None
    features = {name: SampleBuffer.from_moments(d[f"{name}_count"], d[f"{name}_mean"], d[f"{name}_variance"],
                                                channels=channels)
                for name, channels in FEATURE_CHANNELS.items() if f"{name}_mean" in d}
    return SampleBuffer.from_moments(d["count"], d["mean"], d["variance"], features=features)


def uniform_buffers(renderer: str, scene: str, shape: tuple[int, int] | None, spps: tuple[int, ...], group: int,
                    cache: Path, *, prefix: str = "", **options: Any) -> dict[int, SampleBuffer]:
    """Group ``group``'s buffers at every spp: one renderer (seed ``group``), samples added in order.

    ``options`` go to the renderer (``features="all"`` for buffers with features); ``prefix``
    keeps their cache files apart from the plain ones.
    """
    paths = {s: cache / f"{prefix}{renderer}_{scene}_g{group}_s{s}.npz" for s in spps}
    renders = {s: _render_key(renderer, scene, shape, group, s, options) for s in spps}
    loaded = {s: _load(p, renders[s], s) for s, p in paths.items()}
    if all(b is not None for b in loaded.values()):
        return loaded  # type: ignore[return-value]
    r = create_renderer(renderer, scene, shape=shape, seed=group, **options)
    shape = r.shape if shape is None else shape
    out, buffer, done = {}, None, 0
    for s in sorted(spps):
        part = r(SampleRequest.uniform(shape, s - done, first_index=done))
        buffer = part if buffer is None else buffer.merge(part)
        done = s
        _save(paths[s], buffer, renders[s])
        out[s] = buffer
    getattr(r, "close", lambda: None)()
    return out


def reference(renderer: str, scene: str, shape: tuple[int, int] | None, cache: Path) -> np.ndarray:
    if renderer == "tracer":
        from awr_denoise import tracer  # the bundled tracer's own cached 4096-spp references
        return np.asarray(tracer.load_reference(scene), dtype=np.float64)
    assert shape is not None
    path = cache / f"{renderer}_{scene}_{shape[0]}x{shape[1]}_{MITSUBA_REFERENCE_SPP}spp_reference.npy"
    image = load_arrays(path, lambda a: None if a.shape == (*shape, 3) and np.isfinite(a).all()
                        else f"shape {a.shape} or values not finite, not a {shape[0]}x{shape[1]} reference")
    if image is None:
        r = create_renderer(renderer, scene, shape=shape, seed=10**6)
        image = np.asarray(r(SampleRequest.uniform(shape, MITSUBA_REFERENCE_SPP)).mean)
        save_arrays(path, image)
    return image


def _mitsuba_available() -> bool:
    try:
        from awr_denoise.renderers import renderer_factory
        renderer_factory("mitsuba")
        import mitsuba  # noqa: F401  (the extra 'mitsuba')
        return True
    except ImportError as error:
        print(f"skipping the Mitsuba 3 scenes: {error}")
        return False


# ---------------------------------------------------------------------------- quality
def _measure(image: np.ndarray, x: np.ndarray, ref: np.ndarray, seconds: float) -> dict[str, Any]:
    return {"relmse": relmse(image, ref), "mse": mse(image, ref), "mean_error": mean_error(image, x),
            "negative": int((image < 0).sum()), "seconds": seconds}


def quality(scenes: list[tuple[str, str, tuple[int, int] | None]], spps: tuple[int, ...], groups: int, cache: Path,
            methods: dict[str, Any]) -> list[dict[str, Any]]:
    """Every method (reconstruct's options, a function of the buffer, or None: the plain mean) on every group."""
    rows = []
    for renderer, scene, shape in scenes:
        ref = reference(renderer, scene, shape, cache)
        for g in range(groups):
            for spp, buffer in uniform_buffers(renderer, scene, shape, spps, g, cache).items():
                x = prepare(buffer, "log").mean
                for name, options in methods.items():
                    start = time.perf_counter()
                    image = (x if options is None else options(buffer) if callable(options)
                             else reconstruct(buffer, **options))
                    rows.append({"renderer": renderer, "scene": scene, "spp": spp, "group": g, "method": name,
                                 **_measure(image, x, ref, time.perf_counter() - start)})
        print(f"{renderer} {scene}: done", flush=True)
    return rows


def _mean(rows: list[dict], key: str, **where: Any) -> float:
    values = [r[key] for r in rows if all(r[k] == v for k, v in where.items())]
    return float(np.mean(values)) if values else float("nan")


def quality_tables(rows: list[dict], method: str = "default", base: str = "stage 1") -> None:
    """Markdown: per scene and spp, the means over groups; then the issue's goals per scene."""
    print(f"\n| scene | spp | relMSE plain | relMSE {base} | relMSE {method} | gain vs {base} | MSE / plain "
          f"({base}) | MSE / plain ({method}) | worst mean error % ({base}, {method}) |")
    print("|---|---|---|---|---|---|---|---|---|")
    scenes = list(dict.fromkeys((r["renderer"], r["scene"]) for r in rows))
    summary = []
    for renderer, scene in scenes:
        w = {"renderer": renderer, "scene": scene}
        spps = sorted({r["spp"] for r in rows if r["scene"] == scene})
        gains, mse_ratio, rel_ratio = [], [], []
        for spp in spps:
            rp, rb, rm = (_mean(rows, "relmse", spp=spp, method=m, **w) for m in ("plain", base, method))
            mp, mb, mm = (_mean(rows, "mse", spp=spp, method=m, **w) for m in ("plain", base, method))
            eb, em = (max(r["mean_error"] for r in rows if r["scene"] == scene and r["spp"] == spp and r["method"] == m)
                      for m in (base, method))
            print(f"| {scene} | {spp} | {rp:.5f} | {rb:.5f} | {rm:.5f} | {rb / rm:.2f} | {mb / mp:.2f} | {mm / mp:.2f} "
                  f"| {100 * eb:.2f}, {100 * em:.2g} |")
            if spp <= 32:
                gains.append(rb / rm)
            mse_ratio.append(mm / mp)
            rel_ratio.append(rm / rp)
        summary.append((scene, gains, max(mse_ratio), max(rel_ratio)))
    print(f"\n| scene | relMSE gain vs {base}, 8 / 16 / 32 spp | max MSE / plain | max relMSE / plain |")
    print("|---|---|---|---|")
    for scene, gains, m, r in summary:
        print(f"| {scene} | {' / '.join(f'{g:.2f}' for g in gains)} | {m:.2f} | {r:.2f} |")
    every = [g for _, gains, _, _ in summary for g in gains]
    print(f"\ngeometric mean of the gain at 8-32 spp: {np.exp(np.mean(np.log(every))):.2f}, least {min(every):.2f}")
    variants = (*CHEAPER, *SHIFTED, *COMPARED, *FLOORS, *PILOTS, *PRIORS, *MODERATED, *CHANCES, *RIMS, *WINDOWS,
                *PROBES)
    for other in (m for m in variants if any(r["method"] == m for r in rows)):
        cheaper_table(rows, other, method)
    if all(any(r["method"] == m for r in rows) for m in SPUN):
        spun_table(rows, method)


def spun_table(rows: list[dict], method: str = "default") -> None:
    """:data:`SPUN` over ``method`` at every spp: relMSE of each shift count, MSE of the most shifts (means over
    groups), the worst MSE over the plain mean's; then the relMSE ratios' spans and geometric means."""
    names = list(SPUN)
    spps = sorted({r["spp"] for r in rows})
    columns = " / ".join(map(str, spps))
    print("\n| scene | " + " | ".join(f"relMSE {n} / {method}, {columns} spp" for n in names)
          + f" | MSE {names[-1]} / {method} | max MSE / plain ({names[-1]}) |")
    print("|---|" + "---|" * (len(names) + 2))
    ratios: dict[str, list[tuple[int, float]]] = {n: [] for n in names}
    for renderer, scene in dict.fromkeys((r["renderer"], r["scene"]) for r in rows):
        w = {"renderer": renderer, "scene": scene}
        cells = []
        for n in names:
            mine = [_mean(rows, "relmse", spp=s, method=n, **w) / _mean(rows, "relmse", spp=s, method=method, **w)
                    for s in spps]
            ratios[n] += list(zip(spps, mine))
            cells.append(" / ".join(f"{r:.3f}" for r in mine))
        mse = [_mean(rows, "mse", spp=s, method=names[-1], **w) / _mean(rows, "mse", spp=s, method=method, **w)
               for s in spps]
        worst = max(_mean(rows, "mse", spp=s, method=names[-1], **w) / _mean(rows, "mse", spp=s, method="plain", **w)
                    for s in spps)
        print(f"| {scene} | " + " | ".join(cells) + f" | {' / '.join(f'{m:.3f}' for m in mse)} | {worst:.2f} |")
    for n in names:
        for label, picked in (("8-32 spp", [r for s, r in ratios[n] if s <= 32]),
                              ("every spp", [r for _, r in ratios[n]])):
            print(f"{n} / {method}, {label}: {min(picked):.3f}-{max(picked):.3f}, geometric mean "
                  f"{np.exp(np.mean(np.log(picked))):.3f}")


def cheaper_table(rows: list[dict], cheaper: str, method: str = "default") -> None:
    """relMSE of a variant (cheaper or earlier) over the default's, and its MSE over the plain mean's, at 8-32 spp."""
    compared = sorted({r["spp"] for r in rows if r["spp"] <= 32})
    columns = " / ".join(map(str, compared))
    print(f"\n| scene | relMSE {cheaper} / {method}, {columns} spp | max MSE / plain ({cheaper}) |")
    print("|---|---|---|")
    ratios = []
    for renderer, scene in dict.fromkeys((r["renderer"], r["scene"]) for r in rows):
        w = {"renderer": renderer, "scene": scene}
        spps = [s for s in sorted({r["spp"] for r in rows if r["scene"] == scene}) if s <= 32]
        mine = [_mean(rows, "relmse", spp=s, method=cheaper, **w) / _mean(rows, "relmse", spp=s, method=method, **w)
                for s in spps]
        worst = max(_mean(rows, "mse", spp=s, method=cheaper, **w) / _mean(rows, "mse", spp=s, method="plain", **w)
                    for s in sorted({r["spp"] for r in rows if r["scene"] == scene}))
        ratios += mine
        print(f"| {scene} | {' / '.join(f'{r:.2f}' for r in mine)} | {worst:.2f} |")
    print(f"\ngeometric mean of {cheaper} / {method} at {compared[0]}-{compared[-1]} spp: "
          f"{np.exp(np.mean(np.log(ratios))):.2f}, most {max(ratios):.2f}")


# ---------------------------------------------------------------------------- samplers
SAMPLER_KINDS: dict[str, Any] = {
    "uniform": lambda shape, seed: UniformSampler(shape, seed=seed),
    "variance": lambda shape, seed: VarianceSampler(shape, seed=seed),
    "awr": lambda shape, seed: AdaptiveSampler(shape, seed=seed),
    "awr, linear priorities": lambda shape, seed: AdaptiveSampler(shape, seed=seed, domain="linear"),
    "awr, measured gain": lambda shape, seed: AdaptiveSampler(shape, seed=seed, noise_model="reconstruction"),
    "awr, levels": lambda shape, seed: AdaptiveSampler(shape, seed=seed, noise_model="levels"),
    "awr, relative error alone": lambda shape, seed: AdaptiveSampler(shape, seed=seed, absolute_above=None),
}
"""``samplers``: the strategies compared at equal samples, each made from (shape, seed)."""
CAPS = (1.0, 3.0, 10.0)
"""``samplers --caps``: other values of ``absolute_above`` beside the default's 6, as samplers ``awr, cap C``."""


INITIALS = (1, 4)
"""``samplers --initials``: other values of ``initial_spp`` beside the default's 2, as samplers ``awr, initial N``."""


def initial_kinds(initials: tuple[int, ...]) -> dict[str, Any]:
    """Samplers ``awr, initial N``: AWR's default with ``initial_spp=N``."""
    return {f"awr, initial {n}": (lambda shape, seed, n=n: AdaptiveSampler(shape, seed=seed, initial_spp=n))
            for n in initials}


def cap_kinds(caps: tuple[float, ...]) -> dict[str, Any]:
    """Samplers ``awr, cap C``: AWR's default with ``absolute_above=C``."""
    return {f"awr, cap {c:g}": (lambda shape, seed, c=c: AdaptiveSampler(shape, seed=seed, absolute_above=c))
            for c in caps}


REFRESH_KINDS: dict[str, Any] = {
    "awr, levels": SAMPLER_KINDS["awr, levels"],
    "awr, measured gain": SAMPLER_KINDS["awr, measured gain"],
    **{f"awr, measured gain, refresh {r:g}": (lambda shape, seed, r=r: AdaptiveSampler(
        shape, seed=seed, noise_model="reconstruction", gain_refresh=r)) for r in (1.5, 2.0)},
}
"""``refresh``: the measured gain measured every round (the default) and once the samples grew by 1.5 or 2, against
the paper's level model (the samplers' default when the section was written)."""


def samplers(scenes: list[tuple[str, str, tuple[int, int] | None]], spps: tuple[int, ...], seeds: int,
             cache: Path, kinds: dict[str, Any] = SAMPLER_KINDS) -> list[dict[str, Any]]:
    """Equal samples: every kind of :data:`SAMPLER_KINDS`, renders of seeds ``0..seeds-1``, progressive to
    each spp; stage 1 and the default on every buffer; the time spent in ``ask()`` (priorities + allocation)."""
    rows = []
    for renderer_name, scene, shape in scenes:
        ref = reference(renderer_name, scene, shape, cache)
        for seed in range(seeds):
            for kind, make in kinds.items():
                renderer = create_renderer(renderer_name, scene, shape=shape, seed=seed)
                sampler = make(ref.shape[:2], seed)
                asked = [0.0]
                ask = sampler.ask

                def timed_ask(budget: int | None = None, ask: Any = ask, asked: list = asked) -> Any:
                    start = time.process_time()
                    request = ask(budget)
                    asked[0] += time.process_time() - start
                    return request

                sampler.ask = timed_ask  # type: ignore[method-assign]
                for spp in sorted(spps):
                    buffer = sampler.run(renderer, spp)
                    x = prepare(buffer, "log").mean
                    for name, options in (("stage 1", {"stages": 1}), ("default", {})):
                        image = reconstruct(buffer, **options)
                        rows.append({"renderer": renderer_name, "scene": scene, "seed": seed, "sampler": kind,
                                     "spp": spp, "method": name, "ask_seconds": asked[0],
                                     **_measure(image, x, ref, 0.0),  # its mean_error: against the means
                                     "reference_mean_error": mean_error(image, ref)})
                getattr(renderer, "close", lambda: None)()
        print(f"{renderer_name} {scene}: done", flush=True)
    return rows


def refresh_table(rows: list[dict]) -> None:
    """The gain measured less often against every round: relMSE and MSE ratios, and ask()'s time."""
    refreshed = [k for k in dict.fromkeys(r["sampler"] for r in rows) if "refresh" in k]

    def mean(key: str, **where: Any) -> float:
        return _mean(rows, key, method="default", **where)

    print("\n| scene | spp | relMSE levels / measured gain | " + " | ".join(
        f"relMSE levels / {k.split(', ')[-1]}" for k in refreshed) + " | MSE levels / measured gain | " + " | ".join(
        f"MSE levels / {k.split(', ')[-1]}" for k in refreshed) + " | ask() CPU time to the spp, levels / every round / "
        + " / ".join(k.split(", ")[-1] for k in refreshed) + " |")
    print("|---|---|" + "---|" * (3 + 2 * len(refreshed)))
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for spp in sorted({r["spp"] for r in rows}):
            base = "awr, levels" if any(r["sampler"] == "awr, levels" for r in rows) else "awr"  # older runs: "awr"
            kinds = [base, "awr, measured gain", *refreshed]
            rel = {k: mean("relmse", scene=scene, spp=spp, sampler=k) for k in kinds}
            sq = {k: mean("mse", scene=scene, spp=spp, sampler=k) for k in kinds}
            ask = [mean("ask_seconds", scene=scene, spp=spp, sampler=k) for k in kinds]
            print(f"| {scene} | {spp} | " + " | ".join(f"{rel[base] / rel[k]:.2f}" for k in kinds[1:]) + " | "
                  + " | ".join(f"{sq[base] / sq[k]:.2f}" for k in kinds[1:]) + " | "
                  + " / ".join(f"{t:.2f}" for t in ask) + " s |")


def sampler_table(rows: list[dict]) -> None:
    def mean(key: str, **where: Any) -> float:
        return _mean(rows, key, method="default", **where)

    def errors(scene: str, spp: int, sampler: str) -> dict[str, float]:
        """``{"r": relMSE, "m": MSE}`` of the default reconstruction, mean over seeds."""
        return {k: mean(key, scene=scene, spp=spp, sampler=sampler) for k, key in (("r", "relmse"), ("m", "mse"))}

    def worst_mean_error(scene: str, spp: int, sampler: str) -> float:
        """The largest image-mean error against the reference over the seeds, in percent."""
        return 100 * max(r["reference_mean_error"] for r in rows if r["method"] == "default" and r["scene"] == scene
                         and r["spp"] == spp and r["sampler"] == sampler)

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    spps = sorted({r["spp"] for r in rows})
    print("\n| scene | spp | uniform | variance | awr | awr, linear priorities | uniform / awr | variance / awr |")
    print("|---|---|---|---|---|---|---|---|")
    for scene in scenes:
        for spp in spps:
            v = {k: mean("relmse", scene=scene, spp=spp, sampler=k) for k in ("uniform", "variance", "awr",
                                                                              "awr, linear priorities")}
            print(f"| {scene} | {spp} | " + " | ".join(f"{v[k]:.5f}" for k in ("uniform", "variance", "awr",
                                                                             "awr, linear priorities"))
                  + f" | {v['uniform'] / v['awr']:.2f} | {v['variance'] / v['awr']:.2f} |")
    print("\n| scene | spp | relMSE awr | relMSE relative error alone | relative alone / awr, relMSE and MSE "
          "| uniform / awr, relMSE and MSE | uniform / relative alone, MSE |")
    print("|---|---|---|---|---|---|---|")
    for scene in scenes:
        for spp in spps:
            a, r, u = (errors(scene, spp, s) for s in ("awr", "awr, relative error alone", "uniform"))
            print(f"| {scene} | {spp} | {a['r']:.5f} | {r['r']:.5f} | {r['r'] / a['r']:.2f}, {r['m'] / a['m']:.2f} "
                  f"| {u['r'] / a['r']:.2f}, {u['m'] / a['m']:.2f} | {u['m'] / r['m']:.2f} |")
    print("\n| scene | spp | relMSE awr | relMSE measured gain | awr / measured gain | MSE awr / measured gain "
          "| uniform / measured gain, relMSE and MSE "
          "| worst image-mean error against the reference %, awr and measured gain "
          "| ask() CPU time to 32 spp, awr and measured gain |")
    print("|---|---|---|---|---|---|---|---|---|")
    for scene in scenes:
        for spp in spps:
            a, g, u = (errors(scene, spp, s) for s in ("awr", "awr, measured gain", "uniform"))
            worst = [worst_mean_error(scene, spp, s) for s in ("awr", "awr, measured gain")]
            time_cell = ""
            if spp == max(spps):
                ta, tg = (mean("ask_seconds", scene=scene, spp=spp, sampler=s) for s in ("awr", "awr, measured gain"))
                time_cell = f"{ta:.2f} s, {tg:.2f} s"
            print(f"| {scene} | {spp} | {a['r']:.5f} | {g['r']:.5f} | {a['r'] / g['r']:.2f} | {a['m'] / g['m']:.2f} "
                  f"| {u['r'] / g['r']:.2f}, {u['m'] / g['m']:.2f} | {worst[0]:.2f}, {worst[1]:.2f} "
                  f"| {time_cell} |")
    levels, measured = "awr, levels", "awr, measured gain"
    if any(r["sampler"] == levels for r in rows):
        print("\n| scene | spp | relMSE levels | relMSE awr | levels / awr, relMSE and MSE "
              "| measured gain / awr, relMSE and MSE | uniform / awr, relMSE and MSE "
              "| worst image-mean error against the reference %, levels and awr "
              "| ask() CPU time to 32 spp, levels, awr and measured gain |")
        print("|---|---|---|---|---|---|---|---|---|")
    for scene in scenes if any(r["sampler"] == levels for r in rows) else []:
        for spp in spps:
            a, lv, g, u = (errors(scene, spp, k) for k in ("awr", levels, measured, "uniform"))
            worst = [worst_mean_error(scene, spp, k) for k in (levels, "awr")]
            time_cell = ""
            if spp == max(spps):
                times = (mean("ask_seconds", scene=scene, spp=spp, sampler=k) for k in (levels, "awr", measured))
                time_cell = ", ".join(f"{t:.2f} s" for t in times)
            print(f"| {scene} | {spp} | {lv['r']:.5f} | {a['r']:.5f} | {lv['r'] / a['r']:.2f}, {lv['m'] / a['m']:.2f} "
                  f"| {g['r'] / a['r']:.2f}, {g['m'] / a['m']:.2f} | {u['r'] / a['r']:.2f}, {u['m'] / a['m']:.2f} "
                  f"| {worst[0]:.2f}, {worst[1]:.2f} | {time_cell} |")
    def over_default(kinds: list[str], headers: list[str], names: str | None = None) -> None:
        """relMSE and MSE of each kind over the default's (``awr``); with ``names`` (the default's and
        the kinds'), also the worst image-mean error against the reference and ask()'s time to 32 spp."""
        if not kinds:
            return
        extra = [f"worst image-mean error against the reference %, {names}", f"ask() CPU time to 32 spp, {names}"]
        print("\n| scene | spp | " + " | ".join(headers + (extra if names else [])) + " |")
        print("|---|---|" + "---|" * (len(kinds) + 2 * (names is not None)))
        for scene in scenes:
            for spp in spps:
                a = errors(scene, spp, "awr")
                line = " | ".join(f"{e['r'] / a['r']:.3f}, {e['m'] / a['m']:.2f}"
                                  for e in (errors(scene, spp, k) for k in kinds))
                if names:
                    line += " | " + ", ".join(f"{worst_mean_error(scene, spp, k):.2f}" for k in ("awr", *kinds))
                    times = (mean("ask_seconds", scene=scene, spp=spp, sampler=k) for k in ("awr", *kinds))
                    line += " | " + (", ".join(f"{t:.2f} s" for t in times) if spp == max(spps) else "")
                print(f"| {scene} | {spp} | {line} |")

    caps = sorted({float(r["sampler"].split()[-1]) for r in rows if r["sampler"].startswith("awr, cap ")})
    if caps:
        over_default([f"awr, cap {c:g}" for c in caps] + ["awr, relative error alone"],
                     [f"cap {c:g} / cap 6 (default), relMSE and MSE" for c in caps]
                     + ["relative alone / cap 6, relMSE and MSE"])
    initials = [f"awr, initial {n}" for n in sorted({int(r["sampler"].split()[-1]) for r in rows
                                                      if r["sampler"].startswith("awr, initial ")})]
    over_default(initials, [f"{k[5:]} / initial 2 (default), relMSE and MSE" for k in initials],
                 "initial 2 and " + " and ".join(k[5:] for k in initials))


SEED_SCENES = ("gradient", "edges", "hdr_source", "fireflies")
SEED_SHAPE = (64, 64)  # tests/test_sampling.py's size


def seeds(names: tuple[str, ...], spps: tuple[int, ...], count: int) -> list[dict[str, Any]]:
    """Per seed, as tests/test_sampling.py runs them: AWR sampling (the default, levels, measured gain) and uniform,
    each from scratch, the default (relMSE and MSE), and relMSE with the previous pilot threshold (1.5) and with
    the strict guard (:func:`strict_guard`)."""
    rows = []
    for name in names:
        scene = make_scene(name, SEED_SHAPE)
        ref = scene.reference()
        for spp in spps:
            for seed in range(count):
                for kind in ("awr", "uniform", "awr, measured gain", "awr, levels"):
                    sampler = SAMPLER_KINDS[kind](SEED_SHAPE, seed)
                    buffer = sampler.run(SyntheticRenderer(scene, seed=seed), spp)
                    image, before = reconstruct(buffer), reconstruct(buffer, c_s=1.5)
                    rows.append({"scene": name, "spp": spp, "seed": seed, "sampler": kind,
                                 "relmse": relmse(image, ref), "mse": mse(image, ref),
                                 "relmse_pilot_1.5": relmse(before, ref),
                                 "relmse_strict_guard": relmse(strict_guard(buffer), ref)})
        print(f"{name}: done", flush=True)
    return rows


def seeds_table(rows: list[dict]) -> None:
    strict = all("relmse_strict_guard" in r for r in rows)  # rows stored before that column have none
    print("\n| scene | spp | seeds | uniform / awr, least | most | mean | seeds where uniform wins | mean, pilot c_s 1.5 "
          "| relMSE pilot 2 / 1.5, awr | relMSE pilot 2 / 1.5, uniform | MSE uniform / awr, mean (least) |"
          + (" uniform / awr with the strict guard, mean (seeds where uniform wins) | relMSE default / strict guard, "
             "awr | uniform |" if strict else ""))
    print("|---|---|---|---|---|---|---|---|---|---|---|" + ("---|---|---|" if strict else ""))
    for name in dict.fromkeys(r["scene"] for r in rows):
        for spp in sorted({r["spp"] for r in rows if r["scene"] == name}):
            pick = [r for r in rows if r["scene"] == name and r["spp"] == spp]
            ids = sorted({r["seed"] for r in pick})
            get = {(r["seed"], r["sampler"]): r for r in pick}
            ratio = {i: get[i, "uniform"]["relmse"] / get[i, "awr"]["relmse"] for i in ids}
            before = [get[i, "uniform"]["relmse_pilot_1.5"] / get[i, "awr"]["relmse_pilot_1.5"] for i in ids]
            moved = {k: [get[i, k]["relmse"] / get[i, k]["relmse_pilot_1.5"] for i in ids] for k in ("awr", "uniform")}
            lost = [str(i) for i in ids if ratio[i] <= 1] or ["none"]
            squared = [get[i, "uniform"]["mse"] / get[i, "awr"]["mse"] for i in ids]
            print(f"| {name} | {spp} | 0-{ids[-1]} | {min(ratio.values()):.2f} | {max(ratio.values()):.2f} | "
                  f"{np.mean(list(ratio.values())):.2f} | {', '.join(lost)} | {np.mean(before):.2f} | "
                  + " | ".join(f"{min(moved[k]):.2f}-{max(moved[k]):.2f}" for k in ("awr", "uniform"))
                  + f" | {np.mean(squared):.2f} ({min(squared):.2f}) |" + (_strict_cells(get, ids) if strict else ""))

    def against_measured(ids: list, ratios: Any) -> list[str]:
        lev, uni, sq = (ratios(over, "awr, measured gain", key)
                        for over, key in (("awr", "relmse"), ("uniform", "relmse"), ("awr", "mse")))
        return [_span(lev), _span(uni), _where(ids, uni), f"{np.mean(sq):.2f} ({min(sq):.2f})"]

    def against_levels(ids: list, ratios: Any) -> list[str]:
        lev, uni, sq = ratios("awr, levels", "awr"), ratios("uniform", "awr, levels"), ratios("awr, levels", "awr", "mse")
        won = ", ".join(str(i) for i, r in zip(ids, lev) if r < 1) or "none"  # levels' error below the default's
        return [_span(lev), won, _span(uni), _where(ids, uni), f"{np.mean(sq):.2f} ({min(sq):.2f})"]

    _seed_table(rows, "awr, measured gain", ("relMSE awr / measured gain, least-most (mean)",
                                             "uniform / measured gain, least-most (mean)", "seeds where uniform wins",
                                             "MSE awr / measured gain, mean (least)"), against_measured)
    _seed_table(rows, "awr, levels", ("relMSE levels / awr, least-most (mean)", "seeds where levels wins",
                                      "uniform / levels, least-most (mean)", "seeds where uniform beats levels",
                                      "MSE levels / awr, mean (least)"), against_levels)


def _strict_cells(get: dict, ids: list) -> str:
    """The seeds table's strict-guard columns: uniform over AWR with it, and the default over it per sampler."""
    ratio = [get[i, "uniform"]["relmse_strict_guard"] / get[i, "awr"]["relmse_strict_guard"] for i in ids]
    lost = ", ".join(str(i) for i, r in zip(ids, ratio) if r <= 1) or "none"
    moved = {k: [get[i, k]["relmse"] / get[i, k]["relmse_strict_guard"] for i in ids] for k in ("awr", "uniform")}
    return (f" {np.mean(ratio):.2f} ({lost}) | " + " | ".join(f"{min(moved[k]):.2f}-{max(moved[k]):.2f}"
                                                            for k in ("awr", "uniform")) + " |")


def _seed_table(rows: list[dict], kind: str, header: tuple[str, ...], cells: Any) -> None:
    """A per-seed table comparing sampler ``kind`` (none when the rows have no such run):
    ``cells(ids, ratios)`` gives the columns after scene, spp and seeds (:func:`_seed_ratios`)."""
    if not any(r["sampler"] == kind for r in rows):
        return
    print("\n| scene | spp | seeds | " + " | ".join(header) + " |")
    print("|---" * (3 + len(header)) + "|")
    for name, spp, ids, ratios in _seed_ratios(rows):
        print(f"| {name} | {spp} | 0-{ids[-1]} | " + " | ".join(cells(ids, ratios)) + " |")


def _seed_ratios(rows: list[dict]) -> Any:
    """Per scene and spp: the seeds and ``ratios(over, under, key="relmse")``, two samplers' errors seed by seed."""
    for name in dict.fromkeys(r["scene"] for r in rows):
        for spp in sorted({r["spp"] for r in rows if r["scene"] == name}):
            get = {(r["seed"], r["sampler"]): r for r in rows if r["scene"] == name and r["spp"] == spp}
            ids = sorted({i for i, _ in get})

            def ratios(over: str, under: str, key: str = "relmse", get: dict = get, ids: list = ids) -> list[float]:
                return [get[i, over][key] / get[i, under][key] for i in ids]

            yield name, spp, ids, ratios


def _span(values: list[float]) -> str:
    return f"{min(values):.2f}-{max(values):.2f} ({np.mean(values):.2f})"


def _where(ids: list, values: list[float]) -> str:
    """The seeds whose ratio is at most 1 (uniform's error over a sampler's: where uniform wins)."""
    return ", ".join(str(i) for i, r in zip(ids, values) if r <= 1) or "none"


# ---------------------------------------------------------------------------- synthetic
def synthetic(names: tuple[str, ...], spps: tuple[int, ...], seeds: int, shape: tuple[int, int],
              methods: dict[str, Any] = METHODS) -> list[dict]:
    """Known clean images: the plain mean, stage 1, the default (and ``methods``' others), seeds averaged, nested spp."""
    rows = []
    for name in names:
        scene = make_scene(name, shape)
        ref = scene.reference()
        for seed in range(seeds):
            renderer, buffer, done = SyntheticRenderer(scene, seed=seed), None, 0
            for spp in spps:
                part = renderer(SampleRequest.uniform(shape, spp - done, first_index=done))
                buffer = part if buffer is None else buffer.merge(part)
                done = spp
                for method, options in methods.items():
                    image = buffer.mean if options is None else reconstruct(buffer, **options)
                    rows.append({"scene": name, "shape": list(shape), "spp": spp, "seed": seed, "method": method,
                                 "relmse": relmse(image, ref), "mse": mse(image, ref)})
    return rows


def synthetic_table(rows: list[dict]) -> None:
    methods = [m for m in dict.fromkeys(r["method"] for r in rows) if m != "plain"]
    print("\n| scene | size | spp | relMSE plain | " + " | ".join(f"{m} / plain (relMSE, MSE)" for m in methods) + " |")
    print("|---|---|---|---|" + "---|" * len(methods))
    for name, shape in dict.fromkeys((r["scene"], tuple(r["shape"])) for r in rows):
        for spp in sorted({r["spp"] for r in rows if r["scene"] == name and tuple(r["shape"]) == shape}):
            w = {"scene": name, "spp": spp}
            same = [r for r in rows if tuple(r["shape"]) == shape]
            rel = {m: _mean(same, "relmse", method=m, **w) for m in ["plain", *methods]}
            sq = {m: _mean(same, "mse", method=m, **w) for m in ["plain", *methods]}
            print(f"| {name} | {shape[1]}x{shape[0]} | {spp} | {rel['plain']:.5f} | "
                  + " | ".join(f"{rel[m] / rel['plain']:.2f}, {sq[m] / sq['plain']:.2f}" for m in methods) + " |")


# ---------------------------------------------------------------------------- finishing
FINISHING_SHAPE = (128, 128)  # awr bench's size for the Mitsuba scenes, where one factor failed
FINISHING_SPPS = (4, 8, 16, 32, 64, 128)
FINISHING_SYNTHETIC_SPPS = (4, 16, 64, 256)


def _corrections(buffer: SampleBuffer) -> dict[str, np.ndarray]:
    """The default's output before its mean correction, then each correction of it."""
    prepared = prepare(buffer, "log")
    x, v = prepared.mean, prepared.variance
    image = reconstruct(buffer, preserve_mean=False)
    return {"plain": np.asarray(x), "none": image, "one factor": match_mean(image, x, v)[0],
            **{f"restore, share {share:g}" + (" (default)" if share == RESTORE_SHARE else ""):
               restore_mean(image, x, v, share=share)[0] for share in (0.05, 0.2)},
            "restore, no cap": restore_mean(image, x, v, share=np.inf)[0]}


def finishing(groups: int, cache: Path, mitsuba: bool) -> list[dict[str, Any]]:
    """Mean corrections on the Mitsuba scenes at 128x128 (``groups`` renders) and the synthetic fireflies."""
    rows = []
    cases = [("mitsuba", s) for s in MITSUBA_SCENES] if mitsuba else []
    cases.append(("synthetic", "fireflies"))
    for renderer, scene in cases:
        if renderer == "mitsuba":
            ref = reference(renderer, scene, FINISHING_SHAPE, cache / "s128")
            per_group = [uniform_buffers(renderer, scene, FINISHING_SHAPE, FINISHING_SPPS, g, cache, prefix="s128_")
                         for g in range(groups)]
        else:
            synthetic_scene = make_scene(scene, (96, 96))
            ref = synthetic_scene.reference()
            per_group = []
            for g in range(groups):
                r, buffer, done, nested = SyntheticRenderer(synthetic_scene, seed=g), None, 0, {}
                for spp in FINISHING_SYNTHETIC_SPPS:
                    part = r(SampleRequest.uniform((96, 96), spp - done, first_index=done))
                    buffer = part if buffer is None else buffer.merge(part)
                    nested[spp], done = buffer, spp
                per_group.append(nested)
        for g, buffers in enumerate(per_group):
            for spp, buffer in buffers.items():
                for name, image in _corrections(buffer).items():
                    rows.append({"renderer": renderer, "scene": scene, "spp": spp, "group": g, "method": name,
                                 "relmse": relmse(image, ref), "mse": mse(image, ref)})
        print(f"{renderer} {scene}: done", flush=True)
    return rows


EMPTY_SPPS = (8, 32)
EMPTY_LAYOUTS = ("20% scattered", "50% scattered", "70% scattered", "the right half")
"""``empty``: which pixels of a full render lose their samples (scattered: each pixel alone, at random)."""


def _emptied(buffer: SampleBuffer, layout: str, rng: np.random.Generator) -> tuple[SampleBuffer, np.ndarray]:
    """``buffer`` with the pixels of ``layout`` made sample-less, and the (H, W) mask of those still sampled."""
    if layout == "the right half":
        sampled = np.arange(buffer.shape[1])[None, :] < buffer.shape[1] // 2
        sampled = np.broadcast_to(sampled, buffer.shape)
    else:
        sampled = rng.random(buffer.shape) >= int(layout.split("%")[0]) / 100
    kept = sampled[..., None]
    return SampleBuffer.from_moments(np.where(sampled, buffer.count, 0), np.where(kept, buffer.mean, 0.0),
                                     np.where(kept, buffer.variance, 0.0)), sampled


def empty_pixels_counted(buffer: SampleBuffer) -> np.ndarray:
    """The default as it was before the guard left pixels without samples out of its risk: their filled means (a
    neighbour's) summed as measurements, with their one pooled sample's variance (``sure_blend(...,
    measured=None)``)."""
    def guard(*args: Any, measured: Any = None, **options: Any) -> Any:
        return sure_blend(*args, **options)
    with mock.patch.object(sys.modules["awr_denoise.reconstruct"], "sure_blend", guard):
        return reconstruct(buffer)


def empty_copied(buffer: SampleBuffer) -> np.ndarray:
    """The default on the buffer with every pixel without samples a copy of its nearest sampled neighbour, its
    per-sample variance (as estimated) and count included, instead of one sample of the pooled variance."""
    empty = buffer.count == 0
    if not empty.any():
        return reconstruct(buffer)
    _, (rows, cols) = ndimage.distance_transform_edt(empty, return_indices=True)
    return reconstruct(SampleBuffer.from_moments(buffer.count[rows, cols], buffer.mean[rows, cols],
                                                 buffer.estimated_variance()[rows, cols]))


def empty_pixels(scenes: list[tuple[str, str, tuple[int, int] | None]], spps: tuple[int, ...], groups: int,
                 cache: Path) -> list[dict[str, Any]]:
    """Every scene's uniform renders with pixels made sample-less (:data:`EMPTY_LAYOUTS`; the same pixels for
    every spp of a render): MSE and relMSE over the pixels still sampled and over all, and the image mean's
    change from the plain (filled) mean's, of the plain mean, the default, :func:`empty_pixels_counted` and
    :func:`empty_copied`."""
    rows = []
    for renderer, scene, shape in scenes:
        ref = reference(renderer, scene, shape, cache)
        for g in range(groups):
            for spp, full in uniform_buffers(renderer, scene, shape, spps, g, cache).items():
                for i, layout in enumerate(EMPTY_LAYOUTS):
                    buffer, sampled = _emptied(full, layout, np.random.default_rng([g, i]))
                    plain = prepare(buffer, "linear").mean
                    for method, image in (("plain", plain), ("default", reconstruct(buffer)),
                                          ("empty pixels counted", empty_pixels_counted(buffer)),
                                          ("empty pixels copied", empty_copied(buffer))):
                        rows.append({"renderer": renderer, "scene": scene, "spp": spp, "group": g, "layout": layout,
                                     "method": method, "mse_sampled": mse(image[sampled], ref[sampled]),
                                     "relmse_sampled": relmse(image[sampled], ref[sampled]),
                                     "mse": mse(image, ref), "relmse": relmse(image, ref),
                                     "mean_change": float(image.mean() / plain.mean() - 1)})
        print(f"{renderer} {scene}: done", flush=True)
    return rows


def empty_table(rows: list[dict]) -> None:
    """Per scene, spp and layout, over the renders: each method's errors over the plain mean's, on the sampled
    pixels and on all (the mean of the renders' ratios; the worst render's MSE ratio in brackets)."""
    methods = [m for m in dict.fromkeys(r["method"] for r in rows) if m != "plain"]
    heads = [f"{m}: {part}" for m in methods for part in ("sampled pixels, MSE, relMSE / plain (worst)",
                                                           "all pixels, MSE, relMSE / plain (worst)")]
    print("\n| renderer | scene | spp | pixels without samples | " + " | ".join(heads)
          + " | largest image-mean change |")
    print("|---|---|---|---|" + "---|" * (len(heads) + 1))
    for renderer, scene, spp, layout in dict.fromkeys((r["renderer"], r["scene"], r["spp"], r["layout"]) for r in rows):
        here = [r for r in rows if (r["renderer"], r["scene"], r["spp"], r["layout"]) == (renderer, scene, spp, layout)]
        plain = {r["group"]: r for r in here if r["method"] == "plain"}
        cells = []
        for m in methods:
            mine = [r for r in here if r["method"] == m]
            for part in ("_sampled", ""):
                a = np.array([(r[f"mse{part}"] / plain[r["group"]][f"mse{part}"],
                               r[f"relmse{part}"] / plain[r["group"]][f"relmse{part}"]) for r in mine])
                cells.append(f"{a[:, 0].mean():.2f}, {a[:, 1].mean():.2f} ({a[:, 0].max():.2f})")
        change = max(abs(r["mean_change"]) for r in here if r["method"] == "default")
        print(f"| {renderer} | {scene} | {spp} | {layout} | " + " | ".join(cells) + f" | {change:.2%} |")
    _empty_summary(rows, methods)


def _empty_summary(rows: list[dict], methods: list[str]) -> None:
    """The figures docs/reconstruction.md quotes from the table: per layout, the geometric mean over the cells of
    each method's cell (the mean of the renders' ratios to the plain mean's) and of each method's cell over the
    default's; the cells above the plain mean on average, and the single renders above it."""
    def ratios(where: tuple, method: str, key: str) -> list[float]:
        here = [r for r in rows if (r["renderer"], r["scene"], r["spp"], r["layout"]) == where]
        plain = {r["group"]: r[key] for r in here if r["method"] == "plain"}
        return [r[key] / plain[r["group"]] for r in here if r["method"] == method]

    cells = list(dict.fromkeys((r["renderer"], r["scene"], r["spp"], r["layout"]) for r in rows))
    print()
    for key, name in (("mse_sampled", "sampled pixels, MSE"), ("relmse_sampled", "sampled pixels, relMSE"),
                      ("mse", "all pixels, MSE"), ("relmse", "all pixels, relMSE")):
        for m in methods:
            mean = {c: float(np.mean(ratios(c, m, key))) for c in cells}
            per_layout = {layout: [c for c in cells if c[3] == layout] for layout in EMPTY_LAYOUTS}
            geo = {layout: float(np.exp(np.mean([np.log(mean[c]) for c in some])))
                   for layout, some in per_layout.items()}
            above = [mean[c] for c in cells if mean[c] > 1]
            renders = sum(ratio > 1 for c in cells for ratio in ratios(c, m, key))
            print(f"{name}, {m} / plain: " + ", ".join(f"{layout} {g:.2f}" for layout, g in geo.items())
                  + f"; largest {max(mean.values()):.3f}; {len(above)} of {len(cells)} cells above 1"
                  + (f" (by up to {max(above) - 1:.2%})" if above else "") + f", {renders} single renders")
            if m != "default":
                default = {c: float(np.mean(ratios(c, "default", key))) for c in cells}
                print(f"    {m} / default (the cells' ratio): " + ", ".join(
                    f"{layout} {np.exp(np.mean([np.log(mean[c] / default[c]) for c in some])):.2f}"
                    for layout, some in per_layout.items()))


def finishing_table(rows: list[dict]) -> None:
    methods = [m for m in dict.fromkeys(r["method"] for r in rows) if m != "plain"]
    print("\nMSE / plain mean's, mean over renders (worst render); relMSE / plain mean's, mean over renders\n")
    print("| scene | spp | " + " | ".join(methods) + " |")
    print("|---|---|" + "---|" * len(methods))
    for renderer, scene in dict.fromkeys((r["renderer"], r["scene"]) for r in rows):
        for spp in sorted({r["spp"] for r in rows if r["scene"] == scene}):
            cells = []
            for m in methods:
                ratios = []
                for g in sorted({r["group"] for r in rows if r["scene"] == scene}):
                    get = {r["method"]: r for r in rows if r["scene"] == scene and r["spp"] == spp and r["group"] == g}
                    ratios.append((get[m]["mse"] / get["plain"]["mse"], get[m]["relmse"] / get["plain"]["relmse"]))
                a = np.array(ratios)
                cells.append(f"{a[:, 0].mean():.3f} ({a[:, 0].max():.3f}); {a[:, 1].mean():.3f}")
            print(f"| {scene} | {spp} | " + " | ".join(cells) + " |")


# ---------------------------------------------------------------------------- speed
def speed(sizes: list[str], repeats: int, extra: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """Median seconds of every variant of :data:`SPEED_VARIANTS` (and the ``extra`` ones of :data:`SHIFTED`,
    :data:`SPUN`, :data:`COMPARED` and :data:`PROBES`)."""
    variants = {**SPEED_VARIANTS, **{name: {**COMPARED, **PROBES}.get(name, name) for name in extra}}
    rows = []
    print("| image | " + " | ".join(variants) + " |")
    print("|---|" + "---|" * len(variants))
    for size in sizes:
        shape = SIZES[size]
        n = repeats or (3 if size == "1080p" else 9)
        scene = make_scene("edges", shape)
        buffer = SyntheticRenderer(scene, seed=1)(SampleRequest.uniform(shape, 8))
        clean = scene.reference()
        seconds: dict[str, list[float]] = {name: [] for name in variants}
        names = list(variants)
        for round_ in range(n + 1):
            # Each round starts one variant later, as in agreed_speed: at 1080p the first call of a round can be
            # slower than the same call later in it (this machine's memory, not the code).
            for name in names[round_ % len(names):] + names[:round_ % len(names)]:
                options = variants[name]
                start = time.perf_counter()
                if isinstance(options, str) or callable(options):
                    (options if callable(options) else {**COMPARED, **CHEAPER, **SHIFTED, **SPUN}[options])(buffer)
                else:
                    reconstruct(buffer, **{k: (clean if v == "reference" else v) for k, v in options.items()})
                if round_:  # the first round builds and caches the transforms' operators
                    seconds[name].append(time.perf_counter() - start)
        medians = {k: float(np.median(v)) for k, v in seconds.items()}
        base = medians["stage 1 alone"]
        rows.append({"size": size, "repeats": n, "seconds": medians, "ratio": {k: v / base for k, v in medians.items()}})
        print(f"| {size} | " + " | ".join(f"{v:.3f} s ({v / base:.2f}x)" for v in medians.values()) + " |", flush=True)
    return rows


def agreed_buffers(shape: tuple[int, int]) -> dict[str, SampleBuffer]:
    """Buffers where many pixels' samples all agreed, for ``agreed``: black squares of 120 pixels (every sample
    0) beside noisy ones at 8 spp, as a tracer's scene before a black background; samples of 3 in 10% of
    draws, else exactly 0, at 2 spp (every pixel that missed beside one that hit); and those means and
    variances at counts of 2-39, as an adaptive run leaves them."""
    rng = np.random.default_rng(5)
    h, w = shape
    mean, variance = rng.random((h, w, 3)), 0.1 * rng.random((h, w, 3))
    black = (np.arange(h)[:, None] // 120 + np.arange(w)[None, :] // 120) % 2 == 0
    mean[black], variance[black] = 0.0, 0.0
    pixel = np.repeat(np.arange(h * w), 2)
    hits = (rng.random(pixel.size) < 0.1)[:, None] * np.full((1, 3), 3.0)
    hit_or_zero = SampleBuffer.from_samples(pixel, hits, shape)
    # The same hits and misses at the counts of an adaptive run: no count holds a sixteenth of the pixels, every
    # entry that missed takes the offset-by-offset path (the slowest the moderation gets).
    counts = rng.integers(2, 40, shape)
    return {"black squares, 8 spp": SampleBuffer.from_moments(np.full(shape, 8), mean, variance),
            "hit or zero, 2 spp": hit_or_zero,
            "hit or zero, 2-39 spp": SampleBuffer.from_moments(counts, hit_or_zero.mean, hit_or_zero.variance)}


def agreed_speed(sizes: list[str], repeats: int) -> list[dict[str, Any]]:
    """Median seconds of the moderation alone (``pooling.estimated_variance``), the default reconstruction and
    one ``AdaptiveSampler.ask()`` round (a sampler that has the buffer), each beside the same with agreeing
    samples held exact (``AGREED_PRIOR`` 0), interleaved, on :func:`agreed_buffers`; the moderation also with every
    entry gathered offset by offset (``pooling._SCATTER_SHARE`` infinite), the form before entries at 0 were weighed
    from the spread pixels outward; and, where numba is installed (extra ``fast``), the moderation and ``ask()`` with
    the moderation's compiled loop (``AWR_DENOISE_KERNELS=numba``, ``pooling._moderation_loop``); and the moderation
    and ``ask()`` with the masks as they were made before (:func:`_masks_as_before`) and with no light's rim looked
    for (:func:`_rims_lend`), each ratio this version's time over theirs."""
    rows = []
    compiled = "numba" in fused.available()
    print("| image | buffer | moderation alone | gathered only | ratio | default | held exact | ratio | ask() "
          "| held exact | ratio |" + (" moderation, compiled | ratio | ask(), compiled | ratio |" if compiled else "")
          + " moderation, masks as before | ratio | ask(), masks as before | ratio | moderation, rims lend | ratio "
          "| ask(), rims lend | ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|" + "---|" * 4 * compiled + "---|" * 8)
    for size in sizes:
        for kind, buffer in agreed_buffers(SIZES[size]).items():
            # Each case is set up untimed and returns the call that is timed: a sampler that has the buffer is
            # built anew before each ask() (asking again before tell() returns the same request).
            moderate = partial(pooling.estimated_variance, buffer.count, buffer.mean, buffer.variance,
                               buffer.variance_known)
            cases = {"moderation alone": lambda m=moderate: m,
                     "moderation, gathered only": lambda m=moderate: partial(_gathered_only, m),
                     "default": lambda b=buffer: partial(reconstruct, b),
                     "agreed samples held exact": lambda b=buffer: partial(agreed_held_exact, b),
                     "ask()": lambda b=buffer: AdaptiveSampler.from_buffer(b, round=1).ask,
                     "ask(), agreed samples held exact":
                         lambda b=buffer: partial(_held_exact, AdaptiveSampler.from_buffer(b, round=1).ask)}
            if compiled:
                cases["moderation, compiled"] = lambda m=moderate: partial(_compiled, m)
                cases["ask(), compiled"] = lambda b=buffer: partial(_compiled,
                                                                    AdaptiveSampler.from_buffer(b, round=1).ask)
            cases["moderation, masks as before"] = lambda m=moderate: partial(_masks_as_before, m)
            cases["ask(), masks as before"] = lambda b=buffer: partial(_masks_as_before,
                                                                       AdaptiveSampler.from_buffer(b, round=1).ask)
            cases["moderation, rims lend"] = lambda m=moderate: partial(_rims_lend, m)
            cases["ask(), rims lend"] = lambda b=buffer: partial(_rims_lend,
                                                                 AdaptiveSampler.from_buffer(b, round=1).ask)
            seconds: dict[str, list[float]] = {name: [] for name in cases}
            names = list(cases)
            for round_ in range(1 + (repeats or (3 if size == "1080p" else 9))):
                # Each round starts one case later: at 1080p the case that came first in every round was measured
                # several times slower than the same call later in the round (this machine's memory, not the code).
                for name in names[round_ % len(names):] + names[:round_ % len(names)]:
                    run = cases[name]()
                    start = time.perf_counter()
                    run()
                    if round_:  # the first round builds and caches the transforms' operators
                        seconds[name].append(time.perf_counter() - start)
            medians = {k: float(np.median(v)) for k, v in seconds.items()}
            rows.append({"size": size, "buffer": kind, "repeats": len(seconds["default"]), "seconds": medians})
            m = list(medians.values())
            print(f"| {size} | {kind} | {m[0]:.3f} s | {m[1]:.3f} s | {m[0] / m[1]:.2f} | {m[2]:.3f} s | {m[3]:.3f} s "
                  f"| {m[2] / m[3]:.2f} | {m[4]:.3f} s | {m[5]:.3f} s | {m[4] / m[5]:.2f} |"
                  + (f" {m[6]:.3f} s | {m[6] / m[0]:.2f} | {m[7]:.3f} s | {m[7] / m[4]:.2f} |" if compiled else "")
                  + f" {m[-4]:.3f} s | {m[0] / m[-4]:.2f} | {m[-3]:.3f} s | {m[4] / m[-3]:.2f} |"
                  + f" {m[-2]:.3f} s | {m[0] / m[-2]:.2f} | {m[-1]:.3f} s | {m[4] / m[-1]:.2f} |", flush=True)
    return rows


def _gathered_only(run: Any) -> Any:
    """``run()`` with every entry of the moderation gathered offset by offset (``pooling._SCATTER_SHARE`` infinite)."""
    with mock.patch.object(pooling, "_SCATTER_SHARE", math.inf):
        return run()


def _compiled(run: Any) -> Any:
    """``run()`` with the compiled kernels (``fused.using("numba")``)."""
    with fused.using("numba"):
        return run()


def _masks_as_before(run: Any) -> Any:
    """``run()`` with the moderation's whole-image masks made as before commit 683014f: scipy's maximum filter for
    the spread neighbours, numpy's broadcast over the channels for the known pixels, ``np.nonzero`` of the 3-D mask
    (the same results)."""
    size = (pooling.POOL_WINDOW, pooling.POOL_WINDOW, 1)
    with mock.patch.object(pooling, "_near", lambda mask: ndimage.maximum_filter(mask, size=size, mode="nearest")), \
            mock.patch.object(pooling, "_in_pixels", lambda plane, pixels: plane & pixels[..., None]), \
            mock.patch.object(pooling, "_nonzero", np.nonzero):
        return run()


def _rims_lend(run: Any) -> Any:
    """``run()`` as before a light's rim stopped lending its spread: no pixel is a rim (``rims.EDGE_BLOCK`` out of
    reach), so no rim is looked for past the test for two agreeing levels."""
    with mock.patch.object(rims, "EDGE_BLOCK", sys.maxsize):
        return run()


def _held_exact(run: Any) -> Any:
    """``run()`` with ``pooling.AGREED_PRIOR`` at 0, put back afterwards."""
    with mock.patch.object(pooling, "AGREED_PRIOR", 0.0):
        return run()


# ---------------------------------------------------------------------------- main
def recorded_command(script: str, argv: list[str] | None, args: argparse.Namespace | None = None) -> str:
    """The command a results section records; the cache folder and a trial's output (this machine's business)
    as ``DIR`` and ``FILE``: after their options' names, and, given the parsed ``args``, wherever their values
    are written (``--cache=X``, an abbreviated ``--cach X``, which argparse takes too)."""
    given = list(argv if argv is not None else sys.argv[1:])
    hidden = {"--cache": "DIR", "--images": "DIR", "--output": "FILE"}
    values = {str(Path(getattr(args, name[2:]))): word for name, word in hidden.items()
              if args is not None and getattr(args, name[2:], None) is not None}  # as written or as parsed
    shown: list[str] = []
    for i, a in enumerate(given):
        option, equals, value = a.partition("=")
        if i > 0 and given[i - 1] in hidden:
            shown.append(hidden[given[i - 1]])
        elif a and str(Path(a)) in values and i > 0 and given[i - 1].startswith("--"):
            shown.append(values[str(Path(a))])
        elif equals and option.startswith("--") and (option in hidden or (value and str(Path(value)) in values)):
            shown.append(f"{option}={hidden.get(option) or values[str(Path(value))]}")
        else:
            shown.append(a)
    return f"benchmarks/{script} " + " ".join(shown)


def check_scenes(parser: argparse.ArgumentParser, names: list[str] | None, known: tuple[str, ...]) -> None:
    """Refuse (exit 2, one line) a ``--scenes`` name the section does not know, and a Mitsuba scene Mitsuba 3
    cannot render here: such a name was dropped, and a section of none measured nothing."""
    unknown = [n for n in names or () if n not in known]
    if unknown:
        parser.error(f"--scenes: {', '.join(unknown)} not among {', '.join(known)}")
    if any(n in MITSUBA_SCENES for n in names or ()) and not _mitsuba_available():
        parser.error("--scenes: Mitsuba 3 cannot run here (the extra 'mitsuba'), so its scenes cannot be measured")


def quality_scenes(names: list[str] | None) -> list[tuple[str, str, tuple[int, int] | None]]:
    """(renderer, scene, shape) of the named scenes (default: all); Mitsuba's only when it can run here."""
    names = names or list(TRACER_SCENES) + list(MITSUBA_SCENES)
    scenes: list[tuple[str, str, tuple[int, int] | None]] = [("tracer", s, None) for s in names if s in TRACER_SCENES]
    if any(s in MITSUBA_SCENES for s in names) and _mitsuba_available():
        scenes += [("mitsuba", s, MITSUBA_SHAPE) for s in names if s in MITSUBA_SCENES]
    return scenes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("section", choices=("quality", "samplers", "refresh", "seeds", "synthetic", "speed",
                                            "agreed", "finishing", "empty", "tables"))
    parser.add_argument("--scenes", nargs="+", help="scenes (default: every bundled tracer and Mitsuba scene)")
    parser.add_argument("--spps", nargs="+", type=whole_option(minimum=1, maximum=MAX_SPP), default=list(SPPS))
    parser.add_argument("--groups", type=whole_option(minimum=0), default=0,
                        help="renders per scene (default 4; finishing: 12; samplers: seeds, 2; empty: 2)")
    parser.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "awr-denoise" / "reconstruct",
                        help="where rendered buffers and Mitsuba references are kept (default %(default)s)")
    parser.add_argument("--sizes", nargs="+", choices=tuple(SIZES), default=list(SIZES))
    parser.add_argument("--repeats", type=whole_option(minimum=0), default=0,
                        help="speed: rounds per size (default 9, 3 at 1080p)")
    parser.add_argument("--cheaper", action="store_true", help="quality: also the cheaper variants (CHEAPER)")
    parser.add_argument("--spun", action="store_true",
                        help="quality, speed: also the first Wiener stage's pilot cycle-spun over 2 and 4 shifts "
                             "(SPUN)")
    parser.add_argument("--shifts", action="store_true",
                        help="quality, speed: also the Wiener stages on the decimated transform, cycle-spun (SHIFTED)")
    parser.add_argument("--compare", action="store_true",
                        help="quality and speed: also earlier forms of the default (COMPARED)")
    parser.add_argument("--floors", action="store_true", help="quality: also other energy floors (FLOORS)")
    parser.add_argument("--pilots", action="store_true", help="quality: also other pilot thresholds (PILOTS)")
    parser.add_argument("--priors", action="store_true", help="quality: also other agreed-sample priors (PRIORS)")
    parser.add_argument("--moderated", action="store_true",
                        help="quality: also every variance moderated towards its neighbours' (moderated_variances.py)")
    parser.add_argument("--chances", action="store_true",
                        help="quality: also other least chances for the clamp's neighbours (CHANCES)")
    parser.add_argument("--rims", action="store_true",
                        help="quality: also the default before a light's rim stopped lending its spread (RIMS)")
    parser.add_argument("--caps", action="store_true", help="samplers: also other absolute_above values (CAPS)")
    parser.add_argument("--initials", action="store_true", help="samplers: also other initial_spp values (INITIALS)")
    parser.add_argument("--windows", action="store_true", help="quality, synthetic: also other guard windows (WINDOWS)")
    parser.add_argument("--probes", action="store_true",
                        help="quality, synthetic, speed: also the guard with its divergence probed (PROBES)")
    parser.add_argument("--output", type=results_file, default=RESULTS,
                        help="results file whose section this run replaces, and that 'tables' prints "
                             "(default benchmarks/results/reconstruct.json; another file keeps a partial run "
                             "from replacing the stored section)")
    args = parser.parse_args(argv)
    check_scenes(parser, args.scenes,
                 tuple(list_scenes()) if args.section == "seeds" else TRACER_SCENES + MITSUBA_SCENES)
    command = recorded_command("bench_reconstruct.py", argv, args)
    if args.section == "quality":
        rows = quality(quality_scenes(args.scenes), tuple(args.spps), args.groups or 4, args.cache,
                       {**METHODS, **(CHEAPER if args.cheaper else {}), **(SHIFTED if args.shifts else {}),
                        **(SPUN if args.spun else {}),
                        **(COMPARED if args.compare else {}),
                        **(FLOORS if args.floors else {}), **(PILOTS if args.pilots else {}),
                        **(PRIORS if args.priors else {}), **(MODERATED if args.moderated else {}),
                        **(CHANCES if args.chances else {}), **(RIMS if args.rims else {}),
                        **(WINDOWS if args.windows else {}), **(PROBES if args.probes else {})})
        update_section(args.output, "quality", rows, command)
        quality_tables(rows)
    elif args.section == "samplers":
        rows = samplers(quality_scenes(args.scenes), tuple(s for s in args.spps if s <= 32) or (8, 16, 32),
                        args.groups or 2, args.cache, {**SAMPLER_KINDS, **(cap_kinds(CAPS) if args.caps else {}),
                                                       **(initial_kinds(INITIALS) if args.initials else {})})
        update_section(args.output, "samplers", rows, command)
        sampler_table(rows)
    elif args.section == "refresh":
        rows = samplers(quality_scenes(args.scenes), tuple(s for s in args.spps if s <= 32) or (8, 16, 32),
                        args.groups or 2, args.cache, REFRESH_KINDS)
        update_section(args.output, "refresh", rows, command)
        refresh_table(rows)
    elif args.section == "seeds":
        rows = seeds(tuple(args.scenes or SEED_SCENES), tuple(s for s in args.spps if s <= 64) or (8, 16, 32, 64),
                     args.groups or 10)
        update_section(args.output, "seeds", rows, command)
        seeds_table(rows)
    elif args.section == "synthetic":
        methods = {**METHODS, **(WINDOWS if args.windows else {}), **(PROBES if args.probes else {})}
        rows = synthetic(("gradient", "edges", "hdr_source", "fireflies", "rare_light"), (4, 16, 64, 256, 1024), 2,
                         (96, 96), methods)
        rows += synthetic(("hdr_source",), (8, 16, 32, 64, 128), 12, (64, 64), methods)
        update_section(args.output, "synthetic", rows, command)
        synthetic_table(rows)
    elif args.section == "speed":
        rows = speed(args.sizes, args.repeats, (*(SHIFTED if args.shifts else ()), *(SPUN if args.spun else ()),
                                                *(COMPARED if args.compare else ()),
                                                *(PROBES if args.probes else ())))
        update_section(args.output, "speed", rows, command)
    elif args.section == "agreed":
        rows = agreed_speed(args.sizes, args.repeats)
        update_section(args.output, "agreed", rows, command)
    elif args.section == "finishing":
        rows = finishing(args.groups or 12, args.cache, _mitsuba_available())
        update_section(args.output, "finishing", rows, command)
        finishing_table(rows)
    elif args.section == "empty":
        spps = EMPTY_SPPS if args.spps == list(SPPS) else tuple(args.spps)  # 8 and 32 unless given
        rows = empty_pixels(quality_scenes(args.scenes), spps, args.groups or 2, args.cache)
        update_section(args.output, "empty", rows, command)
        empty_table(rows)
    else:  # print the tables of the stored results
        data = json.loads(args.output.read_text())
        for section, show in (("quality", quality_tables), ("samplers", sampler_table), ("refresh", refresh_table),
                              ("seeds", seeds_table),
                              ("synthetic", synthetic_table),
                              ("finishing", finishing_table), ("empty", empty_table)):
            if section in data:
                print(f"\n## {section} ({data[section]['command']})")
                show(data[section]["rows"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
