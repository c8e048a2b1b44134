"""The LP teacher: controls for a discrete plan, or a proof that there are none.

The teacher decides candidates with the plan LP (:mod:`.plan_solve`): exact when no mode's noise
depends on the state (:func:`~.plan_lp.lp_exact`: ``Found`` / ``Refuted``), otherwise a sound
relaxation (``Refuted`` or ``Unknown``) followed by a fixed point on re-rolled covariances. What
``guarantee="closed_loop"`` checks of a plan and its plan LP with room for the tracking correction
live in :mod:`.closed_loop_plan` (re-exported here); the mode search in :mod:`.mode_search`.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import TYPE_CHECKING

import numpy as np

from ..backends import Backend
from ..belief import rollout
from ..execution_target import ExecutionTarget
from ..semantics import robustness
from .abstraction import Abstraction
from .closed_loop_plan import (
    BACKOFF_LEVELS,
    _noisy,
    closed_loop_check,
    closed_loop_lp,
    execution_margin,
)
from .interfaces import Budget, Conflict, Found, Proposer, Refuted, Teacher, Unknown, Verdict
from .mode_search import MLOScore, ModeSearch, RoomScore, Score, lp_trial
from .plan import DiscretePlan
from .plan_lp import PlanLPContext, Scaling, covariance_schedule, lp_exact
from .plan_solve import TIGHTEN, LPGoal, LPOutcome, Phases, solve_plan_lp
from .results import SolveStats
from .room import give_room

if TYPE_CHECKING:
    from ..problem import Problem
    from .options import Objective

__all__ = [
    "LPOutcome",
    "LPTeacher",
    "BACKOFF_LEVELS",
    "TIGHTEN",
    "closed_loop_check",
    "closed_loop_lp",
    "covariance_schedule",
    "execution_margin",
    "solve_plan_lp",
]

logger = logging.getLogger(__name__)

PREFIX_STEPS = 16
"""Transitions of the first prefix on which :class:`LPTeacher` tries to refute a long plan."""

ROOM_ROUNDS = 8
"""LP rounds the plan LP's plans get toward their execution room (a work budget)."""


def _prefix_conflict(plan: DiscretePlan, out: LPOutcome, num_modes: int) -> Conflict:
    """The plan LP's conflict with the plan's modes up to its last step (several modes)."""
    last = max((k for k, _ in out.conflict), default=0)
    modes = plan.modes[: last + 1].copy() if num_modes > 1 else None
    kind = "exact" if out.exact else "lower-bound covariance"
    return Conflict(out.conflict, modes, f"Farkas certificate of the plan LP ({kind})", out.proof)


class LPTeacher(Teacher):
    """Decides candidates with the plan LP (exact without state-dependent noise).

    Parameters
    ----------
    problem : Problem
    abstraction : Abstraction
    scaling : Scaling
    backend : Backend
    rounds : int
        Fixed-point rounds on re-rolled covariances under state-dependent noise.
    objective : {None, "effort", "margin", "time"}
        The LP optimises ``effort`` and ``margin`` for each discrete plan (``time`` is the
        proposer's: shortest first).
    effort_weights : ndarray, shape (m,), optional
    closed_loop : bool
        ``guarantee="closed_loop"``: a plan is accepted when the true state predicted under the
        executor (:func:`idstlpy.closed_loop.predicted_state`) passes the monitor, and the
        fixed point freezes those predicted covariances instead of the re-rolled MLO ones.
    execution : ExecutionTarget, optional
        ``guarantee="execution"``'s target: with several modes, the mode search scores
        sequences by their plan's predicted execution (:class:`~.mode_search.RoomScore`), and
        proposed modes whose plan LP is feasible are searched too when it falls short.
    """

    name = "lp"

    def __init__(
        self,
        problem: Problem,
        abstraction: Abstraction,
        scaling: Scaling,
        backend: Backend,
        rounds: int = 3,
        objective: Objective | None = None,
        effort_weights: np.ndarray | None = None,
        closed_loop: bool = False,
        execution: ExecutionTarget | None = None,
    ) -> None:
        self.problem = problem
        self.closed_loop = closed_loop
        self.abs = abstraction
        self.scaling = scaling
        self.backend = backend
        self.rounds = rounds
        self.objective = objective if objective in ("effort", "margin") else None
        # Under closed_loop the executor must track the plan: without an objective of its own, the
        # plan LP's vertex solutions (saturated inputs flipping sign inside a region) are replaced
        # by the least-effort plan that keeps the execution margin.
        self._smooth = self.objective if self.objective is not None or not closed_loop else "effort"
        self.effort_weights = effort_weights
        self.context = PlanLPContext.of(problem, abstraction, scaling, backend)
        self._goal = LPGoal(self._smooth, effort_weights)
        self.last: LPOutcome | None = None
        # Several modes: a refuted candidate's modes are searched before the refutation is
        # returned (issue 24); the attribute lets tests compare with the bare prefix clauses.
        self.mode_search = True
        # Without an objective (whose optimum the room would move) and under the MLO guarantee,
        # a plan gets the room its execution needs (:mod:`.room`), as the sampler's plans do.
        self._room = objective is None and not closed_loop
        # Under guarantee="execution" the mode search reads the execution as well (the proposed
        # modes are searched even when their plan LP is feasible).
        self.target = execution
        self.reads_execution = (
            execution is not None and self._room and _noisy(problem.switched_system, problem.initial_state)
        )
        self._modes = ModeSearch(problem.switched_system.num_modes, abstraction)

    @property
    def _search_applies(self) -> bool:
        """Whether a refuted candidate's modes are searched (:meth:`_search_modes`).

        Only where the plan LP is exact (no state-dependent noise): elsewhere the belief-space
        sampler chooses its own modes and is handed the candidates refuted for their modes
        (``SamplerTeacher.rescue``), which was faster on the perception suite's sensor
        switching (2-4 s with the sampler at the first refutation, 4-8 s after twenty LP-refuted
        candidates).
        """
        return self.mode_search and self.exact(self.problem)

    def _with_room(
        self, actions: np.ndarray, controls: np.ndarray, stats: SolveStats, budget: Budget | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The LP plan's modes and controls after :func:`.room.give_room` (at most
        :data:`ROOM_ROUNDS` LPs); the plan may come back shorter (the requirements it meets may
        end earlier), so both are returned."""
        problem = self.problem
        traj = rollout(problem.switched_system, problem.initial_state, actions, controls)
        deadline = None if budget is None else budget.deadline
        moved = give_room(problem, self.abs, self.scaling, traj, ROOM_ROUNDS, stats, deadline)
        return np.asarray(moved.get_action(), dtype=int), np.asarray(moved.get_control(), dtype=float)

    def applies(self, problem: Problem) -> bool:
        """The LP is a sound relaxation of every problem."""
        return True

    def exact(self, problem: Problem) -> bool:
        """Exact when no mode's noise depends on the state."""
        return lp_exact(problem.switched_system)

    def guide(self, proposer: Proposer, plan: DiscretePlan) -> None:
        """Prefer, in the proposer's next searches, the labels the last LP's trajectory has."""
        out, abstraction = self.last, self.abs
        if out is None or out.means is None or out.covs is None or not abstraction.num_atoms:
            return
        K = out.means.shape[0] - 1
        truth = np.stack(
            [
                abstraction.truth(out.means[k], out.covs[k], int(plan.modes[k]) if k else -1)
                for k in range(K + 1)
            ],
            axis=1,
        )
        proposer.guide(plan, truth)

    def searches_modes(self, problem: Problem) -> bool:
        """With several modes and the plan LP exact, under ``guarantee="execution"``."""
        return self.reads_execution and problem.switched_system.num_modes > 1 and self.exact(problem)

    def below_target(self) -> None:
        """Stop searching modes (see ``context.BELOW_TARGET_MIN``) unless the search reads the
        execution: on the MLO plan LP it would map the proposer's mode sequences back to the plan
        set aside; reading the execution, it looks for the modes that hold better."""
        if not self.reads_execution:
            self.mode_search = False

    def _solve(
        self,
        plan: DiscretePlan,
        margin: float,
        budget: Budget,
        stats: SolveStats,
        covs: np.ndarray | None = None,
        control_backoff: np.ndarray | None = None,
        refute_only: bool = False,
    ) -> LPOutcome:
        """:func:`solve_plan_lp` for ``plan`` in this teacher's context, with its objective."""
        phases: Phases = "refute" if refute_only else "elastic"
        with stats.clock("time_lp"):
            out = solve_plan_lp(
                self.context,
                plan,
                margin,
                covs=covs,
                control_backoff=control_backoff,
                goal=self._goal,
                budget=budget,
                time_limit=max(budget.remaining(), 1e-3),
                phases=phases,
            )
        stats.lp_calls += 1
        return out

    def _prefix_refutation(self, plan: DiscretePlan, budget: Budget, stats: SolveStats) -> LPOutcome | None:
        """The plan LP of a prefix of ``plan`` when it is infeasible, else ``None``.

        A plan of ``K`` transitions is tried first on its first ``P`` = :data:`PREFIX_STEPS`,
        ``4 P``, ... transitions (while ``P <= K / 2``): the prefix's LP keeps only the rows of
        steps ``<= P``, a relaxation of the plan's, so its Farkas certificate refutes the plan.
        Conflicts at the frontier of reach lie in the first few steps (ReachAvoid's within 16 of
        its 101), and the whole horizon's LP costs the lazy loop that much more per candidate; a
        plan that passes every prefix costs at most two thirds of its own LP more.
        """
        K = plan.num_transitions
        P = PREFIX_STEPS
        while 2 * P <= K:
            head = DiscretePlan(plan.required[:, : P + 1], plan.modes[: P + 1], P + 1)
            out = self._solve(head, 0.0, budget, stats, refute_only=True)
            if out.status == "infeasible":
                return out
            if out.status != "feasible":
                return None
            P *= 4
        return None

    def _every_mode_refutation(
        self, plan: DiscretePlan, budget: Budget, stats: SolveStats
    ) -> LPOutcome | None:
        """The plan LP of ``plan``'s requirements over every mode sequence, when it is infeasible.

        The LP is the plan LP on the hull relaxation (:func:`~.covariance_floor.hull_system`:
        every mode's input at once) with the covariance floor over all switching sequences as
        its covariance schedule (:func:`~.covariance_floor.covariance_floor`); its Farkas
        certificate refutes the requirements whatever the modes. ``None`` when it is feasible,
        or when no such relaxation is sound for the problem (different ``A``, 0 not an input).
        """
        from .covariance_floor import covariance_floor, hull_system

        problem = self.problem
        system, init = problem.switched_system, problem.initial_state
        if "_hull" not in self.__dict__:
            hull = hull_system(system, problem.control_domain)
            scaling = Scaling(self.scaling.dx, np.tile(self.scaling.du, system.num_modes))
            self._hull: PlanLPContext | None = None
            if hull is not None:
                self._hull = PlanLPContext(
                    hull, hull.control_domain, init.mean, init.cov, self.abs, scaling, self.backend
                )
            self._floor: np.ndarray | None = None
        if self._hull is None:
            return None
        K = plan.num_transitions
        if self._floor is None or self._floor.shape[0] < K + 1:
            steps = max(K, 2 * (0 if self._floor is None else self._floor.shape[0]))
            floor = covariance_floor(system.system_modes, init.cov, steps, budget)
            if floor is None:
                self._hull = None
                return None
            self._floor = floor.covs
        flat = DiscretePlan(plan.required, np.zeros(plan.length, dtype=int), plan.length)
        with stats.clock("time_lp"):
            out = solve_plan_lp(
                self._hull,
                flat,
                covs=self._floor[: K + 1],
                budget=budget,
                time_limit=max(budget.remaining(), 1e-3),
                phases="refute",
            )
        stats.lp_calls += 1
        return out if out.status == "infeasible" else None

    def _search_modes(
        self, plan: DiscretePlan, first: LPOutcome | None, budget: Budget, stats: SolveStats
    ) -> DiscretePlan | None:
        """Modes for ``plan``'s requirements whose plan LP is feasible, or ``None``
        (:mod:`.mode_search`; under ``guarantee="execution"`` the modes whose plan is predicted
        to hold best among those).

        ``first`` is the proposed modes' whole-plan LP when already solved (its conflict guides
        the first moves).
        """

        def solve(trial: DiscretePlan) -> LPOutcome:
            return self._solve(trial, 0.0, budget, stats, refute_only=True)

        score: Score
        if self.reads_execution and self.target is not None:
            target = (self.target.belief, self.target.state)
            score = RoomScore(self.problem, self.context, solve, budget.remaining, target)
        else:
            score = MLOScore(solve)
        start = None
        if first is not None and np.isfinite(first.excess):
            start = lp_trial(plan, first)
        best = self._modes.run(plan, score, start, warm=self.reads_execution, budget=budget)
        if best is None or best.key[0] < 1:
            return None
        return DiscretePlan(plan.required, best.modes, plan.length)

    def teach(self, plan: DiscretePlan, budget: Budget, stats: SolveStats) -> Verdict:
        """Solve the plan LP for ``plan`` (see :func:`solve_plan_lp`).

        With several modes, a plan LP refuted on the proposed modes is followed by a search of
        the modes (:meth:`_search_modes`); when it finds none, the refutation of the proposed
        modes is returned (a proof) and the requirement set is set aside for every other mode
        sequence (not a proof).
        """
        problem = self.problem
        system, init = problem.switched_system, problem.initial_state
        margin = execution_margin(system, init, self.abs, plan)
        out = self._prefix_refutation(plan, budget, stats)
        whole = out is None  # the LP below is the whole plan's (not a prefix's)
        if out is None:
            out = self._solve(plan, margin, budget, stats)
        set_aside = False
        proposed: tuple[DiscretePlan, LPOutcome] | None = None  # refuted, then modes searched
        searches = system.num_modes > 1 and self._search_applies
        if out.status == "infeasible" and searches:
            proposed = (plan, out)
            every = self._every_mode_refutation(plan, budget, stats)
            if every is not None:
                self.last = out
                proof = (
                    "Farkas certificate of the plan LP over every mode sequence (every mode's input "
                    "at once, the covariance floor over all switching sequences)"
                )
                return Refuted(Conflict(every.conflict, None, proof, every.proof))
            searched = self._search_modes(plan, out if whole else None, budget, stats)
            if searched is not None:
                again = self._solve(searched, margin, budget, stats)
                if again.status != "infeasible":
                    plan, out = searched, again
            set_aside = out.status == "infeasible"
        elif out.status == "feasible" and searches and self.reads_execution:
            # Met on paper; the modes may still leave the execution no room (a look on the last
            # step): the search keeps them unless it finds modes predicted to hold better.
            searched = self._search_modes(plan, None, budget, stats)
            if searched is not None and not np.array_equal(searched.modes, plan.modes):
                again = self._solve(searched, margin, budget, stats)
                if again.feasible:
                    plan, out = searched, again
        self.last = out
        if out.status == "infeasible":
            return Refuted(_prefix_conflict(plan, out, system.num_modes), set_aside=set_aside)
        verdict = self._decide(plan, out, margin, budget, stats)
        if isinstance(verdict, Found) and searches and self.reads_execution:
            verdict = dataclasses.replace(verdict, searched=True)
        if isinstance(verdict, Unknown) and proposed is not None and self.exact(problem):
            # The searched modes met the LP but not the monitor's promise (e.g. the predicted
            # closed loop): the proposed modes' refutation stands (a proof) and the requirement
            # set is set aside, instead of the proposer offering it again with other modes (the
            # search would find the same ones). No sampler serves a problem the LP is exact for.
            return Refuted(_prefix_conflict(*proposed, system.num_modes), set_aside=True)
        return verdict

    def _decide(
        self, plan: DiscretePlan, out: LPOutcome, margin: float, budget: Budget, stats: SolveStats
    ) -> Verdict:
        """The verdict on a plan whose LP is feasible (or unknown): its controls, or why not."""
        problem = self.problem
        system, init = problem.switched_system, problem.initial_state
        if out.status == "unknown":
            return Unknown(out.why, out.means)
        actions = np.asarray(plan.modes[1 : plan.length], dtype=int)
        if out.exact and out.controls is not None and not self.closed_loop:
            controls = out.controls
            if self._room and _noisy(system, init):
                actions, controls = self._with_room(actions, controls, stats, budget)
            return Found(actions, controls, "the plan LP", exact=True)
        found = self._fixed_point(plan, actions, out, margin, budget, stats)
        if found is not None:
            return found
        if self.closed_loop:
            return Unknown(
                "the plan LP found no plan whose predicted closed loop keeps the promise", out.means
            )
        return Unknown("the plan LP is only a relaxation under state-dependent noise", out.means)

    def _fixed_point(
        self,
        plan: DiscretePlan,
        actions: np.ndarray,
        out: LPOutcome,
        margin: float,
        budget: Budget,
        stats: SolveStats,
    ) -> Found | None:
        """Re-solve the LP on the covariances its own plan really has.

        Roll the LP's controls out exactly (under ``closed_loop``: and predict the executed true
        state); if the monitor accepts, that is the plan. Otherwise freeze those covariances and
        solve again (a fixed-point iteration that settles at once when the covariances do not
        depend on the means along the plan: constant sensor noise, and no input clipping under
        ``closed_loop``).
        """
        problem = self.problem
        system, init, formula = problem.switched_system, problem.initial_state, problem.stl_formula

        def lp(backoff: np.ndarray | None, covs: np.ndarray) -> LPOutcome:
            return self._solve(plan, margin, budget, stats, covs=covs, control_backoff=backoff)

        controls = out.controls
        for _ in range(self.rounds):
            if controls is None:
                return None
            traj = rollout(system, init, actions, controls)
            if self.closed_loop:
                # Trackability is the loop's last word (cegis._certify tries one repair).
                judged, rho, ok, _ = closed_loop_check(system, traj, problem.control_domain, formula)
            else:
                judged, rho = traj, robustness(traj, formula)
                ok = rho >= 0
            logger.debug("plan LP fixed point: %d steps, margin %.3g", plan.length - 1, rho)
            if ok:
                how = (
                    "the plan LP on predicted closed-loop covariances"
                    if self.closed_loop
                    else "the plan LP on re-rolled covariances"
                )
                if self._room and _noisy(system, init):
                    # The room its execution needs, as on the exact path (issue 24: this path
                    # returned plans without it, and without a word).
                    actions, controls = self._with_room(actions, controls, stats, budget)
                return Found(actions, controls, how, exact=out.exact)

            if self.closed_loop:
                nxt = closed_loop_lp(system, traj, problem.control_domain, judged, lp)
            else:
                nxt = lp(None, judged.get_cov())
            if not nxt.feasible:
                return None
            controls = nxt.controls
        return None
