"""Where the belief-space sampler aims: the workspace box, the formula's regions, the sensing points.

A sample is drawn inside the region the plan requires next (its inner half, around the Chebyshev
centre), near a point where some mode senses best, or uniformly in the workspace box; a belief
is certain enough for a region once its covariance's trace is below the region's floor.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .abstraction import Abstraction
from .plan_lp import noise_depends_on_state

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = ["SampleSpace"]


class SampleSpace:
    """The sampling geometry of one problem (shared by every candidate's tree).

    Parameters
    ----------
    problem : Problem
    abstraction : Abstraction

    Attributes
    ----------
    workspace : tuple of ndarray
        ``(low, high)``: the box around the initial belief and every region's finite bounds.
    sensing : ndarray, shape (s, n)
        Where some mode senses best (empty without state-dependent noise).
    centers : list of (ndarray or None)
        Per proposition, its region's Chebyshev centre (``None`` for an unconstrained one).
    """

    def __init__(self, problem: Problem, abstraction: Abstraction) -> None:
        self.problem = problem
        self.system = problem.switched_system
        self.abs = abstraction
        # Under-actuated dynamics pin the coordinates a region leaves open (see sample_in_atom).
        self._underactuated = not all(
            np.linalg.matrix_rank(mode.B) >= self.system.n for mode in self.system.system_modes
        )
        self.regions = [abstraction.region(i) for i in range(abstraction.num_atoms)]
        self.boxes = []
        self.centers = []
        for idx, r in enumerate(self.regions):
            if r.H.shape[0] and not r.is_empty():
                low, high = abstraction.bounds(idx)
                center = r.chebyshev_center()[0]
            else:
                low, high, center = (
                    np.full(self.system.n, -np.inf),
                    np.full(self.system.n, np.inf),
                    None,
                )
            self.boxes.append((low, high))
            self.centers.append(center)
        self.workspace = self._workspace_box()
        self._floors: dict[int, float] = {}
        self.sensing = self._sensing_points()

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
        for low, high in self.boxes:
            lows.append(np.where(np.isfinite(low), low, mean0))
            highs.append(np.where(np.isfinite(high), high, mean0))
        low, high = np.min(lows, axis=0), np.max(highs, axis=0)
        pad = np.where(high - low < 1e-6, 1.0, 0.0)
        return low - pad, high + pad

    def sample_in_atom(self, i: int, rng: np.random.Generator) -> np.ndarray | None:
        low, high = self.boxes[i]
        wl, wh = self.workspace
        # Open sides (half-planes) borrow the workspace box, never crossing the finite side.
        low = np.where(np.isfinite(low), low, np.minimum(wl, np.where(np.isfinite(high), high, wl)))
        high = np.where(np.isfinite(high), high, np.maximum(wh, low))
        region = self.regions[i]
        center = self.centers[i]
        # Under-actuated dynamics: coordinates the region leaves open (a velocity) take the
        # centre's value, so a branch arrives at rest rather than passing through.
        pin = self._underactuated and center is not None
        both_open = ~np.isfinite(self.boxes[i][0]) & ~np.isfinite(self.boxes[i][1])
        for _ in range(20):
            s = rng.uniform(low, high)
            if center is not None:
                s = center + 0.5 * (s - center)
                if pin:
                    s = np.where(both_open, center, s)
            if np.all(region.H @ s + region.c <= 0):
                return s
        return center

    def floor(self, goal: int | None) -> float:
        """Trace of covariance below which a belief is certain enough for the goal region."""
        if goal is None or goal in self._floors:
            return self._floors.get(goal, 0.0) if goal is not None else 0.0
        ap = self.abs.atoms[goal]
        floor = 0.0
        if ap.predicates and self.centers[goal] is not None:
            radius = self.regions[goal].chebyshev_center()[1]
            z = float(np.max(np.where(np.isfinite(ap.cone.z), ap.cone.z, 0.0)))
            if z > 0 and np.isfinite(radius):
                sd = 0.25 * radius / z  # a quarter of the room the region leaves the mean
                floor = self.system.n * sd**2
        self._floors[goal] = floor
        return floor


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
