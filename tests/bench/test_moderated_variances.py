"""``benchmarks/moderated_variances.py``: the moderation the benchmarks try is the formula its docstring states."""

from __future__ import annotations

import numpy as np
import pytest

from awr_denoise import SampleBuffer


@pytest.fixture(scope="module")
def mod(benchmark_script):
    return benchmark_script("moderated_variances")


def _direct(count, mean, variance, prior, window=5, ratio=2.0):
    """The formula pixel by pixel (edges repeated), the reference for the whole-image passes."""
    h, w, channels = mean.shape
    dof = np.maximum(count - 1, 0).astype(float)
    out = variance.copy()
    r = window // 2
    for i in range(h):
        for j in range(w):
            if dof[i, j] == 0:
                continue
            for c in range(channels):
                num = den = 0.0
                for y in range(i - r, i + r + 1):
                    for x in range(j - r, j + r + 1):
                        yy, xx = min(max(y, 0), h - 1), min(max(x, 0), w - 1)
                        a, b = abs(mean[yy, xx, c]), abs(mean[i, j, c])
                        if a <= ratio * b + 1e-300 and b <= ratio * a + 1e-300:
                            num += dof[yy, xx] * variance[yy, xx, c]
                            den += dof[yy, xx]
                local = num / den if den > 0 else variance[i, j, c]
                out[i, j, c] = (dof[i, j] * variance[i, j, c] + prior * local) / (dof[i, j] + prior)
    return out


def test_the_whole_image_passes_give_the_formula(mod):
    rng = np.random.default_rng(3)
    count = rng.integers(0, 6, (7, 9))
    mean = rng.lognormal(0, 1, (7, 9, 2))
    variance = rng.lognormal(0, 1, (7, 9, 2)) * (count[..., None] > 1)
    buffer = SampleBuffer.from_moments(count, mean, variance)
    for prior in (0.0, 2.0, 8.0):
        got = mod.moderated(buffer, prior).variance
        want = _direct(buffer.count, buffer.mean, buffer.variance, prior)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)


def test_a_light_lends_nothing_to_the_dark_beside_it(mod):
    count = np.full((6, 6), 4)
    mean = np.where(np.arange(6) < 3, 0.1, 50.0)[None, :, None] * np.ones((6, 6, 1))
    variance = np.where(np.arange(6) < 3, 0.01, 400.0)[None, :, None] * np.ones((6, 6, 1))
    out = mod.moderated(SampleBuffer.from_moments(count, mean, variance), 8.0).variance
    np.testing.assert_allclose(out[:, :3], 0.01, rtol=1e-12)
    np.testing.assert_allclose(out[:, 3:], 400.0, rtol=1e-12)


def test_each_variant_reconstructs_the_moderated_buffer(mod):
    from awr_denoise import reconstruct
    from awr_denoise.bench import noisy_buffer

    buffer = noisy_buffer((24, 24), smooth=1.0, noise=0.2)
    for name, run in mod.VARIANTS.items():
        prior = float(name.rsplit("=", 1)[1])
        np.testing.assert_array_equal(run(buffer), reconstruct(mod.moderated(buffer, prior)))
