"""``SolverOptions``: the single, validated source of every solver parameter.

Budgets that *decide* the search are counted in work (candidates, LP calls, sampler iterations),
so the same problem, options and seed give the same plan on any machine under any load.
Wall-clock limits (``rrt_timeout`` per candidate, ``time_limit`` overall) are safety caps: when
one is hit the result says so (``SolveStats.caps_hit``) and reproducibility is no longer promised.

The options are given flat (the paper's keyword façade: ``problem.solve(rrt_timeout=...)``), and
read in groups, one per part of the solver, each a frozen dataclass holding only what that part
reads: :attr:`SolverOptions.sampler` (:class:`SamplerOptions`), :attr:`SolverOptions.search`
(:class:`SearchOptions`: the proposer, the abstraction and the plan LP),
:attr:`SolverOptions.eager` (:class:`EagerOptions`), :attr:`SolverOptions.objectives`
(:class:`ObjectiveOptions`), :attr:`SolverOptions.target` (:class:`TargetOptions`) and when the
solve stops, :attr:`SolverOptions.termination` (one :class:`Termination`, composable as OMPL's
``PlannerTerminationCondition``: ``Termination.time(60) | Termination.work(candidates=500)``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from functools import cached_property
from typing import Any, Literal, get_args

import numpy as np

from .._checks import as_float, as_int
from ..backends import available_backends, default_milp_backend
from ..errors import InvalidArgumentError, InvalidTypeError, OutOfRangeError
from ..execution_target import DEFAULT_EXECUTION_TARGET, ExecutionTarget, as_execution_target
from .termination import StopRule, Termination

__all__ = [
    "DEFAULT_RRT_TIMEOUT",
    "GUARANTEES",
    "ITERATIONS_PER_SECOND",
    "OBJECTIVES",
    "TIME_CAP_PER_RRT_TIMEOUT",
    "TRACKINGS",
    "EagerOptions",
    "Guarantee",
    "Objective",
    "ObjectiveOptions",
    "SamplerOptions",
    "SearchOptions",
    "SolverOptions",
    "TargetOptions",
    "Termination",
    "Tracking",
]

Guarantee = Literal["execution", "mlo", "closed_loop"]
"""What a returned plan promises (see :attr:`SolverOptions.guarantee`)."""
Objective = Literal["effort", "time", "margin"]
"""What an optimising solve optimises (see :attr:`SolverOptions.objective`)."""
Tracking = Literal["fitted", "paper"]
"""The tracking gains a solve plans with (see :attr:`SolverOptions.tracking`)."""
TRACKINGS: tuple[Tracking, ...] = get_args(Tracking)
"""The values of :attr:`SolverOptions.tracking` (the first is the default)."""

GUARANTEES: tuple[Guarantee, ...] = get_args(Guarantee)
"""The values of :attr:`SolverOptions.guarantee` (the first is the default)."""
OBJECTIVES: tuple[Objective, ...] = get_args(Objective)
"""The values of :attr:`SolverOptions.objective` besides ``None``."""

DEFAULT_RRT_TIMEOUT = 60.0
"""The paper's ``rrt_timeout``, the default. At this value it only sets the work budgets (the
sampler's iterations per candidate, the overall cap): no per-candidate clock, so that a default
solve is decided by work on any machine under any load; any other value given is also a
wall-clock cap on each candidate's search."""

ITERATIONS_PER_SECOND = 250
"""Sampler iterations per second of ``rrt_timeout`` when ``sampler_iterations`` is not given.

The paper's ``rrt_timeout`` is a time; the work budget derived from it is
``ceil(ITERATIONS_PER_SECOND * rrt_timeout)`` iterations per candidate (15,000 for the paper's
60 s). A 2-core machine runs 1,500-4,000 light-dark iterations per second, so the budget,
not the clock, ends a candidate's search: see BENCHMARKS.md.
"""

TIME_CAP_PER_RRT_TIMEOUT = 10.0
"""The overall wall-clock cap, when neither ``time_limit`` nor a :class:`Termination` clock is
given, is this many times ``rrt_timeout`` (the paper's only time: 600 s for its 60 s)."""

_MAX_SEED = 2**63 - 1

CODE_ONLY_OPTIONS = frozenset({"stop_rules"})
"""Options a problem file cannot hold (callables and thread flags: :meth:`Termination.when`,
:meth:`Termination.cancellable`); ``[solver]`` accepts every other field."""

# The flat keywords a Termination stands for (make / with_ expand `termination=` into them).
_TERMINATION_KEYWORDS = ("time_limit", "max_candidates", "max_lp_calls", "first_found", "stop_rules")


def sat_backends() -> list[str]:
    """Names python-sat accepts for its solvers (``SolverOptions.sat_backend``)."""
    from pysat.solvers import SolverNames

    return sorted({n for names in vars(SolverNames).values() if isinstance(names, tuple) for n in names})


def _seed(value: Any) -> int | None:
    if value is None:
        return None
    if isinstance(value, np.random.Generator):
        return int(value.integers(_MAX_SEED))
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise InvalidTypeError(
            f"seed must be a non-negative int, a numpy Generator or None, got {type(value).__name__}"
        )
    if int(value) < 0:
        raise OutOfRangeError(f"seed must be a non-negative int, got {int(value)}")
    return int(value)


def _name(value: Any, name: str, choices: tuple[str, ...] | None = None) -> str:
    if not isinstance(value, str) or not value:
        raise InvalidTypeError(f"{name} must be a non-empty string, got {value!r}")
    if choices is not None and value not in choices:
        raise InvalidArgumentError(
            f"{name} must be one of {', '.join(choices)} (installed here); got {value!r}"
        )
    return value


@dataclass(frozen=True)
class SamplerOptions:
    """What the belief-space sampler (:mod:`.sampler`) reads (see :class:`SolverOptions`).

    Parameters
    ----------
    rrt_timeout : float
        Wall-clock safety cap (s) on one candidate's search, unless it is the default
        (:data:`DEFAULT_RRT_TIMEOUT`: no per-candidate clock).
    iterations : int
        Iterations per candidate (the work budget that decides the search;
        :attr:`SolverOptions.iterations_per_candidate`).
    delta_near, delta_drain, goal_bias : float
        The paper's radii of node choice and draining, and the goal bias.
    min_num_of_steps, max_num_of_steps : int
        Range of the number of steps of one extension.
    shortcut_checks : int
        Full re-checks the plan shortcutting may spend.
    polish_rounds : int
        Rounds of the room LP that polishes a sampled plan.
    """

    rrt_timeout: float
    iterations: int
    delta_near: float
    delta_drain: float
    goal_bias: float
    min_num_of_steps: int
    max_num_of_steps: int
    shortcut_checks: int
    polish_rounds: int


@dataclass(frozen=True)
class SearchOptions:
    """What the discrete search reads: the proposer (:mod:`.proposer`), the abstraction's pruning
    (:mod:`.abstraction`) and the plan LP (:mod:`.teacher`).

    Parameters
    ----------
    max_plan_length : int
        Longest plan (steps) the proposer may unroll.
    max_pruning_lps : int
        Cap on the abstraction's one-step reachability LPs.
    sat_backend, lp_backend : str
        The proposer's SAT solver and the LP back-end.
    seed : int or None
        Parent seed of every random stream.
    """

    max_plan_length: int
    max_pruning_lps: int
    sat_backend: str
    lp_backend: str
    seed: int | None


@dataclass(frozen=True)
class EagerOptions:
    """When and with what the eager MILP (:mod:`.milp`) takes over.

    Parameters
    ----------
    lazy_candidates : int
        Candidates the lazy loop tries at least before the eager MILP may take over.
    lazy_conflict_size : float
        Median conflict size above which the lazy loop is deemed not to converge.
    milp_backend : str
        The MILP back-end (resolved: never ``"auto"``).
    """

    lazy_candidates: int
    lazy_conflict_size: float
    milp_backend: str


@dataclass(frozen=True)
class ObjectiveOptions:
    """What the optimisation (:mod:`.objectives`) reads.

    Parameters
    ----------
    objective : {None, "effort", "time", "margin"}
        What to optimise (``None``: the first verified plan).
    effort_weights : tuple of float or None
        Per-input weights of ``"effort"`` (``None``: ones).
    polish_rounds : int
        Scales the refinement's rounds (``2 * max(polish_rounds, 4)``).
    """

    objective: Objective | None
    effort_weights: tuple[float, ...] | None
    polish_rounds: int

    @property
    def weights(self) -> np.ndarray | None:
        """``effort_weights`` as an array, shape (m,), or ``None`` (ones)."""
        return None if self.effort_weights is None else np.asarray(self.effort_weights, dtype=float)


@dataclass(frozen=True)
class TargetOptions:
    """What a returned plan promises, and the execution target it is held to.

    Parameters
    ----------
    guarantee : {"execution", "mlo", "closed_loop"}
        What the chance constraints constrain and a returned plan promises.
    execution_target : ExecutionTarget
        Least predicted success rates of the execution.
    tracking : {"fitted", "paper"}
        The tracking gains the plans are made for.
    """

    guarantee: Guarantee
    execution_target: ExecutionTarget
    tracking: Tracking = "fitted"


@dataclass(frozen=True)
class SolverOptions:
    """Validated parameters of :meth:`Problem.solve` (the paper's, and the solver's own).

    Parameters
    ----------
    rrt_timeout : float
        Sets the default work budget ``sampler_iterations`` and the default overall cap
        (``10 * rrt_timeout``); a value other than the default (:data:`DEFAULT_RRT_TIMEOUT`) is
        also a wall-clock safety cap, in seconds, on the sampler's search for one candidate.
    delta_near : float
        Radius within which the sampler prefers the least uncertain node to extend.
    delta_drain : float
        Radius within which the sampler keeps only the least uncertain node.
    goal_bias : float
        Probability of aiming a sample at the candidate's next required region.
    min_num_of_steps, max_num_of_steps : int
        Range of the number of steps of one sampler extension.
    seed : int, numpy Generator or None
        Seed of every random choice (each candidate gets its own stream spawned from it).
        ``None`` draws fresh entropy (not reproducible).
    time_limit : float, optional
        Overall wall-clock safety cap in seconds, counted from the first line of ``solve``
        (default ``10 * rrt_timeout``).
    max_candidates : int, optional
        Stop after this many discrete candidates (a work budget).
    sampler_iterations : int, optional
        Sampler iterations per candidate (the work budget that decides the search); default
        ``ceil(ITERATIONS_PER_SECOND * rrt_timeout)``.
    lazy_candidates : int
        Candidates the lazy loop tries at least on an LP-exact single-mode problem before the
        eager MILP may take over.
    lazy_conflict_size : float
        After ``lazy_candidates``, the eager MILP takes over once the median size of the last
        ``lazy_candidates`` proven conflicts exceeds this (the lazy loop is no longer
        converging; see :func:`~idstlpy.synthesis.milp.switch_to_eager`), and in any case after
        ``10 * lazy_candidates`` candidates; earlier, from 3 candidates on, once the median of
        the last 3 exceeds it by more than one requirement (conflicts large from the start).
        ``0`` switches after exactly ``lazy_candidates``.
    max_plan_length : int
        Longest plan (in steps) the proposer may unroll; a formula that needs a longer one ends
        ``budget_exhausted`` with that reason.
    max_pruning_lps : int
        Cap on the one-step reachability LPs of the abstraction's pruning.
    polish_rounds : int
        Rounds of the margin LP that moves a sampled plan away from the boundaries it grazes.
    shortcut_checks : int
        Full re-checks the sampler's plan shortcutting may spend.
    objective : {None, "effort", "time", "margin"}
        ``None``: the first verified plan. ``"effort"``: least ``sum_k sum_j w_j |u_kj|``;
        ``"time"``: fewest steps; ``"margin"``: largest robustness (see
        :mod:`idstlpy.synthesis.objectives`).
    effort_weights : sequence of float, optional
        Per-input weights ``w`` of ``"effort"`` (default ones), length ``m``.
    guarantee : {"execution", "mlo", "closed_loop"}
        What the chance constraints constrain and what a returned plan promises.
        ``"execution"`` (the default): the plan satisfies the formula under the paper's (MLO)
        semantics *and* its predicted execution (:func:`idstlpy.executor.predict.predict_closed_loop`:
        the Kalman filter, the modes' LQR tracking, inputs clipped to the control domain, the true
        start drawn from the prior, the model's noise) meets ``execution_target`` on both
        readings (the executed belief satisfies the formula; the true states satisfy its
        deterministic reading). A candidate predicted below target is repaired (the closed-loop
        repair of ``"closed_loop"``) or set aside while the search goes on; if only a plan below
        target can be returned, ``SolveResult.meets_target`` is False and an
        :class:`~idstlpy.errors.ExecutionTargetWarning` is issued. ``"mlo"``: the paper's
        semantics only (the belief under the maximum-likelihood observation).
        ``"closed_loop"``: the true state predicted under the executor
        (:func:`idstlpy.closed_loop.predicted_state`). The returned plan is always the MLO belief
        trajectory the executor tracks; under ``"closed_loop"`` the result's ``predicted`` holds
        the distribution that was verified.
    execution_target : ExecutionTarget, (belief, state) pair, mapping or None
        Least predicted success rates of the execution (:class:`~idstlpy.execution_target.ExecutionTarget`);
        default 90% belief / 95% true state. The search is held to it under
        ``guarantee="execution"``; under every guarantee a found result says whether its plan
        meets it (``SolveResult.meets_target``).
    tracking : {"fitted", "paper"}
        The executor's LQR tracking the plans are made for, for modes without their own
        ``lqr_gains``. ``"fitted"`` (the default): weights from the problem's scales (Bryson's
        rule: ``Q_ii = 1 / d_i^2`` with ``d_i`` the tightest half-width the formula's regions
        put on state coordinate ``i``, ``R_jj = 1 / r_j^2`` with ``r_j`` the control domain's
        half-width), and for a plan predicted below the execution target firmer weights
        (``Q`` x10, x100) and the paper's, keeping the first that meets the target
        (:mod:`idstlpy.synthesis.tracking_choice`). ``"paper"``: the paper's ``Q = I``,
        ``R = 0.05 I`` (:data:`idstlpy.tracking.DEFAULT_LQR`), the behaviour before. The
        returned plan carries its gains (``plan.tracking``, ``result.tracking``); the
        executors use them.
    smooth : bool
        Without an objective, prefer small input changes among the plans that hold (the
        default): the verified plan's input total variation is lowered with its modes, its
        requirements and its execution room kept (:func:`idstlpy.synthesis.objectives.smooth`),
        and the smoothed plan is returned only when it passes the final check, meets the
        execution target whenever the first plan does and predicts no less success (within half
        a point). ``False``: the first verified plan as
        it came.
    sat_backend : str
        python-sat solver name (``"cadical195"``, ``"minisat22"``, ``"glucose4"``, ...).
    lp_backend, milp_backend : str
        Registered linear back-ends (see :mod:`idstlpy.backends`); ``"highs"`` is
        always available. ``milp_backend="auto"`` (the default) resolves to
        :func:`~idstlpy.backends.default_milp_backend`: ``"scip"`` when the ``scip`` extra
        (``pyscipopt``) is installed, measured 2-20x faster on the eager MILPs of the
        benchmarks (BENCHMARKS.md), else ``"highs"``; the resolved name is kept here.
    max_lp_calls : int, optional
        Stop before the next candidate once this many LPs were solved (a work budget).
    first_found : bool
        Stop at the first verified plan (see :class:`Termination`).
    stop_rules : tuple of StopRule
        A :class:`Termination`'s predicates, cancellations and ``&`` compositions
        (:meth:`Termination.when`, :meth:`Termination.cancellable`), checked before each
        candidate; set through ``termination=``.

    Notes
    -----
    ``time_limit``, ``max_candidates``, ``max_lp_calls``, ``first_found`` and ``stop_rules`` are
    the keywords of one :class:`Termination` (:attr:`termination`); :meth:`make` and :meth:`with_` (and so
    ``problem.solve``) also take it whole, as ``termination=``. Each part of the solver reads its
    group: :attr:`sampler`, :attr:`search`, :attr:`eager`, :attr:`objectives`, :attr:`target`.
    """

    rrt_timeout: float = DEFAULT_RRT_TIMEOUT
    delta_near: float = 2.0
    delta_drain: float = 0.5
    goal_bias: float = 0.25
    min_num_of_steps: int = 3
    max_num_of_steps: int = 15
    seed: int | None = None
    time_limit: float | None = None
    max_candidates: int | None = None
    sampler_iterations: int | None = None
    lazy_candidates: int = 10
    lazy_conflict_size: float = 3.0
    max_plan_length: int = 100_000
    max_pruning_lps: int = 400
    polish_rounds: int = 4
    shortcut_checks: int = 24
    objective: Literal["effort", "time", "margin"] | None = None
    effort_weights: tuple[float, ...] | None = None
    guarantee: Literal["execution", "mlo", "closed_loop"] = "execution"
    execution_target: ExecutionTarget = DEFAULT_EXECUTION_TARGET
    tracking: Literal["fitted", "paper"] = "fitted"
    smooth: bool = True
    sat_backend: str = "cadical195"
    lp_backend: str = "highs"
    milp_backend: str = "auto"
    max_lp_calls: int | None = None
    first_found: bool = False
    stop_rules: tuple[StopRule, ...] = ()

    def __post_init__(self) -> None:
        put = object.__setattr__
        put(self, "rrt_timeout", as_float(self.rrt_timeout, "rrt_timeout", 0.0, low_open=True))
        put(self, "delta_near", as_float(self.delta_near, "delta_near", 0.0))
        put(self, "delta_drain", as_float(self.delta_drain, "delta_drain", 0.0))
        put(self, "goal_bias", as_float(self.goal_bias, "goal_bias", 0.0, 1.0))
        lo = as_int(self.min_num_of_steps, "min_num_of_steps", minimum=1)
        hi = as_int(self.max_num_of_steps, "max_num_of_steps", minimum=1)
        if lo > hi:
            raise InvalidArgumentError(f"min_num_of_steps must be <= max_num_of_steps, got {lo} > {hi}")
        put(self, "min_num_of_steps", lo)
        put(self, "max_num_of_steps", hi)
        put(self, "seed", _seed(self.seed))
        if self.time_limit is not None:
            put(self, "time_limit", as_float(self.time_limit, "time_limit", 0.0, low_open=True))
        for key in ("max_candidates", "sampler_iterations", "max_lp_calls"):
            if getattr(self, key) is not None:
                put(self, key, as_int(getattr(self, key), key, minimum=1))
        put(self, "lazy_candidates", as_int(self.lazy_candidates, "lazy_candidates", minimum=0))
        put(self, "lazy_conflict_size", as_float(self.lazy_conflict_size, "lazy_conflict_size", 0.0))
        put(self, "max_plan_length", as_int(self.max_plan_length, "max_plan_length", minimum=1))
        put(self, "max_pruning_lps", as_int(self.max_pruning_lps, "max_pruning_lps", minimum=0))
        put(self, "polish_rounds", as_int(self.polish_rounds, "polish_rounds", minimum=0))
        put(self, "shortcut_checks", as_int(self.shortcut_checks, "shortcut_checks", minimum=0))
        if self.objective is not None:
            put(self, "objective", _name(self.objective, "objective", OBJECTIVES))
        if self.effort_weights is not None:
            try:
                w = tuple(float(v) for v in np.asarray(self.effort_weights, dtype=float).reshape(-1))
            except (TypeError, ValueError):
                raise InvalidTypeError(
                    f"effort_weights must be numbers, got {self.effort_weights!r}"
                ) from None
            if not w or not all(math.isfinite(v) and v >= 0 for v in w):
                raise InvalidArgumentError(f"effort_weights must be finite and >= 0, got {list(w)}")
            put(self, "effort_weights", w)
        put(self, "guarantee", _name(self.guarantee, "guarantee", GUARANTEES))
        put(self, "execution_target", as_execution_target(self.execution_target, "execution_target"))
        if self.tracking not in TRACKINGS:
            raise InvalidArgumentError(
                f"tracking must be one of {', '.join(TRACKINGS)}; got {self.tracking!r}"
            )
        put(self, "sat_backend", _name(self.sat_backend, "sat_backend", tuple(sat_backends())))
        put(self, "lp_backend", _name(self.lp_backend, "lp_backend", tuple(available_backends())))
        if self.milp_backend == "auto":
            put(self, "milp_backend", default_milp_backend())
        put(
            self,
            "milp_backend",
            _name(self.milp_backend, "milp_backend", tuple(available_backends(integer=True))),
        )
        if not isinstance(self.smooth, bool | np.bool_):
            raise InvalidTypeError(f"smooth must be a bool, got {type(self.smooth).__name__}")
        put(self, "smooth", bool(self.smooth))
        if not isinstance(self.first_found, bool | np.bool_):
            raise InvalidTypeError(f"first_found must be a bool, got {type(self.first_found).__name__}")
        put(self, "first_found", bool(self.first_found))
        # Validated as a Termination's rules are (one place says what a stop rule is).
        put(self, "stop_rules", Termination(rules=self.stop_rules).rules)

    @classmethod
    def make(cls, **kw: Any) -> SolverOptions:
        """Validated options from keywords; an unknown keyword is an error naming it.

        Parameters
        ----------
        **kw
            Option name to value: any of the class's parameters (see :class:`SolverOptions`),
            or ``termination``: a :class:`Termination` standing for ``time_limit``,
            ``max_candidates``, ``max_lp_calls``, ``first_found`` and ``stop_rules``.

        Returns
        -------
        SolverOptions

        Raises
        ------
        InvalidArgumentError
            For an unknown keyword (the message names it and lists the known ones), or
            ``termination`` given with one of the keywords it stands for.
        """
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(kw) - known - {"termination"})
        if unknown:
            raise InvalidArgumentError(
                f"unknown solver option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
            )
        return cls(**_expand_termination(kw))

    def with_(self, **kw: Any) -> SolverOptions:
        """A validated copy with some options replaced.

        Parameters
        ----------
        **kw
            Option name to new value: any of the class's parameters (see :class:`SolverOptions`),
            or ``termination`` (as in :meth:`make`; it replaces all four keywords it stands for).

        Returns
        -------
        SolverOptions

        Raises
        ------
        InvalidArgumentError
            For an unknown keyword (the message names it), or ``termination`` given with one of
            the keywords it stands for.
        """
        known = {f.name for f in fields(self)}
        unknown = sorted(set(kw) - known - {"termination"})
        if unknown:
            raise InvalidArgumentError(f"unknown solver option(s) {', '.join(unknown)}")
        return replace(self, **_expand_termination(kw))

    @property
    def total_time_cap(self) -> float:
        """The overall wall-clock cap in seconds (``time_limit`` or ``10 * rrt_timeout``)."""
        if self.time_limit is not None:
            return self.time_limit
        return TIME_CAP_PER_RRT_TIMEOUT * self.rrt_timeout

    @property
    def iterations_per_candidate(self) -> int:
        """The sampler's work budget per candidate (see :data:`ITERATIONS_PER_SECOND`)."""
        if self.sampler_iterations is not None:
            return self.sampler_iterations
        return max(1, math.ceil(ITERATIONS_PER_SECOND * self.rrt_timeout))

    @cached_property
    def termination(self) -> Termination:
        """When the solve stops: its clock (:attr:`total_time_cap`, always set), its work
        budgets (``max_candidates``, ``max_lp_calls``), ``first_found`` and its ``stop_rules``."""
        return Termination(
            self.total_time_cap, self.max_candidates, self.max_lp_calls, self.first_found, self.stop_rules
        )

    @cached_property
    def sampler(self) -> SamplerOptions:
        """What the belief-space sampler reads."""
        return SamplerOptions(
            self.rrt_timeout,
            self.iterations_per_candidate,
            self.delta_near,
            self.delta_drain,
            self.goal_bias,
            self.min_num_of_steps,
            self.max_num_of_steps,
            self.shortcut_checks,
            self.polish_rounds,
        )

    @cached_property
    def search(self) -> SearchOptions:
        """What the proposer, the abstraction's pruning and the plan LP read."""
        return SearchOptions(
            self.max_plan_length, self.max_pruning_lps, self.sat_backend, self.lp_backend, self.seed
        )

    @cached_property
    def eager(self) -> EagerOptions:
        """When and with what the eager MILP takes over."""
        return EagerOptions(self.lazy_candidates, self.lazy_conflict_size, self.milp_backend)

    @cached_property
    def objectives(self) -> ObjectiveOptions:
        """What the optimisation reads."""
        return ObjectiveOptions(self.objective, self.effort_weights, self.polish_rounds)

    @cached_property
    def target(self) -> TargetOptions:
        """The guarantee and the execution target."""
        return TargetOptions(self.guarantee, self.execution_target, self.tracking)


def _expand_termination(kw: dict[str, Any]) -> dict[str, Any]:
    """``kw`` with a ``termination`` replaced by the keywords it stands for."""
    if "termination" not in kw:
        return kw
    kw = dict(kw)
    termination = kw.pop("termination")
    if not isinstance(termination, Termination):
        raise InvalidTypeError(f"termination must be a Termination, got {type(termination).__name__}")
    both = sorted(set(kw) & set(_TERMINATION_KEYWORDS))
    if both:
        raise InvalidArgumentError(
            f"termination stands for {', '.join(_TERMINATION_KEYWORDS)}: give it or {', '.join(both)}, "
            "not both"
        )
    return {**kw, **termination.keywords()}
