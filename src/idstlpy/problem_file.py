"""TOML problem files: a whole synthesis problem as plain data, with no code in it.

A problem file describes the modes of a switched belief system, the control domain, the
initial belief, named atomic propositions, the formula (in the text syntax of
:mod:`idstlpy.syntax`), solver parameters, and the real system a plan is executed on. It is
read with :mod:`tomllib`; nothing in it is executed: matrices are numbers, and the only
expressions (state-dependent noise, linear constraints) are parsed with :mod:`ast` and checked
against a small whitelist before being interpreted by this module.

Layout (``examples/light_dark.toml`` is the paper's listing)::

    name = "light-dark"                           # optional
    description = "..."                           # optional
    formula = "(free_space U[0,240] G[0,40] target)"   # top-level keys come before any [table]

    [[modes]]                                     # one table per mode q = 0, 1, ...
    A = [[1.0, 0.0], [0.0, 1.0]]
    B = [[0.25, 0.0], [0.0, 0.25]]
    W = [[0.0, 0.0], [0.0, 0.0]]                  # optional (default zero): process noise
    C = [[1.0, 0.0], [0.0, 1.0]]                  # optional: no C means no sensing
    V = "0.1*(5 - x[0])**2 + 0.001"               # optional: observation noise n(x), see below

    [control_domain]                              # a box ...
    low = [-1.0, -1.0]
    high = [1.0, 1.0]
    # ... or A = [[...]] and b = [...] for {u : A u <= b}

    [initial_belief]
    mean = [0.0, 2.5]
    cov = [[0.1, 0.0], [0.0, 0.1]]                # or a vector: the diagonal

    [propositions.free_space]
    modes = [0]                                   # optional (default: every mode)
    confidence = 0.99                             # 1 - eps, for the constraints below
    constraints = ["x[0] >= -1", "x[0] <= 5", "-1 <= x[1] <= 4",
                   { expr = "x[0] + x[1] <= 6", confidence = 0.95 }]

    [solver]                                      # keyword arguments of Problem.solve
    rrt_timeout = 60

    [execution]                                   # the plan's execution (validate)
    real_initial_state = [0.5, 2.75]
    [[execution.real_system]]                     # modes as above; A and B only = an LCS
    A = [[1.0, 0.0], [0.0, 1.0]]
    B = [[0.25, 0.0], [0.0, 0.25]]
    [execution.lqr]                               # tracking controller of every mode
    horizon = 5
    Q_final = [[1.0, 0.0], [0.0, 1.0]]
    Q = [[1.0, 0.0], [0.0, 1.0]]
    R = [[0.05, 0.0], [0.0, 0.05]]

    [validation]
    runs = 100
    seed = 0

The observation noise ``V`` of a mode is one of

- a matrix of numbers (``n(x) = V``, constant);
- an expression string ``s(x)``: ``n(x) = s(x) * I`` (``p x p`` identity);
- a table ``{ scale = <expression string or number>, matrix = [[...]] }``:
  ``n(x) = scale(x) * matrix`` (``matrix`` defaults to the identity).

Expressions use numbers, ``x[i]`` (``0 <= i < n``), ``+ - * / **``, unary minus, parentheses
and the functions ``sqrt``, ``exp``, ``abs``, ``min``, ``max``; anything else is a
:class:`~idstlpy.errors.ProblemFileError` naming the file, line and field. Constraints are
linear comparisons ``lhs <= rhs`` / ``lhs >= rhs`` (chains ``a <= x[0] <= b`` give two).

Every error is a :class:`~idstlpy.errors.ProblemFileError` whose message starts with
``file:line: field:`` (the line is found in the text on a best-effort basis).
"""

from __future__ import annotations

import ast
import copy
import dataclasses
import logging
import math
import os
import re
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .belief import to_belief
from .dynamical_system import LCS, SwitchedSystem, mk_lbs, mk_lcs, mk_switched_sys
from .errors import IdstlpyError, ProblemFileError
from .expressions import ProbabilisticLinearPredicate, RealValuedVariable, mk_variable
from .formulas import STLAtomicProposition
from .sets import Polytope
from .syntax import RESERVED_NAMES, FormulaSyntaxError, parse_formula
from .synthesis.problem import Problem

__all__ = [
    "ProblemSpec",
    "BuiltProblem",
    "ExecutionSettings",
    "NoiseExpression",
    "load_problem",
    "apply_overrides",
    "parse_override_path",
    "parse_noise_expression",
    "parse_linear_constraint",
]

logger = logging.getLogger(__name__)

_TOP_KEYS = (
    "name", "description", "formula", "modes", "control_domain", "initial_belief",
    "propositions", "solver", "execution", "validation",
)
_REQUIRED_TOP = ("formula", "modes", "control_domain", "initial_belief")
_MODE_KEYS = ("A", "B", "W", "C", "V")
_MAX_EXPRESSION_LENGTH = 2000

Path_ = tuple[str | int, ...]


# ------------------------------------------------------------------------------------------------
# error reporting
# ------------------------------------------------------------------------------------------------


def _field_name(path: Path_) -> str:
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + part
    return out or "<file>"


_HEADER_RE = re.compile(r"^\s*(\[\[?)\s*([^\[\]#]+?)\s*\]\]?\s*(?:#.*)?$")
_KEY_RE = re.compile(r"^\s*([A-Za-z0-9_\-\".' ]+?)\s*=")


def _split_dotted(key: str) -> tuple[str, ...]:
    parts = re.findall(r'"([^"]*)"|\'([^\']*)\'|([^.\s]+)', key)
    return tuple(a or b or c for a, b, c in parts)


def _find_line(text: str, path: Path_) -> int | None:
    """Best-effort 1-based line of ``path`` in the TOML ``text`` (None when not found)."""
    lines = text.splitlines()
    sections: list[tuple[tuple[str | int, ...], int, int]] = [((), 0, len(lines))]
    counts: dict[tuple[str, ...], int] = {}
    for i, line in enumerate(lines):
        m = _HEADER_RE.match(line)
        if m is None:
            continue
        keys = _split_dotted(m.group(2))
        concrete: list[str | int] = []
        # re-insert the indices of enclosing arrays of tables
        for j, key in enumerate(keys):
            concrete.append(key)
            prefix = keys[: j + 1]
            if prefix in counts and (j < len(keys) - 1 or m.group(1) != "[["):
                concrete.append(counts[prefix] - 1)
        if m.group(1) == "[[":
            counts[keys] = counts.get(keys, 0) + 1
            concrete.append(counts[keys] - 1)
        start, end = sections[-1][1], i
        sections[-1] = (sections[-1][0], start, end)
        sections.append((tuple(concrete), i, len(lines)))
    best: tuple[tuple[str | int, ...], int, int] | None = None
    for sec in sections:
        head = sec[0]
        if len(head) <= len(path) and tuple(path[: len(head)]) == head:
            if best is None or len(head) > len(best[0]):
                best = sec
    if best is None:
        return None
    head, start, end = best
    rest = [p for p in path[len(head) :]]
    if not rest:
        return start + 1 if head else None
    # look for `key =` (or a dotted `key.sub =`) inside the section
    keys = [p for p in rest if isinstance(p, str)]
    body_start = start + 1 if head else start
    for depth in range(len(keys), 0, -1):
        want = tuple(keys[:depth])
        for i in range(body_start, end):
            m = _KEY_RE.match(lines[i])
            if m is None or _HEADER_RE.match(lines[i]):
                continue
            got = _split_dotted(m.group(1))
            if got == want or (depth == 1 and got[:1] == want):
                return i + 1
    return start + 1 if head else None


class _Context:
    """Where a problem came from, for error messages."""

    def __init__(self, name: str, source: str, overridden: Sequence[str] = ()) -> None:
        self.name = name
        self.source = source
        self.overridden = [tuple(parse_override_path(k)) for k in overridden]

    def error(self, path: Path_, message: str) -> ProblemFileError:
        fieldname = _field_name(path)
        overridden = any(tuple(path[: len(o)]) == o for o in self.overridden)
        line = None if overridden else _find_line(self.source, path)
        if overridden:
            where = f"{self.name}: {fieldname} (override)"
        elif line is not None:
            where = f"{self.name}:{line}: {fieldname}"
        else:
            where = f"{self.name}: {fieldname}"
        err = ProblemFileError(f"{where}: {message}")
        err.file = self.name  # type: ignore[attr-defined]
        err.line = line  # type: ignore[attr-defined]
        err.field = fieldname  # type: ignore[attr-defined]
        return err


# ------------------------------------------------------------------------------------------------
# plain-data checks
# ------------------------------------------------------------------------------------------------


def _table(
    ctx: _Context, path: Path_, value: Any, allowed: Sequence[str], required: Sequence[str] = ()
) -> dict:
    if not isinstance(value, dict):
        raise ctx.error(path, f"must be a table, got {_kind(value)}")
    for key in value:
        if key not in allowed:
            hint = ""
            if path and key in _TOP_KEYS:
                hint = " (top-level keys such as this one must come before the first [table])"
            raise ctx.error(
                path + (key,), f"unknown key {key!r}; allowed: {', '.join(allowed)}{hint}"
            )
    for key in required:
        if key not in value:
            hint = ""
            if not path:  # a top-level key written after a [table] header lands in that table
                for sub, table in value.items():
                    if isinstance(table, dict) and key in table:
                        hint = (
                            f" (found {sub}.{key}: top-level keys must come before the first "
                            "[table])"
                        )
            raise ctx.error(path, f"missing required key {key!r}{hint}")
    return value


def _kind(value: Any) -> str:
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


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _number(
    ctx: _Context, path: Path_, value: Any, low: float | None = None, high: float | None = None
) -> float:
    if not _is_number(value):
        raise ctx.error(path, f"must be a number, got {_kind(value)}")
    x = float(value)
    if not math.isfinite(x):
        raise ctx.error(path, f"must be finite, got {value}")
    if (low is not None and x < low) or (high is not None and x > high):
        raise ctx.error(path, f"must lie in [{low}, {high}], got {value}")
    return x


def _integer(ctx: _Context, path: Path_, value: Any, minimum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ctx.error(path, f"must be an integer, got {_kind(value)}")
    if minimum is not None and value < minimum:
        raise ctx.error(path, f"must be >= {minimum}, got {value}")
    return value


def _string(ctx: _Context, path: Path_, value: Any) -> str:
    if not isinstance(value, str):
        raise ctx.error(path, f"must be a string, got {_kind(value)}")
    return value


def _vector(ctx: _Context, path: Path_, value: Any, size: int | None = None) -> np.ndarray:
    if not isinstance(value, list) or not all(_is_number(v) for v in value):
        raise ctx.error(path, f"must be an array of numbers, got {_kind(value)}")
    arr = np.array(value, dtype=float)
    if size is not None and arr.shape[0] != size:
        raise ctx.error(path, f"must have length {size}, got length {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ctx.error(path, "contains non-finite values")
    return arr


def _matrix(
    ctx: _Context, path: Path_, value: Any, rows: int | None = None, cols: int | None = None
) -> np.ndarray:
    if not isinstance(value, list) or not all(isinstance(r, list) for r in value):
        raise ctx.error(path, f"must be a matrix (an array of rows), got {_kind(value)}")
    for i, row in enumerate(value):
        if not all(_is_number(v) for v in row):
            raise ctx.error(path, f"row {i} must contain only numbers")
    widths = {len(r) for r in value}
    if len(widths) > 1:
        raise ctx.error(path, f"rows have different lengths {sorted(widths)}")
    width = widths.pop() if widths else 0
    arr = np.array(value, dtype=float).reshape(len(value), width)
    want = f"({rows if rows is not None else '*'}, {cols if cols is not None else '*'})"
    if (rows is not None and arr.shape[0] != rows) or (cols is not None and arr.shape[1] != cols):
        raise ctx.error(path, f"must have shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ctx.error(path, "contains non-finite values")
    return arr


# ------------------------------------------------------------------------------------------------
# whitelisted expressions
# ------------------------------------------------------------------------------------------------

Node = tuple
_FUNCTIONS: dict[str, tuple[int, int | None]] = {
    "sqrt": (1, 1), "exp": (1, 1), "abs": (1, 1), "min": (2, None), "max": (2, None),
}
_BINOPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**"}
_ALLOWED = "numbers, x[i], + - * / **, parentheses, sqrt, exp, abs, min, max"


class _ExpressionError(Exception):
    def __init__(self, message: str, column: int | None = None) -> None:
        super().__init__(message)
        self.column = column


def _describe(node: ast.AST) -> str:
    names = {
        ast.Attribute: "attribute access", ast.Lambda: "lambda", ast.ListComp: "comprehension",
        ast.SetComp: "comprehension", ast.DictComp: "comprehension",
        ast.GeneratorExp: "generator expression", ast.Name: "name", ast.Call: "call",
        ast.Subscript: "subscript", ast.BoolOp: "boolean operator", ast.IfExp: "conditional",
        ast.NamedExpr: "assignment", ast.Starred: "starred argument",
    }
    return names.get(type(node), type(node).__name__)


def _convert(node: ast.AST, n: int, var: str, compare: bool) -> Node:
    col = getattr(node, "col_offset", None)
    if isinstance(node, ast.Constant):
        value = node.value
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise _ExpressionError(f"constant {value!r} is not a number", col)
        try:
            x = float(value)
        except OverflowError as exc:
            raise _ExpressionError("number too large", col) from exc
        if not math.isfinite(x):
            raise _ExpressionError("number too large", col)
        return ("const", x)
    if isinstance(node, ast.Subscript):
        if not (isinstance(node.value, ast.Name) and node.value.id == var):
            raise _ExpressionError(f"only {var}[i] may be subscripted", col)
        index = node.slice
        if not (isinstance(index, ast.Constant) and type(index.value) is int):
            raise _ExpressionError(f"the index of {var}[i] must be an integer literal", col)
        if not 0 <= index.value < n:
            raise _ExpressionError(f"index {index.value} is out of range: {var} has size {n}", col)
        return ("x", index.value)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd):
        inner = _convert(node.operand, n, var, False)
        return ("neg", inner) if isinstance(node.op, ast.USub) else inner
    if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
        return (
            _BINOPS[type(node.op)],
            _convert(node.left, n, var, False),
            _convert(node.right, n, var, False),
        )
    if isinstance(node, ast.Call):
        func = node.func
        if not (isinstance(func, ast.Name) and func.id in _FUNCTIONS):
            if isinstance(func, ast.Name):
                what = repr(func.id)
            elif isinstance(func, ast.Attribute):
                what = "a method or attribute"
            else:
                what = f"a {_describe(func)}"
            raise _ExpressionError(f"calling {what} is not allowed (allowed: {_ALLOWED})", col)
        if node.keywords:
            raise _ExpressionError(f"{func.id}() takes no keyword arguments", col)
        lo, hi = _FUNCTIONS[func.id]
        if len(node.args) < lo or (hi is not None and len(node.args) > hi):
            raise _ExpressionError(f"{func.id}() takes {lo if lo == hi else f'{lo} or more'} arguments", col)
        return ("call", func.id, tuple(_convert(a, n, var, False) for a in node.args))
    if isinstance(node, ast.Compare) and compare:
        ops = []
        for op in node.ops:
            if isinstance(op, ast.LtE):
                ops.append("<=")
            elif isinstance(op, ast.GtE):
                ops.append(">=")
            else:
                raise _ExpressionError("only <= and >= comparisons are allowed", col)
        operands = [node.left, *node.comparators]
        return ("cmp", tuple(ops), tuple(_convert(o, n, var, False) for o in operands))
    if isinstance(node, ast.Compare):
        raise _ExpressionError("a comparison is not allowed here", col)
    if isinstance(node, ast.Name):
        raise _ExpressionError(f"unknown name {node.id!r} (allowed: {_ALLOWED})", col)
    raise _ExpressionError(f"{_describe(node)} is not allowed (allowed: {_ALLOWED})", col)


def _parse_tree(text: str, n: int, var: str, compare: bool) -> Node:
    if not isinstance(text, str):
        raise _ExpressionError(f"must be a string, got {_kind(text)}")
    if len(text) > _MAX_EXPRESSION_LENGTH:
        raise _ExpressionError(f"expression longer than {_MAX_EXPRESSION_LENGTH} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise _ExpressionError(f"syntax error: {exc.msg}", (exc.offset or 1) - 1) from None
    except (RecursionError, MemoryError, ValueError):
        raise _ExpressionError("expression too deeply nested or invalid") from None
    try:
        return _convert(tree.body, n, var, compare)
    except RecursionError:
        raise _ExpressionError("expression too deeply nested") from None


def _evaluate(node: Node, x: np.ndarray) -> np.float64:
    kind = node[0]
    if kind == "const":
        return np.float64(node[1])
    if kind == "x":
        return np.float64(x[node[1]])
    if kind == "neg":
        return -_evaluate(node[1], x)
    if kind == "call":
        args = [_evaluate(a, x) for a in node[2]]
        name = node[1]
        if name == "sqrt":
            return np.sqrt(args[0])
        if name == "exp":
            return np.exp(args[0])
        if name == "abs":
            return np.abs(args[0])
        if name == "min":
            return np.min(np.array(args))
        return np.max(np.array(args))
    a = _evaluate(node[1], x)
    b = _evaluate(node[2], x)
    if kind == "+":
        return a + b
    if kind == "-":
        return a - b
    if kind == "*":
        return a * b
    if kind == "/":
        return a / b
    return np.power(a, b)


class NoiseExpression:
    """A state-dependent noise matrix ``n(x) = scale(x) * matrix`` read from a problem file.

    A plain object holding the parsed expression tree (tuples) and the matrix, so it pickles
    and can be shipped to other processes; calling it interprets the tree with NumPy.

    Parameters
    ----------
    text : str
        The expression as written (kept for printing).
    tree : tuple
        The whitelisted expression tree from :func:`parse_noise_expression`.
    matrix : array_like, shape (p, r)
    """

    def __init__(self, text: str, tree: Node, matrix: Any) -> None:
        self.text = text
        self.tree = tree
        self.matrix = np.array(matrix, dtype=float)

    def scale(self, x: Any) -> float:
        """The scalar ``scale(x)``."""
        with np.errstate(all="ignore"):
            return float(_evaluate(self.tree, np.asarray(x, dtype=float).reshape(-1)))

    def __call__(self, x: Any) -> np.ndarray:
        return self.scale(x) * self.matrix

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, NoiseExpression)
            and self.tree == other.tree
            and np.array_equal(self.matrix, other.matrix)
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"NoiseExpression({self.text!r}, matrix shape {self.matrix.shape})"


def parse_noise_expression(text: str, n: int, matrix: Any = None, var: str = "x") -> NoiseExpression:
    """Parse a whitelisted scalar expression of the state into a :class:`NoiseExpression`.

    Parameters
    ----------
    text : str
        E.g. ``"0.1*(5 - x[0])**2 + 0.001"``.
    n : int
        State dimension (``x[i]`` needs ``0 <= i < n``).
    matrix : array_like, optional
        The constant factor (default: the ``n x n`` identity).
    var : str
        Name of the state variable in the text.

    Raises
    ------
    InvalidArgumentError
        (a :class:`ProblemFileError`) for anything outside the whitelist.
    """
    try:
        tree = _parse_tree(text, n, var, compare=False)
    except _ExpressionError as exc:
        raise ProblemFileError(f"noise expression {text!r}: {exc}") from None
    return NoiseExpression(text, tree, np.identity(n) if matrix is None else matrix)


def _linear(node: Node) -> tuple[dict[int, float], float]:
    """Interpret a tree as an affine function ``sum h_i x_i + c``."""
    kind = node[0]
    if kind == "const":
        return {}, node[1]
    if kind == "x":
        return {node[1]: 1.0}, 0.0
    if kind == "neg":
        h, c = _linear(node[1])
        return {i: -v for i, v in h.items()}, -c
    if kind == "call":
        args = [_linear(a) for a in node[2]]
        if any(h for h, _ in args):
            raise _ExpressionError(f"{node[1]}() of the state is not linear")
        with np.errstate(all="ignore"):
            return {}, float(_evaluate(node, np.zeros(0)))
    (h1, c1), (h2, c2) = _linear(node[1]), _linear(node[2])
    if kind in ("+", "-"):
        s = 1.0 if kind == "+" else -1.0
        h = dict(h1)
        for i, v in h2.items():
            h[i] = h.get(i, 0.0) + s * v
        return h, c1 + s * c2
    if kind == "*":
        if h1 and h2:
            raise _ExpressionError("the product of two terms in x is not linear")
        if h2:
            (h1, c1), (h2, c2) = (h2, c2), (h1, c1)
        return {i: v * c2 for i, v in h1.items()}, c1 * c2
    if kind == "/":
        if h2:
            raise _ExpressionError("division by a term in x is not linear")
        if c2 == 0:
            raise _ExpressionError("division by zero")
        return {i: v / c2 for i, v in h1.items()}, c1 / c2
    if h1 or h2:
        raise _ExpressionError("powers of the state are not linear")
    with np.errstate(all="ignore"):
        return {}, float(np.power(np.float64(c1), np.float64(c2)))


def parse_linear_constraint(text: str, n: int, var: str = "x") -> list[tuple[np.ndarray, float]]:
    """Parse ``"x[0] >= -1"`` (or a chain ``"-1 <= x[0] <= 5"``) into half-spaces ``h' x + c <= 0``.

    Parameters
    ----------
    text : str
    n : int
        State dimension.
    var : str
        Name of the state variable in the text.

    Returns
    -------
    list of (ndarray, float)
        One ``(h, c)`` per comparison, oriented as ``h' x + c <= 0`` (the same orientation the
        Python API gives: ``x[0] >= -1`` is ``-x[0] - 1 <= 0``).
    """
    try:
        return _linear_constraint(text, n, var)
    except _ExpressionError as exc:
        raise ProblemFileError(f"constraint {text!r}: {exc}") from None


def _linear_constraint(text: str, n: int, var: str) -> list[tuple[np.ndarray, float]]:
    tree = _parse_tree(text, n, var, compare=True)
    if tree[0] != "cmp":
        raise _ExpressionError("a constraint must compare two sides with <= or >=, e.g. x[0] >= -1")
    out = []
    operands = [_linear(o) for o in tree[2]]
    for op, (hl, cl), (hr, cr) in zip(tree[1], operands[:-1], operands[1:], strict=True):
        small, big = ((hl, cl), (hr, cr)) if op == "<=" else ((hr, cr), (hl, cl))
        h = np.zeros(n)
        for i, v in small[0].items():
            h[i] += v
        for i, v in big[0].items():
            h[i] -= v
        c = small[1] - big[1]
        if not np.any(h != 0):
            raise _ExpressionError(f"the comparison does not involve {var}")
        if not (np.all(np.isfinite(h)) and math.isfinite(c)):
            raise _ExpressionError("coefficients are not finite")
        out.append((h, float(c)))
    return out


# ------------------------------------------------------------------------------------------------
# problem specs
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ExecutionSettings:
    """How a plan is executed and validated (the ``[execution]`` and ``[validation]`` tables).

    Attributes
    ----------
    real_system : SwitchedSystem
        The system the plan runs on (default: the planning model itself).
    real_initial_state : ndarray, shape (n,)
        True initial state (default: the initial belief's mean).
    lqr : dict or None
        ``horizon``, ``Q_final``, ``Q``, ``R`` of the tracking controller of every mode
        (:meth:`~idstlpy.dynamical_system.LCS.compute_finite_horizon_lqr`), or None.
    runs : int
        Number of validation runs.
    seed : int or None
        Seed of the validation runs.
    """

    real_system: SwitchedSystem
    real_initial_state: np.ndarray
    lqr: dict[str, Any] | None = None
    runs: int = 100
    seed: int | None = None


class BuiltProblem(NamedTuple):
    """What :meth:`ProblemSpec.build` returns (unpacks as ``problem, solver_kwargs, execution``)."""

    problem: Problem
    solver_kwargs: dict[str, Any]
    execution: ExecutionSettings


@dataclass(frozen=True)
class ProblemSpec:
    """A problem file as plain data: the parsed TOML, its text and where it came from.

    Create it with :func:`load_problem`; it pickles cheaply and builds the solver objects on
    demand with :meth:`build`.

    Attributes
    ----------
    data : dict
        The parsed TOML (with overrides applied).
    source : str
        The file's text (for error messages and for shipping to other processes).
    name : str
        The file's path, or ``"<string>"``.
    overrides : dict
        The overrides applied to ``data`` by :func:`apply_overrides`.
    """

    data: dict[str, Any]
    source: str
    name: str = "<string>"
    overrides: dict[str, Any] = field(default_factory=dict)

    def build(self) -> BuiltProblem:
        """Build the :class:`~idstlpy.Problem`, the ``solve`` keyword arguments and the execution settings.

        Returns
        -------
        BuiltProblem
            ``(problem, solver_kwargs, execution)``.

        Raises
        ------
        ProblemFileError
        """
        return _Builder(self).build()

    @property
    def title(self) -> str:
        """The ``name`` key of the file, or the file name."""
        name = self.data.get("name")
        return name if isinstance(name, str) else Path(self.name).stem


def load_problem(path_or_text: str | os.PathLike[str], *, name: str | None = None) -> ProblemSpec:
    """Read and check a TOML problem file.

    Parameters
    ----------
    path_or_text : str or path-like
        A path (``Path``, or a one-line string naming an existing file or ending in
        ``.toml``), or the TOML text itself.
    name : str, optional
        Name used in error messages (default: the path, or ``"<string>"``).

    Returns
    -------
    ProblemSpec
        The plain data; the whole problem has been checked (built once) already.

    Raises
    ------
    ProblemFileError
        For a missing or unreadable file, invalid TOML, unknown keys, missing fields, wrong
        shapes and expressions outside the whitelist; the message names the file, line and
        field.
    """
    text, source_name = _read(path_or_text)
    spec_name = name or source_name
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        err = _plain_error(f"{spec_name}{':' + m.group(1) if m else ''}", f"invalid TOML: {exc}")
        err.file, err.line = spec_name, int(m.group(1)) if m else None  # type: ignore[attr-defined]
        raise err from None
    spec = ProblemSpec(data, text, spec_name)
    spec.build()
    return spec


def _read(path_or_text: str | os.PathLike[str]) -> tuple[str, str]:
    if isinstance(path_or_text, os.PathLike) or (
        isinstance(path_or_text, str)
        and "\n" not in path_or_text
        and (path_or_text.endswith(".toml") or Path(path_or_text).is_file())
    ):
        path = Path(path_or_text)
        try:
            return path.read_text(encoding="utf-8"), str(path)
        except (OSError, UnicodeDecodeError) as exc:
            raise _plain_error(str(path), f"cannot read the problem file: {exc}") from None
    if not isinstance(path_or_text, str):
        raise _plain_error(None, f"expected a path or TOML text, got {type(path_or_text).__name__}")
    if "\n" not in path_or_text and "=" not in path_or_text:
        raise _plain_error(path_or_text, "no such problem file (and not TOML text either)")
    return path_or_text, "<string>"


_SEGMENT_RE = re.compile(r"(\.)?(?:([A-Za-z_][A-Za-z0-9_\-]*)|(\d+))|\[(\d+)\]")


def parse_override_path(key: str) -> list[str | int]:
    """Split an override key such as ``"modes[0].V.scale"`` or ``"solver.rrt_timeout"``.

    ``modes.0.V`` is the same as ``modes[0].V``.

    Returns
    -------
    list of str or int
        Table keys (str) and array indices (int).

    Raises
    ------
    ProblemFileError
        For a malformed key.
    """
    if not isinstance(key, str) or not key:
        raise _plain_error(None, f"override key must be a non-empty string, got {key!r}")
    parts: list[str | int] = []
    pos = 0
    while pos < len(key):
        m = _SEGMENT_RE.match(key, pos)
        if m is None or (m.group(1) is None and parts and m.group(4) is None) or (
            m.group(1) is not None and not parts
        ):
            raise _plain_error(None, f"override key {key!r} is malformed at character {pos + 1}")
        if m.group(2) is not None:
            parts.append(m.group(2))
        elif m.group(3) is not None:
            if not parts:
                raise _plain_error(None, f"override key {key!r} must start with a name")
            parts.append(int(m.group(3)))
        else:
            parts.append(int(m.group(4)))
        pos = m.end()
    if not isinstance(parts[0], str):
        raise _plain_error(None, f"override key {key!r} must start with a name")
    return parts


def _plain_error(file: str | None, message: str, field: str | None = None) -> ProblemFileError:
    err = ProblemFileError(f"{file}: {message}" if file else message)
    err.file, err.line, err.field = file, None, field  # type: ignore[attr-defined]
    return err


def apply_overrides(spec: ProblemSpec, overrides: Mapping[str, Any]) -> ProblemSpec:
    """A copy of ``spec`` with some values replaced (for parameter sweeps).

    Parameters
    ----------
    spec : ProblemSpec
    overrides : mapping of str to value
        Dotted paths (``"solver.rrt_timeout"``, ``"modes[0].V"``, ``"initial_belief.mean"``,
        ``"propositions.target.confidence"``) to plain values (numbers, strings, arrays,
        tables). Missing tables on the way are created; the result is checked again, so an
        unknown key is reported.

    Returns
    -------
    ProblemSpec

    Raises
    ------
    ProblemFileError
    """
    if not overrides:
        return spec
    data = copy.deepcopy(spec.data)
    for key, value in overrides.items():
        path = parse_override_path(key)
        node: Any = data
        for i, part in enumerate(path[:-1]):
            nxt = path[i + 1]
            if isinstance(part, int):
                if not isinstance(node, list) or not 0 <= part < len(node):
                    where = _field_name(tuple(path[:i]))
                    raise _plain_error(spec.name, f"override {key!r}: no element {part} in {where}", key)
                node = node[part]
            else:
                if not isinstance(node, dict):
                    where = _field_name(tuple(path[:i]))
                    raise _plain_error(spec.name, f"override {key!r}: {where} is not a table", key)
                if part not in node:
                    node[part] = [] if isinstance(nxt, int) else {}
                node = node[part]
        last = path[-1]
        if isinstance(last, int):
            if not isinstance(node, list) or not 0 <= last < len(node):
                raise _plain_error(spec.name, f"override {key!r}: no element {last}", key)
            node[last] = copy.deepcopy(value)
        else:
            if not isinstance(node, dict):
                where = _field_name(tuple(path[:-1]))
                raise _plain_error(spec.name, f"override {key!r}: {where} is not a table", key)
            node[last] = copy.deepcopy(value)
    merged = {**spec.overrides, **dict(overrides)}
    out = ProblemSpec(data, spec.source, spec.name, merged)
    out.build()
    return out


# ------------------------------------------------------------------------------------------------
# building
# ------------------------------------------------------------------------------------------------


def _solver_parameters() -> dict[str, Any]:
    from .synthesis.options import SolverOptions

    return {f.name: f.default for f in dataclasses.fields(SolverOptions)}


class _Builder:
    def __init__(self, spec: ProblemSpec) -> None:
        self.spec = spec
        self.ctx = _Context(spec.name, spec.source, list(spec.overrides))

    def err(self, path: Path_, message: str) -> ProblemFileError:
        return self.ctx.error(path, message)

    def build(self) -> BuiltProblem:
        data = _table(self.ctx, (), self.spec.data, _TOP_KEYS, _REQUIRED_TOP)
        for key in ("name", "description"):
            if key in data:
                _string(self.ctx, (key,), data[key])
        modes_data = data["modes"]
        if not isinstance(modes_data, list) or not modes_data:
            raise self.err(("modes",), "must be a non-empty array of tables ([[modes]])")
        modes = []
        n = m = None
        for q, md in enumerate(modes_data):
            mode = self.mode(("modes", q), md, n, m, planning=True)
            n, m = mode.n, mode.m
            modes.append(mode)
        n, m = modes[0].n, modes[0].m  # every mode was checked against the first
        system = mk_switched_sys(modes)
        control = self.control_domain(data["control_domain"], m)
        belief = self.initial_belief(data["initial_belief"], n)
        x = mk_variable(size=n, dtype=float, name="x")
        atoms = self.propositions(data.get("propositions", {}), x, system.num_modes)
        formula_text = _string(self.ctx, ("formula",), data["formula"])
        try:
            formula = parse_formula(formula_text, atoms, x, system.num_modes)
        except FormulaSyntaxError as exc:
            raise self.err(
                ("formula",), f"{exc.detail} at column {exc.position + 1} of {formula_text!r}"
            ) from None
        used = {ap.name for ap in formula.atomic_propositions()}
        for unused in sorted(set(atoms) - used):
            logger.info("%s: proposition %r is not used by the formula", self.spec.name, unused)
        try:
            problem = Problem(system, control, belief, formula)
        except IdstlpyError as exc:
            raise self.err(("modes",), f"the problem is inconsistent: {exc}") from None
        solver = self.solver(data.get("solver", {}))
        execution = self.execution(data.get("execution", {}), data.get("validation", {}), system, belief.mean)
        return BuiltProblem(problem, solver, execution)

    # -- systems -------------------------------------------------------------------------------
    def mode(self, path: Path_, md: Any, n: int | None, m: int | None, planning: bool) -> LCS:
        md = _table(self.ctx, path, md, _MODE_KEYS, ("A", "B"))
        A = _matrix(self.ctx, path + ("A",), md["A"], n, n)
        if A.shape[0] != A.shape[1]:
            raise self.err(path + ("A",), f"must be square, got shape {A.shape}")
        n = A.shape[0]
        if n == 0:
            raise self.err(path + ("A",), "must have at least one row")
        B = _matrix(self.ctx, path + ("B",), md["B"], n, m)
        if B.shape[1] == 0:
            raise self.err(path + ("B",), "must have at least one column")
        if not planning and set(md) <= {"A", "B"}:
            return mk_lcs(A, B)
        W = _matrix(self.ctx, path + ("W",), md["W"], n, None) if "W" in md else np.zeros((n, n))
        C = _matrix(self.ctx, path + ("C",), md["C"], None, n) if "C" in md else None
        if C is not None and C.shape[0] == 0:
            raise self.err(path + ("C",), "must have at least one row (omit C for no sensing)")
        V: Any = None
        if "V" in md:
            if C is None:
                raise self.err(path + ("V",), "observation noise V needs an output matrix C")
            V = self.noise(path + ("V",), md["V"], n, C.shape[0])
        try:
            return mk_lbs(A, B, W, C, V)
        except IdstlpyError as exc:
            raise self.err(path, str(exc)) from None

    def noise(self, path: Path_, value: Any, n: int, p: int) -> Any:
        if isinstance(value, list):
            return _matrix(self.ctx, path, value, p, None)
        if isinstance(value, str):
            return self.expression(path, value, n, np.identity(p))
        if isinstance(value, dict):
            value = _table(self.ctx, path, value, ("scale", "matrix"), ("scale",))
            matrix = (
                _matrix(self.ctx, path + ("matrix",), value["matrix"], p, None)
                if "matrix" in value
                else np.identity(p)
            )
            scale = value["scale"]
            if _is_number(scale):
                return _number(self.ctx, path + ("scale",), scale) * matrix
            return self.expression(path + ("scale",), scale, n, matrix)
        raise self.err(
            path,
            "must be a matrix, an expression string, or a table {scale = ..., matrix = ...}; "
            f"got {_kind(value)}",
        )

    def expression(self, path: Path_, text: Any, n: int, matrix: np.ndarray) -> NoiseExpression:
        if not isinstance(text, str):
            raise self.err(path, f"must be an expression string or a number, got {_kind(text)}")
        try:
            tree = _parse_tree(text, n, "x", compare=False)
        except _ExpressionError as exc:
            raise self.err(path, f"{exc} in {text!r}") from None
        return NoiseExpression(text, tree, matrix)

    def control_domain(self, value: Any, m: int) -> Polytope:
        path: Path_ = ("control_domain",)
        value = _table(self.ctx, path, value, ("low", "high", "A", "b"))
        box = {"low", "high"} & set(value)
        ineq = {"A", "b"} & set(value)
        if box and ineq:
            raise self.err(path, "give either low/high (a box) or A/b (A u <= b), not both")
        if box:
            for key in ("low", "high"):
                if key not in value:
                    raise self.err(path, f"missing required key {key!r} (a box needs low and high)")
            low = _vector(self.ctx, path + ("low",), value["low"], m)
            high = _vector(self.ctx, path + ("high",), value["high"], m)
            if np.any(low > high):
                raise self.err(path + ("low",), "must be <= high in every component")
            # rows in the order of logical_and(u[0] >= low[0], u[0] <= high[0], u[1] >= ...)
            H = np.zeros((2 * m, m))
            c = np.zeros(2 * m)
            for i in range(m):
                H[2 * i, i], c[2 * i] = -1.0, low[i]
                H[2 * i + 1, i], c[2 * i + 1] = 1.0, -high[i]
            return Polytope(H, c)
        if ineq:
            for key in ("A", "b"):
                if key not in value:
                    raise self.err(path, f"missing required key {key!r} (A u <= b needs A and b)")
            A = _matrix(self.ctx, path + ("A",), value["A"], None, m)
            b = _vector(self.ctx, path + ("b",), value["b"], A.shape[0])
            poly = Polytope.from_inequalities(A, b)
            if poly.is_empty():
                raise self.err(path, "is empty: no input satisfies A u <= b")
            return poly
        raise self.err(path, "missing required keys: low and high (a box), or A and b (A u <= b)")

    def initial_belief(self, value: Any, n: int) -> Any:
        path: Path_ = ("initial_belief",)
        value = _table(self.ctx, path, value, ("mean", "cov"), ("mean", "cov"))
        mean = _vector(self.ctx, path + ("mean",), value["mean"], n)
        cov_value = value["cov"]
        if isinstance(cov_value, list) and cov_value and all(_is_number(v) for v in cov_value):
            cov = np.diag(_vector(self.ctx, path + ("cov",), cov_value, n))
        else:
            cov = _matrix(self.ctx, path + ("cov",), cov_value, n, n)
        try:
            return to_belief(mean, cov)
        except IdstlpyError as exc:
            raise self.err(path + ("cov",), str(exc)) from None

    # -- specification -------------------------------------------------------------------------
    def propositions(
        self, value: Any, x: RealValuedVariable, num_modes: int
    ) -> dict[str, STLAtomicProposition]:
        path: Path_ = ("propositions",)
        if not isinstance(value, dict):
            raise self.err(path, f"must be a table of propositions, got {_kind(value)}")
        atoms: dict[str, STLAtomicProposition] = {}
        for name, pd in value.items():
            ppath = path + (name,)
            if not name.isidentifier() or name in RESERVED_NAMES:
                raise self.err(
                    ppath,
                    f"proposition name {name!r} must be an identifier other than "
                    f"{', '.join(sorted(RESERVED_NAMES))}",
                )
            pd = _table(self.ctx, ppath, pd, ("constraints", "confidence", "modes"))
            default_conf = (
                _number(self.ctx, ppath + ("confidence",), pd["confidence"], 0.5, 1.0)
                if "confidence" in pd
                else None
            )
            constraints = pd.get("constraints", [])
            if not isinstance(constraints, list):
                raise self.err(ppath + ("constraints",), f"must be an array, got {_kind(constraints)}")
            preds: list[ProbabilisticLinearPredicate] = []
            for i, item in enumerate(constraints):
                cpath = ppath + ("constraints", i)
                conf = default_conf
                if isinstance(item, dict):
                    item = _table(self.ctx, cpath, item, ("expr", "confidence"), ("expr",))
                    if "confidence" in item:
                        conf = _number(self.ctx, cpath + ("confidence",), item["confidence"], 0.5, 1.0)
                    item = item["expr"]
                if not isinstance(item, str):
                    raise self.err(
                        cpath,
                        "must be a string such as 'x[0] >= -1' or a table {expr, confidence}, "
                        f"got {_kind(item)}"
                    )
                if conf is None:
                    raise self.err(
                        cpath, "has no confidence: set confidence for the proposition or the constraint"
                    )
                try:
                    halfspaces = _linear_constraint(item, x.size, "x")
                except _ExpressionError as exc:
                    raise self.err(cpath, f"{exc} in {item!r}") from None
                preds.extend(ProbabilisticLinearPredicate(h, c, x, 1.0 - conf) for h, c in halfspaces)
            modes = None
            if "modes" in pd:
                mv = pd["modes"]
                if not isinstance(mv, list):
                    raise self.err(ppath + ("modes",), f"must be an array of mode numbers, got {_kind(mv)}")
                modes = []
                for j, k in enumerate(mv):
                    k = _integer(self.ctx, ppath + ("modes", j), k, 0)
                    if k >= num_modes:
                        raise self.err(
                            ppath + ("modes", j),
                            f"mode {k} is out of range: the system has modes 0..{num_modes - 1}",
                        )
                    modes.append(k)
            atoms[name] = STLAtomicProposition(preds, modes, name=name)
        return atoms

    def solver(self, value: Any) -> dict[str, Any]:
        path: Path_ = ("solver",)
        params = _solver_parameters()
        value = _table(self.ctx, path, value, tuple(params))
        kwargs: dict[str, Any] = {}
        for key, v in value.items():
            default = params[key]
            if isinstance(default, str):
                if not isinstance(v, str):
                    raise self.err(path + (key,), f"must be a string, got {_kind(v)}")
                kwargs[key] = v
                continue
            if isinstance(v, bool) or not (_is_number(v) or (v is None)):
                raise self.err(path + (key,), f"must be a number, got {_kind(v)}")
            integral = type(default) is int or key in ("seed", "max_candidates", "sampler_iterations")
            if integral:
                if not (isinstance(v, int) or (isinstance(v, float) and v.is_integer())):
                    raise self.err(path + (key,), f"must be an integer, got {v}")
                v = int(v)
            kwargs[key] = v
        try:
            from .synthesis.options import SolverOptions

            SolverOptions.make(**{**params, **kwargs})
        except IdstlpyError as exc:
            bad = next((k for k in kwargs if k in str(exc)), None)
            raise self.err(path + ((bad,) if bad else ()), str(exc)) from None
        except (ImportError, AttributeError, KeyError, TypeError):  # pragma: no cover
            pass
        return kwargs

    def execution(
        self, value: Any, validation: Any, system: SwitchedSystem, mean: np.ndarray
    ) -> ExecutionSettings:
        path: Path_ = ("execution",)
        value = _table(self.ctx, path, value, ("real_system", "real_initial_state", "lqr"))
        n, m = system.n, system.m
        real = system
        if "real_system" in value:
            rs = value["real_system"]
            if not isinstance(rs, list) or not rs:
                raise self.err(
                    path + ("real_system",),
                    "must be a non-empty array of tables ([[execution.real_system]])",
                )
            real = mk_switched_sys(
                [self.mode(path + ("real_system", q), md, n, m, planning=False) for q, md in enumerate(rs)]
            )
            if real.num_modes != system.num_modes:
                raise self.err(
                    path + ("real_system",),
                    f"has {real.num_modes} modes, the planning model has {system.num_modes}",
                )
        x0 = (
            _vector(self.ctx, path + ("real_initial_state",), value["real_initial_state"], n)
            if "real_initial_state" in value
            else np.array(mean, dtype=float)
        )
        lqr = None
        if "lqr" in value:
            lpath = path + ("lqr",)
            lv = _table(self.ctx, lpath, value["lqr"], ("horizon", "Q_final", "Q", "R"), ("horizon",))
            size = {"Q_final": n, "Q": n, "R": m}
            lqr = {"horizon": _integer(self.ctx, lpath + ("horizon",), lv["horizon"], 1)}
            for key, k in size.items():
                lqr[key] = (
                    _matrix(self.ctx, lpath + (key,), lv[key], k, k) if key in lv else np.identity(k)
                )
        vpath: Path_ = ("validation",)
        vv = _table(self.ctx, vpath, validation, ("runs", "seed"))
        runs = _integer(self.ctx, vpath + ("runs",), vv["runs"], 1) if "runs" in vv else 100
        seed = _integer(self.ctx, vpath + ("seed",), vv["seed"], 0) if "seed" in vv else None
        return ExecutionSettings(real, x0, lqr, runs, seed)
