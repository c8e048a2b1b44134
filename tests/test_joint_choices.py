"""The joint MILP of multi-mode plans (issue 31): its lower-bound tables, its proofs and plans.

Small horizons; every ``infeasible`` is re-checked by brute force over every mode sequence
(``tests/oracles/joint_modes.py``), every plan by the independent roll-out and monitor.
"""

from __future__ import annotations

import itertools
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tests.oracles.brute_force import sat
from tests.oracles.joint_modes import goal_reachable
from tests.oracles.rollout import ModeSpec, mlo_rollout

import idstlpy as stl
from idstlpy.synthesis.covariances import covariance_schedule
from idstlpy.synthesis.joint_milp import CovarianceTables, run_ladder


def _specs(problem: stl.Problem) -> list[ModeSpec]:
    out = []
    for mode in problem.switched_system.system_modes:
        C = None if mode.p == 0 else np.asarray(mode.C)
        V = None if C is None else np.asarray(mode.V)
        out.append(ModeSpec(np.asarray(mode.A), np.asarray(mode.B), np.asarray(mode.W), C, V))
    return out


def _oracle_holds(problem: stl.Problem, traj: stl.ProbabilisticTSTrajectory) -> bool:
    actions = np.asarray(traj.get_action(), dtype=int)
    controls = np.asarray(traj.get_control(), dtype=float).reshape(len(actions), -1)
    init = problem.initial_state
    trace = mlo_rollout(_specs(problem), init.mean, init.cov, list(actions), controls)
    return bool(sat(problem.stl_formula, 0, trace))


def _look_or_move(distance: int, deadline: int, gap: int | None = None, looks_needed: int = 1) -> stl.Problem:
    """A 1-D robot: move (``|u| <= 1``, blind) or stop and look; the goal ``distance`` away.

    ``looks_needed = 2``: the goal's precision needs two looks (``V`` larger); ``gap``: a camera
    duty cycle ``G(move | G[1, gap] move)`` on the mode variable.
    """
    x = stl.mk_variable(size=1, dtype=float)
    u = stl.mk_variable(size=1, dtype=float, name="u")
    q = stl.mk_variable(size=2, dtype=int)
    v = 0.01 if looks_needed == 1 else 0.15
    move = stl.mk_lbs(A=np.eye(1), B=np.eye(1), W=0.01 * np.eye(1))
    look = stl.mk_lbs(A=np.eye(1), B=np.zeros((1, 1)), W=0.01 * np.eye(1), C=np.eye(1), V=v * np.eye(1))
    goal = stl.logical_and(
        stl.prob(x[0] >= distance - 0.15) >= 0.95, stl.prob(x[0] <= distance + 0.15) >= 0.95, name="goal"
    )
    formula = stl.eventually(0, deadline, goal)
    if gap is not None:
        cycle = stl.logical_or(q == 0, stl.always(1, gap, q == 0))
        formula = stl.until(cycle, 0, deadline, stl.logical_and(goal, cycle))
    U = stl.logical_and(u[0] >= -1, u[0] <= 1).region
    return stl.Problem(
        stl.mk_switched_sys([move, look]),
        U,
        stl.to_belief(mean=np.zeros(1), cov=np.eye(1)),
        formula,
    )


def _goal_oracle(problem: stl.Problem, deadline: int, distance: int) -> list[int] | None:
    init = problem.initial_state
    goal = [(np.array([-1.0]), distance - 0.15, 0.05), (np.array([1.0]), -(distance + 0.15), 0.05)]
    U = (np.array([[1.0], [-1.0]]), np.array([-1.0, -1.0]))
    return goal_reachable(_specs(problem), init.mean, init.cov, U, goal, deadline)


def _solve(problem: stl.Problem, **kw: object) -> stl.SolveResult:
    # lazy_candidates = 0: the joint MILP takes over at once (the default waits 20 candidates)
    options: dict[str, object] = {"seed": 0, "time_limit": 60.0, "lazy_candidates": 0, **kw}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a plan below the execution target is in its result
        return problem.solve_result(**options)


@pytest.mark.parametrize(("distance", "deadline"), [(2, 2), (3, 3), (2, 1)])
def test_no_time_to_look_and_move_is_proven_by_the_joint_milp(distance: int, deadline: int) -> None:
    problem = _look_or_move(distance, deadline)
    result = _solve(problem)
    assert result.status == "infeasible"
    assert "joint MILP" in result.reason or result.stats.milp_calls == 0
    assert _goal_oracle(problem, deadline, distance) is None  # brute force agrees


@pytest.mark.parametrize(("distance", "deadline"), [(2, 3), (3, 4)])
def test_time_to_look_and_move_gives_a_verified_plan(distance: int, deadline: int) -> None:
    problem = _look_or_move(distance, deadline)
    witness = _goal_oracle(problem, deadline, distance)
    assert witness is not None and 1 in witness  # a look is needed and fits
    result = _solve(problem)
    assert result.status == "found"
    assert result.stats.milp_calls >= 1
    assert _oracle_holds(problem, result.trajectory)
    assert 1 in np.asarray(result.trajectory.get_action()).tolist()


def test_duty_cycle_on_the_mode_variable_is_a_constraint_of_the_model() -> None:
    gap = 2
    problem = _look_or_move(1, 8, gap=gap, looks_needed=2)
    result = _solve(problem)
    assert result.status == "found"
    assert _oracle_holds(problem, result.trajectory)
    actions = np.asarray(result.trajectory.get_action(), dtype=int).tolist()
    looks = [k for k, a in enumerate(actions) if a == 1]
    assert len(looks) >= 2  # one look is not precise enough
    assert all(b - a > gap for a, b in itertools.pairwise(looks))


def test_mlo_guarantee_never_uses_the_joint_milp() -> None:
    problem = _look_or_move(3, 4)
    result = _solve(problem, guarantee="mlo")
    assert result.stats.milp_calls == 0


def _random_modes(draw: st.DrawFn) -> list[object]:
    n = draw(st.integers(1, 2))
    A = np.eye(n) * draw(st.floats(0.8, 1.1))
    modes = []
    for q in range(draw(st.integers(2, 3))):
        W = draw(st.floats(0.01, 0.3)) * np.eye(n)
        if q == 0 or draw(st.booleans()):
            modes.append(stl.mk_lbs(A=A, B=np.eye(n), W=W))
        else:
            V = draw(st.sampled_from([0.0, 0.05, 0.3, 1.0])) * np.eye(n)  # 0: a noise-free sensor
            modes.append(stl.mk_lbs(A=A, B=np.eye(n), W=W, C=np.eye(n), V=V))
    return modes


@st.composite
def _tables_case(draw: st.DrawFn) -> tuple[list[object], np.ndarray, list[int]]:
    modes = _random_modes(draw)
    n = modes[0].A.shape[0]
    cov0 = draw(st.floats(0.01, 2.0)) * np.eye(n)
    seq = draw(st.lists(st.integers(0, len(modes) - 1), min_size=1, max_size=9))
    return modes, cov0, seq


@settings(max_examples=40, deadline=None)
@given(_tables_case())
def test_pattern_tables_bound_every_sequence_from_below(
    case: tuple[list[object], np.ndarray, list[int]],
) -> None:
    modes, cov0, seq = case
    H = len(seq)
    tables = CovarianceTables(modes, cov0, H)
    actions = np.asarray(seq)
    exact, _ = covariance_schedule(modes, cov0, actions)
    for k in range(1, H + 1):
        assert np.linalg.eigvalsh(exact[k] - tables.lows[k]).min() >= -1e-9
        for j in range(1, k + 1):  # every suffix pattern, from the lower-bound prior before it
            low = tables.cov(k, tuple(int(a) for a in seq[k - j : k]))
            assert np.linalg.eigvalsh(exact[k] - low).min() >= -1e-9
        assert np.allclose(tables.cov(k, tuple(seq[:k])), exact[k], atol=1e-9)  # the full prefix is exact
        w, covs = tables.full(k)
        index = sum(int(q) * len(modes) ** (w - 1 - i) for i, q in enumerate(seq[k - w : k]))
        assert np.linalg.eigvalsh(exact[k] - covs[index]).min() >= -1e-9
        for q in range(len(modes)):
            for r, runs in tables.runs(q).items():
                if r <= k and all(a == q for a in seq[k - r : k]):
                    assert np.linalg.eigvalsh(exact[k] - runs[k - r]).min() >= -1e-9


def test_run_ladder_is_increasing_and_within_the_horizon() -> None:
    for window, H in ((5, 70), (3, 10), (1, 4)):
        ladder = run_ladder(window, H)
        assert ladder == sorted(set(ladder))
        assert all(window < r <= H for r in ladder)


def test_a_proposer_dry_only_on_set_aside_candidates_hands_over_to_the_joint_milp() -> None:
    # default lazy_candidates: the lazy loop runs first; its mode search sets the requirement
    # sets aside (no proof), and the joint MILP then proves what the loop could not
    problem = _look_or_move(3, 3)
    result = _solve(problem, lazy_candidates=10)
    assert result.status == "infeasible"
    assert 0 < result.stats.candidates < 20
    assert result.stats.milp_calls >= 1
    assert _goal_oracle(problem, 3, 3) is None
