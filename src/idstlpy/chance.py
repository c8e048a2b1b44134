"""The chance constraint's deterministic equivalent: the one home of this formula.

A Gaussian belief ``N(m, S)`` satisfies ``P[h'x + c <= 0] >= 1 - eps`` iff

    h' m + c + Phi^-1(1 - eps) * sqrt(h' S h) <= 0.

``eps = 0`` gives ``Phi^-1(1) = inf``: the constraint then holds only with zero variance along
``h`` (the term is taken as 0 there), and no mean can meet it with positive variance (the term is
``+inf``). Every part of the package (sets, monitor, abstraction, teachers, MILP, validation)
calls these functions, vectorised over faces and, where given, over a time axis.

A *joint* chance constraint ``P[H x + c <= 0] >= 1 - eps`` (a whole polytope, one confidence)
is judged by Boole's inequality: it holds when the per-face violation probabilities sum to at
most ``eps`` (:func:`joint_risk`), which is sound for the region's probability and equivalent to
the existence of per-face risks ``eps_f``, ``sum eps_f <= eps``, each face meeting its own
deterministic equivalent. :func:`joint_slack` is its margin in the units of :func:`slack`: the
largest ``r`` such that every face moved inwards by ``r`` still passes (a 1-D root, found by
bisection and reported on its feasible side). :func:`allocate_shares` chooses the per-face risks
the planner plans with.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.special import ndtr, ndtri

__all__ = [
    "quantile",
    "std_terms",
    "slack",
    "joint_risk",
    "joint_tail_sum",
    "joint_slack",
    "allocate_shares",
]


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


def _face_moments(
    H: np.ndarray, c: np.ndarray, mean: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Distance ``d_f = -(h_f' m + c_f)`` and standard deviation ``sqrt(h_f' S h_f)`` per face."""
    d = -(mean @ H.T + c)
    if cov.ndim == 2:
        var = np.einsum("fi,ij,fj->f", H, cov, H)
    else:
        var = np.einsum("fi,tij,fj->tf", H, cov, H)
    return d, np.sqrt(np.maximum(var, 0.0))


def _tail(d: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """``P[N(0, sd^2) > d]`` per face: ``Phi(-d / sd)``; 0 or 1 for a face without variance."""
    with np.errstate(divide="ignore", invalid="ignore"):
        out = ndtr(-d / sd)
    return np.where(sd > 0, out, np.where(d >= 0, 0.0, 1.0))


def joint_tail_sum(d: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """``sum_f P[N(0, sd_f^2) > d_f]`` over the last axis: Boole's bound from face distances.

    Parameters
    ----------
    d : ndarray, shape (..., F)
        ``-(h_f' m + c_f)`` per face (positive inside).
    sd : ndarray, shape (..., F)
        ``sqrt(h_f' S h_f)`` per face (a face without variance counts 0 inside, 1 outside).

    Returns
    -------
    ndarray, shape (...)
    """
    return np.asarray(
        np.sum(_tail(np.asarray(d, dtype=float), np.asarray(sd, dtype=float)), axis=-1), dtype=float
    )


def joint_risk(H: np.ndarray, c: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Boole's bound on ``P[x not in {H x + c <= 0}]`` for ``x ~ N(mean, cov)``.

    Parameters
    ----------
    H, c : ndarray, shapes (F, n), (F,)
        The region's faces ``h_f' x + c_f <= 0``.
    mean : ndarray, shape (n,) or (T, n)
    cov : ndarray, shape (n, n) or (T, n, n)

    Returns
    -------
    ndarray, shape () or (T,)
        ``sum_f P[h_f' x + c_f > 0]`` (may exceed 1).
    """
    d, sd = _face_moments(H, c, mean, cov)
    return np.asarray(np.sum(_tail(d, sd), axis=-1), dtype=float)


def joint_slack(
    H: np.ndarray, c: np.ndarray, eps: float, mean: np.ndarray, cov: np.ndarray, iterations: int = 100
) -> np.ndarray:
    """Margin of a joint chance constraint under Boole's inequality (``>= 0``: it holds).

    The largest ``r`` with ``sum_f P[h_f' x + c_f + r > 0] <= eps``: every face can move ``r``
    inwards and some allocation ``eps_f`` (``sum eps_f <= eps``) still meets every face's
    deterministic equivalent. With one face it is :func:`slack` itself. The root lies between
    the equal-share slack (``eps / F`` per face, feasible) and the single-face slack at ``eps``
    (an upper bound); bisection keeps the feasible end, so a returned ``r >= 0`` is a proof.

    Parameters
    ----------
    H, c : ndarray, shapes (F, n), (F,)
    eps : float
        The allowed probability of leaving the region, in ``[0, 0.5]``.
    mean : ndarray, shape (n,) or (T, n)
    cov : ndarray, shape (n, n) or (T, n, n)
    iterations : int, default 100
        Bisection steps.

    Returns
    -------
    ndarray, shape () or (T,)
    """
    H = np.asarray(H, dtype=float)
    c = np.asarray(c, dtype=float)
    F = H.shape[0]
    if eps <= 0.0 or F == 1:
        z = quantile(np.full(F, eps))
        return np.asarray(np.min(slack(H, c, z, mean, cov), axis=-1), dtype=float)
    d, sd = _face_moments(H, c, mean, cov)
    shape = d.shape[:-1]
    d = d.reshape(-1, F)
    sd = np.broadcast_to(sd, d.shape) if sd.ndim == 1 else sd.reshape(-1, F)
    lo = np.min(d - float(quantile(eps / F)) * sd, axis=-1)
    hi = np.min(d - float(quantile(eps)) * sd, axis=-1)
    lo = np.minimum(lo, hi)
    out = np.where(np.isfinite(lo) & np.isfinite(hi), lo, -np.inf)
    todo = np.flatnonzero(np.isfinite(lo) & np.isfinite(hi))
    if todo.size:
        out[todo] = _root(d[todo], sd[todo], eps, lo[todo], hi[todo], iterations)
    return np.asarray(out.reshape(shape), dtype=float)


def _root(
    d: np.ndarray, sd: np.ndarray, eps: float, a: np.ndarray, b: np.ndarray, iterations: int
) -> np.ndarray:
    """The largest ``r`` in ``[a, b]`` with ``sum_f tail(d_f - r, sd_f) <= eps``, feasible side.

    ``a`` is feasible. Illinois false position on the bracket, a bisection every fourth step;
    returns the bracket's feasible end once the bracket is narrower than ``1e-12`` of the
    problem's scale or the end's risk is within ``1e-10 eps`` of ``eps``.
    """

    def g(r: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return np.sum(_tail(d[rows] - r[:, None], sd[rows]), axis=-1) - eps

    rows = np.arange(d.shape[0])
    ga = g(a, rows)
    gb = g(b, rows)
    a = np.where(gb <= 0, b, a)  # the upper end itself is feasible (other faces risk-free)
    scale = np.maximum(np.maximum(np.abs(a), np.abs(b)), np.max(sd, axis=-1))
    side = np.zeros(d.shape[0], dtype=int)  # which end moved last: -1 a, +1 b
    live = np.flatnonzero((gb > 0) & (b - a > 1e-12 * scale) & (ga < -1e-10 * eps))
    for it in range(iterations):
        if not live.size:
            break
        A, B, GA, GB = a[live], b[live], ga[live], gb[live]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = B - GB * (B - A) / (GB - GA)
        bad = ~np.isfinite(x) | (x <= A) | (x >= B) | (it % 4 == 3)
        x = np.where(bad, 0.5 * (A + B), x)
        gx = g(x, live)
        left = gx <= 0
        a[live] = np.where(left, x, A)
        ga[live] = np.where(left, gx, GA)
        b[live] = np.where(left, B, x)
        gb[live] = np.where(left, GB, gx)
        # Illinois: an end kept twice in a row has its value halved (the position moves to it)
        move = np.where(left, -1, 1)
        stuck_b = left & (side[live] == -1)
        stuck_a = ~left & (side[live] == 1)
        gb[live] = np.where(stuck_b, 0.5 * gb[live], gb[live])
        ga[live] = np.where(stuck_a, 0.5 * ga[live], ga[live])
        side[live] = move
        # done when the bracket is narrow or the feasible end's risk is eps to 1e-10 of it
        live = live[(b[live] - a[live] > 1e-12 * scale[live]) & (ga[live] < -1e-10 * eps)]
    return a


def _chebyshev_center(H: np.ndarray, c: np.ndarray) -> np.ndarray | None:
    """Centre of the largest ball in ``{H x + c <= 0}``; ``None`` if empty, flat or unbounded."""
    from scipy.optimize import linprog

    n = H.shape[1]
    norms = np.linalg.norm(H, axis=1)
    scale = 1.0 + float(np.max(np.abs(c)))
    cap = 1e6 * scale
    res = linprog(
        np.r_[np.zeros(n), -1.0],
        A_ub=np.hstack([H, norms[:, None]]),
        b_ub=-c,
        bounds=[(None, None)] * n + [(None, cap)],
        method="highs",
    )
    if res.status != 0 or res.x is None:
        return None
    radius = float(res.x[n])
    if not np.isfinite(radius) or radius <= 1e-9 * scale or radius >= cap * (1 - 1e-9):
        return None
    return np.asarray(res.x[:n], dtype=float)


def _analytic_center(H: np.ndarray, c: np.ndarray, start: np.ndarray) -> np.ndarray:
    """The point maximising ``sum_f log(-(h_f' x + c_f))`` (damped Newton from an interior point).

    Unlike the Chebyshev centre it is unique (the middle of a long box, not one of its ends).
    """
    x = np.asarray(start, dtype=float).copy()

    def value(y: np.ndarray) -> float:
        d = -(H @ y + c)
        return float(np.sum(np.log(d))) if np.all(d > 0) else -np.inf

    for _ in range(100):
        d = -(H @ x + c)
        w = H / d[:, None]
        grad = np.sum(w, axis=0)  # gradient of -sum log d
        hess = w.T @ w
        try:
            step = -np.linalg.solve(hess + 1e-12 * np.eye(hess.shape[0]), grad)
        except np.linalg.LinAlgError:
            break
        decrement = float(-grad @ step)
        if decrement < 1e-14:
            break
        t, base = 1.0, value(x)
        while t > 1e-12 and value(x + t * step) < base + 0.25 * t * decrement:
            t *= 0.5
        if t <= 1e-12:
            break
        x = x + t * step
    return x


def allocate_shares(
    H: np.ndarray, c: np.ndarray, eps: float, cov: np.ndarray, mix: float = 0.5
) -> np.ndarray:
    """Per-face risks for planning a joint chance constraint (they sum to ``eps``).

    The allocation that lets the widest belief of the prior's shape meet the region: the
    region's analytic centre ``x0`` and the scale ``a`` at which ``N(x0, a^2 cov)`` meets the
    joint constraint with margin 0 give the risks ``P[h_f' x + c_f > 0]`` there (the faces that
    bind get the risk; far faces almost none). They are mixed with equal shares
    (``mix * eps / F`` each) because a plan need not sit at the centre. Equal shares when the
    region is unbounded or has no interior, or ``eps = 0``.

    Parameters
    ----------
    H, c : ndarray, shapes (F, n), (F,)
    eps : float
    cov : ndarray, shape (n, n)
        The shape of the beliefs (the prior's covariance; the identity where it is zero).
    mix : float, default 0.5
        Weight of the equal shares, in ``[0, 1]``.

    Returns
    -------
    ndarray, shape (F,)
        Non-negative, summing to at most ``eps``.
    """
    H = np.asarray(H, dtype=float)
    c = np.asarray(c, dtype=float)
    F, n = H.shape
    equal = np.full(F, eps / F)
    if eps <= 0.0 or F == 1:
        return equal
    center = _chebyshev_center(H, c)
    if center is None:
        return equal
    center = _analytic_center(H, c, center)
    S = np.asarray(cov, dtype=float)
    sd0 = np.sqrt(np.maximum(np.einsum("fi,ij,fj->f", H, S, H), 0.0))
    if not np.all(sd0 > 0):
        S = np.eye(n)
        sd0 = np.linalg.norm(H, axis=1)
    d = -(H @ center + c)
    # The margin at N(x0, a^2 S) falls with a: bisection on log a for the root.
    lo, hi = 1e-12, 1.0
    while joint_slack(H, c, eps, center, hi * hi * S) > 0 and hi < 1e12:
        hi *= 4.0
    for _ in range(200):
        mid = np.sqrt(lo * hi)
        if joint_slack(H, c, eps, center, mid * mid * S) >= 0:
            lo = mid
        else:
            hi = mid
        if hi / lo < 1 + 1e-9:
            break
    need = _tail(d, lo * sd0)
    total = float(np.sum(need))
    if not np.isfinite(total) or total <= 0:
        return equal
    need = need * (eps / total)
    out = mix * equal + (1.0 - mix) * need
    return out * min(1.0, eps / float(np.sum(out)))
