"""Command-line commands over problem files: ``solve``, ``validate`` and ``sweep``.

::

    idstlpy solve examples/light_dark.toml --set solver.rrt_timeout=5
    idstlpy validate examples/light_dark.toml --out results/
    idstlpy sweep examples/sweep_light_dark.toml --executor dask --scheduler tcp://host:8786

Each command writes one JSON record per job into ``--out`` (named by the job's hash, so an
interrupted sweep resumes), shows a progress line on stderr and prints a summary table.
Exit status: 0 when every job ran (whatever the solver's verdict), 1 when a job failed,
2 when a problem or sweep file is invalid.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from collections.abc import Mapping, Sequence
from typing import Any, TextIO

from ..batch import EXECUTORS, Job, load_sweep, run_jobs, summarize
from ..errors import IdstlpyError, ProblemFileError
from ..problem_file import apply_overrides, load_problem

__all__ = ["register", "parse_set_option", "format_table"]

DEFAULT_OUT = "idstlpy-results"


def register(subparsers: Any) -> None:
    """Add the ``solve``, ``validate`` and ``sweep`` commands to an argparse subparsers object.

    Each parser sets ``func``: a callable taking the parsed namespace and returning the exit
    status.
    """
    solve = subparsers.add_parser(
        "solve", help="solve a TOML problem file",
        description="Load a problem file, solve it and write one JSON result record.",
    )
    solve.add_argument("file", help="TOML problem file (see examples/light_dark.toml)")
    _common(solve, single=True)
    solve.set_defaults(func=_cmd_solve)

    validate = subparsers.add_parser(
        "validate", help="solve a problem file and execute the plan on its real system",
        description="Solve, then run the plan on the file's [execution] real system "
        "([validation] runs) and write one JSON result record.",
    )
    validate.add_argument("file", help="TOML problem file with [execution] and [validation]")
    _common(validate, single=True)
    validate.set_defaults(func=_cmd_validate)

    sweep = subparsers.add_parser(
        "sweep", help="run a parameter sweep (TOML sweep file)",
        description="Run every job of a sweep file; existing result files are reused.",
    )
    sweep.add_argument("file", metavar="SWEEP.toml", help="TOML sweep file")
    _common(sweep, single=False)
    sweep.set_defaults(func=_cmd_sweep)


def _common(parser: argparse.ArgumentParser, single: bool) -> None:
    parser.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                        help=f"directory of the JSON result files (default: {DEFAULT_OUT})")
    parser.add_argument("--executor", choices=EXECUTORS, default=None,
                        help="where jobs run (default: inprocess for one job, processes for a sweep)")
    parser.add_argument("--scheduler", metavar="ADDR", default=None,
                        help="Dask scheduler address (with --executor dask; default: a local cluster)")
    parser.add_argument("--workers", type=_positive_int, metavar="N", default=None,
                        help="worker processes (default: number of CPUs)")
    parser.add_argument("--seed", type=_seed, default=None,
                        help="seed (solve/validate: the solver's seed, default the file's; "
                        "sweep: root of the job seeds, default the sweep file's)")
    parser.add_argument("--no-resume", dest="resume", action="store_false",
                        help="run jobs again even when their result file exists")
    parser.add_argument("--quiet", action="store_true", help="no progress line on stderr")
    if single:
        parser.add_argument("--set", dest="overrides", action="append", default=[],
                            metavar="KEY=VALUE",
                            help="override a value, e.g. solver.rrt_timeout=5 (TOML value syntax)")


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _seed(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text}")
    return value


def parse_set_option(items: Sequence[str]) -> dict[str, Any]:
    """``["solver.rrt_timeout=5", "name=x"]`` to overrides (values in TOML syntax, else strings)."""
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


class _Progress:
    """A one-line progress bar on stderr."""

    def __init__(self, stream: TextIO, enabled: bool, width: int = 30) -> None:
        self.stream = stream
        self.enabled = enabled
        self.width = width
        self.tty = hasattr(stream, "isatty") and stream.isatty()
        self.cached = 0
        self.failed = 0

    def __call__(self, done: int, total: int, record: Mapping[str, Any]) -> None:
        if record.get("timing", {}).get("cached"):
            self.cached += 1
        if record.get("status") == "error":
            self.failed += 1
        if not self.enabled:
            return
        filled = self.width * done // max(total, 1)
        bar = "#" * filled + "." * (self.width - filled)
        extra = []
        if self.cached:
            extra.append(f"{self.cached} cached")
        if self.failed:
            extra.append(f"{self.failed} failed")
        suffix = f" ({', '.join(extra)})" if extra else ""
        line = f"[{bar}] {done}/{total} jobs, last: {record.get('status')}{suffix}"
        if self.tty:
            self.stream.write("\r" + line + ("\n" if done == total else ""))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()


def _short(value: Any, width: int) -> str:
    text = str(value)
    return text if len(text) <= width else text[: width - 3] + "..."


def format_table(records: Sequence[Mapping[str, Any]]) -> str:
    """A plain-text summary table of result records (one row per job)."""
    header = ["id", "status", "steps", "margin", "time [s]", "belief/state ok", "overrides / reason"]
    rows = [header]
    for r in records:
        result = r.get("result") or {}
        plan = result.get("plan") or {}
        timing = r.get("timing") or {}
        solver_time = (timing.get("solver") or {}).get("time_total")
        margin = result.get("margin")
        validation = r.get("validation")
        vtext = "-"
        if isinstance(validation, Mapping):
            rates = [validation.get(k) for k in ("belief_success_rate", "state_success_rate")]
            if all(isinstance(v, int | float) for v in rates):
                vtext = f"{rates[0]:.2f}/{rates[1]:.2f}"
            else:
                vtext = "done"
        overrides = (r.get("job") or {}).get("overrides") or {}
        note = ", ".join(f"{k}={v}" for k, v in overrides.items())
        if r.get("status") == "error":
            err = r.get("error") or {}
            note = f"{err.get('type')}: {err.get('message')}".splitlines()[0]
        elif not note:
            note = result.get("reason", "")
        rows.append([
            str(r.get("id", ""))[:8],
            str(r.get("status")),
            str(plan.get("num_of_steps", "-")),
            f"{margin:.3g}" if isinstance(margin, int | float) else "-",
            f"{solver_time:.2f}" if isinstance(solver_time, int | float) else "-",
            vtext,
            _short(note, 60),
        ])
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    counts = summarize(records)
    lines.append("")
    lines.append("total: " + ", ".join(f"{n} {status}" for status, n in sorted(counts.items())))
    return "\n".join(lines)


def _run(args: argparse.Namespace, jobs: list[Job]) -> int:
    progress = _Progress(sys.stderr, not args.quiet)
    records = run_jobs(
        jobs, args.out, args.executor, workers=args.workers, scheduler=args.scheduler,
        resume=args.resume, progress=progress,
    )
    print(format_table(records))
    print(f"results: {args.out}/")
    return 1 if any(r.get("status") == "error" for r in records) else 0


def _single(args: argparse.Namespace, kind: str) -> int:
    try:
        overrides = parse_set_option(args.overrides)
        spec = apply_overrides(load_problem(args.file), overrides)
        job = Job(kind, spec.source, spec.name, overrides, args.seed)
    except IdstlpyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return _run(args, [job])


def _cmd_solve(args: argparse.Namespace) -> int:
    return _single(args, "solve")


def _cmd_validate(args: argparse.Namespace) -> int:
    return _single(args, "validate")


def _cmd_sweep(args: argparse.Namespace) -> int:
    try:
        sweep = load_sweep(args.file)
        jobs = sweep.jobs(seed=args.seed)
    except IdstlpyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        print(f"sweep {sweep.name}: {len(jobs)} job(s) of {sweep.problem_name}", file=sys.stderr)
    return _run(args, jobs)
