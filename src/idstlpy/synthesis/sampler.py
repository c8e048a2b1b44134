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
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .. import _progress as progress
from ..belief import belief_step
from .abstraction import Abstraction
from .belief_tree import BeliefTree
from .interfaces import Proposer
from .options import SolverOptions
from .patrol import Patrol
from .plan import DiscretePlan, evaluate_bool
from .sample_space import SampleSpace
from .steering import STEER_LOOKAHEAD, STEER_SHRINK, Steering, steering_center

if TYPE_CHECKING:
    from ..problem import Problem

# (the steering's constants and centre live in .steering; named here too, where the sampler's
# users have always found them)
__all__ = ["STEER_LOOKAHEAD", "STEER_SHRINK", "BeliefSampler", "SamplerOutcome", "steering_center"]

_FOCUS = 0.75
"""Probability that an iteration extends only the most advanced lineages (see ``_events``)."""

MAX_FAILS = 16
"""Extensions of a node that took not one step (each toward another sample) after which it is
no longer extended. A lineage past what its plan allows in time (the formula's deadline too
close for any reachable region) stays completable for the proposer, which does not know the
dynamics, yet every step from it breaks its plan; at the front of the most advanced lineages
it drew three iterations in four, and a three-robot block spent its 15,000 iterations on such
nodes (296 nodes grown, two candidates, 25 s). Not under ``guarantee="mlo"``, whose plans stay
as recorded (``benchmarks/loop_reference.py``)."""

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


@dataclass
class _Growth:
    """One candidate's search: its tree, the plans its nodes follow, its random stream."""

    tree: BeliefTree
    plans: list[DiscretePlan]
    events: list[tuple[np.ndarray, np.ndarray]]  # per plan, its key events (``_events``)
    patrol: Patrol | None  # a patrol's progress is its alternating visits, not the plan's events
    rng: np.random.Generator
    deadline: float  # ``time.perf_counter()`` seconds: a safety cap only
    horizon: int  # the proposer's longest plan
    capped: bool = False
    alive: set[int] = field(default_factory=set)  # nodes whose prefix was checked completable
    dropped: int = 0  # dead nodes deactivated


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
        self.formula = problem.stl_formula
        self.steering = st = Steering(self.system, problem.control_domain, self.opt.max_num_of_steps)
        # (the steering's domain and gains under the names the sampler's tests read)
        self.u_center, self.UH, self.Uc, self.Uc_gentle = st.u_center, st.UH, st.Uc, st.Uc_gentle
        self._gains, self._index = st.gains, st.index
        n, m, a = self.system.n, self.system.m, abstraction.num_atoms
        self.max_nodes = max(MIN_NODES, TREE_BYTES // (8 * (n + n * n + m + 9) + a + 1))
        self._underactuated = not all(st.full_rank)
        self._any_full_rank = any(st.full_rank)
        self._pareto = any(np.any(mode.process_cov != 0) for mode in self.system.system_modes)
        self.space = SampleSpace(problem, abstraction)
        self.max_fails = MAX_FAILS if options.guarantee != "mlo" else np.iinfo(np.int64).max

    def _steer(
        self, q: int, mean: np.ndarray, target: np.ndarray, remaining: int = 1, gentle: bool = False
    ) -> np.ndarray:
        """Input of mode ``q`` toward ``target``: :meth:`.steering.Steering.steer`."""
        return self.steering.steer(q, mean, target, remaining, gentle)

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
        self, tree: BeliefTree, leaf_truth: np.ndarray, leaf_k: int, leaf_mode: int, parent: int
    ) -> DiscretePlan | None:
        """A plan consistent with the realised prefix (path to ``parent`` plus the new step), or None."""
        path = tree.path(parent)
        truth = np.vstack([tree.truth[path], leaf_truth[None, :]]).T  # (n_atoms, k+1)
        modes = np.concatenate([tree.action[path[1:]], [leaf_mode]]).astype(int)
        return self.proposer.complete(truth, modes)

    def _satisfied(self, tree: BeliefTree, leaf: int) -> bool:
        path = tree.path(leaf)
        truth = tree.truth[path].T
        return bool(evaluate_bool(self.formula, truth, self.abs.index)[id(self.formula)][0])

    # -- main loop --------------------------------------------------------------------------------
    def run(
        self, plan: DiscretePlan, iterations: int, rng: np.random.Generator, deadline: float
    ) -> SamplerOutcome:
        """Grow a tree guided by ``plan`` for at most ``iterations`` iterations.

        ``rng`` is the candidate's own random stream; ``deadline`` (``time.perf_counter()``
        seconds) is a safety cap only.
        """
        g = self._start(plan, rng, deadline)
        tree = g.tree
        iters = 0
        while iters < iterations:
            if g.capped or (not iters % 32 and time.perf_counter() >= deadline):
                g.capped = True
                break
            if not iters % 256:
                progress.report(sampler_iterations=iters, nodes=tree.size)
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
            leaf = self._iterate(g, act)
            if leaf is None:
                continue
            if self._satisfied(tree, leaf):
                path = tree.path(leaf)
                logger.info("sampler: goal after %d iterations, %d nodes", iters, tree.size)
                return SamplerOutcome(
                    tree.action[path[1:]].copy(), tree.control[path[1:]].copy(), tree.size, iters, False
                )
            self._drain(tree, leaf, act)
        logger.info(
            "sampler: %s after %d iterations, %d nodes (%d dead nodes dropped)",
            "wall-clock cap" if g.capped else "budget spent",
            iters,
            tree.size,
            g.dropped,
        )
        if logger.isEnabledFor(logging.DEBUG):
            self._log_tree(g)
        return SamplerOutcome(None, None, tree.size, iters, g.capped, tree.closest())

    def _start(self, plan: DiscretePlan, rng: np.random.Generator, deadline: float) -> _Growth:
        """A search for ``plan``: a tree of the initial belief alone."""
        init = self.problem.initial_state
        tree = BeliefTree(self.system.n, self.system.m, self.abs.num_atoms)
        root = tree.add(init.mean, init.cov, 0, -1, -1, None, self.abs.truth(init.mean, init.cov, -1), 0)
        tree.active[root] = True
        events = [self._events(plan)]
        # A patrol (some region required again and again): progress is the number of
        # alternating visits a lineage has made, not the plan's events (re-timing defers them).
        ev_atoms0 = events[0][1].tolist()
        cycle = list(dict.fromkeys(ev_atoms0))
        recurring = len(cycle) >= 2 and len(ev_atoms0) > len(cycle)
        patrol = Patrol(cycle, 2 * self.opt.max_num_of_steps) if recurring else None
        return _Growth(tree, [plan], events, patrol, rng, deadline, self.proposer.cap)

    def _iterate(self, g: _Growth, act: np.ndarray) -> int | None:
        """One extension from a node among ``act``: the new leaf, or None when not one step was possible."""
        tree, rng = g.tree, g.rng
        goal, ref, aim_goal, s = self._aim(g, act)
        pool = act
        if goal is not None and not aim_goal:
            # Nodes already at the goal are only extended toward the goal: an exploration
            # sample must not drag a lineage out of the region it is holding.
            off = act[~tree.truth[act, goal]]
            pool = off if off.size else act
        node = ref if g.patrol is not None and aim_goal else self._select(tree, pool, s, goal, rng)
        center = self.space.centers[goal] if goal is not None else None
        # Holding with under-actuated dynamics (or under process noise): settle at the centre
        # (every position off it is margin the growing covariance will need later).
        settle = bool(
            (self._underactuated or self._pareto)
            and aim_goal
            and center is not None
            and tree.truth[node, goal]
        )
        if settle:
            s = np.asarray(center)
        steps = int(rng.integers(self.opt.min_num_of_steps, self.opt.max_num_of_steps + 1))
        if settle:
            # A hold is not limited to one extension's length: a holder settling at the
            # centre goes on for the rest of its plan (it stops where the plan breaks).
            steps = max(steps, g.plans[int(tree.plan[node])].length - int(tree.k[node]))
        prefer = self._extension_mode(tree, node, goal, rng)
        # (a patrol's round trips need full speed: its deadlines leave no time for gentleness)
        gentle = self._any_full_rank and g.patrol is None and bool(rng.random() < 0.5)
        cur = self._extend(g, node, s, steps, prefer, gentle)
        if cur != node:
            return cur
        # Not one step was possible: if the node's own prefix can no longer be completed
        # (a deadline of the formula has passed), it is dead: never select it again.
        tree.fails[node] += 1
        if (
            settle
            or tree.fails[node] >= self.max_fails
            or (node not in g.alive and not self._alive(tree, node))
        ):
            # (a holder that cannot take one more step toward the centre never will:
            # that steering is deterministic)
            tree.active[node] = False
            g.dropped += 1
        else:
            g.alive.add(node)
        return None

    def _aim(self, g: _Growth, act: np.ndarray) -> tuple[int | None, int, bool, np.ndarray]:
        """The goal region, the reference node, whether the sample aims at the goal, the sample.

        The reference is the least uncertain active node (a patrol: a random one among those
        certain enough); with probability ``goal_bias`` the sample lies in the region it should
        make for next, otherwise it explores (:meth:`_explore`).
        """
        tree, rng = g.tree, g.rng
        goal: int | None
        if g.patrol is not None:
            unc = tree.unc[act]
            sure = act[unc <= max(float(unc.min()), self.space.floor(g.patrol.cycle[0]))]
            ref = int(sure[int(rng.integers(sure.size))])
            goal = g.patrol.goal(tree, ref)
        else:
            ref = int(act[int(np.argmin(tree.unc[act]))])
            goal = self._next_goal(tree, ref, g.events[int(tree.plan[ref])])
        aim_goal = goal is not None and rng.random() < self.opt.goal_bias
        s = self.space.sample_in_atom(goal, rng) if aim_goal and goal is not None else None
        if s is None:
            return goal, ref, False, self._explore(rng)
        return goal, ref, aim_goal, s

    def _explore(self, rng: np.random.Generator) -> np.ndarray:
        """An exploration sample: near a sensing point (at half the goal bias), else anywhere."""
        space = self.space
        if space.sensing.shape[0] and rng.random() < 0.5 * self.opt.goal_bias:
            width = space.workspace[1] - space.workspace[0]
            near: np.ndarray = space.sensing[int(rng.integers(space.sensing.shape[0]))] + 0.05 * width * (
                rng.random(self.system.n) - 0.5
            )
            return near
        return rng.uniform(*space.workspace)

    def _extend(self, g: _Growth, node: int, s: np.ndarray, steps: int, prefer: int, gentle: bool) -> int:
        """Extend ``node`` up to ``steps`` steps toward ``s``, checking the plan at every step.

        A step that breaks its node's plan is re-timed (:meth:`_replan`); the extension stops
        where it cannot be. Returns the last node added (``node`` when none was).
        """
        tree, rng = g.tree, g.rng
        modes = self.system.system_modes
        cur = node
        for j in range(steps):
            k = int(tree.k[cur]) + 1
            if k > g.horizon or tree.size >= self.max_nodes:
                break
            if j and not j % 64 and time.perf_counter() >= g.deadline:
                g.capped = True
                break
            pl = g.plans[int(tree.plan[cur])]
            allowed = self._allowed_modes(pl, k)
            if not allowed:
                break
            if prefer in allowed:
                q = prefer
            else:
                q = allowed[0] if len(allowed) == 1 else int(rng.choice(allowed))
            u = self._steer(q, tree.mean[cur], s, steps - j, gentle)
            mean, cov = belief_step(modes[q], tree.mean[cur], tree.cov[cur], u)
            truth = self.abs.truth(mean, cov, q)
            pid = int(tree.plan[cur])
            if k < pl.length and not np.all(truth[pl.required[:, k]]):
                new = self._replan(tree, truth, k, q, cur)
                if new is None:
                    break
                g.plans.append(new)
                g.events.append(self._events(new))
                pid = len(g.plans) - 1
            if g.patrol is not None:
                stage = g.patrol.visit(tree, cur, truth, k)
            else:
                stage = int(np.searchsorted(g.events[pid][0], k, side="right"))
            cur = tree.add(mean, cov, k, cur, q, u, truth, pid, stage)
            if g.patrol is not None:
                g.patrol.record_visit(tree, cur, truth, k)
        return cur

    def _log_tree(self, g: _Growth) -> None:
        """Debug summary of a tree that found no plan: where its nodes are, how long they held."""
        tree, names = g.tree, self.abs.names()
        held = tree.truth[: tree.size]
        logger.debug(
            "sampler tree: nodes per proposition %s; longest run per proposition %s; "
            "deepest step %d; plans %d",
            {names[i]: int(held[:, i].sum()) for i in range(self.abs.num_atoms)},
            {
                names[i]: int(np.max(tree.run[: tree.size][held[:, i]], initial=0))
                for i in range(self.abs.num_atoms)
            },
            int(tree.k[: tree.size].max()),
            len(g.plans),
        )

    def _next_goal(self, tree: BeliefTree, node: int, events: tuple[np.ndarray, np.ndarray]) -> int | None:
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

    def _alive(self, tree: BeliefTree, node: int) -> bool:
        """Whether the realised prefix up to ``node`` can still be completed (one SAT call).

        The root is always alive (the candidate itself completes it).
        """
        if tree.parent[node] < 0:
            return True
        path = tree.path(node)
        truth = tree.truth[path].T
        modes = tree.action[path[1:]].astype(int)
        return self.proposer.complete(truth, modes) is not None

    def _extension_mode(self, tree: BeliefTree, node: int, goal: int | None, rng: np.random.Generator) -> int:
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
            bool(tree.truth[node, goal]) or tree.unc[node] > self.space.floor(goal)
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

    def _select(
        self, tree: BeliefTree, pool: np.ndarray, s: np.ndarray, goal: int | None, rng: np.random.Generator
    ) -> int:
        """Least uncertain node within ``delta_near`` of ``s`` (else the nearest).

        Uncertainty below what the goal region needs counts as equal; ties go to the node that
        has held its current label longest (progress), then to the less uncertain.
        """
        d = np.linalg.norm(tree.mean[pool] - s, axis=1)
        within = d <= self.opt.delta_near
        if not np.any(within):
            return int(pool[np.argmin(d)])
        near = pool[within]
        floor = self.space.floor(goal)
        unc = tree.unc[near]
        progress = np.where(tree.truth[near, goal], tree.run[near], 0) if goal is not None else 0 * unc
        key = np.maximum(unc, floor)
        if self._pareto and goal is not None and rng.random() < 0.5:
            # Under process noise a hold loses certainty as it goes on: a holding node that still
            # has three quarters of the region's room counts as certain enough (progress decides).
            # A fully actuated holder reaches the centre in a step or two, where its covariance
            # settles (re-sensing): every holder counts.
            roomy = unc <= 9.0 * floor if self._underactuated else np.ones(near.shape[0], dtype=bool)
            key = np.where(tree.truth[near, goal] & roomy, floor, key)
        order = np.lexsort((unc, -progress, key))
        return int(near[order[0]])

    def _drain(self, tree: BeliefTree, leaf: int, act: np.ndarray) -> None:
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


def _bucket(run: np.ndarray | int) -> np.ndarray:
    return np.floor(np.log2(np.asarray(run) + 1.0)).astype(int)
