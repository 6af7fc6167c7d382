"""Valid inputs where the default reconstruction loses to the plain mean (docs/reconstruction.md, "Where the
default loses to the plain mean").

Run from the repository root::

    .venv/bin/python benchmarks/bench_limits.py [--chances]

Six synthetic kinds of image, each with a known clean image, many noise seeds, and the same samples given to
every method: isolated true bright pixels (glints), samples that are either a hit or exactly 0 (a small light
reached now and then), a light seen directly on an exact background (its rim hit or missed), a noisy lit object
in a black void, texture at the scale of one pixel, and a dark line one pixel wide in a bright field.
Each cell is a ratio to the plain mean's error over the same renders: of the summed MSE (or relMSE) over every
seed (the average render), and the worst single render's ratio. Beside the default: without the SURE guard,
without the image mean's restoration, and stage 1 alone, which says which part of the default each loss comes
from; the guard given the Wiener stages' divergence measured by one probe (``guard_probes=1``); the clamp as
it was before its neighbours were tested (and, with ``--chances``, at smaller least chances than the default's);
the default before a light's rim stopped lending its spread to the exact pixels beside it.
Results: ``benchmarks/results/limits.json``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
from scipy import ndimage

from awr_denoise import SampleBuffer, finishing, reconstruct, rims
from awr_denoise.bench import update_section
from awr_denoise.bench.records import results_file
from awr_denoise.metrics import mse, relmse

RESULTS = Path(__file__).resolve().parent / "results" / "limits.json"
METHODS: dict[str, dict[str, Any]] = {"default": {}, "no guard": {"guard": False},
                                      "no mean restoration": {"preserve_mean": False}, "stage 1": {"stages": 1},
                                      "guard probes 1": {"guard_probes": 1}}
CHANCES: dict[str, float] = {"clamp pools every neighbour": 0.0}
"""Columns of the default with ``finishing.POOL_CHANCE`` at another value; 0 is the form before the clamp's
neighbours were tested (docs/reconstruction.md, "The clamp's neighbours")."""
MORE_CHANCES: dict[str, float] = {"pool chance 1e-4": 1e-4, "pool chance 1e-5": 1e-5}
"""``--chances``: smaller least chances than the default's 1e-3."""


def at_chance(buffer: SampleBuffer, chance: float) -> np.ndarray:
    """The default reconstruction with ``finishing.POOL_CHANCE`` at ``chance`` (put back afterwards)."""
    with mock.patch.object(finishing, "POOL_CHANCE", chance):
        return reconstruct(buffer)


def rims_lend(buffer: SampleBuffer) -> np.ndarray:
    """The default as it was before a light's rim stopped lending its spread to the exact pixels beside it
    (``rims.EDGE_BLOCK`` out of reach: no pixel is a rim; docs/reconstruction.md, "Samples that all agreed")."""
    with mock.patch.object(rims, "EDGE_BLOCK", sys.maxsize):
        return reconstruct(buffer)


def gaussian(truth: np.ndarray, spp: int, relative_sd: float, rng: np.random.Generator) -> SampleBuffer:
    """Means and per-sample variances of ``spp`` Gaussian samples of sd ``relative_sd * truth`` per pixel."""
    sd = relative_sd * truth
    mean = truth + sd / np.sqrt(spp) * rng.standard_normal(truth.shape)
    variance = sd**2 * rng.chisquare(spp - 1, truth.shape) / (spp - 1)  # the sample variance's own noise
    return SampleBuffer.from_moments(np.full(truth.shape[:2], spp), mean, variance)


def glints(spp: int, rng: np.random.Generator) -> tuple[np.ndarray, SampleBuffer]:
    """30 true bright pixels of 5-50 on a background of 0.2, 64x64 RGB, relative noise 0.5."""
    truth = np.full((64, 64, 3), 0.2)
    truth.reshape(-1, 3)[rng.choice(64 * 64, 30, replace=False)] = rng.uniform(5, 50, (30, 1))
    return truth, gaussian(truth, spp, 0.5, rng)


def one_glint(spp: int, rng: np.random.Generator) -> tuple[np.ndarray, SampleBuffer]:
    """One pixel of 30 on 0.1, 32x32, one channel, relative noise 0.5."""
    truth = np.full((32, 32, 1), 0.1)
    truth[16, 16] = 30.0
    return truth, gaussian(truth, spp, 0.5, rng)


def hit_or_zero(p: float) -> Any:
    def make(spp: int, rng: np.random.Generator) -> tuple[np.ndarray, SampleBuffer]:
        """Samples of 0.3 / p with probability p, else exactly 0: a constant image of 0.3, 64x64."""
        pixel = np.repeat(np.arange(64 * 64), spp)
        values = 0.3 * (rng.random(pixel.size) < p) / p
        return np.full((64, 64, 1), 0.3), SampleBuffer.from_samples(pixel, values, (64, 64))
    return make


def covered(radiance: Any, spp: int, rng: np.random.Generator, moving: bool = False,
            noisy: bool = False) -> tuple[np.ndarray, SampleBuffer]:
    """64x64 RGB pixels of ``radiance(y, x[, t])`` (one channel, repeated), each sample at a uniform point of its
    pixel (and time in [0, 1) where ``moving``): the clean image is each pixel's mean over 64x64 points (and 8
    times), the samples hit or miss what they cover; ``noisy``: each sample also times an exponential draw of
    mean 1 (a surface lit by indirect light)."""
    h = w = 64
    grid = (np.arange(64) + 0.5) / 64
    y, x = np.arange(h)[:, None, None, None] + grid[:, None], np.arange(w)[None, :, None, None] + grid
    if moving:
        truth = np.mean([radiance(y, x, (k + 0.5) / 8).mean(axis=(2, 3)) for k in range(8)], axis=0)
    else:
        truth = radiance(y, x).mean(axis=(2, 3))
    pixel = np.repeat(np.arange(h * w), spp)
    at = (pixel // w + rng.random(pixel.size), pixel % w + rng.random(pixel.size))
    values = radiance(*at, rng.random(pixel.size)) if moving else radiance(*at)
    if noisy:
        values = values * rng.exponential(1.0, values.size)
    return truth[..., None] * np.ones(3), SampleBuffer.from_samples(pixel, values[:, None] * np.ones(3), (h, w))


def light_on_black(background: float, radius: float = 2.5, level: float = 100.0) -> Any:
    def make(spp: int, rng: np.random.Generator) -> tuple[np.ndarray, SampleBuffer]:
        """A disc of ``level`` on an exact ``background``: the rim hits or misses the light, every other pixel is
        exact (a light seen directly against an empty backdrop)."""
        def radiance(y: np.ndarray, x: np.ndarray) -> np.ndarray:
            return np.where((y - 32.2) ** 2 + (x - 32.3) ** 2 < radius**2, level, background)
        return covered(radiance, spp, rng)
    return make


def lit_disc(level: float) -> Any:
    def make(spp: int, rng: np.random.Generator) -> tuple[np.ndarray, SampleBuffer]:
        """A lit surface of mean ``level`` with noisy samples (exponential) filling a disc of radius 12 on exact
        black: an object in a black void, its rim hit or missed (relMSE's fixed 0.01 weighs the black pixels' error
        1e4 times as much at 100 as at 1)."""
        def radiance(y: np.ndarray, x: np.ndarray) -> np.ndarray:
            return np.where((y - 32.2) ** 2 + (x - 32.3) ** 2 < 12.0**2, level, 0.0)
        return covered(radiance, spp, rng, noisy=True)
    return make


def small_lights(spp: int, rng: np.random.Generator) -> tuple[np.ndarray, SampleBuffer]:
    """Twelve lights of 1000 and radius 1.2 pixels on black: too small for an exact inside."""
    centres = rng.uniform(4, 60, (12, 2))

    def radiance(y: np.ndarray, x: np.ndarray) -> np.ndarray:
        inside = np.zeros(np.broadcast(y, x).shape, dtype=bool)
        for cy, cx in centres:
            inside |= (y - cy) ** 2 + (x - cx) ** 2 < 1.2**2
        return np.where(inside, 1000.0, 0.0)
    return covered(radiance, spp, rng)


def moving_light(spp: int, rng: np.random.Generator) -> tuple[np.ndarray, SampleBuffer]:
    """A light of 100 and radius 3 pixels on black, moving 8 pixels across the exposure: its trail hits or misses."""
    def radiance(y: np.ndarray, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        return np.where((y - 32.2) ** 2 + (x - 28.3 - 8.0 * t) ** 2 < 3.0**2, 100.0, 0.0)
    return covered(radiance, spp, rng, moving=True)


def texture(low: float, high: float, log: bool, blur: float = 0.0) -> Any:
    def make(spp: int, rng: np.random.Generator) -> tuple[np.ndarray, SampleBuffer]:
        """Every pixel its own value, U(low, high) or 10^U(low, high), 64x64, relative noise 0.5; ``blur``:
        then filtered by a Gaussian of that many pixels (as a pixel's footprint filters texture)."""
        draw = rng.uniform(low, high, (64, 64, 1))
        truth = 10.0**draw if log else draw
        if blur:
            truth = ndimage.gaussian_filter(truth, (blur, blur, 0), mode="reflect")
        return truth, gaussian(truth, spp, 0.5, rng)
    return make


def dark_line(level: float, width: int = 1) -> Any:
    def make(spp: int, rng: np.random.Generator) -> tuple[np.ndarray, SampleBuffer]:
        """``width`` columns of 0.01 in a field of ``level``, 64x64, relative noise 0.5."""
        truth = np.full((64, 64, 1), level)
        truth[:, 32:32 + width] = 0.01
        return truth, gaussian(truth, spp, 0.5, rng)
    return make


CASES: list[tuple[str, Any, tuple[int, ...], int]] = [
    ("30 glints of 5-50 on 0.2, RGB", glints, (4, 16, 64), 40),
    ("one glint of 30 on 0.1", one_glint, (4, 16), 40),
    ("hit or zero, p = 0.02", hit_or_zero(0.02), (2, 4, 8, 64), 12),
    ("hit or zero, p = 0.1", hit_or_zero(0.1), (2, 4, 8), 12),
    ("hit or zero, p = 0.5", hit_or_zero(0.5), (2, 4), 12),
    ("a light of 100 seen directly on black", light_on_black(0.0), (2, 4, 16, 64), 8),
    ("the same on an exact 0.05", light_on_black(0.05), (2, 4, 16, 64), 8),
    ("twelve lights of 1000, radius 1.2, on black", small_lights, (2, 4, 16), 8),
    ("a noisy lit disc of 1 on black", lit_disc(1.0), (4, 8, 32), 8),
    ("a noisy lit disc of 100 on black", lit_disc(100.0), (4, 8, 32), 8),
    ("a light of 100 moving 8 px, on black", moving_light, (2, 4, 16), 8),
    ("pixel-scale texture, U(0.2, 0.8)", texture(0.2, 0.8, False), (4, 16, 64, 256), 8),
    ("pixel-scale texture, 10^U(-1, 1)", texture(-1.0, 1.0, True), (4, 16, 64, 256), 8),
    ("the same, blurred by 0.5 px", texture(-1.0, 1.0, True, 0.5), (4, 16), 8),
    ("the same, blurred by 1 px", texture(-1.0, 1.0, True, 1.0), (4, 16), 8),
    ("dark 1-px line in a field of 1", dark_line(1.0), (8,), 8),
    ("dark 1-px line in a field of 10", dark_line(10.0), (8, 64), 8),
    ("dark 1-px line in a field of 100", dark_line(100.0), (8,), 8),
    ("dark 2-px line in a field of 100", dark_line(100.0, 2), (8,), 8),
    ("dark 3-px line in a field of 100", dark_line(100.0, 3), (8,), 8),
]
"""(name, make, spps, seeds) of every case; ``make(spp, rng)`` gives the clean image and the buffer of one render."""


def run(seed_scale: float = 1.0, chances: dict[str, float] = CHANCES) -> list[dict[str, Any]]:
    rows = []
    for name, make, spps, seeds in CASES:
        for spp in spps:
            for seed in range(max(1, round(seeds * seed_scale))):
                truth, buffer = make(spp, np.random.default_rng(1000 * spp + seed))
                images = {"plain": buffer.mean, **{m: reconstruct(buffer, **o) for m, o in METHODS.items()},
                          **{m: at_chance(buffer, c) for m, c in chances.items()}, "rims lend": rims_lend(buffer)}
                for method, image in images.items():
                    rows.append({"case": name, "spp": spp, "seed": seed, "method": method,
                                 "mse": mse(image, truth), "relmse": relmse(image, truth),
                                 "mean_change": float(np.abs(image.mean() / buffer.mean.mean() - 1))})
    return rows


def table(rows: list[dict[str, Any]]) -> None:
    methods = list(dict.fromkeys(r["method"] for r in rows if r["method"] != "plain"))
    print("\n| case | spp | seeds | " + " | ".join(f"{m}: MSE, relMSE / plain (worst render)" for m in methods)
          + " | largest image-mean change: default, no mean restoration |")
    print("|---|---|---|" + "---|" * (len(methods) + 1))
    for case, spp in dict.fromkeys((r["case"], r["spp"]) for r in rows):
        same = [r for r in rows if r["case"] == case and r["spp"] == spp]
        plain = {r["seed"]: r for r in same if r["method"] == "plain"}
        cells = []
        for method in methods:
            mine = [r for r in same if r["method"] == method]
            ratio = {k: sum(r[k] for r in mine) / sum(plain[r["seed"]][k] for r in mine) for k in ("mse", "relmse")}
            worst = max(r["mse"] / plain[r["seed"]]["mse"] for r in mine)
            cells.append(f"{ratio['mse']:.2f}, {ratio['relmse']:.2f} ({worst:.2f})")
        change = [max(r["mean_change"] for r in same if r["method"] == m) for m in ("default", "no mean restoration")]
        print(f"| {case} | {spp} | {len(plain)} | " + " | ".join(cells)
              + f" | {100 * change[0]:.2g}%, {100 * change[1]:.2g}% |")


def _scale(value: str) -> float:
    """``--seed-scale``: a finite number above 0 (NaN, infinity, 0 or below were a late error or one seed)."""
    try:
        scale = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{value!r} is not a number") from None
    if not math.isfinite(scale) or scale <= 0:
        raise argparse.ArgumentTypeError(f"{value} is not a finite number above 0")
    return scale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed-scale", type=_scale, default=1.0, help="seeds per case times this (a quick look: 0.25)")
    parser.add_argument("--chances", action="store_true",
                        help="also the default at smaller least chances for the clamp's neighbours (MORE_CHANCES)")
    parser.add_argument("--output", type=results_file, default=RESULTS)
    args = parser.parse_args(argv)
    rows = run(args.seed_scale, {**CHANCES, **(MORE_CHANCES if args.chances else {})})
    update_section(args.output, "limits", rows, "benchmarks/bench_limits.py " + " ".join(argv or sys.argv[1:]))
    table(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
