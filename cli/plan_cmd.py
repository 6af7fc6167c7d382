"""``awr plan``: ask the sampler where the next samples go, as a request map for a renderer."""

from __future__ import annotations

import argparse

from awr_denoise.allocation import MAX_BUDGET
from awr_denoise.io import provenance, read_sample_dump, write_request
from awr_denoise.io.exr import read_header, read_windows
from awr_denoise.io.request_map import MAX_ROUND
from awr_denoise.noise_gain import DEFAULT_NOISE_MODEL
from awr_denoise.rare_paths import DEFAULT_RARE_PATHS, RARE_PATHS
from awr_denoise.sampling import (DEFAULT_AWR_INITIAL_SPP, DEFAULT_INITIAL_SPP, DEFAULT_ROUND_GROWTH, NOISE_MODELS, SAMPLERS,
                                  AdaptiveSampler)
from awr_denoise.wavelets import DEFAULT_WAVELET, max_levels

from .common import (EXIT_OK, UsageError, add_plane_options, answered_round, check_memory, dump_options_given,
                     dumped_round, dumped_seed, plane_kwargs, run_settings, status)
from .paths import PathPlan, check_plane_windows, plane_options
from .sampler_settings import CARRIED, carried_settings, described, sampler_settings
from .values import (MAX_LEVELS, MAX_ROUND_GROWTH, MAX_SEED, MAX_SPP, UNSET, image_size, nonempty, or_unset, real,
                     wavelet_name, whole)

__all__ = ["register", "run", "STRATEGIES"]

STRATEGIES = tuple(SAMPLERS)
"""The sampling strategies ``--strategy`` offers, by the library's names."""


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``plan`` sub-parser to ``sub``."""
    p = sub.add_parser("plan", help="write the next request map (ask)",
                       description="Decide how many new samples each pixel gets and write them as a request "
                                   "map (counts, first_index) for an external renderer. Without a dump, plan "
                                   "the uniform first round of an image of --size.")
    p.add_argument("input", nargs="?", metavar="DUMP.exr", help="running sample dump (omit for the first round)")
    p.add_argument("-o", "--output", type=nonempty, required=True, metavar="REQUEST.exr")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    budget = p.add_mutually_exclusive_group()
    budget.add_argument("--budget", type=whole(minimum=0, maximum=MAX_BUDGET), metavar="N",
                        help="total new samples of this round")
    budget.add_argument("--round-spp", type=real(above=0, maximum=MAX_SPP), metavar="S",
                        help="new samples of this round per pixel on average")
    p.add_argument("--round-growth", type=real(above=0, maximum=MAX_ROUND_GROWTH), metavar="G",
                   help="new samples of a round planned from a dump as a share of the samples taken so far "
                        f"(default: the dump's awr:round_growth, else {DEFAULT_ROUND_GROWTH}); recorded for the rest "
                        "of the run, where --budget or --round-spp sizes one round and wins over it there")
    p.add_argument("--size", type=image_size, metavar="WxH", help="image size of the first round (without a dump)")
    p.add_argument("--initial-spp", type=whole(minimum=1, maximum=MAX_SPP),
                   help=f"samples per pixel of the first round (default {DEFAULT_AWR_INITIAL_SPP} with the awr strategy, "
                        f"{DEFAULT_INITIAL_SPP} with the others); with a dump, the least any pixel is brought up to")
    p.add_argument("--strategy", choices=STRATEGIES,
                   help="awr wavelet priorities, uniform, or per-pixel variance (default: the dump's awr:strategy, "
                        "the strategy of the rounds before, else awr)")
    p.add_argument("--seed", type=whole(minimum=0, maximum=MAX_SEED), help="seed of the renderer's sequences and tie-breaking "
                                            "(default: the dump's awr:seed, which it must match, else 0)")
    p.add_argument("--round", type=whole(minimum=0, maximum=MAX_ROUND - 1),  # merge numbers the next round
                   help="round number (default: the dump's awr:round, else 1; the first round, without a dump, "
                        "is 0)")
    # The run's settings: the dump's (awr:*, which a request records and merge carries), else the defaults; an
    # option given holds from this round on (docs/cli.md, "A run keeps its settings").
    p.add_argument("--wavelet", type=wavelet_name,
                   help=f"wavelet of the priority analysis (default: the dump's awr:priority_wavelet, else "
                        f"{DEFAULT_WAVELET})")
    p.add_argument("--levels", type=or_unset(whole(minimum=1, maximum=MAX_LEVELS), "auto"), metavar="L|auto",
                   help="decomposition depth of the priority analysis, or auto, the depth the image allows (default: "
                        "the dump's awr:priority_levels, else auto)")
    p.add_argument("--spp-max", type=or_unset(whole(minimum=1, maximum=MAX_SPP), "none"), metavar="N|none",
                   help="most samples any pixel may have, or none (default: the dump's awr:spp_max, else none)")
    p.add_argument("--noise-model", choices=NOISE_MODELS,
                   help="awr only: model what reconstruction leaves of a pixel's noise by a wavelet shrinkage's exact "
                        "gain (shrinkage), the paper's levels, or the default reconstruction's measured gain "
                        "(reconstructs the dump; docs/sampling.md); default: the dump's awr:noise_model, else "
                        "shrinkage")
    p.add_argument("--rare-paths", choices=RARE_PATHS,
                   help="awr and variance: spread the samples of regions lit through rare paths (most samples 0, "
                        "or fireflies on a lit base) evenly, which keeps their image mean (even), only those whose "
                        "samples are mostly 0 (zeros), or rank their pixels like the rest (ranked; docs/sampling.md, "
                        "'Rare paths'); default: the dump's awr:rare_paths, else even")
    p.add_argument("-q", "--quiet", action="store_true")
    add_plane_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Run ``awr plan``; returns the exit status (errors are raised and reported by ``main``)."""
    plan = PathPlan(overwrite=args.overwrite)
    plan.read(args.input, "DUMP.exr")
    for spec, option in plane_options(args):
        plan.read_plane(spec, option)
    plan.write(args.output, "-o/--output")
    plan.check()
    check_plane_windows(args.input, plane_options(args))
    # A run keeps its strategy and first round's spp (the least a pixel is brought up to) through
    # files: merge carries them from each request into the dump (a uniform baseline stays uniform).
    dumped_header = {} if args.input is None else read_header(args.input)
    dumped, dumped_initial = (None, None) if args.input is None else run_settings(args.input, dumped_header)
    from_dump = args.strategy is None and dumped is not None
    if args.strategy is None:
        args.strategy = dumped or AdaptiveSampler.strategy
    cls = SAMPLERS[args.strategy]
    same_run = dumped is None or dumped == args.strategy
    # The run's sampler settings, each where its option is not given: those of the dump's strategy that this one
    # uses too (each means the same in every strategy that uses it; the first round's spp does not).
    # Only those it uses are read, so an option given replaces a dump's value that does not fit.
    used = {name for name, _, _, strategies in CARRIED if getattr(args, name) is None and args.strategy in strategies}
    carried = {} if args.input is None else carried_settings(args.input, dumped_header, dumped, names=used)
    named = {name: option for name, _, option, _ in CARRIED}  # what set each: an option, or the dump
    for name, key, _, _ in CARRIED:
        if name in carried:
            setattr(args, name, carried[name])
            named[name] = f"{args.input}: {key}"
    lifted = {name for name in ("spp_max", "levels") if getattr(args, name) == UNSET}  # --spp-max none, --levels auto
    for name in lifted:
        setattr(args, name, None)
    options: dict = {"spp_max": args.spp_max}
    initial_given = args.initial_spp is not None
    if not initial_given and dumped_initial is not None and same_run:  # another strategy: its own default
        args.initial_spp = dumped_initial
    if args.initial_spp is not None and args.spp_max is not None and args.initial_spp > args.spp_max:
        # Refused, not clamped, wherever either comes from: the run's first round would silently change.
        cap_given = named["spp_max"] == "--spp-max"
        if initial_given:
            cap = (f"--spp-max {args.spp_max}" if cap_given
                   else f"awr:spp_max {args.spp_max} of {args.input} (give --spp-max to change it)")
            raise UsageError(f"--initial-spp: {args.initial_spp} exceeds {cap}, the most any pixel may have")
        cap, give = (("--spp-max", "--initial-spp") if cap_given else ("its awr:spp_max", "--initial-spp or --spp-max"))
        raise UsageError(f"{args.input}: awr:initial_spp {args.initial_spp} exceeds {cap} {args.spp_max}, the most "
                         f"any pixel may have (give {give})")
    if args.initial_spp is not None:  # else the strategy's own default
        options["initial_spp"] = args.initial_spp
    if args.round_growth is not None:
        options["round_growth"] = args.round_growth
    if cls._ranks:  # the samplers that rank pixels (awr, variance)
        options["rare_paths"] = args.rare_paths or DEFAULT_RARE_PATHS
    elif args.rare_paths is not None:
        raise UsageError(f"--rare-paths: only the strategies that rank pixels (awr, variance) spread rare paths, not "
                         f"{args.strategy}" + (f" (the awr:strategy of {args.input})" if from_dump else ""))
    if cls is AdaptiveSampler:
        options.update(wavelet=args.wavelet or DEFAULT_WAVELET, levels=args.levels,
                       noise_model=args.noise_model or DEFAULT_NOISE_MODEL)
    else:  # a setting that would do nothing is refused, not ignored
        for option, value, what in (("--noise-model", args.noise_model, "models the reconstruction's noise"),
                                    ("--wavelet", args.wavelet, "analyses the image in wavelets"),
                                    ("--levels", "auto" if "levels" in lifted else args.levels,
                                     "analyses the image in wavelets")):
            if value is not None:
                raise UsageError(f"{option}: only --strategy awr {what}, not {args.strategy}"
                                 + (f" (the awr:strategy of {args.input}; give --strategy awr)" if from_dump else ""))
    windows: dict = {}
    if args.input is None:
        if args.size is None:
            raise UsageError("plan: give a running DUMP.exr, or --size WxH for the first round")
        _refuse_what_a_first_round_ignores(args)
        shape = args.size
        if args.levels is not None and args.levels > max_levels(shape):
            raise UsageError(f"--levels: {args.levels} is outside 1..{max_levels(shape)} for an image of "
                             f"{shape[1]}x{shape[0]}")
        # About 112 bytes a pixel at the peak (the sampler's statistics, the request, the file's planes:
        # 1.39 GB more at 4096x4096 than at 2048x2048 in a measurement of the maximum resident size).
        check_memory("--size", 112.0 * shape[0] * shape[1], f"a first round of {shape[1]}x{shape[0]}")
        seed = 0 if args.seed is None else args.seed
        sampler = cls(shape, seed=seed, **options)
        round_number = 0
        unrecorded = []  # the first round reads no file
        if args.round is not None and args.round != 0:
            raise UsageError("--round: the first round (without a dump) is round 0")
    else:
        if args.size is not None:
            raise UsageError("--size: only for the first round; the dump fixes the size")
        dump = read_sample_dump(args.input, **plane_kwargs(args))
        answered = answered_round(dump.attributes)
        if answered is not None:
            # A batch holds one round's samples, from its request's first_index on: planned from, it would hand
            # out indices the run has used and lose the run's seed.
            merge = "awr merge BATCH.exr" if answered == "0" else "awr merge DUMP.exr BATCH.exr"
            raise UsageError(f"{args.input}: a batch answering request round {answered}, not the running dump: plan "
                             f"from the dump `{merge} --request REQUEST.exr -o NEXT.exr` writes")
        windows = read_windows(args.input)  # the request covers the dump's pixels, where they are
        if args.levels is not None and args.levels > max_levels(dump.buffer.shape):
            image = f"the image of {args.input}" if named["levels"] == "--levels" else "its image"
            raise UsageError(f"{named['levels']}: {args.levels} is outside 1..{max_levels(dump.buffer.shape)} for "
                             f"{image}")
        seed = dumped_seed(args.input, dump.attributes)
        if args.seed is not None and "awr:seed" in dump.attributes and args.seed != seed:
            # A dump's samples continue one random sequence; merge would refuse the batch.
            raise UsageError(f"--seed: {args.seed} differs from awr:seed {seed} of {args.input} (a dump's samples "
                             "continue one sequence; plan without --seed)")
        seed = args.seed if args.seed is not None else seed
        round_number = args.round if args.round is not None else dumped_round(args.input, dump.attributes)
        unrecorded = [key for key, given in (("awr:round", args.round), ("awr:seed", args.seed))
                      if key not in dump.attributes and given is None]
        if round_number < 1:
            raise UsageError(f"--round: rounds after the first are numbered from 1, got {round_number}")
        sampler = cls.from_buffer(dump.buffer, seed=seed, round=round_number, issued=dump.issued,
                                  **options)
    budget = args.budget
    if args.round_spp is not None:
        h, w = sampler.shape
        budget = max(1, int(round(args.round_spp * h * w)))
    try:
        request = sampler.ask(budget)
        plan.check_unchanged()  # after the last read: the dump and its windows are of one version
        header = {**provenance(seed=seed, strategy=args.strategy, initial_spp=sampler.initial_spp),
                  **sampler_settings(sampler), **windows}  # the run's settings, which merge carries on
        write_request(args.output, request, header=header, overwrite=args.overwrite)
    except ValueError as exc:  # the library names its arguments; name the option that set them
        option = _option_behind(str(exc), args, named["spp_max"])
        if option is None:
            raise
        raise UsageError(f"{option}: {str(exc).split(': ', 1)[-1]}") from None
    h, w = request.shape
    kept = described(carried)  # the run's settings this plan took from the dump, where not the defaults
    status(f"{args.output}: round {request.round}, {request.total} samples "
           f"({request.total / (h * w):.3g} per pixel), seed {seed}" + (f"; {kept} (the run's, from {args.input})"
                                                                        if kept else ""), quiet=args.quiet)
    if unrecorded:  # a batch without the request it answers reads as a dump of its own run: said, not guessed
        status(f"{args.input} records no {' or '.join(unrecorded)}: planned as a run of its own, its samples the first "
               "of each pixel; a batch answering a request is merged into the running dump first (awr merge DUMP.exr "
               "BATCH.exr --request REQUEST.exr)", quiet=args.quiet)
    return EXIT_OK


def _refuse_what_a_first_round_ignores(args: argparse.Namespace) -> None:
    """The first round reads no dump and is uniform: the layout of a dump would do nothing in it, so it is refused,
    not ignored, and so is a second size of the round. (What shapes later rounds is recorded in its request.)"""
    given = dump_options_given(args)
    if given:
        raise UsageError(f"{given[0][0]}: describes a running DUMP.exr; the first round (--size) reads none")
    size = "--budget" if args.budget is not None else "--round-spp" if args.round_spp is not None else None
    if size is not None and args.initial_spp is not None:  # two sizes of one round: one would be dropped
        raise UsageError(f"--initial-spp: the first round's samples per pixel, which {size} sets too; give one")


def _option_behind(message: str, args: argparse.Namespace, spp_max: str) -> str | None:
    """The option given (or ``spp_max``, the dump's attribute that set it) that set what a sampler's refusal names
    (``spp_max``, the round's size)."""
    if "spp_max" in message and args.spp_max is not None:
        if spp_max == "--spp-max":
            return f"--spp-max {args.spp_max:g}"
        cap = f"awr:spp_max {args.spp_max:g} of {args.input}"  # the dump's: and the round's size, if given
        size = (f"--round-spp {args.round_spp:.10g}" if args.round_spp is not None
                else f"--budget {args.budget}" if args.budget is not None else None)
        return cap if size is None else f"{size} beside {cap}"
    if message.startswith(("budget:", "first_index + counts:")):
        if args.round_spp is not None:
            return f"--round-spp {args.round_spp:.10g}"
        if args.budget is not None:
            return f"--budget {args.budget}"
    if message.startswith("first_index + counts:"):  # the default round past what the input already holds
        return f"{args.input}: its samples and the next round's"
    return None
