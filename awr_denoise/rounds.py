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
``reserve`` keeps its time out of the rounds' budget, given in seconds or timed on round 0's samples
(:func:`reconstruction_seconds`; docs/sampling.md, "A time budget")."""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from ._progress import auto_tqdm as tqdm

from . import _checks
from .allocation import MAX_BUDGET
from .buffers import SampleBuffer
from .errors import TimeBudgetWarning
from .reconstruct import reconstruct as _reconstruct
from .requests import Renderer, SampleRequest

if TYPE_CHECKING:  # the samplers import this module
    from .sampling import Sampler

__all__ = ["ROUND_OVERHEAD", "RANKED_COST_MARGIN", "RESERVE_MARGIN", "DEFAULT_RUN_SPP", "MAX_SECONDS", "RoundPlan",
           "reconstruction_seconds", "run_rounds"]

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

RESERVE_MARGIN = 1.3
""":func:`reconstruction_seconds`' factor on a reconstruction's time scaled from its buffer's central quarter: a
whole image took 0.79-1.03 times four quarters' time at 256x256 and 512x512, and the machine's load moves single
timings by a tenth or more. At 1920x1080 and 3840x2160 it took 1.03-1.26 times in the ``awr`` command's memory setting
and 1.26-1.34 times in glibc's default, whose fresh mappings of whole-image temporaries fault in: the estimate is then
1.03-1.27 times the reconstruction's own time in the command, about that time (0.98) at 3840x2160 in glibc's default.
A caller that also writes files reserves their share on top (``awr render``'s ``WRITE_SHARE``). A margin of 1.6 cost
every size samples under a time budget (docs/sampling.md, "A time budget": ``benchmarks/bench_budget.py --trial``)."""

WHOLE_BELOW = 128 * 128
""":func:`reconstruction_seconds` times a buffer of fewer pixels whole: a quarter would be mostly fixed costs."""

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
               reserve: float | Callable[[SampleBuffer], float] | None = None, progress: bool = False,
               callback: Callable[[SampleRequest, SampleBuffer], bool | None] | None = None) -> SampleBuffer:
    """:meth:`~awr_denoise.sampling.Sampler.run`: ask, render, tell until ``total_spp`` or the time budget ends.

    ``total_spp``, ``seconds`` and ``reserve`` are checked here, by name (``total_spp`` ``None``: 32 without
    ``seconds``, no goal with it). ``reserve``: seconds of ``seconds`` kept for other work than the rounds
    (the reconstruction after them; below ``seconds``), or a function of the buffer after the run's first round
    (round 0's samples, or a pending round's) returning them, its own time spent from the budget. A pending
    round is told first, whole. Returns the sampler's buffer.
    """
    pixels = sampler.shape[0] * sampler.shape[1]
    seconds = _checks.real("seconds", seconds, above=0, maximum=MAX_SECONDS, none=True)
    progress = _checks.flag("progress", progress)
    if callback is not None and not callable(callback):  # found after round 0, else
        raise TypeError(f"callback: expected a function of (request, buffer), got {_checks.described(callback)}")
    if reserve is not None:
        if seconds is None:  # it would do nothing: refused
            raise ValueError("reserve: only a time budget (seconds) keeps time for after the run")
        if not callable(reserve):
            reserve = _checks.real("reserve", reserve, minimum=0, maximum=MAX_SECONDS)
            if reserve >= seconds:  # known before any round: refused, not found after the first
                raise ValueError(f"reserve: {reserve:g} s leaves nothing of the {seconds:g}-s budget for rounds")
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
                if rounds == 1 and reserve is not None:  # round 0's samples: what the reconstruction will see
                    _keep(plan, reserve, buffer)
            if bar is not None:
                bar.update(request.total)
            if callback is not None and callback(request, buffer) is False:
                break
    if plan is not None and rounds == 1 and (spent := _clock() - plan.start) > seconds:
        warnings.warn(f"seconds: the first round alone took {spent:.3g} s of a {seconds:.3g}-s budget; a uniform "
                      "render may spend a budget this short better (docs/sampling.md, 'A time budget')",
                      TimeBudgetWarning, stacklevel=3)
    return sampler.buffer


def _keep(plan: RoundPlan, reserve: float | Callable[[SampleBuffer], float], buffer: SampleBuffer) -> None:
    """Take ``reserve`` (seconds, or a function of round 0's ``buffer`` giving them) out of ``plan``'s budget."""
    kept = _checks.real("reserve", reserve(buffer) if callable(reserve) else reserve, minimum=0,
                        maximum=MAX_SECONDS)
    budget, plan.seconds, spent = plan.seconds, plan.seconds - kept, _clock() - plan.start
    if plan.seconds <= spent <= budget:  # (a first round past the budget is said by itself)
        warnings.warn(f"seconds: {kept:.3g} s of the {budget:.3g}-s budget kept for other work (reserve) leave no "
                      "time for rounds after the first (docs/sampling.md, 'A time budget')", TimeBudgetWarning,
                      stacklevel=4)


def reconstruction_seconds(buffer: SampleBuffer, reconstruct: Callable[[SampleBuffer], object] | None = None
                           ) -> float:
    """The seconds ``reconstruct(buffer)`` is expected to take on this machine: a run's ``reserve``.

    Timed on the buffer's central quarter (half of each side), times four and :data:`RESERVE_MARGIN`: the
    reconstruction's time hardly depends on the samples, only on the pixels and the settings. A buffer of fewer
    than :data:`WHOLE_BELOW` pixels, or whose quarter ``reconstruct`` refuses (``levels`` its half sides cannot
    take), is timed whole. Like every time budget, the estimate follows the machine's load when it is taken.

    Parameters
    ----------
    buffer
        The samples so far (round 0's, as a run's ``reserve``): their shape, channels and features.
    reconstruct
        The reconstruction the caller runs after the run, with its settings (default
        :func:`~awr_denoise.reconstruct`: paper section 5, Eq. 10-11, and the project's later stages).

    Examples
    --------
    Rounds for half a second, of which the default reconstruction's time, timed on round 0's samples, is kept
    for it (docs/sampling.md, "A time budget"):

    >>> from awr_denoise import AdaptiveSampler
    >>> from awr_denoise.rounds import reconstruction_seconds
    >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
    >>> renderer = SyntheticRenderer(make_scene("edges", (64, 64)))
    >>> buffer = AdaptiveSampler((64, 64)).run(renderer, seconds=0.5, reserve=reconstruction_seconds)
    >>> 0 < reconstruction_seconds(buffer) < 0.5
    True
    """
    if not isinstance(buffer, SampleBuffer):
        raise TypeError(f"buffer: expected a SampleBuffer, got {_checks.described(buffer)}")
    if reconstruct is not None and not callable(reconstruct):
        raise TypeError(f"reconstruct: expected a function of a SampleBuffer, got {_checks.described(reconstruct)}")
    reconstruct = _reconstruct if reconstruct is None else reconstruct
    h, w = buffer.shape
    if h * w >= WHOLE_BELOW and min(h, w) >= 2:  # (a strip one pixel thin has no central quarter)
        rows, cols = slice(h // 4, h // 4 + h // 2), slice(w // 4, w // 4 + w // 2)
        part, scale = buffer.crop(rows, cols), (h * w) / ((h // 2) * (w // 2))
        started = _clock()
        try:
            reconstruct(part)
        except ValueError:  # settings the half sides cannot take: timed whole
            pass
        else:
            return RESERVE_MARGIN * scale * (_clock() - started)
    started = _clock()
    reconstruct(buffer)
    return RESERVE_MARGIN * (_clock() - started)


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
