"""``objective="margin"`` against an independently built optimum (brute force over discrete choices).

The problems are small: a planar single integrator ``x' = x + u``, ``|u_i| <= 1``, ``x0 = 0``,
horizon 3, formulas that are conjunctions of "some box at some step" choices. Their robustness
is ``max`` over one choice per conjunct of the ``min`` of the chosen boxes' slacks, so the optimum
is the best of a handful of LPs (maximise ``t`` with every chosen face at least ``t`` inside),
built here with :func:`scipy.optimize.linprog` and nothing of idstlpy's. Two shapes are covered:
the margin MILP's cap attained (a goal's centre reachable: the feasibility probe decides) and not
attained (two goals that the dynamics cannot both centre: the ladder of probes decides, each rung a
feasibility MILP at the best plan's exact margin, the last one refuted). A third
test checks the benchmark translation's hard state box against the same brute force with the box
as hard rows.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from benchmarks.stlpy_translate import make_problem
from scipy.optimize import linprog

import idstlpy as stl
from idstlpy import prob as P

H = 3
Box = tuple[float, float, float, float]  # x_lo, x_hi, y_lo, y_hi


def _brute_force(conjuncts: list[list[tuple[Box, int]]], hard: Box | None = None) -> float:
    """Largest ``t`` over one ``(box, step)`` per conjunct, every chosen face ``t`` inside.

    Variables ``u_0..u_{H-1}`` (2 each) and ``t``; ``x_k = sum_{j<k} u_j``. ``hard`` is a box
    every ``x_k`` must lie in, with no ``t``.
    """
    nu = 2 * H
    best = -np.inf
    for choice in itertools.product(*conjuncts):
        A_ub, b_ub = [], []

        def face(k: int, dim: int, sign: float, level: float, with_t: bool, rows=A_ub, rhs=b_ub) -> None:
            # sign * (x_k[dim] - level) >= t  ->  -sign * sum u_j[dim] + t <= -sign * level
            row = np.zeros(nu + 1)
            for j in range(k):
                row[2 * j + dim] = -sign
            row[nu] = 1.0 if with_t else 0.0
            rows.append(row)
            rhs.append(-sign * level)

        for (x_lo, x_hi, y_lo, y_hi), k in choice:
            face(k, 0, 1.0, x_lo, True)
            face(k, 0, -1.0, x_hi, True)
            face(k, 1, 1.0, y_lo, True)
            face(k, 1, -1.0, y_hi, True)
        if hard is not None:
            for k in range(1, H + 1):
                face(k, 0, 1.0, hard[0], False)
                face(k, 0, -1.0, hard[1], False)
                face(k, 1, 1.0, hard[2], False)
                face(k, 1, -1.0, hard[3], False)
        c = np.zeros(nu + 1)
        c[nu] = -1.0
        res = linprog(
            c, A_ub=np.array(A_ub), b_ub=b_ub, bounds=[(-1, 1)] * nu + [(None, 10.0)], method="highs"
        )
        if res.status == 0:
            best = max(best, -res.fun)
    return float(best)


def _box_ap(x, box: Box, name: str):
    x_lo, x_hi, y_lo, y_hi = box
    return stl.logical_and(
        P(x[0] >= x_lo) >= 0.9,
        P(x[0] <= x_hi) >= 0.9,
        P(x[1] >= y_lo) >= 0.9,
        P(x[1] <= y_hi) >= 0.9,
        name=name,
    )


def _problem(formula_of):
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    mode = stl.mk_lbs(np.eye(2), np.eye(2), np.zeros((2, 2)))
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    return stl.Problem(
        stl.mk_switched_sys([mode]), domain, stl.to_belief([0.0, 0.0], np.zeros((2, 2))), formula_of(x)
    )


GOAL_A: Box = (2.0, 3.0, -0.5, 0.5)  # centre (2.5, 0) reachable at step 3: margin 0.5
GOAL_B: Box = (-1.6, -1.0, 1.0, 1.6)  # centre (-1.3, 1.3): margin 0.3 from step 2 on
NEAR_B: Box = (-1.0, -0.4, 0.4, 1.0)  # centre (-0.7, 0.7) reachable at step 1: margin 0.3
FAR_A: Box = (1.2, 2.2, -0.4, 0.4)  # centre (1.7, 0): margin 0.4, but not two steps after B


def _cap_attained(x):
    """(F[1,3] A | F[1,3] B) & G[0,3] x_1 <= 0.8: the optimum 0.5 is A's centre."""
    return stl.logical_and(
        stl.logical_or(
            stl.eventually(1, 3, _box_ap(x, GOAL_A, "A")), stl.eventually(1, 3, _box_ap(x, GOAL_B, "B"))
        ),
        stl.always(0, 3, stl.logical_and(P(x[1] <= 0.8) >= 0.9, name="free")),
    )


def _cap_not_attained(x):
    """F[1,2] B' & F[3,3] A': B' (left) then A' (right); the dynamics trade one margin for the other.

    Only B' at step 1 leaves time to reach A' (x_3 <= x_1 + 2): margins x_1 + 0.8 (A') and
    -0.4 - x_1 (B'), best at x_1 = -0.6: 0.2, below both propositions' own bounds (0.3, 0.4).
    """
    return stl.logical_and(
        stl.eventually(1, 2, _box_ap(x, NEAR_B, "B")), stl.eventually(3, 3, _box_ap(x, FAR_A, "A"))
    )


CASES = {
    "cap attained": (
        _cap_attained,
        # The free half-plane holds at every step: t <= 0.8 - y_k is a conjunct per step.
        lambda: _brute_force_with_half_plane(
            [[(GOAL_A, k) for k in (1, 2, 3)] + [(GOAL_B, k) for k in (1, 2, 3)]]
        ),
    ),
    "cap not attained": (
        _cap_not_attained,
        lambda: _brute_force([[(NEAR_B, k) for k in (1, 2)], [(FAR_A, 3)]]),
    ),
}


def _brute_force_with_half_plane(conjuncts: list[list[tuple[Box, int]]]) -> float:
    """As :func:`_brute_force`, with ``y_k <= 0.8`` at every step as a margin face (a box open
    on three sides: its other faces are far enough never to bind)."""
    far = 1e3
    half = (-far, far, -far, 0.8)
    per_step = [[(half, k)] for k in range(1, H + 1)]
    # Step 0: y_0 = 0 leaves slack 0.8, a constant bound on t.
    return min(_brute_force(conjuncts + per_step), 0.8)


@pytest.mark.parametrize("case", sorted(CASES))
def test_margin_optimum_matches_brute_force(case):
    formula_of, brute = CASES[case]
    problem = _problem(formula_of)
    result = problem.solve_result(seed=0, objective="margin")
    expected = brute()
    assert result.status == "found"
    assert result.optimal and result.optimal_scope == "horizon"
    assert result.objective_value == pytest.approx(expected, abs=1e-6)
    assert stl.robustness(result.trajectory, problem.stl_formula) == pytest.approx(expected, abs=1e-6)
    # The bound is a bound, and it meets the value at a proven optimum.
    assert result.objective_bound >= result.objective_value - 1e-9
    assert result.objective_bound == pytest.approx(expected, abs=1e-6)


@pytest.mark.parametrize("backend", ["highs", "scip"])
def test_margin_optimum_is_the_same_on_every_milp_backend(backend):
    pytest.importorskip("pyscipopt") if backend == "scip" else None
    problem = _problem(_cap_not_attained)
    result = problem.solve_result(seed=0, objective="margin", milp_backend=backend)
    assert result.optimal
    assert result.objective_value == pytest.approx(CASES["cap not attained"][1](), abs=1e-6)


def test_no_random_plan_beats_the_reported_bound():
    problem = _problem(_cap_not_attained)
    result = problem.solve_result(seed=0, objective="margin")
    rng = np.random.default_rng(0)
    system, init = problem.switched_system, problem.initial_state
    best = -np.inf
    for _ in range(300):
        controls = rng.uniform(-1, 1, size=(H, 2))
        traj = stl.rollout(system, init, np.zeros(H, dtype=int), controls)
        best = max(best, stl.robustness(traj, problem.stl_formula))
    assert best <= result.objective_bound + 1e-9
    assert best <= result.objective_value + 1e-9


class _Pred:
    """stlpy's ``LinearPredicate`` as the translator reads it: ``a' y - b >= 0``."""

    def __init__(self, a, b):
        self.a = np.asarray(a, dtype=float).reshape((-1, 1))
        self.b = np.array([float(b)])


class _Tree:
    def __init__(self, subs, kind, ts):
        self.subformula_list, self.combination_type, self.timesteps = subs, kind, ts


def _stlpy_box(box: Box) -> _Tree:
    x_lo, x_hi, y_lo, y_hi = box
    preds = [_Pred([1, 0], x_lo), _Pred([-1, 0], -x_hi), _Pred([0, 1], y_lo), _Pred([0, -1], -y_hi)]
    return _Tree(preds, "and", [0, 0, 0, 0])


@pytest.mark.parametrize(("x_hi", "optimum"), [(2.6, 0.5), (2.4, 0.4)])
def test_hard_state_box_is_a_constraint_not_part_of_the_margin(x_hi, optimum):
    """stlpy's robustness mode: the box is hard, rho is the specification's alone.

    With ``x_0 <= 2.6`` the goal's centre (2.5, 0) is inside the box (optimum 0.5; counted in the
    margin, the box would give 0.3, halfway between the goal's left face and the box's); with
    ``x_0 <= 2.4`` the best plan sits on the box's face (optimum 0.4; counted: 0.2).
    """
    goal = _stlpy_box(GOAL_A)
    spec = _Tree([goal, goal, goal], "or", [1, 2, 3])  # F[1,3] goal
    box = (-5.0, x_hi, -5.0, 5.0)
    assert _brute_force([[(GOAL_A, k) for k in (1, 2, 3)]], hard=box) == pytest.approx(optimum, abs=1e-9)
    x_lo, x_hi_, y_lo, y_hi = box
    args = (spec, np.eye(2), np.eye(2), np.eye(2), np.zeros((2, 2)), [0.0, 0.0], [-1, -1], [1, 1], H)
    bounds = ([x_lo, y_lo], [x_hi_, y_hi])
    problem, tr = make_problem(*args, *bounds, hard_box=True)
    result = problem.solve_result(seed=0, objective="margin")
    assert result.status == "found" and result.optimal
    rho = stl.robustness(result.trajectory, tr(spec))
    assert rho == pytest.approx(optimum, abs=1e-6)
    means = result.trajectory.get_mean()
    assert np.all(means[:, 0] <= x_hi) and np.all(means[:, 0] >= x_lo)
    # Counted in the margin (the feasibility benchmark's translation), the box caps rho.
    soft, tr_soft = make_problem(*args, *bounds)
    soft_result = soft.solve_result(seed=0, objective="margin")
    assert stl.robustness(soft_result.trajectory, soft.stl_formula) == pytest.approx(
        min(optimum, (x_hi - GOAL_A[0]) / 2), abs=1e-6
    )


@pytest.mark.parametrize("backend", ["highs", "scip"])
def test_margin_optimisation_after_the_ladder_is_still_a_proof(monkeypatch, backend):
    # No rung after the first plan: the optimisation above its level decides (and refutes it).
    pytest.importorskip("pyscipopt") if backend == "scip" else None
    from idstlpy.synthesis import milp_solve

    monkeypatch.setattr(milp_solve, "_LADDER_RUNGS", 0)
    problem = _problem(_cap_not_attained)
    result = problem.solve_result(seed=0, objective="margin", milp_backend=backend)
    expected = CASES["cap not attained"][1]()
    assert result.optimal and result.objective_value == pytest.approx(expected, abs=1e-6)
    assert expected - 1e-9 <= result.objective_bound <= expected + 1e-6
