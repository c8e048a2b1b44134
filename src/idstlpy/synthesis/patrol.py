"""Progress of a patrol in the belief-space sampler's tree.

A patrol is a plan that requires some regions again and again. Re-timing defers its events, so a
lineage's progress is not the number of plan events it has met but the number of alternating
visits it has made, each within ``gap`` steps of the last.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .belief_tree import BeliefTree

__all__ = ["Patrol"]


@dataclass(frozen=True)
class Patrol:
    """The regions a patrol alternates between, in order, and the longest step gap between visits.

    Attributes
    ----------
    cycle : list of int
        Proposition indices, in the order the plan first requires them.
    gap : int
        A lineage that enters no region for more than ``gap`` steps has stalled.
    """

    cycle: list[int]
    gap: int

    def entered(self, tree: BeliefTree, parent: int, truth: np.ndarray) -> int:
        """The patrol region a step from ``parent`` newly enters (not the last one), or -1."""
        last = int(tree.last[parent])
        for a in self.cycle:
            if truth[a] and not tree.truth[parent, a] and a != last:
                return a
        return -1

    def visit(self, tree: BeliefTree, parent: int, truth: np.ndarray, k: int) -> int:
        """Patrol progress of a step from ``parent``: one more alternating visit when it enters
        the next region within ``gap`` steps of the last visit; 0 once a lineage has stalled."""
        a = self.entered(tree, parent, truth)
        since = k - int(tree.lastk[parent])
        if a >= 0:
            return int(tree.stage[parent]) + 1 if since <= self.gap or tree.last[parent] < 0 else 1
        return int(tree.stage[parent]) if since <= self.gap else 0

    def record_visit(self, tree: BeliefTree, node: int, truth: np.ndarray, k: int) -> None:
        """Remember the patrol region ``node`` newly entered (and when)."""
        parent = int(tree.parent[node])
        a = self.entered(tree, parent, truth)
        if a >= 0:
            tree.last[node], tree.lastk[node] = a, k

    def goal(self, tree: BeliefTree, node: int) -> int:
        """A patrol's next region for ``node``: the one after the region it last entered."""
        last = int(tree.last[node])
        if last < 0:
            for a in self.cycle:
                if not tree.truth[node, a]:
                    return a
            return self.cycle[0]
        return self.cycle[(self.cycle.index(last) + 1) % len(self.cycle)]
