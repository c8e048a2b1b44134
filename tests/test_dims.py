"""Planning in more dimensions (issue 24): independent robots split into blocks and composed."""

from __future__ import annotations

import numpy as np
import pytest
from benchmarks.dims_family import ROBOTS, TARGET_HALF, RobotsLight, build, check_instance, lazy_plan, witness

import idstlpy as stl
from idstlpy.synthesis import decoupled

BUDGET = {"sampler_iterations": 3000, "max_candidates": 20, "time_limit": 60}


@pytest.mark.parametrize("k", [1, 2, 3])
def test_instances_have_a_witness_and_a_lazy_plan_fails(k):
    checks = check_instance(k)
    assert checks["witness"][0] and checks["witness"][1] > 0
    assert not checks["lazy"][0]
    # independent of the package's monitor too: the witness's own roll-out, read by hand
    problem = build(k)
    traj = stl.rollout(problem.switched_system, problem.initial_state, *witness(k))
    cov = np.array([traj.get_cov(j) for j in range(traj.num_of_steps + 1)])
    assert np.allclose(cov[:, :2, 2:], 0.0) if k > 1 else True  # the blocks never couple
    assert lazy_plan(k)[1].shape[1] == 2 * k


def test_noise_is_block_diagonal_and_takes_batches():
    noise = RobotsLight(3)
    x = np.array([1.0, 2.0, 4.0, 0.0, 5.0, 3.0])
    n = noise(x)
    assert np.allclose(n, np.diag(np.repeat(0.1 * (5 - x[0::2]) ** 2 + 0.001, 2)))
    batch = noise(np.stack([x, x + 1]))
    assert batch.shape == (2, 6, 6) and np.allclose(batch[0], n)


def test_split_finds_the_robots():
    blocks = decoupled.split(build(3))
    assert blocks is not None and len(blocks) == 3
    for i, b in enumerate(blocks):
        assert b.states.tolist() == [2 * i, 2 * i + 1] == b.inputs.tolist() == b.outputs.tolist()
        assert len(b.conjuncts) == 1 and b.rows.size == 4


def _two_robots(noise, formula_kind="conjunction"):
    x = stl.mk_variable(size=4, dtype=float)
    u = stl.mk_variable(size=4, dtype=float, name="u")
    bounds = []
    for j in range(4):
        bounds += [u[j] >= -1, u[j] <= 1]

    def box(i, lo, hi, conf, name):
        return stl.logical_and(
            stl.prob(x[2 * i] >= lo[0]) >= conf,
            stl.prob(x[2 * i] <= hi[0]) >= conf,
            stl.prob(x[2 * i + 1] >= lo[1]) >= conf,
            stl.prob(x[2 * i + 1] <= hi[1]) >= conf,
            name=name,
        )

    goal0 = stl.eventually(0, 30, box(0, (-0.5, -0.5), (0.5, 0.5), 0.9, "g0"))
    goal1 = stl.eventually(0, 30, box(1, (0.5, 2.5), (1.5, 3.5), 0.9, "g1"))
    if formula_kind == "conjunction":
        formula = stl.logical_and(goal0, goal1)
    elif formula_kind == "one":
        formula = goal0
    elif formula_kind == "sum":  # one chance constraint over both robots
        formula = stl.logical_and(
            goal0, stl.eventually(0, 30, stl.logical_and(stl.prob(x[0] + x[2] <= 3) >= 0.9))
        )
    else:  # one proposition over both robots
        both = stl.logical_and(
            *box(0, (-0.5, -0.5), (0.5, 0.5), 0.9, "a").predicates,
            *box(1, (0.5, 2.5), (1.5, 3.5), 0.9, "b").predicates,
            name="both",
        )
        formula = stl.eventually(0, 30, both)
    system = stl.mk_switched_sys(
        [stl.mk_lbs(A=np.eye(4), B=0.25 * np.eye(4), W=np.zeros((4, 4)), C=np.eye(4), V=noise)]
    )
    prior = stl.to_belief(mean=np.array([0.0, 2.0, 1.0, 0.0]), cov=0.01 * np.eye(4))
    return stl.Problem(system, stl.logical_and(*bounds).region, prior, formula)


def _coupled_noise(x):
    # robot 1's sensor depends on robot 0's position: one block
    f = 0.05 + 0.01 * (x[0] - 1.0) ** 2
    return f * np.eye(4)


def test_split_refuses_coupled_sensing_and_joint_propositions():
    assert decoupled.split(_two_robots(_coupled_noise)) is None
    # a proposition over both robots is projected (one conjunct for both blocks) ...
    team = decoupled.split(_two_robots(RobotsLight(2, a=0.01, b=0.05), "joint"))
    assert team is not None and [len(b.conjuncts) for b in team] == [1, 1]
    # ... but one chance constraint over both robots ties them
    assert decoupled.split(_two_robots(RobotsLight(2, a=0.01, b=0.05), "sum")) is None
    blocks = decoupled.split(_two_robots(RobotsLight(2, a=0.01, b=0.05)))
    assert blocks is not None and len(blocks) == 2


def test_a_free_block_gets_steady_inputs():
    problem = _two_robots(RobotsLight(2, a=0.01, b=0.05), "one")
    blocks = decoupled.split(problem)
    assert blocks is not None and [len(b.conjuncts) for b in blocks] == [1, 0]
    # the paper's tracking weights: with the fitted ones (the default since issue 34) the free
    # robot's input moves off the centre by 1/32 at one step; not yet explained (closing note)
    result = problem.solve_result(seed=3, **BUDGET, tracking="paper")
    assert result.status == "found" and "independent blocks" in result.reason
    controls = result.trajectory.get_control()
    assert np.allclose(controls[:, 2:], 0.0)  # the free robot's domain centre
    assert stl.satisfies(result.trajectory, problem.stl_formula)


def _solve(k, seed, **more):
    problem = build(k)
    return problem, problem.solve_result(seed=seed, **BUDGET, **more)


def test_six_dimensions_solved_and_verified():
    problem, result = _solve(3, seed=7)
    assert result.status == "found", result.reason
    assert "3 independent blocks" in result.reason and not result.stats.caps_hit
    traj = result.trajectory
    # the monitor, and an independent roll-out of the plan's modes and inputs
    assert stl.satisfies(traj, problem.stl_formula)
    again = stl.rollout(problem.switched_system, problem.initial_state, traj.get_action(), traj.get_control())
    assert stl.satisfies(again, problem.stl_formula)
    assert stl.robustness(again, problem.stl_formula) >= 0
    assert np.all(np.abs(traj.get_control()) <= 1 + 1e-9)
    # every robot looked: its covariance fell well below the prior's before it held its target
    final = again.get_cov(again.num_of_steps)
    assert np.all(np.diag(final) < 0.01)
    assert result.stats.candidates <= 20 and result.stats.execution_room is not None
    assert result.execution is not None and result.execution.meets_target


def test_same_seed_same_plan():
    _, first = _solve(2, seed=5)
    _, second = _solve(2, seed=5)
    assert first.status == second.status == "found"
    assert np.array_equal(first.trajectory.get_control(), second.trajectory.get_control())
    assert np.array_equal(first.trajectory.get_action(), second.trajectory.get_action())
    assert first.stats.candidates == second.stats.candidates
    assert first.stats.sampler_iterations == second.stats.sampler_iterations


def test_four_dimensions_solved_and_joint_search_still_available(monkeypatch):
    problem, result = _solve(2, seed=1)
    assert result.status == "found" and "2 independent blocks" in result.reason
    assert stl.satisfies(result.trajectory, problem.stl_formula)
    # switched off, the same problem goes to the joint search (which may or may not find it)
    monkeypatch.setattr(decoupled, "ENABLED", False)
    small = _two_robots(RobotsLight(2, a=0.01, b=0.05))
    joint = small.solve_result(seed=0, **BUDGET)
    assert "independent blocks" not in joint.reason
    if joint.status == "found":
        assert stl.satisfies(joint.trajectory, small.stl_formula)


def test_team_formula_is_projected_and_composed_with_holds():
    problem = build(2, form="all")
    blocks = decoupled.split(problem)
    assert blocks is not None and len(blocks) == 2
    result = problem.solve_result(seed=2, **BUDGET)
    assert result.status == "found", result.reason
    assert "projections, composed with holds" in result.reason
    traj = result.trajectory
    again = stl.rollout(problem.switched_system, problem.initial_state, traj.get_action(), traj.get_control())
    assert stl.satisfies(again, problem.stl_formula)
    # the team holds its targets together for the last 41 steps
    centres = np.concatenate([np.asarray(c) for _, c in ROBOTS[:2]])
    tail = np.array([again.get_mean(j) for j in range(again.num_of_steps - 40, again.num_of_steps + 1)])
    assert np.all(np.abs(tail - centres) <= TARGET_HALF)
    assert result.stats.execution_room is not None
    # the default guarantee: the composed plan's predicted execution meets the target
    assert result.execution is not None and result.execution.meets_target


def test_a_composed_plan_that_fails_the_final_check_goes_to_the_joint_search(monkeypatch, caplog):
    # break the composition on purpose: the padding input leaves the control domain
    monkeypatch.setattr(
        decoupled, "_hold_input", lambda mode, dom, block, mean: np.full(block.inputs.size, 5.0)
    )
    problem = _two_robots(RobotsLight(2, a=0.01, b=0.05), "one")
    with caplog.at_level("INFO", logger="idstlpy.synthesis.pipeline"):
        result = problem.solve_result(seed=3, **BUDGET)
    assert "independent blocks" not in result.reason
    assert any("composed plan failed the final check" in r.getMessage() for r in caplog.records)
    if result.status == "found":
        assert stl.satisfies(result.trajectory, problem.stl_formula)
        assert np.all(np.abs(result.trajectory.get_control()) <= 1 + 1e-6)


def test_team_instances_have_a_witness_and_a_lazy_plan_fails():
    for k in (2, 3):
        checks = check_instance(k, form="all")
        assert checks["witness"][0] and not checks["lazy"][0]


def test_a_block_no_sensor_reads_is_solved_as_a_blind_block():
    """Two decoupled coordinates, a state-dependent sensor reading only the first: the second
    block has no sensor row and is a blind sub-system (was a DimensionError: empty C)."""
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    mode = stl.mk_lbs(
        A=np.eye(2),
        B=np.eye(2),
        W=0.01 * np.eye(2),
        C=np.array([[1.0, 0.0]]),
        V=lambda s: np.array([[0.1 + 0.01 * float(np.asarray(s)[..., 0].mean()) ** 2]]),
    )
    near = stl.logical_and(stl.prob(x[0] >= 1.0) >= 0.9, stl.prob(x[1] >= 1.0) >= 0.9, name="near")
    problem = stl.Problem(
        stl.mk_switched_sys([mode]),
        stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region,
        stl.to_belief(np.zeros(2), 0.01 * np.eye(2)),
        stl.eventually(0, 6, near),
    )
    blocks = decoupled.split(problem)
    assert blocks is not None and any(b.outputs.size == 0 for b in blocks)
    result = problem.solve_result(seed=0, guarantee="mlo")
    assert result.status == "found", result.reason
    assert stl.satisfies(result.trajectory, problem.stl_formula)
