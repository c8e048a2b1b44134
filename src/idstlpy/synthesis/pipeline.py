"""The solve pipeline: what :meth:`Problem.solve <idstlpy.problem.Problem.solve>` runs, in order.

As cvxpy's ``_build_solving_chain`` lists the reductions of a solve, :data:`STAGES` lists the
stages of one, and :func:`solve` walks them top to bottom:

1. :class:`Decoupled` (:mod:`.decoupled`): a problem of independent blocks is planned block by
   block and the composed plan verified; its result, or ``None`` (not applicable, a block not
   found, the composed plan set aside) and the search runs;
2. :class:`Search` (:mod:`.cegis`): the proposer / teacher loop of the paper's Fig. 1; a result;
3. :class:`JointAllocation` (:mod:`.allocation`, only with joint chance constraints): a found
   plan gets one round of risk re-allocation, any other result a search over allocations; a
   result;
4. :class:`ClosedLoopFallback` (:mod:`.escalation`, only under ``guarantee="execution"``
   without ``first_found``): when only plans below the execution target were found, one
   closed-loop solve in the time left; a result. The warnings of stages 1-3 are held while it
   decides which answer stands, and issued again for that answer;
5. :class:`MarkovSwitching` (:mod:`.markov_plan`, only for a system with chance switching): the
   returned plan's bound under the switching; a result.

A cancelled solve (:meth:`~.termination.Termination.cancellable`) runs neither stage 3 nor 4.

Stages 1 and 2 share one :class:`~.context.SolveContext` (their statistics add up), one deadline
scope and the tracking gains the solve plans with (:func:`~idstlpy.tracking.planning_gains`):
the time limit, hit anywhere in them, ends the solve with the reason :func:`_timed_out` writes.
Stages 3 and 4 re-run stages 1-2 (:func:`core`) on a changed problem or guarantee: a re-solve is
the core again, so they receive it as their solver, as the decoupled stage does for each block.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .. import _deadline as deadline
from ..markov import switching_of
from ..tracking import planning_gains
from .allocation import refine_allocation, search_allocation
from .cegis import search, verify
from .context import SolveContext
from .decoupled import solve_decoupled
from .escalation import closed_loop_fallback
from .finish import finish
from .interfaces import BudgetExceeded
from .markov_plan import after_switching
from .options import SolverOptions
from .results import SolveResult
from .termination import CANCELLED

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = [
    "STAGES",
    "ClosedLoopFallback",
    "Decoupled",
    "JointAllocation",
    "MarkovSwitching",
    "Search",
    "core",
    "solve",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Decoupled:
    """Stage 1: independent blocks planned one by one (:func:`~.decoupled.solve_decoupled`)."""

    name: str = "decoupled"

    def applies(self, ctx: SolveContext) -> bool:
        """Not for an objective (the blocks' optima are not the joint one) nor under
        ``guarantee="closed_loop"`` (each block would be verified against its own prediction)."""
        return ctx.options.objective is None and not ctx.closed_loop

    def run(self, ctx: SolveContext) -> SolveResult | None:
        """The composed plan, verified (:func:`~.cegis.verify`: under ``"execution"`` the target
        too, or it is set aside), else ``None``: the search runs."""
        plan = solve_decoupled(ctx.problem, ctx.options, ctx.budget, ctx.stats, core)
        if plan is None:
            return None
        checked = verify(ctx, plan.actions, plan.controls)
        if checked is None:
            logger.info("decoupled: the composed plan failed the final check; searching the joint problem")
            return None
        return finish(ctx, "found", f"{plan.how}; the monitor agrees", checked)


@dataclass(frozen=True)
class Search:
    """Stage 2: the CEGIS loop (:func:`~.cegis.search`)."""

    name: str = "search"

    def run(self, ctx: SolveContext) -> SolveResult:
        """The loop's answer."""
        return search(ctx)


@dataclass(frozen=True)
class JointAllocation:
    """Stage 3: the joint chance constraints' risk allocation (:mod:`.allocation`)."""

    name: str = "joint allocation"

    def applies(self, problem: Problem) -> bool:
        """Only for a problem with joint chance constraints."""
        return bool(getattr(problem, "_joint", False))

    def run(self, problem: Problem, options: SolverOptions, start: float, result: SolveResult) -> SolveResult:
        """A found plan: one round of re-allocation (:func:`~.allocation.refine_allocation`); any
        other result: the relaxation and other allocations (:func:`~.allocation.search_allocation`)."""
        if result.status == "found":
            return refine_allocation(problem, options, start, result, core)
        return search_allocation(problem, options, start, result, core)


@dataclass(frozen=True)
class ClosedLoopFallback:
    """Stage 4: a closed-loop solve when only plans below target were found
    (:func:`~.escalation.closed_loop_fallback`)."""

    name: str = "closed-loop fallback"

    def applies(self, options: SolverOptions) -> bool:
        """Under the default guarantee, unless the first verified plan is the answer."""
        return options.target.guarantee == "execution" and not options.termination.first_found

    def run(
        self,
        problem: Problem,
        options: SolverOptions,
        start: float,
        first: SolveResult,
        held: list[warnings.WarningMessage],
    ) -> SolveResult:
        """The answer that stands, its warnings (``held``: those of stages 1-3) issued again."""
        return closed_loop_fallback(problem, options, start, first, held, core)


@dataclass(frozen=True)
class MarkovSwitching:
    """Stage 5: the plan's bound under chance switching (:func:`~.markov_plan.after_switching`)."""

    name: str = "chance switching bound"

    def applies(self, problem: Problem) -> bool:
        """Only for a switched system with chance switching."""
        return switching_of(problem.switched_system) is not None

    def run(self, problem: Problem, options: SolverOptions, result: SolveResult) -> SolveResult:
        """``result`` with its plan's bound under the switching."""
        return after_switching(problem, options, result)


DECOUPLED, SEARCH, ALLOCATION = Decoupled(), Search(), JointAllocation()
FALLBACK, SWITCHING = ClosedLoopFallback(), MarkovSwitching()

STAGES = (DECOUPLED, SEARCH, ALLOCATION, FALLBACK, SWITCHING)
"""The stages of a solve, in the order :func:`solve` runs them."""


def solve(problem: Problem, options: SolverOptions, start: float) -> SolveResult:
    """Run the stages of :data:`STAGES` on ``problem`` (see the module docstring).

    Parameters
    ----------
    problem : Problem
    options : SolverOptions
    start : float
        ``time.perf_counter()`` at the first line of ``Problem.solve``: every stage shares the
        one time cap counted from it.

    Returns
    -------
    SolveResult
    """
    if FALLBACK.applies(options):
        with warnings.catch_warnings(record=True) as held:
            warnings.simplefilter("always")
            first = _first(problem, options, start)
        result = FALLBACK.run(problem, options, start, first, held)
    else:
        result = _first(problem, options, start)
    if SWITCHING.applies(problem):
        result = SWITCHING.run(problem, options, result)
    return result


def _first(problem: Problem, options: SolverOptions, start: float) -> SolveResult:
    """Stages 1-3: the core, then (joint chance constraints) the risk allocation."""
    result = core(problem, options, start)
    if ALLOCATION.applies(problem) and CANCELLED not in result.stats.caps_hit:
        result = ALLOCATION.run(problem, options, start, result)
    return result


def core(problem: Problem, options: SolverOptions, start: float | None = None) -> SolveResult:
    """Stages 1-2 under one context and deadline: the decoupled blocks, else the search.

    Parameters
    ----------
    problem : Problem
    options : SolverOptions
    start : float, optional
        ``time.perf_counter()`` at the first line of ``solve``: the wall-clock cap counts from it.

    Returns
    -------
    SolveResult
    """
    ctx = SolveContext(problem, options, time.perf_counter() if start is None else start)
    base = ctx.target.tracking[0] if ctx.target.tracking else None
    # every closed-loop reading of the solve (predictions, execution room, repair) sees the
    # fitted gains; the returned plan carries them (finish)
    # The deadline reaches the loops below the synthesis (the predicted executions) through the
    # scope; the parts that take the budget check it themselves.
    with deadline.scope(ctx.budget.deadline), planning_gains(problem.switched_system, base):
        try:
            if DECOUPLED.applies(ctx):
                composed = DECOUPLED.run(ctx)
                if composed is not None:
                    return composed
            return SEARCH.run(ctx)
        except BudgetExceeded as exc:
            return _timed_out(ctx, exc)


def _timed_out(ctx: SolveContext, exc: BudgetExceeded) -> SolveResult:
    """The result of stages 1-2 when the time limit ended them (``caps_hit`` names it)."""
    if "time_limit" not in ctx.stats.caps_hit:
        ctx.stats.caps_hit.append("time_limit")
    cap = f"time limit of {ctx.options.total_time_cap:.3g} s"
    when = f"{cap} reached during {exc.where}"
    if exc.ahead:
        when = f"{cap} nearly reached during {exc.where}: {exc.ahead} would not fit in the time left"
    return finish(ctx, "budget_exhausted", f"{when}; {ctx.counts()}")
