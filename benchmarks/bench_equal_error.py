"""Equal-error spp of AWR sampling at 32 spp over render seeds (docs/benchmarks.md, "Reading the results").

Run from the repository root::

    .venv/bin/python benchmarks/bench_equal_error.py [--scenes NAME ...] [--seeds N ...]

(``--size``, ``--uniform-max-spp`` and ``--output`` make a smaller trial run, as the script's test does.)

``awr bench`` measures the equal-error spp on render seed 0 alone: every method there shares that seed's
random numbers, so method differences are not seed noise, but the figure itself is one draw. This script
renders each scene again with other seeds, each seed with its own uniform Monte Carlo curve (4-1024 spp, the
same progressive render as ``awr bench``) and its own fit of the reference's noise floor, so each equal-error
spp is computed as ``awr bench`` computes it. Beside the default sampler: the relative error alone
(``absolute_above=None``, docs/sampling.md, "Relative and absolute error"), whose relMSE is lower where a
small bright light holds the squared error and whose MSE is higher there. Results:
``benchmarks/results/equal_error.json``.
"""

from __future__ import annotations

import argparse
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
    args = parser.parse_args(argv)
    if args.uniform_max_spp < 2 * SPP:
        parser.error(f"--uniform-max-spp must be at least {2 * SPP}")
    config = BenchmarkConfig(width=args.size, height=args.size, uniform_max_spp=args.uniform_max_spp)
    rows = []
    for name in args.scenes:
        for seed in args.seeds:
            rows.append(scene_seed(name, seed, config))
            d, r = rows[-1]["default"], rows[-1]["relative error alone"]
            print(f"{name} seed {seed}: {d['equal_error_spp']:.0f} spp (relative error alone "
                  f"{r['equal_error_spp']:.0f}); MSE over the plain mean's {d['mse'] / d['plain_mse']:.2f}", flush=True)
    update_section(args.output, "seeds", rows,
                   "benchmarks/bench_equal_error.py " + " ".join(sys.argv[1:] if argv is None else argv))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
