"""Control domains that are not boxes (issue 32, item 2): the prediction projects as the executor does.

Ground truth: ``tests/oracles/polytope_executor.py``, an executor written apart from the package
(its own Kalman filter, LQR gains and a geometric projection on the polygon), run as Monte Carlo.

- the projection (:func:`idstlpy.tracking.control_projector`, shared by the executor and the
  prediction) is the oracle's on random polygons, whichever of its two paths (active sets checked
  for all rows at once; the least-distance programme by non-negative least squares) answers;
- on seeded random problems of each family (diamonds, boxes with a corner cut, random polygons),
  the prediction's success estimates agree with the oracle's Monte Carlo within sampling error
  and no lower bound lies above its measured rate beyond sampling error, under the default
  closure and under the Gaussian one (whose moments leave the projection out: its estimates
  are sampled through it, its bounds discounted by the probability that it acts);
- ``meets_target`` follows: a plan the unprojected loop predicts at 97% and the oracle measures
  at 82% is reported below target; the planner's judge reads the same prediction, and
  ``guarantee="closed_loop"`` checks plans on the projected (particle) loop.

The big campaign (100 random problems, 4000 runs each) is ``benchmarks/polytope_domains.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from oracles.polytope_executor import (
    DOMAIN_FAMILIES,
    _domain,
    polygon_vertices,
    project_on_polygon,
    random_case,
    run_executor,
    success,
)

import idstlpy as stl
from idstlpy.closed_loop import predicted_state, projection_left_out, trackable
from idstlpy.execution.prediction import predict_closed_loop
from idstlpy.execution_target import ExecutionTarget
from idstlpy.executor import ExecutorSpec
from idstlpy.sets import Polytope
from idstlpy.synthesis.closed_loop_plan import closed_loop_check
from idstlpy.synthesis.predicted_execution import PredictedExecution
from idstlpy.tracking import PolytopeProjection, control_projector

RUNS = 400  # oracle executions per case
SAMPLES = 4000  # the prediction's samples (its default)
Z = 4.0  # standard errors allowed (a handful of cases, two readings each: no false alarm)


def _sd(p: float, runs: int, samples: int = 0) -> float:
    """Standard deviation of the difference of two independent binomial rates around ``p``
    (a floor of one event in ``runs``: a rate of 0 or 1 still has a sampling error)."""
    p = min(max(p, 1.0 / runs), 1.0 - 1.0 / runs)
    return math.sqrt(p * (1 - p) * (1.0 / runs + (1.0 / samples if samples else 0.0)))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from(DOMAIN_FAMILIES))
def test_projection_is_the_geometric_one(seed: int, family: str) -> None:
    rng = np.random.default_rng(seed)
    H, c = _domain(rng, family)
    project = control_projector(Polytope(H, c), 2)
    assert isinstance(project, PolytopeProjection)
    U = rng.normal(size=(300, 2)) * 3.0 * float(np.max(np.abs(c)))
    got = project(U)
    want = project_on_polygon(U, H, c, polygon_vertices(H, c))
    np.testing.assert_allclose(got, want, atol=1e-9)
    # the least-distance programme alone gives the same points
    values = U @ project.H.T + project.c
    outside = np.flatnonzero(np.any(values > project.INSIDE_TOL, axis=1))
    assert outside.size  # the test is not empty: points outside were projected
    for i in outside[:20].tolist():
        np.testing.assert_allclose(project.one(U[i], values[i]), want[i], atol=1e-9)
    # inside points are returned unchanged, one row projects as in a batch
    inside = np.setdiff1d(np.arange(U.shape[0]), outside)
    np.testing.assert_array_equal(got[inside], U[inside])
    np.testing.assert_array_equal(project(U[outside[0]]), got[outside[0]])


def test_executor_and_prediction_share_the_projection() -> None:
    case = random_case(3, "diamond")
    problem, _ = case.to_problem()
    spec = ExecutorSpec.make(problem.switched_system, control_domain=problem.control_domain)
    assert spec.project == control_projector(problem.control_domain, 2)
    assert spec.box is None


def test_non_finite_inputs_are_left_as_they_are() -> None:
    """A diverging run's input (inf, NaN) is not handed to the solver (no raw scipy error)."""
    H = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]])
    project = control_projector(Polytope(H, -np.ones(4)), 2)
    U = np.array([[np.inf, 0.0], [np.nan, 1.0], [3.0, 0.0]])
    out = project(U)
    np.testing.assert_array_equal(out[:2], U[:2])
    np.testing.assert_allclose(out[2], [1.0, 0.0], atol=1e-12)


def test_an_empty_domain_is_refused() -> None:
    empty = Polytope(np.array([[1.0, 1.0], [-1.0, -1.0]]), np.array([1.0, 1.0]))  # u0 + u1 <= -1 and >= 1
    with pytest.raises(stl.errors.InvalidArgumentError, match="control_domain is empty"):
        control_projector(empty, 2)


# seeded cases of each family (deterministic): 289 is the one of 300 the unprojected loop
# predicts at 97% and executes at 82% (below)
CASES = [(11, "diamond"), (40, "diamond"), (1, "cut_box"), (289, None), (0, "polygon"), (3, "polygon")]


def _oracle(case, runs: int = RUNS, seed: int = 12345, weights=None) -> dict[str, float]:
    M, P, X, moved = run_executor(case, runs, seed, weights)
    ok = success(case, M, P, X)
    return {"belief": float(ok["belief"].mean()), "state": float(ok["state"].mean()), "moved": moved}


@pytest.mark.parametrize("seed, family", CASES)
def test_prediction_agrees_with_the_oracle(seed: int, family: str | None) -> None:
    case = random_case(seed, family)
    problem, plan = case.to_problem()
    measured = _oracle(case)
    assert measured["moved"] > 0.02  # the projection acts: the test is not about the unclipped loop
    pred = predict_closed_loop(problem, plan, real_initial_cov=case.cov0, samples=SAMPLES)
    assert pred.closure == "particles"  # "auto": the domain takes the input with probability > 1%
    gauss = predict_closed_loop(
        problem, plan, real_initial_cov=case.cov0, samples=SAMPLES, closure="gaussian"
    )
    for reading in ("belief", "state"):
        rate = measured[reading]
        for p in (pred, gauss):
            est = getattr(p, f"{reading}_success_estimate")
            bound = getattr(p, f"{reading}_success_bound")
            assert abs(est - rate) <= Z * _sd(est, RUNS, SAMPLES), (p.closure, reading, est, rate)
            assert bound <= rate + Z * _sd(rate, RUNS), (p.closure, reading, bound, rate)


def test_meets_target_follows_the_projection() -> None:
    case = random_case(289)
    problem, plan = case.to_problem()
    target = ExecutionTarget(0.9, 0.95)
    measured = _oracle(case, runs=2000)
    assert measured["belief"] < 0.9 - 3 * _sd(0.9, 2000)  # below the target, not by noise
    # the loop without the projection (what the prediction used to read) meets the target ...
    free = predict_closed_loop(problem, plan, real_initial_cov=case.cov0, control_domain=None)
    assert PredictedExecution.from_prediction(free, target).meets_target
    # ... the executor's does not, and says by how much
    pred = predict_closed_loop(problem, plan, real_initial_cov=case.cov0)
    verdict = PredictedExecution.from_prediction(pred, target)
    assert not verdict.meets_target
    assert abs(pred.belief_success_estimate - measured["belief"]) <= Z * _sd(
        measured["belief"], 2000, SAMPLES
    )
    assert verdict.belief_bound <= measured["belief"] + Z * _sd(measured["belief"], 2000)


def test_the_planner_judges_with_the_projected_loop() -> None:
    """A solve on a diamond domain: the result's predicted execution is the oracle's rate."""
    case = random_case(11, "diamond")
    problem, _ = case.to_problem()
    # smooth=False: the smoothing step keeps this plan's inputs off the faces, and the test is
    # about a plan whose executed inputs the projection moves
    result = problem.solve_result(seed=0, time_limit=60, execution_target=(0.5, 0.5), smooth=False)
    assert result.status == "found" and result.execution is not None
    plan = result.trajectory
    N = plan.num_of_steps
    case.actions = np.asarray(plan.get_action()[:N], dtype=int)
    case.controls = np.asarray(plan.get_control()[:N], dtype=float)
    # the oracle tracks with the weights the plan reports (its own Riccati recursion on them)
    assert plan.tracking is not None and plan.tracking.weights is not None
    measured = _oracle(case, weights=dict(plan.tracking.weights))
    assert measured["moved"] > 0.02  # the planner's inputs reach the faces: the projection acts
    assert result.execution.closure == "particles"
    ex = result.execution
    for reading in ("belief", "state"):
        est = getattr(ex, f"{reading}_estimate")
        assert abs(est - measured[reading]) <= Z * _sd(est, RUNS, ex.samples), (reading, est, measured)
        assert getattr(ex, f"{reading}_bound") <= measured[reading] + Z * _sd(measured[reading], RUNS)


def test_the_closed_loop_guarantee_reads_the_projected_loop() -> None:
    """``guarantee="closed_loop"`` checks a plan on the particle closure when the Gaussian one
    leaves out a projection that acts (here on a plan that is trackable: the box rule alone would
    have kept the Gaussian closure)."""
    case = random_case(1, "diamond", (0.5, 0.8))
    problem, plan = case.to_problem()
    system, domain = problem.switched_system, problem.control_domain
    assert trackable(system, plan, domain)
    assert projection_left_out(system, plan, domain)
    assert not projection_left_out(system, plan, None)
    box = Polytope(np.vstack([np.eye(2), -np.eye(2)]), -0.3 * np.ones(4))  # clips, but is linearised
    assert not projection_left_out(system, plan, box)
    x = stl.mk_variable(2)
    loose = stl.always(0, plan.num_of_steps, stl.prob(x[0] <= 1e3) >= 0.9)
    predicted, margin, ok, tracks = closed_loop_check(system, plan, domain, loose)
    assert ok and tracks and margin > 0
    particles = predicted_state(system, plan, domain, closure="particles")
    gaussian = predicted_state(system, plan, domain, closure="gaussian")
    np.testing.assert_array_equal(predicted.get_cov(), particles.get_cov())
    assert not np.allclose(predicted.get_cov(), gaussian.get_cov(), rtol=1e-3, atol=0.0)
