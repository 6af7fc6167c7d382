"""The ``awr:*`` header attributes that say how a file was made: built here, and only here.

Every file the project writes carries ``awr:version``; a denoised image also records the
reconstruction's resolved settings (the depth actually used, never a "default" placeholder),
what it was made from and how much thresholding did; a render records its scene, seed and
strategy. Keys use the ``awr:`` prefix; values are ints, floats or strings (what EXR
attributes can hold).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

from .._version import __version__
from ..buffers import SampleBuffer
from ..reconstruct import Reconstruction
from .exr import header_value

__all__ = ["PREFIX", "provenance", "image_provenance", "read_provenance"]

PREFIX = "awr:"
"""Prefix of every attribute the project writes."""

# Reference renders of earlier versions wrote ``awr_*`` keys; they are still read.
_LEGACY_PREFIX = "awr_"


def _value(key: str, value: Any) -> int | float | str:
    """An attribute value EXR can hold (bools and None become strings)."""
    if isinstance(value, bool) or value is None:
        return str(value).lower()
    if isinstance(value, (int, float, str)):
        return value
    if hasattr(value, "item"):  # numpy scalars
        return _value(key, value.item())
    raise TypeError(f"{key}: provenance values are numbers or strings, got {type(value).__name__}")


def provenance(**fields: Any) -> dict[str, int | float | str]:
    """``awr:``-prefixed attributes from keyword fields, with ``awr:version``.

    Examples
    --------
    >>> from awr_denoise.io.provenance import provenance
    >>> provenance(scene="default", seed=3)["awr:seed"]
    3
    >>> sorted(provenance(scene="default"))
    ['awr:scene', 'awr:version']
    """
    header: dict[str, int | float | str] = {PREFIX + "version": __version__}
    header.update({PREFIX + key: _value(key, value) for key, value in fields.items()})
    return header


def image_provenance(result: Reconstruction, buffer: SampleBuffer, *, source: str | os.PathLike[str] | None = None,
                     **fields: Any) -> dict[str, int | float | str]:
    """The attributes of a denoised image: its reconstruction's settings, input and outcome.

    Parameters
    ----------
    result
        The reconstruction (its :attr:`~awr_denoise.Reconstruction.parameters` are recorded).
    buffer
        The statistics it was made from (average spp, non-finite samples dropped on input).
    source
        The input file; its name (not its directory) is recorded as ``awr:input``.
    **fields
        Further attributes, e.g. ``scene="default"``.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer, reconstruct_detailed
    >>> from awr_denoise.io.provenance import image_provenance
    >>> buffer = SampleBuffer.from_moments(np.full((16, 16), 4), np.ones((16, 16, 3)), np.ones((16, 16, 3)))
    >>> header = image_provenance(reconstruct_detailed(buffer, variance_probes=0), buffer, source="out/a.exr")
    >>> header["awr:input"], header["awr:levels"], header["awr:spp"]
    ('a.exr', 1, 4.0)
    """
    parameters = {key: value for key, value in result.parameters.items() if value is not None}
    header = provenance(**parameters)
    header[PREFIX + "spp"] = float(buffer.total_samples / buffer.count.size)
    header[PREFIX + "fraction_zeroed"] = float(result.fraction_zeroed)
    header[PREFIX + "nonfinite"] = int(buffer.nonfinite)
    if source is not None:
        header[PREFIX + "input"] = os.path.basename(os.fspath(source))
    header.update(provenance(**fields))
    return header


def read_provenance(header: Mapping[str, Any]) -> dict[str, Any]:
    """The ``awr:`` attributes of a header, keyed without the prefix (older ``awr_`` keys too).

    Examples
    --------
    >>> from awr_denoise.io.provenance import read_provenance
    >>> read_provenance({"awr:spp": 4, "awr_seed": "7", "owner": "me"})
    {'spp': 4, 'seed': '7'}
    """
    out: dict[str, Any] = {}
    for key in header:
        for prefix in (PREFIX, _LEGACY_PREFIX):
            if str(key).startswith(prefix) and key[len(prefix):] not in out:
                out[key[len(prefix):]] = header_value(header, key)
    return out
