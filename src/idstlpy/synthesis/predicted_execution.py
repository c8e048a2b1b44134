"""The predicted execution a result carries (:class:`PredictedExecution`): the planner's
prediction of how often its plan holds when executed, per reading, against the execution target.
A leaf of the synthesis core, as :mod:`.results` (which re-exports it)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ..errors import InvalidArgumentError
from ..execution_target import DEFAULT_EXECUTION_TARGET, ExecutionTarget, as_execution_target

if TYPE_CHECKING:
    from ..executor.predict import ClosedLoopPrediction

__all__ = ["PredictedExecution"]


def _finite_or_none(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


@dataclass(frozen=True)
class PredictedExecution:
    """The predicted execution of a returned plan, and whether it meets the execution target.

    Read off :func:`idstlpy.executor.predict.predict_closed_loop` under the planner's reading of
    the execution: the Kalman filter and the modes' LQR tracking (their gains at solve time),
    inputs clipped to the control domain, the true start drawn from the prior, the model's noise.

    Parameters
    ----------
    belief_estimate, state_estimate : float
        Predicted probability that the executed belief satisfies the formula / that the true
        states satisfy its deterministic reading (sampled from the predicted loop).
    belief_bound, state_bound : float
        Lower bounds on the same probabilities (sound for the linear-Gaussian model; under the
        particle closure capped by a 99.9% Clopper-Pearson bound of the samples).
    proposition_violation : dict
        Per atomic proposition, ``{"belief": p, "state": p}``: predicted probability that it is
        broken at some step the plan promises it.
    target : ExecutionTarget
        The target the rates were held to.
    samples : int
        Model samples behind the estimates: a candidate's 1000; a returned plan's re-sampled until
        each estimate's 95% interval is about +-0.5 points (or a quarter of its distance from the
        target; at most 20000; :meth:`idstlpy.synthesis.context.TargetWatch.report`).
    closure : str
        ``"gaussian"`` or ``"particles"`` (how the loop's non-linearities were modelled).
    """

    belief_estimate: float
    state_estimate: float
    belief_bound: float
    state_bound: float
    proposition_violation: dict[str, dict[str, float]] = field(default_factory=dict)
    target: ExecutionTarget = DEFAULT_EXECUTION_TARGET
    samples: int = 0
    closure: str = "gaussian"

    @classmethod
    def from_prediction(cls, prediction: ClosedLoopPrediction, target: ExecutionTarget) -> PredictedExecution:
        """Summarise a :class:`~idstlpy.executor.predict.ClosedLoopPrediction` against ``target``.

        Parameters
        ----------
        prediction : ClosedLoopPrediction
            A prediction made with a formula and samples.
        target : ExecutionTarget

        Returns
        -------
        PredictedExecution
        """
        return cls(
            float(prediction.belief_success_estimate),
            float(prediction.state_success_estimate),
            float(prediction.belief_success_bound),
            float(prediction.state_success_bound),
            {k: {r: float(v) for r, v in d.items()} for k, d in prediction.proposition_violation.items()},
            target,
            int(prediction.samples),
            str(prediction.closure),
        )

    @property
    def meets_target(self) -> bool:
        """Whether both predicted success estimates reach the target (NaN never does)."""
        return self.target.met_by(self.belief_estimate, self.state_estimate) and not (
            math.isnan(self.belief_estimate) or math.isnan(self.state_estimate)
        )

    @property
    def shortfall(self) -> float:
        """The larger shortfall of the two estimates below the target (0 when met; 1 for NaN)."""
        gaps = [
            1.0 if math.isnan(rate) else max(0.0, bar - rate)
            for rate, bar in (
                (self.belief_estimate, self.target.belief),
                (self.state_estimate, self.target.state),
            )
        ]
        return max(gaps)

    def summary(self) -> str:
        """One line: predicted rates, bounds and the verdict against the target."""
        verdict = "meets" if self.meets_target else "BELOW"
        return (
            f"predicted execution: belief {_pct(self.belief_estimate)} (>= {_pct(self.belief_bound)}), "
            f"true state {_pct(self.state_estimate)} (>= {_pct(self.state_bound)}); {verdict} the target "
            f"{self.target}"
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able data (NaN becomes ``None``)."""
        return {
            "belief_estimate": _finite_or_none(self.belief_estimate),
            "state_estimate": _finite_or_none(self.state_estimate),
            "belief_bound": _finite_or_none(self.belief_bound),
            "state_bound": _finite_or_none(self.state_bound),
            "proposition_violation": {
                k: {r: _finite_or_none(v) for r, v in d.items()}
                for k, d in self.proposition_violation.items()
            },
            "target": self.target.as_dict(),
            "samples": self.samples,
            "closure": self.closure,
            "meets_target": self.meets_target,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> PredictedExecution:
        """Inverse of :meth:`to_dict`.

        Parameters
        ----------
        data : dict

        Returns
        -------
        PredictedExecution

        Raises
        ------
        InvalidArgumentError
            When ``data`` is not a mapping.
        """
        if not isinstance(data, dict):
            raise InvalidArgumentError(f"execution must be a mapping, got {type(data).__name__}")

        def num(v: Any) -> float:
            return float("nan") if v is None else float(v)

        return cls(
            num(data.get("belief_estimate")),
            num(data.get("state_estimate")),
            num(data.get("belief_bound")),
            num(data.get("state_bound")),
            {
                str(k): {str(r): num(v) for r, v in d.items()}
                for k, d in dict(data.get("proposition_violation") or {}).items()
            },
            as_execution_target(data.get("target"), "execution.target"),
            int(data.get("samples", 0)),
            str(data.get("closure", "gaussian")),
        )


def _pct(rate: float) -> str:
    return "nan" if math.isnan(rate) else f"{100.0 * rate:.1f}%"
