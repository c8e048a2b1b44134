"""Planning under chance switching, the minimum honest version (issue 35).

A problem whose system carries a :class:`~idstlpy.markov.MarkovSwitching` is planned as today
for the commanded sequence (the planner does not see the jumps). Then, unless
``guarantee="mlo"``, the found plan's success is bounded over the executed mode sequences
(:func:`~idstlpy.executor.markov_bound.markov_bound`, with the planner's reading of the
execution: the true start drawn from the prior, inputs projected on the control domain), the
result's :attr:`~idstlpy.SolveResult.execution` becomes that bound's (``closure="markov"``: the
estimates and the bounds are over every sequence, the verified ones' and the sampled
remainder's: ``total_*_bound``), and the execution target is judged on the **bounds**: when
a bound is below its target the reason says so and an
:class:`~idstlpy.errors.ExecutionTargetWarning` is issued, even when the estimates meet it.
"""

from __future__ import annotations

import dataclasses
import logging
import warnings

from ..errors import ExecutionTargetWarning, IdstlpyError
from ..executor.markov_bound import MarkovBound, markov_bound
from ..problem import Problem
from .options import SolverOptions
from .predicted_execution import PredictedExecution
from .results import SolveResult

__all__ = ["after_switching", "execution_of"]

logger = logging.getLogger(__name__)


def execution_of(bound: MarkovBound, options: SolverOptions) -> PredictedExecution:
    """The bound as the result's predicted execution (``closure="markov"``)."""
    samples = len(bound.sequences)
    return PredictedExecution(
        bound.total_belief_estimate,
        bound.total_state_estimate,
        bound.total_belief_bound,
        bound.total_state_bound,
        {},
        options.execution_target,
        samples,
        "markov",
    )


def after_switching(problem: Problem, options: SolverOptions, result: SolveResult) -> SolveResult:
    """``result`` with its plan's bound under the problem's chance switching (module notes)."""
    plan = result.trajectory
    if plan is None or options.guarantee == "mlo":
        return result
    try:
        bound = markov_bound(problem, plan, real_initial_cov=problem.initial_state.cov)
    except IdstlpyError as exc:
        # (an unobserved executed mode, mode propositions: not bounded yet; say so, claim nothing)
        reason = f"{result.reason}; under chance switching: no bound ({exc})"
        return dataclasses.replace(result, reason=reason, execution=None)
    target = options.execution_target
    summary = (
        f"under chance switching: bound belief {bound.total_belief_bound:.4f}, state "
        f"{bound.total_state_bound:.4f} (confidence {bound.confidence:g}): "
        f"{len(bound.sequences)} executed mode sequences of mass {bound.covered_mass:.6f} verified "
        f"(bound belief {bound.belief_bound:.4f}, state {bound.state_bound:.4f}, nothing assumed of "
        f"the rest), the rest sampled ({bound.rest_runs} runs); estimates belief "
        f"{bound.total_belief_estimate:.4f}, state {bound.total_state_estimate:.4f}"
    )
    if not bound.meets(target.belief, target.state):
        summary += (
            f"; the bound does not prove the execution target ({target.belief:g} belief, "
            f"{target.state:g} state)"
        )
        # (at the caller of Problem.solve: pipeline.solve and its stage add two frames)
        warnings.warn(ExecutionTargetWarning(summary), stacklevel=6)
    if bound.note:
        summary += f"; {bound.note}"
    logger.info("%s", summary)
    return dataclasses.replace(
        result, reason=f"{result.reason}; {summary}", execution=execution_of(bound, options)
    )
