"""The exact LP teacher: controls for a discrete plan, or a proof that there are none.

For a fixed mode sequence the MLO mean is affine in the controls and, when no mode's noise
depends on the state, the covariance schedule is fixed: every chance constraint of the plan is a
linear constraint on the controls, and one LP (scipy's HiGHS) decides the plan exactly. With
state-dependent noise the same LP is run with a *lower bound* on the covariance (the update with
zero observation noise; the Riccati update is monotone in ``R``), which makes it a sound
necessary condition: its infeasibility proofs are still valid counterexamples.

The LP is elastic (one slack per requirement, minimise their sum); when the optimum is positive
the requirements whose rows carry non-zero duals form an infeasible subset (a Farkas
certificate), which the proposer blocks.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog
from scipy.sparse import coo_matrix

from ..belief import kalman_update
from .abstraction import Abstraction
from .plan import DiscretePlan

__all__ = ["LPOutcome", "covariance_schedule", "solve_plan_lp"]

logger = logging.getLogger(__name__)

_FEAS_TOL = 1e-9
_TIGHTEN = 1e-6  # above HiGHS' primal tolerance (1e-7): the monitor's exact re-check passes


@dataclass
class LPOutcome:
    """Result of the plan LP.

    Attributes
    ----------
    feasible : bool
    exact : bool
        True when the covariance schedule is exact (no state-dependent noise on the plan).
    controls : ndarray, shape (K, m), or None
    means : ndarray, shape (K+1, n), or None
        Means of the LP's trajectory (also returned when infeasible: the least-violating one).
    conflict : list of (step, atom)
        An infeasible subset of the requirements (empty when feasible).
    covs : ndarray, shape (K+1, n, n), or None
        The covariance schedule the LP used (exact or lower bound).
    """

    feasible: bool
    exact: bool
    controls: np.ndarray | None
    means: np.ndarray | None
    conflict: list[tuple[int, int]]
    covs: np.ndarray | None = None


def covariance_schedule(system, cov0: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, bool]:
    """Covariances along a mode sequence, exact or a lower bound.

    Returns
    -------
    covs : ndarray, shape (K+1, n, n)
    exact : bool
        False when some mode's noise depends on the state (then ``covs`` is the zero-noise lower
        bound at those steps).
    """
    K = actions.shape[0]
    n = cov0.shape[0]
    covs = np.empty((K + 1, n, n))
    covs[0] = cov0
    exact = True
    modes = system.system_modes
    for k in range(K):
        mode = modes[actions[k]]
        P = mode.A @ covs[k] @ mode.A.T + mode.process_cov
        if mode.p == 0:
            covs[k + 1] = P
        elif mode.has_state_dependent_noise:
            exact = False
            covs[k + 1] = kalman_update(mode, np.zeros(n), P, R=np.zeros((mode.p, mode.p)))[1]
        else:
            covs[k + 1] = kalman_update(mode, np.zeros(n), P)[1]
    return covs, exact


def solve_plan_lp(
    system,
    control_domain,
    mean0: np.ndarray,
    cov0: np.ndarray,
    abstraction: Abstraction,
    plan: DiscretePlan,
    margin: float = 0.0,
    *,
    covs: np.ndarray | None = None,
    anchor: np.ndarray | None = None,
    trust: float = np.inf,
) -> LPOutcome:
    """Find controls that meet every requirement of ``plan`` (see the module docstring).

    With ``margin > 0``, a feasible plan is re-solved to push every required face up to
    ``margin`` (in state units) inside its bound, so the plan survives execution noise; the
    first LP alone would return a vertex on the boundary.

    ``covs`` (shape (K+1, n, n)) replaces the covariance schedule of the modes, e.g. the exact
    covariances of a trajectory under state-dependent noise; the result is then exact only near
    that trajectory, so ``anchor`` (its means, shape (K+1, n)) and ``trust`` bound how far every
    mean may move (infinity norm) in the margin phase.
    """
    n, m = system.n, system.m
    K = plan.num_transitions
    actions = np.asarray(plan.modes[1 : K + 1], dtype=int)
    if covs is None:
        covs, exact = covariance_schedule(system, cov0, actions)
    else:
        exact = False
    reqs = [(k, i) for (k, i) in plan.requirements() if k >= 1 and abstraction.atoms[i].predicates]
    if K == 0:
        return LPOutcome(True, exact, np.zeros((0, m)), mean0[None, :].copy(), [], covs)

    nx, nu, ns = K * n, K * m, len(reqs)
    nvar = nx + nu + ns + 1  # the last column is the uniform margin t of the second phase

    # Dynamics: x_{k+1} - A x_k - B u_k = 0 (x_0 is the fixed initial mean).
    rows, cols, vals = [], [], []
    b_eq = np.zeros(K * n)
    eye = np.eye(n)
    for k in range(K):
        mode = system.system_modes[actions[k]]
        r0 = k * n
        ri, ci = np.indices((n, n))
        rows.append((r0 + ri).ravel())
        cols.append((k * n + ci).ravel())
        vals.append(eye.ravel())
        if k >= 1:
            rows.append((r0 + ri).ravel())
            cols.append(((k - 1) * n + ci).ravel())
            vals.append(-mode.A.ravel())
        else:
            b_eq[:n] = mode.A @ mean0
        rb, cb = np.indices((n, m))
        rows.append((r0 + rb).ravel())
        cols.append((nx + k * m + cb).ravel())
        vals.append(-mode.B.ravel())
    A_eq = coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(K * n, nvar)
    ).tocsr()

    # Inequalities: control domain at every step, then one block of faces per requirement.
    UH, Uc = control_domain.H, control_domain.c
    nU = UH.shape[0]
    rows, cols, vals, rhs = [], [], [], []
    ri, ci = np.indices(UH.shape)
    for k in range(K):
        rows.append((k * nU + ri).ravel())
        cols.append((nx + k * m + ci).ravel())
        vals.append(UH.ravel())
    rhs.append(np.tile(-Uc, K))
    row = K * nU
    owner_rows: list[np.ndarray] = []
    impossible: list[tuple[int, int]] = []
    for r, (k, i) in enumerate(reqs):
        cone = abstraction.atoms[i].cone
        var = np.einsum("ij,jk,ik->i", cone.H, covs[k], cone.H)
        sd = np.sqrt(np.maximum(var, 0.0))
        if np.any(np.isinf(cone.z) & (sd > 0)):
            impossible.append((k, i))
        with np.errstate(invalid="ignore"):
            terms = np.where(np.isinf(cone.z) & (sd <= 0), 0.0, cone.z * sd)
        terms = np.where(np.isfinite(terms), terms, 0.0)
        f = cone.num_faces
        fi, fj = np.indices((f, n))
        rows.append((row + fi).ravel())
        cols.append(((k - 1) * n + fj).ravel())
        vals.append(cone.H.ravel())
        rows.append(row + np.arange(f))
        cols.append(np.full(f, nx + nu + r))
        vals.append(-np.ones(f))
        rows.append(row + np.arange(f))
        cols.append(np.full(f, nvar - 1))
        vals.append(np.linalg.norm(cone.H, axis=1))
        rhs.append(-(cone.c + terms) - _TIGHTEN)
        owner_rows.append(np.full(f, r))
        row += f
    if impossible:
        return LPOutcome(False, exact, None, None, impossible[:1], covs)
    A_ub = coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(row, nvar)
    ).tocsr()
    b_ub = np.concatenate(rhs)
    cost = np.concatenate([np.zeros(nx + nu), np.ones(ns), [0.0]])
    bounds = [(None, None)] * (nx + nu) + [(0, None)] * ns + [(0, 0)]
    res = linprog(cost, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=b_eq, bounds=bounds, method="highs")
    if res.status != 0:
        # The dynamics and control domain alone are infeasible (an empty control set): block the
        # whole plan.
        logger.debug("plan LP status %d: %s", res.status, res.message)
        return LPOutcome(False, exact, None, None, reqs, covs)
    x = res.x
    means = np.vstack([mean0, x[:nx].reshape(K, n)])
    controls = x[nx : nx + nu].reshape(K, m)
    if res.fun <= _FEAS_TOL * max(1, ns):
        if margin > 0 and ns:
            cost2 = np.zeros(nvar)
            cost2[-1] = -1.0
            bounds2 = [(None, None)] * (nx + nu) + [(0, 0)] * ns + [(0, margin)]
            if anchor is not None and np.isfinite(trust):
                ref = np.asarray(anchor)[1 : K + 1].ravel()
                bounds2[:nx] = list(zip(ref - trust, ref + trust, strict=True))
            res2 = linprog(cost2, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=b_eq, bounds=bounds2, method="highs")
            if res2.status == 0:
                x = res2.x
                means = np.vstack([mean0, x[:nx].reshape(K, n)])
                controls = x[nx : nx + nu].reshape(K, m)
        return LPOutcome(True, exact, controls, means, [], covs)
    duals = np.abs(res.ineqlin.marginals[K * nU :])
    owners = np.concatenate(owner_rows) if owner_rows else np.zeros(0, dtype=int)
    involved = sorted(set(owners[duals > 1e-9].tolist()))
    if not involved:
        involved = [r for r in range(ns) if x[nx + nu + r] > _FEAS_TOL]
    conflict = [reqs[r] for r in involved]
    return LPOutcome(False, exact, controls, means, conflict, covs)
