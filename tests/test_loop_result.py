"""The loop's result is built once, about the plan returned (synthesis/finish.py)."""

from __future__ import annotations

import warnings

from benchmarks.defaults_problems import drive_look

from idstlpy.errors import ExecutionTargetWarning


def test_an_optimised_plan_below_target_is_warned_about_once() -> None:
    # Under guarantee="mlo" the two-mode drive/look plan is below the execution target; with an
    # objective the first verified plan used to get a result (and a warning) of its own before
    # the optimised one was returned.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = drive_look().solve_result(seed=0, guarantee="mlo", objective="effort")
    assert result.status == "found" and result.meets_target is False
    assert result.objective == "effort" and result.objective_value > 0
    shortfalls = [w for w in caught if issubclass(w.category, ExecutionTargetWarning)]
    assert len(shortfalls) == 1
    assert f"{100 * result.execution.belief_estimate:.1f}%" in str(shortfalls[0].message)
