"""The joint MILP: modes, propositions and inputs of a multi-mode plan chosen in one model (issue 31).

The eager MILP (:mod:`.milp`) holds a single-mode problem whose covariance schedule is fixed. With
several modes whose sensor noise does not depend on the state (:func:`~.covariances.lp_exact`)
the covariance at step ``k`` is a function of the mode sequence alone, and the plan is decided
here in one mixed-integer model:

- the letters of the proposer's BMC encoding, as in the eager MILP: propositions ``p[i, k]``, the
  one-hot modes ``m[q, k]`` (mode used to arrive at ``k``), the trace length, and every Tseitin
  gate and learnt clause. Mode constraints written in the formula (duty cycles on a mode
  variable, "no sensing in a region", "sense only while still") are clauses of that encoding,
  hence rows of this model, not filters on enumerated sequences;
- the means' dynamics with one input block per mode (``u_k = sum_q u_k^q``, ``u_k^q`` in
  ``m[q, k+1] U``: the perspective of a bounded control domain, exact) where the modes' ``B``
  differ; the modes must share ``A`` (otherwise the model is not built);
- each chance constraint ``h' x_k + c + z sqrt(h' Sigma_k h) <= 0`` claimed at ``k`` as big-M rows
  whose tightening is a *lower bound* of the true one, indexed by the pattern of the last few
  modes (:class:`CovarianceTables`): the Riccati maps are monotone in the prior, so the covariance
  after a pattern ``s`` applied to a lower bound ``L_j`` of every ``Sigma_j`` bounds every
  sequence that ends with ``s`` from below. The model is a relaxation: its ``infeasible`` is a
  proof for plans of at most ``bound + 1`` steps;
- lazily added cuts: the model's plan is rolled through the exact recursion on its own modes;
  a claimed face it violates gets the rows of the shortest suffix pattern whose lower bound
  already refutes the plan's mean (:meth:`JointSolver.cut`), at every step that pattern can end
  at. The cut says what those modes cannot achieve, for every sequence that ends with them (a
  full-prefix pattern is the exact covariance, the last resort).

The returned plan is the model's letters, modes and inputs after the exact check; the caller
(:mod:`.eager`) hands it to the plan LP teacher and the loop's verify step.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix, eye, hstack, kron, vstack

from ..backends import Backend, LinearModel
from ..chance import std_terms
from .bmc import BMCEncoder
from .covariances import covariance_schedule, lp_exact
from .interfaces import Budget
from .milp_bounds import hard_steps, invariant_box, support, support_points
from .milp_model import RowBlocks, clause_rows
from .plan_lp import PlanLPContext

if TYPE_CHECKING:
    from ..dynamical_system import LCS

__all__ = ["CovarianceTables", "JointAnswer", "JointModel", "JointSolver", "joint_supported"]

logger = logging.getLogger("idstlpy.synthesis.milp")

PATTERN_CAP = 32
"""Most mode patterns per step in the first model (``num_modes ** window``): 2 modes look 5 steps
back, 3 modes 3 steps."""

_Row = tuple[int, tuple[int, ...], float]
"""A pattern row: the direction (or face), the mode pattern it holds under (oldest first) and its
standard deviation (or room)."""

_MAX_BIG_M = 1e7  # normalised, scaled units: beyond this the model is numerically unreliable
ROOM_WINDOW = 2
"""Execution cuts hold under this many table windows of the plan's last modes."""

_SD_TOL = 1e-3  # relative: a pattern's standard deviation this close to a weaker one adds no row
_VIOLATION = 1e-5  # normalised rows: what the exact check counts as a violated face


def joint_supported(ctx: PlanLPContext) -> str | None:
    """Why the joint model cannot hold ``ctx``'s system (``None`` when it can)."""
    system = ctx.system
    if system.num_modes < 2:
        return "one mode (the eager MILP's case)"
    if not lp_exact(system):
        return "the covariance depends on the mean"
    modes = system.system_modes
    A0 = modes[0].A
    if any(not np.array_equal(mode.A, A0) for mode in modes[1:]):
        return "the modes' A differ"
    low, high = ctx.control_domain.bounding_box()
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
        if any(not np.array_equal(mode.B, modes[0].B) for mode in modes[1:]):
            return "the modes' B differ and the control domain is unbounded"
    return None


def _riccati(mode: LCS, S: np.ndarray) -> np.ndarray:
    """One exact MLO covariance step of ``mode`` (prediction, then the update if it senses)."""
    P = mode.A @ S @ mode.A.T + mode.process_cov
    if mode.p == 0:
        return np.asarray(P)
    R = mode.noise_cov(np.zeros(S.shape[0]))
    PCt = P @ mode.C.T
    Sy = mode.C @ PCt + R
    Sy = 0.5 * (Sy + Sy.T)
    try:
        K = np.linalg.solve(Sy, PCt.T).T
    except np.linalg.LinAlgError:  # a noise-free sensor meeting a known direction
        K = (np.linalg.pinv(Sy, hermitian=True) @ PCt.T).T
    post = P - K @ PCt.T
    out: np.ndarray = 0.5 * (post + post.T)
    return out


def _riccati_batch(mode: LCS, S: np.ndarray) -> np.ndarray:
    """:func:`_riccati` of every matrix of ``S`` (shape (T, n, n)) at once."""
    P = np.einsum("ij,tjk,lk->til", mode.A, S, mode.A) + mode.process_cov
    if mode.p == 0 or not P.shape[0]:
        return np.asarray(P)
    R = mode.noise_cov(np.zeros(S.shape[1]))
    PCt = P @ mode.C.T
    Sy = mode.C @ PCt + R
    Sy = 0.5 * (Sy + np.swapaxes(Sy, 1, 2))
    try:
        K = np.swapaxes(np.linalg.solve(Sy, np.swapaxes(PCt, 1, 2)), 1, 2)
    except np.linalg.LinAlgError:  # a noise-free sensor meeting a known direction
        K = np.swapaxes(np.linalg.pinv(Sy, hermitian=True) @ np.swapaxes(PCt, 1, 2), 1, 2)
    post = P - K @ np.swapaxes(PCt, 1, 2)
    return np.asarray(0.5 * (post + np.swapaxes(post, 1, 2)))


def run_ladder(window: int, H: int) -> list[int]:
    """Run lengths with rows of their own: every length up to twice the window, then a
    geometric ladder (ratio 1.25) up to ``H``."""
    out = list(range(window + 1, min(2 * window, H) + 1))
    r = float(2 * window)
    while True:
        r = max(r * 1.25, r + 1)
        if int(r) > H:
            break
        out.append(int(r))
    return out


class CovarianceTables:
    """Lower bounds on the covariance at each step, as a function of the last modes.

    ``lows[j]`` bounds every mode sequence's ``Sigma_j`` from below: ``Sigma_0`` itself, then the
    prediction with the least process noise every mode has and the update with the information
    of every sensing mode at once (monotone in both, so below every mode's step). A pattern
    ``s`` of the modes arriving at ``k - |s| + 1 .. k`` applied exactly to ``lows[k - |s|]``
    bounds ``Sigma_k`` of every sequence ending with ``s``; at ``|s| = k`` it is exact.

    Parameters
    ----------
    modes : sequence of LCS
        Sharing ``A``, with state-independent noise.
    cov0 : ndarray, shape (n, n)
    H : int
        Last step.
    """

    def __init__(self, modes: Sequence[LCS], cov0: np.ndarray, H: int) -> None:
        self.modes = list(modes)
        self.Q = len(self.modes)
        self.H = H
        n = cov0.shape[0]
        A = self.modes[0].A
        W = [mode.process_cov for mode in self.modes]
        W_low = W[0] if all(np.array_equal(w, W[0]) for w in W) else np.zeros((n, n))
        info = np.zeros((n, n))
        perfect = False  # a noise-free sensor: infinite information, no finite matrix bounds it
        for mode in self.modes:
            if mode.p:
                R = mode.noise_cov(np.zeros(n))
                if np.linalg.cond(R) > 1e12:
                    perfect = True
                else:
                    info += mode.C.T @ np.linalg.solve(R, mode.C)
        lows = np.zeros((H + 1, n, n))  # zero: the trivial lower bound
        lows[0] = cov0
        for j in range(1, H + 1 if not perfect else 1):
            P = A @ lows[j - 1] @ A.T + W_low
            post = P @ np.linalg.inv(np.eye(n) + info @ P)  # (P^-1 + J)^-1, P may be singular
            post = 0.5 * (post + post.T)
            w, v = np.linalg.eigh(post)
            lows[j] = (v * np.maximum(w, 0.0)) @ v.T
        self.lows = lows
        self.window = 1
        while self.Q ** (self.window + 1) <= PATTERN_CAP:
            self.window += 1
        self._memo: dict[tuple[int, tuple[int, ...]], np.ndarray] = {}
        self._runs: dict[int, dict[int, np.ndarray]] = {}

    def cov(self, k: int, pattern: tuple[int, ...]) -> np.ndarray:
        """The lower bound on ``Sigma_k`` for sequences whose last modes are ``pattern``."""
        key = (k, pattern)
        out = self._memo.get(key)
        if out is None:
            S = self.lows[k - len(pattern)]
            for q in pattern:
                S = _riccati(self.modes[q], S)
            out = S
            self._memo[key] = out
        return out

    def runs(self, q: int) -> dict[int, np.ndarray]:
        """Lower bounds after runs of mode ``q``: ``{r: covs}`` for the lengths of
        :func:`run_ladder`, ``covs[j]`` the bound on ``Sigma_{j + r}`` of every sequence whose
        last ``r`` modes are ``q`` (shape (H + 1 - r, n, n)). A run of a blind mode is the
        "steps since the last look" of the field's stop-and-look tables."""
        out = self._runs.get(q)
        if out is None:
            out = {}
            ladder = set(run_ladder(self.window, self.H))
            S = self.lows[: self.H].copy()  # one chain per start j, batched
            for r in range(1, self.H + 1):
                S = _riccati_batch(self.modes[q], S[: self.H + 1 - r])
                if r in ladder:
                    out[r] = S
            self._runs[q] = out
        return out

    def full(self, k: int) -> tuple[int, np.ndarray]:
        """Step ``k``'s window and the covariances of every pattern of it, shape (Q^w, n, n);
        pattern index in base ``Q``, the oldest mode the most significant digit."""
        w = min(k, self.window)
        start = self.lows[k - w]
        level = [start]
        for _ in range(w):
            level = [_riccati(mode, S) for S in level for mode in self.modes]
        return w, np.stack(level)


@dataclass
class JointAnswer:
    """One solve of the joint model."""

    status: str  # "found", "infeasible", "timeout"
    why: str = ""
    claims: np.ndarray | None = None
    actions: np.ndarray | None = None
    controls: np.ndarray | None = None
    means: np.ndarray | None = None


@dataclass
class JointModel:
    """The built model and the column blocks its answer reads."""

    model: LinearModel
    nb: int
    n_rows_face: int
    input_blocks: list[int] = field(default_factory=list)  # first column of each input block


class JointSolver:
    """The joint model of the proposer's encoding, with its lazily added cuts (module docstring).

    Parameters
    ----------
    context : PlanLPContext
    budget : Budget
    """

    def __init__(self, context: PlanLPContext, budget: Budget) -> None:
        self.context = context
        self.budget = budget
        system = context.system
        self.modes = list(system.system_modes)
        self.Q = len(self.modes)
        self.n, self.m = system.n, system.m
        self.tables: CovarianceTables | None = None
        self.patterns: set[tuple[int, ...]] = set()
        """The cuts' mode patterns (oldest first), kept across bounds: each holds at every step it
        fits (its lower bound at step ``k`` starts from ``lows[k - len]``), so what a pattern
        of modes failed to achieve at one step is stated wherever it can end."""
        self.rounds = 0
        ab = context.abstraction
        dx = context.scaling.dx
        G = ab.H * dx[None, :]
        g = np.linalg.norm(G, axis=1)
        self.g = np.where(g > 0, g, 1.0)
        self.Gn = G / self.g[:, None]
        self.room: dict[int, list[_Row]] = {}
        """Execution cuts per step: ``(face, pattern, room)`` (:meth:`add_room`)."""
        self.proofs = True
        """Whether the model is a relaxation of the problem (no execution cut yet): only then is
        its ``infeasible`` a proof."""
        self._row_cache: dict[int, tuple[np.ndarray, list[_Row]]] = {}
        norms = np.linalg.norm(ab.H, axis=1)
        unit = ab.H / np.where(norms > 0, norms, 1.0)[:, None]
        lead = np.argmax(np.abs(unit) > 1e-12, axis=1) if unit.size else np.zeros(0, dtype=int)
        sign = np.where(unit[np.arange(unit.shape[0]), lead] < 0, -1.0, 1.0) if unit.size else np.zeros(0)
        unit = unit * sign[:, None]
        keys, first, inverse = np.unique(np.round(unit, 10), axis=0, return_index=True, return_inverse=True)
        self.dirs = unit[first] if unit.size else np.zeros((0, self.n))
        """Unit face directions (up to sign), shape (D, n): the standard deviations the model holds."""
        self.D = int(self.dirs.shape[0])
        self.face_dir = np.asarray(inverse, dtype=np.int64).reshape(-1)
        self.hnorm = norms
        self.shared_B = all(np.array_equal(mode.B, self.modes[0].B) for mode in self.modes[1:])

    def _tables(self, H: int) -> CovarianceTables:
        if self.tables is None or self.tables.H < H:
            self.tables = CovarianceTables(self.modes, self.context.cov0, H)
        return self.tables

    # ------------------------------------------------------------------------------------------
    # the model

    def build(self, enc: BMCEncoder) -> JointModel | str:
        """The joint model over ``enc`` with the cuts so far, or why it cannot be built."""
        ctx, H, n, m = self.context, enc.H, self.n, self.m
        if np.any(ctx.abstraction.z < 0):
            return "a chance constraint with eps > 0.5 (its tightening falls with the variance)"
        if not np.all(np.isfinite(ctx.abstraction.z)):
            return "a chance constraint with eps = 0"
        tables = self._tables(H)
        dx, du = ctx.scaling.dx, ctx.scaling.du
        blocks = 1 if self.shared_B else self.Q
        nb = enc.num_vars
        nx, nu = H * n, H * m * blocks
        ns = H * self.D
        nvar = nb + nx + nu + ns
        acc = RowBlocks()
        clause_rows(enc, nvar, acc)
        # dynamics: x~_{k+1} - A~ x~_k - sum_b B~_b u~^b_k = [k = 0] A~ x~_0
        A = self.modes[0].A
        At = A * dx[None, :] / dx[:, None]
        shift = csr_matrix((np.ones(max(H - 1, 0)), (np.arange(1, H), np.arange(H - 1))), shape=(H, H))
        dyn_x = (eye(H * n) - kron(shift, At)).tocsr()
        parts = [csr_matrix((H * n, nb)), dyn_x]
        starts = []
        for b in range(blocks):
            Bt = self.modes[b].B * du[None, :] / dx[:, None]
            parts.append(-kron(eye(H), Bt).tocsr())
            starts.append(nb + nx + b * H * m)
        rhs = np.zeros(H * n)
        if H:
            rhs[:n] = At @ (ctx.mean0 / dx)
        parts.append(csr_matrix((H * n, ns)))
        acc.add(hstack(parts).tocsr(), rhs, rhs)
        # control domain: one block, or the perspective of each mode's block
        U = ctx.control_domain
        UH = U.H * du[None, :]
        unorm = np.linalg.norm(UH, axis=1)
        keep = unorm > 0
        UHn, Ucn = UH[keep] / unorm[keep, None], U.c[keep] / unorm[keep]
        nU = UHn.shape[0]
        for b in range(blocks):
            if not nU or not H:
                break
            blockU = kron(eye(H), UHn).tocsr()
            left = csr_matrix((H * nU, starts[b]))
            right = csr_matrix((H * nU, nvar - starts[b] - H * m))
            rows = hstack([left, blockU, right]).tocsr()
            if self.shared_B:
                acc.add(rows, np.full(H * nU, -np.inf), np.tile(-Ucn, H))
            else:
                # u^b_k in m[b, k+1] U: H u + c z <= 0 (u^b = 0 off its mode: U is bounded)
                zcols = np.repeat(np.asarray(enc.m[b, 1 : H + 1], dtype=np.int64) - 1, nU)
                gate = csr_matrix((np.tile(Ucn, H), (np.arange(H * nU), zcols)), shape=(H * nU, nvar))
                acc.add((rows + gate).tocsr(), np.full(H * nU, -np.inf), np.zeros(H * nU))
        s0 = nb + nx + nu
        faces = self._face_rows(enc, tables, nvar, s0, acc)
        if isinstance(faces, str):
            return faces
        fixed_p, never_p, count, s_low, s_high = faces
        A_all = vstack(acc.blocks).tocsr()
        A_all.eliminate_zeros()
        lower = np.concatenate([np.zeros(nb), np.full(nx + nu, -np.inf), s_low])
        upper = np.concatenate([np.ones(nb), np.full(nx + nu, np.inf), s_high])
        alive = np.asarray(enc.alive[: H + 1]) - 1
        lower[alive] = 1.0  # the trace is the whole bound: a shorter plan extends to it
        upper[enc.alive[H + 1] - 1] = 0.0
        lower[sorted(set(fixed_p) - set(never_p))] = 1.0
        upper[never_p] = 0.0
        upper[enc.selector - 1] = 0.0  # abandoned candidates are not proofs: their clauses are off
        integrality = np.zeros(nvar)
        for letters in (np.asarray(enc.alive), enc.p.ravel(), enc.m.ravel()):
            integrality[np.asarray(letters, dtype=np.int64) - 1] = 1
        model = LinearModel(
            np.zeros(nvar),
            A_all,
            np.concatenate(acc.lo),
            np.concatenate(acc.hi),
            lower,
            upper,
            integrality,
            cuts=False,
            probing="off",
            feaspump=False,
        )
        logger.info(
            "joint MILP: %d binaries, %d continuous, %d rows (%d face rows, %d cut patterns)",
            int(integrality.sum()),
            nx + nu,
            A_all.shape[0],
            count,
            len(self.patterns),
        )
        return JointModel(model, nb, count, starts)

    def _face_rows(
        self, enc: BMCEncoder, tables: CovarianceTables, nvar: int, s0: int, acc: RowBlocks
    ) -> tuple[list[int], list[int], int, np.ndarray, np.ndarray] | str:
        """The chance constraints' rows: ``(fixed_p, never_p, face rows, s_low, s_high)``.

        Per step ``k`` and face direction ``d`` (unit normals up to sign: a box's faces share
        two in the plane) a column ``s[k, d]``, a lower bound on the standard deviation along
        ``d``: at least the least over every pattern (its column bound), and at least the
        pattern's bound whenever the last modes are that pattern (a row with the pattern's mode
        letters, no state). Each claimed face is one big-M row ``h~' x~_k + z |h| s[k, d] / g
        <= -c / g`` when ``p[i, k]``. The execution cuts (:meth:`add_room`) are rows of their own.
        """
        ctx, H, n, D = self.context, enc.H, self.n, self.D
        ab = ctx.abstraction
        F, owner = ab.H, ab.owner
        s_low = np.zeros(H * D)
        s_high = np.zeros(H * D)
        fixed_p: list[int] = []
        never_p: list[int] = []
        if not F.shape[0]:
            return fixed_p, never_p, 0, s_low, s_high
        hard = hard_steps(enc.formula, ab, H)
        reach_max, box_max = self._reach(enc, F)
        mcols = np.asarray(enc.m, dtype=np.int64) - 1  # (Q, H+1)
        nb = int(enc.num_vars)
        coef = ab.z * self.hnorm / self.g  # of s[k, d(f)] in face f's normalised row
        r_idx: list[np.ndarray] = []
        c_idx: list[np.ndarray] = []
        vals: list[np.ndarray] = []
        lo: list[np.ndarray] = []
        hi: list[np.ndarray] = []
        count = 0

        def add(
            rows: np.ndarray, cols: np.ndarray, values: np.ndarray, low: np.ndarray, high: np.ndarray
        ) -> None:
            nonlocal count
            r_idx.append(rows + count)
            c_idx.append(cols)
            vals.append(values)
            lo.append(low)
            hi.append(high)
            count += low.shape[0]

        for k in range(1, H + 1):
            if not k % 16:
                self.budget.check("building the joint MILP")
            base, table_rows = self._table_rows(tables, k)
            rows = list(table_rows)
            for pattern in sorted(self.patterns):
                if len(pattern) > k or len(pattern) <= min(k, tables.window):
                    continue  # too long for step k, or within the table's window already
                sd = self._dir_sd(tables.cov(k, pattern))
                for dd in np.nonzero(sd > base * (1 + _SD_TOL) + 1e-300)[0]:
                    rows.append((int(dd), pattern, float(sd[dd])))
            scols = s0 + (k - 1) * D + np.arange(D)
            top = base.copy()
            for d, pattern, sd_p in rows:
                top[d] = max(top[d], sd_p)
                gap = sd_p - base[d]
                zc = [int(mcols[q, k - len(pattern) + 1 + i]) for i, q in enumerate(pattern)]
                # s - gap * sum(z) >= sd_p - gap * len: s >= sd_p when every mode matches
                add(
                    np.zeros(1 + len(zc), dtype=np.int64),
                    np.asarray([scols[d], *zc], dtype=np.int64),
                    np.concatenate([[1.0], np.full(len(zc), -gap)]),
                    np.asarray([sd_p - gap * len(zc)]),
                    np.asarray([np.inf]),
                )
            s_low[(k - 1) * D : k * D] = base
            s_high[(k - 1) * D : k * D] = top
            # the faces: h~' x~_k + coef s[k, d(f)] <= -c / g when p holds
            reach = np.minimum(reach_max[k], box_max[k]) / self.g
            rhs = -ab.c / self.g
            top_f = coef * top[self.face_dir]
            big = reach + top_f - rhs
            p_cols = np.asarray(enc.p[owner, k], dtype=np.int64) - 1
            fixed_p.extend(int(v) for v in np.unique(p_cols[hard[k, owner]]))
            sel = np.nonzero(big > 0)[0]  # big <= 0: every reachable mean is inside
            if sel.size and (not np.all(np.isfinite(big[sel])) or np.max(big[sel]) > _MAX_BIG_M):
                return "the reachable means are unbounded (no finite big-M)"
            xcols = nb + (k - 1) * n + np.arange(n)
            if sel.size:
                cols = np.hstack(
                    [
                        np.broadcast_to(xcols, (sel.size, n)),
                        scols[self.face_dir[sel]][:, None],
                        p_cols[sel][:, None],
                    ]
                )
                values = np.hstack([self.Gn[sel], coef[sel][:, None], big[sel][:, None]])
                add(
                    np.repeat(np.arange(sel.size), n + 2),
                    cols.ravel(),
                    values.ravel(),
                    np.full(sel.size, -np.inf),
                    rhs[sel] + big[sel],
                )
            for f, pattern, need in self.room.get(k, ()):
                zc = [int(mcols[q, k - len(pattern) + 1 + i]) for i, q in enumerate(pattern)]
                big_r = float(reach[f] + top_f[f] - rhs[f] + need)
                if not big_r > 0 or not np.isfinite(big_r):
                    continue
                add(
                    np.zeros(n + 2 + len(zc), dtype=np.int64),
                    np.asarray([*xcols, scols[self.face_dir[f]], p_cols[f], *zc], dtype=np.int64),
                    np.concatenate([self.Gn[f], [coef[f]], np.full(1 + len(zc), big_r)]),
                    np.asarray([-np.inf]),
                    np.asarray([rhs[f] - need + big_r * (1 + len(zc))]),
                )
        if count:
            block = coo_matrix(
                (np.concatenate(vals), (np.concatenate(r_idx), np.concatenate(c_idx))), shape=(count, nvar)
            ).tocsr()
            acc.add(block, np.concatenate(lo), np.concatenate(hi))
        return fixed_p, never_p, count, s_low, s_high

    def _dir_sd(self, cov: np.ndarray) -> np.ndarray:
        """Standard deviation along each face direction, shape (D,) or (T, D) for (T, n, n)."""
        U = self.dirs
        if cov.ndim == 2:
            var = np.einsum("di,ij,dj->d", U, cov, U)
        else:
            var = np.einsum("di,tij,dj->td", U, cov, U)
        return np.asarray(np.sqrt(np.maximum(var, 0.0)))

    def _bounds(self, cov: np.ndarray) -> np.ndarray:
        """``h~' x~ <= bound`` per face (normalised, scaled) under ``cov`` (shape (n, n) or
        (T, n, n))."""
        ab = self.context.abstraction
        terms = std_terms(ab.H, ab.z, cov)
        return np.asarray(-(ab.c + terms) / self.g)

    def add_room(
        self, requirements: Sequence[tuple[int, int]], need: Sequence[np.ndarray], actions: np.ndarray
    ) -> int:
        """Execution cuts: each required face-step keeps ``need`` (units of ``h'x``, per the
        atom's faces) of room beyond its lower-bound tightening whenever the modes arriving in the
        last :data:`ROOM_WINDOW` times :attr:`CovarianceTables.window` steps are ``actions``' (the
        spreads the executor's loop adds depend on the modes, mostly the recent ones; a shorter
        pattern also held plans that approach differently and need less). A heuristic of the execution
        (:mod:`.room_measure`), not a relaxation: once any is added, ``infeasible`` proves nothing
        (:attr:`proofs`). Returns the number of new rows."""
        ab = self.context.abstraction
        window = ROOM_WINDOW * self._tables(actions.shape[0]).window
        added = 0
        for (k, i), needs in zip(requirements, need, strict=True):
            if k < 1:
                continue
            faces = np.nonzero(ab.owner == i)[0]
            pattern = tuple(int(q) for q in actions[max(k - window, 0) : k])
            entries = self.room.setdefault(k, [])
            for f, nf in zip(faces, np.asarray(needs, dtype=float), strict=True):
                value = float(nf) / float(self.g[f])
                old = [e for e in entries if e[0] == f and e[1] == pattern]
                if old and old[0][2] >= value - 1e-9:
                    continue
                if old:
                    entries.remove(old[0])
                entries.append((int(f), pattern, value))
                added += 1
        if added:
            self.proofs = False
        return added

    def _table_rows(self, tables: CovarianceTables, k: int) -> tuple[np.ndarray, list[_Row]]:
        """Step ``k``'s least standard deviation per direction (over every pattern) and its
        pattern rows ``(direction, pattern, sd)`` (cached): a row for every suffix of the window
        whose bound exceeds its parent's by more than :data:`_SD_TOL` (relative; dropping a row
        only weakens the relaxation), and for the runs of one mode longer than the window."""
        cached = self._row_cache.get(k)
        if cached is not None:
            return cached
        w, covs = tables.full(k)
        sd_all = self._dir_sd(covs)  # (Q^w, D)
        base = sd_all.min(axis=0)
        rows: list[_Row] = []
        Q = self.Q
        digits = [
            [tuple(int(d) for d in np.base_repr(s, Q).zfill(j)[-j:]) for s in range(Q**j)]
            for j in range(1, w + 1)
        ]
        for d in range(self.D):
            parent: dict[tuple[int, ...], float] = {(): float(base[d])}
            for j in range(1, w + 1):
                per = sd_all[:, d].reshape(Q ** (w - j), Q**j).min(axis=0)
                for s in range(Q**j):
                    pattern = digits[j - 1][s]
                    value = float(per[s])
                    if value > parent[pattern[1:]] * (1 + _SD_TOL) + 1e-300:
                        rows.append((d, pattern, value))
                    parent[pattern] = max(value, parent[pattern[1:]])
        # runs of one mode longer than the window (the steps since the last look)
        for q in range(Q):
            same = sum(q * Q**i for i in range(w))  # the pattern "q throughout the window"
            prev = sd_all[same].copy()
            for r, covs_r in tables.runs(q).items():
                if r > k or r <= w:
                    continue
                sd_r = self._dir_sd(covs_r[k - r])
                for dd in np.nonzero(sd_r > prev * (1 + _SD_TOL) + 1e-300)[0]:
                    rows.append((int(dd), (q,) * r, float(sd_r[dd])))
                prev = np.maximum(prev, sd_r)
        self._row_cache[k] = (base, rows)
        return base, rows

    def _reach(self, enc: BMCEncoder, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per step and face, the largest value over the reachable means (support functions over
        every mode's input) and over the box the invariants leave; shapes (H+1, F)."""
        ctx, H, n = self.context, enc.H, self.n
        A = self.modes[0].A
        Bs = [mode.B for mode in self.modes]
        points = support_points(ctx.control_domain)
        powers = np.empty((H + 1, F.shape[0], n))
        powers[0] = F
        for j in range(1, H + 1):
            powers[j] = powers[j - 1] @ A
        gain = (
            np.stack([np.max([support(points, powers[j] @ B) for B in Bs], axis=0) for j in range(H)])
            if H
            else np.zeros((0, F.shape[0]))
        )
        reach_max = np.einsum("kfn,n->kf", powers, ctx.mean0)
        with np.errstate(invalid="ignore"):
            reach_max[1:] += np.cumsum(gain, axis=0)
        inv_low, inv_high = invariant_box(enc.formula, ctx.abstraction, n, H)
        low, high = np.empty((H + 1, n)), np.empty((H + 1, n))
        low[0] = high[0] = ctx.mean0
        b_high = np.max([support(points, B) for B in Bs], axis=0)
        b_low = np.min([-support(points, -B) for B in Bs], axis=0)
        Ap, An = np.maximum(A, 0.0), np.minimum(A, 0.0)
        for k in range(1, H + 1):
            with np.errstate(invalid="ignore"):
                lo_k = _prod(Ap, low[k - 1]) + _prod(An, high[k - 1]) + b_low
                hi_k = _prod(Ap, high[k - 1]) + _prod(An, low[k - 1]) + b_high
            low[k] = np.maximum(np.where(np.isnan(lo_k), -np.inf, lo_k), inv_low[k])
            high[k] = np.minimum(np.where(np.isnan(hi_k), np.inf, hi_k), inv_high[k])
            high[k] = np.maximum(high[k], low[k])
        with np.errstate(invalid="ignore"):
            box = np.where(F[None] > 0, F[None] * high[:, None, :], F[None] * low[:, None, :])
        box_max = np.where(F[None] == 0, 0.0, box).sum(axis=2)
        box_max = np.where(np.isnan(box_max), np.inf, box_max)
        return reach_max, box_max

    # ------------------------------------------------------------------------------------------
    # solving, checking, cutting

    def solve(self, enc: BMCEncoder, backend: Backend) -> JointAnswer:
        """One model over ``enc`` with the cuts so far, solved."""
        built = self.build(enc)
        if isinstance(built, str):
            return JointAnswer("unsupported", built)
        self.rounds += 1
        # No first look (shift-and-propagate before the root LP): on these models it never found
        # a plan and cost SCIP ~35% of its time (quiet_zone 15.2 -> 9.6 s, duty_cycle 6.6 -> 4.4 s
        # over their 7 solves, under load).
        sol = backend.solve(built.model, max(self.budget.remaining(), 1e-3))
        if sol.status == "infeasible":
            return JointAnswer("infeasible", "the joint MILP is infeasible")
        if sol.x is None:
            return JointAnswer("timeout", sol.message)
        x = sol.x
        H, n, m = enc.H, self.n, self.m
        nb = built.nb
        dx, du = self.context.scaling.dx, self.context.scaling.du
        means = np.vstack([self.context.mean0, x[nb : nb + H * n].reshape(H, n) * dx])
        controls = np.zeros((H, m))
        for start in built.input_blocks:
            controls += x[start : start + H * m].reshape(H, m) * du
        if self.Q > 1:
            actions = np.argmax(x[np.asarray(enc.m[:, 1 : H + 1], dtype=np.int64) - 1], axis=0)
        else:
            actions = np.zeros(H, dtype=int)
        claims = np.round(x[enc.p - 1]).astype(bool) if enc.p.size else np.zeros((0, H + 1), bool)
        return JointAnswer("found", "", claims, actions.astype(int), controls, means)

    def cut(self, answer: JointAnswer) -> int:
        """Roll the exact recursion on the answer's modes; add a cut per violated claimed face
        (the shortest refuting suffix of its modes). Returns the number of new cuts (0: the
        answer's means meet every claimed face exactly, with :attr:`backoff`)."""
        if answer.claims is None or answer.actions is None or answer.means is None:
            return 0
        ab = self.context.abstraction
        actions = answer.actions
        H = actions.shape[0]
        covs, _ = covariance_schedule(self.modes, self.context.cov0, actions, self.budget)
        tables = self._tables(H)
        added = 0
        for k in range(1, H + 1):
            claimed = answer.claims[ab.owner, k]
            if not claimed.any():
                continue
            value = self.Gn @ (answer.means[k] / self.context.scaling.dx)
            bad = np.nonzero(claimed & (value - self._bounds(covs[k]) > _VIOLATION))[0]
            for f in bad:
                pattern = self._refuting_suffix(tables, k, actions, int(f), float(value[f]))
                if pattern is None or pattern in self.patterns:
                    continue
                self.patterns.add(pattern)
                added += 1
        logger.info("joint MILP: %d cuts added (round %d)", added, self.rounds)
        return added

    def _refuting_suffix(
        self, tables: CovarianceTables, k: int, actions: np.ndarray, f: int, value: float
    ) -> tuple[int, ...] | None:
        """The shortest suffix of the modes arriving up to ``k`` (longer than the window; lengths
        double, the last is ``k``: exact) whose lower bound refutes face ``f`` at ``value``."""
        j = tables.window + 1
        while True:
            j = min(j, k)
            pattern = tuple(int(q) for q in actions[k - j : k])
            if value - float(self._bounds(tables.cov(k, pattern))[f]) > 0.5 * _VIOLATION:
                return pattern
            if j >= k:
                return None
            j *= 2


def _prod(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        P = M * v[None, :]
    return np.asarray(np.where(M == 0, 0.0, P).sum(axis=1))
