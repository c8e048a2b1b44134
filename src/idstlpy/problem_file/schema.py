"""The keys of a problem file and the checks of plain TOML values (tables, numbers, matrices).

The key lists below are the schema: ``docs/problem-files.md`` documents every one of them (a
test checks it). Each check takes a :class:`~idstlpy.problem_file.locations.Context` and the
field path of the value, and raises an error naming the file, line and field.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..execution import validation as _validation
from ..synthesis.options import CODE_ONLY_OPTIONS, SolverOptions
from .locations import Context, FieldPath, scan_lines

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
    "section_keys",
    "section_of",
    "check_trailing_keys",
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


def section_keys() -> dict[str, tuple[str, ...]]:
    """Every table of a problem file, by the header that opens it, with the keys it accepts.

    ``""`` is the top level (the keys before the first header); ``[propositions.NAME]`` stands
    for every proposition's table.

    Returns
    -------
    dict
        ``header -> keys``, e.g. ``"[validation]" -> ("runs", "seed", ...)``.
    """
    return {
        "": TOP_KEYS,
        "[[modes]]": MODE_KEYS,
        "[control_domain]": CONTROL_DOMAIN_KEYS,
        "[initial_belief]": INITIAL_BELIEF_KEYS,
        "[propositions.NAME]": PROPOSITION_KEYS,
        "[solver]": tuple(
            f.name for f in dataclasses.fields(SolverOptions) if f.name not in CODE_ONLY_OPTIONS
        ),
        "[execution]": EXECUTION_KEYS,
        "[[execution.real_system]]": MODE_KEYS,
        "[execution.lqr]": LQR_KEYS,
        "[validation]": VALIDATION_KEYS,
        "[validation.replan_options]": REPLAN_OPTION_KEYS,
        "[validation.start_check]": START_CHECK_KEYS,
    }


def section_of(path: FieldPath) -> str | None:
    """The header of the table at ``path`` as :func:`section_keys` names it (None: not a table
    that a header opens, e.g. an inline ``V = { scale = ... }``).

    Parameters
    ----------
    path : tuple of str or int
        A table's field path (``("modes", 0)``, ``("validation",)``...).

    Returns
    -------
    str or None
    """
    names = [p for p in path if isinstance(p, str)]
    if not names:
        return ""
    if names[0] == "propositions" and len(names) == 2:
        return "[propositions.NAME]"
    for header in section_keys():
        if header.strip("[]").split(".") == names:
            return header
    return None


def _elsewhere(key: str, here: str | None) -> list[str]:
    """The other tables that accept ``key`` (top level first, then in the file's order)."""
    return [h for h, keys in section_keys().items() if h != here and key in keys]


def _show_section(header: str) -> str:
    return "the top level (before the first [table] header)" if header == "" else header


def check_trailing_keys(ctx: Context) -> None:
    """Reject a key appended at the end of the file that TOML put in the last table by surprise.

    TOML puts every ``key = value`` written after a ``[table]`` header into that table, up to the
    next header. A line such as ``seed = 3`` appended at the end of a file whose last table is
    ``[validation]`` is therefore ``validation.seed``, which is also a valid key, so nothing
    would complain while the user meant ``[solver] seed``. A key is rejected here when all of
    these hold: it is in the file's last table, a blank line separates it from that table's
    keys above it (it was appended, not written with them), and another table accepts it too.
    A key that only another table accepts is rejected by :func:`table` (with the same advice).

    Parameters
    ----------
    ctx : Context
        The file (its text is scanned line by line; a key overridden with ``--set`` is not
        checked).

    Raises
    ------
    ProblemFileError
        ``file:line: field: `seed` is under [validation] here ...; did you mean [solver]?``.
    """
    lines = scan_lines(ctx.source)
    headers = [i for i, ln in enumerate(lines) if ln.kind == "header"]
    if not headers:
        return
    start = headers[-1]
    head = lines[start]
    here = section_of(head.keys)
    seen_key, gap = False, False
    for ln in lines[start + 1 :]:
        if ln.kind == "blank":
            gap = gap or seen_key
            continue
        if ln.kind != "key":
            continue
        if gap and here is not None and ln.keys[0] in section_keys()[here]:
            # the tables under the same top-level name ([validation.start_check] below
            # [validation]) are not what an appended line was meant for
            family = here.strip("[]").split(".")[0]
            others = [h for h in _elsewhere(ln.keys[0], here) if h.strip("[]").split(".")[0] != family]
            path: FieldPath = tuple(head.keys) + ln.keys
            if others and not any(tuple(path[: len(o)]) == o for o in ctx.overridden):
                key = ln.keys[0]
                shown = " or ".join(_show_section(h) for h in others)
                raise ctx.error(
                    path,
                    f"`{key}` is under {here} here: TOML puts every key written after a [table] "
                    f"header into that table (up to the next header), and line {ln.number} comes after "
                    f"{here} (line {head.number}), a blank line below its other keys; did you "
                    f"mean {shown}? Move the line under that header; to keep it in {here}, write "
                    f"it with {here}'s other keys (no blank line between)",
                    line=ln.number,
                )
        seen_key = True


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
            elif (here := section_of(path)) is not None and (others := _elsewhere(key, here)):
                shown = " or ".join(_show_section(h) for h in others)
                hint = (
                    f"; `{key}` is a key of {shown}: TOML puts every key written after a [table] "
                    f"header into that table (up to the next header), so move the line under "
                    f"{'that header' if len(others) == 1 else 'the one you meant'}"
                )
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
