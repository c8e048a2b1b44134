"""Active-perception problems beyond the paper's light-dark example (issue 11), each with a witness.

Every builder takes ``size`` (``"small"`` or ``"full"``) and returns ``(problem, witness)``: the
problem is written with the public API only (``import idstlpy as stl``) and ``witness`` is a
hand-made plan ``(actions, controls)`` whose exact MLO belief roll-out (``stl.rollout``) satisfies
the formula (``stl.satisfies``), checked in ``tests/test_perception_suite.py``. A feasible
instance is therefore *known* feasible: a solver answering ``infeasible`` on it is unsound. The
noise-floor instance has no witness (``None``): it is infeasible, and its docstring gives the
arithmetic.

Sensing is the paper's light-dark sensor unless noted: the observation noise matrix is
``n(x) = (a (light - x_0)^2 + b) I`` (so ``R(x) = n(x)^2 I``), with the paper's ``a = 1/10``,
``b = 0.001`` and the light at ``x_0 = 5``; it is a picklable :class:`LightNoise`, so problems
travel to process pools. Unless noted the geometry is the paper's: free space ``[-1, 5] x [-1, 4]``
at 99% per face, target ``[-0.25, 0.25]^2`` at 95% per face, prior ``N((0, 2.5), 0.1 I)``, inputs
in ``[-1, 1]^2``. ``KINDS`` lists the kinds (name -> :class:`Kind`) in the issue's order.

Witnesses are scripted with :class:`Script`: drive toward the light, wait there for the
covariance to shrink, come back and hold; every step's mean is the planning model's
(deterministic) MLO mean, and the covariances come from ``stl.rollout``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import idstlpy as stl

__all__ = [
    "KINDS",
    "Kind",
    "LightNoise",
    "Script",
    "SIZES",
    "build",
    "check_witness",
    "real_initial_state",
    "real_system",
    "noise_floor_arithmetic",
]

SIZES = ("small", "full")

Z95 = 1.6448536269514722  # Phi^-1(0.95)
Z99 = 2.3263478740408408  # Phi^-1(0.99)
PAPER_SIGMAS = np.array([0.5, 0.25, 0.25]) / np.sqrt(0.1)
"""The paper executes from (0.5, 2.75) with the prior N((0, 2.5), 0.1 I): offsets of 1.58 and 0.79
prior standard deviations. Every instance's true start is offset the same way along its position
coordinates (velocities start at their mean)."""


@dataclass(frozen=True)
class LightNoise:
    """Light-dark observation noise ``n(x) = (a (light - x[coord])^2 + b) I_dim`` (picklable).

    ``R(x) = n(x) n(x)' = (a (light - x[coord])^2 + b)^2 I``: its floor is ``b^2 I`` (at the light).
    """

    a: float = 0.1
    b: float = 0.001
    light: float = 5.0
    coord: int = 0
    dim: int = 2

    def __call__(self, x: Any) -> np.ndarray:
        return (self.a * (self.light - x[self.coord]) ** 2 + self.b) * np.eye(self.dim)


# ------------------------------------------------------------------------------------------------
# Formula helpers


def _p(pred: Any, conf: float) -> Any:
    return stl.prob(pred) >= conf


def box(x: Any, lo: Sequence[float], hi: Sequence[float], conf: float, name: str, coords=None) -> Any:
    """Atomic proposition ``lo <= x[coords] <= hi`` with confidence ``conf`` on every face."""
    coords = range(len(lo)) if coords is None else coords
    preds = []
    for i, low, high in zip(coords, lo, hi, strict=True):
        preds += [_p(x[i] >= low, conf), _p(x[i] <= high, conf)]
    return stl.logical_and(*preds, name=name)


def outside_box(x: Any, lo: Sequence[float], hi: Sequence[float], conf: float, name: str) -> Any:
    """Free space minus the box ``[lo, hi]``: a disjunction of half-planes (one proposition each)."""
    faces = []
    for i, (low, high) in enumerate(zip(lo, hi, strict=True)):
        faces.append(stl.logical_and(_p(x[i] <= low, conf), name=f"{name}_below_{i}"))
        faces.append(stl.logical_and(_p(x[i] >= high, conf), name=f"{name}_above_{i}"))
    return stl.logical_or(*faces)


def _light_dark_system(n: int = 2, b_gain: float = 0.25, W: float = 0.0, noise: LightNoise | None = None):
    noise = LightNoise(dim=n) if noise is None else noise
    return stl.mk_switched_sys(
        [
            stl.mk_lbs(
                A=np.identity(n),
                B=b_gain * np.identity(n),
                W=W * np.identity(n),
                C=np.identity(n),
                V=noise,
                V_floor=noise.b,
            )
        ]
    )


def _unit_box(u: Any, m: int, bound: float = 1.0) -> Any:
    preds = []
    for i in range(m):
        preds += [u[i] >= -bound, u[i] <= bound]
    return stl.logical_and(*preds).region


def _hold(size: str, small: int = 10, full: int = 40) -> int:
    if size not in SIZES:
        raise ValueError(f"size must be one of {SIZES}, got {size!r}")
    return small if size == "small" else full


# ------------------------------------------------------------------------------------------------
# Witness scripting


class Script:
    """Build a plan step by step on the planning model's MLO mean (deterministic).

    ``goto`` drives the position toward a point with the largest admissible input (saturated
    dead-beat on a box input domain; a PD law for the double integrator), ``wait`` applies zero
    input. Controls are clipped to ``[-umax, umax]``.
    """

    def __init__(self, problem: stl.Problem, umax: float = 1.0) -> None:
        self.system = problem.switched_system
        self.mean = np.array(problem.initial_state.mean, dtype=float)
        self.umax = umax
        self.actions: list[int] = []
        self.controls: list[np.ndarray] = []

    def _step(self, mode: int, u: np.ndarray) -> None:
        m = self.system.system_modes[mode]
        u = np.clip(u, -self.umax, self.umax)
        self.mean = m.A @ self.mean + m.B @ u
        self.actions.append(mode)
        self.controls.append(u)

    def goto(self, goal: Sequence[float], mode: int = 0, max_steps: int = 10_000, speed: float = 1.0):
        """Single integrator ``x' = x + B u``: saturated dead-beat until the mean is at ``goal``."""
        goal = np.asarray(goal, dtype=float)
        m = self.system.system_modes[mode]
        pinv = np.linalg.pinv(m.B)
        for _ in range(max_steps):
            if np.max(np.abs(goal - self.mean)) < 1e-12:
                return self
            u = pinv @ (goal - self.mean)
            # scale rather than clip per axis: keep the straight line
            scale = max(1.0, np.max(np.abs(u)) / (self.umax * speed))
            self._step(mode, u / scale)
        raise RuntimeError(f"goto {goal} did not converge")

    def goto_di(self, goal: Sequence[float], mode: int = 0, vmax: float = 0.5, tol: float = 1e-6):
        """Double integrator (position p, velocity v): track a braking velocity profile to ``goal``.

        Per axis the desired velocity is ``sign(e) min(vmax, sqrt(1.4 a |e|), 0.3 |e|)`` (``e`` the
        position error, ``a`` the largest acceleration), reached by a saturated one-step input.
        """
        goal = np.asarray(goal, dtype=float)
        m = self.system.system_modes[mode]
        d = goal.shape[0]
        gain = np.diag(m.B[d:, :])  # velocity_i += gain_i u_i
        amax = np.abs(gain) * self.umax
        for _ in range(10_000):
            p, v = self.mean[:d], self.mean[d:]
            e = goal - p
            if np.max(np.abs(e)) < tol and np.max(np.abs(v)) < tol:
                return self
            v_des = np.sign(e) * np.minimum.reduce(
                [np.full(d, vmax), np.sqrt(1.4 * amax * np.abs(e)), 0.3 * np.abs(e)]
            )
            self._step(mode, (v_des - v) / gain)
        raise RuntimeError(f"goto_di {goal} did not converge")

    def wait(self, steps: int, mode: int = 0):
        for _ in range(steps):
            self._step(mode, np.zeros(self.system.m))
        return self

    def plan(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self.actions, dtype=int), np.array(self.controls, dtype=float).reshape(
            -1, self.system.m
        )


def check_witness(problem: stl.Problem, witness: tuple[np.ndarray, np.ndarray]) -> tuple[bool, float, Any]:
    """Roll the witness out with the exact belief dynamics; (satisfied, robustness, trajectory)."""
    actions, controls = witness
    traj = stl.rollout(problem.switched_system, problem.initial_state, actions, controls)
    margin = stl.robustness(traj, problem.stl_formula)
    return margin >= 0.0, margin, traj


# ------------------------------------------------------------------------------------------------
# The paper's geometry


def _paper_atoms(x: Any, n: int = 2, scale: float = 1.0):
    hi = [5.0, 4.0, 4.0][:n]
    free = box(x, [-scale] * n, [scale * h for h in hi], 0.99, "free_space")
    target = box(x, [-0.25 * scale] * n, [0.25 * scale] * n, 0.95, "target")
    return free, target


def _paper_prior(n: int = 2, scale: float = 1.0):
    mean = np.array([0.0, 2.5, 2.5][:n]) * scale
    return stl.to_belief(mean=mean, cov=0.1 * scale**2 * np.identity(n))


def _light_dark_witness(problem: stl.Problem, hold: int, look: Sequence[float], wait: int, home=None):
    """Drive to ``look`` (near the light), wait, come back to ``home`` (the target's centre), hold."""
    n = problem.switched_system.n
    home = np.zeros(n) if home is None else np.asarray(home, dtype=float)
    s = Script(problem)
    s.goto(look).wait(wait).goto(home).wait(hold)
    return s.plan()


# ------------------------------------------------------------------------------------------------
# (a) double integrator


DI_W = 3e-4
"""Velocity process noise of the double integrator (``W = diag(0, 0, DI_W, DI_W)``)."""


def double_integrator(size: str = "full"):
    """(a) A 4-D double integrator that must reach the target and hold it (10 / 40 steps).

    State ``(p_x, p_y, v_x, v_y)``, ``p' = p + v + 0.025 u``, ``v' = v + 0.05 u``, ``|u_i| <= 1``;
    process noise ``W = diag(0, 0, 3e-4, 3e-4)`` on the velocity (``DI_W``); the light-dark sensor observes
    the position (``C = [I 0]``). Prior ``N((0, 2.5, 0, 0), diag(0.1, 0.1, 0.001, 0.001))``.
    ``free_space U[0,240] G[0,hold] target`` with the paper's regions on the position.
    """
    hold = _hold(size)
    x = stl.mk_variable(size=4, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    A = np.identity(4)
    A[0, 2] = A[1, 3] = 1.0
    B = np.zeros((4, 2))
    B[0, 0] = B[1, 1] = 0.025
    B[2, 0] = B[3, 1] = 0.05
    W = np.diag([0.0, 0.0, DI_W, DI_W])
    C = np.hstack([np.identity(2), np.zeros((2, 2))])
    noise = LightNoise()
    system = stl.mk_switched_sys([stl.mk_lbs(A=A, B=B, W=W, C=C, V=noise, V_floor=noise.b)])
    free, target = _paper_atoms(x)
    problem = stl.Problem(
        switched_system=system,
        control_domain=_unit_box(u, 2),
        initial_state=stl.to_belief(mean=[0.0, 2.5, 0.0, 0.0], cov=np.diag([0.1, 0.1, 0.001, 0.001])),
        stl_formula=stl.until(free, 0, 240, stl.always(0, hold, target)),
    )
    s = Script(problem)
    s.goto_di([4.5, 2.5]).wait(10).goto_di([0.0, 0.0]).wait(hold)
    return problem, s.plan()


# ------------------------------------------------------------------------------------------------
# (b) detour around an obstacle

OBSTACLE_LO, OBSTACLE_HI = (1.5, 1.0), (3.0, 4.5)


def detour(size: str = "full"):
    """(b) An obstacle ``[1.5, 3] x [1, 4.5]`` between the start and the light (10 / 40-step hold).

    The obstacle covers the straight line from the start (0, 2.5) to the light and reaches past
    the free space's top, so the plan must go below it (the corridor ``y in [-1, 1]``).
    Avoidance is free space minus a box: a disjunction of four half-plane propositions (99% each),
    required with free space on the whole approach:
    ``(free_space & (below_x | above_x | below_y | above_y)) U[0,240] G[0,hold] target``
    (the until's left side is the invariant up to the reach; a ``G[0,H]`` at the top would force
    plans of ``H + 1`` steps).
    """
    hold = _hold(size)
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    free, target = _paper_atoms(x)
    avoid = outside_box(x, OBSTACLE_LO, OBSTACLE_HI, 0.99, "obstacle")
    problem = stl.Problem(
        switched_system=_light_dark_system(),
        control_domain=_unit_box(u, 2),
        initial_state=_paper_prior(),
        stl_formula=stl.until(stl.logical_and(free, avoid), 0, 240, stl.always(0, hold, target)),
    )
    s = Script(problem)
    s.goto([0.0, 0.0]).goto([4.0, 0.0]).wait(2).goto([0.0, 0.0]).wait(hold)
    return problem, s.plan()


# ------------------------------------------------------------------------------------------------
# (c) sequence and patrol

A_BOX = ((-0.25, -0.25), (0.25, 0.25))
B_BOX = ((-0.25, 2.75), (0.25, 3.25))


def sequence(size: str = "full"):
    """(c) Visit A, then B (nested until), then hold B (10 / 40 steps).

    ``free_space U[0,240] (A & (free_space U[0,120] G[0,hold] B))`` with A = the paper's target
    ``[-0.25, 0.25]^2`` and B = ``[-0.25, 0.25] x [2.75, 3.25]`` (both 95% per face, in the dark).
    """
    hold = _hold(size)
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    free, _ = _paper_atoms(x)
    a = box(x, *A_BOX, 0.95, "A")
    b = box(x, *B_BOX, 0.95, "B")
    formula = stl.until(free, 0, 240, stl.logical_and(a, stl.until(free, 0, 120, stl.always(0, hold, b))))
    problem = stl.Problem(_light_dark_system(), _unit_box(u, 2), _paper_prior(), formula)
    s = Script(problem)
    s.goto([4.0, 2.5]).wait(2).goto([0.0, 0.0]).goto([0.0, 3.0]).wait(hold)
    return problem, s.plan()


def patrol(size: str = "full"):
    """(c) A patrol between A and B: ``free_space U[0,240] G[0,H](F[0,P] A & F[0,P] B)``.

    ``H, P = 40, 20`` (full) or ``10, 10`` (small). A is the paper's target; B is
    ``[-0.25, 0.25] x [1.75, 2.25]`` (full) or ``[-0.25, 0.25] x [1, 1.5]`` (small), both 95% per
    face. Every window of ``P + 1`` steps must visit both, so a round trip A -> B -> A takes at most
    ``P + 1`` steps: 16 of 21 (full) and 10 of 11 (small) at full speed.
    """
    hold = _hold(size)
    period = 10 if size == "small" else 20
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    free, _ = _paper_atoms(x)
    a = box(x, *A_BOX, 0.95, "A")
    b_box = ((-0.25, 1.75), (0.25, 2.25)) if size == "full" else ((-0.25, 1.0), (0.25, 1.5))
    b = box(x, *b_box, 0.95, "B")
    patrol_f = stl.always(
        0, hold, stl.logical_and(stl.eventually(0, period, a), stl.eventually(0, period, b))
    )
    problem = stl.Problem(
        _light_dark_system(), _unit_box(u, 2), _paper_prior(), stl.until(free, 0, 240, patrol_f)
    )
    b_centre = [0.0, 0.5 * (b_box[0][1] + b_box[1][1])]
    s = Script(problem)
    s.goto([4.0, 2.5]).wait(2).goto([0.0, 0.0])
    # alternate until the patrol window (hold + period steps after its start) is covered
    start = len(s.actions)
    while len(s.actions) < start + hold + period + 1:
        s.goto(b_centre).goto([0.0, 0.0])
    s.goto(b_centre)
    return problem, s.plan()


# ------------------------------------------------------------------------------------------------
# (d) hold under process noise

NOISY_HOLD_W = 0.05
NOISY_TARGET = ((3.0, -0.5), (4.0, 0.5))


def noisy_hold(size: str = "full"):
    """(d) Hold a target under process noise ``W = 0.05 I`` (10 / 40 steps): sensing inside the hold.

    The target is ``[3, 4] x [-0.5, 0.5]`` (95% per face: a standard deviation of at most 0.304,
    i.e. a variance of at most 0.0924, at its centre). Every step adds ``w = W W' = 0.0025`` per
    axis. The steady-state variance of the scalar Riccati recursion ``P = (P + w) R / (P + w + R)``
    is ``(-w + sqrt(w^2 + 4 w R)) / 2``: 0.0188 at the target's left edge (x = 3, R = 0.161),
    0.0101 at its centre (x = 3.5, R = 0.0511), 0.0040 at its right edge (x = 4, R = 0.0102), and
    0.1238 in the paper's dark target (x = 0, R = 6.26), where no hold is possible. From the
    centre's steady state a belief that stopped sensing would lose the target's confidence after
    ``(0.0924 - 0.0101) / 0.0025 = 33`` steps, fewer than the full hold: the hold is kept by sensing
    during it. The witness holds at the centre (monitor margin 0.26; executed with the suite's
    settings, 200 runs, seed 0: belief 91%, true state 96.5%).

    :func:`noisy_hold_narrow` is a tighter variant whose best plan cannot meet the execution goal.
    """
    return _noisy_hold(size, NOISY_HOLD_W, NOISY_TARGET, [3.5, 0.0])


NARROW_HOLD_W = 0.04
NARROW_TARGET = ((2.75, -0.25), (3.25, 0.25))


def noisy_hold_narrow(size: str = "full"):
    """(d') A tight hold under process noise: ``W = 0.04 I``, target ``[2.75, 3.25] x [-0.25, 0.25]``.

    95% per face needs a variance of at most 0.0231 at the target's centre; ``w = 0.0016`` per step.
    Steady-state variances (see :func:`noisy_hold`): 0.0195 at the left edge (x = 2.75), 0.0153 at
    the centre, 0.0115 at the right edge (x = 3.25), 0.0992 in the dark (x = 0); blind, the centre's
    margin lasts ``(0.0231 - 0.0153) / 0.0016 < 5`` steps. Feasible (the witness holds at the centre,
    monitor margin 0.047, about the best: nearer the light the offset costs more than the sharper
    belief gains), but that plan holds in 0% (belief) / 22% (true state) of executions (200 runs,
    seed 0): per-step 95% confidence does not make a 40-step hold under process noise succeed. It
    measures the search, not the execution goal (the first version of :func:`noisy_hold`).

    No plan meets the execution goal. The closed-loop prediction of holds at ``x = 2.9 .. 3.15``
    (``tests/test_room.py``, BENCHMARKS.md): the executed belief's mean wanders around the plan
    with a standard deviation of 0.045 per axis at every hold position (it is driven by the process
    noise the filter follows), while the best hold (the centre) keeps only 0.047 inside each face:
    about one standard deviation, a 15% chance per face and step, over 40 steps and 4 faces; the
    predicted belief success is 0.000 at every position. The true state spreads 0.132 (centre)
    against a half-width of 0.25 (1.9 sd per face and step): predicted state success at most 0.23.

    The search must still find the MLO plan: only within 0.047 of the centre does the belief meet
    the target, so holders settle at the centre and hold for the rest of their plan in one
    extension (``sampler.py``; found on 10/10 seeds, BENCHMARKS.md).
    """
    return _noisy_hold(size, NARROW_HOLD_W, NARROW_TARGET, [3.0, 0.0])


def _noisy_hold(size: str, W: float, target_box, hold_at: Sequence[float]):
    hold = _hold(size)
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    free, _ = _paper_atoms(x)
    target = box(x, *target_box, 0.95, "target")
    problem = stl.Problem(
        _light_dark_system(W=W),
        _unit_box(u, 2),
        _paper_prior(),
        stl.until(free, 0, 240, stl.always(0, hold, target)),
    )
    s = Script(problem)
    s.goto([3.5, 2.0]).goto(hold_at).wait(hold)
    return problem, s.plan()


# ------------------------------------------------------------------------------------------------
# (e) sensor switching before a narrow door

DOOR_X = (4.0, 4.5)
DOOR_Y = (1.25, 1.75)


def sensor_switching(size: str = "full"):
    """(e) Two modes before a narrow door (10 / 40-step hold beyond it).

    Mode 0 is fast and blind: ``B = 0.5 I``, no sensor (``mk_lbs`` without ``C``), process noise
    ``W = 0.05 I``. Mode 1 is slow and senses: ``B = 0.1 I``, ``W = 0``, light-dark sensor with the
    light in the door (``x_0 = 4.25``). Free space ``[-1, 9] x [-1, 4]``; a wall ``x in [4, 4.5]``
    with a door ``y in [1.25, 1.75]`` (0.5 wide: at 99% on each face the belief's standard
    deviation across it must be below 0.107, the prior's is 0.316). Prior ``N((0, 1.5), 0.1 I)``,
    target ``[6.5, 7.5] x [1, 2]`` at 95%:
    ``(free_space & (x <= 4 | x >= 4.5 | door)) U[0,240] G[0,hold] target``.
    """
    hold = _hold(size)
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    noise = LightNoise(light=4.25)
    fast = stl.mk_lbs(A=np.identity(2), B=0.5 * np.identity(2), W=0.05 * np.identity(2))
    slow = stl.mk_lbs(
        A=np.identity(2),
        B=0.1 * np.identity(2),
        W=np.zeros((2, 2)),
        C=np.identity(2),
        V=noise,
        V_floor=noise.b,
    )
    free = box(x, [-1.0, -1.0], [9.0, 4.0], 0.99, "free_space")
    wall = stl.logical_or(
        stl.logical_and(_p(x[0] <= DOOR_X[0], 0.99), name="before_wall"),
        stl.logical_and(_p(x[0] >= DOOR_X[1], 0.99), name="after_wall"),
        box(x, [DOOR_Y[0]], [DOOR_Y[1]], 0.99, "door", coords=[1]),
    )
    target = box(x, [6.5, 1.0], [7.5, 2.0], 0.95, "target")
    problem = stl.Problem(
        stl.mk_switched_sys([fast, slow]),
        _unit_box(u, 2),
        stl.to_belief(mean=[0.0, 1.5], cov=0.1 * np.identity(2)),
        stl.until(stl.logical_and(free, wall), 0, 240, stl.always(0, hold, target)),
    )
    s = Script(problem)
    s.goto([3.0, 1.5], mode=0).wait(3, mode=1).goto([4.75, 1.5], mode=1).goto([7.0, 1.5], mode=0)
    s.wait(hold, mode=1)
    return problem, s.plan()


# ------------------------------------------------------------------------------------------------
# (f) 3-D, (g) long horizon, (h) scaled workspace, (i) weaker formula, (k) the listing


def light_dark_3d(size: str = "full"):
    """(f) Light-dark in 3-D: free space ``[-1, 5] x [-1, 4]^2``, target ``[-0.25, 0.25]^3``, prior
    ``N((0, 2.5, 2.5), 0.1 I)``, light at ``x_0 = 5`` (10 / 40-step hold)."""
    hold = _hold(size)
    x = stl.mk_variable(size=3, dtype=float)
    u = stl.mk_variable(size=3, dtype=float, name="u")
    free, target = _paper_atoms(x, n=3)
    problem = stl.Problem(
        _light_dark_system(n=3),
        _unit_box(u, 3),
        _paper_prior(n=3),
        stl.until(free, 0, 240, stl.always(0, hold, target)),
    )
    return problem, _light_dark_witness(problem, hold, [4.0, 2.5, 2.5], 2)


def long_horizon(size: str = "full"):
    """(g) The listing with a long horizon: ``free_space U[0,1000] G[0,200] target`` (small:
    ``U[0,500] G[0,100]``)."""
    deadline, hold = (500, 100) if _hold(size) == 10 else (1000, 200)
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    free, target = _paper_atoms(x)
    problem = stl.Problem(
        _light_dark_system(),
        _unit_box(u, 2),
        _paper_prior(),
        stl.until(free, 0, deadline, stl.always(0, hold, target)),
    )
    return problem, _light_dark_witness(problem, hold, [4.0, 2.5], 2)


def scaled_workspace(size: str = "full"):
    """(h) The listing with every length scaled by 4 (10 / 40-step hold).

    Free space ``[-4, 20] x [-4, 16]``, target ``[-1, 1]^2``, prior ``N((0, 10), 1.6 I)``, ``B = I``
    (same number of steps), light at ``x_0 = 20`` with ``n(x) = 4 (0.1 ((20 - x_0) / 4)^2 + 0.001)``
    ``= 0.025 (20 - x_0)^2 + 0.004``: the paper's problem in other units, so the same plans (scaled)
    solve it.
    """
    hold = _hold(size)
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    free, target = _paper_atoms(x, scale=4.0)
    problem = stl.Problem(
        _light_dark_system(b_gain=1.0, noise=LightNoise(a=0.025, b=0.004, light=20.0)),
        _unit_box(u, 2),
        _paper_prior(scale=4.0),
        stl.until(free, 0, 240, stl.always(0, hold, target)),
    )
    return problem, _light_dark_witness(problem, hold, [16.0, 10.0], 2)


def weaker_formula(size: str = "full"):
    """(i) The listing without its free-space proposition: ``F[0,240] G[0,hold] target`` (10 / 40).

    Strictly easier than the listing (every plan of the listing satisfies it); the light lies
    outside the bounding box of the formula's regions and the prior.
    """
    hold = _hold(size)
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    _, target = _paper_atoms(x)
    problem = stl.Problem(
        _light_dark_system(),
        _unit_box(u, 2),
        _paper_prior(),
        stl.eventually(0, 240, stl.always(0, hold, target)),
    )
    return problem, _light_dark_witness(problem, hold, [4.0, 2.5], 2)


def listing(size: str = "full"):
    """(k) The paper's listing itself: ``idstlpy.scenarios.light_dark(240, hold)`` (10 / 40)."""
    from idstlpy import scenarios

    hold = _hold(size)
    problem = scenarios.light_dark(240, hold)
    return problem, _light_dark_witness(problem, hold, [4.0, 2.5], 2)


# ------------------------------------------------------------------------------------------------
# (j) noise floor (infeasible)

FLOOR_B = 0.5
FLOOR_W = 0.1


def noise_floor_arithmetic(
    w: float = FLOOR_W**2, r_min: float = FLOOR_B**2, conf: float = 0.95, half_width=0.25
):
    """Steady-state variance floor vs the target's requirement (per axis).

    Returns ``(p_ss, required)``: ``p_ss = (-w + sqrt(w^2 + 4 w r_min)) / 2`` is the fixed point of
    ``P -> (P + w) r / (P + w + r)`` at the best noise ``r = r_min``; ``required`` is the largest
    variance a belief centred in the target can have, ``(half_width / Phi^-1(conf))^2``.
    """
    p_ss = (-w + np.sqrt(w * w + 4.0 * w * r_min)) / 2.0
    z = {0.95: Z95, 0.99: Z99}.get(conf)
    if z is None:
        from scipy.special import ndtri

        z = float(ndtri(conf))
    return float(p_ss), float((half_width / z) ** 2)


def noise_floor(size: str = "full"):
    """(j) Infeasible: the target's confidence is out of reach because the sensor is never precise enough.

    The listing (10 / 40-step hold) with process noise ``W = 0.1 I`` (``w = W W' = 0.01`` per axis)
    and ``n(x) = (0.1 (5 - x_0)^2 + 0.5) I``, so ``R(x) >= r_min = 0.25`` everywhere (declared as
    ``V_floor = 0.5``). Per axis, with ``A = I`` and ``C = I`` the covariance stays
    ``P_k I`` with ``P_{k+1} = (P_k + w) r_k / (P_k + w + r_k)``, increasing in ``P_k`` and in
    ``r_k``. Its fixed point at ``r_min`` is ``P_ss = (-w + sqrt(w^2 + 4 w r_min)) / 2 =
    (-0.01 + sqrt(0.0001 + 0.01)) / 2 = 0.04525`` (std 0.2127), and the prior ``0.1 >= P_ss``, so by
    induction ``P_k >= 0.04525`` at every step. The target ``[-0.25, 0.25]^2`` at 95% needs, on both
    faces of an axis, ``|m| + 1.645 sd <= 0.25``, i.e. ``sd <= 0.25 / 1.645 = 0.152`` (variance
    0.0231) even at its centre: ``0.2127 > 0.152``, no belief reaches the target. Witness: none.
    """
    hold = _hold(size)
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    free, target = _paper_atoms(x)
    problem = stl.Problem(
        _light_dark_system(W=FLOOR_W, noise=LightNoise(b=FLOOR_B)),
        _unit_box(u, 2),
        _paper_prior(),
        stl.until(free, 0, 240, stl.always(0, hold, target)),
    )
    return problem, None


# ------------------------------------------------------------------------------------------------
# Registry


@dataclass(frozen=True)
class Kind:
    """One kind of problem: its builder, the expected answer and the issue's label."""

    name: str
    label: str
    build: Callable[[str], tuple[stl.Problem, Any]]
    expected: str  # "feasible" (verified witness), "infeasible" (argued), "unknown"
    positions: int = 2
    notes: str = field(default="")


KINDS: dict[str, Kind] = {
    k.name: k
    for k in [
        Kind("double_integrator", "(a) 4-D double integrator, hold", double_integrator, "feasible"),
        Kind("detour", "(b) detour around an obstacle", detour, "feasible"),
        Kind("sequence", "(c) sequence A then B (nested until)", sequence, "feasible"),
        Kind("patrol", "(c) patrol G(F A & F B)", patrol, "feasible"),
        Kind("noisy_hold", "(d) hold under process noise", noisy_hold, "feasible"),
        Kind("noisy_hold_narrow", "(d') tight hold under process noise", noisy_hold_narrow, "feasible"),
        Kind("sensor_switching", "(e) sensor switching, narrow door", sensor_switching, "feasible"),
        Kind("light_dark_3d", "(f) 3-D light-dark", light_dark_3d, "feasible", positions=3),
        Kind("long_horizon", "(g) long horizon U[0,1000] G[0,200]", long_horizon, "feasible"),
        Kind("scaled_workspace", "(h) 4x workspace", scaled_workspace, "feasible"),
        Kind("weaker_formula", "(i) listing without free space", weaker_formula, "feasible"),
        Kind("noise_floor", "(j) noise floor", noise_floor, "infeasible"),
        Kind("listing", "(k) the paper's listing", listing, "feasible"),
    ]
}


def build(kind: str, size: str = "full") -> tuple[stl.Problem, Any]:
    """``(problem, witness)`` of one kind at one size."""
    return KINDS[kind].build(size)


def real_system(problem: stl.Problem) -> Any:
    """The executed system: every planning mode's ``A, B`` as a deterministic ``mk_lcs``."""
    return stl.mk_switched_sys([stl.mk_lcs(A=m.A, B=m.B) for m in problem.switched_system.system_modes])


def real_initial_state(kind: str, problem: stl.Problem) -> np.ndarray:
    """The true start: the prior mean offset like the paper's (1.58 and 0.79 prior std's)."""
    mean = np.array(problem.initial_state.mean, dtype=float)
    sd = np.sqrt(np.diag(problem.initial_state.cov))
    k = KINDS[kind].positions
    mean[:k] += PAPER_SIGMAS[:k] * sd[:k]
    return mean
