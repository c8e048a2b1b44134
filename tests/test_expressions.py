"""Variables, linear expressions and predicates (paper Section IV, Figs. 2 and 3)."""

from __future__ import annotations

import numpy as np
import pytest

import idstlpy as stl


@pytest.fixture
def x():
    return stl.mk_variable(size=2, dtype=float)


def test_mk_variable_kinds():
    x = stl.mk_variable(3)
    assert isinstance(x, stl.RealValuedVariable) and isinstance(x, stl.LinearExpression)
    assert x.size == 3 and len(x) == 3
    np.testing.assert_array_equal(x.coef, np.eye(3))
    np.testing.assert_array_equal(x.const, np.zeros(3))
    q = stl.mk_variable(size=2, dtype=int)
    assert isinstance(q, stl.DiscreteVariable) and q.size == 2
    assert not isinstance(q, stl.LinearExpression)


def test_indexing(x):
    e = x[1]
    assert e.is_scalar
    np.testing.assert_array_equal(e.coef, [[0.0, 1.0]])
    np.testing.assert_array_equal(x[-1].coef, [[0.0, 1.0]])
    np.testing.assert_array_equal(x[0:2].coef, np.eye(2))
    assert [list(r.coef[0]) for r in x] == [[1.0, 0.0], [0.0, 1.0]]
    assert e.variable is x


def test_arithmetic_with_scalars_and_vectors(x):
    e = 2 * x[0] - 3 * x[1] + 1.5
    np.testing.assert_allclose(e.coef, [[2.0, -3.0]])
    np.testing.assert_allclose(e.const, [1.5])
    e = (x[0] + 1) / 4
    np.testing.assert_allclose(e.coef, [[0.25, 0.0]])
    np.testing.assert_allclose(e.const, [0.25])
    e = 5 - x[1]
    np.testing.assert_allclose(e.coef, [[0.0, -1.0]])
    np.testing.assert_allclose(e.const, [5.0])
    v = x * np.array([2.0, 3.0]) + np.array([1.0, -1.0])
    np.testing.assert_allclose(v.coef, np.diag([2.0, 3.0]))
    np.testing.assert_allclose(v.const, [1.0, -1.0])
    v = -x
    np.testing.assert_allclose(v.coef, -np.eye(2))
    e = np.float64(2.0) * x[0]
    np.testing.assert_allclose(e.coef, [[2.0, 0.0]])
    e = x[0] + x[1] - x[0]
    np.testing.assert_allclose(e.coef, [[0.0, 1.0]])


def test_matmul_inner_product(x):
    e = x @ np.array([1.0, 2.0])
    assert e.is_scalar
    np.testing.assert_allclose(e.coef, [[1.0, 2.0]])
    e2 = np.array([3.0, -1.0]) @ (x + 1)
    np.testing.assert_allclose(e2.coef, [[3.0, -1.0]])
    np.testing.assert_allclose(e2.const, [2.0])
    np.testing.assert_allclose(x.dot([0.5, 0.5]).coef, [[0.5, 0.5]])


def test_comparisons_build_linear_predicates(x):
    p = x[0] >= -1
    assert isinstance(p, stl.LinearPredicate) and not isinstance(p, stl.ProbabilisticLinearPredicate)
    np.testing.assert_allclose(p.h, [-1.0, 0.0])  # -x0 - 1 <= 0
    assert p.c == -1.0
    p = x[1] <= 4
    np.testing.assert_allclose(p.h, [0.0, 1.0])
    assert p.c == -4.0
    p = x[0] <= x[1] + 2
    np.testing.assert_allclose(p.h, [1.0, -1.0])
    assert p.c == -2.0
    p = 3 <= x[0]  # reflected: x0 >= 3
    np.testing.assert_allclose(p.h, [-1.0, 0.0])
    assert p.c == 3.0
    assert p.variable is x
    region = x <= [1.0, 2.0]
    assert isinstance(region, stl.ConvexRegion)
    assert [(list(q.h), q.c) for q in region.predicates] == [([1.0, 0.0], -1.0), ([0.0, 1.0], -2.0)]
    assert p.region.contains([3.0, 0.0]) and not p.region.contains([2.9, 0.0])


def test_prob_builds_chance_constraint(x):
    cp = stl.prob(x[0] >= -1) >= 1 - 0.01
    assert isinstance(cp, stl.ProbabilisticLinearPredicate)
    np.testing.assert_allclose(cp.h, [-1.0, 0.0])
    assert cp.c == -1.0
    assert cp.eps == pytest.approx(0.01)
    assert isinstance(cp.predicate, stl.LinearPredicate)
    np.testing.assert_allclose(cp.predicate.h, cp.h)
    assert (stl.prob(x[1] <= 0) >= 0.5).eps == pytest.approx(0.5)
    assert (stl.prob(x[1] <= 0) >= 1.0).eps == 0.0
    both = stl.prob(x <= [1.0, 1.0]) >= 0.95
    assert isinstance(both, stl.ConvexRegion) and both.is_probabilistic
    assert [p.eps for p in both.predicates] == pytest.approx([0.05, 0.05])


def test_discrete_predicates():
    q = stl.mk_variable(3, dtype=int)
    p = q == 2
    assert isinstance(p, stl.DiscretePredicate)
    assert p.value == 2 and p.modes == frozenset({2}) and p.variable is q
    assert (q != 0).modes == frozenset({1, 2})
    assert stl.logical_or(q == 0, q == 2).modes == frozenset({0, 2})


def test_printing(x):
    assert str(x[0] - 2 * x[1] + 1.5) == "x[0] - 2.0*x[1] + 1.5"
    assert str(x[0] >= -1) == "-x[0] - 1.0 <= 0"
    assert str(stl.prob(x[0] <= 1) >= 0.95) == "P[x[0] - 1.0 <= 0] >= 0.95"
    assert str(x) == "[x[0], x[1]]"
    assert str(stl.mk_variable(2, int) == 1) == "q == 1"


def test_non_linear_and_ambiguous_operations_raise(x):
    with pytest.raises(stl.InvalidTypeError, match="not linear"):
        _ = x[0] * x[1]
    with pytest.raises(stl.InvalidTypeError, match="strict"):
        _ = x[0] < 1
    with pytest.raises(stl.InvalidTypeError, match="equality"):
        _ = x[0] == 1
    with pytest.raises(stl.InvalidTypeError, match="truth value"):
        bool(x[0] <= 1)
    with pytest.raises(stl.InvalidArgumentError, match="by zero"):
        _ = x[0] / 0
    y = stl.mk_variable(2, name="y")
    with pytest.raises(stl.InvalidArgumentError, match="different variables"):
        _ = x[0] + y[0]
    with pytest.raises(stl.InvalidTypeError, match="upper bounds"):
        _ = stl.prob(x[0] <= 1) <= 0.9
    with pytest.raises(stl.InvalidTypeError, match="prob"):
        stl.prob(stl.prob(x[0] <= 1) >= 0.9)
