"""When a solve stops: :class:`Termination`, one object composed with ``|`` (after OMPL's
``PlannerTerminationCondition``): a wall-clock cap (a safety cap), work budgets (candidates, LP
calls: the same seed gives the same answer), or the first verified plan. Read by the loop through
:attr:`~.options.SolverOptions.termination`; its keywords are the solve's ``time_limit``,
``max_candidates``, ``max_lp_calls`` and ``first_found``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .._checks import as_float, as_int
from ..errors import InvalidArgumentError, InvalidTypeError

__all__ = ["Termination"]


def _limit(a: int | None, b: int | None) -> int | None:
    """The tighter of two optional work limits."""
    if a is None:
        return b
    return a if b is None else min(a, b)


@dataclass(frozen=True)
class Termination:
    """When a solve stops: the first of its conditions to hold ends it.

    One object for what OMPL's ``PlannerTerminationCondition`` does: a wall-clock cap, work
    budgets, stop at the first plan, combined with ``|`` (whichever comes first; the tighter of
    two limits of the same kind)::

        Termination.time(60) | Termination.work(candidates=500)
        Termination.work(lp_calls=2000) | Termination.first()

    Give it as ``problem.solve(termination=...)`` (or to :meth:`SolverOptions.make` /
    :meth:`SolverOptions.with_`): it stands for the keywords ``time_limit``, ``max_candidates``,
    ``max_lp_calls`` and ``first_found``, which it replaces (giving both is an error).
    :attr:`SolverOptions.termination` is the condition a solve runs under, built from those
    keywords; its clock is always set (``10 * rrt_timeout`` when none is given).

    Work budgets decide the search (the same seed gives the same plan); the clock is a safety
    cap (when it decides, ``SolveStats.caps_hit`` says so).

    Parameters
    ----------
    seconds : float, optional
        Wall-clock cap in seconds, counted from the first line of ``solve``.
    candidates : int, optional
        Stop before the proposer's candidate number ``candidates + 1`` (``max_candidates``).
    lp_calls : int, optional
        Stop before the next candidate once this many LPs were solved (``max_lp_calls``).
    first_found : bool
        Stop at the first verified plan: no search for a better one after it (the refinement of
        an ``objective``; under ``guarantee="execution"``, the further search and the closed-loop
        fallback for a plan that meets the execution target once one below it was found: that
        plan is returned, flagged). The eager MILP, when it chooses the plan, still proves its
        own optimum.
    """

    seconds: float | None = None
    candidates: int | None = None
    lp_calls: int | None = None
    first_found: bool = False

    def __post_init__(self) -> None:
        put = object.__setattr__
        if self.seconds is not None:
            put(self, "seconds", as_float(self.seconds, "seconds", 0.0, low_open=True))
        for key in ("candidates", "lp_calls"):
            if getattr(self, key) is not None:
                put(self, key, as_int(getattr(self, key), key, minimum=1))
        if not isinstance(self.first_found, bool | np.bool_):
            raise InvalidTypeError(f"first_found must be a bool, got {type(self.first_found).__name__}")
        put(self, "first_found", bool(self.first_found))

    @classmethod
    def time(cls, seconds: float) -> Termination:
        """Stop after ``seconds`` of wall-clock time (a safety cap).

        Parameters
        ----------
        seconds : float
            The cap, > 0.

        Returns
        -------
        Termination
        """
        return cls(seconds=seconds)

    @classmethod
    def work(cls, *, candidates: int | None = None, lp_calls: int | None = None) -> Termination:
        """Stop after an amount of work (reproducible: the same seed gives the same plan).

        Parameters
        ----------
        candidates : int, optional
            Discrete candidates the proposer may offer.
        lp_calls : int, optional
            LPs the solve may spend (checked before each candidate).

        Returns
        -------
        Termination

        Raises
        ------
        InvalidArgumentError
            When neither is given.
        """
        if candidates is None and lp_calls is None:
            raise InvalidArgumentError("Termination.work needs candidates or lp_calls")
        return cls(candidates=candidates, lp_calls=lp_calls)

    @classmethod
    def first(cls) -> Termination:
        """Stop at the first verified plan (see ``first_found``).

        Returns
        -------
        Termination
        """
        return cls(first_found=True)

    def __or__(self, other: Termination) -> Termination:
        """Stop when either condition holds."""
        if not isinstance(other, Termination):
            return NotImplemented
        seconds = self.seconds if other.seconds is None else other.seconds
        if self.seconds is not None and other.seconds is not None:
            seconds = min(self.seconds, other.seconds)
        return Termination(
            seconds,
            _limit(self.candidates, other.candidates),
            _limit(self.lp_calls, other.lp_calls),
            self.first_found or other.first_found,
        )

    def work_done(self, candidates: int, lp_calls: int) -> str | None:
        """Which work budget is spent, in the words of its keyword, or ``None``.

        Checked by the loop before each candidate (a deterministic point of the search).

        Parameters
        ----------
        candidates : int
            Candidates proposed so far.
        lp_calls : int
            LPs solved so far.

        Returns
        -------
        str or None
            E.g. ``"max_candidates = 500 reached"``.
        """
        if self.candidates is not None and candidates >= self.candidates:
            return f"max_candidates = {self.candidates} reached"
        if self.lp_calls is not None and lp_calls >= self.lp_calls:
            return f"max_lp_calls = {self.lp_calls} reached ({lp_calls} LPs solved)"
        return None

    def keywords(self) -> dict[str, Any]:
        """The :class:`SolverOptions` keywords this condition stands for.

        Returns
        -------
        dict
            ``time_limit``, ``max_candidates``, ``max_lp_calls`` and ``first_found``.
        """
        return {
            "time_limit": self.seconds,
            "max_candidates": self.candidates,
            "max_lp_calls": self.lp_calls,
            "first_found": self.first_found,
        }
