"""The re-planning check's first stage (:mod:`idstlpy.execution.vouch`): the plan's shared
prediction conditioned on a run's belief.

What must hold: the vouch reads the full check's value up to the two linearisations' difference
and not above it (there it would pass a check the full prediction fails), the decisions and the
records of an execution are those of the full checks, and the full prediction is skipped where
the vouch reaches the risk."""

from __future__ import annotations

import math

import numpy as np
import pytest

import idstlpy as stl
import idstlpy.execution.batches as batches
import idstlpy.execution.replanner as replanner
import idstlpy.execution.resolving as resolving
import idstlpy.execution.vouch as vouch
from idstlpy.progression import progress
from idstlpy.scenarios import light_dark, light_dark_real_system

SAMPLER = {"rrt_timeout": 60, "delta_near": 2, "delta_drain": 0.5, "goal_bias": 0.25}


@pytest.fixture(scope="module")
def listing() -> tuple[stl.Problem, stl.ProbabilisticTSTrajectory]:
    problem = light_dark()
    plan = problem.solve(**SAMPLER, min_num_of_steps=3, max_num_of_steps=15, seed=0)
    assert plan is not None
    return problem, plan


def test_vouch_is_below_the_full_check(
    listing: tuple[stl.Problem, stl.ProbabilisticTSTrajectory], monkeypatch: pytest.MonkeyPatch
) -> None:
    problem, plan = listing
    pairs: list[tuple[float, float]] = []
    decide = replanner.decide

    def both(resolver, policy, formula, snap):  # type: ignore[no-untyped-def]
        ref = replanner.check_reference(resolver.model.spec, snap.plan, formula)
        assert ref is not None
        v = ref.vouch(snap.executed, snap.belief, policy.risk_on)
        p, _ = resolver.model.predict(snap.plan, snap.j, progress(formula, snap.executed), snap.belief)
        pairs.append((v, p))
        return decide(resolver, policy, formula, snap)

    monkeypatch.setattr(replanner, "decide", both)
    stl.execute(problem, plan, light_dark_real_system(), [0.5, 2.75], seed=3, policy=stl.ReplanPolicy())
    got = np.array(pairs)
    assert got.shape[0] == plan.num_of_steps - 1  # one check per step 1 .. N-1
    assert np.isfinite(got).all()
    # Light-dark's sensor depends on the state and its inputs are clipped: the vouch keeps the
    # plan's linearisation (conditioned on the run), the full check re-linearises around the
    # run's own path. Measured: the vouch at most 7e-7 above the full bound, 0.0013 below on
    # average; a vouch well above the full check would pass checks the full one fails.
    assert np.all(got[:, 0] <= got[:, 1] + 1e-5), got[got[:, 0] > got[:, 1] + 1e-5]
    assert np.all(np.abs(got[:, 0] - got[:, 1]) <= 0.01)
    assert float(np.mean(got[:, 0] - got[:, 1])) <= 0.0


def test_same_records_with_and_without_the_vouch(
    listing: tuple[stl.Problem, stl.ProbabilisticTSTrajectory], monkeypatch: pytest.MonkeyPatch
) -> None:
    problem, plan = listing
    calls = [0]
    predict = resolving._RiskModel.predict

    def counted(self, *a, **kw):  # type: ignore[no-untyped-def]
        calls[0] += 1
        return predict(self, *a, **kw)

    monkeypatch.setattr(resolving._RiskModel, "predict", counted)
    x0 = np.array([0.5, 2.75])
    real = light_dark_real_system()
    # risk 0.99: below some vouches (full checks run), above the plan's own bound (no re-solve)
    policy = stl.ReplanPolicy(risk=0.99)
    fast = stl.execute(problem, plan, real, x0, seed=5, policy=policy)
    fast_calls = calls[0]
    monkeypatch.setattr(replanner, "check_reference", lambda *a: None)
    calls[0] = 0
    slow = stl.execute(problem, plan, real, x0, seed=5, policy=policy)
    assert slow == fast
    assert calls[0] == plan.num_of_steps - 1
    assert fast_calls < calls[0]


def test_default_policy_validates_without_full_predictions(
    listing: tuple[stl.Problem, stl.ProbabilisticTSTrajectory], monkeypatch: pytest.MonkeyPatch
) -> None:
    problem, plan = listing
    calls = [0]
    predict = resolving._RiskModel.predict

    def counted(self, *a, **kw):  # type: ignore[no-untyped-def]
        calls[0] += 1
        return predict(self, *a, **kw)

    monkeypatch.setattr(resolving._RiskModel, "predict", counted)
    real = light_dark_real_system()
    a = stl.validate(problem, plan, real, runs=4, seed=1, executor="serial", policy=stl.ReplanPolicy())
    b = stl.validate(problem, plan, real, runs=4, seed=1, executor="serial", policy=stl.ReplanPolicy())
    assert calls[0] == 0  # every check of the default policy (risk 0.9) vouched for
    assert a.replans == b.replans == (0, 0, 0, 0)
    assert a.belief_success_rate == b.belief_success_rate


def test_no_vouch_for_a_re_solved_plan(listing: tuple[stl.Problem, stl.ProbabilisticTSTrajectory]) -> None:
    problem, plan = listing
    runner = stl.ReplanningExecutor(problem, plan, stl.ReplanPolicy())
    ref = replanner.check_reference(runner.spec, plan, problem.stl_formula)
    assert ref is not None
    executed = stl.ProbabilisticTSTrajectory(
        plan.get_mean()[:3], plan.get_cov()[:3], (plan.get_action()[:2] + 1) % 2, plan.get_control()[:2]
    )
    belief = stl.GaussianBelief(plan.get_mean(2), plan.get_cov(2))
    assert math.isnan(ref.vouch(executed, belief, "both"))  # modes left the plan's
    executed = stl.ProbabilisticTSTrajectory(
        plan.get_mean()[:3], plan.get_cov()[:3], plan.get_action()[:2], plan.get_control()[:2]
    )
    assert 0.0 < ref.vouch(executed, belief, "both") <= 1.0


def test_batched_policy_runs_are_the_executed_ones(
    listing: tuple[stl.Problem, stl.ProbabilisticTSTrajectory], monkeypatch: pytest.MonkeyPatch
) -> None:
    problem, plan = listing
    real = light_dark_real_system()
    # risk 0.9: every check passes on this plan; half the runs are taken from the batch, the
    # others executed one at a time (as a run the vouch falls short on would be)
    policy = stl.ReplanPolicy()
    taken: list[int] = []
    calls: list[int] = []
    vouched_runs = vouch.vouched_runs

    def half(*a):  # type: ignore[no-untyped-def]
        ok = vouched_runs(*a)
        assert ok.all()
        seen = sum(calls)  # runs seen so far (validate may hand them over in several batches)
        calls.append(ok.size)
        ok[(seen + np.arange(ok.size)) % 2 == 1] = False
        taken.append(int(ok.sum()))
        return ok

    monkeypatch.setattr(vouch, "vouched_runs", half)
    kw = {"runs": 6, "seed": 2, "executor": "serial", "policy": policy, "keep_trajectories": 6}
    fast = stl.validate(problem, plan, real, **kw)
    assert sum(taken) == 3
    monkeypatch.setattr(batches, "_vouched_batch", lambda *a: {})
    slow = stl.validate(problem, plan, real, **kw)
    assert fast.replans == slow.replans
    assert fast.belief_success_rate == slow.belief_success_rate
    assert fast.state_success_rate == slow.state_success_rate
    assert len(fast.executions) == len(slow.executions) == 6
    for (bf, rf), (bs, rs) in zip(fast.executions, slow.executions, strict=True):
        np.testing.assert_allclose(bf.get_mean(), bs.get_mean(), rtol=0, atol=1e-9)
        np.testing.assert_allclose(rf.get_state(), rs.get_state(), rtol=0, atol=1e-9)
