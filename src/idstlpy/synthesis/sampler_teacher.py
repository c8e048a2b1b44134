"""The belief-space sampler as the synthesis loop's teacher under state-dependent noise.

Each candidate gets its own random stream (spawned from the solve's seed) and the sampler's work
budget; a plan found is shortened (:func:`.shortcut.shortcut`) and given room (:mod:`.room`).
The sampler never refutes a candidate; it also *rescues* candidates the plan LP refuted for their
mode sequence only (it chooses its own modes).
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

import numpy as np

from ..belief import rollout
from .abstraction import Abstraction
from .interfaces import Budget, Found, Proposer, Refuted, Teacher, Unknown, Verdict
from .options import DEFAULT_RRT_TIMEOUT, SolverOptions
from .plan import DiscretePlan
from .plan_lp import Scaling, lp_exact
from .results import SolveStats
from .room import give_room
from .sampler import BeliefSampler
from .shortcut import shortcut

if TYPE_CHECKING:
    from ..problem import Problem

__all__ = ["SamplerTeacher"]

logger = logging.getLogger(__name__)


class SamplerTeacher(Teacher):
    """Decides candidates under state-dependent noise by sampling belief space (never refutes).

    Parameters
    ----------
    problem : Problem
    abstraction : Abstraction
    proposer : Proposer
        Used to re-time a branch whose realised prefix breaks the candidate.
    options : SolverOptions
    scaling : Scaling
        Units for the polish LP.
    seeds : numpy.random.SeedSequence
        Parent of every candidate's random stream (one child spawned per candidate).
    """

    name = "sampler"

    def __init__(
        self,
        problem: Problem,
        abstraction: Abstraction,
        proposer: Proposer,
        options: SolverOptions,
        scaling: Scaling,
        seeds: np.random.SeedSequence,
    ) -> None:
        self.problem = problem
        self.abs = abstraction
        self.options = options.sampler
        self.scaling = scaling
        self.seeds = seeds
        self.sampler = BeliefSampler(problem, abstraction, proposer, options)

    def applies(self, problem: Problem) -> bool:
        """Only problems the plan LP is not exact for (:func:`~.plan_lp.lp_exact`) need sampling."""
        return not lp_exact(problem.switched_system)

    def exact(self, problem: Problem) -> bool:
        """Sampling never proves a candidate impossible."""
        return False

    def teach(self, plan: DiscretePlan, budget: Budget, stats: SolveStats) -> Verdict:
        """Search belief space for ``plan`` within its work budget; shortcut and polish a find."""
        rng = np.random.default_rng(self.seeds.spawn(1)[0])
        # Under the default rrt_timeout the work budget alone ends a candidate's search (the
        # solve's overall cap stays): a loaded machine runs a long horizon's 15,000 iterations in
        # more than 60 s, and the clock would decide the plan. A value the user gave is a cap.
        per_candidate = (
            self.options.rrt_timeout if self.options.rrt_timeout != DEFAULT_RRT_TIMEOUT else np.inf
        )
        cap = min(budget.deadline, time.perf_counter() + per_candidate)
        budget_iters = self.options.iterations
        with stats.clock("time_sampling"):
            out = self.sampler.run(plan, budget_iters, rng, cap)
        stats.nodes += out.nodes
        stats.sampler_iterations += out.iterations
        if out.capped and not budget.expired() and "rrt_timeout" not in stats.caps_hit:
            stats.caps_hit.append("rrt_timeout")
        if out.actions is None or out.controls is None:
            why = (
                f"sampler: rrt_timeout ({self.options.rrt_timeout:g} s) reached after "
                f"{out.iterations} iterations"
                if out.capped
                else f"sampler: no plan within its budget of {budget_iters} iterations"
            )
            return Unknown(why, closest=out.closest, budgeted=True)
        with stats.clock("time_sampling"):
            actions, controls = shortcut(
                self.problem,
                self.abs,
                self.sampler.steering,
                out.actions,
                out.controls,
                self.options.shortcut_checks,
            )
        with stats.clock("time_lp"):
            actions, controls = self._polish(actions, controls, stats, budget.deadline)
        return Found(actions, controls, "the belief-space sampler")

    def rescue(self, plan: DiscretePlan, refuted: Refuted, budget: Budget, stats: SolveStats) -> Verdict:
        """Search belief space for a candidate the LP refuted for its mode sequence only.

        With several modes an LP conflict names the modes of the candidate, so the proposer
        would enumerate mode sequences one by one (``2^k`` of them for ``k`` steps); the sampler
        chooses its own modes, so it gets the candidate's requirements on the 1st, 2nd, 4th,
        8th, ... such refutation (a deterministic schedule). Returns ``refuted`` unchanged
        unless the sampler finds a plan (which the loop's monitor then checks).
        """
        conflict = refuted.conflict
        if conflict.modes is None or self.problem.switched_system.num_modes < 2:
            return refuted
        self._mode_refutations = getattr(self, "_mode_refutations", 0) + 1
        n = self._mode_refutations
        if n & (n - 1):
            return refuted
        logger.info("sampler: rescuing candidate refuted for its modes only (%d such refutations)", n)
        verdict = self.teach(plan, budget, stats)
        return verdict if isinstance(verdict, Found) else refuted

    def _polish(
        self, actions: np.ndarray, controls: np.ndarray, stats: SolveStats, deadline: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Give a sampled plan the room its execution needs, keeping its modes.

        The sampler stops at the first belief that meets the plan, often a hair inside a
        required region and with inputs on their bounds, and such a plan breaks under execution
        noise. Each round takes the requirements the trajectory meets (its witness), predicts the
        closed loop around it (:func:`.room.execution_room`: per required face and step, the
        room the executed belief and the true state need; per input face, the room the tracking
        correction needs), and solves one step of sequential convex programming toward that
        room (:func:`.room.room_lp`, means within ``trust``); the re-rolled plan is kept only if
        the monitor still accepts it and its room improved (:meth:`.room.Room.better_than`);
        ``trust`` halves after a round that did not help. It stops when the room is complete
        (:attr:`.room.Room.complete`), or after a failed round once every required face has its
        room. The rounds are a work budget (``2 * max(polish_rounds, 4)``); no round starts after
        ``deadline`` (the solve's time limit).
        """
        problem = self.problem
        traj = rollout(problem.switched_system, problem.initial_state, actions, controls)
        rounds = 2 * max(self.options.polish_rounds, 4) if self.options.polish_rounds else 0
        traj = give_room(problem, self.abs, self.scaling, traj, rounds, stats, deadline)
        return traj.get_action(), traj.get_control()
