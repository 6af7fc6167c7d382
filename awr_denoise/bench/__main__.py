"""``python -m awr_denoise.bench``: the benchmark's command line (:mod:`awr_denoise.bench.command`)."""

from __future__ import annotations

from .command import main

if __name__ == "__main__":  # importing this module (e.g. for doctests) runs nothing
    raise SystemExit(main())
