"""Fuzz the EXR readers and the ``awr`` command line with random and mutated files.

Every case is a file derived from a small valid seed (an awr sample dump, a pbrt-style dump,
a plain image, a deep per-sample dump, a request map; each written uncompressed and
compressed) by one mutation: truncation, a wrong magic number, flipped bits, overwritten
words (0, -1, 2**31-1, random), inserted or deleted bytes, a huge declared data window,
random garbage, an empty file, or a structural change written through OpenEXR itself (wrong
channel types, NaN/Inf/negative planes, fractional counts, deep channels whose per-pixel
sample counts disagree, deep parts without their semantics attribute).

Each case goes through the readers (``read_sample_buffer``, ``read_sample_dump``,
``read_image``, ``read_deep_samples``, ``read_request``, ``read_header``) and through
``awr info`` and ``awr denoise`` in-process (``main(argv)``). The contract checked:

* a reader either returns finite statistics or raises ``InputFileError``: any other exception
  is a failure;
* ``awr`` exits 0, or exits 2 with exactly one stderr line ``awr: error: ...`` and no
  traceback; exit 1 or another code is a failure;
* a failed ``awr denoise`` leaves no output file and no temporary file behind;
* the input file is byte-identical afterwards (SHA-256);
* a case finishes within ``--timeout`` seconds (SIGALRM in-process; the soak also runs its
  chunks in child processes with an address-space limit, so a hang or a crash in C code is
  caught and the case saved).

Cases are a pure function of ``(seed, index)``; a failing case is written to the failures
directory with a JSON note, for a regression test in ``tests/data/fuzz_regressions/``.

Usage::

    python benchmarks/fuzz_soak.py --cases 10000            # the long local soak
    python benchmarks/fuzz_soak.py --cases 200 --seed 7     # another stream
    python benchmarks/fuzz_soak.py --replay FILE.exr        # one saved case, verbosely
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import awr_denoise.io as awr_io  # readers looked up at call time: a test substitutes a broken one
from awr_denoise import SampleBuffer, SampleRequest
from awr_denoise.bench import command_line, write_json
from awr_denoise.cli.main import main as awr_main
from awr_denoise.errors import InputFileError, InputFileWarning

DEFAULT_TIMEOUT = 20.0
MEMORY_LIMIT = 4 * 1024**3  # address space of soak children: a huge allocation fails, not the machine

MUTATIONS = ("valid", "truncate", "magic", "flip_bits", "overwrite_word", "insert_bytes", "delete_bytes",
             "huge_window", "garbage", "empty", "channel_type", "bad_values", "deep_inconsistent",
             "deep_no_semantics", "png_named_exr")


# ---------------------------------------------------------------------------- seeds
def _openexr_write(path: Path, channels: dict, header: dict | None = None, *, deep: bool = False,
                   compression: str = "none") -> None:
    import OpenEXR  # optional extra "exr", imported lazily

    comp = {"none": OpenEXR.NO_COMPRESSION, "zip": OpenEXR.ZIP_COMPRESSION, "zips": OpenEXR.ZIPS_COMPRESSION,
            "rle": OpenEXR.RLE_COMPRESSION, "piz": OpenEXR.PIZ_COMPRESSION}[compression]
    attrs = {"compression": comp, "type": OpenEXR.deepscanline if deep else OpenEXR.scanlineimage}
    attrs.update(header or {})
    with OpenEXR.File(attrs, channels) as f:
        f.write(str(path))


def _seed_buffer(shape=(5, 4), seed=0):
    rng = np.random.default_rng(seed)
    h, w = shape
    count = rng.integers(0, 9, shape)
    count[0, 0] = 4
    mean = rng.random((h, w, 3))
    var = rng.random((h, w, 3)) * 0.1
    buf = SampleBuffer.from_moments(count, mean, var)
    return SampleBuffer(buf.count, buf.mean, buf.variance, buf.channels, buf.variance_known, 3)


def write_seeds(directory: Path) -> dict[str, Path]:
    """The valid seed files every case is derived from (a few hundred bytes to a few KiB)."""
    directory.mkdir(parents=True, exist_ok=True)
    seeds: dict[str, Path] = {}
    buf = _seed_buffer()
    h, w = buf.shape
    seeds["awr_zip"] = awr_io.write_sample_buffer(directory / "awr_zip.exr", buf, header={"awr:round": 2})
    f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
    awr_planes = {"sampleCount": np.ascontiguousarray(buf.count.astype(np.uint32))}
    for i, c in enumerate("RGB"):
        awr_planes[c] = f32(buf.mean[..., i])
        awr_planes[f"variance.{c}"] = f32(buf.variance[..., i])
    _openexr_write(directory / "awr_none.exr", awr_planes, {"awr:semantics": "sample-statistics"})
    seeds["awr_none"] = directory / "awr_none.exr"
    pbrt = {c: f32(buf.mean[..., i]) for i, c in enumerate("RGB")}
    pbrt.update({f"Variance.{c}": f32(buf.variance[..., i]) for i, c in enumerate("RGB")})
    _openexr_write(directory / "pbrt_none.exr", pbrt, {"samplesPerPixel": 8})
    seeds["pbrt_none"] = directory / "pbrt_none.exr"
    _openexr_write(directory / "pbrt_rle.exr", pbrt, {"samplesPerPixel": 8}, compression="rle")
    seeds["pbrt_rle"] = directory / "pbrt_rle.exr"
    half = {c: np.ascontiguousarray(buf.mean[..., i].astype(np.float16)) for i, c in enumerate("RGB")}
    _openexr_write(directory / "image_half.exr", half)
    seeds["image_half"] = directory / "image_half.exr"
    seeds["image_zip"] = awr_io.write_image(directory / "image_zip.exr", buf.mean)
    rng = np.random.default_rng(1)
    pixels = rng.integers(0, h * w, 40)
    seeds["deep"] = awr_io.write_deep_samples(directory / "deep.exr", pixels, rng.random((40, 3)), (h, w))
    req = SampleRequest(rng.integers(0, 5, (h, w)), rng.integers(0, 9, (h, w)), round=3)
    seeds["request"] = awr_io.write_request(directory / "request.exr", req)
    return seeds


# ---------------------------------------------------------------------------- mutations
def _find_window(data: bytes) -> int | None:
    """Offset of the dataWindow box2i payload (4 int32: xMin, yMin, xMax, yMax)."""
    key = b"dataWindow\x00box2i\x00"
    at = data.find(key)
    return None if at < 0 else at + len(key) + 4


def _structural(kind: str, rng: np.random.Generator, path: Path) -> str:
    """Write a structurally hostile but well-formed EXR to ``path``; returns a description."""
    buf = _seed_buffer(seed=int(rng.integers(1 << 30)))
    h, w = buf.shape
    f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
    planes = {"sampleCount": np.ascontiguousarray(buf.count.astype(np.uint32))}
    for i, c in enumerate("RGB"):
        planes[c] = f32(buf.mean[..., i])
        planes[f"variance.{c}"] = f32(buf.variance[..., i])
    header = {"awr:semantics": "sample-statistics"}
    if kind == "channel_type":
        victim = str(rng.choice(sorted(planes)))
        choice = int(rng.integers(4))
        if choice == 0:
            planes[victim] = np.ascontiguousarray(planes[victim].astype(np.float16))
            what = f"{victim} as HALF"
        elif choice == 1:
            planes[victim] = np.ascontiguousarray((planes[victim] * 1000).astype(np.uint32))
            what = f"{victim} as UINT"
        elif choice == 2:
            planes["sampleCount"] = f32(buf.count + 0.5)
            what = "fractional FLOAT counts"
        else:
            planes["sampleCount"] = np.ascontiguousarray(np.full((h, w), 2**32 - 1, np.uint32))
            what = "UINT counts of 2**32-1"
        _openexr_write(path, planes, header)
        return what
    if kind == "bad_values":
        victim = str(rng.choice(sorted(k for k in planes if k != "sampleCount")))
        bad = [np.nan, np.inf, -np.inf, -1.0, 3.4e38][int(rng.integers(5))]
        a = planes[victim].copy()
        a[int(rng.integers(h)), int(rng.integers(w))] = bad
        planes[victim] = a
        _openexr_write(path, planes, header)
        return f"{victim} holds {bad}"
    if kind in ("deep_inconsistent", "deep_no_semantics"):
        sizes = rng.integers(0, 4, (h, w))
        grids = {}
        for c in "RGB":
            g = np.empty((h, w), dtype=object)
            for r in range(h):
                for col in range(w):
                    g[r, col] = np.ascontiguousarray(rng.random(int(sizes[r, col])), dtype=np.float32)
            grids[c] = g
        head = {} if kind == "deep_no_semantics" else {"awr:semantics": "mc-samples"}
        _openexr_write(path, grids, head, deep=True, compression="none")
        if kind == "deep_no_semantics":
            return "deep without awr:semantics"
        # OpenEXR refuses to write channels with different per-pixel counts, so corrupt the
        # (uncompressed) cumulative sample count table of one scanline instead.
        data = bytearray(path.read_bytes())
        table = _deep_count_tables(bytes(data), h, w)
        if not table:
            return "deep (count table not found)"
        line = int(rng.integers(len(table)))
        pixel = int(rng.integers(w))
        at = table[line] + 4 * pixel
        old = int.from_bytes(data[at:at + 4], "little", signed=True)
        value = [old + 1, old - 1, old + 1000, -1, 2**31 - 1, 0][int(rng.integers(6))]
        counts = np.frombuffer(bytes(data[table[line]:table[line] + 4 * w]), dtype="<i4").astype(np.int64)
        data[at:at + 4] = int(value).to_bytes(4, "little", signed=True)
        path.write_bytes(bytes(data))
        changed = counts.copy()
        changed[pixel] = value
        # Still a valid file (samples only moved between pixels of the line) when the
        # cumulative counts stay non-decreasing and the line's total is unchanged.
        valid = bool((np.diff(np.r_[0, changed]) >= 0).all() and changed[-1] == counts[-1])
        return f"deep count table line {line} pixel {pixel}: {old} -> {value}{'' if valid else ' (invalid)'}"
    raise ValueError(kind)


def _header_end(data: bytes) -> int:
    """Offset just past the (single-part) header's terminating null byte."""
    at = 8  # magic + version
    while data[at] != 0:
        name_end = data.index(b"\x00", at)
        type_end = data.index(b"\x00", name_end + 1)
        size = int.from_bytes(data[type_end + 1:type_end + 5], "little", signed=True)
        at = type_end + 5 + size
    return at + 1


def _deep_count_tables(data: bytes, h: int, w: int) -> list[int]:
    """Offsets of the cumulative sample-count table of each scanline chunk of an uncompressed
    single-part deep scanline file (chunk: int32 y, 3 uint64 sizes, then w int32 counts)."""
    try:
        at = _header_end(data)
        offsets = [int.from_bytes(data[at + 8 * i:at + 8 * i + 8], "little") for i in range(h)]
        return [o + 4 + 24 for o in offsets if 0 < o < len(data) - 28 - 4 * w]
    except (ValueError, IndexError):
        return []


@dataclass
class Case:
    index: int
    seed_name: str
    mutation: str
    detail: str
    data: bytes = field(repr=False)

    @property
    def must_reject(self) -> bool:
        """Known to be invalid: a reader of its pixel data must not return a result."""
        return self.detail.endswith("(invalid)")


def make_case(seed: int, index: int, seeds: dict[str, Path], scratch: Path) -> Case:
    """Case ``index`` of stream ``seed`` (a pure function of both)."""
    rng = np.random.default_rng([seed, index])
    mutation = MUTATIONS[int(rng.integers(len(MUTATIONS)))] if index % 50 else "valid"
    seed_name = str(rng.choice(sorted(seeds)))
    data = seeds[seed_name].read_bytes()
    n = len(data)
    detail = ""
    if mutation == "valid":
        pass
    elif mutation == "truncate":
        cut = int(rng.integers(0, n))
        data, detail = data[:cut], f"cut at {cut}/{n}"
    elif mutation == "magic":
        data = bytes(rng.integers(0, 256, 4, dtype=np.uint8)) + data[4:]
        detail = "random magic"
    elif mutation == "flip_bits":
        b = bytearray(data)
        k = int(rng.integers(1, 17))
        for at in rng.integers(0, n, k):
            b[int(at)] ^= 1 << int(rng.integers(8))
        data, detail = bytes(b), f"{k} bit(s)"
    elif mutation == "overwrite_word":
        b = bytearray(data)
        at = int(rng.integers(0, max(1, n - 4)))
        word = [0, 0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, int(rng.integers(1 << 32))][int(rng.integers(5))]
        b[at:at + 4] = int(word).to_bytes(4, "little")
        data, detail = bytes(b[:n]), f"word {word:#x} at {at}"
    elif mutation == "insert_bytes":
        at = int(rng.integers(0, n))
        k = int(rng.integers(1, 64))
        data = data[:at] + bytes(rng.integers(0, 256, k, dtype=np.uint8)) + data[at:]
        detail = f"{k} byte(s) at {at}"
    elif mutation == "delete_bytes":
        at = int(rng.integers(0, n))
        k = int(rng.integers(1, 64))
        data, detail = data[:at] + data[at + k:], f"{k} byte(s) at {at}"
    elif mutation == "huge_window":
        at = _find_window(data)
        b = bytearray(data)
        big = [2**31 - 1, 2**30, 100_000, 65_536, -(2**31)][int(rng.integers(5))]
        which = int(rng.integers(4))
        if at is not None:
            b[at + 4 * which:at + 4 * which + 4] = int(big).to_bytes(4, "little", signed=True)
        data, detail = bytes(b), f"dataWindow[{which}] = {big}"
    elif mutation == "garbage":
        k = int(rng.integers(1, 4096))
        head = data[:4] if rng.random() < 0.5 else b""
        data = head + bytes(rng.integers(0, 256, k, dtype=np.uint8))
        detail = f"{k} random byte(s){' after the magic' if head else ''}"
    elif mutation == "empty":
        data, detail = b"", "empty file"
    elif mutation == "png_named_exr":
        data, detail = b"\x89PNG\r\n\x1a\n" + bytes(rng.integers(0, 256, 64, dtype=np.uint8)), "PNG bytes"
    else:
        target = scratch / f"structural_{index}.exr"
        if target.exists():
            target.unlink()
        detail = _structural(mutation, rng, target)
        data = target.read_bytes()
        target.unlink()
        seed_name = "structural"
    return Case(index, seed_name, mutation, detail, data)


# ---------------------------------------------------------------------------- running one case
class CaseTimeout(Exception):
    pass


@contextlib.contextmanager
def deadline(seconds: float):
    """Raise CaseTimeout after ``seconds`` (main thread only; Python code, not inside C)."""
    if seconds <= 0 or not hasattr(signal, "setitimer"):
        yield
        return

    def _fire(signum, frame):
        raise CaseTimeout(f"no result within {seconds:g} s")

    old = signal.signal(signal.SIGALRM, _fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _check_buffer(buf) -> str | None:
    for name in ("mean", "variance"):
        if not np.isfinite(getattr(buf, name)).all():
            return f"{name} not finite"
    if (buf.count < 0).any():
        return "negative counts"
    return None


def run_readers(path: Path) -> list[tuple[str, str, str]]:
    """(reader, outcome, message) for each reader; outcome 'ok', 'rejected' or 'FAIL'."""
    readers = {
        "read_sample_buffer": lambda: awr_io.read_sample_buffer(path),
        "read_sample_dump": lambda: awr_io.read_sample_dump(path).buffer,
        "read_image": lambda: awr_io.read_image(path),
        "read_deep_samples": lambda: awr_io.read_deep_samples(path),
        "read_request": lambda: awr_io.read_request(path),
        "read_header": lambda: awr_io.read_header(path),
    }
    results = []
    for name, call in readers.items():
        try:
            # A reader's warning about the file is an answer the contract allows (a mean where nothing was
            # counted, a lossy compression), not a failure; every other warning is left to the filters in force
            # (under pytest an error, which fails the case).
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", InputFileWarning)
                value = call()
        except InputFileError as exc:
            msg = str(exc)
            results.append((name, "rejected", msg) if "\n" not in msg else (name, "FAIL", "multi-line: " + msg))
            continue
        except CaseTimeout:
            raise
        except Exception as exc:  # noqa: BLE001 - anything else is what we are looking for
            results.append((name, "FAIL", f"{type(exc).__name__}: {exc}"))
            continue
        problem = None
        if hasattr(value, "mean") and hasattr(value, "variance"):
            problem = _check_buffer(value)
        elif isinstance(value, np.ndarray) and value.dtype.kind == "f" and not np.isfinite(value).all():
            problem = "image not finite"
        results.append((name, "FAIL", problem) if problem else (name, "ok", ""))
    return results


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """``awr`` in-process: (exit status, stdout, stderr) as Python sees them."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = awr_main(argv)
    return rc, out.getvalue(), err.getvalue()


def check_cli(argv: list[str], output: Path | None, *, must_fail: bool = False) -> str | None:
    """None if ``awr argv`` honours the contract, else what went wrong. ``must_fail``: the
    input is known to be invalid, so exit 0 is a failure too."""
    before = set(output.parent.iterdir()) if output is not None else set()
    rc, out, err = run_cli(argv)
    if rc == 0 and must_fail:
        return "exit 0 on an input known to be invalid (an invalid deep sample count table)"
    lines = [ln for ln in err.splitlines() if ln.strip()]
    if rc == 0:
        if output is not None:
            if not output.exists():
                return "exit 0 but no output file"
            if not np.isfinite(awr_io.read_image(output)).all():
                return "exit 0 with a non-finite output image"
            output.unlink()
        return None
    if rc != 2:
        return f"exit {rc}: {' | '.join(lines)[:300]}"
    if len(lines) != 1 or not lines[0].startswith("awr: error: "):
        return f"exit 2 but stderr is not one 'awr: error:' line: {err[:300]!r}"
    if "Traceback" in err or "internal error" in err:
        return f"traceback or internal error: {err[:300]!r}"
    if output is not None:
        after = set(output.parent.iterdir())
        if after - before:
            return f"partial output left behind: {sorted(p.name for p in after - before)}"
    return None


def run_case(case: Case, workdir: Path, *, timeout: float = DEFAULT_TIMEOUT, cli: bool = True) -> dict:
    """Run one case; returns a JSON-able record with ``failures`` (empty when it passed)."""
    case_dir = workdir / f"case_{case.index}"
    if case_dir.exists():
        shutil.rmtree(case_dir)
    (case_dir / "out").mkdir(parents=True)
    path = case_dir / "input.exr"
    path.write_bytes(case.data)
    digest = _sha(path)
    failures: list[str] = []
    outcomes: dict[str, str] = {}
    t0 = time.perf_counter()
    try:
        with deadline(timeout):
            for name, outcome, message in run_readers(path):
                outcomes[name] = outcome
                if outcome == "FAIL":
                    failures.append(f"{name}: {message}"[:400])
                elif outcome == "ok" and case.must_reject and name != "read_header":
                    failures.append(f"{name}: accepted an invalid deep sample count table")
            if cli:
                problem = check_cli(["info", str(path)], None)
                if problem:
                    failures.append(f"awr info: {problem}")
                out = case_dir / "out" / "denoised.exr"
                problem = check_cli(["denoise", str(path), "-o", str(out), "-q"], out, must_fail=case.must_reject)
                if problem:
                    failures.append(f"awr denoise: {problem}")
    except CaseTimeout as exc:
        failures.append(f"timeout: {exc}")
    except MemoryError:
        failures.append("MemoryError escaped")
    if _sha(path) != digest:
        failures.append("input file modified")
    seconds = time.perf_counter() - t0
    shutil.rmtree(case_dir, ignore_errors=True)
    return {"index": case.index, "seed_file": case.seed_name, "mutation": case.mutation, "detail": case.detail,
            "bytes": len(case.data), "outcomes": outcomes, "failures": failures, "seconds": round(seconds, 3)}


# ---------------------------------------------------------------------------- the soak
def _limit_memory(limit: int) -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if hard == resource.RLIM_INFINITY or hard > limit:
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))


def _chunk_main(seed: int, start: int, stop: int, workdir: Path, timeout: float, progress: Path) -> None:
    """Child process: run cases start..stop-1, one JSON line per case on ``progress``."""
    _limit_memory(MEMORY_LIMIT)
    seeds = write_seeds(Path(tempfile.mkdtemp(prefix="seeds_", dir=workdir)))
    with open(progress, "a") as log:
        for index in range(start, stop):
            log.write(json.dumps({"started": index}) + "\n")
            log.flush()
            record = run_case(make_case(seed, index, seeds, workdir), workdir, timeout=timeout)
            log.write(json.dumps(record) + "\n")
            log.flush()


def soak(cases: int, seed: int, *, timeout: float, chunk: int, failures_dir: Path, report: Path | None) -> int:
    started = time.time()
    tally: Counter = Counter()
    outcome_tally: Counter = Counter()
    failed: list[dict] = []
    root = Path(__file__).resolve().parent.parent
    env = dict(os.environ)
    env["PYTHONPATH"] = str(root) + os.pathsep + env.get("PYTHONPATH", "")
    with tempfile.TemporaryDirectory(prefix="awr_fuzz_") as tmp:
        workdir = Path(tmp)
        index = 0
        while index < cases:
            stop = min(cases, index + chunk)
            progress = workdir / f"progress_{index}.jsonl"
            cmd = [sys.executable, __file__, "--child", str(seed), str(index), str(stop), str(workdir),
                   str(timeout), str(progress)]
            try:
                proc = subprocess.run(cmd, env=env, capture_output=True, text=True,
                                      timeout=timeout * (stop - index) + 120)
                crashed = proc.returncode != 0
                why = f"child exit {proc.returncode}: {proc.stderr.strip()[-300:]}"
            except subprocess.TimeoutExpired:
                crashed, why = True, "hang (child killed)"
            records, last_started = [], None
            if progress.exists():
                for line in progress.read_text().splitlines():
                    item = json.loads(line)
                    if "started" in item:
                        last_started = item["started"]
                    else:
                        records.append(item)
            done = {r["index"] for r in records}
            if crashed and last_started is None:
                print(f"chunk {index}..{stop - 1} failed before its first case: {why}", file=sys.stderr)
                return 2
            if crashed and last_started is not None and last_started not in done:
                seeds = write_seeds(Path(tempfile.mkdtemp(prefix="seeds_", dir=workdir)))
                case = make_case(seed, last_started, seeds, workdir)
                records.append({"index": last_started, "seed_file": case.seed_name, "mutation": case.mutation,
                                "detail": case.detail, "bytes": len(case.data), "outcomes": {},
                                "failures": [why], "seconds": None})
                done.add(last_started)
            for r in records:
                tally[r["mutation"], "fail" if r["failures"] else "pass"] += 1
                for reader, outcome in r["outcomes"].items():
                    outcome_tally[r["mutation"], outcome] += 1
                if r["failures"]:
                    failed.append(r)
                    _save_failure(seed, r, failures_dir, workdir)
            index = max(done) + 1 if done else stop
            print(f"  {index}/{cases} cases, {len(failed)} failing, {time.time() - started:.0f} s", flush=True)
    _print_table(tally, outcome_tally)
    summary = {"seed": seed, "cases": cases, "failing": len(failed), "seconds": round(time.time() - started, 1),
               "command": command_line("benchmarks/fuzz_soak.py", ["--cases", str(cases), "--seed", str(seed)]),
               "by_mutation": {f"{m}:{k}": v for (m, k), v in sorted(tally.items())},
               "reader_outcomes": {f"{m}:{k}": v for (m, k), v in sorted(outcome_tally.items())},
               "failures": failed[:200]}
    if report is not None:
        write_json(report, summary, indent=1)
        print(f"wrote {report}")
    return 1 if failed else 0


def _save_failure(seed: int, record: dict, failures_dir: Path, workdir: Path) -> None:
    failures_dir.mkdir(parents=True, exist_ok=True)
    seeds = write_seeds(Path(tempfile.mkdtemp(prefix="seeds_", dir=workdir)))
    case = make_case(seed, record["index"], seeds, workdir)
    name = f"s{seed}_c{record['index']}_{record['mutation']}"
    (failures_dir / f"{name}.exr").write_bytes(case.data)
    write_json(failures_dir / f"{name}.json", record, indent=1)


def _print_table(tally: Counter, outcome_tally: Counter) -> None:
    print(f"{'mutation':>18} {'cases':>6} {'passed':>6} {'failed':>6}   reader outcomes (ok/rejected/FAIL)")
    for m in MUTATIONS:
        p, f = tally[m, "pass"], tally[m, "fail"]
        if p + f == 0:
            continue
        o = f"{outcome_tally[m, 'ok']}/{outcome_tally[m, 'rejected']}/{outcome_tally[m, 'FAIL']}"
        print(f"{m:>18} {p + f:>6} {p:>6} {f:>6}   {o}")


def replay(path: Path, timeout: float) -> int:
    case = Case(0, "replay", "replay", str(path), path.read_bytes())
    with tempfile.TemporaryDirectory(prefix="awr_fuzz_") as tmp:
        record = run_case(case, Path(tmp), timeout=timeout)
    print(json.dumps(record, indent=1))
    return 1 if record["failures"] else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Fuzz the EXR readers and the awr command line.")
    parser.add_argument("--cases", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=20091216)
    parser.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT, help="seconds per case")
    parser.add_argument("--chunk", type=int, default=500, help="cases per child process")
    parser.add_argument("--failures", type=Path, default=Path(__file__).resolve().parent / "results" / "fuzz_failures")
    parser.add_argument("--report", type=Path, default=Path(__file__).resolve().parent / "results" / "fuzz_soak.json")
    parser.add_argument("--replay", type=Path, help="run one saved case and print its record")
    parser.add_argument("--child", nargs=6, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        seed, start, stop, workdir, timeout, progress = args.child
        _chunk_main(int(seed), int(start), int(stop), Path(workdir), float(timeout), Path(progress))
        return 0
    if args.replay:
        return replay(args.replay, args.timeout)
    return soak(args.cases, args.seed, timeout=args.timeout, chunk=args.chunk, failures_dir=args.failures,
                report=args.report)


if __name__ == "__main__":
    raise SystemExit(main())
