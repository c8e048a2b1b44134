"""Brute-force reachability of mean regions, independent of :mod:`idstlpy.synthesis.abstraction`.

Whether some point of ``Ri`` reaches ``Rj`` in exactly ``d`` steps of ``x' = A x + B_q u``
(``u`` in ``U``), decided for every mode sequence ``q_0 .. q_{d-1}`` by its own feasibility LP
(``scipy.optimize.linprog``), written out step by step.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.optimize import linprog


def reachable(
    A: np.ndarray,
    Bs: list[np.ndarray],
    U: tuple[np.ndarray, np.ndarray],
    Ri: tuple[np.ndarray, np.ndarray],
    Rj: tuple[np.ndarray, np.ndarray],
    d: int,
) -> bool:
    """True when some mode sequence of length ``d`` takes a point of ``Ri`` into ``Rj``.

    Polytopes are ``(H, c)`` with ``H x + c <= 0``. Variables: ``x_0`` then ``u_0 .. u_{d-1}``;
    ``x_d = A^d x_0 + sum_t A^(d-1-t) B_{q_t} u_t``.
    """
    n, m = A.shape[0], Bs[0].shape[1]
    width = n + d * m
    for seq in itertools.product(range(len(Bs)), repeat=d):
        blocks, rhs = [], []
        start = np.zeros((Ri[0].shape[0], width))
        start[:, :n] = Ri[0]
        blocks.append(start)
        rhs.append(-Ri[1])
        for t in range(d):
            row = np.zeros((U[0].shape[0], width))
            row[:, n + t * m : n + (t + 1) * m] = U[0]
            blocks.append(row)
            rhs.append(-U[1])
        end = np.zeros((Rj[0].shape[0], width))
        end[:, :n] = Rj[0] @ np.linalg.matrix_power(A, d)
        for t, q in enumerate(seq):
            end[:, n + t * m : n + (t + 1) * m] = Rj[0] @ np.linalg.matrix_power(A, d - 1 - t) @ Bs[q]
        blocks.append(end)
        rhs.append(-Rj[1])
        res = linprog(
            np.zeros(width), A_ub=np.vstack(blocks), b_ub=np.concatenate(rhs), bounds=[(None, None)] * width
        )
        if res.status != 2:  # 2: infeasible; anything else is not a proof of unreachability
            return True
    return False
