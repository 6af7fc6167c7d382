"""The run loop of :meth:`~awr_denoise.sampling.Sampler.run`: ask, render, tell until a sample goal or a deadline.

Without a deadline every round asks for the sampler's default budget (``round_growth`` of the samples so far;
paper section 4 leaves the round size open), the last one cut to land on the goal. With a time budget
(``seconds``) the rounds are planned from what the last one measured (:class:`RoundPlan`): how long the
renderer took per sample and how long the sampler's own work took (``ask`` and ``tell``, whose priority
analysis costs about the same whatever the round's size). A round then asks for at least enough samples that
the sampler's work is :data:`ROUND_OVERHEAD` of its render time (a fast renderer gets fewer, larger rounds:
more of the budget goes to samples), for no more than the time left can render, and the round before the
deadline takes all that is left. The run stops when less than one sample per pixel fits. The final
reconstruction is the caller's, after the run: leave it its time (docs/sampling.md, "A time budget").
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from tqdm.auto import tqdm

from .allocation import MAX_BUDGET
from .errors import TimeBudgetWarning
from .requests import Renderer, SampleRequest

if TYPE_CHECKING:  # the samplers import this module
    from .buffers import SampleBuffer
    from .sampling import Sampler

__all__ = ["ROUND_OVERHEAD", "DEFAULT_RUN_SPP", "MAX_SECONDS", "RoundPlan", "run_rounds"]

DEFAULT_RUN_SPP = 32.0
""":meth:`~awr_denoise.sampling.Sampler.run`'s goal in samples per pixel given neither ``total_spp`` nor ``seconds``."""
MAX_SECONDS = 1e9
"""The longest time budget :meth:`~awr_denoise.sampling.Sampler.run` takes (about 30 years: more is a mistake)."""

ROUND_OVERHEAD = 0.1
"""Under a time budget, the sampler's time per round (``ask`` and ``tell``) as the largest share of the round's
render time: rounds grow until it holds. Measured against shares of 0.05 and 0.25 and the sampler's default rounds
beside Mitsuba 3 and the bundled tracer (docs/sampling.md, "A time budget")."""

_clock: Callable[[], float] = time.perf_counter
"""The clock of the deadline (a test replaces it)."""


@dataclass
class RoundPlan:
    """The budget of each round under a deadline, from the costs the last round measured.

    Parameters
    ----------
    seconds
        The time budget of the rounds, from ``start``.
    pixels
        The image's pixels: the run stops when fewer samples than this fit in the time left.
    start
        When the budget began (:data:`_clock`'s time).

    Examples
    --------
    A renderer that takes 1 ms per sample and a sampler that takes 20 ms per round, 64 pixels, 1 s in all:

    >>> from awr_denoise.rounds import RoundPlan
    >>> plan = RoundPlan(1.0, pixels=64, start=0.0)
    >>> plan.budget(16, now=0.0)            # nothing measured yet: the sampler's default
    16
    >>> plan.record(overhead=0.02, render=0.016, samples=16)
    >>> plan.budget(16, now=0.04)           # 20 ms is 10% of 200 samples' render time
    200
    >>> plan.budget(16, now=0.70)           # 0.3 s left: 200 would leave too little for one more round
    280
    >>> plan.budget(16, now=0.95)           # less than one sample per pixel fits: stop
    0
    """

    seconds: float
    pixels: int
    start: float = field(default_factory=lambda: _clock())
    overhead: float | None = None
    """The sampler's seconds (``ask`` and ``tell``) in the last round."""
    per_sample: float | None = None
    """The renderer's seconds per sample in the last round."""

    def record(self, *, overhead: float, render: float, samples: int) -> None:
        """What a round cost: the sampler's seconds, the renderer's seconds and its samples."""
        self.overhead = max(0.0, float(overhead))
        self.per_sample = max(0.0, float(render)) / samples if samples > 0 else self.per_sample

    def budget(self, default: int, *, now: float | None = None) -> int:
        """Samples of the next round (0: stop), given the sampler's ``default`` budget."""
        if self.overhead is None:  # nothing measured yet
            return default
        left = self.seconds - ((_clock() if now is None else now) - self.start)
        if left <= 0:
            return 0
        if not self.per_sample:  # a renderer too fast for the clock: the default rounds until the time is up
            return default
        o, r = self.overhead, self.per_sample
        afford = min((left - o) / r, MAX_BUDGET)
        if afford < self.pixels:
            return 0
        afford = int(afford)
        budget = min(max(default, math.ceil(o / (ROUND_OVERHEAD * r))), afford)
        if left - o - budget * r < o + self.pixels * r:  # no room for one more round after it
            budget = afford
        return budget


def run_rounds(sampler: Sampler, renderer: Renderer, goal: int | None, *, seconds: float | None = None,
               progress: bool = False, callback: Callable[[SampleRequest, SampleBuffer], bool | None] | None = None
               ) -> SampleBuffer:
    """Ask, render, tell until ``goal`` samples were issued (``None``: no goal) or the time budget ends.

    The caller (:meth:`~awr_denoise.sampling.Sampler.run`) has checked ``goal`` and ``seconds``. A pending
    round is told first, whole. Returns the sampler's buffer.
    """
    pixels = sampler.shape[0] * sampler.shape[1]
    plan = None if seconds is None else RoundPlan(seconds, pixels)
    rounds = 0
    with tqdm(total=goal, initial=sampler.total_samples, unit="sample", desc=sampler.strategy) \
            if progress else nullcontext() as bar:
        while True:
            issued = sampler.issued
            room = None if sampler.spp_max is None else int(np.maximum(sampler.spp_max - issued, 0).sum())
            remaining = [n for n in (None if goal is None else goal - int(issued.sum()), room) if n is not None]
            if remaining and min(remaining) <= 0:  # a pending round fits in both: it was asked within them
                break
            budget = None
            if sampler.pending is None:
                budget = sampler.default_budget()
                if plan is not None:
                    budget = plan.budget(budget)
                    if budget == 0:
                        break
                budget = min([budget, *remaining])
            started = _clock()
            request = sampler.ask(budget)
            asked = _clock()
            samples = renderer(request)
            rendered = _clock()
            buffer = sampler.tell(request, samples)
            rounds += 1
            if plan is not None:
                plan.record(overhead=(asked - started) + (_clock() - rendered), render=rendered - asked,
                            samples=request.total)
            if bar is not None:
                bar.update(request.total)
            if callback is not None and callback(request, buffer) is False:
                break
    if plan is not None and rounds == 1 and (spent := _clock() - plan.start) > plan.seconds:
        warnings.warn(f"seconds: the first round alone took {spent:.3g} s of a {plan.seconds:.3g}-s budget; a uniform "
                      "render may spend a budget this short better (docs/sampling.md, 'A time budget')",
                      TimeBudgetWarning, stacklevel=3)
    return sampler.buffer
