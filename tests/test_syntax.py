"""Text syntax of formulas: printing and the recursive-descent parser read each other back."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

import idstlpy as stl
from idstlpy.syntax import FormulaSyntaxError, format_atom, format_formula, parse_formula

X = stl.mk_variable(size=3, dtype=float)
NUM_MODES = 3


def _named(name: str, modes=None, level: float = 0.95) -> stl.STLAtomicProposition:
    return stl.STLAtomicProposition(
        [stl.prob(X[0] <= 1.0) >= level, stl.prob(X[1] >= -2.5) >= level], modes, name=name
    )


NAMED = {
    "free_space": _named("free_space", [0]),
    "target": _named("target", [0, 2], 0.99),
    "light": _named("light"),
    "_a1": stl.STLAtomicProposition((), [1], name="_a1"),
}

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
coef = st.one_of(st.just(0.0), st.just(1.0), st.just(-1.0), st.just(-0.0), finite)


@st.composite
def chance_constraints(draw) -> stl.ProbabilisticLinearPredicate:
    h = [draw(coef) for _ in range(X.size)]
    c = draw(coef)
    eps = draw(st.one_of(st.sampled_from([0.0, 0.5, 0.01, 0.05]), st.floats(0.0, 0.5)))
    return stl.ProbabilisticLinearPredicate(h, c, X, eps)


@st.composite
def atoms(draw) -> stl.STLAtomicProposition:
    kind = draw(st.sampled_from(["named", "true", "false", "anon", "anon"]))
    if kind == "named":
        return NAMED[draw(st.sampled_from(sorted(NAMED)))]
    if kind == "true":
        return stl.TRUE
    if kind == "false":
        return stl.FALSE
    preds = draw(st.lists(chance_constraints(), max_size=3))
    modes = draw(st.one_of(st.none(), st.frozensets(st.integers(0, NUM_MODES - 1), max_size=NUM_MODES)))
    return stl.STLAtomicProposition(preds, modes)


interval = st.tuples(st.integers(0, 50), st.integers(0, 50)).map(lambda t: (min(t), max(t)))


def _extend(children):
    def binary(cls):
        return st.lists(children, min_size=2, max_size=3).map(cls)

    def temporal(kind):
        return st.tuples(children, interval, children).map(lambda t: kind(t[0], t[1][0], t[1][1], t[2]))

    return st.one_of(
        binary(stl.STLAnd),
        binary(stl.STLOr),
        temporal(stl.until),
        temporal(stl.release),
        st.tuples(interval, children).map(lambda t: stl.eventually(t[0][0], t[0][1], t[1])),
        st.tuples(interval, children).map(lambda t: stl.always(t[0][0], t[0][1], t[1])),
    )


formulas = st.recursive(atoms(), _extend, max_leaves=8)


@given(formulas)
def test_round_trip(formula):
    text = str(formula)
    parsed = parse_formula(text, NAMED, X, NUM_MODES)
    assert str(parsed) == text
    assert format_formula(parsed) == text
    assert parsed.horizon == formula.horizon


@given(atoms())
def test_round_trip_unnamed_definition(ap):
    text = format_atom(ap, use_name=False)
    parsed = parse_formula(text, NAMED, X, NUM_MODES)
    assert format_atom(parsed, use_name=False) == text
    if not ap.is_false and ap is not stl.TRUE:
        assert parsed.modes == ap.modes
        # h and c read back exactly; eps up to the rounding of the printed level 1 - eps
        assert [(list(p.h), p.c, 1.0 - p.eps) for p in parsed.predicates] == [
            (list(p.h), p.c, 1.0 - p.eps) for p in ap.predicates
        ]


def test_listing_prints_and_parses():
    q = stl.mk_variable(size=1, dtype=int)
    x = stl.mk_variable(size=2, dtype=float)
    free = stl.logical_and(q == 0, stl.prob(x[0] >= -1) >= 1 - 0.01, name="free_space")
    target = stl.logical_and(q == 0, stl.prob(x[0] <= 0.25) >= 1 - 0.05, name="target")
    f = stl.until(free, 0, 240, stl.always(0, 40, target))
    assert str(f) == "(free_space U[0,240] G[0,40] target)"
    g = parse_formula(str(f), {"free_space": free, "target": target}, x, 1)
    assert isinstance(g, stl.STLUntil) and g.left is free
    assert isinstance(g.right, stl.STLRelease) and g.right.left is stl.FALSE
    assert g.right.right is target


def test_whitespace_is_free_and_named_atoms_are_shared():
    g = parse_formula("  (free_space&F[ 1 , 2 ]target)\n", NAMED, X, NUM_MODES)
    assert str(g) == "(free_space & F[1,2] target)"
    assert g.children[0] is NAMED["free_space"]


def test_inline_atom_semantics():
    g = parse_formula("{P[-x[0] + 2.5*x[2] - 1.0 <= 0] >= 0.9 & (q == 0 | q == 2)}", {}, X, 3)
    assert isinstance(g, stl.STLAtomicProposition)
    (p,) = g.predicates
    assert list(p.h) == [-1.0, 0.0, 2.5] and p.c == -1.0
    assert p.eps == pytest.approx(0.1)
    assert g.modes == frozenset({0, 2})
    assert parse_formula("{}", {}, X).is_true
    assert parse_formula("{false}", {}, X).modes == frozenset()
    assert parse_formula("true", {}) is stl.TRUE and parse_formula("false", {}) is stl.FALSE


@pytest.mark.parametrize(
    ("text", "column", "message"),
    [
        ("(free_space & target", 21, "expected ')'"),
        ("(free_space & target | light)", 22, "cannot mix"),
        ("F[3,1] target", 2, "start <= end"),
        ("F[1,2]", 7, "expected a formula"),
        ("{P[x[3] <= 0] >= 0.9}", 6, "out of range"),
        ("{P[x[0] <= 1] >= 0.9}", 12, "P[... <= 0]"),
        ("{P[x[0] <= 0] >= 0.3}", 18, "[0.5, 1]"),
        ("{P[y[0] <= 0] >= 0.9}", 4, "state variable 'x'"),
        ("{q == 3}", 7, "out of range"),
        ("nowhere", 1, "unknown proposition 'nowhere'"),
        ("free_space $", 12, "unexpected character"),
        ("free_space target", 12, "expected end"),
        ("(free_space U[0,1.5] target)", 17, "integer"),
        ("__import__('os')", 12, "unexpected character"),
        ("", 1, "expected a formula"),
    ],
)
def test_errors_carry_position(text, column, message):
    with pytest.raises(FormulaSyntaxError) as info:
        parse_formula(text, NAMED, X, NUM_MODES)
    assert info.value.position == column - 1
    assert f"column {column}" in str(info.value)
    assert message in str(info.value)
    assert isinstance(info.value, stl.InvalidArgumentError)


def test_deep_nesting_is_an_error_not_a_crash():
    text = "(" * 500 + "light" + " & light)" * 500
    with pytest.raises(FormulaSyntaxError, match="nested deeper"):
        parse_formula(text, NAMED, X)


def test_non_string_rejected():
    with pytest.raises(stl.InvalidTypeError, match="text .* must be a str, got int"):
        parse_formula(42, NAMED, X)  # type: ignore[arg-type]
