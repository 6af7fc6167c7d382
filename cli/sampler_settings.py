"""The sampler settings a run carries through its files, for ``awr plan`` to continue.

``awr render`` and ``awr plan`` write the settings their sampler ranked with into the running dump and the
request; ``awr merge`` carries a request's into the dump it tells; the next ``awr plan`` takes them where its
own option is not given. Without them a run planned through files with ``--rare-paths zeros`` or ``--noise-model
levels`` went back to the defaults at the first ``plan`` that did not repeat the option, silently.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Collection
from typing import Any

from awr_denoise.errors import InputFileError
from awr_denoise.io.dump import header_count
from awr_denoise.io.exr import brief, header_value
from awr_denoise.noise_gain import DEFAULT_NOISE_MODEL
from awr_denoise.rare_paths import DEFAULT_RARE_PATHS, RARE_PATHS
from awr_denoise.sampling import DEFAULT_ROUND_GROWTH, NOISE_MODELS, AdaptiveSampler, Sampler
from awr_denoise.wavelets import DEFAULT_WAVELET, max_levels

from .values import MAX_LEVELS, MAX_ROUND_GROWTH, MAX_SPP, real, wavelet_name

__all__ = ["CARRIED", "DEFAULTS", "carried_settings", "sampler_settings", "described"]

CARRIED: tuple[tuple[str, str, str, tuple[str, ...]], ...] = (
    # (the samplers' keyword, the header attribute, plan's option, the strategies that use it)
    ("round_growth", "awr:round_growth", "--round-growth", ("awr", "uniform", "variance")),
    ("spp_max", "awr:spp_max", "--spp-max", ("awr", "uniform", "variance")),
    ("rare_paths", "awr:rare_paths", "--rare-paths", ("awr", "variance")),
    ("noise_model", "awr:noise_model", "--noise-model", ("awr",)),
    ("wavelet", "awr:priority_wavelet", "--wavelet", ("awr",)),
    ("levels", "awr:priority_levels", "--levels", ("awr",)),
)
"""The settings a request and a running dump carry beside ``awr:strategy`` and ``awr:initial_spp``; each keeps one
meaning and one default in every strategy that uses it, so a new strategy takes those it uses."""

DEFAULTS: dict[str, Any] = {"round_growth": DEFAULT_ROUND_GROWTH, "spp_max": None, "rare_paths": DEFAULT_RARE_PATHS,
                             "noise_model": DEFAULT_NOISE_MODEL, "wavelet": DEFAULT_WAVELET, "levels": None}
"""Each setting's value when neither an option nor the dump gives it (the samplers' defaults)."""

_GROWTH = real(above=0, maximum=MAX_ROUND_GROWTH)


def described(settings: dict[str, Any]) -> str:
    """The settings of ``settings`` (samplers' keywords) that differ from :data:`DEFAULTS`, as plan's options in
    :data:`CARRIED`'s order (``--spp-max 64, --rare-paths zeros``): what a run carries that its user may have
    forgotten giving. A growth is shown exactly, as the request records it (``0.3``, ``1``)."""
    shown = {name: str(value).removesuffix(".0") if isinstance(value, float) else str(value)
             for name, value in settings.items() if value != DEFAULTS[name]}
    return ", ".join(f"{option} {shown[name]}" for name, _, option, _ in CARRIED if name in shown)


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


def carried_settings(path: str | os.PathLike[str], attributes: dict, strategy: str | None,
                     shape: tuple[int, int] | None = None, *, names: Collection[str] | None = None) -> dict[str, Any]:
    """The samplers' keywords a running dump or request carries for ``strategy`` (its ``awr:strategy``; ``None``
    for none, which plan reads as ``awr``), each checked as ``plan`` checks it and refused naming the file and the
    attribute: the depth against the image of ``shape`` too, when it is given. The settings of other strategies
    are neither read nor checked: no plan of this run uses them; with ``names``, only those keywords are."""
    strategy = strategy or AdaptiveSampler.strategy
    out: dict[str, Any] = {}
    for name, key, _, strategies in CARRIED:
        if key not in attributes or strategy not in strategies or (names is not None and name not in names):
            continue
        raw = header_value(attributes, key)
        if name in ("spp_max", "levels"):
            out[name] = header_count(path, attributes, key, 1, MAX_SPP if name == "spp_max" else MAX_LEVELS, low=1)
            if name == "levels" and shape is not None and out[name] > max_levels(shape):
                raise InputFileError(f"{path}: {key}: {out[name]} is outside 1..{max_levels(shape)} for its image")
            continue
        text = str(raw).strip()
        try:
            if name == "round_growth":
                out[name] = _GROWTH(text)
            elif name == "wavelet":
                out[name] = wavelet_name(text)
            elif text in (choices := RARE_PATHS if name == "rare_paths" else NOISE_MODELS):
                out[name] = text
            else:
                raise argparse.ArgumentTypeError(f"is not one of {', '.join(choices)}")
        except argparse.ArgumentTypeError as exc:
            reason = (f"is not a number above 0 and at most {MAX_ROUND_GROWTH:g}" if name == "round_growth"
                      else str(exc).split("' ", 1)[-1] if name == "wavelet" else str(exc))  # the value shown once
            raise InputFileError(f"{path}: {key}: {brief(raw)} {reason}") from None
    return out
