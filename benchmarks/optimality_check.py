"""Issue 25: are the objectives' claims true? Random small one-mode problems against an exact MILP.

Each problem (:func:`oracles.exact_optimiser.random_small_problem`: 1-2 states, horizon <= 12,
noise-free or with constant noise, box domains that are symmetric, off-centre or exclude
``u = 0``) is solved with ``objective="effort"``, ``"time"`` and ``"margin"`` and compared with the
independent exact optimiser of ``tests/oracles/exact_optimiser.py``. A claim is false when:

- ``infeasible`` while the oracle has a plan;
- ``optimal=True`` with a value more than ``1e-6 * max(1, |optimum|)`` from the optimum;
- ``objective_bound`` on the wrong side of the optimum (above it for effort and time, below it
  for margin) by more than that tolerance;
- ``optimal=True`` beside a ``gap`` above 1e-6;
- a ``found`` plan that fails the independent roll-out and monitor, or leaves the control box.

Run (the package under test comes from ``PYTHONPATH``; ``/work/main/src`` gives the code before)::

    PYTHONPATH=src python benchmarks/optimality_check.py --count 200
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from oracles.brute_force import sat  # noqa: E402
from oracles.exact_optimiser import Undecided, exact_optimum, random_small_problem  # noqa: E402
from oracles.rollout import loosen, mlo_rollout  # noqa: E402

OBJECTIVES = ("effort", "time", "margin")
TOL = 1e-6


def check(seed: int, time_limit: float, guarantee: str = "mlo") -> list[tuple[str, str, str]]:
    """``(objective, kind, detail)`` for every false claim on problem ``seed`` (and counters)."""
    sp = random_small_problem(seed)
    out: list[tuple[str, str, str]] = []
    for name in OBJECTIVES:
        try:
            opt = exact_optimum(sp.mode, sp.lo, sp.hi, sp.mean0, sp.cov0, sp.formula, name, sp.weights)
        except Undecided:
            out.append((name, "oracle undecided (feasible within tolerances only)", sp.describe))
            continue
        t0 = time.perf_counter()
        res = sp.problem.solve_result(
            seed=0,
            objective=name,
            effort_weights=tuple(sp.weights),
            time_limit=time_limit,
            guarantee=guarantee,
        )
        dt = time.perf_counter() - t0
        noise = "noisy" if sp.noisy else "noise-free"
        out.append((name, f"status:{res.status}", noise))
        out.append((name, "seconds", f"{dt:.3f}"))
        if not opt.feasible:
            out.append((name, f"oracle infeasible, status {res.status}", noise))
            if res.status == "found":
                out.append((name, "oracle says infeasible, plan found", sp.describe))
            continue
        tol = TOL * max(1.0, abs(opt.value))
        if res.status == "infeasible":
            out.append((name, "FALSE infeasible", sp.describe))
            continue
        if res.status != "found":
            continue
        traj = res.trajectory
        acts, controls = traj.get_action(), traj.get_control()
        trace = mlo_rollout([sp.mode], sp.mean0, sp.cov0, acts, controls)
        if not sat(loosen(sp.formula, trace, 1e-7), 0, trace):
            out.append((name, "FALSE found (monitor)", sp.describe))
        box_tol = 1e-9 * max(1.0, float(np.max(np.abs(np.r_[sp.lo, sp.hi]))))
        if controls.size and (np.any(controls < sp.lo - box_tol) or np.any(controls > sp.hi + box_tol)):
            out.append((name, "FALSE found (domain)", sp.describe))
        v, b = res.objective_value, res.objective_bound
        worse = (v < opt.value - tol) if name == "margin" else (v > opt.value + tol)
        if worse:
            out.append((name, "value not optimal", f"{v:.9g} vs {opt.value:.9g}"))
        if res.optimal:
            out.append((name, "claimed optimal", ""))
            if worse:
                out.append((name, "FALSE optimal", f"{v:.9g} vs {opt.value:.9g}; {sp.describe}"))
            if not np.isfinite(res.gap) or res.gap > TOL:
                out.append((name, "FALSE optimal beside a gap", f"gap {res.gap:.3g}"))
        if np.isfinite(b):
            wrong = (b < opt.value - tol) if name == "margin" else (b > opt.value + tol)
            if wrong:
                out.append((name, "FALSE bound", f"bound {b:.9g} vs optimum {opt.value:.9g}; {sp.describe}"))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--count", type=int, default=200)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument(
        "--guarantee",
        default="mlo",
        help="the solves' guarantee (default mlo, the oracle's semantics; 'execution' checks that its "
        "claims stay true: the MLO optimum bounds the execution problem's)",
    )
    ap.add_argument("--verbose", action="store_true")
    args = ap.parse_args(argv)
    tally: Counter[tuple[str, str]] = Counter()
    seconds: dict[str, list[float]] = {name: [] for name in OBJECTIVES}
    examples: dict[tuple[str, str], str] = {}
    for seed in range(args.start, args.start + args.count):
        for name, kind, detail in check(seed, args.time_limit, args.guarantee):
            if kind == "seconds":
                seconds[name].append(float(detail))
                continue
            tally[(name, f"{kind} [{detail}]" if kind.startswith("status") else kind)] += 1
            examples.setdefault((name, kind), f"seed {seed}: {detail}")
            if args.verbose and kind.startswith(("FALSE", "oracle")):
                print(f"seed {seed} {name}: {kind}: {detail}", flush=True)
    print(
        f"{args.count} problems (seeds {args.start}..{args.start + args.count - 1}),",
        f"guarantee={args.guarantee}",
    )
    for name in OBJECTIVES:
        print(f"\n{name}: median solve {np.median(seconds[name]):.3f} s, max {np.max(seconds[name]):.3f} s")
        for (obj, kind), count in sorted(tally.items()):
            if obj == name and count:
                line = f"  {kind}: {count}"
                if kind.startswith(("FALSE", "oracle", "value")):
                    line += f"   e.g. {examples.get((obj, kind), '')[:160]}"
                print(line)
    false = sum(c for (_, k), c in tally.items() if k.startswith("FALSE"))
    print(f"\nfalse claims: {false}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
