"""PrSTL formulas (paper Fig. 5) and their constructors.

Grammar (paper Section II-C)::

    phi := pi^mu_eps | pi^Q | phi_1 & phi_2                       (state formulas)
    f   := phi | f_1 & f_2 | f_1 | f_2 | f_1 U[a,b] f_2 | f_1 R[a,b] f_2

A state formula is an :class:`STLAtomicProposition`: a conjunction of chance constraints (a
belief cone) and a set of admissible modes (the Boolean formula over ``q == k`` predicates).
``eventually(a, b, f) = true U[a,b] f`` and ``always(a, b, f) = false R[a,b] f``.

Printing (``str(f)``) uses the text syntax read back by :mod:`idstlpy.syntax`::

    (free_space U[0,240] G[0,40] target)

``repr(f)`` is the same text, shortened for long formulas; in a notebook a formula displays
its text, its horizon and the definitions of its named propositions (``_repr_html_``).

Formulas are immutable values: they compare and hash **structurally**. Two formulas built
separately from the same parts are equal (``==``) and have the same hash; the order of
operands and of a proposition's chance constraints matters, the order of its modes does not;
the state variable counts by its name and size. Equal formulas print identically. The solver
keys its own tables by ``id(formula)``, so two equal sub-formulas stay two nodes there.

Interval bounds ``a <= b`` are integers in ``[0, MAX_BOUND]`` (``MAX_BOUND = 2**53``, the
largest integer a float64 holds exactly), and so is a formula's :attr:`~STLFormula.horizon`
(the sum of the nested ``b`` bounds): the arithmetic on bounds stays exact in int64 and float64.
"""

from __future__ import annotations

import html
from collections.abc import Iterable, Iterator
from functools import cached_property
from typing import Any

import numpy as np

from ._checks import as_int
from .errors import InvalidArgumentError, InvalidTypeError
from .expressions import (
    ConvexRegion,
    DiscreteFormula,
    JointChanceConstraint,
    LinearPredicate,
    ProbabilisticLinearPredicate,
    RealValuedVariable,
    _fmt_num,
    format_affine,
)
from .sets import BeliefCone, make_belief_cone

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
    "MAX_BOUND",
    "logical_and",
    "logical_or",
    "until",
    "eventually",
    "release",
    "always",
    "as_formula",
    "format_formula",
    "format_atom",
    "allocate_joint_risk",
    "map_joints",
    "map_atoms",
]

MAX_BOUND = 2**53
"""Largest interval bound (and formula horizon) accepted: ``2**53``."""

_REPR_LIMIT = 200  # characters of repr(formula) before it is shortened
_HTML_LIMIT = 4000  # characters of formula text shown by _repr_html_


def _shorten(text: str, limit: int = _REPR_LIMIT) -> str:
    """``text`` itself, or its head and tail around `` ... `` when longer than ``limit``."""
    if len(text) <= limit:
        return text
    tail = max(limit // 5, 10)
    head = limit - tail - 5
    return f"{text[:head]} ... {text[-tail:]}"


class STLFormula:
    """Base class of PrSTL formulas.

    Formulas are immutable, compare and hash structurally (see the module documentation) and
    combine with ``&`` (:func:`logical_and`) and ``|`` (:func:`logical_or`).
    """

    children: tuple[STLFormula, ...] = ()

    @property
    def horizon(self) -> int:
        """Number of steps after the evaluation instant the formula can look at."""
        raise NotImplementedError

    def atomic_propositions(self) -> list[STLAtomicProposition]:
        """The distinct atomic propositions (state formulas), in order of first appearance.

        Distinct means distinct objects: two equal propositions built separately are both
        listed (the solver gives each its own letter).
        """
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

    # -- structural equality ------------------------------------------------------------------
    # Both walk the tree with an explicit stack: deep formulas do not hit the recursion limit.
    def _local(self) -> tuple[Any, ...]:
        """The fields that define the node itself (its children aside)."""
        raise NotImplementedError

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, STLFormula):
            return False
        pairs: list[tuple[STLFormula, STLFormula]] = [(self, other)]
        seen: set[tuple[int, int]] = set()  # shared sub-formulas are compared once
        while pairs:
            f, g = pairs.pop()
            if f is g or (id(f), id(g)) in seen:
                continue
            seen.add((id(f), id(g)))
            if (
                type(f) is not type(g)
                or hash(f) != hash(g)
                or len(f.children) != len(g.children)
                or f._local() != g._local()
            ):
                return False
            pairs.extend(zip(f.children, g.children, strict=True))
        return True

    def __hash__(self) -> int:
        cached = self.__dict__.get("_hash")
        if cached is not None:
            return int(cached)
        stack: list[STLFormula] = [self]
        while stack:  # post-order: a node is hashed once its children are
            node = stack[-1]
            pending = [c for c in node.children if "_hash" not in c.__dict__]
            if pending:
                stack.extend(pending)
                continue
            stack.pop()
            node.__dict__["_hash"] = hash(
                (type(node).__name__, node._local(), tuple(c.__dict__["_hash"] for c in node.children))
            )
        return int(self.__dict__["_hash"])

    def __getstate__(self) -> dict[str, Any]:
        # str hashes are salted per process: a cached hash must not travel with a pickle.
        state = dict(self.__dict__)
        state.pop("_hash", None)
        return state

    # -- operators ----------------------------------------------------------------------------
    def __and__(self, other: Any) -> STLFormula:
        return logical_and(self, other)

    def __or__(self, other: Any) -> STLFormula:
        return logical_or(self, other)

    def __bool__(self) -> bool:
        raise InvalidTypeError("a formula has no truth value; evaluate it on a trajectory")

    # -- printing -----------------------------------------------------------------------------
    def __repr__(self) -> str:
        return _shorten(str(self))

    def __str__(self) -> str:
        return format_formula(self)

    def _repr_html_(self) -> str:
        """Notebook display: the text, the horizon and the named propositions' definitions."""
        text = str(self)
        rows: dict[str, str] = {}
        for ap in self.atomic_propositions():
            if ap.name is not None and ap._constant is None:
                definition = _shorten(format_atom(ap, use_name=False), _HTML_LIMIT)
                rows.setdefault(
                    ap.name + definition,
                    f"<tr><td><code>{html.escape(ap.name)}</code></td>"
                    f"<td><code>{html.escape(definition)}</code></td></tr>",
                )
        table = (
            "<table><tr><th>proposition</th><th>definition</th></tr>" + "".join(rows.values()) + "</table>"
            if rows
            else ""
        )
        return (
            f"<div><code>{html.escape(_shorten(text, _HTML_LIMIT))}</code>"
            f"<br><small>{type(self).__name__}, horizon {self.horizon} steps</small>"
            f"{table}</div>"
        )


def _predicate_key(p: ProbabilisticLinearPredicate) -> tuple[Any, ...]:
    return (tuple(float(v) for v in p.h), float(p.c), float(p.eps), p.variable.name, p.variable.size)


class STLAtomicProposition(STLFormula):
    """A state formula: chance constraints on the belief and a set of admissible modes.

    Holds at step ``k`` iff the belief ``X_k`` meets its chance constraints and joint chance
    constraints and (for ``k >= 1``) the mode ``q_{k-1}`` used to arrive at ``X_k`` is in
    :attr:`modes`. Usually built with :func:`logical_and`
    (``logical_and(prob(x[0] <= 1) >= 0.95, q == 0, name="goal")``).

    :attr:`predicates` lists the proposition's own chance constraints followed by the faces of
    its joint constraints at their planned shares (:attr:`JointChanceConstraint.face_constraints`):
    :attr:`cone`, the solver's reading, is a sufficient condition for the proposition. The
    monitor (:func:`idstlpy.semantics.atom_margins`) judges each joint constraint as a whole.

    Parameters
    ----------
    predicates : iterable of ProbabilisticLinearPredicate
        The chance constraints (may be empty: no constraint on the belief).
    modes : iterable of int, optional
        Admissible modes (non-negative integers); ``None`` means every mode.
    name : str, optional
        Name used when printing and in plans (a Python identifier).
    joints : iterable of JointChanceConstraint, optional
        Joint chance constraints ``P[x in region] >= 1 - eps`` (one confidence per region).
    """

    def __init__(
        self,
        predicates: Iterable[ProbabilisticLinearPredicate] = (),
        modes: Iterable[int] | None = None,
        name: str | None = None,
        *,
        joints: Iterable[JointChanceConstraint] = (),
        _constant: bool | None = None,
    ) -> None:
        preds = _as_tuple(predicates, "predicates", "an iterable of chance constraints")
        for p in preds:
            if not isinstance(p, ProbabilisticLinearPredicate):
                raise InvalidTypeError(
                    f"an atomic proposition takes chance constraints prob(pred) >= 1 - eps, "
                    f"got {type(p).__name__}"
                )
        jts = _as_tuple(joints, "joints", "an iterable of joint chance constraints")
        for j in jts:
            if not isinstance(j, JointChanceConstraint):
                raise InvalidTypeError(
                    f"joints takes joint chance constraints prob_in(region) >= 1 - eps, "
                    f"got {type(j).__name__}"
                )
        self.joints: tuple[JointChanceConstraint, ...] = jts
        self.num_single = len(preds)
        preds = preds + tuple(f for j in jts for f in j.face_constraints)
        if len({id(p.variable) for p in preds}) > 1:
            raise InvalidArgumentError("all chance constraints of a proposition must be over one variable")
        if name is not None and (not isinstance(name, str) or not name.isidentifier()):
            raise InvalidArgumentError(f"name must be an identifier such as 'free_space', got {name!r}")
        self.predicates: tuple[ProbabilisticLinearPredicate, ...] = preds
        self.modes: frozenset[int] | None = (
            None
            if modes is None
            else frozenset(
                as_int(m, "modes entry", minimum=0)
                for m in _as_tuple(modes, "modes", "an iterable of mode indices (ints)")
            )
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
        """Always 0: a state formula looks at the current step only."""
        return 0

    def _local(self) -> tuple[Any, ...]:
        return (
            self._constant,
            self.name,
            self.modes,
            tuple(_predicate_key(p) for p in self.predicates[: self.num_single]),
            tuple(j._key() for j in self.joints),
        )

    def __repr__(self) -> str:
        if self.name is None or self._constant is not None:
            return _shorten(str(self))
        return _shorten(f"{self.name} := {format_atom(self, use_name=False)}")


def _as_tuple(value: Any, name: str, expected: str) -> tuple[Any, ...]:
    if isinstance(value, str | bytes):
        raise InvalidTypeError(f"{name} must be {expected}, got {type(value).__name__}")
    try:
        return tuple(value)
    except TypeError as exc:
        raise InvalidTypeError(f"{name} must be {expected}, got {type(value).__name__}") from exc


TRUE = STLAtomicProposition(name="true", _constant=True)
"""The proposition that holds at every step of a trajectory (``pi^Q``)."""
FALSE = STLAtomicProposition(modes=(), name="false", _constant=False)
"""The proposition that holds nowhere.

Read literally, ``pi^{}`` would hold at ``k = 0`` (mode atoms are vacuous there), which would
make ``always(0, b, f)`` collapse to ``f`` at step 0. ``always = false R`` means the constant, so
every evaluator treats :data:`FALSE` as false at every step; a user's empty mode set keeps the
literal reading.
"""


class _Junction(STLFormula):
    """Shared code of :class:`STLAnd` and :class:`STLOr`."""

    def __init__(self, children: Iterable[Any]) -> None:
        kind = type(self).__name__
        items = _as_tuple(children, "children", "an iterable of formulas")
        self.children = tuple(as_formula(c, f"{kind} operand {i}") for i, c in enumerate(items))
        if len(self.children) < 2:
            raise InvalidArgumentError(f"{kind} needs at least two operands, got {len(self.children)}")
        self._horizon = max(c.horizon for c in self.children)

    @property
    def horizon(self) -> int:
        """The largest horizon of the operands."""
        return self._horizon

    def _local(self) -> tuple[Any, ...]:
        return ()


class STLAnd(_Junction):
    """Conjunction of formulas (usually built with :func:`logical_and` or ``f1 & f2``).

    Parameters
    ----------
    children : iterable of STLFormula
        At least two operands (chance constraints and mode formulas are made propositions).
    """


class STLOr(_Junction):
    """Disjunction of formulas (usually built with :func:`logical_or` or ``f1 | f2``).

    Parameters
    ----------
    children : iterable of STLFormula
        At least two operands (chance constraints and mode formulas are made propositions).
    """


class STLTemporalFormula(STLFormula):
    """Base class of the interval operators ``f1 U[a,b] f2`` and ``f1 R[a,b] f2``.

    Parameters
    ----------
    left : STLFormula
        The left operand ``f1`` (a chance constraint or mode formula is made a proposition).
    a : int
        Start of the interval, in steps: ``0 <= a <= b``.
    b : int
        End of the interval, in steps: ``b <= MAX_BOUND`` (``2**53``).
    right : STLFormula
        The right operand ``f2``.
    """

    symbol = "?"

    def __init__(self, left: Any, a: Any, b: Any, right: Any) -> None:
        self.a = _as_bound(a, "a")
        self.b = _as_bound(b, "b")
        if self.a > self.b:
            raise InvalidArgumentError(f"interval [a, b] needs a <= b, got a={self.a}, b={self.b}")
        self.left = as_formula(left, "left operand")
        self.right = as_formula(right, "right operand")
        self.children = (self.left, self.right)
        self._horizon = self.b + max(self.left.horizon, self.right.horizon)
        if self._horizon > MAX_BOUND:
            raise InvalidArgumentError(
                f"the formula's horizon b + (operands' horizon) = {self.b} + "
                f"{self._horizon - self.b} = {self._horizon} exceeds MAX_BOUND = 2**53"
            )

    @property
    def horizon(self) -> int:
        """``b`` plus the larger horizon of the operands."""
        return self._horizon

    def _local(self) -> tuple[Any, ...]:
        return (self.a, self.b)


def _as_bound(value: Any, name: str) -> int:
    out = as_int(value, name, minimum=0)
    if out > MAX_BOUND:
        raise InvalidArgumentError(
            f"interval bound {name} must be <= MAX_BOUND = 2**53 = {MAX_BOUND}, got {_fmt_big(out)}"
        )
    return out


def _fmt_big(value: int) -> str:
    text = str(value)
    return text if len(text) <= 40 else f"{text[:20]}... ({len(text)} digits)"


class STLUntil(STLTemporalFormula):
    """``f1 U[a,b] f2``: some ``k'`` in ``[k+a, k+b]`` has ``f2``; ``f1`` holds on ``[k+a, k')``.

    Usually built with :func:`until` or :func:`eventually`.

    Parameters
    ----------
    left : STLFormula
        ``f1``, which must hold until ``f2`` does (from ``k + a`` on).
    a : int
        Start of the interval, in steps: ``0 <= a <= b``.
    b : int
        End of the interval, in steps: ``b <= MAX_BOUND`` (``2**53``).
    right : STLFormula
        ``f2``, which must hold at some step of ``[k + a, k + b]``.
    """

    symbol = "U"


class STLRelease(STLTemporalFormula):
    """``f1 R[a,b] f2``: ``f2`` on ``[k+a, k+b]``, or up to and including a ``k'`` with ``f1``.

    Usually built with :func:`release` or :func:`always`.

    Parameters
    ----------
    left : STLFormula
        ``f1``, which releases ``f2`` at the first step it holds.
    a : int
        Start of the interval, in steps: ``0 <= a <= b``.
    b : int
        End of the interval, in steps: ``b <= MAX_BOUND`` (``2**53``).
    right : STLFormula
        ``f2``, which must hold on ``[k + a, k + b]`` until released.
    """

    symbol = "R"


def as_formula(value: Any, what: str = "argument") -> STLFormula:
    """Coerce a chance constraint, a region of them or a mode formula to a formula.

    Parameters
    ----------
    value : STLFormula, ProbabilisticLinearPredicate, ConvexRegion or DiscreteFormula
        A formula (returned as is), a chance constraint or a region of them (made a
        proposition), or a mode formula such as ``q == 1`` (made a proposition over modes).
    what : str
        How error messages name ``value`` (e.g. ``"left operand"``).

    Returns
    -------
    STLFormula

    Raises
    ------
    InvalidTypeError
        For a deterministic predicate (no confidence stated) or anything else.
    """
    if isinstance(value, STLFormula):
        return value
    if isinstance(value, ProbabilisticLinearPredicate):
        return STLAtomicProposition([value])
    if isinstance(value, JointChanceConstraint):
        return STLAtomicProposition(joints=[value])
    if isinstance(value, ConvexRegion) and value.is_probabilistic:
        return STLAtomicProposition(value.predicates)  # type: ignore[arg-type]
    if isinstance(value, DiscreteFormula):
        return STLAtomicProposition((), value.modes)
    if isinstance(value, LinearPredicate | ConvexRegion):
        raise InvalidTypeError(
            f"{what}: a deterministic predicate ({value}) is not a PrSTL formula; "
            "state a confidence with prob(pred) >= 1 - eps"
        )
    raise InvalidTypeError(f"{what} must be a PrSTL formula or predicate, got {type(value).__name__}")


def _operands(args: tuple[Any, ...], func: str) -> tuple[Any, ...]:
    """The operands of ``func(*args)``; a single list or tuple stands for its items."""
    if len(args) == 1 and isinstance(args[0], list | tuple):
        args = tuple(args[0])
    if not args:
        raise InvalidArgumentError(f"{func} needs at least one argument")
    return args


def logical_and(*args: Any, name: str | None = None) -> Any:
    """Conjunction (paper ``logical_and(*args)``).

    The result depends on what is combined:

    - linear predicates only: a :class:`ConvexRegion` (its ``.region`` is a polytope);
    - chance constraints only, no name: a :class:`ConvexRegion` of them (a belief cone);
    - chance constraints and mode predicates, or a ``name``: an :class:`STLAtomicProposition`;
    - anything temporal: an :class:`STLAnd` (state parts merged into one proposition).

    Parameters
    ----------
    *args : predicates, chance constraints, mode formulas or formulas
        The operands, given one by one or as a single list or tuple
        (``logical_and(p1, p2)`` and ``logical_and([p1, p2])`` are the same).
    name : str, optional
        Name of the resulting state formula (an identifier such as ``"free_space"``); the
        operands must then be state parts (chance constraints, mode formulas, unnamed
        propositions).

    Returns
    -------
    ConvexRegion, STLAtomicProposition or STLAnd

    Raises
    ------
    InvalidArgumentError
        Without operands.
    InvalidTypeError
        For an operand that is not a predicate or formula, or deterministic predicates mixed
        with PrSTL parts.
    """
    args = _operands(args, "logical_and")
    linear: list[LinearPredicate] = []
    chance: list[ProbabilisticLinearPredicate] = []
    joints: list[JointChanceConstraint] = []
    modes: frozenset[int] | None = None
    formulas: list[STLFormula] = []
    has_state_formula = False
    for i, arg in enumerate(args):
        if isinstance(arg, ProbabilisticLinearPredicate):
            chance.append(arg)
        elif isinstance(arg, JointChanceConstraint):
            joints.append(arg)
            has_state_formula = True
        elif isinstance(arg, LinearPredicate):
            linear.append(arg)
        elif isinstance(arg, ConvexRegion):
            (chance if arg.is_probabilistic else linear).extend(arg.predicates)  # type: ignore[arg-type]
        elif isinstance(arg, DiscreteFormula):
            modes = arg.modes if modes is None else modes & arg.modes
            has_state_formula = True
        elif isinstance(arg, STLAtomicProposition) and arg.name is None:
            chance.extend(arg.predicates[: arg.num_single])
            joints.extend(arg.joints)
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
        state = STLAtomicProposition(chance, modes, name=name, joints=joints)
    parts = ([state] if state is not None else []) + formulas
    if len(parts) == 1:
        return parts[0]
    return STLAnd(_flatten(parts, STLAnd))


def logical_or(*args: Any, name: str | None = None) -> Any:
    """Disjunction (paper ``logical_or(*args)``).

    Over mode predicates only it gives a mode formula (a set of modes); otherwise an
    :class:`STLOr` of the arguments as formulas.

    Parameters
    ----------
    *args : mode formulas, chance constraints or formulas
        The operands, given one by one or as a single list or tuple
        (``logical_or(f1, f2)`` and ``logical_or([f1, f2])`` are the same).
    name : str, optional
        Only over mode predicates: name the set of modes as a state formula.

    Returns
    -------
    DiscreteFormula, STLAtomicProposition or STLOr

    Raises
    ------
    InvalidArgumentError
        Without operands, or with a ``name`` for operands that are not mode predicates.
    InvalidTypeError
        For an operand that is not a formula (deterministic predicates included).
    """
    args = _operands(args, "logical_or")
    if all(isinstance(a, DiscreteFormula) for a in args):
        modes: frozenset[int] = frozenset().union(*(a.modes for a in args))
        out = DiscreteFormula(modes, max(a.num_values for a in args))
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
    """``formula1 U[a,b] formula2`` (paper ``until``).

    Holds at step ``k`` iff ``formula2`` holds at some ``k'`` in ``[k + a, k + b]`` and
    ``formula1`` holds at every step of ``[k + a, k')`` (``formula1`` is needed only from
    ``k + a``).

    Parameters
    ----------
    formula1 : STLFormula
        The formula that must hold until ``formula2`` does (a chance constraint, a region of
        them or a mode formula is made a proposition).
    a : int
        Start of the interval, in steps (``0 <= a <= b``).
    b : int
        End of the interval, in steps (at most :data:`MAX_BOUND` ``= 2**53``).
    formula2 : STLFormula
        The formula that must eventually hold.

    Returns
    -------
    STLUntil

    Raises
    ------
    InvalidTypeError
        For bounds that are not integers, or operands that are not formulas.
    InvalidArgumentError
        For bounds outside ``0 <= a <= b <= 2**53`` or a horizon beyond ``2**53``.
    """
    return STLUntil(formula1, a, b, formula2)


def eventually(a: int, b: int, formula: Any) -> STLUntil:
    """``F[a,b] formula = true U[a,b] formula`` (paper ``eventually``).

    Parameters
    ----------
    a : int
        Start of the interval, in steps (``0 <= a <= b``).
    b : int
        End of the interval, in steps (at most :data:`MAX_BOUND` ``= 2**53``).
    formula : STLFormula
        The formula that must hold at some step of ``[k + a, k + b]``.

    Returns
    -------
    STLUntil
        With :data:`TRUE` on the left.

    Raises
    ------
    InvalidTypeError, InvalidArgumentError
        As :func:`until`.
    """
    return STLUntil(TRUE, a, b, formula)


def release(formula1: Any, a: int, b: int, formula2: Any) -> STLRelease:
    """``formula1 R[a,b] formula2`` (paper ``release``).

    Holds at step ``k`` iff ``formula2`` holds at every step of ``[k + a, k + b]``, or up to
    and including a step of that interval where ``formula1`` holds.

    Parameters
    ----------
    formula1 : STLFormula
        The releasing formula.
    a : int
        Start of the interval, in steps (``0 <= a <= b``).
    b : int
        End of the interval, in steps (at most :data:`MAX_BOUND` ``= 2**53``).
    formula2 : STLFormula
        The formula that must hold until released.

    Returns
    -------
    STLRelease

    Raises
    ------
    InvalidTypeError, InvalidArgumentError
        As :func:`until`.
    """
    return STLRelease(formula1, a, b, formula2)


def always(a: int, b: int, formula: Any) -> STLRelease:
    """``G[a,b] formula = false R[a,b] formula`` (paper ``always``).

    Parameters
    ----------
    a : int
        Start of the interval, in steps (``0 <= a <= b``).
    b : int
        End of the interval, in steps (at most :data:`MAX_BOUND` ``= 2**53``).
    formula : STLFormula
        The formula that must hold at every step of ``[k + a, k + b]``.

    Returns
    -------
    STLRelease
        With :data:`FALSE` on the left.

    Raises
    ------
    InvalidTypeError, InvalidArgumentError
        As :func:`until`.
    """
    return STLRelease(FALSE, a, b, formula)


# ------------------------------------------------------------------------------------------------
# printing: the text syntax of idstlpy.syntax (which reads it back and re-exports these)
# ------------------------------------------------------------------------------------------------


def format_atom(ap: STLAtomicProposition, use_name: bool = True) -> str:
    """Text of an atomic proposition: its name, or its definition in braces.

    Parameters
    ----------
    ap : STLAtomicProposition
        The proposition to print.
    use_name : bool
        Print a named proposition by name (default) or by its definition.

    Returns
    -------
    str
        ``true``, ``false``, the name, or ``{P[... <= 0] >= p & q == k}``.
    """
    if not isinstance(ap, STLAtomicProposition):
        raise InvalidTypeError(f"ap must be an STLAtomicProposition, got {type(ap).__name__}")
    if ap._constant is True:
        return "true"
    if ap._constant is False:
        return "false"
    if use_name and ap.name is not None:
        return ap.name
    items = [
        f"P[{format_affine(p.h, p.c, p.variable.name)} <= 0] >= {_fmt_num(1.0 - p.eps)}"
        for p in ap.predicates[: ap.num_single]
    ]
    items.extend(str(j) for j in ap.joints)
    if ap.modes is not None:
        if not ap.modes:
            items.append("false")
        else:
            modes = " | ".join(f"q == {m}" for m in sorted(ap.modes))
            items.append(f"({modes})" if len(ap.modes) > 1 else modes)
    return "{" + " & ".join(items) + "}"


def format_formula(formula: STLFormula) -> str:
    """The text of ``formula`` (named propositions print by name); ``str(formula)`` calls it.

    Parameters
    ----------
    formula : STLFormula
        The formula to print.

    Returns
    -------
    str
        Text that :func:`idstlpy.syntax.parse_formula` reads back to a formula printing
        identically.
    """
    if isinstance(formula, STLAtomicProposition):
        return format_atom(formula)
    if isinstance(formula, STLAnd | STLOr):
        op = " & " if isinstance(formula, STLAnd) else " | "
        return "(" + op.join(format_formula(c) for c in formula.children) + ")"
    if isinstance(formula, STLUntil):
        if isinstance(formula.left, STLAtomicProposition) and formula.left._constant is True:
            return f"F[{formula.a},{formula.b}] {format_formula(formula.right)}"
        return f"({format_formula(formula.left)} U[{formula.a},{formula.b}] {format_formula(formula.right)})"
    if isinstance(formula, STLRelease):
        if isinstance(formula.left, STLAtomicProposition) and formula.left.is_false:
            return f"G[{formula.a},{formula.b}] {format_formula(formula.right)}"
        return f"({format_formula(formula.left)} R[{formula.a},{formula.b}] {format_formula(formula.right)})"
    raise InvalidTypeError(f"cannot format {type(formula).__name__}: not a PrSTL formula")


def map_atoms(formula: STLFormula, fn: Any) -> STLFormula:
    """The formula with every non-constant atomic proposition ``ap`` replaced by ``fn(ap)``.

    Sub-formulas where nothing changed are shared (the formula itself is returned when ``fn``
    changed nothing); a sub-formula shared in ``formula`` stays shared.

    Parameters
    ----------
    formula : STLFormula
    fn : callable
        ``STLAtomicProposition -> STLAtomicProposition`` (return ``ap`` itself to keep it).

    Returns
    -------
    STLFormula
    """
    memo: dict[int, STLFormula] = {}

    def rec(f: STLFormula) -> STLFormula:
        key = id(f)
        if key in memo:
            return memo[key]
        out: STLFormula = f
        if isinstance(f, STLAtomicProposition):
            if f._constant is None:
                out = fn(f)
        else:
            kids = tuple(rec(c) for c in f.children)
            if any(k is not c for k, c in zip(kids, f.children, strict=True)):
                if isinstance(f, STLTemporalFormula):
                    out = type(f)(kids[0], f.a, f.b, kids[1])
                elif isinstance(f, STLAnd | STLOr):
                    out = type(f)(kids)
        memo[key] = out
        return out

    return rec(formula)


def map_joints(formula: STLFormula, fn: Any) -> STLFormula:
    """The formula with every joint chance constraint ``j`` of a proposition replaced by ``fn(j)``.

    Parameters
    ----------
    formula : STLFormula
    fn : callable
        ``JointChanceConstraint -> JointChanceConstraint`` (the same faces and ``eps``: only the
        planned shares may differ, so the result equals ``formula``).

    Returns
    -------
    STLFormula
        ``formula`` itself when no joint constraint changed (see :func:`map_atoms`).
    """
    if not any(ap.joints for ap in formula.atomic_propositions()):
        return formula

    def atom(ap: STLAtomicProposition) -> STLAtomicProposition:
        if not ap.joints:
            return ap
        joints = [fn(j) for j in ap.joints]
        if all(a is b for a, b in zip(joints, ap.joints, strict=True)):
            return ap
        return STLAtomicProposition(ap.predicates[: ap.num_single], ap.modes, name=ap.name, joints=joints)

    return map_atoms(formula, atom)


def allocate_joint_risk(formula: STLFormula, cov: Any) -> STLFormula:
    """The formula with every joint chance constraint's shares chosen for beliefs shaped like ``cov``.

    Each :class:`JointChanceConstraint` that the caller did not fix
    (:meth:`~JointChanceConstraint.with_shares`) gets the allocation of
    :func:`idstlpy.chance.allocate_shares`. The result is equal to ``formula`` (the shares are
    how the solver plans, not what the formula means) and shares its sub-formulas where nothing
    changed; a formula without joint constraints is returned as is.

    Parameters
    ----------
    formula : STLFormula
    cov : array_like, shape (n, n)
        The covariance whose shape the allocation assumes (a problem passes its prior's).

    Returns
    -------
    STLFormula
    """
    from .chance import allocate_shares

    cov = np.asarray(cov, dtype=float)

    def fn(j: JointChanceConstraint) -> JointChanceConstraint:
        if j.fixed:
            return j
        return j.with_shares(allocate_shares(j.H, j.c, j.eps, cov), fixed=False)

    return map_joints(formula, fn)
