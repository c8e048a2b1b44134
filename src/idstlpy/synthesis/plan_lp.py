"""The plan LP: controls that meet a discrete plan's requirements, as one linear model.

For a fixed mode sequence the MLO mean is affine in the controls, and when no mode's noise
depends on the state the covariance schedule is fixed: every chance constraint of the plan is a
linear constraint on the controls and the LP decides the plan exactly. With state-dependent
noise the same LP is built on a *lower bound* of the covariance (the update with zero
observation noise; the Riccati update is monotone in ``R`` and in the prior), a sound necessary
condition whose infeasibility proofs remain valid.

Numerics. Variables are scaled per state and input coordinate (:class:`Scaling`, from the
problem's own magnitudes) and every inequality row is normalised, so the solver's absolute
tolerances are relative to the problem: the same plan is found, or refuted, in metres or in
micrometres. Refutations are claimed only when the elastic LP's optimum is far above the
solver's tolerances; a borderline optimum is *unknown*, never a proof.

This module builds the rows (:func:`build_plan_rows`, from one solve's :class:`PlanLPContext`);
:mod:`.plan_solve` solves them (the LP teacher's, the repairs' and the re-timing's plan LPs) and
:mod:`.milp` (the eager model) extends them. The covariance schedules, and whether the LP is
exact (:func:`~.covariances.lp_exact`, the one place that decides it), are :mod:`.covariances`'.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix

from ..backends import Backend, HighsBackend
from ..chance import std_terms
from .covariances import (
    cached_schedule,
    covariance_jacobian,
    covariance_schedule,
    lp_exact,
    noise_depends_on_state,
    row_cache,
)
from .interfaces import Budget
from .plan import DiscretePlan

if TYPE_CHECKING:
    from ..dynamical_system import SwitchedSystem
    from ..problem import Problem
    from ..sets import Polytope
    from .abstraction import Abstraction
    from .covariance_floor import Modes

__all__ = [
    "PlanLPContext",
    "PlanRows",
    "Scaling",
    "build_plan_rows",
    "cached_schedule",
    "covariance_jacobian",
    "covariance_schedule",
    "lp_exact",
    "noise_depends_on_state",
]

_TINY = 1e-300


def _magnitude(values: np.ndarray) -> float:
    finite = np.abs(values[np.isfinite(values)])
    finite = finite[finite > _TINY]
    return float(np.max(finite)) if finite.size else 0.0


@dataclass(frozen=True)
class Scaling:
    """Per-coordinate units of the state and input: ``x = dx * x_scaled``, ``u = du * u_scaled``.

    Attributes
    ----------
    dx : ndarray, shape (n,)
    du : ndarray, shape (m,)
    """

    dx: np.ndarray
    du: np.ndarray

    @classmethod
    def compute(
        cls,
        system: SwitchedSystem,
        control_domain: Polytope,
        mean0: np.ndarray,
        cov0: np.ndarray,
        abstraction: Abstraction,
    ) -> Scaling:
        """Units read off the prior, the propositions' regions and the control domain."""
        n, m = system.n, system.m
        dx = np.zeros(n)
        for i in range(n):
            cands = [abs(mean0[i]), float(np.sqrt(max(cov0[i, i], 0.0)))]
            for j in range(abstraction.num_atoms):
                low, high = abstraction.bounds(j)
                cands.append(_magnitude(np.array([low[i], high[i]])))
            dx[i] = max(cands)
        fallback = float(np.max(dx)) if np.any(dx > 0) else 1.0
        dx = np.where(dx > 0, dx, fallback)
        low, high = control_domain.bounding_box()
        du = np.array([_magnitude(np.array([low[j], high[j]])) for j in range(m)])
        if np.any(du == 0):
            # Unbounded or degenerate input axes: the unit that moves the state by one of its units.
            for col in np.nonzero(du == 0)[0].tolist():
                gains = [np.max(np.abs(mode.B[:, col]) / dx) for mode in system.system_modes]
                g = max(gains)
                du[col] = 1.0 / g if g > 0 else 1.0
        return cls(dx, du)


@dataclass(frozen=True)
class PlanLPContext:
    """What every plan LP of one solve shares: built once per solve, passed to each LP.

    Attributes
    ----------
    system : SwitchedSystem
        The modes (the hull relaxation's for the every-mode refutation).
    control_domain : Polytope
    mean0 : ndarray, shape (n,)
        The prior's mean.
    cov0 : ndarray, shape (n, n)
        The prior's covariance.
    abstraction : Abstraction
        The formula's propositions (their faces and the rows' caches live on it).
    scaling : Scaling
        Units of the LP's variables.
    backend : Backend
        The LP back-end (default HiGHS).
    """

    system: SwitchedSystem
    control_domain: Polytope
    mean0: np.ndarray
    cov0: np.ndarray
    abstraction: Abstraction
    scaling: Scaling
    backend: Backend = field(default_factory=HighsBackend)

    @classmethod
    def of(
        cls,
        problem: Problem,
        abstraction: Abstraction,
        scaling: Scaling | None = None,
        backend: Backend | None = None,
    ) -> PlanLPContext:
        """The context of ``problem``'s plan LPs (units computed from the problem when not given)."""
        system, domain, init = problem.switched_system, problem.control_domain, problem.initial_state
        if scaling is None:
            scaling = Scaling.compute(system, domain, init.mean, init.cov, abstraction)
        backend = backend if backend is not None else HighsBackend()
        return cls(system, domain, init.mean, init.cov, abstraction, scaling, backend)

    @property
    def exact(self) -> bool:
        """Whether the plan LP is exact for this context's system (:func:`lp_exact`)."""
        return lp_exact(self.system)


@dataclass
class PlanRows:
    """The rows of the plan LP in scaled variables ``[x_1..x_K, u_0..u_{K-1}]`` plus extras.

    Attributes
    ----------
    K, n, m : int
    nx, nu : int
        Column counts of the states and inputs (``K n``, ``K m``).
    A_eq, b_eq : dynamics rows (``K n``) and right-hand side
    A_U, b_U : control-domain rows (normalised), ``A_U z <= b_U``
    face_H : ndarray, shape (R, K n + K m)  (sparse)
        One row per required face, normalised: ``face_H z + face_off <= 0`` is the face.
    face_off : ndarray, shape (R,)
    face_norm : ndarray, shape (R,)
        ``||h|| / ||h * dx||`` per face: converts a distance in state units to scaled rows.
    face_unit : ndarray, shape (R,)
        ``1 / ||h * dx||`` per face: converts a raw slack ``-(h'x + c + ...)`` (the monitor's
        robustness units) to scaled rows.
    face_owner : ndarray, shape (R,)
        Index into ``requirements`` of each face row.
    requirements : list of (step, atom)
    impossible : list of (step, atom)
        Requirements no belief can meet (``eps = 0`` with positive variance).
    covs : ndarray, shape (K + 1, n, n)
    exact : bool
    """

    K: int
    n: int
    m: int
    A_eq: csr_matrix
    b_eq: np.ndarray
    A_U: csr_matrix
    b_U: np.ndarray
    face_H: csr_matrix
    face_off: np.ndarray
    face_norm: np.ndarray
    face_unit: np.ndarray
    face_owner: np.ndarray
    requirements: list[tuple[int, int]]
    impossible: list[tuple[int, int]]
    covs: np.ndarray
    exact: bool
    scaling: Scaling

    @property
    def nx(self) -> int:
        """Number of state columns."""
        return self.K * self.n

    @property
    def nu(self) -> int:
        """Number of input columns."""
        return self.K * self.m

    def unscale(self, z: np.ndarray, mean0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Means (K + 1, n) and controls (K, m) in problem units from scaled columns ``z``."""
        K, n, m = self.K, self.n, self.m
        means = np.vstack([mean0, z[: K * n].reshape(K, n) * self.scaling.dx])
        controls = z[K * n : K * n + K * m].reshape(K, m) * self.scaling.du
        return means, controls


def build_plan_rows(
    context: PlanLPContext,
    requirements: list[tuple[int, int]],
    actions: np.ndarray,
    covs: np.ndarray | None = None,
    budget: Budget | None = None,
    linearisation: tuple[list[np.ndarray], np.ndarray] | None = None,
) -> PlanRows:
    """Rows of the plan LP of ``context`` for a mode sequence ``actions`` (K,) and ``requirements``.

    ``covs`` (K + 1, n, n) replaces the covariance schedule of the modes (e.g. the exact
    covariances of a sampled trajectory); the rows are then not exact. ``linearisation``
    ``(S, ref)`` adds, to each face's standard-deviation term, its first-order dependence on
    the means around the reference means ``ref`` (K + 1, n): ``S[k]`` (k, n, n, n) holds
    ``d covs[k] / d mean_j[i]`` for ``j = 1..k`` (from :func:`covariance_jacobian`).

    The lazy loop calls this once per candidate on the same problem, so what does not depend on
    the candidate is kept on ``abstraction`` (one solve's lifetime): the covariance schedule
    (extended from its longest common prefix with the last one) and each proposition's scaled,
    normalised faces. The rows are the same, entry for entry, as a fresh build's.
    """
    modes, control_domain = context.system.system_modes, context.control_domain
    mean0, cov0, abstraction, scaling = context.mean0, context.cov0, context.abstraction, context.scaling
    K = int(actions.shape[0])
    n, m = mean0.shape[0], scaling.du.shape[0]
    dx, du = scaling.dx, scaling.du
    if covs is None:
        covs, exact = cached_schedule(abstraction, modes, cov0, actions, budget)
    else:
        exact = False
    ncol = K * n + K * m
    if budget is not None and K >= 1024:
        budget.check("building the plan LP")
    A_eq, b_eq = _dynamics_rows(modes, actions, mean0, dx, du, ncol)
    A_U, b_U = _control_rows(control_domain, du, K, n, m, ncol)
    if linearisation is None:
        faces = _face_rows(abstraction, requirements, covs, dx, n, ncol)
    else:
        faces = _linearised_face_rows(abstraction, requirements, covs, dx, n, ncol, linearisation)
    face_H, off, norms, units, owner, impossible = faces
    return PlanRows(
        K,
        n,
        m,
        A_eq,
        b_eq,
        A_U,
        b_U,
        face_H,
        off,
        norms,
        units,
        owner,
        list(requirements),
        impossible,
        covs,
        exact,
        scaling,
    )


def _dynamics_rows(
    modes: Modes, actions: np.ndarray, mean0: np.ndarray, dx: np.ndarray, du: np.ndarray, ncol: int
) -> tuple[csr_matrix, np.ndarray]:
    """Dynamics, row-scaled by 1/dx: x~_{k+1} - (A~) x~_k - (B~) u~_k = [k = 0] A~ x~_0."""
    K = int(actions.shape[0])
    n, m = mean0.shape[0], du.shape[0]
    b_eq = np.zeros(K * n)
    if K == 0:
        return csr_matrix((0, ncol)), b_eq
    used = np.unique(actions)
    At = np.zeros((len(modes), n, n))
    Bt = np.zeros((len(modes), n, m))
    for q in used.tolist():
        At[q] = modes[q].A * dx[None, :] / dx[:, None]
        Bt[q] = modes[q].B * du[None, :] / dx[:, None]
    b_eq[:n] = At[int(actions[0])] @ (mean0 / dx)
    # Each row (k, i) in column order: -A~ on x_{k-1} (k >= 1), the identity on x_k, -B~ on u_k;
    # built as CSR directly (every coefficient kept, zeros too, as a COO build would).
    ks = np.arange(K)
    cols_a = (ks[:, None, None] - 1) * n + np.arange(n)[None, None, :]  # (K, 1, n)
    cols_e = ks[:, None, None] * n + np.arange(n)[None, None, :]
    cols_b = K * n + ks[:, None, None] * m + np.arange(m)[None, None, :]
    shape_a, shape_b = (K, n, n), (K, n, m)
    data = np.concatenate(
        [-At[actions], np.broadcast_to(np.eye(n), shape_a), -Bt[actions]], axis=2
    )  # (K, n, 2n + m)
    parts = ((cols_a, shape_a), (cols_e, shape_a), (cols_b, shape_b))
    index = np.concatenate([np.broadcast_to(c, sh) for c, sh in parts], axis=2)
    width = np.full(K * n, 2 * n + m)
    width[:n] = n + m  # step 0 reads the known x_0 (it is in b_eq)
    data, index = data.reshape(K * n, -1), index.reshape(K * n, -1)
    data = np.concatenate([data[:n, n:].ravel(), data[n:].ravel()])
    index = np.concatenate([index[:n, n:].ravel(), index[n:].ravel()])
    indptr = np.concatenate([[0], np.cumsum(width)])
    A_eq = csr_matrix((data, index, indptr), shape=(K * n, ncol))
    return A_eq, b_eq


def _control_rows(
    control_domain: Polytope, du: np.ndarray, K: int, n: int, m: int, ncol: int
) -> tuple[csr_matrix, np.ndarray]:
    """The control domain at every step, rows normalised."""
    UH = control_domain.H * du[None, :]
    unorm = np.linalg.norm(UH, axis=1)
    keep = unorm > 0
    UH, Uc = UH[keep] / unorm[keep, None], control_domain.c[keep] / unorm[keep]
    nU = UH.shape[0]
    b_U = np.tile(-Uc, K)
    if K == 0 or nU == 0:
        return csr_matrix((K * nU, ncol)), b_U
    # Row (k, f) reads u_k: m coefficients (zeros kept), CSR built directly.
    cols = K * n + np.arange(K)[:, None, None] * m + np.arange(m)[None, None, :]  # (K, 1, m)
    index = np.broadcast_to(cols, (K, nU, m)).ravel()
    data = np.tile(UH.ravel(), K)
    indptr = np.arange(K * nU + 1) * m
    return csr_matrix((data, index, indptr), shape=(K * nU, ncol)), b_U


@dataclass(frozen=True)
class _Faces:
    """One proposition's faces in scaled units: what every face row of it shares."""

    H: np.ndarray  # (F, n) raw normals
    c: np.ndarray  # (F,)
    z: np.ndarray  # (F,)
    live: np.ndarray  # (F,) bool: the face reads the mean (its scaled normal is non-zero)
    block: np.ndarray  # (F_live, n): scaled normal / its norm
    g: np.ndarray  # (F_live,): ||h * dx||
    inv: np.ndarray  # (F_live,): 1 / ||h * dx||
    norm: np.ndarray  # (F_live,): ||h|| / ||h * dx||


def _faces(abstraction: Abstraction, i: int, dx: np.ndarray) -> _Faces:
    store = row_cache(abstraction).setdefault("faces", {})
    key = (i, dx.tobytes())
    out: _Faces | None = store.get(key)
    if out is None:
        cone = abstraction.atoms[i].cone
        G = cone.H * dx[None, :]
        g = np.linalg.norm(G, axis=1)
        live = g != 0
        gl = g[live]
        # Per face, as one-face builds computed them (the same rounding, the same rows).
        hn = np.array([np.linalg.norm(h) for h in cone.H[live]])
        out = _Faces(cone.H, cone.c, cone.z, live, G[live] / gl[:, None], gl, 1.0 / gl, hn / gl)
        store[key] = out
    return out


_FaceParts = tuple[csr_matrix, np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[tuple[int, int]]]


def _face_rows(
    abstraction: Abstraction,
    requirements: list[tuple[int, int]],
    covs: np.ndarray,
    dx: np.ndarray,
    n: int,
    ncol: int,
) -> _FaceParts:
    """One normalised row per live face of every requirement, in requirement then face order.

    A face reads the mean at its step only: one block of ``n`` coefficients, so a plan of K
    steps builds its rows in O(K), one vectorised pass per proposition.
    """
    R = len(requirements)
    if R == 0:
        empty = np.zeros(0)
        return csr_matrix((0, ncol)), empty, empty, empty, np.zeros(0, dtype=int), []
    req = np.asarray(requirements, dtype=int).reshape(R, 2)
    count = np.zeros(R, dtype=int)  # rows of each requirement
    parts: list[tuple[np.ndarray, _Faces, np.ndarray, np.ndarray]] = []
    impossible: list[tuple[int, int, int]] = []  # (requirement, face, ...) sorted below
    for i in np.unique(req[:, 1]).tolist():
        idx = np.flatnonzero(req[:, 1] == i)
        fc = _faces(abstraction, i, dx)
        terms = std_terms(fc.H, fc.z, covs[req[idx, 0]])  # (r, F)
        dead = np.any(np.isinf(terms), axis=1)  # eps = 0 with positive variance: no belief meets it
        for r in idx[dead].tolist():
            impossible.append((r, -1, i))
        ok = idx[~dead]
        terms = terms[~dead]
        if not fc.live.all():
            # A face that does not read the mean holds or fails whatever the controls.
            fails = fc.c[~fc.live][None, :] + terms[:, ~fc.live] > 0
            for a, f in zip(*np.nonzero(fails), strict=True):
                impossible.append((int(ok[a]), int(np.flatnonzero(~fc.live)[f]), i))
        count[ok] = fc.block.shape[0]
        offs = (fc.c[fc.live][None, :] + terms[:, fc.live]) / fc.g[None, :]
        parts.append((ok, fc, offs, req[ok, 0]))
    start = np.concatenate([[0], np.cumsum(count)])
    nrows = int(start[-1])
    off = np.empty(nrows)
    norms = np.empty(nrows)
    units = np.empty(nrows)
    owner = np.empty(nrows, dtype=int)
    # Every row reads one step's mean: n coefficients (zeros kept) in column order, so the CSR
    # arrays are filled in place, row r at r * n.
    data = np.empty((nrows, n))
    index = np.empty((nrows, n), dtype=np.int64)
    cols_n = np.arange(n)
    for ok, fc, offs, ks in parts:
        F = fc.block.shape[0]
        if F == 0 or ok.size == 0:
            continue
        r = start[ok][:, None] + np.arange(F)[None, :]  # (r, F)
        off[r] = offs
        norms[r] = fc.norm[None, :]
        units[r] = fc.inv[None, :]
        owner[r] = ok[:, None]
        data[r] = fc.block[None, :, :]
        index[r] = (ks - 1)[:, None, None] * n + cols_n[None, None, :]  # the mean at the face's step
    face_H = csr_matrix((data.ravel(), index.ravel(), np.arange(nrows + 1) * n), shape=(nrows, ncol))
    impossible.sort(key=lambda t: (t[0], t[1]))
    return face_H, off, norms, units, owner, [requirements[r] for r, _, _ in impossible]


def _linearised_face_rows(
    abstraction: Abstraction,
    requirements: list[tuple[int, int]],
    covs: np.ndarray,
    dx: np.ndarray,
    n: int,
    ncol: int,
    linearisation: tuple[list[np.ndarray], np.ndarray],
) -> _FaceParts:
    """Face rows with each standard-deviation term linearised in the means (one face at a time)."""
    S, ref = linearisation
    rows, cols, vals, off, norms, units, owner = [], [], [], [], [], [], []
    impossible: list[tuple[int, int]] = []
    r = 0
    for idx, (k, i) in enumerate(requirements):
        cone = abstraction.atoms[i].cone
        terms = std_terms(cone.H, cone.z, covs[k])
        if np.any(np.isinf(terms)):
            impossible.append((k, i))
            continue
        G = cone.H * dx[None, :]
        g = np.linalg.norm(G, axis=1)
        slope = None
        if k >= 1:
            sd = np.sqrt(np.maximum(np.einsum("fa,ab,fb->f", cone.H, covs[k], cone.H), 0.0))
            # d (z sd) / d mean_j[i] = z h' (dP_k / d mean_j[i]) h / (2 sd), for j = 1..k.
            dvar = np.einsum("fa,jiab,fb->fji", cone.H, S[k], cone.H)
            with np.errstate(divide="ignore", invalid="ignore"):
                slope = np.where(
                    sd[:, None, None] > 0, cone.z[:, None, None] * dvar / (2 * sd[:, None, None]), 0.0
                )
            slope = np.where(np.isfinite(slope), slope, 0.0)
        for f in range(cone.num_faces):
            if g[f] == 0 and slope is None:
                if cone.c[f] + terms[f] > 0:
                    impossible.append((k, i))
                continue
            base = cone.c[f] + terms[f]
            if slope is None:
                gf = float(g[f])
                nz = np.array([k - 1])
                block = (G[f] / gf)[None, :]
            else:
                coef = slope[f].copy()
                coef[k - 1] += cone.H[f]
                base -= float(np.sum(slope[f] * ref[1 : k + 1]))
                scaled = coef * dx[None, :]
                gf = float(np.linalg.norm(scaled[k - 1])) if g[f] > 0 else float(np.linalg.norm(scaled))
                if gf == 0:
                    if base > 0:
                        impossible.append((k, i))
                    continue
                nz = np.nonzero(np.any(scaled != 0, axis=1))[0]
                block = scaled[nz] / gf
            rows.append(np.full(nz.size * n, r))
            cols.append((nz[:, None] * n + np.arange(n)[None, :]).ravel())
            vals.append(block.ravel())
            off.append(base / gf)
            norms.append(np.linalg.norm(cone.H[f]) / gf)
            units.append(1.0 / gf)
            owner.append(idx)
            r += 1
    return (
        _sparse(rows, cols, vals, r, ncol),
        np.asarray(off, dtype=float),
        np.asarray(norms, dtype=float),
        np.asarray(units, dtype=float),
        np.asarray(owner, dtype=int),
        impossible,
    )


def _sparse(rows: list[Any], cols: list[Any], vals: list[Any], nrow: int, ncol: int) -> csr_matrix:
    if not rows:
        return csr_matrix((nrow, ncol))
    return coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(nrow, ncol)
    ).tocsr()


def plan_requirements(plan: DiscretePlan, abstraction: Abstraction) -> list[tuple[int, int]]:
    """The plan's requirements that constrain the mean (steps >= 1, atoms with predicates)."""
    return [(k, i) for (k, i) in plan.requirements() if k >= 1 and abstraction.atoms[i].predicates]
