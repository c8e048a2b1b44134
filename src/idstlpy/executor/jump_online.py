"""The online executor under chance switching: a robot's loop that is told the executed mode.

:class:`JumpExecutor` is :class:`~idstlpy.executor.OnlineExecutor` for a system with a
:class:`~idstlpy.markov.MarkovSwitching` (:func:`~idstlpy.markov.with_switching`): when the
executed mode is observed, each step is given it (``step(observation, executed=s)``) and the
executor tracks with the gain of ``s`` and filters with the model of ``s``; when it is not, the
commanded mode's (the argument is then ignored). The arithmetic is that of
:func:`~idstlpy.executor.jump_law.roll_executed` for one run, so :func:`idstlpy.simulate`'s run
with jumps is this loop with a simulated plant (a test checks it bit for bit).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._checks import as_int, as_vector
from ..belief import GaussianBelief
from ..dynamical_system import SwitchedSystem
from ..errors import InvalidArgumentError, InvalidTypeError
from ..markov import switching_of
from ..problem import Problem
from ..trajectory import ProbabilisticTSTrajectory
from .jump_law import check_unobserved, mode_laws
from .spec import ExecutorSpec

__all__ = ["JumpExecutor"]


class JumpExecutor:
    """Executes a plan one observation at a time under chance switching (module notes).

    Parameters
    ----------
    source : Problem, SwitchedSystem or ExecutorSpec
        What runs the plan; its system must carry a chance switching. A Problem gives its
        control domain (unless ``control_domain`` is given).
    plan : ProbabilisticTSTrajectory
        The plan (``N`` steps): commanded modes, means and inputs.
    steps : int, optional
        Execute only the first ``steps <= N`` steps.
    **options
        Keywords of :meth:`ExecutorSpec.make` (not with an ``ExecutorSpec``); the gains of every
        mode are resolved (any mode may execute).

    Raises
    ------
    InvalidArgumentError
        When the system has no chance switching, or an argument is invalid.
    InvalidTypeError
        When an argument has the wrong type.
    """

    def __init__(
        self,
        source: Problem | SwitchedSystem | ExecutorSpec,
        plan: ProbabilisticTSTrajectory,
        *,
        steps: int | None = None,
        **options: Any,
    ) -> None:
        if not isinstance(plan, ProbabilisticTSTrajectory):
            raise InvalidTypeError(f"plan must be a ProbabilisticTSTrajectory, got {type(plan).__name__}")
        if isinstance(source, ExecutorSpec):
            if options:
                raise InvalidArgumentError(f"options {sorted(options)} are given twice: set them on the spec")
            spec = source
        elif isinstance(source, Problem):
            options.setdefault("control_domain", source.control_domain)
            spec = ExecutorSpec.make(source.switched_system, **options)
        elif isinstance(source, SwitchedSystem):
            spec = ExecutorSpec.make(source, **options)
        else:
            raise InvalidTypeError(
                f"source must be a Problem, a SwitchedSystem or an ExecutorSpec, got {type(source).__name__}"
            )
        switching = switching_of(spec.system)
        if switching is None:
            raise InvalidArgumentError(
                "source: the system has no chance switching (stl.with_switching); use OnlineExecutor"
            )
        if not switching.observed:
            check_unobserved(spec)
        self.spec = spec
        self.observed = switching.observed
        N = (
            plan.num_of_steps
            if steps is None
            else as_int(steps, "steps", minimum=0, maximum=plan.num_of_steps)
        )
        self.num_of_steps = N
        self.laws = mode_laws(spec, plan, N)
        self._plan = plan
        self._commanded = plan.get_action()[:N]
        self.reset()

    def reset(self, initial_belief: GaussianBelief | None = None) -> None:
        """Start over at step 0 from ``initial_belief`` (default the plan's first belief)."""
        b = initial_belief
        self.mean = np.array(self._plan.get_mean(0) if b is None else b.mean, dtype=float)
        self.cov = np.array(self._plan.get_cov(0) if b is None else b.cov, dtype=float)
        self.k = 0
        self._pending: tuple[int, np.ndarray] | None = None

    @property
    def done(self) -> bool:
        """True once every step was commanded and observed."""
        return self.k >= self.num_of_steps and self._pending is None

    def _law_mode(self, executed: int | None) -> int:
        q = int(self._commanded[self.k])
        if not self.observed:
            return q  # (the executor believes its command)
        if executed is None:
            raise InvalidArgumentError(
                "executed: the executed mode is observed under this switching; give the mode of this step"
            )
        return as_int(executed, "executed", minimum=0, maximum=self.spec.system.num_modes - 1)

    def command(self, executed: int | None = None) -> tuple[int, np.ndarray]:
        """The commanded mode and the input (m,) of the current step, given its executed mode."""
        if self._pending is not None:
            raise InvalidArgumentError("command: the last input's observation is pending (call observe)")
        if self.k >= self.num_of_steps:
            raise InvalidArgumentError(f"command: all {self.num_of_steps} steps were executed")
        j = self._law_mode(executed)
        u = self.laws[j].control(self.k, self.mean[None, :])[0]
        self._pending = (j, u)
        return int(self._commanded[self.k]), u

    def observe(self, observation: ArrayLike | None) -> None:
        """Filter the observation (p,) that followed the last input (None when none came)."""
        if self._pending is None:
            raise InvalidArgumentError("observe: no input was commanded since the last observation")
        j, u = self._pending
        law = self.laws[j]
        Y = None
        if observation is not None and law.steps[self.k].model.p:
            Y = as_vector(observation, "observation", law.steps[self.k].model.p)[None, :]
        M, P = law.filter(self.k, self.mean[None, :], self.cov, u[None, :], Y)
        self.mean, self.cov = M[0], P
        self.k += 1
        self._pending = None

    def step(
        self, observation: ArrayLike | None = None, executed: int | None = None
    ) -> tuple[int, np.ndarray]:
        """Filter ``observation`` (when an input is pending), then :meth:`command` the next step."""
        if self._pending is not None:
            self.observe(observation)
        return self.command(executed)
