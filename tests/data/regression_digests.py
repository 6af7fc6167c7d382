"""Digests of the library's numerical outputs, to hold a restructuring to bit-identical results.

``python tests/data/regression_digests.py --write`` recomputes every case and stores the SHA-256
of each output array in ``regression_digests.json``; ``tests/test_regression_digests.py``
recomputes them and compares. Regenerate the file only for a change that is *meant* to alter
results (a new default, a fixed bug), and say so in the commit that does it.

Every case uses the synthetic renderer (its samples are a pure function of seed, pixel and
sample index) so the digests depend on the library alone, not on a path tracer's BVH.
"""

from __future__ import annotations

import argparse
import hashlib
import json
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

DIGESTS = Path(__file__).with_name("regression_digests.json")
SHAPE = (40, 56)


def digest(*arrays: np.ndarray) -> str:
    """SHA-256 of the arrays' dtypes, shapes and bytes."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _uniform(scene: str, spp: int = 8, seed: int = 1):
    renderer = SyntheticRenderer(make_scene(scene, SHAPE), seed=seed)
    return renderer(SampleRequest.uniform(SHAPE, spp))


def _adaptive(cls, scene: str, **options) -> str:
    sampler = cls(SHAPE, seed=3, **options)
    counts: list[np.ndarray] = []
    renderer = SyntheticRenderer(make_scene(scene, SHAPE), seed=2)
    buffer = sampler.run(renderer, 12, callback=lambda request, _: counts.append(request.counts))
    return digest(buffer.count, buffer.mean, buffer.variance, *counts)


def _cli(tmp: Path) -> dict[str, str]:
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
        "cli_denoise": digest(read_image(tmp / "out.exr")),
        "cli_denoise_linear": digest(read_image(tmp / "lin.exr")),
        "cli_plan": digest(request.counts, request.first_index),
        "cli_merge": digest(merged.count, merged.mean, merged.variance),
    }


CASES: dict[str, Callable[[], str]] = {
    # Stage 1 alone (stages=1): in the log domain in float32 (the default precision), elsewhere in
    # float64, the reconstruction of every earlier version bit for bit.
    "reconstruct_edges": lambda: digest(reconstruct(_uniform("edges"), stages=1)),
    "reconstruct_hdr_source": lambda: digest(reconstruct(_uniform("hdr_source"), stages=1)),
    "reconstruct_fireflies": lambda: digest(reconstruct(_uniform("fireflies"), stages=1)),
    "reconstruct_linear": lambda: digest(reconstruct(_uniform("hdr_source"), domain="linear", stages=1)),
    "reconstruct_gamma_haar": lambda: digest(reconstruct(_uniform("edges"), domain="gamma", wavelet="haar",
                                                         levels=2, stages=1)),
    "reconstruct_luminance": lambda: digest(reconstruct(_uniform("fireflies"), mode="luminance", c_s=2.0, stages=1)),
    "reconstruct_no_clamp": lambda: digest(reconstruct(_uniform("gradient", 3), pixel_clamp=None, stages=1)),
    "reconstruct_sparse": lambda: digest(reconstruct(_uniform("edges", 1), stages=1)),
    "reconstruct_detailed": lambda: digest(*(lambda r: (r.image, r.variance))(
        reconstruct_detailed(_uniform("edges"), variance_probes=4, stages=1))),
    # The default: stage 1 as the pilot of the Wiener stages, the guard and the finishing steps.
    "stages_edges": lambda: digest(reconstruct(_uniform("edges"))),
    "stages_hdr_source": lambda: digest(reconstruct(_uniform("hdr_source"))),
    "stages_fireflies": lambda: digest(reconstruct(_uniform("fireflies"))),
    "stages_luminance": lambda: digest(reconstruct(_uniform("fireflies"), mode="luminance")),
    "stages_float64": lambda: digest(reconstruct(_uniform("hdr_source"), precision="float64")),
    "stages_detailed": lambda: digest(*(lambda r: (r.image, r.variance))(
        reconstruct_detailed(_uniform("edges"), variance_probes=4))),
    "sampling_density": lambda: digest(sampling_density(_uniform("edges", 4))),
    "adaptive_edges": lambda: _adaptive(AdaptiveSampler, "edges"),
    "adaptive_fireflies": lambda: _adaptive(AdaptiveSampler, "fireflies", round_growth=0.5),
    "variance_hdr_source": lambda: _adaptive(VarianceSampler, "hdr_source"),
    "uniform_gradient": lambda: _adaptive(UniformSampler, "gradient"),
}


def compute() -> dict[str, str]:
    """Every case's digest, the command-line ones included (they need the ``exr`` extra)."""
    out = {name: case() for name, case in CASES.items()}
    with tempfile.TemporaryDirectory() as tmp:
        out.update(_cli(Path(tmp)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"store the digests in {DIGESTS.name}")
    args = parser.parse_args()
    digests = compute()
    # Compared with what was stored before writing: after --write, the file says nothing.
    stored = json.loads(DIGESTS.read_text(encoding="utf-8")) if DIGESTS.exists() else {}
    if args.write:
        DIGESTS.write_text(json.dumps(digests, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    for name, value in digests.items():
        print(f"{name:28s} {'same' if stored.get(name) == value else 'DIFFERENT'}")


if __name__ == "__main__":
    main()
