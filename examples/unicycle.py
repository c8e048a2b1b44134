"""A nonlinear unicycle tracked by a plan made on its linearisation (a real plant as a step function).

The robot is a unicycle with state ``(p_x, p_y, theta)`` and inputs ``(v, omega)``, sampled at
``dt``::

    p_x' = p_x + dt v cos(theta)
    p_y' = p_y + dt v sin(theta)
    theta' = theta + dt omega

with actuator noise on ``v`` and ``omega``. The planner only knows its linearisation around
driving along the x axis at speed ``V0`` (``cos theta ~ 1``, ``v sin theta ~ V0 theta``), a
position sensor with a fixed noise (GPS-like) and a compass with noise, and plans a belief that
reaches a goal box off to the side while staying in a corridor (``guarantee="closed_loop"``: the
promises are for the tracked loop). Each plan is then executed on the *nonlinear* plant, given to
:func:`idstlpy.validate` as ``plant=unicycle_step``, and on the linear model itself, to see what
the linearisation costs. Twice: with the speed kept near the linearisation's ``V0`` (the plan
stays where the model is right), and with the speed free in [0, 1.5] (the planner then uses
large headings and speeds far from ``V0``, where the model is wrong, and the real robot fails
much more often than the model predicts).

Run it with ``python examples/unicycle.py [runs]`` (default 1000 runs of each). The numbers
are recorded in ``benchmarks/executor_results.md``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

import idstlpy as stl

DT = 0.5
"""Sampling period (s)."""
V0 = 1.0
"""Speed (m/s) of the linearisation point (driving along the x axis)."""
ACTUATOR_STD = np.array([0.05, 0.05])
"""Standard deviations of the speed (m/s) and turn-rate (rad/s) disturbances of the real robot."""


def unicycle_step(state: np.ndarray, u: np.ndarray, mode: int, rng: np.random.Generator) -> np.ndarray:
    """One step of the nonlinear unicycle, with actuator noise drawn from ``rng``.

    Parameters
    ----------
    state : ndarray, shape (3,)
        ``(p_x, p_y, theta)``.
    u : ndarray, shape (2,)
        ``(v, omega)``, as the executor applies it (projected on the control domain).
    mode : int
        The planning mode (unused: the sensors switch, the robot's motion does not).
    rng : numpy.random.Generator
        The run's random generator.

    Returns
    -------
    ndarray, shape (3,)
    """
    v, omega = u + ACTUATOR_STD * rng.standard_normal(2)
    px, py, theta = state
    return np.array([px + DT * v * np.cos(theta), py + DT * v * np.sin(theta), theta + DT * omega])


def linearised_problem(speed: tuple[float, float] = (0.8, 1.2)) -> stl.Problem:
    """The planning problem on the unicycle's linearisation around ``theta = 0``, ``v = V0``.

    Parameters
    ----------
    speed : (float, float)
        Bounds of the speed input ``v`` (the control domain; the turn rate is in [-0.6, 0.6]).

    Returns
    -------
    Problem
        Reach the goal box (x in [3.5, 4.5], y in [1.0, 1.6], 90% each bound) within 12 steps,
        staying in the corridor y in [-0.3, 1.8] (95% each bound).
    """
    x = stl.mk_variable(size=3, dtype=float)
    u = stl.mk_variable(size=2, dtype=float)
    q = stl.mk_variable(size=1, dtype=int)
    A = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, DT * V0], [0.0, 0.0, 1.0]])
    B = DT * np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    W = B @ np.diag(ACTUATOR_STD)  # the actuator noise, seen through B, is the model's process noise
    mode = stl.mk_lbs(A=A, B=B, W=W, C=np.eye(3), V=np.diag([0.2, 0.2, 0.1]))
    low, high = speed
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=stl.logical_and(u[0] >= low, u[0] <= high, u[1] >= -0.6, u[1] <= 0.6).region,
        initial_state=stl.to_belief(mean=np.zeros(3), cov=np.diag([0.01, 0.01, 0.005])),
        stl_formula=stl.logical_and(
            stl.always(
                0,
                12,
                stl.logical_and(
                    q == 0, stl.prob(x[1] >= -0.3) >= 0.95, stl.prob(x[1] <= 1.8) >= 0.95, name="corridor"
                ),
            ),
            stl.eventually(
                0,
                12,
                stl.logical_and(
                    stl.prob(x[0] >= 3.5) >= 0.9,
                    stl.prob(x[0] <= 4.5) >= 0.9,
                    stl.prob(x[1] >= 1.0) >= 0.9,
                    stl.prob(x[1] <= 1.6) >= 0.9,
                    name="goal",
                ),
            ),
        ),
    )


def main(runs: int = 1000) -> dict[str, stl.ValidationReport]:
    """Plan on the linearisation (two speed ranges), validate on the nonlinear plant and on the model."""
    x0 = np.zeros(3)
    reports = {}
    for speed in [(0.8, 1.2), (0.0, 1.5)]:
        problem = linearised_problem(speed)
        t0 = time.perf_counter()
        # guarantee="closed_loop": the plan's chance constraints hold for the tracked loop
        plan = problem.solve(rrt_timeout=30, seed=0, max_num_of_steps=12, guarantee="closed_loop")
        if plan is None:
            raise SystemExit(f"no plan: {problem.last_result.reason}")
        heading = float(np.max(np.abs(plan.get_mean()[:, 2])))
        print(
            f"speed in {speed}: plan of {plan.num_of_steps} steps in {time.perf_counter() - t0:.1f} s, "
            f"largest planned heading {heading:.2f} rad"
        )
        for plant_name, options in [
            ("nonlinear unicycle", {"plant": unicycle_step, "process_noise": "none"}),
            ("linearised model", {}),
        ]:
            report = stl.validate(problem, plan, None, x0, runs=runs, seed=1, executor="serial", **options)
            reports[f"speed {speed}, {plant_name}"] = report
            print(
                f"  {plant_name:18s}: belief {report.belief_success_rate:.3f} "
                f"[{report.belief_ci[0]:.3f}, {report.belief_ci[1]:.3f}], true state "
                f"{report.state_success_rate:.3f} [{report.state_ci[0]:.3f}, {report.state_ci[1]:.3f}] "
                f"({report.elapsed:.1f} s)"
            )
    return reports


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 1000)
