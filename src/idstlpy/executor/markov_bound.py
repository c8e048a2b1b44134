"""A sound lower bound on a plan's success under chance switching (issue 35).

Under a :class:`~idstlpy.markov.MarkovSwitching` the executed mode sequence ``s`` is random.
PrSTL is read over the joint distribution of the noises and the jumps: the probability that the
execution satisfies the formula is

    P[success] = sum over every executed sequence s of P(s) * P[success | s].

Given ``s`` and an *observed* executed mode, the closed loop is the executor of
:mod:`idstlpy.executor.predict` tracking the plan's means and inputs with the modes ``s`` (the
plant, the sensor, the tracking gain and the Kalman filter of ``s_k`` at step ``k``), a
linear-Gaussian process whose law :func:`~idstlpy.executor.predict.predict_closed_loop`
computes exactly when every sensor's noise is constant and no input is projected on the control
domain; its ``success_bound`` is then a sound lower bound on ``P[success | s]``.

The inputs of the executor are projected on the control domain; the law is that of the loop
without projection, and the two loops, driven by the same noises, coincide as long as no
unprojected input leaves the domain. So, with ``c_k(s)`` the union bound over the domain's faces
on the probability that the unprojected input of step ``k`` leaves it,

    P[success | s] >= success_bound(s) - sum_k c_k(s)          (clipped at 0).

The bound enumerates executed sequences best-first (in order of decreasing probability: a
prefix's probability bounds every completion's), stops at ``max_sequences`` sequences or once
the next one is less likely than ``min_probability``, and reports

    bound = sum over the enumerated s of P(s) * max(0, success_bound(s) - sum_k c_k(s))

assuming nothing of the sequences left out (their mass ``1 - covered_mass`` counts as failure).
The point estimate is the covered sequences' model-sampled success rates weighted by their
probabilities and renormalised by the covered mass (it assumes the rest behave alike).

**The remainder, sampled.** When the verified sequences leave mass out, ``rest_runs`` executions
of the executor itself run with sequences drawn from the chain *conditioned on the remainder*
(drawn from the chain, the verified ones rejected); their Clopper-Pearson lower bound ``r`` on the
success given the remainder completes the bound,
``total_bound = bound + (1 - covered_mass) * r``, a lower bound at confidence ``1 - delta``
(every sampled bound at ``1 - delta / (max_sequences + 1)``, a union bound). ``bound`` alone
(nothing assumed of the rest) stays reported.

**The executed belief reading.** When the executed mode is observed the executor's belief is a
Gaussian whose mean and covariance follow the observed sequence: the belief reading of the
formula (``P[h'x + c <= 0] >= 1 - eps`` on the filter's Gaussian) is read on that belief, the
sequence being known; the execution target's belief rate is then the mixture over sequences,
``sum_s P(s) P[belief satisfies | s]``, bounded in the same way.

**Not sound (the flag says so):** a state-dependent sensor noise on a mode of an enumerated
sequence (the loop is then only approximately Gaussian: the bound is the Gaussian model's).
**An unobserved executed mode**: the executor tracks and filters with the commanded mode while the
plant and the sensor are the executed one's; this module has no Gaussian law for that loop, so
every sequence (and the remainder) is bounded by the executor's own runs (confidence
``1 - delta``). **Not supported yet** (an error says so): a real system other than the model, a
formula whose propositions name modes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from .._checks import as_float, as_int
from ..dynamical_system import SwitchedSystem
from ..errors import InvalidArgumentError, InvalidTypeError
from ..formulas import STLFormula
from ..markov import MarkovSwitching, switching_of
from ..sets import Polytope
from ..trajectory import ProbabilisticTSTrajectory
from .markov_sampling import (
    ExecutorRuns,
    SequenceBound,
    SequenceVerifier,
    sequences_by_probability,
)

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = ["MarkovBound", "SequenceBound", "markov_bound", "sequences_by_probability"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class MarkovBound:
    """A plan's success under chance switching (module notes).

    Attributes
    ----------
    state_bound, belief_bound : float
        ``sum_s P(s) * bound(s)`` over the verified sequences: lower bounds on the probability
        that the true states / the executed belief satisfy the formula (sound when
        :attr:`sound`).
    covered_mass : float
        ``sum_s P(s)`` over the verified sequences.
    state_estimate, belief_estimate : float
        Point estimates over the covered sequences (their rates, renormalised by the mass).
    rest_mass : float
        ``1 - covered_mass``, the sequences not verified.
    rest_state_bound, rest_belief_bound : float
        Clopper-Pearson lower bounds on the success given the remainder (``rest_runs``
        executions drawn from the chain conditioned on it); NaN without them.
    rest_state_estimate, rest_belief_estimate : float
        The remainder's measured rates (NaN without runs).
    rest_runs : int
        Executions behind them.
    sequences : tuple of SequenceBound
        The verified sequences, most likely first.
    exhausted : bool
        True when every sequence of positive probability was verified.
    sound : bool
        False when a verified sequence uses a mode with state-dependent sensor noise and no
        executions were sampled (``sampled_runs=0``).
    confidence : float
        1 when every sequence's bound is analytic (a proof for the linear-Gaussian loop);
        ``1 - delta`` when some are sampled (Clopper-Pearson, union over the sequences).
    note : str
        Why the bound is not sound, or ``""``.
    """

    state_bound: float
    belief_bound: float
    covered_mass: float
    state_estimate: float
    belief_estimate: float
    sequences: tuple[SequenceBound, ...]
    exhausted: bool
    sound: bool
    confidence: float = 1.0
    note: str = ""
    rest_mass: float = 0.0
    rest_state_bound: float = float("nan")
    rest_belief_bound: float = float("nan")
    rest_state_estimate: float = float("nan")
    rest_belief_estimate: float = float("nan")
    rest_runs: int = 0

    @property
    def total_state_bound(self) -> float:
        """``state_bound + rest_mass * rest_state_bound`` (the remainder's sampled bound; NaN
        counted as 0): a lower bound at confidence :attr:`confidence`."""
        return self.state_bound + self.rest_mass * _or_zero(self.rest_state_bound)

    @property
    def total_belief_bound(self) -> float:
        """``belief_bound + rest_mass * rest_belief_bound`` (as :attr:`total_state_bound`)."""
        return self.belief_bound + self.rest_mass * _or_zero(self.rest_belief_bound)

    @property
    def total_state_estimate(self) -> float:
        """The point estimate over every sequence: the verified ones' and the remainder's runs."""
        return _mix(self.state_estimate, self.covered_mass, self.rest_state_estimate, self.rest_mass)

    @property
    def total_belief_estimate(self) -> float:
        """As :attr:`total_state_estimate`, for the executed belief."""
        return _mix(self.belief_estimate, self.covered_mass, self.rest_belief_estimate, self.rest_mass)

    def meets(self, target_belief: float, target_state: float) -> bool:
        """Whether the total bounds prove both execution rates (at :attr:`confidence`)."""
        return (
            self.sound and self.total_belief_bound >= target_belief and self.total_state_bound >= target_state
        )


def _or_zero(value: float) -> float:
    return 0.0 if np.isnan(value) else value


def _mix(covered: float, mass: float, rest: float, rest_mass: float) -> float:
    """The estimate over every sequence (the covered ones alone when the remainder has no runs)."""
    if np.isnan(rest) or rest_mass <= 0.0:
        return covered
    if mass <= 0.0:  # (nothing verified: the covered estimate is NaN)
        return rest
    return covered * mass + rest * rest_mass


def _check(formula: STLFormula, switching: MarkovSwitching, runs: int) -> None:
    if not switching.observed and not runs:
        raise InvalidArgumentError(
            "switching: the bound for an unobserved executed mode comes from the executor's own "
            "runs only (no Gaussian law); give sampled_runs > 0 or rest_runs > 0"
        )
    for ap in formula.atomic_propositions():
        if ap.modes:
            raise InvalidArgumentError(
                f"stl_formula: proposition {ap.name or ap} names modes; the bound under chance "
                "switching does not read mode propositions yet"
            )


def markov_bound(
    problem_or_system: Problem | SwitchedSystem,
    plan: ProbabilisticTSTrajectory,
    *,
    formula: STLFormula | None = None,
    switching: MarkovSwitching | None = None,
    control_domain: Polytope | None | str = "problem",
    real_initial_state: ArrayLike | None = None,
    max_sequences: int = 64,
    sample_min_probability: float = 0.01,
    min_probability: float = 1e-6,
    samples: int = 256,
    sampled_runs: int = 1000,
    rest_runs: int = 4000,
    delta: float = 1e-3,
    seed: int = 0,
    **options: Any,
) -> MarkovBound:
    """A sound lower bound on the success of ``plan`` under chance switching (module notes).

    Parameters
    ----------
    problem_or_system : Problem or SwitchedSystem
        The planning model (a Problem also gives the formula and the control domain).
    plan : ProbabilisticTSTrajectory
        The plan; its modes are the commands, ``N`` steps.
    formula : STLFormula, optional
        Overrides the problem's formula (required with a system).
    switching : MarkovSwitching, optional
        The chain; default the system's (:func:`~idstlpy.markov.with_switching`).
    control_domain : Polytope, None or "problem"
        The domain the executor projects inputs on (``"problem"``: the problem's).
    real_initial_state : array_like, shape (n,), optional
        True start (default the plan's initial mean).
    max_sequences : int, default 64
        Most executed sequences examined (verified or deferred to the remainder).
    sample_min_probability : float, default 0.01
        A sequence that needs its own executions (a state-dependent sensor, a clip mass above
        :data:`~idstlpy.executor.markov_sampling.CLIP_TOLERANCE`) and is less likely than this
        is left to the remainder's runs instead (when ``rest_runs > 0``).
    min_probability : float, default 1e-6
        Sequences less likely than this are left out (and counted as failures).
    samples : int, default 256
        Model samples per sequence for the point estimates (0: NaN estimates).
    sampled_runs : int, default 1000
        Executions of the executor itself per sequence whose analytic bound does not hold or
        is weak (a state-dependent sensor; a clip mass above
        :data:`~idstlpy.executor.markov_sampling.CLIP_TOLERANCE`); their Clopper-Pearson lower
        bound, at confidence ``1 - delta / (max_sequences + 1)`` each, then joins the analytic
        one (0: never).
    rest_runs : int, default 4000
        Executions of the executor with sequences drawn from the chain conditioned on the
        remainder (the sequences not verified; rejection sampling, at most 50 draws per run):
        their Clopper-Pearson bound on the remainder's success completes the bound
        (:attr:`MarkovBound.total_state_bound`); 0: the remainder counts as failure.
    delta : float, default 1e-3
        Probability that some sampled bound fails (the union over the sequences): the bound
        holds with confidence ``1 - delta`` when a sequence was sampled, surely otherwise.
    seed : int
        Seed of the model samples and the executions.
    **options
        Further options of :func:`~idstlpy.executor.predict.predict_closed_loop`
        (``lqr_gains``, ``default_lqr``, ``process_noise``, ``initial_belief``,
        ``real_initial_cov``).

    Returns
    -------
    MarkovBound

    Raises
    ------
    InvalidArgumentError
        Without a switching or a formula, or for what is not supported yet (module notes).
    InvalidTypeError
        When an argument has the wrong type.
    """
    system, formula, domain = _resolve(problem_or_system, formula, control_domain)
    switching = switching if switching is not None else switching_of(system)
    if switching is None:
        raise InvalidArgumentError(
            "switching: the system has no chance switching (stl.with_switching(system, "
            "stl.mk_markov_switching(P))) and none was given"
        )
    if not isinstance(switching, MarkovSwitching):
        raise InvalidTypeError(
            f"switching must be made by mk_markov_switching, got {type(switching).__name__}"
        )
    for bad in ("closure", "control_domain", "real_system", "executor"):
        if bad in options:
            raise InvalidArgumentError(f"{bad}: not an option of markov_bound (the bound fixes it)")
    max_sequences = as_int(max_sequences, "max_sequences", minimum=1)
    min_probability = as_float(min_probability, "min_probability", low=0.0, high=1.0)
    samples = as_int(samples, "samples", minimum=0)
    sampled_runs = as_int(sampled_runs, "sampled_runs", minimum=0)
    rest_runs = as_int(rest_runs, "rest_runs", minimum=0)
    _check(formula, switching, sampled_runs + rest_runs)
    sample_min_probability = as_float(sample_min_probability, "sample_min_probability", low=0.0, high=1.0)
    delta = as_float(delta, "delta", low=0.0, high=1.0, low_open=True)
    runs = ExecutorRuns.make(
        system, plan, domain, real_initial_state, sampled_runs, delta, max_sequences, seed, options, switching
    )
    verifier = SequenceVerifier(
        system, plan, formula, switching, domain, real_initial_state, samples, seed, options, runs
    )
    verified: list[SequenceBound] = []
    exhausted, deferred = True, 0
    for executed, prob in sequences_by_probability(switching, plan.get_action()):
        if len(verified) + deferred >= max_sequences or prob < min_probability:
            exhausted = False
            break
        # an unlikely sequence that would need its own runs stays in the remainder, whose runs
        # (drawn from the chain) cover it in proportion to its probability
        one = verifier.bound(executed, prob, prob < sample_min_probability and rest_runs > 0)
        if one is None:
            deferred += 1
            exhausted = False
        else:
            verified.append(one)
    mass = float(sum(v.probability for v in verified))
    rest = (float("nan"), float("nan"), float("nan"), float("nan"), 0)
    if rest_runs and not exhausted and mass < 1.0:
        # (its own i.i.d. starts: the trials of a Clopper-Pearson bound must be independent)
        rest_runner = ExecutorRuns.make(
            system,
            plan,
            domain,
            real_initial_state,
            rest_runs,
            delta,
            max_sequences,
            seed + 1,
            options,
            switching,
        )
        rest = rest_runner.rest(
            formula, switching, {v.executed for v in verified}, rest_runs, 1.0 - delta / (max_sequences + 1)
        )
    return _summarise(verified, exhausted, verifier.unsound, rest, delta)


def _summarise(
    verified: list[SequenceBound],
    exhausted: bool,
    unsound: bool,
    rest: tuple[float, float, float, float, int],
    delta: float,
) -> MarkovBound:
    """The :class:`MarkovBound` of the verified sequences and the remainder's runs."""
    mass = float(sum(v.probability for v in verified))
    state = float(sum(v.probability * v.state_bound for v in verified))
    belief = float(sum(v.probability * v.belief_bound for v in verified))
    nan = float("nan")
    est_s = float(sum(v.probability * v.state_estimate for v in verified) / mass) if mass else nan
    est_b = float(sum(v.probability * v.belief_estimate for v in verified) / mass) if mass else nan
    note = ""
    if unsound:
        note = (
            "a mode has state-dependent sensor noise and sampled_runs=0: the loop given a sequence "
            "is only approximately Gaussian and the bound is the Gaussian model's, not a proof"
        )
    any_sampled = any(v.sampled for v in verified) or rest[4] > 0
    logger.debug(
        "markov_bound: %d sequences, mass %.6g, bound state %.4g belief %.4g",
        len(verified),
        mass,
        state,
        belief,
    )
    return MarkovBound(
        state_bound=min(state, mass),
        belief_bound=min(belief, mass),
        covered_mass=min(mass, 1.0),
        state_estimate=est_s,
        belief_estimate=est_b,
        sequences=tuple(verified),
        exhausted=exhausted,
        sound=not unsound,
        confidence=1.0 - delta if any_sampled else 1.0,
        note=note,
        rest_mass=max(0.0, 1.0 - mass),
        rest_state_bound=rest[0],
        rest_belief_bound=rest[1],
        rest_state_estimate=rest[2],
        rest_belief_estimate=rest[3],
        rest_runs=rest[4],
    )


def _resolve(
    problem_or_system: Problem | SwitchedSystem,
    formula: STLFormula | None,
    control_domain: Polytope | None | str,
) -> tuple[SwitchedSystem, STLFormula, Polytope | None]:
    """The system, the formula and the control domain of the arguments."""
    if isinstance(problem_or_system, SwitchedSystem):
        system = problem_or_system
        problem_formula, problem_domain = None, None
    else:
        found = getattr(problem_or_system, "switched_system", None)  # a Problem (model layer)
        if not isinstance(found, SwitchedSystem):
            raise InvalidTypeError(
                "problem_or_system must be a Problem or a SwitchedSystem, got "
                f"{type(problem_or_system).__name__}"
            )
        system = found
        problem_formula = problem_or_system.stl_formula
        problem_domain = problem_or_system.control_domain
    formula = formula if formula is not None else problem_formula
    if formula is None:
        raise InvalidArgumentError("formula: the bound needs a formula (give a Problem or formula=...)")
    if isinstance(control_domain, str):
        if control_domain != "problem":
            raise InvalidArgumentError(
                f"control_domain must be a Polytope, None or 'problem', got {control_domain!r}"
            )
        domain = problem_domain
    elif control_domain is None or isinstance(control_domain, Polytope):
        domain = control_domain
    else:
        raise InvalidTypeError(
            f"control_domain must be a Polytope, None or 'problem', got {type(control_domain).__name__}"
        )
    return system, formula, domain
