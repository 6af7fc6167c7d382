"""Frames on a local Dask cluster whose worker is killed mid-run: how often the run ends, fails or hangs.

Run from the repository root (needs the extra ``dask``)::

    .venv/bin/python benchmarks/soak_dask_worker_loss.py --runs 20

Each run writes ``--frames`` small dumps (64x64, 8 spp) once, denoises them with
:func:`awr_denoise.parallel.denoise_frames` on a local cluster of two worker processes, and SIGKILLs
one worker (its nanny starts another) ``--delay`` seconds in. Every run is a child process under a
time limit: "ok" (every frame written, none reported failed), "failed" (a frame reported failed:
say which), "hung" (past ``--timeout``), and whether every output exists and is whole. A worker
killed after it wrote a frame but before the client fetched the result makes Dask run that frame
again; docs/distributed.md ("A worker lost mid-run") says what the library does then. Results:
``benchmarks/results/dask_worker_loss.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results" / "dask_worker_loss.json"


def one_run(folder: Path, frames: int, delay: float) -> None:
    """In a child process: the frames on a fresh cluster, a worker killed after ``delay`` s; prints one JSON line."""
    import numpy as np
    import psutil

    from awr_denoise import SampleBuffer
    from awr_denoise.io import read_image, write_sample_buffer
    from awr_denoise.parallel import FramesFailedError, denoise_frames, get_executor

    inputs = [folder / "in" / f"f{i:04d}.exr" for i in range(frames)]
    if not inputs[-1].exists():
        inputs[0].parent.mkdir(exist_ok=True)
        for i, path in enumerate(inputs):
            mean = 0.5 + 0.1 * np.random.default_rng(i).random((64, 64, 3))
            write_sample_buffer(path, SampleBuffer.from_moments(np.full((64, 64), 8), mean, np.full((64, 64, 3), 0.04)))
    out = Path(tempfile.mkdtemp(prefix="out-", dir=folder))
    outputs = [out / p.name for p in inputs]
    killed: dict[str, float] = {}

    def kill_a_worker() -> None:
        time.sleep(delay)
        for child in psutil.Process().children(recursive=True):
            try:
                command = " ".join(child.cmdline())
            except psutil.Error:  # gone meanwhile
                continue
            if "spawn_main" in command and "resource_tracker" not in command:  # a worker, not the tracker
                killed["written"] = sum(o.exists() for o in outputs)
                child.send_signal(signal.SIGKILL)
                return

    outcome, failed = "ok", []
    with get_executor("dask", workers=2) as executor:
        threading.Thread(target=kill_a_worker, daemon=True).start()
        try:
            denoise_frames(inputs, outputs, executor=executor)
        except FramesFailedError as error:
            outcome, failed = "failed", [f"{Path(s).name}: {type(e).__name__}" for s, e in error.failures.items()]
    whole = all(o.exists() and read_image(o).shape == (64, 64, 3) for o in outputs)
    print(json.dumps({"outcome": outcome, "failed": failed, "all_written": whole, "killed": killed}), flush=True)


def soak(runs: int, frames: int, delay: float, timeout: float) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory(prefix="awr-dask-soak-") as folder:
        for run in range(runs):
            start = time.perf_counter()
            proc = subprocess.Popen([sys.executable, __file__, "--child", folder, "--frames", str(frames),
                                     "--delay", str(delay)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                    text=True, start_new_session=True)
            try:
                out, _ = proc.communicate(timeout=timeout)
                lines = [line for line in out.splitlines() if line.startswith("{")]
                row = json.loads(lines[-1]) if lines else {"outcome": f"exit {proc.returncode}"}
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)  # the cluster's processes too
                proc.communicate()
                row = {"outcome": "hung"}
            row.update(run=run, seconds=round(time.perf_counter() - start, 1))
            print(json.dumps(row), flush=True)
            rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--delay", type=float, default=1.2, help="seconds into the run a worker is killed")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds after which a run counts as hung")
    parser.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.child is not None:
        one_run(args.child, args.frames, args.delay)
        return 0
    rows = soak(args.runs, args.frames, args.delay, args.timeout)
    counts = {k: sum(r["outcome"] == k for r in rows) for k in dict.fromkeys(r["outcome"] for r in rows)}
    written = sum(bool(r.get("all_written")) for r in rows)
    unkilled = sum(r.get("killed") == {} for r in rows)  # finished before the kill: they test nothing
    print(f"{len(rows)} runs: {counts}; every output written and whole in {written}; no worker killed in {unkilled}")
    command = "benchmarks/soak_dask_worker_loss.py " + " ".join(argv if argv is not None else sys.argv[1:])
    text = json.dumps({"command": command, "counts": counts, "all_written": written, "no_worker_killed": unkilled,
                       "rows": rows}, indent=1) + "\n"
    from awr_denoise.io.atomic import atomic_write  # the parent imports the package only here (its runs are children)
    atomic_write(args.output, lambda temporary: Path(temporary).write_text(text), overwrite=True)  # whole or none
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
