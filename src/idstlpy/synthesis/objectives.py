"""What "a good plan" means: the objectives a solve can optimise, and the anytime refiner.

- ``"effort"``: ``sum_k sum_j w_j |u_kj|`` (lower is better; per-input weights ``w``);
- ``"time"``: the plan's number of steps (its transitions; lower is better): a plan of ``N``
  transitions decides the formula true by step ``N``;
- ``"margin"``: the monitor's robustness (higher is better), stlpy's robustness mode for PrSTL.

On the eager MILP's path (one mode, no state-dependent noise) the optimum is exact over every
plan within the horizon, for the problem as stated (no execution margin, idle steps free; see
:mod:`.milp` and ``eager.EagerMILP._retime``), and ``optimal=True`` only within 1e-6 of its proven bound
(issue 25). On the sampler path the plan is refined by sequential convex programming: freeze
the exact covariances of the current plan, solve the plan LP for the objective with the means
kept within a trust region, re-roll the exact belief dynamics, keep the result only if the
monitor still accepts it, the objective improved and the plan keeps the execution room
(:mod:`.room`) it had (up to all of it); the trust region halves after a round that did not
help (the trust-region repair loop, :mod:`.repair`). The rounds are a work budget
(``SolverOptions.polish_rounds``), so the result is reproducible.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from ..belief import rollout
from ..semantics import robustness
from ..trajectory import ProbabilisticTSTrajectory
from .abstraction import Abstraction
from .options import OBJECTIVES as OPTION_OBJECTIVES
from .options import Objective
from .plan_lp import PlanLPContext, Scaling
from .plan_solve import LPGoal, TrustRegion, solve_plan_lp
from .repair import STOP, Stop, repair
from .results import SolveStats
from .room import RoomState, note_room, room_lp, room_state

if TYPE_CHECKING:
    from ..formulas import STLFormula
    from ..problem import Problem

__all__ = ["OBJECTIVES", "better", "objective_value", "refine", "smooth", "total_variation"]

logger = logging.getLogger(__name__)

OBJECTIVES: tuple[Objective, ...] = OPTION_OBJECTIVES


def objective_value(
    name: Objective, traj: ProbabilisticTSTrajectory, formula: STLFormula, weights: np.ndarray | None = None
) -> float:
    """The value of objective ``name`` on a plan (see the module docstring).

    Parameters
    ----------
    name : {"effort", "time", "margin"}
        The objective; any other name raises ``ValueError``.
    traj : ProbabilisticTSTrajectory
        The plan.
    formula : STLFormula
        The formula whose robustness is the ``"margin"`` objective (unused by the others).
    weights : ndarray, shape (m,), optional
        Per-input weights of ``"effort"`` (default: all ones; unused by the others).

    Returns
    -------
    float
    """
    if name == "effort":
        return _effort(traj.get_control(), _weights(traj.get_control().shape[1], weights))
    if name == "time":
        return float(traj.num_of_steps)
    if name == "margin":
        return float(robustness(traj, formula))
    raise ValueError(f"unknown objective {name!r}")


def total_variation(controls: np.ndarray, weights: np.ndarray | None = None) -> float:
    """``sum_k sum_j w_j |u_{k+1,j} - u_kj|``: how much a plan's input changes (what the default
    plans' smoothing lowers).

    Parameters
    ----------
    controls : ndarray, shape (K, m)
        The plan's inputs.
    weights : ndarray, shape (m,), optional
        Per-input weights ``w`` (default ones).

    Returns
    -------
    float
    """
    u = np.asarray(controls, dtype=float)
    if u.shape[0] < 2:
        return 0.0
    w = _weights(u.shape[1], weights)
    return float(np.sum(np.abs(np.diff(u, axis=0)) @ w))


def smooth(
    problem: Problem,
    abstraction: Abstraction,
    scaling: Scaling,
    traj: ProbabilisticTSTrajectory,
    rounds: int,
    stats: SolveStats,
) -> ProbabilisticTSTrajectory:
    """A verified plan with less input change: the default plans' tie-break (issue 34).

    The same trust-region SCP as :func:`refine`, minimising the inputs' total variation
    (:func:`total_variation`, each input in the units of the control domain's half-width: a
    volt and a newton weigh by how far their domains reach) with the plan's execution room kept
    (:mod:`.room`): every step is kept only when the monitor accepts the re-rolled plan, the
    total variation dropped and the room is kept; the caller re-checks the plan as any other
    (the final check and the execution target). Feasibility is not changed: the same modes, the
    same requirements, the room kept.

    Parameters
    ----------
    problem : Problem
    abstraction : Abstraction
    scaling : Scaling
    traj : ProbabilisticTSTrajectory
        A plan the monitor accepts.
    rounds : int
        Work budget: LP rounds.
    stats : SolveStats
        ``lp_calls`` are recorded here.

    Returns
    -------
    ProbabilisticTSTrajectory
        A plan the monitor accepts, with no more input total variation than ``traj``
        (``traj`` itself when nothing better was found).
    """
    if traj.num_of_steps < 2:
        return traj
    context = PlanLPContext.of(problem, abstraction, scaling)
    base = room_state(context, problem.stl_formula, traj)
    if base is None:
        return traj
    weights = 1.0 / np.maximum(scaling.du, 1e-300)  # per input, in its domain's units
    value = total_variation(traj.get_control(), weights)
    if value <= 0.0:
        return traj
    keep = min(1.0, max(base.room.score, 0.0))
    steps = _RefineSteps(context, problem, "smooth", weights, keep, stats, lambda: 0.0)
    end = repair(steps, _Refined(base, value), rounds)
    return end.at.traj


def better(name: Objective | Literal["smooth"], a: float, b: float) -> bool:
    """Whether value ``a`` improves on ``b`` (by more than a relative 1e-9).

    Parameters
    ----------
    name : str
        The objective: ``"margin"`` is maximised, every other objective (and ``"smooth"``, the
        total variation) minimised.
    a : float
        The candidate value.
    b : float
        The value to beat.

    Returns
    -------
    bool
    """
    tol = 1e-9 * max(1.0, abs(b))
    return a > b + tol if name == "margin" else a < b - tol


def refine(
    problem: Problem,
    abstraction: Abstraction,
    scaling: Scaling,
    traj: ProbabilisticTSTrajectory,
    name: Objective,
    weights: np.ndarray | None,
    rounds: int,
    stats: SolveStats,
    elapsed: Callable[[], float],
) -> ProbabilisticTSTrajectory:
    """Improve a verified plan for objective ``name`` by trust-region SCP (module docstring).

    Parameters
    ----------
    problem : Problem
    abstraction : Abstraction
    scaling : Scaling
    traj : ProbabilisticTSTrajectory
        A plan the monitor accepts.
    name : {"effort", "margin"}
    weights : ndarray, shape (m,), optional
    rounds : int
        Work budget: LP rounds.
    stats : SolveStats
        ``lp_calls`` and ``improvements`` are recorded here.
    elapsed : callable
        Seconds since the solve started (for the improvement history).

    Returns
    -------
    ProbabilisticTSTrajectory
        A plan the monitor accepts, at least as good as ``traj``.
    """
    if name not in ("effort", "margin"):
        return traj
    context = PlanLPContext.of(problem, abstraction, scaling)
    value = objective_value(name, traj, problem.stl_formula, weights)
    base = room_state(context, problem.stl_formula, traj)
    if base is None:
        return traj
    # The room the execution needs (:mod:`.room`) is kept up to what the plan had: an objective
    # must not buy itself with it.
    keep = min(1.0, max(base.room.score, 0.0))
    steps = _RefineSteps(context, problem, name, weights, keep, stats, elapsed)
    end = repair(steps, _Refined(base, value), rounds)
    if name == "effort":
        note_room(stats, end.at.room)
    return end.at.traj


CONVERGED = 0.01
"""The effort refiner stops once its LP promises less than this relative improvement."""

PATIENCE = 2
"""... or after this many rounds in a row without an improvement (the trust region then is a
quarter of where the last improvement was found: what is left is small, measured on the
listing in ``benchmarks/effort_listing.py``)."""


SMOOTH_ROOM_SLACK = 0.2
"""The fraction of its room a smoothing step may lose (the room's dependence on the plan is
linearised in the step's LP; the smoothed plan is judged on the execution target again)."""


SMOOTH_PATIENCE = 4
"""Smoothing stops after this many rounds in a row without an improvement (a sixteenth of the
first trust region: the light-dark plans' room is linearised on their state-dependent noise)."""


@dataclass(frozen=True)
class _Refined:
    """The refiner's state: the plan with its witness and room, and its objective's value."""

    at: RoomState
    value: float


class _RefineSteps:
    """:func:`refine`'s parts of the repair loop (:class:`.repair.RepairSteps`).

    The step's LP is the room LP minimising the effort with the room kept (``"effort"``), or
    the plan LP maximising the margin on the plan's linearised covariances (``"margin"``); a
    step is kept when the monitor accepts it, the objective improved and the room is kept (one
    restoration step may give it back).
    """

    name = "refine"

    def __init__(
        self,
        context: PlanLPContext,
        problem: Problem,
        name: Objective | Literal["smooth"],
        weights: np.ndarray | None,
        keep: float,
        stats: SolveStats,
        elapsed: Callable[[], float],
    ) -> None:
        self.context, self.init, self.formula = context, problem.initial_state, problem.stl_formula
        self.objective, self.weights, self.keep = name, weights, keep
        self.w = _weights(context.system.m, weights)
        self.stats, self.elapsed = stats, elapsed
        # how much of the room a step may lose to the linearisation: smoothing is a tie-break
        # whose plan is judged again on the execution target, so it may lose a fifth
        self.slack = max(1e-3, SMOOTH_ROOM_SLACK * keep) if name == "smooth" else 1e-3

    def done(self, state: _Refined) -> bool:
        return False

    def first_trust(self, state: _Refined) -> float:
        # Wide (a quarter of the plan's extent); the loop halves it after every failed round.
        means = state.at.traj.get_mean()
        extent = float(np.max(means.max(axis=0) - means.min(axis=0)))
        dx = self.context.scaling.dx
        return max(0.25 * extent, 2.0 * state.at.room.largest_need, 1e-3 * float(np.max(dx)))

    def propose(self, state: _Refined, trust: float, left: float) -> np.ndarray | Stop | None:
        at, L = state.at, state.at.plan.length
        controls: np.ndarray | None = None
        if self.objective in ("effort", "smooth"):
            out = room_lp(
                self.context,
                at.plan,
                at.traj,
                at.room,
                trust,
                effort_weights=self.w,
                t_max=self.keep,
                time_limit=left,
                smooth=self.objective == "smooth",
            )
            controls = None if out is None else out[0]
        elif self.objective == "margin":
            region = TrustRegion(at.traj.get_mean()[:L], trust, linearise=True)
            covs = at.traj.get_cov()[:L]
            goal = LPGoal(self.objective)
            lp = solve_plan_lp(
                self.context, at.plan, 0.0, covs=covs, region=region, goal=goal, time_limit=left
            )
            controls = lp.controls if lp.feasible else None
        self.stats.lp_calls += 1
        if controls is not None and self.objective in ("effort", "smooth"):
            if self._value(controls) >= (1.0 - CONVERGED) * state.value:
                return STOP  # a smaller trust region only raises the LP's optimum
        return controls

    def _value(self, controls: np.ndarray) -> float:
        """The input effort, or the total variation under ``"smooth"``."""
        if self.objective == "smooth":
            return total_variation(controls, self.w)
        return _effort(controls, self.w)

    def _of(self, traj: ProbabilisticTSTrajectory) -> float:
        if self.objective == "smooth":
            return total_variation(traj.get_control(), self.w)
        return objective_value(self.objective, traj, self.formula, self.weights)

    def accept(self, state: _Refined, controls: np.ndarray, trust: float) -> _Refined | None:
        name, formula = self.objective, self.formula
        acts = state.at.traj.get_action()
        moved = rollout(self.context.system, self.init, acts[: state.at.plan.length - 1], controls)
        margin = robustness(moved, formula)
        value = self._of(moved)
        # The room may not pay for the objective: it is what the execution needs (the monitor's
        # margin beyond it is not, and keeping it too blocks most effort savings).
        if not (margin >= 0.0 and better(name, value, state.value)):
            return None
        at = room_state(self.context, formula, moved)
        if name in ("effort", "smooth") and at is not None and at.room.score < self.keep - self.slack:
            # The room's dependence on the plan is linearised: one restoration step from the
            # moved plan gives it back (sequential convex programming).
            self.stats.lp_calls += 1
            moved, at = self._restore(moved, at, trust)
            value = self._of(moved)
            margin = robustness(moved, formula)
        ok = margin >= 0.0 and better(name, value, state.value)
        if not (ok and at is not None and at.room.score >= self.keep - self.slack):
            return None
        logger.debug("refine %s: %.4g -> %.4g (trust %.3g)", name, state.value, value, trust)
        if name != "smooth":  # the objective's history (smoothing is no objective)
            self.stats.improvements.append((float(self.elapsed()), value))
        return _Refined(at, value)

    def stuck(self, state: _Refined, failures: int) -> bool:
        if self.objective == "smooth":  # a linearised room needs smaller steps: halve further
            return failures >= SMOOTH_PATIENCE
        return self.objective == "effort" and failures >= PATIENCE

    def _restore(
        self, traj: ProbabilisticTSTrajectory, at: RoomState, trust: float
    ) -> tuple[ProbabilisticTSTrajectory, RoomState | None]:
        """One room LP from ``traj`` (no objective): the plan and its room after it, or ``traj``'s own."""
        out = room_lp(self.context, at.plan, traj, at.room, trust, t_max=self.keep)
        if out is None:
            return traj, at
        moved = rollout(self.context.system, self.init, traj.get_action()[: at.plan.length - 1], out[0])
        if robustness(moved, self.formula) < 0:
            return traj, at
        return moved, room_state(self.context, self.formula, moved)


def _weights(m: int, weights: np.ndarray | None) -> np.ndarray:
    """Per-input effort weights, shape (m,) (all ones by default)."""
    return np.ones(m) if weights is None else np.asarray(weights, dtype=float)


def _effort(controls: np.ndarray, weights: np.ndarray) -> float:
    """``sum_k sum_j w_j |u_kj|`` of controls of shape (K, m): the ``"effort"`` objective."""
    return float(np.sum(np.abs(np.asarray(controls)) @ weights))
