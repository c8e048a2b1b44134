"""The executor layer: the spec, the one step law and the online executor."""

from __future__ import annotations

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.errors import DimensionError, InvalidArgumentError, InvalidTypeError
from idstlpy.executor import ExecutorSpec, OnlineExecutor, StepLaw
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system
from idstlpy.sets import Polytope


def _listing(steps=20):
    problem = light_dark(deadline=30, hold=5)
    system = problem.switched_system
    plan = stl.rollout(
        system, problem.initial_state, np.zeros(steps, dtype=int), np.tile([0.5, -0.5], (steps, 1))
    )
    return problem, system, plan


def _two_modes():
    A = np.array([[1.0, 0.1], [0.0, 0.95]])
    W = 0.05 * np.eye(2)
    return stl.mk_switched_sys(
        [
            stl.mk_lbs(A=A, B=0.25 * np.eye(2), W=W, C=np.eye(2), V=0.2 * np.eye(2)),
            stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=W),
        ]
    )


def test_online_executor_driven_by_hand_is_simulate():
    """A user's loop around OnlineExecutor, with the plant of the paper's listing, gives simulate's run."""
    problem, system, plan = _listing()
    real = light_dark_real_system()
    sim, run = stl.simulate(system, plan, 20, LIGHT_DARK_REAL_INITIAL_STATE, real, seed=5)
    executor = stl.OnlineExecutor(system, plan)
    rng = np.random.default_rng(5)
    x = np.asarray(LIGHT_DARK_REAL_INITIAL_STATE, dtype=float)
    y = None
    means = [executor.mean.copy()]
    while not executor.done:
        q, u = executor.step(y)
        mode = system.mode(q)
        x = real.mode(0).A @ x + real.mode(0).B @ u + mode.W @ rng.standard_normal(mode.W.shape[1])
        y = mode.C @ x + mode.noise(x) @ rng.standard_normal(mode.noise(x).shape[1])
        if executor.k == 1:
            assert executor.pending
    executor.observe(y)
    means.append(executor.mean.copy())
    assert executor.k == 20 and executor.done and not executor.pending
    np.testing.assert_array_equal(executor.belief.mean, sim.get_mean(20))
    np.testing.assert_array_equal(executor.belief.cov, sim.get_cov(20))
    np.testing.assert_array_equal(x, run.get_state(20))


def test_online_executor_from_a_problem_clips_to_its_domain():
    problem, system, plan = _listing()
    far = stl.to_belief([5.0, -5.0], np.eye(2))
    executor = OnlineExecutor(problem, plan)
    executor.reset(far)
    _, u = executor.step()
    assert np.all(problem.control_domain.H @ u + problem.control_domain.c <= 1e-9)
    unclipped = OnlineExecutor(problem, plan, control_domain=None)
    unclipped.reset(far)
    assert np.abs(unclipped.step()[1]).max() > np.abs(u).max()


def test_online_executor_sequence_errors():
    system = _two_modes()
    plan = stl.rollout(system, stl.to_belief([0.0, 0.0], np.eye(2)), [0, 1, 0], np.zeros((3, 2)))
    ex = OnlineExecutor(system, plan)
    with pytest.raises(InvalidArgumentError, match="first call takes None"):
        ex.step([0.0, 0.0])
    with pytest.raises(InvalidArgumentError, match="no input is pending"):
        ex.observe(None)
    q, _ = ex.step(None)
    assert q == 0
    with pytest.raises(InvalidArgumentError, match="pending"):
        ex.command()
    with pytest.raises(InvalidArgumentError, match="observation must be an array of shape"):
        ex.step(None)
    with pytest.raises(DimensionError, match="observation must have shape"):
        ex.step([1.0, 2.0, 3.0])
    with pytest.raises(InvalidArgumentError, match="observation must be finite"):
        ex.step([np.nan, 0.0])
    q, _ = ex.step([0.1, 0.0])
    assert q == 1
    with pytest.raises(InvalidArgumentError, match="blind"):
        ex.step([0.0, 0.0])
    ex.step(None)
    assert ex.done and ex.pending
    with pytest.raises(InvalidArgumentError, match="done.*observe"):
        ex.step([0.0, 0.1])
    ex.observe([0.0, 0.1])
    assert not ex.pending
    with pytest.raises(InvalidArgumentError, match="done"):
        ex.step(None)
    ex.reset()
    assert ex.k == 0 and not ex.done
    with pytest.raises(DimensionError, match="initial_belief"):
        ex.reset(stl.to_belief([0.0], [[1.0]]))


def test_online_executor_bad_arguments():
    system = _two_modes()
    plan = stl.rollout(system, stl.to_belief([0.0, 0.0], np.eye(2)), [0, 1], np.zeros((2, 2)))
    with pytest.raises(InvalidArgumentError, match="plan is None"):
        OnlineExecutor(system, None)
    with pytest.raises(InvalidTypeError, match="plan must be"):
        OnlineExecutor(system, plan.get_mean())
    with pytest.raises(InvalidTypeError, match="source must be"):
        OnlineExecutor("system", plan)
    spec = ExecutorSpec.make(system)
    with pytest.raises(InvalidArgumentError, match="given twice"):
        OnlineExecutor(spec, plan, process_noise="none")
    with pytest.raises(DimensionError, match="control_domain"):
        OnlineExecutor(system, plan, control_domain=Polytope.box([-1.0], [1.0]))
    with pytest.raises(InvalidArgumentError, match="process_noise"):
        ExecutorSpec.make(system, process_noise="loud")
    with pytest.raises(InvalidTypeError, match="plant must be a step function"):
        ExecutorSpec.make(system, plant="robot")
    with pytest.raises(InvalidArgumentError, match="either real_system"):
        ExecutorSpec.make(system, plant=lambda x, u, q, rng: x, real_system=system)
    with pytest.raises(InvalidArgumentError, match="process_noise='real'"):
        ExecutorSpec.make(system, plant=lambda x, u, q, rng: x, process_noise="real")
    one = stl.mk_switched_sys([system.mode(0)])
    with pytest.raises(DimensionError, match="the system has 0..0"):
        OnlineExecutor(one, plan)
    two_real = stl.mk_switched_sys([stl.mk_lcs(np.eye(2), np.eye(2))] * 2)
    three = stl.mk_switched_sys([system.mode(0), system.mode(1), system.mode(0)])
    plan3 = stl.rollout(three, stl.to_belief([0.0, 0.0], np.eye(2)), [2], np.zeros((1, 2)))
    with pytest.raises(DimensionError, match="real_system has modes 0..1"):
        OnlineExecutor(three, plan3, real_system=two_real)


def test_spec_is_frozen_and_resolves_gains_once():
    system = _two_modes()
    spec = ExecutorSpec.make(system, default_lqr={"horizon": 3})
    assert sorted(spec.gains) == [0, 1] and len(spec.gains[0]) == 3
    with pytest.raises(AttributeError):
        spec.process_noise = "none"  # type: ignore[misc]
    with pytest.raises(TypeError):
        spec.gains[0] = ()  # type: ignore[index]
    with pytest.raises(ValueError):
        spec.gains[0][0][0, 0] = 1.0


def test_batch_law_runs_many_runs_at_once_like_one_run_each():
    """S runs in one batch: row i follows the same law as a run alone (same draws given)."""
    system = _two_modes()
    plan = stl.rollout(system, stl.to_belief([0.0, 0.0], 0.1 * np.eye(2)), [0, 1, 0, 0], np.full((4, 2), 0.3))
    law = StepLaw(ExecutorSpec.make(system, control_domain=Polytope.box([-0.4, -0.4], [0.4, 0.4])), plan)
    S = 5
    rng = np.random.default_rng(0)
    X = rng.normal(size=(S, 2))
    M = np.zeros((S, 2))
    cov = plan.get_cov(0)
    for k in range(4):
        U = law.control(k, M)
        assert np.all(np.abs(U) <= 0.4)
        for i in range(S):
            np.testing.assert_allclose(U[i], law.control(k, M[i : i + 1])[0], rtol=0, atol=1e-15)
        X = law.plant(k, X, U, rng)
        Y = law.observe(k, X, rng)
        M_new, cov_new = law.filter(k, M, cov, U, Y)
        for i in range(S):
            m1, c1 = law.filter(k, M[i : i + 1], cov, U[i : i + 1], None if Y is None else Y[i : i + 1])
            np.testing.assert_allclose(M_new[i], m1[0], atol=1e-14)
            np.testing.assert_allclose(cov_new, c1, atol=1e-14)
        M, cov = M_new, cov_new
    assert cov.shape == (2, 2)


def test_state_dependent_noise_gives_each_run_its_covariance():
    problem, system, plan = _listing(6)
    law = StepLaw(ExecutorSpec.make(system), plan)
    rng = np.random.default_rng(1)
    M = np.array([[0.0, 1.0], [3.0, 1.0], [-2.0, 1.0]])
    U = law.control(0, M)
    X = law.plant(0, M.copy(), U, rng)
    Y = law.observe(0, X, rng)
    _, covs = law.filter(0, M, plan.get_cov(0), U, Y)
    assert covs.shape == (3, 2, 2)
    assert not np.allclose(covs[0], covs[1])
    _, one = law.filter(0, M[1:2], plan.get_cov(0), U[1:2], Y[1:2])
    np.testing.assert_array_equal(one, covs[1])


def _linear_plant(A, B):
    def step(x, u, q, rng):
        return A @ x + B @ u

    return step


def test_a_linear_step_function_plant_is_the_linear_real_system_bit_for_bit():
    problem, system, plan = _listing()
    real = light_dark_real_system()
    A, B = real.mode(0).A, real.mode(0).B
    a_sim, a_real = stl.simulate(system, plan, 20, LIGHT_DARK_REAL_INITIAL_STATE, real, seed=3)
    b_sim, b_real = system.simulate(
        plan, 20, LIGHT_DARK_REAL_INITIAL_STATE, None, seed=3, plant=_linear_plant(A, B)
    )
    for a, b in [(a_sim.get_mean(), b_sim.get_mean()), (a_real.get_state(), b_real.get_state())]:
        assert np.array_equal(a, b)


def test_plant_reaches_validate_and_execute():
    problem, system, plan = _listing(8)
    real = light_dark_real_system()
    step = _linear_plant(real.mode(0).A, real.mode(0).B)
    x0 = LIGHT_DARK_REAL_INITIAL_STATE
    ref = stl.validate(problem, plan, real, x0, runs=4, seed=2, executor="serial")
    got = stl.validate(problem, plan, None, x0, runs=4, seed=2, executor="serial", plant=step)
    assert got.belief_margins == ref.belief_margins and got.state_margins == ref.state_margins
    run_ref = stl.execute(problem, plan, real, x0, seed=4)
    run = stl.execute(problem, plan, None, x0, seed=4, plant=step)
    assert np.array_equal(run.real.get_state(), run_ref.real.get_state())
    with pytest.raises(InvalidArgumentError, match="predict needs a linear real_system"):
        stl.validate(problem, plan, None, x0, runs=2, executor="serial", plant=step, predict=True)


def test_plant_errors_name_the_problem():
    problem, system, plan = _listing(3)
    x0 = LIGHT_DARK_REAL_INITIAL_STATE
    with pytest.raises(DimensionError, match="plant step function must return a state of shape"):
        stl.simulate(system, plan, 3, x0, None, plant=lambda x, u, q, rng: np.zeros(3))
    with pytest.raises(InvalidArgumentError, match="either real_system"):
        stl.simulate(system, plan, 3, x0, light_dark_real_system(), plant=lambda x, u, q, rng: x)


def test_nonlinear_plant_with_its_own_noise_is_reproducible():
    """The plant's generator is the run's: the same seed gives the same nonlinear run."""
    module = _example("unicycle")
    problem = module.linearised_problem()
    system = problem.switched_system
    plan = stl.rollout(system, problem.initial_state, np.zeros(6, dtype=int), np.tile([1.0, 0.3], (6, 1)))
    runs = [
        stl.simulate(
            system, plan, 6, np.zeros(3), None, seed=9, plant=module.unicycle_step, process_noise="none"
        )
        for _ in range(2)
    ]
    assert np.array_equal(runs[0][1].get_state(), runs[1][1].get_state())
    other = stl.simulate(
        system, plan, 6, np.zeros(3), None, seed=10, plant=module.unicycle_step, process_noise="none"
    )
    assert not np.array_equal(runs[0][1].get_state(), other[1].get_state())


def _example(name):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).parents[1] / "examples" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"{name}_example", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_ros2_example_runs_without_ros(capsys):
    import sys

    module = _example("ros2_node")
    assert "rclpy" not in sys.modules
    x = module._fake_loop(steps=10, seed=1)
    assert x.shape == (2,) and "done" in capsys.readouterr().out
    problem, system, plan = _listing(4)
    core = module.ExecutorCore(problem, plan)
    commands = [core.tick(None)]
    while commands[-1] is not None:
        commands.append(core.tick(np.array([0.0, 2.5])))
    assert len(commands) == 5 and core.finished


def test_spec_and_online_executor_pickle():
    import pickle

    problem, system, plan = _listing(5)
    spec = ExecutorSpec.make(system, control_domain=problem.control_domain, default_lqr={"horizon": 2})
    back = pickle.loads(pickle.dumps(spec))
    assert sorted(back.gains) == sorted(spec.gains)
    assert all(
        np.array_equal(a, b) for q in spec.gains for a, b in zip(back.gains[q], spec.gains[q], strict=True)
    )
    with pytest.raises(ValueError):
        back.gains[0][0][0, 0] = 1.0
    np.testing.assert_array_equal(back.project(np.array([3.0, -3.0])), [1.0, -1.0])
    ex = OnlineExecutor(spec, plan)
    first = ex.step()
    again = pickle.loads(pickle.dumps(ex))
    y = np.array([0.1, 2.4])
    a, b = ex.step(y), again.step(y)
    assert a[0] == b[0] and np.array_equal(a[1], b[1]) and first[0] == 0


def test_a_diverging_execution_is_reported_with_its_step():
    system = _two_modes()
    plan = stl.rollout(system, stl.to_belief([1.0, 1.0], np.eye(2)), [0, 0, 0, 0], np.zeros((4, 2)))
    with np.errstate(all="ignore"), pytest.raises(InvalidArgumentError, match="diverged at step 2"):
        stl.simulate(system, plan, 4, [1.0, 1.0], None, plant=lambda x, u, q, rng: x * 1e200)
