"""What to raise after ``budget_exhausted``: the budget that decided, and a value to try.

A ``budget_exhausted`` result is not a statement about the problem: some budget ended the search.
Its reason should let a user act without reading the solver: which budget decided, how much of
each was spent, and the option to raise (with a concrete value). The advice is read off the
solve's counters and options, never guessed from the wording of the reason.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..dynamical_system import POLBSWithNonLinNoise, SwitchedSystem
from .options import SolverOptions
from .results import SolveStats

__all__ = ["budget_advice", "floorless_modes"]


def floorless_modes(system: SwitchedSystem) -> list[int]:
    """The modes whose sensor noise is state-dependent with no declared ``V_floor``.

    Their noise floor is zero, so no covariance-floor proof can show a confidence out of reach:
    a search that ends on such a problem says how to make the proofs apply.
    """
    return [
        q
        for q, mode in enumerate(system.system_modes)
        if isinstance(mode, POLBSWithNonLinNoise) and not np.any(mode.noise_floor)
    ]


def _g(value: float) -> str:
    return f"{value:.3g}"


def _candidates_tip(budget: int, remaining: tuple[int, int] | None) -> str:
    """What to raise after ``max_candidates = budget`` decided: the value that settles the current
    length where the candidates left were counted, else four times the budget."""
    if remaining is None:
        return f"raise max_candidates (it was {budget}; try {4 * budget})"
    n, steps = remaining
    return (
        f"raise max_candidates (it was {budget}; try {budget + n}: at most {n} candidates of at "
        f"most {steps} steps were left, so {budget + n} settles plans that short: a plan, or none "
        "of them left)"
    )


def budget_advice(
    reason: str,
    stats: SolveStats,
    options: SolverOptions,
    horizon: int | None = None,
    sampler_abandoned: int = 0,
    floorless: Sequence[int] = (),
    remaining: tuple[int, int] | None = None,
) -> str:
    """One sentence naming what to raise after a ``budget_exhausted`` answer.

    Parameters
    ----------
    reason : str
        The solve's reason so far (says which budget stopped the loop).
    stats : SolveStats
        The solve's counters (candidates, abandoned, caps hit, sampler iterations).
    options : SolverOptions
        The options the solve ran with (their values scale the suggestions).
    horizon : int, optional
        The formula's horizon, the most ``max_plan_length`` ever needs.
    sampler_abandoned : int
        Candidates the belief sampler gave up on (its work budget or its wall-clock cap); the
        other abandoned candidates failed for reasons no budget changes.
    floorless : sequence of int
        Modes with state-dependent sensor noise and no declared ``V_floor``
        (:func:`floorless_modes`): no more budget can turn their search into a proof.
    remaining : (int, int), optional
        ``(n, steps)``: at most ``n`` candidates of at most ``steps`` steps were left when
        ``max_candidates`` stopped the search (counted up to four times the budget): the
        candidates that settle plans of that length.

    Returns
    -------
    str
        ``"to search further: ..."``, or ``""`` when no budget option would change the answer
        (for instance, a refutation that holds only for one risk allocation).
    """
    tips: list[str] = []
    stop, search, sampler = options.termination, options.search, options.sampler
    if "max_candidates" in reason and stop.candidates is not None:
        tips.append(_candidates_tip(stop.candidates, remaining))
    if "max_lp_calls" in reason and stop.lp_calls is not None:
        tips.append(f"raise max_lp_calls (it was {stop.lp_calls}; try {4 * stop.lp_calls})")
    if "max_plan_length" in reason:
        longer = 4 * search.max_plan_length
        if horizon is not None and horizon > 0:
            longer = min(longer, int(horizon))
        tips.append(f"raise max_plan_length (it was {search.max_plan_length}; try {longer})")
    if sampler_abandoned:
        per = sampler.iterations
        if "rrt_timeout" in stats.caps_hit:
            tips.append(
                f"{sampler_abandoned} of {stats.candidates} candidates were abandoned when the "
                f"sampler's wall-clock cap rrt_timeout={_g(sampler.rrt_timeout)} s ended their "
                f"search: raise rrt_timeout (try {_g(4 * sampler.rrt_timeout)})"
            )
        else:
            tips.append(
                f"{sampler_abandoned} of {stats.candidates} candidates were abandoned by the "
                f"sampler after its work budget of {per} iterations each: raise "
                f"sampler_iterations (try {4 * per}) or rrt_timeout (it scales the default)"
            )
    # Work budgets first: they decide the search; the wall clock only caps it.
    if "time_limit" in stats.caps_hit:
        cap = stop.seconds if stop.seconds is not None else options.total_time_cap
        tips.append(f"raise time_limit (it was {_g(cap)} s; try time_limit={_g(4 * cap)})")
    if not tips:
        return ""
    advice = "to search further: " + "; ".join(tips)
    if floorless:
        # A new user's impossible task (a sensor never better than 0.5) searched for minutes:
        # the proofs need the noise's lower bound, which a callable cannot state by itself.
        advice += (
            f". If the task may be impossible: mode(s) {list(floorless)} have state-dependent "
            "sensor noise without V_floor, so no noise-floor proof applies; declare "
            "mk_lbs(..., V_floor=...) (a constant the noise never goes below) so that a "
            "confidence out of reach of that floor is proven infeasible"
        )
    return advice
