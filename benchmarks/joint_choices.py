"""Discrete choices decided in one solve (issue 31): benchmark families for the joint MILP.

``python -m benchmarks.joint_choices [--seeds 10] [--families a,b] [--time-limit 60] [--lazy]
[--out benchmarks/joint_choices_results.md]``; ``--witnesses`` checks the witnesses instead.

Families (built with the public API only; the modes are those of ``sensing_families.sensor_cost``:
drive ``B = 0.25 I`` blind, sense ``B = 0.05 I`` with ``C = I, V = 0.1 I``, both ``W = 0.01 I``;
the prior ``N(0, 0.2 I)``; ``free = [-2, 5] x [-2, 2]`` at 99%; the target
``[2.75, 3.25] x [-0.25, 0.25]`` at 95%, held for ``hold`` steps):

- ``obstacle``: the two-mode robot past a box obstacle ``[1.2, 1.8] x [-0.6, 0.6]`` written as a
  four-way disjunction (left of, right of, below or above it, each at 99%) against the same robot
  without it (``open``): the issue's goal is ``obstacle`` within 5x ``open``;
- ``three_modes``: fast-blind (``B = 0.3 I``), slow-noisy (``B = 0.08 I``, ``V = 0.3 I``) and
  stopped-precise (``B = 0``, ``V = 0.02 I``), a deadline (``x >= 1.5`` by step 8), a dock whose
  precision only the stopped look gives;
- ``quiet_zone``: sensing forbidden while the robot may be in the strip ``1 <= x <= 2``
  (``G(x <= 1 | x >= 2 | drive)``, each side at 99%);
- ``duty_cycle``: a camera duty cycle on the mode variable, ``G(drive | G[1,5] drive)`` (a frame
  is followed by five without), where the target needs two frames (``V = 0.1 I``, a tighter
  target of half-width 0.2);
- ``infeasible``: ``look_or_move`` (a 1-D robot: move ``|u| <= 1`` blind, or stop and look
  precisely; the goal 3 away at 95% with half-width 0.1 by step 3: three moves and a look do not
  fit in three steps; with 6 away by step 6, likewise) and ``floor_three`` (three sensing modes
  whose best look leaves a variance above what the goal asks: the fixed point of the best update).

Every row records status, wall-clock time, candidates (lazy candidates plus the joint MILP's
plans handed to the plan LP) and MILP solves per seed; the summary gives found (or proven
infeasible) over seeds, median / p90 time, median / max proposals, and whether the returned plan
meets the execution target.
"""

from __future__ import annotations

import argparse
import datetime as dt
import subprocess
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import idstlpy as stl

from .perception_problems import Script
from .sensing_families import _box, _domain, _prob, check_plan, predicted_rates

__all__ = ["FAMILIES", "JInstance", "instances", "main", "run_one", "witness_rows"]

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class JInstance:
    """One instance: its builder returns ``(problem, witness)`` (a plan or None)."""

    family: str
    name: str
    build: Callable[[], tuple[stl.Problem, Any]]
    expected: str  # "feasible" or "infeasible"


def _two_modes(v: float = 0.1) -> list[Any]:
    drive = stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=0.01 * np.eye(2))
    sense = stl.mk_lbs(A=np.eye(2), B=0.05 * np.eye(2), W=0.01 * np.eye(2), C=np.eye(2), V=v * np.eye(2))
    return [drive, sense]


def _target(x: Any, half: float = 0.25) -> Any:
    return _box(x, [3.0 - half, -half], [3.0 + half, half], 0.95, "tgt")


def obstacle(box: bool = True, hold: int = 5, horizon: int = 40) -> tuple[stl.Problem, Any]:
    """The two-mode robot past a box obstacle (``box``) or in the open (module docstring)."""
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    free = _box(x, [-2.0, -2.0], [5.0, 2.0], 0.99, "free")
    safe = free
    if box:
        avoid = stl.logical_or(
            stl.logical_and(_prob(x[0] <= 1.2, 0.99), name="left"),
            stl.logical_and(_prob(x[0] >= 1.8, 0.99), name="right"),
            stl.logical_and(_prob(x[1] <= -0.6, 0.99), name="below"),
            stl.logical_and(_prob(x[1] >= 0.6, 0.99), name="above"),
        )
        safe = stl.logical_and(free, avoid)
    problem = stl.Problem(
        stl.mk_switched_sys(_two_modes()),
        _domain(u, [-1, -1], [1, 1]),
        stl.to_belief(mean=np.zeros(2), cov=0.2 * np.eye(2)),
        stl.until(safe, 0, horizon, stl.always(0, hold, _target(x))),
    )
    s = Script(problem)
    s.wait(3, mode=1)
    if box:
        s.goto([0.6, -1.1], mode=0, speed=0.8).goto([2.4, -1.1], mode=0, speed=0.8)
    s.goto([3.0, 0.0], mode=0, speed=0.8).wait(hold + 1, mode=1)
    return problem, s.plan()


def three_modes(deadline: int = 8, horizon: int = 30) -> tuple[stl.Problem, Any]:
    """Fast-blind, slow-noisy and stopped-precise modes, a deadline and a precise dock."""
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    fast = stl.mk_lbs(A=np.eye(2), B=0.3 * np.eye(2), W=0.01 * np.eye(2))
    slow = stl.mk_lbs(A=np.eye(2), B=0.08 * np.eye(2), W=0.01 * np.eye(2), C=np.eye(2), V=0.3 * np.eye(2))
    stop = stl.mk_lbs(A=np.eye(2), B=np.zeros((2, 2)), W=0.01 * np.eye(2), C=np.eye(2), V=0.02 * np.eye(2))
    free = _box(x, [-2.0, -2.0], [5.0, 2.0], 0.99, "free")
    reach = stl.logical_and(_prob(x[0] >= 1.5, 0.9), name="half_way")
    dock = _box(x, [2.9, -0.1], [3.1, 0.1], 0.95, "dock")
    problem = stl.Problem(
        stl.mk_switched_sys([fast, slow, stop]),
        _domain(u, [-1, -1], [1, 1]),
        stl.to_belief(mean=np.zeros(2), cov=0.2 * np.eye(2)),
        stl.logical_and(
            stl.eventually(0, deadline, reach), stl.until(free, 0, horizon, stl.always(0, 2, dock))
        ),
    )
    s = Script(problem)
    s.goto([1.8, 0.0], mode=0, speed=0.9).goto([2.4, 0.0], mode=1).wait(4, mode=2)
    s.goto([3.0, 0.0], mode=0, speed=0.8).wait(4, mode=2)
    return problem, s.plan()


def quiet_zone(horizon: int = 40, hold: int = 5) -> tuple[stl.Problem, Any]:
    """Sensing forbidden while the robot may be in the strip ``1 <= x <= 2``."""
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    q = stl.mk_variable(size=2, dtype=int)
    free = _box(x, [-2.0, -2.0], [5.0, 2.0], 0.99, "free")
    quiet = stl.logical_or(
        stl.logical_and(_prob(x[0] <= 1.0, 0.99), name="before"),
        stl.logical_and(_prob(x[0] >= 2.0, 0.99), name="after"),
        q == 0,
    )
    problem = stl.Problem(
        stl.mk_switched_sys(_two_modes()),
        _domain(u, [-1, -1], [1, 1]),
        stl.to_belief(mean=np.zeros(2), cov=0.2 * np.eye(2)),
        stl.until(
            stl.logical_and(free, quiet), 0, horizon, stl.always(0, hold, stl.logical_and(_target(x), quiet))
        ),
    )
    s = Script(problem)
    s.wait(3, mode=1).goto([3.0, 0.0], mode=0, speed=0.8).wait(hold + 1, mode=1)
    return problem, s.plan()


def duty_cycle(horizon: int = 40, hold: int = 3, gap: int = 5) -> tuple[stl.Problem, Any]:
    """A camera duty cycle on the mode variable; the target needs two frames."""
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    q = stl.mk_variable(size=2, dtype=int)
    free = _box(x, [-2.0, -2.0], [5.0, 2.0], 0.99, "free")
    cycle = stl.logical_or(q == 0, stl.always(1, gap, q == 0))
    problem = stl.Problem(
        stl.mk_switched_sys(_two_modes()),
        _domain(u, [-1, -1], [1, 1]),
        stl.to_belief(mean=np.zeros(2), cov=0.2 * np.eye(2)),
        stl.until(
            stl.logical_and(free, cycle),
            0,
            horizon,
            stl.always(0, hold, stl.logical_and(_target(x, 0.2), cycle)),
        ),
    )
    s = Script(problem)
    s.goto([3.0, 0.0], mode=0, speed=0.8).wait(1, mode=1).wait(gap, mode=0).wait(1, mode=1)
    s.wait(gap + hold, mode=0)
    return problem, s.plan()


def look_or_move(distance: int = 3) -> tuple[stl.Problem, Any]:
    """Infeasible: ``distance`` moves (``|u| <= 1``) and a look do not fit in ``distance`` steps."""
    x = stl.mk_variable(size=1, dtype=float)
    u = stl.mk_variable(size=1, dtype=float, name="u")
    move = stl.mk_lbs(A=np.eye(1), B=np.eye(1), W=0.01 * np.eye(1))
    look = stl.mk_lbs(A=np.eye(1), B=np.zeros((1, 1)), W=0.01 * np.eye(1), C=np.eye(1), V=0.01 * np.eye(1))
    goal = stl.logical_and(
        _prob(x[0] >= distance - 0.1, 0.95), _prob(x[0] <= distance + 0.1, 0.95), name="goal"
    )
    problem = stl.Problem(
        stl.mk_switched_sys([move, look]),
        _domain(u, [-1], [1]),
        stl.to_belief(mean=np.zeros(1), cov=np.eye(1)),
        stl.eventually(0, distance, goal),
    )
    return problem, None


def floor_three() -> tuple[stl.Problem, Any]:
    """Infeasible: three sensing modes (``V = 0.5, 0.45, 0.4``, ``W = 0.1``: best fixed point
    ``p = (p + 0.01) 0.16 / (p + 0.17)``, sd 0.188 per axis) against a goal asking sd 0.122."""
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    modes = [
        stl.mk_lbs(A=np.eye(2), B=b * np.eye(2), W=0.1 * np.eye(2), C=np.eye(2), V=v * np.eye(2))
        for b, v in ((0.5, 0.5), (0.3, 0.45), (0.0, 0.4))
    ]
    goal = _box(x, [2.8, 2.8], [3.2, 3.2], 0.95, "goal")
    problem = stl.Problem(
        stl.mk_switched_sys(modes),
        _domain(u, [-1, -1], [1, 1]),
        stl.to_belief(mean=np.zeros(2), cov=0.1 * np.eye(2)),
        stl.eventually(0, 20, goal),
    )
    return problem, None


def instances() -> list[JInstance]:
    """Every instance, family by family."""
    return [
        JInstance("obstacle", "box", lambda: obstacle(True), "feasible"),
        JInstance("obstacle", "open", lambda: obstacle(False), "feasible"),
        JInstance("three_modes", "d8", lambda: three_modes(8), "feasible"),
        JInstance("quiet_zone", "strip", lambda: quiet_zone(), "feasible"),
        JInstance("duty_cycle", "gap5", lambda: duty_cycle(), "feasible"),
        JInstance("infeasible", "look_or_move3", lambda: look_or_move(3), "infeasible"),
        JInstance("infeasible", "look_or_move6", lambda: look_or_move(6), "infeasible"),
        JInstance("infeasible", "floor_three", floor_three, "infeasible"),
    ]


FAMILIES = sorted({i.family for i in instances()})


def run_one(inst: JInstance, seed: int, time_limit: float, lazy: bool = False) -> dict[str, Any]:
    """Solve one instance with one seed; a row (``lazy``: the joint MILP switched off)."""
    from idstlpy.synthesis import eager

    eager.JOINT_MODES = not lazy
    problem, _ = inst.build()
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = problem.solve_result(seed=seed, time_limit=time_limit)
    wall = time.perf_counter() - t0
    row: dict[str, Any] = {
        "family": inst.family,
        "instance": inst.name,
        "expected": inst.expected,
        "seed": seed,
        "status": result.status,
        "time": wall,
        "candidates": result.stats.candidates,
        "milp": result.stats.milp_calls,
        "meets": getattr(result, "meets_target", None),
        "reason": " ".join(str(result.reason).split())[:160],
        "oracle": None,
        "modes": None,
    }
    if result.status == "found" and result.trajectory is not None:
        traj = result.trajectory
        plan = (np.asarray(traj.get_action(), dtype=int), np.asarray(traj.get_control(), dtype=float))
        row["oracle"] = check_plan(problem, plan)
        row["modes"] = "".join(str(int(a)) for a in plan[0])
    return row


def witness_rows() -> list[str]:
    """Markdown rows: each feasible instance's witness checked by the oracles and predicted."""
    out = ["| family | instance | witness (oracles) | predicted belief / state |", "|---|---|---|---|"]
    for inst in instances():
        problem, plan = inst.build()
        if plan is None:
            continue
        ok = check_plan(problem, plan)
        b, s = predicted_rates(problem, plan)
        out.append(f"| {inst.family} | {inst.name} | {'holds' if ok else 'fails'} | {b:.3f} / {s:.3f} |")
    return out


def _summary(rows: list[dict[str, Any]]) -> list[str]:
    out = [
        "| family | instance | expected | ok / seeds | median s | p90 s | proposals median / max | "
        "MILPs median | meets target | oracle | modes (seed 0) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    keys = sorted({(r["family"], r["instance"]) for r in rows}, key=lambda k: (k[0], k[1]))
    for fam, name in keys:
        rs = [r for r in rows if r["family"] == fam and r["instance"] == name]
        expected = rs[0]["expected"]
        want = "found" if expected == "feasible" else "infeasible"
        ok = sum(r["status"] == want for r in rs)
        times = np.array([r["time"] for r in rs])
        props = np.array([r["candidates"] + r["milp"] for r in rs])
        milps = np.array([r["milp"] for r in rs])
        meets = sum(bool(r["meets"]) for r in rs if r["status"] == "found")
        oracle = sum(bool(r["oracle"]) for r in rs if r["status"] == "found")
        found = sum(r["status"] == "found" for r in rs)
        out.append(
            f"| {fam} | {name} | {expected} | {ok}/{len(rs)} | {np.median(times):.2f} | "
            f"{np.percentile(times, 90):.2f} | {int(np.median(props))} / {int(props.max())} | "
            f"{int(np.median(milps))} | {meets}/{found} | {oracle}/{found} | "
            f"{rs[0]['modes'] or rs[0]['status']} |"
        )
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--families", default="")
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--lazy", action="store_true", help="the joint MILP switched off (the lazy loop)")
    ap.add_argument("--witnesses", action="store_true")
    ap.add_argument("--out", default="")
    args = ap.parse_args(argv)
    if args.witnesses:
        print("\n".join(witness_rows()))
        return
    want = {f for f in args.families.split(",") if f}
    rows = []
    for inst in instances():
        if want and inst.family not in want:
            continue
        for seed in range(args.seeds):
            row = run_one(inst, seed, args.time_limit, args.lazy)
            rows.append(row)
            print(
                f"{row['family']}/{row['instance']} seed {seed}: {row['status']} {row['time']:.2f} s, "
                f"{row['candidates']} candidates, {row['milp']} MILPs, meets {row['meets']}, "
                f"oracle {row['oracle']}, modes {row['modes']}; {row['reason'][:90]}",
                flush=True,
            )
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT)
    lines = [
        f"Run {dt.datetime.now(dt.UTC):%Y-%m-%d %H:%M} UTC at {commit.stdout.strip()}, "
        f"{'lazy loop' if args.lazy else 'default (joint MILP after the lazy loop stalls)'}, "
        f"{args.seeds} seeds, cap {args.time_limit:g} s",
        "",
        *_summary(rows),
    ]
    print("\n".join(lines))
    if args.out:
        with open(args.out, "a", encoding="utf-8") as fh:
            fh.write("\n" + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
