"""Renderer presets and auto-detection, on small synthetic files written here with OpenEXR."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.exr
OpenEXR = pytest.importorskip("OpenEXR")

from awr_denoise.errors import InputFileError  # noqa: E402
from awr_denoise.errors import InputFileWarning  # noqa: E402
from awr_denoise.io import detect_preset, read_sample_buffer, read_sample_dump  # noqa: E402
from awr_denoise.io.colour import MITSUBA_XYZ_TO_SRGB, PBRT_XYZ_TO_SRGB  # noqa: E402
from awr_denoise.io.presets import parse_plane, plane_file  # noqa: E402

H, W = 4, 5


def _write(path, planes, header=None):
    with OpenEXR.File(dict(header or {}), planes) as f:
        f.write(str(path))
    return path


def _ramp(offset=0.0, dtype=np.float32):
    return (np.arange(H * W).reshape(H, W) / (H * W) + offset).astype(dtype)


def test_pbrt_gbuffer(tmp_path):
    var = {f"Variance.{c}": _ramp(0.1 * i, np.float16) for i, c in enumerate("RGB")}
    for v in var.values():
        v[0, 0] = 0  # environment-only pixel: pbrt's "unknown"
    planes = {c: _ramp(i, np.float16) for i, c in enumerate("RGB")} | var
    planes |= {"Albedo.R": _ramp(), "N.X": _ramp(), "RelativeVariance.R": _ramp(), "u": _ramp()}
    f = _write(tmp_path / "pbrt.exr", planes, {"samplesPerPixel": 16})
    assert detect_preset(list(planes), {}) == "pbrt"
    buf = read_sample_buffer(f)
    assert buf.channels == ("R", "G", "B")
    assert (buf.count == 16).all()
    np.testing.assert_allclose(buf.mean[..., 2], _ramp(2, np.float16), rtol=0)
    # Variance is pbrt's sensor XYZ: converted to sRGB with channels taken as fully correlated.
    sd = np.sqrt(np.stack([var[f"Variance.{c}"].astype(np.float64) for c in "RGB"], -1))
    np.testing.assert_allclose(buf.variance[1:], ((sd @ PBRT_XYZ_TO_SRGB.T) ** 2)[1:])
    assert not buf.variance_known[0, 0] and buf.variance_known[1:].all()
    # --spp overrides the header; without either the count is missing.
    assert (read_sample_buffer(f, spp=4).count == 4).all()
    g = _write(tmp_path / "nospp.exr", planes)
    with pytest.raises(InputFileError, match=r"nospp\.exr: .*samplesPerPixel"):
        read_sample_buffer(g)
    # A header count that is not a render's (whole, at least 1) is refused, not truncated or read as
    # "no samples" (which discarded the file's values).
    for bad in (16.7, -0.5, 0, "64.5"):
        h = _write(tmp_path / "badspp.exr", planes, {"samplesPerPixel": bad})
        with pytest.raises(InputFileError, match=r"badspp\.exr: samplesPerPixel: .*not a sample count"):
            read_sample_buffer(h)
    # Python's float() reads other scripts' digits and underscores: not a count a renderer wrote.
    for bad in ("\uff11\uff16", "1_6", "16 spp"):
        h = _write(tmp_path / "badspp.exr", planes, {"samplesPerPixel": bad})
        with pytest.raises(InputFileError, match=r"badspp\.exr: samplesPerPixel: header attribute is not a number"):
            read_sample_buffer(h)
    assert (read_sample_buffer(_write(tmp_path / "text.exr", planes, {"samplesPerPixel": " 16 "})).count == 16).all()


@pytest.mark.parametrize("layer", ["ViewLayer", "View Layer 2"])
def test_cycles_multilayer_normalised_counts(tmp_path, layer):
    samples = 64
    count = np.arange(H * W).reshape(H, W) % samples + 1
    planes = {f"{layer}.Combined.{c}": _ramp(i) for i, c in enumerate("RGBA")}
    planes[f"{layer}.Debug Sample Count.X"] = (count * np.float32(1.0 / samples)).astype(np.float32)
    planes[f"{layer}.Denoising Albedo.R"] = _ramp()
    planes |= {f"{layer}.Variance AOV.{c}": _ramp(0.5) for c in "RGB"}
    f = _write(tmp_path / "cycles.exr", planes, {f"cycles.{layer}.samples": str(samples)})
    assert detect_preset(list(planes), {}) == "cycles"
    with pytest.raises(InputFileError, match=r"cycles\.exr: .*Combined: Blender Cycles writes no variance pass"):
        read_sample_buffer(f)
    # The pass read is the one named: Noisy Image where the file has it (Blender's denoiser was on).
    planes |= {f"{layer}.Noisy Image.{c}": _ramp() for c in "RGB"}
    noisy = _write(tmp_path / "noisy.exr", planes, {f"cycles.{layer}.samples": str(samples)})
    with pytest.raises(InputFileError, match=rf"noisy\.exr: {layer}\.Noisy Image: Blender Cycles writes no variance"):
        read_sample_buffer(noisy)
    buf = read_sample_buffer(f, variance=f"{layer}.Variance AOV")
    np.testing.assert_array_equal(buf.count, count)
    assert buf.channels == ("R", "G", "B")  # alpha is not a colour channel
    np.testing.assert_array_equal(buf.mean[..., 1], _ramp(1))
    # A normalised count above 1 cannot come from Cycles (it divides by the samples taken): one such
    # pixel would rescale every pixel's count, so it is refused.
    stray = (count * np.float32(1.0 / samples)).astype(np.float32)
    stray[0, 0] = 2.0
    planes[f"{layer}.Debug Sample Count.X"] = stray
    g = _write(tmp_path / "stray.exr", planes, {f"cycles.{layer}.samples": str(samples)})
    with pytest.raises(InputFileError, match=r"stray\.exr: .*Debug Sample Count.X: .*reaches 2"):
        read_sample_buffer(g, variance=f"{layer}.Variance AOV")


def test_cycles_several_layers_need_a_choice(tmp_path):
    planes = {f"{layer}.Combined.{c}": _ramp() for layer in ("A", "B") for c in "RGB"}
    planes |= {f"A.Var.{c}": _ramp() for c in "RGB"}
    f = _write(tmp_path / "two.exr", planes, {"cycles.A.samples": "4", "cycles.B.samples": "4"})
    with pytest.raises(InputFileError, match="several view layers"):
        read_sample_buffer(f, variance="A.Var")
    with pytest.warns(InputFileWarning, match="no sample count pass"):
        assert (read_sample_buffer(f, variance="A.Var", layer="A").count == 4).all()


def test_renderman(tmp_path):
    n = np.full((H, W), 32, np.float32)
    planes = {f"Ci.{c}": _ramp(i) for i, c in enumerate("rgb")} | {"a": _ramp()}
    planes |= {f"mse.{c}": _ramp(0.01) for c in "rgb"} | {"sampleCount": n, "albedo.r": _ramp()}
    f = _write(tmp_path / "rman.exr", planes)
    assert detect_preset(list(planes), {}) == "renderman"
    buf = read_sample_buffer(f)
    assert (buf.count == 32).all()
    # mse is the variance of the pixel mean by default: per-sample variance = mse * n.
    np.testing.assert_allclose(buf.variance[..., 0], _ramp(0.01).astype(np.float64) * 32)
    np.testing.assert_allclose(read_sample_buffer(f, variance_kind="sample").variance[..., 0],
                               _ramp(0.01).astype(np.float64))


def test_mitsuba_moment(tmp_path):
    mean = _ramp(0.5)
    tint = {"X": 0.9, "Y": 1.0, "Z": 1.1}  # a colour: X, Y and Z differ
    means = {c: (mean * t).astype(np.float32) for c, t in tint.items()}
    m2s = {c: (means[c].astype(np.float64) ** 2 + 0.3).astype(np.float32) for c in "XYZ"}
    planes = {f"nested.{c}": means[c] for c in "XYZ"} | {f"m2_nested.{c}": m2s[c] for c in "XYZ"}
    f = _write(tmp_path / "mi.exr", planes)
    assert detect_preset(list(planes), {}) == "mitsuba"
    with pytest.raises(InputFileError, match=r"mi\.exr: .*no per-pixel sample count"):
        read_sample_buffer(f)
    buf = read_sample_buffer(f, spp=8)
    assert buf.channels == ("R", "G", "B") and (buf.count == 8).all()
    # The moments are CIE XYZ: the mean and the standard deviation go through Mitsuba's matrix.
    xyz = np.stack([means[c] for c in "XYZ"], -1).astype(np.float64)
    xyz_sd = np.sqrt((np.stack([m2s[c] for c in "XYZ"], -1).astype(np.float64) - xyz**2) * 8 / 7)
    np.testing.assert_allclose(buf.mean, xyz @ MITSUBA_XYZ_TO_SRGB.T, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(buf.variance, (xyz_sd @ MITSUBA_XYZ_TO_SRGB.T) ** 2, rtol=1e-5)


def test_mitsuba_mono_variant_is_luminance(tmp_path):
    # The mono variants write X = Y = Z (the luminance) in every moment: the XYZ matrix would tint
    # a grey value (R +20%, B -9% on a real Mitsuba render).
    mean = _ramp(0.5)
    m2 = (mean.astype(np.float64) ** 2 + 0.3).astype(np.float32)
    f = _write(tmp_path / "mono.exr", {f"nested.{c}": mean for c in "XYZ"} | {f"m2_nested.{c}": m2 for c in "XYZ"})
    dump = read_sample_dump(f, spp=8)
    assert dump.buffer.channels == ("Y",)
    np.testing.assert_allclose(dump.buffer.mean[..., 0], mean)
    np.testing.assert_allclose(dump.buffer.variance[..., 0], (m2 - mean.astype(np.float64) ** 2) * 8 / 7, rtol=1e-5)
    assert any("mono" in note for note in dump.notes)


def test_mitsuba_half_second_moment_underflow_is_unknown(tmp_path):
    # float16 moments of a dim render: E[x^2] = 0 beside a mean of 6e-6 (its square is below half's
    # smallest subnormal). Refused as "not E[x^2]" before; the variance is lost, not zero.
    mean = np.full((H, W), 6.25e-6, np.float16)
    m2 = np.zeros((H, W), np.float16)
    m2[0, 0] = mean[0, 0]  # one pixel with a second moment that survived
    mean[1, 1] = m2[1, 1] = 0  # a black pixel: known, no spread
    planes = {f"nested.{c}": mean * t for c, t in zip("XYZ", (0.9, 1.0, 1.1))} | {f"m2_nested.{c}": m2 for c in "XYZ"}
    f = _write(tmp_path / "dim.exr", planes)
    with pytest.warns(InputFileWarning, match=r"dim\.exr: m2_nested: .*underflowed HALF"):
        buf = read_sample_buffer(f, spp=8)
    expected = np.zeros((H, W), bool)
    expected[0, 0] = expected[1, 1] = True
    np.testing.assert_array_equal(buf.variance_known, expected)


def test_generic_multi_file(tmp_path):
    beauty = _write(tmp_path / "beauty.exr", {c: _ramp(i) for i, c in enumerate("RGB")})
    _write(tmp_path / "var.exr", {f"err.{c}": _ramp(0.2) for c in "RGB"})
    _write(tmp_path / "n.exr", {"n": np.full((H, W), 7, np.float32)})
    buf = read_sample_buffer(beauty, color="RGB", variance=f"{tmp_path / 'var.exr'}:err",
                             count=f"{tmp_path / 'n.exr'}:n", variance_kind="mean")
    assert (buf.count == 7).all()
    np.testing.assert_allclose(buf.variance[..., 0], _ramp(0.2).astype(np.float64) * 7)
    # --spp when there is no count plane
    assert (read_sample_buffer(beauty, color="RGB", variance=f"{tmp_path / 'var.exr'}:err", spp=3).count == 3).all()
    # ... and refused beside one, which it would be ignored for
    with pytest.raises(InputFileError, match=r"n\.exr: n: holds per-pixel sample counts; spp=3"):
        read_sample_buffer(beauty, color="RGB", variance=f"{tmp_path / 'var.exr'}:err",
                           count=f"{tmp_path / 'n.exr'}:n", spp=3)


def test_spp_is_refused_on_a_dump_that_has_its_counts(tmp_path):
    from awr_denoise import SampleBuffer
    from awr_denoise.io import write_sample_buffer

    dump = tmp_path / "d.exr"
    write_sample_buffer(dump, SampleBuffer.from_moments(np.full((H, W), 8), np.full((H, W, 3), 0.5),
                                                        np.full((H, W, 3), 0.04)))
    assert (read_sample_buffer(dump).count == 8).all()
    with pytest.raises(InputFileError, match=r"d\.exr: sampleCount: holds per-pixel sample counts; spp=3"):
        read_sample_buffer(dump, spp=3)


def test_generic_size_mismatch_names_second_file(tmp_path):
    beauty = _write(tmp_path / "beauty.exr", {c: _ramp(i) for i, c in enumerate("RGB")})
    _write(tmp_path / "small.exr", {f"v.{c}": np.ones((2, 2), np.float32) for c in "RGB"})
    with pytest.raises(InputFileError, match=r"small\.exr: v: size 2x2 does not match 5x4"):
        read_sample_buffer(beauty, color="RGB", variance=f"{tmp_path / 'small.exr'}:v", spp=4)


def test_generic_missing_plane(tmp_path):
    beauty = _write(tmp_path / "beauty.exr", {c: _ramp(i) for i, c in enumerate("RGB")})
    with pytest.raises(InputFileError, match=r"beauty\.exr: nope: no variance channel"):
        read_sample_buffer(beauty, color="RGB", variance="nope", spp=4)


def test_unknown_preset_rejected(tmp_path):
    with pytest.raises(ValueError, match="preset"):
        read_sample_buffer(tmp_path / "x.exr", preset="vray")


def test_uint_count_plane_read_exactly(tmp_path):
    # OpenImageIO would normalise a UINT channel read as float; the readers keep it exact.
    beauty = _write(tmp_path / "b.exr", {c: _ramp(i) for i, c in enumerate("RGB")}
                    | {f"v.{c}": _ramp() for c in "RGB"} | {"n": np.full((H, W), 3_000_000, np.uint32)})
    assert (read_sample_buffer(beauty, color="RGB", variance="v", count="n").count == 3_000_000).all()


def test_a_feature_file_whose_name_holds_a_colon_is_read_whole(tmp_path, monkeypatch):
    """``--alb take:2.exr``: a file of that whole name is the file (it was read as plane ``2.exr`` of
    the input); ``beauty.exr:Albedo`` stays a plane of a file when no file has the whole name."""
    from pathlib import Path

    from awr_denoise import SampleBuffer
    from awr_denoise.io import read_sample_dump, write_image, write_sample_buffer
    from awr_denoise.io.presets import feature_plane_file

    monkeypatch.chdir(tmp_path)
    write_sample_buffer("d.exr", SampleBuffer.from_moments(np.full((4, 4), 2), np.ones((4, 4, 3)), np.ones((4, 4, 3))))
    write_image("take:2.exr", np.full((4, 4, 3), 0.25))
    assert feature_plane_file("take:2.exr") == Path("take:2.exr")
    assert feature_plane_file("beauty.exr:Albedo") == Path("beauty.exr")
    albedo = read_sample_dump("d.exr", albedo="take:2.exr").buffer.features["albedo"]
    np.testing.assert_array_equal(albedo.mean, np.full((4, 4, 3), 0.25))


def _parts_file(path, parts):
    """A multi-part EXR written by OpenEXR itself: ``parts`` is [(header, planes)]."""
    import OpenEXR

    base = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    written = [OpenEXR.Part({**base, **header}, {k: np.array(v) for k, v in planes.items()}, name=f"part{i}")
               for i, (header, planes) in enumerate(parts)]  # copies: the binding turns the values into Channels
    with OpenEXR.File(written) as f:
        f.write(str(path))
    return path


def _awr_planes(tmp_path, scale=1.0):
    import OpenEXR

    from awr_denoise.buffers import SampleBuffer
    from awr_denoise.io import write_sample_buffer

    rng = np.random.default_rng(5)
    write_sample_buffer(tmp_path / "one.exr", SampleBuffer.from_moments(np.full((6, 8), 4), rng.random((6, 8, 3)),
                                                                       rng.random((6, 8, 3)) * 0.1), overwrite=True)
    with OpenEXR.File(str(tmp_path / "one.exr"), separate_channels=True) as f:
        header = {k: v for k, v in f.header().items() if k.startswith("awr:")}
        planes = {k: v.pixels * np.float32(scale) if k in "RGB" else v.pixels.copy() for k, v in f.channels().items()}
    return header, planes


def test_the_view_asked_for_is_the_one_read_from_an_awr_dump(tmp_path):
    """``--view right`` on a two-view awr dump read the left view's samples, exit 0 (red-team pass 5)."""
    from awr_denoise.io import read_sample_dump

    header, left = _awr_planes(tmp_path)
    _, right = _awr_planes(tmp_path, scale=10.0)
    path = _parts_file(tmp_path / "stereo.exr", [({**header, "view": "left"}, left),
                                                 ({**header, "view": "right"}, right)])
    means = {view: read_sample_dump(path, view=view).buffer.mean for view in ("left", "right")}
    np.testing.assert_allclose(means["right"], means["left"] * 10, rtol=1e-6)
    with pytest.raises(InputFileError, match="several views"):
        read_sample_dump(path)
    two = _parts_file(tmp_path / "two.exr", [(header, left), (header, right)])  # two sample parts, no views
    with pytest.raises(InputFileError, match=r"is in several parts \(0 and 1\)"):  # its channels, each twice
        read_sample_dump(two)


def test_an_awr_dump_split_into_parts_is_named_so(tmp_path):
    """A pipeline tool split a dump, means and counts in one part and variances in another (oiiotool --siappend):
    refused as "variance.R: missing", though the file holds it (an attack pass); the line now says where it is."""
    from awr_denoise.io import read_sample_dump

    header, planes = _awr_planes(tmp_path)
    variances = {k: v for k, v in planes.items() if k.startswith("variance.")}
    rest = {k: v for k, v in planes.items() if k not in variances}
    path = _parts_file(tmp_path / "split.exr", [(header, rest), ({}, variances)])
    with pytest.raises(InputFileError, match=r"split.exr: variance.B: in another part than sampleCount: an awr dump "
                                             r"keeps its channels in one part"):
        read_sample_dump(path)


def test_parts_with_another_data_window_are_refused(tmp_path):
    """The samples in part 1 at (0, 0), an image in part 0 at (100, 200): the outputs took part 0's
    window, placing the denoised pixels elsewhere, exit 0 (red-team pass 5)."""
    from awr_denoise.io import read_image, read_sample_dump

    header, planes = _awr_planes(tmp_path)
    h, w = planes["R"].shape
    preview = {"preview." + c: planes[c] for c in "RGB"}
    path = _parts_file(tmp_path / "w.exr", [({"dataWindow": ((100, 200), (100 + w - 1, 200 + h - 1))}, preview),
                                            ({**header, "dataWindow": ((0, 0), (w - 1, h - 1))}, planes)])
    with pytest.raises(InputFileError, match="part 1's data window differs from the first part's"):
        read_sample_dump(path)
    with pytest.raises(InputFileError, match="R: its part's data window differs"):
        read_image(path)
    stereo = _parts_file(tmp_path / "s.exr", [({"view": "left"}, {c: planes[c] for c in "RGB"}),
                                              ({"view": "right"}, {c: planes[c] * 10 for c in "RGB"})])
    with pytest.raises(InputFileError, match=r"R: is in several parts \(views left, right: choose one with view=; "
                                         r"awr diff: --view, --ref-view\)"):
        read_image(stereo)  # it took the first view
    np.testing.assert_array_equal(read_image(stereo, view="right"), 10 * read_image(stereo, view="left"))
    with pytest.raises(InputFileError, match=r"s\.exr: no view 'centre' \(views: left, right\)"):
        read_image(stereo, view="centre")
    # One part holding both views (OpenEXR's multiView: the first view's channels bare, right.R...):
    # --view right was "no view 'right'", and without a view the left one was read silently (a review).
    import OpenEXR

    one = tmp_path / "one.exr"
    with OpenEXR.File({"multiView": ["left", "right"]},
                      {**{c: planes[c] for c in "RGB"}, **{f"right.{c}": planes[c] * 10 for c in "RGB"}}) as f:
        f.write(str(one))
    np.testing.assert_array_equal(read_image(one, view="right"), 10 * read_image(one, view="left"))
    with pytest.raises(InputFileError, match=r"one\.exr: R: holds views left, right in one part"):
        read_image(one)


@pytest.mark.parametrize("compression", ["DWAA_COMPRESSION", "PXR24_COMPRESSION"])
def test_a_lossily_compressed_dump_is_read_with_a_warning(tmp_path, compression):
    """A DWAA dump's means came back changed by up to 0.02, without a word (red-team pass 5)."""
    import OpenEXR

    from awr_denoise.io import read_sample_dump

    header, planes = _awr_planes(tmp_path)
    path = _parts_file(tmp_path / "lossy.exr", [({**header, "compression": getattr(OpenEXR, compression)}, planes)])
    with pytest.warns(InputFileWarning, match=f"{compression.removesuffix('_COMPRESSION')} compression is lossy"):
        try:
            read_sample_dump(path)
        except InputFileError as exc:  # DWAA can make a small variance negative: refused then, warned first
            assert "negative" in str(exc)


def test_an_empty_plane_name_after_a_files_colon_is_refused(tmp_path):
    """``file.exr:`` is not the file's default plane (a script's unset ``$PLANE``); a bare plane is the
    main input's, and a plane name may hold colons of its own."""
    with pytest.raises(ValueError, match=r"plane 'beauty\.exr:': no plane name after the file's colon"):
        parse_plane("beauty.exr:", None)
    with pytest.raises(ValueError, match="no plane name"):
        plane_file("beauty.exr:")
    assert plane_file("variance") is None and plane_file("layer:variance") is None
    assert parse_plane("beauty.exr:variance", None) == (Path("beauty.exr"), "variance")
    assert parse_plane("variance", tmp_path / "d.exr") == (tmp_path / "d.exr", "variance")


def test_the_colour_plane_given_as_its_own_variance_is_warned_about(tmp_path):
    """``--variance ViewLayer.Combined`` (the colour itself) was read as a spread without a word, and the
    reconstruction zeroed 99% of the coefficients (a walkthrough): accepted, with a warning naming the plane."""
    planes = {c: _ramp(i) for i, c in enumerate("RGB")} | {f"var.{c}": _ramp(0.1) for c in "RGB"}
    f = _write(tmp_path / "g.exr", planes)
    with pytest.warns(InputFileWarning, match=r"g\.exr: R,G,B: the variance plane is the colour plane itself"):
        read_sample_buffer(f, color="RGB", variance="RGB", spp=4)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_sample_buffer(f, color="RGB", variance="var", spp=4)


def test_the_pbrt_preset_on_another_renderers_file_names_pbrts_channels(tmp_path):
    """``--preset pbrt`` on a file without pbrt's planes was "RGB: no colour channel(s) named this"."""
    f = _write(tmp_path / "c.exr", {"ViewLayer.Combined.R": _ramp(), "ViewLayer.Combined.G": _ramp(),
                                    "ViewLayer.Combined.B": _ramp()})
    with pytest.raises(InputFileError, match=r"c\.exr: no R,G,B and Variance\.\* channels \(pbrt-v4's GBufferFilm\) "
                                             r"for the pbrt preset \(channels: ViewLayer\.Combined\.B"):
        read_sample_buffer(f, preset="pbrt")


def test_a_half_count_pass_is_read_within_halfs_rounding(tmp_path):
    """The count check allows a pass's own rounding only: HALF's (2**-11 relative) for a HALF pass, so counts of
    k/300 stored in HALF still read as k, and a scale that does not divide them is still refused."""
    samples = 300
    count = np.arange(H * W).reshape(H, W) % samples + 1
    planes = {f"ViewLayer.Combined.{c}": _ramp(i) for i, c in enumerate("RGBA")}
    planes["ViewLayer.Debug Sample Count.X"] = (count / samples).astype(np.float16)
    planes |= {f"ViewLayer.Variance AOV.{c}": _ramp(0.5) for c in "RGB"}
    stored = planes["ViewLayer.Debug Sample Count.X"].astype(np.float64) * samples
    f = _write(tmp_path / "half.exr", planes, {"cycles.ViewLayer.samples": str(samples)})
    assert np.abs(stored - count).max() > 1e-3  # HALF's rounding is there to allow
    buf = read_sample_buffer(f, variance="ViewLayer.Variance AOV", spp=samples)
    np.testing.assert_array_equal(buf.count, count)
    with pytest.raises(InputFileError, match="normalised counts times 512 are not whole numbers"):
        read_sample_buffer(f, variance="ViewLayer.Variance AOV", spp=512)


def test_a_file_resized_or_blurred_after_the_render_is_warned_about(tmp_path):
    """pbrt-v4's GBufferFilm output blurred or box-downsized by a pipeline tool (OpenImageIO, as oiiotool does) keeps
    its whole sample count and plausible variances, and was denoised as independent pixels without a word (an attack
    pass). The neighbours' correlation, measured before on Mitsuba's films alone, is measured on pbrt's too; the
    file as pbrt wrote it reads without that warning."""
    import warnings

    oiio = pytest.importorskip("OpenImageIO")
    written = Path(__file__).parent / "data" / "pbrt" / "pbrt_gbuffer_fp32.exr"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read_sample_dump(written)
    assert not [w for w in caught if "share samples" in str(w.message)]
    source = oiio.ImageBuf(str(written))
    blur = oiio.ImageBufAlgo.convolve(source, oiio.ImageBufAlgo.make_kernel("gaussian", 3, 3))
    down = oiio.ImageBufAlgo.resize(source, filtername="box", roi=oiio.ROI(0, 32, 0, 32))
    for name, changed in (("blur.exr", blur), ("down.exr", down)):
        assert not changed.has_error
        changed.write(str(tmp_path / name))
        with pytest.warns(InputFileWarning, match=name + r": R,G,B: neighbouring pixel means vary .* pixels share "
                                                        r"samples \(the file resized or blurred"):
            read_sample_dump(tmp_path / name)
