"""Frame sequences (awr_denoise.parallel.frames) against serial runs, bit for bit."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from awr_denoise import reconstruct
from awr_denoise.parallel import (
    FramesFailedError,
    denoise_frames,
)
from parallel_helpers import (
    assert_same_files,
    serial_frames,
)


def test_denoise_frames_equals_the_serial_run_bitwise(tmp_path, dumps):
    options = {"c_s": 1.5, "wavelet": "bior4.4", "domain": "log"}
    serial = [tmp_path / f"serial.{i:04d}.exr" for i in range(len(dumps))]
    serial_frames(dumps, serial, **options)
    threaded = [tmp_path / f"threads.{i:04d}.exr" for i in range(len(dumps))]
    written = denoise_frames(dumps, threaded, **options)
    assert written == threaded
    assert_same_files(threaded, serial)
    from awr_denoise.io import read_image, read_sample_buffer

    np.testing.assert_array_equal(read_image(serial[1]),
                                  reconstruct(read_sample_buffer(dumps[1]), **options).astype(np.float32))


def _images_per_frame(tmp_path, dumps, stem: str, seed: int) -> list:
    """One random RGB image per dump, of its size, at ``tmp_path / f"{stem}.{i}.exr"``."""
    from awr_denoise.io import read_sample_buffer, write_image

    rng = np.random.default_rng(seed)
    shape = read_sample_buffer(dumps[0]).shape
    paths = [tmp_path / f"{stem}.{i}.exr" for i in range(len(dumps))]
    for path in paths:
        write_image(path, rng.random((*shape, 3)))
    return paths


def test_each_frame_may_read_its_own_plane_files(tmp_path, dumps):
    """``read_options`` one dict per input: frame i reads its own albedo, as a serial run with it does."""
    from awr_denoise.io import read_image, read_sample_buffer

    albedos = _images_per_frame(tmp_path, dumps, "alb", 3)
    per_frame = [{"albedo": str(path)} for path in albedos]
    outputs = [tmp_path / f"out.{i}.exr" for i in range(len(dumps))]
    denoise_frames(dumps, outputs, read_options=per_frame, features=True)
    for dump, albedo, output in zip(dumps, albedos, outputs):
        alone = reconstruct(read_sample_buffer(dump, albedo=str(albedo)), features=True).astype(np.float32)
        np.testing.assert_array_equal(read_image(output), alone)
    other = reconstruct(read_sample_buffer(dumps[1], albedo=str(albedos[0])), features=True).astype(np.float32)
    assert not np.array_equal(read_image(outputs[1]), other)
    with pytest.raises(ValueError, match=f"read_options: 2 given for {len(dumps)} input"):
        denoise_frames(dumps, [tmp_path / f"x.{i}.exr" for i in range(len(dumps))], read_options=per_frame[:2])
    with pytest.raises(TypeError, match="read_options: expected one dict per input"):
        denoise_frames(dumps, [tmp_path / f"x.{i}.exr" for i in range(len(dumps))],
                       read_options=[*per_frame[:-1], "albedo"])
    assert not list(tmp_path.glob("x.*"))


def test_each_frame_may_have_its_own_reference(tmp_path, dumps):
    """``reference`` one path per input: frame i's error against its own, as a run per frame gives it."""
    from awr_denoise.parallel import denoise_frame

    refs = _images_per_frame(tmp_path, dumps, "ref", 5)
    seen = []
    denoise_frames(dumps, [tmp_path / f"out.{i}.exr" for i in range(len(dumps))], reference=refs, on_frame=seen.append)
    errors = {frame.source: frame.relmse for frame in seen}
    for i, (dump, ref) in enumerate(zip(dumps, refs)):
        assert errors[str(dump)] == denoise_frame(dump, tmp_path / f"alone.{i}.exr", reference=ref).relmse
    assert errors[str(dumps[1])] != denoise_frame(dumps[1], tmp_path / "other.exr", reference=refs[0]).relmse
    with pytest.raises(ValueError, match=f"reference: 2 given for {len(dumps)} input"):
        denoise_frames(dumps, [tmp_path / f"x.{i}.exr" for i in range(len(dumps))], reference=refs[:2])
    with pytest.raises(TypeError, match="reference: expected one path per input"):
        denoise_frames(dumps, [tmp_path / f"x.{i}.exr" for i in range(len(dumps))], reference=[*refs[:-1], 3])
    with pytest.raises(ValueError, match="input"):  # an output that is a frame's reference
        denoise_frames(dumps, [*refs[:1], *[tmp_path / f"x.{i}.exr" for i in range(1, len(dumps))]], reference=refs,
                       overwrite=True)
    assert not list(tmp_path.glob("x.*"))


def test_denoise_frames_refuses_existing_outputs_before_any_work(tmp_path, dumps):
    outputs = [tmp_path / f"out.{i}.exr" for i in range(len(dumps))]
    outputs[2].write_bytes(b"keep me")
    with pytest.raises(FileExistsError, match="out.2.exr"):
        denoise_frames(dumps, outputs)
    assert not outputs[0].exists() and outputs[2].read_bytes() == b"keep me"
    denoise_frames(dumps, outputs, overwrite=True)
    assert outputs[2].read_bytes()[:4] == b"\x76\x2f\x31\x01"  # EXR magic number


def test_denoise_frames_reports_failed_frames_and_writes_the_others(tmp_path, dumps):
    broken = tmp_path / "broken.exr"
    broken.write_bytes(b"not an exr")
    inputs = [dumps[0], broken, dumps[2]]
    outputs = [tmp_path / f"out.{i}.exr" for i in range(3)]
    with pytest.raises(FramesFailedError, match="1 of 3") as info:
        denoise_frames(inputs, outputs)
    assert list(info.value.failures) == [str(broken)]
    assert outputs[0].exists() and outputs[2].exists() and not outputs[1].exists()
    assert not list(tmp_path.glob(".*.tmp*"))  # atomic writes leave no partial file


def test_denoise_frames_checks_its_arguments(tmp_path, dumps):
    with pytest.raises(ValueError, match="outputs"):
        denoise_frames(dumps, [tmp_path / "a.exr"])
    with pytest.raises(ValueError, match="more than once"):
        denoise_frames(dumps[:2], [tmp_path / "a.exr", tmp_path / "a.exr"])
    with pytest.raises(ValueError, match="also an input"):
        denoise_frames(dumps[:1], dumps[:1], overwrite=True)
    assert denoise_frames([], []) == []


def test_one_frame_runs_in_the_calling_thread(tmp_path, dumps, monkeypatch):
    """Without an executor one frame runs in this thread, so Ctrl-C stops it at once (a worker
    thread cannot be stopped: the caller would wait for the whole reconstruction); it is still
    the serial run's image, and its failure is still a FramesFailedError."""
    from awr_denoise.parallel import frames

    threads = []
    real = frames.denoise_frame
    monkeypatch.setattr(frames, "denoise_frame",
                        lambda *a, **k: threads.append(threading.current_thread()) or real(*a, **k))
    serial = [tmp_path / "serial.exr"]
    serial_frames(dumps[:1], serial)
    seen = []
    assert denoise_frames(dumps[:1], [tmp_path / "one.exr"], on_frame=seen.append) == [tmp_path / "one.exr"]
    assert threads == [threading.main_thread()] and [f.output for f in seen] == [tmp_path / "one.exr"]
    assert_same_files([tmp_path / "one.exr"], serial)
    broken = tmp_path / "broken.exr"
    broken.write_bytes(b"not an exr")
    with pytest.raises(FramesFailedError, match="1 of 1") as info:
        denoise_frames([broken], [tmp_path / "never.exr"])
    assert list(info.value.failures) == [str(broken)] and not (tmp_path / "never.exr").exists()


def test_each_frames_reconstruction_runs_on_the_threads_given(tmp_path, dumps, monkeypatch):
    """``threads``: a pool each frame's reconstruction spreads its own work over (its ``executor``), the same images
    as the serial run, one frame or several; refused beside frames run in other processes, which cannot take it."""
    import concurrent.futures as cf
    import functools

    from awr_denoise.parallel import frames

    given = []
    real = frames.reconstruct_detailed
    monkeypatch.setattr(frames, "reconstruct_detailed", functools.wraps(real)(
        lambda *a, **k: given.append(k.get("executor")) or real(*a, **k)))  # wraps: its signature is checked
    serial = [tmp_path / f"serial.{i:04d}.exr" for i in range(len(dumps))]
    serial_frames(dumps, serial)
    given.clear()
    with cf.ThreadPoolExecutor(2) as pool:
        one = [tmp_path / "one.exr"]
        denoise_frames(dumps[:1], one, threads=pool)
        assert given == [None, pool]  # the options' trial on an 8x8 image first, on this thread
        assert_same_files(one, serial[:1])
        given.clear()
        several = [tmp_path / f"several.{i:04d}.exr" for i in range(len(dumps))]
        denoise_frames(dumps, several, threads=pool)
        assert given == [None] + [pool] * len(dumps)
        assert_same_files(several, serial)
        with cf.ProcessPoolExecutor(1) as processes:
            with pytest.raises(ValueError, match=r"^threads: a thread pool of this process, where the frames run in "
                                                 r"other processes \(ProcessPoolExecutor\)"):
                denoise_frames(dumps[:1], [tmp_path / "never.exr"], executor=processes, threads=pool)
    with pytest.raises(TypeError, match="^threads: expected a concurrent.futures.Executor, got int"):
        denoise_frames(dumps[:1], [tmp_path / "never.exr"], threads=2)
    assert not (tmp_path / "never.exr").exists()


def test_a_dump_without_samples_is_refused_naming_it(tmp_path):
    """The reconstruction's own refusal does not know the file (second red-team pass)."""
    from awr_denoise import SampleBuffer
    from awr_denoise.io import write_sample_buffer

    write_sample_buffer(tmp_path / "empty.exr", SampleBuffer.empty((4, 4)))
    with pytest.raises(FramesFailedError, match=r"empty\.exr: InputFileError: .*empty\.exr: no pixel has any sample"):
        denoise_frames([tmp_path / "empty.exr"], [tmp_path / "out.exr"])
    assert not (tmp_path / "out.exr").exists()


def test_a_reference_with_other_channels_is_refused_not_compared_in_part(tmp_path, dumps):
    """A one-channel depth map as the reference was compared with R alone (``awr diff`` refused it):
    the reference has the image's channel names or as many colour channels (red-team pass 5)."""
    from awr_denoise.errors import InputFileError
    from awr_denoise.io import read_sample_buffer, write_image
    from awr_denoise.parallel.frames import denoise_frame

    clean = reconstruct(read_sample_buffer(dumps[0]))
    write_image(tmp_path / "z.exr", clean[..., :1], channels=("Z",))
    with pytest.raises(InputFileError, match="z.exr: 1 channel"):
        denoise_frame(dumps[0], tmp_path / "o.exr", reference=tmp_path / "z.exr")
    assert not (tmp_path / "o.exr").exists()
    write_image(tmp_path / "rgba.exr", np.concatenate([clean, np.ones_like(clean[..., :1])], axis=-1),
                channels=("R", "G", "B", "A"))  # the image's channels by name: A left out
    assert denoise_frame(dumps[0], tmp_path / "o.exr", reference=tmp_path / "rgba.exr").relmse < 1e-10


def test_a_preview_of_two_channels_is_refused_before_the_work(tmp_path, monkeypatch):
    """It failed after the reconstruction, naming the library's ``image`` (red-team pass 5)."""
    from awr_denoise import SampleBuffer
    from awr_denoise.errors import InputFileError
    from awr_denoise.io import write_sample_buffer
    from awr_denoise.parallel import frames

    write_sample_buffer(tmp_path / "uv.exr", SampleBuffer.from_moments(np.full((8, 8), 4), np.ones((8, 8, 2)),
                                                                       np.ones((8, 8, 2)), channels=("U", "V")))
    monkeypatch.setattr(frames, "reconstruct_detailed", lambda *a, **k: pytest.fail("reconstructed first"))
    with pytest.raises(InputFileError, match=r"uv.exr: 2 channels \(U,V\); a preview"):
        frames.denoise_frame(tmp_path / "uv.exr", tmp_path / "o.exr", preview=tmp_path / "p.png")


def test_relative_paths_on_dask_workers_in_another_folder(tmp_path, dumps, cluster, monkeypatch):
    """A Dask worker runs in its own folder (``dask worker`` started from $HOME): relative frame paths
    were read and written there, from other dumps of the same names, and the caller found no output
    (exit 0; a red-team pass). Paths now go to the workers absolute, and come back as given."""
    distributed = pytest.importorskip("distributed")
    from awr_denoise.io import read_sample_buffer

    monkeypatch.chdir(tmp_path)  # the cluster's workers started in the test run's folder, not here
    names = [str(p.relative_to(tmp_path)) for p in dumps]
    outputs = [f"out.{i:04d}.exr" for i in range(len(dumps))]
    seen = []
    with distributed.Client(cluster.scheduler_address) as client:
        written = denoise_frames(names, outputs, executor=client.get_executor(pure=False), on_frame=seen.append,
                                 read_options={"variance": None})
    assert [str(p) for p in written] == outputs and sorted(str(f.output) for f in seen) == outputs
    assert sorted(f.source for f in seen) == sorted(names)
    serial = [tmp_path / f"serial.{i:04d}.exr" for i in range(len(dumps))]
    serial_frames(dumps, serial)
    assert_same_files([tmp_path / o for o in outputs], serial)
    assert read_sample_buffer(dumps[0]).shape  # the caller's own dumps were read


def test_a_frame_run_again_takes_its_own_identical_output_as_written(tmp_path, dumps):
    """Dask runs a finished frame again when the worker holding its result dies before the result was
    fetched: the second attempt found the output the first had written, complete, and the frame was
    reported as failed with FileExistsError (a red-team pass). An output identical byte for
    byte to what the attempt writes is its own; any other file is still refused."""
    from awr_denoise.parallel import denoise_frame

    out, png = tmp_path / "out.exr", tmp_path / "out.png"
    first = denoise_frame(dumps[0], out, preview=png)
    before = out.read_bytes(), png.read_bytes()
    again = denoise_frame(dumps[0], out, preview=png, again=True)
    assert (again.output, again.preview) == (first.output, first.preview)
    assert (out.read_bytes(), png.read_bytes()) == before
    with pytest.raises(FileExistsError, match="out.exr"):
        denoise_frame(dumps[0], out, preview=png)  # not a task run again
    with pytest.raises(FileExistsError, match="out.exr"):
        denoise_frame(dumps[1], out, preview=png, again=True)  # another frame's image
    png.unlink()
    denoise_frame(dumps[0], out, preview=png, again=True)  # killed between the image and its preview
    assert png.read_bytes() == before[1] and sorted(p.name for p in tmp_path.iterdir() if "out" in p.name) == [
        "out.exr", "out.png"]


def test_denoise_frame_checks_its_outputs_before_the_work_as_denoise_frames_does(tmp_path, dumps):
    """``denoise_frame`` (public) replaced its input, its reference or its own output with the preview, after
    the reconstruction; a preview that existed was found after the image was written (a red-team pass)."""
    import shutil

    from awr_denoise.parallel import denoise_frame

    shutil.copy(dumps[0], tmp_path / "dump.exr")
    before = (tmp_path / "dump.exr").read_bytes()
    for kwargs, message in (({"output": tmp_path / "o.exr", "preview": tmp_path / "o.exr"}, "more than once"),
                            ({"output": tmp_path / "o.exr", "preview": tmp_path / "dump.exr"}, "also an input"),
                            ({"output": tmp_path / "dump.exr"}, "also an input"),
                            ({"output": tmp_path / "o.exr", "reference": tmp_path / "dump.exr",
                              "preview": tmp_path / "dump.exr"}, "also an input")):
        with pytest.raises(ValueError, match=message):
            denoise_frame(tmp_path / "dump.exr", overwrite=True, **kwargs)
    (tmp_path / "p.png").write_bytes(b"x")
    with pytest.raises(FileExistsError, match="p.png"):
        denoise_frame(tmp_path / "dump.exr", tmp_path / "o.exr", preview=tmp_path / "p.png")
    assert not (tmp_path / "o.exr").exists() and (tmp_path / "dump.exr").read_bytes() == before


@pytest.mark.parametrize("call", ["frame", "frames"])
def test_frame_arguments_are_checked_by_name_before_any_work(tmp_path, dumps, call):
    """Truthy strings were read as flags (``overwrite="no"`` replaced the outputs), an empty reference
    compared nothing, an exposure without previews did nothing, a callback that is no function failed after
    the outputs were written, one path for a list was read character by character."""
    from awr_denoise.parallel import denoise_frame

    out = tmp_path / "o.exr"
    out.write_bytes(b"precious")

    def run(**kwargs):
        if call == "frame":
            return denoise_frame(dumps[0], out, **kwargs)
        return denoise_frames([dumps[0]], [out], **kwargs)

    for kwargs, error, message in (({"overwrite": "no"}, TypeError, "overwrite: expected True or False"),
                                   ({"overwrite": True, "half": 1}, TypeError, "half: expected True or False"),
                                   ({"overwrite": True, "reference": ""}, ValueError, "reference: an empty file"),
                                   ({"overwrite": True, "exposure": 2.0}, ValueError, "exposure: 2 sets the")):
        with pytest.raises(error, match=message):
            run(**kwargs)
    if call == "frames":
        with pytest.raises(TypeError, match="on_frame: expected a function"):
            run(overwrite=True, on_frame=5)
        with pytest.raises(TypeError, match="inputs: expected a list of file names, got str"):
            denoise_frames(str(dumps[0]), str(out), overwrite=True)
        with pytest.raises(ValueError, match="reference: an empty file name"):
            denoise_frames([dumps[0]], [out], reference=[""], overwrite=True)
    else:
        with pytest.raises(TypeError, match="reference: expected a file name, got list"):
            run(overwrite=True, reference=[str(out)])
        with pytest.raises(TypeError, match="read_options: expected a dict"):
            run(overwrite=True, read_options=[{}])
    assert out.read_bytes() == b"precious"


def test_reconstruction_options_are_checked_once_before_any_frame(tmp_path, dumps, monkeypatch):
    """``c_s=-1`` or a misspelt option failed every frame after its read, as a FramesFailedError."""
    from awr_denoise.parallel import frames

    monkeypatch.setattr(frames, "read_sample_dump", lambda *a, **k: pytest.fail("a frame was read"))
    outputs = [tmp_path / f"o.{i}.exr" for i in range(len(dumps))]
    with pytest.raises(ValueError, match="c_s: must be >= 0"):
        denoise_frames(dumps, outputs, c_s=-1)
    with pytest.raises(TypeError, match="cs: not an option of the reconstruction"):
        denoise_frames(dumps, outputs, cs=1.0)
    with pytest.raises(TypeError, match="variance_probes: not an option"):  # each frame's is 0
        denoise_frames(dumps, outputs, variance_probes=4)
    # The reconstruction's other checks, which failed every frame after its read as well: a guide function is not
    # called for them (OIDN would run for nothing).
    guide = lambda buffer: pytest.fail("the guide function ran")  # noqa: E731
    for options, message in (({"wavelet": "nope"}, "wavelet: 'nope' is not a discrete wavelet"),
                             ({"domain": "lug"}, "domain: 'lug' is not one of"),
                             ({"mode": "hue"}, "mode: 'hue'"),
                             ({"boundary": "mirror"}, "boundary: 'mirror' is not one of"),
                             ({"guide_projection": 0.3}, "guide_projection: 0.3 given without a guide"),
                             ({"guide": guide, "guide_projection": 1.5}, "guide_projection: must be <= 1"),
                             ({"guide": guide, "guard_probes": 1}, "guard_probes: not with a guide"),
                             ({"features": True, "stages": 1}, "features: it gives the pilot of the Wiener stages"),
                             ({"levels": -1}, "levels: must be >= 1")):
        with pytest.raises(ValueError, match=message):
            denoise_frames(dumps, outputs, **options)
    for options, message in (({"guide": "oidn"}, "guide: 'oidn' is a name"), ({"features": "yes"}, "features: "),
                             ({"levels": "x"}, "levels: ")):
        with pytest.raises(TypeError, match=message):
            denoise_frames(dumps, outputs, **options)
    assert not any(o.exists() for o in outputs)


def test_the_error_against_the_reference_is_the_written_half_images(tmp_path):
    """With ``half`` the error was the float image's, not the file's that --maxerror is meant to check (a
    walkthrough): now the two agree to the bit."""
    from awr_denoise.io import read_image
    from awr_denoise.metrics import relmse
    from awr_denoise.parallel import denoise_frame

    pbrt = Path(__file__).resolve().parents[1] / "data" / "pbrt"
    frame = denoise_frame(pbrt / "pbrt_gbuffer_default.exr", tmp_path / "h.exr", reference=pbrt / "pbrt_ref.exr",
                          half=True)
    assert frame.relmse == relmse(read_image(tmp_path / "h.exr"), read_image(pbrt / "pbrt_ref.exr"))


def test_plane_options_are_read_for_the_workers_as_the_serial_reader_reads_them(tmp_path, monkeypatch):
    """Frames on processes and Dask get plane options with their files made absolute. A bare plane name that is also
    a file in the working folder (a file named ``variance``) was made that file on them only, and the frame refused
    (an attack pass): the colour's, variance's and count's bare names are planes of the input; a feature's may be a
    whole file, as ``--alb albedo.exr``."""
    from awr_denoise.parallel.frames import _absolute_plane

    monkeypatch.chdir(tmp_path)
    for name in ("variance", "albedo.exr", "in.exr"):
        (tmp_path / name).write_bytes(b"")
    assert _absolute_plane("variance", "variance") == "variance"
    assert _absolute_plane("count", "variance") == "variance"
    assert _absolute_plane("variance", "in.exr:variance") == f"{tmp_path / 'in.exr'}:variance"
    assert _absolute_plane("albedo", "albedo.exr") == str(tmp_path / "albedo.exr")
    assert _absolute_plane("albedo", "in.exr:Albedo") == f"{tmp_path / 'in.exr'}:Albedo"
    assert _absolute_plane("albedo", "Albedo") == "Albedo"
