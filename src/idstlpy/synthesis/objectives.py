"""What "a good plan" means: the objectives a solve can optimise, and the anytime refiner.

- ``"effort"``: ``sum_k sum_j w_j |u_kj|`` (lower is better; per-input weights ``w``);
- ``"time"``: the plan's number of steps (its transitions; lower is better): a plan of ``N``
  transitions decides the formula true by step ``N``;
- ``"margin"``: the monitor's robustness (higher is better), stlpy's robustness mode for PrSTL.

On the eager MILP's path (one mode, no state-dependent noise) the optimum is exact over every
plan within the horizon, for the problem as stated (no execution margin, idle steps free; see
:mod:`.milp` and ``cegis._retime``), and ``optimal=True`` only within 1e-6 of its proven bound
(issue 25). On the sampler path the plan is refined by sequential convex programming: freeze
the exact covariances of the current plan, solve the plan LP for the objective with the means
kept within a trust region, re-roll the exact belief dynamics, keep the result only if the
monitor still accepts it, the objective improved and the plan keeps the execution room
(:mod:`.room`) it had (up to all of it); the trust region halves after a round that did not
help. The rounds are a work budget (``SolverOptions.polish_rounds``), so the result is
reproducible.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..belief import rollout
from ..semantics import robustness
from ..trajectory import ProbabilisticTSTrajectory
from .abstraction import Abstraction
from .plan import DiscretePlan, trajectory_plan
from .plan_lp import Scaling
from .results import SolveStats
from .room import Room, execution_room, note_room, room_lp
from .teacher import solve_plan_lp

__all__ = ["OBJECTIVES", "better", "objective_value", "refine"]

logger = logging.getLogger(__name__)

OBJECTIVES: tuple[str, ...] = ("effort", "time", "margin")


def objective_value(
    name: str, traj: ProbabilisticTSTrajectory, formula: Any, weights: np.ndarray | None = None
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


def better(name: str, a: float, b: float) -> bool:
    """Whether value ``a`` improves on ``b`` (by more than a relative 1e-9).

    Parameters
    ----------
    name : str
        The objective: ``"margin"`` is maximised, every other objective minimised.
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
    problem: Any,
    abstraction: Abstraction,
    scaling: Scaling,
    traj: ProbabilisticTSTrajectory,
    name: str,
    weights: np.ndarray | None,
    rounds: int,
    stats: SolveStats,
    elapsed: Any,
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
    system, init, formula = problem.switched_system, problem.initial_state, problem.stl_formula
    domain = problem.control_domain
    best = objective_value(name, traj, formula, weights)
    base = _room(problem, abstraction, traj)
    # The room the execution needs (:mod:`.room`) is kept up to what the plan had: an objective
    # must not buy itself with it.
    keep = min(1.0, max(base[1].score, 0.0)) if base is not None else 0.0
    trust = None
    # The room of the current plan: computed once per accepted plan (each evaluation predicts
    # the closed loop, the refiner's largest cost after its LPs).
    current = base
    failed = 0
    w = _weights(system.m, weights)
    for _ in range(rounds):
        if current is None:
            break
        plan, room = current
        means = traj.get_mean()
        if trust is None:
            # Start wide (a quarter of the plan's extent) and halve after every failed round.
            extent = float(np.max(means.max(axis=0) - means.min(axis=0)))
            trust = max(0.25 * extent, 2.0 * room.largest_need, 1e-3 * float(np.max(scaling.dx)))
        L = plan.length
        controls: np.ndarray | None = None
        if name == "effort":
            out = room_lp(
                system,
                domain,
                init,
                abstraction,
                plan,
                traj,
                room,
                trust,
                scaling,
                effort_weights=w,
                t_max=keep,
            )
            controls = None if out is None else out[0]
        else:
            lp = solve_plan_lp(
                system,
                domain,
                init.mean,
                init.cov,
                abstraction,
                plan,
                0.0,
                covs=traj.get_cov()[:L],
                anchor=means[:L],
                trust=trust,
                scaling=scaling,
                objective=name,
                linearise=True,
            )
            controls = lp.controls if lp.feasible else None
        stats.lp_calls += 1
        if controls is not None and name == "effort" and _effort(controls, w) >= (1.0 - CONVERGED) * best:
            # A smaller trust region only raises the LP's optimum: nothing left to gain here.
            break
        if controls is not None:
            acts = traj.get_action()
            moved = rollout(system, init, acts[: L - 1], controls)
            margin = robustness(moved, formula)
            value = objective_value(name, moved, formula, weights)
            # The room may not pay for the objective: it is what the execution needs (the
            # monitor's margin beyond it is not, and keeping it too blocks most effort savings).
            if margin >= 0.0 and better(name, value, best):
                moved_room = _room(problem, abstraction, moved)
                if name == "effort" and moved_room is not None and moved_room[1].score < keep - 1e-3:
                    # The room's dependence on the plan is linearised: one restoration step
                    # from the moved plan gives it back (sequential convex programming).
                    stats.lp_calls += 1
                    moved, moved_room = _restore(
                        problem, abstraction, scaling, moved, moved_room, trust, keep
                    )
                    value = objective_value(name, moved, formula, weights)
                    margin = robustness(moved, formula)
                ok = margin >= 0.0 and better(name, value, best)
                if ok and moved_room is not None and moved_room[1].score >= keep - 1e-3:
                    logger.debug("refine %s: %.4g -> %.4g (trust %.3g)", name, best, value, trust)
                    traj, best, current = moved, value, moved_room
                    stats.improvements.append((float(elapsed()), value))
                    failed = 0
                    continue
        failed += 1
        if name == "effort" and failed >= PATIENCE:
            break
        trust *= 0.5
    if current is not None and name == "effort":
        note_room(stats, current[1])
    return traj


CONVERGED = 0.01
"""The effort refiner stops once its LP promises less than this relative improvement."""

PATIENCE = 2
"""... or after this many rounds in a row without an improvement (the trust region then is a
quarter of where the last improvement was found: what is left is small, measured on the
listing in ``benchmarks/effort_listing.py``)."""


def _weights(m: int, weights: np.ndarray | None) -> np.ndarray:
    """Per-input effort weights, shape (m,) (all ones by default)."""
    return np.ones(m) if weights is None else np.asarray(weights, dtype=float)


def _effort(controls: np.ndarray, weights: np.ndarray) -> float:
    """``sum_k sum_j w_j |u_kj|`` of controls of shape (K, m): the ``"effort"`` objective."""
    return float(np.sum(np.abs(np.asarray(controls)) @ weights))


def _restore(
    problem: Any,
    abstraction: Abstraction,
    scaling: Scaling,
    traj: ProbabilisticTSTrajectory,
    current: tuple[DiscretePlan, Room],
    trust: float,
    keep: float,
) -> tuple[ProbabilisticTSTrajectory, tuple[DiscretePlan, Room] | None]:
    """One room LP from ``traj`` (no objective): the plan and room after it, or ``traj``'s own."""
    system, init = problem.switched_system, problem.initial_state
    plan, room = current
    domain = problem.control_domain
    out = room_lp(system, domain, init, abstraction, plan, traj, room, trust, scaling, t_max=keep)
    if out is None:
        return traj, current
    moved = rollout(system, init, traj.get_action()[: plan.length - 1], out[0])
    if robustness(moved, problem.stl_formula) < 0:
        return traj, current
    return moved, _room(problem, abstraction, moved)


def _room(
    problem: Any, abstraction: Abstraction, traj: ProbabilisticTSTrajectory
) -> tuple[DiscretePlan, Room] | None:
    """The requirements ``traj`` meets (its earliest witness) and its execution room, or None."""
    plan = trajectory_plan(problem.stl_formula, abstraction, traj)
    if plan is None:
        return None
    room = execution_room(problem.switched_system, problem.control_domain, abstraction, plan, traj)
    return None if room is None else (plan, room)
