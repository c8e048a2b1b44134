"""What the default guarantee's prediction costs, and whether a change keeps its numbers.

Under the default ``guarantee="execution"`` every plan the planner finds gets a predicted
execution (:func:`idstlpy.executor.predict.predict_closed_loop` via
``synthesis.context.SolveContext.predict``). This benchmark times that prediction alone and whole
default solves, on three problems:

- ``dims3``: three 2-D light-dark robots (6-D, :mod:`benchmarks.dims_family`, ``build(3)``);
- ``listing``: the paper's listing (``idstlpy.scenarios.light_dark(240, 40)``, the listing's
  sampler parameters);
- ``noisy_hold``: the perception suite's (d), hold under process noise (``small``).

Subcommands (run from the repository root, ``PYTHONPATH=src``; to measure another commit, point
``PYTHONPATH`` at its ``src`` and keep this file's directory on the path)::

    python -m benchmarks.prediction_cost capture --out plans.pkl
    python -m benchmarks.prediction_cost predict --plans plans.pkl --reps 3 --json new_predict.json
    python -m benchmarks.prediction_cost solve --reps 3 --json new_solve.json
    python -m benchmarks.prediction_cost screen --plans plans.pkl --json screen.json
    python -m benchmarks.prediction_cost report --old old_predict.json --new new_predict.json

``capture`` solves each problem once (seed 0, default options) and keeps every prediction request
the planner made (the problem it predicted on, the plan, the keywords), so that two commits
predict exactly the same plans. ``predict`` re-runs those requests (median of ``--reps``) and
prints, per plan, a digest of every rate the prediction reports (success estimates and bounds,
per-constraint violations and per-step probabilities, per-proposition violations) and one of its
moments: equal digests mean bit-identical numbers. ``solve`` times whole default solves and
digests the plan and its ``result.execution``. ``screen`` compares, per plan, the cheap Gaussian
closure with the particle closure the planner uses (the numbers behind the screening proposal in
``benchmarks/prediction_cost_results.md``). ``report`` prints the old / new table.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["PROBLEMS", "capture", "predict_digests", "rate_digest", "solve_timings"]

ROOT = Path(__file__).resolve().parent.parent

LISTING_SAMPLER: dict[str, Any] = {
    "rrt_timeout": 60,
    "delta_near": 2,
    "delta_drain": 0.5,
    "goal_bias": 0.25,
    "min_num_of_steps": 3,
    "max_num_of_steps": 15,
}


def _dims3() -> Any:
    from benchmarks import dims_family

    return dims_family.build(3)


def _listing() -> Any:
    from idstlpy import scenarios

    return scenarios.light_dark(240, 40)


def _noisy_hold() -> Any:
    from benchmarks import perception_problems

    return perception_problems.build("noisy_hold", "small")[0]


PROBLEMS: dict[str, tuple[Callable[[], Any], dict[str, Any]]] = {
    "dims3": (_dims3, {}),
    "listing": (_listing, LISTING_SAMPLER),
    "noisy_hold": (_noisy_hold, LISTING_SAMPLER),
}
"""Name -> (builder, ``solve_result`` keywords besides ``seed`` and ``time_limit``)."""

TIME_LIMIT = 120.0


def _hash(arrays: list[Any]) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(np.asarray(a, dtype=float)).tobytes())
    return h.hexdigest()[:16]


def rate_digest(pred: Any) -> tuple[str, str, dict[str, float]]:
    """Digests of a prediction's rates and of its moments, and its headline rates."""
    head = {
        k: float(getattr(pred, k))
        for k in (
            "state_success_estimate",
            "belief_success_estimate",
            "state_success_bound",
            "belief_success_bound",
            "state_success_sampled_bound",
            "belief_success_sampled_bound",
        )
    }
    rates: list[Any] = list(head.values())
    for c in pred.constraints:
        rates += [c.belief_violation, c.state_violation, c.belief_probability, c.state_probability]
    for name in sorted(pred.proposition_violation):
        rates += [pred.proposition_violation[name][r] for r in ("belief", "state")]
    moments = [
        pred.augmented_mean,
        pred.augmented_cov,
        pred.filter_cov,
        pred.transitions,
        pred.offsets,
        pred.noise_covs,
        pred.clip_probability,
    ]
    return _hash(rates), _hash(moments), head


def _load() -> None:
    """Put this checkout's ``benchmarks`` package on the path (``PYTHONPATH`` gives ``src``)."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))


# --------------------------------------------------------------------------------------------
# capture


def capture(names: list[str], seed: int = 0) -> list[dict[str, Any]]:
    """Solve each problem once and keep every prediction request the planner made.

    The planner's call is in ``synthesis/context.py`` (``SolveContext.predict``); before the loop
    was split (a01afad and earlier) it was in ``synthesis/cegis.py`` (``_Run.predict``).
    """
    import importlib

    try:
        context: Any = importlib.import_module("idstlpy.synthesis.context")
    except ImportError:
        context = importlib.import_module("idstlpy.synthesis.cegis")

    requests: list[dict[str, Any]] = []
    original = context.predict_closed_loop

    for name in names:
        build, kw = PROBLEMS[name]

        def spy(problem: Any, plan: Any, _name: str = name, **options: Any) -> Any:
            requests.append({"name": _name, "problem": problem, "plan": plan, "options": options})
            return original(problem, plan, **options)

        context.predict_closed_loop = spy
        try:
            build().solve_result(seed=seed, time_limit=TIME_LIMIT, **kw)
        finally:
            context.predict_closed_loop = original
    return requests


# --------------------------------------------------------------------------------------------
# predict / solve / screen


def predict_digests(requests: list[dict[str, Any]], reps: int) -> list[dict[str, Any]]:
    """Re-run every captured prediction ``reps`` times: median seconds, digests, rates."""
    from idstlpy.execution.prediction import predict_closed_loop

    rows = []
    for i, req in enumerate(requests):
        times, pred = [], None
        for _ in range(reps):
            t0 = time.perf_counter()
            pred = predict_closed_loop(req["problem"], req["plan"], **req["options"])
            times.append(time.perf_counter() - t0)
        rates, moments, head = rate_digest(pred)
        rows.append(
            {
                "name": req["name"],
                "index": i,
                "n": int(req["plan"].n),
                "steps": int(req["plan"].num_of_steps),
                "closure": pred.closure,
                "seconds": statistics.median(times),
                "rates": rates,
                "moments": moments,
                **head,
            }
        )
    return rows


def solve_timings(names: list[str], reps: int, seed: int = 0) -> list[dict[str, Any]]:
    """Whole default solves: median seconds, prediction seconds, and digests of the answer."""
    rows = []
    for name in names:
        build, kw = PROBLEMS[name]
        runs = []
        for _ in range(reps):
            problem = build()
            t0 = time.perf_counter()
            result = problem.solve_result(seed=seed, time_limit=TIME_LIMIT, **kw)
            wall = time.perf_counter() - t0
            plan = result.plan
            plan_digest = (
                _hash([plan.get_mean(), plan.get_cov(), plan.get_action(), plan.get_control()])
                if plan is not None
                else "-"
            )
            ex = result.execution
            ex_rates = [] if ex is None else [ex.belief_estimate, ex.state_estimate]
            ex_rates += [] if ex is None else [ex.belief_bound, ex.state_bound]
            runs.append(
                {
                    "wall": wall,
                    "prediction": float(result.stats.time_prediction),
                    "predictions": int(result.stats.predictions),
                    "status": result.status,
                    "plan": plan_digest,
                    "execution": _hash(ex_rates),
                }
            )
        rows.append(
            {
                "name": name,
                "seconds": statistics.median(r["wall"] for r in runs),
                "prediction_seconds": statistics.median(r["prediction"] for r in runs),
                "predictions": runs[0]["predictions"],
                "status": runs[0]["status"],
                "plan": runs[0]["plan"],
                "execution": runs[0]["execution"],
                "same_every_run": len({(r["plan"], r["execution"]) for r in runs}) == 1,
            }
        )
    return rows


def screen(requests: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per plan: the particle closure (the planner's) against the cheap Gaussian closure."""
    from idstlpy.execution.prediction import predict_closed_loop

    rows = []
    for i, req in enumerate(requests):
        out: dict[str, Any] = {"name": req["name"], "index": i, "n": int(req["plan"].n)}
        for closure in ("auto", "gaussian"):
            opts = dict(req["options"], closure=closure)
            t0 = time.perf_counter()
            pred = predict_closed_loop(req["problem"], req["plan"], **opts)
            out[closure] = {
                "seconds": time.perf_counter() - t0,
                "closure": pred.closure,
                "state": float(pred.state_success_estimate),
                "belief": float(pred.belief_success_estimate),
            }
        rows.append(out)
    return rows


# --------------------------------------------------------------------------------------------
# report


def report(old: list[dict[str, Any]], new: list[dict[str, Any]], key: str = "seconds") -> str:
    """A markdown table of old / new medians, ratios and digest agreement, row by row."""
    lines = []
    if "rates" in old[0]:
        lines.append(
            "| problem | plan | n | steps | closure | old s | new s | old / new | rates equal "
            "| moments equal |"
        )
        lines.append("|---|---|---|---|---|---|---|---|---|---|")
        for a, b in zip(old, new, strict=True):
            lines.append(
                f"| {a['name']} | {a['index']} | {a['n']} | {a['steps']} | {a['closure']} | {a[key]:.3f} | "
                f"{b[key]:.3f} | {a[key] / b[key]:.2f} | {a['rates'] == b['rates']} | "
                f"{a['moments'] == b['moments']} |"
            )
    else:
        lines.append(
            "| problem | status | old s | new s | old / new | old prediction s | new prediction s | "
            "predictions | plan and execution equal |"
        )
        lines.append("|---|---|---|---|---|---|---|---|---|")
        for a, b in zip(old, new, strict=True):
            same = a["plan"] == b["plan"] and a["execution"] == b["execution"]
            lines.append(
                f"| {a['name']} | {a['status']} / {b['status']} | {a['seconds']:.2f} | {b['seconds']:.2f} | "
                f"{a['seconds'] / b['seconds']:.2f} | {a['prediction_seconds']:.2f} | "
                f"{b['prediction_seconds']:.2f} | {a['predictions']} / {b['predictions']} | {same} |"
            )
    ratios = [a[key] / b[key] for a, b in zip(old, new, strict=True)]
    lines.append("")
    lines.append(f"Median ratio old / new: {statistics.median(ratios):.2f} over {len(ratios)} rows.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    _load()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    cap = sub.add_parser("capture")
    cap.add_argument("--out", required=True)
    cap.add_argument("--problems", default=",".join(PROBLEMS))
    pre = sub.add_parser("predict")
    pre.add_argument("--plans", required=True)
    pre.add_argument("--reps", type=int, default=3)
    pre.add_argument("--json", required=True)
    sol = sub.add_parser("solve")
    sol.add_argument("--problems", default=",".join(PROBLEMS))
    sol.add_argument("--reps", type=int, default=3)
    sol.add_argument("--json", required=True)
    scr = sub.add_parser("screen")
    scr.add_argument("--plans", required=True)
    scr.add_argument("--json", required=True)
    rep = sub.add_parser("report")
    rep.add_argument("--old", required=True)
    rep.add_argument("--new", required=True)
    args = parser.parse_args(argv)
    meta = {"cores": os.cpu_count(), "load": os.getloadavg(), "python_path": os.environ.get("PYTHONPATH", "")}
    if args.cmd == "capture":
        requests = capture(args.problems.split(","))
        with open(args.out, "wb") as fh:
            pickle.dump(requests, fh)
        print(f"{len(requests)} prediction requests -> {args.out}")
        return 0
    if args.cmd in ("predict", "screen"):
        with open(args.plans, "rb") as fh:
            requests = pickle.load(fh)
        rows = predict_digests(requests, args.reps) if args.cmd == "predict" else screen(requests)
    elif args.cmd == "solve":
        rows = solve_timings(args.problems.split(","), args.reps)
    else:
        old, new = (json.loads(Path(p).read_text())["rows"] for p in (args.old, args.new))
        print(report(old, new))
        return 0
    meta["load_after"] = os.getloadavg()
    Path(args.json).write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    for row in rows:
        print(json.dumps(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())
