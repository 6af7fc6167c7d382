"""A stand-in for a renderer that is not written in Python, talking to ``awr`` through files only.

It uses numpy and the OpenEXR bindings, nothing from awr_denoise, so it shows exactly what
another program has to read and write (see docs/integrate_external_renderer.md)::

    python external_renderer.py REQUEST.exr BATCH.exr        # render the requested samples
    python external_renderer.py --reference W H REF.exr      # the noise-free image

The image is analytic: a smooth gradient with a sharp-edged disc; every sample adds
noise whose random numbers depend only on (seed, pixel, sample index), so the same
sample is identical however the work is split into rounds.
"""

from __future__ import annotations

import sys

import numpy as np
import OpenEXR


def clean(x: np.ndarray, y: np.ndarray, width: int, height: int) -> np.ndarray:
    """(N, 3) noise-free radiance at continuous pixel positions ``x``, ``y``."""
    u, v = x / width, y / height
    disc = ((u - 0.6) ** 2 + (v - 0.45) ** 2 < 0.07).astype(np.float64)
    base = 0.2 + 0.6 * u
    return np.stack([base + 0.8 * disc, 0.3 + 0.4 * v + 0.2 * disc, 0.5 - 0.3 * u * v + 0.5 * disc], axis=-1)


def _uniform(seed: int, pixel: np.ndarray, index: np.ndarray, dim: int) -> np.ndarray:
    # A counter-based hash (splitmix64 finaliser): one number per (seed, pixel, index, dim).
    with np.errstate(over="ignore"):
        z = (np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + pixel.astype(np.uint64) * np.uint64(0xBF58476D1CE4E5B9)
             + index.astype(np.uint64) * np.uint64(0x94D049BB133111EB) + np.uint64(dim) * np.uint64(0x2545F4914F6CDD1D))
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) / float(2**53)


def render_samples(counts: np.ndarray, first_index: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(pixel, values): flat pixel index and (N, 3) value of every requested sample."""
    height, width = counts.shape
    flat = counts.ravel().astype(np.int64)
    pixel = np.repeat(np.arange(flat.size, dtype=np.int64), flat)
    starts = np.cumsum(flat) - flat
    index = first_index.ravel().astype(np.int64)[pixel] + np.arange(pixel.size) - np.repeat(starts, flat)
    row, col = np.divmod(pixel, width)
    x = col + _uniform(seed, pixel, index, 0)
    y = row + _uniform(seed, pixel, index, 1)
    noise = 0.4 * (_uniform(seed, pixel, index, 2) - 0.5)[:, None] * np.array([1.0, 0.8, 1.2])
    return pixel, clean(x, y, width, height) + noise


def _read_request(path: str) -> tuple[np.ndarray, np.ndarray, int, dict[str, str]]:
    with OpenEXR.File(path, separate_channels=True) as f:
        ch = f.channels()
        counts = ch["counts"].pixels.astype(np.int64)  # FLOAT channels holding whole numbers
        first = ch["first_index"].pixels.astype(np.int64)
        # Read header values inside the block: the header dict is emptied when the file closes.
        header = f.header()
        seed = int(str(header.get("awr:seed", 0)))
        # Which request the batch answers, so that merge refuses it with another (a stale batch).
        answers = {"awr:request_round": str(header.get("awr:round", 0)),
                   "awr:request_total": str(header.get("awr:total", int(counts.sum())))}
    return counts, first, seed, answers


def write_batch(path: str, counts: np.ndarray, pixel: np.ndarray, values: np.ndarray,
                answers: dict[str, str] | None = None) -> None:
    """Per-pixel count, mean and unbiased per-sample variance in the awr dump layout, and the
    request it answers (``awr:request_round``, ``awr:request_total``) when given."""
    height, width = counts.shape
    n = np.bincount(pixel, minlength=height * width).astype(np.float64)
    safe = np.maximum(n, 1.0)
    channels = {"sampleCount": n.reshape(height, width).astype(np.float32)}
    for c, name in enumerate("RGB"):
        mean = np.bincount(pixel, weights=values[:, c], minlength=n.size) / safe
        m2 = np.bincount(pixel, weights=(values[:, c] - mean[pixel]) ** 2, minlength=n.size)
        var = np.where(n > 1, m2 / np.maximum(n - 1, 1), 0.0)
        channels[name] = mean.reshape(height, width).astype(np.float32)
        channels["variance." + name] = var.reshape(height, width).astype(np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "awr:variance_kind": "sample", **(answers or {})}
    with OpenEXR.File(header, channels) as f:
        f.write(path)


def write_reference(path: str, width: int, height: int, supersampling: int = 8) -> None:
    """The noise-free image, box-filtered over each pixel."""
    s = (np.arange(supersampling) + 0.5) / supersampling
    yy, xx = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    acc = np.zeros((height, width, 3))
    for dy in s:  # a loop over sub-pixel offsets; every pixel is vectorised
        for dx in s:
            acc += clean((xx + dx).ravel(), (yy + dy).ravel(), width, height).reshape(height, width, 3)
    acc /= supersampling**2
    channels = {name: acc[..., c].astype(np.float32) for c, name in enumerate("RGB")}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, channels) as f:
        f.write(path)


def main(argv: list[str]) -> int:
    if len(argv) == 4 and argv[0] == "--reference":
        write_reference(argv[3], int(argv[1]), int(argv[2]))
        return 0
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    counts, first, seed, answers = _read_request(argv[0])
    pixel, values = render_samples(counts, first, seed)
    write_batch(argv[1], counts, pixel, values, answers)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
