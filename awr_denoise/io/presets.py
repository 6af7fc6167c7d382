"""Reading sample statistics written by other renderers (layout presets and auto-detection).

Each preset says where a renderer puts the pixel mean, its spread and the sample count:

=========  ===========================  ===============================  ==========================================
preset     mean                         spread (variance kind)           count
=========  ===========================  ===============================  ==========================================
awr        ``R,G,B``                    ``variance.*`` (header says)     ``sampleCount`` (FLOAT)
pbrt       ``R,G,B``                    ``Variance.*`` (sample)          header ``samplesPerPixel``
cycles     ``<layer>.Combined.*``       none: give ``variance=``         ``<layer>.Debug Sample Count.X`` x header
                                                                         ``cycles.<layer>.samples``
renderman  ``Ci.*``                     ``mse.*`` (mean)                 ``sampleCount``
mitsuba    ``<name>.*``                 ``m2_<name>.*`` (second_moment)  none: give ``spp=``
generic    ``color=``                   ``variance=``                    ``count=`` or ``spp=``
=========  ===========================  ===============================  ==========================================

pbrt writes a variance of 0 where it has no estimate (pixels that saw only the environment);
such pixels are marked unknown, never "converged". Channel names are split on the *last*
dot (component) and, for Cycles, the *first* dot (view layer): pass names such as
``Debug Sample Count`` contain spaces, so nothing is split on whitespace or on every dot.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._typing import FloatArray
from ..buffers import VARIANCE_KINDS, SampleBuffer
from .deep import samples_from_deep_part
from .dump import COUNT_CHANNEL, VARIANCE_PREFIX, SampleDump, buffer_from_awr_part, whole_counts
from .exr import ExrPart, checked_plane, file_error, header_value, read_exr

__all__ = ["PRESETS", "detect_preset", "read_sample_buffer", "read_sample_dump", "parse_plane"]

PRESETS = ("auto", "awr", "pbrt", "cycles", "renderman", "mitsuba", "generic", "deep")
"""Accepted values of ``preset``."""

# Component suffixes in the order they are read; the buffer gets R, G, B names for colour.
_SUFFIX_ORDER = ("R", "G", "B", "A", "r", "g", "b", "a", "X", "Y", "Z", "W", "x", "y", "z", "w")
_COLOUR_NAME = {"R": "R", "G": "G", "B": "B", "r": "R", "g": "G", "b": "B",
                "X": "R", "Y": "G", "Z": "B", "x": "R", "y": "G", "z": "B"}
_ALPHA = {"A", "a", "W", "w"}


@dataclass(frozen=True)
class _Plane:
    """Channels of one logical plane inside one file."""

    path: Path
    channels: tuple[str, ...]
    arrays: tuple[np.ndarray, ...]

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.arrays[0].shape)  # type: ignore[return-value]

    @property
    def label(self) -> str:
        prefix = os.path.commonprefix(list(self.channels)) if len(self.channels) > 1 else self.channels[0]
        return prefix.rstrip(".") or ",".join(self.channels)


class _File:
    """An EXR file's flat channels (all parts merged, first part wins) and headers."""

    def __init__(self, path: Path, parts: list[ExrPart]):
        self.path = path
        self.parts = parts
        self.channels: dict[str, np.ndarray] = {}
        self.header: dict = {}
        for part in parts:
            if part.deep:
                continue
            for name, arr in part.channels.items():
                self.channels.setdefault(name, arr)
            for key, value in part.header.items():
                self.header.setdefault(key, value)

    def plane(self, name: str, *, colour: bool, what: str) -> _Plane:
        """Resolve ``name`` as one channel, or as the prefix of ``name.<suffix>`` channels."""
        if name in ("", "RGB", "rgb") and {"R", "G", "B"} <= set(self.channels):
            names: list[str] = ["R", "G", "B"]
        elif name in self.channels:
            names = [name]
        else:
            members = {c.rsplit(".", 1)[1]: c for c in self.channels
                       if "." in c and c.rsplit(".", 1)[0] == name}
            if colour:
                members = {s: c for s, c in members.items() if s not in _ALPHA} or members
            names = [members[s] for s in _SUFFIX_ORDER if s in members]
            names += sorted(c for s, c in members.items() if s not in _SUFFIX_ORDER)
        if not names:
            found = ", ".join(sorted(self.channels)) or "none"
            raise file_error(self.path, f"no {what} channel(s) named this (channels: {found})", name or "RGB")
        return _Plane(self.path, tuple(names), tuple(self.channels[n] for n in names))




def _open(path: str | os.PathLike[str], opened: dict[Path, _File]) -> _File:
    p = Path(path)
    key = p.resolve() if p.exists() else p
    if key not in opened:
        opened[key] = _File(p, read_exr(p))
    return opened[key]


def parse_plane(spec: str, default_file: str | os.PathLike[str] | None) -> tuple[Path, str]:
    """Split ``file.exr:plane`` into (file, plane); a bare ``plane`` refers to ``default_file``.

    Only the last colon separates, and only when what precedes it names an EXR file, so
    plane names and drive letters keep their colons.
    """
    if ":" in spec:
        file_part, plane = spec.rsplit(":", 1)
        if file_part.lower().endswith(".exr") or Path(file_part).is_file():
            return Path(file_part), plane
    if default_file is None:
        raise ValueError(f"plane {spec!r}: no input file given; write it as file.exr:{spec}")
    return Path(default_file), spec


def detect_preset(channels: Sequence[str], header: dict) -> str:
    """Name of the preset whose channel layout matches, or ``"generic"`` when none does."""
    names = set(channels)
    if str(header.get("awr:semantics", "")) == "sample-statistics" or (
            COUNT_CHANNEL in names and any(n.startswith(VARIANCE_PREFIX) for n in names)):
        return "awr"
    if any(n.startswith("Variance.") for n in names):
        return "pbrt"
    if any(re.fullmatch(r"[^.]+\.Combined\.[RGB]", n) for n in names):
        return "cycles"
    if any(n == "mse" or n.startswith("mse.") for n in names) or any(n.startswith("Ci.") or n == "Ci"
                                                                         for n in names):
        return "renderman"
    if any(n.startswith("m2_") for n in names):
        return "mitsuba"
    return "generic"


def _check_shapes(planes: Sequence[_Plane]) -> None:
    first = planes[0]
    for plane in planes[1:]:
        if plane.shape != first.shape:
            raise file_error(plane.path, f"size {plane.shape[1]}x{plane.shape[0]} does not match "
                                         f"{first.shape[1]}x{first.shape[0]} of {first.path}", plane.label)


def _values(plane: _Plane, *, nonnegative: bool = False) -> FloatArray:
    return np.stack([checked_plane(plane.path, n, a, nonnegative=nonnegative)
                     for n, a in zip(plane.channels, plane.arrays)], axis=-1)


def _channel_names(plane: _Plane) -> tuple[str, ...]:
    suffixes = [c.rsplit(".", 1)[-1] for c in plane.channels]
    if len(suffixes) == 1:
        return ("Y",)
    mapped = [_COLOUR_NAME.get(s, s) for s in suffixes]
    if len(set(mapped)) == len(mapped):
        return tuple(mapped)
    return tuple(plane.channels)


def _spp_counts(path: Path, spp: int | None, shape: tuple[int, int], where: str) -> np.ndarray:
    if spp is None:
        raise file_error(path, f"no sample count in the file ({where}); pass spp= / --spp N")
    if int(spp) < 0:
        raise ValueError(f"spp: must be non-negative, got {spp}")
    return np.full(shape, int(spp), np.int64)


def _header_int(path: Path, header: dict, key: str) -> int | None:
    if key not in header:
        return None
    raw = header_value(header, key)
    try:
        value = int(float(str(raw).strip()))
    except ValueError:
        raise file_error(path, f"header attribute is not a number: {raw!r}", key) from None
    if value < 0:
        raise file_error(path, f"header attribute is negative: {value}", key)
    return value


def _assemble(path: Path, count: np.ndarray, colour: _Plane, spread: _Plane, kind: str,
              known: np.ndarray | None = None) -> SampleBuffer:
    if len(spread.channels) != len(colour.channels):
        raise file_error(spread.path, f"{len(spread.channels)} channel(s) but the colour plane "
                                      f"{colour.label} has {len(colour.channels)}", spread.label)
    mean = _values(colour)
    variance = _values(spread, nonnegative=kind != "second_moment")
    try:
        return SampleBuffer.from_moments(count, mean, variance, variance_kind=kind,
                                         channels=_channel_names(colour), variance_known=known)
    except ValueError as exc:
        raise file_error(path, str(exc)) from None


def _kind(value: str | None, default: str) -> str:
    kind = value or default
    if kind not in VARIANCE_KINDS:
        raise ValueError(f"variance_kind: {kind!r} is not one of {', '.join(VARIANCE_KINDS)}")
    return kind


@dataclass
class _Context:
    """One read: the main file, the options, and the files opened so far (planes may name others)."""

    path: Path
    file: _File
    color: str | None
    variance: str | None
    count: str | None
    variance_kind: str | None
    spp: int | None
    layer: str | None
    opened: dict[Path, _File]

    def plane(self, spec: str, *, colour: bool = False, what: str) -> _Plane:
        file_path, name = parse_plane(spec, self.path)
        return _open(file_path, self.opened).plane(name, colour=colour, what=what)

    def count_plane(self) -> tuple[_Plane, np.ndarray] | None:
        """The ``count=`` plane and its whole counts, if one was given."""
        if self.count is None:
            return None
        counts = self.plane(self.count, what="count")
        if len(counts.channels) != 1:
            raise file_error(counts.path, f"a count plane has one channel, found {len(counts.channels)}",
                             counts.label)
        return counts, whole_counts(counts.path, counts.channels[0], counts.arrays[0])


@dataclass
class _Layout:
    """Where a preset found the statistics."""

    colour: _Plane
    spread: _Plane
    kind: str
    count: np.ndarray
    count_plane: _Plane | None = None
    known: np.ndarray | None = None


def _pbrt(ctx: _Context) -> _Layout:
    colour = ctx.plane(ctx.color or "RGB", colour=True, what="colour")
    spread = ctx.plane(ctx.variance or "Variance", what="variance")
    # pbrt writes 0 where it has no estimate (environment-only pixels): unknown, not converged.
    known = ~(_values(spread, nonnegative=True) == 0).all(axis=-1)
    given = ctx.count_plane()
    if given is not None:
        return _Layout(colour, spread, _kind(ctx.variance_kind, "sample"), given[1], given[0], known)
    n = _header_int(ctx.path, ctx.file.header, "samplesPerPixel")
    if ctx.spp is not None or n is None:
        cnt = _spp_counts(ctx.path, ctx.spp, colour.shape, "no samplesPerPixel header attribute")
    else:
        cnt = np.full(colour.shape, n, np.int64)
    return _Layout(colour, spread, _kind(ctx.variance_kind, "sample"), cnt, None, known)


def _cycles_layer(ctx: _Context) -> str:
    layers = sorted({m.group(1) for c in ctx.file.channels if (m := re.fullmatch(r"([^.]+)\.Combined\.[RGB]", c))})
    if ctx.layer is not None:
        if ctx.layer not in layers:
            raise file_error(ctx.path, f"no such layer (layers with a Combined pass: {', '.join(layers) or 'none'})",
                             f"{ctx.layer}.Combined")
        return ctx.layer
    if len(layers) == 1:
        return layers[0]
    if not layers:
        raise file_error(ctx.path, "no <layer>.Combined.R/G/B channels", "Combined")
    raise file_error(ctx.path, f"ambiguous: several view layers ({', '.join(layers)}); choose one with "
                               "layer= / --layer", "Combined")


def _cycles(ctx: _Context) -> _Layout:
    layer = _cycles_layer(ctx)
    colour = ctx.plane(ctx.color or f"{layer}.Combined", colour=True, what="colour")
    if ctx.variance is None:
        raise file_error(ctx.path, "Blender Cycles writes no variance pass; render one as an AOV and pass it "
                                   "with variance= / --variance PLANE (and --variance-kind)", f"{layer}.Combined")
    spread = ctx.plane(ctx.variance, what="variance")
    kind = _kind(ctx.variance_kind, "sample")
    given = ctx.count_plane()
    if given is not None:
        return _Layout(colour, spread, kind, given[1], given[0])
    samples = _header_int(ctx.path, ctx.file.header, f"cycles.{layer}.samples")
    debug_name = f"{layer}.Debug Sample Count"
    if debug_name not in ctx.file.channels and f"{debug_name}.X" not in ctx.file.channels:
        n = samples if ctx.spp is None else int(ctx.spp)
        cnt = _spp_counts(ctx.path, n, colour.shape, f"no Debug Sample Count pass, no cycles.{layer}.samples")
        return _Layout(colour, spread, kind, cnt)
    counts = ctx.plane(debug_name, what="count")
    if samples is None and ctx.spp is None:
        raise file_error(ctx.path, f"the sample count pass is normalised but the header has no "
                                   f"cycles.{layer}.samples; pass spp= / --spp N", counts.channels[0])
    # Cycles stores count / samples; cycles-merge multiplies back by the header value.
    scale = samples if ctx.spp is None else int(ctx.spp)
    raw = checked_plane(ctx.path, counts.channels[0], counts.arrays[0], nonnegative=True) * scale
    if (np.abs(raw - np.rint(raw)) > 1e-2).any():
        raise file_error(ctx.path, f"normalised counts times {scale} are not whole numbers", counts.channels[0])
    return _Layout(colour, spread, kind, np.rint(raw).astype(np.int64), counts)


def _renderman(ctx: _Context) -> _Layout:
    color = ctx.color
    if color is None:
        color = "Ci" if any(c == "Ci" or c.startswith("Ci.") for c in ctx.file.channels) else "RGB"
    colour = ctx.plane(color, colour=True, what="colour")
    spread = ctx.plane(ctx.variance or "mse", what="variance")
    kind = _kind(ctx.variance_kind, "mean")
    if ctx.count is None and COUNT_CHANNEL in ctx.file.channels:
        ctx.count = COUNT_CHANNEL
    given = ctx.count_plane()
    if given is not None:
        return _Layout(colour, spread, kind, given[1], given[0])
    return _Layout(colour, spread, kind, _spp_counts(ctx.path, ctx.spp, colour.shape, f"no {COUNT_CHANNEL} channel"))


def _mitsuba(ctx: _Context) -> _Layout:
    variance = ctx.variance
    if variance is None:
        m2 = sorted({c.rsplit(".", 1)[0] if "." in c else c for c in ctx.file.channels if c.startswith("m2_")})
        if not m2:
            raise file_error(ctx.path, "no m2_<name> second-moment channels (Mitsuba 3 moment integrator)", "m2_*")
        if len(m2) > 1 and ctx.color is None:
            raise file_error(ctx.path, f"ambiguous: several second moments ({', '.join(m2)}); choose with "
                                       "color=/variance=", "m2_*")
        variance = m2[0]
    colour = ctx.plane(ctx.color or variance[len("m2_"):], colour=True, what="colour")
    spread = ctx.plane(variance, what="second moment")
    if len(spread.channels) > len(colour.channels):  # an alpha moment has no colour counterpart
        k = len(colour.channels)
        spread = _Plane(spread.path, spread.channels[:k], spread.arrays[:k])
    kind = _kind(ctx.variance_kind, "second_moment")
    given = ctx.count_plane()
    if given is not None:
        return _Layout(colour, spread, kind, given[1], given[0])
    cnt = _spp_counts(ctx.path, ctx.spp, colour.shape, "Mitsuba 3 writes no per-pixel sample count")
    return _Layout(colour, spread, kind, cnt)


def _generic(ctx: _Context) -> _Layout:
    colour = ctx.plane(ctx.color or "RGB", colour=True, what="colour")
    if ctx.variance is None:
        raise file_error(ctx.path, "no variance plane given (variance= / --variance PLANE)", colour.label)
    spread = ctx.plane(ctx.variance, what="variance")
    kind = _kind(ctx.variance_kind, "sample")
    given = ctx.count_plane()
    if given is not None:
        return _Layout(colour, spread, kind, given[1], given[0])
    return _Layout(colour, spread, kind, _spp_counts(ctx.path, ctx.spp, colour.shape, "no count= plane"))


_READERS = {"pbrt": _pbrt, "cycles": _cycles, "renderman": _renderman, "mitsuba": _mitsuba,
            "generic": _generic, "awr": _generic}


def read_sample_dump(
    path: str | os.PathLike[str] | None,
    *,
    preset: str = "auto",
    color: str | None = None,
    variance: str | None = None,
    count: str | None = None,
    variance_kind: str | None = None,
    spp: int | None = None,
    layer: str | None = None,
    nonfinite: str = "raise",
) -> SampleDump:
    """Read sample statistics with their bookkeeping (see :func:`read_sample_buffer`).

    Returns
    -------
    SampleDump
        ``.buffer``; ``.issued`` (samples handed out per pixel: the awr layout's
        ``issuedCount``, else the count); ``.attributes`` (the ``awr:*`` header of an awr
        dump, empty for other layouts).
    """
    if preset not in PRESETS:
        raise ValueError(f"preset: {preset!r} is not one of {', '.join(sorted(PRESETS))}")
    if variance_kind is not None:
        _kind(variance_kind, "sample")
    if path is None:
        if color is None:
            raise ValueError("path: give an input file or a color plane as file.exr:plane")
        path = parse_plane(color, None)[0]
    p = Path(path)
    parts = read_exr(p)
    if preset in ("auto", "deep") and parts[0].deep:
        buf = samples_from_deep_part(p, parts[0], nonfinite=nonfinite)
        return SampleDump(buf, buf.count, {})
    if preset == "deep":
        raise file_error(p, "is not a deep EXR")
    f = _File(p, parts)
    if not f.channels:
        raise file_error(p, "has no flat channels")
    if preset == "auto":
        preset = "generic" if color is not None else detect_preset(list(f.channels), f.header)
    if preset == "generic" and color is None and variance is None and count is None:
        raise file_error(p, "cannot detect the layout (channels: " + ", ".join(sorted(f.channels))
                         + "); choose a preset or give color=/variance=/count= (--color/--variance/--count)")
    if preset == "awr" and color is None and variance is None:
        flat = [part for part in parts if not part.deep and COUNT_CHANNEL in part.channels]
        if not flat:
            raise file_error(p, "missing (not in the awr dump layout)", COUNT_CHANNEL)
        return buffer_from_awr_part(p, flat[0], variance_kind=variance_kind)
    ctx = _Context(p, f, color, variance, count, variance_kind, spp, layer, {p.resolve(): f})
    layout = _READERS[preset](ctx)
    planes = [layout.colour, layout.spread] + ([layout.count_plane] if layout.count_plane is not None else [])
    _check_shapes(planes)
    buffer = _assemble(p, layout.count, layout.colour, layout.spread, layout.kind, layout.known)
    return SampleDump(buffer, layout.count, {})


def read_sample_buffer(
    path: str | os.PathLike[str] | None,
    *,
    preset: str = "auto",
    color: str | None = None,
    variance: str | None = None,
    count: str | None = None,
    variance_kind: str | None = None,
    spp: int | None = None,
    layer: str | None = None,
    nonfinite: str = "raise",
) -> SampleBuffer:
    """Read per-pixel sample statistics from an EXR file, channels by name.

    Parameters
    ----------
    path
        The dump (a flat EXR, or a deep EXR with ``awr:semantics = "mc-samples"``).
    preset
        ``"auto"`` (detect from the channel names), ``"awr"``, ``"pbrt"``, ``"cycles"``,
        ``"renderman"``, ``"mitsuba"``, ``"generic"`` or ``"deep"``; see the module table.
    color, variance, count
        Plane overrides, each a channel name, a channel prefix (``Variance`` for
        ``Variance.R/G/B``) or ``file.exr:plane`` to read it from another file. Giving
        ``color`` with ``preset="auto"`` selects the generic mode.
    variance_kind
        ``"sample"``, ``"mean"`` or ``"second_moment"``; overrides the preset's default.
    spp
        Samples per pixel where the file has no count (Mitsuba; also overrides pbrt's and
        Cycles' header value).
    layer
        Cycles view layer when the file has several.
    nonfinite
        Policy for NaN/Inf *samples* of a deep per-sample dump: ``"raise"`` (default),
        ``"drop"`` or ``"zero"``, counted in the buffer's ``nonfinite``. Flat files hold
        statistics, where NaN/Inf is always an error.

    Returns
    -------
    SampleBuffer
        The statistics, variance converted to per-sample variance on entry.

    Raises
    ------
    InputFileError
        Missing, corrupt or non-EXR file; missing or ambiguous channels; size mismatch
        between files; NaN/Inf (half-float overflow named); negative variance or counts.
    """
    return read_sample_dump(path, preset=preset, color=color, variance=variance, count=count,
                            variance_kind=variance_kind, spp=spp, layer=layer, nonfinite=nonfinite).buffer
