"""A light's rim: pixels whose samples are a coverage of two exact regions (``awr_denoise.rims``)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from awr_denoise import SampleBuffer
from awr_denoise.rims import EDGE_BLOCK, EDGE_TOLERANCE, coverage_edges


def _in_a_block(mean, agreed, y, x, c):
    """Whether entry (y, x, c) agreed and lies in an EDGE_BLOCK square of entries that agreed at its level."""
    h, w = agreed.shape[:2]
    k = EDGE_BLOCK
    for top in range(y - k + 1, y + 1):
        for left in range(x - k + 1, x + 1):
            if top < 0 or left < 0 or top + k > h or left + k > w:
                continue
            if all(agreed[a, b, c] and mean[a, b, c] == mean[y, x, c]
                   for a in range(top, top + k) for b in range(left, left + k)):
                return True
    return False


def rims_by_definition(count, mean, variance, known, window=5, jump_ratio=4.0):
    """The coverage edges written out pixel by pixel: spread entries whose samples all lie at the least and greatest
    levels of the exact regions (EDGE_BLOCK squares of agreeing entries) that reach into their window (cut at the
    image's edges), the two further apart than ``jump_ratio``: their population variance at the Bhatia-Davis bound
    and their samples at ``hi`` a whole number, in units of the gap."""
    h, w, channels = mean.shape
    r = window // 2
    agreed = (variance == 0) & (np.asarray(known) & (np.asarray(count) >= 2))[..., None]
    found = np.zeros(mean.shape, bool)
    for i in range(h):
        for j in range(w):
            for c in range(channels):
                if not known[i, j] or count[i, j] < 2 or variance[i, j, c] <= 0:
                    continue
                levels = [mean[y, x, c] for y in range(max(i - r, 0), min(i + r + 1, h))
                          for x in range(max(j - r, 0), min(j + r + 1, w)) if _in_a_block(mean, agreed, y, x, c)]
                if not levels:
                    continue
                lo, hi, m, n = min(levels), max(levels), mean[i, j, c], count[i, j]
                if not lo < m < hi or (lo > 0 and hi <= jump_ratio * lo) or (hi < 0 and -lo <= -jump_ratio * hi):
                    continue
                gap = hi - lo
                below, above = (m - lo) / gap, (hi - m) / gap
                hits = n * below
                found[i, j, c] = (abs(variance[i, j, c] / gap / gap * (n - 1) / n - below * above) <= EDGE_TOLERANCE
                                  and abs(hits - round(hits)) <= EDGE_TOLERANCE * n and 0.5 < hits < n - 0.5)
    return found


def _edges(buf: SampleBuffer, **kwargs) -> np.ndarray:
    known = buf.variance_known[..., None]
    got = coverage_edges(buf.count, buf.mean, buf.variance, known & (buf.variance == 0),
                         known & (buf.variance > 0), window=5, jump_ratio=4.0, **kwargs)
    return np.zeros(buf.mean.shape, bool) if got is None else got


def _lights(rng: np.random.Generator, spp: int, shape=(20, 23), levels=(0.0, 100.0, 7.0), noisy=0.1) -> SampleBuffer:
    """Discs at ``levels[1:]`` on an exact ``levels[0]``, each sample at a uniform point of its pixel (rims hit or
    miss), and a share ``noisy`` of the pixels given noise of their own in every sample (no coverage)."""
    h, w = shape
    pixel = np.repeat(np.arange(h * w), spp)
    y, x = pixel // w + rng.random(pixel.size), pixel % w + rng.random(pixel.size)
    values = np.full(pixel.size, levels[0])
    for level in levels[1:]:
        cy, cx, radius = rng.uniform(3, h - 3), rng.uniform(3, w - 3), rng.uniform(1.5, 4.0)
        values = np.where((y - cy) ** 2 + (x - cx) ** 2 < radius**2, level, values)
    values = values + (rng.random(h * w) < noisy)[pixel] * rng.random(pixel.size)
    return SampleBuffer.from_samples(pixel, np.stack([values, values * 0.5, values * 0.0], axis=1), shape)


@pytest.mark.parametrize("spp", [2, 4, 16])
@pytest.mark.parametrize("seed", range(4))
def test_matches_the_pixel_by_pixel_definition(spp, seed):
    """Lights on an exact background, some samples noisy: every channel (one of them all 0: no rim there)."""
    buf = _lights(np.random.default_rng(seed), spp)
    want = rims_by_definition(buf.count, buf.mean, buf.variance, buf.variance_known)
    assert want[..., 0].sum() >= 5
    assert_array_equal(_edges(buf), want)
    assert not want[..., 2].any()


def test_a_light_s_rim_is_found_in_float32_files_too():
    """Means and variances stored as float32 (an EXR dump) still put the rim on the bound within the tolerance."""
    buf = _lights(np.random.default_rng(7), 4, noisy=0.0)
    stored = SampleBuffer.from_moments(buf.count, buf.mean.astype(np.float32), buf.variance.astype(np.float32))
    assert _edges(buf)[..., 0].sum() >= 5
    assert_array_equal(_edges(stored), _edges(buf))


def test_noise_between_the_levels_and_close_levels_make_no_rim():
    """Every sample noisy (no pixel reaches the bound), or two levels within the jump ratio (texels side by side)."""
    rng = np.random.default_rng(3)
    assert not _edges(_lights(rng, 4, noisy=1.0)).any()
    assert not _edges(_lights(rng, 4, levels=(1.0, 3.0), noisy=0.0)).any()
    assert _edges(_lights(rng, 4, levels=(1.0, 5.0), noisy=0.0)).any()


def test_one_level_or_none_is_looked_at_no_further():
    """A black background alone (every agreeing pixel at one level), or nothing agreed: None, nothing to do."""
    buf = _lights(np.random.default_rng(0), 4, levels=(0.0,), noisy=0.3)
    assert coverage_edges(buf.count, buf.mean, buf.variance, buf.variance == 0, buf.variance > 0, window=5,
                          jump_ratio=4.0) is None
    nothing = np.zeros(buf.mean.shape, bool)
    assert coverage_edges(buf.count, buf.mean, buf.variance, nothing, buf.variance > 0, window=5,
                          jump_ratio=4.0) is None



def test_chance_agreement_makes_no_region():
    """Samples that hit half the time at 2 spp: a quarter of the pixels agree at the hit, a quarter at 0, by chance;
    two such pixels in a window made a region before, and nearly every mixed pixel a rim (the agreeing ones then
    kept their chance level, 15x the MSE of the form before). Only a square of them makes a region now."""
    rng = np.random.default_rng(5)
    shape, spp = (64, 64), 2
    pixel = np.repeat(np.arange(shape[0] * shape[1]), spp)
    values = (rng.random(pixel.size) < 0.5) * 0.6
    buf = SampleBuffer.from_samples(pixel, values[:, None], shape)
    spread = buf.variance_known[..., None] & (buf.variance > 0)
    assert _edges(buf).sum() < 0.05 * spread.sum()


@pytest.mark.parametrize("mean, variance, rim", [(0.001, 0.05, False), (25.0, 2500.0, True), (25.0, 2000.0, False),
                                                 (20.0, 2133.3333333333335, False)])
def test_samples_must_be_whole_numbers_at_the_two_levels(mean, variance, rim):
    """Beside regions at 0 and 100, 4 samples: a mean of 0.001 cannot be whole samples at 0 and 100 (the bound alone,
    absolute, let it through), nor can 20 with 2133.3 (the bound of 20 and 80, four samples)."""
    count = np.full((4, 6), 4)
    mean_ = np.zeros((4, 6, 1))
    mean_[:, 3:] = 100.0
    var = np.zeros_like(mean_)
    mean_[1, 2], var[1, 2] = mean, variance
    got = coverage_edges(count, mean_, var, var == 0, var > 0, window=5, jump_ratio=4.0)
    assert (got is not None and bool(got[1, 2, 0])) == rim


def test_levels_past_float64s_square_are_told_apart():
    """Regions at 0 and 2e154, whose gap squared passes float64: a pixel of modest noise between them is no rim (the
    tolerance was Inf there), and one whose samples are whole at both (one of four at 2e154) still is."""
    count = np.full((4, 6), 4)
    mean = np.zeros((4, 6, 1))
    mean[:, 3:] = 2e154
    variance = np.zeros_like(mean)
    mean[1, 2], variance[1, 2] = 3.0, 1.0
    mean[2, 2], variance[2, 2] = 0.5e154, 0.25 * 2e154 * 2e154  # (m - lo)(hi - m) 4 / 3 = gap^2 / 4
    got = coverage_edges(count, mean, variance, variance == 0, variance > 0, window=5, jump_ratio=4.0)
    assert not got[1, 2, 0] and got[2, 2, 0]
