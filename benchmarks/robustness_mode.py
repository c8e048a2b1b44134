"""Robustness mode (issue 13): ``objective="margin"`` against stlpy's MICP maximising robustness.

``python -m benchmarks.robustness_mode [--scenarios ...] [--T 25] [--timeout 120] [--peers ...]
[--repeats 3] [--peer-cache PATH]``

For each stlpy scenario (translated automatically, as in the main benchmark, with stlpy's state
box as a hard constraint: ``make_problem(..., hard_box=True)``), idstlpy solves with
``objective="margin"`` and stlpy's MICP maximises its robustness ``rho`` with each open solver
(and Gurobi where its size-limited licence admits the model). Both optima are in the same units
(the translator keeps stlpy's predicates ``a'y - b >= 0`` as the faces whose slack the monitor
reports); idstlpy's ``rho`` is the robustness of its plan for the translated *specification*
(without the box), which is what stlpy's ``rho`` measures, and the plan is checked against the
box separately. The table gives both values, their difference, the times and each peer's time
divided by idstlpy's, in wall-clock and in CPU seconds (both sides solve in-process, so CPU time
is the fairer measure on a shared machine). Results go to ``benchmarks/robustness_results.md``.

``--peer-cache`` keeps the peers' answers in a JSON file (they do not depend on idstlpy): a later
run with the same file re-uses them instead of solving again, and the table says when each side
was measured.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import time
from typing import Any

SCENARIOS = ["ReachAvoid", "EitherOr", "NarrowPassage", "RandomMultitarget", "DoorPuzzle", "SteppingStones"]
MATCH_TOL = 1e-6


def _stamp() -> str:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return f"{datetime.datetime.now(datetime.UTC):%H:%M} UTC, load {load:.1f}"


def idstlpy_margin(name: str, T: int, time_limit: float, backend: str = "auto") -> dict[str, Any]:
    """idstlpy's optimum robustness for the translated scenario (box hard), end to end."""
    import numpy as np

    import idstlpy as I

    from .catalogue import build
    from .stlpy_translate import make_problem

    t0, c0 = time.perf_counter(), time.process_time()
    spec, sysm, x0, T, d = build(name, T)
    problem, tr = make_problem(spec, sysm.A, sysm.B, sysm.C, sysm.D, x0, *d.u_box, T, *d.x_box, hard_box=True)
    res = problem.solve_result(seed=0, time_limit=time_limit, objective="margin", milp_backend=backend)
    e2e, cpu = time.perf_counter() - t0, time.process_time() - c0
    out: dict[str, Any] = {
        "status": res.status,
        "e2e_s": e2e,
        "cpu_s": cpu,
        "optimal": res.optimal,
        "scope": res.optimal_scope,
    }
    if res.trajectory is not None:
        traj = res.trajectory
        out["value"] = float(I.robustness(traj, tr(spec)))  # the specification's own robustness
        out["objective"] = res.objective_value
        out["bound"] = res.objective_bound
        means = traj.get_mean()
        lo, hi = d.x_box
        inside = np.all(means >= np.asarray(lo)) and np.all(means <= np.asarray(hi))
        out["in_box"] = bool(inside)
        out["satisfied"] = bool(I.satisfies(traj, problem.stl_formula))
    return out


def run_peers(
    names: list[str], T: int, peers: list[str], timeout: float, cache: str | None
) -> dict[str, Any]:
    """The peers' answers per scenario and back-end (from ``cache`` where it has them)."""
    from .peers import stlpy_micp

    store: dict[str, Any] = {}
    if cache and os.path.exists(cache):
        with open(cache) as fh:
            store = json.load(fh)
    for name in names:
        for backend in peers:
            key = f"{name}/T{T}/{backend}/{timeout:g}"
            if key in store:
                continue
            when = _stamp()
            c0 = time.process_time()
            try:
                r = stlpy_micp(name, T, backend, "robustness", timeout)
            except Exception as exc:  # a peer that cannot run here is reported, not fatal
                r = {"status": "error", "detail": f"{type(exc).__name__}: {exc}"}
            r["cpu_s"] = time.process_time() - c0  # in-process solvers: every thread's CPU
            r = {k: v for k, v in r.items() if isinstance(v, (int, float, str, bool, type(None)))}
            r["measured"] = when
            store[key] = r
            print(key, r.get("status"), r.get("stlpy_robustness"), r.get("e2e_s"), flush=True)
            if cache:
                with open(cache, "w") as fh:
                    json.dump(store, fh, indent=1, sort_keys=True)
    return store


def main(argv: list[str] | None = None) -> None:
    """Run the comparison and write the markdown table."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", default=",".join(SCENARIOS))
    ap.add_argument("--T", default="25", help="horizons, comma-separated")
    ap.add_argument(
        "--later-scenarios",
        default=None,
        help="scenarios for the horizons after the first (default: --scenarios)",
    )
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--peers", default="highs,scip,gurobi")
    ap.add_argument("--repeats", type=int, default=3, help="idstlpy solves per cell (median time)")
    ap.add_argument("--peer-cache", default=None)
    ap.add_argument("--backend", default="auto", help="idstlpy's milp_backend")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "robustness_results.md"))
    a = ap.parse_args(argv)
    git = ["git", "rev-parse", "--short", "HEAD"]
    commit = subprocess.run(git, capture_output=True, text=True).stdout.strip()  # what is measured
    # A clean snapshot (`git archive`) is no repository: its commit comes from the environment.
    commit = commit or os.environ.get("IDSTLPY_COMMIT", "unknown")
    names = a.scenarios.split(",")
    peers = a.peers.split(",")
    horizons = [int(t) for t in a.T.split(",")]
    rows = []
    later = a.later_scenarios.split(",") if a.later_scenarios else names
    for T in horizons:
        these = names if T == horizons[0] else later
        store = run_peers(these, T, peers, a.timeout, a.peer_cache)
        for name in these:
            runs = []
            when = _stamp()
            for _ in range(max(a.repeats, 1)):
                runs.append(idstlpy_margin(name, T, a.timeout, a.backend))
            ours = dict(runs[0])
            ours["e2e_s"] = statistics.median(r["e2e_s"] for r in runs)
            ours["cpu_s"] = statistics.median(r["cpu_s"] for r in runs)
            ours["all_s"] = [r["e2e_s"] for r in runs]
            ours["measured"] = when
            ours["consistent"] = all(r.get("value") == runs[0].get("value") for r in runs)
            got = {b: store[f"{name}/T{T}/{b}/{a.timeout:g}"] for b in peers}
            rows.append((name, T, ours, got))
            print(name, T, ours, flush=True)
    lines = [
        '# Robustness mode: idstlpy `objective="margin"` vs stlpy\'s MICP (maximise rho)',
        "",
        f"Command: `python -m benchmarks.robustness_mode --T {a.T} --timeout {a.timeout:g} --peers {a.peers} "
        f"--repeats {a.repeats}{' --later-scenarios ' + a.later_scenarios if a.later_scenarios else ''}"
        f"{' --peer-cache ' + a.peer_cache if a.peer_cache else ''}`; "
        f"{datetime.date.today()}, nproc {os.cpu_count()}, commit {commit} (idstlpy side). Times are end "
        "to end (specification, model building and solve); idstlpy's is the median of "
        f"{a.repeats} solves. stlpy keeps the state box as hard constraints outside rho; idstlpy gets it "
        "as a hard constraint too (`make_problem(..., hard_box=True)`), and its `rho` is the robustness "
        "of its plan for the translated specification alone (`in box` checks the box). `same` = "
        f"|rho_idstlpy - rho_peer| <= {MATCH_TOL:g} against a peer that proved its optimum. `speed-up` = "
        "peer seconds / idstlpy seconds (a peer's time-out gives a lower bound, `>`).",
        "",
        "| scenario | T | idstlpy rho | optimal (scope) | in box | idstlpy s (cpu) | peer | peer status "
        "| peer rho | peer s (cpu) | rho diff | same | speed-up wall (cpu) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, T, ours, got in rows:
        value = ours.get("value", float("nan"))
        for backend, p in got.items():
            pr, ps = p.get("stlpy_robustness"), p.get("e2e_s")
            pc = p.get("cpu_s") if ps is not None else None  # a peer not run only built its model
            diff = (value - pr) if pr is not None and "value" in ours else float("nan")
            proven = p.get("status") == "solved"
            same = "yes" if proven and abs(diff) <= MATCH_TOL else ("no" if proven and diff == diff else "-")
            decided = proven or p.get("status") == "infeasible"
            speed = "-"
            if ps:
                lower = "" if decided else "> "
                cpu_ratio = f"{pc / ours['cpu_s']:.3g}" if pc else "-"
                speed = f"{lower}{ps / ours['e2e_s']:.3g} ({lower}{cpu_ratio})"
            lines.append(
                f"| {name} | {T} | {value:.9g} | {ours['optimal']} ({ours['scope'] or '-'}) | "
                f"{ours.get('in_box', '-')} | {ours['e2e_s']:.3g} ({ours['cpu_s']:.3g}) | {backend} | "
                f"{p.get('status')} | {'-' if pr is None else f'{pr:.9g}'} | "
                f"{'-' if ps is None else f'{ps:.3g}'} ({'-' if pc is None else f'{pc:.3g}'}) | "
                f"{diff:.2g} | {same} | {speed} |"
            )
    lines += ["", "When each side was measured (UTC, 1-minute load average; nproc 2, shared machine):", ""]
    for name, T, ours, got in rows:
        peer_when = "; ".join(f"{b} {p.get('measured', '?')}" for b, p in got.items())
        runs_s = ", ".join(f"{s:.2f}" for s in ours["all_s"])
        lines.append(
            f"- {name} T = {T}: idstlpy {ours['measured']} (runs {runs_s} s, "
            f"same plan every run: {ours['consistent']}); {peer_when}"
        )
    with open(a.out, "w") as fh:
        fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
