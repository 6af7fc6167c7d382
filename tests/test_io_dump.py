"""The project's sample-dump layout and request maps: exact round trips and bad input."""

from __future__ import annotations

import os
import threading
import warnings

import numpy as np
import pytest

pytestmark = pytest.mark.exr
OpenEXR = pytest.importorskip("OpenEXR")

from awr_denoise import SampleBuffer, SampleRequest  # noqa: E402
from awr_denoise.errors import InputFileError, InputFileWarning  # noqa: E402
from awr_denoise.io import (  # noqa: E402
    read_request,
    read_sample_buffer,
    read_sample_dump,
    request_attributes,
    write_request,
    write_sample_buffer,
)


def _buffer(rng, shape=(6, 5), channels=("R", "G", "B")) -> SampleBuffer:
    count = rng.integers(0, 40, size=shape)
    count[0, 0] = 2**24  # the largest count float32 stores exactly (with all below it)
    count[0, 1] = 2**24 - 1
    mean = rng.random(shape + (len(channels),)).astype(np.float32)
    var = rng.random(shape + (len(channels),)).astype(np.float32)
    return SampleBuffer.from_moments(count, mean, var, channels=channels)


def _write(path, planes, header=None):
    with OpenEXR.File(dict(header or {}), planes) as f:
        f.write(str(path))


def test_round_trip_counts_exact_and_statistics(tmp_path, rng):
    buf = _buffer(rng)
    write_sample_buffer(tmp_path / "d.exr", buf, header={"awr:round": 3, "awr:seed": 2**40 + 1})
    dump = read_sample_dump(tmp_path / "d.exr")
    back = dump.buffer
    np.testing.assert_array_equal(back.count, buf.count)
    np.testing.assert_array_equal(back.mean, buf.mean)
    np.testing.assert_array_equal(back.variance, buf.variance)
    np.testing.assert_array_equal(back.variance_known, buf.variance_known)
    assert back.channels == buf.channels
    assert dump.attributes["awr:round"] == 3 and int(dump.attributes["awr:seed"]) == 2**40 + 1
    with OpenEXR.File(str(tmp_path / "d.exr"), separate_channels=True) as f:
        ch = f.channels()
        assert ch["sampleCount"].pixels.dtype == np.float32  # FLOAT, not UINT (OIIO normalises UINT)
        assert f.header()["awr:variance_kind"] == "sample"


@pytest.mark.parametrize(("key", "value"), [("awr:variance_kind", "mean"), ("awr:channels", "X,Y,Z"),
                                            ("awr:nonfinite", -5), ("awr:semantics", "sample-request")])
def test_a_header_cannot_replace_the_layouts_own_attributes(tmp_path, rng, key, value):
    """``header={"awr:variance_kind": "mean"}`` was written over the writer's own: the per-sample variance read back
    multiplied by the counts, exit 0 (an attack pass); other keys made files the readers refuse."""
    buffer = _buffer(rng)
    with pytest.raises(ValueError, match=f"^header: {key} .* is the layout's own attribute, written from the data"):
        write_sample_buffer(tmp_path / "d.exr", buffer, header={key: value})
    assert not (tmp_path / "d.exr").exists()
    # The same value as the writer's (a header carried from another dump) is no conflict.
    write_sample_buffer(tmp_path / "d.exr", buffer, header={"awr:nonfinite": 0, "awr:channels": "R,G,B"})
    np.testing.assert_array_equal(read_sample_buffer(tmp_path / "d.exr").variance, buffer.variance)


def test_a_request_header_cannot_replace_its_round_or_total(tmp_path):
    """``header={"awr:round": 1}`` over a request of round 5 read back as round 1; a round past the readers' last was
    written and then refused by ``read_request`` (an attack pass)."""
    request = SampleRequest.uniform((2, 3), 4, round=5)
    for key, value in (("awr:round", 1), ("awr:total", 99), ("awr:sampler_id", 3)):
        with pytest.raises(ValueError, match=f"^header: {key} {value!r} is the layout's own attribute"):
            write_request(tmp_path / "r.exr", request, header={key: value})
    write_request(tmp_path / "r.exr", request, header={"awr:round": 5})
    assert read_request(tmp_path / "r.exr").round == 5
    last = SampleRequest.uniform((2, 3), 4, round=2**31 - 1)
    with pytest.raises(ValueError, match=r"^request: round 2147483647 is beyond the last a request map records"):
        write_request(tmp_path / "last.exr", last)
    assert not (tmp_path / "last.exr").exists()


def test_channel_order_kept_for_non_rgb_names(tmp_path, rng):
    buf = _buffer(rng, channels=("Z2", "B1", "A0"))
    write_sample_buffer(tmp_path / "d.exr", buf)
    assert read_sample_buffer(tmp_path / "d.exr").channels == ("Z2", "B1", "A0")


def test_counts_above_float32_exact_range_refused(tmp_path):
    count = np.full((2, 2), 2**24 + 1)
    buf = SampleBuffer.from_moments(count, np.zeros((2, 2, 3)), np.zeros((2, 2, 3)))
    with pytest.raises(ValueError, match=r"2\*\*24"):
        write_sample_buffer(tmp_path / "d.exr", buf)
    assert os.listdir(tmp_path) == []


def test_unknown_variance_mask_round_trips(tmp_path, rng):
    count = np.full((3, 3), 8)
    known = np.ones((3, 3), bool)
    known[1, 1] = False
    buf = SampleBuffer.from_moments(count, rng.random((3, 3, 3)), rng.random((3, 3, 3)), variance_known=known)
    write_sample_buffer(tmp_path / "d.exr", buf)
    np.testing.assert_array_equal(read_sample_buffer(tmp_path / "d.exr").variance_known, known)


def test_issued_counts_round_trip(tmp_path, rng):
    buf = _buffer(rng, shape=(2, 3))
    issued = buf.count + np.array([[0, 1, 0], [2, 0, 0]])
    write_sample_buffer(tmp_path / "d.exr", buf, issued=issued)
    np.testing.assert_array_equal(read_sample_dump(tmp_path / "d.exr").issued, issued)
    write_sample_buffer(tmp_path / "e.exr", buf)
    np.testing.assert_array_equal(read_sample_dump(tmp_path / "e.exr").issued, buf.count)


@pytest.mark.parametrize("kind,factor", [("sample", 1.0), ("mean", 4.0)])
def test_variance_kind_header_is_honoured(tmp_path, kind, factor):
    one = np.ones((2, 2), np.float32)
    planes = {c: one * 0.5 for c in "RGB"} | {f"variance.{c}": one * 0.25 for c in "RGB"}
    planes["sampleCount"] = one * 4
    _write(tmp_path / "d.exr", planes, {"awr:variance_kind": kind})
    np.testing.assert_allclose(read_sample_buffer(tmp_path / "d.exr").variance, 0.25 * factor)


def test_a_mean_where_nothing_was_counted_is_read_as_no_samples_with_a_warning(tmp_path):
    """A batch whose count plane went wrong (zeros where the renderer rendered) lost its means without a word, and
    ``awr merge`` said only that samples were missing; ``from_sums`` refuses the same input."""
    one = np.ones((2, 3), np.float32)
    count = one * 4
    count[0] = 0
    planes = {c: one * 0.5 for c in "RGB"} | {f"variance.{c}": one * 0.25 for c in "RGB"} | {"sampleCount": count}
    _write(tmp_path / "d.exr", planes, {})
    with pytest.warns(InputFileWarning, match=r"d\.exr: sampleCount: 3 pixel\(s\) counted 0 hold a non-zero mean"):
        dump = read_sample_dump(tmp_path / "d.exr")
    np.testing.assert_array_equal(dump.buffer.mean[0], 0.0)
    planes |= {c: np.where(count > 0, 0.5, 0).astype(np.float32) for c in "RGB"}  # as the project writes it
    _write(tmp_path / "e.exr", planes, {})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_sample_dump(tmp_path / "e.exr")


def test_a_files_description_keeps_its_warnings_and_leaves_other_threads_theirs(tmp_path, monkeypatch, recwarn):
    """``describe_file`` recorded its read's warnings with ``warnings.catch_warnings(record=True)``, which replaces
    every thread's filters: a renderer thread's warnings were taken as the file's and lost to that thread (an
    attack pass)."""
    from awr_denoise.io import describe

    one = np.ones((2, 3), np.float32)
    count = one * 4
    count[0] = 0
    _write(tmp_path / "d.exr", {c: one * 0.5 for c in "RGB"} | {f"variance.{c}": one * 0.25 for c in "RGB"}
           | {"sampleCount": count}, {})
    real = describe.read_sample_dump

    def reading(*args, **kwargs):  # another thread warns while this one reads
        other = threading.Thread(target=warnings.warn, args=("from another thread",))
        other.start()
        other.join()
        return real(*args, **kwargs)

    monkeypatch.setattr(describe, "read_sample_dump", reading)
    info = describe.describe_file(tmp_path / "d.exr")
    assert [w for w in info["warnings"] if "counted 0 hold a non-zero mean" in w]
    assert not [w for w in info["warnings"] if "another thread" in w]
    assert [str(w.message) for w in recwarn] == ["from another thread"]


def test_a_mean_where_a_count_plane_says_0_is_warned_about_in_every_layout(tmp_path):
    """The generic layout (a renderer's own count plane, --count) lost such means without a word too."""
    one = np.ones((2, 3), np.float32)
    count = one * 4
    count[0, :2] = 0
    planes = {c: one * 0.5 for c in "RGB"} | {f"var.{c}": one * 0.25 for c in "RGB"} | {"n": count}
    _write(tmp_path / "g.exr", planes, {})
    with pytest.warns(InputFileWarning, match=r"g\.exr: n: 2 pixel\(s\) counted 0 hold a non-zero mean"):
        read_sample_dump(tmp_path / "g.exr", color="RGB", variance="var", count="n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a count from spp= counts every pixel
        read_sample_dump(tmp_path / "g.exr", color="RGB", variance="var", spp=4)


def test_an_unknown_variance_kind_in_a_header_is_named_once(tmp_path):
    one = np.ones((2, 2), np.float32)
    planes = {c: one * 0.5 for c in "RGB"} | {f"variance.{c}": one * 0.25 for c in "RGB"}
    planes["sampleCount"] = one * 4
    _write(tmp_path / "d.exr", planes, {"awr:variance_kind": "Sample"})
    with pytest.raises(InputFileError, match=r"^\S*d\.exr: awr:variance_kind: 'Sample' is not one of sample, mean, "
                                             r"second_moment$"):
        read_sample_dump(tmp_path / "d.exr")


def test_a_variance_kind_option_against_the_files_own_header_is_refused(tmp_path):
    """``awr merge DUMP BATCH --request R --variance-kind mean`` (the batch's variance is of the mean,
    its header silent) applied the option to the running dump too, whose header says "sample":
    its variance multiplied by its counts, the merge 1.38x too noisy, exit 0 (a red-team pass). A
    file's own header is now never contradicted; in a merge the option is the silent inputs'."""
    from awr_denoise.cli.main import main

    one = np.ones((2, 2), np.float32)
    planes = {c: one * 0.5 for c in "RGB"} | {f"variance.{c}": one * 0.25 for c in "RGB"}
    planes["sampleCount"] = one * 4
    _write(tmp_path / "d.exr", planes, {"awr:variance_kind": "sample"})
    _write(tmp_path / "silent.exr", planes, {})
    with pytest.raises(InputFileError, match=r"d\.exr: awr:variance_kind: its header says what its variance holds "
                                             r"\('sample'\); variance_kind 'mean' \(--variance-kind\) contradicts it"):
        read_sample_dump(tmp_path / "d.exr", variance_kind="mean")
    np.testing.assert_allclose(read_sample_buffer(tmp_path / "d.exr", variance_kind="sample").variance, 0.25)
    np.testing.assert_allclose(read_sample_buffer(tmp_path / "silent.exr", variance_kind="mean").variance, 1.0)
    # In a merge the option describes the inputs whose header is silent (the batch), not the running dump.
    # (The two files hold the same means, refused as the same samples without --allow-duplicates: not the point.)
    args = ["merge", str(tmp_path / "d.exr"), str(tmp_path / "silent.exr"), "--variance-kind", "mean", "-q",
            "--allow-duplicates", "-o", str(tmp_path / "m.exr")]
    assert main(args) == 0
    both = read_sample_buffer(tmp_path / "m.exr")
    expected = SampleBuffer.from_moments(np.full((2, 2), 4), np.full((2, 2, 3), 0.5), np.full((2, 2, 3), 0.25)).merge(
        SampleBuffer.from_moments(np.full((2, 2), 4), np.full((2, 2, 3), 0.5), np.full((2, 2, 3), 1.0)))
    np.testing.assert_allclose(both.variance, expected.variance, rtol=1e-6)
    # Every input saying, the option reaches them all: one it contradicts is refused, nothing written.
    _write(tmp_path / "d2.exr", planes, {"awr:variance_kind": "sample"})
    args = ["merge", str(tmp_path / "d.exr"), str(tmp_path / "d2.exr"), "--variance-kind", "mean", "-q",
            "--allow-duplicates", "-o", str(tmp_path / "n.exr")]
    assert main(args) == 2 and not (tmp_path / "n.exr").exists()


def test_second_moment_kind(tmp_path):
    one = np.ones((2, 2), np.float32)
    planes = {c: one * 0.5 for c in "RGB"} | {f"variance.{c}": one * 0.5 for c in "RGB"}
    planes["sampleCount"] = one * 5
    _write(tmp_path / "d.exr", planes, {"awr:variance_kind": "second_moment"})
    np.testing.assert_allclose(read_sample_buffer(tmp_path / "d.exr").variance, (0.5 - 0.25) * 5 / 4)


def _planes(**over):
    one = np.ones((3, 4), np.float32)
    planes = {c: one * 0.5 for c in "RGB"} | {f"variance.{c}": one * 0.1 for c in "RGB"}
    planes["sampleCount"] = one * 4
    planes.update(over)
    return planes


def test_a_variance_below_float32s_range_stays_a_noisy_pixel(tmp_path):
    """Means near 1e-22 have variances near 1e-44: float32 stored some as 0, which read back as known
    noise-free pixels (a red-team pass). Kept at float32's least subnormal instead."""
    rng = np.random.default_rng(2)
    variance = rng.uniform(1e-47, 1e-44, (4, 4, 3))
    buf = SampleBuffer.from_moments(np.full((4, 4), 4), 1e-22 * (1 + rng.random((4, 4, 3))), variance)
    write_sample_buffer(tmp_path / "d.exr", buf)
    back = read_sample_buffer(tmp_path / "d.exr")
    assert (back.variance > 0).all() and back.variance_known.all()
    np.testing.assert_allclose(back.variance, variance, atol=1.5e-45)  # float32 subnormals' spacing


def test_a_variance_plane_wholly_below_float32s_range_is_refused(tmp_path):
    """An image at 1e-24 with 30% noise (variances near 1e-49) was written with every variance at float32's least
    subnormal and read back 3.5e4x too noisy, without a word (an attack pass): refused, naming the plane, before
    anything is written. A few such pixels beside variances float32 holds are kept as above."""
    rng = np.random.default_rng(3)
    mean = 1e-24 * (1 + rng.random((4, 4, 3)))
    buf = SampleBuffer.from_moments(np.full((4, 4), 8), mean, (0.3 * mean) ** 2)
    with pytest.raises(ValueError, match=r"d\.exr: variance\.R: every value is below float32's range \(the largest "
                                         r".*e-49\), which would be stored as 1\.4e-45; scale the buffer up"):
        write_sample_buffer(tmp_path / "d.exr", buf)
    assert not (tmp_path / "d.exr").exists()
    scaled = SampleBuffer.from_moments(np.full((4, 4), 8), 1e24 * mean, (0.3e24 * mean) ** 2)
    write_sample_buffer(tmp_path / "d.exr", scaled)
    np.testing.assert_allclose(read_sample_buffer(tmp_path / "d.exr").variance, scaled.variance, rtol=1e-6)
    mixed = np.full((4, 4, 3), 0.01)
    mixed[0, 0] = 1e-49
    write_sample_buffer(tmp_path / "m.exr", SampleBuffer.from_moments(np.full((4, 4), 8), np.full((4, 4, 3), 0.5),
                                                                      mixed))


def test_a_half_count_from_2048_on_is_refused(tmp_path):
    """A HALF count channel stores 2049 samples as 2048 (its spacing is 2 there): read as 2048
    without a word (a red-team pass). Counts below 2048 are exact and read; from 2048 on, refused
    with the advice."""
    planes = _planes(sampleCount=np.full((3, 4), 2047, np.float16))
    _write(tmp_path / "ok.exr", planes)
    assert read_sample_buffer(tmp_path / "ok.exr").count.max() == 2047
    planes["sampleCount"] = np.full((3, 4), 2049, np.float16)  # stored as 2048
    _write(tmp_path / "half.exr", planes)
    with pytest.raises(InputFileError, match=r"half\.exr: sampleCount: 12 pixel\(s\) reach 2048, where a HALF channel "
                                             r"stops holding sample counts exactly .*; write the count as FLOAT"):
        read_sample_buffer(tmp_path / "half.exr")


@pytest.mark.parametrize("channel,value,what", [
    ("G", np.nan, "NaN"),
    ("variance.B", np.inf, "Inf"),
    ("variance.R", -1.0, "negative"),
    ("sampleCount", -2.0, "negative"),
    ("sampleCount", 2.5, "not whole"),
    # Not rounded to 4 and to 0 (a pixel without samples) either, however close (a red-team pass):
    ("sampleCount", 4.0009, "not whole"),
    ("sampleCount", 0.0009, "not whole"),
    # Not "negative" (1e30 wrapped around int64 before), nor a count a float channel holds exactly:
    ("sampleCount", 1e30, "exceed 16777216"),
    ("sampleCount", 2.0**25, "exceed 16777216"),
])
def test_bad_values_name_file_and_channel(tmp_path, channel, value, what):
    planes = _planes()
    bad = planes[channel].copy()
    bad[1, 2] = value
    planes[channel] = bad
    _write(tmp_path / "bad.exr", planes)
    with pytest.raises(InputFileError, match=rf"bad\.exr: {channel}: .*{what}"):
        read_sample_buffer(tmp_path / "bad.exr")


@pytest.mark.parametrize("value", [7.0, -3.0, 0.5])
def test_a_variance_known_mask_other_than_0_or_1_is_refused(tmp_path, value):
    """``varianceKnown`` is a mask: 7 or -3 was read as known or unknown without a word (a red-team pass)."""
    known = np.ones((3, 4), np.float32)
    _write(tmp_path / "ok.exr", _planes(varianceKnown=known))
    assert read_sample_buffer(tmp_path / "ok.exr").variance_known.all()
    known[2, 3] = value
    _write(tmp_path / "bad.exr", _planes(varianceKnown=known))
    with pytest.raises(InputFileError, match=r"bad\.exr: varianceKnown: 1 pixel\(s\) are neither 0 .* nor 1"):
        read_sample_buffer(tmp_path / "bad.exr")


def test_half_overflow_named(tmp_path):
    planes = _planes()
    var = planes["variance.G"].astype(np.float16)
    var[0, 0] = np.float16(np.inf)  # what a renderer's half channel holds after 70000 overflowed
    planes["variance.G"] = var
    _write(tmp_path / "h.exr", planes)
    with pytest.raises(InputFileError, match=r"h\.exr: variance\.G: .*half-float overflow"):
        read_sample_buffer(tmp_path / "h.exr")


def test_missing_variance_channel(tmp_path):
    planes = _planes()
    del planes["variance.B"]
    _write(tmp_path / "m.exr", planes, {"awr:channels": "R,G,B"})
    with pytest.raises(InputFileError, match=r"m\.exr: variance\.B: missing"):
        read_sample_buffer(tmp_path / "m.exr")


def test_statistics_the_header_does_not_list_are_refused_not_dropped(tmp_path):
    """``awr:channels`` naming R,G in a dump that holds B and its variance too: B was dropped without a word (an
    attack pass). The header and the channels disagree: refused, naming both; feature planes are not counted."""
    planes = _planes()
    _write(tmp_path / "m.exr", planes, {"awr:channels": "R,G"})
    with pytest.raises(InputFileError, match=r"m\.exr: awr:channels: 'R,G' does not list B, .*\(variance\.B\)"):
        read_sample_buffer(tmp_path / "m.exr")
    _write(tmp_path / "all.exr", planes, {"awr:channels": "R,G,B"})
    assert read_sample_buffer(tmp_path / "all.exr").mean.shape[-1] == 3


def test_undetectable_layout(tmp_path):
    _write(tmp_path / "u.exr", {"foo": np.ones((2, 2), np.float32)})
    with pytest.raises(InputFileError, match=r"u\.exr: cannot detect the layout \(channels: foo\); choose"):
        read_sample_buffer(tmp_path / "u.exr")
    # A plain colour image (pbrt-v4's default rgb film writes one): said so, with the film that writes a variance.
    _write(tmp_path / "rgb.exr", {c: np.ones((2, 2), np.float32) for c in "RGBA"})
    with pytest.raises(InputFileError, match=r"rgb\.exr: cannot detect the layout \(channels: A, B, G, R\): an image "
                                             r"of colours only, .*pbrt-v4's rgb film writes none: render with its "
                                             r"gbuffer film"):
        read_sample_buffer(tmp_path / "rgb.exr")
    # The generic preset asked for by name was told to "choose a preset": it is told to name the planes.
    with pytest.raises(InputFileError, match=r"u\.exr: cannot detect the layout \(channels: foo\); the generic "
                                             r"preset reads the planes named: give color=/variance=/count="):
        read_sample_buffer(tmp_path / "u.exr", preset="generic")


def test_independent_renders_without_a_colour_plane_are_told_to_name_it(tmp_path):
    """``merge --independent`` of plain images was told "no spread or count to denoise from ... give
    color=/variance=/count=" (an attack pass), where it needs no spread, refuses a variance and has its count from
    ``spp``: what is missing is the colour plane."""
    from awr_denoise.io import read_independent_renders

    rng = np.random.default_rng(0)
    for k in (1, 2):
        _write(tmp_path / f"r{k}.exr", {c: rng.random((2, 2)).astype(np.float32) for c in "RGB"})
    paths = [tmp_path / "r1.exr", tmp_path / "r2.exr"]
    with pytest.raises(InputFileError, match=r"r1\.exr: cannot detect the layout \(channels: B, G, R\): name the "
                                             r"render's colour plane \(color=, --color: RGB for its R,G,B channels\)$"):
        read_independent_renders(paths, spp=4)
    assert (read_independent_renders(paths, color="RGB", spp=4).buffer.count == 8).all()


@pytest.mark.parametrize("count_name", [None, "count"])
def test_a_batch_without_its_sample_count_is_named_as_one(tmp_path, count_name):
    """A batch in the awr layout that left out ``sampleCount`` (or named it otherwise) got the generic "cannot
    detect the layout" message, which did not say what was missing."""
    planes = _planes()
    count = planes.pop("sampleCount")
    if count_name is not None:
        planes[count_name] = count
    _write(tmp_path / "b.exr", planes, {"awr:variance_kind": "sample"})
    with pytest.raises(InputFileError, match=r"b\.exr: has variance\.\* channels, the awr layout's, but no "
                                             r"sampleCount channel \(channels: B, G, R, .*\): write each pixel's "
                                             r"number of samples there, or name the planes"):
        read_sample_buffer(tmp_path / "b.exr")
    # Read generically, as the message says, it is read.
    read = read_sample_buffer(tmp_path / "b.exr", color="RGB", variance="variance", spp=4)
    assert read.total_samples == 4 * 12
    # With its count and read generically by choice, a file is not told its count is missing.
    _write(tmp_path / "c.exr", _planes(), {"awr:variance_kind": "sample"})
    with pytest.raises(InputFileError, match=r"c\.exr: cannot detect the layout"):
        read_sample_buffer(tmp_path / "c.exr", preset="generic")


def test_request_round_trip_exact(tmp_path, rng):
    counts = rng.integers(0, 9, size=(5, 7))
    first = rng.integers(0, 2**24 - 9, size=(5, 7))
    req = SampleRequest(counts, first, round=4, sampler_id=12)
    write_request(tmp_path / "r.exr", req, header={"awr:seed": 9})
    back = read_request(tmp_path / "r.exr")
    np.testing.assert_array_equal(back.counts, counts)
    np.testing.assert_array_equal(back.first_index, first)
    assert (back.round, back.sampler_id, back.total) == (4, 12, req.total)


@pytest.mark.parametrize("seed", [0, 7, 2**31, 2**63 - 1])
def test_a_request_written_from_python_names_the_runs_seed(tmp_path, seed):
    """A renderer that reads its seed from the request (as `plan`'s carry it) gets the sampler's, not 0;
    seeds past an int attribute are stored as text, as the readers expect, and a header copied from such a
    request agrees with the same seed."""
    write_request(tmp_path / "r.exr", SampleRequest.uniform((2, 3), 1), seed=seed)
    copied = request_attributes(tmp_path / "r.exr")
    assert int(str(copied["awr:seed"])) == seed
    write_request(tmp_path / "again.exr", SampleRequest.uniform((2, 3), 1), seed=seed, header=copied)


@pytest.mark.parametrize("seed, header, match", [
    (-1, None, "seed: must be >= 0"), (2**63, None, "seed: must be <= 9223372036854775807"),
    (1.5, None, "seed: must be a whole number"), (True, None, "seed: expected a number, got the bool"),
    (7, {"awr:seed": 8}, "seed: 7 differs from the header's awr:seed 8")])
def test_a_bad_or_conflicting_seed_writes_no_request(tmp_path, seed, header, match):
    with pytest.raises((TypeError, ValueError), match=match):
        write_request(tmp_path / "r.exr", SampleRequest.uniform((2, 3), 1), seed=seed, header=header)
    assert not (tmp_path / "r.exr").exists()


def test_request_beyond_float32_refused(tmp_path):
    req = SampleRequest.uniform((2, 2), 4, first_index=2**24)
    with pytest.raises(ValueError, match="first_index"):
        write_request(tmp_path / "r.exr", req)


def test_request_total_checksum(tmp_path):
    one = np.ones((2, 2), np.float32)
    _write(tmp_path / "r.exr", {"counts": one, "first_index": one * 0}, {"awr:total": 5})
    with pytest.raises(InputFileError, match=r"r\.exr: counts: .*awr:total"):
        read_request(tmp_path / "r.exr")


# ---------------------------------------------------------------------------- features
def _with_features(rng, shape=(4, 5), n=160) -> SampleBuffer:
    h, w = shape
    pixels = np.concatenate([np.repeat(np.arange(h * w), 2), rng.integers(0, h * w, n - 2 * h * w)])
    normal = rng.normal(size=(n, 3))
    features = {"albedo": rng.random((n, 3)), "normal": normal / np.linalg.norm(normal, axis=1, keepdims=True),
                "depth": rng.uniform(1, 5, n)}
    return SampleBuffer.from_samples(pixels, rng.random((n, 3)), shape, features=features)


def _assert_float32_equal(a: SampleBuffer, b: SampleBuffer) -> None:
    assert a.channels == b.channels
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_array_equal(a.variance_known, b.variance_known)
    np.testing.assert_array_equal(a.mean, b.mean.astype(np.float32))
    np.testing.assert_array_equal(a.variance, b.variance.astype(np.float32))


def test_features_round_trip_with_their_variances(tmp_path, rng):
    buf = _with_features(rng)
    write_sample_buffer(tmp_path / "f.exr", buf)
    with OpenEXR.File(str(tmp_path / "f.exr"), separate_channels=True) as f:
        names = set(f.parts[0].channels)
        assert f.parts[0].header["awr:features"] == "albedo,normal,depth"
        assert f.parts[0].header["awr:channels"] == "R,G,B"   # older readers see the radiance only
    assert {"albedo.R", "variance.albedo.B", "normal.X", "variance.normal.Z", "depth.Z", "variance.depth.Z"} <= names
    assert not {"albedo.sampleCount", "depth.varianceKnown"} & names   # same counts as the radiance: not stored
    back = read_sample_buffer(tmp_path / "f.exr")
    _assert_float32_equal(back, buf)
    assert tuple(back.features) == ("albedo", "normal", "depth")
    for name, feature in buf.features.items():
        _assert_float32_equal(back.features[name], feature)


def test_feature_counts_and_unknown_variances_round_trip(tmp_path, rng):
    buf = _with_features(rng)
    count = np.full(buf.shape, 3)
    depth = SampleBuffer.from_moments(count, np.full(buf.shape, 2.0), np.zeros(buf.shape), channels=["Z"],
                                      variance_known=np.zeros(buf.shape, bool))
    buf = SampleBuffer.from_moments(buf.count, buf.mean, buf.variance, features={"depth": depth})
    write_sample_buffer(tmp_path / "c.exr", buf)
    back = read_sample_buffer(tmp_path / "c.exr").features["depth"]
    np.testing.assert_array_equal(back.count, count)
    assert not back.variance_known.any() and (back.mean == 2.0).all()


def test_feature_planes_without_the_header_are_found(tmp_path):
    planes = _planes(**{"depth.Z": np.full((3, 4), 7, np.float32), "variance.depth.Z": np.zeros((3, 4), np.float32)})
    _write(tmp_path / "n.exr", planes)
    back = read_sample_buffer(tmp_path / "n.exr")
    assert back.channels == ("R", "G", "B") and tuple(back.features) == ("depth",)
    assert (back.features["depth"].mean == 7).all()


@pytest.mark.parametrize("header, drop, message", [
    ({"awr:features": "depth,shade"}, None, r"awr:features: 'shade' is not one of albedo, normal, depth"),
    ({"awr:features": "depth"}, "variance.depth.Z", r"variance\.depth\.Z: missing \(the dump's depth feature\)"),
])
def test_bad_feature_planes_are_named(tmp_path, header, drop, message):
    planes = _planes(**{"depth.Z": np.ones((3, 4), np.float32), "variance.depth.Z": np.zeros((3, 4), np.float32)})
    planes.pop(drop, None)
    _write(tmp_path / "b.exr", planes, header)
    with pytest.raises(InputFileError, match=r"b\.exr: " + message):
        read_sample_buffer(tmp_path / "b.exr")


def test_a_negative_feature_variance_is_named(tmp_path):
    planes = _planes(**{"depth.Z": np.ones((3, 4), np.float32), "variance.depth.Z": -np.ones((3, 4), np.float32)})
    _write(tmp_path / "v.exr", planes, {"awr:features": "depth"})
    with pytest.raises(InputFileError, match=r"v\.exr: variance\.depth\.Z: .*negative"):
        read_sample_buffer(tmp_path / "v.exr")


def test_radiance_names_that_collide_with_feature_planes_are_refused(tmp_path, rng):
    buf = _with_features(rng)
    clash = SampleBuffer.from_moments(buf.count, buf.mean, buf.variance, channels=["depth.Z", "G", "B"],
                                      features=dict(buf.features))
    with pytest.raises(ValueError, match="channel name 'depth.Z' collides with the dump layout"):
        write_sample_buffer(tmp_path / "x.exr", clash)
    assert not (tmp_path / "x.exr").exists()


def test_a_request_file_past_the_exact_issued_count_is_refused_by_the_reader(tmp_path):
    """write_request refuses first_index + counts past 2**24; a file edited by hand is refused when read,
    naming it, rather than when a merge writes its dump (a message naming neither)."""
    counts = np.full((2, 2), 8, np.float32)
    counts[0, 0] = 2**24
    _write(tmp_path / "r.exr", {"counts": counts, "first_index": np.full((2, 2), 8, np.float32)}, {})
    with pytest.raises(InputFileError, match=r"r\.exr: counts: 1 pixel\(s\) would issue samples past index 16777216"):
        read_request(tmp_path / "r.exr")


@pytest.mark.parametrize("layout", ["transposed", "fortran", "row broadcast"])
def test_count_planes_keep_their_pixels_in_any_memory_layout(tmp_path, rng, layout):
    """The OpenEXR bindings write a plane's raw memory and ignore its strides: counts, issued
    counts, the known-variance mask and a request's counts and first indices of a transposed,
    Fortran-ordered or broadcast array were written as a permutation of their pixels, with the
    same total, so no check caught it (red-team pass of the API's array layouts)."""
    h, w = 4, 5
    if layout == "transposed":  # a renderer storing (W, H) hands over its array transposed
        counts = (np.arange(h * w).reshape(w, h) + 2).T
    elif layout == "fortran":
        counts = np.asfortranarray(np.arange(h * w).reshape(h, w) + 2)
    else:
        counts = np.broadcast_to(np.arange(w) + 2, (h, w))
    known = np.asfortranarray(counts % 3 != 0)
    mean = rng.random((h, w, 3))
    buffer = SampleBuffer.from_moments(counts, mean, np.full((h, w, 3), 0.1), variance_known=known)
    issued = np.asfortranarray(counts + 1 + np.arange(h)[:, None])
    write_sample_buffer(tmp_path / "d.exr", buffer, issued=issued)
    dump = read_sample_dump(tmp_path / "d.exr")
    np.testing.assert_array_equal(dump.buffer.count, counts)
    np.testing.assert_array_equal(dump.buffer.variance_known, known)
    np.testing.assert_array_equal(dump.issued, issued)
    np.testing.assert_array_equal(dump.buffer.mean, mean.astype(np.float32))
    first = np.asfortranarray(np.arange(h * w).reshape(h, w) * 7)
    write_request(tmp_path / "r.exr", SampleRequest(counts, first))
    back = read_request(tmp_path / "r.exr")
    np.testing.assert_array_equal(back.counts, counts)
    np.testing.assert_array_equal(back.first_index, first)


def test_issued_counts_are_checked_before_compared(tmp_path, rng):
    """A NaN issued count was cast to an integer first (a RuntimeWarning) and reported as "fewer
    issued than counted"; a complex one was written as its real part."""
    buffer = _buffer(rng, shape=(2, 2))
    issued = np.asarray(buffer.count, np.float64).copy()
    issued[0, 1] = np.nan
    with pytest.raises(ValueError, match="issued: counts must be whole numbers"):
        write_sample_buffer(tmp_path / "d.exr", buffer, issued=issued)
    with pytest.raises(TypeError, match="issued: complex"):
        write_sample_buffer(tmp_path / "d.exr", buffer, issued=buffer.count + 0j)
    with pytest.raises(ValueError, match="issued: 4 pixel\\(s\\) exceed 16777216"):
        write_sample_buffer(tmp_path / "d.exr", buffer, issued=np.full((2, 2), 2**63 + 5, np.uint64))
    assert not (tmp_path / "d.exr").exists()


def test_variances_that_samples_of_0_or_more_cannot_have_are_warned_about(tmp_path):
    """A dump converted to another colour space by a pipeline tool (OpenImageIO's colorconvert, as oiiotool does)
    kept its counts and header and was read as valid, exit 0: a third of its pixels then held a mean of 0 beside a
    variance of 0.5 (an attack pass). Such a pixel is now warned about, naming the file and channel; the dump as
    written reads without a word."""
    oiio = pytest.importorskip("OpenImageIO")
    from awr_denoise.synthetic import SyntheticRenderer, make_scene

    shape = (32, 48)
    buffer = SyntheticRenderer(make_scene("edges", shape), seed=2)(SampleRequest.uniform(shape, 8))
    mean, variance = buffer.mean.copy(), buffer.variance.copy()
    mean[:, :12], variance[:, :12] = 0.0, 0.0  # a black border, where nothing was hit
    buffer = SampleBuffer.from_moments(buffer.count, mean, variance)
    written = write_sample_buffer(tmp_path / "d.exr", buffer)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_sample_dump(written)
    converted = oiio.ImageBufAlgo.colorconvert(oiio.ImageBuf(str(written)), "lin_rec709", "lin_ap1")
    assert not converted.has_error
    converted.write(str(tmp_path / "acescg.exr"))
    with pytest.warns(InputFileWarning, match="acescg.exr: [RGB]: pixel .* changed after it was written"):
        read_sample_dump(tmp_path / "acescg.exr")
