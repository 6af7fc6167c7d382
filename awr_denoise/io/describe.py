"""What an EXR file holds, for ``awr info``: layout, layers, views, passes, counts, and what is
missing before it can be denoised. Works on any file the readers accept, including renderer
files that cannot be denoised as they are (Mitsuba without ``spp``, Cycles without variance).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputFileError
from .cycles import cycles_layers
from .exr import file_error, header_value, read_exr
from .presets import describe_layout, detect_preset, file_views, read_sample_dump, warnings_collected
from .request_map import read_request

__all__ = ["describe_file"]

_HEADER_PREFIXES = ("awr:", "cycles.", "samplesPerPixel", "generatedBy", "Software", "renderTimeSeconds")


def _stats(a: Any) -> dict[str, float]:
    a = np.asarray(a)
    return {"min": float(a.min()), "mean": float(a.mean()), "max": float(a.max())}


def describe_file(path: str | os.PathLike[str], *, preset: str = "auto", color: str | None = None,
                  variance: str | None = None, count: str | None = None, variance_kind: str | None = None,
                  spp: int | None = None, layer: str | None = None, view: str | None = None,
                  nonfinite: str = "raise", albedo: str | None = None, normal: str | None = None,
                  depth: str | None = None) -> dict[str, Any]:
    """A JSON-ready description of an EXR file.

    Returns
    -------
    dict
        ``file``, ``width``, ``height``, ``windows`` (``dataWindow`` and ``displayWindow`` as
        ``[[xmin, ymin], [xmax, ymax]]``), ``parts``, ``deep``, ``views``, ``channels``,
        ``attributes`` (renderer and ``awr:*`` header values) and ``kind`` (``"samples"``,
        ``"request"`` or ``"image"``). For sample statistics also ``preset``, ``colour``,
        ``variance`` and ``count`` (where each was found, or None), ``layers`` (Cycles: pass
        names per view layer), ``notes`` and ``warnings`` (the readers' decisions),
        ``missing`` (what must be supplied before ``awr denoise`` can run; empty when
        nothing), ``features`` (albedo, normal, depth found: their plane and, when the file is
        readable, the range of their means and the pixels whose variance the file gives) and,
        when readable, ``total_samples``, ``spp``, ``mean``, ...

    Raises
    ------
    InputFileError
        The file is not a readable EXR, or an option names a layer, view or plane it lacks.

    Examples
    --------
    >>> import numpy as np, os, tempfile
    >>> from awr_denoise.io import write_image
    >>> from awr_denoise.io.describe import describe_file
    >>> f = os.path.join(tempfile.mkdtemp(), "img.exr"); _ = write_image(f, np.ones((2, 3, 3)))
    >>> d = describe_file(f); (d["kind"], d["width"], d["height"])
    ('image', 3, 2)
    """
    p = Path(path)
    parts = read_exr(p)
    header = parts[0].header
    attrs: dict[str, Any] = {}
    for part in parts:
        for key in part.header:
            if str(key).startswith(_HEADER_PREFIXES) and key not in attrs:
                attrs[str(key)] = header_value(part.header, key)
    lo, hi = header["dataWindow"]
    views = file_views(parts)
    channels = sorted({c.name for part in parts for c in part.header.get("channels", [])})
    window = {"dataWindow": [[int(v) for v in lo], [int(v) for v in hi]]}
    if "displayWindow" in header:
        window["displayWindow"] = [[int(v) for v in corner] for corner in header["displayWindow"]]
    info: dict[str, Any] = {"file": os.fspath(path), "width": int(hi[0] - lo[0] + 1),
                            "height": int(hi[1] - lo[1] + 1), "windows": window, "parts": len(parts),
                            "deep": any(part.deep for part in parts), "views": views, "channels": channels,
                            "attributes": attrs}
    # A renderer's batch may carry its request's header, semantics and all: its channels say which it is.
    if str(attrs.get("awr:semantics", "")) == "sample-request" and "counts" in channels:
        req = read_request(p)
        info.update(kind="request", round=req.round, total=req.total, spp=_stats(req.counts),
                    first_index=_stats(req.first_index))
        return info
    if view is not None and view not in views:  # no part of it matched: described as an image (a walkthrough)
        raise file_error(p, f"no view {view!r} (views: {', '.join(views) or 'none, a single-view file'})")
    options = dict(preset=preset, color=color, variance=variance, count=count, variance_kind=variance_kind,
                   spp=spp, layer=layer, albedo=albedo, normal=normal, depth=depth)
    missing: list[str] = []
    # A file of one view (a stereo render with one eye enabled) is read in that view, as the readers
    # do; without it no part matched and the render was called an image.
    chosen_view = view if view is not None or len(views) != 1 else views[0]
    if view is None and len(views) > 1:
        chosen_view = views[0]
        missing.append(f"a view: the file has {len(views)} ({', '.join(views)}); choose one with --view "
                       f"(described here: {chosen_view})")
    if not info["deep"]:
        if preset == "auto" and color is None and variance is None and count is None:
            flat = [c for part in parts if not part.deep and part.header.get("view") in (None, chosen_view)
                    for c in part.channels]
            if detect_preset(flat, header) == "generic":
                info.update(kind="image")
                return info
        # A count given for an awr dump goes to its reader, which says why it is refused (an awr dump counts its
        # samples in sampleCount), not to a layout that finds no variance in it.
        if (preset == "awr" or (preset == "auto" and color is None and variance is None
                                and detect_preset(channels, header) == "awr")):
            return _read_fully(info, p, options, chosen_view, nonfinite, preset="awr", missing=missing)
        layers = cycles_layers(channels)
        if (layer is None and color is None and len(layers) > 1 and preset in ("auto", "cycles")
                and detect_preset(channels, header) == "cycles"):
            # Described in its first layer, as a file of several views is in its first view: the ambiguity alone
            # described nothing (a walkthrough).
            options["layer"] = sorted(layers)[0]
            missing.append(f"a layer: the file has {len(layers)} ({', '.join(sorted(layers))}); choose one with "
                           f"--layer (described here: {options['layer']})")
        name, layout, notes, warned, planes = describe_layout(p, parts, **options, view=chosen_view)
        info.update(kind="samples", preset=name, colour=layout.colour.label,
                    variance=None if layout.spread is None else layout.spread.label,
                    count=None if layout.count is None else _stats(layout.count),
                    # As a dump read fully says them (the JSON's documented keys); it replaces them where it is.
                    spp=None if layout.count is None else _stats(layout.count),
                    total_samples=None if layout.count is None else int(np.asarray(layout.count).sum()),
                    notes=list(notes), warnings=list(warned),
                    features={n: {"plane": plane} for n, plane in planes.items()})
        if name == "cycles":
            info["layers"] = {k: sorted(v) for k, v in sorted(layers.items())}
        if layout.spread is None:
            missing.append("a variance: " + ("Cycles writes none; merge renders made with different seeds "
                                             "(awr merge --independent A.exr B.exr ...) or give --variance PLANE"
                                             if name == "cycles" else "give --variance PLANE"))
        if layout.count is None:
            missing.append("a sample count: " + ("Mitsuba 3 writes none; give --spp N, the samples it took per "
                                                 "pixel (the sampler's sample_count, rounded up by stratified, "
                                                 "multijitter, orthogonal and ldsampler)"
                                                 if name == "mitsuba" else "give --spp N or --count PLANE"))
    else:
        return _read_fully(info, p, options, chosen_view, nonfinite, preset="deep", missing=missing)
    info["missing"] = missing
    if any(not item.startswith("a view") for item in missing):
        return info
    return _read_fully(info, p, options, chosen_view, nonfinite, preset=info["preset"], missing=missing)


def _read_fully(info: dict[str, Any], p: Path, options: dict[str, Any], view: str | None, nonfinite: str, *,
                preset: str, missing: list[str]) -> dict[str, Any]:
    """Read the statistics themselves and add what they say to ``info``."""
    info.setdefault("kind", "samples")
    info.setdefault("preset", preset)
    info.setdefault("notes", [])
    info.setdefault("warnings", [])
    info["missing"] = missing
    with warnings_collected() as caught:  # this thread's alone (another thread's warnings stay its own)
        try:
            dump = read_sample_dump(p, **options, view=view, nonfinite=nonfinite)
        except InputFileError as exc:
            info["missing"].append(str(exc))
            return info
    for message in caught:
        if message not in info["warnings"]:
            info["warnings"].append(message)
    for note in dump.notes:
        if note not in info["notes"] and note not in info["warnings"]:
            info["notes"].append(note)
    buf = dump.buffer
    info.update(buffer_channels=list(buf.channels), total_samples=buf.total_samples, spp=_stats(buf.count),
                pixels_without_samples=int((buf.count == 0).sum()),
                variance_unknown=int((~buf.variance_known & (buf.count >= 2)).sum()),
                nonfinite_dropped=int(buf.nonfinite), mean=_stats(buf.mean),
                issued_total=int(np.asarray(dump.issued).sum()))
    if buf.total_samples == 0:  # what awr denoise refuses: "ready" would be a false promise
        info["missing"].append("samples: no pixel has any sample")
    described = info.setdefault("features", {})
    for name, feature in buf.features.items():
        described.setdefault(name, {}).update(
            channels=list(feature.channels), mean=_stats(feature.mean),
            variance_known=int((feature.variance_known & (feature.count >= 2)).sum()))

    return info
