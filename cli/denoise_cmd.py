"""``awr denoise``: wavelet reconstruction of a sample dump into an image (Eq. 10-11)."""

from __future__ import annotations

import argparse
import contextlib

from awr_denoise.domains import DOMAIN_NAMES
from awr_denoise.parallel import FrameResult, FramesFailedError, denoise_frames
from awr_denoise.reconstruct import DEFAULT_C_S, DEFAULT_DOMAIN, DEFAULT_MODE, MODES
from awr_denoise.wavelets import DEFAULT_WAVELET

from .common import (
    EXIT_OK,
    RuntimeFailure,
    UsageError,
    add_plane_options,
    frame_jobs,
    plane_kwargs,
    progress,
    refuse_same_file,
    status,
)
from .parallel_options import add_executor_arguments, executor_from_args, executor_requested

__all__ = ["register", "run", "add_reconstruction_options", "reconstruction_kwargs"]


def add_reconstruction_options(parser: argparse.ArgumentParser) -> None:
    """``--c-s``, ``--wavelet``, ``--levels``, ``--domain``, ``--mode``, with the library's defaults."""
    g = parser.add_argument_group("reconstruction")
    g.add_argument("--c-s", type=float, default=DEFAULT_C_S, metavar="C",
                   help="threshold in standard errors (Eq. 11); 0 returns the plain mean (default %(default)g)")
    g.add_argument("--wavelet", default=DEFAULT_WAVELET,
                   help="PyWavelets discrete wavelet (default %(default)s, CDF 9/7)")
    g.add_argument("--levels", type=int, metavar="L", help="decomposition depth (default: automatic)")
    g.add_argument("--domain", default=DEFAULT_DOMAIN, choices=DOMAIN_NAMES,
                   help="domain in which coefficients are thresholded (default %(default)s)")
    g.add_argument("--mode", default=DEFAULT_MODE, choices=MODES,
                   help="threshold every channel, or decide on luminance and keep hue (default %(default)s)")


def reconstruction_kwargs(args: argparse.Namespace) -> dict:
    """Keyword arguments of :func:`awr_denoise.reconstruct_detailed` from the options."""
    return {"c_s": args.c_s, "wavelet": args.wavelet, "levels": args.levels, "domain": args.domain,
            "mode": args.mode}


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``denoise`` sub-parser to ``sub``."""
    p = sub.add_parser("denoise", help="reconstruct a denoised image from a sample dump",
                       description="Reconstruct a denoised image from per-pixel sample statistics "
                                   "(wavelet soft thresholding by propagated standard error).")
    p.add_argument("input", nargs="?", metavar="DUMP.exr",
                   help="sample dump (any preset); may hold a #### frame placeholder")
    p.add_argument("--hdr", metavar="DUMP.exr", help="same as the positional input (oidnDenoise's name)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.exr", help="denoised image (may hold ####)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--frames", metavar="RANGE", help="frame numbers for #### patterns, e.g. 1-100 or 1-100x5")
    p.add_argument("--half", action="store_true", help="write HALF channels (refused above 65504)")
    p.add_argument("--preview", metavar="OUT.png", help="also write an sRGB PNG preview (may hold ####)")
    p.add_argument("--exposure", type=float, default=0.0, help="preview exposure in stops (default 0)")
    p.add_argument("-r", "--ref", metavar="REF.exr", help="reference image to compare the result with")
    p.add_argument("--maxerror", type=float, metavar="E",
                   help="with --ref: fail (exit 1) when the relative MSE exceeds E")
    p.add_argument("--alb", metavar="FILE", help=argparse.SUPPRESS)
    p.add_argument("--nrm", metavar="FILE", help=argparse.SUPPRESS)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    add_reconstruction_options(p)
    add_plane_options(p)
    add_executor_arguments(p)
    p.set_defaults(run=run)


def _note(frame: FrameResult, nonfinite_policy: str) -> str:
    """The one-line summary of a denoised frame."""
    h, w = frame.shape
    note = f"{frame.output}: {w}x{h}, {frame.spp:.3g} spp, {100 * frame.fraction_zeroed:.1f}% coefficients zeroed"
    if frame.nonfinite:
        note += f", {frame.nonfinite} non-finite sample(s) {'dropped' if nonfinite_policy == 'drop' else 'zeroed'} " \
                "on input"
    if frame.relmse is not None:
        note += f", relMSE {frame.relmse:.4g}"
    return note


def run(args: argparse.Namespace) -> int:
    """Run ``awr denoise``; returns the exit status (errors are raised and reported by ``main``)."""
    if args.alb or args.nrm:
        raise UsageError("--alb/--nrm: wavelet reconstruction uses no feature guides; drop these options")
    if args.input and args.hdr:
        raise UsageError("give the input either as DUMP.exr or with --hdr, not both")
    source = args.input or args.hdr
    if not source:
        raise UsageError("no input: give DUMP.exr (or --hdr DUMP.exr)")
    if args.maxerror is not None and not args.ref:
        raise UsageError("--maxerror needs --ref REF.exr")
    jobs = frame_jobs([source] + ([args.preview] if args.preview else []), args.output, args.frames)
    # Check every frame's names before writing anything.
    for inputs, output in jobs:
        refuse_same_file(output, [inputs[0], args.ref, args.color, args.variance, args.count])
        if len(inputs) > 1:
            refuse_same_file(inputs[1], [inputs[0], output])
    frames: list[FrameResult] = []
    bar = progress(iter(range(len(jobs))), quiet=args.quiet, total=len(jobs), desc="frames")

    def done(frame: FrameResult) -> None:
        frames.append(frame)
        next(bar, None)
        status(_note(frame, args.nonfinite), quiet=args.quiet)

    # Without --workers a single frame runs in this thread and several on a thread pool; with
    # them, on the executor asked for (one task per frame: paths travel, not pixels).
    executor = executor_from_args(args) if executor_requested(args) else contextlib.nullcontext(None)
    with executor as pool:
        try:
            denoise_frames([i[0] for i, _ in jobs], [o for _, o in jobs],
                           previews=[i[1] for i, _ in jobs] if args.preview else None, exposure=args.exposure,
                           reference=args.ref, executor=pool, overwrite=args.overwrite, half=args.half,
                           read_options=plane_kwargs(args), on_frame=done, **reconstruction_kwargs(args))
        except FramesFailedError as exc:
            # The first failed frame's own error, so it keeps its exit status and one-line message.
            raise next(iter(exc.failures.values())) from None
        finally:
            bar.close()
    if args.maxerror is not None:
        over = [f for f in frames if f.relmse is not None and f.relmse > args.maxerror]
        if over:
            f = over[0]
            raise RuntimeFailure(f"{f.output}: relMSE {f.relmse:.4g} against {args.ref} exceeds "
                                 f"--maxerror {args.maxerror:g}")
    return EXIT_OK
