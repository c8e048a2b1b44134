"""Bounded model checking of a PrSTL formula over the proposition abstraction (SAT, python-sat).

Letters are the formula's atomic propositions and the modes. For every step ``k <= H`` (``H`` the
formula's horizon) the encoding has

- ``p[i, k]``: proposition ``i`` is *claimed* to hold at ``k``; the formula has no negation, so
  a claim is a requirement and an unclaimed proposition may hold or not;
- ``m[q, k]`` (``k >= 1``): mode ``q`` is used to arrive at ``k`` (exactly one);
- ``alive[k]``: the trace has a step ``k`` (``alive[k+1] -> alive[k]``); iterative deepening
  bounds the plan length with the assumption ``not alive[N+1]``, so every depth reuses one
  incremental solver and everything it learnt.

Interval operators are encoded without unrolling ``O(H * (b - a))`` terms:

- windows ``F[a,b] f`` / ``G[a,b] f`` come from a shared sparse table of ``OR`` / ``AND`` gates
  over power-of-two spans (``O(H log(b - a))`` gates, shared by every use of ``f``);
- ``f1 U[a,b] f2`` at ``k`` is ``F[a,b] f2`` at ``k`` and the untimed chain
  ``U*(j) = f2(j) | (f1(j) & U*(j+1))`` at ``k + a`` (equivalent on discrete time: the earliest
  ``f2`` inside the window is a witness of both);
- ``f1 R[a,b] f2`` is ``G[a,b] f2 | (f2 U[a,b] (f1 & f2))``.

Gates are hash-consed (Tseitin with constant folding), so equal sub-terms share one variable.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterable, Sequence

import numpy as np
from pysat.solvers import NoSuchSolverError, Solver

from ..errors import InvalidArgumentError
from ..formulas import STLAnd, STLAtomicProposition, STLFormula, STLOr, STLRelease, STLUntil
from .budget import Budget, BudgetExceeded

__all__ = ["BMCEncoder"]

logger = logging.getLogger(__name__)

_CHECK_EVERY = 1 << 15  # variables between two looks at the wall-clock cap while encoding


class BMCEncoder:
    """Incremental SAT encoding of ``formula`` over ``len(atoms)`` propositions and ``num_modes`` modes.

    Parameters
    ----------
    formula : STLFormula
    atoms : sequence of STLAtomicProposition
        The non-constant propositions, in a fixed order (index ``i`` of ``p[i, k]``).
    num_modes : int
    bound : int, optional
        Last step the encoding unrolls (plans of at most ``bound`` steps); default the
        formula's horizon. Steps past it satisfy nothing, exactly as past the end of a plan.
    sat_backend : str
        python-sat solver name.
    budget : Budget, optional
        Wall-clock cap, checked while encoding and enforced on every SAT call.
    """

    def __init__(
        self,
        formula: STLFormula,
        atoms: Sequence[STLAtomicProposition],
        num_modes: int,
        bound: int | None = None,
        sat_backend: str = "cadical195",
        budget: Budget | None = None,
    ) -> None:
        self.formula = formula
        self.atoms = list(atoms)
        self.atom_index = {id(a): i for i, a in enumerate(self.atoms)}
        self.num_modes = num_modes
        self.H = formula.horizon if bound is None else int(bound)
        self.budget = budget
        self._nvars = 0
        self.clauses: list[list[int]] = []
        self.T = self._new()
        self.clauses.append([self.T])
        self._gates: dict[tuple[object, ...], int] = {}
        H = self.H
        self.alive = [self.T] + [self._new() for _ in range(H + 1)]  # alive[H+1] = "longer than H"
        for k in range(H + 1):
            self.clauses.append([-self.alive[k + 1], self.alive[k]])
        self.p = np.array([[self._new() for _ in range(H + 1)] for _ in self.atoms], dtype=np.int64).reshape(
            len(self.atoms), H + 1
        )
        if num_modes == 1:
            self.m = np.full((1, H + 1), self.T, dtype=np.int64)
        else:
            self.m = np.array([[self._new() for _ in range(H + 1)] for _ in range(num_modes)], dtype=np.int64)
            for k in range(1, H + 1):
                col = [int(v) for v in self.m[:, k]]
                self.clauses.append(col)
                for a in range(num_modes):
                    for b in range(a + 1, num_modes):
                        self.clauses.append([-col[a], -col[b]])
        for i, ap in enumerate(self.atoms):
            for k in range(H + 1):
                lit = int(self.p[i, k])
                self.clauses.append([-lit, self.alive[k]])
                if k >= 1 and ap.modes is not None:
                    self.clauses.append([-lit] + [int(self.m[q, k]) for q in sorted(ap.modes)])
        self._memo: dict[tuple[int, int], int] = {}
        self._tables: dict[tuple[int, str, int], dict[int, int]] = {}
        self._chains: dict[tuple[int, int], dict[int, int]] = {}
        self._conj: dict[int, STLFormula] = {}
        self.root = self.lit(formula, 0)
        self.clauses.append([self.root])
        self.selector = self._new()  # assumed true while abandoned candidates are set aside
        # python-sat cannot interrupt CaDiCaL: its calls are checked against the cap between calls.
        self._interruptible = not sat_backend.startswith("cadical")
        try:
            self.solver = Solver(name=sat_backend, bootstrap_with=self.clauses)
        except (NoSuchSolverError, ValueError, NotImplementedError) as exc:
            raise InvalidArgumentError(f"sat_backend {sat_backend!r} cannot be used: {exc}") from None
        self.learnt: list[list[int]] = []
        self.sat_calls = 0
        logger.debug("BMC encoding: %d variables, %d clauses, horizon %d", self._nvars, len(self.clauses), H)

    # -- gates ------------------------------------------------------------------------------------
    def _new(self) -> int:
        self._nvars += 1
        if self.budget is not None and not self._nvars % _CHECK_EVERY:
            self.budget.check(f"SAT encoding of {self.H + 1} steps")
        return self._nvars

    def new_selector(self) -> int:
        """A fresh variable for a family of guarded clauses (the proposer's preferences)."""
        return self._new()

    @property
    def num_vars(self) -> int:
        """Number of SAT variables."""
        return self._nvars

    def _and(self, lits: Iterable[int]) -> int:
        T = self.T
        out: set[int] = set()
        for lit in lits:
            if lit == -T:
                return -T
            if lit != T:
                out.add(lit)
        if not out:
            return T
        if any(-lit in out for lit in out):
            return -T
        if len(out) == 1:
            return next(iter(out))
        key = ("&", tuple(sorted(out)))
        g = self._gates.get(key)
        if g is None:
            g = self._new()
            self._gates[key] = g
            for lit in out:
                self.clauses.append([-g, lit])
            self.clauses.append([g] + [-lit for lit in out])
        return g

    def _or(self, lits: Iterable[int]) -> int:
        return -self._and(-lit for lit in lits)

    # -- formula ----------------------------------------------------------------------------------
    def lit(self, f: STLFormula, k: int) -> int:
        """Literal that is true iff ``f`` holds at step ``k`` (false past the horizon)."""
        if k > self.H:
            return -self.T
        key = (id(f), k)
        got = self._memo.get(key)
        if got is not None:
            return got
        if isinstance(f, STLAtomicProposition):
            if f.is_false:
                out = -self.T
            elif id(f) in self.atom_index:
                out = int(self.p[self.atom_index[id(f)], k])
            else:  # `true`: any step that exists
                out = self.alive[k]
        elif isinstance(f, STLAnd):
            out = self._and(self.lit(c, k) for c in f.children)
        elif isinstance(f, STLOr):
            out = self._or(self.lit(c, k) for c in f.children)
        elif isinstance(f, STLUntil):
            out = self._until(f.left, f.right, k + f.a, k + f.b)
        elif isinstance(f, STLRelease):
            window = self._window(f.right, "&", k + f.a, k + f.b)
            if f.left.is_false if isinstance(f.left, STLAtomicProposition) else False:
                out = window
            else:
                both = self._conj.get(id(f))
                if both is None:
                    both = STLAnd((f.left, f.right))
                    self._conj[id(f)] = both
                out = self._or([window, self._until(f.right, both, k + f.a, k + f.b)])
        else:
            raise TypeError(f"cannot encode {type(f).__name__}")
        self._memo[key] = out
        return out

    def _until(self, left: STLFormula, right: STLFormula, lo: int, hi: int) -> int:
        reach = self._window(right, "|", lo, hi)
        if isinstance(left, STLAtomicProposition) and left.is_true and id(left) not in self.atom_index:
            return reach  # `true` holds on every existing step before the witness
        return self._and([reach, self._chain(left, right, lo)])

    def _chain(self, left: STLFormula, right: STLFormula, j: int) -> int:
        """Untimed ``left U right`` at ``j`` over the whole bounded trace (built backwards)."""
        if j > self.H:
            return -self.T
        chain = self._chains.setdefault((id(left), id(right)), {})
        if j not in chain:
            # The chain is filled contiguously from its lowest built step up to H.
            start = min(chain) if chain else self.H + 1
            nxt = chain.get(start, -self.T)
            for i in range(start - 1, j - 1, -1):
                nxt = self._or([self.lit(right, i), self._and([self.lit(left, i), nxt])])
                chain[i] = nxt
        return chain[j]

    def _window(self, f: STLFormula, op: str, lo: int, hi: int) -> int:
        """``op`` (``&`` or ``|``) of ``f`` over steps ``lo..hi`` (steps past ``H`` are false)."""
        if op == "&" and hi > self.H:
            return -self.T
        hi = min(hi, self.H)
        if lo > hi:
            return -self.T
        length = hi - lo + 1
        level = length.bit_length() - 1
        first = self._table(f, op, level, lo)
        second = self._table(f, op, level, hi - (1 << level) + 1)
        return self._and([first, second]) if op == "&" else self._or([first, second])

    def _table(self, f: STLFormula, op: str, level: int, j: int) -> int:
        if level == 0:
            return self.lit(f, j)
        table = self._tables.setdefault((id(f), op, level), {})
        got = table.get(j)
        if got is None:
            half = 1 << (level - 1)
            a = self._table(f, op, level - 1, j)
            b = self._table(f, op, level - 1, j + half)
            got = self._and([a, b]) if op == "&" else self._or([a, b])
            table[j] = got
        return got

    # -- solving ----------------------------------------------------------------------------------
    def add_clause(self, clause: Sequence[int]) -> None:
        """Add a (blocking or pruning) clause for good."""
        lits = [int(v) for v in clause]
        self.learnt.append(lits)
        self.solver.add_clause(lits)

    def set_phases(self, literals: Sequence[int]) -> None:
        """Preferred polarities for the next searches."""
        self.solver.set_phases([int(v) for v in literals])

    def solve(self, depth: int | None = None, assumptions: Sequence[int] = ()) -> bool:
        """Is there a claim assignment of length ``<= depth + 1`` steps (default: the bound)?

        Raises
        ------
        BudgetExceeded
            When the wall-clock cap interrupts the SAT search.
        """
        assume = [int(v) for v in assumptions]
        if depth is not None and depth < self.H:
            assume.append(-self.alive[depth + 1])
        self.sat_calls += 1
        if self.budget is None or not self._interruptible:
            if self.budget is not None:
                self.budget.check("SAT search")
            return bool(self.solver.solve(assumptions=assume))
        self.budget.check("SAT search")
        timer = threading.Timer(max(self.budget.remaining(), 0.0), self.solver.interrupt)
        timer.daemon = True
        timer.start()
        try:
            out = self.solver.solve_limited(assumptions=assume, expect_interrupt=True)
        finally:
            timer.cancel()
        if out is None:
            raise BudgetExceeded("SAT search")
        return bool(out)

    def model_claims(self) -> tuple[np.ndarray, np.ndarray, int]:
        """Claims of the last model: ``(truth (n_atoms, H+1) bool, modes (H+1,) int, length)``.

        ``modes[k]`` is the mode used to arrive at ``k`` (``modes[0]`` is meaningless); ``length``
        is the number of alive steps.
        """
        model = self.solver.get_model()
        val = np.zeros(self._nvars + 1, dtype=bool)
        pos = np.asarray(model, dtype=np.int64)
        val[pos[pos > 0]] = True
        val[self.T] = True
        truth = val[self.p] if self.p.size else np.zeros((0, self.H + 1), dtype=bool)
        modes = np.argmax(val[self.m], axis=0) if self.num_modes > 1 else np.zeros(self.H + 1, dtype=int)
        alive = val[np.asarray(self.alive[: self.H + 1])]
        length = int(np.sum(alive))
        return truth, modes, length

    def close(self) -> None:
        """Free the SAT solver."""
        self.solver.delete()
