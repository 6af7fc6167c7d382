"""Helpers shared by the ``awr`` subcommands: errors, frame patterns, paths, plane options.

Kept free of numerical work: every subcommand is argument parsing around library calls.
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import os
import re
import sys
from collections.abc import Iterable, Iterator, Sequence
from typing import Any

import numpy as np

from awr_denoise._progress import auto_tqdm as tqdm
from awr_denoise._progress import bars_shown
from awr_denoise.buffers import NONFINITE_POLICIES, VARIANCE_KINDS
from awr_denoise.errors import InputFileError
from awr_denoise.io import PRESETS
from awr_denoise.io.dump import header_count
from awr_denoise.io.exr import brief, header_value
from awr_denoise.io.request_map import MAX_ROUND
from awr_denoise.sampling import SAMPLERS

from .errors import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, RuntimeFailure, UsageError, one_line_warnings, shown
from .sampler_settings import carried_settings
from .values import MAX_FRAMES, MAX_SEED, MAX_SPP, nonempty, whole

__all__ = [
    "dump_options_given",
    "available_memory",
    "check_memory",
    "RENDER_BYTES_PER_PIXEL",
    "EXIT_OK",
    "EXIT_FAILURE",
    "EXIT_USAGE",
    "UsageError",
    "RuntimeFailure",
    "add_output_options",
    "add_plane_options",
    "plane_kwargs",
    "parse_frames",
    "expand_frames",
    "frame_jobs",
    "progress",
    "print_json",
    "status",
    "one_line_warnings",
]


def add_output_options(parser: argparse.ArgumentParser, *, output_help: str) -> None:
    """``-o/--output`` and ``--overwrite``."""
    parser.add_argument("-o", "--output", type=nonempty, required=True, metavar="FILE", help=output_help)
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")


def add_plane_options(parser: argparse.ArgumentParser) -> None:
    """Options that say where the statistics are inside the input EXR files."""
    g = parser.add_argument_group("input layout (see docs/io.md)")
    g.add_argument("--preset", default="auto", choices=PRESETS,
                   help="renderer layout of the input; 'auto' detects it from the channel names")
    g.add_argument("--color", type=nonempty, metavar="PLANE", help="mean plane, e.g. 'RGB', 'Ci' or 'beauty.exr:RGB'")
    g.add_argument("--variance", type=nonempty, metavar="PLANE", help="spread plane, e.g. 'Variance' or 'var.exr:mse'")
    g.add_argument("--count", type=nonempty, metavar="PLANE", help="per-pixel sample count plane")
    g.add_argument("--variance-kind", choices=VARIANCE_KINDS,
                   help="what --variance holds: per-sample variance, variance of the mean, or E[x^2]")
    g.add_argument("--spp", type=whole(minimum=1, maximum=MAX_SPP), metavar="N",
                   help="samples per pixel when the file has no count")
    g.add_argument("--layer", type=nonempty, metavar="NAME", help="Cycles view layer when the file has several")
    g.add_argument("--view", type=nonempty, metavar="NAME",
                   help="view of a stereo/multiview file, e.g. 'left' (required when the file has several)")
    g.add_argument("--nonfinite", default=NONFINITE_POLICIES[0], choices=NONFINITE_POLICIES,
                   help="NaN/Inf samples of a deep per-sample dump: refuse them (default), leave them "
                        "out, or count them as 0; dropped or zeroed samples are reported")
    f = parser.add_argument_group("features (albedo, normal, depth; see docs/io.md)",
                                  "Read automatically where the preset knows the planes (pbrt, Cycles, Mitsuba "
                                  "aov, awr dumps); these options name them. They are carried into the buffer "
                                  "and its dumps; the reconstruction uses them with --guide features or --guide oidn.")
    f.add_argument("--alb", type=nonempty, metavar="FILE[:PLANE]",
                   help="albedo: an image file (its R,G,B, as oidnDenoise --alb), FILE:PLANE, or a PLANE of the input")
    f.add_argument("--nrm", type=nonempty, metavar="FILE[:PLANE]",
                   help="shading normal: an image file (R,G,B or X,Y,Z), FILE:PLANE, or a PLANE of the input")
    f.add_argument("--depth", type=nonempty, metavar="FILE[:PLANE]",
                   help="depth: an image file (its Z or only channel), FILE:PLANE, or a PLANE of the input")


def plane_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments of :func:`awr_denoise.io.read_sample_buffer` from the plane options."""
    return {"preset": args.preset, "color": args.color, "variance": args.variance, "count": args.count,
            "variance_kind": args.variance_kind, "spp": args.spp, "layer": args.layer,
            "view": args.view, "nonfinite": args.nonfinite, "albedo": args.alb, "normal": args.nrm,
            "depth": args.depth}


def dump_options_given(args: argparse.Namespace) -> list[tuple[str, Any]]:
    """``(option, value)`` of every option describing a sample dump that was given (not at its default): the
    plane files and planes, then the layout's options. A command whose file is no dump refuses them."""
    given = [(option, spec) for option, spec in (("--color", args.color), ("--variance", args.variance),
                                                 ("--count", args.count), ("--alb", args.alb), ("--nrm", args.nrm),
                                                 ("--depth", args.depth))]
    given += [("--preset", None if args.preset == "auto" else args.preset), ("--variance-kind", args.variance_kind),
              ("--spp", args.spp), ("--layer", args.layer), ("--view", args.view),
              ("--nonfinite", None if args.nonfinite == NONFINITE_POLICIES[0] else args.nonfinite)]
    return [(option, value) for option, value in given if value is not None]


_RANGE = re.compile(r"^(-?[0-9]{1,18})(?:-(-?[0-9]{1,18})(?:[x:]([0-9]{1,18}))?)?$")  # ASCII digits only


def parse_frames(spec: str) -> list[int]:
    """Frame numbers from ``1-100``, ``1-100x5`` (every 5th), ``3`` or ``1,4,10-12``."""
    frames: list[int] = []
    for item in spec.split(","):
        m = _RANGE.match(item.strip())
        if not m:
            raise UsageError(f"--frames: cannot read {item!r} (use e.g. 1-100, 1-100x5 or 1,4,7)")
        first = int(m.group(1))
        last = int(m.group(2)) if m.group(2) is not None else first
        step = int(m.group(3) or 1)
        if last < first or step < 1:
            raise UsageError(f"--frames: empty range {item!r}")
        span = range(first, last + 1, step)
        if len(frames) + len(span) > MAX_FRAMES:  # counted before any list is built
            raise UsageError(f"--frames: {spec!r} names more than {MAX_FRAMES} frames")
        frames.extend(span)
    if len(set(frames)) < len(frames):  # else refused later as an output "written twice", which named no frame list
        twice = next(n for n, k in collections.Counter(frames).items() if k > 1)
        raise UsageError(f"--frames: {spec!r} names frame {twice} more than once")
    return frames


_HASHES = re.compile(r"#+")


def expand_frames(pattern: str, frame: int) -> str:
    """``shot.####.exr`` with frame 7 is ``shot.0007.exr`` (the run of ``#`` gives the padding).

    Only the file name holds the placeholder: a ``#`` in a folder name (``take#1/``) is kept."""
    folder, name = os.path.split(pattern)
    if not _HASHES.search(name):
        raise UsageError(f"{pattern}: no #### frame placeholder in the file name")
    return os.path.join(folder, _HASHES.sub(lambda m: f"{frame:0{len(m.group(0))}d}", name))


def frame_jobs(inputs: Sequence[str], output: str, frames: str | None) -> list[tuple[list[str], str]]:
    """(inputs, output) per frame; without ``--frames`` a single job with the names as given."""
    if frames is None:
        for name in [*inputs, output]:
            if _HASHES.search(os.path.basename(name)):
                raise UsageError(f"{name}: the name has a #### frame placeholder but no --frames was given")
        return [(list(inputs), output)]
    numbers = parse_frames(frames)
    if not _HASHES.search(os.path.basename(output)):
        raise UsageError(f"{output}: with --frames the output needs a #### placeholder in its file name")
    jobs = []
    for f in numbers:
        jobs.append(([expand_frames(i, f) if _HASHES.search(os.path.basename(i)) else i for i in inputs],
                     expand_frames(output, f)))
    return jobs


ANSWERS = {"awr:request_round": "round", "awr:request_total": "total"}
"""Optional batch header attributes: the request a batch answers, checked by ``merge --request``
(a batch that copied its request's header names it by ``awr:round`` and ``awr:total``)."""


def answer_keys(attributes: dict) -> dict[str, str]:
    """The header keys naming the request a batch answers, and the request field each names (none: no batch)."""
    copied = attributes.get("awr:semantics") == "sample-request"  # the request's own header, copied whole
    named = {**ANSWERS, **({"awr:round": "round", "awr:total": "total"} if copied else {})}
    return {key: field for key, field in named.items() if key in attributes}


def answered_round(attributes: dict) -> str | None:
    """The round of the request a batch names it answers (as written), or ``None`` for a file that names none."""
    keys = answer_keys(attributes)
    return next((str(attributes[key]) for key, field in keys.items() if field == "round"), None) if keys else None


def run_settings(path: str | os.PathLike[str], attributes: dict) -> tuple[str | None, int | None]:
    """The strategy and first round's spp (``awr:strategy``, ``awr:initial_spp``) a running dump or request
    carries for ``plan`` to continue its run (``None`` where absent), refused naming the file and the
    attribute where no run could go on: ``merge`` read and wrote them on unchecked, and the next ``plan``
    refused the dump (an initial spp of 0 without naming either)."""
    strategy = None
    if "awr:strategy" in attributes:
        strategy = str(header_value(attributes, "awr:strategy"))
        if strategy not in SAMPLERS:
            raise InputFileError(f"{path}: awr:strategy: {brief(strategy)} is not one of {', '.join(SAMPLERS)}")
    initial = None
    if "awr:initial_spp" in attributes:
        initial = header_count(path, attributes, "awr:initial_spp", 1, MAX_SPP, low=1)
    return strategy, initial


def dumped_seed(path: str | os.PathLike[str], attributes: dict) -> int:
    """A running dump's ``awr:seed`` (0 without), refused naming the file and the attribute."""
    return header_count(path, attributes, "awr:seed", 0, MAX_SEED)


def dumped_round(path: str | os.PathLike[str], attributes: dict) -> int:
    """A running dump's ``awr:round`` (1 without): rounds after the first are numbered from 1, and merge
    numbers the next one, so the last round has none."""
    return header_count(path, attributes, "awr:round", 1, MAX_ROUND - 1, low=1)


def run_settings_refused(path: str | os.PathLike[str], attributes: dict, shape: tuple[int, int], *,
                         request: bool = False) -> str | None:
    """The line ``plan`` would refuse a running dump of ``shape`` with for its ``awr:*`` run settings (strategy,
    first round's spp, the sampler's settings, seed, round; plan's own checks), or ``None``: ``info`` reports it
    beside "ready to denoise", which is about ``denoise``. With ``request``, the line ``merge --request`` would
    refuse a request map with for the settings it carries into the dump (its round is the request's own, checked
    as the map is read)."""
    try:
        strategy, _ = run_settings(path, attributes)
        carried_settings(path, attributes, strategy, shape)
        dumped_seed(path, attributes)
        if not request:
            dumped_round(path, attributes)
    except InputFileError as error:
        return str(error)
    return None


_PLANE_KWARGS = {"--color": "color", "--variance": "variance", "--count": "count", "--alb": "albedo",
                 "--nrm": "normal", "--depth": "depth"}
"""The keyword of :func:`plane_kwargs` each plane option sets."""


def frame_planes(specs: Sequence[tuple[str | None, str]], frames: Sequence[int | None]
                 ) -> list[list[tuple[str | None, str]]]:
    """Each frame's plane options ``(spec, option)``: a file name with a ``####`` placeholder (``--alb
    alb.####.exr``, ``--variance var.####.exr:V``) names each frame's own file; one without serves every
    frame. Without frames (``[None]``) a placeholder is refused, as in an input's name."""
    out = []
    for frame in frames:
        specs_of_frame = []
        for spec, option in specs:
            if spec is not None and _HASHES.search(os.path.basename(spec)):
                if frame is None:
                    raise UsageError(f"{option}: {spec}: the name has a #### frame placeholder but no --frames "
                                     "was given")
                spec = expand_frames(spec, frame)
            specs_of_frame.append((spec, option))
        out.append(specs_of_frame)
    return out


def frame_plane_kwargs(args: argparse.Namespace, planes: Sequence[Sequence[tuple[str | None, str]]]
                       ) -> dict[str, Any] | list[dict[str, Any]]:
    """:func:`plane_kwargs` for every frame of ``planes`` (:func:`frame_planes`): one dict when the frames
    share their plane files, else one per frame."""
    common = plane_kwargs(args)
    per_frame = [common | {_PLANE_KWARGS[option]: spec for spec, option in specs} for specs in planes]
    return common if all(frame == common for frame in per_frame) else per_frame


def progress(iterable: Iterable[Any], *, quiet: bool, total: int | None = None, desc: str = "") -> Iterator[Any]:
    """tqdm progress bar on stderr unless ``quiet``, stderr is not a terminal
    (:func:`awr_denoise._progress.bars_shown`) or only one item."""
    if not bars_shown(quiet) or (total is not None and total <= 1):
        yield from iterable
        return
    yield from tqdm(iterable, total=total, desc=desc, file=sys.stderr, leave=False)


def print_json(data: Any) -> None:
    """Machine-readable output on stdout (strict JSON: infinite values become strings)."""
    print(json.dumps(_finite(data), indent=2, sort_keys=True, default=_jsonable, allow_nan=False))


def _finite(value: Any) -> Any:
    if isinstance(value, (np.ndarray, np.generic)):  # a header's vector or matrix may hold NaN too
        value = value.tolist()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def status(message: str, *, quiet: bool) -> None:
    """A progress note on stderr (stdout is kept for results), printed above any progress bar."""
    if not quiet:
        try:
            tqdm.write(shown(message), file=sys.stderr)  # a name's escape sequences are shown, not obeyed
        except OSError:  # nobody reads stderr any more (a closed pipe): the work stands, its note is lost
            pass


def available_memory() -> int | None:
    """Bytes of memory the system can still give (``MemAvailable``), or None where it does not say."""
    try:
        with open("/proc/meminfo", encoding="ascii") as info:
            for line in info:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


RENDER_BYTES_PER_PIXEL = 410.0
"""The least memory a render of the bundled tracer takes a pixel at its peak on one thread (the statistics, the
tracer's batches, the reconstruction): the maximum resident size of a 1-spp uniform render 1276 MB higher at
2048x2048 than at 1024x1024 with ``--threads 1``, twice (``/usr/bin/time -f %M awr render --scene default --width N
--height N --spp 1 --uniform -o r.exr --threads 1``); ``awr render`` and ``awr bench --size`` check it."""


def check_memory(option: str, needed: float, what: str) -> None:
    """Refuse, naming ``option``, work that needs more memory than is available: the kernel's
    out-of-memory killer ends the process without a word (exit 137) otherwise."""
    free = available_memory()
    if free is not None and needed > free:
        raise UsageError(f"{option}: {what} needs about {needed / 2**30:.1f} GiB of memory, and "
                         f"{free / 2**30:.1f} GiB are available")
