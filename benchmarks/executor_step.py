"""Cost of one :meth:`idstlpy.OnlineExecutor.step` without re-plans (issue 22's online executor).

Run: ``python -m benchmarks.executor_step [--plans 200] [--steps 85] [--seed 0]``.

The executor runs the paper's listing (light-dark: one 2-D mode, a position sensor whose noise is
a Python function of the state, inputs clipped to [-1, 1]^2) on a plan of ``--steps`` steps
(a rollout of the model towards the light and back, the shape and length of the listing's
solved plans), ``--plans`` times from ``reset()``. The observations are drawn beforehand by
:func:`idstlpy.simulate` with the same seed, so the clock measures only what a robot's loop pays
per control period: the filter update with the observation, the tracking law and the projection
on the control domain. Each call is timed with ``time.perf_counter_ns``; the table gives the
median, the 99th and 99.9th percentiles and the maximum over all calls, for the listing and for the
same system with a constant sensor noise (no Python noise function). Goal (issue 22): median
<= 100 microseconds, p99 <= 1 ms.
"""

from __future__ import annotations

import argparse
import gc
import time

import numpy as np

import idstlpy as stl
from idstlpy.scenarios import light_dark


def _plan(system, initial, steps: int) -> stl.ProbabilisticTSTrajectory:
    half = steps // 2
    controls = np.vstack([np.tile([1.0, -0.1], (half, 1)), np.tile([-1.0, 0.0], (steps - half, 1))])
    return stl.rollout(system, initial, np.zeros(steps, dtype=int), 0.25 * controls)


def _constant_noise(system):
    mode = system.mode(0)
    return stl.mk_switched_sys([stl.mk_lbs(A=mode.A, B=mode.B, W=mode.W, C=mode.C, V=0.3 * np.eye(2))])


def measure(system, problem, plans: int, steps: int, seed: int) -> np.ndarray:
    """Per-call times (ns) of ``step`` over ``plans`` executions of a ``steps``-step plan."""
    plan = _plan(system, problem.initial_state, steps)
    _, real = stl.simulate(
        system, plan, steps, np.array([0.5, 2.75]), None, seed=seed, control_domain=problem.control_domain
    )
    observations = [None] + [real.get_observation(k) for k in range(1, steps)]
    executor = stl.OnlineExecutor(system, plan, control_domain=problem.control_domain)
    times = np.empty(plans * steps, dtype=np.int64)
    clock = time.perf_counter_ns
    i = 0
    gc.disable()
    try:
        for _ in range(plans):
            executor.reset()
            for y in observations:
                t0 = clock()
                executor.step(y)
                times[i] = clock() - t0
                i += 1
    finally:
        gc.enable()
    return times


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--plans", type=int, default=200)
    parser.add_argument("--steps", type=int, default=85)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    problem = light_dark()
    rows = [
        "| system | calls | median (us) | p99 (us) | p99.9 (us) | max (us) |",
        "|---|---|---|---|---|---|",
    ]
    for name, system in [
        ("listing (noise function of the state)", problem.switched_system),
        ("listing, constant sensor noise", _constant_noise(problem.switched_system)),
    ]:
        measure(system, problem, 5, args.steps, args.seed)  # warm-up
        t = measure(system, problem, args.plans, args.steps, args.seed) / 1000.0
        q = np.percentile(t, [50, 99, 99.9])
        rows.append(f"| {name} | {t.size} | {q[0]:.1f} | {q[1]:.1f} | {q[2]:.1f} | {t.max():.1f} |")
    table = "\n".join(rows)
    print(table)
    return table


if __name__ == "__main__":
    main()
