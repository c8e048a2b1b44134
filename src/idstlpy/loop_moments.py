"""The moments of the executor's closed loop around a plan: :func:`propagate`.

With ``delta_k = x_k - m_k`` the true state's deviation from the plan and ``eta_k = mean_k - m_k``
the executed belief mean's, the joint ``z = (delta, eta[, dP])`` is propagated step by step: its
mean and covariance, the one-step transitions ``F``, offsets ``g`` and noise covariances ``Q``, the
filter covariance, the gains and a bound on the probability that the input is clipped (the
derivation, and what is exact and what is linearised, is in :mod:`idstlpy.executor.predict`).
Under ``closure="particles"`` the moments are those of samples pushed through the loop itself
(:mod:`idstlpy.loop_samples`). :mod:`idstlpy.closed_loop` re-exports everything here.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import ndtr

from ._deadline import check
from .belief import _joseph, kalman_gain
from .dynamical_system import LCS, SwitchedSystem
from .errors import InvalidArgumentError
from .loop_samples import LoopStep, NoiseInterpolant, ParticleCloud, SensorDraw, cubature, sqrt_psd
from .sets import Polytope
from .tracking import box_bounds, control_projector, gain_at
from .trajectory import ProbabilisticTSTrajectory

__all__ = ["ClosedLoopMoments", "prob_le", "propagate", "sqrt_psd", "step_parts"]


def prob_le(mu: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """``P[X <= 0]`` for ``X ~ N(mu, sd^2)``; an indicator when ``sd == 0``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        p = ndtr(-mu / sd)
    return np.where(sd > 0, p, (mu <= 0).astype(float))


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


_SQRT_2PI = np.sqrt(2 * np.pi)


def _clipped_moments(
    mu: np.ndarray, sd: np.ndarray, low: np.ndarray, high: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Moments of ``clip(Y_i, low_i, high_i)`` for ``Y_i ~ N(mu_i, sd_i^2)``, each shape (m,).

    Returns the mean, the variance and ``P[low_i < Y_i < high_i]`` (the expected derivative of the
    clip: by Stein's lemma ``Cov(z, clip(Y_i)) = P_in Cov(z, Y_i)`` for any ``z`` jointly Gaussian
    with ``Y``).
    """
    pos = sd > 0
    if not pos.any():  # no spread (an estimate the loop has not perturbed yet): the clip itself
        return np.clip(mu, low, high), np.zeros(mu.shape), ((mu > low) & (mu < high)).astype(float)
    if pos.all():
        with np.errstate(invalid="ignore", divide="ignore"):
            X = (np.stack((low, high)) - mu) / sd  # (a, b)
        if np.isfinite(X).all():
            # A box with both bounds and a spread on every input (the usual case): the general
            # expressions below without their guards, per input on Python floats (a handful of
            # inputs: numpy's per-call cost would dominate). Elementwise IEEE operations either
            # way, squares as products: the same numbers.
            Fx, Px = ndtr(X).tolist(), (np.exp(-0.5 * X**2) / _SQRT_2PI).tolist()
            e1s, vs, ps = [], [], []
            for lo, hi, m_i, s, a, b, Fa, Fb, pa, pb in zip(
                low.tolist(), high.tolist(), mu.tolist(), sd.tolist(), *X.tolist(), *Fx, *Px, strict=True
            ):
                p_in, F_up, dp, s2 = Fb - Fa, 1 - Fb, pa - pb, s * s
                e1 = lo * Fa + hi * F_up + m_i * p_in + s * dp
                e2 = (
                    lo * lo * Fa
                    + hi * hi * F_up
                    + (m_i * m_i + s2) * p_in
                    + 2 * m_i * s * dp
                    + s2 * (a * pa - b * pb)
                )
                e1s.append(e1)
                vs.append(max(e2 - e1 * e1, 0.0))
                ps.append(p_in)
            return np.array(e1s), np.array(vs), np.array(ps)
    s = np.where(pos, sd, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = (low - mu) / s
        b = (high - mu) / s
    Fa, Fb = ndtr(a), ndtr(b)
    pa = np.where(np.isfinite(a), np.exp(-0.5 * np.where(np.isfinite(a), a, 0.0) ** 2), 0.0) / _SQRT_2PI
    pb = np.where(np.isfinite(b), np.exp(-0.5 * np.where(np.isfinite(b), b, 0.0) ** 2), 0.0) / _SQRT_2PI
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
    the clip, ``F, g, Q`` their statistical linear regression); ``unmodelled_projection``: the
    inputs are projected on a control domain that is not a box and the moments (Gaussian
    closure) are those of the loop without the projection (``clip`` bounds, per step, the
    probability that it acts; ``steps`` apply it).
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
    unmodelled_projection: bool = False


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
        From :func:`idstlpy.closed_loop.real_modes_for`.
    gains : dict
        From :func:`idstlpy.closed_loop.gains_for`.
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
        kept. Under a control domain that is not a box, the Gaussian closure's moments are the
        unprojected loop's (:attr:`ClosedLoopMoments.unmodelled_projection`; the particles and
        the steps project each sample as the executor does). ``"auto"``: particles under a
        state-dependent sensor or when the control domain (a box or any polytope) takes the
        input with probability above 1% at some step, the Gaussian closure otherwise.
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
    used = {int(q) for q in plan.get_action()[:N]}
    state_dependent = any(system.mode(q).p and system.mode(q).has_state_dependent_noise for q in used)
    if closure not in ("auto", "gaussian", "particles"):
        raise InvalidArgumentError(f"closure must be 'auto', 'gaussian' or 'particles', got {closure!r}")
    if closure == "auto":
        if N == 0:
            closure = "gaussian"
        elif state_dependent:
            closure = "particles"
        elif domain is None:
            closure = "gaussian"
        else:
            first = propagate(
                system, plan, N, real_modes, gains, process_noise, z0, S0, P0, sensor_noise, domain,
                filter_sensitivity, "gaussian",
            )  # fmt: skip
            if float(first.clip.max()) <= 0.01:
                return first
            closure = "particles"
    sens = filter_sensitivity and state_dependent
    # a polytope that is not a box: the executor's projection, applied to every sample
    project = control_projector(domain, m) if domain is not None and box is None else None
    run = _Run(
        system, plan, real_modes, gains, process_noise, sensor_noise, domain, box, sens,
        2 * n + (n * n if sens else 0), closure == "particles" and N > 0, particles,
        cubature(n) if sensor_noise == "expected" else None, np.random.default_rng(seed), project,
    )  # fmt: skip
    if (
        N > 0
        and not run.use_particles
        and run.D == 2 * n
        and (sensor_noise == "plan" or not state_dependent)
        and (fast := run.batched(N, z0, S0, P0)) is not None
    ):
        return fast
    out = run.moments(N, z0, S0, P0)
    z, S, P = out.mean[0], out.cov[0], P0
    cloud = ParticleCloud.start(z0, S0, run.D, run.particles, run.rng) if run.use_particles else None
    for k in range(N):
        check("predicting a plan's execution")  # a solve's time limit (no-op outside a solve)
        z, S, P = run.step(out, k, z, S, P, cloud)
    return out


@dataclass
class _Run:
    """The settings one propagation reads at every step (checked by :func:`propagate`)."""

    system: SwitchedSystem
    plan: ProbabilisticTSTrajectory
    real_modes: Sequence[LCS]
    gains: Mapping[int, Sequence[np.ndarray]]
    process_noise: str
    sensor_noise: str
    domain: Polytope | None
    box: tuple[np.ndarray, np.ndarray] | None
    sens: bool  # the filter-sensitivity coordinates are carried
    D: int  # the joint state's dimension
    use_particles: bool
    particles: int
    cub: tuple[np.ndarray, np.ndarray] | None  # the cubature of sensor_noise="expected"
    rng: np.random.Generator
    project: Callable[[np.ndarray], np.ndarray] | None  # the projection on a non-box domain
    # What does not change within a call, read once (the planner propagates hundreds of loops a
    # solve, each a few dozen steps of small matrices: the per-step overhead is the cost).
    _parts: dict[tuple[int, int], _Parts] = field(init=False, default_factory=dict)
    _plan: tuple[np.ndarray, np.ndarray, np.ndarray] = field(init=False)
    _eye: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self._plan = (self.plan.get_action(), self.plan.get_mean(), self.plan.get_control())
        self._eye = np.eye(self.system.n)

    def parts(self, q: int, remaining: int) -> _Parts:
        """:func:`step_parts` and what follows from them alone, kept per mode and steps left."""
        key = (q, remaining if remaining < _horizon(self.gains[q]) else -1)
        kept = self._parts.get(key)
        if kept is None:
            mode, real_or_none, Kt, W = step_parts(
                self.system, self.real_modes, self.gains, self.process_noise, q, remaining
            )
            like = next((pt for (q2, _), pt in self._parts.items() if q2 == q), None)
            kept = self._parts[key] = _Parts.of(mode, real_or_none, Kt, W, self.system.n, like)
        return kept

    def moments(self, N: int, z0: np.ndarray, S0: np.ndarray, P0: np.ndarray) -> ClosedLoopMoments:
        """The result's arrays, the start filled in."""
        n, m, D = self.system.n, self.system.m, self.D
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
            sensitivity=self.sens,
        )
        out.mean[0, : 2 * n], out.cov[0, : 2 * n, : 2 * n], out.P[0] = z0, S0, P0
        out.closure = "particles" if self.use_particles else "gaussian"
        out.unmodelled_projection = self.project is not None and not self.use_particles
        out.steps = []
        return out

    def batched(self, N: int, z0: np.ndarray, S0: np.ndarray, P0: np.ndarray) -> ClosedLoopMoments | None:
        """:meth:`step` ``N`` times, what does not depend on the loop's moments at once.

        For the Gaussian closure without the sensitivity coordinates, the sensor noise read at the
        plan (or constant): the filter then does not depend on the loop, nor (without a control
        domain) do ``F``, ``g`` and ``Q``; only the moments' recursion (and the clip's
        linearisation) is stepped. The same operations as :meth:`step` on the same operands
        (batched matrix products are the per-matrix ones), so the same numbers; None when the loop
        diverges (:meth:`step` then finds where, and says so).
        """
        n, D = self.system.n, self.D
        eye = self._eye
        actions, means, controls = self._plan
        total = self.plan.num_of_steps
        parts = [self.parts(int(q), total - k) for k, q in enumerate(actions[:N].tolist())]
        A = np.stack([pt.mode.A for pt in parts])
        B = np.stack([pt.mode.B for pt in parts])
        Ar = np.stack([pt.real.A for pt in parts])
        Br = np.stack([pt.real.B for pt in parts])
        Kt = np.stack([pt.K for pt in parts])
        m_k, m_next, v = means[:N], means[1 : N + 1], controls[:N]
        nominal = (A @ m_k[:, :, None])[:, :, 0] + (B @ v[:, :, None])[:, :, 0]
        r = m_next - nominal
        d = (Ar @ m_k[:, :, None])[:, :, 0] + (Br @ v[:, :, None])[:, :, 0] - m_next
        # the filter, at the plan's nominal prediction: kept across calls (the planner's
        # candidates share their start and runs of modes), keyed by its inputs' content
        Ps, Ls, LCs, LRLs, roots = [P0], [], [], [], []
        P = P0
        node = _FILTERS.root(P0)
        mode_keys: dict[int, tuple[Any, ...]] = {}
        try:
            for k, pt in enumerate(parts):
                mode = pt.mode
                mk = mode_keys.get(id(mode))
                if mk is None:
                    C = mode.C if mode.p else np.zeros((0, n))
                    mk = mode_keys[id(mode)] = (
                        mode.A.shape,
                        mode.A.tobytes(),
                        mode.process_cov.tobytes(),
                        C.shape,
                        C.tobytes(),
                    )
                R_f = R_t = pt.zero_p
                key: tuple[Any, ...] = mk
                if mode.p:
                    R_f, R_t = mode.noise_cov(nominal[k]), mode.noise_cov(m_next[k])
                    key = (mk, R_f.tobytes(), R_t.tobytes())
                hit = node.get(key)
                if hit is None:
                    Lk, P_next, LC = _filter(mode, P, nominal[k], n, eye, R_f)
                    LRL = Lk @ R_t @ Lk.T if mode.p else None
                    hit = node[key] = ((Lk, P_next, LC, LRL, pt.sensor_root(R_t)), {})
                    _FILTERS.added(hit[0])
                (Lk, P, LC, LRL, root), node = hit
                Ps.append(P)
                Ls.append(Lk)
                LCs.append(LC)
                LRLs.append(LRL)
                roots.append(root)
        except np.linalg.LinAlgError:
            return None
        Pst = np.stack(Ps)
        if not np.isfinite(Pst.sum()):
            return None
        LC = np.stack(LCs)
        ILC = eye - LC
        LCAr = LC @ Ar
        Gw = np.zeros((N, D, n))
        Gw[:, :n] = eye
        Gw[:, n:] = LC
        Qw = np.stack([pt.Qw for pt in parts])
        Q0 = Gw @ Qw @ np.swapaxes(Gw, 1, 2)  # the process noise's part of Q
        out = self.moments(N, z0, S0, P0)
        out.P[1:] = Pst[1:]
        out.K[:] = Kt
        out.L = Ls
        F, g = out.F, out.g
        F[:, :n, :n] = Ar
        if self.box is None and self.domain is None:  # F, g and Q do not depend on the loop
            BrK = Br @ Kt
            F[:, :n, n:] = -BrK
            F[:, n:, :n] = LCAr
            F[:, n:, n:] = ILC @ np.stack([pt.A_eta for pt in parts]) - LC @ BrK
            g[:, :n] = d
            g[:, n:] = (ILC @ -r[:, :, None])[:, :, 0] + (LC @ d[:, :, None])[:, :, 0]
            Q = Q0
        else:
            Ge = np.zeros((N, D, B.shape[2]))
            Ge[:, :n] = Br
            Ge[:, n:] = ILC @ B + LC @ Br
            Q = np.empty_like(Q0)
        z, S = out.mean[0], out.cov[0]
        for k in range(N):
            if Q is not Q0:  # the clip's linearisation at this step's moments
                K_eff, c_u, E, out.clip[k] = _input(
                    Kt[k], v[k], z[n:], S[n:, n:], self.box, self.domain, self.system.m
                )
                BrK = Br[k] @ K_eff
                F[k, :n, n:] = -BrK
                F[k, n:, :n] = LCAr[k]
                F[k, n:, n:] = ILC[k] @ (A[k] - B[k] @ K_eff) - LC[k] @ BrK
                drift = Br[k] @ c_u + d[k]
                g[k, :n] = drift
                g[k, n:] = ILC[k] @ (B[k] @ c_u - r[k]) + LC[k] @ drift
                Q[k] = Q0[k] + Ge[k] @ E @ Ge[k].T
            z = F[k] @ z + g[k]
            S_pre = F[k] @ S @ F[k].T + Q[k]
            if LRLs[k] is not None:
                S_pre[n:, n:] += LRLs[k]
            S = 0.5 * (S_pre + S_pre.T)
            if not np.isfinite(z.sum() + S.sum()):
                return None
            out.mean[k + 1], out.cov[k + 1] = z, S
        for k, LRL in enumerate(LRLs):
            if LRL is not None:
                Q[k, n:, n:] += LRL
        out.Q[:] = 0.5 * (Q + np.swapaxes(Q, 1, 2))
        low, high = (None, None) if self.box is None else self.box
        out.steps = [
            LoopStep(
                K=pt.K, v=v[k], low=low, high=high, Ar=pt.real.A, Br=pt.real.B, A=pt.mode.A,
                B=pt.mode.B, d=d[k], r=r[k], LC=LCs[k], Lk=Ls[k], W_root=pt.W_root, R_root=roots[k],
                sens=None, project=self.project,
            )
            for k, pt in enumerate(parts)
        ]  # fmt: skip
        return out

    def step(
        self,
        out: ClosedLoopMoments,
        k: int,
        z: np.ndarray,
        S: np.ndarray,
        P: np.ndarray,
        cloud: ParticleCloud | None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Step ``k``: linearise the loop at the moments ``z, S`` (the samples' under particles),
        record it in ``out`` and return the next moments and filter covariance."""
        n, m = self.system.n, self.system.m
        actions, means, controls = self._plan
        q = int(actions[k])
        parts = self.parts(q, self.plan.num_of_steps - k)
        mode, real, Kt, state_dep = parts.mode, parts.real, parts.K, parts.state_dep
        v = controls[k]
        m_k, m_next = means[k], means[k + 1]
        if cloud is not None:  # the moments the linearisation below is taken at are the samples'
            z, S = cloud.zc, cloud.Sp
        eta = z[n : 2 * n]
        nominal_pred = mode.A @ m_k + mode.B @ v
        r = m_next - nominal_pred
        d = real.A @ m_k + real.B @ v - m_next
        if self.box is None and self.domain is None:  # the input is never clipped
            K_eff, c_u, E, clip, A_eta = Kt, parts.zero_m, None, 0.0, parts.A_eta
        else:
            K_eff, c_u, E, clip = _input(Kt, v, eta, S[n : 2 * n, n : 2 * n], self.box, self.domain, m)
            A_eta = parts.A_eta if self.box is None else mode.A - mode.B @ K_eff
        out.clip[k] = clip
        # Filter: its noise is evaluated at its own (random) predicted mean, linearised at the plan's
        # nominal one ("plan": the plan's MLO covariances) or at the predicted one (otherwise).
        plan_point = self.sensor_noise == "plan" or not state_dep
        if plan_point:
            x_lin = nominal_pred
        else:
            # The filter's predicted mean is m_next + eta_pred, eta_pred = A_eta eta + B c_u - r + B e.
            eta_pred_mean = A_eta @ eta + mode.B @ c_u - r
            if cloud is not None:
                eta_pred_mean = cloud.predicted_eta(mode, Kt, v, self.box, n, self.project) - r
            x_lin = m_next + eta_pred_mean
        Lk, P_next, LC = _filter(mode, P, x_lin, n, self._eye)
        lin = _Linear(mode, real, K_eff, c_u, E, r, d, LC, Lk, A_eta, m_next, x_lin, state_dep)
        F, g, J = lin.transition(self.D, self.sens, self._eye)
        Qw = parts.Qw
        Qk = lin.noise(Qw)
        z = F @ z + g
        S_pre = F @ S @ F.T + Qk
        noise = None  # the sensor's noise factor, for samples drawing it at their own state
        if cloud is not None and state_dep and mode.p:
            noise = SensorDraw(mode, NoiseInterpolant.fit(mode, m_next + z[:n], S_pre[:n, :n]))
        R_true = parts.zero_p
        if mode.p:
            R_true = self.sensor_cov(mode, state_dep, m_next, z[:n], S_pre[:n, :n])
            LRL = Lk @ R_true @ Lk.T
            Qk[n : 2 * n, n : 2 * n] += LRL  # Qk and S_pre are this step's own arrays
            S_pre[n : 2 * n, n : 2 * n] += LRL
        S = 0.5 * (S_pre + S_pre.T)
        step = lin.loop_step(Kt, v, self.box, F, J, parts, R_true, self.sens)
        step.project = self.project
        if noise is not None:
            step.noise = noise
            step.m_next, step.C, step.Qp = m_next, mode.C, mode.process_cov
            step.P_prev, step.P_next = P, P_next
        out.steps.append(step)  # type: ignore[union-attr]
        if cloud is not None:
            z, S, F, g, Qk = cloud.advance(step, self.rng)
        P = P_next
        # (a finite sum has finite terms; only a non-finite one needs the elementwise look)
        if not np.isfinite(z.sum() + S.sum() + P.sum()) and not (
            np.all(np.isfinite(z)) and np.all(np.isfinite(S)) and np.all(np.isfinite(P))
        ):
            raise InvalidArgumentError(
                f"the predicted closed loop diverged at step {k + 1} (non-finite moments)"
            )
        out.mean[k + 1], out.cov[k + 1], out.P[k + 1] = z, S, P
        out.F[k], out.g[k], out.Q[k], out.K[k] = F, g, 0.5 * (Qk + Qk.T), Kt
        out.L.append(Lk)
        return z, S, P

    def sensor_cov(
        self,
        mode: LCS,
        state_dep: bool,
        m_next: np.ndarray,
        delta: np.ndarray,
        S_delta: np.ndarray,
    ) -> np.ndarray:
        """The sensor noise covariance acting on the loop, ``R`` at the true state (``delta``: its
        predicted mean deviation, ``S_delta`` its covariance) as ``sensor_noise`` reads it."""
        if self.sensor_noise == "plan" or not state_dep:
            return mode.noise_cov(m_next)
        if self.sensor_noise == "mean":
            return mode.noise_cov(m_next + delta)
        pts, w = self.cub  # type: ignore[misc]
        xs = m_next + delta + pts @ sqrt_psd(S_delta).T
        # the noise factor directly: R(x) = n(x) n(x)' without noise_cov's per-call checks
        # (a non-finite factor makes the moments non-finite, caught below)
        nxs = np.stack([mode.noise(xi) for xi in xs])
        out: np.ndarray = np.einsum("g,gpq,grq->pr", w, nxs, nxs)
        return out


def _input(
    Kt: np.ndarray,
    v: np.ndarray,
    eta: np.ndarray,
    S_eta: np.ndarray,
    box: tuple[np.ndarray, np.ndarray] | None,
    domain: Polytope | None,
    m: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The input: ``u - v = c_u - K_eff eta + e``, the statistical linearisation of the clip
    (``e`` uncorrelated with the loop, covariance ``E``), and the bound on the probability that
    the input is clipped (0 without a domain)."""
    if box is not None:
        mu_y = v - Kt @ eta
        sd_y = np.sqrt(np.maximum((Kt @ S_eta @ Kt.T).diagonal(), 0.0))
        e1, var, p_in = _clipped_moments(mu_y, sd_y, box[0], box[1])
        K_eff = p_in[:, None] * Kt
        return (
            K_eff,
            e1 - v + K_eff @ eta,
            np.diag(np.maximum(var - p_in**2 * sd_y**2, 0.0)),
            min(1.0, float((1.0 - p_in).sum())),
        )
    K_eff, c_u, E, clip = Kt, np.zeros(m), np.zeros((m, m)), 0.0
    if domain is not None:  # a general polytope: the projection is not modelled, only bounded
        mu_y = v - Kt @ eta
        HK = domain.H @ Kt
        sd_f = np.sqrt(np.maximum(np.einsum("fi,ij,fj->f", HK, S_eta, HK), 0.0))
        clip = min(1.0, float(np.sum(1.0 - prob_le(domain.H @ mu_y + domain.c, sd_f))))
    return K_eff, c_u, E, clip


def _filter(
    mode: LCS, P: np.ndarray, x_lin: np.ndarray, n: int, eye: np.ndarray, R: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The filter's step at the linearisation point ``x_lin``: Kalman gain, covariance, ``L C``
    (:func:`~idstlpy.belief.kalman_update`'s covariance, its gain computed once); ``R``: the
    sensor's noise there, when the caller has it."""
    P_pred = mode.A @ P @ mode.A.T + mode.process_cov
    if mode.p:
        R_filter = mode.noise_cov(x_lin) if R is None else R
        Lk = kalman_gain(mode.C, P_pred, R_filter)
        return Lk, _joseph(Lk, mode.C, P_pred, R_filter), Lk @ mode.C
    return np.zeros((n, 0)), 0.5 * (P_pred + P_pred.T), np.zeros((n, n))


class _FilterCache:
    """The filter's steps (gain, covariance, ``L C``, ``L R L'``, the sensor noise's root) as a
    trie per prior covariance, each step keyed by the content of what it reads (the mode's
    ``A``, process covariance and ``C``, the sensor's noise at the step); read-only arrays.
    Cleared whole past :attr:`KEPT` steps."""

    KEPT = 10_000  # (about 1 kB a step)

    def __init__(self) -> None:
        self.tries: dict[bytes, dict[Any, Any]] = {}
        self.count = 0

    def root(self, P0: np.ndarray) -> dict[Any, Any]:
        key = np.asarray(P0.shape).tobytes() + P0.tobytes()
        node = self.tries.get(key)
        if node is None:
            node = self.tries[key] = {}
        return node

    def added(self, arrays: tuple[np.ndarray | None, ...]) -> None:
        for a in arrays:
            if a is not None:
                a.flags.writeable = False
        self.count += 1
        if self.count > self.KEPT:
            self.tries.clear()
            self.count = 0


_FILTERS = _FilterCache()


def _horizon(gains: Sequence[np.ndarray]) -> int:
    """The steps left from which :func:`~idstlpy.tracking.gain_at` gives ``K_0``."""
    return len(gains)


@dataclass
class _Parts:
    """A mode's step parts (:func:`step_parts`) and what follows from them alone."""

    mode: LCS
    real: LCS
    K: np.ndarray  # the tracking gain
    Qw: np.ndarray  # the process noise's covariance (zero without one)
    W_root: np.ndarray  # its root, (n, 0) without one
    A_eta: np.ndarray  # A - B K: the estimate's deviation, the input unclipped
    state_dep: bool  # a sensor whose noise depends on the state
    zero_m: np.ndarray  # (read-only zeros)
    zero_p: np.ndarray
    R_root: list[np.ndarray]  # the root of a constant sensor noise, once asked for (shared by the mode)

    @staticmethod
    def of(
        mode: LCS, real: LCS | None, K: np.ndarray, W: np.ndarray | None, n: int, like: _Parts | None
    ) -> _Parts:
        """The parts of a step in ``mode``; ``like``: another gain's parts of the same mode."""
        if like is None:
            Qw = W @ W.T if W is not None and W.shape[1] else np.zeros((n, n))
            zero_m, zero_p = np.zeros(mode.m), np.zeros((mode.p, mode.p))
            zero_m.flags.writeable = zero_p.flags.writeable = False
            W_root, R_root = sqrt_psd(Qw) if Qw.any() else np.zeros((n, 0)), []
        else:
            Qw, W_root, zero_m, zero_p, R_root = like.Qw, like.W_root, like.zero_m, like.zero_p, like.R_root
        return _Parts(
            mode, mode if real is None else real,  # (never None: real_modes is a list)
            K, Qw, W_root, mode.A - mode.B @ K, bool(mode.p) and mode.has_state_dependent_noise,
            zero_m, zero_p, R_root,
        )  # fmt: skip

    def sensor_root(self, R: np.ndarray) -> np.ndarray:
        """The root of the sensor noise ``R`` acting at this step (kept when it is constant)."""
        if not self.mode.p:
            return np.zeros((0, 0))
        if self.state_dep:
            return sqrt_psd(R)
        if not self.R_root:
            self.R_root.append(sqrt_psd(R))
        return self.R_root[0]


@dataclass
class _Linear:
    """One step of the loop, linearised: ``z_{k+1} = F z_k + g + noise`` (module notes)."""

    mode: LCS
    real: LCS
    K_eff: np.ndarray
    c_u: np.ndarray
    E: np.ndarray | None  # None: the input is not clipped (c_u = 0, E = 0)
    r: np.ndarray
    d: np.ndarray
    LC: np.ndarray
    Lk: np.ndarray
    A_eta: np.ndarray
    m_next: np.ndarray
    x_lin: np.ndarray
    state_dep: bool
    Gw: np.ndarray = field(init=False)  # how the process noise enters
    Ge: np.ndarray = field(init=False)  # how the clipping residual enters

    def transition(
        self, D: int, sens: bool, I: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``F``, ``g`` and the sensitivity's ``J`` (None unless a state-dependent sensor's
        sensitivity is carried); ``I`` the identity (n, n)."""
        A, B, Ar, Br = self.mode.A, self.mode.B, self.real.A, self.real.B
        n, m = A.shape[0], B.shape[1]
        LC, K_eff, c_u, r = self.LC, self.K_eff, self.c_u, self.r
        ILC = I - LC
        BrK = Br @ K_eff
        F = np.zeros((D, D))
        F[:n, :n] = Ar
        F[:n, n : 2 * n] = -BrK
        F[n : 2 * n, :n] = LC @ Ar
        F[n : 2 * n, n : 2 * n] = ILC @ self.A_eta - LC @ BrK
        g = np.zeros(D)
        if self.E is None:  # the input unclipped: c_u = 0
            drift = self.d
            g[n : 2 * n] = ILC @ -r + LC @ drift
        else:
            drift = Br @ c_u + self.d
            g[n : 2 * n] = ILC @ (B @ c_u - r) + LC @ drift
        g[:n] = drift
        self.Gw = np.zeros((D, n))
        self.Gw[:n] = I
        self.Gw[n : 2 * n] = LC
        self.Ge = np.zeros((D, m))
        if self.E is not None:
            self.Ge[:n] = Br
            self.Ge[n : 2 * n] = ILC @ B + LC @ Br
        J = None
        if sens:
            self.Ge[:n] = Br
            self.Ge[n : 2 * n] = ILC @ B + LC @ Br
            Phi = ILC @ A
            F[2 * n :, 2 * n :] = np.kron(Phi, Phi)
            if self.state_dep:
                dR = _noise_cov_jacobian(self.mode, self.x_lin)
                Lk = self.Lk
                J = np.stack([(Lk @ dR[i] @ Lk.T).reshape(-1) for i in range(n)], axis=1)  # (n^2, n)
                F[2 * n :, n : 2 * n] = J @ self.A_eta
                g[2 * n :] = J @ (B @ c_u - r - (self.x_lin - self.m_next))
                self.Ge[2 * n :] = J @ B
        return F, g, J

    def noise(self, Qw: np.ndarray) -> np.ndarray:
        """The covariance of the process noise and of the clipping residual (``transition`` first)."""
        Qk: np.ndarray = self.Gw @ Qw @ self.Gw.T
        if self.E is not None:
            Qk += self.Ge @ self.E @ self.Ge.T
        return Qk

    def loop_step(
        self,
        Kt: np.ndarray,
        v: np.ndarray,
        box: tuple[np.ndarray, np.ndarray] | None,
        F: np.ndarray,
        J: np.ndarray | None,
        parts: _Parts,
        R_true: np.ndarray,
        sens: bool,
    ) -> LoopStep:
        """The step as a map on samples (:class:`~idstlpy.loop_samples.LoopStep`)."""
        n = self.mode.A.shape[0]
        sens_map = None
        if sens:
            sens_map = (F[2 * n :, 2 * n :], J if J is not None else np.zeros((n * n, n)),
                        (self.x_lin - self.m_next) if self.state_dep else np.zeros(n))  # fmt: skip
        return LoopStep(
            K=Kt, v=v, low=None if box is None else box[0], high=None if box is None else box[1],
            Ar=self.real.A, Br=self.real.B, A=self.mode.A, B=self.mode.B, d=self.d, r=self.r,
            LC=self.LC, Lk=self.Lk,
            W_root=parts.W_root, R_root=parts.sensor_root(R_true), sens=sens_map,
        )  # fmt: skip
