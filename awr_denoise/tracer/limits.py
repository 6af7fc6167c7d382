"""Bounds on a scene's numbers, and the field checks the scene parsers share.

The tracer computes in float64 but traces in float32 (Embree) and stores its buffers as float32:
a number finite in float64 can still overflow there. Such a scene used to render without a
word, all black (a vertex at 1e39 is Inf in float32 and every ray misses the whole BVH), or to
fail only when the image was written, blaming the output file. The parsers refuse it instead,
naming the field, with the bounds below.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["MAX_COORDINATE", "MAX_RADIANCE", "shown", "numbers", "in_range", "vector", "rgb_radiance", "reach",
           "check_reach", "check_radiance", "refuse_unknown"]

MAX_COORDINATE = 1e11
"""Largest coordinate (scene units, either sign) of any vertex over the shutter, and of the camera and point lights.

Embree intersects in float32, and its ray-triangle test multiplies three lengths: Möller-Trumbore's
``T = Ng . (v0 - o)``, ``Ng`` the unnormalised cross product of two edges, reaches about 40 B**3 for
coordinates within ±B (ray origins too: a lens, a moving object's own space put them a little further).
float32 ends at 3.4e38, so a bound that only keeps squared lengths finite (1e15) is not enough: measured,
a triangle spanning ±2e12 already loses its hits, the default scene scaled by 1e13 most of them.
At 1e11 the product stays about 1e4 times below the end. No scene needs more: float32 holds 7 digits,
so a scene 1e11 units across resolves nothing finer than 1e4 of its units.
"""

MAX_RADIANCE = 1e15
"""Largest emitted radiance, light intensity or irradiance, and environment radiance (after its ``scale``).

A sample is a light's radiance times the path's throughput, and the buffers written hold its square
(the variance) as float32, which ends at 3.4e38. With lights at most 1e15 the square stays near 1e30,
leaving a factor of 3e8 for the geometry that lifts a sample above its light (an inverse squared
distance, a 1 / pdf). The bundled sky's sun is 600: the bound leaves twelve orders of magnitude.
"""


def shown(value: Any) -> str:
    """``repr(value)``, cut short: a refusal stays one readable line."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def refuse_unknown(where: str, spec: dict[str, Any], known: set[str] | frozenset[str]) -> None:
    """A ValueError naming the fields of ``spec`` not in ``known`` (a typo would otherwise do nothing)."""
    unknown = set(spec) - set(known)
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {sorted(unknown)}; valid: {sorted(known)}")


def numbers(where: str, value: Any, what: str = "numbers") -> np.ndarray:
    """``value`` (a JSON number or nested lists of them) as a float64 array; refused, naming ``where``, when
    any entry is not a number: strings and booleans (``"0.5"``, ``true``), which ``np.asarray(..., float)``
    converted without a word, an integer past float64 (an internal ``OverflowError``) or ragged lists.

    Examples
    --------
    >>> from awr_denoise.tracer.limits import numbers
    >>> numbers("albedo", [0.5, 1, 0.25])
    array([0.5 , 1.  , 0.25])
    >>> numbers("albedo", ["0.5", "0.5", "0.5"])
    Traceback (most recent call last):
    ...
    ValueError: albedo: expected numbers, got ['0.5', '0.5', '0.5']
    """
    try:
        array = np.asarray(value)
    except (TypeError, ValueError, OverflowError):  # ragged lists
        array = np.empty(0, object)
    # Integers and floats only: kind "b" (booleans), "U" (strings), "O" (mixed, ints past int64) refused,
    # and booleans among numbers, which numpy makes numbers ([false, true, 2]: a face of vertices 0, 1, 2).
    if array.dtype.kind not in "iuf" or (array.size and not isinstance(value, np.ndarray)
                                         and bool in set(map(type, np.asarray(value, dtype=object).ravel()))):
        raise ValueError(f"{where}: expected {what}, got {shown(value)}")
    with np.errstate(over="ignore"):  # a uint64 or float beyond float64 cannot occur; an int64 fits
        return array.astype(np.float64)


def in_range(where: str, direction: np.ndarray) -> np.ndarray:
    """``direction`` scaled by a power of two (exact) into lengths whose squares neither overflow nor
    underflow; unchanged when they do not, so a direction normalises to the same bits as before. A zero
    vector is refused, naming ``where``. A light direction of 1e200 normalised to zero (its square past
    float64: the light dropped), a motion axis of 1e-170 was refused as zero (a red-team pass).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.tracer.limits import in_range
    >>> in_range("axis", np.array([0.0, 1e200, 0.0])) / np.linalg.norm(in_range("axis", np.array([0.0, 1e200, 0.0])))
    array([0., 1., 0.])
    """
    largest = float(np.abs(direction).max(initial=0.0))
    if not largest > 0:
        raise ValueError(f"{where}: must be non-zero")
    if 2.0**-500 <= largest <= 2.0**500:
        return direction
    return np.ldexp(direction, -math.frexp(largest)[1])


def vector(spec: dict[str, Any], key: str, where: str, default: Any = None) -> np.ndarray:
    """The field ``where.key`` as 3 finite numbers (``default`` when absent; absent without one: refused)."""
    if key not in spec and default is None:
        raise ValueError(f"{where}.{key}: missing")
    what = "3 finite numbers"
    value = numbers(f"{where}.{key}", spec.get(key, default), what)
    if value.shape != (3,) or not np.all(np.isfinite(value)):
        raise ValueError(f"{where}.{key}: expected {what}, got {shown(spec.get(key))}")
    return value


def reach(points: Any) -> float:
    """The largest coordinate of ``points`` in absolute value (inf when any is NaN: a shape past float64)."""
    points = np.asarray(points, np.float64)
    if not points.size:
        return 0.0
    if np.isnan(points).any():
        return float("inf")
    return float(np.abs(points).max())


def check_reach(where: str, distance: float, what: str = "") -> None:
    """Refuse, naming ``where``, a ``distance`` (a coordinate, a length) beyond :data:`MAX_COORDINATE`."""
    if not distance <= MAX_COORDINATE:
        said = f"{what} reaches {distance:g}," if what else f"{distance:g} is"
        raise ValueError(f"{where}: {said} beyond the ±{MAX_COORDINATE:g} scene units the tracer traces in "
                         "(float32)")


def check_radiance(where: str, peak: float, what: str = "") -> None:
    """Refuse, naming ``where``, a radiance ``peak`` beyond :data:`MAX_RADIANCE`."""
    if not peak <= MAX_RADIANCE:
        said = f"{what} reaches {peak:g}," if what else f"{peak:g} is"
        raise ValueError(f"{where}: {said} beyond the {MAX_RADIANCE:g} a radiance may reach (a sample's "
                         "square, its variance, must stay within float32)")


def rgb_radiance(where: str, value: Any) -> np.ndarray:
    """``value`` (a number or 3) as RGB: finite, >= 0, at most :data:`MAX_RADIANCE`; else refused, named ``where``."""
    what = "a number or 3 numbers"
    try:
        rgb = np.broadcast_to(numbers(where, value, what), (3,)).copy()
    except ValueError:
        raise ValueError(f"{where}: expected {what}, got {shown(value)}") from None
    if not np.all(np.isfinite(rgb)) or np.any(rgb < 0):
        raise ValueError(f"{where}: must be finite and >= 0, got {shown(value)}")
    check_radiance(where, float(rgb.max()))
    return rgb
