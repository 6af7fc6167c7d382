"""The benchmark's command line, shared by ``awr bench`` and ``python -m awr_denoise.bench``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from .._checks import MAX_SPP, file_option, path_option, whole_option
from .._progress import bars_shown
from ..io.atomic import check_creatable
from .config import OVERHEAD_SIZES, BenchmarkConfig
from .rendering import tracer_module
from .runner import run_benchmark

__all__ = ["DESCRIPTION", "add_arguments", "config_from_args", "run_from_args", "main"]

_SIDES = (16, 2**14)  # smaller images leave the crops and the c_s sweep nothing to show

DESCRIPTION = "The speed/accuracy benchmark on the bundled path-traced scenes (``awr bench``)."
"""One-line description of ``python -m awr_denoise.bench``."""


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the benchmark's options to ``parser`` (shared by ``awr bench`` and ``python -m``).

    Parameters
    ----------
    parser
        The parser (or sub-parser) to extend.

    Returns
    -------
    argparse.ArgumentParser
        ``parser``.

    Examples
    --------
    >>> args = add_arguments(argparse.ArgumentParser()).parse_args(["--quick", "--spp", "8", "4"])
    >>> args.quick, args.spp, str(args.output_dir)
    (True, [8, 4], 'docs')
    """
    parser.add_argument("--quick", action="store_true", help="fewer sample counts, seeds and sizes (a few minutes)")
    parser.add_argument("--scenes", nargs="+", metavar="SCENE", default=None, help="bundled scenes (default: all)")
    parser.add_argument("--output-dir", type=path_option, default=Path("docs"),
                        help="where benchmarks.md and img/ go (default: docs)")
    parser.add_argument("--results", type=file_option, default=None,
                        help="JSON output (default: benchmarks/results/quality.json beside the output dir)")
    parser.add_argument("--reference-spp", type=whole_option(minimum=1, maximum=MAX_SPP), default=None,
                        help="re-render references below this spp with the tracer, replacing the cached ones "
                             "(data/references in a checkout, the user's cache folder in an install, or "
                             "$AWR_DENOISE_REFERENCE_DIR)")
    parser.add_argument("--spp", type=whole_option(minimum=1, maximum=MAX_SPP), nargs="+", default=None,
                        help="average spp to measure at")
    parser.add_argument("--size", type=whole_option(minimum=_SIDES[0], maximum=_SIDES[1]), nargs=2,
                        metavar=("WIDTH", "HEIGHT"), default=None,
                        help=f"override the scenes' resolution, {_SIDES[0]}-{_SIDES[1]} pixels a side (references "
                             "are then rendered on the fly)")
    parser.add_argument("--overhead-sizes", nargs="*", choices=tuple(OVERHEAD_SIZES), default=None, metavar="SIZE",
                        help=f"image sizes of the overhead measurement ({', '.join(OVERHEAD_SIZES)}; "
                             "the option alone skips it)")
    parser.add_argument("--no-oidn", action="store_true", help="skip Open Image Denoise even if installed")
    parser.add_argument("--no-mitsuba", action="store_true", help="skip the Mitsuba 3 scenes even if Mitsuba is installed")
    parser.add_argument("--mitsuba-scenes", nargs="+", metavar="SCENE", default=None,
                        help="Mitsuba 3 scenes (default: the four of awr_denoise.adapters.mitsuba_scenes.SCENE_NAMES; "
                             "ALL_SCENES adds the two lit through rare paths)")
    parser.add_argument("--mitsuba-references", type=path_option, default=None, metavar="DIR",
                        help="where Mitsuba 3's references are cached (default: data/cache/mitsuba in a checkout, "
                             "mitsuba in the user's cache folder in an install)")
    parser.add_argument("--no-plots", action="store_true", help="write no PNG figures")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def config_from_args(args: argparse.Namespace) -> BenchmarkConfig:
    """The :class:`BenchmarkConfig` that options parsed by :func:`add_arguments` ask for.

    ``--quick`` starts from :meth:`BenchmarkConfig.quick`, otherwise from the full run; the
    other options override fields of it.

    Examples
    --------
    >>> args = add_arguments(argparse.ArgumentParser()).parse_args(["--quick", "--spp", "8", "4", "8"])
    >>> config_from_args(args).spps
    (4, 8)
    """
    overrides: dict[str, Any] = {}
    if args.scenes:
        overrides["scenes"] = tuple(args.scenes)
    if args.reference_spp is not None:
        overrides["reference_spp"] = args.reference_spp
    if args.spp:
        overrides["spps"] = tuple(sorted(set(args.spp)))
    if args.size:
        overrides["width"], overrides["height"] = args.size
    if args.overhead_sizes is not None:
        overrides["overhead_sizes"] = tuple(args.overhead_sizes)
    if args.no_oidn:
        overrides["oidn"] = False
    if args.no_mitsuba:
        overrides["mitsuba"] = False
    if args.mitsuba_scenes:
        overrides["mitsuba_scenes"] = tuple(args.mitsuba_scenes)
    if args.mitsuba_references is not None:
        overrides["mitsuba_reference_dir"] = str(args.mitsuba_references)
    return BenchmarkConfig.quick(**overrides) if args.quick else replace(BenchmarkConfig(), **overrides)


_OPTION_NAMES = (("results_path / --results:", "--results:"), ("output_dir / --output-dir:", "--output-dir:"),
                 ("mitsuba_scenes:", "--mitsuba-scenes:"), ("scenes:", "--scenes:"))
"""The library's parameter names at the start of a refusal, and the options that set them."""


def _refuse_unread(args: argparse.Namespace, config: BenchmarkConfig) -> None:
    """Options the run would not read: refused, not ignored (a red-team pass found both accepted)."""
    if args.mitsuba_scenes and args.no_mitsuba:
        raise ValueError("--mitsuba-scenes: no Mitsuba scene runs with --no-mitsuba")
    if args.mitsuba_references is not None:
        if args.no_mitsuba:
            raise ValueError("--mitsuba-references: no Mitsuba reference is read with --no-mitsuba")
        if not args.mitsuba_references.is_dir():  # made when the first reference is: a file there failed the run
            check_creatable(args.mitsuba_references, option="--mitsuba-references")
    if args.reference_spp is not None and args.size:
        tracer = tracer_module()
        for name in config.scenes or tracer.list_scenes():
            scene = tracer.load_scene(name) if name in tracer.list_scenes() else None  # unknown: refused later
            if scene is not None and (scene.width, scene.height) != tuple(args.size):
                raise ValueError(f"--reference-spp: read at each scene's own size, and {name} is "
                                 f"{scene.width}x{scene.height}; at --size {args.size[0]} {args.size[1]} its reference "
                                 f"is rendered on the spot at {config.inline_reference_spp} spp")


def run_from_args(args: argparse.Namespace) -> int:
    """Run the benchmark with options parsed by :func:`add_arguments`; print the summary.

    Parameters
    ----------
    args
        The parsed options.

    Returns
    -------
    int
        0; 2 for a bad option (an unknown scene, an output that cannot be written), 1 for a
        missing extra: one line on stderr names the problem.

    Raises
    ------
    ValueError
        Inconsistent options (a usage error, for the caller's parser to report).
    """
    config = config_from_args(args)
    try:
        _refuse_unread(args, config)
        results = run_benchmark(config, output_dir=args.output_dir, results_path=args.results,
                                plots=not args.no_plots, progress=bars_shown(args.quiet),
                                mode_name="quick" if args.quick else "full")
    except ImportError as exc:  # one line in the form of every awr error (docs/cli.md)
        print(f"awr: error: {exc}", file=sys.stderr)
        return 1
    except (ValueError, FileExistsError, FileNotFoundError) as exc:  # the user's options: nothing was written
        message = str(exc)
        for name, option in _OPTION_NAMES:  # the library names its parameters; the command line its options
            if message.startswith(name):
                message = option + message[len(name):]
        print(f"awr: error: {message}", file=sys.stderr)
        return 2
    s = results["summary"]
    print(f"{'scene':<14} " + " ".join(f"{m:>16}" for m in s["scenes"][next(iter(s["scenes"]))]["relmse"]))
    for name, entry in s["scenes"].items():
        print(f"{name:<14} " + " ".join(f"{v:>16.5f}" for v in entry["relmse"].values()))
    print(f"relMSE at {s['headline_spp']} spp; OIDN: {results['meta']['oidn']}; "
          f"run time {results['meta']['run_seconds'] / 60:.1f} min")
    for flag in s["flags"]:
        print(f"FLAG: {flag}")
    for flag in s.get("flags_not_confirmed", []):
        print(f"flag not confirmed over seeds: {flag}")
    if args.output_dir is not None:
        print(f"wrote {args.output_dir / 'benchmarks.md'}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``python -m awr_denoise.bench [--quick] [--scenes ...] [--output-dir docs]``.

    Parameters
    ----------
    argv
        The arguments; ``None`` reads :data:`sys.argv`.

    Returns
    -------
    int
        The exit status (2 for a usage error, through :meth:`argparse.ArgumentParser.error`).
    """
    parser = add_arguments(argparse.ArgumentParser(prog="python -m awr_denoise.bench", description=DESCRIPTION))
    args = parser.parse_args(argv)
    try:
        return run_from_args(args)
    except ValueError as exc:
        parser.error(str(exc))
