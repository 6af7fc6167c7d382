"""--alb, --nrm, --depth (cli/common.py, cli/paths.py): features read from files or planes, checked
like every other input, carried into dumps, shown by ``awr info``, said to be unused by the
reconstruction without ``--guide``, and used with it."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("OpenEXR")

from awr_denoise import SampleBuffer, SampleRequest  # noqa: E402
from awr_denoise.cli.denoise_cmd import unused_features  # noqa: E402
from awr_denoise.errors import BackendError  # noqa: E402
from awr_denoise.cli.main import main  # noqa: E402
from awr_denoise.io import (  # noqa: E402
    read_header,
    read_image,
    read_provenance,
    read_sample_dump,
    write_image,
    write_request,
    write_sample_buffer,
)
from cli_helpers import H, W, dump_buffer, one_error_line  # noqa: E402

pytestmark = pytest.mark.exr

PBRT = Path(__file__).resolve().parents[1] / "data" / "pbrt" / "pbrt_gbuffer_default.exr"


def _images(tmp_path: Path) -> None:
    write_sample_buffer(tmp_path / "d.exr", dump_buffer(0))
    write_image(tmp_path / "alb.exr", np.full((H, W, 3), 0.5))
    write_image(tmp_path / "nrm.exr", np.broadcast_to([0.0, 0.0, 1.0], (H, W, 3)).copy(), channels=("X", "Y", "Z"))


def _refused(tmp_path: Path, capsys, cases: list[tuple[list[str], str]]) -> None:
    """Each option set is refused with exit 2 and one line holding ``message``, and nothing is written."""
    for bad, message in cases:
        out = tmp_path / "bad.exr"
        assert main(["denoise", str(tmp_path / "d.exr"), *bad, "-o", str(out)]) == 2, bad
        assert message in one_error_line(capsys.readouterr().err)
        assert not out.exists()


def test_denoise_reads_the_features_and_says_they_are_unused(tmp_path, capsys):
    _images(tmp_path)
    plain = tmp_path / "plain.exr"
    assert main(["denoise", str(tmp_path / "d.exr"), "-o", str(plain)]) == 0
    assert "features" not in capsys.readouterr().err
    out = tmp_path / "o.exr"
    assert main(["denoise", str(tmp_path / "d.exr"), "--alb", str(tmp_path / "alb.exr"),
                 "--nrm", str(tmp_path / "nrm.exr"), "-o", str(out)]) == 0
    assert "features albedo, normal read but not used (see --guide)" in capsys.readouterr().err
    np.testing.assert_array_equal(read_image(out), read_image(plain))   # not used: the same image
    assert "--guide oidn or --guide features uses them" in _help(capsys, "denoise")


def test_denoise_guide_features_uses_them(tmp_path, capsys):
    _images(tmp_path)
    plain, guided = tmp_path / "plain.exr", tmp_path / "guided.exr"
    assert main(["denoise", str(tmp_path / "d.exr"), "-o", str(plain), "-q"]) == 0
    assert main(["denoise", str(tmp_path / "d.exr"), "--alb", str(tmp_path / "alb.exr"), "--guide", "features",
                 "-o", str(guided)]) == 0
    assert "not used" not in capsys.readouterr().err
    assert not np.array_equal(read_image(guided), read_image(plain))


def test_denoise_guide_features_without_features_is_refused(tmp_path, capsys):
    _images(tmp_path)
    out = tmp_path / "o.exr"
    assert main(["denoise", str(tmp_path / "d.exr"), "--guide", "features", "-o", str(out)]) == 2
    one_error_line(capsys.readouterr().err, "d.exr: holds no feature buffers", "--alb")  # the file, named
    assert not out.exists()


def test_denoise_guide_needs_wiener_stages(tmp_path, capsys):
    _images(tmp_path)
    out = tmp_path / "o.exr"
    assert main(["denoise", str(tmp_path / "d.exr"), "--guide", "oidn", "--stages", "1", "-o", str(out)]) == 2
    assert "--guide oidn: it gives the pilot of the Wiener stages; it needs --stages 2 or more" in one_error_line(capsys.readouterr().err)
    assert not out.exists()


def test_denoise_guide_oidn(tmp_path, capsys):
    pytest.importorskip("pyoidn", reason="the OIDN guide needs the extra oidn")
    _images(tmp_path)
    plain, guided = tmp_path / "plain.exr", tmp_path / "guided.exr"
    assert main(["denoise", str(tmp_path / "d.exr"), "-o", str(plain), "-q"]) == 0
    assert main(["denoise", str(tmp_path / "d.exr"), "--alb", str(tmp_path / "alb.exr"),
                 "--nrm", str(tmp_path / "nrm.exr"), "--guide", "oidn", "-o", str(guided), "-q"]) == 0
    image = read_image(guided)
    assert np.isfinite(image).all() and not np.array_equal(image, read_image(plain))
    np.testing.assert_allclose(image.mean(axis=(0, 1)), read_image(plain).mean(axis=(0, 1)), rtol=1e-3)


def test_denoise_guide_projection(tmp_path, capsys):
    """``--guide-projection S`` reaches the reconstruction (0: the guide is the pilot only) and is
    recorded; out of [0, 1], not a number, or without ``--guide oidn`` it is refused before any output."""
    pytest.importorskip("pyoidn", reason="the OIDN guide needs the extra oidn")
    _images(tmp_path)
    images = {}
    for share in ("0", "1"):
        out = tmp_path / f"g{share}.exr"
        assert main(["denoise", str(tmp_path / "d.exr"), "--guide", "oidn", "--guide-projection", share,
                     "-o", str(out), "-q"]) == 0
        images[share] = read_image(out)
        assert float(read_provenance(read_header(out))["guide_projection"]) == float(share)
    assert not np.array_equal(images["0"], images["1"])
    _refused(tmp_path, capsys, [
        (["--guide", "oidn", "--guide-projection", "1.5"], "--guide-projection: must be <= 1"),
        (["--guide", "oidn", "--guide-projection", "nan"], "--guide-projection: must be a finite number"),
        (["--guide-projection", "0.3"], "--guide-projection: it is the share of a guide's projection"),
        (["--guide", "features", "--guide-projection", "0.3"], "it needs --guide oidn"),
        (["--guide", "oidn", "--guide-projection", "0.3", "--mode", "luminance"],
         "--guide-projection 0.3: not with --mode luminance, where the means are not projected")])
    assert main(["denoise", str(tmp_path / "d.exr"), "--guide", "oidn", "--guide-projection", "0", "--mode",
                 "luminance", "-o", str(tmp_path / "lum.exr"), "-q"]) == 0


def test_denoise_guide_auxiliary(tmp_path, capsys):
    """``--guide-auxiliary MODE`` reaches OIDN (none: the colour alone, the features read said unused) and is
    recorded with OIDN's quality, as the default's prefilter is; without ``--guide oidn``, or with ``--alb`` or
    ``--nrm`` it would leave out, it is refused before any output."""
    pytest.importorskip("pyoidn", reason="the OIDN guide needs the extra oidn")
    _images(tmp_path)
    images = {}
    for mode in (None, "prefilter", "none"):
        out = tmp_path / f"g{mode}.exr"
        assert main(["denoise", str(tmp_path / "d.exr"), "--alb", str(tmp_path / "alb.exr"), "--nrm",
                     str(tmp_path / "nrm.exr"), "--guide", "oidn", *(["--guide-auxiliary", mode] if mode else []),
                     "-o", str(out), "-q"] if mode != "none" else
                    ["denoise", str(tmp_path / "d.exr"), "--guide", "oidn", "--guide-auxiliary", mode,
                     "-o", str(out), "-q"]) == 0
        images[mode] = read_image(out)
        recorded = read_provenance(read_header(out))
        assert (recorded["guide_auxiliary"], recorded["guide_quality"]) == (mode or "prefilter", "high")
    np.testing.assert_array_equal(images[None], images["prefilter"])
    assert not np.array_equal(images["prefilter"], images["none"])
    features = ("albedo", "normal", "depth")
    assert unused_features(features, "oidn", "none") == features and unused_features(features, "oidn") == ("depth",)
    _refused(tmp_path, capsys, [
        (["--guide-auxiliary", "none"],
         "--guide-auxiliary none: it says how OIDN takes the albedo and normal; it needs --guide oidn"),
        (["--guide", "features", "--guide-auxiliary", "clean"], "it needs --guide oidn"),
        (["--guide", "oidn", "--guide-auxiliary", "none", "--alb", str(tmp_path / "alb.exr")],
         "--alb: --guide-auxiliary none leaves the albedo and normal out"),
        (["--guide", "oidn", "--guide-auxiliary", "dirty"], "invalid choice: 'dirty'"),
        (["--guide-auxiliary", "none", "--alb", str(tmp_path / "alb.exr")], "it needs --guide oidn"),
        (["--guide", "oidn", "--guide-auxiliary", "noisy"], "d.exr holds no albedo, so OIDN takes the colour alone"),
        (["--guide", "oidn", "--guide-auxiliary", "clean", "--alb", str(tmp_path / "alb.exr")],
         "--guide-auxiliary clean: OIDN takes the features as clean only as a pair, and")])


def test_a_dump_oidn_cannot_denoise_is_named_as_the_file(tmp_path, capsys):
    """A one-channel dump with --guide oidn was refused as "buffer: ..." (the library's argument), not by its name."""
    pytest.importorskip("pyoidn", reason="the OIDN guide needs the extra oidn")
    mono = Path(__file__).parent.parent / "data" / "mitsuba" / "mitsuba_mono_aov.exr"
    assert main(["denoise", str(mono), "--spp", "8", "--guide", "oidn", "-o", str(tmp_path / "o.exr"), "-q"]) == 2
    assert one_error_line(capsys.readouterr().err).startswith(f"awr: error: {mono}: OIDN (guides.oidn / --guide oidn) "
                                                              "denoises one three-channel colour")
    assert not (tmp_path / "o.exr").exists()


def test_a_readers_warning_is_said_once(tmp_path, capsys):
    """The first frame read for the options' checks (``--nrm`` without ``--alb``) said the reader's warnings a second
    time: an albedo given as the normal was "too long" twice."""
    pytest.importorskip("pyoidn", reason="the OIDN guide needs the extra oidn")
    pbrt = Path(__file__).parent.parent / "data" / "pbrt" / "pbrt_gbuffer_default.exr"
    assert main(["denoise", str(pbrt), "--guide", "oidn", "--nrm", f"{pbrt}:Albedo", "-o",
                 str(tmp_path / "o.exr"), "-q"]) == 0
    assert capsys.readouterr().err.count("Albedo as the normal") == 1


def test_denoise_says_oidn_failed_in_one_line(tmp_path, capsys, monkeypatch):
    """OIDN failing at run time (out of memory) is one line in OIDN's words and exit 1, no "internal error", and no
    output is written."""
    import awr_denoise.guides as guides
    import awr_denoise.cli.denoise_cmd as denoise_cmd

    def failed(*args, **kwargs):
        raise BackendError("OIDN color+albedo+normal failed: out of memory")

    monkeypatch.setattr(denoise_cmd, "oidn_available", lambda: True)
    monkeypatch.setattr(guides, "oidn", failed)
    _images(tmp_path)
    capsys.readouterr()
    assert main(["denoise", str(tmp_path / "d.exr"), "--guide", "oidn", "-o", str(tmp_path / "o.exr")]) == 1
    assert one_error_line(capsys.readouterr().err) == "awr: error: OIDN color+albedo+normal failed: out of memory"
    assert not (tmp_path / "o.exr").exists()


def test_denoise_guide_oidn_without_pyoidn_is_refused(tmp_path, capsys, monkeypatch):
    import awr_denoise.cli.denoise_cmd as denoise_cmd
    monkeypatch.setattr(denoise_cmd, "oidn_available", lambda: False)
    _images(tmp_path)
    out = tmp_path / "o.exr"
    assert main(["denoise", str(tmp_path / "d.exr"), "--guide", "oidn", "-o", str(out)]) == 1  # an extra missing
    line = one_error_line(capsys.readouterr().err)
    assert "--guide oidn: the OIDN guide needs pyoidn" in line and 'pip install "awr-denoise[oidn]"' in line
    assert not out.exists()


def _help(capsys, command: str) -> str:
    try:
        code = main([command, "--help"])
    except SystemExit as exc:
        code = exc.code
    assert code == 0
    return " ".join(capsys.readouterr().out.split())


def test_info_shows_the_features_found(tmp_path, capsys):
    assert main(["info", str(PBRT)]) == 0
    out = capsys.readouterr().out
    assert "feature albedo from Albedo: mean min 0 / max 0.8853" in out
    assert "feature normal from Ns" in out and "feature depth from P.Z" in out
    assert "awr denoise --guide features or --guide oidn uses them" in out
    _images(tmp_path)
    assert main(["info", str(tmp_path / "d.exr"), "--depth", f"{tmp_path / 'alb.exr'}:G", "--json"]) == 0
    assert '"depth"' in capsys.readouterr().out


def test_merge_carries_the_features_of_the_batches(tmp_path, capsys):
    rng = np.random.default_rng(1)
    request = SampleRequest.uniform((H, W), 4)
    write_request(tmp_path / "req.exr", request)
    rows, cols, _ = request.pixel_list()
    depth = rng.uniform(1, 2, len(rows))
    batch = SampleBuffer.from_samples(np.stack([rows, cols], 1), rng.random((len(rows), 3)), (H, W),
                                      features={"depth": depth})
    write_sample_buffer(tmp_path / "b.exr", batch)
    assert main(["merge", "--request", str(tmp_path / "req.exr"), str(tmp_path / "b.exr"),
                 "-o", str(tmp_path / "m.exr"), "-q"]) == 0
    merged = read_sample_dump(tmp_path / "m.exr").buffer
    np.testing.assert_allclose(merged.features["depth"].mean, batch.features["depth"].mean, rtol=1e-6)


@pytest.mark.parametrize("args, needles", [
    (["--alb", "{t}/none.exr"], ["--alb", "none.exr", "no such file"]),
    (["--nrm", "{t}/alb.exr:Nope"], ["alb.exr", "Nope", "no normal channel"]),
    (["--depth", "{t}/alb.exr"], ["alb.exr", "no depth channels (Z or a single channel"]),
    (["--alb", "{t}/small.exr"], ["small.exr", "size 4x4 does not match"]),
    (["--alb", "{t}/nan.exr"], ["nan.exr", "NaN"]),
    (["--alb", "{t}/o.exr", "-o", "{t}/o.exr", "--overwrite"], ["o.exr", "-o/--output is the input", "--alb"]),
    (["--alb", "{t}/dir"], ["--alb", "dir"]),
])
def test_bad_feature_options_are_one_line_and_write_nothing(tmp_path, capsys, args, needles):
    _images(tmp_path)
    write_image(tmp_path / "small.exr", np.zeros((4, 4, 3)))
    nan = np.full((H, W, 3), 0.5, np.float32)
    nan[3, 4, 1] = np.nan
    write_image(tmp_path / "o.exr", np.zeros((H, W, 3)))
    _write_raw(tmp_path / "nan.exr", nan)
    (tmp_path / "dir").mkdir()
    before = sorted(os.listdir(tmp_path))
    output = [] if "-o" in args else ["-o", str(tmp_path / "out.exr")]  # given twice, it would be refused as such
    code = main(["denoise", str(tmp_path / "d.exr"), *output, *[a.format(t=tmp_path) for a in args]])
    assert code == 2
    one_error_line(capsys.readouterr().err, *needles)
    assert sorted(os.listdir(tmp_path)) == before


def _write_raw(path: Path, rgb: np.ndarray) -> None:
    import OpenEXR

    with OpenEXR.File({}, {c: np.ascontiguousarray(rgb[..., i]) for i, c in enumerate("RGB")}) as f:
        f.write(str(path))


def test_merge_independent_refuses_feature_options(tmp_path, capsys):
    _images(tmp_path)
    write_sample_buffer(tmp_path / "e.exr", dump_buffer(1))
    code = main(["merge", "--independent", str(tmp_path / "d.exr"), str(tmp_path / "e.exr"), "--alb",
                 str(tmp_path / "alb.exr"), "-o", str(tmp_path / "m.exr"), "--preset", "generic", "--color", "RGB"])
    assert code == 2
    one_error_line(capsys.readouterr().err, "--alb", "--independent")


def test_render_writes_the_tracers_features_into_the_dump(tmp_path, capsys):
    pytest.importorskip("embreex")
    out = tmp_path / "r.exr"
    assert main(["render", "--scene", "sky_objects", "--width", "24", "--height", "16", "--spp", "4", "--uniform",
                 "--features", "depth,albedo", "-o", str(out), "-q"]) == 0
    buffer = read_sample_dump(out).buffer
    assert tuple(buffer.features) == ("albedo", "depth")
    np.testing.assert_array_equal(buffer.features["depth"].count, buffer.count)
    assert main(["render", "--scene", "sky_objects", "--features", "shade", "-o", str(tmp_path / "x.exr")]) == 2
    one_error_line(capsys.readouterr().err, "--features", "'shade' is not one of albedo, normal, depth")
    assert not (tmp_path / "x.exr").exists()


def test_render_guide_features_uses_the_rendered_features(tmp_path, capsys):
    pytest.importorskip("embreex")
    common = ["render", "--scene", "sky_objects", "--width", "24", "--height", "16", "--spp", "4", "--uniform"]
    assert main(common + ["--features", "all", "-o", str(tmp_path / "plain.exr")]) == 0
    assert "not used: see --guide" in capsys.readouterr().err
    assert main(common + ["--features", "all", "--guide", "features", "-o", str(tmp_path / "guided.exr")]) == 0
    assert "not used" not in capsys.readouterr().err
    plain, guided = (read_image(tmp_path / f"{name}.denoised.exr") for name in ("plain", "guided"))
    assert not np.array_equal(plain, guided)
    out = tmp_path / "none.exr"
    assert main(common + ["--guide", "features", "-o", str(out)]) == 2  # refused before rendering
    one_error_line(capsys.readouterr().err, "--guide features: nothing to guide with; render the features too")
    assert not out.exists()


def test_render_guide_auxiliary(tmp_path, capsys):
    """A way of taking the albedo with no albedo rendered is refused before rendering; with ``none`` the rendered
    features are said to be left out by it, and a normal alone is not refused for want of an albedo."""
    pytest.importorskip("embreex")
    pytest.importorskip("pyoidn", reason="the OIDN guide needs the extra oidn")
    common = ["render", "--scene", "sky_objects", "--width", "24", "--height", "16", "--spp", "4", "--uniform",
              "--guide", "oidn"]
    out = tmp_path / "clean.exr"
    assert main(common + ["--guide-auxiliary", "clean", "-o", str(out)]) == 2
    one_error_line(capsys.readouterr().err, "--guide-auxiliary clean: OIDN takes the colour alone without an albedo")
    assert not out.exists()
    assert main(common + ["--guide-auxiliary", "clean", "--features", "albedo", "-o", str(out)]) == 2
    one_error_line(capsys.readouterr().err, "--guide-auxiliary clean: OIDN takes the features as clean only as a pair")
    assert not out.exists()
    for features in ("albedo,normal", "normal"):
        assert main(common + ["--guide-auxiliary", "none", "--features", features,
                              "-o", str(tmp_path / f"n{len(features)}.exr")]) == 0
        assert "not used: --guide-auxiliary none leaves them out" in capsys.readouterr().err
    assert read_provenance(read_header(tmp_path / "n6.denoised.exr"))["guide_auxiliary"] == "none"
    # Without features rendered OIDN takes the colour alone: said in the summary, as --guide features is refused.
    assert main(common + ["-o", str(tmp_path / "bare.exr")]) == 0
    assert "OIDN took the colour alone (--features albedo,normal" in capsys.readouterr().err


def test_render_features_from_a_renderer_that_renders_none_is_refused(tmp_path, capsys, monkeypatch):
    """The registry says which renderers render features (their module's list_features())."""
    monkeypatch.chdir(tmp_path)
    code = main(["render", "--renderer", "synthetic", "edges", "--width", "8", "--height", "8", "--spp", "2",
                 "-o", "r.exr", "--features", "albedo", "-q"])
    assert code == 2
    one_error_line(capsys.readouterr().err, "--features", "synthetic", "does not render albedo", "no features")
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(("option", "value", "key", "default", "refusals"), [
    ("--guard-window", "13", "guard_window", 9, [(["--guard-window", "8"], "--guard-window: must be odd"),
                                                 (["--guard-window", "0"], "--guard-window: must be >= 1"),
                                                 (["--guard-window", "2000"], "--guard-window: must be <= 1023")]),
    ("--guard-probes", "1", "guard_probes", 0, [(["--guard-probes", "-1"], "--guard-probes: must be >= 0"),
                                               (["--guard-probes", "1.5"], "--guard-probes")]),
])
def test_denoise_guard_options(tmp_path, capsys, option, value, key, default, refusals):
    """``--guard-window W`` and ``--guard-probes N`` reach the reconstruction and are recorded; out of range,
    not whole, or with ``--stages 1`` they are refused before any output."""
    _images(tmp_path)
    plain, given = tmp_path / "default.exr", tmp_path / "given.exr"
    assert main(["denoise", str(tmp_path / "d.exr"), "-o", str(plain), "-q"]) == 0
    assert main(["denoise", str(tmp_path / "d.exr"), option, value, "-o", str(given), "-q"]) == 0
    assert int(read_provenance(read_header(given))[key]) == int(value)
    assert int(read_provenance(read_header(plain))[key]) == default
    assert not np.array_equal(read_image(plain), read_image(given))
    _refused(tmp_path, capsys, [*refusals, ([option, value, "--stages", "1"], "it needs --stages 2 or more")])


def test_denoise_guard_probes_are_refused_with_the_oidn_guide(tmp_path, capsys):
    """The guide's projection comes after the probed stages; 0 probes (the default) is accepted with it."""
    pytest.importorskip("pyoidn", reason="the OIDN guide needs the extra oidn")
    _images(tmp_path)
    _refused(tmp_path, capsys, [(["--guide", "oidn", "--guard-probes", "1"],
                                 "--guard-probes 1: not with --guide oidn")])
    out = tmp_path / "guided.exr"
    assert main(["denoise", str(tmp_path / "d.exr"), "--guide", "oidn", "--guard-probes", "0",
                 "-o", str(out), "-q"]) == 0


def test_guide_oidn_says_or_refuses_the_features_it_does_not_use(tmp_path, capsys):
    """OIDN takes a normal only beside an albedo and no depth: ``--nrm`` without an albedo, ``--depth`` and a
    rendered normal without an albedo did nothing with ``--guide oidn``, without a word (a red-team pass)."""
    from awr_denoise.guides import oidn_available

    if not oidn_available():
        pytest.skip("the OIDN guide needs the extra oidn (pyoidn)")
    _images(tmp_path)
    write_image(tmp_path / "depth.exr", np.full((H, W, 1), 2.0), channels=("Z",))
    _refused(tmp_path, capsys, [
        (["--guide", "oidn", "--nrm", str(tmp_path / "nrm.exr")], "--nrm: OIDN takes a normal only beside an albedo"),
        (["--guide", "oidn", "--alb", str(tmp_path / "alb.exr"), "--depth", str(tmp_path / "depth.exr")],
         "--depth: --guide oidn uses no depth")])
    assert main(["denoise", str(tmp_path / "d.exr"), "--guide", "oidn", "--alb", str(tmp_path / "alb.exr"),
                 "--nrm", str(tmp_path / "nrm.exr"), "-o", str(tmp_path / "o.exr")]) == 0
    assert "not used" not in capsys.readouterr().err
    # A dump's own normal without an albedo, or its depth, is said to be unused.
    carried = SampleBuffer.from_moments(np.full((H, W), 4), np.full((H, W, 3), 0.5), np.full((H, W, 3), 0.01),
                                        features={"normal": SampleBuffer.from_moments(
                                            np.full((H, W), 4), np.broadcast_to([0.0, 0.0, 1.0], (H, W, 3)).copy(),
                                            np.zeros((H, W, 3)), channels=("X", "Y", "Z"))})
    write_sample_buffer(tmp_path / "n.exr", carried)
    assert main(["denoise", str(tmp_path / "n.exr"), "--guide", "oidn", "-o", str(tmp_path / "n.out.exr")]) == 0
    assert "features normal read but not used by --guide oidn" in capsys.readouterr().err
    common = ["render", "--renderer", "synthetic", "edges", "--width", "16", "--height", "12", "--spp", "2"]
    assert main([*common, "--features", "normal", "--guide", "oidn", "-o", str(tmp_path / "r.exr")]) == 2
    one_error_line(capsys.readouterr().err, "--features: --guide oidn uses a normal only beside an albedo")


@pytest.mark.parametrize("options, words", [
    (["--guide", "oidn", "--guide-projection", "0.3", "--mode", "luminance"], "--guide-projection 0.3: not with"),
    (["--guide", "oidn", "--stages", "1"], "--guide oidn: it gives the pilot of the Wiener stages"),
])
def test_render_refuses_reconstruction_options_before_loading_its_scene(tmp_path, capsys, monkeypatch, options, words):
    """Checked only once the image size was known, after a Mitsuba scene file was loaded and rendered: a whole
    render, then exit 2."""
    from awr_denoise.cli import render_cmd

    def loaded(args):
        raise AssertionError("the scene was loaded before the options were checked")

    monkeypatch.setattr(render_cmd, "_scene", loaded)
    assert main(["render", "--scene", "default", "--spp", "2", "-o", str(tmp_path / "d.exr"), *options]) == 2
    one_error_line(capsys.readouterr().err, words)
    assert list(tmp_path.iterdir()) == []


def test_the_header_records_the_planes_that_guided_the_image(tmp_path, capsys):
    """Where each feature came from is recorded beside ``awr:features`` when features guide the image: the input's
    planes as named in it, another file's as ``name.exr:plane`` (its name, as ``awr:input`` records the input's)."""
    out = tmp_path / "pbrt.exr"
    assert main(["denoise", str(PBRT), "--guide", "features", "-o", str(out), "-q"]) == 0
    header = read_header(out)
    assert (header["awr:albedo_plane"], header["awr:normal_plane"], header["awr:depth_plane"]) == (
        "Albedo", "Ns", "P.Z")
    _images(tmp_path)
    out = tmp_path / "files.exr"
    assert main(["denoise", str(tmp_path / "d.exr"), "--alb", str(tmp_path / "alb.exr"), "--nrm",
                 str(tmp_path / "nrm.exr"), "--guide", "features", "-o", str(out), "-q"]) == 0
    header = read_header(out)
    assert (header["awr:albedo_plane"], header["awr:normal_plane"]) == ("alb.exr:R,G,B", "nrm.exr:X,Y,Z")
    assert "awr:depth_plane" not in header and str(tmp_path) not in str(header)
    dump = tmp_path / "with_features.exr"  # a dump's own features keep their layout's names
    write_sample_buffer(dump, read_sample_dump(tmp_path / "d.exr", albedo=str(tmp_path / "alb.exr")).buffer)
    out = tmp_path / "dump.exr"
    assert main(["denoise", str(dump), "--guide", "features", "-o", str(out), "-q"]) == 0
    assert read_header(out)["awr:albedo_plane"] == "albedo"
    out = tmp_path / "unguided.exr"  # read but not used: nothing said of them
    assert main(["denoise", str(PBRT), "-o", str(out), "-q"]) == 0
    assert not any(key.endswith("_plane") for key in read_header(out))
    assert read_sample_dump(PBRT).feature_planes == {"albedo": "Albedo", "normal": "Ns", "depth": "P.Z"}


def test_the_summary_says_when_oidn_took_the_colour_alone(tmp_path, capsys):
    """A dump without an albedo, ``--guide oidn``: OIDN took the colour alone, recorded in the header only (a
    walkthrough); the summary says it, as render's does."""
    pytest.importorskip("pyoidn")
    write_sample_buffer(tmp_path / "d.exr", dump_buffer(0))
    assert main(["denoise", str(tmp_path / "d.exr"), "--guide", "oidn", "-o", str(tmp_path / "o.exr")]) == 0
    assert "OIDN took the colour alone (the input holds no albedo: --alb gives one)" in capsys.readouterr().err
    assert main(["denoise", str(PBRT), "--guide", "oidn", "-o", str(tmp_path / "p.exr")]) == 0
    assert "colour alone" not in capsys.readouterr().err


def test_the_header_records_only_the_planes_oidn_took(tmp_path):
    """OIDN takes the albedo and the normal beside it, never the depth, and none with --guide-auxiliary none: the
    depth plane (and all three with none) was recorded as guiding the image, beside a summary saying otherwise."""
    pytest.importorskip("pyoidn")
    out = tmp_path / "oidn.exr"
    assert main(["denoise", str(PBRT), "--guide", "oidn", "-o", str(out), "-q"]) == 0
    header = read_header(out)
    assert (header["awr:albedo_plane"], header["awr:normal_plane"]) == ("Albedo", "Ns")
    assert "awr:depth_plane" not in header
    out = tmp_path / "none.exr"
    assert main(["denoise", str(PBRT), "--guide", "oidn", "--guide-auxiliary", "none", "-o", str(out), "-q"]) == 0
    assert not any(key.endswith("_plane") for key in read_header(out))
