"""Finite-horizon discrete-time LQR: the backward Riccati recursion (the paper's Section IV-E).

A model-layer module: a mode computes its own gains with it
(:meth:`~idstlpy.dynamical_system.LCS.compute_finite_horizon_lqr`), and the executor's tracking law
(:mod:`idstlpy.tracking`) uses them.

For ``x_{k+1} = A x_k + B u_k`` and the cost
``J = x_h' Q_final x_h + sum_{k<h} x_k' Q x_k + u_k' R u_k`` the backward Riccati recursion is::

    P_h = Q_final
    K_k = (R + B' P_{k+1} B)^{-1} B' P_{k+1} A
    P_k = Q + A' P_{k+1} (A - B K_k)

and the optimal input is ``u_k = -K_k x_k``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._checks import as_covariance, as_int, as_matrix
from .errors import DimensionError, InvalidArgumentError

__all__ = ["TrackingGains", "finite_horizon_lqr", "riccati_costs"]


def _validate(
    A: Any, B: Any, horizon: Any, Q_final: Any, Q: Any, R: Any
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray, np.ndarray]:
    A = as_matrix(A, "A")
    if A.shape[0] != A.shape[1]:
        raise DimensionError(f"A must be square, got shape {A.shape}")
    n = A.shape[0]
    B = as_matrix(B, "B", (n, None))
    m = B.shape[1]
    if m == 0:
        raise DimensionError("B must have at least one column (the system has no input)")
    horizon = as_int(horizon, "horizon", minimum=1)
    Q_final = as_covariance(Q_final, "Q_final", n)
    Q = as_covariance(Q, "Q", n)
    R = as_covariance(R, "R", m)
    if float(np.linalg.eigvalsh(R)[0]) <= 1e-12 * max(1.0, float(np.max(np.abs(R)))):
        raise InvalidArgumentError(
            f"R must be positive definite; its smallest eigenvalue is {float(np.linalg.eigvalsh(R)[0]):.3g}"
        )
    return A, B, horizon, Q_final, Q, R


def riccati_costs(
    A: Any, B: Any, horizon: int, Q_final: Any, Q: Any, R: Any
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Gains and cost-to-go matrices of the backward Riccati recursion.

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, m)
    horizon : int
        Number of steps ``h >= 1``.
    Q_final, Q : array_like, shape (n, n)
        Terminal and stage state weights (symmetric positive semi-definite).
    R : array_like, shape (m, m)
        Input weight (symmetric positive definite).

    Returns
    -------
    gains : list of ndarray, each shape (m, n)
        ``K_0 .. K_{h-1}``.
    costs : list of ndarray, each shape (n, n)
        ``P_0 .. P_h`` (``P_h = Q_final``); ``x' P_0 x`` is the optimal cost from ``x``.
    """
    A, B, h, Q_final, Q, R = _validate(A, B, horizon, Q_final, Q, R)
    P = Q_final
    gains: list[np.ndarray] = [np.empty(0)] * h
    costs: list[np.ndarray] = [np.empty(0)] * (h + 1)
    costs[h] = P
    for k in range(h - 1, -1, -1):
        S = R + B.T @ P @ B
        K = np.linalg.solve(S, B.T @ P @ A)
        P = Q + A.T @ P @ (A - B @ K)
        P = 0.5 * (P + P.T)
        gains[k] = K
        costs[k] = P
    return gains, costs


def finite_horizon_lqr(A: Any, B: Any, horizon: int, Q_final: Any, Q: Any, R: Any) -> list[np.ndarray]:
    """Gains of the finite-horizon discrete LQR (backward Riccati recursion).

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, m)
    horizon : int
        Number of steps ``h >= 1`` of the receding horizon.
    Q_final, Q : array_like, shape (n, n)
        Terminal and stage state weights (symmetric positive semi-definite).
    R : array_like, shape (m, m)
        Input weight (symmetric positive definite).

    Returns
    -------
    list of ndarray, each shape (m, n)
        ``K_0 .. K_{h-1}``; the tracking law is ``u = u_plan - K_0 (x_est - x_plan)``.

    Raises
    ------
    DimensionError
        When the shapes disagree.
    InvalidArgumentError
        When ``horizon < 1``, ``Q``/``Q_final`` is not symmetric PSD or ``R`` is not
        symmetric positive definite.
    """
    return riccati_costs(A, B, horizon, Q_final, Q, R)[0]


@dataclass(frozen=True)
class TrackingGains:
    """The tracking a plan was made for: every mode's gains, and the weights that made them.

    Made by :func:`idstlpy.tracking.make_tracking`; a model-layer record because a plan carries
    it (:attr:`idstlpy.trajectory.ProbabilisticTSTrajectory.tracking`).

    Parameters
    ----------
    name : str
        ``"fitted"`` (Bryson's rule, :func:`idstlpy.tracking.fitted_weights`), ``"fitted x10"``,
        ``"fitted x100"`` (firmer) or ``"paper"`` (:data:`idstlpy.tracking.DEFAULT_LQR`).
    weights : mapping or None
        ``horizon``, ``Q_final``, ``Q``, ``R`` of the modes without their own gains.
    gains : mapping
        Mode -> gains ``K_0 .. K_{h-1}`` (each (m, n)) of every mode.
    """

    name: str
    weights: Mapping[str, Any] | None
    gains: Mapping[int, tuple[np.ndarray, ...]]

    def describe(self) -> str:
        """One phrase naming the weights, e.g. ``fitted gains (Q = diag(400, 0), R = diag(0.25))``."""
        if self.weights is None:
            return f"{self.name} gains"
        Q, R = (np.atleast_1d(np.asarray(self.weights[k], dtype=float)) for k in ("Q", "R"))
        qd = np.diag(Q) if Q.ndim == 2 else Q
        rd = np.diag(R) if R.ndim == 2 else R
        fmt = ", ".join
        return (
            f"{self.name} gains (Q = diag({fmt(f'{v:.3g}' for v in qd)}), "
            f"R = diag({fmt(f'{v:.3g}' for v in rd)}), horizon {int(self.weights['horizon'])})"
        )

    def default_lqr(self) -> dict[str, Any] | None:
        """The weights as the ``default_lqr`` keyword of the executors (lists, JSON-able)."""
        if self.weights is None:
            return None
        return {
            k: (np.asarray(v, dtype=float).tolist() if not np.isscalar(v) else v)
            for k, v in self.weights.items()
        }

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able data."""
        return {
            "name": self.name,
            "weights": self.default_lqr(),
            "gains": {str(q): [K.tolist() for K in Ks] for q, Ks in self.gains.items()},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TrackingGains:
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        data : mapping
            Output of :meth:`to_dict`.

        Returns
        -------
        TrackingGains
        """
        gains = {
            int(q): tuple(np.asarray(K, dtype=float) for K in Ks) for q, Ks in dict(data["gains"]).items()
        }
        return cls(str(data["name"]), data.get("weights"), gains)
