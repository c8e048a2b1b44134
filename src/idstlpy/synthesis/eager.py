"""The eager MILP as a strategy of the loop: when to take over, and what it returns.

On an LP-exact, single-mode problem whose lazy loop has not converged (:func:`.milp.switch_to_eager`
decides, from the proven conflicts and the count of candidates), the eager MILP (:mod:`.milp`)
chooses the discrete plan over the proposer's encoding, growing the bound until it finds a plan or
proves there is none; the plan is re-timed by the plan LP on its witness and verified by the
loop's verify step. :meth:`EagerMILP.solve` returns a typed outcome: a plan with what the MILP
proved about its objective (:class:`MILPProof`), the end of the search (:class:`EagerEnd`:
``infeasible`` or ``budget_exhausted``), or :class:`EagerDeclined` (the lazy loop goes on). The
optimiser asks it for the optimum over the whole horizon (:meth:`EagerMILP.optimum`) and for the
best bound it proved on the way (:attr:`EagerMILP.proven_bound`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..backends import Backend, get_backend
from ..belief import rollout
from ..trajectory import ProbabilisticTSTrajectory
from .context import SolveContext, Verified, Verify
from .interfaces import BudgetExceeded, Found, Proposer
from .joint_milp import JointAnswer, JointSolver, joint_supported
from .milp import MILPOutcome, solve_milp, switch_to_eager
from .objectives import better, objective_value
from .options import Objective
from .plan import DiscretePlan, extract_witness
from .plan_lp import PlanLPContext
from .plan_solve import TIGHTEN, LPGoal, solve_plan_lp
from .room_measure import execution_room
from .teacher import LPTeacher, execution_margin

__all__ = ["EagerDeclined", "EagerEnd", "EagerMILP", "EagerOutcome", "EagerPlan", "MILPProof"]

logger = logging.getLogger(__name__)

JOINT_MODES = True
"""Whether LP-exact multi-mode problems under ``guarantee="execution"`` go to the joint MILP
(benchmarks switch it off to measure the lazy loop alone)."""

JOINT_AFTER = 2
"""The joint MILP takes over after this many times ``lazy_candidates`` lazy candidates (20 by
default; ``lazy_candidates = 0``: at once)."""

JOINT_ROUNDS = 60
"""Joint MILP solves (cut rounds included) before the lazy loop takes over."""

RETIME_TIGHTENINGS = (1e-12, 1e-10, 1e-8, TIGHTEN)
"""Room (relative to the smallest state unit) the effort re-timing keeps, tried in turn until
the monitor's exact re-check accepts the plan (:meth:`EagerMILP._retime`)."""


@dataclass(frozen=True)
class MILPProof:
    """What the eager MILP proved about the objective of the plan it chose.

    Attributes
    ----------
    proven : bool
        The MILP proved its plan optimal, and no bound on the way was borderline.
    scope : str
        The plans the bound is over: ``"horizon"`` or ``"plans of at most N steps"``.
    bound : float
        The MILP's proven bound (``nan`` without an objective).
    """

    proven: bool
    scope: str
    bound: float


@dataclass(frozen=True)
class EagerPlan:
    """The eager MILP's plan, verified, and what it proved."""

    plan: Verified
    proof: MILPProof
    how: str = "the eager MILP chose the plan, the LP timed it, the monitor agrees"


@dataclass(frozen=True)
class EagerEnd:
    """The eager MILP ended the search without a plan (``infeasible`` is a proof)."""

    status: Literal["infeasible", "budget_exhausted"]
    reason: str


@dataclass(frozen=True)
class EagerDeclined:
    """No answer from the eager MILP: the model cannot be bounded soundly, or its plan did not
    survive verification. The lazy loop goes on (and the MILP is not tried again)."""

    why: str


EagerOutcome = EagerPlan | EagerEnd | EagerDeclined


class EagerMILP:
    """The eager model over the proposer's encoding (see the module docstring).

    Parameters
    ----------
    ctx : SolveContext
    proposer : Proposer
        Its encoding (:meth:`~.interfaces.Proposer.export`) is the MILP's discrete part; the
        strategy grows it.
    verify : Verify
        The loop's verify step, for the MILP's plans.
    enabled : bool
        Whether the strategy may take over (an LP-exact, single-mode problem).
    joint : bool
        Several modes, LP-exact (:mod:`.joint_milp`): the joint MILP chooses modes, propositions
        and inputs together, at once (:meth:`_solve_joint`).
    teacher : LPTeacher, optional
        The plan LP teacher, which times the joint MILP's discrete plan with the room its
        execution needs (and may improve its modes for the execution).
    """

    def __init__(
        self,
        ctx: SolveContext,
        proposer: Proposer,
        verify: Verify,
        enabled: bool,
        joint: bool = False,
        teacher: LPTeacher | None = None,
    ) -> None:
        self.ctx = ctx
        self.proposer = proposer
        self.verify = verify
        self.enabled = enabled or joint
        self.joint = joint
        self.teacher = teacher
        # An optimum over the horizon is the MILP's job: with an objective, go there at once.
        options = ctx.options
        self.lazy_budget = 0 if options.objective is not None else options.lazy_candidates
        self.proven_bound: tuple[float, str] | None = None
        """An objective's bound the MILP proved over a scope (every plan of it, under the paper's
        semantics, which every returned plan meets), kept when its own plan is not returned (set
        aside below the execution target): ``(bound, scope)`` or None."""

    def due(self) -> bool:
        """Whether the MILP takes over now (:func:`~.milp.switch_to_eager`)."""
        ctx = self.ctx
        if self.joint:
            # The lazy loop first: the sensing families' problems converge there in at most 18
            # candidates (unchanged, bit for bit); past JOINT_AFTER times lazy_candidates it is
            # walking mode sequences one by one, and the joint MILP decides them at once.
            return self.enabled and ctx.stats.candidates >= JOINT_AFTER * ctx.options.lazy_candidates
        return self.enabled and switch_to_eager(
            self.proposer.hard, ctx.stats.candidates, self.lazy_budget, ctx.options.lazy_conflict_size
        )

    def solve(self) -> EagerOutcome:
        """Choose the plan with the MILP, growing the bound until a plan or a proof."""
        ctx, proposer = self.ctx, self.proposer
        if self.joint:
            outcome = self._solve_joint()
            if isinstance(outcome, EagerDeclined):
                self.enabled = False
                logger.info("joint MILP declined: %s", outcome.why)
            return outcome
        objective = ctx.options.objective
        if objective in ("effort", "margin"):
            while proposer.grow():  # the optimum over the whole horizon, not the first bound
                pass
        bounded = self._bounded()
        if not isinstance(bounded, tuple):
            if isinstance(bounded, EagerDeclined):
                self.enabled = False
            return bounded
        out, borderline = bounded
        if out.claims is None or out.controls is None:
            self.enabled = False
            return EagerDeclined("the MILP returned no plan")
        # Re-timed with only the LP's own tightening (2e-7 of the smallest state unit), a plan
        # can graze a face whose unit is larger (ReachAvoid's position, 10x the velocity's: 2e-8
        # on the scaled row, below HiGHS' tolerance) and fail the monitor by rounding (-1e-15),
        # which cost a second re-timing. Without an objective that reads the margin, the
        # re-timing leaves room of 1e-5 of the largest state unit inside every required face.
        room = 1e-5 * float(np.max(ctx.units.dx)) if objective in (None, "time") else 0.0
        whole = proposer.bound >= proposer.H or objective == "time"  # shorter plans are all inside
        scope = "horizon" if whole else f"plans of at most {proposer.bound} steps"
        if objective is not None and out.proven and not borderline:
            self.proven_bound = (out.bound, scope)
        checked = self._retime(out.claims, out.controls, objective, room)
        if checked is None:
            self.enabled = False
            return EagerDeclined("the MILP's plan failed verification")
        return EagerPlan(checked, MILPProof(out.proven and not borderline, scope, out.bound))

    def _solve_joint(self) -> EagerOutcome:
        """The joint MILP (:mod:`.joint_milp`) with its lazy cuts, growing the bound until a plan
        is verified or the relaxation proves there is none.

        Each round solves the model, rolls the exact recursion on its modes and adds the cuts of
        the faces it violates; a plan whose claimed faces hold exactly is timed by the plan LP
        teacher (the room its execution needs) and judged by the loop's verify step (monitor and
        execution target). A plan judged below the target adds execution cuts (:meth:`_room_cuts`):
        plans with the room their execution needs, and no proof any more.
        """
        ctx, proposer, stats = self.ctx, self.proposer, self.ctx.stats
        backend = get_backend(ctx.options.milp_backend, integer=True)
        problem, init = ctx.problem, ctx.problem.initial_state
        context = PlanLPContext(
            problem.switched_system, problem.control_domain, init.mean, init.cov, ctx.abstraction, ctx.units
        )
        why = joint_supported(context)
        if why is not None:
            return EagerDeclined(why)
        solver = JointSolver(context, ctx.budget)
        rounds = 0
        while True:
            ctx.budget.check("the joint MILP")
            spent = ctx.work_stop()
            if spent is not None:  # the work budget counts the plans the joint MILP hands the LP
                return EagerEnd("budget_exhausted", f"{spent}; {ctx.counts()}")
            if rounds >= JOINT_ROUNDS:
                return EagerDeclined(f"the joint MILP did not settle in {JOINT_ROUNDS} rounds")
            rounds += 1
            with stats.clock("time_lp"):
                answer = solver.solve(proposer.export(), backend)
            stats.milp_calls += 1
            if answer.status == "unsupported":
                return EagerDeclined(answer.why)
            if answer.status == "timeout":
                ctx.budget.check("the joint MILP")
                return EagerEnd("budget_exhausted", f"the joint MILP stopped: {answer.why}; {ctx.counts()}")
            if answer.status == "infeasible":
                if not solver.proofs:
                    return EagerEnd(
                        "budget_exhausted",
                        "no plan the joint MILP found meets the execution target, and no plan keeps "
                        f"the room the execution cuts ask; {ctx.counts()}",
                    )
                end = self._infeasible("the joint MILP (modes chosen with the plan)")
                if end is not None:
                    return end
                proposer.grow()
                continue
            with stats.clock("time_lp"):
                added = solver.cut(answer)
            # The plan LP decides the model's letters and modes exactly: a plan at the limit of
            # the lower bounds often needs only its means moved (no cut round for that).
            checked = self._joint_plan(answer, own=not added, own_first=not solver.proofs)
            if checked is not None:
                return EagerPlan(
                    checked,
                    MILPProof(False, "", float("nan")),
                    "the joint MILP chose the modes and the plan, the exact recursion and the monitor agree",
                )
            if added:
                continue
            if not self._room_cuts(solver, answer):
                return EagerEnd(
                    "budget_exhausted",
                    f"no plan the joint MILP found meets the execution target; {ctx.counts()}",
                )

    def _room_cuts(self, solver: JointSolver, answer: JointAnswer) -> int:
        """After a plan judged below the execution target: the room its execution needs
        (:func:`~.room_measure.execution_room`) as execution cuts of the model
        (:meth:`~.joint_milp.JointSolver.add_room`). Returns the number of new rows."""
        ctx = self.ctx
        if answer.claims is None or answer.actions is None or answer.controls is None:
            return 0
        witness = extract_witness(ctx.formula, answer.claims, ctx.abstraction.index, prefer_late=True)
        if witness is None:
            return 0
        required, L = witness
        plan = DiscretePlan(required[:, :L], np.concatenate([[-1], answer.actions[: L - 1]]).astype(int), L)
        problem = ctx.problem
        traj = rollout(problem.switched_system, problem.initial_state, answer.actions, answer.controls)
        room = execution_room(problem.switched_system, problem.control_domain, ctx.abstraction, plan, traj)
        if room is None:
            return 0
        added = solver.add_room(room.requirements, room.need, answer.actions)
        logger.info("joint MILP: plan below the execution target; %d execution cuts", added)
        return added

    def _joint_plan(self, answer: JointAnswer, own: bool, own_first: bool) -> Verified | None:
        """Verify the joint MILP's plan: timed by the plan LP teacher on its letters and modes
        (exact; the room its execution needs; the teacher's own mode search off: the model is
        the mode search), else its own inputs when they meet the claimed faces exactly
        (``own``; ``own_first``: those first, they keep the execution cuts' room)."""
        ctx = self.ctx
        if answer.claims is None or answer.actions is None or answer.controls is None:
            return None
        actions, controls = answer.actions, answer.controls
        attempts = ["own", "teacher"] if own_first else ["teacher", "own"]
        if not own:
            attempts.remove("own")
        for attempt in attempts:
            if attempt == "own":
                checked = self.verify(actions, controls)
                if checked is not None:
                    return checked
                continue
            if self.teacher is None:
                continue
            witness = extract_witness(ctx.formula, answer.claims, ctx.abstraction.index, prefer_late=True)
            if witness is None:
                continue
            required, L = witness
            modes = np.concatenate([[-1], actions[: L - 1]]).astype(int)
            plan = DiscretePlan(required[:, :L], modes, L)
            below = ctx.stats.below_target
            for search in (False, True):
                # first the model's modes as they are; a plan below the execution target gets
                # the teacher's mode search, which reads the execution (a look moved earlier)
                if search and (ctx.stats.below_target == below or not self.teacher.mode_search):
                    break
                ctx.stats.candidates += 1
                searching = self.teacher.mode_search
                self.teacher.mode_search = search
                try:
                    verdict = self.teacher.teach(plan, ctx.budget, ctx.stats)
                finally:
                    self.teacher.mode_search = searching
                if isinstance(verdict, Found):
                    checked = self.verify(verdict.actions, verdict.controls)
                    if checked is not None:
                        return checked
        return None

    def _bounded(self) -> tuple[MILPOutcome, bool] | EagerEnd | EagerDeclined:
        """The MILP at growing bounds: its first plan and whether a bound on the way was
        borderline (no shorter plan is proven absent then), or how the search ends."""
        ctx, proposer = self.ctx, self.proposer
        backend = get_backend(ctx.options.milp_backend, integer=True)
        borderline = False  # some bound's infeasibility rested on a tolerance (time's search)
        last: tuple[int, float] | None = None  # the last bound's steps and seconds
        while True:
            logger.info(
                "%d candidates tried: the eager MILP takes over at %d steps",
                ctx.stats.candidates,
                proposer.bound,
            )
            steps = max(proposer.bound, 1)
            # Building a MILP is not interruptible everywhere (its solver reads it at once): a
            # bound that would not fit in the time left, at the last bound's pace, is not tried.
            if last is not None and last[1] * steps / last[0] > ctx.budget.remaining():
                raise BudgetExceeded("the eager MILP", f"its model of {steps} steps")
            started = time.perf_counter()
            out = self._milp(backend, ctx.options.objective)
            last = (steps, time.perf_counter() - started)
            if out.status == "unsupported":
                logger.info("eager MILP not used: %s", out.why)
                return EagerDeclined(out.why)
            if out.status == "timeout":
                ctx.budget.check("the eager MILP")
                # (its solver is given the time left: a time limit there is the overall cap)
                if "time limit" in out.why.lower().replace("timelimit", "time limit") and (
                    "time_limit" not in ctx.stats.caps_hit
                ):
                    ctx.stats.caps_hit.append("time_limit")
                return EagerEnd("budget_exhausted", f"the eager MILP stopped: {out.why}; {ctx.counts()}")
            if out.status == "borderline":
                # No proof either way at this bound: at the horizon that is the answer; below it
                # the search goes on, but no shorter plan is proven absent any more.
                if proposer.bound >= proposer.H or proposer.bound >= proposer.cap:
                    return EagerEnd("budget_exhausted", f"{out.why}; {ctx.counts()}")
                borderline = True
                proposer.grow()
                continue
            if out.status == "infeasible":
                end = self._infeasible()
                if end is not None:
                    return end
                proposer.grow()
                continue
            return out, borderline

    def _infeasible(self, what: str = "the eager MILP") -> EagerEnd | None:
        """What the MILP's proof at the current bound ends, if anything (else: grow the bound)."""
        ctx, proposer = self.ctx, self.proposer
        if proposer.bound >= proposer.H:
            return EagerEnd(
                "infeasible", f"{what} proved that no plan exists within the horizon; {ctx.counts()}"
            )
        if proposer.bound >= proposer.cap:
            return EagerEnd(
                "budget_exhausted",
                f"no plan of at most max_plan_length = {ctx.options.max_plan_length} steps ({what}); "
                f"{ctx.counts()}",
            )
        return None

    def _milp(self, backend: Backend, objective: Objective | None) -> MILPOutcome:
        """The MILP over the proposer's current encoding."""
        ctx = self.ctx
        problem, stats = ctx.problem, ctx.stats
        init = problem.initial_state
        with stats.clock("time_lp"):
            context = PlanLPContext(
                problem.switched_system,
                problem.control_domain,
                init.mean,
                init.cov,
                ctx.abstraction,
                ctx.units,
            )
            out = solve_milp(self.proposer.export(), context, backend, ctx.budget, objective, ctx.weights)
        stats.milp_calls += 1
        return out

    def optimum(self, name: Objective) -> tuple[ProbabilisticTSTrajectory, bool, float, bool] | None:
        """The MILP's optimum of objective ``name`` over every plan up to the horizon (or
        ``max_plan_length``).

        Returns ``(plan, proven, bound, whole_horizon)`` or ``None`` when the MILP cannot be
        built soundly or finds nothing.
        """
        proposer = self.proposer
        while proposer.grow():
            pass
        out = self._milp(get_backend(self.ctx.options.milp_backend, integer=True), name)
        if out.status != "found" or out.claims is None or out.controls is None:
            return None
        if out.proven and proposer.bound >= proposer.H:
            self.proven_bound = (out.bound, "horizon")
        checked = self._retime(out.claims, out.controls, name)
        if checked is None:
            return None
        return checked.traj, out.proven, out.bound, proposer.bound >= proposer.H

    def _retime(
        self, claims: np.ndarray, controls: np.ndarray, objective: Objective | None, room: float = 0.0
    ) -> Verified | None:
        """Verify a MILP's plan, first re-solved by the plan LP on its witness (exact re-timing).

        ``room`` is the least margin (state units) the re-timing leaves inside the required
        faces. Without an objective (or for ``"time"``, whose value is the length) the re-timing
        also keeps the execution margin (:func:`~.teacher.execution_margin`). For ``"effort"`` and
        ``"margin"`` it solves the problem as stated (issue 25: the margin kept for execution is
        not part of the optimum the MILP proves): ``"effort"`` tries the tightenings of
        :data:`RETIME_TIGHTENINGS` in turn (the first plan the monitor accepts, so the value is
        the LP's optimum to ~1e-12 of the state's unit instead of 2e-7 of it divided by the
        input gain), and the MILP's own plan is verified too; the better of the two is returned.
        """
        formula = self.ctx.formula
        witness = extract_witness(
            formula, claims, self.ctx.abstraction.index, prefer_late=objective != "time"
        )
        optimising = objective in ("effort", "margin")
        found: list[Verified] = []
        if witness is not None:
            required, L = witness
            plan = DiscretePlan(required[:, :L], np.zeros(L, dtype=int), L)
            solved, timed = self._timed(plan, objective, room)
            if solved and not optimising:
                return timed  # the re-timed plan or nothing, as without an objective
            if timed is not None:
                found.append(timed)
        if optimising or not found:
            raw = self.verify(np.zeros(controls.shape[0], dtype=int), controls)
            if raw is not None:
                found.append(raw)
        if not found:
            return None
        if objective is None or objective == "time":
            return found[0]
        values = [objective_value(objective, v.traj, formula, self.ctx.weights) for v in found]
        best = 0
        for i in range(1, len(found)):
            if better(objective, values[i], values[best]):
                best = i
        return found[best]

    def _timed(
        self, plan: DiscretePlan, objective: Objective | None, room: float
    ) -> tuple[bool, Verified | None]:
        """The plan LP's re-timing of the MILP's witness ``plan``, verified (see :meth:`_retime`);
        for ``"effort"`` the first of :data:`RETIME_TIGHTENINGS` that passes.

        Returns ``(solved, plan)``: ``solved`` is False when the last LP found no plan.
        """
        ctx = self.ctx
        problem, stats = ctx.problem, ctx.stats
        system, init = problem.switched_system, problem.initial_state
        optimising = objective in ("effort", "margin")
        keep = room if optimising else max(execution_margin(system, init, ctx.abstraction, plan), room)
        for tighten in RETIME_TIGHTENINGS if objective == "effort" else (TIGHTEN,):
            context = PlanLPContext.of(
                problem, ctx.abstraction, ctx.units, get_backend(ctx.options.lp_backend)
            )
            goal = LPGoal(objective if optimising else None, ctx.weights, tighten)
            with stats.clock("time_lp"):
                lp = solve_plan_lp(
                    context,
                    plan,
                    keep,
                    goal=goal,
                    time_limit=max(ctx.budget.remaining(), 1e-3),
                    phases="witness",  # the MILP's witness: no elastic phase when it holds
                )
            stats.lp_calls += 1
            if not (lp.feasible and lp.controls is not None):
                return False, None
            checked = self.verify(np.zeros(plan.length - 1, dtype=int), lp.controls)
            if not optimising or checked is not None:
                return True, checked
        return True, None
