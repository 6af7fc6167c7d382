"""Parallel benchmark: speed-up from 1 to 2 workers for frames, tiled rendering and tiled reconstruction.

Run from the repository root::

    .venv/bin/python benchmarks/bench_parallel.py            # several minutes on a 2-core machine
    .venv/bin/python benchmarks/bench_parallel.py --quick    # smaller workloads, 2 repeats

Each workload runs serially in this process (no executor), on a thread pool and on a local Dask
cluster (worker processes, one thread each) with 1 and with 2 workers. Every timing is the median
of ``--repeats`` runs after one warm-up run on the same executor (worker imports, the renderer
built in each worker and the wavelet operator caches are not timed); the configurations take
turns within each repeat, so a change in the machine's load affects them alike. Executor
start-up is reported on its own, with the load average. Prints a markdown table and writes
``benchmarks/results/parallel.json``.

Workloads:

* ``frames``: :func:`awr_denoise.parallel.denoise_frames` on a sequence of sample dumps (EXR
  files in a temporary directory), one task per frame;
* ``render``: :func:`awr_denoise.parallel.render_tiled`, an adaptive render of the bundled path
  tracer's ``cornell_gi`` scene (the synthetic ``fireflies`` scene without embreex), one task per
  tile and round;
* ``tiled reconstruction``: :func:`awr_denoise.parallel.reconstruct_tiled` of one large frame.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import tempfile
import time
from concurrent.futures import Executor
from pathlib import Path

from awr_denoise import AdaptiveSampler, SampleBuffer, SampleRequest, reconstruct
from awr_denoise.bench import command_line, load_average, machine_info, write_json
from awr_denoise.bench.records import results_file
from awr_denoise.io import write_sample_buffer
from awr_denoise.parallel import (
    RendererSpec,
    denoise_frame,
    denoise_frames,
    get_executor,
    halo_width,
    reconstruct_tiled,
    render_tiled,
)
from awr_denoise.synthetic import SyntheticRenderer, make_scene

RESULTS = Path(__file__).resolve().parent / "results" / "parallel.json"
CONFIGS = (("threads", 1), ("threads", 2), ("dask", 1), ("dask", 2))


def _renderer_spec(shape: tuple[int, int]) -> tuple[RendererSpec, str]:
    try:
        from awr_denoise import tracer  # noqa: F401 - optional extra "tracer" (embreex): is it installed?
    except ImportError:
        return RendererSpec.synthetic("fireflies", shape, seed=1), "synthetic fireflies"
    return (RendererSpec.tracer("cornell_gi", width=shape[1], height=shape[0], seed=1, threads=1),
            "path tracer, cornell_gi")


class Workloads:
    """The three workloads, each runnable serially or on an executor."""

    def __init__(self, directory: Path, quick: bool) -> None:
        self.n_frames = 4 if quick else 8
        frame_shape = (256, 256) if quick else (512, 512)
        self.inputs = []
        for frame in range(self.n_frames):
            path = directory / f"dump.{frame:04d}.exr"
            scene = make_scene("edges", frame_shape)
            write_sample_buffer(path, SyntheticRenderer(scene, seed=frame)(SampleRequest.uniform(frame_shape, 4)))
            self.inputs.append(path)
        self.outputs = [directory / f"denoised.{frame:04d}.exr" for frame in range(self.n_frames)]
        self.render_shape = (90, 120) if quick else (180, 240)
        self.render_spp = 8 if quick else 16
        self.render_tile = 64
        self.spec, self.renderer_name = _renderer_spec(self.render_shape)
        recon_shape = (768, 768) if quick else (1536, 1536)
        scene = make_scene("hdr_source", recon_shape)
        self.recon_buffer: SampleBuffer = SyntheticRenderer(scene, seed=2)(SampleRequest.uniform(recon_shape, 4))
        self.recon_tile = 512
        self.descriptions = {
            "frames": f"denoise_frames: {self.n_frames} frames of {frame_shape[1]}x{frame_shape[0]}, "
                      "one task per frame",
            "render": f"render_tiled: adaptive {self.render_spp} spp, {self.render_shape[1]}x{self.render_shape[0]} "
                      f"({self.renderer_name}), {self.render_tile}-pixel tiles",
            "tiled reconstruction": f"reconstruct_tiled: {recon_shape[1]}x{recon_shape[0]}, {self.recon_tile}-pixel "
                                    f"tiles, halo {halo_width('bior4.4', 5)}",
        }

    def run(self, name: str, executor: Executor | None) -> None:
        if name == "frames":
            if executor is None:
                for source, target in zip(self.inputs, self.outputs):
                    denoise_frame(source, target, overwrite=True)
            else:
                denoise_frames(self.inputs, self.outputs, executor=executor, overwrite=True)
        elif name == "render":
            sampler = AdaptiveSampler(self.render_shape, seed=1)
            if executor is None:
                sampler.run(self.spec(), self.render_spp)
            else:
                render_tiled(self.spec, sampler, total_spp=self.render_spp, tile=self.render_tile, executor=executor)
        elif name == "tiled reconstruction":
            if executor is None:
                reconstruct(self.recon_buffer)
            else:
                reconstruct_tiled(self.recon_buffer, tile=self.recon_tile, executor=executor)
        else:
            raise ValueError(name)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="smaller workloads and 2 repeats")
    parser.add_argument("--repeats", type=int, help="timed runs per configuration (default 3, 2 with --quick)")
    parser.add_argument("--output", type=results_file, default=RESULTS, help=f"JSON results (default {RESULTS.name})")
    args = parser.parse_args(argv)
    repeats = args.repeats or (2 if args.quick else 3)
    names = ("frames", "render", "tiled reconstruction")
    timings: dict[str, dict[str, float]] = {name: {} for name in names}
    startup: dict[str, float] = {}
    load_start = load_average()  # other processes on the machine skew every timing
    samples: dict[str, dict[str, list[float]]] = {name: {} for name in names}
    with tempfile.TemporaryDirectory() as tmp, contextlib.ExitStack() as stack:
        work = Workloads(Path(tmp), args.quick)
        executors: dict[str, Executor | None] = {"serial": None}
        for kind, workers in CONFIGS:
            label = f"{kind}-{workers}"
            start = time.perf_counter()
            executors[label] = stack.enter_context(get_executor(kind, workers=workers))
            startup[label] = time.perf_counter() - start
        for label, executor in executors.items():
            for name in names:
                work.run(name, executor)  # warm-up: imports and renderer construction in the workers
        # Configurations take turns within every repeat, so a change in the machine's load
        # while the benchmark runs affects them alike.
        for repeat in range(repeats):
            for label, executor in executors.items():
                for name in names:
                    start = time.perf_counter()
                    work.run(name, executor)
                    samples[name].setdefault(label, []).append(time.perf_counter() - start)
            print(f"  repeat {repeat + 1}/{repeats} done", file=sys.stderr)
    for name in names:
        timings[name] = {label: statistics.median(times) for label, times in samples[name].items()}

    rows = []
    header = ("workload", "serial", "threads 1", "threads 2", "speed-up", "dask 1", "dask 2", "speed-up")
    print("| " + " | ".join(header) + " |")
    print("|" + "|".join("---" for _ in header) + "|")
    results: dict[str, dict] = {}
    for name in names:
        t = timings[name]
        thread_speedup = t["threads-1"] / t["threads-2"]
        dask_speedup = t["dask-1"] / t["dask-2"]
        results[name] = {"description": work.descriptions[name], "seconds": t, "all_seconds": samples[name],
                         "speedup_threads_1_to_2": thread_speedup, "speedup_dask_1_to_2": dask_speedup,
                         "speedup_dask_2_vs_serial": t["serial"] / t["dask-2"]}
        rows.append(name)
        print(f"| {name} | {t['serial']:.2f} s | {t['threads-1']:.2f} s | {t['threads-2']:.2f} s | "
              f"{thread_speedup:.2f}x | {t['dask-1']:.2f} s | {t['dask-2']:.2f} s | {dask_speedup:.2f}x |")
    print()
    print("executor start-up: " + ", ".join(f"{k} {v:.2f} s" for k, v in startup.items()))
    load_end = load_average()
    if load_start and load_end:
        print(f"load average (1 min) at start {load_start[0]:.2f}, at end {load_end[0]:.2f} on {os.cpu_count()} CPUs")
    for name in names:
        print(f"- {name}: {work.descriptions[name]}")

    payload = {
        "command": command_line("benchmarks/bench_parallel.py", argv),
        "repeats": repeats,
        "statistic": "median seconds after one warm-up run per executor; configurations interleaved",
        "machine": machine_info("dask", "distributed"),
        "load_average_1_5_15_min": {"start": load_start, "end": load_end},
        "executor_startup_seconds": startup,
        "workloads": results,
    }
    write_json(args.output, payload, indent=2)
    print(f"\nwrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
