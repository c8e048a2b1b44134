"""Issue 34: tracking gains fitted to the problem by default, carried by the plan, used by the executors."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import idstlpy as stl
from idstlpy.errors import ExecutionTargetWarning, InvalidArgumentError
from idstlpy.sets import Polytope
from idstlpy.synthesis.tracking_choice import tracking_candidates
from idstlpy.tracking import (
    DEFAULT_LQR,
    FITTED_SCALES,
    finite_horizon_lqr,
    fitted_weights,
    make_tracking,
    planning_gains,
    system_gains,
)


def _msd(
    k: float = 2.0, c: float = 0.5, force: float = 5.0, goal: float = 0.5, tol: float = 0.05
) -> stl.Problem:
    """A 1 kg mass-spring-damper pushed to ``goal`` and held within ``tol`` (benchmarks/plant_family)."""
    A = np.array([[0.0, 1.0], [-k, -c]])
    mode = stl.from_continuous(
        A, np.array([[0.0], [1.0]]), dt=0.05, noise_intensity=np.diag([0.0, 0.01]),
        C=np.array([[1.0, 0.0]]), V_cov=[[0.005**2]],
    )  # fmt: skip
    x = stl.mk_variable(2, float)
    u = stl.mk_variable(1, float)
    at = stl.logical_and(
        stl.prob(x[0] >= goal - tol) >= 0.95, stl.prob(x[0] <= goal + tol) >= 0.95, name="at"
    )
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=stl.logical_and(u[0] >= -force, u[0] <= force).region,
        initial_state=stl.to_belief(mean=np.zeros(2), cov=np.diag([1e-4, 1e-4])),
        stl_formula=stl.eventually(0, 60, stl.always(0, 10, at)),
    )


def test_fitted_weights_follow_brysons_rule():
    system = stl.mk_switched_sys([stl.mk_lcs(np.eye(3), np.diag([1.0, 2.0, 0.5])[:, :2])])
    # faces h'x + c <= 0: |x0| <= 4 and |x1| <= 1; 0.9 <= x0 <= 1.1 (x2 bounded by neither)
    e = np.eye(3)
    wide = Polytope(np.array([e[0], -e[0], e[1], -e[1]]), np.array([-4.0, -4.0, -1.0, -1.0]))
    narrow = Polytope(np.array([e[0], -e[0]]), np.array([-1.1, 0.9]))
    domain = Polytope.box([-3.0, -0.5], [3.0, 1.5])
    w = fitted_weights(system, [wide, narrow], domain)
    assert w is not None
    # x0: the narrow region's half-width 0.1; x1: the wide one's 1; x2: bounded by none
    np.testing.assert_allclose(np.diag(w["Q"]), [1 / 0.1**2, 1.0, 0.0])
    np.testing.assert_allclose(w["Q_final"], w["Q"])
    np.testing.assert_allclose(np.diag(w["R"]), [1 / 3.0**2, 1 / 1.0**2])
    assert w["horizon"] == DEFAULT_LQR["horizon"]


def test_fitted_weights_on_an_unbounded_input_use_the_input_that_moves_a_state_by_its_room():
    system = stl.mk_switched_sys([stl.mk_lcs(np.eye(2), np.array([[0.5], [0.0]]))])
    region = Polytope.box([-0.2, -1.0], [0.2, 1.0])
    w = fitted_weights(system, [region], None)
    assert w is not None
    # x0's room 0.2 is moved by u = 0.2 / 0.5 = 0.4 in one step (x1 is not moved by u): R = 1 / 0.4^2
    # against Q_00 = 1 / 0.2^2, the weights divided by R's largest entry (the gains' scale-free form)
    np.testing.assert_allclose(w["R"], [[1.0]])
    np.testing.assert_allclose(w["Q"][0, 0], (1 / 0.2**2) / (1 / 0.4**2))


def test_fitted_weights_are_none_without_a_bounded_coordinate():
    system = stl.mk_switched_sys([stl.mk_lcs(np.eye(2), np.eye(2))])
    half_plane = Polytope(np.array([[1.0, 0.0]]), np.array([-1.0]))
    assert fitted_weights(system, [half_plane], Polytope.box([-1, -1], [1, 1])) is None


@settings(max_examples=30, deadline=None)
@given(
    st.floats(0.01, 10.0),
    st.floats(0.01, 10.0),
    st.floats(1e-3, 1e3),
)
def test_fitted_gains_do_not_depend_on_the_units(half_x, half_u, unit):
    # The same problem in other units (x' = unit x, u' = unit u): the fitted gains map exactly.
    A, B = np.array([[1.0, 0.1], [0.0, 0.9]]), np.array([[0.0], [0.1]])
    system = stl.mk_switched_sys([stl.mk_lcs(A, B)])
    w = fitted_weights(
        system, [Polytope.box([-half_x, -10.0], [half_x, 10.0])], Polytope.box([-half_u], [half_u])
    )
    scaled = fitted_weights(
        system,
        [Polytope.box([-unit * half_x, -unit * 10.0], [unit * half_x, unit * 10.0])],
        Polytope.box([-unit * half_u], [unit * half_u]),
    )
    assert w is not None and scaled is not None
    K = finite_horizon_lqr(A, B, 5, w["Q_final"], w["Q"], w["R"])[0]
    K2 = finite_horizon_lqr(A, B, 5, scaled["Q_final"], scaled["Q"], scaled["R"])[0]
    np.testing.assert_allclose(K2, K, rtol=1e-6)


def test_a_solve_returns_a_plan_with_its_fitted_gains_and_the_paper_option_keeps_the_old_ones():
    problem = _msd()
    result = problem.solve_result(seed=0, time_limit=60)
    assert result.found and result.meets_target
    used = result.tracking
    assert used is not None and used is result.trajectory.tracking
    assert used.name.startswith("fitted")
    candidates = tracking_candidates(problem, "fitted")
    assert [c.name for c in candidates] == [
        *("fitted" if s == 1.0 else f"fitted x{s:g}" for s in FITTED_SCALES),
        "paper",
    ]
    paper = tracking_candidates(problem, "paper")
    assert [c.name for c in paper] == ["paper"]
    mode = problem.switched_system.mode(0)
    expected = finite_horizon_lqr(mode.A, mode.B, 5, np.eye(2), np.eye(2), 0.05 * np.eye(1))
    for K, K_ref in zip(paper[0].gains[0], expected, strict=True):
        np.testing.assert_allclose(K, K_ref)


def test_modes_with_their_own_gains_keep_them():
    problem = _msd()
    mode = problem.switched_system.mode(0)
    own = mode.compute_finite_horizon_lqr(5, np.diag([100.0, 1.0]), np.diag([100.0, 1.0]), [[0.1]])
    assert tracking_candidates(problem, "fitted") == ()
    plan = stl.rollout(problem.switched_system, problem.initial_state, [0] * 3, np.zeros((3, 1)))
    plan.tracking = make_tracking(problem.switched_system, "paper", None)
    # the paper's gains for a mode with its own: the mode's own are kept
    np.testing.assert_allclose(plan.tracking.gains[0][0], own[0])


def test_the_executors_track_with_the_plans_gains_unless_told_otherwise():
    problem = _msd()
    system = problem.switched_system
    plan = stl.rollout(system, problem.initial_state, [0] * 8, np.full((8, 1), 0.5))
    weights = {"horizon": 5, "Q_final": np.diag([400.0, 0.0]), "Q": np.diag([400.0, 0.0]), "R": [[0.04]]}
    plan.tracking = make_tracking(system, "fitted", weights)
    x0 = np.array([0.02, -0.01])
    _, with_plan = stl.simulate(system, plan, 8, x0, None, seed=1, control_domain=problem.control_domain)
    _, explicit = stl.simulate(
        system, plan, 8, x0, None, seed=1, control_domain=problem.control_domain, default_lqr=weights
    )
    _, paper = stl.simulate(
        system, plan, 8, x0, None, seed=1, control_domain=problem.control_domain, default_lqr=DEFAULT_LQR
    )
    np.testing.assert_allclose(with_plan.get_control(), explicit.get_control())
    assert not np.allclose(with_plan.get_control(), paper.get_control())
    # the online executor and the prediction read the same gains
    online = stl.OnlineExecutor(problem, plan)
    np.testing.assert_allclose(online.spec.gains_for(plan)[0][0], plan.tracking.gains[0][0])
    assert online.spec.defaulted == {0}  # made without the plan: the plan decides its gains
    explicit_pred = stl.predict_closed_loop(problem, plan, default_lqr=weights, samples=200, seed=0)
    plan_pred = stl.predict_closed_loop(problem, plan, samples=200, seed=0)
    assert plan_pred.state_success_estimate == explicit_pred.state_success_estimate
    np.testing.assert_allclose(plan_pred.augmented_cov, explicit_pred.augmented_cov)


def test_planning_gains_apply_to_their_system_only():
    problem = _msd()
    system = problem.switched_system
    other = _msd().switched_system
    fitted = tracking_candidates(problem, "fitted")[0]
    mine = system_gains(system)  # no plan, no solve: the paper's weights
    from idstlpy.closed_loop import gains_for

    plan = stl.rollout(system, problem.initial_state, [0, 0], np.zeros((2, 1)))
    with planning_gains(system, fitted):
        inside = gains_for(system, np.array([0, 0]), None, None, plan)
        elsewhere = gains_for(other, np.array([0, 0]), None, None, plan)
    outside = gains_for(system, np.array([0, 0]), None, None, plan)
    np.testing.assert_allclose(inside[0][0], fitted.gains[0][0])
    np.testing.assert_allclose(elsewhere[0][0], mine[0][0])  # the paper's: another system
    np.testing.assert_allclose(outside[0][0], mine[0][0])


def test_the_plans_gains_round_trip_through_json(tmp_path):
    problem = _msd()
    result = problem.solve_result(seed=0, time_limit=60)
    path = tmp_path / "r.json"
    result.save(path)
    back = stl.load_result(path)
    assert back.tracking is not None and back.tracking.name == result.tracking.name
    for q, Ks in result.tracking.gains.items():
        for K, K2 in zip(Ks, back.tracking.gains[q], strict=True):
            np.testing.assert_array_equal(K, K2)
    json.dumps(result.trajectory.to_dict(), allow_nan=False)


def test_tracking_option_is_checked():
    with pytest.raises(InvalidArgumentError, match="tracking"):
        stl.SolverOptions(tracking="firm")


def test_a_flag_names_the_gains_and_a_value_to_try():
    # a hold far tighter than the sensor allows: no gain set reaches the target
    problem = _msd(tol=0.012)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = problem.solve_result(seed=0, time_limit=30, max_candidates=10)
    assert result.found and not result.meets_target
    flagged = [w for w in caught if issubclass(w.category, ExecutionTargetWarning)]
    assert flagged
    text = str(flagged[0].message)
    assert f"tracked with {result.tracking.name} gains" in text
    assert f"tracked with {result.tracking.name} gains" in result.reason
    assert "Q = diag(" in result.reason
    # every gain set was predicted, and the reason lists the others' rates
    for name in ("fitted", "paper"):
        assert name in result.reason.split("tracked with", 1)[1]
