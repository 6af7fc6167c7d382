"""Core benchmark: speed and memory of reconstruct() and ask(), and quality on synthetic scenes.

Run from the repository root::

    .venv/bin/python benchmarks/bench_core.py                  # everything, a few minutes
    .venv/bin/python benchmarks/bench_core.py --quick          # 256x256 speed, fewer quality runs
    .venv/bin/python benchmarks/bench_core.py --only levels    # one section, updated in the JSON

Prints markdown tables and writes ``benchmarks/results/core.json``. ``precision``: stage 1 in
float32 (the default) against float64 on the tracer's and Mitsuba 3's buffers. Speed: at 1080p and 4K RGB,
the floor (PyWavelets' 5-level bior4.4 ``wavedec2`` + ``waverec2`` of the float32 frame),
``reconstruct(stages=1)`` (its fused kernels compiled by numba where the ``fast`` extra is
installed, again with their numpy reference, the library's default, and its float64
reference), the default ``reconstruct``, one
``AdaptiveSampler.ask()`` round and one ``tell()`` (merging a round's samples),
on one core (OMP/MKL/OPENBLAS_NUM_THREADS=1, no executor) and again with a 2-thread executor
(everything but the float64 reference); medians of
repeats in which the cases are interleaved, and ratios to the floor of the same run. Memory: in a
fresh process per case, the tracemalloc peak above the built buffer and the peak RSS, as
multiples of the input buffer (count + mean + variance). ``tell``: one ``tell()`` with the merge compiled
(extra ``fast``) against its numpy reference, on one thread and two, beside the floor. ``rare_paths``: ``ask()``
with rare-path regions evened (the default, :mod:`awr_denoise.rare_paths`) against ranked, on a frame with none and
on one lit through rare paths everywhere, on one core and with a 2-thread executor (the search beside the density).
``--keep-freed-memory``: every section, the memory children included, in the memory setting the ``awr`` command makes
when it starts (:func:`awr_denoise.memory.keep_freed_memory`); without it, in glibc's default, as a Python caller who
sets nothing.
"""

from __future__ import annotations

import os

# One core unless the caller says otherwise: set before numpy and scipy load their thread pools.
for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from concurrent.futures import ThreadPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pywt  # noqa: E402
from scipy import ndimage  # noqa: E402

from awr_denoise import (AdaptiveSampler, SampleBuffer, SampleRequest, UniformSampler, VarianceSampler,  # noqa: E402
                         fused, reconstruct)
from awr_denoise.bench import (OVERHEAD_SIZES, command_line, load_average, machine_info, noisy_buffer,  # noqa: E402
                               peak_memory, write_json)
from awr_denoise.bench.records import results_file  # noqa: E402
from awr_denoise.domains import Domain  # noqa: E402
from awr_denoise.memory import keep_freed_memory  # noqa: E402
from awr_denoise.prepare import prepare  # noqa: E402
from awr_denoise.rare_paths import rare_path_mask  # noqa: E402
from awr_denoise.thresholding import _float32_margin  # noqa: E402
from awr_denoise.metrics import mean_error, mse, relmse  # noqa: E402
from awr_denoise.synthetic import SyntheticRenderer, make_scene  # noqa: E402
from awr_denoise.wavelets import default_levels  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "core.json"
FLOOR_LEVELS = 5
SPEED_SIZES = ["1080p", "4K"]  # --sizes changes it
FAST = fused.available()[-1]  # stage 1's fastest kernels here: "numba" with the extra "fast", else "numpy"


def _floor(image: np.ndarray, levels: int = FLOOR_LEVELS) -> None:
    """The floor: PyWavelets' 5-level bior4.4 forward plus inverse of a float32 RGB frame."""
    with warnings.catch_warnings():  # 5 levels are "too many" for pywt below 1080p: the time is what counts
        warnings.simplefilter("ignore", UserWarning)
        pywt.waverec2(pywt.wavedec2(image, "bior4.4", level=levels, axes=(0, 1)), "bior4.4", axes=(0, 1))


class _Ask:
    """One ``ask()`` round of a sampler that has the buffer (built untimed, as a render loop has it)."""

    def __init__(self, buf, executor: ThreadPoolExecutor | None = None, **options) -> None:
        self.buf, self.executor, self.options = buf, executor, options
        self.setup()

    def setup(self) -> None:
        self.sampler = AdaptiveSampler.from_buffer(self.buf, round=1, executor=self.executor, **self.options)

    def __call__(self) -> None:
        self.sampler.ask()


class _Tell(_Ask):
    """One ``tell()``: a round's samples (the round's counts, random means) merged into the buffer."""

    def setup(self) -> None:
        super().setup()
        self.request = self.sampler.ask()
        counts = self.request.counts
        rng = np.random.default_rng(0)
        variance = rng.random(counts.shape + (3,)) * (counts[..., None] > 1)
        self.batch = SampleBuffer.from_moments(counts, rng.random(counts.shape + (3,)), variance)

    def __call__(self) -> None:
        self.sampler.tell(self.request, self.batch)


def _cases(buf, pool: ThreadPoolExecutor | None) -> dict:
    """What is timed, by name; with ``pool``, the channels on two threads."""
    image = buf.mean.astype(np.float32)
    if pool is None:
        return {"floor": lambda: _floor(image),
                # Stage 1 with the fused kernels compiled (where numba is installed), and with their
                # numpy reference, the default.
                "reconstruct_stages1": lambda: _with_kernels(FAST, reconstruct, buf, stages=1),
                "reconstruct_stages1_numpy": lambda: _with_kernels("numpy", reconstruct, buf, stages=1),
                # The float64 reference of stage 1 (float32 is the default in the log domain).
                "reconstruct_stages1_float64": lambda: reconstruct(buf, stages=1, precision="float64"),
                "reconstruct_default": lambda: reconstruct(buf),
                # The paper's level model, the samplers' default before the shrinkage's gain.
                "ask": _Ask(buf), "ask_levels": _Ask(buf, noise_model="levels"), "tell": _Tell(buf)}
    return {"reconstruct_stages1": lambda: _with_kernels(FAST, reconstruct, buf, stages=1, executor=pool),
            "reconstruct_default": lambda: reconstruct(buf, executor=pool), "ask": _Ask(buf, pool),
            "tell": _Tell(buf, pool)}


class _TellKernels(_Tell):
    """One ``tell()`` with the merge's ``kernels`` backend (:mod:`awr_denoise.merging`: numba or its numpy
    reference)."""

    def __init__(self, buf, kernels: str, executor: ThreadPoolExecutor | None = None) -> None:
        self.kernels = kernels
        super().__init__(buf, executor)

    def __call__(self) -> None:
        with fused.using(self.kernels):
            super().__call__()


def tell(sizes: list[str], repeats: int = 7) -> list[dict]:
    """One ``tell()`` (a round's samples merged into the buffer) with the merge compiled against its numpy reference.

    The four cases (each backend on one thread and on two) and the floor interleaved in every repeat; medians.
    Both backends give the same bits (tests/test_merging.py); "compiled" is numba where the extra ``fast`` is
    installed (else the numpy reference twice).
    """
    rows = []
    for name in sizes:
        buf = noisy_buffer(OVERHEAD_SIZES[name], smooth=0.0, noise=0.0)
        image = buf.mean.astype(np.float32)
        with ThreadPoolExecutor(2) as pool:
            cases = {"floor": lambda: _floor(image)}
            for threads, executor in ((1, None), (2, pool)):
                for kernels in ("numpy", FAST):
                    cases[f"{kernels}_{threads}"] = _TellKernels(buf, kernels, executor)
            for fn in cases.values():  # warm-up: the compiled loop loaded, pages touched
                fn()
            times = _interleaved(cases, repeats)
        row = {"size": name, "kernels": FAST, "repeats": repeats, "seconds": times,
               "x_floor": {k: v / times["floor"] for k, v in times.items()},
               "compiled_x_numpy_1": times[f"{FAST}_1"] / times["numpy_1"],
               "compiled_x_numpy_2": times[f"{FAST}_2"] / times["numpy_2"]}
        rows.append(row)
        x = row["x_floor"]
        print(f"| {name} | {times['floor']:.3f} s | {times['numpy_1']:.3f} s ({x['numpy_1']:.2f}x) | "
              f"{times[f'{FAST}_1']:.3f} s ({x[f'{FAST}_1']:.2f}x) | {times['numpy_2']:.3f} s ({x['numpy_2']:.2f}x) | "
              f"{times[f'{FAST}_2']:.3f} s ({x[f'{FAST}_2']:.2f}x) | {row['compiled_x_numpy_1']:.2f} / "
              f"{row['compiled_x_numpy_2']:.2f} |", flush=True)
    return rows


def _with_kernels(name: str, fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` with the fused kernels' ``name`` backend, then the choice before again."""
    with fused.using(name):
        return fn(*args, **kwargs)


def _interleaved(cases: dict, repeats: int) -> dict:
    """Median wall seconds of every case, the cases interleaved in each repeat (same load for all)."""
    times: dict = {name: [] for name in cases}
    for _ in range(repeats):
        for name, fn in cases.items():
            if hasattr(fn, "setup"):
                fn.setup()
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
    return {name: statistics.median(values) for name, values in times.items()}


def _memory_child(size: str, case: str) -> None:
    """In a fresh process: tracemalloc peak above the built buffer, and the process' peak RSS."""
    buf = noisy_buffer(OVERHEAD_SIZES[size], smooth=0.0, noise=0.0)
    _with_kernels(FAST, reconstruct, noisy_buffer((64, 64), smooth=0.0, noise=0.0), stages=1)  # loaded before the peak
    pool = ThreadPoolExecutor(2) if case.startswith("2threads:") else None
    fn = _cases(buf, pool)[case.split(":")[-1]]  # the ask() case builds its sampler here, before the peak
    base_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    _, peak = peak_memory(fn)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"tracemalloc_peak": peak, "maxrss": rss, "maxrss_before": base_rss, "input": buf.nbytes}))


# Whether this run keeps freed memory (--keep-freed-memory): its memory children then do too.
_KEPT = {"kept": False}


def _memory(size: str, case: str) -> dict:
    keep = ["--keep-freed-memory"] if _KEPT["kept"] else []
    out = subprocess.run([sys.executable, __file__, "--memory-child", size, case, *keep], capture_output=True,
                         text=True, check=True, env=os.environ.copy())
    return json.loads(out.stdout.strip().splitlines()[-1])


# Run in a fresh interpreter that has not imported numba: the seconds the first compiled stage 1
# costs beyond a second one (64x64), that is numba's import and the loading of the kernels'
# machine code (compiled and cached on disk by the speed runs before): what a process pays once.
_KERNEL_LOAD_CHILD = """
import json, time
from awr_denoise import fused, reconstruct
from awr_denoise.bench import noisy_buffer
buf = noisy_buffer((64, 64), smooth=0.0, noise=0.0)
reconstruct(buf, stages=1)  # the numpy path warm: only the kernels' own cost is left
assert "numba" not in __import__("sys").modules
times = []
for _ in range(2):
    t = time.perf_counter()
    fused.set_backend("numba")
    reconstruct(buf, stages=1)
    times.append(time.perf_counter() - t)
print(json.dumps({"load_s": times[0] - times[1]}))
"""


def _kernel_load(repeats: int = 3) -> float | None:
    """Median over fresh processes of what the compiled kernels cost once; ``None`` without numba."""
    if FAST != "numba":
        return None
    runs = [json.loads(subprocess.run([sys.executable, "-c", _KERNEL_LOAD_CHILD], capture_output=True, text=True,
                                      check=True).stdout.strip().splitlines()[-1])["load_s"]
            for _ in range(repeats)]
    return statistics.median(runs)


# The cases whose peak memory is measured, each in a fresh process (the table's last columns, in this order). On two
# threads ask() looks for regions lit through rare paths beside its density: both sets of arrays at once.
MEMORY_CASES = ("reconstruct_stages1", "reconstruct_stages1_float64", "reconstruct_default", "ask",
                "2threads:reconstruct_default", "2threads:ask")


def speed(sizes: list[str], repeats: int = 5) -> list[dict]:
    """Floor, stage 1 alone, the default reconstruction and one ask() round; 1 and 2 threads; memory."""
    rows = []
    for name in sizes:
        shape = OVERHEAD_SIZES[name]
        # Unblurred random means without added noise (the content barely changes the time).
        buf = noisy_buffer(shape, smooth=0.0, noise=0.0)
        reps = repeats if shape[0] * shape[1] <= 2_100_000 else max(1, repeats // 2)
        one = _cases(buf, None)
        for fn in one.values():  # warm-up: cached operators and transfer functions, as a render loop has
            fn()
        with ThreadPoolExecutor(2) as pool:
            two = _cases(buf, pool)
            for fn in two.values():
                fn()
            # One- and two-thread cases interleaved together: every ratio shares the load.
            both = _interleaved({**one, **{f"2threads:{k}": fn for k, fn in two.items()}}, reps)
        t1 = {k: v for k, v in both.items() if not k.startswith("2threads:")}
        t2 = {k.split(":", 1)[1]: v for k, v in both.items() if k.startswith("2threads:")}
        row = {"size": name, "pixels": shape[0] * shape[1], "input_MB": buf.nbytes / 2**20, "repeats": reps,
               "stage1_kernels": FAST,
               "seconds_1core": t1, "seconds_2threads": t2,
               "x_floor_1core": {k: v / t1["floor"] for k, v in t1.items()},
               "x_floor_2threads": {k: v / t1["floor"] for k, v in t2.items()}}
        mem = {case: _memory(name, case) for case in MEMORY_CASES}
        # maxrss_before: the process' peak once the synthetic buffer is built (its float64
        # temporaries often set the peak); the call's own peak is the tracemalloc figure.
        row["memory"] = {case: {"tracemalloc_peak_x_input": m["tracemalloc_peak"] / m["input"],
                                "maxrss_MB": m["maxrss"] / 2**20, "maxrss_before_MB": m["maxrss_before"] / 2**20,
                                "maxrss_x_input": m["maxrss"] / m["input"]}
                         for case, m in mem.items()}
        # What the compiled kernels save per call, and what a process pays once for them.
        row["stage1_kernel_saving_s"] = t1["reconstruct_stages1_numpy"] - t1["reconstruct_stages1"]
        row["stage1_kernel_load_s"] = _kernel_load()
        rows.append(row)
        x1, x2 = row["x_floor_1core"], row["x_floor_2threads"]
        print(f"| {name} | {row['input_MB']:.0f} MB | {t1['floor']:.3f} s | "
              f"{t1['reconstruct_stages1']:.3f} s ({x1['reconstruct_stages1']:.1f}x) | "
              f"{t1['reconstruct_stages1_numpy']:.3f} s ({x1['reconstruct_stages1_numpy']:.1f}x) | "
              f"{t1['reconstruct_stages1_float64']:.3f} s ({x1['reconstruct_stages1_float64']:.1f}x) | "
              f"{t1['reconstruct_default']:.3f} s ({x1['reconstruct_default']:.1f}x) | "
              f"{t1['ask']:.3f} s ({x1['ask']:.1f}x) | {t1['ask_levels']:.3f} s ({x1['ask_levels']:.1f}x) | "
              f"{t1['tell']:.3f} s ({x1['tell']:.1f}x) | "
              f"{t2['reconstruct_stages1']:.3f} s ({x2['reconstruct_stages1']:.1f}x) | "
              f"{t2['reconstruct_default']:.3f} s ({x2['reconstruct_default']:.1f}x) | "
              f"{t2['ask']:.3f} s ({x2['ask']:.1f}x) | {t2['tell']:.3f} s ({x2['tell']:.1f}x) | "
              + " | ".join(f"{row['memory'][c]['tracemalloc_peak_x_input']:.1f}x" for c in MEMORY_CASES) + " |",
              flush=True)
    for row in rows:
        load, saving = row["stage1_kernel_load_s"], row["stage1_kernel_saving_s"]
        if load is not None:
            calls = f"{load / saving:.0f} calls" if saving > 0 else "never"
            print(f"\n{row['size']}: the compiled kernels save {saving:.3f} s per stage 1 and cost {load:.2f} s "
                  f"once per process (numba's import and cached code): they pay from {calls}", flush=True)
    return rows


def _hit_or_zero_buffer(shape, spp: int = 8, p: float = 0.02, seed: int = 0) -> SampleBuffer:
    """Every sample 1 / p with chance p, else 0: a frame lit through rare paths (awr_denoise.rare_paths)."""
    hits = np.random.default_rng(seed).binomial(spp, p, size=shape).astype(np.float64)
    mean = hits / p / spp
    variance = (hits * (1 / p - mean) ** 2 + (spp - hits) * mean**2) / (spp - 1)
    return SampleBuffer.from_moments(np.full(shape, spp), np.repeat(mean[..., None], 3, -1),
                                     np.repeat(variance[..., None], 3, -1))


def _rare_path_cases(buf: SampleBuffer, executor: ThreadPoolExecutor | None = None) -> dict:
    """One ask() round of the default sampler (rare-path regions evened) and of the same with them ranked; with an
    ``executor`` both on its threads too (the search then runs beside the density: ``*_2threads``)."""
    cases = {"even": _Ask(buf), "ranked": _Ask(buf, rare_paths="ranked")}
    if executor is not None:
        cases.update(even_2threads=_Ask(buf, executor), ranked_2threads=_Ask(buf, executor, rare_paths="ranked"))
    return cases


def rare_paths_cost(sizes: list[str], repeats: int = 11) -> list[dict]:
    """ask() with rare-path regions evened (the default) against ranked, on a frame with none (the speed section's
    buffer: the search alone) and on one lit through rare paths everywhere (the search and the evening)."""
    rows = []
    for name in sizes:
        shape = OVERHEAD_SIZES[name]
        for label, buf in (("no rare paths", noisy_buffer(shape, smooth=0.0, noise=0.0)),
                           ("rare paths everywhere", _hit_or_zero_buffer(shape))):
            with ThreadPoolExecutor(2) as pool:
                cases = _rare_path_cases(buf, pool)
                for fn in cases.values():
                    fn()
                t = _interleaved(cases, repeats)
            mask = float(rare_path_mask(buf).mean())
            rows.append({"size": name, "buffer": label, "repeats": repeats, "seconds": t, "masked_share": mask,
                         "ratio": t["even"] / t["ranked"], "ratio_2threads": t["even_2threads"] / t["ranked_2threads"]})
            print(f"| {name} | {label} | {100 * mask:.0f}% | {t['ranked']:.3f} s | {t['even']:.3f} s | "
                  f"{t['even'] / t['ranked']:.2f} | {t['ranked_2threads']:.3f} s | {t['even_2threads']:.3f} s | "
                  f"{t['even_2threads'] / t['ranked_2threads']:.2f} |", flush=True)
    return rows


def fft_budget(size: str = "1080p", repeats: int = 5) -> dict:
    """How many plane FFTs the default reconstruction runs, and what they cost beside the floor.

    The FFT calls of one default ``reconstruct`` are counted by wrapping ``ducc0.fft``; one
    forward plus inverse real FFT of a float32 plane of the size is timed interleaved with the
    floor, so ``fft_pairs * pair_s / floor_s`` is what the Wiener stages' FFTs alone cost in
    multiples of the floor, whatever else is made faster.
    """
    import ducc0

    shape = OVERHEAD_SIZES[size]
    buf = noisy_buffer(shape, smooth=0.0, noise=0.0)
    counts = {"r2c": 0, "c2r": 0}
    originals = {name: getattr(ducc0.fft, name) for name in counts}

    def counting(name):
        def call(a, *args, **kwargs):
            counts[name] += int(np.prod(np.shape(a)[:-2], dtype=np.int64))
            return originals[name](a, *args, **kwargs)
        return call

    for name in counts:
        setattr(ducc0.fft, name, counting(name))
    try:
        reconstruct(buf)
    finally:
        for name, fn in originals.items():
            setattr(ducc0.fft, name, fn)
    plane = np.random.default_rng(0).random(shape).astype(np.float32)
    image = buf.mean.astype(np.float32)
    t = _interleaved({"floor": lambda: _floor(image),
                      "fft_pair": lambda: ducc0.fft.c2r(ducc0.fft.r2c(plane), lastsize=shape[1], forward=False,
                                                        inorm=2)}, repeats)
    pairs = (counts["r2c"] + counts["c2r"]) / 2
    row = {"size": size, "plane_ffts": counts, "floor_s": t["floor"], "fft_pair_s": t["fft_pair"],
           "ffts_x_floor": pairs * t["fft_pair"] / t["floor"]}
    print(f"| {size} | {counts['r2c']} + {counts['c2r']} | {t['fft_pair']:.4f} s | {t['floor']:.3f} s | "
          f"{row['ffts_x_floor']:.1f}x |", flush=True)
    return row


def _dilated(a: np.ndarray, taps: np.ndarray, axis: int, step: int) -> np.ndarray:
    """Periodic correlation of ``a`` along ``axis`` with ``taps`` spaced ``step`` apart ("a trous").

    The plane is viewed as ``step`` interleaved sequences along the axis (its length a multiple of
    ``step``), each filtered with the undilated taps by ``scipy.ndimage``: no zero taps are multiplied.
    """
    n = a.shape[axis]
    view = a.reshape(a.shape[:axis] + (n // step, step) + a.shape[axis + 1:])
    return ndimage.correlate1d(view, taps, axis=axis, mode="wrap").reshape(a.shape)


def _atrous_ndimage(plane: np.ndarray, wavelet: str, levels: int) -> list:
    """The undecimated analysis as a cascade of scipy.ndimage's compiled 1-D filters: per level,
    two passes along the rows (low and high) and four along the columns, dilated by ``2^(j-1)``."""
    w = pywt.Wavelet(wavelet)
    lo, hi = np.asarray(w.dec_lo[::-1], plane.dtype), np.asarray(w.dec_hi[::-1], plane.dtype)
    approx, out = plane, []
    for j in range(levels):
        step = 2 ** j
        rows_lo, rows_hi = _dilated(approx, lo, 1, step), _dilated(approx, hi, 1, step)
        approx = _dilated(rows_lo, lo, 0, step)
        out.append((_dilated(rows_lo, hi, 0, step), _dilated(rows_hi, lo, 0, step), _dilated(rows_hi, hi, 0, step)))
    return [approx] + out[::-1]


def atrous(size: str = "1080p", repeats: int = 5) -> dict:
    """The Wiener stages' FFT route against direct a-trous filtering, one float32 plane, one core.

    One of performance.md's design options for a cheaper default: filter the undecimated bands
    directly (the kernels have 7-9 taps, dilated) instead of through FFTs. Timed interleaved on
    one plane of the size, its height and width rounded up to a multiple of ``2^levels`` (what
    PyWavelets' ``swt2`` needs), at the Wiener stages' depth for the size:

    - the FFT route as a Wiener stage runs it: one forward FFT, then per band the product with
      its transfer function and one inverse FFT (analysis); per band one forward FFT and the
      product with its synthesis function, summed, then one inverse FFT (synthesis);
    - PyWavelets' compiled a-trous transform, ``swt2`` and ``iswt2``: the same coefficients up
      to a circular shift (``tests/bench/test_bench_core_atrous.py``);
    - the analysis as a cascade of scipy.ndimage's compiled 1-D filters (:func:`_atrous_ndimage`).

    The exact variance (Eq. 10) has no such cascade: its kernels are the bands' squared
    equivalent filters, up to ``(2^L - 1) * 8 + 1`` taps per axis at depth ``L``; it stays an FFT.
    """
    from awr_denoise.reconstruct import _wiener_levels
    from awr_denoise.stationary import stationary_transform

    levels = _wiener_levels(default_levels(OVERHEAD_SIZES[size]))
    m = 2 ** levels
    shape = tuple(-(-n // m) * m for n in OVERHEAD_SIZES[size])
    plane = np.random.default_rng(0).random(shape).astype(np.float32)
    t = stationary_transform(shape, levels=levels, dtype="float32")
    nb = len(t.bands)

    def fft_analysis():
        spec = t.spectrum(plane)
        return [t.planes(spec * t.analysis(b)) for b in range(nb)]

    bands = fft_analysis()

    def fft_synthesis():
        total = t.spectrum(bands[0]) * t.synthesis(0)
        for b in range(1, nb):
            total += t.spectrum(bands[b]) * t.synthesis(b)
        return t.planes(total)

    coeffs = pywt.swt2(plane, "bior4.4", level=levels, trim_approx=True)
    frame = np.random.default_rng(1).random(OVERHEAD_SIZES[size] + (3,)).astype(np.float32)
    times = _interleaved({"floor": lambda: _floor(frame), "fft_analysis": fft_analysis,
                          "fft_synthesis": fft_synthesis,
                          "swt2": lambda: pywt.swt2(plane, "bior4.4", level=levels, trim_approx=True),
                          "iswt2": lambda: pywt.iswt2(coeffs, "bior4.4"),
                          "ndimage_analysis": lambda: _atrous_ndimage(plane, "bior4.4", levels)}, repeats)
    row = {"size": size, "plane": list(shape), "levels": levels, "bands": nb,
           **{f"{k}_s": v for k, v in times.items()},
           "swt2_x_fft": times["swt2"] / times["fft_analysis"],
           "iswt2_x_fft": times["iswt2"] / times["fft_synthesis"],
           "ndimage_x_fft": times["ndimage_analysis"] / times["fft_analysis"]}
    print(f"| {size} ({shape[0]}x{shape[1]}, {levels} levels) | {times['floor']:.3f} s "
          f"| {times['fft_analysis']:.3f} s | {times['swt2']:.3f} s ({row['swt2_x_fft']:.2f}x) "
          f"| {times['ndimage_analysis']:.3f} s "
          f"({row['ndimage_x_fft']:.2f}x) | {times['fft_synthesis']:.3f} s | {times['iswt2']:.3f} s "
          f"({row['iswt2_x_fft']:.2f}x) |", flush=True)
    return row


def _reach(touched: np.ndarray, level: int, taps: int) -> float:
    """Share of level ``level``'s decimated coefficient positions whose ``taps``-tap analysis support,
    ``(taps - 1) (2^level - 1) + 1`` pixels wide, holds a ``True`` pixel of ``touched``."""
    width = (taps - 1) * (2**level - 1) + 1
    step = 2**level
    return float(ndimage.maximum_filter(touched, size=width, mode="mirror")[::step, ::step].mean())


TOUCHED_SCENES = (("tracer", "default"), ("tracer", "chess_dof"), ("tracer", "rolling_balls"),
                  ("tracer", "sky_objects"), ("tracer", "soft_shadows"), ("tracer", "cornell_gi"),
                  ("mitsuba", "cornell_box"), ("mitsuba", "envmap_sun"), ("mitsuba", "glossy_glass"),
                  ("mitsuba", "dof_checker"))
"""(renderer, scene): the bundled tracer's six scenes at their 128x128 and, with the extra ``mitsuba``,
the adapter's four at 256x256 (skipped with a notice without it)."""


def touched(scenes: tuple[tuple[str, str], ...] = TOUCHED_SCENES, spp: int = 32) -> list[dict]:
    """Could ``ask()`` be incremental? How much of the image one adaptive round changes.

    Each scene, ``AdaptiveSampler``'s defaults, rounds up to ``spp``: per round
    after the first (uniform) one, the share of pixels that get samples, and the share of the
    decimated wavelet coefficients of levels 1 and 2 whose support (the 9-tap bior4.4 analysis
    filters, ``8 (2^j - 1) + 1`` pixels wide at level ``j``) holds one of them: the coefficients an
    incremental ``ask()`` would have to redo at the least (level 1 holds three quarters of the
    detail coefficients, level 2 three sixteenths; coarser supports are wider still).
    """
    from awr_denoise.renderers import create_renderer

    taps = len(pywt.Wavelet("bior4.4").dec_lo)
    rows = []
    for kind, name in scenes:
        try:
            renderer = create_renderer(kind, name, seed=0, **({"shape": (256, 256)} if kind == "mitsuba" else {}))
        except ImportError as error:  # the optional renderer's extra is missing
            print(f"skipping {kind} {name}: {error}", flush=True)
            continue
        sampler = AdaptiveSampler(renderer.shape, seed=0)
        pixels, level1, level2, total, rounds = [], [], [], 0, 0
        while total < spp * renderer.shape[0] * renderer.shape[1]:
            request = sampler.ask()
            got = request.counts > 0
            if rounds:
                pixels.append(float(got.mean()))
                level1.append(_reach(got, 1, taps))
                level2.append(_reach(got, 2, taps))
            sampler.tell(request, renderer(request))
            total += int(request.counts.sum())
            rounds += 1
        row = {"renderer": kind, "scene": name, "shape": list(renderer.shape), "rounds": rounds, "pixels": pixels,
               "level1_coefficients": level1, "level2_coefficients": level2}
        rows.append(row)
        print(f"| {name} | {rounds} | {min(pixels):.0%}-{max(pixels):.0%} | {min(level1):.0%}-{max(level1):.0%} "
              f"| {min(level2):.0%}-{max(level2):.0%} |", flush=True)
    return rows


def precision(spps=(8, 32, 128), group: int = 0) -> list[dict]:
    """Stage 1 in float32 (the default) against its float64 reference on buffers the renderers wrote.

    The bundled tracer's scenes and, when the ``mitsuba`` extra is installed, Mitsuba 3's, as
    ``benchmarks/bench_reconstruct.py quality`` renders and caches them (group ``group``, its
    cache directory): relMSE and MSE against the references, the image mean, and the largest
    difference of a pixel relative to ``|x| + k`` (the log domain's own scale).
    """
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_reconstruct as br  # the renders and references of the quality measurements

    cache = Path.home() / ".cache" / "awr-denoise" / "reconstruct"
    scenes = [("tracer", s, None) for s in br.TRACER_SCENES]
    if br._mitsuba_available():
        scenes += [("mitsuba", s, br.MITSUBA_SHAPE) for s in br.MITSUBA_SCENES]
    rows = []
    for renderer, scene, shape in scenes:
        ref = br.reference(renderer, scene, shape, cache)
        for spp, buf in br.uniform_buffers(renderer, scene, shape, spps, group, cache).items():
            single = reconstruct(buf, stages=1)
            double = reconstruct(buf, stages=1, precision="float64")
            k = 0.1 * Domain("log").resolved_scale(buf.mean)
            row = {"renderer": renderer, "scene": scene, "spp": spp, "float32_margin": _float32_margin_of(buf),
                   "relmse_float32": relmse(single, ref), "relmse_float64": relmse(double, ref),
                   "mse_float32": mse(single, ref), "mse_float64": mse(double, ref),
                   "mean_change": mean_error(single, double),
                   "largest_pixel_change": float((np.abs(single - double) / (np.abs(double) + k)).max())}
            rows.append(row)
            print(f"| {renderer} | {scene} | {spp} | {row['relmse_float32'] / row['relmse_float64'] - 1:+.1e} | "
                  f"{row['mse_float32'] / row['mse_float64'] - 1:+.1e} | {row['mean_change']:.1e} | "
                  f"{row['largest_pixel_change']:.1e} | {row['float32_margin']:.3g} |", flush=True)
    return rows


def _firefly_buffer(value: float, seed: int = 0) -> tuple[SampleBuffer, np.ndarray]:
    """64x64 RGB at 16 spp, a sinusoid of 0.5 +- 0.3 with noise, and one pixel holding one sample of ``value``."""
    rng = np.random.default_rng(seed)
    clean = 0.5 + 0.3 * np.sin(np.arange(64) / 5.0)[None, :, None] * np.ones((64, 64, 3))
    variance = np.full(clean.shape, 0.05)
    mean = clean + rng.standard_normal(clean.shape) * np.sqrt(variance / 16)
    mean[10, 10], variance[10, 10] = value / 16 + 0.5, value**2 / 16
    return SampleBuffer.from_moments(np.full((64, 64), 16), mean, variance), clean


def wiener_precision(spps=(8, 32), group: int = 0) -> list[dict]:
    """The default reconstruction in float32 (its default) against ``precision="float64"``, all stages.

    The rendered buffers of :func:`precision`, and a synthetic firefly: one sample of 1e4, 1e6 or 1e9 in one pixel
    of a 64x64 image at 16 spp (its "clean" image the reference; "far": pixels 13 or more from it). Each row: the
    difference per pixel in standard errors of its mean (median, 99th percentile, largest), relMSE and MSE of
    float32 over float64's, and the far pixels' MSE over float64's where there is a firefly.
    """
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_reconstruct as br

    cache = Path.home() / ".cache" / "awr-denoise" / "reconstruct"
    cases = [(f"firefly {value:.0e}", *_firefly_buffer(value)) for value in (1e4, 1e6, 1e9)]
    scenes = [("tracer", s, None) for s in br.TRACER_SCENES]
    if br._mitsuba_available():
        scenes += [("mitsuba", s, br.MITSUBA_SHAPE) for s in br.MITSUBA_SCENES]
    for renderer, scene, shape in scenes:
        ref = br.reference(renderer, scene, shape, cache)
        cases += [(f"{renderer} {scene} {spp} spp", buf, ref)
                  for spp, buf in br.uniform_buffers(renderer, scene, shape, spps, group, cache).items()]
    rows = []
    for name, buf, ref in cases:
        single, double = reconstruct(buf), reconstruct(buf, precision="float64")
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.abs(single - double) / np.sqrt(buf.variance_of_mean())
        z = z[np.isfinite(z)]
        row = {"case": name, "median_sd": float(np.median(z)), "p99_sd": float(np.percentile(z, 99)),
               "max_sd": float(z.max()), "relmse_ratio": relmse(single, ref) / relmse(double, ref),
               "mse_ratio": mse(single, ref) / mse(double, ref), "far_mse_ratio": None}
        if name.startswith("firefly"):
            far = np.ones(ref.shape[:2], bool)
            far[:23, :23] = False
            row["far_mse_ratio"] = mse(single[far], ref[far]) / mse(double[far], ref[far])
        rows.append(row)
        far_cell = "" if row["far_mse_ratio"] is None else f"{row['far_mse_ratio']:.3f}"
        print(f"| {name} | {row['median_sd']:.1e} | {row['p99_sd']:.2g} | {row['max_sd']:.2g} | "
              f"{row['relmse_ratio']:.4f} | {row['mse_ratio']:.4f} | {far_cell} |", flush=True)
    return rows


def _float32_margin_of(buffer: SampleBuffer) -> float:
    """The smallest over channels of stage 1's margin to its switch to float64 (below 1: float64)."""
    p = prepare(buffer, "log")
    count = p.count[:, :, 0].astype(np.float32)
    margins = []
    for c in range(p.mean.shape[2]):
        plane = fused.log_plane(p.mean[:, :, c], p.sample_variance[:, :, c], count, p.bound.k)
        if plane is not None:  # else beyond float32 altogether: float64 anyway
            margins.append(_float32_margin(plane[0], p.mean[:, :, c], p.sample_variance[:, :, c], count, p.bound.k))
    return min(margins, default=0.0)


def quality(shape=(128, 128), spps=(8, 32), seed=3) -> list[dict]:
    rows = []
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        for spp in spps:
            row = {"scene": scene_name, "spp": spp}
            uniform = UniformSampler(shape).run(SyntheticRenderer(scene, seed=seed), spp)
            row["uniform_mean"] = (relmse(uniform.mean, ref), mse(uniform.mean, ref))
            row["uniform_awr"] = (relmse(reconstruct(uniform), ref), mse(reconstruct(uniform), ref))
            variance = VarianceSampler(shape).run(SyntheticRenderer(scene, seed=seed), spp)
            row["variance_awr"] = (relmse(reconstruct(variance), ref), mse(reconstruct(variance), ref))
            adaptive = AdaptiveSampler(shape).run(SyntheticRenderer(scene, seed=seed), spp)
            row["adaptive_awr"] = (relmse(reconstruct(adaptive), ref), mse(reconstruct(adaptive), ref))
            rows.append(row)
            cells = " | ".join(f"{row[k][0]:.4f} / {row[k][1]:.2e}"
                               for k in ("uniform_mean", "uniform_awr", "variance_awr", "adaptive_awr"))
            print(f"| {scene_name} | {spp} | {cells} |", flush=True)
    return rows


def domains(shape=(128, 128), spps=(4, 16), seed=1) -> list[dict]:
    variants = {"linear": Domain("linear"), "log k=0.02": Domain("log", 0.02), "log k=0.1": Domain("log", 0.1),
                "log k=0.5": Domain("log", 0.5), "gamma 2.2": Domain("gamma"),
                "log k=0.1 robust": Domain("log", 0.1, robust=True)}
    rows = []
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        for spp in spps:
            buf = UniformSampler(shape).run(SyntheticRenderer(scene, seed=seed), spp)
            row = {"scene": scene_name, "spp": spp, "mean": relmse(buf.mean, ref)}
            for label, dom in variants.items():
                row[label] = relmse(reconstruct(buf, domain=dom), ref)
            rows.append(row)
            print(f"| {scene_name} | {spp} | {row['mean']:.4f} | "
                  + " | ".join(f"{row[k]:.4f}" for k in variants) + " |", flush=True)
    return rows


def pixel_clamps(shape=(64, 64), spps=(4, 8, 32), seeds=range(5)) -> list[dict]:
    """Mean relMSE over seeds, and the worst ratio to the noisy mean, per pixel clamp."""
    clamps = {"none (Eq. 11 only)": None, "z=2": 2.0, "z=2.5": 2.5, "z=3": 3.0}
    rows = []
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        for spp in spps:
            buffers = [SyntheticRenderer(scene, seed=s)(SampleRequest.uniform(shape, spp)) for s in seeds]
            means = [relmse(b.mean, ref) for b in buffers]
            row = {"scene": scene_name, "spp": spp, "mean": float(np.mean(means))}
            for label, z in clamps.items():
                errs = [relmse(reconstruct(b, pixel_clamp=z), ref) for b in buffers]
                row[label] = {"relmse": float(np.mean(errs)),
                              "worst_ratio_to_mean": float(max(e / m for e, m in zip(errs, means)))}
            rows.append(row)
            print(f"| {scene_name} | {spp} | {row['mean']:.4f} | "
                  + " | ".join(f"{row[k]['relmse']:.4f} ({row[k]['worst_ratio_to_mean']:.2f})" for k in clamps)
                  + " |", flush=True)
    return rows


def level_weights(shape=(128, 128), spp=16, seed=3) -> list[dict]:
    rows = []
    weights = (0.0, 0.25, 0.5, 1.0)
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        uniform = UniformSampler(shape).run(SyntheticRenderer(scene, seed=seed), spp)
        row = {"scene": scene_name, "spp": spp, "uniform_awr": relmse(reconstruct(uniform), ref)}
        for lw in weights:
            buf = AdaptiveSampler(shape, level_weight=lw, noise_model="levels").run(SyntheticRenderer(scene, seed=seed), spp)
            row[f"w={lw}"] = relmse(reconstruct(buf), ref)
        rows.append(row)
        print(f"| {scene_name} | {row['uniform_awr']:.4f} | " + " | ".join(f"{row[f'w={lw}']:.4f}" for lw in weights)
              + " |", flush=True)
    return rows


def round_growths(shape=(128, 128), spps=(8, 32), seeds=(3, 4, 5)) -> list[dict]:
    """AdaptiveSampler's round size: relMSE after reconstruction, mean over seeds."""
    rows = []
    growths = (0.25, 0.5, 1.0)
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        for spp in spps:
            row = {"scene": scene_name, "spp": spp}
            for growth in growths:
                errors, rounds = [], []
                for seed in seeds:
                    sampler = AdaptiveSampler(shape, seed=seed, round_growth=growth)
                    buf = sampler.run(SyntheticRenderer(scene, seed=seed), spp)
                    errors.append(relmse(reconstruct(buf), ref))
                    rounds.append(sampler.round)
                row[f"g={growth}"] = {"relmse": float(np.mean(errors)), "rounds": rounds[0]}
            rows.append(row)
            print(f"| {scene_name} | {spp} | " + " | ".join(
                f"{row[f'g={g}']['relmse']:.4f} ({row[f'g={g}']['rounds']})" for g in growths) + " |", flush=True)
    return rows


def levels(shapes=((128, 128), (256, 256)), spps=(8, 32), seeds=(3, 4)) -> list[dict]:
    """Decomposition depth: relMSE of uniform + AWR and AWR + AWR, mean over seeds, per size."""
    rows = []
    for shape in shapes:
        depths = (2, 3, 4, 5)
        for scene_name in ("gradient", "edges", "hdr_source", "fireflies"):
            scene = make_scene(scene_name, shape)
            ref = scene.reference(8)
            for spp in spps:
                row = {"size": f"{shape[1]}x{shape[0]}", "scene": scene_name, "spp": spp,
                       "default": default_levels(shape)}
                for lv in depths:
                    uniform, adaptive = [], []
                    for seed in seeds:
                        buf = UniformSampler(shape, seed=seed).run(SyntheticRenderer(scene, seed=seed), spp)
                        uniform.append(relmse(reconstruct(buf, levels=lv), ref))
                        buf = AdaptiveSampler(shape, seed=seed, levels=lv).run(SyntheticRenderer(scene, seed=seed), spp)
                        adaptive.append(relmse(reconstruct(buf, levels=lv), ref))
                    row[f"L={lv}"] = {"uniform_awr": float(np.mean(uniform)), "awr_awr": float(np.mean(adaptive))}
                rows.append(row)
                print(f"| {row['size']} | {scene_name} | {spp} | " + " | ".join(
                    f"{row[f'L={lv}']['uniform_awr']:.4f} / {row[f'L={lv}']['awr_awr']:.4f}" for lv in depths) + " |",
                    flush=True)
    return rows


def uniform_fractions(shape=(128, 128), spps=(8, 32), seeds=(3, 4, 5, 6)) -> list[dict]:
    """AdaptiveSampler's uniform share: relMSE after reconstruction, mean over seeds.

    ``rare_light (disc)`` is the error of the rare_light scene inside its small bright disc (grown
    by 3 pixels), where a share of uniform samples would matter if anywhere.
    """
    rows = []
    fractions = (0.0, 0.1, 0.3)
    for scene_name in ("gradient", "edges", "hdr_source", "fireflies", "rare_light"):
        scene = make_scene(scene_name, shape)
        ref = scene.reference(8)
        regions = {scene_name: np.ones(shape, bool)}
        if scene_name == "rare_light":
            regions["rare_light (disc)"] = ndimage.binary_dilation(ref[..., 0] > 0.5, iterations=3)
        for spp in spps:
            errors = {(name, f): [] for name in regions for f in fractions}
            for fraction in fractions:
                for seed in seeds:
                    sampler = AdaptiveSampler(shape, seed=seed, uniform_fraction=fraction)
                    out = reconstruct(sampler.run(SyntheticRenderer(scene, seed=seed), spp))
                    for name, mask in regions.items():
                        errors[name, fraction].append(relmse(out[mask], ref[mask]))
            for name in regions:
                row = {"scene": name, "spp": spp, **{f"f={f}": float(np.mean(errors[name, f])) for f in fractions}}
                rows.append(row)
                print(f"| {name} | {spp} | " + " | ".join(f"{row[f'f={f}']:.4f}" for f in fractions) + " |",
                      flush=True)
    return rows


OPERATOR_SHAPES = {"1080p": OVERHEAD_SIZES["1080p"], "4K": OVERHEAD_SIZES["4K"], "16K panorama": (8192, 16384)}


def _every_impulse(apply, n_in: int, step=None, edge=None):
    """An operator built the direct way, one impulse per sample (quadratic in the side): the build
    the library used before its linear one, kept here as the reference it is timed against."""
    from scipy import sparse

    blocks = []
    for start in range(0, n_in, 256):
        stop = min(n_in, start + 256)
        impulses = np.zeros((n_in, stop - start))
        impulses[np.arange(start, stop), np.arange(stop - start)] = 1.0
        blocks.append(sparse.csc_matrix(apply(impulses)))
    return sparse.hstack(blocks, format="csr")


def operators(shapes: dict = OPERATOR_SHAPES, repeats: int = 3) -> list[dict]:
    """Cold build of an image's exact-variance operators, what every fresh process (each ``awr``
    command, each round of the file-based loop) builds on its first reconstruction or ``ask()``:
    both sides' equivalent filters and diagonals at the default depth, the library's linear build
    against one impulse per sample (:func:`_every_impulse`). Medians of interleaved repeats."""
    from awr_denoise import wavelets

    def build(route):
        def run():
            wavelets._axis_operators.cache_clear()
            wavelets._axis_diagonals.cache_clear()
            original, wavelets._sparse_operator = wavelets._sparse_operator, route
            try:
                for n in dict.fromkeys(shape):
                    wavelets._axis_operators(n, wavelets.DEFAULT_WAVELET, "symmetric", levels)
                    wavelets._axis_diagonals(n, wavelets.DEFAULT_WAVELET, "symmetric", levels)
            finally:
                wavelets._sparse_operator = original
                wavelets._axis_operators.cache_clear()
                wavelets._axis_diagonals.cache_clear()
        return run

    rows = []
    for name, shape in shapes.items():
        levels = default_levels(shape)
        times = _interleaved({"linear": build(wavelets._sparse_operator), "every_impulse": build(_every_impulse)},
                             repeats)
        row = {"size": name, "shape": list(shape), "levels": levels, "linear_s": times["linear"],
               "every_impulse_s": times["every_impulse"], "speedup": times["every_impulse"] / times["linear"]}
        print(f"| {name} ({shape[1]}x{shape[0]}, {levels} levels) | {times['every_impulse']:.3f} s "
              f"| {times['linear']:.3f} s | {row['speedup']:.1f}x |", flush=True)
        rows.append(row)
    return rows


SECTIONS = {
    "precision": ("Stage 1 in float32 against float64 (stages=1, rendered buffers): relative changes",
                  "| renderer | scene | spp | relMSE | MSE | image mean | largest pixel change (x (abs(x) + k)) "
              "| float32 margin (below 1: float64) |",
                  lambda quick: precision(spps=(8,) if quick else (8, 32, 128))),
    "wiener_precision": ("The default reconstruction in float32 against float64 (every stage): difference per "
                         "pixel in standard errors of its mean, and float32's errors over float64's",
                         "| case | median | 99th percentile | largest | relMSE | MSE | MSE of the far pixels |",
                         lambda quick: wiener_precision(spps=(8,) if quick else (8, 32))),
    "speed": ("Speed against the PyWavelets floor (medians of interleaved repeats; x floor of the same run) "
              "and peak memory (tracemalloc, x input buffer)",
              "| size | input buffer | floor | stages=1 | stages=1, numpy kernels | stages=1 float64 | default | ask() | ask(), levels | tell() "
              "| stages=1, 2 threads "
              "| default, 2 threads | ask(), 2 threads | tell(), 2 threads | stages=1 peak | stages=1 float64 peak | default peak | ask() peak "
              "| default, 2 threads, peak | ask(), 2 threads, peak |",
              lambda quick: speed(["256x256"] if quick else SPEED_SIZES)),
    "tell": ("One tell() with the merge compiled (extra fast) against its numpy reference (medians of interleaved "
             "repeats; x floor of the same run)",
             "| size | floor | tell(), numpy | tell(), compiled | tell(), numpy, 2 threads "
             "| tell(), compiled, 2 threads | compiled / numpy, 1 / 2 threads |",
             lambda quick: tell(["256x256"] if quick else SPEED_SIZES)),
    "rare_paths": ("ask() with rare-path regions evened (the default) against ranked (medians of interleaved repeats)",
                   "| size | buffer | pixels in rare-path regions | ask(), ranked | ask(), evened | evened / ranked "
                   "| ask(), ranked, 2 threads | ask(), evened, 2 threads | evened / ranked, 2 threads |",
                   lambda quick: rare_paths_cost(["256x256"] if quick else ["256x256", "1080p"])),
    "fft_budget": ("The default reconstruction's FFTs against the floor (one core)",
                   "| size | plane FFTs (forward + inverse) | one forward + inverse pair | floor | FFTs alone |",
                   lambda quick: [fft_budget("256x256" if quick else "1080p")]),
    "atrous": ("The Wiener stages' FFT route against direct a-trous filtering (one float32 plane, one core; "
               "x the FFT route in brackets)",
               "| size | floor (RGB frame) | FFT analysis | swt2 | scipy.ndimage cascade | FFT synthesis | iswt2 |",
               lambda quick: [atrous("256x256" if quick else "1080p")]),
    "operators": ("Cold build of the exact variance's operators, both sides (what a fresh process builds first)",
                  "| size | one impulse per sample | linear build | speed-up |",
                  lambda quick: operators({"256x256": (256, 256)} if quick else OPERATOR_SHAPES, 1 if quick else 3)),
    "touched": ("How much of the image an adaptive round changes (bundled tracer, AdaptiveSampler's defaults, "
                "to 32 spp)",
                "| scene | rounds | pixels given samples per round | level-1 coefficients they reach | level 2 |",
                lambda quick: touched(TOUCHED_SCENES[:2] if quick else TOUCHED_SCENES, 8 if quick else 32)),
    "quality": ("Quality, synthetic 128x128 (relMSE / MSE, equal samples)",
                "| scene | spp | uniform mean | uniform + AWR | variance-driven + AWR | AWR adaptive + AWR |",
                lambda quick: quality(spps=(8,) if quick else (8, 32))),
    "domains": ("Reconstruction domain (relMSE, uniform sampling, c_s = 1)",
                "| scene | spp | mean | linear | log k=0.02 | log k=0.1 | log k=0.5 | gamma 2.2 | log k=0.1 robust |",
                lambda quick: domains(spps=(4,) if quick else (4, 16))),
    "pixel_clamps": ("Pixel clamp (64x64, mean relMSE over 5 seeds, worst ratio to the noisy mean in brackets)",
                     "| scene | spp | mean | none (Eq. 11 only) | z=2 | z=2.5 | z=3 |",
                     lambda quick: pixel_clamps(spps=(8,) if quick else (4, 8, 32))),
    "level_weights": ("Sampler level weight (relMSE after reconstruction, 16 spp)",
                      "| scene | uniform + AWR | w=0 | w=0.25 | w=0.5 | w=1 |",
                      lambda quick: level_weights()),
    "round_growths": ("Sampler round growth (relMSE after reconstruction, mean of 3 seeds; rounds in brackets)",
                      "| scene | spp | growth 0.25 | growth 0.5 | growth 1.0 |",
                      lambda quick: round_growths(spps=(8,) if quick else (8, 32))),
    "uniform_fractions": ("Sampler uniform share (relMSE after reconstruction, mean of 4 seeds)",
                          "| scene | spp | uniform_fraction 0 | 0.1 | 0.3 |",
                          lambda quick: uniform_fractions(spps=(8,) if quick else (8, 32))),
    "levels": ("Levels (relMSE, uniform + AWR / AWR + AWR, mean of 2 seeds)",
               "| size | scene | spp | L=2 | L=3 | L=4 | L=5 |",
               lambda quick: levels(shapes=((128, 128),) if quick else ((128, 128), (256, 256)),
                                    spps=(8,) if quick else (8, 32))),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="256x256 speed only, fewer quality runs")
    parser.add_argument("--only", nargs="+", choices=tuple(SECTIONS), metavar="SECTION",
                        help=f"run only these sections ({', '.join(SECTIONS)}) and update them in the JSON")
    parser.add_argument("--output", type=results_file, default=RESULTS)
    parser.add_argument("--sizes", nargs="+", choices=tuple(OVERHEAD_SIZES), default=SPEED_SIZES,
                        help="sizes of the speed section (default: 1080p 4K)")
    parser.add_argument("--keep-freed-memory", action="store_true",
                        help="the memory setting awr makes when it starts (awr_denoise.memory.keep_freed_memory), "
                             "for every section; refused where it cannot apply (not glibc, MALLOC_ variables set)")
    parser.add_argument("--memory-child", nargs=2, metavar=("SIZE", "CASE"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.keep_freed_memory:  # before any large array
        if not keep_freed_memory():
            parser.error("--keep-freed-memory: the setting does not apply here (not glibc, or the allocator is set "
                         "in the environment)")
        _KEPT["kept"] = True
    if args.memory_child:
        _memory_child(*args.memory_child)
        return 0
    SPEED_SIZES[:] = args.sizes
    results = {}
    if args.only and args.output.is_file():
        results = json.loads(args.output.read_text())
    results["machine"] = machine_info("numpy", "scipy", "PyWavelets", "ducc0")
    results["command"] = command_line("benchmarks/bench_core.py", argv)
    results["threads"] = {var: os.environ.get(var) for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS",
                                                                 "OPENBLAS_NUM_THREADS")}
    results["keep_freed_memory"] = _KEPT["kept"]
    results["load_average_start"] = load_average()
    for name in args.only or SECTIONS:
        title, header, run = SECTIONS[name]
        print(f"\n## {title}\n")
        print(header)
        print("|---" * (header.count("|") - 1) + "|")
        results[name] = run(args.quick)
        results.setdefault("commands", {})[name] = results["command"]  # the run that made this section
    results["load_average_end"] = load_average()
    write_json(args.output, results, indent=2)
    print(f"\nwrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
