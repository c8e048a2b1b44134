"""Receding-horizon execution: track a plan, predict its success as it goes, re-plan when needed.

:func:`execute` runs a plan exactly as :func:`~idstlpy.execution.simulation.simulate` does
(Kalman filter, receding-horizon LQR, true state moved by the real system; it *calls*
``simulate`` on the remaining plan, a chunk of steps at a time, with one random stream), and at
decision steps re-solves the problem from the current executed belief:

- ``replan=None``: never; the execution is bit-identical to ``simulate`` with the same seed;
- ``replan="every"``: a re-solve every ``every`` steps (receding-horizon control);
- ``replan="on_risk"``: every ``check_every`` steps the closed-loop prediction
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

The start check
---------------
Before the first step nothing has been observed, so whether a plan is good enough to start with
depends on the problem and the plan only. :func:`start_check` predicts the plan's success from
its start belief and, below ``risk``, re-solves the problem (at most ``resolves`` times, seeds
derived from its own ``seed``), keeping the best-predicted plan. Call it once and execute its
plan many times; or let ``execute(start_resolves=n)`` make the same check inside every run (its
re-solve seeds then derive from the run's seed). It composes: a second call with
``solver_options={"guarantee": "closed_loop"}`` tries plans made against the predicted true
state when MLO re-solves did not reach the risk.

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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from scipy.stats import chi2

from .._checks import as_float, as_int, as_seed_sequence
from ..belief import GaussianBelief, to_belief
from ..errors import IdstlpyError, InvalidArgumentError, InvalidTypeError
from ..executor import PlantStep, ProcessNoise
from ..formulas import FALSE, TRUE, STLFormula
from ..progression import progress
from ..semantics import robustness
from ..tracking import system_gains
from ..trajectory import ProbabilisticTSTrajectory, RealTrajectory
from .simulation import simulate

if TYPE_CHECKING:
    from .prediction import ClosedLoopPrediction

__all__ = ["ExecutionReport", "Replan", "StartCheck", "execute", "replan_seed", "start_check"]

logger = logging.getLogger(__name__)

ReplanMode = Literal["on_risk", "every"] | None

_REPLAN_KEY = 0x5E501E  # spawn-key word of the re-solve seeds (distinct from validate's children)


@dataclass(frozen=True, eq=False)
class Replan:
    """One re-plan attempt of :func:`execute`.

    Parameters
    ----------
    step : int
        Execution step ``k`` of the attempt: the re-solve starts from the executed belief ``X_k``.
    reason : str
        ``"risk"`` (predicted success below ``risk`` at a scheduled check), ``"drift"`` (the
        same at a check made because the belief left its predicted ellipse), ``"start"`` (the
        same before the first step, ``execute(start_resolves=...)``), ``"every"`` (the
        schedule) or ``"violated"`` (the executed prefix already broke the formula: nothing to
        re-solve).
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
    """Steps ``j .. N`` of a plan as a plan of its own (``simulate`` indexes gains by what remains)."""
    return ProbabilisticTSTrajectory(
        plan.get_mean()[j:], plan.get_cov()[j:], plan.get_action()[j:], plan.get_control()[j:]
    )


def _state_reading(
    states: np.ndarray, actions: np.ndarray, controls: np.ndarray
) -> ProbabilisticTSTrajectory:
    n = states.shape[1]
    return ProbabilisticTSTrajectory(states, np.zeros((states.shape[0], n, n)), actions, controls)


@dataclass(frozen=True)
class _RiskModel:
    """How the executor predicts a plan's success: the planning model only, its gains, domain and
    process noise, and the measure a risk threshold reads (``execute``'s checks, ``start_check``)."""

    system: Any
    gains: list[Any]
    control_domain: Any
    process_noise: str
    measure: str
    on: str
    samples: int

    @classmethod
    def make(
        cls,
        problem: Any,
        clip_controls: Any,
        process_noise: str,
        lqr_gains: Any,
        default_lqr: Any,
        risk_measure: Any,
        risk_on: Any,
        risk_samples: Any,
    ) -> _RiskModel:
        if risk_measure not in ("bound", "estimate"):
            raise InvalidArgumentError(f"risk_measure must be 'bound' or 'estimate', got {risk_measure!r}")
        if risk_on not in ("belief", "state", "both"):
            raise InvalidArgumentError(f"risk_on must be 'belief', 'state' or 'both', got {risk_on!r}")
        samples = as_int(risk_samples, "risk_samples", minimum=1)
        if not isinstance(clip_controls, bool):
            raise InvalidTypeError(f"clip_controls must be a bool, got {type(clip_controls).__name__}")
        system = problem.switched_system
        return cls(
            system,
            list(system_gains(system, lqr_gains, default_lqr).values()),
            problem.control_domain if clip_controls else None,
            process_noise,
            risk_measure,
            risk_on,
            samples,
        )

    def predict(
        self, plan: ProbabilisticTSTrajectory, j: int, psi: STLFormula, belief: GaussianBelief
    ) -> tuple[float, ClosedLoopPrediction | None]:
        """Predicted probability that the rest of ``plan`` from its step ``j``, started at
        ``belief``, satisfies ``psi``; and the prediction (None for a constant formula)."""
        if psi is TRUE or psi is FALSE:
            return (1.0 if psi is TRUE else 0.0), None
        from .prediction import predict_closed_loop

        pred = predict_closed_loop(
            self.system,
            _suffix(plan, j),
            None,  # the planning model: the executor does not know the real system
            belief.mean,
            formula=psi,
            control_domain=self.control_domain,
            process_noise="model" if self.process_noise == "model" else "none",
            lqr_gains=self.gains,
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


def _resolve_options(
    options: Any, solver_options: Mapping[str, Any] | None, replan_time_limit: Any, adopt: Any
) -> Any:
    """The re-solves' SolverOptions (``options`` with ``solver_options``, capped at
    ``replan_time_limit``); also checks ``adopt``."""
    from ..synthesis.options import SolverOptions

    if adopt not in ("better", "always"):
        raise InvalidArgumentError(f"adopt must be 'better' or 'always', got {adopt!r}")
    replan_time_limit = as_float(replan_time_limit, "replan_time_limit", 0.0, low_open=True)
    if options is None:
        base = SolverOptions()
    elif isinstance(options, SolverOptions):
        base = options
    else:
        raise InvalidTypeError(f"options must be a SolverOptions, got {type(options).__name__}")
    if solver_options is not None:
        if not isinstance(solver_options, Mapping):
            raise InvalidTypeError(f"solver_options must be a mapping, got {type(solver_options).__name__}")
        base = base.with_(**solver_options)
    cap = replan_time_limit if base.time_limit is None else min(base.time_limit, replan_time_limit)
    return base.with_(time_limit=cap)


def _judge(
    record: Replan,
    new: ProbabilisticTSTrajectory | None,
    old: ProbabilisticTSTrajectory,
    j: int,
    psi: STLFormula,
    belief: GaussianBelief,
    p_old: float,
    model: _RiskModel,
    adopt: str,
    predict_always: bool = False,
) -> tuple[Replan, float, ClosedLoopPrediction | None]:
    """A re-solve's record with the comparison ``adopt`` asks for; the new plan's predicted
    success and prediction (NaN and None when not predicted).

    ``adopt="better"``: a fresh MLO plan may track worse than the one followed (the rest of
    ``old`` from its step ``j``, predicted ``p_old``, NaN when not yet predicted), so it is
    adopted only when predicted better. ``"always"``: adopted when found, predicted only with
    ``predict_always``.
    """
    if new is None or (adopt == "always" and not predict_always):
        return record, math.nan, None
    if math.isnan(p_old):
        p_old, _ = model.predict(old, j, psi, belief)
    p_new, pred = model.predict(new, 0, psi, belief)
    adopted = adopt == "always" or p_new > p_old
    return _with(record, predicted=p_old, new_predicted=p_new, adopted=adopted), p_new, pred


def _check_start(
    problem: Any,
    plan: ProbabilisticTSTrajectory,
    belief: GaussianBelief,
    risk: float,
    resolves: int,
    options: Any,
    seed_of: Callable[[int], int],
    model: _RiskModel,
    adopt: str,
) -> tuple[ProbabilisticTSTrajectory, float, ClosedLoopPrediction | None, list[Replan]]:
    """The start check (module notes): the plan to follow, its predicted success, its prediction
    and the re-solve records. ``seed_of(i)`` is the solver seed of re-solve ``i``."""
    formula = problem.stl_formula
    p, pred = model.predict(plan, 0, formula, belief)
    current = plan
    records: list[Replan] = []
    for i in range(resolves):
        if p >= risk:
            break
        record, new = _resolve(problem, belief, formula, options, seed_of(i), 0, "start", p)
        # the loop goes on while below the risk: the new plan is predicted whatever ``adopt``
        record, p_new, new_pred = _judge(record, new, current, 0, formula, belief, p, model, adopt, True)
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


def execute(
    problem: Any,
    plan: ProbabilisticTSTrajectory,
    real_system: Any,
    real_initial_state: Any,
    seed: int | np.random.SeedSequence | None = None,
    *,
    replan: ReplanMode = None,
    risk: float = 0.9,
    every: int = 10,
    check_every: int | None = 1,
    drift: float | None = None,
    start_resolves: int = 0,
    risk_measure: Literal["bound", "estimate"] = "bound",
    risk_on: Literal["belief", "state", "both"] = "both",
    risk_samples: int = 1000,
    max_replans: int = 20,
    adopt: Literal["better", "always"] = "better",
    replan_time_limit: float = 30.0,
    options: Any = None,
    solver_options: Mapping[str, Any] | None = None,
    clip_controls: bool = True,
    process_noise: ProcessNoise = "model",
    lqr_gains: Mapping[int, Sequence[np.ndarray]] | Sequence[Sequence[np.ndarray] | None] | None = None,
    default_lqr: Mapping[str, Any] | None = None,
    plant: PlantStep | None = None,
) -> ExecutionReport:
    """Execute a plan under real noise, re-planning from the executed belief when asked to.

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
    replan : {None, "on_risk", "every"}
        When to re-solve (module notes).
    risk : float
        ``"on_risk"``: re-solve when the predicted success of the remaining plan is below this
        (in ``[0, 1]``).
    every : int
        ``"every"``: re-solve every this many executed steps (>= 1).
    check_every : int or None
        ``"on_risk"``: predict every this many executed steps (>= 1). A prediction costs about
        five executions of the remaining plan (0.1 s for an 82-step light-dark plan). ``None``:
        no scheduled check; only the drift test and the start check decide.
    drift : float in (0, 1), optional
        ``"on_risk"``: also predict at any step at which the executed belief's mean lies outside
        the ``drift`` confidence ellipse of its last predicted distribution (module notes). The
        plan is then executed one step at a time (the random stream, hence the execution up to
        the first adopted re-plan, is the same).
    start_resolves : int
        ``"on_risk"``: the start check. Before the first step the plan's success is predicted
        from the start belief; while it is below ``risk``, the problem is re-solved (at most this
        many times, counted in ``max_replans``; each adopted as after any check). A plan that
        grazes a constraint in its first steps breaks it before a scheduled or drift check can
        see it coming. 0 (default): no start check.
    risk_measure : {"bound", "estimate"}
        The prediction's sound lower bound or its sampled estimate.
    risk_on : {"belief", "state", "both"}
        Success of the executed belief, of the true state (the deterministic reading), or the
        smaller of the two. The true state's bound can be far below the measured rate when a
        chance constraint allows its true state to leave the region (0% against a measured 47%
        on the disturbed light-dark case of ``benchmarks/closed_loop_results.md``): a risk
        threshold on it then re-plans at every check.
    risk_samples : int
        Samples of the Gaussian model for ``risk_measure="estimate"``.
    max_replans : int
        At most this many re-solves per execution (>= 0).
    adopt : {"better", "always"}
        ``"better"`` (default): a re-solved plan replaces the current one only when its
        predicted success from the current belief is higher (both predicted as for ``risk``);
        ``"always"``: whenever the re-solve finds a plan (plain receding-horizon control).
    replan_time_limit : float
        Wall-clock cap (seconds) of one re-solve: the solver's ``time_limit`` is the smaller of
        this and the options' own.
    options : SolverOptions, optional
        The solver options of the re-solves (use the ones the plan was solved with); the seed is
        replaced by the derived one.
    solver_options : mapping, optional
        :class:`~idstlpy.SolverOptions` fields overriding ``options`` (e.g. ``rrt_timeout``).
    clip_controls, process_noise, lqr_gains, default_lqr
        As in :func:`~idstlpy.execution.validation.validate`.
    plant : callable, optional
        A (nonlinear) plant as a step function ``(state, input, mode, rng) -> next_state``
        moving the true state instead of ``real_system`` (which must then be None); see
        :func:`~idstlpy.execution.simulation.simulate`. The risk checks predict with the model.

    Returns
    -------
    ExecutionReport

    Raises
    ------
    InvalidTypeError
        When ``problem`` is not a Problem, ``plan`` not a trajectory, or an option has the wrong
        type.
    InvalidArgumentError
        When ``plan`` is None or an option is out of range (the message names it).
    DimensionError
        When dimensions of the plan, the model and the real system disagree.
    """
    from ..synthesis.problem import Problem

    t0 = time.perf_counter()
    if not isinstance(problem, Problem):
        raise InvalidTypeError(f"problem must be a Problem, got {type(problem).__name__}")
    if plan is None:
        raise InvalidArgumentError(
            "plan is None: there is no plan to execute (see problem.last_result.reason)"
        )
    if not isinstance(plan, ProbabilisticTSTrajectory):
        raise InvalidTypeError(f"plan must be a ProbabilisticTSTrajectory, got {type(plan).__name__}")
    if replan not in (None, "on_risk", "every"):
        raise InvalidArgumentError(f"replan must be None, 'on_risk' or 'every', got {replan!r}")
    risk = as_float(risk, "risk", 0.0, 1.0)
    every = as_int(every, "every", minimum=1)
    if check_every is not None:
        check_every = as_int(check_every, "check_every", minimum=1)
    if drift is not None:
        drift = as_float(drift, "drift", 0.0, 1.0, low_open=True)
        if drift == 1.0:
            raise InvalidArgumentError("drift must be < 1 (a confidence), got 1.0")
    max_replans = as_int(max_replans, "max_replans", minimum=0)
    start_resolves = as_int(start_resolves, "start_resolves", minimum=0)
    base = _resolve_options(options, solver_options, replan_time_limit, adopt)
    ss = as_seed_sequence(seed)
    rng = np.random.default_rng(ss)  # the same stream simulate(seed=seed) draws

    system = problem.switched_system
    formula = problem.stl_formula
    model = _RiskModel.make(
        problem, clip_controls, process_noise, lqr_gains, default_lqr, risk_measure, risk_on, risk_samples
    )
    sim_options: dict[str, Any] = {
        "control_domain": model.control_domain,
        "process_noise": process_noise,
        "lqr_gains": model.gains,
        "plant": plant,
    }

    # The drift test's reference: (execution step, predicted belief means (L, n), their
    # covariances (L, n, n)) of the last prediction of the plan followed.
    reference: list[tuple[int, np.ndarray, np.ndarray]] = []
    threshold = float(chi2.ppf(drift, system.n)) if drift is not None else math.inf

    def predicted_success(
        current: ProbabilisticTSTrajectory,
        j: int,
        psi: STLFormula,
        belief: GaussianBelief,
        at: int | None = None,
    ) -> float:
        """Predicted probability that the rest of ``current`` from its step ``j`` satisfies ``psi``
        (with ``at``, the execution step, the prediction becomes the drift test's reference)."""
        value, pred = model.predict(current, j, psi, belief)
        remember(pred, at)
        return value

    def remember(pred: ClosedLoopPrediction | None, at: int | None) -> None:
        if pred is not None and at is not None and drift is not None:
            reference[:] = [(at, pred.belief_mean, pred.belief_mean_cov)]

    # Executed so far (lists of per-chunk arrays; row 0 of every later chunk repeats the last row).
    current = plan
    start = 0  # execution step at which ``current`` started
    plans: list[tuple[int, ProbabilisticTSTrajectory]] = [(0, plan)]
    means = [plan.get_mean(0)[None, :]]
    covs = [plan.get_cov(0)[None, :, :]]
    states: list[np.ndarray] = []
    observations: list[np.ndarray] = []
    actions: list[np.ndarray] = []
    controls: list[np.ndarray] = []
    belief = GaussianBelief(plan.get_mean(0).copy(), plan.get_cov(0).copy())
    x: Any = real_initial_state
    replans: list[Replan] = []
    attempts = 0
    violated = False
    k = 0
    p_max = max((mode.p for mode in system.system_modes), default=0)

    def drifted(k: int) -> bool:
        """Whether the executed belief's mean left its predicted ``drift`` ellipse at step ``k``."""
        if not reference:
            return False
        at, mu, cov = reference[0]
        i = k - at
        if i >= mu.shape[0]:
            return False
        d = belief.mean - mu[i]
        C = cov[i] + 1e-12 * (1.0 + float(np.trace(cov[i]))) * np.eye(d.shape[0])
        return float(d @ np.linalg.solve(C, d)) > threshold

    def decision_due(k: int) -> str | None:
        if replan is None or k == 0 or violated or attempts >= max_replans:
            return None
        if replan == "every" and k % every == 0:
            return "every"
        if replan == "on_risk" and check_every is not None and k % check_every == 0:
            return "risk"
        return "drift" if drift is not None and drifted(k) else None

    def attempt(
        k: int, j: int, psi: STLFormula, why: str, p_old: float
    ) -> ProbabilisticTSTrajectory | None:
        """Re-solve ``psi`` from the current belief at step ``k``; the new plan when adopted."""
        nonlocal attempts
        record, new_plan = _resolve(problem, belief, psi, base, replan_seed(ss, attempts), k, why, p_old)
        attempts += 1
        record, _, pred = _judge(record, new_plan, current, j, psi, belief, p_old, model, adopt)
        if record.adopted and new_plan is not None and drift is not None:
            # the adopted plan's prediction is the drift test's reference
            if pred is not None:
                remember(pred, k)
            else:
                predicted_success(new_plan, 0, psi, belief, at=k)
        replans.append(record)
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
        if not (record.adopted and new_plan is not None):
            return None
        plans.append((k, new_plan))
        return new_plan

    if replan == "on_risk" and formula is not TRUE and formula is not FALSE and (drift or start_resolves):
        # Before the first step: the start check (module notes) and the drift test's first
        # reference, the prediction of the plan that is followed.
        current, _, pred, records = _check_start(
            problem,
            plan,
            belief,
            risk,
            min(start_resolves, max_replans),
            base,
            lambda i: replan_seed(ss, i),
            model,
            adopt,
        )
        replans.extend(records)
        attempts += len(records)
        plans[:] = [(0, current)]  # a plan replaced at the start was never followed
        remember(pred, 0)

    while True:
        j = k - start
        remaining = current.num_of_steps - j
        if remaining <= 0:
            break
        why = decision_due(k)
        if why is not None:
            prefix = ProbabilisticTSTrajectory(
                np.concatenate(means), np.concatenate(covs), np.concatenate(actions), np.concatenate(controls)
            )
            psi = progress(formula, prefix)
            if psi is FALSE:
                violated = True  # the prefix broke the formula: no plan can repair it
                replans.append(Replan(k, "violated", 0.0, "skipped", False, formula=str(psi)))
            elif psi is not TRUE:
                p_old = float("nan")
                go = replan == "every"
                if replan == "on_risk":
                    p_old = predicted_success(current, j, psi, belief, at=k)
                    go = p_old < risk
                if go:
                    adopted = attempt(k, j, psi, why, p_old)
                    if adopted is not None:
                        current, start = adopted, k
                        j, remaining = 0, adopted.num_of_steps
        # Execute up to the next decision step (or the end of the plan) with simulate itself.
        if replan is None:
            chunk = remaining
        elif replan == "on_risk" and drift is not None:
            chunk = 1
        elif replan == "every":
            chunk = min(remaining, every - k % every)
        elif check_every is None:
            chunk = remaining  # no schedule and no drift test: only the start check decides
        else:
            chunk = min(remaining, check_every - k % check_every)
        xi_sim, xi_real = simulate(
            system,
            _suffix(current, j),
            chunk,
            x,
            real_system,
            seed=rng,
            initial_belief=belief,
            **sim_options,
        )
        if not states:
            states.append(xi_real.get_state()[:1])
            observations.append(_pad(xi_real.get_observation()[:1], p_max))
        means.append(xi_sim.get_mean()[1:])
        covs.append(xi_sim.get_cov()[1:])
        states.append(xi_real.get_state()[1:])
        observations.append(_pad(xi_real.get_observation()[1:], p_max))
        actions.append(xi_sim.get_action())
        controls.append(xi_sim.get_control())
        belief = GaussianBelief(xi_sim.get_mean(chunk), xi_sim.get_cov(chunk))
        x = xi_real.get_state(chunk)
        k += chunk

    all_actions = np.concatenate(actions) if actions else np.zeros(0, dtype=int)
    all_controls = np.concatenate(controls) if controls else np.zeros((0, system.m))
    xi_b = ProbabilisticTSTrajectory(np.concatenate(means), np.concatenate(covs), all_actions, all_controls)
    if not states:  # a plan of no step: nothing was executed
        x0 = np.asarray(real_initial_state, dtype=float).reshape(1, -1)
        states, observations = [x0], [np.full((1, p_max), np.nan)]
    all_states = np.concatenate(states)
    xi_r = RealTrajectory(all_states, np.concatenate(observations), all_actions, all_controls)
    b_margin = robustness(xi_b, formula)
    s_margin = robustness(_state_reading(all_states, all_actions, all_controls), formula)
    entropy = ss.entropy
    return ExecutionReport(
        belief=xi_b,
        real=xi_r,
        replans=tuple(replans),
        belief_satisfied=b_margin >= 0.0,
        state_satisfied=s_margin >= 0.0,
        belief_margin=b_margin,
        state_margin=s_margin,
        plans=tuple(plans),
        seed_entropy=int(entropy) if isinstance(entropy, int | np.integer) else tuple(entropy or ()),
        elapsed=time.perf_counter() - t0,
    )


@dataclass(frozen=True)
class StartCheck:
    """Outcome of :func:`start_check`.

    Parameters
    ----------
    plan : ProbabilisticTSTrajectory
        The plan to follow: the given one, or a re-solved plan predicted better.
    predicted : float
        Predicted success of ``plan`` from its start belief (the risk measure's).
    initial_predicted : float
        Predicted success of the plan given to the check.
    replans : tuple of Replan
        The re-solves made (reason ``"start"``, step 0), in order.
    """

    plan: ProbabilisticTSTrajectory = field(repr=False)
    predicted: float
    initial_predicted: float
    replans: tuple[Replan, ...]

    @property
    def replaced(self) -> bool:
        """Whether a re-solved plan replaced the given one."""
        return any(r.adopted for r in self.replans)


def start_check(
    problem: Any,
    plan: ProbabilisticTSTrajectory,
    *,
    risk: float = 0.9,
    resolves: int = 2,
    seed: int | np.random.SeedSequence = 0,
    risk_measure: Literal["bound", "estimate"] = "bound",
    risk_on: Literal["belief", "state", "both"] = "both",
    risk_samples: int = 1000,
    adopt: Literal["better", "always"] = "better",
    replan_time_limit: float = 30.0,
    options: Any = None,
    solver_options: Mapping[str, Any] | None = None,
    clip_controls: bool = True,
    process_noise: str = "model",
    lqr_gains: Mapping[int, Sequence[np.ndarray]] | Sequence[Sequence[np.ndarray] | None] | None = None,
    default_lqr: Mapping[str, Any] | None = None,
) -> StartCheck:
    """Check a plan before it is executed; re-solve it while its predicted success is below ``risk``.

    The plan's success is predicted from its start belief as :func:`execute` predicts it
    (the planning model, the executor's gains and clipping, ``risk_measure`` and ``risk_on``).
    Below ``risk``, the problem is re-solved (at most ``resolves`` times, solver seeds derived
    from ``seed``) and a new plan is kept when predicted better (``adopt="better"``) or whenever
    one is found (``"always"``). Nothing is observed before the first step, so the check is the
    same for every execution: make it once, then execute its plan (module notes).

    Parameters
    ----------
    problem : Problem
        The problem the plan solves.
    plan : ProbabilisticTSTrajectory
        The plan to check, ``N`` steps, starting at the problem's prior.
    risk : float
        The predicted success a plan needs to be followed as it is (in ``[0, 1]``).
    resolves : int
        Re-solves at most (>= 0).
    seed : int or SeedSequence
        Seed of the re-solves' seeds (re-solve ``i`` uses ``replan_seed(SeedSequence(seed), i)``).
    risk_measure, risk_on, risk_samples, adopt, replan_time_limit, options, solver_options
        As in :func:`execute`; ``solver_options={"guarantee": "closed_loop"}`` re-solves against
        the predicted true state.
    clip_controls, process_noise, lqr_gains, default_lqr
        The executor's, as in :func:`~idstlpy.execution.validation.validate`.

    Returns
    -------
    StartCheck

    Raises
    ------
    InvalidTypeError
        When ``problem`` is not a Problem, ``plan`` not a trajectory, or an option has the wrong
        type.
    InvalidArgumentError
        When ``plan`` is None or an option is out of range (the message names it).
    """
    from ..synthesis.problem import Problem

    if not isinstance(problem, Problem):
        raise InvalidTypeError(f"problem must be a Problem, got {type(problem).__name__}")
    if plan is None:
        raise InvalidArgumentError("plan is None: there is no plan to check (see problem.last_result.reason)")
    if not isinstance(plan, ProbabilisticTSTrajectory):
        raise InvalidTypeError(f"plan must be a ProbabilisticTSTrajectory, got {type(plan).__name__}")
    risk = as_float(risk, "risk", 0.0, 1.0)
    resolves = as_int(resolves, "resolves", minimum=0)
    ss = as_seed_sequence(seed, allow_none=False)
    base = _resolve_options(options, solver_options, replan_time_limit, adopt)
    model = _RiskModel.make(
        problem, clip_controls, process_noise, lqr_gains, default_lqr, risk_measure, risk_on, risk_samples
    )
    belief = GaussianBelief(plan.get_mean(0).copy(), plan.get_cov(0).copy())
    current, p, _, records = _check_start(
        problem, plan, belief, risk, resolves, base, lambda i: replan_seed(ss, i), model, adopt
    )
    return StartCheck(current, p, records[0].predicted if records else p, tuple(records))


def _pad(obs: np.ndarray, p_max: int) -> np.ndarray:
    """Observations with ``p_max`` columns (NaN where a mode observes fewer)."""
    if obs.shape[1] == p_max:
        return obs
    out = np.full((obs.shape[0], p_max), np.nan)
    out[:, : obs.shape[1]] = obs
    return out


def _with(record: Replan, **changes: Any) -> Replan:
    from dataclasses import replace

    return replace(record, **changes)


def _resolve(
    problem: Any,
    belief: GaussianBelief,
    psi: STLFormula,
    options: Any,
    seed: int,
    step: int,
    reason: str,
    predicted: float,
) -> tuple[Replan, ProbabilisticTSTrajectory | None]:
    """Re-solve ``psi`` from ``belief``; the record and the new plan (None when none was found)."""
    from ..synthesis.problem import Problem

    t0 = time.perf_counter()
    try:
        cov = 0.5 * (belief.cov + belief.cov.T)  # the filter's Joseph form is symmetric up to rounding
        sub = Problem(problem.switched_system, problem.control_domain, to_belief(belief.mean, cov), psi)
        result = sub.solve_result(options=options.with_(seed=seed))
    except IdstlpyError as exc:
        # A re-plan that cannot even be posed keeps the old plan; the record says why.
        return (
            Replan(
                step,
                reason,
                predicted,
                "error",
                False,
                solve_time=time.perf_counter() - t0,
                seed=seed,
                formula=str(psi),
                reason_text=f"{type(exc).__name__}: {exc}",
            ),
            None,
        )
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
