"""Undecimated (stationary) wavelet transform with the exact variance of every coefficient.

The decimated transform of :mod:`awr_denoise.wavelets` depends on where its grid falls: shifting
the image by one pixel changes which coefficients exist, so thresholding leaves artefacts that
move with the grid (the shift artefacts and part of the ringing the paper lists among its
limitations, section 7). The stationary transform keeps every coefficient of every shift at
once: no band is decimated, and each level's filters are the previous level's upsampled by two
("a trous"). Synthesis averages over the decimation phases, as PyWavelets' ``iswt2`` does, so
reconstruction is perfect.

Every band is one circular convolution of the image with a separable kernel ``K_b``, done here
with FFTs on the image taken as periodic. Pixel means are independent, so the variance of a
band's coefficients is the circular convolution of the pixel variances with ``K_b^2`` (Eq. 10
of the paper without the square root), exactly, at the cost of one more FFT per band. On the
periodic canvas the detail kernels have zero sum and the coarse band's analysis times synthesis
has unit gain at zero frequency, so the image sum depends on the coarse band alone.

Layout, as :func:`~awr_denoise.wavelets.forward`'s: ``[cA_L, (cH_L, cV_L, cD_L), ...,
(cH_1, cV_1, cD_1)]``, every band of the image's own (H, W) size.

``dtype="float32"`` runs the FFTs in single precision (about half the time and memory); the
float64 transform is the reference the tests compare it against.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from functools import lru_cache
from itertools import product
from typing import NamedTuple

import ducc0
import numpy as np
import pywt
from scipy import fft as sfft

from . import _checks
from ._typing import FloatArray, Shape2D
from .wavelets import DEFAULT_WAVELET, WAVELET_NAMES, default_levels, max_levels

__all__ = ["StationaryTransform", "stationary_transform", "precision_for", "check_fft_environment", "DTYPES",
           "BACKENDS"]

DTYPES = ("float64", "float32")
"""Precisions of the FFTs: ``"float64"`` (the reference) and ``"float32"``."""

BACKENDS = ("ducc0", "scipy")
"""FFT libraries: ``"ducc0"`` (the default, docs/performance.md) and ``"scipy"`` (``scipy.fft``, the
reference the tests compare with)."""

def check_fft_environment() -> None:
    """Refuse a thread count in the environment that ducc0 cannot read.

    ducc0 reads ``DUCC0_NUM_THREADS``, else ``OMP_NUM_THREADS``, when its first FFT runs, whatever
    ``workers`` says, and stops with a C++ assertion on anything but a whole number: an empty
    value (``export OMP_NUM_THREADS=$UNSET_VARIABLE`` in a job script), ``4,2`` (valid for
    OpenMP), ``-1``, a number past ``2**63 - 1``. Checked here, before any work, with the variable named.

    Raises
    ------
    ValueError
        Naming the variable and its value.

    Examples
    --------
    >>> from awr_denoise.stationary import check_fft_environment
    >>> check_fft_environment()  # the variables unset or whole numbers
    """
    for name in ("DUCC0_NUM_THREADS", "OMP_NUM_THREADS"):  # ducc0's order: the first one set counts
        if name in os.environ:
            value = os.environ[name]
            # ducc0 parses a C long from ASCII: more digits, or non-ASCII digits or spaces, stop it.
            digits = value.strip(" \t\n\r\f\v").lstrip("+").lstrip("0")  # leading zeros: any number (ducc0 too)
            valid = re.fullmatch(r"\s*\+?[0-9]+\s*", value, re.ASCII) is not None
            if not valid or len(digits) > 19 or int(digits or 0) > 2**63 - 1:
                raise ValueError(f"{name}={value!r}: the FFT library (ducc0) reads it as a whole number of threads; "
                                 "set it to one, or unset it")
            return


_CACHE_BYTES = 64 * 2**20  # 2-D transfer functions kept per transform (all of them up to about 512x512)


class _Axis(NamedTuple):
    """Transfer functions along one axis, per level ``j = 1..L`` (index ``j - 1``)."""

    analysis: dict  # kind ("lo", "hi") -> list of per-level analysis transfer functions
    squared: dict  # the transfer functions of the squared analysis kernels
    synthesis: dict
    diagonal: dict  # of s(u) k(-u): a band's share of the transform pair's diagonal


def _transfer(taps: np.ndarray, n: int, step: int, half: bool) -> np.ndarray:
    """Transfer function of a filter upsampled by ``step`` on a periodic axis of length ``n``."""
    k = np.arange(n // 2 + 1 if half else n)
    return np.exp(-2j * np.pi * np.outer(k, np.arange(taps.size) * step % n) / n) @ taps


def _plane_indices(leading: tuple[int, ...]) -> Iterator[tuple[int, ...]]:
    """The indices of every (H, W) plane of an array with these leading dimensions, in C order.

    ``np.ndindex``'s order, without its cost: it builds a strided array per call, which adds up
    beside the FFTs of small planes.
    """
    return product(*(range(n) for n in leading))


_DELAY_TOLERANCE = 0.02  # how far a level's delay may be from a pure phase, |D| in [0.98, 1.02]


@lru_cache(maxsize=32)
def _axis(n: int, levels: int, wavelet: str, half: bool) -> _Axis:
    """The a-trous filter bank of one axis, its squared kernels and its exact synthesis.

    Level ``j`` uses the wavelet's filters upsampled by ``2^(j-1)``. Each level's synthesis
    pair is divided by that level's delay ``(D_lo R_lo + D_hi R_hi) / 2`` (a pure phase for
    every perfect-reconstruction filter bank), so every level, and the whole bank, reconstructs
    exactly.
    """
    dec_lo, dec_hi, rec_lo, rec_hi = (np.asarray(f, np.float64) for f in pywt.Wavelet(wavelet).filter_bank)
    size = n // 2 + 1 if half else n
    analysis: dict = {"lo": [], "hi": []}
    squared: dict = {"lo": [], "hi": []}
    synthesis: dict = {"lo": [], "hi": []}
    diagonal: dict = {"lo": [], "hi": []}
    spectrum, kernel_of = (np.fft.rfft, lambda t: np.fft.irfft(t, n)) if half else (np.fft.fft, lambda t: np.fft.ifft(t).real)
    a_lo = np.ones(size, complex)  # the cascade of low-pass filters so far
    s_lo = np.ones(size, complex)
    for j in range(1, levels + 1):
        step = 2 ** (j - 1)
        lo, hi = _transfer(dec_lo, n, step, half), _transfer(dec_hi, n, step, half)
        r_lo, r_hi = _transfer(rec_lo, n, step, half), _transfer(rec_hi, n, step, half)
        delay = 0.5 * (lo * r_lo + hi * r_hi)
        # A pure phase for every perfect-reconstruction bank; 'dmey', a finite approximation of Meyer's wavelet, is
        # 0.6% off one (it was refused for that), and divided by its delay it reconstructs exactly all the same.
        if not np.allclose(np.abs(delay), 1.0, atol=_DELAY_TOLERANCE):
            raise ValueError(f"wavelet: {wavelet!r} is not a perfect-reconstruction filter bank")
        bands = {"hi": (a_lo * hi, s_lo * 0.5 * r_hi / delay), "lo": (a_lo * lo, s_lo * 0.5 * r_lo / delay)}
        for kind, (a, s) in bands.items():
            kernel = kernel_of(a)
            analysis[kind].append(a)
            squared[kind].append(spectrum(kernel * kernel))
            synthesis[kind].append(s)
            diagonal[kind].append(spectrum(kernel_of(s) * np.roll(kernel[::-1], 1)))
        a_lo, s_lo = bands["lo"]
    return _Axis(analysis, squared, synthesis, diagonal)


class StationaryTransform:
    """The undecimated separable wavelet transform of (H, W) planes on the periodic image.

    Parameters
    ----------
    shape
        (H, W) of the planes.
    wavelet
        PyWavelets discrete wavelet; default ``"bior4.4"`` (CDF 9/7).
    levels
        Depth; default :func:`~awr_denoise.wavelets.default_levels`.
    dtype
        ``"float64"`` or ``"float32"``: the precision of the FFTs (inputs are converted, and
        the public methods return float64).
    workers
        Threads of each FFT.
    backend
        FFT library, one of :data:`BACKENDS`; the results agree to rounding.

    Examples
    --------
    Perfect reconstruction, the bands in :func:`~awr_denoise.wavelets.forward`'s layout
    (every band full size):

    >>> import numpy as np
    >>> from awr_denoise.stationary import StationaryTransform
    >>> image = np.random.default_rng(0).random((24, 20, 3))
    >>> t = StationaryTransform((24, 20), levels=2)
    >>> coeffs = t.forward(image)
    >>> len(coeffs), coeffs[0].shape, [band.shape for band in coeffs[1]]
    (3, (24, 20, 3), [(24, 20, 3), (24, 20, 3), (24, 20, 3)])
    >>> bool(np.allclose(t.inverse(coeffs), image))
    True

    Detail bands carry no part of the image sum (zero-sum kernels on the periodic image):

    >>> bool(abs(float(t.inverse([coeffs[0], (0, 0, 0), (0, 0, 0)]).sum() - image.sum())) < 1e-9)
    True

    Exact variances (Eq. 10): one noisy pixel of variance 1 gives every coefficient of a band
    the square of the weight its kernel puts on that pixel, so a band's variances sum to the
    kernel's energy:

    >>> v = np.zeros((24, 20))
    >>> v[5, 7] = 1.0
    >>> var = t.variance(v)
    >>> kernel = t.forward(np.where(v > 0, 1.0, 0.0))[2][2]          # cD of level 1
    >>> bool(np.isclose(var[2][2].sum(), (kernel ** 2).sum()))
    True
    """

    def __init__(self, shape: Shape2D, *, wavelet: str = DEFAULT_WAVELET, levels: int | None = None,
                 dtype: str = "float64", workers: int = 1, backend: str = "ducc0") -> None:
        h, w = _checks.shape2d("shape", shape)
        if _checks.name("wavelet", wavelet) not in WAVELET_NAMES:
            raise ValueError(f"wavelet: {wavelet!r} is not a discrete wavelet PyWavelets knows")
        lv = default_levels((h, w)) if levels is None else _checks.whole("levels", levels, minimum=1,
                                                                        maximum=max_levels((h, w)))
        self.shape: Shape2D = (h, w)
        self.wavelet = pywt.Wavelet(wavelet).name
        self.levels: int = int(lv)  # type: ignore[arg-type]
        self.dtype = np.dtype(_checks.name("dtype", dtype, DTYPES))
        self.workers = _checks.whole("workers", workers, minimum=1, maximum=1024)
        self.backend = _checks.name("backend", backend, BACKENDS)
        if self.backend == "ducc0":
            check_fft_environment()
        self._complex = np.complex64 if self.dtype == np.float32 else np.complex128
        self._rows = _axis(h, self.levels, self.wavelet, False)
        self._cols = _axis(w, self.levels, self.wavelet, True)
        self._cache: dict = {}
        # Every product (four kinds per band) is kept if all of them fit, none otherwise: a stage
        # uses each once in turn, so a partial cache would hold memory and save little time.
        product = h * (w // 2 + 1) * np.dtype(self._complex).itemsize
        self._caching = 4 * (3 * self.levels + 1) * product <= _CACHE_BYTES
        # (row kind, column kind, level index) of every band, in the layout's order.
        self.bands: list[tuple[str, str, int]] = [("lo", "lo", self.levels - 1)]
        for j in range(self.levels - 1, -1, -1):
            self.bands += [("hi", "lo", j), ("lo", "hi", j), ("hi", "hi", j)]

    def __repr__(self) -> str:
        return (f"StationaryTransform({self.shape}, wavelet={self.wavelet!r}, levels={self.levels}, "
                f"dtype={self.dtype.name!r}, backend={self.backend!r})")

    # -- building blocks on (..., H, W) planes: what the Wiener stage composes -------------------
    def _outer(self, which: str, band: int) -> np.ndarray:
        key = (which, band)
        cached = self._cache.get(key)
        if cached is not None:
            return cached
        r, c, j = self.bands[band]
        rows, cols = getattr(self._rows, which), getattr(self._cols, which)
        # Each axis' factor rounded to the FFTs' precision first: one product in that precision.
        out = np.multiply.outer(rows[r][j].astype(self._complex), cols[c][j].astype(self._complex))
        if self._caching:
            self._cache[key] = out
        return out

    def analysis(self, band: int) -> np.ndarray:
        """(H, W // 2 + 1) transfer function of band ``band`` (an index into :attr:`bands`)."""
        return self._outer("analysis", band)

    def squared(self, band: int) -> np.ndarray:
        """Transfer function of the band's squared kernel: filtering variances with it is Eq. 10."""
        return self._outer("squared", band)

    def synthesis(self, band: int) -> np.ndarray:
        """Transfer function that takes the band back to the image (summed over bands: identity)."""
        return self._outer("synthesis", band)

    def diagonal(self, band: int) -> np.ndarray:
        """Transfer function of ``h_b(u) = s_b(u) K_b(-u)``, synthesis times reversed analysis kernel.

        Scaling band ``b``'s coefficients by a map ``f_b`` and synthesising is a linear map of
        the image whose diagonal (each pixel's weight on its own value) is ``f_b`` filtered
        with ``h_b``; summed over the bands with every ``f_b = 1`` it is 1 everywhere.
        """
        return self._outer("diagonal", band)

    def bounded(self, variance: FloatArray | None) -> FloatArray | None:
        """``variance``, capped where this transform's sums over the image would overflow its dtype.

        A float32 band's FFT sums its variances over the image: a pixel ~1e29 times noisier than
        the image is bright (at 4K) would make it Inf and spread NaN. A Wiener factor or a
        projection weight there is 0 with the cap as without it. float64: ``variance`` itself.
        """
        if variance is None or self.dtype != np.float32 or not variance.size:
            return variance
        cap = float(np.finfo(np.float32).max) / (64.0 * self.shape[0] * self.shape[1])
        return variance if variance.max() <= cap else np.minimum(variance, cap)

    def cap(self, planes: np.ndarray) -> None:
        """Cap variance ``planes`` in place where their sums over the image would overflow this
        transform's dtype (float32 or float64; Inf becomes the cap): :meth:`bounded` in a stage's own
        domain, after its weights."""
        np.minimum(planes, float(np.finfo(self.dtype).max) / (64.0 * self.shape[0] * self.shape[1]), out=planes)

    def spectrum(self, planes: FloatArray, *, out: np.ndarray | None = None) -> np.ndarray:
        """``rfft2`` of (..., H, W) planes in the transform's precision, into ``out`` if given."""
        a = np.asarray(planes, dtype=self.dtype)
        if self.backend == "scipy":
            spec = sfft.rfft2(a, workers=self.workers)
            if out is None:
                return spec
            out[...] = spec
            return out
        if out is None:
            out = np.empty(a.shape[:-1] + (a.shape[-1] // 2 + 1,), self._complex)
        # One plane per call: ducc0 vectorises across the transforms of a call, so a batch's
        # rounding would depend on its size; plane by plane, a channel's result is the same
        # whether it runs alone, with others or on another thread.
        for index in _plane_indices(a.shape[:-2]):
            ducc0.fft.r2c(a[index], axes=(0, 1), out=out[index], nthreads=self.workers)
        return out

    def planes(self, spectrum: np.ndarray, *, overwrite: bool = False, out: np.ndarray | None = None) -> FloatArray:
        """Inverse of :meth:`spectrum` (planes in the transform's precision, into ``out`` if given);
        ``overwrite`` may reuse ``spectrum``."""
        if self.backend == "scipy":
            image = sfft.irfft2(spectrum, s=self.shape, workers=self.workers, overwrite_x=overwrite)
            if out is None:
                return image
            out[...] = image
            return out
        if out is None:
            out = np.empty(spectrum.shape[:-2] + self.shape, self.dtype)
        for index in _plane_indices(spectrum.shape[:-2]):  # plane by plane, as in spectrum()
            # forward=False, inorm=2: the inverse of the forward transform (divided by H * W).
            ducc0.fft.c2r(spectrum[index], axes=(0, 1), lastsize=self.shape[1], forward=False, inorm=2,
                          out=out[index], nthreads=self.workers, allow_overwriting_input=overwrite)
        return out

    # -- the public transform on (H, W) or (H, W, C) images ------------------------------------
    def _channels_first(self, image: FloatArray, param: str) -> np.ndarray:
        a = np.asarray(image)
        if a.dtype.kind not in "fiu" or a.ndim not in (2, 3) or a.shape[:2] != self.shape:
            raise ValueError(f"{param}: expected a numeric array of shape {self.shape} or {self.shape + ('C',)}, "
                             f"got {a.dtype} {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"{param}: {int((~np.isfinite(a)).sum())} value(s) are NaN or Inf")
        return np.moveaxis(a, -1, 0) if a.ndim == 3 else a

    @staticmethod
    def _layout(bands: list, ndim: int) -> list:
        out = [np.moveaxis(b, 0, -1) if ndim == 3 else b for b in bands]
        return [out[0]] + [tuple(out[1 + 3 * i: 4 + 3 * i]) for i in range((len(out) - 1) // 3)]

    def forward(self, image: FloatArray) -> list:
        """Coefficients of an (H, W) or (H, W, C) image, in the layout of the module docstring."""
        spec = self.spectrum(self._channels_first(image, "image"))
        bands = [self.planes(spec * self.analysis(b)).astype(np.float64) for b in range(len(self.bands))]
        return self._layout(bands, np.ndim(image))

    def variance(self, variance_of_mean: FloatArray) -> list:
        """Exact variance of every coefficient: pixel variances filtered with each ``K_b^2``."""
        v = self._channels_first(variance_of_mean, "variance_of_mean")
        if (v < 0).any():
            raise ValueError(f"variance_of_mean: {int((v < 0).sum())} value(s) are negative")
        spec = self.spectrum(v)
        bands = [np.maximum(self.planes(spec * self.squared(b)), 0.0).astype(np.float64)
                 for b in range(len(self.bands))]  # max: FFT rounding around exact zeros
        return self._layout(bands, np.ndim(variance_of_mean))

    def inverse(self, coeffs: list) -> FloatArray:
        """The image from coefficients in :meth:`forward`'s layout (scalars stand for constant bands)."""
        if len(coeffs) != self.levels + 1:
            raise ValueError(f"coeffs: expected {self.levels + 1} entries (scale band and {self.levels} levels), "
                             f"got {len(coeffs)}")
        flat = [coeffs[0]] + [band for level in coeffs[1:] for band in level]
        full = self.shape + next((np.shape(b)[2:] for b in flat if np.ndim(b) == 3), ())
        total = None
        for b, band in enumerate(flat):
            a = np.broadcast_to(np.asarray(band, dtype=np.float64), full)
            part = self.spectrum(np.moveaxis(a, -1, 0) if len(full) == 3 else a) * self.synthesis(b)
            total = part if total is None else total + part
        out = self.planes(total).astype(np.float64)
        return np.moveaxis(out, 0, -1) if len(full) == 3 else out


@lru_cache(maxsize=16)
def stationary_transform(shape: Shape2D, wavelet: str = DEFAULT_WAVELET, levels: int | None = None,
                         dtype: str = "float64", workers: int = 1, backend: str = "ducc0") -> StationaryTransform:
    """A cached :class:`StationaryTransform` (its filter banks are built once per setting).

    Examples
    --------
    >>> from awr_denoise.stationary import stationary_transform
    >>> stationary_transform((64, 64), levels=3) is stationary_transform((64, 64), levels=3)
    True
    """
    return StationaryTransform(shape, wavelet=wavelet, levels=levels, dtype=dtype, workers=workers, backend=backend)


_FLOAT32_RANGE = 2.0**100
"""The largest magnitude a float32 stage takes: its FFTs sum up to ``H * W`` products of values."""


def precision_for(dtype: str, *values: FloatArray | float) -> str:
    """``dtype``, or ``"float64"`` where a float32 stage could not hold ``values``: a domain's offset
    or scale chosen so that the image or the relative stage's ``k`` exceeds float32's range gave
    NaN over the whole image (a review of the library's options). Variances are capped instead
    (:meth:`StationaryTransform.bounded`).

    Examples
    --------
    >>> from awr_denoise.stationary import precision_for
    >>> precision_for("float32", 0.5, 1e3), precision_for("float32", 1e39), precision_for("float64", 1e39)
    ('float32', 'float64', 'float64')
    """
    if dtype != "float32":
        return dtype
    largest = max((float(np.abs(v).max(initial=0.0)) for v in values), default=0.0)
    return dtype if largest < _FLOAT32_RANGE else "float64"
