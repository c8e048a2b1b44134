"""Figures of plans and executions (matplotlib is imported inside the functions).

- :func:`plot_workspace` draws, on one axes and in two chosen state coordinates, a shading of
  the sensing quality with its colorbar, the regions of the formula's atomic propositions
  (clipped to the view, half-planes included), a planned belief trajectory (means, 95%
  covariance ellipses, modes coloured along it), an executed belief, the observations received
  and the true states; the legend names every kind of mark and stays off the data.
- :func:`plot_light_dark` is the same with the shading taken from the problem's sensor: the
  noise standard deviation of the plan's mode over the workspace (brighter is less noise).
- :func:`plot_monte_carlo` overlays many executions.
- Both draw, with ``predicted=`` (a :class:`~idstlpy.execution.prediction.ClosedLoopPrediction`,
  or from ``validate(..., predict=True)``'s report), the predicted true-state mean and its 95%
  ellipses: where the executor is expected to take the robot, before it runs.
- :func:`plot_time_series` draws any trajectory against the step: per state the mean with a
  2-sigma band, then the inputs and the modes; it works for any state dimension.
- :func:`save_figure` writes a figure in the format of the file's extension (PNG, PDF, SVG).

Every drawing function takes an axes (or axes) to draw on, and returns a small dataclass
holding what it drew (the python-control convention).
"""

from __future__ import annotations

import logging
import os
import textwrap
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import DimensionError, IdstlpyError, InvalidArgumentError, InvalidTypeError

__all__ = [
    "WorkspaceArtists",
    "MonteCarloArtists",
    "TimeSeriesArtists",
    "plot_workspace",
    "plot_light_dark",
    "plot_monte_carlo",
    "plot_time_series",
    "sensor_light",
    "sensor_noise_std",
    "clip_halfplanes",
    "save_figure",
    "FIGURE_FORMATS",
    "RUN_WINDOW",
    "temporal_windows",
]

logger = logging.getLogger(__name__)

_CHI2_95_2DOF = 5.991464547107979  # ellipses enclose 95% of a 2-D Gaussian

FIGURE_FORMATS = ("png", "pdf", "svg")
"""Formats :func:`save_figure` writes, chosen by the file's extension."""

MODE_COLORS = ("tab:cyan", "tab:pink", "tab:olive", "tab:green", "tab:brown", "tab:gray", "gold", "navy")
"""Colours of the modes along a plan (mode ``q`` takes ``MODE_COLORS[q % len]``)."""

REGION_COLORS = ("black", "darkgreen", "darkviolet", "saddlebrown", "teal")
"""Edge colours of the propositions' regions, in order of appearance."""

LegendPlacement = bool | str


@dataclass
class WorkspaceArtists:
    """What :func:`plot_workspace` drew.

    Attributes
    ----------
    figure, ax : matplotlib Figure and Axes
        Where it was drawn.
    light : AxesImage or None
        The shading of the sensing quality.
    colorbar : Colorbar or None
        The shading's colorbar (its label names the quantity).
    regions : dict[str, Polygon]
        One patch per atomic proposition with chance constraints (by name): the states its mean
        must be in at zero covariance, clipped to the view.
    plan : Line2D or None
        Planned means.
    plan_ellipses : list of Ellipse
        Planned 95% covariance ellipses.
    modes : LineCollection or None
        The plan's segments coloured by the mode applied along them (when shown).
    executed : Line2D or None
        Executed belief means.
    executed_ellipses : list of Ellipse
        Executed 95% covariance ellipses.
    observations : PathCollection or None
        The observations received (their first two outputs, in the drawn coordinates).
    real : Line2D or None
        True states.
    predicted : Line2D or None
        The predicted true-state mean (``predicted=``).
    predicted_ellipses : list of Ellipse
        The predicted true state's 95% ellipses.
    legend : Legend or None
        The legend.
    legend_proxies : list of Artist
        Entries of the legend that are not drawn on the axes (ellipses, shading, modes).
    dims : tuple of int
        The two state coordinates drawn.
    region_labels : dict[str, Text]
        The name of each proposition drawn, written inside its region.
    region_groups : dict[str, PathPatch]
        Per disjunction of half-planes (``"left | right | below | above"``), the filled union of
        its operands (the view minus the obstacle); ``regions`` maps each operand to it too.
    obstacles : dict[str, Polygon]
        Per disjunction of half-planes, the hatched set outside every operand (the obstacle).
    light_constant : float or None
        The value of a shading that is the same everywhere (then nothing is shaded and no
        colorbar drawn; the legend gives the value).
    start, end : Line2D or None
        Markers of the initial mean and of the plan's last mean.
    sensing : PathCollection or None
        The plan's sensing steps (a mode with an output), one marker at the belief each
        observation updates, in the mode's colour (when the modes are shown).
    still : list of Annotation
        ``"n steps in place"`` where the plan's mean stays put for several steps (e.g. a mode
        with ``B = 0`` that only looks).
    caption : Text or None
        What the ellipses, the shading and the regions are, under the axes.
    """

    figure: Any
    ax: Any
    light: Any = None
    colorbar: Any = None
    regions: dict[str, Any] = field(default_factory=dict)
    plan: Any = None
    plan_ellipses: list[Any] = field(default_factory=list)
    modes: Any = None
    executed: Any = None
    executed_ellipses: list[Any] = field(default_factory=list)
    observations: Any = None
    real: Any = None
    predicted: Any = None
    predicted_ellipses: list[Any] = field(default_factory=list)
    legend: Any = None
    legend_proxies: list[Any] = field(default_factory=list)
    dims: tuple[int, int] = (0, 1)
    region_labels: dict[str, Any] = field(default_factory=dict)
    region_groups: dict[str, Any] = field(default_factory=dict)
    obstacles: dict[str, Any] = field(default_factory=dict)
    light_constant: float | None = None
    start: Any = None
    end: Any = None
    sensing: Any = None
    still: list[Any] = field(default_factory=list)
    caption: Any = None


@dataclass
class MonteCarloArtists:
    """What :func:`plot_monte_carlo` drew.

    Attributes
    ----------
    figure, ax : matplotlib Figure and Axes
        Where it was drawn.
    workspace : WorkspaceArtists or None
        Shading, regions and the plan (None for a one-state problem).
    executed : list of Line2D
        One line per executed belief.
    real : list of Line2D
        One line per true-state trajectory.
    title : Text
        The title (success rates).
    legend : Legend or None
        The legend.
    time_series : TimeSeriesArtists or None
        For a one-state problem: the time series the executions are overlaid on.
    clipped : list of Line2D
        One x per true-state run that leaves the axes (farther than :data:`RUN_WINDOW` spans
        of the plan's own extent), where it leaves them.
    """

    figure: Any
    ax: Any
    workspace: WorkspaceArtists | None
    executed: list[Any] = field(default_factory=list)
    real: list[Any] = field(default_factory=list)
    title: Any = None
    legend: Any = None
    time_series: TimeSeriesArtists | None = None
    clipped: list[Any] = field(default_factory=list)


@dataclass
class TimeSeriesArtists:
    """What :func:`plot_time_series` drew.

    Attributes
    ----------
    figure : matplotlib Figure
        The figure.
    axes : list of Axes
        One per drawn state, then the inputs' axes and the modes' axes (when drawn).
    ax : Axes
        The first axes (for a title).
    states : tuple of int
        The state coordinates drawn, in the order of ``axes``.
    means, bands : dict[int, Artist]
        Per state coordinate, the planned mean (Line2D) and its ``sigma`` band (PolyCollection).
    executed_means, executed_bands : dict[int, Artist]
        The same for the executed belief.
    real : dict[int, Line2D]
        Per state coordinate, the true state.
    bounds : list of Line2D
        The propositions' bounds on single coordinates (horizontal lines).
    controls_ax : Axes or None
        The inputs' axes.
    controls : list of Line2D
        One line per input (planned), then one per input (executed, dashed).
    modes_ax : Axes or None
        The modes' axes.
    modes : list of Line2D
        The planned modes (and the executed ones, when different from the plan's).
    mode_bands : list of BrokenBarHCollection
        One coloured band per run of the same planned mode (the colours of
        :func:`plot_workspace`).
    legend : Legend or None
        The legend of the states' axes.
    regions : dict[str, Polygon]
        Per box-shaped proposition (every face on one coordinate), its interval on each drawn
        state it constrains, filled across the axes and labelled with its name (key: the name,
        ``"goal (x[1])"`` for its second and later states).
    runs_executed, runs_real : dict[int, list of Line2D]
        Per state coordinate, one thin line per execution of ``executions=`` (executed belief
        means, true states).
    start, end : dict[int, Line2D]
        Per state coordinate, the markers of the plan's first and last mean.
    caption : Text or None
        What the bands and the thin lines are, under the last axes.
    region_labels : dict[str, Text]
        The names written on the filled bands (placed away from the plan's mean and from each
        other).
    windows : list of (str, int, int)
        The formula's temporal operators with the steps each applies to (its window, shifted by
        the windows of the operators around it), drawn as brackets above the first axes.
    """

    figure: Any
    axes: list[Any]
    ax: Any
    states: tuple[int, ...]
    means: dict[int, Any] = field(default_factory=dict)
    bands: dict[int, Any] = field(default_factory=dict)
    executed_means: dict[int, Any] = field(default_factory=dict)
    executed_bands: dict[int, Any] = field(default_factory=dict)
    real: dict[int, Any] = field(default_factory=dict)
    bounds: list[Any] = field(default_factory=list)
    controls_ax: Any = None
    controls: list[Any] = field(default_factory=list)
    modes_ax: Any = None
    modes: list[Any] = field(default_factory=list)
    mode_bands: list[Any] = field(default_factory=list)
    legend: Any = None
    regions: dict[str, Any] = field(default_factory=dict)
    runs_executed: dict[int, list[Any]] = field(default_factory=dict)
    runs_real: dict[int, list[Any]] = field(default_factory=dict)
    start: dict[int, Any] = field(default_factory=dict)
    end: dict[int, Any] = field(default_factory=dict)
    caption: Any = None
    region_labels: dict[str, Any] = field(default_factory=dict)
    windows: list[tuple[str, int, int]] = field(default_factory=list)


# ----------------------------------------------------------------------------------------------
# Sensing maps


def _sensor_mode(problem: Any, mode: int | None) -> Any:
    modes = list(problem.switched_system.system_modes)
    if mode is None:
        observing = [md for md in modes if md.p]
        return observing[0] if observing else None
    return problem.switched_system.mode(mode)


def _full_states(problem: Any, dims: Sequence[int], base: Any) -> Callable[[np.ndarray], np.ndarray]:
    """Map points (k, 2) of the ``dims`` plane to states (k, n), other coordinates from ``base``."""
    n = problem.switched_system.n
    ref = np.asarray(problem.initial_state.mean if base is None else base, dtype=float).reshape(-1)
    if ref.shape != (n,):
        raise DimensionError(f"base must be a state of size {n}, got shape {ref.shape}")
    d = list(dims)
    if len(d) != 2 or not all(0 <= i < n for i in d) or d[0] == d[1]:
        raise DimensionError(f"dims must be two different coordinates in 0..{n - 1}, got {tuple(dims)}")

    def lift(points: np.ndarray) -> np.ndarray:
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise DimensionError(f"points must have shape (k, 2), got {pts.shape}")
        out = np.tile(ref, (pts.shape[0], 1))
        out[:, d] = pts
        return out

    return lift


def sensor_noise_std(
    problem: Any, mode: int | None = None, *, dims: Sequence[int] = (0, 1), base: Any = None
) -> Callable[[np.ndarray], np.ndarray] | None:
    """The sensor's noise standard deviation over the workspace: ``sqrt(trace R(x) / p)``.

    For a noise ``n(x) = s(x) I`` this is ``s(x)``; in general the root mean square of the
    outputs' standard deviations (smaller means better sensing).

    Parameters
    ----------
    problem : Problem
        Supplies the modes and the initial belief.
    mode : int, optional
        Which mode's sensor (default: the first mode with an output).
    dims : sequence of two int
        The state coordinates of the points the map takes.
    base : array_like, shape (n,), optional
        The other coordinates of the states evaluated (default: the initial mean).

    Returns
    -------
    callable or None
        Maps points of shape (k, 2) (coordinates ``dims``) to values of shape (k,); None when
        the mode does not observe (or no mode does).
    """
    sensor = _sensor_mode(problem, mode)
    if sensor is None or not sensor.p:
        return None
    lift = _full_states(problem, dims, base)

    def noise_std(points: np.ndarray) -> np.ndarray:
        states = lift(points)
        return np.array([np.sqrt(max(float(np.trace(sensor.noise_cov(x))), 0.0) / sensor.p) for x in states])

    return noise_std


def sensor_light(
    problem: Any, mode: int | None = None, *, dims: Sequence[int] = (0, 1), base: Any = None
) -> Callable[[np.ndarray], np.ndarray] | None:
    """A light map from a problem's sensor: ``-log10 trace R(x)`` (higher means better sensing).

    Parameters
    ----------
    problem : Problem
        Supplies the modes and the initial belief.
    mode : int, optional
        Which mode's sensor (default: the first mode with an output).
    dims : sequence of two int
        The state coordinates of the points the map takes.
    base : array_like, shape (n,), optional
        The other coordinates of the states evaluated (default: the initial mean).

    Returns
    -------
    callable or None
        Maps points of shape (k, 2) to values of shape (k,); None when no mode observes.
    """
    sensor = _sensor_mode(problem, mode)
    if sensor is None or not sensor.p:
        return None
    lift = _full_states(problem, dims, base)

    def light(points: np.ndarray) -> np.ndarray:
        states = lift(points)
        return np.array([-np.log10(max(float(np.trace(sensor.noise_cov(x))), 1e-300)) for x in states])

    return light


# ----------------------------------------------------------------------------------------------
# Geometry


def _ellipse(mean: np.ndarray, cov: np.ndarray, **kw: Any) -> Any:
    from matplotlib.patches import Ellipse

    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    vals = np.maximum(vals, 0.0)
    angle = float(np.degrees(np.arctan2(vecs[1, -1], vecs[0, -1])))
    width, height = 2 * np.sqrt(_CHI2_95_2DOF * vals[::-1])
    return Ellipse(tuple(mean), float(width), float(height), angle=angle, **kw)


def clip_halfplanes(H: np.ndarray, c: np.ndarray, low: Any, high: Any) -> np.ndarray:
    """The polygon ``{y in [low, high] : H y + c <= 0}`` (counter-clockwise vertices, shape (v, 2)).

    Parameters
    ----------
    H : ndarray, shape (F, 2)
        Face normals.
    c : ndarray, shape (F,)
        Offsets.
    low, high : array_like, shape (2,)
        Corners of the view box.

    Returns
    -------
    ndarray, shape (v, 2)
        Empty (shape (0, 2)) when nothing of the region is in view.
    """
    (x0, y0), (x1, y1) = low, high
    poly = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    scale = max(1.0, float(np.max(np.abs(poly))))
    for h, cst in zip(np.asarray(H, dtype=float), np.asarray(c, dtype=float), strict=True):
        if not len(poly):
            break
        norm = float(np.linalg.norm(h))
        if norm == 0.0:
            if cst > 0:
                return np.zeros((0, 2))
            continue
        s = (poly @ h + cst) / norm
        tol = 1e-12 * scale
        out: list[np.ndarray] = []
        for i in range(len(poly)):
            p, q = poly[i], poly[(i + 1) % len(poly)]
            sp, sq = s[i], s[(i + 1) % len(poly)]
            if sp <= tol:
                out.append(p)
            if (sp < -tol and sq > tol) or (sp > tol and sq < -tol):
                out.append(p + (sp / (sp - sq)) * (q - p))
        poly = np.array(out).reshape(-1, 2)
    if len(poly) < 3:
        return np.zeros((0, 2))
    keep = np.ones(len(poly), dtype=bool)
    keep[1:] = np.any(np.abs(np.diff(poly, axis=0)) > 1e-12 * scale, axis=1)
    poly = poly[keep]
    if len(poly) > 1 and np.allclose(poly[0], poly[-1], atol=1e-12 * scale):
        poly = poly[:-1]
    return poly if len(poly) >= 3 else np.zeros((0, 2))


def _number(v: float) -> str:
    return f"{v:.4g}"


def _face_text(h: np.ndarray, cst: float) -> str:
    """``h x + c <= 0`` as text: ``x[0] <= 2`` for one coordinate, else ``x[0] + 2 x[1] <= 3``."""
    nz = np.flatnonzero(h)
    if nz.size == 1:
        i = int(nz[0])
        bound = -cst / h[i]
        return f"x[{i}] {'<=' if h[i] > 0 else '>='} {_number(bound)}"
    terms = []
    for k in nz:
        a = float(h[k])
        sign = "-" if a < 0 else "+"
        mag = "" if abs(a) == 1.0 else f"{_number(abs(a))} "
        terms.append(f"{sign} {mag}x[{int(k)}]")
    text = " ".join(terms).lstrip("+ ")
    return f"{text} <= {_number(-cst)}" if nz.size else f"0 <= {_number(-cst)}"


def _atom_label(ap: Any, H: np.ndarray, c: np.ndarray) -> str:
    """A proposition's name, or for an unnamed one its constraints (``x[0] <= 2 & x[1] >= 1``)."""
    if ap.name:
        return str(ap.name)
    faces = [_face_text(h, cst) for h, cst in zip(H, c, strict=True)]
    text = " & ".join(faces[:2]) + (f" & ... ({len(faces)} faces)" if len(faces) > 2 else "")
    return text or "true"


def _atoms(problem: Any) -> list[tuple[int, str, np.ndarray, np.ndarray, Any]]:
    """``(j, label, H, c, ap)`` per atomic proposition with chance constraints (``j`` counts them).

    ``H x + c <= 0`` is the set its mean must be in at zero covariance; ``j`` picks the style,
    so a proposition looks the same in every figure. The label is the proposition's name, or
    its constraints when it has none (an inline ``{P[...] >= ...}``).
    """
    out: list[tuple[int, str, np.ndarray, np.ndarray, Any]] = []
    used: set[str] = set()
    for ap in problem.stl_formula.atomic_propositions():
        if not ap.predicates:
            continue
        region = ap.cone.deterministic_region
        H, c = np.asarray(region.H, dtype=float), np.asarray(region.c, dtype=float)
        label = _atom_label(ap, H, c)
        base, k = label, 2
        while label in used:  # two distinct propositions with one text: keep both
            label, k = f"{base} ({k})", k + 1
        used.add(label)
        out.append((len(out), label, H, c, ap))
    return out


def _propositions(problem: Any) -> list[tuple[int, str, np.ndarray, np.ndarray]]:
    """``(j, label, H, c)`` per atomic proposition with chance constraints (see :func:`_atoms`)."""
    return [(j, name, H, c) for j, name, H, c, _ in _atoms(problem)]


def _region_style(j: int) -> dict[str, Any]:
    return {"color": REGION_COLORS[j % len(REGION_COLORS)], "linestyle": "--" if j == 0 else "-"}


def _proposition_halfplanes(
    problem: Any, dims: Sequence[int]
) -> list[tuple[int, str, np.ndarray, np.ndarray]]:
    """Per atomic proposition with chance constraints, its faces on the ``dims`` coordinates."""
    return [(j, name, H, c) for j, name, H, c, _ in _plane_atoms(problem, dims)]


def _plane_atoms(problem: Any, dims: Sequence[int]) -> list[tuple[int, str, np.ndarray, np.ndarray, Any]]:
    """:func:`_proposition_halfplanes` with each proposition (``ap``) last, and only if all its
    faces are on the plane for ``ap`` (else None: a cross-section, not the whole set)."""
    d = list(dims)
    others = [i for i in range(problem.switched_system.n) if i not in d]
    out = []
    for j, name, H, c, ap in _atoms(problem):
        on_plane = np.all(H[:, others] == 0.0, axis=1) if others else np.ones(H.shape[0], dtype=bool)
        if not on_plane.all():
            logger.debug(
                "plot_workspace: %s: %d face(s) on other coordinates than %s not drawn",
                name,
                int((~on_plane).sum()),
                tuple(d),
            )
        if on_plane.any():
            out.append((j, name, H[on_plane][:, d], c[on_plane], ap if on_plane.all() else None))
    return out


def _halfplane_groups(
    problem: Any, atoms: list[tuple[int, str, np.ndarray, np.ndarray, Any]]
) -> list[list[int]]:
    """Disjunctions of half-planes: per ``STLOr`` of the formula whose operands are all
    propositions of one face on the plane (``left | right | below | above``: the complement of an
    obstacle), the positions in ``atoms`` of its operands. A proposition joins one group at most.
    """
    from .formulas import STLAtomicProposition, STLOr

    where = {id(ap): i for i, (_, _, H, _, ap) in enumerate(atoms) if ap is not None and H.shape[0] == 1}
    groups: list[list[int]] = []
    taken: set[int] = set()
    for node in problem.stl_formula.walk():
        if not isinstance(node, STLOr):
            continue
        kids = node.children
        if not all(isinstance(k, STLAtomicProposition) and id(k) in where for k in kids):
            continue
        members = list(dict.fromkeys(where[id(k)] for k in kids))
        if len(members) >= 2 and not taken.intersection(members):
            groups.append(members)
            taken.update(members)
    return groups


def _bounded_box(H: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Bounding box of ``{y : H y + c <= 0}`` in the plane, or None when unbounded or empty."""
    from .sets import Polytope

    try:
        low, high = Polytope(H, c).bounding_box()
    except IdstlpyError:
        return None
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))) or np.any(low > high):
        return None
    return low, high


# ----------------------------------------------------------------------------------------------
# Helpers


def _axes(ax: Any, figsize: tuple[float, float] = (9.0, 5.5)) -> tuple[Any, Any]:
    if ax is None:
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=figsize, layout="constrained")
        return fig, ax
    return ax.figure, ax


def _check_problem(problem: Any) -> None:
    from .formulas import STLFormula

    if not isinstance(getattr(problem, "stl_formula", None), STLFormula) or not hasattr(
        problem, "switched_system"
    ):
        raise InvalidTypeError(f"problem must be a Problem, got {type(problem).__name__}")


def _check_traj(traj: Any, what: str, n: int | None) -> None:
    from .trajectory import ProbabilisticTSTrajectory, RealTrajectory

    if not isinstance(traj, ProbabilisticTSTrajectory | RealTrajectory):
        raise InvalidTypeError(f"{what} must be a trajectory, got {type(traj).__name__}")
    dim = traj.n
    if n is not None and dim != n:
        raise DimensionError(f"{what} has state dimension {dim}, the problem has n = {n}")


def _check_dims(dims: Any, n: int) -> tuple[int, int]:
    if n < 2:
        raise DimensionError(
            f"a workspace plot needs two state coordinates; the state has n = {n}: use plot_time_series"
        )
    try:
        d = tuple(int(i) for i in dims)
    except (TypeError, ValueError) as exc:
        raise DimensionError(f"dims must be two different coordinates in 0..{n - 1}, got {dims!r}") from exc
    if len(d) != 2 or not all(0 <= i < n for i in d) or d[0] == d[1]:
        raise DimensionError(f"dims must be two different coordinates in 0..{n - 1}, got {dims!r}")
    return d[0], d[1]


def _extent(
    initial_mean: np.ndarray, boxes: list[tuple[np.ndarray, np.ndarray]], trajs: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    pts = [initial_mean[None, :]] + [np.vstack(b) for b in boxes] + [t for t in trajs if t.size]
    allp = np.vstack(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.08 * np.maximum(hi - lo, 1.0)
    return lo - pad, hi + pad


def _place_legend(ax: Any, proxies: list[Any], where: LegendPlacement) -> Any:
    """A legend of the labelled artists and ``proxies``, outside the axes or at the best place."""
    if where is False or where is None:
        return None
    handles, labels = ax.get_legend_handles_labels()
    handles = list(handles) + list(proxies)
    labels = list(labels) + [p.get_label() for p in proxies]
    if not handles:
        return None
    if where is True or where == "outside":
        return ax.legend(
            handles, labels, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize="small"
        )
    if isinstance(where, str):
        return ax.legend(handles, labels, loc=where, fontsize="small")
    raise InvalidArgumentError(
        f"legend must be True, False, 'outside' or a matplotlib location, got {where!r}"
    )


def _light_norm(norm: Any, values: np.ndarray) -> Any:
    from matplotlib.colors import LogNorm, Normalize

    finite = values[np.isfinite(values)]
    if norm is None or norm == "linear":
        return None
    if norm == "log":
        if finite.size and float(finite.min()) > 0.0 and float(finite.max()) > 10.0 * float(finite.min()):
            return LogNorm(vmin=float(finite.min()), vmax=float(finite.max()))
        return None
    if isinstance(norm, Normalize):
        return norm
    raise InvalidArgumentError(
        f"light_norm must be None, 'linear', 'log' or a matplotlib Normalize, got {norm!r}"
    )


def _mode_color(q: int) -> str:
    return MODE_COLORS[int(q) % len(MODE_COLORS)]


def _mode_text(problem: Any, q: int) -> str:
    """What mode ``q`` does: how it senses (``"blind"``, ``"senses, noise std 0.1"``, ``"senses,
    noise varies with the state"``) and, when ``B = 0``, ``"stands still"`` (``A = I``: the mean
    stays) or ``"no input"`` (the state drifts by ``A``)."""
    md = problem.switched_system.mode(int(q))
    if not md.p:
        parts = ["blind"]
    elif md.has_state_dependent_noise:
        parts = ["senses, noise varies with the state"]
    else:
        # The largest standard deviation of the (constant) sensor noise: what tells a precise
        # sensor from a poor one in the legend.
        std = float(np.sqrt(max(np.linalg.eigvalsh(md.noise_floor).max(initial=0.0), 0.0)))
        parts = ["senses, noise-free" if std == 0 else f"senses, noise std {std:.3g}"]
    if not np.any(md.B):
        still = np.array_equal(md.A, np.eye(md.n))  # the mean stays; noise may still move x
        parts.append("stands still: B = 0" if still else "no input: B = 0")
    return ", ".join(parts)


def _draw_sensing(ax: Any, problem: Any, plan: Any, d: list[int], out: Any, proxies: list[Any]) -> None:
    """A dot in the mode's colour at the belief each observation of the plan updates."""
    from matplotlib.lines import Line2D

    modes = problem.switched_system.system_modes
    actions = plan.get_action()
    steps = np.array([k for k in range(plan.num_of_steps) if modes[int(actions[k])].p > 0], dtype=int)
    if not steps.size:
        return
    pts = plan.get_mean()[steps + 1][:, d]
    out.sensing = ax.scatter(
        pts[:, 0],
        pts[:, 1],
        s=30,
        c=[_mode_color(int(actions[k])) for k in steps],
        edgecolors="black",
        linewidths=0.7,
        zorder=4.6,
    )
    proxies.append(
        Line2D(
            [],
            [],
            ls="none",
            marker="o",
            ms=6,
            mfc="0.8",
            mec="black",
            mew=0.7,
            label=f"sensing step ({steps.size} of {plan.num_of_steps}): the belief it updates",
        )
    )


def _annotate_still(ax: Any, points: np.ndarray) -> list[Any]:
    """``"n steps in place"`` where consecutive means (k, 2) do not move (a look with ``B = 0``)."""
    if len(points) < 3:
        return []
    scale = max(1.0, float(np.max(np.abs(points))))
    still = np.linalg.norm(np.diff(points, axis=0), axis=1) <= 1e-9 * scale
    notes = []
    k = 0
    while k < still.size:
        if not still[k]:
            k += 1
            continue
        k1 = k
        while k1 < still.size and still[k1]:
            k1 += 1
        if k1 - k >= 2:
            notes.append(
                ax.annotate(
                    f"{k1 - k} steps in place (k = {k}..{k1})",
                    xy=tuple(points[k]),
                    xytext=(9, 4),
                    textcoords="offset points",
                    fontsize="x-small",
                    zorder=8,
                    bbox={
                        "boxstyle": "round,pad=0.15",
                        "facecolor": "white",
                        "edgecolor": "none",
                        "alpha": 0.7,
                    },
                )
            )
        k = k1
    return notes


def _fill(color: str, alpha: float = 0.13) -> tuple[float, float, float, float]:
    from matplotlib.colors import to_rgba

    return to_rgba(color, alpha)


def _centroid(verts: np.ndarray) -> np.ndarray:
    """The area centroid of a simple polygon (v, 2) (its vertex mean when degenerate)."""
    x, y = verts[:, 0], verts[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2.0
    if abs(area) <= 1e-12 * max(1.0, float(np.max(np.abs(verts))) ** 2):
        return verts.mean(axis=0)
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6.0 * area)


def _label_spot(
    verts: np.ndarray,
    avoid: np.ndarray,
    blockers: list[np.ndarray],
    lo: np.ndarray,
    hi: np.ndarray,
) -> np.ndarray:
    """Where to write a region's name: inside it, off the drawn trajectories and other labels.

    The centroid when it is clear (5% of the view from every point of ``avoid`` (k, 2) and
    outside every polygon of ``blockers``), else the clearest of points near the corners and
    the edges' middles, moved into the region; when none of those is 3% of the view clear (a
    small region the plan crosses), just above or below the region.
    """
    from matplotlib.path import Path as MplPath

    span = np.maximum(hi - lo, 1e-12)
    centre = _centroid(verts)
    nxt = np.roll(verts, -1, axis=0)
    cands = [centre]
    for t in (0.2, 0.35):
        cands += list(verts + t * (centre - verts))
        cands += list(0.5 * (verts + nxt) + t * (centre - 0.5 * (verts + nxt)))
    paths = [MplPath(b) for b in blockers if len(b) >= 3]

    def clearance(p: np.ndarray) -> float:
        score = float(np.min(np.linalg.norm((avoid - p) / span, axis=1))) if len(avoid) else 1.0
        if any(path.contains_point((float(p[0]), float(p[1]))) for path in paths):
            score -= 10.0  # on another region or the obstacle: only when nothing else is free
        return score

    best, best_score = centre, -np.inf
    for i, p in enumerate(cands):
        score = clearance(p)
        if i == 0 and score >= 0.05:
            return p
        if score > best_score + 1e-9:
            best, best_score = p, score
    if best_score < 0.03:
        gap = 0.04 * span[1]
        for p in (
            np.array([centre[0], verts[:, 1].max() + gap]),
            np.array([centre[0], verts[:, 1].min() - gap]),
        ):
            inside = lo[1] + gap <= p[1] <= hi[1] - gap
            if inside and (score := clearance(p)) > best_score + 0.01:
                best, best_score = p, score
    return best


def _region_text(ax: Any, point: np.ndarray, name: str, color: str) -> Any:
    cx, cy = point
    return ax.text(
        cx,
        cy,
        name,
        ha="center",
        va="center",
        fontsize="small",
        color=color,
        fontweight="bold",
        zorder=7.5,
        clip_on=True,
        bbox={"boxstyle": "round,pad=0.2", "facecolor": "white", "edgecolor": "none", "alpha": 0.65},
    )


def _obstacle_boxes(problem: Any, d: list[int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Bounding boxes of the obstacles left out by disjunctions of half-planes (to keep them in view)."""
    atoms = _plane_atoms(problem, d)
    out = []
    for group in _halfplane_groups(problem, atoms):
        H = np.vstack([atoms[i][2] for i in group])
        c = np.concatenate([atoms[i][3] for i in group])
        box = _bounded_box(-H, -c)
        if box is not None:
            out.append(box)
    return out


def _draw_regions(
    ax: Any, problem: Any, d: list[int], lo: np.ndarray, hi: np.ndarray, out: Any
) -> list[tuple[str, np.ndarray, str]]:
    """Fill each proposition's region; a disjunction of half-planes as one union, its obstacle hatched.

    Returns the labels to write, ``(name, polygon (v, 2), colour)``, once the trajectories are
    drawn (:func:`_write_region_labels` keeps them off the trajectories).
    """
    from matplotlib.patches import PathPatch, Polygon
    from matplotlib.path import Path as MplPath

    atoms = _plane_atoms(problem, d)
    groups = _halfplane_groups(problem, atoms)
    grouped = {i for g in groups for i in g}
    labels: list[tuple[str, np.ndarray, str]] = []
    for i, (j, name, H, c, _) in enumerate(atoms):
        if i in grouped:
            continue
        verts = clip_halfplanes(H, c, lo, hi)
        if not len(verts):
            logger.debug("plot_workspace: region %s is empty in view", name)
            continue
        style = _region_style(j)
        poly = Polygon(
            verts,
            closed=True,
            facecolor=_fill(style["color"]),
            edgecolor=style["color"],
            linestyle=style["linestyle"],
            linewidth=1.5,
            label=name,
            zorder=2,
        )
        ax.add_patch(poly)
        out.regions[name] = poly
        labels.append((name, verts, style["color"]))
    view = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    for group in groups:
        members = [atoms[i] for i in group]
        label = " | ".join(m[1] for m in members)
        color = _region_style(members[0][0])["color"]
        H = np.vstack([m[2] for m in members])
        c = np.concatenate([m[3] for m in members])
        hole = clip_halfplanes(-H, -c, lo, hi)  # outside every operand: the obstacle
        outer = MplPath(np.vstack([view, view[:1]]), closed=True)
        if len(hole):
            ring = hole if _area(hole) < 0 else hole[::-1]  # clockwise: a hole in the view
            inner = MplPath(np.vstack([ring, ring[:1]]), closed=True)
            path = MplPath.make_compound_path(outer, inner)
        else:
            path = outer
        union = PathPatch(
            path, facecolor=_fill(color), edgecolor="none", label=f"{label} (one of them holds)", zorder=1.9
        )
        ax.add_patch(union)
        out.region_groups[label] = union
        if len(hole):
            obstacle = Polygon(
                hole,
                closed=True,
                facecolor=_fill("0.3", 0.3),
                edgecolor=color,
                hatch="//",
                linewidth=1.5,
                label=f"obstacle: not ({label})",
                zorder=2.1,
            )
            ax.add_patch(obstacle)
            out.obstacles[label] = obstacle
        for _, name, Hm, cm, _ in members:
            out.regions[name] = union
            verts = clip_halfplanes(Hm, cm, lo, hi)
            if len(verts):
                labels.append((name, verts, color))
    return labels


def _write_region_labels(
    ax: Any,
    labels: list[tuple[str, np.ndarray, str]],
    avoid: list[np.ndarray],
    lo: np.ndarray,
    hi: np.ndarray,
    out: Any,
) -> None:
    """Write each region's name where :func:`_label_spot` finds room (smaller regions first)."""
    dense = []
    for a in avoid:  # the trajectories' segments too, not only their points
        if len(a) >= 2:
            dense += [a[:-1] + t * (a[1:] - a[:-1]) for t in (0.25, 0.5, 0.75)]
    points = np.vstack([a for a in [*avoid, *dense] if a.size] or [np.zeros((0, 2))])
    areas = {name: abs(_area(verts)) for name, verts, _ in labels}
    obstacles = [np.asarray(o.get_xy()) for o in out.obstacles.values()]
    placed: list[np.ndarray] = []
    for name, verts, color in sorted(labels, key=lambda t: areas[t[0]]):
        smaller = [
            v
            for other, v, _ in labels
            if areas[other] < areas[name]
            and other != name
            and out.regions.get(other) is not None
            and out.regions[other] not in out.region_groups.values()
        ]
        spot = _label_spot(
            verts, np.vstack([points, *placed]) if placed else points, obstacles + smaller, lo, hi
        )
        placed.append(spot[None, :])
        out.region_labels[name] = _region_text(ax, spot, name, color)


def _area(verts: np.ndarray) -> float:
    x, y = verts[:, 0], verts[:, 1]
    return float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) / 2.0)


def _workspace_caption(out: Any, shade: str, every: int | None) -> str:
    """What the ellipses, the shading and the regions of a workspace figure are."""
    parts = []
    if out.plan_ellipses or out.executed_ellipses:
        who = []
        if out.plan_ellipses:
            who.append("planned (blue" + (f", every {every} steps" if every and every > 1 else "") + ")")
        if out.executed_ellipses:
            who.append("executed (orange)")
        parts.append("Ellipses: 95% confidence regions of the belief, " + " and ".join(who) + ".")
    if out.predicted_ellipses:
        parts.append("Dashed dark red: 95% of the predicted true state.")
    if out.light is not None:
        parts.append(f"Shading: {shade} (see the colorbar).")
    elif out.light_constant is not None:
        parts.append(f"No shading: {shade} is {out.light_constant:.3g} everywhere.")
    if out.regions:
        parts.append(
            "Filled regions: where each proposition holds for a belief without uncertainty "
            "(the mean needs room for its covariance)."
        )
    if out.obstacles:
        parts.append("Hatched: the obstacle, outside every operand of a disjunction.")
    return " ".join(parts)


def _add_caption(out: Any, text: str) -> Any:
    """``text`` wrapped under the axes (under the colorbar when there is one)."""
    if not text:
        return None
    anchor = out.colorbar.ax if out.colorbar is not None else out.ax
    offset = -42 if out.colorbar is not None else -34
    return anchor.annotate(
        textwrap.fill(text, 95),
        xy=(0.0, 0.0),
        xycoords="axes fraction",
        xytext=(0, offset),
        textcoords="offset points",
        ha="left",
        va="top",
        fontsize="x-small",
        color="0.25",
        annotation_clip=False,
    )


# ----------------------------------------------------------------------------------------------
# Workspace


def plot_workspace(
    problem: Any,
    plan: Any = None,
    executed: Any = None,
    real: Any = None,
    ax: Any = None,
    light: Callable[[np.ndarray], np.ndarray] | None = None,
    *,
    dims: Sequence[int] = (0, 1),
    ellipse_every: int | None = None,
    resolution: int = 120,
    legend: LegendPlacement = "outside",
    light_label: str | None = None,
    light_cmap: str = "gray",
    light_norm: Any = None,
    colorbar: bool = True,
    show_modes: bool | None = None,
    light_legend: str | None = None,
    predicted: Any = None,
    caption: bool = True,
    include: np.ndarray | None = None,
) -> WorkspaceArtists:
    """Draw a problem's workspace with a plan and an execution, in two chosen state coordinates.

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
        Where to draw (default: a new figure with a constrained layout).
    light : callable, optional
        ``light(points (k, 2)) -> (k,)``: a map to shade over the view (points in the ``dims``
        coordinates), e.g. :func:`sensor_noise_std` or :func:`sensor_light`.
    dims : sequence of two int
        The two state coordinates to draw (any two of ``0..n-1``). A proposition is drawn by its
        faces on these two coordinates (the cross-section of the set it describes); faces on
        other coordinates are not drawn.
    ellipse_every : int, optional
        Draw a covariance ellipse every this many steps (default: about 25 per trajectory).
    resolution : int
        Grid points per axis of the shading.
    legend : bool or str
        ``"outside"`` (default, or True): right of the axes, off the data; a matplotlib
        location such as ``"best"`` to place it inside; False for none.
    light_label : str, optional
        What the shading shows: the colorbar's label and the legend entry (default
        ``"sensing quality (brighter is better)"``).
    light_cmap : str
        Colormap of the shading (``"gray"``: brighter for higher values; ``"gray_r"`` for lower).
    light_norm : None, "linear", "log" or matplotlib Normalize
        Scaling of the shading (``"log"`` falls back to linear for values not all positive or
        spanning less than a decade).
    colorbar : bool
        Add a colorbar under the axes for the shading.
    show_modes : bool, optional
        Colour the plan by the mode applied along each segment (default: when the system has
        more than one mode).
    light_legend : str, optional
        A shorter name of the shading for the legend (default ``light_label``).
    predicted : ClosedLoopPrediction, optional
        A prediction of the execution (:func:`~idstlpy.execution.prediction.predict_closed_loop`
        or ``validate(..., predict=True).predicted``): its true-state mean (dotted red) and 95%
        ellipses of the true state (dashed red), every ``ellipse_every`` steps.
    caption : bool
        Write under the axes what the ellipses, the shading and the regions are.
    include : ndarray, shape (k, 2), optional
        Points of the plane (coordinates ``dims``) the axes must include as well (the runs of
        :func:`plot_monte_carlo`).

    Returns
    -------
    WorkspaceArtists

    Notes
    -----
    Each proposition's region (the means that satisfy its chance constraints at zero
    covariance) is filled and labelled with its name (an unnamed one with its constraints). The
    operands of a disjunction of half-planes (an obstacle avoided as ``left | right | below |
    above``) are filled as one region, their union, and the obstacle they leave out is hatched.
    The start (initial mean) and the end of the plan are marked; with the modes shown, each
    sensing step is a dot in its mode's colour, the legend says which modes sense, which are
    blind and which stand still (``B = 0``), and a mean that stays put for several steps is
    annotated. A shading that is the same everywhere (constant sensor noise) is not drawn: the
    legend gives its value instead of a colorbar.

    Raises
    ------
    DimensionError
        When ``dims`` are not two different coordinates (or the state is 1-D: use
        :func:`plot_time_series`), or a trajectory's dimension is not the problem's.
    InvalidTypeError
        When ``problem`` is not a problem or a trajectory is not a trajectory.
    """
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    _check_problem(problem)
    n = problem.switched_system.n
    d0, d1 = _check_dims(dims, n)
    d = [d0, d1]
    for traj, what in ((plan, "plan"), (executed, "executed"), (real, "real")):
        if traj is not None:
            _check_traj(traj, what, n)
    if predicted is not None:
        _check_prediction(predicted, n)
    resolution = int(resolution)
    if resolution < 2:
        raise InvalidArgumentError(f"resolution must be >= 2, got {resolution}")
    fig, ax = _axes(ax)
    out = WorkspaceArtists(figure=fig, ax=ax, dims=(d0, d1))
    proxies: list[Any] = []

    halfplanes = _proposition_halfplanes(problem, d)
    boxes = [b for b in (_bounded_box(H, c) for _, _, H, c in halfplanes) if b is not None]
    boxes += _obstacle_boxes(problem, d)
    trajs = [t.get_mean()[:, d] for t in (plan, executed) if t is not None]
    if real is not None:
        trajs.append(real.get_state()[:, d])
    if predicted is not None:
        trajs.append(predicted.state_mean[:, d])
    if include is not None:
        trajs.append(np.asarray(include, dtype=float).reshape(-1, 2))
    lo, hi = _extent(np.asarray(problem.initial_state.mean, dtype=float)[d], boxes, trajs)

    if light is not None:
        xs = np.linspace(lo[0], hi[0], resolution)
        ys = np.linspace(lo[1], hi[1], resolution)
        X, Y = np.meshgrid(xs, ys)
        pts = np.column_stack([X.ravel(), Y.ravel()])
        vals = np.asarray(light(pts), dtype=float)
        if vals.shape != (pts.shape[0],):
            raise DimensionError(f"light must map points (k, 2) to values (k,), got shape {vals.shape}")
        label = light_label or "sensing quality (brighter is better)"
        finite = vals[np.isfinite(vals)]
        if finite.size and float(np.ptp(finite)) <= 1e-9 * max(float(np.abs(finite).max()), 1e-300):
            out.light_constant = float(finite[0])
    if light is not None and out.light_constant is not None:
        proxies.append(
            Patch(
                facecolor="none",
                edgecolor="none",
                label=f"{light_legend or label}: {out.light_constant:.3g} everywhere (constant: not shaded)",
            )
        )
    elif light is not None:
        out.light = ax.imshow(
            vals.reshape(X.shape),
            origin="lower",
            extent=(lo[0], hi[0], lo[1], hi[1]),
            cmap=light_cmap,
            norm=_light_norm(light_norm, vals),
            aspect="auto",
            alpha=0.8,
            zorder=0,
            interpolation="bilinear",
        )
        name = light_legend or label
        proxies.append(
            Patch(
                facecolor="0.55",
                edgecolor="0.3",
                alpha=0.8,
                label=f"shading: {name}" + (" (colorbar)" if colorbar and light_legend else ""),
            )
        )
        if colorbar:
            out.colorbar = fig.colorbar(
                out.light, ax=ax, location="bottom", fraction=0.05, pad=0.02 if _constrained(fig) else 0.12
            )
            out.colorbar.set_label(label, fontsize="small")

    region_labels = _draw_regions(ax, problem, d, lo, hi, out)

    def every(traj: Any) -> int:
        return ellipse_every or max(1, (traj.num_of_steps + 1) // 25)

    if plan is not None:
        m = plan.get_mean()
        colour_modes = problem.switched_system.num_modes > 1 if show_modes is None else bool(show_modes)
        if colour_modes and plan.num_of_steps:
            segments = np.stack([m[:-1, d], m[1:, d]], axis=1)
            actions = plan.get_action()
            out.modes = LineCollection(
                list(segments),
                colors=[_mode_color(q) for q in actions],
                linewidths=4.0,
                alpha=0.85,
                zorder=3.5,
            )
            ax.add_collection(out.modes)
            for q in sorted(set(actions.tolist())):
                proxies.append(
                    Line2D(
                        [],
                        [],
                        color=_mode_color(q),
                        lw=4.0,
                        alpha=0.85,
                        label=f"plan: mode {q} ({_mode_text(problem, q)})",
                    )
                )
            _draw_sensing(ax, problem, plan, d, out, proxies)
        (out.plan,) = ax.plot(
            m[:, d[0]],
            m[:, d[1]],
            "-",
            color="black" if out.modes is not None else "tab:blue",
            lw=0.9 if out.modes is not None else 1.5,
            label="plan: mean",
            zorder=4,
        )
        out.still = _annotate_still(ax, m[:, d])
        for k in range(0, plan.num_of_steps + 1, every(plan)):
            e = _ellipse(m[k, d], plan.get_cov(k)[np.ix_(d, d)], fill=False, ec="tab:blue", lw=0.6, zorder=3)
            ax.add_patch(e)
            out.plan_ellipses.append(e)
        if out.plan_ellipses:
            proxies.append(
                Line2D(
                    [],
                    [],
                    ls="none",
                    marker="o",
                    ms=9,
                    mfc="none",
                    mec="tab:blue",
                    mew=0.8,
                    label="plan: 95% covariance ellipses",
                )
            )
    if executed is not None:
        m = executed.get_mean()
        (out.executed,) = ax.plot(
            m[:, d[0]], m[:, d[1]], "-", color="tab:orange", lw=1.2, label="executed belief: mean", zorder=5
        )
        for k in range(0, executed.num_of_steps + 1, every(executed)):
            cov = executed.get_cov(k)[np.ix_(d, d)]
            e = _ellipse(m[k, d], cov, fill=False, ec="tab:orange", lw=0.5, zorder=3)
            ax.add_patch(e)
            out.executed_ellipses.append(e)
        if out.executed_ellipses:
            proxies.append(
                Line2D(
                    [],
                    [],
                    ls="none",
                    marker="o",
                    ms=9,
                    mfc="none",
                    mec="tab:orange",
                    mew=0.8,
                    label="executed: 95% covariance ellipses",
                )
            )
    if real is not None:
        obs = real.get_observation()
        if obs.ndim == 2 and obs.shape[1] > max(d):
            ok = np.all(np.isfinite(obs[:, d]), axis=1)
            if ok.any():
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
    if predicted is not None:
        _draw_prediction(ax, predicted, d, ellipse_every, out, proxies)
    start = np.asarray(problem.initial_state.mean, dtype=float)[d]
    (out.start,) = ax.plot(
        [start[0]],
        [start[1]],
        ls="none",
        marker="o",
        ms=9,
        mfc="white",
        mec="black",
        mew=1.5,
        label="start (initial mean)",
        zorder=8,
    )
    last = plan if plan is not None else executed
    if last is not None:
        end = last.get_mean()[-1, d]
        (out.end,) = ax.plot(
            [end[0]],
            [end[1]],
            ls="none",
            marker="*",
            ms=15,
            mfc="gold",
            mec="black",
            mew=1.0,
            label="end of plan" if plan is not None else "end of execution",
            zorder=8,
        )
    _write_region_labels(ax, region_labels, [*trajs, start[None, :]], lo, hi, out)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    # One unit is one unit on both axes, so a round covariance is drawn round; a very elongated
    # workspace (a corridor) keeps the free aspect rather than a sliver of a figure.
    spans = np.asarray(hi, dtype=float)[:2] - np.asarray(lo, dtype=float)[:2]
    if np.all(spans > 0) and max(spans) / min(spans) <= 5.0:
        ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel(f"x[{d[0]}]")
    ax.set_ylabel(f"x[{d[1]}]")
    out.legend_proxies = proxies
    out.legend = _place_legend(ax, proxies, legend)
    if caption:
        every_plan = every(plan) if plan is not None else None
        shade = light_legend or light_label or "sensing quality"
        out.caption = _add_caption(out, _workspace_caption(out, shade, every_plan))
    return out


def _check_prediction(predicted: Any, n: int) -> None:
    from .execution import ClosedLoopPrediction

    if not isinstance(predicted, ClosedLoopPrediction):
        raise InvalidTypeError(
            f"predicted must be a ClosedLoopPrediction (predict_closed_loop, or validate(predict=True)"
            f".predicted), got {type(predicted).__name__}"
        )
    if predicted.n != n:
        raise DimensionError(f"predicted has state dimension {predicted.n}, the problem has n = {n}")


def _draw_prediction(
    ax: Any,
    predicted: Any,
    d: list[int],
    ellipse_every: int | None,
    out: WorkspaceArtists,
    proxies: list[Any],
) -> None:
    """The predicted true-state mean and 95% ellipses (red like the true state, dashed: a forecast)."""
    from matplotlib.lines import Line2D

    mean, cov = predicted.state_mean, predicted.state_cov
    steps = mean.shape[0]
    (out.predicted,) = ax.plot(
        mean[:, d[0]],
        mean[:, d[1]],
        ":",
        color="darkred",
        lw=1.2,
        label="predicted true state: mean",
        zorder=6.5,
    )
    every = ellipse_every or max(1, steps // 25)
    for k in range(0, steps, every):
        e = _ellipse(mean[k, d], cov[k][np.ix_(d, d)], fill=False, ec="darkred", ls="--", lw=0.7, zorder=6.5)
        ax.add_patch(e)
        out.predicted_ellipses.append(e)
    if out.predicted_ellipses:
        proxies.append(
            Line2D(
                [],
                [],
                ls="none",
                marker="o",
                ms=9,
                mfc="none",
                mec="darkred",
                mew=0.8,
                label="predicted true state: 95% ellipses",
            )
        )


def _constrained(fig: Any) -> bool:
    engine = fig.get_layout_engine() if hasattr(fig, "get_layout_engine") else None
    return engine is not None and type(engine).__name__ == "ConstrainedLayoutEngine"


def _plan_mode(problem: Any, plan: Any) -> int | None:
    """The observing mode the plan uses most (ties: the lowest), else the first observing mode."""
    modes = list(problem.switched_system.system_modes)
    observing = [q for q, md in enumerate(modes) if md.p]
    if not observing:
        return None
    if plan is not None and plan.num_of_steps:
        counts = np.bincount(plan.get_action(), minlength=len(modes))
        used = [q for q in observing if counts[q] > 0]
        if used:
            return max(used, key=lambda q: (counts[q], -q))
    return observing[0]


def plot_light_dark(
    problem: Any,
    plan: Any = None,
    executed: Any = None,
    real: Any = None,
    ax: Any = None,
    light: Callable[[np.ndarray], np.ndarray] | None = None,
    *,
    mode: int | None = None,
    **kwargs: Any,
) -> WorkspaceArtists:
    """:func:`plot_workspace` shaded by the sensor: the noise std of the plan's mode (brighter: less noise).

    Parameters
    ----------
    problem : Problem
        Supplies the formula's regions, the sensor and the initial belief.
    plan : ProbabilisticTSTrajectory, optional
        As in :func:`plot_workspace`.
    executed : ProbabilisticTSTrajectory, optional
        As in :func:`plot_workspace`.
    real : RealTrajectory, optional
        As in :func:`plot_workspace`.
    ax : matplotlib Axes, optional
        As in :func:`plot_workspace`.
    light : callable, optional
        Overrides the sensor-derived map (then shaded as in :func:`plot_workspace`).
    mode : int, optional
        Whose sensor to show (default: the observing mode the plan uses most, else the first
        observing mode). Its :func:`sensor_noise_std` is shaded on a log scale, the other state
        coordinates taken from the initial mean.
    **kwargs
        Passed to :func:`plot_workspace` (``dims``, ``legend``, ``colorbar``...).

    Returns
    -------
    WorkspaceArtists
    """
    _check_problem(problem)
    if light is None:
        q = _plan_mode(problem, plan) if mode is None else int(mode)
        dims = kwargs.get("dims", (0, 1))
        if q is not None and problem.switched_system.n >= 2:
            _check_dims(dims, problem.switched_system.n)
            light = sensor_noise_std(problem, q, dims=dims)
        if light is not None:
            kwargs.setdefault(
                "light_label", f"sensor noise std of mode {q} (RMS over outputs; brighter is less noise)"
            )
            kwargs.setdefault("light_legend", f"sensor noise std of mode {q}")
            kwargs.setdefault("light_cmap", "gray_r")
            kwargs.setdefault("light_norm", "log")
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
    dims: Sequence[int] = (0, 1),
    legend: LegendPlacement = "outside",
    colorbar: bool = True,
    predicted: Any = None,
) -> MonteCarloArtists:
    """Overlay many executions of a plan; the title gives the success rate(s).

    A problem of one state has no workspace plane: the executions are overlaid on its time
    series (:func:`plot_time_series` with ``executions=``; a single ``ax`` draws the state
    alone, without the inputs' and modes' axes).

    Parameters
    ----------
    problem : Problem
        Supplies the formula's regions, the sensor and the initial belief.
    plan : ProbabilisticTSTrajectory
        The plan (dashed, above the executions).
    executions : sequence of (ProbabilisticTSTrajectory, RealTrajectory)
        E.g. ``ValidationReport.executions``.
    report : ValidationReport, optional
        Supplies the belief / state success rates and their confidence intervals.
    ax : matplotlib Axes, optional
        Where to draw (default: a new figure); for a one-state problem, an Axes or the axes of
        :func:`plot_time_series`.
    light : callable, optional
        As in :func:`plot_light_dark` (default: the sensor noise of the plan's mode).
    success_rate : float, optional
        Used in the title when no report is given.
    dims : sequence of two int
        The two state coordinates to draw.
    legend : bool or str
        As in :func:`plot_workspace`.
    colorbar : bool
        Add the shading's colorbar.
    predicted : ClosedLoopPrediction or False, optional
        Draw the predicted true-state mean and 95% ellipses (see :func:`plot_workspace`); default
        the report's prediction (``validate(..., predict=True)``), if any; False: none.

    Returns
    -------
    MonteCarloArtists
    """
    from matplotlib.lines import Line2D

    _check_problem(problem)
    if problem.switched_system.n == 1:
        single = ax is not None and not isinstance(ax, list | tuple | np.ndarray)
        ts = plot_time_series(
            problem,
            plan,
            axes=[ax] if single else ax,
            executions=executions,
            controls=not single,
            modes=not single,
            legend=legend,
        )
        one = MonteCarloArtists(
            figure=ts.figure,
            ax=ts.ax,
            workspace=None,
            executed=list(ts.runs_executed.get(0, [])),
            real=list(ts.runs_real.get(0, [])),
            legend=ts.legend,
            time_series=ts,
        )
        one.title = ts.ax.set_title(
            _monte_carlo_title(report, success_rate, len(executions)), fontsize="small"
        )
        return one
    if predicted is None and report is not None:
        predicted = getattr(report, "predicted", None)
    if predicted is False:
        predicted = None
    n = problem.switched_system.n
    d = list(_check_dims(dims, n))
    for i, pair in enumerate(executions):
        if not isinstance(pair, tuple | list) or len(pair) != 2:
            raise InvalidArgumentError(f"executions[{i}] must be a pair (executed belief, real trajectory)")
        _check_traj(pair[0], f"executions[{i}][0]", n)
        _check_traj(pair[1], f"executions[{i}][1]", n)
    runs = [p[0].get_mean()[:, d] for p in executions] + [p[1].get_state()[:, d] for p in executions]
    ws = plot_light_dark(
        problem,
        plan,
        ax=ax,
        light=light,
        dims=dims,
        legend=False,
        colorbar=colorbar,
        predicted=predicted,
        include=_run_window(problem, plan, d, runs),
    )
    ax = ws.ax
    if ws.plan is not None:  # keep the plan visible above the executions that track it
        ws.plan.set_zorder(7)
        ws.plan.set_linestyle("--")
    out = MonteCarloArtists(figure=ws.figure, ax=ax, workspace=ws)
    for xs, xr in executions:
        m = xs.get_mean()
        (line,) = ax.plot(m[:, d[0]], m[:, d[1]], color="tab:orange", lw=0.6, alpha=0.35, zorder=5)
        out.executed.append(line)
        s = xr.get_state()
        (rline,) = ax.plot(s[:, d[0]], s[:, d[1]], color="tab:red", lw=0.5, alpha=0.35, zorder=6)
        out.real.append(rline)
    clipped = _mark_clipped(ax, [p[1].get_state()[:, d] for p in executions], out)
    title = _monte_carlo_title(report, success_rate, len(executions))
    if clipped:
        title += f"\n{clipped} true-state runs leave the axes (x: where they leave)"
    out.title = ax.set_title(title, fontsize="small")
    proxies = list(ws.legend_proxies)
    if clipped:
        proxies.append(
            Line2D([], [], color="tab:red", marker="x", ls="none", label=f"leaves the axes ({clipped} runs)")
        )
    if out.executed:
        proxies.append(
            Line2D([], [], color="tab:orange", lw=0.8, label=f"executed beliefs ({len(out.executed)})")
        )
        proxies.append(Line2D([], [], color="tab:red", lw=0.8, label=f"true states ({len(out.real)})"))
        if ws.caption is not None:
            text = ws.caption.get_text().replace("\n", " ")
            text += (
                f" Thin lines: {len(out.executed)} executions "
                "(orange: executed belief means, red: true states)."
            )
            ws.caption.set_text(textwrap.fill(text, 95))
    out.legend = _place_legend(ax, proxies, legend)
    return out


RUN_WINDOW = 4.0
"""How far (in spans of the plan's own extent) the Monte Carlo axes reach to include every run;
a run beyond it is clipped and marked where it leaves."""


def _run_window(problem: Any, plan: Any, d: list[int], runs: list[np.ndarray]) -> np.ndarray | None:
    """The corners (2, 2) of the runs' extent, cut at :data:`RUN_WINDOW` spans around the
    plan's own (start, regions, plan); None without runs."""
    points = [r for r in runs if r.size and np.isfinite(r).all()]
    if not points:
        return None
    halfplanes = _proposition_halfplanes(problem, d)
    boxes = [b for b in (_bounded_box(H, c) for _, _, H, c in halfplanes) if b is not None]
    boxes += _obstacle_boxes(problem, d)
    own = [plan.get_mean()[:, d]] if plan is not None else []
    lo, hi = _extent(np.asarray(problem.initial_state.mean, dtype=float)[d], boxes, own)
    span = hi - lo
    allp = np.vstack(points)
    low = np.maximum(allp.min(axis=0), lo - RUN_WINDOW * span)
    high = np.minimum(allp.max(axis=0), hi + RUN_WINDOW * span)
    return np.vstack([low, high])


def _mark_clipped(ax: Any, runs: list[np.ndarray], out: Any) -> int:
    """Mark with an x, on the border of the axes, where each run that leaves them leaves; the count."""
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    count = 0
    for r in runs:
        outside = (
            (r[:, 0] < x0) | (r[:, 0] > x1) | (r[:, 1] < y0) | (r[:, 1] > y1) | ~np.isfinite(r).all(axis=1)
        )
        if not outside.any():
            continue
        count += 1
        k = int(np.argmax(outside))
        p = np.nan_to_num(r[k], nan=x0, posinf=max(x1, y1), neginf=min(x0, y0))
        (mark,) = ax.plot(
            np.clip(p[0], x0, x1), np.clip(p[1], y0, y1), "x", color="tab:red", ms=6, mew=1.5,
            zorder=8, clip_on=False,
        )  # fmt: skip
        out.clipped.append(mark)
    return count


def _monte_carlo_title(report: Any, success_rate: float | None, count: int) -> str:
    if report is not None:
        return (
            f"{report.runs} runs: belief {100 * report.belief_success_rate:.1f}% "
            f"[{100 * report.belief_ci[0]:.1f}, {100 * report.belief_ci[1]:.1f}], "
            f"state {100 * report.state_success_rate:.1f}% "
            f"[{100 * report.state_ci[0]:.1f}, {100 * report.state_ci[1]:.1f}]"
        )
    if success_rate is not None:
        return f"{count} executions: success {100 * float(success_rate):.1f}%"
    return f"{count} executions"


# ----------------------------------------------------------------------------------------------
# Time series


def _axis_bounds(problem: Any, i: int) -> list[tuple[int, str, float]]:
    """``(j, name, b)`` per face ``x[i] <= b`` / ``x[i] >= b`` of a proposition on coordinate ``i`` alone."""
    out: list[tuple[int, str, float]] = []
    for j, name, H, c in _propositions(problem):
        alone = np.all(np.delete(H, i, axis=1) == 0.0, axis=1) & (H[:, i] != 0.0)
        out.extend((j, name, float(-cst / h)) for h, cst in zip(H[alone, i], c[alone], strict=True))
    return out


def _fill_intervals(ax: Any, problem: Any, i: int, out: Any, track: np.ndarray | None = None) -> None:
    """Fill, across the axes of state ``i``, the interval of each box-shaped proposition on
    ``x[i]``, and name it where the name covers neither the plan's mean ``track`` (one value per
    step) nor another name."""
    ax.autoscale_view()
    y0, y1 = ax.get_ylim()
    x0, x1 = ax.get_xlim()
    placed: list[tuple[float, float]] = []  # (x fraction, y fraction) of the names written
    # a name's height (x-small text and its box, ~12 points) as a fraction of the axes' height
    tall = min(0.5, 12.0 / max(1.0, ax.bbox.height * 72.0 / ax.figure.dpi))
    for j, name, H, c, _ in _atoms(problem):
        if not np.all(np.count_nonzero(H, axis=1) == 1) or not np.any(H[:, i]):
            continue  # an oblique face, or nothing on x[i]: its bounds alone are drawn
        mine = H[:, i] != 0.0  # a box: its interval on x[i] is the projection of its set
        lower = max([-cst / h for h, cst in zip(H[mine, i], c[mine], strict=True) if h < 0], default=-np.inf)
        upper = min([-cst / h for h, cst in zip(H[mine, i], c[mine], strict=True) if h > 0], default=np.inf)
        lo, hi = max(lower, y0), min(upper, y1)
        if not lo < hi:
            continue
        color = _region_style(j)["color"]
        span = ax.axhspan(lo, hi, facecolor=_fill(color, 0.1), edgecolor="none", zorder=0.5)
        key = name if name not in out.regions else f"{name} (x[{i}])"
        out.regions[key] = span
        fx, y = _name_spot(lo, hi, (x0, x1), (y0, y1), track, placed, tall)
        placed.append((fx, (y - y0) / (y1 - y0)))
        out.region_labels[key] = ax.text(
            x0 + fx * (x1 - x0),
            y,
            name,
            ha="left",
            va="center",
            fontsize="x-small",
            color=color,
            fontweight="bold",
            zorder=2.6,
            bbox={"boxstyle": "round,pad=0.15", "facecolor": "white", "edgecolor": "none", "alpha": 0.6},
        )
    ax.set_ylim(y0, y1)


_NAME_SPOTS = (0.01, 0.25, 0.5, 0.75)
"""Where along the time axis (fractions) a band's name may go."""


def _name_spot(
    lo: float,
    hi: float,
    xlim: tuple[float, float],
    ylim: tuple[float, float],
    track: np.ndarray | None,
    placed: list[tuple[float, float]],
    tall: float = 0.1,
) -> tuple[float, float]:
    """The spot (x fraction, y) of a band's name: inside ``[lo, hi]`` (its middle, or a
    quarter from either end) or, when no spot there is clear, just beside it; clear of the
    plan's mean ``track`` and of the names ``placed`` already (``(x fraction, y fraction)``);
    ``tall`` is a name's height as a fraction of the axes'."""
    (x0, x1), (y0, y1) = xlim, ylim
    height = y1 - y0
    best, best_score = (_NAME_SPOTS[0], 0.5 * (lo + hi)), -np.inf
    inside = (0.5 * (lo + hi), lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo))
    # just outside the band (a thin band the plan runs through has no free spot inside)
    off, edge = 0.7 * tall * height, 0.5 * tall * height
    beside = tuple(y for y in (hi + off, lo - off) if y0 + edge < y < y1 - edge)
    for y in inside + beside:
        penalty = 0.0 if y in inside else 0.5
        yf = (y - y0) / height
        for fx in _NAME_SPOTS:
            # a name is ~0.2 of the axes wide and ``tall`` high: its clearance to the others
            others = min(
                (max(abs(fx - px) / 0.22, abs(yf - py) / (1.1 * tall)) for px, py in placed), default=9.0
            )
            plan = 9.0
            if track is not None and track.size:
                steps = np.arange(track.shape[0])
                seen = (steps >= x0 + fx * (x1 - x0)) & (steps <= x0 + (fx + 0.2) * (x1 - x0))
                if seen.any():
                    plan = float(np.min(np.abs(track[seen] - y))) / height / (0.6 * tall)
            score = min(others, 1.0) * 2 + min(plan, 1.0) - 0.01 * fx - penalty  # clear, inside, left
            if score > best_score:
                best, best_score = (fx, y), score
    return best


def _operator_text(node: Any) -> str:
    """``F[a,b]``, ``G[a,b]``, ``U[a,b]`` or ``R[a,b]`` of a temporal node."""
    from .formulas import FALSE, TRUE

    op = node.symbol
    if op == "U" and node.left is TRUE:
        op = "F"
    elif op == "R" and node.left is FALSE:
        op = "G"
    return f"{op}[{node.a},{node.b}]"


def _operand_text(node: Any) -> str:
    """An operand's propositions (``target``, ``a, b``), ``(...)`` around a temporal one."""
    from .formulas import STLTemporalFormula

    names = sorted({ap.name or "?" for ap in _propositions_of(node) if not (ap.is_true or ap.is_false)})
    text = ", ".join(names) or str(node)
    return f"({text} ...)" if isinstance(node, STLTemporalFormula) else text


def _propositions_of(node: Any) -> list[Any]:
    """The atomic propositions of a formula node (``node.atomic_propositions()``)."""
    return list(node.atomic_propositions())


def temporal_windows(formula: Any) -> list[tuple[str, int, int]]:
    """The formula's temporal operators, outermost first, with the steps each one applies to.

    An operator ``[a, b]`` evaluated at the steps ``lo .. hi`` (0 for the formula itself, else
    the steps its enclosing operator looks at) looks at ``lo + a .. hi + b``; its label names
    the operator and the propositions under it (``G[0,10] target``).

    Parameters
    ----------
    formula : STLFormula

    Returns
    -------
    list of (str, int, int)
        ``(label, first step, last step)``.
    """
    from .formulas import STLTemporalFormula

    out: list[tuple[str, int, int]] = []

    def walk(node: Any, lo: int, hi: int) -> None:
        if isinstance(node, STLTemporalFormula):
            op = _operator_text(node)
            label = f"{op} {_operand_text(node.right)}"
            if op[0] in "UR":
                label = f"{_operand_text(node.left)} {label}"
            start, end = lo + node.a, hi + node.b
            out.append((label, start, end))
            walk(node.left, lo, end)
            walk(node.right, start, end)
            return
        for child in getattr(node, "children", ()):
            walk(child, lo, hi)

    walk(formula, 0, 0)
    return out


def _draw_windows(ax: Any, formula: Any, out: Any) -> None:
    """Brackets above ``ax``, one per temporal operator over the steps it applies to."""
    from matplotlib.transforms import blended_transform_factory

    windows = temporal_windows(formula)
    out.windows = windows
    tr = blended_transform_factory(ax.transData, ax.transAxes)
    for row, (label, start, end) in enumerate(windows):
        y = 1.05 + 0.14 * row
        ax.plot([start, start, end, end], [y - 0.025, y, y, y - 0.025], color="0.3", lw=1.0,
                transform=tr, clip_on=False)  # fmt: skip
        ax.text(start, y + 0.01, f"{label}: steps {start}..{end}", transform=tr, ha="left",
                va="bottom", fontsize="x-small", color="0.2", clip_on=False)  # fmt: skip
        for k in (start, end):
            ax.axvline(k, color="0.5", lw=0.6, ls=(0, (2, 3)), zorder=0.4)


def _run_line(
    ax: Any, values: np.ndarray, color: str, lw: float, zorder: float, label: str, first: bool
) -> Any:
    """One execution's thin line against the step (labelled only for the first run)."""
    (line,) = ax.plot(
        np.arange(values.shape[0]),
        values,
        color=color,
        lw=lw,
        alpha=0.35,
        zorder=zorder,
        label=label if first else None,
    )
    return line


def plot_time_series(
    problem: Any,
    plan: Any,
    executed: Any = None,
    real: Any = None,
    axes: Any = None,
    *,
    states: Sequence[int] | None = None,
    sigma: float = 2.0,
    controls: bool = True,
    modes: bool = True,
    bounds: bool = True,
    legend: LegendPlacement = "outside",
    executions: Sequence[tuple[Any, Any]] | None = None,
    caption: bool = True,
) -> TimeSeriesArtists:
    """Draw trajectories against the step: each state's mean with a band, the inputs, the modes.

    Works for any state dimension (one axes per drawn state coordinate).

    Parameters
    ----------
    problem : Problem or None
        Supplies the propositions' bounds on single coordinates (drawn dotted); None for none.
    plan : ProbabilisticTSTrajectory
        The planned belief: mean (blue) and ``mean +- sigma * std`` band per state, its inputs
        (steps, ``u_k`` held from step ``k`` to ``k + 1``) and its modes.
    executed : ProbabilisticTSTrajectory, optional
        An executed belief (orange, with its band; its inputs dashed).
    real : RealTrajectory, optional
        The true states (red).
    axes : sequence of Axes, optional
        Where to draw: one per state drawn, then one for the inputs and one for the modes (when
        drawn). Default: a new figure with a column of shared-step axes.
    states : sequence of int, optional
        The state coordinates to draw (default: all).
    sigma : float
        Half-width of the band in standard deviations (2: about 95% per coordinate).
    controls : bool
        Draw the inputs (when the plan has any).
    modes : bool
        Draw the modes.
    bounds : bool
        Draw the propositions' bounds on single coordinates (needs ``problem``).
    legend : bool or str
        As in :func:`plot_workspace` (one legend, on the first axes).
    executions : sequence of (ProbabilisticTSTrajectory, RealTrajectory), optional
        Many executions overlaid (e.g. ``ValidationReport.executions``): per state, one thin
        line per executed belief mean (orange) and per true state (red).
    caption : bool
        Write under the last axes what the bands and lines are.

    Returns
    -------
    TimeSeriesArtists

    Notes
    -----
    The plan's first and last means are marked (start: a white circle, end: a gold star), as
    in :func:`plot_workspace`; the modes' axis names each mode with what it does (``senses``,
    ``blind``, ``stands still: B = 0``).

    Raises
    ------
    DimensionError
        When a state index is out of range, the trajectories' dimensions disagree or ``axes``
        has the wrong length.
    InvalidTypeError
        When ``plan`` is not a belief trajectory.
    """
    from .trajectory import ProbabilisticTSTrajectory

    if not isinstance(plan, ProbabilisticTSTrajectory):
        raise InvalidTypeError(f"plan must be a ProbabilisticTSTrajectory, got {type(plan).__name__}")
    n = plan.n
    if problem is not None:
        _check_problem(problem)
        if problem.switched_system.n != n:
            raise DimensionError(
                f"plan has state dimension {n}, the problem has n = {problem.switched_system.n}"
            )
    if executed is not None:
        if not isinstance(executed, ProbabilisticTSTrajectory):
            raise InvalidTypeError(
                f"executed must be a ProbabilisticTSTrajectory, got {type(executed).__name__}"
            )
        _check_traj(executed, "executed", n)
    if real is not None:
        _check_traj(real, "real", n)
    runs: list[tuple[Any, Any]] = []
    for i, pair in enumerate(executions or ()):
        if not isinstance(pair, tuple | list) or len(pair) != 2:
            raise InvalidArgumentError(f"executions[{i}] must be a pair (executed belief, real trajectory)")
        _check_traj(pair[0], f"executions[{i}][0]", n)
        _check_traj(pair[1], f"executions[{i}][1]", n)
        runs.append((pair[0], pair[1]))
    idx = tuple(range(n)) if states is None else tuple(int(i) for i in states)
    if not idx or any(not 0 <= i < n for i in idx) or len(set(idx)) != len(idx):
        raise DimensionError(f"states must be different coordinates in 0..{n - 1}, got {states!r}")
    sigma = float(sigma)
    if not np.isfinite(sigma) or sigma < 0:
        raise InvalidArgumentError(f"sigma must be a finite number >= 0, got {sigma}")
    draw_u = bool(controls) and plan.m > 0 and plan.num_of_steps > 0
    draw_q = bool(modes) and plan.num_of_steps > 0
    count = len(idx) + int(draw_u) + int(draw_q)
    if axes is None:
        import matplotlib.pyplot as plt

        ratios = [1.5] * len(idx) + [1.2] * int(draw_u) + [0.7] * int(draw_q)
        fig, ax_arr = plt.subplots(
            count,
            1,
            sharex=True,
            figsize=(8.0, 1.2 + sum(ratios)),
            layout="constrained",
            squeeze=False,
            gridspec_kw={"height_ratios": ratios},
        )
        ax_list = list(ax_arr[:, 0])
    else:
        ax_list = list(np.ravel(np.asarray(axes, dtype=object)))
        if len(ax_list) != count:
            raise DimensionError(
                f"axes must hold {count} axes ({len(idx)} states, {int(draw_u)} inputs, "
                f"{int(draw_q)} modes), got {len(ax_list)}"
            )
        fig = ax_list[0].figure
    out = TimeSeriesArtists(figure=fig, axes=ax_list, ax=ax_list[0], states=idx)
    band_label = f"plan: mean \u00b1 {sigma:g} std"

    steps = np.arange(plan.num_of_beliefs)
    named: set[str] = set()
    mean, std = plan.get_mean(), plan.get_std()
    for row, i in enumerate(idx):
        ax = ax_list[row]
        out.bands[i] = ax.fill_between(
            steps,
            mean[:, i] - sigma * std[:, i],
            mean[:, i] + sigma * std[:, i],
            color="tab:blue",
            alpha=0.2,
            lw=0,
            label=band_label if row == 0 else None,
        )
        (out.means[i],) = ax.plot(
            steps, mean[:, i], color="tab:blue", lw=1.3, label="plan: mean" if row == 0 else None
        )
        if executed is not None:
            em, es = executed.get_mean(), executed.get_std()
            ek = np.arange(executed.num_of_beliefs)
            out.executed_bands[i] = ax.fill_between(
                ek,
                em[:, i] - sigma * es[:, i],
                em[:, i] + sigma * es[:, i],
                color="tab:orange",
                alpha=0.15,
                lw=0,
                label=f"executed: mean \u00b1 {sigma:g} std" if row == 0 else None,
            )
            (out.executed_means[i],) = ax.plot(
                ek, em[:, i], color="tab:orange", lw=1.0, label="executed: mean" if row == 0 else None
            )
        out.runs_executed[i], out.runs_real[i] = [], []
        for r, (xs, xr) in enumerate(runs):
            first = row == 0 and r == 0  # one legend entry per kind of line
            out.runs_executed[i].append(
                _run_line(
                    ax, xs.get_mean()[:, i], "tab:orange", 0.6, 1.5, f"executed beliefs ({len(runs)})", first
                )
            )
            out.runs_real[i].append(
                _run_line(ax, xr.get_state()[:, i], "tab:red", 0.5, 1.6, f"true states ({len(runs)})", first)
            )
        (out.start[i],) = ax.plot(
            [0],
            [mean[0, i]],
            ls="none",
            marker="o",
            ms=8,
            mfc="white",
            mec="black",
            mew=1.5,
            zorder=8,
            label="start (initial mean)" if row == 0 else None,
        )
        (out.end[i],) = ax.plot(
            [plan.num_of_steps],
            [mean[-1, i]],
            ls="none",
            marker="*",
            ms=13,
            mfc="gold",
            mec="black",
            zorder=8,
            label="end of plan" if row == 0 else None,
        )
        if real is not None:
            rs = real.get_state()
            (out.real[i],) = ax.plot(
                np.arange(rs.shape[0]),
                rs[:, i],
                color="tab:red",
                lw=0.9,
                label="true state" if row == 0 else None,
            )
        if bounds and problem is not None:
            for j, name, value in _axis_bounds(problem, i):
                line = ax.axhline(
                    value,
                    color=_region_style(j)["color"],
                    ls=":",
                    lw=1.0,
                    label=f"{name}: bounds" if name not in named else None,
                )
                named.add(name)
                out.bounds.append(line)
            _fill_intervals(ax, problem, i, out, plan.get_mean()[:, i])
        ax.set_ylabel(f"x[{i}]")
    row = len(idx)
    if draw_u:
        ax = ax_list[row]
        out.controls_ax = ax
        u = plan.get_control()
        k = np.arange(plan.num_of_steps + 1)
        for j in range(plan.m):
            (line,) = ax.step(k, np.append(u[:, j], u[-1, j]), where="post", lw=1.1, label=f"u[{j}]")
            out.controls.append(line)
        if executed is not None and executed.num_of_steps and executed.m == plan.m:
            eu = executed.get_control()
            ek = np.arange(executed.num_of_steps + 1)
            for j in range(plan.m):
                (line,) = ax.step(
                    ek,
                    np.append(eu[:, j], eu[-1, j]),
                    where="post",
                    lw=0.9,
                    ls="--",
                    color=out.controls[j].get_color(),
                    label=f"u[{j}] executed",
                )
                out.controls.append(line)
        ax.set_ylabel("input")
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize="small")
        row += 1
    if draw_q:
        ax = ax_list[row]
        out.modes_ax = ax
        q = plan.get_action()
        k = np.arange(plan.num_of_steps + 1)
        (line,) = ax.step(k, np.append(q, q[-1]), where="post", color="black", lw=1.2, label="plan")
        out.modes.append(line)
        change = np.flatnonzero(np.diff(q)) + 1
        for k0, k1 in zip(np.r_[0, change], np.r_[change, q.size], strict=True):
            qq = int(q[k0])
            out.mode_bands.append(
                ax.broken_barh(
                    [(int(k0), int(k1 - k0))], (qq - 0.3, 0.6), color=_mode_color(qq), alpha=0.5, lw=0
                )
            )
        if executed is not None and executed.num_of_steps:
            eq = executed.get_action()
            if eq.shape != q.shape or np.any(eq != q):
                ek = np.arange(executed.num_of_steps + 1)
                (line,) = ax.step(
                    ek, np.append(eq, eq[-1]), where="post", color="tab:orange", ls="--", label="executed"
                )
                out.modes.append(line)
        num_modes = problem.switched_system.num_modes if problem is not None else int(q.max()) + 1
        ax.set_yticks(range(num_modes))
        if problem is not None:
            ax.set_yticklabels(
                [f"{m} ({_mode_text(problem, m)})" for m in range(num_modes)], fontsize="small"
            )
        ax.set_ylim(-0.5, num_modes - 0.5)
        ax.set_ylabel("mode")
    ax_list[-1].set_xlabel("step k")
    if problem is not None and idx:
        _draw_windows(ax_list[0], problem.stl_formula, out)
    # One legend for the states' axes (each label once), on the first.
    handles: dict[str, Any] = {}
    for ax in ax_list[: len(idx)]:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
    if legend is not False and legend is not None and handles:
        first = ax_list[0]
        if legend is True or legend == "outside":
            out.legend = first.legend(
                list(handles.values()),
                list(handles),
                loc="upper left",
                bbox_to_anchor=(1.02, 1.0),
                borderaxespad=0.0,
                fontsize="small",
            )
        else:
            out.legend = _place_legend(first, [], legend)
    if caption:
        text = f"Bands: the planned belief's mean \u00b1 {sigma:g} standard deviations per state"
        if executed is not None:
            text += " (orange: the executed belief's)"
        text += "."
        if runs:
            text += f" Thin lines: {len(runs)} executions (orange: executed belief means, red: true states)."
        if out.regions:
            text += (
                " Filled bands: each box-shaped proposition's interval on that state, for a belief "
                "without uncertainty (the mean needs room for its spread); dotted: their bounds."
            )
        elif out.bounds:
            text += " Dotted: the propositions' bounds on single coordinates (at zero covariance)."
        last = ax_list[-1]
        out.caption = last.annotate(
            textwrap.fill(text, 100),
            xy=(0.0, 0.0),
            xycoords="axes fraction",
            xytext=(0, -34),
            textcoords="offset points",
            ha="left",
            va="top",
            fontsize="x-small",
            color="0.25",
            annotation_clip=False,
        )
    return out


# ----------------------------------------------------------------------------------------------
# Files


def save_figure(figure: Any, path: str | os.PathLike[str], *, dpi: int = 150, **kwargs: Any) -> Path:
    """Write a figure in the format of the file's extension: ``.png``, ``.pdf`` or ``.svg``.

    The bounding box is tight, so a legend outside the axes is kept.

    Parameters
    ----------
    figure : matplotlib Figure or an ``*Artists`` object of this module
        What to save (an artists object gives its ``figure``).
    path : path
        The file; its extension chooses the format (PDF and SVG are vector formats).
    dpi : int
        Resolution of PNG files (and of the shading embedded in PDF / SVG).
    **kwargs
        Passed to ``Figure.savefig``.

    Returns
    -------
    Path

    Raises
    ------
    InvalidArgumentError
        For another extension or a folder that does not exist.
    """
    fig = getattr(figure, "figure", figure)
    if not hasattr(fig, "savefig"):
        raise InvalidTypeError(f"figure must be a matplotlib Figure, got {type(figure).__name__}")
    out = Path(path)
    fmt = out.suffix.lower().lstrip(".")
    if fmt not in FIGURE_FORMATS:
        raise InvalidArgumentError(
            f"figure {str(out)!r}: the extension gives the format; use one of "
            f"{', '.join('.' + f for f in FIGURE_FORMATS)}"
        )
    if not out.parent.is_dir():
        raise InvalidArgumentError(f"figure {str(out)!r}: folder {str(out.parent)!r} does not exist")
    kwargs.setdefault("bbox_inches", "tight")
    fig.savefig(out, format=fmt, dpi=dpi, **kwargs)
    return out
