"""Solving the plan LP: controls for a discrete plan, or a proof that there are none.

The plan LP (:mod:`.plan_lp`'s rows, for one solve's :class:`~.plan_lp.PlanLPContext`) is solved
in two phases through a registered back-end:

1. *elastic*: one slack per requirement, minimise their sum. An optimum far above the solver's
   tolerances is a proof of infeasibility, and the requirements whose rows carry non-zero duals
   form an infeasible subset on their own (the duals are a Farkas certificate of that subset
   together with the dynamics and the control domain): that subset is the conflict. A
   borderline optimum is *unknown*;
2. *margin*: with the slacks at zero, push every required face inside its bound by up to
   ``margin`` (state units), so the plan survives execution noise; a zero-slack plan keeps
   margin 0 and the monitor decides it exactly. An objective (:class:`LPGoal`) follows.

When no mode's noise depends on the state the LP is exact (:func:`~.plan_lp.lp_exact`:
``Found`` / ``Refuted``); otherwise it is a sound relaxation (``Refuted`` or ``Unknown``), or,
on a trajectory's frozen covariances within a :class:`TrustRegion`, one step of sequential
convex programming.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal

import numpy as np
from scipy.sparse import csr_matrix, diags, vstack

from ..backends import Backend, LinearModel
from .interfaces import Budget
from .plan import DiscretePlan
from .plan_lp import PlanLPContext, PlanRows, build_plan_rows, covariance_jacobian, plan_requirements
from .proofs import FaceProof, NoProof, Proof, RowsProof

if TYPE_CHECKING:
    from ..sets import Polytope
    from .options import Objective

__all__ = [
    "LPGoal",
    "LPOutcome",
    "MarginModel",
    "Phases",
    "TIGHTEN",
    "TrustRegion",
    "margin_model",
    "margin_phase",
    "solve_plan_lp",
]

logger = logging.getLogger(__name__)

FEASIBLE_TOL = 1e-9
"""Elastic optimum (per requirement, normalised rows) at or below which the plan is feasible."""
REFUTE_TOL = 1e-6
"""Elastic optimum above which infeasibility is claimed (10x HiGHS' primal tolerance)."""
_DUAL_TOL = 1e-9
TIGHTEN = 2e-7
"""Room (relative to the state's units) a plan keeps inside its faces when it can: twice HiGHS'
primal tolerance on the normalised rows, so the monitor's exact re-check passes."""


@dataclass
class LPOutcome:
    """Result of the plan LP.

    Attributes
    ----------
    status : {"feasible", "infeasible", "unknown"}
        ``infeasible`` is a proof (see the module docstring); ``unknown`` is not.
    exact : bool
        True when the covariance schedule is exact (no state-dependent noise on the plan).
    controls : ndarray, shape (K, m), or None
    means : ndarray, shape (K + 1, n), or None
        Means of the LP's trajectory (also the least-violating one when infeasible).
    conflict : list of (step, atom)
        An infeasible subset of the requirements (empty unless infeasible).
    covs : ndarray, shape (K + 1, n, n), or None
        The covariance schedule the LP used (exact or lower bound).
    why : str
        Why the outcome is ``unknown`` (empty otherwise).
    excess : float
        The elastic LP's total violation (normalised rows; ``inf`` when a requirement is
        impossible on its own, ``nan`` when the elastic phase did not run): the mode search's
        score.
    rows : PlanRows or None
        The rows the LP was built from when they are the plain plan rows of the plan (no given
        covariances, trust region or input back-off): the room LP of the same plan on the same
        covariances reads them instead of building them again (the mode search's scores).
    proof : Proof or None
        When infeasible: what proves the conflict (the Farkas ray of its rows, or the face no
        belief meets), for the certificate of an ``infeasible`` (:mod:`.proofs`).
    """

    status: Literal["feasible", "infeasible", "unknown"]
    exact: bool
    controls: np.ndarray | None
    means: np.ndarray | None
    conflict: list[tuple[int, int]] = field(default_factory=list)
    covs: np.ndarray | None = None
    why: str = ""
    excess: float = float("nan")
    rows: PlanRows | None = field(default=None, compare=False, repr=False)
    proof: Proof | None = field(default=None, compare=False, repr=False)

    @property
    def feasible(self) -> bool:
        """True when the LP found controls."""
        return self.status == "feasible"


@dataclass(frozen=True)
class TrustRegion:
    """How far the plan LP's means may move from a trajectory's, whose covariances it freezes.

    Attributes
    ----------
    anchor : ndarray, shape (K + 1, n)
        The trajectory's means.
    radius : float
        Largest move of every mean (infinity norm, state units) in the margin and objective
        phases; infinite: no bound.
    linearise : bool
        Add each standard-deviation term's first-order dependence on the means around
        ``anchor`` (:func:`~.plan_lp.covariance_jacobian`): a step of a sequential convex
        programme in belief space (the radius should then be finite).
    """

    anchor: np.ndarray
    radius: float = np.inf
    linearise: bool = False


@dataclass(frozen=True)
class LPGoal:
    """What the plan LP optimises after feasibility.

    Attributes
    ----------
    objective : {None, "effort", "margin"}
        ``"effort"`` minimises ``sum_k sum_j w_j |u_kj|`` while keeping the execution margin;
        ``"margin"`` maximises the smallest slack of the required faces (the monitor's
        robustness over this plan's requirements); ``None`` keeps the margin phase.
    effort_weights : ndarray, shape (m,), optional
        Per-input weights ``w`` of the effort objective (default ones).
    tighten : float
        The least room kept inside the faces, relative to the smallest state unit (default
        :data:`TIGHTEN`); an objective's exact re-timing asks for less (issue 25).
    """

    objective: Objective | None = None
    effort_weights: np.ndarray | None = None
    tighten: float = TIGHTEN


Phases = Literal["elastic", "refute", "witness"]
"""``"elastic"``: the elastic phase, then the margin and objective phases of a feasible plan;
``"refute"``: only the elastic phase (a feasible plan's controls are the elastic LP's), for a
relaxation asked only for its refutation (a prefix of a plan); ``"witness"``: the plan is
expected to be feasible (a MILP's witness), the margin and objective phases run first and the
elastic phase only when they find nothing."""


def solve_plan_lp(
    context: PlanLPContext,
    plan: DiscretePlan,
    margin: float = 0.0,
    *,
    covs: np.ndarray | None = None,
    region: TrustRegion | None = None,
    control_backoff: np.ndarray | None = None,
    goal: LPGoal | None = None,
    budget: Budget | None = None,
    time_limit: float = np.inf,
    phases: Phases = "elastic",
) -> LPOutcome:
    """Find controls that meet every requirement of ``plan`` (see the module docstring).

    Parameters
    ----------
    context : PlanLPContext
        The solve's system, control domain, prior, abstraction, units and back-end.
    plan : DiscretePlan
    margin : float
        Room to leave inside every required face, in state units (second phase).
    covs : ndarray, shape (K + 1, n, n), optional
        Covariances to use instead of the modes' schedule (e.g. a sampled trajectory's); the
        result is then exact only near that trajectory, which ``region`` bounds.
    region : TrustRegion, optional
    control_backoff : ndarray, shape (K, F), optional
        Per step, how far inside each face of the control domain (its units) the input must
        stay (room for the executor's tracking correction, :func:`~.teacher.closed_loop_lp`).
        An ``infeasible`` answer is then about the shrunk domain, no proof about the problem.
    goal : LPGoal, optional
        The objective after feasibility (default: the margin phase only).
    budget : Budget, optional
        Overall wall-clock cap, checked while the rows are built.
    time_limit : float
        Wall-clock cap in seconds for each LP.
    phases : {"elastic", "refute", "witness"}
        Which phases run, in which order (:data:`Phases`).

    Returns
    -------
    LPOutcome
    """
    K = plan.num_transitions
    if K == 0:
        covs0 = context.cov0[None, :, :] if covs is None else covs
        mean0 = context.mean0[None, :].copy()
        return LPOutcome("feasible", covs is None, np.zeros((0, context.system.m)), mean0, [], covs0)
    rows = _plan_rows(context, plan, covs, region, control_backoff, budget)
    if rows.impossible:
        return LPOutcome(
            "infeasible",
            rows.exact,
            None,
            None,
            rows.impossible[:1],
            rows.covs,
            excess=float("inf"),
            proof=_impossible_proof(context, rows),
        )
    goal = goal if goal is not None else LPGoal()
    limit = float(min(time_limit, 1e9))
    if phases == "witness":
        # The phases' rows are the plan's with t >= 0: a solution of theirs meets the plan.
        z2 = _optimise(rows, context.backend, limit, margin, region, goal)
        if z2 is not None:
            means, controls = rows.unscale(z2, context.mean0)
            return LPOutcome("feasible", rows.exact, controls, means, [], rows.covs)
    out = _elastic(context, rows, limit, margin, region, goal, phases == "refute")
    if covs is None and region is None and control_backoff is None:
        out = dataclasses.replace(out, rows=rows)
    return out


def _plan_rows(
    context: PlanLPContext,
    plan: DiscretePlan,
    covs: np.ndarray | None,
    region: TrustRegion | None,
    control_backoff: np.ndarray | None,
    budget: Budget | None,
) -> PlanRows:
    """The plan LP's rows for ``plan`` (linearised in a region, inputs backed off)."""
    K = plan.num_transitions
    actions = np.asarray(plan.modes[1 : K + 1], dtype=int)
    lin = None
    if region is not None and region.linearise and covs is not None:
        ref = np.asarray(region.anchor)[: K + 1]
        jac = covariance_jacobian(
            context.system.system_modes, actions, ref, covs[: K + 1], context.scaling.dx
        )
        lin = (jac, ref)
    reqs = plan_requirements(plan, context.abstraction)
    rows = build_plan_rows(context, reqs, actions, covs, budget=budget, linearisation=lin)
    if control_backoff is not None:
        du = context.scaling.du
        rows = _backed_off(rows, context.control_domain, du, np.asarray(control_backoff)[:K])
    return rows


def _elastic(
    context: PlanLPContext,
    rows: PlanRows,
    limit: float,
    margin: float,
    region: TrustRegion | None,
    goal: LPGoal,
    refute_only: bool,
) -> LPOutcome:
    """The elastic phase; a feasible plan's margin and objective phases (unless ``refute_only``)."""
    mean0 = context.mean0
    model, ns = _elastic_model(rows)
    sol = context.backend.solve(model, limit)
    if sol.status != "optimal" or sol.x is None:
        why = f"plan LP: {sol.status} ({sol.message})"
        logger.debug(why)
        return LPOutcome("unknown", rows.exact, None, None, [], rows.covs, why)
    z = sol.x
    means, controls = rows.unscale(z, mean0)
    excess = float(sol.objective)
    if excess <= FEASIBLE_TOL * max(1, ns):
        if refute_only:
            return LPOutcome("feasible", rows.exact, controls, means, [], rows.covs, excess=excess)
        z2 = _optimise(rows, context.backend, limit, margin, region, goal)
        if z2 is not None:
            means, controls = rows.unscale(z2, mean0)
        return LPOutcome("feasible", rows.exact, controls, means, [], rows.covs)
    if excess <= REFUTE_TOL:
        why = f"plan LP borderline: total violation {excess:.3g} is within solver tolerances"
        return LPOutcome("unknown", rows.exact, controls, means, [], rows.covs, why, excess)
    nE, nU = rows.A_eq.shape[0], rows.A_U.shape[0]
    duals = np.abs(sol.row_duals[nE + nU :]) if sol.row_duals is not None else np.zeros(0)
    involved = sorted(set(rows.face_owner[duals > _DUAL_TOL].tolist())) if duals.size else []
    if not involved:
        slack = z[rows.nx + rows.nu : rows.nx + rows.nu + ns]
        involved = [r for r in range(ns) if slack[r] > FEASIBLE_TOL]
    conflict = [rows.requirements[r] for r in involved]
    proof = _farkas(rows, sol.row_duals, involved) if sol.row_duals is not None else None
    return LPOutcome(
        "infeasible", rows.exact, controls, means, conflict, rows.covs, excess=excess, proof=proof
    )


def _farkas(rows: PlanRows, duals: np.ndarray, involved: list[int]) -> RowsProof:
    """The conflict's rows and the elastic LP's duals as a Farkas ray of them.

    The elastic LP's optimal duals ``pi`` (``d objective / d bound``) meet ``pi' A = 0`` on the
    plan's columns (free, cost 0) and ``pi' b = excess > 0``; so ``-pi`` over the dynamics,
    the control domain and the faces of the conflict's requirements is a Farkas ray of those
    rows (the faces of the other requirements carry no dual). Only the steps up to the
    conflict's last are kept; the faces are the rows the proof is about (not pivots of the
    exact repair), the dynamics and control rows may absorb the ray's rounding.
    """
    K, n = rows.K, rows.n
    nE, nU = rows.A_eq.shape[0], rows.A_U.shape[0]
    per = nU // K if K else 0
    owners = np.asarray(rows.face_owner)
    faces = np.flatnonzero(np.isin(owners, involved)) if involved else np.zeros(0, dtype=int)
    last = max((rows.requirements[r][0] for r in involved), default=K)
    last = min(max(int(last), 1), K)
    eq_rows = np.arange(last * n)
    u_rows = np.arange(last * per)
    A = vstack([rows.A_eq[eq_rows], rows.A_U[u_rows], rows.face_H[faces]]).tocsr()
    rhs = np.concatenate([rows.b_eq[eq_rows], rows.b_U[u_rows], -rows.face_off[faces]])
    y = -np.concatenate([duals[eq_rows], duals[nE + u_rows], duals[nE + nU + faces]])
    equality = np.zeros(rhs.shape[0], dtype=bool)
    equality[: eq_rows.size] = True
    pivots = np.zeros(rhs.shape[0], dtype=bool)
    pivots[: eq_rows.size + u_rows.size] = True
    kind = "exact" if rows.exact else "lower-bound covariance"
    about = f"plan LP ({kind}, {last} steps): dynamics, control domain and {faces.size} required faces"
    return RowsProof(A, rhs, equality, y, pivots, about)


def _impossible_proof(context: PlanLPContext, rows: PlanRows) -> Proof:
    """What proves the first requirement no belief meets: the face of it that fails at its
    step's covariance whatever the mean (``eps = 0`` with positive variance along the face, or
    a face that does not read the mean and fails)."""
    from ..chance import std_terms

    k, i = rows.impossible[0]
    cone = context.abstraction.atoms[i].cone
    cov = rows.covs[k]
    terms = std_terms(cone.H, cone.z, cov)
    live = np.linalg.norm(cone.H * rows.scaling.dx[None, :], axis=1) != 0
    for f in range(cone.num_faces):
        if np.isinf(terms[f]) or (not live[f] and cone.c[f] + terms[f] > 0):
            return FaceProof(cone.H[f], float(cone.c[f]), float(cone.z[f]), np.zeros(cov.shape[0]), cov)
    return NoProof(f"requirement {(k, i)}: no face found that fails on its own")


def _backed_off(rows: PlanRows, control_domain: Polytope, du: np.ndarray, backoff: np.ndarray) -> PlanRows:
    """``rows`` with every control face ``f`` at step ``k`` moved ``backoff[k, f]`` inward.

    The rows are normalised and faces with a zero row dropped as in
    :func:`~.plan_lp.build_plan_rows`; a copy, because built rows may be cached.
    """
    unorm = np.linalg.norm(control_domain.H * du[None, :], axis=1)
    keep = unorm > 0
    shift = (backoff[:, keep] / unorm[keep][None, :]).ravel()
    if shift.shape != rows.b_U.shape:
        raise ValueError(f"control_backoff has {shift.size} entries for {rows.b_U.size} control rows")
    return dataclasses.replace(rows, b_U=rows.b_U - shift)


def _optimise(
    rows: PlanRows,
    backend: Backend,
    limit: float,
    margin: float,
    region: TrustRegion | None,
    goal: LPGoal,
) -> np.ndarray | None:
    """The phases after feasibility: the execution margin, then the objective (if any)."""
    objective = goal.objective
    if rows.face_H.shape[0] == 0 and objective != "effort":
        return None
    dx = rows.scaling.dx
    if objective == "margin":
        # The monitor's robustness: the smallest raw slack, as large as the plan allows.
        big = 1e6 * float(np.max(dx))
        out = margin_phase(rows, backend, limit, t_lo=0.0, t_hi=big, coef=rows.face_unit, region=region)
        return None if out is None else out[0]
    t_max = max(float(margin), goal.tighten * float(np.min(dx)))
    first = None
    if rows.face_H.shape[0]:
        first = margin_phase(rows, backend, limit, t_lo=0.0, t_hi=t_max, coef=rows.face_norm, region=region)
    if objective != "effort":
        return None if first is None else first[0]
    # Keep the execution margin the first phase reached, then spend as little input as possible.
    keep = 0.0 if first is None else max(0.0, first[1] * (1.0 - 1e-6))
    weights = np.ones(rows.m) if goal.effort_weights is None else np.asarray(goal.effort_weights, dtype=float)
    second = margin_phase(
        rows,
        backend,
        limit,
        t_lo=keep,
        t_hi=max(keep, t_max),
        coef=rows.face_norm,
        effort=weights,
        region=region,
    )
    if second is not None:
        return second[0]
    return None if first is None else first[0]


def _elastic_model(rows: PlanRows) -> tuple[LinearModel, int]:
    ns = len(rows.requirements)
    ncol = rows.nx + rows.nu
    R = rows.face_H.shape[0]
    # [A_eq 0; A_U 0; face_H S] with S[r, owner[r]] = -1, built as CSR arrays directly (the
    # sparse stacking cost more than the LP on the mode search's small models).
    top = vstack([rows.A_eq, rows.A_U]).tocsr()
    face = csr_matrix(rows.face_H)
    ends = face.indptr[1:]
    data = np.insert(face.data, ends, -1.0)
    index = np.insert(face.indices, ends, ncol + np.asarray(rows.face_owner, dtype=face.indices.dtype))
    indptr = face.indptr + np.arange(R + 1)
    A = csr_matrix(
        (
            np.concatenate([top.data, data]),
            np.concatenate([top.indices, index]),
            np.concatenate([top.indptr, top.nnz + indptr[1:]]),
        ),
        shape=(top.shape[0] + R, ncol + ns),
    )
    lo = np.concatenate([rows.b_eq, np.full(rows.A_U.shape[0] + R, -np.inf)])
    hi = np.concatenate([rows.b_eq, rows.b_U, -rows.face_off])
    c = np.concatenate([np.zeros(ncol), np.ones(ns)])
    lb = np.concatenate([np.full(ncol, -np.inf), np.zeros(ns)])
    ub = np.full(ncol + ns, np.inf)
    return LinearModel(c, A, lo, hi, lb, ub), ns


def margin_phase(
    rows: PlanRows,
    backend: Backend,
    limit: float,
    *,
    t_lo: float,
    t_hi: float,
    coef: np.ndarray,
    per_face: bool = False,
    effort: np.ndarray | None = None,
    region: TrustRegion | None = None,
    b_U: np.ndarray | None = None,
) -> tuple[np.ndarray, float] | None:
    """One optimisation over the plan rows with a margin ``t`` in ``[t_lo, t_hi]``.

    Each required face ``r`` reads ``face_H z + coef_r * t <= -face_off``, with one ``t`` for
    every face or, ``per_face``, one each. Without ``effort`` the LP maximises ``t`` (the sum of
    the ``t_r``); with per-input weights ``effort`` (shape (m,)) it minimises
    ``sum_k sum_j effort_j |u_kj|`` (problem units) at any ``t`` in the range. The means stay
    in ``region``; ``b_U`` replaces the control rows' right-hand side (a back-off). Returns the
    scaled columns and the (smallest) ``t``, or ``None`` when the LP has no optimum
    (:func:`margin_model`, then :meth:`MarginModel.solve`).
    """
    return margin_model(
        rows, t_lo=t_lo, t_hi=t_hi, coef=coef, per_face=per_face, effort=effort, region=region, b_U=b_U
    ).solve(backend, limit)


@dataclass(frozen=True)
class MarginModel:
    """The LP of one :func:`margin_phase`, built (:func:`margin_model`) and not yet solved.

    Attributes
    ----------
    model : LinearModel
    ncol : int
        The plan rows' columns (scaled means, then inputs), first in the model's.
    nt : int
        The margin columns after them (one, or one per face).
    u_rows : slice
        The control rows among the model's rows (their right-hand side is the back-off).
    """

    model: LinearModel
    ncol: int
    nt: int
    u_rows: slice

    def with_b_U(self, b_U: np.ndarray) -> MarginModel:
        """The same LP with the control rows' right-hand side ``b_U`` (nothing rebuilt: the room
        LP's input levels differ only there)."""
        hi = self.model.row_hi.copy()
        hi[self.u_rows] = b_U
        return replace(self, model=replace(self.model, row_hi=hi))

    def solve(self, backend: Backend, limit: float) -> tuple[np.ndarray, float] | None:
        """The scaled columns and the (smallest) margin, or ``None`` when the LP has no optimum."""
        sol = backend.solve(self.model, limit)
        if sol.status != "optimal" or sol.x is None:
            return None
        ncol = self.ncol
        return sol.x[:ncol], float(np.min(sol.x[ncol : ncol + self.nt]))


def _block_rows(blocks: list[list[tuple[csr_matrix, int]]], ncol: int) -> csr_matrix:
    """The CSR matrix of block rows, each a list of ``(block, first column)`` side by side (the
    rest zero): the entries :func:`scipy.sparse.vstack` of :func:`~scipy.sparse.hstack` keeps,
    each row's in block order, without their per-block conversions (the margin LPs' set-up cost
    about as much as their solve)."""
    rows, cols, data, start = [], [], [], 0
    for row in blocks:
        height = row[0][0].shape[0]
        for block, first in row:
            counts = np.diff(block.indptr)
            rows.append(start + np.repeat(np.arange(height), counts))
            cols.append(first + block.indices[: block.indptr[-1]])
            data.append(block.data[: block.indptr[-1]])
        start += height
    r = np.concatenate(rows)
    order = np.argsort(r, kind="stable")
    indptr = np.zeros(start + 1, dtype=np.int64)
    np.cumsum(np.bincount(r, minlength=start), out=indptr[1:])
    return csr_matrix(
        (np.concatenate(data)[order], np.concatenate(cols)[order].astype(np.int64), indptr),
        shape=(start, ncol),
    )


def margin_model(
    rows: PlanRows,
    *,
    t_lo: float,
    t_hi: float,
    coef: np.ndarray,
    per_face: bool = False,
    effort: np.ndarray | None = None,
    region: TrustRegion | None = None,
    b_U: np.ndarray | None = None,
    differences: bool = False,
) -> MarginModel:
    """The LP of :func:`margin_phase` (its parameters), not solved: a caller that solves it
    again with only the control rows' right-hand side changed (the room LP's input levels)
    builds it once (:meth:`MarginModel.with_b_U`).

    Each required face ``r`` reads ``face_H z + coef_r * t <= -face_off``, with one ``t`` for
    every face or, ``per_face``, one each. Without ``effort`` the LP maximises ``t`` (the sum of
    the ``t_r``); with per-input weights ``effort`` (shape (m,)) it minimises
    ``sum_k sum_j effort_j |u_kj|`` (problem units) at any ``t`` in the range, or with
    ``differences`` the input's total variation ``sum_k sum_j effort_j |u_{k+1,j} - u_kj|``
    (the smoothing of default plans). The means stay in ``region``; ``b_U`` replaces the control
    rows' right-hand side (a back-off).
    """
    R = rows.face_H.shape[0]
    ncol = rows.nx + rows.nu
    K, m = rows.K, rows.m
    nE, nU = rows.A_eq.shape[0], rows.A_U.shape[0]
    nt = R if per_face else 1
    terms = (K - 1 if differences else K) * m
    na = max(terms, 0) if effort is not None else 0
    extra = nt + na
    t_block = diags(coef, format="csr") if per_face else csr_matrix(coef[:, None])
    blocks: list[list[tuple[csr_matrix, int]]] = [
        [(rows.A_eq, 0)],
        [(rows.A_U, 0)],
        [(rows.face_H, 0), (t_block, ncol)],
    ]
    lo = [rows.b_eq, np.full(nU + R, -np.inf)]
    hi = [rows.b_eq, rows.b_U if b_U is None else b_U, -rows.face_off]
    if na:
        # a_kj >= +-u_kj (problem units): du_j u~_kj - a_kj <= 0 and -du_j u~_kj - a_kj <= 0;
        # with differences, a_kj >= +-(u_{k+1,j} - u_kj) the same way.
        du = np.tile(rows.scaling.du, K)[:na]
        idx = np.arange(na)
        shape = (na, ncol + extra)
        move = csr_matrix((du, (idx, rows.nx + idx)), shape=shape)
        if differences:
            move = csr_matrix((du, (idx, rows.nx + m + idx)), shape=shape) - move
        aux = csr_matrix((-np.ones(na), (idx, ncol + nt + idx)), shape=shape)
        blocks += [[(move + aux, 0)], [(aux - move, 0)]]
        lo.append(np.full(2 * na, -np.inf))
        hi.append(np.zeros(2 * na))
    A = _block_rows(blocks, ncol + extra)
    c = np.zeros(ncol + extra)
    if effort is None:
        c[ncol : ncol + nt] = -1.0
    elif na:
        c[ncol + nt :] = np.tile(effort, K)[:na]
    lb = np.concatenate([np.full(ncol, -np.inf), np.full(nt, t_lo), np.zeros(na)])
    ub = np.concatenate([np.full(ncol, np.inf), np.full(nt, t_hi), np.full(na, np.inf)])
    if region is not None and np.isfinite(region.radius):
        dx = rows.scaling.dx
        ref = (np.asarray(region.anchor)[1 : K + 1] / dx).ravel()
        width = region.radius / np.tile(dx, K)
        lb[: rows.nx] = ref - width
        ub[: rows.nx] = ref + width
    model = LinearModel(c, A, np.concatenate(lo), np.concatenate(hi), lb, ub)
    return MarginModel(model, ncol, nt, slice(nE, nE + nU))
