"""``budget_exhausted`` names the budget that decided and what to raise, with a value to try."""

from __future__ import annotations

import numpy as np
import pytest

import idstlpy as stl


def _line(n_goal: float, lit: bool = False) -> stl.Problem:
    x = stl.mk_variable(1, float)
    u = stl.mk_variable(1, float)
    if lit:
        mode = stl.mk_lbs(
            A=[[1.0]], B=[[1.0]], W=[[0.0]], C=[[1.0]], V=lambda s: np.array([[0.1 + 0.1 * s[0] ** 2]])
        )
    else:
        mode = stl.mk_lbs(A=[[1.0]], B=[[1.0]], W=[[0.0]])
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.zeros(1), cov=0.01 * np.eye(1)),
        stl_formula=stl.eventually(
            0,
            20,
            stl.logical_and(
                stl.prob(x[0] >= n_goal) >= 0.9, stl.prob(x[0] <= n_goal + 1) >= 0.9, name="goal"
            ),
        ),
    )


def test_max_candidates_names_the_option_and_a_value():
    result = _line(10.0).solve_result(max_candidates=1, lazy_candidates=5, seed=0)
    assert result.status == "budget_exhausted"
    assert "raise max_candidates (it was 1; try 4)" in result.reason


def test_max_plan_length_names_the_option_and_a_value_within_the_horizon():
    result = _line(10.0).solve_result(max_plan_length=5, seed=0)
    assert result.status == "budget_exhausted", result.reason
    assert "raise max_plan_length (it was 5; try 20)" in result.reason


def test_sampler_budget_names_sampler_iterations():
    from idstlpy.scenarios import light_dark

    result = light_dark().solve_result(sampler_iterations=1, max_candidates=4, seed=0)
    assert result.status == "budget_exhausted", result.reason
    assert result.stats.abandoned >= 1
    assert "raise sampler_iterations (try 4)" in result.reason


def test_no_advice_when_the_answer_is_a_proof_or_a_plan():
    found = _line(3.0).solve_result(seed=0)
    assert found.status == "found"
    assert "to search further" not in found.reason
    x = stl.mk_variable(1, float)
    out_of_reach = _line(30.0).solve_result(seed=0)  # 30 steps needed, horizon 20: a proof
    assert out_of_reach.status == "infeasible"
    assert "to search further" not in out_of_reach.reason
    assert x.size == 1


@pytest.mark.parametrize("limit", [1e-6])
def test_time_limit_names_time_limit(limit):
    result = _line(10.0, lit=True).solve_result(time_limit=limit, seed=0)
    assert result.status == "budget_exhausted"
    assert "raise time_limit" in result.reason


def test_budget_exhausted_carries_the_closest_partial_plan(tmp_path):
    from idstlpy.scenarios import light_dark

    problem = light_dark()
    result = problem.solve_result(sampler_iterations=20, max_candidates=3, seed=0)
    assert result.status == "budget_exhausted", result.reason
    closest = result.closest
    assert isinstance(closest, stl.ProbabilisticTSTrajectory)
    assert closest.num_of_steps >= 1
    # It is what the search got to, not a plan: the formula does not hold on it.
    assert not stl.satisfies(closest, problem.stl_formula)
    # Re-rolled and judged by the independent oracles (tests/oracles), not the planner's code.
    from oracles.brute_force import sat
    from oracles.rollout import ModeSpec, mlo_rollout

    mode = problem.switched_system.mode(0)
    spec = ModeSpec(mode.A, mode.B, mode.W, mode.C, mode.noise)
    mean0, cov0 = problem.initial_state.mean, problem.initial_state.cov
    trace = mlo_rollout([spec], mean0, cov0, closest.get_action(), closest.get_control())
    np.testing.assert_allclose([m for m, _ in trace.states], closest.get_mean(), atol=1e-9)
    assert not sat(problem.stl_formula, 0, trace)
    assert stl.load_result(result.save(tmp_path / "r.json")) == result
    assert result.plan is None


def test_found_results_carry_no_closest():
    assert _line(3.0).solve_result(seed=0).closest is None


def test_the_closest_partial_plan_is_plottable():
    import matplotlib

    matplotlib.use("Agg")
    from idstlpy.plotting import plot_workspace
    from idstlpy.scenarios import light_dark

    problem = light_dark()
    result = problem.solve_result(sampler_iterations=20, max_candidates=3, seed=0)
    artists = plot_workspace(problem, plan=result.closest)
    assert artists is not None


def test_a_floorless_state_dependent_sensor_is_named_and_v_floor_turns_it_into_a_proof():
    """A new user's impossible task (a sensor never better than 0.5) searched to the cap; the
    reason now says which modes lack ``V_floor``, and declaring it proves ``infeasible``."""
    import numpy as np

    import idstlpy as stl
    from idstlpy.synthesis.advice import floorless_modes

    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float)

    def problem(floor: float | None) -> stl.Problem:
        mode = stl.mk_lbs(
            A=np.eye(1),
            B=np.eye(1),
            W=0.1 * np.eye(1),
            C=np.eye(1),
            V=lambda s: (0.5 + 0.2 * abs(float(s[0]) - 3)) * np.eye(1),
            V_floor=floor,
        )
        goal = stl.logical_and(stl.prob(x[0] >= 0.95) >= 0.99, stl.prob(x[0] <= 1.05) >= 0.99, name="tight")
        return stl.Problem(
            switched_system=stl.mk_switched_sys([mode]),
            control_domain=stl.logical_and(u[0] >= -1, u[0] <= 1).region,
            initial_state=stl.to_belief(mean=np.zeros(1), cov=np.eye(1)),
            stl_formula=stl.eventually(0, 20, goal),
        )

    bare = problem(None)
    assert floorless_modes(bare.switched_system) == [0]
    r = bare.solve_result(max_candidates=3, seed=0)
    assert r.status == "budget_exhausted"
    assert "mode(s) [0] have state-dependent sensor noise without V_floor" in r.reason
    floored = problem(0.5)
    assert floorless_modes(floored.switched_system) == []
    assert floored.solve_result(max_candidates=3, seed=0).status == "infeasible"


def test_closest_is_a_partial_plan_when_every_candidate_was_refuted():
    """No teacher reported a closest plan (the plan LP refuted every candidate): the longest
    feasible prefix of the candidate refuted deepest is shown, and the statistics stay the
    search's own."""
    problem = _line(10.0)
    result = problem.solve_result(max_candidates=2, lazy_candidates=5, seed=0)
    assert result.status == "budget_exhausted" and result.stats.refuted == result.stats.candidates == 2
    closest = result.closest
    assert isinstance(closest, stl.ProbabilisticTSTrajectory) and closest.num_of_steps >= 1
    assert not stl.satisfies(closest, problem.stl_formula)
    assert np.all(np.abs(closest.get_control()) <= 1.0 + 1e-9)  # inside the control domain
    assert result.stats.lp_calls <= 3 * result.stats.candidates + 3


def test_the_candidates_advice_counts_what_settles_the_current_length():
    """max_candidates stopped the search with few candidates of the current length left: the
    advice counts them (each set aside: a refutation excludes at least as much), and the value
    it suggests settles that length: the re-run finds a plan or moves past it."""
    import re

    x, u = stl.mk_variable(1, float), stl.mk_variable(1, float, name="u")
    problem = stl.Problem(
        stl.mk_switched_sys([stl.mk_lbs(A=[[1.0]], B=[[1.0]], W=[[0.0]])]),
        stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        stl.to_belief(np.zeros(1), 0.01 * np.eye(1)),
        stl.eventually(
            0, 40, stl.logical_and(stl.prob(x[0] >= 10.0) >= 0.9, stl.prob(x[0] <= 11.0) >= 0.9, name="goal")
        ),
    )
    first = problem.solve_result(seed=0, max_candidates=8, lazy_candidates=100)
    assert first.status == "budget_exhausted"
    got = re.search(r"try (\d+): at most (\d+) candidates of at most (\d+) steps were left", first.reason)
    assert got is not None, first.reason
    value, left, steps = (int(g) for g in got.groups())
    assert value == 8 + left
    assert first.stats.bmc_depth <= steps  # the count's proposals are not in the statistics
    again = problem.solve_result(seed=0, max_candidates=value, lazy_candidates=100)
    assert again.status == "found" or again.stats.bmc_depth > steps
    if again.status == "found":
        assert stl.satisfies(again.plan, problem.stl_formula)
