"""``awr render --seconds S`` end to end: how long the whole command takes against ``S``.

Run from the repository root::

    .venv/bin/python benchmarks/bench_budget.py                       # about 12 minutes
    .venv/bin/python benchmarks/bench_budget.py --renderers tracer --repeats 1

Each case runs the command as a user does (a new process: ``awr render --seconds S`` on a scene at a size,
writing the dump, the denoised image and the preview into a fresh folder) and reads the two times it prints:
the rounds' (from the command's start, the renderer's setup included) and the denoising's and the files'. The
budget covers both: the rounds leave the denoising the time its trial on round 0's samples predicted
(``rounds.reconstruction_seconds`` with the command's settings, times ``1 + WRITE_SHARE`` for the files).
Python's start-up comes before the command starts and is not in ``S``: it is measured in the same run as the
wall time of ``awr --version`` (the floor), and the wall time of each render is reported beside it. Cases run
``--repeats`` times (3), interleaved; medians. The command runs on its default ``--threads`` (2, or 1 on one CPU)
unless this script's ``--threads`` says otherwise. Results: ``benchmarks/results/budget.json``.

``--trial`` measures what the prediction rests on instead (section ``trial``): on 2-spp uniform buffers of the
tracer's default scene at each size, the default reconstruction of the whole image against four times its
central quarter's (``RESERVE_MARGIN``), writing the dump, the image and the preview against the reconstruction
(``WRITE_SHARE``), and ``reconstruction_seconds``' estimate against both together; ``--repeats`` times
interleaved, medians; the reconstructions on the threads ``awr render`` gives them (``--threads``). Each repeat
is a new process that does what the command does, in its order: the memory setting ``awr`` makes when it starts
(``awr_denoise/memory.py``; ``--allocator glibc`` leaves glibc's default, as a Python caller has it), the
estimate on the central quarter (the process' first reconstruction), the whole reconstruction, the files.
"""

from __future__ import annotations

import argparse
import functools
import json
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from awr_denoise import SampleRequest, reconstruct_detailed
from awr_denoise.bench import update_section
from awr_denoise.bench.records import results_file
from awr_denoise.cli.parallel_options import library_threads, threads_from_args
from awr_denoise.io import read_sample_buffer, write_image, write_preview, write_sample_buffer
from awr_denoise.memory import keep_freed_memory
from awr_denoise.renderers import create_renderer
from awr_denoise.rounds import reconstruction_seconds

RESULTS = Path(__file__).resolve().parent / "results" / "budget.json"
CASES: dict[str, list[tuple[str, tuple[int, int], float]]] = {
    "tracer": [("default", (256, 256), 5.0), ("default", (512, 512), 10.0), ("default", (1920, 1080), 30.0),
               ("default", (3840, 2160), 120.0)],
    "mitsuba": [("cornell_box", (256, 256), 5.0), ("cornell_box", (1920, 1080), 30.0)],
    "synthetic": [("edges", (64, 64), 1.0)],
}
"""(scene, (width, height), S) per renderer (``synthetic``: the script's test, not run by default)."""
TRIAL_SIZES = ("256x256", "512x512", "1920x1080", "3840x2160")
""":func:`trial`'s sizes by default."""
_STATUS = re.compile(r"([0-9.]+) spp \(awr\) in ([0-9.]+) s; .* in ([0-9.]+) s")
"""The command's last line: spp, the rounds' seconds, the denoising's and the files' seconds."""


def _awr(*args: str) -> tuple[subprocess.CompletedProcess, float]:
    """Run ``awr`` in a new process as a user does; (the finished process, its wall time)."""
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", "import sys; from cli.main import main; sys.exit(main())", *args],
                          capture_output=True, text=True, check=False)
    return done, time.perf_counter() - started


def render(renderer: str, scene: str, size: tuple[int, int], seconds: float, seed: int, threads: int | None = None
           ) -> dict[str, Any]:
    """One ``awr render --seconds`` run (on ``--threads``, else the command's default): its printed times and its
    wall time."""
    with tempfile.TemporaryDirectory() as folder:
        done, wall = _awr("render", scene, "--renderer", renderer, "--width", str(size[0]), "--height", str(size[1]),
                          "--seconds", str(seconds), "--seed", str(seed), "-o", str(Path(folder) / "dump.exr"),
                          *(() if threads is None else ("--threads", str(threads))))
    if done.returncode != 0:
        raise RuntimeError(f"awr render {renderer} {scene}: exit {done.returncode}: {done.stderr.strip()}")
    found = _STATUS.search(done.stderr)
    if found is None:
        raise RuntimeError(f"awr render {renderer} {scene}: no status line in {done.stderr!r}")
    spp, rounds, finish = map(float, found.groups())
    warned = [line for line in done.stderr.splitlines() if "warning" in line]
    return {"spp": spp, "rounds": rounds, "finish": finish, "command": rounds + finish, "wall": wall,
            "warnings": warned}


def measure(renderers: list[str], repeats: int, threads: int | None = None) -> list[dict[str, Any]]:
    """Every case of ``renderers``, ``repeats`` times interleaved, on ``threads`` (the command's default for
    ``None``); per case the medians and the runs."""
    cases = [(r, *case) for r in renderers for case in CASES[r]]
    runs: dict[int, list[dict[str, Any]]] = {i: [] for i in range(len(cases))}
    floors = []
    for k in range(repeats):
        floors.append(_awr("--version")[1])
        for i, (renderer, scene, size, seconds) in enumerate(cases):
            runs[i].append(render(renderer, scene, size, seconds, seed=k, threads=threads))
    floor = statistics.median(floors)
    rows = []
    for i, (renderer, scene, size, seconds) in enumerate(cases):
        median = {key: statistics.median(run[key] for run in runs[i])
                  for key in ("spp", "rounds", "finish", "command", "wall")}
        rows.append({"renderer": renderer, "scene": scene, "size": list(size), "seconds": seconds,
                     "threads": threads_from_args(argparse.Namespace(threads=threads)), **median,
                     "command_over_budget": median["command"] / seconds, "startup": floor,
                     "worst_over_budget": max(run["command"] for run in runs[i]) / seconds, "runs": runs[i]})
    return rows


def _seconds(work: Any, *args: Any) -> float:
    started = time.perf_counter()
    work(*args)
    return time.perf_counter() - started


def _files(buffer: Any, image: Any) -> None:
    """Write what ``awr render`` writes: the dump, the denoised image and its preview."""
    with tempfile.TemporaryDirectory() as folder:
        write_sample_buffer(Path(folder) / "dump.exr", buffer)
        write_image(Path(folder) / "dump.denoised.exr", image)
        write_preview(Path(folder) / "dump.denoised.png", image)


ALLOCATORS = ("command", "glibc")
"""``--allocator``: the memory setting ``awr`` makes when it starts (``awr_denoise/memory.py``), or glibc's default."""


def trial(sizes: list[tuple[int, int]], repeats: int, threads: int | None = None, allocator: str = "command"
          ) -> list[dict[str, Any]]:
    """Per size: the whole reconstruction over four quarters', the files over the reconstruction, the estimate
    over both (2-spp uniform buffers of the tracer's default scene; medians of ``repeats``, interleaved, each a
    new process: :func:`trial_once`), the reconstruction on ``threads`` as ``awr render --threads`` runs it (the
    command's default for ``None``) and with ``allocator``'s memory setting."""
    count = threads_from_args(argparse.Namespace(threads=threads))
    found: list[dict[str, list[float]]] = [{} for _ in sizes]
    applied = set()
    with tempfile.TemporaryDirectory() as folder:
        dumps = []
        for width, height in sizes:
            renderer = create_renderer("tracer", "default", shape=(height, width), seed=0)
            dumps.append(Path(folder) / f"{width}x{height}.exr")
            write_sample_buffer(dumps[-1], renderer(SampleRequest.uniform((height, width), 2)))
        for _ in range(repeats):
            for dump, seen in zip(dumps, found):
                done = subprocess.run([sys.executable, __file__, "--trial-once", str(dump), "--threads", str(count),
                                       "--allocator", allocator], capture_output=True, text=True, check=False)
                if done.returncode != 0:
                    raise RuntimeError(f"trial of {dump.name}: exit {done.returncode}: {done.stderr.strip()}")
                times = json.loads(done.stdout)
                applied.add(times.pop("allocator"))
                for key, value in times.items():
                    seen.setdefault(key, []).append(value)
    rows = []
    for (width, height), seen in zip(sizes, found):
        median = {key: statistics.median(values) for key, values in seen.items()}
        rows.append({"size": [width, height], **median, "runs": seen,
                     "whole_over_quarters": median["whole"] / (4 * median["quarter"]),
                     "files_over_whole": median["files"] / median["whole"],
                     "estimate_over_both": median["estimate"] / (median["whole"] + median["files"])})
    (used,) = applied  # the same in every process: the environment is this script's
    return [{**row, "threads": count, "allocator": used} for row in rows]


def trial_once(dump: Path, threads: int, allocator: str) -> dict[str, Any]:
    """One repeat of the trial, in this (new) process, in the command's order: ``allocator``'s memory setting,
    the estimate (its quarter's reconstruction the process' first), the whole reconstruction, the files. The
    quarter's time is that of the reconstruction the estimate timed, scaled to a quarter of the pixels (it times
    a buffer under ``WHOLE_BELOW`` pixels whole)."""
    kept = allocator == "command" and keep_freed_memory()
    buffer = read_sample_buffer(dump)
    h, w = buffer.shape
    timed: list[tuple[int, float]] = []  # (pixels, seconds) of each reconstruction the estimate ran
    with library_threads(threads) as pool:
        denoise = functools.partial(reconstruct_detailed, variance_probes=0, executor=pool)

        def estimated(part: Any) -> Any:
            started = time.perf_counter()
            result = denoise(part)
            timed.append((part.shape[0] * part.shape[1], time.perf_counter() - started))
            return result

        estimate = reconstruction_seconds(buffer, estimated)
        started = time.perf_counter()
        image = denoise(buffer).image
        whole = time.perf_counter() - started
    pixels, seconds = timed[-1]  # the one it scaled: its quarter's, or the whole image's
    return {"whole": whole, "quarter": seconds * (h * w / 4) / pixels, "files": _seconds(_files, buffer, image),
            "estimate": estimate, "allocator": "command" if kept else "glibc"}


def trial_table(rows: list[dict[str, Any]]) -> str:
    """The trial's rows as a Markdown table."""
    lines = ["| size | threads | memory | reconstruction s | whole / 4 quarters | files / reconstruction | estimate / "
             "(reconstruction + files) |", "|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['size'][0]}x{row['size'][1]} | {row['threads']} | {row['allocator']} | "
                     f"{row['whole']:.2f} | "
                     f"{row['whole_over_quarters']:.2f} | "
                     f"{row['files_over_whole']:.2f} | {row['estimate_over_both']:.2f} |")
    return "\n".join(lines)


def table(rows: list[dict[str, Any]]) -> str:
    """The rows as a Markdown table."""
    lines = ["| renderer | scene | size | threads | S | spp | rounds s | denoise + files s | command / S (worst) | "
             "wall s (start-up) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['renderer']} | {row['scene']} | {row['size'][0]}x{row['size'][1]} | {row['threads']} "
                     f"| {row['seconds']:g} "
                     f"| {row['spp']:.3g} | {row['rounds']:.1f} | {row['finish']:.1f} | "
                     f"{row['command_over_budget']:.2f} ({row['worst_over_budget']:.2f}) | {row['wall']:.1f} "
                     f"({row['startup']:.1f}) |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--renderers", nargs="+", choices=list(CASES), default=["tracer", "mitsuba"])
    parser.add_argument("--repeats", type=int, default=3, metavar="N", help="runs of each case, interleaved (3)")
    parser.add_argument("--trial", nargs="*", metavar="WxH",
                        help="instead: what the prediction rests on, at these sizes (default 256x256 512x512 "
                             "1920x1080 3840x2160; section trial)")
    parser.add_argument("--threads", type=int, choices=range(1, 65), metavar="N",
                        help="awr render's --threads, and the trial's (default: the command's own, 2 or 1 on one CPU)")
    parser.add_argument("--allocator", choices=ALLOCATORS, default="command",
                        help="the trial's memory: awr's setting (command, default) or glibc's default (glibc)")
    parser.add_argument("--trial-once", type=Path, help=argparse.SUPPRESS)  # one repeat's new process
    parser.add_argument("--output", type=results_file, default=RESULTS)
    args = parser.parse_args(argv)
    if args.trial_once is not None:
        print(json.dumps(trial_once(args.trial_once, args.threads or 1, args.allocator)))
        return 0
    if not 1 <= args.repeats <= 99:
        parser.error("--repeats: 1 to 99")
    command = "benchmarks/bench_budget.py " + " ".join(sys.argv[1:] if argv is None else argv)
    if args.trial is not None:
        try:
            sizes = [tuple(int(side) for side in size.split("x")) for size in args.trial or TRIAL_SIZES]
        except ValueError:
            parser.error("--trial: sizes as WxH")
        if any(len(size) != 2 or min(size) < 16 for size in sizes):
            parser.error("--trial: sizes as WxH, each side at least 16")
        rows = trial(sizes, args.repeats, args.threads, args.allocator)
        update_section(args.output, "trial", rows, command)
        print(trial_table(rows))
        return 0
    rows = measure(args.renderers, args.repeats, args.threads)
    update_section(args.output, "budget", rows, command)
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
