"""Issue 15, goal 2: plans made with ``guarantee="closed_loop"`` keep each chance constraint on the
true state under execution, at most 3x the MLO solve time.

For every problem (the paper's light-dark listing and the active-perception suite's instances)
and seed: solve with ``guarantee="mlo"`` and ``"closed_loop"`` (alternating, in one process),
then execute the closed-loop plan ``--runs`` times with :func:`idstlpy.simulate` (LQR tracking,
Kalman filter, inputs clipped to the control domain), the true start drawn from the prior (the
distribution the promise is about). A chance constraint ``P[h'x + c <= 0] >= 1 - eps`` is
*promised* at step ``k`` when the plan's predicted true state meets it; its measured violation
rate there must be at most ``eps``. Reported per problem: solve times and their ratio, the worst
promised constraint's violation rate against its ``eps``, and how many promised (constraint,
step) pairs exceed ``eps`` beyond the 95% Wilson interval (a real failure, not sampling noise).
The MLO plan is executed the same way for comparison (its own promise is about the belief).

    python -m benchmarks.closed_loop_guarantee --seeds 3 --runs 500 --size full \
        --out benchmarks/closed_loop_guarantee_results.md
"""

from __future__ import annotations

import argparse
import platform
import statistics
import subprocess
import time
from typing import Any

import numpy as np

import idstlpy as stl
from idstlpy import scenarios
from idstlpy.chance import quantile
from idstlpy.closed_loop import predicted_state, trackable
from idstlpy.execution.validation import wilson_interval
from idstlpy.synthesis import cegis  # noqa: F401  (imported by the first solve otherwise: not its time)

from . import perception_problems as pp

SUITE_KINDS = (
    "noisy_hold",
    "noisy_hold_narrow",
    "double_integrator",
    "detour",
    "sequence",
    "light_dark_3d",
    "long_horizon",
    "scaled_workspace",
    "weaker_formula",
    "sensor_switching",
    "patrol",
)


def _problems(size: str, kinds: list[str]) -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    for kind in kinds:
        if kind == "listing":
            out.append(("listing", lambda: scenarios.light_dark()))
        else:
            out.append((kind, lambda kind=kind: pp.build(kind, size)[0]))
    return out


def _faces(problem: Any) -> list[tuple[np.ndarray, float, float]]:
    faces = []
    for ap in problem.stl_formula.atomic_propositions():
        for pred in getattr(ap, "predicates", ()):
            faces.append((np.asarray(pred.h, dtype=float).reshape(-1), float(pred.c), float(pred.eps)))
    return faces


def _execute(problem: Any, plan: Any, runs: int, seed: int) -> dict[str, Any]:
    """Per promised (face, step): violation counts of the true state over ``runs`` executions."""
    system, domain = problem.switched_system, problem.control_domain
    faces = _faces(problem)
    # the prediction the planner judged the plan on (teacher.closed_loop_check): the clip's
    # linearisation for a trackable plan, the particle closure for one that rides the faces
    tracks = domain is None or trackable(system, plan, domain)
    pred = predicted_state(system, plan, domain, closure="gaussian" if tracks else "particles")
    L = plan.num_of_steps + 1
    H = np.array([h for h, _, _ in faces])
    c = np.array([cc for _, cc, _ in faces])
    eps = np.array([e for _, _, e in faces])
    mu = pred.get_mean() @ H.T + c  # (L, F)
    sd = np.sqrt(np.maximum(np.einsum("fi,kij,fj->kf", H, pred.get_cov(), H), 0.0))
    promised = mu + quantile(eps)[None, :] * sd <= 0
    violations = np.zeros((L, len(faces)))
    rng = np.random.default_rng(seed)
    init = problem.initial_state
    for _ in range(runs):
        x0 = rng.multivariate_normal(init.mean, init.cov)
        _, real = stl.simulate(system, plan, plan.num_of_steps, x0, system, seed=rng, control_domain=domain)
        violations += real.get_state() @ H.T + c > 0
    rate = violations / runs
    worst, worst_eps, failures = 0.0, 0.0, 0
    for k, f in zip(*np.nonzero(promised), strict=True):
        if rate[k, f] - eps[f] > worst - worst_eps:
            worst, worst_eps = float(rate[k, f]), float(eps[f])
        lo, _ = wilson_interval(int(violations[k, f]), runs)
        failures += int(lo > eps[f])
    return {"worst": worst, "worst_eps": worst_eps, "failures": failures, "promised": int(promised.sum())}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--runs", type=int, default=500)
    ap.add_argument("--size", choices=pp.SIZES, default="full")
    ap.add_argument("--kinds", default="listing," + ",".join(SUITE_KINDS))
    ap.add_argument("--time-limit", type=float, default=120.0)
    ap.add_argument(
        "--repeats", type=int, default=1, help="solves per guarantee, alternating; times are their medians"
    )
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout
    lines = [
        "# guarantee='closed_loop' under execution (issue 15, goal 2)",
        "",
        f"- command: `python -m benchmarks.closed_loop_guarantee --seeds {args.seeds} --runs {args.runs} "
        f"--size {args.size} --time-limit {args.time_limit:g} --repeats {args.repeats} --kinds {args.kinds}`",
        f"- commit {commit.strip() or 'unknown (not run from a git checkout)'}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
        f"{platform.machine()} nproc {__import__('os').cpu_count()}; cap {args.time_limit:g} s per solve",
        "- executions: true start drawn from the prior, LQR tracking, Kalman filter, inputs clipped",
        "- CL trackable: the closed-loop plan's inputs leave 1 sd of the tracking correction free on "
        "every control face (`idstlpy.closed_loop.trackable`), where the linearised clipping is accurate",
        "- times: wall clock (perf_counter) and CPU time of the solving process (process_time: "
        "less sensitive to other jobs sharing the cores; the solver's modules are imported before "
        "the first solve); with --repeats R, the medians of R alternating solves (the first "
        "solve's plan is executed)",
        "- worst: the promised (constraint, step) pair furthest above its eps (rate / eps); failures: "
        "promised pairs whose 95% Wilson interval lies above eps",
        "",
        "| problem | seed | MLO | closed_loop | time ratio | MLO CPU | CL CPU | CPU ratio | CL trackable | "
        "CL worst violation / eps | CL failures (of promised) | MLO plan worst / eps | MLO failures |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    ratios: list[float] = []
    cpu_ratios: list[float] = []
    for name, make in _problems(args.size, args.kinds.split(",")):
        for seed in range(args.seeds):
            row: dict[str, Any] = {}
            walls: dict[str, list[float]] = {"mlo": [], "closed_loop": []}
            cpus: dict[str, list[float]] = {"mlo": [], "closed_loop": []}
            for _ in range(args.repeats):  # alternating, so that both see the same load
                for g in ("mlo", "closed_loop"):
                    problem = make()
                    t0, c0 = time.perf_counter(), time.process_time()
                    res = problem.solve_result(seed=seed, guarantee=g, time_limit=args.time_limit)
                    walls[g].append(time.perf_counter() - t0)
                    cpus[g].append(time.process_time() - c0)
                    row.setdefault(g, (res, problem))
            (rm, pm), (rc, pc) = row["mlo"], row["closed_loop"]
            tm, tc = statistics.median(walls["mlo"]), statistics.median(walls["closed_loop"])
            cm, cc = statistics.median(cpus["mlo"]), statistics.median(cpus["closed_loop"])
            both = rm.found and rc.found
            ratio = tc / tm if both else float("nan")
            cpu_ratio = cc / cm if both and cm > 0 else float("nan")
            if np.isfinite(ratio):
                ratios.append(ratio)
            if np.isfinite(cpu_ratio):
                cpu_ratios.append(cpu_ratio)
            cl = _execute(pc, rc.trajectory, args.runs, 1000 + seed) if rc.found else None
            ml = _execute(pm, rm.trajectory, args.runs, 1000 + seed) if rm.found else None

            def cell(e: dict[str, Any] | None, what: str) -> str:
                if e is None:
                    return "-"
                if what == "worst":
                    return f"{e['worst']:.3f} / {e['worst_eps']:.2f}"
                return f"{e['failures']} ({e['promised']})"

            tracks = "-"
            if rc.found:
                tracks = str(trackable(pc.switched_system, rc.trajectory, pc.control_domain))
            lines.append(
                f"| {name} | {seed} | {rm.status} {tm:.2f} s | {rc.status} {tc:.2f} s | "
                f"{ratio:.2f} | {cm:.2f} s | {cc:.2f} s | {cpu_ratio:.2f} | {tracks} | "
                f"{cell(cl, 'worst')} | {cell(cl, 'failures')} | "
                f"{cell(ml, 'worst')} | {cell(ml, 'failures')} |"
            )
            print(lines[-1], flush=True)
    if ratios:
        lines += [
            "",
            f"Median time ratio closed_loop / MLO over solved pairs: {statistics.median(ratios):.2f} "
            f"(max {max(ratios):.2f}, {len(ratios)} pairs); of CPU times: "
            f"{statistics.median(cpu_ratios):.2f} (max {max(cpu_ratios):.2f}).",
        ]
    text = "\n".join(lines) + "\n"
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text)
    print(text)


if __name__ == "__main__":
    main()
