"""Issue 23: default plans (``guarantee="execution"``) executed from prior-drawn starts, against ``"mlo"``.

For every problem (the issue's, our own in :mod:`benchmarks.defaults_problems` and, with
``--suite``, the kinds of :mod:`benchmarks.perception_problems` at size small) both guarantees
solve with the same options and seed; the default plan is executed ``--runs`` times by
``simulate`` (Kalman filter, the modes' default LQR tracking, inputs clipped to the control
domain, process noise of the model) from true starts drawn from the prior, and the measured
success rates (executed belief, true state; 95% Wilson intervals) are put next to the target and
the predicted rates (``result.execution``). Time and candidates of the two guarantees side by side.

Usage::

    python -m benchmarks.defaults [--runs 1000] [--suite] [--problems a,b] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

import idstlpy as stl
from benchmarks import defaults_problems as dp
from idstlpy.execution.validation import state_trajectory, wilson_interval

OPTIONS = dict(
    rrt_timeout=60,
    delta_near=2,
    delta_drain=0.5,
    goal_bias=0.25,
    min_num_of_steps=3,
    max_num_of_steps=15,
    seed=0,
    time_limit=60,
)


def agree(pred: float, n_pred: int, measured: float, n_meas: int, alpha: float = 0.05) -> bool:
    """Whether a predicted and a measured rate agree by a two-sided two-proportion z-test (pooled)
    at level ``alpha``: the prediction is itself an estimate from ``n_pred`` model samples."""
    from scipy.stats import norm

    k = round(pred * n_pred) + round(measured * n_meas)
    pooled = k / (n_pred + n_meas)
    se = np.sqrt(pooled * (1 - pooled) * (1 / n_pred + 1 / n_meas))
    if se == 0:
        return bool(pred == measured)
    return bool(2 * norm.sf(abs(pred - measured) / se) >= alpha)


def execute(problem: stl.Problem, plan: Any, runs: int, seed: int) -> tuple[int, int]:
    """Successes (executed belief, true state) of ``runs`` executions from prior-drawn starts."""
    rng = np.random.default_rng(seed)
    init, formula = problem.initial_state, problem.stl_formula
    ok_b = ok_s = 0
    for _ in range(runs):
        x0 = rng.multivariate_normal(init.mean, init.cov)
        xi_sim, xi_real = stl.simulate(
            problem.switched_system,
            plan,
            plan.num_of_steps,
            x0,
            problem.switched_system,
            seed=rng,
            control_domain=problem.control_domain,
        )
        ok_b += stl.robustness(xi_sim, formula) >= 0
        ok_s += stl.robustness(state_trajectory(xi_real), formula) >= 0
    return ok_b, ok_s


def problems(names: Sequence[str] | None, suite: bool) -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = [(n, b) for n, b in dp.PROBLEMS.items() if not names or n in names]
    if suite:
        from benchmarks import perception_problems as pp

        for kind in pp.KINDS:
            if names and kind not in names:
                continue
            out.append((f"suite:{kind}", lambda kind=kind: pp.build(kind, "small")[0]))
    return out


def run_one(name: str, build: Any, runs: int) -> dict[str, Any]:
    row: dict[str, Any] = {"name": name}
    for g in ("mlo", "execution"):
        problem = build()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t0 = time.perf_counter()
            r = problem.solve_result(guarantee=g, **OPTIONS)
            row[f"{g}_time"] = time.perf_counter() - t0
        row[f"{g}_status"] = r.status
        row[f"{g}_candidates"] = r.stats.candidates
        if g == "execution":
            row["result"] = r
            row["problem"] = problem
    r = row["result"]
    if r.found:
        ex = r.execution
        b, s = execute(row["problem"], r.trajectory, runs, seed=2026)
        row.update(
            pred_b=ex.belief_estimate,
            pred_s=ex.state_estimate,
            pred_n=ex.samples,
            meets=ex.meets_target,
            mc_b=b / runs,
            mc_s=s / runs,
            ci_b=wilson_interval(b, runs),
            ci_s=wilson_interval(s, runs),
        )
    return row


def pct(x: float) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{100 * x:.1f}"


def table(rows: list[dict[str, Any]], runs: int) -> str:
    head = (
        "| problem | default: status | flag | predicted b / s | measured b / s (95% Wilson) | "
        "at target (b>=90, s>=95 within CI) or flagged | pred. inside CI (b, s) | "
        "pred. samples | agree, two-sample 5% (b, s) | time default / mlo (s) | "
        "ratio | candidates default / mlo |\n|---|---|---|---|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    for row in rows:
        ratio = row["execution_time"] / max(row["mlo_time"], 1e-9)
        row["ratio"] = ratio
        if "pred_b" in row:
            cb, cs = row["ci_b"], row["ci_s"]
            holds = cb[1] >= 0.90 and cs[1] >= 0.95
            ok = holds or not row["meets"]
            row["ok"] = ok
            inside = (cb[0] <= row["pred_b"] <= cb[1], cs[0] <= row["pred_s"] <= cs[1])
            row["inside"] = inside
            same = (
                agree(row["pred_b"], row["pred_n"], row["mc_b"], runs),
                agree(row["pred_s"], row["pred_n"], row["mc_s"], runs),
            )
            row["agree"] = same
            lines.append(
                f"| {row['name']} | {row['execution_status']} | {'meets' if row['meets'] else 'BELOW'} | "
                f"{pct(row['pred_b'])} / {pct(row['pred_s'])} | "
                f"{pct(row['mc_b'])} [{pct(cb[0])}, {pct(cb[1])}] / "
                f"{pct(row['mc_s'])} [{pct(cs[0])}, {pct(cs[1])}] | {'yes' if ok else 'NO'} | "
                f"{'yes' if inside[0] else 'no'}, {'yes' if inside[1] else 'no'} | {row['pred_n']} | "
                f"{'yes' if same[0] else 'NO'}, {'yes' if same[1] else 'NO'} | "
                f"{row['execution_time']:.2f} / {row['mlo_time']:.2f} | {ratio:.2f} | "
                f"{row['execution_candidates']} / {row['mlo_candidates']} |"
            )
        else:
            lines.append(
                f"| {row['name']} | {row['execution_status']} (mlo: {row['mlo_status']}) "
                "| - | - | - | - | - | - | - | "
                f"{row['execution_time']:.2f} / {row['mlo_time']:.2f} | {ratio:.2f} | "
                f"{row['execution_candidates']} / {row['mlo_candidates']} |"
            )
    found = [r for r in rows if "pred_b" in r]
    ratios = [r["ratio"] for r in rows]
    inside = [v for r in found for v in r["inside"]]
    agreeing = [v for r in found for v in r["agree"]]
    summary = [
        "",
        f"- problems: {len(rows)}, default plans found: {len(found)}; at target or flagged: "
        f"{sum(r['ok'] for r in found)} / {len(found)}; "
        f"meeting the target (flag): {sum(r['meets'] for r in found)}",
        f"- time default / mlo: median {statistics.median(ratios):.2f}x, worst {max(ratios):.2f}x "
        f"(wall clock on a shared 2-core machine)",
        f"- predicted rate inside the {runs}-run 95% Wilson interval: {sum(inside)} / {len(inside)} readings "
        f"({100 * sum(inside) / max(1, len(inside)):.0f}%)",
        f"- predicted and measured rates agree (two-sample test, 5%): {sum(agreeing)} / {len(agreeing)} "
        f"readings ({100 * sum(agreeing) / max(1, len(agreeing)):.0f}%)",
    ]
    return "\n".join(lines + summary)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--suite", action="store_true", help="also the perception suite's kinds (size small)")
    ap.add_argument("--problems", default="", help="comma-separated names (default: all)")
    ap.add_argument("--out", default=str(Path(__file__).with_name("defaults_results.md")))
    args = ap.parse_args(argv)
    names = [n for n in args.problems.split(",") if n]
    rows = []
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
        ).stdout.strip()
    except OSError:
        commit = "?"
    for name, build in problems(names, args.suite):
        row = run_one(name, build, args.runs)
        rows.append(row)
        print(
            name,
            {k: v for k, v in row.items() if k not in ("result", "problem")},
            file=sys.stderr,
            flush=True,
        )
    text = (
        f"# Default plans executed (issue 23)\n\n`python -m benchmarks.defaults --runs {args.runs}"
        f"{' --suite' if args.suite else ''}{' --problems ' + args.problems if args.problems else ''}`, "
        f"started {started} at commit {commit}, load average {load} (1/5/15 min). "
        f"Options: {OPTIONS}. Executions from prior-drawn true starts, "
        f"{args.runs} per problem; target 90% belief / 95% true state.\n\n" + table(rows, args.runs) + "\n"
    )
    Path(args.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
