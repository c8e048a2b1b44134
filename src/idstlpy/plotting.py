"""Figures of plans and executions in a 2-D workspace (matplotlib is imported inside functions).

:func:`plot_workspace` draws, on one axes, the sensing quality (``light``), the regions of the
formula's atomic propositions, a planned belief trajectory (means and covariance ellipses), an
executed belief, the observations received and the true states. :func:`plot_light_dark` is the
same with the light taken from the problem's sensor noise. :func:`plot_monte_carlo` overlays many
executions. Every function takes ``ax=`` and returns a small dataclass holding what it drew.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import DimensionError, IdstlpyError, InvalidArgumentError, InvalidTypeError

__all__ = [
    "WorkspaceArtists",
    "MonteCarloArtists",
    "plot_workspace",
    "plot_light_dark",
    "plot_monte_carlo",
    "sensor_light",
]

logger = logging.getLogger(__name__)

_CHI2_95_2DOF = 5.991464547107979  # ellipses enclose 95% of a 2-D Gaussian


@dataclass
class WorkspaceArtists:
    """What :func:`plot_workspace` drew.

    Attributes
    ----------
    figure, ax : matplotlib Figure and Axes
    light : AxesImage or None
        The light shading.
    regions : dict[str, Polygon]
        One patch per atomic proposition with chance constraints (by name).
    plan : Line2D or None
        Planned means.
    plan_ellipses : list of Ellipse
        Planned 95% covariance ellipses.
    executed : Line2D or None
        Executed belief means.
    executed_ellipses : list of Ellipse
    observations : PathCollection or None
    real : Line2D or None
        True states.
    """

    figure: Any
    ax: Any
    light: Any = None
    regions: dict[str, Any] = field(default_factory=dict)
    plan: Any = None
    plan_ellipses: list[Any] = field(default_factory=list)
    executed: Any = None
    executed_ellipses: list[Any] = field(default_factory=list)
    observations: Any = None
    real: Any = None


@dataclass
class MonteCarloArtists:
    """What :func:`plot_monte_carlo` drew.

    Attributes
    ----------
    figure, ax : matplotlib Figure and Axes
    workspace : WorkspaceArtists
        Light, regions and the plan.
    executed : list of Line2D
        One line per executed belief.
    real : list of Line2D
        One line per true-state trajectory.
    title : Text
    """

    figure: Any
    ax: Any
    workspace: WorkspaceArtists
    executed: list[Any] = field(default_factory=list)
    real: list[Any] = field(default_factory=list)
    title: Any = None


def sensor_light(problem: Any, mode: int | None = None) -> Callable[[np.ndarray], np.ndarray] | None:
    """A light map from a problem's sensor: ``-log10 trace R(x)`` (higher means better sensing).

    Parameters
    ----------
    problem : Problem
    mode : int, optional
        Which mode's sensor (default: the first mode with an output).

    Returns
    -------
    callable or None
        Maps points of shape (k, n) to values of shape (k,); None when no mode observes.
    """
    modes = list(problem.switched_system.system_modes)
    if mode is None:
        observing = [md for md in modes if md.p]
        if not observing:
            return None
        sensor = observing[0]
    else:
        sensor = problem.switched_system.mode(mode)
    n = problem.switched_system.n
    base = np.asarray(problem.initial_state.mean, dtype=float)

    def light(points: np.ndarray) -> np.ndarray:
        pts = np.asarray(points, dtype=float)
        out = np.empty(pts.shape[0])
        for i, p in enumerate(pts):
            x = base.copy() if pts.shape[1] < n else p
            if pts.shape[1] < n:
                x[: pts.shape[1]] = p
            out[i] = -np.log10(max(float(np.trace(sensor.noise_cov(x))), 1e-300))
        return out

    return light


def _ellipse(mean: np.ndarray, cov: np.ndarray, **kw: Any) -> Any:
    from matplotlib.patches import Ellipse

    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    vals = np.maximum(vals, 0.0)
    angle = float(np.degrees(np.arctan2(vecs[1, -1], vecs[0, -1])))
    width, height = 2 * np.sqrt(_CHI2_95_2DOF * vals[::-1])
    return Ellipse(tuple(mean), float(width), float(height), angle=angle, **kw)


def _axes(ax: Any, figsize: tuple[float, float] = (6.0, 5.0)) -> tuple[Any, Any]:
    if ax is None:
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=figsize)
        return fig, ax
    return ax.figure, ax


def _check_traj(traj: Any, what: str, n: int) -> None:
    from .trajectory import ProbabilisticTSTrajectory, RealTrajectory

    if not isinstance(traj, ProbabilisticTSTrajectory | RealTrajectory):
        raise InvalidTypeError(f"{what} must be a trajectory, got {type(traj).__name__}")
    dim = traj.n if isinstance(traj, ProbabilisticTSTrajectory) else traj.get_state().shape[1]
    if dim != n:
        raise DimensionError(f"{what} has state dimension {dim}, the problem has n = {n}")


def _extent(problem: Any, regions: list[np.ndarray], trajs: list[np.ndarray], dims: tuple[int, int]) -> Any:
    pts = [r for r in regions] + [t[:, list(dims)] for t in trajs]
    pts.append(np.asarray(problem.initial_state.mean)[list(dims)][None, :])
    allp = np.vstack([p for p in pts if p.size])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.08 * np.maximum(hi - lo, 1.0)
    return lo - pad, hi + pad


def plot_workspace(
    problem: Any,
    plan: Any = None,
    executed: Any = None,
    real: Any = None,
    ax: Any = None,
    light: Callable[[np.ndarray], np.ndarray] | None = None,
    *,
    dims: tuple[int, int] = (0, 1),
    ellipse_every: int | None = None,
    resolution: int = 120,
    legend: bool = True,
) -> WorkspaceArtists:
    """Draw a problem's workspace with a plan and an execution.

    Parameters
    ----------
    problem : Problem
        Supplies the formula's regions and the initial belief.
    plan : ProbabilisticTSTrajectory, optional
        Planned belief (means (N+1, n), covariances), drawn in blue with 95% ellipses.
    executed : ProbabilisticTSTrajectory, optional
        Executed belief (orange).
    real : RealTrajectory, optional
        True states (red) and observations (purple dots).
    ax : matplotlib Axes, optional
        Where to draw (default: a new figure).
    light : callable, optional
        ``light(points (k, 2)) -> (k,)``: the sensing quality to shade (brighter is better).
    dims : tuple of int
        The two state coordinates to draw.
    ellipse_every : int, optional
        Draw a covariance ellipse every this many steps (default: about 25 per trajectory).
    resolution : int
        Grid points per axis of the light shading.
    legend : bool
        Add a legend.

    Returns
    -------
    WorkspaceArtists
    """
    from matplotlib.patches import Polygon

    from .formulas import STLFormula

    n = problem.switched_system.n
    if not isinstance(getattr(problem, "stl_formula", None), STLFormula):
        raise InvalidTypeError(f"problem must be a Problem, got {type(problem).__name__}")
    if len(dims) != 2 or not all(0 <= d < n for d in dims) or dims[0] == dims[1]:
        raise DimensionError(f"dims must be two different coordinates in 0..{n - 1}, got {dims}")
    for traj, what in ((plan, "plan"), (executed, "executed"), (real, "real")):
        if traj is not None:
            _check_traj(traj, what, n)
    fig, ax = _axes(ax)
    out = WorkspaceArtists(figure=fig, ax=ax)

    # Regions of the atomic propositions (their zero-covariance shapes).
    region_pts: list[tuple[str, np.ndarray]] = []
    if n == 2:
        for i, ap in enumerate(problem.stl_formula.atomic_propositions()):
            if not ap.predicates:
                continue
            name = ap.name or f"ap{i}"
            try:
                verts = ap.cone.deterministic_region.vertices_2d()
            except IdstlpyError as exc:  # unbounded or empty region: nothing to draw
                logger.debug("plot_workspace: skip region %s (%s)", name, exc)
                continue
            region_pts.append((name, verts))
    trajs = [t.get_mean() for t in (plan, executed) if t is not None]
    if real is not None:
        trajs.append(real.get_state())
    lo, hi = _extent(problem, [v for _, v in region_pts], trajs, dims)

    if light is not None:
        xs = np.linspace(lo[0], hi[0], resolution)
        ys = np.linspace(lo[1], hi[1], resolution)
        X, Y = np.meshgrid(xs, ys)
        pts = np.column_stack([X.ravel(), Y.ravel()])
        vals = np.asarray(light(pts), dtype=float)
        if vals.shape != (pts.shape[0],):
            raise DimensionError(f"light must map points (k, 2) to values (k,), got shape {vals.shape}")
        out.light = ax.imshow(
            vals.reshape(X.shape),
            origin="lower",
            extent=(lo[0], hi[0], lo[1], hi[1]),
            cmap="gray",
            aspect="auto",
            alpha=0.8,
            zorder=0,
        )

    colors = ["black", "tab:green", "tab:purple", "tab:brown", "tab:cyan"]
    for j, (name, verts) in enumerate(region_pts):
        poly = Polygon(
            verts,
            closed=True,
            fill=False,
            edgecolor=colors[j % len(colors)],
            linewidth=1.5,
            linestyle="-" if j else "--",
            label=name,
            zorder=2,
        )
        ax.add_patch(poly)
        out.regions[name] = poly

    def every(traj: Any) -> int:
        return ellipse_every or max(1, (traj.num_of_steps + 1) // 25)

    d = list(dims)
    if plan is not None:
        m = plan.get_mean()
        (out.plan,) = ax.plot(m[:, d[0]], m[:, d[1]], "-", color="tab:blue", lw=1.5, label="plan", zorder=4)
        for k in range(0, plan.num_of_steps + 1, every(plan)):
            e = _ellipse(m[k, d], plan.get_cov(k)[np.ix_(d, d)], fill=False, ec="tab:blue", lw=0.6, zorder=3)
            ax.add_patch(e)
            out.plan_ellipses.append(e)
    if executed is not None:
        m = executed.get_mean()
        (out.executed,) = ax.plot(
            m[:, d[0]], m[:, d[1]], "-", color="tab:orange", lw=1.2, label="executed belief", zorder=5
        )
        for k in range(0, executed.num_of_steps + 1, every(executed)):
            cov = executed.get_cov(k)[np.ix_(d, d)]
            e = _ellipse(m[k, d], cov, fill=False, ec="tab:orange", lw=0.5, zorder=3)
            ax.add_patch(e)
            out.executed_ellipses.append(e)
    if real is not None:
        obs = real.get_observation()
        if obs.ndim == 2 and obs.shape[1] >= 2 and np.any(np.isfinite(obs[:, 0])):
            ok = np.all(np.isfinite(obs[:, d]), axis=1) if obs.shape[1] > max(d) else None
            if ok is not None and ok.any():
                out.observations = ax.scatter(
                    obs[ok, d[0]],
                    obs[ok, d[1]],
                    s=4,
                    color="tab:purple",
                    alpha=0.5,
                    label="observations",
                    zorder=4,
                )
        s = real.get_state()
        (out.real,) = ax.plot(
            s[:, d[0]], s[:, d[1]], "-", color="tab:red", lw=1.0, label="true state", zorder=6
        )
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_xlabel(f"x[{d[0]}]")
    ax.set_ylabel(f"x[{d[1]}]")
    if legend:
        ax.legend(loc="best", fontsize="small")
    return out


def plot_light_dark(
    problem: Any,
    plan: Any = None,
    executed: Any = None,
    real: Any = None,
    ax: Any = None,
    light: Callable[[np.ndarray], np.ndarray] | None = None,
    **kwargs: Any,
) -> WorkspaceArtists:
    """:func:`plot_workspace` with the light taken from the problem's sensor (:func:`sensor_light`).

    Parameters
    ----------
    problem, plan, executed, real, ax
        As in :func:`plot_workspace`.
    light : callable, optional
        Overrides the sensor-derived light map.
    **kwargs
        Passed to :func:`plot_workspace`.

    Returns
    -------
    WorkspaceArtists
    """
    if light is None:
        light = sensor_light(problem)
    return plot_workspace(problem, plan, executed, real, ax=ax, light=light, **kwargs)


def plot_monte_carlo(
    problem: Any,
    plan: Any,
    executions: Sequence[tuple[Any, Any]],
    report: Any = None,
    ax: Any = None,
    light: Callable[[np.ndarray], np.ndarray] | None = None,
    *,
    success_rate: float | None = None,
    dims: tuple[int, int] = (0, 1),
) -> MonteCarloArtists:
    """Overlay many executions of a plan; the title gives the success rate(s).

    Parameters
    ----------
    problem : Problem
    plan : ProbabilisticTSTrajectory
    executions : sequence of (ProbabilisticTSTrajectory, RealTrajectory)
        E.g. ``ValidationReport.executions``.
    report : ValidationReport, optional
        Supplies the belief / state success rates and their confidence intervals.
    ax : matplotlib Axes, optional
    light : callable, optional
        As in :func:`plot_workspace` (default: :func:`sensor_light`).
    success_rate : float, optional
        Used in the title when no report is given.
    dims : tuple of int

    Returns
    -------
    MonteCarloArtists
    """
    if light is None:
        light = sensor_light(problem)
    ws = plot_workspace(problem, plan, ax=ax, light=light, dims=dims, legend=False)
    ax = ws.ax
    if ws.plan is not None:  # keep the plan visible above the executions that track it
        ws.plan.set_zorder(7)
        ws.plan.set_linestyle("--")
    d = list(dims)
    out = MonteCarloArtists(figure=ws.figure, ax=ax, workspace=ws)
    n = problem.switched_system.n
    for i, pair in enumerate(executions):
        if not isinstance(pair, tuple | list) or len(pair) != 2:
            raise InvalidArgumentError(f"executions[{i}] must be a pair (executed belief, real trajectory)")
        xs, xr = pair
        _check_traj(xs, f"executions[{i}][0]", n)
        _check_traj(xr, f"executions[{i}][1]", n)
        m = xs.get_mean()
        (line,) = ax.plot(m[:, d[0]], m[:, d[1]], color="tab:orange", lw=0.6, alpha=0.35, zorder=5)
        out.executed.append(line)
        s = xr.get_state()
        (rline,) = ax.plot(s[:, d[0]], s[:, d[1]], color="tab:red", lw=0.5, alpha=0.35, zorder=6)
        out.real.append(rline)
    if report is not None:
        title = (
            f"{report.runs} runs: belief {100 * report.belief_success_rate:.1f}% "
            f"[{100 * report.belief_ci[0]:.1f}, {100 * report.belief_ci[1]:.1f}], "
            f"state {100 * report.state_success_rate:.1f}% "
            f"[{100 * report.state_ci[0]:.1f}, {100 * report.state_ci[1]:.1f}]"
        )
    elif success_rate is not None:
        title = f"{len(executions)} executions: success {100 * float(success_rate):.1f}%"
    else:
        title = f"{len(executions)} executions"
    out.title = ax.set_title(title, fontsize="small")
    if out.executed:
        out.executed[0].set_label("executed beliefs")
        out.real[0].set_label("true states")
    ax.legend(loc="best", fontsize="small")
    return out
