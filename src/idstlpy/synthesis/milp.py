"""Eager fallback for plans the LP decides exactly: the BMC encoding and the plan LP as one MILP.

When the covariance schedule does not depend on the mean (no state-dependent noise) and the
system has one mode, the lazy loop (SAT proposes, LP refutes) can need many candidates on
formulas with many disjunctions (obstacle sides, alternative targets). This module hands the same
problem to HiGHS' branch and bound in one piece:

- every SAT variable of the BMC encoding is a 0/1 variable, every clause ``l_1 | ... | l_r`` the
  row ``sum(pos) - sum(neg) >= 1 - |neg|``; the clauses learnt so far (pruning facts and
  counterexamples) come along. Only the letters (propositions, modes, trace length) are declared
  integer: the gates are Tseitin equivalences, integral whenever their inputs are, so branch and
  bound never branches on them (measured once each: SteppingStones T = 100 13.4 s -> 1.7 s,
  ReachAvoid T = 200 3.2 s -> 1.9 s, DoorPuzzle T = 100 unchanged);
- ``p[i, k] = 1`` implies the chance constraints of proposition ``i`` at step ``k`` through big-M
  rows whose ``M`` is the exact largest value of the face over the reachable means (support
  functions of the control domain), so the relaxation is as tight as big-M can be;
- the dynamics, the control domain and the fixed covariance schedule are as in the plan LP.

The encoding keeps the compact windows of :mod:`~idstlpy.synthesis.bmc` (``O(H log b)`` gates), so
the model is much smaller than the usual MILP encodings of STL.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, milp
from scipy.sparse import coo_matrix, vstack

from ..formulas import STLAnd, STLAtomicProposition, STLRelease
from .abstraction import Abstraction
from .bmc import BMCEncoder
from .teacher import covariance_schedule

__all__ = ["solve_milp"]

logger = logging.getLogger(__name__)

_TIGHTEN = 1e-6  # HiGHS' feasibility tolerance; the monitor re-checks exactly
_INT_TOL = 2e-6  # above HiGHS' mip_feasibility_tolerance (1e-6): a binary may be off by that much


@contextlib.contextmanager
def _quiet_stdout():
    """Silence HiGHS' C++ debug prints for the duration of a solve (library code never prints)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        yield
        return
    sys.stdout.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


def _control_vertices(U) -> np.ndarray:
    """Vertices of the (bounded) control domain, shape (v, m)."""
    m = U.dim
    if m == 1:
        low, high = U.bounding_box()
        return np.array([[low[0]], [high[0]]])
    from scipy.spatial import HalfspaceIntersection

    center, _ = U.chebyshev_center()
    return HalfspaceIntersection(np.hstack([U.H, U.c[:, None]]), center).intersections


def _invariants(formula, abstraction: Abstraction) -> list[tuple[int, int]]:
    """Propositions the formula requires at every step ``0..b``: ``(atom, b)`` pairs.

    Read off the top-level conjunction: ``always(0, b, ap)`` (or of a conjunction of them).
    """
    parts = formula.children if isinstance(formula, STLAnd) else (formula,)
    out = []
    for f in parts:
        if isinstance(f, STLRelease) and f.a == 0 and f.left.is_false:
            body = f.right.children if isinstance(f.right, STLAnd) else (f.right,)
            for ap in body:
                if isinstance(ap, STLAtomicProposition) and id(ap) in abstraction.index and ap.predicates:
                    out.append((abstraction.index[id(ap)], f.b))
    return out


def _invariant_box(formula, abstraction: Abstraction, n: int, H: int) -> tuple[np.ndarray, np.ndarray]:
    """Per step, the bounding box of the means the invariants allow, shapes (H+1, n)."""
    low, high = np.full((H + 1, n), -np.inf), np.full((H + 1, n), np.inf)
    for i, b in _invariants(formula, abstraction):
        lo_i, hi_i = abstraction.region(i).bounding_box()
        steps = slice(0, min(b, H) + 1)
        low[steps] = np.maximum(low[steps], lo_i)
        high[steps] = np.minimum(high[steps], hi_i)
    return low, high


def solve_milp(
    enc: BMCEncoder,
    abstraction: Abstraction,
    system,
    control_domain,
    mean0: np.ndarray,
    cov0: np.ndarray,
    time_limit: float,
) -> tuple[str, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    """Solve the whole synthesis problem as one MILP (single mode, mean-independent covariance).

    Returns
    -------
    status : {"found", "infeasible", "timeout"}
    actions : ndarray of int, shape (H,), or None
    controls : ndarray, shape (H, m), or None
    claims : ndarray of bool, shape (n_atoms, H+1), or None
        The propositions the MILP's solution claims at each step (its discrete plan).
    """
    H = enc.H
    n, m = system.n, system.m
    mode = system.system_modes[0]
    A, B = mode.A, mode.B
    actions = np.zeros(H, dtype=int)
    covs, exact = covariance_schedule(system, cov0, actions)
    if not exact:
        raise ValueError("the MILP path needs a mean-independent covariance schedule")
    nb = enc.num_vars
    nx, nu = H * n, H * m
    nvar = nb + nx + nu
    ox, ou = nb, nb + nx

    def col_x(k: int) -> int:  # x_k for k >= 1
        return ox + (k - 1) * n

    rows_A, lo, hi = [], [], []

    # Clauses.
    clauses = enc.clauses + enc.learnt
    r_idx, c_idx, vals, rhs = [], [], [], []
    for r, clause in enumerate(clauses):
        neg = 0
        for lit in clause:
            r_idx.append(r)
            c_idx.append(abs(lit) - 1)
            vals.append(1.0 if lit > 0 else -1.0)
            neg += lit < 0
        rhs.append(1.0 - neg)
    if clauses:
        rows_A.append(coo_matrix((vals, (r_idx, c_idx)), shape=(len(clauses), nvar)))
        lo.append(np.array(rhs))
        hi.append(np.full(len(clauses), np.inf))

    # Dynamics x_{k+1} = A x_k + B u_k.
    r_idx, c_idx, vals = [], [], []
    eq = np.zeros(nx)
    ri, ci = np.indices((n, n))
    rb, cb = np.indices((n, m))
    for k in range(H):
        base = k * n
        r_idx.append((base + ri).ravel())
        c_idx.append((col_x(k + 1) + ci).ravel())
        vals.append(np.eye(n).ravel())
        if k >= 1:
            r_idx.append((base + ri).ravel())
            c_idx.append((col_x(k) + ci).ravel())
            vals.append(-A.ravel())
        else:
            eq[:n] = A @ mean0
        r_idx.append((base + rb).ravel())
        c_idx.append((ou + k * m + cb).ravel())
        vals.append(-B.ravel())
    rows_A.append(
        coo_matrix((np.concatenate(vals), (np.concatenate(r_idx), np.concatenate(c_idx))), shape=(nx, nvar))
    )
    lo.append(eq)
    hi.append(eq)

    # Control domain.
    UH, Uc = control_domain.H, control_domain.c
    nU = UH.shape[0]
    ri, ci = np.indices(UH.shape)
    r_idx = np.concatenate([(k * nU + ri).ravel() for k in range(H)])
    c_idx = np.concatenate([(ou + k * m + ci).ravel() for k in range(H)])
    rows_A.append(coo_matrix((np.tile(UH.ravel(), H), (r_idx, c_idx)), shape=(H * nU, nvar)))
    lo.append(np.full(H * nU, -np.inf))
    hi.append(np.tile(-Uc, H))

    # Big-M implications p[i, k] -> faces of proposition i at step k.
    verts = _control_vertices(control_domain)
    F = abstraction.H
    inv_low, inv_high = _invariant_box(enc.formula, abstraction, n, H)
    if F.shape[0]:
        # sup over reachable means of h' x_k = h A^k x0 + sum_j max_v h A^j B v.
        powers = np.empty((H + 1, F.shape[0], n))
        powers[0] = F
        for j in range(1, H + 1):
            powers[j] = powers[j - 1] @ A
        gain = np.einsum("jfn,nm,vm->jfv", powers[:H], B, verts).max(axis=2)  # (H, F)
        reach_max = np.einsum("kfn,n->kf", powers, mean0)
        reach_max[1:] += np.cumsum(gain, axis=0)
        r_idx, c_idx, vals, ub = [], [], [], []
        row = 0
        fi = np.arange(F.shape[0])
        for k in range(1, H + 1):
            var = np.einsum("ij,jk,ik->i", F, covs[k], F)
            sd = np.sqrt(np.maximum(var, 0.0))
            with np.errstate(invalid="ignore"):
                terms = np.where(np.isinf(abstraction.z) & (sd <= 0), 0.0, abstraction.z * sd)
            bound = -(abstraction.c + terms) - _TIGHTEN  # h' x_k <= bound when p holds
            # The tightest bound on h' x_k: reachability, or a region required at every step.
            with np.errstate(invalid="ignore"):
                box_max = np.where(F > 0, F * inv_high[k], F * inv_low[k])
            box_max = np.where(F == 0, 0.0, box_max).sum(axis=1)
            big = np.maximum(np.minimum(reach_max[k], box_max) - bound, 0.0)
            impossible = ~np.isfinite(bound)
            p_cols = enc.p[abstraction.owner, k] - 1
            for f in fi:
                if impossible[f]:
                    # eps = 0 with variance: the proposition cannot hold here.
                    r_idx.append(row)
                    c_idx.append(int(p_cols[f]))
                    vals.append(1.0)
                    ub.append(0.0)
                    row += 1
                    continue
                if big[f] <= 0:
                    continue  # every reachable mean satisfies the face
                r_idx.extend([row] * (n + 1))
                c_idx.extend(list(range(col_x(k), col_x(k) + n)) + [int(p_cols[f])])
                # p within HiGHS' integrality tolerance of 1 must still enforce the face.
                vals.extend(list(F[f]) + [float(big[f]) / (1.0 - _INT_TOL)])
                ub.append(bound[f] + big[f])
                row += 1
        if row:
            rows_A.append(coo_matrix((vals, (r_idx, c_idx)), shape=(row, nvar)))
            lo.append(np.full(row, -np.inf))
            hi.append(np.array(ub))

    A_all = vstack(rows_A).tocsr()
    lower = np.concatenate([np.zeros(nb), np.full(nx + nu, -np.inf)])
    upper = np.concatenate([np.ones(nb), np.full(nx + nu, np.inf)])
    # The trace is the whole horizon: every step exists.
    alive = np.asarray(enc.alive[: H + 1]) - 1
    lower[alive] = 1.0
    upper[enc.alive[H + 1] - 1] = 0.0
    # Only the letters branch: every gate is a full Tseitin equivalence of its inputs, so it is
    # integral whenever they are (a continuous gate in [0, 1] is exact and halves HiGHS' work).
    integrality = np.zeros(nvar)
    for letters in (np.asarray(enc.alive), enc.p.ravel(), enc.m.ravel()):
        integrality[letters - 1] = 1
    logger.info("MILP: %d binaries, %d continuous, %d rows", nb, nx + nu, A_all.shape[0])
    with _quiet_stdout():
        res = milp(
            np.zeros(nvar),
            integrality=integrality,
            bounds=Bounds(lower, upper),
            constraints=LinearConstraint(A_all, np.concatenate(lo), np.concatenate(hi)),
            options={"time_limit": max(time_limit, 0.01), "disp": False},
        )
    if res.status == 0 and res.x is not None:
        controls = res.x[ou:].reshape(H, m)
        claims = np.round(res.x[enc.p - 1]).astype(bool) if enc.p.size else np.zeros((0, H + 1), bool)
        return "found", actions, controls, claims
    if res.status == 2:
        return "infeasible", None, None, None
    logger.info("MILP stopped: %s", res.message)
    return "timeout", None, None, None
