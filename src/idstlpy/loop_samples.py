"""The executor's closed loop around a plan as a map on samples (the particle closure).

:class:`LoopStep` pushes samples of the loop's joint state ``z = (delta, eta[, dP])`` through one
step with the clip of the corrected input itself (on a box; on any other polytope the executor's
Euclidean projection, :func:`idstlpy.tracking.control_projector`) and, under a state-dependent sensor, each
sample's own noise drawn from the sensor at its own true state (:class:`SensorDraw`) and its
own Kalman filter, ``R`` at its own predicted mean (:func:`batched_gain`):
what :func:`idstlpy.closed_loop.propagate` propagates under ``closure="particles"`` and what
:func:`idstlpy.executor.predict.predict_closed_loop` samples its rates from.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .belief import gain_from
from .dynamical_system import LCS
from .errors import InvalidArgumentError
from .tracking import tracking_input

__all__ = [
    "LoopStep",
    "NoiseInterpolant",
    "ParticleCloud",
    "batched_gain",
    "cubature",
    "SensorDraw",
    "sqrt_psd",
]


def sqrt_psd(S: np.ndarray) -> np.ndarray:
    """A square root ``T`` with ``T T' = S`` for a symmetric PSD ``S`` (eigenvalues clipped at 0)."""
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    root: np.ndarray = V * np.sqrt(np.maximum(w, 0.0))
    return root


@functools.lru_cache(maxsize=16)
def cubature(n: int) -> tuple[np.ndarray, np.ndarray]:
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


_GH3 = np.sqrt(3.0)


@dataclass
class NoiseInterpolant:
    """A state-dependent sensor's noise factor ``n(x)`` around a Gaussian ``N(c, T T')``, as the
    tensor-product quadratic that interpolates it at the 3-node Gauss-Hermite points (the points
    :func:`~idstlpy.closed_loop.propagate`'s expectation of ``R`` already evaluates): exact for
    a noise factor that is quadratic in ``x``, evaluated on many samples at once. At most four
    directions (the largest of ``T``) are resolved; along the others ``n`` is frozen at the
    centre.
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
        grid = cubature(r)[0] if r else np.zeros((1, 0))  # the 3-node Gauss-Hermite grid (r <= 4)
        values = np.stack([mode.noise(center + T @ xi) for xi in grid])
        return NoiseInterpolant(center, inv, values)

    def expectation(self) -> np.ndarray:
        """``E[n(x) n(x)']`` under ``N(c, T T')`` by the nodes' Gauss-Hermite rule: shape (p, p)."""
        r = self.inv.shape[0]
        w = cubature(r)[1] if r else np.ones(1)
        mean: np.ndarray = np.einsum("g,gpq,grq->pr", w, self.values, self.values)
        return mean

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
        out: np.ndarray = (self.values.reshape(G, p * q).T @ wts).T.reshape(S, p, q)
        return out


_CHECKED = 64
"""Samples (besides the extremes) at which :class:`SensorDraw` compares the interpolant with the
sensor: a region the interpolant misses that holds 5% of the samples is seen with probability
0.96."""


@dataclass
class SensorDraw:
    """A state-dependent sensor's noise factor ``n(x)`` on the samples of one step, as
    ``simulate`` draws it: at each sample's own state.

    The :class:`NoiseInterpolant` fitted to the step's predicted true state is used when it
    reproduces ``n`` at the step's first samples' extremes (per direction, both ends, and the
    farthest from the centre) and at :data:`_CHECKED` others (a factor quadratic in each coordinate: the
    interpolant is then ``n`` itself, 3 calls per direction instead of one per sample);
    otherwise every sample calls the sensor (:meth:`~idstlpy.dynamical_system.LCS.noise_batch`:
    once for the batch when the function takes one, else once per sample), so that a sensor the
    interpolant cannot follow (a step, the light-dark spot) is drawn from the sensor itself.
    The choice is made once per step, on the first samples pushed through it (the particle
    closure's, seeded): deterministic.
    """

    mode: LCS
    fitted: NoiseInterpolant
    use_fitted: bool | None = None  # None: not yet checked

    def check(self, *batches: np.ndarray) -> None:
        """Choose the interpolant or the sensor from samples (S, n) of the states it will see."""
        fitted = self.fitted
        picks = []
        for X in batches:
            if not X.shape[0]:
                continue
            xi = (X - fitted.center) @ fitted.inv.T  # (S, r)
            idx = {0, X.shape[0] - 1, *np.linspace(0, X.shape[0] - 1, _CHECKED).astype(int).tolist()}
            if xi.shape[1]:
                idx |= {*np.argmin(xi, axis=0).tolist(), *np.argmax(xi, axis=0).tolist()}
            idx.add(int(np.argmax(np.sum((X - fitted.center) ** 2, axis=1))))
            picks.append(X[sorted(idx)])
        if not picks:
            self.use_fitted = True
            return
        P = np.vstack(picks)
        exact = self.mode.noise_batch(P)
        scale = 1.0 + float(np.abs(exact).max(initial=0.0))
        self.use_fitted = bool(np.allclose(fitted(P), exact, rtol=1e-8, atol=1e-10 * scale))

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """``n(x)`` at samples ``X`` (S, n): shape (S, p, q) (:meth:`check` first)."""
        if self.use_fitted:
            return self.fitted(X)
        return self.mode.noise_batch(X)


@dataclass
class LoopStep:
    """One step of the closed loop around the plan, as a map on samples of ``z = (delta, eta[, dP])``.

    The moment propagation (:func:`~idstlpy.closed_loop.propagate`) linearises the clip of the corrected input
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
    # A state-dependent sensor, per sample (closure "particles"): its noise factor on samples,
    # the plan's next mean, C, the process covariance and the nominal filter covariances P_k, P_{k+1}.
    noise: SensorDraw | None = None
    m_next: np.ndarray | None = None
    C: np.ndarray | None = None
    Qp: np.ndarray | None = None
    P_prev: np.ndarray | None = None
    P_next: np.ndarray | None = None
    # The projection on a control domain that is not a box (the executor's own,
    # :func:`~idstlpy.tracking.control_projector`); a box is ``low``/``high``.
    project: Callable[[np.ndarray], np.ndarray] | None = None

    def advance(self, Z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Samples (S, D) of ``z_k`` -> samples of ``z_{k+1}`` (fresh noise from ``rng``).

        With a :class:`SensorDraw` the sensor noise is drawn at each sample's true state,
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
        if self.project is not None:
            y = self.project(y)
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
        X_true = m_next + delta_n
        per_sample = Z.shape[1] > 2 * n and self.P_prev is not None and self.P_next is not None
        if noise.use_fitted is None:
            noise.check(X_true, m_next + eta_pred) if per_sample else noise.check(X_true)
        nx = noise(X_true)  # (S, p, q): the sensor at the true state
        nu = (nx @ rng.standard_normal((S, nx.shape[2], 1)))[:, :, 0]
        out = np.empty_like(Z)
        out[:, :n] = delta_n
        if not per_sample:
            innov = (delta_n - eta_pred) @ C.T + nu
            out[:, n : 2 * n] = eta_pred + innov @ self.Lk.T
            if Z.shape[1] > 2 * n:
                out[:, 2 * n :] = Z[:, 2 * n :]
            return out
        Pk = self.P_prev + Z[:, 2 * n :].reshape(S, n, n)
        P_pred = self.A @ Pk @ self.A.T + self.Qp
        nf = noise(m_next + eta_pred)  # the filter's R at its own predicted mean
        R = nf @ np.swapaxes(nf, 1, 2)
        PCt = P_pred @ C.T  # (S, n, p)
        Sinn = C @ PCt + R  # (S, p, p)
        Lg = batched_gain(PCt, Sinn)
        innov = (delta_n - eta_pred) @ C.T + nu
        out[:, n : 2 * n] = eta_pred + (Lg @ innov[:, :, None])[:, :, 0]
        IKC = np.eye(n) - Lg @ C
        P_new = IKC @ P_pred @ np.swapaxes(IKC, 1, 2) + Lg @ R @ np.swapaxes(Lg, 1, 2)
        out[:, 2 * n :] = (0.5 * (P_new + np.swapaxes(P_new, 1, 2)) - self.P_next).reshape(S, n * n)
        return out


def batched_gain(PCt: np.ndarray, S: np.ndarray) -> np.ndarray:
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
class ParticleCloud:
    """The particles of ``closure="particles"`` (:func:`idstlpy.closed_loop.propagate`): the
    samples, their mean, centred samples and covariance, carried from one step to the next."""

    Zp: np.ndarray
    zc: np.ndarray
    Xc: np.ndarray
    Sp: np.ndarray
    particles: int

    @staticmethod
    def start(
        z0: np.ndarray, S0: np.ndarray, D: int, particles: int, rng: np.random.Generator
    ) -> ParticleCloud:
        """``particles`` samples of ``z`` (``D`` coordinates) around ``z0`` (2n,) with the covariance
        ``S0``, shifted to the exact mean (the coordinates past ``2n`` start at 0)."""
        n = z0.shape[0] // 2
        Zp = np.zeros((particles, D))
        Zp[:, : 2 * n] = z0 + rng.standard_normal((particles, 2 * n)) @ sqrt_psd(S0).T
        Zp[:, : 2 * n] += z0 - Zp[:, : 2 * n].mean(axis=0)  # the exact mean
        zc = Zp.mean(axis=0)
        Xc = Zp - zc
        return ParticleCloud(Zp, zc, Xc, Xc.T @ Xc / particles, particles)

    def predicted_eta(
        self,
        mode: LCS,
        Kt: np.ndarray,
        v: np.ndarray,
        box: tuple[np.ndarray, np.ndarray] | None,
        n: int,
        project: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> np.ndarray:
        """The samples' mean filter prediction deviation, before ``- r`` (inputs clipped to
        ``box`` or projected by ``project``)."""
        y_p = v - self.Zp[:, n : 2 * n] @ Kt.T
        if box is not None:
            y_p = np.clip(y_p, box[0], box[1])
        elif project is not None:
            y_p = project(y_p)
        out: np.ndarray = (self.Zp[:, n : 2 * n] @ mode.A.T + (y_p - v) @ mode.B.T).mean(axis=0)
        return out

    def advance(
        self, step: LoopStep, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Push the samples through ``step``: their moments ``z, S`` and the statistical linear
        regression ``F, g, Q`` of ``z_{k+1}`` on ``z_k``."""
        particles, zc, Xc, Sp = self.particles, self.zc, self.Xc, self.Sp
        Zn = step.advance(self.Zp, rng)
        z = Zn.mean(axis=0)
        Yc = Zn - z
        S = Yc.T @ Yc / particles
        w, V = np.linalg.eigh(0.5 * (Sp + Sp.T))
        keep = w > 1e-12 * max(1.0, float(w.max(initial=0.0)))
        pinv = (V[:, keep] / w[keep]) @ V[:, keep].T
        F = (Yc.T @ Xc / particles) @ pinv  # the statistical linear regression of z_{k+1} on z_k
        g = z - F @ zc
        Qk = S - F @ Sp @ F.T
        self.Zp, self.zc, self.Xc, self.Sp = Zn, z, Yc, S
        return z, S, F, g, Qk
