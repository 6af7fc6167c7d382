"""``awr demo``: uniform vs. adaptive sampling, with and without reconstruction, at equal samples."""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from awr_denoise import reconstruct
from awr_denoise._checks import path_option
from awr_denoise.io import provenance, write_image, write_preview
from awr_denoise.metrics import mean_error, mse, relmse
from awr_denoise.reconstruct import DEFAULT_PILOT_C_S
from awr_denoise._progress import bars_shown
from awr_denoise.renderers import create_renderer

from awr_denoise.io.atomic import OutputSet, check_creatable, folders_made
from awr_denoise.io.exr import require_exr

from .errors import shown
from .common import EXIT_OK, UsageError, print_json, status
from .parallel_options import add_threads_argument, library_threads, threads_from_args
from .paths import PathPlan
from .values import MAX_EXPOSURE, MAX_SEED, MAX_SPP, real, whole
from .render_cmd import TRACER, default_scene, render_buffer, tracer_module

__all__ = ["register", "run"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``demo`` sub-parser to ``sub``."""
    p = sub.add_parser("demo", help="render the default scene, denoise, and compare with the reference",
                       description="Render a bundled scene uniformly and adaptively at the same average samples "
                                   "per pixel, reconstruct both, write EXR and PNG images under --out, and print "
                                   "the error of each against the scene's reference.")
    p.add_argument("--scene", help="bundled scene (default: the tracer's default scene)")
    p.add_argument("--spp", type=whole(minimum=1, maximum=MAX_SPP), default=8,
                   help="samples per pixel of both renders, on average for the adaptive one (default 8)")
    p.add_argument("--seed", type=whole(minimum=0, maximum=MAX_SEED - 1), default=0)
    p.add_argument("--c-s", type=real(minimum=0), default=DEFAULT_PILOT_C_S,
                   help="threshold of the reconstruction's first stage (Eq. 11; default %(default)g)")
    p.add_argument("--out", type=path_option, default="out", metavar="DIR",
                   help="output directory (default out/); the demo replaces its own files there")
    p.add_argument("--exposure", type=real(minimum=-MAX_EXPOSURE, maximum=MAX_EXPOSURE), default=0.0,
                   help="preview exposure in stops")
    add_threads_argument(p, "the adaptive render's ranking, between the renderer's rounds, and the reconstructions")
    p.add_argument("--json", action="store_true", help="machine-readable results")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run ``awr demo``; returns the exit status (errors are raised and reported by ``main``)."""
    tracer = tracer_module()
    # Its images are EXRs: without the extra, an install rendered the reference (minutes) and then failed to write
    # the first image (an attack pass).
    require_exr()
    if args.scene is not None and not args.scene.strip():  # refused by its option, never taken as not given
        raise UsageError(f"--scene: an empty name; leave it out for the default scene ({default_scene(tracer)})")
    name = args.scene or default_scene(tracer)
    if name not in tracer.list_scenes():
        raise UsageError(f"--scene: {name!r} is not one of {', '.join(sorted(tracer.list_scenes()))}")
    out = Path(args.out)
    labels = ("uniform_mean", "uniform_awr", "adaptive_awr")
    plan = PathPlan(overwrite=True)  # the demo replaces its own files
    for label in labels:
        plan.write(out / f"{name}_{label}.exr", "--out")
        plan.write(out / f"{name}_{label}.png", "--out", "png")
    plan.write(out / f"{name}_reference.png", "--out", "png")
    cached = getattr(tracer, "reference_path", None)
    if callable(cached) and Path(cached(name)).is_file():  # an input: no output may be it, by a link or a name
        plan.read(cached(name), "the cached reference")
    if os.path.lexists(out) and not out.is_dir():  # a file, a broken link or a loop of links
        raise UsageError(f"--out: {out} exists and is not a directory")
    if out.is_dir():
        plan.check()  # before two renders: an image name taken by a folder or a FIFO, say
    else:
        plan.check_names()
        try:  # created only once there is something to write: a refusal leaves no folder
            check_creatable(out, option="--out")
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    scene = tracer.load_scene(name)
    if callable(cached) and not Path(cached(name)).is_file():
        status(f"rendering the reference of {name} once (cached as {cached(name)}); this takes a while",
               quiet=args.quiet)
    reference = np.asarray(tracer.load_reference(name), dtype=np.float64)
    where = cached(name) if callable(cached) else name  # the file, which the user can remove (a stale cache)
    if reference.shape[:2] != tuple(scene.shape):  # before two renders, not after
        raise UsageError(f"{where}: the reference of {name} is {reference.shape[1]}x{reference.shape[0]}, the scene "
                         f"{scene.shape[1]}x{scene.shape[0]}; remove it to render it again")
    start = time.perf_counter()
    # The library's own work on --threads, as in awr render: the same images on any number.
    with library_threads(threads_from_args(args)) as pool:
        status(f"rendering {name} uniformly at {args.spp} spp", quiet=args.quiet)
        renderer = create_renderer(TRACER, scene, seed=args.seed, progress=bars_shown(args.quiet))
        uniform = render_buffer(renderer, scene.shape, spp=args.spp, adaptive=False, seed=args.seed,
                                quiet=args.quiet)[0]
        status(f"rendering {name} adaptively at {args.spp} spp", quiet=args.quiet)
        renderer = create_renderer(TRACER, scene, seed=args.seed + 1)
        adaptive = render_buffer(renderer, scene.shape, spp=args.spp, adaptive=True, seed=args.seed + 1,
                                 quiet=args.quiet, executor=pool)[0]
        images = dict(zip(labels, (uniform.mean, reconstruct(uniform, c_s=args.c_s, executor=pool),
                                   reconstruct(adaptive, c_s=args.c_s, executor=pool))))
    if reference.shape != uniform.mean.shape:
        raise UsageError(f"{where}: the reference of {name} is {reference.shape}, the render {uniform.mean.shape}")
    results = {}
    with folders_made(out), OutputSet(overwrite=True) as outputs:  # every image of the demo, or none (new folders too)
        for label, image in images.items():
            exr = out / f"{name}_{label}.exr"
            write_image(outputs.add(exr), image,
                        header=provenance(scene=name, spp=args.spp, c_s=args.c_s, method=label))
            write_preview(outputs.add(out / f"{name}_{label}.png"), image, exposure=args.exposure)
            results[label] = {"relmse": relmse(image, reference), "mse": mse(image, reference),
                              "mean_error": mean_error(image, reference), "file": str(exr)}
        write_preview(outputs.add(out / f"{name}_reference.png"), reference, exposure=args.exposure)
        outputs.commit()  # asks first for a signal whose exception was lost (interrupts.raising)
    seconds = time.perf_counter() - start
    if args.json:
        print_json({"scene": name, "spp": args.spp, "seconds": seconds, "results": results})
        return EXIT_OK
    h, w = uniform.shape
    print(f"{name} {w}x{h}, {args.spp} spp on average, c_s {args.c_s:g} ({seconds:.1f} s); images in {shown(out)}/")
    print(f"  {'method':<14} {'relMSE':>10} {'MSE':>12} {'mean error':>11}")
    for label, r in results.items():
        print(f"  {label:<14} {r['relmse']:>10.5f} {r['mse']:>12.6g} {100 * r['mean_error']:>10.2f}%")
    return EXIT_OK
