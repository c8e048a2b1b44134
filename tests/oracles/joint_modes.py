"""Brute force over every mode sequence, for the joint MILP's claims on small horizons (issue 31).

Independent of :mod:`idstlpy.synthesis`: the covariances come from the textbook roll-out of
:mod:`.rollout` (constant sensor noise: they depend on the modes alone), and for each mode
sequence and each step a goal may be met at, one feasibility LP (``scipy.optimize.linprog``)
over the inputs decides whether the means can meet the goal's chance constraints there, with
``x_t = A^t x_0 + sum_s A^(t-1-s) B_{q_s} u_s`` written out step by step.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
from scipy.optimize import linprog
from scipy.stats import norm

from .rollout import ModeSpec, mlo_rollout

__all__ = ["goal_reachable"]


def goal_reachable(
    modes: Sequence[ModeSpec],
    mean0: np.ndarray,
    cov0: np.ndarray,
    U: tuple[np.ndarray, np.ndarray],
    goal: Sequence[tuple[np.ndarray, float, float]],
    deadline: int,
) -> list[int] | None:
    """A mode sequence under which some plan meets ``F[0, deadline] goal``, or None when none does.

    Parameters
    ----------
    modes : sequence of ModeSpec
        Constant sensor noise (a matrix ``V``).
    mean0, cov0 : arrays
        The prior.
    U : (H, c)
        The control domain ``H u + c <= 0``.
    goal : sequence of (h, c, eps)
        The goal's chance constraints ``P(h'x + c <= 0) >= 1 - eps`` (``0 < eps < 0.5``).
    deadline : int
        The goal must hold at some step ``0..deadline``.
    """
    m = modes[0].B.shape[1]
    HU, cU = U
    for t in range(deadline + 1):
        for seq in itertools.product(range(len(modes)), repeat=t):
            trace = mlo_rollout(modes, mean0, cov0, list(seq), np.zeros((t, m)))
            _, cov = trace.states[t]
            # rows over u_0..u_{t-1}: h' x_t + c + z sd <= 0 and H u_s + c_U <= 0
            A_ub, b_ub = [], []
            for h, c, eps in goal:
                h = np.asarray(h, dtype=float)
                z = float(norm.ppf(1.0 - eps))
                sd = float(np.sqrt(max(h @ cov @ h, 0.0)))
                free = h @ _power(modes, seq, 0, t) @ mean0
                row = np.zeros(t * m)
                for s in range(t):
                    row[s * m : (s + 1) * m] = h @ _power(modes, seq, s + 1, t) @ modes[seq[s]].B
                A_ub.append(row)
                b_ub.append(-(free + c + z * sd))
            for s in range(t):
                block = np.zeros((HU.shape[0], t * m))
                block[:, s * m : (s + 1) * m] = HU
                A_ub.extend(block)
                b_ub.extend(-cU)
            if t == 0:
                if all(v >= -1e-12 for v in b_ub):
                    return []
                continue
            res = linprog(
                np.zeros(t * m),
                A_ub=np.asarray(A_ub),
                b_ub=np.asarray(b_ub),
                bounds=(None, None),
                method="highs",
            )
            if res.status == 0:
                return list(seq)
    return None


def _power(modes: Sequence[ModeSpec], seq: Sequence[int], start: int, stop: int) -> np.ndarray:
    """``A_{q_{stop-1}} ... A_{q_start}`` (the identity when ``start == stop``)."""
    n = modes[0].A.shape[0]
    out = np.eye(n)
    for s in range(start, stop):
        out = modes[seq[s]].A @ out
    return out
