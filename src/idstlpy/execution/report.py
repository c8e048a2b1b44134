"""The report of a Monte Carlo validation: :class:`ValidationReport`, its verdict and its views.

:func:`build_report` gathers the runs' records (:mod:`idstlpy.execution.monitor`) into rates
with their Wilson intervals (:mod:`idstlpy.execution.intervals`); the report judges them against
an execution target (:meth:`ValidationReport.verdict`), puts a prediction beside them
(:meth:`ValidationReport.prediction_comparison`) and renders itself as text, HTML and plain data.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..execution_target import DEFAULT_EXECUTION_TARGET, ExecutionTarget
from ..semantics import robustness
from ..trajectory import ProbabilisticTSTrajectory, RealTrajectory
from .intervals import comparison as _comparison
from .intervals import margin_stats as _margin_stats
from .intervals import violation_rates, wilson_interval
from .monitor import disjunctions, propositions

if TYPE_CHECKING:  # the prediction is imported when asked for (validate(predict=True))
    from .prediction import ClosedLoopPrediction
    from .validation_spec import ValidationSpec

__all__ = ["ValidationReport", "build_report"]


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
    disjunction_violations : dict
        Per disjunction of propositions (``left | right | below | above``,
        :func:`~idstlpy.execution.monitor.disjunctions`): the runs that broke it (every operand)
        at a step the plan satisfies it, as ``proposition_violations``. Its operands' own rates
        count a run that left one operand for another; :meth:`summary` shows the disjunction.
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
    disjunction_violations: dict[str, dict[str, Any]] = field(default_factory=dict)

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
        # an operand of a disjunction is reported as the disjunction: a run that left it for
        # another operand broke no promise of the formula
        operands = {part for name in self.disjunction_violations for part in name.split(" | ")}
        rows = [
            (name, v, None if cmp is None else cmp["predicates"][name])
            for name, v in self.predicate_violations.items()
            if name.split(": ")[0] not in operands
        ]
        rows += [(name, v, None) for name, v in self.disjunction_violations.items()]
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
            "disjunction_violations": {k: dict(v) for k, v in self.disjunction_violations.items()},
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


def build_report(
    spec: ValidationSpec,
    results: list[dict[str, Any]],
    elapsed: float,
    predicted: ClosedLoopPrediction | None = None,
) -> ValidationReport:
    """The report of the runs' records (one per run, in run order).

    Parameters
    ----------
    spec : ValidationSpec
        What was measured (the plan, the seeds, the true start, the execution target).
    results : list of dict
        The records (:func:`~idstlpy.execution.monitor.run_record`, with ``trajectories`` and
        ``replans`` when kept / re-planned).
    elapsed : float
        Wall-clock seconds.
    predicted : ClosedLoopPrediction, optional
        The predicted execution.

    Returns
    -------
    ValidationReport
    """
    formula, plan = spec.problem.stl_formula, spec.plan
    runs = len(results)
    belief_margins = tuple(float(r["belief_margin"]) for r in results)
    state_margins = tuple(float(r["state_margin"]) for r in results)
    b_ok = sum(m >= 0.0 for m in belief_margins)
    s_ok = sum(m >= 0.0 for m in state_margins)
    props = propositions(formula)
    prop_names = [ap.name or f"ap{i}" for i, ap in enumerate(props)]
    pred_names = [
        f"{pname}: {pred}" for ap, pname in zip(props, prop_names, strict=True) for pred in ap.predicates
    ]
    entropy = spec.root.entropy
    return ValidationReport(
        runs=runs,
        seed_entropy=int(entropy) if isinstance(entropy, int | np.integer) else tuple(entropy or ()),
        num_of_steps=spec.num_of_steps,
        plan_margin=robustness(plan, formula),
        belief_successes=b_ok,
        state_successes=s_ok,
        belief_success_rate=b_ok / runs,
        state_success_rate=s_ok / runs,
        belief_ci=wilson_interval(b_ok, runs),
        state_ci=wilson_interval(s_ok, runs),
        belief_margins=belief_margins,
        state_margins=state_margins,
        proposition_violations=violation_rates(results, "belief_props", "state_props", prop_names),
        predicate_violations=violation_rates(results, "belief_preds", "state_preds", pred_names),
        disjunction_violations=violation_rates(
            results, "belief_ors", "state_ors", [name for name, _ in disjunctions(formula)]
        ),
        elapsed=elapsed,
        executions=tuple(r["trajectories"] for r in results if "trajectories" in r),
        predicted=predicted,
        replans=tuple(int(r["replans"]) for r in results if "replans" in r),
        true_start=None if spec.starts is not None else tuple(float(v) for v in spec.start),
        execution_target=spec.execution_target,
    )
