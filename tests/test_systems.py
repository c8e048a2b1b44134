"""Dynamical systems, switched systems, rollouts and trajectories (paper Fig. 6)."""

from __future__ import annotations

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.dynamical_system import mk_lbs


def test_mk_lbs_builds_the_documented_classes():
    I2 = np.eye(2)
    lcs = stl.mk_lcs(I2, 0.25 * I2)
    assert type(lcs) is stl.LCS and (lcs.n, lcs.m, lcs.p) == (2, 2, 0)
    assert not lcs.has_output
    lbs = mk_lbs(I2, np.ones((2, 1)), 0.1 * I2)
    assert type(lbs) is stl.LBS and lbs.m == 1 and lbs.p == 0
    np.testing.assert_allclose(lbs.process_cov, 0.01 * I2)
    lin = mk_lbs(I2, I2, I2, C=[[1.0, 0.0]], V=[[0.3, 0.4]])
    assert type(lin) is stl.POLBSWithLinNoise and isinstance(lin, stl.POLBS)
    assert lin.p == 1 and lin.has_output and not lin.has_state_dependent_noise
    np.testing.assert_allclose(lin.noise_cov(np.zeros(2)), [[0.25]])
    nonlin = mk_lbs(I2, I2, I2, C=I2, V=lambda s: (1.0 + s[0] ** 2) * I2)
    assert type(nonlin) is stl.POLBSWithNonLinNoise and nonlin.has_state_dependent_noise
    np.testing.assert_allclose(nonlin.noise_cov(np.array([2.0, 0.0])), 25.0 * I2)
    for sys_ in (lcs, lbs, lin, nonlin):
        assert isinstance(sys_, stl.DynamicalSystem) and isinstance(sys_, stl.LCS)
    np.testing.assert_allclose(lcs.step([1.0, 2.0], [4.0, 0.0]), [2.0, 2.0])


def test_switched_system():
    I2 = np.eye(2)
    modes = [stl.mk_lcs(I2, I2), mk_lbs(2 * I2, I2, I2)]
    system = stl.mk_switched_sys(modes)
    assert isinstance(system, stl.SwitchedSystem) and isinstance(system, stl.DynamicalSystem)
    assert system.num_modes == 2 and system.system_modes.size == 2
    assert (system.n, system.m) == (2, 2)
    assert system.mode(1) is modes[1]
    assert system.system_modes[0] is modes[0]
    with pytest.raises(stl.OutOfRangeError, match="mode 2"):
        system.mode(2)
    single = stl.mk_switched_sys(modes[0])
    assert single.num_modes == 1


def test_rollout_mean_is_affine_in_controls_and_records_plan():
    A = np.array([[1.0, 0.2], [0.0, 1.0]])
    B = np.array([[0.0], [0.2]])
    system = stl.mk_switched_sys(
        [mk_lbs(A, B, 0.1 * np.eye(2), C=[[1.0, 0.0]], V=[[0.1]]), mk_lbs(A, -B, 0.1 * np.eye(2))]
    )
    b0 = stl.to_belief([0.0, 1.0], 0.2 * np.eye(2))
    actions = [0, 1, 1, 0]
    rng = np.random.default_rng(0)
    u1, u2 = rng.normal(size=(4, 1)), rng.normal(size=(4, 1))
    t1 = stl.rollout(system, b0, actions, u1)
    t2 = stl.rollout(system, b0, actions, u2)
    t12 = stl.rollout(system, b0, actions, 0.5 * u1 + 0.5 * u2)
    np.testing.assert_allclose(t12.get_mean(), 0.5 * t1.get_mean() + 0.5 * t2.get_mean(), atol=1e-12)
    # constant noise: the covariance depends only on the mode sequence
    np.testing.assert_allclose(t1.get_cov(), t2.get_cov(), atol=1e-14)
    # hand-computed first step
    np.testing.assert_allclose(t1.get_mean(1), A @ np.array([0.0, 1.0]) + B @ u1[0])
    assert t1.num_of_steps == 4 and len(t1) == 5 and t1.n == 2
    assert t1.get_action(2) == 1 and isinstance(t1.get_action(2), int)
    np.testing.assert_array_equal(t1.get_action(), actions)
    np.testing.assert_allclose(t1.get_control(3), u1[3])
    np.testing.assert_allclose(t1.get_mean(0), [0.0, 1.0])
    np.testing.assert_allclose(t1.get_cov(0), 0.2 * np.eye(2))
    assert t1.get_mean().shape == (5, 2) and t1.get_cov().shape == (5, 2, 2)


def test_rollout_without_steps():
    system = stl.mk_switched_sys([stl.mk_lcs(np.eye(2), np.eye(2))])
    traj = stl.rollout(system, stl.to_belief([1.0, 1.0], np.eye(2)), [], np.zeros((0, 2)))
    assert traj.num_of_steps == 0
    np.testing.assert_allclose(traj.get_mean(0), [1.0, 1.0])


def test_trajectory_index_errors_and_shapes():
    traj = stl.ProbabilisticTSTrajectory(np.zeros((3, 2)), np.zeros((3, 2, 2)), [0, 0], np.zeros((2, 1)))
    with pytest.raises(stl.OutOfRangeError, match="mean index 3"):
        traj.get_mean(3)
    with pytest.raises(stl.OutOfRangeError, match="action index 2"):
        traj.get_action(2)
    with pytest.raises(stl.DimensionError, match="covs must have shape"):
        stl.ProbabilisticTSTrajectory(np.zeros((3, 2)), np.zeros((3, 2, 3)), [0, 0], np.zeros((2, 1)))
    with pytest.raises(stl.DimensionError, match="actions must have shape"):
        stl.ProbabilisticTSTrajectory(np.zeros((3, 2)), np.zeros((3, 2, 2)), [0], np.zeros((2, 1)))
    with pytest.raises(stl.InvalidArgumentError, match="finite"):
        stl.ProbabilisticTSTrajectory(np.full((1, 2), np.nan), np.zeros((1, 2, 2)), [], np.zeros((0, 1)))
    real = stl.RealTrajectory(np.zeros((3, 2)), np.zeros((3, 1)), [1, 0], np.zeros((2, 2)))
    assert real.num_of_steps == 2 and real.get_action(0) == 1
    assert real.get_state().shape == (3, 2)


# -- state-space objects (python-control's StateSpace, scipy's, duck-typed) -------------------------
class _StateSpace:
    """The attributes idstlpy reads from python-control's ``StateSpace``."""

    def __init__(self, A, B, C, D, dt):
        self.A, self.B, self.C, self.D, self.dt = (
            np.asarray(A),
            np.asarray(B),
            np.asarray(C),
            np.asarray(D),
            dt,
        )


A_SS = np.array([[1.0, 0.1], [0.0, 1.0]])
B_SS = np.array([[0.0], [0.1]])
C_SS = np.array([[1.0, 0.0]])


@pytest.mark.parametrize("dt", [True, 0.1, 1])
def test_mk_lcs_and_mk_lbs_accept_a_discrete_state_space(dt):
    ss = _StateSpace(A_SS, B_SS, C_SS, np.zeros((1, 1)), dt)
    lcs = stl.mk_lcs(ss)
    assert type(lcs) is stl.LCS and (lcs.n, lcs.m, lcs.p) == (2, 1, 0)
    np.testing.assert_array_equal(lcs.A, A_SS)
    np.testing.assert_array_equal(lcs.B, B_SS)
    observed = mk_lbs(ss, W=0.1 * np.eye(2), V=[[0.2]])
    assert type(observed) is stl.POLBSWithLinNoise
    np.testing.assert_array_equal(observed.C, C_SS)
    np.testing.assert_allclose(observed.noise_cov(np.zeros(2)), [[0.04]])
    light = mk_lbs(ss, W=np.zeros((2, 2)), V=lambda s: [[0.1 + s[0] ** 2]])
    assert type(light) is stl.POLBSWithNonLinNoise
    noise_free = mk_lbs(ss, W=np.zeros((2, 2)))
    assert type(noise_free) is stl.POLBSWithLinNoise and noise_free.p == 1
    blind = mk_lbs(_StateSpace(A_SS, B_SS, np.zeros((0, 2)), np.zeros((0, 1)), dt), W=np.eye(2))
    assert type(blind) is stl.LBS
    assert stl.mk_switched_sys([lcs, observed, blind]).num_modes == 3


def test_scipy_state_space_is_accepted_when_discrete():
    signal = pytest.importorskip("scipy.signal")
    discrete = signal.StateSpace(A_SS, B_SS, C_SS, np.zeros((1, 1)), dt=0.1)
    np.testing.assert_array_equal(stl.mk_lcs(discrete).A, A_SS)
    continuous = signal.StateSpace(A_SS, B_SS, C_SS, np.zeros((1, 1)))
    with pytest.raises(stl.InvalidArgumentError, match="discrete-time .* dt=None"):
        stl.mk_lcs(continuous)


def test_python_control_state_space_is_accepted_when_discrete():
    control = pytest.importorskip("control")
    sys_d = control.ss(A_SS, B_SS, C_SS, 0, dt=0.1)
    np.testing.assert_array_equal(stl.mk_lcs(sys_d).B, B_SS)
    with pytest.raises(stl.InvalidArgumentError, match="discrete-time"):
        stl.mk_lcs(control.ss(A_SS, B_SS, C_SS, 0))


@pytest.mark.parametrize("dt", [0, 0.0, None, False, -0.1, float("inf"), "0.1"])
def test_state_space_in_continuous_or_unknown_time_is_rejected(dt):
    ss = _StateSpace(A_SS, B_SS, C_SS, np.zeros((1, 1)), dt)
    match = r"mk_lcs takes a discrete-time state-space system.*sample\(Ts\)"
    with pytest.raises(stl.InvalidArgumentError, match=match):
        stl.mk_lcs(ss)
    with pytest.raises(stl.InvalidArgumentError, match="mk_lbs takes a discrete-time"):
        mk_lbs(ss, W=np.eye(2))


def test_state_space_argument_errors():
    ss = _StateSpace(A_SS, B_SS, C_SS, [[0.5]], True)
    with pytest.raises(stl.InvalidArgumentError, match=r"D must be zero .* got D = \[\[0.5\]\]"):
        mk_lbs(ss, W=np.eye(2))
    ok = _StateSpace(A_SS, B_SS, C_SS, [[0.0]], True)
    with pytest.raises(stl.InvalidTypeError, match="mk_lcs: B comes from the state-space system"):
        stl.mk_lcs(ok, B_SS)
    with pytest.raises(stl.InvalidTypeError, match="mk_lbs: C comes from the state-space system"):
        mk_lbs(ok, W=np.eye(2), C=C_SS)
    with pytest.raises(stl.InvalidTypeError, match="mk_lbs needs W"):
        mk_lbs(ok)
    with pytest.raises(stl.InvalidArgumentError, match="_StateSpace.A contains NaN"):
        stl.mk_lcs(_StateSpace([[np.nan]], [[1.0]], [[1.0]], [[0.0]], True))


def test_switched_system_html_lists_modes():
    I2 = np.eye(2)
    system = stl.mk_switched_sys(
        [stl.mk_lcs(I2, I2), mk_lbs(I2, I2, I2, C=I2, V=0.1 * I2), mk_lbs(I2, I2, I2, C=I2, V=lambda s: I2)]
    )
    html = system._repr_html_()
    assert "3 modes, n=2 states, m=2 inputs" in html
    for text in ("none (blind)", "constant", "state-dependent V(x)", "POLBSWithNonLinNoise"):
        assert text in html
