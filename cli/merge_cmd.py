"""``awr merge``: fold new batches of samples into the running dump (tell), exactly."""

from __future__ import annotations

import argparse

from .common import EXIT_OK, UsageError, add_plane_options, plane_kwargs, refuse_same_file, status

__all__ = ["register", "run"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``merge`` sub-parser to ``sub``."""
    p = sub.add_parser("merge", help="merge batch dumps into the running dump (tell)",
                       description="Merge sample dumps with Chan's exact parallel update of count, mean and "
                                   "variance, and write the result in the awr dump layout. The first input is "
                                   "the running dump (or the first batch).")
    p.add_argument("inputs", nargs="+", metavar="DUMP.exr", help="running dump, then new batches")
    p.add_argument("-o", "--output", required=True, metavar="MERGED.exr",
                   help="merged dump (a new file: inputs are never replaced)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--request", metavar="REQUEST.exr",
                   help="the request the last batch answers: checks its counts and records issued samples")
    p.add_argument("--independent", action="store_true",
                   help="the inputs are whole renders of the same frame with different seeds and no variance "
                        "(Blender Cycles): merge them with the variance estimated from the spread of their means")
    p.add_argument("-q", "--quiet", action="store_true")
    add_plane_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run ``awr merge``; returns the exit status (errors are raised and reported by ``main``)."""
    import numpy as np

    from awr_denoise.errors import InputFileError
    from awr_denoise.io import read_request, read_sample_dump, request_attributes, write_sample_buffer

    refuse_same_file(args.output, [*args.inputs, args.request])
    if args.independent:
        from awr_denoise.io import read_independent_renders

        kwargs = plane_kwargs(args)
        dump = read_independent_renders(args.inputs, **{k: kwargs[k] for k in ("preset", "color", "count", "spp",
                                                                                 "layer", "view")})
        write_sample_buffer(args.output, dump.buffer, overwrite=args.overwrite)
        h, w = dump.buffer.shape
        status(f"{args.output}: {len(args.inputs)} independent renders, {dump.buffer.total_samples} samples "
               f"({dump.buffer.total_samples / (h * w):.4g} spp)", quiet=args.quiet)
        return EXIT_OK
    dumps = [read_sample_dump(path, **plane_kwargs(args)) for path in args.inputs]
    merged = dumps[0].buffer
    issued = np.array(dumps[0].issued)
    for path, dump in zip(args.inputs[1:], dumps[1:]):
        if dump.buffer.shape != merged.shape:
            h, w = dump.buffer.shape
            raise InputFileError(f"{path}: size {w}x{h} does not match {merged.shape[1]}x{merged.shape[0]} "
                                 f"of {args.inputs[0]}")
        if dump.buffer.channels != merged.channels:
            raise InputFileError(f"{path}: channels {','.join(dump.buffer.channels)} do not match "
                                 f"{','.join(merged.channels)} of {args.inputs[0]}")
        merged = merged.merge(dump.buffer)
        issued = issued + dump.issued
    attrs = {k: v for k, v in dumps[0].attributes.items()
             if k in ("awr:seed", "awr:round", "awr:strategy", "awr:scene")}
    rounds = [int(str(d.attributes["awr:round"])) for d in dumps if "awr:round" in d.attributes]
    if args.request:
        request = read_request(args.request)
        last, last_path = dumps[-1].buffer, args.inputs[-1]
        if request.shape != last.shape:
            h, w = request.shape
            raise InputFileError(f"{args.request}: size {w}x{h} does not match {last.shape[1]}x{last.shape[0]} "
                                 f"of {last_path}")
        over = last.count > request.counts
        if over.any():
            raise InputFileError(f"{last_path}: sampleCount: {int(over.sum())} pixel(s) hold more samples than "
                                 f"{args.request} asked for")
        # Samples asked for but not delivered (dropped NaN/Inf) still used up their indices.
        issued = np.maximum(issued, request.first_index + request.counts)
        rounds.append(request.round)
        req_attrs = request_attributes(args.request)
        if "awr:seed" in req_attrs and "awr:seed" not in attrs:
            attrs["awr:seed"] = req_attrs["awr:seed"]
    elif len(dumps) == 1:
        raise UsageError("merge: give the running dump and at least one batch (or --request for a first batch)")
    if rounds:  # without any round information (plain batches) plan starts at round 1
        attrs["awr:round"] = max(rounds) + 1
    write_sample_buffer(args.output, merged, header=attrs, issued=issued, overwrite=args.overwrite)
    h, w = merged.shape
    status(f"{args.output}: {merged.total_samples} samples ({merged.total_samples / (h * w):.4g} spp), "
           f"next round {attrs.get('awr:round', 1)}", quiet=args.quiet)
    return EXIT_OK
