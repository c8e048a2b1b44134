"""The true starts of a Monte Carlo: one fixed state, or one draw per run from the plan's prior.

:func:`idstlpy.validate` runs every execution from a fixed true start when it is given one (the
paper's listing), else from a start drawn from the prior (the plan's first belief): then the
rates are the ones the plan's promise is about when the true start is unknown. The draws come
from their own stream (``default_rng(SeedSequence(seed))``), so a run's noise is the same either
way.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .._checks import as_int, as_seed_sequence, as_vector
from ..errors import InvalidArgumentError
from ..trajectory import ProbabilisticTSTrajectory

__all__ = ["prior_starts", "true_starts"]


def prior_starts(
    plan: ProbabilisticTSTrajectory, runs: int, seed: int | np.random.SeedSequence | None = None
) -> np.ndarray:
    """True starts drawn from the plan's prior ``N(mean_0, cov_0)``, one row per run.

    The draws come from ``default_rng(SeedSequence(seed))`` in one call of shape (runs, n), so
    the first ``k`` rows do not depend on ``runs``; a singular ``cov_0`` draws in its range.

    Parameters
    ----------
    plan : ProbabilisticTSTrajectory
        The plan; its first belief is the prior.
    runs : int
        Number of starts (>= 0).
    seed : int or SeedSequence, optional
        Root seed (``validate``'s ``seed``).

    Returns
    -------
    ndarray, shape (runs, n)
    """
    runs = as_int(runs, "runs", minimum=0)
    mean, cov = plan.get_mean(0), plan.get_cov(0)
    factor = _sqrt_psd(cov)
    z = np.random.default_rng(as_seed_sequence(seed)).standard_normal((runs, mean.shape[0]))
    return np.asarray(mean + z @ factor.T)


def _sqrt_psd(cov: np.ndarray) -> np.ndarray:
    """A factor ``L`` with ``L L' = cov`` (Cholesky, else the symmetric square root)."""
    try:
        return np.asarray(np.linalg.cholesky(cov))
    except np.linalg.LinAlgError:
        w, v = np.linalg.eigh(0.5 * (cov + cov.T))
        return np.asarray(v * np.sqrt(np.clip(w, 0.0, None)))


def true_starts(
    real_initial_state: ArrayLike | str | None,
    plan: ProbabilisticTSTrajectory,
    runs: int,
    root: np.random.SeedSequence,
    n: int,
) -> tuple[np.ndarray, np.ndarray | None]:
    """``validate``'s reading of ``real_initial_state``: the nominal start and the runs' starts.

    Parameters
    ----------
    real_initial_state : array_like of shape (n,), "prior" or None
        A fixed true start, or (None, ``"prior"``) a start per run drawn from the prior.
    plan : ProbabilisticTSTrajectory
        The plan; its first belief is the prior.
    runs : int
        Number of runs.
    root : numpy.random.SeedSequence
        The Monte Carlo's root seed (the draws' stream).
    n : int
        The state dimension of the model.

    Returns
    -------
    start : ndarray, shape (n,)
        The fixed start, or the prior's mean when the starts are drawn.
    starts : ndarray of shape (runs, n), or None
        The runs' starts drawn from the prior; None for a fixed start.

    Raises
    ------
    InvalidArgumentError, DimensionError
        Naming ``real_initial_state``.
    """
    if real_initial_state is None or (isinstance(real_initial_state, str) and real_initial_state == "prior"):
        return plan.get_mean(0).copy(), prior_starts(plan, runs, root)
    if isinstance(real_initial_state, str):
        raise InvalidArgumentError(
            f"real_initial_state must be an array of shape (n,), 'prior' or None, got {real_initial_state!r}"
        )
    return as_vector(real_initial_state, "real_initial_state", n), None
