"""Mitsuba 3 film filters: telling from the data whether pixels' samples were weighted as the method assumes.

The ``moment`` integrator's moments are accumulated through the film's reconstruction filter.
With a box filter each sample lands in one pixel and pixel means are independent, as the
method assumes. With Mitsuba's default ``gaussian`` filter (or ``tent``, ``mitchell``...) a
sample lands in several pixels: neighbouring means share samples, and the per-pixel "variance"
m2 - m1^2 also absorbs the image's variation across the filter footprint. The file does not say
which filter was used (Mitsuba writes only ``generatedBy``), so :func:`filter_correlation`
tests the consequence: the second difference ``m[x-1] - 2 m[x] + m[x+1]`` of independent
means has variance ``v[x-1] + 4 v[x] + v[x+1]``; a blurring filter removes most of that noise.

Measured on Mitsuba 3.9 renders of its Cornell box (32x32 and 64x64, 2-256 spp; see
docs/io.md), the median of ``d^2 / (v[x-1] + 4 v[x] + v[x+1])`` over all pixel triplets and
channels was 0.72-1.29 with a box filter, 0.06-0.23 with ``gaussian`` up to 64 spp (0.42 at
256 spp), 0.13-0.35 with ``tent`` and 0.15-0.38 with ``mitchell``; ``lanczos`` (0.35-1.5) is
not told apart. Below :data:`CORRELATED_BELOW` the reader warns. Filters with negative lobes
(``mitchell``, ``catmullrom``, ``lanczos``) also leave some pixels with a negative second
moment, which no set of samples has: the reader refuses such a file before this test runs.

A filter narrower than a pixel (``gaussian`` with ``stddev`` 0.1, ``tent`` with ``radius`` 0.4) shares
no sample between pixels, so the test above cannot see it, but it weights a pixel's samples unequally,
some by 0: the pixel's effective sample count falls far below ``spp`` and ``m2 - m1^2`` understates
the noise of its mean several times over (found in a red-team pass). :func:`moment_bound` proves it from the
moments themselves. Radiance samples are never negative, and ``n`` samples ``x_i >= 0`` satisfy
``sum x_i^2 <= (sum x_i)^2``, so equally weighted ones give ``m2 <= n m1^2``: a pixel beyond that
bound holds more samples than its count says, or samples weighted unequally. The same bound refuses
an ``spp`` given too small (8-spp moments read as 2 spp: variances 4x too large; a 16-spp file merged
as 8 spp: its mean weighted as half the samples it holds).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..buffers import SampleBuffer

__all__ = ["CORRELATED_BELOW", "FilterCheck", "filter_correlation", "MomentBound", "moment_bound", "RAW_FILM"]

CORRELATED_BELOW = 0.3
"""Median normalised second difference under which the pixel means are taken as correlated."""

_MIN_TRIPLETS = 200
RAW_FILM = ("holds Mitsuba's unnormalised film (film.bitmap(raw=True)): its planes are sums weighted by the filter "
            "and W is their weights; write film.write() or film.bitmap(), or divide every plane by W")
"""Why a Mitsuba file with a root ``W`` channel is refused, as a dump and as an image (``awr diff`` compared
its sums)."""
_BOUND_SLACK = 0.01  # m2 / (n m1^2) beyond 1 + this: not the rounding of float32 or HALF sums (2**-9 and less)
_AGREED_WITHIN = 2.0**-9  # m2 / m1^2 - 1 below this: samples that agreed, to a HALF's rounding
_MIN_AGREED = 64  # pixels that must all agree before a file is called one sample per pixel


@dataclass(frozen=True)
class FilterCheck:
    """Outcome of :func:`filter_correlation`."""

    ratio: float
    triplets: int

    @property
    def correlated(self) -> bool:
        """True when neighbouring means are clearly correlated (not a box filter)."""
        return self.ratio < CORRELATED_BELOW

    @property
    def measured(self) -> str:
        """What was measured, the first half of a warning."""
        return (f"neighbouring pixel means vary {1 / max(self.ratio, 1e-9):.1f}x less than their variances allow "
                f"(median normalised second difference {self.ratio:.2f}, {CORRELATED_BELOW} or more expected)")

    @property
    def message(self) -> str:
        """One line for a warning on a Mitsuba film."""
        return (f"{self.measured}: the film filter is probably not 'box', so pixels share samples and variances are "
                "off; render with rfilter type 'box'")

    @property
    def shared(self) -> str:
        """One line for a warning on another renderer's file (pbrt-v4's), where the filter is not the cause named."""
        return (f"{self.measured}: pixels share samples (the file resized or blurred after it was rendered, or a "
                "film filter wider than a pixel), and their variances are off")


def filter_correlation(buffer: SampleBuffer) -> FilterCheck | None:
    """Median of squared second differences of pixel means over their stated variance.

    Returns None when fewer than 200 pixel triplets have a known, positive variance (too
    little to tell).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> rng = np.random.default_rng(0)
    >>> samples = rng.normal(1.0, 0.3, (32, 32, 16))          # independent pixels, 16 spp
    >>> buf = SampleBuffer.from_moments(np.full((32, 32), 16), samples.mean(-1), samples.var(-1, ddof=1))
    >>> filter_correlation(buf).correlated
    False
    """
    mean = buffer.mean
    v = buffer.variance / np.maximum(buffer.count, 1)[..., None]
    usable = buffer.variance_known[..., None] & (v > 0)
    ratios = []
    for axis in (0, 1):
        if mean.shape[axis] < 3:
            continue
        first = [slice(None)] * 3
        mid = [slice(None)] * 3
        last = [slice(None)] * 3
        first[axis], mid[axis], last[axis] = slice(0, -2), slice(1, -1), slice(2, None)
        a, b, c = tuple(first), tuple(mid), tuple(last)
        d = mean[a] - 2 * mean[b] + mean[c]
        s = v[a] + 4 * v[b] + v[c]
        ok = usable[a] & usable[b] & usable[c]
        ratios.append(d[ok] ** 2 / s[ok])
    r = np.concatenate(ratios) if ratios else np.zeros(0)
    if r.size < _MIN_TRIPLETS:
        return None
    return FilterCheck(float(np.median(r)), int(r.size))


@dataclass(frozen=True)
class MomentBound:
    """Outcome of :func:`moment_bound`: the fewest samples a pixel's moments need, against its count."""

    needed: float
    count: int
    pixel: tuple[int, int]
    judged: int
    agreed: bool

    @property
    def exceeded(self) -> bool:
        """True when a pixel's moments need more samples than it counts (beyond rounding)."""
        return self.needed > self.count * (1.0 + _BOUND_SLACK)

    @property
    def message(self) -> str:
        """One line: which pixel, how many samples its moments need, and the two causes."""
        y, x = self.pixel
        return (f"pixel (x {x}, y {y})'s second moment is {self.needed:.6g} times its squared mean, which "
                f"{self.count} equally weighted samples never exceed (a pixel's spread needs at least that many "
                "samples): the file holds more samples per pixel than given, or the film's filter weighted them "
                "unequally (any filter but box: Mitsuba's default gaussian too, a gaussian or tent narrower than a "
                "pixel most); give the sampler's sample_count as spp "
                "and render the moments with rfilter box")


def moment_bound(count: np.ndarray, mean: np.ndarray, second: np.ndarray, *,
                 smallest: float = float(np.finfo(np.float32).tiny)) -> MomentBound | None:
    """The largest ``m2 / m1^2`` of pixels whose samples are non-negative, against their counts.

    Parameters
    ----------
    count
        (H, W) samples per pixel, as given or read.
    mean, second
        (H, W, C) first and second moments of radiance samples, as the file stores them.
    smallest
        The smallest normal value of the stored type (HALF: ``2**-14``): pixels whose moments are
        below it hold too few digits to judge, and are not.

    Returns
    -------
    MomentBound or None
        None when a mean is negative (the samples are not all non-negative and the bound does not
        hold) or no pixel can be judged. ``agreed``: every judged pixel of count above 1 has
        ``m2 = m1^2`` to rounding, at least 64 of them: samples that all agreed, or moments of one
        sample each read with a larger count.

    Examples
    --------
    Two pixels of 4 samples each, one with a single nonzero sample (its moments need exactly 4):

    >>> import numpy as np
    >>> from awr_denoise.io.mitsuba import moment_bound
    >>> samples = np.array([[[[0.0], [0.0], [0.0], [2.0]], [[1.0], [1.2], [0.8], [1.0]]]])  # (1, 2, 4, 1)
    >>> m1, m2 = samples.mean(axis=2), (samples**2).mean(axis=2)
    >>> bound = moment_bound(np.full((1, 2), 4), m1, m2)
    >>> bound.needed, bound.exceeded, bound.pixel
    (4.0, False, (0, 0))
    >>> moment_bound(np.full((1, 2), 2), m1, m2).exceeded      # read as 2 spp: more samples than counted
    True
    """
    count = np.asarray(count)
    mean, second = np.asarray(mean, dtype=np.float64), np.asarray(second, dtype=np.float64)
    finite = np.isfinite(mean) & np.isfinite(second)
    if (mean[finite] < 0).any():
        return None
    judged = finite & (mean >= smallest) & (second >= smallest)
    if not judged.any():
        return None
    with np.errstate(over="ignore"):
        needed = np.where(judged, second / np.where(judged, mean, 1.0) ** 2, 0.0)
    spread = needed.max(axis=-1)  # per pixel, its largest channel
    n = np.broadcast_to(count, spread.shape)
    worst = np.unravel_index(int(np.argmax(spread / np.maximum(n, 1))), spread.shape)
    several = judged.any(axis=-1) & (n > 1)
    agreed = bool(several.sum() >= _MIN_AGREED and (spread[several] <= 1.0 + _AGREED_WITHIN).all())
    return MomentBound(float(spread[worst]), int(n[worst]), (int(worst[0]), int(worst[1])),
                       int(judged.any(axis=-1).sum()), agreed)
