"""Reading :func:`~idstlpy.executor.predict.predict_closed_loop`'s arguments.

The problem or system, the plan and the steps predicted, the executor's settings (an
:class:`~idstlpy.executor.spec.ExecutorSpec` or the keywords ``simulate`` takes), the closure's
settings and the loop's start, each checked with an error naming the argument.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, TypedDict

import numpy as np
from numpy.typing import ArrayLike

from .._checks import as_covariance, as_int, as_vector
from ..belief import GaussianBelief
from ..closed_loop import gains_for, real_modes_for
from ..dynamical_system import LCS, SwitchedSystem
from ..errors import DimensionError, InvalidArgumentError, InvalidTypeError
from ..formulas import STLFormula
from ..problem import Problem
from ..sets import Polytope
from ..tracking import GainsOverride
from ..trajectory import ProbabilisticTSTrajectory
from .spec import ExecutorSpec, ProcessNoise, resolve_process_noise

__all__ = [
    "Closure",
    "EXECUTOR_DEFAULTS",
    "LoopSettings",
    "OPTION_DEFAULTS",
    "PredictOptions",
    "SensorNoise",
    "check_closure",
    "executor_parts",
    "plan_steps",
    "resolve",
    "start_of",
    "with_defaults",
]

SensorNoise = Literal["expected", "mean", "plan"]
Closure = Literal["auto", "gaussian", "particles"]


class PredictOptions(TypedDict, total=False):
    """The keywords of :func:`predict_closed_loop` besides its named parameters
    (``**options: Unpack[PredictOptions]``: type checkers and editors know them;
    ``predict_closed_loop`` checks them at run time). Documented there."""

    control_domain: Polytope | None | str
    process_noise: ProcessNoise
    lqr_gains: GainsOverride
    default_lqr: Mapping[str, Any] | None
    initial_belief: GaussianBelief | None
    real_initial_cov: ArrayLike | None
    sensor_noise: SensorNoise
    filter_sensitivity: bool
    closure: Closure
    particles: int


OPTION_DEFAULTS: dict[str, Any] = {
    "control_domain": "problem",
    "process_noise": "auto",
    "lqr_gains": None,
    "default_lqr": None,
    "initial_belief": None,
    "real_initial_cov": None,
    "sensor_noise": "expected",
    "filter_sensitivity": True,
    "closure": "auto",
    "particles": 4000,
}
"""Every :class:`PredictOptions` keyword's default."""


def resolve(
    problem_or_system: Problem | SwitchedSystem,
    formula: STLFormula | None,
    control_domain: Polytope | None | str,
) -> tuple[SwitchedSystem, STLFormula | None, Polytope | None]:
    if isinstance(problem_or_system, Problem):
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


def with_defaults(options: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword options with their defaults; an unknown keyword is an error naming it."""
    unknown = sorted(set(options) - set(OPTION_DEFAULTS))
    if unknown:
        names = sorted((*OPTION_DEFAULTS, "formula", "num_of_steps", "samples", "seed", "executor"))
        raise InvalidTypeError(
            f"predict_closed_loop got an unexpected keyword argument {', '.join(map(repr, unknown))}; "
            f"its options are {', '.join(names)}"
        )
    return {**OPTION_DEFAULTS, **options}


def plan_steps(system: SwitchedSystem, plan: object, num_of_steps: object) -> tuple[int, np.ndarray]:
    """The steps predicted and the plan's modes over them, checked against the system."""
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
    return N, actions


@dataclass(frozen=True)
class LoopSettings:
    """How the closed loop is propagated (:func:`idstlpy.closed_loop.propagate`'s settings)."""

    real_modes: list[LCS]
    gains: Mapping[int, Sequence[np.ndarray]]
    process_noise: str
    domain: Polytope | None
    sensor_noise: str
    filter_sensitivity: bool
    closure: str
    particles: int


def check_closure(
    sensor_noise: object, filter_sensitivity: object, closure: object, particles: object
) -> int:
    """Validate the closure's settings; the number of particles."""
    if sensor_noise not in ("expected", "mean", "plan"):
        raise InvalidArgumentError(f"sensor_noise must be 'expected', 'mean' or 'plan', got {sensor_noise!r}")
    if not isinstance(filter_sensitivity, bool):
        raise InvalidTypeError(f"filter_sensitivity must be a bool, got {type(filter_sensitivity).__name__}")
    count: int = as_int(particles, "particles", minimum=2)
    if closure not in ("auto", "gaussian", "particles"):
        raise InvalidArgumentError(f"closure must be 'auto', 'gaussian' or 'particles', got {closure!r}")
    return count


def executor_parts(
    system: SwitchedSystem,
    actions: np.ndarray,
    executor: ExecutorSpec | None,
    keywords: Mapping[str, Any],
    domain: Polytope | None,
    plan: ProbabilisticTSTrajectory | None = None,
) -> tuple[list[LCS], Mapping[int, Sequence[np.ndarray]], str, Polytope | None]:
    """The real modes, tracking gains, process-noise reading and control domain of the loop.

    From ``executor`` when given (its gains resolved once), else from the executor keywords
    (``real_system``, ``process_noise``, ``lqr_gains``, ``default_lqr``; ``domain`` already read
    off ``control_domain``; modes without gains take those ``plan`` was made for).
    """
    if executor is None:
        process_noise = resolve_process_noise(keywords["process_noise"], keywords["real_system"])
        real_modes = real_modes_for(keywords["real_system"], system, actions)
        gains = gains_for(system, actions, keywords["lqr_gains"], keywords["default_lqr"], plan)
        return real_modes, gains, process_noise, domain
    if not isinstance(executor, ExecutorSpec):
        raise InvalidTypeError(f"executor must be an ExecutorSpec, got {type(executor).__name__}")
    # a keyword left at its default (the same object, or the same string) is not "given"
    given = sorted(
        k
        for k, v in keywords.items()
        if v is not EXECUTOR_DEFAULTS[k] and not (isinstance(v, str) and v == EXECUTOR_DEFAULTS[k])
    )
    if given:
        raise InvalidArgumentError(f"give either executor or the executor keywords {given}, not both")
    if executor.system is not system:
        raise InvalidArgumentError("executor.system must be the planning model the plan is predicted on")
    if executor.real_modes is None:
        raise InvalidArgumentError(
            "executor: a plant given as a step function cannot be predicted (the prediction is "
            "the linear closed loop; give a linear real_system)"
        )
    executor.check_plan_modes(actions)
    chosen = executor.gains if plan is None else executor.gains_for(plan)
    return list(executor.real_modes), chosen, executor.process_noise, executor.control_domain


EXECUTOR_DEFAULTS: dict[str, Any] = {
    "real_system": None,
    "control_domain": "problem",
    "process_noise": "auto",
    "lqr_gains": None,
    "default_lqr": None,
}
"""The executor keywords' defaults: an ``executor`` excludes any other value."""


def start_of(
    plan: ProbabilisticTSTrajectory,
    n: int,
    real_initial_state: ArrayLike | None,
    initial_belief: GaussianBelief | None,
    real_initial_cov: ArrayLike | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The loop's start: the mean ``z0`` (2n,) and covariance ``S0`` of ``(delta_0, eta_0)`` and
    the filter's prior covariance ``P0``."""
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
    return np.concatenate([x0 - m0, b0 - m0]), S0, P0.copy()
