"""The solve's result, built once (:func:`finish`): status, reason, plan, prediction, objective.

Every way the loop ends comes here with what it knows, and the :class:`~.results.SolveResult` is
made in one piece: a ``found`` plan gets its predicted execution (and an
:class:`~idstlpy.errors.ExecutionTargetWarning` when that is below target), a search that ends
without a plan returns the best plan set aside below the execution target when there is one, an
``infeasible`` that is no proof under the guarantee (or the risk allocation) becomes
``budget_exhausted``, and a ``budget_exhausted`` says what to raise and shows the closest
partial plan.
"""

from __future__ import annotations

import copy
import logging
import os
import sys
import warnings
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ..belief import rollout
from ..errors import ExecutionTargetWarning
from .advice import budget_advice, floorless_modes
from .allocation import NO_PROOF
from .context import PREDICT_SAMPLES, SolveContext, Verified, plan_key
from .interfaces import BudgetExceeded
from .objectives import objective_value
from .options import Objective
from .results import PredictedExecution, SolveResult, Status

if TYPE_CHECKING:
    from ..trajectory import ProbabilisticTSTrajectory

__all__ = ["ObjectiveClaim", "finish"]

logger = logging.getLogger(__name__)


class ObjectiveClaim(NamedTuple):
    """What a result says about the objective: its value and, where proven, a bound.

    ``bound`` is proven over ``scope`` (``nan``: none); ``optimal`` only when the value is within
    the tolerance of it (:data:`.optimise.OPTIMALITY_TOL`).
    """

    name: Objective
    value: float
    bound: float = float("nan")
    optimal: bool = False
    scope: str = ""


def finish(
    ctx: SolveContext,
    status: Status,
    reason: str,
    plan: Verified | None = None,
    claim: ObjectiveClaim | None = None,
    certificate: dict[str, Any] | None = None,
) -> SolveResult:
    """The solve's :class:`~.results.SolveResult` (see the module docstring).

    Parameters
    ----------
    ctx : SolveContext
    status : {"found", "infeasible", "budget_exhausted"}
        As the loop ended (a plan set aside may turn it into ``found``).
    reason : str
    plan : Verified, optional
        The plan found (``status == "found"``).
    claim : ObjectiveClaim, optional
        The found plan's objective (the optimiser's).
    certificate : dict, optional
        The certificate of an ``infeasible`` (:mod:`.proofs`); kept only when the result stays
        ``infeasible``, whose reason then says when it is not certified.
    """
    stats = ctx.stats
    below = ctx.target.below if status != "found" else None
    if below is not None:
        # Under "execution": no plan met the target, but a verified one was set aside.
        reason = (
            f"no plan met the execution target {ctx.options.execution_target} before the search "
            f"stopped ({reason}); the best verified plan is returned"
        )
        status, plan = "found", below
        name = ctx.options.objective
        if name is not None:  # the plan set aside: its objective's value, no optimality claimed
            claim = ObjectiveClaim(name, objective_value(name, below.traj, ctx.formula, ctx.weights))
    stats.time_total = ctx.budget.elapsed()
    if status != "found":
        status, reason = _unfound(ctx, status, reason)
    if status != "infeasible":
        certificate = None
    elif certificate is None or not certificate.get("certified"):
        why = "no certificate was made" if certificate is None else str(certificate.get("summary", ""))
        reason += f"; this proof is not certified ({why})"
    traj = None if plan is None else plan.traj
    execution = None
    if traj is not None and traj.tracking is None and ctx.target.tracking:
        traj.tracking = ctx.target.tracking[0]  # the gains the search planned with
    if status == "found" and plan is not None:
        execution, cut = _report(ctx, plan)
        if below is not None and execution is not None:
            # the reason follows the estimate reported (rarely, one set aside on its quick
            # estimate meets the target on the precise one)
            reason += (
                ", whose precise prediction meets it"
                if execution.meets_target
                else ", predicted below target"
            )
        reason += cut
        if execution is not None:
            gains_note = "" if execution.meets_target or traj is None else _gains_note(ctx, traj)
            reason += f"; {gains_note}" if gains_note else ""
            _warn_below_target(ctx, execution, gains_note)
        stats.time_total = ctx.budget.elapsed()
    logger.info("solve: %s (%s) in %.3f s", status, reason, stats.time_total)
    closest = None
    if status == "budget_exhausted" and ctx.closest is None and ctx.partial is not None:
        ctx.closest = _partial(ctx)
    if status == "budget_exhausted" and ctx.closest is not None:
        acts, ctrls, _ = ctx.closest
        closest = rollout(ctx.problem.switched_system, ctx.problem.initial_state, acts, ctrls)
    if claim is not None and ctx.joint:  # optimal (and bounded) at the planned risk allocation only
        claim = claim._replace(optimal=False, scope="", bound=float("nan"))
    return SolveResult(
        status,
        traj,
        reason,
        float("nan") if plan is None else plan.margin,
        stats,
        str(ctx.formula),
        objective=None if claim is None else claim.name,
        objective_value=float("nan") if claim is None else claim.value,
        objective_bound=float("nan") if claim is None else claim.bound,
        optimal=False if claim is None else claim.optimal,
        optimal_scope="" if claim is None else claim.scope,
        guarantee=ctx.options.guarantee,
        predicted=None if plan is None else plan.predicted,
        closest=closest,
        execution=execution,
        certificate=certificate,
    )


def _report(ctx: SolveContext, plan: Verified) -> tuple[PredictedExecution | None, str]:
    """The returned plan's predicted execution (:meth:`~.context.TargetWatch.report`: more
    samples than a candidate's) and, when the time limit stopped it, what was reported instead
    (the estimate the loop judged the plan on, else none) as a tail for the reason."""
    try:
        return ctx.target.report(plan.traj), ""
    except BudgetExceeded:
        if "time_limit" not in ctx.stats.caps_hit:
            ctx.stats.caps_hit.append("time_limit")
        if plan.execution is not None:
            return plan.execution, (
                f" (the time limit of {ctx.options.total_time_cap:.3g} s stopped the precise "
                f"prediction: the execution reported is the {PREDICT_SAMPLES}-sample estimate)"
            )
        return None, (
            f" (the time limit of {ctx.options.total_time_cap:.3g} s stopped the prediction of "
            "its execution: none is reported)"
        )


def _partial(ctx: SolveContext) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The longest feasible prefix of the last refuted candidate (``ctx.partial``), unless the
    time limit was reached (it would run past it)."""
    if ctx.partial is None or ctx.budget.expired():
        return None
    try:
        return ctx.partial()
    except BudgetExceeded:
        return None


def _remaining(ctx: SolveContext, reason: str) -> tuple[int, int] | None:
    """When ``max_candidates`` decided: how many candidates of the current length remain (up to
    four times the budget; :func:`~.cegis._remaining`), unless the time limit was reached."""
    budget = ctx.options.termination.candidates
    if budget is None or "max_candidates" not in reason or ctx.remaining is None or ctx.budget.expired():
        return None
    kept = copy.copy(ctx.stats)  # the count's encoding work is not the search's
    try:
        return ctx.remaining(4 * budget)
    except BudgetExceeded:
        return None
    finally:
        ctx.stats.__dict__.update(kept.__dict__)


def _unfound(ctx: SolveContext, status: Status, reason: str) -> tuple[Status, str]:
    """The status and reason of a solve that ends without a plan, with what qualifies them."""
    if status == "infeasible" and not ctx.proofs_hold:
        status = "budget_exhausted"
        reason += (
            " under the MLO reading; with state-dependent sensor noise that is no proof for "
            "guarantee='closed_loop'"
        )
    # With no candidate refuted and no MILP solved, the proof is LP pruning's alone, which does
    # not depend on the risk allocation (mean regions, each joint face alone at its eps, the
    # step-0 labels read by Boole's bound): it stands for the joint constraints as they are.
    if status == "infeasible" and ctx.joint and (ctx.stats.candidates or ctx.stats.milp_calls):
        status = "budget_exhausted"
        reason += NO_PROOF  # allocation.search_allocation may prove it on the relaxation
    if status == "budget_exhausted":
        advice = budget_advice(
            reason,
            ctx.stats,
            ctx.options,
            ctx.formula.horizon,
            ctx.budget_abandoned,
            floorless_modes(ctx.problem.switched_system),
            _remaining(ctx, reason),
        )
        reason += f"; {advice}" if advice else ""
    if "time_limit" in ctx.stats.caps_hit:
        reason += " (the wall-clock cap decided this; the same seed may differ elsewhere)"
    return status, reason


def _gains_note(ctx: SolveContext, traj: ProbabilisticTSTrajectory) -> str:
    """For a plan below target: the tracking gains it was predicted with, what the other gain
    sets predicted, and firmer weights to try (empty when every mode has its own gains)."""
    used = traj.tracking
    if used is None:
        return ""
    tried = ctx.target.tried.get(plan_key(traj), [])
    others = "; ".join(
        f"{g.name} {100 * p.belief_estimate:.1f}% / {100 * p.state_estimate:.1f}%"
        for g, p in tried
        if g is not used
    )
    note = f"tracked with {used.describe()}"
    if others:
        note += f" (the other gain sets predicted belief / true state: {others})"
    if used.weights is None:
        return note
    Q = np.atleast_2d(np.asarray(used.weights["Q"], dtype=float))
    firmer = [
        p
        for g, p in tried
        if g.weights is not None
        and np.trace(np.atleast_2d(np.asarray(g.weights["Q"], dtype=float))) > np.trace(Q)
    ]
    if firmer:  # firmer tracking was predicted and did no better: the gains are not what fails
        return f"{note}; firmer tracking predicted no better, so the shortfall is not the tracking's alone"
    R = np.atleast_2d(np.asarray(used.weights["R"], dtype=float))
    q = ", ".join(f"{10.0 * v:.3g}" for v in np.diag(Q))
    r = ", ".join(f"{v:.3g}" for v in np.diag(R))
    return (
        f"{note}; to try firmer tracking, set each mode's gains before solving: "
        f"mode.compute_finite_horizon_lqr({int(used.weights['horizon'])}, Q_final=Q, Q=Q, R=R) "
        f"with Q = diag({q}), R = diag({r})"
    )


def _warn_below_target(ctx: SolveContext, execution: PredictedExecution, gains_note: str = "") -> None:
    """An :class:`~idstlpy.errors.ExecutionTargetWarning` for a returned plan below target."""
    if execution.meets_target:
        return
    warnings.warn(
        ExecutionTargetWarning(
            f"the returned plan falls short of the execution target {execution.target}: "
            f"predicted to hold for the executed belief in "
            f"{100 * execution.belief_estimate:.1f}% and for the true state in "
            f"{100 * execution.state_estimate:.1f}% of executions "
            f"(guarantee={ctx.options.guarantee!r})"
            + (f"; {gains_note}" if gains_note else "")
            + "; see result.execution"
        ),
        stacklevel=_user_stacklevel(),
    )


def _user_stacklevel() -> int:
    """The ``stacklevel`` (for a ``warnings.warn`` in the caller) of the first frame outside the
    package, so that a warning names the user's line."""
    package = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    level, frame = 1, sys._getframe(1)  # stacklevel 1: the caller of warnings.warn
    while frame.f_back is not None and os.path.abspath(frame.f_code.co_filename).startswith(package):
        frame, level = frame.f_back, level + 1
    return level
