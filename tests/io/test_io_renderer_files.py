"""Mitsuba 3 and Blender Cycles readers on files the renderers wrote (tests/data/mitsuba, cycles;
regenerate with tests/data/generate/*.py). Fresh renders run when the renderer is installed."""

from __future__ import annotations

import importlib.util
import itertools
import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

# Cycles writes no variance: these tests read its files with the colour plane as the variance, only so that
# they read, and the warning that says so (tests/test_io_presets.py) is not what they test.
pytestmark = [pytest.mark.exr, pytest.mark.filterwarnings(
    "ignore:.*the variance plane is the colour plane itself:awr_denoise.errors.InputFileWarning")]
OpenEXR = pytest.importorskip("OpenEXR")

from awr_denoise import SampleRequest, reconstruct  # noqa: E402
from awr_denoise.cli.main import main  # noqa: E402
from awr_denoise.errors import InputFileError, InputFileWarning  # noqa: E402
from awr_denoise.io import read_image, read_independent_renders, read_sample_dump, write_image  # noqa: E402
from awr_denoise.io.exr import write_exr  # noqa: E402

DATA = Path(__file__).parent.parent / "data"
GEN = DATA / "generate"
MI, CY, PB = DATA / "mitsuba", DATA / "cycles", DATA / "pbrt"


def _channels(path):
    with OpenEXR.File(str(path), separate_channels=True) as f:
        out = {}
        for i in range(len(f.parts)):
            for k, v in f.channels(i).items():
                out.setdefault(k, v.pixels.astype(np.float64))
    return out


# ---------------------------------------------------------------- Mitsuba 3

@pytest.mark.parametrize("name", ["mitsuba_box.exr", "mitsuba_cli_box.exr"])
def test_mitsuba_xyz_mean_is_the_films_srgb(name):
    ch = _channels(MI / name)
    buf = read_sample_dump(MI / name, spp=8).buffer
    film = np.stack([ch[c] for c in "RGB"], -1)  # the film's own linear sRGB of the same samples
    np.testing.assert_allclose(buf.mean, film, rtol=5e-3, atol=1e-4 * film.max())


def test_mitsuba_colour_against_reference():
    ref = read_image(MI / "mitsuba_ref.exr").astype(np.float64)
    ch = _channels(MI / "mitsuba_box.exr")
    as_rgb = np.stack([ch[f"nested.{c}"] for c in "XYZ"], -1)  # the old reading: XYZ as R,G,B
    buf = read_sample_dump(MI / "mitsuba_box.exr", spp=8).buffer
    err_new = np.mean((buf.mean - ref) ** 2)
    err_old = np.mean((as_rgb - ref) ** 2)
    assert err_new < 0.6 * err_old  # measured 0.47x


def test_mitsuba_aov_rgb_moments_used_and_close_to_conversion():
    dump = read_sample_dump(MI / "mitsuba_aov.exr", spp=8)
    assert any("exact RGB variances" in n for n in dump.notes)
    conv = read_sample_dump(MI / "mitsuba_aov.exr", spp=8, preset="mitsuba", color="main").buffer
    ok = dump.buffer.variance > 0
    ratio = np.median(conv.variance[ok] / dump.buffer.variance[ok])
    assert 0.85 < ratio < 1.15  # measured 0.95-0.99 per channel (docs/io.md)


def test_a_mono_renders_aovs_are_found_beside_its_luminance(tmp_path):
    """A mono variant's moment around an aov integrator: its colour plane is main.Y, and its AOVs were looked for
    beside it (main.Y.albedo): dropped by info, refused by --guide features (a red-team pass)."""
    dump = read_sample_dump(MI / "mitsuba_mono_aov.exr", spp=8)
    assert dump.buffer.channels == ("Y",)
    assert set(dump.buffer.features) == {"albedo", "normal", "depth"}
    assert all(f.variance_known.all() for f in dump.buffer.features.values())  # each AOV's m2_ moment
    ch = _channels(MI / "mitsuba_mono_aov.exr")
    np.testing.assert_array_equal(dump.buffer.features["albedo"].mean[..., 0], ch["main.albedo.R"])
    out = tmp_path / "guided.exr"
    assert main(["denoise", str(MI / "mitsuba_mono_aov.exr"), "--spp", "8", "--guide", "features", "-q",
                 "-o", str(out)]) == 0
    assert read_image(out, channels=["Y"]).shape == (16, 16, 1)


def test_a_mitsuba_aov_named_as_a_feature_keeps_its_moment():
    """``--alb FILE:main.albedo`` read the plane's values alone: its m2_main.albedo beside it was not used."""
    named = read_sample_dump(MI / "mitsuba_aov.exr", spp=8, albedo="main.albedo").buffer.features["albedo"]
    found = read_sample_dump(MI / "mitsuba_aov.exr", spp=8).buffer.features["albedo"]
    assert named.variance_known.all()
    np.testing.assert_array_equal(named.variance, found.variance)
    np.testing.assert_array_equal(named.mean, found.mean)


def test_mitsubas_raw_film_is_refused_as_a_dump_and_as_an_image(tmp_path, capsys):
    """film.bitmap(raw=True): weighted sums and their weights W. As a dump it was refused as "not E[x^2]
    (variance_kind)"; awr diff compared the sums as an image, exit 0 (a red-team pass)."""
    raw = MI / "mitsuba_raw.exr"
    assert "W" in _channels(raw)
    with pytest.raises(InputFileError, match=r"mitsuba_raw\.exr: W: holds Mitsuba's unnormalised film"):
        read_sample_dump(raw, spp=8)
    with pytest.raises(InputFileError, match="divide every plane by W"):
        read_image(raw)
    for argv in ([str(raw), "-r", str(MI / "mitsuba_ref.exr")], [str(MI / "mitsuba_ref.exr"), "-r", str(raw)]):
        assert main(["diff", *argv]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "unnormalised film" in err[0]
    write_exr(tmp_path / "rgbw.exr", {c: np.ones((4, 4), np.float32) for c in "RGBW"})  # not Mitsuba's: an image
    assert read_image(tmp_path / "rgbw.exr").shape == (4, 4, 3)


def test_a_mitsuba_batch_merges_into_a_running_dump_with_its_spp(tmp_path, capsys):
    """--spp reads the inputs without their own counts: an awr dump beside a Mitsuba file refused it ("holds
    per-pixel sample counts") and the Mitsuba file refused its absence (a red-team pass): no way to merge them."""
    first = tmp_path / "dump.exr"
    # The two files are one render (seed 0) in two layouts: the same samples, merged here only for their layouts.
    assert main(["merge", str(MI / "mitsuba_aov_position.exr"), str(MI / "mitsuba_aov_of_moment.exr"), "--spp", "8",
                 "--allow-duplicates", "-o", str(first), "-q"]) == 0
    merged = tmp_path / "merged.exr"
    assert main(["merge", str(first), str(MI / "mitsuba_half_aov.exr"), "--spp", "16", "-o", str(merged), "-q"]) == 0
    buffer = read_sample_dump(merged).buffer
    assert (buffer.count == 8 + 8 + 16).all()
    half = read_sample_dump(MI / "mitsuba_half_aov.exr", spp=16).buffer
    np.testing.assert_allclose(buffer.mean, (16 * read_sample_dump(first).buffer.mean + 16 * half.mean) / 32,
                               rtol=1e-5, atol=1e-7)
    # With every input counting its own samples, --spp still describes none of them: refused.
    assert main(["merge", str(first), str(merged), "--spp", "8", "-o", str(tmp_path / "x.exr"), "-q"]) == 2
    assert "--spp is for files without them" in capsys.readouterr().err


def test_one_mitsuba_render_in_two_files_is_not_merged_as_twice_the_samples(tmp_path, capsys):
    """Two files of one Mitsuba render (its sampler's seed 0 by default): their means differ by float rounding, so
    the copy check (equal bytes) let them through as 16 spp, the variance halved (a walkthrough)."""
    out = tmp_path / "m.exr"
    assert main(["merge", str(MI / "mitsuba_box.exr"), str(MI / "mitsuba_aov.exr"), "--spp", "8", "-o", str(out),
                 "-q"]) == 2
    err = capsys.readouterr().err
    assert "hold the same samples up to rounding" in err and "--allow-duplicates" in err
    assert not out.exists()
    seeds = sorted(CY.glob("cycles_seed_*.exr"))[:2]  # two seeds of one scene: other samples, merged
    assert main(["merge", "--independent", *map(str, seeds), "-o", str(tmp_path / "c.exr"), "-q"]) == 0


def test_one_pbrt_render_in_float_and_in_half_floats_is_not_merged_as_twice_the_samples(tmp_path, capsys):
    """pbrt-v4 wrote one render twice, as floats and as its default half floats: their means differ by the halves'
    rounding, 2% of some of their signed sums, so the test up to float rounding merged them as 32 spp (an attack
    pass). The same render's replicates of other seeds (the same counts) still merge."""
    out = tmp_path / "m.exr"
    assert main(["merge", str(PB / "pbrt_gbuffer_fp32.exr"), str(PB / "pbrt_gbuffer_default.exr"), "-o", str(out),
                 "-q"]) == 2
    err = capsys.readouterr().err
    assert "hold the same samples up to rounding" in err and "half floats" in err and "--allow-duplicates" in err
    assert not out.exists()
    seeds = sorted((PB / "seeds").glob("pbrt_gbuffer_seed*.exr"))
    assert len(seeds) == 8
    assert main(["merge", *map(str, seeds), "-o", str(out), "-q"]) == 0
    assert (read_sample_dump(out).buffer.count == 16 * 8).all()


def _exr_parts(path: Path) -> tuple[dict, dict[str, np.ndarray]]:
    with OpenEXR.File(str(path), separate_channels=True) as f:
        header = dict(f.header())
        header.pop("channels", None)
        return header, {k: c.pixels.copy() for k, c in f.channels().items()}


def test_a_channel_in_two_parts_of_a_renderers_file_is_refused_not_taken_from_the_first(tmp_path, capsys):
    """pbrt-v4's dump with a second part repeating its channels (all NaN), or the 1024-spp reference as the first part
    beside the 16-spp dump: the first part won, silently, for every channel and attribute, and the reference's means
    were denoised as 1024 spp with the dump's variance (an attack pass). Refused naming the file and a channel, by the
    readers of samples, planes and features."""
    header, channels = _exr_parts(PB / "pbrt_gbuffer_fp32.exr")
    nan = {k: np.full_like(v, np.nan) if v.dtype.kind == "f" else v for k, v in channels.items()}
    repeated = tmp_path / "repeated.exr"
    OpenEXR.File([OpenEXR.Part(dict(header, name="first"), channels, "first"),
                  OpenEXR.Part(dict(header, name="second"), nan, "second")]).write(str(repeated))
    reference_header, reference = _exr_parts(PB / "pbrt_ref.exr")
    mixed = tmp_path / "mixed.exr"
    OpenEXR.File([OpenEXR.Part(dict(reference_header, name="beauty"), reference, "beauty"),
                  OpenEXR.Part(dict(header, name="samples"), channels, "samples")]).write(str(mixed))
    for path in (repeated, mixed):
        with pytest.raises(InputFileError, match=r"is in several parts \(0 and 1\)"):
            read_sample_dump(path)
        out = tmp_path / "o.exr"
        for argv in (["denoise", str(path), "-o", str(out)], ["info", str(path)],
                     ["merge", str(PB / "pbrt_gbuffer_fp32.exr"), str(path), "-o", str(out)],
                     ["denoise", str(PB / "pbrt_gbuffer_fp32.exr"), "--variance", f"{path}:Variance", "-o", str(out)]):
            code = main(argv + ([] if argv[0] == "info" else ["-q"]))
            captured = capsys.readouterr()
            said = captured.err + captured.out  # info describes the file, and says what is missing on stdout
            assert "is in several parts" in said and str(path.name) in said, (argv, said)
            assert code == 2 and not out.exists(), argv
    # Parts that name each channel once (pbrt's seeds in one file each) still read.
    assert read_sample_dump(PB / "pbrt_gbuffer_fp32.exr").buffer.count.min() == 16


def test_a_single_part_multi_view_file_is_read_in_the_view_asked_for(tmp_path, capsys):
    """OpenEXR's multiView in one part (the first view's channels bare, the others' prefixed, right.R), built from
    pbrt-v4's dump with the right view's means doubled: read as a single-view file, the left view silently, and
    --view right was "no view 'right'" (an attack pass). Now several views need --view, and each reads its own."""
    header, channels = _exr_parts(PB / "pbrt_gbuffer_fp32.exr")
    both = dict(channels)
    for name, plane in channels.items():
        both[f"right.{name}"] = plane * 2 if name in ("R", "G", "B") else plane.copy()
    stereo = tmp_path / "stereo.exr"
    OpenEXR.File(dict(header, multiView=["left", "right"]), both).write(str(stereo))
    with pytest.raises(InputFileError, match=r"has several views \(left, right\)"):
        read_sample_dump(stereo)
    left, right = (read_sample_dump(stereo, view=v).buffer for v in ("left", "right"))
    plain = read_sample_dump(PB / "pbrt_gbuffer_fp32.exr").buffer
    np.testing.assert_array_equal(left.mean, plain.mean)
    np.testing.assert_allclose(right.mean, 2 * plain.mean, rtol=1e-6)
    np.testing.assert_array_equal(right.variance, plain.variance)
    out = tmp_path / "o.exr"
    assert main(["denoise", str(stereo), "-o", str(out), "-q"]) == 2 and not out.exists()
    assert "has several views" in capsys.readouterr().err
    assert main(["denoise", str(stereo), "--view", "right", "-o", str(out), "-q"]) == 0
    # An awr dump never holds two views in one part: refused, not read as its first view whatever --view says.
    from awr_denoise.io import write_sample_buffer

    dump = write_sample_buffer(tmp_path / "dump.exr", plain)
    header, channels = _exr_parts(dump)
    OpenEXR.File(dict(header, multiView=["left", "right"]),
                 channels | {f"right.{k}": v for k, v in channels.items()}).write(str(stereo))
    with pytest.raises(InputFileError, match="holds views left, right in one part"):
        read_sample_dump(stereo, view="right")


def test_pbrts_chromaticities_set_the_colour_space_its_xyz_variance_is_converted_to(tmp_path, capsys):
    """pbrt-v4 writes chromaticities for an output colour space other than sRGB (util/image.cpp), its means then in
    that RGB and its Variance still in sensor XYZ: the variance was converted to sRGB beside Rec.2020 means, and the
    outputs dropped the attribute, without a word (an attack pass). Converted by the file's own primaries, said in a
    note, carried by denoise's image and merge's dump; inputs of two colour spaces are not merged."""
    from awr_denoise.io.colour import PBRT_XYZ_TO_SRGB, xyz_statistics_to_rgb, xyz_to_rgb

    header, channels = _exr_parts(PB / "pbrt_gbuffer_fp32.exr")
    xyz = np.stack([channels[f"Variance.{c}"] for c in "RGB"], axis=-1).astype(np.float64)
    rec2020 = (0.708, 0.292, 0.170, 0.797, 0.131, 0.046, 0.3127, 0.3290)
    plain = read_sample_dump(PB / "pbrt_gbuffer_fp32.exr").buffer
    for name, chromaticities in (("rec2020", rec2020), ("srgb", (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.329)),
                                 ("nan", (np.nan,) * 8), ("line", (0.2, 0.2, 0.3, 0.3, 0.4, 0.4, 0.3127, 0.329))):
        path = tmp_path / f"{name}.exr"
        OpenEXR.File(dict(header, chromaticities=chromaticities), channels).write(str(path))
        if name in ("nan", "line"):
            with pytest.raises(InputFileError, match=f"{name}.exr: chromaticities: "):
                read_sample_dump(path)
            continue
        dump = read_sample_dump(path)
        buffer = dump.buffer
        assert any("converted to the linear RGB of its chromaticities" in note for note in dump.notes)
        assert any("primaries other than sRGB's" in note for note in dump.notes) == (name == "rec2020")
        np.testing.assert_array_equal(buffer.mean, plain.mean)  # the means are the file's, in its own RGB
        known = plain.variance > 0
        expected = xyz_statistics_to_rgb(None, xyz, xyz_to_rgb(np.float32(chromaticities)))[1]
        np.testing.assert_allclose(buffer.variance[known], expected[known], rtol=1e-5)
        if name == "srgb":  # within the rounding of pbrt's matrix
            np.testing.assert_allclose(buffer.variance[known], plain.variance[known], rtol=2e-3)
    assert not np.allclose(xyz_to_rgb(rec2020), PBRT_XYZ_TO_SRGB, atol=0.1)
    image, merged = tmp_path / "image.exr", tmp_path / "merged.exr"
    assert main(["denoise", str(tmp_path / "rec2020.exr"), "-o", str(image), "-q"]) == 0
    assert main(["merge", str(tmp_path / "rec2020.exr"), str(PB / "pbrt_gbuffer_default.exr"), "-o", str(merged),
                 "-q", "--allow-duplicates"]) == 2
    assert "in other colour spaces" in capsys.readouterr().err and not merged.exists()
    copy = tmp_path / "copy.exr"
    copy.write_bytes((tmp_path / "rec2020.exr").read_bytes())
    assert main(["merge", str(tmp_path / "rec2020.exr"), str(copy), "-o", str(merged), "-q",
                 "--allow-duplicates"]) == 0
    for path in (image, merged):
        with OpenEXR.File(str(path), header_only=True) as f:
            np.testing.assert_allclose(f.header()["chromaticities"], rec2020, rtol=1e-6)
    with pytest.raises(ValueError, match="header: chromaticities: expected 8 finite numbers"):
        write_image(tmp_path / "bad.exr", np.ones((2, 2, 3)), header={"chromaticities": (0.7, 0.3)})
    assert main(["denoise", str(merged), "-o", str(tmp_path / "again.exr"), "-q"]) == 0  # on through the dump
    seeds = sorted((PB / "seeds").glob("pbrt_gbuffer_seed*.exr"))[:2]  # renders of other seeds, merged as such
    renders = []
    for seed in seeds:
        seed_header, seed_channels = _exr_parts(seed)
        renders.append(tmp_path / seed.name)
        OpenEXR.File(dict(seed_header, chromaticities=rec2020), seed_channels).write(str(renders[-1]))
    independent = tmp_path / "independent.exr"
    assert main(["merge", "--independent", *map(str, renders), "-o", str(independent), "-q"]) == 0
    with OpenEXR.File(str(independent), header_only=True) as f:
        np.testing.assert_allclose(f.header()["chromaticities"], rec2020, rtol=1e-6)
    assert main(["merge", "--independent", str(renders[0]), str(seeds[1]), "-o", str(tmp_path / "mixed.exr"),
                 "-q"]) == 2
    assert "in other colour spaces" in capsys.readouterr().err and not (tmp_path / "mixed.exr").exists()
    with OpenEXR.File(str(tmp_path / "again.exr"), header_only=True) as f:
        np.testing.assert_allclose(f.header()["chromaticities"], rec2020, rtol=1e-6)


def _sky_render(path: Path, spp: int, seed: int) -> None:
    """A render in the project's layout, at ``spp`` everywhere: a constant sky over 60% of it (no noise there) above
    noisy ground, whose true values do not depend on ``seed``."""
    from awr_denoise import SampleBuffer
    from awr_denoise.io import write_sample_buffer

    h, w = 64, 96
    truth = np.random.default_rng(1).uniform(0.2, 0.4, (h - 40, w, 3))
    mean = np.broadcast_to(np.array([0.7, 0.56, 0.42]), (h, w, 3)).copy()
    variance = np.zeros((h, w, 3))
    variance[40:] = (0.3 * truth) ** 2
    mean[40:] = truth + np.random.default_rng(seed).normal(size=truth.shape) * np.sqrt(variance[40:] / spp)
    write_sample_buffer(path, SampleBuffer.from_moments(np.full((h, w), spp), mean, variance))


def test_a_half_float_copy_of_a_render_of_many_samples_is_not_merged_as_twice_them(tmp_path, capsys):
    """A 65536-spp render and its copy with the means and variances in half floats, the counts kept (pbrt-v4's
    default output beside a float one): the halves' rounding was more than 0.05 of the noise, which a constant sky
    does not have, and the two were merged as twice the samples, exit 0 (an attack pass; from 16384 spp on here).
    Two renders of other seeds at the same counts, up to a million samples per pixel, still merge."""
    from awr_denoise.cli import merge_cmd

    render, copy, out = tmp_path / "float.exr", tmp_path / "half.exr", tmp_path / "m.exr"
    _sky_render(render, 2**16, seed=2)
    with OpenEXR.File(str(render), separate_channels=True) as f:
        header = dict(f.header())
        channels = {k: v.pixels if k == "sampleCount" else v.pixels.astype(np.float16) for k, v in f.channels().items()}
    assert "sampleCount" in channels
    OpenEXR.File(header, channels).write(str(copy))
    # The case this is about: the sums differ by more than the test up to rounding or noise allows.
    one, two = (read_sample_dump(p).buffer for p in (render, copy))
    apart = np.abs(merge_cmd._signatures(one.mean)[0] - merge_cmd._signatures(two.mean)[0])
    assert np.any(apart > merge_cmd._NOISE_SHARE * np.hypot(merge_cmd._noise(one), merge_cmd._noise(two)))
    assert main(["merge", str(render), str(copy), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert "hold the same samples up to rounding" in err and "--allow-duplicates" in err and not out.exists()
    for spp in (4096, 1_000_000):
        first, second = tmp_path / f"a{spp}.exr", tmp_path / f"b{spp}.exr"
        _sky_render(first, spp, seed=2)
        _sky_render(second, spp, seed=3)
        assert main(["merge", str(first), str(second), "-o", str(tmp_path / f"m{spp}.exr"), "-q"]) == 0, spp
        assert (read_sample_dump(tmp_path / f"m{spp}.exr").buffer.count == 2 * spp).all()


def test_a_render_and_its_half_float_copy_are_not_two_seeds(tmp_path, capsys):
    """``--independent`` refused a copy with the same pixels, not one converted to half floats (an attack pass): their
    spread, the rounding alone, made a variance 1e-5 of the renders' own. Two seeds of one scene still merge."""
    seed = CY / "cycles_seed_1.exr"
    copy = tmp_path / "half.exr"
    with OpenEXR.File(str(seed), separate_channels=True) as f:
        assert len(f.parts) == 1
        header = dict(f.header())
        channels = {k: v.pixels.astype(np.float16) for k, v in f.channels().items()}
    OpenEXR.File(header, channels).write(str(copy))
    out = tmp_path / "m.exr"
    assert main(["merge", "--independent", str(seed), str(copy), "-o", str(out), "-q"]) == 2
    assert "up to half-float rounding (a copy?)" in capsys.readouterr().err
    assert not out.exists()
    assert main(["merge", "--independent", str(seed), str(CY / "cycles_seed_2.exr"), "-o", str(out), "-q"]) == 0


def test_an_aov_integrator_without_radiance_is_warned_about():
    """moment around an aov integrator with no radiance integrator inside: Mitsuba writes 0 for the radiance,
    read and denoised into a black image without a word (a red-team pass)."""
    with pytest.warns(InputFileWarning, match=r"main: every pixel is 0; an aov integrator inside moment without"):
        dump = read_sample_dump(MI / "mitsuba_aov_no_radiance.exr", spp=8)
    assert not dump.buffer.mean.any() and set(dump.buffer.features) == {"albedo", "normal", "depth"}


def test_mitsuba_mono_variant_reads_its_luminance():
    # llvm_ad_mono writes X = Y = Z (the luminance) in every moment; the XYZ matrix made it a tinted
    # colour (R +20%, B -9%).
    ch = _channels(MI / "mitsuba_mono.exr")
    dump = read_sample_dump(MI / "mitsuba_mono.exr", spp=8)
    assert dump.buffer.channels == ("Y",)
    np.testing.assert_array_equal(dump.buffer.mean[..., 0], ch["nested.Y"])
    np.testing.assert_allclose(dump.buffer.mean[..., 0], ch["Y"], rtol=1e-5, atol=1e-7)  # the film's own
    m2 = ch["m2_nested.Y"]
    np.testing.assert_allclose(dump.buffer.variance[..., 0], np.maximum(m2 - ch["nested.Y"] ** 2, 0) * 8 / 7,
                               rtol=1e-6, atol=1e-12)


def test_mitsuba_half_moments_within_rounding_are_read():
    # component_format float16: a wall's normal.Z is a half subnormal (-6e-8) beside E[x^2] = 0.
    ch = _channels(MI / "mitsuba_half_aov.exr")
    z, z2 = ch["main.normal.Z"], ch["m2_main.normal.Z"]
    assert (z2 < 0.99 * z**2).any()  # what was refused as "not E[x^2]"
    dump = read_sample_dump(MI / "mitsuba_half_aov.exr", spp=16)
    normal = dump.buffer.features["normal"]
    assert np.isfinite(normal.variance).all() and (normal.variance >= 0).all()
    np.testing.assert_array_equal(normal.mean[..., 2], z)


def test_mitsuba_uint32_channels_are_refused(tmp_path, capsys):
    # component_format uint32 stores clamp(x, 0, 1) * 2**32: read as numbers, 10**9 times too large.
    assert main(["diff", str(MI / "mitsuba_uint32.exr"), "-r", str(MI / "mitsuba_ref.exr")]) == 2
    err = capsys.readouterr().err
    assert "mitsuba_uint32.exr" in err and "UINT" in err and "Traceback" not in err
    with pytest.raises(InputFileError, match="UINT"):
        read_image(MI / "mitsuba_uint32.exr")


def test_mitsuba_negative_lobed_filter_is_named():
    with pytest.raises(InputFileError, match=r"mitsuba_mitchell\.exr: .*negative second moment.*rfilter box"):
        read_sample_dump(MI / "mitsuba_mitchell.exr", spp=8)


def test_negative_second_moments_of_a_lossy_codec_name_it_not_the_filter(tmp_path):
    """Mitsuba's box-filtered moments recompressed with DWAA by a pipeline tool hold negative second moments; the
    line blamed a filter with negative lobes and said to render with rfilter box, which the file was (an attack
    pass). It names the codec first now."""
    oiio = pytest.importorskip("OpenImageIO")
    source = oiio.ImageBuf(str(MI / "mitsuba_box.exr"))
    spec = source.spec()
    spec.attribute("compression", "dwaa")
    out = oiio.ImageOutput.create(str(tmp_path / "box_dwaa.exr"))
    assert out.open(str(tmp_path / "box_dwaa.exr"), spec)
    assert out.write_image(source.get_pixels(oiio.FLOAT))
    out.close()
    with pytest.warns(InputFileWarning, match="DWAA compression is lossy"):
        with pytest.raises(InputFileError, match=r"box_dwaa\.exr: .*negative second moment: a lossy compression "
                                                 r"\(DWAA\) changed them"):
            read_sample_dump(tmp_path / "box_dwaa.exr", spp=8)


def test_mitsuba_aovs_nested_in_a_moment_are_not_radiance():
    # position and geo_normal AOVs have X,Y,Z components too: m2_main.position was taken for a
    # second radiance moment ("ambiguous").
    dump = read_sample_dump(MI / "mitsuba_aov_position.exr", spp=8)
    assert any("exact RGB variances" in n for n in dump.notes)
    ch = _channels(MI / "mitsuba_aov_position.exr")
    np.testing.assert_array_equal(dump.buffer.mean, np.stack([ch[f"main.img.{c}"] for c in "RGB"], -1))


def test_mitsuba_moment_inside_an_aov_integrator_is_detected():
    ch = _channels(MI / "mitsuba_aov_of_moment.exr")
    assert not any(c.startswith("m2_") for c in ch)  # img.m2_nested.*: no channel starts with m2_
    buf = read_sample_dump(MI / "mitsuba_aov_of_moment.exr", spp=8).buffer
    film = np.stack([ch[f"img.{c}"] for c in "RGB"], -1)
    np.testing.assert_allclose(buf.mean, film, rtol=5e-3, atol=1e-4 * film.max())


def test_mitsuba_two_moments_named_by_colour_keep_the_conversion(capsys):
    with pytest.raises(InputFileError, match="ambiguous.*--color"):
        read_sample_dump(MI / "mitsuba_two.exr", spp=8)
    chosen = read_sample_dump(MI / "mitsuba_two.exr", spp=8, color="a").buffer
    preset = read_sample_dump(MI / "mitsuba_two.exr", spp=8, color="a", preset="mitsuba").buffer
    np.testing.assert_array_equal(chosen.mean, preset.mean)
    np.testing.assert_array_equal(chosen.variance, preset.variance)
    ch = _channels(MI / "mitsuba_two.exr")
    assert not np.allclose(chosen.mean[..., 0], ch["a.X"])  # XYZ converted, not passed as R
    # Naming the planes the generic way keeps them Mitsuba's (it read XYZ as RGB and E[x^2] as a variance).
    assert main(["info", str(MI / "mitsuba_two.exr"), "--spp", "8", "--color", "a", "--variance", "m2_a"]) == 0
    assert "layout: mitsuba" in capsys.readouterr().out


def test_a_variance_plane_of_the_users_own_in_a_mitsuba_file(tmp_path, capsys):
    """A per-sample variance the user added is not one of Mitsuba's second moments: read as E[x^2]
    it was refused, or wrong where it exceeds the squared mean. It is read as a variance, in the
    preset (its XYZ converted like the moments)."""
    planes = _channels(MI / "mitsuba_box.exr")
    # The unbiased per-sample variance of the same 8 samples, as a user would store it.
    own = {f"myvar.{c}": np.maximum(planes[f"m2_nested.{c}"] - planes[f"nested.{c}"] ** 2, 0) * 8 / 7
           for c in "XYZ"}
    rgb = {f"rgbvar.{c}": own[f"myvar.{x}"] for c, x in zip("RGB", "XYZ")}
    path = tmp_path / "with_variance.exr"
    write_exr(path, {k: v.astype(np.float32) for k, v in (planes | own | rgb).items()})
    moments = read_sample_dump(path, spp=8, color="nested")
    users = read_sample_dump(path, spp=8, color="nested", variance="myvar")
    assert users.buffer.channels == ("R", "G", "B")
    np.testing.assert_array_equal(users.buffer.mean, moments.buffer.mean)
    np.testing.assert_allclose(users.buffer.variance, moments.buffer.variance, rtol=1e-5,
                               atol=1e-6 * moments.buffer.variance.max())
    with pytest.raises(InputFileError, match="nested is CIE XYZ and this variance is not"):
        read_sample_dump(path, spp=8, color="nested", variance="rgbvar")
    assert main(["info", str(path), "--spp", "8", "--color", "nested", "--variance", "myvar"]) == 0
    assert "layout: mitsuba" in capsys.readouterr().out


def test_a_variance_plane_of_the_users_own_in_a_pbrt_file(tmp_path):
    """pbrt's count and features are kept beside the user's variance (they were lost when it
    switched to the generic reader); another file's ``Variance`` is not pbrt's XYZ."""
    source = DATA / "pbrt" / "pbrt_gbuffer_fp32.exr"
    planes = _channels(source)
    rng = np.random.default_rng(3)
    mine = {f"myvar.{c}": rng.uniform(0.5, 2.0, planes["R"].shape) for c in "RGB"}
    path = tmp_path / "with_variance.exr"
    write_exr(path, {k: v.astype(np.float32) for k, v in (planes | mine).items()},
              header={"samplesPerPixel": 16})
    read = read_sample_dump(path, variance="myvar")
    assert set(read.buffer.features) == {"albedo", "normal", "depth"}
    assert (read.buffer.count == 16).all()
    stacked = np.stack([mine[f"myvar.{c}"] for c in "RGB"], axis=-1).astype(np.float32)
    np.testing.assert_array_equal(read.buffer.variance, stacked.astype(np.float64))
    other = tmp_path / "other.exr"
    write_exr(other, {f"Variance.{c}": np.ones(planes["R"].shape, np.float32) for c in "RGB"})
    named = read_sample_dump(path, variance=f"{other}:Variance")
    np.testing.assert_array_equal(named.buffer.variance, 1.0)  # not converted from XYZ


@pytest.mark.parametrize("path, options, named", [
    (DATA / "pbrt" / "pbrt_gbuffer_fp32.exr", {"variance": "Variance", "spp": 16},
     "Variance is pbrt-v4's variance in CIE XYZ"),
    (MI / "mitsuba_box.exr", {"color": "nested", "variance": "m2_nested", "spp": 16},
     r"m2_nested is a Mitsuba 3 moment integrator's second moment E\[x\^2\] in CIE XYZ, like its colour"),
])
def test_the_generic_layout_on_a_renderers_own_spread_says_it_is_xyz(path, options, named, tmp_path):
    """Read generically when asked, but not without a word: the spread these renderers write is CIE XYZ (and
    Mitsuba's a second moment), which the generic layout takes as it is named. A variance plane of the user's
    own in the same file is not the renderer's: no warning."""
    with pytest.warns(InputFileWarning, match=f"{named}.*--preset auto"):
        read_sample_dump(path, preset="generic", **options)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # their own presets read them without this warning
        read_sample_dump(path, spp=16)
    planes = _channels(path)
    colour = options.get("color")
    names = [f"{colour}.{c}" for c in "XYZ"] if colour else ["R", "G", "B"]
    mine = tmp_path / "mine.exr"
    variances = {f"myvar.{n.rsplit('.', 1)[-1]}": np.full(planes[n].shape, 0.1, np.float32) for n in names}
    write_exr(mine, {k: v.astype(np.float32) for k, v in planes.items()} | variances)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_sample_dump(mine, preset="generic", **(options | {"variance": "myvar"}))


def test_an_aovs_moment_named_reads_with_its_mean(tmp_path):
    """``m2_main.img`` (an AOV's moment inside ``moment``) was "m2_main.: no colour channel(s)";
    a Mitsuba file holding a ``Variance.*`` plane of the user's was read as pbrt's."""
    named = read_sample_dump(MI / "mitsuba_aov.exr", spp=8, variance="m2_main.img")
    by_colour = read_sample_dump(MI / "mitsuba_aov.exr", spp=8, color="main.img")
    np.testing.assert_array_equal(named.buffer.mean, by_colour.buffer.mean)
    np.testing.assert_array_equal(named.buffer.variance, by_colour.buffer.variance)
    planes = _channels(MI / "mitsuba_box.exr")
    path = tmp_path / "with_variance.exr"
    write_exr(path, {k: v.astype(np.float32) for k, v in planes.items()}
              | {f"Variance.{c}": np.ones_like(planes["R"], np.float32) for c in "RGB"})
    np.testing.assert_array_equal(read_sample_dump(path, spp=8).buffer.mean,
                                  read_sample_dump(MI / "mitsuba_box.exr", spp=8).buffer.mean)


def test_a_moment_named_with_its_file_or_through_a_link_is_still_a_moment(tmp_path):
    """``input.exr:m2_nested`` read E[x^2] as the colour (exit 0); a hard link to the input was
    not the input, so its moment was read as a per-sample variance."""
    planes = _channels(MI / "mitsuba_box.exr")
    path = tmp_path / "box.exr"
    write_exr(path, {k: v.astype(np.float32) for k, v in planes.items()})
    (tmp_path / "hard.exr").hardlink_to(path)
    expected = read_sample_dump(path, spp=8).buffer
    for spec in (f"{path}:m2_nested", f"{tmp_path / 'hard.exr'}:m2_nested"):
        got = read_sample_dump(path, spp=8, variance=spec).buffer
        np.testing.assert_array_equal(got.mean, expected.mean)
        np.testing.assert_array_equal(got.variance, expected.variance)


def test_a_users_variance_of_another_width_is_refused_not_cut(tmp_path):
    """A one-channel variance beside a mono file's X,Y,Z was an IndexError; an R,G,B,Z variance
    beside R,G,B lost its Z without a word (the cut was meant for an alpha moment)."""
    mono = _channels(MI / "mitsuba_mono.exr")
    box = _channels(MI / "mitsuba_box.exr")
    path = tmp_path / "mono.exr"
    ones = np.ones_like(mono["nested.Y"], np.float32)
    write_exr(path, {k: v.astype(np.float32) for k, v in mono.items()} | {"v1": ones})
    with pytest.raises(InputFileError, match=r"1 variance channel\(s\) \(v1\) for the 3 of the colour"):
        read_sample_dump(path, spp=8, variance="v1")
    path = tmp_path / "box.exr"
    write_exr(path, {k: v.astype(np.float32) for k, v in box.items()}
              | {f"v4.{c}": np.ones_like(box["R"], np.float32) for c in "RGBZ"})
    with pytest.raises(InputFileError, match=r"4 variance channel\(s\)"):
        read_sample_dump(path, spp=8, color="RGB", variance="v4")
    write_exr(path, {k: v.astype(np.float32) for k, v in box.items()}
              | {f"v4.{c}": np.full_like(box["R"], 1e-6, np.float32) for c in "RGBA"}, overwrite=True)
    read = read_sample_dump(path, spp=8, color="RGB", variance="v4")  # an alpha variance is dropped
    np.testing.assert_array_equal(read.buffer.variance, np.float32(1e-6))


def test_a_layer_named_like_a_moment(tmp_path):
    planes = _channels(MI / "mitsuba_box.exr")
    path = tmp_path / "layer.exr"
    write_exr(path, {f"m2_pass.{k}": v.astype(np.float32) for k, v in planes.items() if "nested" in k})
    got = read_sample_dump(path, spp=8, variance="m2_pass.m2_nested").buffer
    np.testing.assert_array_equal(got.mean, read_sample_dump(MI / "mitsuba_box.exr", spp=8).buffer.mean)


def test_independent_renders_refuse_a_named_variance(tmp_path, capsys):
    """Options that would do nothing with --independent are refused (``--request`` was ignored, its
    round and seed not recorded, exit 0: a red-team pass)."""
    from awr_denoise.io import write_request

    files = [str(p) for p in sorted(CY.glob("cycles_seed_*.exr"))]
    write_request(tmp_path / "r.exr", SampleRequest.uniform((32, 32), 16))
    for option in ("--variance", "--variance-kind", "--request"):
        value = {"--variance": "x", "--variance-kind": "sample", "--request": str(tmp_path / "r.exr")}[option]
        assert main(["merge", *files, "--independent", "-o", str(tmp_path / "o.exr"), option, value]) == 2
        assert f"{option}: not read with --independent" in capsys.readouterr().err
    assert not (tmp_path / "o.exr").exists()


def test_xyz_image_is_not_compared_by_y_alone(capsys):
    with pytest.raises(InputFileError, match="X,Y,Z"):
        read_image(MI / "mitsuba_xyz.exr")
    assert main(["diff", str(MI / "mitsuba_xyz.exr"), "-r", str(MI / "mitsuba_xyz.exr")]) == 2
    assert "X,Y,Z" in capsys.readouterr().err
    image = read_image(MI / "mitsuba_xyz.exr", channels=["X", "Y", "Z"])
    assert image.shape == (16, 16, 3)
    xyz = str(MI / "mitsuba_xyz.exr")
    assert main(["diff", xyz, "-r", xyz, "--channels", "X,Y,Z"]) == 0  # X,Y,Z with X,Y,Z: compared
    capsys.readouterr()


def test_an_xyz_image_is_not_compared_with_an_rgb_one(tmp_path, capsys):
    """The advice of the X,Y,Z refusal (``--ref-channels X,Y,Z``) compared an sRGB image with an XYZ reference
    channel by channel, R with X: a 45% mean error printed as a result (a walkthrough)."""
    rgb = tmp_path / "rgb.exr"
    write_image(rgb, read_image(MI / "mitsuba_xyz.exr", channels=["X", "Y", "Z"]))  # R,G,B channels
    xyz = str(MI / "mitsuba_xyz.exr")
    for args in (["--ref-channels", "X,Y,Z"], ["--channels", "R,G,B", "--ref-channels", "Z,Y,X"]):
        assert main(["diff", str(rgb), "-r", xyz, *args]) == 2
        err = capsys.readouterr().err
        assert "mitsuba_xyz.exr: its CIE X,Y,Z would be compared with the other image's R,G,B" in err
    assert main(["diff", xyz, "-r", str(rgb), "--channels", "X,Y,Z"]) == 2
    assert "mitsuba_xyz.exr: its CIE X,Y,Z" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["mitsuba_gaussian", "mitsuba_narrow_gaussian"])
def test_mitsuba_unequal_sample_weights_are_proved_by_the_moments(name, capsys):
    """Mitsuba's default gaussian filter was warned about (its neighbours' means correlated); one within the
    pixel (stddev 0.1) shares no sample, passed that test and understated the variances 3-10x (a red-team
    pass). Equally weighted non-negative samples give m2 <= n m1^2: both are refused by it."""
    with pytest.raises(InputFileError, match=r"m2_nested: pixel \(x \d+, y \d+\)'s second moment is [\d.]+ times its "
                                             r"squared mean, which 8 equally weighted .*rfilter box"):
        read_sample_dump(MI / f"{name}.exr", spp=8)
    assert main(["denoise", str(MI / f"{name}.exr"), "--spp", "8", "-o", "never.exr"]) == 2
    err = capsys.readouterr().err
    # Mitsuba's default filter named: "a gaussian narrower than a pixel" read as not the default's (a walkthrough).
    assert "weighted them unequally (any filter but box: Mitsuba's default gaussian too" in err
    read_sample_dump(MI / "mitsuba_box.exr", spp=8)  # filterwarnings=error: any warning fails


def test_an_spp_below_what_the_moments_hold_is_refused(tmp_path, capsys):
    """8-spp moments read as 2 spp had 4x the variance; a 16-spp file merged as 8 spp weighted its mean as half
    its samples. Some pixel of 8 samples has one nonzero sample: its moments need exactly 8."""
    for spp in (2, 7):
        with pytest.raises(InputFileError, match=r"is 8 times its squared mean, which %d equally" % spp):
            read_sample_dump(MI / "mitsuba_box.exr", spp=spp)
    with pytest.raises(InputFileError, match=r"m2_main: .* is 16\.0\d* times .* which 8 equally"):  # HALF, 16 spp
        read_sample_dump(MI / "mitsuba_half_aov.exr", spp=8)
    read_sample_dump(MI / "mitsuba_half_aov.exr", spp=16)  # its rounding (16.01) is not a sample more
    out = tmp_path / "merged.exr"
    assert main(["merge", str(MI / "mitsuba_aov_position.exr"), str(MI / "mitsuba_half_aov.exr"), "--spp", "8",
                 "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mitsuba_half_aov.exr: m2_main" in err[0] and not out.exists()


def test_moments_of_one_sample_read_as_more_are_warned_about():
    """A 1-spp film read with spp 8: every variance exactly 0, every pixel "converged", no word."""
    with pytest.warns(InputFileWarning, match="every pixel's samples agree exactly .* counted 8 per pixel"):
        dump = read_sample_dump(MI / "mitsuba_spp1.exr", spp=8)
    buffer = dump.buffer  # m2 - m1^2 to float32's rounding (spread over R, G, B by the XYZ conversion)
    assert (buffer.variance.sum(axis=-1) <= 1e-5 * (buffer.mean**2).sum(axis=-1)).all()
    read_sample_dump(MI / "mitsuba_spp1.exr", spp=1)  # no warning


def test_the_filter_correlation_still_warns_where_the_moments_cannot_tell(tmp_path):
    """A per-sample variance of the user's own is no moment: the bound does not apply, the neighbours' test does."""
    planes = _channels(MI / "mitsuba_gaussian.exr")
    own = {f"myvar.{c}": np.maximum(planes[f"m2_nested.{c}"] - planes[f"nested.{c}"] ** 2, 0) * 8 / 7
           for c in "XYZ"}
    path = tmp_path / "gaussian_with_variance.exr"
    write_exr(path, {k: v.astype(np.float32) for k, v in (planes | own).items()})
    with pytest.warns(InputFileWarning, match="film filter is probably not 'box'"):
        read_sample_dump(path, spp=8, color="nested", variance="myvar")


def test_mitsuba_info_without_spp_and_denoise_asks_for_it(tmp_path, capsys):
    assert main(["info", str(MI / "mitsuba_box.exr")]) == 0
    assert "--spp N" in capsys.readouterr().out
    assert main(["denoise", str(MI / "mitsuba_box.exr"), "-o", str(tmp_path / "o.exr")]) == 2
    assert "spp" in capsys.readouterr().err
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.skipif(importlib.util.find_spec("mitsuba") is None, reason="needs the 'mitsuba' extra")
def test_mitsuba_fresh_renders_variance_matches_seed_spread(tmp_path):
    subprocess.run([sys.executable, str(GEN / "mitsuba_files.py"), str(tmp_path), "--seeds", "1:12", "mitsuba_box"],
                   check=True, capture_output=True)
    files = sorted(tmp_path.glob("mitsuba_box_seed_*.exr"))
    bufs = [read_sample_dump(f, spp=8).buffer for f in files]
    measured = np.var([b.mean for b in bufs], axis=0, ddof=1)
    predicted = np.mean([b.variance for b in bufs], axis=0) / 8
    ratio = measured.sum(axis=(0, 1)) / predicted.sum(axis=(0, 1))
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio


# ---------------------------------------------------------------- Blender Cycles

def test_cycles_prefers_noisy_image():
    with pytest.warns(InputFileWarning, match="same count"):
        dump = read_sample_dump(CY / "cycles_default.exr", variance="ViewLayer.Denoising Albedo")
    ch = _channels(CY / "cycles_default.exr")
    np.testing.assert_array_equal(dump.buffer.mean[..., 0], ch["ViewLayer.Noisy Image.R"])
    assert not np.array_equal(ch["ViewLayer.Noisy Image.R"], ch["ViewLayer.Combined.R"])


def test_cycles_count_scale_is_the_samples_rendered():
    """Asked for 512, converged early: bit-identical to a render asking for exactly 304."""
    a, b = _channels(CY / "cycles_converged.exr"), _channels(CY / "cycles_converged_304.exr")
    assert all(np.array_equal(a[k], b[k]) for k in a)
    dump = read_sample_independent = read_sample_dump(CY / "cycles_converged.exr", variance="ViewLayer.Combined")
    assert dump.buffer.count.max() == 304  # header says 512
    np.testing.assert_array_equal(dump.buffer.count, np.rint(a["ViewLayer.Debug Sample Count.X"] * 304))
    del read_sample_independent


@pytest.mark.parametrize(("name", "spp", "divisor"), [("cycles_converged.exr", 512, 304),
                                                     ("cycles_time_limit.exr", 4096, 3856)])
def test_an_spp_the_count_pass_contradicts_is_refused(name, spp, divisor):
    """The samples asked for in Blender, given as --spp where the render stopped early: the normalised counts
    times it were within the 1% then allowed of whole numbers, and every count came out up to 1.68x too high
    without a word (a walkthrough). The pass's own divisor is named; a multiple of it still reads."""
    with pytest.raises(InputFileError, match=f"normalised counts times {spp} are not whole numbers "
                                             rf"\(the pass's own divisor: {divisor}\)"):
        read_sample_dump(CY / name, variance="ViewLayer.Combined", spp=spp)
    assert read_sample_dump(CY / name, variance="ViewLayer.Combined", spp=divisor).buffer.count.max() == divisor


def test_cycles_counts_of_a_render_off_the_checks_grid():
    """Asked for 100 samples (checks at 16, ..., 96), most pixels converged at 48 and 26 ran to 100:
    the finest count difference (96 to 100) is not a check's step, and the counts were read as
    12..25, a quarter of the truth, with a note only (a red-team pass, on Blender 5's file)."""
    counts = _channels(CY / "cycles_adaptive_100.exr")["ViewLayer.Debug Sample Count.X"]
    dump = read_sample_dump(CY / "cycles_adaptive_100.exr", variance="ViewLayer.Combined")
    np.testing.assert_array_equal(dump.buffer.count, np.rint(counts * 100))
    assert dump.buffer.count.max() == 100 and (dump.buffer.count[dump.buffer.count < 100] % 16 == 0).all()
    assert any("ran to the end of the render: 100 samples" in note for note in dump.notes)


def test_cycles_counts_off_the_grid_without_the_requested_samples_are_ambiguous(tmp_path):
    """The same file without cycles.ViewLayer.samples (a tool that dropped the header): 100 samples with pixels
    stopped at 16, ..., 96 and 100 also fit 400 with pixels stopped at 64, ..., 384 and 400, and the counts were read
    as 400 at the top, 4x the truth, with a note only (an attack pass). Refused naming both; --spp reads it."""
    from awr_denoise.io.cycles import sample_count_scale

    with OpenEXR.File(str(CY / "cycles_adaptive_100.exr"), separate_channels=True) as f:
        parts = [(dict(f.header(i)), {k: c.pixels.copy() for k, c in f.channels(i).items()})
                 for i in range(len(f.parts))]
    assert any("cycles.ViewLayer.samples" in header for header, _ in parts)
    for header, _ in parts:
        header.pop("cycles.ViewLayer.samples", None)
        header.pop("channels", None)
    bare = tmp_path / "bare.exr"
    if len(parts) == 1:
        OpenEXR.File(*parts[0]).write(str(bare))
    else:
        OpenEXR.File([OpenEXR.Part(h, c, str(h.get("name", i))) for i, (h, c) in enumerate(parts)]).write(str(bare))
    with pytest.raises(InputFileError, match=r"fit 400 samples rendered .* and 100 .* pass spp="):
        read_sample_dump(bare, variance="ViewLayer.Combined")
    counts = read_sample_dump(bare, variance="ViewLayer.Combined", spp=100).buffer.count
    np.testing.assert_array_equal(counts, read_sample_dump(CY / "cycles_adaptive_100.exr",
                                                           variance="ViewLayer.Combined").buffer.count)
    # On the grid both readings agree: no refusal without the header (S = 256, pixels at 48, 64 and 256).
    assert sample_count_scale(np.array([48, 64, 256]) / 256, None)[0] == 256


def test_cycles_denoising_passes_with_the_denoiser_off_are_not_called_denoised():
    """The denoiser off with its passes stored (what ``--guide`` needs) was warned about as "Combined
    is already denoised": Blender 5 writes Noisy Image whenever its denoiser runs (cycles_default),
    so denoising passes without it mean the denoiser was off (a red-team pass)."""
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*denois", category=InputFileWarning)
        dump = read_sample_dump(CY / "cycles_features.exr", variance="ViewLayer.Combined", spp=16)
    assert set(dump.buffer.features) == {"albedo", "normal", "depth"}
    assert any("the denoiser was off" in note for note in dump.notes)
    combined = _channels(CY / "cycles_features.exr")
    np.testing.assert_array_equal(dump.buffer.mean[..., 0], combined["ViewLayer.Combined.R"])


def test_cycles_time_limit_counts_consistent():
    buf = read_sample_dump(CY / "cycles_time_limit.exr", variance="ViewLayer.Combined").buffer
    assert buf.count.max() <= 4096 and (buf.count % 16 == 0).all() and buf.count.min() >= 64


def test_cycles_layer_with_dot_stereo_and_missing_count():
    with pytest.warns(InputFileWarning, match="same count"):
        assert read_sample_dump(CY / "cycles_layer_dot.exr", variance="beauty.main.Combined").buffer.shape == (32, 32)
    with pytest.raises(InputFileError, match="several views .left, right."):
        read_sample_dump(CY / "cycles_stereo.exr", variance="ViewLayer.Combined")
    with pytest.warns(InputFileWarning, match="no sample count pass"):
        left = read_sample_dump(CY / "cycles_stereo.exr", variance="ViewLayer.Combined", view="left").buffer
    with pytest.warns(InputFileWarning):
        right = read_sample_dump(CY / "cycles_stereo.exr", variance="ViewLayer.Combined", view="right").buffer
    assert not np.array_equal(left.mean, right.mean)
    with pytest.warns(InputFileWarning, match="no sample count pass"):
        read_sample_dump(CY / "cycles_adaptive_nocount.exr", variance="ViewLayer.Combined")


@pytest.mark.parametrize("path", [MI / "mitsuba_box.exr", DATA / "pbrt" / "pbrt_gbuffer_default.exr"],
                         ids=["mitsuba", "pbrt"])
def test_layer_on_a_file_without_view_layers_is_refused(path, tmp_path, capsys):
    # Ignored, layer= would read the file's only colour while the user asked for another layer.
    with pytest.raises(InputFileError, match=f"{path.name}: layer='beauty' / --layer: only Blender Cycles"):
        read_sample_dump(path, layer="beauty")
    out = tmp_path / "dump.exr"
    assert main(["denoise", str(path), "-o", str(out), "--layer", "beauty", "-q"]) == 2
    assert not out.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "only Blender Cycles files have view layers" in err[0]
    # A Cycles file keeps its layer (the file's only one, named).
    assert read_sample_dump(CY / "cycles_default.exr", layer="ViewLayer", variance="ViewLayer.Combined",
                            spp=16).buffer.shape


def test_layer_on_independent_renders_without_view_layers_is_refused():
    files = [MI / "mitsuba_box.exr", MI / "mitsuba_gaussian.exr"]
    with pytest.raises(InputFileError, match="only Blender Cycles files have view layers"):
        read_independent_renders(files, layer="ViewLayer")


def test_cycles_independent_renders_merged_and_denoised(tmp_path):
    files = sorted(CY.glob("cycles_seed_*.exr"))
    with pytest.warns(InputFileWarning):
        dump = read_independent_renders(files)
    buf = dump.buffer
    assert (buf.count == 8 * 16).all() and buf.variance_known.all()
    means = np.array([read_image(f)[..., :3] for f in files], dtype=np.float64)
    np.testing.assert_allclose(buf.mean, means.mean(0), rtol=1e-6)
    np.testing.assert_allclose(buf.variance, means.var(0, ddof=1) * 16, rtol=1e-6)
    out = tmp_path / "merged.exr"
    assert main(["merge", "--independent", *map(str, files), "-o", str(out), "-q"]) == 0
    assert main(["denoise", str(out), "-o", str(tmp_path / "d.exr"), "-q"]) == 0


def test_cycles_independent_renders_denoised_beat_mean():
    """Every way of merging four of the eight 16-spp Cycles renders (70 buffers): on average the
    default reconstruction's MSE against the 2048-spp reference is below the plain mean's.

    One buffer is no fair test: the mean of all eight renders happens to be 6.7x closer to the
    reference than their own spread predicts (7.1e-4), and the default's MSE there is 1.06x the
    mean's. Stage 1 alone, the previous default, is 1.9x the mean's on average (6x on all eight):
    it smooths the glossy sphere's highlight, which the Wiener stages and the guard keep."""
    files = sorted(CY.glob("cycles_seed_*.exr"))
    plain = denoised = paper = 0.0
    ref = read_image(CY / "cycles_ref.exr")[..., :3].astype(np.float64)
    for subset in itertools.combinations(files, 4):
        with pytest.warns(InputFileWarning):
            buf = read_independent_renders(list(subset)).buffer
        plain += np.mean((buf.mean - ref) ** 2)
        denoised += np.mean((reconstruct(buf) - ref) ** 2)
        paper += np.mean((reconstruct(buf, stages=1) - ref) ** 2)
    assert denoised < 0.95 * plain
    assert paper > 1.5 * plain


@pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs the 'blender' extra (bpy)")
def test_cycles_fresh_renders(tmp_path):
    """Render with Blender: early convergence checked against a render of exactly the derived
    count, and the independent-render variance against the spread of group means."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import cycles_files as cf; from pathlib import Path; "
            "out = Path(sys.argv[2]); n = sys.argv[3]; s = int(sys.argv[4]); "
            "cf.render('cycles_converged', out, samples=s).rename(out / n)")
    run = lambda name, samples: subprocess.run([sys.executable, "-c", code, str(GEN), str(tmp_path), name, str(samples)],  # noqa: E731
                                               check=True, capture_output=True)
    run("a.exr", 512)
    s = int(read_sample_dump(tmp_path / "a.exr", variance="ViewLayer.Combined").buffer.count.max())
    run("b.exr", s)
    a, b = _channels(tmp_path / "a.exr"), _channels(tmp_path / "b.exr")
    assert all(np.array_equal(a[k], b[k]) for k in a)
    subprocess.run([sys.executable, str(GEN / "cycles_files.py"), str(tmp_path), *[f"cycles_seed_{k}" for k in range(1, 9)]],
                   check=True, capture_output=True)
    files = sorted(tmp_path.glob("cycles_seed_*.exr"))
    with pytest.warns(InputFileWarning):
        halves = [read_independent_renders(files[:4]).buffer, read_independent_renders(files[4:]).buffer]
    measured = (halves[0].mean - halves[1].mean) ** 2 / 2
    predicted = (halves[0].variance_of_mean() + halves[1].variance_of_mean()) / 2
    ratio = measured.sum() / predicted.sum()
    assert 0.6 < ratio < 1.6, ratio


def test_diff_reads_a_cycles_layer_with_channels(capsys):
    """A Blender multilayer file has several layers with R,G,B: ``awr diff`` names the choice in its own
    terms, and ``--channels ViewLayer.Combined`` (a layer) or a list of names reads it."""
    image, ref = str(CY / "cycles_default.exr"), str(CY / "cycles_ref.exr")
    assert main(["diff", image, "-r", ref]) == 2
    assert "awr diff --channels" in capsys.readouterr().err
    assert main(["diff", image, "-r", ref, "--channels", "ViewLayer.Combined", "--json"]) == 0
    by_layer = capsys.readouterr().out
    names = ",".join(f"ViewLayer.Combined.{c}" for c in "RGB")
    assert main(["diff", image, "-r", ref, "--channels", names, "--json"]) == 0
    assert capsys.readouterr().out == by_layer
    assert main(["diff", image, "-r", ref, "--channels", "ViewLayer.Nope"]) == 2
    assert "ViewLayer.Nope: neither a channel nor a layer" in capsys.readouterr().err
    assert main(["diff", image, "-r", ref, "--channels", f"{names},ViewLayer.Combined.R"]) == 2
    assert "names a channel twice" in capsys.readouterr().err
    # The multilayer file as the reference: the hint names the reference's option, which reads it.
    assert main(["diff", image, "-r", image, "--channels", "ViewLayer.Combined"]) == 2
    assert "--ref-channels" in capsys.readouterr().err
    assert main(["diff", image, "-r", image, "--channels", "ViewLayer.Combined", "--ref-channels",
                 "ViewLayer.Combined", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["mse"] == 0.0
    # A layer in a later part (Blender writes one part per pass) was "neither a channel nor a layer".
    noisy = ",".join(f"ViewLayer.Noisy Image.{c}" for c in "RGB")
    assert main(["diff", image, "-r", ref, "--channels", noisy, "--ref-channels", "ViewLayer.Combined",
                 "--json"]) == 0
    spelled = capsys.readouterr().out
    assert main(["diff", image, "-r", ref, "--channels", "ViewLayer.Noisy Image", "--ref-channels",
                 "ViewLayer.Combined", "--json"]) == 0
    assert capsys.readouterr().out == spelled
    # A stereo reference: one view of it (there was no way to compare against one).
    stereo, layer = str(CY / "cycles_stereo.exr"), ["--channels", "ViewLayer.Combined", "--ref-channels",
                                                    "ViewLayer.Combined"]
    assert main(["diff", stereo, "-r", stereo, *layer]) == 2
    assert "choose one with view=; awr diff: --view, --ref-view" in capsys.readouterr().err
    assert main(["diff", stereo, "-r", stereo, *layer, "--view", "left", "--ref-view", "left", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["mse"] == 0.0
    assert main(["diff", stereo, "-r", stereo, *layer, "--view", "left", "--ref-view", "right", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["mse"] > 0


def test_two_black_renders_are_not_taken_for_one(tmp_path):
    """Means all 0 have signed sums of 0 whatever their samples: two renders with means of 0 (their spreads apart)
    are not refused as one render up to rounding (equal bytes still are, by the copy check)."""
    from awr_denoise import SampleBuffer
    from awr_denoise.io import write_sample_buffer

    for k in (1, 2):
        write_sample_buffer(tmp_path / f"b{k}.exr", SampleBuffer.from_moments(np.full((4, 4), 4), np.zeros((4, 4, 3)),
                                                                             np.full((4, 4, 3), 0.01 * k)))
    assert main(["merge", str(tmp_path / "b1.exr"), str(tmp_path / "b2.exr"), "-o", str(tmp_path / "m.exr"),
                 "-q"]) == 0


def test_a_moment_named_as_the_colour_is_named_as_a_moment():
    """``--color m2_a`` was refused as "m2_m2_a: no second moment channel(s)", a name the user never gave."""
    with pytest.raises(InputFileError, match=r"mitsuba_two\.exr: m2_a: a second moment, named as the colour; give its "
                                             r"mean plane \(a\)$"):
        read_sample_dump(MI / "mitsuba_two.exr", spp=8, color="m2_a")
