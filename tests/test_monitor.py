"""The monitor (idstlpy.semantics) against the brute-force oracle of the paper's semantics."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from oracles.brute_force import Trace, sat

import idstlpy as stl
from idstlpy.formulas import STLAtomicProposition

X = stl.mk_variable(2, name="x")


def _traj(means, covs, actions) -> stl.ProbabilisticTSTrajectory:
    means = np.asarray(means, dtype=float)
    L = means.shape[0]
    return stl.ProbabilisticTSTrajectory(means, np.asarray(covs, dtype=float), actions, np.zeros((L - 1, 1)))


def _oracle_trace(traj: stl.ProbabilisticTSTrajectory) -> Trace:
    L = traj.num_of_steps + 1
    states = [(traj.get_mean(k), traj.get_cov(k)) for k in range(L)]
    return Trace(states, [traj.get_action(k) for k in range(L - 1)])


# --------------------------------------------------------------------------------------------
# strategies


@st.composite
def chance_constraints(draw):
    angle = draw(st.floats(0.0, 2 * np.pi))
    scale = draw(st.sampled_from([0.5, 1.0, 2.0]))
    h = scale * np.array([np.cos(angle), np.sin(angle)])
    c = draw(st.floats(-2.0, 2.0))
    eps = draw(st.sampled_from([0.01, 0.05, 0.1, 0.25, 0.5]))
    return stl.ProbabilisticLinearPredicate(h, c, X, eps)


@st.composite
def atoms(draw, num_modes: int):
    kind = draw(st.integers(0, 9))
    if kind == 0:
        return stl.TRUE
    if kind == 1:
        return stl.FALSE
    preds = draw(st.lists(chance_constraints(), min_size=0, max_size=2))
    modes = draw(st.one_of(st.none(), st.frozensets(st.integers(0, num_modes - 1), max_size=num_modes)))
    return STLAtomicProposition(preds, modes)


def intervals():
    return st.tuples(st.integers(0, 3), st.integers(0, 3)).map(lambda t: (t[0], t[0] + t[1]))


def formulas(num_modes: int, depth: int, top: bool = False):
    base = atoms(num_modes)
    if depth == 0:
        return base
    sub = formulas(num_modes, depth - 1)
    return st.one_of(
        *([] if top else [base]),
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
    L = draw(st.integers(1, 12))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    means = rng.uniform(-2.0, 2.0, size=(L, 2))
    covs = np.empty((L, 2, 2))
    for k in range(L):
        rank = int(rng.integers(0, 3))
        M = rng.normal(size=(2, rank)) * rng.uniform(0.05, 0.8)
        covs[k] = M @ M.T
    actions = rng.integers(0, num_modes, size=L - 1)
    formula = draw(formulas(num_modes, draw(st.integers(1, 3)), top=True))
    return _traj(means, covs, actions), formula


# --------------------------------------------------------------------------------------------
# property tests


@settings(max_examples=200)  # the central property: worth more examples than the default
@given(cases())
def test_monitor_matches_brute_force_oracle(case):
    traj, formula = case
    trace = _oracle_trace(traj)
    L = traj.num_of_steps + 1
    for k in range(L + 2):  # in range and past the end (strong reading: nothing holds there)
        expected = sat(formula, k, trace)
        assert stl.satisfies(traj, formula, k) == expected, (str(formula), k)
        assert (stl.robustness(traj, formula, k) >= 0.0) == expected, (str(formula), k)


@given(cases())
def test_robustness_sign_is_satisfaction(case):
    traj, formula = case
    r = stl.robustness(traj, formula)
    assert not np.isnan(r)
    assert (r >= 0.0) == stl.satisfies(traj, formula)
    report = stl.monitor(traj, formula)
    assert report.satisfied == stl.satisfies(traj, formula)
    assert report.margin == r or (np.isinf(r) and report.margin == r)


# --------------------------------------------------------------------------------------------
# hand cases

ZERO = np.zeros((2, 2))


def _bool_traj(values: list[float], actions=None) -> stl.ProbabilisticTSTrajectory:
    """Means whose x[0] takes the given values; covariance zero; all mode 0 by default."""
    L = len(values)
    means = np.c_[np.asarray(values, dtype=float), np.zeros(L)]
    acts = [0] * (L - 1) if actions is None else actions
    return _traj(means, np.zeros((L, 2, 2)), acts)


P = stl.logical_and(stl.prob(X[0] >= 1) >= 0.9, name="p")  # x[0] >= 1
R = stl.logical_and(stl.prob(X[0] >= 2) >= 0.9, name="r")  # x[0] >= 2


def test_until_needs_left_operand_only_from_k_plus_a():
    # p false at 0, true at 1; r true at 2.
    traj = _bool_traj([0.0, 1.0, 2.0])
    assert stl.satisfies(traj, stl.until(P, 1, 3, R))
    assert not stl.satisfies(traj, stl.until(P, 0, 3, R))
    # the witness itself need not satisfy the left operand
    traj2 = _bool_traj([0.0, 0.0, 2.0])
    assert not stl.satisfies(traj2, stl.until(P, 1, 2, R))
    assert stl.satisfies(traj2, stl.until(P, 2, 2, R))


def test_plan_too_short_to_witness_always_fails():
    G = stl.always(0, 3, P)
    assert not stl.satisfies(_bool_traj([1.0, 1.0, 1.0]), G)  # indices 0..2 only
    assert stl.satisfies(_bool_traj([1.0, 1.0, 1.0, 1.0]), G)
    assert not stl.satisfies(_bool_traj([1.0, 1.0, 0.0, 1.0]), G)
    # eventually beyond the end fails too
    assert not stl.satisfies(_bool_traj([0.0, 0.0]), stl.eventually(2, 4, stl.TRUE))
    assert stl.satisfies(_bool_traj([0.0, 0.0, 0.0]), stl.eventually(2, 4, stl.TRUE))


def test_release_semantics_by_hand():
    # r holds at 0..1, p (release trigger) holds at 1: released at k'=1.
    traj = _bool_traj([2.0, 2.0, 0.0])
    # p at k'=1 requires x>=1: yes (2.0). f2 = r on [0, 1]: yes.
    assert stl.satisfies(traj, stl.release(P, 0, 5, R))
    assert not stl.satisfies(traj, stl.always(0, 5, R))
    traj2 = _bool_traj([0.0, 1.0, 2.0])  # r fails at 0: nothing can release it
    assert not stl.satisfies(traj2, stl.release(P, 0, 2, R))


def test_constants_and_mode_atoms():
    traj = _bool_traj([0.0, 0.0, 0.0], actions=[1, 0])
    q = stl.mk_variable(2, dtype=int)
    q1 = stl.logical_and(q == 1)
    assert [stl.satisfies(traj, q1, k) for k in range(3)] == [True, True, False]
    assert all(stl.satisfies(traj, stl.TRUE, k) for k in range(3))
    assert not stl.satisfies(traj, stl.TRUE, 3)
    assert not any(stl.satisfies(traj, stl.FALSE, k) for k in range(4))
    empty = STLAtomicProposition((), ())  # a user's empty mode set keeps the literal reading
    assert [stl.satisfies(traj, empty, k) for k in range(3)] == [True, False, False]
    # G[0,0] f == f at 0 (not collapsed by a vacuous false at k = 0)
    assert not stl.satisfies(_bool_traj([0.0]), stl.always(0, 0, P))
    assert stl.satisfies(_bool_traj([1.0]), stl.always(0, 0, P))


def test_chance_constraint_uses_covariance():
    # x[0] >= 1 with 90%: mean 1.5, sd s: need 1.5 - 1.2816 s >= 1, i.e. s <= 0.390
    for sd, expected in [(0.3, True), (0.45, False)]:
        traj = _traj([[1.5, 0.0]], [[[sd**2, 0.0], [0.0, 9.0]]], [])
        assert stl.satisfies(traj, P) == expected
        margin = stl.robustness(traj, P)
        assert margin == pytest.approx(1.5 - 1.0 - 1.2815515655446004 * sd)


def test_monitor_rejects_bad_step_index_and_dimension():
    traj = _bool_traj([1.0, 1.0])
    with pytest.raises(stl.InvalidArgumentError, match="k must be >= 0"):
        stl.robustness(traj, P, -1)
    y = stl.mk_variable(3, name="y")
    f3 = stl.logical_and(stl.prob(y[0] <= 1) >= 0.9, name="f3")
    with pytest.raises(stl.DimensionError, match="3-dimensional"):
        stl.satisfies(traj, f3)


def test_monitor_report_names_atoms():
    traj = _bool_traj([0.0, 1.0, 2.0])
    report = stl.monitor(traj, stl.until(P, 0, 2, R))
    assert set(report.atom_margins) == {"p", "r"}
    np.testing.assert_allclose(report.atom_margins["r"], [-2.0, -1.0, 0.0])
    assert report.satisfied is False  # p fails at 0
