"""The chance constraint's deterministic equivalent: the one home of this formula.

A Gaussian belief ``N(m, S)`` satisfies ``P[h'x + c <= 0] >= 1 - eps`` iff

    h' m + c + Phi^-1(1 - eps) * sqrt(h' S h) <= 0.

``eps = 0`` gives ``Phi^-1(1) = inf``: the constraint then holds only with zero variance along
``h`` (the term is taken as 0 there), and no mean can meet it with positive variance (the term is
``+inf``). Every part of the package (sets, monitor, abstraction, teachers, MILP, validation)
calls these functions, vectorised over faces and, where given, over a time axis.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.special import ndtri

__all__ = ["quantile", "std_terms", "slack"]


def quantile(eps: Any) -> np.ndarray:
    """``Phi^-1(1 - eps)``: how many standard deviations a chance constraint reserves.

    Parameters
    ----------
    eps : array_like, shape (F,)
        Tolerances in ``[0, 0.5]``.

    Returns
    -------
    ndarray, shape (F,)
        Non-negative; ``inf`` where ``eps == 0``.
    """
    return np.asarray(ndtri(1.0 - np.asarray(eps, dtype=float)), dtype=float)


def std_terms(H: np.ndarray, z: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``z_f * sqrt(h_f' S h_f)`` per face (and per step when ``cov`` has a time axis).

    Parameters
    ----------
    H : ndarray, shape (F, n)
        Face normals.
    z : ndarray, shape (F,)
        Quantiles from :func:`quantile`.
    cov : ndarray, shape (n, n) or (T, n, n)
        Covariance(s).

    Returns
    -------
    ndarray, shape (F,) or (T, F)
        ``0`` where ``z = inf`` and the variance is zero, ``inf`` where ``z = inf`` and it is not.
    """
    if cov.ndim == 2:
        var = np.einsum("fi,ij,fj->f", H, cov, H)
    else:
        var = np.einsum("fi,tij,fj->tf", H, cov, H)
    sd = np.sqrt(np.maximum(var, 0.0))
    infinite = np.isinf(z)
    with np.errstate(invalid="ignore"):
        terms = np.where(infinite, 0.0, z) * sd
    return np.where(infinite & (sd > 0), np.inf, terms)


def slack(H: np.ndarray, c: np.ndarray, z: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Distance of each deterministic equivalent from its bound (``>= 0``: the constraint holds).

    Parameters
    ----------
    H, c, z : ndarray, shapes (F, n), (F,), (F,)
        Faces ``h_f' x + c_f <= 0`` and their quantiles.
    mean : ndarray, shape (n,) or (T, n)
    cov : ndarray, shape (n, n) or (T, n, n)

    Returns
    -------
    ndarray, shape (F,) or (T, F)
    """
    return -(mean @ H.T + c + std_terms(H, z, cov))
