"""Chance switching (issue 35): the model's validation, execution with jumps, and the sound bound
against an exact enumeration of every executed mode sequence (tests/oracles/markov.py)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from oracles.markov import Mode, all_sequences, exact_always_probability, monte_carlo_always

import idstlpy as stl
from idstlpy.errors import DimensionError, ExecutionTargetWarning, InvalidArgumentError, InvalidTypeError
from idstlpy.executor.jump_online import JumpExecutor
from idstlpy.executor.markov_bound import sequences_by_probability
from idstlpy.markov import switching_of

# --------------------------------------------------------------------------------------------
# A small family: nominal, failed actuator (weak B), camera dropout (no sensor); 2-D, constant noise

N_STEPS = 6
B0 = 0.25 * np.eye(2)
MODES = {
    "nominal": Mode(np.eye(2), B0, 0.04 * np.eye(2), np.eye(2), 0.05 * np.eye(2)),
    "failed": Mode(np.eye(2), 0.1 * np.eye(2), 0.04 * np.eye(2), np.eye(2), 0.05 * np.eye(2)),
    "dropout": Mode(np.eye(2), B0, 0.04 * np.eye(2), np.zeros((0, 2)), np.zeros((0, 0))),
}
GAIN = {"nominal": 1.5 * np.eye(2), "failed": 3.0 * np.eye(2), "dropout": 1.5 * np.eye(2)}
H = np.array([[1.0, 0.0], [0.0, 1.0]])
C = np.array([-1.15, -1.15])  # x[0] <= 1.15, x[1] <= 1.15 at every step


def _lbs(md: Mode) -> stl.dynamical_system.LBS:
    if md.C.shape[0]:
        return stl.mk_lbs(md.A, md.B, md.W, md.C, md.V)
    return stl.mk_lbs(md.A, md.B, md.W)


def _setup(names: list[str], P: np.ndarray, steps: int = N_STEPS, observed: bool = True):
    modes = [MODES[nm] for nm in names]
    system = stl.mk_switched_sys([_lbs(md) for md in modes])
    sysm = stl.with_switching(system, stl.mk_markov_switching(P, observed=observed))
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    ap = stl.logical_and(stl.prob(x[0] <= 1.15) >= 0.9, stl.prob(x[1] <= 1.15) >= 0.9, name="safe")
    formula = stl.always(0, steps, ap)
    domain = stl.logical_and(u[0] >= -10, u[0] <= 10, u[1] >= -10, u[1] <= 10).region
    prior = stl.to_belief(np.zeros(2), 0.01 * np.eye(2))
    problem = stl.Problem(sysm, domain, prior, formula)
    controls = np.full((steps, 2), 0.5)
    plan = stl.rollout(system, prior, np.zeros(steps, dtype=int), controls)
    K = [GAIN[nm] for nm in names]
    gains = {j: [K[j]] for j in range(len(names))}
    return problem, plan, modes, K, gains


def _exact(problem, plan, modes, K, P, start_cov=None):
    return exact_always_probability(
        modes,
        K,
        plan.get_mean(),
        plan.get_control(),
        P,
        plan.get_action().tolist(),
        plan.get_mean(0),
        np.zeros((2, 2)) if start_cov is None else start_cov,
        plan.get_cov(0),
        H,
        C,
        list(range(plan.num_of_steps + 1)),
    )


P_FAIL_DROP = np.array(
    [
        # commanded nominal: fail with 5% (persistent), drop a frame with 20% (not persistent)
        [[0.75, 0.05, 0.20], [0.0, 1.0, 0.0], [0.75, 0.05, 0.20]],
        [[0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
        [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    ]
)


# --------------------------------------------------------------------------------------------
# The model


@pytest.mark.parametrize(
    ("P", "error", "words"),
    [
        (
            [[[0.5, 0.6], [0.0, 1.0]], [[0.0, 1.0], [0.0, 1.0]]],
            InvalidArgumentError,
            "transitions[0, 0, :] sums",
        ),
        ([[[1.2, -0.2], [0.0, 1.0]], [[0.0, 1.0], [0.0, 1.0]]], InvalidArgumentError, "transitions[0, 0, 0]"),
        ([[[np.nan, 1.0], [0.0, 1.0]], [[0.0, 1.0], [0.0, 1.0]]], InvalidArgumentError, "NaN"),
        (np.ones((2, 3, 3)) / 3, DimensionError, "num_commanded = num_modes"),
        (np.ones((2, 2, 3)) / 3, DimensionError, "shape"),
        ([1.0, 0.0], DimensionError, "shape"),
        ("abc", InvalidTypeError, "transitions must be a numeric array"),
    ],
)
def test_bad_transition_matrices_are_refused_naming_the_row(P, error, words):
    with pytest.raises(error, match=None) as info:
        stl.mk_markov_switching(P)
    assert words in str(info.value)


def test_bad_initial_observed_and_mode_count_are_refused():
    P = np.eye(2)
    with pytest.raises(InvalidArgumentError, match="initial sums"):
        stl.mk_markov_switching(P, initial=[0.5, 0.4])
    with pytest.raises(DimensionError, match="initial must have shape"):
        stl.mk_markov_switching(P, initial=[1.0])
    with pytest.raises(InvalidTypeError, match="observed"):
        stl.mk_markov_switching(P, observed="yes")
    system = stl.mk_switched_sys([_lbs(MODES["nominal"])])
    with pytest.raises(DimensionError, match="switching has 2 modes, the system has 1"):
        stl.with_switching(system, stl.mk_markov_switching(P))
    with pytest.raises(InvalidTypeError, match="mk_markov_switching"):
        stl.with_switching(system, P)


def test_a_square_matrix_is_the_same_for_every_command_and_rows_are_read_only():
    sw = stl.mk_markov_switching([[0.9, 0.1], [0.3, 0.7]])
    assert sw.transitions.shape == (2, 2, 2)
    np.testing.assert_array_equal(sw.transitions[0], sw.transitions[1])
    with pytest.raises(ValueError):
        sw.transitions[0, 0, 0] = 1.0


def test_with_switching_leaves_the_system_without_jumps():
    system = stl.mk_switched_sys([_lbs(MODES["nominal"]), _lbs(MODES["failed"])])
    sysm = stl.with_switching(system, stl.mk_markov_switching(np.eye(2)))
    assert switching_of(system) is None
    assert switching_of(sysm) is not None
    assert sysm.system_modes is system.system_modes


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    M=st.integers(2, 3),
    N=st.integers(1, 5),
    sparse=st.booleans(),
)
def test_best_first_enumeration_is_every_sequence_in_order(seed, M, N, sparse):
    rng = np.random.default_rng(seed)
    P = rng.dirichlet(np.ones(M), size=(M, M))
    if sparse:  # zero entries (persistent modes), rows renormalised
        P = np.where(rng.random(P.shape) < 0.3, 0.0, P)
        P[..., 0] += P.sum(axis=2) == 0
        P = P / P.sum(axis=2, keepdims=True)
    sw = stl.mk_markov_switching(P)
    commanded = rng.integers(0, M, N).tolist()
    truth = all_sequences(np.asarray(sw.transitions), commanded)
    got = list(sequences_by_probability(sw, commanded))
    assert {s for s, _ in got} == set(truth)
    for s, p in got:
        assert math.isclose(p, truth[s], rel_tol=1e-12, abs_tol=1e-300)
        assert math.isclose(sw.sequence_probability(commanded, s), truth[s], rel_tol=1e-12)
    probs = [p for _, p in got]
    assert all(a >= b * (1 - 1e-12) for a, b in zip(probs, probs[1:], strict=False))
    assert math.isclose(sum(probs), 1.0, rel_tol=1e-9)


def test_drawn_sequences_follow_the_chain():
    sw = stl.mk_markov_switching(P_FAIL_DROP)
    commanded = [0, 0, 0, 0]
    draws = sw.draw(commanded, np.random.default_rng(5), runs=40_000)
    truth = all_sequences(P_FAIL_DROP, commanded)
    keys, counts = np.unique(draws, axis=0, return_counts=True)
    freq = {tuple(k.tolist()): c / draws.shape[0] for k, c in zip(keys, counts, strict=True)}
    assert set(freq) <= set(truth)
    for s, p in truth.items():
        assert abs(freq.get(s, 0.0) - p) <= 5 * math.sqrt(p * (1 - p) / draws.shape[0]) + 1e-4


# --------------------------------------------------------------------------------------------
# The bound against the exact enumeration


@pytest.mark.parametrize(
    ("names", "P", "steps"),
    [
        (["nominal", "failed", "dropout"], P_FAIL_DROP, 4),
        (["nominal", "failed"], np.array([[[0.9, 0.1], [0.0, 1.0]], [[0.0, 1.0], [0.0, 1.0]]]), 6),
        (["nominal", "dropout"], np.array([[[0.7, 0.3], [0.7, 0.3]], [[0.0, 1.0], [0.0, 1.0]]]), 6),
    ],
)
def test_bound_against_exact_enumeration_of_every_sequence(names, P, steps):
    problem, plan, modes, K, gains = _setup(names, P, steps)
    exact = _exact(problem, plan, modes, K, P)
    b = stl.markov_bound(
        problem, plan, control_domain=None, lqr_gains=gains, samples=2000, max_sequences=10_000
    )
    assert b.exhausted and b.sound and b.confidence == 1.0
    assert math.isclose(b.covered_mass, 1.0, rel_tol=1e-9)
    assert len(b.sequences) == len(all_sequences(P, plan.get_action().tolist()))
    assert b.state_bound <= exact + 1e-5
    assert b.state_bound >= exact - 0.05  # Hunter's bound is close on a chained always
    assert abs(b.state_estimate - exact) <= 0.02


def test_truncated_bound_assumes_nothing_of_the_rest():
    problem, plan, modes, K, gains = _setup(["nominal", "failed", "dropout"], P_FAIL_DROP, 4)
    exact = _exact(problem, plan, modes, K, P_FAIL_DROP)
    b = stl.markov_bound(
        problem, plan, control_domain=None, lqr_gains=gains, samples=0, max_sequences=5, rest_runs=0
    )
    assert len(b.sequences) == 5 and not b.exhausted
    assert b.covered_mass < 1.0
    assert b.state_bound <= b.covered_mass
    assert b.state_bound <= exact + 1e-5
    probs = [s.probability for s in b.sequences]
    assert probs == sorted(probs, reverse=True)
    assert b.rest_runs == 0
    full = stl.markov_bound(
        problem, plan, control_domain=None, lqr_gains=gains, samples=0, max_sequences=5, rest_runs=3000
    )
    assert full.rest_runs == 3000 and full.confidence == pytest.approx(0.999)
    assert full.state_bound == pytest.approx(b.state_bound, abs=1e-12)
    assert full.total_state_bound <= exact + 1e-3  # (a 99.9% bound: fails with probability <= 1e-3)
    # the remainder's runs recover most of the mass the enumeration left out
    assert full.total_state_bound >= b.state_bound + 0.5 * (1 - b.covered_mass) * exact
    b2 = stl.markov_bound(
        problem, plan, control_domain=None, lqr_gains=gains, samples=0, min_probability=0.05
    )
    assert all(s.probability >= 0.05 for s in b2.sequences)


def test_exact_oracle_agrees_with_its_own_monte_carlo():
    names = ["nominal", "failed", "dropout"]
    problem, plan, modes, K, gains = _setup(names, P_FAIL_DROP, 4)
    exact = _exact(problem, plan, modes, K, P_FAIL_DROP)
    args = (modes, K, plan.get_mean(), plan.get_control(), P_FAIL_DROP, plan.get_action().tolist())
    mc = monte_carlo_always(
        *args, plan.get_mean(0), np.zeros((2, 2)), plan.get_cov(0), H, C, list(range(5)), 4000, seed=3
    )
    assert abs(mc - exact) <= 4 * math.sqrt(exact * (1 - exact) / 4000) + 1e-3


def test_validate_measures_the_independent_simulator_rate_and_the_bound_is_below():
    names = ["nominal", "failed", "dropout"]
    problem, plan, modes, K, gains = _setup(names, P_FAIL_DROP, 4)
    runs = 4000
    rep = stl.validate(
        problem, plan, None, plan.get_mean(0), runs=runs, seed=11, clip_controls=False, lqr_gains=gains
    )
    measured = rep.state_success_rate
    args = (modes, K, plan.get_mean(), plan.get_control(), P_FAIL_DROP, plan.get_action().tolist())
    mc = monte_carlo_always(
        *args, plan.get_mean(0), np.zeros((2, 2)), plan.get_cov(0), H, C, list(range(5)), runs, seed=4
    )
    pooled = (measured + mc) / 2
    assert abs(measured - mc) <= 4 * math.sqrt(2 * pooled * (1 - pooled) / runs) + 1e-3
    b = stl.markov_bound(problem, plan, control_domain=None, lqr_gains=gains, samples=0)
    assert b.state_bound <= measured + 4 * math.sqrt(measured * (1 - measured) / runs) + 1e-3


def test_clipped_inputs_take_the_sampled_bound_and_stay_below_the_measured_rate():
    names = ["nominal", "failed"]
    P = np.array([[[0.85, 0.15], [0.0, 1.0]], [[0.0, 1.0], [0.0, 1.0]]])
    problem, plan, modes, K, gains = _setup(names, P, 5)
    u = stl.mk_variable(2, name="u2")
    box = stl.logical_and(u[0] >= -0.55, u[0] <= 0.55, u[1] >= -0.55, u[1] <= 0.55).region
    b = stl.markov_bound(problem, plan, control_domain=box, lqr_gains=gains, samples=0, sampled_runs=1000)
    assert any(s.sampled for s in b.sequences) and b.confidence == pytest.approx(0.999)
    assert all(s.clip_mass > 1e-3 for s in b.sequences if s.sampled)
    args = (modes, K, plan.get_mean(), plan.get_control(), P, plan.get_action().tolist())
    runs = 4000
    mc = monte_carlo_always(
        *args,
        plan.get_mean(0),
        np.zeros((2, 2)),
        plan.get_cov(0),
        H,
        C,
        list(range(6)),
        runs,
        seed=8,
        box=(np.full(2, -0.55), np.full(2, 0.55)),
    )
    assert b.state_bound <= mc + 4 * math.sqrt(mc * (1 - mc) / runs) + 1e-3
    assert b.state_bound >= mc - 0.1  # the sampled bound is informative


# --------------------------------------------------------------------------------------------
# Execution with jumps against the executor without them


def test_a_chain_that_never_jumps_executes_as_the_system_without_one():
    names = ["nominal", "failed"]
    identity = np.array([[[1.0, 0.0], [1.0, 0.0]], [[0.0, 1.0], [0.0, 1.0]]])
    problem, plan, _, _, gains = _setup(names, identity, 6)
    sysm = problem.switched_system
    base = stl.mk_switched_sys(list(sysm.system_modes))
    a_sim, a_real = stl.simulate(base, plan, 6, plan.get_mean(0), None, seed=3, lqr_gains=gains)
    b_sim, b_real = stl.simulate(sysm, plan, 6, plan.get_mean(0), None, seed=3, lqr_gains=gains)
    np.testing.assert_array_equal(b_real.get_action(), plan.get_action())
    # (the same draws; the jump path keeps one covariance per run: equal up to rounding)
    np.testing.assert_allclose(b_real.get_state(), a_real.get_state(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(b_sim.get_mean(), a_sim.get_mean(), rtol=0, atol=1e-12)
    b = stl.markov_bound(problem, plan, control_domain=None, lqr_gains=gains, samples=0)
    pred = stl.predict_closed_loop(
        base, plan, formula=problem.stl_formula, control_domain=None, samples=0, lqr_gains=gains
    )
    assert len(b.sequences) == 1
    assert b.state_bound == pytest.approx(pred.state_success_bound, abs=1e-12)


def test_simulate_records_the_executed_modes_and_is_reproducible():
    problem, plan, _, _, gains = _setup(["nominal", "failed", "dropout"], P_FAIL_DROP, 6)
    sysm = problem.switched_system
    runs = [stl.simulate(sysm, plan, 6, plan.get_mean(0), None, seed=s, lqr_gains=gains) for s in range(40)]
    again = stl.simulate(sysm, plan, 6, plan.get_mean(0), None, seed=0, lqr_gains=gains)
    np.testing.assert_array_equal(again[1].get_state(), runs[0][1].get_state())
    executed = np.array([r[1].get_action() for r in runs])
    assert (executed != 0).any()  # some run jumped
    for (xi_sim, xi_real), seq in zip(runs, executed, strict=True):
        np.testing.assert_array_equal(xi_sim.get_action(), plan.get_action())
        obs = xi_real.get_observation()
        # a dropped frame (mode 2) observes nothing
        for k, s in enumerate(seq):
            assert np.isnan(obs[k + 1]).all() == (s == 2)


def test_unobserved_switching_is_bounded_by_the_executors_runs_below_the_independent_simulator():
    names = ["nominal", "failed"]
    P = np.array([[[0.8, 0.2], [0.0, 1.0]], [[0.0, 1.0], [0.0, 1.0]]])
    problem, plan, modes, K, gains = _setup(names, P, 5, observed=False)
    xi_sim, xi_real = stl.simulate(
        problem.switched_system, plan, 5, plan.get_mean(0), None, seed=1, lqr_gains=gains
    )
    assert np.isfinite(xi_real.get_state()).all()
    b = stl.markov_bound(
        problem, plan, control_domain=None, lqr_gains=gains, sampled_runs=2000, rest_runs=2000
    )
    assert all(s.sampled for s in b.sequences) and b.confidence == pytest.approx(0.999)
    args = (modes, K, plan.get_mean(), plan.get_control(), P, plan.get_action().tolist())
    runs = 4000
    mc = monte_carlo_always(
        *args,
        plan.get_mean(0),
        np.zeros((2, 2)),
        plan.get_cov(0),
        H,
        C,
        list(range(6)),
        runs,
        seed=9,
        observed=False,
    )
    assert b.total_state_bound <= mc + 4 * math.sqrt(mc * (1 - mc) / runs) + 1e-3
    assert b.total_state_bound >= mc - 0.05
    with pytest.raises(InvalidArgumentError, match="unobserved"):
        stl.markov_bound(problem, plan, sampled_runs=0, rest_runs=0)
    problem2, plan2, _, _, gains2 = _setup(["nominal", "dropout"], np.eye(2), 5, observed=False)
    with pytest.raises(InvalidArgumentError, match="same output dimension"):
        stl.simulate(problem2.switched_system, plan2, 5, plan2.get_mean(0), None, seed=1, lqr_gains=gains2)


def test_validate_refuses_a_prediction_that_ignores_the_jumps():
    problem, plan, _, _, gains = _setup(["nominal", "failed", "dropout"], P_FAIL_DROP, 4)
    with pytest.raises(InvalidArgumentError, match="markov_bound"):
        stl.validate(problem, plan, None, runs=10, seed=0, predict=True, lqr_gains=gains)


def test_solve_reports_the_bound_and_judges_the_target_on_it():
    names = ["nominal", "failed"]
    P = np.array([[[0.97, 0.03], [0.0, 1.0]], [[0.0, 1.0], [0.0, 1.0]]])
    problem, _, _, _, _ = _setup(names, P, 6)
    x = stl.mk_variable(2)
    goal = stl.logical_and(
        stl.prob(x[0] >= 0.8) >= 0.9,
        stl.prob(x[0] <= 1.8) >= 0.9,
        stl.prob(x[1] >= 0.8) >= 0.9,
        stl.prob(x[1] <= 1.8) >= 0.9,
        name="goal",
    )
    u = stl.mk_variable(2, name="u3")
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    sw_problem = stl.Problem(
        problem.switched_system, domain, problem.initial_state, stl.eventually(0, 12, goal)
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = sw_problem.solve_result(seed=0)
    assert res.status == "found"
    assert res.trajectory is not None and res.trajectory.num_of_steps >= 3
    assert res.execution is not None and res.execution.closure == "markov"
    runs = 4000
    rep = stl.validate(sw_problem, res.trajectory, None, runs=runs, seed=2)
    for bound, rate in (
        (res.execution.state_bound, rep.state_success_rate),
        (res.execution.belief_bound, rep.belief_success_rate),
    ):
        assert bound <= rate + 4 * math.sqrt(rate * (1 - rate) / runs) + 1e-3
    assert "under chance switching: bound" in res.reason
    below = res.execution.state_bound < 0.95 or res.execution.belief_bound < 0.9
    assert ("does not prove the execution target" in res.reason) == below
    said = [
        w
        for w in caught
        if issubclass(w.category, ExecutionTargetWarning) and "under chance switching" in str(w.message)
    ]
    assert len(said) == int(below)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExecutionTargetWarning)
        mlo = sw_problem.solve_result(seed=0, guarantee="mlo")
    assert mlo.execution is None or mlo.execution.closure != "markov"
    assert "chance switching" not in mlo.reason


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 100_000),
    second=st.sampled_from(["failed", "dropout"]),
    steps=st.integers(2, 4),
    limit=st.floats(0.7, 1.3),
)
def test_bound_never_above_the_exact_probability_on_random_chains(seed, second, steps, limit):
    rng = np.random.default_rng(seed)
    P = rng.dirichlet(np.ones(2) * 0.7, size=(2, 2))
    names = ["nominal", second]
    problem, plan, modes, K, gains = _setup(names, P, steps)
    c = np.array([-limit, -limit])
    exact = exact_always_probability(
        modes,
        K,
        plan.get_mean(),
        plan.get_control(),
        np.asarray(switching_of(problem.switched_system).transitions),
        plan.get_action().tolist(),
        plan.get_mean(0),
        np.zeros((2, 2)),
        plan.get_cov(0),
        H,
        c,
        list(range(steps + 1)),
    )
    x = stl.mk_variable(2)
    ap = stl.logical_and(stl.prob(x[0] <= limit) >= 0.9, stl.prob(x[1] <= limit) >= 0.9, name="safe")
    b = stl.markov_bound(
        problem,
        plan,
        formula=stl.always(0, steps, ap),
        control_domain=None,
        lqr_gains=gains,
        samples=0,
        max_sequences=1000,
    )
    assert b.exhausted and b.confidence == 1.0
    assert b.state_bound <= exact + 1e-5


def test_the_online_jump_executor_is_simulates_loop_with_jumps():
    problem, plan, _, _, gains = _setup(["nominal", "failed", "dropout"], P_FAIL_DROP, 6)
    sysm = problem.switched_system
    for seed in range(5):
        xi_sim, xi_real = stl.simulate(sysm, plan, 6, plan.get_mean(0), None, seed=seed, lqr_gains=gains)
        ex = JumpExecutor(sysm, plan, lqr_gains=gains)
        executed = xi_real.get_action()
        obs = xi_real.get_observation()
        for k in range(6):
            q, u = ex.command(int(executed[k]))
            assert q == plan.get_action()[k]
            np.testing.assert_array_equal(u, xi_sim.get_control()[k])
            y = obs[k + 1]
            ex.observe(None if np.isnan(y).all() else y)
            np.testing.assert_array_equal(ex.mean, xi_sim.get_mean()[k + 1])
        assert ex.done
    ex = JumpExecutor(sysm, plan, lqr_gains=gains)
    with pytest.raises(InvalidArgumentError, match="executed mode is observed"):
        ex.command()
    with pytest.raises(InvalidArgumentError, match="no chance switching"):
        JumpExecutor(stl.mk_switched_sys(list(sysm.system_modes)), plan, lqr_gains=gains)
