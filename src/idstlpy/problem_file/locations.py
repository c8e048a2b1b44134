"""Where a value sits in a problem file: field paths, override keys, lines, and error messages.

Every error about a problem (or sweep) file is a :class:`~idstlpy.errors.ProblemFileError`
whose message starts with ``file:line: field:``. A *field path* is a tuple of table keys (str)
and array indices (int), printed as ``modes[0].V.scale``; the same text is an *override key*
(:func:`parse_override_path` reads it back). The line is found in the TOML text on a
best-effort basis (:func:`find_line`); a value that came from an override has no line and is
reported as ``file: field (override)``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

from ..errors import ProblemFileError

__all__ = [
    "FieldPath",
    "Context",
    "TomlLine",
    "scan_lines",
    "field_name",
    "find_line",
    "parse_override_path",
    "plain_error",
]

FieldPath = tuple[str | int, ...]
"""A field of a problem file: table keys (str) and array indices (int)."""


def field_name(path: FieldPath) -> str:
    """Print a field path as ``modes[0].V.scale`` (``<file>`` for the empty path).

    Parameters
    ----------
    path : tuple of str or int
        Table keys and array indices.

    Returns
    -------
    str
    """
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + part
    return out or "<file>"


_HEADER_RE = re.compile(r"^\s*(\[\[?)\s*([^\[\]#]+?)\s*\]\]?\s*(?:#.*)?$")
_KEY_RE = re.compile(r"^\s*([A-Za-z0-9_\-\".' ]+?)\s*=")


def _split_dotted(key: str) -> tuple[str, ...]:
    parts = re.findall(r'"([^"]*)"|\'([^\']*)\'|([^.\s]+)', key)
    return tuple(a or b or c for a, b, c in parts)


def find_line(text: str, path: FieldPath) -> int | None:
    """Best-effort 1-based line of the field ``path`` in the TOML ``text``.

    Parameters
    ----------
    text : str
        The TOML text.
    path : tuple of str or int
        The field.

    Returns
    -------
    int or None
        The line of the key (or of the table header of the nearest enclosing table), or None
        when nothing matches.
    """
    lines = text.splitlines()
    sections: list[tuple[FieldPath, int, int]] = [((), 0, len(lines))]
    counts: dict[tuple[str, ...], int] = {}
    for i, line in enumerate(lines):
        m = _HEADER_RE.match(line)
        if m is None:
            continue
        keys = _split_dotted(m.group(2))
        concrete: list[str | int] = []
        # re-insert the indices of enclosing arrays of tables
        for j, key in enumerate(keys):
            concrete.append(key)
            prefix = keys[: j + 1]
            if prefix in counts and (j < len(keys) - 1 or m.group(1) != "[["):
                concrete.append(counts[prefix] - 1)
        if m.group(1) == "[[":
            counts[keys] = counts.get(keys, 0) + 1
            concrete.append(counts[keys] - 1)
        start, end = sections[-1][1], i
        sections[-1] = (sections[-1][0], start, end)
        sections.append((tuple(concrete), i, len(lines)))
    best: tuple[FieldPath, int, int] | None = None
    for sec in sections:
        head = sec[0]
        if len(head) <= len(path) and tuple(path[: len(head)]) == head:
            if best is None or len(head) > len(best[0]):
                best = sec
    if best is None:
        return None
    head, start, end = best
    rest = list(path[len(head) :])
    if not rest:
        return start + 1 if head else None
    # look for `key =` (or a dotted `key.sub =`) inside the section
    wanted = [p for p in rest if isinstance(p, str)]
    body_start = start + 1 if head else start
    for depth in range(len(wanted), 0, -1):
        want = tuple(wanted[:depth])
        for i in range(body_start, end):
            km = _KEY_RE.match(lines[i])
            if km is None or _HEADER_RE.match(lines[i]):
                continue
            got = _split_dotted(km.group(1))
            if got == want or (depth == 1 and got[:1] == want):
                return i + 1
    return start + 1 if head else None


@dataclass(frozen=True)
class TomlLine:
    """One line of a TOML text that starts outside any value (see :func:`scan_lines`).

    Attributes
    ----------
    number : int
        1-based line number.
    kind : {"blank", "comment", "header", "key"}
        A blank line, a comment, a ``[table]`` / ``[[array]]`` header or a ``key = value`` line.
    keys : tuple of str
        The header's dotted name, or the key's (``("validation", "seed")`` for
        ``validation.seed = 3``); empty for blank lines and comments.
    array : bool
        True for an ``[[array of tables]]`` header.
    """

    number: int
    kind: str
    keys: tuple[str, ...] = ()
    array: bool = False


def scan_lines(text: str) -> list[TomlLine]:
    """The lines of ``text`` that start outside a value, classified (TOML's own scoping rules).

    A line that continues a multi-line array or string (``[0, 1]]`` of a matrix written over
    several lines) is skipped, so it is never taken for a table header.

    Parameters
    ----------
    text : str
        A TOML text (assumed valid: :mod:`tomllib` has read it).

    Returns
    -------
    list of TomlLine
    """
    out: list[TomlLine] = []
    depth = 0  # open brackets and braces of a value that spans lines
    quote: str | None = None  # an open multi-line string's delimiter
    for number, line in enumerate(text.splitlines(), start=1):
        if depth == 0 and quote is None:
            stripped = line.strip()
            if not stripped:
                out.append(TomlLine(number, "blank"))
                continue
            if stripped.startswith("#"):
                out.append(TomlLine(number, "comment"))
                continue
            header = _HEADER_RE.match(line)
            if header is not None:
                keys = _split_dotted(header.group(2))
                out.append(TomlLine(number, "header", keys, header.group(1) == "[["))
                continue  # a header holds no value: nothing to track
            km = _KEY_RE.match(line)
            if km is not None:
                out.append(TomlLine(number, "key", _split_dotted(km.group(1))))
        depth, quote = _track(line, depth, quote)
    return out


def _track(line: str, depth: int, quote: str | None) -> tuple[int, str | None]:
    """The bracket depth and open multi-line string after ``line`` (strings and comments skipped)."""
    i = 0
    while i < len(line):
        if quote is not None:
            if line.startswith(quote, i):
                i += len(quote)
                quote = None
                continue
            i += 2 if line[i] == "\\" and quote[0] == '"' else 1
            continue
        ch = line[i]
        if ch == "#":
            break
        if line.startswith('"""', i) or line.startswith("'''", i):
            quote = line[i : i + 3]
            i += 3
            continue
        if ch in "\"'":
            end = i + 1
            while end < len(line) and line[end] != ch:
                end += 2 if ch == '"' and line[end] == "\\" else 1
            i = end + 1
            continue
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth = max(0, depth - 1)
        i += 1
    return depth, quote


def plain_error(file: str | None, message: str, field: str | None = None) -> ProblemFileError:
    """A :class:`ProblemFileError` ``"file: message"`` with ``file``, ``line`` (None) and ``field`` set.

    Parameters
    ----------
    file : str or None
        The file's name (omitted from the message when None).
    message : str
        What is wrong.
    field : str, optional
        The field, as printed by :func:`field_name`.

    Returns
    -------
    ProblemFileError
    """
    err = ProblemFileError(f"{file}: {message}" if file else message)
    err.file, err.line, err.field = file, None, field  # type: ignore[attr-defined]
    return err


_SEGMENT_RE = re.compile(r"(\.)?(?:([A-Za-z_][A-Za-z0-9_\-]*)|(\d+))|\[(\d+)\]")


def parse_override_path(key: str) -> list[str | int]:
    """Split an override key such as ``"modes[0].V.scale"`` or ``"solver.rrt_timeout"``.

    ``modes.0.V`` is the same as ``modes[0].V``.

    Parameters
    ----------
    key : str
        The dotted key.

    Returns
    -------
    list of str or int
        Table keys (str) and array indices (int).

    Raises
    ------
    ProblemFileError
        For a malformed key.
    """
    if not isinstance(key, str) or not key:
        raise plain_error(None, f"override key must be a non-empty string, got {key!r}")
    parts: list[str | int] = []
    pos = 0
    while pos < len(key):
        m = _SEGMENT_RE.match(key, pos)
        if (
            m is None
            or (m.group(1) is None and parts and m.group(4) is None)
            or (m.group(1) is not None and not parts)
        ):
            raise plain_error(None, f"override key {key!r} is malformed at character {pos + 1}")
        if m.group(2) is not None:
            parts.append(m.group(2))
        elif m.group(3) is not None:
            if not parts:
                raise plain_error(None, f"override key {key!r} must start with a name")
            parts.append(int(m.group(3)))
        else:
            parts.append(int(m.group(4)))
        pos = m.end()
    if not isinstance(parts[0], str):
        raise plain_error(None, f"override key {key!r} must start with a name")
    return parts


class Context:
    """Where a problem came from, to build error messages that name the file, line and field.

    Parameters
    ----------
    name : str
        The file's name (or ``"<string>"``).
    source : str
        The file's text.
    overridden : sequence of str
        Override keys: fields under them are reported as ``(override)``, without a line.
    """

    def __init__(self, name: str, source: str, overridden: Sequence[str] = ()) -> None:
        self.name = name
        self.source = source
        self.overridden = [tuple(parse_override_path(k)) for k in overridden]

    def error(self, path: FieldPath, message: str, line: int | None = None) -> ProblemFileError:
        """The error ``file:line: field: message`` about the field ``path``.

        Parameters
        ----------
        path : tuple of str or int
            The field.
        message : str
            What is wrong with it.
        line : int, optional
            The field's line when the caller knows it (default: found in the text).

        Returns
        -------
        ProblemFileError
            With attributes ``file``, ``line`` (or None) and ``field``.
        """
        fieldname = field_name(path)
        overridden = any(tuple(path[: len(o)]) == o for o in self.overridden)
        if overridden:
            line = None
        elif line is None:
            line = find_line(self.source, path)
        if overridden:
            where = f"{self.name}: {fieldname} (override)"
        elif line is not None:
            where = f"{self.name}:{line}: {fieldname}"
        else:
            where = f"{self.name}: {fieldname}"
        err = ProblemFileError(f"{where}: {message}")
        err.file = self.name  # type: ignore[attr-defined]
        err.line = line  # type: ignore[attr-defined]
        err.field = fieldname  # type: ignore[attr-defined]
        return err
