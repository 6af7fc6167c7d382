"""``awr_denoise.rounds``: ``Sampler.run``'s loop under a sample goal and under a time budget.

Time is a fake clock here (``rounds._clock`` replaced): the renderer advances it by a fixed cost per sample and
the sampler's ``ask`` by a fixed cost per round, so the plan's arithmetic is tested exactly, not the machine's
speed (the measured trade is in docs/sampling.md, "A time budget").
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from awr_denoise import AdaptiveSampler, SampleBuffer, TimeBudgetWarning, UniformSampler, rounds
from awr_denoise.rounds import RANKED_COST_MARGIN, ROUND_OVERHEAD, RoundPlan
from awr_denoise.synthetic import SyntheticRenderer, make_scene

SHAPE = (16, 16)
PIXELS = SHAPE[0] * SHAPE[1]


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch):
    fake = FakeClock()
    monkeypatch.setattr(rounds, "_clock", fake)
    return fake


class TimedRenderer:
    """The synthetic ``edges`` scene; every sample costs ``per_sample`` seconds of the fake clock."""

    def __init__(self, clock: FakeClock, per_sample: float) -> None:
        self.clock, self.per_sample = clock, per_sample
        self.inner = SyntheticRenderer(make_scene("edges", SHAPE), seed=0)
        self.rounds: list[int] = []

    def __call__(self, request):
        self.clock.now += request.total * self.per_sample
        self.rounds.append(request.total)
        return self.inner(request)


def timed_sampler(clock: FakeClock, overhead: float, cls=AdaptiveSampler, **options):
    """A sampler whose ``ask`` costs ``overhead`` seconds of the fake clock."""
    sampler = cls(SHAPE, seed=0, **options)
    ask = sampler.ask

    def costly_ask(budget=None):
        clock.now += overhead
        return ask(budget)

    sampler.ask = costly_ask
    return sampler


@pytest.mark.parametrize("seconds", [0.5, 1.0, 1.5, 2.0])
def test_a_time_budget_ends_the_run_within_it_and_the_last_round_takes_what_is_left(clock, seconds):
    renderer, overhead = TimedRenderer(clock, 1e-4), 0.01
    sampler = timed_sampler(clock, overhead)
    buffer = sampler.run(renderer, seconds=seconds)
    assert clock.now <= seconds
    # The round before the deadline took what was left, not a round with too little time after it for another
    # (at 1.5 s the rounds' growth alone would leave 23 ms unused).
    assert clock.now > seconds - 2 * renderer.per_sample
    assert buffer.total_samples == sum(renderer.rounds) == sampler.total_samples


def test_rounds_grow_until_the_samplers_time_is_its_share_of_their_render_time(clock):
    renderer, overhead = TimedRenderer(clock, 1e-5), 0.01
    timed_sampler(clock, overhead).run(renderer, seconds=5.0)
    least = math.ceil(overhead / (ROUND_OVERHEAD * renderer.per_sample))
    # Round 0 (nothing measured), then the first ranked round, planned at twice round 0's cost per sample (what
    # ranked samples cost is not known yet): half the share rule's samples; the last takes what is left.
    assert renderer.rounds[1] == math.ceil(least / RANKED_COST_MARGIN)
    middle = renderer.rounds[2:-1]
    assert middle and all(n >= least for n in middle)
    # Without the deadline the same sampler would have asked for its default rounds, far smaller here.
    plain = TimedRenderer(clock, 1e-5)
    AdaptiveSampler(SHAPE, seed=0).run(plain, total_spp=sum(renderer.rounds) / PIXELS)
    assert len(plain.rounds) > len(renderer.rounds) and max(plain.rounds[1:4]) < least / 10


def test_a_sampler_that_does_not_rank_plans_its_second_round_at_round_0s_rate(clock):
    """A uniform sampler's later samples are placed as round 0's: no margin for a ranking's costlier pixels."""
    renderer, overhead = TimedRenderer(clock, 1e-5), 0.01
    timed_sampler(clock, overhead, cls=UniformSampler).run(renderer, seconds=5.0)
    assert renderer.rounds[1] == math.ceil(overhead / (ROUND_OVERHEAD * renderer.per_sample))
    assert clock.now <= 5.0


class RankedCostRenderer(TimedRenderer):
    """Samples after round 0 cost ``ranked_factor`` times as much: a ranking sends them to costlier pixels (beside
    Mitsuba 3 at 1080p, 1.6 times round 0's uniform ones)."""

    def __init__(self, clock: FakeClock, per_sample: float, ranked_factor: float) -> None:
        super().__init__(clock, per_sample)
        self.ranked_factor = ranked_factor

    def __call__(self, request):
        if request.round > 0:
            self.clock.now += request.total * self.per_sample * (self.ranked_factor - 1)
        return super().__call__(request)


@pytest.mark.parametrize("seconds", [0.15, 0.2, 0.25, 0.5])
def test_ranked_samples_costlier_than_round_0s_do_not_overrun_the_budget(clock, seconds):
    """Ranked samples at up to RANKED_COST_MARGIN times round 0's cost: planned at round 0's rate, the first ranked
    round would have run past the budget; the rounds after it are planned at its own rate."""
    renderer = RankedCostRenderer(clock, 1e-4, ranked_factor=RANKED_COST_MARGIN)
    timed_sampler(clock, 0.01).run(renderer, seconds=seconds)
    assert clock.now <= seconds and len(renderer.rounds) >= 2


def slow_ranking(sampler: AdaptiveSampler, clock: FakeClock, seconds: float) -> AdaptiveSampler:
    """``sampler``'s priority analysis (``density``) costs ``seconds`` of the fake clock."""
    density = sampler.density

    def costly_density():
        clock.now += seconds
        return density()

    sampler.density = costly_density
    return sampler


@pytest.mark.parametrize("seconds", [0.5, 1.0, 2.0])
def test_the_rankings_cost_is_known_before_the_rounds_size(clock, seconds):
    """A priority analysis of 0.3 s per round, far more than round 0's ``ask``: each round's is timed before its
    size is chosen, and no ranking starts that would leave no room for its round."""
    renderer = TimedRenderer(clock, 1e-4)
    sampler = slow_ranking(timed_sampler(clock, 0.001), clock, 0.3)
    sampler.run(renderer, seconds=seconds)
    assert clock.now <= seconds
    # The time is used: less than one more ranked round (its ranking and 1 spp) would have fitted.
    assert clock.now > seconds - (0.3 + 0.001 + PIXELS * renderer.per_sample)


@pytest.mark.parametrize("seconds", [0.14, 0.15, 0.16])
def test_the_round_after_a_ranking_is_sized_on_the_time_it_left(clock, seconds):
    """The first ranking (30 ms, where round 0's ``ask`` took 1 ms) is timed before its round's size: the round
    that takes what is left takes what the ranking left. Sized as if the ranking cost what round 0's ``ask`` did,
    it runs past the budget at 0.14 and 0.15 s (ranked samples at the margin's cost: nothing else absorbs it)."""
    renderer = RankedCostRenderer(clock, 1e-4, ranked_factor=RANKED_COST_MARGIN)
    slow_ranking(timed_sampler(clock, 0.001), clock, 0.03).run(renderer, seconds=seconds)
    assert clock.now <= seconds + 1e-12 and len(renderer.rounds) == 2


def test_a_ranking_done_ahead_is_the_one_the_round_allocates_by(clock):
    """Under a deadline each ranked round's priorities are computed once, ahead of ``ask``, and allocated by:
    the same requests, pixel for pixel, as the run without a deadline, which ranks inside ``ask``."""
    seen, plain, calls = [], [], []
    sampler = timed_sampler(clock, 1e-3)
    density = sampler.density
    sampler.density = lambda: calls.append(sampler.round) or density()
    sampler.run(TimedRenderer(clock, 1e-2), seconds=60.0, callback=lambda request, _: seen.append(request.counts))
    assert calls == list(range(1, len(seen)))  # once per round after round 0
    AdaptiveSampler(SHAPE, seed=0).run(SyntheticRenderer(make_scene("edges", SHAPE), seed=0),
                                      total_spp=sum(int(c.sum()) for c in seen) / PIXELS,
                                      callback=lambda request, _: plain.append(request.counts))
    assert len(seen) == len(plain) >= 4
    for ours, theirs in zip(seen[:-2], plain[:-2]):
        np.testing.assert_array_equal(ours, theirs)


def test_a_slow_renderer_keeps_the_samplers_own_rounds(clock):
    """Where the sampler's time is already a small share of the render's, the deadline changes no request but
    the last: the same counts, pixel for pixel, as without it."""
    renderer = TimedRenderer(clock, 1e-2)
    seen = []
    timed_sampler(clock, 1e-3).run(renderer, seconds=60.0, callback=lambda request, _: seen.append(request.counts))
    plain = []
    AdaptiveSampler(SHAPE, seed=0).run(SyntheticRenderer(make_scene("edges", SHAPE), seed=0),
                                      total_spp=sum(renderer.rounds) / PIXELS,
                                      callback=lambda request, _: plain.append(request.counts))
    assert len(seen) == len(plain) >= 4
    for ours, theirs in zip(seen[:-2], plain[:-2]):
        np.testing.assert_array_equal(ours, theirs)


def test_the_first_round_is_rendered_whatever_the_budget_and_a_budget_it_overran_is_said(clock):
    renderer = TimedRenderer(clock, 1e-3)
    with pytest.warns(TimeBudgetWarning, match=r"seconds: the first round alone took 0\.522 s of a 1e-09-s budget"):
        buffer = timed_sampler(clock, 0.01).run(renderer, seconds=1e-9)
    assert renderer.rounds == [2 * PIXELS] and buffer.total_samples == 2 * PIXELS  # round 0 at 2 spp


def test_a_run_of_several_rounds_says_nothing(clock, recwarn):
    timed_sampler(clock, 0.01).run(TimedRenderer(clock, 1e-4), seconds=1.0)
    assert not [w for w in recwarn if "seconds" in str(w.message)]


def test_a_sample_goal_and_a_time_budget_stop_at_whichever_comes_first(clock):
    fast = TimedRenderer(clock, 1e-6)
    assert timed_sampler(clock, 1e-4).run(fast, total_spp=8, seconds=100.0).total_samples == 8 * PIXELS
    clock.now = 0.0
    slow = TimedRenderer(clock, 1e-3)
    buffer = timed_sampler(clock, 1e-4).run(slow, total_spp=1000, seconds=2.0)
    assert clock.now <= 2.0 and buffer.total_samples < 1000 * PIXELS


def test_spp_max_ends_a_run_without_a_goal(clock):
    renderer = TimedRenderer(clock, 1e-6)
    sampler = timed_sampler(clock, 1e-4, cls=UniformSampler, spp_max=6)
    buffer = sampler.run(renderer, seconds=1e6)
    assert (buffer.count == 6).all() and clock.now < 1.0


def test_a_renderer_too_fast_for_the_clock_runs_the_default_rounds_until_the_time_is_up(clock):
    renderer = TimedRenderer(clock, 0.0)
    sampler = timed_sampler(clock, 0.25)
    sampler.run(renderer, seconds=2.0)
    assert 2.0 <= clock.now <= 2.25 and len(renderer.rounds) == 8  # a round starts while time is left


def test_without_a_time_budget_the_run_goes_to_32_spp_as_before():
    renderer = SyntheticRenderer(make_scene("edges", SHAPE), seed=0)
    assert AdaptiveSampler(SHAPE).run(renderer).total_samples == 32 * PIXELS
    assert AdaptiveSampler(SHAPE).run(renderer, total_spp=None).total_samples == 32 * PIXELS


def test_a_pending_round_is_told_first_and_counted_in_the_budget(clock):
    renderer = TimedRenderer(clock, 1e-4)
    sampler = timed_sampler(clock, 0.01)
    first = sampler.ask()
    buffer = sampler.run(renderer, seconds=1.0)
    assert renderer.rounds[0] == first.total and sampler.pending is None and clock.now <= 1.0 + 0.01
    assert buffer.total_samples == sum(renderer.rounds)


@pytest.mark.parametrize("seconds", [0, -1.0, float("nan"), float("inf"), 1e10, True, "1"])
def test_a_time_budget_is_checked_by_name(seconds):
    renderer = SyntheticRenderer(make_scene("edges", SHAPE), seed=0)
    with pytest.raises((ValueError, TypeError), match="seconds"):
        AdaptiveSampler(SHAPE).run(renderer, seconds=seconds)


def test_the_plan_stops_when_less_than_one_sample_per_pixel_fits():
    plan = RoundPlan(1.0, pixels=100, start=0.0)
    plan.record(overhead=0.1, render=0.01, samples=100)  # 0.1 ms per sample
    assert plan.budget(50, now=0.0) > 0
    assert plan.budget(50, now=1.0 - 0.1 - 100 * 1e-4 + 1e-6) == 0
    assert plan.budget(50, now=2.0) == 0


@pytest.mark.parametrize("reserve", [0.3, 1.2])
def test_a_reserve_ends_the_rounds_that_much_earlier(clock, reserve):
    renderer = TimedRenderer(clock, 1e-4)
    timed_sampler(clock, 0.01).run(renderer, seconds=2.0, reserve=reserve)
    assert 2.0 - reserve - 2 * renderer.per_sample < clock.now <= 2.0 - reserve


def test_a_reserve_function_sees_round_0s_samples_once_and_its_own_time_is_spent(clock):
    renderer, seen = TimedRenderer(clock, 1e-4), []

    def reserve(buffer):
        seen.append(buffer.total_samples)
        clock.now += 0.2  # timing a reconstruction takes time too
        return 0.5

    timed_sampler(clock, 0.01).run(renderer, seconds=2.0, reserve=reserve)
    assert seen == [2 * PIXELS] and len(renderer.rounds) > 2
    assert 1.5 - 2 * renderer.per_sample < clock.now <= 1.5


def test_a_reserve_that_leaves_no_time_for_rounds_is_said_once(clock):
    renderer = TimedRenderer(clock, 1e-3)  # round 0: 0.512 s of rendering, 0.01 s of asking
    with pytest.warns(TimeBudgetWarning, match=r"seconds: 0\.8 s of the 1-s budget kept for other work \(reserve\) "
                                               r"leave no time for rounds after the first") as said:
        timed_sampler(clock, 0.01).run(renderer, seconds=1.0, reserve=0.8)  # round 0 took 0.52 s of the 0.2 left
    assert renderer.rounds == [2 * PIXELS] and len(said) == 1
    clock.now = 0.0
    with pytest.warns(TimeBudgetWarning, match="the first round alone took") as said:
        timed_sampler(clock, 0.01).run(TimedRenderer(clock, 1e-3), seconds=0.1, reserve=0.05)
    assert len(said) == 1  # the round's overrun, not the reserve's too


@pytest.mark.parametrize("reserve", [-1.0, float("nan"), float("inf"), 1e10, True, "1"])
def test_a_reserve_is_checked_by_name(clock, reserve):
    with pytest.raises((ValueError, TypeError), match="reserve"):
        timed_sampler(clock, 0.01).run(TimedRenderer(clock, 1e-4), seconds=1.0, reserve=reserve)
    with pytest.raises((ValueError, TypeError), match="reserve"):  # what a function returns, too
        timed_sampler(clock, 0.01).run(TimedRenderer(clock, 1e-4), seconds=1.0, reserve=lambda _: reserve)
    with pytest.raises(ValueError, match="reserve: only a time budget"):
        timed_sampler(clock, 0.01).run(TimedRenderer(clock, 1e-4), total_spp=4, reserve=0.1)
    renderer = TimedRenderer(clock, 1e-4)
    with pytest.raises(ValueError, match="reserve: 1 s leaves nothing of the 1-s budget"):  # before any round
        timed_sampler(clock, 0.01).run(renderer, seconds=1.0, reserve=1.0)
    assert renderer.rounds == []


class TimedReconstruction:
    """A reconstruction costing ``per_pixel`` seconds of the fake clock per pixel, refusing sides below ``least``."""

    def __init__(self, clock: FakeClock, per_pixel: float, least: int = 1) -> None:
        self.clock, self.per_pixel, self.least, self.seen = clock, per_pixel, least, []

    def __call__(self, buffer):
        self.seen.append(buffer)
        if min(buffer.shape) < self.least:
            raise ValueError("levels: too many for this image")
        self.clock.now += buffer.count.size * self.per_pixel


@pytest.mark.parametrize("shape", [(256, 256), (255, 257), (128, 128)])
def test_reconstruction_seconds_times_the_central_quarter_and_scales_it(clock, shape):
    mean = np.arange(shape[0] * shape[1], dtype=float).reshape(shape)
    buffer = SampleBuffer.from_moments(np.ones(shape, dtype=np.int64), mean, np.zeros(shape))
    timed = TimedReconstruction(clock, 1e-6)
    estimate = rounds.reconstruction_seconds(buffer, timed)
    (part,) = timed.seen
    h, w = shape[0] // 2, shape[1] // 2
    np.testing.assert_array_equal(part.mean[..., 0], mean[shape[0] // 4:shape[0] // 4 + h, shape[1] // 4:][:, :w])
    assert estimate == pytest.approx(rounds.RESERVE_MARGIN * shape[0] * shape[1] * 1e-6)


def test_reconstruction_seconds_times_a_small_buffer_or_a_refused_quarter_whole(clock):
    small = SampleBuffer.from_moments(np.ones((64, 100), dtype=np.int64), np.ones((64, 100)), np.zeros((64, 100)))
    timed = TimedReconstruction(clock, 1e-6)
    assert rounds.reconstruction_seconds(small, timed) == pytest.approx(rounds.RESERVE_MARGIN * 6400e-6)
    assert [b.shape for b in timed.seen] == [(64, 100)]
    large = SampleBuffer.from_moments(np.ones((256, 256), dtype=np.int64), np.ones((256, 256)),
                                             np.zeros((256, 256)))
    refusing = TimedReconstruction(clock, 1e-6, least=200)
    assert rounds.reconstruction_seconds(large, refusing) == pytest.approx(rounds.RESERVE_MARGIN * 65536e-6)
    assert [b.shape for b in refusing.seen] == [(128, 128), (256, 256)]


def test_reconstruction_seconds_times_a_strip_one_pixel_thin_whole(clock):
    """A 1x16384 buffer has no central quarter: it was "rows: 0:0 holds none of the image's 1 rows"."""
    for shape in ((1, 16384), (16384, 1)):
        strip = SampleBuffer.from_moments(np.ones(shape, dtype=np.int64), np.ones(shape), np.zeros(shape))
        timed = TimedReconstruction(clock, 1e-6)
        assert rounds.reconstruction_seconds(strip, timed) == pytest.approx(rounds.RESERVE_MARGIN * 16384e-6)
        assert [b.shape for b in timed.seen] == [shape]


def test_run_and_reconstruction_seconds_check_their_arguments_before_any_round(clock):
    renderer = TimedRenderer(clock, 1e-4)
    with pytest.raises(TypeError, match="callback: expected a function"):
        timed_sampler(clock, 0.01).run(renderer, total_spp=4, callback=5)
    with pytest.raises(TypeError, match="progress: expected True or False"):
        timed_sampler(clock, 0.01).run(renderer, total_spp=4, progress="no")
    assert renderer.rounds == []
    with pytest.raises(TypeError, match="buffer: expected a SampleBuffer"):
        rounds.reconstruction_seconds(np.zeros((16, 16, 3)))
    with pytest.raises(TypeError, match="reconstruct: expected a function"):
        rounds.reconstruction_seconds(SampleBuffer.empty(SHAPE), 5)
