"""The belief-space sampler's steering law: inputs that move a mean toward a sample.

A fully actuated mode pushes as hard as it can (the one-step least-norm input, pulled into the
control domain); an under-actuated one plans the fastest admissible least-norm input sequence
over a lookahead, so that it can still brake. Half the sampler's extensions (and its shortcut)
steer *gently*, within the control domain shrunk about its centre (:data:`STEER_SHRINK`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..sets import Polytope

if TYPE_CHECKING:
    from ..dynamical_system import LCS, SwitchedSystem

__all__ = ["STEER_LOOKAHEAD", "STEER_SHRINK", "Steering", "steering_center"]

STEER_SHRINK = 0.8
"""Gentle steering keeps a fully actuated mode's inputs within this fraction of the control
domain (scaled about its Chebyshev centre), leaving the executor's tracking correction and the
polish (:mod:`.room`) the rest. Half the extensions (and the shortcut) steer gently; the others
use the whole domain, which tight deadlines need; a patrol (a region required again and again,
whose round trips must be made at full speed) never steers gently."""

STEER_LOOKAHEAD = 256
"""The longest input sequence the steering plans (``max_num_of_steps`` when smaller): the
steering gains take O(h^2) time and memory in the lookahead ``h``."""


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


class Steering:
    """The steering law of one switched system on one control domain.

    Parameters
    ----------
    system : SwitchedSystem
    domain : Polytope
        The control domain ``{u : H u + c <= 0}``.
    max_steps : int
        The longest extension (``max_num_of_steps``): the lookahead is at most
        :data:`STEER_LOOKAHEAD`.
    """

    def __init__(self, system: SwitchedSystem, domain: Polytope, max_steps: int) -> None:
        self.system = system
        self.u_center = steering_center(domain)
        # Steering uses the control domain shrunk about its centre: inputs on their bounds leave
        # the executor's tracking correction no room and the polish no slack to move the plan.
        # {c0 + s (v - c0) : H v + c <= 0} = {u : H u + s c - (1 - s) H c0 <= 0}.
        self.UH, self.Uc = domain.H, domain.c
        self.Uc_gentle = STEER_SHRINK * domain.c - (1.0 - STEER_SHRINK) * (domain.H @ self.u_center)
        # The steering looks at most STEER_LOOKAHEAD ahead: the gains cost O(h^2) time and memory
        # (max_num_of_steps = 10**9 must not allocate them).
        lookahead = max(1, min(max_steps, STEER_LOOKAHEAD))
        self.gains = [self._steering_gains(mode, lookahead) for mode in system.system_modes]
        self.index = [self._controllability_index(mode, lookahead) for mode in system.system_modes]
        self.full_rank = [np.linalg.matrix_rank(mode.B) >= system.n for mode in system.system_modes]

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

    def steer(
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
        gains = self.gains[q]
        Uc = self.Uc_gentle if gentle and self.full_rank[q] else self.Uc
        m = self.system.m
        lo = min(self.index[q], len(gains))
        hi = min(max(remaining, lo), len(gains)) if not self.full_rank[q] else lo
        u = None
        for h in range(lo, hi + 1):
            Ah, G = gains[h - 1]
            seq = (G @ (target - Ah @ mean)).reshape(h, m)
            if np.all(seq @ self.UH.T + Uc <= 1e-12):
                return np.asarray(seq[0])
            if h == hi:
                u = seq[0]
                if not self.full_rank[q]:
                    # receding horizon of the longest extension: it can always still stop
                    Ah, G = gains[-1]
                    part = self.partial(mean, target, Ah, G, len(gains))
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

    def partial(
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
