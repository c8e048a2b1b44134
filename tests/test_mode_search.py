"""The mode search (synthesis/mode_search.py): its two readings and the room's failure estimate.

Issue 23: under the paper's MLO reading a two-mode robot "looks on the last step", which meets
the formula on paper and holds in a minority of executions; the default guarantee's mode search
scores sequences by their predicted execution instead. Checked here against independent
ground truth: the loop's failure estimate against its own arithmetic, and the modes it picks
against a Monte Carlo of the executor.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from benchmarks import defaults_problems as dp
from scipy.stats import norm

import idstlpy as stl
from idstlpy.backends import HighsBackend
from idstlpy.synthesis.abstraction import Abstraction
from idstlpy.synthesis.mode_search import MLOScore, ModeSearch, RoomScore, _rolled, allowed_modes
from idstlpy.synthesis.plan import DiscretePlan, trajectory_plan
from idstlpy.synthesis.plan_lp import PlanLPContext, Scaling
from idstlpy.synthesis.plan_solve import solve_plan_lp
from idstlpy.synthesis.room import room_lp
from idstlpy.synthesis.room_measure import Room, execution_room, mlo_means, plan_have


def _room(have, sd_b, sd_s, terms, w_b, w_s) -> Room:
    arrays = [np.asarray(a, dtype=float) for a in (have, sd_b, sd_s, terms, w_b, w_s)]
    have, sd_b, sd_s, terms, w_b, w_s = arrays
    need = np.ones_like(have)
    return Room(
        [(1, 0)], [need], [have], np.zeros((1, 0)), np.zeros((1, 0)), np.zeros(1),
        terms=[terms], sd_belief=[sd_b], sd_state=[sd_s], weight_belief=[w_b], weight_state=[w_s],
    )  # fmt: skip


def test_failure_is_the_weighted_sum_of_crossing_probabilities():
    room = _room([0.3, 0.5], [0.1, 0.2], [0.2, 0.4], [0.05, 0.1], [1.0, 0.5], [1.0, 1.0])
    belief, state = room.failure(room.have)
    assert belief == pytest.approx(norm.sf(3.0) + 0.5 * norm.sf(2.5), rel=1e-12)
    assert state == pytest.approx(norm.sf(0.35 / 0.2) + norm.sf(0.6 / 0.4), rel=1e-12)
    # more room, fewer failures; no spread: a face fails exactly when it has no room
    more = room.failure([np.array([0.4, 0.6])])
    assert more[0] < belief and more[1] < state
    flat = _room([0.1, -0.1], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [1.0, 1.0], [1.0, 1.0])
    assert flat.failure(flat.have) == (1.0, 1.0)
    assert flat.failure([np.array([0.1, 0.1])]) == (0.0, 0.0)


def _setting(name: str):
    problem = dp.build(name)
    system, init = problem.switched_system, problem.initial_state
    abstraction = Abstraction(problem.stl_formula, system.n)
    scaling = Scaling.compute(system, problem.control_domain, init.mean, init.cov, abstraction)
    context = PlanLPContext.of(problem, abstraction, scaling, HighsBackend())

    def solve(plan: DiscretePlan):
        return solve_plan_lp(context, plan, phases="refute")

    return problem, abstraction, context, solve


def _mlo_plan(problem: stl.Problem):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", stl.ExecutionTargetWarning)
        result = problem.solve_result(seed=0, guarantee="mlo", time_limit=60, max_candidates=100)
    assert result.found
    return result.trajectory


def test_room_score_prefers_modes_that_hold_over_the_paper_reading():
    """drive_sense (issue 23's second two-mode problem): the MLO plan's modes against the modes
    the room's search picks for the same requirements, each scored and then executed."""
    problem, abstraction, context, solve = _setting("drive_sense")
    traj = _mlo_plan(problem)
    plan = trajectory_plan(problem.stl_formula, abstraction, traj)
    assert plan is not None
    plan = DiscretePlan(plan.required, np.concatenate([[0], traj.get_action()]).astype(int), plan.length)
    score = RoomScore(problem, context, solve, lambda: 60.0, (0.9, 0.95))
    mlo_trial = score(plan)
    assert mlo_trial.key[0] == 1 and not mlo_trial.done  # met on paper, short when executed
    best = ModeSearch(problem.switched_system.num_modes, abstraction).run(plan, score, warm=True)
    assert best is not None and best.key > mlo_trial.key
    # the two sequences' plans that keep the most room, executed: the search's hold more often
    rates = []
    for modes in (plan.modes, best.modes):
        cand = DiscretePlan(plan.required, modes, plan.length)
        out = solve(cand)
        assert out.feasible
        system, init, domain = problem.switched_system, problem.initial_state, problem.control_domain
        rolled = stl.rollout(system, init, modes[1:], out.controls)
        room = execution_room(system, domain, abstraction, cand, rolled)
        moved = room_lp(context, cand, rolled, room, np.inf)
        assert moved is not None
        run = stl.rollout(system, init, modes[1:], moved[0])
        assert stl.satisfies(run, problem.stl_formula)
        report = stl.validate(problem, run, system, runs=300, seed=3)
        rates.append((report.belief_success_rate, report.state_success_rate))
    assert rates[1][0] > rates[0][0] and rates[1][1] > rates[0][1], rates


def test_room_failure_with_other_controls_reuses_the_spreads():
    """plan_have with the same modes gives exactly the room the re-predicted plan has (constant
    noise: the spreads do not depend on the means)."""
    problem, abstraction, context, solve = _setting("drive_look")
    traj = _mlo_plan(problem)
    plan = trajectory_plan(problem.stl_formula, abstraction, traj)
    assert plan is not None
    system, domain = problem.switched_system, problem.control_domain
    room = execution_room(system, domain, abstraction, plan, traj)
    assert room is not None
    shifted = stl.rollout(system, problem.initial_state, traj.get_action(), 0.9 * traj.get_control())
    again = execution_room(system, domain, abstraction, plan, shifted)
    assert again is not None
    for a, b in zip(plan_have(abstraction, room, shifted.get_mean()), again.have, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)


def test_mlo_means_are_the_rollouts_to_the_bit():
    """The mode search reads a re-planned sequence's room from mlo_means instead of a roll-out:
    its decisions stay the same only if the means are the roll-out's exactly."""
    problem, _, _, _ = _setting("drive_sense")
    system, init = problem.switched_system, problem.initial_state
    rng = np.random.default_rng(0)
    actions = rng.integers(0, system.num_modes, size=30)
    controls = rng.uniform(-1.0, 1.0, size=(30, system.m))
    means = mlo_means(system, init.mean, actions, controls)
    rolled = stl.rollout(system, init, actions, controls).get_mean()
    assert means.shape == rolled.shape
    assert np.array_equal(means, rolled)
    assert not np.array_equal(means[1:], means[:-1])


def test_mlo_score_search_is_deterministic_and_respects_mode_atoms():
    problem, abstraction, context, solve = _setting("drive_sense")
    traj = _mlo_plan(problem)
    plan = trajectory_plan(problem.stl_formula, abstraction, traj)
    assert plan is not None
    plan = DiscretePlan(plan.required, np.zeros(plan.length, dtype=int), plan.length)
    runs = [ModeSearch(2, abstraction).run(plan, MLOScore(solve)) for _ in range(2)]
    assert runs[0] is not None and runs[1] is not None
    np.testing.assert_array_equal(runs[0].modes, runs[1].modes)
    allowed = allowed_modes(plan, abstraction, 2)
    assert all(int(runs[0].modes[k]) in allowed[k] for k in range(1, plan.length))
    if runs[0].done:
        assert solve(DiscretePlan(plan.required, runs[0].modes, plan.length)).feasible


def test_room_lp_reads_the_plan_lps_rows_to_the_same_answer():
    """RoomScore hands the room LP the plan LP's rows (the same plan, covariances and
    requirements): the answer is the one the room LP's own rows give, to the bit."""
    problem, abstraction, context, solve = _setting("drive_sense")
    traj = _mlo_plan(problem)
    plan = trajectory_plan(problem.stl_formula, abstraction, traj)
    assert plan is not None
    out = solve(plan)
    assert out.status == "feasible" and out.rows is not None
    system, domain = problem.switched_system, problem.control_domain
    K = plan.num_transitions
    rolled = stl.rollout(system, problem.initial_state, plan.modes[1 : K + 1], out.controls)
    room = execution_room(system, domain, abstraction, plan, rolled)
    assert room is not None
    # the condition under which the room LP reads them (else it builds its own)
    assert np.array_equal(out.rows.covs, rolled.get_cov()[: K + 1])
    # RoomScore's roll-out reads the plan LP's covariances: the roll-out's, to the bit
    fast = _rolled(system, problem.initial_state, plan.modes[1 : K + 1], out.controls, out)
    for a, b in ((fast.get_mean(), rolled.get_mean()), (fast.get_cov(), rolled.get_cov())):
        assert a.shape == b.shape and np.array_equal(a, b)
    assert np.array_equal(fast.get_action(), rolled.get_action())
    assert np.array_equal(fast.get_control(), rolled.get_control())
    args = (context, plan, rolled, room, np.inf)
    own = room_lp(*args, linearise=False, polish=False)
    read = room_lp(*args, linearise=False, polish=False, rows=out.rows)
    assert own is not None and read is not None
    assert np.array_equal(own[0], read[0]) and own[1] == read[1]
    # a plan LP with given covariances keeps no rows (they need not be the plain plan's)
    given = solve_plan_lp(context, plan, covs=out.covs, phases="refute")
    assert given.rows is None
