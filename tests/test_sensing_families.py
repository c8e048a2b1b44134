"""The sensing families' witnesses (issue 24): they hold on paper and when executed; lazy plans fail.

Every feasible instance of :mod:`benchmarks.sensing_families` comes with a hand-made witness and
a lazy plan (the task without its looks). Checked here, independently of the solver:

- the witness satisfies the formula under the paper's MLO semantics by the oracles
  (``tests/oracles/rollout.py`` roll-out, ``tests/oracles/brute_force.py`` monitor), the lazy
  plan does not;
- the witness's predicted execution (true start drawn from the prior) meets the default
  execution target (90% belief / 95% true state), and so does a small Monte Carlo of it
  (``stl.validate`` from prior-drawn starts). With few samples an estimate is compared with the
  target through its Wilson 95% interval: it fails only when the interval lies wholly below the
  target. The module docstring records the 1000-sample / 1000-run numbers.
"""

from __future__ import annotations

import numpy as np
import pytest
from benchmarks import sensing_families as sf

import idstlpy as stl
from idstlpy.execution.validation import wilson_interval

BELIEF, STATE = stl.ExecutionTarget().belief, stl.ExecutionTarget().state  # the default: 90% / 95%
SAMPLES = 300

FEASIBLE = [i for i in sf.instances() if i.expected == "feasible"]
IDS = [f"{i.family}/{i.name}" for i in FEASIBLE]


def _not_below(rate: float, trials: int, target: float) -> bool:
    """``rate`` of ``trials`` is not significantly below ``target`` (its Wilson interval reaches it)."""
    return wilson_interval(round(rate * trials), trials)[1] >= target


@pytest.fixture(scope="module", params=FEASIBLE, ids=IDS)
def built(request):
    inst = request.param
    return inst, inst.build()


def test_every_family_has_several_instances():
    for family in sf.FAMILIES:
        assert sum(i.family == family for i in sf.instances()) >= 3, family


def test_witness_passes_the_oracles_and_the_lazy_plan_fails_them(built):
    inst, (problem, witness, lazy) = built
    assert sf.check_plan(problem, witness), f"{inst.name}: the witness fails the oracles"
    assert not sf.check_plan(problem, lazy), f"{inst.name}: the lazy plan passes the oracles"
    # the lazy plan skips the sensing the witness does
    if len(problem.switched_system.system_modes) > 1:
        assert np.sum(lazy[0] == 1) < np.sum(witness[0] == 1)


def test_witness_executes_at_the_target(built):
    inst, (problem, witness, _) = built
    pb, ps = sf.predicted_rates(problem, witness, samples=SAMPLES, seed=0)
    assert _not_below(pb, SAMPLES, BELIEF), f"{inst.name}: predicted belief {pb:.3f}"
    assert _not_below(ps, SAMPLES, STATE), f"{inst.name}: predicted true state {ps:.3f}"
    mb, ms = sf.measured_rates(problem, witness, runs=SAMPLES, seed=0)
    assert _not_below(mb, SAMPLES, BELIEF), f"{inst.name}: measured belief {mb:.3f}"
    assert _not_below(ms, SAMPLES, STATE), f"{inst.name}: measured true state {ms:.3f}"


def test_infeasible_instances_have_no_witness():
    for inst in sf.instances():
        if inst.expected == "infeasible":
            _, witness, lazy = inst.build()
            assert witness is None and lazy is None


def test_three_robots_are_six_states_six_inputs_one_light():
    problem, witness, _ = sf.three_robots(10)
    system = problem.switched_system
    assert (system.n, system.m, len(system.system_modes)) == (6, 6, 1)
    mode = system.system_modes[0]
    assert callable(mode.V)  # state-dependent sensing (the light)
    # each robot's noise depends on its own position only: robot 1 at the light, the others far
    x = np.array([0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    diag = np.diag(np.asarray(mode.V(x)))
    assert diag[2] == diag[3] < diag[0] == diag[4]
    assert witness[1].shape[1] == 6
