"""Batch runs of problem files: one machine, a process pool or a Dask cluster.

A :class:`Job` is plain data: the text of a problem file, overrides, a seed and a kind
(``"solve"`` or ``"validate"``). :func:`run_job` turns it into a plain-data record (JSON-able);
nothing but the job and the record crosses process boundaries, so every backend gives the same
records for the same jobs:

- ``"inprocess"``: :class:`InProcessExecutor` (default for one job);
- ``"processes"``: :class:`concurrent.futures.ProcessPoolExecutor` (default for several jobs);
- ``"dask"``: :class:`DaskExecutor` on a ``distributed`` scheduler address, or on a
  ``LocalCluster`` when no address is given (``pip install idstlpy[dask]``; imported lazily).

All three are :class:`concurrent.futures.Executor` objects, and :func:`run_jobs` accepts any
other executor too. Records are written one JSON file per job, named by the job's hash
(:attr:`Job.key`), so an interrupted sweep resumes where it stopped: jobs whose result file
exists are not run again (except failed ones).

A sweep file (TOML) lists the jobs::

    problem = "light_dark.toml"       # the base problem file, relative to the sweep file
    kind = "solve"                    # or "validate"
    seed = 2024                       # every job's seed is spawned from it
    repeats = 2                       # jobs per parameter combination (default 1)

    [grid]                            # the cartesian product of these values ...
    "solver.goal_bias" = [0.1, 0.25]
    "solver.rrt_timeout" = [1, 5]

    [[cases]]                         # ... for each of these override sets (default: one, empty)
    "initial_belief.mean" = [0.0, 2.5]

The seed of repeat ``r`` of combination ``i`` is drawn from
``numpy.random.SeedSequence(seed, spawn_key=(i, r))``: appending combinations or repeats does not
change the seeds (and so the result files) of the existing jobs.
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import itertools
import json
import logging
import math
import multiprocessing
import os
import platform
import time
import tomllib
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import IdstlpyError, InvalidArgumentError, ProblemFileError
from .problem_file import _Context, _integer, _string, _table, apply_overrides, load_problem

__all__ = [
    "JOB_KINDS",
    "EXECUTORS",
    "Job",
    "Sweep",
    "InProcessExecutor",
    "DaskExecutor",
    "make_executor",
    "run_job",
    "run_jobs",
    "load_sweep",
    "comparable",
    "result_path",
    "summarize",
]

logger = logging.getLogger(__name__)

JOB_KINDS = ("solve", "validate")
EXECUTORS = ("inprocess", "processes", "dask")
RECORD_VERSION = 1

ProgressCallback = Callable[[int, int, dict[str, Any]], None]


# ------------------------------------------------------------------------------------------------
# jobs
# ------------------------------------------------------------------------------------------------


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
    from .execution.validate import validate

    if execution.lqr is not None:
        for mode in problem.switched_system.system_modes:
            mode.compute_finite_horizon_lqr(
                horizon=execution.lqr["horizon"], Q_final=execution.lqr["Q_final"],
                Q=execution.lqr["Q"], R=execution.lqr["R"],
            )
    seed = execution.seed if job.seed is None else _derived_seed(job.seed, 1)
    # "serial": the runs of one job stay in its worker (jobs are the unit of parallelism)
    report = validate(
        problem, trajectory, execution.real_system, execution.real_initial_state,
        runs=execution.runs, seed=seed, executor="serial",
    )
    return report.as_dict() if hasattr(report, "as_dict") else dict(report)


def comparable(record: Mapping[str, Any]) -> dict[str, Any]:
    """``record`` without what varies from run to run (``timing``, ``elapsed``, any ``time*`` field)."""

    def strip(value: Any) -> Any:
        if isinstance(value, Mapping):
            return {
                k: strip(v) for k, v in value.items()
                if k not in ("timing", "elapsed") and not (isinstance(k, str) and k.startswith("time"))
            }
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value

    return strip(record)


# ------------------------------------------------------------------------------------------------
# executors
# ------------------------------------------------------------------------------------------------


class InProcessExecutor(cf.Executor):
    """Runs each submitted call at once, in the calling thread (no pickling, easy debugging)."""

    max_workers = 1

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future:
        future: cf.Future = cf.Future()
        future.set_running_or_notify_cancel()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - delivered through the future
            future.set_exception(exc)
        return future


class DaskExecutor(cf.Executor):
    """A :class:`concurrent.futures.Executor` over a Dask ``distributed`` client.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:8786``); without it a ``LocalCluster`` is
        started (and closed by :meth:`shutdown`).
    workers : int, optional
        Workers of the local cluster (default: the number of CPUs).
    processes : bool
        Local cluster with worker processes (default) or threads in this process.

    Notes
    -----
    Workers of a remote cluster need ``idstlpy`` installed; jobs carry the problem text, so no
    shared filesystem is needed.
    """

    def __init__(
        self, scheduler: str | None = None, workers: int | None = None, processes: bool = True
    ) -> None:
        try:
            from distributed import Client, LocalCluster
        except ImportError as exc:
            raise InvalidArgumentError(
                "the dask executor needs dask and distributed: pip install 'idstlpy[dask]'"
            ) from exc
        self._cluster = None
        if scheduler:
            self._client = Client(scheduler)
        else:
            self._cluster = LocalCluster(
                n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                processes=processes, dashboard_address=None,
            )
            self._client = Client(self._cluster)
        self._pending: set[Any] = set()

    @property
    def max_workers(self) -> int:
        """Threads across the cluster's workers."""
        try:
            return max(1, sum(self._client.nthreads().values()))
        except Exception:  # pragma: no cover - scheduler unreachable
            return 1

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future:
        dask_future = self._client.submit(fn, *args, pure=False, **kwargs)
        future: cf.Future = cf.Future()
        future.set_running_or_notify_cancel()
        self._pending.add(dask_future)

        def transfer(done: Any) -> None:
            self._pending.discard(done)
            try:
                future.set_result(done.result())
            except BaseException as exc:  # noqa: BLE001 - delivered through the future
                future.set_exception(exc)

        dask_future.add_done_callback(transfer)
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        if cancel_futures:
            for f in list(self._pending):
                f.cancel()
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()


def make_executor(
    kind: str = "inprocess", workers: int | None = None, scheduler: str | None = None
) -> cf.Executor:
    """An executor by name: ``"inprocess"``, ``"processes"`` or ``"dask"``.

    Parameters
    ----------
    kind : str
    workers : int, optional
        Worker processes (``processes``) or local-cluster workers (``dask``); default: CPUs.
    scheduler : str, optional
        Dask scheduler address (``dask`` only; default: a local cluster).
    """
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise InvalidArgumentError(f"workers must be a positive int, got {workers!r}")
    if kind == "inprocess":
        return InProcessExecutor()
    if kind == "processes":
        # spawn: workers start clean (no forked threads or locks), the same on every platform
        return cf.ProcessPoolExecutor(
            max_workers=workers or os.cpu_count() or 1,
            mp_context=multiprocessing.get_context("spawn"),
        )
    if kind == "dask":
        return DaskExecutor(scheduler=scheduler, workers=workers)
    raise InvalidArgumentError(f"executor must be one of {EXECUTORS}, got {kind!r}")


# ------------------------------------------------------------------------------------------------
# running
# ------------------------------------------------------------------------------------------------


def result_path(out_dir: str | os.PathLike[str], job: Job) -> Path:
    """Where the record of ``job`` is written: ``out_dir / f"{job.key}.json"``."""
    return Path(out_dir) / f"{job.key}.json"


def _write_atomic(path: Path, record: Mapping[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(record, indent=1, sort_keys=True, allow_nan=False) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _load_existing(path: Path) -> dict[str, Any] | None:
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("version") != RECORD_VERSION:
        return None
    if record.get("status") == "error":
        return None  # failed jobs are run again
    return record


def _executor_width(executor: cf.Executor) -> int:
    for attr in ("max_workers", "_max_workers"):
        value = getattr(executor, attr, None)
        if isinstance(value, int) and value > 0:
            return value
    return os.cpu_count() or 1


def run_jobs(
    jobs: Sequence[Job],
    out_dir: str | os.PathLike[str] | None = None,
    executor: str | cf.Executor | None = None,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = True,
    progress: ProgressCallback | None = None,
) -> list[dict[str, Any]]:
    """Run jobs on an executor, writing one JSON record per job.

    Parameters
    ----------
    jobs : sequence of Job
    out_dir : path, optional
        Directory of the result files (created); None keeps records in memory only.
    executor : {"inprocess", "processes", "dask"} or concurrent.futures.Executor, optional
        Default: ``"inprocess"`` for at most one job to run, ``"processes"`` otherwise. An
        executor passed in is not shut down.
    workers, scheduler
        See :func:`make_executor`.
    resume : bool
        Skip jobs whose result file exists (failed jobs are always run again).
    progress : callable, optional
        ``progress(done, total, record)`` after each job (cached ones included).

    Returns
    -------
    list of dict
        The records, in the order of ``jobs``. ``record["timing"]["cached"]`` says whether it
        was read from an existing file, ``record["timing"]["backend"]`` which executor ran it.
    """
    jobs = list(jobs)
    for i, job in enumerate(jobs):
        if not isinstance(job, Job):
            raise InvalidArgumentError(f"jobs[{i}] must be a Job, got {type(job).__name__}")
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    unique: dict[str, Job] = {}
    for job in jobs:
        unique.setdefault(job.key, job)
    records: dict[str, dict[str, Any]] = {}
    total = len(unique)
    done = 0
    if out is not None and resume:
        for key, job in unique.items():
            existing = _load_existing(result_path(out, job))
            if existing is not None:
                existing.setdefault("timing", {})["cached"] = True
                records[key] = existing
                done += 1
                if progress is not None:
                    progress(done, total, existing)
    todo = [job for key, job in unique.items() if key not in records]
    if todo:
        logger.info("running %d job(s), %d already done", len(todo), len(records))
        owned = not isinstance(executor, cf.Executor)
        if executor is None:
            executor = "inprocess" if len(todo) <= 1 else "processes"
        backend = executor if isinstance(executor, str) else type(executor).__name__
        ex = make_executor(executor, workers, scheduler) if isinstance(executor, str) else executor
        try:
            window = 2 * _executor_width(ex) if not isinstance(ex, InProcessExecutor) else 1
            queue = iter(todo)
            pending: dict[cf.Future, Job] = {}

            def fill() -> None:
                while len(pending) < window:
                    job = next(queue, None)
                    if job is None:
                        return
                    pending[ex.submit(run_job, job.as_dict())] = job

            fill()
            while pending:
                finished, _ = cf.wait(list(pending), return_when=cf.FIRST_COMPLETED)
                for fut in finished:
                    job = pending.pop(fut)
                    try:
                        record = fut.result()
                    except Exception as exc:  # the worker itself failed (killed, unpicklable...)
                        record = _failure_record(job, exc)
                    record.setdefault("timing", {}).update(backend=backend, cached=False)
                    if out is not None:  # failed jobs too (for inspection); resume reruns them
                        _write_atomic(result_path(out, job), record)
                    records[job.key] = record
                    done += 1
                    if progress is not None:
                        progress(done, total, record)
                fill()
        finally:
            if owned:
                ex.shutdown(wait=True, cancel_futures=True)
    return [records[job.key] for job in jobs]


def _failure_record(job: Job, exc: BaseException) -> dict[str, Any]:
    return {
        "version": RECORD_VERSION,
        "id": job.key,
        "job": {
            "kind": job.kind, "problem": job.problem_name,
            "overrides": _jsonable(job.overrides), "seed": job.seed,
        },
        "status": "error",
        "result": None,
        "validation": None,
        "error": {"type": type(exc).__name__, "message": str(exc), "traceback": None},
        "timing": {},
    }


# ------------------------------------------------------------------------------------------------
# sweeps
# ------------------------------------------------------------------------------------------------

_SWEEP_KEYS = ("name", "description", "problem", "kind", "seed", "repeats", "grid", "cases")


@dataclass(frozen=True)
class Sweep:
    """A parameter sweep over one problem file (see the module docstring for the file format).

    Attributes
    ----------
    problem_name : str
        Path of the base problem file.
    problem_text : str
        Its text.
    kind : {"solve", "validate"}
    seed : int
        Root of every job's seed.
    combinations : list of dict
        One override set per parameter combination.
    repeats : int
        Jobs per combination (each with its own seed).
    name : str
    """

    problem_name: str
    problem_text: str
    kind: str = "solve"
    seed: int = 0
    combinations: list[dict[str, Any]] = field(default_factory=lambda: [{}])
    repeats: int = 1
    name: str = "sweep"

    def jobs(self, seed: int | None = None) -> list[Job]:
        """The jobs, combination-major; ``seed`` replaces the sweep's root seed."""
        root = self.seed if seed is None else seed
        out = []
        for i, overrides in enumerate(self.combinations):
            for r in range(self.repeats):
                ss = np.random.SeedSequence(root, spawn_key=(i, r))
                job_seed = int(ss.generate_state(1, np.uint64)[0])
                out.append(Job(self.kind, self.problem_text, self.problem_name, dict(overrides), job_seed))
        return out


def _flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in table.items():
        path = f"{prefix}.{key}" if prefix else key
        if isinstance(value, dict) and "." not in key and "[" not in key:
            out.update(_flatten(value, path))
        else:
            out[path] = value
    return out


def load_sweep(path: str | os.PathLike[str]) -> Sweep:
    """Read and check a sweep file (every combination is applied to the problem once).

    Parameters
    ----------
    path : path
        The sweep TOML file; its ``problem`` path is relative to the file's directory.

    Returns
    -------
    Sweep

    Raises
    ------
    ProblemFileError
        Naming the sweep file (or the problem file) and the line of the bad entry.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ProblemFileError(f"{path}: cannot read the sweep file: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ProblemFileError(f"{path}: invalid TOML: {exc}") from None
    ctx = _Context(str(path), text)
    _table(ctx, (), data, _SWEEP_KEYS, ("problem",))
    problem_rel = _string(ctx, ("problem",), data["problem"])
    problem_path = (path.parent / problem_rel) if not Path(problem_rel).is_absolute() else Path(problem_rel)
    if not problem_path.is_file():
        raise ctx.error(("problem",), f"problem file {str(problem_path)!r} does not exist")
    kind = _string(ctx, ("kind",), data.get("kind", "solve"))
    if kind not in JOB_KINDS:
        raise ctx.error(("kind",), f"must be one of {', '.join(JOB_KINDS)}, got {kind!r}")
    seed = _integer(ctx, ("seed",), data.get("seed", 0), 0)
    repeats = _integer(ctx, ("repeats",), data.get("repeats", 1), 1)
    name = _string(ctx, ("name",), data.get("name", path.stem))
    if "description" in data:
        _string(ctx, ("description",), data["description"])
    grid = data.get("grid", {})
    if not isinstance(grid, dict):
        raise ctx.error(("grid",), "must be a table of parameter paths to arrays of values")
    grid = _flatten(grid)
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise ctx.error(("grid", key), "must be a non-empty array of values")
    cases = data.get("cases", [{}])
    if not isinstance(cases, list) or not all(isinstance(c, dict) for c in cases) or not cases:
        raise ctx.error(("cases",), "must be a non-empty array of tables ([[cases]])")
    cases = [_flatten(c) for c in cases]
    keys = list(grid)
    combinations = [
        {**case, **dict(zip(keys, values, strict=True))}
        for case in cases
        for values in itertools.product(*(grid[k] for k in keys))
    ]
    base = load_problem(problem_path)
    for i, combo in enumerate(combinations):
        try:
            apply_overrides(base, combo)
        except ProblemFileError as exc:
            where = ("cases", i // max(1, len(combinations) // len(cases))) if "cases" in data else ("grid",)
            raise ctx.error(where, f"combination {combo}: {exc}") from None
    return Sweep(str(problem_path), base.source, kind, seed, combinations, repeats, name)


def summarize(records: Iterable[Mapping[str, Any]]) -> dict[str, int]:
    """Count records by status."""
    counts: dict[str, int] = {}
    for r in records:
        counts[str(r.get("status"))] = counts.get(str(r.get("status")), 0) + 1
    return counts
