"""Feature buffers: per-pixel albedo, shading normal and depth carried beside the radiance.

A renderer can report, for every sample, what it hit first: the surface's albedo, its shading
normal and its depth. Production denoisers use these auxiliary images to tell edges of the scene
from noise (Intel Open Image Denoise takes ``albedo`` and ``normal``). Each feature is kept as a
:class:`~awr_denoise.buffers.SampleBuffer` of its own (count, mean, per-sample variance), so it
is merged exactly like the radiance (Chan's update) and its noise is known where it has one.
A :class:`~awr_denoise.buffers.SampleBuffer` holds them in ``features``, a read-only mapping
keyed by name (docs/concepts.md, "Features").

===========  ==========  ===================================================================
name         channels    holds
===========  ==========  ===================================================================
``albedo``   R, G, B     reflectance of the surface, in [0, 1] (0 where nothing was hit)
``normal``   X, Y, Z     shading normal in world space, unit length per sample (0 on a miss)
``depth``    Z           distance from the camera plane along the view axis (0 on a miss)
===========  ==========  ===================================================================

Where a renderer follows perfect mirrors and glass before it reports (the bundled tracer does,
as OIDN's documentation recommends) is for the renderer to say (docs/tracer.md, "Features").

This module has the names, the channel layouts and the rules: features are validated against
the buffer that owns them (:func:`checked_features`) and merged as if a buffer without a
feature held no sample of it (:func:`merge_features`), which keeps every merge exact.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np

from ._arrays import plain

if TYPE_CHECKING:  # the buffer imports this module; annotations only
    from .buffers import SampleBuffer

__all__ = ["FEATURE_CHANNELS", "FEATURE_NAMES", "FeatureMap", "feature_channels", "feature_names",
           "checked_features", "merge_features", "map_features", "feature_rows"]

FEATURE_CHANNELS: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "albedo": ("R", "G", "B"),
    "normal": ("X", "Y", "Z"),
    "depth": ("Z",),
})
"""The features a buffer may carry and the channel names of each, in their canonical order."""

FEATURE_NAMES: tuple[str, ...] = tuple(FEATURE_CHANNELS)
"""``("albedo", "normal", "depth")``: the order features are listed, stored and shown in."""



class FeatureMap(Mapping):
    """A read-only ``{name: SampleBuffer}`` mapping that pickles (buffers travel to worker processes).

    Examples
    --------
    >>> from awr_denoise.features import FeatureMap
    >>> features = FeatureMap({})
    >>> features == {}, len(features)
    (True, 0)
    """

    def __init__(self, items: Mapping[str, SampleBuffer]) -> None:
        self._items = dict(items)

    def __getitem__(self, name: str) -> SampleBuffer:
        return self._items[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        return f"FeatureMap({self._items!r})"


_EMPTY = FeatureMap({})


def feature_channels(name: str) -> tuple[str, ...]:
    """The channel names of feature ``name``.

    Examples
    --------
    >>> from awr_denoise.features import feature_channels
    >>> feature_channels("normal"), feature_channels("depth")
    (('X', 'Y', 'Z'), ('Z',))
    """
    if not isinstance(name, str):
        raise TypeError(f"features: expected a feature name, got {type(name).__name__} {name!r}")
    if name not in FEATURE_CHANNELS:
        raise ValueError(f"features: {name!r} is not one of {', '.join(FEATURE_NAMES)}")
    return FEATURE_CHANNELS[name]


def feature_names(names: str | Iterable[str] | None) -> tuple[str, ...]:
    """Feature names checked and put in canonical order (``None`` or ``()`` for none).

    A comma-separated string is accepted, as on the command line; ``"all"`` names every feature.

    Examples
    --------
    >>> from awr_denoise.features import feature_names
    >>> feature_names("depth,albedo"), feature_names("all"), feature_names(None)
    (('albedo', 'depth'), ('albedo', 'normal', 'depth'), ())
    """
    if names is None:
        return ()
    if isinstance(names, str):
        parts = [n.strip() for n in names.split(",")] if names.strip() else []
        if "" in parts:  # "albedo," or "albedo,,depth": a name left out, not a list to tidy
            raise ValueError(f"features: {names!r} has an empty name between its commas")
        names = FEATURE_NAMES if names == "all" else parts
    if not isinstance(names, Iterable):
        raise TypeError(f"features: expected feature names, got {type(names).__name__} {names!r}")
    chosen = [n for n in names]
    for n in chosen:
        feature_channels(n)
    if len(set(chosen)) != len(chosen):
        raise ValueError(f"features: {', '.join(chosen)} names a feature twice")
    return tuple(n for n in FEATURE_NAMES if n in chosen)


def checked_features(owner: SampleBuffer, features: Mapping[str, SampleBuffer] | None) -> Mapping[str, SampleBuffer]:
    """``features`` validated against the buffer ``owner`` that holds them, as a read-only mapping.

    Each feature must be a buffer of the owner's class with the owner's (H, W), the feature's
    channels (:data:`FEATURE_CHANNELS`) and no features of its own; its counts are its own
    (normally the radiance's: one feature value per sample). Features come out in
    :data:`FEATURE_NAMES` order.

    Raises
    ------
    TypeError, ValueError
        Naming ``features[<name>]`` and what is wrong.
    """
    if features is None or (isinstance(features, Mapping) and not features):
        return _EMPTY
    if not isinstance(features, Mapping):
        raise TypeError(f"features: expected a mapping of feature name to buffer, got {type(features).__name__}")
    for name in features:
        feature_channels(name)
    checked: dict[str, SampleBuffer] = {}
    for name in FEATURE_NAMES:
        if name not in features:
            continue
        value = features[name]
        where = f"features[{name!r}]"
        if not isinstance(value, type(owner)):
            raise TypeError(f"{where}: expected a {type(owner).__name__}, got {type(value).__name__}")
        if value.shape != owner.shape:
            raise ValueError(f"{where}: shape {value.shape} does not match the buffer's {owner.shape}")
        if value.channels != FEATURE_CHANNELS[name]:
            raise ValueError(f"{where}: channels {value.channels}, expected {FEATURE_CHANNELS[name]}")
        if value.features:
            raise ValueError(f"{where}: a feature cannot hold features of its own")
        checked[name] = value
    return FeatureMap(checked)


def map_features(features: Mapping[str, SampleBuffer],
                 function: Callable[[SampleBuffer], SampleBuffer]) -> dict[str, SampleBuffer]:
    """``{name: function(feature)}`` for every feature (a crop, a conversion)."""
    return {name: function(value) for name, value in features.items()}


def merge_features(first: SampleBuffer, second: SampleBuffer) -> dict[str, SampleBuffer]:
    """The features of the union of two buffers' samples, each merged exactly.

    A feature one side lacks counts as one with no samples there, so the other side's statistics
    are taken as they are: merging into an empty buffer (a sampler's first round) keeps the
    renderer's features, and a round rendered without them leaves them as they were (their
    counts then fall behind the radiance's, which the counts say).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> depth = SampleBuffer.from_samples(np.array([0, 0]), np.array([2.0, 4.0]), (1, 1), channels=["Z"])
    >>> with_depth = SampleBuffer.from_samples(np.array([0, 0]), np.array([1.0, 1.0]), (1, 1),
    ...                                        features={"depth": np.array([[2.0], [4.0]])})
    >>> merged = SampleBuffer.empty((1, 1), channels=1).merge(with_depth)
    >>> merged.features["depth"].mean.ravel().tolist(), merged.features["depth"].variance.ravel().tolist()
    ([3.0], [2.0])
    """
    names = [n for n in FEATURE_NAMES if n in first.features or n in second.features]
    merged: dict[str, SampleBuffer] = {}
    for name in names:
        a, b = first.features.get(name), second.features.get(name)
        if a is None:
            merged[name] = b  # type: ignore[assignment]
        elif b is None:
            merged[name] = a
        else:
            try:
                merged[name] = a.merge(b)
            except ValueError as error:  # past float64, or one statistics object twice: the feature's, named
                raise ValueError(f"features[{name!r}]: {str(error).removeprefix('other: ')}") from None
    return merged


def feature_rows(name: str, rows: object, n: int) -> np.ndarray:
    """Per-sample values of feature ``name`` for ``n`` samples as an (N, channels) float64 copy
    (:meth:`~awr_denoise.buffers.SampleBuffer.from_samples`' ``features``), checked."""
    a = plain(f"features[{name!r}]", rows)
    a = a[:, None] if a.ndim == 1 else a
    width = len(FEATURE_CHANNELS.get(name, ()))
    if not width:
        raise ValueError(f"features: {name!r} is not one of {', '.join(FEATURE_CHANNELS)}")
    if a.ndim != 2 or a.shape != (n, width):
        raise ValueError(f"features[{name!r}]: expected ({n}, {width}) per-sample values, got shape {np.shape(rows)}")
    if a.dtype.kind not in "fiu":
        raise TypeError(f"features[{name!r}]: expected a numeric array, got dtype {a.dtype}")
    return a.astype(np.float64)
