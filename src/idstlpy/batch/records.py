"""Result files: one versioned JSON schema for every result the package writes.

A *record* is the JSON form of a :class:`~idstlpy.SolveResult` (``schema``, ``status``,
``reason``, ``margin``, ``formula``, ``stats``, ``plan``: what ``SolveResult.to_dict()`` gives)
plus where it came from: the job ``id``, the ``kind`` of run, the ``problem`` (its file name,
title, SHA-256 and text, and the overrides applied), the ``seed`` and where it came from, the
solver options, the Monte Carlo ``validation`` report, the ``check`` of a saved plan, an
``error`` and the ``timing``. ``idstlpy solve``, ``validate``, ``sweep`` and ``demo`` write
records; ``SolveResult.save`` writes the same schema without the context, and
:func:`idstlpy.load_result` reads both. ``docs/results-schema.md`` documents every field.

Records are strict JSON: NaN and infinities are written as ``null``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidArgumentError
from ..problem_file import ProblemSpec, apply_overrides, load_problem, text_sha256
from ..synthesis import SolveResult

__all__ = [
    "RESULT_SCHEMA",
    "RECORD_KINDS",
    "FINISHED_STATUSES",
    "jsonable",
    "result_to_dict",
    "problem_section",
    "software_section",
    "plan_steps",
    "read_record",
    "write_record",
    "plan_from_record",
    "problem_from_record",
]


def _result_schema() -> str:
    try:
        from ..synthesis.results import RESULT_SCHEMA as schema
    except ImportError:  # pragma: no cover - the core's result module moved
        return "idstlpy.result/1"
    return str(schema)


RESULT_SCHEMA = _result_schema()
"""The schema identifier of every result file (``"idstlpy.result/1"``)."""

RECORD_KINDS = ("solve", "validate", "demo")
"""What produced a record: a solve, a validation (solve or saved plan, then Monte Carlo), the demo."""

FINISHED_STATUSES = ("found", "infeasible", "budget_exhausted", "rejected")
"""Statuses of a finished run (``"error"`` is not one: such jobs are run again on resume)."""


def jsonable(value: Any) -> Any:
    """Plain JSON data: arrays to lists, NumPy scalars to Python ones, NaN and infinities to None.

    Parameters
    ----------
    value : object
        Nested dicts, lists, tuples, arrays, numbers and strings (anything else becomes its
        ``as_dict()`` / ``to_dict()`` when it has one, else its ``str``).

    Returns
    -------
    object
        Data that ``json.dumps(..., allow_nan=False)`` accepts.
    """
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, bool | int | str) or value is None:
        return value
    for name in ("to_dict", "as_dict"):
        method = getattr(value, name, None)
        if callable(method):
            return jsonable(method())
    return str(value)


def result_to_dict(result: Any) -> dict[str, Any]:
    """The JSON form of a :class:`~idstlpy.SolveResult` (its ``to_dict()``), NaN-free.

    Parameters
    ----------
    result : SolveResult

    Returns
    -------
    dict
        ``schema``, ``status``, ``reason``, ``margin``, ``formula``, ``stats``, ``plan``.
    """
    to_dict = getattr(result, "to_dict", None)
    if callable(to_dict):
        return jsonable(to_dict())  # type: ignore[no-any-return]
    traj = result.trajectory  # pragma: no cover - results without to_dict (older cores)
    return jsonable(  # type: ignore[no-any-return]  # pragma: no cover
        {
            "schema": RESULT_SCHEMA,
            "status": result.status,
            "reason": result.reason,
            "margin": result.margin,
            "formula": getattr(result, "formula", ""),
            "stats": result.stats.as_dict(),
            "plan": None
            if traj is None
            else {
                "mean": traj.get_mean(),
                "cov": traj.get_cov(),
                "action": traj.get_action(),
                "control": traj.get_control(),
            },
        }
    )


def problem_section(spec: ProblemSpec, include_text: bool = True) -> dict[str, Any]:
    """The ``problem`` field of a record: name, title, SHA-256, text and overrides.

    Parameters
    ----------
    spec : ProblemSpec
        The problem as loaded (``spec.source`` is the text before overrides).
    include_text : bool
        Record the text itself (``idstlpy plot`` rebuilds the problem from it); without it,
        only its SHA-256.

    Returns
    -------
    dict
    """
    return {
        "name": spec.name,
        "title": spec.title,
        "sha256": text_sha256(spec.source),
        "text": spec.source if include_text else None,
        "overrides": jsonable(dict(spec.overrides)),
    }


def software_section() -> dict[str, str | None]:
    """Which code made a record: versions of idstlpy, Python and NumPy, the platform, the commit.

    Returns
    -------
    dict
        ``{"idstlpy", "commit", "python", "numpy", "platform"}``; ``commit`` is the git commit
        of the checkout idstlpy runs from, ``None`` when it is not run from one (see
        :func:`idstlpy._version.git_commit`). The same as a result's ``software`` field.
    """
    from .._version import software_info

    return software_info()


def plan_steps(plan: Mapping[str, Any] | None) -> int | None:
    """The number of steps of a record's ``plan`` (None without a plan).

    Parameters
    ----------
    plan : dict or None
        The ``plan`` field of a record.

    Returns
    -------
    int or None
    """
    if not isinstance(plan, Mapping):
        return None
    if isinstance(plan.get("num_of_steps"), int):
        return int(plan["num_of_steps"])
    for key in ("action", "actions"):
        if isinstance(plan.get(key), list):
            return len(plan[key])
    for key in ("mean", "means"):
        if isinstance(plan.get(key), list):
            return len(plan[key]) - 1
    return None


def write_record(path: str | os.PathLike[str], record: Mapping[str, Any]) -> Path:
    """Write a record atomically (a temporary file, then a rename) as strict JSON.

    Parameters
    ----------
    path : path
        Destination file.
    record : dict

    Returns
    -------
    Path
    """
    out = Path(path)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    text = json.dumps(jsonable(record), indent=1, sort_keys=True, allow_nan=False) + "\n"
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, out)
    return out


def read_record(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a result file of schema :data:`RESULT_SCHEMA`.

    Parameters
    ----------
    path : path

    Returns
    -------
    dict

    Raises
    ------
    InvalidArgumentError
        When the file cannot be read, is not JSON, or is not a result file of this schema.
    """
    name = os.fspath(path)
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InvalidArgumentError(f"{name}: cannot read the result file: {exc}") from None
    if not isinstance(data, dict) or data.get("schema") != RESULT_SCHEMA:
        got = data.get("schema") if isinstance(data, dict) else type(data).__name__
        raise InvalidArgumentError(
            f"{name}: not an idstlpy result file (schema {RESULT_SCHEMA!r}, got {got!r})"
        )
    return data


def plan_from_record(record: Mapping[str, Any], name: str = "<record>") -> Any:
    """The plan of a record as a :class:`~idstlpy.ProbabilisticTSTrajectory` (None without a plan).

    Parameters
    ----------
    record : dict
        A record (or the output of ``SolveResult.to_dict()``).
    name : str
        Used in error messages.

    Returns
    -------
    ProbabilisticTSTrajectory or None
        Read by ``SolveResult.from_dict`` (the core's reader of the ``plan`` field).

    Raises
    ------
    InvalidArgumentError
        For a failed run or a malformed plan.
    """
    if record.get("status") == "error":
        err = record.get("error") or {}
        raise InvalidArgumentError(
            f"{name}: the run failed ({err.get('type')}: {err.get('message')}); it has no result"
        )
    if record.get("plan") is None:
        return None
    # the core reads the plan; the status only has to be one it knows ("rejected" is ours)
    data = {**record, "status": "found"}
    try:
        return SolveResult.from_dict(data).trajectory
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InvalidArgumentError(f"{name}: malformed plan: {exc}") from None


def problem_from_record(record: Mapping[str, Any], name: str = "<record>") -> ProblemSpec:
    """Rebuild the problem a record was run on, from the text and overrides it recorded.

    Parameters
    ----------
    record : dict
    name : str
        Used in error messages.

    Returns
    -------
    ProblemSpec

    Raises
    ------
    InvalidArgumentError
        When the record does not carry the problem's text (give the problem file instead).
    """
    problem = record.get("problem")
    if not isinstance(problem, Mapping) or not isinstance(problem.get("text"), str):
        raise InvalidArgumentError(
            f"{name}: the result file does not record the problem's text; give the problem file"
        )
    text = problem["text"]
    spec = load_problem(text, name=str(problem.get("name") or name))
    overrides = problem.get("overrides") or {}
    return apply_overrides(spec, overrides) if overrides else spec
