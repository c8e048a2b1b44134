"""A hand-written chance-constrained MILP peer for PrSTL with state-independent noise.

When the observation noise does not depend on the state, the MLO covariance schedule
``S_0, S_1, ..`` of a fixed mode sequence does not depend on the controls, so every chance
constraint ``prob(h' x + c <= 0) >= 1 - eps`` has the deterministic equivalent

    h' m_k + c + Phi^-1(1 - eps) sqrt(h' S_k h) <= 0,

linear in the mean ``m_k``, itself linear in the controls. The formula is encoded with the
classic big-M scheme (one binary per atomic proposition and step, continuous ``[0, 1]``
indicators for ``and`` / ``or``, until / release unrolled over their windows, strong reading
past the horizon) and solved by HiGHS through :func:`scipy.optimize.milp`.

The peer handles one mode (the schedule is then fixed); :func:`noisy_reach_avoid` is the
benchmark problem: a 2-D single integrator with process noise and a constant-noise position
sensor that must avoid an obstacle, stay in the workspace and reach a goal.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.optimize import Bounds, LinearConstraint, milp

import idstlpy as I
from idstlpy.belief import belief_step
from idstlpy.formulas import STLAnd, STLAtomicProposition, STLOr, STLRelease, STLUntil

__all__ = ["noisy_reach_avoid", "solve_prstl_milp", "MILPEncoder"]

BIG_M = 1000.0
MARGIN = 1e-6  # tighten every deterministic equivalent so HiGHS tolerances cannot flip the monitor


def noisy_reach_avoid(T: int, eps: float = 0.05) -> I.Problem:
    """2-D reach-avoid under noise: ``G[0,T](workspace & not obstacle) & F[0,T] goal``.

    ``x' = x + u + 0.05 w`` (``|u_i| <= 0.5``), sensor ``y = x + 0.1 v``; prior ``N([1, 2],
    0.01 I)``; goal ``[7, 8] x [8, 9]``, obstacle ``[3, 5] x [4, 6]``, workspace
    ``[0, 10]^2``; every chance constraint at ``1 - eps``.
    """
    x = I.mk_variable(2, name="x")
    u = I.mk_variable(2, name="u")
    lvl = 1 - eps
    mode = I.mk_lbs(A=np.eye(2), B=np.eye(2), W=0.05 * np.eye(2), C=np.eye(2), V=0.1 * np.eye(2))
    workspace = I.logical_and(
        I.prob(x[0] >= 0) >= lvl,
        I.prob(x[0] <= 10) >= lvl,
        I.prob(x[1] >= 0) >= lvl,
        I.prob(x[1] <= 10) >= lvl,
        name="workspace",
    )
    outside = I.logical_or(
        I.prob(x[0] <= 3) >= lvl, I.prob(x[0] >= 5) >= lvl, I.prob(x[1] <= 4) >= lvl, I.prob(x[1] >= 6) >= lvl
    )
    goal = I.logical_and(
        I.prob(x[0] >= 7) >= lvl,
        I.prob(x[0] <= 8) >= lvl,
        I.prob(x[1] >= 8) >= lvl,
        I.prob(x[1] <= 9) >= lvl,
        name="goal",
    )
    spec = I.logical_and(I.always(0, T, I.logical_and(workspace, outside)), I.eventually(0, T, goal))
    return I.Problem(
        switched_system=I.mk_switched_sys([mode]),
        control_domain=I.logical_and(u[0] >= -0.5, u[0] <= 0.5, u[1] >= -0.5, u[1] <= 0.5).region,
        initial_state=I.to_belief(mean=np.array([1.0, 2.0]), cov=0.01 * np.eye(2)),
        stl_formula=spec,
    )


class MILPEncoder:
    """Big-M encoding of a PrSTL formula over a fixed covariance schedule."""

    def __init__(self, problem: I.Problem, N: int) -> None:
        sysm = problem.switched_system
        if sysm.num_modes != 1:
            raise ValueError("the MILP peer fixes the mode sequence: one mode only")
        mode = sysm.system_modes[0]
        if mode.has_state_dependent_noise:
            raise ValueError("the MILP peer needs state-independent noise (fixed covariances)")
        self.problem, self.N, self.mode = problem, int(N), mode
        n, m = sysm.n, sysm.m
        self.n, self.m = n, m
        # Covariance schedule (independent of the controls and of the mean).
        covs = [problem.initial_state.cov]
        for _ in range(N):
            covs.append(belief_step(mode, np.zeros(n), covs[-1], np.zeros(m))[1])
        self.covs = covs
        self.lb: list[float] = []
        self.ub: list[float] = []
        self.integ: list[int] = []
        self.rows: list[tuple[dict[int, float], float, float]] = []
        self.mean = [self._vars(n) for _ in range(N + 1)]
        self.u = [self._vars(m) for _ in range(N)]
        self._memo: dict[tuple[int, int], Any] = {}

    # -- model building -------------------------------------------------------------------------
    def _vars(self, k: int, lo: float = -np.inf, hi: float = np.inf, integer: bool = False) -> list[int]:
        start = len(self.lb)
        self.lb.extend([lo] * k)
        self.ub.extend([hi] * k)
        self.integ.extend([1 if integer else 0] * k)
        return list(range(start, start + k))

    def _row(self, coefs: dict[int, float], lo: float, hi: float) -> None:
        self.rows.append((coefs, lo, hi))

    def dynamics(self) -> None:
        A, B = self.mode.A, self.mode.B
        m0 = self.problem.initial_state.mean
        for i in range(self.n):
            self._row({self.mean[0][i]: 1.0}, m0[i], m0[i])
        dom = self.problem.control_domain
        for k in range(self.N):
            for i in range(self.n):
                row = {self.mean[k + 1][i]: 1.0}
                for j in range(self.n):
                    if A[i, j]:
                        row[self.mean[k][j]] = row.get(self.mean[k][j], 0.0) - A[i, j]
                for j in range(self.m):
                    if B[i, j]:
                        row[self.u[k][j]] = -B[i, j]
                self._row(row, 0.0, 0.0)
            for r in range(dom.H.shape[0]):  # H u + c <= 0
                self._row(
                    {self.u[k][j]: dom.H[r, j] for j in range(self.m) if dom.H[r, j]}, -np.inf, -dom.c[r]
                )

    def z(self, f: Any, k: int) -> Any:
        """Indicator of ``f`` at step ``k``: a column index, or the constant True / False."""
        key = (id(f), k)
        if key not in self._memo:
            self._memo[key] = self._encode(f, k)
        return self._memo[key]

    def _and(self, parts: list[Any]) -> Any:
        if any(p is False for p in parts):
            return False
        cols = [p for p in parts if p is not True]
        if not cols:
            return True
        if len(cols) == 1:
            return cols[0]
        (z,) = self._vars(1, 0.0, 1.0)
        for c in cols:
            self._row({z: 1.0, c: -1.0}, -np.inf, 0.0)
        return z

    def _or(self, parts: list[Any]) -> Any:
        if any(p is True for p in parts):
            return True
        cols = [p for p in parts if p is not False]
        if not cols:
            return False
        if len(cols) == 1:
            return cols[0]
        (z,) = self._vars(1, 0.0, 1.0)
        row = {z: 1.0}
        for c in cols:
            row[c] = row.get(c, 0.0) - 1.0
        self._row(row, -np.inf, 0.0)
        return z

    def _encode(self, f: Any, k: int) -> Any:
        if k > self.N:
            return False  # strong reading: nothing holds past the end of the trace
        if isinstance(f, STLAtomicProposition):
            if f.is_false:
                return False
            if f.modes is not None and k >= 1 and 0 not in f.modes:
                return False
            if not f.predicates:
                return True
            cone = f.cone
            (z,) = self._vars(1, 0.0, 1.0, integer=True)
            S = self.covs[k]
            for r in range(cone.H.shape[0]):
                h = cone.H[r]
                sd = float(np.sqrt(max(h @ S @ h, 0.0)))
                tight = float(cone.c[r] + (cone.z[r] * sd if sd > 0 else 0.0)) + MARGIN
                row = {self.mean[k][j]: h[j] for j in range(self.n) if h[j]}
                row[z] = BIG_M  # h' m + tight <= M (1 - z)
                self._row(row, -np.inf, BIG_M - tight)
            return z
        if isinstance(f, STLAnd):
            return self._and([self.z(c, k) for c in f.children])
        if isinstance(f, STLOr):
            return self._or([self.z(c, k) for c in f.children])
        if isinstance(f, STLUntil):
            branches = []
            for d in range(f.a, f.b + 1):
                if k + d > self.N:
                    break
                branches.append(
                    self._and([self.z(f.right, k + d)] + [self.z(f.left, k + j) for j in range(f.a, d)])
                )
            return self._or(branches)
        if isinstance(f, STLRelease):
            all_right = self._and([self.z(f.right, k + d) for d in range(f.a, f.b + 1)])
            branches = [all_right]
            for d in range(f.a, f.b + 1):
                if k + d > self.N:
                    break
                branches.append(
                    self._and([self.z(f.left, k + d)] + [self.z(f.right, k + j) for j in range(f.a, d + 1)])
                )
            return self._or(branches)
        raise TypeError(f"cannot encode {type(f).__name__}")

    def build(self) -> None:
        self.dynamics()
        root = self.z(self.problem.stl_formula, 0)
        if root is False:
            self._row({}, 1.0, 1.0)  # infeasible on purpose
        elif root is not True:
            self._row({root: 1.0}, 1.0, 1.0)

    def matrices(self) -> tuple[sp.csr_matrix, np.ndarray, np.ndarray]:
        data, ri, ci, lo, hi = [], [], [], [], []
        for r, (coefs, a, b) in enumerate(self.rows):
            for c, v in coefs.items():
                ri.append(r)
                ci.append(c)
                data.append(v)
            lo.append(a)
            hi.append(b)
        A = sp.csr_matrix((data, (ri, ci)), shape=(len(self.rows), len(self.lb)))
        return A, np.array(lo), np.array(hi)


def solve_prstl_milp(
    problem: I.Problem, N: int, time_limit: float = 60.0, t_start: float | None = None
) -> dict[str, Any]:
    """Encode and solve; returns timings, status and the controls (``None`` without a plan)."""
    t0 = time.perf_counter() if t_start is None else t_start
    enc = MILPEncoder(problem, N)
    enc.build()
    A, lo, hi = enc.matrices()
    build_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    res = milp(
        c=np.zeros(len(enc.lb)),
        constraints=LinearConstraint(A, lo, hi),
        integrality=np.array(enc.integ),
        bounds=Bounds(np.array(enc.lb), np.array(enc.ub)),
        options={"time_limit": float(max(time_limit - build_s, 0.1)), "disp": False},
    )
    solve_s = time.perf_counter() - t1
    out: dict[str, Any] = {
        "build_s": build_s,
        "solve_s": solve_s,
        "e2e_s": build_s + solve_s,
        "nvars": len(enc.lb),
        "ncons": len(enc.rows),
        "nbin": int(sum(enc.integ)),
        "detail": f"scipy.milp status {res.status}: {res.message}",
        "controls": None,
    }
    if res.x is not None:
        out["controls"] = np.array([[res.x[c] for c in enc.u[k]] for k in range(N)])
        out["status"] = "solved"
    elif res.status == 2:
        out["status"] = "infeasible"
    elif res.status == 1:
        out["status"] = "timeout"
    else:
        out["status"] = "error"
    return out
