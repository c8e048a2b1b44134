"""Covariance schedules along a mode sequence, and whether they depend on the means.

For a fixed mode sequence the MLO covariances follow the Riccati recursion. When no mode's
observation noise depends on the state they are fixed by the modes (:func:`lp_exact`: the plan
LP is then exact); otherwise the schedule built with each noise's declared floor is a lower
bound (the update is monotone in ``R`` and in the prior), and :func:`covariance_jacobian` gives
its first-order dependence on the means (the plan LP's sequential convex steps).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..belief import kalman_gain, kalman_update
from .budget import Budget

if TYPE_CHECKING:
    from ..dynamical_system import LCS, SwitchedSystem
    from .covariance_floor import Modes

__all__ = [
    "cached_schedule",
    "covariance_jacobian",
    "covariance_schedule",
    "lp_exact",
    "noise_depends_on_state",
    "row_cache",
]


def noise_depends_on_state(mode: LCS) -> bool:
    """Whether ``mode``'s measurement update depends on the mean: it senses (``p > 0``) through
    a noise that is a function of the state. Only such a mode makes the covariance schedule a
    function of the means (a mode that senses nothing has no noise to depend on)."""
    return bool(mode.p) and bool(mode.has_state_dependent_noise)


def lp_exact(system: SwitchedSystem) -> bool:
    """Whether the plan LP is exact for ``system``: no mode's covariance update depends on the
    means (:func:`noise_depends_on_state`), so the covariance schedule is fixed by the modes and
    the LP decides a plan (``Found`` / ``Refuted``); otherwise it is a sound relaxation, a
    step of sequential convex programming around a trajectory, and the repairs need a trust
    region. The one definition every part of the synthesis reads."""
    return not any(noise_depends_on_state(mode) for mode in system.system_modes)


def covariance_schedule(
    modes: Modes, cov0: np.ndarray, actions: np.ndarray, budget: Budget | None = None
) -> tuple[np.ndarray, bool]:
    """Covariances along a mode sequence: exact, or a lower bound under state-dependent noise.

    Parameters
    ----------
    modes : sequence of LCS
    cov0 : ndarray, shape (n, n)
    actions : ndarray of int, shape (K,)
    budget : Budget, optional
        Wall-clock cap, checked every 64 steps.

    Returns
    -------
    covs : ndarray, shape (K + 1, n, n)
    exact : bool
        False when some step uses a mode with state-dependent noise (its covariance is then the
        lower bound obtained with the noise's floor, ``R = mode.noise_floor``: the update is
        monotone in ``R``).
    """
    K = actions.shape[0]
    n = cov0.shape[0]
    covs = np.empty((K + 1, n, n))
    covs[0] = cov0
    exact = True
    zero_mean = np.zeros(n)
    for k in range(K):
        if budget is not None and not (k + 1) % 64:
            budget.check("the covariance schedule")
        mode = modes[int(actions[k])]
        P = mode.A @ covs[k] @ mode.A.T + mode.process_cov
        if mode.p == 0:
            covs[k + 1] = P
        elif noise_depends_on_state(mode):
            exact = False  # the declared floor of R(x) (zero if none) gives a lower bound
            covs[k + 1] = _lower_update(mode, P)
        else:
            covs[k + 1] = kalman_update(mode, zero_mean, P)[1]
    return covs, exact


def _lower_update(mode: LCS, P: np.ndarray) -> np.ndarray:
    """The measurement update with the noise's floor ``F <= R(x)``: a lower bound on the posterior.

    ``P - P C' (C P C' + F)^+ C P`` with a pseudo-inverse, which stays exact when ``F`` is zero
    and ``C P C'`` singular (a perfect sensor, or a direction the prior already knows). Should
    rounding leave it indefinite or not finite, zero, the trivial lower bound, is used.
    """
    C, F = mode.C, mode.noise_floor
    with np.errstate(all="ignore"):
        PCt = P @ C.T
        S = C @ PCt + F
        if not np.all(np.isfinite(S)):
            return np.zeros_like(P)
        post = P - PCt @ np.linalg.pinv(0.5 * (S + S.T), rcond=1e-12, hermitian=True) @ PCt.T
        post = 0.5 * (post + post.T)
    if not np.all(np.isfinite(post)):
        return np.zeros_like(P)
    w, v = np.linalg.eigh(post)
    return np.asarray((v * np.maximum(w, 0.0)) @ v.T)


def row_cache(abstraction: object) -> dict[str, Any]:
    """What the plan rows keep on ``abstraction`` for one solve's lifetime (schedules, faces).

    Any object the cache lives with serves (the solve's
    :class:`~idstlpy.synthesis.abstraction.Abstraction`, which reads the schedules for its own
    covariance bounds, so this module must not need its type).
    """
    cache: dict[str, Any] = abstraction.__dict__.setdefault("_plan_rows_cache", {})
    return cache


def cached_schedule(
    abstraction: object,
    modes: Modes,
    cov0: np.ndarray,
    actions: np.ndarray,
    budget: Budget | None,
) -> tuple[np.ndarray, bool]:
    """:func:`covariance_schedule`, extended from the last schedule of the same modes and prior.

    The schedule up to step ``k`` depends only on ``actions[:k]``, so the steps shared with the
    previous request are copied, not recomputed (single-mode problems never recompute a step).
    """
    K = int(actions.shape[0])
    key = (tuple(id(mode) for mode in modes), cov0.shape, cov0.tobytes())
    store = row_cache(abstraction).setdefault("schedules", {})
    entry = store.get(key)
    # The entry holds the modes themselves: while it lives, their ids name no other object.
    if entry is None:
        entry = (tuple(modes), np.zeros(0, dtype=int), cov0[None, :, :].copy(), np.zeros(1, dtype=bool))
    _, done, covs_done, inexact_done = entry
    L = min(K, done.shape[0])
    same = np.flatnonzero(done[:L] != actions[:L])
    p = int(same[0]) if same.size else L
    covs = np.empty((K + 1,) + cov0.shape)
    covs[: p + 1] = covs_done[: p + 1]
    inexact = np.empty(K + 1, dtype=bool)  # inexact[k]: some step before k used a lower bound
    inexact[: p + 1] = inexact_done[: p + 1]
    if p < K:
        tail, tail_exact = covariance_schedule(modes, covs[p], actions[p:], budget)
        covs[p + 1 :] = tail[1:]
        if tail_exact:
            inexact[p + 1 :] = inexact[p]
        else:
            lower = [noise_depends_on_state(modes[int(q)]) for q in actions[p:]]
            inexact[p + 1 :] = inexact[p] | (np.cumsum(lower) > 0)
    if K >= done.shape[0] or p < K:
        store[key] = (tuple(modes), np.asarray(actions, dtype=int).copy(), covs.copy(), inexact.copy())
    return covs, not bool(inexact[K])


def covariance_jacobian(
    modes: Modes, actions: np.ndarray, means: np.ndarray, covs: np.ndarray, dx: np.ndarray
) -> list[np.ndarray]:
    """How the MLO covariances depend on the means: ``S[k][j - 1, i] = d covs[k] / d means[j][i]``.

    The covariance depends on the means only through the observation noise ``R(mean_k)`` of
    each update. With the Kalman gain ``K_k`` at the optimum, ``d P_k = K_k dR K_k'`` at step
    ``k``, and a change of the predicted covariance propagates as ``M dP M'`` with
    ``M = (I - K C) A``. ``dR / d mean`` is a central difference with step ``1e-5 dx``. A
    singular innovation covariance ``C P C' + R`` takes the pseudo-inverse's gain
    (:func:`idstlpy.belief.kalman_gain`), the limit of the regular case.

    Parameters
    ----------
    modes : sequence of LCS
    actions : ndarray of int, shape (K,)
    means : ndarray, shape (K + 1, n)
    covs : ndarray, shape (K + 1, n, n)
        The exact roll-out being linearised.
    dx : ndarray, shape (n,)
        State units (for the difference steps).

    Returns
    -------
    list of ndarray
        ``S[k]`` has shape (k, n, n, n).
    """
    K = actions.shape[0]
    n = means.shape[1]
    eye = np.eye(n)
    S: list[np.ndarray] = [np.zeros((0, n, n, n))]
    for k in range(1, K + 1):
        mode = modes[int(actions[k - 1])]
        A = mode.A
        P = A @ covs[k - 1] @ A.T + mode.process_cov
        if mode.p == 0:
            M, gain = A, None
        else:
            C = mode.C
            R = mode.noise_cov(means[k])
            # A singular innovation covariance (a noise-free sensor of a direction the belief
            # already knows) has the pseudo-inverse's gain, the exact limit (belief.gain_from).
            gain = kalman_gain(C, P, R)
            M = (eye - gain @ C) @ A
        prev = np.einsum("ab,jibc,dc->jiad", M, S[k - 1], M) if k > 1 else np.zeros((0, n, n, n))
        new = np.zeros((1, n, n, n))
        if gain is not None and noise_depends_on_state(mode):
            for i in range(n):
                h = 1e-5 * dx[i]
                up, down = means[k].copy(), means[k].copy()
                up[i] += h
                down[i] -= h
                dR = (mode.noise_cov(up) - mode.noise_cov(down)) / (2 * h)
                new[0, i] = gain @ dR @ gain.T
        S.append(np.concatenate([prev, new]))
    return S
