"""What a stopped search can still show: the loop's progress counters, the longest feasible
prefix of a refuted candidate (``result.closest`` when no teacher reported one) and how many
candidates of the current length were left (the advice's value for ``max_candidates``).

The loop (:mod:`.cegis`) reports its counters after each candidate and hands the other two to
:class:`~.context.SolveContext` as callables; :func:`~.finish.finish` calls them once, after the
search stopped, with their work kept out of the solve's statistics.
"""

from __future__ import annotations

import numpy as np

from .. import _progress as progress
from .context import SolveContext
from .interfaces import Found, Proposer, ProposerDry, Refuted, Teacher
from .plan import DiscretePlan
from .results import SolveStats

__all__ = ["PARTIAL_TRIES", "partial_plan", "remaining", "report"]


def report(ctx: SolveContext, length: int) -> None:
    """The loop's counters for a progress display (:mod:`idstlpy._progress`)."""
    s = ctx.stats
    progress.report(
        candidates=s.candidates,
        refuted=s.refuted,
        abandoned=s.abandoned,
        length=length,
        below_target=s.below_target,
        sampler_iterations=0,
    )


def remaining(ctx: SolveContext, proposer: Proposer, cap: int) -> tuple[int, int] | None:
    """``(n, steps)``: at most ``n`` candidates of at most ``steps`` steps remain (each one the
    proposer still offers is set aside to count the next; a refutation would exclude at least as
    much), or ``None`` past ``cap``. Called once the search has stopped: it changes the proposer."""
    bound, calls = proposer.bound, proposer.sat_calls
    try:
        return _count(proposer, bound, cap)
    finally:
        ctx.uncounted_sat_calls += proposer.sat_calls - calls


def _count(proposer: Proposer, bound: int, cap: int) -> tuple[int, int] | None:
    """:func:`remaining`'s count."""
    for n in range(cap + 1):
        plan = proposer.propose()
        if isinstance(plan, ProposerDry) or proposer.bound != bound or plan.length - 1 > bound:
            return n, bound
        proposer.abandon(plan)
    return None


PARTIAL_TRIES = 4
"""Prefixes of the last refuted candidate tried for ``result.closest`` (each one plan LP)."""


def partial_plan(
    ctx: SolveContext, teacher: Teacher, plan: DiscretePlan, refuted: Refuted
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The longest prefix of ``plan`` the teacher finds a plan for, among prefixes ending before
    the refutation's last requirement, halved up to :data:`PARTIAL_TRIES` times: what the search
    got closest to when every candidate was refuted (``result.closest``; not a plan). Its work is
    counted apart (the solve's statistics stay the search's)."""
    last = max((k for k, _ in refuted.conflict.requirements), default=plan.length - 1)
    length = min(last, plan.length - 1)  # the steps 0..last-1, before the last requirement
    scratch = SolveStats()
    for _ in range(PARTIAL_TRIES):
        if length < 2:
            return None
        prefix = DiscretePlan(plan.required[:, :length].copy(), plan.modes[:length].copy(), length)
        verdict = teacher.teach(prefix, ctx.budget, scratch)
        if isinstance(verdict, Found):
            return verdict.actions, verdict.controls, length / plan.length
        length //= 2
    return None
