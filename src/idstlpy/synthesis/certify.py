"""The closed-loop repair: make a plan keep its promise under the executor.

Under ``guarantee="closed_loop"`` (and for a plan below the execution target) a verified plan
whose predicted true state (:func:`~.closed_loop_plan.closed_loop_check`) breaks the formula is repaired
by the trust-region repair loop (:mod:`.repair`), its score the predicted true state's margin.
Each round freezes the predicted covariances in the plan LP of the requirements the plan meets
(its witness), leaves the execution margin where it can and keeps room for the tracking
correction (:func:`~.closed_loop_plan.closed_loop_lp`); the re-rolled plan is checked again. Under
constant sensor noise and without clipping the predicted covariances depend on the modes only,
so one round is exact; otherwise the means may move at most ``trust`` per round (halved after
a round that did not help) and the round takes the first fraction of the LP's step that passes
(:func:`line_search`). A plan whose prediction passes but whose inputs leave the tracking
correction no room (:func:`idstlpy.closed_loop.trackable`) gets one repair round and is kept if
that does not give a trackable plan (a plan found by the line search was that round's outcome
already).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..belief import rollout
from ..trajectory import ProbabilisticTSTrajectory
from .closed_loop_plan import closed_loop_check, closed_loop_lp, execution_margin
from .interfaces import Budget
from .plan import DiscretePlan, trajectory_plan
from .plan_lp import PlanLPContext
from .plan_solve import LPOutcome, TrustRegion, solve_plan_lp
from .repair import STOP, RepairSteps, Stop, repair
from .results import SolveStats

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = ["Certified", "Checked", "MIN_ROUNDS", "STEP_FRACTIONS", "certify", "line_search"]

logger = logging.getLogger(__name__)

MIN_ROUNDS = 2
"""Least work budget (LP rounds) of a repair, whatever ``SolverOptions.polish_rounds`` says."""

STEP_FRACTIONS = (1.0, 0.5, 0.25, 0.125, 0.0625)
"""Fractions of a sequential-convex repair step tried in turn (:func:`line_search`)."""


class Certified(NamedTuple):
    """A plan that keeps its promise: the MLO plan, the predicted true state's margin and that
    predicted distribution."""

    traj: ProbabilisticTSTrajectory
    margin: float
    predicted: ProbabilisticTSTrajectory


class Checked(NamedTuple):
    """A plan and what :func:`~.closed_loop_plan.closed_loop_check` says of it."""

    traj: ProbabilisticTSTrajectory
    predicted: ProbabilisticTSTrajectory
    margin: float
    ok: bool
    tracks: bool


def certify(
    context: PlanLPContext,
    problem: Problem,
    traj: ProbabilisticTSTrajectory,
    *,
    exact: bool,
    rounds: int,
    stats: SolveStats,
    budget: Budget,
) -> Certified | None:
    """Make ``traj`` keep its promise under the executor (module notes).

    Parameters
    ----------
    context : PlanLPContext
        The solve's plan LP context.
    problem : Problem
    traj : ProbabilisticTSTrajectory
        The plan (its MLO roll-out).
    exact : bool
        Whether one LP round is the answer (no trust region, no line search).
    rounds : int
        Work budget: LP rounds (at least :data:`MIN_ROUNDS`); a step undone costs one more.
    stats : SolveStats
        ``lp_calls`` and ``time_lp`` are counted here; ``execution_room`` is cleared (the promise
        is the predicted true state itself).
    budget : Budget
        Wall-clock cap, checked before every closed-loop check.

    Returns
    -------
    Certified or None
        None when no plan passes.
    """
    stats.execution_room = None
    steps = _CertifySteps(context, problem, exact, max(MIN_ROUNDS, rounds), stats, budget)
    parts: RepairSteps[Checked, ProbabilisticTSTrajectory | Checked] = steps
    repair(parts, steps.check(traj), steps.rounds)
    if steps.found is not None:
        if steps.spent:
            logger.info("closed-loop repair: the plan keeps its promise after %d round(s)", steps.spent)
        return Certified(steps.found.traj, steps.found.margin, steps.found.predicted)
    if steps.fallback is not None:
        logger.info(
            "closed-loop check: no trackable plan found; the plan's inputs ride the control domain's "
            "faces, where the prediction linearises the clipping"
        )
        fallback = steps.fallback
        return Certified(fallback.traj, fallback.margin, fallback.predicted)
    logger.info("closed-loop repair failed: the predicted true state breaks the formula")
    return None


class _CertifySteps:
    """:func:`certify`'s parts of the repair loop (:class:`.repair.RepairSteps`).

    ``spent`` counts the rounds as the repair always has: a step, and a step undone (the plan
    went back to the better one before it), each cost one; at ``rounds`` the repair stops.
    """

    name = "closed-loop repair"

    def __init__(
        self,
        context: PlanLPContext,
        problem: Problem,
        exact: bool,
        rounds: int,
        stats: SolveStats,
        budget: Budget,
    ) -> None:
        self.context, self.problem, self.exact = context, problem, exact
        self.rounds, self.stats, self.budget = rounds, stats, budget
        self.spent = 0
        self.found: Checked | None = None  # a passing, trackable plan
        self.fallback: Checked | None = None  # a passing plan that rides the faces
        self.searched = False  # whether the current plan is a fraction of a repair step
        self._plan: tuple[ProbabilisticTSTrajectory, DiscretePlan | None] | None = None

    def check(self, traj: ProbabilisticTSTrajectory) -> Checked:
        """The closed-loop check of ``traj``."""
        self.budget.check("the closed-loop certification")
        problem = self.problem
        checked = Checked(
            traj, *closed_loop_check(self.context.system, traj, problem.control_domain, problem.stl_formula)
        )
        logger.debug(
            "closed-loop repair round %d: margin %.3g, trackable %s",
            self.spent,
            checked.margin,
            checked.tracks,
        )
        return checked

    def witness(self, traj: ProbabilisticTSTrajectory) -> DiscretePlan | None:
        """The requirements ``traj`` meets (computed once per plan)."""
        if self._plan is None or self._plan[0] is not traj:
            self._plan = (traj, trajectory_plan(self.problem.stl_formula, self.context.abstraction, traj))
        return self._plan[1]

    def done(self, state: Checked) -> bool:
        if state.ok and state.tracks:
            self.found = state
            return True
        if self.fallback is not None:
            if state.ok and state.margin > self.fallback.margin:
                self.fallback = state
            return True  # one repair of a passing plan that rides the faces, no more (it rarely pays)
        if state.ok:
            self.fallback = state
            if self.searched:
                return True  # the step just taken was that plan's repair LP already
        return self.spent >= self.rounds

    def first_trust(self, state: Checked) -> float:
        plan = self.witness(state.traj)
        if self.exact or plan is None:
            return np.inf
        target = execution_margin(
            self.context.system, self.problem.initial_state, self.context.abstraction, plan
        )
        return 2.0 * max(target, 1e-3 * float(np.max(self.context.scaling.dx)))

    def propose(
        self, state: Checked, trust: float, left: float
    ) -> ProbabilisticTSTrajectory | Checked | Stop | None:
        plan = self.witness(state.traj)
        self.spent += 1
        if plan is None:
            return STOP
        lp = closed_loop_lp(
            self.context.system,
            state.traj,
            self.problem.control_domain,
            state.predicted,
            self._solver(state, plan, trust),
        )
        if not lp.feasible or lp.controls is None:
            return None
        L = plan.length
        if self.exact or self.fallback is not None:
            # exact: the step is the answer; a passing plan's one repair round is after a
            # trackable plan, which a fraction of an untrackable step rarely gives
            acts = state.traj.get_action()[: L - 1]
            return rollout(self.context.system, self.problem.initial_state, acts, lp.controls)
        step = line_search(self.context, self.problem, state.traj, lp.controls, state.margin, self.budget)
        if step is not None:
            self.searched = True
        return step  # None: no fraction helps, a smaller trust region's LP next

    def _solver(
        self, state: Checked, plan: DiscretePlan, trust: float
    ) -> Callable[[np.ndarray | None, np.ndarray], LPOutcome]:
        """The plan LP :func:`~.closed_loop_plan.closed_loop_lp` asks for (a back-off, covariances)."""
        L = plan.length
        target = execution_margin(
            self.context.system, self.problem.initial_state, self.context.abstraction, plan
        )
        # Under state-dependent noise the covariances move with the means: a step of sequential
        # convex programming, not a frozen-covariance LP.
        region = TrustRegion(state.traj.get_mean()[:L], trust, linearise=not self.exact)

        def solve(backoff: np.ndarray | None, covs: np.ndarray) -> LPOutcome:
            with self.stats.clock("time_lp"):
                out = solve_plan_lp(
                    self.context,
                    plan,
                    target,
                    covs=covs[:L],
                    region=region,
                    control_backoff=None if backoff is None else backoff[: L - 1],
                    budget=self.budget,
                    time_limit=max(self.budget.remaining(), 1e-3),
                )
            self.stats.lp_calls += 1
            return out

        return solve

    def accept(
        self, state: Checked, proposal: ProbabilisticTSTrajectory | Checked, trust: float
    ) -> Checked | None:
        moved = proposal if isinstance(proposal, Checked) else self.check(proposal)
        if not moved.ok and moved.margin < state.margin:
            # The step made it worse: back to the plan before it, with smaller steps (a round).
            self.spent += 1
            return None
        return moved

    def stuck(self, state: Checked, failures: int) -> bool:
        # exact: no smaller step helps; a passing fallback: its one repair round is over
        return self.exact or self.fallback is not None


def line_search(
    context: PlanLPContext,
    problem: Problem,
    traj: ProbabilisticTSTrajectory,
    controls: np.ndarray,
    margin: float,
    budget: Budget,
) -> Checked | None:
    """The first fraction of the repair step ``traj -> controls`` whose plan keeps its promise.

    Under state-dependent noise the repair LP linearises the covariances at the current means,
    and its whole step (as far as the trust region) can break what it meant to mend, even in
    the plan's own MLO roll-out (the double integrator, seed 1: -0.19 after a full step from
    -0.012), while a fraction of the same step passes. The roll-out's means are linear in the
    controls, so a fraction ``a`` moves every mean ``a`` times as far. Each fraction of
    :data:`STEP_FRACTIONS` is checked in turn (the Gaussian screen of
    :func:`~.closed_loop_plan.closed_loop_check` first, which makes the failing ones cheap).

    Parameters
    ----------
    context : PlanLPContext
    problem : Problem
    traj : ProbabilisticTSTrajectory
        The current plan (its MLO roll-out).
    controls : ndarray, shape (L - 1, m)
        The repair LP's controls (its first ``L - 1`` actions are kept).
    margin : float
        The current plan's closed-loop margin.
    budget : Budget
        Wall-clock cap, checked before every fraction.

    Returns
    -------
    Checked or None
        The first fraction's plan that passes the check, else the best one when it improves on
        ``margin``, else None.
    """
    system, init, formula = context.system, problem.initial_state, problem.stl_formula
    L = controls.shape[0] + 1
    acts, start = traj.get_action()[: L - 1], traj.get_control()[: L - 1]
    best: Checked | None = None
    for a in STEP_FRACTIONS:
        budget.check("the closed-loop certification")
        moved = rollout(system, init, acts, start + a * (controls - start))
        checked = Checked(moved, *closed_loop_check(system, moved, problem.control_domain, formula))
        logger.debug("closed-loop repair: %.3g of the step, margin %.3g", a, checked.margin)
        if checked.ok:
            return checked
        if checked.margin > margin and (best is None or checked.margin > best.margin):
            best = checked
    return best
