"""``awr info``: what a sample dump, renderer file, request map or image holds."""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from awr_denoise.io.describe import describe_file
from awr_denoise.io.exr import read_header

from . import interrupts
from .common import (EXIT_OK, UsageError, add_plane_options, answered_round, dump_options_given, plane_kwargs,
                     print_json, run_settings_refused)
from .errors import shown
from .paths import PathPlan, check_plane_windows, plane_options

__all__ = ["register", "run", "describe"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``info`` sub-parser to ``sub``."""
    p = sub.add_parser("info", help="describe a sample dump, renderer file, request map or EXR image",
                       description="Resolution, channels, layout, layers, views, samples per pixel, and what is "
                                   "missing before the file can be denoised.")
    p.add_argument("input", metavar="FILE.exr")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    add_plane_options(p)
    p.set_defaults(run=run)


def describe(path: str, args: argparse.Namespace) -> dict[str, Any]:
    """A JSON-ready description of ``path`` (see :func:`awr_denoise.io.describe.describe_file`)."""
    return describe_file(path, **plane_kwargs(args))


def _line(text: str) -> None:
    """One line of the report: names and header values from the file shown, never obeyed (a channel
    named with an escape sequence rewrote the terminal)."""
    print(shown(text))


def _print(info: dict[str, Any]) -> None:
    views = f", views {', '.join(info['views'])}" if info.get("views") else ""
    _line(f"{info['file']}: {info['width']}x{info['height']}, {info['parts']} part(s)"
          f"{', deep' if info['deep'] else ''}{views}, {info['kind']}")
    _line(f"  channels: {', '.join(info['channels'])}")
    windows = info.get("windows", {})
    data, display = windows.get("dataWindow"), windows.get("displayWindow")
    if data and display and data != display:
        # A crop (or an overscan) is worth a line; a plain full frame is not.
        (x0, y0), (x1, y1) = data
        (u0, v0), (u1, v1) = display
        inside, apart = x0 >= u0 and y0 >= v0 and x1 <= u1 and y1 <= v1, x0 > u1 or y0 > v1 or x1 < u0 or y1 < v0
        where = "inside" if inside else "outside" if apart else "overlapping"
        _line(f"  data window ({x0}, {y0})-({x1}, {y1}) {where} display window ({u0}, {v0})-({u1}, {v1})")
    if info["kind"] == "samples":
        if "colour" in info:
            _line(f"  layout: {info['preset']}; colour {info['colour']}, variance {info['variance'] or 'none'}")
        else:
            _line(f"  layout: {info['preset']}")
        for layer, passes in info.get("layers", {}).items():
            _line(f"  layer {layer}: {', '.join(passes)}")
        if "pixels_without_samples" in info:  # the statistics read: everything they say
            s = info["spp"]
            _line(f"  samples: {info['total_samples']} total, "
                  f"spp min {s['min']:g} / mean {s['mean']:.4g} / max {s['max']:g}; "
                  f"{info['pixels_without_samples']} pixel(s) without samples; "
                  f"{info['variance_unknown']} with unknown variance; {info['nonfinite_dropped']} non-finite "
                  "sample(s) dropped or zeroed")
        elif info.get("count"):  # the counts alone (no variance to read the statistics with)
            s = info["count"]
            _line(f"  samples per pixel: min {s['min']:g} / mean {s['mean']:.4g} / max {s['max']:g}"
                  + (f"; {info['total_samples']} total" if info.get("total_samples") is not None else ""))
        for name, feature in info.get("features", {}).items():
            where = f" from {feature['plane']}" if "plane" in feature else ""
            values = ""
            if "mean" in feature:
                m = feature["mean"]
                values = (f": mean min {m['min']:.4g} / max {m['max']:.4g}, variance known at "
                          f"{feature['variance_known']} pixel(s)")
            _line(f"  feature {name}{where}{values}")
        if info.get("features"):
            _line("  (features are read and carried; awr denoise --guide features or --guide oidn uses them)")
        for note in info.get("notes", []):
            _line(f"  note: {note}")
        for warning in info.get("warnings", []):
            _line(f"  warning: {warning}")
        missing = info.get("missing", [])
        _line("  ready to denoise" if not missing else "  missing before denoising:")
        for item in missing:
            _line(f"    - {item}")
    elif info["kind"] == "request":
        s = info["spp"]
        _line(f"  request: round {info['round']}, {info['total']} samples, per pixel min {s['min']:g} / "
              f"mean {s['mean']:.4g} / max {s['max']:g}")
        for warning in info.get("warnings", []):
            _line(f"  warning: {warning}")
    for key, value in sorted(info["attributes"].items()):
        _line(f"  {key} = {_shown(value)}")


def _shown(value: object) -> object:
    """A float attribute EXR held in single precision as its shortest decimal there (1.2, not 1.2000000476837158)."""
    if isinstance(value, float) and math.isfinite(value) and float(np.float32(value)) == value:
        return str(np.float32(value))
    return value


def run(args: argparse.Namespace) -> int:
    """Run ``awr info``; returns the exit status (errors are raised and reported by ``main``)."""
    plan = PathPlan()
    plan.read(args.input, "FILE.exr")
    for spec, option in plane_options(args):
        plan.read_plane(spec, option)
    plan.check()
    check_plane_windows(args.input, plane_options(args))
    info = describe(args.input, args)
    given = dump_options_given(args)
    if given and info["kind"] in ("request", "image"):  # described without them: refused, not ignored
        what = "a request map" if info["kind"] == "request" else "an image"
        raise UsageError(f"{given[0][0]}: describes a sample dump; {args.input} is {what}")
    if info["kind"] in ("samples", "request"):
        # "ready to denoise" is about denoise; a running dump's run settings are plan's, a request's merge's (it
        # carries them into the dump), said here too
        is_request = info["kind"] == "request"
        refused = run_settings_refused(args.input, read_header(args.input), (info["height"], info["width"]),
                                       request=is_request)
        if refused is not None:
            who = "awr merge --request refuses it" if is_request else "awr plan refuses it as a running dump"
            info.setdefault("warnings", []).append(f"{who}: {refused}")
        answered = None if is_request else answered_round(read_header(args.input))
        if answered is not None:  # a batch looks like a dump: said, as plan refuses it
            into = "alone" if answered == "0" else "into the running dump"
            info.setdefault("notes", []).append(f"a batch answering request round {answered}: merge it {into} with "
                                                "--request; awr plan refuses it")
    # A signal whose exception a C extension's import swallowed: no report after it.
    interrupts.check()
    if args.json:
        print_json(info)
    else:
        _print(info)
    return EXIT_OK
