"""The package's solver: what :meth:`Problem.solve <idstlpy.problem.Problem.solve>` runs.

:class:`~idstlpy.problem.Problem` (the data and its validation) is a model-layer class, re-exported
here under its former path; this module registers :func:`solve` with it when imported
(:func:`~idstlpy.problem.register_solver`; ``import idstlpy`` imports it).
"""

from __future__ import annotations

import time
from typing import Any

from ..errors import InvalidTypeError
from ..problem import Problem, register_solver
from .options import SolverOptions
from .pipeline import solve as run_pipeline
from .results import SolveResult

__all__ = ["Problem", "solve"]


def solve(problem: Problem, options: SolverOptions | None = None, /, **overrides: Any) -> SolveResult:
    """Solve ``problem``: the stages of :data:`.pipeline.STAGES` in order (the decoupled blocks or
    the CEGIS loop, then (joint chance constraints) the risk re-allocation, then (only plans below
    target under the default guarantee) a closed-loop solve).

    Parameters
    ----------
    problem : Problem
    options : SolverOptions, optional
        Every solver parameter at once; ``overrides`` take precedence.
    **overrides
        Any :class:`SolverOptions` field.

    Returns
    -------
    SolveResult

    Raises
    ------
    InvalidTypeError
        When ``options`` is not a :class:`SolverOptions`.
    InvalidArgumentError
        When an override names no option or has a bad value.
    """
    start = time.perf_counter()
    if options is None:
        opts = SolverOptions.make(**overrides)
    elif isinstance(options, SolverOptions):
        opts = options.with_(**overrides) if overrides else options
    else:
        raise InvalidTypeError(f"options must be a SolverOptions, got {type(options).__name__}")

    return run_pipeline(problem, opts, start)


def _registered(problem: Problem, options: object | None, /, **overrides: Any) -> SolveResult:
    """:func:`solve` as :meth:`Problem.solve_result` calls it (any ``options``, checked here)."""
    if options is not None and not isinstance(options, SolverOptions):
        raise InvalidTypeError(f"options must be a SolverOptions, got {type(options).__name__}")
    return solve(problem, options, **overrides)


register_solver(_registered)  # Problem.solve / solve_result (see idstlpy.problem)
