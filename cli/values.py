"""Option value types for ``argparse``: numbers checked where they are parsed.

A bad value (``--exposure nan``, ``--spp inf``, ``--seed 1e30``, ``--levels 100``) becomes a
usage error naming the option before anything is read, rendered or written. The bounds are
those of the files and arrays the values end up in, named once here.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable

from awr_denoise import _checks
from awr_denoise.features import feature_names
from awr_denoise.wavelets import WAVELET_NAMES

from .errors import UsageError

__all__ = ["MAX_SPP", "MAX_SEED", "MAX_PIXELS", "MAX_SIDE", "MAX_LEVELS", "MAX_EXPOSURE", "MAX_FRAMES",
           "MAX_ROUND_GROWTH", "UNSET", "real", "whole", "or_unset", "nonempty", "image_size", "check_pixels",
           "wavelet_name", "feature_list"]

MAX_SPP = _checks.MAX_SPP
"""Samples per pixel: counts are stored as float32, exact up to 2**24."""
MAX_SEED = 2**63 - 1
"""Seeds are non-negative and fit a signed 64-bit integer."""
MAX_SIDE = 2**20
"""Largest image side in pixels."""
MAX_PIXELS = 2**28
"""Largest image in pixels (16384 x 16384); a reconstruction needs about 5.5 x 57 bytes per pixel
(docs/robustness.md, section 7), 80 GiB at this size."""
MAX_LEVELS = 32
"""Wavelet levels beyond this exceed any image side (the exact bound depends on the size)."""
MAX_EXPOSURE = 1000.0
"""Preview exposure in stops (2**1000 already saturates every positive float64)."""
MAX_FRAMES = 1_000_000
"""Frames one ``--frames`` range may name."""
MAX_ROUND_GROWTH = 1e6
"""The largest ``--round-growth``: a round of a million times the samples so far."""
UNSET = 0
"""What :func:`or_unset` parses its word to: no value (no cap, the automatic depth), where 0 is never one."""


_REAL = re.compile(r"\s*[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|inf(?:inity)?|nan)\s*",
                   re.IGNORECASE)


def real(*, minimum: float | None = None, maximum: float | None = None, above: float | None = None,
         name: str = "number") -> Callable[[str], float]:
    """An argparse type: a finite float within bounds (``above`` is an open lower bound)."""

    def parse(text: str) -> float:
        try:
            if not _REAL.fullmatch(text):  # Python's float() also reads '1_0' as 10 and other scripts' digits
                raise ValueError(text)
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {name}, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite {name}, got {text!r}")
        if above is not None and not value > above:
            raise argparse.ArgumentTypeError(f"must be > {above:.15g}, got {text}")
        if minimum is not None and value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum:.15g}, got {text}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"must be <= {maximum:.15g}, got {text}")
        return value

    parse.__name__ = name
    return parse


whole = _checks.whole_option
"""An argparse type: an integer within bounds (``1.5``, ``1e3`` and ``inf`` are refused)."""


def or_unset(parse: Callable[[str], int], word: str) -> Callable[[str], int]:
    """An argparse type: ``parse``'s values (all above 0), or ``word`` for none (:data:`UNSET`): ``awr plan
    --spp-max none`` lifts a cap the running dump carries, ``--levels auto`` the depth it carries."""

    def parse_or_unset(text: str) -> int:
        return UNSET if text == word else parse(text)

    parse_or_unset.__name__ = getattr(parse, "__name__", "value")
    return parse_or_unset


def _too_many_pixels(height: int, width: int) -> str | None:
    if height > MAX_SIDE or width > MAX_SIDE:  # the side at fault, not a pixel count within the limit
        return f"{width}x{height}: a side of {max(height, width)} pixels; sides up to {MAX_SIDE} are supported"
    if height * width > MAX_PIXELS:
        side = math.isqrt(MAX_PIXELS)
        return (f"{width}x{height} is {width * height} pixels; at most {MAX_PIXELS} ({side}x{side}) "
                f"with sides up to {MAX_SIDE} are supported")
    return None


def check_pixels(option: str, height: int, width: int) -> None:
    """Refuse an image size beyond :data:`MAX_SIDE` or :data:`MAX_PIXELS`, naming ``option``."""
    problem = _too_many_pixels(height, width)
    if problem:
        raise UsageError(f"{option}: {problem}")


def image_size(text: str) -> tuple[int, int]:
    """An argparse type: ``WIDTHxHEIGHT`` as (H, W), each side >= 1, within the size limits."""
    m = re.fullmatch(r"\s*([0-9]{1,9})\s*[xX]\s*([0-9]{1,9})\s*", text)
    if not m or int(m.group(1)) <= 0 or int(m.group(2)) <= 0:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 640x480, got {text!r}")
    width, height = int(m.group(1)), int(m.group(2))
    problem = _too_many_pixels(height, width)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return height, width


def nonempty(text: str) -> str:
    """An argparse type: a name that is not empty (a plane, a file, a layer, a view). An empty one, from a
    script's unset variable (``--alb "$ALB"``), was taken as no option at all, or refused by a message
    about something else (the default colour's variance, the folder ``.``)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"an empty name ({text!r})")
    return text


def wavelet_name(text: str) -> str:
    """An argparse type: a discrete wavelet PyWavelets knows."""
    if text not in WAVELET_NAMES:
        raise argparse.ArgumentTypeError(f"{text!r} is not a discrete wavelet PyWavelets knows "
                                         "(for example bior4.4, haar, db2)")
    if text == "dmey":  # denoise refused it after reading, plan took it: every command refuses it here
        raise argparse.ArgumentTypeError("'dmey' (PyWavelets' discrete Meyer) is not a perfect-reconstruction "
                                         "filter bank, which the reconstruction's Wiener stages need")
    return text


def feature_list(text: str) -> tuple[str, ...]:
    """An argparse type: feature names, comma separated, or ``all`` (``albedo,normal,depth``)."""
    try:
        names = feature_names(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("features: ")) from None
    if not names:
        raise argparse.ArgumentTypeError(f"no feature named in {text!r} (albedo, normal, depth or all)")
    return names
