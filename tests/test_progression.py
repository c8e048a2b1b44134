"""Formula progression (idstlpy.progression) against both monitors.

The property: for every formula ``phi``, trajectory ``xi`` and split step ``k``,
``satisfies(xi, phi) == satisfies(xi[k:], progress(phi, xi[:k+1]))``, where the suffix ``xi[k:]``
starts at the shared belief ``X_k`` (its mode predicates hold vacuously there).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from oracles.brute_force import Trace, sat

import idstlpy as stl
from idstlpy.errors import InvalidTypeError
from idstlpy.formulas import STLAtomicProposition
from idstlpy.progression import progress, progress_step

X = stl.mk_variable(2, name="x")


def _traj(means, covs, actions) -> stl.ProbabilisticTSTrajectory:
    means = np.asarray(means, dtype=float)
    L = means.shape[0]
    return stl.ProbabilisticTSTrajectory(means, np.asarray(covs, dtype=float), actions, np.zeros((L - 1, 1)))


def _slice(
    traj: stl.ProbabilisticTSTrajectory, start: int, stop: int | None = None
) -> stl.ProbabilisticTSTrajectory:
    L = traj.num_of_steps + 1
    stop = L if stop is None else stop
    return _traj(traj.get_mean()[start:stop], traj.get_cov()[start:stop], traj.get_action()[start : stop - 1])


def _trace(traj: stl.ProbabilisticTSTrajectory) -> Trace:
    L = traj.num_of_steps + 1
    return Trace([(traj.get_mean(k), traj.get_cov(k)) for k in range(L)], list(traj.get_action()))


@st.composite
def chance_constraints(draw):
    angle = draw(st.floats(0.0, 2 * np.pi))
    h = np.array([np.cos(angle), np.sin(angle)])
    c = draw(st.floats(-1.5, 1.5))
    eps = draw(st.sampled_from([0.05, 0.25, 0.5]))
    return stl.ProbabilisticLinearPredicate(h, c, X, eps)


@st.composite
def atoms(draw, num_modes: int):
    kind = draw(st.integers(0, 9))
    if kind == 0:
        return stl.TRUE
    if kind == 1:
        return stl.FALSE
    preds = draw(st.lists(chance_constraints(), min_size=0, max_size=2))
    # Mode sets are drawn often: the split step's mode is the convention under test.
    modes = draw(st.one_of(st.none(), st.frozensets(st.integers(0, num_modes - 1), max_size=num_modes)))
    return STLAtomicProposition(preds, modes)


def intervals():
    return st.tuples(st.integers(0, 3), st.integers(0, 4)).map(lambda t: (t[0], t[0] + t[1]))


def formulas(num_modes: int, depth: int):
    base = atoms(num_modes)
    if depth == 0:
        return base
    sub = formulas(num_modes, depth - 1)
    return st.one_of(
        base,
        st.lists(sub, min_size=2, max_size=3).map(stl.STLAnd),
        st.lists(sub, min_size=2, max_size=3).map(stl.STLOr),
        st.tuples(sub, intervals(), sub).map(lambda t: stl.until(t[0], t[1][0], t[1][1], t[2])),
        st.tuples(sub, intervals(), sub).map(lambda t: stl.release(t[0], t[1][0], t[1][1], t[2])),
        st.tuples(intervals(), sub).map(lambda t: stl.eventually(t[0][0], t[0][1], t[1])),
        st.tuples(intervals(), sub).map(lambda t: stl.always(t[0][0], t[0][1], t[1])),
    )


@st.composite
def cases(draw):
    num_modes = draw(st.integers(1, 3))
    L = draw(st.integers(1, 10))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    means = rng.uniform(-1.5, 1.5, size=(L, 2))
    covs = np.empty((L, 2, 2))
    for k in range(L):
        M = rng.normal(size=(2, int(rng.integers(0, 3)))) * rng.uniform(0.05, 0.6)
        covs[k] = M @ M.T
    actions = rng.integers(0, num_modes, size=L - 1)
    formula = draw(formulas(num_modes, draw(st.integers(1, 3))))
    return _traj(means, covs, actions), formula


@settings(max_examples=300)  # the central property of the module
@given(cases())
def test_progress_preserves_satisfaction_at_every_split(case):
    traj, formula = case
    L = traj.num_of_steps + 1
    whole = sat(formula, 0, _trace(traj))
    assert stl.satisfies(traj, formula) == whole
    for k in range(L):
        psi = progress(formula, _slice(traj, 0, k + 1))
        suffix = _slice(traj, k)
        assert sat(psi, 0, _trace(suffix)) == whole, (str(formula), k, str(psi))
        assert stl.satisfies(suffix, psi) == whole, (str(formula), k, str(psi))


@given(cases())
def test_progressed_formula_ignores_the_split_step(case):
    """Everything at X_k is decided by the prefix: changing the suffix's step 0 changes nothing."""
    traj, formula = case
    L = traj.num_of_steps + 1
    for k in range(L):
        psi = progress(formula, _slice(traj, 0, k + 1))
        suffix = _slice(traj, k)
        means, covs = suffix.get_mean().copy(), suffix.get_cov().copy()
        means[0] += 7.0  # far from every constraint's boundary
        covs[0] = 4.0 * np.eye(2)
        moved = _traj(means, covs, suffix.get_action())
        assert stl.satisfies(moved, psi) == stl.satisfies(suffix, psi), (str(formula), k, str(psi))


@given(cases(), st.data())
def test_progress_composes(case, data):
    """Progressing over k then over j more steps is progressing over k + j (repeated replans)."""
    traj, formula = case
    L = traj.num_of_steps + 1
    k = data.draw(st.integers(0, L - 1))
    j = data.draw(st.integers(0, L - 1 - k))
    once = progress(formula, _slice(traj, 0, k + j + 1))
    psi = progress(formula, _slice(traj, 0, k + 1))
    twice = progress(psi, _slice(traj, k, k + j + 1))
    rest = _slice(traj, k + j)
    assert stl.satisfies(rest, once) == stl.satisfies(rest, twice)


def test_until_half_way_and_hold_in_progress():
    free = stl.logical_and(stl.prob(X[0] <= 1.0) >= 0.9, name="free")
    target = stl.logical_and(stl.prob(X[0] >= 2.0) >= 0.9, name="target")
    phi = stl.until(free, 0, 10, stl.always(0, 3, target))
    # Three steps in free space, then two in the target (a hold in progress).
    means = np.array([[0.0, 0], [0.5, 0], [0.8, 0], [2.5, 0], [2.6, 0]])
    traj = _traj(means, np.zeros((5, 2, 2)), [0, 0, 0, 0])
    psi = progress(phi, traj)
    # The hold that started at step 3 needs target at steps 5 and 6 (suffix steps 1, 2); the
    # until may still be met by a later hold (free needed no more: step 4 left free space).
    assert "target" in str(psi)
    assert stl.satisfies(_traj(np.array([[2.6, 0], [2.7, 0], [2.8, 0]]), np.zeros((3, 2, 2)), [0, 0]), psi)
    assert not stl.satisfies(
        _traj(np.array([[2.6, 0], [2.7, 0], [0.0, 0]]), np.zeros((3, 2, 2)), [0, 0]), psi
    )
    # Decided prefixes give constants.
    assert progress(stl.eventually(0, 5, target), traj) is stl.TRUE
    assert progress(stl.always(0, 5, free), traj) is stl.FALSE


def test_mode_of_the_split_step_is_decided_by_the_prefix():
    in_mode_1 = STLAtomicProposition((), modes=[1], name="in1")
    phi = stl.always(0, 2, stl.logical_or(in_mode_1, stl.eventually(0, 0, in_mode_1)))
    traj = _traj(np.zeros((2, 2)), np.zeros((2, 2, 2)), [0])  # arrived at step 1 in mode 0
    psi = progress(stl.always(1, 2, in_mode_1), traj)
    assert psi is stl.FALSE  # the suffix's step 0 would hold vacuously; the prefix says no
    assert progress(phi, _traj(np.zeros((1, 2)), np.zeros((1, 2, 2)), [])) is not stl.FALSE


def test_bad_inputs_raise_package_errors():
    traj = _traj(np.zeros((2, 2)), np.zeros((2, 2, 2)), [0])
    with pytest.raises(InvalidTypeError, match="formula"):
        progress("G[0,1] p", traj)  # type: ignore[arg-type]
    with pytest.raises(InvalidTypeError, match="trajectory_prefix"):
        progress(stl.TRUE, np.zeros((2, 2)))  # type: ignore[arg-type]
    with pytest.raises(InvalidTypeError, match="truth"):
        progress_step(STLAtomicProposition([stl.prob(X[0] <= 1) >= 0.9]), {})


def test_progressed_size_stays_bounded():
    p = stl.logical_and(stl.prob(X[0] <= 0.0) >= 0.9, name="p")
    phi = stl.always(0, 200, stl.eventually(0, 5, p))
    means = np.zeros((150, 2))
    means[::3, 0] = -1.0  # p every third step
    traj = _traj(means, np.zeros((150, 2, 2)), np.zeros(149, dtype=int))
    psi = progress(phi, traj)
    assert sum(1 for _ in psi.walk()) < 40
    assert stl.satisfies(traj, phi) == stl.satisfies(_slice(traj, 149), psi)


def _exhaustive_formulas():
    """Every single operator over mode atoms with every small interval, and one nesting."""
    p = STLAtomicProposition((), modes=[1], name="p")
    r = STLAtomicProposition((), modes=[0], name="r")
    out = []
    for a in range(3):
        for b in range(a, a + 3):
            for left, right in ((p, r), (stl.TRUE, r), (stl.FALSE, p), (r, p)):
                out.append(stl.until(left, a, b, right))
                out.append(stl.release(left, a, b, right))
            out.append(stl.until(p, a, b, stl.always(0, 1, r)))
            out.append(stl.always(a, b, stl.eventually(1, 2, p)))
    return out


@pytest.mark.parametrize("formula", _exhaustive_formulas(), ids=str)
def test_progress_exhaustive_on_mode_traces(formula):
    """All mode sequences of up to 6 beliefs, every split: catches off-by-one interval shifts."""
    import itertools

    for L in range(1, 7):
        for actions in itertools.product((0, 1), repeat=L - 1):
            traj = _traj(np.zeros((L, 2)), np.zeros((L, 2, 2)), list(actions))
            whole = sat(formula, 0, _trace(traj))
            for k in range(L):
                psi = progress(formula, _slice(traj, 0, k + 1))
                assert sat(psi, 0, _trace(_slice(traj, k))) == whole, (actions, k, str(psi))
