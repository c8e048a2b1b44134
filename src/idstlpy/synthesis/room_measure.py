"""Execution room: how far inside what it must satisfy a plan stays, so that its execution holds.

A plan made on the maximum-likelihood-observation (MLO) belief is executed by
:func:`idstlpy.simulate`: an LQR tracks it, a Kalman filter estimates the state. Around the plan
that loop is linear-Gaussian (:mod:`idstlpy.closed_loop`): the executed belief's mean deviates
from the planned one by ``eta_k`` and the true state by ``delta_k``, zero-mean with covariances
``S_eta[k]`` and ``S_x[k]`` that :func:`idstlpy.closed_loop.propagate` predicts (the planner's
reading: the true start is drawn from the prior, the model's process noise, the default tracking
gains, the corrected input clipped to the control domain).

For a required chance constraint ``P[h'x + c <= 0] >= 1 - eps`` (the plan meets
``h'm_k + c + z_eps sd_P <= 0``, ``sd_P = sqrt(h' P_k h)``) at step ``k``:

- the **executed belief** meets it when ``h'(m_k + eta_k) + c + z_eps sd_P <= 0``; keeping
  ``b_belief = z_b sqrt(h' S_eta[k] h)`` of room makes that hold with probability ``Phi(z_b)``;
- the **true state** meets its deterministic reading ``h'x_k + c <= 0`` with probability
  ``Phi(z_s)`` when ``h'm_k + c + z_s sqrt(h' S_x[k] h) <= 0``, i.e. with
  ``b_state = z_s sd_x - z_eps sd_P`` of room beyond the plan's own.

The room of the face is ``b = max(b_belief, b_state, floor)`` (units of ``h'x``), with
``floor`` = :data:`ROOM_FLOOR` times the Chebyshev radius of the smallest bounded required region
(what the linear-Gaussian model leaves out does not vanish where the predicted spread does).

Choosing ``z``. The formula fails when any required face breaks at any required step, so ``z``
comes from a union bound over the face-steps, ``z = Phi^-1(1 - alpha / n)`` with ``alpha`` half
of issue 11's failure rate (:data:`BELIEF_FAILURE`, :data:`STATE_FAILURE`; the other half for
what the model leaves out). A plain Bonferroni count ``n`` of every face-step (a 40-step hold:
160) asks ``z ~ 3.4`` and empties the tight regions, while the deviations are strongly
correlated in time. ``n`` is therefore a Hunter-type count: only face-steps with less than five
standard deviations of room count, and a face-step chained to the same face at the previous
step adds only the probability of a *new* crossing, about ``min(1, 1.7 sqrt(1 - rho))`` (``rho``
the correlation of the two steps' deviations along the face, from the loop's transitions: near
1 in a slow hold, near 0 where fresh measurement noise dominates, e.g. at the light). ``z`` is
clipped to ``[Z_MIN, Z_MAX]``.

Inputs. Per step and face of the control domain the plan also keeps ``z_u`` standard
deviations of the tracking correction ``K_k eta_k`` free (as
:func:`idstlpy.closed_loop.tracking_backoff`): an input riding a bound leaves the correction no
room, the executor clips it and the deviations grow (and the linear-Gaussian prediction then
under-states them: sensor switching's fast approaches broke the target 7% of the time where the
model said 0%). The input room is kept at the first feasible level of
:data:`.room.INPUT_LEVELS`.

:func:`execution_room` measures, per required face, the room a plan has and the room it needs
(a :class:`Room`); :mod:`.room` gives a plan that room (its LP, :func:`.room.room_lp`, and the
repair loop, :func:`.room.give_room`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import ndtr, ndtri

from ..chance import std_terms
from ..closed_loop import TRACKABLE_Z, correction_spread, gains_for, propagate, tracking_backoff
from ..errors import InvalidArgumentError
from ..trajectory import ProbabilisticTSTrajectory
from .abstraction import Abstraction
from .plan import DiscretePlan
from .plan_lp import plan_requirements

if TYPE_CHECKING:
    from ..closed_loop import ClosedLoopMoments
    from ..dynamical_system import SwitchedSystem
    from ..sets import Polytope

__all__ = [
    "BELIEF_FAILURE",
    "INPUT_ENOUGH",
    "INPUT_Z",
    "ROOM_FLOOR",
    "STATE_FAILURE",
    "Z_MAX",
    "Z_MIN",
    "Room",
    "execution_room",
    "mlo_means",
    "plan_have",
]

logger = logging.getLogger(__name__)

BELIEF_FAILURE = 0.05
"""Probability of a broken requirement the executed belief's room is sized for (half of issue
11's 10%: the loop is linearised and the true start is not the prior's mean)."""
STATE_FAILURE = 0.025
"""The same for the true state's deterministic reading (half of issue 11's 5%)."""
ROOM_FLOOR = 0.25
"""Least room on every required face, as a fraction of the Chebyshev radius of the smallest
bounded required region: what the linear-Gaussian prediction leaves out (the linearised sensor
and clipping, a true start off the prior's mean) does not vanish where the predicted spread does
(a plan at the light, where the sensor is nearly perfect, would otherwise graze the wall)."""
Z_MIN, Z_MAX = 1.6448536269514722, 4.0
"""Bounds on the standard deviations kept (``Phi^-1(0.95)`` and 4)."""

INPUT_Z = TRACKABLE_Z
"""Standard deviations of the tracking correction kept free on every face of the control domain
(what :func:`idstlpy.closed_loop.trackable` asks)."""

INPUT_ENOUGH = 0.5
"""Fraction of the tracking correction's room at which a plan whose required faces keep all
theirs is not polished further."""

_CAP = 10.0
"""Room ratios above this count as this (a face far from its bound)."""


@dataclass(frozen=True)
class Room:
    """The room a plan keeps and the room its execution needs, per required face and input face.

    Attributes
    ----------
    requirements : list of (step, atom)
        The plan's requirements that read the mean (as the plan LP's rows).
    need : list of ndarray
        Per requirement, shape (F_i,): the room (units of ``h'x + c``) its faces need.
    have : list of ndarray
        Per requirement, shape (F_i,): the room they keep, ``-(h'm_k + c + z_eps sd_P)``.
    input_need : ndarray, shape (N, F_u)
        Per step and control face, the room the tracking correction needs (domain units).
    input_have : ndarray, shape (N, F_u)
        The room the plan's inputs leave, ``-(H u_k + c)``.
    clip : ndarray, shape (N,)
        Predicted probability (upper bound) that the corrected input is clipped.
    z_belief, z_state : float
        Standard deviations of the predicted deviation kept per face and step (module notes).
    terms, sd_belief, sd_state, weight_belief, weight_state : list of ndarray
        Per requirement, shape (F_i,): the plan's own term ``z_eps sd_P``, the predicted spread
        of the executed belief's mean and of the true state along the face, and the face-step's
        weight in the Hunter-type count (:func:`_weights`; before the "near" test): what
        :meth:`failure` reads.
    """

    requirements: list[tuple[int, int]]
    need: list[np.ndarray]
    have: list[np.ndarray]
    input_need: np.ndarray
    input_have: np.ndarray
    clip: np.ndarray
    z_belief: float = 0.0
    z_state: float = 0.0
    terms: list[np.ndarray] = field(default_factory=list)
    sd_belief: list[np.ndarray] = field(default_factory=list)
    sd_state: list[np.ndarray] = field(default_factory=list)
    weight_belief: list[np.ndarray] = field(default_factory=list)
    weight_state: list[np.ndarray] = field(default_factory=list)

    def failure(self, have: list[np.ndarray]) -> tuple[float, float]:
        """Predicted probabilities that an execution breaks a required face, per reading.

        The linear-Gaussian loop's marginal crossing probabilities of the required faces,
        summed with the Hunter-type weights of :func:`_weights` (a union bound over face-steps
        that counts a chained face-step's new crossings only), for a plan that keeps ``have``
        (per requirement, shape (F_i,); e.g. :attr:`have`, or another plan's with the same
        modes: without state-dependent noise the spreads do not depend on the means).

        Returns
        -------
        (belief, state) : tuple of float
            Upper estimates (not bounds: the loop is linearised) of the failure probability of
            the executed belief and of the true state's deterministic reading, each at most 1.
        """
        if not self.sd_belief:
            return 0.0, 0.0
        h = np.concatenate(have)
        readings = (
            (h, self.sd_belief, self.weight_belief),
            (h + np.concatenate(self.terms), self.sd_state, self.weight_state),
        )
        out = []
        for margin, sds, weights in readings:
            sd, w = np.concatenate(sds), np.concatenate(weights)
            with np.errstate(divide="ignore", invalid="ignore"):
                p = np.where(sd > 0, ndtr(-margin / np.where(sd > 0, sd, 1.0)), (margin < 0).astype(float))
            out.append(float(min(1.0, np.sum(w * p))))
        return out[0], out[1]

    @cached_property
    def _ratios(self) -> np.ndarray:
        # computed once: score, coverage and complete read it several times per polish round
        if not any(need.size for need in self.need):
            return np.full(1, _CAP)
        return _ratio(np.concatenate(self.have), np.concatenate(self.need))

    @property
    def score(self) -> float:
        """The smallest fraction of the needed room a required face keeps (capped at ``_CAP``).

        ``>= 1``: every required face keeps its room; ``< 0``: some requirement is broken.
        """
        return float(np.min(self._ratios))

    @property
    def coverage(self) -> float:
        """The mean over the required faces of the fraction of their room they keep (at most 1)."""
        return float(np.mean(np.clip(self._ratios, -1.0, 1.0)))

    @property
    def input_score(self) -> float:
        """The smallest fraction of the tracking correction's room an input keeps."""
        if not self.input_need.size:
            return _CAP
        return float(np.min(_ratio(self.input_have, self.input_need)))

    def better_than(self, other: Room) -> bool:
        """Whether this room improves on ``other``: lexicographically the smallest fraction (up to
        1), the mean fraction, the inputs' smallest fraction (up to 1)."""
        key = (min(self.score, 1.0), self.coverage, min(self.input_score, 1.0))
        ref = (min(other.score, 1.0), other.coverage, min(other.input_score, 1.0))
        tol = (1e-6, 1e-4, 1e-6)
        for a, b, t in zip(key, ref, tol, strict=True):
            if a > b + t:
                return True
            if a < b - t:
                return False
        return False

    @property
    def complete(self) -> bool:
        """Every required face keeps all the room it needs, every input at least
        :data:`INPUT_ENOUGH` of it (chasing the rest costs rounds and rarely pays)."""
        return self.score >= 1.0 and self.input_score >= INPUT_ENOUGH

    @property
    def largest_need(self) -> float:
        """The largest room any required face needs (state units of ``h'x``)."""
        return max([float(np.max(b)) for b in self.need if b.size] + [0.0])


def _ratio(have: np.ndarray, need: np.ndarray) -> np.ndarray:
    tiny = 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(need > tiny, have / np.maximum(need, tiny), np.where(have >= -tiny, _CAP, -_CAP))
    return np.minimum(r, _CAP)


def _loop(
    system: SwitchedSystem, traj: ProbabilisticTSTrajectory, control_domain: Polytope
) -> ClosedLoopMoments | None:
    """The planner's closed loop around ``traj`` (module notes), or None when it diverges."""
    n, N = system.n, traj.num_of_steps
    actions = np.asarray(traj.get_action(), dtype=int)[:N]
    P0 = traj.get_cov(0)
    S0 = np.zeros((2 * n, 2 * n))
    S0[:n, :n] = P0
    try:
        return propagate(
            system,
            traj,
            N,
            list(system.system_modes),
            gains_for(system, actions, None, None, traj),
            "model",
            np.zeros(2 * n),
            S0,
            P0.copy(),
            # the filter's noise at the plan's means: 5-10x cheaper than the expectation over
            # the predicted true state, and the same to first order
            "plan",
            control_domain,
            False,
        )
    except InvalidArgumentError as exc:  # a diverging loop: no room can be computed
        logger.debug("execution room: %s", exc)
        return None


def _quantile(alpha: float, count: float) -> float:
    """``Phi^-1(1 - alpha / count)``, clipped to ``[Z_MIN, Z_MAX]``."""
    z = float(ndtri(1.0 - alpha / max(count, 1.0)))
    return min(max(z, Z_MIN), Z_MAX)


def _trials(have: np.ndarray, sd: np.ndarray, weights: np.ndarray, reach: float = 5.0) -> float:
    """Effective number of independent chances to break the faces (a Hunter-type union bound).

    Only face-steps with less than ``reach`` standard deviations of room count, each with its
    ``weights`` (:func:`_weights`): a face-step chained to the same face at the previous step
    (correlation ``rho``) adds the probability of a new crossing, ``P[X_k fails, X_{k-1} does
    not] ~ P[X_k fails] z sqrt((1 - rho) / pi)`` at a threshold ``z ~ 3``: ``min(1, 1.7
    sqrt(1 - rho))``; an unchained one adds 1.
    """
    near = have < reach * sd
    return float(np.sum(np.where(near, weights, 0.0)))


def _weights(rho: np.ndarray, chained: np.ndarray) -> np.ndarray:
    """Per face-step, its weight in the Hunter-type count (:func:`_trials`): ``min(1, 1.7
    sqrt(1 - rho))`` when chained to the same face at the previous step, else 1."""
    return np.where(chained, np.minimum(1.0, 1.7 * np.sqrt(np.maximum(1.0 - rho, 0.0))), 1.0)


def plan_have(abstraction: Abstraction, room: Room, means: np.ndarray) -> list[np.ndarray]:
    """The room a plan with ``means`` (shape (>= L, n), its MLO roll-out's) keeps on ``room``'s
    required faces (as :attr:`Room.have`), with the plan's own terms of ``room`` (the same
    modes: the covariances are those of ``room``'s plan without state-dependent noise)."""
    out = []
    for (k, i), terms in zip(room.requirements, room.terms, strict=True):
        cone = abstraction.atoms[i].cone
        out.append(-(cone.H @ means[k] + cone.c + terms))
    return out


def mlo_means(
    system: SwitchedSystem, mean0: np.ndarray, actions: np.ndarray, controls: np.ndarray
) -> np.ndarray:
    """The means of the MLO roll-out (:func:`~idstlpy.belief.rollout_arrays`'s, to the bit)
    without its covariances: what :func:`plan_have` reads of a plan whose modes keep another
    plan's covariances (half a roll-out's cost: the covariances are its Kalman updates)."""
    N = actions.shape[0]
    modes = system.system_modes
    means = np.empty((N + 1, mean0.shape[0]))
    means[0] = mean0
    for k in range(N):
        mode = modes[int(actions[k])]
        means[k + 1] = mode.A @ means[k] + mode.B @ controls[k]
    return means


def _face_sd(H: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``sqrt(h_f' S h_f)`` per face ``h_f`` (rows of ``H``, shape (F, n)); ``S`` (n, n)."""
    sd: np.ndarray = np.sqrt(np.maximum(np.einsum("fa,ab,fb->f", H, S, H), 0.0))
    return sd


def execution_room(
    system: SwitchedSystem,
    control_domain: Polytope,
    abstraction: Abstraction,
    plan: DiscretePlan,
    traj: ProbabilisticTSTrajectory,
    belief_failure: float = BELIEF_FAILURE,
    state_failure: float = STATE_FAILURE,
    z_input: float = INPUT_Z,
) -> Room | None:
    """The room ``traj`` keeps for ``plan``'s requirements and the room its execution needs.

    Parameters
    ----------
    system : SwitchedSystem
    control_domain : Polytope
    abstraction : Abstraction
    plan : DiscretePlan
        The requirements (a witness the trajectory meets), ``L`` steps.
    traj : ProbabilisticTSTrajectory
        The plan's MLO roll-out (at least ``L - 1`` steps; the closed loop is predicted over all).
    belief_failure, state_failure : float
        Failure probabilities the room is sized for (module notes).
    z_input : float
        Standard deviations of the tracking correction kept on the control faces.

    Returns
    -------
    Room or None
        None when the predicted closed loop diverges.
    """
    loop = _loop(system, traj, control_domain)
    if loop is None:
        return None
    reqs = plan_requirements(plan, abstraction)
    parts = _face_parts(system.n, loop, traj, abstraction, reqs)
    radii = [abstraction.radius(i) for i in {i for _, i in reqs}]
    finite = [r for r in radii if np.isfinite(r)]
    floor = ROOM_FLOOR * min(finite) if finite else 0.0
    # every face-step's numbers at once (element-wise: the same as per requirement), then split
    cat = [np.concatenate([p[j] for p in parts]) if parts else np.zeros(0) for j in range(7)]
    have_all, terms_all, sdx_all, sde_all, rx_all, re_all, ch_all = cat
    w_b, w_s = _weights(re_all, ch_all), _weights(rx_all, ch_all)
    if parts:
        z_b = _quantile(belief_failure, _trials(have_all, sde_all, w_b))
        z_s = _quantile(state_failure, _trials(have_all + terms_all, sdx_all, w_s))
    else:
        z_b = z_s = Z_MIN
    need_all = np.maximum(np.maximum(z_b * sde_all, z_s * sdx_all - terms_all), floor)
    ends = [int(e) for e in np.cumsum([p[0].shape[0] for p in parts])]
    bounds = list(zip([0, *ends[:-1]], ends, strict=False))  # none without requirements

    def split(a: np.ndarray) -> list[np.ndarray]:
        return [a[lo:hi] for lo, hi in bounds]

    input_need, input_have = _input_room(system, traj, control_domain, loop, z_input)
    return Room(
        reqs, split(need_all), [p[0] for p in parts], input_need, input_have, loop.clip, z_b, z_s,
        terms=[p[1] for p in parts],
        sd_belief=[p[3] for p in parts],
        sd_state=[p[2] for p in parts],
        weight_belief=split(w_b),
        weight_state=split(w_s),
    )  # fmt: skip


def _face_parts(
    n: int,
    loop: ClosedLoopMoments,
    traj: ProbabilisticTSTrajectory,
    abstraction: Abstraction,
    reqs: list[tuple[int, int]],
) -> list[tuple[np.ndarray, ...]]:
    """Per requirement ``(k, i)``, per face: the room kept, the plan's own back-off term, the
    true state's and the belief's predicted spread along the face, their correlations with the
    previous step's and whether the face is chained to it (the same face required at ``k - 1``)."""
    S = loop.cov
    means, covs = traj.get_mean(), traj.get_cov()
    required = set(reqs)
    # a chained face-step reads its previous step's spreads, the previous requirement's own
    spreads: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def spread(k: int, i: int, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if (k, i) not in spreads:
            spreads[k, i] = (_face_sd(H, S[k, :n, :n]), _face_sd(H, S[k, n : 2 * n, n : 2 * n]))
        return spreads[k, i]

    # per atom, its faces and whether every quantile is finite (std_terms' infinite-quantile
    # cases then cannot arise: its terms are z * sd, computed here in the same operations)
    faces: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, bool]] = {}
    cross: dict[int, np.ndarray] = {}  # per step k, Cov(z_k, z_{k-1}) (several atoms read it)
    parts: list[tuple[np.ndarray, ...]] = []
    with np.errstate(divide="ignore", invalid="ignore"):
        for k, i in reqs:
            if i not in faces:
                cone = abstraction.atoms[i].cone
                faces[i] = (cone.H, cone.c, cone.z, bool(np.all(np.isfinite(cone.z))))
            H, c, z, finite_z = faces[i]
            if finite_z:
                terms = z * np.sqrt(np.maximum(np.einsum("fi,ij,fj->f", H, covs[k], H), 0.0))
            else:
                terms = std_terms(H, z, covs[k])
            terms = np.where(np.isfinite(terms), terms, 0.0)
            sd_x, sd_eta = spread(k, i, H)
            chained = np.full(H.shape[0], (k - 1, i) in required and k >= 1)
            rho_x = np.zeros(H.shape[0])
            rho_eta = np.zeros(H.shape[0])
            if chained[0]:
                if k not in cross:
                    cross[k] = loop.F[k - 1][: 2 * n, : 2 * n] @ S[k - 1, : 2 * n, : 2 * n]
                C = cross[k]
                prev_x, prev_eta = spread(k - 1, i, H)
                rho_x = np.einsum("fa,ab,fb->f", H, C[:n, :n], H) / (sd_x * prev_x)
                rho_eta = np.einsum("fa,ab,fb->f", H, C[n : 2 * n, n : 2 * n], H) / (sd_eta * prev_eta)
                rho_x = np.where(np.isfinite(rho_x), rho_x, 1.0)
                rho_eta = np.where(np.isfinite(rho_eta), rho_eta, 1.0)
            have = -(H @ means[k] + c + terms)
            parts.append((have, terms, sd_x, sd_eta, rho_x, rho_eta, chained))
    return parts


def _input_room(
    system: SwitchedSystem,
    traj: ProbabilisticTSTrajectory,
    control_domain: Polytope,
    loop: ClosedLoopMoments,
    z_input: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Per step and control face: the room the tracking correction needs and the room the
    plan's inputs leave (both (N, F_u))."""
    N = traj.num_of_steps
    Hu, cu = control_domain.H, control_domain.c
    if Hu.shape[0] and N:
        spread = correction_spread(loop, Hu)
        input_need = tracking_backoff(system, traj, control_domain, z_input, spread)
        input_have = -(traj.get_control()[:N] @ Hu.T + cu[None, :])
        return input_need, input_have
    return np.zeros((N, Hu.shape[0])), np.zeros((N, Hu.shape[0]))
