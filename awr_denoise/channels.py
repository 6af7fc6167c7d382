"""Channel names and the luminance of a set of channels."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from . import _checks
from ._typing import FloatArray

__all__ = ["default_channel_names", "adopted_channels", "luminance_weights", "luminance_variance", "channel_groups",
           "colours", "resolve_channels",
           "channel_count", "MAX_CHANNELS"]

_REC709 = np.array([0.2126, 0.7152, 0.0722])

MAX_CHANNELS = 4096
"""Far beyond any renderer's AOVs; keeps a mistyped count from allocating terabytes."""


def default_channel_names(n_channels: int) -> tuple[str, ...]:
    """Conventional channel names for ``n_channels`` channels (``R,G,B`` for three).

    Examples
    --------
    >>> from awr_denoise.channels import default_channel_names
    >>> default_channel_names(1), default_channel_names(3)
    (('Y',), ('R', 'G', 'B'))
    >>> default_channel_names(2)
    ('ch0', 'ch1')
    """
    n_channels = _checks.whole("n_channels", n_channels, minimum=0, maximum=MAX_CHANNELS)
    if n_channels == 1:
        return ("Y",)
    if n_channels == 3:
        return ("R", "G", "B")
    if n_channels == 4:
        return ("R", "G", "B", "A")
    return tuple(f"ch{i}" for i in range(n_channels))


def adopted_channels(given: Sequence[str], expected: Sequence[str]) -> tuple[str, ...]:
    """``expected``, the names a batch of channels ``given`` takes when merged into statistics named ``expected``.

    A renderer that did not name its channels (:func:`default_channel_names`) takes the
    statistics' names; channels named otherwise must be the same names in the same order: merged
    channel by channel, ``B,G,R`` or ``X,Y,Z`` into ``R,G,B`` would swap or mislabel them. The
    default names are refused too where the statistics' names hold one of them elsewhere (``R,G,B``
    into ``B,G,R`` or ``B,G,R,depth``): unnamed and really ``R,G,B`` cannot be told apart, and the
    two readings swap channels. A batch that is really ``R,G,B`` merged into ``X,Y,Z`` statistics cannot be told
    from an unnamed one: it is renamed.

    Examples
    --------
    >>> from awr_denoise.channels import adopted_channels
    >>> adopted_channels(("R", "G", "B"), ("X", "Y", "Z"))       # unnamed (the defaults): renamed
    ('X', 'Y', 'Z')
    >>> adopted_channels(("B", "G", "R"), ("R", "G", "B"))
    Traceback (most recent call last):
    ...
    ValueError: samples: channels B,G,R do not match the sampler's R,G,B
    """
    given, expected = tuple(given), tuple(expected)
    if given == expected:
        return expected
    if given != default_channel_names(len(given)):
        raise ValueError(f"samples: channels {','.join(given)} do not match the sampler's {','.join(expected)}")
    bare = [name.rsplit(".", 1)[-1].upper() for name in expected]
    if any(name in bare and bare.index(name) != i for i, name in enumerate(given)):
        raise ValueError(f"samples: channels {','.join(given)} (the default names) would be reordered into the "
                         f"sampler's {','.join(expected)}; name the batch's channels")
    return expected


def luminance_variance(variance: FloatArray, weights: FloatArray) -> FloatArray:
    """(H, W) per-sample variance of luminance from (H, W, C) per-channel variances: ``(sum_c w_c s_c)^2``.

    Channel covariances are not stored; the colour channels of a path-traced sample are strongly
    correlated (one path, one throughput): this is the fully correlated upper bound, exact for grey.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.channels import luminance_variance
    >>> luminance_variance(np.full((1, 1, 2), 4.0), np.array([0.5, 0.5]))
    array([[4.]])
    """
    y = np.sqrt(variance) @ weights
    return np.square(y, out=y)


def luminance_weights(channels: Sequence[str]) -> FloatArray:
    """Weights that turn the channels into luminance.

    Rec. 709 weights when the channels are ``R, G, B`` (an ``A`` channel gets weight 0), the
    single channel itself when there is one, and the plain average otherwise.

    Examples
    --------
    >>> from awr_denoise import luminance_weights
    >>> luminance_weights(["beauty.R", "beauty.G", "beauty.B", "beauty.A"])
    array([0.2126, 0.7152, 0.0722, 0.    ])
    >>> luminance_weights(["Y"]), luminance_weights(["albedo", "depth"])
    (array([1.]), array([0.5, 0.5]))
    """
    names = [_checks.name("channels", c).rsplit(".", 1)[-1].upper() for c in _sequence(channels)]
    if not names:
        raise ValueError("channels: no channel names given")
    weights = np.zeros(len(names))
    if {"R", "G", "B"} <= set(names):
        for name, w in zip("RGB", _REC709):
            weights[names.index(name)] = w
        return weights
    return np.full(len(names), 1.0 / len(names))


def channel_groups(channels: Sequence[str]) -> list[tuple[int, ...]] | None:
    """The channels a reconstruction treats apart: each colour together, every other channel alone.

    A colour is R, G and B of one layer (the name's part before its last dot), else X, Y and Z,
    else a single Y; every other channel (an alpha, a depth, an AOV) is a group of its own. ``None``
    (every channel together) where that leaves one group: one colour alone, or no colour at all
    (``ch0``, ``ch1``). The domain's scale is the mean of its channels and the luminance mode's
    factor is made from the colour: an alpha or an AOV reconstructed with the colour moved the
    colour, and the luminance factor moved an exact alpha (docs/robustness.md, "Channels that are
    not colour").

    Examples
    --------
    >>> from awr_denoise.channels import channel_groups
    >>> channel_groups(["R", "G", "B", "A"])
    [(0, 1, 2), (3,)]
    >>> channel_groups(["A", "B", "G", "R", "depth"]), channel_groups(["Y", "A"])
    ([(1, 2, 3), (0,), (4,)], [(0,), (1,)])
    >>> channel_groups(["a.R", "a.G", "a.B", "b.R", "b.G", "b.B"])    # two layers, two colours
    [(0, 1, 2), (3, 4, 5)]
    >>> channel_groups(["R", "G", "B"]) is None, channel_groups(["ch0", "ch1"]) is None
    (True, True)
    """
    groups = colours(_sequence(channels))
    taken = {i for group in groups for i in group}
    groups += [(i,) for i in range(len(channels)) if i not in taken]
    return groups if taken and len(groups) > 1 else None


def colours(channels: Sequence[str]) -> list[tuple[int, ...]]:
    """The colours among ``channels``, each as its channels' indices in the data's order.

    A colour is R, G and B of one layer (the name's part before its last dot; the first of each
    name), else X, Y and Z, else a single Y (:func:`channel_groups`).

    Examples
    --------
    >>> from awr_denoise.channels import colours
    >>> colours(["A", "B", "G", "R", "depth"]), colours(["Y", "A"]), colours(["ch0", "ch1"])
    ([(1, 2, 3)], [(0,)], [])
    """
    names = [str(c) for c in _sequence(channels)]
    bare = [name.rsplit(".", 1)[-1].upper() for name in names]
    layers = [name.rsplit(".", 1)[0] if "." in name else "" for name in names]
    groups: list[tuple[int, ...]] = []
    taken: set[int] = set()
    for colour in (("R", "G", "B"), ("X", "Y", "Z"), ("Y",)):
        for layer in dict.fromkeys(layers):  # the layers in their order
            first: dict[str, int] = {}
            for i, (name, of) in enumerate(zip(bare, layers)):
                if of == layer and name in colour and i not in taken:
                    first.setdefault(name, i)  # the first of each, as luminance_weights
            if len(first) == len(colour):
                groups.append(tuple(sorted(first.values())))
                taken.update(first.values())
    return groups


def _refuse_set(channels: object) -> None:
    """Refuse a set of names: its order is its hashes', not the data's (random between runs)."""
    if isinstance(channels, (set, frozenset)):
        raise TypeError("channels: a set of names has no order; give them as a list or a tuple, in the data's order")


def _sequence(channels: object) -> list:
    """Channel names in the data's order: a sequence, not a set."""
    _refuse_set(channels)
    if isinstance(channels, (str, bytes)) or not hasattr(channels, "__iter__") or getattr(channels, "ndim", 1) == 0:
        raise TypeError(f"channels: expected a sequence of channel names, got {_checks.described(channels)}")
    return list(channels)


def _names_or_count(channels: object, kind: str) -> Any:
    """``channels`` checked as a number of channels or an ordered collection of names (one with
    ``kind``, ``__len__`` or ``__iter__``); a set is refused, its order is not the data's."""
    channels = _checks.scalar(channels)
    _refuse_set(channels)
    if isinstance(channels, (bool, np.bool_, float, np.floating, str, bytes)) or not (
            isinstance(channels, (int, np.integer)) or hasattr(channels, kind)) or (
            isinstance(channels, np.ndarray) and channels.ndim != 1):  # a masked 0-d array, a 2-D one
        raise TypeError(f"channels: expected a number of channels or their names, got {_checks.described(channels)}")
    return channels


def resolve_channels(channels: Sequence[str] | int | None, n_channels: int) -> tuple[str, ...]:
    """Channel names for ``n_channels`` channels: given names checked, or :func:`default_channel_names`.

    Examples
    --------
    >>> from awr_denoise.channels import resolve_channels
    >>> resolve_channels(None, 3), resolve_channels(["Y"], 1)
    (('R', 'G', 'B'), ('Y',))
    """
    if channels is None:
        return default_channel_names(n_channels)
    channels = _names_or_count(channels, "__iter__")
    if isinstance(channels, (int, np.integer)):
        if channels != n_channels:
            raise ValueError(f"channels: {channels} given but the data has {n_channels}")
        return default_channel_names(n_channels)
    names = tuple(channels)
    for name in names:  # None or b"G" became the names 'None' and "b'G'"; an empty one cannot be written
        if not isinstance(name, str):
            raise TypeError(f"channels: expected names (str), got {type(name).__name__} {name!r} among them")
        if not name:
            raise ValueError("channels: an empty name")
    if len(names) != n_channels:
        raise ValueError(f"channels: {len(names)} names given for {n_channels} channel(s)")
    if len(set(names)) != len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"channels: duplicate names {', '.join(twice[:5])}" + (", ..." if len(twice) > 5 else ""))
    return names


def channel_count(channels: Sequence[str] | int) -> int:
    """The number of channels given as a count or as names (checked: a whole number or a sequence).

    Examples
    --------
    >>> from awr_denoise.channels import channel_count
    >>> channel_count(3), channel_count(["R", "G", "B", "A"])
    (3, 4)
    """
    channels = _names_or_count(channels, "__len__")
    if isinstance(channels, (int, np.integer)):
        return _checks.whole("channels", channels, minimum=1, maximum=MAX_CHANNELS)  # type: ignore[return-value]
    return len(channels)
