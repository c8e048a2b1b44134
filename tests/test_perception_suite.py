"""The active-perception suite's feasibility claims (issue 11), checked without calling the solver.

Every feasible kind's hand-made witness is rolled out with the exact belief dynamics and must
pass the monitor (so an ``infeasible`` answer on it would be unsound); the noise-floor kind's
infeasibility argument is checked numerically. The solver's success is measured by
``python -m benchmarks.perception_suite``, not asserted here.
"""

from __future__ import annotations

import numpy as np
import pytest
from benchmarks import perception_problems as pp
from benchmarks import perception_suite as suite

import idstlpy as stl

FEASIBLE = [name for name, kind in pp.KINDS.items() if kind.expected == "feasible"]


def test_every_kind_of_the_issue_is_there():
    assert len(pp.KINDS) == 13
    assert {k.expected for k in pp.KINDS.values()} <= {"feasible", "infeasible", "unknown"}
    assert [k for k, v in pp.KINDS.items() if v.expected == "infeasible"] == ["noise_floor"]


@pytest.mark.parametrize("size", pp.SIZES)
@pytest.mark.parametrize("kind", FEASIBLE)
def test_witness_satisfies_the_formula(kind, size):
    problem, witness = pp.build(kind, size)
    actions, controls = witness
    assert controls.shape == (actions.shape[0], problem.switched_system.m)
    # inputs inside the control domain
    H, c = problem.control_domain.H, problem.control_domain.c
    assert np.all(controls @ H.T + c <= 1e-9)
    traj = stl.rollout(problem.switched_system, problem.initial_state, actions, controls)
    assert stl.satisfies(traj, problem.stl_formula)
    assert stl.robustness(traj, problem.stl_formula) > 1e-3  # not on a boundary by rounding luck


def test_sensing_is_needed():
    """The target's confidence is out of reach from the prior without sensing (active perception)."""
    problem, _ = pp.build("listing", "small")
    sd0 = np.sqrt(problem.initial_state.cov[0, 0])
    assert 0.25 / pp.Z95 < sd0  # the prior's std is wider than the target allows


def test_noisy_hold_needs_sensing_during_the_hold():
    """Under W = 0.05 I the dark cannot hold the target; at the target, sensing keeps it."""
    problem, (actions, controls) = pp.build("noisy_hold", "full")
    w = pp.NOISY_HOLD_W**2
    noise = pp.LightNoise()
    p_centre, required = pp.noise_floor_arithmetic(w=w, r_min=noise([3.5])[0, 0] ** 2, half_width=0.5)
    p_dark, _ = pp.noise_floor_arithmetic(w=w, r_min=noise([0.0])[0, 0] ** 2, half_width=0.5)
    assert p_centre < required < p_dark
    assert (required - p_centre) / w < 40  # without sensing the full hold would be lost
    traj = stl.rollout(problem.switched_system, problem.initial_state, actions, controls)
    # held at the centre, the variance settles at the steady state
    assert traj.get_cov()[-1][0, 0] == pytest.approx(p_centre, rel=0.02)


def test_narrow_noisy_hold_arithmetic():
    w = pp.NARROW_HOLD_W**2
    noise = pp.LightNoise()
    p_centre, required = pp.noise_floor_arithmetic(w=w, r_min=noise([3.0])[0, 0] ** 2)
    p_dark, _ = pp.noise_floor_arithmetic(w=w, r_min=noise([0.0])[0, 0] ** 2)
    assert p_centre < required < p_dark
    assert (required - p_centre) / w < 5


@pytest.mark.parametrize("size", pp.SIZES)
def test_noise_floor_is_out_of_reach(size):
    """The steady-state variance under the best sensing exceeds what the target needs."""
    problem, witness = pp.build("noise_floor", size)
    assert witness is None
    p_ss, required = pp.noise_floor_arithmetic()
    assert p_ss == pytest.approx(0.04525, abs=1e-5)
    assert required == pytest.approx(0.0231, abs=1e-4)
    assert p_ss > required
    # the declared floor is the true minimum of the noise (reached at the light)
    mode = problem.switched_system.system_modes[0]
    np.testing.assert_allclose(mode.noise_cov(np.array([5.0, 0.0])), pp.FLOOR_B**2 * np.identity(2))
    # sit as near the light as free space allows (x = 4.5) for a long time: the variance converges
    # to that place's steady state, above p_ss, and never below p_ss anywhere
    s = pp.Script(problem)
    s.goto([4.5, 2.5]).wait(300).goto([0.0, 0.0]).wait(50)
    traj = stl.rollout(problem.switched_system, problem.initial_state, *s.plan())
    variances = traj.get_cov()[:, 0, 0]
    assert variances.min() >= p_ss - 1e-12
    p_there, _ = pp.noise_floor_arithmetic(r_min=mode.noise_cov(np.array([4.5, 0.0]))[0, 0])
    assert variances.min() == pytest.approx(p_there, rel=1e-3) and p_there > required
    assert not stl.satisfies(traj, problem.stl_formula)


def test_real_initial_state_is_the_papers():
    problem, _ = pp.build("listing", "full")
    np.testing.assert_allclose(pp.real_initial_state("listing", problem), [0.5, 2.75])
    problem, _ = pp.build("double_integrator", "small")
    np.testing.assert_allclose(pp.real_initial_state("double_integrator", problem), [0.5, 2.75, 0.0, 0.0])
    real = pp.real_system(problem)
    assert real.num_modes == problem.switched_system.num_modes


def test_summary_and_table_from_rows():
    rows = [
        {
            "kind": "listing",
            "status": "found",
            "solve_s": 0.3,
            "plan_length": 70,
            "mc_belief_rate": 1.0,
            "mc_state_rate": 0.99,
            "nodes": 100,
            "candidates": 2,
            "caps_hit": "",
            "check": "ok",
        },
        {
            "kind": "listing",
            "status": "budget_exhausted",
            "solve_s": 120.0,
            "plan_length": "",
            "mc_belief_rate": "",
            "mc_state_rate": "",
            "nodes": 5000,
            "candidates": 9,
            "caps_hit": "time_limit",
            "check": "ok",
        },
        {
            "kind": "noise_floor",
            "status": "infeasible",
            "solve_s": "0.2",
            "plan_length": "",
            "mc_belief_rate": "",
            "mc_state_rate": "",
            "nodes": "0",
            "candidates": "0",
            "caps_hit": "",
            "check": "ok",
        },
    ]
    summary = {s["kind"]: s for s in suite.summarise(rows)}
    assert summary["listing"]["success"] == 0.5
    assert summary["listing"]["median_length"] == 70
    assert summary["listing"]["caps_hit"] == 1
    assert summary["noise_floor"]["success"] == 1.0
    table = suite.markdown_table(list(summary.values()))
    assert "(k) the paper's listing" in table and "1/2" in table


def test_arguments():
    args = suite.parse_args(["--size", "small", "--seeds", "3", "--kinds", "listing,noise_floor"])
    assert args.kinds == ["listing", "noise_floor"] and args.seeds == 3 and args.time_limit == 120.0
    with pytest.raises(SystemExit):
        suite.parse_args(["--kinds", "nope"])


# ------------------------------------------------------------------------------------------------
# Small versions of the kinds the sampler used to miss, solved (the monitor verifies every "found")


def _solve_small(kind, seed=0):
    problem, _ = pp.build(kind, "small")
    result = problem.solve_result(**suite.SAMPLER, seed=seed, time_limit=120)
    return problem, result


def _assert_found_and_met(problem, result):
    """Found, and the plan's controls re-rolled from the prior satisfy the formula (the monitor)."""
    assert result.status == "found", result.reason
    traj = stl.rollout(
        problem.switched_system,
        problem.initial_state,
        result.trajectory.get_action(),
        result.trajectory.get_control(),
    )
    assert stl.satisfies(traj, problem.stl_formula)


@pytest.mark.parametrize("kind", ["sensor_switching", "patrol", "double_integrator"])
def test_small_version_is_solved(kind):
    problem, result = _solve_small(kind)
    _assert_found_and_met(problem, result)
    assert not result.stats.caps_hit  # decided by the work budget, not by the clock


def test_sensor_switching_is_found_by_the_sampler_and_is_deterministic():
    """The LP refutes candidates for their mode sequence only; the sampler picks its own modes
    (with gentle steering the slow sensing mode alone often makes it in time)."""
    _, first = _solve_small("sensor_switching", seed=3)
    _, again = _solve_small("sensor_switching", seed=3)
    assert first.status == again.status == "found"
    assert "sampler" in first.reason
    actions = first.trajectory.get_action()
    assert set(np.unique(actions)) <= {0, 1}
    np.testing.assert_array_equal(actions, again.trajectory.get_action())
    np.testing.assert_array_equal(first.trajectory.get_control(), again.trajectory.get_control())


def test_double_integrator_steering_can_always_stop():
    """Toward a sample out of reach, the steering keeps the branch able to stop within one extension."""
    from idstlpy.synthesis.abstraction import Abstraction
    from idstlpy.synthesis.options import SolverOptions
    from idstlpy.synthesis.sampler import BeliefSampler

    problem, _ = pp.build("double_integrator", "small")
    opts = SolverOptions.make(**suite.SAMPLER)
    sampler = BeliefSampler(problem, Abstraction(problem.stl_formula, 4), None, opts)
    mode = problem.switched_system.system_modes[0]
    H, c = problem.control_domain.H, problem.control_domain.c
    mean = np.array([0.0, 2.5, 0.0, 0.0])
    far = np.array([4.5, 2.5, 0.0, 0.0])
    horizon = opts.max_num_of_steps
    for _ in range(6 * horizon):
        u = sampler._steer(0, mean, far, 3)
        assert np.all(H @ u + c <= 1e-9)
        mean = mode.A @ mean + mode.B @ u
        # braking at full deceleration stops within the horizon
        assert np.max(np.abs(mean[2:])) <= horizon * 0.05 + 1e-9
    assert mean[0] > 4.0 and abs(mean[2]) < 0.05  # arrived, nearly at rest


def test_tight_hold_under_process_noise_is_found():
    """(d'): a 40-step hold whose belief must sit within 0.05 of the target's centre. Holders
    settle at the centre and go on for the rest of their plan (a hold is not limited to one
    extension), and under process noise a holder is selected by its progress."""
    problem, _ = pp.build("noisy_hold_narrow", "full")
    # The paper's reading: under the default ("execution") no plan of (d') meets the target and
    # the search for one runs to the time cap (benchmarks/defaults_results.md).
    result = problem.solve_result(**suite.SAMPLER, seed=0, time_limit=120, guarantee="mlo")
    _assert_found_and_met(problem, result)
    assert not result.stats.caps_hit
    # No plan of (d') keeps the room its execution needs (perception_problems.noisy_hold_narrow):
    # the result says so instead of passing the plan off as one that holds.
    assert result.stats.execution_room is not None and result.stats.execution_room < 1.0
    assert stl.SolveResult.from_dict(result.to_dict()).stats.execution_room == result.stats.execution_room
