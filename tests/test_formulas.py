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
    g = stl.logical_and(_cp(x, 0, 1), q == 1, stl.logical_or(q == 0, q == 1), stl.always(0, 2, named))
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
    assert str(stl.until(safe, 0, 240, stl.always(0, 40, target))) == ("(free_space U[0,240] G[0,40] target)")
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


# -- convenience forms (issue 14 "Inputs") -------------------------------------------------------
def test_logical_and_and_or_accept_a_single_list_or_tuple(xq):
    x, q = xq
    p1, p2 = _cp(x, 0, 1), _cp(x, 1, 2)
    polytope = stl.logical_and([x[0] <= 1, x[1] <= 1])
    assert list(polytope.predicates) == [x[0] <= 1, x[1] <= 1]
    region = stl.logical_and([p1, p2])
    assert isinstance(region, stl.ConvexRegion) and list(region.predicates) == [p1, p2]
    assert stl.logical_and((p1, q == 1), name="a") == stl.logical_and(p1, q == 1, name="a")
    a = stl.logical_and(p1, name="a")
    b = stl.logical_and(p2, name="b")
    assert stl.logical_or([a, b]) == stl.logical_or(a, b)
    assert stl.logical_or((q == 0, q == 1)) == stl.logical_or(q == 0, q == 1)
    assert stl.logical_and([a]) is a
    with pytest.raises(stl.InvalidArgumentError, match="logical_and needs at least one argument"):
        stl.logical_and([])
    with pytest.raises(stl.InvalidArgumentError, match="logical_or needs at least one argument"):
        stl.logical_or(())
    with pytest.raises(stl.InvalidTypeError, match="logical_and argument 1 must be a predicate"):
        stl.logical_and([p1, "p2"])


# -- structural equality -------------------------------------------------------------------------
def _listing(x, q):
    free = stl.logical_and(q == 0, stl.prob(x[0] >= -1) >= 1 - 0.01, stl.prob(x[1] <= 4) >= 0.99, name="free")
    target = stl.logical_and(q == 0, stl.prob(x[0] <= 0.25) >= 0.95, name="target")
    return stl.until(free, 0, 240, stl.always(0, 40, target))


def test_identical_formulas_built_separately_are_equal_and_hash_alike():
    f = _listing(stl.mk_variable(2), stl.mk_variable(1, dtype=int))
    g = _listing(stl.mk_variable(2), stl.mk_variable(1, dtype=int))  # other variable objects
    assert f is not g and f == g and hash(f) == hash(g)
    assert not (f != g)
    assert len({f, g}) == 1 and g in [f] and {f: 1}[g] == 1
    assert f.right == g.right and f.left == g.left


def test_structurally_different_formulas_are_unequal(xq):
    x, q = xq
    a = stl.logical_and(_cp(x, 0, 1), name="a")
    b = stl.logical_and(_cp(x, 1, 1), name="b")
    different = [
        stl.until(a, 0, 5, b),
        stl.until(a, 0, 6, b),
        stl.until(a, 1, 5, b),
        stl.until(b, 0, 5, a),
        stl.release(a, 0, 5, b),
        stl.eventually(0, 5, b),
        stl.always(0, 5, b),
        a & b,
        b & a,  # operand order counts
        a | b,
        stl.logical_and(_cp(x, 0, 1), name="c"),  # same definition, other name
        stl.logical_and(_cp(x, 0, 1, eps=0.1), name="a"),  # other confidence
        stl.logical_and(_cp(x, 0, 2), name="a"),  # other constant
        stl.logical_and(_cp(x, 0, 1), q == 1, name="a"),  # modes
        stl.logical_and(stl.prob(stl.mk_variable(2, name="y")[0] <= 1) >= 0.95, name="a"),  # variable
        stl.logical_and(stl.prob(stl.mk_variable(3)[0] <= 1) >= 0.95, name="a"),  # its size
        stl.TRUE,
        stl.FALSE,
        a,
    ]
    for i, f in enumerate(different):
        for j, g in enumerate(different):
            assert (f == g) == (i == j), (f, g)
    assert len(set(different)) == len(different)
    assert a != "a" and a != 3 and (a == None) is False  # noqa: E711


def test_mode_order_does_not_count_and_equal_formulas_print_alike(xq):
    x, _ = xq
    p = _cp(x, 0, 1)
    f = stl.STLAtomicProposition([p], [1, 0])
    g = stl.STLAtomicProposition([p], (0, 1))
    assert f == g and hash(f) == hash(g) and str(f) == str(g)
    assert stl.STLAtomicProposition([p], [0]) != stl.STLAtomicProposition([p])


def test_parsed_formula_equals_the_built_one(xq):
    x, q = xq
    f = _listing(x, q)
    atoms = {ap.name: ap for ap in f.atomic_propositions()}
    assert stl.parse_formula(str(f), atoms) == f
    anon = stl.eventually(1, 3, stl.logical_and(_cp(x, 0, 1), q == 1))
    assert stl.parse_formula(str(anon), state_variable=stl.mk_variable(2)) == anon


def test_pickled_formula_is_equal_and_carries_no_salted_hash():
    import pickle

    f = _listing(stl.mk_variable(2), stl.mk_variable(1, dtype=int))
    h = hash(f)
    assert "_hash" not in f.__getstate__()
    g = pickle.loads(pickle.dumps(f))
    assert g == f and hash(g) == h


def test_atomic_propositions_still_lists_distinct_objects(xq):
    x, _ = xq
    a1 = stl.logical_and(_cp(x, 0, 1), name="a")
    a2 = stl.logical_and(_cp(x, 0, 1), name="a")
    assert a1 == a2
    aps = stl.logical_and(stl.eventually(0, 1, a1), stl.always(0, 1, a2)).atomic_propositions()
    named = [ap for ap in aps if ap.name == "a"]
    assert len(named) == 2 and named[0] is a1 and named[1] is a2


def test_predicates_and_mode_formulas_compare_structurally(xq):
    x, q = xq
    y = stl.mk_variable(2)
    assert (x[0] <= 1) == (y[0] <= 1) and hash(x[0] <= 1) == hash(y[0] <= 1)
    assert (x[0] <= 1) != (x[0] <= 2) and (x[0] <= 1) != (x[1] <= 1)
    assert _cp(x, 0, 1) == _cp(y, 0, 1) and _cp(x, 0, 1) != _cp(x, 0, 1, eps=0.1)
    assert _cp(x, 0, 1) != (x[0] <= 1)  # a chance constraint is not its predicate
    assert (q == 1) == (q == 1) and hash(q == 1) == hash(q == 1)
    assert stl.logical_or(q == 0, q == 1) == stl.logical_or(q == 1, q == 0) and (q == 0) != (q == 1)
    assert (q != 0) == (q == 1)  # the same set of modes


# -- reprs --------------------------------------------------------------------------------------------
def test_repr_is_the_text_syntax(xq):
    x, q = xq
    f = _listing(x, q)
    assert repr(f) == str(f) == "(free U[0,240] G[0,40] target)"
    target = f.right.right
    assert repr(target) == "target := {P[x[0] - 0.25 <= 0] >= 0.95 & q == 0}"
    assert repr(stl.TRUE) == "true" and repr(stl.FALSE) == "false"
    anon = stl.logical_and(_cp(x, 0, 1), q == 1)
    assert repr(anon) == str(anon)


def test_long_repr_is_shortened(xq):
    x, _ = xq
    atoms = [stl.logical_and(_cp(x, i % 2, i), name=f"region_{i}") for i in range(60)]
    f = stl.logical_or([stl.eventually(0, i, a) for i, a in enumerate(atoms)])
    text, short = str(f), repr(f)
    assert len(text) > 1000 and len(short) <= 200
    head, tail = short.split(" ... ")
    assert text.startswith(head) and text.endswith(tail)


def test_repr_html_shows_text_horizon_and_definitions(xq):
    x, q = xq
    f = _listing(x, q)
    html = f._repr_html_()
    assert "(free U[0,240] G[0,40] target)" in html and "horizon 280 steps" in html
    assert "<code>target</code>" in html and "&lt;= 0] &gt;= 0.95 &amp; q == 0" in html
    assert html.count("<code>free</code>") == 1


def test_equality_and_hash_of_deep_and_shared_formulas():
    def chain(depth):
        f = stl.TRUE
        for _ in range(depth):
            f = stl.eventually(0, 1, f)
        return f

    a, b = chain(3000), chain(3000)  # deeper than the recursion limit
    assert a == b and hash(a) == hash(b) and a != chain(2999)

    def shared(depth):
        f = stl.eventually(0, 1, stl.TRUE)
        for _ in range(depth):
            f = stl.STLAnd([f, f])  # a DAG whose tree has 2**depth leaves
        return f

    assert shared(60) == shared(60) and hash(shared(60)) == hash(shared(60))
