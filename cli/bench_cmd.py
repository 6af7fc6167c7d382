"""``awr bench``: the speed/accuracy benchmark on the bundled scenes (see docs/benchmarks.md)."""

from __future__ import annotations

import argparse

from awr_denoise.bench.command import add_arguments, run_from_args

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
    return run_from_args(args)
