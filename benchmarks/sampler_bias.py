"""AWR sampling's own image mean: the bias a pixel's own samples make when they rank it, and what removing it costs.

Run from the repository root::

    .venv/bin/python benchmarks/sampler_bias.py                     # about 15 minutes
    .venv/bin/python benchmarks/sampler_bias.py --report            # the tables of the stored results
    .venv/bin/python benchmarks/sampler_bias.py --routes            # what is left: each route taken out, 8 spp
    .venv/bin/python benchmarks/sampler_bias.py --rare-paths        # Mitsuba's scenes lit through rare paths
    .venv/bin/python benchmarks/sampler_bias.py --rare-paths --bundled   # the same variants on the bundled scenes
    .venv/bin/python benchmarks/sampler_bias.py --rare-paths --renderers synthetic   # and on synthetic fireflies

Ranked by statistics its own samples are part of, a pixel whose first samples caught a bright path ranks high,
takes more samples and is diluted back towards its mean; one whose first samples missed it ranks low and keeps
its low mean: on heavy-tailed scenes the AWR buffer's image mean came out low. ``AdaptiveSampler`` therefore ranks
each pixel by its 8 neighbours' relative error, its own left out (``awr_denoise.priorities.pooled_deviation``;
docs/sampling.md, "The pixel's own samples"). This script measures the buffer's plain image mean against the
reference, its mean over the runs (the bias) and its root mean square (what one render is off by), beside the
default reconstruction's relMSE and MSE, on both renderers (the bundled tracer's six scenes at 128x128, Mitsuba
3's four at 256x256, the cached references of ``awr bench`` and ``bench_mitsuba.py``), for the default sampler
and variants:

- ``own pixel ranked``: the previous default, every term pooled over 3x3 pixels with the pixel's own samples
  (:func:`own_pixel_ranked` swaps it in for the run);
- ``uniform share 0.3``: the public ``uniform_fraction=0.3`` beside the default;
- ``own pixel ranked, uniform share 0.3``: the remedy measured before the default changed.

Uniform sampling's plain mean (the adapter's or the tracer's uniform request, the same seeds) is the unbiased
baseline beside them. Results: ``benchmarks/results/sampler_bias.json``.

``--routes`` measures, in the same way, what is left of the bias: through which of the ranking's terms a pixel's own
samples still reach its next ones (:data:`ROUTES`; ``benchmarks/results/sampler_bias_routes.json``).

``--rare-paths`` runs Mitsuba's scenes lit through rare paths (``mitsuba_scenes.HEAVY_TAILED_SCENES``: most samples
exactly 0), where the bias was largest, with :data:`RARE_PATH_VARIANTS` and uniform sampling's reconstruction beside
them, and reports every figure as it is, not over the default's (``benchmarks/results/sampler_bias_rare_paths.json``);
with ``--bundled``, the same variants on the bundled scenes of ``--renderers`` instead
(``benchmarks/results/sampler_bias_rare_paths_bundled.json``): what evening rare paths does where there are few.
``--renderers synthetic`` runs :data:`SYNTHETIC_SCENES` (with ``--rare-paths`` only; alone, into
``benchmarks/results/sampler_bias_rare_paths_synthetic.json``): rare samples on a lit base (fireflies), which only
the second test of the detector of rare paths takes for them.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

import awr_denoise.priorities as priorities
from awr_denoise import AdaptiveSampler, SampleRequest, reconstruct
from awr_denoise.adapters.mitsuba_scenes import HEAVY_TAILED_SCENES, SCENE_NAMES
from awr_denoise.bench.records import results_file
from awr_denoise.io.atomic import atomic_write
from awr_denoise.metrics import mse, relmse
from awr_denoise.prepare import prepare

REPOSITORY = Path(__file__).resolve().parent.parent
RESULTS = REPOSITORY / "benchmarks" / "results" / "sampler_bias.json"
ROUTES_RESULTS = REPOSITORY / "benchmarks" / "results" / "sampler_bias_routes.json"
RARE_PATHS_RESULTS = REPOSITORY / "benchmarks" / "results" / "sampler_bias_rare_paths.json"
RARE_PATHS_BUNDLED_RESULTS = REPOSITORY / "benchmarks" / "results" / "sampler_bias_rare_paths_bundled.json"
RARE_PATHS_SYNTHETIC_RESULTS = REPOSITORY / "benchmarks" / "results" / "sampler_bias_rare_paths_synthetic.json"
TRACER_SCENES = ("default", "chess_dof", "rolling_balls", "sky_objects", "soft_shadows", "cornell_gi")
MITSUBA_SCENES = SCENE_NAMES  # the adapter's bundled scenes; importing their names needs no Mitsuba
RARE_PATH_SCENES = HEAVY_TAILED_SCENES
SYNTHETIC_SCENES = ("fireflies", "rare_light")  # awr_denoise.synthetic's heavy-tailed scenes, at 64x64
VARIANTS: dict[str, dict[str, Any]] = {
    "default": {},
    "own pixel ranked": {"own_pixel": True},
    "uniform share 0.3": {"uniform_fraction": 0.3},
    "own pixel ranked, uniform share 0.3": {"own_pixel": True, "uniform_fraction": 0.3},
}
ROUTES: dict[str, dict[str, Any]] = {
    "default": {},
    # the capped absolute term pools the pixel's own samples (3x3); the shrinkage gain's coefficients hold its mean
    "no absolute term": {"absolute_above": None},
    "neighbours + absolute term": {"noise_model": "levels", "level_weight": 0.0},  # no gain
    "neighbours only": {"noise_model": "levels", "level_weight": 0.0, "absolute_above": None},  # neither
}
"""The routes through which a pixel's own samples still rank it, taken out one at a time and together: with
neither, each pixel is ranked by its 8 neighbours' relative error alone, which its own samples never reach."""
RARE_PATH_VARIANTS: dict[str, dict[str, Any]] = {
    "default": {},
    "fireflies ranked": {"rare_paths": "zeros"},
    "rare paths ranked": {"rare_paths": "ranked"},
    "rare paths ranked, uniform share 0.3": {"rare_paths": "ranked", "uniform_fraction": 0.3},
}
"""What ``--rare-paths`` runs beside uniform sampling: the default (rare-path regions evened,
``awr_denoise.rare_paths``), the default before fireflies on a lit base were evened too (``rare_paths="zeros"``),
the form before that which ranks every pixel, and that with the public uniform share."""
_FINITE_TOP = float(np.finfo(np.float64).max) / 16


def _pooled_with_own_pixel(buffer: Any, domain: Any = "log", *, absolute_above: float | None = 6.0,
                           prepared: Any = None) -> np.ndarray:
    """``pooled_deviation`` before the pixel's own samples were left out: both terms pooled over 3x3 pixels."""
    p = prepare(buffer, domain, luminance=True) if prepared is None else prepared
    s2 = p.sample_variance_y
    if absolute_above is not None:
        level = absolute_above * p.domain.resolved_scale(p.mean)
        if level > 0 and np.isfinite(level):
            with np.errstate(over="ignore"):
                s2 = np.minimum(s2 + p.sample_variance / level / level, _FINITE_TOP)
    return np.sqrt(np.maximum(ndimage.uniform_filter(s2, 3, mode="nearest"), 0.0))


@contextlib.contextmanager
def own_pixel_ranked(enabled: bool = True) -> Iterator[None]:
    """The samplers' deviation as it was before this version (:func:`_pooled_with_own_pixel`) for the block."""
    saved = priorities.pooled_deviation
    if enabled:
        priorities.pooled_deviation = _pooled_with_own_pixel
    try:
        yield
    finally:
        priorities.pooled_deviation = saved


def _tracer_cases() -> Iterator[tuple[str, Any, np.ndarray]]:
    """(scene, renderer by seed, reference) for the bundled tracer's scenes at their size (``awr bench``'s)."""
    from awr_denoise.bench.config import BenchmarkConfig
    from awr_denoise.bench.rendering import make_tracer, reference_image, tracer_module

    config = BenchmarkConfig()
    for name in TRACER_SCENES:
        scene = tracer_module().load_scene(name, width=config.width, height=config.height)
        reference, _ = reference_image(name, scene, config)
        @contextlib.contextmanager
        def factory(seed: int, scene: Any = scene) -> Iterator[Any]:
            renderer = make_tracer(scene, seed, config.threads)
            try:
                yield renderer
            finally:
                renderer.close()

        yield name, factory, reference


def _mitsuba_cases(names: tuple[str, ...] = MITSUBA_SCENES) -> Iterator[tuple[str, Any, np.ndarray]]:
    """The same for Mitsuba 3's scenes at 256x256, through the adapter, against ``bench_mitsuba.py``'s references."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_mitsuba  # noqa: E402 (the reference cache and its keys)
    from awr_denoise.adapters.mitsuba import MitsubaRenderer

    for name in names:
        renderer = MitsubaRenderer(name, shape=(256, 256), seed=0)
        ref = bench_mitsuba.reference(renderer, name, 2048, cache=REPOSITORY / "benchmarks" / "cache" / "mitsuba",
                                      regenerate=False)

        @contextlib.contextmanager
        def factory(seed: int, renderer: Any = renderer) -> Iterator[Any]:
            renderer.seed = seed  # one scene load for every run: the adapter is closed after the scene's last
            yield renderer

        try:
            yield name, factory, ref["mean"]
        finally:
            renderer.close()


def _synthetic_cases() -> Iterator[tuple[str, Any, np.ndarray]]:
    """The same for the synthetic heavy-tailed scenes (:data:`SYNTHETIC_SCENES`) at 64x64, against their clean
    images."""
    from awr_denoise.synthetic import SyntheticRenderer, make_scene

    for name in SYNTHETIC_SCENES:
        scene = make_scene(name, (64, 64))

        @contextlib.contextmanager
        def factory(seed: int, scene: Any = scene) -> Iterator[Any]:
            yield SyntheticRenderer(scene, seed=seed)

        yield name, factory, scene.reference()


def measure(name: str, factory: Any, reference: np.ndarray, spps: list[int], seeds: list[int],
            variants: dict[str, dict[str, Any]] | None = None, *, reconstruct_uniform: bool = False) -> dict[str, Any]:
    """Every variant (default :data:`VARIANTS`) and uniform sampling at each spp over ``seeds``: image-mean
    errors, relMSE, MSE, and how far the reconstruction moved the image mean from its buffer's (means). With
    ``reconstruct_uniform``, also uniform sampling's default reconstruction (``uniform, reconstructed``)."""
    ref_mean = float(reference.mean())
    shape = reference.shape[:2]
    out: dict[str, Any] = {"scene": name, "reference_image_mean": ref_mean, "spp": {}}
    for spp in spps:
        rows: dict[str, list[tuple[float, float, float, float]]] = {"uniform": []}
        for seed in seeds:
            with factory(seed) as renderer:
                buffer = renderer(SampleRequest.uniform(shape, spp))
            plain = np.asarray(buffer.mean)
            rows["uniform"].append((plain.mean() / ref_mean - 1, relmse(plain, reference), mse(plain, reference), 0.0))
            if reconstruct_uniform:
                image = reconstruct(buffer)
                rows.setdefault("uniform, reconstructed", []).append(
                    (float(image.mean()) / ref_mean - 1, relmse(image, reference), mse(image, reference),
                     _change(image, plain)))
        for label, options in (VARIANTS if variants is None else variants).items():
            options = dict(options)
            own = options.pop("own_pixel", False)
            rows[label] = []
            for seed in seeds:
                with factory(seed) as renderer, own_pixel_ranked(own):
                    buffer = AdaptiveSampler(shape, seed=seed, **options).run(renderer, total_spp=spp)
                image, plain = reconstruct(buffer), np.asarray(buffer.mean)
                rows[label].append((float(plain.mean()) / ref_mean - 1, relmse(image, reference),
                                    mse(image, reference), _change(image, plain)))
        out["spp"][str(spp)] = {label: {"image_mean_error": float(np.mean([r[0] for r in runs])),
                                        "image_mean_error_sd": float(np.std([r[0] for r in runs], ddof=1)
                                                                     / np.sqrt(len(runs))),
                                        "relmse": float(np.mean([r[1] for r in runs])),
                                        "mse": float(np.mean([r[2] for r in runs])),
                                        "reconstruction_mean_change": float(np.mean([r[3] for r in runs]))}
                                for label, runs in rows.items()}
        print(f"[{name}] {spp} spp: " + ", ".join(
            f"{label} {100 * v['image_mean_error']:+.2f}%" for label, v in out["spp"][str(spp)].items()), flush=True)
    return out


def _change(image: np.ndarray, plain: np.ndarray) -> float:
    """How far the reconstruction moved the image mean from its buffer's (relative; 0 for a black buffer kept
    black, and the absolute change for one that is not)."""
    before, after = float(plain.mean()), float(image.mean())
    return after / before - 1 if before else after


def rms_error(values: dict[str, float], runs: int) -> float:
    """Root mean square over the runs of the image-mean error, from their mean and its standard error."""
    return math.sqrt(values["image_mean_error"] ** 2 + (runs - 1) * values["image_mean_error_sd"] ** 2)


def table(results: dict[str, Any]) -> str:
    """Markdown: per scene and spp, the image mean's error, mean over the runs (its bias) and root mean square
    (what one render is off by), for uniform sampling's plain mean and each variant's AWR buffer; then each
    variant's relMSE and MSE over the default's."""
    labels = list(results.get("variants", VARIANTS))
    runs = len(results["seeds"])
    head = ("| renderer | scene | spp | image mean, bias: uniform / " + " / ".join(labels)
            + " | image mean, root mean square: uniform / " + " / ".join(labels)
            + " | relMSE over the default's: " + " / ".join(labels[1:])
            + " | MSE over the default's: " + " / ".join(labels[1:]) + " |")
    lines = [head, "|---" * 7 + "|"]
    for renderer, scenes in results["renderers"].items():
        for row in scenes:
            for spp, v in row["spp"].items():
                d = v["default"]
                lines.append(
                    f"| {renderer} | {row['scene']} | {spp} | "
                    + " / ".join(f"{100 * v[k]['image_mean_error']:+.2f}%" for k in ["uniform", *labels]) + " | "
                    + " / ".join(f"{100 * rms_error(v[k], runs):.2f}%" for k in ["uniform", *labels]) + " | "
                    + " / ".join(f"{v[k]['relmse'] / d['relmse']:.2f}" for k in labels[1:]) + " | "
                    + " / ".join(f"{v[k]['mse'] / d['mse']:.2f}" for k in labels[1:]) + " |")
    return "\n".join(lines)


def rare_table(results: dict[str, Any]) -> str:
    """Markdown for ``--rare-paths``: per scene and spp, each method's image-mean error (mean over the runs, with its
    standard error: the buffer's plain mean for the AWR rows), its relMSE and MSE as they are (the AWR rows
    reconstructed by default), and how far the reconstruction moved the image mean from its input's."""
    labels = ["uniform", "uniform, reconstructed", *results["variants"]]
    lines = ["| renderer | scene | spp | method | image mean error (standard error) | relMSE | MSE "
             "| reconstruction's image mean over its input's |", "|---" * 8 + "|"]
    for renderer, scenes in results["renderers"].items():
        for row in scenes:
            for spp, v in row["spp"].items():
                for k in labels:
                    what = k if k.startswith("uniform,") or k == "uniform" else f"AWR sampling, {k}"
                    lines.append(f"| {renderer} | {row['scene']} | {spp} | {what} | "
                                 f"{100 * v[k]['image_mean_error']:+.2f}% ({100 * v[k]['image_mean_error_sd']:.2f}%) | "
                                 f"{v[k]['relmse']:.4g} | {v[k]['mse']:.4g} | "
                                 + ("" if k == "uniform" else f"{100 * v[k]['reconstruction_mean_change']:+.2f}%")
                                 + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, nargs="+", help="sample counts (default 8 32; 8 with --routes)")
    parser.add_argument("--seeds", type=int, default=10, help="render seeds 0..N-1 (default 10)")
    parser.add_argument("--renderers", nargs="+", choices=("tracer", "mitsuba", "synthetic"),
                        help="default tracer mitsuba (mitsuba with --rare-paths); synthetic, with --rare-paths only: "
                             "awr_denoise.synthetic's heavy-tailed scenes (SYNTHETIC_SCENES) at 64x64")
    parser.add_argument("--output", type=results_file, default=RESULTS)
    parser.add_argument("--report", action="store_true", help="print the tables of --output and render nothing")
    parser.add_argument("--routes", action="store_true",
                        help="the routes of what bias is left (ROUTES) instead of VARIANTS; default --spp 8, "
                             "--output benchmarks/results/sampler_bias_routes.json")
    parser.add_argument("--rare-paths", action="store_true",
                        help="Mitsuba's scenes lit through rare paths (RARE_PATH_SCENES) with RARE_PATH_VARIANTS and "
                             "uniform sampling reconstructed; --output benchmarks/results/sampler_bias_rare_paths.json")
    parser.add_argument("--bundled", action="store_true",
                        help="with --rare-paths: the bundled scenes of --renderers instead of the rare-path scenes; "
                             "--output benchmarks/results/sampler_bias_rare_paths_bundled.json")
    args = parser.parse_args(argv)
    if args.routes and args.rare_paths:
        parser.error("--routes and --rare-paths: give one")
    if args.bundled and not args.rare_paths:
        parser.error("--bundled: only with --rare-paths")
    variants = ROUTES if args.routes else RARE_PATH_VARIANTS if args.rare_paths else VARIANTS
    if args.renderers is None:
        args.renderers = ["mitsuba"] if args.rare_paths and not args.bundled else ["tracer", "mitsuba"]
    if args.output == RESULTS and (args.routes or args.rare_paths):
        args.output = (ROUTES_RESULTS if args.routes else RARE_PATHS_BUNDLED_RESULTS if args.bundled
                       else RARE_PATHS_SYNTHETIC_RESULTS if args.renderers == ["synthetic"] else RARE_PATHS_RESULTS)
    if "synthetic" in args.renderers and not args.rare_paths:
        parser.error("--renderers synthetic: only with --rare-paths")
    if "tracer" in args.renderers and args.rare_paths and not args.bundled:
        parser.error("--renderers tracer: the tracer has no rare-path scenes; with --rare-paths, give --bundled")
    args.spp = args.spp or ([8] if args.routes else [8, 32])
    report = rare_table if args.rare_paths else table
    if args.report:
        print(report(json.loads(args.output.read_text())))
        return 0
    if args.seeds < 2 or min(args.spp) < 4:
        parser.error("--seeds needs 2 or more (a spread), --spp 4 or more (AWR's first round is 2)")
    seeds = list(range(args.seeds))
    start = time.perf_counter()
    results: dict[str, Any] = {"command": " ".join(["benchmarks/sampler_bias.py", *(argv or sys.argv[1:])]),
                               "seeds": seeds, "variants": variants, "renderers": {}}
    for renderer in args.renderers:
        cases = (_tracer_cases() if renderer == "tracer" else _synthetic_cases() if renderer == "synthetic"
                 else _mitsuba_cases(RARE_PATH_SCENES if args.rare_paths and not args.bundled else MITSUBA_SCENES))
        results["renderers"][renderer] = [measure(name, factory, reference, args.spp, seeds, variants,
                                                  reconstruct_uniform=args.rare_paths)
                                          for name, factory, reference in cases]
    results["seconds"] = time.perf_counter() - start
    args.output.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(results, indent=1) + "\n"
    atomic_write(args.output, lambda temporary: Path(temporary).write_text(text), overwrite=True)  # whole or none
    print(report(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
