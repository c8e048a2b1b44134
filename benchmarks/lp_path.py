"""Noise-free reach-avoid through the LP teacher: solve time against the horizon.

Run: ``python -m benchmarks.lp_path [--horizons 25,50,100,200] [--repeats 5] [--lazy-candidates N]
[--lazy-conflict-size S] [--milp-backend highs|scip]``.

:func:`idstlpy.scenarios.reach_avoid`: a 4-D double integrator (``|u_i| <= 0.5``, zero
covariance, so every chance constraint is a plain linear one) must avoid the box
``[3, 5] x [4, 6]`` at every step and reach ``[7, 8] x [8, 9]`` within ``T`` steps from ``(1, 1)``
at rest: ``G[0,T] avoid & F[0,T] goal``. Prints a Markdown table
(median of the repeats, and which path decided the problem). ``--lazy-candidates`` and
``--lazy-conflict-size`` override when the lazy SAT/LP loop hands the problem to the eager MILP
(``SolverOptions.lazy_candidates``, default 10, and ``lazy_conflict_size``, default 3: the
switch follows the conflicts' sizes; ``--lazy-conflict-size 0`` is the fixed count).

``--switch-ab CELLS`` (e.g. ``DI:200,PrSTL:50,NarrowPassage:200``; ``DI`` is this problem,
``PrSTL`` the PrSTL suite's noisy reach-avoid, any other name an stlpy scenario translated as in
the stlpy suite) instead measures the switch rule of commit 3356fca (no early look) against the
current :func:`idstlpy.synthesis.milp.switch_to_eager` in one process, the two interleaved
``--repeats`` times per cell; CPU seconds of the solve (median), wall seconds, candidates, and
each answer checked by the monitor.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from idstlpy.scenarios import reach_avoid


def previous_rule(
    conflicts: Sequence[Sequence[Any]], candidates: int, min_candidates: int, conflict_size: float
) -> bool:
    """``switch_to_eager`` as of commit 3356fca: no early look, ``lazy_candidates`` at least."""
    if candidates < min_candidates:
        return False
    window = max(min_candidates, 1)
    if conflict_size <= 0 or candidates >= 10 * window:
        return True
    recent = [len(c) for c in conflicts[-window:]]
    return not recent or float(np.median(recent)) > conflict_size


def _problem(cell: str) -> Any:
    name, T = cell.split(":")
    if name == "DI":
        return reach_avoid(int(T))
    if name == "PrSTL":
        from .prstl_milp import noisy_reach_avoid

        return noisy_reach_avoid(int(T))
    from .catalogue import build
    from .stlpy_translate import make_problem

    spec, sysm, x0, T2, d = build(name, int(T))
    return make_problem(spec, sysm.A, sysm.B, sysm.C, sysm.D, x0, *d.u_box, T2, *d.x_box)[0]


def switch_ab(cells: list[str], repeats: int) -> None:
    """Previous vs current switch rule, interleaved in one process (see the module docstring)."""
    import idstlpy as I
    import idstlpy.synthesis.eager as eager
    from idstlpy.synthesis.milp import switch_to_eager

    rules = {"previous": previous_rule, "current": switch_to_eager}
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"nproc {os.cpu_count()}, load {load:.1f}, {time.strftime('%H:%M UTC', time.gmtime())}\n")
    print(
        "| cell | previous CPU s | current CPU s | current / previous | previous wall s | current wall s "
        "| candidates (previous / current) | answers (previous / current) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    try:
        for cell in cells:
            cpu: dict[str, list[float]] = {k: [] for k in rules}
            wall: dict[str, list[float]] = {k: [] for k in rules}
            seen: dict[str, tuple[str, int]] = {}
            for r in range(repeats):
                for tag in ("previous", "current") if r % 2 == 0 else ("current", "previous"):
                    eager.switch_to_eager = rules[tag]  # type: ignore[assignment]
                    problem = _problem(cell)
                    c0, w0 = time.process_time(), time.perf_counter()
                    out = problem.solve_result(rrt_timeout=30, time_limit=30, seed=0)
                    cpu[tag].append(time.process_time() - c0)
                    wall[tag].append(time.perf_counter() - w0)
                    answer = out.status
                    if out.found:
                        answer += (
                            " (monitor ok)"
                            if I.satisfies(out.trajectory, problem.stl_formula)
                            else " (MONITOR REJECTS)"
                        )
                    seen[tag] = (answer, out.stats.candidates)
            p, c = statistics.median(cpu["previous"]), statistics.median(cpu["current"])
            wp, wc = statistics.median(wall["previous"]), statistics.median(wall["current"])
            print(
                f"| {cell} | {p:.3f} | {c:.3f} | {c / p:.2f} | {wp:.3f} | {wc:.3f} | "
                f"{seen['previous'][1]} / {seen['current'][1]} | "
                f"{seen['previous'][0]} / {seen['current'][0]} |",
                flush=True,
            )
    finally:
        eager.switch_to_eager = switch_to_eager
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"\nload {load:.1f} at the end, {time.strftime('%H:%M UTC', time.gmtime())}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.lp_path",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--horizons", default="25,50,100,200")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--lazy-candidates", type=int, default=None)
    p.add_argument("--lazy-conflict-size", type=float, default=None)
    p.add_argument("--milp-backend", default="auto")
    p.add_argument("--switch-ab", default=None, metavar="CELLS")
    a = p.parse_args(argv)
    if a.switch_ab:
        switch_ab([c.strip() for c in a.switch_ab.split(",") if c.strip()], a.repeats)
        return 0
    kw: dict = {"milp_backend": a.milp_backend}
    if a.lazy_conflict_size is not None:
        kw["lazy_conflict_size"] = a.lazy_conflict_size
    if a.lazy_candidates is not None:
        kw["lazy_candidates"] = a.lazy_candidates
    print("| T | status | median solve (s) | min / max (s) | candidates | plan steps | decided by |")
    print("|---|---|---|---|---|---|---|")
    for T in (int(t) for t in a.horizons.split(",")):
        times, result = [], None
        for _ in range(a.repeats):
            problem = reach_avoid(T)
            t0 = time.perf_counter()
            result = problem.solve_result(rrt_timeout=60, seed=0, **kw)
            times.append(time.perf_counter() - t0)
        steps = result.trajectory.num_of_steps if result.found else "-"
        print(
            f"| {T} | {result.status} | {statistics.median(times):.3f} | {min(times):.3f} / "
            f"{max(times):.3f} | {result.stats.candidates} | {steps} | {result.reason} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
