"""Empirical Wiener shrinkage against a pilot estimate, on the stationary transform.

The classical second step of wavelet denoisers (BM3D's second stage, and Ghael, Sayeed and
Baraniuk's "improved wavelet denoising via empirical Wiener filtering"): a first estimate, the
*pilot*, says how much signal each coefficient holds, and every detail coefficient of the noisy
image is scaled by the Wiener factor

    f = P^2 / (P^2 + Delta^2)

with ``P`` the pilot's coefficient and ``Delta^2`` the exact variance of the noisy coefficient
(Eq. 10 of the paper, carried through the stationary transform by
:class:`~awr_denoise.stationary.StationaryTransform`). The scale band is kept as it is. Where the
variance is zero the factor is 1, so noiseless pixels come back unchanged.

:func:`relative_wiener` runs it in a domain relative to the signal: the means are divided by a
weight ``w = (|pilot| + k)^alpha`` fixed from the pilot before the transform and multiplied back
after. Because ``w`` is fixed, the stage is linear in the means and their variances stay exact,
``Var(x / w) = v / w^2``. ``alpha = 1`` makes the noise relative to the signal (the error
relMSE measures); ``alpha = 0`` is the linear domain (the error MSE measures).

A thresholded pilot (stage 1's) has lost every coefficient below its threshold, faint texture
included, and its factors would remove that texture again. The *energy floor* of the first of
several stages (:func:`chain`, :data:`DEFAULT_FLOOR`) uses ``max(P^2, S^2)`` instead of ``P^2``,
``S^2`` the local mean of ``X^2 - margin Delta^2``: the energy the means themselves show.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import NamedTuple

import numpy as np

from . import _checks
from ._signals import stop_point
from ._typing import FloatArray
from ._window_sums import window_sum
from .stationary import StationaryTransform

__all__ = ["WienerResult", "wiener_filter", "relative_wiener", "stage_weights", "WienerChain", "chain",
           "DIVERGENCE_STEP", "rademacher_probes", "DEFAULT_FLOOR"]

DEFAULT_FLOOR = (5, 2.0)
"""``(window, margin)`` of the energy floor of the first stage of :func:`chain` (:func:`relative_wiener`).
On both renderers' ten scenes, four groups each, 8-128 spp (``benchmarks/bench_reconstruct.py
quality --compare --floors``; docs/reconstruction.md, "The energy floor, measured"): without
the floor relMSE is 1.03-1.17x the default's at 8-32 spp on every scene (geometric mean 1.08),
MSE higher except within 0.001 of the plain mean's on two rows; 3x3 is worse everywhere
(geometric mean 1.05), 7x7, a margin of 1.5 or of 3 within 4% of it, and at most 2% better
anywhere (a margin of 1.5 on ``sky_objects``)."""


def _planes(a: FloatArray, dtype: np.dtype, *, copy: bool = False) -> np.ndarray:
    """(H, W) or (..., H, W, C) to contiguous (1, H, W) or (..., C, H, W) planes of ``dtype``.

    ``copy``: always a new array (the caller divides it in place), never a view of ``a``.
    """
    a = np.asarray(a)
    a = a[None] if a.ndim == 2 else np.moveaxis(a, -1, -3)
    return np.array(a, dtype=dtype, order="C") if copy else np.ascontiguousarray(a, dtype=dtype)


def _last(a: np.ndarray, ndim: int) -> FloatArray:
    """Back to the caller's (H, W) or (..., H, W, C) layout, float64."""
    a = a[..., 0, :, :] if ndim == 2 else np.moveaxis(a, -3, -1)
    return np.ascontiguousarray(a, dtype=np.float64)


def _times(spectrum: np.ndarray, transfer: np.ndarray) -> np.ndarray:
    """``spectrum * transfer`` in place (no temporary)."""
    spectrum *= transfer
    return spectrum


class WienerResult(NamedTuple):
    """What a Wiener stage returns.

    Attributes
    ----------
    image
        The filtered planes, in the caller's layout, float64.
    extra
        The filtered ``extra`` planes (probes), or ``None``.
    leverage
        With ``leverage=True``: each pixel's weight on its own value in the stage's linear map
        (factors held fixed), the diagonal ``d out_p / d x_p``; otherwise ``None``.
    """

    image: FloatArray
    extra: FloatArray | None = None
    leverage: FloatArray | None = None


def wiener_filter(transform: StationaryTransform, x: FloatArray, variance: FloatArray, pilot: FloatArray, *,
                  extra: FloatArray | None = None, leverage: bool = False) -> WienerResult:
    """Scale every detail coefficient of ``x`` by ``P^2 / (P^2 + Delta^2)``; keep the scale band.

    Parameters
    ----------
    transform
        The stationary transform of the image's shape.
    x
        (H, W) or (H, W, C) noisy planes.
    variance
        Variance of every pixel of ``x`` (independent pixels), same shape, or one (H, W) plane
        shared by the channels.
    pilot
        The pilot estimate, shaped like ``variance``: one plane of each gives one set of factors
        applied to every channel of ``x``.
    extra
        Optional (N, H, W, C) planes filtered with the *same* factors (probes of the stage's
        linear map).
    leverage
        Also return the diagonal of the stage's linear map (one more FFT per band).

    Returns
    -------
    WienerResult
        The filtered ``x``, and the filtered ``extra`` and the leverage when asked for.

    Examples
    --------
    With a noiseless pilot equal to the clean image, the filter keeps what is well above the
    noise and removes the rest (a ramp under noise of standard deviation 0.3):

    >>> import numpy as np
    >>> from awr_denoise.stationary import StationaryTransform
    >>> from awr_denoise.wiener import wiener_filter
    >>> clean = np.tile(np.linspace(0.0, 4.0, 32), (32, 1))
    >>> noisy = clean + 0.3 * np.random.default_rng(0).standard_normal((32, 32))
    >>> t = StationaryTransform((32, 32), levels=3)
    >>> out = wiener_filter(t, noisy, np.full((32, 32), 0.09), clean, leverage=True)
    >>> rms = lambda a: float(np.sqrt(np.mean((a - clean) ** 2)))
    >>> round(rms(noisy), 2), rms(out.image) < rms(noisy) / 3
    (0.29, True)

    Each pixel keeps a small share of its own value; the rest comes from its neighbours:

    >>> 0 < float(out.leverage.min()) < float(out.leverage.max()) < 0.5
    True

    Zero variance keeps every coefficient (factor 1): the image comes back unchanged.

    >>> bool(np.allclose(wiener_filter(t, noisy, np.zeros((32, 32)), np.zeros((32, 32))).image, noisy))
    True
    """
    ndim = np.ndim(x)
    if np.shape(variance) != np.shape(pilot) or np.shape(variance)[:2] != np.shape(x)[:2] or (
            np.ndim(variance) == 3 and np.shape(variance)[2] != np.shape(x)[2]) or np.ndim(variance) > np.ndim(x):
        raise ValueError(f"variance, pilot: shapes {np.shape(variance)} and {np.shape(pilot)} do not fit x's "
                         f"{np.shape(x)} (same shape, or one (H, W) plane each)")
    dtype = transform.dtype
    out, out_e, diagonal = _filter(transform, [_planes(x, dtype), _planes(variance, dtype), _planes(pilot, dtype)],
                                   None if extra is None else _planes(extra, dtype), leverage)
    return WienerResult(_last(out, ndim), None if out_e is None else _last(out_e, 3),
                        None if diagonal is None else _last(diagonal, ndim if np.ndim(variance) == 3 else 2))


_PARALLEL_BANDS = 2  # bands filtered at once with ``run``: each holds its own scratch and contributions
_PARALLEL_PIXELS = 2**18  # below 512x512 a band is too little work for a thread: with ``run``, the bands stay serial


class _Scratch:
    """One band's working planes; with ``slots``, every contribution spectrum also gets its own."""

    def __init__(self, t: StationaryTransform, n_factors: int, shapes: dict | None, floor: bool = False) -> None:
        self.work = np.empty(t.shape[:1] + (t.shape[1] // 2 + 1,), np.complex64 if t.dtype == np.float32
                             else np.complex128)
        self.factors = np.empty((n_factors,) + t.shape, t.dtype)  # one per pilot plane
        # The noise plane serves the factors, the coefficient plane the scaling after them: one buffer.
        self.noise = self.coeff = np.empty(t.shape, t.dtype)
        # With the energy floor: every channel's band coefficients, computed for the factors and
        # kept for the scaling (not computed twice), and the evidence plane.
        self.kept = np.empty((n_factors,) + t.shape, t.dtype) if floor else None
        self.evidence = np.empty(t.shape, t.dtype) if floor else None
        self.slots = None if shapes is None else {kind: np.empty(shape, self.work.dtype)
                                                  for kind, shape in shapes.items()}

    def target(self, kind: str, index: tuple) -> np.ndarray:
        """Where a contribution is written: its own slot, or the shared ``work`` plane."""
        return self.work if self.slots is None else self.slots[kind][index]


def _band(t: StationaryTransform, b: int, spectra: tuple, leverage: bool, scratch: _Scratch,
          add: Callable[[str, tuple, np.ndarray], None], floor: tuple[int, float] | None = None) -> None:
    """Band ``b``'s Wiener factors and contributions (``add(kind, index, spectrum)``, in a fixed order).

    Kinds: ``"d"`` the diagonal's share (per factor plane), ``"x"`` the scaled image (per
    channel), ``"e"`` the scaled probes (per probe and channel). ``floor`` (one factor plane
    per channel only): :func:`relative_wiener`'s energy floor.
    """
    stop_point()  # a band at a time: the longest steps of a reconstruction (a quarter second at 1080p)
    spec_x, spec_v, spec_p, spec_e = spectra
    # Each transfer function is alive only while it is used (above 512x512 each is built on the
    # fly, a complex plane as large as a spectrum): the squared one and the diagonal's for the
    # factors, the synthesis one for the scaling after them.
    a, squared = t.analysis(b), t.squared(b)
    diagonal = t.diagonal(b) if leverage else None
    work, noise, coeff = scratch.work, scratch.noise, scratch.coeff
    tiny = np.finfo(t.dtype).tiny  # factor 1 where the variance is 0; ~0 where the pilot is 0
    for c, factor in enumerate(scratch.factors):
        t.planes(np.multiply(spec_p[c], a, out=work), overwrite=True, out=factor)
        np.multiply(factor, factor, out=factor)
        t.planes(np.multiply(spec_v[c], squared, out=work), overwrite=True, out=noise)
        np.maximum(noise, 0.0, out=noise)  # FFT rounding around exact zeros
        if floor is not None:
            assert scratch.kept is not None and scratch.evidence is not None
            x_band = t.planes(np.multiply(spec_x[c], a, out=work), overwrite=True, out=scratch.kept[c])
            with np.errstate(over="ignore", invalid="ignore"):  # beyond the precision's range: no floor there
                evidence = np.multiply(x_band, x_band, out=scratch.evidence)
                evidence -= floor[1] * noise
                # The window's mean, summed from its own entries (._window_sums: a firefly's rounding error stays in
                # its windows) on the periodic canvas; divided first, or float32 sums near its top would overflow.
                evidence /= floor[0] * floor[0]
                window_sum(evidence, floor[0], mode="wrap", out=evidence)
            np.nan_to_num(evidence, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
            np.maximum(factor, evidence, out=factor)
        factor += tiny
        noise += factor
        np.divide(factor, noise, out=factor)
        if diagonal is not None:
            add("d", (c,), _times(t.spectrum(factor, out=scratch.target("d", (c,))), diagonal))
    del squared, diagonal
    s = t.synthesis(b)

    def scaled(spectrum: np.ndarray, factor: np.ndarray, out: np.ndarray) -> np.ndarray:
        """The spectrum of one plane's band coefficients times ``factor``, taken back by ``s``, in ``out``."""
        t.planes(np.multiply(spectrum, a, out=work), overwrite=True, out=coeff)
        np.multiply(coeff, factor, out=coeff)
        return _times(t.spectrum(coeff, out=out), s)

    for c in range(spec_x.shape[0]):
        factor = scratch.factors[c if len(scratch.factors) > 1 else 0]
        if scratch.kept is not None:
            out = scratch.target("x", (c,))
            add("x", (c,), _times(t.spectrum(np.multiply(scratch.kept[c], factor, out=coeff), out=out), s))
        else:
            add("x", (c,), scaled(spec_x[c], factor, scratch.target("x", (c,))))
        if spec_e is not None:
            for n in range(spec_e.shape[0]):
                add("e", (n, c), scaled(spec_e[n, c], factor, scratch.target("e", (n, c))))


def _filter(t: StationaryTransform, planes: list[np.ndarray], es: np.ndarray | None, leverage: bool,
            run: Callable | None = None, floor: tuple[int, float] | None = None
            ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """:func:`wiener_filter` on (C, H, W) planes in the transform's precision.

    ``planes`` is ``[xs, vs, ps]`` (``vs``, ``ps``: C or 1 planes); it is emptied once their
    spectra are taken, so a caller that holds no other reference frees them for the band loop.
    Every band costs three inverse FFTs (pilot, noise and image coefficients) and one forward
    FFT (the scaled coefficients) per plane, one more forward FFT with ``leverage``. The work
    between them runs one plane at a time in buffers reused from band to band: at 1080p or 4K
    the whole-image spectra are what memory holds, not one temporary per channel and step.

    With ``run`` (an executor's map) :data:`_PARALLEL_BANDS` bands at a time run on its threads,
    each in its own buffers; their contributions are summed in band order, so the result is
    the same, bit for bit, as without (at the cost of those bands' buffers in memory). Below
    :data:`_PARALLEL_PIXELS` the bands run serially all the same: threads were slower there in the
    probes that set the threshold (docs/performance.md, Threads; ``benchmarks/bench_core.py
    --only speed --sizes 256x256`` measures the default with and without a second thread).
    """
    spec_x, spec_v, spec_p = (t.spectrum(a) for a in planes)
    planes.clear()
    if floor is not None and spec_p.shape[0] != spec_x.shape[0]:
        raise ValueError("floor: needs one pilot and variance plane per channel (the evidence is each channel's)")
    spec_e = None if es is None else t.spectrum(es)
    keep = t.analysis(0) * t.synthesis(0)
    totals = {"x": spec_x * keep, "e": None if spec_e is None else spec_e * keep,
              # The scale band's factor is 1: its share of the diagonal is h_0's sum, a constant.
              "d": None if not leverage else np.zeros_like(spec_v) + t.spectrum(np.ones(t.shape)) * t.diagonal(0)}
    spectra = (spec_x, spec_v, spec_p, spec_e)

    def add(kind: str, index: tuple, spectrum: np.ndarray) -> None:
        totals[kind][index] += spectrum

    bands = range(1, len(t.bands))
    if run is None or t.shape[0] * t.shape[1] < _PARALLEL_PIXELS:
        scratch = _Scratch(t, spec_p.shape[0], None, floor is not None)
        for b in bands:
            _band(t, b, spectra, leverage, scratch, add, floor)
    else:
        shapes = {kind: total.shape for kind, total in totals.items() if total is not None}
        # One set of buffers per band in flight, reused from pair to pair: fresh ones for every
        # band would cost the kernel's zeroing of their pages each time. The first band of a
        # group adds its contributions to the totals as it goes, as the serial loop does (every
        # earlier band is summed by then); the others keep theirs in slots, summed after it in
        # band order: the same bits, and one band's slots fewer in memory.
        scratches = [_Scratch(t, spec_p.shape[0], None if i == 0 else shapes, floor is not None)
                     for i in range(_PARALLEL_BANDS)]

        def one(job: tuple[int, _Scratch]) -> _Scratch:
            _band(t, job[0], spectra, leverage, job[1], add if job[1].slots is None else lambda *_: None, floor)
            return job[1]

        for start in range(1, len(t.bands), _PARALLEL_BANDS):
            for scratch in run(one, list(zip(range(start, min(start + _PARALLEL_BANDS, len(t.bands))), scratches))):
                for kind, slots in (scratch.slots or {}).items():
                    totals[kind] += slots  # per band, every plane of a kind in one sum: the same bits
    done = {kind: None if total is None else t.planes(total, overwrite=True) for kind, total in totals.items()}
    return done["x"], done["e"], done["d"]


def stage_weights(pilot: FloatArray, k: float, exponent: float, *, dtype: str | np.dtype = "float64") -> FloatArray:
    """The per-pixel weights ``(|pilot| + k)^exponent`` of a relative stage, computed in ``dtype``.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.wiener import stage_weights
    >>> stage_weights(np.array([0.0, 3.0, -8.0]), 1.0, 0.5)
    array([1., 2., 3.])
    """
    k = _checks.real("k", k, above=0)
    exponent = _checks.real("exponent", exponent, minimum=0, maximum=1)
    base = np.abs(np.asarray(pilot, dtype=dtype))
    # At least the dtype's smallest normal number: a k that rounds to 0 would divide by 0.
    base += max(np.asarray(k, dtype=base.dtype), np.finfo(base.dtype).tiny)
    if exponent == 1.0:
        return base
    if exponent == 0.5:
        return np.sqrt(base)
    return base**exponent


def relative_wiener(transform: StationaryTransform, x: FloatArray, variance: FloatArray, pilot: FloatArray, *,
                    k: float, exponent: float, extra: FloatArray | None = None, leverage: bool = False,
                    run: Callable | None = None, floor: tuple[int, float] | None = None) -> WienerResult:
    """One Wiener stage in the domain ``x / w``, ``w = (|pilot| + k)^exponent`` (module docstring).

    Parameters
    ----------
    transform, extra, leverage
        As in :func:`wiener_filter`; ``extra`` is divided and multiplied by the same weights,
        and the leverage is the same in both domains (``w`` cancels on the diagonal).
    x
        (H, W, C) pixel means.
    variance
        Variance of every mean, (H, W, C), or one (H, W) plane (luminance: shared factors).
    pilot
        The previous estimate, shaped like ``variance``; it sets the weights and the factors.
    k
        Offset of the weights (the level below which error counts absolutely, like relMSE's
        epsilon); must be > 0.
    exponent
        ``alpha`` in [0, 1]: 0 is the linear domain, 1 the ratio to the pilot.
    run
        ``run(f, items)``, an executor's map: bands in parallel on its threads, the same result
        bit for bit (more memory: each band in flight holds its own planes).
    floor
        ``(window, margin)``: the energy floor, for a pilot that may lack signal the means show
        (a thresholded one). The pilot's squared coefficient ``P^2`` in the factor is replaced
        by ``max(P^2, S^2)``, ``S^2`` the ``window`` x ``window`` mean of ``X^2 - margin
        Delta^2`` over the band (``X`` the means' coefficients): the signal energy the means
        themselves show beyond ``margin`` times their noise (the local estimate of Mihcak et
        al. 1999, "Low-complexity image denoising based on statistical modeling of wavelet
        coefficients"). The factors then depend on the means, so the stage is no longer linear
        in them: :func:`chain` floors its first stage only, whose pilot is stage 1's. Needs one
        pilot and variance plane per channel.

    Returns
    -------
    WienerResult
        The stage's estimate (H, W, C), and the filtered ``extra`` and the leverage when asked.

    Examples
    --------
    A square 1000x brighter than the ground, 8 samples per pixel of 30% relative noise, and a
    perfect pilot. In the linear domain (``exponent=0``) the square's noise spills onto the
    ground; in the ratio domain (``exponent=1``) the ground's relative error drops 50x:

    >>> import numpy as np
    >>> from awr_denoise.stationary import StationaryTransform
    >>> from awr_denoise.wiener import relative_wiener
    >>> clean = np.ones((32, 32, 1))
    >>> clean[12:20, 12:20] = 1000.0
    >>> variance = (0.3 * clean) ** 2 / 8
    >>> noisy = clean + np.sqrt(variance) * np.random.default_rng(0).standard_normal(clean.shape)
    >>> t = StationaryTransform((32, 32), levels=3)
    >>> ground = clean == 1.0
    >>> rel = lambda a: float(np.mean(((a - clean) / clean)[ground] ** 2))
    >>> [round(rel(relative_wiener(t, noisy, variance, clean, k=0.1, exponent=e).image), 4) for e in (0.0, 1.0)]
    [3.5084, 0.0002]
    >>> round(rel(noisy), 4)
    0.0105
    """
    t = transform
    ndim = np.ndim(x)
    if floor is not None:
        if not isinstance(floor, tuple) or len(floor) != 2:
            raise ValueError(f"floor: expected (window, margin), got {floor!r}")
        floor = (int(_checks.whole("floor window", floor[0], minimum=1, maximum=1023)),  # type: ignore[arg-type]
                 float(_checks.real("floor margin", floor[1], minimum=0)))  # type: ignore[arg-type]
    # Planes first, in the transform's precision: the weights, the divisions and the products
    # back are as exact as the FFTs that sit between them.
    pilot_planes = _planes(pilot, t.dtype, copy=True)
    w = stage_weights(pilot_planes, k, exponent, dtype=t.dtype)
    xs = _planes(x, t.dtype, copy=True)
    xs /= w
    vs = _planes(variance, t.dtype, copy=True)
    # Capped in the stage's domain, where it is summed: divided by w^2 (about k^1.5 beside means of 0)
    # a variance of 5.7e36 passed float32's range and overflowed in the factors. A factor is 0 there
    # with the cap as without it.
    with np.errstate(over="ignore"):
        vs /= w
        vs /= w  # not w * w: that over/underflows first
    t.cap(vs)
    pilot_planes /= w
    es = None
    if extra is not None:
        es = _planes(extra, t.dtype, copy=True)
        es /= w
    planes = [xs, vs, pilot_planes]
    del xs, vs, pilot_planes  # _filter frees them once it has their spectra
    out, out_e, diagonal = _filter(t, planes, es, leverage, run, floor)
    out *= w
    if out_e is not None:
        out_e *= w
    return WienerResult(_last(out, ndim), None if out_e is None else _last(out_e, 3),
                        None if diagonal is None else _last(diagonal, ndim if np.ndim(variance) == 3 else 2))


class WienerChain(NamedTuple):
    """What :func:`chain` returns: the last stage's image, diagonal and probe variance, the chain's divergence."""

    image: FloatArray
    leverage: FloatArray | None  # the last stage's diagonal (H, W, C or 1), for the SURE guard
    variance: FloatArray | None  # the last stage's probe variance, if asked for
    divergence: FloatArray | None = None  # the whole chain's, measured by probes (H, W, C), if asked for


DIVERGENCE_STEP = 0.1
"""Size of :func:`chain`'s divergence probes in standard errors of the means. The estimate is a
secant across the move: small enough for the stages to be nearly linear over it, and large enough
that the change stays well above a float32 transform's rounding at pixels whose standard error is
1e-5 of their value."""


_PROBE_BATCH = 8  # probes filtered together through the last Wiener stage


def rademacher_probes(v: FloatArray, probes: int, seed: int) -> Iterator[np.ndarray]:
    """Batches (n, H, W, C) of Rademacher probes ``+-sqrt(v)`` of the (H, W, C) variances ``v``.

    Channel ``c`` draws its signs from ``seed + c``, so channels probed one by one (first channel
    ``c``, ``seed + c``) or together get the same probes. Filtered through a linear map, their
    mean square is the map's output variance, without bias.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.wiener import rademacher_probes
    >>> batches = list(rademacher_probes(np.full((2, 2, 1), 4.0), 10, seed=0))
    >>> [b.shape for b in batches], sorted(set(np.concatenate(batches).ravel().tolist()))
    ([(8, 2, 2, 1), (2, 2, 2, 1)], [-2.0, 2.0])
    """
    rngs = [np.random.default_rng(seed + c) for c in range(v.shape[2])]
    sd = np.sqrt(v)
    for start in range(0, probes, _PROBE_BATCH):
        size = (min(_PROBE_BATCH, probes - start),) + v.shape[:2]
        yield sd * np.stack([rng.choice((-1.0, 1.0), size=size) for rng in rngs], axis=-1)


def chain(transform: StationaryTransform, x: FloatArray, v: FloatArray, pilot: FloatArray,
          exponents: tuple[float, ...], *, k: float, weights: FloatArray | None = None,
          shared: FloatArray | None = None, leverage: bool = False, probes: int = 0, seed: int = 0,
          keep: FloatArray | float = 0.0, run: Callable | None = None,
          floor: tuple[int, float] | None = None, divergence_probes: int = 0) -> WienerChain:
    """Every Wiener stage in turn (:func:`relative_wiener`, one ``exponent`` each), each stage's
    result the next one's pilot, on (H, W, C) planes at unit scale.

    ``keep`` is the share of the first ``pilot`` every later stage keeps in its own (a trusted
    guide's, :func:`~awr_denoise.guided.pilots`). With luminance ``weights`` (and the luminance
    variance ``shared``) the factors come from luminance, one set for every channel. With
    ``probes``, the last stage's output variance is estimated by :func:`rademacher_probes`.
    ``run`` (an executor's map) filters bands in parallel (:func:`relative_wiener`). ``floor``
    is the first stage's energy floor (:func:`relative_wiener`) when more stages follow: that
    stage's pilot comes from outside the chain (stage 1's thresholded image, or a guide's), and
    the last stage, whose diagonal and probes describe the chain to the guard, stays linear in
    the means for its fixed pilot.

    The diagonal holds every stage's factors fixed, but each stage's pilot is the stage before's
    result, made from the same means: the chain follows a pixel's own mean more than its diagonal
    says. ``divergence_probes`` measures that (Monte Carlo SURE; Ramani, Blu and Unser 2008): the
    whole chain again on the means moved by ``+-DIVERGENCE_STEP`` standard errors, each pixel's
    change over its own move, averaged over the probes (``pilot`` held: stage 1's own dependence
    is not counted). Unbiased where the chain is smooth; its noise is the rest of the row of the
    chain's Jacobian, which the guard's window sums average out.

    Examples
    --------
    Two stages on a noisy ramp, starting from the noisy means themselves as the pilot (the
    reconstruction starts from stage 1's thresholding, a better one); the second stage takes the
    first one's result as its pilot:

    >>> import numpy as np
    >>> from awr_denoise.stationary import StationaryTransform
    >>> from awr_denoise.wiener import chain
    >>> clean = np.tile(np.linspace(1.0, 2.0, 32), (32, 1))[..., None]
    >>> noisy = clean + 0.1 * np.random.default_rng(0).standard_normal(clean.shape)
    >>> out = chain(StationaryTransform((32, 32), levels=3), noisy, np.full(clean.shape, 0.01), noisy,
    ...             (0.75, 0.4), k=0.1, leverage=True)
    >>> rms = lambda a: round(float(np.sqrt(np.mean((a - clean) ** 2))), 3)
    >>> rms(noisy), rms(out.image), out.leverage.shape
    (0.097, 0.056, (32, 32, 1))
    """
    v, shared = transform.bounded(v), transform.bounded(shared)
    variance = v if shared is None else shared

    def last_pilot(means: FloatArray) -> FloatArray:
        out = pilot
        for i, exponent in enumerate(exponents[:-1]):
            out = relative_wiener(transform, means, variance, out if weights is None else out @ weights, k=k,
                                  exponent=exponent, run=run, floor=floor if i == 0 else None
                                  ).image * (1 - keep) + keep * pilot
        return out if weights is None else out @ weights

    p = last_pilot(x)
    result = relative_wiener(transform, x, variance, p, k=k, exponent=exponents[-1], leverage=leverage, run=run)
    var_out = None
    if probes:
        var_out = np.zeros_like(x)
        for e in rademacher_probes(v, probes, seed):
            filtered = relative_wiener(transform, x, variance, p, k=k, exponent=exponents[-1], extra=e, run=run).extra
            var_out += (filtered * filtered).sum(axis=0)
        var_out /= probes
    divergence = None
    if divergence_probes:
        divergence = np.zeros_like(x)
        for batch in rademacher_probes(v, divergence_probes, seed):
            for e in batch:
                e *= DIVERGENCE_STEP
                moved = x + e
                moved = relative_wiener(transform, moved, variance, last_pilot(moved), k=k, exponent=exponents[-1],
                                        run=run).image
                moved -= result.image
                # The probe's sign over its size: e / e^2; 0 where a pixel has no variance (it is not moved).
                with np.errstate(divide="ignore", invalid="ignore"):
                    divergence += np.where(e != 0, moved / e, 0.0)
        divergence /= divergence_probes
    lev = result.leverage
    return WienerChain(result.image, None if lev is None else (lev if lev.ndim == 3 else lev[..., None]), var_out,
                       divergence)
