"""Re-solving a problem from an executed belief, and judging the new plan.

The parts of re-planning that call the solver and the closed-loop prediction, shared by
:class:`~idstlpy.execution.replanner.ReplanningExecutor` (hence :func:`idstlpy.execute`) and
:func:`idstlpy.start_check`: the record of an attempt (:class:`Replan`), the re-solve seeds
(:func:`replan_seed`), the risk model (a plan's predicted success) and the resolver (re-solve,
compare, the start check).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..belief import GaussianBelief, to_belief
from ..errors import IdstlpyError, InvalidArgumentError, InvalidTypeError
from ..executor import ExecutorSpec
from ..formulas import FALSE, TRUE, STLFormula
from ..synthesis.options import SolverOptions
from ..synthesis.problem import Problem, solve
from ..trajectory import ProbabilisticTSTrajectory
from .policy import Adopt, ReplanPolicy, RiskMeasure, RiskOn

if TYPE_CHECKING:
    from .prediction import ClosedLoopPrediction

__all__ = ["Replan", "replan_seed"]

logger = logging.getLogger(__name__)

_REPLAN_KEY = 0x5E501E  # spawn-key word of the re-solve seeds (distinct from validate's children)


@dataclass(frozen=True, eq=False)
class Replan:
    """One re-plan attempt of :func:`~idstlpy.execute` (or of a :class:`ReplanningExecutor`).

    Parameters
    ----------
    step : int
        Execution step ``k`` of the attempt: the re-solve starts from the executed belief ``X_k``.
    reason : str
        ``"risk"`` (predicted success below ``risk`` at a scheduled check), ``"drift"`` (the
        same at a check made because the belief left its predicted ellipse), ``"start"`` (the
        same before the first step, ``start_resolves``), ``"every"`` (the schedule) or
        ``"violated"`` (the executed prefix already broke the formula: nothing to re-solve).
    predicted : float
        Predicted success of the remaining plan at this step (NaN when not predicted).
    status : str
        The re-solve's ``SolveResult.status`` (``"found"``, ``"infeasible"``,
        ``"budget_exhausted"``), ``"error"`` when building the problem failed, or ``"skipped"``.
    adopted : bool
        Whether the new plan replaced the old one.
    new_predicted : float
        Predicted success of the new plan (NaN when not predicted).
    solve_time : float
        Wall-clock seconds of the re-solve (not part of equality).
    plan_steps : int
        Steps of the new plan (0 without one).
    seed : int
        The solver seed used (derived, see :func:`replan_seed`).
    formula : str
        The progressed formula that was re-solved.
    reason_text : str
        The solver's ``reason`` (or the error).
    caps_hit : tuple of str
        Wall-clock caps the re-solve hit (reproducibility is not promised then).
    delay : int
        Steps between the attempt (``step``) and the step at which it took effect (its plan
        followed, or the old one kept): the policy's ``adopt_delay``, or more when a background
        re-solve finished later (:class:`~idstlpy.ReplanningExecutor`).
    """

    step: int
    reason: str
    predicted: float
    status: str
    adopted: bool
    new_predicted: float = float("nan")
    solve_time: float = field(default=0.0, compare=False)
    plan_steps: int = 0
    seed: int = 0
    formula: str = ""
    reason_text: str = ""
    caps_hit: tuple[str, ...] = ()
    delay: int = 0

    def _key(self) -> tuple[Any, ...]:
        # NaN (no prediction) equals NaN here: two runs of the same seed give equal records.
        return tuple(
            "nan" if isinstance(v, float) and math.isnan(v) else v
            for f, v in vars(self).items()
            if f != "solve_time"
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Replan):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())


def check_problem_plan(problem: object, plan: object, what: str) -> None:
    """Raise a package error naming ``problem`` or ``plan`` when they cannot be executed."""
    if not isinstance(problem, Problem):
        raise InvalidTypeError(f"problem must be a Problem, got {type(problem).__name__}")
    if plan is None:
        raise InvalidArgumentError(
            f"plan is None: there is no plan to {what} (see problem.last_result.reason)"
        )
    if not isinstance(plan, ProbabilisticTSTrajectory):
        raise InvalidTypeError(f"plan must be a ProbabilisticTSTrajectory, got {type(plan).__name__}")


def replan_seed(seed_sequence: np.random.SeedSequence, index: int) -> int:
    """The solver seed of re-plan ``index`` of an execution (a fixed function of the seed).

    Parameters
    ----------
    seed_sequence : numpy.random.SeedSequence
        The execution's seed sequence (its noise stream is ``default_rng(seed_sequence)``).
    index : int
        0 for the first re-plan attempt, 1 for the second, ...

    Returns
    -------
    int
        A seed in ``[0, 2**63)``, independent of the execution's noise stream.
    """
    child = np.random.SeedSequence(
        seed_sequence.entropy, spawn_key=(*seed_sequence.spawn_key, _REPLAN_KEY, int(index))
    )
    return int(child.generate_state(1, np.uint64)[0] >> np.uint64(1))


def _suffix(plan: ProbabilisticTSTrajectory, j: int) -> ProbabilisticTSTrajectory:
    """Steps ``j .. N`` of a plan as a plan of its own."""
    return ProbabilisticTSTrajectory(
        plan.get_mean()[j:], plan.get_cov()[j:], plan.get_action()[j:], plan.get_control()[j:]
    )


@dataclass(frozen=True)
class _RiskModel:
    """How the executor predicts a plan's success: the planning model only (the executor's
    gains, control domain and process noise) and the measure a risk threshold reads."""

    spec: ExecutorSpec
    measure: RiskMeasure
    on: RiskOn
    samples: int

    @classmethod
    def make(cls, spec: ExecutorSpec, policy: ReplanPolicy) -> _RiskModel:
        return cls(spec, policy.risk_measure, policy.risk_on, policy.risk_samples)

    def predict(
        self, plan: ProbabilisticTSTrajectory, j: int, psi: STLFormula, belief: GaussianBelief
    ) -> tuple[float, ClosedLoopPrediction | None]:
        """Predicted probability that the rest of ``plan`` from its step ``j``, started at
        ``belief``, satisfies ``psi``; and the prediction (None for a constant formula)."""
        if psi is TRUE or psi is FALSE:
            return (1.0 if psi is TRUE else 0.0), None
        from .prediction import predict_closed_loop

        spec = self.spec
        pred = predict_closed_loop(
            spec.system,
            _suffix(plan, j),
            None,  # the planning model: the executor does not know the real system
            belief.mean,
            formula=psi,
            control_domain=spec.control_domain,
            # the executor knows only its model: its noise, unless the run has none at all
            process_noise="none" if spec.process_noise == "none" else "model",
            lqr_gains={q: list(Ks) for q, Ks in spec.gains_for(plan).items()},  # by mode, not position
            initial_belief=belief,
            real_initial_cov=belief.cov,
            samples=self.samples if self.measure == "estimate" else 0,
            seed=0,
            closure="gaussian",  # a check is made often: the cheap closure
        )
        if self.measure == "bound":
            b, s = pred.belief_success_bound, pred.state_success_bound
        else:
            b, s = pred.belief_success_estimate, pred.state_success_estimate
        value = {"belief": b, "state": s, "both": min(b, s)}[self.on]
        return (float(value) if math.isfinite(value) else 0.0), pred


@dataclass(frozen=True)
class _Resolver:
    """Re-solves a problem from a belief and judges the new plan (the policy's ``adopt``)."""

    problem: Problem
    model: _RiskModel
    options: SolverOptions  # capped at the policy's replan_time_limit
    adopt: Adopt

    def resolve(
        self, belief: GaussianBelief, psi: STLFormula, seed: int, step: int, reason: str, predicted: float
    ) -> tuple[Replan, ProbabilisticTSTrajectory | None]:
        """Re-solve ``psi`` from ``belief``; the record and the new plan (None when none was found)."""
        problem = self.problem
        t0 = time.perf_counter()
        try:
            cov = 0.5 * (belief.cov + belief.cov.T)  # the filter's Joseph form is symmetric up to rounding
            sub = Problem(problem.switched_system, problem.control_domain, to_belief(belief.mean, cov), psi)
            result = solve(sub, self.options.with_(seed=seed))
        except IdstlpyError as exc:
            # A re-plan that cannot even be posed keeps the old plan; the record says why.
            why = f"{type(exc).__name__}: {exc}"
            elapsed = time.perf_counter() - t0
            record = Replan(step, reason, predicted, "error", False, solve_time=elapsed, seed=seed,
                            formula=str(psi), reason_text=why)  # fmt: skip
            return record, None
        new = result.trajectory if result.status == "found" else None
        record = Replan(
            step,
            reason,
            predicted,
            result.status,
            adopted=new is not None,
            solve_time=time.perf_counter() - t0,
            plan_steps=0 if new is None else new.num_of_steps,
            seed=seed,
            formula=str(psi),
            reason_text=str(result.reason),
            caps_hit=tuple(result.stats.caps_hit),
        )
        return record, new

    def judge(
        self,
        record: Replan,
        new: ProbabilisticTSTrajectory | None,
        old: tuple[ProbabilisticTSTrajectory, int],
        psi: STLFormula,
        belief: GaussianBelief,
        p_old: float,
        predict_always: bool = False,
    ) -> tuple[Replan, float, ClosedLoopPrediction | None]:
        """A re-solve's record with the comparison ``adopt`` asks for; the new plan's predicted
        success and prediction (NaN and None when not predicted).

        ``adopt="better"``: a fresh MLO plan may track worse than the one followed (``old``: the
        plan and its step ``j``, predicted ``p_old``, NaN when not yet predicted), so it is
        adopted only when predicted better. ``"always"``: adopted when found, predicted only with
        ``predict_always``.
        """
        if new is None or (self.adopt == "always" and not predict_always):
            return record, math.nan, None
        if math.isnan(p_old):
            p_old, _ = self.model.predict(old[0], old[1], psi, belief)
        p_new, pred = self.model.predict(new, 0, psi, belief)
        adopted = self.adopt == "always" or p_new > p_old
        return replace(record, predicted=p_old, new_predicted=p_new, adopted=adopted), p_new, pred

    def check_start(
        self,
        plan: ProbabilisticTSTrajectory,
        belief: GaussianBelief,
        risk: float,
        resolves: int,
        seed_of: Callable[[int], int],
    ) -> tuple[ProbabilisticTSTrajectory, float, ClosedLoopPrediction | None, list[Replan]]:
        """The start check (:func:`~idstlpy.start_check`): the plan to follow, its predicted
        success, its prediction and the re-solve records. ``seed_of(i)`` seeds re-solve ``i``."""
        formula = self.problem.stl_formula
        p, pred = self.model.predict(plan, 0, formula, belief)
        current = plan
        records: list[Replan] = []
        for i in range(resolves):
            if p >= risk:
                break
            record, new = self.resolve(belief, formula, seed_of(i), 0, "start", p)
            # the loop goes on while below the risk: the new plan is predicted whatever ``adopt``
            record, p_new, new_pred = self.judge(record, new, (current, 0), formula, belief, p, True)
            records.append(record)
            logger.info(
                "start check: re-solve %d %s (%s, predicted %.3g -> %.3g, %.2f s)",
                i,
                "adopted" if record.adopted else "kept the old plan",
                record.status,
                p,
                p_new,
                record.solve_time,
            )
            if record.adopted and new is not None:
                current, p, pred = new, p_new, new_pred
        return current, p, pred, records
