"""A cheap first stage of a re-planning check: the plan's own prediction, conditioned on the run.

A scheduled check (:class:`~idstlpy.ReplanPolicy`, ``trigger="on_risk"``) predicts the rest of
the plan from the run's current belief: a closed-loop prediction of the remaining steps (0.1 s
on the light-dark plan), at every step of every run with the default ``check_every=1``. Most of
that work depends on the plan, not on the run. The prediction of the *whole* plan from its first
belief (the same for every run of ``validate``) is a joint Gaussian over the loop's state
``z_t = (delta_t, eta_t[, dP_t])`` at every step (:func:`~idstlpy.execution.prediction.
predict_closed_loop`, Gaussian closure); what a run knows at step ``k`` is its filter's belief:
``eta_k`` (its mean's deviation from the plan) and, with a state-dependent sensor, ``dP_k`` (its
covariance's). Conditioning that Gaussian on the run's ``(eta_k, dP_k)`` gives the distribution
of every later constraint's left-hand side: its mean is affine in the run's belief and its
spread does not depend on it. So, once per plan and step (shared by every run), the gains of
that affine map and the conditional spreads are computed; per check, the run's belief is pushed
through them in ``O(E d)`` for ``E`` later events of the plan's witness and ``d = n (+ n^2)``.

The value (:meth:`CheckReference.vouch`) is a sound lower bound on the probability that the rest
of the plan satisfies the progressed formula, *in that linear-Gaussian model*: the witness
``W`` of the original formula (the one the prediction's own bound used, per reading) is checked
on the executed belief at the steps ``<= k`` (progression decides those steps from the prefix);
if every such event held, the formula holds whenever every later event of ``W`` holds, and one
minus Hunter's tree bound on their conditional failures (each face's events chained in time;
the conditional correlations are run-independent too) bounds that from below. A check passes on
it (no full prediction) only when it reaches the risk; otherwise the full prediction decides,
as before.

How it relates to the full check
--------------------------------
With constant sensor noise and no clipping the loop is exactly linear-Gaussian and the Kalman
belief is a sufficient statistic: the conditional above *is* the full check's model, and both
are sound lower bounds of the same probability (they may differ by their witnesses: the full
check takes the best of those it finds for the progressed formula). With a state-dependent
sensor or a clipped input the full check re-linearises around the run's own predicted path, the
vouch keeps the plan's linearisation (conditioned on the run's belief and, with
``filter_sensitivity``, its filter covariance's first-order deviation); the two are different
approximations of the same model, and only a vouch at or above the risk skips the full
prediction. Not vouched (the full check runs): a plan other than the one the run started with
(an adopted re-plan solves a progressed formula), a control domain that is not a box (the
Gaussian moments leave its projection out), a past witness event that failed on the executed
belief, executed modes that left the plan's.
"""

from __future__ import annotations

import hashlib
import logging
import math
import pickle
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..belief import GaussianBelief
from ..closed_loop import ClosedLoopMoments, prob_le
from ..executor import ExecutorSpec
from ..executor.success_bound import (
    _standardised,
    bivariate_normal_cdf,
    mode_truth,
    stack_faces,
    success_bound,
)
from ..formulas import FALSE, TRUE, STLAtomicProposition, STLFormula
from ..semantics import atom_margins
from ..trajectory import ProbabilisticTSTrajectory
from .policy import ReplanPolicy

__all__ = ["CheckReference", "check_reference", "vouched_runs"]

logger = logging.getLogger(__name__)

_READINGS = ("belief", "state")
_SLACK = 1e-9
"""Subtracted from every bivariate probability (numerical safety, as the full bound's)."""
_RCOND = 1e-10
"""Relative cut-off of the pseudo-inverse of the observed coordinates' covariance (at step 0
``eta`` is deterministic: its covariance is 0 and the conditional is the plain prediction)."""


@dataclass(frozen=True)
class _StepGains:
    """One reading's conditional at plan step ``j``: the witness events at steps ``> j``.

    ``mu`` (E,) their unconditional means, ``gain`` (E, d) the map from the observed deviation
    ``o - m_o`` to the shift of their means, ``sd`` (E,) their conditional spreads; ``first``,
    ``second`` (P,) the pairs of Hunter's tree (each face's events chained in time) and ``rho``
    (P,) their conditional correlations (like the spreads, independent of the run)."""

    mu: np.ndarray
    gain: np.ndarray
    sd: np.ndarray
    first: np.ndarray
    second: np.ndarray
    rho: np.ndarray

    def failure(self, dev: np.ndarray, enough: float = 0.0) -> np.ndarray:
        """Hunter's bound on the probability that some event fails, given the observed
        deviation ``dev`` (d,) or (S, d); shape () or (S,). Where Boole's sum is already at
        most ``enough`` it is returned instead (the pairs' bivariate probabilities cost most)."""
        mu = self.mu + dev @ self.gain.T
        p = 1.0 - prob_le(mu, self.sd)
        total = np.asarray(p.sum(axis=-1), dtype=float)
        if self.first.size:
            need = total > enough
            if np.any(need):
                rows = (mu[need], p[need]) if mu.ndim == 2 else (mu, p)
                t = _standardised(rows[0], self.sd)
                i, j = self.first, self.second
                both = bivariate_normal_cdf(t[..., i], t[..., j], self.rho)
                q = rows[1]
                both = np.maximum(0.0, np.minimum(both - _SLACK, np.minimum(q[..., i], q[..., j])))
                if mu.ndim == 2:
                    total[need] -= both.sum(axis=-1)
                else:
                    total = total - both.sum(axis=-1)
        return np.asarray(np.clip(total, 0.0, 1.0))


@dataclass(frozen=True)
class CheckReference:
    """The prediction of a whole plan from its first belief, prepared for conditional checks.

    Attributes
    ----------
    plan : ProbabilisticTSTrajectory
        The plan (``N`` steps).
    n : int
        State dimension.
    sensitivity : bool
        Whether the filter covariance's deviation ``dP`` (``n^2`` coordinates) is observed too.
    observed_mean : ndarray, shape (L, d)
        The predicted mean of the observed coordinates ``(eta, dP)`` at every step.
    nominal_cov : ndarray, shape (L, n, n)
        The filter covariance the prediction is linearised at (``dP = P - nominal_cov``).
    gains : dict
        Per reading, per plan step ``j`` (1 .. N - 1), the :class:`_StepGains`.
    past : dict
        Per reading, the witness events ``(atom index, step)`` (sorted by step).
    aps : list of STLAtomicProposition
        The formula's propositions, in the prediction's order.
    """

    plan: ProbabilisticTSTrajectory
    n: int
    sensitivity: bool
    observed_mean: np.ndarray
    nominal_cov: np.ndarray
    gains: dict[str, list[_StepGains | None]]
    past: dict[str, list[tuple[int, int]]]
    aps: list[STLAtomicProposition]

    def vouch(
        self, executed: ProbabilisticTSTrajectory, belief: GaussianBelief, on: str, risk: float = 1.0
    ) -> float:
        """A lower bound on the rest of the plan's success from execution step ``k`` (module
        notes), or NaN when it cannot be given.

        Parameters
        ----------
        executed : ProbabilisticTSTrajectory
            The executed belief ``X_0 .. X_k`` (``k`` modes), ``k`` the plan's step.
        belief : GaussianBelief
            The current belief ``X_k`` (mean (n,), covariance (n, n)).
        on : {"belief", "state", "both"}
            Whose success (the policy's ``risk_on``).
        risk : float
            The value that is enough: where Boole's sum already reaches it, that sum (a lower
            bound of Hunter's) is returned instead (1: Hunter's bound always).

        Returns
        -------
        float
        """
        k = executed.num_of_steps
        N = self.plan.num_of_steps
        if not 1 <= k < N or not np.array_equal(executed.get_action(), self.plan.get_action()[:k]):
            return math.nan
        eta = belief.mean - self.plan.get_mean(k)
        if self.sensitivity:
            dP = (belief.cov - self.nominal_cov[k]).reshape(-1)
            o = np.concatenate([eta, dP])
        else:
            o = eta
        dev = o - self.observed_mean[k]
        readings = _READINGS if on == "both" else (on,)
        margins: dict[int, np.ndarray] = {}
        value = 1.0
        for r in readings:
            for i, t in self.past[r]:
                if t > k:
                    break
                if i not in margins:
                    margins[i] = atom_margins(
                        self.aps[i], executed.get_mean(), executed.get_cov(), executed.get_action()
                    )
                if not margins[i][t] >= 0.0:
                    return math.nan  # the witness broke on the prefix: the full check decides
            g = self.gains[r][k]
            if g is None:
                return math.nan
            value = min(value, 1.0 - float(g.failure(dev, 1.0 - risk)))
        return value


def _conditional_gains(
    loop: ClosedLoopMoments, a: np.ndarray, mu: np.ndarray, events: list[tuple[int, int]], n: int
) -> list[_StepGains | None]:
    """Per plan step ``j``, the conditional of the events ``(face, step)`` at steps ``> j``
    given the observed coordinates ``z_j[n:]`` (``a`` (L, F, D): the faces' functionals; ``mu``
    (L, F): their means).

    ``Cov(a_t' z_t, o_j) = a_t' F_{t-1} ... F_j Cov(z_j)[:, o]``: the rows ``a_t' F_{t-1} ...
    F_j`` of every event are carried backwards from ``j = t`` (one product per step for all the
    events), so the whole table costs ``O(N)`` products instead of ``O(N^2)``."""
    L = loop.mean.shape[0]
    pairs_sorted = sorted(set(events), key=lambda e: (e[1], e[0]))
    out: list[_StepGains | None] = [None] * L
    D = loop.mean.shape[1]
    d = D - n
    if not pairs_sorted:
        z = np.zeros(0)
        for j in range(1, L - 1):
            out[j] = _StepGains(z, np.zeros((0, d)), z, z.astype(int), z.astype(int), z)
        return out
    ef = np.array([f for f, _ in pairs_sorted])
    et = np.array([t for _, t in pairs_sorted])
    A = a[et, ef]  # (E, D)
    var = np.einsum("ei,eij,ej->e", A, loop.cov[et], A)
    mu_e = mu[et, ef]
    # Hunter's chains: each face's events in time order (run-independent cross-covariances)
    order = np.lexsort((et, ef))
    same = ef[order[:-1]] == ef[order[1:]]
    p1, p2 = order[:-1][same], order[1:][same]
    unc = np.empty(p1.size)
    for i, (e1, e2) in enumerate(zip(p1.tolist(), p2.tolist(), strict=True)):
        vec = loop.cov[et[e1]] @ A[e1]
        for s_ in range(int(et[e1]), int(et[e2])):
            vec = loop.F[s_] @ vec
        unc[i] = float(A[e2] @ vec)
    R = A.copy()
    for j in range(L - 2, 0, -1):
        start = int(np.searchsorted(et, j, side="right"))  # the events at steps > j
        R[start:] = R[start:] @ loop.F[j]
        S = loop.cov[j]
        Soo_pinv = np.linalg.pinv(S[n:, n:], rcond=_RCOND, hermitian=True)
        C = R[start:] @ S[:, n:]  # (e, d): Cov(face_t, o_j)
        W = C @ Soo_pinv
        sd = np.sqrt(np.maximum(var[start:] - np.einsum("ed,ed->e", W, C), 0.0))
        live = p1 >= start  # both ends at steps > j (p2 is later than p1)
        i1, i2 = p1[live] - start, p2[live] - start
        denom = sd[i1] * sd[i2]
        keep = denom > 0
        i1, i2, denom = i1[keep], i2[keep], denom[keep]
        cov = unc[live][keep] - np.einsum("pd,pd->p", W[i1], C[i2])
        out[j] = _StepGains(mu_e[start:], W, sd, i1, i2, np.clip(cov / denom, -1.0, 1.0))
    return out


def _build(spec: ExecutorSpec, plan: ProbabilisticTSTrajectory, formula: STLFormula) -> CheckReference | None:
    """The reference of ``plan`` (None where the vouch does not apply: module notes)."""
    from .prediction import predict_closed_loop

    domain = spec.control_domain
    if domain is not None and spec.box is None:
        return None  # the Gaussian moments leave a non-box projection out
    n = spec.system.n
    belief = GaussianBelief(plan.get_mean(0).copy(), plan.get_cov(0).copy())
    pred = predict_closed_loop(
        spec.system,
        plan,
        None,
        belief.mean,
        formula=formula,
        control_domain=domain,
        process_noise="none" if spec.process_noise == "none" else "model",
        lqr_gains={q: list(Ks) for q, Ks in spec.gains.items()},
        initial_belief=belief,
        real_initial_cov=belief.cov,
        samples=0,
        seed=0,
        closure="gaussian",  # the checks' own closure (resolving._RiskModel)
    )
    mean, cov = pred.augmented_mean, pred.augmented_cov
    D = mean.shape[1]
    loop = ClosedLoopMoments(
        mean=mean,
        cov=cov,
        F=pred.transitions,
        g=pred.offsets,
        Q=pred.noise_covs,
        P=pred.filter_cov,
        K=pred.tracking_gains,
        L=list(pred.kalman_gains),
        clip=pred.clip_probability,
        sensitivity=D > 2 * n,
    )
    aps = [ap for ap in formula.atomic_propositions() if not ap.is_false and not ap.is_true]
    L = mean.shape[0]
    faces = stack_faces(aps, loop, plan.get_mean(), n)
    actions = plan.get_action()
    mode_ok = mode_truth(aps, actions, L)
    plan_truth = np.zeros((len(aps), L), dtype=bool)
    for i, ap in enumerate(aps):
        margins = atom_margins(ap, plan.get_mean(), plan.get_cov(), actions)
        plan_truth[i, : min(L, margins.shape[0])] = margins[:L] >= 0.0
    gains: dict[str, list[_StepGains | None]] = {}
    past: dict[str, list[tuple[int, int]]] = {}
    for r in _READINGS:
        bound, witness = success_bound(formula, aps, faces, mode_ok, plan_truth, r, loop)
        if not witness and bound < 1.0:
            return None  # no witness: nothing to condition
        events = [(int(f), t) for i, t in witness for f in np.flatnonzero(faces.atom == i)]
        gains[r] = _conditional_gains(loop, faces.a[r], faces.mu[r], events, n)
        past[r] = sorted(witness, key=lambda e: e[1])
    observed_mean = mean[:, n:].copy()  # (eta, dP)'s predicted means
    return CheckReference(plan, n, loop.sensitivity, observed_mean, pred.filter_cov, gains, past, aps)


_Key = tuple[int, int, int]
_BY_ID: OrderedDict[_Key, tuple[object, object, object, CheckReference | None]] = OrderedDict()
_BY_CONTENT: OrderedDict[bytes, CheckReference | None] = OrderedDict()
_CACHE_SIZE = 16
_LOCK = threading.Lock()


def _fingerprint(spec: ExecutorSpec, plan: ProbabilisticTSTrajectory, formula: STLFormula) -> bytes | None:
    """A digest of what a reference depends on (``validate`` makes its spec, and a process pool
    unpickles its plan, once per batch of runs: equal contents, other objects); None when some
    part does not pickle."""
    try:
        parts = pickle.dumps(
            (spec.system, spec.control_domain, spec.process_noise, dict(spec.gains), formula),
            protocol=pickle.HIGHEST_PROTOCOL,
        )
    except Exception:  # a user's noise function need not pickle: then the objects' identities key it
        return None
    digest = hashlib.sha256(parts)
    for arr in (plan.get_mean(), plan.get_cov(), plan.get_action(), plan.get_control()):
        digest.update(np.ascontiguousarray(arr).tobytes())
    return digest.digest()


def _remember(cache: OrderedDict, key: object, value: object) -> None:  # type: ignore[type-arg]
    cache[key] = value
    cache.move_to_end(key)
    while len(cache) > _CACHE_SIZE:
        cache.popitem(last=False)


def check_reference(
    spec: ExecutorSpec, plan: ProbabilisticTSTrajectory, formula: STLFormula
) -> CheckReference | None:
    """The (cached) :class:`CheckReference` of ``plan`` under ``spec`` for ``formula``.

    Computed once per process for the same contents (the runs of a ``validate`` share them) and
    kept for the :data:`_CACHE_SIZE` most recent; None where the vouch does not apply.
    """
    if formula is TRUE or formula is FALSE:
        return None
    key = (id(spec), id(plan), id(formula))
    with _LOCK:
        hit = _BY_ID.get(key)
        if hit is not None and hit[0] is spec and hit[1] is plan and hit[2] is formula:
            return hit[3]
    fp = _fingerprint(spec, plan, formula)
    with _LOCK:
        found = fp is not None and fp in _BY_CONTENT
        ref = _BY_CONTENT[fp] if found and fp is not None else None
    if not found:
        ref = _build(spec, plan, formula)
    with _LOCK:
        # the objects are kept with their entry: their ids cannot be reused while it lives
        _remember(_BY_ID, key, (spec, plan, formula, ref))
        if fp is not None:
            _remember(_BY_CONTENT, fp, ref)
    return ref


def vouched_runs(
    ref: CheckReference,
    policy: ReplanPolicy,
    means: np.ndarray,
    covs: np.ndarray,
    actions: np.ndarray,
) -> np.ndarray:
    """Which runs of a batch (executed as the fixed plan) every scheduled check vouches for.

    Such a run is the run ``execute`` makes with ``policy`` (no check decides anything), so
    ``validate`` may take it from the batched execution of the fixed plan (up to rounding).

    Parameters
    ----------
    ref : CheckReference
        The plan's reference (the plan executed from its step 0).
    policy : ReplanPolicy
        ``trigger="on_risk"``, ``risk_measure="bound"``, no ``drift``, no start check.
    means : ndarray, shape (L, S, n)
        The runs' belief means.
    covs : ndarray, shape (L, n, n) or (L, S, n, n)
        Their covariances (shared by the runs, or each run's).
    actions : ndarray of int, shape (L - 1,)
        The plan's modes (every run's).

    Returns
    -------
    ndarray of bool, shape (S,)
    """
    L, S, n = means.shape
    N = ref.plan.num_of_steps
    every = policy.check_every
    if every is None or policy.max_replans == 0 or L - 1 != N:
        return np.ones(S, dtype=bool)  # no scheduled check at all
    readings = _READINGS if policy.risk_on == "both" else (policy.risk_on,)
    # the first step at which some past witness event fails, per run and reading
    first_fail = {r: np.full(S, np.iinfo(np.int64).max) for r in readings}
    for s in range(S):
        run_covs = covs if covs.ndim == 3 else covs[:, s]
        margins: dict[int, np.ndarray] = {}
        for r in readings:
            for i, t in ref.past[r]:
                if i not in margins:
                    margins[i] = atom_margins(ref.aps[i], means[:, s], run_covs, actions)
                if not margins[i][t] >= 0.0:
                    first_fail[r][s] = t
                    break
    ok = np.ones(S, dtype=bool)
    for k in range(every, N, every):
        eta = means[k] - ref.plan.get_mean(k)  # (S, n)
        if ref.sensitivity:
            dP = (covs[k] - ref.nominal_cov[k]).reshape(-1, n * n)
            dP = np.broadcast_to(dP, (S, n * n))
            o = np.concatenate([eta, dP], axis=1)
        else:
            o = eta
        dev = o - ref.observed_mean[k]
        value = np.ones(S)
        for r in readings:
            g = ref.gains[r][k]
            if g is None:
                return np.zeros(S, dtype=bool)
            value = np.minimum(value, 1.0 - g.failure(dev, 1.0 - policy.risk))
            value = np.where(first_fail[r] <= k, math.nan, value)
        ok &= (value >= policy.risk) & (value > 0.0)
    return ok
