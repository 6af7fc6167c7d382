"""Frame sequences: one task per frame, each reading its dump and writing its image itself.

Tasks get file *paths*, not pixels, so nothing but names crosses a network, and the work inside
a task is the serial computation: every image is bitwise identical to a serial run whatever the
executor. ``awr denoise`` runs its frames through :func:`denoise_frames`, with or without
``--workers``.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import filecmp
import inspect
import os
import tempfile
from collections.abc import Callable, Collection, Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import _checks
from ..buffers import SampleBuffer
from ..errors import AWRError, InputFileError
from ..guides import oidn_features
from ..io import SampleDump, read_image, read_sample_dump, write_image, write_preview
from ..io.atomic import check_writable, public_name, standing_for
from ..io.exr import Window, check_same_windows, format_window, read_header, recorded_windows
from ..io.presets import feature_plane_file, plane_file
from ..io.provenance import image_provenance
from ..metrics import relmse
from ..reconstruct import reconstruct_detailed
from ..settings import resolve_settings
from .executors import dask_client, executor_or_threads, submit, wait_first

__all__ = ["FrameResult", "FramesFailedError", "denoise_frame", "denoise_frames"]


class FramesFailedError(AWRError):
    """Some frames of :func:`denoise_frames` failed; the others were written.

    Attributes
    ----------
    failures
        Input path to the exception its frame raised, in input order.
    """

    def __init__(self, failures: dict[str, BaseException], total: int) -> None:
        self.failures = dict(failures)
        lines = [f"{len(failures)} of {total} frame(s) failed:"]
        lines += [f"  {path}: {type(exc).__name__}: {exc}" for path, exc in failures.items()]
        super().__init__("\n".join(lines))


@dataclass(frozen=True)
class FrameResult:
    """What :func:`denoise_frame` did with one frame.

    Attributes
    ----------
    source, output, preview
        The dump read, the image written and the PNG preview written (or None).
    shape
        (H, W) of the image.
    spp
        Average samples per pixel of the dump.
    fraction_zeroed
        Share of detail coefficients thresholding set to zero.
    nonfinite
        NaN/Inf samples the reader dropped or zeroed.
    relmse
        Relative MSE against the reference, when one was given.
    features
        Features the dump held (albedo, normal, depth), used with ``guide``/``features`` only.
    unsampled
        Pixels without samples (their values estimated from the sampled pixels around them).
    """

    source: str
    output: Path
    preview: Path | None
    shape: tuple[int, int]
    spp: float
    fraction_zeroed: float
    nonfinite: int
    relmse: float | None = None
    features: tuple[str, ...] = ()
    unsampled: int = 0


def _reference_error(reference: str | os.PathLike[str], image: np.ndarray, channels: Sequence[str], source: str,
                     windows: dict[str, Any]) -> float:
    """relMSE of ``image`` (its ``channels``) against the reference image file: its channels of those
    names, else its colour, which must have as many channels (a one-channel depth map compared
    with R alone gave another verdict than ``awr diff``, which refused it)."""
    names = {getattr(c, "name", str(c)) for c in read_header(reference).get("channels", [])}
    with recorded_windows() as reads:  # its windows from the read of its pixels, not from another
        ref = read_image(reference, channels=list(channels)) if set(channels) <= names else read_image(reference)
    if ref.shape[:2] != image.shape[:2]:
        raise InputFileError(f"{os.fspath(reference)}: size {ref.shape[1]}x{ref.shape[0]} does not match "
                             f"{image.shape[1]}x{image.shape[0]} of {source}")
    if ref.shape[2] != image.shape[2]:
        raise InputFileError(f"{os.fspath(reference)}: {ref.shape[2]} channel(s), the image of {source} has "
                             f"{image.shape[2]} ({','.join(channels)})")
    check_same_windows(reference, reads[0][1], source, windows)
    return relmse(image, ref)


def _changed(source: str, checked: Mapping[str, Window], found: Mapping[str, Window]) -> InputFileError:
    """The error of a source whose windows, read with its samples, are not those it was checked in."""
    key = "dataWindow" if checked.get("dataWindow") != found.get("dataWindow") else "displayWindow"
    shown = [format_window(w[key]) if key in w else "none" for w in (checked, found)]
    return InputFileError(f"{source}: changed while it was read (replaced or rewritten meanwhile: {key} "
                          f"{shown[0]} when checked, {shown[1]} with its samples); nothing was written from it")


def denoise_frame(source: str | os.PathLike[str], output: str | os.PathLike[str], *,
                  preview: str | os.PathLike[str] | None = None, exposure: float = 0.0,
                  reference: str | os.PathLike[str] | None = None, overwrite: bool = False, half: bool = False,
                  read_options: dict[str, Any] | None = None, again: bool = False,
                  windows: Mapping[str, Window] | None = None, **reconstruct_options: Any) -> FrameResult:
    """Read one dump, reconstruct it, write the image (and a preview) atomically.

    Parameters
    ----------
    source
        Sample dump (any layout :func:`~awr_denoise.io.read_sample_buffer` reads).
    output
        EXR image to write, with the ``awr:*`` provenance of
        :func:`~awr_denoise.io.provenance.image_provenance`.
    preview
        Optional sRGB PNG preview, at ``exposure`` stops.
    reference
        Optional reference image; the result's relMSE against it is returned.
    overwrite, half
        As in :func:`~awr_denoise.io.write_image`.
    read_options
        Keyword arguments of :func:`~awr_denoise.io.read_sample_buffer`.
    again
        The frame may be a task run again (Dask runs a finished task again when the worker holding
        its result dies before it was fetched): an existing output, or preview, identical byte for
        byte to what this attempt writes is its earlier attempt's, and is taken as written.
    windows
        The data and display windows (:func:`~awr_denoise.io.exr.read_windows`) the caller found the
        source in and checked its other inputs and options against: a source read in others was
        replaced or rewritten since, and is refused (:class:`InputFileError`) before any work.
    **reconstruct_options
        Keyword arguments of :func:`~awr_denoise.reconstruct`.

    Returns
    -------
    FrameResult
    """
    source, output = _checks.file_path("source", source), _checks.file_path("output", output)
    preview = None if preview is None else _checks.file_path("preview", preview)
    reference = None if reference is None else _checks.file_path("reference", reference)
    _checks.real("exposure", exposure)
    overwrite, half, again = (_checks.flag(name, value) for name, value in
                              (("overwrite", overwrite), ("half", half), ("again", again)))
    if exposure != 0 and preview is None:  # it sets the preview alone: refused, not ignored
        raise ValueError(f"exposure: {exposure:g} sets the preview's exposure; there is no preview")
    if read_options is not None and not isinstance(read_options, Mapping):
        raise TypeError(f"read_options: expected a dict, got {_checks.described(read_options)}")
    # Before the work, as denoise_frames checks its lists: an output that is the input, the reference, a plane
    # file or the preview was replaced after the reconstruction (a red-team pass). A task run again (``again``)
    # may find its own output, compared below.
    read = [source, *([reference] if reference else []), *_plane_files(read_options or {})]
    _check_outputs(read, [output], None if preview is None else [preview], overwrite or again)
    if windows is not None and not isinstance(windows, Mapping):
        raise TypeError(f"windows: expected a dict like read_windows() returns, got {type(windows).__name__}")
    # The image keeps the dump's data and display windows, taken from the read that gave the samples
    # (the reader reads the source first): a second read of the path met the next version of a file
    # replaced meanwhile, and placed one version's pixels in the other's window.
    with recorded_windows() as reads:
        dump = read_sample_dump(source, **(read_options or {}))
    buffer = dump.buffer
    checked, windows, space = windows, reads[0][1], reads[0][2]
    if checked is not None and dict(checked) != windows:
        raise _changed(source, checked, windows)
    if not buffer.count.any():  # refused by the reconstruction too, but there without the file's name
        raise InputFileError(f"{source}: no pixel has any sample")
    if preview is not None and buffer.n_channels not in (1, 3, 4):  # before the work, not after it
        raise InputFileError(f"{source}: {buffer.n_channels} channels ({','.join(buffer.channels)}); a preview "
                             "(preview= / --preview) shows 1, 3 or 4")
    if reconstruct_options.get("features") and not buffer.features:  # the file's fault, named (not the argument's)
        raise InputFileError(f"{source}: holds no feature buffers (albedo, normal or depth) to guide with; give "
                             "them as files (--alb, --nrm, --depth; albedo=, normal=, depth=)")
    try:
        result = reconstruct_detailed(buffer, variance_probes=0, **reconstruct_options)
    except ValueError as exc:  # what the buffer cannot do is the file's: named as the file, not as "buffer"
        if not str(exc).startswith("buffer: "):
            raise
        raise InputFileError(f"{source}: {str(exc).removeprefix('buffer: ')}") from None
    image = np.asarray(result.image)
    if half:  # the error of the image written, which --maxerror checks: HALF's rounding included
        image = image.astype(np.float16).astype(np.float64)
    error = _reference_error(reference, image, buffer.channels, source, windows) if reference else None
    header = {**image_provenance(result, buffer, source=source, **_guiding_planes(dump, result, reconstruct_options)),
              **windows}
    if space is not None:  # the dump's RGB (pbrt-v4 writes it for any colour space but sRGB): the image's too
        header["chromaticities"] = space

    def write(path: str | os.PathLike[str], replace: bool) -> str | os.PathLike[str]:
        return write_image(path, result.image, channels=buffer.channels, half=half, overwrite=replace, header=header)

    def draw(path: str | os.PathLike[str], replace: bool) -> str | os.PathLike[str]:
        return write_preview(path, result.image, exposure=exposure, overwrite=replace)

    written = write(output, overwrite or (again and _identical(output, write)))
    shown = draw(preview, overwrite or (again and _identical(preview, draw))) if preview else None
    return FrameResult(source, Path(written), None if shown is None else Path(shown), buffer.shape,
                       buffer.total_samples / buffer.count.size, float(result.fraction_zeroed),
                       int(buffer.nonfinite), error, tuple(buffer.features), int(np.count_nonzero(buffer.count == 0)))


def _guiding_planes(dump: SampleDump, result: Any, options: Mapping[str, Any]) -> dict[str, str]:
    """``albedo_plane=...`` and the like for each feature that guided the result: the plane of the input
    (``Albedo``), or ``file.exr:plane`` for another file (its name, as ``awr:input`` records the input's).

    The feature pilot takes every feature (with a guide too, where the gate closes); OIDN the albedo, and the
    normal beside it, unless told to take none (its recorded ``guide_auxiliary``); another guide none."""
    read = dump.buffer.features
    if options.get("features"):
        used: Collection[str] = read
    elif "guide_auxiliary" in result.parameters:  # OIDN's guide, the way it took the features recorded
        used = oidn_features(read, result.parameters["guide_auxiliary"])
    else:
        used = ()
    return {f"{name}_plane": _plane_name(where) for name, where in dump.feature_planes.items() if name in used}


def _plane_name(where: str) -> str:
    """``dir/alb.exr:Albedo`` as ``alb.exr:Albedo``; a plane of the input as it is."""
    path, sep, plane = where.rpartition(":")
    return f"{os.path.basename(path)}:{plane}" if sep and path else where


def _identical(target: str | os.PathLike[str], write: Callable[[str, bool], Any]) -> bool:
    """Whether ``target`` exists and holds, byte for byte, what ``write(path, replace)`` writes (a
    frame's writers are deterministic), written for the comparison in a temporary folder."""
    if not os.path.isfile(target):
        return False
    with tempfile.TemporaryDirectory(prefix="awr-frame-") as folder:
        probe = os.path.join(folder, os.path.basename(os.fspath(target)))
        write(probe, True)
        return filecmp.cmp(probe, target, shallow=False)


def _stat(path: str) -> os.stat_result | None:
    try:
        return os.stat(path)
    except OSError:
        return None


_PLANE_OPTIONS = ("color", "variance", "count", "albedo", "normal", "depth")
"""The reading options that may name a file (``file.exr:plane``, or a whole file for a feature)."""


_FEATURE_OPTIONS = ("albedo", "normal", "depth")
"""The plane options whose bare name may be a whole file (``--alb albedo.exr``); the colour's, variance's and
count's bare names are planes of the input (:func:`~awr_denoise.io.presets.plane_file`)."""


def _absolute_plane(option: str, spec: Any) -> Any:
    """A plane option with its file's path made absolute (a plane of the input itself unchanged): read as the
    serial reader reads it (a plane named as a file in the working folder was made a file on Dask only, and
    refused there; an attack pass)."""
    if not isinstance(spec, str):
        return spec
    if option in _FEATURE_OPTIONS and feature_plane_file(spec) == Path(spec):
        return os.path.abspath(spec)  # a whole file
    if plane_file(spec) is not None:  # its files were checked before: no empty plane name
        file, plane = spec.rsplit(":", 1)
        return f"{os.path.abspath(file)}:{plane}"
    return spec


def _per_frame(param: str, value: Any, frames: int, one: Callable[[Any], bool], what: str) -> list[Any]:
    """``value`` as one item per frame: ``value`` itself for every frame when ``one(value)`` (the same for all),
    else the caller's list of ``frames`` items, each ``one`` of them and none None."""
    if one(value):
        return [value] * frames
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise TypeError(f"{param}: expected a {what}, or one {what} per input, got {type(value).__name__}")
    if len(value) != frames:
        raise ValueError(f"{param}: {len(value)} given for {frames} input(s)")
    for item in value:
        if item is None or not one(item):
            raise TypeError(f"{param}: expected one {what} per input, got a {type(item).__name__} among them")
    return list(value)


def _read_options_per_frame(read_options: Mapping[str, Any] | Sequence[Mapping[str, Any]] | None,
                            frames: int) -> list[dict[str, Any]]:
    """``read_options`` as one dict per frame: the same for every frame, or the caller's list of them."""
    given = _per_frame("read_options", read_options, frames, lambda v: v is None or isinstance(v, Mapping), "dict")
    return [dict(options or {}) for options in given]


def _references_per_frame(reference: str | os.PathLike[str] | Sequence[str | os.PathLike[str]] | None,
                          frames: int) -> list[str | None]:
    """``reference`` as one path (or None) per frame: the same for every frame, or the caller's list of them."""
    given = _per_frame("reference", reference, frames, lambda v: v is None or isinstance(v, (str, os.PathLike)),
                       "path")
    return [None if path is None else _checks.file_path("reference", path) for path in given]


def _check_reconstruct_options(options: Mapping[str, Any]) -> None:
    """The options every frame's reconstruction takes, checked once before any frame is read: a name it does not
    take or a setting out of range failed every frame after its read (a red-team pass). What depends on a frame
    (its levels against its size) is its own."""
    known = set(inspect.signature(reconstruct_detailed).parameters) - {"buffer", "variance_probes"}
    unknown = sorted(set(options) - known)
    if unknown:
        raise TypeError(f"{unknown[0]}: not an option of the reconstruction (reconstruct_detailed takes "
                        f"{', '.join(sorted(known))})")
    settings = set(inspect.signature(resolve_settings).parameters)
    resolve_settings(**{name: value for name, value in options.items() if name in settings})
    # The reconstruction's other checks (the wavelet, domain, mode, boundary, the guide's share, the features'
    # flag...) failed every frame too: they run here on an 8x8 colour of two samples a pixel with an albedo. A guide
    # function or image stands in as an 8x8 image (OIDN would run for nothing; an image's shape is the frame's); a
    # guide's name goes as it is, refused. The levels' range and the executor are the frame's and the call's.
    levels = options.get("levels")
    if levels is not None:
        _checks.whole("levels", levels, minimum=1, integral=True)
    trial = {name: value for name, value in options.items() if name not in ("levels", "executor")}
    if trial.get("guide") is not None and not isinstance(trial["guide"], str):
        trial["guide"] = np.ones((8, 8, 3))
    ones, count = np.ones((8, 8, 3)), np.full((8, 8), 2)
    albedo = SampleBuffer.from_moments(count, ones / 2, ones)
    reconstruct_detailed(SampleBuffer.from_moments(count, ones, ones, features={"albedo": albedo}), variance_probes=0,
                         **trial)


def _plane_files(read_options: Mapping[str, Any]) -> list[str]:
    """The files a frame's ``file.exr:plane`` read options name (an empty plane name refused, named)."""
    files = []
    for option, spec in read_options.items():
        if isinstance(spec, str):
            try:
                file = plane_file(spec)
            except ValueError as exc:
                raise ValueError(f"{option}: {exc}") from None
            files += [] if file is None else [str(file)]
    return files


def _check_outputs(sources: list[str], targets: list[str], previews: list[str] | None, overwrite: bool) -> None:
    """Refuse output lists that collide with each other or the inputs, and existing outputs."""
    written = targets + (previews or [])
    resolved = [Path(t).resolve() for t in written]
    if len(set(resolved)) != len(resolved):
        raise ValueError("outputs: the same file is listed more than once")
    inputs = {Path(s).resolve() for s in sources}
    inodes = {(st.st_dev, st.st_ino) for st in map(_stat, sources) if st is not None}
    for target, where in zip(written, resolved):
        st = _stat(target)
        if where in inputs or (st is not None and (st.st_dev, st.st_ino) in inodes):
            raise ValueError(f"outputs: {target} is also an input")
    for target in written:
        check_writable(target, overwrite=overwrite)


def denoise_frames(inputs: Sequence[str | os.PathLike[str]], outputs: Sequence[str | os.PathLike[str]], *,
                   previews: Sequence[str | os.PathLike[str]] | None = None, exposure: float = 0.0,
                   reference: str | os.PathLike[str] | Sequence[str | os.PathLike[str]] | None = None,
                   executor: Executor | None = None, overwrite: bool = False, half: bool = False,
                   read_options: Mapping[str, Any] | Sequence[Mapping[str, Any]] | None = None,
                   on_frame: Callable[[FrameResult], None] | None = None,
                   windows: Sequence[Mapping[str, Window] | None] | None = None,
                   threads: Executor | None = None, **reconstruct_options: Any) -> list[Path]:
    """Denoise a sequence of sample dumps, one task per frame (:func:`denoise_frame`).

    Every image is bitwise identical to a serial run whatever the executor; writes are atomic,
    so a failed frame leaves no partial file.

    Parameters
    ----------
    inputs
        Sample dumps, one per frame. With a Dask cluster the paths must be readable on every
        worker (a shared file system).
    outputs
        Image to write for each input, same length and order.
    previews
        Optional PNG preview for each input (same length), at ``exposure`` stops.
    reference
        Optional reference image every frame is compared with (:attr:`FrameResult.relmse`), or one per input
        (same length: each frame's own).
    executor
        Runs the frames; default this thread for one frame, else a thread pool of up to one
        thread per CPU for this call.
    overwrite
        Replace existing outputs. Without it an existing output is refused before any frame
        is processed.
    half
        Write HALF channels (see :func:`~awr_denoise.io.write_image`).
    read_options
        Keyword arguments of :func:`~awr_denoise.io.read_sample_buffer` (``preset``,
        ``color``, ``variance``, ``albedo``, ...): one dict for every frame, or one per input (each
        frame's own plane files, ``albedo="alb.0007.exr"``).
    on_frame
        Called in this thread with each frame's :class:`FrameResult` as the frame completes.
    windows
        For each input, the windows the caller found it in (or None): an input read in others fails
        its frame (see :func:`denoise_frame`).
    threads
        A thread pool of this process each frame's reconstruction spreads its own work over
        (:func:`~awr_denoise.reconstruct`'s ``executor``; the same image); not with frames run in other
        processes (a process pool, Dask), which cannot take it.
    **reconstruct_options
        Keyword arguments of :func:`~awr_denoise.reconstruct` (``c_s``, ``wavelet``,
        ``levels``, ``domain``, ``mode``, ``boundary``). Each frame runs on one worker.

    Returns
    -------
    list of Path
        The written images, in input order.

    Raises
    ------
    FramesFailedError
        When frames failed; every other frame was still written. ``failures`` maps each
        failed input to its exception.
    FileExistsError
        An output exists and ``overwrite`` is False (checked before any work starts).
    ValueError
        Mismatched lengths, an output listed twice, or an output that is also an input.
    """
    _checks.real("exposure", exposure)
    overwrite, half = _checks.flag("overwrite", overwrite), _checks.flag("half", half)
    if on_frame is not None and not callable(on_frame):  # found after the frames were written, else
        raise TypeError(f"on_frame: expected a function of a FrameResult, got {_checks.described(on_frame)}")
    sources, targets = _checks.file_paths("inputs", inputs), _checks.file_paths("outputs", outputs)
    shown = None if previews is None else _checks.file_paths("previews", previews)
    if exposure != 0 and shown is None:  # it sets the previews alone: refused, not ignored
        raise ValueError(f"exposure: {exposure:g} sets the previews' exposure; there are no previews")
    if len(sources) != len(targets) or (shown is not None and len(shown) != len(sources)):
        raise ValueError(f"outputs: {len(targets)} given for {len(sources)} input(s)"
                         + ("" if shown is None else f" (and {len(shown)} previews)"))
    if windows is not None and (isinstance(windows, (str, bytes, Mapping)) or not isinstance(windows, Sequence)):
        raise TypeError(f"windows: expected one read_windows() dict (or None) per input, got {type(windows).__name__}")
    checked = [None] * len(sources) if windows is None else list(windows)
    if len(checked) != len(sources):
        raise ValueError(f"windows: {len(checked)} given for {len(sources)} input(s)")
    per_frame = _read_options_per_frame(read_options, len(sources))
    references = _references_per_frame(reference, len(sources))
    read = sources + sorted({r for r in references if r is not None})
    read += [path for frame in per_frame for path in _plane_files(frame)]
    _check_outputs(read, targets, shown, overwrite)
    if not sources:
        return []
    _check_reconstruct_options(reconstruct_options)
    if threads is not None:
        _checks.executor("threads", threads, here=False)
        if executor is not None and (dask_client(executor) is not None or isinstance(executor, cf.ProcessPoolExecutor)):
            raise ValueError(f"threads: a thread pool of this process, where the frames run in other processes "
                             f"({type(executor).__name__}); give it to a thread pool's frames, or none")
        reconstruct_options = {**reconstruct_options, "executor": threads}
    options = {"exposure": exposure, "overwrite": overwrite, "half": half, **reconstruct_options}
    as_given = list(zip(sources, targets, shown if shown is not None else [None] * len(sources)))
    staged = [{path: public_name(path) for path in (target, preview) if path is not None and public_name(path) != path}
              for _, target, preview in as_given]  # a caller's OutputSet temporaries (awr denoise's)
    if executor is not None and dask_client(executor) is not None:
        # Dask runs a finished frame again when the worker holding its result dies before it was
        # fetched: that attempt finds the output the first wrote, complete, and took it for someone
        # else's file (a frame written, reported as failed).
        options["again"] = True
        # A Dask worker runs in its own folder (dask worker started from $HOME): a relative path
        # there names another file. Every path goes as the caller sees it, absolute.
        staged = [{os.path.abspath(p): name for p, name in names.items()} for names in staged]
        sources, targets = [os.path.abspath(p) for p in sources], [os.path.abspath(p) for p in targets]
        shown = None if shown is None else [os.path.abspath(p) for p in shown]
        references = [None if r is None else os.path.abspath(r) for r in references]
        per_frame = [{k: _absolute_plane(k, v) if k in _PLANE_OPTIONS else v for k, v in frame.items()}
                      for frame in per_frame]
    if executor is None and len(sources) == 1:
        # One frame runs in this thread, where Ctrl-C stops it at once; on a worker thread, which
        # cannot be stopped, the caller would wait for the whole reconstruction first.
        try:
            result = _frame_task(sources[0], targets[0], None if shown is None else shown[0], checked[0],
                                 {**options, "read_options": per_frame[0], "reference": references[0]}, staged[0])
        except Exception as exc:
            raise FramesFailedError({sources[0]: exc}, 1) from exc
        if on_frame is not None:
            on_frame(result)
        return [result.output]
    failures: dict[str, BaseException] = {}
    with executor_or_threads(executor, len(sources)) as pool:
        pending = {submit(pool, _frame_task, s, t, None if shown is None else shown[i], checked[i],
                          {**options, "read_options": per_frame[i], "reference": references[i]}, staged[i]): i
                   for i, (s, t) in enumerate(zip(sources, targets))}
        try:
            while pending:
                done = wait_first(pool, pending)
                for future in done:
                    # Let go of a finished frame at once: a Dask cluster that loses the worker holding
                    # its result would otherwise run the frame again, over its own written output.
                    source, output, preview = as_given[pending.pop(future)]
                    if future.exception() is not None:
                        failures[source] = future.exception()
                    elif on_frame is not None:  # named as the caller named it
                        on_frame(dataclasses.replace(future.result(), source=source, output=Path(output),
                                                     preview=None if preview is None else Path(preview)))
        except BaseException:
            # Ctrl-C or a failing callback: frames not started yet never start (the ones
            # running finish, since threads cannot be stopped, before the pool closes).
            for future in pending:
                future.cancel()
            raise
    if failures:
        ordered = {s: failures[s] for s, _, _ in as_given if s in failures}
        raise FramesFailedError(ordered, len(sources)) from next(iter(ordered.values()))
    return [Path(t) for _, t, _ in as_given]


def _frame_task(source: str, output: str, preview: str | None, windows: Mapping[str, Window] | None,
                options: dict[str, Any], staged: dict[str, str]) -> FrameResult:
    """:func:`denoise_frame` with its options in one picklable dict (runs in a worker). ``staged``: the outputs
    that are temporaries of the caller's :class:`~awr_denoise.io.atomic.OutputSet`, with their targets' names
    (a worker process knows nothing of it: :func:`~awr_denoise.io.atomic.standing_for`)."""
    with standing_for(staged):
        return denoise_frame(source, output, preview=preview, windows=windows, **options)
