"""An independent, textbook MLO belief roll-out (``algorithm.md`` section 2), for the oracles.

Written from the design notes alone; it does not import :mod:`idstlpy.belief` (nor any other
part of idstlpy), so a bug in the package's roll-out cannot hide in the tests' ground truth.

For a mode ``(A, B, W, C, V)`` with ``R(x) = n(x) n(x)'`` (``n`` is ``V``: a matrix or a callable)::

    mean' = A mean + B u                       (maximum-likelihood observation: zero innovation)
    P     = A cov A' + W W'
    R     = R(mean')                           (noise evaluated at the predicted mean)
    K     = P C' (C P C' + R)^-1
    cov'  = (I - K C) P (I - K C)' + K R K'    (Joseph form)

A mode with no output (``C`` is ``None``) skips the update. The innovation covariance is
inverted with the Moore-Penrose pseudo-inverse, which is the inverse whenever it exists and the
textbook choice when a noise-free sensor meets a zero prediction covariance.

Also here: :func:`loosen`, a copy of a formula whose every chance constraint is relaxed by a
tolerance relative to the trace's magnitudes, so that a plan claimed at margin 0 by the package
is not rejected over a last-bit rounding difference between two correct roll-outs.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .brute_force import Trace

__all__ = ["ModeSpec", "mlo_step", "mlo_rollout", "loosen"]


@dataclass
class ModeSpec:
    """One mode as plain arrays: what the test gave ``mk_lbs``.

    Attributes
    ----------
    A : (n, n) array
    B : (n, m) array
    W : (n, w) array
        Process noise matrix (``W W'`` is the disturbance covariance).
    C : (p, n) array or None
        Output matrix; ``None`` means the mode observes nothing.
    V : (p, r) array, callable ``x -> (p, r)`` array, or None
        Observation noise matrix ``n(x)`` (``None`` with a ``C``: a noise-free sensor).
    """

    A: np.ndarray
    B: np.ndarray
    W: np.ndarray
    C: np.ndarray | None = None
    V: Any = None
    label: str = field(default="")

    @property
    def state_dependent(self) -> bool:
        """True when the observation noise is a function of the state."""
        return self.C is not None and callable(self.V)

    def noise_cov(self, x: np.ndarray) -> np.ndarray:
        """``R(x) = n(x) n(x)'``."""
        assert self.C is not None
        if self.V is None:
            return np.zeros((self.C.shape[0], self.C.shape[0]))
        nx = np.asarray(self.V(x) if callable(self.V) else self.V, dtype=float)
        return nx @ nx.T


def mlo_step(
    mode: ModeSpec, mean: np.ndarray, cov: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One maximum-likelihood-observation Kalman step."""
    A, B, W = mode.A, mode.B, mode.W
    mean_next = A.dot(mean) + B.dot(u)
    P = A.dot(cov).dot(A.T) + W.dot(W.T)
    if mode.C is None:
        return mean_next, P
    C = mode.C
    R = mode.noise_cov(mean_next)
    S = C.dot(P).dot(C.T) + R
    K = P.dot(C.T).dot(np.linalg.pinv(S))
    I_KC = np.eye(P.shape[0]) - K.dot(C)
    cov_next = I_KC.dot(P).dot(I_KC.T) + K.dot(R).dot(K.T)
    return mean_next, 0.5 * (cov_next + cov_next.T)


def mlo_rollout(
    modes: Sequence[ModeSpec],
    mean0: np.ndarray,
    cov0: np.ndarray,
    actions: Sequence[int],
    controls: Any,
) -> Trace:
    """The belief trace ``X_0 .. X_N`` of ``N`` actions and controls, as a brute-force :class:`Trace`."""
    mean = np.array(mean0, dtype=float).reshape(-1)
    cov = np.array(cov0, dtype=float).reshape(mean.size, mean.size)
    acts = [int(a) for a in np.asarray(actions, dtype=int).reshape(-1)]
    m = modes[0].B.shape[1]
    us = np.asarray(controls, dtype=float).reshape(len(acts), m)
    states = [(mean, cov)]
    for q, u in zip(acts, us, strict=True):
        mean, cov = mlo_step(modes[q], mean, cov, u)
        states.append((mean, cov))
    return Trace(states, acts)


def _rebuild(formula: Any, relax: Callable[[Any], Any], memo: dict[int, Any]) -> Any:
    """Copy of ``formula`` with every chance constraint mapped by ``relax`` (constants kept)."""
    from idstlpy.formulas import FALSE, TRUE, STLAnd, STLAtomicProposition, STLOr, STLRelease, STLUntil

    key = id(formula)
    if key in memo:
        return memo[key]
    if formula is TRUE or formula is FALSE:
        out = formula
    elif isinstance(formula, STLAtomicProposition):
        out = STLAtomicProposition([relax(p) for p in formula.predicates], formula.modes, formula.name)
    elif isinstance(formula, STLAnd):
        out = STLAnd([_rebuild(c, relax, memo) for c in formula.children])
    elif isinstance(formula, STLOr):
        out = STLOr([_rebuild(c, relax, memo) for c in formula.children])
    elif isinstance(formula, STLUntil):
        out = STLUntil(
            _rebuild(formula.left, relax, memo), formula.a, formula.b, _rebuild(formula.right, relax, memo)
        )
    elif isinstance(formula, STLRelease):
        out = STLRelease(
            _rebuild(formula.left, relax, memo), formula.a, formula.b, _rebuild(formula.right, relax, memo)
        )
    else:
        raise TypeError(f"unknown formula type {type(formula).__name__}")
    memo[key] = out
    return out


def loosen(formula: Any, trace: Trace, rel: float = 1e-9) -> Any:
    """``formula`` with each face ``h'x + c <= 0`` moved out by ``rel`` times its magnitude on ``trace``.

    The magnitude of a face is ``|c| + |h| (max |mean| + max sd)`` over the trace, so the slack is
    relative to the problem's units (1e-6 or 1e6 alike). Every PrSTL operator is monotone in its
    atoms, so the loosened formula holds wherever the original does.
    """
    from idstlpy.expressions import ProbabilisticLinearPredicate

    mean_mag = max(float(np.max(np.abs(m))) for m, _ in trace.states)
    sd_mag = max(float(np.sqrt(np.max(np.abs(np.diag(S))))) for _, S in trace.states)

    def relax(p: Any) -> Any:
        mag = abs(p.c) + float(np.linalg.norm(p.h)) * (mean_mag + sd_mag)
        return ProbabilisticLinearPredicate(p.h, p.c - rel * mag, p.variable, p.eps)

    return _rebuild(formula, relax, {})
