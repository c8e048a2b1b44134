"""Issue 34: default tracking gains on plants from python-control (motors, a mass-spring-damper,
a quadrotor's altitude, thermal processes; 10 instances).

Each plant is a continuous-time ``control.ss(...)`` sampled by ``stl.from_continuous`` (zero-order
hold, exact process-noise discretisation), with a "go there and hold" formula in its own units
(radians, metres, degrees Celsius, rad/s) and a box of admissible inputs (volts, newtons, m/s^2,
heater duty). Every instance is solved twice with the same options and seed: with the default
tracking (``tracking="fitted"``: weights from the problem's scales, chosen among a few by the
predicted execution) and with the paper's weights (``tracking="paper"``: ``Q = I``,
``R = 0.05 I``, the default before). Each returned plan is executed ``--runs`` times by
``stl.validate`` (the model as the plant, true starts from the prior, the plan's own tracking
gains) and the measured success rates are compared with the execution target 90% belief / 95%
true state (met when the 95% Wilson interval reaches it).

Usage::

    python -m benchmarks.plant_family [--runs 1000] [--plants a,b] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import subprocess
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import control
import numpy as np

import idstlpy as stl
from idstlpy.execution.validation import wilson_interval

OPTIONS: dict[str, Any] = {"seed": 0, "time_limit": 60}
TARGET = (0.90, 0.95)


def _hold_problem(
    plant: Any,
    dt: float,
    qc: Any,
    sensor_cov: Any,
    coord: int,
    goal: float,
    tol: float,
    low: Any,
    high: Any,
    start: Any,
    start_cov: Any,
    reach: int,
    hold: int,
    extra: Any = None,
) -> stl.Problem:
    """``F[0, reach] G[0, hold] |x[coord] - goal| <= tol`` (each face with 95% confidence),
    optionally under an invariant ``extra(x)`` (a list of chance constraints) at every step."""
    mode = stl.from_continuous(plant, dt=dt, noise_intensity=np.asarray(qc, dtype=float), V_cov=sensor_cov)
    n, m = mode.n, mode.m
    x = stl.mk_variable(n, float)
    u = stl.mk_variable(m, float)
    at = stl.logical_and(
        stl.prob(x[coord] >= goal - tol) >= 0.95, stl.prob(x[coord] <= goal + tol) >= 0.95, name="at_goal"
    )
    formula: Any = stl.eventually(0, reach, stl.always(0, hold, at))
    if extra is not None:
        safe = stl.logical_and(*extra(x), name="safe")
        formula = stl.until(safe, 0, reach, stl.always(0, hold, stl.logical_and(at, safe)))
    low, high = np.atleast_1d(low), np.atleast_1d(high)
    domain = stl.logical_and(*(c for j in range(m) for c in (u[j] >= low[j], u[j] <= high[j]))).region
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=domain,
        initial_state=stl.to_belief(
            mean=np.asarray(start, dtype=float), cov=np.asarray(start_cov, dtype=float)
        ),
        stl_formula=formula,
    )


def dc_motor(tau: float, gain: float, volts: float, tol: float, sensor: float = 0.02, qc: float = 0.01):
    """A DC motor's angle (rad) and speed (rad/s), input voltage; turn to 1 rad and hold."""
    plant = control.ss([[0, 1], [0, -1 / tau]], [[0], [gain / tau]], [[1, 0]], [[0]])
    return _hold_problem(
        plant, 0.1, np.diag([0.0, qc]), [[sensor**2]], 0, 1.0, tol, -volts, volts,
        [0.0, 0.0], np.diag([1e-4, 1e-4]), 40, 10,
    )  # fmt: skip


def dc_motor_3(volts: float = 12.0, tol: float = 0.05):
    """A DC motor with its armature current (J=0.01, b=0.1, K=0.01, R=1, L=0.5): angle, speed,
    current; encoder on the angle; turn to 1 rad and hold."""
    J, b, K, R, L = 0.01, 0.1, 0.01, 1.0, 0.5
    A = [[0, 1, 0], [0, -b / J, K / J], [0, -K / L, -R / L]]
    plant = control.ss(A, [[0], [0], [1 / L]], [[1, 0, 0]], [[0]])
    return _hold_problem(
        plant, 0.1, np.diag([0.0, 0.01, 0.0]), [[0.01**2]], 0, 1.0, tol, -volts, volts,
        [0.0, 0.0, 0.0], np.diag([1e-4, 1e-4, 1e-4]), 50, 10,
    )  # fmt: skip


def motor_speed():
    """A DC motor's speed loop (rad/s), input voltage 0..24 V; reach 100 rad/s +-3 and hold."""
    plant = control.ss([[-2.0]], [[10.0]], [[1.0]], [[0]])
    return _hold_problem(
        plant, 0.05, [[4.0]], [[1.0]], 0, 100.0, 3.0, 0.0, 24.0, [0.0], [[1.0]], 40, 10,
    )  # fmt: skip


def mass_spring_damper(k: float, c: float, force: float, goal: float, tol: float):
    """A 1 kg mass on a spring (k N/m) and damper (c N s/m), force input; position sensor."""
    plant = control.ss([[0, 1], [-k, -c]], [[0], [1]], [[1, 0]], [[0]])
    return _hold_problem(
        plant, 0.05, np.diag([0.0, 0.01]), [[0.005**2]], 0, goal, tol, -force, force,
        [0.0, 0.0], np.diag([1e-4, 1e-4]), 60, 10,
    )  # fmt: skip


def quadrotor_altitude(drag: float, accel: float, speed_limit: float | None):
    """A quadrotor's altitude (m) and climb rate (m/s), thrust beyond hover as an acceleration
    (m/s^2); barometer on the altitude; climb to 2 m and hold +-0.1 (optionally never faster
    than ``speed_limit``)."""
    plant = control.ss([[0, 1], [0, -drag]], [[0], [1]], [[1, 0]], [[0]])
    extra = None
    if speed_limit is not None:
        lim = speed_limit

        def extra(x: Any) -> list[Any]:
            return [stl.prob(x[1] <= lim) >= 0.95, stl.prob(x[1] >= -lim) >= 0.95]

    return _hold_problem(
        plant, 0.1, np.diag([0.0, 0.02]), [[0.03**2]], 0, 2.0, 0.1, -accel, accel,
        [0.0, 0.0], np.diag([1e-3, 1e-4]), 50, 10, extra,
    )  # fmt: skip


def thermal(two_mass: bool):
    """A heated room (deg C above ambient 20), heater duty 0..1 (3 kW); reach 45 deg C +-1 and
    hold. ``two_mass``: the room air exchanges with a slow wall mass (air, wall)."""
    if two_mass:
        A = [[-1 / 5 - 1 / 8, 1 / 8], [1 / 40, -1 / 40 - 1 / 60]]
        plant = control.ss(A, [[15.0], [0.0]], [[1, 0]], [[0]])
        qc, start_cov = np.diag([0.05, 0.01]), np.diag([0.1, 0.1])
    else:
        plant = control.ss([[-1 / 5]], [[10.0]], [[1.0]], [[0]])
        qc, start_cov = [[0.05]], [[0.1]]
    n = 2 if two_mass else 1
    return _hold_problem(
        plant, 0.5, qc, [[0.1**2]], 0, 25.0, 1.0, 0.0, 1.0, np.zeros(n), start_cov, 60, 10,
    )  # fmt: skip


PLANTS: dict[str, Callable[[], stl.Problem]] = {
    "dc_motor_slow": lambda: dc_motor(tau=1.0, gain=1.0, volts=2.0, tol=0.05),
    "dc_motor_fast": lambda: dc_motor(tau=0.1, gain=1.0, volts=12.0, tol=0.05),
    "dc_motor_current": dc_motor_3,
    "motor_speed": motor_speed,
    "msd_soft": lambda: mass_spring_damper(k=2.0, c=0.5, force=5.0, goal=0.5, tol=0.05),
    "msd_stiff": lambda: mass_spring_damper(k=20.0, c=1.0, force=30.0, goal=1.0, tol=0.02),
    "quad_altitude": lambda: quadrotor_altitude(drag=0.1, accel=3.0, speed_limit=None),
    "quad_altitude_speed_limit": lambda: quadrotor_altitude(drag=0.3, accel=2.0, speed_limit=1.0),
    "thermal_room": lambda: thermal(False),
    "thermal_two_mass": lambda: thermal(True),
}
"""The ten instances, by name."""


def run_one(name: str, tracking: str, runs: int) -> dict[str, Any]:
    """Solve ``name`` under ``tracking`` and validate its plan ``runs`` times."""
    problem = PLANTS[name]()
    row: dict[str, Any] = {"name": name, "tracking": tracking}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        r = problem.solve_result(tracking=tracking, **OPTIONS)
        row["time"] = time.perf_counter() - t0
    row["status"], row["candidates"] = r.status, r.stats.candidates
    if r.trajectory is None:
        return row
    plan = r.trajectory
    row["gains"] = r.tracking.name if r.tracking is not None else "-"
    row["pred"] = (r.execution.belief_estimate, r.execution.state_estimate) if r.execution else None
    row["meets"] = bool(r.meets_target)
    row["tv"] = float(np.abs(np.diff(plan.get_control(), axis=0)).sum())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rep = stl.validate(problem, plan, None, runs=runs, seed=2026, executor="serial")
    b, s = round(rep.belief_success_rate * runs), round(rep.state_success_rate * runs)
    row["mc"] = (b / runs, s / runs)
    row["ci"] = (wilson_interval(b, runs), wilson_interval(s, runs))
    row["at_target"] = row["ci"][0][1] >= TARGET[0] and row["ci"][1][1] >= TARGET[1]
    return row


def _pct(x: float) -> str:
    return f"{100 * x:.1f}"


def table(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| plant | tracking | status | gains used | predicted b / s | measured b / s [95% Wilson] | "
        "meets target (measured) | input TV | time (s) | candidates |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        if "mc" not in row:
            lines.append(
                f"| {row['name']} | {row['tracking']} | {row['status']} | - | - | - | NO | - | "
                f"{row['time']:.1f} | {row['candidates']} |"
            )
            continue
        (lb, hb), (ls, hs) = row["ci"]
        pred = row["pred"]
        lines.append(
            f"| {row['name']} | {row['tracking']} | {row['status']} | {row['gains']} | "
            f"{_pct(pred[0])} / {_pct(pred[1])} | {_pct(row['mc'][0])} [{_pct(lb)}, {_pct(hb)}] / "
            f"{_pct(row['mc'][1])} [{_pct(ls)}, {_pct(hs)}] | {'yes' if row['at_target'] else 'NO'} | "
            f"{row['tv']:.3g} | {row['time']:.1f} | {row['candidates']} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--plants", default="")
    ap.add_argument("--trackings", default="fitted,paper")
    ap.add_argument("--out", default="")
    args = ap.parse_args(argv)
    names = [n for n in args.plants.split(",") if n] or list(PLANTS)
    rows = []
    for name in names:
        for tracking in args.trackings.split(","):
            rows.append(run_one(name, tracking, args.runs))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    text = table(rows)
    summary = []
    for tracking in args.trackings.split(","):
        mine = [r for r in rows if r["tracking"] == tracking]
        summary.append(f"- `{tracking}`: {sum(bool(r.get('at_target')) for r in mine)}/{len(mine)} at target")
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    out = f"commit {commit}; {args.runs} validated runs per plan\n\n{text}\n\n" + "\n".join(summary) + "\n"
    print(out)
    if args.out:
        Path(args.out).write_text(out)


if __name__ == "__main__":
    main()
