"""Core benchmark: speed and memory of reconstruct() and ask(), and quality on synthetic scenes.

Run from the repository root::

    .venv/bin/python benchmarks/bench_core.py                  # everything, a few minutes
    .venv/bin/python benchmarks/bench_core.py --quick          # 256x256 speed, fewer quality runs
    .venv/bin/python benchmarks/bench_core.py --only levels    # one section, updated in the JSON

Prints markdown tables and writes ``benchmarks/results/core.json``. Timings are medians of
repeated runs on one core (no executor); memory is the tracemalloc peak of a separate run,
reported as a multiple of the input buffer (count + mean + variance).
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from scipy import ndimage

from awr_denoise import AdaptiveSampler, SampleRequest, UniformSampler, VarianceSampler, reconstruct
from awr_denoise.bench import OVERHEAD_SIZES, machine_info, median_time, noisy_buffer, peak_memory, write_json
from awr_denoise.domains import Domain
from awr_denoise.metrics import mse, relmse
from awr_denoise.synthetic import SyntheticRenderer, make_scene
from awr_denoise.wavelets import default_levels

RESULTS = Path(__file__).resolve().parent / "results" / "core.json"


def speed(sizes: list[str]) -> list[dict]:
    rows = []
    for name in sizes:
        shape = OVERHEAD_SIZES[name]
        # Unblurred random means without added noise: the buffer of the timings in docs/performance.md.
        buf = noisy_buffer(shape, smooth=0.0, noise=0.0)
        repeats = 5 if name == "256x256" else 3
        reconstruct(buf)  # build and cache the wavelet operators once, as a renderer's loop would
        sampler = AdaptiveSampler.from_buffer(buf, round=1)
        sampler.ask()
        t_rec = median_time(lambda: reconstruct(buf), repeats)
        with ThreadPoolExecutor(2) as pool:
            t_rec2 = median_time(lambda: reconstruct(buf, executor=pool), repeats)
        t_ask = median_time(lambda: AdaptiveSampler.from_buffer(buf, round=1).ask(), repeats)
        _, m_rec = peak_memory(lambda: reconstruct(buf))
        _, m_ask = peak_memory(lambda: AdaptiveSampler.from_buffer(buf, round=1).ask())
        row = {"size": name, "pixels": shape[0] * shape[1], "input_MB": buf.nbytes / 2**20,
               "reconstruct_s": t_rec, "reconstruct_2threads_s": t_rec2, "ask_s": t_ask,
               "reconstruct_peak_x_input": m_rec / buf.nbytes, "ask_peak_x_input": m_ask / buf.nbytes}
        rows.append(row)
        print(f"| {name} | {row['input_MB']:.0f} MB | {t_rec:.3f} s | {t_rec2:.3f} s | {t_ask:.3f} s | "
              f"{row['reconstruct_peak_x_input']:.1f}x | {row['ask_peak_x_input']:.1f}x |", flush=True)
    return rows


def quality(shape=(128, 128), spps=(8, 32), seed=3) -> list[dict]:
    rows = []
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        for spp in spps:
            row = {"scene": scene_name, "spp": spp}
            uniform = UniformSampler(shape).run(SyntheticRenderer(scene, seed=seed), spp)
            row["uniform_mean"] = (relmse(uniform.mean, ref), mse(uniform.mean, ref))
            row["uniform_awr"] = (relmse(reconstruct(uniform), ref), mse(reconstruct(uniform), ref))
            variance = VarianceSampler(shape).run(SyntheticRenderer(scene, seed=seed), spp)
            row["variance_awr"] = (relmse(reconstruct(variance), ref), mse(reconstruct(variance), ref))
            adaptive = AdaptiveSampler(shape).run(SyntheticRenderer(scene, seed=seed), spp)
            row["adaptive_awr"] = (relmse(reconstruct(adaptive), ref), mse(reconstruct(adaptive), ref))
            rows.append(row)
            cells = " | ".join(f"{row[k][0]:.4f} / {row[k][1]:.2e}"
                               for k in ("uniform_mean", "uniform_awr", "variance_awr", "adaptive_awr"))
            print(f"| {scene_name} | {spp} | {cells} |", flush=True)
    return rows


def domains(shape=(128, 128), spps=(4, 16), seed=1) -> list[dict]:
    variants = {"linear": Domain("linear"), "log k=0.02": Domain("log", 0.02), "log k=0.1": Domain("log", 0.1),
                "log k=0.5": Domain("log", 0.5), "gamma 2.2": Domain("gamma"),
                "log k=0.1 robust": Domain("log", 0.1, robust=True)}
    rows = []
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        for spp in spps:
            buf = UniformSampler(shape).run(SyntheticRenderer(scene, seed=seed), spp)
            row = {"scene": scene_name, "spp": spp, "mean": relmse(buf.mean, ref)}
            for label, dom in variants.items():
                row[label] = relmse(reconstruct(buf, domain=dom), ref)
            rows.append(row)
            print(f"| {scene_name} | {spp} | {row['mean']:.4f} | "
                  + " | ".join(f"{row[k]:.4f}" for k in variants) + " |", flush=True)
    return rows


def pixel_clamps(shape=(64, 64), spps=(4, 8, 32), seeds=range(5)) -> list[dict]:
    """Mean relMSE over seeds, and the worst ratio to the noisy mean, per pixel clamp."""
    clamps = {"none (Eq. 11 only)": None, "z=2": 2.0, "z=2.5": 2.5, "z=3": 3.0}
    rows = []
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        for spp in spps:
            buffers = [SyntheticRenderer(scene, seed=s)(SampleRequest.uniform(shape, spp)) for s in seeds]
            means = [relmse(b.mean, ref) for b in buffers]
            row = {"scene": scene_name, "spp": spp, "mean": float(np.mean(means))}
            for label, z in clamps.items():
                errs = [relmse(reconstruct(b, pixel_clamp=z), ref) for b in buffers]
                row[label] = {"relmse": float(np.mean(errs)),
                              "worst_ratio_to_mean": float(max(e / m for e, m in zip(errs, means)))}
            rows.append(row)
            print(f"| {scene_name} | {spp} | {row['mean']:.4f} | "
                  + " | ".join(f"{row[k]['relmse']:.4f} ({row[k]['worst_ratio_to_mean']:.2f})" for k in clamps)
                  + " |", flush=True)
    return rows


def level_weights(shape=(128, 128), spp=16, seed=3) -> list[dict]:
    rows = []
    weights = (0.0, 0.25, 0.5, 1.0)
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        uniform = UniformSampler(shape).run(SyntheticRenderer(scene, seed=seed), spp)
        row = {"scene": scene_name, "spp": spp, "uniform_awr": relmse(reconstruct(uniform), ref)}
        for lw in weights:
            buf = AdaptiveSampler(shape, level_weight=lw).run(SyntheticRenderer(scene, seed=seed), spp)
            row[f"w={lw}"] = relmse(reconstruct(buf), ref)
        rows.append(row)
        print(f"| {scene_name} | {row['uniform_awr']:.4f} | " + " | ".join(f"{row[f'w={lw}']:.4f}" for lw in weights)
              + " |", flush=True)
    return rows


def round_growths(shape=(128, 128), spps=(8, 32), seeds=(3, 4, 5)) -> list[dict]:
    """AdaptiveSampler's round size: relMSE after reconstruction, mean over seeds."""
    rows = []
    growths = (0.25, 0.5, 1.0)
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        for spp in spps:
            row = {"scene": scene_name, "spp": spp}
            for growth in growths:
                errors, rounds = [], []
                for seed in seeds:
                    sampler = AdaptiveSampler(shape, seed=seed, round_growth=growth)
                    buf = sampler.run(SyntheticRenderer(scene, seed=seed), spp)
                    errors.append(relmse(reconstruct(buf), ref))
                    rounds.append(sampler.round)
                row[f"g={growth}"] = {"relmse": float(np.mean(errors)), "rounds": rounds[0]}
            rows.append(row)
            print(f"| {scene_name} | {spp} | " + " | ".join(
                f"{row[f'g={g}']['relmse']:.4f} ({row[f'g={g}']['rounds']})" for g in growths) + " |", flush=True)
    return rows


def levels(shapes=((128, 128), (256, 256)), spps=(8, 32), seeds=(3, 4)) -> list[dict]:
    """Decomposition depth: relMSE of uniform + AWR and AWR + AWR, mean over seeds, per size."""
    rows = []
    for shape in shapes:
        depths = (2, 3, 4, 5)
        for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
            scene = make_scene(scene_name, shape)
            ref = scene.reference(8)
            for spp in spps:
                row = {"size": f"{shape[1]}x{shape[0]}", "scene": scene_name, "spp": spp,
                       "default": default_levels(shape)}
                for lv in depths:
                    uniform, adaptive = [], []
                    for seed in seeds:
                        buf = UniformSampler(shape, seed=seed).run(SyntheticRenderer(scene, seed=seed), spp)
                        uniform.append(relmse(reconstruct(buf, levels=lv), ref))
                        buf = AdaptiveSampler(shape, seed=seed, levels=lv).run(SyntheticRenderer(scene, seed=seed), spp)
                        adaptive.append(relmse(reconstruct(buf, levels=lv), ref))
                    row[f"L={lv}"] = {"uniform_awr": float(np.mean(uniform)), "awr_awr": float(np.mean(adaptive))}
                rows.append(row)
                print(f"| {row['size']} | {scene_name} | {spp} | " + " | ".join(
                    f"{row[f'L={lv}']['uniform_awr']:.4f} / {row[f'L={lv}']['awr_awr']:.4f}" for lv in depths) + " |",
                    flush=True)
    return rows


def uniform_fractions(shape=(128, 128), spps=(8, 32), seeds=(3, 4, 5, 6)) -> list[dict]:
    """AdaptiveSampler's uniform share: relMSE after reconstruction, mean over seeds.

    ``rare_light (disc)`` is the error of the rare_light scene inside its small bright disc (grown
    by 3 pixels), where a share of uniform samples would matter if anywhere.
    """
    rows = []
    fractions = (0.0, 0.1, 0.3)
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies", "rare_light"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        regions = {scene_name: np.ones(shape, bool)}
        if scene_name == "rare_light":
            regions["rare_light (disc)"] = ndimage.binary_dilation(ref[..., 0] > 0.5, iterations=3)
        for spp in spps:
            errors = {(name, f): [] for name in regions for f in fractions}
            for fraction in fractions:
                for seed in seeds:
                    sampler = AdaptiveSampler(shape, seed=seed, uniform_fraction=fraction)
                    out = reconstruct(sampler.run(SyntheticRenderer(scene, seed=seed), spp))
                    for name, mask in regions.items():
                        errors[name, fraction].append(relmse(out[mask], ref[mask]))
            for name in regions:
                row = {"scene": name, "spp": spp, **{f"f={f}": float(np.mean(errors[name, f])) for f in fractions}}
                rows.append(row)
                print(f"| {name} | {spp} | " + " | ".join(f"{row[f'f={f}']:.4f}" for f in fractions) + " |",
                      flush=True)
    return rows


SECTIONS = {
    "speed": ("Speed (one core) and peak memory",
              "| size | input buffer | reconstruct | reconstruct, 2 threads | ask() | reconstruct peak | ask() peak |",
              lambda quick: speed(["256x256"] if quick else list(OVERHEAD_SIZES))),
    "quality": ("Quality, synthetic 128x128 (relMSE / MSE, equal samples)",
                "| scene | spp | uniform mean | uniform + AWR | variance-driven + AWR | AWR adaptive + AWR |",
                lambda quick: quality(spps=(8,) if quick else (8, 32))),
    "domains": ("Reconstruction domain (relMSE, uniform sampling, c_s = 1)",
                "| scene | spp | mean | linear | log k=0.02 | log k=0.1 | log k=0.5 | gamma 2.2 | log k=0.1 robust |",
                lambda quick: domains(spps=(4,) if quick else (4, 16))),
    "pixel_clamps": ("Pixel clamp (64x64, mean relMSE over 5 seeds, worst ratio to the noisy mean in brackets)",
                     "| scene | spp | mean | none (Eq. 11 only) | z=2 | z=2.5 | z=3 |",
                     lambda quick: pixel_clamps(spps=(8,) if quick else (4, 8, 32))),
    "level_weights": ("Sampler level weight (relMSE after reconstruction, 16 spp)",
                      "| scene | uniform + AWR | w=0 | w=0.25 | w=0.5 | w=1 |",
                      lambda quick: level_weights()),
    "round_growths": ("Sampler round growth (relMSE after reconstruction, mean of 3 seeds; rounds in brackets)",
                      "| scene | spp | growth 0.25 | growth 0.5 | growth 1.0 |",
                      lambda quick: round_growths(spps=(8,) if quick else (8, 32))),
    "uniform_fractions": ("Sampler uniform share (relMSE after reconstruction, mean of 4 seeds)",
                          "| scene | spp | uniform_fraction 0 | 0.1 | 0.3 |",
                          lambda quick: uniform_fractions(spps=(8,) if quick else (8, 32))),
    "levels": ("Levels (relMSE, uniform + AWR / AWR + AWR, mean of 2 seeds)",
               "| size | scene | spp | L=2 | L=3 | L=4 | L=5 |",
               lambda quick: levels(shapes=((128, 128),) if quick else ((128, 128), (256, 256)),
                                    spps=(8,) if quick else (8, 32))),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="256x256 speed only, fewer quality runs")
    parser.add_argument("--only", nargs="+", choices=tuple(SECTIONS), metavar="SECTION",
                        help=f"run only these sections ({', '.join(SECTIONS)}) and update them in the JSON")
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    results = {}
    if args.only and args.output.is_file():
        results = json.loads(args.output.read_text())
    results["machine"] = machine_info()
    for name in args.only or SECTIONS:
        title, header, run = SECTIONS[name]
        print(f"\n## {title}\n")
        print(header)
        print("|---" * (header.count("|") - 1) + "|")
        results[name] = run(args.quick)
    write_json(args.output, results, indent=2)
    print(f"\nwrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
