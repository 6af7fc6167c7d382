"""``awr merge``: fold new batches of samples into the running dump (tell), exactly."""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import warnings
from pathlib import Path

import numpy as np

from awr_denoise import Sampler, SampleBuffer, SampleRequest
from awr_denoise.buffers import NONFINITE_POLICIES
from awr_denoise.errors import InputFileError, InputFileWarning, StaleRequestError
from awr_denoise.io import (
    provenance,
    read_independent_renders,
    read_request,
    read_sample_dump,
    request_attributes,
    write_sample_buffer,
)
from awr_denoise.io.atomic import same_file
from awr_denoise.io.deep import check_answers
from awr_denoise.io.dump import COUNT_CHANNEL, SEMANTICS_STATISTICS, SampleDump, header_count
from awr_denoise.io.exr import ExrPart, brief, check_same_windows, read_exr, read_windows, recorded_windows
from awr_denoise.io.request_map import MAX_ROUND

from .common import ANSWERS, EXIT_OK, UsageError, add_plane_options, answer_keys, plane_kwargs, run_settings, status
from .paths import PathPlan, check_plane_windows, plane_options
from .sampler_settings import CARRIED, carried_settings
from .values import MAX_SEED, MAX_SPP, nonempty

__all__ = ["register", "run"]

_SETTINGS = ("awr:strategy", "awr:initial_spp") + tuple(key for _, key, _, _ in CARRIED)
"""The run's settings, which plan continues: its strategy, first round and the settings its sampler ranked with."""
_KEPT = ("seed", "round", "scene") + tuple(key.removeprefix("awr:") for key in _SETTINGS)
"""Provenance carried from the running dump."""


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``merge`` sub-parser to ``sub``."""
    p = sub.add_parser("merge", help="merge batch dumps into the running dump (tell)",
                       description="Merge sample dumps with Chan's exact parallel update of count, mean and "
                                   "variance, and write the result in the awr dump layout. The first input is "
                                   "the running dump (or the first batch).")
    p.add_argument("inputs", nargs="+", metavar="DUMP.exr", help="running dump, then new batches")
    p.add_argument("-o", "--output", type=nonempty, required=True, metavar="MERGED.exr",
                   help="merged dump (a new file: inputs are never replaced)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--request", metavar="REQUEST.exr",
                   help="the request the last batch answers: checks its counts and records issued samples")
    p.add_argument("--independent", action="store_true",
                   help="the inputs are whole renders of the same frame with different seeds and no variance "
                        "(Blender Cycles): merge them with the variance estimated from the spread of their means")
    p.add_argument("--allow-duplicates", action="store_true",
                   help="merge inputs that are the same file or hold the same samples (they are then counted "
                        "twice; refused by default)")
    p.add_argument("-q", "--quiet", action="store_true")
    add_plane_options(p)
    p.set_defaults(run=run)


def _check_match(path: str, buffer: SampleBuffer, first: SampleBuffer, first_path: str) -> None:
    """Refuse a batch whose size or channels differ from the first input's, naming both files."""
    if buffer.shape != first.shape:
        h, w = buffer.shape
        raise InputFileError(f"{path}: size {w}x{h} does not match {first.shape[1]}x{first.shape[0]} of {first_path}")
    if buffer.channels != first.channels:
        raise InputFileError(f"{path}: channels {','.join(buffer.channels)} do not match "
                             f"{','.join(first.channels)} of {first_path}")


def _tell(merged: SampleBuffer, issued: np.ndarray, request_path: str, batch: SampleDump,
          batch_path: str) -> tuple[SampleBuffer, np.ndarray, int, str | None]:
    """Tell the last batch as the answer to its request (the library's :meth:`Sampler.tell`).

    Returns the merged statistics, the sample indices issued, the request's round and a note on
    requested samples the batch lacks.
    """
    request = read_request(request_path)
    if request.shape != batch.buffer.shape:
        h, w = request.shape
        raise InputFileError(f"{request_path}: size {w}x{h} does not match {batch.buffer.shape[1]}x"
                             f"{batch.buffer.shape[0]} of {batch_path}")
    if batch.index_bounds is not None:  # a deep batch names its samples: they must be the ones issued
        check_answers(batch_path, batch.index_bounds, request)
    _check_answered(batch_path, batch.attributes, request_path, request)
    sampler = Sampler.from_buffer(merged, issued=issued, round=request.round)
    try:
        sampler.resume(request)
    except StaleRequestError as exc:  # most often the inputs in another order: said how they go
        raise InputFileError(f"{request_path}: {exc}; give the running dump it was planned from first (none for round "
                             "0) and the one batch that answers it last (a batch's tiles merged without --request "
                             "first)") from None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            sampler.tell(request, batch.buffer)
        except ValueError as exc:
            raise InputFileError(f"{batch_path}: sampleCount: {exc}") from None
    note = "; ".join(str(w.message) for w in caught) or None
    return sampler.buffer, sampler.issued, request.round, note


def _answers(path: str, attributes: dict) -> dict[str, int] | None:
    """The round and total of the request a batch names (``awr:request_*``, or its copied header)."""
    found = {field: header_count(path, attributes, key, 0, 2**63 - 1)
             for key, field in answer_keys(attributes).items()}
    return found if set(found) == {"round", "total"} else None


def _check_answered(batch_path: str, attributes: dict, request_path: str, request: SampleRequest) -> None:
    """Refuse a batch whose header names another request than the one it is told with.

    A flat batch holds no sample indices, so a stale batch (the last round's, told again with the
    next request) would merge its samples twice; a renderer that copies the request's round and
    total into ``awr:request_round`` and ``awr:request_total`` lets this be caught.
    """
    for key, field in answer_keys(attributes).items():
        value = header_count(batch_path, attributes, key, 0, 2**63 - 1)
        if value != getattr(request, field):
            raise InputFileError(f"{batch_path}: {key}: it answers a request of {field} {value}, not "
                                 f"{request_path} ({field} {getattr(request, field)}): a batch of another round?")


def _check_batch_seed(batch_path: str, attributes: dict, request_path: str, asked: dict | None) -> None:
    """Refuse a told batch whose header names another ``awr:seed`` than its request's: its samples are another
    loop's sequence (a renderer that took another loop's seed, or copied another loop's request header), and
    merged as this loop's round they counted twice beside that loop's own (an attack pass). A batch that names
    no seed is taken as its request's."""
    if asked is None or "awr:seed" not in attributes or "awr:seed" not in asked:
        return
    wanted = header_count(request_path, asked, "awr:seed", 0, MAX_SEED)
    found = header_count(batch_path, attributes, "awr:seed", 0, MAX_SEED)
    if found != wanted:
        raise InputFileError(f"{batch_path}: awr:seed: its samples are of the sequence of seed {found}, not of "
                             f"{request_path}'s seed {wanted}: a batch of another loop?")


def _input_kwargs(args: argparse.Namespace) -> list[dict]:
    """Each input's reading options: ``--variance-kind`` describes the inputs whose header does not
    say what their variance holds (a renderer's batch beside the running dump, which says
    ``sample``), and ``--spp`` the inputs without their own sample counts (a Mitsuba batch beside
    the running dump, which counts its samples per pixel); with every input saying, either reaches
    them all, and an input it contradicts is refused."""
    kwargs = plane_kwargs(args)
    per_input = [dict(kwargs) for _ in args.inputs]
    given = [(option, says) for option, says in (("variance_kind", _says_variance_kind), ("spp", _counts_its_samples))
             if kwargs.get(option) is not None]
    parts = [read_exr(path, header_only=True) for path in args.inputs] if given else []
    for option, says in given:
        said = [says(file_parts) for file_parts in parts]
        if not all(said):
            for options, own in zip(per_input, said):
                if own:
                    options[option] = None
    return per_input


def _says_variance_kind(parts: list[ExrPart]) -> bool:
    """A header saying what the file's variance holds (an awr dump's)."""
    return any("awr:variance_kind" in part.header for part in parts)


def _counts_its_samples(parts: list[ExrPart]) -> bool:
    """An awr dump's per-pixel count channel, or a deep dump's samples."""
    return any(part.deep or any(getattr(c, "name", None) == COUNT_CHANNEL for c in part.header.get("channels", ()))
               for part in parts)


RUNNING = "awr:running"
"""1 on a loop's running dump (``merge --request``'s output, ``awr render``'s, a plain merge of running
dumps), each pixel's samples its seed's sequence from index 0 on; 0 on a plain merge of anything
else (batches start at ``first_index``). Files without it (older versions) are judged by their round."""


SEEDS = "awr:seeds"
"""On a merge that holds loops' samples and is no running dump (loops of several seeds merged plainly, or one loop's
dump beside samples of no loop): the seeds whose sequences from index 0 it holds, as text (``0 1``). The duplicate
checks read them, so that a newer dump of any of those loops merged with it later is refused (both hold that
loop's first samples)."""
MAX_SEEDS = 4096
"""The most seeds :data:`SEEDS` records (more loops than any farm runs; the header stays small)."""


def _running(attributes: dict) -> bool:
    """Whether a file is a running dump: marked so, or, unmarked, statistics naming a seed and a round."""
    if attributes.get("awr:semantics") != SEMANTICS_STATISTICS or "awr:seed" not in attributes:
        return False
    marked = attributes.get(RUNNING)
    return str(marked).strip() == "1" if marked is not None else "awr:round" in attributes


@dataclasses.dataclass(frozen=True)
class _Seen:
    """What the duplicate checks keep of an input once it is merged: not its statistics."""

    path: str
    digest: bytes | None  # of its count, mean and variance, when it holds samples
    running: tuple[frozenset[int], np.ndarray] | None  # the seeds whose first samples it holds, and where
    counts: bytes | None = None  # the digest of its counts alone
    signature: np.ndarray | None = None  # its means' signed sums (_signatures)
    noise: float = 0.0  # the standard error of each signed sum, from its known variances (_noise)
    signature16: np.ndarray | None = None  # the same of its means rounded to half floats (_signatures)


_SIGNED_SUMS = 8  # one byte of each position's hash (_signatures)
_ROUNDING = 1e-5
"""Signed sums of two inputs' means within this share of each other, every one, with the same counts: the same
samples up to rounding (the renderer's, or a conversion's). Two renders of other seeds differ by their noise over
the means' own size, orders of magnitude more."""
_NOISE_SHARE = 0.05
"""Signed sums of two inputs' means within this share of their own noise (:func:`_noise`), every one, with the same
counts: the same samples up to a coarser rounding, a copy in half floats (2**-11 of each mean; pbrt's default
output beside its float one). Two renders of other seeds differ by about their noise: all eight sums within 0.05 of
it by chance has a probability of about 1e-11 (a standard normal within 0.05, eight times)."""


_HALF_MAX = float(np.finfo(np.float16).max)
_SIGN_CHUNK = 1 << 18  # entries a block: 16 MB of signs (a 4K frame's hashes at once took 200 MB)


def _signatures(mean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:data:`_SIGNED_SUMS` sums of the means, each with signs drawn from the entries' positions, and the same sums of
    the means rounded to half floats (clipped to the largest half, so never inf).

    Unlike a digest, the first are close for means equal up to rounding (two files of one Mitsuba render with the same
    seed, a copy converted). The second are the same to float rounding for a render and its copy in half floats,
    whatever the noise: the halves' rounding (2**-11 of each mean) exceeds :data:`_NOISE_SHARE` of the noise where
    that is small, at thousands of samples per pixel or where many pixels have none (a constant sky), and a half-float
    copy of a 65536-spp render was merged as twice the samples (an attack pass). Two renders of other seeds differ by
    their noise in both, unless it is below half a half's step at every pixel, where they are one image to 16 bits.
    One hash of each position gives every sum its signs (its bits 40 to 47), block by block.
    """
    flat = np.ascontiguousarray(mean, np.float64).ravel()
    sums = np.zeros((2, _SIGNED_SUMS))
    for start in range(0, flat.size, _SIGN_CHUNK):
        block = flat[start:start + _SIGN_CHUNK]
        both = np.stack([block, np.clip(block, -_HALF_MAX, _HALF_MAX).astype(np.float16)])
        hashes = np.arange(start, start + block.size, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)
        bits = np.unpackbits((hashes >> np.uint64(40)).astype(np.uint8)[:, None], axis=1)  # (entries, 8)
        sums += both @ (1.0 - 2.0 * bits)
    return sums[0], sums[1]


def _noise(buffer: SampleBuffer) -> float:
    """The standard error of each of :func:`_signatures`' first sums (their signs square to 1): the root of the summed
    variances of the means, where they are known (unknown variances count 0, which only makes the test stricter)."""
    return float(np.sqrt(np.sum(buffer.variance.sum(axis=-1) / np.maximum(buffer.count, 1))))  # (H, W) temporaries


def _of_the_run(path: str, attributes: dict, seeds: frozenset[int]) -> bool:
    """Whether a batch may be of the run whose seeds are ``seeds``: it names none (a renderer's batch), or one of
    them (a batch that copied its request's header)."""
    if "awr:seed" not in attributes:
        return True
    return header_count(path, attributes, "awr:seed", 0, MAX_SEED) in seeds


def _seeds(path: str, attributes: dict, told: bool) -> frozenset[int]:
    """The seeds whose sequences from index 0 an input holds: its :data:`SEEDS`, else a running dump's
    ``awr:seed``; none for a told batch (it starts at its request's ``first_index``) or any other file."""
    if told:
        return frozenset()
    if SEEDS in attributes:
        raw = attributes[SEEDS]
        words = str(raw).split()
        if not 1 <= len(words) <= MAX_SEEDS:
            raise InputFileError(f"{path}: {SEEDS}: {brief(raw)} is not a list of 1 to {MAX_SEEDS} seeds")
        return frozenset(header_count(path, {SEEDS: word}, SEEDS, 0, MAX_SEED) for word in words)
    if _running(attributes):
        return frozenset({header_count(path, attributes, "awr:seed", 0, MAX_SEED)})
    return frozenset()


def _seen(path: str, dump: SampleDump, seeds: frozenset[int]) -> _Seen:
    buffer = dump.buffer
    digest = counts = signature = signature16 = None
    noise = 0.0
    if buffer.total_samples:
        h = hashlib.sha256()
        for a in (buffer.count, buffer.mean, buffer.variance):
            h.update(repr((a.dtype.str, a.shape)).encode())
            h.update(np.ascontiguousarray(a).data)
        digest = h.digest()
        counts = hashlib.sha256(np.ascontiguousarray(buffer.count).data).digest()
        signature, signature16 = _signatures(buffer.mean)
        noise = _noise(buffer)
    return _Seen(path, digest, (seeds, buffer.count > 0) if seeds else None, counts, signature, noise, signature16)


def _refuse_copies(earlier: list[_Seen], new: _Seen) -> None:
    """Refuse an input that holds the same samples as an earlier one (a copy, or two running dumps of
    one seed with samples at the same pixels): merged, they would count twice. A merge recording :data:`SEEDS` is
    taken to hold each of those seeds' first samples wherever it has samples: one of them merged again
    is refused even where the pixels it shares with the merge were another seed's (a refusal, never a count twice)."""
    for old in earlier:
        if new.digest is not None and new.digest == old.digest:
            why = "hold the same samples (a copy?)"
        elif new.counts is not None and new.counts == old.counts and np.any(new.signature != 0) and (np.all(
                np.abs(new.signature - old.signature)
                <= np.maximum(_ROUNDING * np.maximum(np.abs(new.signature), np.abs(old.signature)),
                              _NOISE_SHARE * np.hypot(new.noise, old.noise))) or np.all(
                np.abs(new.signature16 - old.signature16)
                <= _ROUNDING * np.maximum(np.abs(new.signature16), np.abs(old.signature16)))):  # (all black: none)
            why = ("hold the same samples up to rounding (their means differ by far less than their noise: one "
                   "render written twice, in half floats once, or two renders of one seed: Mitsuba's sampler seed "
                   "is 0 unless set)")
        elif new.running and old.running and (common := new.running[0] & old.running[0]) and (
                shared := int(np.count_nonzero(new.running[1] & old.running[1]))):
            if len(new.running[0]) == len(old.running[0]) == 1:
                why = (f"are running dumps of one sample sequence (awr:seed {min(common)}): at {shared} pixel(s) "
                       "both hold its first samples, the same samples (loops on two machines need two seeds)")
            else:  # a merge of several loops, or of a loop and other samples, on either side
                why = (f"both hold the first samples of the sample sequences of awr:seed "
                       f"{', '.join(str(seed) for seed in sorted(common))} at {shared} pixel(s), the same samples")
        else:
            continue
        raise UsageError(f"merge: {new.path} and {old.path} {why}; merging would count their samples twice "
                         "(pass --allow-duplicates to merge them anyway)")


def _one_colour_space(spaces: list[tuple[str, tuple[float, ...] | None]]) -> dict[str, tuple[float, ...]]:
    """The header of the inputs' one RGB (``chromaticities``: none for sRGB, the format's default), or a refusal
    naming two inputs of different ones: their means and variances would be added across colour spaces. pbrt-v4
    writes the attribute for any output colour space but sRGB; the merged dump carries it, as ``denoise``'s image."""
    for path, space in spaces[1:]:
        if space != spaces[0][1]:
            def said(value: tuple[float, ...] | None) -> str:
                return "none (sRGB)" if value is None else " ".join(f"{v:.4g}" for v in value)

            raise UsageError(f"merge: {path} and {spaces[0][0]} are in other colour spaces (chromaticities "
                             f"{said(space)} against {said(spaces[0][1])}): their samples cannot be merged")
    return {} if not spaces or spaces[0][1] is None else {"chromaticities": spaces[0][1]}


def _refuse_duplicates(paths: list[str]) -> None:
    """Refuse two inputs that are one file (merged, its samples would count twice)."""
    for j in range(1, len(paths)):
        for i in range(j):
            if same_file(paths[i], paths[j]):
                raise UsageError(f"merge: {paths[j]} and {paths[i]} are the same file; merging would count their "
                                 "samples twice (pass --allow-duplicates to merge them anyway)")


def _replaced(asked: dict | None) -> set[str]:
    """The running dump's run settings that a told request's own replace in the output: those it records, and with
    ``awr:round_growth`` (a plan that records all its sampler's settings; none left is automatic) all of
    :data:`CARRIED`'s."""
    if asked is None:
        return set()
    return {key for key in _SETTINGS if key in asked} | (
        {key for _, key, _, _ in CARRIED} if "awr:round_growth" in asked else set())


def run(args: argparse.Namespace) -> int:
    """Run ``awr merge``; returns the exit status (errors are raised and reported by ``main``)."""
    plan = PathPlan(overwrite=args.overwrite)
    for path in args.inputs:
        plan.read(path, "DUMP.exr")
    plan.read(args.request, "--request")
    for spec, option in plane_options(args):
        plan.read_plane(spec, option)
    plan.write(args.output, "-o/--output")
    plan.check()
    # Pixels line up only when every file places them alike (crops keep their windows).
    check_plane_windows(args.inputs[0], plane_options(args))
    windows = read_windows(args.inputs[0])
    for path in [*args.inputs[1:], *([args.request] if args.request else [])]:
        check_same_windows(path, read_windows(path), args.inputs[0], windows)
    if args.independent:
        if args.request:  # a setting that would do nothing is refused, not ignored
            raise UsageError("--request: not read with --independent (whole renders answer no request; merge "
                             "their result into a running dump with --request after)")
        given = [option for spec, option in plane_options(args)[3:] if spec is not None]
        if given:
            raise UsageError(f"{given[0]}: features are not read with --independent (each render's would need "
                             "merging as a render of its own)")
        kwargs = plane_kwargs(args)
        # Independent renders' variance is their spread; a named plane would be ignored.
        for key, option in (("variance", "--variance"), ("variance_kind", "--variance-kind")):
            if kwargs.get(key) is not None:
                raise UsageError(f"{option}: not read with --independent (the variance is the renders' spread "
                                 "about their mean)")
        if args.nonfinite != NONFINITE_POLICIES[0]:  # a render's NaN is refused: its mean has no samples to drop
            raise UsageError(f"--nonfinite: {args.nonfinite} is not read with --independent (a render's mean holds "
                             "no samples to drop or zero)")
        if args.allow_duplicates:  # identical renders are refused by what they are, not as copies
            raise UsageError("--allow-duplicates: not read with --independent (renders with the same pixels are "
                             "refused: their spread is no variance)")
        if args.preset == "deep":  # the library's refusal named its parameter, ``preset``
            raise UsageError("--preset: deep is not read with --independent (whole renders are flat images)")
        if args.spp is not None and args.spp * len(args.inputs) > MAX_SPP:
            raise UsageError(f"--spp: {args.spp} per render, {len(args.inputs)} renders, exceed {MAX_SPP} samples "
                             "per pixel (2**24, the counts' float32 limit)")
        if len(args.inputs) < 2:  # the library's refusal named its parameter, ``paths``
            raise UsageError(f"--independent: {len(args.inputs)} render given; the spread of their means needs at "
                             "least 2")
        if not args.allow_duplicates:
            _refuse_duplicates(args.inputs)
        with recorded_windows() as reads:
            dump = read_independent_renders(args.inputs, **{k: kwargs[k] for k in ("preset", "color", "count", "spp",
                                                                                     "layer", "view")})
        inputs = {Path(path) for path in args.inputs}  # the renders' colour spaces, not those of other files read
        space = _one_colour_space([(path, found) for path, _, found in reads if Path(path) in inputs])
        plan.check_unchanged()  # after the last read: every render and its windows of one version
        write_sample_buffer(args.output, dump.buffer, header={**windows, **space}, overwrite=args.overwrite)
        h, w = dump.buffer.shape
        status(f"{args.output}: {len(args.inputs)} independent renders, {dump.buffer.total_samples} samples "
               f"({dump.buffer.total_samples / (h * w):.4g} spp)", quiet=args.quiet)
        return EXIT_OK
    if len(args.inputs) == 1 and not args.request:
        raise UsageError("merge: give the running dump and at least one batch (or --request for a first batch)")
    if not args.allow_duplicates:
        _refuse_duplicates(args.inputs)
    # One input in memory at a time beside the merged statistics: read, checked, merged, let go.
    # Plain batches merge with Chan's update; a batch answering --request (the last) is told to a sampler.
    seen: list[_Seen] = []
    held: set[int] = set()  # the seeds whose first samples the inputs hold
    rounds: list[int] = []
    answers: list[dict | None] = []
    next_round, run_seeds = None, frozenset()  # the running dump's (the first input's) awr:round and seeds
    all_running = True
    merged = issued = told = None
    # The request's run settings, which replace the running dump's in the output: those are neither checked nor
    # carried (plan, which wrote the request, did not read them either).
    asked = None if not args.request else {k: v for k, v in request_attributes(args.request).items()
                                           if v is not None}
    replaced = _replaced(asked)
    spaces: list[tuple[str, tuple[float, ...] | None]] = []
    for index, (path, kwargs) in enumerate(zip(args.inputs, _input_kwargs(args))):
        with recorded_windows() as reads:
            dump = read_sample_dump(path, **kwargs)
        spaces.append((path, reads[0][2] if reads else None))
        _one_colour_space(spaces)  # before it is merged
        if RUNNING in dump.attributes and str(dump.attributes[RUNNING]).strip() not in ("0", "1"):
            # Read as "not running" without a word, it dropped the loop's seed from the merge (a red-team pass).
            raise InputFileError(f"{path}: {RUNNING}: {brief(dump.attributes[RUNNING])} is not 0 or 1")
        is_told = bool(args.request) and index == len(args.inputs) - 1
        if is_told:
            _check_batch_seed(path, dump.attributes, args.request, asked)
        seeds = _seeds(path, dump.attributes, is_told)
        if index == 0:
            first, attrs = dump.buffer, {k: v for k, v in dump.attributes.items()
                                         if k.removeprefix("awr:") in _KEPT and k not in replaced}
            run_strategy, _ = run_settings(path, attrs)  # carried into the output for plan: checked as plan does
            carried_settings(path, attrs, run_strategy, dump.buffer.shape)
            if asked is not None:  # before any batch is read
                strategy, _ = run_settings(args.request, asked)
                carried_settings(args.request, asked, strategy or run_strategy, dump.buffer.shape)
            loop_settings, loop_path, differ = None, None, {}
        else:
            _check_match(path, dump.buffer, first, args.inputs[0])
        if seeds:
            # Loops' dumps (and merges of them) give the run's settings wherever they stand among the inputs,
            # carried only where they agree, a setting one leaves out (no cap, the automatic depth, or dropped by
            # an earlier merge) being one too; else the output's would follow the inputs' order. (The settings a
            # told request replaces are its own.)
            kept = [key for key in _SETTINGS if key not in replaced]
            settings = {key: dump.attributes[key] for key in kept if key in dump.attributes}
            if index:  # every loop's checked as the first input's are, wherever it stands
                carried_settings(path, settings, run_settings(path, settings)[0], dump.buffer.shape)
            if loop_settings is None:
                loop_settings, loop_path = settings, path
            else:
                for key in kept:
                    if str(settings.get(key)) != str(loop_settings.get(key)):
                        differ.setdefault(key, path)
        held |= seeds
        all_running = all_running and (is_told or _running(dump.attributes))  # a told batch: its request's
        answers.append(_answers(path, dump.attributes))
        if index == 0 and _running(dump.attributes):
            next_round, run_seeds = header_count(path, dump.attributes, "awr:round", 0, MAX_ROUND), seeds
        elif index and not is_told and answers[-1] is not None and next_round is not None \
                and answers[-1]["round"] < next_round and _of_the_run(path, dump.attributes, run_seeds):
            # A running dump has taken in every round before its own: a batch of one of them is most likely in it
            # already. Not refused: a batch names no loop, and another loop's may be meant.
            warnings.warn(f"{path}: answers request round {answers[-1]['round']}, and the running dump "
                          f"{args.inputs[0]} (next round {next_round}) has taken that round in: if this batch is in "
                          "it, its samples now count twice; merge a round's batch once, with --request",
                          InputFileWarning, stacklevel=2)
        if not args.allow_duplicates:
            _refuse_copies(seen, new := _seen(path, dump, seeds))
            seen.append(new)
        if "awr:round" in dump.attributes:
            rounds.append(header_count(path, dump.attributes, "awr:round", 0, MAX_ROUND))
        if is_told:
            told = dump
        elif merged is None:
            merged, issued = dump.buffer, np.array(dump.issued)
        else:
            merged, issued = merged.merge(dump.buffer), issued + dump.issued
        del dump
    if loop_settings is not None:
        for key in _SETTINGS:
            if key not in replaced:
                attrs.pop(key, None)
        attrs.update(loop_settings)
    for key, path in differ.items():
        first_value = attrs.pop(key, None)
        status(f"merge: {key} of {path} is not {loop_path}'s ("
               f"{'none' if first_value is None else brief(first_value)}): not carried, the next plan takes its "
               "option or default", quiet=args.quiet)
    if merged is None:  # the first batch of a run, told alone
        merged, issued = SampleBuffer.empty(first.shape, channels=first.channels), np.zeros(first.shape, np.int64)
    del first
    if told is not None:
        merged, issued, request_round, note = _tell(merged, issued, args.request, told, args.inputs[-1])
        rounds.append(request_round)
        if note:
            status(f"{args.inputs[-1]}: {note}", quiet=args.quiet)
        # The run's newest settings, which plan continues (uniform stays uniform); the dump's they replace were
        # left out of ``attrs`` above.
        attrs.update({key: asked[key] for key in _SETTINGS if key in asked})
        seed = asked.get("awr:seed")
        if seed is not None:
            seed = header_count(args.request, {"awr:seed": seed}, "awr:seed", 0, MAX_SEED)  # the request's, named so
            if "awr:seed" not in attrs:
                attrs["awr:seed"] = seed
            elif seed != (kept := header_count(args.inputs[0], attrs, "awr:seed", 0, MAX_SEED)):
                # Kept silently, the dump's seed would misname the batch's samples (another dump's request?).
                raise UsageError(f"merge: {args.request}: awr:seed {seed} does not match awr:seed {kept} of "
                                 f"{args.inputs[0]} (plan each request from the running dump)")
            if held:  # a merge of several loops goes on with this seed too: counted among those it holds
                held.add(seed)
    if rounds:  # without any round information (plain batches) plan starts at round 1
        if max(rounds) + 1 > MAX_ROUND:  # a dump that no tool would read again
            raise UsageError(f"merge: the next round would be {max(rounds) + 1}, beyond the last ({MAX_ROUND})")
        attrs["awr:round"] = max(rounds) + 1
    if len(held) > MAX_SEEDS:
        raise UsageError(f"merge: the inputs hold the samples of {len(held)} seeds, more than {SEEDS} records "
                         f"({MAX_SEEDS})")
    if "awr:seed" in attrs:
        header_count(args.inputs[0], attrs, "awr:seed", 0, MAX_SEED)
    # A loop's running dump (told, or running dumps of one seed merged): its samples are every pixel's sequence
    # from 0.
    running = all_running and len(held) <= 1  # (a told merge of other samples than one loop's is none)
    if told is None and len(held) == 1:  # one loop's, whichever input it was
        attrs["awr:seed"] = min(held)
    elif told is None and held:  # several loops' samples: no one seed's sequence
        attrs.pop("awr:seed", None)
        status(f"merge: the inputs hold the loops of seeds {', '.join(str(seed) for seed in sorted(held))}: "
               f"{SEEDS} names them and no awr:seed is carried (each loop goes on from its own dump)",
               quiet=args.quiet)
    if held and not running:  # a loop's samples beside others: a newer dump of that loop is refused beside it
        attrs[SEEDS] = " ".join(str(seed) for seed in sorted(held))
    attrs[RUNNING] = int(running)
    if told is None and answers and all(a is not None and a == answers[0] for a in answers):
        # Tiles of one batch, merged before they are told: still naming their request.
        attrs.update({key: answers[0][field] for key, field in ANSWERS.items()})
    header = {**provenance(**{k.removeprefix("awr:"): v for k, v in attrs.items()}), **windows,
              **_one_colour_space(spaces)}
    plan.check_unchanged()  # after the last read: every dump and its windows of one version
    write_sample_buffer(args.output, merged, header=header, issued=issued, overwrite=args.overwrite)
    h, w = merged.shape
    status(f"{args.output}: {merged.total_samples} samples ({merged.total_samples / (h * w):.4g} spp), "
           f"next round {attrs.get('awr:round', 1)}", quiet=args.quiet)
    return EXIT_OK
