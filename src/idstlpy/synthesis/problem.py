"""``Problem``: a switched belief system, a control domain, an initial belief and a formula."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .._checks import as_float, as_int
from ..belief import GaussianBelief
from ..dynamical_system import SwitchedSystem
from ..errors import DimensionError, InvalidArgumentError, InvalidTypeError, OutOfRangeError
from ..formulas import STLFormula, as_formula
from ..sets import Polytope
from ..trajectory import ProbabilisticTSTrajectory

__all__ = ["Problem", "SolveResult", "SolveStats", "SolverOptions"]

logger = logging.getLogger(__name__)

Status = Literal["found", "infeasible", "budget_exhausted"]


@dataclass
class SolveStats:
    """How the solver spent its effort.

    Attributes
    ----------
    candidates : int
        Discrete plans proposed by the BMC proposer.
    counterexamples : int
        Blocking clauses added (LP infeasibility proofs and failed prefixes).
    pruned_letters, pruned_steps : int
        Letters / letter-to-letter steps excluded for good by LP pruning.
    bmc_depth : int
        Deepest bound the proposer reached.
    nodes : int
        Belief nodes grown by the sampler.
    sat_calls, lp_calls : int
    time_total, time_bmc, time_lp, time_sampling : float
        Seconds.
    """

    candidates: int = 0
    counterexamples: int = 0
    pruned_letters: int = 0
    pruned_steps: int = 0
    bmc_depth: int = 0
    nodes: int = 0
    sat_calls: int = 0
    lp_calls: int = 0
    time_total: float = 0.0
    time_bmc: float = 0.0
    time_lp: float = 0.0
    time_sampling: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        """Plain-data copy (for JSON result files)."""
        return dict(self.__dict__)


@dataclass
class SolveResult:
    """Outcome of :meth:`Problem.solve`.

    Attributes
    ----------
    status : {"found", "infeasible", "budget_exhausted"}
        ``infeasible`` is a proof (the proposer ran out of plans); ``budget_exhausted`` is not.
    trajectory : ProbabilisticTSTrajectory or None
        The verified plan when ``status == "found"``.
    reason : str
        One sentence on why the solver stopped.
    margin : float
        Monitor robustness of the returned plan (``nan`` without a plan).
    stats : SolveStats
    """

    status: Status
    trajectory: ProbabilisticTSTrajectory | None
    reason: str
    margin: float = float("nan")
    stats: SolveStats = field(default_factory=SolveStats)

    @property
    def found(self) -> bool:
        """True when a verified plan was found."""
        return self.status == "found"

    @property
    def solve_time(self) -> float:
        """Wall-clock seconds spent in ``solve``."""
        return self.stats.time_total


@dataclass(frozen=True)
class SolverOptions:
    """Validated parameters of :meth:`Problem.solve` (paper Section III)."""

    rrt_timeout: float = 60.0
    delta_near: float = 2.0
    delta_drain: float = 0.5
    goal_bias: float = 0.25
    min_num_of_steps: int = 3
    max_num_of_steps: int = 15
    seed: int | None = None
    time_limit: float | None = None
    max_candidates: int | None = None

    @classmethod
    def make(cls, **kw: Any) -> SolverOptions:
        rrt_timeout = as_float(kw["rrt_timeout"], "rrt_timeout", 0.0, low_open=True)
        delta_near = as_float(kw["delta_near"], "delta_near", 0.0)
        delta_drain = as_float(kw["delta_drain"], "delta_drain", 0.0)
        goal_bias = as_float(kw["goal_bias"], "goal_bias", 0.0, 1.0)
        lo = as_int(kw["min_num_of_steps"], "min_num_of_steps", minimum=1)
        hi = as_int(kw["max_num_of_steps"], "max_num_of_steps", minimum=1)
        if lo > hi:
            raise InvalidArgumentError(f"min_num_of_steps must be <= max_num_of_steps, got {lo} > {hi}")
        seed = kw.get("seed")
        if seed is not None and not isinstance(seed, int | np.integer):
            raise InvalidTypeError(f"seed must be an int or None, got {type(seed).__name__}")
        time_limit = kw.get("time_limit")
        if time_limit is not None:
            time_limit = as_float(time_limit, "time_limit", 0.0, low_open=True)
        max_candidates = kw.get("max_candidates")
        if max_candidates is not None:
            max_candidates = as_int(max_candidates, "max_candidates", minimum=1)
        return cls(
            rrt_timeout,
            delta_near,
            delta_drain,
            goal_bias,
            lo,
            hi,
            None if seed is None else int(seed),
            time_limit,
            max_candidates,
        )


class Problem:
    """A PrSTL synthesis problem (paper Section IV-E).

    Parameters
    ----------
    switched_system : SwitchedSystem
        The modes the plan may switch between.
    control_domain : Polytope
        Admissible inputs ``U`` (shape (k, m) inequalities), e.g. ``logical_and(u[0] >= -1, ...).region``.
    initial_state : GaussianBelief
        The prior belief ``N(mean, cov)`` from :func:`~idstlpy.to_belief`.
    stl_formula : STLFormula
        The specification.

    Raises
    ------
    DimensionError
        When the state or control dimensions of the parts disagree.
    OutOfRangeError
        When the formula names a mode the system does not have.
    """

    def __init__(
        self,
        switched_system: SwitchedSystem,
        control_domain: Polytope,
        initial_state: GaussianBelief,
        stl_formula: STLFormula,
    ) -> None:
        if not isinstance(switched_system, SwitchedSystem):
            raise InvalidTypeError(
                f"switched_system must be made by mk_switched_sys, got {type(switched_system).__name__}"
            )
        if not isinstance(control_domain, Polytope):
            raise InvalidTypeError(
                "control_domain must be a Polytope, e.g. logical_and(u[0] >= -1, u[0] <= 1).region; "
                f"got {type(control_domain).__name__}"
            )
        if not isinstance(initial_state, GaussianBelief):
            raise InvalidTypeError(
                f"initial_state must be made by to_belief(mean, cov), got {type(initial_state).__name__}"
            )
        formula = as_formula(stl_formula, "stl_formula")
        n, m = switched_system.n, switched_system.m
        if control_domain.dim != m:
            raise DimensionError(
                f"control_domain has dimension {control_domain.dim}, the system has m = {m} inputs"
            )
        if control_domain.is_empty():
            raise InvalidArgumentError("control_domain is empty: no admissible input")
        if initial_state.n != n:
            raise DimensionError(
                f"initial_state has dimension {initial_state.n}, the system has n = {n} states"
            )
        for ap in formula.atomic_propositions():
            for p in ap.predicates:
                if p.variable.size != n:
                    raise DimensionError(
                        f"proposition {ap.name or ap} is over a variable of size {p.variable.size}, "
                        f"the system state has n = {n}"
                    )
            if ap.modes is not None and ap.modes and max(ap.modes) >= switched_system.num_modes:
                raise OutOfRangeError(
                    f"proposition {ap.name or ''} names mode {max(ap.modes)}, the system has modes "
                    f"0..{switched_system.num_modes - 1}"
                )
        # Evaluate every noise function once so a bad one is reported now, by name.
        for q, mode in enumerate(switched_system.system_modes):
            if mode.p:
                R = mode.noise_cov(initial_state.mean)
                if R.shape != (mode.p, mode.p):
                    raise DimensionError(f"mode {q}: noise covariance has shape {R.shape}")
        self.switched_system = switched_system
        self.control_domain = control_domain
        self.initial_state = initial_state
        self.stl_formula = formula
        self.last_result: SolveResult | None = None

    def solve(
        self,
        rrt_timeout: float = 60.0,
        delta_near: float = 2.0,
        delta_drain: float = 0.5,
        goal_bias: float = 0.25,
        min_num_of_steps: int = 3,
        max_num_of_steps: int = 15,
        seed: int | None = None,
        *,
        time_limit: float | None = None,
        max_candidates: int | None = None,
    ) -> ProbabilisticTSTrajectory | None:
        """Find modes and controls whose MLO belief trajectory satisfies the formula.

        Parameters
        ----------
        rrt_timeout : float
            Seconds the belief-space sampler may spend on one candidate plan.
        delta_near : float
            Radius within which the sampler prefers the least uncertain node to extend.
        delta_drain : float
            Radius within which only the least uncertain node is kept.
        goal_bias : float
            Probability of aiming at the candidate's next required region.
        min_num_of_steps, max_num_of_steps : int
            Range of the number of steps of one extension.
        seed : int, optional
            Seed of the sampler; the same seed gives the same plan.
        time_limit : float, optional
            Overall wall-clock budget in seconds (default ``10 * rrt_timeout``).
        max_candidates : int, optional
            Stop after this many discrete candidates.

        Returns
        -------
        ProbabilisticTSTrajectory or None
            A plan verified by the monitor, or ``None``; :attr:`last_result` says why.
        """
        return self.solve_result(
            rrt_timeout,
            delta_near,
            delta_drain,
            goal_bias,
            min_num_of_steps,
            max_num_of_steps,
            seed,
            time_limit=time_limit,
            max_candidates=max_candidates,
        ).trajectory

    def solve_result(
        self,
        rrt_timeout: float = 60.0,
        delta_near: float = 2.0,
        delta_drain: float = 0.5,
        goal_bias: float = 0.25,
        min_num_of_steps: int = 3,
        max_num_of_steps: int = 15,
        seed: int | None = None,
        *,
        time_limit: float | None = None,
        max_candidates: int | None = None,
    ) -> SolveResult:
        """Like :meth:`solve`, but return the full :class:`SolveResult` (status, reason, statistics)."""
        options = SolverOptions.make(
            rrt_timeout=rrt_timeout,
            delta_near=delta_near,
            delta_drain=delta_drain,
            goal_bias=goal_bias,
            min_num_of_steps=min_num_of_steps,
            max_num_of_steps=max_num_of_steps,
            seed=seed,
            time_limit=time_limit,
            max_candidates=max_candidates,
        )
        from .cegis import synthesize

        result = synthesize(self, options)
        self.last_result = result
        return result

    def __repr__(self) -> str:
        return (
            f"Problem(n={self.switched_system.n}, m={self.switched_system.m}, "
            f"modes={self.switched_system.num_modes}, formula={self.stl_formula})"
        )
