"""The keys of a problem file and the checks of plain TOML values (tables, numbers, matrices).

The key lists below are the schema: ``docs/problem-files.md`` documents every one of them (a
test checks it). Each check takes a :class:`~idstlpy.problem_file.locations.Context` and the
field path of the value, and raises an error naming the file, line and field.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..execution import validation as _validation
from .locations import Context, FieldPath

__all__ = [
    "TOP_KEYS",
    "REQUIRED_TOP",
    "MODE_KEYS",
    "NOISE_TABLE_KEYS",
    "CONTROL_DOMAIN_KEYS",
    "INITIAL_BELIEF_KEYS",
    "PROPOSITION_KEYS",
    "CONSTRAINT_TABLE_KEYS",
    "EXECUTION_KEYS",
    "LQR_KEYS",
    "VALIDATION_KEYS",
    "REPLAN_POLICIES",
    "REPLAN_OPTION_KEYS",
    "START_CHECK_KEYS",
    "NONE",
    "DEFAULT_VALIDATION_RUNS",
    "kind_of",
    "is_number",
    "table",
    "number",
    "integer",
    "string",
    "vector",
    "matrix",
]

TOP_KEYS = (
    "name",
    "description",
    "formula",
    "modes",
    "control_domain",
    "initial_belief",
    "propositions",
    "solver",
    "execution",
    "validation",
)
REQUIRED_TOP = ("formula", "modes", "control_domain", "initial_belief")
MODE_KEYS = ("A", "B", "W", "C", "V")
NOISE_TABLE_KEYS = ("scale", "matrix")
CONTROL_DOMAIN_KEYS = ("low", "high", "A", "b")
INITIAL_BELIEF_KEYS = ("mean", "cov")
PROPOSITION_KEYS = ("constraints", "confidence", "modes")
CONSTRAINT_TABLE_KEYS = ("expr", "region", "confidence")
EXECUTION_KEYS = ("real_system", "real_initial_state", "lqr")
LQR_KEYS = ("horizon", "Q_final", "Q", "R")
VALIDATION_KEYS = ("runs", "seed", "predict", "replan", "replan_options", "start_check", "execution_target")
REPLAN_POLICIES = ("none", "on_risk", "every")
"""``[validation] replan``: ``"none"`` is ``validate(replan=None)`` (TOML has no null)."""
REPLAN_OPTION_KEYS = tuple(sorted(_validation.REPLAN_OPTION_KEYS - {"options"}))
"""``[validation.replan_options]``: the keywords of ``execute`` (its ``options`` is ``[solver]``)."""
START_CHECK_KEYS = (
    "risk",
    "resolves",
    "seed",
    "risk_measure",
    "risk_on",
    "risk_samples",
    "adopt",
    "replan_time_limit",
    "solver_options",
)
"""``[validation.start_check]``: the keywords of ``start_check`` (its ``options`` is ``[solver]``)."""
NONE = "none"
"""How a file writes Python's None where an option takes one (``check_every``, ``drift``)."""
DEFAULT_VALIDATION_RUNS = 100


def kind_of(value: Any) -> str:
    """A TOML type in words (``"a number"``, ``"a table"``...), for messages.

    Parameters
    ----------
    value : object
        A value read from TOML.

    Returns
    -------
    str
    """
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "a table"
    return type(value).__name__


def is_number(value: Any) -> bool:
    """True for an int or float that is not a bool.

    Parameters
    ----------
    value : object

    Returns
    -------
    bool
    """
    return isinstance(value, int | float) and not isinstance(value, bool)


def table(
    ctx: Context, path: FieldPath, value: Any, allowed: Sequence[str], required: Sequence[str] = ()
) -> dict[str, Any]:
    """Check that ``value`` is a table with only ``allowed`` keys and every ``required`` one.

    Parameters
    ----------
    ctx : Context
    path : tuple of str or int
        The field of ``value``.
    value : object
    allowed, required : sequence of str

    Returns
    -------
    dict
        ``value`` itself.
    """
    if not isinstance(value, dict):
        raise ctx.error(path, f"must be a table, got {kind_of(value)}")
    for key in value:
        if key not in allowed:
            hint = ""
            if path and key in TOP_KEYS:
                hint = " (top-level keys such as this one must come before the first [table])"
            raise ctx.error(path + (key,), f"unknown key {key!r}; allowed: {', '.join(allowed)}{hint}")
    for key in required:
        if key not in value:
            hint = ""
            if not path:  # a top-level key written after a [table] header lands in that table
                for sub, inner in value.items():
                    if isinstance(inner, dict) and key in inner:
                        hint = f" (found {sub}.{key}: top-level keys must come before the first [table])"
            raise ctx.error(path, f"missing required key {key!r}{hint}")
    return value


def number(
    ctx: Context, path: FieldPath, value: Any, low: float | None = None, high: float | None = None
) -> float:
    """Check a finite number, optionally within ``[low, high]``.

    Parameters
    ----------
    ctx : Context
    path : tuple of str or int
    value : object
    low, high : float, optional
        Bounds (inclusive).

    Returns
    -------
    float
    """
    if not is_number(value):
        raise ctx.error(path, f"must be a number, got {kind_of(value)}")
    x = float(value)
    if not math.isfinite(x):
        raise ctx.error(path, f"must be finite, got {value}")
    if (low is not None and x < low) or (high is not None and x > high):
        raise ctx.error(path, f"must lie in [{low}, {high}], got {value}")
    return x


def integer(ctx: Context, path: FieldPath, value: Any, minimum: int | None = None) -> int:
    """Check an integer, optionally ``>= minimum``.

    Parameters
    ----------
    ctx : Context
    path : tuple of str or int
    value : object
    minimum : int, optional

    Returns
    -------
    int
    """
    if isinstance(value, bool) or not isinstance(value, int):
        raise ctx.error(path, f"must be an integer, got {kind_of(value)}")
    if minimum is not None and value < minimum:
        raise ctx.error(path, f"must be >= {minimum}, got {value}")
    return value


def string(ctx: Context, path: FieldPath, value: Any) -> str:
    """Check a string.

    Parameters
    ----------
    ctx : Context
    path : tuple of str or int
    value : object

    Returns
    -------
    str
    """
    if not isinstance(value, str):
        raise ctx.error(path, f"must be a string, got {kind_of(value)}")
    return value


def vector(ctx: Context, path: FieldPath, value: Any, size: int | None = None) -> np.ndarray:
    """Check an array of finite numbers, optionally of length ``size``.

    Parameters
    ----------
    ctx : Context
    path : tuple of str or int
    value : object
    size : int, optional

    Returns
    -------
    ndarray, shape (size,)
    """
    if not isinstance(value, list) or not all(is_number(v) for v in value):
        raise ctx.error(path, f"must be an array of numbers, got {kind_of(value)}")
    arr = np.array(value, dtype=float)
    if size is not None and arr.shape[0] != size:
        raise ctx.error(path, f"must have length {size}, got length {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ctx.error(path, "contains non-finite values")
    return arr


def matrix(
    ctx: Context,
    path: FieldPath,
    value: Any,
    rows: int | None = None,
    cols: int | None = None,
    why: str = "",
) -> np.ndarray:
    """Check a matrix (an array of rows of finite numbers), optionally of a given shape.

    Parameters
    ----------
    ctx : Context
    path : tuple of str or int
    value : object
    rows, cols : int, optional
        The expected shape (None: any).
    why : str
        Appended to a shape error, e.g. ``" (2 states, 2 inputs from control_domain)"``.

    Returns
    -------
    ndarray, shape (rows, cols)
    """
    if not isinstance(value, list) or not all(isinstance(r, list) for r in value):
        raise ctx.error(path, f"must be a matrix (an array of rows), got {kind_of(value)}")
    for i, row in enumerate(value):
        if not all(is_number(v) for v in row):
            raise ctx.error(path, f"row {i} must contain only numbers")
    widths = {len(r) for r in value}
    if len(widths) > 1:
        raise ctx.error(path, f"rows have different lengths {sorted(widths)}")
    width = widths.pop() if widths else 0
    arr = np.array(value, dtype=float).reshape(len(value), width)
    want = f"({rows if rows is not None else '*'}, {cols if cols is not None else '*'})"
    if (rows is not None and arr.shape[0] != rows) or (cols is not None and arr.shape[1] != cols):
        raise ctx.error(path, f"must have shape {want}{why}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ctx.error(path, "contains non-finite values")
    return arr
