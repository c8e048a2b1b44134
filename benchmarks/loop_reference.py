"""A fingerprint of the synthesis loop's answers on a fixed set of problems, to show a refactoring
of the loop changes none of them (issue 22).

Each problem is solved with fixed seeds and work budgets (candidates, sampler iterations; the
wall-clock caps are generous, so they decide nothing on a quiet machine) and recorded: status,
reason, candidates, LP calls, the plan's modes, a hash of its controls (rounded to 1e-12), the
monitor margin, and the objective's value, bound and optimality flag. The set covers every path of
the loop: the listing (the sampler), the perception suite's small problems (one and two modes),
problems of issue 23 (one and two modes, the default guarantee), an infeasible one, objectives
(the eager MILP, the plan LP's re-timing, the sampler's refinement), ``guarantee="mlo"`` and
``guarantee="closed_loop"``, and two independent robots (the decoupled path).

Usage (from the repository root, ``PYTHONPATH=src:.``)::

    python -m benchmarks.loop_reference --write benchmarks/results/loop_reference.json
    python -m benchmarks.loop_reference --check benchmarks/results/loop_reference.json

``--check`` exits 1 and names the fields when any record differs; ``--only NAME,...`` limits the
run to some problems.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

import idstlpy as stl
from benchmarks import defaults_problems, perception_problems
from benchmarks.dims_family import RobotsLight
from idstlpy.scenarios import light_dark, reach_avoid

LISTING = dict(
    rrt_timeout=60, delta_near=2, delta_drain=0.5, goal_bias=0.25, min_num_of_steps=3, max_num_of_steps=15
)
"""The paper's listing's sampler options."""
CAPS = dict(time_limit=120, max_candidates=400)
"""Generous wall-clock cap, and a work budget that decides instead."""


def _unreachable() -> stl.Problem:
    """``F[0,10] goal`` with the goal 36 steps away (examples/unsatisfiable.toml): infeasible."""
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    mode = stl.mk_lbs(np.eye(2), 0.25 * np.eye(2), np.zeros((2, 2)))
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    goal = stl.logical_and(
        stl.prob(x[0] >= 9) >= 0.9,
        stl.prob(x[0] <= 10) >= 0.9,
        stl.prob(x[1] >= -0.5) >= 0.9,
        stl.prob(x[1] <= 0.5) >= 0.9,
        name="goal",
    )
    belief = stl.to_belief([0.0, 0.0], 0.01 * np.eye(2))
    return stl.Problem(stl.mk_switched_sys([mode]), domain, belief, stl.eventually(0, 10, goal))


def _two_robots() -> stl.Problem:
    """Two independent 2-D single integrators, each to its own box (the decoupled path)."""
    x = stl.mk_variable(4)
    u = stl.mk_variable(4, name="u")
    bounds = []
    for j in range(4):
        bounds += [u[j] >= -1, u[j] <= 1]

    def box(i: int, lo: tuple[float, float], hi: tuple[float, float], name: str) -> Any:
        return stl.logical_and(
            stl.prob(x[2 * i] >= lo[0]) >= 0.9,
            stl.prob(x[2 * i] <= hi[0]) >= 0.9,
            stl.prob(x[2 * i + 1] >= lo[1]) >= 0.9,
            stl.prob(x[2 * i + 1] <= hi[1]) >= 0.9,
            name=name,
        )

    formula = stl.logical_and(
        stl.eventually(0, 30, box(0, (-0.5, -0.5), (0.5, 0.5), "g0")),
        stl.eventually(0, 30, box(1, (0.5, 2.5), (1.5, 3.5), "g1")),
    )
    noise = RobotsLight(2, a=0.01, b=0.05)  # state-dependent, block-diagonal: the blocks split
    mode = stl.mk_lbs(np.eye(4), 0.25 * np.eye(4), np.zeros((4, 4)), C=np.eye(4), V=noise)
    belief = stl.to_belief(np.array([0.0, 2.0, 1.0, 0.0]), 0.01 * np.eye(4))
    return stl.Problem(stl.mk_switched_sys([mode]), stl.logical_and(*bounds).region, belief, formula)


def _perception(kind: str) -> Callable[[], stl.Problem]:
    return lambda: perception_problems.build(kind, "small")[0]


# name -> (builder, solve_result keywords)
PROBLEMS: dict[str, tuple[Callable[[], stl.Problem], dict[str, Any]]] = {
    "listing": (light_dark, {**LISTING, "seed": 0}),
    "listing_time": (light_dark, {**LISTING, "seed": 0, "objective": "time"}),
    "perception_patrol": (_perception("patrol"), {**LISTING, "seed": 0}),
    "perception_noisy_hold": (_perception("noisy_hold"), {**LISTING, "seed": 1}),
    "perception_sensor_switching": (_perception("sensor_switching"), {**LISTING, "seed": 0}),
    "defaults_corridor": (defaults_problems.corridor, {"seed": 0}),
    "defaults_two_goals": (defaults_problems.two_goals, {"seed": 0}),
    "defaults_avoid_1d": (defaults_problems.avoid_1d, {"seed": 0}),
    "defaults_one_d": (defaults_problems.one_d, {"seed": 0}),
    "defaults_drive_look": (defaults_problems.drive_look, {"seed": 0}),
    "defaults_drive_look_mlo": (defaults_problems.drive_look, {"seed": 0, "guarantee": "mlo"}),
    "defaults_thermal_dark": (defaults_problems.thermal_dark, {"seed": 0}),
    "defaults_avoid_1d_closed_loop": (defaults_problems.avoid_1d, {"seed": 0, "guarantee": "closed_loop"}),
    "defaults_one_d_closed_loop": (defaults_problems.one_d, {"seed": 0, "guarantee": "closed_loop"}),
    "infeasible": (_unreachable, {"seed": 0}),
    "reach_avoid_eager": (lambda: reach_avoid(25), {**LISTING, "seed": 0, "lazy_candidates": 3}),
    "reach_avoid_lazy": (lambda: reach_avoid(25), {**LISTING, "seed": 0, "lazy_candidates": 1000}),
    "reach_avoid_effort": (lambda: reach_avoid(25), {"seed": 0, "objective": "effort"}),
    "reach_avoid_margin": (lambda: reach_avoid(25), {"seed": 0, "objective": "margin"}),
    "reach_avoid_time": (lambda: reach_avoid(25), {"seed": 0, "objective": "time"}),
    "avoid_1d_effort": (defaults_problems.avoid_1d, {"seed": 0, "objective": "effort"}),
    "listing_effort": (light_dark, {**LISTING, "seed": 0, "objective": "effort"}),
    "defaults_drive_sense_below": (defaults_problems.drive_sense, {"seed": 0}),
    "defaults_drive_look_capped": (defaults_problems.drive_look, {"seed": 0, "max_candidates": 30}),
    "two_robots": (_two_robots, {"seed": 0, "guarantee": "mlo", "sampler_iterations": 3000}),
}


def _float(v: float) -> str:
    """A float as text that survives JSON exactly (NaN included)."""
    return repr(float(v))


def record(name: str) -> dict[str, Any]:
    """Solve problem ``name`` and return its fingerprint."""
    build, kwargs = PROBLEMS[name]
    problem = build()
    result = problem.solve_result(**{**CAPS, **kwargs})
    traj = result.trajectory
    out: dict[str, Any] = {
        "status": result.status,
        "reason": result.reason,
        "candidates": result.stats.candidates,
        "refuted": result.stats.refuted,
        "abandoned": result.stats.abandoned,
        "lp_calls": result.stats.lp_calls,
        "milp_calls": result.stats.milp_calls,
        "margin": _float(result.margin),
        "optimal": result.optimal,
        "objective_value": _float(result.objective_value),
        "objective_bound": _float(result.objective_bound),
        "optimal_scope": result.optimal_scope,
        "meets_target": None if result.execution is None else bool(result.execution.meets_target),
    }
    if traj is not None:
        controls = np.ascontiguousarray(np.round(np.asarray(traj.get_control(), dtype=float), 12))
        out["actions"] = [int(a) for a in traj.get_action()]
        out["controls_sha256"] = hashlib.sha256(controls.tobytes()).hexdigest()
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    group = p.add_mutually_exclusive_group(required=True)
    group.add_argument("--write", metavar="PATH", help="record the fingerprints into PATH")
    group.add_argument("--check", metavar="PATH", help="compare with the fingerprints in PATH")
    p.add_argument("--only", default="", help="comma-separated problem names (default: all)")
    args = p.parse_args(argv)
    names = [n for n in args.only.split(",") if n] or list(PROBLEMS)
    got: dict[str, Any] = {}
    for name in names:
        t0 = time.perf_counter()
        got[name] = record(name)
        print(f"{name}: {got[name]['status']} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    if args.write:
        with open(args.write, "w") as f:
            json.dump(got, f, indent=1, sort_keys=True)
            f.write("\n")
        return 0
    with open(args.check) as f:
        reference = json.load(f)
    bad = 0
    for name in names:
        want, have = reference.get(name), got[name]
        if want != have:
            bad += 1
            fields = sorted(k for k in set(want or {}) | set(have) if (want or {}).get(k) != have.get(k))
            print(f"DIFFERS {name}: {', '.join(fields)}")
            for k in fields:
                print(f"    {k}: {(want or {}).get(k)!r} -> {have.get(k)!r}")
    print(f"{len(names) - bad} / {len(names)} identical")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
