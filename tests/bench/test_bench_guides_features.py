"""``benchmarks/bench_guides.py``: the demodulated guides of ``features`` use the albedo they name."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from awr_denoise import SampleBuffer, SampleRequest, reconstruct
from awr_denoise.renderers import create_renderer


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_guides")


@pytest.fixture(scope="module")
def buffer():
    """A textured, defocused scene: its albedo means are noisy and vary."""
    return create_renderer("tracer", "chess_dof", shape=(32, 32), seed=0, features="all")(
        SampleRequest.uniform((32, 32), 4))


def test_a_constant_albedo_leaves_the_reconstruction_as_it_is(bench, buffer):
    """Demodulating by a constant only rescales the radiance, which the reconstruction follows: the
    guide is the default's image. The buffer's own (textured) albedo gives another one."""
    assert buffer.features["albedo"].mean.std() > 0.1
    half = np.full(buffer.mean.shape, 0.5 - 0.02)  # 0.5 with the guide's offset: an exact rescaling
    np.testing.assert_allclose(bench._demodulated(buffer, albedo=half), reconstruct(buffer), rtol=1e-12, atol=0)
    assert not np.allclose(bench._demodulated(buffer), reconstruct(buffer), rtol=1e-3)


def test_the_reconstructed_albedo_is_the_one_divided_by(bench, buffer):
    """With a noise-free albedo buffer its reconstruction is its means, so both demodulated guides agree;
    with the noisy one they differ."""
    albedo = buffer.features["albedo"]
    exact = SampleBuffer.from_moments(albedo.count, albedo.mean, np.zeros_like(albedo.mean))
    clean = dataclasses.replace(buffer, features={**buffer.features, "albedo": exact})
    np.testing.assert_allclose(bench._demodulated_reconstructed(clean), bench._demodulated(clean), rtol=1e-9)
    assert not np.allclose(bench._demodulated_reconstructed(buffer), bench._demodulated(buffer), rtol=1e-3)


def test_the_table_divides_by_the_default_and_the_plain_mean(bench, capsys):
    rows = [{"renderer": "r", "scene": "s", "spp": spp, "group": 0, "method": m, "relmse": rel, "mse": sq}
            for spp in (8, 32) for m, rel, sq in (("plain", 4.0, 2.0), ("default", 2.0, 1.0), ("way", 1.0, 1.5))]
    bench.feature_limits_table(rows)
    assert "| s | 0.50 / 0.50; 0.75 |" in capsys.readouterr().out


def test_no_demodulation_below_the_floor(bench, buffer):
    """Where the albedo is below ``below`` (sky, emitters) the radiance is not divided: an albedo below
    it everywhere gives the default's image; the offset demodulation by the same (varying) albedo does not."""
    dark = np.zeros(buffer.mean.shape)
    dark[::2] = 0.04  # rows of black and of 0.04: both below 0.05
    np.testing.assert_allclose(bench._demodulated(buffer, albedo=dark, below=0.05), reconstruct(buffer),
                               rtol=1e-12, atol=0)
    assert not np.allclose(bench._demodulated(buffer, albedo=dark), reconstruct(buffer), rtol=1e-3)
