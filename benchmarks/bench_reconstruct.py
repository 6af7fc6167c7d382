"""Speed of the default reconstruction against stage 1 alone (the previous default), side by side.

Run from the repository root::

    .venv/bin/python benchmarks/bench_reconstruct.py                 # 128x128, 256x256, 1080p
    .venv/bin/python benchmarks/bench_reconstruct.py --sizes 128x128 --repeats 5

Every variant is timed on the same buffer in interleaved rounds (one call of each per round),
and the table gives median seconds and the ratio to stage 1 alone measured in the same rounds:
on a shared machine only such ratios mean much. Writes ``benchmarks/results/reconstruct.json``.
The buffers are 8-spp renders of the synthetic ``edges`` scene (the time does not depend on
the content).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from awr_denoise import SampleRequest, reconstruct
from awr_denoise.bench import machine_info, write_json
from awr_denoise.synthetic import SyntheticRenderer, make_scene

RESULTS = Path(__file__).resolve().parent / "results" / "reconstruct.json"
SIZES = {"128x128": (128, 128), "256x256": (256, 256), "1080p": (1080, 1920)}
VARIANTS = {
    "stage 1 alone": {"stages": 1},
    "default": {},
    "default, float64 FFTs": {"precision": "float64"},
    "default without the guard": {"guard": False},
    "three Wiener stages": {"stages": 4, "wiener_exponents": (0.75, 0.5, 0.4)},
}


def timings(shape: tuple[int, int], repeats: int) -> dict[str, float]:
    """Median seconds of every variant over ``repeats`` interleaved rounds (after one warm-up)."""
    scene = make_scene("edges", shape)
    buffer = SyntheticRenderer(scene, seed=1)(SampleRequest.uniform(shape, 8))
    seconds: dict[str, list[float]] = {name: [] for name in VARIANTS}
    for round_ in range(repeats + 1):
        for name, options in VARIANTS.items():
            start = time.perf_counter()
            reconstruct(buffer, **options)
            if round_:  # the first round builds and caches the transforms' operators
                seconds[name].append(time.perf_counter() - start)
    return {name: float(np.median(values)) for name, values in seconds.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", choices=tuple(SIZES), default=list(SIZES))
    parser.add_argument("--repeats", type=int, default=0, help="rounds per size (default 9, 3 at 1080p)")
    args = parser.parse_args(argv)
    rows = []
    print("| image | " + " | ".join(VARIANTS) + " |")
    print("|---|" + "---|" * len(VARIANTS))
    for name in args.sizes:
        repeats = args.repeats or (3 if name == "1080p" else 9)
        medians = timings(SIZES[name], repeats)
        base = medians["stage 1 alone"]
        rows.append({"size": name, "repeats": repeats, "seconds": medians,
                     "ratio": {k: v / base for k, v in medians.items()}})
        print(f"| {name} | " + " | ".join(f"{v:.3f} s ({v / base:.2f}x)" for v in medians.values()) + " |", flush=True)
    write_json(RESULTS, {"machine": machine_info(), "command": "benchmarks/bench_reconstruct.py", "sizes": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
