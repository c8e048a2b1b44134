"""The benchmark's stlpy translation and its PrSTL MILP peer, tested without stlpy installed.

``_Pred`` / ``_Tree`` below reproduce stlpy 0.3's data model and its expansions of ``always``,
``eventually`` and ``until`` (``stlpy/STL/formula.py``) line for line, so the translator sees
exactly the trees stlpy builds. With zero covariance idstlpy's margin of a translated formula
must equal stlpy's robustness, not just agree in sign.
"""

from __future__ import annotations

import numpy as np
import pytest
from benchmarks.prstl_milp import noisy_reach_avoid, solve_prstl_milp
from benchmarks.stlpy_translate import (
    Translator,
    UntranslatableError,
    make_problem,
    stlpy_robustness_reference,
)

import idstlpy as I


class _Formula:
    def __and__(self, other):
        return _Tree([self, other], "and", [0, 0])

    def __or__(self, other):
        return _Tree([self, other], "or", [0, 0])

    def always(self, t1, t2):
        ts = list(range(t1, t2 + 1))
        return _Tree([self for _ in ts], "and", ts)

    def eventually(self, t1, t2):
        ts = list(range(t1, t2 + 1))
        return _Tree([self for _ in ts], "or", ts)

    def until(self, other, t1, t2):
        branches = []
        for tp in range(t1, t2 + 1):
            subs = [self for _ in range(t1, tp)] + [other]
            branches.append(_Tree(subs, "and", list(range(t1, tp + 1))))
        return _Tree(branches, "or", [0 for _ in branches])


class _Pred(_Formula):
    """``a' y - b >= 0``."""

    def __init__(self, a, b):
        self.a = np.asarray(a, dtype=float).reshape((-1, 1))
        self.b = np.atleast_1d(b)


class _Tree(_Formula):
    def __init__(self, subformula_list, combination_type, timesteps):
        self.subformula_list = subformula_list
        self.combination_type = combination_type
        self.timesteps = timesteps


def _inside(bounds, d=6):
    x1, x2, y1, y2 = bounds
    e1, e2 = np.eye(d)[0], np.eye(d)[1]
    return _Pred(e1, x1) & _Pred(-e1, -x2) & _Pred(e2, y1) & _Pred(-e2, -y2)


def _outside(bounds, d=6):
    x1, x2, y1, y2 = bounds
    e1, e2 = np.eye(d)[0], np.eye(d)[1]
    return _Pred(e1, x2) | _Pred(-e1, -x1) | _Pred(e2, y2) | _Pred(-e2, -y1)


def _double_integrator():
    Id, Z = np.eye(2), np.zeros((2, 2))
    A = np.block([[Id, Id], [Z, Id]])
    B = np.block([[Z], [Id]])
    C = np.block([[Id, Z], [Z, Id], [Z, Z]])
    D = np.block([[Z], [Z], [Id]])
    return A, B, C, D


def _specs(T):
    goal, obstacle = (7, 8, 8, 9), (3, 5, 4, 6)
    reach_avoid = _outside(obstacle).always(0, T) & _inside(goal).eventually(0, T)
    door = _outside((0, 10, 3, 4)).until(_inside((1.5, 2.5, 2.2, 3.0)), 0, T)
    dwell = _inside((1, 2, 6, 7)).always(0, 3) | _inside((7, 8, 4.5, 5.5)).always(0, 3)
    either = dwell.eventually(2, T - 3)
    # An irregular tree: children at arbitrary shifts (the translator's fallback).
    irregular = _Tree([_inside(goal), _outside((0, 1.2, 1.5, 2.5)), reach_avoid], "or", [3, 1, 0])
    return {"reach_avoid": reach_avoid, "door": door, "either": either, "irregular": irregular}


def _rollout(A, B, x0, controls):
    xs = [x0]
    for u in controls:
        xs.append(A @ xs[-1] + B @ u)
    return np.array(xs)


@pytest.mark.parametrize("which", ["reach_avoid", "door", "either", "irregular"])
def test_translation_margin_equals_stlpy_robustness(which):
    T = 10
    A, B, C, D = _double_integrator()
    spec = _specs(T)[which]
    tr = Translator(C, D)
    formula = tr(spec)
    rng = np.random.default_rng(0)
    x0 = np.array([1.0, 2.0, 0.0, 0.0])
    outcomes = set()
    for trial in range(40):
        if trial % 2:
            controls = rng.uniform(-0.5, 0.5, size=(T, 2))
        else:  # drift towards the goal so that some trajectories satisfy
            controls = np.clip(rng.normal([0.15, 0.15], 0.2, size=(T, 2)), -0.5, 0.5)
        xs = _rollout(A, B, x0, controls)
        us = np.vstack([controls, np.zeros((1, 2))])
        y = C @ xs.T + D @ us.T
        rho = stlpy_robustness_reference(spec, y, 0)
        covs = np.zeros((T + 1, 4, 4))
        traj = I.ProbabilisticTSTrajectory(xs, covs, np.zeros(T, dtype=int), controls)
        margin = I.robustness(traj, formula)
        assert margin == pytest.approx(rho, abs=1e-9)
        assert I.satisfies(traj, formula) == (rho >= 0)
        outcomes.add(bool(rho >= 0))
    assert False in outcomes  # the comparison is not vacuous


def test_translation_recognises_temporal_shapes():
    A, B, C, D = _double_integrator()
    specs = _specs(12)
    tr = Translator(C, D)
    tr(specs["reach_avoid"])
    assert (tr.stats.always, tr.stats.eventually, tr.stats.shifted) == (1, 1, 0)
    tr = Translator(C, D)
    f = tr(specs["door"])
    assert isinstance(f, I.STLUntil) and (f.a, f.b) == (0, 12)
    tr = Translator(C, D)
    f = tr(specs["either"])
    assert isinstance(f, I.STLUntil) and (f.a, f.b) == (2, 9)  # eventually = true U
    assert tr.stats.always == 2


def test_predicate_on_the_input_is_refused():
    A, B, C, D = _double_integrator()
    reads_u = _Pred(np.eye(6)[4], 0.1)  # y[4] = u[0]
    with pytest.raises(UntranslatableError):
        Translator(C, D)(reads_u.always(0, 3))


def test_make_problem_solves_and_the_plan_satisfies_stlpy_semantics():
    T = 8
    A, B, C, D = _double_integrator()
    spec = _inside((2, 3, 2, 3)).eventually(0, T) & _outside((1.2, 1.8, 0, 5)).always(0, T)
    x0 = np.array([0.5, 0.5, 0.0, 0.0])
    x_box = (np.array([0.0, 0.0, -1.0, -1.0]), np.array([10.0, 10.0, 1.0, 1.0]))
    problem, _ = make_problem(spec, A, B, C, D, x0, [-0.5, -0.5], [0.5, 0.5], T, *x_box)
    res = problem.solve_result(rrt_timeout=10, time_limit=15, seed=0)
    if res.status == "found":
        traj = res.trajectory
        xs = traj.get_mean()[: T + 1]
        us = np.zeros((T + 1, 2))
        us[: traj.num_of_steps] = traj.get_control()[:T]
        assert stlpy_robustness_reference(spec, C @ xs.T + D @ us.T, 0) >= -1e-6
        assert I.satisfies(traj, problem.stl_formula)
    else:  # the solver may be out of budget, but it must not claim infeasibility
        assert res.status == "budget_exhausted"


def test_prstl_milp_peer_returns_a_plan_the_monitor_accepts():
    T = 20
    problem = noisy_reach_avoid(T)
    out = solve_prstl_milp(problem, T, time_limit=20)
    assert out["status"] == "solved"
    traj = I.rollout(problem.switched_system, problem.initial_state, np.zeros(T, dtype=int), out["controls"])
    assert I.satisfies(traj, problem.stl_formula)
    # Too short to reach the goal from (1, 2) with |u| <= 0.5: the MILP proves infeasibility.
    assert solve_prstl_milp(noisy_reach_avoid(5), 5, time_limit=20)["status"] == "infeasible"
