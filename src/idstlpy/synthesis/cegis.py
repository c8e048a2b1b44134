"""Counterexample-guided synthesis: the proposer / teacher loop of the paper's Fig. 1.

The loop orchestrates typed parts (:mod:`.interfaces`) and decides nothing itself:

1. LP pruning (:class:`~.abstraction.Abstraction`) proves letters empty, pairs disjoint and
   steps impossible; the proposer takes these as proven clauses.
2. The proposer (:class:`~.proposer.BMCProposer`) offers the shortest discrete plan left.
3. The teachers, in order, decide it: the plan LP (:class:`~.teacher.LPTeacher`; exact when
   the covariance does not depend on the mean), then, under state-dependent noise, the
   belief-space sampler (:class:`~.sampler.SamplerTeacher`). The first ``Found`` or
   ``Refuted`` settles the candidate; ``Unknown`` passes it on.
4. ``Refuted`` becomes a proven clause; a candidate every teacher gave up on is *abandoned*
   (set aside, not a proof). A ``Found`` plan is re-rolled with the exact belief dynamics and
   must pass the monitor; otherwise it is abandoned.
5. On an LP-exact single-mode problem whose lazy loop has not converged after
   ``lazy_candidates`` candidates, the eager MILP (:mod:`.milp`) chooses the discrete plan.

With ``guarantee="execution"`` (the default) a plan that passes the monitor must also meet the
execution target: its predicted execution (:func:`idstlpy.executor.predict.predict_closed_loop`,
the true start drawn from the prior) reaches ``options.execution_target`` on both readings
(:func:`_hold`). A plan below target gets the closed-loop repair (:func:`~.certify.certify`) and is
predicted again; one still below target is set aside (the best is kept) and the search goes on
for at most :data:`BELOW_TARGET_EXTRA` times the candidates it took, at least
:data:`BELOW_TARGET_MIN` more. If no plan meets the target by then (or another budget ends the
search), the best plan set aside is returned ``found`` with ``meets_target`` False, the reason
says so and an :class:`~idstlpy.errors.ExecutionTargetWarning` is issued. Every found result,
under every guarantee, carries its predicted execution (``SolveResult.execution``).

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

import logging
import os
import sys
import time
import warnings
from typing import Any, NamedTuple

import numpy as np

from ..backends import get_backend
from ..belief import rollout
from ..errors import ExecutionTargetWarning, IdstlpyError
from ..executor.predict import predict_closed_loop
from ..semantics import robustness
from ..trajectory import ProbabilisticTSTrajectory
from .abstraction import Abstraction
from .advice import budget_advice
from .allocation import NO_PROOF
from .certify import Certified, certify
from .decoupled import solve_decoupled
from .interfaces import Budget, BudgetExceeded, Found, ProposerDry, Refuted, Teacher, Unknown
from .milp import solve_milp, switch_to_eager
from .objectives import better, objective_value, refine
from .options import SolverOptions
from .plan import DiscretePlan, extract_witness
from .plan_lp import PlanLPContext, Scaling, lp_exact
from .plan_solve import LPGoal
from .proposer import BMCProposer
from .results import PredictedExecution, SolveResult, SolveStats, Status
from .sampler import SamplerTeacher
from .teacher import TIGHTEN, LPTeacher, closed_loop_check, execution_margin, solve_plan_lp

__all__ = ["synthesize"]

logger = logging.getLogger(__name__)

PREDICT_SAMPLES = 1000
"""Model samples (and particles of the particle closure) of each predicted execution: the
estimates' standard error is at most 1.6 points, 0.7 near a 95% rate."""
BELOW_TARGET_EXTRA = 2.0
"""Under ``guarantee="execution"``, after the first verified plan below target (found after ``c``
candidates) the search goes on for at most ``BELOW_TARGET_EXTRA * c`` more candidates ..."""
BELOW_TARGET_MIN = 200
"""... and at least this many (a work budget: the same seed gives the same plan). From then on
the plan LP's mode search (issue 24) is off: it scores modes on the MLO plan LP, and maps the
proposer's mode sequences back to the plan just set aside (a "look on the last step"); the
proposer's own enumeration of mode sequences is what finds plans that hold when executed."""


def _input_scale(system: Any, domain: Any, units: Scaling) -> np.ndarray | None:
    """Per input, the scale :func:`_warn_far_inputs` compares a plan's inputs with, shape (m,);
    ``None`` when the control domain is bounded (the domain itself then bounds the inputs).

    The larger of the input's unit and, where some mode's ``B`` moves the state with it, the
    input that moves a state coordinate by one of its units in one step (``dx_i / |B_ij|``).
    """
    low, high = domain.bounding_box()
    if np.all(np.isfinite(low)) and np.all(np.isfinite(high)):
        return None
    scale = np.array(units.du, dtype=float)
    for mode in system.system_modes:
        B = np.abs(mode.B)
        with np.errstate(divide="ignore"):
            reach = np.where(B > 0, units.dx[:, None] / np.where(B > 0, B, 1.0), np.inf)
        move = np.min(reach, axis=0)
        scale = np.maximum(scale, np.where(np.isfinite(move), move, 0.0))
    return scale


def _user_stacklevel() -> int:
    """The ``stacklevel`` (for a ``warnings.warn`` in the caller) of the first frame outside the
    package, so that a warning names the user's line."""
    package = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    level, frame = 1, sys._getframe(1)  # stacklevel 1: the caller of warnings.warn
    while frame.f_back is not None and os.path.abspath(frame.f_code.co_filename).startswith(package):
        frame, level = frame.f_back, level + 1
    return level


class _Run:
    """The state of one solve: the parts, the budget and the statistics."""

    def __init__(self, problem: Any, options: SolverOptions, start: float) -> None:
        self.problem = problem
        self.options = options
        self.budget = Budget(options.total_time_cap, start)
        self.stats = SolveStats()
        # Candidates the sampler gave up on: the part of `abandoned` a budget option can change.
        self.sampler_abandoned = 0
        # The closest partial plan a teacher reported (actions, controls, progress), for a
        # budget_exhausted result to show what the search got to.
        self.closest: tuple[np.ndarray, np.ndarray, float] | None = None
        self.formula = problem.stl_formula
        self.milp_proof: tuple[bool, str, float] = (False, "", float("nan"))
        # An objective's bound the eager MILP proved over a scope (every plan of it, under the
        # paper's semantics, which every returned plan meets), kept when its own plan is not
        # returned (set aside below the execution target): (bound, scope) or None.
        self.mlo_bound: tuple[float, str] | None = None
        self.closed_loop = options.guarantee == "closed_loop"
        self.execution = options.guarantee == "execution"
        # Under "execution": the best verified plan below target so far, and the candidate count
        # at which the search stops looking for one that meets it.
        self.below: Verified | None = None
        self.below_until: int | None = None
        self._predicted: tuple[ProbabilisticTSTrajectory, PredictedExecution] | None = None
        self.unrepaired: set[tuple[int, ...]] = set()  # mode sequences whose repair fell short
        system = problem.switched_system
        self._units: Scaling | None = None  # the loop's (use_units), else computed when asked
        # Under closed_loop, MLO proofs carry over only when the filter covariance is the MLO one.
        self.proofs_hold = not self.closed_loop or lp_exact(system)
        # Joint chance constraints are planned at one risk allocation (a sufficient condition):
        # a refutation under it proves nothing about the others.
        self.joint = any(ap.joints for ap in self.formula.atomic_propositions())

    def done(
        self,
        status: Status,
        reason: str,
        traj: ProbabilisticTSTrajectory | None = None,
        margin: float = np.nan,
        predicted: ProbabilisticTSTrajectory | None = None,
    ) -> SolveResult:
        stats = self.stats
        fallback = status != "found" and self.below is not None
        if fallback and self.below is not None:
            # Under "execution": no plan met the target, but a verified one was set aside.
            below = self.below
            reason = (
                f"no plan met the execution target {self.options.execution_target} before the search "
                f"stopped ({reason}); the best verified plan is returned, predicted below target"
            )
            status, traj, margin, predicted = "found", below.traj, below.margin, below.predicted
        stats.time_total = self.budget.elapsed()
        if status == "infeasible" and not self.proofs_hold:
            status = "budget_exhausted"
            reason += (
                " under the MLO reading; with state-dependent sensor noise that is no proof for "
                "guarantee='closed_loop'"
            )
        if status == "infeasible" and self.joint:
            status = "budget_exhausted"
            reason += NO_PROOF  # allocation.prove_infeasible may prove it on the relaxation
        if status == "budget_exhausted":
            advice = budget_advice(reason, stats, self.options, self.formula.horizon, self.sampler_abandoned)
            reason += f"; {advice}" if advice else ""
        if status != "found" and "time_limit" in stats.caps_hit:
            reason += " (the wall-clock cap decided this; the same seed may differ elsewhere)"
        execution = None
        if status == "found" and traj is not None:
            execution = self.predict(traj)
            if not execution.meets_target:
                warnings.warn(
                    ExecutionTargetWarning(
                        f"the returned plan falls short of the execution target {execution.target}: "
                        f"predicted to hold for the executed belief in "
                        f"{100 * execution.belief_estimate:.1f}% and for the true state in "
                        f"{100 * execution.state_estimate:.1f}% of executions "
                        f"(guarantee={self.options.guarantee!r}); see result.execution"
                    ),
                    stacklevel=_user_stacklevel(),
                )
            stats.time_total = self.budget.elapsed()
        logger.info("solve: %s (%s) in %.3f s", status, reason, stats.time_total)
        closest = None
        if status == "budget_exhausted" and self.closest is not None:
            acts, ctrls, _ = self.closest
            closest = rollout(self.problem.switched_system, self.problem.initial_state, acts, ctrls)
        result = SolveResult(
            status,
            traj,
            reason,
            margin,
            stats,
            str(self.formula),
            guarantee=self.options.guarantee,
            predicted=predicted,
            closest=closest,
            execution=execution,
        )
        name = self.options.objective
        if fallback and name is not None and traj is not None:
            # The plan set aside below target: its objective's value, no optimality claimed.
            weights = self.options.effort_weights
            w = None if weights is None else np.asarray(weights, dtype=float)
            result.objective = name
            result.objective_value = objective_value(name, traj, self.formula, w)
        return result

    def use_units(self, scaling: Scaling) -> None:
        """The units the final check measures inputs in: the loop's own."""
        self._units = scaling

    @property
    def units(self) -> Scaling:
        """The problem's :class:`~.plan_lp.Scaling` (computed here when the loop gave none)."""
        if self._units is None:
            problem = self.problem
            system = problem.switched_system
            init = problem.initial_state
            abstraction = Abstraction(problem.stl_formula, system.n)
            self._units = Scaling.compute(system, problem.control_domain, init.mean, init.cov, abstraction)
        return self._units

    def predict(self, traj: ProbabilisticTSTrajectory) -> PredictedExecution:
        """The plan's predicted execution against the target (the last one is remembered).

        The planner's reading of the execution: the true start drawn from the prior, the
        model's noise, the modes' tracking gains, inputs clipped to the control domain. A
        prediction that cannot be made (a diverging loop) counts as below target (NaN rates).
        """
        if self._predicted is not None and self._predicted[0] is traj:
            return self._predicted[1]
        problem, stats = self.problem, self.stats
        target = self.options.execution_target
        with stats.clock("time_prediction"):
            try:
                pred = predict_closed_loop(
                    problem,
                    traj,
                    real_initial_cov=problem.initial_state.cov,
                    samples=PREDICT_SAMPLES,
                    particles=PREDICT_SAMPLES,
                    seed=0,
                )
                out = PredictedExecution.from_prediction(pred, target)
            except IdstlpyError as exc:
                logger.info("the plan's execution could not be predicted: %s", exc)
                nan = float("nan")
                out = PredictedExecution(nan, nan, nan, nan, {}, target)
        stats.predictions += 1
        self._predicted = (traj, out)
        return out

    def set_aside(self, checked: Verified) -> None:
        """Keep a verified plan below target if it is the best so far; start the extra search."""
        stats = self.stats
        stats.below_target += 1
        ex = checked.execution
        if self.below is None or (
            ex is not None
            and self.below.execution is not None
            and ex.shortfall < self.below.execution.shortfall
        ):
            self.below = checked
        if self.below_until is None:
            c = stats.candidates
            extra = max(BELOW_TARGET_MIN, int(np.ceil(BELOW_TARGET_EXTRA * c)))
            self.below_until = c if self.options.termination.first_found else c + extra

    def counts(self) -> str:
        s = self.stats
        return f"{s.candidates} candidates: {s.refuted} refuted by proofs, {s.abandoned} abandoned"


def synthesize(problem: Any, options: SolverOptions, start: float | None = None) -> SolveResult:
    """Run the CEGIS loop on ``problem`` (see the module docstring).

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
    run = _Run(problem, options, time.perf_counter() if start is None else start)
    try:
        composed = _decoupled(run, problem, options)
        if composed is not None:
            return composed
        return _loop(run, problem, options)
    except BudgetExceeded as exc:
        run.stats.caps_hit.append("time_limit")
        return run.done(
            "budget_exhausted",
            f"time limit of {options.total_time_cap:.3g} s reached during {exc.where}; {run.counts()}",
        )


def _decoupled(run: _Run, problem: Any, options: SolverOptions) -> SolveResult | None:
    """Independent blocks planned one by one (:mod:`.decoupled`); the composed plan must pass the
    final check (:func:`_verify`: under ``"execution"`` the target too, or it is set aside), else
    ``None`` and the joint loop runs."""
    if options.objective is not None or run.closed_loop:
        return None
    plan = solve_decoupled(problem, options, run.budget, run.stats, synthesize)
    if plan is None:
        return None
    system, init = problem.switched_system, problem.initial_state
    abstraction = Abstraction(problem.stl_formula, system.n)
    scaling = Scaling.compute(system, problem.control_domain, init.mean, init.cov, abstraction)
    run.use_units(scaling)
    checked = _verify(run, plan.actions, plan.controls, abstraction, scaling)
    if checked is None:
        logger.info("decoupled: the composed plan failed the final check; searching the joint problem")
        return None
    how = f"{plan.how}; the monitor agrees"
    return run.done("found", how, checked.traj, checked.margin, checked.predicted)


def _loop(run: _Run, problem: Any, options: SolverOptions) -> SolveResult:
    system, init, formula = problem.switched_system, problem.initial_state, problem.stl_formula
    stats, budget = run.stats, run.budget
    lp_backend = get_backend(options.lp_backend)
    abstraction = Abstraction(formula, system.n)
    scaling = Scaling.compute(system, problem.control_domain, init.mean, init.cov, abstraction)
    run.use_units(scaling)
    with stats.clock("time_lp"):
        report = abstraction.prune(
            system,
            problem.control_domain,
            init.mean,
            init.cov,
            budget,
            options.max_pruning_lps,
            lp_backend,
            (scaling.dx, scaling.du),
        )
        report.out_of_reach = abstraction.out_of_reach(
            system, init.cov, min(formula.horizon, options.max_plan_length), budget
        )
    stats.pruned_letters = (
        len(report.empty_atoms)
        + len(report.disjoint_pairs)
        + len(report.initial_false)
        + len(report.out_of_reach)
    )
    stats.pruned_steps = len(report.impossible_steps)
    proposer = BMCProposer(formula, abstraction, system.num_modes, report, options, budget, stats)
    try:
        seeds = np.random.SeedSequence(options.seed)
        weights = None if options.effort_weights is None else np.asarray(options.effort_weights, dtype=float)
        teachers: list[Teacher] = [
            LPTeacher(
                problem, abstraction, scaling, lp_backend, 3, options.objective, weights, run.closed_loop
            )
        ]
        lp_exact = teachers[0].exact(problem)
        # The sampler serves state-dependent noise only, where the LP is not exact; its set-up
        # (~10 ms) is skipped elsewhere.
        sampler = None
        if not lp_exact:
            sampler = SamplerTeacher(problem, abstraction, proposer, options, scaling, seeds)
        if sampler is not None and sampler.applies(problem):
            teachers.append(sampler)
        eager = lp_exact and system.num_modes == 1
        # An optimum over the horizon is the MILP's job: with an objective, go there at once.
        lazy_budget = 0 if options.objective is not None else options.lazy_candidates
        while True:
            budget.check("the proposer / teacher loop")
            spent = options.termination.work_done(stats.candidates, stats.lp_calls)
            if spent is not None:
                return run.done("budget_exhausted", f"{spent}; {run.counts()}")
            if run.below_until is not None and stats.candidates >= run.below_until:
                spent = "first_found" if options.termination.first_found else "the search budget"
                return run.done("budget_exhausted", f"{spent} after a plan below target; {run.counts()}")
            if eager and switch_to_eager(
                proposer.hard, stats.candidates, lazy_budget, options.lazy_conflict_size
            ):
                result = _eager(run, proposer, abstraction, scaling)
                if result is not None:
                    return _optimise(run, result, proposer, abstraction, scaling, "milp")
                eager = False  # the model could not be bounded soundly: stay lazy
            proposal = proposer.propose()
            if isinstance(proposal, ProposerDry):
                if proposal.proven:
                    return run.done("infeasible", f"{proposal.reason}; {run.counts()}")
                return run.done("budget_exhausted", f"{proposal.reason}; {run.counts()}")
            plan = proposal
            stats.candidates += 1
            verdict = None
            for teacher in teachers:
                verdict = teacher.teach(plan, budget, stats)
                if teacher is teachers[0] and isinstance(teacher, LPTeacher):
                    _guide(proposer, abstraction, teacher, plan)
                if not isinstance(verdict, Unknown):
                    break
            if isinstance(verdict, Refuted) and sampler is not None and sampler in teachers:
                # A proof for this mode sequence only: the sampler chooses its own modes.
                verdict = sampler.rescue(plan, verdict, budget, stats)
            if isinstance(verdict, Refuted):
                proposer.block(verdict.conflict)
                if verdict.set_aside:
                    proposer.set_aside(plan)  # its modes were searched: no proof, not retried
                stats.refuted += 1
                stats.counterexamples += 1
                logger.debug("candidate %d refuted: %s", stats.candidates, verdict.conflict.proof)
                continue
            if isinstance(verdict, Found):
                set_aside = stats.below_target
                checked = _verify(run, verdict.actions, verdict.controls, abstraction, scaling)
                if stats.below_target > set_aside:
                    for teacher in teachers:  # see BELOW_TARGET_MIN
                        if isinstance(teacher, LPTeacher):
                            teacher.mode_search = False
                if checked is not None:
                    found = run.done(
                        "found",
                        f"{verdict.how} met the plan and the monitor agrees",
                        checked.traj,
                        checked.margin,
                        checked.predicted,
                    )
                    path = "lp" if verdict.exact else "sampler"
                    return _optimise(run, found, proposer, abstraction, scaling, path)
                why = (
                    "the plan's predicted closed loop failed the monitor, even repaired"
                    if run.closed_loop
                    else "the plan's predicted execution is below the execution target (repair included)"
                    if stats.below_target > set_aside
                    else "the plan failed the monitor's exact re-check"
                )
            else:
                why = verdict.why if verdict is not None else "no teacher applies"
            proposer.abandon(plan)
            stats.abandoned += 1
            if isinstance(verdict, Unknown) and verdict.why.startswith("sampler"):
                run.sampler_abandoned += 1
            if isinstance(verdict, Unknown) and verdict.closest is not None:
                if run.closest is None or verdict.closest[2] > run.closest[2]:
                    run.closest = verdict.closest
            logger.info("candidate %d abandoned: %s", stats.candidates, why)
    finally:
        stats.sat_calls = proposer.sat_calls
        proposer.close()


def _optimise(
    run: _Run,
    found: SolveResult,
    proposer: BMCProposer,
    abstraction: Abstraction,
    scaling: Scaling,
    path: str,
) -> SolveResult:
    """Optimise a verified plan for the objective (anytime: the best verified plan is kept).

    ``path`` says where the plan came from: ``"lp"`` (the plan LP, exact for its discrete
    plan), ``"milp"`` (the eager MILP, optimal within its bound) or ``"sampler"``.
    """
    options, stats, problem = run.options, run.stats, run.problem
    name = options.objective
    if name is None or found.trajectory is None:
        return found
    formula = problem.stl_formula
    weights = None if options.effort_weights is None else np.asarray(options.effort_weights, dtype=float)
    traj = found.trajectory
    value = objective_value(name, traj, formula, weights)
    stats.improvements.append((run.budget.elapsed(), value))
    optimal, scope, bound = False, "", float("nan")
    how = found.reason
    try:
        if path == "milp":
            optimal, scope, bound = run.milp_proof
        elif path == "lp":
            if name == "time":
                optimal = stats.abandoned == 0
                scope, bound = ("shortest first", value) if optimal else ("", float("nan"))
            else:
                # The plan LP's optimum is over the controls of one set of requirements, with the
                # execution margin kept: no claim about the problem (issue 25).
                eligible = problem.switched_system.num_modes == 1
                if eligible and not options.termination.first_found:
                    better_run = _global(run, proposer, abstraction, scaling, name, weights)
                    if better_run is not None:
                        new_traj, proven, new_bound, horizon = better_run
                        new_value = objective_value(name, new_traj, formula, weights)
                        if better(name, new_value, value):
                            traj, value = new_traj, new_value
                            stats.improvements.append((run.budget.elapsed(), value))
                            how = "the eager MILP chose the plan, the LP timed it, the monitor agrees"
                        if proven and horizon:
                            optimal, scope, bound = True, "horizon", new_bound
        elif not options.termination.first_found:
            traj = refine(
                problem,
                abstraction,
                scaling,
                traj,
                name,
                weights,
                max(options.polish_rounds, 4) * 2,
                stats,
                run.budget.elapsed,
            )
            value = objective_value(name, traj, formula, weights)
    except BudgetExceeded:
        stats.caps_hit.append("time_limit")
        how += " (the time limit stopped the optimisation: the best plan so far)"
    final = _check(run, traj)
    if final is not None and run.execution and traj is not found.trajectory:
        if found.meets_target and not run.predict(traj).meets_target:
            final = None  # the optimised plan lost the execution target the first plan met
    if final is None:
        # The optimiser works on the MLO belief; its plan may lose the closed-loop promise the
        # first plan had: keep that one.
        logger.info("the optimised plan fails the closed-loop check: the first plan is kept")
        traj, final = found.trajectory, _check(run, found.trajectory)
        value, optimal, scope, bound = objective_value(name, traj, formula, weights), False, "", float("nan")
        how = found.reason + " (the optimised plan failed the closed-loop check)"
    if not np.isfinite(bound) and run.mlo_bound is not None:
        # The eager MILP's plan was not returned (below the execution target, or a repair moved
        # it), but its proven bound holds for every plan of its scope, the returned one included.
        bound, scope = run.mlo_bound
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
    margin = robustness(traj, formula) if final is None else final.margin
    result = run.done("found", how, traj, margin, None if final is None else final.predicted)
    result.objective = name
    result.objective_value = value
    result.objective_bound = bound
    result.optimal = optimal
    result.optimal_scope = scope
    if run.joint:  # optimal (and bounded) at the planned risk allocation only: not claimed
        result.optimal, result.optimal_scope, result.objective_bound = False, "", float("nan")
    return result


OPTIMALITY_TOL = 1e-6
"""``optimal=True`` only when ``|value - bound| <= OPTIMALITY_TOL * max(1, |value|)`` (the
result's ``gap``), with the bound proven over the result's ``optimal_scope``."""


def _global(
    run: _Run,
    proposer: BMCProposer,
    abstraction: Abstraction,
    scaling: Scaling,
    name: str,
    weights: np.ndarray | None,
) -> tuple[ProbabilisticTSTrajectory, bool, float, bool] | None:
    """The eager MILP's optimum over every plan up to the horizon (or ``max_plan_length``).

    Returns ``(plan, proven, bound, whole_horizon)`` or ``None`` when the MILP cannot be built
    soundly or finds nothing.
    """
    problem, options, stats, budget = run.problem, run.options, run.stats, run.budget
    init, system = problem.initial_state, problem.switched_system
    while proposer.grow():
        pass
    with stats.clock("time_lp"):
        out = solve_milp(
            proposer.export(),
            abstraction,
            system,
            problem.control_domain,
            init.mean,
            init.cov,
            scaling,
            get_backend(options.milp_backend, integer=True),
            budget,
            name,
            weights,
        )
    stats.milp_calls += 1
    if out.status != "found" or out.claims is None or out.controls is None:
        return None
    if out.proven and proposer.bound >= proposer.H:
        run.mlo_bound = (out.bound, "horizon")
    checked = _retime(run, abstraction, scaling, out.claims, out.controls, name, weights)
    if checked is None:
        return None
    return checked.traj, out.proven, out.bound, proposer.bound >= proposer.H


def _retime(
    run: _Run,
    abstraction: Abstraction,
    scaling: Scaling,
    claims: np.ndarray,
    controls: np.ndarray,
    objective: str | None,
    weights: np.ndarray | None,
    room: float = 0.0,
) -> Verified | None:
    """Verify a MILP's plan, first re-solved by the plan LP on its witness (exact re-timing).

    ``room`` is the least margin (state units) the re-timing leaves inside the required faces.
    Without an objective (or for ``"time"``, whose value is the length) the re-timing also keeps
    the execution margin (:func:`~.teacher.execution_margin`). For ``"effort"`` and ``"margin"``
    it solves the problem as stated (issue 25: the margin kept for execution is not part of the
    optimum the MILP proves): ``"effort"`` tries the tightenings of :data:`RETIME_TIGHTENINGS` in
    turn (the first plan the monitor accepts, so the value is the LP's optimum to ~1e-12 of the
    state's unit instead of 2e-7 of it divided by the input gain), and the MILP's own plan is
    verified too; the better of the two is returned.
    """
    problem, options, stats, budget = run.problem, run.options, run.stats, run.budget
    init, system = problem.initial_state, problem.switched_system
    actions = np.zeros(controls.shape[0], dtype=int)
    witness = extract_witness(problem.stl_formula, claims, abstraction.index, prefer_late=objective != "time")
    optimising = objective in ("effort", "margin")
    found: list[Verified] = []
    if witness is not None:
        required, L = witness
        plan = DiscretePlan(required[:, :L], np.zeros(L, dtype=int), L)
        keep = room if optimising else max(execution_margin(system, init, abstraction, plan), room)
        for tighten in RETIME_TIGHTENINGS if objective == "effort" else (TIGHTEN,):
            context = PlanLPContext.of(problem, abstraction, scaling, get_backend(options.lp_backend))
            goal = LPGoal(objective if optimising else None, weights, tighten)
            with stats.clock("time_lp"):
                lp = solve_plan_lp(
                    context,
                    plan,
                    keep,
                    goal=goal,
                    time_limit=max(budget.remaining(), 1e-3),
                    phases="witness",  # the MILP's witness: no elastic phase when it holds
                )
            stats.lp_calls += 1
            if not (lp.feasible and lp.controls is not None):
                break
            checked = _verify(run, np.zeros(L - 1, dtype=int), lp.controls, abstraction, scaling)
            if not optimising:
                return checked  # the re-timed plan or nothing, as without an objective
            if checked is not None:
                found.append(checked)
                break
    if optimising or not found:
        raw = _verify(run, actions, controls, abstraction, scaling)
        if raw is not None:
            found.append(raw)
    if not found:
        return None
    if objective is None or objective == "time":
        return found[0]
    name = str(objective)
    values = [objective_value(name, v.traj, problem.stl_formula, weights) for v in found]
    best = 0
    for i in range(1, len(found)):
        if better(name, values[i], values[best]):
            best = i
    return found[best]


RETIME_TIGHTENINGS = (1e-12, 1e-10, 1e-8, TIGHTEN)
"""Room (relative to the smallest state unit) the effort re-timing keeps, tried in turn until
the monitor's exact re-check accepts the plan (:func:`_retime`)."""


def _guide(proposer: BMCProposer, abstraction: Abstraction, teacher: LPTeacher, plan: DiscretePlan) -> None:
    """Prefer, in the next SAT searches, the labels the LP's trajectory actually has."""
    out = teacher.last
    if out is None or out.means is None or out.covs is None or not abstraction.num_atoms:
        return
    K = out.means.shape[0] - 1
    truth = np.stack(
        [abstraction.truth(out.means[k], out.covs[k], int(plan.modes[k]) if k else -1) for k in range(K + 1)],
        axis=1,
    )
    proposer.guide(plan, truth)


def _eager(
    run: _Run, proposer: BMCProposer, abstraction: Abstraction, scaling: Scaling
) -> SolveResult | None:
    """Hand an LP-exact, single-mode problem to a MILP back-end (see :mod:`.milp`).

    Returns ``None`` when the model cannot be bounded soundly (the lazy loop goes on).
    """
    problem, options, stats, budget = run.problem, run.options, run.stats, run.budget
    init, system = problem.initial_state, problem.switched_system
    backend = get_backend(options.milp_backend, integer=True)
    weights = None if options.effort_weights is None else np.asarray(options.effort_weights, dtype=float)
    if options.objective in ("effort", "margin"):
        while proposer.grow():  # the optimum over the whole horizon, not the first bound
            pass
    borderline = False  # some bound's infeasibility rested on a tolerance (time's search)
    while True:
        logger.info(
            "%d candidates tried: the eager MILP takes over at %d steps", stats.candidates, proposer.bound + 1
        )
        with stats.clock("time_lp"):
            out = solve_milp(
                proposer.export(),
                abstraction,
                system,
                problem.control_domain,
                init.mean,
                init.cov,
                scaling,
                backend,
                budget,
                options.objective,
                weights,
            )
        stats.milp_calls += 1
        if out.status == "unsupported":
            logger.info("eager MILP not used: %s", out.why)
            return None
        if out.status == "timeout":
            budget.check("the eager MILP")
            return run.done("budget_exhausted", f"the eager MILP stopped: {out.why}; {run.counts()}")
        if out.status == "borderline":
            # No proof either way at this bound: at the horizon that is the answer; below it the
            # search goes on, but no shorter plan is proven absent any more.
            if proposer.bound >= proposer.H or proposer.bound >= proposer.cap:
                return run.done("budget_exhausted", f"{out.why}; {run.counts()}")
            borderline = True
            proposer.grow()
            continue
        if out.status == "infeasible":
            if proposer.bound >= proposer.H:
                return run.done(
                    "infeasible",
                    f"the eager MILP proved that no plan exists within the horizon; {run.counts()}",
                )
            if proposer.bound >= proposer.cap:
                return run.done(
                    "budget_exhausted",
                    f"no plan of at most max_plan_length = {options.max_plan_length} steps (eager MILP); "
                    f"{run.counts()}",
                )
            proposer.grow()
            continue
        break
    claims, controls = out.claims, out.controls
    if claims is None or controls is None:
        return None
    # Re-timed with only the LP's own tightening (2e-7 of the smallest state unit), a plan can
    # graze a face whose unit is larger (ReachAvoid's position, 10x the velocity's: 2e-8 on the
    # scaled row, below HiGHS' tolerance) and fail the monitor by rounding (-1e-15), which cost a
    # second re-timing. Without an objective that reads the margin, the re-timing leaves room of
    # 1e-5 of the largest state unit inside every required face at once.
    room = 1e-5 * float(np.max(scaling.dx)) if options.objective in (None, "time") else 0.0
    whole = proposer.bound >= proposer.H or options.objective == "time"  # shorter plans are all inside
    scope = "horizon" if whole else f"plans of at most {proposer.bound + 1} steps"
    if options.objective is not None and out.proven and not borderline:
        run.mlo_bound = (out.bound, scope)
    checked = _retime(run, abstraction, scaling, claims, controls, options.objective, weights, room)
    if checked is None:
        return None
    run.milp_proof = (out.proven and not borderline, scope, out.bound)
    return run.done(
        "found",
        "the eager MILP chose the plan, the LP timed it, the monitor agrees",
        checked.traj,
        checked.margin,
        checked.predicted,
    )


class Verified(NamedTuple):
    """A plan that passed the monitor: the MLO plan, its margin and, under closed_loop, the
    predicted true-state distribution the margin is about."""

    traj: ProbabilisticTSTrajectory
    margin: float
    predicted: ProbabilisticTSTrajectory | None
    execution: PredictedExecution | None = None


def _check(run: _Run, traj: ProbabilisticTSTrajectory | None) -> Verified | None:
    """The final check of a plan: everything a ``found`` promises, in one place.

    1. the dynamics: the belief is re-rolled from the plan's modes and controls with the exact
       MLO belief dynamics (:func:`~idstlpy.belief.rollout`), and that roll-out is what is
       judged and returned;
    2. the control domain: every input meets every face of ``control_domain`` to
       :data:`DOMAIN_TOL` of the input's unit (:func:`_outside_domain`);
    3. the monitor: on the MLO belief, or under ``guarantee="closed_loop"`` on the true state
       predicted under the executor.

    Inputs far outside the problem's scale on an unbounded control domain are allowed but
    warned about (:func:`_warn_far_inputs`). Returns ``None`` when a promise is broken.
    """
    if traj is None:
        return None
    problem = run.problem
    formula = problem.stl_formula
    traj = rollout(problem.switched_system, problem.initial_state, traj.get_action(), traj.get_control())
    why = _outside_domain(problem.control_domain, traj.get_control(), run.units.du)
    if why:
        logger.warning("a plan was rejected by the final check: %s", why)
        return None
    if not run.closed_loop:
        margin = robustness(traj, formula)
        checked = Verified(traj, margin, None) if margin >= 0 else None
    else:
        predicted, margin, ok, _ = closed_loop_check(
            problem.switched_system, traj, problem.control_domain, formula
        )
        checked = Verified(traj, margin, predicted) if ok else None
    if checked is not None:
        _warn_far_inputs(run, traj.get_control())
    return checked


DOMAIN_TOL = 1e-6
"""How far (in units of the inputs, :class:`~.plan_lp.Scaling`'s ``du``, along each face's
normal) an input may lie outside the control domain and still count as inside it: the LPs'
tolerances are 1e-7 on the same scaled rows."""

FAR_INPUTS = 1e3
"""On an unbounded control domain, inputs beyond this many of the problem's input scale are
warned about (:func:`_warn_far_inputs`)."""


def _outside_domain(domain: Any, controls: np.ndarray, du: np.ndarray) -> str:
    """Why ``controls`` (shape (N, m)) break ``domain``, or ``""`` when every input meets it.

    Each face ``h'u + c <= 0`` is measured in the inputs' units: ``(h'u + c) / ||h * du||``
    (``du``, shape (m,): :class:`~.plan_lp.Scaling`'s input units).
    """
    if controls.shape[0] == 0 or domain.H.shape[0] == 0:
        return ""
    if not np.all(np.isfinite(controls)):
        return "the plan's inputs are not finite"
    norms = np.linalg.norm(domain.H * du[None, :], axis=1)
    norms = np.where(norms > 0, norms, 1.0)
    excess = (controls @ domain.H.T + domain.c[None, :]) / norms[None, :]
    worst = float(np.max(excess))
    if worst <= DOMAIN_TOL:
        return ""
    k, f = np.unravel_index(int(np.argmax(excess)), excess.shape)
    return (
        f"the input at step {int(k)} ({np.array2string(controls[k], precision=6)}) breaks face "
        f"{int(f)} of the control domain by {worst:.3g} of its unit (tolerance {DOMAIN_TOL:g})"
    )


def _warn_far_inputs(run: _Run, controls: np.ndarray) -> None:
    """Warn when a plan on an unbounded control domain uses inputs far outside the problem's scale.

    Inputs beyond :data:`FAR_INPUTS` times the input scale (:func:`_input_scale`) are legal
    but rarely meant (a domain bounded on one side only): a ``UserWarning`` and a logged warning.
    """
    scale = _input_scale(run.problem.switched_system, run.problem.control_domain, run.units)
    if controls.shape[0] == 0 or scale is None:
        return
    ratio = np.max(np.abs(controls), axis=0) / scale
    if not np.any(ratio > FAR_INPUTS):
        return
    j = int(np.argmax(ratio))
    msg = (
        f"the plan uses input u[{j}] = {float(np.max(np.abs(controls[:, j]))):.6g}, "
        f"{float(ratio[j]):.3g} times the problem's input scale ({float(scale[j]):.3g}), "
        "on an unbounded control_domain: bound the control domain if such inputs are not meant"
    )
    logger.warning(msg)
    warnings.warn(msg, UserWarning, stacklevel=2)


def _verify(
    run: _Run, actions: np.ndarray, controls: np.ndarray, abstraction: Abstraction, scaling: Scaling
) -> Verified | None:
    """Re-roll the exact belief dynamics and run the final check (:func:`_check`); the plan and
    its margin if it passes.

    Under ``guarantee="closed_loop"`` a plan whose predicted true state fails is repaired first
    (:func:`~.certify.certify`).
    """
    problem = run.problem
    traj = rollout(problem.switched_system, problem.initial_state, actions, controls)
    if run.closed_loop:
        certified = _certify(run, traj, abstraction, scaling)
        # The final check (the domain, the roll-out, the prediction) is _check's, as for every plan.
        return None if certified is None else _check(run, certified.traj)
    checked = _check(run, traj)
    if checked is None:
        logger.warning(
            "candidate failed the final re-check (monitor margin %.3g)",
            robustness(traj, problem.stl_formula),
        )
    if checked is not None and run.execution:
        return _hold(run, checked, abstraction, scaling)
    return checked


def _hold(run: _Run, checked: Verified, abstraction: Abstraction, scaling: Scaling) -> Verified | None:
    """Under ``guarantee="execution"``: the verified plan if its predicted execution meets the
    target, else its closed-loop repair (:func:`~.certify.certify`) if that keeps the paper's semantics and
    meets it; otherwise the better of the two is set aside (:meth:`_Run.set_aside`) and None
    returned (the candidate is abandoned, the search goes on)."""
    execution = run.predict(checked.traj)
    checked = checked._replace(execution=execution)
    if execution.meets_target:
        return checked
    logger.info("verified plan below the execution target (%s): repairing", execution.summary())
    room = run.stats.execution_room
    modes = tuple(int(a) for a in checked.traj.get_action())
    repaired = None
    if modes not in run.unrepaired:  # the repair keeps the modes: once per mode sequence
        try:
            repaired = _certify(run, checked.traj, abstraction, scaling)
        finally:
            run.stats.execution_room = room
    best = checked
    if repaired is not None:
        margin = robustness(repaired.traj, run.formula)
        if margin >= 0:  # the repair keeps the MLO semantics (it should: its covariances are larger)
            ex = run.predict(repaired.traj)
            fixed = Verified(repaired.traj, margin, None, ex)
            if ex.meets_target:
                logger.info("the closed-loop repair meets the execution target (%s)", ex.summary())
                return fixed
            if ex.shortfall < execution.shortfall:
                best = fixed
    run.unrepaired.add(modes)
    logger.info("plan set aside below the execution target: %s", (best.execution or execution).summary())
    run.set_aside(best)
    return None


def _certify(
    run: _Run, traj: ProbabilisticTSTrajectory, abstraction: Abstraction, scaling: Scaling
) -> Certified | None:
    """The closed-loop repair (:func:`~.certify.certify`) of ``traj`` with this solve's parts."""
    context = PlanLPContext.of(run.problem, abstraction, scaling, get_backend(run.options.lp_backend))
    rounds, exact = run.options.polish_rounds, run.proofs_hold
    return certify(context, run.problem, traj, exact=exact, rounds=rounds, stats=run.stats, budget=run.budget)
