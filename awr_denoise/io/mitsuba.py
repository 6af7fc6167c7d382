"""Mitsuba 3 film filters: telling from the data whether neighbouring pixel means are correlated.

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..buffers import SampleBuffer

__all__ = ["CORRELATED_BELOW", "FilterCheck", "filter_correlation"]

CORRELATED_BELOW = 0.3
"""Median normalised second difference under which the pixel means are taken as correlated."""

_MIN_TRIPLETS = 200


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
    def message(self) -> str:
        """One line for a warning."""
        return (f"neighbouring pixel means vary {1 / max(self.ratio, 1e-9):.1f}x less than their variances allow "
                "(median normalised second difference "
                f"{self.ratio:.2f}, {CORRELATED_BELOW} or more expected): the film filter is probably not "
                "'box', so pixels share samples and variances are off; render with rfilter type 'box'")


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
