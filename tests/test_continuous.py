"""Modes from continuous-time models: checked against python-control's c2d and a fine-grained
Monte Carlo of the continuous noise (an independent integration, not Van Loan's formula)."""

from __future__ import annotations

import control
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import idstlpy as stl
from idstlpy.continuous import cov_factor, discretize, from_continuous

# A damped oscillator with a second input: rotating, non-invertible-free dynamics.
A_OSC = np.array([[0.0, 1.0], [-2.0, -0.3]])
B_OSC = np.array([[0.0, 0.5], [1.0, 0.0]])


def _random_stable(rng: np.random.Generator, n: int) -> np.ndarray:
    M = rng.normal(size=(n, n))
    return M - (np.max(np.linalg.eigvals(M).real) + 0.5) * np.eye(n)


@pytest.mark.parametrize("dt", [0.01, 0.1, 0.7])
def test_zero_order_hold_matches_python_control(dt):
    d = discretize(A_OSC, B_OSC, dt)
    ref = control.c2d(control.ss(A_OSC, B_OSC, np.eye(2), np.zeros((2, 2))), dt, method="zoh")
    np.testing.assert_allclose(d.A, ref.A, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(d.B, ref.B, rtol=1e-10, atol=1e-12)
    assert d.dt == dt
    np.testing.assert_array_equal(d.Q, np.zeros((2, 2)))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 4), m=st.integers(1, 3), dt=st.floats(0.01, 2.0))
def test_zoh_property_against_python_control(seed, n, m, dt):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    B = rng.normal(size=(n, m))
    d = discretize(A, B, dt)
    ref = control.c2d(control.ss(A, B, np.eye(n), np.zeros((n, m))), dt, method="zoh")
    np.testing.assert_allclose(d.A, ref.A, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(d.B, ref.B, rtol=1e-8, atol=1e-10)


def test_noise_discretisation_scalar_closed_form():
    # dx = a x dt + dbeta, intensity q: Q_d = q (exp(2 a dt) - 1) / (2 a); integrator: q dt.
    a, q, dt = -0.8, 0.3, 0.5
    d = discretize([[a]], [[1.0]], dt, noise_intensity=[[q]])
    assert d.Q[0, 0] == pytest.approx(q * (np.exp(2 * a * dt) - 1) / (2 * a), rel=1e-12)
    d0 = discretize([[0.0]], [[1.0]], dt, noise_intensity=[[q]])
    assert d0.Q[0, 0] == pytest.approx(q * dt, rel=1e-12)


def test_noise_discretisation_double_integrator_closed_form():
    # The classic white-noise-acceleration model: Q_d = q [[dt^3/3, dt^2/2], [dt^2/2, dt]].
    q, dt = 0.7, 0.2
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    d = discretize(A, [[0.0], [1.0]], dt, noise_intensity=np.diag([0.0, q]))
    expected = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    np.testing.assert_allclose(d.Q, expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(d.W @ d.W.T, d.Q, rtol=1e-10, atol=1e-15)


def test_noise_discretisation_against_fine_monte_carlo():
    # Euler-Maruyama with 400 substeps per period, 40,000 paths: the covariance after one period
    # must match Q_d within the sampling error (relative standard error ~ sqrt(2 / 40000) = 0.7%).
    Qc = np.array([[0.2, 0.05], [0.05, 0.4]])
    dt, sub, paths = 0.5, 400, 40_000
    h = dt / sub
    rng = np.random.default_rng(12345)
    L = np.linalg.cholesky(Qc * h)
    X = np.zeros((paths, 2))
    Ah = np.eye(2) + A_OSC * h
    for _ in range(sub):
        X = X @ Ah.T + rng.standard_normal((paths, 2)) @ L.T
    empirical = np.cov(X.T)
    d = discretize(A_OSC, B_OSC, dt, noise_intensity=Qc)
    scale = np.sqrt(np.outer(np.diag(d.Q), np.diag(d.Q)))
    # 5% of the entries' scale: ~7 standard errors of the sampling plus Euler's O(h) bias.
    np.testing.assert_array_less(np.abs(empirical - d.Q), 0.05 * scale)


def test_from_continuous_state_space_builds_the_mode_mk_lbs_would():
    sys_c = control.ss(A_OSC, B_OSC, [[1.0, 0.0]], [[0.0, 0.0]])
    R = np.array([[0.04]])
    mode = from_continuous(sys_c, dt=0.1, noise_intensity=0.01 * np.eye(2), V_cov=R)
    d = discretize(A_OSC, B_OSC, 0.1, 0.01 * np.eye(2))
    assert isinstance(mode, stl.POLBSWithLinNoise)
    np.testing.assert_allclose(mode.A, d.A)
    np.testing.assert_allclose(mode.B, d.B)
    np.testing.assert_allclose(mode.W @ mode.W.T, d.Q, atol=1e-15)
    np.testing.assert_allclose(mode.noise_cov(np.zeros(2)), R)
    np.testing.assert_array_equal(mode.C, [[1.0, 0.0]])
    # Python-control's own discretisation gives the same A, B for the same system.
    ref = control.c2d(sys_c, 0.1, method="zoh")
    np.testing.assert_allclose(mode.A, ref.A, rtol=1e-10)
    np.testing.assert_allclose(mode.B, ref.B, rtol=1e-10)


def test_from_continuous_matrices_blind_and_state_dependent():
    blind = from_continuous(A_OSC, B_OSC, dt=0.2)
    assert type(blind) is stl.LBS
    np.testing.assert_array_equal(blind.W, np.zeros((2, 2)))
    lit = from_continuous(
        A_OSC, B_OSC, dt=0.2, C=np.eye(2), V=lambda x: (0.1 + x[0] ** 2) * np.eye(2), V_floor=0.1
    )
    assert lit.has_state_dependent_noise
    np.testing.assert_allclose(lit.noise_cov(np.array([1.0, 0.0])), 1.21 * np.eye(2))


def test_a_continuous_mode_solves_and_its_plan_holds():
    # A continuous-time 1-D integrator sampled at 0.5 s, measured with R = 0.01: reach [0.9, 1.1].
    x = stl.mk_variable(1, float)
    u = stl.mk_variable(1, float)
    mode = from_continuous([[0.0]], [[1.0]], dt=0.5, noise_intensity=[[1e-3]], C=[[1.0]], V_cov=[[0.01]])
    problem = stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.zeros(1), cov=0.01 * np.eye(1)),
        stl_formula=stl.eventually(
            0, 10, stl.logical_and(stl.prob(x[0] >= 0.9) >= 0.9, stl.prob(x[0] <= 1.1) >= 0.9, name="goal")
        ),
    )
    result = problem.solve_result(rrt_timeout=5, seed=0)
    assert result.status == "found"
    assert stl.satisfies(result.trajectory, problem.stl_formula)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"A": A_OSC, "B": B_OSC, "dt": 0.0}, stl.InvalidArgumentError, "dt"),
        ({"A": A_OSC, "B": B_OSC, "dt": float("nan")}, stl.InvalidArgumentError, "dt"),
        ({"A": A_OSC, "B": B_OSC, "dt": "0.1"}, stl.InvalidTypeError, "dt"),
        ({"A": A_OSC, "dt": 0.1}, stl.InvalidTypeError, "needs B"),
        ({"A": A_OSC, "B": np.ones((3, 1)), "dt": 0.1}, stl.DimensionError, "B must have n = 2"),
        (
            {"A": A_OSC, "B": B_OSC, "dt": 0.1, "noise_intensity": -np.eye(2)},
            stl.InvalidArgumentError,
            "noise_intensity must be positive semi-definite",
        ),
        (
            {"A": A_OSC, "B": B_OSC, "dt": 0.1, "noise_intensity": np.eye(3)},
            stl.DimensionError,
            "noise_intensity must have shape",
        ),
        ({"A": A_OSC, "B": B_OSC, "dt": 0.1, "V_cov": np.eye(2)}, stl.InvalidArgumentError, "without C"),
        (
            {"A": A_OSC, "B": B_OSC, "dt": 0.1, "C": np.eye(2), "V_cov": np.eye(2), "V": np.eye(2)},
            stl.InvalidArgumentError,
            "not both",
        ),
        (
            {"A": A_OSC, "B": B_OSC, "dt": 0.1, "C": np.eye(2), "V_cov": [[1.0, 2.0], [0.0, 1.0]]},
            stl.InvalidArgumentError,
            "V_cov must be symmetric",
        ),
    ],
)
def test_bad_input_is_named(kwargs, error, match):
    with pytest.raises(error, match=match):
        from_continuous(**kwargs)


def test_state_space_misuse_is_named():
    sys_d = control.ss(A_OSC, B_OSC, np.eye(2), np.zeros((2, 2)), 0.1)
    with pytest.raises(stl.InvalidArgumentError, match="continuous-time"):
        from_continuous(sys_d, dt=0.1)
    with pytest.raises(stl.InvalidTypeError, match="B comes from the state-space system"):
        from_continuous(control.ss(A_OSC, B_OSC, np.eye(2), np.zeros((2, 2))), B_OSC, dt=0.1)
    with pytest.raises(stl.InvalidArgumentError, match="D must be zero"):
        from_continuous(control.ss(A_OSC, B_OSC, np.eye(2), np.ones((2, 2))), dt=0.1)
    # mk_lbs of a continuous system points at from_continuous.
    with pytest.raises(stl.InvalidArgumentError, match="from_continuous"):
        stl.mk_lbs(control.ss(A_OSC, B_OSC, np.eye(2), np.zeros((2, 2))), W=np.zeros((2, 2)))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), k=st.integers(1, 4), rank=st.integers(0, 4))
def test_cov_factor_is_a_root_of_singular_covariances(seed, k, rank):
    rng = np.random.default_rng(seed)
    G = rng.normal(size=(k, min(rank, k)))
    S = G @ G.T
    F = cov_factor(S)
    np.testing.assert_allclose(F @ F.T, S, atol=1e-10 * max(1.0, np.abs(S).max()))


def test_random_stable_noise_against_integral_quadrature():
    # Q_d = int_0^dt e^{As} Qc e^{A's} ds by Gauss-Legendre quadrature (independent of Van Loan).
    import scipy.linalg

    rng = np.random.default_rng(7)
    for n in (1, 2, 3):
        A = _random_stable(rng, n)
        G = rng.normal(size=(n, n))
        Qc = G @ G.T
        dt = 0.3
        nodes, weights = np.polynomial.legendre.leggauss(40)
        s = 0.5 * dt * (nodes + 1)
        Q = sum(
            0.5 * dt * w * scipy.linalg.expm(A * si) @ Qc @ scipy.linalg.expm(A * si).T
            for si, w in zip(s, weights, strict=True)
        )
        np.testing.assert_allclose(discretize(A, np.ones((n, 1)), dt, Qc).Q, Q, rtol=1e-9, atol=1e-12)
