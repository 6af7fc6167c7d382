"""Stored outputs of the library, to hold a restructuring to the same results.

``python tests/data/regression_outputs.py --write`` recomputes every case and stores its output
arrays in ``regression_outputs.npz``; ``tests/test_regression_outputs.py`` recomputes them and
compares. Regenerate the file only for a change that is *meant* to alter results (a new default,
a fixed bug), and say so in the commit that does it.

Integer arrays (sample counts, requests) must match exactly. Float arrays must match to a
tolerance relative to the array's largest magnitude: :data:`FLOAT64_TOL` where every step runs in
float64, :data:`FLOAT32_TOL` where the transforms run in float32 (the log domain at the default
precision). Bit-exact digests were used before; they broke on another CPU, whose numpy takes
other SIMD paths: with numpy's AVX-512 paths, or its AVX-512, AVX2 and FMA paths, disabled
(``NPY_DISABLE_CPU_FEATURES``) the float64 cases move by at most 2.3e-15 of their scale, the
float32 ones by at most 1.1e-6 for images and 4.0e-5 for the probes' variance estimate; sample
counts stay the same. A default changed by 10% moves them by far more (a test says so).

Every case uses the synthetic renderer (its samples are a pure function of seed, pixel and
sample index) so the outputs depend on the library alone, not on a path tracer's BVH.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from awr_denoise import AdaptiveSampler, SampleRequest, UniformSampler, VarianceSampler, reconstruct
from awr_denoise import reconstruct_detailed
from awr_denoise.priorities import sampling_density
from awr_denoise.synthetic import SyntheticRenderer, make_scene

OUTPUTS = Path(__file__).with_name("regression_outputs.npz")
SHAPE = (40, 56)
FLOAT64_TOL = 1e-9
"""Tolerance, relative to the array's largest magnitude, of the cases computed in float64."""
FLOAT32_TOL = 5e-4
"""Tolerance of the cases whose transforms run in float32: 12x the largest move measured across SIMD paths."""
FLOAT32_CASES = frozenset({"reconstruct_edges", "reconstruct_hdr_source", "reconstruct_fireflies",
                           "reconstruct_luminance", "reconstruct_no_clamp", "reconstruct_sparse",
                           "reconstruct_detailed", "stages_edges", "stages_hdr_source", "stages_fireflies",
                           "stages_luminance", "stages_detailed", "cli_denoise"})
"""The cases in the log domain at the default precision, whose transforms run in float32."""


def arrays(*values: np.ndarray) -> tuple[np.ndarray, ...]:
    """The output arrays of one case, as plain arrays."""
    return tuple(np.array(v) for v in values)


def _uniform(scene: str, spp: int = 8, seed: int = 1):
    renderer = SyntheticRenderer(make_scene(scene, SHAPE), seed=seed)
    return renderer(SampleRequest.uniform(SHAPE, spp))


def _adaptive(cls, scene: str, **options) -> tuple[np.ndarray, ...]:
    sampler = cls(SHAPE, seed=3, **options)
    counts: list[np.ndarray] = []
    renderer = SyntheticRenderer(make_scene(scene, SHAPE), seed=2)
    buffer = sampler.run(renderer, 12, callback=lambda request, _: counts.append(request.counts))
    return arrays(buffer.count, buffer.mean, buffer.variance, *counts)


def _cli(tmp: Path) -> dict[str, tuple[np.ndarray, ...]]:
    """``awr denoise``, ``awr plan`` and ``awr merge`` on dumps written by the library."""
    from awr_denoise.io import read_image, read_request, read_sample_buffer, write_sample_buffer

    a, b = _uniform("edges", 4, seed=5), _uniform("edges", 4, seed=6)
    write_sample_buffer(tmp / "a.exr", a)
    write_sample_buffer(tmp / "b.exr", b)
    awr = [sys.executable, "-m", "awr_denoise.cli.main"]
    runs = {
        "cli_denoise": ["denoise", str(tmp / "a.exr"), "-o", str(tmp / "out.exr"), "-q"],
        "cli_denoise_linear": ["denoise", str(tmp / "a.exr"), "-o", str(tmp / "lin.exr"), "--domain", "linear",
                               "--c-s", "1.5", "--stages", "1", "-q"],
        "cli_plan": ["plan", str(tmp / "a.exr"), "-o", str(tmp / "req.exr"), "--round-spp", "2", "-q"],
        "cli_merge": ["merge", str(tmp / "a.exr"), str(tmp / "b.exr"), "-o", str(tmp / "m.exr"), "-q"],
    }
    for args in runs.values():
        subprocess.run(awr + args, check=True)
    merged = read_sample_buffer(tmp / "m.exr")
    request = read_request(tmp / "req.exr")
    return {
        "cli_denoise": arrays(read_image(tmp / "out.exr")),
        "cli_denoise_linear": arrays(read_image(tmp / "lin.exr")),
        "cli_plan": arrays(request.counts, request.first_index),
        "cli_merge": arrays(merged.count, merged.mean, merged.variance),
    }


CASES: dict[str, Callable[[], tuple[np.ndarray, ...]]] = {
    # Stage 1 alone (stages=1): in the log domain in float32 (the default precision), elsewhere in
    # float64, the reconstruction of every earlier version bit for bit.
    "reconstruct_edges": lambda: arrays(reconstruct(_uniform("edges"), stages=1)),
    "reconstruct_hdr_source": lambda: arrays(reconstruct(_uniform("hdr_source"), stages=1)),
    "reconstruct_fireflies": lambda: arrays(reconstruct(_uniform("fireflies"), stages=1)),
    "reconstruct_linear": lambda: arrays(reconstruct(_uniform("hdr_source"), domain="linear", stages=1)),
    "reconstruct_gamma_haar": lambda: arrays(reconstruct(_uniform("edges"), domain="gamma", wavelet="haar",
                                                         levels=2, stages=1)),
    "reconstruct_luminance": lambda: arrays(reconstruct(_uniform("fireflies"), mode="luminance", c_s=2.0, stages=1)),
    "reconstruct_no_clamp": lambda: arrays(reconstruct(_uniform("gradient", 3), pixel_clamp=None, stages=1)),
    "reconstruct_sparse": lambda: arrays(reconstruct(_uniform("edges", 1), stages=1)),
    "reconstruct_detailed": lambda: arrays(*(lambda r: (r.image, r.variance))(
        reconstruct_detailed(_uniform("edges"), variance_probes=4, stages=1))),
    # The default: stage 1 as the pilot of the Wiener stages, the guard and the finishing steps.
    "stages_edges": lambda: arrays(reconstruct(_uniform("edges"))),
    "stages_hdr_source": lambda: arrays(reconstruct(_uniform("hdr_source"))),
    "stages_fireflies": lambda: arrays(reconstruct(_uniform("fireflies"))),
    "stages_luminance": lambda: arrays(reconstruct(_uniform("fireflies"), mode="luminance")),
    "stages_float64": lambda: arrays(reconstruct(_uniform("hdr_source"), precision="float64")),
    "stages_detailed": lambda: arrays(*(lambda r: (r.image, r.variance))(
        reconstruct_detailed(_uniform("edges"), variance_probes=4))),
    "sampling_density": lambda: arrays(sampling_density(_uniform("edges", 4))),
    "adaptive_edges": lambda: _adaptive(AdaptiveSampler, "edges"),
    "adaptive_fireflies": lambda: _adaptive(AdaptiveSampler, "fireflies", round_growth=0.5),
    "variance_hdr_source": lambda: _adaptive(VarianceSampler, "hdr_source"),
    "uniform_gradient": lambda: _adaptive(UniformSampler, "gradient"),
}


def compute() -> dict[str, tuple[np.ndarray, ...]]:
    """Every case's output arrays, the command-line ones included (they need the ``exr`` extra)."""
    out = {name: case() for name, case in CASES.items()}
    with tempfile.TemporaryDirectory() as tmp:
        out.update(_cli(Path(tmp)))
    return out


def load() -> dict[str, tuple[np.ndarray, ...]]:
    """The stored outputs, as :func:`compute` returns them."""
    out: dict[str, list[np.ndarray]] = {}
    with np.load(OUTPUTS) as data:  # keys are "name/index"
        for name, index in sorted((k.rsplit("/", 1)[0], int(k.rsplit("/", 1)[1])) for k in data.files):
            out.setdefault(name, []).append(data[f"{name}/{index}"])
    return {name: tuple(arrays) for name, arrays in out.items()}


def deviation(name: str, computed: tuple[np.ndarray, ...], stored: tuple[np.ndarray, ...]) -> str | None:
    """Why ``computed`` is not ``stored`` within the case's tolerance, or None when it is."""
    if len(computed) != len(stored):
        return f"{name}: {len(computed)} arrays, {len(stored)} stored"
    tol = FLOAT32_TOL if name in FLOAT32_CASES else FLOAT64_TOL
    for i, (a, b) in enumerate(zip(computed, stored)):
        if a.shape != b.shape or a.dtype.kind != b.dtype.kind:
            return f"{name}[{i}]: {a.dtype}{a.shape}, stored {b.dtype}{b.shape}"
        if a.dtype.kind in "iub":
            if not np.array_equal(a, b):
                return f"{name}[{i}]: {int((a != b).sum())} integers differ"
            continue
        if np.array_equal(a, b, equal_nan=True):
            continue
        if not (np.isfinite(a).all() and np.isfinite(b).all()):
            return f"{name}[{i}]: non-finite values differ"
        scale = float(np.abs(b).max()) or 1.0
        moved = float(np.abs(a - b).max()) / scale
        if moved > tol:
            return f"{name}[{i}]: moved {moved:.2e} of its scale (tolerance {tol:g})"
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"store the outputs in {OUTPUTS.name}")
    args = parser.parse_args()
    computed = compute()
    # Compared with what was stored before writing: after --write, the file says nothing.
    stored = load() if OUTPUTS.exists() else {}
    if args.write:
        np.savez_compressed(OUTPUTS, **{f"{name}/{i}": a for name, values in computed.items()
                                        for i, a in enumerate(values)})
    for name, values in computed.items():
        why = deviation(name, values, stored[name]) if name in stored else f"{name}: not stored"
        print(f"{name:28s} {'same' if why is None else 'DIFFERENT: ' + why}")


if __name__ == "__main__":
    main()
