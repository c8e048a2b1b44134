"""The problems of issue 23 (plans that hold when executed, by default) and problems of our own.

Every builder returns a :class:`idstlpy.Problem` written with the public API only. The issue's
four problems come first (``ISSUE``), then ten of our own (``OWN``); ``PROBLEMS`` maps every name
to its builder. Choices the issue leaves open are stated in each docstring (control domains of
``|u_i| <= 1``, the second two-mode problem's free space ``[-2, 5] x [-2, 2]`` at 99%).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

import idstlpy as stl

__all__ = ["ISSUE", "OWN", "PROBLEMS", "SpotSensor", "build"]


@dataclass(frozen=True)
class SpotSensor:
    """Noise factor ``good`` within ``radius`` of ``spot`` (coordinate ``coord``), ``bad`` elsewhere.

    Picklable, so problems travel to process pools.
    """

    spot: float = 3.0
    radius: float = 0.5
    good: float = 0.05
    bad: float = 0.5
    coord: int = 0
    dim: int = 1

    def __call__(self, x: Any) -> np.ndarray:
        s = self.good if abs(float(x[self.coord]) - self.spot) <= self.radius else self.bad
        return s * np.eye(self.dim)


@dataclass(frozen=True)
class HeaterSensor:
    """Thermometer noise that grows with the temperature's distance from ``ambient`` (picklable)."""

    ambient: float = 0.0
    a: float = 0.02
    b: float = 0.05

    def __call__(self, x: Any) -> np.ndarray:
        return np.array([[self.a * (float(x[0]) - self.ambient) ** 2 + self.b]])


def _p(pred: Any, conf: float) -> Any:
    return stl.prob(pred) >= conf


def _box(
    x: Any, lo: Sequence[float], hi: Sequence[float], conf: float, name: str, extra: Sequence[Any] = ()
) -> Any:
    preds: list[Any] = list(extra)
    for i, (low, high) in enumerate(zip(lo, hi, strict=True)):
        preds += [_p(x[i] >= low, conf), _p(x[i] <= high, conf)]
    return stl.logical_and(*preds, name=name)


def _unit_box(u: Any, m: int, bound: float = 1.0) -> Any:
    preds = []
    for i in range(m):
        preds += [u[i] >= -bound, u[i] <= bound]
    return stl.logical_and(*preds).region


# ------------------------------------------------------------------------------------------------
# The issue's problems


def one_d() -> stl.Problem:
    """1-D: ``x' = x + u``, ``|u| <= 1``, ``C = 1``, sensor std 0.05 within 0.5 of ``x = 3`` and
    0.5 elsewhere, prior ``N(0, 1)``, ``F[0,30] G[0,5] (5.8 <= x <= 6.2 at 90%)``."""
    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float)
    sensor = SpotSensor()
    mode = stl.mk_lbs(
        A=np.eye(1), B=np.eye(1), W=np.zeros((1, 1)), C=np.eye(1), V=sensor, V_floor=sensor.good
    )
    goal = _box(x, [5.8], [6.2], 0.9, "goal")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=_unit_box(u, 1),
        initial_state=stl.to_belief(mean=np.zeros(1), cov=np.eye(1)),
        stl_formula=stl.eventually(0, 30, stl.always(0, 5, goal)),
    )


def _drive_look(W: float) -> stl.Problem:
    x, u = stl.mk_variable(2, float), stl.mk_variable(2, float)
    q = stl.mk_variable(2, int)
    del q
    drive = stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=W * np.eye(2), C=np.eye(2), V=0.5 * np.eye(2))
    look = stl.mk_lbs(A=np.eye(2), B=np.zeros((2, 2)), W=W * np.eye(2), C=np.eye(2), V=0.01 * np.eye(2))
    safe = _box(x, [-1, -1], [5, 5], 0.99, "safe")
    goal = _box(x, [2.8, 2.8], [3.2, 3.2], 0.95, "goal")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([drive, look]),
        control_domain=_unit_box(u, 2),
        initial_state=stl.to_belief(mean=np.zeros(2), cov=0.1 * np.eye(2)),
        stl_formula=stl.until(safe, 0, 40, goal),
    )


def drive_look() -> stl.Problem:
    """Two modes, 2-D single integrator: drive (``B = 0.5 I``, ``V = 0.5 I``) or look (``B = 0``,
    ``V = 0.01 I``), ``W = 0``, prior ``N(0, 0.1 I)``, ``|u_i| <= 1``, ``safe U[0,40] goal``
    (safe ``[-1,5]^2`` at 99%, goal ``[2.8,3.2]^2`` at 95%)."""
    return _drive_look(0.0)


def drive_look_noisy() -> stl.Problem:
    """The same with ``W = 0.1 I``."""
    return _drive_look(0.1)


def drive_sense() -> stl.Problem:
    """drive (``B = 0.25 I``, ``W = 0.01 I``, no sensor) or sense (``B = 0.05 I``, ``C = I``,
    ``V = 0.1 I``), prior ``N(0, 0.2 I)``, ``|u_i| <= 1``, ``free U[0,60] G[0,10] tgt``: free
    ``[-2, 5] x [-2, 2]`` at 99% (the issue does not give it; ``x >= -1`` at 99% fails at the
    prior), tgt the sense mode and the 0.5 x 0.5 box at (3, 0) at 95%."""
    x, u = stl.mk_variable(2, float), stl.mk_variable(2, float)
    q = stl.mk_variable(2, int)
    drive = stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=0.01 * np.eye(2))
    sense = stl.mk_lbs(A=np.eye(2), B=0.05 * np.eye(2), W=0.01 * np.eye(2), C=np.eye(2), V=0.1 * np.eye(2))
    free = _box(x, [-2, -2], [5, 2], 0.99, "free")
    tgt = _box(x, [2.75, -0.25], [3.25, 0.25], 0.95, "tgt", extra=[q == 1])
    return stl.Problem(
        switched_system=stl.mk_switched_sys([drive, sense]),
        control_domain=_unit_box(u, 2),
        initial_state=stl.to_belief(mean=np.zeros(2), cov=0.2 * np.eye(2)),
        stl_formula=stl.until(free, 0, 60, stl.always(0, 10, tgt)),
    )


def listing() -> stl.Problem:
    """The paper's listing, verbatim (README)."""
    q = stl.mk_variable(size=1, dtype=int)
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float)
    return stl.Problem(
        switched_system=stl.mk_switched_sys(
            [
                stl.dynamical_system.mk_lbs(
                    A=np.identity(x.size),
                    B=0.25 * np.eye(x.size, u.size),
                    W=np.zeros((2, 2)),
                    C=np.identity(2),
                    V=_paper_noise,
                )
            ]
        ),
        control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0, u[1] >= -1.0, u[1] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.array([0, 2.5]), cov=np.diag([0.1, 0.1])),
        stl_formula=stl.until(
            stl.logical_and(
                q == 0,
                stl.prob(x[0] >= -1) >= 1 - 0.01,
                stl.prob(x[0] <= 5) >= 1 - 0.01,
                stl.prob(x[1] >= -1) >= 1 - 0.01,
                stl.prob(x[1] <= 4) >= 1 - 0.01,
                name="free_space",
            ),
            0,
            240,
            stl.always(
                0,
                40,
                stl.logical_and(
                    q == 0,
                    stl.prob(x[0] >= -0.25) >= 1 - 0.05,
                    stl.prob(x[0] <= 0.25) >= 1 - 0.05,
                    stl.prob(x[1] >= -0.25) >= 1 - 0.05,
                    stl.prob(x[1] <= 0.25) >= 1 - 0.05,
                    name="target",
                ),
            ),
        ),
    )


def _paper_noise(state: Any) -> np.ndarray:
    return ((1 / 10) * (5 - state[0]) ** 2 + 0.001) * np.identity(2)


# ------------------------------------------------------------------------------------------------
# Our own


def double_integrator_position() -> stl.Problem:
    """A 1-D double integrator (position, velocity; dt 0.5) sensing only its position (std 0.1),
    process noise 0.01 on the velocity, ``|u| <= 1``, prior ``N((0, 0), diag(0.05, 0.01))``:
    reach ``[1.8, 2.2]`` (95%) within 30 steps and stay 5, position in ``[-1, 3]`` (99%) until."""
    x, u = stl.mk_variable(2, float), stl.mk_variable(1, float)
    A = np.array([[1.0, 0.5], [0.0, 1.0]])
    B = np.array([[0.125], [0.5]])
    mode = stl.mk_lbs(A=A, B=B, W=np.diag([0.0, 0.01]), C=np.array([[1.0, 0.0]]), V=np.array([[0.1]]))
    safe = stl.logical_and(_p(x[0] >= -1, 0.99), _p(x[0] <= 3, 0.99), name="safe")
    goal = stl.logical_and(_p(x[0] >= 1.8, 0.95), _p(x[0] <= 2.2, 0.95), name="goal")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=_unit_box(u, 1),
        initial_state=stl.to_belief(mean=np.zeros(2), cov=np.diag([0.05, 0.01])),
        stl_formula=stl.until(safe, 0, 30, stl.always(0, 5, goal)),
    )


def look_drive_noisy() -> stl.Problem:
    """Look / drive robot with process noise 0.05: drive (``B = 0.5 I``, blind) or look (``B =
    0.1 I``, ``V = 0.05 I``), prior ``N(0, 0.1 I)``; ``safe U[0,30] goal``, goal ``[1.7, 2.3]^2``
    at 95% reached in the look mode, safe ``[-1, 4]^2`` at 99%."""
    x, u = stl.mk_variable(2, float), stl.mk_variable(2, float)
    q = stl.mk_variable(2, int)
    drive = stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=0.05 * np.eye(2))
    look = stl.mk_lbs(A=np.eye(2), B=0.1 * np.eye(2), W=0.05 * np.eye(2), C=np.eye(2), V=0.05 * np.eye(2))
    safe = _box(x, [-1, -1], [4, 4], 0.99, "safe")
    goal = _box(x, [1.7, 1.7], [2.3, 2.3], 0.95, "goal", extra=[q == 1])
    return stl.Problem(
        switched_system=stl.mk_switched_sys([drive, look]),
        control_domain=_unit_box(u, 2),
        initial_state=stl.to_belief(mean=np.zeros(2), cov=0.1 * np.eye(2)),
        stl_formula=stl.until(safe, 0, 30, goal),
    )


def thermal() -> stl.Problem:
    """1-D thermal process ``T' = 0.95 T + b u``, ``0 <= u <= 1``: heat (``b = 0.5``, the
    thermometer useless: std 1) or rest (``b = 0.05``, an accurate thermometer: std 0.05), process
    noise 0.05, prior ``N(0, 0.25)``: reach ``[4.5, 5.5]`` (90%) within 30 steps and hold it 5."""
    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float)
    heat = stl.mk_lbs(
        A=np.array([[0.95]]), B=np.array([[0.5]]), W=np.array([[0.05]]), C=np.eye(1), V=np.eye(1)
    )
    rest = stl.mk_lbs(
        A=np.array([[0.95]]), B=np.array([[0.05]]), W=np.array([[0.05]]), C=np.eye(1), V=0.05 * np.eye(1)
    )
    goal = stl.logical_and(_p(x[0] >= 4.5, 0.9), _p(x[0] <= 5.5, 0.9), name="warm")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([heat, rest]),
        control_domain=stl.logical_and(u[0] >= 0.0, u[0] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.zeros(1), cov=0.25 * np.eye(1)),
        stl_formula=stl.eventually(0, 30, stl.always(0, 5, goal)),
    )


def thermal_dark() -> stl.Problem:
    """One-mode heater whose thermometer worsens with the temperature (``0.02 (T - 0)^2 + 0.05``),
    process noise 0.02, prior ``N(0, 0.1)``, ``F[0,25] G[0,4] (2.7 <= T <= 3.3 at 90%)``."""
    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float)
    sensor = HeaterSensor()
    mode = stl.mk_lbs(
        A=np.array([[0.95]]),
        B=np.array([[0.5]]),
        W=np.array([[0.02]]),
        C=np.eye(1),
        V=sensor,
        V_floor=sensor.b,
    )
    goal = stl.logical_and(_p(x[0] >= 2.7, 0.9), _p(x[0] <= 3.3, 0.9), name="warm")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.zeros(1), cov=0.1 * np.eye(1)),
        stl_formula=stl.eventually(0, 25, stl.always(0, 4, goal)),
    )


def integrator_2d_constant() -> stl.Problem:
    """2-D single integrator (``B = 0.5 I``, ``W = 0.05 I``, ``V = 0.2 I``), prior ``N(0, 0.1 I)``:
    reach ``[2, 3] x [1, 2]`` at 95% within 20 steps and hold 5, inside ``[-1, 4]^2`` at 99%."""
    x, u = stl.mk_variable(2, float), stl.mk_variable(2, float)
    mode = stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=0.05 * np.eye(2), C=np.eye(2), V=0.2 * np.eye(2))
    safe = _box(x, [-1, -1], [4, 4], 0.99, "safe")
    goal = _box(x, [2, 1], [3, 2], 0.95, "goal")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=_unit_box(u, 2),
        initial_state=stl.to_belief(mean=np.zeros(2), cov=0.1 * np.eye(2)),
        stl_formula=stl.until(safe, 0, 20, stl.always(0, 5, goal)),
    )


def one_d_spot_tight() -> stl.Problem:
    """The issue's 1-D problem with a narrower goal ``[5.85, 6.15]`` at 95%, held 3 steps."""
    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float)
    sensor = SpotSensor()
    mode = stl.mk_lbs(
        A=np.eye(1), B=np.eye(1), W=np.zeros((1, 1)), C=np.eye(1), V=sensor, V_floor=sensor.good
    )
    goal = _box(x, [5.85], [6.15], 0.95, "goal")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=_unit_box(u, 1),
        initial_state=stl.to_belief(mean=np.zeros(1), cov=np.eye(1)),
        stl_formula=stl.eventually(0, 30, stl.always(0, 3, goal)),
    )


def corridor() -> stl.Problem:
    """2-D single integrator in a corridor ``[-0.5, 6] x [-0.6, 0.6]`` (99%) with ``W = 0.02 I``,
    ``V = 0.1 I``: reach ``x_0 >= 5`` (95%) within 25 steps, prior ``N(0, 0.02 I)``."""
    x, u = stl.mk_variable(2, float), stl.mk_variable(2, float)
    mode = stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=0.02 * np.eye(2), C=np.eye(2), V=0.1 * np.eye(2))
    safe = _box(x, [-0.5, -0.6], [6, 0.6], 0.99, "corridor")
    goal = stl.logical_and(_p(x[0] >= 5, 0.95), _p(x[1] >= -0.6, 0.99), _p(x[1] <= 0.6, 0.99), name="exit")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=_unit_box(u, 2),
        initial_state=stl.to_belief(mean=np.zeros(2), cov=0.02 * np.eye(2)),
        stl_formula=stl.until(safe, 0, 25, goal),
    )


def two_goals() -> stl.Problem:
    """2-D single integrator (``W = 0.03 I``, ``V = 0.15 I``): visit A ``[1.5, 2.5] x [-0.5, 0.5]``
    then B ``[1.5, 2.5] x [1.5, 2.5]`` (95% each), prior ``N(0, 0.05 I)``."""
    x, u = stl.mk_variable(2, float), stl.mk_variable(2, float)
    mode = stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=0.03 * np.eye(2), C=np.eye(2), V=0.15 * np.eye(2))
    a = _box(x, [1.5, -0.5], [2.5, 0.5], 0.95, "A")
    b = _box(x, [1.5, 1.5], [2.5, 2.5], 0.95, "B")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=_unit_box(u, 2),
        initial_state=stl.to_belief(mean=np.zeros(2), cov=0.05 * np.eye(2)),
        stl_formula=stl.eventually(0, 20, stl.logical_and(a, stl.eventually(0, 20, b))),
    )


def blind_then_look() -> stl.Problem:
    """1-D: a fast blind mode (``B = 1``, ``W = 0.05``) and a slow sensing mode (``B = 0.2``,
    std 0.05), prior ``N(0, 0.3)``: ``F[0,20] G[0,4] (3.8 <= x <= 4.2 at 95% in the sensing
    mode)``."""
    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float)
    q = stl.mk_variable(2, int)
    fast = stl.mk_lbs(A=np.eye(1), B=np.eye(1), W=np.array([[0.05]]))
    slow = stl.mk_lbs(A=np.eye(1), B=0.2 * np.eye(1), W=np.array([[0.05]]), C=np.eye(1), V=np.array([[0.05]]))
    goal = _box(x, [3.8], [4.2], 0.95, "goal", extra=[q == 1])
    return stl.Problem(
        switched_system=stl.mk_switched_sys([fast, slow]),
        control_domain=_unit_box(u, 1),
        initial_state=stl.to_belief(mean=np.zeros(1), cov=0.3 * np.eye(1)),
        stl_formula=stl.eventually(0, 20, stl.always(0, 4, goal)),
    )


def avoid_1d() -> stl.Problem:
    """1-D integrator (``W = 0.05``, std 0.2): stay below 2 (99%) until reaching ``[1, 1.6]`` at
    90%, prior ``N(0, 0.1)``."""
    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float)
    mode = stl.mk_lbs(A=np.eye(1), B=0.5 * np.eye(1), W=np.array([[0.05]]), C=np.eye(1), V=np.array([[0.2]]))
    safe = stl.logical_and(_p(x[0] <= 2.0, 0.99), name="below")
    goal = _box(x, [1.0], [1.6], 0.9, "goal")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=_unit_box(u, 1),
        initial_state=stl.to_belief(mean=np.zeros(1), cov=0.1 * np.eye(1)),
        stl_formula=stl.until(safe, 0, 20, stl.always(0, 3, goal)),
    )


ISSUE: dict[str, Callable[[], stl.Problem]] = {
    "listing": listing,
    "one_d": one_d,
    "drive_look": drive_look,
    "drive_look_noisy": drive_look_noisy,
    "drive_sense": drive_sense,
}
OWN: dict[str, Callable[[], stl.Problem]] = {
    "double_integrator_position": double_integrator_position,
    "look_drive_noisy": look_drive_noisy,
    "thermal": thermal,
    "thermal_dark": thermal_dark,
    "integrator_2d_constant": integrator_2d_constant,
    "one_d_spot_tight": one_d_spot_tight,
    "corridor": corridor,
    "two_goals": two_goals,
    "blind_then_look": blind_then_look,
    "avoid_1d": avoid_1d,
}
PROBLEMS: dict[str, Callable[[], stl.Problem]] = {**ISSUE, **OWN}


def build(name: str) -> stl.Problem:
    """The problem called ``name`` (a key of :data:`PROBLEMS`)."""
    return PROBLEMS[name]()
