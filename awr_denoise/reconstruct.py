"""Reconstruction: the paper's thresholding (section 5, Eq. 10-11), then empirical Wiener stages.

1. **Stage 1** (:mod:`awr_denoise.thresholding`): every wavelet coefficient of the pixel means is
   soft-thresholded at ``c_s`` times its exact standard error (Eq. 10-11) on the decimated
   transform, in the thresholding domain. ``stages=1`` returns this, the paper's reconstruction,
   with every pixel clamped to ``pixel_clamp`` standard errors of its own mean.
2. **Stages 2, 3, ...** (:mod:`awr_denoise.wiener`): the previous estimate is the pilot of an empirical Wiener
   filter on the undecimated transform (:mod:`awr_denoise.stationary`), in a domain relative to the pilot
   (``x / (|pilot| + k)^alpha``, one ``alpha`` per stage from ``wiener_exponents``). Every variance stays exact
   because each stage is linear in the means for its pilot. The first of several stages floors its pilot's
   (stage 1's) energy by the means' own local evidence (:data:`~awr_denoise.wiener.DEFAULT_FLOOR`, channel mode).
3. **Finishing** (:mod:`awr_denoise.finishing`): the pooled pixel clamp, no negative radiance,
   and the image mean of every channel equal to the input's.

docs/reconstruction.md has the measurements behind every default.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from . import _checks
from ._signals import stop_point
from ._typing import FloatArray
from .buffers import SampleBuffer
from .channels import channel_groups, luminance_weights
from .domains import Domain
from .finishing import clip_negative, pooled_clamp, restore_mean
from .guided import checked_inputs, checked_projection, guide_colour, guide_fields, pilots, projected
from .prepare import Prepared, prepare
from .settings import (DEFAULT_C_S, DEFAULT_PILOT_C_S, DEFAULT_PIXEL_CLAMP, DEFAULT_PRECISION, DEFAULT_STAGES,
                       DEFAULT_WIENER_EXPONENTS, PRECISIONS, Settings, resolve_settings)
from .stationary import precision_for, stationary_transform
from .sure import DEFAULT_GUIDED_TOLERANCE, DEFAULT_GUIDED_WINDOW, DEFAULT_WINDOW, sure_blend
from .thresholding import threshold_stage
from .wavelets import DEFAULT_WAVELET, wavelet_operators
from .wiener import DEFAULT_FLOOR, chain

__all__ = ["reconstruct", "reconstruct_detailed", "Reconstruction", "Settings", "resolve_settings", "later_stages",
           "MODES", "DEFAULT_C_S", "DEFAULT_PILOT_C_S", "DEFAULT_DOMAIN", "DEFAULT_MODE", "DEFAULT_PIXEL_CLAMP",
           "DEFAULT_STAGES", "DEFAULT_WIENER_EXPONENTS", "DEFAULT_PRECISION", "PRECISIONS"]

MODES = ("channels", "luminance")
"""``"channels"``: each channel thresholded with its own Delta; ``"luminance"``: thresholds
decided on luminance, the same shrink factor applied to every channel (hue-preserving)."""

DEFAULT_MODE = MODES[0]
"""Default mode: every channel thresholded with its own Delta."""

DEFAULT_DOMAIN = "log"
"""Default thresholding domain of stage 1; chosen by measurement (docs/reconstruction.md)."""

@dataclass(frozen=True, eq=False)
class Reconstruction:
    """Result of :func:`reconstruct_detailed`.

    Attributes
    ----------
    image
        (H, W, C) reconstructed image.
    thresholds
        Per channel, stage 1's ``c_s * Delta`` in :func:`~awr_denoise.wavelets.forward`'s
        layout (detail bands only: ``[None, (tH, tV, tD)_L, ..., (tH, tV, tD)_1]``), in the
        thresholding domain.
    fraction_zeroed
        Fraction of detail coefficients stage 1 set to zero, over all channels (over the first
        colour's where other channels are reconstructed apart, :func:`~awr_denoise.channels.channel_groups`).
    variance
        (H, W, C) estimated variance of the output (see Notes of :func:`reconstruct_detailed`).
    levels
        Decomposition depth of stage 1.
    domain
        The domain stage 1 thresholded in.
    parameters
        The settings that made it, resolved (``c_s``, ``wavelet``, ``levels``, ``domain``
        name, ``mode``, ``boundary``, ``pixel_clamp``, ``stages``, ...): what a file's
        provenance records.
    noise_gain
        (H, W) share of each pixel's noise variance that the Wiener stages and the guard pass
        on to the image, ``(1 - l)^2 + l (2 - l) L`` for the guard's share ``l`` and the stages'
        diagonal ``L`` (channel mean, the first colour's as ``fraction_zeroed``; ``None`` without the guard), and 1
        at pixels without samples. What ``AdaptiveSampler(noise_model="reconstruction")`` spends samples by
        (docs/sampling.md).

    Examples
    --------
    A flat grey image under noise of one standard error per pixel (8 samples of variance 0.08):

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer, reconstruct_detailed
    >>> rng = np.random.default_rng(1)
    >>> mean = 0.5 + 0.1 * rng.standard_normal((32, 32, 3))
    >>> buffer = SampleBuffer.from_moments(np.full((32, 32), 8), mean, np.full((32, 32, 3), 0.08))
    >>> result = reconstruct_detailed(buffer, stages=1, variance_probes=4)
    >>> result.image.shape, result.levels, result.domain.name
    ((32, 32, 3), 2, 'log')
    >>> round(result.fraction_zeroed, 2)              # pure noise: most details are zeroed
    0.69
    >>> bool((result.variance < buffer.variance_of_mean()).all())
    True
    >>> {key: result.parameters[key] for key in ("c_s", "wavelet", "pixel_clamp", "stages")}
    {'c_s': 1.0, 'wavelet': 'bior4.4', 'pixel_clamp': 2.5, 'stages': 1}
    """

    image: FloatArray
    thresholds: list
    fraction_zeroed: float
    variance: FloatArray
    levels: int
    domain: Domain
    parameters: dict = field(default_factory=dict)
    noise_gain: FloatArray | None = None


def _wiener_levels(levels: int) -> int:
    """Stationary stages' depth: stage 1's less one from 4 levels on (as good, 20% faster; below, every
    level counts: a third of the gain lost at 32x32 with 1 level not 2; docs/reconstruction.md)."""
    return levels - 1 if levels >= 4 else levels


def _wiener_stages(prepared: Prepared, pilot: FloatArray, exponents: tuple[float, ...], *, levels: int, wavelet: str,
                   precision: str, luminance: tuple[Prepared, FloatArray] | None, guard: bool, probes: int, seed: int,
                   run: Callable, parallel: bool, keep: FloatArray | float, guide: FloatArray | None,
                   projection: float, floor: tuple[int, float] | None = DEFAULT_FLOOR,
                   window: int = DEFAULT_WINDOW, guard_probes: int = 0, tolerance: float = 1.0,
                   spared_beside: float | None = None) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """Stages 2.. and the SURE guard on the image brought to unit scale; the probe variance if asked, the noise gain.

    With ``parallel`` the Wiener stages filter their bands on ``run``'s threads (an executor's
    map; :func:`~awr_denoise.wiener.chain`), every channel together, and the guard's two criteria
    run side by side: the same image, bit for bit.
    """
    s, k, x, v = prepared.unit_scaled()
    # 1 / k as well: a domain scale given far below the image's level leaves k tiny at the image's.
    transform = stationary_transform(x.shape[:2], wavelet, levels, precision_for(precision, k, 1.0 / k, x, pilot / s))
    options = {"k": k, "leverage": guard, "probes": probes, "keep": keep, "seed": seed,
               "run": run if parallel else None, "divergence_probes": guard_probes if guard else 0}
    # The first Wiener stage's energy floor needs each channel's own factors: channel mode only.
    floor_setting = floor if luminance is None else None
    if luminance is None:  # every channel in one call: each band's transfer functions are built once
        done = chain(transform, x, v, pilot / s, exponents, weights=None, shared=None, floor=floor_setting, **options)
    else:
        done = chain(transform, x, v, pilot / s, exponents, weights=luminance[1],
                     shared=luminance[0].variance / s / s, **options)
    out, var_out, leverage = done.image, done.variance, done.leverage
    if guide is not None and luminance is None:  # channel mode: the means projected on the guide (.guided)
        g = np.where(keep > 0, guide, 0.0) / s  # where the gate is closed a guide may be near overflow
        out, leverage, var_out = projected(transform, x, v, g, out, leverage, keep, k=k, probes=probes, seed=seed,
                                           probe_variance=var_out, projection=projection)
    gain = None
    if guard:
        assert leverage is not None
        stop_point()
        # The guard's risk needs the stages' divergence: their diagonal (factors held), or measured.
        divergence = leverage if done.divergence is None else done.divergence
        if luminance is None:
            out, lam = sure_blend(out, x, v, divergence, k=k, window=window, run=options["run"],
                                  measured=prepared.sampled, tolerance=tolerance, spared_beside=spared_beside)
        else:  # one share for every channel, decided on luminance: hue is kept
            weights = luminance[1]
            _, lam = sure_blend(out @ weights, x @ weights, luminance[0].variance / s / s,
                                divergence[..., 0] if done.divergence is None else divergence @ weights, k=k,
                                window=window, measured=prepared.sampled, tolerance=tolerance,
                                spared_beside=spared_beside)
            lam = lam[..., None]
            out = x + lam * (out - x)
        if var_out is not None:
            # (1 - l) x + l o, with Cov(x, o) = L v on the diagonal of a linear map.
            var_out = (1 - lam) ** 2 * v + lam * lam * var_out + 2 * lam * (1 - lam) * leverage * v
        # A pixel's noise reaches the blend as (1 - l)^2 + 2 l (1 - l) L + l^2 sum_q A_qp^2; the last sum
        # is taken as L, its value for a projection (a shrinkage's is at most about L; held at 0 or above).
        gain = np.maximum(np.mean((1 - lam) ** 2 + lam * (2 - lam) * leverage, axis=-1), 0.0)
        if prepared.sampled is not None:  # nothing measured there has been reduced: samples must still go there
            gain[~prepared.sampled] = 1.0
    return out * s, None if var_out is None else var_out * s * s, gain


def later_stages(prepared: Prepared, image: FloatArray, variance: FloatArray | None, settings: Settings, *, levels: int,
                 wavelet: str, luminance: tuple[Prepared, FloatArray] | None = None, run: Callable | None = None,
                 keep: FloatArray | float = 0.0, guide: FloatArray | None = None, projection: float = 0.0
                 ) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """Everything after stage 1: the Wiener stages, the guard, the pixel clamp, non-negativity, the mean.

    Parameters
    ----------
    prepared
        The whole image's planes (:func:`~awr_denoise.prepare.prepare`).
    image, variance, keep
        Stage 1's result (the first Wiener stage's pilot) and its variance (or ``None``); ``keep``: the
        (H, W, 1) share of that pilot every later stage keeps in its own (:func:`~awr_denoise.guided.pilots`);
        ``guide``: the checked guide, whose projection takes ``projection`` of the result (:func:`~awr_denoise.guided.projected`).
    settings
        From :func:`resolve_settings`.
    levels, wavelet
        Stage 1's depth and wavelet.
    luminance
        Luminance mode: the luminance plane (prepared with ``prepared.domain``) and weights.
    run
        ``run(f, items)``, an executor's ``map``: the Wiener stages' bands two at a time on its
        threads and the guard's two criteria side by side (the same result); default: one thread.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray or None, numpy.ndarray or None)
        The image, its variance (see :func:`reconstruct_detailed`, Notes) and the noise gain
        (:attr:`Reconstruction.noise_gain`).
    """
    parallel = run is not None
    run, gain = run or (lambda f, items: [f(i) for i in items]), None
    if settings.stages > 1:
        image, variance, gain = _wiener_stages(prepared, image, settings.exponents, levels=_wiener_levels(levels),
                                               wavelet=wavelet, precision=settings.precision, luminance=luminance,
                                               guard=settings.guard, probes=settings.probes, seed=settings.seed, run=run,
                                               parallel=parallel, keep=keep, guide=guide, projection=projection,
                                               floor=settings.floor, window=settings.guard_window,
                                               guard_probes=settings.guard_probes,
                                               tolerance=settings.guard_tolerance,
                                               spared_beside=settings.guard_spared_beside)
        stop_point()
        if settings.pixel_clamp is not None:
            lum = None if luminance is None else luminance[0]
            image, moved = pooled_clamp(image, prepared.mean if lum is None else lum.mean,
                                        prepared.variance if lum is None else lum.variance, settings.pixel_clamp,
                                        weights=None if luminance is None else luminance[1], count=prepared.count)
            if variance is not None:
                variance = np.where(moved, prepared.variance, variance)
    if settings.nonnegative:
        image, clipped = clip_negative(image, prepared.mean)
        if variance is not None:
            variance = np.where(clipped, 0.0, variance)
    if settings.preserve_mean:
        stop_point()
        image, t = restore_mean(image, prepared.mean, prepared.variance, run=run)
        if variance is not None:  # a blend (1 - t) o + t x: at most the blend of the standard errors
            variance = ((1 - t) * np.sqrt(variance) + t * np.sqrt(prepared.variance)) ** 2
    return image, variance, gain


def reconstruct_detailed(
    buffer: SampleBuffer,
    *,
    c_s: float | None = None,
    wavelet: str = DEFAULT_WAVELET,
    levels: int | None = None,
    domain: str | Domain = DEFAULT_DOMAIN,
    mode: str = DEFAULT_MODE,
    boundary: str = "symmetric",
    executor: Executor | None = None,
    pixel_clamp: float | None = DEFAULT_PIXEL_CLAMP,
    stages: int = DEFAULT_STAGES,
    wiener_exponents: Sequence[float] = DEFAULT_WIENER_EXPONENTS,
    guard: bool | None = None,
    guard_window: int | None = None,
    guard_probes: int | None = None,
    preserve_mean: bool | None = None,
    nonnegative: bool | None = None,
    precision: str = DEFAULT_PRECISION,
    variance_probes: int = 16,
    seed: int = 0,
    guide: FloatArray | None = None,
    guide_projection: float | None = None,
    features: bool = False,
) -> Reconstruction:
    """Reconstruct an image from sample statistics and report what the stages did.

    Parameters
    ----------
    buffer
        Per-pixel sample statistics.
    c_s
        Smoothing constant of Eq. 11 in stage 1: thresholds are ``c_s`` standard errors.
        ``0`` with ``stages=1`` returns the Monte Carlo mean (as the Wiener stages' pilot, the means
        are what they shrink against); about 0.5-2 is useful. Default
        :data:`DEFAULT_C_S` (1.0) with ``stages=1``, :data:`DEFAULT_PILOT_C_S` (2.0) when
        stage 1 is the pilot of Wiener stages.
    wavelet
        PyWavelets wavelet of every stage; ``"bior4.4"`` (CDF 9/7) by default.
    levels
        Decomposition depth; default :func:`~awr_denoise.wavelets.default_levels`.
    domain
        Stage 1's thresholding domain: ``"log"`` (default), ``"gamma"`` or ``"linear"``
        (the paper, literally), or a :class:`~awr_denoise.domains.Domain`; its offset ``k``
        is also the offset of the Wiener stages' weights.
    mode
        ``"channels"`` (default) or ``"luminance"`` (every stage decides on luminance and
        applies one factor to every channel: hue-preserving), see :data:`MODES`.
    boundary
        PyWavelets signal extension mode of stage 1.
    executor
        Optional ``concurrent.futures.Executor``: stage 1's channels, the Wiener stages' bands
        (two at a time, from 512x512 on) and the guard's two criteria run on its threads, with
        the same result as without (numpy, scipy, PyWavelets and ducc0 release the GIL; more
        memory: docs/performance.md, Threads).
    pixel_clamp
        Keep every output pixel within ``pixel_clamp`` standard errors of its own mean: Eq. 11
        picks each *coefficient* inside its confidence interval, and this asks the same of each
        *pixel*. With ``stages=1`` in the thresholding domain; with Wiener stages once, after
        them, in radiance, each pixel's standard error pooled with its neighbours' (its 3x3
        median if larger); their pilot, stage 1, then runs unclamped. It stops the blur of a
        bright edge from leaking into dark pixels whose means are precise. Default 2.5.
    stages
        ``1``: the paper's reconstruction (stage 1 alone). ``n > 1``: stage 1 as the pilot of
        ``n - 1`` empirical Wiener stages on the undecimated transform. Default
        :data:`DEFAULT_STAGES`.
    wiener_exponents
        ``alpha`` of each Wiener stage (``x / (|pilot| + k)^alpha``; 1: relative to the pilot,
        0: linear); at least ``stages - 1`` of them, in [0, 1]; with more, the last ones (``stages=2``:
        one stage at 0.4, the measured trade of docs/reconstruction.md, "A cheaper default, measured").
    guard
        After the Wiener stages, keep in every ``guard_window`` square only the share of their change
        from the plain mean that Stein's unbiased risk estimate says lowers both the squared and
        the relative squared error (:mod:`awr_denoise.sure`), a change kept whole up to
        :data:`~awr_denoise.sure.DEFAULT_TOLERANCE` times the noise it may remove (but beside a much
        brighter pixel: :data:`~awr_denoise.sure.DEFAULT_SPARED_BESIDE`). Default: on with Wiener
        stages; it needs them (``stages > 1``).
    guard_window
        Side of the guard's square neighbourhood (odd; default :data:`~awr_denoise.sure.DEFAULT_WINDOW`,
        9, and :data:`~awr_denoise.sure.DEFAULT_GUIDED_WINDOW`, 17, with a ``guide`` the gate
        trusts). Wider windows estimate the share with less noise: 13 and 17 measured up to 7% lower
        relMSE on eight of the ten bundled and Mitsuba scenes, but up to 11% higher MSE next to a
        small, very bright light (docs/reconstruction.md, "The guard's window, measured").
    guard_probes
        ``0`` (default): the guard's risk takes the Wiener stages' diagonal with their factors held
        fixed. ``n > 0``: their divergence measured by ``n`` random probes, each a second run of the
        Wiener stages (:func:`~awr_denoise.wiener.chain`). The stages follow a pixel's own mean more
        than their diagonal says (each stage's pilot is made from the same means), most in texture at
        the scale of one pixel, where the default has up to 2.5x the plain mean's relMSE and one
        probe brings it to 1.3x or below; on the rendered scenes of both renderers it costs 2-10%
        relMSE and 1.7-1.9x the time (docs/reconstruction.md, "The guard's divergence"). Not with a
        ``guide``.
    preserve_mean
        Give every channel back the energy the stages took, where they took it, so its image
        mean equals the input's, exactly (to rounding; :func:`~awr_denoise.finishing.restore_mean`:
        a channel of negative mean as its mirror image; none whose input and output means differ
        in sign; a change beyond 5% only where it is significant).
        Default: on with Wiener stages, off with ``stages=1`` (the paper's reconstruction as it is).
    nonnegative
        Zero negative output pixels in every channel whose means are all >= 0 (before the
        mean is matched, so the output stays >= 0). Default as ``preserve_mean``.
    precision
        ``"float32"`` (default) or ``"float64"``: the FFTs of the Wiener stages and stage 1 in
        the log domain (:func:`~awr_denoise.thresholding.threshold_stage`); float64 is the reference.
    variance_probes
        Random probes used to estimate :attr:`Reconstruction.variance`; each costs one
        transform pair per channel. ``0`` skips the estimate (the variance is then NaN).
    seed
        Seed of the probes.
    guide, features
        An (H, W, C) image or a function of the buffer making one (:func:`awr_denoise.guides.oidn`), or ``True``:
        the pilot of the Wiener stages where the samples allow it, the guide's or the features' (:mod:`.guided`).
        Beside an alpha or an AOV a guide may hold the colour's channels alone, and guides it alone.
        Given both, the guide is the pilot and the features are not used (measured: the feature pilot
        where the guide's gate closes changed nothing, docs/guides.md, "What else was tried").
    guide_projection
        With a guide: the share of the result taken from the means projected on it, in [0, 1] (default
        :data:`~awr_denoise.guided.PROJECTION_SHARE`; 0: the guide is the pilot only; docs/guides.md).
        In ``mode="luminance"`` the means are not projected (the guide is the pilot only): a share other
        than 0 is refused there.

    Notes
    -----
    Channels beside R, G and B (an alpha, an AOV) are reconstructed apart, each alone with the same
    settings, so that none moves the colour (the domain's scale is the mean of the channels it is
    given, the luminance factor is the colour's): :func:`~awr_denoise.channels.channel_groups`.

    Pixels without samples take their nearest sampled neighbour's mean and the variance of a
    single sample, so they are smoothed over rather than read as black; having no mean of their
    own, they have no weight in the guard's risk (:func:`~awr_denoise.sure.sure_blend`, ``measured``)
    nor in a guide's gate, and keep the Wiener stages' result. Unknown per-sample variances are
    pooled from neighbours (:meth:`SampleBuffer.estimated_variance`).

    The output variance is that of the last stage linearised around its result, estimated without bias
    by Rademacher probes ``+-sqrt(v)``. With ``stages=1``, the shrink factor of every coefficient is
    held fixed (soft thresholding has slope 1 where it keeps a coefficient, 0 where it zeroes one) and
    the domain is undone by the delta method. With Wiener stages, the last stage's pilot, weights and
    factors (and the guard's share; a guide's clipping pattern) are held fixed, so the map is linear in
    the means; clamped pixels take their mean's variance, zeroed ones none, and the mean's restoration
    blends it with the mean's. It leaves out the noise that reaches the output through the pilot
    (every earlier stage) and all bias, so it underestimates (docs/reconstruction.md: the ratio).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer, reconstruct_detailed
    >>> rng = np.random.default_rng(1)
    >>> mean = 0.5 + 0.1 * rng.standard_normal((32, 32, 3))
    >>> buffer = SampleBuffer.from_moments(np.full((32, 32), 8), mean, np.full((32, 32, 3), 0.08))
    >>> result = reconstruct_detailed(buffer, c_s=1.0, domain="linear", variance_probes=0)
    >>> error = lambda image: float(np.abs(image - 0.5).mean())
    >>> error(result.image) < error(buffer.mean) / 2
    True

    One threshold list per channel, in :func:`~awr_denoise.wavelets.forward`'s layout: no
    threshold for the scale band, then ``(cH, cV, cD)`` from the coarsest level to the finest:

    >>> [None if t is None else [band.shape for band in t] for t in result.thresholds[0]]
    [None, [(14, 14), (14, 14), (14, 14)], [(20, 20), (20, 20), (20, 20)]]

    ``c_s = 0`` thresholds nothing and returns the Monte Carlo mean (Eq. 11):

    >>> exact = reconstruct_detailed(buffer, c_s=0, stages=1, variance_probes=0)
    >>> exact.fraction_zeroed, bool(np.allclose(exact.image, buffer.mean, rtol=1e-10))
    (0.0, True)
    """
    if not isinstance(buffer, SampleBuffer):
        raise TypeError(f"buffer: expected a SampleBuffer, got {type(buffer).__name__}")
    mode = _checks.name("mode", mode, MODES)
    settings = resolve_settings(c_s=c_s, stages=stages, wiener_exponents=wiener_exponents, pixel_clamp=pixel_clamp,
                                guard=guard, preserve_mean=preserve_mean, nonnegative=nonnegative, precision=precision,
                                variance_probes=variance_probes, seed=seed, guard_window=guard_window,
                                guard_probes=guard_probes)
    if guide is not None and settings.guard_probes:  # before a guide function (OIDN) runs for nothing
        # The guide's gate and projection follow the means, outside the probed stages.
        raise ValueError("guard_probes: not with a guide (its gate and projection are not probed)")
    recorded = guide_fields(guide, buffer)  # a guide function's own settings (guides.OIDNGuide), before it runs
    guide = checked_inputs(buffer, guide, features, settings.stages)
    projection = checked_projection(guide_projection, guide)
    if guide_projection and mode == "luminance":  # it would do nothing: refused (0, the pilot only, is what it does)
        raise ValueError(f"guide_projection: {guide_projection!r} with mode='luminance', where the means are not "
                         "projected (the guide is the pilot only)")
    groups = channel_groups(buffer.channels)
    if groups is not None:  # R,G,B together, an alpha or an AOV beside them alone: none moves another
        options = dict(c_s=c_s, wavelet=wavelet, levels=levels, domain=domain, mode=mode, boundary=boundary,
                       executor=executor, pixel_clamp=pixel_clamp, stages=stages, wiener_exponents=wiener_exponents,
                       guard=guard, guard_window=guard_window, guard_probes=guard_probes, preserve_mean=preserve_mean,
                       nonnegative=nonnegative, precision=precision, variance_probes=variance_probes, seed=seed,
                       features=features)
        whole = guide is not None and guide.shape[2] == buffer.n_channels  # else the colour's alone
        guides = [guide[..., list(group)] if whole else guide if group == guide_colour(buffer) else None
                  for group in groups]
        parts = [reconstruct_detailed(buffer.select(group), guide=part_guide, **options,
                                      guide_projection=None if part_guide is None else guide_projection)
                 for group, part_guide in zip(groups, guides)]
        whole_result = _assembled(parts, groups, probed=settings.probes > 0)
        return replace(whole_result, parameters={**whole_result.parameters, **recorded})
    prepared = prepare(buffer, domain)
    stop_point()  # between the steps: a frame of denoise --frames told to stop ends here (_signals)
    ops = wavelet_operators(buffer.shape, wavelet=wavelet, levels=levels, boundary=boundary)
    run = None if _checks.executor("executor", executor) is None else partial(_checks.mapped, executor)
    luminance = None
    if mode == "luminance":
        luminance = (prepare(buffer, prepared.domain, luminance=True), luminance_weights(buffer.channels))
    stage = threshold_stage(prepared, ops, settings.c_s, mode=mode, pixel_clamp=settings.stage1_clamp, run=run,
                            luminance=None if luminance is None else luminance[0], precision=settings.precision,
                            weights=None if luminance is None else luminance[1])
    variance = stage.output_variance(settings.probes, settings.seed) if settings.probes and settings.stages == 1 else None
    first, keep = pilots(buffer, stage.image, guide, features)
    stop_point()
    if guide is not None and settings.guard and np.any(keep > 0):
        # A guide the gate trusts anywhere: the guard's wider default window and its tolerance (.sure).
        settings = replace(settings, guard_tolerance=DEFAULT_GUIDED_TOLERANCE, guard_spared_beside=None,
                           guard_window=DEFAULT_GUIDED_WINDOW if guard_window is None else settings.guard_window)
    image, variance, gain = later_stages(prepared, first, variance, settings, levels=ops.levels, wavelet=ops.wavelet,
                                   luminance=luminance, run=run, keep=keep, guide=guide, projection=projection)
    return Reconstruction(image=image, thresholds=stage.thresholds,
                          fraction_zeroed=stage.zeroed / stage.total if stage.total else 0.0,
                          variance=np.broadcast_to(np.nan, image.shape) if variance is None else variance,
                          levels=ops.levels, domain=prepared.bound.domain, noise_gain=gain,
                          parameters={"wavelet": ops.wavelet, "levels": ops.levels,
                                      "domain": prepared.bound.domain.name, "mode": mode, "boundary": boundary,
                                      "guide": guide is not None, "features": bool(features) and guide is None,
                                      # luminance mode projects nothing (the guide is the pilot only)
                                      "guide_projection": None if guide is None else 0.0 if mode == "luminance"
                                      else projection, **settings.recorded(),
                                      **recorded})


def _assembled(parts: list[Reconstruction], groups: list[tuple[int, ...]], *, probed: bool) -> Reconstruction:
    """One :class:`Reconstruction` of channel groups reconstructed apart, in the buffer's channel order.

    The image, variance and thresholds of every channel; the rest is the first colour's (the first
    group's): its domain, depth, parameters, share of zeroed coefficients and noise gain. An exact
    alpha zeroes nothing and passes all of its (zero) noise: averaged in, it doubled the gain the
    sampler spends by and halved the share a file's provenance records."""
    order = np.argsort([i for group in groups for i in group])
    thresholds = [t for part in parts for t in part.thresholds]
    image = np.concatenate([part.image for part in parts], axis=2)[..., order]
    return Reconstruction(
        image=image,
        thresholds=[thresholds[i] for i in order],
        fraction_zeroed=parts[0].fraction_zeroed,
        variance=(np.concatenate([part.variance for part in parts], axis=2)[..., order] if probed
                  else np.broadcast_to(np.nan, image.shape)),
        levels=parts[0].levels, domain=parts[0].domain, parameters=parts[0].parameters,
        noise_gain=parts[0].noise_gain)


def reconstruct(
    buffer: SampleBuffer,
    *,
    c_s: float | None = None,
    wavelet: str = DEFAULT_WAVELET,
    levels: int | None = None,
    domain: str | Domain = DEFAULT_DOMAIN,
    mode: str = DEFAULT_MODE,
    boundary: str = "symmetric",
    executor: Executor | None = None,
    pixel_clamp: float | None = DEFAULT_PIXEL_CLAMP,
    stages: int = DEFAULT_STAGES,
    wiener_exponents: Sequence[float] = DEFAULT_WIENER_EXPONENTS,
    guard: bool | None = None,
    guard_window: int | None = None,
    guard_probes: int | None = None,
    preserve_mean: bool | None = None,
    nonnegative: bool | None = None,
    precision: str = DEFAULT_PRECISION,
    guide: FloatArray | None = None,
    guide_projection: float | None = None,
    features: bool = False,
) -> FloatArray:
    """Denoise the pixel means: Eq. 10-11 (paper section 5), then empirical Wiener stages.

    Parameters are those of :func:`reconstruct_detailed`; this returns the (H, W, C) image only.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer, reconstruct
    >>> rng = np.random.default_rng(0)
    >>> count = np.full((32, 32), 8)
    >>> buf = SampleBuffer.from_moments(count, 0.5 + 0.1 * rng.standard_normal((32, 32, 3)),
    ...                                 np.full((32, 32, 3), 0.08))
    >>> out = reconstruct(buf)
    >>> bool(np.abs(out - 0.5).mean() < np.abs(buf.mean - 0.5).mean())
    True
    """
    return reconstruct_detailed(buffer, c_s=c_s, wavelet=wavelet, levels=levels, domain=domain, mode=mode,
                                boundary=boundary, executor=executor, pixel_clamp=pixel_clamp, stages=stages,
                                wiener_exponents=wiener_exponents, guard=guard, guard_window=guard_window,
                                guard_probes=guard_probes, preserve_mean=preserve_mean, nonnegative=nonnegative,
                                precision=precision, variance_probes=0, guide=guide,
                                guide_projection=guide_projection, features=features).image
