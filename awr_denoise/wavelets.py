"""Wavelet transforms of pixel-mean images and exact propagation of their variance.

The transform is PyWavelets' separable 2-D DWT (``pywt.wavedec2``), coefficient layout
``[cA_L, (cH_L, cV_L, cD_L), ..., (cH_1, cV_1, cD_1)]``. In the paper's notation (paper
section 2; docs/reconstruction.md, "What it computes") ``cA`` are the scale coefficients
``S = <B, Phi>`` and the three detail bands the wavelet coefficients ``W^a = <B, Psi^a>``.

Pixel means are independent, so a coefficient ``C = sum_p K(p) B_p`` has variance
``<v, K^2>`` (Eq. 10 squared). Squared filters do not cascade across levels, so the level-k
*equivalent* 1-D analysis operator of each axis is built exactly (impulses pushed through
PyWavelets' own DWT with the same boundary mode, kept as a sparse matrix), squared entrywise and
applied separably: ``Var(C_k) = K_rows^2 v (K_cols^2)^T``. This is exact for any linear wavelet,
orthogonal or not, any boundary mode and any image size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pywt
from scipy import sparse

from . import _checks
from ._typing import FloatArray, Shape2D

__all__ = [
    "default_levels",
    "max_levels",
    "WaveletOperators",
    "wavelet_operators",
    "forward",
    "inverse",
    "coefficient_variance",
    "shrinkage_diagonal",
    "DETAIL_BANDS",
    "DEFAULT_WAVELET",
    "WAVELET_NAMES",
]

DEFAULT_WAVELET = "bior4.4"
"""CDF 9/7 (JPEG 2000's irreversible wavelet), the default basis everywhere (docs/reconstruction.md)."""

WAVELET_NAMES = tuple(pywt.wavelist(kind="discrete"))
"""Every wavelet the transforms accept: PyWavelets' discrete wavelets."""

DETAIL_BANDS = ("cH", "cV", "cD")
"""PyWavelets' detail bands: ``cH`` high-pass down the rows, ``cV`` across the columns, ``cD`` both."""

_MAX_DEFAULT_LEVELS = 5
_OPERATOR_CHUNK = 256  # impulses pushed through the DWT at once when building an operator


def max_levels(shape: Shape2D) -> int:
    """Deepest decomposition worth running on an image of this shape (at least 1).

    Each level halves the shorter side; beyond ``log2(min(H, W))`` nothing is left to halve.

    Examples
    --------
    >>> from awr_denoise.wavelets import max_levels
    >>> max_levels((480, 640)), max_levels((1, 5))
    (8, 1)
    """
    shortest = max(1, min(_checks.shape2d("shape", shape, minimum=0)))
    return max(1, int(math.floor(math.log2(shortest))))


def default_levels(shape: Shape2D) -> int:
    """Number of levels used when none is given: ``min(5, floor(log2(min(H, W))) - 3)``, >= 1.

    Five levels follow the talk's figures (section 2); the ``- 3`` keeps the coarsest scale
    band at least about 8 pixels on a side so it still holds an image, not a few boundary
    coefficients.

    Examples
    --------
    >>> from awr_denoise.wavelets import default_levels
    >>> default_levels((480, 640)), default_levels((64, 64)), default_levels((16, 16))
    (5, 3, 1)
    """
    shortest = max(1, min(_checks.shape2d("shape", shape, minimum=0)))
    return max(1, min(_MAX_DEFAULT_LEVELS, int(math.floor(math.log2(shortest))) - 3))


def _check_levels(levels: int | None, shape: Shape2D) -> int:
    levels = _checks.scalar(levels)
    if levels is None:
        return default_levels(shape)
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)):
        raise TypeError(f"levels: expected an integer, got {_checks.described(levels)}")
    top = max_levels(shape)
    if not 1 <= int(levels) <= top:
        raise ValueError(f"levels: {levels} is outside 1..{top} for an image of shape {tuple(shape)}")
    return int(levels)


def _check_wavelet(wavelet: str) -> pywt.Wavelet:
    _checks.name("wavelet", wavelet)
    try:
        return pywt.Wavelet(wavelet)
    except (ValueError, TypeError):
        raise ValueError(f"wavelet: {wavelet!r} is not a discrete wavelet PyWavelets knows "
                         f"(for example 'bior4.4', 'haar', 'db2')") from None


def _check_boundary(boundary: str, shape: tuple[int, ...]) -> str:
    if not isinstance(boundary, str) or boundary not in pywt.Modes.modes:
        raise ValueError(f"boundary: {boundary!r} is not one of {', '.join(sorted(pywt.Modes.modes))}")
    if boundary in ("reflect", "antireflect") and min(shape[:2]) < 2:  # else PyWavelets' words, naming no option
        raise ValueError(f"boundary: {boundary!r} needs 2 pixels or more on each side; the image is {shape[:2]}")
    return boundary


def _sparse_operator(apply, n_in: int, step: tuple[int, int], edge: int) -> sparse.csr_matrix:
    """Matrix of the linear map ``apply`` (acting along axis 0 of (n_in, m) arrays), sparse.

    Away from the ends the map is shift-invariant: moving an impulse by ``step[0]`` inputs moves
    its response by ``step[1]`` outputs (a DWT step: 2 and 1; a band's synthesis: 1 and 2^k).
    Only the columns within ``edge`` of either end, where the boundary mode acts, and one
    template column per input phase are computed by ``apply``; every other column is its
    template shifted. That builds the matrix in O(n_in), not O(n_in^2) (a 65536-sample side in a
    fraction of a second instead of minutes). Random probes check the result against ``apply``;
    where they disagree (a map not shift-invariant that far in) every column is computed.
    """
    step_in, step_out = step
    direct = np.r_[0:edge + step_in, n_in - edge:n_in] if n_in > 2 * (edge + step_in) else np.arange(n_in)
    if len(direct) == n_in:
        return _computed_columns(apply, n_in, direct)
    computed = _computed_columns(apply, n_in, direct).tocsc()
    n_out = computed.shape[0]
    rows, cols, vals = [computed.indices], [np.repeat(np.arange(n_in), np.diff(computed.indptr))], [computed.data]
    for phase in range(step_in):
        template = edge + phase
        start, stop = computed.indptr[template], computed.indptr[template + 1]
        t_rows, t_vals = computed.indices[start:stop], computed.data[start:stop]
        columns = np.arange(template + step_in, n_in - edge, step_in)
        shifts = (columns - template) // step_in * step_out
        rows.append((t_rows[None, :] + shifts[:, None]).ravel())
        cols.append(np.repeat(columns, len(t_rows)))
        vals.append(np.tile(t_vals, len(columns)))
    rows_all = np.concatenate(rows)
    if rows_all.size and (rows_all.min() < 0 or rows_all.max() >= n_out):
        return _computed_columns(apply, n_in, np.arange(n_in))
    matrix = sparse.csr_matrix((np.concatenate(vals), (rows_all, np.concatenate(cols))), shape=(n_out, n_in))
    probes = np.random.default_rng(0).standard_normal((n_in, 2))
    expected = apply(probes)
    if not np.allclose(matrix @ probes, expected, rtol=1e-9, atol=1e-12 * max(1.0, float(np.abs(expected).max()))):
        return _computed_columns(apply, n_in, np.arange(n_in))
    return matrix


def _edge(w: pywt.Wavelet) -> int:
    """Samples (or coefficients) from either end within reach of the boundary extension: the
    columns :func:`_sparse_operator` computes rather than shifts (a margin over the filter length)."""
    return 2 * w.dec_len + 4


def _computed_columns(apply, n_in: int, columns: np.ndarray) -> sparse.csr_matrix:
    """The matrix of ``apply`` with only ``columns`` filled (impulses pushed through it, in chunks)."""
    blocks = []
    for start in range(0, len(columns), _OPERATOR_CHUNK):
        chunk = columns[start:start + _OPERATOR_CHUNK]
        impulses = np.zeros((n_in, len(chunk)))
        impulses[chunk, np.arange(len(chunk))] = 1.0
        block = sparse.coo_matrix(apply(impulses))
        blocks.append(sparse.csr_matrix((block.data, (block.row, chunk[block.col])), shape=(block.shape[0], n_in)))
    return sum(blocks[1:], blocks[0]).tocsr() if len(blocks) > 1 else blocks[0]


@dataclass(frozen=True)
class _AxisOperators:
    """Level-k equivalent analysis operators of one axis (k = 1..L): approx and detail."""

    approx: tuple[sparse.csr_matrix, ...]
    detail: tuple[sparse.csr_matrix, ...]
    approx_sq: tuple[sparse.csr_matrix, ...]
    detail_sq: tuple[sparse.csr_matrix, ...]
    approx_sq32: tuple[sparse.csr_matrix, ...]  # the squared operators in float32, for float32 planes
    detail_sq32: tuple[sparse.csr_matrix, ...]

    def squared(self, dtype: np.dtype) -> tuple[tuple[sparse.csr_matrix, ...], tuple[sparse.csr_matrix, ...]]:
        """``(approx_sq, detail_sq)`` in ``dtype`` (float32 or float64)."""
        if np.dtype(dtype) == np.float32:
            return self.approx_sq32, self.detail_sq32
        return self.approx_sq, self.detail_sq


@lru_cache(maxsize=32)
def _axis_operators(n: int, wavelet: str, boundary: str, levels: int) -> _AxisOperators:
    w = pywt.Wavelet(wavelet)
    approx, detail = [], []
    previous = sparse.identity(n, format="csr")
    length = n
    for _ in range(levels):
        lo = _sparse_operator(lambda x: pywt.dwt(x, w, mode=boundary, axis=0)[0], length, (2, 1), _edge(w))
        hi = _sparse_operator(lambda x: pywt.dwt(x, w, mode=boundary, axis=0)[1], length, (2, 1), _edge(w))
        detail.append((hi @ previous).tocsr())
        previous = (lo @ previous).tocsr()
        approx.append(previous)
        length = previous.shape[0]
    approx_sq = tuple(m.multiply(m).tocsr() for m in approx)
    detail_sq = tuple(m.multiply(m).tocsr() for m in detail)
    single = lambda ms: tuple(m.astype(np.float32) for m in ms)  # noqa: E731
    return _AxisOperators(tuple(approx), tuple(detail), approx_sq, detail_sq, single(approx_sq), single(detail_sq))


@dataclass(frozen=True)
class WaveletOperators:
    """The exact equivalent operators for an (H, W) image: rows (axis 0) and columns (axis 1).

    ``rows.approx[k-1]`` maps a column of H pixels to the level-k scale coefficients; squared
    entrywise (``approx_sq``) it maps pixel variances to coefficient variances.

    Examples
    --------
    For Haar, a level-2 scale coefficient weighs four pixels of an axis by 1/2 each:

    >>> import numpy as np
    >>> from awr_denoise.wavelets import wavelet_operators
    >>> ops = wavelet_operators((16, 16), wavelet="haar", levels=2)
    >>> ops.rows.approx[0].shape, ops.rows.approx[1].shape, ops.rows.detail[1].shape
    ((8, 16), (4, 16), (4, 16))
    >>> ops.rows.approx[1].toarray()[0, :6]
    array([0.5, 0.5, 0.5, 0.5, 0. , 0. ])
    >>> np.round(ops.rows.approx_sq[1] @ np.ones(16), 6)    # unit variances stay 1 (orthonormal)
    array([1., 1., 1., 1.])
    """

    shape: Shape2D
    wavelet: str
    boundary: str
    levels: int
    rows: _AxisOperators
    cols: _AxisOperators


def wavelet_operators(shape: Shape2D, *, wavelet: str = DEFAULT_WAVELET, levels: int | None = None,
                      boundary: str = "symmetric") -> WaveletOperators:
    """Build (and cache) the per-axis level-k equivalent analysis operators.

    Parameters
    ----------
    shape
        (H, W) of the image.
    wavelet, levels, boundary
        As in :func:`forward`.

    Examples
    --------
    >>> from awr_denoise.wavelets import wavelet_operators
    >>> ops = wavelet_operators((32, 48))
    >>> ops.wavelet, ops.levels, ops.rows.approx[-1].shape, ops.cols.approx[-1].shape
    ('bior4.4', 2, (14, 32), (18, 48))
    >>> wavelet_operators((32, 48)).rows is ops.rows        # built once per axis and settings
    True
    """
    _check_wavelet(wavelet)
    h, w = _checks.shape2d("shape", shape)
    _check_boundary(boundary, (h, w))
    lv = _check_levels(levels, (h, w))
    return WaveletOperators((h, w), wavelet, boundary, lv,
                            _axis_operators(h, wavelet, boundary, lv),
                            _axis_operators(w, wavelet, boundary, lv))


def forward(image: FloatArray, *, wavelet: str = DEFAULT_WAVELET, levels: int | None = None,
            boundary: str = "symmetric") -> list:
    """2-D DWT of an (H, W) or (H, W, C) image over its first two axes.

    Parameters
    ----------
    image
        Pixel means (the paper's ``B~``).
    wavelet
        A PyWavelets discrete wavelet; default ``"bior4.4"`` is CDF 9/7, JPEG 2000's
        irreversible wavelet.
    levels
        Decomposition depth; default :func:`default_levels`.
    boundary
        PyWavelets signal extension mode; default ``"symmetric"``.

    Returns
    -------
    list
        ``[cA_L, (cH_L, cV_L, cD_L), ..., (cH_1, cV_1, cD_1)]``.

    Examples
    --------
    A constant image has all its energy in the scale band (orthonormal Haar: a factor 2 per
    level) and no detail:

    >>> import numpy as np
    >>> from awr_denoise.wavelets import forward
    >>> coeffs = forward(np.ones((16, 16)), wavelet="haar", levels=2)
    >>> coeffs[0].shape, [band.shape for band in coeffs[1]], [band.shape for band in coeffs[2]]
    ((4, 4), [(4, 4), (4, 4), (4, 4)], [(8, 8), (8, 8), (8, 8)])
    >>> round(float(coeffs[0][0, 0]), 6), max(float(np.abs(band).max()) for band in coeffs[1] + coeffs[2])
    (4.0, 0.0)
    """
    _check_wavelet(wavelet)
    image = np.asarray(image)
    if image.dtype.kind not in "fiu":
        raise TypeError(f"image: expected a numeric array, got dtype {image.dtype}")
    if image.ndim not in (2, 3):
        raise ValueError(f"image: expected shape (H, W) or (H, W, C), got {image.shape}")
    _check_boundary(boundary, image.shape)
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise ValueError(f"image: {bad} value(s) are NaN or Inf")
    return _forward(image, wavelet, _check_levels(levels, image.shape[:2]), boundary)


def _forward(image: FloatArray, wavelet: str, levels: int, boundary: str) -> list:
    """:func:`forward` without the checks: ``pywt.wavedec2``'s loop of ``dwt2`` (the same floats) without its warning
    for levels past pywt's "useful" depth (harmless here), whose filter, process-wide, raced on executor threads."""
    details = []
    for _ in range(levels):
        image, detail = pywt.dwt2(image, wavelet, mode=boundary, axes=(0, 1))
        details.append(detail)
    return [image, *reversed(details)]


def inverse(coeffs: list, shape: Shape2D, *, wavelet: str = DEFAULT_WAVELET, boundary: str = "symmetric") -> FloatArray:
    """Inverse of :func:`forward`, cropped to the original (H, W).

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.wavelets import forward, inverse
    >>> image = np.random.default_rng(0).random((13, 17, 3))     # any size, any channels
    >>> restored = inverse(forward(image), image.shape[:2])
    >>> restored.shape, bool(np.allclose(restored, image))
    ((13, 17, 3), True)
    """
    shape = _checks.shape2d("shape", shape)
    out = pywt.waverec2(coeffs, wavelet, mode=boundary, axes=(0, 1))
    return out[: shape[0], : shape[1]]


def _plane_variance(v: FloatArray, ops: WaveletOperators, *, scales: list | None = None) -> list:
    """Coefficient variances of one (H, W) plane; see :func:`coefficient_variance`.

    Computed in ``v``'s precision (float32 or float64). With ``scales`` (a list), the variance
    of the scale coefficients of every level ``k = 1..L`` is appended to it: the same products,
    so the priorities of :mod:`awr_denoise.priorities` need no second pass.
    """
    rows_approx, rows_detail = ops.rows.squared(v.dtype)
    cols_approx, cols_detail = ops.cols.squared(v.dtype)
    v_t = np.ascontiguousarray(v.T)  # columns first: every column pass is then one sparse product
    details = []
    approx = None
    for k in range(ops.levels):
        low_t = cols_approx[k] @ v_t      # (m_k, H): squared low-pass along the columns
        high_t = cols_detail[k] @ v_t
        # The row passes need C-ordered operands: transposed once here, not in every product.
        low, high = np.ascontiguousarray(low_t.T), np.ascontiguousarray(high_t.T)
        details.append((rows_detail[k] @ low,    # cH: high-pass down the rows
                        rows_approx[k] @ high,   # cV: high-pass across the columns
                        rows_detail[k] @ high))  # cD
        if scales is not None or k == ops.levels - 1:
            approx = rows_approx[k] @ low
            if scales is not None:
                scales.append(approx)
    return [approx] + details[::-1]


def coefficient_variance(variance_of_mean: FloatArray, *, wavelet: str = DEFAULT_WAVELET,
                         levels: int | None = None, boundary: str = "symmetric",
                         operators: WaveletOperators | None = None, precision: str = "float64") -> list:
    """Exact variance of every wavelet coefficient of the pixel-mean image.

    ``Var(C) = <v, K^2>`` with ``K`` the coefficient's equivalent 2-D analysis filter
    (Eq. 10 of the paper without the square root), computed separably with the squared level-k
    equivalent operators of each axis.

    Parameters
    ----------
    variance_of_mean
        (H, W) or (H, W, C) variance of each pixel mean, ``v_p = s2_p / n_p``.
    wavelet, levels, boundary
        As in :func:`forward`.
    operators
        Prebuilt :func:`wavelet_operators` for this shape (they are cached anyway).
    precision
        ``"float64"`` (the reference) or ``"float32"``: the precision of the products (float32
        halves the memory traffic; its relative error is a few float32 epsilons; variances beyond its
        range are refused).

    Returns
    -------
    list
        Same layout as :func:`forward`: ``[Var(cA_L), (Var(cH_L), Var(cV_L), Var(cD_L)), ...]``.

    Examples
    --------
    One noisy pixel (variance 1) among exact ones: each level-1 Haar coefficient weighs it
    by ``+-1/2``, so its coefficients have variance ``1/4`` and the others none:

    >>> import numpy as np
    >>> from awr_denoise.wavelets import coefficient_variance
    >>> v = np.zeros((8, 8))
    >>> v[0, 0] = 1.0
    >>> var = coefficient_variance(v, wavelet="haar", levels=1)
    >>> var[0][:2, :2], var[1][2][:2, :2]
    (array([[0.25, 0.  ],
           [0.  , 0.  ]]), array([[0.25, 0.  ],
           [0.  , 0.  ]]))

    CDF 9/7 is not orthonormal: unit pixel variances give coefficient variances other than 1,
    which is why they are propagated exactly rather than assumed:

    >>> var = coefficient_variance(np.ones((32, 32)), levels=2)
    >>> [round(float(band[8, 8]), 4) for band in var[1]]
    [1.1117, 1.1117, 1.2513]
    >>> single = coefficient_variance(np.ones((32, 32)), levels=2, precision="float32")
    >>> single[1][2].dtype, bool(np.allclose(single[1][2], var[1][2], rtol=1e-6))
    (dtype('float32'), True)
    """
    v = np.asarray(variance_of_mean)
    if v.dtype.kind not in "fiu":
        raise TypeError(f"variance_of_mean: expected a numeric array, got dtype {v.dtype}")
    if precision not in ("float32", "float64"):
        raise ValueError(f"precision: {precision!r} is not one of float32, float64")
    if not (np.isfinite(v) & (v >= 0)).all():
        raise ValueError(f"variance_of_mean: {int((~(np.isfinite(v) & (v >= 0))).sum())} value(s) are NaN, Inf "
                         "or negative")
    # Checked before the cast: past float32's range a variance became Inf (refused as "NaN, Inf") and below its
    # normal numbers 0, an exact pixel (a red-team pass); a margin of 1024 below the top for the sums.
    low, high = float(np.finfo(np.float32).tiny), float(np.finfo(np.float32).max) / 1024
    if precision == "float32" and v.size and (v.max() > high or np.min(v, initial=np.inf, where=v > 0) < low):
        raise ValueError(f"variance_of_mean: values beyond float32's range ({low:.3g} to {high:.3g} here) from "
                         f"{np.min(v, initial=np.inf, where=v > 0):.3g} to {v.max():.3g}; use precision='float64'")
    v = v.astype(np.dtype(precision))
    ops = operators or wavelet_operators(v.shape[:2], wavelet=wavelet, levels=levels, boundary=boundary)
    if ops.shape != v.shape[:2]:
        raise ValueError(f"operators: built for shape {ops.shape}, variance has {v.shape[:2]}")
    if v.ndim == 2:
        return _plane_variance(v, ops)
    planes = [_plane_variance(v[:, :, c], ops) for c in range(v.shape[2])]
    stack = lambda arrays: np.stack(arrays, axis=-1)  # noqa: E731
    out = [stack([p[0] for p in planes])]
    for level in range(1, len(planes[0])):
        out.append(tuple(stack([p[level][b] for p in planes]) for b in range(3)))
    return out


@lru_cache(maxsize=16)
def _axis_diagonals(n: int, wavelet: str, boundary: str, levels: int,
                    dtype: str = "float64") -> tuple[tuple[sparse.csr_matrix, ...], tuple[sparse.csr_matrix, ...]]:
    """Per level k = 1..L, the (n, m_k) matrices ``S_k * A_k^T`` (entrywise) of one axis, approx and detail.

    ``A_k`` is the level-k equivalent analysis operator, ``S_k`` the synthesis operator that takes
    that band back to the n samples (impulses pushed through PyWavelets' own ``waverec`` of a
    level-k decomposition, cropped to n as :func:`inverse` crops). Entry ``(i, a)`` is coefficient
    a's weight on sample i times sample i's weight on coefficient a: its share of the map's
    diagonal at i. ``dtype`` ``"float32"``: the same matrices rounded to float32.
    """
    if dtype != "float64":
        approx, detail = _axis_diagonals(n, wavelet, boundary, levels)
        return tuple(m.astype(dtype) for m in approx), tuple(m.astype(dtype) for m in detail)
    ops = _axis_operators(n, wavelet, boundary, levels)
    w = pywt.Wavelet(wavelet)

    def synthesis(k: int, position: int) -> sparse.csr_matrix:
        # A level-k decomposition is [cA_k, cD_k, ..., cD_1]: the first k steps of the level-L one.
        sizes = [n]
        for _ in range(k):
            sizes.append(pywt.dwt_coeff_len(sizes[-1], w.dec_len, boundary))
        lengths = [sizes[-1], *sizes[:0:-1]]

        def apply(impulses: np.ndarray) -> np.ndarray:
            coeffs = [np.zeros((m, impulses.shape[1])) for m in lengths]
            coeffs[position] = impulses
            return pywt.waverec(coeffs, w, mode=boundary, axis=0)[:n]
        # A level-k coefficient one place on moves its response 2^k samples on.
        return _sparse_operator(apply, lengths[position], (1, 2 ** k), _edge(w))

    approx = tuple(synthesis(k, 0).multiply(ops.approx[k - 1].T).tocsr() for k in range(1, levels + 1))
    detail = tuple(synthesis(k, 1).multiply(ops.detail[k - 1].T).tocsr() for k in range(1, levels + 1))
    return approx, detail


def _along_columns(matrix: sparse.csr_matrix, band: FloatArray) -> FloatArray:
    """``band @ matrix.T`` for a C-ordered (m_h, m_w) band and an (W, m_w) sparse matrix, C-ordered."""
    return np.ascontiguousarray((matrix @ np.ascontiguousarray(band.T)).T)


def shrinkage_diagonal(factors: list, operators: WaveletOperators, *, precision: str = "float64") -> FloatArray:
    """Diagonal of the linear map ``y -> inverse(f * forward(y))``: each pixel's weight on its own value.

    With every detail coefficient scaled by its factor (held fixed) and the scale band by its own,
    the map is ``sum_b S_b diag(f_b) A_b``, separable in each band, so its diagonal is
    ``sum_b P_rows,b f_b P_cols,b^T`` with ``P = S * A^T`` entrywise per axis (exact, no probes):
    the share of each pixel's noise that stays at that pixel after a shrinkage of the wavelet
    coefficients, as the paper's reconstruction (section 4, Eq. 11) or a Wiener stage makes it.

    Parameters
    ----------
    factors
        In :func:`forward`'s layout: ``[f_A, (f_H, f_V, f_D)_L, ..., (f_H, f_V, f_D)_1]``, each the
        shape of its band.
    operators
        :func:`wavelet_operators` of the image's shape.
    precision
        ``"float64"`` (the reference) or ``"float32"`` (half the memory traffic; factors in [0, 1]
        give a diagonal within a few float32 epsilons of the reference's, tested).

    Returns
    -------
    ndarray
        (H, W) diagonal ``L_p`` in ``precision``.

    Examples
    --------
    Keeping every coefficient is the identity (diagonal 1); keeping the scale band alone (two
    levels here) leaves each pixel a small share of its own value (a wide average):

    >>> import numpy as np
    >>> from awr_denoise.wavelets import forward, shrinkage_diagonal, wavelet_operators
    >>> ops = wavelet_operators((32, 32))
    >>> ones = [np.ones_like(c) if i == 0 else tuple(np.ones_like(b) for b in c)
    ...         for i, c in enumerate(forward(np.zeros((32, 32)), levels=ops.levels))]
    >>> bool(np.allclose(shrinkage_diagonal(ones, ops), 1.0))
    True
    >>> scale_only = [ones[0]] + [tuple(np.zeros_like(b) for b in c) for c in ones[1:]]
    >>> round(float(shrinkage_diagonal(scale_only, ops)[16, 16]), 3)
    0.146
    """
    if precision not in ("float32", "float64"):
        raise ValueError(f"precision: {precision!r} is not one of float32, float64")
    rows_approx, rows_detail = _axis_diagonals(operators.shape[0], operators.wavelet, operators.boundary,
                                               operators.levels, precision)
    cols_approx, cols_detail = _axis_diagonals(operators.shape[1], operators.wavelet, operators.boundary,
                                               operators.levels, precision)
    levels = operators.levels
    if len(factors) != levels + 1:
        raise ValueError(f"factors: expected {levels + 1} entries (the scale band and {levels} levels), "
                         f"got {len(factors)}")
    out = rows_approx[-1] @ _along_columns(cols_approx[-1], np.asarray(factors[0], dtype=precision))
    for k in range(1, levels + 1):
        f_h, f_v, f_d = (np.asarray(b, dtype=precision) for b in factors[levels - k + 1])
        # cH is high-pass down the rows and low-pass across the columns, cV the reverse, cD both
        # high-pass: grouped by their row operator, two full-size products per level.
        out += rows_detail[k - 1] @ (_along_columns(cols_approx[k - 1], f_h) + _along_columns(cols_detail[k - 1], f_d))
        out += rows_approx[k - 1] @ _along_columns(cols_detail[k - 1], f_v)
    return out
