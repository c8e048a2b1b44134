"""Executing a plan: exact reproduction without noise, determinism, filter consistency (NEES)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

import idstlpy as stl
from idstlpy.errors import DimensionError, InvalidArgumentError, InvalidTypeError
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system
from idstlpy.sets import Polytope


def _plan(system, initial, N=12, seed=3):
    rng = np.random.default_rng(seed)
    controls = rng.uniform(-1, 1, size=(N, system.m))
    actions = rng.integers(0, system.num_modes, size=N)
    return stl.rollout(system, initial, actions, controls)


def _two_mode_system(V0, V1):
    A = np.array([[1.0, 0.1], [0.0, 0.95]])
    return stl.mk_switched_sys(
        [
            stl.mk_lbs(A=A, B=0.25 * np.eye(2), W=np.zeros((2, 2)), C=np.eye(2), V=V0),
            stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=np.zeros((2, 2)), C=np.array([[1.0, 0.0]]), V=V1),
        ]
    )


@pytest.mark.parametrize("noise", ["constant", "function"])
def test_noise_free_execution_reproduces_plan_exactly(noise):
    if noise == "constant":
        system = _two_mode_system(np.zeros((2, 2)), np.zeros((1, 1)))
    else:
        system = _two_mode_system(lambda x: 0.0 * np.eye(2), lambda x: np.zeros((1, 1)))
    initial = stl.to_belief([0.3, -0.2], np.diag([0.2, 0.1]))
    plan = _plan(system, initial)
    xi_sim, xi_real = system.simulate(plan, plan.num_of_steps, initial.mean, system, seed=1)
    np.testing.assert_allclose(xi_sim.get_mean(), plan.get_mean(), atol=1e-12)
    np.testing.assert_allclose(xi_sim.get_cov(), plan.get_cov(), atol=1e-12)
    np.testing.assert_allclose(xi_real.get_state(), plan.get_mean(), atol=1e-12)
    np.testing.assert_allclose(xi_real.get_control(), plan.get_control(), atol=1e-12)
    np.testing.assert_array_equal(xi_real.get_action(), plan.get_action())
    assert np.all(np.isnan(xi_real.get_observation(0)))


def test_listing_call_runs_and_same_seed_same_run():
    problem = light_dark(deadline=30, hold=5)
    system = problem.switched_system
    plan = stl.rollout(system, problem.initial_state, np.zeros(20, dtype=int), np.tile([0.5, -0.5], (20, 1)))
    for i in range(system.system_modes.size):
        system.system_modes[i].compute_finite_horizon_lqr(
            horizon=5, Q_final=np.identity(2), Q=np.identity(2), R=0.05 * np.identity(2)
        )
    kwargs = dict(
        reference_trajectory=plan,
        num_of_steps=plan.num_of_steps,
        real_initial_state=np.array([0.5, 2.75]),
        real_system=stl.mk_switched_sys([stl.mk_lcs(A=np.identity(2), B=0.25 * np.identity(2))]),
    )
    a_sim, a_real = system.simulate(**kwargs, seed=7)
    b_sim, b_real = system.simulate(**kwargs, seed=7)
    c_sim, _ = system.simulate(**kwargs, seed=8)
    assert a_sim.num_of_steps == plan.num_of_steps == a_real.num_of_steps
    np.testing.assert_array_equal(a_sim.get_mean(), b_sim.get_mean())
    np.testing.assert_array_equal(a_real.get_observation()[1:], b_real.get_observation()[1:])
    assert not np.allclose(a_sim.get_mean(), c_sim.get_mean())
    assert a_real.get_observation().shape == (21, 2)


def test_tracking_pulls_the_estimate_back_to_the_plan():
    # A perfect sensor shows the true offset at once; the LQR removes it.
    system = stl.mk_switched_sys(
        [stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=np.zeros((2, 2)), C=np.eye(2))]
    )
    initial = stl.to_belief([0.0, 0.0], 0.5 * np.eye(2))
    plan = stl.rollout(system, initial, np.zeros(30, dtype=int), np.zeros((30, 2)))
    xi_sim, xi_real = system.simulate(plan, 30, [0.6, -0.4], system, seed=0)
    assert np.linalg.norm(xi_real.get_state(1)) > 0.5
    assert np.linalg.norm(xi_real.get_state(30)) < 1e-6
    assert np.linalg.norm(xi_sim.get_mean(30)) < 1e-6


@pytest.mark.parametrize(
    "domain",
    [
        Polytope.box([-1.0, -1.0], [1.0, 1.0]),
        Polytope(np.array([[1.0, 1.0], [-1.0, 0.0], [0.0, -1.0]]), np.array([-1.0, -1.0, -1.0])),
    ],
)
def test_inputs_are_projected_on_the_control_domain(domain):
    system = stl.mk_switched_sys(
        [stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=np.zeros((2, 2)), C=np.eye(2))]
    )
    initial = stl.to_belief([0.0, 0.0], np.eye(2))
    plan = stl.rollout(system, initial, np.zeros(10, dtype=int), np.zeros((10, 2)))
    _, real = system.simulate(plan, 10, [3.0, 3.0], system, control_domain=domain)
    for u in real.get_control():
        assert np.all(domain.H @ u + domain.c <= 1e-6)
    assert np.abs(real.get_control(1)).max() > 0.5  # it did push (after the first observation)


def test_kalman_filter_is_consistent_nees():
    """Average NEES over M runs at each step lies in the chi-square(M n) 99.9% band."""
    A = np.array([[1.0, 0.2], [0.0, 0.9]])
    W = np.array([[0.1, 0.0], [0.05, 0.2]])
    mode = stl.mk_lbs(A=A, B=0.25 * np.eye(2), W=W, C=np.array([[1.0, 0.0]]), V=np.array([[0.3]]))
    system = stl.mk_switched_sys([mode])
    initial = stl.to_belief([0.0, 1.0], np.diag([0.5, 0.3]))
    T, M, n = 15, 300, 2
    plan = stl.rollout(system, initial, np.zeros(T, dtype=int), np.tile([0.2, -0.1], (T, 1)))
    rng = np.random.default_rng(2024)
    nees = np.zeros((M, T + 1))
    for i in range(M):
        x0 = initial.sample(seed=rng)
        xi_sim, xi_real = system.simulate(plan, T, x0, system, seed=rng, process_noise="model")
        err = xi_real.get_state() - xi_sim.get_mean()
        covs = xi_sim.get_cov()
        nees[i] = np.einsum("ki,kij,kj->k", err, np.linalg.inv(covs), err)
    lo, hi = chi2.ppf([0.0005, 0.9995], M * n) / M
    mean_nees = nees.mean(axis=0)
    assert np.all((mean_nees >= lo) & (mean_nees <= hi)), (mean_nees, lo, hi)


def test_invalid_inputs():
    problem = light_dark(deadline=10, hold=2)
    system = problem.switched_system
    plan = stl.rollout(system, problem.initial_state, np.zeros(5, dtype=int), np.zeros((5, 2)))
    real = light_dark_real_system()
    x0 = LIGHT_DARK_REAL_INITIAL_STATE
    with pytest.raises(InvalidArgumentError, match="reference_trajectory is None"):
        system.simulate(None, 5, x0, real)
    with pytest.raises(InvalidTypeError, match="reference_trajectory"):
        system.simulate(plan.get_mean(), 5, x0, real)
    with pytest.raises(InvalidArgumentError, match="num_of_steps must be <="):
        system.simulate(plan, 6, x0, real)
    with pytest.raises(DimensionError, match="real_initial_state"):
        system.simulate(plan, 5, [0.0, 0.0, 0.0], real)
    with pytest.raises(DimensionError, match="real_system"):
        system.simulate(plan, 5, x0, stl.mk_switched_sys([stl.mk_lcs(np.eye(3), np.eye(3, 2))]))
    with pytest.raises(InvalidTypeError, match="real_system"):
        system.simulate(plan, 5, x0, "real")
    with pytest.raises(DimensionError, match="control_domain"):
        system.simulate(plan, 5, x0, real, control_domain=Polytope.box([-1.0], [1.0]))
    with pytest.raises(InvalidArgumentError, match="process_noise"):
        system.simulate(plan, 5, x0, real, process_noise="loud")
    with pytest.raises(DimensionError, match="lqr gain"):
        system.simulate(plan, 5, x0, real, lqr_gains=[[np.eye(3)]])
    with pytest.raises(TypeError, match="unexpected keyword"):
        system.simulate(plan, 5, x0, real, colour="red")
    xi_sim, xi_real = system.simulate(plan, 0, x0, real)
    assert xi_sim.num_of_steps == 0 and xi_real.get_state().shape == (1, 2)
