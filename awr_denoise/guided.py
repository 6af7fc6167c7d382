"""Pilots for the Wiener stages from outside the samples: a guide image, or the feature buffers.

The Wiener stages (:mod:`awr_denoise.wiener`) scale every detail coefficient of the pixel means
by ``P^2 / (P^2 + Delta^2)``, where ``P`` is the coefficient of a *pilot* estimate and ``Delta``
its exact standard error. The pilot only chooses how much each coefficient of the *means* is
shrunk: the stages' output is a linear filter of the means, so

* as the samples grow (``Delta -> 0``) every factor tends to 1 wherever the pilot has signal,
  and the SURE guard (:mod:`awr_denoise.sure`) returns every neighbourhood where the pilot's
  shrinkage adds more bias than it removes noise to the plain mean: the result converges to the
  mean whatever the pilot says;
* a good pilot (one closer to the clean image than stage 1's thresholding) gives factors closer
  to the oracle's, so less noise and less blur.

A pilot is also checked against the samples before it is used (:func:`gated`): where it lies
further from the pixel means than their noise allows (over a 5x5 neighbourhood, squared
differences summing to more than ``GATE_LOW`` times the variances), stage 1's pilot takes over,
fully from ``GATE_HIGH``. A biased pilot (a denoiser's hallucinated detail, a blur across an edge) is thus
used only where the samples cannot tell it from the truth, and as the samples grow, only where it
is right. Measured (docs/guides.md, "Wrong guides"): without this check a deliberately wrong guide
cost up to 1.17x the plain mean's relMSE next to a small bright light; with it, never more than the
plain mean's (at most 0.97x), and within 0.02 of the default's ratios to it from 64 spp on. The SURE
guard is needed as well: without it the same wrong guides cost 1.05-1.06x the plain mean's relMSE there
at 64 spp.

Two pilots are built here (:func:`pilots`):

``guide``
    Any (H, W, C) image of the scene, for example a neural denoiser's output on the same samples
    (:func:`awr_denoise.guides.oidn`). It is checked (:func:`checked_guide`) and is the pilot of
    *every* Wiener stage where the gate trusts it; where the gate is closed the stages chain as
    they do without a guide (stage 1, then each stage's result).
``features``
    Stage 1's image filtered by an edge-avoiding a-trous wavelet filter (Dammertz, Sewtz,
    Hanika and Lensch 2010, "Edge-avoiding a-trous wavelet transform for fast global
    illumination filtering") whose edge-stopping weights come from the buffer's albedo, normal
    and depth (:func:`feature_pilot`). Each feature difference is measured against the feature's own noise:
    where a feature is noisy (depth of field, glossy albedo) the pixel keeps stage 1's image instead. Gated like
    a guide, it is the first Wiener stage's pilot only.

A guide is also used directly, within what the samples allow (:func:`projected`): the means'
coefficients, the scale band's included, are moved towards the guide's by at most three standard
errors each (:mod:`awr_denoise.projection`), and half of that result (times the gate's share)
replaces half of the Wiener stages'. Where the guide is within the noise, its noise-free detail is followed; where
the samples contradict it, the means' coefficients stay; the SURE guard then sees the blend's
exact leverage. As the samples grow the intervals shrink and the result tends to the means.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from . import _checks
from ._arrays import plain
from ._typing import FloatArray
from ._window_sums import window_sum
from .buffers import SampleBuffer
from .channels import colours
from .prepare import filled_mean
from .projection import project
from .stationary import StationaryTransform
from .wiener import rademacher_probes

__all__ = ["checked_guide", "checked_inputs", "guide_fields", "guide_colour", "feature_pilot", "trust", "gated",
           "pilots", "ATROUS_ITERATIONS", "FEATURE_SIGMAS", "GATE_WINDOW", "GATE_LOW", "GATE_HIGH", "projected",
           "PROJECTION_SHARE", "checked_projection"]

ATROUS_ITERATIONS = 3
"""A-trous passes of :func:`feature_pilot` (steps 1, 2, 4: a 29-pixel footprint). Five passes measured
the same on the bundled tracer's scenes (within 0.1%) at 5/3 the time (docs/guides.md)."""

FEATURE_SIGMAS = {"albedo": 0.1, "normal": 0.3, "depth": 0.05}
"""Differences of each feature that halve (``exp(-1)``) a tap's weight when the feature is noiseless.

Albedo and normal in absolute units, depth relative to the nearer pixel's depth."""

GATE_WINDOW = 5
"""Side of the neighbourhood over which :func:`trust` compares a pilot with the samples."""

GATE_LOW, GATE_HIGH = 3.0, 9.0
"""Mean squared standard errors between pilot and samples where :func:`trust` starts and stops trusting."""

PROJECTION_SHARE = 0.5
"""Most of a guided result that :func:`projected` takes from the projection on the guide (times the
gate's share), the Wiener stages' the rest. Measured at 32 spp with the scale band projected
(docs/guides.md, "What else was tried"): 0.75 lowers relMSE by 2-7% on five scenes (`glossy_glass`
0.90x OIDN's instead of 0.97x) and raises it by 1-5% on the other five (0.99x half's in geometric
mean); the projection alone (1) loses 4-13% on five, most on the tracer's (`default`, `rolling_balls`,
`soft_shadows` 11-13%); none (0) loses 4-32% on nine scenes, most where the guide trails OIDN."""

_COLOUR_SIGMA = 2.0  # colour differences are counted in the means' standard errors
_KERNEL = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0  # the B3 spline of the a-trous transform


def guide_colour(buffer: SampleBuffer) -> tuple[int, ...] | None:
    """The channels a guide of the colour alone stands for: the buffer's only colour, where other
    channels (an alpha, an AOV) are beside it; else ``None`` (a guide then has every channel).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.guided import guide_colour
    >>> rgba = SampleBuffer.from_moments(np.ones((2, 2)), np.ones((2, 2, 4)), np.zeros((2, 2, 4)),
    ...                                  channels=["R", "G", "B", "A"])
    >>> guide_colour(rgba), guide_colour(rgba.select((0, 1, 2)))
    ((0, 1, 2), None)
    """
    found = colours(buffer.channels)
    return found[0] if len(found) == 1 and len(found[0]) < buffer.n_channels else None


def checked_guide(guide: object, buffer: SampleBuffer) -> FloatArray:
    """The guide as a float64 (H, W, C) array, checked against the buffer.

    A guide has the buffer's channels, or, beside other channels (an alpha, an AOV), those of its
    only colour (:func:`guide_colour`), in the buffer's order: it then guides the colour alone.

    Raises
    ------
    ValueError
        If its shape is not the buffer's (H, W, C) nor its colour's (an (H, W) plane is taken for
        one channel), or it holds NaN or infinite values.
    TypeError
        If it is not an array of real numbers (complex, bool, object, strings).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.guided import checked_guide
    >>> buffer = SampleBuffer.from_moments(np.ones((2, 3)), np.ones((2, 3, 3)), np.zeros((2, 3, 3)))
    >>> checked_guide(np.zeros((2, 3, 3)), buffer).shape
    (2, 3, 3)
    >>> checked_guide(np.zeros((3, 2, 3)), buffer)
    Traceback (most recent call last):
    ...
    ValueError: guide: shape (3, 2, 3) does not match the buffer's (2, 3, 3)
    """
    if isinstance(guide, str):  # a guide's name, as the command line's --guide takes it
        raise TypeError(f"guide: {guide!r} is a name; give an image, or a function of the buffer such as "
                        "awr_denoise.guides.oidn (the feature pilot is features=True)")
    given = plain("guide", guide)
    if given.dtype.kind not in "fiu":  # complex (cast to its real part), bool, object: refused as by the buffers
        raise TypeError(f"guide: expected a real (H, W, C) array, got dtype {given.dtype}")
    array = given.astype(np.float64)
    colour = guide_colour(buffer)
    shapes = [(*buffer.shape, buffer.n_channels)] + ([] if colour is None else [(*buffer.shape, len(colour))])
    if array.ndim == 2 and 1 in (shape[2] for shape in shapes):
        array = array[..., None]
    if array.shape not in shapes:
        raise ValueError(f"guide: shape {array.shape} does not match the buffer's {shapes[0]}"
                         + ("" if colour is None else f" nor its colour's {shapes[1]}"))
    bad = ~np.isfinite(array)
    if bad.any():
        row, col, channel = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"guide: {int(bad.sum())} values are NaN or infinite (first at row {row}, column {col}, "
                         f"channel {channel})")
    return array


def _shifted(a: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``a`` moved so that pixel ``(i, j)`` holds ``a[i + dy, j + dx]``, edges repeated."""
    h, w = a.shape[:2]
    rows = np.clip(np.arange(h) + dy, 0, h - 1)
    cols = np.clip(np.arange(w) + dx, 0, w - 1)
    return a[rows][:, cols]


_LARGEST = 2.0**400
"""Values are brought below this (by a power of two) before the pilot squares their differences."""
_SMALLEST_DEPTH = 2.0**-10  # depths all below it are brought near 1 (_feature_planes)


def _unit(mean: np.ndarray, variance: np.ndarray, lift: float = 0.0) -> float:
    """1, or the power of two that brings ``|mean|`` and the standard errors below :data:`_LARGEST` (squares near 1e155
    pass float64), or, all below ``lift``, near 1 (depths of 1e-7 lost every edge to the distances' floor of 1e-12)."""
    top = max(float(np.abs(mean).max(initial=0.0)), math.sqrt(float(variance.max(initial=0.0))))
    return 1.0 if lift <= top <= _LARGEST or top == 0.0 else math.ldexp(1.0, -math.frexp(top)[1])


def _feature_planes(buffer: SampleBuffer) -> list[tuple[np.ndarray, np.ndarray, float, bool]]:
    """(mean, variance of the mean, sigma, relative) of every feature the buffer carries; a relative
    feature (depth) in a unit of its own where its values are too large to square."""
    planes = []
    for name, sigma in FEATURE_SIGMAS.items():
        if name not in buffer.features:
            continue
        feature = buffer.features[name]
        n = np.maximum(feature.count, 1).astype(np.float64)[..., None]
        mean = np.asarray(feature.mean, np.float64)
        variance = np.where(feature.count[..., None] > 1, np.nan_to_num(feature.variance), 0.0) / n
        relative = name == "depth"
        # A relative distance does not change with its unit; depths all tiny are brought near 1.
        unit = _unit(mean, variance, _SMALLEST_DEPTH) if relative else 1.0
        planes.append((mean * unit, variance * unit * unit, sigma, relative))
    return planes


def feature_pilot(buffer: SampleBuffer, image: FloatArray, *, iterations: int = ATROUS_ITERATIONS) -> FloatArray:
    """``image`` smoothed by an edge-avoiding a-trous filter guided by the buffer's features.

    Every pass ``i`` averages each pixel with the 5x5 B3-spline taps ``2^i`` pixels apart,
    each tap weighted by ``exp(-sum_f D_f)`` over the colour and every feature ``f``:

    * colour: ``|c_p - c_q|^2 / (2 s^2 min(v_p, v_q))``, ``v`` the variance of the pixel means and ``s = 2``: only
      differences of several standard errors stop a tap, and a firefly's variance does not open its neighbours;
    * features: ``|f_p - f_q|^2 / (sigma_f^2 + u_p + u_q)``, ``u`` the variance of the feature's
      mean (its sample variance over its count), ``sigma_f`` from :data:`FEATURE_SIGMAS`
      (depth relative to the nearer pixel's).

    A pixel keeps of the filtered image the share ``prod_f sigma_f^2 / (sigma_f^2 + 4 u_p)`` its features' noise
    allows, ``image`` the rest: a feature whose standard error reaches half of ``sigma_f`` (a defocused or glossy
    first hit) cannot tell an edge from its noise, so cannot stop the filter where it should.

    Parameters
    ----------
    buffer
        The samples: the variances of the means and the features (albedo, normal, depth; those
        it carries). Without features only the colour stops the filter.
    image
        (H, W, C) image to smooth (stage 1's result).
    iterations
        Number of passes.

    Returns
    -------
    numpy.ndarray
        The smoothed (H, W, C) image.

    Examples
    --------
    Two halves of different albedo under noise: the filter smooths each half and keeps the
    edge the albedo shows, even where the noisy colour alone would not tell it:

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.guided import feature_pilot
    >>> rng = np.random.default_rng(0)
    >>> clean = np.ones((32, 32, 1)); clean[:, 16:] = 1.2
    >>> albedo = np.repeat(clean / 2, 3, axis=2)
    >>> samples = clean + 0.5 * rng.standard_normal((32, 32, 1))    # 4 samples of variance 1 per pixel
    >>> count = np.full((32, 32), 4)
    >>> buffer = SampleBuffer.from_moments(count, samples, np.ones((32, 32, 1)),
    ...     features={"albedo": SampleBuffer.from_moments(count, albedo, np.zeros((32, 32, 3)))})
    >>> out = feature_pilot(buffer, samples)
    >>> rms = lambda a: float(np.sqrt(np.mean((a - clean) ** 2)))
    >>> rms(out) < rms(samples) / 4, round(float(out[:, 20:].mean() - out[:, :12].mean()), 1)
    (True, 0.2)

    Without the albedo, the colour alone blurs the edge more:

    >>> colour_only = feature_pilot(SampleBuffer.from_moments(count, samples, np.ones((32, 32, 1))), samples)
    >>> edge = lambda a: round(float(np.abs(a - clean)[:, 15:17].mean()), 2)   # the two edge columns
    >>> edge(out), edge(colour_only)
    (0.09, 0.1)
    """
    out = np.array(image, dtype=np.float64)
    variance = buffer.estimated_variance() / np.maximum(buffer.count, 1)[..., None]  # as prepare's
    unit = _unit(out, variance)  # the colour's distances are relative to its variances: the same in any unit
    out *= unit
    variance = variance * unit * unit
    floor = np.finfo(np.float64).tiny + 1e-12 * float(np.mean(np.abs(out)) ** 2)
    features = _feature_planes(buffer)
    for i in range(iterations):
        step = 2**i
        total = np.zeros_like(out)
        weights = np.zeros(out.shape[:2])
        spread = np.zeros_like(out)  # sum of w^2 v_q: the variance of the pass's output
        for a, ky in enumerate(_KERNEL):
            for b, kx in enumerate(_KERNEL):
                dy, dx = (a - 2) * step, (b - 2) * step
                c_q = _shifted(out, dy, dx)
                v_q = _shifted(variance, dy, dx)
                d = ((out - c_q) ** 2 / (_COLOUR_SIGMA**2 * _pair_variance(variance, v_q) + floor)).sum(-1)
                for mean, var, sigma, relative in features:
                    f_q = _shifted(mean, dy, dx)
                    scale = sigma * np.minimum(mean, f_q)[..., 0] if relative else sigma
                    with np.errstate(over="ignore", invalid="ignore"):  # an albedo or normal past 1e154
                        far = ((mean - f_q) ** 2).sum(-1) / (scale**2 + (var + _shifted(var, dy, dx)).sum(-1) + 1e-12)
                    d += np.where(np.isnan(far), np.inf, far)  # inf / inf: as far as can be (the centre tap is 0)
                w = ky * kx * np.exp(-d)
                total += w[..., None] * c_q
                weights += w
                spread += (w * w)[..., None] * v_q
        out = total / weights[..., None]
        # Later passes compare smoothed colours: their differences count against the smoothed
        # noise (as in SVGF), so an edge a few smoothed standard errors high stops the filter.
        variance = spread / (weights * weights)[..., None]
    share = _feature_confidence(features, out.shape[:2])[..., None]
    return (share * out + (1.0 - share) * (np.asarray(image, np.float64) * unit)) / unit


def _pair_variance(v_p: np.ndarray, v_q: np.ndarray) -> np.ndarray:
    """Twice the smaller of a tap's two variances, not their sum (:func:`feature_pilot`; docs/guides.md)."""
    return 2.0 * np.minimum(v_p, v_q)


def _feature_confidence(features: list[tuple[np.ndarray, np.ndarray, float, bool]],
                        shape: tuple[int, ...]) -> np.ndarray:
    """``prod_f sigma_f^2 / (sigma_f^2 + 4 u_p)``, 1 for noiseless features (:func:`feature_pilot`; docs/guides.md)."""
    share = np.ones(shape)
    for mean, var, sigma, relative in features:
        edge = (sigma * mean[..., 0]) ** 2 if relative else sigma * sigma
        noise = 4.0 * var.sum(-1)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # noise past float64: share 0
            share *= np.where(noise > 0, edge / (edge + noise), 1.0)
    return share


def checked_inputs(buffer: SampleBuffer, guide: object, features: object, stages: int) -> FloatArray | None:
    """Check :func:`~awr_denoise.reconstruct` 's ``guide`` and ``features`` before any work is done.

    Parameters
    ----------
    buffer
        The samples.
    guide
        ``None``, an (H, W, C) image, or a function of the buffer that returns one (called here).
    features, stages
        As given to :func:`~awr_denoise.reconstruct`.

    Returns
    -------
    numpy.ndarray or None
        The guide, checked (:func:`checked_guide`), or ``None``.

    Raises
    ------
    ValueError
        A guide or ``features=True`` without Wiener stages (``stages=1``), ``features=True`` on
        a buffer without features, or a guide :func:`checked_guide` refuses.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.guided import checked_inputs
    >>> buffer = SampleBuffer.from_moments(np.ones((4, 4)), np.ones((4, 4, 3)), np.zeros((4, 4, 3)))
    >>> checked_inputs(buffer, None, True, 3)
    Traceback (most recent call last):
    ...
    ValueError: features: the buffer carries no feature buffers (albedo, normal or depth)
    """
    _checks.flag("features", features)
    for name, used in (("guide", guide is not None), ("features", bool(features))):
        if used and stages < 2:
            raise ValueError(f"{name}: it gives the pilot of the Wiener stages; it needs stages > 1")
    if features and not buffer.features:
        raise ValueError("features: the buffer carries no feature buffers (albedo, normal or depth)")
    if callable(guide):  # a guide that is made from the buffer, such as awr_denoise.guides.oidn
        guide = guide(buffer)
        if guide is None:  # a failed denoiser wrapper must not pass for an unguided run
            raise ValueError("guide: the guide function returned None, not an (H, W, C) image")
    return None if guide is None else checked_guide(guide, buffer)


def guide_fields(guide: object, buffer: SampleBuffer) -> dict[str, str | int | float | bool]:
    """What a guide function records of itself: its ``recorded(buffer)``, a mapping of setting names
    to plain values (:class:`awr_denoise.guides.OIDNGuide`), which the result's ``parameters``
    carry; ``{}`` for an image or a function without one. The names begin with ``guide_``, so that
    none stands for a setting of the reconstruction's own.

    Raises
    ------
    TypeError
        If ``recorded`` is not a function returning a mapping of names beginning with ``guide_`` (not
        ``guide_projection``) to strings, numbers or flags.

    Examples
    --------
    >>> from awr_denoise.guided import guide_fields
    >>> class Guide:
    ...     def recorded(self, buffer):
    ...         return {"guide_name": "mine"}
    ...     def __call__(self, buffer): ...
    >>> guide_fields(Guide(), None), guide_fields(None, None)
    ({'guide_name': 'mine'}, {})
    """
    recorded = getattr(guide, "recorded", None) if callable(guide) else None
    if recorded is None:
        return {}
    if not callable(recorded):
        raise TypeError(f"guide: its recorded must be a function of the buffer, got {recorded!r}")
    fields = recorded(buffer)
    if not isinstance(fields, Mapping) or not all(
            isinstance(k, str) and k.startswith("guide_") and k != "guide_projection"
            and isinstance(v, (str, int, float, bool)) for k, v in fields.items()):
        raise TypeError("guide: its recorded settings must map names beginning with guide_ (not guide_projection) "
                        f"to strings, numbers or flags, got {fields!r}")
    return dict(fields)


def pilots(buffer: SampleBuffer, stage1: FloatArray, guide: FloatArray | None,
           features: bool) -> tuple[FloatArray, FloatArray | float]:
    """The Wiener stages' pilots: the first stage's, and the share of it every later stage keeps.

    A guide (checked, :func:`checked_guide`) is the pilot of *every* Wiener stage where
    :func:`trust` allows it: the first stage's pilot is :func:`gated`, and each later stage's
    is ``keep * first + (1 - keep) * previous``, with ``keep`` the gate's share, so where the
    samples contradict the guide the stages chain as they do without it. The feature pilot
    (:func:`feature_pilot`) is gated the same way but is the first stage's pilot only (measured:
    kept in the later stage as well, it lost 8-9% relMSE on the depth-of-field scenes;
    docs/guides.md). Without either, stage 1's image and ``keep = 0``.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.guided import pilots
    >>> buffer = SampleBuffer.from_moments(np.ones((4, 4)), np.ones((4, 4, 3)), np.zeros((4, 4, 3)))
    >>> stage1 = np.ones((4, 4, 3))
    >>> first, keep = pilots(buffer, stage1, None, False)
    >>> first is stage1, keep
    (True, 0.0)
    >>> first, keep = pilots(buffer, stage1, np.ones((4, 4, 3)), False)   # the guide agrees with the means
    >>> keep.shape, float(keep.min())
    ((4, 4, 1), 1.0)
    """
    if guide is None and not features:
        return stage1, 0.0
    candidate = guide if guide is not None else feature_pilot(buffer, stage1)
    share = trust(candidate, buffer)
    return share * candidate + (1.0 - share) * stage1, share if guide is not None else 0.0


def trust(candidate: FloatArray, buffer: SampleBuffer, *, window: int = GATE_WINDOW) -> FloatArray:
    """(H, W, 1) share of ``candidate`` the samples allow: 1 where it is within their noise, 0 where not.

    ``r`` is, over a ``window`` x ``window`` neighbourhood and the channels, the sum of
    ``(candidate - mean)^2`` over the sum of ``v``, the variances of the pixel means: about 1
    (plus its squared bias in standard errors) for an unbiased candidate. A ratio of sums, not a
    mean of ratios: a pixel whose variance the samples happen to underestimate (a few samples of a
    heavy tail) does not veto its neighbourhood. The share is 1 up to ``r = GATE_LOW`` and falls
    linearly to 0 at ``r = GATE_HIGH``. A pixel without samples adds nothing to either sum (its filled
    mean is a neighbour's): a window holding none gives a share of 1, nothing there to hold the
    candidate to.

    Examples
    --------
    Means of 16 samples of variance 1 around a clean 0.5: the clean image is trusted, an image
    two standard errors off is trusted in part, one three standard errors off not at all.

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.guided import trust
    >>> rng = np.random.default_rng(0)
    >>> mean = 0.5 + 0.25 * rng.standard_normal((32, 32, 3))
    >>> buffer = SampleBuffer.from_moments(np.full((32, 32), 16), mean, np.ones((32, 32, 3)))
    >>> [round(float(trust(np.full((32, 32, 3), 0.5 + off), buffer).mean()), 1) for off in (0.0, 0.5, 0.75)]
    [1.0, 0.6, 0.0]
    """
    x = filled_mean(buffer)
    v = buffer.estimated_variance() / np.maximum(buffer.count, 1)[..., None]
    with np.errstate(over="ignore"):  # a guide far beyond the means: its distance is inf, capped, share 0
        distance = np.minimum((candidate - x) ** 2, 1e300).sum(axis=-1)
    v = v.sum(axis=-1)
    # A pixel without samples has no mean to hold the candidate to (its filled mean is a neighbour's): no term.
    empty = buffer.count == 0
    distance[empty], v[empty] = 0.0, 0.0
    spread = window_sum(np.minimum(distance, 1e300 / window**2), window)  # sums, not running ones (._window_sums)
    noise = window_sum(v, window)
    with np.errstate(over="ignore"):  # a spread of 1e300 over a noise of 1e-300: Inf, no trust (an attack pass)
        r = np.where(noise > 0, spread / np.where(noise > 0, noise, 1.0), np.where(spread > 0, np.inf, 0.0))
    return np.clip((GATE_HIGH - r) / (GATE_HIGH - GATE_LOW), 0.0, 1.0)[..., None]


def gated(candidate: FloatArray, stage1: FloatArray, buffer: SampleBuffer) -> FloatArray:
    """``candidate`` where the samples allow it (:func:`trust`), stage 1's image elsewhere."""
    share = trust(candidate, buffer)
    return share * candidate + (1.0 - share) * stage1


def projected(transform: StationaryTransform, x: FloatArray, variance: FloatArray, guide: FloatArray,
              image: FloatArray, leverage: FloatArray | None, share: FloatArray | float, *, k: float,
              probes: int = 0, seed: int = 0, probe_variance: FloatArray | None = None,
              projection: float = PROJECTION_SHARE) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """The Wiener stages' ``image`` moved ``projection * share`` of the way to the means projected on the guide.

    ``share`` is the gate's (:func:`trust`): where it is 0 the image is returned as it is. The
    means' coefficients are moved towards the gated guide's (``share * guide + (1 - share) *
    image``), each within
    :data:`~awr_denoise.projection.DEFAULT_RADIUS` standard errors (:func:`~awr_denoise.projection.project`,
    in its default domain ``x / sqrt(|target| + k)``), and blended with ``image``. Both are linear in the means
    once the factors and the clipping pattern are held fixed, so the blend's ``leverage`` is the
    same blend of theirs (what the SURE guard then needs); with ``probes``, the variance of the
    projection is probed like the Wiener stage's (:func:`~awr_denoise.wiener.rademacher_probes`) and combined
    with ``probe_variance`` by the bound ``((1 - s) sd_1 + s sd_2)^2``.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray or None, numpy.ndarray or None)
        The blend, its leverage (if ``leverage`` was given) and its variance (with ``probes``).

    Examples
    --------
    A guide equal to the means changes nothing in the projection: the blend is the means'
    share of it plus the Wiener stages' share:

    >>> import numpy as np
    >>> from awr_denoise.stationary import StationaryTransform
    >>> from awr_denoise.guided import projected, PROJECTION_SHARE
    >>> x = np.random.default_rng(0).random((16, 16, 3)) + 1.0
    >>> smooth = np.full(x.shape, float(x.mean()))
    >>> out, _, _ = projected(StationaryTransform((16, 16), levels=2), x, np.full(x.shape, 0.01), x, smooth,
    ...                       None, 1.0, k=0.1)
    >>> bool(np.allclose(out, PROJECTION_SHARE * x + (1 - PROJECTION_SHARE) * smooth))
    True
    """
    if projection == 0 or not np.any(share):  # nothing to blend (the gate closed everywhere): the FFTs spared
        return image, leverage, probe_variance
    variance = transform.bounded(variance)
    target = share * guide + (1.0 - share) * image
    result = project(transform, x, variance, target, offset=k, leverage=leverage is not None)
    s = projection * np.asarray(share, np.float64)  # none where the gate is closed: no guide, no change
    out = image + s * (result.image - image)
    lev = None if leverage is None else leverage + s * (result.leverage - leverage)
    var_out = None
    if probes and probe_variance is not None:
        total = np.zeros_like(x)
        for e in rademacher_probes(variance, probes, seed):
            filtered = project(transform, x, variance, target, offset=k, extra=e).extra
            total += (filtered * filtered).sum(axis=0)  # type: ignore[operator]
        var_out = np.where(s > 0, ((1 - s) * np.sqrt(probe_variance) + s * np.sqrt(total / probes)) ** 2,
                           probe_variance)
    return out, lev, var_out


def checked_projection(value: object, guide: FloatArray | None) -> float:
    """``guide_projection`` checked: a number in [0, 1], given only with a guide; ``None``: the default.

    Examples
    --------
    >>> from awr_denoise.guided import checked_projection, PROJECTION_SHARE
    >>> checked_projection(None, None), checked_projection(None, object()) == PROJECTION_SHARE
    (0.0, True)
    >>> checked_projection(0.25, None)
    Traceback (most recent call last):
        ...
    ValueError: guide_projection: 0.25 given without a guide (it is the share of the guide's projection)
    """
    if value is None:
        return 0.0 if guide is None else PROJECTION_SHARE
    share = float(_checks.real("guide_projection", value, minimum=0, maximum=1))  # type: ignore[arg-type]
    if guide is None:
        raise ValueError(f"guide_projection: {value!r} given without a guide (it is the share of the guide's projection)")
    return share
