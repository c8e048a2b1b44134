"""The SAT encoding agrees with the Boolean semantics on every label trace."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import idstlpy as stl
from idstlpy.semantics import formula_margins
from idstlpy.synthesis.bmc import BMCEncoder
from idstlpy.synthesis.plan import evaluate_bool, extract_witness

X = stl.mk_variable(1)
Q = stl.mk_variable(2, dtype=int)
ATOMS = [
    stl.logical_and(stl.prob(X[0] <= 1) >= 0.9, name="a"),
    stl.logical_and(stl.prob(X[0] >= 2) >= 0.9, name="b"),
    stl.logical_and(Q == 1, name="m1"),
]


@st.composite
def formulas(draw, depth=3):
    if depth == 0 or draw(st.integers(0, 3)) == 0:
        return draw(st.sampled_from(ATOMS + [stl.TRUE]))
    kind = draw(st.sampled_from(["and", "or", "U", "R", "F", "G"]))
    if kind in ("and", "or"):
        parts = [draw(formulas(depth - 1)) for _ in range(2)]
        return stl.STLAnd(parts) if kind == "and" else stl.STLOr(parts)
    a = draw(st.integers(0, 3))
    b = a + draw(st.integers(0, 3))
    if kind == "F":
        return stl.eventually(a, b, draw(formulas(depth - 1)))
    if kind == "G":
        return stl.always(a, b, draw(formulas(depth - 1)))
    left, right = draw(formulas(depth - 1)), draw(formulas(depth - 1))
    return stl.until(left, a, b, right) if kind == "U" else stl.release(left, a, b, right)


def _atoms(formula):
    return [ap for ap in formula.atomic_propositions() if ap._constant is None]


def _random_labels(formula, length, seed, p_true):
    """Random truth values of ``formula``'s atoms over ``length`` steps, and their row index."""
    atoms = _atoms(formula)
    truth = np.random.default_rng(seed).random((len(atoms), length)) < p_true
    return truth, {id(a): i for i, a in enumerate(atoms)}


@settings(max_examples=150, deadline=None)
@given(formulas(), st.integers(1, 9), st.integers(0, 2**31 - 1))
def test_sat_encoding_matches_semantics(formula, length, seed):
    rng = np.random.default_rng(seed)
    atoms = _atoms(formula)
    enc = BMCEncoder(formula, atoms, num_modes=2)
    L = min(length, enc.H + 1)
    truth = rng.random((len(atoms), L)) < 0.5
    modes = rng.integers(0, 2, size=L)
    # Mode atoms must agree with the modes used to arrive.
    for i, ap in enumerate(atoms):
        if ap.modes is not None:
            truth[i, 1:] = np.isin(modes[1:], list(ap.modes))
    assume = []
    for i in range(len(atoms)):
        for k in range(L):
            lit = int(enc.p[i, k])
            assume.append(lit if truth[i, k] else -lit)
    for k in range(1, L):
        assume += [int(enc.m[q, k]) if q == modes[k] else -int(enc.m[q, k]) for q in range(2)]
    assume.append(enc.alive[L - 1])
    sat = enc.solve(depth=L - 1, assumptions=assume)
    index = {id(a): i for i, a in enumerate(atoms)}
    expected = bool(evaluate_bool(formula, truth, index)[id(formula)][0])
    margins = {id(a): np.where(truth[i], np.inf, -np.inf) for i, a in enumerate(atoms)}
    assert expected == bool(formula_margins(formula, margins, L)[0] >= 0)
    assert sat == expected
    enc.close()


@settings(max_examples=150, deadline=None)
@given(formulas(), st.integers(1, 10), st.integers(0, 2**31 - 1), st.booleans())
def test_witness_is_sufficient(formula, length, seed, late):
    truth, index = _random_labels(formula, length, seed, 0.7)
    w = extract_witness(formula, truth, index, prefer_late=late)
    holds = bool(evaluate_bool(formula, truth, index)[id(formula)][0])
    assert (w is not None) == holds
    if w is not None:
        required, L = w
        assert not np.any(required & ~truth)  # only true claims are required
        # The witness alone (everything else false, trace cut at L) satisfies the formula.
        assert evaluate_bool(formula, required[:, :L], index)[id(formula)][0]


def test_long_interval_encodes_compactly():
    f = stl.until(ATOMS[0], 0, 960, stl.always(0, 160, ATOMS[1]))
    enc = BMCEncoder(f, _atoms(f), num_modes=1)
    horizon = f.horizon + 1
    # Sparse tables: O(H log b) gates, far below the H * b of a plain unrolling.
    assert enc.num_vars < 20 * horizon
    enc.close()


def _witness_step_by_step(formula, truth, index, late):
    """The witness walked one (sub-formula, step) pair at a time: the reference for the batched one."""
    from idstlpy.formulas import STLAnd, STLAtomicProposition, STLOr, STLUntil

    def constant_true(f):
        return isinstance(f, STLAtomicProposition) and f.is_true and id(f) not in index

    values = evaluate_bool(formula, truth, index)
    L = truth.shape[1]
    required = np.zeros_like(truth, dtype=bool)
    last, seen, stack = 0, set(), [(formula, 0)]
    while stack:
        f, k = stack.pop()
        if (id(f), k) in seen:
            continue
        seen.add((id(f), k))
        last = max(last, k)
        if isinstance(f, STLAtomicProposition):
            if id(f) in index:
                required[index[id(f)], k] = True
        elif isinstance(f, STLAnd):
            stack.extend((c, k) for c in f.children)
        elif isinstance(f, STLOr):
            stack.append((next(c for c in f.children if values[id(c)][k]), k))
        elif isinstance(f, STLUntil):
            v1, v2 = values[id(f.left)], values[id(f.right)]
            start, end = k + f.a, min(k + f.b, L - 1)
            stop = next((j for j in range(start, end + 1) if not v1[j]), end)
            hits = [j for j in range(start, stop + 1) if v2[j]]
            chosen = hits[-1] if late else hits[0]
            stack.append((f.right, chosen))
            if not constant_true(f.left):
                stack.extend((f.left, j) for j in range(start, chosen))
            last = max(last, chosen)
        else:  # release
            v1, v2 = values[id(f.left)], values[id(f.right)]
            start, stop = k + f.a, k + f.b
            end = stop
            for j in range(start, min(stop, L - 1) + 1):
                if not v2[j]:
                    break
                if v1[j]:
                    end = j
                    stack.append((f.left, j))
                    break
            if not constant_true(f.right):
                stack.extend((f.right, j) for j in range(start, end + 1))
            last = max(last, end)
    return required, last + 1


@settings(max_examples=200, deadline=None)
@given(formulas(depth=4), st.integers(1, 12), st.integers(0, 2**31 - 1), st.booleans())
def test_witness_matches_the_step_by_step_walk(formula, length, seed, late):
    # The batched witness (one pass per sub-formula over its steps) is the closure the walk builds.
    truth, index = _random_labels(formula, length, seed, 0.75)
    w = extract_witness(formula, truth, index, prefer_late=late)
    if w is None:
        assert not evaluate_bool(formula, truth, index)[id(formula)][0]
        return
    required, L = _witness_step_by_step(formula, truth, index, late)
    assert w[1] == L
    assert np.array_equal(w[0], required)
