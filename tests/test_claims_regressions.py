"""Every claim true (issue 25): each reproduction of the issue, then the fix, checked independently.

- the paper's listing with every kind of sensor and every objective (a smoke test; the constant
  sensor crashed);
- a noise-free partial sensor with a point prior (a singular innovation covariance crashed);
- a found plan must keep the control domain (the sampler's gentle domain shrank about the wrong
  point, and the final check never looked at the domain);
- time and memory bounded for any ``max_num_of_steps`` (the sampler's steering gains were
  allocated for 10**9 steps);
- a sweep's local Dask cluster listens on loopback only;
- silent misuse: a formula over the input, a domain over the state, inputs of a million on a
  domain bounded on one side.

Found plans are checked with the independent roll-out and monitor of :mod:`oracles`.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
import pytest
from oracles.brute_force import sat
from oracles.rollout import ModeSpec, loosen, mlo_rollout

import idstlpy as stl
from idstlpy.errors import InvalidArgumentError
from idstlpy.synthesis.abstraction import Abstraction
from idstlpy.synthesis.options import SolverOptions

P = stl.prob


def _light(state):
    return ((1 / 10) * (5 - state[0]) ** 2 + 0.001) * np.identity(2)


SENSORS = {"none": None, "constant": 0.1 * np.identity(2), "state_dependent": _light}


def _listing(sensor: str):
    """The paper's listing (README) with the light's sensor replaced by ``sensor``."""
    q = stl.mk_variable(size=1, dtype=int)
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float, name="u")
    spec = ModeSpec(np.identity(2), 0.25 * np.eye(2), np.zeros((2, 2)))
    kwargs = dict(A=spec.A, B=spec.B, W=spec.W)
    if SENSORS[sensor] is not None:
        kwargs.update(C=np.identity(2), V=SENSORS[sensor])
        spec = ModeSpec(spec.A, spec.B, spec.W, np.identity(2), SENSORS[sensor])
    problem = stl.Problem(
        switched_system=stl.mk_switched_sys([stl.dynamical_system.mk_lbs(**kwargs)]),
        control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0, u[1] >= -1.0, u[1] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.array([0, 2.5]), cov=np.diag([0.1, 0.1])),
        stl_formula=stl.until(
            stl.logical_and(
                q == 0,
                P(x[0] >= -1) >= 1 - 0.01,
                P(x[0] <= 5) >= 1 - 0.01,
                P(x[1] >= -1) >= 1 - 0.01,
                P(x[1] <= 4) >= 1 - 0.01,
                name="free_space",
            ),
            0,
            240,
            stl.always(
                0,
                40,
                stl.logical_and(
                    q == 0,
                    P(x[0] >= -0.25) >= 1 - 0.05,
                    P(x[0] <= 0.25) >= 1 - 0.05,
                    P(x[1] >= -0.25) >= 1 - 0.05,
                    P(x[1] <= 0.25) >= 1 - 0.05,
                    name="target",
                ),
            ),
        ),
    )
    return problem, [spec]


LISTING = dict(
    rrt_timeout=60,
    delta_near=2,
    delta_drain=0.5,
    goal_bias=0.25,
    min_num_of_steps=3,
    max_num_of_steps=15,
    seed=0,
)


def _box(problem) -> tuple[np.ndarray, np.ndarray]:
    return problem.control_domain.bounding_box()


def assert_plan_keeps_its_promises(problem, specs, result) -> None:
    """A ``found`` plan: modes in range, inputs in the domain (1e-7 of its scale), the independent
    roll-out equal to the returned beliefs, and the brute-force monitor accepting it."""
    traj = result.trajectory
    assert traj is not None
    N, m = traj.num_of_steps, problem.switched_system.m
    actions = np.asarray(traj.get_action(), dtype=int).reshape(N)
    controls = np.asarray(traj.get_control(), dtype=float).reshape(N, m)
    assert np.all((actions >= 0) & (actions < len(specs)))
    H, c = problem.control_domain.H, problem.control_domain.c
    scale = max(1.0, float(np.max(np.abs(c))))
    assert np.all(controls @ H.T + c <= 1e-7 * scale), f"inputs outside the domain: {controls.tolist()}"
    trace = mlo_rollout(specs, problem.initial_state.mean, problem.initial_state.cov, actions, controls)
    means = np.array([mu for mu, _ in trace.states])
    covs = np.array([S for _, S in trace.states])
    np.testing.assert_allclose(traj.get_mean(), means, rtol=1e-6, atol=1e-9 * (1 + np.max(np.abs(means))))
    np.testing.assert_allclose(traj.get_cov(), covs, rtol=1e-6, atol=1e-12 * (1 + np.max(np.abs(covs))))
    assert sat(loosen(problem.stl_formula, trace), 0, trace), "the brute-force monitor rejects the plan"


# -- 1. the listing with a constant sensor, and every sensor with every objective ------------------------
def test_listing_with_a_constant_sensor_is_found():
    """Issue 25: ``DimensionError: controls must have shape (51, 2)`` from the final check."""
    problem, specs = _listing("constant")
    result = problem.solve_result(**LISTING)
    assert result.status == "found", result.reason
    assert_plan_keeps_its_promises(problem, specs, result)


@pytest.mark.parametrize("objective", [None, "effort", "time", "margin"])
@pytest.mark.parametrize("sensor", list(SENSORS))
def test_listing_smoke_every_sensor_every_objective(sensor, objective):
    """The listing, three sensors x four objectives, within a 10 s cap each (under 60 s in all).

    The budget, chosen honestly: with the constant sensor, ``effort`` and ``margin`` go to the
    eager MILP over the whole horizon (281 steps), which took 12-25 s on the 2-core test machine
    under load; within 10 s they are ``budget_exhausted`` by the clock, and the test then checks
    that the answer says so. Every other case is decided within the cap.

    Blind, the prior's spread never shrinks (``A = I``, ``W = 0``): ``sqrt(0.1) * 1.645 > 0.25``,
    so the target's 95% confidence is out of reach: ``infeasible`` is the truth. Otherwise a plan
    exists (the default solve finds one); an answer cut by the wall-clock cap is honest only when
    ``caps_hit`` says so.
    """
    problem, specs = _listing(sensor)
    result = problem.solve_result(**LISTING, objective=objective, time_limit=10)
    if sensor == "none":
        assert result.status == "infeasible", result.reason
        return
    assert result.status in ("found", "budget_exhausted"), result.reason
    if result.status == "budget_exhausted":
        assert "time_limit" in result.stats.caps_hit, result.reason
        return
    assert_plan_keeps_its_promises(problem, specs, result)


# -- 2. singular innovation covariances -------------------------------------------------------------------
def test_noise_free_partial_sensor_with_a_point_prior():
    """Issue 25: ``LinAlgError: Singular matrix`` from ``covariance_jacobian`` via ``give_room``."""
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    C = np.array([[1.0, 0.0]])
    mode = stl.dynamical_system.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=np.zeros((2, 2)), C=C)
    problem = stl.Problem(
        stl.mk_switched_sys([mode]),
        stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region,
        stl.to_belief(np.zeros(2), np.zeros((2, 2))),
        stl.eventually(0, 10, stl.logical_and(P(x[0] >= 1) >= 0.9, P(x[1] >= 1) >= 0.9)),
    )
    for objective in (None, "effort"):
        result = problem.solve_result(seed=0, objective=objective, time_limit=20)
        assert result.status == "found", result.reason
        specs = [ModeSpec(np.eye(2), 0.5 * np.eye(2), np.zeros((2, 2)), C, None)]
        assert_plan_keeps_its_promises(problem, specs, result)


def test_covariance_jacobian_takes_the_pseudo_inverse_gain():
    """A perfect sensor of a known coordinate: ``C P C' + R = 0``; the derivative is finite."""
    from idstlpy.synthesis.plan_lp import covariance_jacobian

    mode = stl.dynamical_system.mk_lbs(
        A=np.eye(2),
        B=np.eye(2),
        W=np.zeros((2, 2)),
        C=np.array([[1.0, 0.0]]),
        V=lambda s: np.array([[s[0] ** 2]]),
    )
    means = np.zeros((3, 2))
    covs = np.zeros((3, 2, 2))
    S = covariance_jacobian([mode], np.zeros(2, dtype=int), means, covs, np.ones(2))
    assert len(S) == 3 and all(np.all(np.isfinite(s)) for s in S)


# -- 3. the control domain --------------------------------------------------------------------------------
def _sampler(problem, **options):
    from idstlpy.synthesis.sampler import BeliefSampler

    abstraction = Abstraction(problem.stl_formula, problem.switched_system.n)
    return BeliefSampler(problem, abstraction, None, SolverOptions.make(**options))


def _one_dim(lo: float, hi: float | None, formula_of, sensor=_light):
    x = stl.mk_variable(1)
    u = stl.mk_variable(1, name="u")
    V = (lambda s: np.array([[0.1 + 0.1 * s[0] ** 2]])) if sensor is _light else sensor
    mode = stl.dynamical_system.mk_lbs(A=np.eye(1), B=np.eye(1), W=np.zeros((1, 1)), C=np.eye(1), V=V)
    domain = stl.logical_and(u[0] >= lo, u[0] <= hi) if hi is not None else stl.logical_and(u[0] >= lo)
    problem = stl.Problem(
        stl.mk_switched_sys([mode]),
        domain.region,
        stl.to_belief(np.zeros(1), 0.01 * np.eye(1)),
        formula_of(x),
    )
    specs = [ModeSpec(np.eye(1), np.eye(1), np.zeros((1, 1)), np.eye(1), V)]
    return problem, specs


def test_gentle_steering_domain_lies_inside_the_domain():
    """Issue 25's domain u in [-0.0427, 1.7953]: the gentle domain is the domain scaled by
    ``STEER_SHRINK`` about its centre, not a set that reaches below -0.0427."""
    from idstlpy.synthesis.sampler import STEER_SHRINK

    problem, _ = _one_dim(
        -0.0427, 1.7953, lambda x: stl.eventually(0, 5, stl.logical_and(P(x[0] >= 1) >= 0.9))
    )
    sampler = _sampler(problem)
    centre = 0.5 * (-0.0427 + 1.7953)
    lo = centre + STEER_SHRINK * (-0.0427 - centre)
    hi = centre + STEER_SHRINK * (1.7953 - centre)
    gentle = stl.sets.Polytope(sampler.UH, sampler.Uc_gentle)
    low, high = gentle.bounding_box()
    np.testing.assert_allclose([low[0], high[0]], [lo, hi], rtol=1e-9)


def test_final_check_rejects_a_plan_outside_the_domain():
    """The plan the issue saw (u = -0.209 on [-0.0427, 1.7953]) meets the formula but not the domain."""
    from idstlpy.synthesis.cegis import _check, _Run

    def formula(x):
        return stl.eventually(0, 3, stl.logical_and(P(x[0] <= 0.5) >= 0.9))

    problem, _ = _one_dim(-0.0427, 1.7953, formula)
    run = _Run(problem, SolverOptions.make(), time.perf_counter())

    def plan(u: float):
        return stl.rollout(problem.switched_system, problem.initial_state, [0], [[u]])

    assert stl.robustness(plan(-0.209), problem.stl_formula) >= 0
    assert _check(run, plan(-0.209)) is None
    assert _check(run, plan(-0.04)) is not None
    # a rounding error's worth outside (1e-12 of the domain's unit) counts as inside
    assert _check(run, plan(-0.0427 - 1e-12)) is not None


@pytest.mark.parametrize("objective", [None, "effort"])
def test_state_dependent_plans_on_an_off_centre_domain_keep_it(objective):
    """The sampler's problems (state-dependent noise) on issue 25's off-centre domain."""
    problem, specs = _one_dim(
        -0.0427,
        1.7953,
        lambda x: stl.eventually(
            0, 12, stl.always(0, 2, stl.logical_and(P(x[0] >= 1.5) >= 0.9, P(x[0] <= 3) >= 0.9))
        ),
    )
    result = problem.solve_result(seed=0, objective=objective, time_limit=20)
    assert result.status == "found", result.reason
    assert_plan_keeps_its_promises(problem, specs, result)


# -- 4. time and memory bounded ---------------------------------------------------------------------------
def test_steering_gains_do_not_grow_with_max_num_of_steps():
    """A counter, not a clock: 10**9 steps per extension allocate at most STEER_LOOKAHEAD gains."""
    from idstlpy.synthesis.sampler import STEER_LOOKAHEAD

    problem, _ = _listing("state_dependent")
    sampler = _sampler(problem, max_num_of_steps=10**9)
    assert all(len(g) <= STEER_LOOKAHEAD for g in sampler._gains)
    assert all(1 <= i <= STEER_LOOKAHEAD for i in sampler._index)


def test_belief_trees_stop_at_their_memory_cap(monkeypatch):
    """A counter: with the cap set to 100 nodes, no candidate's tree grows beyond it."""
    from idstlpy.synthesis import sampler

    monkeypatch.setattr(sampler, "MIN_NODES", 100)
    monkeypatch.setattr(sampler, "TREE_BYTES", 0)
    problem, specs = _listing("state_dependent")
    result = problem.solve_result(seed=0, max_num_of_steps=10**9, sampler_iterations=10**6, time_limit=10)
    assert result.stats.sampler_iterations > 0
    assert result.stats.nodes <= 100 * max(1, result.stats.candidates)
    if result.status == "found":
        assert_plan_keeps_its_promises(problem, specs, result)


def test_huge_max_num_of_steps_honours_the_time_limit():
    """Issue 25: no answer within 90 s on a small time limit. The overshoot is measured in
    benchmarks/ (no wall clock in a test); here: the search ends, with the cap named if it decided."""
    problem, specs = _listing("state_dependent")
    result = problem.solve_result(seed=0, max_num_of_steps=10**9, time_limit=2)
    assert result.status in ("found", "budget_exhausted"), result.reason
    if result.status == "found":
        assert_plan_keeps_its_promises(problem, specs, result)


def test_light_dark_with_process_noise_honours_the_time_limit():
    """Issue 25's light-dark variant (W = 0.1 I, noise (0.1 (5 - x0)^2 + 0.5) I, ``free U[0,100]
    G[0,10] target``). Generous slack: 3 s asked, 60 s allowed."""
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    mode = stl.dynamical_system.mk_lbs(
        A=np.eye(2),
        B=0.25 * np.eye(2),
        W=0.1 * np.eye(2),
        C=np.eye(2),
        V=lambda s: (0.1 * (5 - s[0]) ** 2 + 0.5) * np.identity(2),
    )
    free = stl.logical_and(
        P(x[0] >= -1) >= 0.99, P(x[0] <= 5) >= 0.99, P(x[1] >= -1) >= 0.99, P(x[1] <= 4) >= 0.99, name="free"
    )
    target = stl.logical_and(
        P(x[0] >= -0.25) >= 0.95,
        P(x[0] <= 0.25) >= 0.95,
        P(x[1] >= -0.25) >= 0.95,
        P(x[1] <= 0.25) >= 0.95,
        name="target",
    )
    problem = stl.Problem(
        stl.mk_switched_sys([mode]),
        stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region,
        stl.to_belief([0.0, 2.5], np.diag([0.1, 0.1])),
        stl.until(free, 0, 100, stl.always(0, 10, target)),
    )
    result = problem.solve_result(seed=0, time_limit=3)
    assert result.status in ("found", "budget_exhausted"), result.reason


# -- 5. nothing listens beyond the machine ----------------------------------------------------------------
@pytest.mark.parametrize("processes", [False, True])
def test_local_dask_cluster_listens_on_loopback_only(processes):
    """Every listening socket of the cluster (this process and its workers), dashboard included."""
    import ipaddress

    import psutil

    from idstlpy.batch.executors import DaskExecutor

    ex = DaskExecutor(workers=1, processes=processes)
    try:
        assert ex.submit(pow, 2, 5).result(timeout=60) == 32
        me = psutil.Process()
        bound = []
        for proc in [me, *me.children(recursive=True)]:
            for conn in proc.net_connections(kind="inet"):
                if conn.status == psutil.CONN_LISTEN:
                    bound.append(conn.laddr.ip)
        assert bound, "the cluster listens nowhere?"
        assert all(ipaddress.ip_address(ip).is_loopback for ip in bound), bound
        link = ex.dashboard_link
        assert link is None or "127.0.0.1" in link, link
        info = ex.client.scheduler_info()
        for address in [info["address"], *info["workers"]]:
            assert "127.0.0.1" in address or address.startswith("inproc://"), address
    finally:
        ex.shutdown()


def test_dask_host_must_be_an_address():
    from idstlpy.batch.executors import DaskExecutor

    with pytest.raises(InvalidArgumentError, match="host"):
        DaskExecutor(host="")


# -- 6. silent misuse -------------------------------------------------------------------------------------
def _parts():
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    system = stl.mk_switched_sys([stl.mk_lcs(np.eye(2), np.eye(2))])
    init = stl.to_belief(np.zeros(2), np.zeros((2, 2)))
    return x, u, system, init


def test_formula_over_the_input_variable_is_refused():
    x, u, system, init = _parts()
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    with pytest.raises(InvalidArgumentError, match="stl_formula"):
        stl.Problem(system, domain, init, stl.eventually(0, 5, stl.logical_and(P(u[0] >= 1) >= 0.9)))


def test_control_domain_over_the_state_variable_is_refused():
    x, u, system, init = _parts()
    with pytest.raises(InvalidArgumentError, match="control_domain"):
        stl.Problem(
            system,
            stl.logical_and(x[0] >= -1, x[0] <= 1).region,
            init,
            stl.eventually(0, 5, stl.logical_and(P(x[0] >= 1) >= 0.9)),
        )


def test_variables_keep_the_role_a_problem_gave_them():
    x, u, system, init = _parts()
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    assert x.role is None and u.role is None
    stl.Problem(system, domain, init, stl.eventually(0, 5, stl.logical_and(P(x[0] >= 1) >= 0.9)))
    assert (x.role, u.role) == ("state", "input")
    assert stl.expressions.region_variable(domain) is u
    # a later problem: the formula over u (the domain built otherwise), the domain over x
    box = stl.sets.Polytope(np.vstack([np.eye(2), -np.eye(2)]), -np.ones(4))
    with pytest.raises(
        InvalidArgumentError, match="stl_formula is written over u, which a Problem already uses"
    ):
        stl.Problem(system, box, init, stl.eventually(0, 5, stl.logical_and(P(u[0] >= 1) >= 0.9)))
    y = stl.mk_variable(2, name="y")
    with pytest.raises(InvalidArgumentError, match="control_domain is written over x"):
        stl.Problem(
            system,
            stl.logical_and(x[0] <= 1).region,
            init,
            stl.eventually(0, 5, stl.logical_and(P(y[0] >= 1) >= 0.9)),
        )
    # the same roles again are fine
    stl.Problem(system, domain, init, stl.eventually(0, 3, stl.logical_and(P(x[1] >= 1) >= 0.9)))


def _half_line():
    """x' = x + u, u >= 1 (bounded on one side), reach x >= 5: inputs of a few units suffice."""
    x = stl.mk_variable(1)
    u = stl.mk_variable(1, name="u")
    return stl.Problem(
        stl.mk_switched_sys([stl.dynamical_system.mk_lbs(A=np.eye(1), B=np.eye(1), W=np.zeros((1, 1)))]),
        stl.logical_and(u[0] >= 1).region,
        stl.to_belief(np.zeros(1), 0.01 * np.eye(1)),
        stl.eventually(0, 10, stl.logical_and(P(x[0] >= 5) >= 0.9)),
    )


@pytest.mark.parametrize("objective", [None, "effort"])
def test_a_domain_bounded_on_one_side_gets_inputs_of_the_problems_scale(objective):
    """Issue 25: u = 1,000,001 (the unbounded target's capped Chebyshev radius became the
    execution margin); now a few units, and no warning."""
    problem = _half_line()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = problem.solve_result(seed=0, objective=objective)
    assert result.status == "found", result.reason
    assert np.max(np.abs(result.trajectory.get_control())) < 100


def test_far_inputs_on_an_unbounded_domain_are_warned_about():
    from idstlpy.synthesis.cegis import _check, _Run

    problem = _half_line()
    run = _Run(problem, SolverOptions.make(), time.perf_counter())
    far = stl.rollout(problem.switched_system, problem.initial_state, [0], [[1_000_001.0]])
    with pytest.warns(UserWarning, match="unbounded control_domain"):
        assert _check(run, far) is not None  # legal: warned, not refused
    near = stl.rollout(problem.switched_system, problem.initial_state, [0], [[6.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _check(run, near) is not None
