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
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from ..belief import belief_step
from .abstraction import Abstraction
from .bmc import BMCEncoder
from .plan import DiscretePlan, evaluate_bool, extract_witness

__all__ = ["BeliefSampler", "SamplerOutcome"]

logger = logging.getLogger(__name__)


@dataclass
class SamplerOutcome:
    """What the sampler found for one candidate."""

    actions: np.ndarray | None
    controls: np.ndarray | None
    nodes: int
    sat_calls: int


class _Tree:
    """Struct-of-arrays node store (grows by doubling)."""

    def __init__(self, n: int, m: int, n_atoms: int, cap: int = 1024) -> None:
        self.n, self.m, self.a = n, m, n_atoms
        self.size = 0
        self._alloc(cap)

    def _alloc(self, cap: int) -> None:
        def grow(old, shape, dtype):
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
        self.cap = cap

    def add(self, mean, cov, k, parent, action, control, truth, plan) -> int:
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
        self.active[i] = False
        self.size += 1
        return i

    def path(self, i: int) -> list[int]:
        out = []
        while i >= 0:
            out.append(i)
            i = int(self.parent[i])
        return out[::-1]


class BeliefSampler:
    """Grows belief trees for candidate plans of one problem (state shared across candidates)."""

    def __init__(
        self,
        problem,
        abstraction: Abstraction,
        encoder: BMCEncoder,
        options,
        rng: np.random.Generator,
    ) -> None:
        self.problem = problem
        self.system = problem.switched_system
        self.abs = abstraction
        self.enc = encoder
        self.opt = options
        self.rng = rng
        self.formula = problem.stl_formula
        U = problem.control_domain
        self.UH, self.Uc = U.H, U.c
        self.u_center = U.chebyshev_center()[0]
        self.B_pinv = [np.linalg.pinv(mode.B) for mode in self.system.system_modes]
        self._regions = [abstraction.region(i) for i in range(abstraction.num_atoms)]
        self._boxes = []
        self._centers = []
        for r in self._regions:
            if r.H.shape[0] and not r.is_empty():
                low, high = r.bounding_box()
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
        low = np.where(np.isfinite(low), low, wl)
        high = np.where(np.isfinite(high), high, wh)
        region = self._regions[i]
        center = self._centers[i]
        for _ in range(20):
            s = self.rng.uniform(low, high)
            if center is not None:
                s = center + 0.5 * (s - center)
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
    def _steer(self, q: int, mean: np.ndarray, target: np.ndarray) -> np.ndarray:
        mode = self.system.system_modes[q]
        u = self.B_pinv[q] @ (target - mode.A @ mean)
        slack = self.UH @ u + self.Uc
        if np.all(slack <= 0):
            return u
        c0 = self.u_center
        d = u - c0
        rate = self.UH @ d
        room = -(self.UH @ c0 + self.Uc)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(rate > 1e-12, room / rate, np.inf)
        return c0 + min(1.0, float(np.min(t))) * d

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
        """A plan consistent with the realised prefix (path to ``parent`` plus the new step), or None.

        The plan is the witness of the *optimistic* completion (every proposition claimed at every
        later step) with the latest until-witnesses, so the branch keeps it as long as possible;
        the SAT proposer then confirms the prefix is completable under everything learnt so far
        (pruning facts and counterexamples).
        """
        path = tree.path(parent)
        truth = np.vstack([tree.truth[path], leaf_truth[None, :]]).T  # (n_atoms, k+1)
        H = self.enc.H
        optimistic = np.ones((truth.shape[0], H + 1), dtype=bool)
        optimistic[:, : leaf_k + 1] = truth
        w = extract_witness(self.formula, optimistic, self.abs.index, prefer_late=True)
        if w is None:
            return None  # not even the best possible future satisfies the formula
        modes = np.concatenate([tree.action[path[1:]], [leaf_mode]])
        assume = [-int(v) for v in self.enc.p[:, : leaf_k + 1][~truth]]
        if self.system.num_modes > 1:
            assume += [int(self.enc.m[q, j + 1]) for j, q in enumerate(modes)]
        if not self.enc.solve(assumptions=assume):
            return None
        required, L = w
        _, model_modes, _ = self.enc.model_claims()
        mm = model_modes[: max(L, leaf_k + 1)].copy()
        mm[1 : leaf_k + 1] = modes
        return DiscretePlan(required[:, :L], mm[:L], L)

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
        while checks < max_checks:
            N = actions.shape[0]
            means, covs = _roll(modes, init.mean, init.cov, actions, controls)
            if i >= N - 2:
                break
            improved = False
            for j in sorted({N, (i + N) // 2 + 1, i + (N - i) // 4 + 2, i + 8, i + 4}, reverse=True):
                if not i + 2 <= j <= N or checks >= max_checks:
                    continue
                q = int(actions[i])
                mean, target = means[i], means[j]
                cut_u = []
                for _ in range(j - i - 1):
                    u = self._steer(q, mean, target)
                    cut_u.append(u)
                    mean = modes[q].A @ mean + modes[q].B @ u
                    if np.linalg.norm(mean - target) <= 1e-9 * (1.0 + np.linalg.norm(target)):
                        break
                else:
                    continue
                new_actions = np.concatenate([actions[:i], np.full(len(cut_u), q), actions[j:]])
                new_controls = np.vstack([controls[:i], np.array(cut_u), controls[j:]])
                checks += 1
                m2, c2 = _roll(modes, init.mean, init.cov, new_actions, new_controls)
                truth = np.array(
                    [
                        self.abs.truth(m2[k], c2[k], int(new_actions[k - 1]) if k else -1)
                        for k in range(len(m2))
                    ]
                ).T
                if evaluate_bool(self.formula, truth, self.abs.index)[id(self.formula)][0]:
                    actions, controls = new_actions, new_controls
                    improved = True
                    break
            if not improved:
                i += max(1, (actions.shape[0] - i) // 8)
        return actions, controls

    # -- main loop --------------------------------------------------------------------------------
    def run(self, plan: DiscretePlan, deadline: float) -> SamplerOutcome:
        """Grow a tree guided by ``plan`` until a goal node is found or ``deadline`` passes."""
        opt, rng, abs_ = self.opt, self.rng, self.abs
        sys = self.system
        modes = sys.system_modes
        init = self.problem.initial_state
        tree = _Tree(sys.n, sys.m, abs_.num_atoms)
        plans = [plan]
        root = tree.add(init.mean, init.cov, 0, -1, -1, None, abs_.truth(init.mean, init.cov, -1), 0)
        tree.active[root] = True
        sat0 = self.enc.sat_calls
        H = self.enc.H
        goal_cache: dict[int, int | None] = {}
        iters = 0
        while time.perf_counter() < deadline:
            iters += 1
            act = np.nonzero(tree.active[: tree.size])[0]
            if act.size == 0:
                break
            # Goal: the first atom, in plan order, that no active node satisfies yet (else the last).
            pid = int(tree.plan[act[int(np.argmin(tree.unc[act]))]])
            if pid not in goal_cache:
                goal_cache[pid] = None
                order = self._goal_atoms(plans[pid])
                goal_cache[pid] = order[-1] if order else None
                for i in order:
                    if not np.any(tree.truth[act, i]):
                        goal_cache[pid] = i
                        break
            goal = goal_cache[pid]
            aim_goal = goal is not None and rng.random() < opt.goal_bias
            s = self._sample_in_atom(goal) if aim_goal else None
            if s is None:
                aim_goal = False
                s = rng.uniform(*self.workspace)
            pool = act
            if goal is not None and not aim_goal:
                # Nodes already at the goal are only extended toward the goal: an exploration
                # sample must not drag a lineage out of the region it is holding.
                off = act[~tree.truth[act, goal]]
                pool = off if off.size else act
            node = self._select(tree, pool, s, goal)
            steps = int(rng.integers(opt.min_num_of_steps, opt.max_num_of_steps + 1))
            cur = node
            for _ in range(steps):
                k = int(tree.k[cur]) + 1
                if k > H:
                    break
                pl = plans[int(tree.plan[cur])]
                allowed = self._allowed_modes(pl, k)
                if not allowed:
                    break
                q = allowed[0] if len(allowed) == 1 else int(rng.choice(allowed))
                u = self._steer(q, tree.mean[cur], s)
                mean, cov = belief_step(modes[q], tree.mean[cur], tree.cov[cur], u)
                truth = abs_.truth(mean, cov, q)
                pid = int(tree.plan[cur])
                if k < pl.length and not np.all(truth[pl.required[:, k]]):
                    new = self._replan(tree, truth, k, q, cur)
                    if new is None:
                        break
                    plans.append(new)
                    pid = len(plans) - 1
                cur = tree.add(mean, cov, k, cur, q, u, truth, pid)
            if cur == node:
                continue
            leaf = cur
            if self._satisfied(tree, leaf):
                path = tree.path(leaf)
                logger.info("sampler: goal after %d iterations, %d nodes", iters, tree.size)
                return SamplerOutcome(
                    tree.action[path[1:]].copy(),
                    tree.control[path[1:]].copy(),
                    tree.size,
                    self.enc.sat_calls - sat0,
                )
            self._drain(tree, leaf, act)
        logger.info("sampler: time-out after %d iterations, %d nodes", iters, tree.size)
        return SamplerOutcome(None, None, tree.size, self.enc.sat_calls - sat0)

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
        order = np.lexsort((unc, -progress, np.maximum(unc, floor)))
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
        if close.size:
            same = np.all(tree.truth[close] == tree.truth[leaf], axis=1)
            same &= _bucket(tree.run[close]) == _bucket(tree.run[leaf])
            close = close[same]
        if close.size and np.min(tree.unc[close]) <= tree.unc[leaf]:
            return  # dominated: the new node stays as an interior node only
        tree.active[close] = False
        tree.active[leaf] = True


def _roll(modes, mean0, cov0, actions, controls) -> tuple[np.ndarray, np.ndarray]:
    N = actions.shape[0]
    means = np.empty((N + 1, mean0.shape[0]))
    covs = np.empty((N + 1, *cov0.shape))
    means[0], covs[0] = mean0, cov0
    for k in range(N):
        means[k + 1], covs[k + 1] = belief_step(modes[int(actions[k])], means[k], covs[k], controls[k])
    return means, covs


def _bucket(run: np.ndarray | int) -> np.ndarray:
    return np.floor(np.log2(np.asarray(run) + 1.0)).astype(int)
