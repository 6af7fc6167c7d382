"""Deep per-sample dumps and PNG previews."""

from __future__ import annotations

import re
import zlib

import numpy as np
import pytest

pytestmark = pytest.mark.exr
OpenEXR = pytest.importorskip("OpenEXR")

from awr_denoise import SampleBuffer  # noqa: E402
from awr_denoise.errors import InputFileError  # noqa: E402
from awr_denoise.io import read_deep_samples, read_sample_buffer, write_deep_samples, write_preview  # noqa: E402
from awr_denoise.io.png import encode_png, tonemap_srgb  # noqa: E402


def test_deep_round_trip_matches_from_samples(tmp_path, rng):
    shape = (5, 6)
    n = 200
    pixels = rng.integers(0, shape[0] * shape[1], size=n)
    pixels[pixels == 7] = 8  # leave a pixel without samples
    values = rng.random((n, 3)).astype(np.float32)
    write_deep_samples(tmp_path / "s.exr", pixels, values, shape, sample_index=np.arange(n),
                       header={"awr:seed": 3})
    back = read_deep_samples(tmp_path / "s.exr")
    expected = SampleBuffer.from_samples(pixels, values, shape)
    np.testing.assert_array_equal(back.count, expected.count)
    assert back.count.flat[7] == 0
    np.testing.assert_allclose(back.mean, expected.mean, rtol=1e-12)
    np.testing.assert_allclose(back.variance, expected.variance, rtol=1e-9)
    # auto-detection goes to the deep reader as well
    np.testing.assert_array_equal(read_sample_buffer(tmp_path / "s.exr").count, expected.count)
    with OpenEXR.File(str(tmp_path / "s.exr"), separate_channels=True) as f:
        assert f.header()["awr:semantics"] == "mc-samples"
        assert not {"Z", "A"} & set(f.channels())


def test_deep_equal_counts_and_coordinates(tmp_path):
    pixels = np.array([[0, 0], [0, 1], [1, 0], [1, 1]] * 2)
    values = np.arange(8.0)
    write_deep_samples(tmp_path / "s.exr", pixels, values, (2, 2), channels=("Y",))
    back = read_deep_samples(tmp_path / "s.exr")
    np.testing.assert_array_equal(back.count, 2)
    np.testing.assert_array_equal(back.mean[..., 0], [[2, 3], [4, 5]])


def test_deep_refuses_depth_channels_and_depth_files(tmp_path):
    with pytest.raises(ValueError, match="depth"):
        write_deep_samples(tmp_path / "z.exr", np.array([0]), np.ones((1, 2)), (1, 1), channels=("R", "Z"))
    obj = np.fromiter([np.array([1.0], np.float32)], object, 1).reshape(1, 1)
    with OpenEXR.File({"type": OpenEXR.deepscanline, "compression": OpenEXR.ZIPS_COMPRESSION},
                      {"Z": obj, "A": obj}) as f:
        f.write(str(tmp_path / "depth.exr"))
    with pytest.raises(InputFileError, match=r"depth\.exr: awr:semantics: .*mc-samples"):
        read_deep_samples(tmp_path / "depth.exr")


def _deep_with(tmp_path, name, channels_attribute, keep):
    """A valid deep dump rewritten with ``awr:channels`` set to ``channels_attribute`` (None: removed)
    and only the channels in ``keep``."""
    pixels = np.repeat(np.arange(4), 3)
    write_deep_samples(tmp_path / "ok.exr", pixels, np.arange(36.0).reshape(12, 3), (2, 2),
                       sample_index=np.tile(np.arange(3.0), 4), overwrite=True)
    f = OpenEXR.File(str(tmp_path / "ok.exr"), separate_channels=True)
    header = {k: v for k, v in f.header().items() if k not in ("channels", "awr:channels")}
    if channels_attribute is not None:
        header["awr:channels"] = channels_attribute
    planes = {k: OpenEXR.Channel(c.pixels) for k, c in f.channels().items() if k in keep}
    with OpenEXR.File(header, planes) as g:
        g.write(str(tmp_path / name))
    return tmp_path / name


@pytest.mark.parametrize("attribute,keep,what", [
    ("", ("R", "G", "B", "sampleIndex"), "names no channel"),
    (",", ("R", "G", "B", "sampleIndex"), "names no channel"),
    (None, ("sampleIndex",), "is not given, and no channel but the sample index"),
    ("sampleIndex", ("R", "G", "B", "sampleIndex"), "names sampleIndex, which a Monte Carlo sample dump reserves"),
])
def test_a_deep_dump_without_sample_values_is_named(tmp_path, attribute, keep, what):
    """No value channel left gave an IndexError (an internal error, exit 1); the sample index named as
    a value was denoised as radiance (a red-team pass)."""
    path = _deep_with(tmp_path, "bad.exr", attribute, keep)
    with pytest.raises(InputFileError, match=rf"bad\.exr: awr:channels: {what}"):
        read_deep_samples(path)
    np.testing.assert_array_equal(read_deep_samples(tmp_path / "ok.exr").count, 3)


def test_deep_nan_sample_named(tmp_path):
    obj = np.fromiter([np.array([1.0, np.nan], np.float32)], object, 1).reshape(1, 1)
    with OpenEXR.File({"type": OpenEXR.deepscanline, "compression": OpenEXR.ZIPS_COMPRESSION,
                       "awr:semantics": "mc-samples"}, {"R": obj}) as f:
        f.write(str(tmp_path / "n.exr"))
    with pytest.raises(InputFileError, match=r"n\.exr: R: .*NaN"):
        read_deep_samples(tmp_path / "n.exr")


def test_tonemap_values():
    px = tonemap_srgb(np.array([[[0.0, 0.0031308, 1.0], [2.0, -1.0, 0.25]]]), exposure=0.0)
    assert px[0, 0].tolist() == [0, 10, 255]
    assert px[0, 1, :2].tolist() == [255, 0]
    assert tonemap_srgb(np.full((1, 1, 3), 0.125), exposure=3.0)[0, 0, 0] == 255


def _decode_png(data: bytes) -> np.ndarray:
    # Minimal decoder for our own unfiltered 8-bit RGB output.
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    idat = data.index(b"IDAT")
    length = int.from_bytes(data[idat - 4:idat], "big")
    raw = np.frombuffer(zlib.decompress(data[idat + 4:idat + 4 + length]), np.uint8).reshape(h, 1 + 3 * w)
    assert (raw[:, 0] == 0).all()
    return raw[:, 1:].reshape(h, w, 3)


def test_builtin_png_encoder(tmp_path):
    px = (np.arange(2 * 3 * 3) * 10).astype(np.uint8).reshape(2, 3, 3)
    np.testing.assert_array_equal(_decode_png(encode_png(px)), px)


def test_write_preview_readable(tmp_path):
    oiio = pytest.importorskip("OpenImageIO")
    img = np.linspace(0, 1, 4 * 5 * 3).reshape(4, 5, 3)
    write_preview(tmp_path / "p.png", img, exposure=0.0)
    back = oiio.ImageBuf(str(tmp_path / "p.png")).get_pixels(oiio.UINT8)
    np.testing.assert_array_equal(back, tonemap_srgb(img))
    with pytest.raises(FileExistsError):
        write_preview(tmp_path / "p.png", img)


@pytest.mark.parametrize("option, value, cli", [
    ("color", "R", ["--color", "R"]), ("variance", "V", ["--variance", "V"]), ("count", "N", ["--count", "N"]),
    ("spp", 4, ["--spp", "4"]), ("view", "left", ["--view", "left"]), ("albedo", "alb.exr", ["--alb", "alb.exr"]),
    ("normal", "nrm.exr", ["--nrm", "nrm.exr"]), ("depth", "z.exr", ["--depth", "z.exr"]),
])
def test_options_a_deep_dump_would_ignore_are_refused(tmp_path, monkeypatch, capsys, option, value, cli):
    """A deep dump's samples carry their own layout: a colour plane, a count, features or a view
    asked for would be silently ignored (a guide run without its albedo), so each is refused."""
    from awr_denoise.cli.main import main
    from awr_denoise.io import read_sample_dump, write_image

    monkeypatch.chdir(tmp_path)
    write_deep_samples("deep.exr", np.repeat(np.arange(16), 2), np.ones((32, 3)), (4, 4))
    for name in ("alb.exr", "nrm.exr", "z.exr"):
        write_image(name, np.full((4, 4, 3), 0.5))
    with pytest.raises(InputFileError, match=f"deep.exr: {option}= / {cli[0]} would be ignored"):
        read_sample_dump("deep.exr", **{option: value})
    assert main(["denoise", "deep.exr", "-o", "o.exr", "-q", *cli]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and cli[0] in err[0] and not (tmp_path / "o.exr").exists()
    assert read_sample_dump("deep.exr").buffer.total_samples == 32  # without them it reads as before


def test_a_count_plane_beside_an_awr_dumps_own_counts_is_refused(tmp_path):
    from awr_denoise.io import read_sample_dump, write_sample_buffer

    write_sample_buffer(tmp_path / "d.exr", SampleBuffer.from_moments(np.full((4, 4), 2), np.ones((4, 4, 3)),
                                                                         np.ones((4, 4, 3))))
    with pytest.raises(InputFileError, match="count= / --count would be ignored: an awr dump counts"):
        read_sample_dump(tmp_path / "d.exr", count="N")


@pytest.mark.parametrize("policy", ["drop", "zero"])
def test_a_nonfinite_policy_on_a_flat_file_is_refused(tmp_path, monkeypatch, capsys, policy):
    """The policy is for a deep dump's samples; on a flat dump it did nothing, without a word, and its NaN
    mean was then refused as though no policy had been asked for (a red-team pass)."""
    from awr_denoise.cli.main import main
    from awr_denoise.io import read_sample_dump, write_sample_buffer

    monkeypatch.chdir(tmp_path)
    write_sample_buffer("d.exr", SampleBuffer.from_moments(np.full((4, 4), 2), np.ones((4, 4, 3)), np.ones((4, 4, 3))))
    with pytest.raises(InputFileError, match="d.exr: nonfinite= / --nonfinite would be ignored: a flat file"):
        read_sample_dump("d.exr", nonfinite=policy)
    for argv in (["denoise", "d.exr", "-o", "o.exr"], ["plan", "d.exr", "-o", "o.exr"],
                 ["merge", "d.exr", "d.exr", "--allow-duplicates", "-o", "o.exr"]):
        assert main([*argv, "-q", "--nonfinite", policy]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--nonfinite would be ignored" in err[0] and not (tmp_path / "o.exr").exists()
    assert read_sample_dump("d.exr", nonfinite="raise").buffer.total_samples == 32
    write_deep_samples("deep.exr", np.repeat(np.arange(16), 2), np.ones((32, 3)), (4, 4))
    assert read_sample_dump("deep.exr", nonfinite=policy).buffer.total_samples == 32  # what it is for


def test_a_deep_dump_is_not_an_independent_render(tmp_path, monkeypatch, capsys):
    """``merge --independent`` said "cannot detect the layout (channels: )" of a deep dump."""
    from awr_denoise.cli.main import main

    monkeypatch.chdir(tmp_path)
    for name, value in (("a.exr", 1.0), ("b.exr", 2.0)):
        write_deep_samples(name, np.repeat(np.arange(16), 2), np.full((32, 3), value), (4, 4))
    assert main(["merge", "a.exr", "b.exr", "-o", "m.exr", "-q", "--independent"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a.exr: a per-sample (deep) dump" in err[0] and "--independent" in err[0], err
    assert main(["merge", "a.exr", "b.exr", "-o", "m.exr", "-q"]) == 0


def test_a_deep_dump_as_a_plane_file_is_named_as_one(tmp_path, monkeypatch):
    """``--variance deep.exr:R,G,B`` said "(channels: none)" of a file that has channels, deep ones."""
    from awr_denoise.io import read_sample_dump, write_image

    monkeypatch.chdir(tmp_path)
    write_deep_samples("deep.exr", np.repeat(np.arange(16), 2), np.ones((32, 3)), (4, 4))
    write_image("img.exr", np.ones((4, 4, 3)))
    with pytest.raises(InputFileError, match="deep.exr: a per-sample \\(deep\\) dump holds no planes"):
        read_sample_dump("img.exr", preset="generic", color="RGB", variance="deep.exr:R,G,B", spp=4)


def test_a_preview_wider_than_libpng_allows_is_written_without_its_errors(tmp_path, capfd):
    """OpenImageIO's libpng refused more than 10**6 pixels a side with two error lines on stderr,
    then the built-in encoder wrote the file (red-team pass 5): it now writes it alone."""
    write_preview(tmp_path / "wide.png", np.full((1, 1_000_001), 0.5))
    assert "libpng" not in capfd.readouterr().err
    header = (tmp_path / "wide.png").read_bytes()[:24]  # the signature, then IHDR's width and height
    assert header[:8] == b"\x89PNG\r\n\x1a\n" and header[12:16] == b"IHDR"
    assert int.from_bytes(header[16:20], "big") == 1_000_001 and int.from_bytes(header[20:24], "big") == 1


def test_a_preview_of_four_channels_is_written_by_openimageio_without_its_errors(tmp_path, capfd, monkeypatch):
    """An RGBA preview reached OpenImageIO as a strided view of its planes: libpng wrote no pixel data and printed
    "No IDATs written into file" on stderr, -q or not, before the built-in encoder wrote the file (an attack pass)."""
    pytest.importorskip("OpenImageIO")
    from awr_denoise.io import png

    monkeypatch.setattr(png, "encode_png", lambda pixels: pytest.fail("the built-in encoder wrote it"))
    strided = np.full((4, 32, 48), 200, np.uint8).transpose(1, 2, 0)
    assert not strided.flags.c_contiguous
    png._write_png(str(tmp_path / "rgba.png"), strided)
    assert capfd.readouterr().err == ""
    assert (tmp_path / "rgba.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_tonemap_refuses_complex_bool_and_masked_images():
    """These were cast: ``0.5+9j`` became grey 188 (red-team pass of the API's array layouts)."""
    with pytest.raises(TypeError, match="image: complex values are not supported"):
        tonemap_srgb(np.full((2, 2, 3), 0.5 + 9j))
    with pytest.raises(TypeError, match="image: expected a numeric array, got dtype bool"):
        tonemap_srgb(np.ones((2, 2, 3), bool))
    with pytest.raises(TypeError, match="image: a masked array with 12 masked entries"):
        tonemap_srgb(np.ma.masked_array(np.ones((2, 2, 3)), mask=True))


def test_deep_sample_indices_refuse_complex(tmp_path):
    with pytest.raises(TypeError, match="sample_index: complex values are not supported"):
        write_deep_samples(tmp_path / "never.exr", np.array([0, 1]), np.ones((2, 3)), (1, 2),
                           sample_index=np.array([0j, 1j]))
    assert not (tmp_path / "never.exr").exists()


@pytest.mark.parametrize(("index", "message"), [(np.array([0.0, np.nan]), "sample indices must be whole numbers"),
                                                (np.array([0.0, -1.0]), "1 sample(s) are negative")])
def test_bad_deep_sample_indices_are_named_as_indices_of_samples(tmp_path, index, message):
    """A NaN sample index was refused as "counts must be whole numbers", a negative one as "1 pixel(s) are
    negative" (a red-team pass): the words of a count plane, for one sample's index."""
    with pytest.raises(ValueError, match=re.escape(f"sample_index: {message}")):
        write_deep_samples(tmp_path / "never.exr", np.array([0, 1]), np.ones((2, 3)), (1, 2), sample_index=index)
    write_deep_samples(tmp_path / "ok.exr", np.array([0, 1]), np.ones((2, 3)), (1, 2), sample_index=np.zeros(2))
    # The same words where a file holds them (written raw: the writer refuses them).
    from awr_denoise.io.deep import sample_index_bounds
    from awr_denoise.io.exr import read_exr

    part = read_exr(tmp_path / "ok.exr")[0]
    grid = part.channels["sampleIndex"]
    grid[0, 1] = np.array([-1.0], np.float32)
    with pytest.raises(InputFileError, match=r"ok\.exr: sampleIndex: 1 sample\(s\) are negative"):
        sample_index_bounds(tmp_path / "ok.exr", part)


def test_a_deep_dump_cropped_by_a_tool_that_kept_its_header_is_named_so(tmp_path):
    """OpenImageIO's crop of a deep dump keeps the header's awr:samples (the whole file's); the crop's count table
    and data agree. It was refused as a "corrupt count table" alone (an attack pass): the line names the crop too."""
    oiio = pytest.importorskip("OpenImageIO")
    rng = np.random.default_rng(0)
    n = rng.integers(4, 17, 24 * 24)
    pixel = np.repeat(np.arange(24 * 24), n)
    write_deep_samples(tmp_path / "deep.exr", pixel, rng.gamma(2.0, 0.25, (pixel.size, 3)).astype(np.float32),
                       (24, 24), sample_index=np.concatenate([np.arange(k) for k in n]))
    cropped = oiio.ImageBufAlgo.crop(oiio.ImageBuf(str(tmp_path / "deep.exr")), oiio.ROI(4, 16, 4, 16))
    assert not cropped.has_error and cropped.deep
    cropped.write(str(tmp_path / "crop.exr"))
    with pytest.raises(InputFileError, match=r"crop.exr: awr:samples: .* declares \d+: a corrupt count table, or a "
                                             r"header kept by a tool that cropped or edited the samples"):
        read_deep_samples(tmp_path / "crop.exr")
