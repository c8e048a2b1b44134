"""Modes from continuous-time models: zero-order hold for the inputs, exact noise discretisation.

Control users keep their plants in continuous time (``dx = (A x + B u) dt + dbeta``, python-control's
``control.ss``). idstlpy plans over sampled steps, so a mode needs the discrete matrices of one
sampling period ``dt``:

* inputs held constant over the period (zero-order hold)::

      A_d = exp(A dt),    B_d = int_0^dt exp(A s) ds B

* a white process noise of intensity ``Q_c`` (``E[dbeta dbeta'] = Q_c dt``) integrates to a
  Gaussian disturbance of covariance (the exact discretisation, computed by Van Loan's method)::

      Q_d = int_0^dt exp(A s) Q_c exp(A' s) ds

The model layer takes square-root factors (``W`` with ``W W' = Q_d``, ``V`` with ``V V' = R``); this
module works in covariances, which is what a datasheet or a continuous model gives, and returns the
factor (:func:`cov_factor`), so the two conventions cannot be mixed up. Sensors are sampled once per
period: ``V_cov`` is the covariance of one sample, not a spectral density.

python-control is optional: a ``StateSpace`` (or any object with ``A``, ``B``, ``C``, ``D`` and
``dt``) is read by its attributes, never imported.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from ._checks import as_float, as_matrix
from .dynamical_system import LBS, _is_state_space, mk_lbs
from .errors import DimensionError, InvalidArgumentError, InvalidTypeError

__all__ = ["Discretization", "cov_factor", "discretize", "from_continuous"]

NoiseFactor = np.ndarray | Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Discretization:
    """One sampling period of a continuous-time linear model.

    Attributes
    ----------
    A : ndarray, shape (n, n)
        ``exp(A_c dt)``.
    B : ndarray, shape (n, m)
        Zero-order-hold input matrix.
    Q : ndarray, shape (n, n)
        Covariance of the integrated process noise over one period (zeros without noise).
    W : ndarray, shape (n, n)
        A square-root factor of ``Q`` (``W @ W.T == Q``), the form :func:`idstlpy.mk_lbs` takes.
    dt : float
        The sampling period.
    """

    A: np.ndarray
    B: np.ndarray
    Q: np.ndarray
    W: np.ndarray
    dt: float


def cov_factor(cov: Any, name: str = "cov") -> np.ndarray:
    """A square-root factor ``F`` of a covariance (``F @ F.T == cov``), for ``W`` or ``V``.

    Parameters
    ----------
    cov : array_like, shape (k, k)
        Symmetric positive semi-definite matrix.
    name : str
        The argument's name in error messages.

    Returns
    -------
    ndarray, shape (k, k)
        The symmetric square root (eigen-decomposition; exact for singular covariances, where a
        Cholesky factor does not exist).

    Raises
    ------
    DimensionError
        When ``cov`` is not square.
    InvalidArgumentError
        When ``cov`` is not symmetric or has a negative eigenvalue (beyond rounding).
    """
    S = as_matrix(cov, name)
    if S.shape[0] != S.shape[1]:
        raise DimensionError(f"{name} must be a square covariance matrix, got shape {S.shape}")
    scale = max(1.0, float(np.max(np.abs(S))))
    if not np.allclose(S, S.T, rtol=1e-9, atol=1e-12 * scale):
        raise InvalidArgumentError(f"{name} must be symmetric (a covariance matrix)")
    S = 0.5 * (S + S.T)
    lam, U = np.linalg.eigh(S)
    if lam.min(initial=0.0) < -1e-9 * scale:
        raise InvalidArgumentError(
            f"{name} must be positive semi-definite (a covariance matrix), "
            f"smallest eigenvalue {lam.min():.3g}"
        )
    # The symmetric root U sqrt(L) U' (not U sqrt(L)): a diagonal covariance gets a diagonal factor.
    return (U * np.sqrt(np.clip(lam, 0.0, None))) @ U.T


def discretize(A: Any, B: Any, dt: float, noise_intensity: Any = None) -> Discretization:
    """Discretize ``dx = (A x + B u) dt + dbeta`` over one period (ZOH inputs, exact noise).

    Parameters
    ----------
    A : array_like, shape (n, n)
        Continuous-time state matrix.
    B : array_like, shape (n, m)
        Continuous-time input matrix.
    dt : float
        Sampling period (> 0).
    noise_intensity : array_like, shape (n, n), optional
        Intensity ``Q_c`` of the white process noise (``E[dbeta dbeta'] = Q_c dt``), symmetric
        positive semi-definite. For noise entering through ``G`` with intensity ``Q_w``, pass
        ``G @ Q_w @ G.T``. ``None``: no process noise.

    Returns
    -------
    Discretization
        ``A``, ``B``, the noise covariance ``Q`` and its factor ``W``.

    Raises
    ------
    DimensionError
        For shapes that disagree.
    InvalidArgumentError
        For a non-positive or non-finite ``dt``, non-finite entries, or an intensity that is not a
        covariance.
    """
    Ac = as_matrix(A, "A")
    n = Ac.shape[0]
    if Ac.shape != (n, n):
        raise DimensionError(f"A must be square (n, n), got shape {Ac.shape}")
    Bc = as_matrix(B, "B")
    if Bc.shape[0] != n:
        raise DimensionError(f"B must have n = {n} rows (A is {n} x {n}), got shape {Bc.shape}")
    h = as_float(dt, "dt", low=0.0, low_open=True)
    m = Bc.shape[1]
    # Zero-order hold: exp([[A, B], [0, 0]] dt) = [[A_d, B_d], [0, I]].
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = Ac, Bc
    E = scipy.linalg.expm(M * h)
    Ad, Bd = E[:n, :n], E[:n, n:]
    if noise_intensity is None:
        Q = np.zeros((n, n))
    else:
        Qc = as_matrix(noise_intensity, "noise_intensity")
        if Qc.shape != (n, n):
            raise DimensionError(f"noise_intensity must have shape ({n}, {n}), got {Qc.shape}")
        cov_factor(Qc, "noise_intensity")  # validates symmetry and semi-definiteness
        # Van Loan (1978): exp([[-A, Q_c], [0, A']] dt) = [[., F12], [0, F22]], A_d = F22',
        # Q_d = A_d F12. Exact for any A (no series truncation), singular A included.
        V = np.zeros((2 * n, 2 * n))
        V[:n, :n], V[:n, n:], V[n:, n:] = -Ac, 0.5 * (Qc + Qc.T), Ac.T
        F = scipy.linalg.expm(V * h)
        Q = Ad @ F[:n, n:]
        Q = 0.5 * (Q + Q.T)
    return Discretization(A=Ad, B=Bd, Q=Q, W=cov_factor(Q, "Q_d"), dt=h)


def _continuous_matrices(sys: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``A, B`` and ``C`` (None without outputs) of a continuous-time state-space object."""
    dt = sys.dt
    if dt is not None and not (isinstance(dt, int | float | np.integer | np.floating) and dt == 0):
        raise InvalidArgumentError(
            f"from_continuous takes a continuous-time system (dt = 0), got {type(sys).__name__} with "
            f"dt={dt!r}; a discrete-time system goes to mk_lbs directly"
        )
    name = type(sys).__name__
    D = as_matrix(sys.D, f"{name}.D") if np.size(sys.D) else np.zeros((0, 0))
    if np.any(D != 0):
        raise InvalidArgumentError(
            f"from_continuous: the system's D must be zero (outputs y = C x + v have no feedthrough), "
            f"got D = {D.tolist()}"
        )
    C = np.asarray(sys.C, dtype=float)
    return (
        as_matrix(sys.A, f"{name}.A"),
        as_matrix(sys.B, f"{name}.B"),
        as_matrix(C, f"{name}.C") if C.size and C.shape[0] > 0 else None,
    )


def from_continuous(
    A: Any,
    B: Any = None,
    *,
    dt: float,
    noise_intensity: Any = None,
    C: Any = None,
    V_cov: Any = None,
    V: NoiseFactor | None = None,
    V_floor: Any = None,
) -> LBS:
    """A mode from continuous-time dynamics sampled every ``dt`` (the paper's ``mk_lbs``, continuous).

    ``dx = (A x + B u) dt + dbeta`` with inputs held over each period and, with ``C``, one
    measurement ``y = C x + v`` per period. The returned mode is exactly :func:`idstlpy.mk_lbs`
    of the discretised matrices (:func:`discretize`).

    Parameters
    ----------
    A : array_like of shape (n, n), or a continuous-time state-space system
        State matrix, or an object with ``A``, ``B``, ``C``, ``D`` and ``dt = 0`` (python-control's
        ``control.ss(A, B, C, D)``); its ``C`` becomes the sensor (none when it has no outputs) and
        its ``D`` must be zero.
    B : array_like, shape (n, m)
        Input matrix; omitted with a state-space system.
    dt : float
        Sampling period (> 0), keyword only.
    noise_intensity : array_like, shape (n, n), optional
        Process-noise intensity ``Q_c`` (covariance per unit time), see :func:`discretize`.
    C : array_like, shape (p, n), optional
        Output matrix (omitted with a state-space system, which carries its own).
    V_cov : array_like, shape (p, p), optional
        Covariance ``R`` of one measurement (a covariance, not a factor). Without ``V_cov`` and
        ``V`` the sensor is noise-free.
    V : array_like of shape (p, r), or callable x -> (p, r), optional
        Alternatively, the measurement-noise *factor* as :func:`idstlpy.mk_lbs` takes it
        (a callable for state-dependent noise). Not together with ``V_cov``.
    V_floor : float or array_like, optional
        As in :func:`idstlpy.mk_lbs`, for a callable ``V``.

    Returns
    -------
    LBS
        An ``LBS`` (blind) or an observed ``POLBS`` subclass, as :func:`idstlpy.mk_lbs` returns.

    Raises
    ------
    InvalidTypeError
        When ``B`` is missing, or ``B`` / ``C`` is given with a state-space system.
    InvalidArgumentError
        For a discrete-time system, a non-zero ``D``, both ``V`` and ``V_cov``, or an invalid
        ``dt`` / covariance.
    DimensionError
        For shapes that disagree.
    """
    if _is_state_space(A):
        if B is not None or C is not None:
            which = "B" if B is not None else "C"
            raise InvalidTypeError(f"from_continuous: {which} comes from the state-space system")
        A, B, C = _continuous_matrices(A)
    if B is None:
        raise InvalidTypeError("from_continuous needs B, the input matrix of shape (n, m)")
    if V is not None and V_cov is not None:
        raise InvalidArgumentError("from_continuous: give the measurement noise as V_cov or V, not both")
    d = discretize(A, B, dt, noise_intensity)
    if V_cov is not None:
        if C is None:
            raise InvalidArgumentError("V_cov (measurement noise) was given without C (output matrix)")
        V = cov_factor(V_cov, "V_cov")
    return mk_lbs(A=d.A, B=d.B, W=d.W, C=C, V=V, V_floor=V_floor)
