"""Peak memory of ``reconstruct`` and of one ``AdaptiveSampler.ask()`` at 4K and 8K (RGB).

Each measurement runs in a fresh subprocess so that one case's caches (the wavelet operators
are cached per shape) and freed-but-kept arenas do not leak into the next. Two figures are
reported per case:

* ``tracemalloc_peak``: the peak of Python/numpy allocations *above* what was live once the
  input buffer had been built (numpy registers its data buffers with tracemalloc; the sparse
  wavelet operators are numpy arrays too), i.e. the working memory of the call;
* ``maxrss``: the process' peak resident set size (``resource.getrusage``), which also holds
  the interpreter, the libraries and the input buffer itself.

Ratios are given against ``SampleBuffer.nbytes`` (count int64 + mean and variance float64 per
channel + a bool mask: 57 bytes per RGB pixel) and against a float32 RGB image (12 bytes per
pixel), the size of the image a renderer would write.

Usage::

    python benchmarks/bench_memory.py                 # 4K and 8K, writes benchmarks/results/memory.json
    python benchmarks/bench_memory.py --sizes 4k      # one size
    python benchmarks/bench_memory.py --sizes 512x256 # any WxH (for a quick check)
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from awr_denoise import AdaptiveSampler, SampleBuffer, reconstruct
from awr_denoise.bench import command_line, machine_info, peak_memory, write_json
from awr_denoise.bench.records import results_file

SIZES = {"4k": (3840, 2160), "8k": (7680, 4320)}
RESULTS = Path(__file__).resolve().parent / "results" / "memory.json"


def _build_buffer(width: int, height: int) -> SampleBuffer:
    """A buffer built with as little transient memory as possible (float32 planes, freed at once).

    Not :func:`awr_denoise.bench.noisy_buffer`: at 8K its float64 planes and blur would raise
    the process' peak RSS, which this benchmark reports.
    """
    rng = np.random.default_rng(1)
    count = np.full((height, width), 8, np.int64)
    # A smooth gradient plus noise: the content does not change the memory, only the shape.
    ramp = np.linspace(0.1, 2.0, width, dtype=np.float32)[None, :, None]
    mean = np.broadcast_to(ramp, (height, width, 3)) + 0.05 * rng.standard_normal((height, width, 3), np.float32)
    variance = np.full((height, width, 3), 0.02, np.float32)
    buf = SampleBuffer.from_moments(count, mean, variance)
    del mean, variance, count
    return buf


def _child(op: str, width: int, height: int) -> dict:
    """Runs inside the subprocess: one measurement, printed as JSON."""
    buf = _build_buffer(width, height)

    def run() -> float:
        t0 = time.perf_counter()
        if op == "reconstruct":
            out = reconstruct(buf)
            assert np.isfinite(out).all()
            del out
        elif op == "ask":
            sampler = AdaptiveSampler.from_buffer(buf, round=1)
            request = sampler.ask(budget=width * height)  # one round of 1 spp
            assert request.total == width * height
            del request, sampler
        else:  # pragma: no cover
            raise ValueError(op)
        return time.perf_counter() - t0

    gc.collect()
    seconds, peak = peak_memory(run)
    maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB on Linux
    return {"op": op, "width": width, "height": height, "channels": 3,
            "buffer_bytes": buf.nbytes, "image_f32_bytes": width * height * 3 * 4,
            "tracemalloc_peak_bytes": peak, "maxrss_bytes": maxrss, "seconds": seconds}


def _parse_size(text: str) -> tuple[str, int, int]:
    key = text.lower()
    if key in SIZES:
        return key, *SIZES[key]
    w, h = key.split("x")
    return key, int(w), int(h)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=["4k", "8k"], help="4k, 8k or WxH")
    parser.add_argument("--ops", nargs="+", default=["reconstruct", "ask"], choices=["reconstruct", "ask"])
    parser.add_argument("--output", type=results_file, default=RESULTS)
    parser.add_argument("--child", nargs=3, metavar=("OP", "W", "H"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(_child(args.child[0], int(args.child[1]), int(args.child[2]))))
        return 0
    rows = []
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parent.parent)
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    for size in args.sizes:
        label, w, h = _parse_size(size)
        for op in args.ops:
            proc = subprocess.run([sys.executable, __file__, "--child", op, str(w), str(h)],
                                  capture_output=True, text=True, env=env, check=False)
            if proc.returncode != 0:
                print(proc.stderr, file=sys.stderr)
                return 1
            row = json.loads(proc.stdout.strip().splitlines()[-1])
            row["size"] = label
            rows.append(row)
            _print_row(row, header=len(rows) == 1)
    meta = {"command": command_line("benchmarks/bench_memory.py", argv), **machine_info()}
    write_json(args.output, {"meta": meta, "results": rows}, indent=2)
    print(f"wrote {args.output}")
    return 0


def _print_row(row: dict, header: bool) -> None:
    gib = 1024.0**3
    if header:
        print(f"{'size':>6} {'op':>12} {'buffer GiB':>10} {'peak GiB':>9} {'x buffer':>8} "
              f"{'x f32 img':>9} {'maxrss GiB':>10} {'s':>7}")
    print(f"{row['size']:>6} {row['op']:>12} {row['buffer_bytes'] / gib:>10.2f} "
          f"{row['tracemalloc_peak_bytes'] / gib:>9.2f} {row['tracemalloc_peak_bytes'] / row['buffer_bytes']:>8.2f} "
          f"{row['tracemalloc_peak_bytes'] / row['image_f32_bytes']:>9.2f} {row['maxrss_bytes'] / gib:>10.2f} "
          f"{row['seconds']:>7.1f}", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
