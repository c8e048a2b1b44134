"""Trajectories: the planned / executed belief and the real state sequence."""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import DimensionError, InvalidArgumentError, OutOfRangeError

__all__ = ["ProbabilisticTSTrajectory", "RealTrajectory"]


def _index(k: int | None, size: int, what: str) -> Any:
    if k is None:
        return slice(None)
    if isinstance(k, bool) or not isinstance(k, int | np.integer):
        raise OutOfRangeError(f"{what} index must be an int or None, got {type(k).__name__}")
    if not -size <= int(k) < size:
        raise OutOfRangeError(f"{what} index {k} is out of range 0..{size - 1}")
    return int(k)


class ProbabilisticTSTrajectory:
    """A belief trajectory ``X_0 -(q_0, u_0)-> X_1 -> ... -> X_N``.

    Parameters
    ----------
    means : array_like, shape (N+1, n)
    covs : array_like, shape (N+1, n, n)
    actions : array_like of int, shape (N,)
        Mode applied at each step (``q_k`` takes ``X_k`` to ``X_{k+1}``).
    controls : array_like, shape (N, m)
    """

    def __init__(self, means: Any, covs: Any, actions: Any, controls: Any) -> None:
        self._means = np.asarray(means, dtype=float)
        self._covs = np.asarray(covs, dtype=float)
        self._actions = np.asarray(actions, dtype=int).reshape(-1)
        self._controls = np.asarray(controls, dtype=float)
        if self._means.ndim != 2:
            raise DimensionError(f"means must have shape (N+1, n), got {self._means.shape}")
        L, n = self._means.shape
        if self._covs.shape != (L, n, n):
            raise DimensionError(f"covs must have shape ({L}, {n}, {n}), got {self._covs.shape}")
        if self._actions.shape != (L - 1,):
            raise DimensionError(f"actions must have shape ({L - 1},), got {self._actions.shape}")
        if self._controls.ndim != 2 or self._controls.shape[0] != L - 1:
            if not (L == 1 and self._controls.size == 0):
                raise DimensionError(
                    f"controls must have shape ({L - 1}, m), got {self._controls.shape}"
                )
            self._controls = (
                self._controls.reshape(0, -1) if self._controls.ndim == 2 else np.zeros((0, 0))
            )
        if not (np.all(np.isfinite(self._means)) and np.all(np.isfinite(self._covs))):
            raise InvalidArgumentError("a trajectory must have finite means and covariances")

    @property
    def num_of_steps(self) -> int:
        """Number of transitions ``N``."""
        return self._actions.shape[0]

    @property
    def n(self) -> int:
        """State dimension."""
        return self._means.shape[1]

    def get_mean(self, k: int | None = None) -> np.ndarray:
        """Mean at step ``k`` (shape (n,)), or all means (shape (N+1, n))."""
        return self._means[_index(k, self.num_of_steps + 1, "mean")]

    def get_cov(self, k: int | None = None) -> np.ndarray:
        """Covariance at step ``k`` (shape (n, n)), or all (shape (N+1, n, n))."""
        return self._covs[_index(k, self.num_of_steps + 1, "cov")]

    def get_action(self, k: int | None = None) -> Any:
        """Mode applied at step ``k`` (int), or all (shape (N,))."""
        out = self._actions[_index(k, self.num_of_steps, "action")]
        return int(out) if k is not None else out

    def get_control(self, k: int | None = None) -> np.ndarray:
        """Control applied at step ``k`` (shape (m,)), or all (shape (N, m))."""
        return self._controls[_index(k, self.num_of_steps, "control")]

    def __len__(self) -> int:
        return self.num_of_steps + 1

    def __repr__(self) -> str:
        return f"ProbabilisticTSTrajectory(num_of_steps={self.num_of_steps}, n={self.n})"


class RealTrajectory:
    """What happened in the real world during an execution.

    Parameters
    ----------
    states : array_like, shape (N+1, n)
        True states.
    observations : array_like, shape (N+1, p)
        Observation received at each step (row 0 is the one taken at the start, or NaN if none).
    actions : array_like of int, shape (N,)
    controls : array_like, shape (N, m)
    """

    def __init__(self, states: Any, observations: Any, actions: Any, controls: Any) -> None:
        self._states = np.asarray(states, dtype=float)
        self._observations = np.asarray(observations, dtype=float)
        self._actions = np.asarray(actions, dtype=int).reshape(-1)
        self._controls = np.asarray(controls, dtype=float)
        if self._states.ndim != 2 or self._actions.shape[0] != self._states.shape[0] - 1:
            raise DimensionError(
                f"states (N+1, n) and actions (N,) disagree: "
                f"{self._states.shape} vs {self._actions.shape}"
            )

    @property
    def num_of_steps(self) -> int:
        """Number of transitions ``N``."""
        return self._actions.shape[0]

    def get_state(self, k: int | None = None) -> np.ndarray:
        """True state at step ``k`` (shape (n,)), or all (shape (N+1, n))."""
        return self._states[_index(k, self.num_of_steps + 1, "state")]

    def get_observation(self, k: int | None = None) -> np.ndarray:
        """Observation at step ``k`` (shape (p,)), or all (shape (N+1, p))."""
        return self._observations[_index(k, self._observations.shape[0], "observation")]

    def get_action(self, k: int | None = None) -> Any:
        """Mode applied at step ``k``, or all."""
        out = self._actions[_index(k, self.num_of_steps, "action")]
        return int(out) if k is not None else out

    def get_control(self, k: int | None = None) -> np.ndarray:
        """Control applied at step ``k``, or all."""
        return self._controls[_index(k, self.num_of_steps, "control")]

    def __repr__(self) -> str:
        return f"RealTrajectory(num_of_steps={self.num_of_steps}, n={self._states.shape[1]})"
