"""Issue 34: figures that show what happened (every run on the axes, or marked where it leaves
them; ``validate --plot`` draws the validation's own runs; ``--predict`` on screen)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import idstlpy as stl  # noqa: E402
from idstlpy import load_problem, plotting  # noqa: E402
from idstlpy.batch import Job  # noqa: E402
from idstlpy.batch.jobs import replay_runs, run_job  # noqa: E402
from idstlpy.cli.example import example_text  # noqa: E402
from idstlpy.cli.files import _print_prediction  # noqa: E402
from idstlpy.plotting import RUN_WINDOW, plot_monte_carlo  # noqa: E402
from idstlpy.trajectory import RealTrajectory  # noqa: E402


@pytest.fixture(scope="module")
def reach_avoid():
    problem = load_problem(example_text("reach-avoid"), name="reach_avoid.toml").build().problem
    controls = np.vstack([np.tile([0.0, -1.0], (3, 1)), np.tile([1.0, 0.0], (10, 1))])
    plan = stl.rollout(problem.switched_system, problem.initial_state, np.zeros(13, dtype=int), controls)
    return problem, plan


def _run(plan, offset):
    """A run whose true state drifts away from the plan by ``offset`` per step."""
    states = plan.get_mean() + np.arange(plan.get_mean().shape[0])[:, None] * np.asarray(offset)
    k = states.shape[0]
    real = RealTrajectory(states, np.full((k, 0), np.nan), plan.get_action(), plan.get_control())
    return plan, real


def test_every_run_within_reach_is_on_the_axes(reach_avoid):
    problem, plan = reach_avoid
    wander = _run(plan, [0.0, 0.9])  # ends about 11 above the plan: beyond the regions' extent
    art = plot_monte_carlo(problem, plan, [_run(plan, [0.0, 0.0]), wander])
    try:
        (x0, x1), (y0, y1) = art.ax.get_xlim(), art.ax.get_ylim()
        s = wander[1].get_state()
        assert y0 <= s[:, 1].min() and y1 >= s[:, 1].max() and x0 <= s[:, 0].min() and x1 >= s[:, 0].max()
        assert art.clipped == [] and "leave the axes" not in art.title.get_text()
    finally:
        plt.close(art.figure)


def test_a_run_beyond_the_window_is_marked_where_it_leaves(reach_avoid):
    problem, plan = reach_avoid
    far = _run(plan, [50.0, 0.0])  # hundreds of spans away: drawing it would squash the task
    art = plot_monte_carlo(problem, plan, [_run(plan, [0.0, 0.0]), far, _run(plan, [0.0, -60.0])])
    try:
        x0, x1 = art.ax.get_xlim()
        assert len(art.clipped) == 2
        assert "2 true-state runs leave the axes" in art.title.get_text()
        assert any("leaves the axes (2 runs)" == t.get_text() for t in art.legend.get_texts())
        mark = art.clipped[0]
        assert mark.get_xdata()[0] == pytest.approx(x1)  # on the right border, where it leaves
        assert x1 - x0 <= (2 * RUN_WINDOW + 2) * 10  # the axes stay near the task (regions span ~8)
    finally:
        plt.close(art.figure)


def test_validate_plot_draws_the_runs_the_validation_made(tmp_path):
    """The runs made again for the figure are the record's: same rates when all are redrawn."""
    overrides = {"solver.rrt_timeout": 5, "validation.runs": 12}
    spec = load_problem(example_text("reach-avoid"), name="reach_avoid.toml")
    record = run_job(Job("validate", spec.source, spec.name, overrides, 3))
    assert record["status"] == "found", record.get("error")
    from idstlpy.problem_file import apply_overrides

    problem, plan, report = replay_runs(apply_overrides(spec, overrides), record, 50)
    v = record["validation"]
    assert report.runs == 12 and len(report.executions) == 12
    assert report.belief_success_rate == v["belief_success_rate"]
    assert report.state_success_rate == v["state_success_rate"]
    assert report.as_dict()["state_margin"] == v["state_margin"]


def test_predict_comparison_is_printed(capsys):
    entry = {"predicted": 0.95, "measured": 0.9, "ci": [0.85, 0.93], "outside": True}
    ok = {"predicted": 0.02, "measured": 0.03, "ci": [0.01, 0.06], "outside": False}
    _print_prediction(
        {
            "success": {"belief": entry, "state": ok},
            "propositions": {"goal": {"belief": ok, "state": entry}},
            "outside": 2,
            "compared": 4,
            "max_abs_diff": 0.05,
        }
    )
    out = capsys.readouterr().out
    assert "success: belief 95.0% ! vs 90.0% [85.0%, 93.0%]; true state 2.0% vs 3.0%" in out
    assert "goal violated: belief 2.0% vs 3.0% [1.0%, 6.0%]; true state 95.0% !" in out
    assert "2 of 4 predicted rates outside the measured interval" in out
    _print_prediction(None)  # no prediction: nothing
    assert capsys.readouterr().out == ""


# -- time series: names that do not overlap, temporal windows marked ------------------------------


def _nested_problem():
    """One state, two boxes with the same centre (their names would sit on each other)."""
    x = stl.mk_variable(1, name="x")
    u = stl.mk_variable(1, name="u")
    mode = stl.mk_lbs(A=np.eye(1), B=np.eye(1), W=0.01 * np.eye(1), C=np.eye(1), V=0.1 * np.eye(1))
    outer = stl.logical_and(stl.prob(x[0] >= -2.0) >= 0.9, stl.prob(x[0] <= 2.0) >= 0.9, name="outer")
    inner = stl.logical_and(stl.prob(x[0] >= -0.3) >= 0.9, stl.prob(x[0] <= 0.3) >= 0.9, name="inner")
    formula = stl.until(outer, 0, 12, stl.always(0, 5, inner))
    problem = stl.Problem(
        stl.mk_switched_sys([mode]),
        stl.logical_and(u[0] >= -1, u[0] <= 1).region,
        stl.to_belief(np.zeros(1), 0.01 * np.eye(1)),
        formula,
    )
    plan = stl.rollout(
        problem.switched_system, problem.initial_state, np.zeros(12, dtype=int), np.zeros((12, 1))
    )
    return problem, plan


def test_temporal_windows_are_the_steps_each_operator_looks_at():
    problem, _ = _nested_problem()
    assert plotting.temporal_windows(problem.stl_formula) == [
        ("outer U[0,12] (inner ...)", 0, 12),
        ("G[0,5] inner", 0, 17),
    ]
    x = stl.mk_variable(1, name="x")
    goal = stl.logical_and(stl.prob(x[0] >= 1.0) >= 0.9, name="goal")
    nested = stl.eventually(2, 6, stl.always(1, 3, goal))
    assert plotting.temporal_windows(nested) == [("F[2,6] (goal ...)", 2, 6), ("G[1,3] goal", 3, 9)]


def test_time_series_names_do_not_overlap_and_windows_are_drawn():
    problem, plan = _nested_problem()
    art = plotting.plot_time_series(problem, plan)
    try:
        art.figure.canvas.draw()
        renderer = art.figure.canvas.get_renderer()
        boxes = {k: t.get_window_extent(renderer) for k, t in art.region_labels.items()}
        assert set(boxes) == {"outer", "inner"}
        assert not boxes["outer"].overlaps(boxes["inner"])
        # neither name covers the plan's mean (it stays at 0, the centre of both boxes)
        ax = art.axes[0]
        pts = ax.transData.transform(np.column_stack([np.arange(13), plan.get_mean()[:, 0]]))
        for box in boxes.values():
            assert not any(box.contains(px, py) for px, py in pts)
        texts = [t.get_text() for t in ax.texts]
        assert "G[0,5] inner: steps 0..17" in texts and "outer U[0,12] (inner ...): steps 0..12" in texts
        assert art.windows == plotting.temporal_windows(problem.stl_formula)
    finally:
        plt.close(art.figure)


# -- a disjunction is reported as the disjunction -----------------------------------------------


def test_a_run_that_changes_operand_breaks_the_operand_not_the_disjunction():
    from idstlpy.execution.monitor import (
        batch_monitor,
        disjunction_violations,
        disjunctions,
        promises,
        propositions,
        violations,
    )

    x = stl.mk_variable(1, name="x")
    left = stl.logical_and(stl.prob(x[0] <= 0.0) >= 0.9, name="left")
    right = stl.logical_and(stl.prob(x[0] >= 1.0) >= 0.9, name="right")
    formula = stl.always(0, 3, stl.logical_or(left, right))
    assert disjunctions(formula) == [("left | right", [0, 1])]
    assert [ap.name for ap in propositions(formula)] == ["left", "right"]

    def traj(xs):
        xs = np.asarray(xs, dtype=float)[:, None]
        return stl.ProbabilisticTSTrajectory(
            xs, np.zeros((xs.shape[0], 1, 1)), np.zeros(3, int), np.zeros((3, 1))
        )

    plan = traj([-1.0, -1.0, 2.0, 2.0])
    promised = promises(formula, plan, 4)
    switched = traj([-1.0, 2.0, 2.0, 2.0])  # leaves `left` early for `right`: the formula holds
    broken = traj([-1.0, 0.5, 2.0, 2.0])  # between the two at step 1: the formula fails
    assert violations(formula, switched, promised)[0] == [True, False]
    assert disjunction_violations(formula, switched, promised) == [False]
    assert disjunction_violations(formula, broken, promised) == [True]
    means = np.stack([switched.get_mean(), broken.get_mean()], axis=1)  # (L, S, n)
    batch = batch_monitor(formula, promised, means, None, np.zeros(3, int))
    assert batch["ors"].tolist() == [[False], [True]]
    assert batch["props"].tolist() == [[True, False], [True, False]]
