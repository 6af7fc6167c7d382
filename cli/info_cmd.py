"""``awr info``: what a sample dump, request map or image holds."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from awr_denoise.io import detect_preset, read_request, read_sample_dump
from awr_denoise.io.exr import header_value, read_exr

from .common import EXIT_OK, add_plane_options, plane_kwargs, print_json

__all__ = ["register", "run", "describe"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``info`` sub-parser to ``sub``."""
    p = sub.add_parser("info", help="describe a sample dump, request map or EXR image",
                       description="Resolution, channels, layout, samples per pixel and bookkeeping of a file.")
    p.add_argument("input", metavar="FILE.exr")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    add_plane_options(p)
    p.set_defaults(run=run)


def _stats(a: Any) -> dict[str, float]:
    return {"min": float(a.min()), "mean": float(a.mean()), "max": float(a.max())}


def describe(path: str, args: argparse.Namespace) -> dict[str, Any]:
    """A JSON-ready description of ``path``."""
    parts = read_exr(path, header_only=True)
    header = parts[0].header
    attrs = {k: header_value(header, k) for k in header if str(k).startswith(("awr:", "cycles.", "samplesPerPixel"))}
    lo, hi = header["dataWindow"]
    info: dict[str, Any] = {"file": path, "width": int(hi[0] - lo[0] + 1), "height": int(hi[1] - lo[1] + 1),
                            "parts": len(parts), "deep": any(p.deep for p in parts),
                            "channels": sorted(c.name for p in parts for c in p.header.get("channels", [])),
                            "attributes": attrs}
    semantics = str(attrs.get("awr:semantics", ""))
    if semantics == "sample-request":
        req = read_request(path)
        info.update(kind="request", round=req.round, total=req.total, spp=_stats(req.counts),
                    first_index=_stats(req.first_index))
        return info
    if args.preset == "auto" and not info["deep"] and args.color is None:
        preset = detect_preset(info["channels"], header)
        if preset == "generic" and args.variance is None:
            info.update(kind="image")
            return info
    dump = read_sample_dump(path, **plane_kwargs(args))
    buf = dump.buffer
    preset = args.preset
    if preset == "auto":
        preset = "deep" if info["deep"] else detect_preset(info["channels"], header)
    info.update(
        kind="samples",
        preset=preset,
        buffer_channels=list(buf.channels), total_samples=buf.total_samples, spp=_stats(buf.count),
        pixels_without_samples=int((buf.count == 0).sum()),
        variance_unknown=int((~buf.variance_known & (buf.count >= 2)).sum()),
        nonfinite_dropped=int(buf.nonfinite),
        mean=_stats(buf.mean), issued_total=int(np.asarray(dump.issued).sum()),
    )
    return info


def run(args: argparse.Namespace) -> int:
    """Run ``awr info``; returns the exit status (errors are raised and reported by ``main``)."""
    info = describe(args.input, args)
    if args.json:
        print_json(info)
        return EXIT_OK
    print(f"{info['file']}: {info['width']}x{info['height']}, {info['parts']} part(s)"
          f"{', deep' if info['deep'] else ''}, {info['kind']}")
    print(f"  channels: {', '.join(info['channels'])}")
    if info["kind"] == "samples":
        s = info["spp"]
        print(f"  layout: {info['preset']}; buffer channels {', '.join(info['buffer_channels'])}")
        print(f"  samples: {info['total_samples']} total, "
              f"spp min {s['min']:g} / mean {s['mean']:.4g} / max {s['max']:g}; "
              f"{info['pixels_without_samples']} pixel(s) without samples; "
              f"{info['variance_unknown']} with unknown variance; {info['nonfinite_dropped']} non-finite sample(s) dropped or zeroed")
    elif info["kind"] == "request":
        s = info["spp"]
        print(f"  request: round {info['round']}, {info['total']} samples, per pixel min {s['min']:g} / "
              f"mean {s['mean']:.4g} / max {s['max']:g}")
    for key, value in sorted(info["attributes"].items()):
        print(f"  {key} = {value}")
    return EXIT_OK
