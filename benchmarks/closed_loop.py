"""Predicted vs measured execution: does :func:`predict_closed_loop` say what ``validate`` finds?

Run: ``python -m benchmarks.closed_loop [--runs 1000] [--seeds 5] [--problems a,b,...] [--out FILE]``.

For every problem the plan is solved, executed ``runs`` times by :func:`idstlpy.validate` (Kalman
filter, receding-horizon LQR, inputs clipped to the domain unless the row says otherwise) and
predicted once by :func:`idstlpy.execution.prediction.predict_closed_loop` with the same options.
Reported per problem:

- *per step*: for every (step, chance constraint) pair, the predicted probability that the true
  state (resp. the executed belief) satisfies the constraint against the measured frequency: the
  largest absolute difference, and the fraction of pairs whose prediction lies in the measured
  Wilson 95% interval (over all pairs, and over the non-trivial ones, where the prediction or
  the measurement is neither 0 nor 1);
- *per predicate*: validate's rates (the constraint broken at some promised step) against the
  predicted ones (Gaussian-model sampling, 20000 samples): largest difference, fraction inside;
- *formula*: the predicted analytic lower bound, sampled (Clopper-Pearson, 0.999) lower bound and
  estimate of the success rate against the measured rate (true state and executed belief).

Problems: ``light_dark`` (the paper's listing, planner seeds ``0..seeds-1``, true start
[0.5, 2.75], noise-free real system); ``light_dark_far`` (the same plans from a farther true start
[1.0, 3.25]); ``light_dark_disturbed`` (the real system adds a disturbance W = 0.02 I);
``linear`` (2-D, one sensing mode with constant noise and process noise; unclipped and clipped);
``integrator`` (4-D double integrator, position sensor, process noise on the velocities;
unclipped and clipped); ``two_modes`` (examples/two_modes.toml: a sensing mode and a blind one).
Writes a Markdown table (with command, date, nproc, git revision) to ``--out`` (default
``benchmarks/closed_loop_results.md``).

``--goal`` runs issue 15's first goal instead: the light-dark listing and every feasible kind of
the active-perception suite (:mod:`benchmarks.perception_problems`, ``--size``), each solved once
with a fixed seed (``--solve-seed``, the listing's sampler parameters, ``--time-limit`` per solve),
then ``validate(..., runs, predict=True)`` (real system and true start of the suite, tracking
gains horizon 5, Q = I, R = 0.05 I, inputs clipped to the domain). Per problem: the worst
per-constraint |predicted - measured| violation rate (executed belief / true state), how many
predicted rates fall outside the measured Wilson 95% interval, the formula's success bound and
estimate against the measured rate, and, to find out why they disagree, the worst per-step
difference, the largest clipping probability and the kind of sensor noise. With ``--why`` a
problem with a per-constraint rate outside its interval is validated and predicted again with
unclipped inputs (same seeds): what remains is the state-dependent sensor linearisation, the only
other approximation of the prediction (exact for constant noise without clipping). It replaces
(or appends) the ``## Goal`` section of ``--out``, leaving the rest of the file as it is.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import idstlpy as stl
from idstlpy.chance import quantile, std_terms
from idstlpy.execution import wilson_interval
from idstlpy.execution.prediction import ClosedLoopPrediction, predict_closed_loop
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system

from .report import machine

ROOT = Path(__file__).resolve().parent.parent
PROBLEMS = ("light_dark", "light_dark_far", "light_dark_disturbed", "linear", "integrator", "two_modes")
_LISTING = {
    "rrt_timeout": 60,
    "delta_near": 2,
    "delta_drain": 0.5,
    "goal_bias": 0.25,
    "min_num_of_steps": 3,
    "max_num_of_steps": 15,
}


@dataclass
class Case:
    """One execution setting: a problem, its plan and how it is executed."""

    name: str
    problem: Any
    plan: Any
    real_system: Any
    x0: np.ndarray
    clip: bool = True
    process_noise: str = "model"
    solve_s: float = 0.0


def _p(pred: Any, eps: float) -> Any:
    return stl.prob(pred) >= 1 - eps


def _box(u: Any, a: float) -> Any:
    return stl.logical_and(u[0] >= -a, u[0] <= a, u[1] >= -a, u[1] <= a).region


def _linear() -> tuple[Any, np.ndarray]:
    x, u = stl.mk_variable(2), stl.mk_variable(2, name="u")
    A = np.array([[1.0, 0.1], [0.0, 0.98]])
    system = stl.mk_switched_sys(
        [stl.mk_lbs(A=A, B=0.25 * np.eye(2), W=0.03 * np.eye(2), C=np.eye(2), V=0.15 * np.eye(2))]
    )
    goal = stl.logical_and(
        _p(x[0] >= 1.6, 0.1), _p(x[0] <= 2.4, 0.1), _p(x[1] >= 1.6, 0.1), _p(x[1] <= 2.4, 0.1), name="goal"
    )
    safe = stl.logical_and(_p(x[0] <= 3, 0.05), _p(x[1] >= -0.5, 0.05), name="safe")
    formula = stl.logical_and(stl.always(0, 20, safe), stl.eventually(5, 20, stl.always(0, 3, goal)))
    problem = stl.Problem(system, _box(u, 1.0), stl.to_belief([0, 0], np.diag([0.05, 0.05])), formula)
    return problem, np.array([0.3, -0.2])


def _integrator() -> tuple[Any, np.ndarray]:
    x, u = stl.mk_variable(4), stl.mk_variable(2, name="u")
    A = np.eye(4)
    A[0, 2] = A[1, 3] = 1.0
    B = np.zeros((4, 2))
    B[2, 0] = B[3, 1] = 1.0
    C = np.hstack([np.eye(2), np.zeros((2, 2))])
    system = stl.mk_switched_sys(
        [stl.mk_lbs(A=A, B=B, W=np.diag([0.0, 0.0, 0.03, 0.03]), C=C, V=0.2 * np.eye(2))]
    )
    goal = stl.logical_and(
        _p(x[0] >= 7, 0.1), _p(x[0] <= 9, 0.1), _p(x[1] >= 7, 0.1), _p(x[1] <= 9, 0.1), name="goal"
    )
    avoid = stl.logical_or(_p(x[0] <= 3, 0.05), _p(x[0] >= 5, 0.05), _p(x[1] <= 4, 0.05), _p(x[1] >= 6, 0.05))
    formula = stl.logical_and(stl.always(0, 20, avoid), stl.eventually(0, 20, stl.always(0, 2, goal)))
    prior = stl.to_belief([1, 1, 0, 0], np.diag([0.05, 0.05, 0.01, 0.01]))
    return stl.Problem(system, _box(u, 0.5), prior, formula), np.array([1.2, 0.9, 0.0, 0.0])


def _timed_solve(problem: Any, **kw: Any) -> tuple[Any, float]:
    t0 = time.perf_counter()
    plan = problem.solve(**kw)
    return plan, time.perf_counter() - t0


def cases(names: tuple[str, ...], seeds: int) -> Iterator[Case]:
    """The execution settings of the benchmark, in order."""
    if {"light_dark", "light_dark_far", "light_dark_disturbed"} & set(names):
        disturbed = stl.mk_switched_sys([stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=0.02 * np.eye(2))])
        for seed in range(seeds):
            problem = light_dark()
            plan, solve_s = _timed_solve(problem, **_LISTING, seed=seed)
            if plan is None:
                continue
            for mode in problem.switched_system.system_modes:
                mode.compute_finite_horizon_lqr(horizon=5, Q_final=np.eye(2), Q=np.eye(2), R=0.05 * np.eye(2))
            if "light_dark" in names:
                yield Case(
                    f"light_dark seed {seed}",
                    problem,
                    plan,
                    light_dark_real_system(),
                    LIGHT_DARK_REAL_INITIAL_STATE,
                    solve_s=solve_s,
                )
            if "light_dark_far" in names:
                yield Case(
                    f"light_dark_far seed {seed}",
                    problem,
                    plan,
                    light_dark_real_system(),
                    np.array([1.0, 3.25]),
                    solve_s=solve_s,
                )
            if "light_dark_disturbed" in names:
                yield Case(
                    f"light_dark_disturbed seed {seed}",
                    problem,
                    plan,
                    disturbed,
                    LIGHT_DARK_REAL_INITIAL_STATE,
                    process_noise="real",
                    solve_s=solve_s,
                )
    builders: dict[str, Callable[[], tuple[Any, np.ndarray]]] = {"linear": _linear, "integrator": _integrator}
    for name in ("linear", "integrator"):
        if name in names:
            problem, x0 = builders[name]()
            plan, solve_s = _timed_solve(problem, rrt_timeout=10, seed=0, max_num_of_steps=40)
            if plan is None:
                continue
            for clip in (False, True):
                yield Case(
                    f"{name} ({'clipped' if clip else 'unclipped'})",
                    problem,
                    plan,
                    problem.switched_system,
                    x0,
                    clip=clip,
                    solve_s=solve_s,
                )
    if "two_modes" in names:
        built = stl.load_problem(ROOT / "examples" / "two_modes.toml").build()
        problem = getattr(built, "problem", built)
        plan, solve_s = _timed_solve(problem, rrt_timeout=10, seed=0)
        if plan is not None:
            yield Case(
                "two_modes", problem, plan, problem.switched_system, np.array([0.5, -0.5]), solve_s=solve_s
            )


def _inside(pred: np.ndarray, hits: np.ndarray, runs: int) -> np.ndarray:
    """Whether each prediction lies in the Wilson 95% interval of ``hits`` out of ``runs``."""
    out = np.empty(pred.shape, dtype=bool)
    for idx in np.ndindex(pred.shape):
        lo, hi = wilson_interval(int(hits[idx]), runs)
        out[idx] = lo - 1e-12 <= pred[idx] <= hi + 1e-12
    return out


def compare(case: Case, runs: int, seed: int = 0) -> dict[str, Any]:
    """Validate and predict one case; the comparison numbers as a row."""
    rep = stl.validate(
        case.problem,
        case.plan,
        case.real_system,
        case.x0,
        runs=runs,
        seed=seed,
        clip_controls=case.clip,
        process_noise=case.process_noise,
        keep_trajectories=runs,
    )
    t0 = time.perf_counter()
    pred: ClosedLoopPrediction = predict_closed_loop(
        case.problem,
        case.plan,
        case.real_system,
        case.x0,
        control_domain="problem" if case.clip else None,
        process_noise=case.process_noise,
        samples=20000,
        seed=seed,
    )
    predict_s = time.perf_counter() - t0
    H = np.array([c.h for c in pred.constraints])
    c = np.array([c.c for c in pred.constraints])
    z = quantile([c.eps for c in pred.constraints])
    states = np.array([real.get_state() for _, real in rep.executions])
    hits = {
        "state": np.sum(states @ H.T + c <= 0, axis=0),
        "belief": np.sum(
            [sim.get_mean() @ H.T + c + std_terms(H, z, sim.get_cov()) <= 0 for sim, _ in rep.executions],
            axis=0,
        ),
    }
    row: dict[str, Any] = {
        "case": case.name,
        "steps": case.plan.num_of_steps,
        "runs": runs,
        "solve_s": case.solve_s,
        "validate_s": rep.elapsed,
        "predict_s": predict_s,
        "max_clip": float(pred.clip_probability.max()) if pred.num_of_steps else 0.0,
    }
    if any(m.p and m.has_state_dependent_noise for m in case.problem.switched_system.system_modes):
        row["linearisation"] = linearisation(case, rep, hits, states, runs)
    for reading in ("state", "belief"):
        p = np.array([getattr(cp, f"{reading}_probability") for cp in pred.constraints]).T  # (L, F)
        meas = hits[reading] / runs
        inside = _inside(p, hits[reading], runs)
        nontrivial = ((p > 1e-3) & (p < 1 - 1e-3)) | ((meas > 0) & (meas < 1))
        row[f"step_{reading}_maxdiff"] = float(np.abs(p - meas).max())
        row[f"step_{reading}_inside"] = float(inside.mean())
        row[f"step_{reading}_nontrivial"] = int(nontrivial.sum())
        row[f"step_{reading}_inside_nontrivial"] = (
            float(inside[nontrivial].mean()) if nontrivial.any() else 1.0
        )
        pv = np.array([pred.predicate_violation[k][reading] for k in rep.predicate_violations])
        mv = np.array([rep.predicate_violations[k][reading] for k in rep.predicate_violations])
        row[f"pred_{reading}_maxdiff"] = float(np.abs(pv - mv).max())
        row[f"pred_{reading}_inside"] = float(np.mean(_inside(pv, np.rint(mv * runs), runs)))
        row[f"pred_{reading}_maxrate"] = float(mv.max())
        row[f"{reading}_bound"] = getattr(pred, f"{reading}_success_bound")
        row[f"{reading}_sampled_bound"] = getattr(pred, f"{reading}_success_sampled_bound")
        row[f"{reading}_estimate"] = getattr(pred, f"{reading}_success_estimate")
        row[f"{reading}_measured"] = getattr(rep, f"{reading}_success_rate")
        row[f"{reading}_ci"] = getattr(rep, f"{reading}_ci")
    return row


VARIANTS = (("plan", False), ("plan", True), ("mean", True), ("expected", False), ("expected", True))
"""(sensor_noise, filter_sensitivity) pairs compared on state-dependent noise."""


def linearisation(case: Case, rep: Any, hits: dict[str, np.ndarray], states: np.ndarray, runs: int) -> dict:
    """Per linearisation variant: per-step max |diff| (state, belief) and true-state moment errors."""
    out = {}
    for sensor, sens in VARIANTS:
        pred = predict_closed_loop(
            case.problem, case.plan, case.real_system, case.x0,
            control_domain="problem" if case.clip else None, process_noise=case.process_noise,
            sensor_noise=sensor, filter_sensitivity=sens, samples=0)  # fmt: skip
        p_x = np.array([cp.state_probability for cp in pred.constraints]).T
        p_b = np.array([cp.belief_probability for cp in pred.constraints]).T
        sd = np.sqrt(np.diagonal(pred.state_cov, axis1=1, axis2=2))
        out[f"{sensor}{'+sens' if sens else ''}"] = {
            "state": float(np.abs(p_x - hits["state"] / runs).max()),
            "belief": float(np.abs(p_b - hits["belief"] / runs).max()),
            "mean_err": float(np.abs(states.mean(axis=0) - pred.state_mean).max()),
            "sd_err": float(np.abs(states.std(axis=0) - sd).max()),
        }
    return out


def linearisation_table(rows: list[dict[str, Any]]) -> str:
    """Per state-dependent case and variant: per-step max |diff| state / belief, moment errors."""
    names = [f"{s}{'+sens' if f else ''}" for s, f in VARIANTS]
    head = "| case | " + " | ".join(f"{n}: step \\|diff\\| x / b; mean / sd err" for n in names) + " |"
    lines = [head, "|---|" + "---|" * len(names)]
    for r in rows:
        lin = r.get("linearisation")
        if not lin:
            continue
        cells = [
            f"{lin[n]['state']:.3f} / {lin[n]['belief']:.3f}; "
            f"{lin[n]['mean_err']:.4f} / {lin[n]['sd_err']:.4f}"
            for n in names
        ]
        lines.append(f"| {r['case']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) if len(lines) > 2 else ""


def _pct(x: float) -> str:
    return f"{100 * x:.1f}%"


def table(rows: list[dict[str, Any]]) -> str:
    """The rows as a Markdown table."""
    head = (
        "| case | steps | max clip P | per step: max \\|diff\\| state / belief | "
        "per step: inside 95% CI, all (non-trivial) state / belief | "
        "per predicate: max \\|diff\\| state / belief (max rate) | "
        "per predicate: inside | success, true state: bound / sampled bound / estimate / measured "
        "[95% CI] | success, belief: bound / sampled bound / estimate / measured [95% CI] | "
        "predict (s) | validate (s) |"
    )
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['steps']} | {r['max_clip']:.2f} | "
            f"{r['step_state_maxdiff']:.3f} / {r['step_belief_maxdiff']:.3f} | "
            f"{_pct(r['step_state_inside'])} ({_pct(r['step_state_inside_nontrivial'])} of "
            f"{r['step_state_nontrivial']}) / {_pct(r['step_belief_inside'])} "
            f"({_pct(r['step_belief_inside_nontrivial'])} of {r['step_belief_nontrivial']}) | "
            f"{r['pred_state_maxdiff']:.3f} / {r['pred_belief_maxdiff']:.3f} "
            f"({r['pred_state_maxrate']:.3f} / {r['pred_belief_maxrate']:.3f}) | "
            f"{_pct(r['pred_state_inside'])} / {_pct(r['pred_belief_inside'])} | "
            f"{_pct(r['state_bound'])} / {_pct(r['state_sampled_bound'])} / {_pct(r['state_estimate'])} / "
            f"{_pct(r['state_measured'])} "
            f"[{_pct(r['state_ci'][0])}, {_pct(r['state_ci'][1])}] | "
            f"{_pct(r['belief_bound'])} / {_pct(r['belief_sampled_bound'])} / {_pct(r['belief_estimate'])} / "
            f"{_pct(r['belief_measured'])} "
            f"[{_pct(r['belief_ci'][0])}, {_pct(r['belief_ci'][1])}] | "
            f"{r['predict_s']:.2f} | {r['validate_s']:.1f} |"
        )
    return "\n".join(lines)


def summary(rows: list[dict[str, Any]]) -> str:
    """Pooled lines: worst differences and whether every bound stayed below its measured rate."""
    out = []
    for group, pick in (
        ("light-dark (state-dependent noise)", lambda r: r["case"].startswith("light_dark")),
        ("constant noise, unclipped (exact)", lambda r: "unclipped" in r["case"]),
        (
            "constant noise, clipped / switching",
            lambda r: "(clipped)" in r["case"] or r["case"] == "two_modes",
        ),
    ):
        sel = [r for r in rows if pick(r)]
        if not sel:
            continue
        below = sum(r[f"{k}_bound"] <= r[f"{k}_ci"][1] for r in sel for k in ("state", "belief"))
        below_s = sum(r[f"{k}_sampled_bound"] <= r[f"{k}_ci"][1] for r in sel for k in ("state", "belief"))

        def worst(key: str, fn: Callable[..., float] = max, sel: list[dict[str, Any]] = sel) -> float:
            return fn(r[key] for r in sel)

        out.append(
            f"- {group}, {len(sel)} cases: per step max |diff| state {worst('step_state_maxdiff'):.3f}, "
            f"belief {worst('step_belief_maxdiff'):.3f}; per predicate max |diff| state "
            f"{worst('pred_state_maxdiff'):.3f}, belief {worst('pred_belief_maxdiff'):.3f}; "
            f"non-trivial per-step pairs inside the 95% interval: state "
            f"{_pct(worst('step_state_inside_nontrivial', min))} (worst case), belief "
            f"{_pct(worst('step_belief_inside_nontrivial', min))}; success bound <= measured upper CI "
            f"in {below}/{2 * len(sel)} (sampled bound: {below_s}/{2 * len(sel)})"
        )
    return "\n".join(out)


# --------------------------------------------------------------------------------------------
# Issue 15's first goal: validate(predict=True) on light-dark and the active-perception suite

GOAL_HEADING = "## Goal: predicted vs measured violation rates (validate(predict=True))"


def goal_cases(kinds: tuple[str, ...], size: str, solve_seed: int, time_limit: float) -> Iterator[Case | str]:
    """Light-dark (the scenario) then each perception kind, solved once; a string for no plan."""
    from . import perception_problems as pp
    from .perception_suite import SAMPLER, _gains

    if "light_dark" in kinds:
        problem = light_dark()
        plan, solve_s = _timed_solve(problem, **_LISTING, seed=solve_seed, time_limit=time_limit)
        if plan is None:
            yield f"light_dark: no plan ({problem.last_result.status})"
        else:
            _gains(problem)
            caps = problem.last_result.stats.caps_hit
            yield Case(
                "light_dark" + (f" (caps hit: {', '.join(caps)})" if caps else ""),
                problem,
                plan,
                light_dark_real_system(),
                LIGHT_DARK_REAL_INITIAL_STATE,
                solve_s=solve_s,
            )
    for kind in kinds:
        if kind == "light_dark":
            continue
        problem, _ = pp.build(kind, size)
        plan, solve_s = _timed_solve(problem, **SAMPLER, seed=solve_seed, time_limit=time_limit)
        if plan is None:
            res = problem.last_result
            yield f"{kind}: no plan ({res.status}, {solve_s:.0f} s)"
            continue
        _gains(problem)
        caps = problem.last_result.stats.caps_hit
        yield Case(
            kind + (f" (caps hit: {', '.join(caps)})" if caps else ""),
            problem,
            plan,
            pp.real_system(problem),
            pp.real_initial_state(kind, problem),
            solve_s=solve_s,
        )


def _jsonable(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


def _noise_kind(problem: Any) -> str:
    modes = problem.switched_system.system_modes
    sensing = "state-dependent" if any(m.p and m.has_state_dependent_noise for m in modes) else "constant"
    if not any(m.p for m in modes):
        sensing = "blind"
    W = max(float(np.abs(m.W).max()) if m.W is not None and m.W.size else 0.0 for m in modes)
    return f"{sensing}{', W' if W > 0 else ''}{f', {len(modes)} modes' if len(modes) > 1 else ''}"


def goal_row(
    case: Case, runs: int, seed: int = 0, samples: int = 20000, predict_seed: int = 0
) -> dict[str, Any]:
    """validate(predict=True) on one case; the goal's numbers (and per-step ones to explain them).

    ``seed`` seeds the executions, ``predict_seed`` the prediction's model samples (kept apart so
    that a second validation seed re-measures the same prediction)."""
    rep = stl.validate(
        case.problem,
        case.plan,
        case.real_system,
        case.x0,
        runs=runs,
        seed=seed,
        clip_controls=case.clip,
        process_noise=case.process_noise,
        keep_trajectories=runs,
        predict=True,
        predict_options={"samples": samples, "seed": predict_seed},
    )
    pred = rep.predicted
    cmp = rep.prediction_comparison()
    assert pred is not None and cmp is not None
    H = np.array([c.h for c in pred.constraints])
    c = np.array([c.c for c in pred.constraints])
    z = quantile([c.eps for c in pred.constraints])
    states = np.array([real.get_state() for _, real in rep.executions])
    hits = {
        "state": np.sum(states @ H.T + c <= 0, axis=0),
        "belief": np.sum(
            [sim.get_mean() @ H.T + c + std_terms(H, z, sim.get_cov()) <= 0 for sim, _ in rep.executions],
            axis=0,
        ),
    }
    row: dict[str, Any] = {
        "case": case.name,
        "steps": case.plan.num_of_steps,
        "runs": runs,
        "solve_s": case.solve_s,
        "seed": seed,
        "samples": pred.samples,
        "entries": comparison_entries(cmp),
        "validate_s": rep.elapsed,
        "noise": _noise_kind(case.problem),
        "max_clip": float(pred.clip_probability.max()) if pred.num_of_steps else 0.0,
        "box_domain": _is_box(case.problem.control_domain),
        "constraints": len(cmp["predicates"]),
        "outside": cmp["outside"],
        "compared": cmp["compared"],
        "outside_names": [
            f"{name} ({r})" for name, v in cmp["predicates"].items() for r, e in v.items() if e["outside"]
        ],
    }
    for reading in ("belief", "state"):
        diffs = [
            abs(v[reading]["diff"]) for v in cmp["predicates"].values() if v[reading]["diff"] is not None
        ]
        row[f"pred_{reading}_maxdiff"] = max(diffs) if diffs else float("nan")
        worst = max(cmp["predicates"].items(), key=lambda kv: abs(kv[1][reading]["diff"] or 0.0))
        row[f"pred_{reading}_worst"] = (worst[0], worst[1][reading])
        row[f"pred_{reading}_maxrate"] = max(v[reading]["measured"] for v in cmp["predicates"].values())
        p = np.array([getattr(cp, f"{reading}_probability") for cp in pred.constraints]).T
        row[f"step_{reading}_maxdiff"] = float(np.abs(p - hits[reading] / runs).max())
        e = cmp["success"][reading]
        row[f"{reading}_bound"] = e["bound"]
        row[f"{reading}_estimate"] = e["predicted"]
        row[f"{reading}_measured"] = e["measured"]
        row[f"{reading}_ci"] = e["ci"]
        row[f"{reading}_bound_holds"] = e["bound_holds"]
        row[f"{reading}_estimate_outside"] = e["outside"]
    return row


def comparison_entries(cmp: dict[str, Any]) -> list[dict[str, Any]]:
    """The compared rates of ``ValidationReport.prediction_comparison`` as flat records."""
    out = []
    for group in ("predicates", "propositions"):
        for name, v in cmp[group].items():
            for reading, e in v.items():
                if e["outside"] is not None:
                    out.append(
                        {
                            "group": group,
                            "name": name,
                            "reading": reading,
                            "predicted": e["predicted"],
                            "measured": e["measured"],
                            "outside": e["outside"],
                        }
                    )
    for reading, e in cmp["success"].items():
        if e["outside"] is not None:  # a success rate: compared as its complement, a failure rate
            out.append(
                {
                    "group": "success",
                    "name": "formula",
                    "reading": reading,
                    "predicted": 1.0 - e["predicted"],
                    "measured": 1.0 - e["measured"],
                    "outside": e["outside"],
                }
            )
    return out


def outside_probability(p: float, runs: int) -> float:
    """Chance that a rate predicted *exactly* (true rate ``p``) falls outside the Wilson 95%
    interval of ``runs`` executions: what one compared rate contributes to the expected count."""
    from scipy.stats import binom

    k = np.arange(runs + 1)
    cis = (wilson_interval(int(i), runs) for i in k)
    out = np.array([not (lo - 1e-12 <= p <= hi + 1e-12) for lo, hi in cis])
    return float(binom.pmf(k, runs, p)[out].sum())


def two_sample_p(predicted: float, samples: int, measured: float, runs: int) -> float:
    """Two-sided p-value (Fisher's exact test) that the model's ``samples`` draws and the
    ``runs`` executions share one violation rate: the predicted rate is itself a Monte Carlo
    estimate (of the particle loop), so the comparison is of two samples."""
    from scipy.stats import fisher_exact

    k1, k2 = round(predicted * samples), round(measured * runs)
    return float(fisher_exact([[k1, samples - k1], [k2, runs - k2]]).pvalue)


def holm(pvalues: list[float], alpha: float = 0.05) -> list[bool]:
    """Holm's step-down rejections at family-wise level ``alpha`` (valid under any dependence)."""
    order = np.argsort(pvalues)
    reject = [False] * len(pvalues)
    m = len(pvalues)
    for rank, i in enumerate(order):
        if pvalues[i] > alpha / (m - rank):
            break
        reject[i] = True
    return reject


def poisson_binomial_tail(probs: list[float], k: int) -> float:
    """P[at least ``k`` of independent events with probabilities ``probs`` occur]."""
    dist = np.zeros(len(probs) + 1)
    dist[0] = 1.0
    for q in probs:
        dist[1:] = dist[1:] * (1 - q) + dist[:-1] * q
        dist[0] *= 1 - q
    return float(dist[k:].sum())


def calibration(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per problem and over all problems of one validation seed: the literal outside count
    against what an exact predictor would give (sum of :func:`outside_probability`), the
    two-sample p-values and Holm's rejections over *all* compared rates of all problems measured
    with that seed (one family)."""
    per, totals = [], []
    for seed in sorted({r["seed"] for r in rows}):
        sel = [r for r in rows if r["seed"] == seed]
        flat = [(r, e) for r in sel for e in r["entries"]]
        for r, e in flat:
            e["p_out"] = outside_probability(e["predicted"], r["runs"])
            e["p_two"] = two_sample_p(e["predicted"], r["samples"], e["measured"], r["runs"])
        rejected = holm([e["p_two"] for _, e in flat])
        for (_, e), rej in zip(flat, rejected, strict=True):
            e["holm"] = rej
        groups = [(r["case"], r["entries"]) for r in sel] + [("**all**", [e for _, e in flat])]
        for name, es in groups:
            n_out = sum(e["outside"] for e in es)
            (totals if name == "**all**" else per).append(
                {
                    "case": name,
                    "seed": seed,
                    "compared": len(es),
                    "outside": n_out,
                    "expected": sum(e["p_out"] for e in es),
                    "min_p": min((e["p_two"] for e in es), default=1.0),
                    "p_below_05": sum(e["p_two"] < 0.05 for e in es),
                    "holm": sum(e["holm"] for e in es),
                    "tail": poisson_binomial_tail([e["p_out"] for e in es], n_out),
                }
            )
    return {"per": per, "totals": totals}


def pooled(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each compared rate with its runs of every validation seed pooled (same plan, same
    prediction): a systematic error shows as a small two-sample p-value here, a chance miss of
    one seed does not. Sorted by that p-value, with Holm's verdict over all of them."""
    acc: dict[tuple[str, str, str, str], dict[str, Any]] = {}
    for r in rows:
        base = r["case"].split(" [seed")[0]
        for e in r["entries"]:
            key = (base, e["group"], e["name"], e["reading"])
            a = acc.setdefault(
                key,
                {
                    "case": base,
                    "group": e["group"],
                    "name": e["name"],
                    "reading": e["reading"],
                    "predicted": e["predicted"],
                    "samples": r["samples"],
                    "hits": 0,
                    "runs": 0,
                    "seeds_outside": 0,
                },
            )
            a["hits"] += round(e["measured"] * r["runs"])
            a["runs"] += r["runs"]
            a["seeds_outside"] += bool(e["outside"])
    out = list(acc.values())
    for a in out:
        a["measured"] = a["hits"] / a["runs"]
        a["p_two"] = two_sample_p(a["predicted"], a["samples"], a["measured"], a["runs"])
    for a, rej in zip(out, holm([a["p_two"] for a in out]), strict=True):
        a["holm"] = rej
    return sorted(out, key=lambda a: a["p_two"])


def pooled_lines(pool: list[dict[str, Any]], worst: int = 8) -> str:
    """The ``worst`` pooled comparisons as Markdown bullets."""
    return "\n".join(
        f"- {a['case']}: {a['group']} `{a['name']}` ({a['reading']}): predicted {a['predicted']:.4f}, "
        f"measured {a['hits']}/{a['runs']} = {a['measured']:.4f}, outside in {a['seeds_outside']} seed(s), "
        f"two-sample p = {a['p_two']:.3g}{' (Holm: rejected)' if a['holm'] else ''}"
        for a in pool[:worst]
    )


def calibration_table(cal: dict[str, Any]) -> str:
    """Markdown of :func:`calibration`."""
    head = (
        "| problem | validation seed | compared | outside the Wilson 95% CI (literal) | expected if "
        "exact | P[>= that many] | two-sample p < 0.05 | min two-sample p | Holm-rejected (all rates, "
        "FWER 5%) |"
    )
    lines = [head, "|" + "---|" * (head.count(" | ") + 1)]
    for c in [*cal["per"], *cal["totals"]]:
        lines.append(
            f"| {c['case']} | {c['seed']} | {c['compared']} | {c['outside']} | "
            f"{c['expected']:.2f} | "
            f"{c['tail']:.3f} | {c['p_below_05']} | {c['min_p']:.3g} | {c['holm']} |"
        )
    return "\n".join(lines)


def _is_box(domain: Any) -> bool:
    if domain is None:
        return True
    H = np.asarray(domain.H, dtype=float)
    return bool(np.all(np.count_nonzero(np.abs(H) > 1e-12, axis=1) <= 1))


def _noclip_cell(r: dict[str, Any]) -> str:
    nc = r.get("noclip")
    if nc is None:
        return "-"
    return (
        f"{nc['pred_belief_maxdiff']:.3f} / {nc['pred_state_maxdiff']:.3f}; "
        f"{nc['outside']} / {nc['compared']}"
    )


def _opt_pct(x: float | None) -> str:
    return "n/a" if x is None or not np.isfinite(x) else _pct(x)


def goal_table(rows: list[dict[str, Any]], skipped: list[str]) -> str:
    """The goal's table and a line per problem without a plan."""
    head = (
        "| problem | steps | sensor noise | max clip P | constraints | worst per-constraint "
        "\\|pred - meas\\| belief / state (max measured rate) | rates outside the 95% CI | "
        "per step: max \\|diff\\| belief / state | "
        "success, belief: bound / estimate / measured [95% CI] | "
        "success, true state: bound / estimate / measured [95% CI] | "
        "unclipped (--why): worst \\|pred - meas\\| belief / state; outside | validate (s) |"
    )
    lines = [head, "|" + "---|" * (head.count(" | ") + 1)]
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['steps']} | {r['noise']} | {r['max_clip']:.2f}"
            f"{'' if r['box_domain'] else ' (not a box)'} | {r['constraints']} | "
            f"{r['pred_belief_maxdiff']:.3f} / {r['pred_state_maxdiff']:.3f} "
            f"({r['pred_belief_maxrate']:.3f} / {r['pred_state_maxrate']:.3f}) | "
            f"{r['outside']} / {r['compared']} | "
            f"{r['step_belief_maxdiff']:.3f} / {r['step_state_maxdiff']:.3f} | "
            + " | ".join(
                f"{_opt_pct(r[f'{k}_bound'])}{'' if r[f'{k}_bound_holds'] is not False else ' (ABOVE)'} / "
                f"{_opt_pct(r[f'{k}_estimate'])}{' (!)' if r[f'{k}_estimate_outside'] else ''} / "
                f"{_pct(r[f'{k}_measured'])} [{_pct(r[f'{k}_ci'][0])}, {_pct(r[f'{k}_ci'][1])}]"
                for k in ("belief", "state")
            )
            + f" | {_noclip_cell(r)} | {r['validate_s']:.1f} |"
        )
    out = "\n".join(lines)
    flagged = [
        f"- {r['case']}: "
        + "; ".join(r["outside_names"])
        + (f"; unclipped: {'; '.join(r['noclip']['outside_names']) or 'none'}" if r.get("noclip") else "")
        for r in rows
        if r["outside_names"]
    ]
    if flagged:
        out += "\n\nPer-constraint rates outside the interval:\n\n" + "\n".join(flagged)
    if skipped:
        out += "\n\nNot compared (no plan):\n\n" + "\n".join(f"- {s}" for s in skipped)
    return out


def write_goal_section(path: Path, text: str) -> None:
    """Replace the goal section of ``path`` (from its heading to the next ``## ``), or append it."""
    old = path.read_text() if path.exists() else ""
    start = old.find(GOAL_HEADING)
    if start < 0:
        new = old.rstrip("\n") + "\n\n" + text.rstrip("\n") + "\n"
    else:
        nxt = old.find("\n## ", start + len(GOAL_HEADING))
        tail = "" if nxt < 0 else old[nxt:]
        new = old[:start] + text.rstrip("\n") + "\n" + tail
    path.write_text(new)


def goal_main(a: argparse.Namespace, argv: list[str] | None) -> int:
    """``--goal``: run, print and record the goal's table."""
    from . import perception_problems as pp

    kinds = ("light_dark",) + tuple(k for k, v in pp.KINDS.items() if v.expected == "feasible")
    if a.kinds:
        kinds = tuple(s.strip() for s in a.kinds.split(",") if s.strip())
        unknown = set(kinds) - {"light_dark", *pp.KINDS}
        if unknown:
            raise SystemExit(f"unknown kinds {sorted(unknown)}")
    rows, skipped = [], []
    seeds = [int(x) for x in a.validate_seeds.split(",") if x.strip()]
    for case in goal_cases(kinds, a.size, a.solve_seed, a.time_limit):
        if isinstance(case, str):
            skipped.append(case)
            print(case, flush=True)
            continue
        for seed in seeds:
            row = goal_row(case, a.runs, seed=seed)
            if len(seeds) > 1:
                row["case"] = f"{row['case']} [seed {seed}]"
            if a.why and row["outside_names"]:
                row["noclip"] = goal_row(dataclasses.replace(case, clip=False), a.runs, seed=seed)
            rows.append(row)
            print(
                f"{row['case']}: {row['steps']} steps, worst per-constraint |diff| belief "
                f"{row['pred_belief_maxdiff']:.3f} state {row['pred_state_maxdiff']:.3f}, outside "
                f"{row['outside']}/{row['compared']}, state success bound {_opt_pct(row['state_bound'])} "
                f"measured {_pct(row['state_measured'])} ({row['validate_s']:.0f} s)",
                flush=True,
            )
            if a.json:
                Path(a.json).write_text(json.dumps(rows, default=_jsonable))
    cal = calibration(rows)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, default=_jsonable))
    table_md = (
        goal_table(rows, skipped) + "\n\nCalibration over all compared rates:\n\n" + calibration_table(cal)
    )
    if len(seeds) > 1:
        pool = pooled(rows)
        n_rej = sum(a["holm"] for a in pool)
        table_md += (
            f"\n\nThe seeds pooled ({len(pool)} rates, {n_rej} Holm-rejected); "
            "smallest two-sample p-values:\n\n" + pooled_lines(pool)
        )
    print()
    print(table_md)
    if a.out != "-":
        mach = machine()
        args = sys.argv[1:] if argv is None else argv
        text = "\n".join(
            [
                GOAL_HEADING,
                "",
                f"- command: `python -m benchmarks.closed_loop {' '.join(args)}`",
                f"- date: {dt.datetime.now().astimezone().isoformat(timespec='seconds')}",
                f"- machine: nproc = {mach['nproc']}, CPU: {mach['cpu']}; {mach['python']}",
                f"- idstlpy revision: {mach['git']}",
                f"- each problem solved once (seed {a.solve_seed}, the listing's sampler parameters, "
                f"time limit {a.time_limit:g} s, perception size `{a.size}`), then `validate(runs={a.runs}, "
                f"predict=True)` with each validation seed {seeds} (the prediction's samples: seed 0): "
                "real system and true start of the perception suite (light-dark: the "
                "paper's), LQR horizon 5, Q = I, R = 0.05 I, inputs clipped to the domain; prediction "
                "with its defaults (sensor_noise='expected', filter_sensitivity=True), 20000 model samples",
                "- a constraint's rate is the fraction of runs that broke it at a step where the plan "
                "satisfies its proposition (validate's); 'outside' counts predicted rates (per "
                "constraint and proposition, belief and true state, and the two success estimates) "
                "outside the measured Wilson 95% interval: about 1 in 20 is expected by chance when the "
                "prediction is exact; '(ABOVE)' marks a success bound above the measured interval",
                "- calibration: 'expected if exact' sums, over the compared rates, the chance that a rate "
                "predicted exactly falls outside the Wilson interval of the runs (binomial at the predicted "
                "rate); 'P[>= that many]' is the Poisson-binomial tail of the literal count (as if the rates "
                "were independent, which they are not: faces, propositions and readings overlap); the "
                "two-sample p-value is Fisher's exact test of the model's samples against the runs (the "
                "predicted rate is a Monte Carlo estimate too); Holm's step-down over every compared rate "
                "of every problem (one family, valid under any dependence) at family-wise level 5%",
                "",
                table_md,
                "",
            ]
        )
        write_goal_section(Path(a.out), text)
        print(f"\nwrote the goal section of {a.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.closed_loop",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--runs", type=int, default=1000)
    p.add_argument("--seeds", type=int, default=5, help="light-dark planner seeds 0..seeds-1")
    p.add_argument("--problems", default=",".join(PROBLEMS), help=f"comma-separated subset of {PROBLEMS}")
    p.add_argument(
        "--out",
        default=str(ROOT / "benchmarks" / "closed_loop_results.md"),
        help="Markdown file to write ('-' for none)",
    )
    p.add_argument(
        "--goal",
        action="store_true",
        help="issue 15's goal: validate(predict=True) on light-dark and the perception suite",
    )
    p.add_argument("--kinds", default="", help="(--goal) comma-separated light_dark and perception kinds")
    p.add_argument("--size", default="full", choices=("small", "full"), help="(--goal) perception size")
    p.add_argument("--solve-seed", type=int, default=0, help="(--goal) the solver's seed")
    p.add_argument("--time-limit", type=float, default=120.0, help="(--goal) seconds per solve")
    p.add_argument(
        "--validate-seeds",
        default="0",
        help="(--goal) comma-separated validation seeds, each a full validate() of every plan",
    )
    p.add_argument("--json", default="", help="(--goal) write every row and compared rate to this file")
    p.add_argument(
        "--why", action="store_true", help="(--goal) re-run a problem with a flagged rate without clipping"
    )
    a = p.parse_args(argv)
    if a.goal:
        return goal_main(a, argv)
    names = tuple(s.strip() for s in a.problems.split(",") if s.strip())
    unknown = set(names) - set(PROBLEMS)
    if unknown:
        p.error(f"unknown problems {sorted(unknown)}; choose from {PROBLEMS}")
    rows = []
    for case in cases(names, a.seeds):
        row = compare(case, a.runs)
        rows.append(row)
        print(
            f"{row['case']}: per step max |diff| state {row['step_state_maxdiff']:.3f} belief "
            f"{row['step_belief_maxdiff']:.3f}; success state bound {row['state_bound']:.3f} "
            f"est {row['state_estimate']:.3f} measured {row['state_measured']:.3f}",
            flush=True,
        )
    md = table(rows)
    summ = summary(rows)
    lin = linearisation_table(rows)
    print()
    print(md)
    print()
    print(summ)
    if lin:
        print()
        print(lin)
    if a.out != "-":
        mach = machine()
        args = sys.argv[1:] if argv is None else argv
        text = "\n".join(
            [
                "# Predicted vs measured closed loop",
                "",
                f"- command: `python -m benchmarks.closed_loop {' '.join(args)}`",
                f"- date: {dt.datetime.now().astimezone().isoformat(timespec='seconds')}",
                f"- machine: nproc = {mach['nproc']}, CPU: {mach['cpu']}; {mach['python']}",
                f"- idstlpy revision: {mach['git']}",
                "- prediction: `predict_closed_loop` defaults (sensor_noise='expected', "
                "filter_sensitivity=True), 20000 Gaussian-model samples for the per-predicate and success "
                "estimates; measured: "
                "`validate` (Wilson 95% intervals), LQR horizon 5, Q = I, R = 0.05 I on light-dark, "
                "the defaults elsewhere",
                "",
                md,
                "",
                summ,
                "",
                *(
                    [
                        "## Linearisation of state-dependent sensor noise",
                        "",
                        "The same executions against the prediction under each linearisation: "
                        "`sensor_noise` (`plan`: R at the planned mean; `mean`: at the predicted true-state "
                        "mean; `expected`: E[R] over the predicted true state) and `+sens` "
                        "(`filter_sensitivity`: the filter covariance's first-order variation "
                        "carried along). "
                        "Cells: per-step max |predicted - measured| probability for the true state / the "
                        "executed belief; max error of the true state's mean / standard deviation.",
                        "",
                        lin,
                        "",
                    ]
                    if lin
                    else []
                ),
            ]
        )
        Path(a.out).write_text(text)
        print(f"\nwrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
