"""Termination as a contract: ``|`` and ``&`` truth tables, a user predicate checked where the
work budgets are, and a cancellation from another thread (issue 33)."""

from __future__ import annotations

import itertools
import threading

import pytest
from benchmarks.defaults_problems import corridor

import idstlpy as stl
from idstlpy.errors import InvalidArgumentError, InvalidTypeError
from idstlpy.synthesis.termination import CANCELLED, SearchProgress, Termination


def _const(value: bool) -> Termination:
    return Termination.when(lambda _: value, name=str(value))


@pytest.mark.parametrize(("a", "b"), list(itertools.product([False, True], repeat=2)))
def test_or_and_and_follow_their_truth_tables(a, b):
    p = SearchProgress()
    assert ((_const(a) | _const(b)).reached(p) is not None) == (a or b)
    assert ((_const(a) & _const(b)).reached(p) is not None) == (a and b)


@pytest.mark.parametrize(("a", "b", "c"), list(itertools.product([False, True], repeat=3)))
def test_nested_compositions_follow_boolean_algebra(a, b, c):
    p = SearchProgress()
    A, B, C = _const(a), _const(b), _const(c)
    assert (((A | B) & C).reached(p) is not None) == ((a or b) and c)
    assert ((A | (B & C)).reached(p) is not None) == (a or (b and c))
    assert (((A & B) & C).reached(p) is not None) == (a and b and c)


@pytest.mark.parametrize(("cands", "lps"), list(itertools.product([0, 2, 5], [0, 9, 10])))
def test_work_budgets_compose_by_both_operators(cands, lps):
    """``&`` of two work budgets holds when both are spent, ``|`` when either is."""
    p = SearchProgress(candidates=cands, lp_calls=lps)
    c, lp = Termination.work(candidates=2), Termination.work(lp_calls=10)
    assert ((c & lp).reached(p) is not None) == (cands >= 2 and lps >= 10)
    assert ((c | lp).reached(p) is not None) == (cands >= 2 or lps >= 10)


def test_and_reports_both_reasons():
    held = (Termination.work(candidates=1) & _const(True)).reached(SearchProgress(candidates=1))
    assert held is not None and "max_candidates = 1 reached" in held.reason
    assert "stop condition True held" in held.reason


def test_bad_compositions_raise_naming_the_argument():
    with pytest.raises(InvalidArgumentError, match="first"):
        Termination.first() & Termination.work(candidates=3)
    with pytest.raises(InvalidTypeError, match="predicate"):
        Termination.when(3)  # type: ignore[arg-type]
    with pytest.raises(InvalidTypeError, match="rules"):
        Termination(rules=("not a rule",))  # type: ignore[arg-type]


def test_the_predicate_sees_the_progress_counters_before_each_candidate():
    seen: list[SearchProgress] = []

    def record(p: SearchProgress) -> bool:
        seen.append(p)
        return p.candidates >= 3

    result = corridor().solve_result(seed=0, termination=Termination.when(record))
    assert result.status == "budget_exhausted"
    assert "stop condition record held" in result.reason
    assert [p.candidates for p in seen] == [0, 1, 2, 3]
    assert all(a.lp_calls <= b.lp_calls for a, b in itertools.pairwise(seen))
    assert seen[-1].refuted + seen[-1].abandoned <= 3


@pytest.mark.parametrize("n", [2, 4])
def test_a_predicate_stopping_after_n_candidates_equals_max_candidates(n):
    by_budget = corridor().solve_result(seed=0, max_candidates=n)
    by_rule = corridor().solve_result(seed=0, termination=Termination.when(lambda p: p.candidates >= n))
    assert by_rule.status == by_budget.status
    assert by_rule.to_dict()["plan"] == by_budget.to_dict()["plan"]
    for key in ("candidates", "refuted", "abandoned", "lp_calls", "sat_calls", "milp_calls"):
        assert getattr(by_rule.stats, key) == getattr(by_budget.stats, key), key
    assert by_rule.stats.candidates == n


def test_and_in_a_solve_waits_for_both():
    """The work budget alone stops after 2 candidates; with ``&`` the predicate decides."""
    both = Termination.work(candidates=2) & Termination.when(lambda p: p.candidates >= 4)
    result = corridor().solve_result(seed=0, termination=both)
    assert result.status == "budget_exhausted"
    assert result.stats.candidates == 4
    assert "max_candidates = 2 reached and stop condition" in result.reason


def test_a_cancel_from_another_thread_ends_the_solve_at_its_next_check():
    """The replanner's thread cancels while the solve is between candidates 2 and 3 (a
    handshake through the predicate, not a sleep); the solve ends at the next check."""
    stop = Termination.cancellable()
    at_two, cancelled = threading.Event(), threading.Event()

    def pause_at_two(p: SearchProgress) -> bool:
        if p.candidates == 2:
            at_two.set()
            assert cancelled.wait(60)
        return False

    def replanner() -> None:
        at_two.wait(60)
        stop.cancel()
        cancelled.set()

    thread = threading.Thread(target=replanner)
    thread.start()
    try:
        long = stop | Termination.when(pause_at_two) | Termination.work(candidates=10_000)
        result = corridor().solve_result(seed=0, termination=long)
    finally:
        cancelled.set()
        thread.join()
    assert stop.cancelled
    assert result.status == "budget_exhausted"
    assert "cancelled" in result.reason
    assert CANCELLED in result.stats.caps_hit
    assert result.stats.candidates == 3  # candidate 3 was proposed before the next check


def test_an_uncancelled_token_changes_nothing():
    plain = corridor().solve_result(seed=0, max_candidates=3)
    with_token = corridor().solve_result(
        seed=0, termination=Termination.cancellable() | stl.Termination.work(candidates=3)
    )
    assert with_token.reason == plain.reason
    assert with_token.stats.caps_hit == plain.stats.caps_hit


def test_a_solve_cancelled_before_it_starts_proposes_nothing_and_starts_no_other_solve():
    stop = Termination.cancellable()
    stop.cancel()
    result = corridor().solve_result(seed=0, termination=stop)
    assert result.status == "budget_exhausted" and result.reason.startswith("cancelled")
    assert result.stats.candidates == 0
    assert result.stats.caps_hit == [CANCELLED]
