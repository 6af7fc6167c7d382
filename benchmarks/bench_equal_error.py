"""Equal-error spp of AWR sampling at 32 spp over render seeds (docs/benchmarks.md, "Reading the results").

Run from the repository root::

    .venv/bin/python benchmarks/bench_equal_error.py [--scenes NAME ...] [--seeds N ...]
    .venv/bin/python benchmarks/bench_equal_error.py --variants   # after the run above: options around the defaults
    .venv/bin/python benchmarks/bench_equal_error.py --baseline   # after the run above: the goal's version, same seeds

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

``--baseline [COMMIT]`` measures the version the reconstruction issue's goal doubles (:data:`BASELINE`, the last
commit before its first change: the single-stage reconstruction and the sampler of then) on the same scenes and
seeds: the commit's files are taken from the repository's history (``git archive``) into a temporary folder and
its own ``AdaptiveSampler``, ``reconstruct`` and benchmark helpers render each seed's AWR samples to 32 spp in a
child process; their equal-error spp is computed here, against each seed's stored uniform curve and floor (the
tracer renders the same samples in both versions: the uniform curves agree), beside this version's (section
``baseline``). The goal's figures were that version's on seed 0 alone.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from awr_denoise import AdaptiveSampler, SampleBuffer, UniformSampler, reconstruct
from awr_denoise.bench import update_section
from awr_denoise.bench.records import results_file
from awr_denoise.bench.analysis import equal_error_spp, fit_noise_floor
from awr_denoise.bench.config import BenchmarkConfig
from awr_denoise.bench.measure import Timing, run_progressive
from awr_denoise.bench.rendering import make_tracer, reference_image, tracer_module
from awr_denoise.metrics import mse, relmse

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_reconstruct import SPUN  # noqa: E402
from moderated_variances import VARIANTS as MODERATED  # noqa: E402

REPOSITORY = Path(__file__).resolve().parent.parent
RESULTS = REPOSITORY / "benchmarks" / "results" / "equal_error.json"
SAMPLERS: dict[str, dict[str, Any]] = {"default": {}, "relative error alone": {"absolute_above": None}}
TARGETS = (4, 8, 16, 32)
"""The AWR runs stop at these spp on the way to 32, as in ``awr bench`` (the round before each is cut to land on
it), so the samples at 32 spp are the benchmark's for seed 0."""
SPP = 32
RECONSTRUCTIONS: dict[str, dict[str, Any]] = {
    "c_s=3": {"c_s": 3.0}, "c_s=4": {"c_s": 4.0}, "stages=2": {"stages": 2},
    "stages=4": {"stages": 4, "wiener_exponents": (0.75, 0.4, 0.4)}, "wiener_exponents=(0.5, 0.4)":
    {"wiener_exponents": (0.5, 0.4)}, "wavelet=sym4": {"wavelet": "sym4"}, "domain=linear": {"domain": "linear"},
    "guard=False": {"guard": False}, "pixel_clamp=None": {"pixel_clamp": None}, **MODERATED,
    "pilot spun over 4 shifts": SPUN["pilot spun over 4 shifts"]}
"""``reconstruct`` options tried on the default sampler's samples (``--variants``); a function of the buffer is a
reconstruction of its own (every variance moderated, ``moderated_variances.py``; the first Wiener stage's pilot
cycle-spun, ``bench_reconstruct.spun_pilot``)."""
SAMPLERS_AROUND: dict[str, dict[str, Any]] = {
    "noise_model=levels": {"noise_model": "levels"}, "noise_model=reconstruction": {"noise_model": "reconstruction"},
    "initial_spp=4": {"initial_spp": 4}, "round_growth=0.5": {"round_growth": 0.5},
    "absolute_above=3": {"absolute_above": 3.0}, "absolute_above=10": {"absolute_above": 10.0},
    "sampler wavelet=haar": {"wavelet": "haar"}, "sampler wavelet=sym4": {"wavelet": "sym4"},
    "sampler domain=linear": {"domain": "linear"}}
"""``AdaptiveSampler`` options tried with the default reconstruction (``--variants``)."""
BASELINE = "f36d7fb690f9498cb7143f1e36b881dbfd9c0dab"
"""The version whose seed-0 equal-error spp the reconstruction issue's goal doubles (``--baseline``): the merge of the
Mitsuba 3 adapter, the last commit on main before the staged reconstruction (its docs/benchmarks.md: 95-260)."""
_BASELINE_CHILD = """
import sys
import numpy as np
import awr_denoise
from awr_denoise import AdaptiveSampler, reconstruct
from awr_denoise.bench.config import BenchmarkConfig
from awr_denoise.bench.measure import run_progressive
from awr_denoise.bench.rendering import make_tracer, tracer_module

out_path, files, size = sys.argv[1], sys.argv[2], int(sys.argv[3]) or None
targets, jobs = [int(t) for t in sys.argv[4].split(",")], sys.argv[5:]
if not awr_denoise.__file__.startswith(files):
    sys.exit(f"the baseline imported the package from {awr_denoise.__file__}, not from its own files")
config = BenchmarkConfig(width=size, height=size)
images = {}
for job in jobs:
    name, seed = job.rsplit(":", 1)
    scene = tracer_module().load_scene(name, width=config.width, height=config.height)
    got = {}

    def snapshot(spp, buffer, timing):
        if spp == targets[-1]:
            got["image"] = np.asarray(reconstruct(buffer), dtype=np.float64)

    renderer = make_tracer(scene, int(seed), config.threads)
    try:
        run_progressive(AdaptiveSampler((scene.height, scene.width), seed=int(seed)), renderer, targets, snapshot)
    finally:
        getattr(renderer, "close", lambda: None)()
    images[job] = got["image"]
np.savez(out_path, **images)
"""
"""Runs in the baseline's own files: the API it uses (``AdaptiveSampler``, ``reconstruct``, ``BenchmarkConfig``,
``run_progressive``, ``make_tracer``, ``tracer_module``) is the same in both versions."""


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
    out += [measured("reconstruction", v, o(buffer) if callable(o) else reconstruct(buffer, **o))
            for v, o in RECONSTRUCTIONS.items()]
    out += [measured("sampler", v, reconstruct(_adaptive(name, seed, o, config))) for v, o in SAMPLERS_AROUND.items()]
    return out


def has_commit(commit: str) -> bool:
    """Whether the repository this script is in holds ``commit`` (a shallow clone may not)."""
    found = subprocess.run(["git", "-C", str(REPOSITORY), "rev-parse", "--verify", "--quiet", f"{commit}^{{commit}}"],
                           capture_output=True, text=True)
    return found.returncode == 0


def baseline_images(commit: str, jobs: list[tuple[str, int]], size: int | None) -> dict[tuple[str, int], np.ndarray]:
    """Each (scene, seed)'s AWR reconstruction at 32 spp by the version at ``commit``, run from its own files."""
    with tempfile.TemporaryDirectory(prefix="awr-baseline-") as tmp:
        archive = Path(tmp) / "version.tar"
        made = subprocess.run(["git", "-C", str(REPOSITORY), "archive", "--format=tar", "--output", str(archive), commit],
                              capture_output=True, text=True)
        if made.returncode != 0:
            raise SystemExit(f"--baseline: commit {commit} is not in this checkout's history "
                             f"({made.stderr.strip() or 'git archive failed'})")
        files = Path(tmp) / "version"
        with tarfile.open(archive) as tar:
            tar.extractall(files, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
        out = Path(tmp) / "images.npz"
        # Its own package first on the path (the child checks it); numpy, embreex and the rest are this environment's.
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(files), os.environ.get("PYTHONPATH")]))}
        subprocess.run([sys.executable, "-c", _BASELINE_CHILD, str(out), str(files), str(size or 0),
                        ",".join(map(str, TARGETS)), *(f"{name}:{seed}" for name, seed in jobs)],
                       env=env, cwd=files, check=True)
        with np.load(out) as images:
            return {(name, seed): images[f"{name}:{seed}"] for name, seed in jobs}


def baseline(rows: list[dict[str, Any]], commit: str, config: BenchmarkConfig) -> list[dict[str, Any]]:
    """The version at ``commit`` on every stored scene and seed, against the seed's stored curve and floor, beside
    this version's stored figure."""
    images = baseline_images(commit, [(r["scene"], r["seed"]) for r in rows], config.width)
    out = []
    for row in rows:
        scene = tracer_module().load_scene(row["scene"], width=config.width, height=config.height)
        reference, _ = reference_image(row["scene"], scene, config)
        c_spps, corrected = [s for s, _ in row["uniform_curve"]], [e - row["floor"] for _, e in row["uniform_curve"]]
        image = images[row["scene"], row["seed"]]
        error = relmse(image, reference)
        eq, extrapolated = equal_error_spp(error - row["floor"], c_spps, corrected, row["slope"])
        out.append({"scene": row["scene"], "seed": row["seed"], "commit": commit, "relmse": error,
                    "mse": mse(image, reference), "equal_error_spp": eq, "extrapolated": extrapolated,
                    "this_version": row["default"]["equal_error_spp"],
                    "this_version_mse": row["default"]["mse"]})
    return out


def baseline_table(rows: list[dict[str, Any]]) -> str:
    """Markdown: per scene, each seed's equal-error spp of the baseline and of this version, and the ratios."""
    seeds = sorted({r["seed"] for r in rows})
    lines = ["| scene | " + " | ".join(f"seed {s}" for s in seeds)
             + " | mean | ratio of the means | ratio per seed | MSE over the baseline's, mean |",
             "|" + "---|" * (len(seeds) + 5)]
    for name in dict.fromkeys(r["scene"] for r in rows):
        mine = {r["seed"]: r for r in rows if r["scene"] == name}
        cells = [f"{mine[s]['equal_error_spp']:.0f} -> {mine[s]['this_version']:.0f}" if s in mine else ""
                 for s in seeds]
        old = np.mean([r["equal_error_spp"] for r in mine.values()])
        new = np.mean([r["this_version"] for r in mine.values()])
        ratios = [r["this_version"] / r["equal_error_spp"] for r in mine.values()]
        mse_ratio = np.mean([r["this_version_mse"] / r["mse"] for r in mine.values()])
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {old:.0f} -> {new:.0f} | {new / old:.2f} | "
                     f"{min(ratios):.2f}-{max(ratios):.2f} | {mse_ratio:.2f} |")
    return "\n".join(lines)


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
    parser.add_argument("--output", type=results_file, default=RESULTS)
    parser.add_argument("--variants", action="store_true",
                        help="options around the defaults, on the scenes and seeds stored in --output")
    parser.add_argument("--baseline", nargs="?", const=BASELINE, default=None, metavar="COMMIT",
                        help="the version at COMMIT (default: the goal's, %(const).7s) on the scenes and seeds stored "
                             "in --output")
    args = parser.parse_args(argv)
    if args.variants and args.baseline:
        parser.error("--variants and --baseline: one at a time")
    if args.baseline and not has_commit(args.baseline):
        parser.error(f"--baseline: {args.baseline} is not a commit in this checkout's history")
    if args.uniform_max_spp < 2 * SPP:
        parser.error(f"--uniform-max-spp must be at least {2 * SPP}")
    config = BenchmarkConfig(width=args.size, height=args.size, uniform_max_spp=args.uniform_max_spp)
    command = "benchmarks/bench_equal_error.py " + " ".join(sys.argv[1:] if argv is None else argv)
    if args.variants or args.baseline:
        option = "--variants" if args.variants else "--baseline"
        stored = json.loads(args.output.read_text()).get("seeds", {}).get("rows", []) if args.output.exists() else []
        chosen = [r for r in stored if r["scene"] in args.scenes and r["seed"] in args.seeds]
        if not chosen:
            parser.error(f"{option}: {args.output} holds no stored seed of these scenes; "
                         f"run without {option} first")
        if args.baseline:
            rows = baseline(chosen, args.baseline, config)
            update_section(args.output, "baseline", rows, command)
            print(baseline_table(rows))
            return 0
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
