"""A problem file as plain data (:class:`ProblemSpec`) and :func:`load_problem`."""

from __future__ import annotations

import hashlib
import os
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .builder import BuiltProblem, build
from .locations import plain_error

__all__ = ["ProblemSpec", "load_problem", "text_sha256"]


def text_sha256(text: str) -> str:
    """The SHA-256 of a problem file's text (UTF-8), in hex: how result files name their problem.

    Parameters
    ----------
    text : str
        The file's text.

    Returns
    -------
    str
        64 hex digits.
    """
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class ProblemSpec:
    """A problem file as plain data: the parsed TOML, its text and where it came from.

    Create it with :func:`load_problem`; it pickles cheaply and builds the solver objects on
    demand with :meth:`build`.

    Parameters
    ----------
    data : dict
        The parsed TOML (with overrides applied).
    source : str
        The file's text (for error messages and for shipping to other processes).
    name : str
        The file's path, or ``"<string>"``.
    overrides : dict
        The overrides applied to ``data`` by :func:`~idstlpy.problem_file.apply_overrides`.
    """

    data: dict[str, Any]
    source: str
    name: str = "<string>"
    overrides: dict[str, Any] = field(default_factory=dict)

    def build(self) -> BuiltProblem:
        """Build the :class:`~idstlpy.Problem`, the ``solve`` keyword arguments and the execution settings.

        Returns
        -------
        BuiltProblem
            ``(problem, solver_kwargs, execution)``.

        Raises
        ------
        ProblemFileError
        """
        return build(self)

    @property
    def title(self) -> str:
        """The ``name`` key of the file, or the file name."""
        name = self.data.get("name")
        return name if isinstance(name, str) else Path(self.name).stem

    @property
    def sha256(self) -> str:
        """SHA-256 of :attr:`source` (the text as read, before overrides)."""
        return text_sha256(self.source)

    @property
    def seed(self) -> int | None:
        """The ``[solver]`` seed (after overrides), or None when the file sets none."""
        solver = self.data.get("solver")
        seed = solver.get("seed") if isinstance(solver, dict) else None
        return seed if isinstance(seed, int) and not isinstance(seed, bool) else None


def load_problem(path_or_text: str | os.PathLike[str], *, name: str | None = None) -> ProblemSpec:
    """Read and check a TOML problem file.

    Parameters
    ----------
    path_or_text : str or path-like
        A path (``Path``, or a one-line string naming an existing file or ending in
        ``.toml``), or the TOML text itself.
    name : str, optional
        Name used in error messages (default: the path, or ``"<string>"``).

    Returns
    -------
    ProblemSpec
        The plain data; the whole problem has been checked (built once) already.

    Raises
    ------
    ProblemFileError
        For a missing or unreadable file, invalid TOML, unknown keys, missing fields, wrong
        shapes and expressions outside the whitelist; the message names the file, line and
        field.
    """
    text, source_name = _read(path_or_text)
    spec_name = name or source_name
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        err = plain_error(f"{spec_name}{':' + m.group(1) if m else ''}", f"invalid TOML: {exc}")
        err.file, err.line = spec_name, int(m.group(1)) if m else None  # type: ignore[attr-defined]
        raise err from None
    spec = ProblemSpec(data, text, spec_name)
    spec.build()
    return spec


def _read(path_or_text: str | os.PathLike[str]) -> tuple[str, str]:
    if isinstance(path_or_text, os.PathLike) or (
        isinstance(path_or_text, str)
        and "\n" not in path_or_text
        and (path_or_text.endswith(".toml") or Path(path_or_text).is_file())
    ):
        path = Path(path_or_text)
        try:
            return path.read_text(encoding="utf-8"), str(path)
        except (OSError, UnicodeDecodeError) as exc:
            raise plain_error(str(path), f"cannot read the problem file: {exc}") from None
    if not isinstance(path_or_text, str):
        raise plain_error(None, f"expected a path or TOML text, got {type(path_or_text).__name__}")
    if "\n" not in path_or_text and "=" not in path_or_text:
        raise plain_error(path_or_text, "no such problem file (and not TOML text either)")
    return path_or_text, "<string>"
