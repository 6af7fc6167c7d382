"""``awr denoise``: wavelet reconstruction of a sample dump into an image (Eq. 10-11)."""

from __future__ import annotations

import argparse
import contextlib
import os
import warnings
from collections.abc import Sequence
from pathlib import Path

from awr_denoise.domains import DOMAIN_NAMES
from awr_denoise.errors import InputFileError
from awr_denoise.guided import PROJECTION_SHARE
from awr_denoise.guides import AUXILIARY, GUIDES, OIDN_HINT, OIDNGuide, oidn_available, oidn_features
from awr_denoise.io import read_image, read_sample_buffer
from awr_denoise.io.atomic import OutputSet
from awr_denoise.io.exr import check_same_windows, read_windows, recorded_windows
from awr_denoise.parallel import FrameResult, FramesFailedError, denoise_frames
from awr_denoise.reconstruct import (
    DEFAULT_C_S,
    DEFAULT_DOMAIN,
    DEFAULT_MODE,
    DEFAULT_PILOT_C_S,
    DEFAULT_STAGES,
    DEFAULT_WIENER_EXPONENTS,
    MODES,
)
from awr_denoise.sure import DEFAULT_GUIDED_WINDOW, DEFAULT_WINDOW
from awr_denoise.wavelets import DEFAULT_WAVELET, max_levels

from .common import (
    EXIT_OK,
    RuntimeFailure,
    UsageError,
    add_plane_options,
    frame_jobs,
    frame_plane_kwargs,
    frame_planes,
    parse_frames,
    progress,
    status,
)
from .errors import shown
from .parallel_options import (add_executor_arguments, add_threads_argument, executor_from_args, executor_requested,
                               library_threads, threads_from_args)
from .paths import PathPlan, check_file_name, check_plane_windows, plane_options
from .values import MAX_EXPOSURE, MAX_LEVELS, nonempty, real, wavelet_name, whole

__all__ = ["register", "run", "add_reconstruction_options", "reconstruction_kwargs", "check_reconstruction_options",
           "exr_shape", "GUIDE_CHOICES"]

GUIDE_CHOICES = (*GUIDES, "features")
"""``--guide`` values: a guide of :data:`awr_denoise.guides.GUIDES`, or the feature pilot."""


def exr_shape(path: str) -> tuple[int, int]:
    """(H, W) of an EXR file from its data window (the header only is read)."""
    return _shape(read_windows(path))


def _shape(windows: dict) -> tuple[int, int]:
    (x0, y0), (x1, y1) = windows["dataWindow"]
    return y1 - y0 + 1, x1 - x0 + 1


def add_reconstruction_options(parser: argparse.ArgumentParser) -> None:
    """``--stages``, ``--c-s``, ``--wavelet``, ``--levels``, ``--domain``, ``--mode``, with the library's defaults."""
    g = parser.add_argument_group("reconstruction")
    g.add_argument("--stages", type=whole(minimum=1, maximum=1 + len(DEFAULT_WIENER_EXPONENTS)),
                   default=DEFAULT_STAGES, metavar="N",
                   help="1: the paper's thresholding alone (Eq. 10-11); N > 1: it and the last N - 1 Wiener stages "
                        "of the default, then the SURE guard, the image mean kept and no negative pixels "
                        "(default %(default)d)")
    g.add_argument("--c-s", type=real(minimum=0), default=None, metavar="C",
                   help=f"threshold in standard errors (Eq. 11) of the first stage (default {DEFAULT_PILOT_C_S:g}, "
                        f"{DEFAULT_C_S:g} with --stages 1); 0 with --stages 1 returns the plain mean")
    g.add_argument("--wavelet", type=wavelet_name, default=DEFAULT_WAVELET,
                   help="PyWavelets discrete wavelet (default %(default)s, CDF 9/7)")
    g.add_argument("--levels", type=whole(minimum=1, maximum=MAX_LEVELS), metavar="L", help="decomposition depth (default: automatic)")
    g.add_argument("--domain", default=DEFAULT_DOMAIN, choices=DOMAIN_NAMES,
                   help="domain in which coefficients are thresholded (default %(default)s)")
    g.add_argument("--mode", default=DEFAULT_MODE, choices=MODES,
                   help="threshold every channel, or decide on luminance and keep hue (default %(default)s)")
    g.add_argument("--guide", choices=GUIDE_CHOICES,
                   help="pilot of the Wiener stages, used only where the samples allow it: 'oidn', Open Image "
                        "Denoise on the means with the albedo and normal when present (extra oidn), for every "
                        "stage, and followed within three standard errors of each coefficient; 'features', an "
                        "a-trous filter guided by albedo, normal and depth, for the first "
                        "(default: neither)")
    g.add_argument("--guard-window", type=whole(minimum=1, maximum=1023), metavar="W",
                   help=f"side of the SURE guard's square window, odd (default {DEFAULT_WINDOW}, {DEFAULT_GUIDED_WINDOW} with "
                        "--guide oidn where the gate trusts it; wider is better on "
                        "most scenes and worse next to small, very bright lights: docs/reconstruction.md)")
    g.add_argument("--guard-probes", type=whole(minimum=0, maximum=100_000), metavar="N",
                   help="measure the Wiener stages' divergence for the SURE guard with N probes, each a second run "
                        "of the stages (default 0: their diagonal); 1 keeps texture at the scale of one pixel near "
                        "the plain mean's error, at some cost elsewhere: docs/reconstruction.md")
    g.add_argument("--guide-projection", type=real(minimum=0, maximum=1), metavar="S",
                   help="with --guide oidn: the share of the result taken from the means moved towards the guide "
                        f"within three standard errors; 0 makes the guide the pilot only (default {PROJECTION_SHARE:g})")
    g.add_argument("--guide-auxiliary", choices=AUXILIARY,
                   help="with --guide oidn: how OIDN takes the albedo and normal: denoised first by its own filters "
                        "(prefilter, the default), as noisy, as clean (features of a separate render of many "
                        "samples; oidnDenoise's --clean_aux), or not at all (none)")


def reconstruction_kwargs(args: argparse.Namespace) -> dict:
    """Keyword arguments of :func:`awr_denoise.reconstruct_detailed` from the options."""
    guide = getattr(args, "guide", None)
    projection = getattr(args, "guide_projection", None)
    return {"stages": args.stages, "c_s": args.c_s, "wavelet": args.wavelet, "levels": args.levels,
            "domain": args.domain, "mode": args.mode, "features": guide == "features",
            "guide": OIDNGuide(auxiliary=getattr(args, "guide_auxiliary", None) or "prefilter") if guide == "oidn"
            else GUIDES.get(guide),
            **({} if projection is None else {"guide_projection": projection}),
            **({} if getattr(args, "guard_window", None) is None else {"guard_window": args.guard_window}),
            **({} if getattr(args, "guard_probes", None) is None else {"guard_probes": args.guard_probes})}


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``denoise`` sub-parser to ``sub``."""
    p = sub.add_parser("denoise", help="reconstruct a denoised image from a sample dump",
                       description="Reconstruct a denoised image from per-pixel sample statistics "
                                   "(wavelet soft thresholding by propagated standard error). Albedo, normal "
                                   "and depth (--alb, --nrm, --depth, or found in the input) are read and "
                                   "checked; --guide oidn or --guide features uses them.")
    p.add_argument("input", nargs="?", metavar="DUMP.exr",
                   help="sample dump (any preset); may hold a #### frame placeholder")
    p.add_argument("--hdr", type=nonempty, metavar="DUMP.exr", help="same as the positional input (oidnDenoise's name)")
    p.add_argument("-o", "--output", type=nonempty, required=True, metavar="OUT.exr",
                   help="denoised image (may hold ####)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--frames", metavar="RANGE", help="frame numbers for #### patterns, e.g. 1-100 or 1-100x5")
    p.add_argument("--half", action="store_true",
                   help="write HALF channels (refused above 65504, or where a whole channel would round to 0: below 3e-8)")
    p.add_argument("--preview", type=nonempty, metavar="OUT.png", help="also write an sRGB PNG preview (may hold ####)")
    p.add_argument("--exposure", type=real(minimum=-MAX_EXPOSURE, maximum=MAX_EXPOSURE),
                   help="preview exposure in stops (default 0; with --preview)")
    p.add_argument("-r", "--ref", type=nonempty, metavar="REF.exr",
                   help="reference image to compare the result with (may hold ####: each frame's own)")
    p.add_argument("--maxerror", type=real(minimum=0), metavar="E",
                   help="with --ref: fail (exit 1) when the relative MSE exceeds E")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    add_reconstruction_options(p)
    add_plane_options(p)
    add_executor_arguments(p)
    add_threads_argument(p, "one frame's reconstruction")
    p.set_defaults(run=run)


def _library_threads(args: argparse.Namespace, frames: int) -> int:
    """The threads one frame's reconstruction runs on (``--threads``): one where the frames are the parallel work
    (several run side by side) or run in other processes (``--executor processes`` or ``dask``), where a
    ``--threads`` above 1 is refused, not ignored."""
    given = getattr(args, "threads", None)
    elsewhere = getattr(args, "executor", None) in ("processes", "dask") or getattr(args, "scheduler", None)
    if given is not None and given > 1 and (frames > 1 or elsewhere):
        why = (f"the {frames} frames run side by side instead, each on one thread (--workers sets how many)"
               if frames > 1 else "the frame is reconstructed in a worker process, not in this one")
        raise UsageError(f"--threads: {why}; leave --threads out")
    return 1 if frames > 1 or elsewhere else threads_from_args(args)


def _named_as_output(error: BaseException, final: dict[Path, str], sources: Sequence[str] = ()) -> BaseException:
    """A frame's error naming its output, not the staged file a worker wrote (the names of the
    staging folder are known to this process only: a process or Dask worker's message holds them),
    and its input as the user named it (workers are given absolute paths)."""
    text = str(error)
    for staged, output in final.items():
        for form in sorted({os.fspath(staged), os.path.abspath(staged)}, key=len, reverse=True):  # longest first
            text = text.replace(form, output)
    for source in sources:
        absolute = os.path.abspath(source)
        if absolute != source:
            text = text.replace(absolute, source)
    if text == str(error) or isinstance(error, OSError):  # an OSError's errno and paths stay its own
        return error
    try:
        return type(error)(text)
    except Exception:  # noqa: BLE001 - an exception type with other arguments: its own message, then
        return error


def unused_features(features: tuple[str, ...], guide: str | None, auxiliary: str | None = None) -> tuple[str, ...]:
    """The features a reconstruction with ``--guide guide`` does not use: all without a guide or with OIDN told to
    leave them out (``--guide-auxiliary none``); with OIDN the depth, and a normal without an albedo beside it (OIDN
    takes a normal only with an albedo)."""
    if guide is None:
        return tuple(features)
    if guide == "oidn":
        taken = oidn_features(features, auxiliary)
        return tuple(n for n in features if n not in taken)
    return ()


def _note(frame: FrameResult, output: str, nonfinite_policy: str, guide: str | None = None,
          auxiliary: str | None = None) -> str:
    """The one-line summary of a denoised frame."""
    h, w = frame.shape
    note = f"{output}: {w}x{h}, {frame.spp:.3g} spp, {100 * frame.fraction_zeroed:.1f}% coefficients zeroed"
    if frame.nonfinite:
        note += f", {frame.nonfinite} non-finite sample(s) {'dropped' if nonfinite_policy == 'drop' else 'zeroed'} " \
                "on input"
    if frame.unsampled:  # their values are estimated from the pixels around them: said, as awr info says it
        note += f", {frame.unsampled} pixel(s) without samples estimated from their surroundings"
    if frame.relmse is not None:
        note += f", relMSE {frame.relmse:.4g}"
    if unused := unused_features(frame.features, guide, auxiliary):
        note += f"; features {', '.join(unused)} read but not used " + (
            "(see --guide)" if guide is None else f"by --guide {guide}"
            + (" --guide-auxiliary none" if auxiliary == "none" else ""))
    if guide == "oidn" and auxiliary != "none" and not oidn_features(frame.features, auxiliary):
        note += "; OIDN took the colour alone (the input holds no albedo: --alb gives one)"
    return note


def check_reconstruction_options(args: argparse.Namespace, shape: tuple[int, int] | None, where: str) -> None:
    """Refuse ``--levels`` beyond what an image of ``shape`` allows (``None``: not known yet, checked later), and a
    ``--guide`` that cannot run, before any work."""
    guide = getattr(args, "guide", None)
    if guide is not None and args.stages < 2:
        raise UsageError(f"--guide {guide}: it gives the pilot of the Wiener stages; it needs --stages 2 or more")
    if guide == "oidn" and not oidn_available():
        raise RuntimeFailure(f"--guide oidn: {OIDN_HINT}")  # an extra missing: exit 1, as the tracer's or Mitsuba's
    window = getattr(args, "guard_window", None)
    if window is not None and window % 2 == 0:
        raise UsageError(f"--guard-window: must be odd, got {window}")
    if window is not None and args.stages < 2:
        raise UsageError(f"--guard-window {window}: the SURE guard follows the Wiener stages; it needs --stages 2 or more")
    probes = getattr(args, "guard_probes", None)
    if probes is not None and args.stages < 2:
        raise UsageError(f"--guard-probes {probes}: the SURE guard follows the Wiener stages; "
                         "it needs --stages 2 or more")
    if probes and guide in GUIDES:
        raise UsageError(f"--guard-probes {probes}: not with --guide {guide} (its gate and projection are not probed)")
    auxiliary = getattr(args, "guide_auxiliary", None)
    if auxiliary is not None and guide != "oidn":
        raise UsageError(f"--guide-auxiliary {auxiliary}: it says how OIDN takes the albedo and normal; it needs "
                         "--guide oidn")
    projection = getattr(args, "guide_projection", None)
    if projection is not None and guide not in GUIDES:
        raise UsageError("--guide-projection: it is the share of a guide's projection; it needs --guide oidn")
    if projection and args.mode == "luminance":  # the library's words name its parameters, not these options
        raise UsageError(f"--guide-projection {projection:g}: not with --mode luminance, where the means are not "
                         "projected (the guide is the pilot only; 0 says so)")
    if shape is not None and args.levels is not None and args.levels > max_levels(shape):
        h, w = shape
        raise UsageError(f"--levels: {args.levels} is outside 1..{max_levels(shape)} for the {w}x{h} image of {where}")


def _frame_label(option: str, jobs: list, frame: int | None) -> str:
    return option if len(jobs) == 1 or frame is None else f"{option} (frame {frame})"


def _check_references(refs: list[str], sources: list[str], windows: list[dict]) -> None:
    """Read each frame's reference once (finite, readable; one file serving every frame is read once) and match
    its size and windows to its input's ``windows``, those its other checks were made in."""
    read: dict[str, tuple] = {}  # its size and windows only: a sequence's references are not all held at once
    for ref, source, theirs in zip(refs, sources, windows):
        if ref not in read:
            with recorded_windows() as reads:  # the windows of the read that gave its pixels (not of another)
                read[ref] = (read_image(ref).shape[:2], reads[0][1])
        (ref_h, ref_w), ref_windows = read[ref]
        h, w = _shape(theirs)
        if (ref_h, ref_w) != (h, w):
            raise InputFileError(f"{ref}: size {ref_w}x{ref_h} does not match {w}x{h} of {source}")
        check_same_windows(ref, ref_windows, source, theirs)


def run(args: argparse.Namespace) -> int:
    """Run ``awr denoise``; returns the exit status (errors are raised and reported by ``main``).

    Every path and option is checked before any frame is read; the images and previews of all
    frames are written to temporaries and moved into place together once every frame
    succeeded (a failure or Ctrl-C leaves none of them).
    """
    if args.input and args.hdr:
        raise UsageError("give the input either as DUMP.exr or with --hdr, not both")
    source = args.input or args.hdr
    if not source:
        raise UsageError("no input: give DUMP.exr (or --hdr DUMP.exr)")
    if args.maxerror is not None and not args.ref:
        raise UsageError("--maxerror needs --ref REF.exr")
    if args.guide == "oidn" and args.depth:  # read and dropped: refused, not ignored
        raise UsageError("--depth: --guide oidn uses no depth (--guide features does)")
    for option, given in (("--alb", args.alb), ("--nrm", args.nrm)):
        if given and args.guide == "oidn" and args.guide_auxiliary == "none":  # read and dropped as well
            raise UsageError(f"{option}: --guide-auxiliary none leaves the albedo and normal out")
    if args.exposure is not None and not args.preview:  # it sets the preview alone: refused, not ignored
        raise UsageError("--exposure needs --preview OUT.png (it sets the preview's exposure alone)")
    check_file_name(args.output, "-o/--output")  # before the frames' placeholders are looked for in the name
    if args.preview:
        check_file_name(args.preview, "--preview")
    if args.frames is not None and "#" not in Path(source).name:  # each frame would denoise the one dump again
        raise UsageError(f"{source}: with --frames the input needs a #### placeholder in its file name")
    if args.frames is not None and args.preview and "#" not in Path(args.preview).name:
        raise UsageError(f"--preview: {args.preview}: with --frames the preview needs a #### placeholder")
    jobs = frame_jobs([source] + ([args.preview] if args.preview else []), args.output, args.frames)
    threads = _library_threads(args, len(jobs))
    numbers = parse_frames(args.frames) if args.frames is not None else [None]
    given = plane_options(args)
    planes = frame_planes(given, numbers)  # each frame's plane files (alb.####.exr)
    refs = [specs[0][0] for specs in frame_planes([(args.ref, "-r/--ref")], numbers)]  # each frame's (ref.####.exr)
    plan = PathPlan(overwrite=args.overwrite)
    for index, (ref, frame) in enumerate(zip(refs, numbers)):
        if ref != args.ref or index == 0:  # a frame's own reference, or the one for every frame, read once
            plan.read(ref, _frame_label("-r/--ref", jobs, frame) if ref != args.ref else "-r/--ref")
    for index, (specs, frame) in enumerate(zip(planes, numbers)):
        for (spec, option), (as_given, _) in zip(specs, given):
            if spec != as_given:  # the frame's own file, from a #### placeholder
                plan.read_plane(spec, option, _frame_label(option, jobs, frame))
            elif index == 0:  # one file for every frame: read once
                plan.read_plane(spec, option)
    for (inputs, output), frame in zip(jobs, numbers):
        plan.read(inputs[0], _frame_label("DUMP.exr" if args.input else "--hdr", jobs, frame))
        plan.write(output, _frame_label("-o/--output", jobs, frame))
        if len(inputs) > 1:
            plan.write(inputs[1], _frame_label("--preview", jobs, frame), "png")
    plan.check()  # and each input's version: one replaced before its last read is refused before the commit
    sources = [inputs[0] for inputs, _ in jobs]
    # Each input's windows, read once: its checks are made in them, and its frame refuses samples read
    # in others (the file replaced since).
    windows: list[dict] = []
    try:
        for src, specs in zip(sources, planes):
            windows.append(read_windows(src))
            check_reconstruction_options(args, _shape(windows[-1]), src)
            check_plane_windows(src, specs)  # every frame: each may have its own data window
        if args.ref:
            _check_references(refs, sources, windows)
        asked = args.guide_auxiliary not in (None, "none")  # a way of taking an albedo: refused without one
        clean = args.guide_auxiliary == "clean" and not args.nrm  # clean features: a pair, refused without a normal
        if args.guide == "oidn" and ((args.nrm or asked) and not args.alb or clean):  # the first frame says
            first = frame_plane_kwargs(args, planes[:1])  # a dict, or a list of one (its own plane files)
            first = first[0] if isinstance(first, list) else first
            with warnings.catch_warnings():
                # Frames read in this process say the reader's warnings themselves: not twice. A worker process' or a
                # cluster's do not reach this one, so there this read says them.
                if getattr(args, "executor", None) in (None, "threads") and getattr(args, "scheduler", None) is None:
                    warnings.simplefilter("ignore")
                found = read_sample_buffer(sources[0], **first).features
            if "albedo" not in found:
                if args.nrm:
                    raise UsageError(f"--nrm: OIDN takes a normal only beside an albedo, and {sources[0]} holds "
                                     "none; give --alb too")
                raise UsageError(f"--guide-auxiliary {args.guide_auxiliary}: {sources[0]} holds no albedo, so OIDN "
                                 "takes the colour alone; give --alb, or leave the option out")
            if clean and "normal" not in found:
                raise UsageError(f"--guide-auxiliary clean: OIDN takes the features as clean only as a pair, and "
                                 f"{sources[0]} holds no normal; give --nrm, or choose noisy or prefilter")
    except ValueError:  # UsageError, InputFileError: a check failed, maybe on an input replaced meanwhile
        plan.check_unchanged()
        raise

    frames: list[FrameResult] = []
    final: dict[Path, str] = {}
    with OutputSet(overwrite=args.overwrite) as outputs:
        staged = []
        for inputs, output in jobs:
            image = outputs.add(output)
            final[image] = output
            preview = None
            if len(inputs) > 1:
                preview = outputs.add(inputs[1])
                final[preview] = inputs[1]
            staged.append((image, preview))
        bar = progress(iter(range(len(jobs))), quiet=args.quiet, total=len(jobs), desc="frames")

        def done(frame: FrameResult) -> None:
            frames.append(frame)
            next(bar, None)

        # Without --workers a single frame runs in this thread and several on a thread pool; with
        # them, on the executor asked for (one task per frame: paths travel, not pixels).
        executor = executor_from_args(args) if executor_requested(args) else contextlib.nullcontext(None)
        with executor as pool, library_threads(threads) as library:
            try:
                # The staging folder is this run's: a frame run again (a Dask worker lost) replaces
                # its own staged file, as a first run writes it.
                denoise_frames(sources, [i for i, _ in staged],
                               previews=[p for _, p in staged] if args.preview else None, exposure=args.exposure or 0.0,
                               reference=refs if args.ref else None, executor=pool, half=args.half, overwrite=True,
                               read_options=frame_plane_kwargs(args, planes), on_frame=done, windows=windows,
                               threads=library, **reconstruction_kwargs(args))
            except FramesFailedError as exc:
                plan.check_unchanged()  # a frame failed on an input replaced meanwhile: that is the error
                source, error = next(iter(exc.failures.items()))
                if type(error).__name__ == "KilledWorker":  # distributed's: it named a task key, not the frame
                    raise RuntimeFailure(f"{source}: the Dask worker denoising it died, on every worker that took it "
                                         "(out of memory, or past the workers' --memory-limit?)") from None
                # The first failed frame's own error, so it keeps its exit status and one-line message.
                raise _named_as_output(error, final, sources) from None
            finally:
                bar.close()
        plan.check_unchanged()  # after the last read of every input, before anything is committed
        outputs.commit()  # asks first for a signal whose exception was lost (interrupts.raising)
    order = {src: i for i, src in enumerate(sources)}
    for frame in sorted(frames, key=lambda f: order.get(f.source, 0)):
        output = final[frame.output]
        status(_note(frame, output, args.nonfinite, args.guide, args.guide_auxiliary), quiet=args.quiet)
        if frame.relmse is not None:  # a result, as awr diff prints its own: on stdout, with -q too
            print(f"{shown(output)}: relMSE {frame.relmse:.6g} against {shown(refs[order[frame.source]])}")
    if args.maxerror is not None:
        over = [f for f in sorted(frames, key=lambda f: order.get(f.source, 0))  # the first frame, not the first done
                if f.relmse is not None and f.relmse > args.maxerror]
        if over:
            f = over[0]
            raise RuntimeFailure(f"{final[f.output]}: relMSE {f.relmse:.4g} against {refs[order[f.source]]} exceeds "
                                 f"--maxerror {args.maxerror:g}")
    return EXIT_OK
