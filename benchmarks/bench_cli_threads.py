"""``--threads``: the command line's own work on one thread and on a pool, run as a user runs it.

Run from the repository root::

    .venv/bin/python benchmarks/bench_cli_threads.py                  # about 8 minutes on a 2-core machine
    .venv/bin/python benchmarks/bench_cli_threads.py --size 640x360 --repeats 1

Each case is a command in a new process, timed by its wall clock, with ``--threads 1`` and with ``--threads N``
(``--threads`` of this script, default 2, the command line's default on two CPUs) in turn within each repeat, so a
change in the machine's load affects both alike; medians of ``--repeats`` (3). The floor, measured in the same run,
is the wall time of ``awr --version``: Python's start-up and the imports, which no thread shortens. The cases:

* ``denoise``: ``awr denoise`` of one frame, a uniform 8-spp dump of the bundled tracer's default scene rendered once
  before the timings (at the size of ``--size``, default 1920x1080);
* ``plan``: what ``awr plan`` does with the next adaptive round of a running dump (an 8-spp adaptive render of the
  same scene, also made once), in a new process: read the dump, one ``ask()`` of an ``AdaptiveSampler`` resumed
  from it, on a pool or not, write the request. ``awr plan`` itself has no ``--threads``: this case is why;
* ``render``: ``awr render --adaptive --spp 8`` of the same scene, the rounds' ranking between the tracer's rounds and
  the reconstruction at the end, the tracer's own threads as they are (its default, one per CPU).

The files each command writes are the same bit for bit on any number of threads (``tests/cli/test_parallel_options.py``
checks that); this script times them. Results: ``benchmarks/results/cli_threads.json``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from awr_denoise.bench import command_line, load_average, machine_info, write_json
from awr_denoise.bench.records import results_file
from awr_denoise.bench.measure import awr_command

RESULTS = Path(__file__).resolve().parent / "results" / "cli_threads.json"
CASES = ("denoise", "plan", "render")


PLAN = """
import sys
from awr_denoise.cli.common import dumped_round
from awr_denoise.cli.parallel_options import library_threads
from awr_denoise.io import read_sample_dump, write_request
from awr_denoise.sampling import AdaptiveSampler

dump = read_sample_dump(sys.argv[1])
with library_threads(int(sys.argv[-1])) as pool:  # after --threads
    sampler = AdaptiveSampler.from_buffer(dump.buffer, round=dumped_round(sys.argv[1], dump.attributes),
                                          issued=dump.issued, executor=pool)
    write_request(sys.argv[2], sampler.ask(), overwrite=True)
"""
"""``awr plan``'s work on a pool (``--threads`` its last argument), which the command does not offer."""


def _shown(command: list[str]) -> str:
    """``command`` as the results and the errors name it: ``awr ...``, or ``python -c PLAN ...``."""
    awr = awr_command()
    if command[:len(awr)] == awr:
        return "awr " + " ".join(command[len(awr):])
    return "python -c PLAN " + " ".join(command[3:]) + " (benchmarks/bench_cli_threads.py)"


def _run(command: list[str], cwd: Path) -> float:
    """The wall time of ``command`` in ``cwd``; a failing command is an error, not a time."""
    start = time.perf_counter()
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{_shown(command)}: exit {done.returncode}: {done.stderr.strip()}")
    return wall


def _scene(size: str) -> list[str]:
    """The bundled tracer's default scene at ``size`` (WxH)."""
    width, height = size.split("x")
    return ["--scene", "default", "--width", width, "--height", height]


def _commands(size: str, spp: int) -> dict[str, list[str]]:
    """Each case's command, run in the folder of its inputs."""
    scene = _scene(size)
    return {
        "denoise": [*awr_command(), "denoise", "uniform.exr", "-o", "out.exr", "-q", "--overwrite"],
        "plan": [sys.executable, "-c", PLAN, "running.exr", "request.exr"],
        "render": [*awr_command(), "render", *scene, "--spp", str(spp), "--adaptive", "-o", "render.exr", "-q",
                   "--overwrite"],
    }


def measure(size: str, spp: int, threads: int, repeats: int, cases: tuple[str, ...]) -> dict[str, Any]:
    """The medians of every case on one thread and on ``threads``, and the floor, in one run."""
    scene, commands = _scene(size), _commands(size, spp)
    rows: dict[str, dict[str, list[float]]] = {case: {"1": [], str(threads): []} for case in cases}
    floor: list[float] = []
    with tempfile.TemporaryDirectory(prefix="awr-bench-threads-") as folder:
        work = Path(folder)
        # The inputs, once (not timed): a uniform dump and a running adaptive one.
        for kind, name in (("--uniform", "uniform.exr"), ("--adaptive", "running.exr")):
            _run([*awr_command(), "render", *scene, "--spp", str(spp), kind, "-o", name, "-q", "--threads", "1"], work)
        for case in cases:  # a warm-up run of each (the file system's caches), not timed
            _run([*commands[case], "--threads", "1"], work)
        for _ in range(repeats):
            floor.append(_run([*awr_command(), "--version"], work))
            for case in cases:
                for count in rows[case]:
                    rows[case][count].append(_run([*commands[case], "--threads", count], work))
    base = statistics.median(floor)
    results = []
    for case in cases:
        one, many = (statistics.median(rows[case][count]) for count in rows[case])
        results.append({"case": case, "timed": _shown(commands[case]) + " --threads N", "runs": rows[case],
                         "one_thread": one, "threads": many, "speed_up": one / many,
                         "speed_up_above_the_floor": (one - base) / (many - base)})
    return {"size": size, "spp": spp, "pool": threads, "repeats": repeats, "floor": base, "floor_runs": floor,
            "rows": results}


def _table(result: dict[str, Any]) -> str:
    pool = result["pool"]
    lines = [f"| command ({result['size']}, {result['spp']} spp) | --threads 1 (s) | --threads {pool} (s) | "
             "speed-up | speed-up above the floor |", "|---|---|---|---|---|"]
    for row in result["rows"]:
        lines.append(f"| `{row['case']}` | {row['one_thread']:.2f} | {row['threads']:.2f} | {row['speed_up']:.2f}x | "
                     f"{row['speed_up_above_the_floor']:.2f}x |")
    lines.append(f"| floor: `awr --version` | {result['floor']:.2f} | | | |")
    return "\n".join(lines)


def _size(text: str) -> str:
    parts = text.split("x")
    if len(parts) != 2 or not all(p.isdigit() and 8 <= int(p) <= 8192 for p in parts):
        raise argparse.ArgumentTypeError(f"expected WxH, each side 8-8192, got {text!r}")
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=_size, default="1920x1080", metavar="WxH", help="image size (1920x1080)")
    parser.add_argument("--spp", type=int, default=8, choices=range(2, 257), metavar="N",
                        help="samples per pixel of the dumps and the render (8)")
    parser.add_argument("--threads", type=int, default=2, choices=range(2, 65), metavar="N",
                        help="the pool timed against one thread (2)")
    parser.add_argument("--repeats", type=int, default=3, choices=range(1, 101), metavar="N", help="runs per case (3)")
    parser.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES), help="the commands timed (all)")
    parser.add_argument("--output", type=results_file, default=RESULTS, help=f"JSON results (default {RESULTS.name})")
    args = parser.parse_args(argv)
    before = load_average()
    result = measure(args.size, args.spp, args.threads, args.repeats, tuple(args.cases))
    result.update(command=command_line("benchmarks/bench_cli_threads.py", argv), machine=machine_info(),
                  load_average={"start": before, "end": load_average()})
    write_json(args.output, result)
    print(_table(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
