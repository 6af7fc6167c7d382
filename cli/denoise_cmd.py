"""``awr denoise``: wavelet reconstruction of a sample dump into an image (Eq. 10-11)."""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import os

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

__all__ = ["register", "run", "add_reconstruction_options", "reconstruction_kwargs"]


def add_reconstruction_options(parser: argparse.ArgumentParser) -> None:
    """``--c-s``, ``--wavelet``, ``--levels``, ``--domain``, ``--mode``."""
    g = parser.add_argument_group("reconstruction")
    g.add_argument("--c-s", type=float, default=1.0, metavar="C",
                   help="threshold in standard errors (Eq. 11); 0 returns the plain mean (default 1)")
    g.add_argument("--wavelet", default="bior4.4", help="PyWavelets wavelet (default bior4.4, CDF 9/7)")
    g.add_argument("--levels", type=int, metavar="L", help="decomposition depth (default: automatic)")
    g.add_argument("--domain", default="log", choices=("log", "gamma", "linear"),
                   help="domain in which coefficients are thresholded (default log)")
    g.add_argument("--mode", default="channels", choices=("channels", "luminance"),
                   help="threshold every channel, or decide on luminance and keep hue (default channels)")


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
    from awr_denoise.parallel import add_executor_arguments

    add_executor_arguments(p)
    p.set_defaults(run=run)


def _denoise_one(args: argparse.Namespace, source: str, output: str, preview: str | None) -> str:
    import numpy as np

    from awr_denoise import __version__, reconstruct_detailed
    from awr_denoise.io import read_image, read_sample_buffer, write_image, write_preview

    buffer = read_sample_buffer(source, **plane_kwargs(args))
    result = reconstruct_detailed(buffer, variance_probes=0, **reconstruction_kwargs(args))
    header = {
        "awr:version": __version__, "awr:c_s": float(args.c_s), "awr:wavelet": args.wavelet,
        "awr:levels": int(result.levels), "awr:domain": args.domain, "awr:mode": args.mode,
        "awr:input": os.path.basename(source), "awr:spp": float(buffer.total_samples / buffer.count.size),
        "awr:fraction_zeroed": float(result.fraction_zeroed), "awr:nonfinite": int(buffer.nonfinite),
    }
    write_image(output, result.image, channels=buffer.channels, header=header, half=args.half,
                overwrite=args.overwrite)
    if preview:
        write_preview(preview, result.image, exposure=args.exposure, overwrite=args.overwrite)
    note = f"{output}: {buffer.shape[1]}x{buffer.shape[0]}, {header['awr:spp']:.3g} spp, " \
           f"{100 * result.fraction_zeroed:.1f}% coefficients zeroed"
    if buffer.nonfinite:
        note += f", {buffer.nonfinite} non-finite sample(s) {'dropped' if args.nonfinite == 'drop' else 'zeroed'} " \
                "on input"
    if args.ref:
        from awr_denoise.metrics import relmse

        ref = read_image(args.ref)
        image = np.asarray(result.image)
        if ref.shape[:2] != image.shape[:2]:
            raise UsageError(f"{args.ref}: size {ref.shape[1]}x{ref.shape[0]} does not match "
                             f"{image.shape[1]}x{image.shape[0]} of {source}")
        k = min(ref.shape[2], image.shape[2])
        err = relmse(image[..., :k], ref[..., :k])
        note += f", relMSE {err:.4g}"
        if args.maxerror is not None and err > args.maxerror:
            raise RuntimeFailure(f"{output}: relMSE {err:.4g} against {args.ref} exceeds --maxerror {args.maxerror:g}")
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
    from awr_denoise.parallel import executor_from_args, executor_requested

    if not executor_requested(args):
        for inputs, output in progress(jobs, quiet=args.quiet, total=len(jobs), desc="frames"):
            note = _denoise_one(args, inputs[0], output, inputs[1] if len(inputs) > 1 else None)
            status(note, quiet=args.quiet)
        return EXIT_OK
    with executor_from_args(args) as executor:  # one task per frame: paths travel, not pixels
        futures = [executor.submit(_denoise_one, args, inputs[0], output, inputs[1] if len(inputs) > 1 else None)
                   for inputs, output in jobs]
        for future in progress(cf.as_completed(futures), quiet=args.quiet, total=len(futures), desc="frames"):
            status(future.result(), quiet=args.quiet)
    return EXIT_OK
