"""The sampler settings a run carries through its files (``cli/sampler_settings.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from awr_denoise import SampleBuffer
from awr_denoise.cli.main import build_parser
from awr_denoise.cli.sampler_settings import CARRIED, DEFAULTS, carried_settings, described, sampler_settings
from awr_denoise.errors import InputFileError
from awr_denoise.io import read_sample_dump, write_sample_buffer
from awr_denoise.cli.values import MAX_ROUND_GROWTH
from awr_denoise.sampling import SAMPLERS, AdaptiveSampler, UniformSampler, VarianceSampler


def test_each_strategy_writes_the_settings_it_ranks_with():
    awr = AdaptiveSampler((8, 8), round_growth=0.3, rare_paths="zeros", noise_model="levels", wavelet="haar",
                          levels=2, spp_max=64)
    assert sampler_settings(awr) == {"awr:round_growth": "0.3", "awr:spp_max": 64, "awr:rare_paths": "zeros",
                                     "awr:noise_model": "levels", "awr:priority_wavelet": "haar",
                                     "awr:priority_levels": 2}
    # Left automatic (no cap, the depth the image allows): not written, so a plan decides it again.
    assert sampler_settings(AdaptiveSampler((8, 8))) == {
        "awr:round_growth": "0.25", "awr:rare_paths": "even", "awr:noise_model": "shrinkage",
        "awr:priority_wavelet": "bior4.4"}
    assert sampler_settings(VarianceSampler((8, 8), rare_paths="ranked")) == {
        "awr:round_growth": "0.25", "awr:rare_paths": "ranked"}
    assert sampler_settings(UniformSampler((8, 8), spp_max=9)) == {"awr:round_growth": "0.25", "awr:spp_max": 9}


def test_a_dump_carries_them_exactly(tmp_path):
    """The growth goes as text: an EXR float attribute is 32-bit and 0.3 came back 0.30000001192092896."""
    awr = AdaptiveSampler((8, 8), round_growth=0.3, rare_paths="zeros", levels=2, spp_max=64)
    buffer = SampleBuffer.from_moments(np.full((8, 8), 2), np.full((8, 8, 3), 0.5), np.full((8, 8, 3), 0.1))
    write_sample_buffer(tmp_path / "d.exr", buffer, header=sampler_settings(awr))
    read = carried_settings(tmp_path / "d.exr", read_sample_dump(tmp_path / "d.exr").attributes, "awr")
    assert read == {"round_growth": 0.3, "spp_max": 64, "rare_paths": "zeros", "noise_model": "shrinkage",
                    "wavelet": "bior4.4", "levels": 2}
    assert AdaptiveSampler((8, 8), **read).round_growth == 0.3
    # Another writer's float attribute is read too.
    assert carried_settings("f.exr", {"awr:round_growth": np.float32(0.25)}, "uniform") == {"round_growth": 0.25}


def test_only_the_strategy_s_own_settings_are_read_and_checked():
    """A dump's settings are those of its strategy (``None``: no strategy, which plan takes for awr); another
    strategy's are neither taken nor checked, as plan neither uses nor refuses them."""
    header = {"awr:round_growth": "1.0", "awr:rare_paths": "zeros", "awr:noise_model": "levels"}
    assert carried_settings("d.exr", header, "uniform") == {"round_growth": 1.0}
    assert carried_settings("d.exr", header, "variance") == {"round_growth": 1.0, "rare_paths": "zeros"}
    assert carried_settings("d.exr", header, "awr") == carried_settings("d.exr", header, None) == {
        "round_growth": 1.0, "rare_paths": "zeros", "noise_model": "levels"}
    assert carried_settings("d.exr", {**header, "awr:noise_model": "evil"}, "variance")["rare_paths"] == "zeros"
    with pytest.raises(InputFileError, match="awr:noise_model"):
        carried_settings("d.exr", {**header, "awr:noise_model": "evil"}, None)


def test_a_depth_is_checked_against_the_image_when_its_shape_is_given():
    assert carried_settings("d.exr", {"awr:priority_levels": 4}, "awr", (24, 32)) == {"levels": 4}
    with pytest.raises(InputFileError, match=r"d\.exr: awr:priority_levels: 5 is outside 1\.\.4 for its image"):
        carried_settings("d.exr", {"awr:priority_levels": 5}, "awr", (24, 32))
    assert carried_settings("d.exr", {"awr:priority_levels": 5}, "variance", (24, 32)) == {}


@pytest.mark.parametrize(("key", "value", "needle"), [
    ("awr:round_growth", "0", "not a number above 0"), ("awr:round_growth", "-0.5", "not a number above 0"),
    ("awr:round_growth", "inf", "not a number above 0"), ("awr:round_growth", "0x10", "not a number above 0"),
    ("awr:round_growth", "1_0", "not a number above 0"), ("awr:round_growth", "2e6", "at most 1e+06"),
    ("awr:round_growth", "x" * 100_000, "(100002 characters) is not a number"),
    ("awr:spp_max", "0", "outside 1.."), ("awr:spp_max", "4.5", "not a whole number"),
    ("awr:priority_levels", 33, "outside 1..32"), ("awr:priority_wavelet", "dmey", "not a perfect-reconstruction"),
    ("awr:priority_wavelet", "morl", "'morl' is not a discrete wavelet"),
    ("awr:rare_paths", "Even", "not one of even, zeros, ranked"), ("awr:noise_model", "", "not one of levels"),
    ("awr:spp_max", "9" * 5000, "... (5002 characters)"),
])
def test_a_bad_value_is_refused_naming_the_file_and_the_attribute(key, value, needle):
    with pytest.raises(InputFileError, match=r"d\.exr") as refused:
        carried_settings("d.exr", {key: value}, "awr")
    assert key in str(refused.value) and needle in str(refused.value) and len(str(refused.value)) < 250


def test_the_settings_a_plan_names_are_those_that_are_not_the_defaults():
    assert described({"round_growth": 0.25, "rare_paths": "even", "noise_model": "shrinkage"}) == ""
    assert described({"levels": 3, "round_growth": 1.0, "spp_max": 64, "rare_paths": "even"}) == \
        "--round-growth 1, --spp-max 64, --levels 3"
    assert described({"round_growth": 0.123456789}) == "--round-growth 0.123456789"  # as recorded, not rounded
    assert set(DEFAULTS) == {name for name, _, _, _ in CARRIED}
    for name, _, _, strategies in CARRIED:  # every default is the samplers' own, in every strategy that uses it
        for strategy in strategies:
            assert getattr(SAMPLERS[strategy]((8, 8)), name) == DEFAULTS[name], (strategy, name)


def test_the_largest_growth_is_the_samplers_own():
    """--round-growth and awr:round_growth stop where the samplers do (values.MAX_ROUND_GROWTH)."""
    assert AdaptiveSampler((8, 8), round_growth=MAX_ROUND_GROWTH).round_growth == MAX_ROUND_GROWTH
    with pytest.raises(ValueError, match="round_growth"):
        AdaptiveSampler((8, 8), round_growth=MAX_ROUND_GROWTH * (1 + 1e-9))


def test_every_setting_is_a_sampler_keyword_and_a_plan_option():
    """A setting added to one side only would be written and never read, or the reverse: plan's option sets the
    argument of the sampler's keyword's name, and each strategy's sampler keeps it as that attribute."""
    values = {"round_growth": 0.5, "spp_max": 7, "rare_paths": "zeros", "noise_model": "levels", "wavelet": "haar",
              "levels": 2}
    for name, key, option, strategies in CARRIED:
        assert key.startswith("awr:")
        args = build_parser().parse_args(["plan", "d.exr", "-o", "r.exr", option, str(values[name])])
        assert getattr(args, name) == values[name], option
        for strategy in strategies:
            assert getattr(SAMPLERS[strategy]((8, 8), **{name: values[name]}), name) == values[name], (strategy, name)
