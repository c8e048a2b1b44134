"""Figures that explain themselves: legends, colorbar, modes, half-plane regions, any state, files."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import idstlpy as stl  # noqa: E402
from idstlpy.errors import DimensionError, InvalidArgumentError, InvalidTypeError  # noqa: E402
from idstlpy.plotting import (  # noqa: E402
    FIGURE_FORMATS,
    MODE_COLORS,
    TimeSeriesArtists,
    clip_halfplanes,
    plot_light_dark,
    plot_monte_carlo,
    plot_time_series,
    plot_workspace,
    save_figure,
    sensor_noise_std,
)
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system  # noqa: E402


@pytest.fixture(autouse=True)
def _close():
    yield
    plt.close("all")


@pytest.fixture(scope="module")
def ld():
    problem = light_dark(deadline=30, hold=5)
    controls = np.vstack([np.tile([1.0, 0.0], (8, 1)), np.tile([-1.0, -1.0], (6, 1))])
    plan = stl.rollout(
        problem.switched_system, problem.initial_state, np.zeros(len(controls), dtype=int), controls
    )
    xi_sim, xi_real = stl.simulate(
        problem.switched_system,
        plan,
        plan.num_of_steps,
        LIGHT_DARK_REAL_INITIAL_STATE,
        light_dark_real_system(),
        seed=0,
    )
    return problem, plan, xi_sim, xi_real


@pytest.fixture(scope="module")
def four_d():
    """A 4-D double integrator with two modes (the second observes the position) and a half-plane."""
    x = stl.mk_variable(4)
    u = stl.mk_variable(2, name="u")
    A = np.eye(4)
    A[0, 2] = A[1, 3] = 1.0
    B = np.zeros((4, 2))
    B[2, 0] = B[3, 1] = 1.0
    system = stl.mk_switched_sys(
        [
            stl.mk_lbs(A, B, 0.01 * np.eye(4)),
            stl.mk_lbs(
                A, B, 0.01 * np.eye(4), C=np.eye(2, 4), V=lambda s: (0.05 + 0.1 * s[0] ** 2) * np.eye(2)
            ),
        ]
    )
    domain = stl.logical_and(u[0] >= -0.5, u[0] <= 0.5, u[1] >= -0.5, u[1] <= 0.5).region
    half = stl.logical_and(stl.prob(x[0] + x[1] >= 3) >= 0.9, name="half_plane")
    goal = stl.logical_and(
        stl.prob(x[0] >= 4) >= 0.9,
        stl.prob(x[0] <= 5) >= 0.9,
        stl.prob(x[1] >= 1) >= 0.9,
        stl.prob(x[1] <= 2) >= 0.9,
        stl.prob(x[2] <= 1) >= 0.9,
        name="goal",
    )
    slow = stl.logical_and(stl.prob(x[2] <= 1) >= 0.9, name="slow")
    formula = stl.logical_and(
        stl.eventually(0, 20, half), stl.eventually(0, 20, goal), stl.always(0, 20, slow)
    )
    problem = stl.Problem(system, domain, stl.to_belief([0, 0, 0, 0], 0.1 * np.eye(4)), formula)
    rng = np.random.default_rng(0)
    actions = np.array([0, 0, 0, 1, 1, 1, 1, 0, 0, 1, 1, 1])
    plan = stl.rollout(system, problem.initial_state, actions, rng.uniform(-0.3, 0.5, size=(12, 2)))
    return problem, plan


def _legend_texts(legend) -> list[str]:
    return [t.get_text() for t in legend.get_texts()]


def _overlap(a, b) -> bool:
    return not (a.x1 <= b.x0 or b.x1 <= a.x0 or a.y1 <= b.y0 or b.y1 <= a.y0)


# ------------------------------------------------------------------------------------------------
# Workspace: what the marks are


def test_legend_names_the_ellipses_and_the_shading_and_the_colorbar_the_noise(ld):
    problem, plan, xi_sim, xi_real = ld
    art = plot_light_dark(problem, plan, xi_sim, xi_real)
    texts = _legend_texts(art.legend)
    assert "plan: 95% covariance ellipses" in texts
    assert "executed: 95% covariance ellipses" in texts
    assert any(t.startswith("shading: sensor noise std of mode 0") for t in texts)
    assert {
        "free_space",
        "target",
        "plan: mean",
        "executed belief: mean",
        "true state",
        "observations",
    } <= set(texts)
    label = art.colorbar.ax.get_xlabel()
    assert "sensor noise std of mode 0" in label and "brighter is less noise" in label
    # The shading is the noise std itself: 0.1 * (5 - x)^2 + 0.001 (V = s(x) I).
    img = art.light.get_array()
    x0, x1, _, _ = art.light.get_extent()
    xs = np.linspace(x0, x1, img.shape[1])
    np.testing.assert_allclose(img[0], 0.1 * (5 - xs) ** 2 + 0.001, rtol=1e-12)
    assert type(art.light.norm).__name__ == "LogNorm"


def test_legend_is_outside_the_axes_by_default_and_can_go_inside_or_away(ld):
    problem, plan, xi_sim, xi_real = ld
    art = plot_light_dark(problem, plan, xi_sim, xi_real)
    art.figure.canvas.draw()
    renderer = art.figure.canvas.get_renderer()
    assert not _overlap(art.legend.get_window_extent(renderer), art.ax.get_window_extent(renderer))
    fig, ax = plt.subplots()  # user axes: still outside (savefig with a tight box keeps it)
    art = plot_light_dark(problem, plan, ax=ax)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    assert not _overlap(art.legend.get_window_extent(renderer), ax.get_window_extent(renderer))
    inside = plot_light_dark(problem, plan, legend="best")
    inside.figure.canvas.draw()
    renderer = inside.figure.canvas.get_renderer()
    box, frame = inside.legend.get_window_extent(renderer), inside.ax.get_window_extent(renderer)
    assert frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1
    assert plot_light_dark(problem, plan, legend=False).legend is None
    with pytest.raises(InvalidArgumentError, match="legend"):
        plot_light_dark(problem, plan, legend=3)


def test_sensor_noise_std_is_the_light_dark_noise(ld):
    problem = ld[0]
    std = sensor_noise_std(problem)
    np.testing.assert_allclose(std(np.array([[5.0, 0.0], [0.0, 3.0]])), [0.001, 2.501])
    with pytest.raises(DimensionError, match="points"):
        std(np.zeros((2, 3)))


def test_modes_are_coloured_along_the_plan(four_d, ld):
    problem, plan = four_d
    art = plot_light_dark(problem, plan)
    assert art.modes is not None
    colours = art.modes.get_colors()
    expected = matplotlib.colors.to_rgba_array([MODE_COLORS[q] for q in plan.get_action()])
    np.testing.assert_allclose(colours[:, :3], expected[:, :3])
    assert len(art.modes.get_segments()) == plan.num_of_steps
    texts = _legend_texts(art.legend)
    assert "plan: mode 0 (blind)" in texts and "plan: mode 1 (senses, noise varies with the state)" in texts
    # The shading is the sensor of the mode the plan uses most (mode 1 here: 7 of 12 steps).
    assert "mode 1" in art.colorbar.ax.get_xlabel()
    # One mode: a plain blue line unless asked.
    ld_problem, ld_plan = ld[0], ld[1]
    assert plot_workspace(ld_problem, ld_plan).modes is None
    assert plot_workspace(ld_problem, ld_plan, show_modes=True).modes is not None
    assert plot_workspace(problem, plan, show_modes=False).modes is None


def test_half_plane_regions_are_clipped_to_the_view(four_d):
    problem, plan = four_d
    art = plot_workspace(problem, plan)
    assert set(art.regions) == {"half_plane", "goal"}  # slow constrains x[2] only
    (x0, x1), (y0, y1) = art.ax.get_xlim(), art.ax.get_ylim()
    verts = art.regions["half_plane"].get_xy()
    assert np.all(verts[:, 0] >= x0 - 1e-9) and np.all(verts[:, 0] <= x1 + 1e-9)
    assert np.all(verts[:, 1] >= y0 - 1e-9) and np.all(verts[:, 1] <= y1 + 1e-9)
    assert np.all(verts.sum(axis=1) >= 3 - 1e-9)  # inside the half-plane x0 + x1 >= 3
    goal = art.regions["goal"].get_xy()
    assert goal[:, 0].min() == pytest.approx(4) and goal[:, 0].max() == pytest.approx(5)
    assert goal[:, 1].min() == pytest.approx(1) and goal[:, 1].max() == pytest.approx(2)


def test_any_two_state_coordinates(four_d):
    problem, plan = four_d
    art = plot_workspace(problem, plan, dims=(2, 0))
    assert art.dims == (2, 0)
    assert art.ax.get_xlabel() == "x[2]" and art.ax.get_ylabel() == "x[0]"
    np.testing.assert_array_equal(art.plan.get_xdata(), plan.get_mean()[:, 2])
    assert set(art.regions) == {"goal", "slow"}  # the half-plane involves x[1]
    slow = art.regions["slow"].get_xy()
    assert slow[:, 0].max() == pytest.approx(1.0)  # x[2] <= 1, clipped on the other sides
    e = art.plan_ellipses[0]
    cov = plan.get_cov(0)[np.ix_([2, 0], [2, 0])]
    assert e.width * e.height == pytest.approx(4 * 5.991464547107979 * np.sqrt(np.linalg.det(cov)))
    light = plot_light_dark(problem, plan, dims=(0, 3))
    assert light.light is not None and light.ax.get_ylabel() == "x[3]"


def test_workspace_of_a_one_state_problem_points_to_the_time_series():
    x = stl.mk_variable(1)
    u = stl.mk_variable(1, name="u")
    problem = stl.Problem(
        stl.mk_switched_sys([stl.mk_lcs(np.eye(1), np.eye(1))]),
        stl.logical_and(u[0] >= -1, u[0] <= 1).region,
        stl.to_belief([0.0], [[0.0]]),
        stl.eventually(0, 5, stl.logical_and(stl.prob(x[0] >= 2) >= 0.9, name="far")),
    )
    with pytest.raises(DimensionError, match="plot_time_series"):
        plot_workspace(problem)
    plan = stl.rollout(
        problem.switched_system, problem.initial_state, np.zeros(3, dtype=int), np.ones((3, 1))
    )
    art = plot_time_series(problem, plan)
    assert isinstance(art, TimeSeriesArtists) and art.states == (0,)
    assert len(art.axes) == 3 and art.ax is art.axes[0]
    assert [line.get_ydata()[0] for line in art.bounds] == [2.0]


def test_monte_carlo_legend_counts_the_executions(ld):
    problem, plan = ld[0], ld[1]
    report = stl.validate(
        problem,
        plan,
        light_dark_real_system(),
        LIGHT_DARK_REAL_INITIAL_STATE,
        runs=3,
        seed=0,
        executor="serial",
        keep_trajectories=3,
    )
    art = plot_monte_carlo(problem, plan, report.executions, report=report)
    texts = _legend_texts(art.legend)
    assert "executed beliefs (3)" in texts and "true states (3)" in texts
    assert "plan: 95% covariance ellipses" in texts
    assert art.workspace.colorbar is not None


# ------------------------------------------------------------------------------------------------
# Clipping


def test_clip_halfplanes():
    box = clip_halfplanes(np.zeros((0, 2)), np.zeros(0), (0, 0), (2, 1))
    assert box.shape == (4, 2)
    tri = clip_halfplanes(np.array([[-1.0, -1.0]]), np.array([2.0]), (0, 0), (2, 2))  # x + y >= 2
    assert sorted(map(tuple, np.round(tri, 12))) == [(0.0, 2.0), (2.0, 0.0), (2.0, 2.0)]
    empty = clip_halfplanes(np.array([[1.0, 0.0]]), np.array([5.0]), (0, 0), (1, 1))  # x <= -5
    assert empty.shape == (0, 2)
    assert clip_halfplanes(np.array([[0.0, 0.0]]), np.array([1.0]), (0, 0), (1, 1)).shape == (0, 2)
    assert clip_halfplanes(np.array([[0.0, 0.0]]), np.array([-1.0]), (0, 0), (1, 1)).shape == (4, 2)
    line = clip_halfplanes(np.array([[1.0, 0.0], [-1.0, 0.0]]), np.array([-0.5, 0.5]), (0, 0), (1, 1))
    assert line.shape == (0, 2)  # a segment has no area to draw


# ------------------------------------------------------------------------------------------------
# Time series


def test_time_series_bands_are_mean_plus_minus_two_std(ld):
    problem, plan, xi_sim, xi_real = ld
    art = plot_time_series(problem, plan, xi_sim, xi_real)
    assert art.states == (0, 1) and len(art.axes) == 4
    assert art.controls_ax is art.axes[2] and art.modes_ax is art.axes[3]
    for i in (0, 1):
        np.testing.assert_array_equal(art.means[i].get_ydata(), plan.get_mean()[:, i])
        path = art.bands[i].get_paths()[0].vertices
        upper = plan.get_mean()[:, i] + 2 * np.sqrt(plan.get_cov()[:, i, i])
        lower = plan.get_mean()[:, i] - 2 * np.sqrt(plan.get_cov()[:, i, i])
        assert path[:, 1].max() == pytest.approx(upper.max())
        assert path[:, 1].min() == pytest.approx(lower.min())
        assert i in art.executed_means and i in art.real
    assert len(art.controls) == 4  # 2 planned + 2 executed
    np.testing.assert_array_equal(art.modes[0].get_ydata()[:-1], plan.get_action())
    texts = _legend_texts(art.legend)
    assert "plan: mean \u00b1 2 std" in texts and "free_space: bounds" in texts and "target: bounds" in texts
    assert art.axes[-1].get_xlabel() == "step k"


def test_time_series_of_any_dimension_and_a_choice_of_states(four_d):
    problem, plan = four_d
    art = plot_time_series(problem, plan)
    assert art.states == (0, 1, 2, 3) and len(art.axes) == 6
    assert len(art.mode_bands) == 4  # runs 0,0,0 | 1,1,1,1 | 0,0 | 1,1,1
    some = plot_time_series(None, plan, states=[3, 1], sigma=1.0, controls=False, modes=False)
    assert some.states == (3, 1) and len(some.axes) == 2 and some.controls_ax is None and not some.bounds
    assert some.axes[0].get_ylabel() == "x[3]"
    fig, axes = plt.subplots(2, 1)
    mine = plot_time_series(None, plan, states=[0], modes=False, axes=axes)
    assert mine.figure is fig and mine.controls_ax is axes[1]


def test_time_series_errors(ld, four_d):
    problem, plan = ld[0], ld[1]
    with pytest.raises(InvalidTypeError, match="plan"):
        plot_time_series(problem, plan.get_mean())
    with pytest.raises(DimensionError, match="states"):
        plot_time_series(problem, plan, states=[2])
    with pytest.raises(DimensionError, match="axes must hold 4 axes"):
        plot_time_series(problem, plan, axes=[plt.subplots()[1]])
    with pytest.raises(DimensionError, match="problem has n = 4"):
        plot_time_series(four_d[0], plan)
    with pytest.raises(InvalidArgumentError, match="sigma"):
        plot_time_series(problem, plan, sigma=-1)


# ------------------------------------------------------------------------------------------------
# Files


@pytest.mark.parametrize("fmt", FIGURE_FORMATS)
def test_save_figure_by_extension(ld, tmp_path, fmt):
    problem, plan, xi_sim, xi_real = ld
    art = plot_light_dark(problem, plan, xi_sim, xi_real)
    path = save_figure(art, tmp_path / f"plan.{fmt.upper() if fmt == 'pdf' else fmt}")
    head = path.read_bytes()[:200]
    magic = {"png": b"\x89PNG", "pdf": b"%PDF", "svg": b"<?xml"}[fmt]
    assert head.startswith(magic)
    if fmt == "svg":
        assert b"<svg" in path.read_bytes()[:2000]
    ts = save_figure(plot_time_series(problem, plan).figure, tmp_path / f"series.{fmt}")
    assert ts.stat().st_size > 1000


def test_save_figure_errors(ld, tmp_path):
    art = plot_workspace(ld[0])
    with pytest.raises(InvalidArgumentError, match="extension gives the format"):
        save_figure(art, tmp_path / "plan.jpg")
    with pytest.raises(InvalidArgumentError, match="does not exist"):
        save_figure(art, tmp_path / "missing" / "plan.png")
    with pytest.raises(InvalidTypeError, match="Figure"):
        save_figure("figure", tmp_path / "plan.png")
