"""Reading sample statistics written by other renderers (layout presets and auto-detection).

Each preset says where a renderer puts the pixel mean, its spread and the sample count:

=========  ===========================  ===============================  ==========================================
preset     mean                         spread (variance kind)           count
=========  ===========================  ===============================  ==========================================
awr        ``R,G,B``                    ``variance.*`` (header says)     ``sampleCount`` (FLOAT)
pbrt       ``R,G,B``                    ``Variance.*`` (sample, XYZ)     header ``samplesPerPixel``
cycles     ``<layer>.Noisy Image.*``,   none: give ``variance=`` or      ``<layer>.Debug Sample Count.X`` x the
           else ``<layer>.Combined.*``  merge independent renders        samples rendered (derived from the data)
renderman  ``Ci.*``                     ``mse.*`` (mean)                 ``sampleCount``
mitsuba    ``<name>.X/Y/Z`` (XYZ)       ``m2_<name>.*`` (second_moment)  none: give ``spp=``
generic    ``color=``                   ``variance=``                    ``count=`` or ``spp=``
=========  ===========================  ===============================  ==========================================

pbrt writes a variance of 0 where it has no estimate (pixels that saw only the environment);
such pixels are marked unknown, never "converged". pbrt's ``Variance`` and Mitsuba's moments are
CIE XYZ and are converted to linear sRGB (:mod:`awr_denoise.io.colour`). Channel names are split
on the *last* dot (component); Cycles names are split from the right into layer, pass and
component (:mod:`awr_denoise.io.cycles`), since layer names may hold dots and pass names spaces.
Files with several views (stereo) need ``view=``. What the reader decided is returned in
``SampleDump.notes``; doubtful input is also reported as an
:class:`~awr_denoise.errors.InputFileWarning`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import re
import threading
import warnings
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._typing import FloatArray
from ..buffers import VARIANCE_KINDS, SampleBuffer
from ..errors import InputFileWarning
from ..features import FEATURE_CHANNELS, FEATURE_NAMES, feature_names
from .colour import MITSUBA_XYZ_TO_SRGB, PBRT_XYZ_TO_SRGB, xyz_statistics_to_rgb, xyz_to_rgb
from .cycles import COLOUR_PASSES, COUNT_PASS, cycles_layers, sample_count_scale, split_channel
from .deep import sample_index_bounds, samples_from_deep_part
from .dump import (COUNT_CHANNEL, MAX_EXACT_COUNT, VARIANCE_PREFIX, SampleDump, buffer_from_awr_part,
                   uncounted_means, whole_counts)
from .exr import (ExrPart, check_same_windows, checked_plane, file_error, header_value, header_windows, multi_views,
                  read_exr, thread_list)
from .features import (MITSUBA_AOV_NAMES, albedo_warning, auto_feature_planes, feature_from_planes, normal_warning,
                       plane_present)
from .mitsuba import RAW_FILM, MomentBound, filter_correlation, moment_bound

__all__ = ["PRESETS", "detect_preset", "read_sample_buffer", "read_sample_dump", "read_independent_renders",
           "parse_plane", "plane_file", "feature_plane_file", "file_views"]

PRESETS = ("auto", "awr", "pbrt", "cycles", "renderman", "mitsuba", "generic", "deep")
"""Accepted values of ``preset``."""

# Component suffixes in the order they are read; the buffer gets R, G, B names for colour.
_SUFFIX_ORDER = ("R", "G", "B", "A", "r", "g", "b", "a", "X", "Y", "Z", "W", "x", "y", "z", "w")
_COLOUR_NAME = {"R": "R", "G": "G", "B": "B", "r": "R", "g": "G", "b": "B",
                "X": "R", "Y": "G", "Z": "B", "x": "R", "y": "G", "z": "B"}
_ALPHA = {"A", "a", "W", "w"}
_FEATURE_AOVS = {aov for names in MITSUBA_AOV_NAMES.values() for aov in names}


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


def file_views(parts: Sequence[ExrPart]) -> list[str]:
    """The views of a multi-view file, in file order: parts' ``view`` attributes, then the views of a part that holds
    several (OpenEXR's ``multiView``); [] for none."""
    views: list[str] = []
    for part in parts:
        if "view" in part.header:
            v = str(header_value(part.header, "view"))
            if v not in views:
                views.append(v)
    views += [v for v in multi_views(parts) if v not in views]
    return views


def _in_view(name: str, view: str | None, within: list[str]) -> str | None:
    """Channel ``name`` of a part holding ``within``'s views as it reads in ``view`` (its prefix gone), or None where
    it belongs to another view."""
    if len(within) < 2 or view is None:
        return name
    prefix = name.split(".", 1)[0] if "." in name else None
    if view == within[0]:
        return None if prefix in within[1:] else name
    return name.split(".", 1)[1] if prefix == view else None


def _part_view(part: ExrPart) -> str | None:
    return str(header_value(part.header, "view")) if "view" in part.header else None


class _File:
    """An EXR file's flat channels (all parts of one view merged, first part wins) and headers."""

    def __init__(self, path: Path, parts: list[ExrPart], view: str | None = None):
        self.path = path
        self.parts = parts
        self.channels: dict[str, np.ndarray] = {}
        self.header: dict = {}
        views = file_views(parts)
        if view is not None and view not in views:
            raise file_error(path, f"no view {view!r} (views: {', '.join(views) or 'none, a single-view file'})")
        if view is None and len(views) > 1:
            # Stereo/multiview parts repeat the same channel names: never pick one silently.
            raise file_error(path, f"has several views ({', '.join(views)}); choose one with view= / --view")
        if view is None and views:
            view = views[0]
        self.view = view
        self.used = [part for part in parts if not part.deep and _part_view(part) in (None, view)]
        first_window = header_windows(parts[0].header).get("dataWindow")
        within = multi_views(parts)
        owner: dict[str, int] = {}
        for part in self.used:
            if header_windows(part.header).get("dataWindow") != first_window:
                # Outputs keep the first part's windows: these pixels would be placed elsewhere.
                raise file_error(path, f"part {part.index}'s data window differs from the first part's; "
                                       "read a file whose parts share one window")
            for name, arr in part.channels.items():
                name = _in_view(name, view, within) if "multiView" in part.header else name
                if name is None:
                    continue
                if name in owner:
                    # The first part won, silently: a second render (or a reference) in another part of one file
                    # gave its means, its counts or its variance to the first (an attack pass).
                    raise file_error(path, f"is in several parts ({owner[name]} and {part.index}); read a file "
                                           "whose parts name each channel once", name)
                owner[name] = part.index
                self.channels[name] = arr
        # Every part's attributes count, whatever its view: Cycles puts cycles.<layer>.samples
        # on the first part only.
        for part in parts:
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




def _window_size(windows: dict) -> tuple[int, int] | None:
    if "dataWindow" not in windows:
        return None
    (x0, y0), (x1, y1) = windows["dataWindow"]
    return y1 - y0 + 1, x1 - x0 + 1


def _open(path: str | os.PathLike[str], opened: dict[Path, _File], view: str | None = None) -> _File:
    p = Path(path)
    key = p.resolve() if p.exists() else p
    if key not in opened:
        parts = read_exr(p)
        if all(part.deep for part in parts):  # said "(channels: none)" of it
            raise file_error(p, "a per-sample (deep) dump holds no planes to read from it")
        opened[key] = _File(p, parts, view)
    return opened[key]


def plane_file(spec: str) -> Path | None:
    """The file of ``file.exr:plane``, or None for a bare ``plane`` (of the command's main input).

    Only the last colon separates, and only when what precedes it names an EXR file, so plane
    names and drive letters keep their colons.

    Raises
    ------
    ValueError
        If nothing follows the file's colon (``"$FILE:$PLANE"`` with ``PLANE`` unset): an empty
        plane name is refused, never read as the file's default plane.

    Examples
    --------
    >>> from awr_denoise.io.presets import plane_file
    >>> plane_file("beauty.exr:variance"), plane_file("variance")
    (PosixPath('beauty.exr'), None)
    """
    if ":" in spec:
        file_part, plane = spec.rsplit(":", 1)
        if file_part.lower().endswith(".exr") or Path(file_part).is_file():
            if not plane:
                raise ValueError(f"plane {spec!r}: no plane name after the file's colon; write {file_part}:PLANE")
            return Path(file_part)
    return None


def parse_plane(spec: str, default_file: str | os.PathLike[str] | None) -> tuple[Path, str]:
    """Split ``file.exr:plane`` into (file, plane); a bare ``plane`` refers to ``default_file``
    (:func:`plane_file` says which, and refuses an empty plane name)."""
    file = plane_file(spec)
    if file is not None:
        return file, spec.rsplit(":", 1)[1]
    if default_file is None:
        raise ValueError(f"plane {spec!r}: no input file given; write it as file.exr:{spec}")
    return Path(default_file), spec


def _whole_file(spec: str) -> bool:
    """Whether a feature spec names a whole file: one that exists under the whole name (colons and
    all: ``take:2.exr``), or an EXR name without a colon."""
    return Path(spec).is_file() or (":" not in spec and spec.lower().endswith(".exr"))


def feature_plane_file(spec: str) -> Path | None:
    """The file a feature plane (``albedo=``, ``--alb``) reads: a whole file, ``file.exr:plane``'s file,
    or None for a plane of the main input.

    Examples
    --------
    >>> from awr_denoise.io.presets import feature_plane_file
    >>> feature_plane_file("albedo.exr"), feature_plane_file("beauty.exr:Albedo"), feature_plane_file("Albedo")
    (PosixPath('albedo.exr'), PosixPath('beauty.exr'), None)
    """
    if _whole_file(spec) or os.path.lexists(spec):  # a directory or FIFO: named, refused
        return Path(spec)
    return plane_file(spec)


def detect_preset(channels: Sequence[str], header: dict) -> str:
    """Name of the preset whose channel layout matches, or ``"generic"`` when none does."""
    names = set(channels)
    if str(header.get("awr:semantics", "")) == "sample-statistics" or (
            COUNT_CHANNEL in names and any(n.startswith(VARIANCE_PREFIX) for n in names)):
        return "awr"
    if any(n.startswith("Variance.") for n in names) and not _moment_prefixes(names):  # pbrt writes no m2_*
        return "pbrt"
    if cycles_layers(names):
        return "cycles"
    if any(n == "mse" or n.startswith("mse.") for n in names) or any(n.startswith("Ci.") or n == "Ci"
                                                                         for n in names):
        return "renderman"
    if _moment_prefixes(names):
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
    if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or not 0 <= spp <= MAX_EXACT_COUNT:
        raise ValueError(f"spp: must be a whole number in 0..{MAX_EXACT_COUNT}, got {spp!r}")
    return np.full(shape, int(spp), np.int64)


def _header_int(path: Path, header: dict, key: str) -> int | None:
    if key not in header:
        return None
    raw = header_value(header, key)
    text = str(raw).strip()
    # ASCII only: Python's float() also reads '1_6' and other scripts' digits ('１６', a red-team pass).
    if not re.fullmatch(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?|[+-]?(inf|nan)", text, re.IGNORECASE):
        raise file_error(path, f"header attribute is not a number: {raw!r}", key)
    number = float(text)
    # A render's sample count: whole (16.7 was read as 16, -0.5 as 0) and at least 1 (0 read every
    # pixel as sampleless, discarding the file's values).
    if not np.isfinite(number) or number > MAX_EXACT_COUNT or number != int(number) or number < 1:
        raise file_error(path, f"header attribute {raw!r} is not a sample count (a whole number 1..{MAX_EXACT_COUNT})",
                         key)
    return int(number)


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
    view: str | None = None
    need_variance: bool = True
    need_count: bool = True
    notes: list[str] = field(default_factory=list)
    feature_planes: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def plane(self, spec: str, *, colour: bool = False, what: str) -> _Plane:
        file_path, name = parse_plane(spec, self.path)
        return self.open(file_path).plane(name, colour=colour, what=what)

    def open(self, path: str | os.PathLike[str]) -> _File:
        """Another file a plane names, its pixels checked to line up with the main file's: a plane of
        the same size in another data window would pair its values with other pixels."""
        f = _open(path, self.opened, self.view)
        if f is not self.file:
            ours, theirs = (header_windows(g.parts[0].header) for g in (self.file, f))
            if _window_size(ours) == _window_size(theirs):  # another size is named by channel, later
                check_same_windows(f.path, theirs, self.path, ours)
        return f

    def count_plane(self) -> tuple[_Plane, np.ndarray] | None:
        """The ``count=`` plane and its whole counts, if one was given."""
        if self.count is None:
            return None
        counts = self.plane(self.count, what="count")
        if self.spp is not None:  # it would be ignored: refused, so a wrong belief about the file shows
            raise file_error(counts.path, f"holds per-pixel sample counts; spp={self.spp} / --spp is for files "
                                          "without them", counts.label)
        if len(counts.channels) != 1:
            raise file_error(counts.path, f"a count plane has one channel, found {len(counts.channels)}",
                             counts.label)
        return counts, whole_counts(counts.path, counts.channels[0], counts.arrays[0])

    def spp_counts(self, shape: tuple[int, int], where: str) -> np.ndarray | None:
        """``spp`` everywhere; None when neither it nor a count is needed (a description)."""
        if self.spp is None and not self.need_count:
            self.notes.append(f"no sample count in the file ({where})")
            return None
        return _spp_counts(self.path, self.spp, shape, where)


@dataclass
class _Layout:
    """Where a preset found the statistics, and what the reader must convert."""

    colour: _Plane
    spread: _Plane | None
    kind: str
    count: np.ndarray | None
    count_plane: _Plane | None = None
    known: np.ndarray | None = None
    # (matrix, "mean_and_variance" | "variance"): the file's statistics are CIE XYZ.
    convert: tuple[np.ndarray, str] | None = None


def _in_input(ctx: _Context, plane: _Plane) -> bool:
    """Whether a plane is the input file's own (not ``other.exr:plane``): only there do the
    renderer's conventions (pbrt's XYZ variance, Mitsuba's second moments) hold."""
    if plane.path == ctx.path:
        return True
    try:
        return os.path.samefile(plane.path, ctx.path)  # a link, hard or symbolic, to the input is the input
    except OSError:
        return False


def _pbrt(ctx: _Context) -> _Layout:
    if ctx.color is None and ctx.variance is None and not (
            {"R", "G", "B"} <= set(ctx.file.channels) and any(c.startswith("Variance.") for c in ctx.file.channels)):
        # "RGB: no colour channel(s) named this" named no pbrt channel (a walkthrough).
        raise file_error(ctx.path, "no R,G,B and Variance.* channels (pbrt-v4's GBufferFilm) for the pbrt preset "
                                   f"(channels: {', '.join(sorted(ctx.file.channels))})")
    colour = ctx.plane(ctx.color or "RGB", colour=True, what="colour")
    spread = ctx.plane(ctx.variance or "Variance", what="variance")
    # pbrt writes 0 where it has no estimate (environment-only pixels): unknown, not converged.
    known = ~(_values(spread, nonnegative=True) == 0).all(axis=-1)
    convert = None
    if spread.channels == ("Variance.R", "Variance.G", "Variance.B") and _in_input(ctx, spread):
        # GBufferFilm accumulates Variance on sensor RGB (CIE XYZ for the default sensor) and
        # converts only the means to the output colour space; also when the plane is named.
        convert = (PBRT_XYZ_TO_SRGB, "variance")
        space = "linear sRGB"
        if "chromaticities" in ctx.file.header:
            # Written for any output colour space but sRGB, whose RGB the means are then in: the variance converted
            # to sRGB beside Rec.2020 means, without a word (an attack pass).
            try:
                convert = (xyz_to_rgb(ctx.file.header["chromaticities"]), "variance")
            except (ValueError, TypeError) as exc:
                raise file_error(ctx.path, str(exc).removeprefix("chromaticities: "), "chromaticities") from None
            space = "the linear RGB of its chromaticities"
            if not np.allclose(convert[0], PBRT_XYZ_TO_SRGB, atol=2e-3):
                space += " (primaries other than sRGB's, which the outputs carry)"
        ctx.notes.append(f"Variance holds pbrt's sensor XYZ: converted to {space} (channels taken as fully "
                         "correlated)")
    if not known.all():
        ctx.notes.append(f"{int((~known).sum())} pixel(s) have Variance 0 (no estimate, e.g. only the "
                         "environment seen): variance unknown, borrowed from neighbours of similar mean")
    kind = _kind(ctx.variance_kind, "sample")
    given = ctx.count_plane()
    if given is not None:
        return _Layout(colour, spread, kind, given[1], given[0], known, convert)
    n = _header_int(ctx.path, ctx.file.header, "samplesPerPixel")
    if ctx.spp is not None or n is None:
        cnt = ctx.spp_counts(colour.shape, "no samplesPerPixel header attribute")
    else:
        cnt = np.full(colour.shape, n, np.int64)
    return _Layout(colour, spread, kind, cnt, None, known, convert)


def _colour_layer(ctx: _Context, layers: Iterable[str]) -> str | None:
    """The view layer a ``color=`` plane of the input belongs to (``Second.Combined`` -> ``Second``),
    the longest layer name that prefixes it (layer names may hold dots); None for another file's plane
    or a name in no layer."""
    if ctx.color is None:
        return None
    file_path, name = parse_plane(ctx.color, ctx.path)
    if file_path != ctx.path:
        try:
            if not os.path.samefile(file_path, ctx.path):
                return None
        except OSError:
            return None
    owners = [layer for layer in layers if name.startswith(layer + ".")]
    return max(owners, key=len) if owners else None


def _cycles_layer(ctx: _Context) -> tuple[str, set[str]]:
    layers = cycles_layers(ctx.file.channels)
    owner = _colour_layer(ctx, layers)
    if ctx.layer is None:
        # The colour plane's own layer: its Debug Sample Count and header samples are those of the
        # render the plane came from (a light group's Combined_<group> is in its layer).
        ctx.layer = owner
    elif owner is not None and owner != ctx.layer:
        # Read, one layer's colour was counted by the other's pass and header (a walkthrough).
        raise file_error(ctx.path, f"--color {ctx.color} is a plane of layer {owner}, not of layer={ctx.layer!r} / "
                                   f"--layer {ctx.layer}, whose counts it would be read with; leave --layer out, or "
                                   "name that layer's plane", f"{owner}.Combined")
    if ctx.layer is not None:
        if ctx.layer not in layers:
            raise file_error(ctx.path, f"no such layer (layers with a Combined pass: {', '.join(sorted(layers)) or 'none'})",
                             f"{ctx.layer}.Combined")
        return ctx.layer, layers[ctx.layer]
    if len(layers) == 1:
        return next(iter(layers.items()))
    if not layers:
        raise file_error(ctx.path, "no <layer>.Combined.R/G/B channels", "Combined")
    raise file_error(ctx.path, f"ambiguous: several view layers ({', '.join(sorted(layers))}); choose one with "
                               "layer= / --layer", "Combined")


def _cycles_colour(ctx: _Context, layer: str, passes: set[str]) -> _Plane:
    if ctx.color is not None:
        plane = ctx.plane(ctx.color, colour=True, what="colour")
        if COLOUR_PASSES[0] in passes and _in_input(ctx, plane) and plane.label == f"{layer}.Combined":
            # Read as named, but not as samples without a word: the denoiser's output (a walkthrough).
            ctx.warnings.append(f"{ctx.path}: {plane.label}: the denoiser's output (the layer has a Noisy Image "
                                f"pass, the Monte Carlo mean): its pixels are not means of samples; leave --color "
                                f"out, or name {layer}.{COLOUR_PASSES[0]}")
        return plane
    if COLOUR_PASSES[0] in passes:
        ctx.notes.append("colour: Noisy Image (Combined is the denoiser's output)")
        return ctx.plane(f"{layer}.{COLOUR_PASSES[0]}", colour=True, what="colour")
    if passes & {"Denoising Albedo", "Denoising Normal", "Denoising Depth"}:
        # Blender (5.0) writes Noisy Image whenever its denoiser runs: denoising passes without it
        # are "Denoising Data" stored with the denoiser off, and Combined is the Monte Carlo mean.
        ctx.notes.append("colour: Combined (denoising passes without a Noisy Image pass: the denoiser was off)")
    return ctx.plane(f"{layer}.Combined", colour=True, what="colour")


def _cycles_counts(ctx: _Context, layer: str, shape: tuple[int, int]) -> tuple[np.ndarray | None, _Plane | None]:
    given = ctx.count_plane()
    if given is not None:
        return given[1], given[0]
    requested = _header_int(ctx.path, ctx.file.header, f"cycles.{layer}.samples")
    debug_name = f"{layer}.{COUNT_PASS}"
    if debug_name not in ctx.file.channels and f"{debug_name}.X" not in ctx.file.channels:
        if ctx.spp is None and requested is not None:
            ctx.warnings.append(f"{ctx.path}: {debug_name}: no sample count pass: every pixel is taken to have "
                                f"the {requested} samples requested, wrong if adaptive sampling (Blender's default) "
                                "or a time limit stopped pixels early; enable the Debug Sample Count pass")
        n = requested if ctx.spp is None else int(ctx.spp)
        if n is None:
            return ctx.spp_counts(shape, f"no Debug Sample Count pass, no cycles.{layer}.samples"), None
        return np.full(shape, n, np.int64), None
    counts = ctx.plane(debug_name, what="count")
    values = checked_plane(ctx.path, counts.channels[0], counts.arrays[0], nonnegative=True, whole=True)
    if ctx.spp is not None:
        scale = int(ctx.spp)
        ctx.notes.append(f"sample count pass times spp={scale}")
    else:
        try:
            scale, how = sample_count_scale(values, requested)
        except ValueError as exc:
            raise file_error(ctx.path, f"{exc}; pass spp= / --spp N (the samples the render took)",
                             counts.channels[0]) from None
        if "same count" in how or "a guess" in how:
            # A uniform pass cannot tell how many samples a time limit or early convergence left.
            ctx.warnings.append(f"{ctx.path}: {counts.channels[0]}: {how}")
        else:
            ctx.notes.append(f"sample count pass: {how}")
    raw = values * scale
    # The pass's rounding, relative: float32 (about 6e-8) or HALF (2**-11). 1% let a guessed spp through: the
    # 512 samples asked for in Blender, on a pass of k / 304, gave counts 1.68x too high (a walkthrough).
    rounding = 2.0**-10 if np.asarray(counts.arrays[0]).dtype == np.float16 else 1e-5
    if (np.abs(raw - np.rint(raw)) > rounding * np.maximum(1.0, raw)).any():
        hint = ""
        if ctx.spp is not None:
            with contextlib.suppress(ValueError):
                hint = f" (the pass's own divisor: {sample_count_scale(values, requested)[0]})"
        raise file_error(ctx.path, f"normalised counts times {scale} are not whole numbers{hint}", counts.channels[0])
    return np.rint(raw).astype(np.int64), counts


def _cycles(ctx: _Context) -> _Layout:
    layer, passes = _cycles_layer(ctx)
    colour = _cycles_colour(ctx, layer, passes)
    spread = None
    kind = _kind(ctx.variance_kind, "sample")
    if ctx.variance is not None:
        spread = ctx.plane(ctx.variance, what="variance")
    elif ctx.need_variance:
        raise file_error(ctx.path, "Blender Cycles writes no variance pass: render the frame several times with "
                                   "different seeds and merge them (awr merge --independent), or pass a variance "
                                   "plane with variance= / --variance", colour.label)  # the pass read: Noisy Image too
    count, count_plane = _cycles_counts(ctx, layer, colour.shape)
    if count is not None and count_plane is None:
        _unrendered_black(ctx, layer, count)
    return _Layout(colour, spread, kind, count, count_plane)


def _unrendered_black(ctx: _Context, layer: str, count: np.ndarray) -> None:
    """Warn of pixels whose Combined R, G, B and A are all exactly 0, where no count pass says how many
    samples they took: Blender writes 0 outside a border render that is not cropped, and these
    pixels would count as samples of black (a transparent background, rendered, reads the same)."""
    names = [f"{layer}.Combined.{c}" for c in "RGBA"]
    if not all(n in ctx.file.channels for n in names):
        return
    zero = np.all([np.asarray(ctx.file.channels[n]) == 0 for n in names], axis=0)
    if zero.shape == count.shape and zero.any():
        taken = sorted({int(v) for v in np.unique(count[zero])})
        ctx.warnings.append(f"{ctx.path}: {layer}.Combined: {int(zero.sum())} pixel(s) are 0 in R, G, B and A "
                            "(outside a border render not cropped to it, or a transparent background): counted as "
                            f"{'/'.join(map(str, taken))} samples of black each; enable the Debug Sample Count "
                            "pass (0 where nothing was rendered)")


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
    return _Layout(colour, spread, kind, ctx.spp_counts(colour.shape, f"no {COUNT_CHANNEL} channel"))


def _components(ctx: _Context, prefix: str) -> set[str]:
    return {c.rsplit(".", 1)[1] for c in ctx.file.channels if "." in c and c.rsplit(".", 1)[0] == prefix}


def _moment_prefixes(channels: Iterable[str]) -> list[str]:
    """Mitsuba's second-moment planes: ``m2_<name>``, or ``<layer>.m2_<name>`` when an ``aov``
    integrator holds the ``moment`` one; an AOV nested under one (``m2_<name>.position``) is not."""
    found = set()
    for c in channels:
        prefix = c.rsplit(".", 1)[0] if "." in c else c
        if prefix.rsplit(".", 1)[-1].startswith("m2_"):
            found.add(prefix)
    return sorted(found)


def _moment_mean(prefix: str) -> str:
    """The mean plane of a second-moment plane: ``m2_a`` -> ``a``, ``img.m2_a`` -> ``img.a``,
    ``m2_main.albedo`` (an AOV's moment) -> ``main.albedo``, ``m2_pass.m2_a`` -> ``m2_pass.a``."""
    parts = prefix.split(".")
    # The last such component: a layer may itself be named m2_<...> (m2_pass.m2_a -> m2_pass.a).
    k = next((i for i in reversed(range(len(parts))) if parts[i].startswith("m2_")), None)
    if k is None:
        return prefix
    parts[k] = parts[k][len("m2_"):]
    return ".".join(parts)


def _moment_of(ctx: _Context, colour: str) -> str:
    """The second-moment plane of a named mean plane: ``m2_<colour>``, else ``<layer>.m2_<name>``."""
    if any(c == "m2_" + colour or c.startswith(f"m2_{colour}.") for c in ctx.file.channels) or "." not in colour:
        return "m2_" + colour
    head, _, last = colour.rpartition(".")
    return f"{head}.m2_{last}"


def _mono(colour: _Plane, spread: _Plane) -> bool:
    """X, Y and Z equal everywhere (and not all zero): a ``mono`` variant's luminance, not a colour."""
    if len(colour.arrays) < 3 or len(spread.arrays) < 3:  # a user's one-channel variance: not a mono triple
        return False
    planes = [np.asarray(a) for a in colour.arrays[:3] + spread.arrays[:3]]
    return (all(np.array_equal(planes[0], a) for a in planes[1:3]) and
            all(np.array_equal(planes[3], a) for a in planes[4:6]) and bool(np.any(planes[0])))


def _mitsuba_moment(ctx: _Context) -> str:
    """The second-moment plane to read: the named colour's, else the moment integrator's own."""
    m2 = _moment_prefixes(ctx.file.channels)
    if not m2:
        raise file_error(ctx.path, "no m2_<name> second-moment channels (Mitsuba 3 moment integrator)", "m2_*")
    if ctx.color is not None:
        if ctx.color.rpartition(".")[2].startswith("m2_"):  # its moment was looked up as m2_m2_... (a walkthrough)
            head, dot, last = ctx.color.rpartition(".")
            raise file_error(ctx.path, "a second moment, named as the colour; give its mean plane "
                                       f"({head}{dot}{last[3:]})", ctx.color)
        return _moment_of(ctx, ctx.color)
    # The moment integrator's own results are <name>.X/Y/Z; RGB moments are AOVs.
    # A normal AOV has X, Y, Z components too: feature AOVs are not the radiance.
    xyz = [p for p in m2 if {"X", "Y", "Z"} <= _components(ctx, p)
           and _moment_mean(p).rsplit(".", 1)[-1] not in _FEATURE_AOVS]
    if len(xyz) > 1:
        raise file_error(ctx.path, f"ambiguous: several second moments ({', '.join(xyz)}); choose one "
                                   "with color= / --color NAME (the plane without m2_)", "m2_*")
    return (xyz or m2)[0]


def _mitsuba(ctx: _Context) -> _Layout:
    if "W" in ctx.file.channels:  # its "moments" are sums: m2 below m1^2, refused before as the wrong variance kind
        raise file_error(ctx.path, RAW_FILM, "W")
    # A variance plane of the user's own (not one of the input's m2_* moments) is read as a
    # per-sample variance, in the preset, so its sample count and features are kept.
    spread = None if ctx.variance is None else ctx.plane(ctx.variance, what="variance")
    moments = spread is None or (_in_input(ctx, spread) and
                                 any(p.startswith("m2_") for p in spread.channels[0].split(".")))
    if moments:
        variance = ctx.variance or _mitsuba_moment(ctx)
        # A moment named with its file (input.exr:m2_a) has its mean in the input, by plane name.
        colour = ctx.plane(ctx.color or _moment_mean(parse_plane(variance, ctx.path)[1]), colour=True,
                           what="colour")
        spread = ctx.plane(variance, what="second moment")
    else:
        colour = ctx.plane(ctx.color or _moment_mean(_mitsuba_moment(ctx)), colour=True, what="colour")
    assert spread is not None
    if len(spread.channels) > len(colour.channels):  # an alpha moment has no colour counterpart
        keep = [i for i, c in enumerate(spread.channels) if c.rsplit(".", 1)[-1] not in _ALPHA]
        spread = _Plane(spread.path, tuple(spread.channels[i] for i in keep), tuple(spread.arrays[i] for i in keep))
    if len(spread.channels) != len(colour.channels):
        raise file_error(spread.path, f"{len(spread.channels)} variance channel(s) ({', '.join(spread.channels)}) "
                                      f"for the {len(colour.channels)} of the colour {colour.label}", spread.label)
    negative = (_values(spread) < 0).any(axis=-1)
    if moments and negative.any():  # E[x^2] of samples is never negative: the film's filter weighted some so
        # A lossy codec's error makes them so too: the filter was named where the file was box-filtered and
        # compressed with DWAA (an attack pass).
        filters = "the film's reconstruction filter has negative lobes (mitchell, catmullrom, lanczos)"
        codecs = ", ".join(_lossy_codecs(ctx.file.used))
        cause = (f"a lossy compression ({codecs}) changed them, or {filters}; write the moments losslessly (ZIP, PIZ) "
                 "with rfilter box") if codecs else f"{filters}; render the moments with rfilter box"
        raise file_error(spread.path, f"{int(negative.sum())} pixel(s) hold a negative second moment: {cause}",
                         spread.label)
    convert = None
    suffixes = tuple(c.rsplit(".", 1)[-1] for c in colour.channels)
    if suffixes == ("X", "Y", "Z") and _mono(colour, spread):
        colour, spread = (_Plane(q.path, q.channels[1:2], q.arrays[1:2]) for q in (colour, spread))
        ctx.notes.append(f"{colour.label}: X, Y and Z are equal everywhere, a mono render's luminance: read as "
                         "one channel Y")
    elif suffixes == ("X", "Y", "Z") and not moments and tuple(c.rsplit(".", 1)[-1] for c in spread.channels) \
            != suffixes:
        raise file_error(spread.path, f"{colour.label} is CIE XYZ and this variance is not (channels "
                                      f"{', '.join(spread.channels)}): name a variance in X, Y, Z, or an RGB "
                                      "colour plane", spread.label)
    elif suffixes == ("X", "Y", "Z"):
        exact = None if ctx.color is not None or ctx.variance is not None else _mitsuba_rgb_twin(ctx, colour)
        if exact is not None:
            colour, spread = exact
            ctx.notes.append(f"colour: {colour.label}, an RGB AOV holding the same samples as the XYZ moments: "
                             "its own second moments give exact RGB variances")
        else:
            convert = (MITSUBA_XYZ_TO_SRGB, "mean_and_variance")
            ctx.notes.append(f"{colour.label} {'moments' if moments else 'and its variance'} are CIE XYZ: "
                             "converted to linear sRGB (channels taken as fully correlated)")
    kind = _kind(ctx.variance_kind, "second_moment" if moments else "sample")
    given = ctx.count_plane()
    if given is not None:
        return _Layout(colour, spread, kind, given[1], given[0], convert=convert)
    cnt = ctx.spp_counts(colour.shape, "Mitsuba 3 writes no per-pixel sample count; give the samples it took per "
                                       "pixel: the sampler's sample_count, rounded up by stratified, multijitter, "
                                       "orthogonal and ldsampler")
    return _Layout(colour, spread, kind, cnt, convert=convert)


def _mitsuba_rgb_twin(ctx: _Context, xyz: _Plane) -> tuple[_Plane, _Plane] | None:
    """An RGB moment pair whose mean is the XYZ mean in sRGB: the same samples (an ``aov``
    integrator's nested image inside ``moment``), whose moments need no colour conversion."""
    target = _values(xyz) @ MITSUBA_XYZ_TO_SRGB.T
    scale = max(float(np.abs(target).max()), 1e-6)
    aov_moments = {c.rsplit(".", 1)[0] for c in ctx.file.channels if c.startswith("m2_") and "." in c}
    for prefix in sorted(aov_moments):
        name = prefix[len("m2_"):]
        if not {"R", "G", "B"} <= _components(ctx, name) or not {"R", "G", "B"} <= _components(ctx, prefix):
            continue
        colour = ctx.plane(name, colour=True, what="colour")
        if colour.shape != xyz.shape or len(colour.channels) != 3:
            continue
        if np.abs(_values(colour) - target).max() <= 1e-4 * scale:
            spread = ctx.plane(prefix, what="second moment")
            return colour, _Plane(spread.path, spread.channels[:3], spread.arrays[:3])
    return None


def _generic(ctx: _Context) -> _Layout:
    colour = ctx.plane(ctx.color or "RGB", colour=True, what="colour")
    spread = None
    if ctx.variance is not None:
        spread = ctx.plane(ctx.variance, what="variance")
    elif ctx.need_variance:
        raise file_error(ctx.path, "no variance plane given (variance= / --variance PLANE)", colour.label)
    kind = _kind(ctx.variance_kind, "sample")
    given = ctx.count_plane()
    if given is not None:
        return _Layout(colour, spread, kind, given[1], given[0])
    passes = sorted(c for c in ctx.file.channels if getattr(split_channel(c), "pass_name", None) == COUNT_PASS)
    if passes:
        # Blender's per-pixel counts (normalised) are in the file: spp everywhere would override the
        # counts adaptive sampling left, and "no sample count in the file" would be false.
        raise file_error(ctx.path, "holds Blender Cycles' per-pixel sample count; the generic layout does not read "
                                   "it, and spp= / --spp would override it: read the file with preset='cycles' / "
                                   "--preset cycles", passes[0])
    return _Layout(colour, spread, kind, ctx.spp_counts(colour.shape, "no count= plane"))


_READERS = {"pbrt": _pbrt, "cycles": _cycles, "renderman": _renderman, "mitsuba": _mitsuba,
            "generic": _generic, "awr": _generic}


def _is_half(plane: _Plane) -> bool:
    return any(np.asarray(a).dtype == np.float16 for a in plane.arrays)


def _half_moments(mean: FloatArray, second: FloatArray, plane: _Plane) -> FloatArray:
    """Second moments stored as HALF, short of the squared mean by no more than a half's rounding of
    both (2**-9 of the square bounds the two relative roundings; 2**-24 is the step below the
    normal range): the square (no spread), not a refusal.

    A dim pixel's ``E[x^2]`` underflows to 0 or a subnormal while its mean still holds digits.
    """
    if not _is_half(plane):
        return second
    square = mean**2
    return np.where((second < square) & (square - second <= 2.0**-9 * square + 2.0**-24), square, second)


def _moment_bound(layout: _Layout) -> MomentBound | None:
    """:func:`~awr_denoise.io.mitsuba.moment_bound` of a layout's radiance moments as stored (before any XYZ
    conversion: X, Y and Z of non-negative radiance are non-negative too); None for a variance plane."""
    colour, spread = layout.colour, layout.spread
    if layout.kind != "second_moment" or spread is None or layout.count is None:
        return None
    if len(spread.channels) == len(colour.channels) + 1:  # an alpha moment: no colour counterpart
        spread = _Plane(spread.path, spread.channels[:-1], spread.arrays[:-1])
    smallest = 2.0**-14 if _is_half(colour) or _is_half(spread) else float(np.finfo(np.float32).tiny)
    return moment_bound(layout.count, _values(colour), _values(spread), smallest=smallest)


def _shared_samples(path: Path, label: str, buffer: SampleBuffer) -> str | None:
    """The warning for neighbouring pixels whose means are correlated, or None
    (:func:`~awr_denoise.io.mitsuba.filter_correlation`): a pbrt-v4 file resized or blurred by a tool after the
    render keeps its whole sample count and plausible variances, and was denoised as independent pixels without a
    word (an attack pass). Mitsuba's reader says it with its own advice. Not on the project's dumps, whose means
    callers also build by hand (constant means beside a nominal variance would warn), nor on a variance plane of
    the user's own."""
    check = filter_correlation(buffer)
    return f"{path}: {label}: {check.shared}" if check is not None and check.correlated else None


def _assemble(path: Path, layout: _Layout, warnings: list[str] | None = None) -> SampleBuffer:
    colour, spread, kind = layout.colour, layout.spread, layout.kind
    assert spread is not None and layout.count is not None
    if len(spread.channels) == len(colour.channels) + 1 and spread.channels[-1].rsplit(".", 1)[-1] in _ALPHA:
        spread = _Plane(spread.path, spread.channels[:-1], spread.arrays[:-1])  # an RGBA plane: no alpha
    if len(spread.channels) != len(colour.channels):
        raise file_error(spread.path, f"{len(spread.channels)} channel(s) but the colour plane "
                                      f"{colour.label} has {len(colour.channels)}", spread.label)
    mean = _values(colour)
    variance = _values(spread, nonnegative=kind != "second_moment")
    known = layout.known
    if warnings is not None and spread.path == colour.path and spread.channels == colour.channels:
        # Accepted (a file read only for its features or counts), but not as a spread without a word (a walkthrough).
        warnings.append(f"{path}: {spread.label}: the variance plane is the colour plane itself: its values are "
                        "taken as the noise; give a real variance (Cycles: awr merge --independent)")
    stray = uncounted_means(path, None if layout.count_plane is None else layout.count_plane.label, layout.count,
                            mean)
    if stray is not None and warnings is not None:
        warnings.append(stray)
    if kind == "second_moment" and _is_half(spread):
        lost = ((variance == 0) & (mean != 0)).any(axis=-1)  # E[x^2] underflowed: no spread left to read
        variance = _half_moments(mean, variance, spread)
        if lost.any():
            known = ~lost if known is None else known & ~lost
            if warnings is not None:
                warnings.append(f"{spread.path}: {spread.label}: {int(lost.sum())} pixel(s) hold a second moment "
                                "that underflowed HALF (0 beside a nonzero mean): variance unknown, borrowed from "
                                "neighbours; write FLOAT channels (Mitsuba: component_format float32)")
    try:
        buffer = SampleBuffer.from_moments(layout.count, mean, variance, variance_kind=kind,
                                           channels=_channel_names(colour), variance_known=known)
    except ValueError as exc:
        raise file_error(path, str(exc)) from None
    if layout.convert is None:
        return buffer
    matrix, what = layout.convert
    new_mean, new_var = xyz_statistics_to_rgb(buffer.mean if what == "mean_and_variance" else None,
                                              buffer.variance, matrix)
    return SampleBuffer(buffer.count, buffer.mean if new_mean is None else new_mean, new_var,
                        ("R", "G", "B"), buffer.variance_known)


def _layout(path: Path, f: _File, preset: str, *, color: str | None, variance: str | None, count: str | None,
            variance_kind: str | None, spp: int | None, layer: str | None, view: str | None,
            need_variance: bool, need_count: bool) -> tuple[_Layout, _Context]:
    ctx = _Context(path, f, color, variance, count, variance_kind, spp, layer, {path.resolve(): f}, view,
                   need_variance, need_count)
    layout = _READERS[preset](ctx)
    planes = [layout.colour] + [q for q in (layout.spread, layout.count_plane) if q is not None]
    _check_shapes(planes)
    return layout, ctx


def _check_layer(p: Path, preset: str, layer: str | None) -> None:
    """Refuse ``layer=`` on a file without view layers: ignored, it would read another plane than asked."""
    if layer is not None and preset != "cycles":
        raise file_error(p, f"layer={layer!r} / --layer: only Blender Cycles files have view layers; this file "
                            f"reads as the {preset} layout")


# The command line's name of each reader argument, for messages that name both.
_OPTION = {"color": "--color", "variance": "--variance", "count": "--count", "variance_kind": "--variance-kind",
           "spp": "--spp", "view": "--view", "albedo": "--alb", "normal": "--nrm", "depth": "--depth",
           "features": "--guide features", "nonfinite": "--nonfinite"}


def _refuse_unused(p: Path, why: str, **given: Any) -> None:
    """Refuse every argument given that this file's layout would ignore: read as asked, or not at all."""
    for name, value in given.items():
        if value is not None:
            raise file_error(p, f"{name}= / {_OPTION[name]} would be ignored: {why}")


def _resolve_preset(p: Path, f: _File, preset: str, color: str | None, variance: str | None,
                    count: str | None, *, independent: bool = False) -> str:
    """The preset a file is read with: ``preset``, or the detected one for ``"auto"``; a file no preset reads is
    refused with what to name (``independent``: a render's colour alone, for :func:`read_independent_renders`)."""
    given = preset
    if preset == "auto":
        preset = detect_preset(list(f.channels), f.header)
        # A plane named in a pbrt or Mitsuba file keeps the preset: read generically, pbrt's XYZ
        # variance and Mitsuba's XYZ second moments passed for sRGB variances, without a word.
        # A variance plane of the user's own is read as such inside the preset (which keeps its
        # sample count and features): see _pbrt and _mitsuba. A Cycles file keeps its preset too:
        # read generically, a light group's pass of an adaptive render lost the layer's Debug
        # Sample Count, and the --spp asked for then overrode Blender's per-pixel counts.
        if color is not None and preset not in ("pbrt", "mitsuba", "cycles"):
            preset = "generic"
    if preset == "generic" and color is None and variance is None and count is None:
        if str(f.header.get("awr:semantics", "")) == "sample-request" or {"counts", "first_index"} <= set(f.channels):
            raise file_error(p, "is a request map (awr plan's output: the samples to render), not samples; render "
                                "it and give the renderer's batch")
        listed = ", ".join(sorted(f.channels))
        if COUNT_CHANNEL not in f.channels and any(n.startswith(VARIANCE_PREFIX) for n in f.channels):
            # An awr batch that left its counts out: the missing channel named, the generic reading beside it.
            raise file_error(p, f"has {VARIANCE_PREFIX}* channels, the awr layout's, but no {COUNT_CHANNEL} channel "
                                f"(channels: {listed}): write each pixel's number of samples there, or name the planes "
                                "(color=/variance= with count= or spp=; --color/--variance with --count or --spp)")
        if independent:  # a render's colour is all these need: the spread is the renders', the count given
            example = ": RGB for its R,G,B channels" if {"R", "G", "B"} <= set(f.channels) else ""
            raise file_error(p, f"cannot detect the layout (channels: {listed}): name the render's colour plane "
                                f"(color=, --color{example})")
        plain = {c.rsplit(".", 1)[-1] for c in f.channels} <= {"R", "G", "B", "A", "Y"}
        hint = (": an image of colours only, no spread or count to denoise from (pbrt-v4's rgb film writes none: "
                "render with its gbuffer film; Mitsuba 3: the moment integrator)" if plain else "")
        # The generic preset asked for by name reads only the planes named: choosing it again is no advice.
        what = "the generic preset reads the planes named: give" if given == "generic" else "choose a preset or give"
        raise file_error(p, f"cannot detect the layout (channels: {listed}){hint}; {what} "
                            "color=/variance=/count= (--color/--variance/--count)")
    return preset


def _generic_reading(ctx: _Context, preset: str, layout: _Layout) -> list[str]:
    """A warning where the generic layout reads a pbrt or Mitsuba file's own spread: pbrt-v4's ``Variance`` and
    Mitsuba's ``m2_*`` second moments are CIE XYZ (Mitsuba's colour too), read generically as they are named."""
    found = detect_preset(list(ctx.file.channels), ctx.file.header) if preset == "generic" else None
    spread = layout.spread
    if found not in ("pbrt", "mitsuba") or spread is None or not _in_input(ctx, spread):
        return []
    label = spread.label
    if found == "pbrt" and label.split(".")[0] == "Variance":
        return [f"{ctx.path}: {label} is pbrt-v4's variance in CIE XYZ; the generic layout reads it as the colour's "
                "own, unconverted; --preset auto (or pbrt) converts it"]
    if found == "mitsuba" and label.startswith("m2_"):
        return [f"{ctx.path}: {label} is a Mitsuba 3 moment integrator's second moment E[x^2] in CIE XYZ, like its "
                "colour; the generic layout reads both as named and unconverted (the moment as a variance unless "
                "--variance-kind second_moment); --preset auto (or mitsuba) converts them"]
    return []


def _feature_plane(ctx: _Context, spec: str, name: str) -> _Plane:
    """A feature plane given by the user: ``file.exr:plane``, a plane of the input, or a whole file.

    A whole file (``--alb albedo.exr``, as oidnDenoise takes it) gives its ``R,G,B`` (or
    ``X,Y,Z``) for albedo and normal, its ``Z`` (or only channel) for depth.
    """
    if not isinstance(spec, str) or not spec:
        raise ValueError(f"{name}: expected a plane or a file, got {spec!r}")
    if not _whole_file(spec):
        return ctx.plane(spec, what=name)
    f = ctx.open(spec)
    if f is ctx.file:  # its R,G,B are the radiance: taken for an albedo without a word
        option = {"albedo": "alb", "normal": "nrm"}.get(name, name)
        raise file_error(f.path, f"is the input itself: name its {name} plane ({name}='{spec}:PLANE', --{option} "
                                 f"'{spec}:PLANE'), or leave {name}= out where the preset finds it")
    width = len(FEATURE_CHANNELS[name])
    for names in ((("R", "G", "B"), ("X", "Y", "Z")) if width == 3 else (("Z",), ("Y",))):
        if set(names) <= set(f.channels):
            return _Plane(f.path, names, tuple(f.channels[c] for c in names))
    flat = [c for c in f.channels if c not in _ALPHA]
    if width == 1 and len(flat) == 1:
        return _Plane(f.path, (flat[0],), (f.channels[flat[0]],))
    raise file_error(f.path, f"no {name} channels ({'R,G,B or X,Y,Z' if width == 3 else 'Z or a single channel'}; "
                             f"channels: {', '.join(sorted(f.channels))}); name the plane as file.exr:plane")


def _features(ctx: _Context, preset: str, layout: _Layout, count: np.ndarray, planes: dict[str, str | None],
              wanted: str | Sequence[str] | None) -> dict[str, SampleBuffer]:
    """The feature buffers of one read: planes given by the user, then those the preset knows."""
    required = () if wanted in (None, "auto") else feature_names(wanted)  # type: ignore[arg-type]
    found: dict[str, tuple[str, str | None]] = {}
    if wanted is not None:
        layer = _cycles_layer(ctx)[0] if preset == "cycles" else None
        colour = layout.colour.label
        if len(layout.colour.channels) == 1 and "." in colour:  # one component (a mono render's Y): not a plane
            colour = colour.rsplit(".", 1)[0]
        found = auto_feature_planes(preset, ctx.file.channels, layer=layer, colour=colour)
    features = {}
    for name in FEATURE_NAMES:
        spec, moment = planes.get(name), None
        if spec is not None:
            plane = _feature_plane(ctx, spec, name)
            beside = f"m2_{plane.label}"  # a Mitsuba AOV's moment, beside the plane named
            if preset == "mitsuba" and _in_input(ctx, plane) and plane_present(beside, ctx.file.channels, name):
                moment = ctx.plane(beside, what=f"{name} second moment")
        elif name in found:
            plane = ctx.plane(found[name][0], what=name)
            if found[name][1] is not None:
                moment = ctx.plane(found[name][1], what=f"{name} second moment")
        elif name in required:
            raise file_error(ctx.path, f"no {name} plane known to the {preset} preset; name one "
                                       f"({name}= / --{'alb' if name == 'albedo' else 'nrm' if name == 'normal' else name})",
                             name)
        else:
            continue
        width = len(FEATURE_CHANNELS[name])
        keep = [c.rsplit(".", 1)[-1] not in _ALPHA for c in plane.channels]
        if sum(keep) == width:  # an RGBA albedo: alpha left out
            plane = _Plane(plane.path, *(tuple(x for x, k in zip(xs, keep) if k) for xs in (plane.channels, plane.arrays)))
        _check_shapes([layout.colour, plane] + ([moment] if moment else []))
        mean = _values(plane)
        second = None
        if moment is not None:
            moment = _Plane(moment.path, moment.channels[:width], moment.arrays[:width])
            second = _half_moments(mean, _values(moment), moment)
        features[name] = feature_from_planes(plane.path, name, plane.label, mean, count, second)
        check = {"normal": normal_warning, "albedo": albedo_warning}.get(name)
        if check is not None and (warned := check(plane.path, plane.label, mean)):
            ctx.warnings.append(warned)
        ctx.feature_planes[name] = plane.label if plane.path == ctx.path else f"{plane.path}:{plane.label}"
        ctx.notes.append(f"{name}: {plane.label}" + (f" (variance from {moment.label})" if moment else
                                                     " (no variance in the file)" if spec is None else
                                                     " (given as a plane: its values, no variance)"))
    return features


# OpenEXR's lossy compressions (PXR24 rounds float32 to 24 bits; B44 and DWA are lossy for half, DWA by channel name
# for float too): statistics read back are not those written.
_LOSSY = ("PXR24_COMPRESSION", "B44_COMPRESSION", "B44A_COMPRESSION", "DWAA_COMPRESSION", "DWAB_COMPRESSION")


def _lossy_codecs(parts: Sequence[ExrPart]) -> list[str]:
    """The lossy compressions among ``parts`` (``"DWAA"``, ...), sorted."""
    names = {getattr(part.header.get("compression"), "name", "") for part in parts}
    return [name.removesuffix("_COMPRESSION") for name in sorted(names) if name in _LOSSY]


def _lossy(p: Path, parts: Sequence[ExrPart]) -> list[str]:
    """A warning per lossy compression among ``parts`` (the statistics were accepted without a word)."""
    return [f"{p}: {codec} compression is lossy: the means and variances read are not those the renderer computed; "
            "write sample dumps losslessly (ZIP, PIZ)" for codec in _lossy_codecs(parts)]


_COLLECTED = threading.local()  # .items: this thread's list while warnings_collected() runs, else absent


@contextlib.contextmanager
def warnings_collected() -> Iterator[list[str]]:
    """Within the block, the readers' warnings of this thread go into the list yielded instead of :mod:`warnings`.

    ``warnings.catch_warnings(record=True)`` replaces every thread's filters while it runs: a file's description
    made so recorded another thread's warnings as the file's, and they were lost to that thread (an attack pass).
    """
    with thread_list(_COLLECTED) as found:
        yield found


def _warn(messages: Sequence[str]) -> None:
    found = getattr(_COLLECTED, "items", None)
    for message in messages:
        if found is not None:
            found.append(message)
        else:
            warnings.warn(message, InputFileWarning, stacklevel=3)


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
    view: str | None = None,
    nonfinite: str = "raise",
    albedo: str | None = None,
    normal: str | None = None,
    depth: str | None = None,
    features: str | Sequence[str] | None = "auto",
) -> SampleDump:
    """Read sample statistics with their bookkeeping (see :func:`read_sample_buffer`).

    Returns
    -------
    SampleDump
        ``.buffer``; ``.issued`` (samples handed out per pixel: the awr layout's
        ``issuedCount``, else the count); ``.attributes`` (the ``awr:*`` header of an awr
        dump, empty for other layouts); ``.notes`` (what was decided about the file).
    """
    if preset not in PRESETS:
        raise ValueError(f"preset: {preset!r} is not one of {', '.join(sorted(PRESETS))}")
    for name, plane in (("color", color), ("variance", variance), ("count", count)):
        if plane is not None and not isinstance(plane, str):  # a set or a list of names: one plane is one name
            raise TypeError(f"{name}: expected a plane name or file.exr:plane, got {type(plane).__name__}")
    if variance_kind is not None:
        _kind(variance_kind, "sample")
    if spp is not None:
        _spp_counts(Path("."), spp, (1, 1), "")  # validates spp before any file is read
    if path is None:
        if color is None:
            raise ValueError("path: give an input file or a color plane as file.exr:plane")
        path = parse_plane(color, None)[0]
    p = Path(path)
    parts = read_exr(p)
    if preset in ("auto", "deep") and parts[0].deep:
        _check_layer(p, "deep", layer)
        _refuse_unused(p, "a deep dump's samples carry their own layout", color=color, variance=variance,
                       count=count, variance_kind=variance_kind, spp=spp, view=view, albedo=albedo, normal=normal,
                       depth=depth, features=None if features in (None, "auto") else features)
        buf = samples_from_deep_part(p, parts[0], nonfinite=nonfinite)
        return SampleDump(buf, buf.count, {}, index_bounds=sample_index_bounds(p, parts[0]))
    if preset == "deep":
        raise file_error(p, "is not a deep EXR")
    # A policy for samples, on a file of statistics: accepted without a word, it did nothing, and a NaN
    # mean was then refused as if the policy had not been asked for (a red-team pass).
    _refuse_unused(p, "a flat file holds statistics, where NaN or Inf is always an error; the policy is for a "
                   "deep dump's samples", nonfinite=None if nonfinite == "raise" else nonfinite)
    f = _File(p, parts, view)
    _warn(_lossy(p, f.used))
    if not f.channels:
        raise file_error(p, "has no flat channels")
    preset = _resolve_preset(p, f, preset, color, variance, count)
    _check_layer(p, preset, layer)
    planes = {"albedo": albedo, "normal": normal, "depth": depth}
    if preset == "awr" and color is None and variance is None:
        _refuse_unused(p, f"an awr dump counts its samples in {COUNT_CHANNEL}", count=count)
        flat = [part for part in f.used if COUNT_CHANNEL in part.channels]  # of the view asked for
        if not flat:
            raise file_error(p, "missing (not in the awr dump layout)", COUNT_CHANNEL)
        if len(flat) > 1:  # never pick one silently
            raise file_error(p, f"{len(flat)} parts hold samples; give a file with one", COUNT_CHANNEL)
        if len(views := multi_views(flat)) > 1:  # read from the part: the first view's, whatever --view said
            raise file_error(p, f"holds views {', '.join(views)} in one part (multiView), which an awr dump never "
                                "does; give one view's dump", COUNT_CHANNEL)
        elsewhere = sorted({c for part in f.used if part is not flat[0] for c in part.channels
                            if c.startswith(VARIANCE_PREFIX) and c not in flat[0].channels})
        if elsewhere:  # a pipeline tool split the dump: "variance.R: missing" named the wrong cause (an attack pass)
            raise file_error(p, f"in another part than {COUNT_CHANNEL}: an awr dump keeps its channels in one part; "
                                "merge the parts into one", elsewhere[0])
        if spp is not None:
            raise file_error(p, f"holds per-pixel sample counts; spp={spp} / --spp is for files without them",
                             COUNT_CHANNEL)
        dump = buffer_from_awr_part(p, flat[0], variance_kind=variance_kind)
        _warn(dump.notes)  # its warnings only (a mean where nothing was counted)
        if not any(planes.values()) and features == "auto":
            return dump
        layout, ctx = _layout(p, f, "generic", color="RGB", variance=None, count=None, variance_kind=None,
                              spp=None, layer=None, view=view, need_variance=False, need_count=False)
        del ctx.notes[:]  # what the stand-in layout found (no count plane) says nothing of the dump or its features
        given = _features(ctx, "awr", layout, dump.buffer.count, planes, None)
        kept = dict(dump.buffer.features) if features is not None else {}
        missing = [n for n in (() if features in (None, "auto") else feature_names(features)) if n not in kept]
        if missing and not set(missing) <= set(given):
            raise file_error(p, f"the dump holds no {missing[0]} feature", missing[0])
        buffer = dataclasses.replace(dump.buffer, features=kept | given)
        # The dump's own features by their layout's names ("albedo"), those given by their planes.
        planes_read = {name: name for name in kept if name not in given} | ctx.feature_planes
        return dataclasses.replace(dump, buffer=buffer, notes=dump.notes + tuple(ctx.notes), feature_planes=planes_read)
    layout, ctx = _layout(p, f, preset, color=color, variance=variance, count=count, variance_kind=variance_kind,
                          spp=spp, layer=layer, view=view, need_variance=True, need_count=True)
    ctx.warnings[:0] = _generic_reading(ctx, preset, layout)
    buffer = _assemble(p, layout, ctx.warnings)
    found = _features(ctx, preset, layout, buffer.count, planes, features)
    if found:
        buffer = dataclasses.replace(buffer, features=found)
    if preset == "pbrt" and variance is None:  # the renderer's own variance, not a plane of the user's
        shared = _shared_samples(p, layout.colour.label, buffer)
        if shared is not None:
            ctx.warnings.append(shared)
    if preset == "mitsuba":
        # The moments' bound is a proof (unequal weights, or more samples than counted), refused; the neighbours'
        # correlation a measurement, warned about: it is all that is left where the bound holds.
        bound = _moment_bound(layout)
        if bound is not None and bound.exceeded:
            assert layout.spread is not None
            raise file_error(layout.spread.path, bound.message, layout.spread.label)
        ratio = filter_correlation(buffer)
        if ratio is not None and ratio.correlated:
            ctx.warnings.append(f"{p}: {layout.colour.label}: {ratio.message}")
        if not buffer.mean.any():  # a black image is possible, a radiance plane nothing wrote more likely
            ctx.warnings.append(f"{p}: {layout.colour.label}: every pixel is 0; an aov integrator inside moment "
                                "without a radiance integrator of its own (such as img: path) writes 0 there")
        if bound is not None and bound.agreed:
            ctx.warnings.append(f"{p}: {layout.colour.label}: every pixel's samples agree exactly (second moment = "
                                f"squared mean) though counted {int(buffer.count.max())} per pixel: moments of one "
                                "sample per pixel? Give spp 1 if so; each variance read is the rounding of m2 - m1^2")
    _warn(ctx.warnings)
    return SampleDump(buffer, buffer.count, {}, tuple(ctx.notes + ctx.warnings),
                      feature_planes=dict(ctx.feature_planes))


_HALF_ROUNDING = 2.0**-9
"""Two renders whose every pixel agrees within this share of the pixel's brightest channel (and within 2**-24, half
floats' finest step, near 0) are one render, once rounded to half floats (11 significant bits: 2**-11 of each
value; a colour conversion after it can grow that a few times). Renders of two seeds agree that closely at every
pixel only below some 1e6 samples' noise, where their spread would be the rounding of such a copy anyway."""


def _within_rounding(a: FloatArray, b: FloatArray) -> bool:
    """Whether means ``a`` and ``b`` (H, W, C) agree at every pixel up to :data:`_HALF_ROUNDING`."""
    scale = np.maximum(np.abs(a), np.abs(b)).max(axis=-1, keepdims=True)
    return bool(np.all(np.abs(a - b) <= _HALF_ROUNDING * scale + 2.0**-24))


def read_independent_renders(
    paths: Sequence[str | os.PathLike[str]],
    *,
    preset: str = "auto",
    color: str | None = None,
    count: str | None = None,
    spp: int | None = None,
    layer: str | None = None,
    view: str | None = None,
) -> SampleDump:
    """Merge renders of the same frame made with different seeds into per-pixel statistics.

    For renderers that write means but no variance (Blender Cycles): each file gives a mean
    and a count per pixel (its count pass, header or ``spp``); the merged buffer has the
    summed counts, the count-weighted mean, and the per-sample variance estimated from the
    spread of the means (:meth:`~awr_denoise.SampleBuffer.from_independent_means`).

    Parameters
    ----------
    paths
        Two or more EXR files of the same size and channels, rendered with different seeds.
    preset, color, count, spp, layer, view
        As for :func:`read_sample_buffer`; applied to every file. Features are not read here
        (the merged buffer has none).

    Returns
    -------
    SampleDump
        The merged statistics; ``notes`` as for one file, plus the number of renders merged.

    Raises
    ------
    InputFileError
        Fewer than two files, a file that repeats another (same content, or the same up to half-float
        rounding: not independent),
        sizes and channels that differ between files, or views that differ (a stereo pair's eyes).

    Warns
    -----
    InputFileWarning
        As for one file, and a lossy compression (its error would read as noise between seeds).
    """
    if len(paths) < 2:
        raise ValueError(f"paths: {len(paths)} file(s) given; the spread of means needs at least 2 renders")
    if preset not in PRESETS or preset == "deep":
        raise ValueError(f"preset: {preset!r} is not one of {', '.join(p for p in sorted(PRESETS) if p != 'deep')}")
    means, counts, notes, warned = [], [], [], []
    channels: tuple[str, ...] | None = None
    first_view: str | None = None
    for path in paths:
        p = Path(path)
        parts = read_exr(p)
        if any(part.deep for part in parts):
            raise file_error(p, "a per-sample (deep) dump, not a render's image: merge it without independent "
                                "renders (--independent)")
        f = _File(p, parts, view)
        if first_view is None:
            first_view = f.view
        elif f.view is not None and f.view != first_view:
            # Each file's only view is taken: a stereo pair's left and right parts (each written alone) are
            # two cameras, and their spread the parallax, not the noise of one view.
            raise file_error(p, f"view {f.view!r} does not match view {first_view!r} of {paths[0]}: independent "
                                "renders are renders of one view")
        # The means are what the spread is taken of: a lossy codec's error would read as noise.
        warned.extend(w for w in _lossy(p, f.used) if w not in warned)
        name = _resolve_preset(p, f, preset, color, None, count, independent=True)
        if name == "awr" and color is None:
            raise file_error(p, "an awr dump holds statistics, not a render's image: merge it without independent "
                                "renders (--independent)")
        _check_layer(p, name, layer)
        layout, ctx = _layout(p, f, name, color=color, variance=None, count=count, variance_kind=None, spp=spp,
                              layer=layer, view=view, need_variance=False, need_count=True)
        assert layout.count is not None
        mean = _values(layout.colour)
        if layout.convert is not None and layout.convert[1] == "mean_and_variance":
            mean = mean @ layout.convert[0].T
        names = ("R", "G", "B") if layout.convert is not None else _channel_names(layout.colour)
        if channels is None:
            channels = names
        elif names != channels or mean.shape != means[0].shape:
            raise file_error(p, f"{mean.shape[1]}x{mean.shape[0]} with channels {','.join(names)} does not match "
                                f"{means[0].shape[1]}x{means[0].shape[0]} {','.join(channels)} of {paths[0]}")
        for k, earlier in enumerate(means):
            if np.array_equal(earlier, mean):
                raise file_error(p, f"has the same pixels as {paths[k]}: renders must use different seeds")
            if _within_rounding(earlier, mean):  # a copy in half floats: its spread would be rounding
                raise file_error(p, f"has the pixels of {paths[k]} up to half-float rounding (a copy?): renders "
                                    "must use different seeds, and the spread of these is rounding, not noise")
        means.append(mean)
        counts.append(layout.count)
        notes.extend(n for n in ctx.notes if n not in notes)
        warned.extend(w for w in ctx.warnings if w not in warned)
    _warn(warned)
    try:
        buffer = SampleBuffer.from_independent_means(np.stack(counts), np.stack(means), channels=channels)
    except ValueError as exc:
        raise file_error(Path(paths[0]), str(exc)) from None
    notes.append(f"{len(paths)} independent renders merged: variance from the spread of their means")
    return SampleDump(buffer, buffer.count, {}, tuple(notes + warned))


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
    view: str | None = None,
    nonfinite: str = "raise",
    albedo: str | None = None,
    normal: str | None = None,
    depth: str | None = None,
    features: str | Sequence[str] | None = "auto",
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
        ``color`` with ``preset="auto"`` selects the generic mode, except in a pbrt, Mitsuba or
        Cycles file (a Cycles plane is counted by its view layer's count pass).
    variance_kind
        ``"sample"``, ``"mean"`` or ``"second_moment"``; overrides the preset's default.
    spp
        Samples per pixel where the file has no count (Mitsuba); overrides pbrt's header
        value, and for Cycles gives the samples the render took (the divisor of the
        normalised count pass).
    layer
        Cycles view layer when the file has several; refused for the other layouts, which have
        none.
    view
        View of a multi-view (stereo) file, e.g. ``"left"``; required when there are several.
    nonfinite
        Policy for NaN/Inf *samples* of a deep per-sample dump: ``"raise"`` (default),
        ``"drop"`` or ``"zero"``, counted in the buffer's ``nonfinite``. Flat files hold
        statistics, where NaN/Inf is always an error: another policy is refused for them.
    albedo, normal, depth
        Feature planes (:mod:`awr_denoise.features`): a plane of the input, ``file.exr:plane``,
        or a whole image file (its ``R,G,B``/``X,Y,Z``, or ``Z``), as ``oidnDenoise --alb/--nrm``
        take them; they override what the preset finds.
    features
        ``"auto"`` (default): also read the features the preset knows the planes of, when the
        file has them (:mod:`awr_denoise.io.features`); a list of names: those must be found;
        ``None``: only the planes given.

    Returns
    -------
    SampleBuffer
        The statistics, variance converted to per-sample variance on entry, colours in linear
        sRGB (Mitsuba's and pbrt's XYZ statistics converted).

    Raises
    ------
    InputFileError
        Missing, corrupt or non-EXR file; missing or ambiguous channels, layers or views;
        size mismatch between files; NaN/Inf (half-float overflow named); negative variance
        or counts.

    Warns
    -----
    InputFileWarning
        An assumed sample count (Cycles without a count pass), an already denoised Cycles
        pass, a Mitsuba film filter that correlates neighbouring pixels.
    """
    return read_sample_dump(path, preset=preset, color=color, variance=variance, count=count,
                            variance_kind=variance_kind, spp=spp, layer=layer, view=view,
                            nonfinite=nonfinite, albedo=albedo, normal=normal, depth=depth,
                            features=features).buffer


def describe_layout(path: Path, parts: list[ExrPart], *, preset: str = "auto", color: str | None = None,
                    variance: str | None = None, count: str | None = None, variance_kind: str | None = None,
                    spp: int | None = None, layer: str | None = None, view: str | None = None,
                    albedo: str | None = None, normal: str | None = None, depth: str | None = None,
                    features: str | Sequence[str] | None = "auto",
                    ) -> tuple[str, _Layout, list[str], list[str], dict[str, str]]:
    """Where a preset finds the statistics, without requiring a variance or a count.

    Returns (preset, layout, notes, warnings, feature planes); used by ``awr info`` to describe
    files that cannot be denoised as they are. The feature planes are read and checked.
    """
    f = _File(path, parts, view)
    name = _resolve_preset(path, f, preset, color, variance, count)
    layout, ctx = _layout(path, f, name, color=color, variance=variance, count=count, variance_kind=variance_kind,
                          spp=spp, layer=layer, view=view, need_variance=False, need_count=False)
    # Said where the statistics are read (read_sample_dump), but a file described without them (a
    # Cycles render, before merging) was called fine.
    ctx.warnings[:0] = _lossy(path, f.used) + _generic_reading(ctx, name, layout)
    count_or_none = np.zeros(layout.colour.shape, np.int64) if layout.count is None else layout.count
    _features(ctx, name, layout, count_or_none, {"albedo": albedo, "normal": normal, "depth": depth}, features)
    return name, layout, ctx.notes, ctx.warnings, ctx.feature_planes
