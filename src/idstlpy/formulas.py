"""PrSTL formulas (paper Fig. 5) and their constructors.

Grammar (paper Section II-C)::

    phi := pi^mu_eps | pi^Q | phi_1 & phi_2                       (state formulas)
    f   := phi | f_1 & f_2 | f_1 | f_2 | f_1 U[a,b] f_2 | f_1 R[a,b] f_2

A state formula is an :class:`STLAtomicProposition`: a conjunction of chance constraints (a
belief cone) and a set of admissible modes (the Boolean formula over ``q == k`` predicates).
``eventually(a, b, f) = true U[a,b] f`` and ``always(a, b, f) = false R[a,b] f``.

Printing (``str(f)``) uses the text syntax read back by :mod:`idstlpy.syntax`::

    (free_space U[0,240] G[0,40] target)
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from functools import cached_property
from typing import Any

import numpy as np

from ._checks import as_int
from .errors import InvalidArgumentError, InvalidTypeError
from .expressions import (
    DiscreteFormula,
    LinearPredicate,
    ProbabilisticLinearPredicate,
    RealValuedVariable,
)
from .sets import BeliefCone, ConvexRegion, make_belief_cone

__all__ = [
    "STLFormula",
    "STLAtomicProposition",
    "STLAnd",
    "STLOr",
    "STLTemporalFormula",
    "STLUntil",
    "STLRelease",
    "TRUE",
    "FALSE",
    "logical_and",
    "logical_or",
    "until",
    "eventually",
    "release",
    "always",
    "as_formula",
]


class STLFormula:
    """Base class of PrSTL formulas."""

    children: tuple[STLFormula, ...] = ()

    @property
    def horizon(self) -> int:
        """Number of steps after the evaluation instant the formula can look at."""
        raise NotImplementedError

    def atomic_propositions(self) -> list[STLAtomicProposition]:
        """The distinct atomic propositions (state formulas), in order of first appearance."""
        seen: dict[int, STLAtomicProposition] = {}
        for node in self.walk():
            if isinstance(node, STLAtomicProposition) and id(node) not in seen:
                seen[id(node)] = node
        return list(seen.values())

    def walk(self) -> Iterator[STLFormula]:
        """Pre-order traversal of the formula tree."""
        stack: list[STLFormula] = [self]
        while stack:
            node = stack.pop()
            yield node
            stack.extend(reversed(node.children))

    def __and__(self, other: Any) -> STLFormula:
        return logical_and(self, other)

    def __or__(self, other: Any) -> STLFormula:
        return logical_or(self, other)

    def __bool__(self) -> bool:
        raise InvalidTypeError("a formula has no truth value; evaluate it on a trajectory")

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self})"

    def __str__(self) -> str:
        from .syntax import format_formula

        return format_formula(self)


class STLAtomicProposition(STLFormula):
    """A state formula: chance constraints on the belief and a set of admissible modes.

    Holds at step ``k`` iff the belief ``X_k`` lies in :attr:`cone` and (for ``k >= 1``) the mode
    ``q_{k-1}`` used to arrive at ``X_k`` is in :attr:`modes`.

    Parameters
    ----------
    predicates : iterable of ProbabilisticLinearPredicate
        The chance constraints (may be empty: no constraint on the belief).
    modes : iterable of int, optional
        Admissible modes; ``None`` means every mode.
    name : str, optional
        Name used when printing and in plans.
    """

    def __init__(
        self,
        predicates: Iterable[ProbabilisticLinearPredicate] = (),
        modes: Iterable[int] | None = None,
        name: str | None = None,
        *,
        _constant: bool | None = None,
    ) -> None:
        preds = tuple(predicates)
        for p in preds:
            if not isinstance(p, ProbabilisticLinearPredicate):
                raise InvalidTypeError(
                    f"an atomic proposition takes chance constraints prob(pred) >= 1 - eps, "
                    f"got {type(p).__name__}"
                )
        if len({id(p.variable) for p in preds}) > 1:
            raise InvalidArgumentError(
                "all chance constraints of a proposition must be over one variable"
            )
        if name is not None and (not isinstance(name, str) or not name.isidentifier()):
            raise InvalidArgumentError(
                f"name must be an identifier such as 'free_space', got {name!r}"
            )
        self.predicates: tuple[ProbabilisticLinearPredicate, ...] = preds
        self.modes: frozenset[int] | None = (
            None if modes is None else frozenset(int(m) for m in modes)
        )
        self.name = name
        self._constant = _constant

    @property
    def variable(self) -> RealValuedVariable | None:
        """The state variable the chance constraints are written over (None without any)."""
        return self.predicates[0].variable if self.predicates else None

    @cached_property
    def cone(self) -> BeliefCone:
        """The belief cone of the chance constraints (no faces when there are none)."""
        if not self.predicates:
            n = 0
            return BeliefCone(np.zeros((0, n)), np.zeros(0), np.zeros(0))
        return make_belief_cone(
            np.array([p.h for p in self.predicates]),
            np.array([p.c for p in self.predicates]),
            np.array([p.eps for p in self.predicates]),
        )

    @property
    def is_true(self) -> bool:
        """True for a proposition with no constraint at all (``pi^Q``: holds on the whole trace)."""
        return self._constant is True or (not self.predicates and self.modes is None)

    @property
    def is_false(self) -> bool:
        """True for the constant :data:`FALSE`, which holds nowhere."""
        return self._constant is False

    @property
    def horizon(self) -> int:
        return 0


TRUE = STLAtomicProposition(name="true", _constant=True)
"""The proposition that holds at every step of a trajectory (``pi^Q``)."""
FALSE = STLAtomicProposition(modes=(), name="false", _constant=False)
"""The proposition that holds nowhere.

Read literally, ``pi^{}`` would hold at ``k = 0`` (mode atoms are vacuous there), which would
make ``always(0, b, f)`` collapse to ``f`` at step 0. ``always = false R`` means the constant, so
every evaluator treats :data:`FALSE` as false at every step; a user's empty mode set keeps the
literal reading.
"""


class STLAnd(STLFormula):
    """Conjunction of formulas."""

    def __init__(self, children: Iterable[STLFormula]) -> None:
        self.children = tuple(children)
        if len(self.children) < 2:
            raise InvalidArgumentError("STLAnd needs at least two operands")

    @property
    def horizon(self) -> int:
        return max(c.horizon for c in self.children)


class STLOr(STLFormula):
    """Disjunction of formulas."""

    def __init__(self, children: Iterable[STLFormula]) -> None:
        self.children = tuple(children)
        if len(self.children) < 2:
            raise InvalidArgumentError("STLOr needs at least two operands")

    @property
    def horizon(self) -> int:
        return max(c.horizon for c in self.children)


class STLTemporalFormula(STLFormula):
    """Base class of the interval operators ``f1 U[a,b] f2`` and ``f1 R[a,b] f2``."""

    symbol = "?"

    def __init__(self, left: Any, a: Any, b: Any, right: Any) -> None:
        self.a = as_int(a, "a", minimum=0)
        self.b = as_int(b, "b", minimum=0)
        if self.a > self.b:
            raise InvalidArgumentError(f"interval [a, b] needs a <= b, got a={self.a}, b={self.b}")
        self.left = as_formula(left, "left operand")
        self.right = as_formula(right, "right operand")
        self.children = (self.left, self.right)

    @property
    def horizon(self) -> int:
        return self.b + max(self.left.horizon, self.right.horizon)


class STLUntil(STLTemporalFormula):
    """``f1 U[a,b] f2``: some ``k'`` in ``[k+a, k+b]`` has ``f2``; ``f1`` holds on ``[k+a, k')``."""

    symbol = "U"


class STLRelease(STLTemporalFormula):
    """``f1 R[a,b] f2``: ``f2`` on ``[k+a, k+b]``, or up to and including a ``k'`` with ``f1``."""

    symbol = "R"


def as_formula(value: Any, what: str = "argument") -> STLFormula:
    """Coerce a chance constraint, a region of them or a mode formula to a formula."""
    if isinstance(value, STLFormula):
        return value
    if isinstance(value, ProbabilisticLinearPredicate):
        return STLAtomicProposition([value])
    if isinstance(value, ConvexRegion) and value.is_probabilistic:
        return STLAtomicProposition(value.predicates)  # type: ignore[arg-type]
    if isinstance(value, DiscreteFormula):
        return STLAtomicProposition((), value.modes)
    if isinstance(value, LinearPredicate | ConvexRegion):
        raise InvalidTypeError(
            f"{what}: a deterministic predicate ({value}) is not a PrSTL formula; "
            "state a confidence with prob(pred) >= 1 - eps"
        )
    raise InvalidTypeError(
        f"{what} must be a PrSTL formula or predicate, got {type(value).__name__}"
    )


def logical_and(*args: Any, name: str | None = None) -> Any:
    """Conjunction (paper ``logical_and(*args)``).

    - linear predicates only: a :class:`ConvexRegion` (its ``.region`` is a polytope);
    - chance constraints only, no name: a :class:`ConvexRegion` of them (a belief cone);
    - chance constraints and mode predicates, or a ``name``: an :class:`STLAtomicProposition`;
    - anything temporal: an :class:`STLAnd` (state parts merged into one proposition).
    """
    if not args:
        raise InvalidArgumentError("logical_and needs at least one argument")
    linear: list[LinearPredicate] = []
    chance: list[ProbabilisticLinearPredicate] = []
    modes: frozenset[int] | None = None
    formulas: list[STLFormula] = []
    has_state_formula = False
    for i, arg in enumerate(args):
        if isinstance(arg, ProbabilisticLinearPredicate):
            chance.append(arg)
        elif isinstance(arg, LinearPredicate):
            linear.append(arg)
        elif isinstance(arg, ConvexRegion):
            (chance if arg.is_probabilistic else linear).extend(arg.predicates)  # type: ignore[arg-type]
        elif isinstance(arg, DiscreteFormula):
            modes = arg.modes if modes is None else modes & arg.modes
            has_state_formula = True
        elif isinstance(arg, STLAtomicProposition) and arg.name is None:
            chance.extend(arg.predicates)
            if arg.modes is not None:
                modes = arg.modes if modes is None else modes & arg.modes
            has_state_formula = True
        elif isinstance(arg, STLFormula):
            formulas.append(arg)
        else:
            raise InvalidTypeError(
                f"logical_and argument {i} must be a predicate or formula, got {type(arg).__name__}"
            )
    if linear and (chance or formulas or has_state_formula):
        raise InvalidTypeError(
            "logical_and mixes deterministic predicates with PrSTL parts; "
            "state a confidence with prob(pred) >= 1 - eps"
        )
    if linear:
        return ConvexRegion(linear, name=name)
    if chance and not has_state_formula and not formulas and name is None:
        return ConvexRegion(chance)
    state = None
    if chance or has_state_formula or name is not None:
        state = STLAtomicProposition(chance, modes, name=name)
    parts = ([state] if state is not None else []) + formulas
    if len(parts) == 1:
        return parts[0]
    return STLAnd(_flatten(parts, STLAnd))


def logical_or(*args: Any, name: str | None = None) -> Any:
    """Disjunction (paper ``logical_or(*args)``).

    Over mode predicates only it gives a mode formula (a set of modes); otherwise an
    :class:`STLOr` of the arguments as formulas.
    """
    if not args:
        raise InvalidArgumentError("logical_or needs at least one argument")
    if all(isinstance(a, DiscreteFormula) for a in args):
        modes = frozenset().union(*(a.modes for a in args))
        out = DiscreteFormula(modes, args[0].num_values)
        if name is not None:
            return STLAtomicProposition((), modes, name=name)
        return out
    if name is not None:
        raise InvalidArgumentError("name= is only for state formulas (logical_and / mode sets)")
    parts = [as_formula(a, f"logical_or argument {i}") for i, a in enumerate(args)]
    if len(parts) == 1:
        return parts[0]
    return STLOr(_flatten(parts, STLOr))


def _flatten(parts: list[STLFormula], cls: type) -> list[STLFormula]:
    out: list[STLFormula] = []
    for p in parts:
        out.extend(p.children if isinstance(p, cls) else [p])
    return out


def until(formula1: Any, a: int, b: int, formula2: Any) -> STLUntil:
    """``formula1 U[a,b] formula2`` (``formula1`` needed only from ``k + a``)."""
    return STLUntil(formula1, a, b, formula2)


def eventually(a: int, b: int, formula: Any) -> STLUntil:
    """``F[a,b] formula = true U[a,b] formula``."""
    return STLUntil(TRUE, a, b, formula)


def release(formula1: Any, a: int, b: int, formula2: Any) -> STLRelease:
    """``formula1 R[a,b] formula2``."""
    return STLRelease(formula1, a, b, formula2)


def always(a: int, b: int, formula: Any) -> STLRelease:
    """``G[a,b] formula = false R[a,b] formula``."""
    return STLRelease(FALSE, a, b, formula)
