"""The ``idstlpy`` command.

Subcommands come from the modules named in :data:`_COMMAND_MODULES`; each module
``idstlpy.cli.<name>`` exposes ``register(subparsers)``, which adds its parsers and sets
``func`` on each of them (``parser.set_defaults(func=handler)``). ``handler(args)`` returns the
exit status (``None`` means 0). A module that does not exist is skipped. Global options
(``-v``) are accepted before or after the subcommand.

Exit status, the same for every subcommand (``docs/cli.md``):

====  ==========================================================================================
0     success: every plan was found (solve, sweep, demo), checked and executed (validate), the
      figure or file was written (plot, example)
1     ran, but some job has no plan: ``infeasible``, ``budget_exhausted``, or a saved plan that
      is ``rejected`` (it does not satisfy the problem)
2     usage or input error: bad arguments, an invalid problem, sweep or result file, a file that
      cannot be read or written; nothing was run
3     a job failed with an error (its record has ``status = "error"``)
4     every plan found and executed, but a validation's measured success rates fall short of
      its execution target (default 90% belief / 95% true state; ``validate --target``)
5     ``check``: some ``infeasible`` result's certificate fails, is missing or is not certified
130   interrupted (Ctrl-C)
====  ==========================================================================================

Errors raised by the library (:class:`~idstlpy.errors.IdstlpyError`, ``ValueError``,
``OSError``) are printed as one line on stderr, without a traceback. Matplotlib uses the
non-interactive Agg backend unless ``MPLBACKEND`` says otherwise.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from typing import Any

from .exit_codes import (
    EXIT_BELOW_TARGET,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_NO_PLAN,
    EXIT_OK,
    EXIT_USAGE,
    exit_status,
)

__all__ = [
    "main",
    "build_parser",
    "exit_status",
    "EXIT_OK",
    "EXIT_NO_PLAN",
    "EXIT_USAGE",
    "EXIT_FAILED",
    "EXIT_BELOW_TARGET",
    "EXIT_INTERRUPTED",
]

_COMMAND_MODULES: tuple[str, ...] = ("demo", "files", "plot", "example", "check")


def _add_global_options(parser: argparse.ArgumentParser, top: bool) -> None:
    """``-v``: on the top parser with a default, on subcommands without one (so both places work)."""
    default: Any = 0 if top else argparse.SUPPRESS
    parser.add_argument("-v", "--verbose", action="count", default=default, help="log progress (-vv: debug)")


def _subparsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    out: list[argparse.ArgumentParser] = []
    for action in parser._actions:  # noqa: SLF001 - argparse keeps subparsers only there
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for sub in dict.fromkeys(action.choices.values()):
                out.append(sub)
                out.extend(_subparsers(sub))
    return out


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every available subcommand registered.

    Returns
    -------
    argparse.ArgumentParser
    """
    from .. import __version__

    parser = argparse.ArgumentParser(
        prog="idstlpy",
        description="Active perception and control synthesis from PrSTL specifications.",
        epilog="exit status: 0 ok, 1 no plan, 2 usage or input error, 3 a job failed, "
        "4 validated below the execution target, 5 a certificate does not verify (docs/cli.md)",
    )
    from .._version import software_info

    commit = software_info()["commit"]  # the checkout's commit, read from .git (None: a wheel)
    version = f"idstlpy {__version__}" + (f" (commit {commit[:12]})" if commit else "")
    parser.add_argument("--version", action="version", version=version)
    _add_global_options(parser, top=True)
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in _COMMAND_MODULES:
        modname = f"{__name__}.{name}"
        try:
            module = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name == modname:
                continue
            raise
        module.register(subparsers)
    for sub in _subparsers(parser):
        if not any("--verbose" in a.option_strings for a in sub._actions):  # noqa: SLF001
            _add_global_options(sub, top=False)
    return parser


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``idstlpy`` command line; returns the exit status.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        See the module docstring (0 ok, 1 no plan, 2 usage or input error, 3 a job failed).
    """
    from ..errors import IdstlpyError

    os.environ.setdefault("MPLBACKEND", "Agg")
    parser = build_parser()
    args = parser.parse_args(argv)
    verbose = getattr(args, "verbose", 0) or 0
    if verbose:
        logging.basicConfig(
            level=logging.DEBUG if verbose > 1 else logging.INFO,
            format="%(levelname)s %(name)s: %(message)s",
        )
    try:
        status = args.func(args)
    except KeyboardInterrupt:
        print("idstlpy: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (IdstlpyError, ValueError, OSError) as exc:
        print(f"idstlpy {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK if status is None else int(status)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
