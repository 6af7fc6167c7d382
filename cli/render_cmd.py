"""``awr render``: render a bundled scene with the built-in path tracer, uniformly or adaptively."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from awr_denoise.sampling import DEFAULT_ROUND_GROWTH

from .common import EXIT_OK, RuntimeFailure, UsageError, status
from .denoise_cmd import add_reconstruction_options, reconstruction_kwargs

__all__ = ["register", "run", "tracer_module", "default_scene", "render_buffer", "derived_path"]


def tracer_module() -> Any:
    """The bundled tracer, or a clear runtime failure when it (or embreex) is missing."""
    try:
        from awr_denoise import tracer
    except ImportError as exc:
        raise RuntimeFailure(f"the bundled tracer is not available: {exc} "
                             "(pip install 'awr-denoise[tracer]')") from None
    missing = [n for n in ("list_scenes", "load_scene", "PathTracer") if not hasattr(tracer, n)]
    if missing:
        raise RuntimeFailure(f"the bundled tracer is not available (missing {', '.join(missing)})")
    return tracer


def default_scene(tracer: Any) -> str:
    """The tracer's default scene name."""
    name = getattr(tracer, "DEFAULT_SCENE", None)
    if name:
        return str(name)
    scenes = list(tracer.list_scenes())
    if not scenes:
        raise RuntimeFailure("the bundled tracer has no scenes")
    for preferred in ("default", "cornell_box"):
        if preferred in scenes:
            return preferred
    return str(scenes[0])


def derived_path(path: str | Path, suffix: str) -> Path:
    """``out/x.exr`` with ``.denoised.png`` is ``out/x.denoised.png``."""
    p = Path(path)
    stem = p.name[: -len(p.suffix)] if p.suffix else p.name
    return p.with_name(stem + suffix)


def render_buffer(tracer: Any, scene: Any, *, spp: float, adaptive: bool, seed: int, sampler: str,
                  initial_spp: int, quiet: bool, renderer: Any = None,
                  round_growth: float = DEFAULT_ROUND_GROWTH) -> tuple[Any, Any, int]:
    """(buffer, issued, next round) of a uniform or adaptive render at ``spp`` on average.

    ``renderer`` replaces the in-process tracer (a tiled renderer over workers, say);
    ``round_growth`` is the adaptive sampler's.
    """
    from awr_denoise import AdaptiveSampler, SampleRequest

    # A uniform render is one request: the tracer's own bar shows it. Adaptive rounds get
    # the sampler's bar instead of one tracer bar per round.
    if renderer is None:
        renderer = tracer.PathTracer(scene, seed=seed, sampler=sampler, progress=not quiet and not adaptive)
    try:
        probe = getattr(renderer, "shape", None) or getattr(scene, "shape", None)
        if probe is None:
            raise RuntimeFailure("the tracer does not report the image size")
        shape = (int(probe[0]), int(probe[1]))
        if not adaptive:
            if spp != int(spp):
                raise UsageError(f"--spp: a uniform render needs whole samples per pixel, got {spp}")
            request = SampleRequest.uniform(shape, int(spp))
            buffer = renderer(request)
            return buffer, request.first_index + request.counts, 1
        awr = AdaptiveSampler(shape, initial_spp=min(initial_spp, max(1, int(spp))), seed=seed,
                              round_growth=round_growth)
        buffer = awr.run(renderer, total_spp=spp, progress=not quiet)
        return buffer, awr.issued, awr.round
    finally:
        close = getattr(renderer, "close", None)
        if callable(close):
            close()


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``render`` sub-parser to ``sub``."""
    p = sub.add_parser("render", help="render a bundled scene (uniform or adaptive) and denoise it",
                       description="Render a bundled scene with the built-in path tracer; write the sample dump, "
                                   "the denoised image and a PNG preview.")
    p.add_argument("--scene", help="bundled scene name (default: the tracer's default scene)")
    p.add_argument("--list-scenes", action="store_true", help="print the bundled scenes and exit")
    p.add_argument("--width", type=int, help="image width (default: the scene's)")
    p.add_argument("--height", type=int, help="image height (default: the scene's)")
    p.add_argument("--spp", type=float, default=16, help="average samples per pixel (default 16)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--adaptive", dest="adaptive", action="store_true", default=True,
                      help="adaptive wavelet sampling (default)")
    mode.add_argument("--uniform", dest="adaptive", action="store_false", help="the same count at every pixel")
    p.add_argument("--initial-spp", type=int, default=4, help="samples per pixel of the first adaptive round")
    p.add_argument("--round-growth", type=float, metavar="G", default=DEFAULT_ROUND_GROWTH,
                   help="adaptive rounds ask for this share of the samples taken so far (default %(default)s; "
                        "larger: fewer, cheaper rounds, see docs/sampling.md)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sampler", choices=("independent", "sobol"), default="independent",
                   help="the tracer's sample sequence")
    p.add_argument("-o", "--output", metavar="DUMP.exr", help="sample dump to write (required unless --list-scenes)")
    p.add_argument("--image", metavar="OUT.exr", help="denoised image (default DUMP.denoised.exr)")
    p.add_argument("--preview", metavar="OUT.png", help="PNG preview (default DUMP.denoised.png)")
    p.add_argument("--exposure", type=float, default=0.0, help="preview exposure in stops")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    add_reconstruction_options(p)
    from awr_denoise.parallel import add_executor_arguments

    add_executor_arguments(p, tile_option=True)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run ``awr render``; returns the exit status (errors are raised and reported by ``main``)."""
    from awr_denoise import __version__, reconstruct
    from awr_denoise.io import write_image, write_preview, write_sample_buffer
    from awr_denoise.io.atomic import check_writable

    tracer = tracer_module()
    if args.list_scenes:
        for name in tracer.list_scenes():
            print(name)
        return EXIT_OK
    if not args.output:
        raise UsageError("render: -o/--output DUMP.exr is required")
    if not args.spp > 0:
        raise UsageError(f"--spp: must be > 0, got {args.spp}")
    image_path = Path(args.image) if args.image else derived_path(args.output, ".denoised.exr")
    preview_path = Path(args.preview) if args.preview else derived_path(args.output, ".denoised.png")
    outputs = [Path(args.output), image_path, preview_path]
    if len({o.resolve() for o in outputs}) != 3:
        raise UsageError(f"{args.output}: the dump, image and preview need three different names")
    for o in outputs:  # refuse before spending time rendering
        check_writable(o, overwrite=args.overwrite)
    name = args.scene or default_scene(tracer)
    if name not in tracer.list_scenes():
        raise UsageError(f"--scene: {name!r} is not one of {', '.join(sorted(tracer.list_scenes()))}")
    scene = tracer.load_scene(name, width=args.width, height=args.height)
    start = time.perf_counter()
    from awr_denoise.parallel import RendererSpec, TiledRenderer, executor_from_args, executor_requested

    options = dict(spp=args.spp, adaptive=args.adaptive, seed=args.seed, sampler=args.sampler,
                   initial_spp=args.initial_spp, quiet=args.quiet, round_growth=args.round_growth)
    if executor_requested(args):
        # Each worker builds its own tracer from a picklable spec; tiles of every round are
        # rendered there and merged exactly (addressable random numbers make it match serial).
        spec = RendererSpec.tracer(name, width=args.width, height=args.height, seed=args.seed,
                                   sampler=args.sampler, threads=1)
        with executor_from_args(args) as executor:
            tiled = TiledRenderer(spec, tile=args.tile, executor=executor)
            buffer, issued, next_round = render_buffer(tracer, scene, renderer=tiled, **options)
    else:
        buffer, issued, next_round = render_buffer(tracer, scene, **options)
    seconds = time.perf_counter() - start
    strategy = "awr" if args.adaptive else "uniform"
    header = {"awr:scene": name, "awr:seed": args.seed, "awr:sampler": args.sampler, "awr:strategy": strategy,
              "awr:round": next_round, "awr:render_seconds": float(seconds)}
    write_sample_buffer(args.output, buffer, header=header, issued=issued, overwrite=args.overwrite)
    image = reconstruct(buffer, **reconstruction_kwargs(args))
    provenance = {"awr:version": __version__, "awr:c_s": float(args.c_s), "awr:wavelet": args.wavelet,
                  "awr:levels": -1 if args.levels is None else args.levels, "awr:domain": args.domain,
                  "awr:mode": args.mode, "awr:input": Path(args.output).name, "awr:scene": name}
    write_image(image_path, image, channels=buffer.channels, header=provenance, overwrite=args.overwrite)
    write_preview(preview_path, image, exposure=args.exposure, overwrite=args.overwrite)
    h, w = buffer.shape
    status(f"{args.output}: {name} {w}x{h}, {buffer.total_samples / (h * w):.3g} spp ({strategy}) in {seconds:.1f} s; "
           f"denoised {image_path}, preview {preview_path}", quiet=args.quiet)
    return EXIT_OK
