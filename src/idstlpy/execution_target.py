"""The execution target: how often an executed plan must keep its promise.

A plan's promise is read two ways when it is executed (see :func:`idstlpy.validate`):

- *belief*: the executed belief trajectory (the Kalman filter's) satisfies the formula;
- *state*: the true states satisfy the formula's deterministic reading (every chance predicate
  ``P[h'x + c <= 0] >= 1 - eps`` read as ``h'x + c <= 0``).

:class:`ExecutionTarget` holds the least acceptable success rate of each reading. The default,
:data:`DEFAULT_EXECUTION_TARGET`, is 90% belief / 95% true state. The planner (its default
guarantee) and :func:`idstlpy.validate` (its verdict) take it as one option, ``execution_target``,
given as an :class:`ExecutionTarget`, a ``(belief, state)`` pair, a mapping with keys ``"belief"``
and ``"state"``, or None for the default; :func:`as_execution_target` turns each into an
:class:`ExecutionTarget` and raises a package error naming the argument otherwise.

This module is part of the model layer: it imports nothing of idstlpy but the errors and checks.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ._checks import as_float
from .errors import InvalidArgumentError, InvalidTypeError

__all__ = ["ExecutionTarget", "DEFAULT_EXECUTION_TARGET", "as_execution_target"]


@dataclass(frozen=True)
class ExecutionTarget:
    """Least acceptable execution success rates, per reading of the formula.

    Parameters
    ----------
    belief : float
        Least acceptable fraction of executions whose executed belief satisfies the formula,
        in ``[0, 1]`` (default 0.90).
    state : float
        Least acceptable fraction of executions whose true states satisfy the formula's
        deterministic reading, in ``[0, 1]`` (default 0.95).

    Raises
    ------
    InvalidTypeError
        A rate is not a number.
    InvalidArgumentError
        A rate is not finite or lies outside ``[0, 1]``.

    Examples
    --------
    >>> ExecutionTarget()
    ExecutionTarget(belief=0.9, state=0.95)
    >>> ExecutionTarget(0.99, 0.99).met_by(0.995, 0.98)
    False
    """

    belief: float = 0.90
    state: float = 0.95

    def __post_init__(self) -> None:
        # frozen: set the checked floats through object.__setattr__
        object.__setattr__(self, "belief", as_float(self.belief, "execution_target.belief", 0.0, 1.0))
        object.__setattr__(self, "state", as_float(self.state, "execution_target.state", 0.0, 1.0))

    def met_by(self, belief_rate: float, state_rate: float) -> bool:
        """Whether both rates reach the target.

        Parameters
        ----------
        belief_rate, state_rate : float
            Success rates (fractions in ``[0, 1]``) of the two readings.

        Returns
        -------
        bool
            ``belief_rate >= self.belief and state_rate >= self.state``.
        """
        return float(belief_rate) >= self.belief and float(state_rate) >= self.state

    def shortfalls(self, belief_rate: float, state_rate: float) -> dict[str, float]:
        """How far each reading falls short of the target (only the readings that do).

        Parameters
        ----------
        belief_rate, state_rate : float
            Success rates of the two readings.

        Returns
        -------
        dict
            ``{reading: target - rate}`` for every reading below its target (empty when met).
        """
        out: dict[str, float] = {}
        for reading, rate in (("belief", belief_rate), ("state", state_rate)):
            bar = getattr(self, reading)
            if float(rate) < bar:
                out[reading] = bar - float(rate)
        return out

    def as_dict(self) -> dict[str, float]:
        """``{"belief": b, "state": s}`` (JSON-ready; :func:`as_execution_target` reads it back).

        Returns
        -------
        dict
        """
        return {"belief": self.belief, "state": self.state}

    def __str__(self) -> str:
        return f"{_pct(self.belief)} belief / {_pct(self.state)} true state"


DEFAULT_EXECUTION_TARGET = ExecutionTarget()
"""The default target: 90% of executions keep the belief reading, 95% the true-state reading."""


def as_execution_target(value: Any, name: str = "execution_target") -> ExecutionTarget:
    """Return ``value`` as an :class:`ExecutionTarget` (None gives the default).

    Parameters
    ----------
    value : ExecutionTarget, (belief, state) pair, mapping, or None
        A mapping needs exactly the keys ``"belief"`` and ``"state"``.
    name : str
        The argument's name, used in error messages.

    Returns
    -------
    ExecutionTarget

    Raises
    ------
    InvalidTypeError
        ``value`` is none of the accepted forms, or a rate is not a number.
    InvalidArgumentError
        A pair of the wrong length, a mapping with other keys, or a rate outside ``[0, 1]``.
    """
    if value is None:
        return DEFAULT_EXECUTION_TARGET
    if isinstance(value, ExecutionTarget):
        return value
    if isinstance(value, Mapping):
        keys = set(value)
        if keys != {"belief", "state"}:
            raise InvalidArgumentError(
                f"{name} must have exactly the keys 'belief' and 'state', got {sorted(map(str, keys))}"
            )
        belief, state = value["belief"], value["state"]
    elif isinstance(value, tuple | list):
        if len(value) != 2:
            raise InvalidArgumentError(f"{name} must be a (belief, state) pair, got {len(value)} values")
        belief, state = value
    else:
        raise InvalidTypeError(
            f"{name} must be an ExecutionTarget, a (belief, state) pair, a mapping or None, "
            f"got {type(value).__name__}"
        )
    return ExecutionTarget(
        belief=as_float(belief, f"{name}.belief", 0.0, 1.0), state=as_float(state, f"{name}.state", 0.0, 1.0)
    )


def _pct(rate: float) -> str:
    return f"{100.0 * rate:.4g}%"
