"""A light's rim: pixels whose samples are a coverage of two exact regions (``awr_denoise.rims``)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from awr_denoise import SampleBuffer
from awr_denoise.rims import EDGE_REGION, EDGE_TOLERANCE, coverage_edges


def rims_by_definition(count, mean, variance, known, window=5, jump_ratio=4.0):
    """The coverage edges written out pixel by pixel: spread entries whose population variance is the Bhatia-Davis
    bound of the least and greatest agreeing levels of their window (cut at the image's edges), each level held by
    EDGE_REGION agreeing pixels there, the two further apart than ``jump_ratio``."""
    h, w, channels = mean.shape
    r = window // 2
    found = np.zeros(mean.shape, bool)
    for i in range(h):
        for j in range(w):
            for c in range(channels):
                if not known[i, j] or count[i, j] < 2 or variance[i, j, c] <= 0:
                    continue
                levels = [mean[y, x, c] for y in range(max(i - r, 0), min(i + r + 1, h))
                          for x in range(max(j - r, 0), min(j + r + 1, w)) if known[y, x] and variance[y, x, c] == 0]
                if not levels:
                    continue
                lo, hi, m, n = min(levels), max(levels), mean[i, j, c], count[i, j]
                ratio = jump_ratio
                if not lo < m < hi or (lo > 0 and hi <= ratio * lo) or (hi < 0 and -lo <= -ratio * hi):
                    continue
                bound = (m - lo) * (hi - m)
                found[i, j, c] = (abs(variance[i, j, c] * (n - 1) / n - bound) <= EDGE_TOLERANCE * (hi - lo) ** 2
                                 and levels.count(lo) >= EDGE_REGION and levels.count(hi) >= EDGE_REGION)
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


def test_the_tolerance_and_the_region_are_what_the_module_says():
    assert EDGE_TOLERANCE == 1e-5 and EDGE_REGION == 2
