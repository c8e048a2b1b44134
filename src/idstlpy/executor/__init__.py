"""What runs a plan, with no knowledge of how plans are found (the layer under synthesis).

- :mod:`idstlpy.executor.spec`: :class:`ExecutorSpec`, the frozen description of the executor
  (system, control domain, tracking gains resolved once, process-noise reading, plant);
- :mod:`idstlpy.executor.law`: :class:`StepLaw`, the one step law (tracking input, true state,
  observation, Kalman filter) for a batch of runs;
- :mod:`idstlpy.executor.online`: :class:`OnlineExecutor`, driven from a user's own loop
  (``reset``, ``step(observation) -> (mode, input)``);
- :mod:`idstlpy.executor.predict`: the predicted execution of a plan (:func:`predict_closed_loop`,
  the linear-Gaussian closed loop), which the planner's default guarantee holds to the target.
"""

from __future__ import annotations

from .law import Step, StepLaw
from .online import OnlineExecutor
from .spec import ExecutorSpec, PlantStep, ProcessNoise

__all__ = ["ExecutorSpec", "OnlineExecutor", "PlantStep", "ProcessNoise", "Step", "StepLaw"]
