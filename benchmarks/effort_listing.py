"""Issue 13's effort goal on the paper's light-dark listing: ``objective="effort"`` against the default plan.

``python -m benchmarks.effort_listing [--seeds 10] [--runs 100]``

For each seed, in one process and alternating (default first, then effort), the listing is
solved with the paper's sampler parameters; reported per seed: the plans' ``sum_k ||u_k||_1``,
their monitor margin, CPU and wall solve time, and (with ``--runs``) how often each plan held
under the paper's execution (``stl.validate``: LQR tracking, Kalman filter, the true start offset
like the paper's). The goal: effort lower by at least 30% at most 3x the default's solve time,
execution rates not below the default plan's.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

import idstlpy as stl
from idstlpy.scenarios import light_dark, light_dark_real_system

LISTING = dict(
    rrt_timeout=60, delta_near=2, delta_drain=0.5, goal_bias=0.25, min_num_of_steps=3, max_num_of_steps=15
)
# The paper's true start: the prior mean offset by (1.58, 0.79) prior standard deviations.
TRUE_START = np.array([0.0, 2.5]) + np.array([1.58, 0.79]) * np.sqrt(0.1)


def _solve(seed: int, objective: str | None) -> tuple[stl.SolveResult, float, float]:
    problem = light_dark()
    c0, w0 = time.process_time(), time.perf_counter()
    result = problem.solve_result(**LISTING, seed=seed, objective=objective)
    return result, time.process_time() - c0, time.perf_counter() - w0


def _rates(result: stl.SolveResult, runs: int, seed: int) -> tuple[float, float]:
    if runs <= 0 or result.trajectory is None:
        return float("nan"), float("nan")
    report = stl.validate(
        light_dark(),
        result.trajectory,
        light_dark_real_system(),
        TRUE_START,
        runs=runs,
        seed=seed,
        executor="serial",
    )
    return report.belief_success_rate, report.state_success_rate


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.effort_listing", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--runs", type=int, default=100, help="Monte Carlo executions per plan (0: none)")
    args = parser.parse_args(argv)
    _solve(0, None)  # warm-up: imports and caches outside the measurement
    print(f"nproc {os.cpu_count()}, load {os.getloadavg()[0]:.1f}")
    print(
        "| seed | effort default | effort objective | saving | margin d / e | cpu d / e s | ratio "
        "| belief d / e | state d / e |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    savings, ratios, wall_ratios = [], [], []
    for seed in range(args.seeds):
        base, bc, bw = _solve(seed, None)
        lean, lc, lw = _solve(seed, "effort")
        if base.trajectory is None or lean.trajectory is None:
            print(f"| {seed} | {base.status} | {lean.status} | - | - | - | - | - | - |")
            continue
        e0 = float(np.abs(base.trajectory.get_control()).sum())
        e1 = float(np.abs(lean.trajectory.get_control()).sum())
        rb, rl = _rates(base, args.runs, seed), _rates(lean, args.runs, seed)
        savings.append(1 - e1 / e0)
        ratios.append(lc / bc)
        wall_ratios.append(lw / bw)
        print(
            f"| {seed} | {e0:.2f} | {e1:.2f} | {1 - e1 / e0:.0%} | {base.margin:.3g} / {lean.margin:.3g} "
            f"| {bc:.2f} / {lc:.2f} | {lc / bc:.2f} | {rb[0]:.2f} / {rl[0]:.2f} | {rb[1]:.2f} / {rl[1]:.2f} |"
        )
    if savings:
        print(
            f"\nmedian saving {statistics.median(savings):.0%} (min {min(savings):.0%}); median time ratio "
            f"effort / default {statistics.median(ratios):.2f} CPU, "
            f"{statistics.median(wall_ratios):.2f} wall "
            f"(max {max(ratios):.2f} CPU); load {os.getloadavg()[0]:.1f} at the end"
        )


if __name__ == "__main__":
    main()
