"""The executor's one step law, written once, for a batch of ``S`` runs (``S = 1`` for one run).

One execution step ``k`` (plan mode ``q = q_k``, plan mean ``m_k``, plan input ``v_k``)::

    u_k      = proj_U( v_k - K (mean_k - m_k) )                  (tracking correction, K of mode q)
    x_{k+1}  = plant(x_k, u_k, q)  [+ W w_k]                      (true state)
    y_{k+1}  = C_q x_{k+1} + n_q(x_{k+1}) v_{k+1}                 (the planning mode's sensor)
    mean, cov <- Kalman(predict with mode q and u_k, update with y_{k+1}, noise at predicted mean)

- ``K`` is ``K_0`` of the mode's finite-horizon gains (receding horizon), ``K_j`` when only
  ``h - j`` plan steps remain (:func:`idstlpy.tracking.gain_at`).
- The plant is linear (``x' = A^real x + B^real u``, one real mode for all or one per planning
  mode, plus ``W w`` of the model's or the real mode's, or none) or a step function
  ``(state, input, mode, rng) -> next_state`` (plus the model's ``W w`` when
  ``process_noise="model"``).
- The observation is drawn from the *planning* model's sensor at the *true* state (the real
  plant of the paper has no sensor); the filter only knows the planning model and evaluates the
  noise function at its own predicted mean.

Every function takes arrays with a leading run axis: states and means (S, n), inputs (S, m),
observations (S, p). The filter's covariance is one (n, n) matrix shared by every run while the
noise does not depend on the state (it then does not depend on the observations either), and
(S, n, n) once a state-dependent sensor has made the runs' covariances differ; a state-dependent
noise function is called once for all runs when it takes a batch of states, else once per run
(:meth:`~idstlpy.dynamical_system.POLBSWithNonLinNoise.noise_batch`), and the runs' filters are
updated together (:func:`~idstlpy.belief.kalman_update_batch`). For
``S = 1`` the arithmetic is that of one vector (``x @ A.T`` is ``A @ x`` bit for bit), so one run
reproduces the serial executor exactly; for ``S > 1`` the runs draw their noises from one
generator, row by row within each draw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._checks import as_int
from ..belief import _joseph, kalman_gain, kalman_update, kalman_update_batch, predict
from ..closed_loop import step_parts
from ..dynamical_system import LCS
from ..errors import DimensionError, InvalidArgumentError
from ..tracking import tracking_input
from ..trajectory import ProbabilisticTSTrajectory
from .spec import ExecutorSpec

__all__ = ["StepLaw", "Step"]


@dataclass(frozen=True)
class Step:
    """Everything the law reads at one plan step, resolved once.

    Attributes
    ----------
    mode : int
        The planning mode ``q_k``.
    model : LCS
        The planning mode (filter and sensor).
    K : ndarray, shape (m, n)
        The tracking gain applied at this step.
    mean : ndarray, shape (n,)
        The plan's mean ``m_k``.
    input : ndarray, shape (m,)
        The plan's input ``v_k``.
    real : LCS or None
        The linear plant's mode (None for a step-function plant).
    W : ndarray, shape (n, r) or None
        The process noise factor added to the true state (None: no process noise).
    """

    mode: int
    model: LCS
    K: np.ndarray
    mean: np.ndarray
    input: np.ndarray
    real: LCS | None
    W: np.ndarray | None


class StepLaw:
    """The one step law of the executor, bound to a plan (see the module docstring).

    Parameters
    ----------
    spec : ExecutorSpec
        What runs the plan.
    plan : ProbabilisticTSTrajectory
        The plan tracked, ``N`` steps; the receding-horizon gain at step ``k`` is the one with
        ``N - k`` plan steps left.
    steps : int, optional
        The steps bound (executed), ``0 <= steps <= N``; default ``N``.

    Raises
    ------
    DimensionError
        When the plan's dimensions or modes disagree with the system, the plant or the gains.
    """

    def __init__(self, spec: ExecutorSpec, plan: ProbabilisticTSTrajectory, steps: int | None = None) -> None:
        system = spec.system
        if plan.n != system.n:
            raise DimensionError(
                f"reference_trajectory has state dimension {plan.n}, the system has n = {system.n}"
            )
        self.spec = spec
        N_ref = plan.num_of_steps
        N = N_ref if steps is None else as_int(steps, "num_of_steps", minimum=0, maximum=N_ref)
        self.num_of_steps = N
        actions = plan.get_action()[:N]
        plan_u = plan.get_control()
        if N and plan_u.shape[1] != system.m:
            raise DimensionError(
                f"reference_trajectory has inputs of size {plan_u.shape[1]}, the system has m = {system.m}"
            )
        spec.check_plan_modes(actions)
        means = plan.get_mean()
        real_modes = spec.real_modes
        gains = spec.gains_for(plan)  # modes without chosen gains: the plan's own
        bound: list[Step] = []
        for k in range(N):
            q = int(actions[k])
            mode, real, K, W = step_parts(system, real_modes, gains, spec.process_noise, q, N_ref - k)
            bound.append(
                Step(
                    q,
                    mode,
                    K,
                    means[k],
                    plan_u[k],
                    real,
                    W if W is not None and W.shape[1] else None,
                )
            )
        self.steps: tuple[Step, ...] = tuple(bound)
        self.p_max = max((mode.p for mode in system.system_modes), default=0)

    # -- the four parts of a step ---------------------------------------------------------------

    def control(self, k: int, means: np.ndarray) -> np.ndarray:
        """The inputs (S, m) applied at step ``k`` by runs whose filter means are ``means`` (S, n)."""
        st = self.steps[k]
        box = self.spec.box
        if box is not None or self.spec.control_domain is None:  # a clip (or nothing) on every row
            low, high = box if box is not None else (None, None)
            return tracking_input(st.input, st.K, means - st.mean, low, high)
        return self.spec.project(tracking_input(st.input, st.K, means - st.mean))  # rows at once

    def plant(self, k: int, states: np.ndarray, inputs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The true states (S, n) after step ``k`` from ``states`` (S, n) under ``inputs`` (S, m)."""
        st = self.steps[k]
        X: np.ndarray
        if st.real is not None:
            X = states @ st.real.A.T + inputs @ st.real.B.T
        else:
            step = self.spec.plant_step
            if step is None:  # pragma: no cover - the spec holds one or the other
                raise InvalidArgumentError("the executor has no plant")
            X = np.empty_like(states)
            n = states.shape[1]
            for i in range(states.shape[0]):
                nxt = np.asarray(step(states[i].copy(), inputs[i].copy(), st.mode, rng), dtype=float)
                if nxt.shape != (n,):
                    raise DimensionError(
                        f"the plant step function must return a state of shape ({n},), got {nxt.shape}"
                    )
                X[i] = nxt
        if st.W is not None:
            X = X + rng.standard_normal((X.shape[0], st.W.shape[1])) @ st.W.T
        return X

    def observe(self, k: int, states: np.ndarray, rng: np.random.Generator) -> np.ndarray | None:
        """The observations (S, p) of the planning mode of step ``k`` at true ``states`` (S, n);
        None for a blind mode."""
        mode = self.steps[k].model
        if not mode.p:
            return None
        Y = states @ mode.C.T
        if mode.has_state_dependent_noise:
            if states.shape[0] > 1:  # one call for the batch when the function takes one
                nxs = mode.noise_batch(states)
                if nxs.shape[2]:
                    draws = rng.standard_normal((states.shape[0], nxs.shape[2]))
                    Y = Y + (nxs @ draws[:, :, None])[:, :, 0]
                return Y
            factors = [mode.noise(x) for x in states]
            r = factors[0].shape[1]
            if r:
                draws = rng.standard_normal((states.shape[0], r))
                for i, nx in enumerate(factors):
                    Y[i] = Y[i] + nx @ draws[i]
            return Y
        nx = mode.noise(states[0])
        if nx.shape[1]:
            Y = Y + rng.standard_normal((states.shape[0], nx.shape[1])) @ nx.T
        return Y

    def filter(
        self, k: int, means: np.ndarray, cov: np.ndarray, inputs: np.ndarray, observations: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The Kalman filter of step ``k``: predict with the planning mode and ``inputs`` (S, m),
        update with ``observations`` (S, p; None for a blind mode).

        ``cov`` is (n, n) when shared by the runs, else (S, n, n); the result keeps it shared
        unless the mode's noise depends on the state and there are several runs.
        """
        mode = self.steps[k].model
        per_run = cov.ndim == 3 or (mode.has_state_dependent_noise and means.shape[0] > 1 and mode.p > 0)
        if not per_run:
            mean_pred = means @ mode.A.T + inputs @ mode.B.T
            P = mode.A @ cov @ mode.A.T + mode.process_cov
            if not mode.p:
                return mean_pred, P
            R = mode.noise_cov(mean_pred[0])
            L = kalman_gain(mode.C, P, R)
            new_cov = _joseph(L, mode.C, P, R)
            if observations is None:
                return mean_pred, new_cov
            return mean_pred + (observations - mean_pred @ mode.C.T) @ L.T, new_cov
        S, n = means.shape
        covs = np.broadcast_to(cov, (S, n, n)) if cov.ndim == 2 else cov
        if S > 1:  # the runs at once (belief.kalman_update_batch: kalman_update up to rounding)
            mean_pred = means @ mode.A.T + inputs @ mode.B.T
            P = mode.A @ covs @ mode.A.T + mode.process_cov
            return kalman_update_batch(mode, mean_pred, P, observations)
        out_m, out_c = np.empty_like(means), np.empty((S, n, n))
        for i in range(S):
            mp, P = predict(mode, means[i], covs[i], inputs[i])
            y = None if observations is None else observations[i]
            out_m[i], out_c[i] = kalman_update(mode, mp, P, y=y, x_noise=mp)
        return out_m, out_c
