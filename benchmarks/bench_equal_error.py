"""Equal-error spp of AWR sampling at 32 spp over render seeds (docs/benchmarks.md, "Reading the results").

Run from the repository root::

    .venv/bin/python benchmarks/bench_equal_error.py [--scenes NAME ...] [--seeds N ...]
    .venv/bin/python benchmarks/bench_equal_error.py --variants   # after the run above: options around the defaults

(``--size``, ``--uniform-max-spp`` and ``--output`` make a smaller trial run, as the script's test does.)

``awr bench`` measures the equal-error spp on render seed 0 alone: every method there shares that seed's
random numbers, so method differences are not seed noise, but the figure itself is one draw. This script
renders each scene again with other seeds, each seed with its own uniform Monte Carlo curve (4-1024 spp, the
same progressive render as ``awr bench``) and its own fit of the reference's noise floor, so each equal-error
spp is computed as ``awr bench`` computes it. Beside the default sampler: the relative error alone
(``absolute_above=None``, docs/sampling.md, "Relative and absolute error"), whose relMSE is lower where a
small bright light holds the squared error and whose MSE is higher there. Results:
``benchmarks/results/equal_error.json``.

``--variants`` asks whether the defaults stand at the optimum over seeds, not on seed 0 alone: on every scene and
seed of the stored run it renders the default sampler's 32 spp again (the stored figure is checked), then
reconstructs those samples with the public options of :data:`RECONSTRUCTIONS` and samples again with those of
:data:`SAMPLERS_AROUND`, each against the seed's stored uniform curve and floor (section ``variants``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from awr_denoise import AdaptiveSampler, SampleBuffer, UniformSampler, reconstruct
from awr_denoise.bench import update_section
from awr_denoise.bench.analysis import equal_error_spp, fit_noise_floor
from awr_denoise.bench.config import BenchmarkConfig
from awr_denoise.bench.measure import Timing, run_progressive
from awr_denoise.bench.rendering import make_tracer, reference_image, tracer_module
from awr_denoise.metrics import mse, relmse

RESULTS = Path(__file__).resolve().parent / "results" / "equal_error.json"
SAMPLERS: dict[str, dict[str, Any]] = {"default": {}, "relative error alone": {"absolute_above": None}}
TARGETS = (4, 8, 16, 32)
"""The AWR runs stop at these spp on the way to 32, as in ``awr bench`` (the round before each is cut to land on
it), so the samples at 32 spp are the benchmark's for seed 0."""
SPP = 32
RECONSTRUCTIONS: dict[str, dict[str, Any]] = {
    "c_s=3": {"c_s": 3.0}, "c_s=4": {"c_s": 4.0}, "stages=2": {"stages": 2},
    "stages=4": {"stages": 4, "wiener_exponents": (0.75, 0.4, 0.4)}, "wiener_exponents=(0.5, 0.4)":
    {"wiener_exponents": (0.5, 0.4)}, "wavelet=sym4": {"wavelet": "sym4"}, "domain=linear": {"domain": "linear"},
    "guard=False": {"guard": False}, "pixel_clamp=None": {"pixel_clamp": None}}
"""``reconstruct`` options tried on the default sampler's samples (``--variants``)."""
SAMPLERS_AROUND: dict[str, dict[str, Any]] = {
    "noise_model=levels": {"noise_model": "levels"}, "noise_model=reconstruction": {"noise_model": "reconstruction"},
    "initial_spp=4": {"initial_spp": 4}, "round_growth=0.5": {"round_growth": 0.5},
    "absolute_above=3": {"absolute_above": 3.0}, "absolute_above=10": {"absolute_above": 10.0}}
"""``AdaptiveSampler`` options tried with the default reconstruction (``--variants``)."""


def _run(sampler: Any, renderer: Any, targets: tuple[int, ...], on_snapshot: Any) -> None:
    """``run_progressive`` with the renderer closed afterwards."""
    try:
        run_progressive(sampler, renderer, targets, on_snapshot)
    finally:
        renderer.close()


def scene_seed(name: str, seed: int, config: BenchmarkConfig) -> dict[str, Any]:
    """One scene and seed: the uniform curve (to ``config.uniform_max_spp``), its noise-floor fit and each
    sampler's errors at 32 spp."""
    scene = tracer_module().load_scene(name, width=config.width, height=config.height)
    reference, _ = reference_image(name, scene, config)
    shape = (scene.height, scene.width)
    curve: list[tuple[int, float]] = []

    def uniform_snapshot(spp: int, buffer: SampleBuffer, timing: Timing) -> None:
        curve.append((spp, relmse(np.asarray(buffer.mean), reference)))

    spps = tuple(2**k for k in range(2, int(np.log2(config.uniform_max_spp)) + 1))
    _run(UniformSampler(shape, seed=seed), make_tracer(scene, seed, config.threads), spps, uniform_snapshot)
    c_spps, c_err = [s for s, _ in curve], [e for _, e in curve]
    slope_a, floor = fit_noise_floor(c_spps, c_err)
    corrected = [e - floor for e in c_err]
    row: dict[str, Any] = {"scene": name, "seed": seed, "uniform_curve": curve, "slope": slope_a, "floor": floor}
    for label, options in SAMPLERS.items():
        out: dict[str, float] = {}

        def snapshot(spp: int, buffer: SampleBuffer, timing: Timing) -> None:
            if spp == SPP:
                image = reconstruct(buffer)
                out.update(relmse=relmse(image, reference), mse=mse(image, reference),
                           plain_mse=mse(np.asarray(buffer.mean), reference))

        _run(AdaptiveSampler(shape, seed=seed, **options), make_tracer(scene, seed, config.threads), TARGETS, snapshot)
        eq, extrapolated = equal_error_spp(out["relmse"] - floor, c_spps, corrected, slope_a)
        row[label] = {**out, "equal_error_spp": eq, "extrapolated": extrapolated}
    return row


def _adaptive(name: str, seed: int, options: dict[str, Any], config: BenchmarkConfig) -> SampleBuffer:
    """The AWR samples at 32 spp of one scene and seed, stopping at :data:`TARGETS` as the benchmark does."""
    scene = tracer_module().load_scene(name, width=config.width, height=config.height)
    got: dict[str, SampleBuffer] = {}

    def snapshot(spp: int, buffer: SampleBuffer, timing: Timing) -> None:
        if spp == SPP:
            got["buffer"] = buffer

    _run(AdaptiveSampler((scene.height, scene.width), seed=seed, **options), make_tracer(scene, seed, config.threads),
         TARGETS, snapshot)
    return got["buffer"]


def variants(row: dict[str, Any], config: BenchmarkConfig) -> list[dict[str, Any]]:
    """Every option of :data:`RECONSTRUCTIONS` and :data:`SAMPLERS_AROUND` on one stored scene and seed."""
    name, seed = row["scene"], row["seed"]
    scene = tracer_module().load_scene(name, width=config.width, height=config.height)
    reference, _ = reference_image(name, scene, config)
    c_spps, corrected = [s for s, _ in row["uniform_curve"]], [e - row["floor"] for _, e in row["uniform_curve"]]

    def measured(kind: str, variant: str, image: np.ndarray) -> dict[str, Any]:
        error = relmse(image, reference)
        eq, extrapolated = equal_error_spp(error - row["floor"], c_spps, corrected, row["slope"])
        return {"scene": name, "seed": seed, "kind": kind, "variant": variant, "relmse": error,
                "mse": mse(image, reference), "equal_error_spp": eq, "extrapolated": extrapolated}

    buffer = _adaptive(name, seed, {}, config)
    out = [measured("default", "default", reconstruct(buffer))]
    # The same samples as the stored run, or the curve and floor are another run's (another --size, another version).
    if not math.isclose(out[0]["relmse"], row["default"]["relmse"], rel_tol=1e-9):
        raise SystemExit(f"{name} seed {seed}: the default's relMSE {out[0]['relmse']:.6e} is not the stored "
                         f"{row['default']['relmse']:.6e}; run the seeds again first")
    out += [measured("reconstruction", v, reconstruct(buffer, **o)) for v, o in RECONSTRUCTIONS.items()]
    out += [measured("sampler", v, reconstruct(_adaptive(name, seed, o, config))) for v, o in SAMPLERS_AROUND.items()]
    return out


def variants_table(rows: list[dict[str, Any]]) -> str:
    """Markdown: per option (rows) and scene (columns), the mean equal-error spp over seeds and, in brackets, the
    mean of its MSE over the default's."""
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    lines = ["| option | " + " | ".join(scenes) + " |", "|" + "---|" * (len(scenes) + 1)]
    default = {(r["scene"], r["seed"]): r for r in rows if r["kind"] == "default"}
    for variant in dict.fromkeys(r["variant"] for r in rows):
        cells = []
        for name in scenes:
            mine = [r for r in rows if r["variant"] == variant and r["scene"] == name]
            ratio = np.mean([r["mse"] / default[name, r["seed"]]["mse"] for r in mine])
            cells.append(f"{np.mean([r['equal_error_spp'] for r in mine]):.0f} ({ratio:.2f})")
        lines.append(f"| {variant} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def table(rows: list[dict[str, Any]]) -> str:
    """Markdown: per scene, each seed's equal-error spp of the default (the relative error alone) and their means."""
    seeds = sorted({r["seed"] for r in rows})
    head = ("| scene | " + " | ".join(f"seed {s}" for s in seeds)
            + " | mean | relative error alone, mean | its MSE over the default's, mean |")
    lines = [head, "|" + "---|" * (len(seeds) + 4)]
    for name in dict.fromkeys(r["scene"] for r in rows):
        mine = {r["seed"]: r for r in rows if r["scene"] == name}
        cells = [f"{mine[s]['default']['equal_error_spp']:.0f} "
                 f"({mine[s]['relative error alone']['equal_error_spp']:.0f})" if s in mine else "" for s in seeds]
        default = [r["default"]["equal_error_spp"] for r in mine.values()]
        alone = [r["relative error alone"]["equal_error_spp"] for r in mine.values()]
        ratio = [r["relative error alone"]["mse"] / r["default"]["mse"] for r in mine.values()]
        lines.append(f"| {name} | " + " | ".join(cells)
                     + f" | {np.mean(default):.0f} | {np.mean(alone):.0f} | {np.mean(ratio):.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", nargs="+", default=list(tracer_module().list_scenes()),
                        metavar="NAME")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4], metavar="N")
    parser.add_argument("--size", type=int, default=None, metavar="PIXELS",
                        help="square images of this side (default: the benchmark's 128x128 and its cached references)")
    parser.add_argument("--uniform-max-spp", type=int, default=1024, metavar="SPP")
    parser.add_argument("--output", type=Path, default=RESULTS)
    parser.add_argument("--variants", action="store_true",
                        help="options around the defaults, on the scenes and seeds stored in --output")
    args = parser.parse_args(argv)
    if args.uniform_max_spp < 2 * SPP:
        parser.error(f"--uniform-max-spp must be at least {2 * SPP}")
    config = BenchmarkConfig(width=args.size, height=args.size, uniform_max_spp=args.uniform_max_spp)
    command = "benchmarks/bench_equal_error.py " + " ".join(sys.argv[1:] if argv is None else argv)
    if args.variants:
        stored = json.loads(args.output.read_text()).get("seeds", {}).get("rows", []) if args.output.exists() else []
        chosen = [r for r in stored if r["scene"] in args.scenes and r["seed"] in args.seeds]
        if not chosen:
            parser.error(f"--variants: {args.output} holds no stored seed of these scenes; "
                         "run without --variants first")
        rows = [v for row in chosen for v in variants(row, config)]
        update_section(args.output, "variants", rows, command)
        print(variants_table(rows))
        return 0
    rows = []
    for name in args.scenes:
        for seed in args.seeds:
            rows.append(scene_seed(name, seed, config))
            d, r = rows[-1]["default"], rows[-1]["relative error alone"]
            print(f"{name} seed {seed}: {d['equal_error_spp']:.0f} spp (relative error alone "
                  f"{r['equal_error_spp']:.0f}); MSE over the plain mean's {d['mse'] / d['plain_mse']:.2f}", flush=True)
    update_section(args.output, "seeds", rows, command)
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
