"""``awr bench``: the speed/accuracy benchmark on the bundled scenes (see docs/benchmarks.md)."""

from __future__ import annotations

import argparse

__all__ = ["register", "run"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``bench`` sub-parser to ``sub``."""
    from awr_denoise.benchmark import add_arguments

    p = sub.add_parser("bench", help="measure error against spp and time on the bundled scenes",
                       description="Render the bundled scenes uniformly and adaptively, reconstruct them with AWR "
                                   "and the peer denoisers, and write docs/benchmarks.md, its figures and the raw "
                                   "numbers as JSON. Needs the tracer and bench extras.")
    add_arguments(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run ``awr bench``; returns the exit status."""
    from awr_denoise.benchmark import run_from_args

    return run_from_args(args)
