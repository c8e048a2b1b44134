"""When and how an execution re-plans: :class:`ReplanPolicy`, one frozen, validated object.

It is the typed form of :func:`idstlpy.execute`'s re-planning keywords and of
:func:`idstlpy.validate`'s ``replan_options`` mapping (:meth:`ReplanPolicy.from_keywords` reads
both); :class:`~idstlpy.execution.replanner.ReplanningExecutor` and :func:`idstlpy.start_check`
read it. What each field means: :mod:`idstlpy.execution.replanning`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from .._checks import as_float, as_int
from ..errors import InvalidArgumentError, InvalidTypeError
from ..synthesis.options import SolverOptions

__all__ = ["Adopt", "POLICY_KEYWORDS", "ReplanPolicy", "ReplanTrigger", "RiskMeasure", "RiskOn"]

ReplanTrigger = Literal["on_risk", "every"]
"""When a re-solve is considered: a predicted success below ``risk``, or a fixed schedule."""
RiskMeasure = Literal["bound", "estimate"]
"""The prediction's sound lower bound, or its sampled point estimate."""
RiskOn = Literal["belief", "state", "both"]
"""Whose success a risk threshold reads: the executed belief's, the true state's, the smaller."""
Adopt = Literal["better", "always"]
"""When a re-solved plan replaces the one followed."""


@dataclass(frozen=True)
class ReplanPolicy:
    """When and how an execution re-plans (validated at construction; frozen).

    Parameters
    ----------
    trigger : {"on_risk", "every"}
        ``"on_risk"``: re-solve when the predicted success of the remaining plan is below
        ``risk`` (checked every ``check_every`` steps, on ``drift`` and at the start);
        ``"every"``: re-solve every ``every`` steps (receding-horizon control). (``execute``'s
        ``replan``; no policy at all means never.)
    risk : float
        ``"on_risk"``: re-solve when the predicted success of the remaining plan is below this
        (in ``[0, 1]``); the start check re-solves while the plan is below it.
    every : int
        ``"every"``: re-solve every this many executed steps (>= 1).
    check_every : int or None
        ``"on_risk"``: predict every this many executed steps (>= 1). A check first conditions
        the plan's own prediction (made once per plan, shared by the runs) on the run's belief
        (tens of microseconds, :mod:`idstlpy.execution.vouch`; without ``drift`` and with
        ``risk_measure="bound"``) and predicts the remaining plan only when that falls short of
        ``risk`` (about five executions of it: 0.1 s for an 82-step light-dark plan). ``None``:
        no scheduled check; only the drift test and the start check decide.
    drift : float in (0, 1), optional
        ``"on_risk"``: also predict at any step at which the executed belief's mean lies outside
        the ``drift`` confidence ellipse of its last predicted distribution (each check re-centres
        the ellipse on the new prediction).
    start_resolves : int
        ``"on_risk"``: the start check. Before the first step the plan's success is predicted
        from the start belief; while it is below ``risk``, the problem is re-solved (at most this
        many times, counted in ``max_replans``; each adopted as after any check). A plan that
        grazes a constraint in its first steps breaks it before a scheduled or drift check can
        see it coming. 0 (default): no start check.
    risk_measure : {"bound", "estimate"}
        The prediction's sound lower bound or its sampled estimate.
    risk_on : {"belief", "state", "both"}
        Success of the executed belief, of the true state (the deterministic reading), or the
        smaller of the two. The true state's bound can be far below the measured rate when a
        chance constraint allows its true state to leave the region (0% against a measured 47%
        on the disturbed light-dark case of ``benchmarks/closed_loop_results.md``): a risk
        threshold on it then re-plans at every check.
    risk_samples : int
        Samples of the Gaussian model for ``risk_measure="estimate"`` (>= 1).
    max_replans : int
        At most this many re-solves per execution (>= 0).
    adopt : {"better", "always"}
        ``"better"`` (default): a re-solved plan replaces the current one only when its
        predicted success from the current belief is higher (both predicted as for ``risk``);
        ``"always"``: whenever the re-solve finds a plan (plain receding-horizon control).
    replan_time_limit : float
        Wall-clock cap (seconds) of one re-solve (> 0): the solver's ``time_limit`` is the
        smaller of this and ``solver``'s own.
    adopt_delay : int
        Steps between a decision and its effect (>= 0). The check and the re-solve start from
        the executed belief at the decision step ``k``; a plan they adopt is followed from
        execution step ``k + adopt_delay`` (from its own step ``adopt_delay``), the plan followed
        until then. 0 (default): at once. This fixes in steps, not seconds, when a re-plan takes
        effect, so a simulated execution (``execute``, ``validate``) gives the same result
        whatever the machine; a :class:`~idstlpy.ReplanningExecutor` with
        ``background=True`` re-solves beside the loop and takes the result at that step, or at
        the first step after it at which the re-solve has finished.
    solver : SolverOptions, optional
        Options of the re-solves (use the ones the plan was solved with; the seed is replaced by
        a derived one, :func:`replan_seed`); default ``SolverOptions()``.

    Raises
    ------
    InvalidArgumentError, InvalidTypeError
        When a field is out of range or of the wrong type (the message names it).
    """

    trigger: ReplanTrigger = "on_risk"
    risk: float = 0.9
    every: int = 10
    check_every: int | None = 1
    drift: float | None = None
    start_resolves: int = 0
    risk_measure: RiskMeasure = "bound"
    risk_on: RiskOn = "both"
    risk_samples: int = 1000
    max_replans: int = 20
    adopt: Adopt = "better"
    replan_time_limit: float = 30.0
    solver: SolverOptions | None = None
    adopt_delay: int = 0

    def __post_init__(self) -> None:
        put = object.__setattr__
        if self.trigger not in ("on_risk", "every"):
            raise InvalidArgumentError(
                f"replan (the policy's trigger) must be 'on_risk' or 'every', got {self.trigger!r}"
            )
        put(self, "risk", as_float(self.risk, "risk", 0.0, 1.0))
        put(self, "every", as_int(self.every, "every", minimum=1))
        if self.check_every is not None:
            put(self, "check_every", as_int(self.check_every, "check_every", minimum=1))
        if self.drift is not None:
            put(self, "drift", as_float(self.drift, "drift", 0.0, 1.0, low_open=True))
            if self.drift == 1.0:
                raise InvalidArgumentError("drift must be < 1 (a confidence), got 1.0")
        put(self, "start_resolves", as_int(self.start_resolves, "start_resolves", minimum=0))
        if self.risk_measure not in ("bound", "estimate"):
            raise InvalidArgumentError(
                f"risk_measure must be 'bound' or 'estimate', got {self.risk_measure!r}"
            )
        if self.risk_on not in ("belief", "state", "both"):
            raise InvalidArgumentError(f"risk_on must be 'belief', 'state' or 'both', got {self.risk_on!r}")
        put(self, "risk_samples", as_int(self.risk_samples, "risk_samples", minimum=1))
        put(self, "max_replans", as_int(self.max_replans, "max_replans", minimum=0))
        if self.adopt not in ("better", "always"):
            raise InvalidArgumentError(f"adopt must be 'better' or 'always', got {self.adopt!r}")
        limit = as_float(self.replan_time_limit, "replan_time_limit", 0.0, low_open=True)
        put(self, "replan_time_limit", limit)
        put(self, "adopt_delay", as_int(self.adopt_delay, "adopt_delay", minimum=0))
        if self.solver is not None and not isinstance(self.solver, SolverOptions):
            raise InvalidTypeError(f"solver must be a SolverOptions, got {type(self.solver).__name__}")

    @classmethod
    def from_keywords(
        cls,
        replan: ReplanTrigger | None = "on_risk",
        *,
        options: SolverOptions | None = None,
        solver_options: Mapping[str, Any] | None = None,
        **fields: Any,
    ) -> ReplanPolicy:
        """The policy of ``execute``'s keywords / ``validate``'s ``replan_options`` mapping.

        Parameters
        ----------
        replan : {"on_risk", "every"} or None
            The trigger (None is read as ``"on_risk"``: the values are still checked).
        options : SolverOptions, optional
            The re-solves' options.
        solver_options : mapping, optional
            :class:`~idstlpy.SolverOptions` fields overriding ``options``.
        **fields
            The other fields of :class:`ReplanPolicy`, by name.

        Returns
        -------
        ReplanPolicy

        Raises
        ------
        InvalidArgumentError, InvalidTypeError
            For an unknown keyword or a bad value (the message names it).
        """
        unknown = sorted(
            set(fields) - {f for f in cls.__dataclass_fields__ if f not in ("trigger", "solver")}
        )
        if unknown:
            raise InvalidArgumentError(f"unknown re-planning option(s) {unknown}")
        if options is not None and not isinstance(options, SolverOptions):
            raise InvalidTypeError(f"options must be a SolverOptions, got {type(options).__name__}")
        solver = options
        if solver_options is not None:
            if not isinstance(solver_options, Mapping):
                raise InvalidTypeError(
                    f"solver_options must be a mapping, got {type(solver_options).__name__}"
                )
            solver = (options or SolverOptions()).with_(**solver_options)
        return cls(trigger="on_risk" if replan is None else replan, solver=solver, **fields)

    def solve_options(self) -> SolverOptions:
        """The re-solves' options: ``solver`` with its time limit capped at ``replan_time_limit``."""
        base = self.solver if self.solver is not None else SolverOptions()
        cap = self.replan_time_limit
        return base.with_(time_limit=cap if base.time_limit is None else min(base.time_limit, cap))


POLICY_KEYWORDS = frozenset(
    {f for f in ReplanPolicy.__dataclass_fields__ if f not in ("trigger", "solver")}
    | {"options", "solver_options"}
)
"""The keywords of :meth:`ReplanPolicy.from_keywords` besides ``replan`` (the trigger): the keys of
``validate``'s deprecated ``replan_options`` and of problem files' ``[validation.replan_options]``
(but ``options``)."""
