"""``awr diff``: error metrics of an image against a reference, and a difference image."""

from __future__ import annotations

import argparse

import numpy as np

from awr_denoise.io import provenance, read_image, write_image
from awr_denoise.metrics import HIGHER_IS_BETTER, METRICS

from awr_denoise.io.exr import check_same_windows, read_exr, recorded_windows

from . import interrupts
from .common import EXIT_OK, RuntimeFailure, UsageError, print_json
from .errors import shown
from .paths import PathPlan
from .values import nonempty, real

__all__ = ["register", "run"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``diff`` sub-parser to ``sub``."""
    p = sub.add_parser("diff", help="compare an image with a reference (relMSE, MSE, image mean, PSNR, SSIM)",
                       description="Error metrics of IMAGE against REF. With --maxerror, exit 1 when the chosen "
                                   "metric is worse than the bound (a golden-image check).")
    p.add_argument("input", metavar="IMAGE.exr", help="image or sample dump (its R,G,B are the mean)")
    p.add_argument("-r", "--ref", type=nonempty, required=True, metavar="REF.exr", help="reference image")
    p.add_argument("-o", "--output", type=nonempty, metavar="DIFF.exr", help="write the signed difference IMAGE - REF")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--metric", choices=tuple(METRICS), help="metric checked by --maxerror (default relmse)")
    p.add_argument("--maxerror", type=real(), metavar="E",
                   help="fail when the metric exceeds E (for psnr and ssim: falls below E)")
    p.add_argument("--channels", metavar="LIST|LAYER",
                   help="IMAGE's channels: comma-separated names (R,G,B), or a layer whose R,G,B are read "
                        "(ViewLayer.Combined in a Blender file); default: its R,G,B")
    p.add_argument("--ref-channels", metavar="LIST|LAYER",
                   help="the reference's channels, as --channels; default: the channels --channels names where the "
                        "reference holds them all (paired by name), else its R,G,B")
    p.add_argument("--view", metavar="NAME", help="the view of a multi-view IMAGE to compare (stereo: left, right)")
    p.add_argument("--ref-view", metavar="NAME", help="the view of a multi-view reference, as --view")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(run=run)


def _channel_names(path: str) -> set[str]:
    """Every part's channel names: Blender writes one part per pass (a later pass's layer is no less there)."""
    return {getattr(channel, "name", str(channel)) for part in read_exr(path, header_only=True)
            if not part.deep for channel in part.header.get("channels", [])}


def _counterpart(spec: str | None, other: str, option: str) -> str | None:
    """The channel choice of the file whose option was not given, when ``option`` gave ``spec`` for the
    other: the same names where ``other`` holds them all (paired by name), else its R,G,B (by position).

    A list that is R,G,B in another order (``B,G,R``, the order ``awr info`` prints) would pair B with
    the other file's R by position: refused, asking for the other file's channels."""
    names = [] if spec is None else [name.strip() for name in spec.split(",")]
    if len(names) < 2:  # none, or a layer or one channel: R,G,B in that order on both sides
        return None
    if set(names) <= _channel_names(other):
        return spec
    bases = [name.rsplit(".", 1)[-1].upper() for name in names]
    if sorted(bases) in (["B", "G", "R"], ["A", "B", "G", "R"]) and bases[:3] != ["R", "G", "B"]:
        counter = "--ref-channels" if option == "--channels" else "--channels"
        raise UsageError(f"{option}: {spec} would be paired by position with {shown(other)}'s R,G,B; "
                         f"give {counter} too")
    return None


def _names(spec: str, option: str) -> list[str]:
    """The channel names of ``spec``, given as ``option``: none empty, none twice."""
    names = [name.strip() for name in spec.split(",")]
    if not all(names):
        raise UsageError(f"{option}: {spec!r} has an empty channel name")
    if len(set(names)) < len(names):
        raise UsageError(f"{option}: {spec!r} names a channel twice")
    return names


def _space(spec: str | None, path: str) -> str | None:
    """``"xyz"`` where ``spec`` names X,Y,Z channels, ``"rgb"`` where it names R,G,B or, not given, the file holds
    them (the default read); else None."""
    if spec is None:
        bases = {name.rsplit(".", 1)[-1] for name in _channel_names(path)}
        return "rgb" if {"R", "G", "B"} <= bases else None
    bases = sorted(name.strip().rsplit(".", 1)[-1] for name in spec.split(","))
    return {("X", "Y", "Z"): "xyz", ("B", "G", "R"): "rgb"}.get(tuple(bases))


def _image(path: str, spec: str | None, option: str, view: str | None) -> np.ndarray:
    """The image at ``path`` with its channel choice ``spec`` (given as ``option``): a
    comma-separated list of names, or one name: a layer's R,G,B if the file has them, else that
    one channel."""
    if spec is None:
        return read_image(path, view=view)
    names = _names(spec, option)
    if len(names) > 1:
        return read_image(path, channels=names, view=view)
    present = _channel_names(path)
    layer = [f"{names[0]}.{c}" for c in "RGB"]
    if set(layer) <= present:
        return read_image(path, channels=layer, view=view)
    if names[0] not in present:
        raise UsageError(f"{path}: {option} {names[0]}: neither a channel nor a layer with R,G,B")
    return read_image(path, channels=names, view=view)


def run(args: argparse.Namespace) -> int:
    """Run ``awr diff``; returns the exit status (errors are raised and reported by ``main``)."""
    if args.metric is not None and args.maxerror is None:  # it chooses what --maxerror checks: alone, nothing
        raise UsageError(f"--metric: {args.metric} is the metric --maxerror checks; give --maxerror E too "
                         "(every metric is printed)")
    args.metric = args.metric or "relmse"
    for spec, option in ((args.channels, "--channels"), (args.ref_channels, "--ref-channels")):
        if spec is not None:  # each list checked as given, before one is lent to the other file
            _names(spec, option)
    if args.maxerror is not None and args.maxerror < 0 and args.metric not in HIGHER_IS_BETTER:
        # relMSE and MSE are never negative: such a bound fails every image, a typo for a check.
        raise UsageError(f"--maxerror: {args.maxerror:g} is below 0, which {args.metric} never is")
    if args.maxerror is not None and args.metric == "ssim" and not -1 <= args.maxerror <= 1:
        # Above 1 every image fails, below -1 every image passes: a typo for a check either way.
        raise UsageError(f"--maxerror: {args.maxerror:g} is outside -1..1, the range of ssim")
    plan = PathPlan(overwrite=args.overwrite)
    plan.read(args.input, "IMAGE.exr")
    plan.read(args.ref, "-r/--ref")
    plan.write(args.output, "-o/--output")
    plan.check()
    image_spec, ref_spec = args.channels, args.ref_channels  # one given: the other pairs by name
    if ref_spec is None:
        ref_spec = _counterpart(image_spec, args.ref, "--channels")
    elif image_spec is None:
        image_spec = _counterpart(ref_spec, args.input, "--ref-channels")
    spaces = {_space(image_spec, args.input), _space(ref_spec, args.ref)}
    if spaces == {"rgb", "xyz"}:  # paired by position, R with X: a plausible number of nothing (a walkthrough)
        raise UsageError(f"{args.ref if _space(ref_spec, args.ref) == 'xyz' else args.input}: its CIE X,Y,Z would be "
                         "compared with the other image's R,G,B channel by channel; compare images of one colour "
                         "space (convert one of them)")
    # Each file's windows from the read of its pixels (another read could meet the file's next version).
    with recorded_windows() as reads:
        image = _image(args.input, image_spec, "--channels", args.view)
    windows = reads[-1][1]
    with recorded_windows() as reads:
        ref = _image(args.ref, ref_spec, "--ref-channels", args.ref_view)
    try:
        if image.shape[:2] != ref.shape[:2]:
            raise UsageError(f"{args.ref}: size {ref.shape[1]}x{ref.shape[0]} does not match "
                             f"{image.shape[1]}x{image.shape[0]} of {args.input}")
        if image.shape[2] != ref.shape[2]:
            raise UsageError(f"{args.ref}: {ref.shape[2]} channel(s) read from the reference, {image.shape[2]} from "
                             f"IMAGE {args.input}; choose matching ones with --channels and --ref-channels")
        check_same_windows(args.ref, reads[-1][1], args.input, windows)
    except ValueError:  # maybe a file replaced between the reads: that is the error then
        plan.check_unchanged()
        raise
    x = image.astype(np.float64)
    r = ref.astype(np.float64)
    result = {"file": args.input, "reference": args.ref} | {name: f(x, r) for name, f in METRICS.items()}
    interrupts.check()  # a signal whose exception a C extension's import swallowed: no output after it
    plan.check_unchanged()  # after the last read: each image and its windows of one version
    if args.output:
        write_image(args.output, x - r, header={**provenance(input=args.input, reference=args.ref), **windows},
                    overwrite=args.overwrite)
    if args.json:
        print_json(result)
    else:
        print(f"{shown(args.input)}: relMSE {result['relmse']:.6g}  MSE {result['mse']:.6g}  "
              f"mean error {100 * result['mean_error']:.3g}%  PSNR {result['psnr']:.4g} dB  SSIM {result['ssim']:.4f}")
    if args.maxerror is not None:
        value = result[args.metric]
        worse = value < args.maxerror if args.metric in HIGHER_IS_BETTER else value > args.maxerror
        if worse:
            raise RuntimeFailure(f"{args.input}: {args.metric} {value:.6g} against {args.ref} is worse than "
                                 f"--maxerror {args.maxerror:g}")
    return EXIT_OK
