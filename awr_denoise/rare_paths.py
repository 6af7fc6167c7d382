"""Regions lit through rare paths, where the samplers spread their samples evenly (an extension of paper section 4).

Where most of a region's samples are exactly 0 and its light comes from the few that are not (a room lit by
the bounce off a small patch, fog around a spot light, the dark contact shadow under an object), a pixel's first
samples do not show its variance: ranked by them, the pixels whose early samples found a bright path take more
samples and are diluted back towards their mean, while those whose samples missed keep their low means. AWR
sampling's image mean came out 4-22% low on such scenes at 8-32 spp (docs/sampling.md, "Rare paths"). No
spatial pooling of the ranking took it off without costing the other scenes (the same section). In such a region
any unevenness of the samples is noise chased, not structure found, so the samplers give its pixels one density,
the mean of theirs (:func:`even_rare_paths`): their counts then depend on no pixel's own samples and the image
mean is kept. The rest of the image is ranked as before.

A pixel lies in such a region (:func:`rare_path_mask`) when, over the window of ``WINDOW`` x ``WINDOW`` blocks of
``BLOCK`` x ``BLOCK`` pixels around its block (20 pixels, aligned to the blocks),

- the per-sample variance pooled within pixels, over the squared mean pooled over their samples (zeros
  included), exceeds :data:`RARE_CV2` (for samples that are 0 or a value ``v``, ``(1 - p) / p`` with ``p`` the
  chance of ``v``: a chance below 1 in 17); steady pixels (:data:`STEADY`) are left out of both, so that a
  bright steady feature, a beam through the fog, does not hide the region around it; and
- the pixels' mean of ``min(CV2_i / min(n_i, OWN_COUNT), 1)`` exceeds :data:`RARE_SHARE`: a pixel's own squared
  coefficient of variation reaches its count ``n_i`` when one sample holds all of its mean, so most pixels hold
  about one hit (a pixel whose samples are all 0 counts 1). A small light seen directly fails this test: its
  pixels hit often.

Both are taken over the pixels that are lit or beside a lit one; a pixel of zeros inside an all-zero square of
:data:`BACKDROP` pixels (a black backdrop beside an object's silhouette) is left out, so that a backdrop's edge
is not read as a region of rare hits. A window holding a negative mean is never a region (signed data has no
rare paths; its means near 0 are not rare hits').

Rare bright samples on a lit base (fireflies: a caustic path now and then on a lit wall) fail the second test:
most pixels have seen none and look steady. Ranked, the few that did take the samples and are diluted back, while
the rest keep means without the fireflies' share: the synthetic ``fireflies`` scene, whose fireflies carry 40% of
its light, came out 32% dark at 8 spp (docs/sampling.md, "Fireflies on a lit base"). Over a larger window
(``HEAVY_WINDOW`` blocks, 36 pixels, nothing counted past the image's edges) of the pixels that are lit and hold two
samples or more, a pixel holds a hit when one sample holds most of its mean (``min(CV2_i / min(n_i, OWN_COUNT), 1)``
at least :data:`HIT`) and its hit's level, ``E[X^2] / E[X] = mean + s^2 / mean`` (a sample's value weighted by its
share of the mean: the hit's own value, whatever the count), is above :data:`HEAVY_RATIO` times the steady level
beside it: the most that a pixel within the 3 x 3 blocks around its block reaches with its mean less two standard
deviations. The hits come from nothing steady beside them; the rim of a small light or a bright object hits at the
level of its steady inside and is not taken. The window is such a region when

- it holds at least :data:`HEAVY_HITS` separate hits (groups of touching pixels with a hit: a field of them, not a
  small disc; a window cut by the image's edges, its share of them, at least all but one);
- those pixels hold more than :data:`HEAVY_LIGHT` of its light (the pixels' means, what ranking could take off the
  image mean) and more than :data:`HEAVY_SHARE` of its per-sample variance (summed over pixels, each pixel once
  however many samples the ranking gave it); and
- at most :data:`HEAVY_DARK` of its pixels are all 0 and none is negative: the base is lit (zeros are the first
  tests' to judge; the misses around a thin bright wire on black, or beside a region of rare hits, are no lit
  base).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from concurrent import futures
from concurrent.futures import Executor, ThreadPoolExecutor
from functools import partial

import numpy as np
from scipy import ndimage

from . import _checks
from ._typing import BoolArray, FloatArray
from ._window_sums import window_sum
from .buffers import SampleBuffer
from .channels import luminance_weights

__all__ = ["rare_path_mask", "even_rare_paths", "rare_path_evening", "RARE_PATHS", "DEFAULT_RARE_PATHS", "RARE_CV2",
           "RARE_SHARE", "BLOCK", "WINDOW", "BACKDROP", "OWN_COUNT", "STEADY", "HIT", "HEAVY_WINDOW", "HEAVY_RATIO",
           "HEAVY_HITS", "HEAVY_LIGHT", "HEAVY_SHARE", "HEAVY_DARK"]

RARE_PATHS = ("even", "zeros", "ranked")
"""The samplers' ``rare_paths``: ``"even"`` (the default) spreads the samples of both kinds of region evenly,
``"zeros"`` only those of regions whose samples are mostly 0 (fireflies on a lit base ranked: lower error there and
their share of the light lost), ``"ranked"`` ranks every pixel (lower error, an image mean several % low)."""
DEFAULT_RARE_PATHS = "even"
"""The samplers' default ``rare_paths`` (docs/sampling.md, "Rare paths")."""
RARE_CV2 = 16.0
"""Least pooled per-sample squared coefficient of variation of a rare-path region (a hit chance below 1/17)."""
RARE_SHARE = 0.5
"""Least mean of ``min(CV2_i / n_i, 1)`` over a rare-path region's pixels: most of them hold about one hit."""
BLOCK = 4
"""Side of the blocks the window statistics are summed over (pixels)."""
WINDOW = 5
"""Side of the window of blocks around a pixel's block (20 pixels)."""
BACKDROP = 15
"""Side of the all-zero squares whose pixels of zeros are a backdrop, not a rare-path region's misses (hits 1 in 40
at 2 spp leave such a square in about one 10^5)."""
OWN_COUNT = 8
"""Most samples a pixel's squared coefficient of variation is divided by (:data:`RARE_SHARE`): past 8 samples a
pixel of rare hits keeps counting as one (its ``CV2_i`` near ``1 / p``), so a region stays found as samples grow."""
STEADY = 0.1
"""Pixels whose ``min(CV2_i / min(n_i, OWN_COUNT), 1)`` is below this are steady and left out of the pooled
variation (their level would dilute it: a beam through fog)."""
HIT = 0.5
"""Least ``min(CV2_i / min(n_i, OWN_COUNT), 1)`` of a pixel holding a hit on a lit base: one sample holds most of its
mean, or, past OWN_COUNT samples, a few do (a pixel the ranking gave hundreds of samples may hold several hits)."""
HEAVY_SHARE = 0.8
"""Least share of a window's per-sample variance (summed over its pixels, each once) that its pixels with a hit
hold, for a region of rare hits on a lit base."""
HEAVY_LIGHT = 0.1
"""Least share of a window's light (its pixels' means) that its pixels with a hit hold, for a region of rare hits on
a lit base: what ranking them can take off its image mean."""
HEAVY_DARK = 0.02
"""Largest share of a window's pixels whose samples are all 0 in a region of rare hits on a lit base."""
HEAVY_WINDOW = 9
"""Side of the window of blocks (36 pixels) of a region of rare hits on a lit base."""
HEAVY_HITS = 4
"""Fewest separate hits (groups of touching pixels with a hit) in the window of a region of rare hits on a lit base:
a field of them, not a small disc of rare light."""
HEAVY_RATIO = 8.0
"""Least ratio of a hit's level (``E[X^2] / E[X]``) to the steady level beside it, for a region of rare hits on a lit
base (the ``fireflies`` scene's stand over a hundred times above it, a light's rim about once; docs/sampling.md,
"Fireflies on a lit base")."""


def rare_path_mask(buffer: SampleBuffer, *, fireflies: bool = True) -> BoolArray:
    """(H, W) pixels of regions lit through rare paths (see the module's description).

    Parameters
    ----------
    buffer
        The merged statistics of the image so far.
    fireflies
        Whether the regions of rare hits on a lit base are found too (``False``: only those whose samples are
        mostly 0, ``rare_paths="zeros"``).

    Returns
    -------
    BoolArray
        ``True`` at the pixels of the regions found.

    Examples
    --------
    Samples that are 40 one time in 40 and 0 otherwise, beside a region of steady noise (4 spp):

    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.rare_paths import rare_path_mask
    >>> rng = np.random.default_rng(0)
    >>> hits = rng.binomial(4, 1 / 40, size=(64, 64)).astype(float)
    >>> mean = hits * 40 / 4
    >>> variance = (hits * (40 - mean) ** 2 + (4 - hits) * mean**2) / 3
    >>> mean[:, 32:], variance[:, 32:] = 1.0, 0.25
    >>> mask = rare_path_mask(SampleBuffer.from_moments(np.full((64, 64), 4), mean[..., None], variance[..., None]))
    >>> float(mask[:, :24].mean()), float(mask[:, 40:].mean())
    (1.0, 0.0)

    Fireflies on a lit base: one sample in 250 is 100, the others between 0.5 and 1.5 (4 spp):

    >>> samples = np.where(rng.random((4, 96, 96)) < 1 / 250, 100.0, rng.uniform(0.5, 1.5, (4, 96, 96)))
    >>> buffer = SampleBuffer.from_moments(np.full((96, 96), 4), samples.mean(0)[..., None],
    ...                                    samples.var(0, ddof=1)[..., None])
    >>> round(float(rare_path_mask(buffer).mean()), 2), float(rare_path_mask(buffer, fireflies=False).mean())
    (1.0, 0.0)
    """
    count = np.asarray(buffer.count, dtype=np.float64)
    weights = luminance_weights(buffer.channels)
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        mean = np.asarray(buffer.mean) @ weights
        # Fully correlated channels, as the samplers' luminance variance (channels.luminance_variance); an unknown
        # variance is stored as 0 (SampleBuffer) and counts no degrees of freedom below.
        deviation = np.sqrt(np.asarray(buffer.variance)) @ weights
    # In units of a power of two near the largest level, exactly (the tests are ratios): no square under- or
    # overflows for levels anywhere in float64's range.
    top = max(float(np.max(mean, initial=0.0)), -float(np.min(mean, initial=0.0)),
              float(np.max(deviation, initial=0.0)))
    if not (np.isfinite(top) and top > 0):
        return np.zeros(count.shape, dtype=bool)
    unit = float(np.ldexp(1.0, int(np.frexp(top)[1]) - 1))  # at most top: finite
    mean, deviation = mean / unit, deviation / unit
    with np.errstate(under="ignore"):  # a deviation 1e-154 of the largest level squares to 0, which is its weight
        sample_var = np.square(deviation)
    lit = mean > 0
    # Pixels of zeros in an all-zero BACKDROP square: a pixel whose square holds no lit pixel, grown back to it.
    backdrop = _dilated(~_dilated(lit, BACKDROP), BACKDROP)
    near = _dilated(lit, 3)
    region = (lit | (near & ~backdrop)) & (count >= 2)
    if not region.any():
        return np.zeros(count.shape, dtype=bool)
    # A pixel's squared coefficient of variation over its count (capped at OWN_COUNT): 1 where one sample holds its
    # mean; a pixel of zeros counts 1. (Squared as a ratio: a lit mean far below the largest level would square to
    # 0; the quotient is finite or +inf, which the cap takes to 1.)
    own = np.ones(count.shape)
    with np.errstate(over="ignore", divide="ignore", under="ignore"):
        np.divide(deviation, mean, out=own, where=lit)
        np.square(own, out=own, where=lit)
        np.divide(own, np.minimum(count, OWN_COUNT), out=own, where=lit)
    np.minimum(own, 1.0, out=own)
    heavy = (_heavy_tails(lit & (count >= 2), own, count, mean, deviation, np.asarray(buffer.variance_known))
             if fireflies else False)
    # Steady pixels (a beam, a lit wall beside the fog) are left out of the pooled variation, which their level
    # would otherwise dilute: the region around them is judged by its own samples.
    varied = region & (own >= STEADY)
    dof = np.where(varied & np.asarray(buffer.variance_known), count - 1.0, 0.0)
    n = np.where(varied, count, 0.0)
    own[~region] = 0.0
    # The six sums in one call (stacked on a last axis: each entry's additions are the same, and one call's overhead
    # replaces six, most of the search's time on small images).
    sums = np.stack([_blocks(x) for x in (n, n * mean, dof, dof * sample_var)] + [_count(region).astype(np.float64),
                                                                                   _blocks(own)], axis=-1)
    n_sum, nm_sum, dof_sum, var_sum, pixels, own_sum = np.moveaxis(_window(sums), -1, 0)
    negative = mean < 0  # any pixel's, in the region or not
    negative = _window(_blocks(negative)) if negative.any() else np.zeros_like(pixels)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        pooled_mean = nm_sum / n_sum
        cv2 = (var_sum / dof_sum) / (pooled_mean * pooled_mean)
        share = own_sum / pixels
        # Signed data (no radiance) has no rare paths to find: a mean near 0 is not a rare hit's.
        rare = (cv2 > RARE_CV2) & (share > RARE_SHARE) & np.isfinite(cv2) & (pooled_mean > 0)
        rare = (rare | heavy) & (negative == 0)
    h, w = count.shape
    # Every pixel of a block so found: a pixel of zeros in it is a miss of the region's rare paths like the others.
    return np.repeat(np.repeat(rare, BLOCK, axis=0), BLOCK, axis=1)[:h, :w]


def _heavy_tails(base: BoolArray, own: FloatArray, count: FloatArray, mean: FloatArray, deviation: FloatArray,
                 known: BoolArray) -> BoolArray:
    """(blocks) windows of rare hits on a lit base over the ``base`` pixels (lit, two samples or more), from the
    pixels' ``own`` variation, counts, means and per-sample standard deviations in the unit of
    :func:`rare_path_mask`."""
    blocks = (-(-count.shape[0] // BLOCK), -(-count.shape[1] // BLOCK))
    candidate = base & known & (own >= HIT)  # one sample holds most of the mean; its level decides below
    if not candidate.any():
        return np.zeros(blocks, dtype=bool)
    # Pixels whose samples are all 0 (a backdrop, or misses of rare paths the first tests judge): not a lit base;
    # and signed data has no rare paths (a negative mean anywhere in the window). Judged first: a frame of zeros
    # (the first tests' regions) has no window to look at further.
    # (Counts: their window sums are exact in any order, so they are taken from running sums. A mask with no pixel
    # is not summed.)
    dark, negative = (mean == 0) & (count >= 2), mean < 0
    lit_pixels = _counts_around(_count(base))
    dark_pixels = _counts_around(_count(dark)) if dark.any() else 0.0
    lit_base = (dark_pixels <= HEAVY_DARK * (lit_pixels + dark_pixels)) & (lit_pixels > 0)
    if negative.any():
        lit_base &= _counts_around(_count(negative)) == 0
    if not lit_base.any():
        return lit_base
    with np.errstate(over="ignore", divide="ignore", invalid="ignore", under="ignore"):
        # What a pixel's samples steadily reach: its mean less two standard deviations. The inside of a light or a
        # lit wall keeps most of its mean; a pixel whose mean a hit or two make (fewer than half its samples) has
        # none. (A pixel whose 2 samples were both fireflies counts as steady, and hides the hits beside it only.)
        floor = mean - 2.0 * deviation
        floor[~(base & known)] = 0.0  # an unknown variance (stored as 0) shows no steadiness
        np.maximum(floor, 0.0, out=floor)
        # The steady level beside each block (3 x 3 blocks): a light's rim lies beside its inside, and a bright steady
        # patch hides no hits further away.
        top = ndimage.maximum_filter(_blocks(floor, np.max), size=3, mode="nearest")
        # E[X^2] / E[X]: a sample's value weighted by its share of the mean, a hit's value for one hit among
        # steady samples whatever the count (the mean is above 0: lit).
        rows, cols = np.nonzero(candidate)
        level = mean[rows, cols] + deviation[rows, cols] ** 2 / mean[rows, cols]
        above = level > HEAVY_RATIO * top[rows // BLOCK, cols // BLOCK]
        rows, cols = rows[above], cols[above]
        at = (rows // BLOCK) * blocks[1] + cols // BLOCK
        # Separate hits, not pixels with one: a field of fireflies scatters them, a small disc of rare light is one
        # group of touching pixels, counted once (in the block of its first pixel) wherever it lies on the blocks.
        hit = np.zeros(count.shape, dtype=bool)
        hit[rows, cols] = True
        labels = ndimage.label(hit, structure=np.ones((3, 3), dtype=bool))[0]
        first = np.unique(labels[rows, cols], return_index=True)[1]
        hits = _counts_around(np.bincount(at[first], minlength=blocks[0] * blocks[1]).reshape(blocks))
        # A window cut by the image's edges needs its share of the groups, and never fewer than all but one.
        pixels = _counts_around(np.outer(_block_sides(count.shape[0]), _block_sides(count.shape[1])))
        lit_base &= hits >= np.maximum(HEAVY_HITS * pixels / float((HEAVY_WINDOW * BLOCK) ** 2), HEAVY_HITS - 1)
        if not lit_base.any():  # the shares below are summed only when some window holds enough hits
            return lit_base
        # Per pixel, not per sample: the image mean weighs each pixel alike, and a pixel the ranking gave hundreds
        # of samples must not weigh more for them.
        light = np.where(base, mean, 0.0)
        spread = np.where(base & known, deviation * deviation, 0.0)
        hit_light, hit_spread = (np.bincount(at, weights=weights, minlength=blocks[0] * blocks[1]).reshape(blocks)
                                 for weights in (light[rows, cols], spread[rows, cols]))
        light_sum, hit_light_sum, var_sum, hit_var_sum = np.moveaxis(_zero_padded_window(np.stack(
            [_blocks(light), hit_light, _blocks(spread), hit_spread], axis=-1)), -1, 0)
        return lit_base & (hit_light_sum > HEAVY_LIGHT * light_sum) & (hit_var_sum > HEAVY_SHARE * var_sum)


def _dilated(mask: BoolArray, size: int) -> BoolArray:
    """Whether any pixel of ``mask`` lies in the ``size`` x ``size`` square (odd ``size``) around each pixel, the square
    cut by the image's edges (scipy's ``maximum_filter`` with ``mode="nearest"``): shifted copies or-ed, a window's
    span doubling each time, in place of scipy's loop over the window's entries."""
    r = size // 2
    out = np.pad(mask, r)  # False past the edges: the square cut there
    for axis in (0, 1):
        span = 1  # out[i] holds the pixels i .. i + span - 1 along the axis
        while span < size:
            step = min(span, size - span)
            ahead = [slice(None)] * 2
            ahead[axis] = slice(step, None)
            behind = [slice(None)] * 2
            behind[axis] = slice(None, -step)
            out[tuple(behind)] |= out[tuple(ahead)]
            span += step
    return out[:mask.shape[0], :mask.shape[1]]


def _counts_around(blocks: np.ndarray) -> FloatArray:
    """:func:`_zero_padded_window` of whole numbers (below 2**53): the same sums, exact in any order, from running
    sums (four lookups a window instead of its entries)."""
    r, size = HEAVY_WINDOW // 2, HEAVY_WINDOW
    run = np.pad(np.asarray(blocks, dtype=np.int64), ((r + 1, r), (r + 1, r))).cumsum(axis=0).cumsum(axis=1)
    return (run[size:, size:] - run[:-size, size:] - run[size:, :-size] + run[:-size, :-size]).astype(np.float64)


def _block_sides(length: int) -> np.ndarray:
    """The pixels each block along an axis of ``length`` pixels holds (BLOCK, the last one fewer)."""
    return np.minimum(BLOCK, length - BLOCK * np.arange(-(-length // BLOCK)))


def _zero_padded_window(blocks: FloatArray) -> FloatArray:
    """Sums over the HEAVY_WINDOW x HEAVY_WINDOW blocks around each block (first two axes; any others stacked sums),
    nothing past the image's edges (a hit in an edge block is counted once, not once for every copy of it)."""
    r = HEAVY_WINDOW // 2
    return window_sum(np.pad(blocks, ((r, r), (r, r)) + ((0, 0),) * (blocks.ndim - 2)), HEAVY_WINDOW)[r:-r, r:-r]


def even_rare_paths(density: FloatArray, buffer: SampleBuffer, rare_paths: str = DEFAULT_RARE_PATHS) -> FloatArray:
    """``density`` (float64) with each connected region of :func:`rare_path_mask` given the mean of its pixels'.

    ``rare_paths="ranked"`` returns it as it is, ``"zeros"`` evens only the regions whose samples are mostly 0
    (``rare_path_mask(buffer, fireflies=False)``). A region's summed density stays what it was, so the allocation
    still gives it its statistics' share of the samples; only their spread over its pixels is made even (the
    water-filling cannot take samples back from a pixel that has more than the region's level already). A pixel
    whose density is not finite keeps it and is left out of its region's mean.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.rare_paths import even_rare_paths, rare_path_mask
    >>> rng = np.random.default_rng(0)
    >>> hits = rng.binomial(4, 1 / 40, size=(64, 64)).astype(float)
    >>> mean = hits * 10.0
    >>> variance = (hits * (40 - mean) ** 2 + (4 - hits) * mean**2) / 3
    >>> buffer = SampleBuffer.from_moments(np.full((64, 64), 4), mean[..., None], variance[..., None])
    >>> density = rng.uniform(0, 2, size=(64, 64))
    >>> evened, mask = even_rare_paths(density, buffer), rare_path_mask(buffer)
    >>> round(float(mask.mean()), 2), np.unique(evened[mask]).size, bool(np.isclose(evened.sum(), density.sum()))
    (1.0, 1, True)
    """
    with rare_path_evening(buffer, rare_paths) as even:
        return even(density)


@contextlib.contextmanager
def rare_path_evening(buffer: SampleBuffer, rare_paths: str = DEFAULT_RARE_PATHS, executor: Executor | None = None
                      ) -> Iterator[Callable[[FloatArray], FloatArray]]:
    """:func:`even_rare_paths` for a density still to be computed: the regions are looked for beside it.

    The samplers' ranking (step 3 of paper section 4) evens these regions every round. The search reads only the
    buffer, as the density's own work does, so on a thread of its own most of its time is hidden behind the
    density's: at 1080p it adds 5-27% to ``ask()`` on two threads where it adds 17-37% on one core
    (docs/sampling.md, "Rare paths"). On exit, the body's error or not, the search is waited for: the buffer is not
    the caller's to change while a thread still reads it.

    Parameters
    ----------
    buffer
        The merged statistics the density is computed from.
    rare_paths
        As for :func:`even_rare_paths` (``"ranked"``: no search, the density as it is).
    executor
        A thread pool the search starts on at entry; ``None`` (or called from one of the pool's own threads): it
        runs in this thread when the density is evened.

    Yields
    ------
    Callable
        ``even(density)``: the density with the regions found evened, as :func:`even_rare_paths` gives it, the same
        bits.

    Examples
    --------
    >>> from concurrent.futures import ThreadPoolExecutor
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.rare_paths import even_rare_paths, rare_path_evening
    >>> rng = np.random.default_rng(0)
    >>> samples = np.where(rng.random((4, 64, 64)) < 1 / 40, 40.0, 0.0)   # 4 spp, most of them 0
    >>> buffer = SampleBuffer.from_moments(np.full((64, 64), 4), samples.mean(0)[..., None],
    ...                                    samples.var(0, ddof=1)[..., None])
    >>> with ThreadPoolExecutor(2) as pool, rare_path_evening(buffer, executor=pool) as even:
    ...     density = rng.uniform(0, 2, size=(64, 64))     # the density's own work, beside the search
    ...     evened = even(density)
    >>> bool((evened != density).any()), bool(np.array_equal(evened, even_rare_paths(density, buffer)))
    (True, True)
    """
    if not isinstance(buffer, SampleBuffer):  # named here, not as an attribute missing on another thread
        raise TypeError(f"buffer: expected a SampleBuffer, got {type(buffer).__name__}")
    rare_paths = _checks.name("rare_paths", rare_paths, RARE_PATHS)
    executor = _checks.executor("executor", executor)
    search = partial(rare_path_mask, buffer, fireflies=rare_paths == "even")
    found = None if executor is None or rare_paths == "ranked" else executor.submit(search)

    def even(density: FloatArray) -> FloatArray:
        density = np.asarray(density, dtype=np.float64)
        if density.shape != buffer.shape:
            raise ValueError(f"density: shape {density.shape} is not the buffer's {buffer.shape}")
        if rare_paths == "ranked":
            return density
        return _evened(density, _checks.outcome(found, search, executor))

    try:
        yield even
    finally:
        # A thread pool's search not started is dropped; one started, or another executor's, is waited for.
        if found is not None and not (isinstance(executor, ThreadPoolExecutor) and found.cancel()):
            futures.wait([found])


def _evened(density: FloatArray, mask: BoolArray) -> FloatArray:
    """``density`` with each connected region of ``mask`` given the mean of its pixels' (:func:`even_rare_paths`)."""
    if not mask.any():
        return density
    finite = mask & np.isfinite(density)
    labels, regions = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    # Summed in units of the largest density (a power of two, exact): sums of densities near 1e308 stay finite.
    unit = float(np.ldexp(1.0, int(np.frexp(np.max(np.abs(density[finite]), initial=1.0))[1]) - 1))
    # Over the regions' finite pixels alone, in raster order: the additions of ndimage.sum over the whole image less
    # its zeros (the same sums), at a small share of its time where the regions are a small share of the image.
    at = labels[finite]
    sums = np.bincount(at, weights=density[finite] / unit, minlength=regions + 1)[1:]
    counts = np.bincount(at, minlength=regions + 1)[1:].astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / counts * unit
    out = density.copy()
    out[finite] = means[at - 1]
    return out


def _blocks(a: FloatArray | BoolArray, reduce: Callable[..., np.ndarray] = np.sum) -> FloatArray:
    """Sums (or another ``reduce``) over the BLOCK x BLOCK blocks of ``a`` (its last blocks padded with zeros), in
    float64."""
    a = np.asarray(a, dtype=np.float64)
    h, w = a.shape
    if h % BLOCK or w % BLOCK:
        padded = np.zeros((-(-h // BLOCK) * BLOCK, -(-w // BLOCK) * BLOCK))
        padded[:h, :w] = a
        a, h, w = padded, *padded.shape
    # Rows of blocks first, then their columns: two reductions over contiguous runs.
    rows = reduce(a.reshape(h // BLOCK, BLOCK, w), axis=1)
    return reduce(rows.reshape(h // BLOCK, w // BLOCK, BLOCK), axis=2)


def _count(mask: BoolArray) -> np.ndarray:
    """The number of ``mask``'s pixels in each BLOCK x BLOCK block (integers), summed as bytes (a float64 copy of
    the mask costs more than the sums)."""
    h, w = mask.shape
    padded = np.zeros((-(-h // BLOCK) * BLOCK, -(-w // BLOCK) * BLOCK), dtype=np.uint8)
    padded[:h, :w] = mask
    rows = padded.reshape(padded.shape[0] // BLOCK, BLOCK, padded.shape[1]).sum(axis=1, dtype=np.int32)
    return rows.reshape(rows.shape[0], padded.shape[1] // BLOCK, BLOCK).sum(axis=2)


def _window(blocks: FloatArray) -> FloatArray:
    """Sums over the WINDOW x WINDOW blocks around each block (first two axes; any others stacked sums; edges
    repeated; each window's own entries, so that a firefly's rounding error does not run along the line as in a
    running sum)."""
    return window_sum(blocks, WINDOW)
