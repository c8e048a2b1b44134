"""guarantee="closed_loop": chance constraints on the true state predicted under the executor.

Checked against ground truth built independently of the planner:
- the planner's prediction (:func:`idstlpy.closed_loop.predicted_state`) against Monte Carlo
  runs of :func:`idstlpy.simulate` with the true start drawn from the prior;
- the covariance order the proofs rely on (never below the MLO covariance under constant
  sensor noise), as a property over random systems;
- every plan the closed-loop solve returns, by the monitor on an independent re-prediction and by
  the executed true states' per-step violation rates;
- the honesty of ``infeasible``: kept under constant noise, demoted under state-dependent noise.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import idstlpy as stl
from idstlpy import scenarios
from idstlpy.closed_loop import predicted_state, trackable, tracking_spread
from idstlpy.errors import InvalidArgumentError
from idstlpy.synthesis.results import SolveResult


def _hold_problem(half_width: float = 0.3, clip: bool = True, conf: float = 0.9) -> stl.Problem:
    """Reach the box around (2, 2) within 12 steps and hold it 8, constant sensor, W > 0."""
    x = stl.mk_variable(size=2)
    u = stl.mk_variable(size=2, name="u")
    mode = stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=0.1 * np.eye(2), C=np.eye(2), V=0.3 * np.eye(2))
    bound = 1.0 if clip else 50.0
    domain = stl.logical_and(u[0] >= -bound, u[0] <= bound, u[1] >= -bound, u[1] <= bound).region
    lo, hi = 2 - half_width, 2 + half_width
    target = stl.logical_and(
        *[stl.prob(e) >= conf for e in (x[0] >= lo, x[0] <= hi, x[1] >= lo, x[1] <= hi)], name="target"
    )
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=domain,
        initial_state=stl.to_belief(mean=np.zeros(2), cov=0.2 * np.eye(2)),
        stl_formula=stl.eventually(0, 12, stl.always(0, 8, target)),
    )


def _random_plan(rng: np.random.Generator, n: int, steps: int) -> tuple[stl.Problem, object]:
    A = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    B = rng.standard_normal((n, n))
    C = rng.standard_normal((1, n))
    mode = stl.mk_lbs(A=A, B=B, W=0.2 * rng.random() * np.eye(n), C=C, V=np.array([[0.1 + rng.random()]]))
    x = stl.mk_variable(size=n)
    u = stl.mk_variable(size=n, name="u")
    problem = stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=stl.logical_and(*[c for i in range(n) for c in (u[i] >= -5, u[i] <= 5)]).region,
        initial_state=stl.to_belief(mean=np.zeros(n), cov=(0.1 + rng.random()) * np.eye(n)),
        stl_formula=stl.eventually(0, 3, stl.prob(x[0] <= 100.0) >= 0.9),
    )
    controls = rng.uniform(-1, 1, size=(steps, n))
    plan = stl.rollout(problem.switched_system, problem.initial_state, np.zeros(steps, dtype=int), controls)
    return problem, plan


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 3), steps=st.integers(1, 12))
def test_predicted_covariance_never_below_mlo_under_constant_noise(seed, n, steps):
    problem, plan = _random_plan(np.random.default_rng(seed), n, steps)
    predicted = predicted_state(problem.switched_system, plan, None)
    for k in range(steps + 1):
        gap = predicted.get_cov(k) - plan.get_cov(k)
        lowest = float(np.linalg.eigvalsh(0.5 * (gap + gap.T))[0])
        assert lowest >= -1e-9 * max(1.0, float(np.abs(plan.get_cov(k)).max())), (k, lowest)
    # Without clipping the loop is linear and centred on the plan.
    np.testing.assert_allclose(predicted.get_mean(), plan.get_mean(), atol=1e-9)


def test_prediction_matches_monte_carlo_of_the_executor():
    problem = _hold_problem(clip=False)
    result = problem.solve_result(seed=0, time_limit=30)
    assert result.found
    plan = result.trajectory
    predicted = predicted_state(problem.switched_system, plan, None)
    rng = np.random.default_rng(7)
    runs = 1500
    init = problem.initial_state
    states = np.empty((runs, plan.num_of_steps + 1, 2))
    for r in range(runs):
        x0 = rng.multivariate_normal(init.mean, init.cov)
        _, real = stl.simulate(
            problem.switched_system, plan, plan.num_of_steps, x0, problem.switched_system, seed=rng
        )
        states[r] = real.get_state()
    dev = states - plan.get_mean()[None]
    mc_cov = np.einsum("rki,rkj->kij", dev, dev) / runs
    pred_cov = predicted.get_cov()
    # Variance estimates from 1500 Gaussian samples: relative sd sqrt(2/1500) = 3.7%; 5 sd.
    for k in range(plan.num_of_steps + 1):
        np.testing.assert_allclose(np.diag(mc_cov[k]), np.diag(pred_cov[k]), rtol=0.2, atol=1e-3)
    np.testing.assert_allclose(dev.mean(axis=0), 0.0, atol=5 * np.sqrt(pred_cov.max() / runs))


def test_mlo_plan_breaks_its_promise_and_closed_loop_keeps_it():
    problem = _hold_problem(0.3)
    mlo = problem.solve_result(seed=0, time_limit=30, guarantee="mlo")
    assert mlo.found and mlo.guarantee == "mlo" and mlo.predicted is None
    system, domain, formula = problem.switched_system, problem.control_domain, problem.stl_formula
    # The MLO plan is fine for its own semantics but its executed true state is not.
    assert stl.robustness(predicted_state(system, mlo.trajectory, domain), formula) < 0

    cl = problem.solve_result(seed=0, time_limit=30, guarantee="closed_loop")
    assert cl.found and cl.guarantee == "closed_loop"
    again = predicted_state(system, cl.trajectory, domain)
    assert stl.robustness(again, formula) == pytest.approx(cl.margin, abs=1e-9)
    assert cl.margin >= 0
    np.testing.assert_allclose(again.get_cov(), cl.predicted.get_cov())
    # Its inputs leave the tracking correction room (the back-off): clipping is rare.
    spread = tracking_spread(system, cl.trajectory, domain)
    assert spread.shape == (cl.trajectory.num_of_steps, 4) and spread.max() > 0
    assert trackable(system, cl.trajectory, domain)
    # The MLO plan rides the input bounds: it leaves the tracking correction no room.
    assert not trackable(system, mlo.trajectory, domain)


def test_closed_loop_check_screens_an_untrackable_plan_with_the_gaussian_closure(monkeypatch):
    """The particle closure (ten Gaussian ones) only for an untrackable plan whose Gaussian
    prediction passes; one whose Gaussian prediction fails is rejected on it (here the particles
    agree: the linearisation under-states the rectifier's spread)."""
    from idstlpy.synthesis import closed_loop_plan as teacher

    real = teacher.predicted_state
    closures: list[str] = []

    def spy(*args, closure="gaussian", **kwargs):
        closures.append(closure)
        return real(*args, closure=closure, **kwargs)

    monkeypatch.setattr(teacher, "predicted_state", spy)
    for half_width, passes in ((0.3, False), (1.2, True)):
        problem = _hold_problem(half_width)
        plan = problem.solve_result(seed=0, time_limit=30, guarantee="mlo").trajectory
        system, domain, formula = problem.switched_system, problem.control_domain, problem.stl_formula
        gaussian = stl.robustness(real(system, plan, domain), formula)
        particles = stl.robustness(real(system, plan, domain, closure="particles"), formula)
        closures.clear()
        _, margin, ok, tracks = teacher.closed_loop_check(system, plan, domain, formula)
        assert not tracks and ok is passes
        if passes:
            assert closures == ["gaussian", "particles"] and margin == particles >= 0
        else:
            assert closures == ["gaussian"] and margin == gaussian < 0 and particles < 0


def test_closed_loop_plan_holds_under_execution_at_the_promised_rate():
    problem = _hold_problem(0.3)
    cl = problem.solve_result(seed=0, time_limit=30, guarantee="closed_loop")
    assert cl.found
    plan = cl.trajectory
    rng = np.random.default_rng(11)
    runs = 400
    init = problem.initial_state
    met = np.zeros((plan.num_of_steps + 1, 4))  # per step, per face of the target
    for _ in range(runs):
        x0 = rng.multivariate_normal(init.mean, init.cov)
        _, real = stl.simulate(
            problem.switched_system,
            plan,
            plan.num_of_steps,
            x0,
            problem.switched_system,
            seed=rng,
            control_domain=problem.control_domain,
        )
        xs = real.get_state()
        met += np.concatenate([xs >= 1.7, xs <= 2.3], axis=1)
    rate = met / runs
    # The last 9 steps hold the target: each face is promised to the true state with 90%.
    # Allow 4 Monte Carlo standard deviations.
    tail = rate[-9:]
    assert tail.min() >= 0.9 - 4 * np.sqrt(0.9 * 0.1 / runs), tail


def test_infeasible_stays_a_proof_under_constant_noise():
    problem = _hold_problem(0.05, conf=0.99)  # the MLO covariance alone does not fit
    assert problem.solve_result(seed=0, time_limit=30).status == "infeasible"
    cl = problem.solve_result(seed=0, time_limit=30, guarantee="closed_loop")
    assert cl.status == "infeasible" and cl.guarantee == "closed_loop"


def test_infeasible_is_not_claimed_under_state_dependent_noise():
    problem = scenarios.light_dark(deadline=2, hold=1)  # the target is out of reach
    mlo = problem.solve_result(seed=0, time_limit=30, guarantee="mlo")
    assert mlo.status == "infeasible"
    cl = problem.solve_result(seed=0, time_limit=30, guarantee="closed_loop")
    assert cl.status == "budget_exhausted"
    assert "no proof for guarantee='closed_loop'" in cl.reason


def test_guarantee_option_is_validated():
    with pytest.raises(InvalidArgumentError, match="guarantee"):
        _hold_problem().solve_result(guarantee="robust")


def test_result_round_trip_keeps_the_prediction(tmp_path):
    problem = _hold_problem(0.3)
    cl = problem.solve_result(seed=0, time_limit=30, guarantee="closed_loop")
    back = stl.load_result(cl.save(tmp_path / "r.json"))
    assert back.guarantee == "closed_loop"
    np.testing.assert_allclose(back.predicted.get_cov(), cl.predicted.get_cov())
    assert SolveResult.from_dict(problem.solve_result(seed=0, time_limit=30).to_dict()).predicted is None


def test_repair_takes_the_first_fraction_of_a_step_that_keeps_the_promise():
    """Under state-dependent noise a whole repair step can break the plan while a fraction of it
    keeps the promise (the double integrator, seed 1): the line search finds that fraction, and
    gives up when no fraction passes or improves."""
    from idstlpy.belief import rollout
    from idstlpy.synthesis.abstraction import Abstraction
    from idstlpy.synthesis.certify import STEP_FRACTIONS, line_search
    from idstlpy.synthesis.interfaces import Budget
    from idstlpy.synthesis.plan_lp import PlanLPContext
    from idstlpy.synthesis.teacher import closed_loop_check

    problem = scenarios.light_dark()
    res = problem.solve_result(seed=0, time_limit=30, guarantee="closed_loop")
    assert res.found
    traj, system, domain = res.trajectory, problem.switched_system, problem.control_domain
    context = PlanLPContext.of(problem, Abstraction(problem.stl_formula, system.n))
    budget = Budget(np.inf)
    L = traj.num_of_steps + 1
    start, acts = traj.get_control(), traj.get_action()[: L - 1]
    j = L // 2
    # a kick and its opposite mid-plan: the whole kick throws the plan off its course
    kick = np.zeros_like(start)
    kick[j, 0], kick[j + 1, 0] = 4.0, -4.0
    whole = rollout(system, problem.initial_state, acts, start + kick)
    assert not closed_loop_check(system, whole, domain, problem.stl_formula)[2]
    found = line_search(context, problem, traj, start + kick, res.margin, budget)
    assert found is not None and found.ok
    out = found.traj
    fraction = (out.get_control()[j, 0] - start[j, 0]) / kick[j, 0]
    assert fraction in STEP_FRACTIONS and fraction < 1.0
    np.testing.assert_allclose(out.get_control(), start + fraction * kick)
    assert closed_loop_check(system, out, domain, problem.stl_formula)[2]
    # the larger fractions did not pass: the first passing one is taken
    for a in STEP_FRACTIONS:
        if a <= fraction:
            break
        moved = rollout(system, problem.initial_state, acts, start + a * kick)
        assert not closed_loop_check(system, moved, domain, problem.stl_formula)[2]
    # a kick no fraction survives, and none improves on the plan's margin: no step
    assert line_search(context, problem, traj, start + 8.0 * kick, res.margin, budget) is None
