"""PrSTL formula objects and their constructors (paper Section IV, Fig. 5)."""

from __future__ import annotations

import pytest

import idstlpy as stl


@pytest.fixture
def xq():
    return stl.mk_variable(2), stl.mk_variable(2, dtype=int)


def _cp(x, i, bound, eps=0.05):
    return stl.prob(x[i] <= bound) >= 1 - eps


def test_logical_and_returns_documented_types(xq):
    x, q = xq
    assert isinstance(stl.logical_and(x[0] <= 1, x[1] <= 1), stl.ConvexRegion)
    region = stl.logical_and(_cp(x, 0, 1), _cp(x, 1, 1))
    assert isinstance(region, stl.ConvexRegion) and region.is_probabilistic
    ap = stl.logical_and(_cp(x, 0, 1), q == 1)
    assert isinstance(ap, stl.STLAtomicProposition)
    assert ap.modes == frozenset({1}) and len(ap.predicates) == 1
    named = stl.logical_and(_cp(x, 0, 1), name="goal")
    assert isinstance(named, stl.STLAtomicProposition) and named.name == "goal"
    assert named.modes is None
    f = stl.logical_and(named, stl.eventually(0, 3, named))
    assert isinstance(f, stl.STLAnd) and len(f.children) == 2
    # state parts merge into one proposition, modes intersect
    g = stl.logical_and(
        _cp(x, 0, 1), q == 1, stl.logical_or(q == 0, q == 1), stl.always(0, 2, named)
    )
    assert isinstance(g, stl.STLAnd)
    state = g.children[0]
    assert isinstance(state, stl.STLAtomicProposition) and state.modes == frozenset({1})
    with pytest.raises(stl.InvalidTypeError, match="deterministic"):
        stl.logical_and(x[0] <= 1, _cp(x, 1, 1))


def test_logical_or_and_operators(xq):
    x, q = xq
    a = stl.logical_and(_cp(x, 0, 1), name="a")
    b = stl.logical_and(_cp(x, 1, 1), name="b")
    f = stl.logical_or(a, b, stl.eventually(1, 2, a))
    assert isinstance(f, stl.STLOr) and len(f.children) == 3
    assert isinstance(a | b, stl.STLOr)
    assert isinstance(a & b, stl.STLAnd)
    nested = stl.logical_or(stl.logical_or(a, b), a)
    assert len(nested.children) == 3  # flattened
    modes = stl.logical_or(q == 0, q == 1, name="any")
    assert isinstance(modes, stl.STLAtomicProposition) and modes.modes == frozenset({0, 1})


def test_temporal_constructors(xq):
    x, _ = xq
    a = stl.logical_and(_cp(x, 0, 1), name="a")
    u = stl.until(a, 1, 4, a)
    assert isinstance(u, stl.STLUntil) and isinstance(u, stl.STLTemporalFormula)
    assert (u.a, u.b, u.left, u.right) == (1, 4, a, a)
    ev = stl.eventually(0, 3, a)
    assert isinstance(ev, stl.STLUntil) and ev.left is stl.TRUE
    al = stl.always(2, 5, a)
    assert isinstance(al, stl.STLRelease) and al.left is stl.FALSE and (al.a, al.b) == (2, 5)
    r = stl.release(a, 0, 0, a)
    assert isinstance(r, stl.STLRelease)
    # chance constraints and mode formulas are coerced to propositions
    ev2 = stl.eventually(0, 1, _cp(x, 0, 1))
    assert isinstance(ev2.right, stl.STLAtomicProposition)


def test_horizon(xq):
    x, _ = xq
    a = stl.logical_and(_cp(x, 0, 1), name="a")
    assert a.horizon == 0
    assert stl.eventually(2, 7, a).horizon == 7
    f = stl.until(a, 0, 240, stl.always(0, 40, a))
    assert f.horizon == 280
    g = stl.logical_and(stl.eventually(0, 3, a), stl.always(1, 9, stl.eventually(0, 2, a)))
    assert g.horizon == 11
    assert stl.logical_or(a, stl.always(0, 4, a)).horizon == 4


def test_atomic_propositions_distinct_in_order(xq):
    x, q = xq
    a = stl.logical_and(_cp(x, 0, 1), name="a")
    b = stl.logical_and(_cp(x, 1, 1), q == 0, name="b")
    f = stl.until(a, 0, 5, stl.logical_and(b, stl.always(0, 2, a)))
    aps = f.atomic_propositions()
    assert aps[:2] == [a, b]
    assert stl.FALSE in aps
    assert len(aps) == 3


def test_str_uses_text_syntax(xq):
    x, q = xq
    safe = stl.logical_and(q == 0, stl.prob(x[0] >= -1) >= 1 - 0.01, name="free_space")
    target = stl.logical_and(stl.prob(x[0] <= 0.25) >= 0.95, name="target")
    assert str(stl.until(safe, 0, 240, stl.always(0, 40, target))) == (
        "(free_space U[0,240] G[0,40] target)"
    )
    assert str(stl.eventually(1, 3, target)) == "F[1,3] target"
    assert str(stl.release(safe, 1, 2, target)) == "(free_space R[1,2] target)"
    assert str(safe & target) == "(free_space & target)"
    assert str(safe | target) == "(free_space | target)"
    anon = stl.logical_and(stl.prob(x[0] <= 1) >= 0.9, q == 1)
    assert str(anon) == "{P[x[0] - 1.0 <= 0] >= 0.9 & q == 1}"
    assert str(stl.TRUE) == "true" and str(stl.FALSE) == "false"


def test_constants():
    assert stl.TRUE.is_true and not stl.TRUE.is_false
    assert stl.FALSE.is_false and not stl.FALSE.is_true
    assert stl.TRUE.horizon == 0
    with pytest.raises(stl.InvalidTypeError, match="truth value"):
        bool(stl.TRUE)
