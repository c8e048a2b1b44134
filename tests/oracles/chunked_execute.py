"""The executor of idstlpy 0.2's ``execute`` before issue 22's rewrite (commit 967ec19), as an
oracle: five nested closures that call :func:`idstlpy.simulate` on the remaining plan a chunk of
steps at a time (one random stream), with the drift / risk checks, the start check and the
re-solves written in their own way.

``tests/test_execute_reference.py`` runs it beside :func:`idstlpy.execute` (written on
:class:`idstlpy.ReplanningExecutor`) on the *current* solver and predictor, so the comparison
isolates the executor: whatever a change to synthesis does to the re-solves, both executors
must make the same records, plans and runs, bit for bit. It does not import the package's
re-planning modules (only the records it builds, :class:`idstlpy.Replan` and
:class:`idstlpy.ExecutionReport`, whose fields are unchanged).
"""

# ruff: noqa
# mypy: ignore-errors
from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Literal
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from idstlpy._checks import as_float, as_int, as_seed_sequence
from idstlpy.belief import GaussianBelief, to_belief
from idstlpy.errors import IdstlpyError, InvalidArgumentError, InvalidTypeError
from idstlpy.executor import PlantStep, ProcessNoise
from idstlpy.formulas import FALSE, TRUE, STLFormula
from idstlpy.progression import progress
from idstlpy.semantics import robustness
from idstlpy.tracking import system_gains
from idstlpy.trajectory import ProbabilisticTSTrajectory, RealTrajectory
from idstlpy.execution.simulation import simulate
from idstlpy.execution.replanning import ExecutionReport
from idstlpy.execution.resolving import Replan

if TYPE_CHECKING:
    from idstlpy.execution.prediction import ClosedLoopPrediction

logger = logging.getLogger(__name__)

ReplanMode = Literal["on_risk", "every"] | None

_REPLAN_KEY = 0x5E501E


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
    """Steps ``j .. N`` of a plan as a plan of its own (``simulate`` indexes gains by what remains),
    tracked with the gains the plan was made for (``plan.tracking``, issue 34)."""
    out = ProbabilisticTSTrajectory(
        plan.get_mean()[j:], plan.get_cov()[j:], plan.get_action()[j:], plan.get_control()[j:]
    )
    out.tracking = plan.tracking
    return out


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
    gains: list[Any] | None
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
            # gains nobody chose: each plan's own (None here, read off the plan's suffix)
            None
            if lqr_gains is None and default_lqr is None
            else list(system_gains(system, lqr_gains, default_lqr).values()),
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
        from idstlpy.execution.prediction import predict_closed_loop

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
    from idstlpy.synthesis.options import SolverOptions

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
    from idstlpy.synthesis.problem import Problem

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

    def attempt(k: int, j: int, psi: STLFormula, why: str, p_old: float) -> ProbabilisticTSTrajectory | None:
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
    from idstlpy.synthesis.problem import Problem

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
