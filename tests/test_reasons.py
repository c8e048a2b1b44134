"""Every sentence of a reason is a claim with a test (issue 32, item 5)."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.synthesis.escalation import _below_target_advice
from idstlpy.synthesis.options import SolverOptions


def _line(goal: float, horizon: int = 40, noise: float = 0.0) -> stl.Problem:
    """A 1-D integrator with |u| <= 1 and an almost exact start: the goal ``[goal, goal + 1]``
    needs exactly ``ceil(goal)`` steps."""
    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float, name="u")
    mode = stl.mk_lbs(A=[[1.0]], B=[[1.0]], W=[[noise]])
    return stl.Problem(
        stl.mk_switched_sys([mode]),
        stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        stl.to_belief(np.zeros(1), 1e-6 * np.eye(1)),
        stl.eventually(
            0,
            horizon,
            stl.logical_and(stl.prob(x[0] >= goal) >= 0.9, stl.prob(x[0] <= goal + 1) >= 0.9, name="goal"),
        ),
    )


@pytest.mark.parametrize("lazy", [10, 0])  # the lazy loop, and the eager MILP at once
def test_max_plan_length_counts_the_plans_steps(lazy):
    """A plan of exactly L steps exists: max_plan_length = L finds it, L - 1 says no plan of at
    most L - 1 steps (and the horizon in steps)."""
    problem = _line(18.5)
    need = problem.solve_result(seed=0, guarantee="mlo").plan.num_of_steps
    assert need == 19
    found = problem.solve_result(seed=0, guarantee="mlo", max_plan_length=need, lazy_candidates=lazy)
    assert found.status == "found" and found.plan.num_of_steps <= need
    assert stl.satisfies(found.plan, problem.stl_formula)
    short = problem.solve_result(seed=0, guarantee="mlo", max_plan_length=need - 1, lazy_candidates=lazy)
    assert short.status == "budget_exhausted"
    assert f"no plan of at most max_plan_length = {need - 1} steps" in short.reason
    if lazy:
        assert "the formula's horizon allows 40" in short.reason
    assert f"raise max_plan_length (it was {need - 1}; try 40)" in short.reason


def _found(
    first_caps: list[str], second_caps: list[str], reason: str = "the search budget after a plan below target"
):
    result = _line(3.0).solve_result(seed=0, guarantee="mlo")
    first = dataclasses.replace(
        result, reason=reason, stats=dataclasses.replace(result.stats, caps_hit=list(first_caps))
    )
    second = dataclasses.replace(result, stats=dataclasses.replace(result.stats, caps_hit=list(second_caps)))
    return first, second


def test_more_time_is_advised_only_when_a_time_cap_decided():
    options = SolverOptions.make(time_limit=2400.0, seed=0)
    first, second = _found([], [])
    untimed = _below_target_advice(first, options, second).reason
    assert "more time" not in untimed and "time_limit=" not in untimed
    assert "no time cap decided" in untimed
    assert "compute_finite_horizon_lqr" in untimed  # the tracking gains
    assert "execution_target (it was" in untimed  # the target
    for caps in (["time_limit"], []):
        first, second = _found(caps, ["time_limit"] if not caps else [])
        timed = _below_target_advice(first, options, second).reason
        assert "more time may help (time_limit=9.6e+03)" in timed
        assert "compute_finite_horizon_lqr" not in timed


def test_candidates_are_the_lever_when_max_candidates_decided():
    options = SolverOptions.make(max_candidates=20, seed=0)
    first, second = _found([], [], reason="max_candidates = 20 reached after a plan below target")
    assert "raise max_candidates (it was 20; try 80)" in _below_target_advice(first, options, second).reason


def test_a_search_no_time_cap_decided_gives_the_same_answer_under_a_larger_time_limit():
    """The claim behind "a larger time_limit gives the same answer": work budgets decide."""
    problem = _line(30.0, horizon=60, noise=0.05)
    a = problem.solve_result(seed=0, max_candidates=3, time_limit=600)
    b = problem.solve_result(seed=0, max_candidates=3, time_limit=2400)
    assert not a.stats.caps_hit and not b.stats.caps_hit
    assert a.status == b.status == "budget_exhausted"
    assert (
        a.reason.replace("600", "").split("; to search")[0]
        == b.reason.replace("2400", "").split("; to search")[0]
    )
    assert a.stats.candidates == b.stats.candidates == 3


def _aside_counts(reason: str) -> dict[str, int]:
    inside = re.search(r"set aside without a proof \((.*?)\); \d+ candidates", reason)
    assert inside is not None, reason
    return {m.group(2): int(m.group(1)) for m in re.finditer(r"(\d+) ([^;]+)", inside.group(1))}


def test_candidates_given_up_are_counted_as_such():
    """A state-dependent sensor never good enough, no floor declared: the sampler gives up on every
    candidate; the reason says how many, and they are the abandoned of the statistics."""
    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float, name="u")
    mode = stl.mk_lbs(
        A=np.eye(1),
        B=np.eye(1),
        W=0.1 * np.eye(1),
        C=np.eye(1),
        V=lambda s: (0.5 + 0.2 * abs(float(s[0]) - 3)) * np.eye(1),
    )
    goal = stl.logical_and(stl.prob(x[0] >= 0.95) >= 0.99, stl.prob(x[0] <= 1.05) >= 0.99, name="tight")
    problem = stl.Problem(
        stl.mk_switched_sys([mode]),
        stl.logical_and(u[0] >= -1, u[0] <= 1).region,
        stl.to_belief(np.zeros(1), np.eye(1)),
        stl.eventually(0, 10, goal),
    )
    result = problem.solve_result(seed=0, sampler_iterations=50)
    assert result.status == "budget_exhausted"
    counts = _aside_counts(result.reason)
    assert counts == {"given up by a teacher": result.stats.abandoned}
    assert result.stats.refuted == 0


def test_the_dry_reason_names_what_set_each_candidate_aside():
    """Stats that say every candidate was refuted (the mode search refutes the modes it tried and
    sets the requirements aside) never read "given up by a teacher"."""
    import time

    from idstlpy.synthesis.context import ASIDE_WHY, SolveContext

    ctx = SolveContext(_line(3.0), SolverOptions.make(seed=0), time.perf_counter())
    ctx.set_aside("no modes")
    ctx.set_aside("no modes")
    reason = ctx.aside_reason()
    assert "2 refuted for the modes tried" in reason and "given up" not in reason
    ctx.set_aside("gave up")
    ctx.set_aside("below target")
    assert _aside_counts(reason_with_counts := ctx.aside_reason() + "; 4 candidates") == {
        "with a verified plan below the execution target": 1,
        "given up by a teacher": 1,
        ASIDE_WHY["no modes"]: 2,
    }, reason_with_counts
