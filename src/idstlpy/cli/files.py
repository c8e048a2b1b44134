"""Command-line commands over problem files: ``solve``, ``validate`` and ``sweep``.

::

    idstlpy solve examples/light_dark.toml --set solver.rrt_timeout=5 --plot plan.pdf
    idstlpy validate examples/light_dark.toml --out results/
    idstlpy validate examples/light_dark.toml --plan results/3f2a9c1e0b7d4a65.json
    idstlpy sweep examples/sweep_light_dark.toml --scheduler tcp://host:8786

Each command writes one JSON record per job into ``--out`` (named by the job's id, so an
interrupted sweep resumes; schema in ``docs/results-schema.md``), shows progress on stderr and
prints a summary table. Exit status: see :mod:`idstlpy.cli` (0 ok, 1 no plan, 2 usage or input
error, 3 a job failed).
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import sys
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from ..batch import EXECUTORS, DaskExecutor, Job, load_sweep, result_path, run_jobs, summarize
from ..batch.jobs import DEFAULT_SEED, replay_runs
from ..batch.records import plan_from_record, plan_steps, read_record
from ..errors import InvalidArgumentError, ProblemFileError
from ..problem_file import ProblemSpec, apply_overrides, load_problem
from .exit_codes import exit_status
from .figures import check_figure_path, save_plan_figure, save_runs_figure
from .progress import ProgressBar, Ticker

__all__ = ["register", "parse_set_option", "format_table", "DEFAULT_OUT"]

DEFAULT_OUT = "idstlpy-results"


def register(subparsers: Any) -> None:
    """Add the ``solve``, ``validate`` and ``sweep`` commands to an argparse subparsers object.

    Each parser sets ``func``: a callable taking the parsed namespace and returning the exit
    status.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        What ``ArgumentParser.add_subparsers`` returned.
    """
    solve = subparsers.add_parser(
        "solve",
        help="solve a TOML problem file",
        description="Load a problem file, solve it and write one JSON result record "
        "(and a figure with --plot).",
        epilog="examples: `idstlpy example light-dark --out light_dark.toml` writes the paper's "
        "problem; exit status: 0 plan found, 1 no plan, 2 input error, 3 the job failed",
    )
    solve.add_argument("file", help="TOML problem file (`idstlpy example --list` shows the shipped ones)")
    _common(solve, single=True)
    solve.set_defaults(func=_cmd_solve)

    validate = subparsers.add_parser(
        "validate",
        help="execute a plan on a problem file's real system (Monte Carlo)",
        description="Solve (or, with --plan, check a saved plan against the problem without "
        "solving), then run the plan on the file's [execution] real system ([validation] runs) "
        "and write one JSON result record.",
        epilog="exit status: 0 plan found or accepted and executed at or above the execution "
        "target, 1 no plan or the saved plan is rejected, 2 input error, 3 the job failed, 4 the "
        "measured success rates fall short of the execution target (--target)",
    )
    validate.add_argument("file", help="TOML problem file with [execution] and [validation]")
    validate.add_argument(
        "--plan",
        metavar="RESULT.json",
        default=None,
        help="a saved result (from solve, validate, sweep, demo or SolveResult.save): re-roll its "
        "modes and controls under this problem, check the formula, execute it; no solving",
    )
    validate.add_argument(
        "--predict",
        action="store_true",
        help="also predict the execution (linear-Gaussian closed loop) and report predicted next "
        "to measured violation rates and success (the same as --set validation.predict=true)",
    )
    validate.add_argument(
        "--replan",
        choices=("none", "on_risk", "every"),
        default=None,
        help="execute every run with re-planning (stl.execute): re-solve when the predicted success "
        "drops below [validation.replan_options] risk, or every `every` steps (the same as --set "
        'validation.replan="..."; docs/problem-files.md also has the start check)',
    )
    validate.add_argument(
        "--target",
        type=_target,
        metavar="BELIEF,STATE",
        default=None,
        help="the execution target the verdict is against: least success rates of the executed "
        "belief and of the true state, e.g. 0.9,0.95 (the default; the same as --set "
        "validation.execution_target=[0.9,0.95]); below it the exit status is 4",
    )
    _common(validate, single=True)
    validate.set_defaults(func=_cmd_validate)

    sweep = subparsers.add_parser(
        "sweep",
        help="run a parameter sweep (TOML sweep file)",
        description="Run every job of a sweep file; finished result files of the same jobs are "
        "reused (resume).",
        epilog="exit status: 0 every plan found, 1 some job has no plan, 2 input error, 3 some job failed",
    )
    sweep.add_argument("file", metavar="SWEEP.toml", help="TOML sweep file (docs/sweeps.md)")
    _common(sweep, single=False)
    sweep.set_defaults(func=_cmd_sweep)


def _common(parser: argparse.ArgumentParser, single: bool) -> None:
    parser.add_argument(
        "--out",
        default=DEFAULT_OUT,
        metavar="DIR",
        help=f"directory of the JSON result files (default: {DEFAULT_OUT})",
    )
    parser.add_argument(
        "--executor",
        choices=EXECUTORS,
        default=None,
        help="where jobs run (default: dask with --scheduler, else inprocess for one job and "
        "processes for several)",
    )
    parser.add_argument(
        "--scheduler",
        metavar="ADDR",
        default=None,
        help="Dask scheduler address, e.g. tcp://host:8786 (implies --executor dask)",
    )
    parser.add_argument(
        "--workers",
        type=_positive_int,
        metavar="N",
        default=None,
        help="worker processes or local Dask workers (default: number of CPUs)",
    )
    parser.add_argument(
        "--seed",
        type=_seed,
        default=None,
        help="seed (solve/validate: the solver's seed, default the file's [solver] seed, else "
        f"{DEFAULT_SEED}; sweep: root of the job seeds, default the sweep file's)",
    )
    parser.add_argument(
        "--no-resume",
        dest="resume",
        action="store_false",
        help="run jobs again even when their result file exists",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    if single:
        parser.add_argument(
            "--set",
            dest="overrides",
            action="append",
            default=[],
            metavar="KEY=VALUE",
            help="override a value, e.g. solver.rrt_timeout=5 (TOML value syntax)",
        )
        parser.add_argument(
            "--plot",
            metavar="FIGURE",
            default=None,
            help="also draw the plan into FIGURE (.png, .pdf or .svg: the extension gives the format)",
        )
        parser.add_argument(
            "--objective",
            choices=("effort", "time", "margin"),
            default=None,
            help="optimise the plan: least input effort, fewest steps or largest robustness margin "
            "(the same as --set solver.objective=...)",
        )
        parser.add_argument(
            "--guarantee",
            choices=("execution", "mlo", "closed_loop"),
            default=None,
            help="what a plan promises: the paper's semantics and a predicted execution that meets the "
            "execution target (execution, default), the paper's semantics only (mlo), or chance "
            "constraints on the predicted true state (closed_loop); the same as --set solver.guarantee=...",
        )


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _target(text: str) -> list[float]:
    parts = text.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected BELIEF,STATE (two rates), got {text!r}") from None
    if len(values) != 2 or not all(0.0 <= v <= 1.0 for v in values):
        raise argparse.ArgumentTypeError(f"expected BELIEF,STATE, two rates in [0, 1], got {text!r}")
    return values


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text}")
    return value


def parse_set_option(items: Sequence[str]) -> dict[str, Any]:
    """``["solver.rrt_timeout=5", "name=x"]`` to overrides (values in TOML syntax, else strings).

    Parameters
    ----------
    items : sequence of str
        ``KEY=VALUE`` texts.

    Returns
    -------
    dict
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ProblemFileError(f"--set {item!r}: expected KEY=VALUE")
        try:
            value = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw.strip()
        out[key] = value
    return out


def _short(value: Any, width: int) -> str:
    text = str(value)
    return text if len(text) <= width else text[: width - 3] + "..."


def format_table(records: Sequence[Mapping[str, Any]]) -> str:
    """A plain-text summary table of result records (one row per job).

    Parameters
    ----------
    records : sequence of dict

    Returns
    -------
    str
    """
    header = [
        "id",
        "status",
        "steps",
        "margin",
        "time [s]",
        "predicted b/s",
        "belief/state ok",
        "overrides / reason",
    ]
    rows = [header]
    for r in records:
        timing = r.get("timing") or {}
        solver_time = (timing.get("solver") or {}).get("time_total")
        margin = r.get("margin")
        validation = r.get("validation")
        vtext = "-"
        if isinstance(validation, Mapping):
            rates = [validation.get(k) for k in ("belief_success_rate", "state_success_rate")]
            if all(isinstance(v, int | float) for v in rates):
                vtext = f"{rates[0]:.2f}/{rates[1]:.2f}"
            else:
                vtext = "done"
        ex = r.get("execution")
        ptext = "-"
        if isinstance(ex, Mapping):
            rates = [ex.get(k) for k in ("belief_estimate", "state_estimate")]
            if all(isinstance(v, int | float) for v in rates):
                ptext = f"{rates[0]:.2f}/{rates[1]:.2f}" + ("" if ex.get("meets_target") else " BELOW")
        problem = r.get("problem") or {}
        overrides = problem.get("overrides") or {}
        note = ", ".join(f"{k}={v}" for k, v in overrides.items())
        if r.get("status") == "error":
            err = r.get("error") or {}
            note = f"{err.get('type')}: {err.get('message')}".splitlines()[0]
        elif not note or r.get("status") == "rejected":
            note = r.get("reason") or ""
        steps = plan_steps(r.get("plan"))
        rows.append(
            [
                str(r.get("id", ""))[:8],
                str(r.get("status")),
                "-" if steps is None else str(steps),
                f"{margin:.3g}" if isinstance(margin, int | float) else "-",
                f"{solver_time:.2f}" if isinstance(solver_time, int | float) else "-",
                ptext,
                vtext,
                _short(note, 60),
            ]
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    counts = summarize(records)
    lines.append("")
    lines.append("total: " + ", ".join(f"{n} {status}" for status, n in sorted(counts.items())))
    return "\n".join(lines)


def _executor(args: argparse.Namespace) -> str | None:
    """``--scheduler`` implies the dask executor; with another ``--executor`` it is an error."""
    if args.scheduler:
        if args.executor not in (None, "dask"):
            raise InvalidArgumentError(f"--scheduler needs the dask executor, got --executor {args.executor}")
        return "dask"
    return args.executor  # type: ignore[no-any-return]


def _announce_executor(ex: cf.Executor) -> None:
    if isinstance(ex, DaskExecutor):
        link = ex.dashboard_link
        if link:
            note = " (install bokeh to see it)" if ex.dashboard_needs_bokeh else ""
            print(f"dask dashboard: {link}{note}", file=sys.stderr, flush=True)
        else:
            print("dask dashboard: none (the scheduler runs no dashboard)", file=sys.stderr, flush=True)


def _run(args: argparse.Namespace, jobs: list[Job], label: str | None = None) -> list[dict[str, Any]]:
    executor = _executor(args)
    bar = ProgressBar(sys.stderr, not args.quiet and label is None)
    ticker = Ticker(
        sys.stderr, enabled=not args.quiet and label is not None, listen=not getattr(args, "verbose", 0)
    )
    if label is not None:
        ticker.start(label)
    try:
        records = run_jobs(
            jobs,
            args.out,
            executor,
            workers=args.workers,
            scheduler=args.scheduler,
            resume=args.resume,
            progress=bar,
            on_executor=_announce_executor,
        )
    finally:
        ticker.stop()
    if label is not None and records and (records[0].get("timing") or {}).get("cached"):
        print(f"(reused {result_path(args.out, jobs[0])}; --no-resume runs it again)", file=sys.stderr)
    print(format_table(records))
    if label is not None:
        print(f"result: {result_path(args.out, jobs[0])}")
    else:
        print(f"results: {args.out}/")
    return records


def _seed_warning(args: argparse.Namespace, spec: ProblemSpec) -> None:
    if args.seed is None and spec.seed is None:
        print(
            f"idstlpy {args.command}: warning: {spec.name} sets no [solver] seed; using the default "
            f"seed {DEFAULT_SEED} (set solver.seed in the file, or pass --seed)",
            file=sys.stderr,
        )


def _single(args: argparse.Namespace, kind: str) -> int:
    figure = check_figure_path(args.plot) if args.plot else None
    sets = list(args.overrides)
    if getattr(args, "objective", None):
        sets.append(f'solver.objective="{args.objective}"')
    if getattr(args, "guarantee", None):
        sets.append(f'solver.guarantee="{args.guarantee}"')
    overrides = parse_set_option(sets)
    if getattr(args, "predict", False):
        overrides["validation.predict"] = True
    if getattr(args, "replan", None):
        overrides["validation.replan"] = args.replan
    if getattr(args, "target", None) is not None:
        overrides["validation.execution_target"] = args.target
    spec = apply_overrides(load_problem(args.file), overrides)
    saved = None
    plan_path = getattr(args, "plan", None)
    if plan_path is not None:
        saved = read_record(plan_path)
        if plan_from_record(saved, plan_path) is None:
            raise InvalidArgumentError(
                f"{plan_path}: the result has no plan (status {saved.get('status')!r})"
            )
    else:
        _seed_warning(args, spec)
    _executor(args)  # check --scheduler / --executor before any work
    job = Job(kind, spec.source, spec.name, overrides, args.seed, saved)
    if saved is not None:
        label = f"checking and executing the saved plan of {plan_path} on {spec.name}"
    else:
        seed = args.seed if args.seed is not None else spec.seed if spec.seed is not None else DEFAULT_SEED
        verb = "solving" if kind == "solve" else "solving and validating"
        label = f"{verb} {spec.name} (seed {seed})"
    records = _run(args, [job], label)
    record = records[0]
    _print_execution(record)
    _print_verdict(record)
    if figure is not None:
        if kind == "validate" and isinstance(record.get("validation"), Mapping):
            _runs_figure(spec, record, figure)
        else:
            _figure(spec, record, figure)
    return exit_status(records)


def _print_execution(record: Mapping[str, Any]) -> None:
    """The found plan's predicted execution against the execution target (every solve)."""
    ex = record.get("execution")
    if not isinstance(ex, Mapping):
        return

    def pct(v: Any) -> str:
        return "n/a" if v is None else f"{100 * float(v):.1f}%"

    target = ex.get("target") or {}
    verdict = "meets" if ex.get("meets_target") else "BELOW"
    print(
        f"predicted execution: belief {pct(ex.get('belief_estimate'))} (>= {pct(ex.get('belief_bound'))}), "
        f"true state {pct(ex.get('state_estimate'))} (>= {pct(ex.get('state_bound'))}); {verdict} the "
        f"target {pct(target.get('belief'))} / {pct(target.get('state'))}"
    )


def _print_verdict(record: Mapping[str, Any]) -> None:
    """The validation's true start and verdict against its execution target (validate only)."""
    validation = record.get("validation")
    if not isinstance(validation, Mapping) or "verdict" not in validation:
        return
    start = validation.get("true_start")
    if start == "prior":
        print("true start: drawn from the prior (every run its own)")
    elif isinstance(start, list):
        print("true start: fixed at [" + ", ".join(f"{v:.4g}" for v in start) + "]")
    print(f"verdict: {validation['verdict']}")
    _print_prediction(validation.get("prediction"))


def _print_prediction(cmp: Any) -> None:
    """``--predict``: the predicted rates beside the measured ones (``!``: outside the measured
    Wilson 95% interval), success first, then per proposition."""
    if not isinstance(cmp, Mapping) or not isinstance(cmp.get("success"), Mapping):
        return

    def pct(v: Any) -> str:
        return "n/a" if not isinstance(v, int | float) else f"{100 * float(v):.1f}%"

    def cell(entry: Any) -> str:
        if not isinstance(entry, Mapping):
            return "n/a"
        lo, hi = (entry.get("ci") or [None, None])[:2]
        flag = " !" if entry.get("outside") else ""
        return f"{pct(entry.get('predicted'))}{flag} vs {pct(entry.get('measured'))} [{pct(lo)}, {pct(hi)}]"

    success = cmp["success"]
    print("prediction vs measured (predicted ! outside the measured 95% interval):")
    print(f"  success: belief {cell(success.get('belief'))}; true state {cell(success.get('state'))}")
    props = cmp.get("propositions") or {}
    if props:
        width = max(len(str(name)) for name in props)
        for name, entry in props.items():
            print(
                f"  {str(name).ljust(width)} violated: belief {cell(entry.get('belief'))}; "
                f"true state {cell(entry.get('state'))}"
            )
    worst = cmp.get("max_abs_diff")
    print(
        f"  {cmp.get('outside')} of {cmp.get('compared')} predicted rates outside the measured interval; "
        f"worst per-predicate |predicted - measured| {'n/a' if worst is None else f'{float(worst):.3f}'}"
    )


def _figure(spec: ProblemSpec, record: Mapping[str, Any], figure: Path) -> None:
    problem = spec.build().problem
    plan = plan_from_record(record, str(figure)) if record.get("status") != "error" else None
    steps = plan_steps(record.get("plan"))
    title = f"{spec.title}: {record.get('status')}"
    if steps is not None:
        margin = record.get("margin")
        title += f", {steps} steps" + (f", margin {margin:.3g}" if isinstance(margin, float) else "")
    save_plan_figure(problem, plan, figure, title)
    print(f"figure: {figure}")


RUNS_DRAWN = 50
"""``validate --plot`` draws the first this-many runs (made again with the same seeds)."""


def _runs_figure(spec: ProblemSpec, record: Mapping[str, Any], figure: Path) -> None:
    """``validate --plot``: the plan with the runs the validation made (the first
    :data:`RUNS_DRAWN`), titled with the whole validation's rates."""
    problem, plan, report = replay_runs(spec, record, RUNS_DRAWN)
    v = record["validation"]

    def pct(key: str) -> str:
        value = v.get(key)
        return "n/a" if not isinstance(value, int | float) else f"{100 * float(value):.1f}%"

    title = (
        f"{spec.title}: {v.get('runs')} runs, belief {pct('belief_success_rate')}, state "
        f"{pct('state_success_rate')} (drawn: the first {report.runs})"
    )
    save_runs_figure(problem, plan, report.executions, figure, title)
    print(f"figure: {figure} ({report.runs} of the runs drawn)")


def _cmd_solve(args: argparse.Namespace) -> int:
    return _single(args, "solve")


def _cmd_validate(args: argparse.Namespace) -> int:
    return _single(args, "validate")


def _cmd_sweep(args: argparse.Namespace) -> int:
    sweep = load_sweep(args.file)
    jobs = sweep.jobs(seed=args.seed)
    _executor(args)
    if not args.quiet:
        print(f"sweep {sweep.name}: {len(jobs)} job(s) of {sweep.problem_name}", file=sys.stderr)
    return exit_status(_run(args, jobs))
