"""``benchmarks/decimated_wiener.py``: the cycle-spun decimated Wiener stages the reconstruction benchmark
measures beside the default's undecimated ones are what they claim to be."""

from __future__ import annotations

import numpy as np
import pytest

from awr_denoise import SampleBuffer, reconstruct
from awr_denoise.bench import noisy_buffer


@pytest.fixture(scope="module")
def dec(benchmark_script):
    return benchmark_script("decimated_wiener")


def _inputs(shape=(20, 18, 1), seed=0):
    rng = np.random.default_rng(seed)
    clean = 1.0 + np.linspace(0, 1, shape[1])[None, :, None] * np.ones(shape)
    v = np.full(shape, 0.02)
    x = clean + np.sqrt(v) * rng.standard_normal(shape)
    return x, v, clean


@pytest.mark.parametrize("shifts", [1, 4, 16])
def test_noise_free_means_come_back_exactly(dec, shifts):
    """Zero variance: every factor is 1, so each shift's transform pair and their mean give the means back."""
    x, _, clean = _inputs()
    out, lev = dec.decimated_wiener(x, np.zeros_like(x), clean, k=0.1, exponent=0.75, levels=2,
                                    shifts=dec.SHIFT_SETS[shifts], leverage=True)
    np.testing.assert_allclose(out, x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(lev, 1.0, atol=1e-12)


@pytest.mark.parametrize("shifts", [1, 4])
def test_the_leverage_is_the_maps_diagonal(dec, shifts):
    """For a fixed pilot (no energy floor) the stage is linear in the means: its output at pixel p for
    the impulse at p is the diagonal the guard is given."""
    x, v, clean = _inputs()
    sh = dec.SHIFT_SETS[shifts]
    _, lev = dec.decimated_wiener(x, v, clean, k=0.1, exponent=0.75, levels=2, shifts=sh, leverage=True)
    h, w, _ = x.shape
    brute = np.empty((h, w))
    for i in range(h):
        for j in range(w):
            e = np.zeros_like(x)
            e[i, j, 0] = 1.0
            brute[i, j] = dec.decimated_wiener(e, v, clean, k=0.1, exponent=0.75, levels=2, shifts=sh)[0][i, j, 0]
    np.testing.assert_allclose(lev[..., 0], brute, rtol=1e-9, atol=1e-12)


def test_more_shifts_remove_more_noise(dec):
    """Averaging shifts averages the decimated grids' artefacts: the error falls from 1 to 4 to 16 shifts."""
    x, v, clean = _inputs((32, 32, 1), seed=3)
    errors = [np.mean((dec.decimated_wiener(x, v, clean, k=0.1, exponent=0.4, levels=3,
                                            shifts=dec.SHIFT_SETS[n])[0] - clean) ** 2) for n in (1, 4, 16)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[0] < np.mean((x - clean) ** 2)


def test_the_variant_keeps_the_defaults_finishing(dec):
    """The whole variant ends like the default, with the image mean restored (2% low without it here)."""
    b = noisy_buffer((48, 40), smooth=0.0, noise=0.3)
    buffer = SampleBuffer.from_moments(b.count, np.abs(b.mean), b.variance)  # radiance: never negative
    image = dec.decimated_default(4)(buffer)
    default = reconstruct(buffer)
    assert image.shape == default.shape
    np.testing.assert_allclose(image.mean(axis=(0, 1)), buffer.mean.mean(axis=(0, 1)), rtol=1e-10)
    assert not np.allclose(image, default)  # a different transform, not the default under another name
