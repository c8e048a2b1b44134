"""Issue 34: smooth default plans, and objectives that keep the execution target."""

from __future__ import annotations

import warnings

import numpy as np
from benchmarks import defaults_problems as dp
from benchmarks import plant_family as pf
from hypothesis import given, settings
from hypothesis import strategies as st

import idstlpy as stl
from idstlpy.synthesis.objectives import total_variation


def _solve(problem: stl.Problem, **kw: object) -> stl.SolveResult:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return problem.solve_result(seed=0, time_limit=60, **kw)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 12), st.integers(1, 3), st.integers(0, 2**31 - 1))
def test_total_variation_is_the_sum_of_absolute_input_changes(K, m, seed):
    u = np.random.default_rng(seed).normal(size=(K, m))
    w = np.random.default_rng(seed + 1).uniform(0.1, 2.0, size=m)
    expected = sum(abs(u[k + 1, j] - u[k, j]) * w[j] for k in range(K - 1) for j in range(m))
    assert abs(total_variation(u, w) - expected) <= 1e-12 * max(1.0, expected)
    assert total_variation(u[:1], w) == 0.0


def test_the_default_plan_is_smoother_and_holds_as_well():
    # a fast DC motor: the first plan LP's plan is bang-bang (TV ~97 V over 12 steps)
    smooth, first = _solve(pf.PLANTS["dc_motor_fast"]()), _solve(pf.PLANTS["dc_motor_fast"](), smooth=False)
    assert smooth.found and first.found
    assert smooth.meets_target and first.meets_target
    tv_smooth = total_variation(smooth.trajectory.get_control())
    tv_first = total_variation(first.trajectory.get_control())
    assert tv_smooth <= 0.5 * tv_first
    # the smoothed plan is a verified plan: the monitor accepts its exact re-roll, inputs in range
    problem = pf.PLANTS["dc_motor_fast"]()
    again = stl.rollout(
        problem.switched_system,
        problem.initial_state,
        smooth.trajectory.get_action(),
        smooth.trajectory.get_control(),
    )
    assert stl.robustness(again, problem.stl_formula) >= 0
    assert np.all(np.abs(smooth.trajectory.get_control()) <= 12.0 + 1e-6)


def test_smoothing_is_skipped_under_first_found():
    a = _solve(pf.PLANTS["dc_motor_fast"](), first_found=True)
    b = _solve(pf.PLANTS["dc_motor_fast"](), smooth=False)
    np.testing.assert_array_equal(a.trajectory.get_control(), b.trajectory.get_control())


def test_objectives_keep_the_target_the_default_plan_meets():
    default = _solve(dp.PROBLEMS["drive_look"]())
    assert default.found and default.meets_target
    for objective in ("effort", "margin", "time"):
        result = _solve(dp.PROBLEMS["drive_look"](), objective=objective)
        assert result.found, objective
        assert result.meets_target, (objective, result.reason)
        assert not result.optimal or np.isfinite(result.objective_bound)
