"""Plans that hold when executed, by default (issue 23): ``guarantee="execution"``.

The default plan satisfies the formula under the paper's semantics and its predicted execution
(the Kalman filter, the modes' LQR tracking, inputs clipped to the control domain, the true start
drawn from the prior, the model's noise) meets the execution target, or the result says it does
not (``meets_target`` False and an :class:`~idstlpy.errors.ExecutionTargetWarning`). The
prediction is checked here against an independent Monte Carlo of ``simulate`` from prior-drawn
starts (small budgets; the 1000-run figures are in ``benchmarks/defaults_results.md``).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from benchmarks import defaults_problems as dp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import idstlpy as stl
from idstlpy.errors import ExecutionTargetWarning, InvalidArgumentError, InvalidTypeError
from idstlpy.execution.validation import state_trajectory, wilson_interval
from idstlpy.execution_target import ExecutionTarget
from idstlpy.synthesis.results import PredictedExecution, SolveResult

Z99 = 2.5758293035489004

SLACK = 0.05
"""Model error allowed on top of the Monte Carlo interval: the prediction linearises the clip and
a state-dependent sensor (issue 23 measured 2-6 points on the problems it lists), and samples
1000 model trajectories of its own."""


def monte_carlo(problem: stl.Problem, plan, runs: int, seed: int) -> tuple[float, float]:
    """Executed-belief and true-state success rates of ``runs`` executions from prior-drawn starts."""
    rng = np.random.default_rng(seed)
    init, formula = problem.initial_state, problem.stl_formula
    ok_b = ok_s = 0
    for _ in range(runs):
        x0 = rng.multivariate_normal(init.mean, init.cov)
        xi_sim, xi_real = stl.simulate(
            problem.switched_system,
            plan,
            plan.num_of_steps,
            x0,
            problem.switched_system,
            seed=rng,
            control_domain=problem.control_domain,
        )
        ok_b += stl.robustness(xi_sim, formula) >= 0
        ok_s += stl.robustness(state_trajectory(xi_real), formula) >= 0
    return ok_b / runs, ok_s / runs


def agrees(predicted: float, successes: float, runs: int) -> bool:
    lo, hi = wilson_interval(int(round(successes * runs)), runs, z=Z99)
    return lo - SLACK <= predicted <= hi + SLACK


def solve(problem: stl.Problem, **kw) -> tuple[SolveResult, list[warnings.WarningMessage]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = problem.solve_result(**kw)
    return result, [w for w in caught if issubclass(w.category, ExecutionTargetWarning)]


def check_default(result: SolveResult, caught: list, problem: stl.Problem, runs: int = 300) -> None:
    """The default's contract on one result: a plan meets the target or is flagged, and its
    prediction agrees with a Monte Carlo of the executor."""
    assert result.guarantee == "execution"
    if not result.found:
        assert result.execution is None and result.meets_target is None
        return
    assert stl.satisfies(result.trajectory, problem.stl_formula)  # the paper's semantics
    ex = result.execution
    assert isinstance(ex, PredictedExecution)
    target = ex.target
    meets = ex.belief_estimate >= target.belief and ex.state_estimate >= target.state
    assert result.meets_target is meets
    assert bool(caught) is (not meets)  # below target: always flagged and warned
    if not meets:
        assert "below target" in result.reason or result.stats.below_target >= 0
    assert ex.belief_bound <= ex.belief_estimate + 1e-9 and ex.state_bound <= ex.state_estimate + 1e-9
    belief, state = monte_carlo(problem, result.trajectory, runs, seed=11)
    assert agrees(ex.belief_estimate, belief, runs), (ex.belief_estimate, belief)
    assert agrees(ex.state_estimate, state, runs), (ex.state_estimate, state)


# ------------------------------------------------------------------------------------------------
# The issue's problems


@pytest.mark.parametrize("name", ["one_d", "drive_look", "drive_look_noisy", "drive_sense"])
def test_issue_problems_default_plan_holds_or_is_flagged(name):
    problem = dp.build(name)
    result, caught = solve(problem, seed=0, time_limit=60, max_candidates=400)
    check_default(result, caught, problem)


def test_issue_one_d_and_drive_look_meet_the_target():
    """The 1-D problem, the noise-free drive/look problem and the second two-mode problem (drive
    blind or sense slowly): the default plan meets the target (their MLO plans held in 30% / 60%
    / 1% of executions in the issue), the two-mode ones within tens of candidates (the mode
    search reads the execution)."""
    for name in ("one_d", "drive_look", "drive_sense"):
        problem = dp.build(name)
        result, caught = solve(problem, seed=0, time_limit=60, max_candidates=400)
        assert result.found and result.meets_target, (name, result)
        assert not caught
        if problem.switched_system.num_modes > 1:
            assert result.stats.candidates <= 50, (name, result.stats.candidates)
        mlo, _ = solve(problem, seed=0, time_limit=60, max_candidates=400, guarantee="mlo")
        assert mlo.found and mlo.guarantee == "mlo"
        assert mlo.execution is not None and not mlo.meets_target  # the paper's reading, flagged


def test_listing_verbatim_keeps_its_promise_under_the_default():
    problem = dp.listing()
    result, caught = solve(
        problem,
        rrt_timeout=60,
        delta_near=2,
        delta_drain=0.5,
        goal_bias=0.25,
        min_num_of_steps=3,
        max_num_of_steps=15,
        seed=0,
    )
    assert result.found and result.meets_target and not caught
    assert result.execution.belief_estimate >= 0.99 and result.execution.state_estimate >= 0.99
    belief, state = monte_carlo(problem, result.trajectory, 100, seed=3)
    assert belief >= 0.97 and state >= 0.97


# ------------------------------------------------------------------------------------------------
# Options, flags, round trips


def test_execution_target_option_is_validated_and_used():
    problem = dp.one_d()
    with pytest.raises(InvalidArgumentError, match="execution_target"):
        problem.solve_result(execution_target=(0.9, 1.5))
    with pytest.raises(InvalidTypeError, match="execution_target"):
        problem.solve_result(execution_target="high")
    with pytest.raises(InvalidArgumentError, match="guarantee"):
        problem.solve_result(guarantee="robust")
    assert stl.SolverOptions().guarantee == "execution"
    assert stl.SolverOptions().execution_target == ExecutionTarget(0.90, 0.95)
    opts = stl.SolverOptions(execution_target={"belief": 0.5, "state": 0.6})
    assert opts.execution_target == ExecutionTarget(0.5, 0.6)
    # A target no plan reaches within the budget: the best plan is returned, flagged and warned.
    noisy = dp.drive_look_noisy()
    result, caught = solve(noisy, seed=0, time_limit=60, max_candidates=30, execution_target=(1.0, 1.0))
    assert result.found and result.meets_target is False and caught
    assert "execution target" in str(caught[0].message)
    assert result.execution.target == ExecutionTarget(1.0, 1.0)


def test_result_json_round_trip_keeps_the_predicted_execution(tmp_path):
    problem = dp.one_d()
    result, _ = solve(problem, seed=0, time_limit=30)
    back = stl.load_result(result.save(tmp_path / "r.json"))
    assert back.guarantee == "execution"
    assert back.execution == result.execution and back.meets_target == result.meets_target
    assert back.execution.proposition_violation.keys() == result.execution.proposition_violation.keys()
    assert "predicted belief/state" in repr(result)
    none = SolveResult.from_dict({**result.to_dict(), "execution": None})
    assert none.execution is None and none.meets_target is None


def test_plain_script_sees_the_warning():
    """The warning reaches a script that configured nothing (the default filters show it).

    With the paper's tracking weights: under the fitted default (issue 34) this plan meets the
    target, and the warning has nothing to say."""
    import subprocess
    import sys

    code = (
        "from benchmarks import defaults_problems as dp\n"
        "r = dp.drive_look_noisy().solve_result(seed=0, time_limit=60, max_candidates=30, tracking='paper')\n"
        "print(r.meets_target)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "False"
    assert "ExecutionTargetWarning" in out.stderr
    assert "<string>:2: ExecutionTargetWarning" in out.stderr  # the user's line, not the library's


# ------------------------------------------------------------------------------------------------
# Property: random small problems


@st.composite
def small_problems(draw):
    n = draw(st.sampled_from([1, 2]))
    modes = draw(st.sampled_from([1, 2]))
    b = draw(st.floats(0.3, 1.0))
    w = draw(st.sampled_from([0.0, 0.02, 0.08]))
    state_dependent = draw(st.booleans())
    goal = draw(st.floats(1.0, 3.0))
    half = draw(st.floats(0.3, 0.6))
    conf = draw(st.sampled_from([0.8, 0.9, 0.95]))
    x, u = stl.mk_variable(n, float), stl.mk_variable(n, float)
    if state_dependent:
        sensor = dp.SpotSensor(spot=goal, radius=0.6, good=0.05, bad=draw(st.floats(0.2, 0.6)), dim=n)
        first = stl.mk_lbs(A=np.eye(n), B=b * np.eye(n), W=w * np.eye(n), C=np.eye(n), V=sensor, V_floor=0.05)
    else:
        v = draw(st.floats(0.05, 0.4))
        first = stl.mk_lbs(A=np.eye(n), B=b * np.eye(n), W=w * np.eye(n), C=np.eye(n), V=v * np.eye(n))
    system = [first]
    if modes == 2:  # a slow mode with a good sensor
        system.append(
            stl.mk_lbs(A=np.eye(n), B=0.1 * np.eye(n), W=w * np.eye(n), C=np.eye(n), V=0.03 * np.eye(n))
        )
    preds = []
    for i in range(n):
        preds += [stl.prob(x[i] >= goal - half) >= conf, stl.prob(x[i] <= goal + half) >= conf]
    target = stl.logical_and(*preds, name="goal")
    control = []
    for i in range(n):
        control += [u[i] >= -1, u[i] <= 1]
    return stl.Problem(
        switched_system=stl.mk_switched_sys(system),
        control_domain=stl.logical_and(*control).region,
        initial_state=stl.to_belief(mean=np.zeros(n), cov=0.1 * np.eye(n)),
        stl_formula=stl.eventually(0, 15, stl.always(0, 3, target)),
    )


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(small_problems())
def test_property_prediction_agrees_with_monte_carlo_and_below_target_is_flagged(problem):
    result, caught = solve(problem, seed=0, time_limit=20, max_candidates=60)
    check_default(result, caught, problem, runs=200)


def test_predicted_execution_summary_and_shortfall():
    ex = PredictedExecution(0.8, 0.97, 0.7, 0.9, {}, ExecutionTarget(0.9, 0.95))
    assert not ex.meets_target and math.isclose(ex.shortfall, 0.1)
    assert "BELOW" in ex.summary()
    nan = PredictedExecution(float("nan"), 1.0, float("nan"), 1.0)
    assert not nan.meets_target and nan.shortfall == 1.0
    assert PredictedExecution.from_dict(ex.to_dict()) == ex


def test_problem_files_take_the_execution_target(tmp_path):
    from idstlpy.cli import main
    from idstlpy.errors import ProblemFileError
    from idstlpy.problem_file import apply_overrides, load_problem

    path = tmp_path / "ra.toml"
    assert main(["example", "reach-avoid", "--out", str(path)]) == 0
    spec = apply_overrides(load_problem(path), {"solver.execution_target": {"belief": 0.5, "state": 0.6}})
    _, solver, _ = spec.build()
    assert stl.SolverOptions.make(**solver).execution_target == ExecutionTarget(0.5, 0.6)
    with pytest.raises(ProblemFileError, match="execution_target"):
        apply_overrides(
            load_problem(path), {"solver.execution_target": {"belief": 2.0, "state": 0.6}}
        ).build()
    with pytest.raises(ProblemFileError, match="execution_target"):
        apply_overrides(load_problem(path), {"solver.execution_target": "high"}).build()


def test_a_plan_below_target_under_an_objective_carries_its_value():
    problem = dp.drive_look_noisy()
    result, caught = solve(problem, seed=0, time_limit=60, max_candidates=30, objective="effort")
    assert result.found and result.meets_target is False and caught
    assert result.objective == "effort" and np.isfinite(result.objective_value) and not result.optimal
