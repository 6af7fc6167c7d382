"""``benchmarks/bench_guides.py``: the demodulated guides of ``features`` use the albedo they name, and their
choice window by window follows Stein's estimate."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from awr_denoise import SampleBuffer, SampleRequest, reconstruct
from awr_denoise.renderers import create_renderer

from .conftest import refused_before_any_work


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


def _fake_reconstruct(buffer, guide=None):
    """The means without a guide; with one, the guide itself (each candidate a known map of the means)."""
    return np.array(buffer.mean) if guide is None else np.array(guide)


def _box3(buffer):
    from scipy import ndimage
    return ndimage.uniform_filter(np.asarray(buffer.mean), size=(3, 3, 1), mode="reflect")


def _noisy(mean, sd, seed=0):
    rng = np.random.default_rng(seed)
    count = np.full(mean.shape[:2], 16)
    return SampleBuffer.from_moments(count, mean + rng.normal(0, sd, mean.shape), np.full(mean.shape, sd * sd * 16))


def test_the_choice_by_sure_takes_a_smoothing_of_noise_and_leaves_detail(bench, monkeypatch):
    """Against the means (divergence 1 per pixel), a 3x3 box (1/9) wins on a flat noisy image and loses on
    a checkerboard whose noise is tiny: the divergence's sign and size decide, as in Stein's estimate (with
    the sign turned, the flat image keeps its means)."""
    monkeypatch.setattr(bench, "reconstruct", _fake_reconstruct)
    # noise small beside the level: the relative criterion's weights, from the default's image (here the
    # noisy means themselves), hardly follow the noise
    flat = _noisy(np.full((32, 32, 3), 1.0), 0.05)
    chosen = bench._chosen_by_sure(flat, np.array(flat.mean), _box3)
    error = {name: np.mean((image - 1.0) ** 2) for name, image in
             (("chosen", chosen), ("box", _box3(flat)), ("means", flat.mean))}
    # one probe's divergence is noisy window by window: the box is taken nearly everywhere, not everywhere
    assert error["box"] < error["chosen"] < 1.5 * error["box"] < 0.3 * error["means"], error
    board = (np.indices((32, 32)).sum(axis=0) % 2)[..., None] * np.ones(3) + 0.5
    detail = _noisy(board, 1e-3)
    chosen = bench._chosen_by_sure(detail, np.array(detail.mean), _box3)
    assert np.abs(chosen - detail.mean).max() < 1e-3 < np.abs(_box3(detail) - detail.mean).max()


def test_the_albedo_moves_with_the_probe_only_when_asked(bench, monkeypatch):
    """A guide that is the albedo's means, whose noise is twice the radiance's and from the same paths
    (a texture's): held fixed (``rho`` 0) its divergence is 0 and it is taken, at four times the means'
    error; its noise counted with the radiance's (``rho`` 1), the means are kept."""
    monkeypatch.setattr(bench, "reconstruct", _fake_reconstruct)
    base = _noisy(np.full((32, 32, 3), 1.0), 0.05)
    albedo = SampleBuffer.from_moments(base.count, 2 * np.array(base.mean) - 1, 4 * np.array(base.variance))
    buffer = dataclasses.replace(base, features={"albedo": albedo})
    follow = lambda b: np.array(b.features["albedo"].mean)  # noqa: E731
    def error(image):
        return float(np.mean((image - 1.0) ** 2))

    fixed = bench._chosen_by_sure(buffer, np.array(buffer.mean), follow)
    counted = bench._chosen_by_sure(buffer, np.array(buffer.mean), follow, rho=1.0)
    assert error(fixed) > 2.5 * error(buffer.mean), (error(fixed), error(buffer.mean))
    assert error(counted) < 1.1 * error(buffer.mean), (error(counted), error(buffer.mean))


def test_the_pilot_rules_are_switched_for_one_measurement_and_restored(bench, buffer):
    """``rules``: both rules are the library's feature pilot; without them another image; afterwards the
    library's own functions again."""
    from awr_denoise import guided
    own = reconstruct(buffer, features=True)
    with bench._pilot_rules(True, True):
        np.testing.assert_array_equal(reconstruct(buffer, features=True), own)
    with bench._pilot_rules(False, False):
        assert not np.allclose(reconstruct(buffer, features=True), own, rtol=1e-3)
    np.testing.assert_array_equal(reconstruct(buffer, features=True), own)
    assert guided._pair_variance.__module__ == guided.__name__


def test_the_rules_table_summarises_every_row(bench, capsys):
    rows = [{"renderer": "r", "scene": "s", "spp": spp, "group": g, "method": m, "relmse": rel, "mse": 1.0}
            for spp in (8, 32) for g in (0, 1)
            for m, rel in (("plain", 4.0), ("default", 2.0), *((name, 1.0 + spp / 16) for name in bench.RULES))]
    bench.pilot_rules_table(rows)
    assert "feature pilot: geometric mean 1.061, worst 1.500, above 1 on 2 of 4" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["quality", "--scenes", "defualt"], "--scenes: defualt not among"),
    (["ablations", "--scenes", "cornell_box"], "--scenes: cornell_box not among"),
    (["quality", "--groups", "0"], "argument --groups: must be >= 1, got 0"),
    (["avenues", "--spps", "64"], "--spps: avenues measures the largest of 64"),
    (["ablations", "--spps", "16"], "--spps: ablations measures 8 and 32 spp"),
    (["stein", "--groups", "1"], "--groups must be at least 2"),
])
def test_bad_options_are_refused_before_any_work_and_the_results_kept(bench, tmp_path, capsys, argv, message):
    """A misspelt scene (or no spp a section measures) wrote an empty section over the stored one, exit 0;
    ``avenues --spps 64`` failed after rendering."""
    refused_before_any_work(bench.main, argv, message, tmp_path, capsys)
