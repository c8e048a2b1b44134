"""Figures the command line writes (``solve --plot``, ``plot``), drawn by :mod:`idstlpy.plotting`.

The format comes from the file's extension: ``.png``, ``.pdf`` or ``.svg``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ..errors import InvalidArgumentError

__all__ = ["FIGURE_FORMATS", "check_figure_path", "save_plan_figure"]

FIGURE_FORMATS = ("png", "pdf", "svg")


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


def save_plan_figure(problem: Any, plan: Any, path: str | os.PathLike[str], title: str = "") -> Path:
    """Draw ``plan`` over ``problem``'s workspace and save it (format from the extension).

    A problem with at least two states is drawn by :func:`idstlpy.plotting.plot_light_dark`
    (the sensing quality, the propositions' regions, the planned means and covariance
    ellipses); a one-state problem by ``idstlpy.plotting.plot_time_series`` when the plotting
    module has it.

    Parameters
    ----------
    problem : Problem
    plan : ProbabilisticTSTrajectory or None
        None draws the workspace alone.
    path : path
        ``.png``, ``.pdf`` or ``.svg``.
    title : str
        The axes' title.

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .. import plotting

    out = check_figure_path(path)
    n = problem.switched_system.n
    if n >= 2:
        fig, ax = plt.subplots(figsize=(6.5, 5.5))
        plotting.plot_light_dark(problem, plan, ax=ax)
    else:
        time_series = getattr(plotting, "plot_time_series", None)
        if time_series is None or plan is None:
            raise InvalidArgumentError(
                "figures of one-state problems need idstlpy.plotting.plot_time_series and a plan"
            )
        art = time_series(problem, plan)
        fig = art.figure
        ax = getattr(art, "ax", None) or fig.axes[0]
    if title:
        ax.set_title(title, fontsize="small")
    try:
        fig.savefig(out, dpi=120, bbox_inches="tight", format=out.suffix.lower().lstrip("."))
    finally:
        plt.close(fig)
    return out
