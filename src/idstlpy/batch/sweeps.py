"""Sweeps: a grid or a list of overrides over one problem file, each job with a spawned seed.

A sweep file (TOML; the reference is ``docs/sweeps.md``)::

    problem = "light_dark.toml"       # the base problem file, relative to the sweep file
    kind = "solve"                    # or "validate"
    seed = 2024                       # every job's seed is spawned from it
    repeats = 2                       # jobs per parameter combination (default 1)

    [grid]                            # the cartesian product of these values ...
    "solver.goal_bias" = [0.1, 0.25]
    "solver.rrt_timeout" = [1, 5]

    [[cases]]                         # ... for each of these override sets (default: one, empty)
    "initial_belief.mean" = [0.0, 2.5]

The seed of repeat ``r`` of combination ``i`` is drawn from
``numpy.random.SeedSequence(seed, spawn_key=(i, r))``: appending combinations or repeats does not
change the seeds (and so the result files) of the existing jobs.
"""

from __future__ import annotations

import itertools
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ProblemFileError
from ..problem_file import apply_overrides, load_problem
from ..problem_file.locations import Context
from ..problem_file.schema import integer, string, table
from .jobs import JOB_KINDS, Job

__all__ = ["SWEEP_KEYS", "Sweep", "load_sweep"]


SWEEP_KEYS = ("name", "description", "problem", "kind", "seed", "repeats", "grid", "cases")


@dataclass(frozen=True)
class Sweep:
    """A parameter sweep over one problem file (the file format is in ``docs/sweeps.md``).

    Parameters
    ----------
    problem_name : str
        Path of the base problem file.
    problem_text : str
        Its text.
    kind : {"solve", "validate"}
    seed : int
        Root of every job's seed.
    combinations : list of dict
        One override set per parameter combination.
    repeats : int
        Jobs per combination (each with its own seed).
    name : str
    """

    problem_name: str
    problem_text: str
    kind: str = "solve"
    seed: int = 0
    combinations: list[dict[str, Any]] = field(default_factory=lambda: [{}])
    repeats: int = 1
    name: str = "sweep"

    def jobs(self, seed: int | None = None) -> list[Job]:
        """The jobs, combination-major.

        Parameters
        ----------
        seed : int, optional
            Replaces the sweep's root seed.

        Returns
        -------
        list of Job
        """
        root = self.seed if seed is None else seed
        out = []
        for i, overrides in enumerate(self.combinations):
            for r in range(self.repeats):
                ss = np.random.SeedSequence(root, spawn_key=(i, r))
                job_seed = int(ss.generate_state(1, np.uint64)[0])
                out.append(Job(self.kind, self.problem_text, self.problem_name, dict(overrides), job_seed))
        return out


def _flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in table.items():
        path = f"{prefix}.{key}" if prefix else key
        if isinstance(value, dict) and "." not in key and "[" not in key:
            out.update(_flatten(value, path))
        else:
            out[path] = value
    return out


def load_sweep(path: str | os.PathLike[str]) -> Sweep:
    """Read and check a sweep file (every combination is applied to the problem once).

    Parameters
    ----------
    path : path
        The sweep TOML file; its ``problem`` path is relative to the file's directory.

    Returns
    -------
    Sweep

    Raises
    ------
    ProblemFileError
        Naming the sweep file (or the problem file) and the line of the bad entry.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ProblemFileError(f"{path}: cannot read the sweep file: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ProblemFileError(f"{path}: invalid TOML: {exc}") from None
    ctx = Context(str(path), text)
    table(ctx, (), data, SWEEP_KEYS, ("problem",))
    problem_rel = string(ctx, ("problem",), data["problem"])
    problem_path = (path.parent / problem_rel) if not Path(problem_rel).is_absolute() else Path(problem_rel)
    if not problem_path.is_file():
        raise ctx.error(("problem",), f"problem file {str(problem_path)!r} does not exist")
    kind = string(ctx, ("kind",), data.get("kind", "solve"))
    if kind not in JOB_KINDS:
        raise ctx.error(("kind",), f"must be one of {', '.join(JOB_KINDS)}, got {kind!r}")
    seed = integer(ctx, ("seed",), data.get("seed", 0), 0)
    repeats = integer(ctx, ("repeats",), data.get("repeats", 1), 1)
    name = string(ctx, ("name",), data.get("name", path.stem))
    if "description" in data:
        string(ctx, ("description",), data["description"])
    grid = data.get("grid", {})
    if not isinstance(grid, dict):
        raise ctx.error(("grid",), "must be a table of parameter paths to arrays of values")
    grid = _flatten(grid)
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise ctx.error(("grid", key), "must be a non-empty array of values")
    cases = data.get("cases", [{}])
    if not isinstance(cases, list) or not all(isinstance(c, dict) for c in cases) or not cases:
        raise ctx.error(("cases",), "must be a non-empty array of tables ([[cases]])")
    cases = [_flatten(c) for c in cases]
    keys = list(grid)
    combinations = [
        {**case, **dict(zip(keys, values, strict=True))}
        for case in cases
        for values in itertools.product(*(grid[k] for k in keys))
    ]
    base = load_problem(problem_path)
    for i, combo in enumerate(combinations):
        try:
            apply_overrides(base, combo)
        except ProblemFileError as exc:
            where = ("cases", i // max(1, len(combinations) // len(cases))) if "cases" in data else ("grid",)
            raise ctx.error(where, f"combination {combo}: {exc}") from None
    return Sweep(str(problem_path), base.source, kind, seed, combinations, repeats, name)
