"""Robustness mode (issue 13): ``objective="margin"`` against stlpy's MICP maximising robustness.

``python -m benchmarks.robustness_mode [--scenarios ...] [--T 25] [--timeout 120] [--peers ...]``

For each stlpy scenario (translated automatically, as in the main benchmark), idstlpy solves with
``objective="margin"`` and stlpy's MICP maximises its robustness ``rho`` with each open solver
(and Gurobi where its size-limited licence admits the model). Both optima are in the same units
(the translator keeps stlpy's predicates ``a'y - b >= 0`` as the faces whose slack the monitor
reports). The table gives both values, their difference, the times and idstlpy's time divided
by each peer's, all measured in one run. Results go to ``benchmarks/robustness_results.md``.
"""

from __future__ import annotations

import argparse
import datetime
import os
import subprocess
import time
from typing import Any

SCENARIOS = ["ReachAvoid", "EitherOr", "NarrowPassage", "RandomMultitarget", "DoorPuzzle", "SteppingStones"]


def idstlpy_margin(name: str, T: int, time_limit: float) -> dict[str, Any]:
    """idstlpy's optimum robustness for the translated scenario."""
    import idstlpy as I

    from .catalogue import build
    from .stlpy_translate import make_problem

    t0 = time.perf_counter()
    spec, sysm, x0, T, d = build(name, T)
    problem, _ = make_problem(spec, sysm.A, sysm.B, sysm.C, sysm.D, x0, *d.u_box, T, *d.x_box)
    res = problem.solve_result(seed=0, time_limit=time_limit, objective="margin")
    e2e = time.perf_counter() - t0
    out: dict[str, Any] = {
        "status": res.status,
        "e2e_s": e2e,
        "optimal": res.optimal,
        "scope": res.optimal_scope,
    }
    if res.trajectory is not None:
        out["value"] = float(I.robustness(res.trajectory, problem.stl_formula))
        out["bound"] = res.objective_bound
    return out


def main(argv: list[str] | None = None) -> None:
    """Run the comparison and write the markdown table."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", default=",".join(SCENARIOS))
    ap.add_argument("--T", type=int, default=25)
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--peers", default="highs,scip,gurobi")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "robustness_results.md"))
    a = ap.parse_args(argv)
    from .peers import stlpy_micp

    rows = []
    for name in a.scenarios.split(","):
        ours = idstlpy_margin(name, a.T, a.timeout)
        peers = {}
        for backend in a.peers.split(","):
            try:
                r = stlpy_micp(name, a.T, backend, "robustness", a.timeout)
            except Exception as exc:  # a peer that cannot run here is reported, not fatal
                r = {"status": "error", "detail": f"{type(exc).__name__}: {exc}"}
            peers[backend] = r
        rows.append((name, ours, peers))
        print(
            name,
            ours,
            {b: (p.get("status"), p.get("stlpy_robustness"), p.get("e2e_s")) for b, p in peers.items()},
            flush=True,
        )
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    lines = [
        '# Robustness mode: idstlpy `objective="margin"` vs stlpy\'s MICP (maximise rho)',
        "",
        f"Command: `python -m benchmarks.robustness_mode --T {a.T} --timeout {a.timeout:g} "
        f"--peers {a.peers}`; "
        f"{datetime.date.today()}, nproc {os.cpu_count()}, commit {commit}. One run; times are end to end "
        "(model building included). `rho` is the optimum each found (stlpy's: its own robustness of its "
        "solution; idstlpy's: the monitor's robustness of its plan).",
        "",
        "| scenario | idstlpy rho | proven | idstlpy s | peer | peer status | peer rho | peer s | rho diff "
        "| time ratio |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, ours, peers in rows:
        for backend, p in peers.items():
            pr, ps = p.get("stlpy_robustness"), p.get("e2e_s")
            diff = (
                (ours.get("value", float("nan")) - pr) if pr is not None and "value" in ours else float("nan")
            )
            ratio = ours["e2e_s"] / ps if ps else float("nan")
            lines.append(
                f"| {name} | {ours.get('value', float('nan')):.6g} | {ours['optimal']} ({ours['scope']}) | "
                f"{ours['e2e_s']:.3g} | {backend} | {p.get('status')} | "
                f"{pr if pr is None else f'{pr:.6g}'} | {ps if ps is None else f'{ps:.3g}'} | "
                f"{diff:.2g} | {ratio:.3g} |"
            )
    with open(a.out, "w") as fh:
        fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
