"""Bounds on the eager MILP's reachable means: the big-M of its faces and the margin's cap.

Single mode, mean-independent covariance (the only problems :func:`~.milp.solve_milp` builds):
from the control domain's support function and the dynamics, every face's largest (and least)
value over the reachable means at each step, and the box the formula's invariants (propositions
it requires at every step of a prefix) leave to the means. :mod:`.milp_model` turns these into
big-M rows whose ``M`` is as small as the reachable set allows; :func:`margin_cap` bounds every
plan's robustness, which caps the margin column of ``objective="margin"``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse import csr_matrix

from .. import _deadline as deadline
from ..backends import HighsBackend, LinearModel
from ..chance import std_terms
from ..formulas import STLAnd, STLAtomicProposition, STLFormula, STLRelease
from ..semantics import formula_margins
from .abstraction import Abstraction

if TYPE_CHECKING:
    from ..sets import Polytope

__all__ = [
    "SupportPoints",
    "contains_zero",
    "hard_steps",
    "invariant_box",
    "margin_cap",
    "state_boxes",
    "support",
    "support_points",
]

SupportPoints = tuple[np.ndarray | None, np.ndarray, np.ndarray]
"""The control domain's vertices (``None`` when unavailable) and its bounding box ``(low, high)``."""


def contains_zero(U: Polytope) -> bool:
    """Whether ``u = 0`` lies in the control domain ``{u : H u + c <= 0}`` (exactly)."""
    return bool(np.all(np.asarray(U.c) <= 0.0))


def support_points(U: Polytope) -> SupportPoints:
    """Vertices of the control domain (``None`` when unavailable) and its bounding box."""
    low, high = U.bounding_box()
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
        return None, low, high
    if U.dim == 1:
        return np.array([[low[0]], [high[0]]]), low, high
    if getattr(U, "is_full_dimensional", False):
        from scipy.spatial import HalfspaceIntersection, QhullError

        try:
            center, _ = U.chebyshev_center()
            return HalfspaceIntersection(np.hstack([U.H, U.c[:, None]]), center).intersections, low, high
        except (QhullError, ValueError):
            pass
    return None, low, high


def support(points: SupportPoints, D: np.ndarray) -> np.ndarray:
    """``max_{u in U} d'u`` for every row ``d`` of ``D`` (an upper bound; ``inf`` if unbounded).

    Exact from the vertices of a bounded, full-dimensional domain; for flat domains (where
    Qhull fails) the bounding box gives a sound over-estimate.
    """
    verts, low, high = points
    if verts is not None:
        return np.asarray((D @ verts.T).max(axis=1))
    with np.errstate(invalid="ignore"):
        box = np.where(D > 0, D * high, D * low)
    return np.asarray(np.where(D == 0, 0.0, box).sum(axis=1))


def _invariants(formula: STLFormula, abstraction: Abstraction) -> list[tuple[int, int]]:
    """Propositions the formula requires at every step ``0..b``: ``(atom, b)`` pairs.

    Read off the top-level conjunction: ``always(0, b, ap)`` (or of a conjunction of them).
    """
    parts = formula.children if isinstance(formula, STLAnd) else (formula,)
    out = []
    for f in parts:
        if (
            isinstance(f, STLRelease)
            and f.a == 0
            and isinstance(f.left, STLAtomicProposition)
            and f.left.is_false
        ):
            body = f.right.children if isinstance(f.right, STLAnd) else (f.right,)
            for ap in body:
                if isinstance(ap, STLAtomicProposition) and id(ap) in abstraction.index and ap.predicates:
                    out.append((abstraction.index[id(ap)], f.b))
    return out


def invariant_box(
    formula: STLFormula, abstraction: Abstraction, n: int, H: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per step, the bounding box of the means the invariants allow, shapes (H+1, n)."""
    low, high = np.full((H + 1, n), -np.inf), np.full((H + 1, n), np.inf)
    for i, b in _invariants(formula, abstraction):
        lo_i, hi_i = abstraction.bounds(i)
        steps = slice(0, min(b, H) + 1)
        low[steps] = np.maximum(low[steps], lo_i)
        high[steps] = np.minimum(high[steps], hi_i)
    return low, high


def hard_steps(formula: STLFormula, abstraction: Abstraction, H: int) -> np.ndarray:
    """``hard[k, i]``: the invariants require proposition ``i`` at step ``k``; shape (H+1, n_atoms)."""
    hard = np.zeros((H + 1, abstraction.num_atoms), dtype=bool)
    for i, b in _invariants(formula, abstraction):
        hard[: min(b, H) + 1, i] = True
    return hard


def state_boxes(
    A: np.ndarray,
    B: np.ndarray,
    points: SupportPoints,
    mean0: np.ndarray,
    inv_low: np.ndarray,
    inv_high: np.ndarray,
    H: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Per step, a box holding every mean that meets the invariants up to it, shapes (H+1, n).

    Interval propagation ``x_{k+1} in A box_k + B U``, intersected with the invariants' box at
    every step: an over-approximation (sound for big-M), tighter than the invariants' box alone
    where the dynamics cannot reach its far side. Infinite where nothing bounds a coordinate.
    """
    n = mean0.shape[0]
    low, high = np.empty((H + 1, n)), np.empty((H + 1, n))
    low[0] = high[0] = mean0
    b_high = support(points, B)
    b_low = -support(points, -B)
    Ap, An = np.maximum(A, 0.0), np.minimum(A, 0.0)

    def prod(M: np.ndarray, v: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            P = M * v[None, :]
        return np.asarray(np.where(M == 0, 0.0, P).sum(axis=1))

    for k in range(1, H + 1):
        if not k % 256:
            deadline.check("building the MILP")
        with np.errstate(invalid="ignore"):
            lo_k = prod(Ap, low[k - 1]) + prod(An, high[k - 1]) + b_low
            hi_k = prod(Ap, high[k - 1]) + prod(An, low[k - 1]) + b_high
        lo_k = np.where(np.isnan(lo_k), -np.inf, lo_k)
        hi_k = np.where(np.isnan(hi_k), np.inf, hi_k)
        low[k] = np.maximum(lo_k, inv_low[k])
        high[k] = np.minimum(hi_k, inv_high[k])
        # An empty box means no plan meets the invariants (the hard rows say so); keep it ordered.
        high[k] = np.maximum(high[k], low[k])
    return low, high


def _common_slack(Hf: np.ndarray, bound: np.ndarray) -> float:
    """``max s`` such that ``h_f' x + s <= bound_f`` for every face ``f`` (``inf`` if unbounded)."""
    if not np.all(np.isfinite(bound)):
        return float(np.min(bound)) if np.any(bound == -np.inf) else np.inf
    nf, n = Hf.shape
    A = csr_matrix(np.hstack([Hf, np.ones((nf, 1))]))
    c = np.zeros(n + 1)
    c[-1] = -1.0
    model = LinearModel(c, A, np.full(nf, -np.inf), bound, np.full(n + 1, -np.inf), np.full(n + 1, np.inf))
    sol = HighsBackend().solve(model, 10.0)
    if sol.status == "optimal" and sol.x is not None:
        # The LP's own tolerance must not make the cap cut the optimum.
        return float(sol.x[-1]) + 1e-9 * max(1.0, abs(float(sol.x[-1])))
    if sol.status == "infeasible":
        return -np.inf
    return np.inf


def margin_cap(
    formula: STLFormula,
    abstraction: Abstraction,
    covs: np.ndarray,
    reach_min: np.ndarray,
    box_low: np.ndarray,
    box_high: np.ndarray,
    H: int,
) -> tuple[float, bool]:
    """An upper bound on the robustness of every plan of ``H + 1`` steps, and whether it is finite.

    Each face's slack at step ``k`` is at most its bound minus the least value the face takes
    over the reachable means (support functions, and the box the invariants leave); the
    monitor's min / max recursion is monotone, so evaluating it on those per-proposition bounds
    bounds the robustness itself (single mode: the arriving mode is 0).
    """
    F = abstraction.H
    L = H + 1
    face_ub = np.empty((L, F.shape[0]))
    for k in range(L):
        bound = -(abstraction.c + std_terms(F, abstraction.z, covs[k]))
        with np.errstate(invalid="ignore"):
            box_min = np.where(F > 0, F * box_low[k], F * box_high[k])
        box_min = np.where(F == 0, 0.0, box_min).sum(axis=1)
        face_ub[k] = bound - np.maximum(reach_min[k], box_min)
    face_ub = np.where(np.isnan(face_ub), np.inf, face_ub)
    atoms: dict[int, np.ndarray] = {}
    widest = np.max([-(abstraction.c + std_terms(F, abstraction.z, covs[k])) for k in range(L)], axis=0)
    for i, ap in enumerate(abstraction.atoms):
        faces = abstraction.owner == i
        ub = face_ub[:, faces].min(axis=1) if faces.any() else np.full(L, np.inf)
        if np.sum(faces) > 1:
            # The faces cannot all have their largest slack at once: the largest common slack
            # over the whole space (at the widest bounds of any step) bounds every step.
            ub = np.minimum(ub, _common_slack(F[faces], widest[faces]))
        if ap.modes is not None and 0 not in ap.modes:
            ub[1:] = -np.inf
        atoms[id(ap)] = ub
    cap = float(formula_margins(formula, atoms, L)[0])
    if not np.isfinite(cap):
        return 0.0, False
    return max(cap, 0.0), True
