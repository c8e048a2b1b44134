"""Ready-made problems: the paper's light-dark example and its variants, and a noise-free reach-avoid."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import dynamical_system
from .belief import to_belief
from .dynamical_system import SwitchedSystem, mk_lcs, mk_switched_sys
from .expressions import mk_variable, prob
from .formulas import always, eventually, logical_and, logical_or, until
from .problem import Problem
from .sets import Polytope

__all__ = [
    "light_dark",
    "light_dark_real_system",
    "light_dark_noise",
    "LIGHT_DARK_REAL_INITIAL_STATE",
    "double_integrator",
    "reach_avoid",
]

LIGHT_DARK_REAL_INITIAL_STATE = np.array([0.5, 2.75])
"""True start of the robot in the paper's execution (the belief's mean is [0, 2.5])."""


def light_dark_noise(state: np.ndarray) -> np.ndarray:
    """The paper's sensor noise ``n(x) = (0.1 (5 - x_0)^2 + 0.001) I``: the light is at ``x_0 = 5``.

    A module-level function (not the listing's lambda), so that the problem pickles.

    It also takes a batch of states (S, 2) and returns (S, 2, 2), so Monte Carlo executions of
    many runs call it once per step (:meth:`~idstlpy.dynamical_system.POLBSWithNonLinNoise.noise_batch`).

    Parameters
    ----------
    state : ndarray, shape (2,) or (S, 2)
        Where the observation is taken.

    Returns
    -------
    ndarray, shape (2, 2) or (S, 2, 2)
        The square-root factor of the observation noise covariance.
    """
    state = np.asarray(state, dtype=float)
    factor = (1 / 10) * (5 - state[..., 0]) ** 2 + 0.001
    return np.asarray(factor[..., None, None] * np.identity(2))


def light_dark(deadline: int = 240, hold: int = 40) -> Problem:
    """The paper's listing: ``free_space U[0,deadline] G[0,hold] target`` under light-dependent noise.

    Parameters
    ----------
    deadline : int
        Latest step by which the target must be reached (240 in the paper).
    hold : int
        Steps the target must then be held (40 in the paper).

    Returns
    -------
    Problem
        Picklable (its noise is :func:`light_dark_noise`, the listing's lambda as a module-level
        function), so process pools take it as it is.
    """
    q = mk_variable(size=1, dtype=int)
    x = mk_variable(size=2, dtype=float)
    u = mk_variable(size=2, dtype=float, name="u")
    return Problem(
        switched_system=mk_switched_sys(
            [
                dynamical_system.mk_lbs(
                    A=np.identity(x.size),
                    B=0.25 * np.eye(x.size, u.size),
                    W=np.zeros((2, 2)),
                    C=np.identity(2),
                    V=light_dark_noise,
                ),
            ]
        ),
        control_domain=logical_and(u[0] >= -1.0, u[0] <= 1.0, u[1] >= -1.0, u[1] <= 1.0).region,
        initial_state=to_belief(mean=np.array([0, 2.5]), cov=np.diag([0.1, 0.1])),
        stl_formula=until(
            logical_and(
                q == 0,
                prob(x[0] >= -1) >= 1 - 0.01,
                prob(x[0] <= 5) >= 1 - 0.01,
                prob(x[1] >= -1) >= 1 - 0.01,
                prob(x[1] <= 4) >= 1 - 0.01,
                name="free_space",
            ),
            0,
            deadline,
            always(
                0,
                hold,
                logical_and(
                    q == 0,
                    prob(x[0] >= -0.25) >= 1 - 0.05,
                    prob(x[0] <= 0.25) >= 1 - 0.05,
                    prob(x[1] >= -0.25) >= 1 - 0.05,
                    prob(x[1] <= 0.25) >= 1 - 0.05,
                    name="target",
                ),
            ),
        ),
    )


def light_dark_real_system() -> SwitchedSystem:
    """The noise-free real system the paper executes the plan on.

    Returns
    -------
    SwitchedSystem
        One mode, ``x+ = x + 0.25 u``, no noise and no sensor.
    """
    return mk_switched_sys([mk_lcs(A=np.identity(2), B=0.25 * np.identity(2))])


def double_integrator() -> tuple[Any, SwitchedSystem, Polytope]:
    """A noise-free 2-D double integrator: state ``(p_x, p_y, v_x, v_y)``, ``|u_i| <= 0.5``.

    Returns
    -------
    x : RealValuedVariable, size 4
    system : SwitchedSystem
        One mode, zero process noise, no sensor.
    control_domain : Polytope, in R^2
    """
    x = mk_variable(4)
    u = mk_variable(2, name="u")
    A = np.eye(4)
    A[0, 2] = A[1, 3] = 1.0
    B = np.zeros((4, 2))
    B[2, 0] = B[3, 1] = 1.0
    system = mk_switched_sys([dynamical_system.mk_lbs(A, B, np.zeros((4, 4)))])
    domain: Polytope = logical_and(u[0] >= -0.5, u[0] <= 0.5, u[1] >= -0.5, u[1] <= 0.5).region
    return x, system, domain


def reach_avoid(T: int) -> Problem:
    """Avoid the box ``[3, 5] x [4, 6]`` at every step, reach ``[7, 8] x [8, 9]`` within ``T`` steps.

    :func:`double_integrator` from ``(1, 1)`` at rest with zero covariance, so every chance
    constraint (0.99) is a plain linear one and the LP decides each candidate exactly.

    Parameters
    ----------
    T : int
        Horizon of both the avoidance and the deadline of the goal.

    Returns
    -------
    Problem
    """
    x, system, domain = double_integrator()

    def p(pred: Any) -> Any:
        return prob(pred) >= 0.99

    avoid = logical_or(p(x[0] <= 3), p(x[0] >= 5), p(x[1] <= 4), p(x[1] >= 6))
    goal = logical_and(p(x[0] >= 7), p(x[0] <= 8), p(x[1] >= 8), p(x[1] <= 9), name="goal")
    formula = logical_and(always(0, T, avoid), eventually(0, T, goal))
    return Problem(system, domain, to_belief([1, 1, 0, 0], np.zeros((4, 4))), formula)
