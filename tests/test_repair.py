"""The trust-region repair loop (:mod:`idstlpy.synthesis.repair`) and its three instances.

The loop on scripted parts: it stops on its work budget, at a deadline, on ``STOP`` and when the
parts say it is stuck; it never returns a proposal its ``accept`` refused; it shrinks the trust
region after a failed round only. Then the instances on the listing: the room, the refiner and
the closed-loop repair return plans the monitor accepts.
"""

from __future__ import annotations

import time

import numpy as np
from benchmarks import perception_problems as pp

import idstlpy as stl
from idstlpy.synthesis.abstraction import Abstraction
from idstlpy.synthesis.interfaces import Budget
from idstlpy.synthesis.objectives import objective_value, refine
from idstlpy.synthesis.plan_lp import PlanLPContext, Scaling, lp_exact
from idstlpy.synthesis.repair import STOP, repair
from idstlpy.synthesis.results import SolveStats
from idstlpy.synthesis.room import give_room


class _Script:
    """Parts whose proposals are a script: ``("step", value)`` proposes ``value`` (kept when the
    "monitor" accepts it, i.e. it is not negative, and it improves on the state), ``None`` fails,
    ``"stop"`` is STOP. Records every trust region it was asked to step within."""

    name = "script"

    def __init__(self, script, stuck_after=None, done_at=None):
        self.script = list(script)
        self.trusts: list[float] = []
        self.accepted: list[float] = []
        self.stuck_after = stuck_after
        self.done_at = done_at

    def done(self, state):
        return self.done_at is not None and state >= self.done_at

    def first_trust(self, state):
        return 8.0

    def propose(self, state, trust, left):
        self.trusts.append(trust)
        item = self.script.pop(0) if self.script else None
        return STOP if item == "stop" else item

    def accept(self, state, proposal, trust):
        if proposal < 0 or proposal <= state:
            return None
        self.accepted.append(proposal)
        return proposal

    def stuck(self, state, failures):
        return self.stuck_after is not None and failures >= self.stuck_after


def test_the_loop_stops_on_its_work_budget():
    parts = _Script([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    assert repair(parts, 0.0, 4) == 4.0
    assert len(parts.trusts) == 4
    assert repair(_Script([1.0]), 0.0, 0) == 0.0


def test_the_loop_never_keeps_a_proposal_accept_refused():
    # -1: the monitor rejects it; 0.5 after 2: no improvement
    parts = _Script([2.0, -1.0, 0.5, 3.0, -5.0])
    end = repair(parts, 0.0, 5)
    assert end == 3.0 and parts.accepted == [2.0, 3.0]


def test_the_trust_region_shrinks_after_a_failed_round_only():
    parts = _Script([1.0, None, -1.0, 2.0, None])
    repair(parts, 0.0, 5, shrink=0.5)
    assert parts.trusts == [8.0, 8.0, 4.0, 2.0, 2.0]


def test_the_loop_stops_on_stop_stuck_done_and_the_deadline():
    parts = _Script([1.0, "stop", 2.0])
    assert repair(parts, 0.0, 5) == 1.0 and len(parts.trusts) == 2
    parts = _Script([None, None, 5.0], stuck_after=2)
    assert repair(parts, 0.0, 5) == 0.0 and len(parts.trusts) == 2
    parts = _Script([1.0, 2.0, 3.0], done_at=2.0)
    assert repair(parts, 0.0, 5) == 2.0 and len(parts.trusts) == 2
    parts = _Script([1.0])
    assert repair(parts, 0.0, 5, deadline=time.perf_counter() - 1.0) == 0.0 and not parts.trusts


def _listing():
    problem, (actions, controls) = pp.build("listing", "small")
    system, init = problem.switched_system, problem.initial_state
    abstraction = Abstraction(problem.stl_formula, system.n)
    scaling = Scaling.compute(system, problem.control_domain, init.mean, init.cov, abstraction)
    traj = stl.rollout(system, init, actions, controls)
    assert stl.robustness(traj, problem.stl_formula) >= 0
    return problem, abstraction, scaling, traj


def test_the_instances_return_plans_the_monitor_accepts():
    problem, abstraction, scaling, traj = _listing()
    formula = problem.stl_formula
    assert not lp_exact(problem.switched_system)
    stats = SolveStats()
    roomy = give_room(problem, abstraction, scaling, traj, 4, stats)
    assert stl.robustness(roomy, formula) >= 0 and stats.execution_room is not None
    assert 1 <= stats.lp_calls <= 4
    stats = SolveStats()
    cheap = refine(problem, abstraction, scaling, traj, "effort", None, 4, stats, lambda: 0.0)
    assert stl.robustness(cheap, formula) >= 0
    assert objective_value("effort", cheap, formula) <= objective_value("effort", traj, formula)
    # the refiner's restoration steps are LPs too, but its rounds are bounded by the budget
    assert stats.lp_calls <= 8


def test_the_closed_loop_repair_returns_a_plan_that_keeps_its_promise_or_none():
    from idstlpy.synthesis.certify import certify
    from idstlpy.synthesis.teacher import closed_loop_check

    problem, abstraction, scaling, traj = _listing()
    context = PlanLPContext.of(problem, abstraction, scaling)
    stats = SolveStats()
    out = certify(context, problem, traj, exact=False, rounds=3, stats=stats, budget=Budget(np.inf))
    if out is not None:
        _, margin, ok, _ = closed_loop_check(
            problem.switched_system, out.traj, problem.control_domain, problem.stl_formula
        )
        assert ok and margin == out.margin
    assert stats.execution_room is None
