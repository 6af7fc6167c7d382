"""The measured noise gain and when it is measured again (awr_denoise/noise_gain.py)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from awr_denoise import AdaptiveSampler, SampleBuffer, noise_gain
from awr_denoise.noise_gain import DEFAULT_GAIN_REFRESH, MeasuredGain
from awr_denoise.reconstruct import reconstruct_detailed
from awr_denoise.synthetic import SyntheticRenderer, make_scene


def _buffer(spp: int, shape: tuple[int, int] = (24, 24), seed: int = 0) -> SampleBuffer:
    rng = np.random.default_rng(seed)
    return SampleBuffer.from_moments(np.full(shape, spp), 0.5 + rng.random(shape + (3,)), np.full(shape + (3,), 0.2))


def test_the_gain_is_the_default_reconstructions():
    buffer = _buffer(4)
    expected = reconstruct_detailed(buffer, variance_probes=0, pixel_clamp=None, preserve_mean=False,
                                    nonnegative=False).noise_gain
    assert_array_equal(MeasuredGain()(buffer), expected)
    # The finishing steps do not change it: the default reconstruction reports the same gain.
    assert_array_equal(reconstruct_detailed(buffer, variance_probes=0).noise_gain, expected)


@pytest.mark.parametrize(("refresh", "spps", "measured"), [
    (1.0, [4, 4, 5, 6, 8], 5),       # every call
    (1.5, [4, 5, 6, 7, 9, 12], 3),   # at 4, 6 (1.5x), 9 (1.5x of 6)
    (2.0, [4, 5, 6, 7, 8, 15, 16], 3),
])
def test_the_gain_is_measured_again_once_the_samples_grow_by_refresh(refresh, spps, measured):
    gain = MeasuredGain(refresh)
    for spp in spps:
        gain(_buffer(spp))
    assert gain.measurements == measured


def test_another_image_or_fewer_samples_are_measured_anew():
    gain = MeasuredGain(1.5)
    first = gain(_buffer(8))
    assert gain(_buffer(8, shape=(24, 16))).shape == (24, 16)       # another shape
    assert gain(_buffer(4)) is not first and gain.measurements == 3   # fewer samples: another buffer


@pytest.mark.parametrize("bad", [0.5, 0.0, -1.0, float("nan"), float("inf"), "2", None])
def test_a_refresh_below_one_or_not_a_number_is_refused(bad):
    with pytest.raises((ValueError, TypeError), match="gain_refresh"):
        MeasuredGain(bad)


def test_the_sampler_takes_gain_refresh_only_with_the_measured_gain():
    with pytest.raises(ValueError, match="gain_refresh: 2.0 needs noise_model='reconstruction'"):
        AdaptiveSampler((16, 16), gain_refresh=2.0)
    with pytest.raises(ValueError, match="gain_refresh"):
        AdaptiveSampler((16, 16), noise_model="reconstruction", gain_refresh=0.9)


@pytest.mark.parametrize(("refresh", "expected"), [(None, 10), (1.0, 10), (1.5, 5), (2.0, 3)])
def test_a_sampler_reconstructs_once_per_measurement(monkeypatch, refresh, expected):
    """To 32 spp from 4 at the default round growth (a quarter of the samples so far): ten adaptive
    rounds, each measured by default; a refresh of 1.5 measures every other one."""
    calls = []
    real = noise_gain.reconstruct_detailed

    def counted(*args, **kwargs):
        calls.append(args[0].total_samples)
        return real(*args, **kwargs)

    monkeypatch.setattr(noise_gain, "reconstruct_detailed", counted)
    scene = make_scene("edges", (32, 32))
    options = {} if refresh is None else {"gain_refresh": refresh}
    sampler = AdaptiveSampler(scene.shape, noise_model="reconstruction", **options)
    sampler.run(SyntheticRenderer(scene), total_spp=32)
    assert len(calls) == expected, calls
    assert DEFAULT_GAIN_REFRESH == 1.0


@pytest.mark.parametrize("refresh", [None, 1.0])
def test_refresh_one_gives_the_requests_of_a_gain_measured_every_round(refresh):
    """gain_refresh=1, the default, is the measurement of every round: each round's density from a
    fresh reconstruction, as a sampler made anew from the buffer gives."""
    scene = make_scene("edges", (32, 32))
    renderer = SyntheticRenderer(scene)
    options = {} if refresh is None else {"gain_refresh": refresh}
    sampler = AdaptiveSampler(scene.shape, noise_model="reconstruction", **options)
    sampler.tell(sampler.ask(), renderer(sampler.ask()))
    for _ in range(3):
        fresh = AdaptiveSampler.from_buffer(sampler.buffer, round=sampler.round, issued=sampler.issued,
                                            noise_model="reconstruction")
        request = sampler.ask()
        assert_array_equal(request.counts, fresh.ask().counts)
        sampler.tell(request, renderer(request))
