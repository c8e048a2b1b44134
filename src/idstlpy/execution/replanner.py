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

The policy (:class:`~idstlpy.execution.policy.ReplanPolicy`) is the typed form of ``execute``'s
re-planning keywords and of ``validate``'s ``replan_options`` (see
:mod:`idstlpy.execution.replanning` for what each field means); the re-solves and their records
are :mod:`idstlpy.execution.resolving`'s.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import chi2

from .._checks import as_seed_sequence
from ..belief import GaussianBelief
from ..dynamical_system import LCS, SwitchedSystem
from ..errors import InvalidArgumentError, InvalidTypeError
from ..executor import ExecutorSpec, OnlineExecutor, PlantStep, ProcessNoise
from ..formulas import FALSE, TRUE, STLFormula
from ..progression import progress
from ..synthesis.problem import Problem
from ..tracking import GainsOverride
from ..trajectory import ProbabilisticTSTrajectory
from .policy import ReplanPolicy
from .resolving import Replan, _Resolver, _RiskModel, check_problem_plan, replan_seed

if TYPE_CHECKING:
    from .prediction import ClosedLoopPrediction

__all__ = ["EXECUTOR_KEYWORDS", "ReplanningExecutor", "executor_spec"]

logger = logging.getLogger(__name__)


class ExecutorKeywords(TypedDict, total=False):
    """The executor's keywords of :func:`~idstlpy.execute` (those of :func:`executor_spec` but
    ``real_system``); :func:`~idstlpy.start_check` takes them but ``plant``."""

    clip_controls: bool
    process_noise: ProcessNoise
    lqr_gains: GainsOverride
    default_lqr: Mapping[str, Any] | None
    plant: PlantStep | None


EXECUTOR_KEYWORDS = frozenset(ExecutorKeywords.__optional_keys__)
"""The keywords of :func:`executor_spec` but ``real_system``: :func:`~idstlpy.execute`'s executor
(and, but ``plant``, :func:`~idstlpy.start_check`'s)."""


def executor_spec(
    problem: Problem,
    *,
    clip_controls: bool = True,
    process_noise: ProcessNoise = "auto",
    lqr_gains: GainsOverride = None,
    default_lqr: Mapping[str, Any] | None = None,
    real_system: SwitchedSystem | LCS | None = None,
    plant: PlantStep | None = None,
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
        check_problem_plan(problem, plan, "execute")
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
    def mean(self) -> np.ndarray:
        """The current filter mean, shape (n,) (read-only view)."""
        return self.executor.mean

    @property
    def cov(self) -> np.ndarray:
        """The current filter covariance, shape (n, n) (read-only view)."""
        return self.executor.cov

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

    def observe(self, observation: ArrayLike | None) -> None:
        """Update the belief with the observation taken after the last input
        (:meth:`idstlpy.OnlineExecutor.observe`).

        Parameters
        ----------
        observation : array_like, shape (p,), or None
            The planning mode's sensor reading; None exactly when that mode is blind.

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

    def step(self, observation: ArrayLike | None = None) -> tuple[int, np.ndarray]:
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
