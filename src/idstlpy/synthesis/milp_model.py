"""The eager MILP's model: the BMC encoding and the plan LP's rows as one mixed-integer program.

Columns, in order (:class:`Columns`): the SAT variables of the encoding (0/1), the scaled means
and inputs of the plan LP, the margin ``t`` (``objective="margin"``) and the absolute inputs
(``objective="effort"``). Rows, in order:

- the clauses (proven and learnt), ``sum(pos) - sum(neg) >= 1 - |neg|``, with the pruning's
  pairwise exclusions merged into clique rows ``sum(p) <= 1`` where that pays
  (:func:`exclusion_cliques`);
- the dynamics and the control domain, as in the plan LP (:func:`~.plan_lp.build_plan_rows`);
- ``a >= +-u`` for the effort (gated by the step's existence where ``u = 0`` is no input);
- the chance constraints: hard rows for the invariants, big-M rows ``p[i, k] = 1 -> face``
  elsewhere with ``M`` from :mod:`.milp_bounds` (:mod:`.milp_faces`), and the margin's rows at
  step 0;

then the bounds, the cost and the integrality (only the letters branch). See :mod:`.milp` for
why each choice.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import chain

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix, hstack, vstack

from ..backends import LinearModel
from .bmc import BMCEncoder
from .milp_bounds import contains_zero
from .milp_faces import chance_rows
from .milp_spec import Columns, MILPSpec, RowBlocks
from .plan_lp import PlanRows, build_plan_rows

__all__ = ["Columns", "MILPModel", "MILPSpec", "RowBlocks", "build_milp", "clique_cover", "exclusion_cliques"]

# One log for the whole eager MILP (model, phases, outcome): users and tests filter on it.
logger = logging.getLogger("idstlpy.synthesis.milp")

_EFFORT_FEAS_TOL = 1e-9  # the rows of the effort MILP hold within this (see build_milp)


@dataclass(frozen=True)
class MILPModel:
    """The built model and what its solve and answer read.

    Attributes
    ----------
    model : LinearModel
    cols : Columns
    face_rows : list of (int, int)
        ``(first row, count)`` of the face rows (hard and big-M), moved out by
        :func:`~.milp_solve.recheck`.
    t_cap : float
        The margin's upper bound (0 without a margin or without faces).
    t_sound : bool
        Whether ``t_cap`` bounds every plan's robustness (else a heuristic cap).
    """

    model: LinearModel
    cols: Columns
    face_rows: list[tuple[int, int]]
    t_cap: float
    t_sound: bool


_CLIQUE_GAIN = 3  # a step's exclusions become cliques when that takes at most a third of the rows


def clique_cover(edges: frozenset[tuple[int, int]]) -> list[list[int]]:
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


def exclusion_cliques(
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
            cover = clique_cover(key)
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


def build_milp(spec: MILPSpec) -> MILPModel | str:
    """The eager MILP of ``spec``, or why it cannot be built soundly (``str``).

    Not built when the covariance depends on the mean, when idle steps cost input over an
    unbounded control domain, or when a big-M is infinite or beyond ``_MAX_BIG_M``.
    """
    ctx, enc, objective = spec.context, spec.enc, spec.objective
    H = enc.H
    n, m = ctx.system.n, ctx.system.m
    rows = build_plan_rows(ctx, [], np.zeros(H, dtype=int), budget=spec.budget)
    if not rows.exact:
        return "the covariance depends on the mean"
    nt = 1 if objective == "margin" else 0
    na = H * m if objective == "effort" else 0
    # Effort when the control domain excludes u = 0: a step after the formula is decided costs
    # input, so the trace length is free and only the steps that exist are priced (issue 25).
    idle_costs = na > 0 and not contains_zero(ctx.control_domain)
    low_u, high_u = ctx.control_domain.bounding_box() if idle_costs else (np.zeros(m), np.zeros(m))
    if idle_costs and not (np.all(np.isfinite(low_u)) and np.all(np.isfinite(high_u))):
        return "idle steps cost input and the control domain is unbounded"
    cols = Columns(enc.num_vars, H * n, H * m, nt, na)
    acc = RowBlocks()
    clause_rows(enc, cols.nvar, acc)
    _plan_rows(rows, cols, acc)
    if na:
        big_u = np.tile(np.maximum(np.abs(low_u), np.abs(high_u)), H) if idle_costs else None
        _effort_rows(spec, cols, acc, big_u)
    faces = chance_rows(spec, rows.covs, cols, acc)
    if isinstance(faces, str):
        return faces
    fixed_p, never_p, face_rows, t_cap, t_sound = faces
    A_all = vstack(acc.blocks).tocsr()
    # The face rows carry every state coordinate, most with a zero coefficient (a box's face has
    # one): stored, they were 29% of the entries SCIP reads (the same search without them).
    A_all.eliminate_zeros()
    cost, lower, upper, integrality = _columns(spec, cols, idle_costs, fixed_p, never_p)
    if nt:
        upper[cols.tcol] = t_cap
    logger.info(
        "MILP: %d binaries, %d continuous, %d rows", int(integrality.sum()), cols.nx + cols.nu, A_all.shape[0]
    )
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
        np.concatenate(acc.lo),
        np.concatenate(acc.hi),
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
    return MILPModel(model, cols, face_rows, t_cap, t_sound)


def clause_rows(enc: BMCEncoder, nvar: int, acc: RowBlocks) -> None:
    """The clauses, and the pruning's exclusions as clique rows.

    ``l_1 | ... | l_r  ->  sum(pos) - sum(neg) >= 1 - |neg|``. The pairwise exclusions of the
    pruning (two disjoint propositions never hold at one step) become one row per clique of
    mutually exclusive propositions, ``sum(p) <= 1``: the same integer points, a tighter
    relaxation, and SCIP's presolve about twice as fast (SteppingStones: 2,860 pair rows -> 702).
    ``nvar`` is the model's column count (the joint MILP's model shares the eager MILP's letters).
    """
    clauses, cliques = exclusion_cliques(enc.clauses + enc.learnt, enc.p)
    if clauses:
        lengths = np.fromiter(map(len, clauses), dtype=np.int64, count=len(clauses))
        lits = np.fromiter(chain.from_iterable(clauses), dtype=np.int64, count=int(lengths.sum()))
        rows_of = np.repeat(np.arange(len(clauses)), lengths)
        negative = lits < 0
        acc.add(
            coo_matrix(
                (np.where(negative, -1.0, 1.0), (rows_of, np.abs(lits) - 1)), shape=(len(clauses), nvar)
            ).tocsr(),
            1.0 - np.bincount(rows_of, weights=negative, minlength=len(clauses)),
            np.full(len(clauses), np.inf),
        )
    if cliques:
        r_idx = [r for r, group in enumerate(cliques) for _ in group]
        c_idx = [v - 1 for group in cliques for v in group]
        acc.add(
            coo_matrix((np.ones(len(c_idx)), (r_idx, c_idx)), shape=(len(cliques), nvar)).tocsr(),
            np.full(len(cliques), -np.inf),
            np.ones(len(cliques)),
        )


def _plan_rows(rows: PlanRows, cols: Columns, acc: RowBlocks) -> None:
    """Dynamics and control domain (scaled, as in the plan LP)."""
    for part, lo, hi in (
        (rows.A_eq, rows.b_eq, rows.b_eq),
        (rows.A_U, np.full(rows.A_U.shape[0], -np.inf), rows.b_U),
    ):
        pad = csr_matrix((part.shape[0], cols.nt + cols.na))
        acc.add(hstack([csr_matrix((part.shape[0], cols.nb)), part, pad]).tocsr(), lo, hi)


def _effort_rows(spec: MILPSpec, cols: Columns, acc: RowBlocks, big_u: np.ndarray | None) -> None:
    """``a_kj >= +-u_kj`` in problem units (``u = du * u~``); gated by ``big_u`` for idle steps."""
    H, m, na, nvar = spec.enc.H, spec.context.system.m, cols.na, cols.nvar
    du = np.tile(spec.context.scaling.du, H)
    idx = np.arange(na)
    first_u = cols.nb + cols.nx
    pos = csr_matrix((du, (idx, first_u + idx)), shape=(na, nvar))
    neg = csr_matrix((-du, (idx, first_u + idx)), shape=(na, nvar))
    aux = csr_matrix((-np.ones(na), (idx, cols.acol + idx)), shape=(na, nvar))
    if big_u is not None:
        # a_kj >= +-u_kj - M_j (1 - alive_{k+1}): a step that does not exist costs nothing.
        steps = np.repeat(np.asarray(spec.enc.alive[1 : H + 1]) - 1, m)
        gate = csr_matrix((big_u, (idx, steps)), shape=(na, nvar))
        acc.add((pos + aux + gate).tocsr(), np.full(na, -np.inf), big_u)
        acc.add((neg + aux + gate).tocsr(), np.full(na, -np.inf), big_u)
    else:
        acc.add((pos + aux).tocsr(), np.full(na, -np.inf), np.zeros(na))
        acc.add((neg + aux).tocsr(), np.full(na, -np.inf), np.zeros(na))


def _columns(
    spec: MILPSpec, cols: Columns, idle_costs: bool, fixed_p: list[int], never_p: list[int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The cost, the column bounds and the integrality: ``(cost, lower, upper, integrality)``."""
    enc, objective, H = spec.enc, spec.objective, spec.enc.H
    nb, nx, nu, nt, na, nvar = cols.nb, cols.nx, cols.nu, cols.nt, cols.na, cols.nvar
    lower = np.concatenate([np.zeros(nb), np.full(nx + nu, -np.inf), np.zeros(nt + na)])
    upper = np.concatenate([np.ones(nb), np.full(nx + nu, np.inf), np.full(nt + na, np.inf)])
    alive = np.asarray(enc.alive[: H + 1]) - 1
    cost = np.zeros(nvar)
    if objective == "time":
        cost[alive[1:]] = 1.0  # the trace length is free: count the steps that exist
    elif idle_costs:
        lower[alive[0]] = 1.0  # free length: the steps that exist are priced
    else:
        lower[alive] = 1.0  # the trace is the whole bound: a shorter plan extends to it
    if nt:
        cost[cols.tcol] = -1.0
    if na:
        m = spec.context.system.m
        w = np.ones(m) if spec.effort_weights is None else np.asarray(spec.effort_weights, dtype=float)
        cost[cols.acol :] = np.tile(w, H)
    upper[enc.alive[H + 1] - 1] = 0.0
    lower[sorted(set(fixed_p) - set(never_p))] = 1.0  # claims the invariants force (the clauses imply them)
    upper[never_p] = 0.0
    upper[enc.selector - 1] = 0.0  # abandoned candidates are not proofs: their clauses are off
    # Only the letters branch: every gate is a full Tseitin equivalence of its inputs, so it is
    # integral whenever they are (a continuous gate in [0, 1] is exact and halves HiGHS' work).
    integrality = np.zeros(nvar)
    for letters in (np.asarray(enc.alive), enc.p.ravel(), enc.m.ravel()):
        integrality[np.asarray(letters, dtype=np.int64) - 1] = 1
    return cost, lower, upper, integrality
