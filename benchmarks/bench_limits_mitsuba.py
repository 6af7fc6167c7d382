"""Mitsuba 3 scenes the quality benchmarks do not have, where the default reconstruction loses to the plain mean
(docs/reconstruction.md, "Where the default loses to the plain mean", "On Mitsuba 3 scenes of other kinds").

Run from the repository root (needs the extra ``mitsuba``; about 10 minutes on two cores, the references cached)::

    .venv/bin/python benchmarks/bench_limits_mitsuba.py [--seeds 4] [--scenes stars ...]

Each scene is built from a Python dict (no files), rendered at 128x128 through the adapter with uniform sampling
(renderer seeds 1 to ``--seeds``, each its own render) and compared, with the default ``reconstruct(buffer)`` and
the plain per-pixel mean, against the adapter's own uniform render at the scene's reference spp (passes of 256 spp,
seeds from 1 000 000 on, which no measured render uses). Cells: the default's relMSE and MSE over the plain mean's,
summed over the renders (the average render), and in brackets how many renders lose; the image mean's shift, the
default's image mean against the plain mean's over the reference's, averaged over the renders (the plain mean is
unbiased: a shift of one sign on every render is the default's bias), and its largest magnitude.
Results: ``benchmarks/results/limits_mitsuba.json``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from awr_denoise import SampleRequest, reconstruct
from awr_denoise.bench import update_section
from awr_denoise.bench.cache import load_arrays, save_arrays
from awr_denoise.bench.records import results_file
from awr_denoise.metrics import mse, relmse

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_reconstruct import recorded_command  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "limits_mitsuba.json"
SHAPE = (128, 128)
SPPS = (4, 8, 32, 128)
REFERENCE_SEED = 1_000_000
PASS_SPP = 256


def _camera(mi: Any, origin: list[float], target: list[float], fov: float = 40.0) -> dict[str, Any]:
    return {"type": "perspective", "fov": fov,
            "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": SHAPE[1], "height": SHAPE[0], "rfilter": {"type": "box"},
                     "pixel_format": "rgb"}}


def _rgb(r: float, g: float | None = None, b: float | None = None) -> dict[str, Any]:
    return {"type": "rgb", "value": [r, r if g is None else g, r if b is None else b]}


def _emitter(r: float, g: float | None = None, b: float | None = None) -> dict[str, Any]:
    return {"type": "area", "radiance": _rgb(r, g, b)}


def _floor(mi: Any, size: float, albedo: float) -> dict[str, Any]:
    return {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(size),
            "bsdf": {"type": "diffuse", "reflectance": _rgb(albedo)}}


def stars(mi: Any) -> dict[str, Any]:
    """Forty emissive spheres of radius 0.15-0.7 pixels and radiance 1-1000 seen directly on black."""
    rng = np.random.default_rng(7)
    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 2},
             "sensor": _camera(mi, [0, 0, 5], [0, 0, 0])}
    for i in range(40):  # a pixel is about 0.028 scene units at the stars' depth
        x, y = rng.uniform(-1.6, 1.6, 2)
        radius, level = rng.uniform(0.004, 0.02), 10 ** rng.uniform(0, 3)
        scene[f"star{i}"] = {"type": "sphere", "center": [float(x), float(y), 0.0], "radius": float(radius),
                             "emitter": _emitter(level, 0.8 * level, 0.6 * level)}
    return scene


def caustic(mi: Any) -> dict[str, Any]:
    """A glass sphere on a diffuse floor, lit only by a sphere light of radius 0.03 and radiance 3000."""
    return {"type": "scene", "integrator": {"type": "path", "max_depth": 8},
            "sensor": _camera(mi, [0, 2.5, 5], [0, 0.6, 0], fov=35),
            "floor": _floor(mi, 5, 0.7),
            "glass": {"type": "sphere", "center": [0, 0.7, 0], "radius": 0.7,
                      "bsdf": {"type": "dielectric", "int_ior": 1.5}},
            "light": {"type": "sphere", "center": [0.8, 3.5, -0.5], "radius": 0.03, "emitter": _emitter(3000.0)}}


def glints(mi: Any) -> dict[str, Any]:
    """Four GGX conductor spheres (alpha 0.02-0.5) under a sphere light of radiance 400 and a dim constant fill."""
    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 6},
             "sensor": _camera(mi, [0, 1.6, 5], [0, 0.5, 0]),
             "floor": _floor(mi, 6, 0.3),
             "fill": {"type": "constant", "radiance": _rgb(0.05)},
             "light": {"type": "sphere", "center": [2, 4, 2], "radius": 0.15, "emitter": _emitter(400.0)}}
    for i, (alpha, material) in enumerate([(0.02, "Au"), (0.08, "Cu"), (0.2, "Al"), (0.5, "Cr")]):
        scene[f"ball{i}"] = {"type": "sphere", "center": [-1.8 + 1.2 * i, 0.5, 0], "radius": 0.5,
                             "bsdf": {"type": "roughconductor", "material": material, "alpha": alpha,
                                      "distribution": "ggx"}}
    return scene


def lights_on_black(mi: Any) -> dict[str, Any]:
    """A square light about 25 pixels wide and a sphere light about 8 pixels in radius, radiance 100, on black."""
    return {"type": "scene", "integrator": {"type": "path", "max_depth": 2},
            "sensor": _camera(mi, [0, 0, 5], [0, 0, 0]),
            "panel": {"type": "rectangle",
                      "to_world": mi.ScalarTransform4f().translate([-0.6, 0.3, 0]).rotate([0, 0, 1], 17).scale(0.35),
                      "emitter": _emitter(100.0)},
            "disc": {"type": "sphere", "center": [0.8, -0.5, 0], "radius": 0.22, "emitter": _emitter(100.0, 50.0, 25.0)}}


def bright_lights(mi: Any) -> dict[str, Any]:
    """A diffuse corner with a panel light and a bulb in view, radiance about 1e4."""
    scale = 1e4 / 50
    return {"type": "scene", "integrator": {"type": "path", "max_depth": 5},
            "sensor": _camera(mi, [0, 1.0, 4.5], [0, 1.0, 0], fov=45),
            "floor": _floor(mi, 5, 0.6),
            "back": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 1.5, -2]).scale(3),
                     "bsdf": {"type": "diffuse", "reflectance": _rgb(0.4, 0.3, 0.3)}},
            "panel": {"type": "rectangle",
                      "to_world": mi.ScalarTransform4f().translate([-0.8, 1.4, -1.9]).scale([0.5, 0.3, 1]),
                      "emitter": _emitter(50 * scale)},
            "bulb": {"type": "sphere", "center": [0.9, 1.2, 0.0], "radius": 0.12,
                     "emitter": _emitter(80 * scale, 60 * scale, 30 * scale)},
            "ball": {"type": "sphere", "center": [0.0, 0.4, 0.3], "radius": 0.4,
                     "bsdf": {"type": "diffuse", "reflectance": _rgb(0.7)}}}


def glyphs(mi: Any) -> dict[str, Any]:
    """Strokes of 1-2 pixels (a bitmap of random glyphs, nearest filtered) on a plane under a small light."""
    rng = np.random.default_rng(3)
    texels = np.full((512, 512), 0.85, np.float32)
    for row in range(8, 512, 12):
        column = 4
        while column < 500:
            width = int(rng.integers(3, 7))
            texels[row:row + 6, column:column + width][rng.random((6, width)) < 0.45] = 0.03
            column += width + 2
    bitmap = mi.Bitmap(np.repeat(texels[:, :, None], 3, axis=2))
    light = mi.ScalarTransform4f().look_at(origin=[1.5, 1.5, 4], target=[0, 0, 0], up=[0, 1, 0]).scale(0.3)
    return {"type": "scene", "integrator": {"type": "path", "max_depth": 4},
            "sensor": _camera(mi, [0, 0, 5], [0, 0, 0]),
            "plane": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(2.2),
                      "bsdf": {"type": "diffuse", "reflectance": {"type": "bitmap", "bitmap": bitmap,
                                                                  "filter_type": "nearest"}}},
            "light": {"type": "rectangle", "to_world": light, "emitter": _emitter(20.0)},
            "fill": {"type": "constant", "radiance": _rgb(0.05)}}


SCENES: dict[str, tuple[Callable[[Any], dict[str, Any]], int, tuple[int, ...]]] = {
    "stars": (stars, 4096, SPPS),
    "caustic": (caustic, 16384, SPPS),
    "glints": (glints, 4096, SPPS),
    "lights on black": (lights_on_black, 32768, (8, 32, 128)),
    "bright lights": (bright_lights, 4096, (4, 8, 32)),
    "glyphs": (glyphs, 4096, (32, 128)),
}
"""name: (scene, reference spp, spps measured)."""


def reference(renderer: Any, name: str, spp: int, cache: Path) -> np.ndarray:
    """The scene's reference, rendered in passes of :data:`PASS_SPP` (cached in ``cache``)."""
    path = cache / f"{name.replace(' ', '_')}_{SHAPE[0]}x{SHAPE[1]}_{spp}.npy"
    cached = load_arrays(path, lambda a: None if a.shape == (*SHAPE, 3) and np.isfinite(a).all()
                         else f"shape {a.shape} or values not finite, not a {SHAPE[0]}x{SHAPE[1]} reference")
    if cached is not None:
        return cached
    total = np.zeros(SHAPE + (3,))
    for k in range(spp // PASS_SPP):
        renderer.seed = REFERENCE_SEED + k
        total += renderer(SampleRequest.uniform(SHAPE, PASS_SPP)).mean
    image = total / (spp // PASS_SPP)
    save_arrays(path, image)
    return image


def run(names: list[str], seeds: int, cache: Path) -> list[dict[str, Any]]:
    from awr_denoise.adapters._mitsuba_runtime import import_mitsuba
    from awr_denoise.adapters.mitsuba import create_renderer

    mi, _ = import_mitsuba()
    rows = []
    for name in names:
        make, reference_spp, spps = SCENES[name]
        renderer = create_renderer(make(mi), shape=SHAPE, seed=0)
        ref = reference(renderer, name, reference_spp, cache)
        for spp in spps:
            for seed in range(1, seeds + 1):
                renderer.seed = seed
                buffer = renderer(SampleRequest.uniform(SHAPE, spp))
                plain, image = buffer.mean, reconstruct(buffer)
                rows.append({"scene": name, "spp": spp, "seed": seed,
                             "relmse": relmse(image, ref), "plain_relmse": relmse(plain, ref),
                             "mse": mse(image, ref), "plain_mse": mse(plain, ref),
                             "shift": float((image.mean() - plain.mean()) / ref.mean())})
        print(f"{name}: done", flush=True)
    return rows


def table(rows: list[dict[str, Any]]) -> None:
    print("\n| scene | spp | renders | relMSE / plain (renders losing) | MSE / plain (renders losing) "
          "| image-mean shift: mean (largest) |")
    print("|---|---|---|---|---|---|")
    for scene, spp in dict.fromkeys((r["scene"], r["spp"]) for r in rows):
        same = [r for r in rows if r["scene"] == scene and r["spp"] == spp]
        cells = []
        for key in ("relmse", "mse"):
            ratio = sum(r[key] for r in same) / sum(r[f"plain_{key}"] for r in same)
            losing = sum(r[key] > r[f"plain_{key}"] for r in same)
            cells.append(f"{ratio:.3g} ({losing})")
        shifts = [r["shift"] for r in same]
        largest = max(shifts, key=abs)
        print(f"| {scene} | {spp} | {len(same)} | {cells[0]} | {cells[1]} "
              f"| {100 * np.mean(shifts):+.2f}% ({100 * largest:+.1f}%) |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", choices=list(SCENES), default=list(SCENES))
    parser.add_argument("--seeds", type=int, default=4, help="renders per scene and spp (renderer seeds 1 to N)")
    parser.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "awr-denoise" / "limits-mitsuba",
                        help="where the references are kept")
    parser.add_argument("--output", type=results_file, default=RESULTS)
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error("--seeds: at least 1")
    rows = run(args.scenes, args.seeds, args.cache)
    update_section(args.output, "limits_mitsuba", rows, recorded_command("bench_limits_mitsuba.py", argv, args))
    table(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
