"""``idstlpy demo light-dark``: the paper's listing end to end.

Solves the light-dark problem with the listing's parameters, tracks the plan with the listing's
LQR weights, runs a Monte Carlo validation, and writes the figures and a JSON summary.
"""

from __future__ import annotations

import argparse
import functools
import itertools
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any, TextIO

import numpy as np

__all__ = ["register", "run_light_dark"]


class _Progress:
    """A one-line progress indicator on stderr (a spinner on a terminal, plain lines otherwise)."""

    def __init__(self, stream: TextIO, enabled: bool = True) -> None:
        self.stream = stream
        self.enabled = enabled
        self.tty = enabled and hasattr(stream, "isatty") and stream.isatty()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._text = ""

    def stage(self, text: str) -> None:
        """Start a stage; a spinner runs while it lasts (terminal only)."""
        self.end()
        if not self.enabled:
            return
        self._text = text
        if not self.tty:
            print(f"... {text}", file=self.stream, flush=True)
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def update(self, text: str) -> None:
        """Change the text of the current stage."""
        self._text = text

    def _spin(self) -> None:
        t0 = time.perf_counter()
        for ch in itertools.cycle("|/-\\"):
            if self._stop.wait(0.1):
                break
            self.stream.write(f"\r{ch} {self._text} ({time.perf_counter() - t0:.0f} s)\x1b[K")
            self.stream.flush()

    def end(self) -> None:
        """Finish the current stage."""
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
            self.stream.write(f"\r  {self._text} done\x1b[K\n")
            self.stream.flush()


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
    """Add ``demo`` (with ``light-dark``) to the ``idstlpy`` command."""
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
    """Handler of ``idstlpy demo light-dark``; returns the exit status (1 when no plan is found)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..execution import validate
    from ..plotting import plot_light_dark, plot_monte_carlo
    from ..scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system

    out_stream = stdout or sys.stdout
    progress = _Progress(stderr or sys.stderr, enabled=not args.quiet)
    out_dir: Path = args.out
    out_dir.mkdir(parents=True, exist_ok=True)

    problem = light_dark(deadline=args.deadline, hold=args.hold)
    progress.stage(f"solving light-dark (deadline {args.deadline}, hold {args.hold}, seed {args.seed})")
    result = problem.solve_result(
        rrt_timeout=args.rrt_timeout,
        delta_near=2,
        delta_drain=0.5,
        goal_bias=0.25,
        min_num_of_steps=3,
        max_num_of_steps=15,
        seed=args.seed,
        time_limit=args.time_limit,
    )
    progress.end()
    stats = result.stats
    rows = [
        ("status", f"{result.status} ({result.reason})"),
        ("solve time", f"{stats.time_total:.2f} s"),
        ("candidates", str(stats.candidates)),
        ("counterexamples", str(stats.counterexamples)),
    ]
    summary: dict[str, Any] = {
        "problem": {"name": "light-dark", "deadline": args.deadline, "hold": args.hold},
        "seed": args.seed,
        "solve": {
            "status": result.status,
            "reason": result.reason,
            "margin": result.margin,
            "stats": stats.as_dict(),
        },
    }
    written: list[Path] = []
    plan = result.trajectory
    if plan is None:
        print("idstlpy demo light-dark: no plan", file=out_stream)
        print(_table(rows), file=out_stream)
        path = out_dir / "summary.json"
        path.write_text(json.dumps(summary, indent=2, default=float))
        print(f"wrote {path}", file=out_stream)
        return 1

    for mode in problem.switched_system.system_modes:
        mode.compute_finite_horizon_lqr(
            horizon=5, Q_final=np.identity(2), Q=np.identity(2), R=0.05 * np.identity(2)
        )
    control_domain = None if args.no_clip else problem.control_domain
    real_system = light_dark_real_system()
    xi_sim, xi_real = problem.switched_system.simulate(
        reference_trajectory=plan,
        num_of_steps=plan.num_of_steps,
        real_initial_state=LIGHT_DARK_REAL_INITIAL_STATE,
        real_system=real_system,
        seed=args.seed,
        control_domain=control_domain,
    )

    progress.stage(f"Monte Carlo: 0/{args.runs} runs")
    report = validate(
        problem,
        plan,
        real_system,
        LIGHT_DARK_REAL_INITIAL_STATE,
        runs=args.runs,
        seed=args.seed,
        clip_controls=not args.no_clip,
        problem_factory=functools.partial(light_dark, args.deadline, args.hold),
        max_workers=args.workers,
        keep_trajectories=min(args.runs, 50),
        progress=lambda done, total: progress.update(f"Monte Carlo: {done}/{total} runs"),
    )
    progress.end()

    progress.stage("drawing figures")
    fig1, ax1 = plt.subplots(figsize=(6.5, 5.5))
    plot_light_dark(problem, plan, xi_sim, xi_real, ax=ax1)
    ax1.set_title(f"light-dark: plan ({plan.num_of_steps} steps) and one execution", fontsize="small")
    path1 = out_dir / "plan_execution.png"
    fig1.savefig(path1, dpi=120, bbox_inches="tight")
    plt.close(fig1)
    fig2, ax2 = plt.subplots(figsize=(6.5, 5.5))
    plot_monte_carlo(problem, plan, report.executions, report=report, ax=ax2)
    path2 = out_dir / "monte_carlo.png"
    fig2.savefig(path2, dpi=120, bbox_inches="tight")
    plt.close(fig2)
    progress.end()
    written += [path1, path2]

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
    summary["plan"] = {"num_of_steps": plan.num_of_steps, "margin": result.margin}
    summary["execution"] = {
        "lqr": {"horizon": 5, "Q_final": "I", "Q": "I", "R": "0.05 I"},
        "clip_controls": not args.no_clip,
        "real_initial_state": LIGHT_DARK_REAL_INITIAL_STATE.tolist(),
    }
    summary["monte_carlo"] = report.as_dict()
    path3 = out_dir / "summary.json"
    path3.write_text(json.dumps(summary, indent=2, default=float))
    written.append(path3)

    print("idstlpy demo light-dark", file=out_stream)
    print(_table(rows), file=out_stream)
    for path in written:
        print(f"wrote {path}", file=out_stream)
    return 0
