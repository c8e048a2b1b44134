"""Iterative risk allocation for joint chance constraints (after Ono and Williams, 2008).

A joint chance constraint ``P[x in region] >= 1 - eps`` is planned at per-face risks
``eps_f`` (``sum eps_f <= eps``), first the ones :class:`~idstlpy.synthesis.problem.Problem`
chose for its prior (:func:`idstlpy.chance.allocate_shares`). Once a plan is found, it shows
which faces needed their risk: at the steps where the plan meets the constraint, a face whose
largest violation probability is well below its share (*inactive*) gives part of the difference
(half of it) to the faces that use all of theirs (*active*), in proportion to their shares. The
plan found stays feasible under the new shares (the inactive faces keep more than they use, the
active ones get more), so a re-solve can only do better: it is made once, with what is left of
the solve's time cap, and its plan is kept when it is found with a larger monitor margin.

This is a deterministic function of the first result: the same seed gives the same plan.

Refutations under one allocation prove nothing about the others, so the CEGIS loop turns an
``infeasible`` into ``budget_exhausted`` (:data:`NO_PROOF`). :func:`prove_infeasible` then tries
the *necessary relaxation*: every joint constraint replaced by its faces, each alone at the
joint confidence (``P[x in region] >= 1 - eps`` implies ``P[h_f' x + c_f <= 0] >= 1 - eps`` for
every face, and every PrSTL operator is monotone in its propositions). If the relaxed problem is
proven infeasible, so is the original one, and the result says ``infeasible``.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from ..chance import joint_tail_sum, quantile, slack
from ..expressions import JointChanceConstraint, ProbabilisticLinearPredicate
from ..formulas import STLAtomicProposition, STLFormula, map_atoms, map_joints
from .options import SolverOptions
from .results import SolveResult

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = ["NO_PROOF", "after_solve", "prove_infeasible", "reallocate", "refine_allocation", "relax_joints"]

NO_PROOF = (
    " at the planned risk allocation of the joint chance constraints; other allocations were not "
    "refuted, so this is no proof"
)
"""What the CEGIS loop appends to the reason of an ``infeasible`` it downgrades."""

logger = logging.getLogger(__name__)

_INACTIVE = 0.5  # a face using less than this fraction of its share gives risk away
_KEEP = 0.5  # an inactive face keeps this fraction of what it does not use


def _needs(joint: JointChanceConstraint, means: np.ndarray, covs: np.ndarray) -> np.ndarray | None:
    """Per face, its largest violation probability over the steps the plan meets it at its shares."""
    held = np.all(slack(joint.H, joint.c, quantile(joint.shares), means, covs) >= 0, axis=1)
    if not held.any():
        return None
    d = -(means[held] @ joint.H.T + joint.c)
    var = np.einsum("fi,tij,fj->tf", joint.H, covs[held], joint.H)
    sd = np.sqrt(np.maximum(var, 0.0))
    tails = joint_tail_sum(d[..., None], sd[..., None])  # (K, F): each face's own tail
    return np.asarray(np.max(tails, axis=0), dtype=float)


def reallocate(formula: STLFormula, means: np.ndarray, covs: np.ndarray) -> STLFormula:
    """One round of iterative risk allocation on the beliefs ``N(means[k], covs[k])`` of a plan.

    Parameters
    ----------
    formula : STLFormula
        The formula the plan was made for (its joint constraints at their planned shares).
    means : ndarray, shape (L, n)
    covs : ndarray, shape (L, n, n)

    Returns
    -------
    STLFormula
        ``formula`` itself when no joint constraint (that the caller did not fix) has both
        inactive and active faces; otherwise an equal formula with new shares.
    """

    def fn(joint: JointChanceConstraint) -> JointChanceConstraint:
        if joint.fixed or joint.eps <= 0 or joint.num_faces < 2:
            return joint
        need = _needs(joint, means, covs)
        if need is None:
            return joint
        shares = joint.shares
        inactive = need < _INACTIVE * shares
        if inactive.all() or not inactive.any():
            return joint
        new = shares.copy()
        new[inactive] = need[inactive] + _KEEP * (shares[inactive] - need[inactive])
        freed = float(np.sum(shares) - np.sum(new))
        active = ~inactive
        new[active] += freed * shares[active] / float(np.sum(shares[active]))
        return joint.with_shares(np.minimum(new, joint.eps), fixed=False)

    return map_joints(formula, fn)


def refine_allocation(
    problem: Problem,
    options: SolverOptions,
    start: float,
    result: SolveResult,
    solve: Callable[[Problem, SolverOptions, float], SolveResult],
) -> SolveResult:
    """Re-solve once with the risk re-allocated to the faces the found plan needed.

    Only for a ``found`` result without an objective (an objective's optimum is its own
    business) whose formula has joint chance constraints with inactive and active faces.

    Parameters
    ----------
    problem : Problem
    options : SolverOptions
    start : float
        ``time.perf_counter()`` at the first line of the solve: the re-solve gets what is left of
        the time cap.
    result : SolveResult
        The first result.
    solve : callable
        ``solve(problem, options, start) -> SolveResult`` (the CEGIS loop).

    Returns
    -------
    SolveResult
        The re-solve's when it found a plan with a larger margin, else ``result``.
    """
    if result.status != "found" or options.objectives.objective is not None or result.trajectory is None:
        return result
    beliefs = result.predicted if result.predicted is not None else result.trajectory
    formula = reallocate(problem.stl_formula, beliefs.get_mean(), beliefs.get_cov())
    if formula is problem.stl_formula:
        return result
    again = copy.copy(problem)
    again.stl_formula = formula
    second = solve(again, options, start)
    if second.status == "found" and second.margin > result.margin + 1e-12 * (1 + abs(result.margin)):
        logger.info(
            "risk allocation: re-solved with the joint constraints' risk on the faces the first "
            "plan needed; margin %.4g -> %.4g",
            result.margin,
            second.margin,
        )
        second.reason += (
            f"; the joint chance constraints' risk re-allocated to the faces the first plan "
            f"needed (margin {result.margin:.4g} -> {second.margin:.4g}; the first solve took "
            f"{result.stats.candidates} candidates)"
        )
        return second
    return result


def relax_joints(formula: STLFormula) -> STLFormula:
    """The necessary relaxation: each joint constraint's faces, each alone at its confidence.

    Parameters
    ----------
    formula : STLFormula

    Returns
    -------
    STLFormula
        Without joint constraints; implied by ``formula`` on every trajectory.
    """

    def atom(ap: STLAtomicProposition) -> STLAtomicProposition:
        if not ap.joints:
            return ap
        faces = [
            ProbabilisticLinearPredicate(h, float(c), j.variable, j.eps)
            for j in ap.joints
            for h, c in zip(j.H, j.c, strict=True)
        ]
        return STLAtomicProposition([*ap.predicates[: ap.num_single], *faces], ap.modes, name=ap.name)

    return map_atoms(formula, atom)


def prove_infeasible(
    problem: Problem,
    options: SolverOptions,
    start: float,
    result: SolveResult,
    solve: Callable[[Problem, SolverOptions, float], SolveResult],
) -> SolveResult:
    """Turn a downgraded ``infeasible`` into a proof when the necessary relaxation is infeasible.

    Parameters
    ----------
    problem : Problem
    options : SolverOptions
    start : float
        ``time.perf_counter()`` at the first line of the solve (the relaxed solve gets what is left
        of the time cap).
    result : SolveResult
        The first result: acted on only when it is a ``budget_exhausted`` the CEGIS loop
        downgraded from ``infeasible`` (its reason ends with :data:`NO_PROOF`).
    solve : callable
        ``solve(problem, options, start) -> SolveResult`` (the CEGIS loop).

    Returns
    -------
    SolveResult
        ``infeasible`` (the relaxed solve's proof and statistics, the original formula) or
        ``result``.
    """
    if result.status != "budget_exhausted" or not result.reason.endswith(NO_PROOF):
        return result
    relaxed = copy.copy(problem)
    relaxed.stl_formula = relax_joints(problem.stl_formula)
    second = solve(relaxed, options, start)
    if second.status != "infeasible":
        return result
    logger.info("joint chance constraints: the necessary relaxation is infeasible, a proof")
    return dataclasses.replace(
        second,
        formula=result.formula,
        reason=(
            f"{second.reason} (proven on the necessary relaxation: every face of each joint "
            "chance constraint alone at its confidence)"
        ),
    )


def after_solve(
    problem: Problem,
    options: SolverOptions,
    start: float,
    result: SolveResult,
    solve: Callable[[Problem, SolverOptions, float], SolveResult],
) -> SolveResult:
    """What a solve with joint chance constraints does after the CEGIS loop.

    A found plan gets one round of risk re-allocation (:func:`refine_allocation`); a downgraded
    ``infeasible`` is tried on the necessary relaxation (:func:`prove_infeasible`).

    Parameters
    ----------
    problem, options, start, result, solve
        As in :func:`refine_allocation`.

    Returns
    -------
    SolveResult
    """
    if result.status == "found":
        return refine_allocation(problem, options, start, result, solve)
    return prove_infeasible(problem, options, start, result, solve)
