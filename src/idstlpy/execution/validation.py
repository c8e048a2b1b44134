"""Monte Carlo validation: how often does the plan's promise hold when it is executed?

Each run executes the plan with :func:`~idstlpy.execution.simulation.simulate` (Kalman filter,
receding-horizon LQR, true state moved by the real system) under its own random stream, and
records

- *belief success*: the executed belief trajectory satisfies the formula (the monitor);
- *state success*: the true states satisfy the formula's deterministic reading, i.e. the
  formula evaluated with zero covariance at the true states (every chance predicate
  ``P[h'x + c <= 0] >= 1 - eps`` becomes ``h'x + c <= 0``);
- *violations*: for every atomic proposition, whether execution broke it at a step where the
  plan satisfies it (the plan's promise), and for every predicate (face) of it, whether that
  face was broken at such a step. A broken promise at a step the formula does not need is still
  counted, so violation rates are an upper view of what went wrong, not failure causes.

With ``predict=True`` the plan's execution is also *predicted* once, before the runs, by
:func:`~idstlpy.execution.prediction.predict_closed_loop` with exactly the options the runs use
(tracking gains, projection on the control domain, process noise, real system, true initial
state), and :attr:`ValidationReport.predicted` holds it. :meth:`ValidationReport.prediction_comparison`
(also in :meth:`~ValidationReport.as_dict` and :meth:`~ValidationReport.summary`) puts the
predicted violation rates and formula success next to the measured ones, with the measured
Wilson 95% interval and an ``outside`` flag per rate. The prediction is exact for constant sensor
noise without clipping (up to its model sampling); with state-dependent noise or clipped inputs it
is a linearisation around the plan, and the comparison shows how far off it is.

Runs are independent: run ``i`` uses child ``i`` of ``numpy.random.SeedSequence(seed).spawn``,
and results are gathered by index, so the same seed gives the identical report whatever the
executor and the number of workers. Without a fixed true start (the default), run ``i`` starts at
row ``i`` of one draw of shape (runs, n) from ``default_rng(SeedSequence(seed))`` mapped through
the prior (:func:`prior_starts`); its noise is the one it has from a fixed start.

Monte Carlo at scale
--------------------
A worker executes its runs together (``batched=True``, the default): the executor's one step
law (:class:`~idstlpy.executor.StepLaw`) advances arrays of all the runs' true states, filter
means and covariances (shared while the sensor noise is constant, one per run once a
state-dependent sensor has made them differ), and the monitor evaluates all of them at once
(:func:`~idstlpy.semantics.formula_margins` over a batch). Every run still draws from its own
generator, in the order a run alone draws (:class:`_RunStreams`), so each run gets exactly the
noise of ``simulate(..., seed=default_rng(child_i))``: the report is the one of the serial loop
(``batched=False``), the margins up to rounding (about 1e-16). A state-dependent noise function
is called once per step for all runs when it takes a batch of states (``x[..., 0]``; see
:class:`~idstlpy.dynamical_system.POLBSWithNonLinNoise`), else once per run; the filters'
updates are batched either way. Progress: ``progress(done, runs)`` after every batch, and an
INFO log record at most every second (the CLI shows it).

Parallelism and pickling
------------------------
Runs are shipped in batches to any :class:`concurrent.futures.Executor` (default: a
``ProcessPoolExecutor`` with 2 workers). A process pool needs the planning model pickled, and
the light-dark noise function is a lambda, which the standard pickle refuses. In order:

1. the payload (model, formula, plan, real system, gains) is pickled as is when it can be;
2. otherwise it is serialised with ``cloudpickle`` if that package is installed (it is with the
   ``dask`` extra);
3. otherwise ``problem_factory`` (a picklable zero-argument callable returning an equivalent
   :class:`~idstlpy.Problem`, e.g. ``functools.partial(scenarios.light_dark, 240, 40)``) rebuilds
   the problem in each worker; the tracking gains travel as plain arrays;
4. otherwise the runs execute in-process (a debug log says so). The result is the same, only
   slower. ``executor="serial"`` asks for the in-process path directly; a
   ``ThreadPoolExecutor`` needs no pickling at all.

Modules
-------
:func:`validate` is a short façade: its keywords are checked and packed into a frozen
:class:`~idstlpy.execution.validation_spec.ValidationSpec` (with the executor as one
:class:`~idstlpy.executor.ExecutorSpec` and re-planning as one
:class:`~idstlpy.execution.policy.ReplanPolicy`), then the parts do one job each: the true starts
(:mod:`~idstlpy.execution.starts`), running batches (:mod:`~idstlpy.execution.batches`), the
monitor of a run (:mod:`~idstlpy.execution.monitor`), rates and intervals
(:mod:`~idstlpy.execution.intervals`), the report and its verdict (:mod:`~idstlpy.execution.report`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from concurrent.futures import Executor, ProcessPoolExecutor, ThreadPoolExecutor
from typing import TYPE_CHECKING, Any, Literal, Unpack

import numpy as np
from numpy.typing import ArrayLike

from ..errors import InvalidArgumentError
from .batches import Payload, batch_size, execute_runs, run_batch, serialise
from .intervals import wilson_interval
from .monitor import face_slacks as _face_slacks  # noqa: F401 - the name of earlier versions
from .monitor import state_trajectory
from .report import ValidationReport, build_report
from .starts import prior_starts
from .validation_spec import (
    PREDICT_OPTIONS,
    REPLAN_OPTION_KEYS,
    VALIDATE_OPTIONS,
    Dispatch,
    ValidateOptions,
    ValidationSpec,
    policy_of,
)

if TYPE_CHECKING:  # the prediction is imported when asked for (validate(predict=True))
    from ..dynamical_system import LCS, SwitchedSystem
    from ..synthesis.problem import Problem
    from ..trajectory import ProbabilisticTSTrajectory
    from .prediction import ClosedLoopPrediction

__all__ = [
    "PREDICT_OPTIONS",
    "REPLAN_OPTION_KEYS",
    "VALIDATE_OPTIONS",
    "ValidationReport",
    "prior_starts",
    "state_trajectory",
    "validate",
    "wilson_interval",
]

logger = logging.getLogger(__name__)

BATCH_RUNS = 4096
"""Most runs executed together as arrays by one worker; fewer when a run's arrays are large
(:func:`~idstlpy.execution.batches.batch_size`: about 32 MB of covariances per batch). The
results do not depend on it: every run draws from its own stream
(:class:`~idstlpy.execution.batches.RunStreams`)."""

SMALL_WORK = 200_000
"""``validate(executor=None)`` runs in-process up to this many run-steps (batched runs only): about
a third of a second of the listing's work on one core, less than starting worker processes."""

PREDICT_SAMPLES = 20000
"""Default model samples of ``validate(predict=True)``: their sampling error (at most 0.0035 on a
rate) is a tenth of the Wilson half-width of 1000 runs, so a flag says something about the model."""


def validate(
    problem: Problem,
    solution: ProbabilisticTSTrajectory,
    real_system: SwitchedSystem | LCS | None,
    real_initial_state: ArrayLike | Literal["prior"] | None = None,
    runs: int = 100,
    seed: int | np.random.SeedSequence | None = None,
    executor: Executor | str | None = None,
    **options: Unpack[ValidateOptions],
) -> ValidationReport:
    """Execute a plan many times and measure how often its promise held (module notes).

    Parameters
    ----------
    problem : Problem
        The problem the plan solves (model, control domain, formula).
    solution : ProbabilisticTSTrajectory
        The plan.
    real_system : SwitchedSystem or None
        The system moving the true state (e.g. ``scenarios.light_dark_real_system()``; or ``plant``).
    real_initial_state : array_like of shape (n,), "prior" or None
        A fixed true start for every run (the paper's listing passes ``[0.5, 2.75]``), or (None,
        ``"prior"``, the default) a true start per run drawn from the prior, the plan's first
        belief: the rates the promise is about when the true start is unknown (:func:`prior_starts`).
    runs : int
        Number of independent executions (>= 1).
    seed : int or SeedSequence, optional
        Root of the run seeds; the same seed gives the identical report for any executor.
    executor : concurrent.futures.Executor, "serial" or None
        Where runs execute (the same report on any): None, in-process for few batched runs
        (``runs x steps <= SMALL_WORK``), else a ``ProcessPoolExecutor(max_workers)``.
    **options
        The keywords below (:data:`~idstlpy.execution.validation_spec.VALIDATE_OPTIONS`), packed
        into a frozen :class:`~idstlpy.execution.validation_spec.ValidationSpec`; an unknown one
        raises :class:`~idstlpy.errors.InvalidTypeError` (a ``TypeError``) naming it.

    Other Parameters
    ----------------
    num_of_steps : int, optional
        Steps per run (default the whole plan; not with ``policy``).
    clip_controls, process_noise, lqr_gains, default_lqr, plant
        The executor, as in :func:`~idstlpy.simulate` (``clip_controls=True``, the default,
        projects the inputs on ``problem.control_domain``); a ``plant`` cannot be predicted.
    problem_factory, max_workers, progress
        Where runs execute: a picklable zero-argument callable rebuilding the problem in a
        process pool's workers; the default pool's workers (2); ``progress(done, runs)``.
    keep_trajectories : int
        Keep the first this-many executions in :attr:`ValidationReport.executions`.
    predict, predict_options
        Also predict the execution (:func:`~idstlpy.predict_closed_loop` with this call's
        executor, start and steps) into :attr:`ValidationReport.predicted`; the prediction's
        own options (:data:`PREDICT_OPTIONS`; ``samples`` default :data:`PREDICT_SAMPLES`).
    policy : ReplanPolicy, optional
        Re-plan every run with :func:`~idstlpy.execute` (:attr:`ValidationReport.replans`).
    replan, replan_options
        Deprecated: ``policy=ReplanPolicy.from_keywords(replan, **replan_options)``.
    execution_target : ExecutionTarget, (belief, state) or mapping, optional
        What the verdict is against (default 90% belief / 95% true state).
    batched : bool
        Execute a worker's runs together as arrays (default) or one by one (the same rates).

    Returns
    -------
    ValidationReport

    Raises
    ------
    InvalidTypeError, InvalidArgumentError, DimensionError
        Naming the argument that is wrong.
    """
    t0 = time.perf_counter()
    opts = policy_of(options, 2)  # (unknown keywords named, deprecated ones warned about)
    spec, dispatch = ValidationSpec.make(
        problem, solution, real_system, real_initial_state, runs, seed, executor, opts
    )
    predicted = _predict(spec) if spec.predict else None
    results = _run(spec, dispatch, t0)
    report = build_report(spec, results, time.perf_counter() - t0, predicted)
    _warn_bound(report, predicted)
    return report


def _predict(spec: ValidationSpec) -> ClosedLoopPrediction:
    """The prediction of exactly the execution ``validate`` runs (same gains, domain, noise, start).

    A true start drawn from the prior is predicted with the prior's covariance.
    """
    from ..markov import switching_of
    from .prediction import predict_closed_loop

    if switching_of(spec.executor.system) is not None:
        raise InvalidArgumentError(
            "predict=True: the closed-loop prediction does not follow chance switching; use "
            "idstlpy.markov_bound(problem, plan) for the bound over the executed mode sequences"
        )
    opts = dict(spec.predict_options)
    opts.setdefault("samples", PREDICT_SAMPLES)
    t0 = time.perf_counter()
    predicted = predict_closed_loop(
        spec.problem,
        spec.plan,
        None,  # (the real system is the executor's)
        spec.start,
        num_of_steps=spec.num_of_steps,
        real_initial_cov=None if spec.starts is None else spec.plan.get_cov(0),
        executor=spec.executor,
        **opts,
    )
    logger.debug("validate: closed-loop prediction in %.3g s", time.perf_counter() - t0)
    return predicted


def _pool(
    spec: ValidationSpec, dispatch: Dispatch, payload: Payload
) -> tuple[Executor | None, bytes | None, bool]:
    """Where the runs execute: the pool (None: in-process), the pickled payload (None: shared),
    whether the pool is made here (and shut down after the runs)."""
    executor, runs, steps = dispatch.executor, spec.runs, spec.num_of_steps
    batched = payload.batched and spec.policy is None and payload.plant is None
    small = batched and runs * max(steps, 1) <= SMALL_WORK
    if executor == "serial" or (executor is None and small):
        if executor is None:
            logger.debug("validate: %d runs of %d steps, batched: running in-process", runs, steps)
        return None, None, False
    if isinstance(executor, ThreadPoolExecutor):
        return executor, None, False
    blob = serialise(payload, dispatch.problem_factory)
    if blob is None:
        logger.debug("validate: problem not picklable and no problem_factory: running in-process")
        return None, None, False
    if isinstance(executor, Executor):
        return executor, blob, False
    return ProcessPoolExecutor(max_workers=dispatch.max_workers), blob, True


def _run(spec: ValidationSpec, dispatch: Dispatch, t0: float) -> list[dict[str, Any]]:
    """Execute the runs in batches where ``dispatch`` says; their records in run order."""
    payload = spec.payload(batch_size(spec.num_of_steps, spec.executor.system.n, BATCH_RUNS))
    runs, starts = spec.runs, spec.starts
    chunk = max(1, math.ceil(runs / (4 * dispatch.max_workers)))
    batches = [
        (i, spec.seeds[i : i + chunk], None if starts is None else starts[i : i + chunk])
        for i in range(0, runs, chunk)
    ]
    results: list[dict[str, Any]] = []
    report_progress = _progress(dispatch.progress, runs, t0)
    pool, blob, own = _pool(spec, dispatch, payload)
    try:
        if pool is None:
            for i, seeds, x0s in batches:
                results.extend(execute_runs(payload, seeds, i, x0s))
                report_progress(len(results))
        else:
            if blob is None:  # threads share the payload
                futures = [pool.submit(execute_runs, payload, seeds, i, x0s) for i, seeds, x0s in batches]
            else:
                futures = [pool.submit(run_batch, blob, seeds, i, x0s) for i, seeds, x0s in batches]
            for fut in futures:
                results.extend(fut.result())
                report_progress(len(results))
    finally:
        if own and pool is not None:
            pool.shutdown()
    return results


def _progress(progress: Callable[[int, int], None] | None, runs: int, t0: float) -> Callable[[int], None]:
    """``progress(done, runs)`` after every batch, and an INFO log record at most every second."""
    last_log = [time.perf_counter()]

    def report_progress(done: int) -> None:
        if progress is not None:
            progress(done, runs)
        now = time.perf_counter()
        if now - last_log[0] >= 1.0 or done == runs:
            last_log[0] = now
            logger.info("validate: %d/%d runs (%.1f s)", done, runs, now - t0)

    return report_progress


def _warn_bound(report: ValidationReport, predicted: ClosedLoopPrediction | None) -> None:
    """Log a warning when a predicted success bound lies above the measured interval."""
    comparison = report.prediction_comparison()
    if comparison is None:
        return
    for reading, entry in comparison["success"].items():
        if entry["bound_holds"] is False:
            # the bound is sound for the Gaussian model only: say when the model failed the plan
            logger.warning(
                "validate: the predicted %s success bound %.4g is above the measured rate's 95%% "
                "interval [%.4g, %.4g] (largest predicted clip probability %.2g): the linearised "
                "closed loop does not describe this execution",
                reading,
                entry["bound"],
                entry["ci"][0],
                entry["ci"][1],
                float(predicted.clip_probability.max())
                if predicted is not None and predicted.num_of_steps
                else 0.0,
            )
