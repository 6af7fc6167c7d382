"""The peer denoisers (awr_denoise.bench.peers)."""

from __future__ import annotations

import numpy as np
import pytest

from awr_denoise.bench import oidn_available, oidn_denoise, skimage_denoise


def _noisy_hdr(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:64, 0:64] / 64.0
    clean = np.stack([1.0 + x, 0.5 + 0.5 * y, 2.0 * np.ones_like(x)], axis=-1)
    noisy = clean * rng.gamma(4.0, 0.25, clean.shape)  # 4-sample-like multiplicative noise
    return clean, noisy


def test_oidn_peer_denoises_a_noisy_hdr_image():
    if not oidn_available():
        pytest.skip("pyoidn is not installed (extra 'oidn')")
    clean, noisy = _noisy_hdr(3)
    out = oidn_denoise(noisy)
    assert out.shape == clean.shape and out.dtype == np.float64 and np.isfinite(out).all()
    assert np.mean((out - clean) ** 2) < 0.25 * np.mean((noisy - clean) ** 2)


def test_skimage_peer_denoises_a_noisy_hdr_image():
    pytest.importorskip("skimage")
    clean, noisy = _noisy_hdr(4)
    out = skimage_denoise(noisy)
    assert out.shape == clean.shape and out.dtype == np.float64 and (out >= 0).all()
    assert np.mean((out - clean) ** 2) < 0.5 * np.mean((noisy - clean) ** 2)
