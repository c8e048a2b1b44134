"""Jobs: one unit of work as plain data, and :func:`run_job`, which turns it into a record.

A :class:`Job` is the text of a problem file, overrides, a seed, a kind (``"solve"`` or
``"validate"``) and, for a validation of a saved plan, that plan; its record (see
:mod:`idstlpy.batch.records`) is plain JSON data. Nothing but the job and the record crosses
process boundaries, so every executor gives the same records for the same jobs.

Seeds: a job's ``seed`` wins; otherwise the file's ``[solver] seed``; otherwise
:data:`DEFAULT_SEED`, so that a file without a seed gives the same plan on every run (and
``idstlpy solve`` and ``idstlpy validate`` check the same plan). The record says which one was
used (``seed`` and ``seed_source``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import platform
import time
import traceback
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from ..errors import IdstlpyError, InvalidArgumentError, ProblemFileError
from ..problem_file import ExecutionSettings, ProblemSpec, apply_overrides, load_problem, text_sha256
from ..synthesis import SolverOptions
from .records import (
    RESULT_SCHEMA,
    jsonable,
    plan_from_record,
    problem_section,
    result_to_dict,
    software_section,
)

__all__ = [
    "JOB_KINDS",
    "DEFAULT_SEED",
    "PLAN_TOLERANCE",
    "Job",
    "run_job",
    "comparable",
    "failure_record",
    "derived_seed",
    "new_record",
    "replan_summary",
]

logger = logging.getLogger("idstlpy.batch")

JOB_KINDS = ("solve", "validate")

DEFAULT_SEED = 0
"""The solver's seed when neither the job nor the problem file gives one."""

PLAN_TOLERANCE = 1e-6
"""Largest difference (relative to the belief's scale) between a saved plan's beliefs and their
re-roll under the problem's dynamics before the saved plan is rejected."""


@dataclass(frozen=True)
class Job:
    """One unit of work, as plain data.

    Parameters
    ----------
    kind : {"solve", "validate"}
        ``solve``: load, build, ``solve_result``. ``validate``: the same (or, with ``plan``,
        check the saved plan instead of solving), then execute the plan on the real system
        (:func:`idstlpy.validate`).
    problem_text : str
        The problem file's text (shipped as is to workers: they need no shared filesystem).
    problem_name : str
        Name used in messages and records (not part of :attr:`key`).
    overrides : dict
        Dotted paths to values (see :func:`~idstlpy.problem_file.apply_overrides`).
    seed : int or None
        Seed of the solver (and, through a spawned child, of the validation runs); None uses
        the file's ``[solver] seed``, or :data:`DEFAULT_SEED`.
    plan : dict or None
        A saved result (``SolveResult.to_dict()`` or a record) whose plan a ``validate`` job
        checks and executes instead of solving.
    """

    kind: str
    problem_text: str
    problem_name: str = "<string>"
    overrides: dict[str, Any] = field(default_factory=dict)
    seed: int | None = None
    plan: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        if self.kind not in JOB_KINDS:
            raise InvalidArgumentError(f"job kind must be one of {JOB_KINDS}, got {self.kind!r}")
        seed = self.seed
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
            raise InvalidArgumentError(f"job seed must be a non-negative int or None, got {self.seed!r}")
        if self.plan is not None:
            if self.kind != "validate":
                raise InvalidArgumentError("a saved plan can only be given to a validate job")
            if not isinstance(self.plan, dict) or not isinstance(self.plan.get("plan"), dict):
                raise InvalidArgumentError("plan must be a saved result with a plan (its 'plan' field)")

    @classmethod
    def from_file(
        cls,
        path: str | os.PathLike[str],
        kind: str = "solve",
        overrides: Mapping[str, Any] | None = None,
        seed: int | None = None,
        plan: dict[str, Any] | None = None,
    ) -> Job:
        """A job for the problem file at ``path`` (its text is read now).

        Parameters
        ----------
        path : path
            The problem file.
        kind : {"solve", "validate"}
        overrides : mapping, optional
            Dotted paths to values.
        seed : int, optional
        plan : dict, optional
            A saved result to validate instead of solving.

        Returns
        -------
        Job
        """
        try:
            text = Path(path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ProblemFileError(f"{path}: cannot read the problem file: {exc}") from None
        return cls(kind, text, str(path), dict(overrides or {}), seed, plan)

    @property
    def key(self) -> str:
        """Hash of everything that determines the result (16 hex digits)."""
        payload = {
            "schema": RESULT_SCHEMA,
            "kind": self.kind,
            "problem": self.problem_text,
            "overrides": jsonable(self.overrides),
            "seed": self.seed,
        }
        if self.plan is not None:
            payload["plan"] = hashlib.sha256(_canonical(self.plan.get("plan")).encode()).hexdigest()
        return hashlib.sha256(_canonical(payload).encode()).hexdigest()[:16]

    @property
    def problem_sha256(self) -> str:
        """SHA-256 of :attr:`problem_text` (what result files record)."""
        return text_sha256(self.problem_text)

    def as_dict(self) -> dict[str, Any]:
        """Plain-data form (what executors ship to workers).

        Returns
        -------
        dict
        """
        return {
            "kind": self.kind,
            "problem_text": self.problem_text,
            "problem_name": self.problem_name,
            "overrides": dict(self.overrides),
            "seed": self.seed,
            "plan": self.plan,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Job:
        """Inverse of :meth:`as_dict`.

        Parameters
        ----------
        data : mapping

        Returns
        -------
        Job
        """
        return cls(
            data["kind"],
            data["problem_text"],
            data.get("problem_name", "<string>"),
            dict(data.get("overrides") or {}),
            data.get("seed"),
            data.get("plan"),
        )


def _canonical(value: Any) -> str:
    return json.dumps(jsonable(value), sort_keys=True, allow_nan=False)


def derived_seed(seed: int, index: int) -> int:
    """Child ``index`` of ``seed`` (``numpy.random.SeedSequence(seed, spawn_key=(index,))``).

    Parameters
    ----------
    seed : int
    index : int

    Returns
    -------
    int
        A 64-bit seed.
    """
    return int(np.random.SeedSequence(seed, spawn_key=(index,)).generate_state(1, np.uint64)[0])


def _seed(job: Job, spec: ProblemSpec) -> tuple[int, str]:
    if job.seed is not None:
        return job.seed, "job"
    if spec.seed is not None:
        return spec.seed, "file"
    logger.warning("%s sets no [solver] seed: using the default seed %d", job.problem_name, DEFAULT_SEED)
    return DEFAULT_SEED, "default"


def new_record(job: Job) -> dict[str, Any]:
    """A record of ``job`` before it runs (``status = "error"`` until a result fills it).

    Parameters
    ----------
    job : Job

    Returns
    -------
    dict
    """
    return {
        "schema": RESULT_SCHEMA,
        "id": job.key,
        "kind": job.kind,
        "status": "error",
        "reason": "",
        "margin": None,
        "formula": None,
        "stats": None,
        "plan": None,
        "problem": {
            "name": job.problem_name,
            "title": Path(job.problem_name).stem,
            "sha256": job.problem_sha256,
            "text": job.problem_text,
            "overrides": jsonable(job.overrides),
        },
        "seed": job.seed,
        "seed_source": "job" if job.seed is not None else None,
        "solver_options": None,
        "plan_source": None,
        "check": None,
        "start_check": None,
        "validation": None,
        "error": None,
        "software": software_section(),
        "timing": {"host": platform.node(), "pid": os.getpid()},
    }


def run_job(job: Job | Mapping[str, Any]) -> dict[str, Any]:
    """Run one job and return its record (plain data; never raises for a failing job).

    Parameters
    ----------
    job : Job or dict
        A :class:`Job` or its :meth:`Job.as_dict`.

    Returns
    -------
    dict
        A record of schema :data:`~idstlpy.batch.records.RESULT_SCHEMA`
        (``docs/results-schema.md``): the result's fields, the job's ``id`` and ``kind``, the
        ``problem`` (name, title, SHA-256, text, overrides), the ``seed`` used and its
        ``seed_source``, the ``solver_options``, the ``check`` of a saved plan, the
        ``start_check`` made before the runs, the ``validation`` report, the ``error`` of a
        failed job, and ``timing`` (everything that varies from run to run: wall time, solver
        times, host).
    """
    if not isinstance(job, Job):
        job = Job.from_dict(job)
    t0 = time.perf_counter()
    record = new_record(job)
    try:
        spec = apply_overrides(load_problem(job.problem_text, name=job.problem_name), job.overrides)
        record["problem"] = problem_section(spec)
        problem, solver_kwargs, execution = spec.build()
        # The executor's gains before solving: guarantee="closed_loop" plans against them.
        _apply_lqr(problem, execution)
        record["formula"] = str(problem.stl_formula)
        seed, source = _seed(job, spec)
        solver_kwargs["seed"] = seed
        record["seed"], record["seed_source"] = seed, source
        record["solver_options"] = jsonable(solver_kwargs)
        if job.plan is not None:
            trajectory = _check_saved_plan(job, problem, record)
        else:
            result = problem.solve_result(**solver_kwargs)
            record.update(result_to_dict(result))
            record["plan_source"] = "solved"
            trajectory = result.trajectory
            stats = record.get("stats") or {}
            record["timing"]["solver"] = {k: v for k, v in stats.items() if k.startswith("time")}
        if job.kind == "validate" and trajectory is not None:
            seed_from_job = job.seed is not None
            options = SolverOptions.make(**solver_kwargs)
            if execution.start_check is not None:
                trajectory, record["start_check"], record["timing"]["start_check"] = _start_check(
                    problem, trajectory, execution, options, seed, seed_from_job
                )
            report = _validate(problem, trajectory, execution, seed, seed_from_job, options)
            record["timing"]["validation"] = report.pop("elapsed", None)
            record["validation"] = report
    except Exception as exc:  # a failing job is a record, not a crash of the whole sweep
        record["status"] = "error"
        record["error"] = {
            "type": type(exc).__name__,
            "message": str(exc),
            "traceback": None if isinstance(exc, IdstlpyError) else traceback.format_exc(),
        }
    record["timing"]["wall_time"] = time.perf_counter() - t0
    return jsonable(record)  # type: ignore[no-any-return]


def _check_saved_plan(job: Job, problem: Any, record: dict[str, Any]) -> Any:
    """Re-roll a saved plan's modes and controls under this problem and monitor the formula.

    Fills the record's result fields and ``check``; returns the re-rolled plan, or None when it
    is rejected (the record's status is then ``"rejected"``).
    """
    from ..belief import rollout
    from ..semantics import robustness

    saved = job.plan or {}
    traj = plan_from_record(saved, "plan")
    rolled = rollout(problem.switched_system, problem.initial_state, traj.get_action(), traj.get_control())
    scale = max(1.0, float(np.max(np.abs(rolled.get_mean()))))
    deviation = max(
        float(np.max(np.abs(rolled.get_mean() - traj.get_mean()))),
        float(np.max(np.abs(rolled.get_cov() - traj.get_cov()))),
    )
    margin = robustness(rolled, problem.stl_formula)
    saved_problem = saved.get("problem") if isinstance(saved.get("problem"), Mapping) else {}
    saved_sha = saved_problem.get("sha256") if isinstance(saved_problem, Mapping) else None
    ok = margin >= 0.0 and deviation <= PLAN_TOLERANCE * scale
    record["check"] = {
        "satisfies": bool(margin >= 0.0),
        "margin": margin,
        "max_deviation": deviation,
        "problem_sha256": saved_sha,
        "same_problem": saved_sha == job.problem_sha256 if saved_sha else None,
    }
    # the saved result's own fields (statistics, objective...) come along; the verdict is ours
    from ..synthesis import SolveResult

    # (its ``software`` too stays ours: this record is made by the running code)
    own = ("schema", "status", "reason", "margin", "formula", "plan", "software")
    for key in result_to_dict(SolveResult("found", None, "")):
        if key not in own and key in saved:
            record[key] = jsonable(saved[key])
    record["formula"] = str(problem.stl_formula)
    record["plan"] = result_to_plan(rolled)
    record["margin"] = margin
    record["plan_source"] = "saved"
    if ok:
        record["status"] = "found"
        record["reason"] = f"saved plan re-rolled and monitored: margin {margin:.4g}"
        return rolled
    record["status"] = "rejected"
    if margin < 0.0:
        record["reason"] = f"the saved plan does not satisfy this problem's formula (margin {margin:.4g})"
    else:
        record["reason"] = (
            f"the saved plan's beliefs differ from their re-roll under this problem by {deviation:.3g}"
        )
    return None


def result_to_plan(traj: Any) -> dict[str, Any]:
    """The ``plan`` field of a record for a trajectory (the core's format).

    Parameters
    ----------
    traj : ProbabilisticTSTrajectory

    Returns
    -------
    dict
    """
    from ..synthesis import SolveResult

    return result_to_dict(SolveResult("found", traj, ""))["plan"]  # type: ignore[no-any-return]


def _apply_lqr(problem: Any, execution: ExecutionSettings) -> None:
    """Give every mode the tracking gains of the file's ``[execution.lqr]`` (if any)."""
    if execution.lqr is None:
        return
    for mode in problem.switched_system.system_modes:
        mode.compute_finite_horizon_lqr(
            horizon=execution.lqr["horizon"],
            Q_final=execution.lqr["Q_final"],
            Q=execution.lqr["Q"],
            R=execution.lqr["R"],
        )


def _start_check(
    problem: Any,
    trajectory: Any,
    execution: ExecutionSettings,
    options: SolverOptions,
    seed: int,
    seed_from_job: bool,
) -> tuple[Any, dict[str, Any], float]:
    """``[validation.start_check]``: the check made once before the runs (``stl.start_check``).

    Returns the plan to execute, the record's ``start_check`` section and the wall-clock seconds.
    The re-solves use the file's ``[solver]`` options with the table's ``solver_options``.
    """
    from ..execution import start_check
    from ..semantics import robustness

    kwargs = dict(execution.start_check or {})
    # the seed rule of [validation] seed: a job's seed decides, else the table's, else a child
    table_seed = kwargs.pop("seed", None)
    sseed = derived_seed(seed, 2) if seed_from_job or table_seed is None else table_seed
    t0 = time.perf_counter()
    checked = start_check(problem, trajectory, seed=sseed, options=options, **kwargs)
    elapsed = time.perf_counter() - t0
    section = {
        "seed": sseed,
        "initial_predicted": checked.initial_predicted,
        "predicted": checked.predicted,
        "replaced": checked.replaced,
        "margin": robustness(checked.plan, problem.stl_formula),
        "resolves": [
            {k: v for k, v in dataclasses.asdict(r).items() if k != "solve_time"} for r in checked.replans
        ],
        "plan": result_to_plan(checked.plan) if checked.replaced else None,
    }
    return checked.plan, section, elapsed


def replan_summary(policy: str, replans: Sequence[int]) -> dict[str, Any]:
    """The ``replan_summary`` of a record's validation: how often the runs re-solved.

    Parameters
    ----------
    policy : {"on_risk", "every"}
        The re-plan policy of the runs.
    replans : sequence of int
        The re-solves of every run (``ValidationReport.replans``).

    Returns
    -------
    dict
        ``policy``, ``runs_replanned`` (runs with at least one re-solve), ``total``, ``mean``
        (per run) and ``max``.
    """
    counts = [int(r) for r in replans]
    return {
        "policy": policy,
        "runs_replanned": sum(r > 0 for r in counts),
        "total": sum(counts),
        "mean": sum(counts) / len(counts) if counts else 0.0,
        "max": max(counts, default=0),
    }


def _validate(
    problem: Any,
    trajectory: Any,
    execution: ExecutionSettings,
    seed: int,
    seed_from_job: bool,
    options: SolverOptions,
) -> dict[str, Any]:
    """Execute the plan ``execution.runs`` times in this process; returns the report as data.

    With ``[validation] replan``, every run re-plans (``validate(policy=...)``); its re-solves
    use ``options`` (the file's ``[solver]``) with the table's ``solver_options``.
    """
    from ..execution import validate

    # (The modes carry the file's tracking gains: run_job gave them before solving.)
    # A job's seed decides everything; otherwise the file's [validation] seed, else a child of
    # the solver's seed (never fresh entropy: the same job gives the same record)
    if seed_from_job or execution.seed is None:
        vseed = derived_seed(seed, 1)
    else:
        vseed = execution.seed
    policy = _replan_policy(execution, options)
    # "serial": the runs of one job stay in its worker (jobs are the unit of parallelism)
    report = validate(
        problem,
        trajectory,
        execution.real_system,
        execution.real_initial_state,
        runs=execution.runs,
        seed=vseed,
        executor="serial",
        predict=execution.predict,
        policy=policy,
        execution_target=execution.execution_target,
    )
    data = report.as_dict()
    data["seed"] = vseed
    if execution.replan is not None:
        data["replan_summary"] = replan_summary(execution.replan, report.replans)
    return data


def _replan_policy(execution: ExecutionSettings, options: SolverOptions) -> Any:
    """The re-planning policy of ``[validation] replan`` (None without one)."""
    from ..execution import ReplanPolicy
    from ..execution.policy import ReplanTrigger

    if execution.replan is None:
        return None
    trigger = cast(ReplanTrigger, execution.replan)  # the file's checks took "on_risk" or "every"
    return ReplanPolicy.from_keywords(trigger, options=options, **execution.replan_options)


def replay_runs(spec: ProblemSpec, record: Mapping[str, Any], count: int) -> tuple[Any, Any, Any]:
    """The first ``count`` runs of a validate record, made again for a figure.

    Run ``i`` of a validation depends on its seed's child ``i`` alone, so the first ``count``
    runs of a validation made with the record's seed, plan (the start check's when it replaced
    the solved one), tracking gains and policy are the runs the record summarises.

    Parameters
    ----------
    spec : ProblemSpec
        The problem (with the job's overrides).
    record : dict
        A ``validate`` record with a plan and a ``validation`` section.
    count : int
        Runs to make again (at most the record's).

    Returns
    -------
    problem : Problem
    plan : ProbabilisticTSTrajectory
        The plan the runs executed.
    report : ValidationReport
        Of the ``count`` runs, their trajectories kept (``report.executions``).

    Raises
    ------
    InvalidArgumentError
        When the record has no plan or no validation.
    """
    from ..execution import validate

    validation = record.get("validation")
    plan = plan_from_record(record, spec.name)
    if plan is None or not isinstance(validation, Mapping) or "seed" not in validation:
        raise InvalidArgumentError(f"{spec.name}: the record has no validated plan to draw the runs of")
    start = record.get("start_check") or {}
    if isinstance(start, Mapping) and start.get("plan"):
        plan = plan_from_record({"plan": start["plan"]}, spec.name)
    problem, solver_kwargs, execution = spec.build()
    _apply_lqr(problem, execution)
    options = SolverOptions.make(**{**solver_kwargs, "seed": record.get("seed")})
    runs = max(1, min(int(count), execution.runs))
    report = validate(
        problem,
        plan,
        execution.real_system,
        execution.real_initial_state,
        runs=runs,
        seed=validation["seed"],
        executor="serial",
        policy=_replan_policy(execution, options),
        keep_trajectories=runs,
    )
    return problem, plan, report


def comparable(record: Mapping[str, Any]) -> dict[str, Any]:
    """``record`` without what varies from run to run (``timing``, ``elapsed``, any ``time*`` field).

    Parameters
    ----------
    record : dict

    Returns
    -------
    dict
    """

    def strip(value: Any) -> Any:
        if isinstance(value, Mapping):
            return {
                k: strip(v)
                for k, v in value.items()
                if k not in ("timing", "elapsed") and not (isinstance(k, str) and k.startswith("time"))
            }
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value

    return strip(record)  # type: ignore[no-any-return]


def failure_record(job: Job, exc: BaseException) -> dict[str, Any]:
    """The record of a job whose worker failed (killed, unpicklable result...).

    Parameters
    ----------
    job : Job
    exc : BaseException
        What the executor raised.

    Returns
    -------
    dict
    """
    record = new_record(job)
    record["error"] = {"type": type(exc).__name__, "message": str(exc), "traceback": None}
    return jsonable(record)  # type: ignore[no-any-return]
