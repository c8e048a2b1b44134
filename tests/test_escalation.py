"""The default guarantee's closed-loop fallback (synthesis/escalation.py).

A new user's drive/look robot (joint boxes, process noise). With the mode search reading only the
paper's MLO semantics, the search finds only plans that hold in about a quarter of executions;
the fallback plans against the predicted execution and must return a plan that (1) satisfies the
formula under the paper's semantics (independent re-roll and monitor), (2) is predicted to meet
the target, and (3) does so in a Monte Carlo. The default's mode search now reads the execution
(synthesis/mode_search.py) and finds such a plan itself (tested below); the fallback is exercised
by switching that reading off, as for a problem where the search cannot find one.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.execution.validation import wilson_interval
from idstlpy.synthesis import eager


def _drive_look() -> stl.Problem:
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float)
    eye = np.identity(2)
    drive = stl.mk_lbs(A=eye, B=0.5 * eye, W=0.05 * eye, C=eye, V=0.6 * eye)
    look = stl.mk_lbs(A=eye, B=np.zeros((2, 2)), W=0.05 * eye, C=eye, V=0.02 * eye)
    box = stl.logical_and
    safe = box(stl.prob_in(box(x[0] >= -1, x[0] <= 6, x[1] >= -1, x[1] <= 6)) >= 0.99, name="safe")
    goal = box(stl.prob_in(box(x[0] >= 4, x[0] <= 5, x[1] >= 4, x[1] <= 5)) >= 0.95, name="goal")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([drive, look]),
        control_domain=box(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region,
        initial_state=stl.to_belief(mean=np.zeros(2), cov=np.diag([0.1, 0.1])),
        stl_formula=stl.until(safe, 0, 30, goal),
    )


def holds_when_executed(problem: stl.Problem, result) -> None:
    """300 executions on the real plant (the modes without noise models: the planning model's
    noise): both readings reach the target within the Wilson interval, and the prediction the
    result carries agrees with the Monte Carlo."""
    real = stl.mk_switched_sys(
        [stl.mk_lcs(A=np.eye(2), B=0.5 * np.eye(2)), stl.mk_lcs(A=np.eye(2), B=np.zeros((2, 2)))]
    )
    report = stl.validate(problem, result.trajectory, real, runs=300, seed=1)
    b_lo, b_hi = wilson_interval(round(report.belief_success_rate * 300), 300)
    s_lo, s_hi = wilson_interval(round(report.state_success_rate * 300), 300)
    assert b_hi >= 0.90 and s_hi >= 0.95, report.summary()
    assert b_lo - 0.03 <= result.execution.belief_estimate <= b_hi + 0.03
    assert s_lo - 0.03 <= result.execution.state_estimate <= s_hi + 0.03


@pytest.fixture(scope="module")
def solved():
    from idstlpy.synthesis.teacher import LPTeacher

    problem = _drive_look()
    init = LPTeacher.__init__

    def mlo_search(self, *args, **kwargs):  # the mode search of the paper's reading only
        init(self, *args, **kwargs)
        self.reads_execution = False

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(LPTeacher, "__init__", mlo_search)
        # the joint MILP (issue 31) now finds this plan meeting the target; the fixture is the
        # lazy loop alone, whose plan misses it, so the fallback is what is tested
        patch.setattr(eager, "JOINT_MODES", False)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = problem.solve_result(seed=0)
    return problem, result, caught


def test_the_default_search_finds_a_plan_that_holds_without_the_fallback():
    problem = _drive_look()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = problem.solve_result(seed=0)
    assert result.status == "found" and result.meets_target is True, result.reason
    assert "guarantee='closed_loop'" not in result.reason
    assert result.stats.candidates <= 50
    assert not [w for w in caught if issubclass(w.category, stl.ExecutionTargetWarning)]
    holds_when_executed(problem, result)


def test_the_fallback_returns_a_plan_that_keeps_every_promise(solved):
    problem, result, caught = solved
    assert result.status == "found", result.reason
    assert result.meets_target is True
    assert "guarantee='closed_loop'" in result.reason and "below the execution target" in result.reason
    # The paper's semantics, re-checked independently of the solver's own check.
    plan = result.trajectory
    again = stl.rollout(problem.switched_system, problem.initial_state, plan.get_action(), plan.get_control())
    np.testing.assert_allclose(again.get_mean(), plan.get_mean(), atol=1e-9)
    assert stl.satisfies(again, problem.stl_formula)
    # ... and by the independent oracles: their own Kalman roll-out, and the goal box's exact
    # probability at the plan's last belief (the covariance stays diagonal here: isotropic modes).
    from oracles.joint import box_probability
    from oracles.rollout import ModeSpec, mlo_rollout

    specs = [ModeSpec(md.A, md.B, md.W, md.C, md.noise) for md in problem.switched_system.system_modes]
    trace = mlo_rollout(
        specs, problem.initial_state.mean, problem.initial_state.cov, plan.get_action(), plan.get_control()
    )
    np.testing.assert_allclose([m for m, _ in trace.states], plan.get_mean(), atol=1e-9)
    mean, cov = trace.states[-1]
    assert abs(cov[0, 1]) < 1e-12
    assert box_probability(np.array([4.0, 4.0]), np.array([5.0, 5.0]), mean, np.diag(cov)) >= 0.95
    # No warning that the plan falls short: it does not.
    assert not [w for w in caught if issubclass(w.category, stl.ExecutionTargetWarning)]


def test_the_fallback_counts_both_solves(solved):
    _, result, _ = solved
    # The MLO search alone set aside 200+ candidates below target before the fallback ran.
    assert result.stats.below_target >= 1
    assert result.stats.candidates > 200


def test_the_fallback_plan_holds_when_executed(solved):
    problem, result, _ = solved
    holds_when_executed(problem, result)


def test_mlo_and_closed_loop_never_fall_back():
    problem = _drive_look()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", stl.ExecutionTargetWarning)
        mlo = problem.solve_result(seed=0, guarantee="mlo")
    assert mlo.guarantee == "mlo" and "guarantee='closed_loop'" not in mlo.reason


def test_a_plan_left_below_target_warns_once_and_says_what_was_tried(monkeypatch):
    from benchmarks.defaults_problems import drive_look_noisy

    problem = drive_look_noisy()
    # the joint MILP (issue 31) meets the target here (97.7% / 99.6% predicted); without it the
    # lazy loop's plan falls short, which is the case this test is about
    monkeypatch.setattr(eager, "JOINT_MODES", False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = problem.solve_result(seed=0, time_limit=30)
    assert result.status == "found" and result.meets_target is False
    target = [w for w in caught if issubclass(w.category, stl.ExecutionTargetWarning)]
    assert len(target) == 1
    assert "guarantee='closed_loop'" in result.reason
