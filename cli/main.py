"""The ``awr`` command: sample dumps in, denoised images and sample requests out.

Subcommands: ``info``, ``denoise``, ``plan`` (ask), ``merge`` (tell), ``diff``, ``render``,
``demo``, ``bench``. Exit status: 0 success, 1 runtime failure, 2 bad usage or bad input. A user
mistake prints one line, ``awr: error: <file>: <channel>: <what>``, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from awr_denoise import __version__
from awr_denoise.errors import InputFileError

from .common import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, RuntimeFailure, UsageError, one_line_warnings

__all__ = ["main", "build_parser"]

_COMMANDS = ("info", "denoise", "plan", "merge", "diff", "render", "demo", "bench")


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors as exceptions, so ``main`` prints them as one line."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise UsageError(f"{message} (see '{self.prog} --help')")


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser (one sub-parser per subcommand)."""
    parser = _Parser(prog="awr", description="Adaptive Wavelet Rendering: denoise Monte Carlo sample dumps "
                                             "and plan where a renderer's next samples go.")
    parser.add_argument("--version", action="version", version=f"awr {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in _COMMANDS:
        module = importlib.import_module(f"{__package__}.{name}_cmd")
        module.register(sub)
    return parser


def _one_line(message: object) -> str:
    return " ".join(str(message).split()) or "unknown error"


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``awr`` command line and return its exit status.

    Parameters
    ----------
    argv
        Arguments without the program name; ``sys.argv[1:]`` by default.
    """
    try:
        parser = build_parser()
        args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
        with one_line_warnings():
            return int(args.run(args) or EXIT_OK)
    except SystemExit as exc:  # --help and --version
        return int(exc.code or 0) if isinstance(exc.code, int) else EXIT_OK
    except KeyboardInterrupt:
        print("awr: interrupted", file=sys.stderr)
        return 130
    except RuntimeFailure as exc:
        print(f"awr: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FAILURE
    except (InputFileError, UsageError, FileExistsError, FileNotFoundError) as exc:
        print(f"awr: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except (ValueError, TypeError) as exc:
        # Library argument validation (unknown wavelet, bad levels...): the user's input.
        print(f"awr: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as exc:
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"awr: error: {where}{_one_line(exc.strerror or exc)}", file=sys.stderr)
        return EXIT_FAILURE
    except ImportError as exc:
        print(f"awr: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FAILURE
    except Exception as exc:  # a bug, not a user mistake: say so, traceback on request
        if os.environ.get("AWR_TRACEBACK"):
            raise
        print(f"awr: error: internal error: {type(exc).__name__}: {_one_line(exc)} "
              "(set AWR_TRACEBACK=1 to see the traceback)", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

