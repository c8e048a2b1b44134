"""Dynamical systems (paper Fig. 6): LCS, LBS, POLBS and switched systems of them.

Each mode ``q`` of a switched system is::

    x_{k+1} = A x_k + B u_k + W w_k,          w_k ~ N(0, I)
    y_k     = C x_k + n(x_k) v_k,             v_k ~ N(0, I)

An :class:`LCS` has neither disturbance nor output; an :class:`LBS` adds the disturbance ``W``;
a :class:`POLBS` adds the output ``C`` with a constant noise matrix
(:class:`POLBSWithLinNoise`) or a noise function of the state (:class:`POLBSWithNonLinNoise`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ._checks import as_matrix, as_vector
from .errors import DimensionError, InvalidArgumentError, InvalidTypeError, NoiseFunctionError

if TYPE_CHECKING:
    from .trajectory import ProbabilisticTSTrajectory, RealTrajectory

__all__ = [
    "DynamicalSystem",
    "LCS",
    "LBS",
    "POLBS",
    "POLBSWithLinNoise",
    "POLBSWithNonLinNoise",
    "SwitchedSystem",
    "mk_lcs",
    "mk_lbs",
    "mk_switched_sys",
]


class DynamicalSystem:
    """Base class of every system."""

    n: int
    m: int


class LCS(DynamicalSystem):
    """Linear control system ``x' = A x + B u``.

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, m)
    """

    def __init__(self, A: Any, B: Any) -> None:
        self.A = as_matrix(A, "A")
        if self.A.shape[0] != self.A.shape[1]:
            raise DimensionError(f"A must be square, got shape {self.A.shape}")
        self.n = self.A.shape[0]
        self.B = as_matrix(B, "B", (self.n, None))
        self.m = self.B.shape[1]
        self.W = np.zeros((self.n, 0))
        self.C = np.zeros((0, self.n))
        self.process_cov = np.zeros((self.n, self.n))
        self.lqr_gains: list[np.ndarray] | None = None

    @property
    def p(self) -> int:
        """Output dimension (0 without sensing)."""
        return self.C.shape[0]

    @property
    def has_output(self) -> bool:
        """True when the mode observes something."""
        return self.p > 0

    @property
    def has_state_dependent_noise(self) -> bool:
        """True when the observation noise depends on the state (covariance depends on the mean)."""
        return False

    def noise(self, x: Any) -> np.ndarray:
        """The noise matrix ``n(x)``, shape (p, r)."""
        return np.zeros((self.p, 0))

    def noise_cov(self, x: Any) -> np.ndarray:
        """``R(x) = n(x) n(x)'``, shape (p, p)."""
        nx = self.noise(x)
        return nx @ nx.T

    @property
    def noise_floor(self) -> np.ndarray:
        """A matrix ``F`` (p, p) with ``R(x) >= F`` (Loewner order) for every state ``x``.

        Exact for constant noise; for state-dependent noise the declared ``V_floor`` (zero when
        none was declared). Sound lower bounds on the covariance (proofs that a confidence is out
        of reach) are computed with it.
        """
        return np.zeros((self.p, self.p))

    def step(self, x: Any, u: Any) -> np.ndarray:
        """Noise-free successor ``A x + B u``."""
        return self.A @ x + self.B @ u

    def compute_finite_horizon_lqr(
        self, horizon: int, Q_final: Any, Q: Any, R: Any
    ) -> list[np.ndarray]:
        """Finite-horizon discrete LQR gains used to track a plan (paper Section IV-E).

        Parameters
        ----------
        horizon : int
            Number of steps ``h`` of the receding horizon.
        Q_final, Q : array_like, shape (n, n)
            Terminal and stage state weights (symmetric PSD).
        R : array_like, shape (m, m)
            Input weight (symmetric positive definite).

        Returns
        -------
        list of ndarray, each shape (m, n)
            Gains ``K_0 .. K_{h-1}``; ``u = u_plan - K_0 (x - x_plan)``. Also stored on the mode
            as :attr:`lqr_gains` for :meth:`SwitchedSystem.simulate`.
        """
        from .execution.lqr import finite_horizon_lqr

        self.lqr_gains = finite_horizon_lqr(self.A, self.B, horizon, Q_final, Q, R)
        return self.lqr_gains

    def __repr__(self) -> str:
        return f"{type(self).__name__}(n={self.n}, m={self.m}, p={self.p})"


class LBS(LCS):
    """Linear belief system: ``x' = A x + B u + W w`` with no observation."""

    def __init__(self, A: Any, B: Any, W: Any) -> None:
        super().__init__(A, B)
        self.W = as_matrix(W, "W", (self.n, None))
        self.process_cov = self.W @ self.W.T


class POLBS(LBS):
    """Partially observable linear belief system: adds ``y = C x + n(x) v``."""

    def __init__(self, A: Any, B: Any, W: Any, C: Any) -> None:
        super().__init__(A, B, W)
        self.C = as_matrix(C, "C", (None, self.n))
        if self.C.shape[0] == 0:
            raise DimensionError("C must have at least one row for a partially observable system")


class POLBSWithLinNoise(POLBS):
    """POLBS with a constant noise matrix ``n(x) = V`` of shape (p, r)."""

    def __init__(self, A: Any, B: Any, W: Any, C: Any, V: Any) -> None:
        super().__init__(A, B, W, C)
        self.V = as_matrix(V, "V", (self.p, None))
        self._R = self.V @ self.V.T

    def noise(self, x: Any) -> np.ndarray:
        return self.V

    def noise_cov(self, x: Any) -> np.ndarray:
        return self._R

    @property
    def noise_floor(self) -> np.ndarray:
        return self._R


class POLBSWithNonLinNoise(POLBS):
    """POLBS whose noise matrix is a function of the state, ``n(x)`` of shape (p, r).

    The function is checked on its first call (shape) and on every call (finite values); a bad
    return raises :class:`~idstlpy.errors.NoiseFunctionError` naming ``V``.
    """

    def __init__(
        self, A: Any, B: Any, W: Any, C: Any, V: Callable[[np.ndarray], Any], V_floor: Any = None
    ) -> None:
        super().__init__(A, B, W, C)
        if not callable(V):
            raise InvalidTypeError(f"V must be a matrix or a callable, got {type(V).__name__}")
        self.V = V
        self._cols: int | None = None
        self._floor = _as_floor(V_floor, self.p)

    @property
    def noise_floor(self) -> np.ndarray:
        return self._floor

    def noise_cov(self, x: Any) -> np.ndarray:
        nx = self.noise(x)
        R = nx @ nx.T
        if self._floor.any() and np.linalg.eigvalsh(R - self._floor).min() < -1e-9 * (1 + np.abs(R).max()):
            raise NoiseFunctionError(
                f"noise function V returned R(x) = n(x) n(x)' below its declared V_floor at x={x}"
            )
        return R

    @property
    def has_state_dependent_noise(self) -> bool:
        return True

    def noise(self, x: Any) -> np.ndarray:
        try:
            out = self.V(x)
        except Exception as exc:  # the user's function failed: say which one and where
            raise NoiseFunctionError(
                f"noise function V raised {type(exc).__name__}: {exc} at x={x}"
            ) from exc
        try:
            arr = np.asarray(out, dtype=float)
        except (TypeError, ValueError) as exc:
            raise NoiseFunctionError(
                f"noise function V must return a matrix, got {type(out).__name__}"
            ) from exc
        if (
            arr.ndim != 2
            or arr.shape[0] != self.p
            or (self._cols is not None and arr.shape[1] != self._cols)
        ):
            want = f"({self.p}, {self._cols if self._cols is not None else 'r'})"
            raise NoiseFunctionError(
                f"noise function V must return a matrix of shape {want}, got shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise NoiseFunctionError(
                f"noise function V returned non-finite values at x={np.asarray(x).tolist()}"
            )
        self._cols = arr.shape[1]
        return arr


class SwitchedSystem(DynamicalSystem):
    """A finite set of modes sharing state and input spaces.

    Attributes
    ----------
    system_modes : ndarray of object, shape (num_modes,)
        The modes (:class:`LCS` or subclasses); the listing iterates ``system_modes.size``.
    """

    def __init__(self, system_modes: Sequence[LCS]) -> None:
        modes = (
            list(np.asarray(system_modes, dtype=object).reshape(-1))
            if not isinstance(system_modes, LCS)
            else [system_modes]
        )
        if not modes:
            raise InvalidArgumentError("system_modes must contain at least one mode")
        for i, mode in enumerate(modes):
            if not isinstance(mode, LCS):
                raise InvalidTypeError(
                    f"system_modes[{i}] must be a system made by mk_lcs / mk_lbs, "
                    f"got {type(mode).__name__}"
                )
        n, m = modes[0].n, modes[0].m
        for i, mode in enumerate(modes):
            if (mode.n, mode.m) != (n, m):
                raise DimensionError(
                    f"system_modes[{i}] has (n, m) = ({mode.n}, {mode.m}); mode 0 has ({n}, {m})"
                )
        arr = np.empty(len(modes), dtype=object)
        for i, mode in enumerate(modes):
            arr[i] = mode
        self.system_modes = arr
        self.n, self.m = n, m

    @property
    def num_modes(self) -> int:
        """Number of modes."""
        return int(self.system_modes.size)

    def mode(self, q: int) -> LCS:
        """Mode ``q`` (raises :class:`~idstlpy.errors.OutOfRangeError` when out of range)."""
        from .errors import OutOfRangeError

        if (
            isinstance(q, bool)
            or not isinstance(q, int | np.integer)
            or not 0 <= int(q) < self.num_modes
        ):
            raise OutOfRangeError(
                f"mode {q!r} is out of range: the system has modes 0..{self.num_modes - 1}"
            )
        return self.system_modes[int(q)]

    def simulate(
        self,
        reference_trajectory: ProbabilisticTSTrajectory,
        num_of_steps: int,
        real_initial_state: Any,
        real_system: SwitchedSystem,
        seed: int | np.random.Generator | None = None,
        **options: Any,
    ) -> tuple[ProbabilisticTSTrajectory, RealTrajectory]:
        """Execute a plan against a real system with a Kalman filter and LQR tracking.

        See :func:`idstlpy.execution.simulate.simulate` for the parameters and returns.
        """
        from .execution.simulate import simulate

        return simulate(
            self,
            reference_trajectory,
            num_of_steps,
            real_initial_state,
            real_system,
            seed=seed,
            **options,
        )

    def __repr__(self) -> str:
        return f"SwitchedSystem(modes={self.num_modes}, n={self.n}, m={self.m})"


def mk_lcs(A: Any, B: Any) -> LCS:
    """Linear control system ``x' = A x + B u`` (deterministic)."""
    return LCS(A, B)


def _as_floor(value: Any, p: int) -> np.ndarray:
    """A declared lower bound on ``R(x)``: ``None`` (zero), ``s`` (``s^2 I``) or a (p, p) PSD matrix."""
    if value is None:
        return np.zeros((p, p))
    if isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool):
        s = float(value)
        if not np.isfinite(s) or s < 0:
            raise InvalidArgumentError(
                f"V_floor must be a non-negative number or a (p, p) matrix, got {value!r}"
            )
        return s * s * np.eye(p)
    F = as_matrix(value, "V_floor", (p, p))
    if not np.allclose(F, F.T) or np.linalg.eigvalsh(0.5 * (F + F.T)).min() < -1e-12:
        raise InvalidArgumentError("V_floor must be symmetric positive semi-definite")
    return 0.5 * (F + F.T)


def mk_lbs(A: Any, B: Any, W: Any, C: Any = None, V: Any = None, V_floor: Any = None) -> LBS:
    """Linear belief system, observed when ``C`` is given.

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, m)
    W : array_like, shape (n, w)
        Process noise matrix (``W W'`` is the disturbance covariance).
    C : array_like, shape (p, n), optional
        Output matrix; without it the mode observes nothing (an :class:`LBS`).
    V : array_like of shape (p, r), or callable x -> (p, r) array, optional
        Observation noise matrix ``n(x)``; constant gives :class:`POLBSWithLinNoise`, a
        function gives :class:`POLBSWithNonLinNoise`. ``None`` with ``C`` means a noise-free sensor.
    V_floor : float or array_like of shape (p, p), optional
        For a callable ``V``: a declared lower bound on ``R(x) = n(x) n(x)'`` over every state (a
        number ``s`` means ``s^2 I``). It lets the solver prove that a confidence is out of reach
        (``infeasible`` instead of a search to the time limit); every evaluation of ``V`` is
        checked against it.

    Returns
    -------
    LBS, POLBSWithLinNoise or POLBSWithNonLinNoise
    """
    if V_floor is not None and not callable(V):
        raise InvalidArgumentError("V_floor is only for a state-dependent (callable) V")
    if C is None:
        if V is not None:
            raise InvalidArgumentError("V (observation noise) was given without C (output matrix)")
        return LBS(A, B, W)
    if V is None:
        C_arr = as_matrix(C, "C")
        return POLBSWithLinNoise(A, B, W, C_arr, np.zeros((C_arr.shape[0], C_arr.shape[0])))
    if callable(V):
        return POLBSWithNonLinNoise(A, B, W, C, V, V_floor)
    return POLBSWithLinNoise(A, B, W, C, V)


def mk_switched_sys(system_modes: Any) -> SwitchedSystem:
    """Switched system from a list (or object array) of modes."""
    return SwitchedSystem(system_modes)


def _as_state(x: Any, n: int, name: str = "x") -> np.ndarray:
    return as_vector(x, name, n)
