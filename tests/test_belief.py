"""Gaussian beliefs and the MLO Kalman step (algorithm.md section 2)."""

from __future__ import annotations

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.dynamical_system import mk_lbs


def _light_dark_noise(state):
    return ((5.0 - state[0]) ** 2 / 10.0 + 0.001) * np.eye(2)


def test_isotropic_scalar_oracle():
    """A = I, W = 0, C = I, R = n(mean')^2 I: 1/s'^2 = 1/s^2 + 1/n(mean')^2."""
    mode = mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=np.zeros((2, 2)), C=np.eye(2), V=_light_dark_noise)
    rng = np.random.default_rng(0)
    for _ in range(25):
        mean = rng.uniform(-1.0, 6.0, size=2)
        s = float(rng.uniform(0.05, 2.0))
        u = rng.uniform(-1.0, 1.0, size=2)
        new_mean, new_cov = stl.belief_step(mode, mean, s**2 * np.eye(2), u)
        np.testing.assert_allclose(new_mean, mean + 0.25 * u, atol=1e-12)
        noise = (5.0 - new_mean[0]) ** 2 / 10.0 + 0.001
        s2 = 1.0 / (1.0 / s**2 + 1.0 / noise**2)
        np.testing.assert_allclose(new_cov, s2 * np.eye(2), rtol=1e-9, atol=1e-14)


def test_lbs_step_is_prediction_only():
    A = np.array([[1.0, 0.5], [0.0, 1.0]])
    B = np.array([[0.0], [1.0]])
    W = np.array([[0.1, 0.0], [0.2, 0.3]])
    mode = mk_lbs(A, B, W)
    mean, cov = np.array([1.0, 2.0]), np.array([[1.0, 0.2], [0.2, 0.5]])
    m2, c2 = stl.belief_step(mode, mean, cov, np.array([3.0]))
    np.testing.assert_allclose(m2, [2.0, 5.0])
    np.testing.assert_allclose(c2, A @ cov @ A.T + W @ W.T)


def test_noise_free_sensor_collapses_observed_directions():
    mode = mk_lbs(np.eye(2), np.eye(2), 0.1 * np.eye(2), C=[[1.0, 0.0]])  # V=None: exact sensor
    _, cov = stl.belief_step(mode, np.zeros(2), np.eye(2), np.zeros(2))
    assert cov[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert cov[1, 1] == pytest.approx(1.01)


def _kalman_filter_errors(modes, actions, mean0, cov0, num_samples, rng):
    """Run a textbook Kalman filter on sampled states and observations; return the errors.

    Written independently of idstlpy.belief: standard-form update ``P = (I - K C) P``.
    """
    n = mean0.shape[0]
    x = rng.multivariate_normal(mean0, cov0, size=num_samples)
    xhat = np.tile(mean0, (num_samples, 1))
    P = cov0.copy()
    errors, covs = [x - xhat], [P.copy()]
    for q in actions:
        A, B, W, C, V = modes[q]
        u = np.ones(B.shape[1])
        x = x @ A.T + u @ B.T + rng.normal(size=(num_samples, W.shape[1])) @ W.T
        xhat = xhat @ A.T + u @ B.T
        P = A @ P @ A.T + W @ W.T
        if C is not None:
            y = x @ C.T + rng.normal(size=(num_samples, V.shape[1])) @ V.T
            S = C @ P @ C.T + V @ V.T
            K = P @ C.T @ np.linalg.inv(S)
            xhat = xhat + (y - xhat @ C.T) @ K.T
            P = (np.eye(n) - K @ C) @ P
        errors.append(x - xhat)
        covs.append(P.copy())
    return errors, covs


def test_mlo_covariance_equals_kalman_error_covariance_monte_carlo():
    A = np.array([[1.0, 0.1], [0.0, 0.95]])
    B = np.array([[0.0], [0.1]])
    W = np.diag([0.1, 0.05])
    C = np.array([[1.0, 0.0]])
    V = np.array([[0.2]])
    raw = [(A, B, W, C, V), (A, B, W, None, None)]
    system = stl.mk_switched_sys([mk_lbs(A, B, W, C, V), mk_lbs(A, B, W)])
    mean0, cov0 = np.array([0.0, 1.0]), np.diag([0.5, 0.3])
    actions = [0, 1, 0, 0, 1, 0]
    plan = stl.rollout(system, stl.to_belief(mean0, cov0), actions, np.ones((len(actions), 1)))
    rng = np.random.default_rng(12345)
    errors, covs = _kalman_filter_errors(raw, actions, mean0, cov0, 100_000, rng)
    for k in range(len(actions) + 1):
        planned = plan.get_cov(k)
        np.testing.assert_allclose(planned, covs[k], rtol=1e-9, atol=1e-12)
        empirical = np.cov(errors[k].T)
        scale = float(np.max(np.abs(planned)))
        np.testing.assert_allclose(empirical, planned, atol=0.03 * scale)
        assert np.all(np.abs(errors[k].mean(axis=0)) < 0.02)
    # the MLO mean is the noise-free prediction (zero innovation)
    np.testing.assert_allclose(plan.get_mean(1), A @ mean0 + B @ np.ones(1))


def test_covariance_stays_symmetric_psd_over_long_rollout():
    rot = 0.999 * np.array([[np.cos(0.1), -np.sin(0.1)], [np.sin(0.1), np.cos(0.1)]])
    B = np.eye(2)
    modes = [
        mk_lbs(rot, B, 0.05 * np.eye(2)),
        mk_lbs(np.eye(2), B, np.array([[0.02, 0.0], [0.01, 0.0]]), C=[[1.0, 0.0]], V=[[1e-4]]),
        mk_lbs(rot.T, B, 0.01 * np.eye(2), C=np.eye(2), V=_light_dark_noise),
        mk_lbs(
            np.array([[1.0, 1.0], [0.0, 1.0]]) * 0.9,
            B,
            np.zeros((2, 1)),
            C=[[0.0, 1.0]],
            V=[[1e-6]],
        ),
    ]
    system = stl.mk_switched_sys(modes)
    rng = np.random.default_rng(7)
    N = 2000
    actions = rng.integers(0, len(modes), size=N)
    controls = rng.uniform(-0.5, 0.5, size=(N, 2))
    traj = stl.rollout(system, stl.to_belief([1.0, 2.0], np.diag([1.0, 1e-3])), actions, controls)
    covs = traj.get_cov()
    assert covs.shape == (N + 1, 2, 2)
    assert np.all(np.isfinite(covs))
    np.testing.assert_allclose(covs, np.transpose(covs, (0, 2, 1)), atol=1e-12)
    eig = np.linalg.eigvalsh(covs)
    scale = np.maximum(1.0, np.abs(eig).max(axis=1))
    assert np.all(eig[:, 0] >= -1e-10 * scale)


def test_to_belief_and_sampling():
    b = stl.to_belief([1, 2], [[2.0, 0.5], [0.5, 1.0]])
    assert isinstance(b, stl.GaussianBelief) and b.n == 2
    xs = b.sample(200_000, seed=1)
    assert xs.shape == (200_000, 2)
    np.testing.assert_allclose(xs.mean(axis=0), [1.0, 2.0], atol=0.02)
    np.testing.assert_allclose(np.cov(xs.T), [[2.0, 0.5], [0.5, 1.0]], atol=0.03)
