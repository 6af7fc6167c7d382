"""The run loop of :meth:`~awr_denoise.sampling.Sampler.run`: ask, render, tell until a sample goal or a deadline.

Without a deadline every round asks for the sampler's default budget (``round_growth`` of the samples so far;
paper section 4 leaves the round size open), the last one cut to land on the goal. With a time budget
(``seconds``) the rounds are planned from what was measured (:class:`RoundPlan`): the sampler ranks the pixels
first (its priority analysis, whose cost hardly depends on the round's size, timed before the size is chosen),
and the last round told how long the renderer took per sample and the rest of the sampler's work (allocation and
``tell``). A round then asks for at least enough samples that the sampler's work is :data:`ROUND_OVERHEAD` of its
render time (a fast renderer gets fewer, larger rounds: more of the budget goes to samples), for no more than the
time left can render, and the round before the deadline takes all that is left. Samples placed by a ranking are
planned at :data:`RANKED_COST_MARGIN` times round 0's uniform ones' cost until a ranked round was measured.
The run stops when less than one sample per pixel fits. The final reconstruction is the caller's, after the run:
leave it its time (docs/sampling.md, "A time budget")."""

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

from . import _checks
from .allocation import MAX_BUDGET
from .errors import TimeBudgetWarning
from .requests import Renderer, SampleRequest

if TYPE_CHECKING:  # the samplers import this module
    from .buffers import SampleBuffer
    from .sampling import Sampler

__all__ = ["ROUND_OVERHEAD", "RANKED_COST_MARGIN", "DEFAULT_RUN_SPP", "MAX_SECONDS", "RoundPlan", "run_rounds"]

DEFAULT_RUN_SPP = 32.0
""":meth:`~awr_denoise.sampling.Sampler.run`'s goal in samples per pixel given neither ``total_spp`` nor ``seconds``."""
MAX_SECONDS = 1e9
"""The longest time budget :meth:`~awr_denoise.sampling.Sampler.run` takes (about 30 years: more is a mistake)."""

ROUND_OVERHEAD = 0.1
"""Under a time budget, the sampler's time per round (its ranking, ``ask`` and ``tell``) as the largest share of the
round's render time: rounds grow until it holds. Measured against shares of 0.05 and 0.25 and the sampler's default
rounds beside Mitsuba 3 and the bundled tracer (docs/sampling.md, "A time budget")."""

RANKED_COST_MARGIN = 2.0
"""Until a ranked round was measured, its samples are planned at this many times round 0's cost per sample: a
ranking sends them to other pixels, scattered (beside Mitsuba 3 1.85 times round 0's at 1080p, 0.97-1.28 times at
256x256; beside the bundled tracer 0.96-1.15 times: docs/sampling.md, "A time budget")."""

_clock: Callable[[], float] = time.perf_counter
"""The clock of the deadline (a test replaces it)."""


@dataclass
class RoundPlan:
    """The budget of each round under a deadline, from the costs the last round measured.

    The sampler's time per round is two parts: its ranking of the pixels (the priority analysis, timed before the
    round's size is chosen: :meth:`budget` takes this round's), and the rest (``ask``'s allocation and ``tell``),
    taken from the last round. The renderer's time per sample is the last round's; when that round was round 0
    (uniform), the next one's samples are planned at :data:`RANKED_COST_MARGIN` times its rate, since a ranking
    sends them to other pixels, which may cost more.

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
    >>> plan.budget(16, now=0.04, ranking=0.01)  # this round's ranking took 10 ms (spent): 30 ms a round
    300
    >>> plan.record(overhead=0.02, render=0.016, samples=16, ranked=False)   # round 0's uniform samples
    >>> plan.budget(16, now=0.6, ranking=0.1)    # ranked ones planned at 2 ms each: 190 fit in what is left
    190
    """

    seconds: float
    pixels: int
    start: float = field(default_factory=lambda: _clock())
    overhead: float | None = None
    """The sampler's seconds in the last round but its ranking (``ask``'s allocation and ``tell``)."""
    ranking: float = 0.0
    """The sampler's seconds ranking the pixels in the last round."""
    per_sample: float | None = None
    """The renderer's seconds per sample in the last round."""
    ranked: bool = True
    """Whether ``per_sample`` was measured on samples placed as the next round's will be: a ranked round's, or any
    round's of a sampler that does not rank (round 0's are uniform; a ranking's may cost more)."""

    def record(self, *, overhead: float, render: float, samples: int, ranking: float = 0.0,
               ranked: bool = True) -> None:
        """What a round cost: the sampler's seconds (its ranking apart), the renderer's seconds and its samples."""
        self.overhead, self.ranking = max(0.0, float(overhead)), max(0.0, float(ranking))
        if samples > 0:
            self.per_sample, self.ranked = max(0.0, float(render)) / samples, ranked

    def budget(self, default: int, *, now: float | None = None, ranking: float | None = None) -> int:
        """Samples of the next round (0: stop), given the sampler's ``default`` budget.

        ``ranking``: the seconds this round's ranking took, already spent by ``now`` (``None``: not timed
        apart, the last round's is expected).
        """
        if self.overhead is None:  # nothing measured yet
            return default
        left = self.seconds - ((_clock() if now is None else now) - self.start)
        if left <= 0:
            return 0
        if not self.per_sample:  # a renderer too fast for the clock: the default rounds until the time is up
            return default
        to_spend = self.overhead + (self.ranking if ranking is None else 0.0)  # this round's sampler time to come
        whole = self.overhead + (self.ranking if ranking is None else ranking)  # a round's sampler time
        r = self.per_sample * (1.0 if self.ranked else RANKED_COST_MARGIN)
        afford = min((left - to_spend) / r, MAX_BUDGET)
        if afford < self.pixels:
            return 0
        afford = int(afford)
        budget = min(max(default, math.ceil(whole / (ROUND_OVERHEAD * r))), afford)
        if left - to_spend - budget * r < whole + self.pixels * r:  # no room for one more round after it
            budget = afford
        return budget


def run_rounds(sampler: Sampler, renderer: Renderer, total_spp: float | None, *, seconds: float | None = None,
               progress: bool = False, callback: Callable[[SampleRequest, SampleBuffer], bool | None] | None = None
               ) -> SampleBuffer:
    """:meth:`~awr_denoise.sampling.Sampler.run`: ask, render, tell until ``total_spp`` or the time budget ends.

    ``total_spp`` and ``seconds`` are checked here, by name (``total_spp`` ``None``: 32 without ``seconds``, no
    goal with it). A pending round is told first, whole. Returns the sampler's buffer.
    """
    pixels = sampler.shape[0] * sampler.shape[1]
    seconds = _checks.real("seconds", seconds, above=0, maximum=MAX_SECONDS, none=True)
    if total_spp is None and seconds is None:
        total_spp = DEFAULT_RUN_SPP
    goal = None if total_spp is None else _goal(sampler, total_spp)
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
            budget, ranking = None, 0.0
            if sampler.pending is None:
                budget = sampler.default_budget()
                if plan is not None:
                    if plan.budget(budget) == 0:  # no round fits, with the last ranking's cost: none is ranked
                        break
                    started = _clock()
                    sampler._prepare()  # this round's ranking: its cost is known before the round's size
                    ranking = _clock() - started
                    budget = plan.budget(budget, ranking=ranking)
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
                            samples=request.total, ranking=ranking, ranked=request.round > 0 or not sampler._ranks)
            if bar is not None:
                bar.update(request.total)
            if callback is not None and callback(request, buffer) is False:
                break
    if plan is not None and rounds == 1 and (spent := _clock() - plan.start) > plan.seconds:
        warnings.warn(f"seconds: the first round alone took {spent:.3g} s of a {plan.seconds:.3g}-s budget; a uniform "
                      "render may spend a budget this short better (docs/sampling.md, 'A time budget')",
                      TimeBudgetWarning, stacklevel=3)
    return sampler.buffer


def _goal(sampler: Sampler, total_spp: float) -> int:
    """``total_spp`` as a number of samples, checked against what the sampler took and may still take."""
    pixels = sampler.shape[0] * sampler.shape[1]
    total_spp = _checks.real("total_spp", total_spp, minimum=0, maximum=MAX_BUDGET / pixels)
    goal = int(round(total_spp * pixels))
    pending = sampler.pending
    taken, asked = int(sampler.issued.sum()), (0 if pending is None else pending.total)
    if goal < taken:
        raise ValueError(f"total_spp: {total_spp} is below the {taken / pixels:.3g} spp already taken")
    if taken < goal < taken + asked:  # a pending round is told whole, if at all
        raise ValueError(f"total_spp: {total_spp} falls inside pending round {pending.round} "
                         f"({taken / pixels:.3g} to {(taken + asked) / pixels:.3g} spp), which is told whole")
    if sampler.spp_max is not None and goal > taken + (room := int(np.maximum(sampler.spp_max - sampler.issued,
                                                                            0).sum())):
        raise ValueError(f"total_spp: {total_spp} exceeds the {(taken + room) / pixels:.6g} spp that spp_max "
                         f"{sampler.spp_max} allows")
    return goal
