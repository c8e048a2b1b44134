"""The re-planning online executor: one observation in, the next mode and input out, re-solving
the problem from the executed belief when the policy asks for it.

:class:`ReplanningExecutor` is :class:`idstlpy.OnlineExecutor` (Kalman filter, receding-horizon
LQR tracking, clipping) plus the checks and re-solves of :func:`idstlpy.execute`, driven from the
user's own loop (a robot's control loop, a ROS 2 node: ``examples/ros2_node.py``)::

    runner = ReplanningExecutor(problem, plan, ReplanPolicy(risk=0.8, check_every=5), seed=0)
    observation = None                          # nothing observed before the first input
    while not runner.done:
        mode, u = runner.step(observation)      # filter update, checks / re-solve, tracking law
        if runner.last_replan is not None:      # a re-plan attempt was made at this step
            log(runner.last_replan)
        robot.switch_sensor(mode); robot.apply(u)
        observation = robot.read_sensor()       # the planning mode's sensor (None if blind)
    runner.observe(observation)                 # the final belief

:func:`idstlpy.execute` is this loop with a simulated plant, so a robot running this object
re-plans exactly as the simulated executions do (same checks, same re-solve seeds).

A step without a check costs what an :class:`~idstlpy.OnlineExecutor` step costs plus the
bookkeeping of the executed prefix (tens of microseconds); a check costs one closed-loop
prediction of the remaining plan, a re-solve one solve (capped by ``replan_time_limit``): run the
object where such a pause is acceptable, or re-plan on another thread and keep stepping.

The policy (:class:`ReplanPolicy`) is the typed form of ``execute``'s re-planning keywords and of
``validate``'s ``replan_options`` (see :mod:`idstlpy.execution.replanning` for what each means).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from scipy.stats import chi2

from .._checks import as_float, as_int, as_seed_sequence
from ..belief import GaussianBelief, to_belief
from ..errors import IdstlpyError, InvalidArgumentError, InvalidTypeError
from ..executor import ExecutorSpec, OnlineExecutor
from ..formulas import FALSE, TRUE, STLFormula
from ..progression import progress
from ..synthesis.options import SolverOptions
from ..synthesis.problem import Problem
from ..trajectory import ProbabilisticTSTrajectory

if TYPE_CHECKING:
    from .prediction import ClosedLoopPrediction

__all__ = ["Replan", "ReplanPolicy", "ReplanningExecutor", "replan_seed"]

logger = logging.getLogger(__name__)

ReplanTrigger = Literal["on_risk", "every"]
"""When a re-solve is considered: a predicted success below ``risk``, or a fixed schedule."""
RiskMeasure = Literal["bound", "estimate"]
"""The prediction's sound lower bound, or its sampled point estimate."""
RiskOn = Literal["belief", "state", "both"]
"""Whose success a risk threshold reads: the executed belief's, the true state's, the smaller."""
Adopt = Literal["better", "always"]
"""When a re-solved plan replaces the one followed."""

_REPLAN_KEY = 0x5E501E  # spawn-key word of the re-solve seeds (distinct from validate's children)


@dataclass(frozen=True)
class ReplanPolicy:
    """When and how an execution re-plans (validated at construction; frozen).

    Parameters
    ----------
    trigger : {"on_risk", "every"}
        ``"on_risk"``: re-solve when the predicted success of the remaining plan is below
        ``risk`` (checked every ``check_every`` steps, on ``drift`` and at the start);
        ``"every"``: re-solve every ``every`` steps (receding-horizon control). (``execute``'s
        ``replan``; no policy at all means never.)
    risk : float
        The predicted success a plan needs to be kept, in ``[0, 1]``.
    every : int
        ``"every"``: steps between re-solves (>= 1).
    check_every : int or None
        ``"on_risk"``: steps between scheduled predictions (>= 1); None: no schedule.
    drift : float in (0, 1), optional
        ``"on_risk"``: also predict when the belief's mean leaves this confidence ellipse of its
        last predicted distribution.
    start_resolves : int
        ``"on_risk"``: re-solves at most before the first step while the plan's predicted
        success is below ``risk`` (>= 0; counted in ``max_replans``).
    risk_measure : {"bound", "estimate"}
        The prediction's sound lower bound or its sampled estimate.
    risk_on : {"belief", "state", "both"}
        Whose success is compared with ``risk``.
    risk_samples : int
        Samples of the Gaussian model for ``risk_measure="estimate"`` (>= 1).
    max_replans : int
        Re-solves at most per execution (>= 0).
    adopt : {"better", "always"}
        A re-solved plan replaces the current one when predicted better, or whenever found.
    replan_time_limit : float
        Wall-clock cap of one re-solve, seconds (> 0); the solver's ``time_limit`` is the
        smaller of this and ``solver``'s own.
    solver : SolverOptions, optional
        Options of the re-solves (use the ones the plan was solved with; the seed is replaced by
        a derived one, :func:`replan_seed`); default ``SolverOptions()``.

    Raises
    ------
    InvalidArgumentError, InvalidTypeError
        When a field is out of range or of the wrong type (the message names it).
    """

    trigger: ReplanTrigger = "on_risk"
    risk: float = 0.9
    every: int = 10
    check_every: int | None = 1
    drift: float | None = None
    start_resolves: int = 0
    risk_measure: RiskMeasure = "bound"
    risk_on: RiskOn = "both"
    risk_samples: int = 1000
    max_replans: int = 20
    adopt: Adopt = "better"
    replan_time_limit: float = 30.0
    solver: SolverOptions | None = None

    def __post_init__(self) -> None:
        put = object.__setattr__
        if self.trigger not in ("on_risk", "every"):
            raise InvalidArgumentError(
                f"replan (the policy's trigger) must be 'on_risk' or 'every', got {self.trigger!r}"
            )
        put(self, "risk", as_float(self.risk, "risk", 0.0, 1.0))
        put(self, "every", as_int(self.every, "every", minimum=1))
        if self.check_every is not None:
            put(self, "check_every", as_int(self.check_every, "check_every", minimum=1))
        if self.drift is not None:
            put(self, "drift", as_float(self.drift, "drift", 0.0, 1.0, low_open=True))
            if self.drift == 1.0:
                raise InvalidArgumentError("drift must be < 1 (a confidence), got 1.0")
        put(self, "start_resolves", as_int(self.start_resolves, "start_resolves", minimum=0))
        if self.risk_measure not in ("bound", "estimate"):
            raise InvalidArgumentError(
                f"risk_measure must be 'bound' or 'estimate', got {self.risk_measure!r}"
            )
        if self.risk_on not in ("belief", "state", "both"):
            raise InvalidArgumentError(f"risk_on must be 'belief', 'state' or 'both', got {self.risk_on!r}")
        put(self, "risk_samples", as_int(self.risk_samples, "risk_samples", minimum=1))
        put(self, "max_replans", as_int(self.max_replans, "max_replans", minimum=0))
        if self.adopt not in ("better", "always"):
            raise InvalidArgumentError(f"adopt must be 'better' or 'always', got {self.adopt!r}")
        limit = as_float(self.replan_time_limit, "replan_time_limit", 0.0, low_open=True)
        put(self, "replan_time_limit", limit)
        if self.solver is not None and not isinstance(self.solver, SolverOptions):
            raise InvalidTypeError(f"solver must be a SolverOptions, got {type(self.solver).__name__}")

    @classmethod
    def from_keywords(
        cls,
        replan: ReplanTrigger | None = "on_risk",
        *,
        options: SolverOptions | None = None,
        solver_options: Mapping[str, Any] | None = None,
        **fields: Any,
    ) -> ReplanPolicy:
        """The policy of ``execute``'s keywords / ``validate``'s ``replan_options`` mapping.

        Parameters
        ----------
        replan : {"on_risk", "every"} or None
            The trigger (None is read as ``"on_risk"``: the values are still checked).
        options : SolverOptions, optional
            The re-solves' options.
        solver_options : mapping, optional
            :class:`~idstlpy.SolverOptions` fields overriding ``options``.
        **fields
            The other fields of :class:`ReplanPolicy`, by name.

        Returns
        -------
        ReplanPolicy

        Raises
        ------
        InvalidArgumentError, InvalidTypeError
            For an unknown keyword or a bad value (the message names it).
        """
        unknown = sorted(
            set(fields) - {f for f in cls.__dataclass_fields__ if f not in ("trigger", "solver")}
        )
        if unknown:
            raise InvalidArgumentError(f"unknown re-planning option(s) {unknown}")
        if options is not None and not isinstance(options, SolverOptions):
            raise InvalidTypeError(f"options must be a SolverOptions, got {type(options).__name__}")
        solver = options
        if solver_options is not None:
            if not isinstance(solver_options, Mapping):
                raise InvalidTypeError(
                    f"solver_options must be a mapping, got {type(solver_options).__name__}"
                )
            solver = (options or SolverOptions()).with_(**solver_options)
        return cls(trigger="on_risk" if replan is None else replan, solver=solver, **fields)

    def solve_options(self) -> SolverOptions:
        """The re-solves' options: ``solver`` with its time limit capped at ``replan_time_limit``."""
        base = self.solver if self.solver is not None else SolverOptions()
        cap = self.replan_time_limit
        return base.with_(time_limit=cap if base.time_limit is None else min(base.time_limit, cap))


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
            process_noise="model" if spec.process_noise == "model" else "none",
            lqr_gains=[list(Ks) for Ks in spec.gains.values()],
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
            result = sub.solve_result(options=self.options.with_(seed=seed))
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


def executor_spec(
    problem: Problem,
    *,
    clip_controls: bool = True,
    process_noise: Any = "model",
    lqr_gains: Any = None,
    default_lqr: Mapping[str, Any] | None = None,
    real_system: Any = None,
    plant: Any = None,
) -> ExecutorSpec:
    """The :class:`~idstlpy.executor.ExecutorSpec` of ``execute``'s keywords (``clip_controls``:
    the problem's control domain, or none)."""
    if not isinstance(clip_controls, bool):
        raise InvalidTypeError(f"clip_controls must be a bool, got {type(clip_controls).__name__}")
    return ExecutorSpec.make(
        problem.switched_system,
        control_domain=problem.control_domain if clip_controls else None,
        process_noise=process_noise,
        lqr_gains=lqr_gains,
        default_lqr=default_lqr,
        real_system=real_system,
        plant=plant,
    )


class ReplanningExecutor:
    """Executes a plan one observation at a time and re-plans from the executed belief.

    Parameters
    ----------
    problem : Problem
        The problem the plan solves (model, control domain, formula).
    plan : ProbabilisticTSTrajectory
        The plan to follow first, ``N`` steps.
    policy : ReplanPolicy, optional
        When and how to re-plan; None: never (the object is an :class:`~idstlpy.OnlineExecutor`
        that records the executed belief).
    seed : int, SeedSequence or None
        The re-solves' seeds derive from it (:func:`replan_seed`); :func:`~idstlpy.execute`
        passes the execution's seed. None: fresh entropy (``seed_sequence.entropy``).
    spec : ExecutorSpec, optional
        What runs the plan (its system must be the problem's); default
        ``executor_spec(problem, **options)``.
    **options
        ``clip_controls``, ``process_noise``, ``lqr_gains``, ``default_lqr``, ``real_system``,
        ``plant`` (see :func:`~idstlpy.execute`); only without ``spec``.

    Attributes
    ----------
    executor : OnlineExecutor
        The executor of the plan followed (replaced at each adopted re-plan).
    last_replan : Replan or None
        The re-plan attempt made by the last :meth:`step` (or the last of the start check after
        :meth:`reset`); None when none was made.

    Raises
    ------
    InvalidTypeError, InvalidArgumentError, DimensionError
        Naming the argument that is wrong.

    Notes
    -----
    Construction (and :meth:`reset`) makes the start check when the policy asks for one
    (``trigger="on_risk"`` with ``drift`` or ``start_resolves``): up to ``start_resolves``
    re-solves before the first step.
    """

    def __init__(
        self,
        problem: Problem,
        plan: ProbabilisticTSTrajectory,
        policy: ReplanPolicy | None = None,
        *,
        seed: int | np.random.SeedSequence | None = 0,
        spec: ExecutorSpec | None = None,
        **options: Any,
    ) -> None:
        if not isinstance(problem, Problem):
            raise InvalidTypeError(f"problem must be a Problem, got {type(problem).__name__}")
        if plan is None:
            raise InvalidArgumentError(
                "plan is None: there is no plan to execute (see problem.last_result.reason)"
            )
        if not isinstance(plan, ProbabilisticTSTrajectory):
            raise InvalidTypeError(f"plan must be a ProbabilisticTSTrajectory, got {type(plan).__name__}")
        if policy is not None and not isinstance(policy, ReplanPolicy):
            raise InvalidTypeError(f"policy must be a ReplanPolicy, got {type(policy).__name__}")
        if spec is None:
            spec = executor_spec(problem, **options)
        elif options:
            raise InvalidArgumentError(f"options {sorted(options)} are given twice: set them on the spec")
        elif not isinstance(spec, ExecutorSpec) or spec.system is not problem.switched_system:
            raise InvalidArgumentError("spec must be an ExecutorSpec of the problem's switched system")
        self.problem, self.policy, self.spec = problem, policy, spec
        self.seed_sequence = as_seed_sequence(seed)
        self._first = plan
        p = policy if policy is not None else ReplanPolicy()
        self._resolver = _Resolver(problem, _RiskModel.make(spec, p), p.solve_options(), p.adopt)
        n = spec.system.n
        self._threshold = float(chi2.ppf(p.drift, n)) if p.drift is not None else math.inf
        self.reset()

    # -- state ---------------------------------------------------------------------------------

    def reset(self) -> None:
        """Start (again) at the first plan's step 0, its first belief as the prior (start check)."""
        plan = self._first
        self._means = [plan.get_mean(0).copy()]
        self._covs = [plan.get_cov(0).copy()]
        self._actions: list[int] = []
        self._controls: list[np.ndarray] = []
        self._replans: list[Replan] = []
        self._attempts = 0
        self._violated = False
        self._reference: tuple[int, np.ndarray, np.ndarray] | None = None  # the drift test's
        self.predicted = math.nan
        self.last_replan: Replan | None = None
        self._plans: list[tuple[int, ProbabilisticTSTrajectory]] = [(0, plan)]
        belief = GaussianBelief(plan.get_mean(0).copy(), plan.get_cov(0).copy())
        policy, formula = self.policy, self.problem.stl_formula
        if (
            policy is not None
            and policy.trigger == "on_risk"
            and formula is not TRUE
            and formula is not FALSE
            and (policy.drift or policy.start_resolves)
        ):
            # Before the first step: the start check and the drift test's first reference.
            plan, p, pred, records = self._resolver.check_start(
                plan,
                belief,
                policy.risk,
                min(policy.start_resolves, policy.max_replans),
                lambda i: replan_seed(self.seed_sequence, i),
            )
            self._replans.extend(records)
            self._attempts += len(records)
            self._plans = [(0, plan)]  # a plan replaced at the start was never followed
            self.predicted = p
            self.last_replan = records[-1] if records else None
            self._remember(pred, 0)
        self._follow(plan, 0, belief)

    def _follow(self, plan: ProbabilisticTSTrajectory, k: int, belief: GaussianBelief) -> None:
        self.executor = OnlineExecutor(self.spec, plan)
        self.executor.reset(belief)
        self._plan, self._start = plan, k

    @property
    def k(self) -> int:
        """Inputs issued so far (the execution step of the next input)."""
        return len(self._actions)

    @property
    def done(self) -> bool:
        """True once the plan followed has issued its last input."""
        return self.executor.done

    @property
    def pending(self) -> bool:
        """True when an input was issued and its observation not yet given."""
        return self.executor.pending

    @property
    def belief(self) -> GaussianBelief:
        """The current belief: mean (n,) and covariance (n, n) (copies)."""
        return self.executor.belief

    @property
    def plan(self) -> ProbabilisticTSTrajectory:
        """The plan followed now (its step 0 was execution step ``plans[-1][0]``)."""
        return self._plan

    @property
    def plans(self) -> tuple[tuple[int, ProbabilisticTSTrajectory], ...]:
        """The plans followed, each with the execution step at which it started."""
        return tuple(self._plans)

    @property
    def replans(self) -> tuple[Replan, ...]:
        """Every re-plan attempt so far, in order."""
        return tuple(self._replans)

    def executed(self) -> ProbabilisticTSTrajectory:
        """The executed belief so far: means (K+1, n), covariances (K+1, n, n), modes (K,) and
        inputs (K, m) of the ``K`` observed steps (an input whose observation is pending is not
        included)."""
        K = len(self._means) - 1
        m = self.spec.system.m
        controls = np.array(self._controls[:K]) if K else np.zeros((0, m))
        return ProbabilisticTSTrajectory(
            np.array(self._means), np.array(self._covs), np.array(self._actions[:K], dtype=int), controls
        )

    def __repr__(self) -> str:
        return (
            f"ReplanningExecutor(k={self.k}, plans={len(self._plans)}, replans={len(self._replans)}, "
            f"predicted={self.predicted:.3g}, pending={self.pending})"
        )

    # -- the loop ------------------------------------------------------------------------------

    def observe(self, observation: Any) -> None:
        """Update the belief with the observation taken after the last input
        (:meth:`idstlpy.OnlineExecutor.observe`).

        Raises
        ------
        InvalidArgumentError
            When no input is pending, the observation is missing or not finite, or the belief
            diverged.
        DimensionError
            When the observation has the wrong shape.
        """
        self.executor.observe(observation)
        mean, cov = self.executor.mean, self.executor.cov
        if not np.isfinite(mean).all():
            raise InvalidArgumentError(f"the execution diverged at step {self.k} (non-finite belief)")
        self._means.append(mean.copy())
        self._covs.append(cov.copy())

    def step(self, observation: Any = None) -> tuple[int, np.ndarray]:
        """Take the observation made after the last input, check and re-plan as the policy asks,
        and return the next mode and input.

        Parameters
        ----------
        observation : array_like, shape (p,), or None
            The reading of the previous step's sensor (None before the first input, and after a
            blind mode).

        Returns
        -------
        mode : int
        input : ndarray, shape (m,)

        Raises
        ------
        InvalidArgumentError
            When the plan is done (the last observation then goes to :meth:`observe`), or an
            observation is given before the first input.
        """
        if self.done:
            raise InvalidArgumentError(
                f"the plan is done after {self.k} inputs"
                + ("; give the last observation to observe()" if self.pending else "")
            )
        if self.pending:
            self.observe(observation)
        elif observation is not None:
            raise InvalidArgumentError(
                "step: an observation was given but no input is pending (the first call takes None)"
            )
        self.last_replan = None
        self._decide()
        mode, u = self.executor.command()
        self._actions.append(mode)
        self._controls.append(u)
        return mode, u

    # -- checks and re-solves ------------------------------------------------------------------

    def _remember(self, pred: ClosedLoopPrediction | None, at: int) -> None:
        """The drift test's reference: the prediction ``pred`` made at execution step ``at``."""
        if pred is not None and self.policy is not None and self.policy.drift is not None:
            self._reference = (at, pred.belief_mean, pred.belief_mean_cov)

    def _predicted(self, psi: STLFormula, belief: GaussianBelief, at: int) -> float:
        """Predicted success of the rest of the plan followed (the drift test's reference)."""
        value, pred = self._resolver.model.predict(self._plan, self.executor.k, psi, belief)
        self._remember(pred, at)
        self.predicted = value
        return value

    def _drifted(self, k: int) -> bool:
        """Whether the belief's mean left its predicted ``drift`` ellipse at step ``k``."""
        if self._reference is None:
            return False
        at, mu, cov = self._reference
        i = k - at
        if i >= mu.shape[0]:
            return False
        d = self.executor.mean - mu[i]
        C = cov[i] + 1e-12 * (1.0 + float(np.trace(cov[i]))) * np.eye(d.shape[0])
        return float(d @ np.linalg.solve(C, d)) > self._threshold

    def _due(self, k: int) -> str | None:
        """Why a decision is due at step ``k`` (``"every"``, ``"risk"``, ``"drift"``), or None."""
        policy = self.policy
        if policy is None or k == 0 or self._violated or self._attempts >= policy.max_replans:
            return None
        if policy.trigger == "every":
            return "every" if k % policy.every == 0 else None
        if policy.check_every is not None and k % policy.check_every == 0:
            return "risk"
        return "drift" if policy.drift is not None and self._drifted(k) else None

    def _decide(self) -> None:
        """The checks of step ``k`` and the re-solve they call for."""
        k = self.k
        why = self._due(k)
        if why is None or self.policy is None:
            return
        psi = progress(self.problem.stl_formula, self.executed())
        if psi is FALSE:
            self._violated = True  # the prefix broke the formula: no plan can repair it
            self._record(Replan(k, "violated", 0.0, "skipped", False, formula=str(psi)))
            return
        if psi is TRUE:
            return
        belief = self.belief
        p_old = math.nan
        if self.policy.trigger == "on_risk":
            p_old = self._predicted(psi, belief, k)
            if p_old >= self.policy.risk:
                return
        self._attempt(k, psi, why, p_old, belief)

    def _attempt(self, k: int, psi: STLFormula, why: str, p_old: float, belief: GaussianBelief) -> None:
        """Re-solve ``psi`` from the current belief at step ``k``; follow the new plan when adopted."""
        resolver = self._resolver
        seed = replan_seed(self.seed_sequence, self._attempts)
        record, new = resolver.resolve(belief, psi, seed, k, why, p_old)
        self._attempts += 1
        record, _, pred = resolver.judge(record, new, (self._plan, self.executor.k), psi, belief, p_old)
        adopted = record.adopted and new is not None
        if adopted and new is not None and self.policy is not None and self.policy.drift is not None:
            # the adopted plan's prediction is the drift test's reference
            if pred is not None:
                self._remember(pred, k)
            else:
                self._reference_of(new, psi, belief, k)
        self._record(record)
        logger.info(
            "execute: step %d, %s re-plan %s (%s, predicted %.3g -> %.3g, %.2f s)",
            k,
            record.reason,
            "adopted" if record.adopted else "kept the old plan",
            record.status,
            record.predicted,
            record.new_predicted,
            record.solve_time,
        )
        if adopted and new is not None:
            self._plans.append((k, new))
            self._follow(new, k, belief)
            if not math.isnan(record.new_predicted):
                self.predicted = record.new_predicted

    def _reference_of(
        self, plan: ProbabilisticTSTrajectory, psi: STLFormula, belief: GaussianBelief, k: int
    ) -> None:
        """The prediction of an adopted ``plan`` as the drift test's reference."""
        _, pred = self._resolver.model.predict(plan, 0, psi, belief)
        self._remember(pred, k)

    def _record(self, record: Replan) -> None:
        self._replans.append(record)
        self.last_replan = record
