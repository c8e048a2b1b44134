"""Exception hierarchy of idstlpy.

Every error raised for bad user input is one of these, so callers can catch either the
package-specific type or the builtin it subclasses (``ValueError``, ``TypeError``,
``IndexError``).
"""

from __future__ import annotations

__all__ = [
    "IdstlpyError",
    "DimensionError",
    "InvalidArgumentError",
    "InvalidTypeError",
    "OutOfRangeError",
    "NoiseFunctionError",
    "ProblemFileError",
    "ExecutionTargetWarning",
]


class IdstlpyError(Exception):
    """Base class of every exception raised by idstlpy."""


class InvalidArgumentError(IdstlpyError, ValueError):
    """An argument has the right type but an invalid value (NaN, bad interval, eps > 0.5...)."""


class DimensionError(InvalidArgumentError):
    """Array shapes do not agree (state, control, output or noise dimensions)."""


class InvalidTypeError(IdstlpyError, TypeError):
    """An argument has the wrong type (a formula where a predicate is expected...)."""


class OutOfRangeError(IdstlpyError, IndexError):
    """An index is outside a variable's range or a mode is outside the system's modes."""


class NoiseFunctionError(InvalidArgumentError):
    """A user-supplied noise function returned the wrong shape or non-finite values."""


class ProblemFileError(InvalidArgumentError):
    """A problem file is malformed; the message names the file, line and field."""


class ExecutionTargetWarning(UserWarning):
    """A returned plan's predicted execution falls short of its execution target.

    Issued with :func:`warnings.warn` (so a plain script shows it) when a solve can only return
    a plan whose predicted success (executed belief or true state) is below
    ``SolverOptions.execution_target``; the result says so too (``meets_target`` is False).
    """
