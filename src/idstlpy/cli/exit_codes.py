"""The exit status of every ``idstlpy`` subcommand (the table is in :mod:`idstlpy.cli`)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

__all__ = [
    "EXIT_OK",
    "EXIT_NO_PLAN",
    "EXIT_USAGE",
    "EXIT_FAILED",
    "EXIT_BELOW_TARGET",
    "EXIT_UNCERTIFIED",
    "EXIT_INTERRUPTED",
    "exit_status",
]

EXIT_OK = 0
"""Every plan found (or accepted), every file written."""
EXIT_NO_PLAN = 1
"""The run finished, but some job has no plan (infeasible, budget_exhausted, rejected)."""
EXIT_USAGE = 2
"""Usage or input error: nothing was run."""
EXIT_FAILED = 3
"""Some job failed with an error (its record has ``status = "error"``)."""
EXIT_BELOW_TARGET = 4
"""Every plan found and executed, but some validation's measured success rates fall short of its
execution target (``record["validation"]["meets_target"]`` is false)."""
EXIT_UNCERTIFIED = 5
"""``idstlpy check``: some ``infeasible`` result's certificate fails, is missing or is not
certified."""
EXIT_INTERRUPTED = 130
"""Interrupted (Ctrl-C)."""


def exit_status(records: Iterable[Mapping[str, Any]]) -> int:
    """The exit status for a run's records: 3 if one failed, 1 if one has no plan, 4 if one's
    validation fell short of its execution target, else 0.

    Parameters
    ----------
    records : iterable of dict
        Records of :mod:`idstlpy.batch.records`.

    Returns
    -------
    int
    """
    records = list(records)
    statuses = [r.get("status") for r in records]
    if any(s == "error" for s in statuses):
        return EXIT_FAILED
    if any(s != "found" for s in statuses):
        return EXIT_NO_PLAN
    for r in records:
        validation = r.get("validation")
        if isinstance(validation, Mapping) and validation.get("meets_target") is False:
            return EXIT_BELOW_TARGET
    return EXIT_OK
