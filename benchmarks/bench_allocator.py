"""The ``awr`` command's allocator setting (awr_denoise/memory.py) against glibc's default, side by side.

Run from the repository root::

    .venv/bin/python benchmarks/bench_allocator.py [--size 1080p] [--repeats 3]

Each repeat starts one fresh process per setting, in alternating order: the default allocator, and the one
``awr`` sets (``keep_freed_memory``: freed whole-image arrays reused instead of mapped afresh). Each process
times three default reconstructions and three ``ask()`` of the same 8-spp buffer of the synthetic ``edges``
scene, and reports its minor page faults and peak memory. Medians over the repeats: the first call (a fresh
process) and the later ones. Results: ``benchmarks/results/allocator.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

from awr_denoise.bench import update_section
from awr_denoise.bench.records import results_file

RESULTS = Path(__file__).resolve().parent / "results" / "allocator.json"
SIZES = {"256x256": (256, 256), "1080p": (1080, 1920)}
SETTINGS = ("glibc default", "awr's setting")

_ONE_PROCESS = """
import json, resource, sys, time
keep = sys.argv[1] == "keep"
if keep:
    from awr_denoise.memory import keep_freed_memory
    assert keep_freed_memory(), "not glibc, or the allocator is set in the environment"
from awr_denoise import AdaptiveSampler, SampleRequest, reconstruct
from awr_denoise.synthetic import SyntheticRenderer, make_scene
shape = (int(sys.argv[2]), int(sys.argv[3]))
buffer = SyntheticRenderer(make_scene("edges", shape), seed=1)(SampleRequest.uniform(shape, 8))
out = {"reconstruct": [], "ask": []}
faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(3):
    start = time.perf_counter(); reconstruct(buffer); out["reconstruct"].append(time.perf_counter() - start)
for _ in range(3):
    sampler = AdaptiveSampler.from_buffer(buffer, round=4)
    start = time.perf_counter(); sampler.ask(); out["ask"].append(time.perf_counter() - start)
usage = resource.getrusage(resource.RUSAGE_SELF)
out["minor_faults"] = usage.ru_minflt - faults
out["peak_mb"] = usage.ru_maxrss / 1024
print(json.dumps(out))
"""


def one_process(keep: bool, shape: tuple[int, int]) -> dict[str, Any]:
    """The timings of one fresh process; the environment's allocator variables removed for both settings."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k not in ("GLIBC_TUNABLES",)}
    run = subprocess.run([sys.executable, "-c", _ONE_PROCESS, "keep" if keep else "default", *map(str, shape)],
                         capture_output=True, text=True, env=env, check=True)
    return json.loads(run.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", choices=tuple(SIZES), default="1080p")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--output", type=results_file, default=RESULTS)
    args = parser.parse_args(argv)
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in SETTINGS}
    for repeat in range(args.repeats):
        order = SETTINGS if repeat % 2 == 0 else SETTINGS[::-1]
        for name in order:
            runs[name].append(one_process(name == SETTINGS[1], SIZES[args.size]))
    rows = []
    print(f"| {args.size}, {args.repeats} processes each | reconstruct, first | reconstruct, later | "
          "ask(), first | ask(), later | minor faults | peak memory |")
    print("|---|---|---|---|---|---|---|")
    for name, found in runs.items():
        row = {"setting": name, "size": args.size, "repeats": args.repeats}
        for what in ("reconstruct", "ask"):
            row[f"{what}_first_s"] = float(np.median([r[what][0] for r in found]))
            row[f"{what}_later_s"] = float(np.median([t for r in found for t in r[what][1:]]))
        row["minor_faults"] = float(np.median([r["minor_faults"] for r in found]))
        row["peak_mb"] = float(np.median([r["peak_mb"] for r in found]))
        rows.append(row)
        print(f"| {name} | {row['reconstruct_first_s']:.2f} s | {row['reconstruct_later_s']:.2f} s | "
              f"{row['ask_first_s']:.3f} s | {row['ask_later_s']:.3f} s | {row['minor_faults']:.0f} | "
              f"{row['peak_mb']:.0f} MB |", flush=True)
    shown = " ".join(argv if argv is not None else sys.argv[1:])
    update_section(args.output, args.size, rows, f"benchmarks/bench_allocator.py {shown}".strip())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
