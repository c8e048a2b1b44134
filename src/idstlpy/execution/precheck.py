"""The check of a plan before it is executed: :func:`start_check` and its outcome, :class:`StartCheck`.

The start check
---------------
Before the first step nothing has been observed, so whether a plan is good enough to start with
depends on the problem and the plan only. :func:`start_check` predicts the plan's success from
its start belief and, below ``risk``, re-solves the problem (at most ``resolves`` times, seeds
derived from its own ``seed``), keeping the best-predicted plan. Call it once and execute its
plan many times; or let ``ReplanPolicy(start_resolves=n)`` make the same check inside every run (its
re-solve seeds then derive from the run's seed). It composes: a second call with
``options=SolverOptions(guarantee="closed_loop")`` tries plans made against the predicted true
state when MLO re-solves did not reach the risk.

The prediction and the re-solves are those of :func:`~idstlpy.execution.replanning.execute`'s
checks (:mod:`idstlpy.execution.resolving`), with the same executor's keywords.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, TypedDict, Unpack

import numpy as np

from .._checks import as_int, as_seed_sequence
from ..belief import GaussianBelief
from ..errors import InvalidArgumentError, InvalidTypeError
from ..executor import ProcessNoise
from ..synthesis.options import SolverOptions
from ..synthesis.problem import Problem
from ..tracking import GainsOverride
from ..trajectory import ProbabilisticTSTrajectory
from .policy import Adopt, ReplanPolicy, RiskMeasure, RiskOn
from .replanner import EXECUTOR_KEYWORDS, executor_spec
from .resolving import Replan, _Resolver, _RiskModel, check_problem_plan, replan_seed

__all__ = ["START_CHECK_KEYWORDS", "StartCheck", "start_check"]


@dataclass(frozen=True)
class StartCheck:
    """Outcome of :func:`start_check`.

    Parameters
    ----------
    plan : ProbabilisticTSTrajectory
        The plan to follow: the given one, or a re-solved plan predicted better.
    predicted : float
        Predicted success of ``plan`` from its start belief (the risk measure's).
    initial_predicted : float
        Predicted success of the plan given to the check.
    replans : tuple of Replan
        The re-solves made (reason ``"start"``, step 0), in order.
    """

    plan: ProbabilisticTSTrajectory = field(repr=False)
    predicted: float
    initial_predicted: float
    replans: tuple[Replan, ...]

    @property
    def replaced(self) -> bool:
        """Whether a re-solved plan replaced the given one."""
        return any(r.adopted for r in self.replans)


class StartCheckOptions(TypedDict, total=False):
    """The keywords of :func:`start_check` (``**options: Unpack[StartCheckOptions]``): the
    fields of its policy, and the executor's."""

    risk: float
    risk_measure: RiskMeasure
    risk_on: RiskOn
    risk_samples: int
    adopt: Adopt
    replan_time_limit: float
    options: SolverOptions | None
    solver_options: Mapping[str, Any] | None
    clip_controls: bool
    process_noise: ProcessNoise
    lqr_gains: GainsOverride
    default_lqr: Mapping[str, Any] | None


START_CHECK_KEYWORDS = frozenset(StartCheckOptions.__optional_keys__) - EXECUTOR_KEYWORDS
"""The re-planning keywords of :func:`start_check` (the fields of its ``policy``)."""


def start_check(
    problem: Problem,
    plan: ProbabilisticTSTrajectory,
    *,
    resolves: int = 2,
    seed: int | np.random.SeedSequence = 0,
    policy: ReplanPolicy | None = None,
    **options: Unpack[StartCheckOptions],
) -> StartCheck:
    """Check a plan before it is executed; re-solve it while its predicted success is below ``risk``.

    The plan's success is predicted from its start belief as :func:`execute` predicts it
    (the planning model, the executor's gains and clipping, ``risk_measure`` and ``risk_on``).
    Below ``risk``, the problem is re-solved (at most ``resolves`` times, solver seeds derived
    from ``seed``) and a new plan is kept when predicted better (``adopt="better"``) or whenever
    one is found (``"always"``). Nothing is observed before the first step, so the check is the
    same for every execution: make it once, then execute its plan (module notes).

    Parameters
    ----------
    problem : Problem
        The problem the plan solves.
    plan : ProbabilisticTSTrajectory
        The plan to check, ``N`` steps, starting at the problem's prior.
    resolves : int
        Re-solves at most (>= 0).
    seed : int or SeedSequence
        Seed of the re-solves' seeds (re-solve ``i`` uses ``replan_seed(SeedSequence(seed), i)``).
    policy : ReplanPolicy, optional
        The check's settings as one object (its ``risk``, ``risk_measure``, ``risk_on``,
        ``risk_samples``, ``adopt``, ``replan_time_limit`` and ``solver``), instead of the
        keywords below (which must then keep their defaults).
    **options
        The keywords below (:data:`START_CHECK_KEYWORDS` and the executor's); any other raises
        :class:`~idstlpy.errors.InvalidTypeError` (a ``TypeError``) naming it.

    Other Parameters
    ----------------
    risk : float
        The predicted success a plan needs to be followed as it is (in ``[0, 1]``; default 0.9).
    risk_measure, risk_on, risk_samples, adopt, replan_time_limit
        As the fields of :class:`ReplanPolicy` (same defaults).
    options : SolverOptions, optional
        The re-solves' options.
    solver_options : mapping, optional
        :class:`~idstlpy.SolverOptions` fields overriding ``options``:
        ``solver_options={"guarantee": "closed_loop"}`` re-solves against the predicted true
        state.
    clip_controls, process_noise, lqr_gains, default_lqr
        The executor's, as in :func:`~idstlpy.execution.validation.validate`.

    Returns
    -------
    StartCheck

    Raises
    ------
    InvalidTypeError, InvalidArgumentError
        Naming the argument that is wrong (``plan`` None, an option of the wrong type or out of
        range, an unknown keyword, ``policy`` given with the keywords).
    """
    check_problem_plan(problem, plan, "check")
    given = _start_policy(policy, options)
    resolves = as_int(resolves, "resolves", minimum=0)
    ss = as_seed_sequence(seed, allow_none=False)
    executor: dict[str, Any] = {k: v for k, v in options.items() if k in EXECUTOR_KEYWORDS}
    spec = executor_spec(problem, **executor)
    resolver = _Resolver(problem, _RiskModel.make(spec, given), given.solve_options(), given.adopt)
    belief = GaussianBelief(plan.get_mean(0).copy(), plan.get_cov(0).copy())
    current, p, _, records = resolver.check_start(
        plan, belief, given.risk, resolves, lambda i: replan_seed(ss, i)
    )
    return StartCheck(current, p, records[0].predicted if records else p, tuple(records))


def _start_policy(policy: ReplanPolicy | None, options: Mapping[str, Any]) -> ReplanPolicy:
    """``start_check``'s policy: ``policy``, or the one of its keywords (checked, never both)."""
    accepted = START_CHECK_KEYWORDS | (EXECUTOR_KEYWORDS - {"plant"})
    unknown = sorted(set(options) - accepted)
    if unknown:
        raise InvalidTypeError(
            f"start_check got an unexpected keyword argument {', '.join(map(repr, unknown))}; "
            f"its options are {', '.join(sorted(accepted))}"
        )
    given = ReplanPolicy.from_keywords(**{k: v for k, v in options.items() if k in START_CHECK_KEYWORDS})
    if policy is None:
        return given
    if not isinstance(policy, ReplanPolicy):
        raise InvalidTypeError(f"policy must be a ReplanPolicy, got {type(policy).__name__}")
    if given != ReplanPolicy():
        raise InvalidArgumentError("give either policy or the keywords risk, risk_measure, ... not both")
    return policy
