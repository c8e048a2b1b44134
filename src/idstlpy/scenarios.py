"""Ready-made problems: the paper's light-dark example and its variants."""

from __future__ import annotations

import numpy as np

from . import dynamical_system
from .belief import to_belief
from .dynamical_system import SwitchedSystem, mk_lcs, mk_switched_sys
from .expressions import mk_variable, prob
from .formulas import always, logical_and, until
from .synthesis.problem import Problem

__all__ = ["light_dark", "light_dark_real_system", "LIGHT_DARK_REAL_INITIAL_STATE"]

LIGHT_DARK_REAL_INITIAL_STATE = np.array([0.5, 2.75])
"""True start of the robot in the paper's execution (the belief's mean is [0, 2.5])."""


def light_dark(deadline: int = 240, hold: int = 40) -> Problem:
    """The paper's listing: ``free_space U[0,deadline] G[0,hold] target`` under light-dependent noise.

    Parameters
    ----------
    deadline : int
        Latest step by which the target must be reached (240 in the paper).
    hold : int
        Steps the target must then be held (40 in the paper).
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
                    V=lambda state: ((1 / 10) * (5 - state[0]) ** 2 + 0.001) * np.identity(2),
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
    """The noise-free real system the paper executes the plan on."""
    return mk_switched_sys([mk_lcs(A=np.identity(2), B=0.25 * np.identity(2))])
