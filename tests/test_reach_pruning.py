"""Multi-step reach pruning: proven gaps between regions, and transitions without room."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import idstlpy as stl
from idstlpy.synthesis.abstraction import Abstraction
from idstlpy.synthesis.interfaces import Budget, ProposerDry
from idstlpy.synthesis.options import SolverOptions
from idstlpy.synthesis.plan import DiscretePlan
from idstlpy.synthesis.proposer import BMCProposer
from idstlpy.synthesis.results import SolveStats

X = stl.mk_variable(1)
U = stl.mk_variable(1, name="u")
DOMAIN = stl.Polytope(np.array([[1.0], [-1.0]]), np.array([-1.0, -1.0]))  # |u| <= 1


def _box(lo: float, hi: float, name: str):
    return stl.logical_and(stl.prob(X[0] >= lo) >= 0.9, stl.prob(X[0] <= hi) >= 0.9, name=name)


def _abstraction(formula):
    return Abstraction(formula, 1)


def _prune(formula, modes, reach=True, max_gap=20):
    abstraction = _abstraction(formula)
    report = abstraction.prune(
        stl.mk_switched_sys(modes),
        DOMAIN,
        np.zeros(1),
        0.01 * np.eye(1),
        reach=reach,
        max_gap=max_gap,
    )
    return abstraction, report


A_BOX, B_BOX = _box(0.0, 0.5, "a"), _box(2.5, 3.0, "b")
FORMULA = stl.logical_and(stl.eventually(0, 20, A_BOX), stl.eventually(0, 20, B_BOX))


def test_gaps_are_proven_then_roomless_for_a_single_integrator():
    # x' = x + 0.5 u: from a = [0, 0.5] to b = [2.5, 3] is 2.0 at least, 0.5 a step: 4 steps;
    # centre to centre (0.25 -> 2.75) is 2.5: 5 steps.
    abstraction, report = _prune(FORMULA, [stl.mk_lbs(np.eye(1), 0.5 * np.eye(1), 0.01 * np.eye(1))])
    a, b = (abstraction.names().index(n) for n in ("a", "b"))
    assert (a, b, -1) in report.impossible_steps
    assert sorted(d for i, j, d in report.impossible_gaps if (i, j) == (a, b)) == [2, 3]
    assert sorted(d for i, j, d in report.roomless_gaps if (i, j) == (a, b)) == [4]
    assert sorted(d for i, j, d in report.impossible_gaps if (i, j) == (b, a)) == [2, 3]


def test_gaps_take_the_fastest_mode_when_the_modes_share_a():
    # A slow mode (B = 0.1) does not slow the proof down: the hull holds the fast mode's moves.
    modes = [
        stl.mk_lbs(np.eye(1), 0.1 * np.eye(1), 0.01 * np.eye(1)),
        stl.mk_lbs(np.eye(1), 0.5 * np.eye(1), 0.01 * np.eye(1)),
    ]
    abstraction, report = _prune(FORMULA, modes)
    a, b = (abstraction.names().index(n) for n in ("a", "b"))
    assert sorted(d for i, j, d in report.impossible_gaps if (i, j) == (a, b)) == [2, 3]


def test_no_gap_is_claimed_for_modes_with_different_dynamics_or_without_reach():
    modes = [
        stl.mk_lbs(np.eye(1), 0.5 * np.eye(1), 0.01 * np.eye(1)),
        stl.mk_lbs(0.9 * np.eye(1), 0.5 * np.eye(1), 0.01 * np.eye(1)),
    ]
    _, report = _prune(FORMULA, modes)
    assert report.impossible_gaps == [] and report.roomless_gaps == []
    _, report = _prune(FORMULA, [stl.mk_lbs(np.eye(1), 0.5 * np.eye(1), 0.01 * np.eye(1))], reach=False)
    assert report.impossible_gaps == [] and report.roomless_gaps == []


def _proposer(formula, report):
    opts = SolverOptions(seed=0)
    return BMCProposer(formula, _abstraction(formula), 1, report, opts, Budget(60.0), SolveStats())


def _gap(plan: DiscretePlan, names: list[str]) -> int:
    a, b = names.index("a"), names.index("b")
    ka = np.nonzero(plan.required[a])[0]
    kb = np.nonzero(plan.required[b])[0]
    return int(kb.min() - ka.max()) if ka.size and kb.size else -1


def test_the_proposer_prefers_transitions_with_room_then_drops_the_preference():
    # a then b (the order matters): the proven gaps exclude 1..3 steps, the roomless one 4.
    formula = stl.eventually(0, 20, stl.logical_and(A_BOX, stl.eventually(1, 20, B_BOX)))
    abstraction, report = _prune(formula, [stl.mk_lbs(np.eye(1), 0.5 * np.eye(1), 0.01 * np.eye(1))])
    names = abstraction.names()
    proposer = _proposer(formula, report)
    first = proposer.propose()
    assert isinstance(first, DiscretePlan)
    assert _gap(first, names) >= 5  # shortest first, but never a transition without room
    # Only roomless plans left (every gap of 5 or more set aside): the preference is dropped
    # and a gap of 4 is offered; no infeasibility is claimed from a preference.
    for d in range(5, 22):
        for k in range(0, 22):
            proposer.soft.append([("p", names.index("a"), k, False), ("p", names.index("b"), k + d, False)])
            proposer._add(proposer.soft[-1], soft=True)
    nxt = proposer.propose()
    assert isinstance(nxt, DiscretePlan) and _gap(nxt, names) == 4
    assert not proposer.prefer_room
    proposer.close()


def test_a_preference_never_makes_a_proof():
    # Every plan of this formula makes the a -> b transition in exactly 4 steps (roomless): the
    # proposer still offers one (never a dry, proven answer).
    formula = stl.eventually(0, 6, stl.logical_and(A_BOX, stl.eventually(4, 4, B_BOX)))
    abstraction, report = _prune(formula, [stl.mk_lbs(np.eye(1), 0.5 * np.eye(1), 0.01 * np.eye(1))])
    assert report.roomless_gaps
    proposer = _proposer(formula, report)
    plan = proposer.propose()
    assert isinstance(plan, DiscretePlan) and _gap(plan, abstraction.names()) == 4
    proposer.abandon(plan)
    out = proposer.propose()
    while isinstance(out, DiscretePlan):
        proposer.abandon(out)
        out = proposer.propose()
    assert isinstance(out, ProposerDry) and not out.proven
    proposer.close()


def test_a_candidate_set_aside_takes_its_step_zero_variants_with_it():
    # (a or c) at step 0, b at step 1: the prior satisfies a and c, so {a@0, b@1} and {c@0, b@1}
    # are the same problem for a teacher; setting one aside sets the other aside too (no proof).
    a = stl.logical_and(stl.prob(X[0] <= 1.0) >= 0.9, name="a")
    c = stl.logical_and(stl.prob(X[0] >= -1.0) >= 0.9, name="c")
    b = stl.logical_and(stl.prob(X[0] <= 5.0) >= 0.9, name="b")
    formula = stl.logical_and(stl.logical_or(a, c), stl.eventually(1, 1, b))
    _, report = _prune(formula, [stl.mk_lbs(np.eye(1), 0.5 * np.eye(1), 0.01 * np.eye(1))])
    proposer = _proposer(formula, report)
    plan = proposer.propose()
    assert isinstance(plan, DiscretePlan)
    assert {k for k, _ in plan.requirements()} == {0, 1}
    proposer.abandon(plan)
    out = proposer.propose()
    assert isinstance(out, ProposerDry) and not out.proven
    proposer.close()


@settings(max_examples=40, deadline=None)
@given(st.integers(min_value=0, max_value=2**31 - 1))
def test_a_proven_gap_is_unreachable_for_every_mode_sequence(seed):
    """A multi-step gap is a proof: whenever the pruning LP says ``Ri`` cannot reach ``Rj`` in
    ``d`` steps, the brute force over every mode sequence (`tests/oracles/reach.py`) agrees, on
    random systems of 1-3 modes sharing ``A`` (some blind in the input: ``B = 0``)."""
    from oracles.reach import reachable

    from idstlpy.backends import HighsBackend
    from idstlpy.dynamical_system import mk_lcs, mk_switched_sys
    from idstlpy.sets import Polytope
    from idstlpy.synthesis.abstraction import _reaches

    rng = np.random.default_rng(seed)
    n, m, Q = int(rng.integers(1, 3)), int(rng.integers(1, 3)), int(rng.integers(1, 4))
    A = np.eye(n) + 0.3 * rng.standard_normal((n, n))
    Bs = [rng.standard_normal((n, m)) * rng.choice([0.0, 1.0, 3.0]) for _ in range(Q)]
    system = mk_switched_sys([mk_lcs(A, B) for B in Bs])
    u = rng.uniform(0.1, 1.0)
    U = (np.vstack([np.eye(m), -np.eye(m)]), -u * np.ones(2 * m))

    def box(centre: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.vstack([np.eye(n), -np.eye(n)]), np.concatenate([-(centre + half), centre - half])

    Ri = box(rng.uniform(-5, 5, n), rng.uniform(0.1, 1, n))
    Rj = box(rng.uniform(-5, 5, n), rng.uniform(0.1, 1, n))
    for d in (2, 3):
        claimed = _reaches(system, Polytope(*U), Polytope(*Ri), Polytope(*Rj), d, HighsBackend(), None, None)
        if not claimed:
            assert not reachable(A, Bs, U, Ri, Rj, d)
