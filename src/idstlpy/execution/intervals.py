"""Statistics of a Monte Carlo: Wilson intervals, rates of counted events, margin summaries.

:func:`idstlpy.validate` measures binomial proportions (runs that succeeded, runs that broke a
promise); this module turns counts into rates with their Wilson 95% intervals, puts a predicted
rate beside a measured one, and summarises the per-run robustness margins.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._checks import as_int
from ..errors import InvalidArgumentError

__all__ = ["wilson_interval", "violation_rates", "comparison", "margin_stats"]


def wilson_interval(successes: int, trials: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95% by default).

    Parameters
    ----------
    successes, trials : int
        ``0 <= successes <= trials``.
    z : float
        Standard-normal quantile of the two-sided level (1.96 for 95%).

    Returns
    -------
    (low, high) : tuple of float
        ``(0.0, 1.0)`` when ``trials == 0``.
    """
    successes = as_int(successes, "successes", minimum=0)
    trials = as_int(trials, "trials", minimum=0)
    if successes > trials:
        raise InvalidArgumentError(f"successes must be <= trials, got {successes} > {trials}")
    if trials == 0:
        return 0.0, 1.0
    if successes == 0:
        return 0.0, float(z * z / (trials + z * z))
    if successes == trials:
        return float(trials / (trials + z * z)), 1.0
    p = successes / trials
    z2 = z * z
    denom = 1.0 + z2 / trials
    center = (p + z2 / (2 * trials)) / denom
    half = z * math.sqrt(p * (1 - p) / trials + z2 / (4 * trials * trials)) / denom
    return max(0.0, center - half), min(1.0, center + half)


def violation_rates(
    results: Sequence[dict[str, Any]], key_b: str, key_s: str, names: Sequence[str]
) -> dict[str, dict[str, Any]]:
    """Per name, the fraction of runs whose flag ``j`` is set, for the belief and the true state.

    Parameters
    ----------
    results : sequence of dict
        One record per run; ``record[key_b][j]`` / ``record[key_s][j]`` is run's flag ``j``.
    key_b, key_s : str
        The keys of the belief's and of the true state's flags.
    names : sequence of str
        The name of flag ``j``.

    Returns
    -------
    dict
        ``{name: {"belief": rate, "state": rate, "belief_ci": [lo, hi], "state_ci": [lo, hi]}}``.
    """
    runs = len(results)
    out: dict[str, dict[str, Any]] = {}
    for j, name in enumerate(names):
        nb = sum(r[key_b][j] for r in results)
        ns = sum(r[key_s][j] for r in results)
        out[name] = {
            "belief": nb / runs,
            "state": ns / runs,
            "belief_ci": list(wilson_interval(nb, runs)),
            "state_ci": list(wilson_interval(ns, runs)),
        }
    return out


def comparison(predicted: float, measured: float, ci: Sequence[float]) -> dict[str, Any]:
    """One predicted rate against a measured one and its interval.

    Parameters
    ----------
    predicted : float
        The predicted rate (NaN: not predicted).
    measured : float
        The measured rate.
    ci : sequence of float
        The measured rate's interval ``[lo, hi]``.

    Returns
    -------
    dict
        ``{"predicted", "measured", "ci", "diff", "outside"}`` (``predicted``, ``diff`` and
        ``outside`` None when ``predicted`` is NaN).
    """
    p = float(predicted)
    if not math.isfinite(p):
        return {"predicted": None, "measured": measured, "ci": list(ci), "diff": None, "outside": None}
    # a hair of slack: a rate predicted exactly at an interval's end (0 or 1) is inside it
    outside = not (ci[0] - 1e-12 <= p <= ci[1] + 1e-12)
    return {"predicted": p, "measured": measured, "ci": list(ci), "diff": p - measured, "outside": outside}


def margin_stats(values: Sequence[float]) -> dict[str, float]:
    """``min``, ``median`` and ``max`` of the finite values (NaN when none is finite).

    Parameters
    ----------
    values : sequence of float

    Returns
    -------
    dict
    """
    arr = np.asarray(values, dtype=float)
    finite = arr[np.isfinite(arr)]
    if not finite.size:
        return {"min": float("nan"), "median": float("nan"), "max": float("nan")}
    return {"min": float(finite.min()), "median": float(np.median(finite)), "max": float(finite.max())}
