"""The belief sampler stops extending a node after MAX_FAILS extensions that took no step."""

from __future__ import annotations

import time

import numpy as np
import pytest
from benchmarks.sensing_families import recurrent

from idstlpy.synthesis.abstraction import Abstraction, PruningReport
from idstlpy.synthesis.interfaces import Budget
from idstlpy.synthesis.options import SolverOptions
from idstlpy.synthesis.plan import DiscretePlan
from idstlpy.synthesis.proposer import BMCProposer
from idstlpy.synthesis.results import SolveStats
from idstlpy.synthesis.sampler import MAX_FAILS, BeliefSampler


def _stuck_root(guarantee: str):
    """A sampler and a growth whose root cannot take a step (the plan's horizon is 0)."""
    problem, _, _ = recurrent(0.05)
    abstraction = Abstraction(problem.stl_formula, 2)
    options = SolverOptions(seed=0, guarantee=guarantee)
    report = PruningReport([], [], [], [])
    proposer = BMCProposer(problem.stl_formula, abstraction, 1, report, options, Budget(60.0), SolveStats())
    sampler = BeliefSampler(problem, abstraction, proposer, options)
    required = np.zeros((abstraction.num_atoms, 2), dtype=bool)
    plan = DiscretePlan(required, np.zeros(2, dtype=int), 2)
    g = sampler._start(plan, np.random.default_rng(0), time.perf_counter() + 60.0)
    g.horizon = 0  # every extension stops before its first step
    return sampler, g


@pytest.mark.parametrize("guarantee", ["execution", "mlo"])
def test_a_node_that_never_steps_is_dropped_after_max_fails(guarantee):
    sampler, g = _stuck_root(guarantee)
    act = np.array([0])
    for i in range(MAX_FAILS - 1):
        assert sampler._iterate(g, act) is None
        assert g.tree.active[0] and g.tree.fails[0] == i + 1  # the root stays alive meanwhile
    assert sampler._iterate(g, act) is None
    # guarantee="mlo" keeps its recorded behaviour: the root is tried again and again
    assert bool(g.tree.active[0]) == (guarantee == "mlo")
    assert g.dropped == (0 if guarantee == "mlo" else 1)
