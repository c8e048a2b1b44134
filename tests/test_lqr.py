"""Finite-horizon LQR: the backward Riccati recursion and its use as a tracking law."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

import idstlpy as stl
from idstlpy.errors import DimensionError, InvalidArgumentError
from idstlpy.tracking import finite_horizon_lqr, riccati_costs


def test_scalar_gains_match_hand_recursion():
    a, b, q, r, qf, h = 1.0, 0.5, 1.0, 0.1, 2.0, 3
    gains = finite_horizon_lqr([[a]], [[b]], h, [[qf]], [[q]], [[r]])
    P, expected = qf, []
    for _ in range(h):
        k = b * P * a / (r + b * b * P)
        P = q + a * P * (a - b * k)
        expected.append(k)
    expected.reverse()  # K_0 first
    assert len(gains) == h
    for K, k in zip(gains, expected, strict=True):
        assert K.shape == (1, 1)
        assert K[0, 0] == pytest.approx(k, rel=1e-12)


def test_matrix_gains_match_explicit_recursion():
    A = np.array([[1.0, 0.1], [0.0, 1.0]])
    B = np.array([[0.0], [0.1]])
    Q, Qf, R = np.diag([1.0, 0.5]), np.diag([3.0, 1.0]), np.array([[0.2]])
    gains, costs = riccati_costs(A, B, 4, Qf, Q, R)
    P = Qf
    for k in range(3, -1, -1):
        K = np.linalg.inv(R + B.T @ P @ B) @ B.T @ P @ A
        P = Q + A.T @ P @ A - A.T @ P @ B @ K
        np.testing.assert_allclose(gains[k], K, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(costs[k], P, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(costs[4], Qf)


def test_long_horizon_converges_to_dare():
    A = np.array([[1.0, 0.25], [0.0, 1.0]])
    B = np.array([[0.03], [0.25]])
    Q, R = np.eye(2), np.array([[0.05]])
    K0 = finite_horizon_lqr(A, B, 300, np.zeros((2, 2)), Q, R)[0]
    P = solve_discrete_are(A, B, Q, R)
    K_inf = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    np.testing.assert_allclose(K0, K_inf, rtol=1e-8)


def test_closed_loop_drives_perturbation_back():
    A = np.array([[1.0, 0.25], [0.0, 1.0]])  # double integrator: unstable open loop
    B = np.array([[0.03], [0.25]])
    K = finite_horizon_lqr(A, B, 5, np.eye(2), np.eye(2), 0.05 * np.eye(1))[0]
    assert np.max(np.abs(np.linalg.eigvals(A - B @ K))) < 1.0
    x = np.array([1.0, -0.5])
    for _ in range(200):
        x = A @ x - B @ (K @ x)
    assert np.linalg.norm(x) < 1e-6


def test_listing_compute_finite_horizon_lqr_stores_gains():
    mode = stl.mk_lcs(A=np.identity(2), B=0.25 * np.identity(2))
    gains = mode.compute_finite_horizon_lqr(
        horizon=5, Q_final=np.identity(2), Q=np.identity(2), R=0.05 * np.identity(2)
    )
    assert mode.lqr_gains is gains and len(gains) == 5
    assert all(K.shape == (2, 2) for K in gains)
    # Isotropic problem: the gains are multiples of the identity.
    np.testing.assert_allclose(gains[0], gains[0][0, 0] * np.eye(2), atol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"R": np.zeros((1, 1))}, InvalidArgumentError, "R must be positive definite"),
        ({"R": -np.eye(1)}, InvalidArgumentError, "R must be positive semi-definite"),
        ({"Q": -np.eye(2)}, InvalidArgumentError, "Q must be positive semi-definite"),
        ({"Q_final": np.array([[1.0, 2.0], [0.0, 1.0]])}, InvalidArgumentError, "Q_final must be symmetric"),
        ({"Q": np.eye(3)}, DimensionError, "Q must have shape"),
        ({"R": np.eye(2)}, DimensionError, "R must have shape"),
        ({"B": np.ones((3, 1))}, DimensionError, "B must have shape"),
        ({"horizon": 0}, InvalidArgumentError, "horizon must be >= 1"),
        ({"horizon": 2.5}, InvalidArgumentError, "horizon"),
    ],
)
def test_invalid_arguments_name_the_argument(kwargs, error, match):
    args = {
        "A": np.eye(2),
        "B": np.ones((2, 1)),
        "horizon": 3,
        "Q_final": np.eye(2),
        "Q": np.eye(2),
        "R": np.eye(1),
    }
    args.update(kwargs)
    with pytest.raises(error, match=match):
        finite_horizon_lqr(**args)
