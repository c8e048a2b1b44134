"""SolverOptions in groups, and one composable Termination (wall clock, work, first found)."""

from __future__ import annotations

import dataclasses
import pickle
import warnings
from typing import get_args

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.errors import InvalidArgumentError, InvalidTypeError
from idstlpy.synthesis.options import (
    GUARANTEES,
    OBJECTIVES,
    Guarantee,
    Objective,
    SolverOptions,
    Termination,
)


def _line(w: float = 0.0, top: float = 4.0) -> stl.Problem:
    """A 1-D integrator that must reach [3, top] within 20 steps (process noise ``w``)."""
    x = stl.mk_variable(1, float)
    u = stl.mk_variable(1, float)
    mode = stl.mk_lbs(A=[[1.0]], B=[[1.0]], W=[[w]])
    goal = stl.logical_and(stl.prob(x[0] >= 3.0) >= 0.9, stl.prob(x[0] <= top) >= 0.9, name="goal")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.zeros(1), cov=0.01 * np.eye(1)),
        stl_formula=stl.eventually(0, 20, goal),
    )


def _lit() -> stl.Problem:
    """The same with a sensor whose noise depends on the state (the sampler's problems)."""
    x = stl.mk_variable(1, float)
    u = stl.mk_variable(1, float)
    mode = stl.mk_lbs(
        A=[[1.0]], B=[[1.0]], W=[[0.0]], C=[[1.0]], V=lambda s: np.array([[0.1 + 0.1 * s[0] ** 2]])
    )
    goal = stl.logical_and(stl.prob(x[0] >= 3.0) >= 0.9, stl.prob(x[0] <= 4.0) >= 0.9, name="goal")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.zeros(1), cov=0.01 * np.eye(1)),
        stl_formula=stl.eventually(0, 20, goal),
    )


def _same(a: stl.SolveResult, b: stl.SolveResult) -> None:
    assert a.status == b.status and a.reason == b.reason
    assert (a.trajectory is None) == (b.trajectory is None)
    if a.trajectory is not None and b.trajectory is not None:
        np.testing.assert_array_equal(a.trajectory.get_action(), b.trajectory.get_action())
        np.testing.assert_array_equal(a.trajectory.get_control(), b.trajectory.get_control())
        np.testing.assert_array_equal(a.trajectory.get_mean(), b.trajectory.get_mean())


# -- the groups ------------------------------------------------------------------------------------


def test_each_group_holds_what_its_part_reads_from_the_flat_keywords():
    opts = SolverOptions(
        rrt_timeout=2.0,
        goal_bias=0.5,
        max_plan_length=30,
        lazy_candidates=3,
        objective="effort",
        effort_weights=[1.0, 2.0],
        guarantee="mlo",
        seed=7,
    )
    assert opts.sampler.rrt_timeout == 2.0 and opts.sampler.goal_bias == 0.5
    assert opts.sampler.iterations == opts.iterations_per_candidate == 500
    assert opts.search.max_plan_length == 30 and opts.search.seed == 7
    assert opts.search.sat_backend == opts.sat_backend and opts.search.lp_backend == opts.lp_backend
    assert opts.eager.lazy_candidates == 3 and opts.eager.milp_backend == opts.milp_backend
    assert opts.objectives.objective == "effort"
    np.testing.assert_array_equal(opts.objectives.weights, [1.0, 2.0])
    assert opts.target.guarantee == "mlo" and opts.target.execution_target == opts.execution_target
    for group in (opts.sampler, opts.search, opts.eager, opts.objectives, opts.target, opts.termination):
        assert dataclasses.is_dataclass(group)
        with pytest.raises(dataclasses.FrozenInstanceError):
            object.__getattribute__(group, "__setattr__")(dataclasses.fields(group)[0].name, None)


def test_groups_are_not_keywords_and_survive_copies_and_pickling():
    opts = SolverOptions(seed=1, max_candidates=5)
    assert {f.name for f in dataclasses.fields(SolverOptions)}.isdisjoint(
        {"sampler", "search", "eager", "objectives", "target", "termination"}
    )
    again = pickle.loads(pickle.dumps(opts))
    assert again == opts and again.termination == opts.termination
    changed = opts.with_(max_candidates=9)
    assert changed.termination.candidates == 9 and opts.termination.candidates == 5


def test_choices_are_literals():
    assert get_args(Objective) == OBJECTIVES == ("effort", "time", "margin")
    assert get_args(Guarantee) == GUARANTEES == ("execution", "mlo", "closed_loop")
    assert SolverOptions().guarantee == GUARANTEES[0]
    with pytest.raises(InvalidArgumentError, match="objective must be one of effort, time, margin"):
        SolverOptions(objective="speed")  # type: ignore[arg-type]


# -- Termination -----------------------------------------------------------------------------------


def test_termination_composes_with_or():
    t = Termination.time(60) | Termination.work(candidates=500)
    assert t == Termination(seconds=60.0, candidates=500)
    t = t | Termination.time(10) | Termination.work(candidates=900, lp_calls=40) | Termination.first()
    assert t == Termination(seconds=10.0, candidates=500, lp_calls=40, first_found=True)
    assert Termination() | Termination() == Termination()
    with pytest.raises(TypeError):
        Termination.time(1) | 3  # type: ignore[operator]


@pytest.mark.parametrize(
    ("make", "error", "match"),
    [
        (lambda: Termination.time(0), InvalidArgumentError, "seconds"),
        (lambda: Termination.time("1"), InvalidTypeError, "seconds"),
        (lambda: Termination.work(), InvalidArgumentError, "candidates or lp_calls"),
        (lambda: Termination.work(candidates=0), InvalidArgumentError, "candidates"),
        (lambda: Termination.work(lp_calls=1.5), InvalidArgumentError, "lp_calls"),
        (lambda: Termination(first_found=1), InvalidTypeError, "first_found"),
    ],
)
def test_termination_rejects_bad_limits(make, error, match):
    with pytest.raises(error, match=match):
        make()


def test_options_termination_is_built_from_the_keywords():
    opts = SolverOptions(rrt_timeout=3.0)
    assert opts.termination == Termination(seconds=30.0)  # the default clock: 10 * rrt_timeout
    opts = SolverOptions(time_limit=5, max_candidates=7, max_lp_calls=11, first_found=True)
    assert opts.termination == Termination(5.0, 7, 11, True)
    assert opts.total_time_cap == 5.0


def test_termination_keyword_stands_for_four_keywords():
    t = Termination.time(60) | Termination.work(candidates=500)
    opts = SolverOptions.make(termination=t, seed=0)
    assert (opts.time_limit, opts.max_candidates, opts.max_lp_calls, opts.first_found) == (
        60.0,
        500,
        None,
        False,
    )
    assert opts.termination == t
    # with_ replaces all four: an unset clock falls back to 10 * rrt_timeout
    later = opts.with_(termination=Termination.work(lp_calls=3))
    assert later.termination == Termination(seconds=600.0, lp_calls=3)
    with pytest.raises(InvalidArgumentError, match="not both"):
        SolverOptions.make(termination=t, max_candidates=3)
    with pytest.raises(InvalidTypeError, match="termination must be a Termination"):
        SolverOptions.make(termination=60)


def test_each_condition_stops_a_solve():
    problem = _line()
    # the wall clock (a safety cap: the result says it decided)
    clock = problem.solve_result(seed=0, termination=Termination.time(1e-4))
    assert clock.status == "budget_exhausted" and "time limit of 0.0001 s" in clock.reason
    assert "time_limit" in clock.stats.caps_hit
    # work: candidates
    cands = problem.solve_result(seed=0, termination=Termination.work(candidates=2))
    assert cands.status == "budget_exhausted" and cands.stats.candidates == 2
    assert cands.reason.startswith("max_candidates = 2 reached")
    # work: LP calls
    lps = problem.solve_result(seed=0, termination=Termination.work(lp_calls=2))
    assert lps.status == "budget_exhausted" and lps.stats.lp_calls == 2
    assert lps.reason.startswith("max_lp_calls = 2 reached")
    assert "raise max_lp_calls (it was 2; try 8)" in lps.reason
    # composed: the first condition to hold decides
    both = problem.solve_result(
        seed=0, termination=Termination.work(candidates=3) | Termination.work(lp_calls=1)
    )
    assert both.reason.startswith("max_lp_calls = 1 reached") and both.stats.candidates == 1
    assert not cands.stats.caps_hit and not lps.stats.caps_hit and not both.stats.caps_hit


def test_first_found_stops_at_the_first_verified_plan_below_target():
    problem = _line(w=0.1, top=3.9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", stl.ExecutionTargetWarning)
        full = problem.solve_result(seed=0, execution_target=(1.0, 1.0))
        first = problem.solve_result(seed=0, execution_target=(1.0, 1.0), termination=Termination.first())
    assert full.status == first.status == "found"
    assert first.meets_target is False and first.stats.below_target == 1
    assert "first_found after a plan below target" in first.reason
    assert first.stats.candidates < full.stats.candidates


def test_first_found_skips_the_objectives_refinement():
    problem = _lit()
    full = problem.solve_result(seed=0, objective="effort")
    first = problem.solve_result(seed=0, objective="effort", first_found=True)
    assert full.status == first.status == "found"
    assert len(full.stats.improvements) > len(first.stats.improvements) == 1
    assert first.objective_value >= full.objective_value
    assert not first.optimal


def test_same_seed_same_result_under_a_composed_termination():
    problem = _line(w=0.1, top=3.9)
    stop = Termination.time(600) | Termination.work(candidates=6, lp_calls=1000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", stl.ExecutionTargetWarning)
        a = problem.solve_result(seed=3, execution_target=(1.0, 1.0), termination=stop)
        b = problem.solve_result(seed=3, execution_target=(1.0, 1.0), termination=stop)
        # the termination is the keywords it stands for: the same solve
        c = problem.solve_result(
            seed=3, execution_target=(1.0, 1.0), time_limit=600, max_candidates=6, max_lp_calls=1000
        )
    _same(a, b)
    _same(a, c)
    assert "max_candidates = 6 reached" in a.reason
