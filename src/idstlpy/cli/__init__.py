"""The ``idstlpy`` command.

Subcommands come from the modules named in :data:`_COMMAND_MODULES`; each module
``idstlpy.cli.<name>`` exposes ``register(subparsers)``, which adds its parsers and sets
``func`` on each of them (``parser.set_defaults(func=handler)``). ``handler(args)`` returns the
exit status (``None`` means 0). A module that does not exist is skipped.

Errors raised by the library (:class:`~idstlpy.errors.IdstlpyError`, ``ValueError``,
``OSError``) are printed as one line on stderr and exit with status 2, without a traceback.
Matplotlib uses the non-interactive Agg backend unless ``MPLBACKEND`` says otherwise.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence

__all__ = ["main", "build_parser"]

_COMMAND_MODULES: tuple[str, ...] = ("demo", "files")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every available subcommand registered."""
    from .. import __version__

    parser = argparse.ArgumentParser(
        prog="idstlpy",
        description="Active perception and control synthesis from PrSTL specifications.",
    )
    parser.add_argument("--version", action="version", version=f"idstlpy {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="log progress (-vv: debug)")
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
    """
    from ..errors import IdstlpyError

    os.environ.setdefault("MPLBACKEND", "Agg")
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.verbose:
        logging.basicConfig(
            level=logging.DEBUG if args.verbose > 1 else logging.INFO,
            format="%(levelname)s %(name)s: %(message)s",
        )
    try:
        status = args.func(args)
    except KeyboardInterrupt:
        print("idstlpy: interrupted", file=sys.stderr)
        return 130
    except (IdstlpyError, ValueError, OSError) as exc:
        print(f"idstlpy {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    return 0 if status is None else int(status)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
