"""Feature planes of real renderer files (pbrt-v4 GBufferFilm, Blender Cycles, Mitsuba 3 ``aov``).

The files in tests/data were written by the renderers (tests/data/generate/*.py; pbrt-v4's are
the project's fixtures). Each test checks what the renderer documents or what its source does.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.exr
OpenEXR = pytest.importorskip("OpenEXR")

from awr_denoise.errors import InputFileError, InputFileWarning  # noqa: E402
from awr_denoise.features import FEATURE_NAMES  # noqa: E402
from awr_denoise.io import read_sample_buffer, read_sample_dump, write_image, write_sample_buffer  # noqa: E402

DATA = Path(__file__).parent.parent / "data"
PBRT = DATA / "pbrt" / "pbrt_gbuffer_default.exr"
PBRT32 = DATA / "pbrt" / "pbrt_gbuffer_fp32.exr"
CYCLES = DATA / "cycles" / "cycles_default.exr"
MITSUBA = DATA / "mitsuba" / "mitsuba_aov.exr"
# Cycles writes no variance; any plane of the right size serves for reading the features.
CYCLES_VARIANCE = f"{CYCLES}:ViewLayer.Noisy Image"
HALF = 2e-3   # pbrt's default file stores HALF: unit normals are unit to about 1e-3


def _read(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the readers' notes about counts are not under test here
        return read_sample_dump(path, **kw)


@pytest.mark.parametrize("path, tolerance", [(PBRT, HALF), (PBRT32, 1e-5)])
def test_pbrt_gbuffer_albedo_normal_and_depth(path, tolerance):
    dump = _read(path)
    buffer = dump.buffer
    assert tuple(buffer.features) == FEATURE_NAMES
    assert {"albedo: Albedo (no variance in the file)", "normal: Ns (no variance in the file)",
            "depth: P.Z (no variance in the file)"} <= set(dump.notes)
    albedo, normal, depth = (buffer.features[n] for n in FEATURE_NAMES)
    z = depth.mean[..., 0]
    hit = z > 0
    # The sky fills the top of the frame; P.Z is camera-space z (pbrt looks down +z): positive.
    assert 0.2 < hit.mean() < 0.9 and z.min() == 0
    assert albedo.mean.min() >= 0 and albedo.mean.max() <= 1
    length = np.linalg.norm(normal.mean, axis=2)
    # GBufferFilm writes normalised normals; a miss writes 0 for all three features.
    np.testing.assert_allclose(length[hit], 1.0, atol=tolerance)
    assert (length[~hit] == 0).all() and (albedo.mean[~hit] == 0).all()
    # Camera-space normals of surfaces facing the camera point back along -z.
    assert (normal.mean[hit][:, 2] <= tolerance).all()
    for feature in (albedo, normal, depth):
        np.testing.assert_array_equal(feature.count, buffer.count)
        assert not feature.variance_known.any()   # pbrt writes no spread of its features


def test_cycles_denoising_passes():
    dump = _read(CYCLES, variance=CYCLES_VARIANCE)
    albedo, normal, depth = (dump.buffer.features[n] for n in FEATURE_NAMES)
    assert "albedo: ViewLayer.Denoising Albedo (no variance in the file)" in dump.notes
    z = depth.mean[..., 0]
    length = np.linalg.norm(normal.mean, axis=2)
    # Where the camera sees the world, Cycles writes depth 0 and normal 0.
    world = z == 0
    assert 0.1 < world.mean() < 0.5 and (length[world] == 0).all()
    assert z.min() >= 0
    # Normals are averaged, not normalised: at most unit length, unit on the diffuse surfaces.
    assert length.max() <= 1 + 1e-6 and (length[~world] > 0.999).mean() > 0.6
    # The glossy sphere: Cycles waits for the next bounce, and where that reaches the world the
    # normal stays 0 and the albedo takes the world's colour, which may exceed 1.
    assert albedo.mean.min() >= 0
    assert (albedo.mean.max(axis=2) <= 1)[length > 0].all()
    assert ((length == 0) & ~world).any()


def test_mitsuba_aov_features_have_exact_variances():
    dump = _read(MITSUBA, spp=8)
    buffer = dump.buffer
    assert buffer.channels == ("R", "G", "B") and "normal: main.normal (variance from m2_main.normal)" in dump.notes
    albedo, normal, depth = (buffer.features[n] for n in FEATURE_NAMES)
    assert albedo.variance_known.all() and depth.variance_known.all()
    hit = depth.mean[..., 0] > 0
    assert hit.mean() > 0.95   # the Cornell box fills the frame
    assert albedo.mean.min() >= 0 and albedo.mean.max() <= 1
    # Per-sample normals are unit vectors: their pixel mean is at most 1, and exactly 1 with no
    # spread (a pixel inside one wall).
    length = np.linalg.norm(normal.mean, axis=2)
    assert length.max() <= 1 + 1e-5
    still = normal.variance.sum(axis=2) < 1e-8
    assert still.mean() > 0.5
    np.testing.assert_allclose(length[still & hit], 1.0, atol=1e-5)
    # The spread is where the features change: edges between walls and objects.
    spread = albedo.variance.sum(axis=2) > 1e-6
    assert 0 < spread.mean() < 0.5


@pytest.mark.parametrize(("path", "kw", "albedo", "normal"), [
    (PBRT, {}, "Albedo", "Ns"), (MITSUBA, {"spp": 8}, "main.albedo", "main.normal"),
    (CYCLES, {"variance": CYCLES_VARIANCE}, "ViewLayer.Denoising Albedo", "ViewLayer.Denoising Normal")])
def test_a_normal_read_as_the_albedo_is_said_to_be_negative(path, kw, albedo, normal):
    """Each renderer's own albedo is read without a word; its normal given as the albedo (``--alb FILE:Ns``), which
    OIDN would take clipped to [0, 1], is said to be negative (44-63% of the pixels in these files)."""
    for given, said in ((None, False), (f"{path}:{normal}", True)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            read_sample_dump(path, **kw, **({} if given is None else {"albedo": given}))
        told = [w for w in caught if issubclass(w.category, InputFileWarning) and re.fullmatch(
            rf"{re.escape(str(path))}: {normal} as the albedo: \d+% of its pixels hold a component below -0.1, "
            r"where an albedo is a reflectance: a normal or a position, or a pixel filter with negative lobes\?",
            str(w.message))]
        assert len(told) == said, [str(w.message) for w in caught]


@pytest.mark.parametrize(("path", "kw", "albedo"), [
    (PBRT, {}, "Albedo"), (MITSUBA, {"spp": 8}, "main.albedo"), (CYCLES, {"variance": CYCLES_VARIANCE},
                                                               "ViewLayer.Denoising Albedo")])
def test_an_albedo_read_as_the_normal_is_said_to_be_too_long(path, kw, albedo):
    """Each renderer's own normal is read without a word; its albedo given as the normal (``--nrm FILE:Albedo``) is
    read, since a dark albedo cannot be told from averaged normals, but said to be too long to be one (16-59% of
    the pixels past length 1.05 in these files)."""
    for normal, said in ((None, False), (f"{path}:{albedo}", True)):
        with warnings.catch_warnings(record=True) as caught:  # the readers' notes about counts beside it
            warnings.simplefilter("always")
            read_sample_dump(path, **kw, **({} if normal is None else {"normal": normal}))
        told = [w for w in caught if issubclass(w.category, InputFileWarning) and re.fullmatch(
            rf"{re.escape(str(path))}: {albedo} as the normal: \d+% of its pixels are longer than 1.05, where a normal "
            r"is a mean of unit vectors \(length at most 1\): an albedo or a colour, normals encoded in \[0, 1\], or a "
            r"pixel filter with negative lobes\?",
            str(w.message))]
        assert len(told) == said, [str(w.message) for w in caught]


def test_features_written_in_the_dump_layout_and_read_back(tmp_path):
    buffer = _read(MITSUBA, spp=8).buffer
    write_sample_buffer(tmp_path / "dump.exr", buffer)
    back = read_sample_buffer(tmp_path / "dump.exr")
    for name in FEATURE_NAMES:
        np.testing.assert_allclose(back.features[name].mean, buffer.features[name].mean, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(back.features[name].variance, buffer.features[name].variance, rtol=1e-6,
                                   atol=1e-7)
        np.testing.assert_array_equal(back.features[name].variance_known, buffer.features[name].variance_known)
    pbrt = _read(PBRT).buffer
    write_sample_buffer(tmp_path / "pbrt.exr", pbrt)
    assert not read_sample_buffer(tmp_path / "pbrt.exr").features["normal"].variance_known.any()


def test_planes_given_override_and_whole_files_are_read(tmp_path):
    pbrt = _read(PBRT).buffer
    # oidnDenoise's way: the albedo in an image file of its own (R, G, B).
    write_image(tmp_path / "alb.exr", np.full(pbrt.shape + (3,), 0.25))
    given = _read(PBRT, albedo=str(tmp_path / "alb.exr"), normal=f"{PBRT}:N").buffer
    np.testing.assert_array_equal(given.features["albedo"].mean, 0.25)
    np.testing.assert_array_equal(given.features["depth"].mean, pbrt.features["depth"].mean)
    only = _read(PBRT, features=None, depth=f"{PBRT}:dzdx").buffer
    assert tuple(only.features) == ("depth",)
    assert _read(PBRT, features=None).buffer.features == {}
    # A dump takes planes too (features added to those it holds).
    write_sample_buffer(tmp_path / "d.exr", pbrt)
    dump = _read(tmp_path / "d.exr", albedo=str(tmp_path / "alb.exr")).buffer
    assert (dump.features["albedo"].mean == 0.25).all() and "normal" in dump.features
    # What it says of them is theirs: no note of the stand-in layout that found them ("no sample count in the
    # file", said of a dump that counts every pixel), no "no variance in the file" of a file that has one.
    write_image(tmp_path / "layers.exr", np.full(pbrt.shape + (3,), 0.5), channels=("a.R", "a.G", "a.B"))
    notes = read_sample_dump(tmp_path / "d.exr", albedo=f"{tmp_path / 'layers.exr'}:a").notes
    assert notes == ("albedo: a (given as a plane: its values, no variance)",), notes


@pytest.mark.parametrize("kw, message", [
    ({"albedo": "Nope"}, r"pbrt_gbuffer_default\.exr: Nope: no albedo channel"),
    ({"depth": "Albedo"}, r"Albedo: 3 channel\(s\), but depth has 1 \(Z\)"),
    ({"features": ["albedo", "normal"], "preset": "pbrt", "albedo": None}, None),
])
def test_bad_feature_planes_are_named(kw, message):
    if message is None:
        assert tuple(_read(PBRT, **kw).buffer.features) == FEATURE_NAMES
        return
    with pytest.raises(InputFileError, match=message):
        _read(PBRT, **kw)


@pytest.mark.parametrize("name, option", [("albedo", "--alb"), ("normal", "--nrm"), ("depth", "--depth")])
def test_the_input_itself_as_a_feature_file_is_refused(name, option):
    """``--alb INPUT.exr`` read the input's R,G,B, the radiance, as the albedo without a word (pbrt's colour
    reached 1.29 as an "albedo"); its own plane is named instead."""
    with pytest.raises(InputFileError, match=rf"pbrt_gbuffer_fp32\.exr: is the input itself: name its {name} plane "
                                             rf"\({name}='.*pbrt_gbuffer_fp32\.exr:PLANE', {option} "):
        _read(PBRT32, **{name: str(PBRT32)})
    named = _read(PBRT32, albedo=f"{PBRT32}:Albedo").buffer
    np.testing.assert_array_equal(named.features["albedo"].mean, _read(PBRT32).buffer.features["albedo"].mean)


def test_a_missing_required_feature_and_a_size_mismatch_are_named(tmp_path):
    with pytest.raises(InputFileError, match=r"mitsuba_box\.exr: normal: no normal plane known to the mitsuba "
                                             r"preset; name one \(normal= / --nrm\)"):
        _read(DATA / "mitsuba" / "mitsuba_box.exr", spp=8, features=["normal"])
    write_image(tmp_path / "small.exr", np.zeros((4, 4, 3)))
    with pytest.raises(InputFileError, match=r"small\.exr: R,G,B: size 4x4 does not match 64x64"):
        _read(PBRT, albedo=str(tmp_path / "small.exr"))
