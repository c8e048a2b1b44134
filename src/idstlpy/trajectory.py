"""Trajectories: the planned / executed belief and the real state sequence.

Counting
--------
A trajectory of ``N`` steps is ``X_0 -(q_0, u_0)-> X_1 -> ... -(q_{N-1}, u_{N-1})-> X_N``:

- ``num_of_steps`` is ``N``, the number of *transitions* (modes and inputs applied);
- ``len(traj)`` is ``N + 1``, the number of *beliefs* (or true states), i.e. the number of rows
  of ``get_mean()`` / ``np.asarray(traj)``, the same as ``num_of_beliefs``.

So ``len(plan) == plan.num_of_steps + 1`` always: the paper's plans of 81 steps hold 82 beliefs.

Plans as data
-------------
``to_dict()`` gives plain JSON-able data (nested lists, ``None`` for NaN and infinities) with a
``"schema"`` key (:data:`BELIEF_TRAJECTORY_SCHEMA`, :data:`REAL_TRAJECTORY_SCHEMA`);
``from_dict()`` is its inverse. ``ProbabilisticTSTrajectory.to_dataframe()`` gives a pandas
table (pandas is optional and imported only there). Both classes pickle.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .errors import DimensionError, InvalidArgumentError, InvalidTypeError, OutOfRangeError
from .lqr import TrackingGains

__all__ = [
    "ProbabilisticTSTrajectory",
    "RealTrajectory",
    "BELIEF_TRAJECTORY_SCHEMA",
    "REAL_TRAJECTORY_SCHEMA",
]

BELIEF_TRAJECTORY_SCHEMA = "idstlpy.belief_trajectory/1"
"""Identifier and version of :meth:`ProbabilisticTSTrajectory.to_dict`'s output."""

REAL_TRAJECTORY_SCHEMA = "idstlpy.real_trajectory/1"
"""Identifier and version of :meth:`RealTrajectory.to_dict`'s output."""


def _index(k: int | None, size: int, what: str) -> Any:
    if k is None:
        return slice(None)
    if isinstance(k, bool) or not isinstance(k, int | np.integer):
        raise OutOfRangeError(f"{what} index must be an int or None, got {type(k).__name__}")
    if not -size <= int(k) < size:
        raise OutOfRangeError(f"{what} index {k} is out of range 0..{size - 1}")
    return int(k)


def _to_json(arr: np.ndarray) -> Any:
    """Nested lists of floats; NaN and infinities become ``None`` (strict JSON has neither)."""
    out = np.asarray(arr, dtype=float).astype(object)
    out[~np.isfinite(np.asarray(arr, dtype=float))] = None
    return out.tolist()


def _from_json(data: Any, name: str, ndim: int) -> np.ndarray:
    """Inverse of :func:`_to_json` (``None`` reads as NaN), checking the number of axes."""
    try:
        arr = np.array(data, dtype=object)
        arr[arr == None] = math.nan  # noqa: E711 - elementwise comparison on an object array
        out = arr.astype(float)
    except (TypeError, ValueError) as exc:
        raise InvalidTypeError(f"{name} must be nested lists of numbers, got {type(data).__name__}") from exc
    if out.size == 0 and out.ndim < ndim:
        out = out.reshape((0,) * ndim)
    if out.ndim != ndim:
        raise DimensionError(f"{name} must have {ndim} axes, got an array with shape {out.shape}")
    return out


def _actions_from_json(data: Any, name: str) -> np.ndarray:
    arr = _from_json(data, name, 1)
    if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
        raise InvalidArgumentError(f"{name} must be integers (mode indices)")
    return arr.astype(int)


def _check_schema(data: Any, schema: str, what: str, legacy: bool) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise InvalidTypeError(f"{what} data must be a dict (from to_dict), got {type(data).__name__}")
    got = data.get("schema")
    if got is None and legacy:
        return data
    if got != schema:
        raise InvalidArgumentError(f"not a {what}: expected schema {schema!r}, got {got!r}")
    return data


def _require(data: dict[str, Any], keys: tuple[str, ...], what: str) -> None:
    missing = [k for k in keys if k not in data]
    if missing:
        raise InvalidArgumentError(f"{what} data lacks the keys {missing}")


def _as_array(values: np.ndarray, dtype: Any, copy: bool | None) -> np.ndarray:
    if dtype is None and not copy:
        return values
    return np.array(values, dtype=dtype, copy=True) if copy else np.asarray(values, dtype=dtype)


class ProbabilisticTSTrajectory:
    """A belief trajectory ``X_0 -(q_0, u_0)-> X_1 -> ... -> X_N``.

    ``num_of_steps`` is ``N`` (transitions); ``len(traj)`` is ``N + 1`` (beliefs).
    ``np.asarray(traj)`` is the array of means, shape (N+1, n).

    Parameters
    ----------
    means : array_like, shape (N+1, n)
        Belief means ``m_0 .. m_N``.
    covs : array_like, shape (N+1, n, n)
        Belief covariances ``S_0 .. S_N``.
    actions : array_like of int, shape (N,)
        Mode applied at each step (``q_k`` takes ``X_k`` to ``X_{k+1}``).
    controls : array_like, shape (N, m)
        Input applied at each step (``u_k`` takes ``X_k`` to ``X_{k+1}``).

    Raises
    ------
    DimensionError
        When the shapes disagree.
    InvalidArgumentError
        When a mean or a covariance is not finite.
    """

    def __init__(self, means: Any, covs: Any, actions: Any, controls: Any) -> None:
        self._means = np.asarray(means, dtype=float)
        self._covs = np.asarray(covs, dtype=float)
        self._actions = np.asarray(actions, dtype=int).reshape(-1)
        self._controls = np.asarray(controls, dtype=float)
        if self._means.ndim != 2 or self._means.shape[0] < 1:
            raise DimensionError(f"means must have shape (N+1, n) with N >= 0, got {self._means.shape}")
        L, n = self._means.shape
        if self._covs.shape != (L, n, n):
            raise DimensionError(f"covs must have shape ({L}, {n}, {n}), got {self._covs.shape}")
        if self._actions.shape != (L - 1,):
            raise DimensionError(f"actions must have shape ({L - 1},), got {self._actions.shape}")
        if self._controls.ndim != 2 or self._controls.shape[0] != L - 1:
            if not (L == 1 and self._controls.size == 0):
                raise DimensionError(f"controls must have shape ({L - 1}, m), got {self._controls.shape}")
            self._controls = self._controls.reshape(0, -1) if self._controls.ndim == 2 else np.zeros((0, 0))
        if not (np.all(np.isfinite(self._means)) and np.all(np.isfinite(self._covs))):
            raise InvalidArgumentError("a trajectory must have finite means and covariances")
        self.tracking: TrackingGains | None = None
        """The tracking the plan was made for (set by the planner on the plans it returns): the
        executors track it with these gains for modes without their own ``lqr_gains``."""

    @property
    def num_of_steps(self) -> int:
        """Number of transitions ``N`` (modes and inputs applied); ``len(self) == N + 1``."""
        return self._actions.shape[0]

    @property
    def num_of_beliefs(self) -> int:
        """Number of beliefs ``N + 1`` (``X_0 .. X_N``), the same as ``len(self)``."""
        return self._means.shape[0]

    @property
    def n(self) -> int:
        """State dimension."""
        return self._means.shape[1]

    @property
    def m(self) -> int:
        """Input dimension (0 when unknown: a trajectory of no step built without inputs)."""
        return self._controls.shape[1]

    def get_mean(self, k: int | None = None) -> np.ndarray:
        """Mean at step ``k`` (shape (n,)), or all means (shape (N+1, n)).

        Parameters
        ----------
        k : int, optional
            Step in ``0..N`` (negative counts from the end); None for all.
        """
        return self._means[_index(k, self.num_of_steps + 1, "mean")]

    def get_cov(self, k: int | None = None) -> np.ndarray:
        """Covariance at step ``k`` (shape (n, n)), or all (shape (N+1, n, n)).

        Parameters
        ----------
        k : int, optional
            Step in ``0..N`` (negative counts from the end); None for all.
        """
        return self._covs[_index(k, self.num_of_steps + 1, "cov")]

    def get_std(self, k: int | None = None) -> np.ndarray:
        """Standard deviations ``sqrt(diag S_k)`` at step ``k`` (shape (n,)), or all (shape (N+1, n)).

        Parameters
        ----------
        k : int, optional
            Step in ``0..N`` (negative counts from the end); None for all.
        """
        cov = self.get_cov(k)
        return np.sqrt(np.maximum(np.diagonal(cov, axis1=-2, axis2=-1), 0.0))

    def get_action(self, k: int | None = None) -> Any:
        """Mode applied at step ``k`` (int), or all (shape (N,)).

        Parameters
        ----------
        k : int, optional
            Step in ``0..N-1`` (negative counts from the end); None for all.
        """
        out = self._actions[_index(k, self.num_of_steps, "action")]
        return int(out) if k is not None else out

    def get_control(self, k: int | None = None) -> np.ndarray:
        """Control applied at step ``k`` (shape (m,)), or all (shape (N, m)).

        Parameters
        ----------
        k : int, optional
            Step in ``0..N-1`` (negative counts from the end); None for all.
        """
        return self._controls[_index(k, self.num_of_steps, "control")]

    def __len__(self) -> int:
        """Number of beliefs, ``num_of_steps + 1``."""
        return self.num_of_steps + 1

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        """The means, shape (N+1, n): ``np.asarray(traj)`` is ``traj.get_mean()``."""
        return _as_array(self._means, dtype, copy)

    def __repr__(self) -> str:
        return f"ProbabilisticTSTrajectory(num_of_steps={self.num_of_steps}, n={self.n}, m={self.m})"

    # ------------------------------------------------------------------------------------------
    # Plans as data

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able data, schema :data:`BELIEF_TRAJECTORY_SCHEMA`.

        Returns
        -------
        dict
            ``{"schema", "num_of_steps", "n", "m", "mean": (N+1, n) lists, "cov": (N+1, n, n),
            "action": (N,) ints, "control": (N, m)}``; NaN and infinities (none in a valid
            plan) would be written as ``None``. ``json.dumps(..., allow_nan=False)`` accepts it.
        """
        return {
            "schema": BELIEF_TRAJECTORY_SCHEMA,
            "num_of_steps": self.num_of_steps,
            "n": self.n,
            "m": self.m,
            "mean": _to_json(self._means),
            "cov": _to_json(self._covs),
            "action": [int(a) for a in self._actions],
            "control": _to_json(self._controls),
            **({} if self.tracking is None else {"tracking": self.tracking.to_dict()}),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ProbabilisticTSTrajectory:
        """Rebuild a trajectory from :meth:`to_dict` output.

        Parameters
        ----------
        data : dict
            Output of :meth:`to_dict` (a dict without ``"schema"`` but with the keys ``mean``,
            ``cov``, ``action``, ``control`` is read too: the plan of older result files).

        Returns
        -------
        ProbabilisticTSTrajectory

        Raises
        ------
        InvalidArgumentError
            When ``data`` has another schema or lacks a key.
        DimensionError
            When the arrays' shapes disagree.
        """
        data = _check_schema(data, BELIEF_TRAJECTORY_SCHEMA, "belief trajectory", legacy=True)
        _require(data, ("mean", "cov", "action", "control"), "belief trajectory")
        means = _from_json(data["mean"], "mean", 2)
        covs = _from_json(data["cov"], "cov", 3)
        actions = _actions_from_json(data["action"], "action")
        controls = _from_json(data["control"], "control", 2)
        m = data.get("m")
        if controls.size == 0 and isinstance(m, int) and not isinstance(m, bool):
            controls = np.zeros((controls.shape[0], m))
        if means.size == 0 and isinstance(data.get("n"), int):
            means = means.reshape(0, int(data["n"]))
        out = cls(means, covs, actions, controls)
        if data.get("tracking") is not None:
            out.tracking = TrackingGains.from_dict(data["tracking"])
        return out

    def to_dataframe(self) -> Any:
        """One row per belief: ``step, mode, control_0.., mean_0.., std_0..`` (needs pandas).

        Row ``k`` holds the belief ``X_k`` (``mean_i``, ``std_i = sqrt(S_k[i, i])``) and the mode
        and input applied *from* it (``q_k``, ``u_k``, as :meth:`get_action` / :meth:`get_control`);
        the last row (``k = N``) has none: its ``mode`` is ``<NA>`` (nullable ``Int64``) and its
        controls are NaN.

        Returns
        -------
        pandas.DataFrame
            ``N + 1`` rows.

        Raises
        ------
        InvalidArgumentError
            When pandas is not installed.
        """
        try:
            import pandas as pd
        except ImportError as exc:
            raise InvalidArgumentError(
                "to_dataframe needs pandas, an optional dependency: pip install pandas"
            ) from exc
        L = self.num_of_beliefs
        columns: dict[str, Any] = {"step": np.arange(L)}
        modes = pd.array([*self._actions.tolist(), None], dtype="Int64")
        columns["mode"] = modes
        controls = np.full((L, self.m), np.nan)
        controls[: L - 1] = self._controls
        for i in range(self.m):
            columns[f"control_{i}"] = controls[:, i]
        for i in range(self.n):
            columns[f"mean_{i}"] = self._means[:, i]
        std = self.get_std()
        for i in range(self.n):
            columns[f"std_{i}"] = std[:, i]
        return pd.DataFrame(columns)


class RealTrajectory:
    """What happened in the real world during an execution.

    ``num_of_steps`` is ``N`` (transitions); ``len(traj)`` is ``N + 1`` (true states).
    ``np.asarray(traj)`` is the array of true states, shape (N+1, n).

    Parameters
    ----------
    states : array_like, shape (N+1, n)
        True states.
    observations : array_like, shape (N+1, p)
        Observation received at each step (row 0 is the one taken at the start, or NaN if none).
    actions : array_like of int, shape (N,)
        Mode applied at each step.
    controls : array_like, shape (N, m)
        Input applied at each step.

    Raises
    ------
    DimensionError
        When the shapes disagree.
    """

    def __init__(self, states: Any, observations: Any, actions: Any, controls: Any) -> None:
        self._states = np.asarray(states, dtype=float)
        self._observations = np.asarray(observations, dtype=float)
        self._actions = np.asarray(actions, dtype=int).reshape(-1)
        self._controls = np.asarray(controls, dtype=float)
        if self._states.ndim != 2 or self._actions.shape[0] != self._states.shape[0] - 1:
            raise DimensionError(
                f"states (N+1, n) and actions (N,) disagree: {self._states.shape} vs {self._actions.shape}"
            )
        if self._observations.ndim == 1 and self._observations.size == 0:
            self._observations = self._observations.reshape(self._states.shape[0], 0)
        if self._observations.ndim != 2 or self._observations.shape[0] != self._states.shape[0]:
            raise DimensionError(
                f"observations must have shape ({self._states.shape[0]}, p), got {self._observations.shape}"
            )

    @property
    def num_of_steps(self) -> int:
        """Number of transitions ``N``; ``len(self) == N + 1``."""
        return self._actions.shape[0]

    @property
    def n(self) -> int:
        """State dimension."""
        return self._states.shape[1]

    def get_state(self, k: int | None = None) -> np.ndarray:
        """True state at step ``k`` (shape (n,)), or all (shape (N+1, n)).

        Parameters
        ----------
        k : int, optional
            Step in ``0..N`` (negative counts from the end); None for all.
        """
        return self._states[_index(k, self.num_of_steps + 1, "state")]

    def get_observation(self, k: int | None = None) -> np.ndarray:
        """Observation at step ``k`` (shape (p,)), or all (shape (N+1, p)).

        Parameters
        ----------
        k : int, optional
            Step in ``0..N`` (negative counts from the end); None for all.
        """
        return self._observations[_index(k, self._observations.shape[0], "observation")]

    def get_action(self, k: int | None = None) -> Any:
        """Mode applied at step ``k`` (int), or all (shape (N,)).

        Parameters
        ----------
        k : int, optional
            Step in ``0..N-1`` (negative counts from the end); None for all.
        """
        out = self._actions[_index(k, self.num_of_steps, "action")]
        return int(out) if k is not None else out

    def get_control(self, k: int | None = None) -> np.ndarray:
        """Control applied at step ``k`` (shape (m,)), or all (shape (N, m)).

        Parameters
        ----------
        k : int, optional
            Step in ``0..N-1`` (negative counts from the end); None for all.
        """
        return self._controls[_index(k, self.num_of_steps, "control")]

    def __len__(self) -> int:
        """Number of true states, ``num_of_steps + 1``."""
        return self.num_of_steps + 1

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        """The true states, shape (N+1, n): ``np.asarray(traj)`` is ``traj.get_state()``."""
        return _as_array(self._states, dtype, copy)

    def __repr__(self) -> str:
        return f"RealTrajectory(num_of_steps={self.num_of_steps}, n={self.n})"

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able data, schema :data:`REAL_TRAJECTORY_SCHEMA`.

        Returns
        -------
        dict
            ``{"schema", "num_of_steps", "n", "p", "m", "state", "observation", "action",
            "control"}``; NaN (e.g. the observation row of a step without one) and infinities
            are written as ``None`` and read back as NaN.
        """
        return {
            "schema": REAL_TRAJECTORY_SCHEMA,
            "num_of_steps": self.num_of_steps,
            "n": self.n,
            "p": self._observations.shape[1],
            "m": self._controls.shape[1] if self._controls.ndim == 2 else 0,
            "state": _to_json(self._states),
            "observation": _to_json(self._observations),
            "action": [int(a) for a in self._actions],
            "control": _to_json(self._controls),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RealTrajectory:
        """Rebuild a real trajectory from :meth:`to_dict` output.

        Parameters
        ----------
        data : dict
            Output of :meth:`to_dict`.

        Returns
        -------
        RealTrajectory

        Raises
        ------
        InvalidArgumentError
            When ``data`` has another schema or lacks a key.
        DimensionError
            When the arrays' shapes disagree.
        """
        data = _check_schema(data, REAL_TRAJECTORY_SCHEMA, "real trajectory", legacy=False)
        _require(data, ("state", "observation", "action", "control"), "real trajectory")
        states = _from_json(data["state"], "state", 2)
        observations = _from_json(data["observation"], "observation", 2)
        if observations.size == 0 and isinstance(data.get("p"), int):
            observations = np.zeros((states.shape[0], int(data["p"])))
        controls = _from_json(data["control"], "control", 2)
        if controls.size == 0 and isinstance(data.get("m"), int):
            controls = np.zeros((controls.shape[0], int(data["m"])))
        return cls(states, observations, _actions_from_json(data["action"], "action"), controls)
