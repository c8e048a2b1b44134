"""The default guarantee's last resort: a closed-loop solve when only plans below target were found.

Under ``guarantee="execution"`` the search plans under the maximum-likelihood observation (the
paper's reading), predicts each verified plan's execution and repairs or sets aside the plans
below the execution target. When the search ends with only such plans, the MLO model was the
wrong one to plan with: a plan that holds needs the execution's own spread in its constraints.
``guarantee="closed_loop"`` plans against exactly that (the predicted true state), so one
closed-loop solve, in the time left of the same cap and with the same seed, is tried before a
below-target plan is returned.

Its plan is returned only when it keeps every promise of the default: it satisfies the formula
under the paper's semantics (re-checked here by the monitor on the MLO belief trajectory) *and*
its predicted execution meets the target. Otherwise the first answer stands, warnings included.
"""

from __future__ import annotations

import dataclasses
import logging
import time
import warnings
from collections.abc import Callable
from typing import TYPE_CHECKING

from ..errors import ExecutionTargetWarning
from ..semantics import robustness
from .options import SolverOptions
from .results import SolveResult, SolveStats
from .termination import CANCELLED

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = ["closed_loop_fallback"]

logger = logging.getLogger(__name__)

_MAXIMA = ("bmc_depth", "encoded_depth")  # statistics that are a maximum, not a count


def _combined(first: SolveStats, second: SolveStats) -> SolveStats:
    """The work of both solves in one record (counts and times add, depths take the maximum)."""
    out = dataclasses.replace(second)
    for f in dataclasses.fields(SolveStats):
        a, b = getattr(first, f.name), getattr(second, f.name)
        if f.name in _MAXIMA:
            setattr(out, f.name, max(a, b))
        elif f.name == "time_total" or f.name == "execution_room":
            continue  # the second solve's clock counts from the same start; its plan's room
        elif isinstance(a, list):
            setattr(out, f.name, [*a, *(x for x in b if x not in a)] if f.name == "caps_hit" else [*a, *b])
        elif isinstance(a, int | float) and not isinstance(a, bool):
            setattr(out, f.name, a + b)
    return out


def _reissue(caught: list[warnings.WarningMessage], keep_target_warning: bool) -> None:
    """Issue the held warnings again; of the execution-target warnings only the last, the one
    about the plan returned (a joint-constraint re-solve may have replaced an earlier plan)."""
    target = [i for i, w in enumerate(caught) if issubclass(w.category, ExecutionTargetWarning)]
    keep = target[-1:] if keep_target_warning else []
    for i, w in enumerate(caught):
        if i in target and i not in keep:
            continue
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)


def _below_target_advice(
    first: SolveResult, options: SolverOptions, second: SolveResult | None
) -> SolveResult:
    """Say what was tried, and name the lever that decided, when the plan returned is below target.

    Time only when a time cap decided (``caps_hit``): a search its work budgets ended is the same
    search under any time limit, so the levers left are the ones that change what is searched
    for (the candidates it may try, the tracking gains the prediction reads, the target).
    """
    if second is not None:
        outcome = "a plan below target too" if second.status == "found" else second.status
        tip = f"a closed-loop solve (guarantee='closed_loop') in the time left ended {outcome}"
        timed = "time_limit" in first.stats.caps_hit or "time_limit" in second.stats.caps_hit
        if timed:
            more = 4 * options.total_time_cap
            tip += f"; the time limit stopped a search: more time may help (time_limit={more:.3g})"
        else:
            tip += "; " + _untimed_levers(first, options)
    else:
        tip = (
            f"no time was left for a closed-loop solve: try time_limit={4 * options.total_time_cap:.3g} "
            "or guarantee='closed_loop'"
        )
    return dataclasses.replace(first, reason=f"{first.reason}; {tip}")


def _untimed_levers(first: SolveResult, options: SolverOptions) -> str:
    """The levers of a below-target answer no time cap decided (its work budgets did)."""
    levers = []
    cands = options.termination.candidates
    if cands is not None and f"max_candidates = {cands} reached" in first.reason:
        levers.append(f"raise max_candidates (it was {cands}; try {4 * cands})")
    levers.append(
        "stronger tracking (each mode's compute_finite_horizon_lqr(...) before solving: the "
        "predicted spread of the executions is the tracking's)"
    )
    target = options.execution_target
    levers.append(f"a lower execution_target (it was {target})")
    return (
        "both searches ended by themselves (no time cap decided: a larger time_limit gives the "
        f"same answer); to get a plan that meets the target: {'; or '.join(levers)}"
    )


def closed_loop_fallback(
    problem: Problem,
    options: SolverOptions,
    start: float,
    first: SolveResult,
    held: list[warnings.WarningMessage],
    synthesize: Callable[[Problem, SolverOptions, float], SolveResult],
) -> SolveResult:
    """When the default guarantee could only return a plan below target, try one closed-loop
    solve in the time left (the pipeline's last stage, :mod:`.pipeline`).

    Parameters
    ----------
    problem : Problem
    options : SolverOptions
        The options of the solve (``guarantee="execution"``, not ``first_found``: the pipeline
        runs this stage only then).
    start : float
        ``time.perf_counter()`` at the first line of ``solve``: both solves share one time cap.
    first : SolveResult
        The answer of the stages before.
    held : list of warnings.WarningMessage
        The warnings those stages issued, held until the answer is known and issued again here.
    synthesize : callable (problem, options, start) -> SolveResult
        The solver (:func:`.pipeline.core`), called with ``guarantee="closed_loop"``.

    Returns
    -------
    SolveResult
        The closed-loop plan when it satisfies the formula under the paper's semantics and meets
        the execution target; the first result otherwise. Its statistics count both solves.
    """
    caught = held
    below = first.status == "found" and first.meets_target is False
    left = options.total_time_cap - (time.perf_counter() - start)
    if not below or CANCELLED in first.stats.caps_hit:  # a cancelled solve starts no other
        _reissue(caught, keep_target_warning=True)
        return first
    if left <= 0:
        _reissue(caught, keep_target_warning=True)
        return _below_target_advice(first, options, None)
    logger.info("execution guarantee: only plans below target; trying guarantee='closed_loop'")
    with warnings.catch_warnings(record=True) as caught_second:
        warnings.simplefilter("always")
        second = synthesize(problem, options.with_(guarantee="closed_loop"), start)
    holds = (
        second.status == "found"
        and second.trajectory is not None
        and second.meets_target is True
        and robustness(second.trajectory, problem.stl_formula) >= 0.0
    )
    if not holds:
        _reissue(caught, keep_target_warning=True)
        logger.info("closed-loop fallback: %s; the first plan stands", second.reason)
        return dataclasses.replace(
            _below_target_advice(first, options, second), stats=_combined(first.stats, second.stats)
        )
    _reissue(caught, keep_target_warning=False)
    _reissue(caught_second, keep_target_warning=True)
    reason = (
        f"{second.reason}; planned against the predicted execution (guarantee='closed_loop') after "
        f"the MLO search found only plans below the execution target (best: {first.reason})"
    )
    return dataclasses.replace(second, reason=reason, stats=_combined(first.stats, second.stats))
