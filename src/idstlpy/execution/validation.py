"""Monte Carlo validation: how often does the plan's promise hold when it is executed?

Each run executes the plan with :func:`~idstlpy.execution.simulation.simulate` (Kalman filter,
receding-horizon LQR, true state moved by the real system) under its own random stream, and
records

- *belief success*: the executed belief trajectory satisfies the formula (the monitor);
- *state success*: the true states satisfy the formula's deterministic reading, i.e. the
  formula evaluated with zero covariance at the true states (every chance predicate
  ``P[h'x + c <= 0] >= 1 - eps`` becomes ``h'x + c <= 0``);
- *violations*: for every atomic proposition, whether execution broke it at a step where the
  plan satisfies it (the plan's promise), and for every predicate (face) of it, whether that
  face was broken at such a step. A broken promise at a step the formula does not need is still
  counted, so violation rates are an upper view of what went wrong, not failure causes.

With ``predict=True`` the plan's execution is also *predicted* once, before the runs, by
:func:`~idstlpy.execution.prediction.predict_closed_loop` with exactly the options the runs use
(tracking gains, projection on the control domain, process noise, real system, true initial
state), and :attr:`ValidationReport.predicted` holds it. :meth:`ValidationReport.prediction_comparison`
(also in :meth:`~ValidationReport.as_dict` and :meth:`~ValidationReport.summary`) puts the
predicted violation rates and formula success next to the measured ones, with the measured
Wilson 95% interval and an ``outside`` flag per rate. The prediction is exact for constant sensor
noise without clipping (up to its model sampling); with state-dependent noise or clipped inputs it
is a linearisation around the plan, and the comparison shows how far off it is.

Runs are independent: run ``i`` uses child ``i`` of ``numpy.random.SeedSequence(seed).spawn``,
and results are gathered by index, so the same seed gives the identical report whatever the
executor and the number of workers. Without a fixed true start (the default), run ``i`` starts at
row ``i`` of one draw of shape (runs, n) from ``default_rng(SeedSequence(seed))`` mapped through
the prior (:func:`prior_starts`); its noise is the one it has from a fixed start.

Monte Carlo at scale
--------------------
A worker executes its runs together (``batched=True``, the default): the executor's one step
law (:class:`~idstlpy.executor.StepLaw`) advances arrays of all the runs' true states, filter
means and covariances (shared while the sensor noise is constant, one per run once a
state-dependent sensor has made them differ), and the monitor evaluates all of them at once
(:func:`~idstlpy.semantics.formula_margins` over a batch). Every run still draws from its own
generator, in the order a run alone draws (:class:`_RunStreams`), so each run gets exactly the
noise of ``simulate(..., seed=default_rng(child_i))``: the report is the one of the serial loop
(``batched=False``), the margins up to rounding (about 1e-16). A state-dependent noise function
is called once per step for all runs when it takes a batch of states (``x[..., 0]``; see
:class:`~idstlpy.dynamical_system.POLBSWithNonLinNoise`), else once per run; the filters'
updates are batched either way. Progress: ``progress(done, runs)`` after every batch, and an
INFO log record at most every second (the CLI shows it).

Parallelism and pickling
------------------------
Runs are shipped in batches to any :class:`concurrent.futures.Executor` (default: a
``ProcessPoolExecutor`` with 2 workers). A process pool needs the planning model pickled, and
the light-dark noise function is a lambda, which the standard pickle refuses. In order:

1. the payload (model, formula, plan, real system, gains) is pickled as is when it can be;
2. otherwise it is serialised with ``cloudpickle`` if that package is installed (it is with the
   ``dask`` extra);
3. otherwise ``problem_factory`` (a picklable zero-argument callable returning an equivalent
   :class:`~idstlpy.Problem`, e.g. ``functools.partial(scenarios.light_dark, 240, 40)``) rebuilds
   the problem in each worker; the tracking gains travel as plain arrays;
4. otherwise the runs execute in-process (a debug log says so). The result is the same, only
   slower. ``executor="serial"`` asks for the in-process path directly; a
   ``ThreadPoolExecutor`` needs no pickling at all.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import pickle
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from .._checks import as_int, as_seed_sequence, as_vector
from ..chance import joint_slack, slack, std_terms
from ..errors import InvalidArgumentError, InvalidTypeError
from ..execution_target import DEFAULT_EXECUTION_TARGET, ExecutionTarget, as_execution_target
from ..executor import PlantStep, ProcessNoise
from ..formulas import STLAtomicProposition, STLFormula
from ..semantics import atom_margins, formula_margins, robustness
from ..tracking import system_gains
from ..trajectory import ProbabilisticTSTrajectory, RealTrajectory
from .simulation import simulate

if TYPE_CHECKING:  # the prediction is imported when asked for (validate(predict=True))
    from ..dynamical_system import LCS, SwitchedSystem
    from ..executor.law import StepLaw
    from ..synthesis.problem import Problem
    from .prediction import ClosedLoopPrediction

__all__ = ["ValidationReport", "validate", "wilson_interval", "state_trajectory", "prior_starts"]

logger = logging.getLogger(__name__)


def wilson_interval(successes: int, trials: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95% by default).

    Parameters
    ----------
    successes, trials : int
        ``0 <= successes <= trials``.
    z : float
        Standard-normal quantile of the two-sided level (1.96 for 95%).

    Returns
    -------
    (low, high) : tuple of float
        ``(0.0, 1.0)`` when ``trials == 0``.
    """
    successes = as_int(successes, "successes", minimum=0)
    trials = as_int(trials, "trials", minimum=0)
    if successes > trials:
        raise InvalidArgumentError(f"successes must be <= trials, got {successes} > {trials}")
    if trials == 0:
        return 0.0, 1.0
    if successes == 0:
        return 0.0, float(z * z / (trials + z * z))
    if successes == trials:
        return float(trials / (trials + z * z)), 1.0
    p = successes / trials
    z2 = z * z
    denom = 1.0 + z2 / trials
    center = (p + z2 / (2 * trials)) / denom
    half = z * math.sqrt(p * (1 - p) / trials + z2 / (4 * trials * trials)) / denom
    return max(0.0, center - half), min(1.0, center + half)


def prior_starts(
    plan: ProbabilisticTSTrajectory, runs: int, seed: int | np.random.SeedSequence | None = None
) -> np.ndarray:
    """True starts drawn from the plan's prior ``N(mean_0, cov_0)``, one row per run.

    The draws come from ``default_rng(SeedSequence(seed))`` in one call of shape (runs, n), so
    the first ``k`` rows do not depend on ``runs``; a singular ``cov_0`` draws in its range.

    Parameters
    ----------
    plan : ProbabilisticTSTrajectory
        The plan; its first belief is the prior.
    runs : int
        Number of starts (>= 0).
    seed : int or SeedSequence, optional
        Root seed (``validate``'s ``seed``).

    Returns
    -------
    ndarray, shape (runs, n)
    """
    runs = as_int(runs, "runs", minimum=0)
    mean, cov = plan.get_mean(0), plan.get_cov(0)
    factor = _sqrt_psd(cov)
    z = np.random.default_rng(as_seed_sequence(seed)).standard_normal((runs, mean.shape[0]))
    return np.asarray(mean + z @ factor.T)


def _sqrt_psd(cov: np.ndarray) -> np.ndarray:
    """A factor ``L`` with ``L L' = cov`` (Cholesky, else the symmetric square root)."""
    try:
        return np.asarray(np.linalg.cholesky(cov))
    except np.linalg.LinAlgError:
        w, v = np.linalg.eigh(0.5 * (cov + cov.T))
        return np.asarray(v * np.sqrt(np.clip(w, 0.0, None)))


def state_trajectory(real: RealTrajectory) -> ProbabilisticTSTrajectory:
    """The true states as a zero-covariance belief trajectory (the formula's deterministic reading).

    Parameters
    ----------
    real : RealTrajectory
        ``N`` steps of true states, shape (N+1, n).

    Returns
    -------
    ProbabilisticTSTrajectory
        Means = true states, covariances zero, same modes and inputs.
    """
    states = real.get_state()
    n = states.shape[1]
    return ProbabilisticTSTrajectory(
        states, np.zeros((states.shape[0], n, n)), real.get_action(), real.get_control()
    )


@dataclass(frozen=True)
class ValidationReport:
    """Outcome of :func:`validate`.

    Attributes
    ----------
    runs : int
        Number of executions.
    seed_entropy : int or tuple of int
        Entropy of the root ``SeedSequence`` (pass it as ``seed``, or
        ``SeedSequence(seed_entropy)``, to reproduce the report).
    num_of_steps : int
        Steps executed per run.
    plan_margin : float
        Monitor robustness of the plan itself.
    belief_successes, state_successes : int
        Runs whose executed belief / true states satisfy the formula.
    belief_success_rate, state_success_rate : float
    belief_ci, state_ci : tuple of float
        Wilson 95% confidence intervals of the two rates.
    belief_margins, state_margins : tuple of float
        Per run, the robustness of the executed belief / of the true states.
    proposition_violations : dict
        Per atomic proposition name: ``{"belief": rate, "state": rate, "belief_ci": [lo, hi],
        "state_ci": [lo, hi]}``; the fraction of runs that broke it at a step where the plan
        satisfies it.
    predicate_violations : dict
        The same per predicate, keyed ``"<proposition>: <predicate>"``.
    elapsed : float
        Wall-clock seconds (not part of equality).
    executions : tuple of (ProbabilisticTSTrajectory, RealTrajectory)
        The first ``keep_trajectories`` executions, for plotting (not part of equality).
    predicted : ClosedLoopPrediction or None
        With ``validate(predict=True)``: the predicted execution under the same options (not
        part of equality); compare with :meth:`prediction_comparison`.
    replans : tuple of int
        With ``validate(replan=...)``: the re-solves of every run (empty without re-planning).
    true_start : tuple of float or None
        The fixed true start of every run, or None when every run drew its own true start from
        the prior (the plan's initial belief), :func:`validate`'s default.
    execution_target : ExecutionTarget
        The success rates the verdict (:attr:`meets_target`, :meth:`verdict`) is against
        (default 90% belief / 95% true state).
    """

    runs: int
    seed_entropy: int | tuple[int, ...]
    num_of_steps: int
    plan_margin: float
    belief_successes: int
    state_successes: int
    belief_success_rate: float
    state_success_rate: float
    belief_ci: tuple[float, float]
    state_ci: tuple[float, float]
    belief_margins: tuple[float, ...]
    state_margins: tuple[float, ...]
    proposition_violations: dict[str, dict[str, Any]]
    predicate_violations: dict[str, dict[str, Any]]
    elapsed: float = field(default=0.0, compare=False)
    executions: tuple[tuple[ProbabilisticTSTrajectory, RealTrajectory], ...] = field(
        default=(), compare=False, repr=False
    )
    predicted: ClosedLoopPrediction | None = field(default=None, compare=False, repr=False)
    replans: tuple[int, ...] = ()
    true_start: tuple[float, ...] | None = None
    execution_target: ExecutionTarget = DEFAULT_EXECUTION_TARGET

    @property
    def start_drawn(self) -> bool:
        """True when every run drew its true start from the prior (no fixed start)."""
        return self.true_start is None

    @property
    def true_start_text(self) -> str:
        """``"drawn from the prior"`` or ``"fixed at [x, y]"``: what the rates are about."""
        if self.true_start is None:
            return "drawn from the prior"
        return "fixed at [" + ", ".join(f"{v:.4g}" for v in self.true_start) + "]"

    @property
    def meets_target(self) -> bool:
        """Whether both measured success rates reach :attr:`execution_target`."""
        return self.execution_target.met_by(self.belief_success_rate, self.state_success_rate)

    def verdict(self) -> str:
        """One line: the measured rates against :attr:`execution_target`, and which fall short.

        ``"meets the target ..."`` or ``"BELOW the target ...: belief 85.0% < 90%"``; the
        verdict compares the measured rates (not their intervals) with the target.

        Returns
        -------
        str
        """
        target = self.execution_target
        measured = (
            f"belief {_pct(self.belief_success_rate)} {_ci(self.belief_ci)}, "
            f"true state {_pct(self.state_success_rate)} {_ci(self.state_ci)}"
        )
        short = target.shortfalls(self.belief_success_rate, self.state_success_rate)
        if not short:
            return f"meets the target ({target}): {measured}"
        what = "; ".join(
            f"{'true state' if r == 'state' else r} {_pct(getattr(self, f'{r}_success_rate'))} "
            f"< {100 * getattr(target, r):.4g}%"
            for r in short
        )
        return f"BELOW the target ({target}): {what} (measured {measured})"

    def meets(self, belief: float = 0.90, state: float = 0.95) -> bool:
        """Whether both success rates reach the given bars.

        Parameters
        ----------
        belief : float
            Least acceptable belief success rate (the paper's 0.90).
        state : float
            Least acceptable state success rate (the paper's 0.95).

        Returns
        -------
        bool
        """
        return self.belief_success_rate >= belief and self.state_success_rate >= state

    def prediction_comparison(self) -> dict[str, Any] | None:
        """Predicted next to measured: violation rates per predicate and proposition, success.

        Every entry is ``{"predicted": p, "measured": r, "ci": [lo, hi], "diff": p - r,
        "outside": flag}`` with ``[lo, hi]`` the measured rate's Wilson 95% interval and
        ``outside`` True when ``p`` falls outside it (None when ``p`` is NaN). ``p`` is the
        prediction's model-sampling estimate (:attr:`ClosedLoopPrediction.samples` samples), so
        it carries a small sampling error of its own. At the 95% level about one rate in twenty
        falls outside by chance even when the prediction is exact.

        Returns
        -------
        dict or None
            None without a prediction. Else ``{"predicates": {name: {"belief": entry, "state":
            entry}}, "propositions": {...}, "success": {"belief": entry, "state": entry},
            "outside": n, "compared": n, "max_abs_diff": d}``; the success entries add
            ``bound`` (the analytic lower bound, sound for the Gaussian model),
            ``sampled_bound`` and ``bound_holds`` (``bound <= hi``). ``outside`` counts the
            flagged rates among the ``compared`` ones; ``max_abs_diff`` is the largest
            ``|predicted - measured|`` over the predicates' violation rates.
        """
        pred = self.predicted
        if pred is None:
            return None
        pred_rates = pred.predicate_violation
        predicates = {
            name: {
                r: _comparison(pred_rates.get(name, {}).get(r, float("nan")), v[r], v[f"{r}_ci"])
                for r in ("belief", "state")
            }
            for name, v in self.predicate_violations.items()
        }
        propositions = {
            name: {
                r: _comparison(
                    pred.proposition_violation.get(name, {}).get(r, float("nan")), v[r], v[f"{r}_ci"]
                )
                for r in ("belief", "state")
            }
            for name, v in self.proposition_violations.items()
        }
        success: dict[str, dict[str, Any]] = {}
        for r in ("belief", "state"):
            ci = getattr(self, f"{r}_ci")
            entry = _comparison(
                getattr(pred, f"{r}_success_estimate"), getattr(self, f"{r}_success_rate"), ci
            )
            bound = float(getattr(pred, f"{r}_success_bound"))
            entry["bound"] = bound if math.isfinite(bound) else None
            sampled = float(getattr(pred, f"{r}_success_sampled_bound"))
            entry["sampled_bound"] = sampled if math.isfinite(sampled) else None
            # the bound is a promise: it must not exceed what the executions can still be
            entry["bound_holds"] = None if not math.isfinite(bound) else bool(bound <= ci[1] + 1e-12)
            success[r] = entry
        entries = [e for d in (predicates, propositions) for v in d.values() for e in v.values()]
        entries += list(success.values())
        compared = [e for e in entries if e["outside"] is not None]
        diffs = [abs(e["diff"]) for v in predicates.values() for e in v.values() if e["outside"] is not None]
        return {
            "predicates": predicates,
            "propositions": propositions,
            "success": success,
            "outside": sum(bool(e["outside"]) for e in compared),
            "compared": len(compared),
            "max_abs_diff": max(diffs) if diffs else None,
        }

    def summary(self) -> str:
        """A plain-text table: the success rates, then violation rates per predicate.

        With a prediction (``validate(predict=True)``) each rate has its predicted value beside
        it and a ``!`` when that value falls outside the measured Wilson 95% interval.

        Returns
        -------
        str
        """
        cmp = self.prediction_comparison()
        lines = [
            f"{self.runs} runs of {self.num_of_steps} steps, plan margin {self.plan_margin:.4g}, "
            f"{self.elapsed:.3g} s",
            f"true start: {self.true_start_text}",
        ]

        def cell(entry: dict[str, Any] | None, rate: float, ci: Sequence[float]) -> str:
            text = f"{_pct(rate)} {_ci(ci)}"
            if entry is not None:
                p = entry["predicted"]
                flag = " !" if entry["outside"] else ""
                text += f" pred {'n/a' if p is None else _pct(p)}{flag}"
            return text

        for r, label in (("belief", "executed belief"), ("state", "true state")):
            entry = None if cmp is None else cmp["success"][r]
            rate, ci = getattr(self, f"{r}_success_rate"), getattr(self, f"{r}_ci")
            text = f"success, {label}: {cell(entry, rate, ci)}"
            if entry is not None and entry["bound"] is not None:
                above = "" if entry["bound_holds"] else ", ABOVE the interval"
                text += f" (bound {_pct(entry['bound'])}{above})"
            lines.append(text)
        rows = [
            (name, v, None if cmp is None else cmp["predicates"][name])
            for name, v in self.predicate_violations.items()
        ]
        if rows:
            width = max(len(name) for name, _, _ in rows)
            lines.append(f"{'violated at a promised step'.ljust(width)}  belief / true state")
            for name, v, entry in rows:
                b = cell(None if entry is None else entry["belief"], v["belief"], v["belief_ci"])
                st = cell(None if entry is None else entry["state"], v["state"], v["state_ci"])
                lines.append(f"{name.ljust(width)}  {b} / {st}")
        lines.append(f"verdict: {self.verdict()}")
        if cmp is not None:
            worst = cmp["max_abs_diff"]
            lines.append(
                f"prediction: {cmp['outside']} of {cmp['compared']} predicted rates outside the measured "
                f"95% interval; worst per-predicate |predicted - measured| "
                f"{'n/a' if worst is None else f'{worst:.3f}'}"
            )
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (
            f"ValidationReport(runs={self.runs}, num_of_steps={self.num_of_steps}, "
            f"belief={_pct(self.belief_success_rate)} {_ci(self.belief_ci)}, "
            f"state={_pct(self.state_success_rate)} {_ci(self.state_ci)}, "
            f"plan_margin={self.plan_margin:.4g}, true_start={self.true_start_text!r}, "
            f"meets_target={self.meets_target}, propositions={len(self.proposition_violations)}, "
            f"predicates={len(self.predicate_violations)}, elapsed={self.elapsed:.3g}s)"
        )

    def _repr_html_(self) -> str:
        """A small HTML table for notebooks: the two rates, then violations per proposition."""
        from html import escape

        head = (
            f"<b>ValidationReport</b>: {self.runs} runs of {self.num_of_steps} steps, "
            f"plan margin {self.plan_margin:.4g}, {self.elapsed:.3g} s; true start "
            f"{escape(self.true_start_text)}; {escape(self.verdict())}"
        )
        rows = [
            "<tr><th></th><th>success</th><th>95% CI</th><th>margin min / median</th></tr>",
        ]
        for name, rate, ci, margins in (
            ("executed belief", self.belief_success_rate, self.belief_ci, self.belief_margins),
            ("true state", self.state_success_rate, self.state_ci, self.state_margins),
        ):
            st = _margin_stats(margins)
            rows.append(
                f"<tr><td>{name}</td><td>{_pct(rate)}</td><td>{_ci(ci)}</td>"
                f"<td>{st['min']:.3g} / {st['median']:.3g}</td></tr>"
            )
        viol = [
            "<tr><th>proposition</th><th>broken (belief)</th><th>broken (state)</th></tr>",
        ]
        for name, v in self.proposition_violations.items():
            viol.append(
                f"<tr><td>{escape(name)}</td><td>{_pct(v['belief'])} {_ci(v['belief_ci'])}</td>"
                f"<td>{_pct(v['state'])} {_ci(v['state_ci'])}</td></tr>"
            )
        return f"<div><p>{head}</p><table>{''.join(rows)}</table><table>{''.join(viol)}</table></div>"

    def as_dict(self) -> dict[str, Any]:
        """Plain-data copy for JSON (margins summarised; trajectories left out).

        Returns
        -------
        dict
            Rates, intervals, margin summaries (``min``, ``median``, ``max``; NaN when no run
            has a finite margin) and violation rates; ``true_start`` (``"prior"`` or the fixed
            start as a list), ``execution_target`` (``{"belief": b, "state": s}``),
            ``meets_target`` and ``verdict`` (:meth:`verdict`).
        """

        return {
            "runs": self.runs,
            "seed_entropy": list(self.seed_entropy)
            if isinstance(self.seed_entropy, tuple)
            else self.seed_entropy,
            "num_of_steps": self.num_of_steps,
            "true_start": "prior" if self.true_start is None else list(self.true_start),
            "plan_margin": self.plan_margin,
            "belief_successes": self.belief_successes,
            "state_successes": self.state_successes,
            "belief_success_rate": self.belief_success_rate,
            "state_success_rate": self.state_success_rate,
            "belief_ci": list(self.belief_ci),
            "state_ci": list(self.state_ci),
            "belief_margin": _margin_stats(self.belief_margins),
            "state_margin": _margin_stats(self.state_margins),
            "proposition_violations": {k: dict(v) for k, v in self.proposition_violations.items()},
            "predicate_violations": {k: dict(v) for k, v in self.predicate_violations.items()},
            "execution_target": self.execution_target.as_dict(),
            "meets_target": self.meets_target,
            "verdict": self.verdict(),
            **({} if self.predicted is None else {"prediction": self._prediction_dict()}),
            **({"replans": list(self.replans)} if self.replans else {}),
            "elapsed": self.elapsed,
        }

    def _prediction_dict(self) -> dict[str, Any]:
        """The comparison plus the prediction's own summary numbers (no per-step arrays)."""
        pred = self.predicted
        if pred is None:
            return {}
        out = dict(self.prediction_comparison() or {})
        out["sensor_noise"] = pred.sensor_noise
        out["samples"] = pred.samples
        out["max_clip_probability"] = (
            float(pred.clip_probability.max()) if pred.clip_probability.size else 0.0
        )
        return out

    to_dict = as_dict


def _pct(rate: float) -> str:
    return f"{100 * rate:.1f}%"


def _ci(ci: Sequence[float]) -> str:
    return f"[{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]"


def _comparison(predicted: float, measured: float, ci: Sequence[float]) -> dict[str, Any]:
    """One predicted rate against a measured one and its interval (see prediction_comparison)."""
    p = float(predicted)
    if not math.isfinite(p):
        return {"predicted": None, "measured": measured, "ci": list(ci), "diff": None, "outside": None}
    # a hair of slack: a rate predicted exactly at an interval's end (0 or 1) is inside it
    outside = not (ci[0] - 1e-12 <= p <= ci[1] + 1e-12)
    return {"predicted": p, "measured": measured, "ci": list(ci), "diff": p - measured, "outside": outside}


def _margin_stats(values: Sequence[float]) -> dict[str, float]:
    arr = np.asarray(values, dtype=float)
    finite = arr[np.isfinite(arr)]
    if not finite.size:
        return {"min": float("nan"), "median": float("nan"), "max": float("nan")}
    return {"min": float(finite.min()), "median": float(np.median(finite)), "max": float(finite.max())}


# --------------------------------------------------------------------------------------------
# Workers (module level so that process pools can pickle them)


@dataclass
class _Payload:
    system: SwitchedSystem | None  # None when rebuilt by the factory
    formula: STLFormula | None
    factory: Callable[[], Problem] | None
    plan: ProbabilisticTSTrajectory
    real_system: SwitchedSystem | LCS | None
    real_initial_state: np.ndarray
    num_of_steps: int
    sim_options: dict[str, Any]
    keep: int
    # validate(replan=...): the problem and execute()'s re-plan options (None: simulate only)
    problem: Problem | None = None
    replan: dict[str, Any] | None = None
    # runs executed together as arrays (the step law over a batch); False: one run at a time
    batched: bool = True


def _propositions(formula: STLFormula) -> list[STLAtomicProposition]:
    return [ap for ap in formula.atomic_propositions() if not ap.is_false and not ap.is_true]


def _face_slacks(ap: STLAtomicProposition, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """Slack of every chance predicate of ``ap`` at every step, shape (L, k) (:func:`chance.slack`).

    The faces of a joint chance constraint all get its margin (:func:`chance.joint_slack`): each is
    violated where the joint constraint is, as the monitor judges it.
    """
    cone = ap.cone
    if cone.num_faces == 0:
        return np.zeros((means.shape[0], 0))
    out = slack(cone.H, cone.c, cone.z, means, covs)
    at = ap.num_single
    for joint in ap.joints:
        out[:, at : at + joint.num_faces] = joint_slack(joint.H, joint.c, joint.eps, means, covs)[:, None]
        at += joint.num_faces
    return out


def _promises(formula: STLFormula, plan: ProbabilisticTSTrajectory, L: int) -> list[np.ndarray]:
    """Per proposition, the steps (< L) at which the plan satisfies it, as boolean masks."""
    out = []
    for ap in _propositions(formula):
        margins = atom_margins(ap, plan.get_mean(), plan.get_cov(), plan.get_action())
        mask = np.zeros(L, dtype=bool)
        upto = min(L, margins.shape[0])
        mask[:upto] = margins[:upto] >= 0.0
        out.append(mask)
    return out


def _violations(
    formula: STLFormula, traj: ProbabilisticTSTrajectory, promises: list[np.ndarray]
) -> tuple[list[bool], list[bool]]:
    means, covs, actions = traj.get_mean(), traj.get_cov(), traj.get_action()
    props: list[bool] = []
    preds: list[bool] = []
    for ap, mask in zip(_propositions(formula), promises, strict=True):
        margins = atom_margins(ap, means, covs, actions)
        # With re-plans the execution may be longer or shorter than the plan: compare the
        # steps both have (the promise is the original plan's).
        mask = mask[: margins.shape[0]]
        margins = margins[: mask.shape[0]]
        props.append(bool(np.any(margins[mask] < 0.0)))
        faces = _face_slacks(ap, means, covs)[: mask.shape[0]]
        preds.extend(bool(np.any(faces[mask, j] < 0.0)) for j in range(faces.shape[1]))
    return props, preds


def _execute(
    payload: _Payload,
    seeds: Sequence[np.random.SeedSequence],
    first_index: int,
    starts: np.ndarray | None = None,
) -> list[dict[str, Any]]:
    """Run the executions of one batch (``first_index`` is the index of ``seeds[0]``).

    ``starts`` (one row per seed) are the runs' true starts; None: ``payload.real_initial_state``.
    """
    if payload.system is None:
        problem = payload.factory()  # type: ignore[misc]
        system, formula = problem.switched_system, problem.stl_formula
    else:
        system, formula = payload.system, payload.formula
    L = payload.num_of_steps + 1
    promises = _promises(formula, payload.plan, L)
    # (a plant step function draws from the generator it is given: one run at a time)
    if payload.replan is None and payload.batched and payload.sim_options.get("plant") is None:
        results: list[dict[str, Any]] = []
        size = _batch_size(payload.num_of_steps, system.n)
        for lo in range(0, len(seeds), size):
            part = seeds[lo : lo + size]
            x0s = None if starts is None else starts[lo : lo + size]
            results.extend(_execute_batch(payload, system, formula, promises, part, first_index + lo, x0s))
        return results
    results = []
    for offset, ss in enumerate(seeds):
        x0 = payload.real_initial_state if starts is None else starts[offset]
        replans = 0
        if payload.replan is not None:
            from .replanning import ReplanPolicy, execute

            of_run = problem if payload.system is None else payload.problem
            assert of_run is not None  # validate(replan=...) puts the problem in the payload
            run = execute(
                of_run,
                payload.plan,
                payload.real_system,
                x0,
                seed=ss,  # execute draws from default_rng(ss): the same noise as simulate below
                clip_controls=payload.sim_options["control_domain"] is not None,
                process_noise=payload.sim_options["process_noise"],
                lqr_gains=payload.sim_options["lqr_gains"],
                plant=payload.sim_options["plant"],
                policy=ReplanPolicy.from_keywords(**payload.replan),
            )
            xi_sim, xi_real, replans = run.belief, run.real, run.num_replans
        else:
            xi_sim, xi_real = simulate(
                system,
                payload.plan,
                payload.num_of_steps,
                x0,
                payload.real_system,
                seed=np.random.default_rng(ss),
                **payload.sim_options,
            )
        state_traj = state_trajectory(xi_real)
        b_props, b_preds = _violations(formula, xi_sim, promises)
        s_props, s_preds = _violations(formula, state_traj, promises)
        res: dict[str, Any] = {
            "belief_margin": robustness(xi_sim, formula),
            "state_margin": robustness(state_traj, formula),
            "belief_props": b_props,
            "belief_preds": b_preds,
            "state_props": s_props,
            "state_preds": s_preds,
        }
        if payload.replan is not None:
            res["replans"] = replans
        if first_index + offset < payload.keep:
            res["trajectories"] = (xi_sim, xi_real)
        results.append(res)
    return results


BATCH_RUNS = 4096
"""Most runs executed together as arrays by one worker; fewer when a run's arrays are large
(:func:`_batch_size`: about 32 MB of covariances per batch). The results do not depend on it:
every run draws from its own stream (:class:`_RunStreams`)."""


def _batch_size(steps: int, n: int) -> int:
    """Runs per batch: :data:`BATCH_RUNS`, fewer when ``runs x (steps + 1) x n^2`` exceeds 4e6."""
    return int(max(16, min(BATCH_RUNS, 4_000_000 // max(1, (steps + 1) * n * n))))


class _RunStreams:
    """A stand-in for the generator of the step law over ``S`` runs: row ``i`` of every draw
    comes from run ``i``'s own generator ``default_rng(seeds[i])``, in the order the run would
    draw alone, so a run executed in a batch gets the noise :func:`simulate` gives it.

    The runs' normals are drawn ahead in blocks (one call per run and block); drawing more
    than a run uses changes nothing, its generator is its own.
    """

    def __init__(self, seeds: Sequence[np.random.SeedSequence], ahead: int) -> None:
        self._gens = [np.random.default_rng(ss) for ss in seeds]
        self._ahead = max(1, int(ahead))
        self._buf = np.empty((len(self._gens), 0))
        self._pos = 0

    def standard_normal(self, size: tuple[int, int]) -> np.ndarray:
        S, r = size
        if S != len(self._gens):  # pragma: no cover - the law always draws one row per run
            raise InvalidArgumentError(f"expected a draw for {len(self._gens)} runs, got {S}")
        if self._pos + r > self._buf.shape[1]:
            fresh = np.empty((S, max(r, self._ahead)))
            for i, gen in enumerate(self._gens):
                gen.standard_normal(out=fresh[i])
            self._buf = np.hstack([self._buf[:, self._pos :], fresh])
            self._pos = 0
        out = self._buf[:, self._pos : self._pos + r]
        self._pos += r
        return out


def _draws_per_run(law: StepLaw) -> int:
    """The normals one run draws along the law's steps (process noise, then the sensor's)."""
    total = 0
    for st in law.steps:
        if st.W is not None:
            total += st.W.shape[1]
        if st.model.p:
            total += st.model.noise(st.mean).shape[1]
    return total


def _execute_batch(
    payload: _Payload,
    system: SwitchedSystem,
    formula: STLFormula,
    promises: list[np.ndarray],
    seeds: Sequence[np.random.SeedSequence],
    first_index: int,
    starts: np.ndarray | None,
) -> list[dict[str, Any]]:
    """Execute ``len(seeds)`` runs together with the step law over a batch, then monitor them
    together; the same records as :func:`_execute`'s one-run-at-a-time loop (up to rounding).

    Arrays are kept time-major, (L, S, ...), so each step writes one contiguous block and the
    monitor reads contiguous traces.
    """
    from ..executor import ExecutorSpec, StepLaw

    plan, N = payload.plan, payload.num_of_steps
    S, n = len(seeds), system.n
    opts = payload.sim_options
    spec = ExecutorSpec.make(
        system,
        control_domain=opts["control_domain"],
        process_noise=opts["process_noise"],
        lqr_gains=opts["lqr_gains"],
        real_system=payload.real_system,
        modes=plan.get_action()[:N].tolist(),
    )
    law = StepLaw(spec, plan, N)
    rng = _RunStreams(seeds, _draws_per_run(law))
    keep = max(0, min(S, payload.keep - first_index))

    X = np.tile(payload.real_initial_state, (S, 1)) if starts is None else np.array(starts, dtype=float)
    M = np.tile(plan.get_mean(0), (S, 1))
    P: np.ndarray = plan.get_cov(0).copy()
    means = np.empty((N + 1, S, n))
    states = np.empty((N + 1, S, n))
    controls = np.empty((N, S, system.m))
    covs: list[np.ndarray] = [P]
    observations = np.full((N + 1, keep, law.p_max), np.nan)
    means[0], states[0] = M, X
    for k in range(N):
        U = law.control(k, M)
        X = law.plant(k, X, U, rng)  # type: ignore[arg-type]
        Y = law.observe(k, X, rng)  # type: ignore[arg-type]
        M, P = law.filter(k, M, P, U, Y)
        means[k + 1], states[k + 1], controls[k] = M, X, U
        covs.append(P)
        if Y is not None and keep:
            observations[k + 1, :, : Y.shape[1]] = Y[:keep]
        if not (np.isfinite(M).all() and np.isfinite(X).all()):
            raise InvalidArgumentError(f"the execution diverged at step {k + 1} (non-finite state)")
    # the filter's covariances: shared by the runs (L, n, n) while the noise is constant
    shared = all(c.ndim == 2 for c in covs)
    cov_arr = np.stack(covs) if shared else np.stack([np.broadcast_to(c, (S, n, n)) for c in covs])
    actions = plan.get_action()[:N]
    belief = _batch_monitor(formula, promises, means, cov_arr, actions)
    state = _batch_monitor(formula, promises, states, None, actions)
    b_props, b_preds = belief["props"].tolist(), belief["preds"].tolist()
    s_props, s_preds = state["props"].tolist(), state["preds"].tolist()
    b_margin, s_margin = belief["margin"].tolist(), state["margin"].tolist()
    results: list[dict[str, Any]] = []
    for i in range(S):
        res: dict[str, Any] = {
            "belief_margin": b_margin[i],
            "state_margin": s_margin[i],
            "belief_props": b_props[i],
            "belief_preds": b_preds[i],
            "state_props": s_props[i],
            "state_preds": s_preds[i],
        }
        if i < keep:
            run_covs = cov_arr if shared else cov_arr[:, i]
            res["trajectories"] = (
                ProbabilisticTSTrajectory(
                    means[:, i].copy(), np.array(run_covs), actions, controls[:, i].copy()
                ),
                RealTrajectory(
                    states[:, i].copy(), observations[:, i].copy(), actions, controls[:, i].copy()
                ),
            )
        results.append(res)
    return results


def _batch_monitor(
    formula: STLFormula,
    promises: list[np.ndarray],
    means: np.ndarray,
    covs: np.ndarray | None,
    actions: np.ndarray,
) -> dict[str, np.ndarray]:
    """The monitor over a batch of ``S`` trajectories at once.

    ``means`` (L, S, n); ``covs`` (L, n, n) shared by the runs, (L, S, n, n), or None for the
    true states (the deterministic reading: zero covariance). Returns ``margin`` (S,) (the
    robustness at step 0, :func:`~idstlpy.semantics.formula_margins` over the batch), ``props``
    (S, #propositions) and ``preds`` (S, #predicates): broken at a promised step. Each face's
    slack is :func:`~idstlpy.chance.slack` (``-(h' mean + c + z sd)``) over the batch.
    """
    L, S, n = means.shape
    atoms: dict[int, np.ndarray] = {}
    faces_of: dict[int, np.ndarray] = {}
    for ap in formula.atomic_propositions():
        key = id(ap)
        if key in atoms:
            continue
        if ap.is_false:
            atoms[key] = np.full((L, S), -np.inf)
            continue
        out = np.full((L, S), np.inf)
        faces = np.zeros((0, L, S))
        if ap.predicates and getattr(ap, "joints", ()):
            # joint chance constraints: the monitor's own atom_margins over the flattened batch
            # (its mode test made void here, applied below), and every face's slack for the counts
            flat_means = means.reshape(L * S, n)
            if covs is None:
                flat_covs = np.zeros((L * S, n, n))
            elif covs.ndim == 3:
                flat_covs = np.broadcast_to(covs[:, None], (L, S, n, n)).reshape(L * S, n, n)
            else:
                flat_covs = covs.reshape(L * S, n, n)
            any_mode = min(ap.modes) if ap.modes else 0
            out = atom_margins(ap, flat_means, flat_covs, np.full(L * S - 1, any_mode)).reshape(L, S)
            # each face's slack, a joint constraint's faces its margin (as the serial loop counts them)
            faces = np.moveaxis(_face_slacks(ap, flat_means, flat_covs).reshape(L, S, -1), 2, 0)
        elif ap.predicates:
            cone = ap.cone
            F = cone.H.shape[0]
            if covs is None:
                std = std_terms(cone.H, cone.z, np.zeros((1, n, n)))[0]  # (F,)
            elif covs.ndim == 3:
                std = std_terms(cone.H, cone.z, covs).T[:, :, None]  # (F, L, 1)
            else:
                std = np.moveaxis(std_terms(cone.H, cone.z, covs.reshape(L * S, n, n)).reshape(L, S, F), 2, 0)
            faces = np.empty((F, L, S))
            for j in range(F):
                face = faces[j]
                np.matmul(means, cone.H[j], out=face)
                face += cone.c[j]
                face += std[j]
                np.negative(face, out=face)
            if F:
                out = faces.min(axis=0)
        if ap.modes is not None and L > 1:
            allowed = np.isin(actions, np.fromiter(ap.modes, dtype=int, count=len(ap.modes)))
            out[1:][~allowed] = -np.inf
        atoms[key] = out
        faces_of[key] = faces
    props = np.zeros((S, len(promises)), dtype=bool)
    preds: list[np.ndarray] = []
    for j, (ap, promise) in enumerate(zip(_propositions(formula), promises, strict=True)):
        mask = promise[:L]
        props[:, j] = np.asarray((atoms[id(ap)][mask] < 0.0).any(axis=0))
        preds.append(np.asarray((faces_of[id(ap)][:, mask] < 0.0).any(axis=1)).T)  # (S, F)
    margin = formula_margins(formula, atoms, L)[0] if L else np.full(S, -np.inf)
    return {
        "margin": np.asarray(margin, dtype=float),
        "props": props,
        "preds": np.concatenate(preds, axis=1) if preds else np.zeros((S, 0), dtype=bool),
    }


def _run_batch(
    blob: bytes, seeds: Sequence[np.random.SeedSequence], first_index: int, starts: np.ndarray | None = None
) -> list[dict[str, Any]]:
    """Worker entry point: unpickle the payload, then :func:`_execute`."""
    return _execute(pickle.loads(blob), seeds, first_index, starts)


def _serialise(payload: _Payload, problem_factory: Callable[[], Problem] | None) -> bytes | None:
    """Bytes loadable by ``pickle.loads`` in a worker, or None when the problem cannot travel."""
    try:
        return pickle.dumps(payload)
    except Exception as exc:  # noqa: BLE001 - any pickling failure sends us to the next option
        logger.debug("validate: payload not picklable (%s)", exc)
    try:
        import cloudpickle  # type: ignore[import-not-found, unused-ignore]

        blob: bytes = cloudpickle.dumps(payload)
        return blob
    except Exception as exc:  # noqa: BLE001
        logger.debug("validate: cloudpickle unavailable or failed (%s)", exc)
    if problem_factory is not None:
        slim = dataclasses.replace(payload, system=None, formula=None, factory=problem_factory, problem=None)
        try:
            return pickle.dumps(slim)
        except Exception as exc:  # noqa: BLE001
            raise InvalidArgumentError(
                f"problem_factory must be picklable (a module-level function or functools.partial): {exc}"
            ) from exc
    return None


SMALL_WORK = 200_000
"""``validate(executor=None)`` runs in-process up to this many run-steps (batched runs only): about
a third of a second of the listing's work on one core, less than starting worker processes."""


PREDICT_SAMPLES = 20000
"""Default model samples of ``validate(predict=True)``: their sampling error (at most 0.0035 on a
rate) is a tenth of the Wilson half-width of 1000 runs, so a flag says something about the model."""

PREDICT_OPTIONS = ("sensor_noise", "filter_sensitivity", "samples", "seed", "closure", "particles")
"""Keys ``predict_options`` accepts (the rest of the prediction's options are validate's own)."""


def _predict(
    problem: Problem,
    plan: ProbabilisticTSTrajectory,
    real_system: SwitchedSystem | LCS | None,
    real_initial_state: np.ndarray,
    steps: int,
    sim_options: Mapping[str, Any],
    options: Mapping[str, Any] | None,
    start_cov: np.ndarray | None = None,
) -> ClosedLoopPrediction:
    """The prediction of exactly the execution ``validate`` runs (same gains, domain, noise, start).

    ``start_cov``: the covariance of a true start drawn from the prior (None: a fixed start).
    """
    from .prediction import predict_closed_loop

    if options is not None and not isinstance(options, Mapping):
        raise InvalidTypeError(f"predict_options must be a mapping, got {type(options).__name__}")
    opts = dict(options or {})
    unknown = sorted(set(opts) - set(PREDICT_OPTIONS))
    if unknown:
        raise InvalidArgumentError(
            f"predict_options: unknown or execution keys {unknown}; accepted: {', '.join(PREDICT_OPTIONS)} "
            "(the execution options are validate's own)"
        )
    opts.setdefault("samples", PREDICT_SAMPLES)
    t0 = time.perf_counter()
    predicted = predict_closed_loop(
        problem,
        plan,
        real_system,
        real_initial_state,
        num_of_steps=steps,
        control_domain=sim_options["control_domain"],
        process_noise=sim_options["process_noise"],
        lqr_gains=sim_options["lqr_gains"],
        real_initial_cov=start_cov,
        **opts,
    )
    logger.debug("validate: closed-loop prediction in %.3g s", time.perf_counter() - t0)
    return predicted


REPLAN_OPTION_KEYS = frozenset(
    {
        "risk",
        "every",
        "check_every",
        "drift",
        "start_resolves",
        "risk_measure",
        "risk_on",
        "risk_samples",
        "max_replans",
        "replan_time_limit",
        "options",
        "solver_options",
        "adopt",
    }
)
"""Keys ``replan_options`` accepts (the execution options are validate's own); problem files'
``[validation.replan_options]`` reads the same keys but ``options`` (their ``[solver]``)."""


def _replan_options(
    replan: str | None,
    options: Mapping[str, Any] | None,
    num_of_steps: int | None,
    plan: ProbabilisticTSTrajectory,
) -> dict[str, Any]:
    """``execute``'s keywords for ``validate(replan=...)``, checked here (errors name the argument)."""
    if replan not in ("on_risk", "every"):
        raise InvalidArgumentError(
            f"replan must be None, 'on_risk' or 'every' (with replan_options), got {replan!r}"
        )
    if options is not None and not isinstance(options, Mapping):
        raise InvalidTypeError(f"replan_options must be a mapping, got {type(options).__name__}")
    unknown = sorted(set(options or {}) - REPLAN_OPTION_KEYS)
    if unknown:
        raise InvalidArgumentError(
            f"replan_options has unknown keys {unknown}; accepted: {sorted(REPLAN_OPTION_KEYS)}"
        )
    if num_of_steps is not None and num_of_steps != plan.num_of_steps:
        raise InvalidArgumentError(
            "num_of_steps cannot be combined with replan: a re-planned run follows its plans to their end"
        )
    return {"replan": replan, **dict(options or {})}


def validate(
    problem: Problem,
    solution: ProbabilisticTSTrajectory,
    real_system: SwitchedSystem | LCS | None,
    real_initial_state: ArrayLike | Literal["prior"] | None = None,
    runs: int = 100,
    seed: int | np.random.SeedSequence | None = None,
    executor: Executor | str | None = None,
    *,
    num_of_steps: int | None = None,
    clip_controls: bool = True,
    process_noise: ProcessNoise = "model",
    lqr_gains: Mapping[int, Sequence[np.ndarray]] | Sequence[Sequence[np.ndarray] | None] | None = None,
    default_lqr: Mapping[str, Any] | None = None,
    problem_factory: Callable[[], Problem] | None = None,
    max_workers: int = 2,
    keep_trajectories: int = 0,
    progress: Callable[[int, int], None] | None = None,
    predict: bool = False,
    predict_options: Mapping[str, Any] | None = None,
    replan: str | None = None,
    replan_options: Mapping[str, Any] | None = None,
    execution_target: ExecutionTarget | Sequence[float] | Mapping[str, float] | None = None,
    plant: PlantStep | None = None,
    batched: bool = True,
) -> ValidationReport:
    """Execute a plan many times and measure how often its promise held.

    Parameters
    ----------
    problem : Problem
        The problem the plan solves (model, control domain, formula).
    solution : ProbabilisticTSTrajectory
        The plan.
    real_system : SwitchedSystem or None
        The system moving the true state (e.g. :func:`idstlpy.scenarios.light_dark_real_system`);
        None with ``plant``.
    real_initial_state : array_like of shape (n,), "prior" or None
        The true initial state. None or ``"prior"`` (the default): every run draws its own true
        start from the prior, the plan's initial belief ``N(mean_0, cov_0)``, so the rates are
        the ones the plan's promise is about when the true start is unknown. An array: every run
        starts at that state (the paper's listing passes ``[0.5, 2.75]``). The report says which
        (:attr:`ValidationReport.true_start`). The starts come from their own stream
        (``default_rng(SeedSequence(seed))``, one draw of shape ``(runs, n)``), so run ``i``'s
        noise is the same as with a fixed start.
    runs : int
        Number of independent executions (>= 1).
    seed : int or SeedSequence, optional
        Root of the run seeds; the same seed gives the identical report for any executor.
    executor : concurrent.futures.Executor, "serial" or None
        Where runs execute. ``None``: in-process when the runs are batched and few
        (``runs x steps <= SMALL_WORK``, a fraction of a second: starting worker processes would
        cost more), else a ``ProcessPoolExecutor(max_workers)`` made (and shut down) here;
        ``"serial"``: in-process. The report is the same on every executor. See the module notes
        on pickling.
    num_of_steps : int, optional
        Steps per run (default the whole plan).
    clip_controls : bool
        Project the corrected inputs on ``problem.control_domain`` (default True).
    process_noise : {"model", "real", "none"}
        See :func:`~idstlpy.execution.simulation.simulate`.
    lqr_gains : mapping or sequence, optional
        Per mode gains; default each mode's ``lqr_gains`` (from ``compute_finite_horizon_lqr``),
        else the defaults of :func:`~idstlpy.execution.simulation.simulate`.
    default_lqr : mapping, optional
        Weights for modes without gains.
    problem_factory : callable, optional
        Picklable zero-argument callable returning an equivalent problem, used by process pools
        when the problem itself cannot be pickled.
    max_workers : int
        Workers of the default process pool.
    keep_trajectories : int
        Keep the first this-many executions in :attr:`ValidationReport.executions`.
    progress : callable, optional
        ``progress(done, runs)`` called in the calling process as batches finish (an INFO log
        record ``validate: done/runs runs`` is also written at most every second).
    predict : bool
        Also predict the execution (:func:`~idstlpy.execution.prediction.predict_closed_loop`
        with this call's gains, control-domain projection, process noise, real system, true
        initial state and number of steps) into :attr:`ValidationReport.predicted`; see
        :meth:`ValidationReport.prediction_comparison`. With ``replan`` it still predicts the
        fixed plan's execution (the loop re-planning departs from). A predicted success bound
        above the measured interval is logged as a warning: the linearised model (clipping,
        state-dependent sensor noise) is then off for this plan.
    predict_options : mapping, optional
        Further options of the prediction: ``sensor_noise``, ``filter_sensitivity``, ``samples``
        (default :data:`PREDICT_SAMPLES`), ``seed`` (of the model sampling, default 0). The
        execution options are this call's and cannot be given here.
    replan : {None, "on_risk", "every"}
        Execute every run with :func:`~idstlpy.execution.replanning.execute` and this re-plan
        policy instead of :func:`simulate` (the same noise for the same seed: runs that never
        re-plan are identical). Verdicts are the original formula's on the whole execution;
        :attr:`ValidationReport.replans` counts the re-solves of every run.
    replan_options : mapping, optional
        Further keywords of ``execute`` (``risk``, ``every``, ``check_every``, ``options``,
        ``solver_options``, ``replan_time_limit``, ...); the execution options are this call's.

    execution_target : ExecutionTarget, (belief, state) pair, mapping or None
        The success rates the report's verdict is against (default
        :data:`~idstlpy.execution_target.DEFAULT_EXECUTION_TARGET`, 90% belief / 95% true
        state); see :attr:`ValidationReport.meets_target` and :meth:`ValidationReport.verdict`.
    plant : callable, optional
        A (nonlinear) plant as a step function ``(state, input, mode, rng) -> next_state``
        moving the true state instead of ``real_system`` (which must then be None); see
        :func:`~idstlpy.execution.simulation.simulate`. With a process pool it must be picklable
        (a module-level function). Not with ``predict`` (the prediction is of a linear loop).

    batched : bool
        Execute and monitor the runs of a worker together, as arrays over runs (default; see
        the module notes); False: one run after the other with :func:`simulate` and the
        monitor. Both give every run the same noise; the rates are the same and the margins
        agree up to rounding.

    Returns
    -------
    ValidationReport
    """
    from ..synthesis.problem import Problem

    t0 = time.perf_counter()
    if not isinstance(problem, Problem):
        raise InvalidTypeError(f"problem must be a Problem, got {type(problem).__name__}")
    if solution is None:
        raise InvalidArgumentError(
            "solution is None: there is no plan to validate (see problem.last_result.reason)"
        )
    if not isinstance(solution, ProbabilisticTSTrajectory):
        raise InvalidTypeError(f"solution must be a ProbabilisticTSTrajectory, got {type(solution).__name__}")
    runs = as_int(runs, "runs", minimum=1)
    max_workers = as_int(max_workers, "max_workers", minimum=1)
    keep = as_int(keep_trajectories, "keep_trajectories", minimum=0)
    steps = solution.num_of_steps if num_of_steps is None else as_int(num_of_steps, "num_of_steps", minimum=0)
    if isinstance(executor, str) and executor != "serial":
        raise InvalidArgumentError(f"executor must be an Executor, 'serial' or None, got {executor!r}")
    if executor is not None and not isinstance(executor, Executor | str):
        raise InvalidTypeError(
            f"executor must be a concurrent.futures.Executor, got {type(executor).__name__}"
        )
    target = as_execution_target(execution_target)
    root = as_seed_sequence(seed)
    children = root.spawn(runs)

    system = problem.switched_system
    gains = list(system_gains(system, lqr_gains, default_lqr).values())
    sim_options: dict[str, Any] = {
        "control_domain": problem.control_domain if clip_controls else None,
        "process_noise": process_noise,
        "lqr_gains": gains,
        "plant": plant,
    }
    if plant is not None and predict:
        raise InvalidArgumentError(
            "predict needs a linear real_system: the prediction cannot follow a plant function"
        )
    starts: np.ndarray | None = None
    if real_initial_state is None or (isinstance(real_initial_state, str) and real_initial_state == "prior"):
        starts = prior_starts(solution, runs, root)
        real_initial_state = solution.get_mean(0).copy()
    elif isinstance(real_initial_state, str):
        raise InvalidArgumentError(
            f"real_initial_state must be an array of shape (n,), 'prior' or None, got {real_initial_state!r}"
        )
    else:
        real_initial_state = as_vector(real_initial_state, "real_initial_state", system.n)
    # Validate every argument once, here, with one short run (errors name the argument).
    simulate(system, solution, min(steps, 1), real_initial_state, real_system, seed=0, **sim_options)
    replan_kw: dict[str, Any] | None = None
    if replan is not None or replan_options is not None:
        replan_kw = _replan_options(replan, replan_options, num_of_steps, solution)
    predicted = None
    if predict:
        predicted = _predict(
            problem,
            solution,
            real_system,
            real_initial_state,
            steps,
            sim_options,
            predict_options,
            None if starts is None else solution.get_cov(0),
        )
    if not isinstance(batched, bool):
        raise InvalidTypeError(f"batched must be True or False, got {type(batched).__name__}")
    payload = _Payload(
        system,
        problem.stl_formula,
        None,
        solution,
        real_system,
        real_initial_state,
        steps,
        sim_options,
        keep,
        batched=batched,
    )
    if replan_kw is not None:
        payload = dataclasses.replace(payload, problem=problem, replan=replan_kw)

    own_pool = None
    pool: Executor | None = None
    blob: bytes | None = None
    small = payload.batched and replan_kw is None and plant is None and runs * max(steps, 1) <= SMALL_WORK
    if executor == "serial" or (executor is None and small):
        if executor is None:
            logger.debug("validate: %d runs of %d steps, batched: running in-process", runs, steps)
        pool = None
    elif isinstance(executor, ThreadPoolExecutor):
        pool = executor
    else:
        blob = _serialise(payload, problem_factory)
        if blob is None:
            logger.debug("validate: problem not picklable and no problem_factory: running in-process")
        elif isinstance(executor, Executor):
            pool = executor
        else:
            own_pool = pool = ProcessPoolExecutor(max_workers=max_workers)

    chunk = max(1, math.ceil(runs / (4 * max_workers)))
    batches = [
        (i, children[i : i + chunk], None if starts is None else starts[i : i + chunk])
        for i in range(0, runs, chunk)
    ]
    results: list[dict[str, Any]] = []
    last_log = [time.perf_counter()]

    def report_progress(done: int) -> None:
        if progress is not None:
            progress(done, runs)
        now = time.perf_counter()
        if now - last_log[0] >= 1.0 or done == runs:
            last_log[0] = now
            logger.info("validate: %d/%d runs (%.1f s)", done, runs, now - t0)

    try:
        if pool is None:
            for i, seeds, x0s in batches:
                results.extend(_execute(payload, seeds, i, x0s))
                report_progress(len(results))
        else:
            if isinstance(pool, ThreadPoolExecutor) or blob is None:  # threads share the payload
                futures = [pool.submit(_execute, payload, seeds, i, x0s) for i, seeds, x0s in batches]
            else:
                futures = [pool.submit(_run_batch, blob, seeds, i, x0s) for i, seeds, x0s in batches]
            for fut in futures:
                results.extend(fut.result())
                report_progress(len(results))
    finally:
        if own_pool is not None:
            own_pool.shutdown()
    report = _report(
        problem.stl_formula, solution, steps, root, results, time.perf_counter() - t0, predicted=predicted
    )
    report = dataclasses.replace(
        report,
        true_start=None if starts is not None else tuple(float(v) for v in real_initial_state),
        execution_target=target,
    )
    comparison = report.prediction_comparison()
    if comparison is not None:
        for reading, entry in comparison["success"].items():
            if entry["bound_holds"] is False:
                # the bound is sound for the Gaussian model only: say when the model failed the plan
                logger.warning(
                    "validate: the predicted %s success bound %.4g is above the measured rate's 95%% "
                    "interval [%.4g, %.4g] (largest predicted clip probability %.2g): the linearised "
                    "closed loop does not describe this execution",
                    reading,
                    entry["bound"],
                    entry["ci"][0],
                    entry["ci"][1],
                    float(predicted.clip_probability.max())
                    if predicted is not None and predicted.num_of_steps
                    else 0.0,
                )
    return report


def _report(
    formula: STLFormula,
    plan: ProbabilisticTSTrajectory,
    steps: int,
    root: np.random.SeedSequence,
    results: list[dict[str, Any]],
    elapsed: float,
    predicted: ClosedLoopPrediction | None = None,
) -> ValidationReport:
    runs = len(results)
    belief_margins = tuple(float(r["belief_margin"]) for r in results)
    state_margins = tuple(float(r["state_margin"]) for r in results)
    b_ok = sum(m >= 0.0 for m in belief_margins)
    s_ok = sum(m >= 0.0 for m in state_margins)

    def rates(key_b: str, key_s: str, names: list[str]) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {}
        for j, name in enumerate(names):
            nb = sum(r[key_b][j] for r in results)
            ns = sum(r[key_s][j] for r in results)
            out[name] = {
                "belief": nb / runs,
                "state": ns / runs,
                "belief_ci": list(wilson_interval(nb, runs)),
                "state_ci": list(wilson_interval(ns, runs)),
            }
        return out

    props = _propositions(formula)
    prop_names = [ap.name or f"ap{i}" for i, ap in enumerate(props)]
    pred_names = [
        f"{pname}: {pred}" for ap, pname in zip(props, prop_names, strict=True) for pred in ap.predicates
    ]
    entropy = root.entropy
    return ValidationReport(
        runs=runs,
        seed_entropy=int(entropy) if isinstance(entropy, int | np.integer) else tuple(entropy or ()),
        num_of_steps=steps,
        plan_margin=robustness(plan, formula),
        belief_successes=b_ok,
        state_successes=s_ok,
        belief_success_rate=b_ok / runs,
        state_success_rate=s_ok / runs,
        belief_ci=wilson_interval(b_ok, runs),
        state_ci=wilson_interval(s_ok, runs),
        belief_margins=belief_margins,
        state_margins=state_margins,
        proposition_violations=rates("belief_props", "state_props", prop_names),
        predicate_violations=rates("belief_preds", "state_preds", pred_names),
        elapsed=elapsed,
        executions=tuple(r["trajectories"] for r in results if "trajectories" in r),
        predicted=predicted,
        replans=tuple(int(r["replans"]) for r in results if "replans" in r),
    )
