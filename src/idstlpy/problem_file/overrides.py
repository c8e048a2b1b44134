"""Overrides: replace values of a problem file by dotted paths (for ``--set`` and sweeps)."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

from .locations import field_name, parse_override_path, plain_error
from .spec import ProblemSpec

__all__ = ["apply_overrides", "parse_override_path"]


def apply_overrides(spec: ProblemSpec, overrides: Mapping[str, Any]) -> ProblemSpec:
    """A copy of ``spec`` with some values replaced (for parameter sweeps).

    Parameters
    ----------
    spec : ProblemSpec
        The problem file as loaded by :func:`~idstlpy.load_problem`.
    overrides : mapping of str to value
        Dotted paths (``"solver.rrt_timeout"``, ``"modes[0].V"``, ``"initial_belief.mean"``,
        ``"propositions.target.confidence"``) to plain values (numbers, strings, arrays,
        tables). Missing tables on the way are created; the result is checked again, so an
        unknown key is reported.

    Returns
    -------
    ProblemSpec
        With ``overrides`` merged into the spec's own.

    Raises
    ------
    ProblemFileError
        Naming the override (``field (override)``) and what is wrong with it.
    """
    if not overrides:
        return spec
    data = copy.deepcopy(spec.data)
    for key, value in overrides.items():
        path = parse_override_path(key)
        node: Any = data
        for i, part in enumerate(path[:-1]):
            nxt = path[i + 1]
            if isinstance(part, int):
                if not isinstance(node, list) or not 0 <= part < len(node):
                    where = field_name(tuple(path[:i]))
                    raise plain_error(spec.name, f"override {key!r}: no element {part} in {where}", key)
                node = node[part]
            else:
                if not isinstance(node, dict):
                    where = field_name(tuple(path[:i]))
                    raise plain_error(spec.name, f"override {key!r}: {where} is not a table", key)
                if part not in node:
                    node[part] = [] if isinstance(nxt, int) else {}
                node = node[part]
        last = path[-1]
        if isinstance(last, int):
            if not isinstance(node, list) or not 0 <= last < len(node):
                raise plain_error(spec.name, f"override {key!r}: no element {last}", key)
            node[last] = copy.deepcopy(value)
        else:
            if not isinstance(node, dict):
                where = field_name(tuple(path[:-1]))
                raise plain_error(spec.name, f"override {key!r}: {where} is not a table", key)
            node[last] = copy.deepcopy(value)
    merged = {**spec.overrides, **dict(overrides)}
    out = ProblemSpec(data, spec.source, spec.name, merged)
    out.build()
    return out
