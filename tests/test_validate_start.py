"""validate measures the promise: true starts drawn from the prior by default, a fixed start on
request, and a verdict against the execution target (issue 23)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from tests.test_validate import detour_plan

import idstlpy as stl
from idstlpy.errors import InvalidArgumentError, InvalidTypeError
from idstlpy.execution import validate
from idstlpy.execution.validation import prior_starts
from idstlpy.execution_target import ExecutionTarget
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system


@pytest.fixture(scope="module")
def case():
    problem = light_dark(deadline=60, hold=40)
    return problem, detour_plan(problem)


def reach_problem():
    """A perfect sensor, no process noise: goal ``0.9 <= x_0 <= 1.1`` within 10 steps."""
    system = stl.mk_switched_sys(
        [stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=np.zeros((2, 2)), C=np.eye(2))]
    )
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    goal = stl.logical_and(stl.prob(x[0] >= 0.9) >= 0.95, stl.prob(x[0] <= 1.1) >= 0.95, name="goal")
    problem = stl.Problem(
        switched_system=system,
        control_domain=stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region,
        initial_state=stl.to_belief([0.0, 0.0], 0.01 * np.eye(2)),
        stl_formula=stl.eventually(0, 10, goal),
    )
    plan = stl.rollout(system, problem.initial_state, np.zeros(4, dtype=int), np.tile([1.0, 0.0], (4, 1)))
    return problem, plan, system


def test_default_draws_the_true_start_from_the_prior(case):
    problem, plan = case
    real = light_dark_real_system()
    report = validate(problem, plan, real, runs=6, seed=4, executor="serial", keep_trajectories=6)
    assert report.true_start is None and report.start_drawn
    assert report.true_start_text == "drawn from the prior"
    starts = np.array([xi_real.get_state()[0] for _, xi_real in report.executions])
    np.testing.assert_array_equal(starts, prior_starts(plan, 6, 4))
    assert len({tuple(s) for s in starts}) == 6  # every run its own start
    # "prior" says the same; the same seed gives the same report
    assert validate(problem, plan, real, "prior", runs=6, seed=4, executor="serial") == report
    # the report says which, everywhere
    data = report.as_dict()
    assert data["true_start"] == "prior"
    json.dumps(data)
    assert "true start: drawn from the prior" in report.summary()
    assert "drawn from the prior" in repr(report) and "drawn from the prior" in report._repr_html_()


def test_a_fixed_start_stays_available_and_is_reported(case):
    problem, plan = case
    report = validate(
        problem,
        plan,
        light_dark_real_system(),
        LIGHT_DARK_REAL_INITIAL_STATE,
        runs=3,
        seed=1,
        executor="serial",
    )
    assert report.true_start == (0.5, 2.75) and not report.start_drawn
    assert report.true_start_text == "fixed at [0.5, 2.75]"
    assert report.as_dict()["true_start"] == [0.5, 2.75]
    assert "true start: fixed at [0.5, 2.75]" in report.summary()


def test_a_drawn_start_keeps_the_runs_noise(case):
    """Run i with a drawn start is run i of a fixed-start validation from that same start."""
    problem, plan = case
    real = light_dark_real_system()
    drawn = validate(problem, plan, real, runs=3, seed=9, executor="serial", keep_trajectories=3)
    x0 = prior_starts(plan, 3, 9)[0]
    fixed = validate(problem, plan, real, x0, runs=1, seed=9, executor="serial", keep_trajectories=1)
    (b_d, r_d), (b_f, r_f) = drawn.executions[0], fixed.executions[0]
    np.testing.assert_array_equal(r_d.get_state(), r_f.get_state())
    np.testing.assert_array_equal(b_d.get_mean(), b_f.get_mean())
    assert drawn.belief_margins[0] == fixed.belief_margins[0]


def test_prior_starts_follow_the_prior(case):
    _, plan = case
    starts = prior_starts(plan, 20000, 0)
    mean, cov = plan.get_mean(0), plan.get_cov(0)
    np.testing.assert_allclose(starts.mean(axis=0), mean, atol=4 * np.sqrt(cov.diagonal().max() / 20000))
    np.testing.assert_allclose(np.cov(starts.T), cov, atol=0.05 * cov.diagonal().max())
    # the first rows do not depend on how many are drawn
    np.testing.assert_array_equal(prior_starts(plan, 5, 0), starts[:5])


def test_prior_starts_of_a_singular_prior():
    problem, plan, _ = reach_problem()
    singular = stl.rollout(
        problem.switched_system,
        stl.to_belief([1.0, 2.0], np.array([[1.0, 1.0], [1.0, 1.0]])),
        np.zeros(1, dtype=int),
        np.zeros((1, 2)),
    )
    starts = prior_starts(singular, 50, 3)
    np.testing.assert_allclose(starts[:, 0] - starts[:, 1], -1.0, atol=1e-12)  # on the prior's line


def test_predict_uses_the_prior_when_the_start_is_drawn(case):
    problem, plan = case
    real = light_dark_real_system()
    drawn = validate(
        problem, plan, real, runs=2, seed=0, executor="serial", predict=True, predict_options={"samples": 200}
    )
    fixed = validate(
        problem,
        plan,
        real,
        plan.get_mean(0),
        runs=2,
        seed=0,
        executor="serial",
        predict=True,
        predict_options={"samples": 200},
    )
    # a random start spreads the predicted true state at step 0; a fixed one does not
    assert drawn.predicted is not None and fixed.predicted is not None
    assert np.trace(drawn.predicted.state_cov[0]) > 0.0
    assert np.trace(fixed.predicted.state_cov[0]) == pytest.approx(0.0, abs=1e-12)


def test_verdict_against_the_default_and_a_given_target():
    problem, plan, system = reach_problem()
    ok = validate(problem, plan, system, [0.0, 0.0], runs=5, seed=0, executor="serial")
    assert ok.execution_target == ExecutionTarget(0.90, 0.95)
    assert ok.meets_target and ok.verdict().startswith("meets the target (90% belief / 95% true state)")
    data = ok.as_dict()
    assert data["execution_target"] == {"belief": 0.9, "state": 0.95}
    assert data["meets_target"] is True and data["verdict"] == ok.verdict()
    assert "verdict: meets the target" in ok.summary()
    # far from the goal with clipped inputs: no run makes it
    far = validate(
        problem, plan, system, [-5.0, 0.0], runs=4, seed=0, executor="serial", execution_target=(0.5, 0.6)
    )
    assert far.state_success_rate == 0.0
    assert far.execution_target == ExecutionTarget(0.5, 0.6)
    assert not far.meets_target
    assert far.verdict().startswith("BELOW the target (50% belief / 60% true state)")
    assert "true state 0.0% < 60%" in far.verdict()
    assert far.as_dict()["meets_target"] is False


def test_bad_start_and_target_name_the_argument(case):
    problem, plan = case
    real = light_dark_real_system()
    with pytest.raises(InvalidArgumentError, match="real_initial_state"):
        validate(problem, plan, real, "posterior", runs=1, executor="serial")
    with pytest.raises(InvalidArgumentError, match="real_initial_state"):
        validate(problem, plan, real, [0.0, 1.0, 2.0], runs=1, executor="serial")
    with pytest.raises(InvalidArgumentError, match="execution_target"):
        validate(problem, plan, real, runs=1, executor="serial", execution_target=(0.9, 1.5))
    with pytest.raises(InvalidTypeError, match="execution_target"):
        validate(problem, plan, real, runs=1, executor="serial", execution_target=0.9)
