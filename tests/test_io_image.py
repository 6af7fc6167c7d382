"""Plain EXR images: round trips, channel lookup by name, atomic and non-clobbering writes."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.exr
OpenEXR = pytest.importorskip("OpenEXR")

from awr_denoise.errors import InputFileError  # noqa: E402
from awr_denoise.io import read_header, read_image, write_image  # noqa: E402


def test_write_exr_takes_any_byte_order_and_names_what_it_refuses(tmp_path):
    """A big-endian plane, a masked plane (its hidden values were written), a float64 or a complex one:
    the bindings' message named no plane (a review of the array-layout fixes)."""
    from awr_denoise.io.exr import write_exr

    plane = np.arange(12, dtype=">f4").reshape(3, 4)
    write_exr(tmp_path / "be.exr", {"R": plane, "G": plane.T.copy().T, "B": np.asfortranarray(plane)})
    back = read_image(tmp_path / "be.exr")
    for c in range(3):
        np.testing.assert_array_equal(back[..., c], plane.astype(np.float32))
    ones = np.ones((2, 2), np.float32)
    for bad, message in ((np.ma.masked_array(ones, mask=[[1, 0], [0, 0]]), "R: a masked array with 1 masked entries"),
                         (ones.astype(np.float64), "R: a plane of dtype float64"),
                         (ones + 0j, "R: a plane of dtype complex64")):
        with pytest.raises(TypeError, match=message):
            write_exr(tmp_path / "bad.exr", {"R": bad})
    assert not (tmp_path / "bad.exr").exists()


def test_round_trip_float32_exact(tmp_path):
    img = np.random.default_rng(0).random((5, 7, 3)).astype(np.float32)
    write_image(tmp_path / "a.exr", img, header={"awr:c_s": 1.5, "awr:wavelet": "bior4.4"})
    back = read_image(tmp_path / "a.exr")
    assert back.dtype == np.float32 and back.shape == (5, 7, 3)
    np.testing.assert_array_equal(back, img)
    h = read_header(tmp_path / "a.exr")
    assert h["awr:wavelet"] == "bior4.4" and h["awr:c_s"] == 1.5 and "awr:version" in h


def test_half_round_trip_and_overflow_refused(tmp_path):
    img = np.full((2, 2, 3), 0.5)
    write_image(tmp_path / "h.exr", img, half=True)
    with OpenEXR.File(str(tmp_path / "h.exr"), separate_channels=True) as f:
        assert f.channels()["R"].pixels.dtype == np.float16
    np.testing.assert_array_equal(read_image(tmp_path / "h.exr"), img)
    with pytest.raises(ValueError, match="half-float"):
        write_image(tmp_path / "o.exr", np.full((2, 2, 3), 1e5), half=True)
    assert not (tmp_path / "o.exr").exists()


def test_channel_order_by_name_not_position(tmp_path):
    h, w = 3, 4
    planes = {"B": np.full((h, w), 3, np.float32), "A": np.ones((h, w), np.float32),
              "G": np.full((h, w), 2, np.float32), "R": np.full((h, w), 1, np.float32)}
    with OpenEXR.File({}, planes) as f:
        f.write(str(tmp_path / "x.exr"))
    np.testing.assert_array_equal(read_image(tmp_path / "x.exr")[0, 0], [1, 2, 3])
    np.testing.assert_array_equal(read_image(tmp_path / "x.exr", channels=["A", "B"])[0, 0], [1, 3])


def test_layer_prefixed_rgb_and_ambiguity(tmp_path):
    one = np.ones((2, 2), np.float32)
    with OpenEXR.File({}, {f"View Layer.Combined.{c}": one * i for i, c in enumerate("RGB")}) as f:
        f.write(str(tmp_path / "c.exr"))
    np.testing.assert_array_equal(read_image(tmp_path / "c.exr")[0, 0], [0, 1, 2])
    chans = {f"{layer}.{c}": one for layer in ("a", "b") for c in "RGB"}
    with OpenEXR.File({}, chans) as f:
        f.write(str(tmp_path / "amb.exr"))
    with pytest.raises(InputFileError, match="ambiguous"):
        read_image(tmp_path / "amb.exr")


@pytest.mark.parametrize("value,what", [(np.nan, "NaN"), (np.inf, "Inf")])
def test_nonfinite_refused_on_write(tmp_path, value, what):
    img = np.zeros((2, 2, 3))
    img[1, 1, 2] = value
    with pytest.raises(ValueError, match=r"n\.exr: B: .*NaN or Inf"):
        write_image(tmp_path / "n.exr", img)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("value, refused", [(65400.0, False), (65472.0, False), (65500.0, True), (-65504.0, True)])
def test_half_values_stored_as_the_half_maximum_are_refused(tmp_path, value, refused):
    """A value stored as +-65504 reads back as Blender's clamp of a larger one, which the readers refuse: the writer
    refuses it, so no Half file of ours is one we cannot read (values just below the maximum round to it)."""
    img = np.full((2, 2, 3), 0.5)
    img[0, 0, 1] = value
    if refused:
        with pytest.raises(ValueError, match="G: image has 1 pixel.*half-float maximum 65504"):
            write_image(tmp_path / "h.exr", img, half=True)
        assert not (tmp_path / "h.exr").exists()
    else:
        write_image(tmp_path / "h.exr", img, half=True)
        assert read_image(tmp_path / "h.exr")[0, 0, 1] == np.float16(value)


@pytest.mark.parametrize("half, value", [(True, 1e-40), (True, 2e-8), (False, 1e-46)])
def test_a_channel_that_would_be_stored_black_is_refused(tmp_path, half, value):
    """Every value of a channel below the stored type's smallest became 0: ``--half`` on means near 1e-40
    wrote an all-black image, exit 0 (a red-team pass). A channel with some values that survive is
    written (a value that small beside them is 0 for any reader), and a black channel stays black."""
    img = np.full((2, 2, 3), 0.5)
    img[..., 1] = value
    with pytest.raises(ValueError, match=r"o\.exr: G: every value of the channel is below the .* stored as 0"):
        write_image(tmp_path / "o.exr", img, half=half)
    assert not (tmp_path / "o.exr").exists()
    img[0, 0, 1], img[..., 2] = 0.5, 0.0
    write_image(tmp_path / "o.exr", img, half=half)
    back = read_image(tmp_path / "o.exr")
    assert back[0, 0, 1] == 0.5 and back[1, 1, 1] == 0 and (back[..., 2] == 0).all()


def test_nonfinite_and_half_overflow_refused_on_read(tmp_path):
    r = np.zeros((2, 2), np.float16)
    r[0, 0] = np.float16(np.inf)
    with OpenEXR.File({}, {"R": r, "G": np.zeros_like(r), "B": np.zeros_like(r)}) as f:
        f.write(str(tmp_path / "ovf.exr"))
    with pytest.raises(InputFileError, match=r"ovf\.exr: R: .*half-float overflow"):
        read_image(tmp_path / "ovf.exr")


def test_overwrite_refused_then_allowed_and_atomic(tmp_path):
    target = tmp_path / "a.exr"
    write_image(target, np.zeros((2, 2, 3)))
    before = target.read_bytes()
    with pytest.raises(FileExistsError, match="a.exr"):
        write_image(target, np.ones((2, 2, 3)))
    assert target.read_bytes() == before
    write_image(target, np.ones((2, 2, 3)), overwrite=True)
    assert read_image(target)[0, 0, 0] == 1
    assert sorted(os.listdir(tmp_path)) == ["a.exr"]  # no temporary file left behind


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    from awr_denoise.io import atomic

    def boom(tmp):
        with open(tmp, "wb") as fh:
            fh.write(b"partial")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic.atomic_write(tmp_path / "x.exr", boom)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("content,what", [(b"", "not an OpenEXR"), (b"hello world", "not an OpenEXR")])
def test_not_an_exr(tmp_path, content, what):
    (tmp_path / "f.exr").write_bytes(content)
    with pytest.raises(InputFileError, match=what):
        read_image(tmp_path / "f.exr")


def test_truncated_exr(tmp_path):
    write_image(tmp_path / "a.exr", np.random.default_rng(1).random((64, 64, 3)))
    data = (tmp_path / "a.exr").read_bytes()
    (tmp_path / "t.exr").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputFileError, match=r"t\.exr: .*(truncated|corrupt)"):
        read_image(tmp_path / "t.exr")


def _claiming(path, side, compression=None):
    """A small valid file whose header claims ``side`` x ``side`` pixels (a corrupt header)."""
    if compression is None:
        write_image(path, np.ones((64, 64, 3)))
    else:
        with OpenEXR.File({"compression": compression, "type": OpenEXR.scanlineimage},
                          {c: np.ones((64, 64), np.float16) for c in "RGB"}) as f:
            f.write(str(path))
    data = bytearray(path.read_bytes())
    for key in (b"dataWindow\0box2i\0", b"displayWindow\0box2i\0"):
        at = data.find(key) + len(key) + 4  # after the attribute's size
        data[at:at + 16] = np.array([0, 0, side - 1, side - 1], "<i4").tobytes()
    path.write_bytes(bytes(data))
    return path


def test_a_header_claiming_more_than_its_file_holds_is_the_files_error(tmp_path, monkeypatch):
    """A 600-byte file claiming 2000000x2000000 pixels was "out of memory" (exit 1, the machine's
    fault); no EXR compression comes near that ratio: refused naming the claim (exit 2)."""
    from awr_denoise.cli.main import main

    path = _claiming(tmp_path / "huge.exr", 2_000_000)
    with pytest.raises(InputFileError, match=r"huge\.exr: its data window claims [\d.e+]+ GiB of pixels in a file "):
        read_image(path)
    assert main(["diff", str(path), "-r", str(path)]) == 2


def test_a_compression_without_a_bound_is_never_called_impossible(tmp_path):
    """HTJ2K keeps a chunk's size almost constant as it grows (a valid 20000x20000 constant tile
    takes 627 bytes, over a millionfold): no claim proves such a file corrupt, so running out of
    memory stays the machine's."""
    path = _claiming(tmp_path / "htj2k.exr", 2_000_000, OpenEXR.HTJ2K256_COMPRESSION)
    # A fresh process: its sys.stdout is file descriptor 1, where the bindings' report is read.
    run = "import sys; from awr_denoise.cli.main import main; sys.exit(main(sys.argv[1:]))"
    done = subprocess.run([sys.executable, "-c", run, "diff", str(path), "-r", str(path)], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    assert "out of memory" in done.stderr and "its pixels take" in done.stderr


@pytest.mark.parametrize("report", ["Warning: Exception raised reading pixel data for part 0 - std::bad_alloc",
                                    "{path}: (EXR_ERR_OUT_OF_MEMORY) Unable to allocate 96000000 bytes"])
def test_the_cxx_and_openexr_out_of_memory_reports_are_out_of_memory(tmp_path, monkeypatch, report):
    """Valid tiled files under ``ulimit -v`` were "truncated or corrupt" (exit 2): the C++
    allocator's and OpenEXR's own reports of running out of memory were not recognised."""
    from awr_denoise.io import exr

    path = tmp_path / "a.exr"
    write_image(path, np.ones((4, 4, 3)))
    real = exr._openexr()

    class Starved:
        def __getattr__(self, name):
            return getattr(real, name)

        @contextlib.contextmanager
        def File(self, *args, header_only=False, **kwargs):  # noqa: N802 - OpenEXR's name
            if header_only:
                with real.File(*args, header_only=True, **kwargs) as f:
                    yield f
                return
            os.write(1, (report.format(path=path) + "\n").encode())  # as the C++ library prints
            yield type("NoParts", (), {"parts": []})()

    monkeypatch.setattr(exr, "_openexr", lambda: Starved())
    with pytest.raises(MemoryError, match="its pixels take"):
        read_image(path)


class _Starved:
    """OpenEXR's bindings whose pixel reads (and, with ``headers=False``, header reads) run out of memory."""

    def __init__(self, real, *, headers: bool = True):
        self.real, self.headers = real, headers

    def __getattr__(self, name):
        return getattr(self.real, name)

    def File(self, *args, header_only=False, **kwargs):  # noqa: N802 - OpenEXR's name
        if header_only and self.headers:
            return self.real.File(*args, header_only=header_only, **kwargs)
        raise MemoryError


def test_running_out_of_memory_on_a_plausible_file_is_the_machines(tmp_path, monkeypatch):
    """The bindings' MemoryError on a file whose size could hold its pixels stays out of memory
    (exit 1), naming what the pixels take; a header read failing so too does not recurse."""
    from awr_denoise.io import exr

    write_image(tmp_path / "a.exr", np.ones((64, 64, 3)))
    starved = _Starved(exr._openexr())
    monkeypatch.setattr(exr, "_openexr", lambda: starved)
    with pytest.raises(MemoryError, match=r"a\.exr \(its pixels take [\d.e+-]+ GiB or more\)"):
        read_image(tmp_path / "a.exr")
    starved.headers = False
    with pytest.raises(MemoryError, match=r"reading .*a\.exr$"):
        read_image(tmp_path / "a.exr")


@pytest.mark.parametrize("compression", ["B44A", "B44", "RLE", "NO"])
def test_a_claim_past_its_compressions_own_ratio_is_the_files_error(tmp_path, monkeypatch, compression):
    """Under an address-space limit a corrupt B44A file claiming 6.25 GiB in 24 KB was "out of
    memory" (exit 1): the bound was one ratio (2**20) for every compression. Each now has its own
    (B44A shrinks a flat 4x4 block of HALF to 3 bytes, 10.7:1), and a valid file near that ratio
    (a constant 2048x2048 image) stays the machine's."""
    from awr_denoise.io import exr

    kind = getattr(OpenEXR, f"{compression}_COMPRESSION")
    corrupt = _claiming(tmp_path / "claims.exr", 2000, kind)
    assert 2 * 3 * 2000**2 < 2**20 * corrupt.stat().st_size  # within the old single bound
    flat = tmp_path / "flat.exr"
    with OpenEXR.File({"compression": kind, "type": OpenEXR.scanlineimage},
                      {c: np.zeros((2048, 2048), np.float16) for c in "RGB"}) as f:
        f.write(str(flat))
    monkeypatch.setattr(exr, "_openexr", lambda real=exr._openexr(): _Starved(real))
    with pytest.raises(InputFileError, match=r"claims\.exr: its data window claims [\d.e+-]+ GiB of pixels in a file"):
        read_image(corrupt)
    with pytest.raises(MemoryError, match=r"flat\.exr \(its pixels take"):
        read_image(flat)


@pytest.mark.parametrize("name", ["MemoryError",
                                  "Warning: Exception raised reading pixel data for part 0 - MemoryError"])
def test_a_corrupt_file_under_a_folder_named_like_the_bindings_report_is_corrupt(tmp_path, monkeypatch, name):
    """The bindings' report names the file: a path holding "MemoryError" made any corrupt file "out
    of memory"; OpenEXR's lines start with the path as given, so a relative one can start like the
    report."""
    monkeypatch.chdir(tmp_path)
    folder = Path(name)
    folder.mkdir()
    write_image(folder / "a.exr", np.random.default_rng(1).random((64, 64, 3)))
    data = (folder / "a.exr").read_bytes()
    (folder / "t.exr").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputFileError, match=r"t\.exr: .*(truncated|corrupt)"):
        read_image(folder / "t.exr")


def test_an_impossible_claim_is_found_under_a_python_level_redirect(tmp_path):
    """The bindings print their report through Python's sys.stdout: under a caller's redirect (a
    notebook) it goes there, and the error said only "no readable parts"."""
    import contextlib
    import io

    path = _claiming(tmp_path / "huge.exr", 2_000_000)
    with contextlib.redirect_stdout(io.StringIO()), pytest.raises(InputFileError, match="claims"):
        read_image(path)


def test_where_the_bindings_reason_went_is_said(tmp_path, monkeypatch):
    """As the bindings do: print the reason through Python's sys.stdout and return no parts."""
    import contextlib
    import io

    from awr_denoise.io import exr

    write_image(tmp_path / "a.exr", np.ones((4, 4, 3)))
    real = exr._openexr()

    class Silent:
        def __getattr__(self, name):
            return getattr(real, name)

        @contextlib.contextmanager
        def File(self, *args, **kwargs):  # noqa: N802 - OpenEXR's name
            print("Warning: Exception raised reading pixel data for part 0 - MemoryError: Unable to allocate")
            yield type("NoParts", (), {"parts": []})()

    monkeypatch.setattr(exr, "_openexr", lambda: Silent())
    seen = io.StringIO()
    with contextlib.redirect_stdout(seen), pytest.raises(InputFileError, match="printed its reason to Python"):
        read_image(tmp_path / "a.exr")
    assert "MemoryError" in seen.getvalue()


def test_other_output_during_a_read_is_passed_through_not_read_as_corruption(tmp_path, monkeypatch, capfd):
    """A progress bar drawn by another thread while OpenEXR reads lands in the read's capture.

    It was taken for OpenEXR's corruption report: multi-frame ``awr denoise`` refused valid
    frames. Now only OpenEXR's own lines count; the rest reaches the stream it was written to.
    """
    from awr_denoise.io import exr

    write_image(tmp_path / "a.exr", np.ones((4, 4, 3)))
    real = exr._openexr()

    class Noisy:
        def __getattr__(self, name):
            return getattr(real, name)

        def File(self, *args, **kwargs):  # noqa: N802 - OpenEXR's name
            os.write(2, b"\rframes:  17%|#7        | 2/12\r")  # what tqdm draws from another thread
            os.write(1, b"a line on stdout\n")
            return real.File(*args, **kwargs)

    monkeypatch.setattr(exr, "_openexr", lambda: Noisy())
    np.testing.assert_array_equal(read_image(tmp_path / "a.exr"), np.ones((4, 4, 3), np.float32))
    out, err = capfd.readouterr()
    assert out == "a line on stdout\n" and err == "\rframes:  17%|#7        | 2/12\r"
    # OpenEXR's own report is still an error, and is not passed through.
    data = (tmp_path / "a.exr").read_bytes()
    (tmp_path / "t.exr").write_bytes(data[: len(data) - 8])
    with pytest.raises(InputFileError, match=r"t\.exr: truncated or corrupt EXR \(.*EXR_ERR"):
        read_image(tmp_path / "t.exr")
    assert "EXR_ERR" not in "".join(capfd.readouterr())


def test_missing_file(tmp_path):
    with pytest.raises(InputFileError, match="no such file"):
        read_image(tmp_path / "nope.exr")


def test_written_files_get_ordinary_permissions(tmp_path):
    # The temporary file is private (mkstemp); the result must not be.
    old = os.umask(0o022)
    try:
        write_image(tmp_path / "a.exr", np.zeros((2, 2, 3)))
    finally:
        os.umask(old)
    assert (tmp_path / "a.exr").stat().st_mode & 0o777 == 0o644
    os.chmod(tmp_path / "a.exr", 0o600)
    write_image(tmp_path / "a.exr", np.ones((2, 2, 3)), overwrite=True)
    assert (tmp_path / "a.exr").stat().st_mode & 0o777 == 0o600  # a replaced file keeps its mode


def test_threaded_reads_keep_stdout(tmp_path, capfd):
    # Reads redirect the C streams to catch OpenEXR's messages; threads must not lose stdout.
    from concurrent.futures import ThreadPoolExecutor

    write_image(tmp_path / "a.exr", np.random.default_rng(2).random((64, 64, 3)))
    data = (tmp_path / "a.exr").read_bytes()
    (tmp_path / "t.exr").write_bytes(data[: len(data) // 2])

    def read(i):
        try:
            return read_image(tmp_path / ("t.exr" if i % 2 else "a.exr")).shape
        except InputFileError:
            return None

    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(read, range(40)))
    assert results.count(None) == 20
    os.write(1, b"still here\n")
    assert "still here" in capfd.readouterr().out


def test_a_locale_that_decodes_names_otherwise_is_named(tmp_path):
    """In a locale whose file names are not UTF-8 (ASCII under LC_ALL=POSIX without coercion,
    Latin-1), Python's name and OpenEXR's bytes differ: a UTF-8 name was "not valid UTF-8", and a
    Latin-1 one was written under one name and then read as "truncated or corrupt" under another."""
    code = ("import os\nfrom awr_denoise.io.atomic import check_utf8_name\n"
            "try:\n    check_utf8_name(os.fsdecode(b'r\\xc3\\xa9.exr'))\nexcept ValueError as e:\n    print(e)\n")
    env = dict(os.environ, LC_ALL="POSIX", PYTHONUTF8="0", PYTHONCOERCECLOCALE="0", PYTHONIOENCODING="utf-8")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert "decoded as ascii here" in out and "UTF-8 locale" in out, out


def test_a_name_that_is_not_utf8_is_refused_naming_it(tmp_path):
    """OpenEXR's binding refused such an output as "use write(path: str)", naming nothing, and a
    valid input was "truncated or corrupt"; both are refused by name, nothing written."""
    folder = os.fsdecode(os.fsencode(tmp_path) + b"/dir\xff")
    os.mkdir(folder)
    with pytest.raises(ValueError, match=r"dir\\xff/w.exr: the name is not valid UTF-8"):
        write_image(os.path.join(folder, "w.exr"), np.ones((2, 2, 3)))
    assert os.listdir(folder) == []
    write_image(tmp_path / "ok.exr", np.ones((2, 2, 3)))
    os.link(tmp_path / "ok.exr", os.path.join(folder, "in.exr"))
    with pytest.raises(InputFileError, match=r"dir\\xff/in.exr: the name is not valid UTF-8"):
        read_image(os.path.join(folder, "in.exr"))
    from awr_denoise.io.atomic import check_utf8_name

    for name in (b"in\xff.exr", "in\ud800.exr"):  # bytes, and a surrogate no file name's bytes give
        with pytest.raises(ValueError, match="the name is not valid UTF-8"):
            check_utf8_name(name)


def test_a_mipmapped_file_is_named_as_such_not_corrupt(tmp_path):
    """OpenEXR writes it, the bindings cannot read its levels: "truncated or corrupt" was wrong."""
    import OpenEXR

    tiles = OpenEXR.TileDescription()
    tiles.xSize = tiles.ySize = 8
    tiles.mode = OpenEXR.MIPMAP_LEVELS
    planes = {c: np.ones((16, 16), np.float32) for c in "RGB"}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.tiledimage, "tiles": tiles},
                      planes) as f:
        f.write(str(tmp_path / "mip.exr"))
    with pytest.raises(InputFileError, match="mip.exr: part 0 is a multi-level tiled EXR"):
        read_image(tmp_path / "mip.exr")
    (tmp_path / "cut.exr").write_bytes((tmp_path / "mip.exr").read_bytes()[:-40])
    with pytest.raises(InputFileError):
        read_image(tmp_path / "cut.exr")


def test_a_mipmapped_file_with_every_level_is_read_at_its_full_resolution(tmp_path):
    """OpenImageIO's maketx writes every level: its first is the image, the same floats as the file with one level
    (docs/io.md; an attack pass found the page saying such files were refused)."""
    oiio = pytest.importorskip("OpenImageIO")
    flat = tmp_path / "flat.exr"
    image = np.random.default_rng(0).random((24, 40, 3)).astype(np.float32)
    write_image(flat, image)
    mip = tmp_path / "mip.exr"
    assert oiio.ImageBufAlgo.make_texture(oiio.MakeTxTexture, oiio.ImageBuf(str(flat)), str(mip), oiio.ImageSpec())
    assert "MIPMAP" in str(_tile_mode(mip))
    np.testing.assert_array_equal(read_image(mip), read_image(flat))


def _tile_mode(path: Path):
    import OpenEXR

    with OpenEXR.File(str(path), header_only=True) as f:
        return f.header()["tiles"].mode


_SWAPPED_FOR_A_FIFO = """
import os, sys
from awr_denoise.io import exr, read_image
path, fifo = sys.argv[1:3]
checked = exr._check_magic

def then_swapped(p):
    checked(p)
    os.rename(fifo, path)  # after the checks, before the read: a FIFO where the file was

exr._check_magic = then_swapped
try:
    read_image(path)
except Exception as exc:
    print(type(exc).__name__, exc)
"""


def test_a_fifo_renamed_into_an_inputs_place_after_its_checks_is_refused_not_waited_on(tmp_path):
    """The bindings open by name and wait for a writer on a FIFO: one renamed into the path between the checks and
    the read held the command until a signal (an attack pass, 3 runs in 30). The file read is now the one opened
    and checked without waiting."""
    import subprocess
    import sys

    if not os.path.isdir("/proc/self/fd"):
        pytest.skip("the read goes by name where /proc/self/fd is missing")
    path, fifo = tmp_path / "in.exr", tmp_path / "fifo"
    write_image(path, np.ones((4, 4, 3)))
    os.mkfifo(fifo)
    run = subprocess.run([sys.executable, "-c", _SWAPPED_FOR_A_FIFO, str(path), str(fifo)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("InputFileError") and "is a FIFO" in run.stdout and "in.exr" in run.stdout


def _patched(path: Path, old: bytes, new: bytes) -> Path:
    """``path`` with the one occurrence of ``old`` in its header replaced by ``new`` (as long)."""
    data = path.read_bytes()
    assert len(old) == len(new) and data.count(old) == 1
    path.write_bytes(data.replace(old, new))
    return path


def test_attributes_the_bindings_cannot_read_are_named_not_called_corrupt(tmp_path):
    """A Latin-1 string (the format's strings are bytes) and a rational of denominator 0 are valid OpenEXR that the
    bindings cannot read: "truncated or corrupt EXR ('utf-8' codec can't decode ...)" and "(Fraction(24, 0))" named
    neither the attribute nor what is wrong (an attack pass)."""
    import fractions

    planes = {c: np.ones((4, 4), np.float32) for c in "RGB"}
    header = {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage, "owner": "caf",
              "framesPerSecond": fractions.Fraction(24, 1)}
    with OpenEXR.File(header, planes) as f:
        f.write(str(tmp_path / "latin.exr"))
    (tmp_path / "fps.exr").write_bytes((tmp_path / "latin.exr").read_bytes())
    _patched(tmp_path / "latin.exr", b"caf", b"ca\xe9")
    with pytest.raises(InputFileError, match=r"latin\.exr: attribute owner: a string that is not UTF-8 text, which "
                                             r"the OpenEXR bindings cannot read; rewrite the file without it"):
        read_image(tmp_path / "latin.exr")
    fps = b"framesPerSecond\x00rational\x00" + (8).to_bytes(4, "little") + (24).to_bytes(4, "little")
    _patched(tmp_path / "fps.exr", fps + (1).to_bytes(4, "little"), fps + (0).to_bytes(4, "little"))
    with pytest.raises(InputFileError, match=r"fps\.exr: attribute framesPerSecond: the rational 24/0, which the "
                                             r"OpenEXR bindings cannot read"):
        read_image(tmp_path / "fps.exr")
    # Cut inside its pixels, the same file is still corrupt.
    (tmp_path / "cut.exr").write_bytes(_patched(tmp_path / "fps.exr", fps + (0).to_bytes(4, "little"),
                                                fps + (1).to_bytes(4, "little")).read_bytes()[:-20])
    with pytest.raises(InputFileError, match=r"cut\.exr: truncated or corrupt EXR"):
        read_image(tmp_path / "cut.exr")


def _subsampled_exr(path: Path, shape: tuple[int, int], channels: dict[str, int]) -> Path:
    """An uncompressed scanline EXR of FLOAT channels, each sampled every ``channels[name]`` pixels on both axes (the
    bindings cannot write subsampled channels): its header, offset table and one chunk per line, as OpenEXR's file
    layout describes them."""
    import struct

    h, w = shape

    def attribute(name: str, kind: str, value: bytes) -> bytes:
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value

    names = sorted(channels)
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, channels[n], channels[n]) for n in names)
    box = struct.pack("<4i", 0, 0, w - 1, h - 1)
    header = (b"\x76\x2f\x31\x01" + struct.pack("<i", 2) + attribute("channels", "chlist", chlist + b"\0")
              + attribute("compression", "compression", b"\0") + attribute("dataWindow", "box2i", box)
              + attribute("displayWindow", "box2i", box) + attribute("lineOrder", "lineOrder", b"\0")
              + attribute("pixelAspectRatio", "float", struct.pack("<f", 1.0))
              + attribute("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
              + attribute("screenWindowWidth", "float", struct.pack("<f", 1.0)) + b"\0")
    lines = []
    for y in range(h):
        data = b"".join(np.full(w // channels[n], 0.5, "<f4").tobytes() for n in names if y % channels[n] == 0)
        lines.append(struct.pack("<ii", y, len(data)) + data)
    start = len(header) + 8 * h
    offsets = np.cumsum([start] + [len(line) for line in lines[:-1]]).astype("<u8")
    path.write_bytes(header + offsets.tobytes() + b"".join(lines))
    return path


def test_a_subsampled_channel_is_named_as_such_not_corrupt(tmp_path):
    """A luminance-chroma file's subsampled channels, whose data the bindings do not read, were "truncated or
    corrupt EXR (channel data missing)" (an attack pass)."""
    whole = _subsampled_exr(tmp_path / "whole.exr", (4, 4), {"R": 1, "G": 1, "B": 1})
    np.testing.assert_array_equal(read_image(whole), np.full((4, 4, 3), 0.5))  # the writer's layout is OpenEXR's
    _subsampled_exr(tmp_path / "sub.exr", (4, 4), {"R": 1, "G": 1, "B": 2})
    with pytest.raises(InputFileError, match=r"sub\.exr: B: subsampled 2x2 \(a luminance-chroma image\?\), which is "
                                             r"not read; write every channel at full resolution"):
        read_image(tmp_path / "sub.exr")


_LIMITED_WRITE = """
import resource, sys
import numpy as np
from awr_denoise.io import write_image
from awr_denoise.io.png import write_preview
kind, path, limit = sys.argv[1], sys.argv[2], int(sys.argv[3])
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))  # Python ignores SIGXFSZ: writes fail with EFBIG
try:
    if kind == "exr":  # flat, 594 bytes: written only when the stream closes
        write_image(path, np.full((64, 64, 3), 0.5, np.float32), overwrite=True)
    else:
        write_preview(path, np.random.default_rng(0).random((128, 128, 3)), overwrite=True)
except OSError as exc:
    print(exc)
    sys.exit(1)
"""


@pytest.mark.parametrize(("kind", "limit"), [("exr", 100), ("exr", 400), ("png", 8192)])
def test_a_write_cut_short_is_an_error_and_replaces_nothing(tmp_path, kind, limit):
    """A file size limit (or a full disk) cut the file, and the writer said nothing: the OpenEXR bindings when a
    small file is written at close, OpenImageIO's PNG writer but in geterror(). The cut file was committed over
    the previous one, exit 0 (a red-team pass)."""
    path = tmp_path / f"out.{kind}"
    path.write_bytes(b"the previous output")
    done = subprocess.run([sys.executable, "-c", _LIMITED_WRITE, kind, str(path), str(limit)], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 1, done.stdout + done.stderr
    assert str(path) in done.stdout
    assert path.read_bytes() == b"the previous output"
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no staging folder left


def test_an_input_that_waits_for_data_is_refused_not_waited_on(tmp_path, monkeypatch):
    """A "regular file" that blocks on read (tracefs' trace_pipe linked as an EXR) hung every command reading it
    (a red-team pass): the magic number is read without waiting, as from such a file, here simulated."""
    from awr_denoise.io import exr

    path = tmp_path / "a.exr"
    write_image(path, np.full((4, 4, 3), 0.5, np.float32))

    def would_block(p, *, limit):
        raise BlockingIOError(11, "Resource temporarily unavailable")
    monkeypatch.setattr(exr, "read_without_waiting", would_block)
    with pytest.raises(InputFileError, match="a.exr: not an OpenEXR file .a file that waits for data"):
        read_image(path)


def test_a_preview_cut_at_close_without_a_report_is_written_again(tmp_path, monkeypatch):
    """On a full disk OpenImageIO's PNG writer can cut the file at close and report nothing, not even in geterror()
    (awr render committed a cut preview, a red-team pass): a file without its closing IEND chunk is encoded again."""
    oiio = pytest.importorskip("OpenImageIO")
    from awr_denoise.io import png

    real_create = oiio.ImageOutput.create

    class CutAtClose:
        def __init__(self):
            self.inner = real_create("png")

        def open(self, path, spec):
            self.path = path
            return self.inner.open(path, spec)

        def write_image(self, pixels):
            return self.inner.write_image(pixels)

        def close(self):
            done = self.inner.close()
            with open(self.path, "r+b") as fh:
                fh.truncate(os.path.getsize(self.path) // 2)
            return done

        def geterror(self):
            return ""

    monkeypatch.setattr(oiio.ImageOutput, "create", staticmethod(lambda kind: CutAtClose()))
    path = tmp_path / "p.png"
    png.write_preview(path, np.random.default_rng(0).random((32, 32, 3)))
    assert path.read_bytes().endswith(b"IEND\xaeB`\x82")
    assert path.read_bytes() == png.encode_png(png.tonemap_srgb(np.random.default_rng(0).random((32, 32, 3))))
