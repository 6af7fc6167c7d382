"""``awr bench``: the speed/accuracy benchmark on the bundled scenes (see docs/benchmarks.md)."""

from __future__ import annotations

import argparse

from awr_denoise.bench.command import add_arguments, run_from_args

from .common import RENDER_BYTES_PER_PIXEL, check_memory

__all__ = ["register", "run"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``bench`` sub-parser to ``sub``."""
    p = sub.add_parser("bench", help="measure error against spp and time on the bundled scenes",
                       description="Render the bundled scenes uniformly and adaptively, reconstruct them with AWR "
                                   "and the peer denoisers, and write docs/benchmarks.md, its figures and the raw "
                                   "numbers as JSON. Needs the tracer and bench extras.")
    add_arguments(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run ``awr bench``; returns the exit status."""
    if args.size:  # beyond the memory available, the out-of-memory killer ended the run without a word (exit 137)
        # Its renders are awr render's, a floor: the benchmark's own peak was 0.85 GB at 256x256 and 0.95 GB at
        # 512x512 (/usr/bin/time -f %M awr bench --quick --scenes default --spp 4 --size N N --overhead-sizes
        # --no-oidn --no-mitsuba --no-plots), about 500 bytes a pixel between them, with the modules' own beside.
        width, height = args.size
        check_memory("--size", RENDER_BYTES_PER_PIXEL * width * height, f"a benchmark at {width}x{height}")
    return run_from_args(args)
