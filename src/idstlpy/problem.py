"""``Problem``: a switched belief system, a control domain, an initial belief and a formula.

A model-layer module: the problem's data and validation. Solving it is the synthesis layer's
work, which this module cannot import (synthesis imports the model): :mod:`idstlpy.synthesis`
registers its solver here when it is imported (:func:`register_solver`, as the execution layer
registers :meth:`~idstlpy.dynamical_system.SwitchedSystem.simulate`), and ``import idstlpy`` (run
before any of its modules) imports it, so :meth:`Problem.solve` always finds it.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from .belief import GaussianBelief
from .dynamical_system import SwitchedSystem, control_domain_mismatch
from .errors import DimensionError, InvalidArgumentError, InvalidTypeError, OutOfRangeError
from .expressions import RealValuedVariable, region_variable
from .formulas import STLFormula, allocate_joint_risk, as_formula
from .sets import Polytope
from .trajectory import ProbabilisticTSTrajectory

__all__ = ["Problem", "SolveOutcome", "Solver", "register_solver"]


class SolveOutcome(Protocol):
    """What a solve reports, as the model layer reads it (:class:`idstlpy.SolveResult` has it all).

    A :class:`typing.Protocol`, never instantiated (calling it raises ``TypeError``).

    Parameters
    ----------
    *args, **kwargs
        The placeholder signature ``typing.Protocol`` gives the class; any call is rejected.
    """

    @property
    def status(self) -> str:
        """``"found"``, ``"infeasible"`` or ``"budget_exhausted"``."""

    @property
    def reason(self) -> str:
        """Why the solve ended so, in words."""

    @property
    def trajectory(self) -> ProbabilisticTSTrajectory | None:
        """The plan, or ``None``."""


class Solver(Protocol):
    """The function behind :meth:`Problem.solve_result`: ``solver(problem, options, **overrides)``.

    A :class:`typing.Protocol`, never instantiated (calling it raises ``TypeError``).

    Parameters
    ----------
    *args, **kwargs
        The placeholder signature ``typing.Protocol`` gives the class; any call is rejected.
    """

    def __call__(self, problem: Problem, options: object | None, /, **overrides: Any) -> SolveOutcome:
        """Solve ``problem`` with ``options`` (or the defaults) and the keyword ``overrides``."""


_SOLVER: dict[str, Solver] = {}


def register_solver(solver: Solver) -> None:
    """Register the function behind :meth:`Problem.solve` (called by the synthesis layer).

    Parameters
    ----------
    solver : callable
        ``solver(problem, options, **overrides)``: ``options`` is the ``options`` argument of
        :meth:`Problem.solve_result` (or ``None``) and ``overrides`` its other arguments given.
    """
    _SOLVER["solve"] = solver


class Problem:
    """A PrSTL synthesis problem (paper Section IV-E).

    The problem's data and its validation; :meth:`solve` and :meth:`solve_result` run the solver
    the synthesis layer registers (:func:`register_solver`).

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
    InvalidArgumentError
        When the formula is written over the variable the control domain is written over, or
        over a variable an earlier Problem used as its input (or the control domain over an
        earlier state variable): variables take their role, ``"state"`` or ``"input"``, in the
        first Problem that uses them (:attr:`~idstlpy.expressions.RealValuedVariable.role`).
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
            raise control_domain_mismatch(control_domain.dim, switched_system)
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
        _check_roles(formula, control_domain)
        # Evaluate every noise function once so a bad one is reported now, by name.
        for q, mode in enumerate(switched_system.system_modes):
            if mode.p:
                R = mode.noise_cov(initial_state.mean)
                if R.shape != (mode.p, mode.p):
                    raise DimensionError(f"mode {q}: noise covariance has shape {R.shape}")
        _take_roles(formula, control_domain)
        self.switched_system = switched_system
        self.control_domain = control_domain
        self.initial_state = initial_state
        # Joint chance constraints get the risk allocation that suits this prior (same meaning).
        self.stl_formula = allocate_joint_risk(formula, initial_state.cov)
        self._joint = any(ap.joints for ap in formula.atomic_propositions())
        self.last_result: SolveOutcome | None = None

    def solve(
        self,
        rrt_timeout: float | None = None,
        delta_near: float | None = None,
        delta_drain: float | None = None,
        goal_bias: float | None = None,
        min_num_of_steps: int | None = None,
        max_num_of_steps: int | None = None,
        seed: int | np.random.Generator | None = None,
        *,
        options: object | None = None,
        **more: Any,
    ) -> ProbabilisticTSTrajectory | None:
        """Find modes and controls whose MLO belief trajectory satisfies the formula.

        Parameters
        ----------
        rrt_timeout : float, default 60
            Sets the sampler's work budget and the overall cap; another value than the default
            is also a wall-clock safety cap (seconds) on the sampler's search for one candidate
            (see :class:`~idstlpy.SolverOptions`).
        delta_near : float, default 2
            Radius within which the sampler prefers the least uncertain node to extend.
        delta_drain : float, default 0.5
            Radius within which only the least uncertain node is kept.
        goal_bias : float, default 0.25
            Probability of aiming at the candidate's next required region.
        min_num_of_steps, max_num_of_steps : int, default 3 and 15
            Range of the number of steps of one extension.
        seed : int, numpy Generator or None
            Seed of every random choice: the same seed gives the same plan (unless a wall-clock
            cap was hit, which ``last_result.stats.caps_hit`` reports).
        options : SolverOptions, optional
            Every solver parameter at once; explicit keywords override it.
        **more
            Any other :class:`~idstlpy.SolverOptions` field (``time_limit``, ``max_candidates``,
            ``sampler_iterations``, ``lazy_candidates``, ``max_plan_length``, back-ends, ...).

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
            options=options,
            **more,
        ).trajectory

    def solve_result(
        self,
        rrt_timeout: float | None = None,
        delta_near: float | None = None,
        delta_drain: float | None = None,
        goal_bias: float | None = None,
        min_num_of_steps: int | None = None,
        max_num_of_steps: int | None = None,
        seed: int | np.random.Generator | None = None,
        *,
        options: object | None = None,
        **more: Any,
    ) -> SolveOutcome:
        """Like :meth:`solve`, but return the full :class:`~idstlpy.SolveResult` (status, reason, statistics).

        Parameters
        ----------
        rrt_timeout, delta_near, delta_drain, goal_bias, min_num_of_steps, max_num_of_steps, seed
            As in :meth:`solve` (``None``: the value in ``options``, or the default).
        options : SolverOptions, optional
            Every solver parameter at once; explicit arguments override it.
        **more
            Any other :class:`~idstlpy.SolverOptions` field.

        Returns
        -------
        SolveResult
            The registered solver's result: :class:`idstlpy.SolveResult` for the package's own
            (:func:`idstlpy.synthesis.problem.solve`, which types it precisely).
        """
        given = {
            "rrt_timeout": rrt_timeout,
            "delta_near": delta_near,
            "delta_drain": delta_drain,
            "goal_bias": goal_bias,
            "min_num_of_steps": min_num_of_steps,
            "max_num_of_steps": max_num_of_steps,
            "seed": seed,
        }
        overrides = {k: v for k, v in given.items() if v is not None}
        overrides.update(more)
        solver = _SOLVER.get("solve")
        if solver is None:  # only when idstlpy.synthesis was never imported (import idstlpy does)
            raise RuntimeError("no solver registered: import idstlpy (it registers the synthesis solver)")
        result = solver(self, options, **overrides)
        self.last_result = result
        return result

    def __repr__(self) -> str:
        return (
            f"Problem(n={self.switched_system.n}, m={self.switched_system.m}, "
            f"modes={self.switched_system.num_modes}, formula={self.stl_formula})"
        )


def _state_variables(formula: STLFormula) -> dict[int, RealValuedVariable]:
    """The variables the formula's chance constraints are written over, by identity."""
    out: dict[int, RealValuedVariable] = {}
    for ap in formula.atomic_propositions():
        for p in ap.predicates:
            out[id(p.variable)] = p.variable
    return out


def _check_roles(formula: STLFormula, control_domain: Polytope) -> None:
    """Refuse a formula over the input variable and a control domain over the state variable."""
    states = _state_variables(formula)
    u = region_variable(control_domain)
    for x in states.values():
        if x.role == "input":
            x.take_role("state", "stl_formula")  # raises, naming the argument
    if u is not None and u.role == "state":
        u.take_role("input", "control_domain")  # raises, naming the argument
    if u is not None and id(u) in states:
        raise InvalidArgumentError(
            f"stl_formula and control_domain are both written over {u.name}: the formula "
            "constrains the state, the control domain the input (two variables, e.g. "
            "x = mk_variable(n) and u = mk_variable(m, name='u'))"
        )


def _take_roles(formula: STLFormula, control_domain: Polytope) -> None:
    """Record the roles of a valid Problem's variables (after :func:`_check_roles`)."""
    for x in _state_variables(formula).values():
        x.take_role("state", "stl_formula")
    u = region_variable(control_domain)
    if u is not None:
        u.take_role("input", "control_domain")
