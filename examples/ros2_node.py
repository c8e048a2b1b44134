"""How to run an idstlpy plan on a robot from a ROS 2 node (no ROS needed to read or run this file).

A ROS 2 node wraps :class:`idstlpy.OnlineExecutor`: at every control period it hands the
executor the observation received since the last input and publishes the mode (which sensor to
use) and the input it returns. The executor owns the belief (Kalman filter of the planning
model) and the tracking law; it never sees the true state, only what the sensors publish.

- :class:`ExecutorCore` is the ROS-free part (testable anywhere): ``tick(observation)`` returns
  the next ``(mode, input)`` or None when the plan is done.
- :func:`make_ros2_node` builds the node (``rclpy`` is imported there, not at module level):
  it subscribes to ``observation`` (``std_msgs/Float64MultiArray``; an empty array for a blind
  mode), publishes ``command`` (``Float64MultiArray``: ``[mode, u_0, ..., u_{m-1}]``) and
  ``belief`` (the mean then the covariance, row-major) from a timer at the control period.
- ``python examples/ros2_node.py`` runs the same core in a fake loop against a simulated robot
  (the paper's light-dark plant), no ROS installed.

Cost per tick without re-plans: about 45 microseconds on the listing's system
(``python -m benchmarks.executor_step``), far inside a 10 Hz or 100 Hz control period.

Re-planning (:func:`idstlpy.execute`'s drift and risk checks) is not part of the online
executor yet: to re-plan on the robot, run the check on ``core.executor.belief`` between ticks
(in another thread or process if a solve takes longer than a period), and when a new plan is
adopted swap in ``OnlineExecutor(problem, new_plan)`` reset to the current belief.
"""

from __future__ import annotations

from typing import Any

import numpy as np

import idstlpy as stl


class ExecutorCore:
    """The ROS-free core of the node: one :class:`idstlpy.OnlineExecutor` and its bookkeeping.

    Parameters
    ----------
    problem : Problem
        The problem the plan solves (its system and control domain run the plan).
    plan : ProbabilisticTSTrajectory
        The plan to execute.
    """

    def __init__(self, problem: Any, plan: stl.ProbabilisticTSTrajectory) -> None:
        self.executor = stl.OnlineExecutor(problem, plan)
        self.executor.reset()
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
    from std_msgs.msg import Float64MultiArray

    class ExecutorNode(Node):  # type: ignore[misc]
        def __init__(self) -> None:
            super().__init__(name)
            self._latest: np.ndarray | None = None
            self.create_subscription(Float64MultiArray, "observation", self._on_observation, 10)
            self._command = self.create_publisher(Float64MultiArray, "command", 10)
            self._belief = self.create_publisher(Float64MultiArray, "belief", 10)
            self.create_timer(period, self._on_timer)

        def _on_observation(self, msg: Any) -> None:
            self._latest = np.asarray(msg.data, dtype=float) if len(msg.data) else None

        def _on_timer(self) -> None:
            observation, self._latest = self._latest, None
            command = core.tick(observation)
            belief = core.executor.belief
            self._belief.publish(Float64MultiArray(data=[*belief.mean, *belief.cov.ravel()]))
            if command is None:
                if core.finished:
                    self.get_logger().info("plan executed")
                return
            mode, u = command
            self._command.publish(Float64MultiArray(data=[float(mode), *u]))

    return ExecutorNode()


def _fake_loop(steps: int = 30, seed: int = 0) -> np.ndarray:
    """The node's loop without ROS: a simulated light-dark robot publishes, the core commands."""
    from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system

    problem = light_dark()
    system = problem.switched_system
    half = steps // 2
    controls = np.vstack([np.tile([1.0, -0.1], (half, 1)), np.tile([-1.0, 0.0], (steps - half, 1))])
    plan = stl.rollout(system, problem.initial_state, np.zeros(steps, dtype=int), 0.25 * controls)
    core = ExecutorCore(problem, plan)
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
            if k % 5 == 0 or k == steps:
                mean = np.round(core.executor.mean, 3)
                print(f"step {k:3d}: mode {mode} input {np.round(u, 3)} belief mean {mean}")
    mean = np.round(core.executor.mean, 3)
    print(f"done: true state {np.round(x, 3)}, belief {mean}, plan {plan.get_mean(steps)}")
    return x


if __name__ == "__main__":
    _fake_loop()
