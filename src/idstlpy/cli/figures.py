"""Figures the command line writes (``solve --plot``, ``plot``), drawn by :mod:`idstlpy.plotting`.

The format comes from the file's extension: ``.png``, ``.pdf`` or ``.svg``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ..errors import InvalidArgumentError

__all__ = ["FIGURE_FORMATS", "FIGURE_KINDS", "check_figure_path", "save_plan_figure", "save_runs_figure"]

FIGURE_FORMATS = ("png", "pdf", "svg")
FIGURE_KINDS = ("auto", "workspace", "time-series")


def check_figure_path(path: str | os.PathLike[str]) -> Path:
    """The figure's path, checked before any work is done: a known extension, an existing folder.

    Parameters
    ----------
    path : path
        ``out.png``, ``out.pdf`` or ``out.svg``.

    Returns
    -------
    Path

    Raises
    ------
    InvalidArgumentError
        For another extension or a missing folder.
    """
    out = Path(path)
    fmt = out.suffix.lower().lstrip(".")
    if fmt not in FIGURE_FORMATS:
        raise InvalidArgumentError(
            f"figure {str(out)!r}: the extension gives the format; use one of "
            f"{', '.join('.' + f for f in FIGURE_FORMATS)}"
        )
    if not out.parent.is_dir():
        raise InvalidArgumentError(f"figure {str(out)!r}: folder {str(out.parent)!r} does not exist")
    return out


def save_plan_figure(
    problem: Any, plan: Any, path: str | os.PathLike[str], title: str = "", kind: str = "auto"
) -> Path:
    """Draw ``plan`` over ``problem`` and save it (format from the extension).

    Parameters
    ----------
    problem : Problem
    plan : ProbabilisticTSTrajectory or None
        None draws the workspace alone.
    path : path
        ``.png``, ``.pdf`` or ``.svg``.
    title : str
        The (first) axes' title.
    kind : {"auto", "workspace", "time-series"}
        ``"workspace"``: :func:`idstlpy.plotting.plot_light_dark` in the plane of ``x[0]`` and
        ``x[1]`` (the sensor noise where it varies, the propositions' regions filled and named,
        an obstacle of a disjunction hatched, start and end, the planned means, sensing steps
        and covariance ellipses, and a caption saying what they are); ``"time-series"``:
        :func:`idstlpy.plotting.plot_time_series` (each state's mean with a 2-sigma band and the
        propositions' intervals, the inputs, the modes); ``"auto"``: the workspace for two or
        more states, else the time series.

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .. import plotting

    if kind not in FIGURE_KINDS:
        raise InvalidArgumentError(f"figure kind must be one of {', '.join(FIGURE_KINDS)}, got {kind!r}")
    out = check_figure_path(path)
    n = problem.switched_system.n
    if kind == "auto":
        kind = "workspace" if n >= 2 else "time-series"
    if kind == "workspace":
        if n < 2:
            raise InvalidArgumentError(f"a workspace figure needs two or more states, the problem has {n}")
        fig, ax = plt.subplots(figsize=(6.5, 5.5))
        plotting.plot_light_dark(problem, plan, ax=ax)
    else:
        if plan is None:
            raise InvalidArgumentError("a time-series figure needs a plan")
        art = plotting.plot_time_series(problem, plan)
        fig, ax = art.figure, art.ax
    if title:
        ax.set_title(title, fontsize="small")
    try:
        fig.savefig(out, dpi=120, bbox_inches="tight", format=out.suffix.lower().lstrip("."))
    finally:
        plt.close(fig)
    return out


def save_runs_figure(
    problem: Any, plan: Any, executions: Any, path: str | os.PathLike[str], title: str = ""
) -> Path:
    """Draw executions of ``plan`` over ``problem`` (:func:`idstlpy.plotting.plot_monte_carlo`).

    Parameters
    ----------
    problem : Problem
    plan : ProbabilisticTSTrajectory
    executions : sequence of (ProbabilisticTSTrajectory, RealTrajectory)
        The runs (``ValidationReport.executions``).
    path : path
        ``.png``, ``.pdf`` or ``.svg``.
    title : str
        The title (default: the plot's own, the runs' count).

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .. import plotting

    out = check_figure_path(path)
    art = plotting.plot_monte_carlo(problem, plan, executions)
    if title:
        clipped = f"\n{len(art.clipped)} true-state runs leave the axes (x: where)" if art.clipped else ""
        art.ax.set_title(title + clipped, fontsize="small")
    try:
        art.figure.savefig(out, dpi=120, bbox_inches="tight", format=out.suffix.lower().lstrip("."))
    finally:
        plt.close(art.figure)
    return out
