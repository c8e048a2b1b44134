"""Batch runs of problem files: one machine, a process pool or a Dask cluster.

- :mod:`~idstlpy.batch.records`: the result files' schema (one for every result file);
- :mod:`~idstlpy.batch.jobs`: :class:`Job` (plain data) and :func:`run_job` (job to record);
- :mod:`~idstlpy.batch.executors`: where jobs run (in-process, processes, Dask);
- :mod:`~idstlpy.batch.runner`: :func:`run_jobs`, one JSON record per job, resumable;
- :mod:`~idstlpy.batch.sweeps`: sweep files (a grid or list of overrides over a problem file).

``docs/sweeps.md`` describes the sweep file; ``docs/results-schema.md`` the records.
"""

from __future__ import annotations

from .executors import EXECUTORS, DaskExecutor, InProcessExecutor, make_executor
from .jobs import DEFAULT_SEED, JOB_KINDS, Job, comparable, run_job
from .records import RESULT_SCHEMA, read_record, write_record
from .runner import result_path, run_jobs, summarize
from .sweeps import Sweep, load_sweep

__all__ = [
    "DEFAULT_SEED",
    "RESULT_SCHEMA",
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
    "read_record",
    "write_record",
]
