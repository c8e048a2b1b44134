"""Running jobs on an executor, one JSON record file per job, resumable."""

from __future__ import annotations

import concurrent.futures as cf
import json
import logging
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ..errors import InvalidArgumentError
from .executors import InProcessExecutor, executor_width, make_executor
from .jobs import Job, failure_record, run_job
from .records import FINISHED_STATUSES, RESULT_SCHEMA, write_record

__all__ = ["ProgressCallback", "run_jobs", "result_path", "finished_record", "summarize"]

logger = logging.getLogger("idstlpy.batch")

ProgressCallback = Callable[[int, int, dict[str, Any]], None]


def result_path(out_dir: str | os.PathLike[str], job: Job) -> Path:
    """Where the record of ``job`` is written: ``out_dir / f"{job.key}.json"``.

    Parameters
    ----------
    out_dir : path
    job : Job

    Returns
    -------
    Path
    """
    return Path(out_dir) / f"{job.key}.json"


def finished_record(path: Path, job: Job) -> dict[str, Any] | None:
    """The record at ``path`` if it is a finished run of exactly ``job``, else None.

    A file counts only when it is a record of the current schema, its ``id`` is the job's key,
    its problem's SHA-256 is the job's, and its status is a finished one (a failed job, a stub
    or a file from another job or an older schema is run again).

    Parameters
    ----------
    path : Path
    job : Job

    Returns
    -------
    dict or None
    """
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    why = None
    if not isinstance(record, dict) or record.get("schema") != RESULT_SCHEMA:
        why = "not a result of the current schema"
    elif record.get("id") != job.key:
        why = f"its id {record.get('id')!r} is not the job's {job.key!r}"
    elif (record.get("problem") or {}).get("sha256") != job.problem_sha256:
        why = "it was run on another problem text"
    elif record.get("status") not in FINISHED_STATUSES:
        why = f"its status is {record.get('status')!r}"
    elif record.get("status") == "found" and not isinstance(record.get("plan"), dict):
        why = "it has no plan"
    elif job.kind == "validate" and record.get("status") == "found" and record.get("validation") is None:
        why = "it has no validation"
    if why is not None:
        logger.info("%s: running the job again (%s)", path, why)
        return None
    return record


def run_jobs(
    jobs: Sequence[Job],
    out_dir: str | os.PathLike[str] | None = None,
    executor: str | cf.Executor | None = None,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    resume: bool = True,
    progress: ProgressCallback | None = None,
    on_executor: Callable[[cf.Executor], None] | None = None,
) -> list[dict[str, Any]]:
    """Run jobs on an executor, writing one JSON record per job.

    Parameters
    ----------
    jobs : sequence of Job
    out_dir : path, optional
        Directory of the result files (created); None keeps records in memory only.
    executor : {"inprocess", "processes", "dask"} or concurrent.futures.Executor, optional
        Default: ``"dask"`` when a ``scheduler`` is given, else ``"inprocess"`` for at most one
        job to run and ``"processes"`` otherwise. An executor passed in is not shut down.
    workers : int, optional
        See :func:`~idstlpy.batch.executors.make_executor`.
    scheduler : str, optional
        A Dask scheduler address; it implies the ``"dask"`` executor.
    resume : bool
        Skip jobs whose result file holds a finished record of the same job (same id, same
        problem text; see :func:`finished_record`); failed jobs are always run again.
    progress : callable, optional
        ``progress(done, total, record)`` after each job (cached ones included).
    on_executor : callable, optional
        ``on_executor(executor)`` once the executor exists, before the first job is submitted
        (e.g. to print the Dask dashboard's address).

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
            existing = finished_record(result_path(out, job), job)
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
            executor = "dask" if scheduler else "inprocess" if len(todo) <= 1 else "processes"
        backend = executor if isinstance(executor, str) else type(executor).__name__
        ex = make_executor(executor, workers, scheduler) if isinstance(executor, str) else executor
        try:
            if on_executor is not None:
                on_executor(ex)
            window = 2 * executor_width(ex) if not isinstance(ex, InProcessExecutor) else 1
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
                        record = failure_record(job, exc)
                    record.setdefault("timing", {}).update(backend=backend, cached=False)
                    if out is not None:  # failed jobs too (for inspection); resume reruns them
                        write_record(result_path(out, job), record)
                    records[job.key] = record
                    done += 1
                    if progress is not None:
                        progress(done, total, record)
                fill()
        finally:
            if owned:
                ex.shutdown(wait=True, cancel_futures=True)
    return [records[job.key] for job in jobs]


def summarize(records: Iterable[Mapping[str, Any]]) -> dict[str, int]:
    """Count records by status.

    Parameters
    ----------
    records : iterable of dict

    Returns
    -------
    dict
        ``status -> count``.
    """
    counts: dict[str, int] = {}
    for r in records:
        counts[str(r.get("status"))] = counts.get(str(r.get("status")), 0) + 1
    return counts
