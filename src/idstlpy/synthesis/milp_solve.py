"""Solving the eager MILP: its phases and the proofs they give.

:mod:`.milp_model` builds the model; here it is solved, by objective:

- without one, a first look at the model as built, then the full solve
  (:func:`solve_feasibility`); its ``infeasible`` is a proof;
- ``"margin"``: a probe at the cap, a ladder of feasibility probes and the full optimisation
  above the best level (:func:`solve_margin`), each plan's exact margin from the LP over its
  letters (:func:`_polish`), the optimum proven when that meets the bound within
  :data:`PROOF_TOL`;
- with an objective, an ``infeasible`` is re-checked with every face moved out (:func:`recheck`):
  it is a proof only when that model is infeasible too.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from ..backends import Backend, BackendSolution, HighsBackend, LinearModel
from .interfaces import Budget

__all__ = [
    "PROOF_TOL",
    "MILPOutcome",
    "MILPStatus",
    "MarginAnswer",
    "recheck",
    "solve_feasibility",
    "solve_margin",
]

# One log for the whole eager MILP (model, phases, outcome): users and tests filter on it.
logger = logging.getLogger("idstlpy.synthesis.milp")

# A margin is proven optimal when the exact LP value of the MILP's plan is this close (relative,
# at least absolute) to the MILP's bound: the MILP's rows hold only within its feasibility
# tolerance (1e-6 of a scaled row), so its bound can exceed the true optimum by about that much.
PROOF_TOL = 1e-6

MILPStatus = Literal["found", "infeasible", "borderline", "timeout", "unsupported"]


class MILPOutcome:
    """What the eager MILP returns.

    Attributes
    ----------
    status : {"found", "infeasible", "borderline", "timeout", "unsupported"}
        ``infeasible`` is a proof for plans of at most ``bound`` steps; ``borderline``: the
        model is infeasible only within the solvers' tolerances (no proof either way);
        ``unsupported`` means the model could not be bounded soundly (unbounded inputs, huge
        big-M).
    actions : ndarray of int, shape (H,), or None
    controls : ndarray, shape (H, m), or None
    claims : ndarray of bool, shape (n_atoms, H + 1), or None
    why : str
    value, bound : float
        The objective's value and the solver's proven bound (``nan`` without an objective).
    proven : bool
        True when the MILP proved its solution optimal (within the bound it was built for).
    """

    def __init__(
        self,
        status: MILPStatus,
        actions: np.ndarray | None = None,
        controls: np.ndarray | None = None,
        claims: np.ndarray | None = None,
        why: str = "",
    ) -> None:
        self.status = status
        self.actions = actions
        self.controls = controls
        self.claims = claims
        self.why = why
        self.value = float("nan")
        self.bound = float("nan")
        self.proven = False


MarginAnswer = tuple[str, np.ndarray | None, np.ndarray | None, float, str]
"""What :func:`solve_margin` returns: ``(status, x, exact, bound, message)``."""


_PROBE_NODES = 2000
_LADDER_RUNGS = 6  # levels above the first plan tried before the full optimisation takes over
# The ladder's probes hold every row within this (SCIP's default is 1e-6): a level half the proof
# tolerance above the best plan is then refuted by presolve alone where the default tolerance
# lets the solver "reach" it (SteppingStones T = 25: infeasible in 0.18 s at 1e-8, a 43-node
# search that returns a plan 1e-6 short at 1e-6).
_LADDER_FEAS_TOL = 1e-8


def _probe(
    model: LinearModel,
    backend: Backend,
    tcol: int,
    level: float,
    budget: Budget,
    node_limit: int | None = _PROBE_NODES,
    feas_tol: float | None = None,
    probing: Literal["full", "short", "off"] = "full",
) -> BackendSolution:
    """A feasibility MILP for a plan whose margin is at least ``level``.

    Without an objective, with the margin's lower bound at ``level``: where the level is
    attained the solver only has to find one plan, and where it is not its presolve (probing
    on the letters, with every face shrunk by the level) usually proves it in one pass.
    """
    budget.check("the eager MILP")
    lb = model.lb.copy()
    lb[tcol] = level
    probe = LinearModel(
        np.zeros_like(model.c),
        model.A,
        model.row_lo,
        model.row_hi,
        lb,
        model.ub,
        model.integrality,
        cuts=False,
        node_limit=node_limit,
        feas_tol=feas_tol,
        probing=probing,
    )
    sol = backend.solve(probe, max(budget.remaining(), 1e-3))
    logger.info("MILP margin: probe at %.12g: %s", level, sol.message)
    return sol


def solve_margin(
    model: LinearModel, backend: Backend, tcol: int, t_cap: float, t_sound: bool, budget: Budget
) -> MarginAnswer:
    """The margin MILP's optimum: ``(status, x, exact, bound, message)``.

    ``status`` is ``"optimal"`` (``bound`` is a proven bound on every plan's margin: the cap, a
    refuted level or the solver's bound), ``"time_limit"`` (``bound`` the solver's, or ``nan``),
    ``"infeasible"`` or ``"error"``; ``x`` the MILP's solution and ``exact`` the LP over its
    letters (:func:`_polish`), whose margin is the plan's.

    With a sound cap, three steps:

    1. a probe at the cap (most stlpy scenarios attain it: a goal's centre, the start's own
       margin): a plan there is optimal by the cap alone;
    2. a ladder: a probe at margin 0 finds a first plan, its exact margin ``v`` comes from the
       LP over its letters, and a probe at ``v`` plus half the proof tolerance either finds a
       better plan (the next rung) or is refuted, which proves ``v`` optimal. Presolve with the
       margin fixed is strong (every face shrinks by it, so probing on the letters propagates
       through the dynamics), where the optimisation's relaxation keeps its bound at the cap
       until deep in the tree (SteppingStones T = 25: three rungs 0.034 -> 0.043 -> 0.0527 and a
       refutation, ~0.8 s, against 2.2 s and 1,700 nodes);
    3. after ``_LADDER_RUNGS`` rungs, or a probe that stops at its node budget, the full
       optimisation above the best level so far (:func:`_optimise_above`).
    """
    best = _Ladder(level=model.lb[tcol])
    if t_sound and t_cap > 0:
        done = _climb(model, backend, tcol, t_cap, budget, best)
        if done is not None:
            return done
    return _optimise_above(model, backend, tcol, budget, best)


@dataclass
class _Ladder:
    """The margin ladder's state: the level to probe, the best plan so far and its exact margin."""

    level: float
    x: np.ndarray | None = None
    exact: np.ndarray | None = None
    v: float | None = None


def _climb(
    model: LinearModel, backend: Backend, tcol: int, t_cap: float, budget: Budget, best: _Ladder
) -> MarginAnswer | None:
    """Steps 1 and 2 of :func:`solve_margin`: the probe at the cap, then the ladder.

    Returns the answer when a probe decides it, else ``None`` with ``best`` holding the best
    plan and level so far (the optimisation takes over).
    """
    top = t_cap * (1.0 - 1e-7)
    sol = _probe(model, backend, tcol, top, budget, probing="short")
    if sol.status in ("optimal", "time_limit") and sol.x is not None:
        polished = _polish(model, sol.x, tcol, budget)
        if polished is not None and polished[tcol] >= t_cap - PROOF_TOL * max(1.0, t_cap):
            return "optimal", sol.x, polished, t_cap, "a plan at the cap"
        # The probe reached the cap only within the solver's tolerances.
        logger.info("MILP margin: the probe's plan is below the cap")
        if polished is not None:
            best.x, best.exact, best.v = sol.x, polished, float(polished[tcol])
    for _ in range(_LADDER_RUNGS + 1):
        if best.v is not None:
            best.level = best.v + 0.5 * PROOF_TOL * max(1.0, abs(best.v))
            if best.level >= top:
                return "optimal", best.x, best.exact, t_cap, "the cap"
        sol = _probe(
            model,
            backend,
            tcol,
            best.level,
            budget,
            node_limit=_PROBE_NODES if best.v is not None else None,
            feas_tol=_LADDER_FEAS_TOL,
        )
        if sol.status == "infeasible":
            if best.v is None:
                return "infeasible", None, None, float("nan"), sol.message
            return "optimal", best.x, best.exact, best.level, f"level {best.level:.12g} refuted"
        if sol.x is None:
            break  # the node budget or an error: the optimisation decides
        polished = _polish(model, sol.x, tcol, budget)
        if polished is None or (best.v is not None and polished[tcol] <= best.v):
            break  # no progress within the tolerances
        best.x, best.exact, best.v = sol.x, polished, float(polished[tcol])
        logger.info("MILP margin: ladder at %.12g", best.v)
    return None


def _optimise_above(
    model: LinearModel, backend: Backend, tcol: int, budget: Budget, best: _Ladder
) -> MarginAnswer:
    """Step 3 of :func:`solve_margin`: the full optimisation above the best level so far."""
    x, exact, v, level = best.x, best.exact, best.v, best.level
    full = model
    if v is not None:
        lb = model.lb.copy()
        lb[tcol] = level
        full = LinearModel(
            model.c,
            model.A,
            model.row_lo,
            model.row_hi,
            lb,
            model.ub,
            model.integrality,
            cuts=model.cuts,
            feas_tol=_LADDER_FEAS_TOL,
        )
    sol = backend.solve(full, max(budget.remaining(), 1e-3))
    if sol.status == "infeasible" and v is not None:
        return "optimal", x, exact, level, f"level {level:.12g} refuted by the optimisation"
    if sol.status in ("optimal", "time_limit") and sol.x is not None:
        polished = _polish(model, sol.x, tcol, budget)
        if v is None or (polished is not None and polished[tcol] > v):
            x, exact = sol.x, polished
        bound = -float(sol.bound)
        if v is not None and np.isfinite(bound):
            bound = max(bound, level)  # the optimisation only saw the plans above the level
        return sol.status, x, exact, bound, sol.message
    if x is not None:
        return "time_limit", x, exact, float("nan"), sol.message
    return sol.status, None, None, float("nan"), sol.message


def solve_feasibility(model: LinearModel, backend: Backend, budget: Budget) -> BackendSolution:
    """Any plan of the feasibility MILP: a first look at the model as built, then the full solve.

    The first look (:attr:`LinearModel.first_look`) runs only shift-and-propagate, before the
    first LP, on the model without presolve; where it finds no plan, the full solve starts from
    scratch on the same (cached) model. On the eager MILPs of stlpy's scenarios presolve
    reshapes the model so that the heuristics miss the plan shift-and-propagate finds at once
    on the model as built, leaving it to diving after the root LP (NarrowPassage T = 100:
    0.31 -> 0.06 s CPU, T = 200: 0.71 -> 0.16 s; EitherOr, RandomMultitarget, ReachAvoid at
    T = 25-200 and SteppingStones at T = 25 gain too). Where the look finds nothing
    (SteppingStones T = 50-200, DoorPuzzle) it costs 5-25% of the full solve. Both are
    deterministic (node and iteration limits, no clock), and an ``infeasible`` of either is a
    proof.
    """
    look = backend.solve(replace(model, first_look=True), max(budget.remaining(), 1e-3))
    if look.x is not None or look.status == "infeasible":
        return look
    logger.info("MILP: the first look found no plan (%s); full solve", look.message)
    budget.check("the eager MILP")
    return backend.solve(model, max(budget.remaining(), 1e-3))


def _polish(model: LinearModel, x: np.ndarray, tcol: int, budget: Budget) -> np.ndarray | None:
    """The LP of ``model`` with its integer columns fixed at ``x`` rounded (``None`` if it fails).

    The fixed columns are substituted out of the rows and the rows left without a column (the
    clauses over letters only) dropped, so HiGHS gets the continuous part alone (5 -> 3.5 ms on
    NarrowPassage's T = 25 model). Returns the full vector, the letters at their rounded values.
    """
    ints = np.zeros(model.num_vars, dtype=bool) if model.integrality is None else model.integrality != 0
    fixed = np.round(x[ints])
    A = model.A.tocsc()
    cont = np.nonzero(~ints)[0]
    shift = A[:, np.nonzero(ints)[0]] @ fixed
    Ac = A[:, cont].tocsr()
    keep = np.diff(Ac.indptr) > 0
    lo, hi = model.row_lo - shift, model.row_hi - shift
    if np.any(lo[~keep] > 1e-9) or np.any(hi[~keep] < -1e-9):
        logger.info("MILP margin: the MILP's letters violate a clause; no exact LP")
        return None
    lp = LinearModel(model.c[cont], Ac[keep], lo[keep], hi[keep], model.lb[cont], model.ub[cont])
    sol = HighsBackend().solve(lp, max(budget.remaining(), 1e-3))
    if sol.status != "optimal" or sol.x is None:
        logger.info("MILP margin: the LP over the MILP's letters did not solve (%s)", sol.message)
        return None
    out = np.empty(model.num_vars)
    out[ints] = fixed
    out[cont] = sol.x
    return out


_RECHECK_TOL = 1e-6
"""How far (normalised rows, in scaled state units) :func:`recheck` moves every face outward."""


def recheck(
    model: LinearModel, backend: Backend, budget: Budget, face_rows: Sequence[tuple[int, int]]
) -> MILPOutcome:
    """Whether an objective MILP's ``infeasible`` survives its tolerance (issue 25).

    The same model without an objective and with every face moved out by :data:`_RECHECK_TOL`
    is solved: still infeasible, the answer is a proof (``"infeasible"``); a plan there means
    the problem is infeasible at most by the solvers' tolerances, and the answer rests on them
    (``"borderline"``); anything else is ``"timeout"``.
    """
    row_hi = model.row_hi.copy()
    for first, count in face_rows:
        row_hi[first : first + count] += _RECHECK_TOL
    loose = replace(model, c=np.zeros_like(model.c), row_hi=row_hi, mip_rel_gap=None)
    sol = backend.solve(loose, max(budget.remaining(), 1e-3))
    if sol.status == "infeasible":
        return MILPOutcome("infeasible", why="the MILP is infeasible, with every face moved out by 1e-6")
    if sol.x is not None:
        return MILPOutcome(
            "borderline",
            why="the MILP is infeasible only within 1e-6 of the faces (a tolerance decides it)",
        )
    return MILPOutcome("timeout", why=f"the re-check of the MILP's infeasibility stopped: {sol.message}")
