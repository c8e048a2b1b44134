"""``idstlpy example NAME [--out FILE]``: write one of the examples shipped inside the package.

The examples are package data (``idstlpy/examples/``), so they are there in any installation,
not only in a clone of the repository. ``idstlpy example --list`` names them; without ``--out``
the example is printed on stdout.
"""

from __future__ import annotations

import argparse
import re
import sys
from importlib import resources
from importlib.abc import Traversable
from pathlib import Path
from typing import Any

from ..errors import InvalidArgumentError
from .exit_codes import EXIT_OK

__all__ = ["register", "example_names", "example_text"]

_SUFFIXES = (".toml", ".ipynb")


def _folder() -> Traversable:
    return resources.files("idstlpy").joinpath("examples")


def _files() -> dict[str, Traversable]:
    """Example name -> file: ``light_dark.toml`` is ``light-dark``, ``light_dark.ipynb`` is
    ``light-dark-notebook``."""
    out: dict[str, Traversable] = {}
    for entry in sorted(_folder().iterdir(), key=lambda e: (not e.name.endswith(".toml"), e.name)):
        name = entry.name
        if entry.is_file() and name.endswith(_SUFFIXES) and not name.startswith("."):
            stem, suffix = name.rsplit(".", 1)
            key = stem.replace("_", "-") + ("-notebook" if suffix == "ipynb" else "")
            out.setdefault(key, entry)
    return dict(sorted(out.items()))


def example_names() -> list[str]:
    """Names of the shipped examples (``light-dark``, ``reach-avoid``, ...).

    Returns
    -------
    list of str
    """
    return list(_files())


def _resolve(name: str) -> Traversable:
    files = _files()
    key = name.replace("_", "-")
    if key.endswith(".ipynb"):
        key = key[: -len(".ipynb")] + "-notebook"
    elif key.endswith(".toml"):
        key = key[: -len(".toml")]
    if key in files:
        return files[key]
    raise InvalidArgumentError(f"no example {name!r}; the examples are: {', '.join(files)}")


def example_text(name: str) -> str:
    """The text of a shipped example.

    Parameters
    ----------
    name : str
        ``light-dark`` (``light_dark`` and ``light_dark.toml`` are accepted too).

    Returns
    -------
    str
    """
    return _resolve(name).read_text(encoding="utf-8")


def _description(entry: Traversable) -> str:
    text = entry.read_text(encoding="utf-8")
    if entry.name.endswith(".ipynb"):
        m = re.search(r'"# ([^"\\]+)', text)
        return f"notebook: {m.group(1)}" if m else "notebook"
    m = re.search(r'^description\s*=\s*"([^"]*)"', text, re.MULTILINE)
    if m:
        return m.group(1)
    m = re.search(r"^#\s*(.+)$", text, re.MULTILINE)
    return m.group(1) if m else ""


def register(subparsers: Any) -> None:
    """Add ``example`` to the ``idstlpy`` command.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        What ``ArgumentParser.add_subparsers`` returned.
    """
    ex = subparsers.add_parser(
        "example",
        help="write a shipped example (problem files, a sweep, a notebook)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="exit status: 0 written, 2 unknown name or the file exists (use --force)",
    )
    ex.add_argument("name", nargs="?", default=None, metavar="NAME", help="the example (see --list)")
    ex.add_argument("--list", action="store_true", help="list the examples and exit")
    ex.add_argument(
        "--out",
        metavar="FILE",
        default=None,
        help="write here (a folder: under the example's file name); default: stdout",
    )
    ex.add_argument("--force", action="store_true", help="overwrite existing files")
    ex.set_defaults(func=_cmd_example)


def _write(entry: Traversable, dest: Path, force: bool) -> Path:
    if dest.exists() and not force:
        raise InvalidArgumentError(f"{dest} exists (use --force to overwrite)")
    dest.write_text(entry.read_text(encoding="utf-8"), encoding="utf-8")
    return dest


def _cmd_example(args: argparse.Namespace) -> int:
    files = _files()
    if args.list or args.name is None:
        width = max(len(k) for k in files)
        for key, entry in files.items():
            print(f"{key.ljust(width)}  {entry.name}: {_description(entry)}")
        return EXIT_OK
    entry = _resolve(args.name)
    if args.out is None:
        sys.stdout.write(entry.read_text(encoding="utf-8"))
        return EXIT_OK
    out = Path(args.out)
    dest = out / entry.name if out.is_dir() or args.out.endswith(("/", "\\")) else out
    if not dest.parent.is_dir():
        raise InvalidArgumentError(f"folder {str(dest.parent)!r} does not exist")
    print(f"wrote {_write(entry, dest, args.force)}")
    # a sweep names its problem file relative to itself: write it alongside when it is shipped
    text = entry.read_text(encoding="utf-8")
    m = re.search(r'^problem\s*=\s*"([^"/\\]+)"', text, re.MULTILINE)
    if m:
        base = next((e for e in files.values() if e.name == m.group(1)), None)
        target = dest.parent / m.group(1)
        if base is not None and not target.exists():
            print(f"wrote {_write(base, target, False)} (the sweep's problem file)")
    return EXIT_OK
