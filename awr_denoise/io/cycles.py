"""Blender Cycles multilayer EXR: view layers, passes, views and the sample-count pass.

Blender writes ``<layer>.<pass>.<component>`` channels, one part per pass (and per view for a
stereo or multiview render, each part carrying a ``view`` attribute). Layer names may contain
dots (``beauty.main``) and pass names spaces (``Debug Sample Count``), so names are split from
the right: the last field is the component, the one before it the pass, the rest the layer, as
Blender's own readers do.

``Debug Sample Count`` holds each pixel's count divided by the number of samples the render
*actually* took, while the header's ``cycles.<layer>.samples`` holds the number *requested*:
they differ when adaptive sampling converged everywhere early or a time limit stopped the
render. :func:`sample_count_scale` recovers the divisor from the data.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

__all__ = ["ADAPTIVE_STEP", "COUNT_PASS", "CyclesChannel", "split_channel", "cycles_layers", "sample_count_scale"]

ADAPTIVE_STEP = 16
"""Samples between two adaptive-sampling convergence checks in Cycles (``adaptive_step``,
``scene/integrator.cpp``, Blender 3.0 to 5.0): pixel counts differ by multiples of it."""

# Passes whose presence marks a Cycles view layer (the colour sources, in order of preference).
COLOUR_PASSES = ("Noisy Image", "Combined")

COUNT_PASS = "Debug Sample Count"
"""The pass of every pixel's sample count, normalised (:func:`sample_count_scale`)."""


@dataclass(frozen=True)
class CyclesChannel:
    """A channel name split into view layer, pass and component."""

    layer: str
    pass_name: str
    component: str


def split_channel(name: str) -> CyclesChannel | None:
    """Split ``layer.pass.component`` from the right; None for names with fewer than three fields.

    Examples
    --------
    >>> split_channel("beauty.main.Debug Sample Count.X")
    CyclesChannel(layer='beauty.main', pass_name='Debug Sample Count', component='X')
    """
    fields = name.rsplit(".", 2)
    if len(fields) != 3 or not all(fields):
        return None
    return CyclesChannel(*fields)


def cycles_layers(channels: Iterable[str]) -> dict[str, set[str]]:
    """View layer -> its pass names, for layers that have a colour pass (Combined or Noisy Image)."""
    passes: dict[str, set[str]] = {}
    for name in channels:
        parsed = split_channel(name)
        if parsed is not None:
            passes.setdefault(parsed.layer, set()).add(parsed.pass_name)
    return {layer: p for layer, p in passes.items() if p & set(COLOUR_PASSES)}


def _smallest_denominator(values: np.ndarray, limit: int) -> int | None:
    """Smallest d <= limit with every value * d a whole number (float32 rounding allowed)."""
    for d in range(1, limit + 1):
        scaled = values * d
        if np.all(np.abs(scaled - np.rint(scaled)) <= 1e-4 * np.maximum(1.0, scaled)):
            return d
    return None


def sample_count_scale(normalised: np.ndarray, requested: int | None, *,
                       step: int = ADAPTIVE_STEP) -> tuple[int, str]:
    """The number of samples Cycles divided ``Debug Sample Count`` by, derived from the data.

    Parameters
    ----------
    normalised
        The pass: per-pixel counts divided by the samples the render actually took, so the
        pixel(s) that got the most samples hold 1.
    requested
        The header's ``cycles.<layer>.samples`` (samples requested), an upper bound; None if
        absent.
    step
        Adaptive sampling's step (:data:`ADAPTIVE_STEP`).

    Returns
    -------
    tuple
        (divisor, how it was found), the second a short sentence for notes.

    Notes
    -----
    The values are ``c_p / S``. The smallest ``d`` making every ``value * d`` whole gives the
    counts up to a common factor ``k`` (``S = k d``). Adaptive sampling stops pixels only at
    convergence checks, ``step`` samples apart, so counts differ by multiples of ``step``;
    assuming the finest difference seen is one step (true as soon as two pixels stopped at
    consecutive checks) fixes ``k = step / D`` with ``D`` the gcd of the differences of
    ``value * d``. A render whose sample count is off the checks' grid (100: checks at 16, 32,
    ..., 96) stops its last pixels at ``S`` itself, one step or less after the last check: the
    differences are then taken below the top value, and where that leaves fewer than two values,
    the requested number is taken if it puts every count below the top on the grid. When every
    pixel has the same count (all values 1) the pass says nothing about ``S`` and the requested
    number is taken. Checked on real Blender 5.0 renders: a render
    asking for 256 samples that converged at 64 is bit-identical to one asking for 64, and this
    returns 64 for it (tests/io/test_io_cycles.py).

    Examples
    --------
    >>> import numpy as np
    >>> sample_count_scale(np.array([48, 64, 64]) / 64, 256)
    (64, 'adaptive counts differ by multiples of 16 samples: 64 samples rendered (256 requested)')
    >>> sample_count_scale(np.array([48, 64, 96, 100]) / 100, 100)[0]     # the last check is 96
    100
    """
    values = np.unique(np.asarray(normalised, dtype=np.float64))
    values = values[values > 0]
    if requested is not None and requested < 1:
        requested = None
    if values.size == 0:
        raise ValueError("the sample count pass is zero everywhere")
    if values[-1] > 1.0 + 1e-6:  # one stray value would rescale every pixel's count
        raise ValueError(f"the sample count pass reaches {values[-1]:.6g}; Cycles divides the counts by the "
                         "samples taken, so no pixel holds more than 1")
    if values.size == 1:
        if requested is None:
            raise ValueError("every pixel has the same normalised count and the header has no "
                             "requested sample count")
        return requested, (f"every pixel has the same count: taken as the {requested} samples requested "
                           "(a time limit or early convergence would make it fewer: pass spp=)")
    limit = requested if requested is not None else 1 << 20
    d = _smallest_denominator(values, limit)
    if d is None:
        raise ValueError(f"normalised counts are not whole numbers of 1/S for any S up to {limit}")
    whole = np.rint(values * d).astype(np.int64)
    readings = []
    for below, rule in ((whole, f"adaptive counts differ by multiples of {step} samples"),
                        # A render whose end is off the checks' grid (S = 100): the top pixels stopped at S.
                        (whole[:-1], f"adaptive counts below the top differ by multiples of {step} samples, the "
                                     "top pixels ran to the end of the render")):
        gcd = int(np.gcd.reduce(np.diff(below))) if below.size > 1 else 0
        if gcd and step % gcd == 0 and (requested is None or d * (step // gcd) <= requested):
            readings.append((d * (step // gcd), rule))
    if requested is None and len({scale for scale, _ in readings}) > 1:
        # Without the header's bound both can fit: S = 100 with pixels stopped at 16, 32, ..., 96 and 100 is S = 400
        # with pixels stopped at 64, 128, ..., 384 and 400; the first reading was taken, every count 4x too high,
        # with a note only (an attack pass on a file without cycles.<layer>.samples).
        (many, _), (few, _) = readings
        raise ValueError(f"the counts fit {many} samples rendered (every pixel stopped at a convergence check) and "
                         f"{few} (the top pixels ran to the end between two checks), and the header has no requested "
                         "sample count to tell them apart")
    if readings:
        scale, rule = readings[0]
        how = f"{rule}: {scale} samples rendered"
    else:
        if requested is not None and requested % d == 0 and all(int(w) * (requested // d) % step == 0
                                                                for w in whole[:-1]):
            scale = requested  # every count below the top on the checks' grid: the render ran to its end
            how = f"adaptive counts below the top are multiples of {step} samples: {scale} samples rendered"
        else:  # not the adaptive pattern: the smallest consistent divisor, a guess below the requested
            scale = d
            how = f"the smallest whole-number scale is {scale} samples" + (
                "" if scale == requested else ": a guess (pass spp= if it is not)")
    if requested is not None:
        how += f" ({requested} requested)"
    return scale, how
