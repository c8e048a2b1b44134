"""Problem.solve: plans are verified, impossibilities are proved fast, bad input is refused."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import idstlpy as stl
from idstlpy.scenarios import double_integrator, light_dark, reach_avoid

LISTING = dict(
    rrt_timeout=60,
    delta_near=2,
    delta_drain=0.5,
    goal_bias=0.25,
    min_num_of_steps=3,
    max_num_of_steps=15,
)


def P(pred, level=0.99):
    return stl.prob(pred) >= level


@pytest.fixture(scope="module")
def light_dark_result():
    problem = light_dark()
    return problem, problem.solve_result(**LISTING, seed=0)


def test_light_dark_plan_takes_the_detour_and_verifies(light_dark_result):
    problem, result = light_dark_result
    assert result.status == "found"
    plan = result.trajectory
    assert stl.satisfies(plan, problem.stl_formula)
    assert result.margin >= 0
    # Active perception: the plan goes toward the light (x_1 ~ 3-5) before holding the target.
    assert plan.get_mean()[:, 0].max() > 2.5
    final = plan.get_mean(-1)
    assert np.all(np.abs(final) <= 0.25)
    assert np.trace(plan.get_cov(-1)) < np.trace(plan.get_cov(0)) / 5


@pytest.mark.parametrize("seed", [1, 5, 8])
def test_light_dark_plans_keep_room_for_execution_noise(seed):
    # Unpolished, these seeds' plans grazed the target (margins 0.003, 0.0016, 0.0001) and held
    # under execution noise in 84%, 60% and 0.5% of runs; the polished ones keep > 0.05.
    problem = light_dark()
    result = problem.solve_result(**LISTING, seed=seed)
    assert result.status == "found"
    assert result.margin == pytest.approx(stl.robustness(result.trajectory, problem.stl_formula))
    assert result.margin > 0.05


def test_anchored_plan_lp_moves_means_at_most_trust():
    from idstlpy.synthesis.abstraction import Abstraction
    from idstlpy.synthesis.plan import DiscretePlan
    from idstlpy.synthesis.plan_lp import PlanLPContext
    from idstlpy.synthesis.plan_solve import TrustRegion, solve_plan_lp

    problem = light_dark()
    plan = problem.solve(**LISTING, seed=0)
    abstraction = Abstraction(problem.stl_formula, problem.switched_system.n)
    L = plan.num_of_steps + 1
    required = np.zeros((abstraction.num_atoms, L), dtype=bool)
    target = [i for i, a in enumerate(abstraction.atoms) if a.name == "target"][0]
    required[target, -1] = True
    modes = np.concatenate([[-1], plan.get_action()]).astype(int)
    context = PlanLPContext.of(problem, abstraction)
    free = solve_plan_lp(context, DiscretePlan(required, modes, L), 1.0, covs=plan.get_cov())
    anchored = solve_plan_lp(
        context,
        DiscretePlan(required, modes, L),
        1.0,
        covs=plan.get_cov(),
        region=TrustRegion(plan.get_mean(), 0.01),
    )
    assert free.feasible and anchored.feasible and not anchored.exact
    assert np.abs(anchored.means - plan.get_mean()).max() <= 0.01 + 1e-7
    assert np.abs(free.means - plan.get_mean()).max() > 0.01


def test_light_dark_plan_is_the_exact_belief_rollout(light_dark_result):
    problem, result = light_dark_result
    plan = result.trajectory
    again = stl.rollout(problem.switched_system, problem.initial_state, plan.get_action(), plan.get_control())
    np.testing.assert_allclose(again.get_mean(), plan.get_mean())
    np.testing.assert_allclose(again.get_cov(), plan.get_cov())
    dom = problem.control_domain
    assert np.all(plan.get_control() @ dom.H.T + dom.c <= 1e-9)


def test_same_seed_same_plan(light_dark_result):
    problem, result = light_dark_result
    again = light_dark().solve(**LISTING, seed=0)
    np.testing.assert_array_equal(again.get_control(), result.trajectory.get_control())


def test_stats_describe_the_run(light_dark_result):
    _, result = light_dark_result
    s = result.stats
    assert s.candidates >= 1 and s.nodes > 0 and s.sat_calls >= 1 and s.lp_calls >= 1
    assert s.time_total >= s.time_sampling > 0


@pytest.mark.parametrize("T", [25, 60])
def test_noise_free_reach_avoid_through_the_lp_path(T):
    problem = reach_avoid(T)
    formula = problem.stl_formula
    result = problem.solve_result(rrt_timeout=5, seed=0)
    assert result.status == "found"
    assert result.stats.nodes == 0  # decided by the LP teacher, no sampling
    assert stl.satisfies(result.trajectory, formula)


def test_logically_unsatisfiable_is_proved_fast():
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    system = stl.mk_switched_sys([stl.mk_lbs(np.eye(2), np.eye(2), np.zeros((2, 2)))])
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    left = stl.logical_and(P(x[0] <= 0), name="left")
    right = stl.logical_and(P(x[0] >= 1), name="right")
    formula = stl.eventually(0, 300, stl.logical_and(stl.always(0, 5, left), stl.always(0, 5, right)))
    problem = stl.Problem(system, domain, stl.to_belief([0, 0], 0.01 * np.eye(2)), formula)
    assert problem.solve(rrt_timeout=60, seed=0) is None
    assert problem.last_result.status == "infeasible"
    # proved by the formula alone: no candidate, no LP, no sampling (the work, not the clock)
    assert problem.last_result.stats.candidates == 0 and problem.last_result.stats.nodes == 0


def test_geometrically_unreachable_is_proved_by_lp_conflicts():
    x = stl.mk_variable(1)
    u = stl.mk_variable(1, name="u")
    system = stl.mk_switched_sys([stl.mk_lbs([[1.0]], [[1.0]], [[0.0]])])
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1).region
    far = stl.logical_and(P(x[0] >= 50), name="far")
    problem = stl.Problem(system, domain, stl.to_belief([0], [[0.0]]), stl.eventually(0, 20, far))
    result = problem.solve_result(rrt_timeout=60, seed=0)
    assert result.status == "infeasible"
    assert result.stats.counterexamples >= 1
    assert result.stats.nodes == 0  # proved by LP conflicts, no sampling


def test_initial_belief_outside_the_required_region_is_none_with_reason():
    x = stl.mk_variable(1)
    u = stl.mk_variable(1, name="u")
    system = stl.mk_switched_sys([stl.mk_lbs([[1.0]], [[1.0]], [[0.0]])])
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1).region
    safe = stl.logical_and(P(x[0] <= 1), name="safe")
    problem = stl.Problem(system, domain, stl.to_belief([3.0], [[0.01]]), stl.always(0, 5, safe))
    assert problem.solve(rrt_timeout=5, seed=0) is None
    assert problem.last_result.status == "infeasible"
    assert "initial" in problem.last_result.reason


def test_switched_modes_sense_before_acting():
    """A slow mode that senses and a fast blind mode: the plan must sense to reach 95% confidence."""
    x = stl.mk_variable(1)
    u = stl.mk_variable(1, name="u")
    q = stl.mk_variable(2, dtype=int)
    slow_sense = stl.mk_lbs([[1.0]], [[0.2]], [[0.05]], C=[[1.0]], V=[[0.05]])
    fast_blind = stl.mk_lbs([[1.0]], [[1.0]], [[0.05]])
    system = stl.mk_switched_sys([slow_sense, fast_blind])
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1).region
    goal = stl.logical_and(P(x[0] >= 4.8, 0.95), P(x[0] <= 5.2, 0.95), name="goal")
    formula = stl.eventually(0, 12, goal)
    problem = stl.Problem(system, domain, stl.to_belief([0.0], [[1.0]]), formula)
    result = problem.solve_result(rrt_timeout=5, seed=0)
    assert result.status == "found"
    plan = result.trajectory
    assert stl.satisfies(plan, formula)
    assert 0 in plan.get_action()  # it had to sense
    assert 1 in plan.get_action()  # and it needed the fast mode to get there in time
    # A formula over modes: the last step must be taken in the sensing mode.
    formula2 = stl.eventually(0, 12, stl.logical_and(q == 0, P(x[0] >= 4.8, 0.95), P(x[0] <= 5.2, 0.95)))
    plan2 = stl.Problem(system, domain, stl.to_belief([0.0], [[1.0]]), formula2).solve(rrt_timeout=5, seed=0)
    assert plan2 is not None and stl.satisfies(plan2, formula2)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(rrt_timeout=0), "rrt_timeout"),
        (dict(goal_bias=1.5), "goal_bias"),
        (dict(min_num_of_steps=5, max_num_of_steps=3), "min_num_of_steps"),
        (dict(min_num_of_steps=0), "min_num_of_steps"),
        (dict(delta_near=-1), "delta_near"),
        (dict(delta_drain=-0.1), "delta_drain"),
    ],
)
def test_bad_solver_parameters(kwargs, match):
    with pytest.raises(stl.InvalidArgumentError, match=match):
        light_dark().solve(**{**LISTING, **kwargs})


def test_problem_parts_must_agree():
    x = stl.mk_variable(3)
    u = stl.mk_variable(2, name="u")
    q = stl.mk_variable(3, dtype=int)
    system = stl.mk_switched_sys([stl.mk_lbs(np.eye(2), np.eye(2), np.zeros((2, 2)))])
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    belief = stl.to_belief([0, 0], np.eye(2))
    with pytest.raises(stl.DimensionError, match="n = 2"):
        stl.Problem(system, domain, belief, stl.eventually(0, 3, P(x[0] <= 1)))
    y = stl.mk_variable(2)
    with pytest.raises(stl.OutOfRangeError, match="mode 2"):
        stl.Problem(system, domain, belief, stl.eventually(0, 3, stl.logical_and(q == 2, P(y[0] <= 1))))
    with pytest.raises(stl.DimensionError, match="control_domain"):
        stl.Problem(system, stl.Polytope.box([-1], [1]), belief, stl.eventually(0, 3, P(y[0] <= 1)))


def test_noise_function_with_wrong_shape_is_named_at_problem_creation():
    u = stl.mk_variable(2, name="u")
    y = stl.mk_variable(2)
    bad = stl.mk_lbs(np.eye(2), np.eye(2), np.zeros((2, 2)), C=np.eye(2), V=lambda s: np.ones(3))
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    with pytest.raises(stl.NoiseFunctionError, match="noise function V"):
        stl.Problem(
            stl.mk_switched_sys([bad]),
            domain,
            stl.to_belief([0, 0], np.eye(2)),
            stl.eventually(0, 3, P(y[0] <= 1)),
        )


def test_time_budget_is_respected():
    """A tiny cap ends the search with the cap named (its overshoot: benchmarks/time_limits.py)."""
    problem = light_dark()
    result = problem.solve_result(**{**LISTING, "rrt_timeout": 0.02}, seed=3, time_limit=0.05)
    assert result.status in ("found", "budget_exhausted")
    if result.status == "budget_exhausted":
        assert "time_limit" in result.stats.caps_hit, result.stats.caps_hit


# -- fuzz: every generated problem ends in a verified plan or None --------------------------------


@st.composite
def random_problems(draw):
    n = draw(st.integers(1, 2))
    x = stl.mk_variable(n)
    noisy = draw(st.sampled_from(["none", "const", "state"]))
    W = draw(st.sampled_from([0.0, 0.05])) * np.eye(n)
    if noisy == "none":
        mode = stl.mk_lbs(np.eye(n), np.eye(n), W)
    elif noisy == "const":
        mode = stl.mk_lbs(np.eye(n), np.eye(n), W, C=np.eye(n), V=0.1 * np.eye(n))
    else:
        mode = stl.mk_lbs(
            np.eye(n),
            np.eye(n),
            W,
            C=np.eye(n),
            V=lambda s: (0.05 + 0.1 * abs(s[0])) * np.eye(len(s)),
        )
    system = stl.mk_switched_sys([mode])
    domain = stl.Polytope.box(-np.ones(n), np.ones(n))

    def box(name):
        lo = np.array([draw(st.floats(-4, 3)) for _ in range(n)])
        hi = lo + np.array([draw(st.floats(0.2, 3)) for _ in range(n)])
        level = draw(st.sampled_from([0.5, 0.9, 0.99]))
        preds = [P(x[i] >= lo[i], level) for i in range(n)] + [P(x[i] <= hi[i], level) for i in range(n)]
        return stl.logical_and(*preds, name=name)

    a, b = box("a"), box("b")
    T = draw(st.integers(1, 8))
    kind = draw(st.sampled_from(["F", "G", "U", "FG", "and", "or"]))
    if kind == "F":
        f = stl.eventually(0, T, a)
    elif kind == "G":
        f = stl.always(0, T, a)
    elif kind == "U":
        f = stl.until(a, 0, T, b)
    elif kind == "FG":
        f = stl.eventually(0, T, stl.always(0, 2, a))
    elif kind == "and":
        f = stl.logical_and(stl.eventually(0, T, a), stl.eventually(0, T, b))
    else:
        f = stl.logical_or(stl.always(0, T, a), stl.eventually(1, T, b))
    mean = np.array([draw(st.floats(-2, 2)) for _ in range(n)])
    return stl.Problem(system, domain, stl.to_belief(mean, 0.05 * np.eye(n)), f)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(random_problems(), st.integers(0, 1000))
def test_fuzz_verified_plan_or_none(problem, seed):
    result = problem.solve_result(rrt_timeout=0.3, seed=seed, time_limit=1.0)
    if result.trajectory is not None:
        assert result.status == "found"
        assert stl.satisfies(result.trajectory, problem.stl_formula)
    else:
        assert result.status in ("infeasible", "budget_exhausted")


def _reach_avoid_in_a_box(T, goal_low=(7.0, 8.0)):
    x, system, domain = double_integrator()
    avoid = stl.logical_or(P(x[0] <= 3), P(x[0] >= 5), P(x[1] <= 4), P(x[1] >= 6))
    goal = stl.logical_and(
        P(x[0] >= goal_low[0]),
        P(x[0] <= goal_low[0] + 1),
        P(x[1] >= goal_low[1]),
        P(x[1] <= goal_low[1] + 1),
        name="goal",
    )
    box = stl.logical_and(
        P(x[0] >= 0),
        P(x[0] <= 10),
        P(x[1] >= 0),
        P(x[1] <= 10),
        P(x[2] >= -1),
        P(x[2] <= 1),
        P(x[3] >= -1),
        P(x[3] <= 1),
        name="box",
    )
    formula = stl.logical_and(stl.always(0, T, avoid), stl.eventually(0, T, goal), stl.always(0, T, box))
    return stl.Problem(system, domain, stl.to_belief([1, 2, 0, 0], np.zeros((4, 4))), formula)


def test_eager_milp_path_plans_and_proves():
    problem = _reach_avoid_in_a_box(25)
    result = problem.solve_result(rrt_timeout=10, seed=0, lazy_candidates=0)
    assert result.status == "found" and "MILP" in result.reason
    assert result.stats.milp_calls >= 1
    assert stl.satisfies(result.trajectory, problem.stl_formula)
    # Too far for 6 steps at |u| <= 0.5, |v| <= 1: a proof, not a time-out.
    far = _reach_avoid_in_a_box(6)
    result = far.solve_result(rrt_timeout=10, seed=0, lazy_candidates=0)
    assert result.status == "infeasible"
