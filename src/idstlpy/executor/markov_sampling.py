"""Sampling for the bound under chance switching (:mod:`idstlpy.executor.markov_bound`).

- :func:`sequences_by_probability`: the executed mode sequences, most likely first;
- :class:`SequenceVerifier`: the bound of one executed sequence (:class:`SequenceBound`): the
  exact Gaussian law's analytic bound minus the clip mass (:func:`clip_mass`), or the executor's
  own runs;
- :class:`ExecutorRuns`: executions of the executor itself (:mod:`idstlpy.executor.jump_law`)
  given an executed sequence, or with sequences drawn from the chain conditioned on the ones not
  verified, and their Clopper-Pearson lower bounds.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import ndtr

from .._checks import as_vector
from ..dynamical_system import SwitchedSystem
from ..errors import InvalidArgumentError
from ..formulas import STLFormula
from ..markov import MarkovSwitching
from ..sets import Polytope
from ..trajectory import ProbabilisticTSTrajectory
from .jump_law import roll_executed, success_of
from .model_sampling import clopper_pearson_lower
from .predict import predict_closed_loop
from .predicted import ClosedLoopPrediction
from .spec import ExecutorSpec

__all__ = [
    "CLIP_TOLERANCE",
    "ExecutorRuns",
    "SequenceBound",
    "SequenceVerifier",
    "clip_mass",
    "sequences_by_probability",
]

CLIP_TOLERANCE = 1e-3
"""Clip mass above which a sequence's executions are also sampled (the analytic bound loses it)."""


def sequences_by_probability(
    switching: MarkovSwitching, commanded: ArrayLike
) -> Iterator[tuple[tuple[int, ...], float]]:
    """Every executed sequence of positive probability, most likely first (best-first search).

    A prefix's probability bounds every completion's, so popping the most probable prefix from a
    heap yields the complete sequences in non-increasing probability; ties are broken by the
    sequence (lexicographic), so the order is deterministic.

    Parameters
    ----------
    switching : MarkovSwitching
    commanded : array_like of int, shape (N,)

    Yields
    ------
    (tuple of int, float)
        A sequence ``s`` (N,) and ``P(s)``.
    """
    q = np.asarray(commanded, dtype=int)
    N = q.shape[0]
    if not N:
        yield (), 1.0
        return
    heap: list[tuple[float, tuple[int, ...]]] = []
    for j, p in enumerate(switching.first(int(q[0])).tolist()):
        if p > 0:
            heapq.heappush(heap, (-p, (j,)))
    while heap:
        neg, prefix = heapq.heappop(heap)
        if len(prefix) == N:
            yield prefix, -neg
            continue
        row = switching.row(int(q[len(prefix)]), prefix[-1])
        for j, p in enumerate(row.tolist()):
            if p > 0:
                heapq.heappush(heap, (neg * p, (*prefix, j)))


@dataclass(frozen=True)
class ExecutorRuns:
    """Executions of the executor itself given an executed sequence (the sampled bound)."""

    spec: ExecutorSpec | None
    plan: ProbabilisticTSTrajectory
    starts: np.ndarray
    mean: np.ndarray | None
    cov: np.ndarray | None
    runs: int
    confidence: float
    seed: int
    observed: bool = True

    @classmethod
    def make(
        cls,
        system: SwitchedSystem,
        plan: ProbabilisticTSTrajectory,
        domain: Polytope | None,
        x0: ArrayLike | None,
        runs: int,
        delta: float,
        max_sequences: int,
        seed: int,
        options: dict[str, Any],
        switching: MarkovSwitching | None = None,
    ) -> ExecutorRuns:
        rng = np.random.default_rng(np.random.SeedSequence([seed, 35]))
        start = plan.get_mean(0) if x0 is None else as_vector(x0, "real_initial_state", system.n)
        x_cov = options.get("real_initial_cov")
        starts = np.tile(start, (runs, 1))
        if x_cov is not None and runs:
            starts = rng.multivariate_normal(start, np.asarray(x_cov, dtype=float), size=runs)
        belief = options.get("initial_belief")
        spec = None
        if runs:
            spec = ExecutorSpec.make(
                system,
                control_domain=domain,
                process_noise=options.get("process_noise", "auto"),
                lqr_gains=options.get("lqr_gains"),
                default_lqr=options.get("default_lqr"),
            )
        mean = None if belief is None else belief.mean
        cov = None if belief is None else belief.cov
        # (at most max_sequences sequences and the remainder: a union bound over max_sequences + 1)
        confidence = 1.0 - delta / (max_sequences + 1)
        observed = True if switching is None else switching.observed
        return cls(spec, plan, starts, mean, cov, runs, confidence, seed, observed)

    def rest(
        self,
        formula: STLFormula,
        switching: MarkovSwitching,
        verified: set[tuple[int, ...]],
        runs: int,
        confidence: float,
    ) -> tuple[float, float, float, float, int]:
        """Bounds and rates (state, belief) of executions whose sequence is none of ``verified``,
        and how many ran: sequences drawn from the chain, those verified rejected (so the runs
        are drawn from the chain conditioned on the remainder), at most 50 draws per run kept."""
        if self.spec is None:  # pragma: no cover - only called with runs
            raise InvalidArgumentError("rest_runs needs sampled executions")
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 37]))
        commanded = self.plan.get_action()
        kept: list[np.ndarray] = []
        count = 0
        for _ in range(50):
            draws = switching.draw(commanded, rng, runs)
            fresh = np.array([tuple(row) not in verified for row in draws.tolist()], dtype=bool)
            kept.append(draws[fresh])
            count += int(fresh.sum())
            if count >= runs:
                break
        executed = np.concatenate(kept)[:runs]
        S = executed.shape[0]
        if not S:
            return 0.0, 0.0, float("nan"), float("nan"), 0
        starts = self.starts[:S]
        r = roll_executed(self.spec, self.plan, executed, self.observed, starts, rng, 0, self.mean, self.cov)
        state = float(success_of(formula, r.states, None).mean())
        belief = float(success_of(formula, r.means, r.covs).mean())
        return (
            clopper_pearson_lower(state, S, confidence),
            clopper_pearson_lower(belief, S, confidence),
            state,
            belief,
            S,
        )

    def run(self, formula: STLFormula, executed: np.ndarray) -> tuple[float, float, float, float]:
        """Bounds (state, belief) and rates (state, belief) of ``runs`` executions given ``executed``."""
        if self.spec is None:  # pragma: no cover - only called with runs
            raise InvalidArgumentError("sampled_runs is 0")
        # each sequence its own stream, from the seed and the sequence (order-independent)
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 36, *executed.tolist()]))
        executed_all = np.tile(executed, (self.runs, 1))
        r = roll_executed(
            self.spec, self.plan, executed_all, self.observed, self.starts, rng, 0, self.mean, self.cov
        )
        state = float(success_of(formula, r.states, None).mean())
        belief = float(success_of(formula, r.means, r.covs).mean())
        return (
            clopper_pearson_lower(state, self.runs, self.confidence),
            clopper_pearson_lower(belief, self.runs, self.confidence),
            state,
            belief,
        )


@dataclass(frozen=True)
class SequenceBound:
    """The verdict on one executed mode sequence.

    Attributes
    ----------
    executed : tuple of int
        The executed modes ``s_0 .. s_{N-1}``.
    probability : float
        ``P(s)`` under the plan's commands.
    state_bound, belief_bound : float
        Sound lower bounds on ``P[success | s]`` (true state, executed belief), the clip mass
        deducted.
    clip_mass : float
        Union bound on the probability that some unprojected input leaves the control domain.
    state_estimate, belief_estimate : float
        Model-sampled success rates given ``s`` (the executions' when sampled; NaN without
        samples).
    sampled : bool
        Whether executions given ``s`` were sampled (their bound joined the analytic one).
    """

    executed: tuple[int, ...]
    probability: float
    state_bound: float
    belief_bound: float
    clip_mass: float
    state_estimate: float
    belief_estimate: float
    sampled: bool = False


def clip_mass(pred: ClosedLoopPrediction, plan: ProbabilisticTSTrajectory, domain: Polytope | None) -> float:
    """Union bound on P[some unprojected input leaves ``domain``] in the predicted loop."""
    if domain is None or not domain.H.shape[0]:
        return 0.0
    N = pred.num_of_steps
    if not N:
        return 0.0
    n = plan.n
    K = pred.tracking_gains  # (N, m, n)
    eta_mu = pred.augmented_mean[:N, n : 2 * n]
    eta_cov = pred.augmented_cov[:N, n : 2 * n, n : 2 * n]
    u_mu = plan.get_control()[:N] - np.einsum("kmn,kn->km", K, eta_mu)
    u_cov = K @ eta_cov @ np.transpose(K, (0, 2, 1))
    H, c = domain.H, domain.c
    mu = u_mu @ H.T + c  # (N, F): face value mean
    var = np.einsum("fm,kmp,fp->kf", H, u_cov, H)
    sd = np.sqrt(np.maximum(var, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(sd > 0, ndtr(mu / np.where(sd > 0, sd, 1.0)), (mu > 0).astype(float))
    return float(out.sum())


@dataclass
class SequenceVerifier:
    """The bound of one executed sequence (the body of the enumeration of
    :func:`~idstlpy.executor.markov_bound.markov_bound`)."""

    system: SwitchedSystem
    plan: ProbabilisticTSTrajectory
    formula: STLFormula
    switching: MarkovSwitching
    domain: Polytope | None
    x0: ArrayLike | None
    samples: int
    seed: int
    options: dict[str, Any]
    runs: ExecutorRuns
    unsound: bool = False

    def bound(self, executed: tuple[int, ...], prob: float, defer: bool) -> SequenceBound | None:
        """The sequence's bound; None when it is left to the remainder (``defer`` and it needs
        its own runs, or it needs them and there are none)."""
        system, plan, ctx = self.system, self.plan, self.runs
        seq = np.asarray(executed, dtype=int)
        stateful = any(system.mode(j).has_state_dependent_noise for j in set(executed))
        if (stateful or not self.switching.observed) and ctx.runs and defer:
            return None  # (unpredicted: its Gaussian law would not be used)
        if not self.switching.observed:  # no Gaussian law of ours: the executor's own runs only
            if not ctx.runs:
                return None
            sb, bb, se, be = ctx.run(self.formula, seq)
            return SequenceBound(executed, prob, sb, bb, float("nan"), se, be, sampled=True)
        plan_s = ProbabilisticTSTrajectory(plan.get_mean(), plan.get_cov(), seq, plan.get_control())
        pred = predict_closed_loop(
            system, plan_s, None, self.x0, formula=self.formula, num_of_steps=plan.num_of_steps,
            samples=self.samples, seed=self.seed, control_domain=None, closure="gaussian", **self.options,
        )  # fmt: skip
        clip = clip_mass(pred, plan, self.domain)
        # The analytic bound is exact for constant sensor noise (module notes); the sampled one
        # (the executor itself, projection and noise functions included) wherever it is not, or
        # where the projection's deduction leaves little of it.
        analytic = (float("nan"), float("nan")) if stateful else (
            max(0.0, pred.state_success_bound - clip), max(0.0, pred.belief_success_bound - clip)
        )  # fmt: skip
        sampled = (float("nan"), float("nan"), float("nan"), float("nan"))
        if ctx.runs and (stateful or clip > CLIP_TOLERANCE):
            if defer:
                return None
            sampled = ctx.run(self.formula, seq)
        if stateful and not ctx.runs:
            self.unsound = True
            analytic = (pred.state_success_bound, pred.belief_success_bound)
        return SequenceBound(
            executed=executed,
            probability=prob,
            state_bound=float(np.nanmax([analytic[0], sampled[0], 0.0])),
            belief_bound=float(np.nanmax([analytic[1], sampled[1], 0.0])),
            clip_mass=clip,
            state_estimate=pred.state_success_estimate if np.isnan(sampled[2]) else sampled[2],
            belief_estimate=pred.belief_success_estimate if np.isnan(sampled[3]) else sampled[3],
            sampled=not np.isnan(sampled[0]),
        )
