"""Brute-force PrSTL evaluator written directly from the paper's definitions (Section II-C).

Independent of :mod:`idstlpy.semantics`: it walks the formula recursively and loops over the
indices ``k'`` and ``k''`` exactly as the bullet definitions do. Conventions:

- strong finite reading: an index ``>= len(trace)`` satisfies nothing (not even ``true``);
- ``pi^Q`` holds at ``k`` iff ``k == 0`` or ``actions[k-1] in Q``; ``modes=None`` means no
  mode constraint;
- the constant :data:`idstlpy.FALSE` holds nowhere (so ``always(a, b, f) = FALSE R f``), the
  constant :data:`idstlpy.TRUE` holds at every in-range index;
- a chance constraint ``prob(h'x + c <= 0) >= 1 - eps`` on ``N(m, S)`` holds iff
  ``h'm + c + Phi^-1(1 - eps) sqrt(h'Sh) <= 0`` (``scipy.stats.norm.ppf``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.stats import norm

from idstlpy.formulas import (
    FALSE,
    TRUE,
    STLAnd,
    STLAtomicProposition,
    STLFormula,
    STLOr,
    STLRelease,
    STLUntil,
)

__all__ = ["Trace", "chance_holds", "sat"]


@dataclass
class Trace:
    """A belief trace: ``states[k] = (mean_k, cov_k)``; ``actions[k]`` is the mode at ``k``."""

    states: Sequence[tuple[np.ndarray, np.ndarray]]
    actions: Sequence[int]

    def __len__(self) -> int:
        return len(self.states)


def chance_holds(h: np.ndarray, c: float, eps: float, mean: np.ndarray, cov: np.ndarray) -> bool:
    """Deterministic equivalent of ``P(h'x + c <= 0) >= 1 - eps`` for ``x ~ N(mean, cov)``."""
    var = float(h @ cov @ h)
    mu = float(h @ mean) + c
    if eps == 0.0:
        # Probability one: only a degenerate direction can guarantee it.
        return var <= 0.0 and mu <= 0.0
    return mu + float(norm.ppf(1.0 - eps)) * math.sqrt(max(var, 0.0)) <= 0.0


def _atom(f: STLAtomicProposition, k: int, trace: Trace) -> bool:
    if f is FALSE:
        return False
    if f is TRUE:
        return True
    mean, cov = trace.states[k]
    for p in f.predicates:
        if not chance_holds(p.h, p.c, p.eps, mean, cov):
            return False
    if f.modes is not None and not (k == 0 or trace.actions[k - 1] in f.modes):
        return False
    return True


def sat(formula: STLFormula, k: int, trace: Trace) -> bool:
    """``trace |=_k formula`` by the literal definitions."""
    if k >= len(trace):
        return False
    if isinstance(formula, STLAtomicProposition):
        return _atom(formula, k, trace)
    if isinstance(formula, STLAnd):
        return all(sat(c, k, trace) for c in formula.children)
    if isinstance(formula, STLOr):
        return any(sat(c, k, trace) for c in formula.children)
    if isinstance(formula, STLUntil):
        f1, f2, a, b = formula.left, formula.right, formula.a, formula.b
        for k1 in range(k + a, k + b + 1):
            if sat(f2, k1, trace) and all(sat(f1, k2, trace) for k2 in range(k + a, k1)):
                return True
        return False
    if isinstance(formula, STLRelease):
        f1, f2, a, b = formula.left, formula.right, formula.a, formula.b
        for k1 in range(k + a, k + b + 1):
            if sat(f1, k1, trace) and all(sat(f2, k2, trace) for k2 in range(k + a, k1 + 1)):
                return True
        return all(sat(f2, k1, trace) for k1 in range(k + a, k + b + 1))
    raise TypeError(f"unknown formula type {type(formula).__name__}")
