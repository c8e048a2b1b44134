"""Monte Carlo validation: rates, confidence intervals, determinism across executors, the bar."""

from __future__ import annotations

import functools
import json
import logging
import pickle
import sys
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.errors import InvalidArgumentError, InvalidTypeError
from idstlpy.execution import ValidationReport, validate, wilson_interval
from idstlpy.scenarios import (
    LIGHT_DARK_REAL_INITIAL_STATE,
    light_dark,
    light_dark_noise,
    light_dark_real_system,
)


def detour_plan(problem):
    """A hand-made light-dark plan: into the light, back to the target, hold (no solver needed)."""
    right = np.tile([1.0, 0.0], (18, 1))  # to x ~ 4.5, where the sensor is good
    back = np.tile([-1.0, -2.5 / 4.5], (18, 1))  # to the origin
    hold = np.zeros((46, 2))
    controls = np.vstack([right, back, hold])
    plan = stl.rollout(
        problem.switched_system, problem.initial_state, np.zeros(len(controls), dtype=int), controls
    )
    assert stl.satisfies(plan, problem.stl_formula)
    return plan


@pytest.fixture(scope="module")
def light_dark_case():
    problem = light_dark(deadline=60, hold=40)
    return problem, detour_plan(problem)


def test_wilson_interval_known_values():
    lo, hi = wilson_interval(5, 10)
    assert lo == pytest.approx(0.2366, abs=1e-4) and hi == pytest.approx(0.7634, abs=1e-4)
    assert wilson_interval(0, 10) == (0.0, pytest.approx(0.2775, abs=1e-4))
    assert wilson_interval(10, 10) == (pytest.approx(0.7225, abs=1e-4), 1.0)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    with pytest.raises(InvalidArgumentError, match="successes must be <= trials"):
        wilson_interval(3, 2)


def test_same_seed_same_report_for_any_executor(light_dark_case):
    problem, plan = light_dark_case
    real = light_dark_real_system()
    args = (problem, plan, real, LIGHT_DARK_REAL_INITIAL_STATE)
    serial = validate(*args, runs=12, seed=5, executor="serial")
    with ThreadPoolExecutor(2) as pool:
        threaded = validate(*args, runs=12, seed=5, executor=pool)
    with ProcessPoolExecutor(2) as procs:  # (cloudpickle or factory)
        processes = validate(*args, runs=12, seed=5, executor=procs)
    default = validate(*args, runs=12, seed=5)  # few batched runs: in-process
    assert serial == threaded == processes == default
    other = validate(*args, runs=12, seed=6, executor="serial")
    assert other.belief_margins != serial.belief_margins
    assert isinstance(serial, ValidationReport) and serial.runs == 12
    assert 0.0 <= serial.belief_success_rate <= 1.0
    assert serial.belief_ci[0] <= serial.belief_success_rate <= serial.belief_ci[1]
    json.dumps(serial.as_dict())  # plain data
    assert set(serial.proposition_violations) == {"free_space", "target"}
    assert len(serial.predicate_violations) == 8


def test_factory_path_when_nothing_can_pickle_the_problem(light_dark_case, monkeypatch, caplog):
    problem, plan = light_dark_case
    # The listing's form: a lambda noise, which plain pickle refuses (scenarios.light_dark pickles).
    mode = problem.switched_system.mode(0)
    listing = stl.Problem(
        stl.mk_switched_sys(
            [stl.mk_lbs(A=mode.A, B=mode.B, W=np.zeros((2, 2)), C=mode.C, V=lambda s: light_dark_noise(s))]
        ),
        problem.control_domain,
        problem.initial_state,
        problem.stl_formula,
    )
    with pytest.raises(Exception, match="lambda"):
        pickle.dumps(listing)
    pickle.dumps(problem)
    monkeypatch.setitem(sys.modules, "cloudpickle", None)  # import cloudpickle -> ImportError
    args = (listing, plan, light_dark_real_system(), LIGHT_DARK_REAL_INITIAL_STATE)
    log = caplog.at_level(logging.DEBUG, logger="idstlpy.execution.validation")
    with log, ProcessPoolExecutor(2) as pool:
        factory = validate(
            *args, runs=4, seed=1, executor=pool, problem_factory=functools.partial(light_dark, 60, 40)
        )
        fallback = validate(*args, runs=4, seed=1, executor=pool)  # no factory: runs in-process
    assert "problem not picklable and no problem_factory: running in-process" in caplog.text
    assert factory == fallback == validate(*args, runs=4, seed=1, executor="serial")


def test_noise_free_execution_succeeds_in_belief_and_state():
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
    assert stl.satisfies(plan, problem.stl_formula)
    report = validate(
        problem, plan, system, [0.0, 0.0], runs=5, seed=0, executor="serial", keep_trajectories=2
    )
    assert report.belief_success_rate == 1.0 and report.state_success_rate == 1.0
    assert report.proposition_violations["goal"]["belief"] == 0.0
    assert len(report.executions) == 2
    # A true start off the belief's mean: the perfect sensor reveals the offset and the LQR removes it.
    off = validate(problem, plan, system, [-0.5, 0.0], runs=3, seed=0, executor="serial", clip_controls=False)
    assert off.state_success_rate == 1.0


def test_invalid_arguments(light_dark_case):
    problem, plan = light_dark_case
    real = light_dark_real_system()
    x0 = LIGHT_DARK_REAL_INITIAL_STATE
    with pytest.raises(InvalidArgumentError, match="solution is None"):
        validate(problem, None, real, x0)
    with pytest.raises(InvalidTypeError, match="problem"):
        validate("problem", plan, real, x0)
    with pytest.raises(InvalidArgumentError, match="runs must be >= 1"):
        validate(problem, plan, real, x0, runs=0)
    with pytest.raises(InvalidArgumentError, match="executor"):
        validate(problem, plan, real, x0, runs=2, executor="fast")
    with pytest.raises(InvalidTypeError, match="seed"):
        validate(problem, plan, real, x0, runs=2, seed=1.5)
    with pytest.raises(InvalidArgumentError, match="seed must be >= 0"):
        validate(problem, plan, real, x0, runs=2, seed=-1)


def test_listing_plan_meets_the_bar():
    """The paper's listing: executed belief >= 90% and true state >= 95% over 100 runs."""
    problem = light_dark()
    result = problem.solve_result(
        rrt_timeout=60,
        delta_near=2,
        delta_drain=0.5,
        goal_bias=0.25,
        min_num_of_steps=3,
        max_num_of_steps=15,
        seed=0,
    )
    assert result.found, f"solver found no plan: {result.reason}"
    for mode in problem.switched_system.system_modes:
        mode.compute_finite_horizon_lqr(
            horizon=5, Q_final=np.identity(2), Q=np.identity(2), R=0.05 * np.identity(2)
        )
    report = validate(
        problem, result.trajectory, light_dark_real_system(), LIGHT_DARK_REAL_INITIAL_STATE, runs=100, seed=0
    )
    assert report.belief_success_rate >= 0.90, report.as_dict()
    assert report.state_success_rate >= 0.95, report.as_dict()


def test_report_repr_is_short_and_has_html(light_dark_case):
    problem, plan = light_dark_case
    report = validate(
        problem,
        plan,
        light_dark_real_system(),
        LIGHT_DARK_REAL_INITIAL_STATE,
        runs=30,
        seed=0,
        executor="serial",
    )
    text = repr(report)
    assert len(text) < 300, text
    assert text.startswith("ValidationReport(runs=30, num_of_steps=82")
    assert f"belief={100 * report.belief_success_rate:.1f}%" in text
    html = report._repr_html_()
    assert html.count("<table>") == 2 and "free_space" in html and "target" in html
    assert "true state" in html and "%" in html
    assert report.to_dict() == report.as_dict()


def test_seed_sequence_with_a_list_entropy_is_reported(light_dark_case):
    problem, plan = light_dark_case
    args = (problem, plan, light_dark_real_system(), LIGHT_DARK_REAL_INITIAL_STATE)
    report = validate(*args, runs=2, seed=np.random.SeedSequence([3, 4]), executor="serial")
    assert report.seed_entropy == (3, 4)
    json.dumps(report.as_dict())
    again = validate(*args, runs=2, seed=np.random.SeedSequence(report.seed_entropy), executor="serial")
    assert again == report


def test_face_slacks_are_the_chance_kernel():
    from idstlpy.chance import slack
    from idstlpy.execution.validation import _face_slacks

    x = stl.mk_variable(2)
    ap = stl.logical_and(stl.prob(x[0] <= 1) >= 1.0, stl.prob(x[1] >= -1) >= 0.9, name="a")
    means = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, -2.0]])
    covs = np.stack([np.zeros((2, 2)), np.diag([0.0, 1.0]), np.diag([1.0, 0.0])])
    got = _face_slacks(ap, means, covs)
    cone = ap.cone
    np.testing.assert_array_equal(got, slack(cone.H, cone.c, cone.z, means, covs))
    assert got[0, 0] == 1.0 and got[1, 0] == -1.0  # eps = 0 with zero variance along the face
    assert got[2, 0] == -np.inf  # eps = 0 with variance: no mean meets it


def test_no_function_shadows_its_submodule():
    import importlib
    import types

    import idstlpy.execution as execution

    for name in ("prediction", "simulation", "validation"):
        assert isinstance(importlib.import_module(f"idstlpy.execution.{name}"), types.ModuleType)
    assert execution.simulate is stl.simulate and callable(execution.simulate)
    assert execution.validate is stl.validate and callable(execution.validate)
    assert execution.simulation.simulate is stl.simulate
    assert execution.validation.validate is stl.validate
