"""Eager fallback for plans the LP decides exactly: the BMC encoding and the plan LP as one MILP.

When the covariance schedule does not depend on the mean (no state-dependent noise) and the
system has one mode, the lazy loop (SAT proposes, LP refutes) can need many candidates on
formulas with many disjunctions (obstacle sides, alternative targets). This module hands the same
problem to HiGHS' branch and bound in one piece:

- every SAT variable of the BMC encoding is a 0/1 variable, every clause ``l_1 | ... | l_r`` the
  row ``sum(pos) - sum(neg) >= 1 - |neg|``; the clauses learnt so far (pruning facts and
  counterexamples) come along. Only the letters (propositions, modes, trace length) are declared
  integer: the gates are Tseitin equivalences, integral whenever their inputs are, so branch and
  bound never branches on them (measured once each: SteppingStones T = 100 13.4 s -> 1.7 s,
  ReachAvoid T = 200 3.2 s -> 1.9 s, DoorPuzzle T = 100 unchanged);
- ``p[i, k] = 1`` implies the chance constraints of proposition ``i`` at step ``k`` through big-M
  rows whose ``M`` is the exact largest value of the face over the reachable means (support
  functions of the control domain), so the relaxation is as tight as big-M can be;
- the dynamics, the control domain and the fixed covariance schedule are as in the plan LP.

The encoding keeps the compact windows of :mod:`~idstlpy.synthesis.bmc` (``O(H log b)`` gates), so
the model is much smaller than the usual MILP encodings of STL.

Its ``infeasible`` is a proof for plans of at most ``bound + 1`` steps only when every big-M is
finite and moderate (a bounded control domain, or invariants that bound the means); otherwise
the model is not built (``unsupported``) and the lazy loop goes on. Variables are scaled and
rows normalised as in the plan LP (:mod:`.plan_lp`), so tolerances are relative to the problem.

With an objective the model is a relaxation of the problem (a claimed face holds within the
integrality tolerance times its big-M, never tighter), so its bound is a bound on every plan, and
its ``infeasible`` is re-checked with every face moved out by 1e-6 (:func:`_recheck`): a plan
there makes the answer ``borderline`` (a tolerance decides it), no proof. With ``"effort"`` and a
control domain that excludes ``u = 0`` the trace length is free and only the steps that exist are
priced (a step after the formula is decided costs input, which a plan need not spend).

With ``objective="margin"`` (largest robustness) the margin ``t`` is a column added to every face
row, and three things make the model fast and its answer a proof:

- ``t`` is capped by the formula's robustness evaluated on upper bounds of every proposition's
  margin (:func:`_margin_cap`: sound, so the cap never cuts the optimum), which keeps every
  big-M small and the relaxation's bound at most the cap;
- a feasibility probe with ``t`` at the cap runs first: where the cap is attained (a goal's
  centre reachable) the plan it finds is optimal by the cap alone; where it is not, a ladder of
  feasibility probes, each at the best plan's exact margin plus half the proof tolerance, ends
  with a level SCIP's presolve refutes (:func:`_solve_margin`);
- the big-M rows have no integrality room, so the model is a relaxation and its bound a bound on
  every plan; the plan's exact margin comes from the LP over its rounded letters
  (:func:`_polish`), and the optimum is *proven* only when the two meet within ``_PROOF_TOL``.

Propositions that exclude each other at a step (the pruning's disjoint pairs) get one clique row
``sum(p) <= 1`` where the exclusion graph is dense (:func:`_exclusion_cliques`), and a plain
feasibility model is solved without cutting planes and without presolve probing (both cost SCIP
more than they save in finding a plan).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import replace
from itertools import chain
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix, hstack, vstack

from ..backends import Backend, BackendSolution, HighsBackend, LinearModel
from ..chance import std_terms
from ..formulas import STLAnd, STLAtomicProposition, STLFormula, STLRelease
from ..semantics import formula_margins
from .abstraction import Abstraction
from .bmc import BMCEncoder
from .interfaces import Budget
from .plan_lp import PlanLPContext, Scaling, build_plan_rows

if TYPE_CHECKING:
    from ..dynamical_system import SwitchedSystem
    from ..sets import Polytope
    from .options import Objective

__all__ = ["MILPOutcome", "solve_milp", "switch_to_eager"]

logger = logging.getLogger(__name__)

_INT_TOL = 2e-6  # above HiGHS' mip_feasibility_tolerance (1e-6): a binary may be off by that much
_MAX_BIG_M = 1e7  # in normalised, scaled units: beyond this the model is numerically unreliable
# A margin is proven optimal when the exact LP value of the MILP's plan is this close (relative,
# at least absolute) to the MILP's bound: the MILP's rows hold only within its feasibility
# tolerance (1e-6 of a scaled row), so its bound can exceed the true optimum by about that much.
_PROOF_TOL = 1e-6
_EFFORT_FEAS_TOL = 1e-9  # the rows of the effort MILP hold within this (see solve_milp)

MILPStatus = Literal["found", "infeasible", "borderline", "timeout", "unsupported"]


class MILPOutcome:
    """What the eager MILP returns.

    Attributes
    ----------
    status : {"found", "infeasible", "borderline", "timeout", "unsupported"}
        ``infeasible`` is a proof for plans of at most ``bound + 1`` steps; ``borderline``: the
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


_EARLY_WINDOW = 3  # conflicts the early look reads (see ``switch_to_eager``)
_EARLY_MARGIN = 1.0  # ... and by how much their median must exceed ``conflict_size``


def switch_to_eager(
    conflicts: Sequence[Sequence[Any]],
    candidates: int,
    min_candidates: int,
    conflict_size: float,
    early: int = _EARLY_WINDOW,
    early_margin: float = _EARLY_MARGIN,
) -> bool:
    """Whether the lazy loop should hand an LP-exact, single-mode problem to the eager MILP.

    A deterministic rule that follows the lazy loop's convergence (it reads only the proven
    conflicts and the count of candidates, never the clock):

    - ``min_candidates <= 0`` (``SolverOptions.lazy_candidates = 0``): eager at once;
    - *early look*: from ``early`` (3) candidates on, as soon as the median size of the last
      ``early`` conflicts exceeds ``conflict_size + early_margin`` (4 requirements by default):
      the loop's very first conflicts are already large, so it is enumerating combinations
      from the start (PrSTL's noisy reach-avoid 9, 8, 7; NarrowPassage 7, 5, 3; EitherOr,
      RandomMultitarget, SteppingStones, DoorPuzzle 10-140), and each further candidate costs a
      plan LP over the horizon that the MILP does not need; from ``2 * early`` candidates on,
      as soon as that median exceeds ``conflict_size`` itself: the margin is for the first
      candidates only, which the SAT solver proposes before any LP has guided it (their
      conflicts carry whatever the least violation happened to break: the double integrator's
      5, 4, 3); a guided window above ``conflict_size`` is enumeration (ReachAvoid's 3, 4, 4
      after its march to the goal, candidate 9);
    - then, from ``min_candidates`` candidates (``SolverOptions.lazy_candidates``) on, as soon
      as the median size of the last ``min_candidates`` conflicts exceeds ``conflict_size``
      (``SolverOptions.lazy_conflict_size``): large conflicts each exclude little;
      small ones (a step or two at the frontier of reach) mean the loop is converging, so it stays;
    - in any case after ``10 * min_candidates`` candidates.

    ``conflict_size <= 0`` gives the fixed count ``min_candidates`` (no early look).

    The horizon and the model's size are deliberately not read: measured (BENCHMARKS.md,
    Analysis), the one-obstacle double integrator and stlpy's ReachAvoid have the same horizon,
    models of the same size and eager MILPs of the same cost at T = 200 (0.27 s CPU each), yet
    the first converges lazily in 13 candidates and the second would need one candidate per
    step; only the conflicts tell them apart. The double integrator's first conflicts are
    5, 4, 3, then 2 (median 4: it stays lazy); ReachAvoid's are 2 until its candidates reach the
    obstacle, then 3-7 (it switches after 9).

    Parameters
    ----------
    conflicts : sequence of sequences
        The proven conflicts so far, oldest first (``BMCProposer.hard``).
    candidates : int
        Candidates tried so far.
    min_candidates : int
    conflict_size : float
    early : int
        Conflicts the early look reads (at most ``min_candidates``).
    early_margin : float

    Returns
    -------
    bool
    """
    if min_candidates <= 0:
        return True
    if conflict_size <= 0:
        return candidates >= min_candidates
    if candidates >= 10 * min_candidates:
        return True
    sizes = [len(c) for c in conflicts]
    look = min(max(early, 1), min_candidates)
    if candidates >= look and len(sizes) >= look:
        threshold = conflict_size + (early_margin if candidates < 2 * look else 0.0)
        if float(np.median(sizes[-look:])) > threshold:
            return True
    if candidates < min_candidates:
        return False
    recent = sizes[-min_candidates:]
    return not recent or float(np.median(recent)) > conflict_size


_CLIQUE_GAIN = 3  # a step's exclusions become cliques when that takes at most a third of the rows


def _clique_cover(edges: frozenset[tuple[int, int]]) -> list[list[int]]:
    """Cliques of the graph ``edges`` that together hold every edge (greedy, deterministic).

    Each clique grows from the first uncovered edge by the vertex adjacent to all its members
    that covers the most uncovered edges (the smallest index on a tie).
    """
    adj: dict[int, set[int]] = {}
    for a, b in edges:
        adj.setdefault(a, set()).add(b)
        adj.setdefault(b, set()).add(a)
    left = set(edges)
    out = []
    for a, b in sorted(edges):
        if (a, b) not in left:
            continue
        clique = [a, b]
        common = adj[a] & adj[b]
        while common:
            best = max(
                sorted(common),
                key=lambda v: sum((min(u, v), max(u, v)) in left for u in clique),
            )
            clique.append(best)
            common &= adj[best]
        clique.sort()
        for i, u in enumerate(clique):
            for v in clique[i + 1 :]:
                left.discard((u, v))
        out.append(clique)
    return out


def _exclusion_cliques(
    clauses: Sequence[Sequence[int]], p: np.ndarray
) -> tuple[list[Sequence[int]], list[list[int]]]:
    """Split ``clauses`` into the others and cliques of letters that exclude each other.

    A clause ``-p[i, k] | -p[j, k]`` (two propositions never hold together at step ``k``) is an
    edge of step ``k``'s exclusion graph; a clique cover of that graph gives rows
    ``sum_{i in C} p[i, k] <= 1`` with the same integer solutions as the pairs. Returns
    ``(other clauses, cliques as lists of 1-based variables)``.
    """
    size = int(p.max()) + 1 if p.size else 1
    atom = np.full(size, -1, dtype=np.int64)
    step = np.full(size, -1, dtype=np.int64)
    atom[p.ravel()] = np.repeat(np.arange(p.shape[0]), p.shape[1])
    step[p.ravel()] = np.tile(np.arange(p.shape[1]), p.shape[0])
    atoms, steps = atom.tolist(), step.tolist()
    edges: dict[int, set[tuple[int, int]]] = {}
    pair_of: list[tuple[int, tuple[int, int]] | None] = []
    for clause in clauses:
        pair = None
        if len(clause) == 2 and clause[0] < 0 and clause[1] < 0 and -clause[0] < size and -clause[1] < size:
            a, b = -clause[0], -clause[1]
            i, j, k = atoms[a], atoms[b], steps[a]
            if i >= 0 and j >= 0 and k == steps[b] and i != j:
                pair = (k, (min(i, j), max(i, j)))
                edges.setdefault(k, set()).add(pair[1])
        pair_of.append(pair)
    cache: dict[frozenset[tuple[int, int]], list[list[int]] | None] = {}
    cliques = []
    for k in sorted(edges):
        key = frozenset(edges[k])
        if key not in cache:
            cover = _clique_cover(key)
            # Only a dense exclusion graph (stones, alternative targets) gains; a sparse one
            # (an obstacle's opposite sides) keeps its pair clauses where they were: there the
            # cover barely shortens the model and a different model only perturbs the solver.
            cache[key] = cover if _CLIQUE_GAIN * len(cover) <= len(key) else None
        merged = cache[key]
        if merged is None:
            edges[k] = set()  # not merged: its clauses stay
        else:
            cliques += [[int(p[i, k]) for i in group] for group in merged]
    rest = [
        c for c, pair in zip(clauses, pair_of, strict=True) if pair is None or pair[1] not in edges[pair[0]]
    ]
    return rest, cliques


def _contains_zero(U: Polytope) -> bool:
    """Whether ``u = 0`` lies in the control domain ``{u : H u + c <= 0}`` (exactly)."""
    return bool(np.all(np.asarray(U.c) <= 0.0))


def _support_points(U: Polytope) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
    """Vertices of the control domain (``None`` when unavailable) and its bounding box."""
    low, high = U.bounding_box()
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
        return None, low, high
    if U.dim == 1:
        return np.array([[low[0]], [high[0]]]), low, high
    if getattr(U, "is_full_dimensional", False):
        from scipy.spatial import HalfspaceIntersection, QhullError

        try:
            center, _ = U.chebyshev_center()
            return HalfspaceIntersection(np.hstack([U.H, U.c[:, None]]), center).intersections, low, high
        except (QhullError, ValueError):
            pass
    return None, low, high


def _support(points: tuple[np.ndarray | None, np.ndarray, np.ndarray], D: np.ndarray) -> np.ndarray:
    """``max_{u in U} d'u`` for every row ``d`` of ``D`` (an upper bound; ``inf`` if unbounded).

    Exact from the vertices of a bounded, full-dimensional domain; for flat domains (where
    Qhull fails) the bounding box gives a sound over-estimate.
    """
    verts, low, high = points
    if verts is not None:
        return np.asarray((D @ verts.T).max(axis=1))
    with np.errstate(invalid="ignore"):
        box = np.where(D > 0, D * high, D * low)
    return np.asarray(np.where(D == 0, 0.0, box).sum(axis=1))


def _invariants(formula: STLFormula, abstraction: Abstraction) -> list[tuple[int, int]]:
    """Propositions the formula requires at every step ``0..b``: ``(atom, b)`` pairs.

    Read off the top-level conjunction: ``always(0, b, ap)`` (or of a conjunction of them).
    """
    parts = formula.children if isinstance(formula, STLAnd) else (formula,)
    out = []
    for f in parts:
        if (
            isinstance(f, STLRelease)
            and f.a == 0
            and isinstance(f.left, STLAtomicProposition)
            and f.left.is_false
        ):
            body = f.right.children if isinstance(f.right, STLAnd) else (f.right,)
            for ap in body:
                if isinstance(ap, STLAtomicProposition) and id(ap) in abstraction.index and ap.predicates:
                    out.append((abstraction.index[id(ap)], f.b))
    return out


def _invariant_box(
    formula: STLFormula, abstraction: Abstraction, n: int, H: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per step, the bounding box of the means the invariants allow, shapes (H+1, n)."""
    low, high = np.full((H + 1, n), -np.inf), np.full((H + 1, n), np.inf)
    for i, b in _invariants(formula, abstraction):
        lo_i, hi_i = abstraction.bounds(i)
        steps = slice(0, min(b, H) + 1)
        low[steps] = np.maximum(low[steps], lo_i)
        high[steps] = np.minimum(high[steps], hi_i)
    return low, high


def _hard_steps(formula: STLFormula, abstraction: Abstraction, H: int) -> np.ndarray:
    """``hard[k, i]``: the invariants require proposition ``i`` at step ``k``; shape (H+1, n_atoms)."""
    hard = np.zeros((H + 1, abstraction.num_atoms), dtype=bool)
    for i, b in _invariants(formula, abstraction):
        hard[: min(b, H) + 1, i] = True
    return hard


def _state_boxes(
    A: np.ndarray,
    B: np.ndarray,
    points: tuple[np.ndarray | None, np.ndarray, np.ndarray],
    mean0: np.ndarray,
    inv_low: np.ndarray,
    inv_high: np.ndarray,
    H: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Per step, a box holding every mean that meets the invariants up to it, shapes (H+1, n).

    Interval propagation ``x_{k+1} in A box_k + B U``, intersected with the invariants' box at
    every step: an over-approximation (sound for big-M), tighter than the invariants' box alone
    where the dynamics cannot reach its far side. Infinite where nothing bounds a coordinate.
    """
    n = mean0.shape[0]
    low, high = np.empty((H + 1, n)), np.empty((H + 1, n))
    low[0] = high[0] = mean0
    b_high = _support(points, B)
    b_low = -_support(points, -B)
    Ap, An = np.maximum(A, 0.0), np.minimum(A, 0.0)

    def prod(M: np.ndarray, v: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            P = M * v[None, :]
        return np.asarray(np.where(M == 0, 0.0, P).sum(axis=1))

    for k in range(1, H + 1):
        with np.errstate(invalid="ignore"):
            lo_k = prod(Ap, low[k - 1]) + prod(An, high[k - 1]) + b_low
            hi_k = prod(Ap, high[k - 1]) + prod(An, low[k - 1]) + b_high
        lo_k = np.where(np.isnan(lo_k), -np.inf, lo_k)
        hi_k = np.where(np.isnan(hi_k), np.inf, hi_k)
        low[k] = np.maximum(lo_k, inv_low[k])
        high[k] = np.minimum(hi_k, inv_high[k])
        # An empty box means no plan meets the invariants (the hard rows say so); keep it ordered.
        high[k] = np.maximum(high[k], low[k])
    return low, high


def _common_slack(Hf: np.ndarray, bound: np.ndarray) -> float:
    """``max s`` such that ``h_f' x + s <= bound_f`` for every face ``f`` (``inf`` if unbounded)."""
    if not np.all(np.isfinite(bound)):
        return float(np.min(bound)) if np.any(bound == -np.inf) else np.inf
    nf, n = Hf.shape
    A = csr_matrix(np.hstack([Hf, np.ones((nf, 1))]))
    c = np.zeros(n + 1)
    c[-1] = -1.0
    model = LinearModel(c, A, np.full(nf, -np.inf), bound, np.full(n + 1, -np.inf), np.full(n + 1, np.inf))
    sol = HighsBackend().solve(model, 10.0)
    if sol.status == "optimal" and sol.x is not None:
        # The LP's own tolerance must not make the cap cut the optimum.
        return float(sol.x[-1]) + 1e-9 * max(1.0, abs(float(sol.x[-1])))
    if sol.status == "infeasible":
        return -np.inf
    return np.inf


def _margin_cap(
    formula: STLFormula,
    abstraction: Abstraction,
    covs: np.ndarray,
    reach_min: np.ndarray,
    box_low: np.ndarray,
    box_high: np.ndarray,
    H: int,
) -> tuple[float, bool]:
    """An upper bound on the robustness of every plan of ``H + 1`` steps, and whether it is finite.

    Each face's slack at step ``k`` is at most its bound minus the least value the face takes
    over the reachable means (support functions, and the box the invariants leave); the
    monitor's min / max recursion is monotone, so evaluating it on those per-proposition bounds
    bounds the robustness itself (single mode: the arriving mode is 0).
    """
    F = abstraction.H
    L = H + 1
    face_ub = np.empty((L, F.shape[0]))
    for k in range(L):
        bound = -(abstraction.c + std_terms(F, abstraction.z, covs[k]))
        with np.errstate(invalid="ignore"):
            box_min = np.where(F > 0, F * box_low[k], F * box_high[k])
        box_min = np.where(F == 0, 0.0, box_min).sum(axis=1)
        face_ub[k] = bound - np.maximum(reach_min[k], box_min)
    face_ub = np.where(np.isnan(face_ub), np.inf, face_ub)
    atoms: dict[int, np.ndarray] = {}
    widest = np.max([-(abstraction.c + std_terms(F, abstraction.z, covs[k])) for k in range(L)], axis=0)
    for i, ap in enumerate(abstraction.atoms):
        faces = abstraction.owner == i
        ub = face_ub[:, faces].min(axis=1) if faces.any() else np.full(L, np.inf)
        if np.sum(faces) > 1:
            # The faces cannot all have their largest slack at once: the largest common slack
            # over the whole space (at the widest bounds of any step) bounds every step.
            ub = np.minimum(ub, _common_slack(F[faces], widest[faces]))
        if ap.modes is not None and 0 not in ap.modes:
            ub[1:] = -np.inf
        atoms[id(ap)] = ub
    cap = float(formula_margins(formula, atoms, L)[0])
    if not np.isfinite(cap):
        return 0.0, False
    return max(cap, 0.0), True


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


def _solve_margin(
    model: LinearModel, backend: Backend, tcol: int, t_cap: float, t_sound: bool, budget: Budget
) -> tuple[str, np.ndarray | None, np.ndarray | None, float, str]:
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
       optimisation above the best level so far.
    """
    level, x, exact, v = model.lb[tcol], None, None, None
    if t_sound and t_cap > 0:
        top = t_cap * (1.0 - 1e-7)
        sol = _probe(model, backend, tcol, top, budget, probing="short")
        if sol.status in ("optimal", "time_limit") and sol.x is not None:
            polished = _polish(model, sol.x, tcol, budget)
            if polished is not None and polished[tcol] >= t_cap - _PROOF_TOL * max(1.0, t_cap):
                return "optimal", sol.x, polished, t_cap, "a plan at the cap"
            # The probe reached the cap only within the solver's tolerances.
            logger.info("MILP margin: the probe's plan is below the cap")
            if polished is not None:
                x, exact, v = sol.x, polished, float(polished[tcol])
        for _ in range(_LADDER_RUNGS + 1):
            if v is not None:
                level = v + 0.5 * _PROOF_TOL * max(1.0, abs(v))
                if level >= top:
                    return "optimal", x, exact, t_cap, "the cap"
            sol = _probe(
                model,
                backend,
                tcol,
                level,
                budget,
                node_limit=_PROBE_NODES if v is not None else None,
                feas_tol=_LADDER_FEAS_TOL,
            )
            if sol.status == "infeasible":
                if v is None:
                    return "infeasible", None, None, float("nan"), sol.message
                return "optimal", x, exact, level, f"level {level:.12g} refuted"
            if sol.x is None:
                break  # the node budget or an error: the optimisation decides
            polished = _polish(model, sol.x, tcol, budget)
            if polished is None or (v is not None and polished[tcol] <= v):
                break  # no progress within the tolerances
            x, exact, v = sol.x, polished, float(polished[tcol])
            logger.info("MILP margin: ladder at %.12g", v)
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


def _solve_feasibility(model: LinearModel, backend: Backend, budget: Budget) -> BackendSolution:
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
"""How far (normalised rows, in scaled state units) :func:`_recheck` moves every face outward."""


def _recheck(
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


def solve_milp(
    enc: BMCEncoder,
    abstraction: Abstraction,
    system: SwitchedSystem,
    control_domain: Polytope,
    mean0: np.ndarray,
    cov0: np.ndarray,
    scaling: Scaling,
    backend: Backend,
    budget: Budget,
    objective: Objective | None = None,
    effort_weights: np.ndarray | None = None,
) -> MILPOutcome:
    """Solve the bounded synthesis problem as one MILP (single mode, mean-independent covariance).

    Parameters
    ----------
    enc : BMCEncoder
        The proposer's current encoding (its proven clauses; abandoned ones are switched off).
    abstraction : Abstraction
    system : SwitchedSystem
    control_domain : Polytope
    mean0 : ndarray, shape (n,)
    cov0 : ndarray, shape (n, n)
    scaling : Scaling
    backend : Backend
        A MILP-capable back-end.
    budget : Budget
    objective : {None, "effort", "margin", "time"}
        ``None``: any feasible plan. ``"effort"``: least ``sum_k sum_j w_j |u_kj|``;
        ``"margin"``: largest robustness (smallest raw slack of the claimed faces);
        ``"time"``: fewest steps (the trace length is free instead of the whole bound).
    effort_weights : ndarray, shape (m,), optional
        Per-input weights of ``"effort"`` (default ones).

    Returns
    -------
    MILPOutcome
        With ``value`` and ``bound`` of the objective when one is given.
    """
    H = enc.H
    n, m = system.n, system.m
    mode = system.system_modes[0]
    A, B = mode.A, mode.B
    dx = scaling.dx
    actions = np.zeros(H, dtype=int)
    context = PlanLPContext(system, control_domain, mean0, cov0, abstraction, scaling)
    rows = build_plan_rows(context, [], actions, budget=budget)
    if not rows.exact:
        return MILPOutcome("unsupported", why="the covariance depends on the mean")
    covs = rows.covs
    nb = enc.num_vars
    nx, nu = H * n, H * m
    nt = 1 if objective == "margin" else 0
    # With an objective, p = 1 - 2e-6 may relax a face by that much of its big-M: the model is a
    # relaxation, its bound a bound on every plan and its infeasibility a proof, and the plan
    # itself is re-solved exactly (the margin's _polish, the plan LP's re-timing). Without one the
    # face is enforced within the integrality tolerance (a plan found is a plan; issue 25: with an
    # objective that over-tightening, 2e-6 of a big-M, refuted a target 2e-6 wide).
    int_tol = 0.0 if objective is not None else _INT_TOL
    na = nu if objective == "effort" else 0
    # Effort when the control domain excludes u = 0: a step after the formula is decided costs
    # input, so the trace length is free and only the steps that exist are priced (issue 25).
    idle_costs = na > 0 and not _contains_zero(control_domain)
    low_u, high_u = control_domain.bounding_box() if idle_costs else (np.zeros(m), np.zeros(m))
    if idle_costs and not (np.all(np.isfinite(low_u)) and np.all(np.isfinite(high_u))):
        return MILPOutcome("unsupported", why="idle steps cost input and the control domain is unbounded")
    tcol, acol = nb + nx + nu, nb + nx + nu + nt
    nvar = nb + nx + nu + nt + na

    blocks, lo, hi = [], [], []

    # Clauses: l_1 | ... | l_r  ->  sum(pos) - sum(neg) >= 1 - |neg|. The pairwise exclusions
    # of the pruning (two disjoint propositions never hold at one step) become one row per clique
    # of mutually exclusive propositions, sum(p) <= 1: the same integer points, a tighter
    # relaxation, and SCIP's presolve about twice as fast (SteppingStones: 2,860 pair rows -> 702).
    clauses, cliques = _exclusion_cliques(enc.clauses + enc.learnt, enc.p)
    if clauses:
        lengths = np.fromiter(map(len, clauses), dtype=np.int64, count=len(clauses))
        lits = np.fromiter(chain.from_iterable(clauses), dtype=np.int64, count=int(lengths.sum()))
        rows_of = np.repeat(np.arange(len(clauses)), lengths)
        negative = lits < 0
        blocks.append(
            coo_matrix(
                (np.where(negative, -1.0, 1.0), (rows_of, np.abs(lits) - 1)), shape=(len(clauses), nvar)
            ).tocsr()
        )
        lo.append(1.0 - np.bincount(rows_of, weights=negative, minlength=len(clauses)))
        hi.append(np.full(len(clauses), np.inf))
    if cliques:
        r_idx = [r for r, group in enumerate(cliques) for _ in group]
        c_idx = [v - 1 for group in cliques for v in group]
        blocks.append(coo_matrix((np.ones(len(c_idx)), (r_idx, c_idx)), shape=(len(cliques), nvar)).tocsr())
        lo.append(np.full(len(cliques), -np.inf))
        hi.append(np.ones(len(cliques)))

    # Dynamics and control domain (scaled, as in the plan LP).
    for part in (rows.A_eq, rows.A_U):
        blocks.append(
            hstack([csr_matrix((part.shape[0], nb)), part, csr_matrix((part.shape[0], nt + na))]).tocsr()
        )
    lo += [rows.b_eq, np.full(rows.A_U.shape[0], -np.inf)]
    hi += [rows.b_eq, rows.b_U]
    if na:
        # a_kj >= +-u_kj in problem units (u = du * u~).
        du = np.tile(scaling.du, H)
        idx = np.arange(na)
        pos = csr_matrix((du, (idx, nb + nx + idx)), shape=(na, nvar))
        neg = csr_matrix((-du, (idx, nb + nx + idx)), shape=(na, nvar))
        aux = csr_matrix((-np.ones(na), (idx, acol + idx)), shape=(na, nvar))
        if idle_costs:
            # a_kj >= +-u_kj - M_j (1 - alive_{k+1}): a step that does not exist costs nothing.
            big_u = np.tile(np.maximum(np.abs(low_u), np.abs(high_u)), H)
            steps = np.repeat(np.asarray(enc.alive[1 : H + 1]) - 1, m)
            gate = csr_matrix((big_u, (idx, steps)), shape=(na, nvar))
            blocks += [(pos + aux + gate).tocsr(), (neg + aux + gate).tocsr()]
            lo.append(np.full(2 * na, -np.inf))
            hi.append(np.concatenate([big_u, big_u]))
        else:
            blocks += [(pos + aux).tocsr(), (neg + aux).tocsr()]
            lo.append(np.full(2 * na, -np.inf))
            hi.append(np.zeros(2 * na))

    # Big-M implications p[i, k] -> faces of proposition i at step k (normalised rows). The
    # invariants (propositions the formula requires at every step 0..b) are hard rows instead,
    # so the box they bound is a fact every other big-M may use.
    F = abstraction.H
    hard = _hard_steps(enc.formula, abstraction, H)
    fixed_p: list[int] = []
    never_p: list[int] = []
    face_rows: list[tuple[int, int]] = []  # (first row, count) of the face rows (for _recheck)
    if F.shape[0]:
        budget.check("building the MILP")
        powers = np.empty((H + 1, F.shape[0], n))
        powers[0] = F
        for j in range(1, H + 1):
            if not j % 1024:
                budget.check("building the MILP")
            powers[j] = powers[j - 1] @ A
        points = _support_points(control_domain)
        gain = (
            np.stack([_support(points, powers[j] @ B) for j in range(H)]) if H else np.zeros((0, F.shape[0]))
        )
        reach_max = np.einsum("kfn,n->kf", powers, mean0)
        with np.errstate(invalid="ignore"):
            reach_max[1:] += np.cumsum(gain, axis=0)
        if nt:
            loss = (
                np.stack([_support(points, -(powers[j] @ B)) for j in range(H)])
                if H
                else np.zeros((0, F.shape[0]))
            )
            reach_min = np.einsum("kfn,n->kf", powers, mean0)
            with np.errstate(invalid="ignore"):
                reach_min[1:] -= np.cumsum(loss, axis=0)
        inv_low, inv_high = _invariant_box(enc.formula, abstraction, n, H)
        box_low, box_high = _state_boxes(A, B, points, mean0, inv_low, inv_high, H)
        G = F * dx[None, :]
        g = np.linalg.norm(G, axis=1)
        g = np.where(g > 0, g, 1.0)
        Gn = G / g[:, None]
        # The margin t (raw slack, the monitor's units) is capped at t_cap. The formula evaluated
        # on upper bounds of every proposition's margin bounds every plan's robustness, so that
        # cap never cuts the optimum, and it keeps the big-M of every face small; without it (no
        # finite bound) a generous heuristic cap stands, and an optimum at it is not proven.
        t_cap, t_sound = 0.0, False
        if nt:
            t_cap, t_sound = _margin_cap(enc.formula, abstraction, covs, reach_min, box_low, box_high, H)
            if not t_sound:
                t_cap = 10.0 * float(np.max(dx)) * float(np.max(np.linalg.norm(F, axis=1)))
        r_parts: list[np.ndarray] = []
        c_parts: list[np.ndarray] = []
        v_parts: list[np.ndarray] = []
        ub_parts: list[np.ndarray] = []
        h_parts: list[np.ndarray] = []
        hc_parts: list[np.ndarray] = []
        hv_parts: list[np.ndarray] = []
        hub_parts: list[np.ndarray] = []
        row = hrow = 0
        for k in range(1, H + 1):
            if not k % 64:
                budget.check("building the MILP")
            terms = std_terms(F, abstraction.z, covs[k])
            bound = -(abstraction.c + terms)  # h' x_k <= bound when p holds
            with np.errstate(invalid="ignore"):
                box_max = np.where(F > 0, F * box_high[k], F * box_low[k])
            box_max = np.where(F == 0, 0.0, box_max).sum(axis=1)
            with np.errstate(invalid="ignore"):
                big = np.maximum(np.minimum(reach_max[k], box_max) + t_cap - bound, 0.0) / g
            p_cols = enc.p[abstraction.owner, k] - 1
            is_hard = hard[k, abstraction.owner]
            finite = np.isfinite(bound)
            # eps = 0 with variance: the proposition cannot hold at k.
            never_p.extend(int(c) for c in np.unique(p_cols[~finite]))
            fixed_p.extend(int(c) for c in np.unique(p_cols[is_hard & finite]))
            # A hard row is dropped only when the dynamics alone keep it (its own box is no reason),
            # with the margin t on top when one is maximised.
            with np.errstate(invalid="ignore"):
                free = reach_max[k] + t_cap - bound > 0
            hsel = np.nonzero(is_hard & finite & free)[0]
            sel = np.nonzero(~is_hard & finite & (big > 0))[0]  # big <= 0: every reachable mean is inside
            if sel.size and (not np.all(np.isfinite(big[sel])) or np.max(big[sel]) > _MAX_BIG_M):
                return MILPOutcome("unsupported", why="the reachable means are unbounded (no finite big-M)")
            xcols = nb + (k - 1) * n + np.arange(n)
            for faces, rr, cc, vv, uu, first in (
                (hsel, h_parts, hc_parts, hv_parts, hub_parts, hrow),
                (sel, r_parts, c_parts, v_parts, ub_parts, row),
            ):
                if not faces.size:
                    continue
                ids = first + np.arange(faces.size)
                cols = [np.broadcast_to(xcols, (faces.size, n))]
                coefs = [Gn[faces]]
                if faces is sel:  # big-M: p = 1 (within the integrality tolerance) enforces the face
                    cols.append(p_cols[faces][:, None])
                    coefs.append((big[faces] / (1.0 - int_tol))[:, None])
                if nt:
                    cols.append(np.full((faces.size, 1), tcol))
                    coefs.append((1.0 / g[faces])[:, None])
                cm, vm = np.hstack(cols), np.hstack(coefs)
                rr.append(np.repeat(ids, cm.shape[1]))
                cc.append(cm.ravel())
                vv.append(vm.ravel())
                uu.append(bound[faces] / g[faces] + (big[faces] if faces is sel else 0.0))
            hrow += hsel.size
            row += sel.size
        for rr, cc, vv, uu, count in (
            (h_parts, hc_parts, hv_parts, hub_parts, hrow),
            (r_parts, c_parts, v_parts, ub_parts, row),
        ):
            if count:
                face_rows.append((sum(b.shape[0] for b in blocks), count))
                blocks.append(
                    coo_matrix(
                        (np.concatenate(vv), (np.concatenate(rr), np.concatenate(cc))), shape=(count, nvar)
                    ).tocsr()
                )
                lo.append(np.full(count, -np.inf))
                hi.append(np.concatenate(uu))
        if nt:
            # Step 0 has no face rows (the prior is given; pruning fixes what holds there), but a
            # proposition claimed there bounds the margin by its slack at the prior, as at every
            # other step: t <= slack_i + (t_cap - slack_i) (1 - p[i, 0]). Without these rows a
            # formula met at step 0 let the margin reach the cap for free (issue 25: 0.2 at step 0
            # reported beside a bound of 0.4, which four steps reach).
            terms0 = std_terms(F, abstraction.z, covs[0])
            with np.errstate(invalid="ignore"):
                face0 = -(abstraction.c + terms0) - F @ mean0
            face0 = np.where(np.isnan(face0), -np.inf, face0)
            s_rows: list[int] = []
            s_cols: list[int] = []
            s_vals: list[float] = []
            s_hi: list[float] = []
            for i in range(abstraction.num_atoms):
                faces = abstraction.owner == i
                if not faces.any():
                    continue
                slack0 = float(np.min(face0[faces]))
                col = int(enc.p[i, 0]) - 1
                if slack0 < 0:
                    never_p.append(col)
                elif slack0 < t_cap:
                    r = len(s_hi)
                    s_rows += [r, r]
                    s_cols += [tcol, col]
                    s_vals += [1.0, t_cap - slack0]
                    s_hi.append(t_cap)
            if s_hi:
                blocks.append(coo_matrix((s_vals, (s_rows, s_cols)), shape=(len(s_hi), nvar)).tocsr())
                lo.append(np.full(len(s_hi), -np.inf))
                hi.append(np.asarray(s_hi))
        logger.debug("MILP: %d hard face rows, %d big-M rows", hrow, row)

    A_all = vstack(blocks).tocsr()
    # The face rows carry every state coordinate, most with a zero coefficient (a box's face has
    # one): stored, they were 29% of the entries SCIP reads (the same search without them).
    A_all.eliminate_zeros()
    lower = np.concatenate([np.zeros(nb), np.full(nx + nu, -np.inf), np.zeros(nt + na)])
    upper = np.concatenate([np.ones(nb), np.full(nx + nu, np.inf), np.full(nt + na, np.inf)])
    if nt:
        upper[tcol] = t_cap if F.shape[0] else 0.0
    alive = np.asarray(enc.alive[: H + 1]) - 1
    cost = np.zeros(nvar)
    if objective == "time":
        cost[alive[1:]] = 1.0  # the trace length is free: count the steps that exist
    elif idle_costs:
        lower[alive[0]] = 1.0  # free length: the steps that exist are priced
    else:
        lower[alive] = 1.0  # the trace is the whole bound: a shorter plan extends to it
    if nt:
        cost[tcol] = -1.0
    if na:
        w = np.ones(m) if effort_weights is None else np.asarray(effort_weights, dtype=float)
        cost[acol:] = np.tile(w, H)
    upper[enc.alive[H + 1] - 1] = 0.0
    lower[sorted(set(fixed_p) - set(never_p))] = 1.0  # claims the invariants force (the clauses imply them)
    upper[never_p] = 0.0
    upper[enc.selector - 1] = 0.0  # abandoned candidates are not proofs: their clauses are off
    # Only the letters branch: every gate is a full Tseitin equivalence of its inputs, so it is
    # integral whenever they are (a continuous gate in [0, 1] is exact and halves HiGHS' work).
    integrality = np.zeros(nvar)
    for letters in (np.asarray(enc.alive), enc.p.ravel(), enc.m.ravel()):
        integrality[np.asarray(letters, dtype=np.int64) - 1] = 1
    logger.info("MILP: %d binaries, %d continuous, %d rows", int(integrality.sum()), nx + nu, A_all.shape[0])
    if nt:
        logger.info("MILP: t_cap %.9g (sound %s)", t_cap, t_sound)
    # The margin MILP's relaxation is as tight as the cap makes it: cutting planes cost SCIP 2-4x
    # the time without moving its bound (measured on stlpy's scenarios, BENCHMARKS.md). A plain
    # feasibility model needs neither cuts nor probing to find its plan: SCIP's root cuts and
    # presolve probing were 40-85% of its time on stlpy's scenarios at T = 50-200 (NarrowPassage
    # T = 100 3.5 -> 0.45 s, SteppingStones T = 100 1.9 -> 0.27 s; DoorPuzzle T = 30 and
    # NarrowPassage T = 50 lose 0.2 s, DoorPuzzle T = 25's proof of infeasibility 0.17 s).
    model = LinearModel(
        cost,
        A_all,
        np.concatenate(lo),
        np.concatenate(hi),
        lower,
        upper,
        integrality,
        cuts=objective in ("effort", "time"),
        probing="off" if objective is None else "full",
        # SCIP's feasibility pump mostly fails on the feasibility model (conflict diving finds
        # the plan): without it 28 cells of stlpy's scenarios, PrSTL and the double integrator
        # take 0.80-1.20x their CPU time (NarrowPassage T = 200 0.86x; BENCHMARKS.md, Analysis).
        # The margin probes keep it (issue 13's measurements).
        feaspump=objective is not None,
        # The effort's bound is as close to the true minimum as the rows are held: at the default
        # 1e-6 a face relaxed by that much moved the bound 1e-4 below it when the input's gain
        # is 0.01 (issue 25).
        feas_tol=_EFFORT_FEAS_TOL if objective == "effort" else None,
    )
    if nt:
        status, x, exact, bound, message = _solve_margin(
            model, backend, tcol, t_cap if F.shape[0] else 0.0, t_sound, budget
        )
        if status == "infeasible":
            return _recheck(model, backend, budget, face_rows)
        if x is None:
            logger.info("MILP stopped: %s", message)
            return MILPOutcome("timeout", why=message)
        plan = x if exact is None else exact  # the same letters; the LP's continuous part is exact
        controls = plan[nb + nx : nb + nx + nu].reshape(H, m) * scaling.du
        claims = np.round(plan[enc.p - 1]).astype(bool) if enc.p.size else np.zeros((0, H + 1), bool)
        out = MILPOutcome("found", actions, controls, claims)
        # The big-M rows of the margin MILP are a relaxation (no integrality room), so every bound
        # it proves holds for every plan; the LP over the rounded letters gives the exact margin of
        # its plan, and the two must meet for a proof.
        out.value, out.bound = float(plan[tcol]), bound
        slack = _PROOF_TOL * max(1.0, abs(bound)) if np.isfinite(bound) else 0.0
        out.proven = (
            status == "optimal"
            and exact is not None
            and np.isfinite(bound)
            and out.value >= bound - slack
            and (t_sound or out.value < t_cap * (1 - 1e-9))
        )
        logger.info(
            "MILP margin: %.12g, exact %.12g, bound %.12g, proven %s (%s)",
            float(x[tcol]),
            out.value,
            out.bound,
            out.proven,
            message,
        )
        return out
    if objective is None:
        sol = _solve_feasibility(model, backend, budget)
    else:
        sol = backend.solve(model, max(budget.remaining(), 1e-3))
    if sol.status in ("optimal", "time_limit") and sol.x is not None:
        controls = sol.x[nb + nx : nb + nx + nu].reshape(H, m) * scaling.du
        claims = np.round(sol.x[enc.p - 1]).astype(bool) if enc.p.size else np.zeros((0, H + 1), bool)
        out = MILPOutcome("found", actions, controls, claims)
        out.proven = sol.status == "optimal"
        if objective == "effort":
            out.value, out.bound = float(sol.objective), float(sol.bound)
        elif objective == "time":
            out.value, out.bound = float(sol.objective), float(sol.bound)
        return out
    if sol.status == "infeasible":
        if objective is None:
            return MILPOutcome("infeasible", why="the MILP is infeasible")
        return _recheck(model, backend, budget, face_rows)
    logger.info("MILP stopped: %s", sol.message)
    return MILPOutcome("timeout", why=sol.message)
