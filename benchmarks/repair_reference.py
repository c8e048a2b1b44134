"""Record (or compare) what the repair loops and the plan LP produce on fixed one-mode problems.

A guard for refactoring the trust-region repair loops (``room.give_room``, the closed-loop
certification, ``objectives.refine``) and the plan LP's solve context: every case is solved with
a fixed seed and work budgets (wall-clock caps far above what the cases take, so no cap decides
anything), and its status, candidates, LP calls, actions, a hash of the controls rounded to 12
digits and the execution room are recorded. Only one-mode problems (the multi-mode search is
another module's).

Usage::

    PYTHONPATH=src python -m benchmarks.repair_reference --record   # write the reference
    PYTHONPATH=src python -m benchmarks.repair_reference            # compare with it
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import defaults_problems as dp
from benchmarks import perception_problems as pp

REFERENCE = Path(__file__).parent / "results" / "repair_reference.json"

OPTIONS: dict[str, Any] = dict(time_limit=120, rrt_timeout=60)


def _suite(kind: str) -> Callable[[], Any]:
    return lambda: pp.build(kind, "small")[0]


# (name, builder, guarantee or None for the default, objective or None[, seed])
CASES: list[tuple[Any, ...]] = [
    ("listing", _suite("listing"), None, None),
    ("listing", _suite("listing"), "mlo", None),
    ("listing", _suite("listing"), "closed_loop", None),
    ("listing", _suite("listing"), "mlo", "effort"),
    ("listing", _suite("listing"), "mlo", "margin"),
    ("double_integrator", _suite("double_integrator"), None, None),
    ("double_integrator", _suite("double_integrator"), "closed_loop", None),
    ("noisy_hold", _suite("noisy_hold"), None, None),
    ("noisy_hold", _suite("noisy_hold"), "mlo", None),
    ("detour", _suite("detour"), "mlo", None),
    ("one_d", dp.one_d, None, None),
    ("one_d", dp.one_d, "mlo", None),
    ("one_d", dp.one_d, "closed_loop", None),
    ("thermal_dark", dp.thermal_dark, None, None),
    ("thermal_dark", dp.thermal_dark, "mlo", "effort"),
    ("corridor", dp.corridor, None, None),
    ("corridor", dp.corridor, "mlo", None),
    ("corridor", dp.corridor, "closed_loop", None),
    ("corridor", dp.corridor, "mlo", "effort"),
    ("corridor", dp.corridor, "mlo", "margin"),
    ("integrator_2d_constant", dp.integrator_2d_constant, None, None),
    ("integrator_2d_constant", dp.integrator_2d_constant, "closed_loop", None),
    # the closed-loop repair's line search (a fraction of the LP's step) runs here
    ("double_integrator", _suite("double_integrator"), "closed_loop", None, 3),
]


def _key(name: str, guarantee: str | None, objective: str | None, seed: int = 0) -> str:
    return f"{name}/{guarantee or 'default'}/{objective or '-'}" + (f"/seed{seed}" if seed else "")


def run_case(
    build: Callable[[], Any], guarantee: str | None, objective: str | None, seed: int = 0
) -> dict[str, Any]:
    """Solve one case; the record compared across commits (and its time, not compared)."""
    problem = build()
    kw = dict(OPTIONS, seed=seed)
    if guarantee is not None:
        kw["guarantee"] = guarantee
    if objective is not None:
        kw["objective"] = objective
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = problem.solve_result(**kw)
    row: dict[str, Any] = {
        "status": r.status,
        "candidates": int(r.stats.candidates),
        "lp_calls": int(r.stats.lp_calls),
        "execution_room": None if r.stats.execution_room is None else float(r.stats.execution_room),
        "caps_hit": list(r.stats.caps_hit),
    }
    if r.trajectory is not None:
        row["actions"] = [int(a) for a in r.trajectory.get_action()]
        controls = np.round(np.asarray(r.trajectory.get_control(), dtype=float), 12) + 0.0
        row["controls"] = hashlib.sha256(np.ascontiguousarray(controls).tobytes()).hexdigest()[:16]
    row["time"] = time.perf_counter() - t0
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--record", action="store_true", help="write the reference")
    parser.add_argument("--only", default="", help="comma-separated case-name filter")
    args = parser.parse_args(argv)
    only = {s for s in args.only.split(",") if s}
    rows: dict[str, dict[str, Any]] = {}
    for name, build, guarantee, objective, *seed in CASES:
        if only and name not in only:
            continue
        key = _key(name, guarantee, objective, *seed)
        rows[key] = run_case(build, guarantee, objective, *seed)
        print(key, json.dumps({k: v for k, v in rows[key].items() if k != "actions"}), flush=True)
    if args.record:
        REFERENCE.parent.mkdir(parents=True, exist_ok=True)
        old = json.loads(REFERENCE.read_text()) if REFERENCE.exists() else {}
        REFERENCE.write_text(json.dumps({**old, **rows}, indent=1, sort_keys=True) + "\n")
        return 0
    ref = json.loads(REFERENCE.read_text())
    bad = 0
    for key, row in rows.items():
        want = ref.get(key)
        got = {k: v for k, v in row.items() if k != "time"}
        if want is None:
            print(f"NEW  {key}")
            continue
        want = {k: v for k, v in want.items() if k != "time"}
        if got != want:
            bad += 1
            diff = {k: (want.get(k), got.get(k)) for k in set(got) | set(want) if got.get(k) != want.get(k)}
            print(f"DIFF {key}: {diff}")
    times = [(k, ref[k]["time"], rows[k]["time"]) for k in rows if k in ref]
    print(
        f"{len(rows) - bad}/{len(rows)} identical; time {sum(t[2] for t in times):.1f} s "
        f"(reference {sum(t[1] for t in times):.1f} s)"
    )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
