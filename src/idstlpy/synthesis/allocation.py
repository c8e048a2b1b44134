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
``infeasible`` that rests on a refuted candidate or a MILP into ``budget_exhausted``
(:data:`NO_PROOF`); LP pruning's own proofs do not depend on the allocation (mean regions, each
joint face alone at its ``eps``, step-0 labels read by Boole's bound) and stand.

Any other result without a plan goes to :func:`search_allocation`. It solves the *necessary
relaxation* first: every joint constraint replaced by its faces, each alone at the joint
confidence (``P[x in region] >= 1 - eps`` implies ``P[h_f' x + c_f <= 0] >= 1 - eps`` for every
face, and every PrSTL operator is monotone in its propositions). If the relaxed problem is
proven infeasible, so is the original one, and the result says ``infeasible``.

Otherwise the relaxation's plan is evidence of where a plan runs (its modes, the requirements
of its witness). Per plan, two allocations are tried, each by solving the original problem
again at those shares: the one of :func:`~.joint_lp.allocation_for_plan` (an LP over that plan's
modes and requirements that optimises every step's per-face risks with the controls, under a
sound piecewise-linear bound of the Gaussian tail; each face then gets the largest risk it used),
then shares in proportion to the largest violation probability each face has on the relaxed
plan itself (:func:`proportional_shares`). When both fail, the relaxation is tightened (every
face alone at ``eps / 2``, ``eps / 4``, ... down to ``eps / F``, where a plan is one at equal
shares) for another plan, and the rounds repeat: at most ``2 (1 + ceil(log2 F))`` solves beyond
the relaxations, within what is left of the solve's time cap (a safety cap: the rounds are
counted, so the same seed gives the same answer). Any plan returned was found and checked on
the original formula (the monitor reads every joint constraint by Boole's bound); the
relaxation's own plans are evidence, never an answer.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from ..chance import joint_tail_sum, quantile, slack
from ..expressions import JointChanceConstraint, ProbabilisticLinearPredicate
from ..formulas import STLAtomicProposition, STLFormula, map_atoms, map_joints
from .joint_lp import allocation_for_plan
from .options import SolverOptions
from .results import SolveResult

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = [
    "NO_PROOF",
    "proportional_shares",
    "reallocate",
    "refine_allocation",
    "relax_joints",
    "search_allocation",
]

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


def relax_joints(formula: STLFormula, scale: float = 1.0) -> STLFormula:
    """The necessary relaxation: each joint constraint's faces, each alone at its confidence.

    Parameters
    ----------
    formula : STLFormula
    scale : float, default 1
        Each face alone at ``scale * eps``: ``1`` is implied by ``formula`` (a necessary
        relaxation); ``1 / F`` implies the joint constraint of ``F`` faces (equal shares).

    Returns
    -------
    STLFormula
        Without joint constraints; implied by ``formula`` on every trajectory when ``scale = 1``.
    """

    def atom(ap: STLAtomicProposition) -> STLAtomicProposition:
        if not ap.joints:
            return ap
        faces = [
            ProbabilisticLinearPredicate(h, float(c), j.variable, j.eps * scale)
            for j in ap.joints
            for h, c in zip(j.H, j.c, strict=True)
        ]
        return STLAtomicProposition([*ap.predicates[: ap.num_single], *faces], ap.modes, name=ap.name)

    return map_atoms(formula, atom)


_FLOOR = 1e-6  # no face gets less than this fraction of eps (a zero share needs zero variance)


def proportional_shares(formula: STLFormula, means: np.ndarray, covs: np.ndarray, scale: float) -> STLFormula:
    """Shares in proportion to what each face needs on a plan of the relaxation at ``scale``.

    Per joint constraint (not fixed by the caller): at the steps where every face meets
    ``scale * eps`` alone (where the relaxed plan may use the constraint), each face's largest
    violation probability ``u_f``; the shares are ``eps * u_f / sum u``, each at least
    ``1e-6 eps``. A plan that meets the constraint at those steps with ``sum u <= eps`` meets
    every face at these shares.

    Parameters
    ----------
    formula : STLFormula
        The original formula (its joint constraints).
    means : ndarray, shape (L, n)
    covs : ndarray, shape (L, n, n)
        The relaxed plan's beliefs.
    scale : float
        The relaxation's level (each face alone at ``scale * eps``).

    Returns
    -------
    STLFormula
        ``formula`` itself when no shares changed.
    """

    def fn(joint: JointChanceConstraint) -> JointChanceConstraint:
        if joint.fixed or joint.eps <= 0 or joint.num_faces < 2:
            return joint
        d = -(means @ joint.H.T + joint.c)
        sd = np.sqrt(np.maximum(np.einsum("fi,tij,fj->tf", joint.H, covs, joint.H), 0.0))
        tails = joint_tail_sum(d[..., None], sd[..., None])  # (L, F): each face alone
        used = np.all(tails <= scale * joint.eps, axis=1)
        if not used.any():
            return joint
        need = np.maximum(np.max(tails[used], axis=0), _FLOOR * joint.eps)
        shares = joint.eps * need / float(np.sum(need))
        if np.allclose(shares, joint.shares, rtol=1e-9, atol=0.0):
            return joint
        return joint.with_shares(shares, fixed=False)

    return map_joints(formula, fn)


def _has_free_joint(formula: STLFormula) -> bool:
    return any(not j.fixed and j.num_faces > 1 for ap in formula.atomic_propositions() for j in ap.joints)


def search_allocation(
    problem: Problem,
    options: SolverOptions,
    start: float,
    result: SolveResult,
    solve: Callable[[Problem, SolverOptions, float], SolveResult],
) -> SolveResult:
    """After a solve with joint constraints that found nothing: prove, or find another allocation.

    The necessary relaxation first (:func:`relax_joints`): infeasible there is a proof for the
    original problem. Then rounds of :func:`proportional_shares` on the plans of relaxations at
    ``eps``, ``eps / 2``, ... ``eps / F`` (the most faces of any joint constraint), each followed by
    a solve of the original problem at the new shares; the first plan found is returned. The
    rounds stop at the solve's time cap (what is left of it) or when a relaxation finds no plan.

    Parameters
    ----------
    problem, options, start, result, solve
        As in :func:`refine_allocation`.

    Returns
    -------
    SolveResult
        ``infeasible`` (the relaxation's proof), the first ``found`` at another allocation, or
        ``result`` with its reason saying how many allocations were tried.
    """
    if result.status in ("found", "infeasible"):
        return result
    base = problem.stl_formula
    faces = max((j.num_faces for ap in base.atomic_propositions() for j in ap.joints), default=1)
    scales = [1.0]
    while scales[-1] / 2 > 1.0 / faces:
        scales.append(scales[-1] / 2)
    if faces > 1 and scales[-1] > 1.0 / faces:
        scales.append(1.0 / faces)
    tried: list[STLFormula] = [base]
    rounds = 0
    for scale in scales:
        if time.perf_counter() - start >= options.total_time_cap:  # a safety cap: the rounds are few
            break
        relaxed = copy.copy(problem)
        relaxed.stl_formula = relax_joints(base, scale)
        evidence = solve(relaxed, options, start)
        if scale == 1.0 and evidence.status == "infeasible":
            logger.info("joint chance constraints: the necessary relaxation is infeasible, a proof")
            return dataclasses.replace(
                evidence,
                formula=result.formula,
                reason=(
                    f"{evidence.reason} (proven on the necessary relaxation: every face of each "
                    "joint chance constraint alone at its confidence)"
                ),
            )
        if evidence.status != "found" or evidence.trajectory is None or not _has_free_joint(base):
            break
        beliefs = evidence.predicted if evidence.predicted is not None else evidence.trajectory
        choices = [
            (
                "optimised in an LP over the relaxed plan's modes and requirements",
                allocation_for_plan(problem, relaxed.stl_formula, evidence.trajectory),
            ),
            (
                "in proportion to what the relaxed plan's faces needed",
                proportional_shares(base, beliefs.get_mean(), beliefs.get_cov(), scale),
            ),
        ]
        for how, formula in choices:
            if formula is None or any(formula is f for f in tried):
                continue
            if time.perf_counter() - start >= options.total_time_cap:
                break
            tried.append(formula)
            rounds += 1
            again = copy.copy(problem)
            again.stl_formula = formula
            second = solve(again, options, start)
            if second.status == "found":
                logger.info("risk allocation: found at allocation %d (relaxation at %.3g eps)", rounds, scale)
                second.reason += (
                    f"; the joint chance constraints' risk {how} (a plan of the relaxation with each "
                    f"face alone at {scale:.3g} eps), after {rounds} allocation(s) beyond the first"
                )
                return second
    if rounds:
        result = dataclasses.replace(
            result,
            reason=(
                f"{result.reason}; {rounds} other allocation(s) tried, from plans of the relaxation, "
                "found none"
            ),
        )
    return result
