"""``time_limit`` is kept on every path (issue 32, item 4): the mechanism, not the clock.

Each test makes the deadline pass at a chosen point (a scope already expired, a build that would
not fit) and checks that the next check stops the solve with the right status, reason and
statistics. The wall-clock overshoot itself is measured in ``benchmarks/time_limits.py``.
"""

from __future__ import annotations

import itertools
import time
from types import SimpleNamespace

import numpy as np
import pytest

import idstlpy as stl
from idstlpy import _deadline
from idstlpy.backends import LinearModel
from idstlpy.executor.predict import predict_closed_loop
from idstlpy.synthesis import context as context_module
from idstlpy.synthesis import proposer as proposer_module


def _line(goal: float, horizon: int = 20) -> stl.Problem:
    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float, name="u")
    mode = stl.mk_lbs(A=[[1.0]], B=[[1.0]], W=[[0.05]], C=[[1.0]], V=[[0.1]])
    return stl.Problem(
        stl.mk_switched_sys([mode]),
        stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        stl.to_belief(np.zeros(1), 0.01 * np.eye(1)),
        stl.eventually(
            0,
            horizon,
            stl.logical_and(stl.prob(x[0] >= goal) >= 0.9, stl.prob(x[0] <= goal + 1) >= 0.9, name="goal"),
        ),
    )


def test_check_is_a_no_op_outside_a_scope_and_raises_once_the_deadline_passed():
    _deadline.check("anywhere")  # no scope: nothing happens
    assert _deadline.remaining() == float("inf")
    with _deadline.scope(time.perf_counter() + 3600.0):
        _deadline.check("inside")  # an hour left
        with _deadline.scope(time.perf_counter() - 1.0), pytest.raises(_deadline.BudgetExceeded) as info:
            _deadline.check("the inner step")
        assert info.value.where == "the inner step"
        # a nested scope cannot extend the enclosing one
        with _deadline.scope(time.perf_counter() + 7200.0):
            assert _deadline.remaining() <= 3600.0
    _deadline.check("after")  # the scopes are gone


def test_the_prediction_stops_at_its_next_step_once_the_deadline_passed():
    problem = _line(3.0)
    plan = problem.solve_result(seed=0, guarantee="mlo").plan
    assert plan is not None
    full = predict_closed_loop(problem, plan, samples=50)  # no scope: runs to the end
    assert full.num_of_steps == plan.num_of_steps
    with _deadline.scope(time.perf_counter() - 1.0), pytest.raises(_deadline.BudgetExceeded) as info:
        predict_closed_loop(problem, plan, samples=50)
    assert info.value.where == "predicting a plan's execution"


def test_a_verified_plan_whose_prediction_the_deadline_stops_is_the_closest(monkeypatch):
    """The deadline passes while a verified plan's execution is predicted: the solve ends
    ``budget_exhausted`` at that step, says so, and shows the plan as ``result.closest``."""
    real = context_module.predict_closed_loop

    def late(*args, **kwargs):
        with _deadline.scope(time.perf_counter() - 1.0):  # the cap passes as the prediction starts
            return real(*args, **kwargs)

    monkeypatch.setattr(context_module, "predict_closed_loop", late)
    problem = _line(3.0)
    result = problem.solve_result(seed=0)
    assert result.status == "budget_exhausted"
    assert "reached during predicting a plan's execution" in result.reason
    assert "time_limit" in result.stats.caps_hit
    assert result.stats.predictions == 0
    closest = result.closest
    assert isinstance(closest, stl.ProbabilisticTSTrajectory)
    # the verified plan itself: it satisfies the formula under the paper's semantics
    assert stl.satisfies(closest, problem.stl_formula)


def test_a_report_the_deadline_stops_leaves_the_found_plan_without_a_prediction(monkeypatch):
    """Under ``guarantee="mlo"`` the found plan's execution is predicted only for the report: cut
    by the deadline, the result keeps the plan (its guarantee is the monitor's), reports no
    execution and says why."""
    real = context_module.predict_closed_loop

    def late(*args, **kwargs):
        with _deadline.scope(time.perf_counter() - 1.0):
            return real(*args, **kwargs)

    monkeypatch.setattr(context_module, "predict_closed_loop", late)
    problem = _line(3.0)
    result = problem.solve_result(seed=0, guarantee="mlo")
    assert result.status == "found" and result.plan is not None
    assert stl.satisfies(result.plan, problem.stl_formula)
    assert result.execution is None and result.meets_target is None
    assert "stopped the prediction of its execution: none is reported" in result.reason
    assert "time_limit" in result.stats.caps_hit


def test_an_encoding_that_would_not_fit_is_not_started(monkeypatch):
    """At the last build's pace the next unrolling would not fit in the time left: the solve
    stops before it (an a priori bound: a SAT solver takes its clauses at once)."""
    ticks = itertools.count(0.0, 1e6)  # every build seems to take 10^6 s
    monkeypatch.setattr(proposer_module, "time", SimpleNamespace(perf_counter=lambda: next(ticks)))
    result = _line(1e9, horizon=10**6).solve_result(seed=0, time_limit=60)
    assert result.status == "budget_exhausted"
    assert "nearly reached during the SAT encoding: its unrolling to" in result.reason
    assert "would not fit in the time left" in result.reason
    assert "time_limit" in result.stats.caps_hit
    assert result.stats.encoded_depth < 10**6


def test_scip_does_not_start_a_build_that_would_not_fit():
    pytest.importorskip("pyscipopt")
    from scipy.sparse import csr_matrix

    from idstlpy.backends_scip import ScipBackend

    model = LinearModel(
        np.array([1.0]),
        csr_matrix(np.array([[1.0]])),
        np.array([1.0]),
        np.array([np.inf]),
        np.array([0.0]),
        np.array([10.0]),
        np.array([1]),
    )
    backend = ScipBackend()
    assert backend.solve(model, 60.0).status == "optimal"
    backend._last = None  # a new model next
    backend._build_rate = 1.0  # one second per entry
    sol = backend.solve(model, 0.5)
    assert sol.status == "time_limit" and sol.x is None
    assert "not started" in sol.message
