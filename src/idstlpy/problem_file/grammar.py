"""The whitelisted expression grammar of problem files, interpreted without ``eval``.

Expressions are parsed with :mod:`ast` and checked against a small whitelist: numbers,
``x[i]`` (``0 <= i < n``), ``+ - * / **``, unary signs, parentheses and the functions
``sqrt``, ``exp``, ``abs``, ``min``, ``max``; comparisons ``<=`` / ``>=`` (chained) in
constraints. Anything else is rejected before anything is evaluated.

Two readings of the same trees:

- a *noise scale* ``s(x)`` (any whitelisted expression) is interpreted with NumPy by
  :class:`NoiseExpression`, a plain picklable object;
- a *linear constraint* is evaluated on the library's own linear expressions: ``x[i]`` is
  ``variable[i]`` (a :class:`~idstlpy.expressions.LinearExpression`), arithmetic and
  comparisons are the operators of the Python API, so ``"2*x[0] - x[1]/4 <= 3"`` gives exactly
  the :class:`~idstlpy.expressions.LinearPredicate` that ``2 * x[0] - x[1] / 4 <= 3`` gives.
"""

from __future__ import annotations

import ast
import math
from typing import Any

import numpy as np

from ..errors import IdstlpyError, ProblemFileError
from ..expressions import LinearExpression, LinearPredicate, RealValuedVariable, mk_variable
from .schema import kind_of

__all__ = [
    "MAX_EXPRESSION_LENGTH",
    "ExpressionError",
    "NoiseExpression",
    "parse_tree",
    "parse_noise_expression",
    "linear_predicates",
    "parse_linear_constraint",
]

MAX_EXPRESSION_LENGTH = 2000

Node = tuple
_FUNCTIONS: dict[str, tuple[int, int | None]] = {
    "sqrt": (1, 1),
    "exp": (1, 1),
    "abs": (1, 1),
    "min": (2, None),
    "max": (2, None),
}
_BINOPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**"}
_ALLOWED = "numbers, x[i], + - * / **, parentheses, sqrt, exp, abs, min, max"


class ExpressionError(Exception):
    """An expression outside the whitelist.

    Parameters
    ----------
    message : str
        What is not allowed.
    column : int, optional
        0-based offset in the expression, when known.
    """

    def __init__(self, message: str, column: int | None = None) -> None:
        super().__init__(message)
        self.column = column


def _describe(node: ast.AST) -> str:
    names = {
        ast.Attribute: "attribute access",
        ast.Lambda: "lambda",
        ast.ListComp: "comprehension",
        ast.SetComp: "comprehension",
        ast.DictComp: "comprehension",
        ast.GeneratorExp: "generator expression",
        ast.Name: "name",
        ast.Call: "call",
        ast.Subscript: "subscript",
        ast.BoolOp: "boolean operator",
        ast.IfExp: "conditional",
        ast.NamedExpr: "assignment",
        ast.Starred: "starred argument",
    }
    return names.get(type(node), type(node).__name__)


def _convert(node: ast.AST, n: int, var: str, compare: bool) -> Node:
    col = getattr(node, "col_offset", None)
    if isinstance(node, ast.Constant):
        value = node.value
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ExpressionError(f"constant {value!r} is not a number", col)
        try:
            x = float(value)
        except OverflowError as exc:
            raise ExpressionError("number too large", col) from exc
        if not math.isfinite(x):
            raise ExpressionError("number too large", col)
        return ("const", x)
    if isinstance(node, ast.Subscript):
        if not (isinstance(node.value, ast.Name) and node.value.id == var):
            raise ExpressionError(f"only {var}[i] may be subscripted", col)
        index = node.slice
        if not (isinstance(index, ast.Constant) and type(index.value) is int):
            raise ExpressionError(f"the index of {var}[i] must be an integer literal", col)
        if not 0 <= index.value < n:
            raise ExpressionError(f"index {index.value} is out of range: {var} has size {n}", col)
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
            raise ExpressionError(f"calling {what} is not allowed (allowed: {_ALLOWED})", col)
        if node.keywords:
            raise ExpressionError(f"{func.id}() takes no keyword arguments", col)
        lo, hi = _FUNCTIONS[func.id]
        if len(node.args) < lo or (hi is not None and len(node.args) > hi):
            raise ExpressionError(f"{func.id}() takes {lo if lo == hi else f'{lo} or more'} arguments", col)
        return ("call", func.id, tuple(_convert(a, n, var, False) for a in node.args))
    if isinstance(node, ast.Compare) and compare:
        ops = []
        for op in node.ops:
            if isinstance(op, ast.LtE):
                ops.append("<=")
            elif isinstance(op, ast.GtE):
                ops.append(">=")
            else:
                raise ExpressionError("only <= and >= comparisons are allowed", col)
        operands = [node.left, *node.comparators]
        return ("cmp", tuple(ops), tuple(_convert(o, n, var, False) for o in operands))
    if isinstance(node, ast.Compare):
        raise ExpressionError("a comparison is not allowed here", col)
    if isinstance(node, ast.Name):
        raise ExpressionError(f"unknown name {node.id!r} (allowed: {_ALLOWED})", col)
    raise ExpressionError(f"{_describe(node)} is not allowed (allowed: {_ALLOWED})", col)


def parse_tree(text: str, n: int, var: str, compare: bool) -> Node:
    """Parse and check ``text`` against the whitelist; returns a tree of plain tuples.

    Parameters
    ----------
    text : str
        The expression.
    n : int
        Size of the state variable (``var[i]`` needs ``0 <= i < n``).
    var : str
        Name of the state variable.
    compare : bool
        Allow ``<=`` / ``>=`` comparisons at the top (constraints).

    Returns
    -------
    tuple
        ``("const", v)``, ``("x", i)``, ``("neg", t)``, ``(op, t1, t2)`` for ``op`` in
        ``+ - * / **``, ``("call", name, args)`` or ``("cmp", ops, operands)``.

    Raises
    ------
    ExpressionError
        For anything outside the whitelist (with the column when known).
    """
    if not isinstance(text, str):
        raise ExpressionError(f"must be a string, got {kind_of(text)}")
    if len(text) > MAX_EXPRESSION_LENGTH:
        raise ExpressionError(f"expression longer than {MAX_EXPRESSION_LENGTH} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ExpressionError(f"syntax error: {exc.msg}", (exc.offset or 1) - 1) from None
    except (RecursionError, MemoryError, ValueError):
        raise ExpressionError("expression too deeply nested or invalid") from None
    try:
        return _convert(tree.body, n, var, compare)
    except RecursionError:
        raise ExpressionError("expression too deeply nested") from None


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
        """The scalar ``scale(x)``.

        Parameters
        ----------
        x : array_like, shape (n,)
            The state.

        Returns
        -------
        float
            NaN or infinite where the expression is (e.g. ``sqrt`` of a negative number).
        """
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

    Returns
    -------
    NoiseExpression

    Raises
    ------
    ProblemFileError
        For anything outside the whitelist.
    """
    try:
        tree = parse_tree(text, n, var, compare=False)
    except ExpressionError as exc:
        raise ProblemFileError(f"noise expression {text!r}: {exc}") from None
    return NoiseExpression(text, tree, np.identity(n) if matrix is None else matrix)


Affine = float | LinearExpression


def _affine(node: Node, x: RealValuedVariable) -> Affine:
    """Evaluate a tree on the library's linear expressions (a float when it does not involve x)."""
    kind = node[0]
    if kind == "const":
        return float(node[1])
    if kind == "x":
        return x[node[1]]
    if kind == "neg":
        return -_affine(node[1], x)
    if kind == "call":
        args = [_affine(a, x) for a in node[2]]
        if any(isinstance(a, LinearExpression) for a in args):
            raise ExpressionError(f"{node[1]}() of the state is not linear")
        with np.errstate(all="ignore"):
            return float(_evaluate(node, np.zeros(0)))
    a, b = _affine(node[1], x), _affine(node[2], x)
    if kind == "**":
        if isinstance(a, LinearExpression) or isinstance(b, LinearExpression):
            raise ExpressionError("powers of the state are not linear")
        with np.errstate(all="ignore"):
            return float(np.power(np.float64(a), np.float64(b)))
    try:
        with np.errstate(all="ignore"):
            if kind == "+":
                return a + b
            if kind == "-":
                return a - b
            if kind == "*":
                if isinstance(a, LinearExpression) and isinstance(b, LinearExpression):
                    raise ExpressionError("the product of two terms in x is not linear")
                return a * b
            if isinstance(b, LinearExpression):
                raise ExpressionError("division by a term in x is not linear")
            if b == 0:
                raise ExpressionError("division by zero")
            return a / b
    except IdstlpyError as exc:  # e.g. a non-finite constant times x[i]
        raise ExpressionError(str(exc)) from None
    except OverflowError:
        raise ExpressionError("number too large") from None


def linear_predicates(text: str, x: RealValuedVariable) -> list[LinearPredicate]:
    """Read ``"x[0] >= -1"`` (or a chain ``"-1 <= x[0] <= 5"``) as predicates over ``x``.

    Parameters
    ----------
    text : str
        Linear comparisons with ``<=`` / ``>=``; ``x`` is written as ``x.name``.
    x : RealValuedVariable
        The state variable.

    Returns
    -------
    list of LinearPredicate
        One per comparison, as the Python API builds it (``x[0] >= -1`` is ``-x[0] - 1 <= 0``).

    Raises
    ------
    ExpressionError
        For text outside the whitelist or a comparison that is not linear in ``x``.
    """
    tree = parse_tree(text, x.size, x.name, compare=True)
    if tree[0] != "cmp":
        raise ExpressionError(f"a constraint must compare two sides with <= or >=, e.g. {x.name}[0] >= -1")
    operands = [_affine(o, x) for o in tree[2]]
    out = []
    for op, left, right in zip(tree[1], operands[:-1], operands[1:], strict=True):
        if not isinstance(left, LinearExpression) and not isinstance(right, LinearExpression):
            raise ExpressionError(f"the comparison does not involve {x.name}")
        try:
            pred = left <= right if op == "<=" else left >= right
        except IdstlpyError:
            raise ExpressionError("coefficients are not finite") from None
        if not isinstance(pred, LinearPredicate):  # pragma: no cover - scalar sides only
            raise ExpressionError("a constraint must compare two scalar sides")
        if not np.any(pred.h != 0):
            raise ExpressionError(f"the comparison does not involve {x.name}")
        if not (np.all(np.isfinite(pred.h)) and math.isfinite(pred.c)):  # pragma: no cover
            raise ExpressionError("coefficients are not finite")
        out.append(pred)
    return out


def parse_linear_constraint(text: str, n: int, var: str = "x") -> list[tuple[np.ndarray, float]]:
    """Parse ``"x[0] >= -1"`` (or a chain ``"-1 <= x[0] <= 5"``) into half-spaces ``h' x + c <= 0``.

    Parameters
    ----------
    text : str
        Linear comparisons with ``<=`` / ``>=``.
    n : int
        State dimension.
    var : str
        Name of the state variable in the text.

    Returns
    -------
    list of (ndarray, float)
        One ``(h, c)`` per comparison, oriented as ``h' x + c <= 0`` (the same orientation the
        Python API gives: ``x[0] >= -1`` is ``-x[0] - 1 <= 0``).

    Raises
    ------
    ProblemFileError
        For text outside the whitelist or a comparison that is not linear.
    """
    try:
        preds = linear_predicates(text, mk_variable(n, float, name=var))
    except ExpressionError as exc:
        raise ProblemFileError(f"constraint {text!r}: {exc}") from None
    return [(p.h, p.c) for p in preds]
