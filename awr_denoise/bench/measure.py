"""How the benchmarks measure: wall and CPU time, medians, peak memory and timed sampler loops.

Shared by ``awr bench`` and the scripts in ``benchmarks/`` so that every speed figure in the
docs is measured the same way. Timings read the clock through the :mod:`time` module at call
time (never a name bound at import), so a test can substitute a deterministic clock.
"""

from __future__ import annotations

import statistics
import sys
import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from scipy import ndimage

from .._typing import Shape2D
from ..buffers import SampleBuffer
from ..requests import Renderer
from ..sampling import Sampler

__all__ = ["Timing", "run_progressive", "timed", "median_time", "peak_memory", "noisy_buffer", "awr_command"]

T = TypeVar("T")


@dataclass
class Timing:
    """Seconds spent in the renderer and in the sampler (``ask`` + ``tell``) over a loop.

    Attributes
    ----------
    render, render_cpu
        Wall and process CPU seconds inside the renderer.
    sampler, sampler_cpu
        Wall and process CPU seconds inside ``ask`` and ``tell``.
    rounds
        Rounds (``ask``/``tell`` pairs) so far.
    """

    render: float = 0.0
    sampler: float = 0.0
    rounds: int = 0
    render_cpu: float = 0.0
    sampler_cpu: float = 0.0

    def copy(self) -> Timing:
        """An independent copy (the loop keeps adding to the original)."""
        return replace(self)

    def fields(self) -> dict[str, float]:
        """The timings under the benchmark's JSON keys.

        Examples
        --------
        >>> Timing(render=2.0, rounds=3).fields()["render_s"]
        2.0
        """
        return {"render_s": self.render, "sampler_s": self.sampler, "rounds": self.rounds,
                "render_cpu_s": self.render_cpu, "sampler_cpu_s": self.sampler_cpu}


def run_progressive(sampler: Sampler, renderer: Renderer, targets: Sequence[int],
                    on_snapshot: Callable[[int, SampleBuffer, Timing], None]) -> None:
    """Drive ``sampler`` with ask/tell up to each target spp in turn, timing render and sampler.

    Parameters
    ----------
    sampler
        The sampler; its rounds keep their default budget, the last one before a target is cut
        to land on it exactly.
    renderer
        Called with each request; returns the new samples' statistics.
    targets
        Average samples per pixel at which to stop and call ``on_snapshot`` (in increasing order).
    on_snapshot
        ``on_snapshot(spp, buffer, timing)`` at each target, with a copy of the timings so far.

    Examples
    --------
    >>> from awr_denoise import UniformSampler
    >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
    >>> renderer = SyntheticRenderer(make_scene("gradient", (8, 8)), seed=0)
    >>> seen = []
    >>> run_progressive(UniformSampler((8, 8)), renderer, [2, 4],
    ...                 lambda spp, buffer, timing: seen.append((spp, buffer.total_samples)))
    >>> seen
    [(2, 128), (4, 256)]
    """
    h, w = sampler.shape
    timing = Timing()
    for target in sorted(targets):
        goal = int(round(target * h * w))
        while sampler.total_samples < goal:
            budget = min(sampler.default_budget(), goal - sampler.total_samples)
            t0, c0 = time.perf_counter(), time.process_time()
            request = sampler.ask(budget)
            t1, c1 = time.perf_counter(), time.process_time()
            samples = renderer(request)
            t2, c2 = time.perf_counter(), time.process_time()
            sampler.tell(request, samples)
            t3, c3 = time.perf_counter(), time.process_time()
            timing.render += t2 - t1
            timing.sampler += (t1 - t0) + (t3 - t2)
            timing.render_cpu += c2 - c1
            timing.sampler_cpu += (c1 - c0) + (c3 - c2)
            timing.rounds += 1
        on_snapshot(target, sampler.buffer, timing.copy())


def timed(fn: Callable[[], T]) -> tuple[T, tuple[float, float]]:
    """``fn()``, and its (wall, CPU) seconds.

    Examples
    --------
    >>> value, (wall, cpu) = timed(lambda: 6 * 7)
    >>> value, wall >= 0.0, cpu >= 0.0
    (42, True, True)
    """
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, (time.perf_counter() - t, time.process_time() - c)


def median_time(fn: Callable[[], Any], repeats: int) -> float:
    """Median wall seconds of ``repeats`` calls of ``fn`` (warm it up before, if it caches).

    Examples
    --------
    >>> median_time(lambda: sum(range(100)), repeats=3) >= 0.0
    True
    """
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def peak_memory(fn: Callable[[], T]) -> tuple[T, int]:
    """``fn()``, and the peak bytes it allocated above what was live when it started.

    numpy registers its data buffers with :mod:`tracemalloc`, so the peak includes arrays;
    tracing slows allocation down, so time a call separately.

    Examples
    --------
    >>> _, peak = peak_memory(lambda: np.ones(1_000_000).sum())
    >>> peak >= 8_000_000
    True
    """
    tracemalloc.start()
    tracemalloc.reset_peak()
    base, _ = tracemalloc.get_traced_memory()
    try:
        out = fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return out, peak - base


def noisy_buffer(shape: Shape2D, spp: int = 4, seed: int = 0, *, smooth: float = 8.0,
                 noise: float = 0.05) -> SampleBuffer:
    """A synthetic RGB buffer to time the library on (its content barely changes the time).

    Means uniform in [0, 1), blurred by a Gaussian of ``smooth`` pixels (none when 0), plus
    normal noise of standard deviation ``noise`` (none when 0); per-sample variances uniform in
    [0, 0.1); ``spp`` samples at every pixel.

    Parameters
    ----------
    shape
        ``(height, width)``.
    spp
        Samples per pixel.
    seed
        Seed of the random numbers.
    smooth, noise
        Blur of the means and noise added to them.

    Returns
    -------
    SampleBuffer
        The buffer.

    Examples
    --------
    >>> buf = noisy_buffer((16, 24), spp=4)
    >>> buf.shape, int(buf.count.sum())
    ((16, 24), 1536)
    """
    rng = np.random.default_rng(seed)
    h, w = shape
    base = rng.uniform(0.0, 1.0, (h, w, 3))
    if smooth > 0:
        base = ndimage.gaussian_filter(base, (smooth, smooth, 0))
    var = rng.uniform(0.0, 0.1, (h, w, 3))
    mean = base + rng.normal(0, noise, base.shape) if noise > 0 else base
    return SampleBuffer.from_moments(np.full((h, w), spp), mean, var)


def awr_command() -> list[str]:
    """How a user starts ``awr``: the console script installed next to this interpreter, else the module.

    The scripts under ``benchmarks/`` time the command as a user runs it (its real start-up path); the tests of
    the command run it the same way.

    Examples
    --------
    >>> import subprocess
    >>> from awr_denoise.bench.measure import awr_command
    >>> subprocess.run([*awr_command(), "--version"], capture_output=True, text=True).stdout.split()[0]
    'awr'
    """
    script = Path(sys.executable).with_name("awr")
    return [str(script)] if script.exists() else [sys.executable, "-m", "awr_denoise.cli.main"]
