"""Automatic translation of stlpy specifications and linear systems into idstlpy problems.

stlpy (0.3) keeps a specification as a tree: leaves are ``LinearPredicate(a, b)`` meaning
``a' y_t - b >= 0`` with the output ``y = C x + D u``; inner nodes are ``STLTree`` objects with a
``combination_type`` ("and" / "or"), a ``subformula_list`` and one time shift per child
(``timesteps``). ``always`` / ``eventually`` / ``until`` are already expanded into such trees:

- ``f.always(t1, t2)``  -> ``and`` over ``[f] * n`` with shifts ``t1 .. t2``;
- ``f.eventually(t1, t2)`` -> the same with ``or``;
- ``f.until(g, t1, t2)`` -> ``or`` (shifts 0) over, for each ``t'`` in ``t1 .. t2``, an ``and``
  of ``[f] * (t' - t1) + [g]`` with shifts ``t1 .. t'``.

The translator recognises these three shapes and maps them back to idstlpy's interval operators
(``always`` / ``eventually`` / ``until``: stlpy's until needs ``f`` on ``[t1, t')`` exactly like
idstlpy's ``f1 U[a,b] f2``); anything else falls back to explicit shifts ``G[t,t] f``. Each
predicate becomes the chance constraint ``prob(-a'C x + b <= 0) >= 1 - eps``; with a noise-free
system and a zero initial covariance every ``eps`` gives the same constraint, so PrSTL reduces to
STL. A predicate that reads the input (``a' D != 0``) has no counterpart over the state and is
refused with :class:`UntranslatableError`.

Nothing here imports stlpy: the translator is duck-typed (``.a``/``.b`` leaves, ``.subformula_list``
/ ``.combination_type`` / ``.timesteps`` nodes), so its pure parts are testable without the peer.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import idstlpy as I
from idstlpy.expressions import ProbabilisticLinearPredicate
from idstlpy.formulas import STLAtomicProposition, STLFormula

__all__ = [
    "UntranslatableError",
    "TranslationStats",
    "Translator",
    "translate_system",
    "make_problem",
    "box_formula",
    "HARD_WEIGHT",
    "stlpy_robustness_reference",
]

EPS = 0.01
"""Confidence slack of every translated chance constraint (irrelevant at zero covariance)."""


class UntranslatableError(ValueError):
    """The stlpy specification or system has no faithful idstlpy counterpart."""


@dataclass
class TranslationStats:
    """Which stlpy shapes the translator recognised."""

    predicates: int = 0
    always: int = 0
    eventually: int = 0
    until: int = 0
    shifted: int = 0
    state_formulas: int = 0


def _is_predicate(node: Any) -> bool:
    return hasattr(node, "a") and hasattr(node, "b") and not hasattr(node, "subformula_list")


def _is_contiguous(ts: Sequence[int]) -> bool:
    return len(ts) >= 1 and all(int(ts[i]) == int(ts[0]) + i for i in range(len(ts)))


class Translator:
    """Translate stlpy formulas over ``y = C x + D u`` to idstlpy formulas over ``x``.

    Parameters
    ----------
    C, D : array_like
        The stlpy output map (``y`` has ``C.shape[0]`` components).
    x : RealValuedVariable, optional
        The idstlpy state variable (created when omitted).
    eps : float
        Slack of each chance constraint.
    """

    def __init__(self, C: Any, D: Any, x: Any = None, eps: float = EPS) -> None:
        self.C = np.asarray(C, dtype=float)
        self.D = np.asarray(D, dtype=float)
        n = self.C.shape[1]
        self.x = x if x is not None else I.mk_variable(n, name="x")
        self.eps = float(eps)
        self.stats = TranslationStats()
        self._memo: dict[int, STLFormula] = {}
        self._pred_memo: dict[int, ProbabilisticLinearPredicate] = {}

    # -- leaves ---------------------------------------------------------------------------------
    def predicate(self, leaf: Any) -> ProbabilisticLinearPredicate:
        """``a' y - b >= 0`` -> ``prob(-(a'C) x + b <= 0) >= 1 - eps``."""
        key = id(leaf)
        if key in self._pred_memo:
            return self._pred_memo[key]
        if not (hasattr(leaf, "a") and hasattr(leaf, "b")):
            raise UntranslatableError(
                f"{type(leaf).__name__} is not a linear predicate (nonlinear predicates are not translated)"
            )
        a = np.asarray(leaf.a, dtype=float).reshape(-1)
        b = float(np.asarray(leaf.b, dtype=float).reshape(-1)[0])
        if a.shape[0] != self.C.shape[0]:
            raise UntranslatableError(f"predicate has dimension {a.shape[0]}, y has {self.C.shape[0]}")
        if self.D.size and np.any(np.abs(a @ self.D) > 0):
            raise UntranslatableError(
                "a predicate reads the control input (a' D != 0); idstlpy predicates are over the state only"
            )
        h = -(a @ self.C)
        if not np.any(h):
            raise UntranslatableError("a predicate does not depend on the state (a' C = 0)")
        out = ProbabilisticLinearPredicate(h, b, self.x, self.eps)
        self._pred_memo[key] = out
        self.stats.predicates += 1
        return out

    # -- trees ----------------------------------------------------------------------------------
    def __call__(self, node: Any) -> STLFormula:
        return self.formula(node)

    def formula(self, node: Any) -> STLFormula:
        """Translate one stlpy node (memoised on object identity, so shared subtrees stay shared)."""
        key = id(node)
        if key in self._memo:
            return self._memo[key]
        if _is_predicate(node):
            out: STLFormula = STLAtomicProposition([self.predicate(node)])
        else:
            out = self._tree(node)
        self._memo[key] = out
        return out

    def _conjunctive_leaves(self, node: Any) -> list[Any] | None:
        """The predicates of a pure conjunction at shift 0, or None."""
        if _is_predicate(node):
            return [node]
        if getattr(node, "combination_type", None) != "and" or any(int(t) != 0 for t in node.timesteps):
            return None
        leaves: list[Any] = []
        for child in node.subformula_list:
            sub = self._conjunctive_leaves(child)
            if sub is None:
                return None
            leaves.extend(sub)
        return leaves

    def _tree(self, node: Any) -> STLFormula:
        kind = node.combination_type
        children = list(node.subformula_list)
        ts = [int(t) for t in node.timesteps]
        if kind not in ("and", "or"):
            raise UntranslatableError(f"unknown combination type {kind!r}")
        # A conjunction of predicates at one instant: one atomic proposition (a polytope).
        leaves = self._conjunctive_leaves(node)
        if leaves is not None:
            self.stats.state_formulas += 1
            return STLAtomicProposition([self.predicate(p) for p in leaves])
        # always / eventually: the same child at contiguous shifts t1..t2.
        if len(children) >= 1 and all(c is children[0] for c in children) and _is_contiguous(ts):
            sub = self.formula(children[0])
            if kind == "and":
                self.stats.always += 1
                return I.always(ts[0], ts[-1], sub)
            self.stats.eventually += 1
            return I.eventually(ts[0], ts[-1], sub)
        until = self._match_until(node) if kind == "or" else None
        if until is not None:
            return until
        # Fallback: explicit shifts of each child.
        parts: list[STLFormula] = []
        for child, t in zip(children, ts, strict=True):
            sub = self.formula(child)
            if t:
                self.stats.shifted += 1
                sub = I.always(t, t, sub) if kind == "and" else I.eventually(t, t, sub)
            parts.append(sub)
        if len(parts) == 1:
            return parts[0]
        return I.logical_and(*parts) if kind == "and" else I.logical_or(*parts)

    def _match_until(self, node: Any) -> STLFormula | None:
        """``or`` (shifts 0) of ``and(f * (t'-t1), g)`` with shifts ``t1..t'`` for ``t' = t1..t2``."""
        if any(int(t) != 0 for t in node.timesteps):
            return None
        branches = list(node.subformula_list)
        left = right = None
        t1 = None
        for i, br in enumerate(branches):
            if getattr(br, "combination_type", None) != "and":
                return None
            subs = list(br.subformula_list)
            ts = [int(t) for t in br.timesteps]
            if len(subs) != i + 1 or not _is_contiguous(ts):
                return None
            if t1 is None:
                t1 = ts[0]
            if ts[0] != t1:
                return None
            if right is None:
                right = subs[-1]
            if subs[-1] is not right:
                return None
            for s in subs[:-1]:
                if left is None:
                    left = s
                if s is not left:
                    return None
        if right is None or t1 is None:
            return None
        t2 = t1 + len(branches) - 1
        self.stats.until += 1
        f2 = self.formula(right)
        if left is None:  # a single branch: g at t1
            return I.eventually(t1, t2, f2)
        return I.until(self.formula(left), t1, t2, f2)


def translate_system(A: Any, B: Any) -> Any:
    """A noise-free idstlpy switched system (one LBS mode with ``W = 0`` and no sensor)."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    return I.mk_switched_sys([I.mk_lbs(A=A, B=B, W=np.zeros((A.shape[0], 1)))])


HARD_WEIGHT = 1e7
"""Weight of the state box's predicates in robustness mode (``make_problem(..., hard_box=True)``)."""


def box_formula(x: Any, low: Any, high: Any, eps: float = EPS, weight: float = 1.0) -> STLAtomicProposition:
    """``low <= x <= high`` as one atomic proposition (infinite bounds are skipped).

    ``weight`` multiplies every predicate (``weight * (x_i - high_i) <= 0``): the same set,
    with a raw slack ``weight`` times the distance to the face.
    """
    low = np.asarray(low, dtype=float)
    high = np.asarray(high, dtype=float)
    w = float(weight)
    preds = []
    n = low.shape[0]
    for i in range(n):
        e = np.zeros(n)
        e[i] = w
        if np.isfinite(low[i]):
            preds.append(ProbabilisticLinearPredicate(-e, w * float(low[i]), x, eps))
        if np.isfinite(high[i]):
            preds.append(ProbabilisticLinearPredicate(e, -w * float(high[i]), x, eps))
    return STLAtomicProposition(preds, name="state_box")


def make_problem(
    spec: Any,
    A: Any,
    B: Any,
    C: Any,
    D: Any,
    x0: Any,
    u_min: Any,
    u_max: Any,
    T: int,
    x_min: Any = None,
    x_max: Any = None,
    eps: float = EPS,
    *,
    hard_box: bool = False,
) -> tuple[Any, Translator]:
    """An idstlpy :class:`~idstlpy.Problem` equivalent to stlpy's MICP problem.

    The state bounds stlpy's examples pass to ``AddStateBounds`` (every ``t`` in ``0..T``)
    become ``G[0,T] box``; the control bounds become the control domain.

    ``hard_box=True`` is for robustness mode: stlpy keeps the box as hard constraints outside
    its ``rho``, whereas idstlpy has only the formula, whose robustness would count the distance
    to the box faces too. The box's predicates are then weighted by :data:`HARD_WEIGHT`: the
    same set, but a raw slack ``HARD_WEIGHT`` times the distance to a face, so the box limits
    the robustness only within ``rho / HARD_WEIGHT`` of its faces (the plan keeps that much
    room inside the box). Every layer of idstlpy (monitor, plan LP, MILP) measures the margin in
    raw slack, so none needs to know. Compare ``robustness(plan, translator(spec))``, the
    specification's own robustness, with stlpy's ``rho``.
    """
    tr = Translator(C, D, eps=eps)
    formula = tr(spec)
    if x_min is not None or x_max is not None:
        n = np.asarray(A).shape[0]
        lo = np.full(n, -np.inf) if x_min is None else np.asarray(x_min, dtype=float)
        hi = np.full(n, np.inf) if x_max is None else np.asarray(x_max, dtype=float)
        weight = HARD_WEIGHT if hard_box else 1.0
        formula = I.logical_and(formula, I.always(0, int(T), box_formula(tr.x, lo, hi, eps, weight)))
    m = np.asarray(B).shape[1]
    u = I.mk_variable(m, name="u")
    lo_u = np.asarray(u_min, dtype=float)
    hi_u = np.asarray(u_max, dtype=float)
    dom = I.logical_and(*[u[i] >= lo_u[i] for i in range(m)], *[u[i] <= hi_u[i] for i in range(m)]).region
    n = np.asarray(A).shape[0]
    problem = I.Problem(
        switched_system=translate_system(A, B),
        control_domain=dom,
        initial_state=I.to_belief(mean=np.asarray(x0, dtype=float), cov=np.zeros((n, n))),
        stl_formula=formula,
    )
    return problem, tr


def stlpy_robustness_reference(node: Any, y: np.ndarray, t: int = 0) -> float:
    """stlpy's robustness recursion (``min`` / ``max`` over children at ``t + shift``).

    Mirrors ``STLTree.robustness``; used by the tests so they need no stlpy. Raises
    ``IndexError`` when the signal is too short, as stlpy asserts.
    """
    if _is_predicate(node):
        if t >= y.shape[1]:
            raise IndexError(f"requested timestep {t}, but y only has {y.shape[1]} timesteps")
        a = np.asarray(node.a, dtype=float).reshape(-1)
        return float(a @ y[:, t] - float(np.asarray(node.b).reshape(-1)[0]))
    vals = [
        stlpy_robustness_reference(c, y, t + int(s))
        for c, s in zip(node.subformula_list, node.timesteps, strict=True)
    ]
    return min(vals) if node.combination_type == "and" else max(vals)
