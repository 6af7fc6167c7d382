"""``awr render``: render a scene, uniformly or adaptively, and denoise it.

The renderer comes from the registry (:mod:`awr_denoise.renderers`): the bundled path tracer by
default (``--renderer tracer``, bundled scenes by name), or any registered renderer such as the
Mitsuba 3 adapter (``--renderer mitsuba SCENE.xml``).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Executor
from pathlib import Path
from types import ModuleType
from typing import Any

from awr_denoise import AdaptiveSampler, SampleRequest, reconstruct_detailed
from awr_denoise.buffers import SampleBuffer
from awr_denoise.io import image_provenance, provenance, write_image, write_preview, write_sample_buffer
from awr_denoise.io.atomic import OutputSet
from awr_denoise.noise_gain import DEFAULT_NOISE_MODEL
from awr_denoise.parallel import RendererSpec, TiledRenderer
from awr_denoise.rare_paths import DEFAULT_RARE_PATHS, RARE_PATHS
from awr_denoise._progress import bars_shown
from awr_denoise.renderers import (
    create_renderer,
    renderer_features,
    renderer_names,
    renderer_scene_files,
    renderer_scenes,
)
from awr_denoise.requests import Renderer, SampleTracer
from awr_denoise.rounds import MAX_SECONDS, reconstruction_seconds
from awr_denoise.sampling import DEFAULT_AWR_INITIAL_SPP, DEFAULT_ROUND_GROWTH, NOISE_MODELS

from .common import EXIT_OK, RENDER_BYTES_PER_PIXEL, RuntimeFailure, UsageError, check_memory, status
from .denoise_cmd import (add_reconstruction_options, check_reconstruction_options, reconstruction_kwargs,
                          unused_features)
from .parallel_options import (DEFAULT_TILE, add_executor_arguments, add_threads_argument, executor_from_args,
                               executor_requested, library_threads, threads_from_args)
from .paths import PathPlan, check_file_name
from .sampler_settings import sampler_settings
from .values import (MAX_EXPOSURE, MAX_ROUND_GROWTH, MAX_SEED, MAX_SIDE, MAX_SPP, check_pixels, feature_list, nonempty,
                     real, whole)

__all__ = ["register", "run", "tracer_module", "default_scene", "render_buffer", "derived_path"]

TRACER = "tracer"
"""Name of the bundled path tracer in the renderer registry (the default renderer)."""
DEFAULT_RENDER_SPP = 16.0
"""``awr render``'s samples per pixel when given neither ``--spp`` nor ``--seconds``."""
WRITE_SHARE = 0.3
"""Under ``--seconds``, writing the dump, the image and the preview as a share of the denoising's time: 0.13-0.23
at 1920x1080 and 3840x2160, up to 0.38 at 256x256 and 512x512, where the estimate's own margin covers the rest
(medians; docs/sampling.md, "A time budget": ``benchmarks/bench_budget.py --trial``)."""


def tracer_module() -> ModuleType:
    """The bundled tracer, or a clear runtime failure when it (or embreex) is missing."""
    try:
        # The optional ``tracer`` extra (embreex): imported only by the commands that render.
        from awr_denoise import tracer
    except ImportError as exc:  # the package's own message names the extra already: said once
        hint = "" if "awr-denoise[tracer]" in str(exc) else " (pip install 'awr-denoise[tracer]')"
        raise RuntimeFailure(f"the bundled tracer is not available: {exc}{hint}") from None
    return tracer


def default_scene(tracer: ModuleType) -> str:
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


def first_round_spp(initial_spp: int, spp: float | None) -> int:
    """The first adaptive round's samples per pixel: ``initial_spp``, at most the render's own (if any), at least 1."""
    return initial_spp if spp is None else min(initial_spp, max(1, int(spp)))


def render_buffer(renderer: Renderer, shape: tuple[int, int], *, spp: float | None, adaptive: bool, seed: int,
                  quiet: bool, initial_spp: int = DEFAULT_AWR_INITIAL_SPP, round_growth: float = DEFAULT_ROUND_GROWTH,
                  noise_model: str = DEFAULT_NOISE_MODEL, gain_refresh: float | None = None,
                  seconds: float | None = None, reserve: Callable[[SampleBuffer], float] | None = None,
                  rare_paths: str = DEFAULT_RARE_PATHS, executor: Executor | None = None
                  ) -> tuple[SampleBuffer, Any, int, dict[str, int | str]]:
    """(buffer, issued, next round, the sampler's settings) of a uniform or adaptive render at ``spp`` on average,
    or adaptive rounds for ``seconds`` (``spp`` then a cap, ``None`` for none) of which ``reserve`` keeps the
    denoising's time (:meth:`~awr_denoise.Sampler.run`). The settings are the header attributes ``awr plan``
    continues the run with (:func:`.sampler_settings.sampler_settings`; none for a uniform render). ``executor``: a
    thread pool the sampler ranks the pixels on between rounds, while the renderer waits (``--threads``).

    The renderer is closed afterwards when it is a :class:`~awr_denoise.requests.SampleTracer`.
    """
    try:
        if not adaptive:
            assert spp is not None and seconds is None, "a uniform render is one request of a given spp"
            if spp != int(spp):
                raise UsageError(f"--spp: a uniform render needs whole samples per pixel, got {spp}")
            request = SampleRequest.uniform(shape, int(spp))
            buffer = renderer(request)
            return buffer, request.first_index + request.counts, 1, {}
        awr = AdaptiveSampler(shape, initial_spp=first_round_spp(initial_spp, spp), seed=seed,
                              round_growth=round_growth, noise_model=noise_model, gain_refresh=gain_refresh,
                              rare_paths=rare_paths, executor=executor)
        buffer = awr.run(renderer, total_spp=spp, seconds=seconds, reserve=reserve, progress=bars_shown(quiet))
        return buffer, awr.issued, awr.round, sampler_settings(awr)
    finally:
        if isinstance(renderer, SampleTracer):
            renderer.close()


def _reserve(args: argparse.Namespace, start: float, executor: Executor | None
             ) -> Callable[[SampleBuffer], float] | None:
    """Under ``--seconds``: the seconds of the budget not for rounds, asked after round 0: the time since ``start``
    before the rounds (the renderer's setup), the denoising's, timed on round 0's samples with the command's
    settings and threads (:func:`~awr_denoise.rounds.reconstruction_seconds`), and the files' (:data:`WRITE_SHARE` of
    it)."""
    if args.seconds is None:
        return None
    denoise = functools.partial(reconstruct_detailed, variance_probes=0, executor=executor,
                                **reconstruction_kwargs(args))
    ready = time.perf_counter()  # the renderer is set up: the rounds begin
    return lambda buffer: (ready - start) + (1 + WRITE_SHARE) * reconstruction_seconds(buffer, denoise)


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``render`` sub-parser to ``sub``."""
    p = sub.add_parser("render", help="render a scene (uniform or adaptive) and denoise it",
                       description="Render a scene with a registered renderer (the built-in path tracer by "
                                   "default); write the sample dump, the denoised image and a PNG preview.")
    p.add_argument("scene_file", nargs="?", metavar="SCENE",
                   help="scene to render: a bundled scene name or a scene file the renderer reads")
    p.add_argument("--scene", help="bundled scene name (default: the tracer's default scene)")
    p.add_argument("--renderer", default=TRACER, metavar="NAME",
                   help=f"registered renderer (default %(default)s; known: {', '.join(renderer_names())})")
    p.add_argument("--list-scenes", action="store_true", help="print the bundled scenes and exit")
    p.add_argument("--width", type=whole(minimum=1, maximum=MAX_SIDE), help="image width (default: the scene's)")
    p.add_argument("--height", type=whole(minimum=1, maximum=MAX_SIDE), help="image height (default: the scene's)")
    p.add_argument("--spp", type=real(above=0, maximum=MAX_SPP), default=None,
                   help=f"average samples per pixel (default {DEFAULT_RENDER_SPP:g}; with --seconds a cap, "
                        "by default none)")
    p.add_argument("--seconds", type=real(above=0, maximum=MAX_SECONDS), metavar="S",
                   help="adaptive rounds, the denoising and the files in about S seconds: the rounds leave the "
                        "denoising the time a trial on the first round's samples predicts; the first round is "
                        "always rendered")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--adaptive", dest="adaptive", action="store_true", default=True,
                      help="adaptive wavelet sampling (default)")
    mode.add_argument("--uniform", dest="adaptive", action="store_false", help="the same count at every pixel")
    p.add_argument("--initial-spp", type=whole(minimum=1, maximum=MAX_SPP),
                   help=f"samples per pixel of the first adaptive round (default {DEFAULT_AWR_INITIAL_SPP})")
    p.add_argument("--round-growth", type=real(above=0, maximum=MAX_ROUND_GROWTH), metavar="G",
                   help="adaptive rounds ask for this share of the samples taken so far "
                        f"(default {DEFAULT_ROUND_GROWTH}; larger: fewer, cheaper rounds, see docs/sampling.md)")
    p.add_argument("--noise-model", choices=NOISE_MODELS,
                   help="adaptive rounds model what reconstruction leaves of a pixel's noise: by a wavelet "
                        "shrinkage's exact gain (shrinkage, the default), by the paper's levels, or by the default "
                        "reconstruction's measured gain, reconstructing every round (ten times the sampler's time; "
                        "docs/sampling.md)")
    p.add_argument("--gain-refresh", type=real(minimum=1, maximum=1e6), metavar="F",
                   help="with --noise-model reconstruction: measure the gain again only once the samples grew by "
                        "this factor (default 1: every round; 1.5: every other round, half the sampler's time; "
                        "docs/sampling.md)")
    p.add_argument("--rare-paths", choices=RARE_PATHS,
                   help="adaptive rounds spread the samples of regions lit through rare paths (most samples 0: "
                        "indirect light, fog; or fireflies on a lit base: caustics) evenly, which keeps their image "
                        "mean (even, the default), only those whose samples are mostly 0 (zeros), or rank their "
                        "pixels like the rest (ranked: lower error there, the image several percent dark; "
                        "docs/sampling.md, 'Rare paths')")
    p.add_argument("--seed", type=whole(minimum=0, maximum=MAX_SEED), default=0)
    p.add_argument("--sampler", default="independent",
                   help="the bundled tracer's sample sequence: independent (default) or sobol")
    p.add_argument("--features", type=feature_list, metavar="NAMES",
                   help="also render albedo, normal, depth (comma separated, or 'all') into the dump (tracer and "
                        "mitsuba render them); --guide features or --guide oidn uses them")
    p.add_argument("-o", "--output", type=nonempty, metavar="DUMP.exr",
                   help="sample dump to write (required unless --list-scenes)")
    p.add_argument("--image", type=nonempty, metavar="OUT.exr", help="denoised image (default DUMP.denoised.exr)")
    p.add_argument("--preview", type=nonempty, metavar="OUT.png", help="PNG preview (default DUMP.denoised.png)")
    p.add_argument("--exposure", type=real(minimum=-MAX_EXPOSURE, maximum=MAX_EXPOSURE), default=0.0,
                   help="preview exposure in stops")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    add_reconstruction_options(p)
    add_executor_arguments(p, tile_option=True)
    add_threads_argument(p, "the adaptive rounds' ranking, between the renderer's rounds, and the reconstruction")
    p.set_defaults(run=run)
    defaults: dict[str, tuple[Any, str]] = {}
    for action in p._actions:
        if action.dest not in ("help", "list_scenes", "renderer"):
            name = (action.option_strings or [action.metavar or action.dest])[-1]
            known = defaults.get(action.dest)  # --adaptive and --uniform share theirs: both named
            defaults[action.dest] = (action.default, name if known is None else f"{known[1]}/{name}")
    _DEFAULTS.clear()  # a parser built again (each call of main) makes them anew
    _DEFAULTS.update(defaults)


_DEFAULTS: dict[str, tuple[Any, str]] = {}
"""Every ``render`` option's default and longest name but ``--list-scenes`` and ``--renderer``: set by :func:`register`,
read by :func:`run`, which refuses other options beside ``--list-scenes``."""


def _scene(args: argparse.Namespace) -> tuple[str, Any, str, tuple[int, int] | None, dict[str, Any]]:
    """(scene as given, scene to build the renderer on, name for headers, shape, renderer options)."""
    if args.scene_file is not None and args.scene is not None:
        raise UsageError("give the scene either as SCENE or with --scene, not both")
    given = args.scene_file if args.scene_file is not None else args.scene
    shape = None if args.width is None and args.height is None else (args.height or 0, args.width or 0)
    if given is not None and not given.strip():  # refused by its option, never taken as the option not given
        raise UsageError(f"{'SCENE' if args.scene_file is not None else '--scene'}: an empty name"
                         + ("" if args.renderer != TRACER else
                            f"; leave it out for the default scene ({default_scene(tracer_module())})"))
    if args.renderer != TRACER:
        if not given:
            raise UsageError(f"--renderer {args.renderer}: give the SCENE to render")
        if args.sampler != "independent":  # the header would record a sequence this renderer never used
            raise UsageError(f"--sampler {args.sampler}: the bundled tracer's sequence; --renderer {args.renderer} "
                             "draws independent samples")
        if (args.width is None) != (args.height is None):  # no scene file here to keep the other side from
            missing = "--height" if args.height is None else "--width"
            raise UsageError(f"{missing}: --renderer {args.renderer} needs both --width and --height to resize")
        if args.features:
            offered = _registry(renderer_features, args.renderer)
            missing = [name for name in args.features if name not in offered]
            if missing:
                raise UsageError(f"--features: --renderer {args.renderer} does not render {', '.join(missing)} "
                                 f"(it renders: {', '.join(offered) or 'no features'})")
        return given, given, Path(given).name, shape, {"features": args.features} if args.features else {}
    tracer = tracer_module()
    name = given or default_scene(tracer)
    if name not in tracer.list_scenes() and Path(name).suffix != ".json":
        raise UsageError(f"--scene: {name!r} is not one of {', '.join(sorted(tracer.list_scenes()))}")
    # The tracer's scene is loaded here, at its final size, so the renderer needs no shape.
    names = tracer.SAMPLER_NAMES
    if args.sampler not in names:  # the tracer's own refusal named its parameter, sampler (an attack pass)
        raise UsageError(f"--sampler: {args.sampler!r} is not one of {', '.join(names)}")
    options: dict[str, Any] = {"sampler": args.sampler}
    if args.features:
        options["features"] = args.features
    return name, tracer.load_scene(name, width=args.width, height=args.height), Path(name).stem, None, options


@contextlib.contextmanager
def _as_options(renderer: str) -> Iterator[None]:
    """A renderer's refusal of its ``shape`` (a synthetic scene has no size of its own) or of its scene's ``name``
    as the options that give them."""
    try:
        yield
    except ValueError as error:
        text = str(error)
        for parameter, options in (("shape: ", "--width/--height"), ("name: ", "SCENE/--scene"),
                                   ("scene: ", "SCENE/--scene")):
            if text.startswith(parameter):
                raise UsageError(f"{options}: --renderer {renderer}: {text[len(parameter):]}") from None
        raise


def _scene_files(renderer: str, scene: str) -> list[tuple[str, Path]]:
    """The files ``scene`` makes ``renderer`` read (the registry's), a missing extra as a :class:`RuntimeFailure`."""
    try:
        return renderer_scene_files(renderer, scene)
    except ImportError as exc:
        raise RuntimeFailure(f"--renderer {renderer}: {exc}") from None


def _registry(lookup: Callable[[str], list[str]], renderer: str) -> list[str]:
    """``lookup(renderer)`` (the registry's scenes or features), a missing extra as a :class:`RuntimeFailure`."""
    try:
        return lookup(renderer)
    except ImportError as exc:
        raise RuntimeFailure(f"--renderer {renderer}: {exc}") from None


def run(args: argparse.Namespace) -> int:
    """Run ``awr render``; returns the exit status (errors are raised and reported by ``main``)."""
    if args.renderer not in renderer_names():
        raise UsageError(f"--renderer: {args.renderer!r} is not one of {', '.join(renderer_names())}")
    if args.list_scenes:
        # The other options were ignored without a word (`--list-scenes -o x.exr` wrote nothing, exit 0: a
        # red-team pass): they would do nothing, as a uniform render's adaptive settings, which are refused.
        given = getattr(args, "options_given", frozenset())
        others = [name for dest, (default, name) in _DEFAULTS.items()
                  if dest in given or getattr(args, dest, default) != default]
        if others:
            raise UsageError(f"--list-scenes: prints the scenes and exits; not with {', '.join(others)}")
        for name in _registry(renderer_scenes, args.renderer):
            print(name)
        return EXIT_OK
    if args.output is None:
        raise UsageError("render: -o/--output DUMP.exr is required")
    for option, value in (("--initial-spp", args.initial_spp), ("--round-growth", args.round_growth),
                          ("--noise-model", args.noise_model), ("--seconds", args.seconds),
                          ("--rare-paths", args.rare_paths)):
        if value is not None and not args.adaptive:  # a setting that would do nothing is refused
            raise UsageError(f"{option}: a uniform render has no adaptive rounds")
    spp = args.spp if args.spp is not None or args.seconds is not None else DEFAULT_RENDER_SPP
    if args.initial_spp is not None and spp is not None and args.initial_spp > spp:  # else cut to it, unsaid
        raise UsageError(f"--initial-spp: {args.initial_spp} exceeds --spp {spp:g}, the whole render's samples "
                         "per pixel")
    if args.tile is not None and not executor_requested(args):  # the tiles are the workers' tasks
        raise UsageError("--tile: tiles split the work over workers; give --workers N (or --executor, --scheduler)")
    if args.gain_refresh is not None and args.noise_model != "reconstruction":
        raise UsageError("--gain-refresh: only --noise-model reconstruction measures a gain")
    auxiliary = args.guide_auxiliary
    if args.guide == "oidn" and auxiliary not in (None, "none") and "albedo" not in (args.features or ()):
        raise UsageError(f"--guide-auxiliary {auxiliary}: OIDN takes the colour alone without an albedo; render "
                         "the features (--features albedo,normal), or leave the option out")
    if args.guide == "oidn" and auxiliary == "clean" and "normal" not in (args.features or ()):
        raise UsageError("--guide-auxiliary clean: OIDN takes the features as clean only as a pair; render the normal "
                         "too (--features albedo,normal), or choose noisy or prefilter")
    if args.guide == "oidn" and auxiliary != "none" and "normal" in (args.features or ()) \
            and "albedo" not in args.features:
        raise UsageError("--features: --guide oidn uses a normal only beside an albedo; render it too "
                         "(--features albedo,normal)")
    if args.guide == "features" and not args.features:
        raise UsageError("--guide features: nothing to guide with; render the features too (--features all)")
    # The image's and preview's names derive from the dump's: -o . named no option ("PosixPath('.') has an empty
    # name", an attack pass).
    check_file_name(args.output, "-o/--output")
    image_path = Path(args.image) if args.image else derived_path(args.output, ".denoised.exr")
    preview_path = Path(args.preview) if args.preview else derived_path(args.output, ".denoised.png")
    plan = PathPlan(overwrite=args.overwrite)
    given = args.scene_file or args.scene
    # A scene file (a bundled scene is a bare name): a JSON scene of the tracer, or any path another
    # renderer is given that names something or has a suffix (Mitsuba loads "scene.txt" as XML too).
    if given and (Path(given).suffix == ".json" if args.renderer == TRACER
                  else bool(Path(given).suffix) or os.path.lexists(given)):
        plan.read(given, "SCENE")
        plan.check()  # the scene file first: it is read for the files it names, checked with the rest
        for field, path in _scene_files(args.renderer, given):
            plan.read(path, f"SCENE's {field}")
    plan.write(args.output, "-o/--output")
    plan.write(image_path, "--image" if args.image else "--image (DUMP.denoised.exr)")
    plan.write(preview_path, "--preview" if args.preview else "--preview (DUMP.denoised.png)", "png")
    plan.check()  # refuse before spending time rendering
    check_reconstruction_options(args, None, "")  # what needs no image size, before a scene file is loaded
    threads = threads_from_args(args)
    if args.width is not None and args.height is not None:
        check_pixels("--width/--height", args.height, args.width)
    given, scene, name, shape, options = _scene(args)
    frame_shape = shape or getattr(scene, "shape", None)
    if frame_shape is not None:
        # The options' size, else the scene file's own (its width and height, or the film it declares).
        given_sides = [o for o, v in (("--width", args.width), ("--height", args.height)) if v is not None]
        sized_by = ("--width/--height" if len(given_sides) == 2 else
                    f"SCENE {given}" + (f" with {given_sides[0]}" if given_sides else ""))
        check_pixels(sized_by, *frame_shape)
        # RENDER_BYTES_PER_PIXEL on one thread, 500 on a pool, whose Wiener stages filter two bands at once (1569 MB
        # and 1503 MB higher at 2048x2048 than at 1024x1024 with --threads 2, the command of its docstring); beyond
        # the memory available, the kernel's out-of-memory killer ended the render without a word (exit 137).
        per_pixel = RENDER_BYTES_PER_PIXEL if threads == 1 else 500.0
        check_memory(sized_by, per_pixel * frame_shape[0] * frame_shape[1],
                     f"a render of {frame_shape[1]}x{frame_shape[0]}" + ("" if threads == 1 else
                                                                        f" on {threads} threads"))
        check_reconstruction_options(args, tuple(frame_shape), name)
        if spp is not None and round(spp * frame_shape[0] * frame_shape[1]) < 1:  # else refused later, as "buffer"
            raise UsageError(f"--spp: {spp:g} per pixel of {frame_shape[1]}x{frame_shape[0]} is not one sample")
    # The library's own work (the rounds' ranking, the reconstruction) on --threads: the renderer waits meanwhile.
    with library_threads(threads) as pool:
        start = time.perf_counter()
        render = dict(spp=spp, adaptive=args.adaptive, seed=args.seed, quiet=args.quiet,
                      gain_refresh=args.gain_refresh, seconds=args.seconds)
        render.update({k: v for k, v in (("initial_spp", args.initial_spp), ("round_growth", args.round_growth),
                                         ("noise_model", args.noise_model), ("rare_paths", args.rare_paths))
                       if v is not None})  # else render_buffer's
        if executor_requested(args):
            # Each worker builds its own renderer from a picklable spec; tiles of every round are
            # rendered there and merged exactly (addressable random numbers make it match serial).
            if args.renderer == TRACER:
                spec = RendererSpec.tracer(given, width=args.width, height=args.height, seed=args.seed, threads=1,
                                           **options)
                frame = scene.shape
            else:
                with _as_options(args.renderer):
                    spec = RendererSpec(args.renderer, given, shape, args.seed, tuple(sorted(options.items())))
                    probe = spec()
                frame = probe.shape
                check_pixels(f"SCENE {given}: its film", *frame)
                if isinstance(probe, SampleTracer):
                    probe.close()
            with executor_from_args(args) as executor:
                tiled = TiledRenderer(spec, tile=args.tile or DEFAULT_TILE, executor=executor)
                buffer, issued, next_round, settings = render_buffer(
                    tiled, frame, reserve=_reserve(args, start, pool), executor=pool, **render)
        else:
            # A uniform render is one request: the renderer's own bar shows it. Adaptive rounds get
            # the sampler's bar instead of one renderer bar per round.
            if args.renderer == TRACER:
                options["progress"] = bars_shown(args.quiet) and not args.adaptive
            with _as_options(args.renderer):
                renderer = create_renderer(args.renderer, scene, shape=shape, seed=args.seed, **options)
            check_pixels(f"SCENE {given}: its film", *renderer.shape)  # a size the scene file declares
            buffer, issued, next_round, settings = render_buffer(
                renderer, renderer.shape, reserve=_reserve(args, start, pool), executor=pool, **render)
        seconds = time.perf_counter() - start
        strategy = "awr" if args.adaptive else "uniform"
        # A running dump (its samples every pixel's sequence from 0), and the run's strategy and first
        # round, which awr plan continues.
        first = {}
        if args.adaptive:
            first["initial_spp"] = first_round_spp(args.initial_spp or DEFAULT_AWR_INITIAL_SPP, spp)
        header = provenance(scene=name, seed=args.seed, sampler=args.sampler, strategy=strategy, round=next_round,
                            render_seconds=float(seconds), renderer=args.renderer, running=1, **first)
        header.update(settings)  # the sampler's, which awr plan continues too
        check_reconstruction_options(args, buffer.shape, name)
        result = reconstruct_detailed(buffer, variance_probes=0, executor=pool, **reconstruction_kwargs(args))
    # The dump, the image and the preview: all three or none.
    with OutputSet(overwrite=args.overwrite) as outputs:
        write_sample_buffer(outputs.add(args.output), buffer, header=header, issued=issued)
        write_image(outputs.add(image_path), result.image, channels=buffer.channels,
                    header=image_provenance(result, buffer, source=args.output, scene=name))
        write_preview(outputs.add(preview_path), result.image, exposure=args.exposure)
        outputs.commit()  # asks first for a signal whose exception was lost (interrupts.raising)
    h, w = buffer.shape
    unused = unused_features(tuple(buffer.features), args.guide, args.guide_auxiliary)
    carried = "" if not unused else f"; features {', '.join(unused)} in the dump (not used: " + (
        "see --guide)" if args.guide is None else "--guide-auxiliary none leaves them out)"
        if args.guide == "oidn" and args.guide_auxiliary == "none" else f"--guide {args.guide} does not use them)")
    if args.guide == "oidn" and args.guide_auxiliary != "none" and "albedo" not in buffer.features:
        carried += "; OIDN took the colour alone (--features albedo,normal renders what it takes beside it)"
    done = time.perf_counter() - start - seconds
    status(f"{args.output}: {name} {w}x{h}, {buffer.total_samples / (h * w):.3g} spp ({strategy}) in {seconds:.1f} s; "
           f"denoised {image_path}, preview {preview_path} in {done:.1f} s{carried}", quiet=args.quiet)
    return EXIT_OK
