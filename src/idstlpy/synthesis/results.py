"""What a solve returns: the status, the verified plan, the reason and the statistics.

A leaf module: every part of the synthesis core may import it, and it imports none of them.
Statistics are counted here, in one place (:class:`SolveStats`), by the loop.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from .._version import software_info
from ..errors import InvalidArgumentError
from ..tracking import TrackingGains
from ..trajectory import ProbabilisticTSTrajectory
from .options import GUARANTEES, Guarantee, Objective
from .predicted_execution import PredictedExecution, _finite_or_none, _pct

if TYPE_CHECKING:
    pass

__all__ = ["RESULT_SCHEMA", "PredictedExecution", "SolveResult", "SolveStats", "Status", "load_result"]

GUARANTEE_NAMES: tuple[Guarantee, ...] = GUARANTEES

Status = Literal["found", "infeasible", "budget_exhausted"]
STATUSES: tuple[str, ...] = ("found", "infeasible", "budget_exhausted")

RESULT_SCHEMA = "idstlpy.result/1"
"""Identifier and version of the JSON form of :class:`SolveResult` (see ``docs/results-schema.md``)."""


@dataclass
class SolveStats:
    """How the solver spent its effort.

    Every field is a constructor argument with a zero / empty default; the loop updates them.

    Parameters
    ----------
    candidates : int
        Discrete plans proposed by the BMC proposer.
    refuted : int
        Candidates a teacher refuted with a proof (each became a blocking clause).
    abandoned : int
        Candidates every teacher gave up on (set aside without a proof).
    counterexamples : int
        Proven blocking clauses added (``refuted`` plus failed monitor re-checks that were proofs).
    pruned_letters, pruned_steps : int
        Letters / letter-to-letter steps excluded for good by LP pruning.
    bmc_depth : int
        Deepest plan length - 1 the proposer searched.
    encoded_depth : int
        Longest plan the SAT encoding was unrolled for (it grows lazily).
    nodes : int
        Belief nodes grown by the sampler.
    sampler_iterations : int
        Sampler iterations (the work budget that decides the search).
    sat_calls, lp_calls, milp_calls : int
        Number of SAT, LP and MILP solver calls.
    time_total, time_bmc, time_lp, time_sampling : float
        Seconds (measured, never used to decide the search).
    caps_hit : list of str
        Wall-clock safety caps that were hit (``"time_limit"``, ``"rrt_timeout"``): when not
        empty, the same seed may give a different answer on another machine.
    improvements : list of (float, float)
        ``(seconds since the start, objective value)`` each time a better verified plan was
        found (empty without an objective).
    execution_room : float or None
        The fraction of its execution room the returned plan keeps (:mod:`.room`: per required
        face and step, the room the predicted closed loop under the default LQR tracking and
        Kalman filter needs for the executed belief to hold in 90% and the true state in 95% of
        runs); 1 or more: all of it. Below 1 the plan is expected to hold less often than that
        (a warning is logged). ``None`` where it was not computed: noise-free problems, plans
        the sampler's polish and the objective's refiner did not see (the LP and MILP paths),
        and ``guarantee="closed_loop"``, whose promise is the predicted true state itself.
    predictions : int
        Predicted executions of plans (:func:`idstlpy.executor.predict.predict_closed_loop`).
    below_target : int
        Verified plans set aside under ``guarantee="execution"`` because their predicted
        execution (after repair) fell short of the execution target.
    time_prediction : float
        Seconds spent predicting executions (measured, never used to decide the search).
    time_certificate : float
        Seconds spent building and checking the certificate of an ``infeasible`` (measured).
    """

    candidates: int = 0
    refuted: int = 0
    abandoned: int = 0
    counterexamples: int = 0
    pruned_letters: int = 0
    pruned_steps: int = 0
    bmc_depth: int = 0
    encoded_depth: int = 0
    nodes: int = 0
    sampler_iterations: int = 0
    sat_calls: int = 0
    lp_calls: int = 0
    milp_calls: int = 0
    time_total: float = 0.0
    time_bmc: float = 0.0
    time_lp: float = 0.0
    time_sampling: float = 0.0
    caps_hit: list[str] = field(default_factory=list)
    improvements: list[tuple[float, float]] = field(default_factory=list)
    execution_room: float | None = None
    predictions: int = 0
    below_target: int = 0
    time_prediction: float = 0.0
    time_certificate: float = 0.0

    @contextmanager
    def clock(self, name: str) -> Iterator[None]:
        """Add the wall-clock time of the ``with`` block to the attribute ``name``.

        Parameters
        ----------
        name : str
            A float field, e.g. ``"time_lp"``; the elapsed seconds are added to it even when
            the block raises.
        """
        t0 = time.perf_counter()
        try:
            yield
        finally:
            setattr(self, name, getattr(self, name) + time.perf_counter() - t0)

    def as_dict(self) -> dict[str, Any]:
        """Plain-data copy (for JSON result files)."""
        return {
            f.name: (list(v) if isinstance(v := getattr(self, f.name), list) else v) for f in fields(self)
        }

    to_dict = as_dict

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SolveStats:
        """Inverse of :meth:`to_dict` (unknown keys are ignored, missing ones take defaults).

        Parameters
        ----------
        data : dict
            Field name to value, as :meth:`to_dict` writes it.

        Returns
        -------
        SolveStats
        """
        known = {f.name for f in fields(cls)}
        kw = {k: v for k, v in data.items() if k in known}
        if "improvements" in kw:
            kw["improvements"] = [(float(a), float(b)) for a, b in kw["improvements"]]
        return cls(**kw)


@dataclass
class SolveResult:
    """Outcome of :meth:`Problem.solve_result`.

    Parameters
    ----------
    status : {"found", "infeasible", "budget_exhausted"}
        ``found``: the plan passed the exact monitor. ``infeasible``: a proof that no plan
        exists (the proposer ran dry over proven clauses only). ``budget_exhausted``: neither;
        ``reason`` says which budget ran out and how many candidates were refuted by proofs
        and how many abandoned.
    trajectory : ProbabilisticTSTrajectory or None
        The verified plan when ``status == "found"``.
    reason : str
        One sentence on why the solver stopped.
    margin : float
        Monitor robustness of the returned plan (``nan`` without a plan).
    stats : SolveStats
        How the solver spent its effort.
    formula : str
        The formula's text (``str(formula)``), for result files.
    objective : str or None
        The objective asked for (``"effort"``, ``"time"``, ``"margin"``) or ``None``.
    objective_value : float
        Its value on the returned plan (``nan`` without a plan or an objective).
    objective_bound : float
        The best proven bound on the optimum over ``optimal_scope``, where known (``nan``
        otherwise): a lower bound for effort and time, an upper bound for margin; never on the
        wrong side of ``objective_value``. A bound the eager MILP proved under the paper's
        semantics holds for every returned plan, and is kept when its own plan was not returned
        (e.g. set aside below the execution target): then ``optimal`` is usually False.
    optimal : bool
        True only when the bound is proven and ``gap <= 1e-6``: the value is within
        ``1e-6 * max(1, |value|)`` of the optimum over ``optimal_scope``.
    optimal_scope : str
        ``"horizon"`` (every plan within the formula's horizon, from the eager MILP; the problem as
        stated, no execution margin), ``"plans of at most N steps"`` (the same under
        ``max_plan_length``), ``"shortest first"`` (time: every shorter candidate was refuted by
        a proof) or ``""``.
    guarantee : {"execution", "mlo", "closed_loop"}
        What ``margin`` and the verification are about: the MLO belief trajectory (the paper's
        semantics; under ``"execution"`` with the predicted execution held to the target) or
        the true state predicted under the executor (``predicted``).
    predicted : ProbabilisticTSTrajectory or None
        With ``guarantee="closed_loop"``: the predicted true-state distribution (means
        (N + 1, n), covariances (N + 1, n, n)) on which the monitor verified the formula.
    closest : ProbabilisticTSTrajectory or None
        With ``budget_exhausted``: the partial plan the search got closest with (the MLO belief
        along the prefix that met most of a candidate's required events, then went deepest),
        for plotting and diagnosis. It does **not** satisfy the formula. ``None`` otherwise.
    software : dict
        Which code made the result: ``{"idstlpy": version, "commit": git commit or None,
        "python", "numpy", "platform"}`` (by default the running code's; a loaded result keeps
        the one it was saved with). The JSON field ``software``.
    execution : PredictedExecution or None
        Every found plan's predicted execution (success estimates and lower bounds for the
        executed belief and the true state, per-proposition violation rates) against the
        execution target; None without a plan.
    certificate : dict or None
        With ``infeasible``: the proof's certificate (schema ``idstlpy.certificate/1``, see
        :mod:`idstlpy.synthesis.certificates`), which ``idstlpy check RESULT.json`` re-checks
        without trusting the LP and SAT solvers; its ``certified`` field is the check made at
        the end of the solve. ``None`` otherwise.

    Notes
    -----
    ``plan`` is another name for ``trajectory`` (the JSON field is ``plan``). Two results are
    ``==`` when every field is equal, arrays element by element and NaN equal to NaN, so
    ``load_result(result.save(path)) == result`` holds (the file is a bit-exact round trip).
    """

    status: Status
    trajectory: ProbabilisticTSTrajectory | None
    reason: str
    margin: float = float("nan")
    stats: SolveStats = field(default_factory=SolveStats)
    formula: str = ""
    objective: Objective | None = None
    objective_value: float = float("nan")
    objective_bound: float = float("nan")
    optimal: bool = False
    optimal_scope: str = ""
    guarantee: Guarantee = "execution"
    predicted: ProbabilisticTSTrajectory | None = None
    software: dict[str, str | None] = field(default_factory=software_info)
    closest: ProbabilisticTSTrajectory | None = None
    execution: PredictedExecution | None = None
    certificate: dict[str, Any] | None = None

    @property
    def plan(self) -> ProbabilisticTSTrajectory | None:
        """The verified plan (another name for ``trajectory``; the JSON field ``plan``)."""
        return self.trajectory

    @property
    def tracking(self) -> TrackingGains | None:
        """The tracking gains the plan was made for (``plan.tracking``: its name, weights and
        every mode's gains; the executors use them), or None without a plan."""
        return None if self.trajectory is None else self.trajectory.tracking

    @property
    def version(self) -> str | None:
        """The version of idstlpy that made this result (``software["idstlpy"]``)."""
        return self.software.get("idstlpy")

    @property
    def commit(self) -> str | None:
        """The git commit of the code that made this result, ``None`` when unknown."""
        return self.software.get("commit")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, SolveResult):
            return NotImplemented
        return all(_same(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))

    @property
    def meets_target(self) -> bool | None:
        """Whether the plan's predicted execution meets the execution target (None without one).

        False means the plan is predicted to hold less often than asked: under
        ``guarantee="execution"`` the solver found no plan that meets it within its budget
        (an :class:`~idstlpy.errors.ExecutionTargetWarning` was issued).
        """
        return None if self.execution is None else self.execution.meets_target

    @property
    def gap(self) -> float:
        """Relative gap between ``objective_value`` and ``objective_bound`` (``nan`` if unknown)."""
        v, b = self.objective_value, self.objective_bound
        if not (math.isfinite(v) and math.isfinite(b)):
            return float("nan")
        return abs(v - b) / max(1.0, abs(v))

    @property
    def certified(self) -> bool | None:
        """Whether the ``infeasible`` proof's certificate verified when the solve ended (``None``
        for other statuses). Re-check a saved result with ``idstlpy check``."""
        if self.status != "infeasible":
            return None
        return bool(self.certificate is not None and self.certificate.get("certified"))

    @property
    def found(self) -> bool:
        """True when a verified plan was found."""
        return self.status == "found"

    @property
    def solve_time(self) -> float:
        """Wall-clock seconds spent in ``solve``."""
        return self.stats.time_total

    def __repr__(self) -> str:
        steps = "" if self.trajectory is None else f", steps={self.trajectory.num_of_steps}"
        obj = ""
        if self.objective is not None:
            obj = f", {self.objective}={self.objective_value:.4g}" + (" (optimal)" if self.optimal else "")
        ex = ""
        if self.execution is not None:
            e = self.execution
            ex = (
                f", predicted belief/state={_pct(e.belief_estimate)}/{_pct(e.state_estimate)}"
                f" ({'meets' if e.meets_target else 'BELOW'} target)"
            )
        return (
            f"SolveResult(status={self.status!r}{steps}, margin={self.margin:.3g}{obj}{ex}, "
            f"time={self.stats.time_total:.3g} s, reason={self.reason!r})"
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able data (NaN and infinities become ``None``), schema :data:`RESULT_SCHEMA`."""
        traj = self.trajectory
        return {
            "schema": RESULT_SCHEMA,
            "status": self.status,
            "reason": self.reason,
            "margin": _finite_or_none(self.margin),
            "formula": self.formula,
            "objective": self.objective,
            "objective_value": _finite_or_none(self.objective_value),
            "objective_bound": _finite_or_none(self.objective_bound),
            "optimal": self.optimal,
            "optimal_scope": self.optimal_scope,
            "guarantee": self.guarantee,
            "stats": self.stats.to_dict(),
            "plan": None if traj is None else _trajectory_to_dict(traj),
            "predicted": None if self.predicted is None else _trajectory_to_dict(self.predicted),
            "software": dict(self.software),
            "closest": None if self.closest is None else _trajectory_to_dict(self.closest),
            "execution": None if self.execution is None else self.execution.to_dict(),
            "certificate": self.certificate,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SolveResult:
        """Rebuild a result from :meth:`to_dict` output.

        Parameters
        ----------
        data : dict
            The JSON data of schema :data:`RESULT_SCHEMA`.

        Returns
        -------
        SolveResult

        Raises
        ------
        InvalidArgumentError
            When ``data`` is not a result of a known schema.
        """
        if not isinstance(data, dict) or data.get("schema") != RESULT_SCHEMA:
            got = data.get("schema") if isinstance(data, dict) else type(data).__name__
            raise InvalidArgumentError(
                f"not an idstlpy result: expected schema {RESULT_SCHEMA!r}, got {got!r}"
            )
        status = data.get("status")
        if status not in STATUSES:
            # Result records of the CLI and sweeps share the schema; a failed or rejected run
            # has no solver result to rebuild.
            why = data.get("error") or data.get("reason") or ""
            raise InvalidArgumentError(
                f"this record holds no solver result: its run ended with status {status!r}"
                + (f" ({why})" if why else "")
                + f"; a result's status is one of {', '.join(STATUSES)}"
            )
        plan = data.get("plan")
        traj = None if plan is None else _trajectory_from_dict(plan)
        pred = data.get("predicted")
        guarantee = str(data.get("guarantee", "mlo"))
        if guarantee not in GUARANTEE_NAMES:
            raise InvalidArgumentError(
                f"guarantee must be one of {', '.join(GUARANTEE_NAMES)}, got {guarantee!r}"
            )
        execution = data.get("execution")

        def num(key: str) -> float:
            v = data.get(key)
            return float("nan") if v is None else float(v)

        return cls(
            status,
            traj,
            str(data.get("reason", "")),
            num("margin"),
            SolveStats.from_dict(data.get("stats", {})),
            str(data.get("formula", "")),
            data.get("objective"),
            num("objective_value"),
            num("objective_bound"),
            bool(data.get("optimal", False)),
            str(data.get("optimal_scope", "")),
            guarantee,
            None if pred is None else _trajectory_from_dict(pred),
            _software_from(data.get("software")),
            closest=None if data.get("closest") is None else _trajectory_from_dict(data["closest"]),
            execution=None if execution is None else PredictedExecution.from_dict(execution),
            certificate=data.get("certificate") if isinstance(data.get("certificate"), dict) else None,
        )

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write :meth:`to_dict` as JSON (strict: no NaN) to ``path``; returns the path.

        Parameters
        ----------
        path : str or path-like
            The file to write (overwritten if it exists).

        Returns
        -------
        pathlib.Path
        """
        out = Path(path)
        out.write_text(json.dumps(self.to_dict(), indent=1, allow_nan=False) + "\n")
        return out


def load_result(path: str | os.PathLike[str]) -> SolveResult:
    """Read a result written by :meth:`SolveResult.save`.

    Parameters
    ----------
    path : str or path-like
        A JSON file of schema :data:`RESULT_SCHEMA`.

    Returns
    -------
    SolveResult
        Its plan (if any) passes ``satisfies`` against the problem it was solved for.
    """
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InvalidArgumentError(f"cannot read result file {os.fspath(path)!r}: {exc}") from None
    return SolveResult.from_dict(data)


def _software_from(data: Any) -> dict[str, str | None]:
    """The ``software`` field of a result file (empty for files written before 0.2.0)."""
    if not isinstance(data, dict):
        return {}
    return {str(k): (None if v is None else str(v)) for k, v in data.items()}


def _same(a: Any, b: Any) -> bool:
    """Equal by value: floats with NaN == NaN, trajectories and arrays element by element."""
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, ProbabilisticTSTrajectory) or isinstance(b, ProbabilisticTSTrajectory):
        if not (isinstance(a, ProbabilisticTSTrajectory) and isinstance(b, ProbabilisticTSTrajectory)):
            return False
        return all(
            _same(x, y)
            for x, y in (
                (a.get_mean(), b.get_mean()),
                (a.get_cov(), b.get_cov()),
                (a.get_action(), b.get_action()),
                (a.get_control(), b.get_control()),
            )
        )
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        x, y = np.asarray(a), np.asarray(b)
        return x.shape == y.shape and bool(np.array_equal(x, y, equal_nan=x.dtype.kind == "f"))
    if isinstance(a, PredictedExecution) and isinstance(b, PredictedExecution):
        return a.to_dict() == b.to_dict()
    if isinstance(a, SolveStats) and isinstance(b, SolveStats):
        return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)


def _trajectory_to_dict(traj: ProbabilisticTSTrajectory) -> dict[str, Any]:
    to_dict = getattr(traj, "to_dict", None)
    if to_dict is not None:
        return dict(to_dict())
    return {
        "mean": traj.get_mean().tolist(),
        "cov": traj.get_cov().tolist(),
        "action": traj.get_action().tolist(),
        "control": traj.get_control().tolist(),
    }


def _trajectory_from_dict(data: dict[str, Any]) -> ProbabilisticTSTrajectory:
    from_dict = getattr(ProbabilisticTSTrajectory, "from_dict", None)
    if from_dict is not None:
        return from_dict(data)  # type: ignore[no-any-return]
    import numpy as np

    return ProbabilisticTSTrajectory(
        np.asarray(data["mean"], dtype=float),
        np.asarray(data["cov"], dtype=float),
        np.asarray(data["action"], dtype=int),
        np.asarray(data["control"], dtype=float),
    )
