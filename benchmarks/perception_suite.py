"""Active-perception suite (issue 11): every kind of :mod:`benchmarks.perception_problems` over seeds.

``python -m benchmarks.perception_suite [--seeds 10] [--kinds a,b,...] [--runs 200]
[--size small|full] [--time-limit 120] [--jobs 1] [--out DIR]``

Each instance is solved once per seed with the paper's sampler parameters (``rrt_timeout=60,
delta_near=2, delta_drain=0.5, goal_bias=0.25, min_num_of_steps=3, max_num_of_steps=15``) and a
``time_limit`` per solve; the row records the status, the wall-clock solve time, the plan length
and the solver's statistics. A found plan is executed ``--runs`` times with
``stl.validate`` (real system: every planning mode's ``A, B`` as ``mk_lcs``; the tracking gains
the plan was made for, ``plan.tracking``; true start offset from the prior mean like the
paper's) and the belief / true-state success rates are recorded.

A row whose status contradicts what is known is flagged in ``check``: ``UNSOUND`` for
``infeasible`` on a kind with a verified witness or ``found`` on the infeasible kind, ``BAD PLAN``
when a returned plan fails an independent re-roll and monitor.

Outputs in ``--out`` (default ``benchmarks/results/perception``, committed with the section of
BENCHMARKS.md they back): ``perception_<size>.csv`` (one
row per kind and seed, written as jobs finish; ``--resume`` skips the rows already there) and
``perception_<size>.md`` (one summary line per kind).
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import logging
import os
import subprocess
import sys
import time
import traceback
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from . import perception_problems as pp

__all__ = ["SAMPLER", "run_job", "summarise", "markdown_table", "main"]

ROOT = Path(__file__).resolve().parent.parent

SAMPLER: dict[str, Any] = {
    "rrt_timeout": 60,
    "delta_near": 2,
    "delta_drain": 0.5,
    "goal_bias": 0.25,
    "min_num_of_steps": 3,
    "max_num_of_steps": 15,
}
"""The paper's listing's sampler parameters."""

STAT_FIELDS = ("candidates", "abandoned", "refuted", "nodes", "sampler_iterations", "bmc_depth", "caps_hit")

FIELDS = (
    "kind",
    "size",
    "seed",
    "expected",
    "status",
    "check",
    "reason",
    "solve_s",
    "plan_length",
    "margin",
    *STAT_FIELDS,
    "mc_runs",
    "mc_belief_rate",
    "mc_state_rate",
    "mc_s",
    "error",
    "commit",
)


def run_job(
    kind: str, size: str, seed: int, time_limit: float, runs: int, commit: str = ""
) -> dict[str, Any]:
    """Solve one instance with one seed, execute the plan; one CSV row (never raises)."""
    import idstlpy as stl

    row: dict[str, Any] = {
        "kind": kind,
        "size": size,
        "seed": seed,
        "expected": pp.KINDS[kind].expected,
        "commit": commit,
    }
    row.update({k: "" for k in FIELDS if k not in row})
    try:
        problem, _ = pp.build(kind, size)
        t0 = time.perf_counter()
        result = problem.solve_result(**SAMPLER, seed=seed, time_limit=time_limit)
        row["solve_s"] = round(time.perf_counter() - t0, 4)
        row["status"] = result.status
        row["reason"] = " ".join(str(result.reason).split())[:300]
        stats = result.stats
        for name in STAT_FIELDS:
            value = getattr(stats, name)
            row[name] = ";".join(value) if isinstance(value, list) else value
        checks = []
        if result.status == "infeasible" and row["expected"] == "feasible":
            checks.append("UNSOUND: infeasible on a kind with a verified witness")
        plan = result.trajectory
        if result.status == "found" and plan is not None:
            if row["expected"] == "infeasible":
                checks.append("UNSOUND: found on an infeasible kind")
            row["plan_length"] = plan.num_of_steps
            row["margin"] = result.margin
            again = stl.rollout(
                problem.switched_system, problem.initial_state, plan.get_action(), plan.get_control()
            )
            if not stl.satisfies(again, problem.stl_formula):
                checks.append("BAD PLAN: the re-rolled plan fails the monitor")
            if runs > 0:
                t1 = time.perf_counter()
                report = stl.validate(
                    problem,
                    plan,
                    pp.real_system(problem),
                    pp.real_initial_state(kind, problem),
                    runs=runs,
                    seed=seed,
                    executor="serial",
                )
                row["mc_s"] = round(time.perf_counter() - t1, 3)
                row["mc_runs"] = runs
                row["mc_belief_rate"] = report.belief_success_rate
                row["mc_state_rate"] = report.state_success_rate
        row["check"] = "; ".join(checks) if checks else "ok"
    except Exception as exc:  # noqa: BLE001 - a crash is a result of the benchmark, recorded
        row["status"] = row["status"] or "error"
        row["check"] = "ERROR"
        row["error"] = f"{type(exc).__name__}: {exc}"[:300]
        logging.getLogger(__name__).error("%s/%s/%d: %s", kind, size, seed, traceback.format_exc())
    return row


# ------------------------------------------------------------------------------------------------
# Summary


def _floats(rows: Iterable[dict[str, Any]], key: str) -> list[float]:
    out = []
    for r in rows:
        v = r.get(key, "")
        if v in ("", None):
            continue
        out.append(float(v))
    return out


def _fmt(value: float | None, digits: int = 3) -> str:
    if value is None or not np.isfinite(value):
        return "-"
    return f"{value:.{digits}g}"


def summarise(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """One summary per kind (in the order of ``KINDS``)."""
    out = []
    for kind, spec in pp.KINDS.items():
        mine = [r for r in rows if r["kind"] == kind]
        if not mine:
            continue
        n = len(mine)
        count = {
            s: sum(r["status"] == s for r in mine)
            for s in ("found", "infeasible", "budget_exhausted", "error")
        }
        good = count["infeasible"] if spec.expected == "infeasible" else count["found"]
        times = _floats(mine, "solve_s")
        found = [r for r in mine if r["status"] == "found"]
        lengths = _floats(found, "plan_length")
        belief = _floats(found, "mc_belief_rate")
        state = _floats(found, "mc_state_rate")
        out.append(
            {
                "kind": kind,
                "label": spec.label,
                "expected": spec.expected,
                "seeds": n,
                "success": good / n,
                **count,
                "median_s": float(np.median(times)) if times else None,
                "p90_s": float(np.percentile(times, 90)) if times else None,
                "median_length": float(np.median(lengths)) if lengths else None,
                "median_belief": float(np.median(belief)) if belief else None,
                "median_state": float(np.median(state)) if state else None,
                "median_nodes": float(np.median(_floats(mine, "nodes"))) if _floats(mine, "nodes") else None,
                "median_candidates": (
                    float(np.median(_floats(mine, "candidates"))) if _floats(mine, "candidates") else None
                ),
                "caps_hit": sum(bool(r.get("caps_hit")) for r in mine),
                "flags": sorted({r["check"] for r in mine if r.get("check") not in ("ok", "")}),
            }
        )
    return out


def markdown_table(summary: Sequence[dict[str, Any]]) -> str:
    """The per-kind table (success over seeds, times over all seeds, lengths and MC over found plans)."""
    head = (
        "| kind | expected | success | found / infeasible / budget / error | median s | p90 s "
        "| median length | MC belief | MC state | median candidates | median nodes | caps hit | flags |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for s in summary:
        lines.append(
            f"| {s['label']} | {s['expected']} | {s['success'] * s['seeds']:.0f}/{s['seeds']} "
            f"| {s['found']} / {s['infeasible']} / {s['budget_exhausted']} / {s['error']} "
            f"| {_fmt(s['median_s'])} | {_fmt(s['p90_s'])} | {_fmt(s['median_length'], 4)} "
            f"| {_fmt(s['median_belief'])} | {_fmt(s['median_state'])} | {_fmt(s['median_candidates'])} "
            f"| {_fmt(s['median_nodes'])} | {s['caps_hit']} | {'; '.join(s['flags']) or '-'} |"
        )
    return head + "\n".join(lines) + "\n"


def _git_commit() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True, timeout=10
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--", "src"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=10,
        )
        return out.stdout.strip() + (" (src/ has uncommitted changes)" if dirty.stdout.strip() else "")
    except Exception:  # noqa: BLE001
        return "unknown"


def header(args: argparse.Namespace, started: str, elapsed: float) -> str:
    """Command, date, machine and commit of a run."""
    return (
        f"- command: `python -m benchmarks.perception_suite {' '.join(args.argv)}`\n"
        f"- started: {started}; wall time {elapsed:.0f} s\n"
        f"- nproc: {os.cpu_count()}; load average at start: {args.load}; jobs: {args.jobs}\n"
        f"- time limit per solve: {args.time_limit} s; Monte Carlo runs per plan: {args.runs}\n"
        f"- git commit at start: {args.commit}\n"
        f"- sampler: {', '.join(f'{k}={v}' for k, v in SAMPLER.items())}\n"
    )


# ------------------------------------------------------------------------------------------------
# Command line


def _read_csv(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.perception_suite", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--seeds", type=int, default=10, help="seeds 0..N-1 per kind (default 10)")
    parser.add_argument("--kinds", default=",".join(pp.KINDS), help="comma-separated kinds (default all)")
    parser.add_argument(
        "--runs", type=int, default=200, help="Monte Carlo executions per found plan (0: none)"
    )
    parser.add_argument("--size", choices=pp.SIZES, default="full")
    parser.add_argument("--time-limit", type=float, default=120.0, help="seconds per solve (default 120)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "perception")
    parser.add_argument(
        "--resume", action="store_true", help="keep the CSV's rows, run only the missing ones"
    )
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    args.load = " ".join(f"{v:.2f}" for v in os.getloadavg())
    args.commit = _git_commit()
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in pp.KINDS]
    if unknown:
        parser.error(f"unknown kinds {unknown}; choose from {list(pp.KINDS)}")
    args.kinds = kinds
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / f"perception_{args.size}.csv"
    md_path = out / f"perception_{args.size}.md"
    rows = _read_csv(csv_path) if args.resume else []
    done = {(r["kind"], int(r["seed"])) for r in rows}
    jobs = [(k, s) for k in args.kinds for s in range(args.seeds) if (k, s) not in done]
    started = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    t0 = time.perf_counter()
    with csv_path.open("w", newline="") as fh:
        # rewritten with the current columns (rows kept by --resume first)
        writer = csv.DictWriter(fh, fieldnames=FIELDS, restval="", extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)

        def record(row: dict[str, Any]) -> None:
            rows.append(row)
            writer.writerow(row)
            fh.flush()
            print(
                f"[{time.perf_counter() - t0:7.0f} s] {row['kind']:18s} seed {row['seed']:>2} "
                f"{row['status']:17s} "
                f"{row['solve_s']!s:>8} s  len {row['plan_length']!s:>5}  MC {row['mc_belief_rate']!s:.5}"
                f"/{row['mc_state_rate']!s:.5}  {row['check']}",
                flush=True,
            )

        if args.jobs <= 1:
            for kind, seed in jobs:
                record(run_job(kind, args.size, seed, args.time_limit, args.runs, args.commit))
        else:
            with ProcessPoolExecutor(max_workers=args.jobs) as pool:
                futures = [
                    pool.submit(run_job, k, args.size, s, args.time_limit, args.runs, args.commit)
                    for k, s in jobs
                ]
                for fut in as_completed(futures):
                    record(fut.result())
    rows = [r for r in rows if r["kind"] in args.kinds and int(r["seed"]) < args.seeds]
    summary = summarise(rows)
    text = (
        f"# Active-perception suite, size {args.size}\n\n"
        + header(args, started, time.perf_counter() - t0)
        + "\n"
        + markdown_table(summary)
    )
    md_path.write_text(text)
    print()
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
