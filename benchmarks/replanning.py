"""Replanning under real noise (issue 15): a fixed plan against ``execute(replan="on_risk" | "every")``.

Run: ``python -m benchmarks.replanning [--runs 50] [--kinds a,b,...] [--size full] [--solve-seed 0]
[--time-limit 60] [--replan-time-limit 5] [--max-replans 3] [--jobs 2] [--resume]
[--out benchmarks/replanning_results.md]``.

Problems: the paper's listing (light-dark, kind ``listing``) and every kind of the
active-perception suite (:mod:`benchmarks.perception_problems`, ``--size``), in :data:`ORDER`
(cheap and informative first), each solved once with ``--solve-seed`` and the listing's sampler
parameters (``--time-limit`` per solve); a kind without a plan is listed with the solver's
status. Every plan is executed ``--runs`` times in three ways, with the *same* execution seeds
(run ``i`` uses child ``i`` of ``SeedSequence(--exec-seed)``; the three columns are paired: until
its first adopted re-plan, a run of the replanning executor is the fixed run, bit for bit):

- ``fixed``: ``execute(replan=None)``, i.e. ``simulate`` (what ``validate`` measures);
- ``on_risk``: ``execute(replan="on_risk", risk=0.99)``, the remaining plan's success predicted
  (sound bound, the smaller of executed belief and true state) every ``check`` steps;
- ``every``: ``execute(replan="every")``, a re-solve every ``every`` steps;
- ``on_risk_cl``: ``on_risk`` whose re-solves plan against the predicted true state
  (``solver_options={"guarantee": "closed_loop"}``), the other options unchanged;
- ``on_drift``: ``on_risk`` that also checks whenever the executed belief's mean leaves the 95%
  ellipse of its last predicted distribution (``drift=0.95``), so a run going astray is checked
  before the schedule's next check;
- ``drift``: checked *only* when the belief leaves that ellipse (no schedule): the re-solves
  (at most ``--max-replans``) are kept for runs that go astray instead of being spent at scheduled
  checks of runs that follow their prediction (with ``risk = 0.99`` above the plan's own
  predicted success, every check re-solves);
- ``drift_start``: ``drift`` with the start check (``execute(start_resolves=2)``): a plan whose
  success predicted from the start belief is below the risk is re-solved before its first step
  (at most twice, counted in ``--max-replans``; adopted when predicted better). Detour's plan
  breaks the obstacle's corner at steps 3-11, before any drift check can see it;
- ``drift_start_cl``: ``drift_start`` whose re-solves use ``guarantee="closed_loop"``;
- ``checked`` (``checked_est``): the start check made *once* per plan (``stl.start_check``,
  :data:`CHECKS`: up to three MLO re-solves, then, while still below the risk, up to two under
  ``guarantee="closed_loop"``; seeds from ``--solve-seed``), its plan then executed by ``drift``
  whose re-solves use ``guarantee="closed_loop"``. Nothing is observed before the first step,
  so the check is the same for every run: ``drift_start_cl`` makes it in every run, at the
  cost of a solve or two per run. ``checked`` reads the risk on the sound bound (as every
  executor above), ``checked_est`` on the sampled estimate (``risk_measure="estimate"``,
  :data:`CHECK_SAMPLES` samples at the start, 1000 at a drift check): the union bound of a long
  plan stays below 0.99 where the plan succeeds in 99.7% of runs, and a check on it re-solves
  in every run.

``check`` and ``every`` scale with the plan (``check = max(5, N // 10)``, ``every =
max(10, N // 5)``, ``N`` the plan's length) so a run costs about ten predictions or five re-solves
whatever the horizon. Re-solves use the listing's sampler parameters, at most ``--max-replans``
per run, ``--replan-time-limit`` seconds each, seeds derived from the run's seed, and the default
``adopt="better"`` (a re-solved plan is followed only when its predicted success is higher).

Real system, true start and tracking: the suite's (every planning mode's ``A, B`` as
``mk_lcs``, process noise of the planning mode, start offset from the prior mean like the
paper's, LQR horizon 5, Q = I, R = 0.05 I, inputs clipped to the domain).

Reported per problem and executor: success of the executed belief and of the true state (the
formula's deterministic reading) with Wilson 95% intervals, re-solves and adopted plans per run
(mean / max), re-solve outcomes, seconds per run. The goal: on every problem where the fixed
plan reaches 90% (per measure), replanning reaches 99%. Each kind's runs are recorded in
``--work`` (default ``results/replanning/<kind>.json``, git-ignored) and the report is rewritten
after every kind, so an interrupted run keeps what it measured (``--resume`` continues it).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from . import perception_problems as pp
from .report import machine

ROOT = Path(__file__).resolve().parent.parent

SAMPLER: dict[str, Any] = {
    "rrt_timeout": 60,
    "delta_near": 2,
    "delta_drain": 0.5,
    "goal_bias": 0.25,
    "min_num_of_steps": 3,
    "max_num_of_steps": 15,
}
MODES = (
    "fixed", "on_risk", "every", "on_risk_cl", "on_drift", "drift", "drift_start", "drift_start_cl",
    "checked", "checked_est",
)  # fmt: skip
CHECKED = ("checked", "checked_est")
CHECKS = (("mlo", 3), ("closed_loop", 2))
"""``checked``: the start check's rounds (guarantee of the re-solves, re-solves at most)."""
CHECK_SAMPLES = 4000
"""``checked_est``: samples of the start check's estimate (made once; a drift check uses 1000:
at 1000 the estimate's sampling error, about 0.003 at 0.99, decides whether a plan predicted
0.989 from 8000 samples is kept)."""
RISK = 0.99
DRIFT = 0.95
START_RESOLVES = 2
"""``drift_start``: re-solves before the first step at most (of the run's ``--max-replans``)."""


def _setup(kind: str, size: str) -> tuple[Any, Any, np.ndarray]:
    """The problem with the suite's tracking gains, its real system and true start."""
    problem, _ = pp.build(kind, size)
    for mode in problem.switched_system.system_modes:
        mode.compute_finite_horizon_lqr(
            horizon=5, Q_final=np.identity(mode.n), Q=np.identity(mode.n), R=0.05 * np.identity(mode.m)
        )
    return problem, pp.real_system(problem), pp.real_initial_state(kind, problem)


def solve_job(kind: str, size: str, seed: int, time_limit: float) -> dict[str, Any]:
    """Solve one problem once; the plan (or None) and how it went."""
    problem, _, _ = _setup(kind, size)
    t0 = time.perf_counter()
    result = problem.solve_result(**SAMPLER, seed=seed, time_limit=time_limit)
    return {
        "kind": kind,
        "status": result.status,
        "plan": result.trajectory,
        "solve_s": time.perf_counter() - t0,
        "reason": " ".join(str(result.reason).split())[:160],
    }


def check_job(kind: str, size: str, plan: Any, mode: str, seed: int, time_limit: float) -> dict[str, Any]:
    """The start check of ``checked`` / ``checked_est``, made once for a plan (:data:`CHECKS`)."""
    import idstlpy as stl

    problem, _, _ = _setup(kind, size)
    options = stl.SolverOptions.make(**SAMPLER)
    measure = "estimate" if mode == "checked_est" else "bound"
    t0 = time.perf_counter()
    current, initial, replans, predicted = plan, None, [], float("nan")
    for guarantee, resolves in CHECKS:
        check = stl.start_check(
            problem, current, risk=RISK, resolves=resolves, seed=seed, options=options,
            solver_options={"guarantee": guarantee}, replan_time_limit=time_limit, risk_measure=measure,
            risk_samples=CHECK_SAMPLES,
        )  # fmt: skip
        initial = check.initial_predicted if initial is None else initial
        current, predicted = check.plan, check.predicted
        replans += [
            (guarantee, r.status, r.adopted, r.new_predicted, bool(r.caps_hit)) for r in check.replans
        ]
        if predicted >= RISK:
            break
    return {
        "plan": current,
        "summary": {
            "initial": initial,
            "predicted": predicted,
            "steps": current.num_of_steps,
            "replans": replans,
            "seconds": time.perf_counter() - t0,
        },
    }


def schedule(num_of_steps: int) -> tuple[int, int]:
    """``(check, every)`` for a plan of ``num_of_steps`` steps (module notes)."""
    return max(5, num_of_steps // 10), max(10, num_of_steps // 5)


def run_batch(
    kind: str,
    size: str,
    plan: Any,
    mode: str,
    seeds: list[np.random.SeedSequence],
    replan_time_limit: float,
    max_replans: int = 3,
) -> list[dict[str, Any]]:
    """Execute one batch of runs of one executor; one small dict per run."""
    import idstlpy as stl

    problem, real, x0 = _setup(kind, size)
    check, every = schedule(plan.num_of_steps)
    kw: dict[str, Any] = {}
    options = stl.SolverOptions.make(**SAMPLER)
    if mode in ("on_risk", "on_risk_cl"):
        kw = {"replan": "on_risk", "risk": RISK, "check_every": check}
    elif mode == "on_drift":  # on_risk, also checked whenever the belief leaves its predicted ellipse
        kw = {"replan": "on_risk", "risk": RISK, "check_every": check, "drift": DRIFT}
    elif mode == "drift":  # checked only when the belief leaves its predicted ellipse (no schedule)
        kw = {"replan": "on_risk", "risk": RISK, "check_every": plan.num_of_steps + 1, "drift": DRIFT}
    elif mode in CHECKED:  # drift, the plan checked once before (check_job)
        kw = {
            "replan": "on_risk",
            "risk": RISK,
            "check_every": plan.num_of_steps + 1,
            "drift": DRIFT,
            "risk_measure": "estimate" if mode == "checked_est" else "bound",
        }
    elif mode in ("drift_start", "drift_start_cl"):  # drift; a plan predicted below the risk re-solved first
        kw = {
            "replan": "on_risk",
            "risk": RISK,
            "check_every": plan.num_of_steps + 1,
            "drift": DRIFT,
            "start_resolves": START_RESOLVES,
        }
    elif mode == "every":
        kw = {"replan": "every", "every": every}
    if mode in ("on_risk_cl", "drift_start_cl", *CHECKED):  # re-solves against the predicted true state
        options = options.with_(guarantee="closed_loop")
    policy = (
        stl.ReplanPolicy.from_keywords(
            options=options, replan_time_limit=replan_time_limit, max_replans=max_replans, **kw
        )
        if kw
        else None  # fixed: simulate's run
    )
    out = []
    for ss in seeds:
        t0 = time.perf_counter()
        rep = stl.execute(problem, plan, real, x0, seed=ss, policy=policy)
        out.append(
            {
                "belief": rep.belief_satisfied,
                "state": rep.state_satisfied,
                "replans": rep.num_replans,
                "adopted": rep.num_adopted,
                "statuses": [r.status for r in rep.replans],
                "caps": sum(bool(r.caps_hit) for r in rep.replans),
                "resolve_s": rep.replan_time,
                "seconds": time.perf_counter() - t0,
            }
        )
    return out


def wilson(k: int, n: int) -> tuple[float, float]:
    from idstlpy.execution import wilson_interval

    return wilson_interval(k, n)


def _pct(x: float) -> str:
    return f"{100 * x:.1f}%"


def _rate(runs: list[dict[str, Any]], key: str) -> str:
    k, n = sum(r[key] for r in runs), len(runs)
    lo, hi = wilson(k, n)
    return f"{_pct(k / n)} [{_pct(lo)}, {_pct(hi)}]"


def summarise(kind: str, plan_len: int, by_mode: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    """Rates, re-plans and time per executor, and the goal's verdict for one problem."""
    row: dict[str, Any] = {"kind": kind, "steps": plan_len, "modes": [m for m in MODES if by_mode.get(m)]}
    for mode in row["modes"]:
        runs = by_mode[mode]
        n = len(runs)
        row[mode] = {
            "n": n,
            "belief": sum(r["belief"] for r in runs) / n,
            "state": sum(r["state"] for r in runs) / n,
            "belief_txt": _rate(runs, "belief"),
            "state_txt": _rate(runs, "state"),
            "replans_mean": float(np.mean([r["replans"] for r in runs])),
            "replans_max": int(max(r["replans"] for r in runs)),
            "adopted_mean": float(np.mean([r["adopted"] for r in runs])),
            "statuses": Counter(st for r in runs for st in r["statuses"]),
            "caps": sum(r["caps"] for r in runs),
            "seconds": float(np.mean([r["seconds"] for r in runs])),
            "resolve_s": float(np.mean([r["resolve_s"] for r in runs])),
        }
    verdicts = []
    for measure in ("belief", "state"):
        if "fixed" not in row:
            verdicts.append(f"{measure}: the fixed plan not measured in this run")
            continue
        if row["fixed"][measure] < 0.90:
            verdicts.append(f"{measure}: fixed < 90%, not in the goal")
            continue
        for mode in [m for m in row["modes"] if m != "fixed"]:
            ok = row[mode][measure] >= 0.99
            verdicts.append(f"{measure} {mode}: {'met' if ok else 'MISSED'} ({_pct(row[mode][measure])})")
    row["goal"] = "; ".join(verdicts)
    return row


def markdown(
    rows: list[dict[str, Any]], missing: list[dict[str, Any]], args: argparse.Namespace, wall: float
) -> str:
    info = machine()
    lines = [
        "# Replanning under real noise (issue 15)",
        "",
        f"- command: `python -m benchmarks.replanning {' '.join(args.argv)}`".rstrip(),
        f"- date: {dt.datetime.now(dt.UTC).isoformat(timespec='seconds')}; wall time {wall:.0f} s",
        f"- machine: {info.get('nproc', '?')} cores, {info.get('cpu', '?')}; idstlpy revision "
        f"{info.get('git', '?')}",
        f"- plans: solver seed {args.solve_seed}, the listing's sampler parameters, "
        f"{args.time_limit:g} s cap; executions: the table's runs per executor, seeds spawned from "
        f"{args.exec_seed} (paired across executors)",
        f"- on_risk: risk = {RISK}, sound bound, min(belief, state), every `check = max(5, N // 10)` steps; "
        f"every: a re-solve every `max(10, N // 5)` steps; at most {args.max_replans} re-solves per run, "
        f"each capped at {args.replan_time_limit:g} s; on_risk_cl: on_risk whose re-solves use "
        f"guarantee='closed_loop'; on_drift: on_risk also checked whenever the executed belief's mean "
        f"leaves the {DRIFT:.0%} ellipse of its last prediction; drift: checked only then; drift_start: "
        f"drift, and a plan predicted below the risk from the start belief re-solved before its first "
        f"step (at most {START_RESOLVES} times, counted in the re-solves); drift_start_cl: drift_start "
        "whose re-solves use guarantee='closed_loop'; checked / checked_est: the start check made once "
        f"per plan (up to {CHECKS[0][1]} MLO re-solves, then {CHECKS[1][1]} closed-loop ones, while below "
        "the risk), then drift with closed-loop re-solves; checked_est reads the risk on the sampled "
        f"estimate ({CHECK_SAMPLES} samples at the start, 1000 at a drift check)",
        "",
        "| problem | steps | executor | runs | belief success [95% CI] | state success [95% CI] "
        "| re-solves / run (max) | adopted / run | re-solve outcomes | s / run |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        for mode in row["modes"]:
            m = row[mode]
            outcomes = ", ".join(f"{k} {v}" for k, v in sorted(m["statuses"].items())) or "-"
            if m["caps"]:
                outcomes += f" (caps hit: {m['caps']})"
            lines.append(
                f"| {row['kind']} | {row['steps']} | {mode} | {m['n']} | "
                f"{m['belief_txt']} | {m['state_txt']} | "
                f"{m['replans_mean']:.2f} ({m['replans_max']}) | {m['adopted_mean']:.2f} | {outcomes} | "
                f"{m['seconds']:.2f} |"
            )
    lines += ["", "Goal (replanning reaches 99% where the fixed plan reaches 90%, per measure):", ""]
    for row in rows:
        lines.append(f"- {row['kind']}: {row['goal']}")
    checks = [(row["kind"], mode, c) for row in rows for mode, c in sorted(row["checks"].items())]
    if checks:
        lines += [
            "",
            "Start checks (`checked`, `checked_est`: once per plan; re-solves as guarantee "
            "status -> predicted, * adopted, ! cap hit):",
            "",
        ]
        for kind, mode, c in checks:
            tries = (
                ", ".join(
                    f"{g} {st} -> {p:.4f}{'*' if a else ''}{'!' if cap else ''}"
                    for g, st, a, p, cap in c["replans"]
                )
                or "none (predicted above the risk)"
            )
            lines.append(
                f"- {kind} {mode}: predicted {c['initial']:.4f} -> {c['predicted']:.4f} "
                f"({c['steps']} steps); re-solves: {tries}; {c['seconds']:.1f} s"
            )
    if missing:
        lines += ["", "Kinds without a plan (not executed):", ""]
        for m in missing:
            lines.append(f"- {m['kind']}: {m['status']} after {m['solve_s']:.1f} s ({m['reason']})")
    return "\n".join(lines) + "\n"


ORDER = (
    "listing",
    "noisy_hold",
    "light_dark_3d",
    "scaled_workspace",
    "detour",
    "sequence",
    "weaker_formula",
    "long_horizon",
    "noisy_hold_narrow",
    "double_integrator",
    "patrol",
    "sensor_switching",
    "noise_floor",
)
"""Kinds in the order they run (cheap and informative first: a run cut short still says most)."""


def run_kind(
    pool: Any, kind: str, args: argparse.Namespace, seeds: list[Any], record: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Solve one kind, execute its plan with the executors ``args.modes`` not yet in ``record``."""
    s = pool.submit(solve_job, kind, args.size, args.solve_seed, args.time_limit).result()
    print(f"{kind}: {s['status']} in {s['solve_s']:.1f} s", file=sys.stderr, flush=True)
    if record is not None and s["plan"] is not None and record.get("steps") != s["plan"].num_of_steps:
        record = None  # the solver gave another plan than the recorded one: measure everything again
    if record is None:
        record = {k: s[k] for k in ("kind", "status", "solve_s", "reason")}
    if s["plan"] is None:
        return record
    record["steps"] = s["plan"].num_of_steps
    runs = record.setdefault("runs", {})
    todo = [m for m in args.modes if m not in runs]
    plans = {m: s["plan"] for m in todo}
    checks = record.setdefault("checks", {})
    for mode in [m for m in todo if m in CHECKED]:
        job = (kind, args.size, s["plan"], mode, args.solve_seed, args.time_limit)
        c = pool.submit(check_job, *job).result()
        plans[mode], checks[mode] = c["plan"], c["summary"]
        print(f"{kind} {mode}: start check {c['summary']}", file=sys.stderr, flush=True)
    chunk = max(1, math.ceil(len(seeds) / 4))
    futures = {
        (mode, i): pool.submit(
            run_batch,
            kind,
            args.size,
            plans[mode],
            mode,
            seeds[i : i + chunk],
            args.replan_time_limit,
            args.max_replans,
        )
        for mode in todo
        for i in range(0, len(seeds), chunk)
    }
    for mode in todo:
        runs[mode] = []
    for (mode, _), fut in futures.items():
        runs[mode].extend(fut.result())
    return record


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.replanning",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--runs", type=int, default=50)
    p.add_argument(
        "--first",
        type=int,
        default=0,
        help="index of the first run (runs first .. first + runs - 1 of the seed stream)",
    )
    p.add_argument("--kinds", default="", help="comma-separated perception kinds (default: all, cheap first)")
    p.add_argument("--size", default="full", choices=pp.SIZES)
    p.add_argument("--solve-seed", type=int, default=0)
    p.add_argument("--exec-seed", type=int, default=2026)
    p.add_argument("--time-limit", type=float, default=60.0, help="seconds per initial solve")
    p.add_argument("--replan-time-limit", type=float, default=5.0, help="seconds per re-solve")
    p.add_argument("--max-replans", type=int, default=3, help="re-solves per run at most")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--work", default=str(ROOT / "results" / "replanning"), help="per-kind JSON records")
    p.add_argument("--resume", action="store_true", help="keep the executors already recorded in --work")
    p.add_argument("--modes", default=",".join(MODES), help=f"comma-separated executors of {MODES}")
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "replanning_results.md"))
    args = p.parse_args(argv)
    args.argv = argv
    kinds = [k for k in args.kinds.split(",") if k] or list(ORDER)
    args.modes = [m for m in args.modes.split(",") if m]
    if not set(args.modes) <= set(MODES):
        p.error(f"--modes must be among {MODES}")
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    seeds = np.random.SeedSequence(args.exec_seed).spawn(args.first + args.runs)[args.first :]
    with ProcessPoolExecutor(args.jobs) as pool:
        for kind in kinds:
            path = work / f"{kind}.json"
            old = json.loads(path.read_text()) if args.resume and path.exists() else None
            if old is not None and ("runs" not in old or all(m in old["runs"] for m in args.modes)):
                continue
            record = run_kind(pool, kind, args, seeds, old)
            path.write_text(json.dumps(record))
            write_report(kinds, args, work, time.perf_counter() - t_start)
    write_report(kinds, args, work, time.perf_counter() - t_start)
    print(Path(args.out).read_text())
    return 0


def write_report(kinds: list[str], args: argparse.Namespace, work: Path, wall: float) -> None:
    """The Markdown report from every recorded kind (rewritten after each kind)."""
    rows, missing = [], []
    for kind in kinds:
        path = work / f"{kind}.json"
        if not path.exists():
            continue
        record = json.loads(path.read_text())
        if "runs" not in record:
            missing.append(record)
            continue
        row = summarise(kind, record["steps"], record["runs"])
        row["checks"] = {m: c for m, c in record.get("checks", {}).items() if m in row["modes"]}
        rows.append(row)
    Path(args.out).write_text(markdown(rows, missing, args, wall))


if __name__ == "__main__":
    raise SystemExit(main())
