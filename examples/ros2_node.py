"""How to run an idstlpy plan on a robot from a ROS 2 node (no ROS needed to read or run this file).

A ROS 2 node wraps :class:`idstlpy.OnlineExecutor`, or :class:`idstlpy.ReplanningExecutor` to
re-plan on the robot: at every control period it hands the executor the observation received
since the last input and publishes the mode (which sensor to use) and the input it returns. The
executor owns the belief (Kalman filter of the planning model) and the tracking law, and the
re-planning one also the drift / risk checks and re-solves of :func:`idstlpy.execute`; it never
sees the true state, only what the sensors publish.

- :class:`ExecutorCore` is the ROS-free part (testable anywhere): ``tick(observation)`` returns
  the next ``(mode, input)`` or None when the plan is done. With a
  :class:`idstlpy.ReplanPolicy` it runs a :class:`idstlpy.ReplanningExecutor`::

      policy = stl.ReplanPolicy(risk=0.8, check_every=10, drift=0.95, replan_time_limit=0.5,
                                solver=stl.SolverOptions(rrt_timeout=0.5))
      core = ExecutorCore(problem, plan, policy=policy, seed=0)

  and ``core.executor.last_replan`` says what the last tick re-planned (published on
  ``replan`` as a log line), ``core.executor.predicted`` the last predicted success.
- :func:`make_ros2_node` builds the node (``rclpy`` is imported there, not at module level):
  it subscribes to ``observation`` (``std_msgs/Float64MultiArray``; an empty array for a blind
  mode), publishes ``command`` (``Float64MultiArray``: ``[mode, u_0, ..., u_{m-1}]``) and
  ``belief`` (the mean then the covariance, row-major) from a timer at the control period.
- ``python examples/ros2_node.py`` runs the same core in a fake loop against a simulated robot
  (the paper's light-dark plant), no ROS installed; ``--replan`` with a re-planning policy.

Cost per tick without re-plans: about 45 microseconds on the listing's system
(``python -m benchmarks.executor_step``), far inside a 10 Hz or 100 Hz control period. A
re-planning tick costs more only at a check (one closed-loop prediction of the remaining plan,
milliseconds to 0.1 s) and at a re-solve (up to ``replan_time_limit``): the timer callback is
then late by that much. Give the policy a ``replan_time_limit`` below what the robot can wait,
or, for long solves, run the re-planning executor in its own thread and let the node repeat the
last command meanwhile.
"""

from __future__ import annotations

from typing import Any

import numpy as np

import idstlpy as stl


class ExecutorCore:
    """The ROS-free core of the node: one online executor and its bookkeeping.

    Parameters
    ----------
    problem : Problem
        The problem the plan solves (its system and control domain run the plan).
    plan : ProbabilisticTSTrajectory
        The plan to execute.
    policy : ReplanPolicy, optional
        Re-plan as this policy says (a :class:`idstlpy.ReplanningExecutor`, whose construction
        makes the policy's start check); None: follow ``plan`` (an :class:`idstlpy.OnlineExecutor`).
    seed : int
        Seed of the re-solves' seeds (with a policy).
    """

    def __init__(
        self,
        problem: Any,
        plan: stl.ProbabilisticTSTrajectory,
        policy: stl.ReplanPolicy | None = None,
        seed: int = 0,
    ) -> None:
        self.executor: stl.OnlineExecutor | stl.ReplanningExecutor
        if policy is None:
            self.executor = stl.OnlineExecutor(problem, plan)
            self.executor.reset()
        else:
            self.executor = stl.ReplanningExecutor(problem, plan, policy, seed=seed)
        self.finished = False

    def tick(self, observation: np.ndarray | None) -> tuple[int, np.ndarray] | None:
        """One control period: the observation since the last input in, the next command out.

        Parameters
        ----------
        observation : ndarray of shape (p,), or None
            The reading of the last commanded mode's sensor (None before the first command and
            for a blind mode).

        Returns
        -------
        (int, ndarray of shape (m,)) or None
            The mode and input to apply; None once the plan is done (the last observation then
            updated the final belief).
        """
        if self.executor.done:
            if self.executor.pending:
                self.executor.observe(observation)
                self.finished = True
            return None
        return self.executor.step(observation)


def make_ros2_node(core: ExecutorCore, period: float = 0.1, name: str = "idstlpy_executor") -> Any:
    """A ROS 2 node running ``core`` every ``period`` seconds (needs ``rclpy`` and ``std_msgs``).

    Parameters
    ----------
    core : ExecutorCore
    period : float
        The control period (s); one ``tick`` per period.
    name : str
        The node's name.

    Returns
    -------
    rclpy.node.Node
        Spin it with ``rclpy.spin(node)`` after ``rclpy.init()``.
    """
    from rclpy.node import Node  # imported here: the module itself runs without ROS
    from std_msgs.msg import Float64MultiArray, String

    class ExecutorNode(Node):  # type: ignore[misc]
        def __init__(self) -> None:
            super().__init__(name)
            self._latest: np.ndarray | None = None
            self.create_subscription(Float64MultiArray, "observation", self._on_observation, 10)
            self._command = self.create_publisher(Float64MultiArray, "command", 10)
            self._belief = self.create_publisher(Float64MultiArray, "belief", 10)
            self._replan = self.create_publisher(String, "replan", 10)
            self.create_timer(period, self._on_timer)

        def _on_observation(self, msg: Any) -> None:
            self._latest = np.asarray(msg.data, dtype=float) if len(msg.data) else None

        def _on_timer(self) -> None:
            observation, self._latest = self._latest, None
            command = core.tick(observation)
            belief = core.executor.belief
            self._belief.publish(Float64MultiArray(data=[*belief.mean, *belief.cov.ravel()]))
            record = getattr(core.executor, "last_replan", None)  # a re-planning executor's
            if record is not None:
                self._replan.publish(String(data=repr(record)))
            if command is None:
                if core.finished:
                    self.get_logger().info("plan executed")
                return
            mode, u = command
            self._command.publish(Float64MultiArray(data=[float(mode), *u]))

    return ExecutorNode()


def _fake_loop(steps: int = 30, seed: int = 0, policy: stl.ReplanPolicy | None = None) -> np.ndarray:
    """The node's loop without ROS: a simulated light-dark robot publishes, the core commands."""
    from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system

    problem = light_dark()
    system = problem.switched_system
    half = steps // 2
    controls = np.vstack([np.tile([1.0, -0.1], (half, 1)), np.tile([-1.0, 0.0], (steps - half, 1))])
    plan = stl.rollout(system, problem.initial_state, np.zeros(steps, dtype=int), 0.25 * controls)
    core = ExecutorCore(problem, plan, policy, seed)
    robot = light_dark_real_system().mode(0)
    rng = np.random.default_rng(seed)
    x = np.asarray(LIGHT_DARK_REAL_INITIAL_STATE, dtype=float)
    observation = None
    while not core.finished:
        command = core.tick(observation)
        if command is not None:
            mode, u = command
            x = robot.A @ x + robot.B @ u  # the robot moves...
            sensor = system.mode(mode)  # ...and the commanded sensor reads its state
            observation = sensor.C @ x + sensor.noise(x) @ rng.standard_normal(sensor.p)
            k = core.executor.k
            record = getattr(core.executor, "last_replan", None)
            if record is not None:
                print(f"step {k - 1:3d}: {record.reason} re-plan {record.status}, adopted {record.adopted}")
            if k % 5 == 0 or k == steps:
                mean = np.round(core.executor.mean, 3)
                print(f"step {k:3d}: mode {mode} input {np.round(u, 3)} belief mean {mean}")
    mean = np.round(core.executor.mean, 3)
    print(f"done: true state {np.round(x, 3)}, belief {mean}, first plan {plan.get_mean(steps)}")
    return x


if __name__ == "__main__":
    import sys

    _fake_loop(
        policy=stl.ReplanPolicy(risk=0.5, check_every=10, max_replans=2, replan_time_limit=5.0)
        if "--replan" in sys.argv[1:]
        else None
    )
