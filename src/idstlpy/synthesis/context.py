"""The context of one solve: what every step of the synthesis loop reads, in one object.

A :class:`SolveContext` holds the problem, the options, the wall-clock :class:`~.interfaces.Budget`
and the :class:`~.results.SolveStats` of one solve, the problem's propositions
(:class:`~.abstraction.Abstraction`) and units (:class:`~.plan_lp.Scaling`), what the guarantee
asks (closed loop, execution target) and whether proofs carry over to it, and the little state
the loop keeps between candidates: the closest partial plan a teacher reported and, in a
:class:`TargetWatch`, the last predicted execution and the best verified plan set aside below the
execution target. The loop and its parts
(:mod:`.cegis`, :mod:`.eager`, :mod:`.optimise`, :mod:`.final_check`, :mod:`.finish`) take it
instead of repeating ``problem, options, budget, stats, abstraction, scaling`` in every signature.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..errors import IdstlpyError
from ..executor.predict import predict_closed_loop
from ..tracking import TrackingGains
from ..trajectory import ProbabilisticTSTrajectory
from .abstraction import Abstraction
from .interfaces import Budget
from .options import SolverOptions
from .plan_lp import Scaling, lp_exact
from .results import PredictedExecution, SolveStats
from .termination import SearchProgress
from .tracking_choice import tracking_candidates

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = [
    "ASIDE_WHY",
    "BELOW_TARGET_EXTRA",
    "BELOW_TARGET_MIN",
    "BELOW_TARGET_PATIENCE",
    "BELOW_TARGET_SEARCHED",
    "JUDGE_STANDARD_ERRORS",
    "PREDICT_SAMPLES",
    "REPORT_HALF_WIDTH",
    "REPORT_MAX_SAMPLES",
    "SolveContext",
    "plan_key",
    "TargetWatch",
    "Verified",
    "Verify",
]

logger = logging.getLogger(__name__)

PREDICT_SAMPLES = 1000
"""Model samples (and particles of the particle closure) of each candidate's predicted execution:
the estimates' standard error is at most 1.6 points, 0.7 near a 95% rate."""
REPORT_HALF_WIDTH = 0.005
"""The returned plan's predicted execution (:meth:`TargetWatch.report`) is re-sampled with enough
samples that each estimate's 95% interval is about this wide on each side (half a point), or a
quarter of the estimate's distance from its target when that is wider (a plan far from the
target needs no finer reading to say so) ..."""
REPORT_MAX_SAMPLES = 20000
"""... with at most this many samples (the particles stay :data:`PREDICT_SAMPLES`: the loop's
moments, so the report samples the very loop the search judged)."""
JUDGE_STANDARD_ERRORS = 3.0
"""A candidate whose quick estimate misses the target by less than this many standard errors (of
a :data:`PREDICT_SAMPLES`-sample estimate at the target) is judged on the precise report: the
precise estimate of a plan set aside beyond it meets the target with probability below 0.2%."""
BELOW_TARGET_EXTRA = 2.0
"""Under ``guarantee="execution"``, after the first verified plan below target (found after ``c``
candidates) the search goes on for at most ``BELOW_TARGET_EXTRA * c`` more candidates ..."""
BELOW_TARGET_MIN = 200
"""... and at least this many (a work budget: the same seed gives the same plan). From then on
the plan LP's mode search (issue 24) is off: it scores modes on the MLO plan LP, and maps the
proposer's mode sequences back to the plan just set aside (a "look on the last step"); the
proposer's own enumeration of mode sequences is what finds plans that hold when executed."""
BELOW_TARGET_SEARCHED = 20
"""The least extra candidates instead of :data:`BELOW_TARGET_MIN` when the mode search reads the
execution (:class:`~.mode_search.RoomScore`: several modes, the plan LP exact): each candidate's
modes were already searched for the plan that holds best, and its requirement set is set aside
for every mode sequence, so one candidate covers what the proposer's enumeration took hundreds
for."""
BELOW_TARGET_PATIENCE = 6
"""The search after a plan below target also stops once this many verified plans in a row were
plans it had already set aside (the same modes and controls, so the same predicted execution):
the search has converged, and the candidates left in its budget would only find them again (the
perception suite's narrow noisy hold: the sampler's plan, given its room, came back identical
six times in a row and the search ran to its 60 s cap). Counted in plans, not seconds: the same
seed gives the same plan. New plans that do not improve on the best do not count: the sampler's
plans are fresh draws, and on the recurrent-sensing family the plan that meets the target came
after 6 new plans in a row that did not improve."""


ASIDE_WHY = {
    "gave up": "given up by a teacher",
    "below target": "with a verified plan below the execution target",
    "unverified": "with a plan that failed the verify step",
    "no modes": (
        "refuted for the modes tried, their requirements set aside for the other mode sequences "
        "after the mode search met them with none"
    ),
}
"""What a candidate was set aside for (:meth:`SolveContext.set_aside`), in a reason's words."""


class Verified(NamedTuple):
    """A plan that passed the monitor: the MLO plan, its margin and, under closed_loop, the
    predicted true-state distribution the margin is about."""

    traj: ProbabilisticTSTrajectory
    margin: float
    predicted: ProbabilisticTSTrajectory | None
    execution: PredictedExecution | None = None


Verify = Callable[[np.ndarray, np.ndarray], Verified | None]
"""The loop's verify step for a plan's modes and controls (``cegis.verify``), as the parts that
verify plans of their own (the eager MILP) are handed it."""


class SolveContext:
    """One solve: the problem, its options, budget, statistics, units, what the guarantee asks,
    and the loop's memory (the closest partial plan, the execution target's :class:`TargetWatch`).

    Parameters
    ----------
    problem : Problem
    options : SolverOptions
    start : float
        ``time.perf_counter()`` at the first line of ``solve``: the wall-clock cap counts from it.
    """

    def __init__(self, problem: Problem, options: SolverOptions, start: float) -> None:
        self.problem = problem
        self.options = options
        self.formula = problem.stl_formula
        self.budget = Budget(options.total_time_cap, start)
        self.stats = SolveStats()
        system, init = problem.switched_system, problem.initial_state
        self.abstraction = Abstraction(self.formula, system.n)
        self.units = Scaling.compute(system, problem.control_domain, init.mean, init.cov, self.abstraction)
        self.closed_loop = options.guarantee == "closed_loop"
        self.execution = options.guarantee == "execution"
        # Under closed_loop, MLO proofs carry over only when the filter covariance is the MLO one.
        self.proofs_hold = not self.closed_loop or lp_exact(system)
        # Joint chance constraints are planned at one risk allocation (a sufficient condition):
        # a refutation under it proves nothing about the others.
        self.joint = any(ap.joints for ap in self.formula.atomic_propositions())
        # Candidates abandoned for want of work (a budget option can change them).
        self.budget_abandoned = 0
        # Candidates set aside without a proof, by why (ASIDE_WHY's keys): the reason of a
        # search that ran dry on them says which.
        self.aside: dict[str, int] = {}
        # The closest partial plan a teacher reported (actions, controls, progress), for a
        # budget_exhausted result to show what the search got to.
        self.closest: tuple[np.ndarray, np.ndarray, float] | None = None
        # When no teacher reported one: how to get the longest feasible prefix of the last
        # candidate a proof refuted (set by the loop; called once, by finish).
        self.partial: Callable[[], tuple[np.ndarray, np.ndarray, float] | None] | None = None
        self.partial_depth = 0
        # How many candidates of at most the current length remain (counted up to a cap by
        # setting each aside; ``None`` past the cap): set by the loop, called once, by finish.
        self.remaining: Callable[[int], tuple[int, int] | None] | None = None
        self.uncounted_sat_calls = 0  # the count's (not the search's)
        self.target = TargetWatch(problem, options, self.stats)

    @property
    def weights(self) -> np.ndarray | None:
        """The effort weights as an array, shape (m,) (``None``: every input weighs 1)."""
        return self.options.objectives.weights

    def set_aside(self, why: str) -> None:
        """Count one candidate set aside without a proof (``why``: a key of :data:`ASIDE_WHY`)."""
        self.aside[why] = self.aside.get(why, 0) + 1

    def aside_reason(self) -> str:
        """Why the proposer ran dry on candidates set aside without a proof, by what set them
        aside (each count a fact of this solve)."""
        parts = [f"{n} {ASIDE_WHY[why]}" for why, n in sorted(self.aside.items()) if n]
        tail = f" ({'; '.join(parts)})" if parts else ""
        return f"every remaining candidate was set aside without a proof{tail}"

    def counts(self) -> str:
        """The candidates so far, as a reason's tail."""
        s = self.stats
        return f"{s.candidates} candidates: {s.refuted} refuted by proofs, {s.abandoned} abandoned"

    def work_stop(self) -> str | None:
        """Why the termination ends the search here (a work budget, then a stop rule: a user
        predicate or a cancellation, which ``caps_hit`` then names), or ``None``. Checked
        before each candidate (and each round of the joint MILP)."""
        termination, s = self.options.termination, self.stats
        spent = termination.work_done(s.candidates, s.lp_calls)
        if spent is not None or not termination.rules:
            return spent
        progress = SearchProgress(
            s.candidates, s.lp_calls, s.milp_calls, s.refuted, s.abandoned, self.budget.elapsed()
        )
        held = termination.rule_reached(progress)
        if held is None:
            return None
        if held.cap is not None and held.cap not in s.caps_hit:
            s.caps_hit.append(held.cap)
        return held.reason


class TargetWatch:
    """What the loop remembers about the execution target: the last predicted execution, the best
    verified plan set aside below the target, and when the search for a better one stops.

    Parameters
    ----------
    problem : Problem
    options : SolverOptions
    stats : SolveStats
        The solve's statistics (predictions and plans below target are counted there).
    """

    def __init__(self, problem: Problem, options: SolverOptions, stats: SolveStats) -> None:
        self.problem = problem
        self.options = options
        self.stats = stats
        # Under "execution": the best verified plan below target so far, and the candidate count
        # at which the search stops looking for one that meets it.
        self.below: Verified | None = None
        self.below_until: int | None = None
        # the least extra candidates after a plan below target (BELOW_TARGET_SEARCHED when the
        # mode search reads the execution)
        self.least_extra = BELOW_TARGET_MIN
        self.unrepaired: set[tuple[int, ...]] = set()  # mode sequences whose repair fell short
        # each verified plan set aside (its modes and controls) and what was set aside for it
        self.seen: dict[bytes, Verified] = {}
        # verified plans in a row that had been set aside before (BELOW_TARGET_PATIENCE)
        self.repeats = 0
        self._predicted: tuple[ProbabilisticTSTrajectory, PredictedExecution] | None = None
        self._reported: tuple[bytes, PredictedExecution] | None = None
        # the gain sets plans may be tracked with, the one the search plans with first
        # (:mod:`.tracking_choice`); per plan set to another, what each set predicted
        self.tracking = tracking_candidates(problem, options.target.tracking)
        self.tried: dict[bytes, list[tuple[TrackingGains, PredictedExecution]]] = {}

    def predict(self, traj: ProbabilisticTSTrajectory) -> PredictedExecution:
        """The plan's predicted execution against the target (the last one is remembered).

        The planner's reading of the execution: the true start drawn from the prior, the
        model's noise, the modes' tracking gains, inputs clipped to the control domain. A
        prediction that cannot be made (a diverging loop) counts as below target (NaN rates).
        """
        if self._predicted is not None and self._predicted[0] is traj:
            return self._predicted[1]
        out = self._predict(traj, PREDICT_SAMPLES)
        if out is None:
            nan = float("nan")
            out = PredictedExecution(nan, nan, nan, nan, {}, self.options.execution_target)
        self._predicted = (traj, out)
        return out

    def _predict(self, traj: ProbabilisticTSTrajectory, samples: int) -> PredictedExecution | None:
        """The planner's reading of the plan's execution with ``samples`` model samples and
        :data:`PREDICT_SAMPLES` particles, seed 0 (the one call candidates and the report
        share); None when it cannot be made (a diverging loop)."""
        problem, stats = self.problem, self.stats
        with stats.clock("time_prediction"):
            try:
                pred = predict_closed_loop(
                    problem,
                    traj,
                    real_initial_cov=problem.initial_state.cov,
                    samples=samples,
                    particles=PREDICT_SAMPLES,
                    seed=0,
                )
            except IdstlpyError as exc:
                logger.info("the plan's execution could not be predicted: %s", exc)
                return None
        stats.predictions += 1
        return PredictedExecution.from_prediction(pred, self.options.execution_target)

    def judge(self, traj: ProbabilisticTSTrajectory) -> PredictedExecution:
        """The loop's verdict on a verified plan: its predicted execution against the target.

        A plan whose :data:`PREDICT_SAMPLES`-sample prediction meets the target, or misses it by
        less than :data:`JUDGE_STANDARD_ERRORS` standard errors, is judged on the precise
        re-sampling :meth:`report` gives, the numbers its result would carry: the loop
        then never accepts a plan on the quick estimate that the result reports below target
        (recurrent sensing's plan met on 1000 samples, was reported at 89.7% and returned
        flagged after 11 candidates, where the search goes on to one that meets). A plan below
        on the quick estimate is below (the precise one is made only for plans that may be
        returned).
        """
        quick = self._fit_tracking(traj, self.predict(traj))
        return self.report(traj) if self._plausible(quick) else quick

    def _fit_tracking(self, traj: ProbabilisticTSTrajectory, quick: PredictedExecution) -> PredictedExecution:
        """A plan below target under the default gains, predicted with the other gain sets
        (:mod:`.tracking_choice`) in order: the first that meets the target, else the one that
        comes closest (ties: the earlier), is kept on the plan (``traj.tracking``) and its
        prediction returned. Deterministic: each prediction has the fixed seed."""
        if self._plausible(quick) or len(self.tracking) < 2 or traj.tracking is not None:
            return quick
        tried = [(self.tracking[0], quick)]
        best = tried[0]
        for gains in self.tracking[1:]:
            traj.tracking = gains
            pred = self._predict(traj, PREDICT_SAMPLES)
            if pred is None:
                continue
            tried.append((gains, pred))
            if pred.shortfall < best[1].shortfall:
                best = (gains, pred)
            if self._plausible(pred):
                best = (gains, pred)
                break
        traj.tracking = None if best[0] is self.tracking[0] else best[0]
        self.tried[plan_key(traj)] = tried
        self._predicted = (traj, best[1])
        return best[1]

    def _plausible(self, quick: PredictedExecution) -> bool:
        """Whether the precise estimate may meet the target: the quick one meets it, or falls short
        by less than :data:`JUDGE_STANDARD_ERRORS` of its standard errors on each reading (the
        plans the report could call "meets" are judged on the report, not set aside on 1000
        samples)."""
        target = self.options.execution_target
        for rate, bar in ((quick.belief_estimate, target.belief), (quick.state_estimate, target.state)):
            if not np.isfinite(rate):
                return False
            se = np.sqrt(max(bar * (1.0 - bar), 1e-12) / PREDICT_SAMPLES)
            if rate < bar - JUDGE_STANDARD_ERRORS * se:
                return False
        return True

    def report(self, traj: ProbabilisticTSTrajectory) -> PredictedExecution:
        """The returned plan's predicted execution, sampled more precisely than a candidate's.

        The loop judges each candidate on :data:`PREDICT_SAMPLES` samples (a standard error up to
        0.7 points near 95%); what the result reports is re-sampled from the same predicted loop
        (same particles, same seed) with as many samples as make both estimates' 95% intervals
        :data:`REPORT_HALF_WIDTH` wide on each side (or a quarter of their distance from the
        target), judged at the candidate's estimates (at most :data:`REPORT_MAX_SAMPLES`).
        Deterministic: the count depends on the candidate's estimates only. The flag
        (``meets_target``) is the precise estimates'.
        """
        key = plan_key(traj)
        if self._reported is not None and self._reported[0] == key:
            return self._reported[1]
        out = self._report(traj)
        self._reported = (key, out)
        return out

    def _report(self, traj: ProbabilisticTSTrajectory) -> PredictedExecution:
        """:meth:`report`'s re-sampling (not remembered)."""
        quick = self.predict(traj)
        target = self.options.execution_target
        samples = PREDICT_SAMPLES
        for rate, bar in ((quick.belief_estimate, target.belief), (quick.state_estimate, target.state)):
            if not np.isfinite(rate):
                return quick
            half = max(REPORT_HALF_WIDTH, abs(rate - bar) / 4.0)
            samples = max(samples, int(np.ceil(1.959964**2 * rate * (1.0 - rate) / half**2)))
        samples = min(samples, REPORT_MAX_SAMPLES)
        if samples <= PREDICT_SAMPLES:
            return quick
        # (the candidate's prediction was made: a failure here is not expected)
        precise = self._predict(traj, samples)
        return quick if precise is None else precise

    def known(self, traj: ProbabilisticTSTrajectory) -> Verified | None:
        """What was set aside for the same plan (modes and controls) before, or ``None``: its
        predicted execution is the same (the prediction's seed is fixed), so it is below target."""
        return self.seen.get(plan_key(traj))

    def set_aside(self, checked: Verified, plan: Verified | None = None) -> None:
        """Keep a verified plan below target if it is the best so far; start the extra search.

        ``checked`` is what is set aside for the verified plan ``plan`` (default ``checked``
        itself; its closed-loop repair when that did better): a plan set aside before counts
        toward :data:`BELOW_TARGET_PATIENCE` (:attr:`repeats`), a new one resets the count.
        """
        stats = self.stats
        stats.below_target += 1
        key = plan_key((checked if plan is None else plan).traj)
        if key in self.seen:
            self.repeats += 1
        else:
            self.repeats = 0
            self.seen[key] = checked
        ex = checked.execution
        if self.below is None or (
            ex is not None
            and self.below.execution is not None
            and ex.shortfall < self.below.execution.shortfall
        ):
            self.below = checked
        if self.below_until is None:
            c = stats.candidates
            extra = max(self.least_extra, int(np.ceil(BELOW_TARGET_EXTRA * c)))
            self.below_until = c if self.options.termination.first_found else c + extra

    def stop_reason(self, candidates: int) -> str | None:
        """Why the search after a plan below target stops before the next candidate (its
        candidate budget is spent, or the last :data:`BELOW_TARGET_PATIENCE` verified plans had
        all been set aside before), or ``None`` (also before any plan was set aside)."""
        if self.below_until is None:
            return None
        if candidates >= self.below_until:
            return "first_found" if self.options.termination.first_found else "the search budget"
        if self.repeats >= BELOW_TARGET_PATIENCE:
            return (
                f"the last {self.repeats} verified plans had all been set aside before (the search converged)"
            )
        return None


def plan_key(traj: ProbabilisticTSTrajectory) -> bytes:
    """A plan's modes and controls, byte for byte (the same plan found again)."""
    actions = np.ascontiguousarray(traj.get_action(), dtype=np.int64)
    controls = np.ascontiguousarray(traj.get_control(), dtype=np.float64)
    return actions.tobytes() + b"|" + controls.tobytes()
