"""Monte Carlo at scale (issue 26): ``validate`` over 10,000 executions, batched against the serial loop.

Run: ``python -m benchmarks.montecarlo [--runs 10000] [--serial-runs 1000] [--repeats 3] [--write]``.

Two problems of the same size (2 states, the listing's plan of 85 steps, inputs clipped to
``[-1, 1]^2``, the listing's LQR tracking, the listing's real system):

- ``listing``: the paper's light-dark listing (:func:`idstlpy.scenarios.light_dark`, solved with
  the paper's settings, seed 0); its sensor noise is the Python function
  :func:`~idstlpy.scenarios.light_dark_noise` of the state;
- ``constant``: the same model and plan with a constant sensor noise ``V = 0.3 I``.

For each, side by side in one run: ``validate(..., runs)`` as it is now (``batched=True``) on a
process pool of 2 workers (the default executor) and in-process (``executor="serial"``), and the
loop it replaces (``batched=False``: ``simulate`` and the monitor one run after the other) on the
same pool. The serial loop is timed on ``--serial-runs`` runs and its time scaled to ``--runs``
(its cost is linear in the runs: every run is the same work); ``--serial-runs`` equal to
``--runs`` times it in full. Times are wall-clock medians over ``--repeats`` repetitions; the
same seed gives the same report on every path (checked here, on the first ``--serial-runs``
runs). True starts: the listing's fixed start ``[0.5, 2.75]`` (the paper's execution) and, for the
listing, starts drawn from the prior (``validate``'s default).

Goals (issue 26): 10,000 executions of the listing in <= 3 s on 2 cores, <= 1 s for the
constant-noise problem.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

import idstlpy as stl
from idstlpy.execution import validate
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system

SOLVER = {
    "rrt_timeout": 60,
    "delta_near": 2,
    "delta_drain": 0.5,
    "goal_bias": 0.25,
    "min_num_of_steps": 3,
    "max_num_of_steps": 15,
}
RESULTS = Path(__file__).resolve().parent / "montecarlo_results.md"


def problems() -> dict[str, tuple[Any, Any]]:
    """``{name: (problem, plan)}``: the listing (solved, seed 0) and its constant-noise twin."""
    problem = light_dark()
    plan = problem.solve(**SOLVER, seed=0)
    if plan is None:
        raise SystemExit("the listing has no plan")
    for mode in problem.switched_system.system_modes:
        mode.compute_finite_horizon_lqr(
            horizon=5, Q_final=np.identity(2), Q=np.identity(2), R=0.05 * np.identity(2)
        )
    mode = problem.switched_system.mode(0)
    const = stl.mk_lbs(A=mode.A, B=mode.B, W=mode.W, C=mode.C, V=0.3 * np.eye(2))
    const.lqr_gains = mode.lqr_gains
    twin = stl.Problem(
        switched_system=stl.mk_switched_sys([const]),
        control_domain=problem.control_domain,
        initial_state=problem.initial_state,
        stl_formula=problem.stl_formula,
    )
    twin_plan = stl.rollout(twin.switched_system, twin.initial_state, plan.get_action(), plan.get_control())
    return {"listing": (problem, plan), "constant": (twin, twin_plan)}


def _cpu() -> float:
    """CPU seconds of this process and of its finished children (a pool's workers, once shut down)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def timed(fn: Any, repeats: int) -> tuple[float, float, Any]:
    """Median wall-clock and CPU seconds (this process and its workers) of ``repeats`` calls, and the
    last result."""
    times, cpu, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), _cpu()
        out = fn()
        times.append(time.perf_counter() - t0)
        cpu.append(_cpu() - c0)
    return statistics.median(times), statistics.median(cpu), out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.montecarlo",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--runs", type=int, default=10000)
    p.add_argument("--serial-runs", type=int, default=1000)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--write", action="store_true", help=f"write {RESULTS.name}")
    a = p.parse_args(argv)

    real = light_dark_real_system()
    load0 = os.getloadavg()
    rows = []
    for name, (problem, plan) in problems().items():
        for start_name, start in (("fixed [0.5, 2.75]", LIGHT_DARK_REAL_INITIAL_STATE), ("prior", None)):
            if name == "constant" and start is None:
                continue

            def run(
                runs: int, start: Any = start, problem: Any = problem, plan: Any = plan, **kw: Any
            ) -> Any:
                return validate(problem, plan, real, start, runs=runs, seed=a.seed, **kw)

            pool_s, pool_cpu, rep = timed(lambda run=run: run(a.runs), a.repeats)
            inproc_s, inproc_cpu, rep_in = timed(lambda run=run: run(a.runs, executor="serial"), a.repeats)
            serial_s, _, rep_serial = timed(lambda run=run: run(a.serial_runs, batched=False), a.repeats)
            check = run(a.serial_runs)
            same = (
                check.belief_successes == rep_serial.belief_successes
                and check.state_successes == rep_serial.state_successes
                and check.predicate_violations == rep_serial.predicate_violations
                and np.allclose(check.belief_margins, rep_serial.belief_margins, rtol=0, atol=1e-9)
                and np.allclose(check.state_margins, rep_serial.state_margins, rtol=0, atol=1e-9)
            )
            serial_scaled = serial_s * a.runs / a.serial_runs
            rows.append(
                (
                    name,
                    start_name,
                    plan.num_of_steps,
                    pool_s,
                    pool_cpu,
                    inproc_s,
                    inproc_cpu,
                    serial_scaled,
                    serial_scaled / pool_s,
                    f"{rep.belief_success_rate:.2%} / {rep.state_success_rate:.2%}",
                    same and rep == rep_in,
                )
            )
            print(rows[-1], file=sys.stderr, flush=True)
    load1 = os.getloadavg()

    command = "python -m benchmarks.montecarlo " + " ".join(argv if argv is not None else sys.argv[1:])
    lines = [
        f"# Monte Carlo at scale: {a.runs} executions per problem",
        "",
        f"Command: `{command.strip()}` (from the repository root, `PYTHONPATH=src`).",
        f"Machine: {os.cpu_count()} cores ({platform.machine()}, Python {platform.python_version()}, "
        f"numpy {np.__version__}); load average {load0[0]:.1f} at the start, {load1[0]:.1f} at the end "
        "(the machine is shared: other processes ran during the measurement).",
        f"Wall-clock medians of {a.repeats} repetitions. `batched, pool`: `validate(runs={a.runs})` now "
        "(default executor: a process pool of 2 workers; `pool CPU`: the CPU seconds of this process and "
        "the workers together, about twice what the 2 cores take in wall-clock time when idle); "
        "`batched, in-process`: the same with "
        '`executor="serial"` (`in-process CPU`: the CPU seconds it used, what one idle core would '
        "take); `serial loop`: `batched=False` (the loop before this change: "
        f"`simulate` and the monitor one run after the other) on the same pool, timed on "
        f"{a.serial_runs} runs and scaled to {a.runs}. `same report`: the batched report of the "
        f"first {a.serial_runs} runs equals the serial loop's (counts, violation rates, margins to "
        "1e-9) and the pool's equals the in-process one.",
        "",
        "| problem | true start | plan steps | batched, pool [s] | pool CPU, all processes [s] | "
        "batched, in-process [s] | in-process CPU [s] | serial loop [s] | speed-up (serial / batched "
        "pool) | belief / state success | same report |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, start_name, steps, pool_s, pool_cpu, inproc_s, inproc_cpu, serial_s, ratio, rates, same in rows:
        lines.append(
            f"| {name} | {start_name} | {steps} | {pool_s:.2f} | {pool_cpu:.2f} | {inproc_s:.2f} | "
            f"{inproc_cpu:.2f} | {serial_s:.1f} | {ratio:.0f}x | {rates} | {'yes' if same else 'NO'} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    if a.write:
        RESULTS.write_text(text + "\n" + GOALS_NOTE)
    return 0


GOALS_NOTE = """Goals (issue 26): the listing's 10,000 executions in <= 3 s on 2 cores, <= 1 s for the
constant-noise problem. Compare the wall-clock columns with them only on an otherwise idle machine
(the load average above); the CPU columns say what the work itself costs.
"""


if __name__ == "__main__":
    raise SystemExit(main())
