"""Ask/tell samplers: which pixels get the next samples (paper section 4).

A sampler owns the merged statistics of an image and hands out :class:`SampleRequest` objects;
a renderer (any callable honouring :class:`~awr_denoise.Renderer`) renders them and the
resulting :class:`SampleBuffer` is told back::

    sampler = AdaptiveSampler((480, 640))
    while (left := 32 * 480 * 640 - int(sampler.issued.sum())) > 0:  # handed out: a dropped sample counts
        request = sampler.ask(min(sampler.default_budget(), left))
        sampler.tell(request, renderer(request))
    image = reconstruct(sampler.buffer)

:meth:`Sampler.run` is exactly that loop. Round 0 spends ``initial_spp`` on every pixel (the paper starts at 4 spp,
:class:`AdaptiveSampler` at 2); later rounds follow the sampler's strategy. Every request's ``counts`` sum to the
budget asked for, exactly. Three strategies share the interface so that benchmarks compare like with like: AWR's
wavelet priorities (:class:`AdaptiveSampler`), :class:`UniformSampler`, per-pixel error (:class:`VarianceSampler`).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor

import numpy as np

from . import _arrays, _checks
from ._serial import OneAtATime, one_at_a_time
from ._typing import CountArray, FloatArray, Shape2D
from .allocation import MAX_BUDGET, _allocate, _allocate_mixed  # the samplers' arrays need no checks
from .buffers import SampleBuffer
from .domains import Domain, resolve_domain
from .errors import StaleRequestError
from .noise_gain import DEFAULT_GAIN_REFRESH, DEFAULT_NOISE_MODEL, NOISE_MODELS, MeasuredGain
from .priorities import DEFAULT_ABSOLUTE_ABOVE, dropped_at_mean, pooled_deviation, sampling_density
from .rare_paths import DEFAULT_RARE_PATHS, RARE_PATHS, rare_path_evening
from .requests import LAST_ROUND, Renderer, SampleRequest, _new_sampler_id
from .rounds import run_rounds
from .wavelets import DEFAULT_WAVELET, wavelet_operators

__all__ = ["Sampler", "AdaptiveSampler", "UniformSampler", "VarianceSampler", "SAMPLERS", "NOISE_MODELS",
           "DEFAULT_INITIAL_SPP", "DEFAULT_AWR_INITIAL_SPP", "DEFAULT_ROUND_GROWTH"]

DEFAULT_ROUND_GROWTH = 0.25
"""Default share of the samples handed out so far that the next round asks for (docs/sampling.md)."""
DEFAULT_INITIAL_SPP = 4
"""Samples per pixel of round 0 of the uniform and variance samplers: the paper's 4 (section 4)."""
DEFAULT_AWR_INITIAL_SPP = 2
"""Round 0 of :class:`AdaptiveSampler`: 2, measured on both renderers (docs/sampling.md, "The first round")."""


class Sampler(OneAtATime):
    """Base of the ask/tell samplers: request bookkeeping, validation and the run loop.

    Parameters
    ----------
    shape
        (H, W) of the image.
    channels
        Number of channels (or their names) renderers return.
    initial_spp
        Samples per pixel of round 0 (the paper starts at 4; :class:`AdaptiveSampler` at 2 by default).
    seed
        Seeds tie-breaking; the same seed and the same told buffers give the same requests.
    spp_min
        Every pixel is brought up to this many samples before any strategy applies; default ``initial_spp``.
    spp_max
        Most samples any pixel may have; ``None`` for no cap.
    round_spp
        Default budget of a round after the first, in samples per pixel; ``None`` grows rounds with the image's samples.
    round_growth
        Without ``round_spp``, a round's default budget is this share of the samples handed out so far (at least
        1 spp), so a render to ``S`` spp takes about ``log(S / initial_spp) / log(1 + round_growth)`` rounds. Larger
        rounds cost fewer priority analyses; docs/benchmarks.md ("The other defaults") measures it.
    executor
        Optional ``concurrent.futures.Executor`` (threads): :meth:`tell` merges on two of its threads and the ranking
        samplers search rare-path regions beside their density; the same requests and buffers (docs/performance.md).

    Examples
    --------
    The ask/tell loop by hand with a synthetic scene's renderer (the uniform strategy here):

    >>> from awr_denoise import UniformSampler
    >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
    >>> renderer = SyntheticRenderer(make_scene("edges", (16, 16)))
    >>> sampler = UniformSampler((16, 16))
    >>> request = sampler.ask()                  # round 0: initial_spp = 4 at every pixel
    >>> request, int(request.counts.min()), int(request.counts.max())
    (SampleRequest(round=0, shape=(16, 16), total=1024), 4, 4)
    >>> sampler.tell(request, renderer(request))
    SampleBuffer(shape=(16, 16), channels=('R', 'G', 'B'), total_samples=1024, spp=4)
    >>> request = sampler.ask()                  # then a quarter of the samples so far
    >>> request.total, int(request.first_index.min())
    (256, 4)
    >>> _ = sampler.tell(request, renderer(request))
    >>> sampler.run(renderer, total_spp=8), sampler.round     # the same loop, to 8 spp
    (SampleBuffer(shape=(16, 16), channels=('R', 'G', 'B'), total_samples=2048, spp=8), 5)
    """

    strategy = "base"
    _ranks = True
    """Whether later rounds rank pixels (a time budget costs them at round 0's, :data:`.rounds.RANKED_COST_MARGIN`)."""

    def __init__(self, shape: Shape2D, *, channels: int | tuple[str, ...] = 3, initial_spp: int = DEFAULT_INITIAL_SPP,
                 seed: int = 0, spp_min: int | None = None, spp_max: int | None = None, round_spp: float | None = None,
                 round_growth: float = DEFAULT_ROUND_GROWTH, executor: Executor | None = None) -> None:
        h, w = _checks.shape2d("shape", shape)
        least = int(self._ranks)  # a strategy ranking pixels by statistics needs a round 0 with some
        initial_spp = _checks.whole("initial_spp", initial_spp, minimum=least, maximum=MAX_BUDGET)
        spp_min = _checks.whole("spp_min", spp_min, minimum=0, maximum=MAX_BUDGET, none=True)
        spp_max = _checks.whole("spp_max", spp_max, minimum=1, maximum=MAX_BUDGET, none=True)
        if spp_min is not None and spp_max is not None and int(spp_min) > int(spp_max):
            raise ValueError(f"spp_min: {spp_min} exceeds spp_max {spp_max}")
        round_spp = _checks.real("round_spp", round_spp, above=0, maximum=MAX_BUDGET, none=True)
        round_growth = _checks.real("round_growth", round_growth, above=0, maximum=1e6)
        seed = _checks.seed("seed", seed)
        if (h * w) * max(initial_spp, round_spp or 0) > MAX_BUDGET:
            raise ValueError(f"shape: {h}x{w} pixels at {max(initial_spp, round_spp or 0):g} spp exceed "
                             f"the {MAX_BUDGET} samples a round may hold")
        self._shape, self.initial_spp = (h, w), int(initial_spp)
        self.spp_min = self.initial_spp if spp_min is None else int(spp_min)
        self.spp_max = None if spp_max is None else int(spp_max)
        if self.spp_max is not None:
            self.initial_spp, self.spp_min = min(self.initial_spp, self.spp_max), min(self.spp_min, self.spp_max)
        self.round_spp = round_spp
        self.round_growth = float(round_growth)
        self.seed = int(seed)
        self.executor = _checks.executor("executor", executor, here=False)
        self._buffer = SampleBuffer.empty((h, w), channels=channels)
        self._issued = np.zeros((h, w), np.int64)
        self._round = 0
        self._pending: SampleRequest | None = None
        self._id = _new_sampler_id()
        OneAtATime.__init__(self)  # ask, tell and resume: one call at a time, from any thread

    @classmethod
    def from_buffer(cls, buffer: SampleBuffer, *, round: int = 1, issued: CountArray | None = None,
                    **options) -> Sampler:
        """Resume from existing statistics (for example a sample dump on disk).

        ``issued``: the sample indices already handed out per pixel (default the buffer's counts), where new requests
        start. ``round`` numbers the next request (and seeds tie-breaking: pass the dump's to stay reproducible).

        Examples
        --------
        >>> from awr_denoise import AdaptiveSampler, SampleRequest
        >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
        >>> earlier = SyntheticRenderer(make_scene("edges", (16, 16)))(SampleRequest.uniform((16, 16), 4))
        >>> sampler = AdaptiveSampler.from_buffer(earlier, round=1)      # e.g. a dump read back
        >>> sampler.total_samples, sampler.ask().total, int(sampler.pending.first_index.min())
        (1024, 256, 4)
        """
        if not isinstance(buffer, SampleBuffer):
            raise TypeError(f"buffer: expected a SampleBuffer, got {type(buffer).__name__}")
        sampler = cls(buffer.shape, **{"channels": buffer.channels, **options})
        _checks.same_channels(options.get("channels"), sampler._buffer.channels, buffer.channels)
        sampler._buffer = buffer
        sampler._issued = np.array(_arrays.check_count(buffer.count if issued is None else issued, "issued"))
        if sampler._issued.shape != buffer.shape or (sampler._issued < buffer.count).any():
            raise ValueError("issued: must have the buffer's shape and be >= its counts")
        sampler._round = _checks.whole("round", round, minimum=0, maximum=LAST_ROUND)
        return sampler

    @property
    def shape(self) -> Shape2D:
        return self._shape

    @property
    def buffer(self) -> SampleBuffer:
        """Merged statistics of every sample told so far."""
        return self._buffer

    @property
    def issued(self) -> CountArray:
        """(H, W) sample indices handed out so far (told or pending)."""
        return self._issued.copy()

    @property
    def pending(self) -> SampleRequest | None:
        """The request asked for and not told yet, if any."""
        return self._pending

    @property
    def round(self) -> int:
        """Number of the next round to be asked."""
        return self._round

    @property
    def total_samples(self) -> int:
        """Samples told so far."""
        return self._buffer.total_samples

    @one_at_a_time
    def resume(self, request: SampleRequest) -> SampleRequest:
        """Take a request issued elsewhere as this sampler's pending one, so it can be told.

        A loop that runs through files (``awr plan`` writes a request map, a renderer answers it, ``awr merge``
        folds the answer in) rebuilds the sampler from the dump with :meth:`from_buffer` in every process; the
        request read back from its file then becomes pending here and :meth:`tell` merges it as in one process.

        Raises
        ------
        StaleRequestError
            A request is pending already, or ``request`` does not start where this sampler's samples stop
            (its ``first_index`` is not :attr:`issued`): its sample indices would repeat or skip.
        ValueError
            ``request`` is for another image size, or would take a pixel past ``spp_max``.

        Examples
        --------
        >>> import numpy as np
        >>> from awr_denoise import SampleBuffer, SampleRequest, UniformSampler
        >>> request = SampleRequest.uniform((2, 2), 3, round=0)
        >>> sampler = UniformSampler((2, 2), channels=1)
        >>> sampler.resume(request).round
        0
        >>> batch = SampleBuffer.from_moments(request.counts, np.ones((2, 2)), np.zeros((2, 2)))
        >>> sampler.tell(request, batch).total_samples, sampler.round
        (12, 1)
        """
        if not isinstance(request, SampleRequest):
            raise TypeError(f"request: expected a SampleRequest, got {type(request).__name__}")
        if self._pending is not None:
            raise StaleRequestError(f"request: round {self._pending.round} is pending; tell it first")
        if request.shape != self._shape:
            raise ValueError(f"request: shape {request.shape} does not match the sampler's {self._shape}")
        if not np.array_equal(request.first_index, self._issued):
            raise StaleRequestError(f"request: round {request.round} does not start where the samples so far stop "
                                    "(its first_index differs from the sample indices issued)")
        # Only where it samples: ask() leaves alone a pixel already past the cap (rendered before it was set).
        if self.spp_max is not None and (over := (request.counts > 0)
                                         & (request.first_index + request.counts > self.spp_max)).any():
            raise ValueError(f"request: {int(over.sum())} pixel(s) would exceed spp_max {self.spp_max}")
        self._pending, self._round = request, int(request.round)
        return request

    def default_budget(self) -> int:
        """Budget of the next round when :meth:`ask` is given none (a growing round: at least 1 spp)."""
        pixels = self._shape[0] * self._shape[1]
        if self._round == 0:
            return self.initial_spp * pixels
        if self.round_spp is not None:
            return max(1, int(round(self.round_spp * pixels)))
        return max(pixels, int(self.round_growth * self._issued.sum()))

    @one_at_a_time
    def ask(self, budget: int | None = None) -> SampleRequest:
        """The next request; asking again before :meth:`tell` returns the same request.

        Parameters
        ----------
        budget
            Total new samples; default :meth:`default_budget`. Round 0 spreads its budget uniformly.

        Examples
        --------
        >>> from awr_denoise import AdaptiveSampler
        >>> sampler = AdaptiveSampler((8, 8))
        >>> request = sampler.ask(100)               # round 0 spreads any budget uniformly
        >>> request.total, sorted(set(request.counts.ravel().tolist())), sampler.ask() is request
        (100, [1, 2], True)
        """
        budget = _checks.whole("budget", budget, minimum=0, maximum=MAX_BUDGET, none=True, integral=True)
        if self._pending is not None:
            if budget is not None and int(budget) != self._pending.total:
                raise StaleRequestError(f"budget: round {self._pending.round} is pending with {self._pending.total} "
                                        f"samples; tell it before asking for {budget}")
            return self._pending
        target = self.default_budget() if budget is None else int(budget)
        capacity = None if self.spp_max is None else np.maximum(self.spp_max - self._issued, 0)  # resumed: >= 0
        if capacity is not None and target > (left := int(capacity.sum())):  # the budget asked, not a share of it
            raise ValueError(f"{'budget' if budget is not None else 'the default budget'}: {target} samples exceed "
                             f"the {left} that spp_max still allows"
                             + ("" if left else " (every pixel has its spp_max samples: the run is complete)"))
        if self._round > LAST_ROUND:  # the last round a request may number has been told (the call takes no round)
            raise ValueError("the sampler: its rounds are spent (round 2**31 - 1, the last a request numbers, is told)")
        rng = np.random.default_rng([self.seed, self._round])
        counts = np.zeros(self._shape, np.int64)
        topped_up = False
        # Every pixel has spp_min already when the least-sampled one has (no whole-image deficit then).
        if self._round > 0 and self._issued.min(initial=self.spp_min) < self.spp_min:
            deficit = np.maximum(self.spp_min - self._issued, 0)
            if capacity is not None:
                deficit = np.minimum(deficit, capacity)
            if deficit.any():
                # Bring every pixel up to spp_min first (uniformly if the budget is short).
                share = min(target, int(deficit.sum()))
                counts += _allocate(deficit * 1.0, 0 * deficit, share, capacity=deficit, rng=rng)  # float, int
                topped_up = True
        rest = target - int(counts.sum()) if topped_up else target
        if rest:
            current = self._issued + counts if topped_up else self._issued
            cap = None if capacity is None else capacity - counts
            # Round 0, or every sample told so far dropped (non-finite): nothing to rank on, so uniform.
            if self._round == 0 or self._buffer.total_samples == 0:
                counts += _allocate(np.ones(self._shape), current, rest, capacity=cap, rng=rng)
            else:
                counts += self._allocate(rest, current, cap, rng)
        self._pending = SampleRequest(counts, self._issued.copy(), self._round, self._id)
        return self._pending

    @one_at_a_time
    def tell(self, request: SampleRequest | int, samples: SampleBuffer) -> SampleBuffer:
        """Merge the samples rendered for ``request``; returns the merged statistics.

        Features the renderer returned with them (albedo, normal, depth) are merged the same way
        (:func:`~awr_denoise.features.merge_features`).

        Raises
        ------
        StaleRequestError
            If ``request`` is not this sampler's pending request (told already, another sampler's, or never asked).
        ValueError
            If ``samples`` does not match the image or has more samples at a pixel than asked.

        Examples
        --------
        >>> from awr_denoise import UniformSampler
        >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
        >>> sampler, renderer = UniformSampler((8, 8)), SyntheticRenderer(make_scene("edges", (8, 8)))
        >>> request = sampler.ask()
        >>> sampler.tell(request, renderer(request)).total_samples, sampler.round
        (256, 1)
        >>> sampler.tell(request, renderer(request))
        Traceback (most recent call last):
            ...
        awr_denoise.errors.StaleRequestError: request: round 0 is not pending (nothing was asked, or it was told)
        """
        pending = self._pending
        number = request.round if isinstance(request, SampleRequest) else request
        if pending is None:
            raise StaleRequestError(f"request: round {number} is not pending (nothing was asked, or it was told)")
        if isinstance(request, SampleRequest):
            if request is not pending and (request.sampler_id != pending.sampler_id or request.round != pending.round):
                raise StaleRequestError(f"request: round {request.round} of sampler {request.sampler_id} is not "
                                        f"the pending round {pending.round} of this sampler ({pending.sampler_id})")
        elif isinstance(request, (int, np.integer)) and not isinstance(request, bool):
            if int(request) != pending.round:
                raise StaleRequestError(f"request: round {request} is not the pending round {pending.round}")
        else:
            raise TypeError(f"request: expected a SampleRequest or a round number, got {type(request).__name__}")
        told = pending.check_answer(samples, self._buffer.channels)
        try:
            self._buffer = self._buffer.merge(told, executor=self.executor)
        except ValueError as error:  # shapes and channels are checked: a merge past float64 names merge's `other`
            if not str(error).startswith("other: "):
                raise
            raise ValueError(f"samples: {str(error).removeprefix('other: ')}") from None
        pending.mark_told(samples)
        self._issued = self._issued + pending.counts
        self._round += 1
        self._pending = None
        return self._buffer

    def run(self, renderer: Renderer, total_spp: float | None = None, *, seconds: float | None = None,
            reserve: float | Callable[[SampleBuffer], float] | None = None, progress: bool = False,
            callback: Callable[[SampleRequest, SampleBuffer], bool | None] | None = None) -> SampleBuffer:
        """Ask, render, tell until the image holds ``total_spp`` samples per pixel on average, or for ``seconds``.

        Built only from :meth:`ask` and :meth:`tell` (:mod:`.rounds`); the last round is trimmed so the total is
        exact. ``total_spp``: 32 without ``seconds``, no goal with it. With ``seconds`` the rounds are planned to
        end within it (the first is always rendered; docs/sampling.md, "A time budget"), and the counts depend on
        the machine; ``reserve`` keeps seconds of it for the reconstruction after the run: a number below it, or a
        function of the buffer after the first round (:func:`~awr_denoise.rounds.reconstruction_seconds`).
        ``callback(request, buffer)`` runs after every round; returning ``False`` stops.

        Examples
        --------
        >>> from awr_denoise import AdaptiveSampler
        >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
        >>> renderer, rounds = SyntheticRenderer(make_scene("edges", (16, 16))), []
        >>> AdaptiveSampler((16, 16)).run(renderer, total_spp=10).total_samples    # exactly 10 spp
        2560
        >>> def two_rounds(request, buffer):
        ...     rounds.append(request.total)
        ...     return len(rounds) < 2
        >>> AdaptiveSampler((16, 16)).run(renderer, total_spp=32, callback=two_rounds).total_samples, rounds
        (768, [512, 256])
        >>> AdaptiveSampler((16, 16)).run(renderer, seconds=0.5).total_samples >= 512   # as many as 0.5 s allow
        True
        """
        return run_rounds(self, renderer, total_spp, seconds=seconds, reserve=reserve, progress=progress,
                          callback=callback)

    def _prepare(self) -> None:
        """Rank the pixels for the next :meth:`ask` now, timed before a round's size is chosen (:mod:`.rounds`)."""

    def _allocate(self, budget: int, current: CountArray, capacity: CountArray | None,
                  rng: np.random.Generator) -> CountArray:
        raise NotImplementedError


class UniformSampler(Sampler):
    """Every pixel gets the same number of samples (to within one); the plain Monte Carlo baseline.

    Examples
    --------
    >>> from awr_denoise import UniformSampler
    >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
    >>> buffer = UniformSampler((8, 8)).run(SyntheticRenderer(make_scene("edges", (8, 8))), total_spp=6.5)
    >>> buffer.total_samples, sorted(set(buffer.count.ravel().tolist()))
    (416, [6, 7])
    """

    strategy = "uniform"
    _ranks = False

    def _allocate(self, budget, current, capacity, rng):
        return _allocate(np.ones(self._shape), current, budget, capacity=capacity, rng=rng)


class VarianceSampler(Sampler):
    """Per-pixel variance-driven sampling, a baseline in the spirit of Cycles' adaptive sampling.

    Samples go where the per-pixel *relative* error is large: the allocation equalises the marginal error reduction
    ``s2_p / (n_p (n_p + 1))`` of each pixel in the error domain (``"log"``: relative error), i.e. ``n_p ~ s_p``. No
    wavelet structure is used. ``uniform_fraction``, ``absolute_above`` and ``rare_paths`` as for
    :class:`AdaptiveSampler` (the same defaults, so the two compare like with like).

    Examples
    --------
    The ``gradient`` scene's noise grows from left to right, relative to its brightness too:

    >>> from awr_denoise import VarianceSampler
    >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
    >>> buffer = VarianceSampler((32, 32)).run(SyntheticRenderer(make_scene("gradient", (32, 32))), total_spp=16)
    >>> bool(buffer.count[:, 16:].sum() > 2 * buffer.count[:, :16].sum())
    True
    """

    strategy = "variance"

    def __init__(self, shape: Shape2D, *, domain: str | Domain = "log", uniform_fraction: float = 0.0,
                 absolute_above: float | None = DEFAULT_ABSOLUTE_ABOVE, rare_paths: str = DEFAULT_RARE_PATHS,
                 **options) -> None:
        super().__init__(shape, **options)
        self.domain = resolve_domain(domain)  # checked now, not at the first adaptive ask() after round 0
        self.uniform_fraction = _checks.real("uniform_fraction", uniform_fraction, minimum=0.0, maximum=1.0)
        self.absolute_above = _checks.real("absolute_above", absolute_above, above=0, none=True)
        self.rare_paths = _checks.name("rare_paths", rare_paths, RARE_PATHS)

    def _density(self) -> FloatArray:
        with rare_path_evening(self._buffer, self.rare_paths, self.executor) as even:  # searched beside the density
            density = even(pooled_deviation(self._buffer, self.domain, absolute_above=self.absolute_above))
        return dropped_at_mean(density, self._buffer.count, self._issued)

    def _allocate(self, budget, current, capacity, rng):
        return _allocate_mixed(self._density(), current, budget, self.uniform_fraction, capacity=capacity, rng=rng)


class AdaptiveSampler(Sampler):
    """Adaptive Wavelet Rendering's sampler (paper section 4).

    Each round, every pixel finds the level ``l_p`` whose covering scale coefficient has the highest priority
    ``P_k = 4^k (Var(S~_k) - sum_a max(0, W~^2 - (2 Delta)^2))``, and the round's budget is spread so that totals
    approach ``n_p ~ s_p 2^(-w l_p)``: samples concentrate on edges (fine levels win) and spread thinly over smooth
    noisy regions (coarse levels win), see :mod:`awr_denoise.priorities`.

    Parameters
    ----------
    shape, channels, initial_spp, seed, spp_min, spp_max, round_spp, round_growth, executor
        See :class:`Sampler`; the executor's threads also compute every ``ask()``'s priorities (and gain).
    wavelet, levels
        Wavelet and depth of the priority analysis (as in :func:`~awr_denoise.reconstruct`).
    domain
        Error domain of the priorities; use the reconstruction's (``"log"`` by default).
    level_weight
        ``noise_model="levels"`` only (refused with the others): ``w`` in ``n_p ~ s_p 2^(-w l_p)``; ``w = 1`` if
        reconstruction averaged a smooth region completely, measured best near 0.25, the default (docs/sampling.md).
        0 turns the sampler into per-pixel variance sampling.
    uniform_fraction
        Share of every round spread uniformly, insurance against variance estimates that are wrong (all first samples
        of a region may miss a small light); off by default: measured, it cost relMSE and bought nothing (sampling.md).
    absolute_above
        ``s_p`` is the error in ``domain`` with each pixel's level capped at this many times the image's mean level: a
        small bright source is ranked by its absolute error, not starved (``None``: not capped;
        :func:`~awr_denoise.priorities.pooled_deviation`, docs/sampling.md "Relative and absolute error").
    noise_model, gain_refresh
        What reconstruction leaves of a pixel's noise (docs/sampling.md, "The noise gain"): ``"levels"`` (the paper's
        model above), ``"shrinkage"`` (the default: ``n_p ~ s_p sqrt(g_p)``, ``g_p`` a Wiener shrinkage's exact share,
        :func:`~awr_denoise.noise_gain.shrinkage_gain`) or ``"reconstruction"`` (``g_p`` the default reconstruction's
        measured share, measured again once the samples grow by ``gain_refresh``, default 1: every round,
        :class:`~awr_denoise.noise_gain.MeasuredGain`; several times the sampler's time).
    rare_paths
        ``"even"`` (default): a rare-path region (most samples 0, or fireflies on a lit base) gets one density, its
        pixels' mean; ``"zeros"`` evens the first kind only; ``"ranked"``: 4-32% dark (:mod:`~awr_denoise.rare_paths`).

    Examples
    --------
    A small light 1000x brighter than its surroundings: its pixels take several times the
    samples of the rest, where :class:`UniformSampler` gives every pixel the same.

    >>> from awr_denoise import AdaptiveSampler
    >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
    >>> scene = make_scene("hdr_source", (32, 32))
    >>> light = scene.reference()[..., 1] > 1.0
    >>> buffer = AdaptiveSampler(scene.shape).run(SyntheticRenderer(scene), total_spp=16)
    >>> buffer.total_samples, bool(buffer.count[light].mean() > 4 * buffer.count[~light].mean())
    (16384, True)
    """

    strategy = "awr"

    def __init__(self, shape: Shape2D, *, channels: int | tuple[str, ...] = 3, initial_spp: int = DEFAULT_AWR_INITIAL_SPP,
                 wavelet: str = DEFAULT_WAVELET, levels: int | None = None, seed: int = 0,
                 spp_min: int | None = None, spp_max: int | None = None, round_spp: float | None = None,
                 round_growth: float = DEFAULT_ROUND_GROWTH, domain: str | Domain = "log", level_weight: float | None = None,
                 uniform_fraction: float = 0.0, noise_model: str = DEFAULT_NOISE_MODEL, gain_refresh: float | None = None,
                 absolute_above: float | None = DEFAULT_ABSOLUTE_ABOVE, rare_paths: str = DEFAULT_RARE_PATHS,
                 executor: Executor | None = None) -> None:
        super().__init__(shape, channels=channels, initial_spp=initial_spp, seed=seed, spp_min=spp_min,
                         spp_max=spp_max, round_spp=round_spp, round_growth=round_growth, executor=executor)
        wavelet_operators(self._shape, wavelet=wavelet, levels=levels)  # validates wavelet and levels now
        self.wavelet, self.levels, self.domain = wavelet, levels, resolve_domain(domain)  # checked before round 0
        self.uniform_fraction = _checks.real("uniform_fraction", uniform_fraction, minimum=0.0, maximum=1.0)
        self.noise_model = _checks.name("noise_model", noise_model, NOISE_MODELS)
        for name, value, model in (("level_weight", level_weight, "levels"),
                                   ("gain_refresh", gain_refresh, "reconstruction")):
            if value is not None and self.noise_model != model:  # it would do nothing: refused
                raise ValueError(f"{name}: {value!r} needs noise_model={model!r}, not {self.noise_model!r}")
        self.level_weight = _checks.real("level_weight", 0.25 if level_weight is None else level_weight, minimum=0)
        self._prepared: tuple[int, FloatArray] | None = None  # (round, density) ranked ahead of ask()
        self._gain = None if self.noise_model != "reconstruction" else MeasuredGain(
            DEFAULT_GAIN_REFRESH if gain_refresh is None else gain_refresh)
        self.absolute_above = _checks.real("absolute_above", absolute_above, above=0, none=True)
        self.rare_paths = _checks.name("rare_paths", rare_paths, RARE_PATHS)

    @one_at_a_time
    def density(self) -> FloatArray:
        """(H, W) density of the next round: :func:`~awr_denoise.priorities.sampling_density`, rare paths evened."""
        with rare_path_evening(self._buffer, self.rare_paths, self.executor) as even:  # searched beside the density
            gain = None if self._gain is None else self._gain(self._buffer, self.executor)  # round 0 is uniform: none
            density = sampling_density(self._buffer, wavelet=self.wavelet, levels=self.levels, domain=self.domain,
                                       level_weight=self.level_weight, noise_gain=gain, noise_model=self.noise_model,
                                       absolute_above=self.absolute_above, executor=self.executor)
            return dropped_at_mean(even(density), self._buffer.count, self._issued)

    def _prepare(self) -> None:
        if self._round > 0 and self._pending is None and self._buffer.total_samples > 0:
            self._prepared = (self._round, self.density())

    def _allocate(self, budget, current, capacity, rng):
        prepared, self._prepared = self._prepared, None
        density = prepared[1] if prepared is not None and prepared[0] == self._round else self.density()
        return _allocate_mixed(density, current, budget, self.uniform_fraction, capacity=capacity, rng=rng)


SAMPLERS: dict[str, type[Sampler]] = {cls.strategy: cls for cls in (AdaptiveSampler, UniformSampler, VarianceSampler)}
"""The samplers by strategy name: ``"awr"``, ``"uniform"``, ``"variance"``."""
