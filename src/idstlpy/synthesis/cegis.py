"""Counterexample-guided synthesis: the proposer / teacher loop of the paper's Fig. 1.

The loop (:func:`_search`) is the figure, and decides nothing itself; its parts are the
interfaces it calls:

1. **propose**: the proposer (:class:`~.interfaces.Proposer`; :class:`~.proposer.BMCProposer`)
   offers the shortest discrete plan left, over the clauses LP pruning proved
   (:class:`~.abstraction.Abstraction`: empty letters, disjoint pairs, impossible steps);
2. **teach**: the teachers (:class:`~.interfaces.Teacher`), in order, decide it: the plan LP
   (:class:`~.teacher.LPTeacher`; exact when the covariance does not depend on the mean), then,
   under state-dependent noise, the belief-space sampler (:class:`~.sampler_teacher.SamplerTeacher`).
   The first ``Found`` or ``Refuted`` settles the candidate; ``Unknown`` passes it on. Each
   teacher may guide the proposer after teaching (``Teacher.guide``), and a refuted candidate
   is offered to every teacher's ``Teacher.rescue`` (the sampler chooses its own modes);
3. **block or abandon**: ``Refuted`` becomes a proven clause; a candidate every teacher gave
   up on, or whose plan fails verification, is *abandoned* (set aside, not a proof);
4. **verify**: a ``Found`` plan is re-rolled with the exact belief dynamics and must pass the
   final check (:func:`~.final_check.final_check`), and what the guarantee asks (below);
5. the **eager MILP** is a strategy (:class:`~.eager.EagerMILP`): on an LP-exact single-mode
   problem whose lazy loop has not converged, it chooses the discrete plan and returns a typed
   outcome (a plan with its proof, an end, or declined);
6. a verified plan is **optimised** for the objective (:func:`~.optimise.optimise`) and the
   result is built once (:func:`~.finish.finish`).

Everything a step reads travels in one :class:`~.context.SolveContext`.

With ``guarantee="execution"`` (the default) a plan that passes the monitor must also meet the
execution target: its predicted execution (:func:`idstlpy.executor.predict.predict_closed_loop`,
the true start drawn from the prior) reaches ``options.execution_target`` on both readings
(:func:`_hold`). A plan below target gets the closed-loop repair (:func:`~.certify.certify`) and is
predicted again; one still below target is set aside (the best is kept) and the search goes on
for at most :data:`~.context.BELOW_TARGET_EXTRA` times the candidates it took, at least
:data:`~.context.BELOW_TARGET_MIN` more (:data:`~.context.BELOW_TARGET_SEARCHED` where the mode search
reads the execution), and only while it finds new plans (it stops after
:data:`~.context.BELOW_TARGET_PATIENCE` verified plans in a row it had set aside before; a plan
found again is not predicted again). If no plan meets the target by then (or another budget
ends the search), the best plan set aside is returned ``found`` with ``meets_target`` False, the
reason says so and an :class:`~idstlpy.errors.ExecutionTargetWarning` is issued. Every found
result, under every guarantee, carries its predicted execution (``SolveResult.execution``).

With ``guarantee="closed_loop"`` the monitor verifies the true state predicted under the executor
(:func:`idstlpy.closed_loop.predicted_state`) instead of the MLO belief, and a plan that fails it
is first repaired (:func:`~.certify.certify`). An MLO refutation stays a proof under constant sensor noise
(the predicted covariance is the filter's plus the estimate's spread, never smaller than the MLO
one, and every chance constraint has ``eps <= 0.5``, so it only gets harder); under
state-dependent noise it is not, and an ``infeasible`` becomes ``budget_exhausted``.

Statuses: ``found`` (monitor-verified), ``infeasible`` (the proposer ran dry over proven
clauses at the formula's full horizon, or the MILP over a correctly bounded model proved it),
``budget_exhausted`` otherwise, with the counts of refuted and abandoned candidates.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..backends import Backend, get_backend
from ..belief import rollout
from ..semantics import robustness
from ..trajectory import ProbabilisticTSTrajectory
from . import eager, stopped
from .abstraction import PruningReport
from .certify import Certified, certify
from .context import BELOW_TARGET_SEARCHED, SolveContext, Verified
from .eager import EagerEnd, EagerMILP, EagerPlan
from .final_check import final_check
from .finish import finish
from .interfaces import BudgetExceeded, Found, Proposer, ProposerDry, Refuted, Teacher, Unknown, Verdict
from .optimise import optimise
from .plan import DiscretePlan
from .plan_lp import PlanLPContext
from .proofs import uncertified_certificate
from .proposer import BMCProposer
from .results import SolveResult, Status
from .sampler_teacher import SamplerTeacher
from .teacher import LPTeacher

if TYPE_CHECKING:
    pass

__all__ = ["search", "verify"]

logger = logging.getLogger(__name__)

_Run = SolveContext
"""The solve context under the name tests use."""
_check = final_check
"""The final check under the name tests use."""


def search(ctx: SolveContext) -> SolveResult:
    """The pipeline's search stage (:mod:`.pipeline`): set up the parts (proposer, teachers,
    eager MILP) and run the loop (:func:`_search`)."""
    backend = get_backend(ctx.options.lp_backend)
    system = ctx.problem.switched_system
    proposer: Proposer = BMCProposer(
        ctx.formula,
        ctx.abstraction,
        system.num_modes,
        _prune(ctx, backend),
        ctx.options,
        ctx.budget,
        ctx.stats,
    )
    ctx.remaining = functools.partial(stopped.remaining, ctx, proposer)
    try:
        teachers, lp_teacher = _teachers(ctx, proposer, backend)
        exact = any(teacher.exact(ctx.problem) for teacher in teachers)
        check = functools.partial(verify, ctx)
        options = ctx.options
        # Several modes, the covariance fixed by the modes: the joint MILP chooses them (issue
        # 31). Not under guarantee="mlo" (the paper's loop, bit for bit) nor "closed_loop", and
        # not for an objective (whose optimum the joint model does not prove).
        joint = (
            exact
            and system.num_modes > 1
            and ctx.execution
            and options.objective is None
            and eager.JOINT_MODES
        )
        milp = EagerMILP(
            ctx,
            proposer,
            check,
            enabled=exact and system.num_modes == 1,
            joint=joint,
            teacher=lp_teacher,
        )
        return _search(ctx, proposer, teachers, milp)
    finally:
        ctx.stats.sat_calls = proposer.sat_calls - ctx.uncounted_sat_calls
        proposer.close()


def _prune(ctx: SolveContext, backend: Backend) -> PruningReport:
    """LP pruning's proven facts (:meth:`~.abstraction.Abstraction.prune`), counted in the stats."""
    problem, options, stats, budget = ctx.problem, ctx.options, ctx.stats, ctx.budget
    system, init, units = problem.switched_system, problem.initial_state, ctx.units
    horizon = min(ctx.formula.horizon, options.max_plan_length)
    with stats.clock("time_lp"):
        # (multi-step gaps only off guarantee="mlo", whose plans stay as recorded)
        report = ctx.abstraction.prune(
            system,
            problem.control_domain,
            init.mean,
            init.cov,
            budget,
            options.max_pruning_lps,
            backend,
            (units.dx, units.du),
            reach=options.guarantee != "mlo",
            max_gap=horizon,
        )
        report.out_of_reach = ctx.abstraction.out_of_reach(system, init.cov, horizon, budget)
        report.proofs.update(
            {
                ("reach", *(i if isinstance(i, tuple) else (i,))): p
                for i, p in ctx.abstraction.reach_proofs.items()
            }
        )
    stats.pruned_letters = (
        len(report.empty_atoms)
        + len(report.disjoint_pairs)
        + len(report.initial_false)
        + len(report.out_of_reach)
    )
    stats.pruned_steps = len(report.impossible_steps)
    return report


def _teachers(ctx: SolveContext, proposer: Proposer, backend: Backend) -> tuple[list[Teacher], LPTeacher]:
    """The plan LP, then (where it is not exact) the belief-space sampler; and the plan LP teacher
    itself, which the eager MILP times its plans with (handed over as built, not recognised by
    its type among the loop's teachers)."""
    problem, options = ctx.problem, ctx.options
    target = options.execution_target if options.guarantee == "execution" else None
    # Under "execution" the plan LP searches as for the default plan (with the execution room):
    # plans tuned to the objective alone (least effort, no room) miss the target and were set
    # aside for thousands of candidates (issue 34); optimise() then improves the plan found.
    lp = LPTeacher(
        problem,
        ctx.abstraction,
        ctx.units,
        backend,
        3,
        None if ctx.execution else options.objective,
        ctx.weights,
        ctx.closed_loop,
        target,
    )
    teachers: list[Teacher] = [lp]
    if lp.searches_modes(problem):
        ctx.target.least_extra = BELOW_TARGET_SEARCHED  # each candidate's modes are searched
    # The sampler serves state-dependent noise only, where the LP is not exact; its set-up
    # (~10 ms) is skipped elsewhere.
    if not lp.exact(problem):
        seeds = np.random.SeedSequence(options.seed)
        sampler = SamplerTeacher(problem, ctx.abstraction, proposer, options, ctx.units, seeds)
        if sampler.applies(problem):
            teachers.append(sampler)
    return teachers, lp


def _search(
    ctx: SolveContext, proposer: Proposer, teachers: Sequence[Teacher], milp: EagerMILP
) -> SolveResult:
    """The paper's figure: propose, teach, block or abandon, verify (see the module docstring)."""
    stats = ctx.stats
    while True:
        stop = _stop(ctx)
        if stop is not None:
            return finish(ctx, "budget_exhausted", stop)
        if milp.due():
            outcome = milp.solve()
            if isinstance(outcome, EagerEnd):
                if outcome.status == "infeasible":
                    return _milp_infeasible(ctx, proposer, teachers, milp, outcome.reason)
                return finish(ctx, outcome.status, outcome.reason)
            if isinstance(outcome, EagerPlan):
                return optimise(ctx, outcome.plan, outcome.how, outcome.proof, milp)
        proposal = proposer.propose()  # propose
        if isinstance(proposal, ProposerDry) and not proposal.proven and milp.joint and milp.enabled:
            # Dry only because requirement sets were set aside (their modes searched, no proof):
            # the joint MILP decides every mode sequence of them at once.
            outcome = milp.solve()
            if isinstance(outcome, EagerEnd):
                return finish(ctx, outcome.status, outcome.reason)
            if isinstance(outcome, EagerPlan):
                return optimise(ctx, outcome.plan, outcome.how, outcome.proof, milp)
        if isinstance(proposal, ProposerDry):
            status: Status = "infeasible" if proposal.proven else "budget_exhausted"
            why = ctx.aside_reason() if proposal.aside else proposal.reason
            cert = _certificate(ctx, proposer) if proposal.proven and _proof_stands(ctx) else None
            return finish(ctx, status, f"{why}; {ctx.counts()}", certificate=cert)
        plan = proposal
        stats.candidates += 1
        stopped.report(ctx, plan.length - 1)
        verdict = _teach(ctx, teachers, proposer, plan)  # teach
        if isinstance(verdict, Refuted):  # block
            _block(ctx, proposer, plan, verdict)
            # the refuted candidate whose proof reached deepest (its prefix is the longest)
            depth = max((k for k, _ in verdict.conflict.requirements), default=0)
            if depth >= ctx.partial_depth:
                ctx.partial_depth = depth
                ctx.partial = functools.partial(stopped.partial_plan, ctx, teachers[0], plan, verdict)
            stopped.report(ctx, plan.length - 1)
            continue
        if isinstance(verdict, Found):  # verify
            set_aside = stats.below_target
            checked = verify(ctx, verdict.actions, verdict.controls)
            below = stats.below_target > set_aside
            if below:
                for teacher in teachers:
                    teacher.below_target()
            if checked is not None:
                how = f"{verdict.how} met the plan and the monitor agrees"
                return optimise(ctx, checked, how, "lp" if verdict.exact else "sampler", milp)
            why = _unverified(ctx, below)
        else:
            why, below = verdict.why, False
        _abandon(ctx, proposer, plan, verdict, why, below)  # abandon
        stopped.report(ctx, plan.length - 1)


RECERTIFY_CANDIDATES = 400
"""Candidates the lazy loop may spend re-deriving an eager MILP's ``infeasible`` (a work budget):
its proof (branch and bound in floating point) has no certificate of its own."""


def _milp_infeasible(
    ctx: SolveContext, proposer: Proposer, teachers: Sequence[Teacher], milp: EagerMILP, reason: str
) -> SolveResult:
    """The eager MILP proved ``infeasible``: re-derive it with the lazy loop for a certificate.

    The lazy loop goes on from where it was (the MILP aside) for at most
    :data:`RECERTIFY_CANDIDATES` candidates: a proven dry run gives the certificate (the reason
    says the proof was re-derived); a plan the monitor verifies means the MILP's proof was wrong
    (a back end's error) and the plan is returned; anything else leaves the MILP's proof
    uncertified, and the reason says so.
    """
    with ctx.stats.clock("time_certificate"):  # the re-derivation is the certificate's cost
        return _rederive(ctx, proposer, teachers, milp, reason)


def _rederive(
    ctx: SolveContext, proposer: Proposer, teachers: Sequence[Teacher], milp: EagerMILP, reason: str
) -> SolveResult:
    """:func:`_milp_infeasible`'s lazy loop."""
    stats = ctx.stats
    why = "the eager MILP's proof (branch and bound) has no exact certificate"
    try:
        for _ in range(RECERTIFY_CANDIDATES):
            proposal = proposer.propose()
            if isinstance(proposal, ProposerDry):
                if proposal.proven and _proof_stands(ctx):
                    cert = _certificate(ctx, proposer, timed=False)
                    if cert is not None and cert.get("certified"):
                        reason += "; re-derived by the lazy loop, whose certificate verifies"
                        return finish(ctx, "infeasible", reason, certificate=cert)
                why += "; the lazy loop's re-derivation " + (
                    "has no verified certificate" if proposal.proven else f"stopped: {proposal.reason}"
                )
                break
            stats.candidates += 1
            verdict = _teach(ctx, teachers, proposer, proposal)
            if isinstance(verdict, Refuted):
                _block(ctx, proposer, proposal, verdict)
                continue
            if isinstance(verdict, Found):
                checked = verify(ctx, verdict.actions, verdict.controls)
                if checked is not None:
                    logger.warning("the eager MILP said infeasible, but the lazy loop found a verified plan")
                    how = (
                        f"{verdict.how} met the plan and the monitor agrees (the eager MILP's "
                        "'infeasible' was wrong)"
                    )
                    return optimise(ctx, checked, how, "lp" if verdict.exact else "sampler", milp)
            why += "; the lazy loop's re-derivation set a candidate aside"
            break
        else:
            why += f"; the lazy loop's re-derivation took more than {RECERTIFY_CANDIDATES} candidates"
    except BudgetExceeded:
        stats.caps_hit.append("time_limit")
        why += "; the time limit stopped the lazy loop's re-derivation"
    return finish(ctx, "infeasible", reason, certificate=uncertified_certificate(why, "milp"))


def _proof_stands(ctx: SolveContext) -> bool:
    """Whether a proven dry run stays ``infeasible`` (what :func:`~.finish.finish` keeps: the
    proofs hold under the guarantee, and with joint chance constraints only LP pruning's proof,
    with no candidate refuted and no MILP solved): only then is its certificate built."""
    stats = ctx.stats
    return ctx.proofs_hold and (not ctx.joint or not (stats.candidates or stats.milp_calls))


def _certificate(ctx: SolveContext, proposer: Proposer, timed: bool = True) -> dict[str, object] | None:
    """The certificate of the proposer's proven dry run (:meth:`~.proposer.BMCProposer.certificate`),
    timed in the statistics' ``time_certificate`` (unless the caller times it)."""
    make = getattr(proposer, "certificate", None)
    if make is None:
        return None
    if not timed:
        out: dict[str, object] = make()
        return out
    with ctx.stats.clock("time_certificate"):
        cert: dict[str, object] = make()
    return cert


def _stop(ctx: SolveContext) -> str | None:
    """Why the search stops before the next candidate (the termination's work, or the search
    after a plan below target), or ``None``."""
    ctx.budget.check("the proposer / teacher loop")
    spent = ctx.work_stop()
    if spent is not None:
        return f"{spent}; {ctx.counts()}"
    spent = ctx.target.stop_reason(ctx.stats.candidates)
    if spent is not None:
        return f"{spent} after a plan below target; {ctx.counts()}"
    return None


def _teach(ctx: SolveContext, teachers: Sequence[Teacher], proposer: Proposer, plan: DiscretePlan) -> Verdict:
    """The teachers' verdict on ``plan``: the first that is not ``Unknown``, each teacher
    guiding the proposer after it taught; a refutation is offered to every teacher's rescue."""
    budget, stats = ctx.budget, ctx.stats
    verdict: Verdict = Unknown("no teacher applies")
    for teacher in teachers:
        verdict = teacher.teach(plan, budget, stats)
        teacher.guide(proposer, plan)
        if not isinstance(verdict, Unknown):
            break
    if not isinstance(verdict, Refuted):
        return verdict
    for teacher in teachers:
        rescued = teacher.rescue(plan, verdict, budget, stats)
        if not isinstance(rescued, Refuted):
            return rescued
        verdict = rescued
    return verdict


def _block(ctx: SolveContext, proposer: Proposer, plan: DiscretePlan, verdict: Refuted) -> None:
    """A proven conflict becomes a clause (and a candidate whose modes were searched is set aside)."""
    proposer.block(verdict.conflict)
    if verdict.set_aside:
        proposer.set_aside(plan)  # its modes were searched: no proof, not retried
        ctx.set_aside("no modes")
    stats = ctx.stats
    stats.refuted += 1
    stats.counterexamples += 1
    logger.debug("candidate %d refuted: %s", stats.candidates, verdict.conflict.proof)


def _abandon(
    ctx: SolveContext, proposer: Proposer, plan: DiscretePlan, verdict: Verdict, why: str, below: bool = False
) -> None:
    """Set a candidate aside without a proof, remembering what the teachers got closest to (a
    plan whose modes were searched for the execution: its requirement set, for every mode
    sequence)."""
    if isinstance(verdict, Found) and verdict.searched:
        proposer.set_aside(plan)
    else:
        proposer.abandon(plan)
    ctx.stats.abandoned += 1
    if isinstance(verdict, Found):
        ctx.set_aside("below target" if below else "unverified")
    else:
        ctx.set_aside("gave up")
    if isinstance(verdict, Unknown):
        if verdict.budgeted:
            ctx.budget_abandoned += 1
        if verdict.closest is not None and (ctx.closest is None or verdict.closest[2] > ctx.closest[2]):
            ctx.closest = verdict.closest
    logger.info("candidate %d abandoned: %s", ctx.stats.candidates, why)


def _unverified(ctx: SolveContext, below: bool) -> str:
    """Why a teacher's plan failed the verify step."""
    if ctx.closed_loop:
        return "the plan's predicted closed loop failed the monitor, even repaired"
    if below:
        return "the plan's predicted execution is below the execution target (repair included)"
    return "the plan failed the monitor's exact re-check"


def verify(ctx: SolveContext, actions: np.ndarray, controls: np.ndarray) -> Verified | None:
    """The verify step: re-roll the exact belief dynamics and run the final check
    (:func:`~.final_check.final_check`); the plan and its margin if it passes.

    Under ``guarantee="closed_loop"`` a plan whose predicted true state fails is repaired first
    (:func:`_certify`); under ``guarantee="execution"`` a plan must meet the execution target
    (:func:`_hold`).
    """
    problem = ctx.problem
    traj = rollout(problem.switched_system, problem.initial_state, actions, controls)
    if ctx.closed_loop:
        certified = _certify(ctx, traj)
        # The final check (the domain, the roll-out, the prediction) is final_check's, as for every plan.
        return None if certified is None else final_check(ctx, certified.traj)
    checked = final_check(ctx, traj)
    if checked is None:
        logger.warning(
            "candidate failed the final re-check (monitor margin %.3g)",
            robustness(traj, problem.stl_formula),
        )
    if checked is not None and ctx.execution:
        return _hold(ctx, checked)
    return checked


def _hold(ctx: SolveContext, checked: Verified) -> Verified | None:
    """Under ``guarantee="execution"``: the verified plan if its predicted execution meets the
    target, else its closed-loop repair (:func:`~.certify.certify`) if that keeps the paper's
    semantics and meets it; otherwise the better of the two is set aside
    (:meth:`~.context.TargetWatch.set_aside`) and None returned (the candidate is abandoned, the
    search goes on)."""
    target = ctx.target
    known = target.known(checked.traj)
    if known is not None:  # found again: the same prediction, and its repair was tried
        logger.info("verified plan set aside before (below the execution target): not predicted again")
        target.set_aside(known, checked)
        return None
    try:
        execution = target.judge(checked.traj)
    except BudgetExceeded:
        # The time limit stopped the prediction of a verified plan: it is what the search got
        # closest to (shown as result.closest), not a plan known to meet the target.
        ctx.closest = (checked.traj.get_action(), checked.traj.get_control(), float("inf"))
        raise
    checked = checked._replace(execution=execution)
    if execution.meets_target:
        return checked
    logger.info("verified plan below the execution target (%s): repairing", execution.summary())
    room = ctx.stats.execution_room
    modes = tuple(int(a) for a in checked.traj.get_action())
    repaired = None
    if modes not in target.unrepaired:  # the repair keeps the modes: once per mode sequence
        try:
            repaired = _certify(ctx, checked.traj)
        finally:
            ctx.stats.execution_room = room
    best = checked
    if repaired is not None:
        margin = robustness(repaired.traj, ctx.formula)
        if margin >= 0:  # the repair keeps the MLO semantics (it should: its covariances are larger)
            ex = target.judge(repaired.traj)
            fixed = Verified(repaired.traj, margin, None, ex)
            if ex.meets_target:
                logger.info("the closed-loop repair meets the execution target (%s)", ex.summary())
                return fixed
            if ex.shortfall < execution.shortfall:
                best = fixed
    target.unrepaired.add(modes)
    logger.info("plan set aside below the execution target: %s", (best.execution or execution).summary())
    target.set_aside(best, checked)
    return None


def _certify(ctx: SolveContext, traj: ProbabilisticTSTrajectory) -> Certified | None:
    """The closed-loop repair of ``traj`` (:func:`~.certify.certify`) in this solve's context."""
    problem, options = ctx.problem, ctx.options
    context = PlanLPContext.of(problem, ctx.abstraction, ctx.units, get_backend(options.lp_backend))
    return certify(
        context,
        problem,
        traj,
        exact=ctx.proofs_hold,
        rounds=options.polish_rounds,
        stats=ctx.stats,
        budget=ctx.budget,
    )
