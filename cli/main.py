"""The ``awr`` command: sample dumps in, denoised images and sample requests out.

Subcommands: ``info``, ``denoise``, ``plan`` (ask), ``merge`` (tell), ``diff``, ``render``,
``demo``, ``bench``. Exit status: 0 success, 1 runtime failure, 2 bad usage or bad input,
130 interrupted (Ctrl-C), 143 terminated (SIGTERM), 129 hung up (SIGHUP), 128 + n for the other
terminating signals (SIGUSR1...), 141 when the reader of stdout went away.
A user mistake prints one line, ``awr: error: <file>: <channel>: <what>``, never a traceback.

This module imports nothing heavy: :func:`main` installs the interrupt handling first and only
then imports the subcommands (and with them numpy, scipy and OpenEXR).
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import os
import select
import signal
import stat
import sys
from collections.abc import Sequence
from concurrent.futures import BrokenExecutor, CancelledError
from typing import Any

from awr_denoise import __version__, memory
from awr_denoise.errors import BackendError, InputFileError

from . import interrupts
from .errors import (
    EXIT_BROKEN_PIPE,
    EXIT_FAILURE,
    EXIT_HANGUP,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_TERMINATED,
    EXIT_USAGE,
    RuntimeFailure,
    UsageError,
    one_line,
    one_line_warnings,
)

__all__ = ["main", "run", "build_parser"]

_COMMANDS = ("info", "denoise", "plan", "merge", "diff", "render", "demo", "bench")


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors as exceptions, so ``main`` prints them as one line."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise UsageError(f"{message} (see '{self.prog} --help')")

    def parse_args(self, args: Any = None, namespace: Any = None) -> argparse.Namespace:  # type: ignore[override]
        # Left-over words are found by the top parser, after the command's: its help is the one to see
        # ('awr merge a.exr -o m.exr b.exr' pointed at 'awr --help').
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:
            command = getattr(namespace, "command", None)
            raise UsageError(f"unrecognized arguments: {' '.join(extras)} "
                             f"(see '{self.prog}{'' if command is None else ' ' + command} --help')")
        return namespace

    def _print_message(self, message: str, file: Any = None) -> None:
        # argparse passes over a failed write (--help > /dev/full exited 0 with nothing written):
        # written and flushed here, a failure is main's to report.
        if message:
            stream = file if file is not None else sys.stderr
            stream.write(message)
            stream.flush()


_GIVEN = "_awr_given_options"
"""The namespace attribute in which :class:`_StoreOnce` and :class:`_FlagRecorded` keep the options given so far
(read out after parsing into ``options_given``)."""


def _given(namespace: argparse.Namespace) -> set[str]:
    """The options given so far while ``namespace`` is parsed (kept in it under :data:`_GIVEN`)."""
    given = getattr(namespace, _GIVEN, None)
    if given is None:
        given = set()
        setattr(namespace, _GIVEN, given)
    return given


class _StoreOnce(argparse._StoreAction):
    """An option that takes a value, refused when given twice. argparse keeps the last one: a wrapper
    script that appended ``-o``, ``-r`` or ``--maxerror`` to a user's arguments got another output,
    reference or bound with exit 0 (a red-team pass), where two spellings of one input (SCENE and
    ``--scene``) were already refused."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        given = _given(namespace)
        if self.dest in given:
            raise UsageError(f"{'/'.join(self.option_strings)}: given twice (the second: {option_string} "
                             f"{' '.join(map(str, values)) if isinstance(values, list) else values}); give it once")
        given.add(self.dest)
        super().__call__(parser, namespace, values, option_string)


class _FlagRecorded(argparse._StoreConstAction):
    """A flag (``store_true``, ``store_false``, ``store_const``), recorded among the options given as
    :class:`_StoreOnce` records those that take a value: ``--adaptive``, at its default, was not seen as given."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        _given(namespace).add(self.dest)
        super().__call__(parser, namespace, values, option_string)


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
    for command in sub.choices.values():
        for action in command._actions:
            if type(action) is argparse._StoreAction and action.option_strings:
                action.__class__ = _StoreOnce
            elif type(action) in (argparse._StoreTrueAction, argparse._StoreFalseAction, argparse._StoreConstAction):
                action.__class__ = _FlagRecorded
    return parser


def _error(message: object, status: int) -> int:
    if interrupts.received() is not None:  # the error is the interrupt's doing: main says so
        return status
    print(f"awr: error: {one_line(message)}", file=sys.stderr)
    return status


def _stdout_is_broken() -> bool:
    """Whether stdout is a pipe whose reader has gone (POLLERR on its write end)."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLERR)
        return bool(poller.poll(0))
    except (AttributeError, OSError, ValueError):
        return False


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's final flush cannot fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (AttributeError, OSError, ValueError):
        pass


# The commands that run FFTs (the reconstruction, the samplers' noise gain): the thread-count
# variables ducc0 reads are checked before their work, not found wrong after a render.
_FFT_COMMANDS = ("denoise", "render", "demo", "bench")  # plan: checked where a plan runs one


def _check_kernels(command: str | None) -> None:
    """``AWR_DENOISE_KERNELS`` (and the FFTs' thread variables) checked before any file is read or
    written (exit 2 if it is wrong)."""
    if command in _FFT_COMMANDS:
        from awr_denoise.stationary import check_fft_environment  # numpy: after the interrupt handling

        try:
            check_fft_environment()
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    if not os.environ.get("AWR_DENOISE_KERNELS"):
        return  # the default kernels: nothing to check
    # Imported here, not at the top: it loads numpy, which must come after the interrupt handling.
    from awr_denoise import fused

    try:
        fused.backend()
    except ImportError as exc:  # the compiled kernels asked for, numba missing: the user's setting
        raise UsageError(str(exc)) from exc
    except ValueError as exc:  # AWR_DENOISE_KERNELS naming no backend, a NUMBA_ variable numba cannot read
        raise UsageError(str(exc)) from None


def _run_failed(exc: OSError) -> int:
    """The exit status of an ``OSError``: a reader gone from stdout is a quiet 141; anything else (a
    full disk, a lost network file system) one line and exit 1. Writers leave no partial file behind."""
    if isinstance(exc, BrokenPipeError):
        if exc.filename is None and _stdout_is_broken():
            _silence_stdout()
            return EXIT_BROKEN_PIPE
        return _error(f"{exc.filename}: {exc.strerror}" if exc.filename else exc.strerror or exc, EXIT_FAILURE)
    where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
    what = exc.strerror or (os.strerror(exc.errno) if exc.errno else None) or exc
    if exc.errno == errno.ENOSPC and not where:
        what = "no space left on device"
        if _stdout_is_full():  # a report printed to a full device named nothing (a red-team pass)
            where = "standard output: "
    return _error(f"{where}{what}", EXIT_FAILURE)


def _stdout_is_full() -> bool:
    """Whether stdout is where space ran out: Linux's /dev/full, or a file on a file system with no block left.
    (The failed write's buffer is gone by now: flushing it again cannot tell.)"""
    try:
        st = os.fstat(sys.stdout.fileno())
        if stat.S_ISCHR(st.st_mode):
            return (os.major(st.st_rdev), os.minor(st.st_rdev)) == (1, 7)
        return stat.S_ISREG(st.st_mode) and os.fstatvfs(sys.stdout.fileno()).f_bavail == 0
    except (AttributeError, OSError, ValueError):
        return False


def _run(argv: Sequence[str] | None) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
        # The options given, whatever their values (`--seed 0` is given too): what a command that takes none reads.
        args.options_given = frozenset(vars(args).pop(_GIVEN, None) or ())
        _check_kernels(getattr(args, "command", None))
        from awr_denoise._progress import bars_shown  # with the subcommands: tqdm checks TQDM_* when imported

        bars_shown(False)  # AWR_PROGRESS read before the work: a frame's bar is drawn only once it is done
        with one_line_warnings():
            status = int(args.run(args) or EXIT_OK)
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return status
    except SystemExit as exc:  # --help and --version
        return int(exc.code or 0) if isinstance(exc.code, int) else EXIT_OK
    except RuntimeFailure as exc:
        return _error(exc, EXIT_FAILURE)
    except (InputFileError, UsageError, FileExistsError, FileNotFoundError) as exc:
        return _error(exc, EXIT_USAGE)
    except (ValueError, TypeError) as exc:
        # Library argument validation (unknown wavelet, bad levels...): the user's input.
        return _error(exc, EXIT_USAGE)
    except OSError as exc:
        if type(exc).__name__ == "CommClosedError":  # distributed's, naming its connection pool's internals
            return _error("the connection to the Dask scheduler closed mid-run (the scheduler stopped or lost?)",
                          EXIT_FAILURE)
        return _run_failed(exc)
    except MemoryError as exc:
        return _error(f"out of memory{': ' + str(exc) if str(exc) else ''}", EXIT_FAILURE)
    except BrokenExecutor as exc:  # a process-pool worker killed (the OOM killer, a signal): not a bug of ours
        return _error(f"a worker process died (killed, or out of memory?): {one_line(exc)}", EXIT_FAILURE)
    except CancelledError as exc:  # a Dask scheduler stopped or lost mid-run cancels every future it held
        why = f": {one_line(exc)}" if str(exc).strip() else ""  # Dask's own is often empty
        return _error(f"the parallel work was cancelled from outside (a Dask scheduler stopped or lost?){why}",
                      EXIT_FAILURE)
    except BackendError as exc:  # an extra's native library cannot start (what to install) or failed (its words)
        return _error(exc, EXIT_FAILURE)
    except ImportError as exc:
        if "failed to map segment" in str(exc):  # the loader's words for a library that did not fit
            return _error(f"out of memory loading a library ({one_line(exc)})", EXIT_FAILURE)
        return _error(exc, EXIT_FAILURE)
    except Exception as exc:  # a bug, not a user mistake: say so, traceback on request
        if os.environ.get("AWR_TRACEBACK", "").strip().lower() in ("1", "true", "yes", "on"):
            raise
        return _error(f"internal error: {type(exc).__name__}: {one_line(exc)} "
                      "(set AWR_TRACEBACK=1 to see the traceback)", EXIT_FAILURE)


def _standard_streams() -> None:
    """Point a closed stdin, stdout or stderr at the null device (cron and daemon launchers close
    them): left closed, the next file opened would take its number and receive the messages, and
    a closed stream is not a reason to call an input corrupt."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
    for name in ("stdin", "stdout", "stderr"):
        if getattr(sys, name) is None:  # Python sets None for a stream closed at start-up
            setattr(sys, name, open(os.devnull, "r" if name == "stdin" else "w", encoding="utf-8"))  # noqa: SIM115
    for stream in (sys.stdout, sys.stderr):
        # A name the stream's encoding cannot show (PYTHONIOENCODING=ascii, a non-UTF-8 name) is
        # shown escaped: it failed the command on a valid file, "'ascii' codec can't encode".
        with contextlib.suppress(AttributeError, ValueError, OSError):
            stream.reconfigure(errors="backslashreplace")


class _DiagnosticStream:
    """``sys.stderr`` while a command runs: once it cannot be written (its reader has gone, a full
    device), what is left to say there is dropped and the work goes on. Progress bars and notes
    are not the command's result; a render failed after its work on a progress bar's write (exit
    1, nothing kept), and a refusal exited 1 instead of 2."""

    def __init__(self, stream: Any) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return int(self._stream.write(text))
        except OSError:
            self._reader_gone()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError:
            self._reader_gone()

    def _reader_gone(self) -> None:
        # The descriptor points at the null device from now on: OpenEXR's C messages and the
        # text still buffered in the stream (flushed again at exit) go nowhere, without an error.
        try:
            fd = self._stream.fileno()
        except (OSError, ValueError):  # not a file (captured by a test harness): drop it
            self._stream = open(os.devnull, "w", encoding="utf-8")  # noqa: SIM115
            return
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, fd)
        os.close(null)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


MIN_ADDRESS_SPACE = 192 * 2**20
"""Bytes of address space (``ulimit -v``) below which the command refuses to start: scipy's import spun for ever
in OpenBLAS' start-up, deaf to SIGTERM, at limits of 130-150 MB (one BLAS thread or not), and failed at once
around them; commands ran from about 230 MB."""


def _one_blas_thread_under_a_memory_limit() -> str | None:
    """Under an address-space limit (``ulimit -v``), OpenBLAS (loaded by scipy) retried its thread
    buffers' ``mmap`` for ever at import, deaf to SIGTERM; with one thread it allocates none. The
    command's own threads are its executor's, not BLAS's (its matrices are 3x3). Returns the refusal
    of a limit below :data:`MIN_ADDRESS_SPACE`, where even one thread's start-up can spin."""
    try:
        import resource
    except ImportError:  # not POSIX
        return None
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if soft < MIN_ADDRESS_SPACE:
        return (f"an address-space limit of {soft // 2**20} MiB (ulimit -v): awr needs at least "
                f"{MIN_ADDRESS_SPACE // 2**20} MiB to start")
    return None


def main(argv: Sequence[str] | None = None, *, ending: bool = False) -> int:
    """Run the ``awr`` command line and return its exit status.

    Parameters
    ----------
    argv
        Arguments without the program name; ``sys.argv[1:]`` by default.
    ending
        The process ends with the command (:func:`run`): the signal handlers are not put back, and a
        signal after the command's end changes neither its status nor its line (a second one ends the
        process at once).
    """
    too_little = _one_blas_thread_under_a_memory_limit()  # before numpy and scipy are imported
    if too_little is not None:
        print(f"awr: error: {too_little}", file=sys.stderr)
        return EXIT_FAILURE
    memory.keep_freed_memory()  # whole-image temporaries reused, not mapped afresh (awr_denoise/memory.py)
    _standard_streams()
    stderr = sys.stderr
    sys.stderr = _DiagnosticStream(stderr)  # type: ignore[assignment]
    try:
        return _main(argv, ending)
    finally:
        sys.stderr = stderr


def run() -> None:
    """The ``awr`` console script: :func:`main`, then the process ends with its status. A signal that
    lands once the command has ended (its outputs committed or removed) changes neither that status nor
    the command's line; a second one ends the process at once (:func:`interrupts.ending`)."""
    sys.exit(main(ending=True))


def _main(argv: Sequence[str] | None, ending: bool = False) -> int:
    """:func:`main` once the standard streams are set up."""
    previous = None
    status = None

    def outcome() -> tuple[int, str | None]:
        return _outcome(status)

    try:
        previous = interrupts.raising()
        status = _run(argv)
        if ending:  # inside the try: a first signal until the handlers are swapped is the command's
            interrupts.ending(previous, outcome)
    except (KeyboardInterrupt, interrupts.Terminated):
        if ending:  # the first signal has set the others ignored: nothing raises here
            interrupts.ending(previous, outcome)
    finally:
        if not ending:
            interrupts.restore(previous)
    if ending:
        return interrupts.say(outcome)
    status, line = outcome()
    if line is not None:
        print(line, file=sys.stderr)
    return status


def _outcome(status: int | None) -> tuple[int, str | None]:
    """The exit status and the line to print, from the command's status (None: it was interrupted).

    A signal counts even when the exception it raised was lost on the way (inside a C extension, a
    weakref callback); no output was committed after it (every commit asks first:
    awr_denoise._signals.COMMIT_CHECKS)."""
    signum = interrupts.received()
    if signum == signal.SIGTERM:
        return EXIT_TERMINATED, "awr: terminated"
    if signum is not None and signum == getattr(signal, "SIGHUP", None):
        return EXIT_HANGUP, "awr: hung up"
    if signum is not None and signum != signal.SIGINT:  # SIGUSR1, SIGXCPU...: the shell's 128 + n
        return 128 + int(signum), f"awr: terminated by {signal.Signals(signum).name}"
    if signum is not None or status is None:
        return EXIT_INTERRUPTED, "awr: interrupted"
    return status, None


if __name__ == "__main__":  # pragma: no cover
    run()
