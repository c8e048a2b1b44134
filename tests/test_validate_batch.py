"""Monte Carlo at scale: runs executed and monitored as arrays give the serial loop's results.

Oracles: the serial loop itself (``validate(batched=False)``: :func:`simulate` and the monitor,
one run at a time, each run with its own stream), :func:`idstlpy.belief.kalman_update` per run,
the noise function called per state, and the monitor's shift-based definitions of until/release.
"""

from __future__ import annotations

import functools
import logging
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from tests.test_validate import detour_plan

import idstlpy as stl
from idstlpy import semantics
from idstlpy.belief import kalman_update, kalman_update_batch
from idstlpy.errors import InvalidTypeError, NoiseFunctionError
from idstlpy.execution import validate
from idstlpy.problem_file import load_problem
from idstlpy.scenarios import (
    LIGHT_DARK_REAL_INITIAL_STATE,
    light_dark,
    light_dark_noise,
    light_dark_real_system,
)

TWO_MODES = Path(__file__).resolve().parents[1] / "examples" / "two_modes.toml"


def assert_same_reports(a, b):
    """The batched report is the serial one: same counts and violation rates, margins to rounding."""
    assert (a.belief_successes, a.state_successes) == (b.belief_successes, b.state_successes)
    assert a.proposition_violations == b.proposition_violations
    assert a.predicate_violations == b.predicate_violations
    np.testing.assert_allclose(a.belief_margins, b.belief_margins, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.state_margins, b.state_margins, rtol=0, atol=1e-9)
    assert len(a.executions) == len(b.executions)
    for (xa, ra), (xb, rb) in zip(a.executions, b.executions, strict=True):
        np.testing.assert_allclose(xa.get_mean(), xb.get_mean(), rtol=0, atol=1e-9)
        np.testing.assert_allclose(xa.get_cov(), xb.get_cov(), rtol=0, atol=1e-9)
        np.testing.assert_allclose(ra.get_state(), rb.get_state(), rtol=0, atol=1e-9)
        np.testing.assert_allclose(xa.get_control(), xb.get_control(), rtol=0, atol=1e-9)
        np.testing.assert_allclose(ra.get_observation(), rb.get_observation(), rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def light_dark_case():
    problem = light_dark(deadline=60, hold=40)
    return problem, detour_plan(problem)


@pytest.mark.parametrize("start", ["fixed", "prior"])
def test_batched_is_the_serial_loop_on_the_listing(light_dark_case, start):
    problem, plan = light_dark_case
    x0 = LIGHT_DARK_REAL_INITIAL_STATE if start == "fixed" else None
    args = (problem, plan, light_dark_real_system(), x0)
    kw = {"runs": 40, "seed": 3, "executor": "serial", "keep_trajectories": 5}
    assert_same_reports(validate(*args, **kw), validate(*args, **kw, batched=False))


def test_batched_is_the_serial_loop_with_a_noise_function_of_one_state():
    """The listing's own lambda cannot take a batch: it is called per run, with the same result."""
    problem = light_dark(deadline=60, hold=40)
    paper = problem.switched_system.mode(0)
    lam = stl.mk_lbs(
        A=paper.A,
        B=paper.B,
        W=paper.W,
        C=paper.C,
        V=lambda x: ((1 / 10) * (5 - x[0]) ** 2 + 0.001) * np.identity(2),
    )
    problem = stl.Problem(
        switched_system=stl.mk_switched_sys([lam]),
        control_domain=problem.control_domain,
        initial_state=problem.initial_state,
        stl_formula=problem.stl_formula,
    )
    plan = detour_plan(problem)
    args = (problem, plan, light_dark_real_system(), None)
    kw = {"runs": 12, "seed": 1, "executor": "serial", "keep_trajectories": 2}
    batched = validate(*args, **kw)
    assert lam._batch is False  # tried once, refused, then one call per state
    assert_same_reports(batched, validate(*args, **kw, batched=False))


def test_batched_is_the_serial_loop_with_two_modes_process_noise_and_clipping():
    """Constant noise (shared covariances), a blind mode, process noise, inputs clipped."""
    problem = load_problem(TWO_MODES).build().problem
    modes = np.array([1, 1, 0, 0, 1, 1, 1, 0, 0, 0, 1, 1, 0, 0])
    controls = np.tile([1.0, 1.0], (len(modes), 1))
    plan = stl.rollout(problem.switched_system, problem.initial_state, modes, controls)
    real = stl.mk_switched_sys(
        [stl.mk_lcs(A=1.01 * np.eye(2), B=0.12 * np.eye(2)), stl.mk_lcs(A=np.eye(2), B=0.45 * np.eye(2))]
    )
    for process_noise in ("model", "real", "none"):
        args = (problem, plan, real, None)
        kw = {
            "runs": 30,
            "seed": 7,
            "executor": "serial",
            "keep_trajectories": 3,
            "process_noise": process_noise,
        }
        batched = validate(*args, **kw)
        assert_same_reports(batched, validate(*args, **kw, batched=False))
    assert 0 < batched.belief_successes < 30 or 0 < batched.state_successes < 30  # not a trivial case


def test_batched_reports_do_not_depend_on_workers_or_batch_size(light_dark_case, monkeypatch):
    problem, plan = light_dark_case
    args = (problem, plan, light_dark_real_system(), None)
    serial = validate(*args, runs=30, seed=2, executor="serial")
    with ThreadPoolExecutor(2) as pool:
        assert validate(*args, runs=30, seed=2, executor=pool) == serial
    factory = functools.partial(light_dark, 60, 40)
    with ProcessPoolExecutor(2) as procs:
        assert validate(*args, runs=30, seed=2, executor=procs, problem_factory=factory) == serial
    assert validate(*args, runs=30, seed=2) == serial  # few runs: in-process by default
    from idstlpy.execution import validation

    monkeypatch.setattr(validation, "BATCH_RUNS", 7)  # many small batches, the same runs
    assert validate(*args, runs=30, seed=2, executor="serial") == serial


def test_progress_is_reported(light_dark_case, caplog):
    problem, plan = light_dark_case
    seen = []
    caplog.set_level(logging.INFO, logger="idstlpy")
    validate(
        problem,
        plan,
        light_dark_real_system(),
        runs=20,
        seed=0,
        executor="serial",
        max_workers=2,
        progress=lambda done, total: seen.append((done, total)),
    )
    assert seen and seen[-1] == (20, 20)
    assert all(b[0] > a[0] for a, b in zip(seen, seen[1:], strict=False))
    assert any("validate: 20/20 runs" in r.getMessage() for r in caplog.records)  # the CLI shows it
    with pytest.raises(InvalidTypeError, match="batched"):
        validate(problem, plan, light_dark_real_system(), runs=2, executor="serial", batched=1)


# ------------------------------------------------------------------------------------------------
# the parts: batched noise, batched Kalman update, batched monitor
# ------------------------------------------------------------------------------------------------


def test_noise_batch_takes_a_batch_function_once_and_checks_it():
    mode = stl.mk_lbs(A=np.eye(2), B=np.eye(2), W=np.zeros((2, 2)), C=np.eye(2), V=light_dark_noise)
    X = np.random.default_rng(0).normal(size=(9, 2))
    out = mode.noise_batch(X)
    assert mode._batch is True and out.shape == (9, 2, 2)
    np.testing.assert_array_equal(out, np.stack([mode.noise(x) for x in X]))
    R = mode.noise_cov_batch(X)
    np.testing.assert_allclose(R, np.stack([mode.noise_cov(x) for x in X]), rtol=1e-15)
    # a function giving a batch of the wrong values is refused and called per state
    liar = stl.mk_lbs(
        A=np.eye(2),
        B=np.eye(2),
        W=np.zeros((2, 2)),
        C=np.eye(2),
        V=lambda x: np.ones((len(x), 2, 2)) if np.ndim(x) == 2 else np.eye(2) * (1 + x[0] ** 2),
    )
    np.testing.assert_array_equal(liar.noise_batch(X), np.stack([liar.noise(x) for x in X]))
    assert liar._batch is False
    # constant noise: one matrix for every state
    const = stl.mk_lbs(A=np.eye(2), B=np.eye(2), W=np.zeros((2, 2)), C=np.eye(2), V=0.3 * np.eye(2))
    np.testing.assert_array_equal(const.noise_batch(X), np.broadcast_to(0.3 * np.eye(2), (9, 2, 2)))
    # a bad value inside a batch raises the per-state error naming the function
    bad = stl.mk_lbs(
        A=np.eye(2),
        B=np.eye(2),
        W=np.zeros((2, 2)),
        C=np.eye(2),
        V=lambda x: np.where(np.asarray(x)[..., 0:1, None] > 5, np.inf, 1.0) * np.ones((2, 2)),
    )
    with pytest.raises(NoiseFunctionError, match="noise function V"):
        bad.noise_cov_batch(np.array([[0.0, 0.0], [6.0, 0.0], [1.0, 1.0]]))


@pytest.mark.parametrize("p", [1, 2, 3])
def test_kalman_update_batch_is_the_update_per_run(p):
    rng = np.random.default_rng(p)
    n, S = 3, 25
    C = rng.normal(size=(p, n))
    mode = stl.mk_lbs(
        A=np.eye(n),
        B=np.eye(n),
        W=np.zeros((n, n)),
        C=C,
        V=lambda x: (
            (0.2 + x[..., :1, None] ** 2) * np.eye(p) if np.ndim(x) == 2 else (0.2 + x[0] ** 2) * np.eye(p)
        ),
    )
    means = rng.normal(size=(S, n))
    G = rng.normal(size=(S, n, n))
    P = G @ np.swapaxes(G, 1, 2)
    P[0] = 0.0  # a (nearly) singular innovation covariance: the per-run fallback
    Y = rng.normal(size=(S, p))
    m_b, c_b = kalman_update_batch(mode, means, P, Y)
    for i in range(S):
        m_1, c_1 = kalman_update(mode, means[i], P[i], y=Y[i], x_noise=means[i])
        np.testing.assert_allclose(m_b[i], m_1, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(c_b[i], c_1, rtol=1e-10, atol=1e-12)


def _until_ref(r1, r2, a, b):
    """The monitor's definition, one index at a time (strong reading: past the end is -inf)."""
    L = len(r1)
    out = np.full(L, -np.inf)
    for k in range(L):
        for d in range(a, b + 1):
            if k + d >= L:
                break
            out[k] = max(out[k], min([r2[k + d], *r1[k + a : k + d]]))
    return out


def _release_ref(r1, r2, a, b):
    L = len(r1)
    out = np.full(L, -np.inf)
    for k in range(L):
        window = [r2[k + d] if k + d < L else -np.inf for d in range(a, b + 1)]
        best = min(window)
        for j, d in enumerate(range(a, b + 1)):
            first = r1[k + d] if k + d < L else -np.inf
            best = max(best, min(first, *window[: j + 1]))
        out[k] = best
    return out


def test_until_and_release_are_their_definitions_on_traces_and_batches():
    rng = np.random.default_rng(0)
    for L in (1, 2, 5, 12):
        for a, b in ((0, 0), (0, 3), (1, 4), (2, 20), (5, 7)):
            R1, R2 = rng.normal(size=(L, 3)), rng.normal(size=(L, 3))
            R1[rng.random((L, 3)) < 0.2] = np.inf
            R2[rng.random((L, 3)) < 0.2] = -np.inf
            U = semantics._until(R1, R2, a, b)
            Rl = semantics._release(R1, R2, a, b)
            for j in range(3):
                np.testing.assert_array_equal(U[:, j], _until_ref(R1[:, j], R2[:, j], a, b))
                np.testing.assert_array_equal(U[:, j], semantics._until(R1[:, j], R2[:, j], a, b))
                np.testing.assert_array_equal(Rl[:, j], _release_ref(R1[:, j], R2[:, j], a, b))


def test_batched_is_the_serial_loop_with_mode_atoms_and_a_joint_constraint():
    """Mode predicates (``q == 0``) and a joint chance constraint (the monitor's joint_slack)."""
    system = load_problem(TWO_MODES).build().problem
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    q = stl.mk_variable(size=1, dtype=int)
    region = stl.logical_and(x[0] >= 2.0, x[0] <= 6.0, x[1] >= 2.0, x[1] <= 6.0)
    goal = stl.logical_and(q == 0, stl.prob_in(region) >= 0.8, name="goal")
    safe = stl.logical_and(stl.prob(x[0] <= 8.0) >= 0.95, stl.prob(x[1] >= -3.0) >= 0.95, name="safe")
    formula = stl.logical_and(stl.eventually(0, 13, goal), stl.always(0, 13, safe))
    problem = stl.Problem(
        switched_system=system.switched_system,
        control_domain=stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region,
        initial_state=system.initial_state,
        stl_formula=formula,
    )
    modes = np.array([1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0])
    plan = stl.rollout(problem.switched_system, problem.initial_state, modes, np.tile([1.0, 1.0], (13, 1)))
    args = (problem, plan, None, None)
    kw = {"runs": 40, "seed": 5, "executor": "serial", "keep_trajectories": 2}
    batched = validate(*args, **kw)
    assert_same_reports(batched, validate(*args, **kw, batched=False))
    assert 0 < batched.belief_successes < 40 or 0 < batched.state_successes < 40  # not a trivial case


def test_montecarlo_benchmark_runs_small(capsys):
    from benchmarks import montecarlo

    assert montecarlo.main(["--runs", "24", "--serial-runs", "12", "--repeats", "1"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith(("| listing", "| constant"))]
    assert len(rows) == 3 and all(row.endswith("| yes |") for row in rows)


@pytest.mark.parametrize("steps", [0, 1, 30])
def test_batched_is_the_serial_loop_on_part_of_the_plan(light_dark_case, steps):
    problem, plan = light_dark_case
    kw = {"runs": 10, "seed": 0, "executor": "serial", "num_of_steps": steps, "keep_trajectories": 2}
    batched = validate(problem, plan, light_dark_real_system(), **kw)
    assert batched.num_of_steps == steps
    assert_same_reports(batched, validate(problem, plan, light_dark_real_system(), batched=False, **kw))
