"""Execute a plan against a simulated plant: Kalman filter plus receding-horizon LQR tracking.

:func:`simulate` is the loop a robot would run with :class:`idstlpy.OnlineExecutor`, with the
plant simulated: every step it asks the executor for the mode and input, moves the true state
with the plant and draws the observation of the planning mode's sensor at it, all by the one
step law of :mod:`idstlpy.executor.law` (see there for the equations)::

    u_k      = proj_U( v_k - K (mean_k - m_k) )                  (LQR correction, K from mode q)
    x_{k+1}  = A^real x_k + B^real u_k + W_q w_k,                 w_k ~ N(0, I)
               (or plant(x_k, u_k, q, rng) [+ W_q w_k] for a step-function plant)
    y_{k+1}  = C_q x_{k+1} + n_q(x_{k+1}) v_{k+1},                v_{k+1} ~ N(0, I)
    mean, cov <- Kalman(predict with mode q and u_k, update with y_{k+1}, noise at predicted mean)
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any, TypedDict, Unpack

import numpy as np
from numpy.typing import ArrayLike

from .._checks import as_int, as_vector
from ..belief import GaussianBelief
from ..dynamical_system import LCS, SwitchedSystem, register_simulator
from ..errors import DimensionError, InvalidArgumentError, InvalidTypeError
from ..executor import ExecutorSpec, OnlineExecutor, PlantStep, ProcessNoise
from ..markov import MarkovSwitching, switching_of
from ..sets import Polytope
from ..tracking import GainsOverride
from ..trajectory import ProbabilisticTSTrajectory, RealTrajectory
from .jumps import roll_jumps

__all__ = ["EXECUTOR_OPTIONS", "simulate"]

logger = logging.getLogger(__name__)


class SimulateOptions(TypedDict, total=False):
    """The executor's keywords of :func:`simulate` (``**options: Unpack[SimulateOptions]``: type
    checkers and editors know them; ``simulate`` checks them at run time)."""

    control_domain: Polytope | None
    process_noise: ProcessNoise
    lqr_gains: GainsOverride
    default_lqr: Mapping[str, Any] | None
    plant: PlantStep | None


EXECUTOR_OPTIONS = tuple(SimulateOptions.__annotations__)
"""The executor's keywords of :func:`simulate` (those of :meth:`ExecutorSpec.make` but the plant's)."""


def simulate(
    system: SwitchedSystem,
    reference_trajectory: ProbabilisticTSTrajectory,
    num_of_steps: int,
    real_initial_state: ArrayLike,
    real_system: SwitchedSystem | LCS | None,
    seed: int | np.random.Generator | np.random.SeedSequence | None = None,
    *,
    initial_belief: GaussianBelief | None = None,
    spec: ExecutorSpec | None = None,
    **options: Unpack[SimulateOptions],
) -> tuple[ProbabilisticTSTrajectory, RealTrajectory]:
    """Execute a plan on a plant with a Kalman filter and receding-horizon LQR tracking.

    Parameters
    ----------
    system : SwitchedSystem
        The planning model (its sensors and noise drive the observations and the filter).
    reference_trajectory : ProbabilisticTSTrajectory
        The plan (``Problem.solve``'s result) with ``N`` steps, state dimension ``n``.
    num_of_steps : int
        Steps to execute, ``0 <= num_of_steps <= N``.
    real_initial_state : array_like, shape (n,)
        True initial state.
    real_system : SwitchedSystem, LCS or None
        The linear system that moves the true state (one mode per planning mode, or a single
        mode); None: the model itself, or the ``plant`` step function (or ``spec``'s plant).
    seed : int, Generator or SeedSequence, optional
        Randomness of the disturbances and measurement noises; the same seed gives the same run.
    initial_belief : GaussianBelief, optional
        Filter prior; default the plan's first belief.
    spec : ExecutorSpec, optional
        The executor as one object (:meth:`idstlpy.executor.ExecutorSpec.make`: control domain,
        process noise, tracking gains, plant), built once and reused over many runs; its system
        must be ``system``. Exclusive with ``real_system`` and the keywords below.
    **options
        The executor's settings as keywords (made into an ``ExecutorSpec`` here):

        - ``control_domain`` (Polytope, optional): admissible inputs (shape ``m``); the
          corrected input is projected on it. ``None`` (the paper's listing) applies it unclipped.
        - ``process_noise`` ({"auto", "model", "real", "none"}): disturbance added to the true
          state: ``"auto"`` (default) the real system's ``W w`` when its modes declare one
          (made by ``mk_lbs``), else the planning mode's; ``"model"`` the planning mode's
          ``W w``, ``"real"`` the real mode's, ``"none"`` none.
        - ``lqr_gains`` (mapping or sequence, optional): per planning mode, a list of gains
          (m, n) overriding ``mode.lqr_gains``.
        - ``default_lqr`` (mapping, optional): weights for modes without gains (see
          :data:`~idstlpy.tracking.DEFAULT_LQR`).
        - ``plant`` (callable, optional): a (nonlinear) plant as a step function ``(state (n,),
          input (m,), mode, rng) -> next state (n,)``, instead of a linear ``real_system`` (which
          must then be None); it draws its own disturbance from ``rng`` (the run's generator),
          ``process_noise="model"`` adds the planning mode's ``W w`` after it, ``"none"`` nothing.

    Returns
    -------
    xi_sim : ProbabilisticTSTrajectory
        The executed belief (filter means (num_of_steps+1, n), covariances, modes, applied inputs).
    xi_real : RealTrajectory
        True states (num_of_steps+1, n), observations (num_of_steps+1, p) with row 0 (and rows
        of unobserved modes) NaN, modes and applied inputs.

    Raises
    ------
    InvalidArgumentError
        When ``reference_trajectory`` is None (no plan) or an option is invalid.
    InvalidTypeError
        For an unknown keyword (the message names it and lists the options) or an argument of
        the wrong type.
    DimensionError
        When dimensions of the plan, the model and the real system disagree.
    """
    N = _check_plan(system, reference_trajectory, num_of_steps)
    x = as_vector(real_initial_state, "real_initial_state", system.n)
    modes = reference_trajectory.get_action()[:N].tolist()
    switching = switching_of(system)
    # under chance switching any mode may execute: the gains of every mode are resolved
    spec = _executor_spec(system, real_system, spec, options, None if switching else modes)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    if switching is not None:
        return _run_jumps(spec, reference_trajectory, N, switching, x, rng, initial_belief)
    executor = OnlineExecutor(spec, reference_trajectory, steps=N)
    executor.reset(initial_belief)
    return _run(executor, reference_trajectory, x, rng)


def _check_plan(system: SwitchedSystem, ref: object, num_of_steps: object) -> int:
    """The number of steps to execute, once the plan and the model are checked."""
    if ref is None:
        raise InvalidArgumentError(
            "reference_trajectory is None: there is no plan to execute "
            "(Problem.solve returned None; see problem.last_result.reason)"
        )
    if not isinstance(ref, ProbabilisticTSTrajectory):
        raise InvalidTypeError(
            f"reference_trajectory must be a ProbabilisticTSTrajectory, got {type(ref).__name__}"
        )
    if not isinstance(system, SwitchedSystem):
        raise InvalidTypeError(f"system must be a SwitchedSystem, got {type(system).__name__}")
    n = system.n
    if ref.n != n:
        raise DimensionError(f"reference_trajectory has state dimension {ref.n}, the system has n = {n}")
    N = as_int(num_of_steps, "num_of_steps", minimum=0)
    if N > ref.num_of_steps:
        raise InvalidArgumentError(
            f"num_of_steps must be <= reference_trajectory.num_of_steps ({ref.num_of_steps}), got {N}"
        )
    return N


def _executor_spec(
    system: SwitchedSystem,
    real_system: SwitchedSystem | LCS | None,
    spec: ExecutorSpec | None,
    options: Mapping[str, Any],
    modes: list[int] | None,
) -> ExecutorSpec:
    """``spec`` checked against ``system``, or the spec of the keyword ``options``."""
    unknown = sorted(set(options) - set(EXECUTOR_OPTIONS))
    if unknown:
        raise InvalidTypeError(
            f"simulate got an unexpected keyword argument {', '.join(map(repr, unknown))}; "
            f"its options are {', '.join(sorted((*EXECUTOR_OPTIONS, 'initial_belief', 'spec')))}"
        )
    if spec is None:
        return ExecutorSpec.make(system, real_system=real_system, modes=modes, **dict(options))
    if not isinstance(spec, ExecutorSpec):
        raise InvalidTypeError(f"spec must be an ExecutorSpec, got {type(spec).__name__}")
    if options or real_system is not None:
        given = sorted([*options, *(["real_system"] if real_system is not None else [])])
        raise InvalidArgumentError(f"give either spec or {given}, not both (set them on the spec)")
    if spec.system is not system:
        raise InvalidArgumentError("spec must be an ExecutorSpec of system (spec.system is another model)")
    return spec


def _run(
    executor: OnlineExecutor, ref: ProbabilisticTSTrajectory, x: np.ndarray, rng: np.random.Generator
) -> tuple[ProbabilisticTSTrajectory, RealTrajectory]:
    """Drive ``executor`` over its steps with the simulated plant from the true state ``x``."""
    law, N, n = executor.law, executor.law.num_of_steps, x.shape[0]
    means = np.empty((N + 1, n))
    covs = np.empty((N + 1, n, n))
    states = np.empty((N + 1, n))
    observations = np.full((N + 1, law.p_max), np.nan)
    controls = np.empty((N, law.spec.system.m))
    means[0], covs[0], states[0] = executor.mean, executor.cov, x
    X = x[None, :]
    for k in range(N):
        _, u = executor.command()
        controls[k] = u
        # True state (the plant), then the sensor of the planning mode at it.
        X = law.plant(k, X, u[None, :], rng)
        Y = law.observe(k, X, rng)
        y = None if Y is None else Y[0]
        if not (np.isfinite(X).all() and (y is None or np.isfinite(y).all())):
            raise InvalidArgumentError(f"the execution diverged at step {k + 1} (non-finite state)")
        if y is not None:
            observations[k + 1, : y.shape[0]] = y
        executor.observe(y)
        means[k + 1], covs[k + 1], states[k + 1] = executor.mean, executor.cov, X[0]
        if not np.isfinite(means[k + 1]).all():
            raise InvalidArgumentError(f"the execution diverged at step {k + 1} (non-finite state)")
    logger.debug("simulate: %d steps, final error %s", N, states[-1] - means[-1])
    actions = ref.get_action()[:N]
    xi_sim = ProbabilisticTSTrajectory(means, covs, actions, controls)
    xi_real = RealTrajectory(states, observations, actions, controls)
    return xi_sim, xi_real


def _run_jumps(
    spec: ExecutorSpec,
    ref: ProbabilisticTSTrajectory,
    N: int,
    switching: MarkovSwitching,
    x: np.ndarray,
    rng: np.random.Generator,
    initial_belief: GaussianBelief | None,
) -> tuple[ProbabilisticTSTrajectory, RealTrajectory]:
    """One run under chance switching (:mod:`idstlpy.execution.jumps`): the executed modes are
    drawn first from ``rng``; ``xi_real``'s modes are the executed ones, ``xi_sim``'s the plan's."""
    mean = None if initial_belief is None else initial_belief.mean
    cov = None if initial_belief is None else initial_belief.cov
    r = roll_jumps(spec, ref, N, switching, x[None, :], rng, keep=1, initial_mean=mean, initial_cov=cov)
    actions = ref.get_action()[:N]
    controls = r.controls[:, 0]
    xi_sim = ProbabilisticTSTrajectory(r.means[:, 0], r.covs[:, 0], actions, controls)
    xi_real = RealTrajectory(r.states[:, 0], r.observations[:, 0], r.executed[0], controls)
    logger.debug("simulate: %d steps under chance switching, executed modes %s", N, r.executed[0].tolist())
    return xi_sim, xi_real


register_simulator(simulate)  # the paper's switched_system.simulate(...) (see dynamical_system)
