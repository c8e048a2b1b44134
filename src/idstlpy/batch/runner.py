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
from .jobs import RECORD_VERSION, Job, failure_record, run_job

__all__ = ["ProgressCallback", "run_jobs", "result_path", "summarize"]

logger = logging.getLogger("idstlpy.batch")

ProgressCallback = Callable[[int, int, dict[str, Any]], None]


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


def summarize(records: Iterable[Mapping[str, Any]]) -> dict[str, int]:
    """Count records by status."""
    counts: dict[str, int] = {}
    for r in records:
        counts[str(r.get("status"))] = counts.get(str(r.get("status")), 0) + 1
    return counts
