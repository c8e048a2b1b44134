"""``idstlpy plot RESULT.json``: draw a saved plan over its problem's workspace.

The problem is rebuilt from the text and overrides the result file records (``solve``,
``validate``, ``sweep`` and ``demo`` record them); a file written by ``SolveResult.save`` has
no problem text: give the problem file with ``--problem``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..batch.records import plan_from_record, plan_steps, problem_from_record, read_record
from ..problem_file import apply_overrides, load_problem, text_sha256
from .exit_codes import EXIT_NO_PLAN, EXIT_OK
from .figures import FIGURE_FORMATS, FIGURE_KINDS, check_figure_path, save_plan_figure

__all__ = ["register"]


def register(subparsers: Any) -> None:
    """Add ``plot`` to the ``idstlpy`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        What ``ArgumentParser.add_subparsers`` returned.
    """
    plot = subparsers.add_parser(
        "plot",
        help="draw a saved plan (a result JSON file)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="exit status: 0 figure written, 1 the result has no plan (the workspace is drawn "
        "alone), 2 input error",
    )
    plot.add_argument("result", metavar="RESULT.json", help="a result file of schema idstlpy.result/1")
    plot.add_argument(
        "--out",
        metavar="FIGURE",
        default=None,
        help=f"figure to write ({', '.join('.' + f for f in FIGURE_FORMATS)}; default: RESULT.png)",
    )
    plot.add_argument(
        "--problem",
        metavar="FILE",
        default=None,
        help="the problem file (default: the problem text recorded in the result)",
    )
    plot.add_argument(
        "--kind",
        choices=FIGURE_KINDS,
        default="auto",
        help="workspace (the plane of x[0], x[1]) or time-series (every state, inputs, modes); "
        "default: the workspace for two or more states",
    )
    plot.set_defaults(func=_cmd_plot)


def _cmd_plot(args: argparse.Namespace) -> int:
    result_path = Path(args.result)
    figure = check_figure_path(args.out or result_path.with_suffix(".png"))
    record = read_record(result_path)
    if args.problem:
        spec = load_problem(args.problem)
        recorded = (record.get("problem") or {}).get("sha256")
        if recorded and recorded != text_sha256(spec.source):
            print(
                f"idstlpy plot: warning: {args.problem} is not the problem text the result was solved for",
                file=sys.stderr,
            )
        overrides = (record.get("problem") or {}).get("overrides") or {}
        if overrides:
            spec = apply_overrides(spec, overrides)
    else:
        spec = problem_from_record(record, str(result_path))
    plan = plan_from_record(record, str(result_path))
    if plan is None and args.kind == "time-series":
        print(f"idstlpy plot: {result_path} has no plan (status {record.get('status')!r})", file=sys.stderr)
        return EXIT_NO_PLAN
    status = record.get("status")
    title = f"{spec.title}: {status}"
    steps = plan_steps(record.get("plan"))
    if steps is not None:
        title += f", {steps} steps"
        margin = record.get("margin")
        if isinstance(margin, float):
            title += f", margin {margin:.3g}"
    save_plan_figure(spec.build().problem, plan, figure, title, kind=args.kind)
    print(f"figure: {figure}")
    return EXIT_OK if plan is not None else EXIT_NO_PLAN
