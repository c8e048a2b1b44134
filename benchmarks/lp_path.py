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
"""

from __future__ import annotations

import argparse
import statistics
import time

from idstlpy.scenarios import reach_avoid


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.lp_path", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--horizons", default="25,50,100,200")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--lazy-candidates", type=int, default=None)
    p.add_argument("--lazy-conflict-size", type=float, default=None)
    p.add_argument("--milp-backend", default="auto")
    a = p.parse_args(argv)
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
        print(f"| {T} | {result.status} | {statistics.median(times):.3f} | {min(times):.3f} / "
              f"{max(times):.3f} | {result.stats.candidates} | {steps} | {result.reason} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
