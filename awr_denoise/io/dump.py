"""The project's own sample-dump layout: per-pixel count, mean and variance in one EXR.

Channels (all FLOAT, looked up by name)::

    R, G, B                 mean of each channel (the buffer's channel names)
    variance.R/G/B          spread; what it holds is the header's awr:variance_kind
    sampleCount             samples per pixel, a whole number stored as FLOAT
    varianceKnown           optional, 1 where the variance is usable, 0 where unknown
    issuedCount             optional, samples requested so far when it differs from
                            sampleCount (dropped non-finite samples); next first_index
    albedo.R/G/B, normal.X/Y/Z, depth.Z
                            optional features (header awr:features), each with its
                            variance.<feature>.<c> planes and, where they differ from the
                            radiance's, <feature>.sampleCount and <feature>.varianceKnown

Header attributes: ``awr:semantics = "sample-statistics"``, ``awr:variance_kind``
(``sample`` | ``mean`` | ``second_moment``), ``awr:channels`` (the channel order, since EXR
sorts channels by name), ``awr:version``, ``awr:nonfinite`` and free provenance such as
``awr:round`` and ``awr:seed``; ``awr:features`` lists the features stored (comma separated).

Counts are FLOAT, not UINT, because OpenImageIO normalises integer channels read as float
(a count of 26 comes back as 6e-9); Cycles and RenderMan store counts as float for the same
reason. float32 holds whole numbers exactly up to 2**24, so larger counts are refused.
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._arrays import numeric
from .._typing import CountArray
from .._version import __version__
from ..buffers import VARIANCE_KINDS, SampleBuffer
from ..features import FEATURE_CHANNELS, FEATURE_NAMES
from .atomic import public_name
from .exr import ExrPart, brief, checked_plane, file_error, header_value, write_exr

__all__ = [
    "COUNT_CHANNEL",
    "KNOWN_CHANNEL",
    "ISSUED_CHANNEL",
    "VARIANCE_PREFIX",
    "SEMANTICS_STATISTICS",
    "FEATURES_ATTRIBUTE",
    "MAX_EXACT_COUNT",
    "SampleDump",
    "write_sample_buffer",
    "buffer_from_awr_part",
    "uncounted_means",
    "exact_counts",
    "checked_header",
]

COUNT_CHANNEL = "sampleCount"
KNOWN_CHANNEL = "varianceKnown"
ISSUED_CHANNEL = "issuedCount"
VARIANCE_PREFIX = "variance."
SEMANTICS_STATISTICS = "sample-statistics"
FEATURES_ATTRIBUTE = "awr:features"
MAX_EXACT_COUNT = 2**24
"""Largest count a float32 channel is guaranteed to hold exactly (with all smaller ones)."""


@dataclass(frozen=True, eq=False)
class SampleDump:
    """A sample buffer read from a dump, with the dump's bookkeeping.

    Attributes
    ----------
    buffer
        The statistics.
    issued
        (H, W) int64 samples requested so far (``first_index`` of the next request), equal
        to ``buffer.count`` unless the dump says otherwise.
    attributes
        The ``awr:*`` header attributes (``awr:round``, ``awr:seed``, ...), plain values.
    notes
        What the reader decided about a renderer's file, one sentence each (which pass gave
        the colour, how counts were derived, conversions made); warnings among them are also
        issued as :class:`~awr_denoise.errors.InputFileWarning`.
    index_bounds
        Each pixel's range of sample indices, where the file records them (deep dumps).
    feature_planes
        Where each feature of ``buffer`` was read: a plane of the file (``Albedo``), or
        ``other.exr:plane`` for a plane of another file (its name as given).
    """

    buffer: SampleBuffer
    issued: CountArray
    attributes: dict[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    index_bounds: Any = None
    """Each pixel's recorded sample indices (:class:`~awr_denoise.io.deep.IndexBounds`), where the
    file records them (a deep dump's ``sampleIndex``), else ``None``."""
    feature_planes: dict[str, str] = field(default_factory=dict)


def exact_counts(name: str, counts: np.ndarray, *, what: str = "counts", unit: str = "pixel(s)") -> np.ndarray:
    """Counts as float32 after checking they are whole, non-negative and exactly representable (``what`` and
    ``unit`` name them in the messages: ``"sample indices"`` of ``"sample(s)"`` for a deep dump's)."""
    c = numeric(name, counts)
    if c.dtype.kind == "f" and (~np.isfinite(c) | (c != np.round(c))).any():
        raise ValueError(f"{name}: {what} must be whole numbers")
    if c.dtype.kind == "u":  # 2**63 and more would wrap to negative in int64: held just past the limit checked below
        c = np.minimum(c, MAX_EXACT_COUNT + 1)
    c = c.astype(np.int64)
    if (c < 0).any():
        raise ValueError(f"{name}: {int((c < 0).sum())} {unit} are negative")
    too_big = c > MAX_EXACT_COUNT
    if too_big.any():
        raise ValueError(f"{name}: {int(too_big.sum())} {unit} exceed {MAX_EXACT_COUNT} "
                         "(2**24), the largest count a float32 channel stores exactly")
    return c.astype(np.float32)


def _float32(path: str | os.PathLike[str], name: str, values: np.ndarray) -> np.ndarray:
    """A plane as float32, refusing values that would be stored as Inf (beyond 3.4e38)."""
    with np.errstate(over="ignore"):
        stored = np.ascontiguousarray(values, dtype=np.float32)
    over = ~np.isfinite(stored)
    if over.any():
        raise ValueError(f"{public_name(path)}: {name}: {int(over.sum())} pixel(s) beyond the float32 range "
                         f"{float(np.finfo(np.float32).max):g}, which would be stored as Inf")
    return stored


def write_sample_buffer(path: str | os.PathLike[str], buffer: SampleBuffer, *,
                        header: Mapping[str, Any] | None = None, issued: CountArray | None = None,
                        overwrite: bool = False) -> Path:
    """Write a :class:`~awr_denoise.SampleBuffer` in the project's dump layout, atomically.

    Parameters
    ----------
    path
        Target EXR file.
    buffer
        Statistics to store; mean and variance are stored as float32 (counts exactly).
    header
        Extra attributes (provenance: ``awr:round``, ``awr:seed``, ...).
    issued
        Optional (H, W) samples requested so far; stored only where it differs from the count.
    overwrite
        Replace an existing file.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    ValueError
        A count above 2**24 (not exact in float32), a mean or variance beyond the float32
        range, a variance plane wholly below it (its largest value stored more than 2x off), a
        channel name that collides with the layout's own channels, or a ``header`` attribute that
        gives one of the layout's own (``awr:variance_kind``, ``awr:channels``, ``awr:nonfinite``,
        ...) another value than the buffer's.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.io import write_sample_buffer, read_sample_buffer
    >>> buf = SampleBuffer.from_samples(np.array([0, 0, 1]), np.array([1.0, 3.0, 2.0]), (1, 2))
    >>> f = os.path.join(tempfile.mkdtemp(), "dump.exr")
    >>> _ = write_sample_buffer(f, buf)
    >>> read_sample_buffer(f).count.tolist()
    [[2, 1]]
    """
    if not isinstance(buffer, SampleBuffer):
        raise TypeError(f"buffer: expected a SampleBuffer, got {type(buffer).__name__}")
    reserved = {COUNT_CHANNEL, KNOWN_CHANNEL, ISSUED_CHANNEL}
    feature_prefixes = tuple(f"{name}." for name in buffer.features)
    for name in buffer.channels:
        if (name in reserved or name.startswith(VARIANCE_PREFIX) or "," in name
                or (feature_prefixes and name.startswith(feature_prefixes))):
            raise ValueError(f"buffer: channel name {name!r} collides with the dump layout")
    planes: dict[str, np.ndarray] = {}
    _statistics_planes(path, planes, buffer, "")
    for name, feature in buffer.features.items():
        _statistics_planes(path, planes, feature, f"{name}.", like=buffer.count)
    if issued is not None:
        iss = numeric("issued", issued)
        if iss.shape != buffer.shape:
            raise ValueError(f"issued: shape {iss.shape} does not match the buffer {buffer.shape}")
        issued_plane = exact_counts("issued", iss)  # whole, not negative, exact in float32: checked before compared
        if (issued_plane < buffer.count).any():
            raise ValueError("issued: fewer samples issued than counted at some pixels")
        if (issued_plane != buffer.count).any():
            planes[ISSUED_CHANNEL] = issued_plane
    attrs: dict[str, Any] = {
        "awr:semantics": SEMANTICS_STATISTICS,
        "awr:variance_kind": "sample",
        "awr:channels": ",".join(buffer.channels),
        "awr:version": __version__,
        "awr:nonfinite": int(buffer.nonfinite),
    }
    if buffer.features:
        attrs[FEATURES_ATTRIBUTE] = ",".join(buffer.features)
    attrs.update(checked_header(header, attrs))
    return write_exr(path, planes, attrs, overwrite=overwrite)


def checked_header(header: Mapping[str, Any] | None, own: Mapping[str, Any]) -> Mapping[str, Any]:
    """``header``, refused where it gives one of the writer's ``own`` attributes another value: those describe the
    planes (``awr:variance_kind="mean"`` over a buffer's per-sample variance read it back 4x too noisy at 4 spp,
    ``awr:round`` replaced a request's round; an attack pass), and a reader trusts them."""
    for key, value in (header or {}).items():
        if key in own and str(value).strip() != str(own[key]):
            raise ValueError(f"header: {key} {value!r} is the layout's own attribute, written from the data as "
                             f"{own[key]!r}; leave it out")
    return header or {}


def _statistics_planes(path: str | os.PathLike[str], planes: dict[str, np.ndarray], buffer: SampleBuffer,
                       prefix: str, like: np.ndarray | None = None) -> None:
    """Planes of one buffer (the radiance, ``prefix=""``, or a feature, ``prefix="depth."``).

    A feature's count is stored only where it differs from the radiance's (``like``), and a
    known-variance mask wherever a pixel with two samples or more is marked unknown.
    """
    if like is None or (buffer.count != like).any():
        planes[prefix + COUNT_CHANNEL] = exact_counts(f"{prefix}count", buffer.count)
    for i, name in enumerate(buffer.channels):
        planes[prefix + name] = _float32(path, prefix + name, buffer.mean[..., i])
        variance = _float32(path, VARIANCE_PREFIX + prefix + name, buffer.variance[..., i])
        # Below float32's least subnormal (1.4e-45) a variance rounds to 0, which reads back as a
        # known, noise-free pixel: kept at that least value instead, still tiny, still noisy.
        variance[(variance == 0) & (buffer.variance[..., i] > 0)] = np.nextafter(np.float32(0), np.float32(1))
        _check_representable(path, VARIANCE_PREFIX + prefix + name, buffer.variance[..., i], variance)
        planes[VARIANCE_PREFIX + prefix + name] = variance
    # Pixels with fewer than two samples are unknown by definition; only a renderer's
    # explicit "unknown" needs the mask.
    if (~buffer.variance_known & (buffer.count >= 2)).any():
        planes[prefix + KNOWN_CHANNEL] = buffer.variance_known.astype(np.float32)


def _check_representable(path: str | os.PathLike[str], name: str, values: np.ndarray, stored: np.ndarray) -> None:
    """Refuse a plane whose largest value float32 stores more than 2x off: the whole plane below float32's range
    (an image at 1e-24 with 30% noise read its variances back 3.5e4x too large; an attack pass). A few pixels
    there beside a plane float32 holds are kept at its least value, negligible beside the rest."""
    top = float(values.max(initial=0.0))
    if top <= 0.0:
        return
    kept = float(stored.max())
    if not 0.5 * top <= kept <= 2.0 * top:
        raise ValueError(f"{public_name(path)}: {name}: every value is below float32's range (the largest "
                         f"{top:.3g}), which would be stored as {kept:.3g}; scale the buffer up (the reconstruction "
                         "scales with it)")


def header_count(path: str | os.PathLike[str], attributes: dict, key: str, default: int, high: int, *,
                 low: int = 0) -> int:
    """A whole-number ``awr:*`` header attribute in ``low``..``high``, refused naming the file and the key.

    ASCII digits only: Python's ``int()`` also reads ``'1_000'`` and other scripts' digits.
    """
    raw = attributes.get(key, default)
    text = str(raw).strip()
    if not re.fullmatch(r"[+-]?[0-9]{1,40}", text):
        raise file_error(path, f"header attribute is not a whole number: {brief(raw)}", key)
    if not low <= int(text) <= high:
        raise file_error(path, f"header attribute {int(text)} is outside {low}..{high}", key)
    return int(text)


def uncounted_means(path: str | os.PathLike[str], label: str | None, count: np.ndarray,
                    mean: np.ndarray) -> str | None:
    """The warning for pixels counted 0 that hold a non-zero mean (``label``: the count plane), or None.

    A pixel counted 0 has no samples and its mean is read as none (``SampleBuffer.from_moments`` zeroes it); one
    holding a colour anyway points at a count plane gone wrong, the renderer's or the user's, whatever the layout.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.io.dump import uncounted_means
    >>> uncounted_means("b.exr", "n", np.array([[4, 0]]), np.array([[[0.5], [0.5]]])).split(", read")[0]
    'b.exr: n: 1 pixel(s) counted 0 hold a non-zero mean'
    >>> uncounted_means("b.exr", "n", np.array([[4, 0]]), np.array([[[0.5], [0.0]]])) is None
    True
    """
    stray = int(np.count_nonzero((np.asarray(count) == 0) & np.any(np.asarray(mean) != 0, axis=-1)))
    if not stray:
        return None
    where = "" if label is None else f"{label}: "
    return (f"{path}: {where}{stray} pixel(s) counted 0 hold a non-zero mean, read as no samples: is the count the "
            "renderer's (a batch writes the samples it rendered there)?")


def whole_counts(path: str | os.PathLike[str], name: str, values: np.ndarray) -> np.ndarray:
    """A count channel as int64, refusing NaN/Inf, negatives, fractions and inexact floats.

    A float channel holds whole numbers exactly only up to 2**24 (the project's own dumps stop
    there), a HALF channel up to 2048, which is also what 2049 rounds to: a HALF count of 2048 or
    more may not be the renderer's count, a larger float one is not, and one beyond int64 would
    wrap to a negative number.
    """
    c = checked_plane(path, name, values, nonnegative=True, whole=True)
    dtype = np.asarray(values).dtype
    if dtype.kind == "f":
        half = dtype.itemsize == 2
        too_big = c >= 2048 if half else c > MAX_EXACT_COUNT
        if too_big.any():
            raise file_error(path, f"{int(too_big.sum())} pixel(s) " + (
                "reach 2048, where a HALF channel stops holding sample counts exactly (2049 is stored as 2048); "
                "write the count as FLOAT" if half else
                f"exceed {MAX_EXACT_COUNT} (2**24), the largest sample count a float channel holds exactly"), name)
    # Exactly whole: every float type holds the whole counts it may carry exactly (above), so a
    # fraction, however small, is not a count (0.0009 must not become a pixel without samples).
    frac = c != np.rint(c)
    if frac.any():
        raise file_error(path, f"{int(frac.sum())} pixel(s) are not whole sample counts", name)
    return c.astype(np.int64)


def _known_mask(path: str | os.PathLike[str], name: str, values: np.ndarray) -> np.ndarray:
    """A ``varianceKnown`` channel as a bool mask, refusing values other than 0 and 1 (and NaN/Inf)."""
    c = checked_plane(path, name, values, whole=True)
    odd = (c != 0) & (c != 1)
    if odd.any():
        raise file_error(path, f"{int(odd.sum())} pixel(s) are neither 0 (variance unknown) nor 1 (known)", name)
    return c == 1


def impossible_spread(path: str | os.PathLike[str], buffer: SampleBuffer) -> str | None:
    """The warning for a known variance above 0 beside a mean of 0 in a channel whose means are all 0 or more, or None.

    Samples of 0 or more whose mean is 0 are all 0, whatever their weights: such a pixel's variance is 0. A file
    where it is not was not written so by a renderer, but changed after it was written: an attack pass found a dump
    converted to ACEScg by a pipeline tool (its counts and header kept) read as valid, a mean of 0 beside a variance
    of 0.5 at a third of its pixels. A channel with a negative mean may hold samples of either sign, and is not
    judged. (The tighter bound ``s^2 <= n m^2`` of equally weighted samples, which
    :func:`~awr_denoise.io.mitsuba.moment_bound` applies to Mitsuba's box-filtered moments, is not applied here:
    dumps of samples with noise of either sign about a mean of 0 or more, the synthetic renderer's, break it.)

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> count = np.full((1, 2), 4)               # one row of two pixels, 4 samples each, one channel
    >>> ok = SampleBuffer.from_moments(count, np.array([[[0.5], [0.0]]]), np.array([[[1.0], [0.0]]]))
    >>> impossible_spread("d.exr", ok) is None
    True
    >>> bad = SampleBuffer.from_moments(count, np.array([[[0.5], [0.0]]]), np.array([[[1.0], [0.5]]]))
    >>> print(impossible_spread("d.exr", bad))  # doctest: +ELLIPSIS
    d.exr: Y: pixel (x 1, y 0) has a mean of 0 and a variance above 0, which samples of 0 or more never have: ...
    """
    for c, name in enumerate(buffer.channels):
        mean, variance = buffer.mean[..., c], buffer.variance[..., c]
        zero = (mean == 0) & (variance > 0) & buffer.variance_known  # known: 2 samples or more; NaN compares False
        if zero.any() and not (mean < 0).any():  # a negative mean: samples that may be negative, no bound
            y, x = np.argwhere(zero)[0]
            return (f"{path}: {name}: pixel (x {x}, y {y}) has a mean of 0 and a variance above 0, which samples "
                    "of 0 or more never have: the file was changed after it was written (a colour conversion, "
                    "a resize or a blur), or its samples are negative")
    return None


def buffer_from_awr_part(path: str | os.PathLike[str], part: ExrPart, *,
                         variance_kind: str | None = None) -> SampleDump:
    """Decode one EXR part in the project's layout (see the module docstring)."""
    ch = part.channels
    header = part.header
    attributes = {k: header_value(header, k) for k in header if str(k).startswith("awr:")}
    if COUNT_CHANNEL not in ch:
        raise file_error(path, "missing (the dump layout stores the sample count here)", COUNT_CHANNEL)
    held = sorted(n[len(VARIANCE_PREFIX):] for n in ch if n.startswith(VARIANCE_PREFIX)
                  and not n[len(VARIANCE_PREFIX):].startswith(tuple(f"{f}." for f in FEATURE_NAMES)))
    if "awr:channels" in attributes:
        names = [n for n in str(attributes["awr:channels"]).split(",") if n]
        unlisted = [n for n in held if n not in names and n in ch]
        if names and unlisted:
            # Statistics the header does not list were dropped without a word (an attack pass): the header and the
            # channels disagree, and which is right is not the reader's to guess.
            raise file_error(path, f"{brief(attributes['awr:channels'])} does not list {', '.join(unlisted)}, whose "
                                   f"means and variances ({', '.join(VARIANCE_PREFIX + n for n in unlisted)}) the "
                                   "dump holds; make the two agree", "awr:channels")
    else:
        names = held
        order = {"R": 0, "G": 1, "B": 2, "A": 3}
        names.sort(key=lambda n: (order.get(n, 4), n))
    if not names:
        raise file_error(path, "no variance.<channel> channels found", VARIANCE_PREFIX + "*")
    declared = attributes.get("awr:variance_kind")
    if variance_kind is not None and declared is not None and str(declared) != variance_kind:
        # An option describes files that do not say (awr merge gives it to those inputs only).
        raise file_error(path, f"its header says what its variance holds ({str(declared)!r}); "
                               f"variance_kind {variance_kind!r} (--variance-kind) contradicts it: the option is for "
                               "files that do not say", "awr:variance_kind")
    kind = variance_kind or str(attributes.get("awr:variance_kind", "sample"))
    if kind not in VARIANCE_KINDS:
        raise file_error(path, f"{kind!r} is not one of {', '.join(VARIANCE_KINDS)}",
                         "awr:variance_kind")
    count = whole_counts(path, COUNT_CHANNEL, ch[COUNT_CHANNEL])
    means, variances = [], []
    for name in names:
        for channel in (name, VARIANCE_PREFIX + name):
            if channel not in ch:
                raise file_error(path, "missing", channel)
        means.append(checked_plane(path, name, ch[name]))
        variances.append(checked_plane(path, VARIANCE_PREFIX + name, ch[VARIANCE_PREFIX + name],
                                       nonnegative=True))
    known = None
    if KNOWN_CHANNEL in ch:
        known = _known_mask(path, KNOWN_CHANNEL, ch[KNOWN_CHANNEL])
    stray = uncounted_means(path, COUNT_CHANNEL, count, np.stack(means, -1))
    notes: tuple[str, ...] = () if stray is None else (stray,)
    try:
        buffer = SampleBuffer.from_moments(count, np.stack(means, -1), np.stack(variances, -1),
                                           variance_kind=kind, channels=names, variance_known=known)
    except ValueError as exc:
        raise file_error(path, str(exc)) from None
    spread = impossible_spread(path, buffer)
    if spread is not None:
        notes += (spread,)
    nonfinite = header_count(path, attributes, "awr:nonfinite", 0, 2**62)
    features = _read_features(path, part, attributes, count, kind)
    if nonfinite or features:
        buffer = dataclasses.replace(buffer, nonfinite=nonfinite, features=features)
    issued = count
    if ISSUED_CHANNEL in ch:
        issued = whole_counts(path, ISSUED_CHANNEL, ch[ISSUED_CHANNEL])
        if (issued < count).any():
            raise file_error(path, "fewer samples issued than counted at some pixels", ISSUED_CHANNEL)
    return SampleDump(buffer, issued, attributes, notes, feature_planes={name: name for name in features})


def _read_features(path: str | os.PathLike[str], part: ExrPart, attributes: Mapping[str, Any],
                   count: np.ndarray, kind: str) -> dict[str, SampleBuffer]:
    """The features of a dump: those ``awr:features`` names, or every complete set of planes."""
    ch = part.channels
    if FEATURES_ATTRIBUTE in attributes:
        names = [n for n in str(attributes[FEATURES_ATTRIBUTE]).split(",") if n]
        for name in names:
            if name not in FEATURE_CHANNELS:
                raise file_error(path, f"{name!r} is not one of {', '.join(FEATURE_NAMES)}", FEATURES_ATTRIBUTE)
    else:
        names = [n for n in FEATURE_NAMES if all(f"{n}.{c}" in ch for c in FEATURE_CHANNELS[n])]
    features = {}
    for name in names:
        prefix = f"{name}."
        planes = [prefix + c for c in FEATURE_CHANNELS[name]]
        for channel in planes + [VARIANCE_PREFIX + p for p in planes]:
            if channel not in ch:
                raise file_error(path, f"missing (the dump's {name} feature)", channel)
        own = count
        if prefix + COUNT_CHANNEL in ch:
            own = whole_counts(path, prefix + COUNT_CHANNEL, ch[prefix + COUNT_CHANNEL])
        known = None
        if prefix + KNOWN_CHANNEL in ch:
            known = _known_mask(path, prefix + KNOWN_CHANNEL, ch[prefix + KNOWN_CHANNEL])
        mean = np.stack([checked_plane(path, p, ch[p]) for p in planes], -1)
        variance = np.stack([checked_plane(path, VARIANCE_PREFIX + p, ch[VARIANCE_PREFIX + p], nonnegative=True)
                             for p in planes], -1)
        try:
            features[name] = SampleBuffer.from_moments(own, mean, variance, variance_kind=kind,
                                                       channels=FEATURE_CHANNELS[name], variance_known=known)
        except ValueError as exc:
            raise file_error(path, str(exc), prefix + "*") from None
    return features
