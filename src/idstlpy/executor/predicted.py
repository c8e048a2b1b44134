"""What :func:`~idstlpy.executor.predict.predict_closed_loop` returns: the predicted execution.

:class:`ClosedLoopPrediction` holds the closed loop's moments (the model is in
:mod:`idstlpy.executor.predict`), the per-step probabilities of every chance constraint
(:class:`ConstraintPrediction`), and the bounds and estimates of the formula's success.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._checks import as_int

__all__ = ["ClosedLoopPrediction", "ConstraintPrediction"]


@dataclass(frozen=True)
class ConstraintPrediction:
    """Predictions for one chance constraint ``P[h'x + c <= 0] >= 1 - eps`` of a proposition.

    Attributes
    ----------
    name : str
        ``"<proposition>: <predicate>"``, the key of
        :attr:`~idstlpy.execution.validate.ValidationReport.predicate_violations`.
    proposition : str
        Name of the atomic proposition (``ap<i>`` when unnamed).
    h : ndarray, shape (n,)
    c : float
    eps : float
    belief_probability : ndarray, shape (L,)
        Per step, the predicted probability that the executed belief satisfies the constraint.
    state_probability : ndarray, shape (L,)
        Per step, the predicted probability that the true state satisfies ``h'x + c <= 0``
        (both from the Gaussian model's marginals, or, under the particle closure with samples,
        sampled from the non-Gaussian loop).
    promised : ndarray of bool, shape (L,)
        Steps at which the plan satisfies the proposition (validate's promise).
    belief_violation, state_violation : float
        Predicted probability that the constraint is broken at some promised step (the rate
        ``validate`` measures), estimated by sampling the Gaussian model; NaN without samples.
    """

    name: str
    proposition: str
    h: np.ndarray
    c: float
    eps: float
    belief_probability: np.ndarray
    state_probability: np.ndarray
    promised: np.ndarray
    belief_violation: float = float("nan")
    state_violation: float = float("nan")


@dataclass(frozen=True)
class ClosedLoopPrediction:
    """The predicted execution of a plan (the model is in the module notes).

    ``L = num_of_steps + 1`` steps, state dimension ``n``, augmented dimension ``D`` (``2n``, plus
    ``n^2`` coordinates ``vec(P_k - filter_cov[k])`` when a used mode's sensor noise depends on
    the state and ``filter_sensitivity`` is on).

    Attributes
    ----------
    num_of_steps : int
    sensor_noise : str
        How state-dependent sensor noise was linearised (``"expected"``, ``"mean"``, ``"plan"``).
    plan_means : ndarray, shape (L, n)
    filter_cov : ndarray, shape (L, n, n)
        The executed belief's covariance at the linearisation point (the plan's own covariances
        for constant noise and the filter starting from the plan's prior).
    augmented_mean : ndarray, shape (L, D)
        ``E[z_k]``, ``z = (x - m, mean - m[, vec dP])``.
    augmented_cov : ndarray, shape (L, D, D)
        ``Cov(z_k)`` (symmetric PSD).
    transitions : ndarray, shape (L - 1, D, D)
        ``F_k``: ``z_{k+1} = F_k z_k + offsets[k] + noise`` and
        ``Cov(z_j, z_k) = F_{j-1} ... F_k augmented_cov[k]`` for ``j > k``.
    offsets : ndarray, shape (L - 1, D)
    noise_covs : ndarray, shape (L - 1, D, D)
        Covariance of the noise of each step (process, measurement, clipping residual).
    tracking_gains : ndarray, shape (L - 1, m, n)
        The LQR gain ``simulate`` applies at each step.
    kalman_gains : tuple of ndarray, each shape (n, p_k)
        The filter's gain at each step at the linearisation point (``p_k = 0`` when blind).
    clip_probability : ndarray, shape (L - 1,)
        Per step, an upper bound (union over the domain's faces) on the probability that the
        corrected input is projected on the control domain; zeros without a domain.
    constraints : tuple of ConstraintPrediction
        Every face of every atomic proposition of the formula, in validate's order.
    propositions : tuple of str
        Names of the atomic propositions, in validate's order.
    proposition_violation : dict
        Per proposition, ``{"belief": p, "state": p}``: predicted probability that it is broken
        at some promised step (model sampling; NaN without samples).
    belief_success_bound, state_success_bound : float
        Lower bounds, sound for the Gaussian model, on the probability that the executed belief /
        the true states satisfy the formula (NaN without a formula). Under ``closure ==
        "particles"`` the Gaussian model only matches the clipped loop's first two moments, and
        its bound is not sound for it (a rectifier's tails are heavier); with samples the bound
        is then the smaller of the Gaussian one and the sampled bound below. Under the Gaussian
        closure on a control domain that is not a box (whose projection the Gaussian moments
        leave out) the bound is the unprojected loop's minus ``min(1, sum(clip_probability))``,
        the probability that the projection acts at all: sound for the projected loop.
    belief_success_estimate, state_success_estimate : float
        Point estimates of the same probabilities by sampling the model (NaN without samples).
    belief_success_sampled_bound, state_success_sampled_bound : float
        One-sided Clopper-Pearson lower bounds (confidence 0.999 over the model sampling) on the
        same probabilities: statistical, not deterministic, but far tighter than the analytic
        bound when the formula needs many events (NaN without samples).
    samples : int
        Model samples behind the estimates.
    witness : tuple of (str, int)
        ``(proposition, step)`` pairs of the witness behind the true-state bound.
    closure : str
        ``"gaussian"`` or ``"particles"`` (:func:`idstlpy.closed_loop.propagate`): how the
        moments were closed; under ``"particles"`` the sampled rates and estimates come from the
        clipped loop (and the state-dependent sensor per sample), not the Gaussian model; on a
        control domain that is not a box they come from the projected loop under either closure.
    """

    num_of_steps: int
    sensor_noise: str
    plan_means: np.ndarray
    filter_cov: np.ndarray
    augmented_mean: np.ndarray
    augmented_cov: np.ndarray
    transitions: np.ndarray
    offsets: np.ndarray
    noise_covs: np.ndarray
    tracking_gains: np.ndarray
    kalman_gains: tuple[np.ndarray, ...]
    clip_probability: np.ndarray
    constraints: tuple[ConstraintPrediction, ...] = ()
    propositions: tuple[str, ...] = ()
    proposition_violation: dict[str, dict[str, float]] = field(default_factory=dict)
    belief_success_bound: float = float("nan")
    state_success_bound: float = float("nan")
    belief_success_estimate: float = float("nan")
    state_success_estimate: float = float("nan")
    belief_success_sampled_bound: float = float("nan")
    state_success_sampled_bound: float = float("nan")
    samples: int = 0
    witness: tuple[tuple[str, int], ...] = ()
    closure: str = "gaussian"

    @property
    def n(self) -> int:
        """State dimension."""
        return int(self.plan_means.shape[1])

    @property
    def joint_mean(self) -> np.ndarray:
        """``E[(x_k - m_k, mean_k - m_k)]``, shape (L, 2n)."""
        return self.augmented_mean[:, : 2 * self.n]

    @property
    def joint_cov(self) -> np.ndarray:
        """Covariance of ``(x_k - m_k, mean_k - m_k)``, shape (L, 2n, 2n)."""
        return self.augmented_cov[:, : 2 * self.n, : 2 * self.n]

    @property
    def state_mean(self) -> np.ndarray:
        """Mean of the true state, shape (L, n)."""
        out: np.ndarray = self.plan_means + self.augmented_mean[:, : self.n]
        return out

    @property
    def state_cov(self) -> np.ndarray:
        """Covariance of the true state, shape (L, n, n)."""
        return self.augmented_cov[:, : self.n, : self.n]

    @property
    def belief_mean(self) -> np.ndarray:
        """Mean of the executed belief's (random) mean, shape (L, n)."""
        n = self.n
        out: np.ndarray = self.plan_means + self.augmented_mean[:, n : 2 * n]
        return out

    @property
    def belief_mean_cov(self) -> np.ndarray:
        """Covariance of the executed belief's mean, shape (L, n, n)."""
        n = self.n
        return self.augmented_cov[:, n : 2 * n, n : 2 * n]

    def cross_cov(self, j: int, k: int) -> np.ndarray:
        """``Cov(z_j, z_k)`` of the joint deviations ``z = (x - m, mean - m)``.

        Parameters
        ----------
        j, k : int
            Steps in ``0 .. num_of_steps``.

        Returns
        -------
        ndarray, shape (2n, 2n)
        """
        L = self.num_of_steps + 1
        j = as_int(j, "j", minimum=0, maximum=L - 1)
        k = as_int(k, "k", minimum=0, maximum=L - 1)
        if j < k:
            return self.cross_cov(k, j).T
        out: np.ndarray = self.augmented_cov[k]
        for i in range(k, j):
            out = self.transitions[i] @ out
        return out[: 2 * self.n, : 2 * self.n]

    @property
    def predicate_violation(self) -> dict[str, dict[str, float]]:
        """Per constraint name, ``{"belief": p, "state": p}``, as validate's predicate rates."""
        return {c.name: {"belief": c.belief_violation, "state": c.state_violation} for c in self.constraints}

    def as_dict(self) -> dict[str, Any]:
        """Plain data for JSON: the scalar predictions and per-step probabilities (no matrices)."""

        def num(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        return {
            "num_of_steps": self.num_of_steps,
            "sensor_noise": self.sensor_noise,
            "samples": self.samples,
            "closure": self.closure,
            "belief_success_bound": num(self.belief_success_bound),
            "state_success_bound": num(self.state_success_bound),
            "belief_success_estimate": num(self.belief_success_estimate),
            "state_success_estimate": num(self.state_success_estimate),
            "belief_success_sampled_bound": num(self.belief_success_sampled_bound),
            "state_success_sampled_bound": num(self.state_success_sampled_bound),
            "max_clip_probability": float(self.clip_probability.max()) if self.clip_probability.size else 0.0,
            "proposition_violations": {
                k: {r: num(v) for r, v in d.items()} for k, d in self.proposition_violation.items()
            },
            "predicate_violations": {
                c.name: {
                    "belief": num(c.belief_violation),
                    "state": num(c.state_violation),
                    "belief_step_probability": c.belief_probability.tolist(),
                    "state_step_probability": c.state_probability.tolist(),
                }
                for c in self.constraints
            },
            "witness": [list(w) for w in self.witness],
        }
