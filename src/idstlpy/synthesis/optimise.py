"""Optimisation of a verified plan for the solve's objective, and what the result claims about it.

Anytime: the first verified plan is kept unless a better one passes the final check. Where the
plan came from decides how it is improved and what can be proven:

- the eager MILP (:class:`~.eager.MILPProof`): optimal within its bound, over its scope;
- the plan LP (exact for its discrete plan): ``"time"`` is optimal when no candidate was
  abandoned (shortest first); ``"effort"`` and ``"margin"`` ask the eager MILP for the optimum over
  the horizon on a single-mode problem;
- the belief-space sampler: trust-region refinement (:func:`~.objectives.refine`), no claim.

``optimal=True`` only when the returned plan's value is within :data:`OPTIMALITY_TOL` of a proven
bound (issue 25).
"""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np

from ..belief import rollout
from ..semantics import robustness
from ..trajectory import ProbabilisticTSTrajectory
from .context import SolveContext, Verified
from .eager import EagerMILP, MILPProof
from .final_check import final_check
from .finish import ObjectiveClaim, finish
from .interfaces import BudgetExceeded
from .objectives import better, objective_value, refine, smooth, total_variation
from .options import Objective
from .results import PredictedExecution, SolveResult

__all__ = ["OPTIMALITY_TOL", "Source", "optimise"]

logger = logging.getLogger(__name__)

OPTIMALITY_TOL = 1e-6
"""``optimal=True`` only when ``|value - bound| <= OPTIMALITY_TOL * max(1, |value|)`` (the
result's ``gap``), with the bound proven over the result's ``optimal_scope``."""

Source = MILPProof | Literal["lp", "sampler"]
"""Where a verified plan came from: the eager MILP (with its proof), the plan LP or the sampler."""


def optimise(ctx: SolveContext, first: Verified, how: str, source: Source, milp: EagerMILP) -> SolveResult:
    """The solve's result for the verified plan ``first``, optimised for the objective if any.

    Parameters
    ----------
    ctx : SolveContext
    first : Verified
        The loop's verified plan.
    how : str
        How it was found (the result's reason).
    source : MILPProof or {"lp", "sampler"}
        Where it came from (see the module docstring).
    milp : EagerMILP
        For the optimum over the horizon and the bounds it proved.
    """
    name = ctx.options.objective
    if name is None:
        return finish(ctx, "found", how, _smoothed(ctx, first))
    # The first plan's predicted execution: an optimised plan must not lose a target it meets.
    first_meets = ctx.target.judge(first.traj).meets_target
    traj, claim, improved = _improve(ctx, first.traj, name, how, source, milp)
    final = final_check(ctx, traj)
    why = "failed the closed-loop check"
    if final is not None and ctx.execution and traj is not first.traj:
        if first_meets and not ctx.target.judge(traj).meets_target:
            final = None  # the optimised plan lost the execution target the first plan met
            why = "missed the execution target the first plan meets"
    unimproved = final is None or traj is first.traj
    if unimproved and ctx.execution and source == "lp" and name in ("effort", "margin"):
        # The problem's optimum (no execution room) lost the target: the objective improves
        # the first plan instead with its execution room kept (issue 34: "effort" returned a
        # plan at 31.6% / 53.5% where the default's met the target).
        kept = _refined_with_room(ctx, first, name, first_meets)
        if kept is not None:
            note = f": the problem's optimum {why})" if final is None else ")"
            traj, final = kept.traj, kept
            claim = ObjectiveClaim(name, objective_value(name, traj, ctx.formula, ctx.weights))
            improved = f"{how} (the first plan optimised with its execution room kept{note}"
    if final is None:
        # The optimiser works on the MLO belief; its plan may lose the closed-loop promise (or
        # the execution target) the first plan had: keep that one.
        logger.info("the optimised plan %s: the first plan is kept", why)
        traj, final = first.traj, final_check(ctx, first.traj)
        claim = ObjectiveClaim(name, objective_value(name, traj, ctx.formula, ctx.weights))
        improved = how + f" (the optimised plan {why}: the first plan is returned, not optimised)"
    claim = _settle(claim, milp.proven_bound)
    # The plan as optimised (not final_check's re-roll of it: the same numbers, and the object
    # whose predicted execution is remembered).
    plan = Verified(traj, robustness(traj, ctx.formula), None) if final is None else final._replace(traj=traj)
    return finish(ctx, "found", improved, plan, claim)


def _refined_with_room(
    ctx: SolveContext, first: Verified, name: Objective, first_meets: bool
) -> Verified | None:
    """``first`` optimised for ``name`` by the trust-region refiner (the execution room kept,
    :func:`~.objectives.refine`), when that improved it, passes the final check and meets the
    execution target whenever ``first`` does; else None."""
    if ctx.options.termination.first_found:
        return None
    rounds = max(ctx.options.polish_rounds, 4) * 2
    try:
        traj = refine(
            ctx.problem, ctx.abstraction, ctx.units, first.traj, name, ctx.weights, rounds, ctx.stats,
            ctx.budget.elapsed,
        )  # fmt: skip
    except BudgetExceeded:
        ctx.stats.caps_hit.append("time_limit")
        return None
    if traj is first.traj:
        return None
    final = final_check(ctx, traj)
    if final is None or (first_meets and not ctx.target.judge(final.traj).meets_target):
        return None
    return final


SMOOTH_ROUNDS = 6
"""LP rounds of the default plan's smoothing (:func:`~.objectives.smooth`): a work budget."""
SMOOTH_BLENDS = (1.0, 0.5, 0.25)
"""The blends of the first plan's controls toward the smoothed ones tried, in order."""


def _smoothed(ctx: SolveContext, first: Verified) -> Verified:
    """The default plan with less input change, when that passes everything ``first`` passed.

    Among the plans that satisfy the formula and the target the default prefers small input
    changes (issue 34: plans zig-zagged and chattered where nothing preferred a smooth one): the
    smoothed plan (:func:`~.objectives.smooth`: the same modes and requirements, the execution
    room kept) replaces ``first`` only when it passes the final check and, under the execution
    guarantee, holds as well (:func:`_holds_as_well`); otherwise ``first`` is returned
    unchanged. Skipped under ``first_found`` (the first plan is the answer) and ``smooth=False``.
    """
    if ctx.options.termination.first_found or not ctx.options.smooth:
        return first
    before = total_variation(first.traj.get_control())
    try:
        traj = smooth(ctx.problem, ctx.abstraction, ctx.units, first.traj, SMOOTH_ROUNDS, ctx.stats)
    except BudgetExceeded:
        ctx.stats.caps_hit.append("time_limit")
        return first
    if traj is first.traj:
        return first
    # The smoothed controls may give up some of the execution room the first plan had (its
    # dependence on the plan is linearised): the blends u0 + a (u1 - u0) are tried, smoothest
    # first; their total variation is at most (1 - a) TV(u0) + a TV(u1) (convexity).
    # (the smoothed plan may end earlier: at the earliest step its requirements are met)
    u1 = traj.get_control()
    K = u1.shape[0]
    u0, acts = first.traj.get_control()[:K], first.traj.get_action()[:K]
    before_ex = ctx.target.judge(first.traj) if ctx.execution else None
    system, init = ctx.problem.switched_system, ctx.problem.initial_state
    for a in SMOOTH_BLENDS:
        blend = traj if a == 1.0 else rollout(system, init, acts, u0 + a * (u1 - u0))
        final = final_check(ctx, blend)
        if final is None:
            continue
        if before_ex is not None and not _holds_as_well(before_ex, ctx.target.judge(final.traj)):
            continue
        logger.info(
            "smoothed the plan (blend %.2g): input total variation %.4g -> %.4g",
            a,
            before,
            total_variation(final.traj.get_control()),
        )
        return final
    logger.info("no smoothed plan kept the final check and the execution target: the first is kept")
    return first


SMOOTH_SUCCESS_SLACK = 0.005
"""A smoothed plan may predict at most this much less success than the first on either reading
(half a point: the precision of the reported estimates), and must meet the target the first meets."""


def _holds_as_well(first: PredictedExecution, smoothed: PredictedExecution) -> bool:
    """Whether the smoothed plan's predicted execution is as good as the first's: the target met
    whenever the first meets it, and neither rate lower by more than :data:`SMOOTH_SUCCESS_SLACK`
    (a tie-break must not buy smoothness with success)."""
    if first.meets_target and not smoothed.meets_target:
        return False
    return (
        smoothed.belief_estimate >= first.belief_estimate - SMOOTH_SUCCESS_SLACK
        and smoothed.state_estimate >= first.state_estimate - SMOOTH_SUCCESS_SLACK
    )


def _improve(
    ctx: SolveContext,
    traj: ProbabilisticTSTrajectory,
    name: Objective,
    how: str,
    source: Source,
    milp: EagerMILP,
) -> tuple[ProbabilisticTSTrajectory, ObjectiveClaim, str]:
    """The optimised plan, its objective claim (before :func:`_settle`) and its reason."""
    stats, weights = ctx.stats, ctx.weights
    first_found = ctx.options.termination.first_found  # the first plan is the answer: no search
    value = objective_value(name, traj, ctx.formula, weights)
    stats.improvements.append((ctx.budget.elapsed(), value))
    claim = ObjectiveClaim(name, value)
    try:
        if isinstance(source, MILPProof):
            claim = ObjectiveClaim(name, value, source.bound, source.proven, source.scope)
        elif source == "lp" and name == "time":
            if stats.abandoned == 0:
                claim = ObjectiveClaim(name, value, value, True, "shortest first")
        elif source == "lp":
            # The plan LP's optimum is over the controls of one set of requirements, with the
            # execution margin kept: no claim about the problem (issue 25).
            if ctx.problem.switched_system.num_modes == 1 and not first_found:
                traj, claim, how = _global(ctx, traj, claim, how, milp)
        elif not first_found:
            rounds = max(ctx.options.polish_rounds, 4) * 2
            traj = refine(
                ctx.problem,
                ctx.abstraction,
                ctx.units,
                traj,
                name,
                weights,
                rounds,
                stats,
                ctx.budget.elapsed,
            )
            claim = ObjectiveClaim(name, objective_value(name, traj, ctx.formula, weights))
    except BudgetExceeded:
        stats.caps_hit.append("time_limit")
        how += " (the time limit stopped the optimisation: the best plan so far)"
    return traj, claim, how


def _global(
    ctx: SolveContext, traj: ProbabilisticTSTrajectory, claim: ObjectiveClaim, how: str, milp: EagerMILP
) -> tuple[ProbabilisticTSTrajectory, ObjectiveClaim, str]:
    """The eager MILP's optimum over the horizon, when better than ``traj``; proven optimal
    when the MILP proved it over the whole horizon."""
    name = claim.name
    found = milp.optimum(name)
    if found is None:
        return traj, claim, how
    new_traj, proven, new_bound, horizon = found
    new_value = objective_value(name, new_traj, ctx.formula, ctx.weights)
    if better(name, new_value, claim.value):
        traj, claim = new_traj, claim._replace(value=new_value)
        ctx.stats.improvements.append((ctx.budget.elapsed(), new_value))
        how = "the eager MILP chose the plan, the LP timed it, the monitor agrees"
    if proven and horizon:
        claim = claim._replace(optimal=True, scope="horizon", bound=new_bound)
    return traj, claim, how


def _settle(claim: ObjectiveClaim, proven: tuple[float, str] | None) -> ObjectiveClaim:
    """The claim about the returned plan: a bound the eager MILP proved over a scope stands for
    it when it has none of its own; the bound is never on the wrong side of the value; optimal
    only within :data:`OPTIMALITY_TOL` of the bound."""
    name, value, bound, optimal, scope = claim
    if not np.isfinite(bound) and proven is not None:
        # The eager MILP's plan was not returned (below the execution target, or a repair moved
        # it), but its proven bound holds for every plan of its scope, the returned one included.
        bound, scope = proven
        bound = max(bound, value) if name == "margin" else min(bound, value)
        optimal = abs(value - bound) <= OPTIMALITY_TOL * max(1.0, abs(value))
    if np.isfinite(bound):
        # The MILP's bound is on its own model, within the solver's tolerances; the verified plan
        # is a bound too, so the reported one is never on the wrong side of the value.
        bound = max(bound, value) if name == "margin" else min(bound, value)
    if optimal and not (np.isfinite(bound) and abs(value - bound) <= OPTIMALITY_TOL * max(1.0, abs(value))):
        # A proof is about the MILP's model; the claim is about the returned plan, which may
        # miss it (re-timed on fewer requirements, repaired for the closed loop): only a plan
        # within the tolerance of the proven bound is called optimal (issue 25).
        logger.info("objective %s: value %.12g vs bound %.12g: not claimed optimal", name, value, bound)
        optimal = False
    return ObjectiveClaim(name, value, bound, optimal, scope)
