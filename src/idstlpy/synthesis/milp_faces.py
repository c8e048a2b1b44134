"""The eager MILP's chance-constraint rows: the formula's propositions as big-M implications.

For every step ``k >= 1`` and every face of proposition ``i``: a hard row where the formula's
invariants require ``i`` at ``k``, else the big-M row ``p[i, k] = 1 -> face`` whose ``M`` is the
face's largest value over the reachable means (:mod:`.milp_bounds`), so the relaxation is as
tight as big-M can be; with ``objective="margin"`` the margin column ``t`` enters every face row
and step 0 gets its own rows (:func:`_step0_rows`). Part of :func:`~.milp_model.build_milp`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse import coo_matrix

from ..chance import joint_slack, std_terms
from .milp_bounds import hard_steps, invariant_box, margin_cap, state_boxes, support, support_points

if TYPE_CHECKING:
    from .milp_spec import Columns, MILPSpec, RowBlocks

__all__ = ["FacePart", "chance_rows"]

# One log for the whole eager MILP (model, phases, outcome): users and tests filter on it.
logger = logging.getLogger("idstlpy.synthesis.milp")

_INT_TOL = 2e-6  # above HiGHS' mip_feasibility_tolerance (1e-6): a binary may be off by that much
_MAX_BIG_M = 1e7  # in normalised, scaled units: beyond this the model is numerically unreliable

FacePart = tuple[list[int], list[int], list[tuple[int, int]], float, bool]


def chance_rows(spec: MILPSpec, covs: np.ndarray, cols: Columns, acc: RowBlocks) -> FacePart | str:
    """The chance constraints' rows: ``(fixed_p, never_p, face_rows, t_cap, t_sound)``, or why not.

    Big-M implications ``p[i, k] -> faces of proposition i at step k`` (normalised rows). The
    invariants (propositions the formula requires at every step ``0..b``) are hard rows instead,
    so the box they bound is a fact every other big-M may use.
    """
    ctx, enc, budget = spec.context, spec.enc, spec.budget
    abstraction, H, F = ctx.abstraction, enc.H, ctx.abstraction.H
    hard = hard_steps(enc.formula, abstraction, H)
    if not F.shape[0]:
        return [], [], [], 0.0, False
    budget.check("building the MILP")
    mode = ctx.system.system_modes[0]
    A, B, n, dx = mode.A, mode.B, ctx.system.n, ctx.scaling.dx
    powers = np.empty((H + 1, F.shape[0], n))
    powers[0] = F
    for j in range(1, H + 1):
        if not j % 1024:
            budget.check("building the MILP")
        powers[j] = powers[j - 1] @ A
    points = support_points(ctx.control_domain)
    gain = np.stack([support(points, powers[j] @ B) for j in range(H)]) if H else np.zeros((0, F.shape[0]))
    reach_max = np.einsum("kfn,n->kf", powers, ctx.mean0)
    with np.errstate(invalid="ignore"):
        reach_max[1:] += np.cumsum(gain, axis=0)
    inv_low, inv_high = invariant_box(enc.formula, abstraction, n, H)
    box_low, box_high = state_boxes(A, B, points, ctx.mean0, inv_low, inv_high, H)
    # The margin t (raw slack, the monitor's units) is capped at t_cap. The formula evaluated
    # on upper bounds of every proposition's margin bounds every plan's robustness, so that
    # cap never cuts the optimum, and it keeps the big-M of every face small; without it (no
    # finite bound) a generous heuristic cap stands, and an optimum at it is not proven.
    t_cap, t_sound = 0.0, False
    if cols.nt:
        loss = (
            np.stack([support(points, -(powers[j] @ B)) for j in range(H)])
            if H
            else np.zeros((0, F.shape[0]))
        )
        reach_min = np.einsum("kfn,n->kf", powers, ctx.mean0)
        with np.errstate(invalid="ignore"):
            reach_min[1:] -= np.cumsum(loss, axis=0)
        t_cap, t_sound = margin_cap(enc.formula, abstraction, covs, reach_min, box_low, box_high, H)
        if not t_sound:
            t_cap = 10.0 * float(np.max(dx)) * float(np.max(np.linalg.norm(F, axis=1)))
    # With an objective, p = 1 - 2e-6 may relax a face by that much of its big-M: the model is a
    # relaxation, its bound a bound on every plan and its infeasibility a proof, and the plan
    # itself is re-solved exactly (the margin's _polish, the plan LP's re-timing). Without one the
    # face is enforced within the integrality tolerance (a plan found is a plan; issue 25: with an
    # objective that over-tightening, 2e-6 of a big-M, refuted a target 2e-6 wide).
    int_tol = 0.0 if spec.objective is not None else _INT_TOL
    rows = _FaceRows(spec, cols, covs, hard, reach_max, (box_low, box_high), t_cap, int_tol)
    for k in range(1, H + 1):
        if not k % 64:
            budget.check("building the MILP")
        if not rows.add_step(k):
            return "the reachable means are unbounded (no finite big-M)"
    face_rows = rows.emit(acc)
    if cols.nt:
        _step0_rows(spec, covs[0], cols, t_cap, acc, rows.never_p)
    logger.debug("MILP: %d hard face rows, %d big-M rows", rows.hard.count, rows.big.count)
    return rows.fixed_p, rows.never_p, face_rows, t_cap, t_sound


@dataclass
class _Triplets:
    """One block of face rows as it is built: COO triplets, upper sides and the row count."""

    r: list[np.ndarray] = field(default_factory=list)
    c: list[np.ndarray] = field(default_factory=list)
    v: list[np.ndarray] = field(default_factory=list)
    ub: list[np.ndarray] = field(default_factory=list)
    count: int = 0


class _FaceRows:
    """The face rows of steps ``1..H``: hard rows (invariants) and big-M rows (claims)."""

    def __init__(
        self,
        spec: MILPSpec,
        cols: Columns,
        covs: np.ndarray,
        hard: np.ndarray,
        reach_max: np.ndarray,
        box: tuple[np.ndarray, np.ndarray],
        t_cap: float,
        int_tol: float,
    ) -> None:
        self.abstraction = spec.context.abstraction
        self.p = spec.enc.p
        self.n = spec.context.system.n
        self.cols, self.covs, self.hard_at, self.reach_max, self.box = cols, covs, hard, reach_max, box
        self.t_cap, self.int_tol = t_cap, int_tol
        G = self.abstraction.H * spec.context.scaling.dx[None, :]
        g = np.linalg.norm(G, axis=1)
        self.g = np.where(g > 0, g, 1.0)
        self.Gn = G / self.g[:, None]
        self.fixed_p: list[int] = []
        self.never_p: list[int] = []
        self.hard = _Triplets()
        self.big = _Triplets()

    def add_step(self, k: int) -> bool:
        """Step ``k``'s rows; ``False`` when a big-M is infinite or too large (no sound model)."""
        ab, F, g = self.abstraction, self.abstraction.H, self.g
        terms = std_terms(F, ab.z, self.covs[k])
        bound = -(ab.c + terms)  # h' x_k <= bound when p holds
        box_low, box_high = self.box
        with np.errstate(invalid="ignore"):
            box_max = np.where(F > 0, F * box_high[k], F * box_low[k])
        box_max = np.where(F == 0, 0.0, box_max).sum(axis=1)
        with np.errstate(invalid="ignore"):
            big = np.maximum(np.minimum(self.reach_max[k], box_max) + self.t_cap - bound, 0.0) / g
        p_cols = self.p[ab.owner, k] - 1
        is_hard = self.hard_at[k, ab.owner]
        finite = np.isfinite(bound)
        # eps = 0 with variance: the proposition cannot hold at k.
        self.never_p.extend(int(c) for c in np.unique(p_cols[~finite]))
        self.fixed_p.extend(int(c) for c in np.unique(p_cols[is_hard & finite]))
        # A hard row is dropped only when the dynamics alone keep it (its own box is no reason),
        # with the margin t on top when one is maximised.
        with np.errstate(invalid="ignore"):
            free = self.reach_max[k] + self.t_cap - bound > 0
        hsel = np.nonzero(is_hard & finite & free)[0]
        sel = np.nonzero(~is_hard & finite & (big > 0))[0]  # big <= 0: every reachable mean is inside
        if sel.size and (not np.all(np.isfinite(big[sel])) or np.max(big[sel]) > _MAX_BIG_M):
            return False
        xcols = self.cols.nb + (k - 1) * self.n + np.arange(self.n)
        for faces, out in ((hsel, self.hard), (sel, self.big)):
            if not faces.size:
                continue
            ids = out.count + np.arange(faces.size)
            cols = [np.broadcast_to(xcols, (faces.size, self.n))]
            coefs = [self.Gn[faces]]
            if faces is sel:  # big-M: p = 1 (within the integrality tolerance) enforces the face
                cols.append(p_cols[faces][:, None])
                coefs.append((big[faces] / (1.0 - self.int_tol))[:, None])
            if self.cols.nt:
                cols.append(np.full((faces.size, 1), self.cols.tcol))
                coefs.append((1.0 / g[faces])[:, None])
            cm, vm = np.hstack(cols), np.hstack(coefs)
            out.r.append(np.repeat(ids, cm.shape[1]))
            out.c.append(cm.ravel())
            out.v.append(vm.ravel())
            out.ub.append(bound[faces] / g[faces] + (big[faces] if faces is sel else 0.0))
        self.hard.count += hsel.size
        self.big.count += sel.size
        return True

    def emit(self, acc: RowBlocks) -> list[tuple[int, int]]:
        """Add the hard, then the big-M rows to ``acc``; their ``(first row, count)``."""
        face_rows = []
        for part in (self.hard, self.big):
            if part.count:
                face_rows.append((acc.count, part.count))
                triplets = (np.concatenate(part.v), (np.concatenate(part.r), np.concatenate(part.c)))
                acc.add(
                    coo_matrix(triplets, shape=(part.count, self.cols.nvar)).tocsr(),
                    np.full(part.count, -np.inf),
                    np.concatenate(part.ub),
                )
        return face_rows


def _step0_rows(
    spec: MILPSpec, cov0: np.ndarray, cols: Columns, t_cap: float, acc: RowBlocks, never_p: list[int]
) -> None:
    """The margin's rows at step 0: ``t <= slack_i + (t_cap - slack_i) (1 - p[i, 0])``.

    Step 0 has no face rows (the prior is given; pruning fixes what holds there), but a
    proposition claimed there bounds the margin by its slack at the prior, as at every other
    step. Without these rows a formula met at step 0 let the margin reach the cap for free
    (issue 25: 0.2 at step 0 reported beside a bound of 0.4, which four steps reach). A
    proposition whose slack at the prior is negative cannot be claimed there (``never_p``).
    """
    abstraction, p = spec.context.abstraction, spec.enc.p
    F = abstraction.H
    terms0 = std_terms(F, abstraction.z, cov0)
    with np.errstate(invalid="ignore"):
        face0 = -(abstraction.c + terms0) - F @ spec.context.mean0
    face0 = np.where(np.isnan(face0), -np.inf, face0)
    s_rows: list[int] = []
    s_cols: list[int] = []
    s_vals: list[float] = []
    s_hi: list[float] = []
    # A joint constraint is read at the prior as the monitor reads it (Boole's bound, the best
    # allocation), not at its planned shares: its faces' rows give way to its joint slack.
    joint0 = {i: np.inf for i, _, _ in abstraction.joint_groups}
    for i, rows, eps in abstraction.joint_groups:
        r0 = float(joint_slack(F[rows], abstraction.c[rows], eps, spec.context.mean0, cov0))
        joint0[i] = min(joint0[i], r0)
    for i in range(abstraction.num_atoms):
        faces = (abstraction.owner == i) & ~abstraction.joint_rows
        if not (abstraction.owner == i).any():
            continue
        slack0 = min(float(np.min(face0[faces])) if faces.any() else np.inf, joint0.get(i, np.inf))
        col = int(p[i, 0]) - 1
        if slack0 < 0:
            never_p.append(col)
        elif slack0 < t_cap:
            r = len(s_hi)
            s_rows += [r, r]
            s_cols += [cols.tcol, col]
            s_vals += [1.0, t_cap - slack0]
            s_hi.append(t_cap)
    if s_hi:
        block = coo_matrix((s_vals, (s_rows, s_cols)), shape=(len(s_hi), cols.nvar)).tocsr()
        acc.add(block, np.full(len(s_hi), -np.inf), np.asarray(s_hi))
