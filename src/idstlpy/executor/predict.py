"""Predict, before executing, what the executor will do with a plan (the linear-Gaussian closed loop).

This module sits below the synthesis layer (the planner's default guarantee asks it whether a
plan meets its execution target); :mod:`idstlpy.execution.prediction` re-exports it.

:func:`~idstlpy.execution.simulate.simulate` tracks a plan with a Kalman filter and
receding-horizon LQR. Around the plan (modes ``q_k``, means ``m_k``, inputs ``v_k``) that loop is
linear, as in LQG-MP (van den Berg, Abbeel, Goldberg, 2011). With ``delta_k = x_k - m_k`` the
true state's deviation and ``eta_k = mean_k - m_k`` the executed belief mean's deviation, one step
of mode ``q`` (model ``A, B, C``, real ``A_r, B_r``, tracking gain ``K``, Kalman gain ``L``) is::

    u_k         = v_k - K eta_k
    delta_{k+1} = A_r delta_k - B_r K eta_k + d_k + W w_k
    eta_{k+1}   = L C A_r delta_k + ((I - L C)(A - B K) - L C B_r K) eta_k
                  - (I - L C) r_k + L C d_k + L C W w_k + L n(x_{k+1}) v_{k+1}

with ``d_k = A_r m_k + B_r v_k - m_{k+1}`` (model mismatch) and ``r_k = m_{k+1} - A m_k - B v_k``
(zero for a plan made by the MLO roll-out). The joint state ``z = (delta, eta)`` (``2n``) is a
linear Gauss-Markov process: its mean starts at ``(x_0 - m_0, mean_0 - m_0)`` (the paper's true
start [0.5, 2.75] against the belief mean [0, 2.5]) and its ``2n x 2n`` covariance is propagated
exactly, ``S_{k+1} = F_k S_k F_k' + Q_k``.

What is exact and what is approximated
--------------------------------------
- **Constant sensor noise, inputs never clipped**: the filter's gains and covariances do not
  depend on the observations, so the prediction is the exact distribution of the execution.
- **Clipped inputs.** ``simulate`` projects ``v_k - K eta_k`` on the control domain. For a box
  the clip is replaced by its statistical linearisation: exact mean of the clipped input, exact
  cross-covariance with the loop (Stein's lemma: the gain becomes ``diag(P[inside]) K``), its
  remaining variance as independent noise. Other polytopes are not modelled (a log warning says
  how likely the projection is). :attr:`ClosedLoopPrediction.clip_probability` reports, per
  step, an upper bound on the probability that the input is clipped.
- **State-dependent sensor noise** ``R(x) = n(x) n(x)'`` is linearised around the plan, in three
  places. (1) The observation noise acting on the loop is ``n(x_{k+1}) v`` at the *true* state:
  ``sensor_noise="expected"`` (default) uses ``E[R(x_{k+1})]`` over the predicted true state
  (Gauss-Hermite cubature; this makes the loop's first two moments right given the gains),
  ``"mean"`` uses ``R`` at the predicted true-state mean and ``"plan"`` at the planned mean
  ``m_{k+1}``. (2) The filter evaluates ``R`` at its own, random, predicted mean: the Kalman gains
  and the filter covariance ``filter_cov`` are computed at the predicted mean of that point
  (``"plan"``: at the plan's, which reproduces the plan's covariances). (3) With
  ``filter_sensitivity=True`` (default) the first-order variation of the filter covariance with
  the filter's mean path, ``dP_{k+1} = Phi dP_k Phi' + L dR L'`` (``Phi = (I - L C) A``; the
  Joseph form is stationary in the gain), is carried as ``n^2`` extra coordinates of the state,
  so that the executed belief's chance constraints, whose ``sqrt(h' P_k h)`` term moves with the
  observations, are linear in one Gaussian vector. The loop is then only approximately Gaussian;
  ``benchmarks/closed_loop.py`` and ``tests/test_prediction.py`` measure the error against Monte
  Carlo.
- **The particle closure** (``closure="particles"``, chosen by the default ``"auto"`` under a
  state-dependent sensor or when the input is clipped with probability above 1%). Both
  non-linearities above make the loop non-Gaussian in ways no Gaussian can follow: a plan riding
  an input bound makes the clipped loop a rectifier (lags are not corrected and accumulate: the
  true state's spread was 3x the linearisation's on the sensor-switching plan), and a
  state-dependent sensor skews the true state toward the dark. Samples of ``z`` are then pushed
  through the loop with the clip itself, each drawing the sensor's noise at its own true state
  (the noise factor's quadratic interpolant over the predicted true state) and, with
  ``filter_sensitivity``, running its own filter (``R`` at its own predicted mean, its own
  covariance, whose deviation from the nominal one is the ``dP`` coordinates). The moments are
  the samples' and ``F, g, Q`` their statistical linear regression; the point estimates below
  are sampled from the same non-linear loop. What remains approximate: the noise factor's
  interpolant (exact for a quadratic one) and the Gaussian marginals behind the per-step
  probabilities and the analytic bound (which is then capped by the sampled one).

From the (augmented) Gaussian, per chance constraint ``P[h'x + c <= 0] >= 1 - eps`` of every
atomic proposition at every step:

- the probability that the **executed belief** satisfies it,
  ``P[h' mean_k + c + Phi^-1(1 - eps) sqrt(h' P_k h) <= 0]`` (``P_k`` the filter covariance;
  :mod:`idstlpy.chance` computes the term);
- the probability that the **true state** satisfies its deterministic reading ``h'x_k + c <= 0``.

A *lower bound* on the probability that the whole formula holds (executed belief, true state):
one minus Hunter's tree bound on the union of the failures of the events a witness of the
formula needs (per constraint, its steps chained in time, with exact bivariate normal
probabilities); the witness is the plan's own (:func:`idstlpy.synthesis.plan.extract_witness`,
latest and earliest until-steps) or the one a dynamic programme on the predicted failure
probabilities finds, whichever bound is smallest. It is sound for the Gaussian model (so exactly
sound in the exact case above). Point estimates of the rates
:func:`~idstlpy.execution.validate.validate` measures (a constraint broken at some promised
step, the formula's success) come from sampling the Gaussian model (no filter, no simulation).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, TypeGuard

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import ndtr, owens_t

from .._checks import as_covariance, as_int, as_vector
from ..belief import GaussianBelief
from ..chance import joint_tail_sum, std_terms
from ..closed_loop import (
    ClosedLoopMoments,
    box_bounds,
    gains_for,
    prob_le,
    propagate,
    real_modes_for,
    sqrt_psd,
)
from ..dynamical_system import LCS, SwitchedSystem
from ..errors import DimensionError, InvalidArgumentError, InvalidTypeError
from ..formulas import STLAnd, STLAtomicProposition, STLFormula, STLOr, STLRelease, STLUntil
from ..semantics import atom_margins
from ..sets import Polytope
from ..trajectory import ProbabilisticTSTrajectory

if TYPE_CHECKING:  # the synthesis layer is above this one
    from ..synthesis.problem import Problem

__all__ = [
    "ClosedLoopPrediction",
    "ConstraintPrediction",
    "predict_closed_loop",
    "bivariate_normal_cdf",
    "SensorNoise",
]

logger = logging.getLogger(__name__)

SensorNoise = Literal["expected", "mean", "plan"]
Closure = Literal["auto", "gaussian", "particles"]

_INTERSECTION_SLACK = 1e-9
"""Subtracted from every bivariate probability the Hunter bound uses (numerical safety)."""


# --------------------------------------------------------------------------------------------
# Bivariate normal


def bivariate_normal_cdf(h: ArrayLike, k: ArrayLike, rho: ArrayLike) -> np.ndarray:
    """``P[Z1 <= h, Z2 <= k]`` for standard normals with correlation ``rho`` (Owen's T).

    Parameters
    ----------
    h, k : array_like, broadcastable
        Upper limits (``+-inf`` allowed).
    rho : array_like, broadcastable
        Correlations in ``[-1, 1]``.

    Returns
    -------
    ndarray
        The probabilities, clipped to the Frechet bounds ``[max(0, Phi(h) + Phi(k) - 1),
        min(Phi(h), Phi(k))]``.
    """
    h, k, rho = np.broadcast_arrays(
        np.asarray(h, dtype=float), np.asarray(k, dtype=float), np.clip(np.asarray(rho, dtype=float), -1, 1)
    )
    ph, pk = ndtr(h), ndtr(k)
    lo, hi = np.maximum(0.0, ph + pk - 1.0), np.minimum(ph, pk)
    s = np.sqrt(np.maximum(0.0, 1.0 - rho * rho))
    finite = np.isfinite(h) & np.isfinite(k)
    # Zeros are taken as +0 (the limit from above, consistent with the beta rule below).
    hf = np.where(finite & (h != 0), h, np.where(finite, 0.0, 1.0))
    kf = np.where(finite & (k != 0), k, np.where(finite, 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ah = (kf - rho * hf) / (hf * s)
        ak = (hf - rho * kf) / (kf * s)
        sign = np.sign(hf) * np.sign(kf)  # not hf * kf, which underflows
        beta = np.where((sign > 0) | ((sign == 0) & (hf + kf >= 0)), 0.0, 0.5)
        general = 0.5 * (ph + pk) - owens_t(hf, ah) - owens_t(kf, ak) - beta
    origin = 0.25 + np.arcsin(rho) / (2 * np.pi)
    out = np.where((hf == 0) & (kf == 0), origin, general)
    degenerate = s < 1e-9
    out = np.where(degenerate & (rho > 0), hi, out)
    out = np.where(degenerate & (rho < 0), lo, out)
    # An infinite limit: the probability is a marginal (or 0), i.e. the Frechet bounds meet.
    out = np.where(finite, out, np.where(np.isposinf(h) | np.isposinf(k), hi, 0.0))
    out = np.where(np.isnan(out), hi, out)
    return np.clip(out, lo, hi)


def _standardised(mu: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """``mu / sd`` with ``+-inf`` for ``sd == 0`` (the sign of ``mu``; ``mu <= 0`` gives ``-inf``)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = mu / sd
    return np.where(sd > 0, t, np.where(mu > 0, np.inf, -np.inf))


# --------------------------------------------------------------------------------------------
# Results


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
        is then the smaller of the Gaussian one and the sampled bound below.
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
        clipped loop (and the state-dependent sensor per sample), not the Gaussian model.
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


# --------------------------------------------------------------------------------------------
# Faces, witnesses and bounds


@dataclass
class _Faces:
    """The chance constraints of the formula's propositions, stacked (``F`` faces).

    For each reading (``"state"``, ``"belief"``) the constraint's left-hand side at step ``k`` is
    ``a[k, f] . z_k + const[k, f]`` (the constraint holds when it is ``<= 0``).
    """

    H: np.ndarray  # (F, n)
    c: np.ndarray  # (F,)
    z: np.ndarray  # (F,)
    atom: np.ndarray  # (F,) index of the proposition
    a: dict[str, np.ndarray]  # (L, F, D)
    mu: dict[str, np.ndarray]  # (L, F) mean of the left-hand side
    sd: dict[str, np.ndarray]  # (L, F) its standard deviation


def _faces(
    aps: list[STLAtomicProposition], loop: ClosedLoopMoments, plan_means: np.ndarray, n: int
) -> _Faces:
    rows_H, rows_c, rows_z, rows_a = [], [], [], []
    for i, ap in enumerate(aps):
        cone = ap.cone
        if cone.num_faces == 0:
            continue
        if cone.dim != n:
            raise DimensionError(
                f"proposition {ap.name or ap} is over a {cone.dim}-dimensional variable, "
                f"the state has n = {n}"
            )
        rows_H.append(cone.H)
        rows_c.append(cone.c)
        rows_z.append(cone.z)
        rows_a.append(np.full(cone.num_faces, i))
    if rows_H:
        H, c = np.vstack(rows_H), np.concatenate(rows_c)
        z, atom = np.concatenate(rows_z), np.concatenate(rows_a).astype(int)
    else:
        H, c, z, atom = np.zeros((0, n)), np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)
    L, D = loop.mean.shape
    nF = H.shape[0]
    a_x = np.zeros((L, nF, D))
    a_x[:, :, :n] = H[None]
    a_b = np.zeros((L, nF, D))
    a_b[:, :, n : 2 * n] = H[None]
    terms = std_terms(H, z, loop.P)  # (L, F): z sqrt(h' P h) at the linearisation point
    if loop.sensitivity and nF:
        # d sqrt(h' P h) = h' dP h / (2 sqrt(h' P h)); no first-order term where it is 0 or eps = 0.
        sd_bar = np.sqrt(np.maximum(np.einsum("fi,kij,fj->kf", H, loop.P, H), 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            coef = np.where((sd_bar > 0) & np.isfinite(z)[None], z[None] / (2 * sd_bar), 0.0)
        hh = np.einsum("fi,fj->fij", H, H).reshape(nF, n * n)
        a_b[:, :, 2 * n :] = coef[:, :, None] * hh[None]
    const_x = plan_means @ H.T + c
    const_b = const_x + terms
    mu, sd = {}, {}
    for name, a, const in (("state", a_x, const_x), ("belief", a_b, const_b)):
        mu[name] = np.einsum("kfd,kd->kf", a, loop.mean) + const
        sd[name] = np.sqrt(np.maximum(np.einsum("kfd,kde,kfe->kf", a, loop.cov, a), 0.0))
    return _Faces(H, c, z, atom, {"state": a_x, "belief": a_b}, mu, sd)


def _mode_ok(aps: list[STLAtomicProposition], actions: np.ndarray, L: int) -> np.ndarray:
    """``ok[a, k]``: the mode part of proposition ``a`` holds at step ``k`` (plan modes), (A, L)."""
    ok = np.ones((len(aps), L), dtype=bool)
    for i, ap in enumerate(aps):
        if ap.is_false:
            ok[i] = False
        elif ap.modes is not None and L > 1:
            ok[i, 1:] = np.isin(actions[: L - 1], np.fromiter(ap.modes, dtype=int, count=len(ap.modes)))
    return ok


def _shift(arr: np.ndarray, d: int) -> np.ndarray:
    """``arr[k + d]`` for every ``k`` (``+inf`` cost past the end)."""
    L = arr.shape[0]
    out = np.full(L, np.inf)
    if d < L:
        out[: L - d] = arr[d:]
    return out


def _dp_costs(formula: STLFormula, atom_cost: dict[int, np.ndarray], L: int) -> dict[int, np.ndarray]:
    """Additive union-bound cost of the cheapest witness of every sub-formula at every step.

    ``atom_cost[id(ap)]`` (L,) is the summed violation probability of the proposition's faces
    (``inf`` where it cannot hold). And sums, or takes the minimum, until / release take the
    cheapest witness step. Costs are sound upper bounds on the failure probability.
    """
    memo: dict[int, np.ndarray] = {}

    def rec(f: STLFormula) -> np.ndarray:
        key = id(f)
        if key in memo:
            return memo[key]
        if isinstance(f, STLAtomicProposition):
            if f.is_false:
                out = np.full(L, np.inf)
            elif key in atom_cost:
                out = atom_cost[key]
            else:
                out = np.zeros(L)
        elif isinstance(f, STLAnd):
            out = np.sum([rec(c) for c in f.children], axis=0)
        elif isinstance(f, STLOr):
            out = np.minimum.reduce([rec(c) for c in f.children])
        elif isinstance(f, STLUntil):
            c1, c2 = rec(f.left), rec(f.right)
            out = np.full(L, np.inf)
            prefix = np.zeros(L)
            for d in range(f.a, min(f.b, L - 1) + 1):
                out = np.minimum(out, _shift(c2, d) + prefix)
                prefix = prefix + _shift(c1, d)
        elif isinstance(f, STLRelease):
            c1, c2 = rec(f.left), rec(f.right)
            out = np.full(L, np.inf)
            prefix = np.zeros(L)
            for d in range(f.a, f.b + 1):
                prefix = prefix + _shift(c2, d)
                out = np.minimum(out, _shift(c1, d) + prefix)
                if d >= L:
                    break
            out = np.minimum(out, prefix)
        else:
            raise InvalidTypeError(f"cannot bound {type(f).__name__}")
        memo[key] = out
        return out

    rec(formula)
    return memo


def _dp_witness(
    formula: STLFormula, costs: dict[int, np.ndarray], atom_index: dict[int, int], L: int
) -> set[tuple[int, int]] | None:
    """The (atom, step) pairs of the cheapest witness the costs describe (None when impossible)."""
    if not np.isfinite(costs[id(formula)][0]):
        return None
    need: set[tuple[int, int]] = set()
    seen: set[tuple[int, int]] = set()
    stack: list[tuple[STLFormula, int]] = [(formula, 0)]

    def cost(f: STLFormula, j: int) -> float:
        return float(costs[id(f)][j]) if 0 <= j < L else np.inf

    while stack:
        f, k = stack.pop()
        if (id(f), k) in seen:
            continue
        seen.add((id(f), k))
        if isinstance(f, STLAtomicProposition):
            if id(f) in atom_index:
                need.add((atom_index[id(f)], k))
        elif isinstance(f, STLAnd):
            stack.extend((c, k) for c in f.children)
        elif isinstance(f, STLOr):
            stack.append((min(f.children, key=lambda c: cost(c, k)), k))
        elif isinstance(f, STLUntil):
            best, best_j, prefix = np.inf, -1, 0.0
            for j in range(k + f.a, min(k + f.b, L - 1) + 1):
                total = cost(f.right, j) + prefix
                if total < best:
                    best, best_j = total, j
                prefix += cost(f.left, j)
            stack.append((f.right, best_j))
            stack.extend((f.left, j) for j in range(k + f.a, best_j))
        elif isinstance(f, STLRelease):
            best, best_j, prefix = np.inf, None, 0.0
            for j in range(k + f.a, k + f.b + 1):
                prefix += cost(f.right, j)
                total = cost(f.left, j) + prefix
                if total < best:
                    best, best_j = total, j
                if j >= L:
                    break
            if prefix <= best:  # the right side on the whole window
                best_j = None
            end = k + f.b if best_j is None else best_j
            if best_j is not None:
                stack.append((f.left, best_j))
            stack.extend((f.right, j) for j in range(k + f.a, end + 1))
    return need


def _hunter_failure(
    events: list[tuple[int, int]], faces: _Faces, reading: str, loop: ClosedLoopMoments
) -> float:
    """Hunter's bound ``sum P(A_i) - sum_{tree} P(A_i & A_j)`` on ``P(some event fails)``.

    ``events`` are (face, step) pairs; faces with the same constraint (``h, c`` and, for the
    belief, ``eps``) are merged; the tree chains each constraint's steps in time order.
    """
    mu, sd, a = faces.mu[reading], faces.sd[reading], faces.a[reading]
    groups: dict[tuple[Any, ...], set[int]] = {}
    rep: dict[tuple[Any, ...], int] = {}
    for f, k in events:
        key: tuple[Any, ...] = (*faces.H[f].tolist(), float(faces.c[f]))
        if reading == "belief":
            key = (*key, float(faces.z[f]))
        groups.setdefault(key, set()).add(k)
        rep.setdefault(key, f)
    total = 0.0
    for key, steps in groups.items():
        f = rep[key]
        ks = sorted(steps)
        p = 1.0 - prob_le(mu[ks, f], sd[ks, f])
        total += float(np.sum(p))
        if len(ks) < 2:
            continue
        # Chain edges: Cov(a_k' z_k, a_j' z_j) = a_k' F_{k-1} ... F_j Cov(z_j) a_j.
        t = _standardised(mu[ks, f], sd[ks, f])
        rhos = np.zeros(len(ks) - 1)
        for i in range(len(ks) - 1):
            j, k = ks[i], ks[i + 1]
            vec = loop.cov[j] @ a[j, f]
            for s in range(j, k):
                vec = loop.F[s] @ vec
            denom = sd[j, f] * sd[k, f]
            if denom > 0:
                rhos[i] = float(a[k, f] @ vec) / denom
        both = bivariate_normal_cdf(t[:-1], t[1:], rhos)
        both = np.maximum(0.0, np.minimum(both - _INTERSECTION_SLACK, np.minimum(p[:-1], p[1:])))
        total -= float(np.sum(both))
    return max(0.0, min(1.0, total))


def _success_bound(
    formula: STLFormula,
    aps: list[STLAtomicProposition],
    faces: _Faces,
    mode_ok: np.ndarray,
    plan_truth: np.ndarray,
    reading: str,
    loop: ClosedLoopMoments,
) -> tuple[float, list[tuple[int, int]]]:
    """Lower bound on the formula's success for one reading, and the witness used."""
    from ..synthesis.plan import extract_witness

    L = mode_ok.shape[1]
    atom_index = {id(ap): i for i, ap in enumerate(aps)}
    viol = 1.0 - prob_le(faces.mu[reading], faces.sd[reading])  # (L, F)
    atom_cost: dict[int, np.ndarray] = {}
    for i, ap in enumerate(aps):
        cost = viol[:, faces.atom == i].sum(axis=1)
        atom_cost[id(ap)] = np.where(mode_ok[i], cost, np.inf)
    candidates: list[set[tuple[int, int]]] = []
    dp = _dp_witness(formula, _dp_costs(formula, atom_cost, L), atom_index, L)
    if dp is not None:
        candidates.append(dp)
    for late in (True, False):
        got = extract_witness(formula, plan_truth, atom_index, prefer_late=late)
        if got is not None:
            candidates.append({(int(i), int(k)) for i, k in zip(*np.nonzero(got[0]), strict=True)})
    best, best_w = np.inf, []
    for w in candidates:
        if any(not mode_ok[i, k] for i, k in w):
            continue
        events = [(int(f), k) for i, k in w for f in np.flatnonzero(faces.atom == i)]
        fail = _hunter_failure(events, faces, reading, loop) if events else 0.0
        if fail < best:
            best, best_w = fail, sorted(w, key=lambda t: (t[1], t[0]))
    if not np.isfinite(best):
        return 0.0, []
    return 1.0 - best, best_w


# --------------------------------------------------------------------------------------------
# Sampling the Gaussian model


def _clopper_pearson_lower(rate: float, trials: int, confidence: float = 0.999) -> float:
    """One-sided Clopper-Pearson lower bound of a binomial proportion (NaN without trials)."""
    if not trials or not np.isfinite(rate):
        return float("nan")
    from scipy.stats import beta

    k = int(round(rate * trials))
    return 0.0 if k == 0 else float(beta.ppf(1.0 - confidence, k, trials - k + 1))


def _joint_groups(aps: list[STLAtomicProposition]) -> list[tuple[np.ndarray, float]]:
    """The face rows (in :func:`_faces` order) of every joint chance constraint, with its ``eps``."""
    out: list[tuple[np.ndarray, float]] = []
    row = 0
    for ap in aps:
        at = row + ap.num_single
        for joint in ap.joints:
            out.append((np.arange(at, at + joint.num_faces), joint.eps))
            at += joint.num_faces
        row += ap.cone.num_faces
    return out


def _sample_events(
    loop: ClosedLoopMoments,
    faces: _Faces,
    size: int,
    rng: np.random.Generator,
    roots: list[np.ndarray],
    groups: list[tuple[np.ndarray, float]] | None = None,
) -> dict[str, np.ndarray]:
    """Face truth on ``size`` trajectories sampled from the model, per reading a bool array (S, L, F).

    The faces of a joint chance constraint (``groups``) are judged together, as the monitor and
    ``validate`` do: on the executed belief by Boole's bound (:func:`idstlpy.chance.joint_risk`),
    on the true state as the region; each of them holds in a sample iff the joint constraint does.
    """
    L, D = loop.mean.shape
    nF = faces.H.shape[0]
    ok = {r: np.empty((size, L, nF), dtype=bool) for r in ("state", "belief")}
    const = {r: faces.mu[r] - np.einsum("kfd,kd->kf", faces.a[r], loop.mean) for r in ok}
    z = loop.mean[0] + rng.standard_normal((size, D)) @ roots[0].T
    clipped = loop.closure == "particles" and loop.steps is not None
    for k in range(L):
        if k and clipped:  # the clipped loop itself (the Gauss-Markov model is its regression)
            z = loop.steps[k - 1].advance(z, rng)  # type: ignore[index]
        elif k:
            z = z @ loop.F[k - 1].T + loop.g[k - 1] + rng.standard_normal((size, D)) @ roots[k].T
        for r in ok:
            ok[r][:, k] = z @ faces.a[r][k].T + const[r][k] <= 0
        if clipped and loop.sensitivity:  # each sample's own filter covariance, not its linearisation
            n = faces.H.shape[1]
            Pk = loop.P[k] + z[:, 2 * n :].reshape(size, n, n)
            lhs = z[:, n : 2 * n] @ faces.H.T + const["state"][k] + std_terms(faces.H, faces.z, Pk)
            ok["belief"][:, k] = lhs <= 0
        for rows, eps in groups or ():
            n = faces.H.shape[1]
            Hg = faces.H[rows]
            P = loop.P[k] + z[:, 2 * n :].reshape(size, n, n) if loop.sensitivity else loop.P[k]
            d = -(z[:, n : 2 * n] @ Hg.T + const["state"][k][rows])
            sd = np.sqrt(np.maximum(np.einsum("fi,...ij,fj->...f", Hg, P, Hg), 0.0))
            held = joint_tail_sum(d, np.broadcast_to(sd, d.shape)) <= eps
            ok["belief"][:, k, rows] = held[:, None]
            ok["state"][:, k, rows] = np.all(ok["state"][:, k, rows], axis=1)[:, None]  # the region
    return ok


def _sample_rates(
    loop: ClosedLoopMoments,
    faces: _Faces,
    samples: int,
    seed: int | np.random.SeedSequence | None,
    formula: STLFormula,
    aps: list[STLAtomicProposition],
    mode_ok: np.ndarray,
    plan_truth: np.ndarray,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, float], dict[str, np.ndarray]]:
    """Model-sampled rates, in chunks of bounded memory: per reading, each face broken at some
    promised step (F,), each proposition broken at some promised step (A,), the formula's success,
    and each face's per-step probability of holding (L, F)."""
    rng = np.random.default_rng(seed)
    L = loop.mean.shape[0]
    nF = faces.H.shape[0]
    roots = [sqrt_psd(loop.cov[0])] + [sqrt_psd(Q) for Q in loop.Q]
    promised = plan_truth[faces.atom].T[None]  # (1, L, F)
    readings = ("state", "belief")
    face_n = {r: np.zeros(nF) for r in readings}
    prop_n = {r: np.zeros(len(aps)) for r in readings}
    ok_n = {r: 0.0 for r in readings}
    step_n = {r: np.zeros((L, nF)) for r in readings}
    chunk = max(1, min(samples, 30_000_000 // max(1, L * max(nF, 1))))
    done = 0
    while done < samples:
        size = min(chunk, samples - done)
        ok = _sample_events(loop, faces, size, rng, roots, _joint_groups(aps))
        for r in readings:
            step_n[r] += np.sum(ok[r], axis=0)
            broken = ~ok[r] & promised  # (S, L, F)
            face_n[r] += np.sum(np.any(broken, axis=1), axis=0)
            for i in range(len(aps)):
                prop_n[r][i] += np.sum(np.any(broken[:, :, faces.atom == i], axis=(1, 2)))
            ok_n[r] += _formula_rate(formula, aps, ok[r], faces, mode_ok) * size
        done += size
    return (
        {r: face_n[r] / samples for r in readings},
        {r: prop_n[r] / samples for r in readings},
        {r: ok_n[r] / samples for r in readings},
        {r: step_n[r] / samples for r in readings},
    )


def _formula_rate(
    formula: STLFormula,
    aps: list[STLAtomicProposition],
    face_ok: np.ndarray,
    faces: _Faces,
    mode_ok: np.ndarray,
) -> float:
    """Fraction of sampled trajectories (face truth (S, L, F)) on which the formula holds."""
    from ..synthesis.plan import evaluate_bool

    S, L, _ = face_ok.shape
    truth = np.empty((S, len(aps), L), dtype=bool)
    for i in range(len(aps)):
        truth[:, i] = np.all(face_ok[:, :, faces.atom == i], axis=2) & mode_ok[i][None, :]
    packed = np.packbits(truth.reshape(S, -1), axis=1)
    uniq, inverse = np.unique(packed, axis=0, return_inverse=True)
    atom_index = {id(ap): i for i, ap in enumerate(aps)}
    holds = np.empty(uniq.shape[0], dtype=bool)
    for u in range(uniq.shape[0]):
        row = np.unpackbits(uniq[u], count=len(aps) * L).astype(bool).reshape(len(aps), L)
        holds[u] = bool(evaluate_bool(formula, row, atom_index)[id(formula)][0])
    return float(np.mean(holds[np.asarray(inverse).reshape(-1)]))


# --------------------------------------------------------------------------------------------
# Public entry point


def _is_problem(obj: object) -> TypeGuard[Problem]:
    """Whether ``obj`` is a problem (a model, a formula and a control domain).

    Read by its attributes, not its class: this module sits below the synthesis layer that
    defines :class:`~idstlpy.synthesis.problem.Problem`.
    """
    return (
        isinstance(getattr(obj, "switched_system", None), SwitchedSystem)
        and hasattr(obj, "stl_formula")
        and hasattr(obj, "control_domain")
    )


def _resolve(
    problem_or_system: Problem | SwitchedSystem,
    formula: STLFormula | None,
    control_domain: Polytope | None | str,
) -> tuple[SwitchedSystem, STLFormula | None, Polytope | None]:
    if _is_problem(problem_or_system):
        system = problem_or_system.switched_system
        formula = problem_or_system.stl_formula if formula is None else formula
        domain = problem_or_system.control_domain if isinstance(control_domain, str) else control_domain
    elif isinstance(problem_or_system, SwitchedSystem):
        system = problem_or_system
        domain = None if isinstance(control_domain, str) else control_domain
    else:
        raise InvalidTypeError(
            f"problem_or_system must be a Problem or a SwitchedSystem, got {type(problem_or_system).__name__}"
        )
    if isinstance(control_domain, str) and control_domain != "problem":
        raise InvalidArgumentError(
            f"control_domain must be a Polytope, None or 'problem', got {control_domain!r}"
        )
    if formula is not None and not isinstance(formula, STLFormula):
        raise InvalidTypeError(f"formula must be an STLFormula, got {type(formula).__name__}")
    return system, formula, domain


def predict_closed_loop(
    problem_or_system: Problem | SwitchedSystem,
    plan: ProbabilisticTSTrajectory,
    real_system: SwitchedSystem | LCS | None = None,
    real_initial_state: ArrayLike | None = None,
    *,
    formula: STLFormula | None = None,
    num_of_steps: int | None = None,
    control_domain: Polytope | None | str = "problem",
    process_noise: str = "model",
    lqr_gains: Mapping[int, Sequence[np.ndarray]] | Sequence[Sequence[np.ndarray] | None] | None = None,
    default_lqr: Mapping[str, Any] | None = None,
    initial_belief: GaussianBelief | None = None,
    real_initial_cov: ArrayLike | None = None,
    sensor_noise: SensorNoise = "expected",
    filter_sensitivity: bool = True,
    samples: int = 4000,
    seed: int | np.random.SeedSequence | None = 0,
    closure: Closure = "auto",
    particles: int = 4000,
) -> ClosedLoopPrediction:
    """Predict the execution of a plan by :func:`~idstlpy.execution.simulate.simulate`.

    Takes the execution options of ``simulate`` / ``validate`` and returns the distribution of
    the true state and of the executed belief at every step, the predicted probability of every
    chance constraint at every step, and a sound lower bound and a point estimate for the formula
    (module notes: exact for constant sensor noise without clipping; clipping on a box and
    state-dependent sensor noise are linearised around the plan).

    Parameters
    ----------
    problem_or_system : Problem or SwitchedSystem
        The planning model (and, for a Problem, the formula and the control domain).
    plan : ProbabilisticTSTrajectory
        The plan, ``N`` steps, state dimension ``n``, input dimension ``m``.
    real_system : SwitchedSystem or LCS, optional
        The system moving the true state (one mode per planning mode, or one for all); default
        the planning model itself.
    real_initial_state : array_like, shape (n,), optional
        True initial state (default the plan's initial mean).
    formula : STLFormula, optional
        Overrides the problem's formula; without any, only the moments are predicted.
    num_of_steps : int, optional
        Steps executed, ``0 <= num_of_steps <= N`` (default ``N``).
    control_domain : Polytope, None or "problem"
        The polytope (shape ``m``) the corrected input is projected on: ``"problem"`` (default)
        the problem's, as ``validate(clip_controls=True)``; None: no projection, as ``simulate``
        without ``control_domain``.
    process_noise : {"model", "real", "none"}
        As in ``simulate``.
    lqr_gains, default_lqr : optional
        As in ``simulate`` (per-mode gains (m, n); weights for modes without gains).
    initial_belief : GaussianBelief, optional
        The filter's prior (default the plan's first belief).
    real_initial_cov : array_like, shape (n, n), optional
        Covariance of a random true initial state (default 0: ``simulate``'s fixed start).
    sensor_noise : {"expected", "mean", "plan"}
        Linearisation of state-dependent sensor noise (module notes); no effect on constant noise.
    filter_sensitivity : bool
        Carry the first-order variation of the filter covariance with the filter's mean path
        (state-dependent noise only).
    samples : int
        Samples of the Gaussian model for the point estimates (0: none, the estimates are NaN).
    seed : int or SeedSequence, optional
        Seed of those samples (default 0: deterministic).
    closure : {"auto", "gaussian", "particles"}
        How the loop's non-linearities are modelled (:func:`idstlpy.closed_loop.propagate`):
        ``"gaussian"``: the clip of the corrected input on a box by its statistical
        linearisation and a state-dependent sensor linearised (``sensor_noise``), the loop kept
        Gaussian; ``"particles"``: ``particles`` samples (seed 0, deterministic) pushed through
        the clip itself, each drawing the sensor's noise at its own true state and running its own
        filter; the moments are theirs and the point estimates are sampled from the same loop;
        ``"auto"`` (default): particles under a state-dependent sensor or when the input is
        clipped with probability above 1% at some step.
    particles : int
        Samples of the particle closure.

    Returns
    -------
    ClosedLoopPrediction

    Raises
    ------
    InvalidArgumentError
        When the plan is None, an option is invalid or the predicted loop diverges.
    DimensionError
        When dimensions of the plan, the model, the domain and the real system disagree.
    InvalidTypeError
        When an argument has the wrong type.
    """
    system, formula, domain = _resolve(problem_or_system, formula, control_domain)
    if plan is None:
        raise InvalidArgumentError(
            "plan is None: there is no plan to predict (see problem.last_result.reason)"
        )
    if not isinstance(plan, ProbabilisticTSTrajectory):
        raise InvalidTypeError(f"plan must be a ProbabilisticTSTrajectory, got {type(plan).__name__}")
    n, m = system.n, system.m
    if plan.n != n:
        raise DimensionError(f"plan has state dimension {plan.n}, the system has n = {n}")
    N = plan.num_of_steps if num_of_steps is None else as_int(num_of_steps, "num_of_steps", minimum=0)
    if N > plan.num_of_steps:
        raise InvalidArgumentError(
            f"num_of_steps must be <= plan.num_of_steps ({plan.num_of_steps}), got {N}"
        )
    actions = np.asarray(plan.get_action(), dtype=int)[:N]
    if N and plan.get_control().shape[1] != m:
        raise DimensionError(f"plan has inputs of size {plan.get_control().shape[1]}, the system has m = {m}")
    if N and (actions.min() < 0 or actions.max() >= system.num_modes):
        raise DimensionError(
            f"the plan uses modes {sorted(set(actions.tolist()))}, the system has 0..{system.num_modes - 1}"
        )
    if process_noise not in ("model", "real", "none"):
        raise InvalidArgumentError(f"process_noise must be 'model', 'real' or 'none', got {process_noise!r}")
    if sensor_noise not in ("expected", "mean", "plan"):
        raise InvalidArgumentError(f"sensor_noise must be 'expected', 'mean' or 'plan', got {sensor_noise!r}")
    if not isinstance(filter_sensitivity, bool):
        raise InvalidTypeError(f"filter_sensitivity must be a bool, got {type(filter_sensitivity).__name__}")
    samples = as_int(samples, "samples", minimum=0)
    particles = as_int(particles, "particles", minimum=2)
    if closure not in ("auto", "gaussian", "particles"):
        raise InvalidArgumentError(f"closure must be 'auto', 'gaussian' or 'particles', got {closure!r}")
    real_modes = real_modes_for(real_system, system, actions)
    gains = gains_for(system, actions, lqr_gains, default_lqr)
    m0 = plan.get_mean(0)
    x0 = m0 if real_initial_state is None else as_vector(real_initial_state, "real_initial_state", n)
    if initial_belief is None:
        b0, P0 = m0, plan.get_cov(0)
    else:
        if not isinstance(initial_belief, GaussianBelief) or initial_belief.n != n:
            raise DimensionError(f"initial_belief must be a GaussianBelief of dimension {n}")
        b0, P0 = initial_belief.mean, initial_belief.cov
    S0 = np.zeros((2 * n, 2 * n))
    if real_initial_cov is not None:
        S0[:n, :n] = as_covariance(real_initial_cov, "real_initial_cov", n)
    z0 = np.concatenate([x0 - m0, b0 - m0])

    loop = propagate(
        system, plan, N, real_modes, gains, process_noise, z0, S0, P0.copy(), sensor_noise, domain,
        filter_sensitivity, closure, particles,
    )  # fmt: skip
    L = N + 1
    plan_means = plan.get_mean()[:L]
    if domain is not None and box_bounds(domain, m) is None and N and loop.clip.max() > 0.01:
        logger.warning(
            "predict_closed_loop: the corrected input leaves the (non-box) control domain with "
            "probability up to %.3g (step %d); its projection is not modelled",
            float(loop.clip.max()),
            int(np.argmax(loop.clip)),
        )
    base: dict[str, Any] = {
        "num_of_steps": N,
        "sensor_noise": sensor_noise,
        "plan_means": plan_means.copy(),
        "filter_cov": loop.P,
        "augmented_mean": loop.mean,
        "augmented_cov": loop.cov,
        "transitions": loop.F,
        "offsets": loop.g,
        "noise_covs": loop.Q,
        "tracking_gains": loop.K,
        "kalman_gains": tuple(loop.L),
        "clip_probability": loop.clip,
        "closure": loop.closure,
    }
    if formula is None:
        return ClosedLoopPrediction(**base)

    aps = [ap for ap in formula.atomic_propositions() if not ap.is_false and not ap.is_true]
    names = [ap.name or f"ap{i}" for i, ap in enumerate(aps)]
    faces = _faces(aps, loop, plan_means, n)
    mode_ok = _mode_ok(aps, actions, L)
    # The plan's promise per proposition (validate's mask), also its truth for the plan witness.
    plan_truth = np.zeros((len(aps), L), dtype=bool)
    for i, ap in enumerate(aps):
        margins = atom_margins(ap, plan.get_mean(), plan.get_cov(), plan.get_action())
        upto = min(L, margins.shape[0])
        plan_truth[i, :upto] = margins[:upto] >= 0.0

    p_state = prob_le(faces.mu["state"], faces.sd["state"])  # (L, F)
    p_belief = prob_le(faces.mu["belief"], faces.sd["belief"])
    nF = faces.H.shape[0]
    viol = {"state": np.full(nF, np.nan), "belief": np.full(nF, np.nan)}
    prop_violation = {nm: {"belief": float("nan"), "state": float("nan")} for nm in names}
    estimate = {"state": float("nan"), "belief": float("nan")}
    if samples:
        viol, prop_rates, estimate, per_step = _sample_rates(
            loop, faces, samples, seed, formula, aps, mode_ok, plan_truth
        )
        if loop.closure == "particles":  # the non-Gaussian loop's own per-step probabilities
            p_state, p_belief = per_step["state"], per_step["belief"]
        prop_violation = {
            nm: {r: float(prop_rates[r][i]) for r in ("belief", "state")} for i, nm in enumerate(names)
        }

    constraints = []
    j = 0
    for i, ap in enumerate(aps):
        for pred in ap.predicates:
            constraints.append(
                ConstraintPrediction(
                    name=f"{names[i]}: {pred}",
                    proposition=names[i],
                    h=faces.H[j].copy(),
                    c=float(faces.c[j]),
                    eps=float(pred.eps),
                    belief_probability=p_belief[:, j].copy(),
                    state_probability=p_state[:, j].copy(),
                    promised=plan_truth[i].copy(),
                    belief_violation=float(viol["belief"][j]),
                    state_violation=float(viol["state"][j]),
                )
            )
            j += 1
    state_bound, witness = _success_bound(formula, aps, faces, mode_ok, plan_truth, "state", loop)
    belief_bound, _ = _success_bound(formula, aps, faces, mode_ok, plan_truth, "belief", loop)
    logger.debug(
        "predict_closed_loop: %d steps, success bound state %.4g belief %.4g, "
        "estimate state %.4g belief %.4g",
        N,
        state_bound,
        belief_bound,
        estimate["state"],
        estimate["belief"],
    )
    sampled_bound = {r: _clopper_pearson_lower(estimate[r], samples) for r in ("belief", "state")}
    if loop.closure == "particles" and samples:
        belief_bound = min(belief_bound, sampled_bound["belief"])
        state_bound = min(state_bound, sampled_bound["state"])
    return ClosedLoopPrediction(
        **base,
        constraints=tuple(constraints),
        propositions=tuple(names),
        proposition_violation=prop_violation,
        belief_success_bound=float(belief_bound),
        state_success_bound=float(state_bound),
        belief_success_estimate=estimate["belief"],
        state_success_estimate=estimate["state"],
        belief_success_sampled_bound=sampled_bound["belief"],
        state_success_sampled_bound=sampled_bound["state"],
        samples=samples,
        witness=tuple((names[i], int(k)) for i, k in witness),
    )
