"""The risk allocation chosen inside an LP, for one discrete plan and mode sequence.

For a fixed mode sequence (and noise that does not depend on the state) the covariance schedule
is fixed and the means are affine in the controls. A joint chance constraint at step ``k`` then
reads, by Boole's bound (the monitor's reading),

    sum_f Phi(-q_f) <= eps,   q_f = -(h_f' m_k + c_f) / sigma_f,   sigma_f = sqrt(h_f' P_k h_f),

which is convex in the controls: ``g(q) = Phi(-q)`` is convex for ``q >= 0``, and every face
must have ``q_f >= Phi^-1(1 - eps) > 0`` anyway (a face alone at ``eps``, for ``eps < 0.5``).
The LP here replaces ``g`` by an *inner* piecewise-linear approximation: an epigraph variable
``r_f`` above every chord of ``g`` between breakpoints ``q_0 = Phi^-1(1 - eps) < q_1 < ... <
q_N`` (a chord of a convex function lies above it between its ends, and the chords' maximum is
the interpolant), above ``g(q_N)`` beyond the last one, and ``sum_f r_f <= eps``. Every point of
the LP therefore meets the joint constraint exactly (``sum_f g(q_f) <= sum_f r_f <= eps``); the
breakpoints' values are rounded up so that floating point keeps the chords above ``g``. Each
step gets its own per-face risks: the allocation is optimised with the controls.

:func:`allocation_for_plan` solves this LP for the discrete plan of a relaxation's trajectory and
turns the per-step risks it used into one allocation per joint constraint (the largest risk each
face needed over the steps, scaled to ``eps``): the shares the CEGIS loop then plans with
(:func:`idstlpy.synthesis.allocation.search_allocation`). Nothing here is trusted: the returned
shares are only a choice, the plan that comes of them is checked by the monitor.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import linprog
from scipy.sparse import coo_matrix
from scipy.special import ndtr

from ..chance import quantile
from ..expressions import JointChanceConstraint
from ..formulas import STLFormula, map_joints
from .abstraction import Abstraction
from .covariances import covariance_schedule
from .plan import trajectory_plan

if TYPE_CHECKING:
    from ..problem import Problem
    from ..trajectory import ProbabilisticTSTrajectory

__all__ = ["RiskLP", "allocation_for_plan", "chord_rows", "optimise_risks"]

logger = logging.getLogger(__name__)

_RATIO = 0.7  # breakpoints where the tail is eps, 0.7 eps, 0.49 eps, ...
_POINTS = 40  # ... down to about 6e-7 eps
_FLOOR = 1e-6  # no face's share below this fraction of eps (a zero share needs zero variance)


def chord_rows(eps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Chords of ``g(q) = Phi(-q)`` above it on ``[Phi^-1(1 - eps), q_N]`` (``0 < eps <= 0.5``).

    Returns
    -------
    slopes, intercepts : ndarray, shape (N,)
        ``r >= slopes[l] * q + intercepts[l]`` for every ``l`` implies ``r >= g(q)`` on the range.
    q : ndarray, shape (N + 1,)
        The breakpoints.
    last : float
        ``g(q_N)`` rounded up: ``r >= last`` bounds ``g`` beyond the last breakpoint.
    """
    q = quantile(eps * _RATIO ** np.arange(_POINTS + 1))
    q = np.maximum(q, 0.0)
    g = ndtr(-q) * (1 + 1e-12) + 1e-300  # rounded up: the chords stay above g
    slopes = np.diff(g) / np.diff(q)
    intercepts = g[:-1] - slopes * q[:-1]
    return slopes, intercepts, q, float(g[-1])


@dataclass(frozen=True)
class RiskLP:
    """The allocation LP's answer for one discrete plan.

    Attributes
    ----------
    means : ndarray, shape (K + 1, n)
        The MLO means of the LP's controls (``means[0]`` the prior's).
    covs : ndarray, shape (K + 1, n, n)
        The mode sequence's covariance schedule (a lower bound under state-dependent noise).
    controls : ndarray, shape (K, m)
    actions : ndarray of int, shape (K,)
    uses : list of (JointChanceConstraint, int)
        Every joint constraint the plan requires, with the step (``>= 1``) it is required at.
    """

    means: np.ndarray
    covs: np.ndarray
    controls: np.ndarray
    actions: np.ndarray
    uses: list[tuple[JointChanceConstraint, int]]


def allocation_for_plan(
    problem: Problem, relaxed: STLFormula, traj: ProbabilisticTSTrajectory
) -> STLFormula | None:
    """Shares for ``problem``'s joint constraints from the discrete plan of ``traj``.

    Each face gets the largest risk it used in :func:`optimise_risks`'s answer over the steps,
    scaled so that the shares sum to ``eps`` (at least ``1e-6 eps`` each).

    Parameters
    ----------
    problem, relaxed, traj
        As in :func:`optimise_risks`.

    Returns
    -------
    STLFormula or None
        The original formula with new shares (not fixed), or ``None`` when
        :func:`optimise_risks` has no answer.
    """
    lp = optimise_risks(problem, relaxed, traj)
    if lp is None:
        return None
    need: dict[int, np.ndarray] = {}
    for joint, k in lp.uses:
        d = -(joint.H @ lp.means[k] + joint.c)
        sd = np.sqrt(np.maximum(np.einsum("fi,ij,fj->f", joint.H, lp.covs[k], joint.H), 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            tails = np.where(sd > 0, ndtr(-d / sd), 0.0)
        prev = need.get(id(joint))
        need[id(joint)] = tails if prev is None else np.maximum(prev, tails)

    def fn(joint: JointChanceConstraint) -> JointChanceConstraint:
        u = need.get(id(joint))
        if u is None or joint.fixed or joint.num_faces < 2:
            return joint
        u = np.maximum(u, _FLOOR * joint.eps)
        return joint.with_shares(joint.eps * u / float(np.sum(u)), fixed=False)

    return map_joints(problem.stl_formula, fn)


def optimise_risks(problem: Problem, relaxed: STLFormula, traj: ProbabilisticTSTrajectory) -> RiskLP | None:
    """Controls and per-step, per-face risks for the discrete plan of ``traj``, in one LP.

    Parameters
    ----------
    problem : Problem
        The original problem (its formula's joint constraints are read by Boole's bound).
    relaxed : STLFormula
        The relaxation ``traj`` was planned for (:func:`~.allocation.relax_joints`): its
        propositions are the original ones, position for position.
    traj : ProbabilisticTSTrajectory
        A plan of the relaxation: its mode sequence and the requirements its earliest witness
        needs are kept; the controls are chosen anew.

    Returns
    -------
    RiskLP or None
        ``None`` when the plan has no witness, the LP is infeasible, or no joint constraint is
        required after step 0. Otherwise every required joint constraint's Boole sum at the
        LP's beliefs is at most its ``eps`` (the chords bound the tail from above), up to the
        LP solver's feasibility tolerance.
    """
    formula = problem.stl_formula
    system = problem.switched_system
    n, m = system.n, system.m
    abs_r = Abstraction(relaxed, n)
    abs_o = Abstraction(formula, n)
    if abs_r.num_atoms != abs_o.num_atoms:
        return None
    plan = trajectory_plan(relaxed, abs_r, traj)
    if plan is None:
        return None
    actions = np.asarray(plan.modes[1 : plan.length], dtype=int)
    K = int(actions.shape[0])
    reqs = [(k, i) for (k, i) in plan.requirements() if k >= 1 and abs_o.atoms[i].predicates]
    # Step 0's requirements are the prior's: no rows, and no say in the shares either (labels and
    # the MILP's step-0 rows read a joint constraint at the prior by Boole's bound, not at shares).
    if K == 0 or not any(abs_o.atoms[i].joints for _, i in reqs):
        return None
    covs, _ = covariance_schedule(system.system_modes, problem.initial_state.cov, actions)
    mean0 = problem.initial_state.mean
    # Columns: x_1..x_K (K n), u_0..u_{K-1} (K m), then one r per (requirement, joint face).
    nx, nu = K * n, K * m
    eq_r: list[int] = []
    eq_c: list[int] = []
    eq_v: list[float] = []
    b_eq = np.zeros(nx)
    for k in range(K):
        mode = system.system_modes[int(actions[k])]
        for a in range(n):
            row = k * n + a
            cols = [k * n + a] + [nx + k * m + b for b in range(m)]
            vals = [1.0] + [-float(mode.B[a, b]) for b in range(m)]
            if k == 0:
                b_eq[row] = float(mode.A[a] @ mean0)
            else:
                cols += [(k - 1) * n + b for b in range(n)]
                vals += [-float(mode.A[a, b]) for b in range(n)]
            eq_r.extend([row] * len(cols))
            eq_c.extend(cols)
            eq_v.extend(vals)
    ub_r: list[int] = []
    ub_c: list[int] = []
    ub_v: list[float] = []
    b_ub: list[float] = []

    def add(cols: list[int], vals: list[float], rhs: float) -> None:
        r = len(b_ub)
        ub_r.extend([r] * len(cols))
        ub_c.extend(cols)
        ub_v.extend(vals)
        b_ub.append(rhs)

    UH, Uc = problem.control_domain.H, problem.control_domain.c
    for k in range(K):
        for h, c in zip(UH, Uc, strict=True):
            add([nx + k * m + b for b in range(m)], [float(v) for v in h], -float(c))
    ncol = nx + nu
    uses: list[tuple[JointChanceConstraint, int, int]] = []  # (joint, step, first r column)
    for k, i in reqs:
        ap = abs_o.atoms[i]
        xcols = [(k - 1) * n + b for b in range(n)]
        for p in ap.predicates[: ap.num_single]:
            sd = float(np.sqrt(max(float(p.h @ covs[k] @ p.h), 0.0)))
            z = float(quantile(p.eps))
            if not np.isfinite(z):
                if sd > 0:
                    return None
                z = 0.0
            add(xcols, [float(v) for v in p.h], -float(p.c) - z * sd)
        for joint in ap.joints:
            if joint.eps <= 0:
                return None
            slopes, intercepts, qs, last = chord_rows(joint.eps)
            first = ncol
            sum_cols = []
            for h, c in zip(joint.H, joint.c, strict=True):
                sd = float(np.sqrt(max(float(h @ covs[k] @ h), 0.0)))
                col = ncol
                ncol += 1
                sum_cols.append(col)
                if sd == 0:
                    add(xcols, [float(v) for v in h], -float(c))  # no variance: the face itself, no risk
                    add([col], [-1.0], 0.0)
                    continue
                # q = -(h'x + c) / sd >= q_0, and r >= slope q + intercept for every chord
                add(xcols, [float(v) for v in h], -float(c) - float(qs[0]) * sd)
                for s, b in zip(slopes, intercepts, strict=True):
                    # r >= s (-(h'x + c)) / sd + b  <=>  -r - (s / sd) h'x <= (s / sd) c - b
                    add([col, *xcols], [-1.0, *(-(s / sd) * h).tolist()], float(s * c / sd - b))
                add([col], [-1.0], -last)
            add(sum_cols, [1.0] * len(sum_cols), joint.eps * (1 - 1e-9))
            uses.append((joint, k, first))
    cost = np.zeros(ncol)
    for joint, _, first in uses:
        cost[first : first + joint.num_faces] = 1.0 / joint.eps  # the least risk: room for the re-solve
    A_eq = coo_matrix((eq_v, (eq_r, eq_c)), shape=(nx, ncol)).tocsr()
    A_ub = coo_matrix((ub_v, (ub_r, ub_c)), shape=(len(b_ub), ncol)).tocsr()
    res = linprog(
        cost,
        A_ub=A_ub,
        b_ub=np.asarray(b_ub),
        A_eq=A_eq,
        b_eq=b_eq,
        bounds=[(None, None)] * ncol,
        method="highs",
    )
    if res.status != 0 or res.x is None:
        logger.info("allocation LP for the relaxation's plan: %s", res.message)
        return None
    means = np.vstack([mean0, res.x[:nx].reshape(K, n)])
    controls = res.x[nx : nx + nu].reshape(K, m)
    return RiskLP(means, covs, controls, actions, [(joint, k) for joint, k, _ in uses])
