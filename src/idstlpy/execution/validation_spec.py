"""What a Monte Carlo validation runs, checked once: :class:`ValidationSpec` and :class:`Dispatch`.

:func:`idstlpy.validate` takes its settings as keywords (the paper's spelling); they are checked
here, every error naming its argument, and packed into frozen objects that the rest of the
validation reads:

- :class:`ValidationSpec`: what is measured (the plan, the runs and their seeds, the true starts,
  the executor as one :class:`~idstlpy.executor.ExecutorSpec`, the re-planning policy as one
  :class:`~idstlpy.execution.policy.ReplanPolicy`, the prediction, the execution target);
- :class:`Dispatch`: where the runs execute (an executor, the default pool's workers, a problem
  factory for process pools, a progress callback).

``replan`` and ``replan_options`` (a mapping of ``execute``'s keywords) are the spelling of earlier
versions: still accepted, with a ``DeprecationWarning``, in favour of ``policy=ReplanPolicy(...)``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any, TypedDict

import numpy as np
from numpy.typing import ArrayLike

from .._checks import as_int, as_seed_sequence
from ..dynamical_system import LCS, SwitchedSystem
from ..errors import InvalidArgumentError, InvalidTypeError
from ..execution_target import DEFAULT_EXECUTION_TARGET, ExecutionTarget, as_execution_target
from ..executor import ExecutorSpec, PlantStep, ProcessNoise
from ..synthesis.problem import Problem
from ..tracking import GainsOverride
from ..trajectory import ProbabilisticTSTrajectory
from .batches import Payload
from .policy import POLICY_KEYWORDS, ReplanPolicy, ReplanTrigger
from .simulation import simulate
from .starts import true_starts

__all__ = [
    "Dispatch",
    "PREDICT_OPTIONS",
    "REPLAN_OPTION_KEYS",
    "VALIDATE_OPTIONS",
    "ValidationSpec",
]


class ValidateOptions(TypedDict, total=False):
    """The keywords of :func:`~idstlpy.validate` (``**options: Unpack[ValidateOptions]``: type
    checkers and editors know them; :func:`check_options` checks them at run time)."""

    num_of_steps: int | None
    clip_controls: bool
    process_noise: ProcessNoise
    lqr_gains: GainsOverride
    default_lqr: Mapping[str, Any] | None
    plant: PlantStep | None
    problem_factory: Callable[[], Problem] | None
    max_workers: int
    keep_trajectories: int
    progress: Callable[[int, int], None] | None
    predict: bool
    predict_options: Mapping[str, Any] | None
    policy: ReplanPolicy | None
    execution_target: ExecutionTarget | Sequence[float] | Mapping[str, float] | None
    batched: bool
    replan: ReplanTrigger | None  # deprecated: policy
    replan_options: Mapping[str, Any] | None  # deprecated: policy


DEPRECATED_OPTIONS = frozenset({"replan", "replan_options"})
"""``validate``'s keywords of earlier versions, still accepted with a ``DeprecationWarning``."""

VALIDATE_OPTIONS = frozenset(ValidateOptions.__optional_keys__) - DEPRECATED_OPTIONS
"""The keywords :func:`~idstlpy.validate` accepts (besides its positional arguments)."""

REPLAN_OPTION_KEYS = POLICY_KEYWORDS
"""Keys ``replan_options`` accepts (the execution options are validate's own); problem files'
``[validation.replan_options]`` reads the same keys but ``options`` (their ``[solver]``)."""

PREDICT_OPTIONS = ("sensor_noise", "filter_sensitivity", "samples", "seed", "closure", "particles")
"""Keys ``predict_options`` accepts (the rest of the prediction's options are validate's own)."""


@dataclass(frozen=True)
class Dispatch:
    """Where the runs of a validation execute (checked; frozen).

    Attributes
    ----------
    executor : concurrent.futures.Executor, "serial" or None
        ``validate``'s ``executor``.
    max_workers : int
        Workers of the default process pool (>= 1).
    problem_factory : callable or None
        Rebuilds the problem in a worker when it cannot be pickled.
    progress : callable or None
        ``progress(done, runs)`` after every batch.
    """

    executor: Executor | str | None = None
    max_workers: int = 2
    problem_factory: Callable[[], Problem] | None = None
    progress: Callable[[int, int], None] | None = None


@dataclass(frozen=True)
class ValidationSpec:
    """What a validation measures: ``validate``'s arguments, checked and resolved (frozen).

    Build it with :meth:`make`; :func:`~idstlpy.validate` does.

    Attributes
    ----------
    problem : Problem
        The problem the plan solves.
    plan : ProbabilisticTSTrajectory
        The plan executed.
    real_system : SwitchedSystem, LCS or None
        The linear plant (None: the model, or the executor's plant).
    seeds : tuple of SeedSequence
        One per run: child ``i`` of the root ``SeedSequence(seed)``.
    root : numpy.random.SeedSequence
        The root of the seeds (and of the drawn starts).
    num_of_steps : int
        Steps per run.
    start : ndarray, shape (n,)
        The fixed true start, or the prior's mean when the starts are drawn.
    starts : ndarray of shape (runs, n), or None
        The runs' true starts drawn from the prior; None for a fixed start.
    executor : ExecutorSpec
        What runs the plan (control domain, process noise, tracking gains of every mode, plant).
    policy : ReplanPolicy or None
        The runs' re-planning (None: they follow the plan).
    predict : bool
        Whether the execution is also predicted.
    predict_options : mapping
        Further options of the prediction (:data:`PREDICT_OPTIONS`).
    keep_trajectories : int
        Runs whose trajectories the report keeps.
    batched : bool
        Runs executed together as arrays.
    execution_target : ExecutionTarget
        What the verdict is against.
    """

    problem: Problem
    plan: ProbabilisticTSTrajectory
    real_system: SwitchedSystem | LCS | None
    seeds: tuple[np.random.SeedSequence, ...]
    root: np.random.SeedSequence
    num_of_steps: int
    start: np.ndarray
    starts: np.ndarray | None
    executor: ExecutorSpec
    policy: ReplanPolicy | None = None
    predict: bool = False
    predict_options: Mapping[str, Any] = field(default_factory=dict)
    keep_trajectories: int = 0
    batched: bool = True
    execution_target: ExecutionTarget = DEFAULT_EXECUTION_TARGET

    @property
    def runs(self) -> int:
        """Number of executions."""
        return len(self.seeds)

    @classmethod
    def make(
        cls,
        problem: Problem,
        solution: ProbabilisticTSTrajectory,
        real_system: SwitchedSystem | LCS | None,
        real_initial_state: ArrayLike | str | None,
        runs: int,
        seed: int | np.random.SeedSequence | None,
        executor: Executor | str | None,
        options: Mapping[str, Any],
    ) -> tuple[ValidationSpec, Dispatch]:
        """Check ``validate``'s arguments (errors name the argument) and resolve them once.

        Parameters
        ----------
        problem, solution, real_system, real_initial_state, runs, seed, executor
            ``validate``'s positional arguments.
        options : mapping
            ``validate``'s keywords (:data:`VALIDATE_OPTIONS`; ``replan`` and ``replan_options``
            must have been turned into ``policy`` by :func:`policy_of`).

        Returns
        -------
        (ValidationSpec, Dispatch)

        Raises
        ------
        InvalidTypeError, InvalidArgumentError, DimensionError
            Naming the argument that is wrong.
        """
        _check_plan(problem, solution)
        opts = dict(options)
        runs = as_int(runs, "runs", minimum=1)
        dispatch = _dispatch(executor, opts)
        keep = as_int(opts.get("keep_trajectories", 0), "keep_trajectories", minimum=0)
        num_of_steps = opts.get("num_of_steps")
        steps = (
            solution.num_of_steps if num_of_steps is None else as_int(num_of_steps, "num_of_steps", minimum=0)
        )
        target = as_execution_target(opts.get("execution_target"))
        root = as_seed_sequence(seed)
        seeds = tuple(root.spawn(runs))
        system = problem.switched_system
        predict = bool(opts.get("predict", False))
        spec = _executor_spec(problem, real_system, opts, predict)
        start, starts = true_starts(real_initial_state, solution, runs, root, system.n)
        # Validate the plan against the model and the start once, with one short run.
        simulate(system, solution, min(steps, 1), start, None, seed=0, spec=spec)
        policy = _policy(opts.get("policy"), num_of_steps, solution)
        batched = opts.get("batched", True)
        if not isinstance(batched, bool):
            raise InvalidTypeError(f"batched must be True or False, got {type(batched).__name__}")
        predict_options = _predict_options(opts.get("predict_options")) if predict else {}
        made = cls(
            problem=problem,
            plan=solution,
            real_system=real_system,
            seeds=seeds,
            root=root,
            num_of_steps=steps,
            start=start,
            starts=starts,
            executor=spec,
            policy=policy,
            predict=predict,
            predict_options=predict_options,
            keep_trajectories=keep,
            batched=batched,
            execution_target=target,
        )
        return made, dispatch

    def payload(self, batch_size: int) -> Payload:
        """What a worker needs to execute runs (:class:`~idstlpy.execution.batches.Payload`)."""
        spec = self.executor
        return Payload(
            system=spec.system,
            formula=self.problem.stl_formula,
            factory=None,
            plan=self.plan,
            real_system=self.real_system,
            real_initial_state=self.start,
            num_of_steps=self.num_of_steps,
            control_domain=spec.control_domain,
            process_noise=spec.process_noise,
            gains=self.gains(),
            plant=spec.plant_step,
            keep=self.keep_trajectories,
            problem=self.problem if self.policy is not None else None,
            policy=self.policy,
            batched=self.batched,
            batch_size=batch_size,
        )

    def gains(self) -> tuple[list[np.ndarray], ...]:
        """The tracking gains of every mode, in mode order (modes nobody chose gains for: the
        plan's own, :meth:`~idstlpy.executor.ExecutorSpec.gains_for`)."""
        gains = self.executor.gains_for(self.plan)
        return tuple(list(gains[q]) for q in range(self.executor.system.num_modes))


def _check_plan(problem: object, solution: object) -> None:
    if not isinstance(problem, Problem):
        raise InvalidTypeError(f"problem must be a Problem, got {type(problem).__name__}")
    if solution is None:
        raise InvalidArgumentError(
            "solution is None: there is no plan to validate (see problem.last_result.reason)"
        )
    if not isinstance(solution, ProbabilisticTSTrajectory):
        raise InvalidTypeError(f"solution must be a ProbabilisticTSTrajectory, got {type(solution).__name__}")


def _executor_spec(
    problem: Problem,
    real_system: SwitchedSystem | LCS | None,
    opts: Mapping[str, Any],
    predict: bool,
) -> ExecutorSpec:
    """The executor of ``validate``'s keywords (``clip_controls``: the problem's domain, or none)."""
    spec = ExecutorSpec.make(
        problem.switched_system,
        control_domain=problem.control_domain if opts.get("clip_controls", True) else None,
        process_noise=opts.get("process_noise", "auto"),
        lqr_gains=opts.get("lqr_gains"),
        default_lqr=opts.get("default_lqr"),
        real_system=real_system,
        plant=opts.get("plant"),
    )
    if spec.plant_step is not None and predict:
        raise InvalidArgumentError(
            "predict needs a linear real_system: the prediction cannot follow a plant function"
        )
    return spec


def _policy(policy: object, num_of_steps: object, solution: ProbabilisticTSTrajectory) -> ReplanPolicy | None:
    if policy is None:
        return None
    if not isinstance(policy, ReplanPolicy):
        raise InvalidTypeError(f"policy must be a ReplanPolicy, got {type(policy).__name__}")
    if num_of_steps is not None and num_of_steps != solution.num_of_steps:
        raise InvalidArgumentError(
            "num_of_steps cannot be combined with a re-planning policy (replan): a re-planned run follows "
            "its plans to their end"
        )
    return policy


def _dispatch(executor: object, opts: Mapping[str, Any]) -> Dispatch:
    max_workers = as_int(opts.get("max_workers", 2), "max_workers", minimum=1)
    if isinstance(executor, str) and executor != "serial":
        raise InvalidArgumentError(f"executor must be an Executor, 'serial' or None, got {executor!r}")
    if executor is not None and not isinstance(executor, Executor | str):
        raise InvalidTypeError(
            f"executor must be a concurrent.futures.Executor, got {type(executor).__name__}"
        )
    factory, progress = opts.get("problem_factory"), opts.get("progress")
    for name, value in (("problem_factory", factory), ("progress", progress)):
        if value is not None and not callable(value):
            raise InvalidTypeError(f"{name} must be callable, got {type(value).__name__}")
    return Dispatch(executor, max_workers, factory, progress)


def _predict_options(options: object) -> dict[str, Any]:
    if options is not None and not isinstance(options, Mapping):
        raise InvalidTypeError(f"predict_options must be a mapping, got {type(options).__name__}")
    opts = dict(options or {})
    unknown = sorted(set(opts) - set(PREDICT_OPTIONS))
    if unknown:
        raise InvalidArgumentError(
            f"predict_options: unknown or execution keys {unknown}; accepted: {', '.join(PREDICT_OPTIONS)} "
            "(the execution options are validate's own)"
        )
    return opts


def check_options(options: Mapping[str, Any]) -> None:
    """Raise :class:`InvalidTypeError` naming any keyword ``validate`` does not take."""
    unknown = sorted(set(options) - VALIDATE_OPTIONS - DEPRECATED_OPTIONS)
    if unknown:
        raise InvalidTypeError(
            f"validate got an unexpected keyword argument {', '.join(map(repr, unknown))}; "
            f"its options are {', '.join(sorted(VALIDATE_OPTIONS))}"
        )


def policy_of(options: Mapping[str, Any], stacklevel: int) -> dict[str, Any]:
    """``options`` checked (:func:`check_options`), the deprecated ``replan`` / ``replan_options``
    made into ``policy`` (with a ``DeprecationWarning``).

    Parameters
    ----------
    options : mapping
        ``validate``'s keywords.
    stacklevel : int
        The warning's stack level (the user's call of ``validate``).

    Returns
    -------
    dict
        The keywords with ``policy`` in place of the deprecated ones.

    Raises
    ------
    InvalidArgumentError, InvalidTypeError
        For an unknown keyword, a bad ``replan`` or ``replan_options`` (the message names it), or
        when ``policy`` is given too.
    """
    check_options(options)
    opts = dict(options)
    legacy = {k: opts.pop(k) for k in sorted(DEPRECATED_OPTIONS & set(opts))}
    if all(v is None for v in legacy.values()):  # (an explicit None changes nothing: no warning)
        return opts
    warnings.warn(
        f"validate({', '.join(f'{k}=...' for k in legacy)}) is deprecated: pass policy=ReplanPolicy(...) "
        "(replan -> trigger; the keys of replan_options are its fields, options and solver_options -> "
        "solver, a SolverOptions)",
        DeprecationWarning,
        stacklevel=stacklevel + 1,
    )
    if opts.get("policy") is not None:
        raise InvalidArgumentError(f"give either policy or {sorted(legacy)}, not both")
    replan, replan_options = legacy.get("replan"), legacy.get("replan_options")
    if replan not in ("on_risk", "every"):
        raise InvalidArgumentError(
            f"replan must be None, 'on_risk' or 'every' (with replan_options), got {replan!r}"
        )
    if replan_options is not None and not isinstance(replan_options, Mapping):
        raise InvalidTypeError(f"replan_options must be a mapping, got {type(replan_options).__name__}")
    unknown = sorted(set(replan_options or {}) - REPLAN_OPTION_KEYS)
    if unknown:
        raise InvalidArgumentError(
            f"replan_options has unknown keys {unknown}; accepted: {sorted(REPLAN_OPTION_KEYS)}"
        )
    opts["policy"] = ReplanPolicy.from_keywords(replan, **dict(replan_options or {}))
    return opts
