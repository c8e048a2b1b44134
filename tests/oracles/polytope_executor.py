"""An independent executor on a polygonal control domain, and random problems to run it on.

Written from the documented execution (README "Execution", :mod:`idstlpy.tracking`'s notes) and
the textbook, not from the package's code: it imports nothing of idstlpy to simulate, so a bug
in the package's executor or in its prediction cannot hide in the ground truth. Per run, at
step ``k`` of a plan (modes ``q_k``, means ``m_k``, inputs ``v_k``) in mode ``(A, B, W, C, V)``::

    u_k     = proj_U(v_k - K_k (mean_k - m_k))         LQR tracking, projected on the domain U
    x_{k+1} = A x_k + B u_k + W w_k                    the true state (model's process noise)
    pred    = A mean_k + B u_k,  P = A P_k A' + W W'
    y       = C x_{k+1} + V nu_k                       (a mode without C observes nothing)
    G       = P C' (C P C' + V V')^-1
    mean_{k+1} = pred + G (y - C pred),  P_{k+1} = (I - G C) P (I - G C)' + G V V' G'

``K_k``: the finite-horizon LQR of the mode (horizon 5, ``Q_final = Q = I``, ``R = 0.05 I``) by
its backward Riccati recursion, ``K_0`` while at least 5 plan steps remain and ``K_{5-r}`` with
``r`` left. The true start is drawn from the prior; the filter starts at the prior.

``proj_U`` is the Euclidean projection on a bounded convex polygon, computed geometrically: the
polygon's vertices are the pairwise intersections of its edge lines that satisfy every
inequality, ordered by angle; a point outside goes to the nearest point of the nearest edge
segment (a different algorithm from the package's active sets and least-distance programme).

The success of a run is judged on the formula family the cases use: every face
``h' x + c <= 0`` of a group must hold at every step of the group's interval; on the executed
belief as the chance constraint ``h' mean + c + Phi^-1(1 - eps) sqrt(h' P h) <= 0``, on the true
state as ``h' x + c <= 0``.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from typing import Any

import numpy as np
from scipy.stats import norm

__all__ = [
    "DOMAIN_FAMILIES",
    "FaceGroup",
    "OracleMode",
    "PolytopeCase",
    "lqr_gains",
    "polygon_vertices",
    "project_on_polygon",
    "random_case",
    "run_executor",
]

DOMAIN_FAMILIES = ("diamond", "cut_box", "polygon")


@dataclass
class OracleMode:
    """One mode as plain arrays (``C`` None: blind)."""

    A: np.ndarray
    B: np.ndarray
    W: np.ndarray
    C: np.ndarray | None
    V: np.ndarray | None


@dataclass
class FaceGroup:
    """Faces ``H x + c <= 0`` (each with its ``eps``) that must hold at every step ``a..b``."""

    H: np.ndarray  # (F, n)
    c: np.ndarray  # (F,)
    eps: np.ndarray  # (F,)
    a: int
    b: int
    name: str


@dataclass
class PolytopeCase:
    """A random problem: modes, prior, polygonal domain ``Hu u + cu <= 0``, plan, formula."""

    family: str
    seed: int
    modes: list[OracleMode]
    mean0: np.ndarray
    cov0: np.ndarray
    Hu: np.ndarray
    cu: np.ndarray
    actions: np.ndarray
    controls: np.ndarray
    groups: list[FaceGroup]

    @property
    def N(self) -> int:
        return int(self.actions.shape[0])

    def mlo_plan(self) -> tuple[np.ndarray, np.ndarray]:
        """The plan's means (N + 1, n) and covariances (N + 1, n, n): the MLO roll-out."""
        mean, P = self.mean0.copy(), self.cov0.copy()
        means, covs = [mean], [P]
        for q, v in zip(self.actions.tolist(), self.controls, strict=True):
            mode = self.modes[q]
            mean = mode.A @ mean + mode.B @ v
            P = mode.A @ P @ mode.A.T + mode.W @ mode.W.T
            if mode.C is not None:
                P = _update_cov(P, mode.C, mode.V)[0]
            means.append(mean)
            covs.append(P)
        return np.array(means), np.array(covs)

    def to_problem(self) -> tuple[Any, Any]:
        """The package's problem and plan (only here is idstlpy imported)."""
        import idstlpy as stl
        from idstlpy.sets import Polytope

        modes = []
        for mode in self.modes:
            kw: dict[str, Any] = {"A": mode.A, "B": mode.B, "W": mode.W}
            if mode.C is not None:
                kw |= {"C": mode.C, "V": mode.V}
            modes.append(stl.mk_lbs(**kw))
        system = stl.mk_switched_sys(modes)
        x = stl.mk_variable(self.mean0.shape[0])
        parts = []
        for g in self.groups:
            preds = []
            for h, c, eps in zip(g.H, g.c, g.eps, strict=True):
                expr = sum(float(h[i]) * x[i] for i in range(h.shape[0]))
                preds.append(stl.prob(expr + float(c) <= 0) >= 1.0 - float(eps))
            ap = stl.logical_and(*preds, name=g.name) if len(preds) > 1 else preds[0]
            parts.append(stl.always(g.a, g.b, ap))
        formula = stl.logical_and(*parts) if len(parts) > 1 else parts[0]
        prior = stl.to_belief(self.mean0, self.cov0)
        problem = stl.Problem(system, Polytope(self.Hu, self.cu), prior, formula)
        plan = stl.rollout(system, prior, self.actions, self.controls)
        return problem, plan


def _update_cov(P: np.ndarray, C: np.ndarray, V: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    R = np.zeros((C.shape[0], C.shape[0])) if V is None else V @ V.T
    G = P @ C.T @ np.linalg.pinv(C @ P @ C.T + R)
    I_GC = np.eye(P.shape[0]) - G @ C
    new = I_GC @ P @ I_GC.T + G @ R @ G.T
    return 0.5 * (new + new.T), G


def lqr_gains(
    A: np.ndarray,
    B: np.ndarray,
    horizon: int = 5,
    r: float = 0.05,
    weights: dict[str, Any] | None = None,
) -> list[np.ndarray]:
    """``K_0 .. K_{h-1}`` of ``sum x'Qx + u'Ru`` over ``h`` steps with terminal weight ``Q_final``:
    the paper's ``Q = Q_final = I``, ``R = r I`` unless ``weights`` (``horizon``, ``Q``, ``Q_final``,
    ``R``: the weights a plan reports it was tracked with) are given."""
    n, m = B.shape
    Q, Qf, R = np.eye(n), np.eye(n), r * np.eye(m)
    if weights is not None:
        horizon = int(weights["horizon"])
        Q, Qf, R = (_matrix(weights[k], d) for k, d in (("Q", n), ("Q_final", n), ("R", m)))
    P = Qf
    out: list[np.ndarray] = []
    for _ in range(horizon):
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P = Q + A.T @ P @ (A - B @ K)
        out.append(K)
    return out[::-1]


def _matrix(value: Any, d: int) -> np.ndarray:
    """A weight as given: a scalar (times I), a diagonal (d,) or a matrix (d, d)."""
    w = np.asarray(value, dtype=float)
    return w * np.eye(d) if w.ndim == 0 else (np.diag(w) if w.ndim == 1 else w)


def polygon_vertices(H: np.ndarray, c: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Vertices (V, 2) of the bounded polygon ``H u + c <= 0``, counter-clockwise."""
    pts = []
    for i, j in combinations(range(H.shape[0]), 2):
        M = H[[i, j]]
        if abs(np.linalg.det(M)) < 1e-12:
            continue
        p = np.linalg.solve(M, -c[[i, j]])
        if np.all(H @ p + c <= tol * (1 + np.abs(c))):
            pts.append(p)
    P = np.unique(np.round(np.array(pts), 12), axis=0)
    centre = P.mean(axis=0)
    order = np.argsort(np.arctan2(P[:, 1] - centre[1], P[:, 0] - centre[0]))
    return P[order]


def project_on_polygon(U: np.ndarray, H: np.ndarray, c: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """Rows of ``U`` (S, 2) projected on the polygon (its inequalities and vertices)."""
    out = U.copy()
    outside = np.any(U @ H.T + c > 1e-12 * np.linalg.norm(H, axis=1), axis=1)
    if not outside.any():
        return out
    X = U[outside]
    a = verts
    b = np.roll(verts, -1, axis=0)
    ab = b - a  # (E, 2)
    t = np.einsum("sed,ed->se", X[:, None, :] - a[None], ab) / np.einsum("ed,ed->e", ab, ab)
    t = np.clip(t, 0.0, 1.0)
    near = a[None] + t[:, :, None] * ab[None]  # (S, E, 2)
    dist = np.sum((near - X[:, None, :]) ** 2, axis=2)
    best = np.argmin(dist, axis=1)
    out[outside] = near[np.arange(X.shape[0]), best]
    return out


def run_executor(
    case: PolytopeCase, runs: int, seed: int, weights: dict[str, Any] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``runs`` executions of the case's plan: the filter means (runs, N + 1, n), the filter
    covariances (N + 1, n, n) (the noise is constant: the same for every run), the true states
    (runs, N + 1, n), and the fraction of (run, step) inputs the projection moved. ``weights``:
    the tracking weights the plan reports (default the paper's, see :func:`lqr_gains`)."""
    rng = np.random.default_rng(seed)
    means_plan, _ = case.mlo_plan()
    n = case.mean0.shape[0]
    N = case.N
    verts = polygon_vertices(case.Hu, case.cu)
    gains = {q: lqr_gains(mode.A, mode.B, weights=weights) for q, mode in enumerate(case.modes)}
    L0 = np.linalg.cholesky(case.cov0 + 1e-15 * np.eye(n))
    X = case.mean0 + rng.standard_normal((runs, n)) @ L0.T
    M = np.tile(case.mean0, (runs, 1))
    P = case.cov0.copy()
    Xs, Ms, Ps = [X], [M], [P]
    moved = 0
    for k in range(N):
        q = int(case.actions[k])
        mode = case.modes[q]
        Ks = gains[q]
        left = N - k
        K = Ks[0] if left >= len(Ks) else Ks[len(Ks) - left]
        wanted = case.controls[k] - (M - means_plan[k]) @ K.T
        U = project_on_polygon(wanted, case.Hu, case.cu, verts)
        moved += int(np.sum(np.any(np.abs(U - wanted) > 0, axis=1)))
        X = X @ mode.A.T + U @ mode.B.T + rng.standard_normal((runs, mode.W.shape[1])) @ mode.W.T
        pred = M @ mode.A.T + U @ mode.B.T
        P = mode.A @ P @ mode.A.T + mode.W @ mode.W.T
        if mode.C is not None:
            Y = X @ mode.C.T
            if mode.V is not None:
                Y = Y + rng.standard_normal((runs, mode.V.shape[1])) @ mode.V.T
            P, G = _update_cov(P, mode.C, mode.V)
            M = pred + (Y - pred @ mode.C.T) @ G.T
        else:
            M = pred
        Xs.append(X)
        Ms.append(M)
        Ps.append(P)
    return np.stack(Ms, axis=1), np.array(Ps), np.stack(Xs, axis=1), moved / max(1, runs * N)


def success(
    case: PolytopeCase, means: np.ndarray, covs: np.ndarray, states: np.ndarray
) -> dict[str, np.ndarray]:
    """Per run, whether the formula held on the executed belief and on the true state (bool (runs,))."""
    runs = means.shape[0]
    ok = {"belief": np.ones(runs, dtype=bool), "state": np.ones(runs, dtype=bool)}
    for g in case.groups:
        z = norm.ppf(1.0 - g.eps)  # (F,)
        for k in range(g.a, g.b + 1):
            sd = np.sqrt(np.maximum(np.einsum("fi,ij,fj->f", g.H, covs[k], g.H), 0.0))
            ok["belief"] &= np.all(means[:, k] @ g.H.T + g.c + z * sd <= 0, axis=1)
            ok["state"] &= np.all(states[:, k] @ g.H.T + g.c <= 0, axis=1)
    return ok


# ------------------------------------------------------------------------------------------------
# random cases


def _domain(rng: np.random.Generator, family: str) -> tuple[np.ndarray, np.ndarray]:
    a = float(rng.uniform(0.5, 2.0))
    if family == "diamond":
        H = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]])
        return H, -a * np.ones(4)
    if family == "cut_box":
        s = rng.choice([-1.0, 1.0], size=2)
        H = np.vstack([np.eye(2), -np.eye(2), s[None, :]])
        kappa = float(rng.uniform(0.3, 1.6))  # the cut u0 +- u1 <= kappa a removes a corner
        return H, -a * np.array([1.0, 1.0, 1.0, 1.0, kappa])
    while True:  # a random polygon around 0 (bounded: no angular gap of pi or more)
        F = int(rng.integers(3, 9))
        ang = np.sort(rng.uniform(0.0, 2 * np.pi, F))
        gaps = np.diff(np.concatenate([ang, [ang[0] + 2 * np.pi]]))
        if gaps.max() < 0.9 * np.pi:
            break
    H = np.stack([np.cos(ang), np.sin(ang)], axis=1) * rng.uniform(0.5, 2.0, (F, 1))
    return H, -a * rng.uniform(0.5, 1.5, F) * np.linalg.norm(H, axis=1)


def _to_boundary(H: np.ndarray, c: np.ndarray, d: np.ndarray) -> float:
    """``t`` with ``t d`` on the boundary (the origin inside)."""
    hd = H @ d
    return float(np.min(-c[hd > 0] / hd[hd > 0]))


def random_case(
    seed: int, family: str | None = None, reach: tuple[float, float] = (0.55, 1.0)
) -> PolytopeCase:
    """A random 2-D problem whose plan pushes its inputs toward the faces of a random polygon.

    Families of domain: ``"diamond"`` (``|u0| + |u1| <= a``), ``"cut_box"`` (a box with a corner
    cut by ``u0 +- u1 <= kappa a``), ``"polygon"`` (3-8 random faces around the origin). One or
    two modes (the second may be blind); inputs at 55-100% (default) of the way from the origin to the
    boundary (``reach``) along one or two directions; the formula: a corridor around the plan's means the
    whole time and a goal around its final mean over the last steps, at random margins (success
    rates spread over the whole range).
    """
    rng = np.random.default_rng(seed)
    family = family or str(rng.choice(DOMAIN_FAMILIES))
    Hu, cu = _domain(rng, family)
    n = 2
    modes = []
    for q in range(int(rng.integers(1, 3))):
        th = rng.uniform(-0.15, 0.15)
        A = float(rng.uniform(0.95, 1.03)) * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        B = float(rng.uniform(0.15, 0.4)) * (np.eye(2) + 0.25 * rng.standard_normal((2, 2)))
        W = float(rng.uniform(0.01, 0.06)) * (np.eye(2) + 0.3 * rng.standard_normal((2, 2)))
        if q == 1 and rng.random() < 0.5:
            C, V = None, None
        elif rng.random() < 0.7:
            C, V = np.eye(2), float(rng.uniform(0.03, 0.3)) * np.eye(2)
        else:
            C = rng.standard_normal((1, 2))
            C /= np.linalg.norm(C)
            V = np.array([[float(rng.uniform(0.03, 0.3))]])
        modes.append(OracleMode(A, B, W, C, V))
    if all(mode.C is None for mode in modes):  # pragma: no cover - mode 0 always sees
        raise AssertionError("a case needs a sensing mode")
    N = int(rng.integers(8, 21))
    actions = rng.integers(0, len(modes), N)
    dirs = rng.standard_normal((2, 2))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    switch = int(rng.integers(N // 3, N + 1))
    controls = np.empty((N, 2))
    for k in range(N):
        d = dirs[0] if k < switch else dirs[1]
        controls[k] = float(rng.uniform(*reach)) * _to_boundary(Hu, cu, d) * d
    mean0 = rng.uniform(-1.0, 1.0, n)
    cov0 = float(rng.uniform(0.002, 0.03)) * np.eye(n)
    case = PolytopeCase(family, seed, modes, mean0, cov0, Hu, cu, actions, controls, [])
    means, covs = case.mlo_plan()
    groups = []
    # corridor: 2-4 directions, the plan's extreme reach plus a margin, at every step
    F = int(rng.integers(2, 5))
    ang = rng.uniform(0.0, 2 * np.pi) + np.arange(F) * 2 * np.pi / F
    G = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    eps = rng.choice([0.05, 0.1, 0.2], size=F)
    z = norm.ppf(1.0 - eps)
    sd = np.sqrt(np.einsum("fi,kij,fj->kf", G, covs, G))
    reach = np.max(means @ G.T + z * sd, axis=0)
    margin = rng.uniform(0.0, 2.5, F) * np.max(sd, axis=0) + rng.uniform(0.0, 0.1, F)
    groups.append(FaceGroup(G, -(reach + margin), eps, 0, N, "corridor"))
    # goal: 2-4 faces around the final mean over the last 0-2 steps
    F = int(rng.integers(2, 5))
    ang = rng.uniform(0.0, 2 * np.pi) + np.arange(F) * 2 * np.pi / F
    G = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    eps = rng.choice([0.05, 0.1, 0.2], size=F)
    w = int(rng.integers(0, 3))
    z = norm.ppf(1.0 - eps)
    sd = np.sqrt(np.einsum("fi,kij,fj->kf", G, covs[N - w :], G))
    reach = np.max(means[N - w :] @ G.T + z * sd, axis=0)
    margin = rng.uniform(-0.5, 2.0, F) * np.max(sd, axis=0) + rng.uniform(0.0, 0.05, F)
    groups.append(FaceGroup(G, -(reach + margin), eps, N - w, N, "goal"))
    case.groups = groups
    return case
