"""The search after a plan below target (``guarantee="execution"``): plans found again.

After the first verified plan below the execution target the loop searches on for a plan that
meets it. A plan it had set aside before (the same modes and controls) is not predicted again,
and the search stops once :data:`~idstlpy.synthesis.context.BELOW_TARGET_PATIENCE` verified
plans in a row were such repeats (counted in plans: deterministic for a seed).
"""

from __future__ import annotations

import warnings

import numpy as np
from benchmarks.perception_problems import build

import idstlpy as stl
from idstlpy.belief import rollout
from idstlpy.execution_target import ExecutionTarget
from idstlpy.synthesis.context import BELOW_TARGET_PATIENCE, TargetWatch, Verified
from idstlpy.synthesis.options import SolverOptions
from idstlpy.synthesis.predicted_execution import PredictedExecution
from idstlpy.synthesis.results import SolveStats


def _line() -> stl.Problem:
    """A 1-D integrator that must reach [3, 3.9] within 20 steps."""
    x = stl.mk_variable(1, float)
    u = stl.mk_variable(1, float)
    mode = stl.mk_lbs(A=[[1.0]], B=[[1.0]], W=[[0.1]])
    goal = stl.logical_and(stl.prob(x[0] >= 3.0) >= 0.9, stl.prob(x[0] <= 3.9) >= 0.9, name="goal")
    return stl.Problem(
        switched_system=stl.mk_switched_sys([mode]),
        control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.zeros(1), cov=0.01 * np.eye(1)),
        stl_formula=stl.eventually(0, 20, goal),
    )


PROBLEM = _line()


def _plan(u: float, belief: float, state: float) -> Verified:
    """A verified plan of five steps at input ``u``, predicted at these rates."""
    traj = rollout(PROBLEM.switched_system, PROBLEM.initial_state, np.zeros(5, dtype=int), np.full((5, 1), u))
    ex = PredictedExecution(belief, state, belief, state, {}, ExecutionTarget(0.9, 0.95))
    return Verified(traj, 1.0, None, ex)


def _watch() -> TargetWatch:
    return TargetWatch(PROBLEM, SolverOptions(), SolveStats())


def test_plans_found_again_stop_the_search():
    watch = _watch()
    first = _plan(0.6, 0.5, 0.9)
    watch.set_aside(first)
    assert watch.repeats == 0 and watch.stop_reason(1) is None
    for i in range(BELOW_TARGET_PATIENCE - 1):
        watch.set_aside(_plan(0.6, 0.5, 0.9))  # the same modes and controls: found again
        assert watch.repeats == i + 1 and watch.stop_reason(2 + i) is None
    watch.set_aside(_plan(0.6, 0.5, 0.9))
    assert watch.repeats == BELOW_TARGET_PATIENCE
    reason = watch.stop_reason(BELOW_TARGET_PATIENCE + 1)
    assert reason is not None and "converged" in reason
    assert watch.stats.below_target == BELOW_TARGET_PATIENCE + 1


def test_a_new_plan_resets_the_count_even_when_it_is_worse():
    watch = _watch()
    watch.set_aside(_plan(0.6, 0.5, 0.9))
    for _ in range(BELOW_TARGET_PATIENCE - 1):
        watch.set_aside(_plan(0.6, 0.5, 0.9))
    watch.set_aside(_plan(0.7, 0.2, 0.5))  # new (other controls), worse: the search goes on
    assert watch.repeats == 0 and watch.stop_reason(BELOW_TARGET_PATIENCE + 1) is None
    assert watch.below is not None and watch.below.execution is not None
    assert watch.below.execution.belief_estimate == 0.5  # the best is kept


def test_a_plan_found_again_is_known_with_what_was_set_aside_for_it():
    watch = _watch()
    plan, repaired = _plan(0.6, 0.3, 0.8), _plan(0.55, 0.6, 0.9)
    assert watch.known(plan.traj) is None
    watch.set_aside(repaired, plan)  # the repair did better: it is what the plan stands for
    again = watch.known(_plan(0.6, 0.0, 0.0).traj)
    assert again is repaired
    assert watch.known(_plan(0.6 + 1e-12, 0.3, 0.8).traj) is None  # another plan


def test_no_stop_before_a_plan_is_set_aside():
    assert _watch().stop_reason(10**6) is None


def test_the_narrow_noisy_hold_stops_when_its_plan_comes_back():
    # The sampler's plan, given its room, comes back identical candidate after candidate: the
    # search ran to its 60 s cap (2026-11-27 morning) before it stopped on repeats.
    problem, _ = build("noisy_hold_narrow", "small")
    options = dict(rrt_timeout=60, delta_near=2, delta_drain=0.5, goal_bias=0.25, seed=0, time_limit=60)
    options.update(min_num_of_steps=3, max_num_of_steps=15)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = problem.solve_result(**options)
    assert result.status == "found" and result.meets_target is False  # flagged, never silent
    assert [w for w in caught if issubclass(w.category, stl.ExecutionTargetWarning)]
    assert f"the last {BELOW_TARGET_PATIENCE} verified plans had all been set aside before" in result.reason
    assert result.stats.candidates < 40 and "time_limit" not in result.stats.caps_hit
    # the repeats were not predicted again (each prediction of a plan set aside counts once, its
    # repair's and the closed-loop fallback's too: fewer predictions than plans set aside)
    assert result.stats.predictions < result.stats.below_target


def test_a_plan_is_accepted_on_the_estimate_its_result_reports():
    """The loop's verdict is the precise re-sampling (:meth:`TargetWatch.judge`), not the
    candidate's 1000 samples: blind_then_look's 12th candidate met the target on 1000 samples,
    was reported at 89.2% belief and came back flagged; judged on the report, the search goes on
    and returns a plan that meets it, and what the result reports is what was judged."""
    from benchmarks import defaults_problems as dp
    from benchmarks.defaults import OPTIONS

    problem = dp.build("blind_then_look")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = problem.solve_result(**OPTIONS)
    assert result.status == "found"
    assert result.meets_target
    ex = result.execution
    assert ex.samples > 1000  # the re-sampled estimate
    assert ex.belief_estimate >= 0.90 and ex.state_estimate >= 0.95
    watch = TargetWatch(problem, SolverOptions(), SolveStats())
    assert watch.judge(result.trajectory) == watch.report(result.trajectory)


def test_a_quick_estimate_near_the_target_is_judged_on_the_report():
    """A plan short of the target on its 1000 samples by less than three standard errors is
    judged on the precise report (a reviewer's counterexample: 94.6% on 1000 samples set aside,
    95.1% reported); one far below is not re-sampled."""
    from idstlpy.synthesis.context import JUDGE_STANDARD_ERRORS, PREDICT_SAMPLES

    watch = TargetWatch(_line(), SolverOptions(), SolveStats())
    target = SolverOptions().execution_target
    se = np.sqrt(target.state * (1 - target.state) / PREDICT_SAMPLES)

    def quick(state: float) -> PredictedExecution:
        return PredictedExecution(0.99, state, 0.9, 0.9, {}, target)

    assert watch._plausible(quick(target.state - 0.5 * JUDGE_STANDARD_ERRORS * se))
    assert watch._plausible(quick(target.state + 0.01))
    assert not watch._plausible(quick(target.state - 1.5 * JUDGE_STANDARD_ERRORS * se))
    assert not watch._plausible(quick(float("nan")))
