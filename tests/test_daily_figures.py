"""Figures that show the task (issue 26): filled, named regions; obstacles of disjunctions; sensing
steps; shading only where the noise varies; start and end; 1-D executions; captions."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import idstlpy as stl  # noqa: E402
from idstlpy import load_problem  # noqa: E402
from idstlpy.cli.example import example_text  # noqa: E402
from idstlpy.cli.figures import save_plan_figure  # noqa: E402
from idstlpy.plotting import plot_light_dark, plot_monte_carlo, plot_time_series, plot_workspace  # noqa: E402

LOOK_DRIVE = """
name = "look-drive"
formula = "(F[0,30] target & G[0,30] (left | below))"

[[modes]]                    # q = 0: look: stand still, sense the position
A = [[1.0, 0.0], [0.0, 1.0]]
B = [[0.0, 0.0], [0.0, 0.0]]
W = [[0.05, 0.0], [0.0, 0.05]]
C = [[1.0, 0.0], [0.0, 1.0]]
V = [[0.1, 0.0], [0.0, 0.1]]

[[modes]]                    # q = 1: drive blind
A = [[1.0, 0.0], [0.0, 1.0]]
B = [[0.5, 0.0], [0.0, 0.5]]
W = [[0.05, 0.0], [0.0, 0.05]]

[control_domain]
low = [-1.0, -1.0]
high = [1.0, 1.0]

[initial_belief]
mean = [0.0, 0.0]
cov = [1.0, 1.0]

[propositions.target]
confidence = 0.95
constraints = ["3.5 <= x[0] <= 4.5", "-0.5 <= x[1] <= 0.5"]

[propositions.left]
confidence = 0.9
constraints = ["x[0] <= 2"]

[propositions.below]
confidence = 0.9
constraints = ["x[1] <= 1"]
"""

ONE_D = """
name = "one-d"
formula = "(F[0,30] G[0,5] goal & G[0,36] lane)"

[[modes]]
A = [[1.0]]
B = [[0.3]]
W = [[0.05]]
C = [[1.0]]
V = { scale = "0.05 + 0.1*(x[0] - 5)**2", matrix = [[1.0]] }

[control_domain]
low = [-1.0]
high = [1.0]

[initial_belief]
mean = [0.0]
cov = [0.2]

[propositions.goal]
confidence = 0.9
constraints = ["3.5 <= x[0] <= 4.5"]

[propositions.lane]
confidence = 0.9
constraints = ["-1 <= x[0] <= 6"]
"""


@pytest.fixture(autouse=True)
def _close():
    yield
    plt.close("all")


def _rings(patch) -> tuple[np.ndarray, np.ndarray]:
    """The two closed rings of a compound path (the view, then its hole)."""
    path = patch.get_path()
    starts = np.flatnonzero(path.codes == path.MOVETO)
    rings = [path.vertices[a : a + 4] for a in starts]
    assert len(rings) == 2
    return rings[0], rings[1]


def _span(patch) -> tuple[float, float]:
    """The (bottom, top) of an ``axhspan`` (a Rectangle, or a Polygon in older matplotlib)."""
    if hasattr(patch, "get_height"):
        return patch.get_y(), patch.get_y() + patch.get_height()
    ys = np.asarray(patch.get_xy())[:, 1]
    return float(ys.min()), float(ys.max())


def _signed_area(v: np.ndarray) -> float:
    return float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]) / 2)


def _texts(legend) -> list[str]:
    return [t.get_text() for t in legend.get_texts()]


@pytest.fixture(scope="module")
def reach_avoid():
    problem = load_problem(example_text("reach-avoid"), name="reach_avoid.toml").build().problem
    controls = np.vstack(
        [np.tile([0.0, -1.0], (3, 1)), np.tile([1.0, 0.0], (10, 1)), np.tile([0.0, 1.0], (2, 1))]
    )
    plan = stl.rollout(problem.switched_system, problem.initial_state, np.zeros(15, dtype=int), controls)
    return problem, plan


@pytest.fixture(scope="module")
def look_drive():
    problem = load_problem(LOOK_DRIVE, name="look_drive.toml").build().problem
    actions = np.array([1, 0, 0, 0, 1, 1, 1, 0, 1, 1])
    controls = np.tile([0.5, -0.5], (10, 1))
    plan = stl.rollout(problem.switched_system, problem.initial_state, actions, controls)
    return problem, plan


# -- regions --------------------------------------------------------------------------------------


def test_obstacle_of_a_disjunction_is_filled_hatched_and_named(reach_avoid):
    problem, plan = reach_avoid
    art = plot_workspace(problem, plan)
    group = "left | right | below | above"
    assert set(art.region_groups) == {group}
    union = art.region_groups[group]
    assert union.get_fill() and union.get_facecolor()[3] > 0
    for name in ("left", "right", "below", "above"):
        assert art.regions[name] is union
    obstacle = art.obstacles[group]
    verts = obstacle.get_xy()
    assert verts[:, 0].min() == pytest.approx(2) and verts[:, 0].max() == pytest.approx(3)
    assert verts[:, 1].min() == pytest.approx(-1) and verts[:, 1].max() == pytest.approx(3)
    assert obstacle.get_hatch() and obstacle.get_fill()
    # the obstacle is a hole of the union: the view counter-clockwise, the obstacle clockwise
    outer, inner = _rings(union)
    assert _signed_area(outer) > 0 > _signed_area(inner)
    np.testing.assert_allclose(sorted(map(tuple, inner)), sorted(map(tuple, verts[:4])))
    # every proposition is filled and labelled with its name, inside the view
    for name in ("arena", "goal"):
        assert art.regions[name].get_fill() and art.regions[name].get_facecolor()[3] > 0
    assert set(art.region_labels) == {"arena", "goal", "left", "right", "below", "above"}
    (x0, x1), (y0, y1) = art.ax.get_xlim(), art.ax.get_ylim()
    for name, text in art.region_labels.items():
        assert text.get_text() == name
        x, y = text.get_position()
        assert x0 <= x <= x1 and y0 <= y <= y1
    # the label of the arena is not written on the obstacle
    assert not obstacle.get_path().contains_point(art.region_labels["arena"].get_position())
    texts = _texts(art.legend)
    assert f"obstacle: not ({group})" in texts
    assert not any(t.startswith("ap") for t in texts)


def test_unnamed_propositions_are_labelled_by_their_constraints():
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    left = stl.logical_and(stl.prob(x[0] <= 2) >= 0.95)
    right = stl.logical_and(stl.prob(x[0] >= 3) >= 0.95)
    goal = stl.logical_and(
        stl.prob(x[0] >= 4) >= 0.9,
        stl.prob(x[0] <= 5) >= 0.9,
        stl.prob(x[1] >= -1) >= 0.9,
        stl.prob(x[1] <= 1) >= 0.9,
    )
    formula = stl.logical_and(stl.always(0, 10, stl.logical_or(left, right)), stl.eventually(0, 10, goal))
    problem = stl.Problem(
        stl.mk_switched_sys([stl.mk_lcs(np.eye(2), np.eye(2))]),
        stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region,
        stl.to_belief([0.0, 0.0], 0.01 * np.eye(2)),
        formula,
    )
    art = plot_workspace(problem)
    assert "x[0] <= 2 | x[0] >= 3" in art.region_groups
    assert {"x[0] <= 2", "x[0] >= 3"} <= set(art.region_labels)
    assert any(name.startswith("x[0] >= 4 & x[0] <= 5") for name in art.regions)
    assert not any(name.startswith("ap") for name in art.regions)


# -- modes, sensing, start and end ------------------------------------------------------------------


def test_sensing_steps_of_a_mode_that_stands_still_are_marked(look_drive):
    problem, plan = look_drive
    art = plot_light_dark(problem, plan)
    sensing = int(np.sum(plan.get_action() == 0))
    assert art.sensing is not None and len(art.sensing.get_offsets()) == sensing == 4
    np.testing.assert_allclose(art.sensing.get_offsets()[0], plan.get_mean()[2])  # after step 1
    texts = _texts(art.legend)
    assert "plan: mode 0 (senses, noise std 0.1, stands still: B = 0)" in texts
    assert "plan: mode 1 (blind)" in texts
    assert any(t.startswith("sensing step (4 of 10)") for t in texts)
    assert [a.get_text() for a in art.still] == ["3 steps in place (k = 1..4)"]


def test_start_and_end_are_marked(look_drive, reach_avoid):
    for problem, plan in (look_drive, reach_avoid):
        art = plot_workspace(problem, plan)
        np.testing.assert_allclose(
            [art.start.get_xdata()[0], art.start.get_ydata()[0]], problem.initial_state.mean
        )
        np.testing.assert_allclose([art.end.get_xdata()[0], art.end.get_ydata()[0]], plan.get_mean()[-1])
        texts = _texts(art.legend)
        assert "start (initial mean)" in texts and "end of plan" in texts
    empty = plot_workspace(reach_avoid[0])
    assert empty.start is not None and empty.end is None


# -- shading --------------------------------------------------------------------------------------


def test_constant_noise_is_not_shaded_and_has_no_colorbar(look_drive):
    problem, plan = look_drive
    art = plot_light_dark(problem, plan)
    assert art.light is None and art.colorbar is None
    assert art.light_constant == pytest.approx(0.1)
    assert len(art.ax.images) == 0 and len(art.figure.axes) == 1
    assert any("0.1 everywhere (constant: not shaded)" in t for t in _texts(art.legend))
    assert "No shading: sensor noise std of mode 0 is 0.1 everywhere" in art.caption.get_text().replace(
        "\n", " "
    )


def test_varying_noise_is_shaded_with_a_colorbar_and_a_caption():
    from idstlpy.scenarios import light_dark

    problem = light_dark(deadline=30, hold=5)
    controls = np.tile([1.0, -0.5], (6, 1))
    plan = stl.rollout(problem.switched_system, problem.initial_state, np.zeros(6, dtype=int), controls)
    art = plot_light_dark(problem, plan)
    assert art.light is not None and art.colorbar is not None and art.light_constant is None
    caption = art.caption.get_text().replace("\n", " ")
    assert "Ellipses: 95% confidence regions of the belief" in caption
    assert "Shading: sensor noise std of mode 0" in caption
    assert "Filled regions" in caption


# -- 1-D ------------------------------------------------------------------------------------------


def test_one_state_executions_are_overlaid_on_the_time_series():
    spec = load_problem(ONE_D, name="one_d.toml")
    problem, _, execution = spec.build()
    plan = stl.rollout(
        problem.switched_system, problem.initial_state, np.zeros(20, dtype=int), np.full((20, 1), 0.6)
    )
    report = stl.validate(
        problem,
        plan,
        execution.real_system,
        execution.real_initial_state,
        runs=5,
        seed=0,
        executor="serial",
        keep_trajectories=5,
    )
    art = plot_monte_carlo(problem, plan, report.executions, report=report)
    assert art.workspace is None and art.time_series is not None
    assert len(art.executed) == 5 and len(art.real) == 5
    assert "5 runs" in art.title.get_text()
    ts = art.time_series
    assert set(ts.regions) == {"goal", "lane"}
    texts = _texts(ts.legend)
    assert "executed beliefs (5)" in texts and "true states (5)" in texts
    assert "start (initial mean)" in texts and "end of plan" in texts
    assert ts.end[0].get_xdata()[0] == plan.num_of_steps
    assert "Thin lines: 5 executions" in ts.caption.get_text().replace("\n", " ")
    assert [t.get_text() for t in ts.modes_ax.get_yticklabels()] == [
        "0 (senses, noise varies with the state)"
    ]
    # on one given axes: the state alone
    fig, ax = plt.subplots()
    single = plot_monte_carlo(problem, plan, report.executions[:2], ax=ax)
    assert single.ax is ax and len(single.executed) == 2
    with pytest.raises(stl.InvalidArgumentError, match="executions"):
        plot_time_series(problem, plan, executions=[report.executions[0][0]])


def test_figures_of_the_command_line_show_the_task(tmp_path, reach_avoid, look_drive):
    for (problem, plan), name in ((reach_avoid, "ra"), (look_drive, "ld")):
        out = save_plan_figure(problem, plan, tmp_path / f"{name}.png", "title")
        assert out.stat().st_size > 10_000


def test_time_series_fills_the_intervals_of_box_shaped_propositions(look_drive):
    problem, plan = look_drive
    art = plot_time_series(problem, plan)
    assert set(art.regions) == {"target", "target (x[1])", "left", "below"}
    assert _span(art.regions["target"]) == pytest.approx((3.5, 4.5))
    assert _span(art.regions["target (x[1])"]) == pytest.approx((-0.5, 0.5))
    assert _span(art.regions["below"]) == pytest.approx((art.axes[1].get_ylim()[0], 1.0))
    assert [t.get_text() for t in art.modes_ax.get_yticklabels()] == [
        "0 (senses, noise std 0.1, stands still: B = 0)",
        "1 (blind)",
    ]


def test_mode_legend_tells_precise_from_poor_sensors_and_drift_from_standing_still():
    from idstlpy.plotting import _mode_text

    x = stl.mk_variable(1, float)
    u = stl.mk_variable(1, float)
    heater = stl.mk_lbs(A=[[1.0]], B=[[0.5]], W=[[0.01]], C=[[1.0]], V=[[0.5]])
    off = stl.mk_lbs(A=[[0.95]], B=[[0.0]], W=[[0.01]], C=[[1.0]], V=[[0.05]])
    lit = stl.mk_lbs(A=[[1.0]], B=[[1.0]], W=[[0.0]], C=[[1.0]], V=lambda s: np.array([[0.1 + s[0] ** 2]]))
    problem = stl.Problem(
        switched_system=stl.mk_switched_sys([heater, off, lit]),
        control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.zeros(1), cov=np.eye(1)),
        stl_formula=stl.eventually(0, 3, stl.logical_and(stl.prob(x[0] >= 0.0) >= 0.9, name="g")),
    )
    assert _mode_text(problem, 0) == "senses, noise std 0.5"
    assert _mode_text(problem, 1) == "senses, noise std 0.05, no input: B = 0"
    assert _mode_text(problem, 2) == "senses, noise varies with the state"


def test_workspace_has_equal_units_unless_it_is_a_corridor(look_drive):
    problem, plan = look_drive
    art = plot_workspace(problem, plan)
    assert art.ax.get_aspect() == 1.0
