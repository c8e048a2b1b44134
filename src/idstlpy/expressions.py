"""Variables, linear expressions and the predicates built from them (paper Figs. 2 and 3).

A :class:`RealValuedVariable` of dimension ``n`` is also a vector of ``n`` linear expressions
``e_i' x + 0``; indexing gives scalar :class:`LinearExpression` objects, arithmetic with scalars
and constant vectors keeps them linear, and comparisons build :class:`LinearPredicate` objects
``h' x + c <= 0``. ``prob(pred) >= 1 - eps`` lifts a linear predicate to a chance constraint on a
Gaussian belief (:class:`ProbabilisticLinearPredicate`). ``q == k`` on a
:class:`DiscreteVariable` builds a :class:`DiscretePredicate` about the system mode.

Predicates and mode formulas are values: they compare and hash structurally (two predicates
with the same coefficients, constant, confidence and variable name and size are equal).
Variables and expressions are not (``==`` on an expression is a predicate constructor, and
refused on real-valued ones).
"""

from __future__ import annotations

import itertools
import weakref
from collections.abc import Iterable, Iterator, Sequence
from functools import cached_property
from typing import Any

import numpy as np

from ._checks import as_float, as_int
from .errors import DimensionError, InvalidArgumentError, InvalidTypeError, OutOfRangeError
from .sets import Polytope, make_belief_cone, make_polytope

__all__ = [
    "ConvexRegion",
    "LinearExpression",
    "RealValuedVariable",
    "DiscreteVariable",
    "ConvexConstraint",
    "LinearPredicate",
    "ProbabilisticLinearPredicate",
    "JointChanceConstraint",
    "DiscretePredicate",
    "DiscreteFormula",
    "mk_variable",
    "prob",
    "prob_in",
    "region_variable",
]

_ids = itertools.count()


def _fmt_num(value: float) -> str:
    # repr is the shortest text that reads back to the same float: printing round-trips.
    return repr(float(value))


class LinearExpression:
    """A vector of affine functions ``H x + c`` of one real-valued variable.

    Parameters
    ----------
    coef : array_like, shape (k, n)
        One row ``h_i'`` per component.
    const : array_like, shape (k,)
        Constant offsets ``c_i``.
    variable : RealValuedVariable
        The variable ``x`` (dimension ``n``) the expression is written over.

    Notes
    -----
    A scalar expression has ``k == 1``; comparisons on it build one :class:`LinearPredicate`.
    Comparing a vector expression builds the conjunction of its components (a
    :class:`ConvexRegion`).
    """

    __array_ufunc__ = None  # numpy defers `array * expr` to our reflected operators

    def __init__(self, coef: Any, const: Any, variable: RealValuedVariable) -> None:
        coef = np.atleast_2d(np.asarray(coef, dtype=float))
        const = np.atleast_1d(np.asarray(const, dtype=float))
        if coef.shape != (const.shape[0], variable.size):
            raise DimensionError(
                f"coef must have shape ({const.shape[0]}, {variable.size}), got {coef.shape}"
            )
        self._coef = coef
        self._const = const
        self._variable = variable

    # -- structure ------------------------------------------------------------------------------
    @property
    def coef(self) -> np.ndarray:
        """Coefficient matrix ``H``, shape (k, n)."""
        return self._coef

    @property
    def const(self) -> np.ndarray:
        """Offsets ``c``, shape (k,)."""
        return self._const

    @property
    def variable(self) -> RealValuedVariable:
        """The variable the expression is written over."""
        return self._variable

    def __len__(self) -> int:
        return self._coef.shape[0]

    @property
    def is_scalar(self) -> bool:
        """True for a single affine function."""
        return self._coef.shape[0] == 1

    def __getitem__(self, index: int | slice) -> LinearExpression:
        k = len(self)
        if isinstance(index, slice):
            rows = list(range(k))[index]
            if not rows:
                raise OutOfRangeError(f"slice {index} selects no component of a {k}-vector")
            return LinearExpression(self._coef[rows], self._const[rows], self._variable)
        if isinstance(index, bool) or not isinstance(index, int | np.integer):
            raise InvalidTypeError(f"index must be an int or a slice, got {type(index).__name__}")
        if not -k <= int(index) < k:
            raise OutOfRangeError(f"index {index} is out of range for a vector of size {k}")
        i = int(index) % k
        return LinearExpression(self._coef[i : i + 1], self._const[i : i + 1], self._variable)

    def __iter__(self) -> Iterator[LinearExpression]:
        return (self[i] for i in range(len(self)))

    # -- arithmetic -----------------------------------------------------------------------------
    def _constant(self, other: Any, op: str) -> np.ndarray:
        try:
            arr = np.asarray(other, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InvalidTypeError(f"cannot {op} a LinearExpression and {type(other).__name__}") from exc
        if arr.ndim > 1 or (arr.ndim == 1 and arr.shape[0] not in (1, len(self))):
            raise DimensionError(
                f"cannot {op} an expression of size {len(self)} and a constant of shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise InvalidArgumentError(f"cannot {op} with a non-finite constant {other!r}")
        return np.broadcast_to(arr, (len(self),))

    def _check_same(self, other: LinearExpression, op: str) -> None:
        if other._variable is not self._variable:
            raise InvalidArgumentError(
                f"cannot {op} expressions over different variables "
                f"({self._variable.name} and {other._variable.name})"
            )
        if len(other) != len(self) and 1 not in (len(other), len(self)):
            raise DimensionError(f"cannot {op} expressions of sizes {len(self)} and {len(other)}")

    def __add__(self, other: Any) -> LinearExpression:
        if isinstance(other, LinearExpression):
            self._check_same(other, "add")
            k = max(len(self), len(other))
            coef = np.broadcast_to(self._coef, (k, self._variable.size)) + other._coef
            return LinearExpression(coef, self._const + other._const, self._variable)
        if isinstance(other, ConvexConstraint | DiscreteVariable):
            return NotImplemented
        return LinearExpression(self._coef, self._const + self._constant(other, "add"), self._variable)

    __radd__ = __add__

    def __neg__(self) -> LinearExpression:
        return LinearExpression(-self._coef, -self._const, self._variable)

    def __pos__(self) -> LinearExpression:
        return self

    def __sub__(self, other: Any) -> LinearExpression:
        if isinstance(other, LinearExpression):
            return self + (-other)
        return self + (-self._constant(other, "subtract"))

    def __rsub__(self, other: Any) -> LinearExpression:
        return (-self) + other

    def __mul__(self, other: Any) -> LinearExpression:
        if isinstance(other, LinearExpression):
            raise InvalidTypeError("the product of two expressions is not linear")
        factor = self._constant(other, "multiply")
        return LinearExpression(self._coef * factor[:, None], self._const * factor, self._variable)

    __rmul__ = __mul__

    def __truediv__(self, other: Any) -> LinearExpression:
        factor = self._constant(other, "divide")
        if np.any(factor == 0):
            raise InvalidArgumentError("division of an expression by zero")
        return self * (1.0 / factor)

    def __matmul__(self, other: Any) -> LinearExpression:
        weights = self._constant(other, "take the inner product of")
        return LinearExpression(weights @ self._coef, [weights @ self._const], self._variable)

    __rmatmul__ = __matmul__

    def dot(self, weights: Any) -> LinearExpression:
        """Inner product ``w' (H x + c)`` as a scalar expression (the same as ``weights @ self``).

        Parameters
        ----------
        weights : array_like, shape (k,)
            One weight per component (a scalar is broadcast).

        Returns
        -------
        LinearExpression
            A scalar expression.
        """
        return self @ weights

    # -- comparisons build predicates -----------------------------------------------------------
    def _compare(self, other: Any, less: bool) -> LinearPredicate | Any:
        if isinstance(other, ConvexConstraint | DiscreteVariable | _Probability | _JointProbability):
            return NotImplemented
        diff = (self - other) if less else (other - self)
        if not isinstance(diff, LinearExpression):
            diff = -diff if not less else diff
        if diff.is_scalar:
            return LinearPredicate(diff._coef[0], float(diff._const[0]), diff._variable)
        return ConvexRegion(
            [
                LinearPredicate(h, float(c), diff._variable)
                for h, c in zip(diff._coef, diff._const, strict=True)
            ]
        )

    def __le__(self, other: Any) -> Any:
        return self._compare(other, less=True)

    def __ge__(self, other: Any) -> Any:
        return self._compare(other, less=False)

    def __lt__(self, other: Any) -> Any:
        raise InvalidTypeError("use <= (closed half-spaces); strict < is not a linear predicate here")

    def __gt__(self, other: Any) -> Any:
        raise InvalidTypeError("use >= (closed half-spaces); strict > is not a linear predicate here")

    def __eq__(self, other: object) -> bool:
        raise InvalidTypeError(
            "equality on real-valued expressions is not a PrSTL predicate; use two inequalities (<= and >=)"
        )

    __hash__ = object.__hash__

    def __bool__(self) -> bool:
        raise InvalidTypeError("a LinearExpression has no truth value; compare it with <= or >=")

    # -- printing -------------------------------------------------------------------------------
    def _row_str(self, i: int) -> str:
        return format_affine(self._coef[i], self._const[i], self._variable.name)

    def __str__(self) -> str:
        if self.is_scalar:
            return self._row_str(0)
        return "[" + ", ".join(self._row_str(i) for i in range(len(self))) + "]"

    def __repr__(self) -> str:
        return f"LinearExpression({self})"


def format_affine(h: np.ndarray, c: float, name: str) -> str:
    """Readable text for ``h' x + c``, e.g. ``-x[0] + 2.5*x[1] - 1.0``."""
    terms: list[str] = []
    for i, hi in enumerate(h):
        if hi == 0:
            continue
        mag = abs(float(hi))
        body = f"{name}[{i}]" if mag == 1 else f"{_fmt_num(mag)}*{name}[{i}]"
        sign = "-" if hi < 0 else "+"
        terms.append(("-" if sign == "-" else "") + body if not terms else f" {sign} {body}")
    if c != 0 or not terms:
        if not terms:
            terms.append(_fmt_num(float(c)))
        else:
            terms.append(f" {'-' if c < 0 else '+'} {_fmt_num(abs(float(c)))}")
    return "".join(terms)


class RealValuedVariable(LinearExpression):
    """A real-valued vector variable ``x in R^n``; also the vector of expressions ``x[i]``.

    Create it with :func:`mk_variable` (``dtype=float``).

    Parameters
    ----------
    size : int
        Dimension ``n >= 1``.
    name : str, optional
        Name used when printing (an identifier; default ``"x"``).
    """

    def __init__(self, size: int, name: str | None = None) -> None:
        self._size = as_int(size, "size", minimum=1)
        self._id = next(_ids)
        self.name = _as_name(name, "x")
        self._role: str | None = None
        super().__init__(np.eye(self._size), np.zeros(self._size), self)

    @property
    def size(self) -> int:
        """Dimension ``n`` of the variable."""
        return self._size

    @property
    def role(self) -> str | None:
        """``"state"`` or ``"input"`` once a :class:`~idstlpy.Problem` used the variable (its
        formula is over the state, its control domain over the input); ``None`` before."""
        return self._role

    def take_role(self, role: str, argument: str) -> None:
        """Give the variable its role, or refuse a second one.

        Parameters
        ----------
        role : {"state", "input"}
        argument : str
            The argument that uses the variable in that role (named in the error).

        Raises
        ------
        InvalidArgumentError
            When a Problem already used the variable in the other role.
        """
        if role not in ("state", "input"):
            raise InvalidArgumentError(f"role must be 'state' or 'input', got {role!r}")
        if self._role is not None and self._role != role:
            raise InvalidArgumentError(
                f"{argument} is written over {self.name}, which a Problem already uses as its "
                f"{self._role} variable: {_ROLE_USE[role]}"
            )
        self._role = role

    def __repr__(self) -> str:
        return f"RealValuedVariable(size={self._size}, name={self.name!r})"


class DiscreteVariable:
    """A variable taking one of ``size`` values ``0 .. size-1`` (the system mode ``q``).

    Create it with :func:`mk_variable` (``dtype=int``); ``q == k`` builds a
    :class:`DiscretePredicate`.

    Parameters
    ----------
    size : int
        Number of values (modes) ``>= 1``.
    name : str
        Name used when printing (an identifier; default ``"q"``).
    """

    def __init__(self, size: int, name: str = "q") -> None:
        self._size = as_int(size, "size", minimum=1)
        self.name = _as_name(name, "q")

    @property
    def size(self) -> int:
        """Number of values the variable can take."""
        return self._size

    def __eq__(self, value: object) -> DiscretePredicate:  # type: ignore[override]
        return DiscretePredicate(self, value)

    def __ne__(self, value: object) -> DiscreteFormula:  # type: ignore[override]
        pred = DiscretePredicate(self, value)
        return DiscreteFormula(frozenset(range(self._size)) - pred.modes, self._size)

    __hash__ = object.__hash__

    def __repr__(self) -> str:
        return f"DiscreteVariable(size={self._size}, name={self.name!r})"


_ROLE_USE = {
    "state": "the formula constrains the state (write it over the state variable, e.g. x[0] <= 5)",
    "input": "the control domain bounds the input (write it over the input variable, e.g. u[0] <= 1)",
}

_REGION_VARIABLES: weakref.WeakKeyDictionary[Any, RealValuedVariable] = weakref.WeakKeyDictionary()
"""The variable each ``.region`` set was written over (:func:`region_variable`)."""


def region_variable(region: Any) -> RealValuedVariable | None:
    """The variable a set made by ``.region`` (of a predicate or a conjunction) was written over.

    Parameters
    ----------
    region : Polytope or BeliefCone

    Returns
    -------
    RealValuedVariable or None
        ``None`` for a set built otherwise (e.g. ``Polytope(H, c)``).
    """
    try:
        return _REGION_VARIABLES.get(region)
    except TypeError:  # not weakly referenceable: not one of ours
        return None


def _remember(region: Any, variable: RealValuedVariable) -> Any:
    try:
        _REGION_VARIABLES[region] = variable
    except TypeError:
        pass
    return region


def _as_name(name: Any, default: str) -> str:
    if name is None:
        return default
    if not isinstance(name, str) or not name.isidentifier():
        raise InvalidArgumentError(f"name must be an identifier such as {default!r}, got {name!r}")
    return name


def mk_variable(size: int, dtype: type = float, name: str | None = None) -> Any:
    """Declare a variable (paper Section IV-B).

    Parameters
    ----------
    size : int
        For ``dtype=float`` the dimension of the vector; for ``dtype=int`` the number of values
        (modes ``0 .. size-1``).
    dtype : {float, int}
        Real-valued or discrete.
    name : str, optional
        Name used when printing; defaults to ``x``-style names for real variables and ``q`` for
        discrete ones.

    Returns
    -------
    RealValuedVariable or DiscreteVariable

    Raises
    ------
    InvalidArgumentError
        For a size below 1 or a name that is not an identifier.
    InvalidTypeError
        For a size that is not an integer or another ``dtype``.
    """
    if dtype is float or dtype is np.float64:
        return RealValuedVariable(size, name=name if name is not None else "x")
    if dtype is int or dtype is np.int64:
        return DiscreteVariable(size, name=name if name is not None else "q")
    raise InvalidTypeError(f"dtype must be float or int, got {dtype!r}")


class ConvexConstraint:
    """Base class of constraints over a real-valued variable (paper Fig. 3)."""

    variable: RealValuedVariable


class LinearPredicate(ConvexConstraint):
    """The half-space ``h' x + c <= 0`` (usually built by comparing expressions: ``x[0] <= 1``).

    Parameters
    ----------
    h : array_like, shape (n,)
        Coefficients (finite).
    c : float
        Constant (finite).
    variable : RealValuedVariable
        The variable ``x`` (dimension ``n``).
    """

    def __init__(self, h: Any, c: float, variable: RealValuedVariable) -> None:
        h = np.asarray(h, dtype=float).reshape(-1)
        if h.shape[0] != variable.size:
            raise DimensionError(f"h must have length {variable.size}, got {h.shape[0]}")
        if not np.all(np.isfinite(h)):
            raise InvalidArgumentError("a linear predicate needs finite coefficients h")
        self.h = h
        self.c = as_float(c, "c")
        self.variable = variable

    @property
    def region(self) -> Any:
        """The half-space as a :class:`~idstlpy.sets.Polytope`."""
        return _remember(Polytope(self.h[None, :], np.array([self.c])), self.variable)

    def __str__(self) -> str:
        return f"{format_affine(self.h, self.c, self.variable.name)} <= 0"

    def __repr__(self) -> str:
        return f"LinearPredicate({self})"

    def __bool__(self) -> bool:
        raise InvalidTypeError(
            "a predicate has no truth value; combine predicates with logical_and / logical_or"
        )

    def _key(self) -> tuple[Any, ...]:
        return (
            tuple(float(v) for v in self.h),
            self.c,
            self.variable.name,
            self.variable.size,
        )

    def __eq__(self, other: object) -> bool:
        if self is other:
            return True
        if not isinstance(other, LinearPredicate) or type(other) is not type(self):
            return False
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash((type(self).__name__, self._key()))


class ProbabilisticLinearPredicate(LinearPredicate):
    """The chance constraint ``prob(h' x + c <= 0) >= 1 - eps`` on a Gaussian belief.

    A belief ``N(m, S)`` satisfies it iff ``h' m + c + Phi^-1(1 - eps) sqrt(h' S h) <= 0``.
    Usually built with :func:`prob`: ``prob(x[0] <= 1) >= 0.95``.

    Parameters
    ----------
    h : array_like, shape (n,)
        Coefficients (finite).
    c : float
        Constant (finite).
    variable : RealValuedVariable
        The variable ``x`` (dimension ``n``).
    eps : float
        Allowed violation probability in ``[0, 0.5]``; ``eps = 0`` demands zero variance
        along ``h``.
    """

    def __init__(self, h: Any, c: float, variable: RealValuedVariable, eps: float) -> None:
        super().__init__(h, c, variable)
        self.eps = as_float(eps, "eps", 0.0, 0.5)

    @property
    def predicate(self) -> LinearPredicate:
        """The deterministic predicate inside ``prob(...)``."""
        return LinearPredicate(self.h, self.c, self.variable)

    def __str__(self) -> str:
        affine = format_affine(self.h, self.c, self.variable.name)
        return f"P[{affine} <= 0] >= {_fmt_num(1 - self.eps)}"

    def _key(self) -> tuple[Any, ...]:
        return (*super()._key(), self.eps)

    def __repr__(self) -> str:
        return f"ProbabilisticLinearPredicate({self})"


class _Probability:
    """``prob(pred)``: waits for ``>= 1 - eps`` to become a chance constraint."""

    def __init__(self, pred: Any) -> None:
        if isinstance(pred, ProbabilisticLinearPredicate):
            raise InvalidTypeError("prob() takes a LinearPredicate, got a chance constraint already")
        if isinstance(pred, ConvexRegion):
            if pred.is_probabilistic:
                raise InvalidTypeError("prob() takes linear predicates, got chance constraints")
            self.preds = list(pred.predicates)
        elif isinstance(pred, LinearPredicate):
            self.preds = [pred]
        else:
            raise InvalidTypeError(
                f"prob() takes a LinearPredicate such as x[0] <= 1, got {type(pred).__name__}"
            )

    def _make(self, level: Any) -> Any:
        p = as_float(level, "probability level (1 - eps)", 0.5, 1.0)
        eps = 1.0 - p
        out = [
            ProbabilisticLinearPredicate(q.h, q.c, q.variable, min(max(eps, 0.0), 0.5)) for q in self.preds
        ]
        if len(out) == 1:
            return out[0]
        return ConvexRegion(out)

    def __ge__(self, level: Any) -> Any:
        return self._make(level)

    __gt__ = __ge__

    def __le__(self, level: Any) -> Any:
        raise InvalidTypeError("write prob(pred) >= 1 - eps; upper bounds on probability are not PrSTL")

    __lt__ = __le__

    def __bool__(self) -> bool:
        raise InvalidTypeError("prob(pred) must be compared: prob(pred) >= 1 - eps")


def prob(pred: LinearPredicate) -> _Probability:
    """Start a chance constraint: ``prob(pred) >= 1 - eps``.

    Parameters
    ----------
    pred : LinearPredicate or ConvexRegion
        ``h' x + c <= 0`` (or a conjunction of them, which gives one chance constraint per face:
        95% on each face of a box is *not* 95% for the box; use :func:`prob_in` for that);
        for example ``x[0] <= 1``.

    Returns
    -------
    object
        Compare it with ``>= 1 - eps`` (``eps`` in ``[0, 0.5]``) to obtain a
        :class:`ProbabilisticLinearPredicate`.
    """
    return _Probability(pred)


class JointChanceConstraint(ConvexConstraint):
    """One confidence for a whole polytope: ``P[x in {H x + c <= 0}] >= 1 - eps``.

    Usually built with :func:`prob_in`: ``prob_in(logical_and(x[0] >= -1, x[0] <= 1)) >= 0.95``.

    A Gaussian belief satisfies it (the monitor's reading, :func:`idstlpy.chance.joint_slack`)
    when Boole's inequality certifies it: the per-face violation probabilities
    ``P[h_f' x + c_f > 0]`` sum to at most ``eps``. That is sound (the region then holds with
    probability at least ``1 - eps``) and is the same as the existence of a risk allocation
    ``eps_f >= 0``, ``sum eps_f <= eps``, under which every face meets its own deterministic
    equivalent ``h_f' m + c_f + Phi^-1(1 - eps_f) sqrt(h_f' S h_f) <= 0``.

    The planner plans against one such allocation, :attr:`shares`: a sufficient condition that
    every part of the solver reads as ordinary chance constraints (:attr:`face_constraints`).
    Unless fixed by the caller (:meth:`with_shares`), the problem chooses the shares for its
    prior (:func:`idstlpy.chance.allocate_shares`).

    Parameters
    ----------
    H : array_like, shape (F, n)
        Face normals (finite, at least one face).
    c : array_like, shape (F,)
        Face offsets (finite).
    variable : RealValuedVariable
        The variable ``x`` (dimension ``n``).
    eps : float
        Allowed probability of leaving the region, in ``[0, 0.5]``.
    shares : array_like, shape (F,), optional
        The risk allocation among the faces (non-negative, summing to at most ``eps``); equal
        shares ``eps / F`` when omitted.
    fixed : bool, default False
        Whether the shares were chosen by the caller (then the problem keeps them).
    """

    def __init__(
        self,
        H: Any,
        c: Any,
        variable: RealValuedVariable,
        eps: float,
        shares: Any = None,
        fixed: bool = False,
    ) -> None:
        if not isinstance(variable, RealValuedVariable):
            raise InvalidTypeError(f"variable must be a RealValuedVariable, got {type(variable).__name__}")
        H = np.atleast_2d(np.asarray(H, dtype=float))
        c = np.atleast_1d(np.asarray(c, dtype=float))
        if H.shape[0] == 0:
            raise InvalidArgumentError("a joint chance constraint needs at least one face")
        if H.shape != (c.shape[0], variable.size):
            raise DimensionError(
                f"H must have shape ({c.shape[0]}, {variable.size}) for {c.shape[0]} faces over "
                f"{variable.name} (size {variable.size}), got {H.shape}"
            )
        if not (np.all(np.isfinite(H)) and np.all(np.isfinite(c))):
            raise InvalidArgumentError("a joint chance constraint needs finite H and c")
        self.H = H
        self.c = c
        self.variable = variable
        self.eps = as_float(eps, "eps", 0.0, 0.5)
        F = H.shape[0]
        if shares is None:
            out = np.full(F, self.eps / F)
        else:
            out = np.asarray(shares, dtype=float).reshape(-1)
            if out.shape != (F,):
                raise DimensionError(f"shares must have length {F} (one per face), got {out.shape[0]}")
            if not np.all(np.isfinite(out)) or np.any(out < 0):
                raise InvalidArgumentError(f"shares must be finite and >= 0, got {out.tolist()}")
            total = float(np.sum(out))
            if total > self.eps * (1 + 1e-9) + 1e-300:
                raise InvalidArgumentError(
                    f"shares must sum to at most eps = {self.eps!r} (Boole's inequality), "
                    f"they sum to {total!r}"
                )
        # Sound by construction: never more than eps in floating point either.
        total = float(np.sum(out))
        if total > self.eps:
            out = out * (self.eps / total) * (1 - 1e-12)
        self.shares = out
        self.fixed = bool(fixed)

    @property
    def num_faces(self) -> int:
        """Number of faces ``F``."""
        return int(self.H.shape[0])

    @property
    def faces(self) -> tuple[LinearPredicate, ...]:
        """The deterministic faces ``h_f' x + c_f <= 0``."""
        return tuple(LinearPredicate(h, float(c), self.variable) for h, c in zip(self.H, self.c, strict=True))

    @property
    def face_constraints(self) -> tuple[JointFace, ...]:
        """The planner's reading: one chance constraint per face at its share (sufficient)."""
        return tuple(JointFace(self, i) for i in range(self.num_faces))

    @property
    def region(self) -> Polytope:
        """The region as a :class:`~idstlpy.sets.Polytope` ``{x : H x + c <= 0}``."""
        return Polytope(self.H, self.c)

    def with_shares(self, shares: Any, fixed: bool = True) -> JointChanceConstraint:
        """The same constraint planned with another risk allocation.

        Parameters
        ----------
        shares : array_like, shape (F,)
            Non-negative per-face risks summing to at most ``eps``.
        fixed : bool, default True
            Keep these shares when a problem is built (``False``: the problem may re-allocate).

        Returns
        -------
        JointChanceConstraint
        """
        return JointChanceConstraint(self.H, self.c, self.variable, self.eps, shares, fixed)

    def __str__(self) -> str:
        body = " & ".join(
            f"{format_affine(h, float(c), self.variable.name)} <= 0"
            for h, c in zip(self.H, self.c, strict=True)
        )
        return f"P[{body}] >= {_fmt_num(1 - self.eps)}"

    def __repr__(self) -> str:
        return f"JointChanceConstraint({self})"

    def __bool__(self) -> bool:
        raise InvalidTypeError("a chance constraint has no truth value; use logical_and / logical_or")

    def _key(self) -> tuple[Any, ...]:
        # The shares are how the planner meets the constraint, not what it means: not in the key.
        return (
            tuple(tuple(float(v) for v in row) for row in self.H),
            tuple(float(v) for v in self.c),
            self.eps,
            self.variable.name,
            self.variable.size,
        )

    def __eq__(self, other: object) -> bool:
        if self is other:
            return True
        if not isinstance(other, JointChanceConstraint):
            return False
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(("JointChanceConstraint", self._key()))


class JointFace(ProbabilisticLinearPredicate):
    """Face ``index`` of a joint chance constraint as the planner reads it: ``eps = shares[index]``.

    Parameters
    ----------
    joint : JointChanceConstraint
        The constraint the face belongs to (``.joint``).
    index : int
        Which face (``.index``).
    """

    def __init__(self, joint: JointChanceConstraint, index: int) -> None:
        super().__init__(joint.H[index], float(joint.c[index]), joint.variable, float(joint.shares[index]))
        self.joint = joint
        self.index = int(index)

    def __str__(self) -> str:
        affine = format_affine(self.h, self.c, self.variable.name)
        return (
            f"{affine} <= 0 (face {self.index + 1} of {self.joint.num_faces}, "
            f"jointly >= {_fmt_num(1 - self.joint.eps)})"
        )

    def __repr__(self) -> str:
        return f"JointFace({self}, planned at {_fmt_num(1 - self.eps)})"


class _JointProbability:
    """``prob_in(region)``: waits for ``>= 1 - eps`` to become a joint chance constraint."""

    def __init__(self, region: Any, variable: Any = None) -> None:
        if isinstance(region, ProbabilisticLinearPredicate | JointChanceConstraint) or (
            isinstance(region, ConvexRegion) and region.is_probabilistic
        ):
            raise InvalidTypeError(
                "prob_in() takes a region of linear predicates (x[0] <= 1, ...), "
                "got chance constraints already"
            )
        if isinstance(region, ConvexRegion):
            preds = list(region.predicates)
            self.H = np.array([p.h for p in preds])
            self.c = np.array([p.c for p in preds])
            self.variable = region.variable
        elif isinstance(region, LinearPredicate):
            self.H, self.c, self.variable = region.h[None, :], np.array([region.c]), region.variable
        elif isinstance(region, Polytope):
            if not isinstance(variable, RealValuedVariable):
                raise InvalidTypeError(
                    "prob_in(polytope, variable): a Polytope needs the state variable it is over "
                    f"(variable=x), got {type(variable).__name__}"
                )
            if region.dim != variable.size:
                raise DimensionError(
                    f"region has dimension {region.dim}, variable {variable.name} has size {variable.size}"
                )
            self.H, self.c, self.variable = np.asarray(region.H), np.asarray(region.c), variable
        else:
            raise InvalidTypeError(
                "prob_in() takes a region such as logical_and(x[0] >= -1, x[0] <= 1) (or a "
                f"Polytope with variable=), got {type(region).__name__}"
            )

    def __ge__(self, level: Any) -> JointChanceConstraint | ProbabilisticLinearPredicate:
        p = as_float(level, "probability level (1 - eps)", 0.5, 1.0)
        eps = min(max(1.0 - p, 0.0), 0.5)
        if self.H.shape[0] == 1:  # one face: the chance constraint itself
            return ProbabilisticLinearPredicate(self.H[0], float(self.c[0]), self.variable, eps)
        return JointChanceConstraint(self.H, self.c, self.variable, eps)

    __gt__ = __ge__

    def __le__(self, level: Any) -> Any:
        raise InvalidTypeError("write prob_in(region) >= 1 - eps; upper bounds on probability are not PrSTL")

    __lt__ = __le__

    def __bool__(self) -> bool:
        raise InvalidTypeError("prob_in(region) must be compared: prob_in(region) >= 1 - eps")


def prob_in(region: Any, variable: RealValuedVariable | None = None) -> _JointProbability:
    """Start a joint chance constraint: ``prob_in(region) >= 1 - eps`` is ``P[x in region] >= 1 - eps``.

    One confidence for the whole region, where ``prob(region) >= 1 - eps`` gives one per face
    (95% on each face of a box holds the box less often than 95%).

    Parameters
    ----------
    region : LinearPredicate, ConvexRegion or Polytope
        The region: a conjunction of linear predicates, e.g.
        ``logical_and(x[0] >= -0.25, x[0] <= 0.25, x[1] >= -0.25, x[1] <= 0.25)`` or
        ``x <= [1, 1]``; a :class:`~idstlpy.sets.Polytope` needs ``variable``.
    variable : RealValuedVariable, optional
        The state variable, for a Polytope only.

    Returns
    -------
    object
        Compare it with ``>= 1 - eps`` (``eps`` in ``[0, 0.5]``) to obtain a
        :class:`JointChanceConstraint` (a :class:`ProbabilisticLinearPredicate` for a region of
        one face).

    Raises
    ------
    InvalidTypeError
        For chance constraints or anything that is not a region of linear predicates.
    """
    return _JointProbability(region, variable)


class DiscreteFormula:
    """A Boolean formula over discrete predicates, kept as the set of modes that satisfy it.

    Built by ``q == k``, ``q != k`` and :func:`~idstlpy.formulas.logical_or` over them; compares
    and hashes by its set of modes and number of values.

    Parameters
    ----------
    modes : iterable of int
        The modes that satisfy the formula.
    num_values : int
        Number of values of the mode variable.
    """

    def __init__(self, modes: Iterable[int], num_values: int) -> None:
        self.num_values = as_int(num_values, "num_values", minimum=1)
        self.modes = frozenset(
            as_int(m, "modes entry", minimum=0, maximum=self.num_values - 1) for m in modes
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, DiscreteFormula):
            return False
        return (self.modes, self.num_values) == (other.modes, other.num_values)

    def __hash__(self) -> int:
        return hash((self.modes, self.num_values))

    def __str__(self) -> str:
        if not self.modes:
            return "false"
        if len(self.modes) == self.num_values:
            return "true"
        return " | ".join(f"q == {m}" for m in sorted(self.modes))

    def __repr__(self) -> str:
        return f"DiscreteFormula({self})"

    def __bool__(self) -> bool:
        raise InvalidTypeError("a discrete predicate has no truth value; use logical_and / logical_or")


class DiscretePredicate(DiscreteFormula):
    """``q == value``: the mode used to arrive at a step is ``value`` (built by ``q == value``).

    Parameters
    ----------
    variable : DiscreteVariable
        The mode variable ``q``.
    value : int
        The mode, in ``0 .. variable.size - 1``.
    """

    def __init__(self, variable: DiscreteVariable, value: Any) -> None:
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise InvalidTypeError(f"mode value must be an int, got {type(value).__name__}")
        if not 0 <= int(value) < variable.size:
            raise OutOfRangeError(
                f"mode value {value} is out of range for {variable.name}, which takes values "
                f"0..{variable.size - 1}"
            )
        super().__init__([int(value)], variable.size)
        self.variable = variable
        self.value = int(value)


class ConvexRegion(ConvexConstraint):
    """A conjunction of linear predicates (or of chance constraints) over one variable.

    ``.region`` is a :class:`~idstlpy.sets.Polytope` for linear predicates and a
    :class:`~idstlpy.sets.BeliefCone` for probabilistic ones.

    Parameters
    ----------
    predicates : iterable of LinearPredicate
        All linear, or all chance constraints, over the same variable (at least one).
    name : str, optional
        A name for the region.
    """

    def __init__(self, predicates: Iterable[LinearPredicate], name: str | None = None) -> None:
        preds = list(predicates)
        if not preds:
            raise InvalidArgumentError("a convex region needs at least one predicate")
        for p in preds:
            if not isinstance(p, LinearPredicate):
                raise InvalidTypeError(f"ConvexRegion takes linear predicates, got {type(p).__name__}")
        kinds = {isinstance(p, ProbabilisticLinearPredicate) for p in preds}
        if len(kinds) > 1:
            raise InvalidTypeError(
                "cannot mix linear predicates and chance constraints in one region; "
                "wrap the linear ones with prob(...) >= 1 - eps"
            )
        variables = {id(p.variable) for p in preds}
        if len(variables) > 1:
            raise InvalidArgumentError("all predicates of a region must be over the same variable")
        self.predicates: Sequence[LinearPredicate] = tuple(preds)
        self.variable: RealValuedVariable = preds[0].variable
        self.name = name

    @property
    def is_probabilistic(self) -> bool:
        """True for a conjunction of chance constraints."""
        return isinstance(self.predicates[0], ProbabilisticLinearPredicate)

    @cached_property
    def region(self) -> Any:
        """The :class:`Polytope` (or :class:`BeliefCone`) the conjunction defines."""
        H = np.array([p.h for p in self.predicates])
        c = np.array([p.c for p in self.predicates])
        if self.is_probabilistic:
            cone = make_belief_cone(H, c, [p.eps for p in self.predicates])  # type: ignore[attr-defined]
            return _remember(cone, self.variable)
        return _remember(make_polytope(H, c), self.variable)

    def __str__(self) -> str:
        return " & ".join(str(p) for p in self.predicates)

    def __repr__(self) -> str:
        return f"ConvexRegion({self})"

    def __bool__(self) -> bool:
        raise InvalidTypeError("a region has no truth value; use logical_and / logical_or")
