"""Sums over square windows of an image, without the residues of a running sum.

``scipy.ndimage.uniform_filter`` keeps a running sum along each line (add the entry entering the window,
subtract the one leaving it). Past a value 1e8 times the others that sum carries the large value's rounding
error along the rest of the line: a pixel 25 columns away from a firefly pooled a variance of exactly 0, and the
guard's share came out 0.2 off far from one (a red-team pass, docs/robustness.md). Here every window's sum is made
of additions of the entries inside it only, so its error is relative to that window's own entries.
"""

from __future__ import annotations

import numpy as np

from ._typing import FloatArray

__all__ = ["window_sum", "neighbour_sum"]


def window_sum(a: FloatArray, size: int, *, mode: str = "edge", out: FloatArray | None = None) -> FloatArray:
    """Sum over the ``size`` x ``size`` square (odd ``size``) around each entry of the first two axes.

    Past the image's edges the entries are those of ``np.pad(..., mode=mode)`` (``"edge"``: scipy's ``"nearest"``;
    ``"reflect"``: scipy's ``"mirror"``; ``"wrap"``). ``out`` may be ``a`` itself.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise._window_sums import window_sum
    >>> a = np.zeros((1, 40)); a[0, 5] = 1e16; a[0, 30] = 1.0
    >>> float(window_sum(a, 5)[0, 30])          # a running sum gives 0 here: 1e16 passed by on the way
    5.0
    """
    r = size // 2
    down = _line_sums(a, r, 0, mode, centre=True)
    return _line_sums(down, r, 1, mode, centre=True, out=out)


def neighbour_sum(a: FloatArray, *, mode: str = "reflect") -> FloatArray:
    """Sum over each entry's 8 neighbours (its 3 x 3 square without it), edges as :func:`window_sum`'s.

    Added up from the neighbours, not the square's sum less the entry: a bright pixel's own value would leave
    its rounding error in its neighbours' sum.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise._window_sums import neighbour_sum
    >>> a = np.full((3, 3), 1.0); a[1, 1] = 1e20
    >>> float(neighbour_sum(a)[1, 1])
    8.0
    """
    column = _line_sums(a, 1, 0, mode, centre=True)  # each entry's column of three
    out = _line_sums(column, 1, 1, mode, centre=False)  # the columns beside it
    out += _line_sums(a, 1, 0, mode, centre=False)  # the entries above and below it
    return out


def _line_sums(a: FloatArray, r: int, axis: int, mode: str, *, centre: bool, out: FloatArray | None = None
               ) -> FloatArray:
    """Along ``axis``: each entry's ``r`` neighbours on either side summed (and the entry itself with ``centre``)."""
    n = a.shape[axis]
    # Where each padded position reads from: position i - r of the padded line is index[i].
    index = np.pad(np.arange(n), r, mode=mode)
    if out is None:
        dtype = np.result_type(a, 0.0)
        out = np.array(a, dtype=dtype) if centre else np.zeros(a.shape, dtype)
    elif centre:
        np.copyto(out, a)
    else:
        out[...] = 0

    def cut(x: np.ndarray, start: int | None, stop: int | None) -> np.ndarray:
        return x[(slice(None),) * axis + (slice(start, stop),)]

    with np.errstate(over="ignore", invalid="ignore"):  # sums past the dtype's range are Inf, as scipy's are
        for d in range(1, r + 1):
            m = min(d, n)  # the entries whose neighbour d away lies past an edge
            if d < n:  # neighbours inside the line: shifted slices
                cut(out, d, None)[...] += cut(a, None, n - d)
                cut(out, None, n - d)[...] += cut(a, d, None)
            cut(out, None, m)[...] += np.take(a, index[r - d:r - d + m], axis=axis)
            cut(out, n - m, None)[...] += np.take(a, index[r + n - m + d:r + n + d], axis=axis)
    return out
