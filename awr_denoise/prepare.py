"""From sample statistics to the plane that thresholding and priorities work on.

Reconstruction (paper section 5) and the sampler's priorities (section 4) both need, per pixel,
a mean and the variance of that mean in the thresholding domain. Getting there takes the same
three steps wherever it happens, so it happens here only:

1. pixels without samples take their nearest sampled neighbour's mean (:func:`filled_mean`), so
   they are smoothed over rather than read as black;
2. unknown per-sample variances (fewer than two samples, or a renderer's "unknown") are pooled
   from neighbours, and the zero variances of samples that all agreed moderated towards theirs
   (:mod:`awr_denoise.pooling`, as :meth:`SampleBuffer.estimated_variance
   <awr_denoise.SampleBuffer.estimated_variance>`); a sample-less pixel counts as one sample of the
   pooled variance;
3. the domain is bound to the image (its offset fixed from the image's level) and the variance
   is carried into it by the delta method (:mod:`awr_denoise.domains`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import ndimage

from . import _checks
from ._typing import BoolArray, FloatArray
from .buffers import SampleBuffer
from .channels import luminance_variance, luminance_weights
from .domains import _LARGEST, _SMALLEST, Domain, _BoundDomain, resolve_domain
from .pooling import estimated_variance

__all__ = ["EstimatedBuffer", "Prepared", "filled_mean", "prepare"]

# log2 of the largest standard error at the unit scale of an image brought to its noise's (Prepared.unit_scaled):
# its square, 2**300, and products of a few such stay far inside float64.
_NOISE_HEADROOM = 150


def filled_mean(buffer: SampleBuffer) -> FloatArray:
    """(H, W, C) pixel means, sample-less pixels given their nearest sampled neighbour's mean.

    Raises
    ------
    ValueError
        If no pixel has a sample.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.prepare import filled_mean
    >>> buffer = SampleBuffer.from_moments([[1, 0]], [[2.0, 0.0]], [[0.0, 0.0]])
    >>> filled_mean(buffer)[..., 0]
    array([[2., 2.]])
    """
    return _filled(buffer, copy=True)


def _filled(buffer: SampleBuffer, *, copy: bool) -> FloatArray:
    """:func:`filled_mean`; without ``copy`` the buffer's own means when every pixel has samples."""
    empty = buffer.count == 0
    if not empty.any():
        return np.array(buffer.mean) if copy else buffer.mean
    if empty.all():
        raise ValueError("buffer: no pixel has any sample")
    _, (rows, cols) = ndimage.distance_transform_edt(empty, return_indices=True)
    return buffer.mean[rows, cols]


class EstimatedBuffer(SampleBuffer):
    """A buffer whose per-sample variances are already estimated (pooled and moderated, :mod:`~awr_denoise.pooling`):
    :func:`prepare` takes them as they are.

    A tile of a larger frame (:func:`~awr_denoise.parallel.reconstruct_tiled`) carries the variances the whole
    frame's preparation estimated; estimating them again inside the tile would see other neighbours (the tile's
    moderated ones) and give the tile other variances than the frame's.
    """


@dataclass(frozen=True, eq=False)
class Prepared:
    """A buffer made ready for thresholding: means, variances and the bound domain.

    Attributes
    ----------
    mean
        (H, W, C) filled means (or (H, W) filled luminance), in linear radiance.
    sample_variance
        Same shape, per-sample variance with unknown entries pooled from neighbours.
    count
        (H, W) or (H, W, 1) float64 sample count, at least 1 (a sample-less pixel counts as one
        sample of the pooled variance), shaped to divide :attr:`sample_variance`.
    bound
        The domain with its offset fixed for this image.
    sampled
        (H, W) pixels with samples of their own, or ``None`` when every pixel has some: a filled
        pixel's mean is no measurement of it (the guard's risk leaves it out, and it keeps the
        Wiener stages' result: :func:`~awr_denoise.sure.sure_blend`).

    Examples
    --------
    Means of 2 with per-sample variance 0.4 from 4 samples, in the log domain with
    ``k = 0.1 * 2``:

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.prepare import prepare
    >>> buffer = SampleBuffer.from_moments(np.full((2, 2), 4), np.full((2, 2), 2.0), np.full((2, 2), 0.4))
    >>> p = prepare(buffer, "log")
    >>> float(p.variance[0, 0, 0]), round(float(p.y[0, 0, 0]), 4)         # s2 / n; log(1 + 2 / 0.2)
    (0.1, 2.3979)
    >>> round(float(p.variance_y[0, 0, 0]), 6)                             # 0.1 / (2 + 0.2)^2
    0.020661
    >>> p.domain.scale                   # the image's level, for tiles or a luminance plane
    2.0
    """

    mean: FloatArray
    sample_variance: FloatArray
    count: FloatArray
    bound: _BoundDomain
    sampled: BoolArray | None = None

    @property
    def domain(self) -> Domain:
        """The thresholding domain, with its scale fixed to this image's.

        A plane prepared with this domain (a tile, or the luminance of the same image) is bound
        exactly as this one, offset for offset.
        """
        dom = self.bound.domain
        if dom.name == "linear" or dom.scale is not None:
            return dom
        scale = self.bound.scale if self.bound.scale is not None else dom.resolved_scale(self.mean)
        return dataclasses.replace(dom, scale=scale)

    def unit_scaled(self) -> tuple[float, float, FloatArray, FloatArray]:
        """``(s, k, x, v)``: a power of two ``s`` near the image's level (dividing by it is exact), and
        the domain's offset ``k``, the means ``x`` and their variances ``v`` at that scale: where the
        Wiener stages work, the image brought to about 1 (or, where its variances would pass float64 there, its
        largest standard error to 2**150)."""
        scale = self.domain.resolved_scale(self.mean)
        # The image's own level, not a scale given to the domain: a Domain(scale=1e-300) beside means
        # of 0.5 took the variances past float64 there, a NaN image (a red-team pass).
        given = self.bound.domain.scale is not None  # else the image's level is the scale, already known
        level = dataclasses.replace(self.domain, scale=None).resolved_scale(self.mean) if given else scale
        exponent = math.frexp(level)[1]
        # Means near 1e-200 beside ordinary variances (an AOV whose samples cancel) took v past float64 at the
        # level's scale: NaN variances. Such an image is brought to its noise's scale instead, its largest
        # standard error 2**150 there. Only where v would pass 2**1000: a few pixels of huge variance in an
        # ordinary image (which the stages take at the level's scale) do not move every pixel's scale.
        largest = float(np.max(self.variance, initial=0.0))
        noisy = largest > 0.0 and math.frexp(largest)[1] - 2 * exponent > 1000
        if noisy:
            exponent = (math.frexp(largest)[1] + 1) // 2 - _NOISE_HEADROOM
        s = math.ldexp(1.0, max(-1000, min(1000, exponent)))
        with np.errstate(over="ignore"):  # past float64 only for a scale some 1e300 times the image's
            k = np.float64(self.domain.offset) * (np.float64(scale) / s)  # not offset * scale: underflows near 5e-324
        # k = Inf failed the stages' own checks. At the noise's scale the level's k is below 2**-150, where the
        # guard's relative weights 1 / (|o| + k)^2 pass float64 beside means of 0: it is held there.
        k = min(max(k, math.ldexp(1.0, -_NOISE_HEADROOM) if noisy else _SMALLEST), _LARGEST)
        return s, float(k), self.mean / s, self.variance / s / s  # not s * s: that underflows near 1e-310

    @cached_property
    def variance(self) -> FloatArray:
        """Variance of each pixel mean in linear radiance, ``s2 / n`` (paper section 3: ``v_p``)."""
        return self.sample_variance / self.count

    @cached_property
    def y(self) -> FloatArray:
        """The means in the thresholding domain."""
        return self.bound.forward(self.mean)

    @cached_property
    def variance_y(self) -> FloatArray:
        """Variance of each mean in the domain, ``(s2 / n) f'(mean)^2`` (delta method)."""
        return self.bound.variance(self.mean, self.variance)

    @cached_property
    def sample_variance_y(self) -> FloatArray:
        """Per-sample variance in the domain, ``s2 f'(mean)^2``."""
        return self.bound.variance(self.mean, self.sample_variance)


def prepare(buffer: SampleBuffer, domain: str | Domain = "log", *, luminance: bool = False) -> Prepared:
    """Fill, pool and bind: the one preparation of statistics for thresholding and priorities.

    Parameters
    ----------
    buffer
        Per-pixel sample statistics.
    domain
        Thresholding domain (name or :class:`~awr_denoise.Domain`); its offset is fixed from
        the prepared plane's own level unless the domain carries a ``scale``.
    luminance
        Prepare one (H, W) luminance plane (weights of :func:`~awr_denoise.luminance_weights`,
        fully correlated channel variances, see
        :meth:`~awr_denoise.SampleBuffer.luminance_variance`) instead of every channel.

    Returns
    -------
    Prepared
        Means, pooled per-sample variances, counts and the bound domain; the domain-side
        quantities (:attr:`Prepared.y`, :attr:`Prepared.variance_y`) are computed on first use.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.prepare import prepare
    >>> count = np.array([[4, 4], [4, 0]])
    >>> mean = np.full((2, 2, 3), 2.0)
    >>> buffer = SampleBuffer.from_moments(count, mean, np.full((2, 2, 3), 0.4))
    >>> p = prepare(buffer, "linear")
    >>> p.variance[..., 0]          # s2 / n; the empty pixel counts as one pooled sample
    array([[0.1, 0.1],
           [0.1, 0.4]])
    >>> p.mean[1, 1]                # filled from its nearest neighbour
    array([2., 2., 2.])
    >>> p.sampled                   # the pixels with samples of their own
    array([[ True,  True],
           [ True, False]])
    """
    if not isinstance(buffer, SampleBuffer):
        raise TypeError(f"buffer: expected a SampleBuffer, got {type(buffer).__name__}")
    dom = resolve_domain(domain)
    _checks.flag("luminance", luminance)
    n = np.maximum(buffer.count, 1).astype(np.float64)
    # The buffer's own arrays (read-only) where nothing is filled or pooled: no copies.
    if isinstance(buffer, EstimatedBuffer):
        sample_variance = buffer.variance
    else:
        sample_variance = estimated_variance(buffer.count, buffer.mean, buffer.variance, buffer.variance_known,
                                             copy=False)
    if luminance:
        weights = luminance_weights(buffer.channels)
        mean = _filled(buffer, copy=False) @ weights  # a new array: no copy needed
        sample_variance = luminance_variance(sample_variance, weights)
    else:
        mean = _filled(buffer, copy=False)
        n = n[..., None]
    bound = dom.bound(mean)
    if dom.scale is not None and dom.name != "linear":
        top = float(np.abs(mean).max(initial=0.0))
        if top > 0 and bound.forward(np.array([top]))[0] == 0:
            # Every mean would be 0 in the domain: a black image, without a word (a red-team pass).
            raise ValueError(f"domain scale: {dom.scale:g} is so far above the image's level (largest |mean| "
                             f"{top:.3g}) that every mean underflows to 0 in the {dom.name} domain; give a "
                             "scale near the image's level, or None for its own")
    sampled = None if buffer.count.all() else buffer.count > 0
    return Prepared(mean, sample_variance, n, bound, sampled)
