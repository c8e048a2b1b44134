"""Belief-space sampling teacher: a Sparse-RRT variant for active perception (paper Section III).

Nodes are MLO beliefs ``(step, mean, cov)`` reached by a mode/control sequence. One iteration:

1. sample a target mean: with probability ``goal_bias`` inside the plan's next required region
   (its inner half, around the Chebyshev centre), otherwise uniformly in the workspace box;
2. choose the node to extend: among active nodes within ``delta_near`` of the sample the least
   uncertain one (trace of the covariance), else the nearest: this is what makes the tree go
   and look before it acts;
3. extend it ``min_num_of_steps..max_num_of_steps`` steps, steering each step toward the sample
   with the input of least squares ``B u ~ sample - A mean`` pulled back into the control domain,
   propagating the exact MLO belief and checking the plan's requirements at every step;
4. keep one representative per ``delta_drain`` neighbourhood (same label, same progress): the
   least uncertain.

A step that breaks the plan does not kill the branch at once: the proposer is asked (SAT with the
realised labels as assumptions) whether the realised prefix can still be completed, and if so the
node follows the new plan. A node is a goal when its realised label trace satisfies the formula.

The search is decided by a work budget (``SolverOptions.iterations_per_candidate`` iterations)
and a random stream of its own per candidate, spawned from the solve's seed: the same seed gives
the same plan on any machine. ``rrt_timeout`` is only a wall-clock safety cap; hitting it is
reported (``SolveStats.caps_hit``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import DTypeLike

from ..belief import belief_step, rollout, rollout_arrays
from ..sets import Polytope
from .abstraction import Abstraction
from .interfaces import Budget, Found, Proposer, Refuted, Teacher, Unknown, Verdict
from .options import SolverOptions
from .plan import DiscretePlan, evaluate_bool
from .plan_lp import Scaling, lp_exact, noise_depends_on_state
from .results import SolveStats
from .room import give_room

if TYPE_CHECKING:  # problem.py imports the loop that imports this module
    from ..dynamical_system import LCS
    from .problem import Problem

__all__ = ["BeliefSampler", "SamplerOutcome", "SamplerTeacher"]

_FOCUS = 0.75
"""Probability that an iteration extends only the most advanced lineages (see ``_events``)."""

STEER_SHRINK = 0.8
"""Gentle steering keeps a fully actuated mode's inputs within this fraction of the control
domain (scaled about its Chebyshev centre), leaving the executor's tracking correction and the
polish (:mod:`.room`) the rest. Half the extensions (and the shortcut) steer gently; the others
use the whole domain, which tight deadlines need; a patrol (a region required again and again,
whose round trips must be made at full speed) never steers gently."""

STEER_LOOKAHEAD = 256
"""The longest input sequence the steering plans (``max_num_of_steps`` when smaller): the
steering gains take O(h^2) time and memory in the lookahead ``h``."""

TREE_BYTES = 128 * 2**20
"""Memory a belief tree may fill (nodes of ``8 (n + n^2 + m + 9) + atoms + 1`` bytes) before the
sampler stops growing it (a work cap: deterministic)."""

MIN_NODES = 250_000
"""Nodes a tree may always hold (the default budget, 15,000 iterations of at most 15 steps,
stays below it)."""

logger = logging.getLogger(__name__)


@dataclass
class SamplerOutcome:
    """What the sampler found for one candidate."""

    actions: np.ndarray | None
    controls: np.ndarray | None
    nodes: int
    iterations: int
    capped: bool
    # On failure, the node the search got closest with (most of the plan's events met, then the
    # deepest): its actions (k,), controls (k, m) and its progress; not a plan that satisfies.
    closest: tuple[np.ndarray, np.ndarray, float] | None = None


class _Tree:
    """Struct-of-arrays node store (grows by doubling)."""

    def __init__(self, n: int, m: int, n_atoms: int, cap: int = 1024) -> None:
        self.n, self.m, self.a = n, m, n_atoms
        self.size = 0
        self._alloc(cap)

    def _alloc(self, cap: int) -> None:
        def grow(old: np.ndarray | None, shape: tuple[int, ...], dtype: DTypeLike) -> np.ndarray:
            new = np.zeros((cap, *shape), dtype=dtype)
            if old is not None:
                new[: self.size] = old[: self.size]
            return new

        g = getattr
        self.mean = grow(g(self, "mean", None), (self.n,), float)
        self.cov = grow(g(self, "cov", None), (self.n, self.n), float)
        self.k = grow(g(self, "k", None), (), np.int64)
        self.parent = grow(g(self, "parent", None), (), np.int64)
        self.action = grow(g(self, "action", None), (), np.int64)
        self.control = grow(g(self, "control", None), (self.m,), float)
        self.unc = grow(g(self, "unc", None), (), float)
        self.active = grow(g(self, "active", None), (), bool)
        self.truth = grow(g(self, "truth", None), (self.a,), bool)
        self.run = grow(g(self, "run", None), (), np.int64)
        self.plan = grow(g(self, "plan", None), (), np.int64)
        self.stage = grow(g(self, "stage", None), (), np.int64)
        self.last = grow(g(self, "last", None), (), np.int64)  # region last entered (patrols)
        self.lastk = grow(g(self, "lastk", None), (), np.int64)  # the step it was entered
        self.cap = cap

    def add(
        self,
        mean: np.ndarray,
        cov: np.ndarray,
        k: int,
        parent: int,
        action: int,
        control: np.ndarray | None,
        truth: np.ndarray,
        plan: int,
        stage: int = 0,
    ) -> int:
        if self.size == self.cap:
            self._alloc(2 * self.cap)
        i = self.size
        self.mean[i], self.cov[i], self.k[i] = mean, cov, k
        self.parent[i], self.action[i] = parent, action
        if control is not None:
            self.control[i] = control
        self.unc[i] = float(np.trace(cov))
        self.truth[i] = truth
        same = parent >= 0 and np.array_equal(self.truth[parent], truth)
        self.run[i] = self.run[parent] + 1 if same else 0
        self.plan[i] = plan
        self.stage[i] = stage
        self.last[i] = self.last[parent] if parent >= 0 else -1
        self.lastk[i] = self.lastk[parent] if parent >= 0 else 0
        self.active[i] = False
        self.size += 1
        return i

    def path(self, i: int) -> list[int]:
        out = []
        while i >= 0:
            out.append(i)
            i = int(self.parent[i])
        return out[::-1]


def steering_center(domain: Polytope, tries: int = 8) -> np.ndarray:
    """The point the sampler's steering pulls inputs toward and shrinks the domain about, shape (m,).

    The Chebyshev centre of a bounded control domain. An unbounded one's Chebyshev LP stops at
    its radius cap (1e6), far from every input a plan needs (a domain ``u >= 1`` had its centre
    at ``u = 1e6 + 1``, and the plans' inputs near it): its centre is instead that of the domain
    cut by a box around its finite bounds (each unbounded side ``2 w`` beyond the finite bound
    across, or ``[-w, w]`` on a free axis, ``w`` the largest finite bound's magnitude, at least
    1), widened tenfold until the cut is not empty.
    """
    center, radius = domain.chebyshev_center()
    if radius < 1e6 * (1 - 1e-9):
        return center
    low, high = domain.bounding_box()
    finite = np.abs(np.concatenate([low[np.isfinite(low)], high[np.isfinite(high)]]))
    w = max(1.0, float(np.max(finite)) if finite.size else 1.0)
    m = domain.dim
    for _ in range(tries):
        lo = np.where(np.isfinite(low), low, np.where(np.isfinite(high), high - 2 * w, -w))
        hi = np.where(np.isfinite(high), high, np.where(np.isfinite(low), low + 2 * w, w))
        box = Polytope(np.vstack([np.eye(m), -np.eye(m)]), np.concatenate([-hi, lo]))
        cut = domain.intersect(box)
        if not cut.is_empty():
            return cut.chebyshev_center()[0]
        w *= 10.0
    return center


class BeliefSampler:
    """Grows belief trees for candidate plans of one problem (state shared across candidates)."""

    def __init__(
        self,
        problem: Problem,
        abstraction: Abstraction,
        proposer: Proposer,
        options: SolverOptions,
    ) -> None:
        self.problem = problem
        self.system = problem.switched_system
        self.abs = abstraction
        self.proposer = proposer
        self.opt = options.sampler
        self.rng = np.random.default_rng(0)  # replaced by each run's own stream
        self.formula = problem.stl_formula
        U = problem.control_domain
        self.u_center = steering_center(U)
        # Steering uses the control domain shrunk about its centre: inputs on their bounds leave
        # the executor's tracking correction no room and the polish no slack to move the plan.
        # {c0 + s (v - c0) : H v + c <= 0} = {u : H u + s c - (1 - s) H c0 <= 0}.
        self.UH, self.Uc = U.H, U.c
        self.Uc_gentle = STEER_SHRINK * U.c - (1.0 - STEER_SHRINK) * (U.H @ self.u_center)
        # The steering looks at most STEER_LOOKAHEAD ahead: the gains cost O(h^2) time and memory
        # (max_num_of_steps = 10**9 must not allocate them).
        lookahead = max(1, min(self.opt.max_num_of_steps, STEER_LOOKAHEAD))
        self._gains = [self._steering_gains(mode, lookahead) for mode in self.system.system_modes]
        self._index = [self._controllability_index(mode, lookahead) for mode in self.system.system_modes]
        n, m, a = self.system.n, self.system.m, abstraction.num_atoms
        self.max_nodes = max(MIN_NODES, TREE_BYTES // (8 * (n + n * n + m + 9) + a + 1))
        self._full_rank = [
            np.linalg.matrix_rank(mode.B) >= self.system.n for mode in self.system.system_modes
        ]
        self._underactuated = not all(self._full_rank)
        self._any_full_rank = any(self._full_rank)
        self._pareto = any(np.any(mode.process_cov != 0) for mode in self.system.system_modes)
        self._regions = [abstraction.region(i) for i in range(abstraction.num_atoms)]
        self._boxes = []
        self._centers = []
        for idx, r in enumerate(self._regions):
            if r.H.shape[0] and not r.is_empty():
                low, high = abstraction.bounds(idx)
                center = r.chebyshev_center()[0]
            else:
                low, high, center = (
                    np.full(self.system.n, -np.inf),
                    np.full(self.system.n, np.inf),
                    None,
                )
            self._boxes.append((low, high))
            self._centers.append(center)
        self.workspace = self._workspace_box()
        self._floors: dict[int, float] = {}
        self._sensing = self._sensing_points()

    @staticmethod
    def _steering_gains(mode: LCS, horizon: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per ``h = 1..horizon``: ``(A^h, G_h)`` where ``G_h`` maps ``target - A^h x`` to the
        least-norm ``h``-step input sequence reaching ``target`` (pseudo-inverse of the ``h``-step
        controllability matrix, shape (h m, n)): steering that respects any linear dynamics.
        """
        A, B = mode.A, mode.B
        out = []
        blocks: list[np.ndarray] = []  # [A^{h-1} B, ..., A B, B] built up one power at a time
        Ah = np.eye(A.shape[0])
        for _ in range(horizon):
            blocks = [A @ blk for blk in blocks] + [B]
            Ah = A @ Ah
            ctrl = np.hstack(blocks)
            out.append((Ah.copy(), np.linalg.pinv(ctrl)))
        return out

    @staticmethod
    def _controllability_index(mode: LCS, horizon: int) -> int:
        """Fewest steps in which the mode's inputs can move the mean anywhere (``horizon`` if never).

        At most ``n`` steps are tried: what ``n`` steps cannot reach, no number can
        (Cayley-Hamilton).
        """
        n = mode.A.shape[0]
        blocks = [mode.B]
        for h in range(1, min(horizon, n) + 1):
            if np.linalg.matrix_rank(np.hstack(blocks)) >= n:
                return h
            blocks.append(mode.A @ blocks[-1])
        return horizon

    def _sensing_points(self) -> np.ndarray:
        """Where some mode senses best: the best tenth of a fixed quasi-random set of points in the
        workspace box grown by its own size on every side (empty without state-dependent noise).

        The formula's regions need not contain the light (a formula without a free-space
        proposition, say), so samples drawn only inside their bounding box may never find it.
        """
        noisy = [m for m in self.system.system_modes if noise_depends_on_state(m)]
        if not noisy:
            return np.zeros((0, self.system.n))
        low, high = self.workspace
        width = high - low
        pts = (low - width) + 3.0 * width * _halton(256, self.system.n)
        quality = np.full(pts.shape[0], np.inf)
        for mode in noisy:
            for j, x in enumerate(pts):
                quality[j] = min(quality[j], float(np.trace(mode.noise_cov(x))))
        keep = np.argsort(quality, kind="stable")[: max(1, pts.shape[0] // 10)]
        return np.asarray(pts[keep])

    def _workspace_box(self) -> tuple[np.ndarray, np.ndarray]:
        mean0 = self.problem.initial_state.mean
        sd0 = np.sqrt(np.diag(self.problem.initial_state.cov))
        lows, highs = [mean0 - 3 * sd0 - 1e-9], [mean0 + 3 * sd0 + 1e-9]
        for low, high in self._boxes:
            lows.append(np.where(np.isfinite(low), low, mean0))
            highs.append(np.where(np.isfinite(high), high, mean0))
        low, high = np.min(lows, axis=0), np.max(highs, axis=0)
        pad = np.where(high - low < 1e-6, 1.0, 0.0)
        return low - pad, high + pad

    # -- sampling ---------------------------------------------------------------------------------
    def _events(self, plan: DiscretePlan) -> tuple[np.ndarray, np.ndarray]:
        """The plan's key events: ``(steps, atoms)``, sorted, where a region becomes required.

        A node follows a plan consistent with its realised prefix, and re-timing defers what it
        has not achieved, so the number of events at or before a node's step counts the goals
        it has really reached in order: its *stage*.
        """
        req = plan.required
        steps, atoms = [], []
        for i in range(req.shape[0]):
            if not self.abs.atoms[i].predicates:
                continue
            row = req[i]
            starts = np.nonzero(row[1:] & ~row[:-1])[0] + 1
            steps.extend(starts.tolist())
            atoms.extend([i] * starts.size)
        order = np.lexsort((np.asarray(atoms, dtype=int), np.asarray(steps, dtype=int)))
        return np.asarray(steps, dtype=int)[order], np.asarray(atoms, dtype=int)[order]

    def _goal_atoms(self, plan: DiscretePlan) -> list[int]:
        """Atoms of the plan ordered by the step they are first required (excluding step 0)."""
        firsts = []
        for i in range(plan.required.shape[0]):
            steps = np.nonzero(plan.required[i, 1:])[0]
            if steps.size and self.abs.atoms[i].predicates:
                firsts.append((int(steps[0]) + 1, i))
        return [i for _, i in sorted(firsts)]

    def _sample_in_atom(self, i: int) -> np.ndarray | None:
        low, high = self._boxes[i]
        wl, wh = self.workspace
        # Open sides (half-planes) borrow the workspace box, never crossing the finite side.
        low = np.where(np.isfinite(low), low, np.minimum(wl, np.where(np.isfinite(high), high, wl)))
        high = np.where(np.isfinite(high), high, np.maximum(wh, low))
        region = self._regions[i]
        center = self._centers[i]
        # Under-actuated dynamics: coordinates the region leaves open (a velocity) take the
        # centre's value, so a branch arrives at rest rather than passing through.
        pin = self._underactuated and center is not None
        both_open = ~np.isfinite(self._boxes[i][0]) & ~np.isfinite(self._boxes[i][1])
        for _ in range(20):
            s = self.rng.uniform(low, high)
            if center is not None:
                s = center + 0.5 * (s - center)
                if pin:
                    s = np.where(both_open, center, s)
            if np.all(region.H @ s + region.c <= 0):
                return s
        return center

    def _sample(self, goal: int | None) -> np.ndarray:
        if goal is not None and self.rng.random() < self.opt.goal_bias:
            s = self._sample_in_atom(goal)
            if s is not None:
                return s
        return self.rng.uniform(*self.workspace)

    # -- steering ---------------------------------------------------------------------------------
    def _steer(
        self, q: int, mean: np.ndarray, target: np.ndarray, remaining: int = 1, gentle: bool = False
    ) -> np.ndarray:
        """Input toward ``target`` within ``remaining`` steps, pulled into the control domain.

        A fully actuated mode pushes as hard as it can (the one-step least-norm input, clipped:
        the fastest). An under-actuated one takes the fastest least-norm input sequence whose
        inputs all lie in the domain (the smallest feasible ``h`` from the controllability index
        up to ``remaining``), else spreads the effort over ``remaining`` steps, so that it can
        still brake (clipped dead-beat sends a double integrator out of its workspace).
        ``gentle``: a fully actuated mode stays within :data:`STEER_SHRINK` of the domain.
        """
        gains = self._gains[q]
        Uc = self.Uc_gentle if gentle and self._full_rank[q] else self.Uc
        m = self.system.m
        lo = min(self._index[q], len(gains))
        hi = min(max(remaining, lo), len(gains)) if not self._full_rank[q] else lo
        u = None
        for h in range(lo, hi + 1):
            Ah, G = gains[h - 1]
            seq = (G @ (target - Ah @ mean)).reshape(h, m)
            if np.all(seq @ self.UH.T + Uc <= 1e-12):
                return np.asarray(seq[0])
            if h == hi:
                u = seq[0]
                if not self._full_rank[q]:
                    # receding horizon of the longest extension: it can always still stop
                    Ah, G = gains[-1]
                    part = self._partial(mean, target, Ah, G, len(gains))
                    if part is not None:
                        return part
        if u is None:  # pragma: no cover - the loop always runs at least once
            u = np.zeros(m)
        slack = self.UH @ u + Uc
        if np.all(slack <= 0):
            return u
        c0 = self.u_center
        d = u - c0
        rate = self.UH @ d
        room = -(self.UH @ c0 + Uc)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(rate > 1e-12, room / rate, np.inf)
        clipped: np.ndarray = c0 + min(1.0, float(np.min(t))) * d
        return clipped

    def _partial(
        self, mean: np.ndarray, target: np.ndarray, Ah: np.ndarray, G: np.ndarray, h: int
    ) -> np.ndarray | None:
        """First input of the admissible ``h``-step sequence that goes furthest toward ``target``.

        Under-actuated dynamics (a double integrator) cannot reach a far sample within one
        extension; clipping the least-norm sequence then leaves the branch at speed, unable to
        brake before a wall. The sequence to the state ``mean + a (target - mean)`` is affine in
        ``a``; the largest ``a`` in ``[0, 1]`` whose inputs all lie in the control domain is a
        ratio test per input row. ``None`` when even ``a = 0`` (come to rest where it is, in the
        sample's direction of travel) is out of reach.
        """
        m = self.system.m
        base = (G @ (mean - Ah @ mean)).reshape(h, m)
        slope = (G @ (target - mean)).reshape(h, m)
        rows0 = base @ self.UH.T + self.Uc  # (h, faces): must stay <= 0
        rate = slope @ self.UH.T
        if np.any(rows0 > 1e-12):
            return None
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            t = np.where(rate > 1e-12, -rows0 / rate, np.inf)
        a = min(1.0, float(np.min(t)))
        return np.asarray(base[0] + a * slope[0])

    # -- plans ------------------------------------------------------------------------------------
    def _allowed_modes(self, plan: DiscretePlan, k: int) -> list[int]:
        modes = set(range(self.system.num_modes))
        if k < plan.length:
            for i in np.nonzero(plan.required[:, k])[0]:
                ms = self.abs.mode_sets[i]
                if ms is not None:
                    modes &= ms
        return sorted(modes)

    def _replan(
        self, tree: _Tree, leaf_truth: np.ndarray, leaf_k: int, leaf_mode: int, parent: int
    ) -> DiscretePlan | None:
        """A plan consistent with the realised prefix (path to ``parent`` plus the new step), or None."""
        path = tree.path(parent)
        truth = np.vstack([tree.truth[path], leaf_truth[None, :]]).T  # (n_atoms, k+1)
        modes = np.concatenate([tree.action[path[1:]], [leaf_mode]]).astype(int)
        return self.proposer.complete(truth, modes)

    def _satisfied(self, tree: _Tree, leaf: int) -> bool:
        path = tree.path(leaf)
        truth = tree.truth[path].T
        return bool(evaluate_bool(self.formula, truth, self.abs.index)[id(self.formula)][0])

    # -- post-processing --------------------------------------------------------------------------
    def shortcut(
        self, actions: np.ndarray, controls: np.ndarray, max_checks: int = 24
    ) -> tuple[np.ndarray, np.ndarray]:
        """Shorten a found plan greedily (sampling plans wander); every accepted cut is re-checked.

        From step ``i``, try to reach the planned mean of a later step ``j`` directly with the
        steering law in fewer steps; splice the cut in when the whole re-rolled plan still
        satisfies the formula (its covariances change: a cut that skips the sensing detour is
        refused). Deterministic, and bounded by ``max_checks`` full re-checks.
        """
        modes = self.system.system_modes
        init = self.problem.initial_state
        checks = 0
        i = 0
        means, covs = rollout_arrays(modes, init.mean, init.cov, actions, controls)
        truth = self.abs.labels(means, covs, actions, 0)
        while checks < max_checks:
            N = actions.shape[0]
            if i >= N - 2:
                break
            improved = False
            for j in sorted({N, (i + N) // 2 + 1, i + (N - i) // 4 + 2, i + 8, i + 4}, reverse=True):
                if not i + 2 <= j <= N or checks >= max_checks:
                    continue
                q = int(actions[i])
                mean, target = means[i], means[j]
                cut_u = []
                for t in range(j - i - 1):
                    u = self._steer(q, mean, target, j - i - 1 - t, gentle=True)
                    cut_u.append(u)
                    mean = modes[q].A @ mean + modes[q].B @ u
                    if np.linalg.norm(mean - target) <= 1e-9 * (1.0 + np.linalg.norm(target)):
                        break
                else:
                    continue
                new_actions = np.concatenate([actions[:i], np.full(len(cut_u), q), actions[j:]])
                new_controls = np.vstack([controls[:i], np.array(cut_u), controls[j:]])
                checks += 1
                # The prefix up to step i is unchanged: roll and label only the tail.
                tail_m, tail_c = rollout_arrays(modes, means[i], covs[i], new_actions[i:], new_controls[i:])
                m2 = np.vstack([means[:i], tail_m])
                c2 = np.concatenate([covs[:i], tail_c])
                t2 = np.hstack([truth[:, : i + 1], self.abs.labels(m2, c2, new_actions, i + 1)])
                if evaluate_bool(self.formula, t2, self.abs.index)[id(self.formula)][0]:
                    actions, controls, means, covs, truth = new_actions, new_controls, m2, c2, t2
                    improved = True
                    break
            if not improved:
                i += max(1, (actions.shape[0] - i) // 8)
        return actions, controls

    # -- main loop --------------------------------------------------------------------------------
    def run(
        self, plan: DiscretePlan, iterations: int, rng: np.random.Generator, deadline: float
    ) -> SamplerOutcome:
        """Grow a tree guided by ``plan`` for at most ``iterations`` iterations.

        ``rng`` is the candidate's own random stream; ``deadline`` (``time.perf_counter()``
        seconds) is a safety cap only.
        """
        self.rng = rng
        opt, abs_ = self.opt, self.abs
        sys = self.system
        modes = sys.system_modes
        init = self.problem.initial_state
        tree = _Tree(sys.n, sys.m, abs_.num_atoms)
        plans = [plan]
        root = tree.add(init.mean, init.cov, 0, -1, -1, None, abs_.truth(init.mean, init.cov, -1), 0)
        tree.active[root] = True
        H = self.proposer.cap
        events = [self._events(plan)]
        # A patrol (some region required again and again): progress is the number of
        # alternating visits a lineage has made, not the plan's events (re-timing defers them).
        ev_atoms0 = events[0][1].tolist()
        cycle = list(dict.fromkeys(ev_atoms0))
        recurring = len(cycle) >= 2 and len(ev_atoms0) > len(cycle)
        gap = 2 * opt.max_num_of_steps
        iters = 0
        capped = False
        alive: set[int] = set()  # nodes whose prefix was checked completable
        dropped = 0
        while iters < iterations:
            if capped or (not iters % 32 and time.perf_counter() >= deadline):
                capped = True
                break
            if tree.size >= self.max_nodes:
                logger.info("sampler: the tree holds %d nodes, its memory cap: no more growth", tree.size)
                break
            iters += 1
            act = np.nonzero(tree.active[: tree.size])[0]
            if act.size == 0:
                break
            # Mostly extend the lineages that have reached the most goals, in order, toward their
            # next one; sometimes the whole tree (exploration, e.g. a sensing detour).
            if rng.random() < _FOCUS:
                stages = tree.stage[act]
                act = act[stages == stages.max()]
            goal: int | None
            if recurring:
                unc = tree.unc[act]
                sure = act[unc <= max(float(unc.min()), self._floor(cycle[0]))]
                ref = int(sure[int(rng.integers(sure.size))])
                goal = self._cycle_goal(tree, ref, cycle)
            else:
                ref = int(act[int(np.argmin(tree.unc[act]))])
                goal = self._next_goal(tree, ref, events[int(tree.plan[ref])])
            aim_goal = goal is not None and rng.random() < opt.goal_bias
            s = self._sample_in_atom(goal) if aim_goal and goal is not None else None
            if s is None:
                aim_goal = False
                if self._sensing.shape[0] and rng.random() < 0.5 * opt.goal_bias:
                    width = self.workspace[1] - self.workspace[0]
                    s = self._sensing[int(rng.integers(self._sensing.shape[0]))] + 0.05 * width * (
                        rng.random(sys.n) - 0.5
                    )
                else:
                    s = rng.uniform(*self.workspace)
            pool = act
            if goal is not None and not aim_goal:
                # Nodes already at the goal are only extended toward the goal: an exploration
                # sample must not drag a lineage out of the region it is holding.
                off = act[~tree.truth[act, goal]]
                pool = off if off.size else act
            node = ref if recurring and aim_goal else self._select(tree, pool, s, goal)
            if (
                (self._underactuated or self._pareto)
                and aim_goal
                and goal is not None
                and self._centers[goal] is not None
                and tree.truth[node, goal]
            ):
                # Holding with under-actuated dynamics: settle at the centre (every position off
                # it is margin the growing covariance will need later).
                s = np.asarray(self._centers[goal])
                settle = True
            else:
                settle = False
            steps = int(rng.integers(opt.min_num_of_steps, opt.max_num_of_steps + 1))
            if settle:
                # A hold is not limited to one extension's length: a holder settling at the
                # centre goes on for the rest of its plan (it stops where the plan breaks).
                steps = max(steps, plans[int(tree.plan[node])].length - int(tree.k[node]))
            prefer = self._extension_mode(tree, node, goal, rng)
            # (a patrol's round trips need full speed: its deadlines leave no time for gentleness)
            gentle = self._any_full_rank and not recurring and bool(rng.random() < 0.5)
            cur = node
            for j in range(steps):
                k = int(tree.k[cur]) + 1
                if k > H or tree.size >= self.max_nodes:
                    break
                if j and not j % 64 and time.perf_counter() >= deadline:
                    capped = True
                    break
                pl = plans[int(tree.plan[cur])]
                allowed = self._allowed_modes(pl, k)
                if not allowed:
                    break
                if prefer in allowed:
                    q = prefer
                else:
                    q = allowed[0] if len(allowed) == 1 else int(rng.choice(allowed))
                u = self._steer(q, tree.mean[cur], s, steps - j, gentle)
                mean, cov = belief_step(modes[q], tree.mean[cur], tree.cov[cur], u)
                truth = abs_.truth(mean, cov, q)
                pid = int(tree.plan[cur])
                if k < pl.length and not np.all(truth[pl.required[:, k]]):
                    new = self._replan(tree, truth, k, q, cur)
                    if new is None:
                        break
                    plans.append(new)
                    events.append(self._events(new))
                    pid = len(plans) - 1
                if recurring:
                    stage = self._visit(tree, cur, truth, k, cycle, gap)
                else:
                    stage = int(np.searchsorted(events[pid][0], k, side="right"))
                cur = tree.add(mean, cov, k, cur, q, u, truth, pid, stage)
                if recurring:
                    self._record_visit(tree, cur, truth, k, cycle)
            if cur == node:
                # Not one step was possible: if the node's own prefix can no longer be completed
                # (a deadline of the formula has passed), it is dead: never select it again.
                if settle or (node not in alive and not self._alive(tree, node)):
                    # (a holder that cannot take one more step toward the centre never will:
                    # that steering is deterministic)
                    tree.active[node] = False
                    dropped += 1
                else:
                    alive.add(node)
                continue
            leaf = cur
            if self._satisfied(tree, leaf):
                path = tree.path(leaf)
                logger.info("sampler: goal after %d iterations, %d nodes", iters, tree.size)
                return SamplerOutcome(
                    tree.action[path[1:]].copy(), tree.control[path[1:]].copy(), tree.size, iters, False
                )
            self._drain(tree, leaf, act)
        logger.info(
            "sampler: %s after %d iterations, %d nodes (%d dead nodes dropped)",
            "wall-clock cap" if capped else "budget spent",
            iters,
            tree.size,
            dropped,
        )
        if logger.isEnabledFor(logging.DEBUG):
            names = abs_.names()
            held = tree.truth[: tree.size]
            logger.debug(
                "sampler tree: nodes per proposition %s; longest run per proposition %s; "
                "deepest step %d; plans %d",
                {names[i]: int(held[:, i].sum()) for i in range(abs_.num_atoms)},
                {
                    names[i]: int(np.max(tree.run[: tree.size][held[:, i]], initial=0))
                    for i in range(abs_.num_atoms)
                },
                int(tree.k[: tree.size].max()),
                len(plans),
            )
        return SamplerOutcome(None, None, tree.size, iters, capped, self._closest(tree))

    @staticmethod
    def _closest(tree: _Tree) -> tuple[np.ndarray, np.ndarray, float] | None:
        """The node with the most plan events met (then the deepest), as actions and controls."""
        size = tree.size
        if size <= 1:
            return None
        stage, k = tree.stage[:size], tree.k[:size]
        best = int(np.lexsort((k, stage))[-1])
        path = tree.path(best)
        if len(path) <= 1:
            return None
        # Progress: events met first, steps realised to break ties (a total order over nodes).
        progress = float(stage[best]) + float(k[best]) / (1.0 + float(k.max()))
        return tree.action[path[1:]].copy(), tree.control[path[1:]].copy(), progress

    def _next_goal(self, tree: _Tree, node: int, events: tuple[np.ndarray, np.ndarray]) -> int | None:
        """The region ``node`` should make for: the first event of its plan after its step whose
        region it is not in (a patrol's next stop, a sequence's next region), else the region of
        its plan's last event (a hold); ``None`` without events.
        """
        ev_steps, ev_atoms = events
        if not ev_atoms.size:
            return None
        later = ev_steps > tree.k[node]
        todo = later & ~tree.truth[node, ev_atoms]
        if np.any(todo):
            return int(ev_atoms[int(np.argmax(todo))])
        if np.any(later):
            return int(ev_atoms[int(np.argmax(later))])
        return int(ev_atoms[-1])

    @staticmethod
    def _entered(tree: _Tree, parent: int, truth: np.ndarray, cycle: list[int]) -> int:
        """The patrol region a step from ``parent`` newly enters (not the last one), or -1."""
        last = int(tree.last[parent])
        for a in cycle:
            if truth[a] and not tree.truth[parent, a] and a != last:
                return a
        return -1

    def _visit(self, tree: _Tree, parent: int, truth: np.ndarray, k: int, cycle: list[int], gap: int) -> int:
        """Patrol progress of a step from ``parent``: one more alternating visit when it enters
        the next region within ``gap`` steps of the last visit; 0 once a lineage has stalled."""
        a = self._entered(tree, parent, truth, cycle)
        since = k - int(tree.lastk[parent])
        if a >= 0:
            return int(tree.stage[parent]) + 1 if since <= gap or tree.last[parent] < 0 else 1
        return int(tree.stage[parent]) if since <= gap else 0

    def _record_visit(self, tree: _Tree, node: int, truth: np.ndarray, k: int, cycle: list[int]) -> None:
        """Remember the patrol region ``node`` newly entered (and when)."""
        parent = int(tree.parent[node])
        a = self._entered(tree, parent, truth, cycle)
        if a >= 0:
            tree.last[node], tree.lastk[node] = a, k

    @staticmethod
    def _cycle_goal(tree: _Tree, node: int, cycle: list[int]) -> int:
        """A patrol's next region for ``node``: the one after the region it last entered."""
        last = int(tree.last[node])
        if last < 0:
            for a in cycle:
                if not tree.truth[node, a]:
                    return a
            return cycle[0]
        return cycle[(cycle.index(last) + 1) % len(cycle)]

    def _alive(self, tree: _Tree, node: int) -> bool:
        """Whether the realised prefix up to ``node`` can still be completed (one SAT call).

        The root is always alive (the candidate itself completes it).
        """
        if tree.parent[node] < 0:
            return True
        path = tree.path(node)
        truth = tree.truth[path].T
        modes = tree.action[path[1:]].astype(int)
        return self.proposer.complete(truth, modes) is not None

    def _extension_mode(self, tree: _Tree, node: int, goal: int | None, rng: np.random.Generator) -> int:
        """The mode one extension prefers (kept over its steps when the plan allows it).

        With one mode, that mode. Otherwise a uniformly random mode, except when the node is
        holding its goal region or is less certain than the region needs: then, three times in
        four, the mode whose next belief is least uncertain (a sensing mode where it senses), so
        holds and approaches under process noise re-sense instead of drifting blind.
        """
        num = self.system.num_modes
        if num == 1:
            return 0
        needs_sensing = goal is not None and (
            bool(tree.truth[node, goal]) or tree.unc[node] > self._floor(goal)
        )
        if needs_sensing and rng.random() < 0.75:
            best, best_unc = 0, np.inf
            zero = np.zeros(self.system.m)
            for q, mode in enumerate(self.system.system_modes):
                _, cov = belief_step(mode, tree.mean[node], tree.cov[node], zero)
                unc = float(np.trace(cov))
                if unc < best_unc:
                    best, best_unc = q, unc
            return best
        return int(rng.integers(num))

    def _select(self, tree: _Tree, pool: np.ndarray, s: np.ndarray, goal: int | None) -> int:
        """Least uncertain node within ``delta_near`` of ``s`` (else the nearest).

        Uncertainty below what the goal region needs counts as equal; ties go to the node that
        has held its current label longest (progress), then to the less uncertain.
        """
        d = np.linalg.norm(tree.mean[pool] - s, axis=1)
        within = d <= self.opt.delta_near
        if not np.any(within):
            return int(pool[np.argmin(d)])
        near = pool[within]
        floor = self._floor(goal)
        unc = tree.unc[near]
        progress = np.where(tree.truth[near, goal], tree.run[near], 0) if goal is not None else 0 * unc
        key = np.maximum(unc, floor)
        if self._pareto and goal is not None and self.rng.random() < 0.5:
            # Under process noise a hold loses certainty as it goes on: a holding node that still
            # has three quarters of the region's room counts as certain enough (progress decides).
            # A fully actuated holder reaches the centre in a step or two, where its covariance
            # settles (re-sensing): every holder counts.
            roomy = unc <= 9.0 * floor if self._underactuated else np.ones(near.shape[0], dtype=bool)
            key = np.where(tree.truth[near, goal] & roomy, floor, key)
        order = np.lexsort((unc, -progress, key))
        return int(near[order[0]])

    def _floor(self, goal: int | None) -> float:
        """Trace of covariance below which a belief is certain enough for the goal region."""
        if goal is None or goal in self._floors:
            return self._floors.get(goal, 0.0) if goal is not None else 0.0
        ap = self.abs.atoms[goal]
        floor = 0.0
        if ap.predicates and self._centers[goal] is not None:
            radius = self._regions[goal].chebyshev_center()[1]
            z = float(np.max(np.where(np.isfinite(ap.cone.z), ap.cone.z, 0.0)))
            if z > 0 and np.isfinite(radius):
                sd = 0.25 * radius / z  # a quarter of the room the region leaves the mean
                floor = self.system.n * sd**2
        self._floors[goal] = floor
        return floor

    def _drain(self, tree: _Tree, leaf: int, act: np.ndarray) -> None:
        """Keep the least uncertain node among same-label, same-progress neighbours of ``leaf``."""
        d = np.linalg.norm(tree.mean[act] - tree.mean[leaf], axis=1)
        close = act[d <= self.opt.delta_drain]
        if self._pareto:
            # Under process noise a hold costs certainty: a longer hold must not lose to a fresh
            # arrival that is merely less uncertain. Keep the Pareto front of (run, certainty).
            close = close[np.all(tree.truth[close] == tree.truth[leaf], axis=1)]
            run, unc = tree.run[leaf], tree.unc[leaf]
            if np.any((tree.run[close] >= run) & (tree.unc[close] <= unc)):
                return
            tree.active[close[(tree.run[close] <= run) & (tree.unc[close] >= unc)]] = False
            tree.active[leaf] = True
            return
        if close.size:
            same = np.all(tree.truth[close] == tree.truth[leaf], axis=1)
            same &= _bucket(tree.run[close]) == _bucket(tree.run[leaf])
            close = close[same]
        if close.size and np.min(tree.unc[close]) <= tree.unc[leaf]:
            return  # dominated: the new node stays as an interior node only
        tree.active[close] = False
        tree.active[leaf] = True


def _halton(count: int, dim: int) -> np.ndarray:
    """The first ``count`` points (from index 1) of the ``dim``-dimensional Halton sequence in [0, 1)."""
    primes: list[int] = []
    c = 2
    while len(primes) < dim:
        if all(c % p for p in primes):
            primes.append(c)
        c += 1
    out = np.zeros((count, dim))
    for d, base in enumerate(primes):
        for i in range(count):
            f, r, k = 1.0, 0.0, i + 1
            while k:
                f /= base
                r += f * (k % base)
                k //= base
            out[i, d] = r
    return out


def _bucket(run: np.ndarray | int) -> np.ndarray:
    return np.floor(np.log2(np.asarray(run) + 1.0)).astype(int)


class SamplerTeacher(Teacher):
    """Decides candidates under state-dependent noise by sampling belief space (never refutes).

    Parameters
    ----------
    problem : Problem
    abstraction : Abstraction
    proposer : Proposer
        Used to re-time a branch whose realised prefix breaks the candidate.
    options : SolverOptions
    scaling : Scaling
        Units for the polish LP.
    seeds : numpy.random.SeedSequence
        Parent of every candidate's random stream (one child spawned per candidate).
    """

    name = "sampler"

    def __init__(
        self,
        problem: Problem,
        abstraction: Abstraction,
        proposer: Proposer,
        options: SolverOptions,
        scaling: Scaling,
        seeds: np.random.SeedSequence,
    ) -> None:
        self.problem = problem
        self.abs = abstraction
        self.options = options.sampler
        self.scaling = scaling
        self.seeds = seeds
        self.sampler = BeliefSampler(problem, abstraction, proposer, options)

    def applies(self, problem: Problem) -> bool:
        """Only problems the plan LP is not exact for (:func:`~.plan_lp.lp_exact`) need sampling."""
        return not lp_exact(problem.switched_system)

    def exact(self, problem: Problem) -> bool:
        """Sampling never proves a candidate impossible."""
        return False

    def teach(self, plan: DiscretePlan, budget: Budget, stats: SolveStats) -> Verdict:
        """Search belief space for ``plan`` within its work budget; shortcut and polish a find."""
        rng = np.random.default_rng(self.seeds.spawn(1)[0])
        cap = min(budget.deadline, time.perf_counter() + self.options.rrt_timeout)
        budget_iters = self.options.iterations
        with stats.clock("time_sampling"):
            out = self.sampler.run(plan, budget_iters, rng, cap)
        stats.nodes += out.nodes
        stats.sampler_iterations += out.iterations
        if out.capped and not budget.expired() and "rrt_timeout" not in stats.caps_hit:
            stats.caps_hit.append("rrt_timeout")
        if out.actions is None or out.controls is None:
            why = (
                f"sampler: rrt_timeout ({self.options.rrt_timeout:g} s) reached after "
                f"{out.iterations} iterations"
                if out.capped
                else f"sampler: no plan within its budget of {budget_iters} iterations"
            )
            return Unknown(why, closest=out.closest, budgeted=True)
        with stats.clock("time_sampling"):
            actions, controls = self.sampler.shortcut(out.actions, out.controls, self.options.shortcut_checks)
        with stats.clock("time_lp"):
            actions, controls = self._polish(actions, controls, stats, budget.deadline)
        return Found(actions, controls, "the belief-space sampler")

    def rescue(self, plan: DiscretePlan, refuted: Refuted, budget: Budget, stats: SolveStats) -> Verdict:
        """Search belief space for a candidate the LP refuted for its mode sequence only.

        With several modes an LP conflict names the modes of the candidate, so the proposer
        would enumerate mode sequences one by one (``2^k`` of them for ``k`` steps); the sampler
        chooses its own modes, so it gets the candidate's requirements on the 1st, 2nd, 4th,
        8th, ... such refutation (a deterministic schedule). Returns ``refuted`` unchanged
        unless the sampler finds a plan (which the loop's monitor then checks).
        """
        conflict = refuted.conflict
        if conflict.modes is None or self.problem.switched_system.num_modes < 2:
            return refuted
        self._mode_refutations = getattr(self, "_mode_refutations", 0) + 1
        n = self._mode_refutations
        if n & (n - 1):
            return refuted
        logger.info("sampler: rescuing candidate refuted for its modes only (%d such refutations)", n)
        verdict = self.teach(plan, budget, stats)
        return verdict if isinstance(verdict, Found) else refuted

    def _polish(
        self, actions: np.ndarray, controls: np.ndarray, stats: SolveStats, deadline: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Give a sampled plan the room its execution needs, keeping its modes.

        The sampler stops at the first belief that meets the plan, often a hair inside a
        required region and with inputs on their bounds, and such a plan breaks under execution
        noise. Each round takes the requirements the trajectory meets (its witness), predicts the
        closed loop around it (:func:`.room.execution_room`: per required face and step, the
        room the executed belief and the true state need; per input face, the room the tracking
        correction needs), and solves one step of sequential convex programming toward that
        room (:func:`.room.room_lp`, means within ``trust``); the re-rolled plan is kept only if
        the monitor still accepts it and its room improved (:meth:`.room.Room.better_than`);
        ``trust`` halves after a round that did not help. It stops when the room is complete
        (:attr:`.room.Room.complete`), or after a failed round once every required face has its
        room. The rounds are a work budget (``2 * max(polish_rounds, 4)``); no round starts after
        ``deadline`` (the solve's time limit).
        """
        problem = self.problem
        traj = rollout(problem.switched_system, problem.initial_state, actions, controls)
        rounds = 2 * max(self.options.polish_rounds, 4) if self.options.polish_rounds else 0
        traj = give_room(problem, self.abs, self.scaling, traj, rounds, stats, deadline)
        return traj.get_action(), traj.get_control()
