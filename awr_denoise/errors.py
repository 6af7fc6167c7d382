"""Exceptions raised by awr_denoise.

Bad arguments raise the built-in ``ValueError``/``TypeError`` with a message that names the
parameter. Violations of the ask/tell protocol raise :class:`StaleRequestError`, which is
also a ``ValueError`` so generic callers can catch either.
"""

from __future__ import annotations

__all__ = ["AWRError", "StaleRequestError", "InputFileError", "BackendError", "BackendUnavailableError",
           "InputFileWarning", "TimeBudgetWarning"]


class AWRError(Exception):
    """Base class of the errors specific to awr_denoise."""


class StaleRequestError(AWRError, ValueError):
    """A :class:`~awr_denoise.SampleRequest` was told twice, out of order, or to another sampler."""


class InputFileError(AWRError, ValueError):
    """An input file is missing, unreadable or does not hold what it should.

    The message always names the file (and the channel, where one is at fault).
    """


class BackendError(AWRError, RuntimeError):
    """An optional extra's native library failed (OIDN's device or filter: out of memory, an unsupported
    CPU); the message names it and keeps its own words."""


class BackendUnavailableError(BackendError):
    """An optional extra is installed but its native backend cannot start here (Mitsuba's Dr.Jit found
    no usable libLLVM, or no CUDA device). The message says what to install or choose instead."""


class InputFileWarning(UserWarning):
    """An input file was read, but what it holds may not give the result the user expects
    (an assumed sample count, a film filter that correlates pixels, an already denoised pass).

    The message names the file and fits on one line; the command line prints it as
    ``awr: warning: <message>``.
    """


class TimeBudgetWarning(UserWarning):
    """A run given a time budget (:meth:`~awr_denoise.Sampler.run`'s ``seconds``) could not keep it: its first
    round, always rendered, alone took longer. The command line prints it as ``awr: warning: <message>``.
    """
