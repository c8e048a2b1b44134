"""Gaussian beliefs and the maximum-likelihood-observation (MLO) Kalman step.

For mode ``q`` with ``R(x) = n(x) n(x)'`` (``algorithm.md`` section 2)::

    mean' = A mean + B u                      (MLO: the innovation is zero)
    P     = A cov A' + W W'
    R     = R(mean')                          (noise evaluated at the predicted mean)
    K     = P C' (C P C' + R)^-1
    cov'  = (I - K C) P (I - K C)' + K R K'   (Joseph form: symmetric PSD by construction)

This module is the single implementation of the belief dynamics: the planner, the monitor's
re-check and the executor all call it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from ._checks import as_covariance, as_vector
from .errors import DimensionError, InvalidArgumentError, OutOfRangeError

if TYPE_CHECKING:  # both import this module
    from .dynamical_system import SwitchedSystem
    from .trajectory import ProbabilisticTSTrajectory

__all__ = [
    "GaussianBelief",
    "to_belief",
    "predict",
    "kalman_gain",
    "gain_from",
    "kalman_update",
    "belief_step",
    "rollout",
    "rollout_arrays",
]


@dataclass(frozen=True)
class GaussianBelief:
    """A Gaussian belief ``N(mean, cov)``.

    The constructor stores its arguments as given (no validation); use :func:`to_belief` to
    build a checked belief.

    Parameters
    ----------
    mean : ndarray, shape (n,)
        Mean of the belief.
    cov : ndarray, shape (n, n)
        Covariance of the belief (symmetric positive semi-definite).
    """

    mean: np.ndarray
    cov: np.ndarray

    @property
    def n(self) -> int:
        """State dimension."""
        return self.mean.shape[0]

    def sample(self, size: int | None = None, seed: int | np.random.Generator | None = None) -> np.ndarray:
        """Draw states from the belief, shape (size, n) (or (n,) without ``size``).

        Parameters
        ----------
        size : int, optional
            Number of states to draw; ``None`` draws a single state of shape (n,).
        seed : int or numpy.random.Generator, optional
            Seed or generator passed to :func:`numpy.random.default_rng`.

        Returns
        -------
        ndarray, shape (size, n) or (n,)
        """
        rng = np.random.default_rng(seed)
        return rng.multivariate_normal(self.mean, self.cov, size=size, method="eigh")


def to_belief(mean: Any, cov: Any) -> GaussianBelief:
    """Initial belief ``N(mean, cov)``.

    Parameters
    ----------
    mean : array_like, shape (n,)
    cov : array_like, shape (n, n) or (n,)
        Symmetric positive semi-definite; a vector gives the variances of a diagonal covariance
        (as problem files accept).

    Returns
    -------
    GaussianBelief
    """
    mean = as_vector(mean, "mean")
    arr = np.asarray(cov, dtype=float) if _is_numeric(cov) else cov
    if isinstance(arr, np.ndarray) and arr.ndim == 1 and arr.shape[0] == mean.shape[0] > 1:
        variances = as_vector(arr, "cov", mean.shape[0])
        if np.any(variances < 0):
            raise InvalidArgumentError(f"cov given as variances must be >= 0, got {variances.tolist()}")
        cov = np.diag(variances)
    shape = np.shape(cov) if _is_numeric(cov) else None
    if shape is not None and len(shape) == 2 and shape[0] == shape[1] and shape[0] != mean.shape[0]:
        # Say that the two disagree, not which one is "wrong": either may be the mistake.
        raise DimensionError(
            f"mean has {mean.shape[0]} entries but cov is {shape[0]} x {shape[1]}: they must agree "
            "(mean of shape (n,), cov of shape (n, n))"
        )
    cov = as_covariance(cov, "cov", mean.shape[0])
    return GaussianBelief(mean, cov)


def _is_numeric(value: Any) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def predict(mode: Any, mean: np.ndarray, cov: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Prediction step: ``(A mean + B u, A cov A' + W W')``.

    Parameters
    ----------
    mode : LCS
        The mode whose ``A``, ``B`` and process noise covariance ``W W'`` are used.
    mean : ndarray, shape (n,)
        Current mean.
    cov : ndarray, shape (n, n)
        Current covariance.
    u : ndarray, shape (m,)
        Control input applied at this step.

    Returns
    -------
    mean_pred, P : ndarray
        Predicted mean (n,) and covariance (n, n).
    """
    A = mode.A
    return A @ mean + mode.B @ u, A @ cov @ A.T + mode.process_cov


def kalman_gain(C: np.ndarray, P: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The Kalman gain ``P C' (C P C' + R)^-1``, shape (n, p).

    Parameters
    ----------
    C : ndarray, shape (p, n)
        Sensor matrix.
    P : ndarray, shape (n, n)
        Predicted covariance.
    R : ndarray, shape (p, p)
        Observation noise covariance.

    Returns
    -------
    ndarray, shape (n, p)
    """
    PCt = P @ C.T
    return gain_from(PCt, C @ PCt + R)


def gain_from(PCt: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``PCt S^-1``: the Kalman gain from ``P C'`` and the innovation covariance.

    Closed form for one or two outputs when ``S`` is well conditioned, else a linear solve, else
    (a singular ``S``) the pseudo-inverse.

    Parameters
    ----------
    PCt : ndarray, shape (n, p)
        Predicted covariance times the sensor matrix's transpose, ``P C'``.
    S : ndarray, shape (p, p)
        Innovation covariance ``C P C' + R``.

    Returns
    -------
    ndarray, shape (n, p)
    """
    if S.shape[0] <= 2:
        K_small = _small_gain(PCt, S)
        if K_small is not None:
            return K_small
    try:
        with np.errstate(all="ignore"):
            K = np.linalg.solve(S.T, PCt.T).T
        if not np.all(np.isfinite(K)):
            raise np.linalg.LinAlgError("ill-conditioned innovation covariance")
    except np.linalg.LinAlgError:
        # A (near-)singular innovation covariance: a perfect sensor of a direction the prior
        # already knows. The pseudo-inverse gives the exact limit.
        K = PCt @ np.linalg.pinv(0.5 * (S + S.T), rcond=1e-12, hermitian=True)
    return np.asarray(K)


def _small_gain(PCt: np.ndarray, S: np.ndarray) -> np.ndarray | None:
    """``PCt S^-1`` in closed form for one or two outputs, or None when ``S`` is (nearly)
    singular or not finite (the caller then solves it as for larger ``S``)."""
    if S.shape[0] == 1:
        s = float(S[0, 0])
        if not (s > 0.0 and np.isfinite(s)):
            return None
        K = PCt / s
    else:
        a, b, c, d = float(S[0, 0]), float(S[0, 1]), float(S[1, 0]), float(S[1, 1])
        det = a * d - b * c
        # well conditioned (the determinant not lost to cancellation), finite
        if not (abs(det) > 1e-10 * (abs(a * d) + abs(b * c)) and np.isfinite(det) and det != 0.0):
            return None
        inv = np.array([[d, -b], [-c, a]]) / det
        K = PCt @ inv
    if not np.isfinite(K).all():
        return None
    return K


def kalman_update(
    mode: Any,
    mean_pred: np.ndarray,
    P: np.ndarray,
    y: np.ndarray | None = None,
    x_noise: np.ndarray | None = None,
    R: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Measurement update in Joseph form.

    Parameters
    ----------
    mode : LCS
        The mode whose sensor ``C``, ``n(.)`` is used.
    mean_pred, P : ndarray
        Predicted mean (n,) and covariance (n, n).
    y : ndarray, shape (p,), optional
        Observation; ``None`` means the maximum-likelihood observation ``C mean_pred`` (zero
        innovation), which leaves the mean unchanged.
    x_noise : ndarray, shape (n,), optional
        Where to evaluate the noise function (default: the predicted mean, as in planning).
    R : ndarray, shape (p, p), optional
        Observation noise covariance to use instead of the mode's (the planner passes zero to
        get a lower bound on the covariance: the update is monotone in ``R``).

    Returns
    -------
    mean, cov : ndarray
    """
    if mode.p == 0:
        return mean_pred, P
    C = mode.C
    if R is None:
        R = mode.noise_cov(mean_pred if x_noise is None else x_noise)
    K = kalman_gain(C, P, R)
    cov = _joseph(K, C, P, R)
    mean = mean_pred if y is None else mean_pred + K @ (y - C @ mean_pred)
    return mean, cov


_EYES: dict[int, np.ndarray] = {}
"""Read-only identity matrices by size (the Joseph update's ``I``)."""


def _joseph(K: np.ndarray, C: np.ndarray, P: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``(I - K C) P (I - K C)' + K R K'``, symmetrised."""
    n = P.shape[0]
    eye = _EYES.get(n)
    if eye is None:
        eye = _EYES[n] = np.eye(n)
        eye.flags.writeable = False
    IKC = eye - K @ C
    KR = K @ R
    cov = IKC @ P @ IKC.T + KR @ K.T
    cov += cov.T
    cov *= 0.5
    return cov


def kalman_update_batch(
    mode: Any, mean_pred: np.ndarray, P: np.ndarray, Y: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`kalman_update` of ``S`` runs at once, the noise at each run's predicted mean.

    The gain is the closed form of :func:`gain_from` for one or two outputs and a batched solve
    for more; a run whose innovation covariance is (nearly) singular or not finite gets
    :func:`gain_from`'s own answer, so every run's update is :func:`kalman_update`'s up to
    rounding.

    Parameters
    ----------
    mode : LCS
        The mode whose sensor ``C``, ``n(.)`` is used (``mode.noise_cov_batch``).
    mean_pred : ndarray, shape (S, n)
        Predicted means.
    P : ndarray, shape (S, n, n)
        Predicted covariances.
    Y : ndarray, shape (S, p), optional
        Observations; None: the maximum-likelihood observations (means unchanged).

    Returns
    -------
    means : ndarray, shape (S, n)
    covs : ndarray, shape (S, n, n)
    """
    if mode.p == 0:
        return mean_pred, P
    C = mode.C
    R = mode.noise_cov_batch(mean_pred)
    PCt = P @ C.T  # (S, n, p)
    Sinn = C @ PCt + R  # (S, p, p)
    p = C.shape[0]
    with np.errstate(all="ignore"):
        if p == 1:
            s = Sinn[:, 0, 0]
            ok = (s > 0.0) & np.isfinite(s)
            K = PCt / np.where(ok, s, 1.0)[:, None, None]
        elif p == 2:
            a, b, c, d = Sinn[:, 0, 0], Sinn[:, 0, 1], Sinn[:, 1, 0], Sinn[:, 1, 1]
            det = a * d - b * c
            ok = (np.abs(det) > 1e-10 * (np.abs(a * d) + np.abs(b * c))) & np.isfinite(det) & (det != 0.0)
            safe = np.where(ok, det, 1.0)[:, None]
            g0, g1 = PCt[:, :, 0], PCt[:, :, 1]  # K = PCt [[d, -b], [-c, a]] / det
            K = np.stack(
                [(g0 * d[:, None] - g1 * c[:, None]) / safe, (g1 * a[:, None] - g0 * b[:, None]) / safe],
                axis=2,
            )
        else:
            ok = np.isfinite(Sinn).all(axis=(1, 2))
            try:
                K = np.swapaxes(np.linalg.solve(np.swapaxes(Sinn, 1, 2), np.swapaxes(PCt, 1, 2)), 1, 2)
            except np.linalg.LinAlgError:
                K = np.full(PCt.shape, np.nan)
        ok &= np.isfinite(K).all(axis=(1, 2))
    if not ok.all():
        K = np.array(K)
        for i in np.flatnonzero(~ok):
            K[i] = gain_from(PCt[i], Sinn[i])
    IKC = np.eye(P.shape[1]) - K @ C
    KR = K @ R
    cov = IKC @ P @ np.swapaxes(IKC, 1, 2) + KR @ np.swapaxes(K, 1, 2)
    cov += np.swapaxes(cov, 1, 2)
    cov *= 0.5
    if Y is None:
        return mean_pred, cov
    innovation = Y - mean_pred @ C.T
    return mean_pred + (K @ innovation[:, :, None])[:, :, 0], cov


def belief_step(mode: Any, mean: np.ndarray, cov: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One MLO belief transition of ``mode`` under input ``u``; returns ``(mean', cov')``.

    Prediction (:func:`predict`) followed by the maximum-likelihood-observation measurement
    update (:func:`kalman_update` with ``y=None``).

    Parameters
    ----------
    mode : LCS
        The mode applied at this step.
    mean : ndarray, shape (n,)
        Current mean.
    cov : ndarray, shape (n, n)
        Current covariance.
    u : ndarray, shape (m,)
        Control input applied at this step.

    Returns
    -------
    mean, cov : ndarray
        Mean (n,) and covariance (n, n) after the step.
    """
    mean_pred, P = predict(mode, mean, cov, u)
    return kalman_update(mode, mean_pred, P)


def rollout(
    system: SwitchedSystem, initial: GaussianBelief, actions: Sequence[int] | np.ndarray, controls: ArrayLike
) -> ProbabilisticTSTrajectory:
    """Roll the MLO belief dynamics along a mode and control sequence.

    Parameters
    ----------
    system : SwitchedSystem
    initial : GaussianBelief
    actions : array_like of int, shape (N,)
        Mode ``q_k`` applied at step ``k``.
    controls : array_like, shape (N, m)

    Returns
    -------
    ProbabilisticTSTrajectory
    """
    from .trajectory import ProbabilisticTSTrajectory

    actions = np.asarray(actions, dtype=int).reshape(-1)
    N = actions.shape[0]
    controls = np.asarray(controls, dtype=float)
    if N and controls.size != N * system.m:
        raise DimensionError(
            f"controls must have shape ({N}, {system.m}) (one input per action), got {controls.shape}"
        )
    controls = controls.reshape(N, system.m) if N else np.zeros((0, system.m))
    if initial.n != system.n:
        raise DimensionError(f"initial belief has dimension {initial.n}, the system has n = {system.n}")
    if N and (actions.min() < 0 or actions.max() >= system.num_modes):
        raise OutOfRangeError(f"actions must be modes in 0..{system.num_modes - 1}, got {actions.tolist()}")
    if not np.all(np.isfinite(controls)):
        raise InvalidArgumentError("controls contain NaN or inf")
    means, covs = rollout_arrays(system.system_modes, initial.mean, initial.cov, actions, controls)
    return ProbabilisticTSTrajectory(means, covs, actions, controls)


def rollout_arrays(
    modes: Sequence[Any] | np.ndarray,
    mean0: np.ndarray,
    cov0: np.ndarray,
    actions: np.ndarray,
    controls: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The MLO roll-out on plain arrays (no validation): the one loop every part calls.

    Parameters
    ----------
    modes : sequence of LCS
        The system's modes.
    mean0 : ndarray, shape (n,)
    cov0 : ndarray, shape (n, n)
    actions : ndarray of int, shape (N,)
    controls : ndarray, shape (N, m)

    Returns
    -------
    means : ndarray, shape (N + 1, n)
    covs : ndarray, shape (N + 1, n, n)
    """
    N = actions.shape[0]
    means = np.empty((N + 1, mean0.shape[0]))
    covs = np.empty((N + 1, *cov0.shape))
    means[0], covs[0] = mean0, cov0
    # belief_step inlined (the planner's innermost loop): the mode's matrices looked up once per
    # mode, the noise function still evaluated (and checked by noise_cov) at every step
    parts: dict[int, tuple[Any, ...]] = {}
    for k in range(N):
        q = int(actions[k])
        part = parts.get(q)
        if part is None:
            mode = modes[q]
            part = (mode, mode.A, mode.A.T, mode.B, mode.process_cov, mode.C, mode.p)
            parts[q] = part
        mode, A, At, B, Q, C, p = part
        mean = A @ means[k] + B @ controls[k]
        P = A @ covs[k] @ At + Q
        means[k + 1] = mean
        if p == 0:
            covs[k + 1] = P
            continue
        R = mode.noise_cov(mean)
        covs[k + 1] = _joseph(kalman_gain(C, P, R), C, P, R)
    return means, covs
