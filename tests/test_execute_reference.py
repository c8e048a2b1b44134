"""``execute`` reproduces the reports recorded before it was rewritten on the re-planning online
executor (issue 22): floats within the tolerance of :mod:`reference_compare` (another CPU's BLAS
kernels round differently), every discrete field exactly.

``tests/data/execute_reference.npz`` holds, for a few recorded-seed cases (re-solves on risk,
drift checks, no schedule, start re-solves, the ``"every"`` schedule, a step-function plant, the
paper's listing with its state-dependent sensor noise), the report of ``execute`` as it was at
commit 967ec19 (five nested closures calling ``simulate`` a chunk at a time; the listing case
was recorded later with that commit's ``execution/replanning.py`` on the then current package):
every record, the plans followed, the executed belief and the true states. The first plan of the
integrator cases is stored too, so only the re-solves go through the solver (small budgets,
seeded, no wall-clock cap hit: deterministic). The re-solves ask for ``guarantee="mlo"``, the
default when the reports were recorded (``"execution"`` became the default later).

The recording pins the results of one day's solver; the old executor itself is kept as an oracle
(``tests/oracles/chunked_execute.py``) and run beside ``execute`` on the current solver, so a
later change to synthesis cannot hide or fake a difference between the two executors.

Regenerate (only when a behaviour change is intended and recorded in CHANGELOG.md)::

    PYTHONPATH=src python tests/test_execute_reference.py
"""

from __future__ import annotations

import json
import math
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from reference_compare import assert_close_to_reference, assert_records_close

import idstlpy as stl

DATA = Path(__file__).parent / "data" / "execute_reference.npz"
OPTIONS = {"rrt_timeout": 2, "seed": 0, "guarantee": "mlo"}  # the guarantee of the recording


def _problem() -> stl.Problem:
    """tests/test_replanning.py's noisy integrator: reach a box and hold it (LP-exact)."""
    x = stl.mk_variable(2, name="x")
    u = stl.mk_variable(2, name="u")
    mode = stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=0.08 * np.eye(2), C=np.eye(2), V=0.1 * np.eye(2))
    target = stl.logical_and(
        stl.prob(x[0] >= 1.4) >= 0.9,
        stl.prob(x[0] <= 2.6) >= 0.9,
        stl.prob(x[1] >= -0.6) >= 0.9,
        stl.prob(x[1] <= 0.6) >= 0.9,
        name="target",
    )
    return stl.Problem(
        stl.mk_switched_sys([mode]),
        stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region,
        stl.to_belief(np.zeros(2), 0.05 * np.eye(2)),
        stl.eventually(0, 12, stl.always(0, 4, target)),
    )


def _slow() -> Any:
    return stl.mk_switched_sys([stl.mk_lcs(A=np.eye(2), B=0.25 * np.eye(2))])


def _real() -> Any:
    return stl.mk_switched_sys([stl.mk_lcs(A=np.eye(2), B=0.5 * np.eye(2))])


def _drag(x: np.ndarray, u: np.ndarray, mode: int, rng: np.random.Generator) -> np.ndarray:
    """A nonlinear plant: the input loses effect far from the origin, plus its own noise."""
    return x + 0.5 * u / (1.0 + 0.1 * float(x @ x)) + 0.02 * rng.standard_normal(2)


# name -> (real system, plant, seed, policy keywords of execute)
CASES: dict[str, tuple[Any, Any, int, dict[str, Any]]] = {
    "on_risk": (
        _real,
        None,
        1,
        {"replan": "on_risk", "risk": 1.0, "check_every": 4, "max_replans": 3, "solver_options": OPTIONS},
    ),
    "drift": (
        _slow,
        None,
        3,
        {
            "replan": "on_risk",
            "risk": 1.0,
            "check_every": 5,
            "drift": 0.95,
            "max_replans": 3,
            "solver_options": OPTIONS,
        },
    ),  # fmt: skip
    "unscheduled_start": (
        _slow,
        None,
        4,
        {
            "replan": "on_risk",
            "risk": 1.0,
            "check_every": None,
            "drift": 0.9,
            "start_resolves": 2,
            "max_replans": 4,
            "solver_options": OPTIONS,
            "adopt": "always",
        },
    ),  # fmt: skip
    "every": (
        _real,
        None,
        11,
        {"replan": "every", "every": 3, "solver_options": OPTIONS, "risk_on": "belief"},
    ),
    "plant_start_only": (
        None,
        _drag,
        5,
        {
            "replan": "on_risk",
            "risk": 1.0,
            "check_every": None,
            "start_resolves": 1,
            "risk_measure": "estimate",
            "risk_samples": 200,
            "solver_options": OPTIONS,
        },
    ),  # fmt: skip
    # The paper's listing (a state-dependent sensor noise), a rollout plan checked every 10 steps.
    "listing_on_risk": (
        None,
        None,
        2,
        {
            "replan": "on_risk",
            "risk": 0.5,
            "check_every": 10,
            "max_replans": 1,
            "replan_time_limit": 30.0,
            "solver_options": {"seed": 0, "guarantee": "mlo"},
        },
    ),  # fmt: skip
}


def _plan(data: Any) -> stl.ProbabilisticTSTrajectory:
    return stl.ProbabilisticTSTrajectory(
        data["plan_mean"], data["plan_cov"], data["plan_action"], data["plan_control"]
    )


def _listing() -> tuple[stl.Problem, stl.ProbabilisticTSTrajectory, Any, np.ndarray]:
    """The paper's listing with a rollout plan towards the light and back (benchmarks/executor_step)."""
    from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system

    problem = light_dark()
    steps = 30
    controls = np.vstack([np.tile([1.0, -0.1], (15, 1)), np.tile([-1.0, 0.0], (steps - 15, 1))])
    plan = stl.rollout(
        problem.switched_system, problem.initial_state, np.zeros(steps, dtype=int), 0.25 * controls
    )
    return problem, plan, light_dark_real_system(), np.asarray(LIGHT_DARK_REAL_INITIAL_STATE, dtype=float)


def _run(name: str, problem: stl.Problem, plan: stl.ProbabilisticTSTrajectory) -> Any:
    real, plant, seed, kw = CASES[name]
    if name.startswith("listing"):
        problem, plan, listing_real, x0 = _listing()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            return stl.execute(problem, plan, listing_real, x0, seed=seed, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the keyword spelling, as recorded
        return stl.execute(
            problem,
            plan,
            None if real is None else real(),
            np.array([0.2, -0.1]),
            seed=seed,
            plant=plant,
            **kw,
        )


def _records(report: Any) -> list[dict[str, Any]]:
    out = []
    for r in report.replans:
        d = {k: v for k, v in vars(r).items() if k != "solve_time"}
        # recorded before Replan had ``delay``: these policies take effect at once
        assert d.pop("delay") == 0
        d["caps_hit"] = list(d["caps_hit"])
        for k in ("predicted", "new_predicted"):
            d[k] = "nan" if math.isnan(d[k]) else float(d[k]).hex()
        out.append(d)
    return out


def _arrays(report: Any) -> dict[str, np.ndarray]:
    out = {
        "mean": report.belief.get_mean(),
        "cov": report.belief.get_cov(),
        "action": report.belief.get_action(),
        "control": report.belief.get_control(),
        "state": report.real.get_state(),
        "observation": report.real.get_observation(),
        "margins": np.array([report.belief_margin, report.state_margin]),
        "satisfied": np.array([report.belief_satisfied, report.state_satisfied]),
        "plan_starts": np.array([k for k, _ in report.plans]),
    }
    for i, (_, p) in enumerate(report.plans):
        out[f"plan{i}_mean"] = p.get_mean()
        out[f"plan{i}_cov"] = p.get_cov()
        out[f"plan{i}_action"] = p.get_action()
        out[f"plan{i}_control"] = p.get_control()
    return out


@pytest.fixture(scope="module")
def reference() -> Any:
    with np.load(DATA, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


@pytest.mark.parametrize("name", sorted(CASES))
def test_execute_reproduces_the_recorded_report(reference, name):
    problem = _problem()
    plan = _plan({k[len("first_") :]: v for k, v in reference.items() if k.startswith("first_")})
    report = _run(name, problem, plan)
    assert_records_close(_records(report), json.loads(str(reference[f"{name}/records"])), name)
    arrays = _arrays(report)
    recorded = sorted(
        k[len(name) + 1 :] for k in reference if k.startswith(f"{name}/") and k != f"{name}/records"
    )
    assert sorted(arrays) == recorded
    for key, value in arrays.items():
        assert_close_to_reference(value, reference[f"{name}/{key}"], f"{name}/{key}")
    assert report.seed_entropy == CASES[name][2]


def _without_guarantee(kw: dict[str, Any]) -> dict[str, Any]:
    solver = {k: v for k, v in kw["solver_options"].items() if k != "guarantee"}
    return {**kw, "solver_options": solver}


LIVE = [(name, False) for name in sorted(CASES)] + [("on_risk", True), ("unscheduled_start", True)]


@pytest.mark.parametrize(("name", "default_guarantee"), LIVE)
def test_execute_is_the_chunked_executor_it_replaced_on_the_current_solver(
    reference, name, default_guarantee
):
    """Beside the old executor (tests/oracles/chunked_execute.py) on today's solver and predictor:
    the same records, plans and runs bit for bit, whatever synthesis does to the re-solves (also
    with the solver's default guarantee, which the recording predates)."""
    from oracles import chunked_execute

    real, plant, seed, kw = CASES[name]
    if default_guarantee:
        kw = _without_guarantee(kw)
    if name.startswith("listing"):
        problem, plan, real_system, x0 = _listing()
    else:
        problem = _problem()
        plan = _plan({k[len("first_") :]: v for k, v in reference.items() if k.startswith("first_")})
        real_system, x0 = (None if real is None else real()), np.array([0.2, -0.1])
    old = chunked_execute.execute(problem, plan, real_system, x0, seed=seed, plant=plant, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        new = stl.execute(problem, plan, real_system, x0, seed=seed, plant=plant, **kw)
    assert _records(new) == _records(old) and old.replans
    old_arrays, new_arrays = _arrays(old), _arrays(new)
    assert sorted(old_arrays) == sorted(new_arrays)
    for key, value in new_arrays.items():
        assert np.array_equal(value, old_arrays[key], equal_nan=True), (name, key)


def test_the_cases_exercise_what_they_are_named_for(reference):
    """The fixture covers re-solves on risk and drift, the start check and the schedule."""
    reasons = {name: [r["reason"] for r in json.loads(str(reference[f"{name}/records"]))] for name in CASES}
    assert "risk" in reasons["on_risk"] and "drift" in reasons["drift"]
    assert "start" in reasons["unscheduled_start"] and "drift" in reasons["unscheduled_start"]
    assert set(reasons["every"]) == {"every"} and reasons["plant_start_only"] == ["start"]
    assert reasons["listing_on_risk"] == ["risk"]
    assert all(len(reference[f"{name}/plan_starts"]) >= 2 for name in ("on_risk", "every"))


def _regenerate() -> None:
    problem = _problem()
    solved = problem.solve(**OPTIONS)
    if solved is None:
        raise SystemExit(f"no plan: {problem.last_result.reason}")
    # the first plan as the test reads it back: its arrays (not the gains it carries)
    plan = _plan(
        {
            f"plan_{k}": v
            for k, v in (
                ("mean", solved.get_mean()),
                ("cov", solved.get_cov()),
                ("action", solved.get_action()),
                ("control", solved.get_control()),
            )
        }
    )
    out: dict[str, Any] = {
        "first_plan_mean": plan.get_mean(),
        "first_plan_cov": plan.get_cov(),
        "first_plan_action": plan.get_action(),
        "first_plan_control": plan.get_control(),
    }
    for name in CASES:
        report = _run(name, problem, plan)
        out[f"{name}/records"] = np.array(json.dumps(_records(report)))
        for key, value in _arrays(report).items():
            out[f"{name}/{key}"] = value
        print(name, [(r.step, r.reason, r.status, r.adopted) for r in report.replans], file=sys.stderr)
    np.savez_compressed(DATA, **out)


if __name__ == "__main__":
    _regenerate()
