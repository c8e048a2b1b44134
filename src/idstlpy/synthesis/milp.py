"""Eager fallback for plans the LP decides exactly: the BMC encoding and the plan LP as one MILP.

When the covariance schedule does not depend on the mean (no state-dependent noise) and the
system has one mode, the lazy loop (SAT proposes, LP refutes) can need many candidates on
formulas with many disjunctions (obstacle sides, alternative targets). This module hands the same
problem to HiGHS' branch and bound in one piece:

- every SAT variable of the BMC encoding is a 0/1 variable, every clause ``l_1 | ... | l_r`` the
  row ``sum(pos) - sum(neg) >= 1 - |neg|``; the clauses learnt so far (pruning facts and
  counterexamples) come along. Only the letters (propositions, modes, trace length) are declared
  integer: the gates are Tseitin equivalences, integral whenever their inputs are, so branch and
  bound never branches on them (measured once each: SteppingStones T = 100 13.4 s -> 1.7 s,
  ReachAvoid T = 200 3.2 s -> 1.9 s, DoorPuzzle T = 100 unchanged);
- ``p[i, k] = 1`` implies the chance constraints of proposition ``i`` at step ``k`` through big-M
  rows whose ``M`` is the exact largest value of the face over the reachable means (support
  functions of the control domain), so the relaxation is as tight as big-M can be;
- the dynamics, the control domain and the fixed covariance schedule are as in the plan LP.

The encoding keeps the compact windows of :mod:`~idstlpy.synthesis.bmc` (``O(H log b)`` gates), so
the model is much smaller than the usual MILP encodings of STL.

Its ``infeasible`` is a proof for plans of at most ``bound`` steps only when every big-M is
finite and moderate (a bounded control domain, or invariants that bound the means); otherwise
the model is not built (``unsupported``) and the lazy loop goes on. Variables are scaled and
rows normalised as in the plan LP (:mod:`.plan_lp`), so tolerances are relative to the problem.

With an objective the model is a relaxation of the problem (a claimed face holds within the
integrality tolerance times its big-M, never tighter), so its bound is a bound on every plan, and
its ``infeasible`` is re-checked with every face moved out by 1e-6 (:func:`~.milp_solve.recheck`): a plan
there makes the answer ``borderline`` (a tolerance decides it), no proof. With ``"effort"`` and a
control domain that excludes ``u = 0`` the trace length is free and only the steps that exist are
priced (a step after the formula is decided costs input, which a plan need not spend).

With ``objective="margin"`` (largest robustness) the margin ``t`` is a column added to every face
row, and three things make the model fast and its answer a proof:

- ``t`` is capped by the formula's robustness evaluated on upper bounds of every proposition's
  margin (:func:`~.milp_bounds.margin_cap`: sound, so the cap never cuts the optimum), which keeps every
  big-M small and the relaxation's bound at most the cap;
- a feasibility probe with ``t`` at the cap runs first: where the cap is attained (a goal's
  centre reachable) the plan it finds is optimal by the cap alone; where it is not, a ladder of
  feasibility probes, each at the best plan's exact margin plus half the proof tolerance, ends
  with a level SCIP's presolve refutes (:func:`~.milp_solve.solve_margin`);
- the big-M rows have no integrality room, so the model is a relaxation and its bound a bound on
  every plan; the plan's exact margin comes from the LP over its rounded letters
  (:func:`~.milp_solve._polish`), and the optimum is *proven* only when the two meet within ``PROOF_TOL``.

Propositions that exclude each other at a step (the pruning's disjoint pairs) get one clique row
``sum(p) <= 1`` where the exclusion graph is dense (:func:`~.milp_model.exclusion_cliques`), and a plain
feasibility model is solved without cutting planes and without presolve probing (both cost SCIP
more than they save in finding a plan).

The work is split by concept: :mod:`.milp_bounds` (the reachable means' bounds: big-M, the
margin's cap), :mod:`.milp_model` (the model: columns, rows, bounds, cost), :mod:`.milp_solve`
(the phases: feasibility, margin ladder, objective, the re-check of an infeasibility) and this
module (when to switch, and the outcome).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..backends import Backend
from .bmc import BMCEncoder
from .interfaces import Budget
from .milp_model import MILPModel, MILPSpec, build_milp
from .milp_solve import PROOF_TOL, MILPOutcome, recheck, solve_feasibility, solve_margin
from .plan_lp import PlanLPContext

if TYPE_CHECKING:
    from .options import Objective

__all__ = ["MILPOutcome", "solve_milp", "switch_to_eager"]

logger = logging.getLogger(__name__)

_EARLY_WINDOW = 3  # conflicts the early look reads (see ``switch_to_eager``)
_EARLY_MARGIN = 1.0  # ... and by how much their median must exceed ``conflict_size``


def switch_to_eager(
    conflicts: Sequence[Sequence[Any]],
    candidates: int,
    min_candidates: int,
    conflict_size: float,
    early: int = _EARLY_WINDOW,
    early_margin: float = _EARLY_MARGIN,
) -> bool:
    """Whether the lazy loop should hand an LP-exact, single-mode problem to the eager MILP.

    A deterministic rule that follows the lazy loop's convergence (it reads only the proven
    conflicts and the count of candidates, never the clock):

    - ``min_candidates <= 0`` (``SolverOptions.lazy_candidates = 0``): eager at once;
    - *early look*: from ``early`` (3) candidates on, as soon as the median size of the last
      ``early`` conflicts exceeds ``conflict_size + early_margin`` (4 requirements by default):
      the loop's very first conflicts are already large, so it is enumerating combinations
      from the start (PrSTL's noisy reach-avoid 9, 8, 7; NarrowPassage 7, 5, 3; EitherOr,
      RandomMultitarget, SteppingStones, DoorPuzzle 10-140), and each further candidate costs a
      plan LP over the horizon that the MILP does not need; from ``2 * early`` candidates on,
      as soon as that median exceeds ``conflict_size`` itself: the margin is for the first
      candidates only, which the SAT solver proposes before any LP has guided it (their
      conflicts carry whatever the least violation happened to break: the double integrator's
      5, 4, 3); a guided window above ``conflict_size`` is enumeration (ReachAvoid's 3, 4, 4
      after its march to the goal, candidate 9);
    - then, from ``min_candidates`` candidates (``SolverOptions.lazy_candidates``) on, as soon
      as the median size of the last ``min_candidates`` conflicts exceeds ``conflict_size``
      (``SolverOptions.lazy_conflict_size``): large conflicts each exclude little;
      small ones (a step or two at the frontier of reach) mean the loop is converging, so it stays;
    - in any case after ``10 * min_candidates`` candidates.

    ``conflict_size <= 0`` gives the fixed count ``min_candidates`` (no early look).

    The horizon and the model's size are deliberately not read: measured (BENCHMARKS.md,
    Analysis), the one-obstacle double integrator and stlpy's ReachAvoid have the same horizon,
    models of the same size and eager MILPs of the same cost at T = 200 (0.27 s CPU each), yet
    the first converges lazily in 13 candidates and the second would need one candidate per
    step; only the conflicts tell them apart. The double integrator's first conflicts are
    5, 4, 3, then 2 (median 4: it stays lazy); ReachAvoid's are 2 until its candidates reach the
    obstacle, then 3-7 (it switches after 9).

    Parameters
    ----------
    conflicts : sequence of sequences
        The proven conflicts so far, oldest first (``BMCProposer.hard``).
    candidates : int
        Candidates tried so far.
    min_candidates : int
    conflict_size : float
    early : int
        Conflicts the early look reads (at most ``min_candidates``).
    early_margin : float

    Returns
    -------
    bool
    """
    if min_candidates <= 0:
        return True
    if conflict_size <= 0:
        return candidates >= min_candidates
    if candidates >= 10 * min_candidates:
        return True
    sizes = [len(c) for c in conflicts]
    look = min(max(early, 1), min_candidates)
    if candidates >= look and len(sizes) >= look:
        threshold = conflict_size + (early_margin if candidates < 2 * look else 0.0)
        if float(np.median(sizes[-look:])) > threshold:
            return True
    if candidates < min_candidates:
        return False
    recent = sizes[-min_candidates:]
    return not recent or float(np.median(recent)) > conflict_size


def solve_milp(
    enc: BMCEncoder,
    context: PlanLPContext,
    backend: Backend,
    budget: Budget,
    objective: Objective | None = None,
    effort_weights: np.ndarray | None = None,
) -> MILPOutcome:
    """Solve the bounded synthesis problem as one MILP (single mode, mean-independent covariance).

    Parameters
    ----------
    enc : BMCEncoder
        The proposer's current encoding (its proven clauses; abandoned ones are switched off).
    context : PlanLPContext
        The system, control domain, prior, abstraction and units (its LP back-end is not used).
    backend : Backend
        A MILP-capable back-end.
    budget : Budget
    objective : {None, "effort", "margin", "time"}
        ``None``: any feasible plan. ``"effort"``: least ``sum_k sum_j w_j |u_kj|``;
        ``"margin"``: largest robustness (smallest raw slack of the claimed faces);
        ``"time"``: fewest steps (the trace length is free instead of the whole bound).
    effort_weights : ndarray, shape (m,), optional
        Per-input weights of ``"effort"`` (default ones).

    Returns
    -------
    MILPOutcome
        With ``value`` and ``bound`` of the objective when one is given.
    """
    spec = MILPSpec(enc, context, budget, objective, effort_weights)
    built = build_milp(spec)
    if isinstance(built, str):
        return MILPOutcome("unsupported", why=built)
    if built.cols.nt:
        return _margin_outcome(spec, built, backend)
    return _outcome(spec, built, backend)


def _found(spec: MILPSpec, built: MILPModel, x: np.ndarray) -> MILPOutcome:
    """A ``"found"`` outcome of the plan ``x`` (its inputs in problem units, its claims)."""
    enc, H, m = spec.enc, spec.enc.H, spec.context.system.m
    controls = x[built.cols.inputs].reshape(H, m) * spec.context.scaling.du
    claims = np.round(x[enc.p - 1]).astype(bool) if enc.p.size else np.zeros((0, H + 1), bool)
    return MILPOutcome("found", np.zeros(H, dtype=int), controls, claims)


def _margin_outcome(spec: MILPSpec, built: MILPModel, backend: Backend) -> MILPOutcome:
    """The margin MILP's answer: its plan, exact margin and bound, and whether they prove it."""
    tcol, t_cap, t_sound, budget = built.cols.tcol, built.t_cap, built.t_sound, spec.budget
    status, x, exact, bound, message = solve_margin(built.model, backend, tcol, t_cap, t_sound, budget)
    if status == "infeasible":
        return recheck(built.model, backend, budget, built.face_rows)
    if x is None:
        logger.info("MILP stopped: %s", message)
        return MILPOutcome("timeout", why=message)
    plan = x if exact is None else exact  # the same letters; the LP's continuous part is exact
    out = _found(spec, built, plan)
    # The big-M rows of the margin MILP are a relaxation (no integrality room), so every bound
    # it proves holds for every plan; the LP over the rounded letters gives the exact margin of
    # its plan, and the two must meet for a proof.
    out.value, out.bound = float(plan[tcol]), bound
    slack = PROOF_TOL * max(1.0, abs(bound)) if np.isfinite(bound) else 0.0
    out.proven = (
        status == "optimal"
        and exact is not None
        and np.isfinite(bound)
        and out.value >= bound - slack
        and (t_sound or out.value < t_cap * (1 - 1e-9))
    )
    logger.info(
        "MILP margin: %.12g, exact %.12g, bound %.12g, proven %s (%s)",
        float(x[tcol]),
        out.value,
        out.bound,
        out.proven,
        message,
    )
    return out


def _outcome(spec: MILPSpec, built: MILPModel, backend: Backend) -> MILPOutcome:
    """The answer of the feasibility, effort or time MILP."""
    objective, budget = spec.objective, spec.budget
    if objective is None:
        sol = solve_feasibility(built.model, backend, budget)
    else:
        sol = backend.solve(built.model, max(budget.remaining(), 1e-3))
    if sol.status in ("optimal", "time_limit") and sol.x is not None:
        out = _found(spec, built, sol.x)
        out.proven = sol.status == "optimal"
        if objective in ("effort", "time"):
            out.value, out.bound = float(sol.objective), float(sol.bound)
        return out
    if sol.status == "infeasible":
        if objective is None:
            return MILPOutcome("infeasible", why="the MILP is infeasible")
        return recheck(built.model, backend, budget, built.face_rows)
    logger.info("MILP stopped: %s", sol.message)
    return MILPOutcome("timeout", why=sol.message)
