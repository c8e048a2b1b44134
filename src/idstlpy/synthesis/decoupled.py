"""Decoupled subsystems: plan each independent block of the state on its own, then compose.

Several robots that share nothing but a plan (``k`` independent light-dark robots, issue 24)
make one belief of ``2 k`` dimensions that the belief sampler does not search well. When the
problem *splits*, it is solved block by block instead. It splits when it has

- one mode (a mode sequence is shared by every block; with one mode there is nothing to share),
  with state-dependent sensor noise (elsewhere the plan LP and the eager MILP are exact and fast,
  and the sampler, which this serves, is not used);
- two or more groups of coordinates: the connected components of a graph that links two
  coordinates whenever ``A``, an input column of ``B``, a face of the control domain, the process
  noise ``W W'``, the prior covariance, an output row of ``C``, the sensor noise
  ``R(x) = n(x) n(x)'`` (its cross terms, and which coordinates its entries depend on, probed at
  :data:`PROBES` fixed states) or one chance constraint couples them;
- no joint chance constraints, no objective, ``guarantee="mlo"`` (the caller checks the last two).

Then the covariance stays block-diagonal along every plan (the Kalman update of a block-diagonal
``C``, ``R`` and prior never couples the blocks) and each block's belief evolves on its own.
Each block gets the *projection* of the formula's top-level conjuncts that constrain it (every
proposition keeps the chance constraints on the block's coordinates only) and is solved as a
problem of its own (the full solver on the block's coordinates, inputs, outputs, faces of the
control domain and prior; seeds spawned from the solve's seed, so the same seed gives the same
plan). The plans are composed: after its plan ends each block holds its last mean (the input
with ``B u = (I - A) mean`` when the domain admits it) until the longest plan ends, and the
composed plan gets the room its execution needs on the whole problem (:func:`.room.give_room`).

When every conjunct constrains one block, the composition is exact (a formula without negation
that a plan satisfies stays satisfied when the plan goes on). Otherwise (``free U G target``
where ``free`` and ``target`` constrain every robot: all must hold their targets together) the
projections are only necessary conditions, and the holds usually make the composition satisfy
the team's formula. Nothing here is trusted: the composed plan is re-rolled with the exact joint
belief dynamics and must pass the solve's final check (:mod:`.final_check`); otherwise, or when
a block is not found, the caller searches the joint problem. A block's ``infeasible`` is not
turned into a claim about the whole problem (the sensor's dependences were probed, not proven).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from ..belief import rollout, to_belief
from ..dynamical_system import LBS, LCS, POLBS, POLBSWithNonLinNoise, mk_lbs, mk_lcs, mk_switched_sys
from ..expressions import ProbabilisticLinearPredicate, mk_variable
from ..formulas import STLAnd, STLAtomicProposition, STLFormula, logical_and, map_atoms
from ..problem import Problem
from ..sets import Polytope
from .abstraction import Abstraction
from .interfaces import Budget
from .plan_lp import Scaling, lp_exact
from .results import SolveResult, SolveStats

if TYPE_CHECKING:
    from .options import SolverOptions

__all__ = ["ENABLED", "Block", "DecoupledPlan", "solve_decoupled", "split"]

logger = logging.getLogger(__name__)

ENABLED = True
"""Whether :func:`solve_decoupled` is tried at all (benchmarks switch it off to compare)."""

PROBES = 6
"""States at which the sensor noise's cross terms and dependences are probed."""

MIN_SECONDS = 0.05
"""A block is not started with less time than this left on the solve's cap."""


@dataclass
class Block:
    """One independent group of a split problem.

    Attributes
    ----------
    states : ndarray of int, shape (n_g,)
        The group's state coordinates.
    inputs : ndarray of int, shape (m_g,)
        Its inputs (the columns of ``B`` that move its states).
    outputs : ndarray of int, shape (p_g,)
        Its outputs (the rows of ``C`` over its states).
    rows : ndarray of int
        The faces of the control domain over its inputs.
    conjuncts : list of STLFormula
        The formula's top-level conjuncts that constrain its states (may be empty); the block's
        formula is their projection (:func:`project`).
    """

    states: np.ndarray
    inputs: np.ndarray
    outputs: np.ndarray
    rows: np.ndarray
    conjuncts: list[STLFormula]


@dataclass
class DecoupledPlan:
    """A composed plan: ``actions`` shape (N,), ``controls`` shape (N, m), and how it was made."""

    actions: np.ndarray
    controls: np.ndarray
    how: str


class _Union:
    def __init__(self, size: int) -> None:
        self.parent = list(range(size))

    def find(self, i: int) -> int:
        while self.parent[i] != i:
            self.parent[i] = self.parent[self.parent[i]]
            i = self.parent[i]
        return i

    def link(self, idx: Sequence[int] | np.ndarray) -> None:
        idx = [int(i) for i in idx]
        for j in idx[1:]:
            a, b = self.find(idx[0]), self.find(j)
            if a != b:
                self.parent[b] = a


def _nonzero(v: np.ndarray, tol: float = 0.0) -> np.ndarray:
    return np.nonzero(np.abs(v) > tol)[0]


def _link_matrix(uf: _Union, M: np.ndarray, tol: float = 0.0) -> None:
    """Link ``i`` and ``j`` for every off-diagonal entry ``M[i, j]`` above ``tol``."""
    for i, j in zip(*np.nonzero(np.abs(M) > tol), strict=True):
        if i != j:
            uf.link([i, j])


def _probe_points(problem: Problem) -> list[np.ndarray]:
    """A fixed set of states around the prior at growing scales (deterministic)."""
    init = problem.initial_state
    mean = np.asarray(init.mean, dtype=float)
    sd = np.sqrt(np.maximum(np.diag(init.cov), 0.0)) + 1.0
    rng = np.random.default_rng(20241124)
    pts = [mean]
    for scale in (0.5, 1.5, 4.0, 10.0, 30.0)[: PROBES - 1]:
        pts.append(mean + scale * sd * rng.standard_normal(mean.shape[0]))
    return pts


def split(problem: Problem) -> list[Block] | None:
    """The independent groups of ``problem`` (see the module docstring), or ``None`` when it does
    not split into two or more."""
    system = problem.switched_system
    formula = problem.stl_formula
    if system.num_modes != 1 or system.n < 2:
        return None
    if lp_exact(system):
        return None  # the plan LP and the eager MILP are exact there: nothing to gain
    mode = system.system_modes[0]
    n, m = system.n, system.m
    atoms = formula.atomic_propositions()
    if any(ap.joints for ap in atoms):
        return None
    conjuncts = _conjuncts(formula)
    uf = _Union(n)
    _link_matrix(uf, mode.A)
    owner_in = np.zeros(m, dtype=int)
    for j in range(m):
        rows = _nonzero(mode.B[:, j])
        if rows.size == 0:
            return None  # an input that moves nothing: no block to give it to
        uf.link(rows)
        owner_in[j] = rows[0]
    domain = problem.control_domain
    for r in range(domain.H.shape[0]):
        ins = _nonzero(domain.H[r])
        uf.link(owner_in[ins])
    _link_matrix(uf, mode.process_cov)
    _link_matrix(uf, np.asarray(problem.initial_state.cov, dtype=float))
    p = mode.C.shape[0]
    owner_out = np.zeros(p, dtype=int)
    for o in range(p):
        cols = _nonzero(mode.C[o])
        if cols.size == 0:
            return None  # an output of no state: its noise could still couple others
        uf.link(cols)
        owner_out[o] = cols[0]
    if p:
        if isinstance(mode, POLBSWithNonLinNoise):
            for x in _probe_points(problem):
                R = mode.noise_cov(x)
                _link_outputs(uf, R, owner_out)
                for j in range(n):
                    moved = x.copy()
                    moved[j] += 0.37 * (1.0 + abs(x[j]))
                    diff = np.abs(mode.noise_cov(moved) - R)
                    hit = np.nonzero(np.any(diff > 1e-12 * (1.0 + np.abs(R)), axis=1))[0]
                    uf.link([j, *owner_out[hit].tolist()])
        else:
            _link_outputs(uf, mode.noise_cov(problem.initial_state.mean), owner_out)
    coords_of: list[set[int]] = []
    for f in conjuncts:
        coords: set[int] = set()
        for ap in f.atomic_propositions():
            for pred in ap.predicates:
                touched = _nonzero(pred.h)
                uf.link(touched)  # one chance constraint is never split
                coords.update(touched.tolist())
        coords_of.append(coords)
    roots = sorted({uf.find(i) for i in range(n)})
    if len(roots) < 2:
        return None
    blocks = []
    for r in roots:
        states = np.array([i for i in range(n) if uf.find(i) == r])
        inputs = np.array([j for j in range(m) if uf.find(int(owner_in[j])) == r], dtype=int)
        outputs = np.array([o for o in range(p) if uf.find(int(owner_out[o])) == r], dtype=int)
        rows = np.array(
            [k for k in range(domain.H.shape[0]) if np.any(np.abs(domain.H[k, inputs]) > 0)], dtype=int
        )
        mine = [f for f, c in zip(conjuncts, coords_of, strict=True) if any(uf.find(i) == r for i in c)]
        if inputs.size == 0:
            return None
        blocks.append(Block(states, inputs, outputs, rows, mine))
    return blocks


def _link_outputs(uf: _Union, R: np.ndarray, owner_out: np.ndarray) -> None:
    for a, b in zip(*np.nonzero(np.abs(R) > 1e-12 * (1.0 + np.abs(R).max())), strict=True):
        if a != b:
            uf.link([owner_out[a], owner_out[b]])


class _BlockNoise:
    """The sensor noise factor of one block: rows ``outputs`` of ``n(x)`` at the state whose
    other coordinates are held at ``ref`` (they do not enter these rows: probed by :func:`split`).
    Takes a state (n_g,) or a batch (S, n_g)."""

    def __init__(
        self, V: Callable[[np.ndarray], Any], ref: np.ndarray, states: np.ndarray, outputs: np.ndarray
    ):
        self.V, self.ref, self.states, self.outputs = V, ref, states, outputs

    def __call__(self, xg: ArrayLike) -> np.ndarray:
        xg = np.asarray(xg, dtype=float)
        x = np.broadcast_to(self.ref, (*xg.shape[:-1], self.ref.shape[0])).copy()
        x[..., self.states] = xg
        return np.asarray(np.asarray(self.V(x))[..., self.outputs, :])


def _sub_problem(problem: Problem, block: Block) -> Problem:
    """The problem of one block: its coordinates, inputs, outputs, faces and conjuncts."""
    mode = problem.switched_system.system_modes[0]
    s, i, o = block.states, block.inputs, block.outputs
    A, B = mode.A[np.ix_(s, s)], mode.B[np.ix_(s, i)]
    sub: LCS
    # a block that no sensor row reads is blind: its sub-system has no C (an empty C is no sensor)
    if isinstance(mode, POLBS) and o.size:
        C = mode.C[np.ix_(o, s)]
        if isinstance(mode, POLBSWithNonLinNoise):
            ref = np.asarray(problem.initial_state.mean, dtype=float)
            floor = mode.noise_floor[np.ix_(o, o)]
            V_floor = floor if np.any(floor) else None
            sub = mk_lbs(A, B, mode.W[s, :], C, _BlockNoise(mode.V, ref, s, o), V_floor)
        else:
            sub = mk_lbs(A, B, mode.W[s, :], C, mode.noise(problem.initial_state.mean)[o, :])
    elif isinstance(mode, LBS):
        sub = mk_lbs(A, B, mode.W[s, :])
    else:
        sub = mk_lcs(A, B)
    x = mk_variable(size=s.size, dtype=float)
    where = {int(c): k for k, c in enumerate(s)}

    def atom(ap: STLAtomicProposition) -> STLAtomicProposition:
        preds = []
        for pred in ap.predicates:
            touched = _nonzero(pred.h)
            if not touched.size or int(touched[0]) not in where:
                continue  # another block's chance constraint (or a constant one)
            h = np.zeros(s.size)
            for c in touched:
                h[where[int(c)]] = pred.h[c]
            preds.append(ProbabilisticLinearPredicate(h, pred.c, x, pred.eps))
        return STLAtomicProposition(preds, ap.modes, ap.name)

    parts = [map_atoms(f, atom) for f in block.conjuncts]
    formula = parts[0] if len(parts) == 1 else logical_and(*parts)
    domain = _sub_domain(problem.control_domain, block)
    init = problem.initial_state
    prior = to_belief(np.asarray(init.mean, dtype=float)[s], np.asarray(init.cov, dtype=float)[np.ix_(s, s)])
    return Problem(mk_switched_sys([sub]), domain, prior, formula)


def _sub_domain(dom: Polytope, block: Block) -> Polytope:
    """The faces of the control domain over the block's inputs, shape (rows, m_g)."""
    return Polytope(dom.H[np.ix_(block.rows, block.inputs)], dom.c[block.rows])


def _hold_input(mode: LCS, dom: Polytope, block: Block, mean: np.ndarray) -> np.ndarray:
    """The block's input after its plan ends: the one that keeps its mean where the plan left it
    (least squares of ``B u = (I - A) mean``) when the control domain admits it, else the domain's
    steering centre. Shape (m_g,)."""
    from .steering import steering_center  # (the sampler imports the synthesis parts)

    s, i = block.states, block.inputs
    A, B = mode.A[np.ix_(s, s)], mode.B[np.ix_(s, i)]
    domain = _sub_domain(dom, block)
    u = np.linalg.lstsq(B, mean - A @ mean, rcond=None)[0]
    if domain.H.shape[0] == 0 or np.all(domain.H @ u + domain.c <= 0):
        return np.asarray(u)
    return np.asarray(steering_center(domain))


def _conjuncts(formula: STLFormula) -> list[STLFormula]:
    return list(formula.children) if isinstance(formula, STLAnd) else [formula]


def _blocks_of(formula: STLFormula, blocks: list[Block]) -> set[int]:
    """The blocks whose states the formula's chance constraints touch."""
    touched: set[int] = set()
    for ap in formula.atomic_propositions():
        for pred in ap.predicates:
            touched.update(_nonzero(pred.h).tolist())
    return {g for g, b in enumerate(blocks) if touched & set(b.states.tolist())}


def _merge(into: SolveStats, sub: SolveStats) -> None:
    """Add a block's work counters and times to the solve's (execution room: the least)."""
    for f in fields(SolveStats):
        a, b = getattr(into, f.name), getattr(sub, f.name)
        if f.name == "caps_hit":
            into.caps_hit.extend(c for c in b if c not in a)
        elif f.name == "execution_room":
            if b is not None:
                into.execution_room = b if a is None else min(a, b)
        elif f.name in ("time_total", "improvements"):
            continue
        elif f.name in ("bmc_depth", "encoded_depth"):
            setattr(into, f.name, max(a, b))
        elif isinstance(a, int | float) and not isinstance(a, bool):
            setattr(into, f.name, a + b)


def _give_room(
    problem: Problem,
    options: SolverOptions,
    budget: Budget,
    stats: SolveStats,
    actions: np.ndarray,
    controls: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The room of the composed plan, measured (and given where an LP round can) on the whole
    problem (:func:`.room.give_room`): the blocks' own rooms are about their own formulas."""
    stats.execution_room = None
    polish = options.sampler.polish_rounds  # the sampler's polish, on the composed plan
    if not polish:
        return actions, controls
    from .room import give_room  # (room imports the plan LP; kept out of the import-time graph)

    init, system = problem.initial_state, problem.switched_system
    traj = rollout(system, init, actions, controls)
    abstraction = Abstraction(problem.stl_formula, system.n)
    scaling = Scaling.compute(system, problem.control_domain, init.mean, init.cov, abstraction)
    rounds = 2 * max(polish, 4)
    traj = give_room(problem, abstraction, scaling, traj, rounds, stats, budget.deadline)
    return np.asarray(traj.get_action(), dtype=int), np.asarray(traj.get_control(), dtype=float)


def solve_decoupled(
    problem: Problem,
    options: SolverOptions,
    budget: Budget,
    stats: SolveStats,
    synthesize: Callable[[Problem, SolverOptions, float], SolveResult],
) -> DecoupledPlan | None:
    """Solve each independent block on its own and compose the plans (``None``: not applicable,
    or a block not found; the caller then searches the joint problem).

    Parameters
    ----------
    problem : Problem
    options : SolverOptions
    budget : Budget
        The solve's wall-clock cap; each block gets what is left of it.
    stats : SolveStats
        The solve's statistics: every block's work is added to it.
    synthesize : callable
        ``synthesize(problem, options, start) -> SolveResult`` (:func:`.pipeline.core`).

    Returns
    -------
    DecoupledPlan or None
    """
    if not ENABLED:
        return None
    blocks = split(problem)
    if blocks is None:
        return None
    logger.info(
        "decoupled: %d independent blocks of %s states; planning each on its own",
        len(blocks),
        [int(b.states.size) for b in blocks],
    )
    seeds = np.random.SeedSequence(options.search.seed).spawn(len(blocks))
    m = problem.switched_system.m
    mode = problem.switched_system.system_modes[0]
    dom = problem.control_domain
    mean0 = np.asarray(problem.initial_state.mean, dtype=float)
    parts = []
    for g, block in enumerate(blocks):
        if not block.conjuncts:
            parts.append((np.zeros((0, block.inputs.size)), mean0[block.states]))
            continue
        sub = _sub_problem(problem, block)
        left = budget.remaining()
        if left < MIN_SECONDS:
            return None
        seed = int(seeds[g].generate_state(1, np.uint64)[0] & np.uint64(2**63 - 1))
        result = synthesize(sub, options.with_(seed=seed, time_limit=left), time.perf_counter())
        _merge(stats, result.stats)
        if result.status != "found" or result.trajectory is None:
            logger.info(
                "decoupled: block %d (states %s): %s: %s",
                g,
                block.states.tolist(),
                result.status,
                result.reason,
            )
            return None
        traj = result.trajectory
        controls_g = np.asarray(traj.get_control(), dtype=float).reshape(-1, block.inputs.size)
        parts.append((controls_g, np.asarray(traj.get_mean(traj.num_of_steps), dtype=float)))
    N = max(c.shape[0] for c, _ in parts)
    controls = np.zeros((N, m))
    for block, (c, last) in zip(blocks, parts, strict=True):
        controls[:, block.inputs] = _hold_input(mode, dom, block, last)
        controls[: c.shape[0], block.inputs] = c
    actions, controls = _give_room(problem, options, budget, stats, np.zeros(N, dtype=int), controls)
    separable = all(len(_blocks_of(f, blocks)) == 1 for f in _conjuncts(problem.stl_formula))
    how = (
        f"{len(blocks)} independent blocks planned one by one and composed"
        if separable
        else f"{len(blocks)} independent blocks planned on the formula's projections, composed with holds"
    )
    return DecoupledPlan(actions, controls, how)
