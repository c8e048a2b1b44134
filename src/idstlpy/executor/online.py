"""The executor a user drives from their own loop: one observation in, the next mode and input out.

:class:`OnlineExecutor` runs a plan on a real robot (or a simulator): it owns the belief (a
Kalman filter of the planning model) and the tracking law, but not the true state. Each control
period the user's loop reads the sensor, calls :meth:`OnlineExecutor.step` with the observation
and applies the returned mode and input::

    executor = OnlineExecutor(problem, plan)      # or (system, plan, control_domain=...)
    executor.reset()                              # prior: the plan's first belief
    observation = None                            # nothing observed before the first input
    while not executor.done:
        mode, u = executor.step(observation)      # filter update, then the tracking law
        robot.switch_sensor(mode); robot.apply(u)
        observation = robot.read_sensor()         # y_{k+1}: mode's sensor (None if blind)
    executor.observe(observation)                 # the final belief, after the last input

:func:`idstlpy.simulate` is this loop with a simulated plant (the same
:class:`~idstlpy.executor.law.StepLaw`), so a robot running this object executes exactly what
simulation, validation and the planner's predictions assume.

Re-planning: :class:`idstlpy.ReplanningExecutor` (:mod:`idstlpy.execution.replanner`, a layer
up: it calls the solver) is this object plus the drift and risk checks and the re-solves of
:func:`idstlpy.execute`, with the same ``step`` / ``observe`` loop.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..belief import GaussianBelief
from ..dynamical_system import SwitchedSystem
from ..errors import DimensionError, InvalidArgumentError, InvalidTypeError
from ..problem import Problem
from ..trajectory import ProbabilisticTSTrajectory
from .law import StepLaw
from .spec import ExecutorSpec

__all__ = ["OnlineExecutor"]


class OnlineExecutor:
    """Executes a plan one observation at a time (Kalman filter plus receding-horizon LQR).

    Parameters
    ----------
    source : Problem, SwitchedSystem or ExecutorSpec
        What runs the plan. A :class:`~idstlpy.problem.Problem` gives its switched system and
        (unless ``control_domain`` is given) its control domain; a ``SwitchedSystem`` is used with
        ``**options``; an :class:`~idstlpy.executor.spec.ExecutorSpec` as it is.
    plan : ProbabilisticTSTrajectory
        The plan (``N`` steps): modes, means and inputs to track.
    steps : int, optional
        Execute only the first ``steps <= N`` steps (the gains still see the whole plan's
        horizon); default ``N``.
    **options
        Keywords of :meth:`ExecutorSpec.make` (``control_domain``, ``process_noise``,
        ``lqr_gains``, ``default_lqr``, ``real_system``, ``plant``); only with a problem or a
        system. The plant and process noise matter only to :func:`idstlpy.simulate`: this object
        never moves a true state.

    Attributes
    ----------
    spec : ExecutorSpec
    law : StepLaw
        The step law bound to the plan.

    Raises
    ------
    InvalidArgumentError, InvalidTypeError, DimensionError
        Naming the argument that is wrong.

    Notes
    -----
    Cost per step without re-plans: a median of about 45 microseconds for the paper's 2-D
    light-dark system, 27 with a constant sensor noise
    (``benchmarks/executor_step.py``).
    """

    def __init__(
        self,
        source: Problem | SwitchedSystem | ExecutorSpec,
        plan: ProbabilisticTSTrajectory,
        *,
        steps: int | None = None,
        **options: Any,
    ) -> None:
        if plan is None:
            raise InvalidArgumentError(
                "plan is None: there is no plan to execute (Problem.solve returned None; see "
                "problem.last_result.reason)"
            )
        if not isinstance(plan, ProbabilisticTSTrajectory):
            raise InvalidTypeError(f"plan must be a ProbabilisticTSTrajectory, got {type(plan).__name__}")
        if isinstance(source, ExecutorSpec):
            if options:
                raise InvalidArgumentError(
                    f"options {sorted(options)} are given twice: with an ExecutorSpec, set them on the spec"
                )
            spec = source
        elif isinstance(source, SwitchedSystem):
            spec = ExecutorSpec.make(source, **options)
        elif isinstance(source, Problem):
            options.setdefault("control_domain", source.control_domain)
            spec = ExecutorSpec.make(source.switched_system, **options)
        else:
            raise InvalidTypeError(
                f"source must be a Problem, a SwitchedSystem or an ExecutorSpec, got {type(source).__name__}"
            )
        self.spec = spec
        self.law = StepLaw(spec, plan, steps)
        self._plan = plan
        self._n = spec.system.n
        self.reset()

    # -- state ---------------------------------------------------------------------------------

    def reset(self, initial_belief: GaussianBelief | None = None, start: int = 0) -> None:
        """Start (again) at the plan's step ``start`` (0 by default).

        Parameters
        ----------
        initial_belief : GaussianBelief, optional
            The filter's prior (dimension ``n``); default the plan's belief at step ``start``.
        start : int
            The plan step of the first input (``0 <= start <= N``): a re-planning executor that
            adopts a plan some steps after the belief it was solved from follows it from there.

        Raises
        ------
        DimensionError
            When ``initial_belief`` is not a GaussianBelief of dimension ``n``.
        InvalidArgumentError
            When ``start`` is outside ``0 .. N``.
        """
        if isinstance(start, bool) or not isinstance(start, int | np.integer):
            raise InvalidTypeError(f"start must be an integer, got {type(start).__name__}")
        if not 0 <= start <= self.law.num_of_steps:
            raise InvalidArgumentError(f"start must lie in 0..{self.law.num_of_steps}, got {start}")
        if initial_belief is None:
            mean, cov = self._plan.get_mean(int(start)).copy(), self._plan.get_cov(int(start)).copy()
        else:
            if not isinstance(initial_belief, GaussianBelief) or initial_belief.n != self._n:
                raise DimensionError(f"initial_belief must be a GaussianBelief of dimension {self._n}")
            mean, cov = initial_belief.mean.copy(), initial_belief.cov.copy()
        self._mean = mean[None, :]
        self._cov = cov
        self._k = int(start)
        self._input: np.ndarray | None = None  # the input issued whose observation is pending

    @property
    def k(self) -> int:
        """Inputs issued so far (the plan step of the next input)."""
        return self._k

    @property
    def done(self) -> bool:
        """True once the plan's ``N`` inputs have been issued."""
        return self._k >= self.law.num_of_steps

    @property
    def pending(self) -> bool:
        """True when an input was issued and its observation not yet given (:meth:`observe`)."""
        return self._input is not None

    @property
    def belief(self) -> GaussianBelief:
        """The current belief: mean (n,) and covariance (n, n) (copies)."""
        return GaussianBelief(self._mean[0].copy(), self._cov.copy())

    @property
    def mean(self) -> np.ndarray:
        """The current filter mean, shape (n,) (read-only view)."""
        view: np.ndarray = self._mean[0]
        view.flags.writeable = False
        return view

    @property
    def cov(self) -> np.ndarray:
        """The current filter covariance, shape (n, n) (read-only view)."""
        view = self._cov.view()
        view.flags.writeable = False
        return view

    def __repr__(self) -> str:
        return (
            f"OnlineExecutor(k={self._k}/{self.law.num_of_steps}, pending={self.pending}, "
            f"mean={np.array2string(self._mean[0], precision=4)})"
        )

    # -- the loop ------------------------------------------------------------------------------

    def observe(self, observation: ArrayLike | None) -> None:
        """Update the belief with the observation taken after the last input.

        Parameters
        ----------
        observation : array_like, shape (p,), or None
            The planning mode's sensor reading ``y_{k}``; None exactly when that mode is blind.

        Raises
        ------
        InvalidArgumentError
            When no input is pending, or the observation is missing (or given for a blind mode),
            or not finite.
        DimensionError
            When the observation has the wrong shape.
        """
        if self._input is None:
            raise InvalidArgumentError("observe: no input is pending (call step or command first)")
        k = self._k - 1
        Y = self._observation(k, observation)
        self._mean, self._cov = self.law.filter(k, self._mean, self._cov, self._input, Y)
        self._input = None

    def command(self) -> tuple[int, np.ndarray]:
        """The mode and input of the current step ``k`` (the tracking law on the current belief).

        Returns
        -------
        mode : int
            The planning mode to run (its sensor gives the next observation).
        input : ndarray, shape (m,)
            The input to apply, projected on the control domain.

        Raises
        ------
        InvalidArgumentError
            When the plan is done, the previous input's observation is pending, or the input is
            not finite (the belief diverged).
        """
        if self._input is not None:
            raise InvalidArgumentError("command: the observation of the last input is pending (call observe)")
        if self.done:
            raise InvalidArgumentError(f"the plan is done: its {self.law.num_of_steps} inputs were issued")
        k = self._k
        U = self.law.control(k, self._mean)
        if not np.isfinite(U).all():
            raise InvalidArgumentError(f"the input of step {k} is not finite: the belief diverged")
        self._input = U
        self._k = k + 1
        return self.law.steps[k].mode, U[0].copy()

    def step(self, observation: ArrayLike | None = None) -> tuple[int, np.ndarray]:
        """Take the observation made after the last input and return the next mode and input.

        Parameters
        ----------
        observation : array_like, shape (p,), or None
            The reading of the previous step's sensor (None before the first input, and after a
            blind mode).

        Returns
        -------
        mode : int
        input : ndarray, shape (m,)

        Raises
        ------
        InvalidArgumentError
            When the plan is done (the last observation then goes to :meth:`observe`), or an
            observation is given before the first input.
        """
        self.receive(observation)
        return self.command()

    def receive(self, observation: ArrayLike | None = None) -> bool:
        """The first half of :meth:`step`: check the call and take the observation, if one is due.

        A loop that decides something between the observation and the next input (the
        re-planning executor) calls this, then :meth:`command`.

        Parameters
        ----------
        observation : array_like, shape (p,), or None
            As for :meth:`step`.

        Returns
        -------
        bool
            True when an observation was due and the belief was updated with it.

        Raises
        ------
        InvalidArgumentError
            As for :meth:`step`.
        """
        if self.done:
            raise InvalidArgumentError(
                f"the plan is done: its {self.law.num_of_steps} inputs were issued"
                + ("; give the last observation to observe()" if self._input is not None else "")
            )
        if self._input is not None:
            self.observe(observation)
            return True
        if observation is not None:
            raise InvalidArgumentError(
                "step: an observation was given but no input is pending (the first call takes None; "
                "the prior already holds what is known at the start)"
            )
        return False

    def _observation(self, k: int, observation: ArrayLike | None) -> np.ndarray | None:
        mode = self.law.steps[k].model
        if not mode.p:
            if observation is not None:
                raise InvalidArgumentError(
                    f"mode {self.law.steps[k].mode} is blind: its observation must be None"
                )
            return None
        if observation is None:
            raise InvalidArgumentError(
                f"mode {self.law.steps[k].mode} observes {mode.p} outputs: "
                f"observation must be an array of shape ({mode.p},)"
            )
        y = np.asarray(observation, dtype=float)
        if y.shape != (mode.p,):
            raise DimensionError(f"observation must have shape ({mode.p},), got {y.shape}")
        if not np.isfinite(y).all():
            raise InvalidArgumentError(f"observation must be finite, got {y} (a sensor fault?)")
        return y[None, :]
