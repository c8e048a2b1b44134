"""The belief-space sampler's tree: nodes are MLO beliefs ``(step, mean, cov)`` with their labels.

A struct-of-arrays store (one array per field, grown by doubling): the sampler selects, extends
and drains nodes with vectorised operations over the active ones.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import DTypeLike

__all__ = ["BeliefTree"]


class BeliefTree:
    """Struct-of-arrays node store (grows by doubling).

    Parameters
    ----------
    n, m, n_atoms : int
        State and input dimensions, number of propositions.
    cap : int
        Initial capacity (nodes).
    """

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
        self.fails = grow(g(self, "fails", None), (), np.int64)  # extensions that took no step
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
        """Append a node (inactive) reached from ``parent`` by ``action`` / ``control``; its index."""
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
        self.fails[i] = 0
        self.size += 1
        return i

    def path(self, i: int) -> list[int]:
        """Node indices from the root to ``i``."""
        out = []
        while i >= 0:
            out.append(i)
            i = int(self.parent[i])
        return out[::-1]

    def closest(self) -> tuple[np.ndarray, np.ndarray, float] | None:
        """The node with the most plan events met (then the deepest), as actions and controls."""
        size = self.size
        if size <= 1:
            return None
        stage, k = self.stage[:size], self.k[:size]
        best = int(np.lexsort((k, stage))[-1])
        path = self.path(best)
        if len(path) <= 1:
            return None
        # Progress: events met first, steps realised to break ties (a total order over nodes).
        progress = float(stage[best]) + float(k[best]) / (1.0 + float(k.max()))
        return self.action[path[1:]].copy(), self.control[path[1:]].copy(), progress
