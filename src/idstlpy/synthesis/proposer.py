"""The BMC proposer: discrete plans from a SAT encoding that is unrolled lazily.

The encoding (:class:`~.bmc.BMCEncoder`) is built for plans of at most ``bound`` steps and
rebuilt with a fourfold bound when no plan that short is left, so cost and memory follow the
plan lengths actually searched, not the formula's interval bounds (``F[0, 10**9] goal`` with the
goal three steps away unrolls a few dozen steps). Every clause the proposer learns is kept in a
symbolic form (proposition or mode, step, sign) and carried over to each rebuilt encoding.

Clauses come in two kinds:

- **proven** (LP pruning facts, teachers' refutations): they exclude plans that cannot exist;
- **abandoned** candidates (a teacher gave up): they are guarded by a selector literal that is
  assumed while searching, so the proposer moves on, but they never count as a proof.

When no candidate is left, the proposer re-asks the SAT solver without the selector: only if
the proven clauses alone leave nothing, at the formula's full horizon, is the answer a proof
(:class:`~.interfaces.ProposerDry` with ``proven=True``).
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from ..formulas import STLAnd, STLAtomicProposition, STLFormula, STLOr, STLRelease, STLUntil
from .abstraction import Abstraction, PruningReport
from .bmc import BMCEncoder
from .interfaces import Budget, BudgetExceeded, Conflict, ProposerDry
from .options import SolverOptions
from .plan import DiscretePlan, extract_witness
from .proofs import NoProof, Proof, build_certificate
from .results import SolveStats

__all__ = ["BMCProposer", "min_plan_length"]

logger = logging.getLogger(__name__)

_FIRST_BOUND = 32  # steps the first encoding unrolls (beyond the formula's minimum length)

# A symbolic literal: ("p", atom, step, positive) or ("m", mode, step, positive).
SymLit = tuple[str, int, int, bool]


def min_plan_length(formula: STLFormula) -> float:
    """Fewest steps any plan satisfying ``formula`` at step 0 must have (``inf``: none can).

    Under the strong finite semantics an index past the end satisfies nothing, so
    ``always(0, b, f)`` needs ``b + 1`` steps and ``f1 U[a, b] f2`` at least ``a + 1``.
    """
    memo: dict[int, float] = {}

    def need(f: STLFormula) -> float:
        got = memo.get(id(f))
        if got is not None:
            return got
        if isinstance(f, STLAtomicProposition):
            out = math.inf if f.is_false else 1.0
        elif isinstance(f, STLAnd):
            out = max(need(c) for c in f.children)
        elif isinstance(f, STLOr):
            out = min(need(c) for c in f.children)
        elif isinstance(f, STLUntil):
            out = f.a + need(f.right)
        elif isinstance(f, STLRelease):
            out = min(f.b + need(f.right), f.a + max(need(f.left), need(f.right)))
        else:
            out = 1.0
        memo[id(f)] = out
        return out

    return need(formula)


class BMCProposer:
    """Proposes discrete plans, shortest first (see the module docstring).

    Parameters
    ----------
    formula : STLFormula
    abstraction : Abstraction
    num_modes : int
    report : PruningReport
        Proven facts from LP pruning (applied at every step of every encoding).
    options : SolverOptions
    budget : Budget
    stats : SolveStats
    """

    def __init__(
        self,
        formula: STLFormula,
        abstraction: Abstraction,
        num_modes: int,
        report: PruningReport,
        options: SolverOptions,
        budget: Budget,
        stats: SolveStats,
    ) -> None:
        self.formula = formula
        self.abs = abstraction
        self.num_modes = num_modes
        self.report = report
        self.options = options.search
        self.budget = budget
        self._build_seconds = 0.0
        self.stats = stats
        self.H = formula.horizon
        # bound b unrolls the states 0..b: plans of at most b steps (b transitions)
        self.cap = min(self.H, self.options.max_plan_length)
        need = min_plan_length(formula)
        self.min_depth = int(need - 1) if math.isfinite(need) else self.H + 1
        self.hard: list[list[SymLit]] = []
        self.hard_proofs: list[Proof] = []  # what proves each of ``hard``
        # The proven clauses of the current encoding as added, with their proofs (the
        # certificate of an ``infeasible``, :meth:`certificate`).
        self.derived: list[tuple[list[int], Proof]] = []
        self.soft: list[list[SymLit]] = []
        self.depth: int | None = None
        self.enc: BMCEncoder | None = None
        # Transitions with no room for the execution (report.roomless_gaps): a preference, guarded
        # by a selector of their own that is assumed until no candidate is left without them.
        self.prefer_room = bool(report.roomless_gaps)
        self._room = 0
        self.bound = 0
        self._sat_calls_done = 0
        if self.min_depth <= self.cap:
            self.bound = min(self.cap, max(self.min_depth, _FIRST_BOUND))
            self._build()

    # -- encoding ---------------------------------------------------------------------------------
    def _build(self) -> None:
        if self.enc is not None:
            self._sat_calls_done += self.enc.sat_calls
            self.enc.close()
        started = time.perf_counter()
        with self.stats.clock("time_bmc"):
            enc = BMCEncoder(
                self.formula,
                self.abs.atoms,
                self.num_modes,
                bound=self.bound,
                sat_backend=self.options.sat_backend,
                budget=self.budget,
            )
            self.enc = enc
            self.derived = []
            self._add_pruning()
            for clause, proof in zip(self.hard, self.hard_proofs, strict=True):
                self._add(clause, soft=False, proof=proof)
            for clause in self.soft:
                self._add(clause, soft=True)
            if self.abs.num_atoms:
                enc.set_phases([int(v) for v in enc.p.ravel()])
        self._build_seconds = time.perf_counter() - started  # (a safety cap's estimate only)
        self.stats.encoded_depth = max(self.stats.encoded_depth, self.bound)
        logger.info("BMC: encoding unrolled to %d steps (%d variables)", self.bound, enc.num_vars)

    def _proven(self, clause: list[int], key: tuple[object, ...]) -> None:
        """Add a pruning fact's clause, remembering its proof (:attr:`PruningReport.proofs`)."""
        proof = self.report.proofs.get(key)
        self.derived.append((clause, proof if proof is not None else NoProof(f"LP pruning fact {key}")))
        self._enc().add_clause(clause)

    def _add_pruning(self) -> None:
        enc, rep, H = self._enc(), self.report, self.bound
        for i in rep.empty_atoms:
            for k in range(H + 1):
                self._proven([-int(enc.p[i, k])], ("empty", i))
        for i, j in rep.disjoint_pairs:
            for k in range(H + 1):
                self._proven([-int(enc.p[i, k]), -int(enc.p[j, k])], ("disjoint", i, j))
        for i, j, q in rep.impossible_steps:
            for k in range(H):
                clause = [-int(enc.p[i, k]), -int(enc.p[j, k + 1])]
                if q >= 0:
                    clause.append(-int(enc.m[q, k + 1]))
                self._proven(clause, ("step", i, j, q))
        for i, j, d in rep.impossible_gaps:
            for k in range(H + 1 - d):
                self._proven([-int(enc.p[i, k]), -int(enc.p[j, k + d])], ("gap", i, j, d))
        if rep.roomless_gaps:
            self._room = enc.new_selector()
            for i, j, d in rep.roomless_gaps:
                for k in range(H + 1 - d):
                    enc.add_clause([-int(enc.p[i, k]), -int(enc.p[j, k + d]), -self._room])
        for i in rep.initial_false:
            self._proven([-int(enc.p[i, 0])], ("initial", i))
        for i in rep.out_of_reach:
            for k in range(1, H + 1):
                key = ("reach", i, k) if ("reach", i, k) in rep.proofs else ("reach", i)
                self._proven([-int(enc.p[i, k])], key)

    def _enc(self) -> BMCEncoder:
        if self.enc is None:  # only when the formula needs longer plans than allowed
            raise RuntimeError("the proposer has no encoding")
        return self.enc

    def _literal(self, lit: SymLit) -> int | None:
        """The SAT literal of a symbolic one; ``None`` when its step lies past the bound (false)."""
        kind, idx, k, positive = lit
        enc = self._enc()
        if k > self.bound:
            return None
        var = int(enc.p[idx, k]) if kind == "p" else int(enc.m[idx, k])
        return var if positive else -var

    def _add(self, clause: list[SymLit], soft: bool, proof: Proof | None = None) -> None:
        enc = self._enc()
        lits = []
        for lit in clause:
            v = self._literal(lit)
            if v is None:
                if not lit[3]:
                    return  # a negated literal past the bound is true: the clause holds
                continue
            lits.append(v)
        if soft:
            lits.append(-enc.selector)
        elif proof is not None:
            self.derived.append((lits or [-enc.T], proof))
        enc.add_clause(lits or [-enc.T])

    @property
    def sat_calls(self) -> int:
        """SAT calls over every encoding built so far."""
        return self._sat_calls_done + (self.enc.sat_calls if self.enc is not None else 0)

    # -- the Proposer interface -------------------------------------------------------------------
    def propose(self) -> DiscretePlan | ProposerDry:
        """The next candidate, shortest first, or why there is none (see the module docstring)."""
        if self.enc is None:
            return ProposerDry(
                False,
                f"the formula needs plans of at least {self.min_depth + 1} steps, more than "
                f"max_plan_length = {self.options.max_plan_length}",
            )
        while True:
            depth = self._search()
            if depth is not None:
                self.depth = depth
                self.stats.bmc_depth = max(self.stats.bmc_depth, depth)
                plan = self._plan()
                if plan is not None:
                    return plan
                continue
            if self.grow():
                continue
            if self.prefer_room:
                # Every plan left makes some transition without room: offer those too (shortest
                # first again).
                logger.info(
                    "proposer: no candidate left with room on every transition; dropping the preference"
                )
                self.prefer_room = False
                self.depth = None
                continue
            return self._dry()

    def grow(self) -> bool:
        """Unroll the encoding further (four times the bound, up to the cap); False when at the cap."""
        if self.enc is None or self.bound >= self.cap:
            return False
        # x4: the encoding costs O(N log N), so overshooting is cheaper than rebuilding often.
        bound = min(self.cap, max(4 * self.bound, self.bound + 1))
        # A build is not interruptible everywhere (the SAT solver takes its clauses at once):
        # one that would not fit in the time left, at the last build's pace, is not started.
        if self._build_seconds * (bound + 1) / (self.bound + 1) > self.budget.remaining():
            raise BudgetExceeded("the SAT encoding", f"its unrolling to {bound} steps")
        self.bound = bound
        self._build()
        return True

    def _assume(self, room: bool = True) -> list[int]:
        out = [self._enc().selector] if self.soft else []
        if room and self.prefer_room:
            out.append(self._room)
        return out

    def _search(self) -> int | None:
        """Smallest depth (from the last one) with a model under every clause, or None."""
        enc = self._enc()
        with self.stats.clock("time_bmc"):
            if not enc.solve(self.bound, self._assume()):
                return None
            if self.depth is None:
                lo, hi = max(0, min(self.min_depth, self.bound)), self.bound
                while lo < hi:  # SAT is monotone in the depth: binary search the shortest
                    mid = (lo + hi) // 2
                    if enc.solve(mid, self._assume()):
                        hi = mid
                    else:
                        lo = mid + 1
                depth = lo
            else:
                depth = min(self.depth, self.bound)
                while not enc.solve(depth, self._assume()):
                    depth = min(self.bound, depth + max(1, depth // 4))
            enc.solve(depth, self._assume())  # leave the model of the chosen depth
        return depth

    def _plan(self) -> DiscretePlan | None:
        enc = self._enc()
        claims, modes, length = enc.model_claims()
        witness = extract_witness(self.formula, claims[:, :length], self.abs.index, prefer_late=True)
        if witness is None:  # cannot happen for a model of the encoding; block it and go on
            logger.warning("BMC model does not satisfy the formula; blocking it")
            clause: list[SymLit] = [
                ("p", int(i), int(k), False) for i, k in zip(*np.nonzero(claims[:, :length]), strict=True)
            ]
            self.soft.append(clause)
            self._add(clause, soft=True)
            return None
        required, L = witness
        return DiscretePlan(required[:, :L], modes[:L].copy(), L)

    def _dry(self) -> ProposerDry:
        enc = self._enc()
        with self.stats.clock("time_bmc"):
            hard_sat = bool(self.soft) and enc.solve(self.bound, [-enc.selector])
        if hard_sat:
            return ProposerDry(False, "every remaining candidate was set aside without a proof", aside=True)
        if self.cap < self.H:
            return ProposerDry(
                False,
                f"no plan of at most max_plan_length = {self.options.max_plan_length} steps; the formula's "
                f"horizon allows {self.H}",
            )
        return ProposerDry(True, self._proof_reason())

    def _proof_reason(self) -> str:
        """Name the proof when LP pruning alone (no teacher) excluded every plan."""
        generic = "the proven clauses exclude every discrete plan up to the formula's horizon"
        if self.hard or self.cap < self.H:
            return generic
        truth = np.ones((self.abs.num_atoms, self.H + 1), dtype=bool)
        truth[self.report.empty_atoms, :] = False
        if extract_witness(self.formula, truth, self.abs.index) is None:
            return "the formula is unsatisfiable over its propositions (its logic, or empty regions)"
        truth[self.report.initial_false, 0] = False
        if extract_witness(self.formula, truth, self.abs.index) is None:
            names = self.abs.names()
            bad = ", ".join(names[i] for i in self.report.initial_false)
            return f"the initial belief does not satisfy what the formula requires at step 0 ({bad})"
        for i in self.report.out_of_reach:
            truth[i, 1:] = False
        if self.report.out_of_reach and extract_witness(self.formula, truth, self.abs.index) is None:
            return "; ".join(self.report.out_of_reach.values())
        return "LP pruning (disjoint regions, impossible one-step moves) excludes every discrete plan"

    def block(self, conflict: Conflict) -> None:
        """Forbid a proven conflict for good (with the modes that shaped it)."""
        clause: list[SymLit] = [("p", i, k, False) for (k, i) in conflict.requirements]
        if conflict.modes is not None and self.num_modes > 1 and conflict.requirements:
            last = max(k for k, _ in conflict.requirements)
            clause += [("m", int(conflict.modes[j]), j, False) for j in range(1, last + 1)]
        proof: Proof = conflict.certificate if conflict.certificate is not None else NoProof(conflict.proof)
        self.hard.append(clause)
        self.hard_proofs.append(proof)
        self._add(clause, soft=False, proof=proof)

    @staticmethod
    def _moved(plan: DiscretePlan) -> list[tuple[int, int]]:
        """``plan``'s requirements after step 0 (all of them when it has none later).

        The prior is fixed: a requirement at step 0 either holds (the teacher's problem is the
        same without it) or was pruned (``initial_false``). A candidate set aside without a
        proof takes with it every candidate that differs from it at step 0 only.
        """
        reqs = plan.requirements()
        later = [(k, i) for (k, i) in reqs if k > 0]
        return later or reqs

    def abandon(self, plan: DiscretePlan) -> None:
        """Set ``plan``'s requirement set aside (with its modes) without treating it as a proof."""
        reqs = self._moved(plan)
        clause: list[SymLit] = [("p", i, k, False) for (k, i) in reqs]
        if self.num_modes > 1 and reqs:
            last = max(k for k, _ in reqs)
            clause += [("m", int(plan.modes[j]), j, False) for j in range(1, last + 1)]
        self.soft.append(clause)
        self._add(clause, soft=True)

    def set_aside(self, plan: DiscretePlan) -> None:
        """Set ``plan``'s requirement set aside for *every* mode sequence, without a proof.

        For a requirement set whose modes a teacher searched without success (issue 24): the
        proposer moves on to other requirement sets instead of walking the mode sequences one by
        one; like :meth:`abandon`, the clause is guarded by the selector, so it never counts
        toward ``infeasible``.
        """
        clause: list[SymLit] = [("p", i, k, False) for (k, i) in self._moved(plan)]
        if clause:
            self.soft.append(clause)
            self._add(clause, soft=True)

    def guide(self, plan: DiscretePlan, truth: np.ndarray) -> None:
        """Prefer, in the next searches, the labels a teacher's trajectory actually has.

        ``truth`` has shape (n_atoms, K + 1): the labels at steps ``0..K``.
        """
        enc = self._enc()
        K = min(truth.shape[1] - 1, self.bound)
        # Step by step, each proposition's literal signed by its label; later steps claimed.
        signed = np.where(truth[:, 1 : K + 1], enc.p[:, 1 : K + 1], -enc.p[:, 1 : K + 1])
        phases = np.concatenate([signed.T.ravel(), enc.p[:, K + 1 :].ravel()])
        enc.set_phases(phases.tolist())

    def complete(self, truth: np.ndarray, modes: np.ndarray) -> DiscretePlan | None:
        """A plan consistent with a realised prefix, or ``None`` when none is left.

        Parameters
        ----------
        truth : ndarray of bool, shape (n_atoms, k + 1)
            The labels realised at steps ``0..k``.
        modes : ndarray of int, shape (k,)
            The modes used to arrive at steps ``1..k``.

        The plan is the witness of the *optimistic* completion (every proposition claimed at
        every later step) with the latest until-witnesses, so a branch keeps it as long as
        possible; the SAT proposer then confirms the prefix is completable under everything
        learnt so far.
        """
        k = truth.shape[1] - 1
        # A realised prefix of k + 1 steps needs room for what the formula may still ask.
        while k + self.min_depth + 1 > self.bound and self.grow():
            pass
        if k > self.bound:
            return None
        optimistic = np.ones((truth.shape[0], self.bound + 1), dtype=bool)
        optimistic[:, : k + 1] = truth
        w = extract_witness(self.formula, optimistic, self.abs.index, prefer_late=True)
        if w is None:
            return None
        enc = self._enc()
        assume = [-int(v) for v in enc.p[:, : k + 1][~truth]]
        if self.num_modes > 1:
            assume += [int(enc.m[q, j + 1]) for j, q in enumerate(modes)]
        with self.stats.clock("time_bmc"):
            # (a realised prefix may make a roomless transition: the preference does not apply)
            ok = enc.solve(assumptions=assume + self._assume(room=False))
        if not ok:
            return None
        required, L = w
        _, model_modes, _ = enc.model_claims()
        mm = model_modes[: max(L, k + 1)].copy()
        mm[1 : k + 1] = modes
        return DiscretePlan(required[:, :L], mm[:L], L)

    def export(self) -> BMCEncoder:
        """The current encoding with its proven clauses, for an eager model.

        Abandoned candidates' clauses carry the selector literal: fix it to false to drop them.
        """
        return self._enc()

    def certificate(self) -> dict[str, object]:
        """The certificate of a proven dry run (:func:`~.proofs.build_certificate`): the current
        encoding and the proven clauses, each with its proof.

        Returns
        -------
        dict
        """
        enc = self._enc()
        return build_certificate(enc.clauses, self.derived, enc.num_vars, self.options.sat_backend)

    def close(self) -> None:
        """Free the SAT solver."""
        if self.enc is not None:
            self._sat_calls_done += self.enc.sat_calls
            self.enc.close()
            self.enc = None
