"""Issue 34: input total variation of default plans, with and without the smoothing tie-break.

Every kind of :mod:`benchmarks.perception_problems` (size small) and every plant of
:mod:`benchmarks.plant_family` is solved with the default options (the paper's sampler
parameters, ``seed=0``, ``time_limit=120``) twice: ``smooth=True`` (the default) and
``smooth=False`` (the first verified plan as it came). The row records the status, whether the
plan meets the execution target (predicted), the input total variation ``sum_k |u_{k+1} - u_k|_1``
and the solve time.

Usage::

    python -m benchmarks.smooth_plans [--only a,b] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings
from typing import Any

import numpy as np

from benchmarks import perception_problems as pp
from benchmarks import plant_family as pf

SAMPLER = {"rrt_timeout": 60, "delta_near": 2, "delta_drain": 0.5, "goal_bias": 0.25}
SAMPLER |= {"min_num_of_steps": 3, "max_num_of_steps": 15, "seed": 0, "time_limit": 120}


def _problem(name: str) -> Any:
    return pf.PLANTS[name]() if name in pf.PLANTS else pp.build(name, "small")[0]


def run_one(name: str, smooth: bool) -> dict[str, Any]:
    problem = _problem(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        r = problem.solve_result(smooth=smooth, **SAMPLER)
        seconds = time.perf_counter() - t0
    plan = r.trajectory
    tv = float(np.abs(np.diff(plan.get_control(), axis=0)).sum()) if plan is not None else float("nan")
    return {"status": r.status, "meets": bool(r.meets_target), "tv": tv, "time": seconds}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="")
    ap.add_argument("--out", default="")
    args = ap.parse_args(argv)
    names = [n for n in args.only.split(",") if n] or [*pp.KINDS, *pf.PLANTS]
    lines = [
        "| problem | status (smooth / first) | meets target | input TV smooth / first | ratio "
        "| time (s) smooth / first |",
        "|---|---|---|---|---|---|",
    ]
    ratios = []
    for name in names:
        on, off = run_one(name, True), run_one(name, False)
        ratio = off["tv"] / on["tv"] if on["tv"] > 0 else float("nan")
        if np.isfinite(ratio):
            ratios.append(ratio)
        lines.append(
            f"| {name} | {on['status']} / {off['status']} | {on['meets']} / {off['meets']} | "
            f"{on['tv']:.4g} / {off['tv']:.4g} | {ratio:.3g} | {on['time']:.1f} / {off['time']:.1f} |"
        )
        print(lines[-1], flush=True)
    text = "\n".join(lines) + (
        f"\n\nmedian TV ratio (first / smooth): {statistics.median(ratios):.3g}\n" if ratios else "\n"
    )
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text)


if __name__ == "__main__":
    main()
