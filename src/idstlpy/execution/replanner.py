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
prediction of the remaining plan, a re-solve one solve (capped by ``replan_time_limit``).

Two ways to run the checks and re-solves, one result:

- ``background=False`` (default; what :func:`idstlpy.execute` and :func:`idstlpy.validate` use):
  a decision due at step ``k`` is computed inside that ``step`` call (which waits for it) and
  takes effect at step ``k + policy.adopt_delay``. The schedule is counted in steps, so the
  same seed gives the same execution on every machine.
- ``background=True`` (a robot's loop): the decision is computed beside the loop by a worker
  process (:mod:`idstlpy.execution.background`); ``step`` never waits for it. The robot keeps
  following the current plan and switches at the first step ``>= k + adopt_delay`` at which the
  decision is in (the new plan verified: predicted from the belief at ``k`` as for
  ``adopt="better"``). A re-plan's :attr:`Replan.delay` says how many steps it took to take
  effect. Whenever every decision arrives within ``adopt_delay`` steps, the execution is the
  ``background=False`` one, step for step; choose ``adopt_delay`` as the steps a re-solve
  takes on the robot (``replan_time_limit`` over the control period) for that to hold.
  :meth:`cancel` drops a decision in flight; :meth:`close` (or a ``with`` block) ends the worker.

While a decision is in flight no other is made; a plan adopted ``d`` steps after the belief it was
solved from is followed from its own step ``d`` (the old plan ran meanwhile), with the filter's
current belief.

The policy (:class:`~idstlpy.execution.policy.ReplanPolicy`) is the typed form of ``execute``'s
re-planning keywords and of ``validate``'s ``replan_options`` (see
:mod:`idstlpy.execution.replanning` for what each field means); the re-solves and their records
are :mod:`idstlpy.execution.resolving`'s.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
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
from .background import BackgroundKind, BackgroundWorker, JobError
from .policy import ReplanPolicy
from .resolving import Replan, _Resolver, _RiskModel, check_problem_plan, replan_seed
from .vouch import check_reference

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
    the problem's control domain, or none; modes without gains tracked as ``plan`` was made for)."""
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


Reference = tuple[np.ndarray, np.ndarray]
"""The drift test's reference: predicted belief means (T, n) and their covariances (T, n, n)."""


@dataclass(frozen=True)
class _Snapshot:
    """What a decision due at execution step ``k`` reads (all of it pickles: it may go to a
    worker process)."""

    k: int
    why: str
    executed: ProbabilisticTSTrajectory
    belief: GaussianBelief
    plan: ProbabilisticTSTrajectory
    j: int  # the plan step of execution step k
    seed: int


@dataclass(frozen=True)
class _Decision:
    """A decision made from a :class:`_Snapshot`: what the loop applies when it takes effect.

    ``record`` is None when nothing was attempted (the check passed, or the formula already
    holds); ``predicted`` the check's or the adopted plan's prediction (NaN: none);
    ``reference`` the drift test's new reference (predicted from step ``k``)."""

    k: int
    record: Replan | None
    new: ProbabilisticTSTrajectory | None
    predicted: float = math.nan
    reference: Reference | None = None
    violated: bool = False


def _reference(pred: ClosedLoopPrediction | None) -> Reference | None:
    return None if pred is None else (pred.belief_mean, pred.belief_mean_cov)


def decide(resolver: _Resolver, policy: ReplanPolicy, formula: STLFormula, snap: _Snapshot) -> _Decision:
    """The checks and re-solve of a decision due at step ``snap.k`` (no state of the loop).

    Parameters
    ----------
    resolver : _Resolver
        The re-solves and the risk model.
    policy : ReplanPolicy
    formula : STLFormula
        The problem's formula (progressed here over ``snap.executed``).
    snap : _Snapshot

    Returns
    -------
    _Decision
    """
    k = snap.k
    if (
        policy.trigger == "on_risk"
        and snap.j == snap.k
        and policy.drift is None
        and policy.risk_measure == "bound"
    ):
        # The plan followed from the start: its shared prediction conditioned on this run's
        # belief may vouch for it without a prediction of its own (:mod:`.vouch`). A positive
        # value means the witness held on the prefix: the formula is not broken (no progression
        # needed to know it), and a formula already decided needs no check either way.
        ref = check_reference(resolver.model.spec, snap.plan, formula)
        vouched = (
            math.nan if ref is None else ref.vouch(snap.executed, snap.belief, policy.risk_on, policy.risk)
        )
        if vouched >= policy.risk and vouched > 0.0:
            return _Decision(k, None, None, vouched, None)
    psi = progress(formula, snap.executed)
    if psi is FALSE:  # the prefix broke the formula: no plan can repair it
        return _Decision(
            k, Replan(k, "violated", 0.0, "skipped", False, formula=str(psi)), None, violated=True
        )
    if psi is TRUE:
        return _Decision(k, None, None)
    belief = snap.belief
    p_old, reference = math.nan, None
    if policy.trigger == "on_risk":
        p_old, pred = resolver.model.predict(snap.plan, snap.j, psi, belief)
        reference = _reference(pred) if policy.drift is not None else None
        if p_old >= policy.risk:
            return _Decision(k, None, None, p_old, reference)
    record, new = resolver.resolve(belief, psi, snap.seed, k, snap.why, p_old)
    record, _, pred = resolver.judge(record, new, (snap.plan, snap.j), psi, belief, p_old)
    if not (record.adopted and new is not None):
        return _Decision(k, record, None, p_old, reference)
    if policy.drift is not None:
        # the adopted plan's prediction is the drift test's reference
        if pred is None:
            _, pred = resolver.model.predict(new, 0, psi, belief)
        reference = _reference(pred)
    return _Decision(k, record, new, p_old, reference)


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
    background : bool or {"process", "thread"}
        False (default): a decision is computed inside the ``step`` that makes it (module
        notes). True or ``"process"``: in a worker process forked here (a thread where fork is
        not available), ``step`` never waits for it; ``"thread"``: in a thread (a step may
        then wait for the interpreter lock). Close the worker with :meth:`close` or a ``with``
        block. The process is forked here: make the object before other threads of the
        program start computing (:mod:`idstlpy.execution.background`).
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
        background: bool | BackgroundKind = False,
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
        if background not in (False, True, "process", "thread"):
            raise InvalidArgumentError(
                f"background must be False, True, 'process' or 'thread', got {background!r}"
            )
        self._worker: BackgroundWorker[_Snapshot, _Decision] | None = None
        if background and policy is not None:
            kind: BackgroundKind = "thread" if background == "thread" else "process"
            resolver, formula = self._resolver, problem.stl_formula
            self._worker = BackgroundWorker(lambda snap: decide(resolver, policy, formula, snap), kind)
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
        # a decision made (or in flight) and not yet in effect: (decision step, its answer)
        self._waiting: tuple[int, _Decision | None] | None = None
        if self._worker is not None:
            self._worker.cancel()
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

    def _follow(
        self, plan: ProbabilisticTSTrajectory, k: int, belief: GaussianBelief, start: int = 0
    ) -> None:
        """Follow ``plan`` (its step 0 is execution step ``k``) from its step ``start``."""
        self.executor = OnlineExecutor(self.spec, plan)
        self.executor.reset(belief, start)
        self._plan, self._start = plan, k

    # -- the worker ----------------------------------------------------------------------------

    @property
    def background(self) -> BackgroundKind | None:
        """Where decisions are computed beside the loop (``"process"``, ``"thread"``), or None."""
        return None if self._worker is None else self._worker.kind

    @property
    def replanning(self) -> bool:
        """True while a decision is in flight or made and not yet in effect."""
        return self._waiting is not None

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the decision in flight is in (a simulated loop, tests); True when it is.

        Parameters
        ----------
        timeout : float, optional
            Seconds at most (None: no limit).
        """
        return self._worker is None or self._worker.wait(timeout)

    def cancel(self) -> None:
        """Drop the decision in flight or waiting (the current plan is kept; the worker process
        running it is ended and a fresh one started)."""
        if self._waiting is None:
            return
        k, _ = self._waiting
        self._waiting = None
        if self._worker is not None:
            self._worker.cancel()
        logger.info("replanning executor: the decision of step %d was cancelled at step %d", k, self.k)

    def close(self) -> None:
        """End the background worker (idempotent; the object then decides in its steps)."""
        if self._worker is not None:
            self._worker.close()
            self._worker = None
        if self._waiting is not None and self._waiting[1] is None:
            self._waiting = None  # its answer will never come

    def __enter__(self) -> ReplanningExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

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
        self._record_belief()

    def _record_belief(self) -> None:
        """Append the belief after the last observation to the executed prefix."""
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
        if self.executor.receive(observation):  # the online executor's checks and filter update
            self._record_belief()
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
        """Step ``k``: take a decision in effect now, or make the one due (at most one at a time)."""
        k = self.k
        if self._waiting is not None:
            self._take(k, *self._waiting)
            if self._waiting is not None:
                return  # in flight, or waiting for its step
        why = self._due(k)
        if why is None or self.policy is None:
            return
        snap = _Snapshot(
            k, why, self.executed(), self.belief, self._plan, self.executor.k,
            replan_seed(self.seed_sequence, self._attempts),
        )  # fmt: skip
        if self._worker is not None:
            self._worker.submit(snap)
            self._waiting = (k, None)
            return
        decision = decide(self._resolver, self.policy, self.problem.stl_formula, snap)
        self._waiting = (k, decision)
        self._take(k, k, decision)

    def _take(self, now: int, k: int, decision: _Decision | None) -> None:
        """Apply the decision made at step ``k`` (None: in flight) if its step ``now`` has come
        and its answer is in."""
        if decision is None and self._worker is not None:
            answer = self._worker.poll()
            if answer is not None:
                _, result = answer
                decision = result if isinstance(result, _Decision) else self._failed(k, result)
                self._waiting = (k, decision)
        delay = self.policy.adopt_delay if self.policy is not None else 0
        if decision is None or now < k + delay:
            return
        self._waiting = None
        self._apply(decision, now)

    def _failed(self, k: int, error: JobError) -> _Decision:
        """A background decision that raised: recorded, the plan kept."""
        logger.warning("replanning executor: the decision of step %d failed: %s", k, error.text)
        return _Decision(k, Replan(k, "error", math.nan, "error", False, reason_text=error.text), None)

    def _apply(self, dec: _Decision, now: int) -> None:
        """Bring the decision made at step ``dec.k`` into effect at step ``now``."""
        k = dec.k
        if dec.violated:
            self._violated = True
        if dec.reference is not None:
            self._reference = (k, *dec.reference)
        if not math.isnan(dec.predicted):
            self.predicted = dec.predicted
        record, new = dec.record, dec.new
        if record is None:  # a check that passed, or nothing left to do
            return
        if record.status != "skipped":
            self._attempts += 1
        start = now - k
        if new is not None and start >= new.num_of_steps:
            record = replace(
                record, adopted=False, reason_text=f"{record.reason_text}; in after its plan's end"
            )
            new = None
        record = replace(record, delay=start)
        self._record(record)
        if record.status != "skipped":
            logger.info(
                "execute: step %d, %s re-plan %s (%s, predicted %.3g -> %.3g, %.2f s, in effect at step %d)",
                k,
                record.reason,
                "adopted" if record.adopted else "kept the old plan",
                record.status,
                record.predicted,
                record.new_predicted,
                record.solve_time,
                now,
            )
        if record.adopted and new is not None:
            self._plans.append((k, new))
            self._follow(new, k, self.belief, start)
            if not math.isnan(record.new_predicted):
                self.predicted = record.new_predicted

    def _record(self, record: Replan) -> None:
        self._replans.append(record)
        self.last_replan = record
