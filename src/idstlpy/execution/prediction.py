"""The predicted execution of a plan: a façade over :mod:`idstlpy.executor.predict`.

The predictor lives below the synthesis layer (the planner's default guarantee, ``"execution"``,
asks it whether a plan meets its execution target); this module keeps its historical import path.
"""

from __future__ import annotations

from ..executor.predict import (
    ClosedLoopPrediction,
    ConstraintPrediction,
    SensorNoise,
    bivariate_normal_cdf,
    predict_closed_loop,
)

__all__ = [
    "ClosedLoopPrediction",
    "ConstraintPrediction",
    "predict_closed_loop",
    "bivariate_normal_cdf",
    "SensorNoise",
]
