"""``idstlpy check RESULT.json``: re-check the certificate of every ``infeasible`` in a result file.

The certificate saved with an ``infeasible`` result (its ``certificate`` field) is checked alone,
without the problem and without trusting the solvers that made it: each LP refutation's Farkas
ray in exact rational arithmetic, each violated face exactly, and the unsatisfiability of the
proof's clauses by a SAT solver of another family than the one that searched
(:func:`idstlpy.synthesis.certificates.check_certificate`).

A file may hold one result (``SolveResult.save``), a record of ``idstlpy solve`` / ``sweep``, a
JSON list of them, or one per line (JSON lines).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ..synthesis.certificates import check_certificate
from .exit_codes import EXIT_OK, EXIT_UNCERTIFIED, EXIT_USAGE

__all__ = ["register"]


def register(subparsers: Any) -> None:
    """Add ``check`` to the ``idstlpy`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        What ``ArgumentParser.add_subparsers`` returned.
    """
    check = subparsers.add_parser(
        "check",
        help="re-check the certificates of infeasible results (exact arithmetic, a second SAT solver)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="exit status: 0 every infeasible result's certificate verifies (or there is none to "
        "check), 5 some certificate fails, is missing or is not certified, 2 input error",
    )
    check.add_argument("results", metavar="RESULT.json", nargs="+", help="result or record files")
    check.set_defaults(func=_run)


def _results(path: Path) -> list[dict[str, Any]]:
    """The result objects in a file (one, a list, or JSON lines)."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise OSError(f"cannot read {str(path)!r}: {exc.strerror or exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        try:
            data = [json.loads(line) for line in text.splitlines() if line.strip()]
        except json.JSONDecodeError as exc:
            raise ValueError(f"{str(path)!r} is not JSON or JSON lines: {exc}") from None
    items = data if isinstance(data, list) else [data]
    if not all(isinstance(item, dict) for item in items):
        raise ValueError(f"{str(path)!r} holds no result objects")
    return items


def _run(args: argparse.Namespace) -> int:
    worst = EXIT_OK
    checked = 0
    for name in args.results:
        path = Path(name)
        try:
            items = _results(path)
        except (OSError, ValueError) as exc:
            print(f"idstlpy check: {exc}", file=sys.stderr)
            return EXIT_USAGE
        for i, item in enumerate(items):
            label = f"{path}" + (f"[{i}]" if len(items) > 1 else "")
            if item.get("status") != "infeasible":
                continue
            checked += 1
            cert = item.get("certificate")
            if not isinstance(cert, dict):
                print(f"{label}: infeasible without a certificate (not certified)")
                worst = EXIT_UNCERTIFIED
                continue
            report = check_certificate(cert)
            print(f"{label}: {report.summary()}")
            if not report.certified:
                worst = EXIT_UNCERTIFIED
            if report.ok and report.certified and cert.get("certified") is False:
                print(f"{label}: note: the solve had recorded this certificate as not certified")
    if not checked:
        print("no infeasible result to check")
    return worst
