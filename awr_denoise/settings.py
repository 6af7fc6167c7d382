"""The reconstruction's stage settings: their defaults, chosen by measurement, and their checks.

:func:`~awr_denoise.reconstruct.reconstruct_detailed` and the tiled reconstruction
(:func:`~awr_denoise.parallel.reconstruct_tiled`) resolve the same settings here, before any work
(docs/reconstruction.md has the measurements behind every default).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from . import _checks
from .stationary import DTYPES
from .sure import DEFAULT_SPARED_BESIDE, DEFAULT_TOLERANCE, DEFAULT_WINDOW
from .wiener import DEFAULT_FLOOR

__all__ = ["Settings", "resolve_settings", "DEFAULT_C_S", "DEFAULT_PILOT_C_S", "DEFAULT_PIXEL_CLAMP",
           "DEFAULT_STAGES", "DEFAULT_WIENER_EXPONENTS", "DEFAULT_PRECISION", "PRECISIONS"]

DEFAULT_C_S = 1.0
"""``c_s`` of Eq. 11 when stage 1 is the whole reconstruction (``stages=1``): one standard error."""

DEFAULT_PILOT_C_S = 2.0
"""``c_s`` of stage 1 when it is the pilot of Wiener stages; chosen by measurement on both renderers: 2 rather
than 1.5 since the first Wiener stage's energy floor gives back, from the means, the faint detail a stricter
pilot removes (docs/reconstruction.md, "The pilot's threshold, measured")."""

DEFAULT_PIXEL_CLAMP = 2.5
"""Default pixel confidence clamp in standard errors; chosen by measurement (docs/reconstruction.md)."""

DEFAULT_STAGES = 3
"""Stage 1 (Eq. 10-11) and the Wiener stages after it; chosen by measurement (docs/reconstruction.md)."""

DEFAULT_WIENER_EXPONENTS = (0.75, 0.4)
"""``alpha`` of each Wiener stage's domain ``x / (|pilot| + k)^alpha``: mostly relative, then closer to linear.
Measured (docs/reconstruction.md): a more relative first stage keeps the noise of bright regions out of dark
ones; a closer-to-linear last one keeps bright pixels from being pulled to their surroundings, and is the one
``stages=2`` keeps (1-15% lower relMSE than the first alone, on every scene of both renderers)."""

PRECISIONS = DTYPES
"""Precisions of stage 1 (log domain) and the Wiener stages' FFTs: ``"float64"`` (the reference), ``"float32"``."""

DEFAULT_PRECISION = "float32"
"""Default precision of stage 1 and the Wiener stages' FFTs (statistics stay float64; docs/reconstruction.md)."""

_MAX_PROBES = 100_000  # each probe is a transform pair per channel; more is never meant



def _exponents(value: Sequence[float]) -> tuple[float, ...]:
    # A 1-D array is a sequence of numbers too (it was refused as none, an attack pass); a 0-d one is a number.
    if isinstance(value, np.ndarray) and value.ndim == 1:
        value = value.tolist()
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise TypeError(f"wiener_exponents: expected a sequence of numbers in [0, 1], got {_checks.described(value)}")
    return tuple(_checks.real("wiener_exponents", a, minimum=0, maximum=1) for a in value)  # type: ignore[misc]


@dataclass(frozen=True)
class Settings:
    """The stage settings of one reconstruction, checked and resolved (defaults filled in)."""

    c_s: float
    stages: int
    exponents: tuple[float, ...]
    pixel_clamp: float | None
    guard: bool
    preserve_mean: bool
    nonnegative: bool
    precision: str
    probes: int
    seed: int
    floor: tuple[int, float] | None = DEFAULT_FLOOR  # the first Wiener stage's (window, margin); channel mode
    guard_window: int = DEFAULT_WINDOW  # side of the guard's square neighbourhood
    guard_probes: int = 0  # probes of the Wiener stages' divergence for the guard; 0: their diagonal
    guard_tolerance: float = DEFAULT_TOLERANCE  # the guard's (sure.sure_blend); sure.DEFAULT_GUIDED_TOLERANCE guided
    guard_spared_beside: float | None = DEFAULT_SPARED_BESIDE  # sure_blend's spared_beside; None guided

    @property
    def stage1_clamp(self) -> float | None:
        """Stage 1's pixel clamp: only where stage 1 is the output (a clamped pilot measured worse)."""
        return self.pixel_clamp if self.stages == 1 else None

    def recorded(self) -> dict:
        """What a file's provenance records of them."""
        wiener = self.stages > 1
        return {"c_s": self.c_s, "pixel_clamp": self.pixel_clamp, "stages": self.stages,
                "wiener_exponents": ",".join(f"{a:g}" for a in self.exponents) if wiener else None,
                "guard": self.guard, "guard_window": self.guard_window if self.guard else None,
                "guard_probes": self.guard_probes if self.guard else None,
                "guard_tolerance": self.guard_tolerance if self.guard else None,
                "guard_spared_beside": self.guard_spared_beside if self.guard else None,
                "preserve_mean": self.preserve_mean, "nonnegative": self.nonnegative, "precision": self.precision}


def resolve_settings(*, c_s: float | None = None, stages: int = DEFAULT_STAGES,
                     wiener_exponents: Sequence[float] = DEFAULT_WIENER_EXPONENTS,
                     pixel_clamp: float | None = DEFAULT_PIXEL_CLAMP, guard: bool | None = None,
                     preserve_mean: bool | None = None, nonnegative: bool | None = None,
                     precision: str = DEFAULT_PRECISION, variance_probes: int = 0, seed: int = 0,
                     guard_window: int | None = None, guard_probes: int | None = None) -> Settings:
    """Check the stage parameters of :func:`reconstruct_detailed` and fill in their defaults.

    Examples
    --------
    >>> from awr_denoise.settings import resolve_settings
    >>> resolve_settings(stages=1).c_s, resolve_settings().c_s, resolve_settings().exponents
    (1.0, 2.0, (0.75, 0.4))
    >>> resolve_settings(stages=2).exponents, resolve_settings(stages=1).exponents   # the last ones
    ((0.4,), ())
    """
    exponents = _exponents(wiener_exponents)
    stages = _checks.whole("stages", stages, minimum=1)  # type: ignore[assignment]
    if stages > 1 + len(exponents):  # type: ignore[operator]
        # Both named, either may be the one given: wiener_exponents=() alone blamed "stages", at its default.
        raise ValueError(f"stages, wiener_exponents: stages={stages} needs {stages - 1} wiener_exponents (one per "
                         f"stage after the first), {len(exponents)} given; give as many, or stages <= "
                         f"{1 + len(exponents)}")
    c_s = _checks.real("c_s", (DEFAULT_C_S if stages == 1 else DEFAULT_PILOT_C_S) if c_s is None else c_s,
                       minimum=0)
    guard = stages > 1 if guard is None else _checks.flag("guard", guard)
    if guard and stages == 1:
        raise ValueError("guard: the SURE guard follows the Wiener stages; it needs stages > 1")
    if isinstance(variance_probes, (float, np.floating)):
        raise ValueError(f"variance_probes: must be an integer >= 0, got {variance_probes!r}")
    if guard_window is None:
        guard_window = DEFAULT_WINDOW
    elif not guard:  # a setting that would do nothing is refused, not ignored
        raise ValueError(f"guard_window: {guard_window} sets the SURE guard's window, but the guard is off")
    guard_window = _checks.whole("guard_window", guard_window, minimum=1, maximum=1023)  # type: ignore[assignment]
    if guard_window % 2 == 0:  # type: ignore[operator]
        raise ValueError(f"guard_window: must be odd, got {guard_window}")
    if guard_probes is None:
        guard_probes = 0
    elif not guard:
        raise ValueError(f"guard_probes: {guard_probes} measures the SURE guard's divergence, but the guard is off")
    if isinstance(guard_probes, (float, np.floating)):
        raise ValueError(f"guard_probes: must be an integer >= 0, got {guard_probes!r}")
    return Settings(
        c_s=c_s, stages=stages, exponents=exponents[len(exponents) - (stages - 1):],  # type: ignore[arg-type, operator]
        pixel_clamp=_checks.real("pixel_clamp", pixel_clamp, minimum=0, none=True), guard=guard,
        preserve_mean=stages > 1 if preserve_mean is None else _checks.flag("preserve_mean", preserve_mean),
        nonnegative=stages > 1 if nonnegative is None else _checks.flag("nonnegative", nonnegative),
        precision=_checks.name("precision", precision, PRECISIONS), seed=_checks.seed("seed", seed),
        probes=_checks.whole("variance_probes", variance_probes, minimum=0, maximum=_MAX_PROBES),  # type: ignore[arg-type]
        guard_window=guard_window,  # type: ignore[arg-type]
        guard_probes=_checks.whole("guard_probes", guard_probes, minimum=0,  # type: ignore[arg-type]
                                   maximum=_MAX_PROBES),
    )
