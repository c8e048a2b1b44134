"""Brute-force references for joint chance constraints ``P[x in {H x + c <= 0}] >= 1 - eps``.

Independent of :mod:`idstlpy.chance`: the region's probability is estimated by sampling the
Gaussian (many samples, with a Wilson interval), Boole's bound is summed face by face with
``scipy.stats.norm``, and the true state of an open-loop execution is rolled out by hand.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.stats import norm


def inside(H: np.ndarray, c: np.ndarray, points: np.ndarray, tol: float = 0.0) -> np.ndarray:
    """Which rows of ``points`` (shape (N, n)) satisfy every face ``h' x + c <= tol``."""
    return np.all(points @ np.asarray(H, dtype=float).T + np.asarray(c, dtype=float) <= tol, axis=1)


def sampled_probability(
    H: np.ndarray, c: np.ndarray, mean: np.ndarray, cov: np.ndarray, samples: int, rng: np.random.Generator
) -> tuple[float, float, float]:
    """``P[x in region]`` for ``x ~ N(mean, cov)`` by sampling: ``(estimate, low, high)``.

    ``low`` / ``high`` is the 99.99% Wilson interval (z = 3.9) of the estimate. A point on a
    face counts as inside up to rounding (``1e-9`` relative to the region's offsets): a belief
    without variance exactly on its face is inside.
    """
    pts = rng.multivariate_normal(
        np.asarray(mean, dtype=float), np.asarray(cov, dtype=float), size=samples, method="eigh"
    )
    tol = 1e-9 * (1.0 + float(np.max(np.abs(c))) + float(np.max(np.abs(mean))))
    hits = int(np.count_nonzero(inside(H, c, pts, tol)))
    return (hits / samples, *wilson(hits, samples, 3.9))


def wilson(hits: int, n: int, z: float) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion ``hits / n``."""
    p = hits / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return max(0.0, mid - half), min(1.0, mid + half)


def boole_risk(H: np.ndarray, c: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> float:
    """``sum_f P[h_f' x + c_f > 0]``, face by face (the literal Boole bound)."""
    total = 0.0
    for h, cf in zip(np.asarray(H, dtype=float), np.asarray(c, dtype=float), strict=True):
        mu = float(h @ mean) + float(cf)
        sd = math.sqrt(max(float(h @ cov @ h), 0.0))
        total += float(norm.sf(-mu / sd)) if sd > 0 else (0.0 if mu <= 0 else 1.0)
    return total


def per_face_holds(H: np.ndarray, c: np.ndarray, eps: Any, mean: np.ndarray, cov: np.ndarray) -> bool:
    """Every face meets its own chance constraint at ``eps[f]`` (the planner's reading)."""
    for h, cf, e in zip(
        np.asarray(H, dtype=float), np.asarray(c, dtype=float), np.broadcast_to(eps, len(c)), strict=True
    ):
        mu = float(h @ mean) + float(cf)
        var = max(float(h @ cov @ h), 0.0)
        if e == 0:
            if var > 0 or mu > 0:
                return False
        elif mu + float(norm.ppf(1 - e)) * math.sqrt(var) > 0:
            return False
    return True


def open_loop_states(
    A: np.ndarray,
    B: np.ndarray,
    W: np.ndarray,
    mean0: np.ndarray,
    cov0: np.ndarray,
    controls: np.ndarray,
    runs: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """True states ``x_{k+1} = A x_k + B u_k + w_k`` from ``x_0 ~ N(mean0, cov0)``: shape (runs, K+1, n)."""
    K = controls.shape[0]
    n = mean0.shape[0]
    out = np.empty((runs, K + 1, n))
    out[:, 0] = rng.multivariate_normal(mean0, cov0, size=runs, method="eigh")
    for k in range(K):
        w = rng.multivariate_normal(np.zeros(n), W, size=runs, method="eigh")
        out[:, k + 1] = out[:, k] @ A.T + controls[k] @ B.T + w
    return out


def box_probability(lo: np.ndarray, hi: np.ndarray, mean: np.ndarray, var: np.ndarray) -> float:
    """Exact ``P[lo <= x <= hi]`` for ``x ~ N(mean, diag(var))``: a product of 1-D probabilities."""
    total = 1.0
    for a, b, m, v in zip(lo, hi, mean, var, strict=True):
        sd = math.sqrt(v)
        total *= float(norm.cdf((b - m) / sd) - norm.cdf((a - m) / sd)) if sd > 0 else float(a <= m <= b)
    return total
