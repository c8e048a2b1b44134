"""The speed paths of issue 12 give the same answers as the slow ones.

- ``build_plan_rows`` keeps the covariance schedule and each proposition's scaled faces on the
  abstraction between candidates: its rows must equal a fresh build's, entry for entry, whatever
  order the candidates come in (prefixes, divergent mode sequences, state-dependent noise).
- Boxes answer emptiness, Chebyshev radius, support and bounding box without an LP: the answers
  must agree with the LPs', and emptiness is never claimed for boxes that merely touch.
"""

from __future__ import annotations

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.sets import Polytope
from idstlpy.synthesis.abstraction import Abstraction
from idstlpy.synthesis.plan_lp import PlanLPContext, Scaling, build_plan_rows


def _problem() -> tuple[stl.SwitchedSystem, stl.Polytope, np.ndarray, np.ndarray, Abstraction]:
    sense = stl.mk_lbs(np.eye(2), 0.5 * np.eye(2), 0.05 * np.eye(2), C=np.eye(2), V=0.2 * np.eye(2))
    blind = stl.mk_lbs(np.eye(2), np.eye(2), 0.05 * np.eye(2))
    dark = stl.mk_lbs(
        np.eye(2),
        np.eye(2),
        0.05 * np.eye(2),
        C=np.eye(2),
        V=lambda s: (0.1 + 0.1 * abs(s[0])) * np.eye(2),
        V_floor=0.1,
    )
    system = stl.mk_switched_sys([sense, blind, dark])
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float)
    goal = stl.logical_and(
        stl.prob(x[0] >= 2) >= 0.9, stl.prob(x[0] <= 3) >= 0.9, stl.prob(x[1] >= -1) >= 0.9, name="goal"
    )
    free = stl.logical_and(stl.prob(x[0] + x[1] <= 6) >= 0.95, stl.prob(x[1] <= 4) >= 0.95, name="free")
    formula = stl.until(free, 0, 12, goal)
    U = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    abstraction = Abstraction(formula, 2)
    return system, U, np.array([0.0, 0.5]), 0.3 * np.eye(2), abstraction


def _same(a: object, b: object) -> None:
    for f in ("A_eq", "A_U", "face_H"):
        x, y = getattr(a, f), getattr(b, f)
        # Built as CSR directly: well formed, columns sorted in every row, as a COO build gives.
        x.check_format(full_check=True)
        ref = x.tocoo().tocsr()
        assert x.has_sorted_indices and (x != ref).nnz == 0
        assert x.shape == y.shape
        np.testing.assert_array_equal(x.indptr, y.indptr)
        np.testing.assert_array_equal(x.indices, y.indices)
        np.testing.assert_array_equal(x.data, y.data)
    for f in ("b_eq", "b_U", "face_off", "face_norm", "face_unit", "face_owner", "covs"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    for f in ("impossible", "exact", "requirements", "K"):
        assert getattr(a, f) == getattr(b, f)


def test_cached_rows_equal_fresh_rows_in_any_candidate_order():
    system, U, mean0, cov0, abstraction = _problem()
    scaling = Scaling.compute(system, U, mean0, cov0, abstraction)
    rng = np.random.default_rng(3)
    prev = np.zeros(0, dtype=int)
    for trial in range(40):
        K = int(rng.integers(0, 13))
        kind = trial % 4
        if kind == 0:  # extends the previous sequence
            actions = np.concatenate([prev, rng.integers(0, 3, size=max(K - prev.size, 0))])[:K]
        elif kind == 1:  # a prefix of it
            actions = prev[: min(K, prev.size)]
        else:  # diverges somewhere
            actions = rng.integers(0, 2 if kind == 2 else 3, size=K)
        actions = actions.astype(int)
        reqs = [
            (int(k), int(i))
            for k in range(1, actions.size + 1)
            for i in range(abstraction.num_atoms)
            if rng.random() < 0.6
        ]
        cached = build_plan_rows(PlanLPContext(system, U, mean0, cov0, abstraction, scaling), reqs, actions)
        other = PlanLPContext(system, U, mean0, cov0, _fresh(abstraction), scaling)
        fresh = build_plan_rows(other, reqs, actions)
        _same(cached, fresh)
        assert cached.exact == (2 not in actions.tolist())
        prev = actions


def _fresh(abstraction: Abstraction) -> Abstraction:
    """The same propositions without any cached rows."""
    other = Abstraction.__new__(Abstraction)
    other.__dict__.update({k: v for k, v in abstraction.__dict__.items() if not k.startswith("_")})
    return other


def test_eps_zero_and_flat_faces_are_reported_impossible_in_requirement_order():
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=2, dtype=float)
    sure = stl.logical_and(stl.prob(x[0] <= 1) >= 1.0, name="sure")  # eps = 0
    loose = stl.logical_and(stl.prob(x[1] <= 1) >= 0.9, name="loose")
    abstraction = Abstraction(stl.logical_and(stl.always(0, 3, loose), stl.eventually(0, 3, sure)), 2)
    system = stl.mk_switched_sys([stl.mk_lbs(np.eye(2), np.eye(2), 0.1 * np.eye(2))])
    U = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    mean0, cov0 = np.zeros(2), 0.1 * np.eye(2)
    scaling = Scaling.compute(system, U, mean0, cov0, abstraction)
    names = abstraction.names()
    reqs = [(k, i) for k in (3, 1, 2) for i in range(abstraction.num_atoms)]
    actions = np.zeros(3, dtype=int)
    rows = build_plan_rows(PlanLPContext(system, U, mean0, cov0, abstraction, scaling), reqs, actions)
    sure_i = names.index("sure")
    assert rows.impossible == [(k, i) for (k, i) in reqs if i == sure_i]
    _same(
        rows,
        build_plan_rows(PlanLPContext(system, U, mean0, cov0, _fresh(abstraction), scaling), reqs, actions),
    )


def _lp_only(P: Polytope) -> Polytope:
    Q = Polytope(P.H, P.c)
    Q.__dict__["_axis_box"] = None  # what the LPs say
    return Q


def test_boxes_agree_with_the_lps():
    rng = np.random.default_rng(0)
    for _ in range(400):
        n = int(rng.integers(1, 4))
        rows, cs = [], []
        for _ in range(int(rng.integers(1, 3 * n + 1))):
            h = np.zeros(n)
            if rng.random() < 0.93:
                h[rng.integers(n)] = rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 10)
            rows.append(h)
            cs.append(rng.normal() * rng.choice([0.01, 1.0, 100.0]))
        P = Polytope(np.array(rows), np.array(cs))
        Q = _lp_only(P)
        assert P._axis_box is not None
        assert P.is_empty() == Q.is_empty()
        assert P.is_full_dimensional == Q.is_full_dimensional
        if not Q.is_empty():
            for a, b in zip(P.bounding_box(), Q.bounding_box(), strict=True):
                np.testing.assert_allclose(a, b, atol=1e-6)
            d = rng.normal(size=n)
            assert P.support(d) == pytest.approx(Q.support(d), abs=1e-6)


def test_touching_boxes_are_not_disjoint():
    third = 1e8 / 3
    a = Polytope([[3.0], [-1.0]], [-1e8, 0.0])  # 0 <= x <= 1e8 / 3
    b = Polytope([[7.0], [-1.0]], [-7e8, third])  # 1e8 / 3 <= x <= 1e8
    assert not a.intersect(b).is_empty()
    assert (
        Polytope.box([0.0, 0.0], [1.0, 1.0]).intersect(Polytope.box([1.0, 1.0], [2.0, 2.0])).is_empty()
        is False
    )
    assert Polytope.box([0.0], [1.0]).intersect(Polytope.box([1.0 + 1e-6], [2.0])).is_empty()
    # A slanted face is not a box: the LP answers.
    assert Polytope([[1.0, 1.0]], [-1.0])._axis_box is None


def test_is_disjoint_agrees_with_the_intersection():
    rng = np.random.default_rng(1)
    for _ in range(300):
        n = int(rng.integers(1, 4))
        boxes = []
        for _ in range(2):
            low = rng.normal(size=n) * 2
            high = low + rng.uniform(-0.5, 3, size=n)
            boxes.append(Polytope(np.vstack([np.eye(n), -np.eye(n)]), np.concatenate([-high, low])))
        a, b = boxes
        assert a.is_disjoint(b) == _lp_only(a).intersect(_lp_only(b)).is_empty()
    slanted = Polytope([[1.0, 1.0]], [-1.0])  # x + y <= 1: not a box, the LP answers
    assert slanted.is_disjoint(Polytope.box([2.0, 2.0], [3.0, 3.0]))
    assert not slanted.is_disjoint(Polytope.box([0.0, 0.0], [3.0, 3.0]))
