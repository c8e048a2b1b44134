"""Execution of plans: LQR tracking, Kalman filtering against a real system, Monte Carlo.

- :func:`finite_horizon_lqr`: gains of the tracking law (``LCS.compute_finite_horizon_lqr``);
- :func:`simulate`: one execution (``SwitchedSystem.simulate``);
- :func:`validate`: many independent executions and the rates at which the plan's promise held.
"""

from __future__ import annotations

from .lqr import finite_horizon_lqr
from .simulate import simulate
from .validate import ValidationReport, validate, wilson_interval

__all__ = ["finite_horizon_lqr", "simulate", "validate", "ValidationReport", "wilson_interval"]
