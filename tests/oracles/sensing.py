"""Brute-force checks of the sensing proofs: every short mode sequence, enumerated.

Independent of :mod:`idstlpy.synthesis` (its covariance floor, schedules and LPs): covariances
are propagated here with a plain Joseph-form Kalman update, mode sequences are enumerated with
``itertools.product``, and plan feasibility for a fixed mode sequence is decided by an LP written
from scratch (``scipy.optimize.linprog``) over the controls, with the chance constraints as
``h'm + c + Phi^-1(1 - eps) sqrt(h' S h) <= 0`` (the MLO mean is affine in the controls and the
covariance schedule fixed when the noise is constant).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np
from scipy.optimize import linprog
from scipy.stats import norm

__all__ = [
    "all_sequences",
    "feasible_for_modes",
    "floor_gap",
    "kalman_cov",
    "schedule",
]


def kalman_cov(A: np.ndarray, Q: np.ndarray, C: np.ndarray, R: np.ndarray, P: np.ndarray) -> np.ndarray:
    """One prediction and Joseph-form update of the covariance (``C`` of shape (0, n): blind)."""
    Pm = A @ P @ A.T + Q
    if C.shape[0] == 0:
        return Pm
    S = C @ Pm @ C.T + R
    K = Pm @ C.T @ np.linalg.pinv(S)
    IKC = np.eye(P.shape[0]) - K @ C
    out = IKC @ Pm @ IKC.T + K @ R @ K.T
    return 0.5 * (out + out.T)


def schedule(
    modes: Sequence[Any],
    cov0: np.ndarray,
    seq: Sequence[int],
    R_of: Callable[[int, int], np.ndarray] | None = None,
) -> np.ndarray:
    """Covariances along ``seq`` (shape (len(seq) + 1, n, n)).

    ``R_of(k, q)`` gives the observation covariance used at step ``k + 1`` by mode ``q`` (default:
    the mode's constant ``V V'``; pass one to evaluate a state-dependent ``V`` anywhere).
    """
    out = [np.asarray(cov0, dtype=float)]
    for k, q in enumerate(seq):
        mode = modes[q]
        W = np.asarray(mode.W, dtype=float)
        Q = W @ W.T
        C = np.asarray(mode.C, dtype=float)
        if C.shape[0] == 0:
            R = np.zeros((0, 0))
        elif R_of is not None:
            R = R_of(k, q)
        else:
            V = np.asarray(mode.V, dtype=float)
            R = V @ V.T
        out.append(kalman_cov(np.asarray(mode.A, dtype=float), Q, C, R, out[-1]))
    return np.array(out)


def all_sequences(num_modes: int, length: int) -> Iterator[tuple[int, ...]]:
    """Every mode sequence of exactly ``length`` steps."""
    return itertools.product(range(num_modes), repeat=length)


def floor_gap(
    modes: Sequence[Any],
    cov0: np.ndarray,
    floor_covs: np.ndarray,
    length: int,
    R_of: Callable[[int, int], np.ndarray] | None = None,
) -> float:
    """Smallest eigenvalue of ``Sigma_k(seq) - L_k`` over every sequence of ``length`` steps and
    every step ``k <= length`` (``>= 0``, up to rounding, when ``L`` is a floor)."""
    worst = np.inf
    for seq in all_sequences(len(modes), length):
        covs = schedule(modes, cov0, seq, R_of)
        for k in range(1, length + 1):
            gap = covs[k] - floor_covs[k]
            worst = min(worst, float(np.linalg.eigvalsh(0.5 * (gap + gap.T)).min()))
    return worst


def feasible_for_modes(
    modes: Sequence[Any],
    U_H: np.ndarray,
    U_c: np.ndarray,
    mean0: np.ndarray,
    cov0: np.ndarray,
    seq: Sequence[int],
    requirements: Sequence[tuple[int, np.ndarray, np.ndarray, float]],
    tol: float = 1e-7,
) -> bool:
    """Whether controls exist that meet ``requirements`` along the mode sequence ``seq``.

    Parameters
    ----------
    modes : sequence of modes with constant noise
    U_H, U_c : the control domain ``U_H u + U_c <= 0``
    mean0, cov0 : the prior
    seq : the modes reaching steps ``1..K``
    requirements : ``(k, H, c, eps)``: at step ``k`` every row ``h'x + c <= 0`` with probability
        ``>= 1 - eps`` (``H`` shape (F, n), ``c`` shape (F,))
    tol : a requirement is met when violated by at most ``tol`` (the LP's slack)

    Returns
    -------
    bool
    """
    K = len(seq)
    n = mean0.shape[0]
    m = U_H.shape[1]
    covs = schedule(modes, cov0, seq)
    # mean_k = Phi_k mean0 + sum_j G_kj u_j
    Phi = [np.eye(n)]
    G = [np.zeros((n, K * m))]
    for k, q in enumerate(seq):
        A, B = np.asarray(modes[q].A, dtype=float), np.asarray(modes[q].B, dtype=float)
        Phi.append(A @ Phi[-1])
        g = A @ G[-1]
        g[:, k * m : (k + 1) * m] += B
        G.append(g)
    rows, rhs = [], []
    for k, H, c, eps in requirements:
        z = norm.ppf(1.0 - eps)
        for h, ci in zip(np.atleast_2d(H), np.atleast_1d(c), strict=True):
            sd = float(np.sqrt(max(h @ covs[k] @ h, 0.0)))
            # h'(Phi mean0 + G u) + c + z sd <= tol
            rows.append(h @ G[k])
            rhs.append(tol - ci - z * sd - h @ Phi[k] @ mean0)
    for k in range(K):
        for h, ci in zip(U_H, U_c, strict=True):
            row = np.zeros(K * m)
            row[k * m : (k + 1) * m] = h
            rows.append(row)
            rhs.append(-ci)
    if not rows:
        return True
    res = linprog(
        np.zeros(K * m),
        A_ub=np.array(rows),
        b_ub=np.array(rhs),
        bounds=[(None, None)] * (K * m),
        method="highs",
    )
    return bool(res.status == 0)
