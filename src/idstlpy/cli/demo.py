"""``idstlpy demo light-dark``: the paper's listing end to end.

Solves the light-dark problem (the shipped ``light_dark.toml``) with the listing's parameters,
tracks the plan with the listing's LQR weights, runs a Monte Carlo validation, and writes the
figures and the result file ``result.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from .exit_codes import EXIT_NO_PLAN, EXIT_OK
from .progress import Ticker

__all__ = ["register", "run_light_dark"]


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0 or not np.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return value


def register(subparsers: Any) -> None:
    """Add ``demo`` (with ``light-dark``) to the ``idstlpy`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        What ``ArgumentParser.add_subparsers`` returned.
    """
    demo = subparsers.add_parser("demo", help="run a worked example end to end", description=__doc__)
    kinds = demo.add_subparsers(dest="demo", metavar="DEMO", required=True)
    ld = kinds.add_parser(
        "light-dark",
        help="the paper's light-dark listing: solve, track, Monte Carlo, figures",
        description=(
            "Solve the paper's light-dark problem (free_space U[0,deadline] G[0,hold] target), "
            "execute the plan with Kalman filtering and LQR tracking, validate it by Monte Carlo "
            "and write figures and a JSON summary."
        ),
    )
    ld.add_argument(
        "--out", type=Path, default=Path("idstlpy-demo"), help="output folder (default: %(default)s)"
    )
    ld.add_argument("--seed", type=int, default=0, help="seed of the solver and the executions (default: 0)")
    ld.add_argument("--runs", type=_positive_int, default=100, help="Monte Carlo runs (default: 100)")
    ld.add_argument(
        "--rrt-timeout",
        type=_positive_float,
        default=60.0,
        help="sampler budget per candidate, s (default: 60)",
    )
    ld.add_argument("--time-limit", type=_positive_float, default=None, help="overall solver budget, s")
    ld.add_argument("--deadline", type=_positive_int, default=240, help="until deadline (default: 240)")
    ld.add_argument("--hold", type=_positive_int, default=40, help="steps to hold the target (default: 40)")
    ld.add_argument("--workers", type=_positive_int, default=2, help="Monte Carlo processes (default: 2)")
    ld.add_argument("--no-clip", action="store_true", help="do not project corrected inputs on |u_i| <= 1")
    ld.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    ld.set_defaults(func=run_light_dark)


def _table(rows: list[tuple[str, str]]) -> str:
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k.ljust(width)}  {v}" for k, v in rows)


def run_light_dark(
    args: argparse.Namespace, stdout: TextIO | None = None, stderr: TextIO | None = None
) -> int:
    """Handler of ``idstlpy demo light-dark``; returns the exit status (1 when no plan is found).

    The problem is the shipped example ``light_dark.toml`` (the paper's listing, checked against
    it by the tests) with the command's options as overrides; the result file ``result.json``
    has the schema of every result file (``docs/results-schema.md``).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options of ``idstlpy demo light-dark``.
    stdout, stderr : file, optional
        Where the summary and the progress go (default: the process's).

    Returns
    -------
    int
        0 with a plan, 1 without.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..batch.jobs import Job, new_record
    from ..batch.records import jsonable, problem_section, result_to_dict, write_record
    from ..execution import validate
    from ..plotting import plot_light_dark, plot_monte_carlo
    from ..problem_file import apply_overrides, load_problem
    from ..synthesis import solve
    from .example import example_text

    out_stream = stdout or sys.stdout
    progress = Ticker(stderr or sys.stderr, enabled=not args.quiet, listen=not getattr(args, "verbose", 0))
    out_dir: Path = args.out
    out_dir.mkdir(parents=True, exist_ok=True)

    overrides: dict[str, Any] = {
        "solver.rrt_timeout": args.rrt_timeout,
        "solver.seed": args.seed,
        "validation.runs": args.runs,
        "validation.seed": args.seed,
    }
    if args.time_limit is not None:
        overrides["solver.time_limit"] = args.time_limit
    if (args.deadline, args.hold) != (240, 40):
        overrides["formula"] = f"(free_space U[0,{args.deadline}] G[0,{args.hold}] target)"
    spec = apply_overrides(load_problem(example_text("light-dark"), name="light_dark.toml"), overrides)
    problem, solver_kwargs, execution = spec.build()
    job = Job("validate", spec.source, spec.name, overrides, args.seed)
    record = new_record(job)
    record.update(
        kind="demo",
        problem=problem_section(spec),
        formula=str(problem.stl_formula),
        seed=args.seed,
        seed_source="job",
        solver_options=jsonable(solver_kwargs),
        plan_source="solved",
    )

    # the listing's tracking gains on every mode before the solve: the plan is made for the loop
    # the demo then runs (the file's [execution.lqr], the paper's weights)
    lqr = execution.lqr or {}
    for mode in problem.switched_system.system_modes:
        mode.compute_finite_horizon_lqr(
            horizon=lqr.get("horizon", 5),
            Q_final=lqr.get("Q_final", np.identity(2)),
            Q=lqr.get("Q", np.identity(2)),
            R=lqr.get("R", 0.05 * np.identity(2)),
        )
    t0 = time.perf_counter()
    progress.start(f"solving light-dark (deadline {args.deadline}, hold {args.hold}, seed {args.seed})")
    result = solve(problem, **solver_kwargs)
    progress.stop(f"solved: {result.status}")
    record.update(result_to_dict(result))
    stats = result.stats
    record["timing"]["solver"] = {k: v for k, v in stats.as_dict().items() if k.startswith("time")}
    rows = [
        ("status", f"{result.status} ({result.reason})"),
        ("solve time", f"{stats.time_total:.2f} s"),
        ("candidates", str(stats.candidates)),
        ("counterexamples", str(stats.counterexamples)),
    ]
    if stats.execution_room is not None:
        rows.append(("execution room kept", f"{stats.execution_room:.2f} (>= 1: all the loop needs)"))
    path_json = out_dir / "result.json"
    plan = result.trajectory
    if plan is None:
        record["timing"]["wall_time"] = time.perf_counter() - t0
        write_record(path_json, record)
        print("idstlpy demo light-dark: no plan", file=out_stream)
        print(_table(rows), file=out_stream)
        print(f"wrote {path_json}", file=out_stream)
        return EXIT_NO_PLAN

    control_domain = None if args.no_clip else problem.control_domain
    xi_sim, xi_real = problem.switched_system.simulate(
        reference_trajectory=plan,
        num_of_steps=plan.num_of_steps,
        real_initial_state=execution.real_initial_state,
        real_system=execution.real_system,
        seed=args.seed,
        control_domain=control_domain,
    )

    progress.start(f"Monte Carlo: 0/{args.runs} runs")
    report = validate(
        problem,
        plan,
        execution.real_system,
        execution.real_initial_state,
        runs=execution.runs,
        seed=args.seed,
        clip_controls=not args.no_clip,
        max_workers=args.workers,
        keep_trajectories=min(args.runs, 50),
        progress=lambda done, total: progress.update(f"Monte Carlo: {done}/{total} runs"),
        predict=True,
    )
    progress.stop(f"Monte Carlo: {report.runs} runs")

    progress.start("drawing figures")
    fig1, ax1 = plt.subplots(figsize=(6.5, 5.5))
    plot_light_dark(problem, plan, xi_sim, xi_real, ax=ax1, predicted=report.predicted)
    ax1.set_title(f"light-dark: plan ({plan.num_of_steps} steps) and one execution", fontsize="small")
    path1 = out_dir / "plan_execution.png"
    fig1.savefig(path1, dpi=120, bbox_inches="tight")
    plt.close(fig1)
    fig2, ax2 = plt.subplots(figsize=(6.5, 5.5))
    plot_monte_carlo(problem, plan, report.executions, report=report, ax=ax2)
    path2 = out_dir / "monte_carlo.png"
    fig2.savefig(path2, dpi=120, bbox_inches="tight")
    plt.close(fig2)
    progress.stop("figures drawn")

    rows += [
        ("plan length", f"{plan.num_of_steps} steps (margin {result.margin:.4f})"),
        (
            "belief success",
            f"{100 * report.belief_success_rate:.1f}% of {report.runs} runs "
            f"(95% CI {100 * report.belief_ci[0]:.1f}-{100 * report.belief_ci[1]:.1f}%)",
        ),
        (
            "state success",
            f"{100 * report.state_success_rate:.1f}% of {report.runs} runs "
            f"(95% CI {100 * report.state_ci[0]:.1f}-{100 * report.state_ci[1]:.1f}%)",
        ),
        ("monte carlo time", f"{report.elapsed:.2f} s"),
    ]
    comparison = report.prediction_comparison()
    if comparison is not None:
        rows += [
            (
                f"predicted {reading} success",
                f"{100 * entry['predicted']:.1f}% (lower bound {100 * entry['bound']:.1f}%)"
                if entry["predicted"] is not None and entry["bound"] is not None
                else "n/a",
            )
            for reading, entry in comparison["success"].items()
        ]
        worst = comparison["max_abs_diff"]
        rows.append(
            (
                "predicted vs measured",
                f"{comparison['outside']} of {comparison['compared']} predicted rates outside the "
                f"95% CI; worst per-constraint difference {'n/a' if worst is None else f'{worst:.3f}'}",
            )
        )
    validation = report.as_dict()
    record["timing"]["validation"] = validation.pop("elapsed", None)
    validation["seed"] = args.seed
    validation["clip_controls"] = not args.no_clip
    record["validation"] = validation
    record["timing"]["wall_time"] = time.perf_counter() - t0
    write_record(path_json, record)

    print("idstlpy demo light-dark", file=out_stream)
    print(_table(rows), file=out_stream)
    for path in (path1, path2, path_json):
        print(f"wrote {path}", file=out_stream)
    return EXIT_OK
