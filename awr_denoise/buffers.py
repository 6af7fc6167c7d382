"""Per-pixel Monte Carlo sample statistics: the :class:`SampleBuffer`.

A renderer reports, for every pixel ``p``, the number of samples ``n_p``, their mean and their
unbiased per-sample variance ``s2_p`` (Overbeck et al. 2009, section 3; docs/concepts.md,
"Sample buffer"). Everything the method needs follows from these three: the variance of the
pixel mean is ``v_p = s2_p / n_p`` and, because pixel means are independent (box pixel filter),
the variance of any linear wavelet coefficient is ``<v, K^2>``.

Statistics are kept in float64 and merged exactly with Chan's parallel update of Welford's
algorithm, so a buffer built from several batches equals the buffer of all samples at once.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field

import numpy as np

from . import _checks
from ._arrays import (ReadOnlyArrays, as_float64, as_mask, check_count, check_finite, flat_pixel_index, frozen, plain,
                      independent_moments, pixel_moments, summed_counts)
from ._typing import BoolArray, CountArray, FloatArray, Shape2D
from .channels import (channel_count, default_channel_names, luminance_variance,  # noqa: F401 - re-exported
                       luminance_weights, resolve_channels)
from .features import FEATURE_CHANNELS, checked_features, feature_rows, map_features, merge_features
from .merging import merge_moments
from .pooling import estimated_variance

__all__ = ["SampleBuffer", "VARIANCE_KINDS", "NONFINITE_POLICIES"]

VARIANCE_KINDS = ("sample", "mean", "second_moment")
"""How a renderer may report spread: per-sample variance, variance of the mean, raw E[x^2]."""

NONFINITE_POLICIES = ("raise", "drop", "zero")
"""What to do with NaN/Inf samples: refuse them, leave them out, or count them as 0."""

@dataclass(frozen=True, eq=False)
class SampleBuffer(ReadOnlyArrays):
    """Per-pixel sample count, mean and unbiased per-sample variance of an image.

    Parameters
    ----------
    count
        (H, W) int64, samples taken at each pixel.
    mean
        (H, W, C) float64, sample mean of each channel (0 where ``count == 0``).
    variance
        (H, W, C) float64, unbiased *per-sample* variance ``M2 / (n - 1)``; this is pbrt's
        ``Variance.*``, **not** the variance of the pixel mean (see :meth:`variance_of_mean`).
        Meaningless where :attr:`variance_known` is False (stored as 0 there).
    channels
        Names of the C channels.
    variance_known
        (H, W) bool, True where the per-sample variance is a usable estimate: at least two
        samples, and the renderer reported it (pbrt writes 0 for "unknown"). Unknown variance
        is never taken as zero variance: :meth:`estimated_variance` pools it from neighbours.
    nonfinite
        Number of NaN/Inf samples that were dropped or zeroed on the way in (see
        :meth:`from_samples`); carried through :meth:`merge`.
    features
        Optional per-pixel features, ``{"albedo" | "normal" | "depth": SampleBuffer}`` with the
        channels of :data:`~awr_denoise.features.FEATURE_CHANNELS`, each with its own count,
        mean and variance; merged and cropped with the radiance (:mod:`awr_denoise.features`).

    Notes
    -----
    Build buffers with the constructors (:meth:`from_samples`, :meth:`from_sums`,
    :meth:`from_moments`, :meth:`empty`); they validate input and raise a ``ValueError``
    that names the parameter and the number of bad pixels. Arrays are read-only. The examples
    of the methods use ``np`` and ``SampleBuffer`` imported as here.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> first = SampleBuffer.from_samples(np.array([0, 0, 1]), np.array([1.0, 3.0, 2.0]), (1, 2))
    >>> both = first.merge(SampleBuffer.from_samples(np.array([1, 1]), np.array([4.0, 6.0]), (1, 2)))
    >>> both.count, both.mean[..., 0], np.round(both.variance_of_mean()[..., 0], 4)   # v_p = s2_p / n_p
    (array([[2, 3]]), array([[2., 4.]]), array([[1.    , 1.3333]]))
    >>> both.crop(slice(0, 1), slice(1, 2))
    SampleBuffer(shape=(1, 1), channels=('Y',), total_samples=3, spp=3)
    """

    count: CountArray
    mean: FloatArray
    variance: FloatArray
    channels: tuple[str, ...]
    variance_known: BoolArray = field(repr=False)
    nonfinite: int = 0
    features: Mapping[str, SampleBuffer] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self._settle(copy=True)

    def _settle(self, *, copy: bool) -> None:
        """Check the fields and freeze them; ``copy=False`` takes float64 arrays nobody else holds as they are."""
        count = check_count(self.count)
        mean = as_float64("mean", self.mean, 3, copy=copy)
        variance = as_float64("variance", self.variance, 3, copy=copy)
        if mean.shape[:2] != count.shape:
            raise ValueError(f"mean: shape {mean.shape} does not match count {count.shape}")
        if variance.shape != mean.shape:
            raise ValueError(f"variance: shape {variance.shape} does not match mean {mean.shape}")
        if count.size == 0 or mean.shape[2] == 0:
            raise ValueError(f"count: empty image of shape {mean.shape}")
        check_finite("mean", mean)
        check_finite("variance", variance)
        if (variance < 0).any():  # per pixel only to count them: a reduction along 3 channels is 10x slower
            raise ValueError(f"variance: {int((variance < 0).any(axis=2).sum())} pixel(s) are negative")
        known = plain("variance_known", self.variance_known)
        if known.shape != count.shape:
            raise ValueError(f"variance_known: shape {known.shape} does not match count {count.shape}")
        known = as_mask("variance_known", known) & (count >= 2)
        # Masked writes only where needed (a merged buffer has none): ~20 ms each at 1080p regardless.
        if (empty := count == 0).any():
            mean[empty] = 0.0
        if (unknown := ~known).any():
            variance[unknown] = 0.0
        channels = resolve_channels(self.channels, mean.shape[2])
        count, mean, variance, known = (frozen(a, adopt=not copy) for a in (count, mean, variance, known))
        object.__setattr__(self, "count", count)
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "variance", variance)
        object.__setattr__(self, "variance_known", known)
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "nonfinite", _checks.whole("nonfinite", self.nonfinite, minimum=0, maximum=2**62))
        object.__setattr__(self, "features", checked_features(self, self.features))

    @classmethod
    def _adopt(cls, count: CountArray, mean: FloatArray, variance: FloatArray, channels: tuple[str, ...],
               known: BoolArray, nonfinite: int, features: Mapping[str, SampleBuffer]) -> SampleBuffer:
        """A buffer of float64 ``mean`` and ``variance`` this module has just made: the constructor's
        checks, without its copies (at 1080p two 50 MB copies per merge)."""
        out = object.__new__(cls)
        for name, value in (("count", count), ("mean", mean), ("variance", variance), ("channels", channels),
                            ("variance_known", known), ("nonfinite", nonfinite), ("features", features)):
            object.__setattr__(out, name, value)
        out._settle(copy=False)
        return out

    # ------------------------------------------------------------------ constructors
    @classmethod
    def empty(cls, shape: Shape2D, *, channels: Sequence[str] | int = 3) -> SampleBuffer:
        """A buffer of the given (H, W) shape with no samples."""
        n_channels = channel_count(channels)
        h, w = _checks.shape2d("shape", shape)
        zeros = np.zeros((h, w, n_channels))
        return cls(np.zeros((h, w), np.int64), zeros, zeros, resolve_channels(channels, n_channels),
                   np.zeros((h, w), bool))

    @classmethod
    def from_moments(
        cls,
        count: CountArray,
        mean: FloatArray,
        variance: FloatArray,
        *,
        variance_kind: str = "sample",
        channels: Sequence[str] | int | None = None,
        variance_known: BoolArray | None = None,
        features: Mapping[str, SampleBuffer] | None = None,
    ) -> SampleBuffer:
        """Build a buffer from per-pixel count, mean and a measure of spread.

        Parameters
        ----------
        count, mean
            (H, W) sample counts and (H, W, C) or (H, W) means.
        variance
            Same shape as ``mean``; what it holds is given by ``variance_kind``.
        variance_kind
            ``"sample"``: unbiased per-sample variance (pbrt-v4 ``Variance.*``);
            ``"mean"``: variance of the pixel mean (multiplied by ``count`` on entry);
            ``"second_moment"``: raw ``E[x^2]`` (Mitsuba 3 ``moment``), turned into
            ``(E[x^2] - mean^2) * n / (n - 1)``. The conversion happens once, here.
        variance_known
            Optional (H, W) mask of pixels whose variance is usable; False marks a renderer's
            "unknown" (pbrt's zero variance on pixels that only saw the environment).
        features
            Optional feature buffers (albedo, normal, depth), kept as given.

        Examples
        --------
        >>> kinds = {"sample": 8.0, "mean": 4.0, "second_moment": 20.0}   # samples 2 and 6, three ways
        >>> [SampleBuffer.from_moments([[2]], [[4]], [[v]], variance_kind=k).variance.item() for k, v in kinds.items()]
        [8.0, 8.0, 8.0]
        """
        if variance_kind not in VARIANCE_KINDS:
            raise ValueError(f"variance_kind: {variance_kind!r} is not one of {', '.join(VARIANCE_KINDS)}")
        count_arr = check_count(count)
        mean_arr = plain("mean", mean)
        var_arr = plain("variance", variance)
        if mean_arr.ndim == 2:
            mean_arr = mean_arr[..., None]
        if var_arr.ndim == 2:
            var_arr = var_arr[..., None]
        mean_arr = as_float64("mean", mean_arr, 3)
        var_arr = as_float64("variance", var_arr, 3)
        if var_arr.shape != mean_arr.shape:
            raise ValueError(f"variance: shape {var_arr.shape} does not match mean {mean_arr.shape}")
        if mean_arr.shape[:2] != count_arr.shape:
            raise ValueError(f"mean: shape {mean_arr.shape} does not match count {count_arr.shape}")
        check_finite("mean", mean_arr)
        check_finite("variance", var_arr)
        n = count_arr[..., None].astype(np.float64)
        if variance_kind == "mean":
            with np.errstate(over="ignore"):
                var_arr = var_arr * n
            if (far := ~np.isfinite(var_arr).all(axis=2)).any():
                raise ValueError(f"variance: {int(far.sum())} pixel(s) hold a variance of the mean that, times their "
                                 "count, is a per-sample variance beyond float64 (1.8e308)")
        elif variance_kind == "second_moment":
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                # E[x^2] >= mean^2: a deficit past rounding, or a mean^2 past float64, is not a second moment
                spread = var_arr - mean_arr**2
                if (short := ((spread < -1e-2 * mean_arr**2) | ~np.isfinite(spread)).any(axis=2)).any():
                    raise ValueError(f"variance: {int(short.sum())} pixel(s) hold a second moment below the squared "
                                     "mean: not E[x^2] (variance_kind)")
                spread = np.maximum(spread, 0.0)
                var_arr = np.where(n > 1, spread * n / np.maximum(n - 1, 1), 0.0)
        known = np.ones(count_arr.shape, bool) if variance_known is None else plain("variance_known", variance_known)
        return cls(count_arr, mean_arr, var_arr, resolve_channels(channels, mean_arr.shape[2]), known,
                   features=features if features is not None else {})

    @classmethod
    def from_sums(cls, count: CountArray, sum: FloatArray,  # noqa: A002 - the name the literature uses
                  sum_sq: FloatArray, *, channels: Sequence[str] | int | None = None) -> SampleBuffer:
        """Build a buffer from per-pixel count, sum of samples and sum of squared samples.

        Notes
        -----
        ``M2 = sum_sq - sum^2 / n`` cancels catastrophically when the mean is large against the
        spread; it is clamped at 0. Prefer :meth:`from_samples` or :meth:`from_moments` when the
        renderer can give them.

        Examples
        --------
        >>> buf = SampleBuffer.from_sums([[2, 1]], [[4.0, 5.0]], [[10.0, 25.0]])   # samples 1, 3 | 5
        >>> buf.mean[..., 0], buf.variance[..., 0], buf.variance_known            # one sample: unknown
        (array([[2., 5.]]), array([[2., 0.]]), array([[ True, False]]))
        """
        count_arr = check_count(count)
        s1, s2 = plain("sum", sum), plain("sum_sq", sum_sq)  # their dtypes checked, not cast: complex is refused
        if s1.ndim == 2:
            s1, s2 = s1[..., None], s2[..., None]
        s1, s2 = as_float64("sum", s1, 3), as_float64("sum_sq", s2, 3)
        if s2.shape != s1.shape or s1.shape[:2] != count_arr.shape:
            raise ValueError(f"sum/sum_sq: shapes {s1.shape}, {s2.shape} do not match count {count_arr.shape}")
        check_finite("sum", s1)
        check_finite("sum_sq", s2)
        n = count_arr[..., None].astype(np.float64)
        safe_n = np.maximum(n, 1.0)
        mean = np.where(n > 0, s1 / safe_n, 0.0)
        with np.errstate(over="ignore", invalid="ignore"):  # sum * mean beyond float64: refused below
            m2 = s2 - s1 * mean
        if not np.isfinite(m2).all():
            raise ValueError("sum_sq: a second moment beyond float64 (sum * mean overflows); pass the variance "
                             "to SampleBuffer.from_moments instead")
        # sum_sq >= sum^2 / n: a deficit past rounding (1%, as from_moments allows a second moment) is not a sum of
        # squares (a negative one was clamped to variance 0); a pixel without samples has nothing to sum.
        if (short := (m2 < -1e-2 * np.abs(s1 * mean)).any(axis=2)).any():
            raise ValueError(f"sum_sq: {int(short.sum())} pixel(s) hold less than sum^2 / count: not a sum of squares")
        if (empty := ((n[..., 0] == 0) & ((s1 != 0) | (s2 != 0)).any(axis=2))).any():
            raise ValueError(f"sum: {int(empty.sum())} pixel(s) without samples (count 0) hold a non-zero sum")
        np.maximum(m2, 0.0, out=m2)
        variance = np.where(n > 1, m2 / np.maximum(n - 1, 1.0), 0.0)
        return cls(count_arr, mean, variance, resolve_channels(channels, s1.shape[2]),
                   np.ones(count_arr.shape, bool))

    @classmethod
    def from_samples(
        cls,
        pixels: np.ndarray,
        values: FloatArray,
        shape: Shape2D,
        *,
        channels: Sequence[str] | int | None = None,
        nonfinite: str = "raise",
        features: Mapping[str, FloatArray] | None = None,
    ) -> SampleBuffer:
        """Accumulate raw samples into per-pixel statistics (exact two-pass, float64).

        Parameters
        ----------
        pixels
            (N, 2) integer ``(row, column)`` coordinates, or (N,) flat row-major indices.
        values
            (N, C) or (N,) sample values.
        shape
            (H, W) of the image.
        nonfinite
            ``"raise"`` (default): a sample with NaN/Inf in any channel is an error;
            ``"drop"``: such samples are left out; ``"zero"``: they count as 0 in every channel.
            Dropped or zeroed samples are counted in :attr:`nonfinite`.
        features
            Optional per-sample feature values, ``{"albedo": (N, 3), "normal": (N, 3),
            "depth": (N,) or (N, 1)}``, one row per sample as ``values``; each becomes a feature
            buffer. A sample that is not finite in its value or any feature is one bad sample.

        Examples
        --------
        >>> buf = SampleBuffer.from_samples(np.array([0, 0, 1, 1]), [1.0, 3.0, np.nan, 2.0], (1, 2), nonfinite="drop")
        >>> buf.count, buf.mean[..., 0], buf.nonfinite
        (array([[2, 1]]), array([[2., 2.]]), 1)
        """
        if nonfinite not in NONFINITE_POLICIES:
            raise ValueError(f"nonfinite: {nonfinite!r} is not one of {', '.join(NONFINITE_POLICIES)}")
        h, w = _checks.shape2d("shape", shape)  # whole sides within the limits: (2.7, 1) is not (2, 1)
        flat = flat_pixel_index(pixels, (h, w))
        vals = plain("values", values)
        if vals.ndim == 1:
            vals = vals[:, None]
        if vals.ndim != 2 or vals.shape[0] != flat.shape[0]:
            raise ValueError(f"values: expected ({flat.shape[0]}, C), got shape {np.shape(values)}")
        if vals.dtype.kind not in "fiu":
            raise TypeError(f"values: expected a numeric array, got dtype {vals.dtype}")
        vals = vals.astype(np.float64)
        if features is not None and not isinstance(features, Mapping):
            raise TypeError(f"features: expected a mapping of feature name to rows, got {type(features).__name__}")
        per_sample = {name: feature_rows(name, rows, flat.shape[0]) for name, rows in (features or {}).items()}
        bad = ~np.isfinite(vals).all(axis=1)
        culprit = "values" if bad.any() else ""
        for name, rows in per_sample.items():
            bad_here = ~np.isfinite(rows).all(axis=1)
            culprit = culprit or (f"features[{name!r}]" if bad_here.any() else "")
            bad |= bad_here
        n_bad = int(bad.sum())
        if n_bad:
            if nonfinite == "raise":
                raise ValueError(f"{culprit}: {n_bad} sample(s) hold NaN or Inf (pass nonfinite='drop' or 'zero')")
            if nonfinite == "drop":
                flat, vals = flat[~bad], vals[~bad]
                per_sample = {name: rows[~bad] for name, rows in per_sample.items()}
            else:
                vals[bad] = 0.0
                for rows in per_sample.values():
                    rows[bad] = 0.0
        feature_buffers = {name: cls._of_samples(flat, rows, (h, w), FEATURE_CHANNELS.get(name), f"features[{name!r}]")
                           for name, rows in per_sample.items()}
        return cls._of_samples(flat, vals, (h, w), channels, "values", n_bad, feature_buffers)  # 0 under "raise"

    @classmethod
    def _of_samples(cls, flat: np.ndarray, vals: FloatArray, shape: Shape2D, channels: Sequence[str] | int | None,
                    name: str, n_bad: int = 0, features: dict[str, SampleBuffer] | None = None) -> SampleBuffer:
        """The buffer of checked, finite samples ``vals`` (N, C) at flat pixels; ``name`` is theirs."""
        count, mean, variance = pixel_moments(flat, vals, shape[0] * shape[1], name)
        return cls(count.reshape(shape), mean.reshape(*shape, -1), variance.reshape(*shape, -1),
                   resolve_channels(channels, vals.shape[1]), np.ones(shape, bool), n_bad,
                   features if features is not None else {})

    @classmethod
    def from_independent_means(
        cls,
        counts: CountArray,
        means: FloatArray,
        *,
        channels: Sequence[str] | int | None = None,
    ) -> SampleBuffer:
        """Merge N independent renders of the same image, each known only by its means and counts.

        For renderers that write no variance (Blender Cycles): render the frame N times with
        different seeds and merge. The merged pixel has ``n = sum_k n_k`` samples and mean
        ``sum_k n_k m_k / n``; the per-sample variance is estimated from the spread of the N
        means, ``s2 = sum_k n_k (m_k - mean)^2 / (N - 1)``, unbiased when each render's mean
        has variance ``s2 / n_k`` (independent renders; ``s2`` is then the *effective*
        per-sample variance, which already includes any stratification gain of the renderer's
        sampler). ``s2 / n`` is the variance of the merged mean, the quantity thresholds use.

        Parameters
        ----------
        counts
            (N, H, W) whole sample counts of each render (``spp`` broadcast, or a count pass).
        means
            (N, H, W, C) or (N, H, W) pixel means of each render.
        channels
            Channel names.

        Returns
        -------
        SampleBuffer
            Variance known where at least two renders have samples.

        Examples
        --------
        >>> import numpy as np
        >>> from awr_denoise import SampleBuffer
        >>> means = np.array([1.0, 2.0, 3.0]).reshape(3, 1, 1)        # three renders of one pixel
        >>> buf = SampleBuffer.from_independent_means(np.full((3, 1, 1), 4), means)
        >>> int(buf.count[0, 0]), float(buf.mean[0, 0, 0]), float(buf.variance[0, 0, 0])
        (12, 2.0, 4.0)
        """
        c = plain("counts", counts)
        m = plain("means", means)
        if m.ndim == 3:
            m = m[..., None]
        if c.ndim != 3 or m.ndim != 4 or m.shape[:3] != c.shape:
            raise ValueError(f"counts/means: expected (N, H, W) and (N, H, W, C), got {c.shape}, {np.shape(means)}")
        if c.shape[0] < 2:
            raise ValueError(f"means: {c.shape[0]} render(s) given; the spread of means needs at least 2")
        per_render = np.stack([check_count(ck, "counts") for ck in c])
        m = np.stack([as_float64("means", mk, 3) for mk in m])
        check_finite("means", m.reshape(-1, *m.shape[2:]))
        n, mean, variance, renders = independent_moments(per_render, m)
        return cls(n, mean, variance, resolve_channels(channels, m.shape[3]), renders >= 2)

    # ------------------------------------------------------------------ properties
    @property
    def shape(self) -> Shape2D:
        """(H, W) of the image."""
        return (int(self.count.shape[0]), int(self.count.shape[1]))

    @property
    def n_channels(self) -> int:
        """Number of channels C."""
        return int(self.mean.shape[2])

    @property
    def total_samples(self) -> int:
        """Total number of samples over all pixels."""
        return int(self.count.sum())

    @property
    def m2(self) -> FloatArray:
        """(H, W, C) sum of squared deviations from the mean, ``variance * (n - 1)``."""
        return self.variance * np.maximum(self.count - 1, 0)[..., None]

    @property
    def nbytes(self) -> int:
        """Memory held by the statistics arrays."""
        own = self.count.nbytes + self.mean.nbytes + self.variance.nbytes + self.variance_known.nbytes
        return int(own + sum(f.nbytes for f in self.features.values()))

    # ------------------------------------------------------------------ statistics
    def estimated_variance(self) -> FloatArray:
        """(H, W, C) per-sample variance, unknown entries and samples that all agreed helped by neighbours.

        Where :attr:`variance_known` is False (fewer than two samples, or a renderer's "unknown"), the
        variance is pooled from the known pixels in a 5x5 window, ``sum(M2) / sum(n - 1)``, and from the
        whole image where the window has none: a single sample never counts as zero variance, nor do samples
        that all agreed (moderated towards the window's, :func:`~awr_denoise.pooling.agreed_variance`).
        With no variance known anywhere the result is 0 (nothing is known to be noisy).

        A pixel with two or more samples whose variance the renderer left unknown (pbrt-v4's
        environment-only pixels) has a mean of its own, and the borrowed variance must not cross
        a large jump in the mean: such a pixel pools only the neighbours whose ``|mean|`` is at
        most 4x its own (per channel); with none, it takes the image's pooled relative variance
        ``sum(M2) / sum((n - 1) mean^2)`` times its own ``mean^2``. Pixels with fewer than two
        samples have no reliable level of their own and pool from all known neighbours.

        Examples
        --------
        >>> mean = np.full((1, 3, 1), 0.5); mean[0, 0] = 2e5        # a light beside a dim sky
        >>> var = np.zeros((1, 3, 1)); var[0, 0] = 1e9; var[0, 2] = 0.01
        >>> known = np.array([[True, False, True]])                 # the middle pixel: unknown
        >>> buf = SampleBuffer.from_moments(np.full((1, 3), 16), mean, var, variance_known=known)
        >>> float(buf.estimated_variance()[0, 1, 0]) < 1.0           # not the light's 5e8
        True
        """
        return estimated_variance(self.count, self.mean, self.variance, self.variance_known)

    def variance_of_mean(self) -> FloatArray:
        """(H, W, C) variance of each pixel mean, ``s2 / n`` (paper section 3: ``v_p``).

        Unknown per-sample variances are pooled from neighbours (:meth:`estimated_variance`);
        pixels without samples get ``inf``.

        Examples
        --------
        >>> SampleBuffer.from_moments([[4, 0]], [[1.0, 0.0]], [[0.4, 0.0]]).variance_of_mean()[..., 0]
        array([[0.1, inf]])
        """
        n = self.count[..., None].astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            v = self.estimated_variance() / n
        v[self.count == 0] = np.inf
        return v

    def luminance(self) -> FloatArray:
        """(H, W) mean luminance (weights of :func:`luminance_weights`)."""
        return self.mean @ luminance_weights(self.channels)

    def luminance_variance(self) -> FloatArray:
        """(H, W) per-sample variance of luminance, from the estimated per-channel variances
        (:func:`~awr_denoise.channels.luminance_variance`: the fully correlated bound ``(sum_c w_c s_c)^2``)."""
        return luminance_variance(self.estimated_variance(), luminance_weights(self.channels))

    # ------------------------------------------------------------------ combining
    def merge(self, other: SampleBuffer, *, executor: Executor | None = None) -> SampleBuffer:
        """Exact statistics of the union of both buffers' samples (Chan et al.'s parallel update).

        ``n = na + nb``, ``mean = ma + d nb / n``, ``M2 = M2a + M2b + d^2 na nb / n`` with
        ``d = mb - ma``, in float64: merging batches gives the statistics of all samples. With an
        ``executor`` (threads) the halves of the rows merge on two of its threads: the same bits.

        Examples
        --------
        >>> a = SampleBuffer.from_samples(np.array([0, 0]), np.array([1.0, 2.0]), (1, 1))
        >>> merged = a.merge(SampleBuffer.from_samples(np.array([0, 0]), np.array([4.0, 5.0]), (1, 1)))
        >>> int(merged.count[0, 0]), float(merged.mean[0, 0, 0]), round(float(merged.variance[0, 0, 0]), 4)
        (4, 3.0, 3.3333)
        """
        if not isinstance(other, SampleBuffer):
            raise TypeError(f"other: expected a SampleBuffer, got {type(other).__name__}")
        if other.shape != self.shape or other.n_channels != self.n_channels:
            raise ValueError(f"other: shape {other.shape + (other.n_channels,)} does not match "
                             f"{self.shape + (self.n_channels,)}")
        if other.channels != self.channels:
            raise ValueError(f"other: channels {other.channels} do not match {self.channels}")
        mean, variance = merge_moments(self.count, self.mean, self.variance, other.count, other.mean, other.variance,
                                       executor=_checks.executor("executor", executor))
        known = (self.variance_known | (self.count < 2)) & (other.variance_known | (other.count < 2))
        return SampleBuffer._adopt(summed_counts(self.count, other.count), mean, variance, self.channels, known,
                                   self.nonfinite + other.nonfinite, merge_features(self, other))

    def select(self, channels: Sequence[int]) -> SampleBuffer:
        """The buffer of some of its channels (indices, in the order given), with its features.

        Examples
        --------
        >>> buf = SampleBuffer.from_moments(np.full((1, 1), 4), np.ones((1, 1, 4)), np.zeros((1, 1, 4)))
        >>> buf.select([3]).channels
        ('A',)
        """
        index = _checks.indices("channels", channels, self.n_channels)
        names = tuple(self.channels[i] for i in index)
        # type(self): some channels of a buffer keep its kind (prepare.EstimatedBuffer's variances stay final).
        return type(self)._adopt(self.count, self.mean[..., index], self.variance[..., index], names,
                                 self.variance_known, self.nonfinite, self.features)

    def crop(self, rows: slice, cols: slice) -> SampleBuffer:
        """The statistics of a rectangular region (a tile), as a new buffer.

        Examples
        --------
        >>> buf = SampleBuffer.from_moments(np.arange(12).reshape(3, 4), np.zeros((3, 4)), np.zeros((3, 4)))
        >>> buf.crop(slice(1, 3), slice(0, 2)).count.tolist()
        [[4, 5], [8, 9]]
        """
        _checks.tile(self.shape, rows, cols)
        count = self.count[rows, cols]  # where dropped samples were is not recorded: the whole image keeps its count
        return SampleBuffer(count, self.mean[rows, cols], self.variance[rows, cols], self.channels,
                            self.variance_known[rows, cols], self.nonfinite if count.shape == self.shape else 0,
                            map_features(self.features, lambda f: f.crop(rows, cols)))

    def __repr__(self) -> str:
        return (f"SampleBuffer(shape={self.shape}, channels={self.channels}, "
                f"total_samples={self.total_samples}, spp={self.total_samples / self.count.size:.3g}"
                + (f", features={tuple(self.features)})" if self.features else ")"))
