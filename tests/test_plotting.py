"""Figures: the artists exist (no pixel comparisons)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import idstlpy as stl  # noqa: E402
from idstlpy.errors import DimensionError, InvalidArgumentError, InvalidTypeError  # noqa: E402
from idstlpy.execution import validate  # noqa: E402
from idstlpy.plotting import (  # noqa: E402
    MonteCarloArtists,
    WorkspaceArtists,
    plot_light_dark,
    plot_monte_carlo,
    plot_workspace,
    sensor_light,
)
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system  # noqa: E402


@pytest.fixture(scope="module")
def case():
    problem = light_dark(deadline=30, hold=5)
    controls = np.vstack([np.tile([1.0, 0.0], (8, 1)), np.tile([-1.0, -1.0], (6, 1))])
    plan = stl.rollout(
        problem.switched_system, problem.initial_state, np.zeros(len(controls), dtype=int), controls
    )
    xi_sim, xi_real = problem.switched_system.simulate(
        plan, plan.num_of_steps, LIGHT_DARK_REAL_INITIAL_STATE, light_dark_real_system(), seed=0
    )
    yield problem, plan, xi_sim, xi_real
    plt.close("all")


def test_plot_light_dark_draws_everything(case):
    problem, plan, xi_sim, xi_real = case
    fig, ax = plt.subplots()
    art = plot_light_dark(problem, plan, xi_sim, xi_real, ax=ax, ellipse_every=3)
    assert isinstance(art, WorkspaceArtists)
    assert art.ax is ax and art.figure is fig
    assert art.light is not None and art.light in ax.images
    assert set(art.regions) == {"free_space", "target"}
    target = art.regions["target"].get_xy()
    assert np.allclose(np.abs(target), 0.25)  # the target box's corners
    assert art.plan is not None and len(art.plan.get_xdata()) == plan.num_of_steps + 1
    assert len(art.plan_ellipses) == len(range(0, plan.num_of_steps + 1, 3))
    assert art.executed is not None and art.executed_ellipses
    assert art.observations is not None and len(art.observations.get_offsets()) == plan.num_of_steps
    assert art.real is not None and np.allclose(art.real.get_xdata()[0], LIGHT_DARK_REAL_INITIAL_STATE[0])
    assert ax.get_legend() is not None


def test_plot_workspace_without_light_or_trajectories(case):
    problem = case[0]
    art = plot_workspace(problem)
    assert art.light is None and art.plan is None and art.real is None
    assert len(art.regions) == 2
    assert art.figure is not None


def test_plot_monte_carlo_title_has_rates(case):
    problem, plan = case[0], case[1]
    report = validate(
        problem,
        plan,
        light_dark_real_system(),
        LIGHT_DARK_REAL_INITIAL_STATE,
        runs=4,
        seed=0,
        executor="serial",
        keep_trajectories=3,
    )
    art = plot_monte_carlo(problem, plan, report.executions, report=report)
    assert isinstance(art, MonteCarloArtists)
    assert len(art.executed) == 3 and len(art.real) == 3
    assert "belief" in art.title.get_text() and "%" in art.title.get_text()
    art2 = plot_monte_carlo(problem, plan, report.executions[:1], success_rate=0.5)
    assert "50.0%" in art2.title.get_text()


def test_sensor_light_is_brighter_near_the_light(case):
    light = sensor_light(case[0])
    vals = light(np.array([[0.0, 0.0], [4.5, 0.0]]))
    assert vals.shape == (2,) and vals[1] > vals[0]


def test_plotting_errors(case):
    problem, plan, xi_sim, xi_real = case
    with pytest.raises(InvalidTypeError, match="plan"):
        plot_workspace(problem, plan=plan.get_mean())
    with pytest.raises(DimensionError, match="dims"):
        plot_workspace(problem, dims=(0, 0))
    with pytest.raises(DimensionError, match="light"):
        plot_workspace(problem, light=lambda pts: np.zeros(3))
    with pytest.raises(InvalidArgumentError, match="executions"):
        plot_monte_carlo(problem, plan, [xi_sim])
