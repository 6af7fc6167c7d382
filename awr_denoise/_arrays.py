"""Checks of the per-pixel arrays a :class:`~awr_denoise.buffers.SampleBuffer` is built from.

Each check raises a ``ValueError`` (or ``TypeError``) naming the parameter and the number of bad
pixels, as the buffer's constructors document; the buffer and its features share them.
"""

from __future__ import annotations

import numpy as np

from ._typing import CountArray, FloatArray, Shape2D

__all__ = ["plain", "numeric", "frozen", "as_float64", "check_finite", "check_count", "flat_pixel_index",
           "pixel_moments", "independent_moments", "as_mask", "ReadOnlyArrays", "summed_counts"]


def plain(name: str, array: object) -> np.ndarray:
    """``np.asarray(array)``, refusing a masked array that masks anything: ``asarray`` drops the mask
    and the values under it would be used (a masked firefly kept, a masked NaN reported as a NaN)."""
    if isinstance(array, np.ma.MaskedArray):
        masked = int(np.ma.getmaskarray(array).sum())
        if masked:
            raise TypeError(f"{name}: a masked array with {masked} masked entries; fill them (numpy.ma.filled) or "
                            "leave those pixels or samples out")
    try:
        return np.asarray(array)
    except ValueError:  # ragged nested lists: numpy's own words name no argument
        raise TypeError(f"{name}: not an array (nested sequences of different lengths?)") from None


def numeric(name: str, array: object) -> np.ndarray:
    """:func:`plain`, refusing complex (its imaginary part would be dropped), bool (a mask passed by
    mistake), object and string arrays, naming ``name``."""
    a = plain(name, array)
    if a.dtype.kind == "c":
        raise TypeError(f"{name}: complex values are not supported")
    if a.dtype.kind not in "fiu":
        raise TypeError(f"{name}: expected a numeric array, got dtype {a.dtype}")
    return a


def frozen(array: np.ndarray, *, adopt: bool = False) -> np.ndarray:
    """A read-only, C-ordered view of ``array`` whose memory's owner is read-only too: numpy lets
    anyone set ``writeable`` back on an array that owns its memory (a sampler's request edited
    after ``ask()`` was then checked against itself by ``tell()``), never on a view of a read-only
    owner. ``adopt``: the owner is the library's own, handed over (made read-only, not copied)."""
    a = np.ascontiguousarray(array)
    owner = a
    while isinstance(owner.base, np.ndarray):
        owner = owner.base
    if owner is not a and owner.flags.writeable and not adopt:  # someone else's memory: a copy of our own
        a = owner = a.copy()
    owner.flags.writeable = False
    view = a.view()
    view.flags.writeable = False
    return view


def as_float64(name: str, array: object, ndim: int, *, copy: bool = True) -> FloatArray:
    """A C-ordered float64 copy of a numeric array of ``ndim`` dimensions (complex, bool and masked
    entries refused); ``copy=False``: the array itself if it is C-ordered float64 already."""
    a = numeric(name, array)
    if a.ndim != ndim:
        raise ValueError(f"{name}: expected {ndim} dimensions, got shape {a.shape}")
    # C order: a buffer of a transposed (W, H) array would otherwise keep its memory order, and a
    # result's last bits (and every file writer) depended on it.
    with np.errstate(over="ignore"):  # a long double beyond float64 becomes Inf: named below, not "NaN or Inf"
        out = a.astype(np.float64, order="C", copy=copy)
    if a.dtype.kind == "f" and a.dtype.itemsize > 8 and (beyond := int((np.isinf(out) & np.isfinite(a)).sum())):
        raise ValueError(f"{name}: {beyond} value(s) beyond float64's range (long doubles are read as float64)")
    return out


def check_finite(name: str, a: FloatArray) -> None:
    """Refuse NaN/Inf, counting the pixels (first two axes) that hold any."""
    bad = ~np.isfinite(a)
    if bad.any():
        pixels = int(bad.reshape(bad.shape[0], bad.shape[1], -1).any(axis=2).sum())
        raise ValueError(f"{name}: {pixels} pixel(s) hold NaN or Inf")


def check_count(count: object, name: str = "count", *, summed: bool = True) -> CountArray:
    """(H, W) whole, non-negative sample counts as int64 (``name``: the parameter a refusal names);
    ``summed``: their total too is held to 2**62 (not for per-pixel sample indices)."""
    c = plain(name, count)
    if c.ndim != 2:
        raise ValueError(f"{name}: expected shape (H, W), got {c.shape}")
    if c.dtype.kind == "f":
        bad = ~(np.abs(c) <= 2**62)  # NaN, Inf, or beyond what int64 counts hold safely
        if bad.any():
            raise ValueError(f"{name}: {int(bad.sum())} pixel(s) hold NaN or Inf (or exceed 2**62)")
        if (c != np.round(c)).any():
            raise ValueError(f"{name}: {int((c != np.round(c)).sum())} pixel(s) are not whole numbers")
    elif c.dtype.kind not in "iu":
        raise TypeError(f"{name}: expected an integer array, got dtype {c.dtype}")
    elif c.dtype.kind == "u" and (c > 2**62).any():  # cast to int64 it would wrap and read as negative
        raise ValueError(f"{name}: {int((c > 2**62).sum())} pixel(s) exceed 2**62, the most int64 counts hold safely")
    c = c.astype(np.int64, order="C")
    if (c < 0).any():
        raise ValueError(f"{name}: {int((c < 0).sum())} pixel(s) are negative")
    if summed and c.sum(dtype=np.float64) > 2**62:  # summed in float64: an int64 sum would wrap to a negative total
        raise ValueError(f"{name}: {c.sum(dtype=np.float64):.4g} samples in all exceed 2**62, the most int64 totals "
                         "hold safely")
    return c


def summed_counts(a: CountArray, b: CountArray) -> CountArray:
    """``a + b`` of two checked count arrays, refused where it passes 2**62 (int64 would wrap it to
    a negative count, reported as one)."""
    if (a > 2**62 - b).any():
        raise ValueError(f"other: {int((a > 2**62 - b).sum())} pixel(s) would hold more than 2**62 samples merged, "
                         "the most int64 counts hold safely")
    return a + b


def flat_pixel_index(pixels: np.ndarray, shape: Shape2D) -> np.ndarray:
    """Row-major flat indices of ``(row, col)`` pairs or flat indices, checked against ``shape``."""
    h, w = shape
    p = plain("pixels", pixels)
    if p.dtype.kind not in "iu":
        raise TypeError(f"pixels: expected integer coordinates, got dtype {p.dtype}")
    if p.ndim == 2 and p.shape[1] == 2:
        rows, cols = p[:, 0].astype(np.int64), p[:, 1].astype(np.int64)
        bad = (rows < 0) | (rows >= h) | (cols < 0) | (cols >= w)
        if bad.any():
            raise ValueError(f"pixels: {int(bad.sum())} coordinate(s) fall outside the {h}x{w} image")
        return rows * w + cols
    if p.ndim == 1:
        flat = p.astype(np.int64)
        bad = (flat < 0) | (flat >= h * w)
        if bad.any():
            raise ValueError(f"pixels: {int(bad.sum())} index(es) fall outside the {h}x{w} image")
        return flat
    raise ValueError(f"pixels: expected (N, 2) coordinates or (N,) flat indices, got shape {p.shape}")


def pixel_moments(pixel: np.ndarray, values: FloatArray, n_pixels: int,
                  name: str = "values") -> tuple[CountArray, FloatArray, FloatArray]:
    """Per-pixel count, mean and sample variance (``M2 / (n - 1)``, 0 below two samples) of samples
    ``values`` (N, C) at ``pixel`` (N,).

    Corrected two-pass in float64 (Chan, Golub and LeVeque 1983), a channel at a time (every pixel and
    sample vectorised): the mean of the deviations from the first mean corrects it, so samples that
    all agree give their value and a variance of exactly 0 (the first mean's rounding alone, squared and
    scaled back from near the float64 limit, was a variance beyond float64 for 7 samples of 1e200).
    Where the squares could overflow (values above 2**480; below it, squared deviations summed over
    fewer than 2**60 samples stay within float64), each pixel's samples are divided by a power of two near its own
    largest value (exact, the same bits) and the variance, not M2, is scaled back: a variance within
    float64 is kept whatever M2 (2**24 samples of +-2**500 have an M2 of 2**1024); one beyond it is
    refused naming ``name``.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise._arrays import pixel_moments
    >>> count, mean, variance = pixel_moments(np.zeros(7, int), np.full((7, 1), 0.1), 1)
    >>> count, bool(mean[0, 0] == 0.1), variance              # 7 x 0.1 / 7 is not 0.1 in float64
    (array([7]), True, array([[0.]]))
    """
    count = np.bincount(pixel, minlength=n_pixels)
    safe = np.maximum(count, 1)
    top = float(np.abs(values).max(initial=0.0))
    scale = None
    if top > 2.0**480:
        peak = np.zeros(n_pixels)
        np.maximum.at(peak, pixel, np.abs(values).max(axis=1))
        # Each pixel's values then lie within +-4; the exponent is held at -1020 or more so that a pixel
        # of zeros or denormals gets a positive scale (2**-1076 would be 0).
        scale = np.ldexp(1.0, np.maximum(np.frexp(peak)[1] - 2, -1020))
        values = values / scale[pixel, None]
    mean = np.empty((n_pixels, values.shape[1]))
    variance = np.empty_like(mean)
    for c in range(values.shape[1]):
        column = np.ascontiguousarray(values[:, c])  # one strided read, not three
        m = np.bincount(pixel, weights=column, minlength=n_pixels) / safe
        dev = column - m.take(pixel)
        m += np.bincount(pixel, weights=dev, minlength=n_pixels) / safe
        np.subtract(column, m.take(pixel), out=dev)
        dev *= dev
        mean[:, c], variance[:, c] = m, np.bincount(pixel, weights=dev, minlength=n_pixels)
    variance /= np.maximum(count - 1, 1)[:, None]
    if scale is not None:
        with np.errstate(over="ignore"):
            mean *= scale[:, None]
            variance *= scale[:, None]
            variance *= scale[:, None]  # twice, not by scale squared: that overflows first
        beyond = int((~np.isfinite(variance).all(axis=1)).sum())
        if beyond:
            raise ValueError(f"{name}: the variance of {beyond} pixel(s) is beyond float64 (1.8e308): their samples "
                             "spread that far, or are so large (above about 1e154) that rounding alone does")
    return count, mean, variance


def independent_moments(counts: CountArray, means: FloatArray) -> tuple[CountArray, FloatArray, FloatArray, np.ndarray]:
    """Per-pixel count, mean and spread of N independent renders known by their checked counts (N, H, W)
    and finite means (N, H, W, C): ``n = sum n_k``, the weighted mean, ``sum n_k (m_k - mean)^2 / (N' - 1)``
    over the ``N'`` renders with samples, and ``N'``.

    Counts are summed in int64 (exact; refused past 2**62); each pixel's means are divided, channel by channel,
    by a power of two near the largest of the renders with samples there (exact) so that neither the weighted
    sums nor the squared spread overflow, nor a small channel beside a large one underflow, the mean is
    the corrected two-pass one (renders that agree give their value and no spread), and a spread beyond
    float64 is refused naming ``means``.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise._arrays import independent_moments
    >>> n, mean, spread, renders = independent_moments(np.full((2, 1, 1), 4), np.full((2, 1, 1, 1), 1e308))
    >>> int(n[0, 0]), float(mean[0, 0, 0]), float(spread[0, 0, 0]), int(renders[0, 0])
    (8, 1e+308, 0.0, 2)
    """
    beyond = counts.sum(axis=0, dtype=np.float64) > 2**62  # in float64: an int64 sum could wrap
    if beyond.any():
        raise ValueError(f"counts: {int(beyond.sum())} pixel(s) would hold more than 2**62 samples merged, the "
                         "most int64 counts hold safely")
    n = counts.sum(axis=0)  # exact in int64 below 2**62 (in float64 2**53 + 1 was 2**53)
    renders = (counts > 0).sum(axis=0)
    # Each channel's scale from the renders with samples there: a render without any may hold anything,
    # and one scale for every channel underflowed the small ones (3e-300 beside 1e300 came out 0).
    m = np.where(counts[..., None] > 0, means, 0.0)
    peak = np.abs(m).max(axis=0)
    scale = np.ldexp(1.0, np.clip(np.frexp(peak)[1] - 2, -1020, None))
    m = m / scale
    w = (counts / np.maximum(n, 1))[..., None]  # each render's share of the pixel's samples
    mean = (w * m).sum(axis=0)
    mean += (w * (m - mean)).sum(axis=0)  # corrected two-pass
    variance = (w * (m - mean) ** 2).sum(axis=0) * n[..., None] / np.maximum(renders - 1, 1)[..., None]
    with np.errstate(over="ignore"):
        mean *= scale
        variance *= scale
        variance *= scale  # twice, not by scale squared: that overflows first
    far = int((~np.isfinite(variance).all(axis=2)).sum())
    if far:
        raise ValueError(f"means: the spread of {far} pixel(s) over the renders is beyond float64 (1.8e308)")
    return n, mean, variance, renders


def as_mask(name: str, array: object) -> np.ndarray:
    """A boolean array from booleans or the numbers 0 and 1; NaN, 0.5 or a string is refused, not cast
    (``bool(nan)`` is True)."""
    a = plain(name, array)
    if a.dtype == bool:
        return a
    if a.dtype.kind not in "fiu":
        raise TypeError(f"{name}: expected booleans (or 0 and 1), got dtype {a.dtype}")
    if not np.isin(a, (0, 1)).all():
        raise ValueError(f"{name}: expected booleans (or 0 and 1), got other values (NaN, fractions)")
    return a.astype(bool)


class ReadOnlyArrays:
    """A frozen dataclass whose arrays stay read-only through pickle and deepcopy (buffers and
    requests travel to worker processes and Dask workers), which rebuild arrays writeable: a
    count edited there to -3 was taken without a check."""

    def __setstate__(self, state: dict) -> None:
        for name, value in state.items():
            object.__setattr__(self, name, frozen(value) if isinstance(value, np.ndarray) else value)
