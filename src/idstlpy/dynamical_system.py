"""Dynamical systems (paper Fig. 6): LCS, LBS, POLBS and switched systems of them.

Each mode ``q`` of a switched system is::

    x_{k+1} = A x_k + B u_k + W w_k,          w_k ~ N(0, I)
    y_k     = C x_k + n(x_k) v_k,             v_k ~ N(0, I)

An :class:`LCS` has neither disturbance nor output; an :class:`LBS` adds the disturbance ``W``;
a :class:`POLBS` adds the output ``C`` with a constant noise matrix
(:class:`POLBSWithLinNoise`) or a noise function of the state (:class:`POLBSWithNonLinNoise`).
"""

from __future__ import annotations

import inspect
import warnings
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ._checks import as_matrix, as_vector
from .errors import (
    DimensionError,
    InvalidArgumentError,
    InvalidTypeError,
    NoiseFunctionError,
    OutOfRangeError,
)
from .lqr import finite_horizon_lqr

if TYPE_CHECKING:
    from .trajectory import ProbabilisticTSTrajectory, RealTrajectory

_SIMULATOR: dict[str, Callable[..., Any]] = {}
"""The executor behind :meth:`SwitchedSystem.simulate`, registered by the layer that defines it.

The model layer cannot import the executor (the executor imports the model), so
:mod:`idstlpy.execution.simulation` registers :func:`~idstlpy.execution.simulation.simulate`
here when it is imported (:func:`register_simulator`); ``import idstlpy`` (run before any of its
modules) imports it, so the paper's ``switched_system.simulate(...)`` always finds it."""


def register_simulator(simulate: Callable[..., Any]) -> None:
    """Register the function behind :meth:`SwitchedSystem.simulate` (called by the execution layer).

    Parameters
    ----------
    simulate : callable
        ``simulate(system, reference_trajectory, num_of_steps, real_initial_state, real_system,
        seed=None, **options)``.
    """
    _SIMULATOR["simulate"] = simulate


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
    """Base class of every system.

    Attributes
    ----------
    n : int
        State dimension.
    m : int
        Input dimension.
    """

    n: int
    m: int


class LCS(DynamicalSystem):
    """Linear control system ``x' = A x + B u`` (build it with :func:`mk_lcs`).

    Parameters
    ----------
    A : array_like, shape (n, n)
        State matrix, ``n >= 1``.
    B : array_like, shape (n, m)
        Input matrix, ``m >= 1``.
    """

    def __init__(self, A: Any, B: Any) -> None:
        self.A = as_matrix(A, "A")
        if self.A.shape[0] != self.A.shape[1]:
            raise DimensionError(f"A must be square, got shape {self.A.shape}")
        if self.A.shape[0] == 0:
            raise DimensionError(
                f"A must be at least 1x1 (a state of dimension n >= 1), got shape {self.A.shape}"
            )
        self.n = self.A.shape[0]
        self.B = as_matrix(B, "B", (self.n, None), axes=("n", "m"), origin=f"n = {self.n} states, from A")
        if self.B.shape[1] == 0:
            raise DimensionError(f"B must have at least one column (m >= 1 inputs), got shape {self.B.shape}")
        self.m = self.B.shape[1]
        self.W = np.zeros((self.n, 0))
        self.C = np.zeros((0, self.n))
        self.process_cov = np.zeros((self.n, self.n))
        self.lqr_gains: list[np.ndarray] | None = None
        # indices this mode has in the switched systems built from it (named in error messages)
        self._mode_indices: set[int] = set()

    def _where(self) -> str:
        """`` of mode 1`` (or ``of modes 0, 2``) once the mode is in a switched system."""
        idx = sorted(getattr(self, "_mode_indices", ()))
        if not idx:
            return ""
        label = "mode" if len(idx) == 1 else "modes"
        return f" of {label} " + ", ".join(str(i) for i in idx)

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
        """The observation noise matrix ``n(x)``.

        Parameters
        ----------
        x : array_like, shape (n,)
            The state (the belief's mean when planning).

        Returns
        -------
        ndarray, shape (p, r)
        """
        return np.zeros((self.p, 0))

    def noise_cov(self, x: Any) -> np.ndarray:
        """The observation noise covariance ``R(x) = n(x) n(x)'``.

        Parameters
        ----------
        x : array_like, shape (n,)
            The state (the belief's mean when planning).

        Returns
        -------
        ndarray, shape (p, p)
        """
        nx = self.noise(x)
        return nx @ nx.T

    def noise_batch(self, X: Any) -> np.ndarray:
        """The observation noise matrices ``n(x)`` at a batch of states.

        Constant noise is one matrix broadcast over the batch; a state-dependent noise function
        is called once for the whole batch when it accepts one (see
        :class:`POLBSWithNonLinNoise`), else once per state.

        Parameters
        ----------
        X : array_like, shape (S, n)
            The states, one per row.

        Returns
        -------
        ndarray, shape (S, p, r)
            Read-only when broadcast (constant noise).
        """
        X = np.asarray(X, dtype=float)
        nx = self.noise(X[0] if X.shape[0] else np.zeros(self.n))
        return np.broadcast_to(nx, (X.shape[0], *nx.shape))

    def noise_cov_batch(self, X: Any) -> np.ndarray:
        """The observation noise covariances ``R(x) = n(x) n(x)'`` at a batch of states.

        Parameters
        ----------
        X : array_like, shape (S, n)
            The states, one per row.

        Returns
        -------
        ndarray, shape (S, p, p)
        """
        X = np.asarray(X, dtype=float)
        R = self.noise_cov(X[0] if X.shape[0] else np.zeros(self.n))
        return np.broadcast_to(R, (X.shape[0], *R.shape))

    @property
    def noise_floor(self) -> np.ndarray:
        """A matrix ``F`` (p, p) with ``R(x) >= F`` (Loewner order) for every state ``x``.

        Exact for constant noise; for state-dependent noise the declared ``V_floor`` (zero when
        none was declared). Sound lower bounds on the covariance (proofs that a confidence is out
        of reach) are computed with it.
        """
        return np.zeros((self.p, self.p))

    def step(self, x: Any, u: Any) -> np.ndarray:
        """Noise-free successor ``A x + B u``.

        Parameters
        ----------
        x : array_like, shape (n,)
            The state.
        u : array_like, shape (m,)
            The input.

        Returns
        -------
        ndarray, shape (n,)
        """
        return self.A @ x + self.B @ u

    def compute_finite_horizon_lqr(self, horizon: int, Q_final: Any, Q: Any, R: Any) -> list[np.ndarray]:
        """Finite-horizon discrete LQR gains used to track a plan (paper Section IV-E).

        Parameters
        ----------
        horizon : int
            Number of steps ``h`` of the receding horizon.
        Q_final : array_like, shape (n, n)
            Terminal state weight (symmetric PSD).
        Q : array_like, shape (n, n)
            Stage state weight (symmetric PSD).
        R : array_like, shape (m, m)
            Input weight (symmetric positive definite).

        Returns
        -------
        list of ndarray, each shape (m, n)
            Gains ``K_0 .. K_{h-1}``; ``u = u_plan - K_0 (x - x_plan)``. Also stored on the mode
            as :attr:`lqr_gains` for :meth:`SwitchedSystem.simulate`.
        """
        self.lqr_gains = finite_horizon_lqr(self.A, self.B, horizon, Q_final, Q, R)
        return self.lqr_gains

    def __repr__(self) -> str:
        return f"{type(self).__name__}(n={self.n}, m={self.m}, p={self.p})"


class LBS(LCS):
    """Linear belief system: ``x' = A x + B u + W w`` with no observation (see :func:`mk_lbs`).

    Parameters
    ----------
    A : array_like, shape (n, n)
        State matrix.
    B : array_like, shape (n, m)
        Input matrix.
    W : array_like, shape (n, w)
        Process noise factor: the disturbance covariance is ``W W'``.
    """

    def __init__(self, A: Any, B: Any, W: Any) -> None:
        super().__init__(A, B)
        self.W = as_matrix(W, "W", (self.n, None), axes=("n", "w"), origin=f"n = {self.n} states, from A")
        self.process_cov = self.W @ self.W.T


class POLBS(LBS):
    """Partially observable linear belief system: adds ``y = C x + n(x) v`` (see :func:`mk_lbs`).

    Parameters
    ----------
    A : array_like, shape (n, n)
        State matrix.
    B : array_like, shape (n, m)
        Input matrix.
    W : array_like, shape (n, w)
        Process noise factor: the disturbance covariance is ``W W'``.
    C : array_like, shape (p, n)
        Output matrix, ``p >= 1``.
    """

    def __init__(self, A: Any, B: Any, W: Any, C: Any) -> None:
        super().__init__(A, B, W)
        self.C = as_matrix(C, "C", (None, self.n), axes=("p", "n"), origin=f"n = {self.n} states, from A")
        if self.C.shape[0] == 0:
            raise DimensionError("C must have at least one row for a partially observable system")


class POLBSWithLinNoise(POLBS):
    """POLBS with a constant noise matrix ``n(x) = V`` of shape (p, r) (see :func:`mk_lbs`).

    Parameters
    ----------
    A : array_like, shape (n, n)
        State matrix.
    B : array_like, shape (n, m)
        Input matrix.
    W : array_like, shape (n, w)
        Process noise factor: the disturbance covariance is ``W W'``.
    C : array_like, shape (p, n)
        Output matrix, ``p >= 1``.
    V : array_like, shape (p, r)
        Observation noise factor: the noise covariance is ``V V'``.
    """

    def __init__(self, A: Any, B: Any, W: Any, C: Any, V: Any) -> None:
        super().__init__(A, B, W, C)
        self.V = as_matrix(V, "V", (self.p, None), axes=("p", "r"), origin=f"p = {self.p} outputs, from C")
        self._R = self.V @ self.V.T

    def noise(self, x: Any) -> np.ndarray:
        """The observation noise matrix: the constant ``V``, whatever the state.

        Parameters
        ----------
        x : array_like, shape (n,)
            The state (not used: the noise is constant).

        Returns
        -------
        ndarray, shape (p, r)
            ``V`` itself (not a copy: do not modify it).
        """
        return self.V

    def noise_cov(self, x: Any) -> np.ndarray:
        """The observation noise covariance ``R = V V'``, whatever the state.

        Parameters
        ----------
        x : array_like, shape (n,)
            The state (not used: the noise is constant).

        Returns
        -------
        ndarray, shape (p, p)
            ``V V'``, computed once (not a copy: do not modify it).
        """
        return self._R

    @property
    def noise_floor(self) -> np.ndarray:
        """The least observation noise covariance, shape (p, p): ``V V'`` itself (exact)."""
        return self._R


class POLBSWithNonLinNoise(POLBS):
    """POLBS whose noise matrix is a function of the state, ``n(x)`` of shape (p, r).

    Every evaluation is checked: the function must return a finite matrix with ``p`` rows and
    the same number ``r`` of columns at every call, and ``R(x) = n(x) n(x)'`` must be finite
    (and above ``V_floor`` when one is declared). A bad return raises
    :class:`~idstlpy.errors.NoiseFunctionError` naming ``V``, the mode (once the system is in a
    switched system), the state and what came back.

    Parameters
    ----------
    A : array_like, shape (n, n)
        State matrix.
    B : array_like, shape (n, m)
        Input matrix.
    W : array_like, shape (n, w)
        Process noise factor: the disturbance covariance is ``W W'``.
    C : array_like, shape (p, n)
        Output matrix, ``p >= 1``.
    V : callable
        ``V(x) -> array (p, r)``, the noise factor at state ``x`` (an array of shape (n,)).
    V_floor : float or array_like of shape (p, p), optional
        Declared lower bound on ``R(x)`` (see :func:`mk_lbs`).

    Notes
    -----
    Batches of states (:meth:`noise_batch`, used by Monte Carlo executions of many runs at
    once): a function written for batches, taking states (S, n) and returning (S, p, r), is
    called once per batch; the first batch checks it against one call per state on three of its
    rows (equal within 1e-12 relative), and a function that fails this (raises, returns another
    shape, or other values, like a function of one state such as ``lambda x: (5 - x[0]) *
    np.identity(2)``) is called once per state from then on. Write ``x[..., 0]`` instead of
    ``x[0]`` and return ``f[..., None, None] * np.identity(p)`` to make a function take both.
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
        self._has_floor = bool(self._floor.any())
        # whether V takes a batch of states (S, n) -> (S, p, r): None until tried (noise_batch)
        self._batch: bool | None = None

    @property
    def noise_floor(self) -> np.ndarray:
        """The declared ``V_floor`` as a (p, p) matrix, zero when none was declared.

        Every ``R(x)`` is checked against it (a return below it raises
        :class:`~idstlpy.errors.NoiseFunctionError`), so the proofs that use it stay sound.
        """
        return self._floor

    def noise_cov(self, x: Any) -> np.ndarray:
        """The observation noise covariance ``R(x) = n(x) n(x)'`` at state ``x``.

        Parameters
        ----------
        x : array_like, shape (n,)
            The state (the belief's mean when planning).

        Returns
        -------
        ndarray, shape (p, p)

        Raises
        ------
        NoiseFunctionError
            When ``V`` fails (see :meth:`noise`), ``R(x)`` is not finite or lies below the
            declared ``V_floor``.
        """
        nx = self.noise(x)
        if nx.size and float(np.abs(nx).max()) > 1e150:  # (finite: noise checked it)
            with np.errstate(over="ignore", invalid="ignore"):
                R = nx @ nx.T
        else:
            R = nx @ nx.T  # cannot overflow
        if not np.isfinite(R).all():
            raise NoiseFunctionError(
                f"noise function V{self._where()} gives a non-finite covariance "
                f"R(x) = n(x) n(x)' = {_show(R)} at x={_show(x)} (n(x) = {_show(nx)} is too large)"
            )
        if self._has_floor and np.linalg.eigvalsh(R - self._floor).min() < -1e-9 * (1 + np.abs(R).max()):
            raise NoiseFunctionError(
                f"noise function V{self._where()} returned R(x) = n(x) n(x)' = {_show(R)} below its "
                f"declared V_floor at x={_show(x)}"
            )
        return R

    @property
    def has_state_dependent_noise(self) -> bool:
        """True: the observation noise is the function ``V`` of the state."""
        return True

    def noise_batch(self, X: Any) -> np.ndarray:
        """The noise matrices ``n(x)`` at a batch of states, shape (S, p, r).

        One call of the function for the batch when it takes batches (class notes), else one
        call per state; every value is checked as :meth:`noise` checks it.

        Parameters
        ----------
        X : array_like, shape (S, n)
            The states, one per row.

        Returns
        -------
        ndarray, shape (S, p, r)
        """
        X = np.asarray(X, dtype=float)
        S = X.shape[0]
        if S >= 2 and getattr(self, "_batch", None) is not False:
            out = self._call_batch(X)
            if out is not None:
                return out
        if S == 0:
            return np.zeros((0, self.p, self._cols or 0))
        return np.stack([self.noise(x) for x in X])

    def _call_batch(self, X: np.ndarray) -> np.ndarray | None:
        """``V(X)`` when the function takes batches (checked on the first batch), else None."""
        S = X.shape[0]
        arr: np.ndarray | None
        try:  # (a function of one state may warn or fail on a batch: quietly, it is only a probe)
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                arr = np.asarray(self.V(X), dtype=float)
        except Exception:  # noqa: BLE001 - a function of one state: call it per state
            arr = None
        good = (
            arr is not None
            and arr.ndim == 3
            and arr.shape[:2] == (S, self.p)
            and (self._cols is None or arr.shape[2] == self._cols)
            and bool(np.isfinite(arr).all())
        )
        if getattr(self, "_batch", None) is None:
            if good and arr is not None:
                for i in sorted({0, S // 2, S - 1}):
                    one = self.noise(X[i])
                    if one.shape != arr.shape[1:] or not np.allclose(arr[i], one, rtol=1e-12, atol=0.0):
                        good = False
                        break
            self._batch = good
        if not good or arr is None:
            return None  # (a batch function returning a bad value: the per-state calls say what)
        self._cols = arr.shape[2]
        return arr

    def noise_cov_batch(self, X: Any) -> np.ndarray:
        """``R(x) = n(x) n(x)'`` at a batch of states, shape (S, p, p), checked as :meth:`noise_cov`.

        Parameters
        ----------
        X : array_like, shape (S, n)
            The states, one per row.

        Returns
        -------
        ndarray, shape (S, p, p)
        """
        X = np.asarray(X, dtype=float)
        nx = self.noise_batch(X)
        with np.errstate(over="ignore", invalid="ignore"):
            R = nx @ np.swapaxes(nx, 1, 2)
        bad = ~np.isfinite(R).all(axis=(1, 2))
        if self._has_floor and X.shape[0]:
            finite = np.where(np.isfinite(R), R, 0.0)
            tol = -1e-9 * (1 + np.abs(finite).max(axis=(1, 2)))
            bad |= np.linalg.eigvalsh(finite - self._floor)[:, 0] < tol
        if bad.any():
            self.noise_cov(X[int(np.flatnonzero(bad)[0])])  # raises the error of that state
        return R

    def noise(self, x: Any) -> np.ndarray:
        """The observation noise matrix ``n(x) = V(x)``, checked.

        Parameters
        ----------
        x : array_like, shape (n,)
            The state (the belief's mean when planning).

        Returns
        -------
        ndarray, shape (p, r)
            ``V(x)`` as a float array; ``r`` is the same at every call.

        Raises
        ------
        NoiseFunctionError
            When ``V`` raises, returns something that is not a finite (p, r) matrix, or changes
            its number of columns ``r`` between calls.
        """
        # every return is checked (shape, finiteness); the messages are only built on failure
        try:
            out = self.V(x)
        except Exception as exc:  # the user's function failed: say which one and where
            who = f"noise function V{self._where()}"
            raise NoiseFunctionError(f"{who} raised {type(exc).__name__}: {exc} at x={_show(x)}") from exc
        try:
            arr = np.asarray(out, dtype=float)
        except (TypeError, ValueError) as exc:
            who = f"noise function V{self._where()}"
            raise NoiseFunctionError(
                f"{who} must return a matrix, got {type(out).__name__} at x={_show(x)}"
            ) from exc
        shape = arr.shape
        if len(shape) == 2 and shape[0] == self.p and shape[1] == self._cols and np.isfinite(arr).all():
            return arr  # the common case: the shape seen before, finite
        who = f"noise function V{self._where()}"
        if arr.ndim != 2 or arr.shape[0] != self.p or (self._cols is not None and arr.shape[1] != self._cols):
            want = f"({self.p}, {self._cols if self._cols is not None else 'r'})"
            raise NoiseFunctionError(
                f"{who} must return a matrix of shape {want}, got shape {arr.shape} "
                f"({_show(arr)}) at x={_show(x)}"
            )
        if not np.all(np.isfinite(arr)):
            raise NoiseFunctionError(f"{who} returned non-finite values {_show(arr)} at x={_show(x)}")
        self._cols = arr.shape[1]
        return arr


def _show(value: Any) -> str:
    """Short text of an array for error messages."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return repr(value)[:80]
    return np.array2string(arr, precision=4, threshold=12, edgeitems=2).replace("\n", "")


class SwitchedSystem(DynamicalSystem):
    """A finite set of modes sharing state and input spaces (build it with :func:`mk_switched_sys`).

    Parameters
    ----------
    system_modes : sequence of LCS
        The modes (:class:`LCS` or subclasses, made by :func:`mk_lcs` / :func:`mk_lbs`), all with
        the same state and input dimensions; a single mode is accepted too.

    Attributes
    ----------
    system_modes : ndarray of object, shape (num_modes,)
        The modes (:class:`LCS` or subclasses); the listing iterates ``system_modes.size``.
    """

    def __init__(self, system_modes: Sequence[LCS] | LCS) -> None:
        if isinstance(system_modes, LCS):
            modes: list[Any] = [system_modes]
        else:
            try:
                modes = list(np.asarray(system_modes, dtype=object).reshape(-1))
            except (TypeError, ValueError) as exc:
                raise InvalidTypeError(
                    f"system_modes must be a list of modes made by mk_lcs / mk_lbs, "
                    f"got {type(system_modes).__name__}"
                ) from exc
        if not modes:
            raise InvalidArgumentError("system_modes must contain at least one mode")
        for i, mode in enumerate(modes):
            if not isinstance(mode, LCS):
                raise InvalidTypeError(
                    f"system_modes[{i}] must be a system made by mk_lcs / mk_lbs, got {type(mode).__name__}"
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
            mode.__dict__.setdefault("_mode_indices", set()).add(i)
        self.system_modes = arr
        self.n, self.m = n, m

    @property
    def num_modes(self) -> int:
        """Number of modes."""
        return int(self.system_modes.size)

    def mode(self, q: int) -> LCS:
        """Mode ``q``.

        Parameters
        ----------
        q : int
            Mode index in ``0 .. num_modes - 1``.

        Returns
        -------
        LCS

        Raises
        ------
        OutOfRangeError
            When ``q`` is not a mode index.
        """
        if isinstance(q, bool) or not isinstance(q, int | np.integer) or not 0 <= int(q) < self.num_modes:
            raise OutOfRangeError(f"mode {q!r} is out of range: the system has modes 0..{self.num_modes - 1}")
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

        The paper's ``switched_system.simulate``; see :func:`idstlpy.execution.simulation.simulate`
        for the details.

        Parameters
        ----------
        reference_trajectory : ProbabilisticTSTrajectory
            The plan (``Problem.solve``'s result).
        num_of_steps : int
            Steps to execute, at most the plan's number of steps.
        real_initial_state : array_like, shape (n,)
            True initial state.
        real_system : SwitchedSystem, LCS or None
            The linear system that moves the true state (None: the model, or the ``plant``
            step function given in ``options``).
        seed : int or Generator, optional
            Randomness of the disturbances and measurement noises.
        **options
            Keyword options of :func:`idstlpy.execution.simulation.simulate` (``control_domain``,
            ``process_noise``, ``lqr_gains``, ``default_lqr``, ``initial_belief``, ``plant``,
            ``spec``); an
            unknown keyword raises :class:`~idstlpy.errors.InvalidTypeError` (a ``TypeError``).

        Returns
        -------
        xi_sim : ProbabilisticTSTrajectory
            The executed belief.
        xi_real : RealTrajectory
            The true states, observations, modes and applied inputs.
        """
        simulate = _SIMULATOR.get("simulate")
        if simulate is None:  # pragma: no cover - importing any part of idstlpy registers it
            raise InvalidArgumentError(
                "no simulator is registered: import idstlpy (not only its model modules)"
            )
        params = inspect.signature(simulate).parameters.values()
        known = {par.name for par in params if par.kind is inspect.Parameter.KEYWORD_ONLY}
        # a simulator taking **options checks them itself (its error names the keyword)
        takes_more = any(par.kind is inspect.Parameter.VAR_KEYWORD for par in params)
        unknown = [] if takes_more else sorted(set(options) - known)
        if unknown:
            raise InvalidTypeError(
                f"simulate got an unexpected keyword argument {', '.join(map(repr, unknown))}; "
                f"its options are {', '.join(sorted(known))}"
            )
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

    def _repr_html_(self) -> str:
        """Notebook display: one row per mode (kind, dimensions, noise)."""
        rows = []
        for i, mode in enumerate(self.system_modes):
            rows.append(
                f"<tr><td>{i}</td><td>{type(mode).__name__}</td><td>{mode.p}</td>"
                f"<td>{_noise_kind(mode)}</td></tr>"
            )
        return (
            f"<div>SwitchedSystem: {self.num_modes} modes, n={self.n} states, m={self.m} inputs"
            "<table><tr><th>mode</th><th>kind</th><th>outputs p</th><th>observation noise</th></tr>"
            + "".join(rows)
            + "</table></div>"
        )


def _noise_kind(mode: LCS) -> str:
    if not mode.has_output:
        return "none (blind)"
    if mode.has_state_dependent_noise:
        return "state-dependent V(x)"
    return "constant" if np.any(mode.noise_floor) else "noise-free"


# ------------------------------------------------------------------------------------------------
# factories
# ------------------------------------------------------------------------------------------------


def _is_state_space(obj: Any) -> bool:
    """Duck typing of python-control's ``StateSpace`` (or scipy's): ``A, B, C, D`` and ``dt``."""
    return not isinstance(obj, np.ndarray | list | tuple) and all(
        hasattr(obj, attr) for attr in ("A", "B", "C", "D", "dt")
    )


def _state_space_matrices(sys: Any, func: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``A, B, C, D`` of a discrete-time state-space object (no import of python-control)."""
    dt = sys.dt
    discrete = dt is True or (
        not isinstance(dt, bool)
        and isinstance(dt, int | float | np.integer | np.floating)
        and np.isfinite(dt)
        and dt > 0
    )
    if not discrete:
        raise InvalidArgumentError(
            f"{func} takes a discrete-time state-space system, got {type(sys).__name__} with "
            f"dt={dt!r} (continuous or unspecified time base); give it a sampling period with "
            "idstlpy.from_continuous(sys, dt=Ts, noise_intensity=...) (zero-order hold, exact "
            "noise discretisation), or discretize it first (sys.sample(Ts) in python-control)"
        )
    return (
        as_matrix(sys.A, f"{type(sys).__name__}.A"),
        as_matrix(sys.B, f"{type(sys).__name__}.B"),
        as_matrix(sys.C, f"{type(sys).__name__}.C"),
        as_matrix(sys.D, f"{type(sys).__name__}.D"),
    )


def mk_lcs(A: Any, B: Any = None) -> LCS:
    """Linear control system ``x' = A x + B u`` (deterministic; paper ``mk_lcs``).

    Parameters
    ----------
    A : array_like of shape (n, n), or a discrete-time state-space system
        State matrix (``n >= 1``). A state-space object such as python-control's
        ``StateSpace`` (anything with ``A``, ``B``, ``C``, ``D`` and ``dt``; ``dt`` must be
        ``True`` or a positive sampling time) gives its ``A`` and ``B``; its outputs are
        ignored (an LCS observes nothing).
    B : array_like, shape (n, m)
        Input matrix (``m >= 1``); omitted when ``A`` is a state-space system.

    Returns
    -------
    LCS

    Raises
    ------
    DimensionError
        For shapes that disagree or empty matrices.
    InvalidArgumentError
        For non-finite entries or a continuous-time state-space system.
    InvalidTypeError
        When ``B`` is missing, or given together with a state-space system.
    """
    if _is_state_space(A):
        if B is not None:
            raise InvalidTypeError("mk_lcs: B comes from the state-space system; pass the system alone")
        A_, B_, _, _ = _state_space_matrices(A, "mk_lcs")
        return LCS(A_, B_)
    if B is None:
        raise InvalidTypeError("mk_lcs needs B, the input matrix of shape (n, m)")
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


def mk_lbs(A: Any, B: Any = None, W: Any = None, C: Any = None, V: Any = None, V_floor: Any = None) -> LBS:
    """Linear belief system, observed when ``C`` is given (paper ``mk_lbs``).

    ``x' = A x + B u + W w`` and, with ``C``, ``y = C x + n(x) v`` (``w``, ``v`` standard normal).

    Parameters
    ----------
    A : array_like of shape (n, n), or a discrete-time state-space system
        State matrix (``n >= 1``). A state-space object such as python-control's
        ``StateSpace`` (``A``, ``B``, ``C``, ``D`` and ``dt``; ``dt`` must be ``True`` or a
        positive sampling time) gives ``A``, ``B`` and the output matrix ``C`` (none when it has
        no outputs); its ``D`` must be zero.
    B : array_like, shape (n, m)
        Input matrix (``m >= 1``); omitted when ``A`` is a state-space system.
    W : array_like, shape (n, w)
        Process noise factor: the disturbance covariance is ``W W'`` (required; zeros for none).
    C : array_like, shape (p, n), optional
        Output matrix; without it the mode observes nothing (an :class:`LBS`). Omitted when
        ``A`` is a state-space system.
    V : array_like of shape (p, r), or callable x -> (p, r) array, optional
        Observation noise factor ``n(x)`` (the noise covariance is ``n(x) n(x)'``); constant
        gives :class:`POLBSWithLinNoise`, a function gives :class:`POLBSWithNonLinNoise` (its
        values are checked at every evaluation). ``None`` with ``C`` means a noise-free sensor.
        A function that also takes a batch of states (S, n) -> (S, p, r) (write ``x[..., 0]``)
        is called once per step for all the runs of a Monte Carlo validation, else once per run
        (see :class:`POLBSWithNonLinNoise`).
    V_floor : float or array_like of shape (p, p), optional
        For a callable ``V``: a declared lower bound on ``R(x) = n(x) n(x)'`` over every state (a
        number ``s`` means ``s^2 I``). It lets the solver prove that a confidence is out of reach
        (``infeasible`` instead of a search to the time limit); every evaluation of ``V`` is
        checked against it.

    Returns
    -------
    LBS, POLBSWithLinNoise or POLBSWithNonLinNoise

    Raises
    ------
    DimensionError
        For shapes that disagree or empty matrices.
    InvalidArgumentError
        For non-finite entries, ``V`` without ``C``, ``V_floor`` without a callable ``V``, or a
        state-space system in continuous time or with a non-zero ``D``.
    InvalidTypeError
        When ``B`` or ``W`` is missing, or ``B`` / ``C`` is given with a state-space system.
    """
    if _is_state_space(A):
        if B is not None or C is not None:
            which = "B" if B is not None else "C"
            raise InvalidTypeError(
                f"mk_lbs: {which} comes from the state-space system; pass the system and W, V"
            )
        A, B, C_ss, D = _state_space_matrices(A, "mk_lbs")
        if np.any(D != 0):
            raise InvalidArgumentError(
                f"mk_lbs: the state-space system's D must be zero (outputs y = C x + n(x) v have no "
                f"feedthrough), got D = {D.tolist()}"
            )
        C = C_ss if C_ss.shape[0] > 0 else None
    if B is None:
        raise InvalidTypeError("mk_lbs needs B, the input matrix of shape (n, m)")
    if W is None:
        raise InvalidTypeError(
            "mk_lbs needs W, the process noise factor of shape (n, w) (np.zeros((n, n)) for none)"
        )
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
    """Switched system from a list (or object array) of modes (paper ``mk_switched_sys``).

    Parameters
    ----------
    system_modes : sequence of LCS, or a single LCS
        The modes, made by :func:`mk_lcs` / :func:`mk_lbs`; the plan picks one at every step
        (mode ``q`` is ``system_modes[q]``). All must share the state and input dimensions.

    Returns
    -------
    SwitchedSystem

    Raises
    ------
    InvalidArgumentError
        Without modes.
    InvalidTypeError
        For an entry that is not a mode.
    DimensionError
        For modes whose dimensions disagree.
    """
    return SwitchedSystem(system_modes)


def control_domain_mismatch(dim: int, system: SwitchedSystem) -> DimensionError:
    """The error for a control domain of dimension ``dim`` on a system with ``system.m != dim`` inputs.

    The input count comes from ``B``'s columns, so the message names ``B``'s shape and the shape
    it would need for this control domain: a ``B`` written with the wrong number of columns
    would otherwise be blamed on the (correct) control domain.

    Parameters
    ----------
    dim : int
        The control domain's dimension.
    system : SwitchedSystem
        The system whose modes' ``B`` (n, m) fix the input count.

    Returns
    -------
    DimensionError
    """
    n, m = system.n, system.m
    return DimensionError(
        f"control_domain has dimension {dim}, the system has m = {m} inputs (B of every mode has "
        f"shape (n, m) = ({n}, {m})): either B is wrong and must have shape ({n}, {dim}) for this "
        f"control domain, or the control domain must bound {m} inputs (u of size {m})"
    )


def _as_state(x: Any, n: int, name: str = "x") -> np.ndarray:
    return as_vector(x, name, n)
