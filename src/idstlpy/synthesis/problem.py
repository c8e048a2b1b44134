"""The package's solver: what :meth:`Problem.solve <idstlpy.problem.Problem.solve>` runs.

:class:`~idstlpy.problem.Problem` (the data and its validation) is a model-layer class, re-exported
here under its former path; this module registers :func:`solve` with it when imported
(:func:`~idstlpy.problem.register_solver`; ``import idstlpy`` imports it).
"""

from __future__ import annotations

import time
from typing import Any

from ..errors import InvalidTypeError
from ..markov import switching_of
from ..problem import Problem, register_solver
from .allocation import after_solve
from .cegis import synthesize
from .escalation import closed_loop_fallback
from .markov_plan import after_switching
from .options import SolverOptions
from .results import SolveResult

__all__ = ["Problem", "solve"]


def solve(problem: Problem, options: SolverOptions | None = None, /, **overrides: Any) -> SolveResult:
    """Solve ``problem``: the CEGIS loop, then (joint chance constraints) the risk re-allocation,
    then (only plans below target under the default guarantee) a closed-loop solve.

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

    def first() -> SolveResult:
        result = synthesize(problem, opts, start)
        if getattr(problem, "_joint", False):  # joint chance constraints (allocation.py)
            result = after_solve(problem, opts, start, result, synthesize)
        return result

    # Under the default guarantee, a closed-loop solve when only plans below target were found.
    result = closed_loop_fallback(problem, opts, start, first, synthesize)
    if switching_of(problem.switched_system) is not None:  # chance switching (markov_plan.py)
        result = after_switching(problem, opts, result)
    return result


def _registered(problem: Problem, options: object | None, /, **overrides: Any) -> SolveResult:
    """:func:`solve` as :meth:`Problem.solve_result` calls it (any ``options``, checked here)."""
    if options is not None and not isinstance(options, SolverOptions):
        raise InvalidTypeError(f"options must be a SolverOptions, got {type(options).__name__}")
    return solve(problem, options, **overrides)


register_solver(_registered)  # Problem.solve / solve_result (see idstlpy.problem)
