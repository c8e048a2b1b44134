"""Jobs: one unit of work as plain data, and :func:`run_job`, which turns it into a record.

A :class:`Job` is the text of a problem file, overrides, a seed and a kind (``"solve"`` or
``"validate"``); its record is plain JSON data. Nothing but the job and the record crosses
process boundaries, so every executor gives the same records for the same jobs.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import time
import traceback
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import IdstlpyError, InvalidArgumentError, ProblemFileError
from ..problem_file import apply_overrides, load_problem

__all__ = ["JOB_KINDS", "RECORD_VERSION", "Job", "run_job", "comparable", "failure_record"]

JOB_KINDS = ("solve", "validate")
RECORD_VERSION = 1


@dataclass(frozen=True)
class Job:
    """One unit of work, as plain data.

    Attributes
    ----------
    kind : {"solve", "validate"}
        ``solve``: load, build, ``solve_result``. ``validate``: the same, then execute the plan
        on the real system (:func:`idstlpy.execution.validate.validate`).
    problem_text : str
        The problem file's text (shipped as is to workers: they need no shared filesystem).
    problem_name : str
        Name used in messages and records (not part of :attr:`key`).
    overrides : dict
        Dotted paths to values (see :func:`~idstlpy.problem_file.apply_overrides`).
    seed : int or None
        Seed of the solver (and, through a spawned child, of the validation runs); None uses
        the seeds written in the file.
    """

    kind: str
    problem_text: str
    problem_name: str = "<string>"
    overrides: dict[str, Any] = field(default_factory=dict)
    seed: int | None = None

    def __post_init__(self) -> None:
        if self.kind not in JOB_KINDS:
            raise InvalidArgumentError(f"job kind must be one of {JOB_KINDS}, got {self.kind!r}")
        seed = self.seed
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
            raise InvalidArgumentError(f"job seed must be a non-negative int or None, got {self.seed!r}")

    @classmethod
    def from_file(
        cls,
        path: str | os.PathLike[str],
        kind: str = "solve",
        overrides: Mapping[str, Any] | None = None,
        seed: int | None = None,
    ) -> Job:
        """A job for the problem file at ``path`` (its text is read now)."""
        try:
            text = Path(path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ProblemFileError(f"{path}: cannot read the problem file: {exc}") from None
        return cls(kind, text, str(path), dict(overrides or {}), seed)

    @property
    def key(self) -> str:
        """Hash of everything that determines the result (16 hex digits)."""
        payload = json.dumps(
            {
                "version": RECORD_VERSION,
                "kind": self.kind,
                "problem": self.problem_text,
                "overrides": _jsonable(self.overrides),
                "seed": self.seed,
            },
            sort_keys=True,
        )
        return hashlib.sha256(payload.encode()).hexdigest()[:16]

    def as_dict(self) -> dict[str, Any]:
        """Plain-data form (what executors ship to workers)."""
        return {
            "kind": self.kind,
            "problem_text": self.problem_text,
            "problem_name": self.problem_name,
            "overrides": dict(self.overrides),
            "seed": self.seed,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Job:
        """Inverse of :meth:`as_dict`."""
        return cls(
            data["kind"],
            data["problem_text"],
            data.get("problem_name", "<string>"),
            dict(data.get("overrides") or {}),
            data.get("seed"),
        )


def _jsonable(value: Any) -> Any:
    """Plain JSON data: arrays to lists, non-finite floats to None."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, bool | int | str) or value is None:
        return value
    if hasattr(value, "as_dict"):
        return _jsonable(value.as_dict())
    return str(value)


def _derived_seed(seed: int, index: int) -> int:
    return int(np.random.SeedSequence(seed, spawn_key=(index,)).generate_state(1, np.uint64)[0])


def run_job(job: Job | Mapping[str, Any]) -> dict[str, Any]:
    """Run one job and return its record (plain data; never raises for a failing job).

    Parameters
    ----------
    job : Job or dict
        A :class:`Job` or its :meth:`Job.as_dict`.

    Returns
    -------
    dict
        ``version``, ``id`` (the job key), ``job`` (kind, problem name, overrides, seed),
        ``status`` (the solver status, or ``"error"``), ``result`` (reason, margin, statistics
        without times, the plan), ``validation`` (the validation report, for validate jobs),
        ``error`` (type, message, traceback) and ``timing`` (everything that varies from run
        to run: wall time, solver times, host).
    """
    if not isinstance(job, Job):
        job = Job.from_dict(job)
    t0 = time.perf_counter()
    record: dict[str, Any] = {
        "version": RECORD_VERSION,
        "id": job.key,
        "job": {
            "kind": job.kind,
            "problem": job.problem_name,
            "overrides": _jsonable(job.overrides),
            "seed": job.seed,
        },
        "status": "error",
        "result": None,
        "validation": None,
        "error": None,
        "timing": {"host": platform.node(), "pid": os.getpid()},
    }
    try:
        spec = apply_overrides(load_problem(job.problem_text, name=job.problem_name), job.overrides)
        problem, solver_kwargs, execution = spec.build()
        if job.seed is not None:
            solver_kwargs["seed"] = job.seed
        result = problem.solve_result(**solver_kwargs)
        stats = result.stats.as_dict()
        record["status"] = result.status
        record["result"] = {
            "status": result.status,
            "reason": result.reason,
            "margin": result.margin,
            "stats": {k: v for k, v in stats.items() if not k.startswith("time")},
            "solver_kwargs": solver_kwargs,
            "plan": _plan(result.trajectory),
        }
        record["timing"]["solver"] = {k: v for k, v in stats.items() if k.startswith("time")}
        if job.kind == "validate" and result.trajectory is not None:
            report = _validate(job, problem, result.trajectory, execution)
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
    return _jsonable(record)


def _plan(traj: Any) -> dict[str, Any] | None:
    if traj is None:
        return None
    return {
        "num_of_steps": int(traj.num_of_steps),
        "actions": traj.get_action().tolist(),
        "controls": traj.get_control().tolist(),
        "means": traj.get_mean().tolist(),
        "covs": traj.get_cov().tolist(),
    }


def _validate(job: Job, problem: Any, trajectory: Any, execution: Any) -> dict[str, Any]:
    """Execute the plan ``execution.runs`` times in this process; returns the report as data."""
    from ..execution.validate import validate

    if execution.lqr is not None:
        for mode in problem.switched_system.system_modes:
            mode.compute_finite_horizon_lqr(
                horizon=execution.lqr["horizon"],
                Q_final=execution.lqr["Q_final"],
                Q=execution.lqr["Q"],
                R=execution.lqr["R"],
            )
    seed = execution.seed if job.seed is None else _derived_seed(job.seed, 1)
    # "serial": the runs of one job stay in its worker (jobs are the unit of parallelism)
    report = validate(
        problem,
        trajectory,
        execution.real_system,
        execution.real_initial_state,
        runs=execution.runs,
        seed=seed,
        executor="serial",
    )
    return report.as_dict() if hasattr(report, "as_dict") else dict(report)


def comparable(record: Mapping[str, Any]) -> dict[str, Any]:
    """``record`` without what varies from run to run (``timing``, ``elapsed``, any ``time*`` field)."""

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

    return strip(record)


def failure_record(job: Job, exc: BaseException) -> dict[str, Any]:
    """The record of a job whose worker failed (killed, unpicklable result...)."""
    return {
        "version": RECORD_VERSION,
        "id": job.key,
        "job": {
            "kind": job.kind,
            "problem": job.problem_name,
            "overrides": _jsonable(job.overrides),
            "seed": job.seed,
        },
        "status": "error",
        "result": None,
        "validation": None,
        "error": {"type": type(exc).__name__, "message": str(exc), "traceback": None},
        "timing": {},
    }
