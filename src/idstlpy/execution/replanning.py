"""Receding-horizon execution: track a plan, predict its success as it goes, re-plan when needed.

:func:`execute` runs a plan exactly as :func:`~idstlpy.execution.simulation.simulate` does
(Kalman filter, receding-horizon LQR, true state moved by the real system, one random stream):
it is the loop of a :class:`~idstlpy.execution.replanner.ReplanningExecutor` (the object a robot
runs: one observation in, the next mode and input out) with a simulated plant. At decision steps
it re-solves the problem from the current executed belief, as its
:class:`~idstlpy.execution.replanner.ReplanPolicy` says (``execute(..., policy=...)``; the
keywords below are its fields, and ``execute``'s deprecated spelling):

- no policy (``policy=None``): never; the execution is bit-identical to ``simulate`` with the same seed;
- ``ReplanPolicy(trigger="every")``: a re-solve every ``every`` steps (receding-horizon control);
- ``ReplanPolicy(trigger="on_risk")``: every ``check_every`` steps the closed-loop prediction
  (:func:`~idstlpy.execution.prediction.predict_closed_loop`) of the *remaining* plan from the
  current belief gives the probability that the formula will hold; below ``risk`` the problem is
  re-solved. With ``drift`` (a confidence, e.g. 0.95) the prediction is also made at any step at
  which the executed belief's mean leaves the ``drift`` ellipse of its distribution as last
  predicted (at step 0, or at the last check or adoption): a run that goes astray is checked as
  it goes astray, one that follows its prediction only on the schedule. Each check re-centres
  the ellipse on the new prediction, so the cadence follows how far reality departs from it.

A re-solved plan replaces the current one when its own predicted success is higher
(``adopt="better"``, the default: a fresh MLO plan may have less room for the tracking error than
the old one, and following it can make things worse), or whenever one is found
(``adopt="always"``).

What is re-solved
-----------------
After ``k`` executed steps the obligation is not the original formula: an until may be half-way,
a hold in progress, a deadline closer. :func:`idstlpy.progression.progress` rewrites the formula
over the executed belief prefix ``X_0 .. X_k`` into the formula ``psi`` the rest must satisfy
(``satisfies(whole, phi) == satisfies(rest, psi)``, the rest starting at ``X_k``). The re-solve
is a new :class:`~idstlpy.Problem` with the same modes and control domain, the prior
``N(mean_k, P_k)`` (the filter's belief) and ``psi``, solved with the caller's solver options, a
wall-clock cap ``replan_time_limit`` and a seed derived from the execution's seed and the
re-plan's index, so the same seed gives the same execution and the same re-plans (unless a
wall-clock cap was hit: the record says so, as ``SolveStats.caps_hit`` does). A re-solve that
finds no plan keeps the old one; every attempt is recorded.

What is predicted
-----------------
The success probability of the remaining plan is predicted with the planning model only (the
executor does not know the real system): the true state is distributed as the current belief
(``real_initial_state = mean_k``, ``real_initial_cov = P_k``), the filter starts at the belief,
and the formula is ``psi``. ``risk_measure="bound"`` (default) uses the prediction's sound lower
bounds (no sampling, about 0.1 s on the light-dark plan), ``"estimate"`` its sampled point
estimates (``risk_samples`` samples). ``risk_on`` chooses the executed belief's success, the true
state's (the formula's deterministic reading) or the smaller of the two.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Unpack

import numpy as np
from numpy.typing import ArrayLike

from .._checks import as_seed_sequence, as_vector
from ..dynamical_system import LCS, SwitchedSystem
from ..errors import InvalidArgumentError, InvalidTypeError
from ..executor import ExecutorSpec
from ..semantics import robustness
from ..synthesis.options import SolverOptions
from ..synthesis.problem import Problem
from ..trajectory import ProbabilisticTSTrajectory, RealTrajectory
from .policy import POLICY_KEYWORDS, Adopt, ReplanPolicy, ReplanTrigger, RiskMeasure, RiskOn
from .replanner import EXECUTOR_KEYWORDS, ExecutorKeywords, ReplanningExecutor, executor_spec
from .resolving import Replan, check_problem_plan, replan_seed

__all__ = [
    "EXECUTOR_KEYWORDS",
    "ExecutionReport",
    "Replan",
    "ReplanPolicy",
    "ReplanningExecutor",
    "execute",
    "replan_seed",
]

logger = logging.getLogger(__name__)


class ExecuteOptions(ExecutorKeywords, total=False):
    """The keywords of :func:`execute`: the executor's, and the deprecated re-planning ones
    (``**options: Unpack[ExecuteOptions]``: type checkers and editors know them)."""

    replan: ReplanTrigger | None
    risk: float
    every: int
    check_every: int | None
    drift: float | None
    start_resolves: int
    risk_measure: RiskMeasure
    risk_on: RiskOn
    risk_samples: int
    max_replans: int
    adopt: Adopt
    adopt_delay: int
    replan_time_limit: float
    options: SolverOptions | None
    solver_options: Mapping[str, Any] | None


_POLICY_KEYWORDS = POLICY_KEYWORDS | {"replan"}
"""``execute``'s deprecated re-planning keywords (:meth:`ReplanPolicy.from_keywords`)."""


@dataclass(frozen=True)
class ExecutionReport:
    """Outcome of :func:`execute`.

    Parameters
    ----------
    belief : ProbabilisticTSTrajectory
        The executed belief (filter means (K+1, n), covariances (K+1, n, n), modes (K,), inputs
        (K, m)), across every plan that was followed.
    real : RealTrajectory
        True states (K+1, n), observations (K+1, p), modes and inputs.
    replans : tuple of Replan
        Every re-plan attempt, in order.
    belief_satisfied, state_satisfied : bool
        Whether the *original* formula holds on the executed belief / on the true states (the
        formula's deterministic reading, zero covariance).
    belief_margin, state_margin : float
        The corresponding robustness.
    plans : tuple of (int, ProbabilisticTSTrajectory)
        The plans followed, each with the execution step at which it started (the first at 0).
    seed_entropy : int or tuple of int
        Entropy of the execution's ``SeedSequence`` (pass ``SeedSequence(seed_entropy)`` as
        ``seed`` to reproduce a run made with ``seed=None``).
    elapsed : float
        Wall-clock seconds, re-solves included (not part of equality).
    """

    belief: ProbabilisticTSTrajectory = field(repr=False)
    real: RealTrajectory = field(repr=False)
    replans: tuple[Replan, ...]
    belief_satisfied: bool
    state_satisfied: bool
    belief_margin: float
    state_margin: float
    plans: tuple[tuple[int, ProbabilisticTSTrajectory], ...] = field(default=(), repr=False)
    seed_entropy: int | tuple[int, ...] = 0
    elapsed: float = field(default=0.0, compare=False)

    @property
    def num_of_steps(self) -> int:
        """Steps executed ``K``."""
        return self.belief.num_of_steps

    @property
    def num_replans(self) -> int:
        """Re-solves attempted (``"violated"`` records excluded)."""
        return sum(r.status != "skipped" for r in self.replans)

    @property
    def num_adopted(self) -> int:
        """Re-solves whose plan was adopted."""
        return sum(r.adopted for r in self.replans)

    @property
    def replan_time(self) -> float:
        """Wall-clock seconds spent in re-solves."""
        return float(sum(r.solve_time for r in self.replans))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ExecutionReport):
            return NotImplemented
        return (
            self.replans == other.replans
            and self.belief_satisfied == other.belief_satisfied
            and self.state_satisfied == other.state_satisfied
            and _same(self.belief_margin, other.belief_margin)
            and _same(self.state_margin, other.state_margin)
            and np.array_equal(self.belief.get_mean(), other.belief.get_mean())
            and np.array_equal(self.belief.get_cov(), other.belief.get_cov())
            and np.array_equal(self.real.get_state(), other.real.get_state())
            and np.array_equal(self.belief.get_action(), other.belief.get_action())
            and np.array_equal(self.belief.get_control(), other.belief.get_control())
        )

    __hash__ = None  # type: ignore[assignment]  # mutable arrays inside: not hashable


def _same(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


def _policy(policy: ReplanPolicy | None, legacy: Mapping[str, Any], caller: str) -> ReplanPolicy | None:
    """The policy of ``caller``: ``policy``, or the deprecated keywords ``legacy`` (warned)."""
    unknown = sorted(set(legacy) - _POLICY_KEYWORDS)
    if unknown:
        raise InvalidArgumentError(f"{caller}() got unexpected keyword(s) {unknown}")
    if policy is not None and not isinstance(policy, ReplanPolicy):
        raise InvalidTypeError(f"policy must be a ReplanPolicy, got {type(policy).__name__}")
    if not legacy:
        return policy
    if policy is not None:
        raise InvalidArgumentError(
            f"give either policy or the re-planning keywords {sorted(legacy)}, not both"
        )
    warnings.warn(
        f"{caller}({', '.join(f'{k}=...' for k in sorted(legacy))}) is deprecated: pass "
        "policy=ReplanPolicy(...) (replan -> trigger; options and solver_options -> solver, a "
        "SolverOptions)",
        DeprecationWarning,
        stacklevel=3,
    )
    kw = dict(legacy)
    replan = kw.pop("replan", None)
    made = ReplanPolicy.from_keywords(replan, **kw)  # checks the values even without replan
    return made if replan is not None else None


def _spec(
    problem: Problem,
    spec: ExecutorSpec | None,
    real_system: SwitchedSystem | LCS | None,
    options: Mapping[str, Any],
) -> ExecutorSpec:
    """``spec`` checked against the problem, or the spec of the executor's keywords ``options``
    (modes without gains tracked as ``plan`` was made for)."""
    if spec is None:
        return executor_spec(problem, real_system=real_system, **options)
    if not isinstance(spec, ExecutorSpec):
        raise InvalidTypeError(f"spec must be an ExecutorSpec, got {type(spec).__name__}")
    given = sorted([*options, *(["real_system"] if real_system is not None else [])])
    if given:
        raise InvalidArgumentError(f"give either spec or {given}, not both (set them on the spec)")
    return spec


def execute(
    problem: Problem,
    plan: ProbabilisticTSTrajectory,
    real_system: SwitchedSystem | LCS | None,
    real_initial_state: ArrayLike,
    seed: int | np.random.SeedSequence | None = None,
    *,
    policy: ReplanPolicy | None = None,
    spec: ExecutorSpec | None = None,
    **options: Unpack[ExecuteOptions],
) -> ExecutionReport:
    """Execute a plan under real noise, re-planning from the executed belief as ``policy`` says.

    The loop of a :class:`~idstlpy.execution.replanner.ReplanningExecutor` with a simulated
    plant: each step it gives the executor the last observation, applies the mode and input it
    returns to the plant and draws the planning mode's sensor at the new true state.

    Parameters
    ----------
    problem : Problem
        The problem the plan solves (model, control domain, formula).
    plan : ProbabilisticTSTrajectory
        The plan to execute first (``problem.solve``'s result), ``N`` steps.
    real_system : SwitchedSystem, LCS or None
        The system moving the true state (one mode per planning mode, or one for all); None with
        ``plant``.
    real_initial_state : array_like, shape (n,)
        True initial state.
    seed : int, SeedSequence or None
        Seed of the execution: the noise stream is ``default_rng(seed)`` (as ``simulate``'s)
        and the re-solves' seeds derive from it (:func:`replan_seed`). ``None``: fresh entropy,
        recorded in :attr:`ExecutionReport.seed_entropy`.
    policy : ReplanPolicy, optional
        When and how to re-plan (module notes); None: never (the run is ``simulate``'s).
    spec : ExecutorSpec, optional
        The executor as one object (its system must be the problem's), instead of
        ``real_system`` (then None) and the executor's keywords below.
    **options
        The executor's keywords below (:data:`EXECUTOR_KEYWORDS`, made into an ``ExecutorSpec``
        here) and the deprecated re-planning ones; any other raises
        :class:`~idstlpy.errors.InvalidArgumentError` naming it.

    Other Parameters
    ----------------
    clip_controls, process_noise, lqr_gains, default_lqr
        As in :func:`~idstlpy.execution.validation.validate`.
    plant : callable, optional
        A (nonlinear) plant as a step function ``(state, input, mode, rng) -> next_state``
        instead of ``real_system`` (then None; see :func:`~idstlpy.simulate`); the risk checks
        predict with the model.
    replan, risk, every, check_every, drift, start_resolves, risk_measure, risk_on, risk_samples
        Deprecated (``DeprecationWarning``), as ``max_replans``, ``adopt``,
        ``replan_time_limit``, ``options`` and ``solver_options``: the policy
        ``ReplanPolicy.from_keywords(replan, ...)`` (none without ``replan``).

    Returns
    -------
    ExecutionReport

    Raises
    ------
    InvalidTypeError, InvalidArgumentError, DimensionError
        Naming the argument that is wrong (``plan`` None, an option of the wrong type or out of
        range, dimensions of the plan, the model and the real system that disagree).
    """
    t0 = time.perf_counter()
    check_problem_plan(problem, plan, "execute")
    executor_kw = {k: v for k, v in options.items() if k in EXECUTOR_KEYWORDS}
    policy = _policy(policy, {k: v for k, v in options.items() if k not in EXECUTOR_KEYWORDS}, "execute")
    ss = as_seed_sequence(seed)
    x = as_vector(real_initial_state, "real_initial_state", problem.switched_system.n)
    spec = _spec(problem, spec, real_system, executor_kw)
    runner = ReplanningExecutor(problem, plan, policy, seed=ss, spec=spec)
    states, observations = _run(runner, x, np.random.default_rng(ss))
    return _report(problem, runner, states, observations, ss, t0)


def _report(
    problem: Problem,
    runner: ReplanningExecutor,
    states: np.ndarray,
    observations: np.ndarray,
    ss: np.random.SeedSequence,
    t0: float,
) -> ExecutionReport:
    """The report of a finished run (the original formula judged on the whole execution)."""
    xi_b = runner.executed()
    actions, controls = xi_b.get_action(), xi_b.get_control()
    xi_r = RealTrajectory(states, observations, actions, controls)
    formula = problem.stl_formula
    b_margin = robustness(xi_b, formula)
    s_margin = robustness(_state_reading(states, actions, controls), formula)
    entropy = ss.entropy
    return ExecutionReport(
        belief=xi_b,
        real=xi_r,
        replans=runner.replans,
        belief_satisfied=b_margin >= 0.0,
        state_satisfied=s_margin >= 0.0,
        belief_margin=b_margin,
        state_margin=s_margin,
        plans=runner.plans,
        seed_entropy=int(entropy) if isinstance(entropy, int | np.integer) else tuple(entropy or ()),
        elapsed=time.perf_counter() - t0,
    )


def _run(
    runner: ReplanningExecutor, x: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Drive ``runner`` to the end of its plans with the simulated plant from the true state
    ``x``; the true states (K+1, n) and the observations (K+1, p_max) (row 0 and blind rows NaN)."""
    p_max = max((mode.p for mode in runner.spec.system.system_modes), default=0)
    states, observations = [x], [np.full(p_max, np.nan)]
    X, y = x[None, :], None
    while not runner.done:
        _, u = runner.step(y)
        law, i = runner.executor.law, runner.executor.k - 1
        # True state (the plant), then the sensor of the planning mode at it.
        X = law.plant(i, X, u[None, :], rng)
        Y = law.observe(i, X, rng)
        y = None if Y is None else Y[0]
        if not (np.isfinite(X).all() and (y is None or np.isfinite(y).all())):
            raise InvalidArgumentError(f"the execution diverged at step {runner.k} (non-finite state)")
        row = np.full(p_max, np.nan)
        if y is not None:
            row[: y.shape[0]] = y
        states.append(X[0])
        observations.append(row)
    if runner.pending:
        runner.observe(y)
    return np.array(states), np.array(observations).reshape(len(states), p_max)


def _state_reading(
    states: np.ndarray, actions: np.ndarray, controls: np.ndarray
) -> ProbabilisticTSTrajectory:
    n = states.shape[1]
    return ProbabilisticTSTrajectory(states, np.zeros((states.shape[0], n, n)), actions, controls)
