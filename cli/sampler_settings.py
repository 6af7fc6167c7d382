"""The sampler settings a run carries through its files, for ``awr plan`` to continue.

``awr render`` and ``awr plan`` write the settings their sampler ranked with into the running dump and the
request; ``awr merge`` carries a request's into the dump it tells; the next ``awr plan`` takes them where its
own option is not given. Without them a run planned through files with ``--rare-paths zeros`` or ``--noise-model
levels`` went back to the defaults at the first ``plan`` that did not repeat the option, silently.
"""

from __future__ import annotations

import math
import os
import re
from typing import Any

from awr_denoise.errors import InputFileError
from awr_denoise.io.dump import header_count
from awr_denoise.io.exr import header_value
from awr_denoise.rare_paths import RARE_PATHS
from awr_denoise.sampling import NOISE_MODELS, Sampler
from awr_denoise.wavelets import WAVELET_NAMES

from .values import MAX_LEVELS, MAX_SPP

__all__ = ["CARRIED", "carried_settings", "sampler_settings"]

CARRIED: tuple[tuple[str, str, str, tuple[str, ...]], ...] = (
    # (the samplers' keyword, the header attribute, plan's option, the strategies that use it)
    ("round_growth", "awr:round_growth", "--round-growth", ("awr", "uniform", "variance")),
    ("spp_max", "awr:spp_max", "--spp-max", ("awr", "uniform", "variance")),
    ("rare_paths", "awr:rare_paths", "--rare-paths", ("awr", "variance")),
    ("noise_model", "awr:noise_model", "--noise-model", ("awr",)),
    ("wavelet", "awr:priority_wavelet", "--wavelet", ("awr",)),
    ("levels", "awr:priority_levels", "--levels", ("awr",)),
)
"""The settings a request and a running dump carry beside ``awr:strategy`` and ``awr:initial_spp``."""

MAX_ROUND_GROWTH = 1e6
"""The largest ``--round-growth`` (and ``awr:round_growth``)."""

_REAL = re.compile(r"[+]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")


def sampler_settings(sampler: Sampler) -> dict[str, int | str]:
    """The header attributes of ``sampler``'s carried settings (:data:`CARRIED`) for its strategy.

    A setting left automatic (``levels=None``, no ``spp_max``) is not written. The round growth is written as
    text: an EXR float attribute is 32-bit, and 0.3 would come back as 0.30000001.
    """
    out: dict[str, int | str] = {}
    for name, key, _, strategies in CARRIED:
        value = getattr(sampler, name, None)
        if sampler.strategy in strategies and value is not None:
            out[key] = repr(float(value)) if name == "round_growth" else value
    return out


def carried_settings(path: str | os.PathLike[str], attributes: dict, strategy: str | None = None) -> dict[str, Any]:
    """The samplers' keywords a running dump or request carries (:data:`CARRIED`), those of ``strategy`` only
    when it is given, each checked and refused naming the file and the attribute."""
    out: dict[str, Any] = {}
    for name, key, _, strategies in CARRIED:
        if key not in attributes or (strategy is not None and strategy not in strategies):
            continue
        raw = header_value(attributes, key)
        if name in ("spp_max", "levels"):
            out[name] = header_count(path, attributes, key, 1, MAX_SPP if name == "spp_max" else MAX_LEVELS, low=1)
            continue
        text = str(raw).strip()
        if name == "round_growth":
            value = float(text) if _REAL.fullmatch(text) else math.nan
            if not 0 < value <= MAX_ROUND_GROWTH:
                raise InputFileError(f"{path}: {key}: {raw!r} is not a number above 0 and at most "
                                     f"{MAX_ROUND_GROWTH:g}")
            out[name] = value
            continue
        if name == "wavelet":
            if text not in WAVELET_NAMES or text == "dmey":  # as plan's --wavelet
                raise InputFileError(f"{path}: {key}: {raw!r} is not a wavelet the priorities take (for example "
                                     "bior4.4, haar, db2)")
        elif text not in (choices := RARE_PATHS if name == "rare_paths" else NOISE_MODELS):
            raise InputFileError(f"{path}: {key}: {raw!r} is not one of {', '.join(choices)}")
        out[name] = text
    return out
