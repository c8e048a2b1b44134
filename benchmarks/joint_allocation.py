"""Issue 32.3: random problems with joint chance constraints that have a plan, solved.

Every problem comes from :func:`oracles.joint_problems.joint_instance` (``tests/oracles``): a
witness plan is rolled out first (independent roll-out) and the ``prob_in(region) >= 1 - eps``
constraints are written around it, with a per-face split of ``eps`` that changes from step to
step; the witness is accepted by ``stl.satisfies`` and by the independent reading (the literal
Boole sum, Monte Carlo and, for boxes, ``scipy.stats.multivariate_normal.cdf``). Each problem is
then solved (``guarantee="mlo"``: the monitor's semantics, seed 0). Reported per problem: the
status, time, candidates and, for a plan, the project's monitor and the independent oracle
(:func:`oracles.joint_problems.plan_check`); for anything else the reason. Goal: 0 give-ups,
0 false reasons (a problem here always has a plan, so any ``infeasible`` is false).

Usage::

    python benchmarks/joint_allocation.py [--seeds 0:80] [--time-limit 60] [--out FILE.md]
        [--lazy-candidates 0 --single-mode]   # the eager MILP path
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from oracles.joint_problems import joint_instance, plan_check, witness_probabilities  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="0:80", help="first:last (exclusive)")
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--samples", type=int, default=20000, help="Monte Carlo samples per witness step")
    ap.add_argument("--out", default=None, help="also write the table to this markdown file")
    ap.add_argument(
        "--lazy-candidates",
        type=int,
        default=None,
        help="SolverOptions.lazy_candidates (0: the eager MILP at once on LP-exact single-mode problems)",
    )
    ap.add_argument("--single-mode", action="store_true", help="only the single-mode problems")
    args = ap.parse_args()
    lo, hi = (int(v) for v in args.seeds.split(":"))
    rows = []
    times = []
    found = give_ups = false_claims = wrong = searched = 0
    witness_bad = 0
    for seed in range(lo, hi):
        inst = joint_instance(seed)
        if args.single_mode and len(inst.modes) != 1:
            continue
        for row in witness_probabilities(inst, samples=args.samples, seed=seed):
            eps = row["eps"]
            if (
                row["boole"] > eps * (1 + 1e-9)
                or row["mc_high"] < 1 - eps
                or row.get("exact", 1.0) < 1 - eps - 1e-6
            ):
                witness_bad += 1
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # execution-target warnings: guarantee="mlo" here
            more = {} if args.lazy_candidates is None else {"lazy_candidates": args.lazy_candidates}
            result = inst.problem.solve_result(seed=0, guarantee="mlo", time_limit=args.time_limit, **more)
        elapsed = time.perf_counter() - t0
        times.append(elapsed)
        check = ""
        if result.status == "found" and result.trajectory is not None:
            monitor, oracle = plan_check(inst, result.trajectory)
            found += 1
            wrong += not (monitor and oracle)
            check = f"monitor {'yes' if monitor else 'NO'}, oracle {'yes' if oracle else 'NO'}"
            if "allocation(s) beyond the first" in result.reason:
                searched += 1
                check += (
                    "; allocation searched: " + result.reason.rsplit("; the joint chance constraints' ", 1)[1]
                )
        else:
            give_ups += 1
            false_claims += result.status == "infeasible"
            check = result.reason
        rows.append(
            f"| {seed} | {inst.describe().split(': ', 1)[1]} | {result.status} | {elapsed:.2f} | "
            f"{result.stats.candidates} | {check} |"
        )
    n = len(rows)
    lines = [
        f"found {found} / {n} ({searched} after the allocation search); give-ups {give_ups}; "
        f"`infeasible` claims (all false here) {false_claims}; "
        f"plans rejected by the monitor or the oracle {wrong}; witnesses the oracle rejects {witness_bad}",
        f"time per problem: median {statistics.median(times):.2f} s, max {max(times):.2f} s, "
        f"total {sum(times):.1f} s",
        "",
        "| seed | problem | status | time (s) | candidates | plan check / reason |",
        "|---|---|---|---|---|---|",
        *rows,
    ]
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
