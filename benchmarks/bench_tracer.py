"""Throughput of the bundled path tracer against raw embreex on the same rays.

For every bundled scene: render ``--spp`` samples per pixel with :class:`PathTracer` (both
cores), then replay exactly the rays that render traced (recorded batch by batch, same batch
sizes, same queries: INTERSECT with ``output=1`` or OCCLUDED) directly through embreex on the
same number of threads. The ratio of the two ray rates is the cost of everything that is not
ray traversal: sampling, camera, shading, light sampling and bookkeeping in numpy.

Usage::

    python benchmarks/bench_tracer.py [--spp 8] [--repeats 3] [--threads 2] [--scenes a b ...]

Prints a table and writes ``benchmarks/results/tracer.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from awr_denoise.bench import command_line, load_average, machine_info, write_json
from awr_denoise.bench.records import results_file
from awr_denoise.requests import SampleRequest
from awr_denoise.tracer import PathTracer, list_scenes, load_scene

__all__ = ["bench_scene", "markdown_table", "main"]

RESULTS = Path(__file__).resolve().parent / "results" / "tracer.json"


def _replay(tracer: PathTracer, record: list, threads: int) -> float:
    """Seconds to trace the recorded ray batches directly with embreex."""
    accel = tracer.accelerator
    scenes = {-1: accel.static_scene, **dict(enumerate(accel.moving_scenes))}

    def run(item: tuple) -> None:
        query, scene_index, o, d, dist = item
        if query == "OCCLUDED":
            scenes[scene_index].run(o, d, dists=dist.copy(), query="OCCLUDED")
        else:
            scenes[scene_index].run(o, d, output=1)

    start = time.perf_counter()
    with ThreadPoolExecutor(max_workers=threads) as pool:
        list(pool.map(run, record))
    return time.perf_counter() - start


def bench_scene(name: str, *, spp: int, repeats: int, threads: int, size: int | None,
                workers: str = "threads") -> dict:
    """Best-of-``repeats`` tracer and raw embreex throughput for one scene."""
    scene = load_scene(name, width=size, height=size)
    tracer = PathTracer(scene, threads=threads, sampler="sobol", workers=workers)
    request = SampleRequest.uniform(tracer.shape, spp)
    tracer(SampleRequest.uniform(tracer.shape, 1))  # warm up (BVH is built at construction)
    best_tracer, rays, samples = np.inf, 0, 0
    for _ in range(repeats):
        before = dict(tracer.stats)
        start = time.perf_counter()
        tracer(request)
        elapsed = time.perf_counter() - start
        best_tracer = min(best_tracer, elapsed)
        rays = int(tracer.stats["rays"] - before["rays"])
        samples = int(tracer.stats["samples"] - before["samples"])
        split = {k: int(tracer.stats[k] - before[k]) for k in ("camera_rays", "bounce_rays", "shadow_rays")}
    # The same render on one thread: how much the thread pool gains.
    single = PathTracer(scene, threads=1, sampler="sobol")
    single(SampleRequest.uniform(single.shape, 1))
    best_single = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        single(request)
        best_single = min(best_single, time.perf_counter() - start)
    # Record the rays in-process (the same rays whatever the workers: samples are addressed).
    single.batch_size = max(1, min(tracer.batch_size, -(-request.total // threads)))  # the pool's batches
    single.accelerator.record = []
    single(request)
    record, single.accelerator.record = single.accelerator.record, None
    recorded_rays = sum(len(item[2]) for item in record)
    best_raw = min(_replay(single, record, threads) for _ in range(repeats))
    best_raw_single = min(_replay(single, record, 1) for _ in range(repeats))
    tracer.close()
    return {
        "scene": name, "width": scene.width, "height": scene.height, "dimension": scene.dimension,
        "triangles": int(len(tracer.accelerator.triangle_vertices)), "spp": spp, "samples": samples,
        "rays": rays, "rays_per_sample": rays / samples, **split,
        "tracer_seconds": best_tracer, "tracer_samples_per_s": samples / best_tracer,
        "tracer_rays_per_s": rays / best_tracer,
        "raw_embree_seconds": best_raw, "raw_embree_rays_per_s": recorded_rays / best_raw,
        "ratio_tracer_to_raw": (rays / best_tracer) / (recorded_rays / best_raw),
        "tracer_single_thread_seconds": best_single, "tracer_thread_speedup": best_single / best_tracer,
        "raw_embree_single_thread_seconds": best_raw_single, "raw_thread_speedup": best_raw_single / best_raw,
    }


def markdown_table(result: dict) -> str:
    """The results as the Markdown table of ``docs/tracer.md``."""
    lines = ["| scene | workers | dim | triangles | rays/sample | tracer Msamples/s | tracer Mrays/s "
             "| raw embreex Mrays/s | tracer/raw | tracer 2 workers / 1 thread | raw 2T/1T |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in result["scenes"]:
        lines.append(
            f"| `{r['scene']}` | {r['workers']} | {r['dimension']} | {r['triangles']} | {r['rays_per_sample']:.2f} "
            f"| {r['tracer_samples_per_s'] / 1e6:.3f} | {r['tracer_rays_per_s'] / 1e6:.2f} "
            f"| {r['raw_embree_rays_per_s'] / 1e6:.2f} | {r['ratio_tracer_to_raw']:.1%} "
            f"| {r['tracer_thread_speedup']:.2f} | {r['raw_thread_speedup']:.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--workers", nargs="+", default=["threads", "processes"], choices=("threads", "processes"),
                        help="how the tracer runs its batches concurrently (each kind is measured)")
    parser.add_argument("--size", type=int, default=None, help="square resolution (default: each scene's own)")
    parser.add_argument("--scenes", nargs="*", default=None)
    parser.add_argument("--output", type=results_file, default=RESULTS)
    parser.add_argument("--markdown-from", type=Path, default=None, metavar="JSON",
                        help="print the Markdown table of an earlier results file and exit")
    # A loaded machine distorts every number here; the load is recorded with the results.
    args = parser.parse_args(argv)
    if args.markdown_from is not None:
        print(markdown_table(json.loads(args.markdown_from.read_text())))
        return 0
    names = args.scenes or list_scenes()
    load_at_start = load_average()
    rows = []
    header = (f"{'scene':<14}{'workers':>10}{'dim':>4}{'tris':>6}{'rays/spl':>9}{'Msamples/s':>11}"
              f"{'Mrays/s':>9}"
              f"{'raw Mrays/s':>12}{'ratio':>7}{'tracer 2T/1T':>13}{'raw 2T/1T':>10}")
    print(header)
    print("-" * len(header))
    for name in names:
        for workers in args.workers:
            r = bench_scene(name, spp=args.spp, repeats=args.repeats, threads=args.threads, size=args.size,
                            workers=workers)
            r["workers"] = workers
            rows.append(r)
            print(f"{name:<14}{workers:>10}{r['dimension']:>4}{r['triangles']:>6}{r['rays_per_sample']:>9.2f}"
                  f"{r['tracer_samples_per_s'] / 1e6:>11.3f}{r['tracer_rays_per_s'] / 1e6:>9.2f}"
                  f"{r['raw_embree_rays_per_s'] / 1e6:>12.2f}{r['ratio_tracer_to_raw']:>7.1%}"
                  f"{r['tracer_thread_speedup']:>13.2f}{r['raw_thread_speedup']:>10.2f}")
    result = {
        "command": command_line("benchmarks/bench_tracer.py", argv),
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "load_average_1_5_15min": {"start": load_at_start, "end": load_average()},
        "machine": machine_info("embreex"),
        "settings": {"spp": args.spp, "repeats": args.repeats, "threads": args.threads, "workers": args.workers,
                     "sampler": "sobol",
                     "timing": "best of repeats, wall clock"},
        "scenes": rows,
    }
    write_json(args.output, result, indent=1)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
