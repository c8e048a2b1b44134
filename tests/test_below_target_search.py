"""The search after a plan below target (``guarantee="execution"``): its convergence stop.

After the first verified plan below the execution target the loop searches on for a plan that
meets it; it stops when :data:`~idstlpy.synthesis.context.BELOW_TARGET_PATIENCE` plans in a row
set aside did not improve on the best one (counted in plans: deterministic for a seed).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.execution_target import ExecutionTarget
from idstlpy.synthesis import context as context_module
from idstlpy.synthesis.context import BELOW_TARGET_PATIENCE, TargetWatch, Verified
from idstlpy.synthesis.options import SolverOptions
from idstlpy.synthesis.predicted_execution import PredictedExecution
from idstlpy.synthesis.results import SolveStats


def _line() -> stl.Problem:
    """A 1-D integrator under process noise that must reach [3, 3.9] within 20 steps: no plan
    meets a 100% target, so every verified plan is set aside."""
    x = stl.mk_variable(1, float)
    u = stl.mk_variable(1, float)
    mode = stl.mk_lbs(A=[[1.0]], B=[[1.0]], W=[[0.1]])
    goal = stl.logical_and(stl.prob(x[0] >= 3.0) >= 0.9, stl.prob(x[0] <= 3.9) >= 0.9, name="goal")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.zeros(1), cov=0.01 * np.eye(1)),
        stl_formula=stl.eventually(0, 20, goal),
    )


def _plan(belief: float, state: float) -> Verified:
    """A verified plan (its trajectory is never read here) predicted at these rates."""
    target = ExecutionTarget(0.9, 0.95)
    return Verified(None, 1.0, None, PredictedExecution(belief, state, belief, state, {}, target))  # type: ignore[arg-type]


def _watch() -> TargetWatch:
    return TargetWatch(_line(), SolverOptions(), SolveStats())


def test_plans_that_do_not_improve_on_the_best_stop_the_search():
    watch = _watch()
    watch.set_aside(_plan(0.5, 0.9))  # the first: the best, the extra search starts
    assert watch.stale == 0 and watch.stop_reason(1) is None
    for i in range(BELOW_TARGET_PATIENCE - 1):
        watch.set_aside(_plan(0.4, 0.99))  # a larger shortfall (belief 50 points short)
        assert watch.stale == i + 1 and watch.stop_reason(2 + i) is None
    watch.set_aside(_plan(0.5, 0.9))  # as good as the best is no improvement either
    assert watch.stale == BELOW_TARGET_PATIENCE
    reason = watch.stop_reason(BELOW_TARGET_PATIENCE + 1)
    assert reason is not None and "converged" in reason
    assert watch.below is not None and watch.below.execution is not None
    assert watch.below.execution.belief_estimate == 0.5  # the first best is kept


def test_an_improvement_resets_the_count():
    watch = _watch()
    watch.set_aside(_plan(0.5, 0.9))
    for _ in range(BELOW_TARGET_PATIENCE - 1):
        watch.set_aside(_plan(0.3, 0.9))
    watch.set_aside(_plan(0.6, 0.9))  # 30 points short instead of 40: better
    assert watch.stale == 0 and watch.stop_reason(BELOW_TARGET_PATIENCE + 1) is None
    assert watch.below is not None and watch.below.execution is not None
    assert watch.below.execution.belief_estimate == 0.6


def test_no_stop_before_a_plan_is_set_aside():
    watch = _watch()
    assert watch.stop_reason(10**6) is None


def test_the_loop_stops_a_search_that_converged(monkeypatch: pytest.MonkeyPatch):
    problem = _line()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", stl.ExecutionTargetWarning)
        full = problem.solve_result(seed=0, execution_target=(1.0, 1.0), guarantee="execution")
        monkeypatch.setattr(context_module, "BELOW_TARGET_PATIENCE", 2)
        short = problem.solve_result(seed=0, execution_target=(1.0, 1.0), guarantee="execution")
        again = problem.solve_result(seed=0, execution_target=(1.0, 1.0), guarantee="execution")
    assert "converged" not in full.reason
    assert short.status == "found" and short.meets_target is False  # flagged, never silent
    assert "no better plan in the last 2 verified plans below target" in short.reason
    assert short.execution is not None and not short.execution.meets_target
    # the first plan set aside and two that did not improve on it (the closed-loop fallback's
    # solve sets none aside)
    assert short.stats.below_target == 3
    assert short.stats.candidates < full.stats.candidates
    assert again.reason == short.reason and again.stats.candidates == short.stats.candidates
