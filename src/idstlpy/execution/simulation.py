"""Execute a plan against a real system: Kalman filter plus receding-horizon LQR tracking.

One execution step ``k`` (plan mode ``q = q_k``, plan mean ``m_k``, plan control ``v_k``)::

    u_k      = proj_U( v_k - K (mean_k - m_k) )                  (LQR correction, K from mode q)
    x_{k+1}  = A^real x_k + B^real u_k + W_q w_k,                 w_k ~ N(0, I)
    y_{k+1}  = C_q x_{k+1} + n_q(x_{k+1}) v_{k+1},                v_{k+1} ~ N(0, I)
    mean, cov <- Kalman(predict with mode q and u_k, update with y_{k+1}, noise at predicted mean)

The real system moves the *true* state ``x`` with its own matrices; the observation is drawn
from the *planning* model's sensor at the true state (the real system of the paper has no
sensor); the filter only knows the planning model, so it evaluates the noise function at its
own predicted mean. ``K`` is ``K_0`` of the mode's finite-horizon gains (receding horizon),
``K_j`` when only ``h - j`` plan steps remain.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any, Literal

import numpy as np

from .._checks import as_int, as_vector
from ..belief import GaussianBelief, kalman_update, predict
from ..closed_loop import real_modes_for
from ..dynamical_system import SwitchedSystem
from ..errors import DimensionError, InvalidArgumentError, InvalidTypeError
from ..sets import Polytope
from ..tracking import control_projector, gain_at, system_gains
from ..trajectory import ProbabilisticTSTrajectory, RealTrajectory

__all__ = ["simulate"]

ProcessNoise = Literal["model", "real", "none"]

logger = logging.getLogger(__name__)


def simulate(
    system: SwitchedSystem,
    reference_trajectory: ProbabilisticTSTrajectory,
    num_of_steps: int,
    real_initial_state: Any,
    real_system: SwitchedSystem,
    seed: int | np.random.Generator | np.random.SeedSequence | None = None,
    *,
    control_domain: Polytope | None = None,
    process_noise: ProcessNoise = "model",
    lqr_gains: Mapping[int, Sequence[np.ndarray]] | Sequence[Sequence[np.ndarray] | None] | None = None,
    default_lqr: Mapping[str, Any] | None = None,
    initial_belief: GaussianBelief | None = None,
) -> tuple[ProbabilisticTSTrajectory, RealTrajectory]:
    """Execute a plan on a real system with a Kalman filter and receding-horizon LQR tracking.

    Parameters
    ----------
    system : SwitchedSystem
        The planning model (its sensors and noise drive the observations and the filter).
    reference_trajectory : ProbabilisticTSTrajectory
        The plan (``Problem.solve``'s result) with ``N`` steps, state dimension ``n``.
    num_of_steps : int
        Steps to execute, ``0 <= num_of_steps <= N``.
    real_initial_state : array_like, shape (n,)
        True initial state.
    real_system : SwitchedSystem
        The system that moves the true state (one mode per planning mode, or a single mode).
    seed : int, Generator or SeedSequence, optional
        Randomness of the disturbances and measurement noises; the same seed gives the same run.
    control_domain : Polytope, optional
        Admissible inputs (shape ``m``); the corrected input is projected on it. ``None``
        (the paper's listing) applies it unclipped.
    process_noise : {"model", "real", "none"}
        Disturbance added to the true state: the planning mode's ``W w`` (default), the real
        mode's ``W w``, or none.
    lqr_gains : mapping or sequence, optional
        Per planning mode, a list of gains (m, n) overriding ``mode.lqr_gains``.
    default_lqr : mapping, optional
        Weights for modes without gains (see :data:`DEFAULT_LQR`).
    initial_belief : GaussianBelief, optional
        Filter prior; default the plan's first belief.

    Returns
    -------
    xi_sim : ProbabilisticTSTrajectory
        The executed belief (filter means (num_of_steps+1, n), covariances, modes, applied inputs).
    xi_real : RealTrajectory
        True states (num_of_steps+1, n), observations (num_of_steps+1, p) with row 0 (and rows
        of unobserved modes) NaN, modes and applied inputs.

    Raises
    ------
    InvalidArgumentError
        When ``reference_trajectory`` is None (no plan) or an option is invalid.
    DimensionError
        When dimensions of the plan, the model and the real system disagree.
    """
    if reference_trajectory is None:
        raise InvalidArgumentError(
            "reference_trajectory is None: there is no plan to execute "
            "(Problem.solve returned None; see problem.last_result.reason)"
        )
    if not isinstance(reference_trajectory, ProbabilisticTSTrajectory):
        raise InvalidTypeError(
            "reference_trajectory must be a ProbabilisticTSTrajectory, "
            f"got {type(reference_trajectory).__name__}"
        )
    if not isinstance(system, SwitchedSystem):
        raise InvalidTypeError(f"system must be a SwitchedSystem, got {type(system).__name__}")
    ref = reference_trajectory
    n, m = system.n, system.m
    if ref.n != n:
        raise DimensionError(f"reference_trajectory has state dimension {ref.n}, the system has n = {n}")
    N_ref = ref.num_of_steps
    N = as_int(num_of_steps, "num_of_steps", minimum=0)
    if N > N_ref:
        raise InvalidArgumentError(
            f"num_of_steps must be <= reference_trajectory.num_of_steps ({N_ref}), got {N}"
        )
    actions = ref.get_action()[:N]
    plan_u = ref.get_control()
    if N and plan_u.shape[1] != m:
        raise DimensionError(
            f"reference_trajectory has inputs of size {plan_u.shape[1]}, the system has m = {m}"
        )
    if N and (actions.min() < 0 or actions.max() >= system.num_modes):
        raise DimensionError(
            f"the plan uses modes {sorted(set(actions.tolist()))}, the system has 0..{system.num_modes - 1}"
        )
    x = as_vector(real_initial_state, "real_initial_state", n)
    real_modes = real_modes_for(real_system, system, actions)
    if process_noise not in ("model", "real", "none"):
        raise InvalidArgumentError(f"process_noise must be 'model', 'real' or 'none', got {process_noise!r}")
    project = control_projector(control_domain, m)
    if isinstance(seed, np.random.Generator):
        rng = seed
    else:
        rng = np.random.default_rng(seed)

    if initial_belief is None:
        mean, cov = ref.get_mean(0).copy(), ref.get_cov(0).copy()
    else:
        if not isinstance(initial_belief, GaussianBelief) or initial_belief.n != n:
            raise DimensionError(f"initial_belief must be a GaussianBelief of dimension {n}")
        mean, cov = initial_belief.mean.copy(), initial_belief.cov.copy()

    gains = system_gains(system, lqr_gains, default_lqr, actions.tolist())
    p_max = max((mode.p for mode in system.system_modes), default=0)

    means = np.empty((N + 1, n))
    covs = np.empty((N + 1, n, n))
    states = np.empty((N + 1, n))
    observations = np.full((N + 1, p_max), np.nan)
    controls = np.empty((N, m))
    means[0], covs[0], states[0] = mean, cov, x
    for k in range(N):
        q = int(actions[k])
        mode = system.mode(q)
        real = real_modes[0] if len(real_modes) == 1 else real_modes[q]
        Ks = gains[q]
        K = gain_at(Ks, N_ref - k)
        u = project(plan_u[k] - K @ (mean - ref.get_mean(k)))
        controls[k] = u
        # True state (real dynamics + disturbance), then the sensor of the planning mode at it.
        x = real.A @ x + real.B @ u
        Wm = mode.W if process_noise == "model" else real.W if process_noise == "real" else None
        if Wm is not None and Wm.shape[1]:
            x = x + Wm @ rng.standard_normal(Wm.shape[1])
        y = None
        if mode.p:
            nx = mode.noise(x)
            y = mode.C @ x + (nx @ rng.standard_normal(nx.shape[1]) if nx.shape[1] else 0.0)
            observations[k + 1, : mode.p] = y
        # Filter: the model's prediction and an update with the received observation.
        mean_pred, P = predict(mode, mean, cov, u)
        mean, cov = kalman_update(mode, mean_pred, P, y=y, x_noise=mean_pred)
        means[k + 1], covs[k + 1], states[k + 1] = mean, cov, x
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(x))):
            raise InvalidArgumentError(f"the execution diverged at step {k + 1} (non-finite state)")
    logger.debug("simulate: %d steps, final error %s", N, states[-1] - means[-1])
    xi_sim = ProbabilisticTSTrajectory(means, covs, actions, controls)
    xi_real = RealTrajectory(states, observations, actions, controls)
    return xi_sim, xi_real
