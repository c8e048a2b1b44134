"""Does the light-dark plan hold under real noise? Monte Carlo validation over planner seeds.

Run: ``python -m benchmarks.execution [--seeds 10] [--runs 200] [--deadline 240 --hold 40]``.

For every planner seed the paper's listing is solved, the plan is executed ``runs`` times against
the noise-free real system with observations drawn at the true state (LQR tracking as in the
listing), and :func:`idstlpy.validate` reports how often the executed belief and the true states
satisfy the formula. Prints a Markdown table (one row per seed, then the pooled rates).
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time

import numpy as np

from idstlpy.execution import validate
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system

_SOLVER = {
    "rrt_timeout": 60,
    "delta_near": 2,
    "delta_drain": 0.5,
    "goal_bias": 0.25,
    "min_num_of_steps": 3,
    "max_num_of_steps": 15,
}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.execution",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--runs", type=int, default=200)
    p.add_argument("--deadline", type=int, default=240)
    p.add_argument("--hold", type=int, default=40)
    a = p.parse_args(argv)

    print(
        f"light-dark deadline {a.deadline}, hold {a.hold}: {a.runs} executions per plan, "
        "LQR horizon 5, Q = I, R = 0.05 I, controls clipped to the domain\n"
    )
    print(
        "| seed | solve (s) | plan steps | plan margin | belief ok | belief 95% CI | state ok | "
        "state 95% CI | validate (s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    belief, state, runs, solve_times = 0, 0, 0, []
    for seed in range(a.seeds):
        problem = light_dark(deadline=a.deadline, hold=a.hold)
        t0 = time.perf_counter()
        plan = problem.solve(**_SOLVER, seed=seed)
        solve_s = time.perf_counter() - t0
        if plan is None:
            print(f"| {seed} | {solve_s:.3f} | no plan | | | | | | |")
            continue
        solve_times.append(solve_s)
        for mode in problem.switched_system.system_modes:
            mode.compute_finite_horizon_lqr(
                horizon=5, Q_final=np.identity(2), Q=np.identity(2), R=0.05 * np.identity(2)
            )
        rep = validate(
            problem,
            plan,
            light_dark_real_system(),
            LIGHT_DARK_REAL_INITIAL_STATE,
            runs=a.runs,
            seed=seed,
            problem_factory=functools.partial(light_dark, a.deadline, a.hold),
        )
        belief += rep.belief_successes
        state += rep.state_successes
        runs += rep.runs
        print(
            f"| {seed} | {solve_s:.3f} | {plan.num_of_steps} | {rep.plan_margin:.3g} | "
            f"{rep.belief_success_rate:.1%} | [{rep.belief_ci[0]:.1%}, {rep.belief_ci[1]:.1%}] | "
            f"{rep.state_success_rate:.1%} | [{rep.state_ci[0]:.1%}, {rep.state_ci[1]:.1%}] | "
            f"{rep.elapsed:.1f} |"
        )
    if runs:
        print(
            f"\npooled over {runs} executions: belief {belief / runs:.1%}, true state {state / runs:.1%}; "
            f"median solve {statistics.median(solve_times):.3f} s"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
