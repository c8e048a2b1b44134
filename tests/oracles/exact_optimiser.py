"""An independent exact optimiser for small one-mode problems: the ground truth of issue 25.

For one mode ``(A, B, W, C, V)`` with a *constant* sensor noise (or none), the belief covariance
does not depend on the controls, so every chance constraint ``P(h'x + c <= 0) >= 1 - eps`` is the
deterministic face ``h' mean_k + c + Phi^-1(1 - eps) sqrt(h' cov_k h) <= 0`` of the mean, and the
mean is affine in the controls: ``mean_k = A^k mean_0 + sum_{j<k} A^(k-1-j) B u_j``. The problem
of a plan of exactly ``N`` steps is then a MILP, written here from the definitions of
:mod:`oracles.brute_force` (strong reading on the finite trace of ``L = N + 1`` states: an index
``>= L`` satisfies nothing) and nothing of idstlpy's synthesis code:

- every (sub-formula, step) pair gets a robustness expression: ``+inf`` / ``-inf`` constants
  (mode atoms, ``TRUE``/``FALSE``, indices past the end), an affine function of the controls (a
  chance constraint's slack ``-(h' mean_k + c + z sd_k)``), or a fresh column ``r`` with
  ``r <= child`` for a conjunction and ``r <= child_i + M_i (1 - b_i)``, ``sum b_i = 1`` for a
  disjunction (``M_i`` from interval bounds of the children over the control box);
- until and release are expanded literally into those conjunctions and disjunctions;
- ``"margin"`` maximises the root (the monitor's robustness), ``"effort"`` minimises
  ``sum_k sum_j w_j |u_kj|`` with the root ``>= 0``, ``"time"`` asks for the smallest ``N``
  whose MILP is feasible.

Plans are enumerated by length ``N = 0 .. horizon`` (a plan longer than the formula's horizon
cannot do better: its prefix of ``horizon`` steps meets the formula the same way, costs no more
and has the same robustness). Each MILP is solved with :func:`scipy.optimize.milp` (HiGHS), then
its binaries are fixed and the LP over the controls re-solved (:func:`scipy.optimize.linprog`), so
the value is an LP vertex's, not within the MILP's tolerances; the plan is re-checked with the
independent roll-out and the brute-force monitor (loosened by 1e-9 relative).

The control domain must be a box ``lo <= u <= hi`` with finite sides.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, linprog, milp
from scipy.stats import norm

from .brute_force import sat
from .rollout import ModeSpec, loosen, mlo_rollout, mlo_step

__all__ = ["Optimum", "Undecided", "exact_optimum", "covariances", "random_small_problem"]

INF = math.inf


class Undecided(RuntimeError):
    """The MILP's plan meets the formula only within the solvers' tolerances: no ground truth."""


@dataclass
class Optimum:
    """The exact optimum of one objective.

    Attributes
    ----------
    feasible : bool
        Whether any plan of at most ``horizon`` steps meets the formula.
    value : float
        The optimum (``nan`` when infeasible; for ``"margin"`` the largest robustness, negative
        when infeasible).
    steps : int
        Length ``N`` of an optimal plan (``-1`` when infeasible).
    controls : ndarray, shape (N, m) or None
    per_length : dict of int to float
        The optimum of every plan length that has a plan.
    """

    feasible: bool
    value: float
    steps: int
    controls: np.ndarray | None
    per_length: dict[int, float]


def covariances(mode: ModeSpec, mean0: np.ndarray, cov0: np.ndarray, N: int) -> list[np.ndarray]:
    """``cov_0 .. cov_N`` of the MLO filter (independent of the controls here)."""
    if mode.state_dependent:
        raise ValueError("the exact optimiser needs a constant sensor noise")
    m = mode.B.shape[1]
    mean, cov = np.asarray(mean0, float), np.asarray(cov0, float)
    out = [cov]
    for _ in range(N):
        mean, cov = mlo_step(mode, mean, cov, np.zeros(m))
        out.append(cov)
    return out


class _Model:
    """Columns ``u`` (N m), then added robustness columns and binaries; rows collected."""

    def __init__(self, N: int, m: int, lo: np.ndarray, hi: np.ndarray) -> None:
        self.nu = N * m
        self.lb = list(np.tile(lo, N))
        self.ub = list(np.tile(hi, N))
        self.integer = [0] * self.nu
        self.rows: list[tuple[dict[int, float], float, float]] = []  # (coefs, lo, hi)
        self.lo_u, self.hi_u = np.tile(lo, N), np.tile(hi, N)

    def column(self, lb: float, ub: float, integer: bool = False) -> int:
        self.lb.append(lb)
        self.ub.append(ub)
        self.integer.append(1 if integer else 0)
        return len(self.lb) - 1

    def row(self, coefs: dict[int, float], lo: float, hi: float) -> None:
        self.rows.append((coefs, lo, hi))

    def affine_range(self, a: np.ndarray, c: float) -> tuple[float, float]:
        pos, neg = np.maximum(a, 0.0), np.minimum(a, 0.0)
        return (
            float(pos @ self.lo_u + neg @ self.hi_u + c),
            float(pos @ self.hi_u + neg @ self.lo_u + c),
        )


@dataclass
class _Aff:
    a: np.ndarray  # coefficients over u
    c: float
    lo: float
    hi: float


@dataclass
class _Var:
    col: int
    lo: float
    hi: float


def _le(model: _Model, col: int, child: Any, slack_col: int | None = None, big: float = 0.0) -> None:
    """Row ``r_col <= child (+ big (1 - b))``."""
    coefs: dict[int, float] = {col: 1.0}
    rhs = 0.0
    if isinstance(child, _Aff):
        for j in np.flatnonzero(child.a):
            coefs[int(j)] = coefs.get(int(j), 0.0) - float(child.a[j])
        rhs = child.c
    else:
        coefs[child.col] = coefs.get(child.col, 0.0) - 1.0
    if slack_col is not None:
        coefs[slack_col] = big
        rhs += big
    model.row(coefs, -INF, rhs)


def _and(model: _Model, children: list[Any]) -> Any:
    kids = [c for c in children if c != INF]
    if any(c == -INF for c in kids):
        return -INF
    if not kids:
        return INF
    if len(kids) == 1:
        return kids[0]
    lo, hi = min(k.lo for k in kids), min(k.hi for k in kids)
    col = model.column(lo, hi)
    for k in kids:
        _le(model, col, k)
    return _Var(col, lo, hi)


def _or(model: _Model, children: list[Any]) -> Any:
    kids = [c for c in children if c != -INF]
    if any(c == INF for c in kids):
        return INF
    if not kids:
        return -INF
    if len(kids) == 1:
        return kids[0]
    lo, hi = min(k.lo for k in kids), max(k.hi for k in kids)
    col = model.column(lo, hi)
    picks = []
    for k in kids:
        b = model.column(0.0, 1.0, integer=True)
        picks.append(b)
        _le(model, col, k, b, hi - k.lo)
    model.row({b: 1.0 for b in picks}, 1.0, 1.0)
    return _Var(col, lo, hi)


def _build(
    formula: Any, mode: ModeSpec, mean0: np.ndarray, covs: list[np.ndarray], N: int, model: _Model
) -> Any:
    """The root's robustness expression for plans of exactly ``N`` steps."""
    from idstlpy.formulas import STLAnd, STLAtomicProposition, STLOr, STLRelease, STLUntil

    n, m = mode.A.shape[0], mode.B.shape[1]
    L = N + 1
    # mean_k = M[k] u + g[k]
    M = [np.zeros((n, N * m))]
    g = [np.asarray(mean0, float)]
    for k in range(1, L):
        Mk = mode.A @ M[-1]
        Mk[:, (k - 1) * m : k * m] += mode.B
        M.append(Mk)
        g.append(mode.A @ g[-1])
    memo: dict[tuple[int, int], Any] = {}

    def atom(f: Any, k: int) -> Any:
        if f.is_false:
            return -INF
        if f.modes is not None and k >= 1 and 0 not in f.modes:
            return -INF
        parts = []
        for p in f.predicates:
            h = np.asarray(p.h, float).reshape(-1)
            var = float(h @ covs[k] @ h)
            if p.eps == 0.0:
                if var > 0.0:
                    return -INF
                z_sd = 0.0
            else:
                z_sd = float(norm.ppf(1.0 - p.eps)) * math.sqrt(max(var, 0.0))
            a = -(h @ M[k])
            c = -(float(h @ g[k]) + float(p.c) + z_sd)
            lo, hi = model.affine_range(a, c)
            parts.append(_Aff(a, c, lo, hi))
        return _and(model, parts)

    def rec(f: Any, k: int) -> Any:
        if k >= L:
            return -INF
        key = (id(f), k)
        if key in memo:
            return memo[key]
        if isinstance(f, STLAtomicProposition):
            out = atom(f, k)
        elif isinstance(f, STLAnd):
            out = _and(model, [rec(c, k) for c in f.children])
        elif isinstance(f, STLOr):
            out = _or(model, [rec(c, k) for c in f.children])
        elif isinstance(f, STLUntil):
            options = []
            for j in range(k + f.a, k + f.b + 1):
                if j >= L:
                    break
                options.append(_and(model, [rec(f.right, j)] + [rec(f.left, i) for i in range(k + f.a, j)]))
            out = _or(model, options)
        elif isinstance(f, STLRelease):
            options = []
            for j in range(k + f.a, k + f.b + 1):
                if j >= L:
                    break
                options.append(
                    _and(model, [rec(f.left, j)] + [rec(f.right, i) for i in range(k + f.a, j + 1)])
                )
            if k + f.b < L:
                options.append(_and(model, [rec(f.right, i) for i in range(k + f.a, k + f.b + 1)]))
            out = _or(model, options)
        else:
            raise TypeError(f"unknown formula type {type(f).__name__}")
        memo[key] = out
        return out

    return rec(formula, 0)


def _lp(c, A, rlo, rhi, lb, ub):
    """``min c'x`` over the rows and bounds with :func:`linprog` (HiGHS), or None."""
    A_ub, b_ub, A_eq, b_eq = [], [], [], []
    for i in range(A.shape[0]):
        if rlo[i] == rhi[i]:
            A_eq.append(A[i])
            b_eq.append(rhi[i])
            continue
        if np.isfinite(rhi[i]):
            A_ub.append(A[i])
            b_ub.append(rhi[i])
        if np.isfinite(rlo[i]):
            A_ub.append(-A[i])
            b_ub.append(-rlo[i])
    return linprog(
        c,
        A_ub=np.array(A_ub) if A_ub else None,
        b_ub=b_ub if A_ub else None,
        A_eq=np.array(A_eq) if A_eq else None,
        b_eq=b_eq if A_eq else None,
        bounds=list(zip(lb, ub, strict=True)),
        method="highs",
    )


def _branch_and_bound(c, A, rlo, rhi, lb, ub, integ, max_nodes: int = 200_000):
    """A plain depth-first branch and bound over LPs (binaries only): the optimum's x, or None."""
    best_x, best_val = None, INF
    stack = [(lb.copy(), ub.copy())]
    nodes = 0
    ints = np.flatnonzero(integ == 1)
    while stack:
        nodes += 1
        if nodes > max_nodes:
            raise RuntimeError("exact optimiser: branch and bound node limit")
        nlb, nub = stack.pop()
        res = _lp(c, A, rlo, rhi, nlb, nub)
        if res.status != 0 or res.fun >= best_val - 1e-12:
            continue
        frac = ints[np.abs(res.x[ints] - np.round(res.x[ints])) > 1e-9]
        if frac.size == 0:
            best_x, best_val = res.x, float(res.fun)
            continue
        j = frac[0]
        for v in (0.0, 1.0):
            blb, bub = nlb.copy(), nub.copy()
            blb[j] = bub[j] = v
            stack.append((blb, bub))
    return best_x


def _solve_length(
    mode: ModeSpec,
    lo: np.ndarray,
    hi: np.ndarray,
    mean0: np.ndarray,
    covs: list[np.ndarray],
    formula: Any,
    N: int,
    objective: str,
    weights: np.ndarray,
) -> tuple[float, np.ndarray] | None:
    """The optimum over plans of exactly ``N`` steps and its controls, or None (no plan)."""
    m = mode.B.shape[1]
    model = _Model(N, m, lo, hi)
    root = _build(formula, mode, mean0, covs, N, model)
    if root == -INF:
        return None
    r = model.column(-INF, INF)
    if root != INF:
        _le(model, r, root)
        model.lb[r], model.ub[r] = root.lo, root.hi
    elif objective == "margin":
        return INF, np.zeros((N, m))
    if objective != "margin" and root != INF and root.hi < 0:
        return None  # the root's robustness is negative for every control in the box
    nvar0 = len(model.lb)
    if objective == "effort":
        model.lb[r] = 0.0
        acols = [model.column(0.0, INF) for _ in range(model.nu)]
        for j, a in enumerate(acols):
            model.row({j: 1.0, a: -1.0}, -INF, 0.0)
            model.row({j: -1.0, a: -1.0}, -INF, 0.0)
    elif objective == "time":
        model.lb[r] = 0.0
    nvar = len(model.lb)
    c = np.zeros(nvar)
    if objective == "margin":
        c[r] = -1.0
    elif objective == "effort":
        c[nvar0:] = np.tile(weights, N)
    A = np.zeros((len(model.rows), nvar))
    rlo, rhi = np.empty(len(model.rows)), np.empty(len(model.rows))
    for i, (coefs, a, b) in enumerate(model.rows):
        for j, v in coefs.items():
            A[i, j] += v
        rlo[i], rhi[i] = a, b
    lb, ub = np.array(model.lb), np.array(model.ub)
    integ = np.array(model.integer)
    cons = [LinearConstraint(A, rlo, rhi)] if len(model.rows) else []
    res = milp(c, constraints=cons, integrality=integ, bounds=Bounds(lb, ub), options={"mip_rel_gap": 1e-9})
    if res.x is None and res.status == 4:
        # HiGHS' presolve fails now and then on these models ("Solve error"); without it, it solves.
        options = {"mip_rel_gap": 1e-9, "presolve": False}
        res = milp(c, constraints=cons, integrality=integ, bounds=Bounds(lb, ub), options=options)
    if res.x is None and res.status == 4:
        # ... and now and then it fails with or without (a few small margin models): a plain
        # branch and bound over LPs decides those.
        x_bb = _branch_and_bound(c, A, rlo, rhi, lb, ub, integ)
        if x_bb is None:
            return None
        res.x, res.status = x_bb, 0
    if res.x is None:
        if res.status == 2:  # infeasible
            return None
        raise RuntimeError(f"exact optimiser: MILP failed ({res.message})")
    # Fix the binaries and re-solve the LP: the value is a vertex's.
    fixed_lb, fixed_ub = lb.copy(), ub.copy()
    ints = integ == 1
    fixed_lb[ints] = fixed_ub[ints] = np.round(res.x[ints])
    lp = _lp(c, A, rlo, rhi, fixed_lb, fixed_ub)
    x = lp.x if lp.status == 0 else res.x
    controls = np.asarray(x[: model.nu]).reshape(N, m)
    if objective == "margin":
        return float(x[r]), controls
    if objective == "effort":
        return float(np.sum(np.abs(controls) @ weights)), controls
    return float(N), controls


def exact_optimum(
    mode: ModeSpec,
    lo: Any,
    hi: Any,
    mean0: Any,
    cov0: Any,
    formula: Any,
    objective: str,
    weights: Any = None,
    max_steps: int | None = None,
    check: bool = True,
) -> Optimum:
    """The exact optimum of ``objective`` over every plan of at most ``horizon`` steps.

    Parameters
    ----------
    mode : ModeSpec
        The one mode (constant sensor noise or none).
    lo, hi : array_like, shape (m,)
        The control box (finite).
    mean0 : array_like, shape (n,)
    cov0 : array_like, shape (n, n)
    formula : STLFormula
    objective : {"effort", "time", "margin"}
    weights : array_like, shape (m,), optional
        Effort weights (default ones).
    max_steps : int, optional
        Longest plan (default: the formula's horizon).
    check : bool
        Re-check the optimal plan with the independent roll-out and monitor.

    Returns
    -------
    Optimum
    """
    lo, hi = np.asarray(lo, float).reshape(-1), np.asarray(hi, float).reshape(-1)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError("the exact optimiser needs a bounded control box")
    mean0 = np.asarray(mean0, float).reshape(-1)
    cov0 = np.asarray(cov0, float).reshape(mean0.size, mean0.size)
    m = mode.B.shape[1]
    w = np.ones(m) if weights is None else np.asarray(weights, float)
    Nmax = formula.horizon if max_steps is None else int(max_steps)
    covs = covariances(mode, mean0, cov0, Nmax)
    per: dict[int, float] = {}
    best: tuple[float, int, np.ndarray] | None = None
    for N in range(Nmax + 1):
        out = _solve_length(mode, lo, hi, mean0, covs, formula, N, objective, w)
        if out is None:
            continue
        value, controls = out
        per[N] = value
        if objective == "time":
            best = (value, N, controls)
            break
        if best is None or (value > best[0] if objective == "margin" else value < best[0]):
            best = (value, N, controls)
    if best is None:
        return Optimum(False, float("nan"), -1, None, per)
    value, N, controls = best
    # The margin's optimum is the largest robustness, negative when no plan meets the formula.
    feasible = objective != "margin" or value >= 0
    if check and feasible and np.isfinite(value):
        trace = mlo_rollout([mode], mean0, cov0, np.zeros(N, dtype=int), controls)
        if not sat(loosen(formula, trace, 1e-7), 0, trace):
            raise Undecided("the optimal plan fails the brute-force monitor: feasible within tolerances only")
    return Optimum(feasible, float(value), N, controls, per)


# ------------------------------------------------------------------------------------------------
# random small problems (the optimality property test and benchmarks/optimality_check.py)


@dataclass
class SmallProblem:
    """A random one-mode problem in the exact optimiser's scope, with its plain arrays."""

    problem: Any
    mode: ModeSpec
    lo: np.ndarray
    hi: np.ndarray
    mean0: np.ndarray
    cov0: np.ndarray
    formula: Any
    weights: np.ndarray
    noisy: bool
    describe: str


def random_small_problem(seed: int, noisy: bool | None = None) -> SmallProblem:
    """A random small one-mode problem (1-2 states, horizon <= 12, constant or no sensor noise).

    The formula is built around a random admissible roll-out (targets and corridors centred on
    its means, widened by the chance constraints' tightening and a random slack, sometimes
    almost zero), so most instances are feasible; one shape in eight puts the goal near or
    beyond the edge of the reachable set instead. The exact optimiser decides. Domains are
    boxes: symmetric, off-centre, or excluding ``u = 0``.
    """
    import idstlpy as stl

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3))
    m = n if rng.random() < 0.7 else 1
    kind = rng.choice(["integrator", "random"])
    A = np.eye(n) if kind == "integrator" else np.eye(n) + 0.15 * rng.standard_normal((n, n))
    B = np.zeros((n, m))
    for j in range(m):
        B[j % n, j] = float(rng.choice([0.05, 0.1, 0.25, 0.5, 1.0]))
    if rng.random() < 0.3:
        B += 0.1 * rng.standard_normal((n, m))
    dom = rng.choice(["symmetric", "off_centre", "no_zero"])
    a = rng.uniform(0.3, 1.5, m)
    if dom == "symmetric":
        lo, hi = -a, a
    elif dom == "off_centre":
        lo, hi = -a * rng.uniform(0.1, 1.0, m), a
    else:
        lo = rng.uniform(0.05, 0.3, m)
        hi = lo + a
        flip = rng.random(m) < 0.5
        lo, hi = np.where(flip, -hi, lo), np.where(flip, -lo, hi)
    noisy = bool(rng.random() < 0.5) if noisy is None else noisy
    mean0 = rng.uniform(-1, 1, n)
    cov0 = np.zeros((n, n))
    W = np.zeros((n, n))
    C = V = None
    if noisy:
        cov0 = np.diag(rng.uniform(0.0005, 0.02, n))
        if rng.random() < 0.6:
            W = float(rng.uniform(0.01, 0.08)) * np.eye(n)
        if rng.random() < 0.5:
            C = np.eye(n)
            V = float(rng.uniform(0.02, 0.3)) * np.eye(n)
    mode = ModeSpec(A, B, W, C, V)
    H = int(rng.integers(2, 13))
    controls = rng.uniform(lo, hi, (H, m))
    trace = mlo_rollout([mode], mean0, cov0, np.zeros(H, dtype=int), controls)
    means = np.array([s[0] for s in trace.states])
    sds = np.array([np.sqrt(np.diag(s[1])) for s in trace.states])

    x = stl.mk_variable(n)
    u = stl.mk_variable(m, name="u")
    eps = float(rng.choice([0.05, 0.1, 0.2]))
    z = float(norm.ppf(1 - eps))

    def box(steps: list[int], name: str, tiny: bool = False) -> Any:
        centre = means[steps].mean(axis=0)
        spread = np.abs(means[steps] - centre).max(axis=0) + z * sds[steps].max(axis=0)
        slack = np.full(n, 1e-6) if tiny else rng.uniform(0.02, 0.4, n)
        half = spread + slack
        parts = []
        for i in range(n):
            if rng.random() < 0.85 or i == 0:
                parts += [
                    stl.prob(x[i] >= float(centre[i] - half[i])) >= 1 - eps,
                    stl.prob(x[i] <= float(centre[i] + half[i])) >= 1 - eps,
                ]
        return stl.logical_and(*parts, name=name)

    shape = rng.choice(["reach", "reach_tiny", "either", "stay_reach", "until", "release", "always", "far"])
    k = int(rng.integers(1, H + 1))
    a0 = int(rng.integers(0, k + 1))
    if shape in ("reach", "reach_tiny"):
        formula = stl.eventually(a0, H, box([k], "goal", tiny=shape == "reach_tiny"))
    elif shape == "either":
        other = means[k] + rng.uniform(-2, 2, n)
        far = stl.logical_and(
            *[stl.prob(x[i] >= float(other[i] - 0.2)) >= 1 - eps for i in range(n)],
            *[stl.prob(x[i] <= float(other[i] + 0.2)) >= 1 - eps for i in range(n)],
            name="other",
        )
        formula = stl.logical_or(stl.eventually(a0, H, box([k], "goal")), stl.eventually(0, H, far))
    elif shape == "stay_reach":
        formula = stl.logical_and(
            stl.always(0, H, box(list(range(H + 1)), "corridor")), stl.eventually(a0, H, box([k], "goal"))
        )
    elif shape == "until":
        formula = stl.until(box(list(range(k)) or [0], "safe"), a0, H, box([k], "goal"))
    elif shape == "release":
        formula = stl.release(box([k], "goal"), 0, H, box(list(range(k + 1)), "safe"))
    elif shape == "far":
        # A goal near the edge of what k steps reach, or beyond it: feasible or not, maybe narrowly.
        reach = k * float(np.max(np.abs(B))) * float(np.max(np.abs(np.r_[lo, hi])))
        centre = means[k] + rng.choice([-1.0, 1.0], n) * rng.uniform(0.3, 1.3, n) * reach
        half = z * sds[k] + (1e-6 if rng.random() < 0.3 else 0.05)
        goal = stl.logical_and(
            *[stl.prob(x[i] >= float(centre[i] - half[i])) >= 1 - eps for i in range(n)],
            *[stl.prob(x[i] <= float(centre[i] + half[i])) >= 1 - eps for i in range(n)],
            name="goal",
        )
        formula = stl.eventually(a0, k, goal)
    else:
        b0 = int(rng.integers(k, H + 1))
        formula = stl.always(k, b0, box(list(range(k, b0 + 1)), "hold"))
    lbs = stl.mk_lbs(A, B, W) if C is None else stl.mk_lbs(A, B, W, C=C, V=V)
    domain = stl.logical_and(
        *[u[j] >= float(lo[j]) for j in range(m)], *[u[j] <= float(hi[j]) for j in range(m)]
    )
    problem = stl.Problem(stl.mk_switched_sys([lbs]), domain.region, stl.to_belief(mean0, cov0), formula)
    weights = np.ones(m) if rng.random() < 0.7 else rng.uniform(0.5, 2.0, m)
    text = (
        f"seed {seed}: n={n} m={m} {kind} dom={dom} [{np.round(lo, 3)}, {np.round(hi, 3)}] "
        f"noisy={noisy} H={formula.horizon} {shape}: {formula}"
    )
    return SmallProblem(problem, mode, lo, hi, mean0, cov0, formula, weights, noisy, text)
