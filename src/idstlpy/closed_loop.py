"""The executor's closed loop around a plan, as a linear-Gaussian process (LQG-MP).

:func:`idstlpy.simulate` tracks a plan with a Kalman filter and the LQR law of
:mod:`idstlpy.tracking`. Around the plan (modes ``q_k``, means ``m_k``, inputs ``v_k``) that loop is
linear: with ``delta_k = x_k - m_k`` the true state's deviation and ``eta_k = mean_k - m_k`` the
executed belief mean's deviation, the joint ``z = (delta, eta)`` is a Gauss-Markov process whose
moments :func:`propagate` computes (the derivation, and what is exact and what is linearised, is
in :mod:`idstlpy.execution.prediction`).

This module is the one home of that propagation. It sits in the model layer because two layers
use it: the planner (``guarantee="closed_loop"`` puts the chance constraints on the predicted true
state, :func:`predicted_state`) and the prediction of an execution
(:func:`idstlpy.predict_closed_loop`).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import ndtr

from .belief import gain_from, kalman_gain, kalman_update
from .dynamical_system import LCS, SwitchedSystem
from .errors import DimensionError, InvalidArgumentError, InvalidTypeError
from .sets import Polytope
from .tracking import box_bounds, gain_at, system_gains, tracking_input
from .trajectory import ProbabilisticTSTrajectory

__all__ = [
    "ClosedLoopMoments",
    "box_bounds",
    "gains_for",
    "predicted_state",
    "trackable",
    "tracking_backoff",
    "tracking_spread",
    "prob_le",
    "propagate",
    "real_modes_for",
    "step_parts",
    "sqrt_psd",
]


def prob_le(mu: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """``P[X <= 0]`` for ``X ~ N(mu, sd^2)``; an indicator when ``sd == 0``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        p = ndtr(-mu / sd)
    return np.where(sd > 0, p, (mu <= 0).astype(float))


# --------------------------------------------------------------------------------------------
# Input handling


def real_modes_for(real_system: Any, system: SwitchedSystem, actions: np.ndarray) -> list[LCS]:
    """The modes moving the true state: the model's (``None``), one for all, or one per mode.

    Parameters
    ----------
    real_system : SwitchedSystem, LCS or None
    system : SwitchedSystem
        The planning model.
    actions : ndarray of int, shape (N,)
        The plan's modes.

    Returns
    -------
    list of LCS
    """
    if real_system is None:
        return list(system.system_modes)
    if isinstance(real_system, LCS):
        real_system = SwitchedSystem([real_system])
    if not isinstance(real_system, SwitchedSystem):
        raise InvalidTypeError(
            f"real_system must be made by mk_switched_sys (or mk_lcs), got {type(real_system).__name__}"
        )
    if (real_system.n, real_system.m) != (system.n, system.m):
        raise DimensionError(
            f"real_system has (n, m) = ({real_system.n}, {real_system.m}); "
            f"the model has ({system.n}, {system.m})"
        )
    modes = list(real_system.system_modes)
    if len(modes) > 1 and actions.size and int(actions.max()) >= len(modes):
        raise DimensionError(
            f"the plan uses mode {int(actions.max())}, real_system has modes 0..{len(modes) - 1} "
            "(give one real mode per planning mode, or a single mode used for all)"
        )
    return modes


def step_parts(
    system: SwitchedSystem,
    real_modes: Sequence[LCS] | None,
    gains: Mapping[int, Sequence[np.ndarray]],
    process_noise: str,
    q: int,
    remaining: int,
) -> tuple[LCS, LCS | None, np.ndarray, np.ndarray | None]:
    """What the executor uses at a plan step in mode ``q`` with ``remaining`` plan steps left.

    The one home of these choices for the executor's step law (:mod:`idstlpy.executor.law`) and
    the moment propagation (:func:`propagate`).

    Parameters
    ----------
    system : SwitchedSystem
        The planning model.
    real_modes : sequence of LCS or None
        The linear plant's modes (one for all, or one per planning mode); None for a plant
        given as a step function.
    gains : mapping
        Mode -> tracking gains ``K_0 .. K_{h-1}``, each (m, n).
    process_noise : {"model", "real", "none"}
    q : int
        The planning mode.
    remaining : int
        Plan steps left (``N - k``).

    Returns
    -------
    mode : LCS
        The planning mode.
    real : LCS or None
        The plant's linear mode (None without ``real_modes``).
    K : ndarray, shape (m, n)
        The receding-horizon tracking gain (:func:`idstlpy.tracking.gain_at`).
    W : ndarray of shape (n, r), or None
        The factor of the process noise added to the true state (None: none).
    """
    mode = system.mode(q)
    real = None if real_modes is None else real_modes[0] if len(real_modes) == 1 else real_modes[q]
    W = None
    if process_noise == "model":
        W = mode.W
    elif process_noise == "real" and real is not None:
        W = real.W
    return mode, real, gain_at(gains[q], remaining), W


def gains_for(
    system: SwitchedSystem,
    actions: np.ndarray,
    lqr_gains: Mapping[int, Sequence[np.ndarray]] | Sequence[Sequence[np.ndarray] | None] | None,
    default_lqr: Mapping[str, Any] | None,
) -> dict[int, list[np.ndarray]]:
    """Tracking gains (:func:`idstlpy.tracking.mode_gains`) of every mode the plan uses.

    Returns
    -------
    dict
        Mode -> list of gains, each shape (m, n).
    """

    return system_gains(system, lqr_gains, default_lqr, actions.tolist())


def sqrt_psd(S: np.ndarray) -> np.ndarray:
    """A square root ``T`` with ``T T' = S`` for a symmetric PSD ``S`` (eigenvalues clipped at 0)."""
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    return V * np.sqrt(np.maximum(w, 0.0))


@functools.lru_cache(maxsize=16)
def _cubature(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Points (P, n) and weights (P,) integrating against ``N(0, I)`` (read-only).

    Gauss-Hermite with 3 nodes per axis (exact for polynomials of degree 5 in each coordinate)
    up to ``n = 4``; the degree-3 spherical rule (``2n`` points ``+-sqrt(n) e_i``) above. Kept per
    ``n``: the particle closure asks for it twice a step.
    """
    pts, w = _cubature_rule(n)
    pts.flags.writeable = False
    w.flags.writeable = False
    return pts, w


def _cubature_rule(n: int) -> tuple[np.ndarray, np.ndarray]:
    if n <= 4:
        nodes = np.array([-np.sqrt(3.0), 0.0, np.sqrt(3.0)])
        weights = np.array([1 / 6, 2 / 3, 1 / 6])
        grids = np.meshgrid(*([nodes] * n), indexing="ij")
        pts = np.stack([g.reshape(-1) for g in grids], axis=1)
        wgrid = np.meshgrid(*([weights] * n), indexing="ij")
        w = np.prod(np.stack([g.reshape(-1) for g in wgrid], axis=1), axis=1)
        return pts, w
    eye = np.sqrt(n) * np.eye(n)
    return np.vstack([eye, -eye]), np.full(2 * n, 1.0 / (2 * n))


# --------------------------------------------------------------------------------------------
# The closed loop


def _clipped_moments(
    mu: np.ndarray, sd: np.ndarray, low: np.ndarray, high: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Moments of ``clip(Y_i, low_i, high_i)`` for ``Y_i ~ N(mu_i, sd_i^2)``, each shape (m,).

    Returns the mean, the variance and ``P[low_i < Y_i < high_i]`` (the expected derivative of the
    clip: by Stein's lemma ``Cov(z, clip(Y_i)) = P_in Cov(z, Y_i)`` for any ``z`` jointly Gaussian
    with ``Y``).
    """
    pos = sd > 0
    s = np.where(pos, sd, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = (low - mu) / s
        b = (high - mu) / s
    Fa, Fb = ndtr(a), ndtr(b)
    pa = np.where(np.isfinite(a), np.exp(-0.5 * np.where(np.isfinite(a), a, 0.0) ** 2), 0.0) / np.sqrt(
        2 * np.pi
    )
    pb = np.where(np.isfinite(b), np.exp(-0.5 * np.where(np.isfinite(b), b, 0.0) ** 2), 0.0) / np.sqrt(
        2 * np.pi
    )
    apa = np.where(np.isfinite(a), np.where(np.isfinite(a), a, 0.0) * pa, 0.0)  # no inf * 0
    bpb = np.where(np.isfinite(b), np.where(np.isfinite(b), b, 0.0) * pb, 0.0)
    lo_t = np.where(np.isfinite(low), low, 0.0)
    hi_t = np.where(np.isfinite(high), high, 0.0)
    p_in = Fb - Fa
    e1 = lo_t * Fa + hi_t * (1 - Fb) + mu * p_in + s * (pa - pb)
    e2 = (
        lo_t**2 * Fa
        + hi_t**2 * (1 - Fb)
        + (mu**2 + s**2) * p_in
        + 2 * mu * s * (pa - pb)
        + s**2 * (apa - bpb)
    )
    var = np.maximum(e2 - e1**2, 0.0)
    det = np.clip(mu, low, high)
    inside = ((mu > low) & (mu < high)).astype(float)
    return np.where(pos, e1, det), np.where(pos, var, 0.0), np.where(pos, p_in, inside)


_GH3 = np.sqrt(3.0)


@dataclass
class NoiseInterpolant:
    """A state-dependent sensor's noise factor ``n(x)`` around a Gaussian ``N(c, T T')``, as the
    tensor-product quadratic that interpolates it at the 3-node Gauss-Hermite points (the points
    :func:`propagate`'s expectation of ``R`` already evaluates): exact for a noise factor that is
    quadratic in ``x``, evaluated on many samples at once. At most four directions (the largest
    of ``T``) are resolved; along the others ``n`` is frozen at the centre.
    """

    center: np.ndarray  # (n,)
    inv: np.ndarray  # (r, n): standardised coordinates xi = inv (x - center)
    values: np.ndarray  # (3^r, p, q): n(x) at the grid points

    @staticmethod
    def fit(mode: LCS, center: np.ndarray, cov: np.ndarray) -> NoiseInterpolant:
        w, V = np.linalg.eigh(0.5 * (cov + cov.T))
        order = np.argsort(w)[::-1]
        w, V = w[order], V[:, order]
        keep = w > 1e-14 * max(1.0, float(w.max(initial=0.0)))
        r = min(int(np.sum(keep)), 4)
        T = V[:, :r] * np.sqrt(w[:r])
        inv = (V[:, :r] / np.sqrt(w[:r])).T if r else np.zeros((0, center.shape[0]))
        grid = _cubature(r)[0] if r else np.zeros((1, 0))  # the 3-node Gauss-Hermite grid (r <= 4)
        values = np.stack([mode.noise(center + T @ xi) for xi in grid])
        return NoiseInterpolant(center, inv, values)

    def expectation(self) -> np.ndarray:
        """``E[n(x) n(x)']`` under ``N(c, T T')`` by the nodes' Gauss-Hermite rule: shape (p, p)."""
        r = self.inv.shape[0]
        w = _cubature(r)[1] if r else np.ones(1)
        return np.einsum("g,gpq,grq->pr", w, self.values, self.values)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """``n(x)`` for samples ``X`` (S, n): shape (S, p, q)."""
        r = self.inv.shape[0]
        if r == 0:
            return np.broadcast_to(self.values[0], (X.shape[0], *self.values.shape[1:]))
        S = X.shape[0]
        xi = self.inv @ (X - self.center).T  # (r, S)
        # Lagrange weights of the nodes -sqrt(3), 0, sqrt(3) per direction: (r, 3, S); samples
        # last, so that the tensor products below run over contiguous rows (1.5x faster at 4000
        # samples and 81 nodes than samples first)
        lag = np.stack([xi * (xi - _GH3) / 6.0, 1.0 - xi**2 / 3.0, xi * (xi + _GH3) / 6.0], axis=1)
        wts = lag[0]
        for i in range(1, r):
            wts = (wts[:, None, :] * lag[i][None, :, :]).reshape(-1, S)
        G, p, q = self.values.shape
        return (self.values.reshape(G, p * q).T @ wts).T.reshape(S, p, q)


@dataclass
class LoopStep:
    """One step of the closed loop around the plan, as a map on samples of ``z = (delta, eta[, dP])``.

    The moment propagation (:func:`propagate`) linearises the clip of the corrected input
    statistically and keeps the loop Gaussian; this map applies the clip itself to every sample
    (the rest of the loop is the same: the filter's gains at the predicted mean, the sensor noise
    at the predicted true state). :meth:`advance` is what ``closure="particles"`` propagates and
    what :func:`idstlpy.execution.prediction.predict_closed_loop` samples its rates from.
    """

    K: np.ndarray  # (m, n) tracking gain
    v: np.ndarray  # (m,) planned input
    low: np.ndarray | None  # (m,) box of the inputs (None: not clipped)
    high: np.ndarray | None
    Ar: np.ndarray
    Br: np.ndarray
    A: np.ndarray
    B: np.ndarray
    d: np.ndarray  # model mismatch A_r m + B_r v - m_next
    r: np.ndarray  # m_next - A m - B v
    LC: np.ndarray
    Lk: np.ndarray  # (n, p)
    W_root: np.ndarray  # (n, n) process noise root
    R_root: np.ndarray  # (p, p) sensor noise root (at the predicted true state)
    sens: tuple[np.ndarray, np.ndarray, np.ndarray] | None  # (kron(Phi, Phi), J, x_lin - m_next)
    # A state-dependent sensor, per sample (closure "particles"): its noise factor's interpolant,
    # the plan's next mean, C, the process covariance and the nominal filter covariances P_k, P_{k+1}.
    noise: NoiseInterpolant | None = None
    m_next: np.ndarray | None = None
    C: np.ndarray | None = None
    Qp: np.ndarray | None = None
    P_prev: np.ndarray | None = None
    P_next: np.ndarray | None = None

    def advance(self, Z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Samples (S, D) of ``z_k`` -> samples of ``z_{k+1}`` (fresh noise from ``rng``).

        With a :class:`NoiseInterpolant` the sensor noise is drawn at each sample's true state,
        and, when the filter-sensitivity coordinates are carried, each sample's filter runs on
        its own covariance (nominal plus the sample's ``dP``) with ``R`` at its own predicted
        mean, as :func:`idstlpy.simulate`'s does; ``dP`` is then the exact deviation.
        """
        n = self.A.shape[0]
        if self.noise is not None:
            return self._advance_state_dependent(Z, rng)
        delta_n, eta_pred = self._track(Z, rng)
        eta_n = eta_pred + (delta_n - eta_pred) @ self.LC.T
        if self.R_root.size:
            nu = rng.standard_normal((Z.shape[0], self.R_root.shape[1])) @ self.R_root.T
            eta_n = eta_n + nu @ self.Lk.T
        out = np.empty_like(Z)
        out[:, :n], out[:, n : 2 * n] = delta_n, eta_n
        if Z.shape[1] > 2 * n:
            if self.sens is None:
                out[:, 2 * n :] = Z[:, 2 * n :]
            else:
                kron, J, off = self.sens
                out[:, 2 * n :] = Z[:, 2 * n :] @ kron.T + (eta_pred - off) @ J.T
        return out

    def _track(self, Z: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """The samples' next true-state deviation and predicted estimation error (before the
        measurement): the tracking correction clipped to the control domain, process noise drawn."""
        n = self.A.shape[0]
        delta, eta = Z[:, :n], Z[:, n : 2 * n]
        y = tracking_input(self.v, self.K, eta, self.low, self.high)
        c = y - self.v
        delta_n = delta @ self.Ar.T + c @ self.Br.T + self.d
        if self.W_root.size:
            delta_n = delta_n + rng.standard_normal((Z.shape[0], self.W_root.shape[1])) @ self.W_root.T
        return delta_n, eta @ self.A.T + c @ self.B.T - self.r

    def _advance_state_dependent(self, Z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        noise, m_next, C = self.noise, self.m_next, self.C
        if noise is None or m_next is None or C is None:  # pragma: no cover - set together
            raise InvalidArgumentError("a state-dependent loop step needs its noise model")
        n, S = self.A.shape[0], Z.shape[0]
        delta_n, eta_pred = self._track(Z, rng)
        nx = noise(m_next + delta_n)  # (S, p, q): the sensor at the true state
        nu = (nx @ rng.standard_normal((S, nx.shape[2], 1)))[:, :, 0]
        out = np.empty_like(Z)
        out[:, :n] = delta_n
        per_sample = Z.shape[1] > 2 * n and self.P_prev is not None and self.P_next is not None
        if not per_sample:
            innov = (delta_n - eta_pred) @ C.T + nu
            out[:, n : 2 * n] = eta_pred + innov @ self.Lk.T
            if Z.shape[1] > 2 * n:
                out[:, 2 * n :] = Z[:, 2 * n :]
            return out
        Pk = self.P_prev + Z[:, 2 * n :].reshape(S, n, n)  # type: ignore[operator]
        P_pred = self.A @ Pk @ self.A.T + self.Qp
        nf = noise(m_next + eta_pred)  # the filter's R at its own predicted mean
        R = nf @ np.swapaxes(nf, 1, 2)
        PCt = P_pred @ C.T  # (S, n, p)
        Sinn = C @ PCt + R  # (S, p, p)
        Lg = _batched_gain(PCt, Sinn)
        innov = (delta_n - eta_pred) @ C.T + nu
        out[:, n : 2 * n] = eta_pred + (Lg @ innov[:, :, None])[:, :, 0]
        IKC = np.eye(n) - Lg @ C
        P_new = IKC @ P_pred @ np.swapaxes(IKC, 1, 2) + Lg @ R @ np.swapaxes(Lg, 1, 2)
        out[:, 2 * n :] = (0.5 * (P_new + np.swapaxes(P_new, 1, 2)) - self.P_next).reshape(S, n * n)
        return out


def _batched_gain(PCt: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Kalman gains ``PCt S^-1`` of many samples, (S, n, p), computed as
    :func:`idstlpy.belief.kalman_gain` computes one (closed form for one or two outputs when well
    conditioned, else a solve, else the pseudo-inverse), so that a sample's filter is the
    executor's also where the innovation covariance is (nearly) singular."""
    num, _, p = PCt.shape
    K = np.full(PCt.shape, np.nan)
    ok = np.zeros(num, dtype=bool)
    with np.errstate(all="ignore"):
        if p == 1:
            s = S[:, 0, 0]
            ok = (s > 0.0) & np.isfinite(s)
            K = PCt / np.where(ok, s, 1.0)[:, None, None]
        elif p == 2:
            a, b, c, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 0], S[:, 1, 1]
            det = a * d - b * c
            ok = (np.abs(det) > 1e-10 * (np.abs(a * d) + np.abs(b * c))) & np.isfinite(det) & (det != 0.0)
            inv = np.stack([np.stack([d, -b], axis=1), np.stack([-c, a], axis=1)], axis=1)
            K = PCt @ (inv / np.where(ok, det, 1.0)[:, None, None])
        else:  # gain_from's solve, one LAPACK call for the batch (a singular one: per sample)
            try:
                K = np.swapaxes(np.linalg.solve(np.swapaxes(S, 1, 2), np.swapaxes(PCt, 1, 2)), 1, 2)
                ok = np.ones(num, dtype=bool)
            except np.linalg.LinAlgError:
                pass
        ok &= np.all(np.isfinite(K), axis=(1, 2))
    for i in np.flatnonzero(~ok):
        K[i] = gain_from(PCt[i], S[i])
    return K


@dataclass
class ClosedLoopMoments:
    """Moments of the closed loop's joint state ``z = (delta, eta[, dP])`` (``D`` coordinates).

    Attributes: ``mean`` (L, D) and ``cov`` (L, D, D) per step; the one-step transitions ``F``
    (N, D, D), offsets ``g`` (N, D) and noise covariances ``Q`` (N, D, D); the filter covariance
    ``P`` (L, n, n); the tracking gains ``K`` (N, m, n) and Kalman gains ``L`` (n, p each); an
    upper bound on the probability that the input is clipped, ``clip`` (N,); ``sensitivity``:
    whether the ``n^2`` filter-sensitivity coordinates are carried; ``steps``: the per-step maps
    on samples (:class:`LoopStep`); ``closure``: how the moments were closed (``"gaussian"``:
    the clip linearised statistically; ``"particles"``: the moments of samples propagated through
    the clip, ``F, g, Q`` their statistical linear regression).
    """

    mean: np.ndarray  # (L, D)
    cov: np.ndarray  # (L, D, D)
    F: np.ndarray  # (N, D, D)
    g: np.ndarray  # (N, D)
    Q: np.ndarray  # (N, D, D)
    P: np.ndarray  # (L, n, n)
    K: np.ndarray  # (N, m, n)
    L: list[np.ndarray]
    clip: np.ndarray  # (N,)
    sensitivity: bool
    steps: list[LoopStep] | None = None
    closure: str = "gaussian"


def _noise_cov_jacobian(mode: LCS, x: np.ndarray) -> np.ndarray:
    """``dR/dx_i`` at ``x`` by central differences, shape (n, p, p)."""
    out = np.empty((x.shape[0], mode.p, mode.p))
    for i in range(x.shape[0]):
        step = 1e-5 * max(1.0, abs(float(x[i])))
        e = np.zeros_like(x)
        e[i] = step
        out[i] = (mode.noise_cov(x + e) - mode.noise_cov(x - e)) / (2 * step)
    return out


def propagate(
    system: SwitchedSystem,
    plan: ProbabilisticTSTrajectory,
    N: int,
    real_modes: list[LCS],
    gains: Mapping[int, Sequence[np.ndarray]],
    process_noise: str,
    z0: np.ndarray,
    S0: np.ndarray,
    P0: np.ndarray,
    sensor_noise: str,
    domain: Polytope | None,
    filter_sensitivity: bool,
    closure: str = "gaussian",
    particles: int = 4000,
    seed: int = 0,
) -> ClosedLoopMoments:
    """Propagate the closed loop's first two moments over ``N`` steps of ``plan``.

    Parameters
    ----------
    system : SwitchedSystem
        The planning model (the filter's).
    plan : ProbabilisticTSTrajectory
        The plan tracked (modes, means, inputs).
    N : int
        Steps to propagate (``<= plan.num_of_steps``).
    real_modes : list of LCS
        From :func:`real_modes_for`.
    gains : dict
        From :func:`gains_for`.
    process_noise : {"model", "real", "none"}
    z0 : ndarray, shape (2n,)
        Mean of ``(delta_0, eta_0)``.
    S0 : ndarray, shape (2n, 2n)
        Its covariance.
    P0 : ndarray, shape (n, n)
        The filter's prior covariance.
    sensor_noise : {"expected", "mean", "plan"}
        Linearisation of a state-dependent sensor (see :mod:`idstlpy.execution.prediction`).
    domain : Polytope or None
        The control domain the corrected input is projected on.
    filter_sensitivity : bool
        Carry the first-order variation of the filter covariance (``n^2`` coordinates).
    closure : {"gaussian", "particles", "auto"}
        ``"gaussian"``: the clip of the corrected input by its statistical linearisation, exact
        for one step from a Gaussian, but it keeps the loop Gaussian: a plan that rides an input
        bound makes the clipped loop a rectifier (deviations on one side are not corrected and
        accumulate) whose spread this under-states. ``"particles"``: ``particles`` samples of
        ``z`` are propagated through the clip itself (:class:`LoopStep`, seeded by ``seed``:
        deterministic); the moments are theirs, and ``F, g, Q`` their statistical linear
        regression (``F = Cov(z_{k+1}, z_k) Cov(z_k)^+``, ``Q`` the residual covariance), so the
        Gauss-Markov model has the samples' per-step moments and one-step covariances.
        With a state-dependent sensor the samples also draw its noise at their own true state
        and run their own filter (:class:`LoopStep`): the skew such a sensor gives the loop is
        kept. ``"auto"``: particles under a state-dependent sensor or when a box clips the input
        with probability above 1% at some step, the (exact) Gaussian closure otherwise.
    particles : int
    seed : int

    Returns
    -------
    ClosedLoopMoments

    Raises
    ------
    InvalidArgumentError
        When the predicted loop diverges.
    """
    n, m = system.n, system.m
    box = box_bounds(domain, m)
    N_ref = plan.num_of_steps
    actions = plan.get_action()
    means = plan.get_mean()
    controls = plan.get_control()
    used = {int(q) for q in actions[:N]}
    state_dependent = any(system.mode(q).p and system.mode(q).has_state_dependent_noise for q in used)
    sens = filter_sensitivity and state_dependent
    D = 2 * n + (n * n if sens else 0)
    I = np.eye(n)
    Z = np.zeros((n, n))
    out = ClosedLoopMoments(
        mean=np.zeros((N + 1, D)),
        cov=np.zeros((N + 1, D, D)),
        F=np.zeros((N, D, D)),
        g=np.zeros((N, D)),
        Q=np.zeros((N, D, D)),
        P=np.empty((N + 1, n, n)),
        K=np.empty((N, m, n)),
        L=[],
        clip=np.zeros(N),
        sensitivity=sens,
    )
    out.mean[0, : 2 * n], out.cov[0, : 2 * n, : 2 * n], out.P[0] = z0, S0, P0
    cub = _cubature(n) if sensor_noise == "expected" else None
    if closure not in ("auto", "gaussian", "particles"):
        raise InvalidArgumentError(f"closure must be 'auto', 'gaussian' or 'particles', got {closure!r}")
    if closure == "auto":
        if N == 0:
            closure = "gaussian"
        elif state_dependent:
            closure = "particles"
        elif box is None:
            closure = "gaussian"
        else:
            first = propagate(
                system, plan, N, real_modes, gains, process_noise, z0, S0, P0, sensor_noise, domain,
                filter_sensitivity, "gaussian",
            )  # fmt: skip
            if float(first.clip.max()) <= 0.01:
                return first
            closure = "particles"
    use_particles = closure == "particles" and N > 0
    out.closure = "particles" if use_particles else "gaussian"
    out.steps = []
    rng = np.random.default_rng(seed)
    Zp = np.zeros((0, D))
    if use_particles:
        Zp = np.zeros((particles, D))
        Zp[:, : 2 * n] = z0 + rng.standard_normal((particles, 2 * n)) @ sqrt_psd(S0).T
        Zp[:, : 2 * n] += z0 - Zp[:, : 2 * n].mean(axis=0)  # the exact mean
    # the samples' mean, centred samples and covariance, carried from one step to the next
    zc, Xc, Sp = np.zeros(D), Zp, np.zeros((D, D))
    if use_particles:
        zc = Zp.mean(axis=0)
        Xc = Zp - zc
        Sp = Xc.T @ Xc / particles
    z, S, P = out.mean[0], out.cov[0], P0
    for k in range(N):
        q = int(actions[k])
        mode, real_or_none, Kt, W = step_parts(system, real_modes, gains, process_noise, q, N_ref - k)
        real = mode if real_or_none is None else real_or_none  # (never None: real_modes is a list)
        A, B, Ar, Br = mode.A, mode.B, real.A, real.B
        Qw = W @ W.T if W is not None and W.shape[1] else Z
        m_k, m_next, v = means[k], means[k + 1], controls[k]
        P_prev = P
        if use_particles:  # the moments the linearisation below is taken at are the samples'
            z, S = zc, Sp
        eta = z[n : 2 * n]
        S_eta = S[n : 2 * n, n : 2 * n]
        nominal_pred = A @ m_k + B @ v
        r = m_next - nominal_pred
        d = Ar @ m_k + Br @ v - m_next
        # The input: u - v = c_u - K_eff eta + e, the statistical linearisation of the clip
        # (e uncorrelated with the loop, covariance E).
        K_eff, c_u, E = Kt, np.zeros(m), np.zeros((m, m))
        if box is not None:
            mu_y = v - Kt @ eta
            sd_y = np.sqrt(np.maximum(np.diag(Kt @ S_eta @ Kt.T), 0.0))
            e1, var, p_in = _clipped_moments(mu_y, sd_y, box[0], box[1])
            K_eff = p_in[:, None] * Kt
            c_u = e1 - v + K_eff @ eta
            E = np.diag(np.maximum(var - p_in**2 * sd_y**2, 0.0))
            out.clip[k] = min(1.0, float(np.sum(1.0 - p_in)))
        elif domain is not None:  # a general polytope: the projection is not modelled, only bounded
            mu_y = v - Kt @ eta
            HK = domain.H @ Kt
            sd_f = np.sqrt(np.maximum(np.einsum("fi,ij,fj->f", HK, S_eta, HK), 0.0))
            out.clip[k] = min(1.0, float(np.sum(1.0 - prob_le(domain.H @ mu_y + domain.c, sd_f))))
        A_eta = A - B @ K_eff
        # The filter's predicted mean is m_next + eta_pred, eta_pred = A_eta eta + B c_u - r + B e.
        eta_pred_mean = A_eta @ eta + B @ c_u - r
        if use_particles:
            y_p = v - Zp[:, n : 2 * n] @ Kt.T
            if box is not None:
                y_p = np.clip(y_p, box[0], box[1])
            eta_pred_mean = (Zp[:, n : 2 * n] @ A.T + (y_p - v) @ B.T).mean(axis=0) - r
        # Filter: its noise is evaluated at its own (random) predicted mean, linearised at the plan's
        # nominal one ("plan": the plan's MLO covariances) or at the predicted one (otherwise).
        P_pred = A @ P @ A.T + mode.process_cov
        state_dep = bool(mode.p) and mode.has_state_dependent_noise
        x_lin = nominal_pred if sensor_noise == "plan" or not state_dep else m_next + eta_pred_mean
        if mode.p:
            R_filter = mode.noise_cov(x_lin)
            Lk = kalman_gain(mode.C, P_pred, R_filter)
            _, P = kalman_update(mode, x_lin, P_pred, R=R_filter)
            LC = Lk @ mode.C
        else:
            Lk = np.zeros((n, 0))
            P = 0.5 * (P_pred + P_pred.T)
            LC = Z
        ILC = I - LC
        BrK = Br @ K_eff
        F = np.zeros((D, D))
        F[: 2 * n, : 2 * n] = np.block([[Ar, -BrK], [LC @ Ar, ILC @ A_eta - LC @ BrK]])
        drift = Br @ c_u + d
        g = np.zeros(D)
        g[: 2 * n] = np.concatenate([drift, ILC @ (B @ c_u - r) + LC @ drift])
        Gw = np.zeros((D, n))  # how the process noise enters
        Gw[: 2 * n] = np.vstack([I, LC])
        Ge = np.zeros((D, m))  # how the clipping residual enters
        Ge[: 2 * n] = np.vstack([Br, ILC @ B + LC @ Br])
        if sens:
            Phi = ILC @ A
            F[2 * n :, 2 * n :] = np.kron(Phi, Phi)
            if state_dep:
                dR = _noise_cov_jacobian(mode, x_lin)
                J = np.stack([(Lk @ dR[i] @ Lk.T).reshape(-1) for i in range(n)], axis=1)  # (n^2, n)
                F[2 * n :, n : 2 * n] = J @ A_eta
                g[2 * n :] = J @ (B @ c_u - r - (x_lin - m_next))
                Ge[2 * n :] = J @ B
        Qk = Gw @ Qw @ Gw.T + Ge @ E @ Ge.T
        z = F @ z + g
        S_pre = F @ S @ F.T + Qk
        R_true = np.zeros((mode.p, mode.p))
        fitted = None  # the sensor's noise interpolant, for samples drawing it at their own state
        if use_particles and state_dep and mode.p:
            fitted = NoiseInterpolant.fit(mode, m_next + z[:n], S_pre[:n, :n])
        if mode.p:
            if sensor_noise == "plan" or not state_dep:
                R_true = mode.noise_cov(m_next)
            elif sensor_noise == "mean":
                R_true = mode.noise_cov(m_next + z[:n])
            elif fitted is not None:
                # the interpolant's nodes are the cubature's points (up to n = 4): reuse them
                # (the moments below are the samples', so only the step's R_root reads this)
                R_true = fitted.expectation()
            else:
                pts, w = cub  # type: ignore[misc]
                xs = m_next + z[:n] + pts @ sqrt_psd(S_pre[:n, :n]).T
                # the noise factor directly: R(x) = n(x) n(x)' without noise_cov's per-call checks
                # (a non-finite factor makes the moments non-finite, caught below)
                nxs = np.stack([mode.noise(xi) for xi in xs])
                R_true = np.einsum("g,gpq,grq->pr", w, nxs, nxs)
            LRL = np.zeros((D, D))
            LRL[n : 2 * n, n : 2 * n] = Lk @ R_true @ Lk.T
            Qk = Qk + LRL
            S_pre = S_pre + LRL
        S = 0.5 * (S_pre + S_pre.T)
        sens_map = None
        if sens:
            sens_map = (F[2 * n :, 2 * n :], J if state_dep else np.zeros((n * n, n)),
                        (x_lin - m_next) if state_dep else np.zeros(n))  # fmt: skip
        step = LoopStep(
            K=Kt, v=v, low=None if box is None else box[0], high=None if box is None else box[1],
            Ar=Ar, Br=Br, A=A, B=B, d=d, r=r, LC=LC, Lk=Lk,
            W_root=sqrt_psd(Qw) if Qw.any() else np.zeros((n, 0)),
            R_root=sqrt_psd(R_true) if mode.p else np.zeros((0, 0)), sens=sens_map,
        )  # fmt: skip
        if fitted is not None:
            step.noise = fitted
            step.m_next, step.C, step.Qp = m_next, mode.C, mode.process_cov
            step.P_prev, step.P_next = P_prev, P
        out.steps.append(step)
        if use_particles:
            Zn = step.advance(Zp, rng)
            z = Zn.mean(axis=0)
            Yc = Zn - z
            S = Yc.T @ Yc / particles
            w, V = np.linalg.eigh(0.5 * (Sp + Sp.T))
            keep = w > 1e-12 * max(1.0, float(w.max(initial=0.0)))
            pinv = (V[:, keep] / w[keep]) @ V[:, keep].T
            F = (Yc.T @ Xc / particles) @ pinv  # the statistical linear regression of z_{k+1} on z_k
            g = z - F @ zc
            Qk = S - F @ Sp @ F.T
            Zp, zc, Xc, Sp = Zn, z, Yc, S
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(S)) and np.all(np.isfinite(P))):
            raise InvalidArgumentError(
                f"the predicted closed loop diverged at step {k + 1} (non-finite moments)"
            )
        out.mean[k + 1], out.cov[k + 1], out.P[k + 1] = z, S, P
        out.F[k], out.g[k], out.Q[k], out.K[k] = F, g, 0.5 * (Qk + Qk.T), Kt
        out.L.append(Lk)
    return out


def _planning_loop(
    system: SwitchedSystem,
    plan: ProbabilisticTSTrajectory,
    control_domain: Polytope | None,
    lqr_gains: Mapping[int, Sequence[np.ndarray]] | Sequence[Sequence[np.ndarray] | None] | None,
    default_lqr: Mapping[str, Any] | None,
    closure: str = "gaussian",
) -> ClosedLoopMoments:
    """The closed loop as the planner reads it (see :func:`predicted_state`).

    The planner asks for the same loop several times per candidate (the check, the tracking
    spread, the repair's covariances): the last few loops are kept, keyed by the system and the
    domain (identity), the closure, the tracking gains and the plan's arrays (content).
    """
    n = system.n
    N = plan.num_of_steps
    actions = np.asarray(plan.get_action(), dtype=int)[:N]
    gains = gains_for(system, actions, lqr_gains, default_lqr)
    arrays = [plan.get_mean(), plan.get_cov(), plan.get_action(), plan.get_control()]
    arrays += [g for q in sorted(gains) for g in gains[q]]
    key = (id(system), id(control_domain), closure, N, n, *(hash(a.tobytes()) for a in arrays))
    for k, (sys_ref, dom_ref, cached) in _LOOPS:
        if k == key and sys_ref is system and dom_ref is control_domain:
            return cached
    P0 = plan.get_cov(0)
    S0 = np.zeros((2 * n, 2 * n))
    S0[:n, :n] = P0
    loop = propagate(
        system,
        plan,
        N,
        list(system.system_modes),
        gains,
        "model",
        np.zeros(2 * n),
        S0,
        P0.copy(),
        "expected",
        control_domain,
        False,
        closure,
    )
    _LOOPS.insert(0, (key, (system, control_domain, loop)))
    del _LOOPS[_LOOPS_KEPT:]
    return loop


_LOOPS_KEPT = 8
_LOOPS: list[tuple[tuple[Any, ...], tuple[Any, Any, ClosedLoopMoments]]] = []


def tracking_spread(
    system: SwitchedSystem,
    plan: ProbabilisticTSTrajectory,
    control_domain: Polytope,
    *,
    lqr_gains: Mapping[int, Sequence[np.ndarray]] | Sequence[Sequence[np.ndarray] | None] | None = None,
    default_lqr: Mapping[str, Any] | None = None,
) -> np.ndarray:
    """Standard deviation of the tracking correction along every face of the control domain.

    The executor applies ``v_k - K_k eta_k`` (``eta_k`` the estimate's deviation from the plan)
    and clips it to the domain ``H u + c <= 0``. A plan whose inputs sit on a face leaves the
    correction no room: it is clipped, the deviations it should remove stay, and the true state
    drifts from the plan. Backing face ``f`` off by ``z`` times ``sd(H_f K_k eta_k)`` at step
    ``k`` (of the unclipped loop) keeps the corrected input inside with probability ``Phi(z)``
    per face and step: the tube of tube MPC, from the predicted loop.

    Parameters
    ----------
    system : SwitchedSystem
    plan : ProbabilisticTSTrajectory
        ``N`` steps (the spread depends on the modes, the plan length through the gains and,
        under state-dependent noise, on the means).
    control_domain : Polytope
        ``F`` faces of dimension ``m``.
    lqr_gains, default_lqr : optional
        As in :func:`idstlpy.simulate`.

    Returns
    -------
    ndarray, shape (N, F)
    """
    N = plan.num_of_steps
    H = control_domain.H
    if N == 0:
        return np.zeros((0, H.shape[0]))
    return correction_spread(_planning_loop(system, plan, None, lqr_gains, default_lqr), H)


def correction_spread(loop: ClosedLoopMoments, H: np.ndarray) -> np.ndarray:
    """``sd(H_f K_k eta_k)`` per step and face of a predicted loop, shape (N, F).

    Parameters
    ----------
    loop : ClosedLoopMoments
        ``N`` steps of a state of dimension ``n``.
    H : ndarray, shape (F, m)
        Faces of the control domain.
    """
    N, n = loop.K.shape[0], loop.K.shape[2]
    HK = np.einsum("fi,kij->kfj", H, loop.K)  # (N, F, n)
    S_eta = loop.cov[:N, n : 2 * n, n : 2 * n]
    return np.sqrt(np.maximum(np.einsum("kfi,kij,kfj->kf", HK, S_eta, HK), 0.0))


TRACKABLE_Z = 1.0
"""A plan is trackable when its inputs leave this many standard deviations of the tracking
correction free on every face of the control domain at every step (per face and step, the
correction is clipped with probability at most ``1 - Phi(1) = 16%``)."""


def tracking_backoff(
    system: SwitchedSystem,
    plan: ProbabilisticTSTrajectory,
    control_domain: Polytope,
    z: float,
    spread: np.ndarray | None = None,
) -> np.ndarray:
    """Per step and face, ``z`` standard deviations of the tracking correction, capped at 40% of
    the domain's width along the face (so that a back-off never empties the domain).

    Parameters
    ----------
    system : SwitchedSystem
    plan : ProbabilisticTSTrajectory
        ``N`` steps.
    control_domain : Polytope
        ``F`` faces.
    z : float
    spread : ndarray, shape (N, F), optional
        :func:`tracking_spread` of the plan, when the caller already has it.

    Returns
    -------
    ndarray, shape (N, F)
        In the domain's units: face ``f`` at step ``k`` becomes ``H_f u + c_f + b_kf <= 0``.
    """
    H = control_domain.H
    if spread is None:
        spread = tracking_spread(system, plan, control_domain)
    width = np.array([control_domain.support(h) + control_domain.support(-h) for h in H])
    return np.minimum(z * spread, 0.4 * width[None, :])


def trackable(
    system: SwitchedSystem, plan: ProbabilisticTSTrajectory, control_domain: Polytope, z: float = TRACKABLE_Z
) -> bool:
    """Whether the plan's inputs leave the tracking correction room (:data:`TRACKABLE_Z`).

    The closed-loop prediction models the clipping of the corrected input by its statistical
    linearisation, which stays Gaussian: for a plan that rides on a face of the domain for many
    steps the clipped loop is a rectifier (lags build up on one side) and the prediction
    under-states the spread. The planner under ``guarantee="closed_loop"`` therefore prefers
    trackable plans, which keep the prediction in the regime where it is accurate.

    Parameters
    ----------
    system : SwitchedSystem
    plan : ProbabilisticTSTrajectory
    control_domain : Polytope
    z : float

    Returns
    -------
    bool
    """
    H, c = control_domain.H, control_domain.c
    N = plan.num_of_steps
    if N == 0 or H.shape[0] == 0:
        return True
    backoff = tracking_backoff(system, plan, control_domain, z)
    lhs = plan.get_control()[:N] @ H.T + c[None, :] + backoff
    return bool(np.all(lhs <= 1e-9 * max(1.0, float(np.max(np.abs(c))))))


def predicted_state(
    system: SwitchedSystem,
    plan: ProbabilisticTSTrajectory,
    control_domain: Polytope | None = None,
    *,
    lqr_gains: Mapping[int, Sequence[np.ndarray]] | Sequence[Sequence[np.ndarray] | None] | None = None,
    default_lqr: Mapping[str, Any] | None = None,
    closure: str = "gaussian",
) -> ProbabilisticTSTrajectory:
    """The true state's predicted distribution when the executor tracks ``plan``: what
    ``guarantee="closed_loop"`` constrains.

    The planner's reading of the execution: the true initial state is distributed as the plan's
    initial belief (the filter starts at its mean), the real system is the model, the process
    noise is the model's, the inputs are projected on ``control_domain`` (a box is linearised
    statistically, see :mod:`idstlpy.execution.prediction`), and a state-dependent sensor is
    linearised around the predicted true state (``sensor_noise="expected"``).

    With constant sensor noise the covariance returned is the filter's (the MLO covariance) plus
    that of the estimate's deviation from the plan (the Kalman filter's estimate is orthogonal to
    its error, whatever the inputs), so it is never smaller than the MLO covariance and every
    chance constraint on it is at least as hard.

    Parameters
    ----------
    system : SwitchedSystem
    plan : ProbabilisticTSTrajectory
        ``N`` steps, state dimension ``n``.
    control_domain : Polytope, optional
    lqr_gains, default_lqr : optional
        As in :func:`idstlpy.simulate`.
    closure : {"gaussian", "particles", "auto"}
        How the clip (and a state-dependent sensor) is modelled (:func:`propagate`): the
        statistical linearisation (default; accurate for a :func:`trackable` plan), or the
        moments of samples pushed through the clip (a plan that rides the input bounds).

    Returns
    -------
    ProbabilisticTSTrajectory
        Means (N + 1, n) (the plan's means plus the predicted mean deviation), covariances
        (N + 1, n, n) of the true state, and the plan's modes and inputs.
    """
    n = system.n
    N = plan.num_of_steps
    loop = _planning_loop(system, plan, control_domain, lqr_gains, default_lqr, closure)
    means = plan.get_mean()[: N + 1] + loop.mean[:, :n]
    covs = loop.cov[:, :n, :n]
    covs = 0.5 * (covs + np.swapaxes(covs, 1, 2))
    return ProbabilisticTSTrajectory(means, covs, plan.get_action(), plan.get_control())
