"""The covariance floor over every switching sequence (issue 24): its soundness and its proofs.

Every floor is re-checked by brute force (:mod:`tests.oracles.sensing`): all mode sequences of a
few steps are enumerated and their exact covariances must lie above the floor (Loewner order).
"""

from __future__ import annotations

import numpy as np
import pytest
from tests.oracles import sensing as oracle

import idstlpy as stl
from idstlpy.synthesis.covariance_floor import covariance_floor


def _random_modes(rng: np.random.Generator, n: int, num: int, blind: bool, state_dep: bool):
    A = np.eye(n) + 0.3 * rng.standard_normal((n, n))
    modes = []
    for q in range(num):
        W = 0.3 * rng.standard_normal((n, n)) if rng.random() < 0.8 else np.zeros((n, n))
        B = rng.standard_normal((n, 1))
        if blind and q == 0:
            modes.append(stl.mk_lbs(A=A, B=B, W=W))
            continue
        p = int(rng.integers(1, n + 1))
        C = rng.standard_normal((p, n))
        if state_dep and q == num - 1:
            base = 0.2 + rng.random()

            def V(x, base=base, p=p):
                return (base + 0.3 * float(x[0]) ** 2) * np.eye(p)

            modes.append(stl.mk_lbs(A=A, B=B, W=W, C=C, V=V, V_floor=base))
        else:
            V = 0.2 * rng.standard_normal((p, p)) + 0.5 * np.eye(p)
            modes.append(stl.mk_lbs(A=A, B=B, W=W, C=C, V=V))
    return modes


@pytest.mark.parametrize("seed", range(8))
def test_floor_is_below_every_sequence(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 4))
    num = int(rng.integers(2, 4))
    modes = _random_modes(rng, n, num, blind=seed % 2 == 0, state_dep=seed % 3 == 0)
    X = rng.standard_normal((n, n))
    cov0 = X @ X.T + 0.1 * np.eye(n)
    length = 6 if num == 2 else 4
    floor = covariance_floor(modes, cov0, length)
    assert floor is not None
    draws = rng.standard_normal((length, n)) * 3.0

    def R_of(k, q):
        mode = modes[q]
        if mode.has_state_dependent_noise:
            v = np.asarray(mode.V(draws[k]))
            return v @ v.T
        return np.asarray(mode.V) @ np.asarray(mode.V).T

    gap = oracle.floor_gap(modes, cov0, floor.covs, length, R_of)
    assert gap >= -1e-9 * (1 + np.abs(floor.covs).max())


def test_no_floor_claimed_when_A_differ_or_a_sensor_is_perfect():
    a = stl.mk_lbs(A=np.eye(2), B=np.eye(2), W=0.1 * np.eye(2))
    b = stl.mk_lbs(A=2 * np.eye(2), B=np.eye(2), W=0.1 * np.eye(2))
    assert covariance_floor([a, b], np.eye(2), 5) is None
    perfect = stl.mk_lbs(A=np.eye(2), B=np.eye(2), W=0.1 * np.eye(2), C=np.eye(2), V=np.zeros((2, 2)))
    assert covariance_floor([a, perfect], np.eye(2), 5) is None
    # a perfect sensor of a direction nobody asks about is no problem when it sees nothing
    blind_dir = stl.mk_lbs(
        A=np.eye(2), B=np.eye(2), W=0.1 * np.eye(2), C=np.array([[1.0, 0.0]]), V=np.array([[0.5]])
    )
    assert covariance_floor([a, blind_dir], np.eye(2), 5) is not None


def _two_mode_floor_problem(v_drive=0.6, v_look=0.4, w=0.1, hold=5):
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float)
    drive = stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=w * np.eye(2), C=np.eye(2), V=v_drive * np.eye(2))
    look = stl.mk_lbs(A=np.eye(2), B=np.zeros((2, 2)), W=w * np.eye(2), C=np.eye(2), V=v_look * np.eye(2))

    def box(lo, hi, conf, name):
        return stl.logical_and(
            *[stl.prob(x[i] >= lo[i]) >= conf for i in range(2)],
            *[stl.prob(x[i] <= hi[i]) >= conf for i in range(2)],
            name=name,
        )

    safe = box([-1, -1], [5, 5], 0.99, "safe")
    goal = box([2.8, 2.8], [3.2, 3.2], 0.95, "goal")
    return stl.Problem(
        stl.mk_switched_sys([drive, look]),
        stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region,
        stl.to_belief(mean=np.zeros(2), cov=0.1 * np.eye(2)),
        stl.until(safe, 0, 40, stl.always(0, hold, goal)),
    )


def test_two_mode_noise_floor_is_proven_infeasible_naming_the_proposition():
    problem = _two_mode_floor_problem()
    result = problem.solve_result(rrt_timeout=60, seed=0, time_limit=30)
    assert result.status == "infeasible"
    assert "goal" in result.reason and "every mode sequence" in result.reason
    assert result.stats.candidates == 0  # the proof needs no candidate at all

    # Independent re-check: enumerate every sequence of 10 steps; no step of any sequence has a
    # variance small enough for the goal at 95% (sd <= 0.2 / 1.645 on each axis, at the centre).
    modes = problem.switched_system.system_modes
    cov0 = problem.initial_state.cov
    need = (0.2 / 1.6448536269514722) ** 2
    best = np.inf
    for seq in oracle.all_sequences(2, 10):
        covs = oracle.schedule(modes, cov0, seq)
        best = min(best, float(covs[1:, 0, 0].min()), float(covs[1:, 1, 1].min()))
    assert best > need


def test_feasible_two_mode_problem_is_not_claimed_out_of_reach():
    # A precise look (V = 0.01) reaches the goal's confidence: no floor claim, a plan is found.
    problem = _two_mode_floor_problem(v_drive=0.5, v_look=0.01, w=0.0, hold=0)
    result = problem.solve_result(rrt_timeout=60, seed=0, time_limit=60, max_candidates=400, guarantee="mlo")
    assert result.status == "found"
    assert stl.robustness(result.trajectory, problem.stl_formula) >= 0
