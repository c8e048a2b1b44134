"""Execution of plans: LQR tracking, Kalman filtering against a real system, Monte Carlo.

Functions (re-exported at the top level as ``idstlpy.finite_horizon_lqr``, ``idstlpy.simulate``,
``idstlpy.validate``):

- :func:`finite_horizon_lqr`: gains of the tracking law (``LCS.compute_finite_horizon_lqr``);
- :func:`simulate`: one execution (``SwitchedSystem.simulate``);
- :func:`validate`: many independent executions and the rates at which the plan's promise held;
- :func:`execute`: one execution that re-plans from the executed belief (receding horizon);
- :func:`start_check`: a plan's predicted success checked (and re-solved) before execution.

Submodules (one job each; none is named like a function it defines):

- :mod:`idstlpy.tracking` (model layer, shared with the planner): the finite-horizon Riccati
  recursion and the tracking law;
- :mod:`idstlpy.execution.simulation`: one execution (filter, tracking, projection on the
  control domain);
- :mod:`idstlpy.execution.validation`: :func:`validate`, the Monte Carlo's façade, whose parts
  are :mod:`~idstlpy.execution.validation_spec` (its settings checked once: ``ValidationSpec``),
  :mod:`~idstlpy.execution.starts` (the true starts), :mod:`~idstlpy.execution.batches`
  (running batches of runs), :mod:`~idstlpy.execution.monitor` (a run's verdicts),
  :mod:`~idstlpy.execution.intervals` (rates, Wilson intervals) and
  :mod:`~idstlpy.execution.report` (:class:`ValidationReport`, its verdict);
- :mod:`idstlpy.execution.policy`: :class:`ReplanPolicy` (when and how to re-plan);
- :mod:`idstlpy.execution.resolving`: re-solves from a belief, :class:`Replan` (their record);
- :mod:`idstlpy.execution.replanner`: :class:`ReplanningExecutor` (the online executor that
  re-plans: one observation in, the next mode and input out);
- :mod:`idstlpy.execution.replanning`: :func:`execute` (its loop with a simulated plant),
  :class:`ExecutionReport`;
- :mod:`idstlpy.execution.precheck`: :func:`start_check` (a plan checked, and re-solved, before
  it is executed), :class:`StartCheck`.
"""

from __future__ import annotations

from ..tracking import finite_horizon_lqr
from .policy import ReplanPolicy
from .precheck import StartCheck, start_check
from .prediction import ClosedLoopPrediction, ConstraintPrediction, predict_closed_loop
from .replanner import ReplanningExecutor
from .replanning import ExecutionReport, Replan, execute
from .simulation import simulate
from .validation import ValidationReport, validate, wilson_interval

__all__ = [
    "ClosedLoopPrediction",
    "ConstraintPrediction",
    "ExecutionReport",
    "execute",
    "finite_horizon_lqr",
    "predict_closed_loop",
    "Replan",
    "ReplanningExecutor",
    "ReplanPolicy",
    "simulate",
    "StartCheck",
    "start_check",
    "validate",
    "ValidationReport",
    "wilson_interval",
]
