"""The executor's closed loop around a plan, as a linear-Gaussian process (LQG-MP).

:func:`idstlpy.simulate` tracks a plan with a Kalman filter and the LQR law of
:mod:`idstlpy.tracking`. Around the plan (modes ``q_k``, means ``m_k``, inputs ``v_k``) that loop is
linear: with ``delta_k = x_k - m_k`` the true state's deviation and ``eta_k = mean_k - m_k`` the
executed belief mean's deviation, the joint ``z = (delta, eta)`` is a Gauss-Markov process whose
moments :func:`propagate` computes (the derivation, and what is exact and what is linearised, is
in :mod:`idstlpy.execution.prediction`).

This module is the one home of that propagation: the moments are computed in
:mod:`idstlpy.loop_moments` (:func:`propagate`, re-exported here) and the samples pushed through
the loop in :mod:`idstlpy.loop_samples`; here the executor's inputs are read and the planner's
reading of the loop is kept. It sits in the model layer because two layers
use it: the planner (``guarantee="closed_loop"`` puts the chance constraints on the predicted true
state, :func:`predicted_state`) and the prediction of an execution
(:func:`idstlpy.predict_closed_loop`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .dynamical_system import LCS, SwitchedSystem
from .errors import DimensionError, InvalidTypeError
from .loop_moments import ClosedLoopMoments, prob_le, propagate, step_parts
from .loop_samples import LoopStep, NoiseInterpolant, batched_gain, cubature, sqrt_psd
from .sets import Polytope
from .tracking import box_bounds, mode_gains, plan_fallback, system_gains
from .trajectory import ProbabilisticTSTrajectory

__all__ = [
    "ClosedLoopMoments",
    "LoopStep",
    "NoiseInterpolant",
    "box_bounds",
    "gains_for",
    "predicted_state",
    "projection_left_out",
    "trackable",
    "tracking_backoff",
    "tracking_spread",
    "prob_le",
    "propagate",
    "real_modes_for",
    "step_parts",
    "sqrt_psd",
]

_cubature = cubature  # the names these had here (tests, benchmarks/dims_results.md)
_batched_gain = batched_gain


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
            f"the model has ({system.n}, {system.m}): the real modes' A must be "
            f"({system.n}, {system.n}) and B ({system.n}, {system.m}), got A "
            f"{real_system.mode(0).A.shape} and B {real_system.mode(0).B.shape}"
        )
    modes = list(real_system.system_modes)
    if len(modes) > 1 and actions.size and int(actions.max()) >= len(modes):
        raise DimensionError(
            f"the plan uses mode {int(actions.max())}, real_system has modes 0..{len(modes) - 1} "
            "(give one real mode per planning mode, or a single mode used for all)"
        )
    return modes


def gains_for(
    system: SwitchedSystem,
    actions: np.ndarray,
    lqr_gains: Mapping[int, Sequence[np.ndarray]] | Sequence[Sequence[np.ndarray] | None] | None,
    default_lqr: Mapping[str, Any] | None,
    plan: ProbabilisticTSTrajectory | None = None,
) -> dict[int, list[np.ndarray]]:
    """Tracking gains (:func:`idstlpy.tracking.mode_gains`) of every mode the plan uses.

    Modes without their own gains (and without ``lqr_gains`` / ``default_lqr``) are tracked with
    the gains the plan was made for (:func:`idstlpy.tracking.plan_fallback`), else the defaults.

    Returns
    -------
    dict
        Mode -> list of gains, each shape (m, n).
    """
    fallback = plan_fallback(system, plan)
    if lqr_gains is not None or default_lqr is not None or fallback is not None:
        return system_gains(system, lqr_gains, default_lqr, actions.tolist(), fallback)
    # The defaults depend on the mode's A and B only, and the planner asks for them hundreds of
    # times a solve (every candidate's predicted loop): the Riccati recursions are kept by content.
    out = {}
    for q in sorted({int(a) for a in actions.tolist()}):
        mode = system.mode(q)
        if getattr(mode, "lqr_gains", None) is not None:
            out[q] = mode_gains(mode)
            continue
        key = (mode.A.shape, mode.B.shape, mode.A.tobytes(), mode.B.tobytes())
        kept = _DEFAULT_GAINS.get(key)
        if kept is None:
            kept = _DEFAULT_GAINS[key] = [K.copy() for K in mode_gains(mode)]
            while len(_DEFAULT_GAINS) > _DEFAULT_GAINS_KEPT:
                del _DEFAULT_GAINS[next(iter(_DEFAULT_GAINS))]
        out[q] = [K.copy() for K in kept]  # copies: a caller may change its gains in place
    return out


_DEFAULT_GAINS_KEPT = 64
_DEFAULT_GAINS: dict[tuple[Any, ...], list[np.ndarray]] = {}
"""The default tracking gains by the mode's ``(A, B)`` (content), oldest first."""


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
    gains = gains_for(system, actions, lqr_gains, default_lqr, plan)
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
    sd: np.ndarray = np.sqrt(np.maximum(np.einsum("kfi,kij,kfj->kf", HK, S_eta, HK), 0.0))
    return sd


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


def projection_left_out(
    system: SwitchedSystem,
    plan: ProbabilisticTSTrajectory,
    control_domain: Polytope | None,
    threshold: float = 0.01,
) -> bool:
    """Whether :func:`predicted_state`'s Gaussian closure leaves out a projection that matters.

    On a control domain that is not a box the Gaussian closure's moments are those of the loop
    without the projection (:attr:`~idstlpy.loop_moments.ClosedLoopMoments.unmodelled_projection`);
    this is True when the corrected input leaves such a domain with probability above
    ``threshold`` at some step (``"auto"``'s rule), so that the particle closure, which projects
    every sample, must be read instead.

    Parameters
    ----------
    system : SwitchedSystem
    plan : ProbabilisticTSTrajectory
    control_domain : Polytope or None
    threshold : float

    Returns
    -------
    bool
    """
    if control_domain is None or not plan.num_of_steps:
        return False
    loop = _planning_loop(system, plan, control_domain, None, None, "gaussian")
    return bool(loop.unmodelled_projection and float(loop.clip.max()) > threshold)


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
