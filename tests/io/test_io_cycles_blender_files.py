"""Cycles readers on Blender's own files that a red-team pass found misread (tests/data/cycles,
``tests/data/generate/cycles_files.py``): half-float values Blender clamped to 65504, a light group's
pass named with ``--color``, the views of stereo renders made one eye at a time, lossy codecs, and a
border render without the count pass."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

# Cycles writes no variance: these tests read its files with the colour plane as the variance, only so that
# they read, and the warning that says so (tests/test_io_presets.py) is not what they test.
pytestmark = [pytest.mark.exr, pytest.mark.filterwarnings(
    "ignore:.*the variance plane is the colour plane itself:awr_denoise.errors.InputFileWarning")]
OpenEXR = pytest.importorskip("OpenEXR")

from awr_denoise.cli.main import main  # noqa: E402
from awr_denoise.errors import InputFileError, InputFileWarning  # noqa: E402
from awr_denoise.io import read_independent_renders, read_sample_dump  # noqa: E402
from awr_denoise.io.describe import describe_file  # noqa: E402

CY = Path(__file__).parent.parent / "data" / "cycles"


def _channels(path: Path) -> dict[str, np.ndarray]:
    """Every channel of every part, by name, as Blender wrote it (OpenEXR, not awr)."""
    out = {}
    with OpenEXR.File(str(path), separate_channels=True) as f:
        for part in f.parts:
            out.update({name: np.asarray(ch.pixels) for name, ch in part.channels.items()})
    return out


def _warned(read, *args, **kwargs) -> list[str]:
    """The InputFileWarnings a read gives (every one, not only the first that matches)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read(*args, **kwargs)
    assert all(issubclass(w.category, InputFileWarning) for w in caught)
    return [str(w.message) for w in caught]


def _refused(capsys: pytest.CaptureFixture[str], out: Path, *needles: str) -> None:
    """One line on stderr naming every needle, and no output written."""
    assert not out.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for needle in needles:
        assert needle in err[0], err[0]


def test_half_values_blender_clamped_to_65504_are_refused(tmp_path, capsys):
    """Blender writes a Half channel's overflow as 65504, not Inf: read as a mean it was too small, and
    merged over seeds that all clamped it, of variance 0."""
    files = [CY / f"cycles_half_clamped_{k}.exr" for k in (1, 2)]
    red = _channels(files[0])["ViewLayer.Combined.R"]
    assert red.dtype == np.float16 and (red == 65504).any() and np.isfinite(red).all()
    with pytest.raises(InputFileError, match=r"cycles_half_clamped_1\.exr: ViewLayer\.Combined\.R: \d+ pixel\(s\) "
                                             r"hold 65504, the half-float maximum.*Float \(Full\)"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InputFileWarning)  # no count pass: fixed counts assumed, said
            read_independent_renders(files)
    out = tmp_path / "merged.exr"
    assert main(["merge", "--independent", *map(str, files), "-o", str(out), "-q"]) == 2
    _refused(capsys, out, "cycles_half_clamped_1.exr", "ViewLayer.Combined.R", "65504", "FLOAT")
    out = tmp_path / "denoised.exr"
    assert main(["denoise", str(files[0]), "--variance", "ViewLayer.Combined", "-o", str(out), "-q"]) == 2
    _refused(capsys, out, "cycles_half_clamped_1.exr", "ViewLayer.Combined.R", "65504", "FLOAT")


def test_a_light_groups_pass_named_as_colour_keeps_the_layers_count_pass(tmp_path, capsys):
    """``--color ViewLayer.Combined_key`` of an adaptive render: counted by the layer's Debug Sample Count
    (Blender's counts), not called countless, and no ``--spp`` overriding them."""
    files = [CY / f"cycles_lightgroup_{k}.exr" for k in (1, 2)]
    truth = sum(np.rint(_channels(f)["ViewLayer.Debug Sample Count.X"] * 64).astype(np.int64) for f in files)
    assert len(np.unique(truth)) > 1  # adaptive: the pixels took different counts
    info = describe_file(files[0], color="ViewLayer.Combined_key")
    assert info["preset"] == "cycles" and info["colour"] == "ViewLayer.Combined_key"
    assert info["count"]["min"] < info["count"]["max"] == 64
    assert not any("no sample count" in n for n in info["notes"] + info["missing"])
    with warnings.catch_warnings():
        warnings.simplefilter("error", InputFileWarning)  # a fixed-count warning: the count pass not read
        buf = read_independent_renders(files, color="ViewLayer.Combined_key").buffer
    np.testing.assert_array_equal(buf.count, truth)
    key = np.stack([_channels(f)[f"ViewLayer.Combined_key.{c}"] for f in files for c in "RGB"]).reshape(2, 3, 32, 32)
    weights = np.stack([np.rint(_channels(f)["ViewLayer.Debug Sample Count.X"] * 64) for f in files])[:, None]
    np.testing.assert_allclose(buf.mean, np.moveaxis((key * weights).sum(0) / weights.sum(0), 0, -1), rtol=1e-6)
    # The generic layout cannot read the pass: --spp there is refused, not laid over Blender's counts.
    out = tmp_path / "m.exr"
    assert main(["merge", "--independent", *map(str, files), "--preset", "generic", "--color",
                 "ViewLayer.Combined_key", "--spp", "64", "-o", str(out), "-q"]) == 2
    _refused(capsys, out, "cycles_lightgroup_1.exr", "ViewLayer.Debug Sample Count.X", "--spp", "--preset cycles")


def test_the_missing_variance_names_the_pass_read(tmp_path, capsys):
    """Blender wrote Noisy Image beside Combined (its denoiser on): the pass read, Noisy Image, is the one the
    refusal names (it named Combined)."""
    out = tmp_path / "o.exr"
    assert main(["denoise", str(CY / "cycles_default.exr"), "-o", str(out)]) == 2
    _refused(capsys, out, "cycles_default.exr: ViewLayer.Noisy Image: Blender Cycles writes no variance pass",
             "awr merge --independent")


def test_the_denoisers_output_named_as_the_colour_is_warned_about():
    """``--color ViewLayer.Combined`` beside a Noisy Image pass read the denoiser's output as means of samples
    without a word (auto-detection says which it takes; a walkthrough)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read_sample_dump(CY / "cycles_default.exr", color="ViewLayer.Combined", variance="ViewLayer.Noisy Image")
    assert any(re.search(r"ViewLayer\.Combined: the denoiser's output .* name ViewLayer\.Noisy Image", str(w.message))
               for w in caught)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read_sample_dump(CY / "cycles_default.exr", color="ViewLayer.Noisy Image", variance="ViewLayer.Combined")
    assert not any("denoiser's output" in str(w.message) for w in caught)


def test_a_colour_plane_names_its_layer(capsys):
    """``--color Second.Combined`` of a two-layer render takes Second's count pass and header (48 samples),
    without ``--layer``; the file's layers are still refused as ambiguous when no plane names one."""
    path = CY / "cycles_two_layers.exr"
    ch = _channels(path)
    with pytest.warns(InputFileWarning, match="Second.Debug Sample Count.X"):
        dump = read_sample_dump(path, color="Second.Combined", variance="Second.Combined")
    np.testing.assert_array_equal(dump.buffer.count, np.rint(ch["Second.Debug Sample Count.X"] * 48))
    np.testing.assert_array_equal(dump.buffer.mean[..., 0], ch["Second.Combined.R"])
    first = describe_file(path, color="ViewLayer.Combined")
    assert first["count"]["max"] == 32
    with pytest.raises(InputFileError, match="several view layers"):
        read_sample_dump(path, variance="Second.Combined")
    # A layer that contradicts the plane's own: Second's colour read with ViewLayer's 32 samples (a walkthrough).
    with pytest.raises(InputFileError, match=r"--color Second\.Combined is a plane of layer Second, not of "
                                             r"layer='ViewLayer'"):
        read_sample_dump(path, color="Second.Combined", variance="Second.Combined", layer="ViewLayer")
    with pytest.warns(InputFileWarning, match="Second.Debug Sample Count.X"):  # the plane's own layer named: read
        assert read_sample_dump(path, color="Second.Combined", variance="Second.Combined",
                                layer="Second").buffer.count.max() == 48


def test_stereo_views_rendered_apart_are_not_merged_as_seeds(tmp_path, capsys):
    """Each file holds one view (every part says left, or right): merged, their spread was the parallax."""
    files = [CY / "cycles_only_left.exr", CY / "cycles_only_right.exr"]
    with pytest.raises(InputFileError, match=r"cycles_only_right\.exr: view 'right' does not match view 'left' "
                                             r"of .*cycles_only_left\.exr"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InputFileWarning)  # every pixel's count the same: said
            read_independent_renders(files)
    out = tmp_path / "m.exr"
    assert main(["merge", "--independent", *map(str, files), "-o", str(out), "-q"]) == 2
    _refused(capsys, out, "cycles_only_left.exr", "cycles_only_right.exr", "'left'", "'right'")


def test_info_on_a_one_view_file_describes_that_view(capsys):
    """A multiview file with one view is that view's render, not an image."""
    path = CY / "cycles_only_right.exr"
    info = describe_file(path)
    assert info["views"] == ["right"]
    assert info["kind"] == "samples" and info["preset"] == "cycles" and info["colour"] == "ViewLayer.Combined"
    counts = np.rint(_channels(path)["ViewLayer.Debug Sample Count.X"] * 32)
    assert info["count"] == {"min": counts.min(), "mean": counts.mean(), "max": counts.max()}
    assert main(["info", str(path)]) == 0
    head = capsys.readouterr().out.splitlines()[0]
    assert head.endswith("views right, samples")


def test_lossy_codecs_are_warned_about_when_merging_and_describing(tmp_path):
    files = [CY / f"cycles_dwaa_{k}.exr" for k in (1, 2)]
    said = _warned(read_independent_renders, files)
    assert [f.name for f in files if any(f"{f.name}: DWAA compression is lossy" in w for w in said)] == \
        [f.name for f in files]
    info = describe_file(files[0])
    assert any("DWAA compression is lossy" in w for w in info["warnings"])
    # A lossless file says nothing of it.
    assert not any("lossy" in w for w in describe_file(CY / "cycles_seed_1.exr")["warnings"])


def test_a_border_render_without_the_count_pass_warns_of_its_black_pixels():
    """Outside an uncropped border Blender writes R = G = B = A = 0: without the count pass those pixels
    read as the requested samples of black, which the warning says, with how many."""
    path = CY / "cycles_border_nocount.exr"
    ch = _channels(path)
    black = int(np.all([ch[f"ViewLayer.Combined.{c}"] == 0 for c in "RGBA"], axis=0).sum())
    assert 0 < black < 32 * 32
    info = describe_file(path)
    assert any(f"ViewLayer.Combined: {black} pixel(s) are 0 in R, G, B and A" in w and "16 samples of black" in w
               for w in info["warnings"])
    assert any(f"{black} pixel(s) are 0" in w for w in _warned(read_sample_dump, path, variance="ViewLayer.Combined"))
    # Rendered everywhere, nothing to say.
    assert not any("are 0 in R, G, B and A" in w for w in describe_file(CY / "cycles_seed_1.exr")["warnings"])


def test_info_of_a_view_the_file_does_not_have_names_its_views(capsys):
    """``awr info stereo.exr --view Left`` said "--view: describes a sample dump; ... is an image": no part matched
    the name, so the file was described as an image (a walkthrough). denoise named the views; info does too."""
    assert main(["info", str(CY / "cycles_stereo.exr"), "--view", "Left"]) == 2
    assert "cycles_stereo.exr: no view 'Left' (views: left, right)" in capsys.readouterr().err
    assert main(["info", str(CY / "cycles_stereo.exr"), "--view", "left"]) == 0


def test_info_json_gives_spp_and_total_samples_without_a_variance(capsys):
    """A Cycles file without variance: the JSON's documented ``spp`` was null and ``total_samples`` absent, the
    counts under an undocumented ``count`` only (a walkthrough)."""
    import json

    assert main(["info", str(CY / "cycles_converged.exr"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["spp"] == {"min": 48.0, "mean": 50.546875, "max": 304.0} and info["total_samples"] == 51760
    assert main(["info", str(CY / "cycles_converged.exr")]) == 0
    assert "samples per pixel: min 48 / mean 50.55 / max 304; 51760 total" in capsys.readouterr().out


def test_info_of_a_file_of_two_view_layers_describes_the_first(capsys):
    """Two view layers gave info only the ambiguity error (exit 2, nothing in --json), where a file of two views is
    described in its first: now described in its first layer, the choice listed as missing."""
    assert main(["info", str(CY / "cycles_two_layers.exr")]) == 0
    out = capsys.readouterr().out
    assert "a layer: the file has 2 (Second, ViewLayer); choose one with --layer (described here: Second)" in out
    assert "samples per pixel: min 48" in out
    with pytest.raises(InputFileError, match="several view layers"):  # the readers still refuse to choose
        read_sample_dump(CY / "cycles_two_layers.exr", variance="Second.Combined")
