"""Issue 34: the re-planning executor's decisions beside the loop, on a schedule counted in steps.

No wall-clock assertion: what is checked is which step a decision takes effect at, the records,
the plans followed and the executed belief, against :func:`idstlpy.execute` (the schedule
``k + adopt_delay``), with the background loop made to wait for each decision (a robot whose
control period is longer than a re-solve) or not.
"""

from __future__ import annotations

import numpy as np
import pytest
from tests.test_replanning import OPTIONS, SOLVER, _problem

import idstlpy as stl
from idstlpy.errors import InvalidArgumentError
from idstlpy.execution.background import BackgroundWorker, JobError

P = stl.ReplanPolicy


@pytest.fixture(scope="module")
def case():
    problem = _problem()
    plan = problem.solve(**OPTIONS)
    assert plan is not None, problem.last_result
    real = stl.mk_switched_sys([stl.mk_lcs(A=np.eye(2), B=0.5 * np.eye(2))])
    return problem, plan, real, np.array([0.2, -0.1])


def _loop(runner, real_lcs, model, x0, rng, wait=True):
    """A robot's loop: before each step, optionally wait for the decision in flight (a control
    period longer than a re-solve); the steps at which a decision was in flight."""
    x, y, states, flying = np.asarray(x0, dtype=float), None, [np.asarray(x0, dtype=float)], []
    while not runner.done:
        if wait:
            assert runner.wait(60.0)
        flying.append(runner.replanning)
        _, u = runner.step(y)
        x = real_lcs.A @ x + real_lcs.B @ u + model.W @ rng.standard_normal(model.W.shape[1])
        y = model.C @ x + model.noise(x) @ rng.standard_normal(model.p)
        states.append(x)
    runner.observe(y)
    return np.array(states), flying


def test_a_delayed_adoption_follows_the_old_plan_until_its_step(case):
    """With ``adopt_delay = d`` the run is the fixed plan's, bit for bit, until step ``k + d`` of
    the first adopted re-plan, whose plan is then followed from its own step ``d``."""
    problem, plan, real, x0 = case
    fixed = stl.execute(problem, plan, real, x0, seed=1)
    for d in (1, 2):
        report = stl.execute(
            problem, plan, real, x0, seed=1, policy=P(risk=1.0, check_every=4, solver=SOLVER, adopt_delay=d)
        )
        made = [r for r in report.replans if r.status != "skipped"]
        assert made and all(r.delay == d for r in made)
        first = next(r for r in made if r.adopted)
        switch = first.step + d
        assert report.plans[1][0] == first.step  # the new plan's step 0 is the decision's step
        assert np.array_equal(report.belief.get_control()[:switch], fixed.belief.get_control()[:switch])
        assert not np.array_equal(report.belief.get_control()[switch], fixed.belief.get_control()[switch])
        # a decision in flight makes no other: the next attempt comes after this one took effect
        assert all(b.step >= a.step + d for a, b in zip(made, made[1:], strict=False))


@pytest.mark.parametrize("kind", ["process", "thread"])
def test_background_decisions_that_arrive_in_time_give_the_deterministic_execution(case, kind):
    problem, plan, real, x0 = case
    policy = P(risk=1.0, check_every=4, max_replans=2, solver=SOLVER, adopt_delay=2)
    report = stl.execute(problem, plan, real, x0, seed=1, policy=policy)
    with stl.ReplanningExecutor(problem, plan, policy, seed=1, background=kind) as runner:
        assert runner.background == kind
        states, flying = _loop(
            runner, real.mode(0), problem.switched_system.mode(0), x0, np.random.default_rng(1)
        )
        assert runner.replans == report.replans and runner.replans
        assert [k for k, _ in runner.plans] == [k for k, _ in report.plans]
        np.testing.assert_allclose(runner.executed().get_mean(), report.belief.get_mean(), rtol=0, atol=1e-12)
        np.testing.assert_allclose(states, report.real.get_state(), rtol=0, atol=1e-12)
        # the decision of step k was in flight (or waiting for its step) during steps k+1 .. k+d
        first = report.replans[0]
        assert flying[first.step] is False and flying[first.step + 1] is True


def test_the_step_that_makes_a_background_decision_does_not_wait_for_it(case):
    """Without waiting, a decision never takes effect in the step that makes it: at least one
    more step is taken on the old plan, and the record says how many (``delay >= 1``)."""
    problem, plan, real, x0 = case
    policy = P(risk=1.0, check_every=4, max_replans=2, solver=SOLVER)  # adopt_delay 0: when in
    with stl.ReplanningExecutor(problem, plan, policy, seed=1, background=True) as runner:
        runner.step(None)
        y = np.zeros(2)
        for _ in range(3):
            runner.step(y)
        assert runner.k == 4 and not runner.replanning
        runner.step(y)  # step 4 makes the decision
        assert runner.replanning and runner.last_replan is None and runner.replans == ()
        assert runner.wait(60.0)
        runner.step(y)
        assert runner.replans and runner.replans[0].step == 4 and runner.replans[0].delay == 1


def test_cancel_drops_the_decision_and_the_worker_is_replaced(case):
    problem, plan, real, x0 = case
    policy = P(risk=1.0, check_every=4, max_replans=2, solver=SOLVER, adopt_delay=1)
    runner = stl.ReplanningExecutor(problem, plan, policy, seed=1, background="process")
    try:
        first = runner._worker._process
        runner.step(None)
        for _ in range(4):
            runner.step(np.zeros(2))
        assert runner.replanning
        runner.cancel()
        assert not runner.replanning and not first.is_alive()
        second = runner._worker._process
        assert second is not first and second.is_alive()
        while not runner.done:
            runner.step(np.zeros(2))
        runner.observe(np.zeros(2))
        assert all(r.step != 4 for r in runner.replans)  # the cancelled decision left no record
    finally:
        runner.close()
    assert not second.is_alive() and runner.background is None
    runner.close()  # idempotent


def test_background_is_checked_and_needs_a_policy(case):
    problem, plan, _, _ = case
    with pytest.raises(InvalidArgumentError, match="background must be False, True, 'process' or 'thread'"):
        stl.ReplanningExecutor(problem, plan, P(), background="gpu")
    assert stl.ReplanningExecutor(problem, plan, None, background=True).background is None
    with pytest.raises(InvalidArgumentError, match="adopt_delay must be >= 0"):
        P(adopt_delay=-1)


def _square(x: int) -> int:
    if x < 0:
        raise ValueError("negative")
    return x * x


@pytest.mark.parametrize("kind", ["process", "thread"])
def test_the_worker_answers_one_job_at_a_time_and_reports_failures(kind):
    worker: BackgroundWorker[int, int] = BackgroundWorker(_square, kind)
    try:
        assert worker.poll() is None and not worker.busy
        job = worker.submit(7)
        with pytest.raises(InvalidArgumentError, match="in flight"):
            worker.submit(8)
        assert worker.wait(30.0)
        assert worker.poll() == (job, 49) and not worker.busy
        worker.submit(-1)
        assert worker.wait(30.0)
        _, answer = worker.poll()
        assert isinstance(answer, JobError) and answer.text == "ValueError: negative"
    finally:
        worker.close()
