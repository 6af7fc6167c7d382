"""Tiled reconstruction: one task per tile of a large frame, equal to the whole-frame result.

Stage 1 (the paper's thresholding) runs tile by tile: each task gets only its tile plus a halo
wide enough for the wavelet support at every level (:func:`halo_width`), and everything that
depends on the whole frame (the depth, the domain's scale, the fill of sample-less pixels, the
pooled variance of unknown pixels) is fixed before the tiles leave. The later stages (the
Wiener stages on the periodic frame, the guard, the image mean) are whole-frame operations and
run in the calling process on the assembled frame. So the result matches
:func:`~awr_denoise.reconstruct` to rounding (docs/distributed.md derives the halo and the
tolerance).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import functools
from collections.abc import Sequence
from concurrent.futures import Executor
from typing import Any

import numpy as np
import pywt

from .. import _checks
from .._typing import FloatArray, Shape2D
from ..buffers import SampleBuffer
from ..channels import channel_groups, luminance_weights
from ..domains import Domain, resolve_domain
from ..prepare import EstimatedBuffer, prepare
from ..reconstruct import (
    DEFAULT_DOMAIN,
    DEFAULT_PIXEL_CLAMP,
    DEFAULT_PRECISION,
    DEFAULT_STAGES,
    DEFAULT_WIENER_EXPONENTS,
    later_stages,
    reconstruct,
    resolve_settings,
)
from ..wavelets import WAVELET_NAMES, default_levels, max_levels
from .executors import dask_client, executor_or_threads, executor_width, submit, wait_first

__all__ = ["tile_grid", "halo_width", "reconstruct_tiled"]


def tile_grid(shape: Shape2D, tile: int | tuple[int, int]) -> list[tuple[slice, slice]]:
    """Row-major ``(rows, cols)`` slices that cover an (H, W) image with tiles of ``tile`` pixels.

    Parameters
    ----------
    shape
        (H, W) of the image.
    tile
        Tile side, or (height, width); the last row and column of tiles may be smaller.
    """
    tile = _checks.scalar(tile)
    if isinstance(tile, (int, np.integer)) and not isinstance(tile, (bool, np.bool_)):
        tile = (tile, tile)
    if isinstance(tile, (str, bytes)) or not hasattr(tile, "__len__") or getattr(tile, "ndim", 1) == 0 \
            or len(tile) != 2:
        raise TypeError(f"tile: expected a side in pixels or (height, width), got {_checks.described(tile)}")
    th, tw = (_checks.whole("tile", t, minimum=1) for t in tile)
    h, w = _checks.shape2d("shape", shape, minimum=0)
    return [(slice(r, min(r + th, h)), slice(c, min(c + tw, w)))
            for r in range(0, h, th) for c in range(0, w, tw)]


def halo_width(wavelet: str = "bior4.4", levels: int = 5) -> int:
    """Pixels of context a tile needs on each side for an exact wavelet reconstruction.

    A level-``k`` coefficient's equivalent analysis filter spans at most
    ``(F - 1)(2^k - 1) + 1`` pixels, ``F`` the longer of the wavelet's decomposition and
    reconstruction filters, and its synthesis filter as many around the same place, so an
    output pixel depends on input pixels at most ``(F - 1)(2^L - 1)`` away along each axis.
    Soft thresholding acts on each coefficient alone and adds no reach. The halo returned is
    the exact reach, computed once from the filters: for every coefficient of every band and
    level (away from the signal's ends), the farthest pair of an input pixel in its analysis
    support and an output pixel in its synthesis support. It equals the bound for orthogonal
    wavelets and is smaller where filters have zero taps (bior4.4: ``7 (2^L - 1)``, not
    ``9 (2^L - 1)``). docs/distributed.md has the derivation and the measured reach.

    Parameters
    ----------
    wavelet
        PyWavelets discrete wavelet.
    levels
        Decomposition depth.

    Examples
    --------
    >>> from awr_denoise.parallel import halo_width
    >>> halo_width("bior4.4", 5), halo_width("haar", 3), halo_width("db2", 2)
    (217, 7, 9)
    """
    levels = _checks.whole("levels", levels, minimum=1, maximum=_checks.MAX_LEVELS)
    if _checks.name("wavelet", wavelet) not in WAVELET_NAMES:
        raise ValueError(f"wavelet: {wavelet!r} is not a discrete wavelet PyWavelets knows")
    return _transform_reach(pywt.Wavelet(wavelet).name, levels)


def _support_ends(nonzero: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First and last True of every row, and whether the row has any."""
    first = np.argmax(nonzero, axis=1)
    last = nonzero.shape[1] - 1 - np.argmax(nonzero[:, ::-1], axis=1)
    return first, last, nonzero.any(axis=1)


@functools.lru_cache(maxsize=64)
def _transform_reach(wavelet: str, levels: int) -> int:
    """Exact reach of the ``levels``-deep transform of ``wavelet`` along one axis (see :func:`halo_width`)."""
    w = pywt.Wavelet(wavelet)
    bound = (max(w.dec_len, w.rec_len) - 1) * (2**levels - 1)
    n = 4 * bound + 2 ** (levels + 3)  # long enough for coefficients that never see an end
    reach = 0
    for k in range(1, levels + 1):
        # Row j of each band: the analysis filter of coefficient j (impulses through the DWT).
        analysis = pywt.wavedec(np.eye(n), w, mode="symmetric", level=k, axis=0)
        for band in (0, 1):  # the level-k approximation and detail, as one axis of a 2-D band
            rows = analysis[band]
            coeffs = [np.zeros((c.shape[0], rows.shape[0])) for c in analysis]
            coeffs[band] = np.eye(rows.shape[0])
            # Column j: the synthesis of a unit coefficient j.
            synthesis = pywt.waverec(coeffs, w, mode="symmetric", axis=0)[:n].T
            a_first, a_last, a_any = _support_ends(rows != 0)
            s_first, s_last, s_any = _support_ends(synthesis != 0)
            interior = a_any & s_any & (a_first >= bound) & (a_last <= n - 1 - bound)
            if interior.any():
                reach = max(reach, int(np.max(np.maximum(s_last - a_first, a_last - s_first)[interior])))
    return reach


def _window(core: slice, halo: int, align: int, length: int) -> slice:
    """``core`` grown by ``halo`` on both sides, its start moved down to a multiple of ``align``.

    The decimated transform is shift-variant: a window that starts on a multiple of ``2^L``
    puts its coefficients on the same grid as the whole image's.
    """
    start = max(0, core.start - halo)
    start -= start % align
    return slice(start, min(length, core.stop + halo))


def _reconstruct_window(count: np.ndarray, mean: FloatArray, variance: FloatArray, channels: tuple[str, ...],
                        core: tuple[slice, slice], options: dict[str, Any]) -> FloatArray:
    """Reconstruct one tile+halo window and return the tile's pixels (runs in a worker)."""
    window = EstimatedBuffer(count, mean, variance, channels, np.ones(count.shape, bool))  # the frame's, as they are
    return reconstruct(window, **options)[core]


_TILE_ATTEMPTS = 3
"""Times a tile is sent to a Dask cluster whose worker, holding the tile's scattered window, died: data scattered
by the client cannot be computed again, and one worker killed failed the whole reconstruction (a bare
CancelledError, or a closed connection of the scatter; an attack pass)."""


def _lost(future: cf.Future) -> bool:
    """Whether a tile's task ended because the cluster lost its data or connection, not by its own error (a worker
    of another awr-denoise, a ConnectionError too, is no loss to try again)."""
    if future.cancelled():
        return True
    error = future.exception()
    return isinstance(error, cf.CancelledError) or type(error).__name__ in ("FutureCancelledError", "CommClosedError")


def _scattered(client: Any, crops: list[Any]) -> list[Any]:
    """``client.scatter(crops)``, tried again when a worker it was sending to died (a closed connection)."""
    for _ in range(_TILE_ATTEMPTS - 1):
        with contextlib.suppress(OSError):
            return list(client.scatter(crops, hash=False))
    return list(client.scatter(crops, hash=False))


def reconstruct_tiled(buffer: SampleBuffer, *, tile: int | tuple[int, int] = 512, halo: int | None = None,
                      executor: Executor | None = None, c_s: float | None = None, wavelet: str = "bior4.4",
                      levels: int | None = None, domain: str | Domain = DEFAULT_DOMAIN, mode: str = "channels",
                      boundary: str = "symmetric", pixel_clamp: float | None = DEFAULT_PIXEL_CLAMP,
                      stages: int = DEFAULT_STAGES, wiener_exponents: Sequence[float] = DEFAULT_WIENER_EXPONENTS,
                      guard: bool | None = None, guard_window: int | None = None, guard_probes: int | None = None,
                      preserve_mean: bool | None = None, nonnegative: bool | None = None,
                      precision: str = DEFAULT_PRECISION) -> FloatArray:
    """Reconstruct a frame tile by tile; equals :func:`~awr_denoise.reconstruct` to rounding.

    Each task receives one tile with a halo of :func:`halo_width` pixels on every side (its
    start aligned to ``2^levels`` so the wavelet grid matches the whole frame's), runs stage 1
    on it, and returns the tile's pixels. Everything that depends on the whole frame is fixed
    before the tiles leave: the number of levels, the domain's ``scale`` (the frame's mean
    absolute pixel value, which :class:`~awr_denoise.Domain` would otherwise take per tile),
    the fill of sample-less pixels and the pooled variance of pixels whose variance is unknown.
    With ``stages > 1`` the Wiener stages, the guard and the finishing steps then run on the
    assembled frame in the calling process (they transform the whole, periodic frame).

    Parameters
    ----------
    buffer
        Per-pixel sample statistics of the whole frame.
    tile
        Tile side in pixels, or (height, width). Each task holds about
        ``(tile + 2 * halo)^2 * (8 + 16 * C)`` bytes of input.
    halo
        Context on each side of a tile; default :func:`halo_width` ``(wavelet, levels)``
        (one more with a robust domain, whose 3x3 median reads one pixel further), the
        smallest that is exact. A smaller halo trades accuracy near tile borders for less
        work.
    executor
        Runs the tiles; default a thread pool for this call.
    c_s, wavelet, levels, domain, mode, boundary, pixel_clamp, stages, wiener_exponents, guard, guard_window, \
guard_probes, preserve_mean, nonnegative, precision
        As in :func:`~awr_denoise.reconstruct`; ``levels`` defaults to the whole frame's
        :func:`~awr_denoise.wavelets.default_levels`.

    Returns
    -------
    numpy.ndarray
        (H, W, C) reconstructed image.

    Notes
    -----
    The body is one loop on purpose: windows are cut and submitted as earlier tasks finish,
    which keeps the cutting, the in-flight bookkeeping and the collection in one place.

    With the default halo, tile and whole-frame results of stage 1 differ only by
    floating-point rounding; the tests hold them to ``1e-12`` of the image's largest value
    (docs/distributed.md), and the whole result to the same with ``precision="float64"`` (to
    float32 rounding otherwise). Windows are cut only as earlier tasks finish (at most twice as
    many in flight as the executor has workers), so the caller holds the frame, three
    frame-sized working arrays and a few windows during stage 1, and the Wiener stages'
    frame-sized spectra after it. Tiles are shipped to Dask workers with ``Client.scatter`` so
    they do not travel through the scheduler.
    """
    settings = resolve_settings(c_s=c_s, stages=stages, wiener_exponents=wiener_exponents, pixel_clamp=pixel_clamp,
                                guard=guard, preserve_mean=preserve_mean, nonnegative=nonnegative,
                                precision=precision, guard_window=guard_window, guard_probes=guard_probes)
    if not isinstance(buffer, SampleBuffer):
        raise TypeError(f"buffer: expected a SampleBuffer, got {type(buffer).__name__}")
    groups = channel_groups(buffer.channels)
    if groups is not None:  # R,G,B together, any other channel alone, as reconstruct does
        parts = [reconstruct_tiled(buffer.select(group), tile=tile, halo=halo, executor=executor, c_s=c_s,
                                   wavelet=wavelet, levels=levels, domain=domain, mode=mode, boundary=boundary,
                                   pixel_clamp=pixel_clamp, stages=stages, wiener_exponents=wiener_exponents,
                                   guard=guard, guard_window=guard_window, guard_probes=guard_probes,
                                   preserve_mean=preserve_mean, nonnegative=nonnegative, precision=precision)
                 for group in groups]
        return np.concatenate(parts, axis=2)[..., np.argsort([i for group in groups for i in group])]
    shape = buffer.shape
    levels = default_levels(shape) if levels is None else levels
    if isinstance(levels, bool) or not 1 <= int(levels) <= max_levels(shape):
        raise ValueError(f"levels: {levels} is outside 1..{max_levels(shape)} for an image of shape {shape}")
    levels = int(levels)
    if halo is None:
        # The robust domain's 3x3 median reads one pixel further than the transform does.
        halo = halo_width(wavelet, levels) + (1 if resolve_domain(domain).robust else 0)
    halo = _checks.whole("halo", halo, minimum=0)
    if halo < 0:
        raise ValueError(f"halo: must be >= 0, got {halo}")
    prepared = prepare(buffer, domain)  # fills, pools and fixes the domain's scale for the whole frame
    mean = prepared.mean
    options = {"c_s": settings.c_s, "wavelet": wavelet, "levels": levels, "domain": prepared.domain,
               "mode": mode, "boundary": boundary, "pixel_clamp": settings.stage1_clamp, "stages": 1,
               "precision": settings.precision}
    # Windows carry the frame's per-sample variance with unknown entries already pooled over the
    # whole frame, so every window pixel is "known". A pixel with fewer than two samples (whose
    # variance a window would pool again) travels as 2 samples of variance 2 s2: its variance
    # of the mean, s2 / max(n, 1), comes out the same (x2 and /2 are exact in floating point).
    few = buffer.count < 2
    count = np.where(few, 2, buffer.count)
    estimated = prepared.sample_variance
    per_sample = np.where(few[..., None], 2.0 * estimated, estimated)
    grid = tile_grid(shape, tile)
    image = np.empty(shape + (buffer.n_channels,))
    with executor_or_threads(executor, len(grid)) as pool:
        client = dask_client(pool)
        in_flight: dict[cf.Future, tuple[tuple[slice, slice], int]] = {}
        remaining = iter(grid)

        def submit_next() -> bool:
            """Cut the next tile's window and submit it; False when every tile is out."""
            tile_slices = next(remaining, None)
            if tile_slices is None:
                return False
            submit_tile(tile_slices, 0)
            return True

        def submit_tile(tile_slices: tuple[slice, slice], attempt: int) -> None:
            rows, cols = tile_slices
            wr = _window(rows, halo, 2**levels, shape[0])
            wc = _window(cols, halo, 2**levels, shape[1])
            if min(wr.stop - wr.start, wc.stop - wc.start) < 2**levels:
                wr, wc = slice(0, shape[0]), slice(0, shape[1])  # too small to decompose: use the frame
            core = (slice(rows.start - wr.start, rows.stop - wr.start),
                    slice(cols.start - wc.start, cols.stop - wc.start))
            crops: list[Any] = [np.ascontiguousarray(a[wr, wc]) for a in (count, mean, per_sample)]
            if client is not None:
                crops = _scattered(client, crops)
            in_flight[submit(pool, _reconstruct_window, *crops, buffer.channels, core, options)] = (tile_slices,
                                                                                                  attempt)

        # Windows are cut as tasks finish, so the driver holds at most a few of them at once.
        limit = 2 * executor_width(pool)
        while len(in_flight) < limit and submit_next():
            pass
        while in_flight:
            done = wait_first(pool, in_flight)
            for future in done:
                tile_slices, attempt = in_flight.pop(future)
                if client is not None and attempt < _TILE_ATTEMPTS - 1 and _lost(future):
                    submit_tile(tile_slices, attempt + 1)  # its scattered window went with a worker: again
                    continue
                image[tile_slices] = future.result()
                submit_next()
    luminance = None
    if mode == "luminance":
        luminance = (prepare(buffer, prepared.domain, luminance=True), luminance_weights(buffer.channels))
    return later_stages(prepared, image, None, settings, levels=levels, wavelet=wavelet, luminance=luminance)[0]
