"""Chance switching (issue 35): a benchmark family of Markov jump systems with the sound bound.

``python -m benchmarks.markov_family [--horizons 25,100] [--runs 10000] [--families a,b]
[--out benchmarks/markov_family_results.md]``

A 2-D robot (``x' = x + 0.25 u + W w``, ``|u_i| <= 1``, a position sensor ``C = I``) must reach
a goal box ``D = 0.15 T`` away (``eventually[0, T]``, confidence 95%) and stay in a corridor
(``always[0, T]``, 99%), ``T`` the horizon. The executed mode jumps by a Markov chain whose
commanded mode is always the nominal one (mode 0); the executed mode is observed:

- ``actuator_failure``: mode 1 has a weaker actuator (``B = 0.1 I``); it fails with 0.5% per step
  and stays failed (persistent);
- ``sensor_dropout``: mode 1 has no sensor; a frame is dropped with 10% per step, independently
  (not persistent);
- ``slippery``: mode 1 has 3x the process noise; the ground turns slippery with 5% per step and
  stays slippery with 80%;
- ``gusts``: mode 1 adds a crosswind that pushes ``x[0]`` by ``0.05 x[1]`` per step (the modes
  have no constant offset, so the drift is a shear of the state); gusts start with 5% and
  persist with 70%.

Each instance: the default ``solve`` (it plans for the commanded modes, then bounds the plan
under the jumps: :func:`idstlpy.markov_bound` with its defaults, the true start drawn from the
prior); the time of the solve, the bound's (also timed alone), the covered mass, the point
estimate, and ``validate`` with ``--runs`` executions with jumps (the measured rates, Wilson 95%
interval). The *verified* bound assumes nothing of the sequences left out; the *total* bound adds
the remainder's sampled bound (``rest_runs`` executions, confidence 0.999). ``total <= measured``
is checked with the interval's upper end.
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import idstlpy as stl

FAMILIES = ("actuator_failure", "sensor_dropout", "slippery", "gusts")


@dataclass
class Row:
    family: str
    horizon: int
    status: str
    steps: int
    solve_s: float
    bound_s: float
    sequences: int
    mass: float
    confidence: float
    belief_bound: float
    state_bound: float
    belief_total: float
    state_total: float
    belief_estimate: float
    state_estimate: float
    belief_mc: float
    state_mc: float
    belief_ci: tuple[float, float]
    state_ci: tuple[float, float]
    mc_s: float


def instance(family: str, T: int) -> stl.Problem:
    """The problem of one family at horizon ``T`` (module notes)."""
    A, B, W = np.eye(2), 0.25 * np.eye(2), 0.03 * np.eye(2)
    C, V = np.eye(2), 0.05 * np.eye(2)
    nominal = stl.mk_lbs(A, B, W, C, V)
    if family == "actuator_failure":
        other = stl.mk_lbs(A, 0.1 * np.eye(2), W, C, V)
        chain = [[0.995, 0.005], [0.0, 1.0]]
    elif family == "sensor_dropout":
        other = stl.mk_lbs(A, B, W)
        chain = [[0.9, 0.1], [0.9, 0.1]]
    elif family == "slippery":
        other = stl.mk_lbs(A, B, 3 * W, C, V)
        chain = [[0.95, 0.05], [0.2, 0.8]]
    elif family == "gusts":
        other = stl.mk_lbs(np.array([[1.0, 0.05], [0.0, 1.0]]), B, W, C, V)
        chain = [[0.95, 0.05], [0.3, 0.7]]
    else:
        raise ValueError(f"unknown family {family!r}")
    system = stl.with_switching(stl.mk_switched_sys([nominal, other]), stl.mk_markov_switching(chain))
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    D = 0.15 * T
    corridor = stl.logical_and(
        stl.prob(x[0] >= -1.0) >= 0.99,
        stl.prob(x[0] <= D + 1.0) >= 0.99,
        stl.prob(x[1] >= -1.0) >= 0.99,
        stl.prob(x[1] <= 2.0) >= 0.99,
        name="corridor",
    )
    goal = stl.logical_and(
        stl.prob(x[0] >= D - 0.5) >= 0.95,
        stl.prob(x[0] <= D + 0.5) >= 0.95,
        stl.prob(x[1] >= 0.0) >= 0.95,
        stl.prob(x[1] <= 1.0) >= 0.95,
        name="goal",
    )
    formula = stl.logical_and(stl.always(0, T, corridor), stl.eventually(0, T, goal))
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    prior = stl.to_belief(np.array([0.0, 0.5]), 0.01 * np.eye(2))
    return stl.Problem(system, domain, prior, formula)


def run(family: str, T: int, runs: int, seed: int = 0) -> Row:
    problem = instance(family, T)
    nan = float("nan")
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = problem.solve_result(seed=seed, time_limit=600)
    solve_s = time.perf_counter() - t0
    plan = res.trajectory
    if plan is None:
        return Row(family, T, res.status, 0, solve_s, nan, 0, nan, nan, nan, nan, nan, nan, nan, nan,
                   nan, nan, (nan, nan), (nan, nan), nan)  # fmt: skip
    t0 = time.perf_counter()
    b = stl.markov_bound(problem, plan, real_initial_cov=problem.initial_state.cov)
    bound_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    rep = stl.validate(problem, plan, None, runs=runs, seed=seed + 1)
    mc_s = time.perf_counter() - t0
    return Row(
        family, T, res.status, plan.num_of_steps, solve_s, bound_s, len(b.sequences), b.covered_mass,
        b.confidence, b.belief_bound, b.state_bound, b.total_belief_bound, b.total_state_bound,
        b.total_belief_estimate, b.total_state_estimate,
        rep.belief_success_rate, rep.state_success_rate, tuple(rep.belief_ci), tuple(rep.state_ci), mc_s,
    )  # fmt: skip


def table(rows: list[Row]) -> str:
    head = (
        "| family | T | status | plan steps | solve s (bound incl.) | bound s | sequences | covered mass "
        "| confidence | verified bound belief / state | total bound belief / state "
        "| estimate belief / state | MC belief / state [95% CI] | total bound <= MC | MC s |\n|" + "---|" * 15
    )
    lines = [head]
    for r in rows:
        ok = r.belief_total <= r.belief_ci[1] and r.state_total <= r.state_ci[1]
        lines.append(
            f"| {r.family} | {r.horizon} | {r.status} | {r.steps} | {r.solve_s:.2f} | {r.bound_s:.2f} "
            f"| {r.sequences} | {r.mass:.4f} | {r.confidence:g} | {r.belief_bound:.3f} / {r.state_bound:.3f} "
            f"| {r.belief_total:.3f} / {r.state_total:.3f} "
            f"| {r.belief_estimate:.3f} / {r.state_estimate:.3f} "
            f"| {r.belief_mc:.3f} [{r.belief_ci[0]:.3f}, {r.belief_ci[1]:.3f}] / {r.state_mc:.3f} "
            f"[{r.state_ci[0]:.3f}, {r.state_ci[1]:.3f}] | {'yes' if ok else 'NO'} | {r.mc_s:.1f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--horizons", default="25,100")
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--out", default="")
    args = ap.parse_args(argv)
    rows = []
    for T in (int(t) for t in args.horizons.split(",")):
        for fam in args.families.split(","):
            row = run(fam, T, args.runs)
            rows.append(row)
            print(table([row]).splitlines()[-1], flush=True)
    text = table(rows)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
