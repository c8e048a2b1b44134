"""When a solve stops: :class:`Termination`, one object composed with ``|`` and ``&`` (after
OMPL's ``PlannerTerminationCondition``): a wall-clock cap (a safety cap), work budgets
(candidates, LP calls: the same seed gives the same answer), the first verified plan, a user
predicate on the search's progress (:meth:`Termination.when`) and a cancellation another thread
may trigger (:meth:`Termination.cancellable`). Read by the loop through
:attr:`~.options.SolverOptions.termination`; its keywords are the solve's ``time_limit``,
``max_candidates``, ``max_lp_calls``, ``first_found`` and ``stop_rules`` (the predicates,
cancellations and ``&`` compositions, checked where the work budgets are: before each
candidate).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from .._checks import as_float, as_int
from ..errors import InvalidArgumentError, InvalidTypeError

__all__ = ["Cancellable", "SearchProgress", "StopRule", "Stopped", "Termination"]

CANCELLED = "cancelled"
"""The ``SolveStats.caps_hit`` entry of a solve a :meth:`Cancellable.cancel` ended."""


@dataclass(frozen=True)
class SearchProgress:
    """The search's progress counters where a termination is checked (before each candidate).

    Parameters
    ----------
    candidates : int
        Candidates the proposer offered so far.
    lp_calls, milp_calls : int
        LPs and MILPs solved so far.
    refuted, abandoned : int
        Candidates refuted (a proven clause) and abandoned (set aside) so far.
    elapsed : float
        Seconds since the first line of ``solve``.
    """

    candidates: int = 0
    lp_calls: int = 0
    milp_calls: int = 0
    refuted: int = 0
    abandoned: int = 0
    elapsed: float = 0.0


@dataclass(frozen=True)
class Stopped:
    """Why a stop rule ends the search.

    Parameters
    ----------
    reason : str
        The words of the result's ``reason``.
    cap : str or None
        The ``SolveStats.caps_hit`` entry it stands for (``"cancelled"``), or ``None``.
    """

    reason: str
    cap: str | None = None


class StopRule(Protocol):
    """A condition a :class:`Termination` checks before each candidate."""

    def reached(self, progress: SearchProgress) -> Stopped | None:
        """Why the search ends now, or ``None`` to go on."""


@dataclass(frozen=True, eq=False)
class _When:
    """A user predicate (:meth:`Termination.when`)."""

    predicate: Callable[[SearchProgress], bool]
    name: str

    def reached(self, progress: SearchProgress) -> Stopped | None:
        return Stopped(f"stop condition {self.name} held") if self.predicate(progress) else None


@dataclass(frozen=True, eq=False)
class _Cancel:
    """A flag another thread sets (:meth:`Cancellable.cancel`); ``threading.Event`` is safe to
    set from any thread and to read from the solve's."""

    event: threading.Event = field(default_factory=threading.Event)

    def reached(self, progress: SearchProgress) -> Stopped | None:
        if not self.event.is_set():
            return None
        return Stopped("cancelled (Termination.cancellable().cancel() was called)", CANCELLED)


@dataclass(frozen=True, eq=False)
class _All:
    """Both conditions hold (``a & b``)."""

    parts: tuple[Termination, Termination]

    def reached(self, progress: SearchProgress) -> Stopped | None:
        held = [part.reached(progress) for part in self.parts]
        if any(h is None for h in held):
            return None
        done = [h for h in held if h is not None]
        cap = next((h.cap for h in done if h.cap is not None), None)
        return Stopped(" and ".join(h.reason for h in done), cap)


def _limit(a: int | None, b: int | None) -> int | None:
    """The tighter of two optional work limits."""
    if a is None:
        return b
    return a if b is None else min(a, b)


@dataclass(frozen=True)
class Termination:
    """When a solve stops: the first of its conditions to hold ends it.

    One object for what OMPL's ``PlannerTerminationCondition`` does: a wall-clock cap, work
    budgets, stop at the first plan, a user predicate, a cancellation from another thread,
    combined with ``|`` (whichever comes first; the tighter of two limits of the same kind) and
    ``&`` (when both hold)::

        Termination.time(60) | Termination.work(candidates=500)
        Termination.work(lp_calls=2000) | Termination.first()
        Termination.work(candidates=50) & Termination.when(lambda p: p.abandoned > 10)
        stop = Termination.cancellable()  # stop.cancel() from the replanner's thread

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
    rules : tuple of StopRule
        The predicates, cancellations and ``&`` compositions (:meth:`when`,
        :meth:`cancellable`, ``&``), any of which ends the search at a check; built by those,
        not by hand.
    """

    seconds: float | None = None
    candidates: int | None = None
    lp_calls: int | None = None
    first_found: bool = False
    rules: tuple[StopRule, ...] = ()

    def __post_init__(self) -> None:
        put = object.__setattr__
        rules = tuple(self.rules) if isinstance(self.rules, tuple | list) else None
        if rules is None or not all(callable(getattr(r, "reached", None)) for r in rules):
            raise InvalidTypeError(
                "rules must be a tuple of stop rules (Termination.when / Termination.cancellable / a & b)"
            )
        put(self, "rules", rules)
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

    @classmethod
    def when(cls, predicate: Callable[[SearchProgress], bool], name: str | None = None) -> Termination:
        """Stop when ``predicate(progress)`` is true, checked where the work budgets are (before
        each candidate), with the search's :class:`SearchProgress`.

        Parameters
        ----------
        predicate : callable (SearchProgress) -> bool
            Called in the solve's thread; an exception it raises ends the solve with it.
        name : str, optional
            Its name in the result's reason (default: the function's name).

        Returns
        -------
        Termination

        Raises
        ------
        InvalidTypeError
            When ``predicate`` is not callable.
        """
        if not callable(predicate):
            raise InvalidTypeError(f"predicate must be callable, got {type(predicate).__name__}")
        label = name if name is not None else getattr(predicate, "__name__", "")
        if not label or label == "<lambda>":
            label = "(a user predicate)"
        return cls(rules=(_When(predicate, str(label)),))

    @classmethod
    def cancellable(cls) -> Cancellable:
        """A condition another thread ends the solve with: call its :meth:`Cancellable.cancel`.

        The solve ends at its next check (before its next candidate) with status
        ``budget_exhausted``, a reason saying it was cancelled and ``"cancelled"`` in
        ``SolveStats.caps_hit``. Compose it as any condition (``Termination.cancellable() |
        Termination.time(60)``): every composition shares the one flag.

        Returns
        -------
        Cancellable
        """
        return Cancellable(rules=(_Cancel(),))

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
            self.rules + other.rules,
        )

    def __and__(self, other: Termination) -> Termination:
        """Stop when both conditions hold, checked before each candidate (a clock inside ``&``
        is read there too: the solve's own safety clock stays ``10 * rrt_timeout`` unless a
        :meth:`time` is composed with ``|``).

        Raises
        ------
        InvalidArgumentError
            When either side stops at the first plan (``first_found`` is a way to search, not a
            condition that holds at a point of it).
        """
        if not isinstance(other, Termination):
            return NotImplemented
        if self.first_found or other.first_found:
            raise InvalidArgumentError(
                "Termination.first() cannot be composed with &: compose it with | instead"
            )
        return Termination(rules=(_All((self, other)),))

    def reached(self, progress: SearchProgress) -> Stopped | None:
        """Why this condition holds at ``progress`` (every part of it: clock, work budgets and
        rules, read at the check), or ``None``.

        Parameters
        ----------
        progress : SearchProgress

        Returns
        -------
        Stopped or None
        """
        if self.seconds is not None and progress.elapsed >= self.seconds:
            return Stopped(f"{self.seconds:.3g} s elapsed")
        spent = self.work_done(progress.candidates, progress.lp_calls)
        if spent is not None:
            return Stopped(spent)
        return self.rule_reached(progress)

    def rule_reached(self, progress: SearchProgress) -> Stopped | None:
        """Why one of the :attr:`rules` holds at ``progress`` (the first in order), or ``None``.

        The loop checks the clock and work budgets itself (:meth:`work_done`), then this.

        Parameters
        ----------
        progress : SearchProgress

        Returns
        -------
        Stopped or None
        """
        for rule in self.rules:
            held = rule.reached(progress)
            if held is not None:
                return held
        return None

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
            ``time_limit``, ``max_candidates``, ``max_lp_calls``, ``first_found`` and
            ``stop_rules``.
        """
        return {
            "time_limit": self.seconds,
            "max_candidates": self.candidates,
            "max_lp_calls": self.lp_calls,
            "first_found": self.first_found,
            "stop_rules": self.rules,
        }


class Cancellable(Termination):
    """A :class:`Termination` another thread ends the solve with (:meth:`Termination.cancellable`).

    Examples
    --------
    >>> stop = Termination.cancellable()
    >>> # in the planner's thread: problem.solve(termination=stop | Termination.time(60))
    >>> stop.cancel()  # in the replanner's thread: the solve ends at its next check
    >>> stop.cancelled
    True
    """

    def _flag(self) -> threading.Event:
        rule = self.rules[0]
        if not isinstance(rule, _Cancel):  # only Termination.cancellable() builds one
            raise InvalidTypeError("a Cancellable is made by Termination.cancellable()")
        return rule.event

    def cancel(self) -> None:
        """End the solves running under this condition at their next check (thread-safe)."""
        self._flag().set()

    @property
    def cancelled(self) -> bool:
        """Whether :meth:`cancel` was called."""
        return self._flag().is_set()
