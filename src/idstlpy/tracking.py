"""The executor's tracking law: finite-horizon discrete-time LQR around a plan (the paper's Section IV-E).

An executor-layer module: the planner (``guarantee="closed_loop"`` plans against the executor's
predicted closed loop) and the executor (:func:`idstlpy.simulate`) both use it; one home for the
gains means the planner predicts exactly the loop that runs. The plain Riccati recursion is in the
model (:mod:`idstlpy.lqr`, re-exported here), where a mode computes its own gains.

With the gains ``K_k`` of :func:`~idstlpy.lqr.finite_horizon_lqr` used to track a plan, ``x`` is
the deviation of the estimated mean from the planned mean: ``u = u_plan - K_0 (x_est - x_plan)``;
in receding horizon only ``K_0`` is applied at every step (``K_j`` when only ``h - j`` plan steps
remain).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import DimensionError, InvalidArgumentError, InvalidTypeError
from .lqr import TrackingGains, finite_horizon_lqr, riccati_costs
from .sets import Polytope

if TYPE_CHECKING:
    from .dynamical_system import LCS, SwitchedSystem

__all__ = [
    "gain_at",
    "tracking_input",
    "system_gains",
    "DEFAULT_LQR",
    "FITTED_SCALES",
    "TrackingGains",
    "fitted_weights",
    "make_tracking",
    "plan_fallback",
    "planning_gains",
    "box_bounds",
    "control_projector",
    "PolytopeProjection",
    "finite_horizon_lqr",
    "mode_gains",
    "riccati_costs",
]


DEFAULT_LQR: dict[str, Any] = {"horizon": 5, "Q_final": 1.0, "Q": 1.0, "R": 0.05}
"""Weights used for a mode without gains: the paper's ``h = 5``, ``Q_final = Q = I``, ``R = 0.05 I``
(scalars multiply the identity)."""


def _weight(value: Any, size: int) -> Any:
    if np.isscalar(value):
        return float(value) * np.eye(size)  # type: ignore[arg-type]
    return value


def mode_gains(
    mode: LCS,
    override: Sequence[np.ndarray] | None = None,
    default_lqr: Mapping[str, Any] | None = None,
    fallback: Sequence[np.ndarray] | None = None,
) -> list[np.ndarray]:
    """Tracking gains of one mode: ``override``, else ``mode.lqr_gains``, else the weights
    ``default_lqr``, else ``fallback`` (the plan's fitted gains), else :data:`DEFAULT_LQR`'s.

    Parameters
    ----------
    mode : LCS
    override : sequence of ndarray (m, n), optional
    default_lqr : mapping, optional
        ``horizon``, ``Q_final``, ``Q``, ``R`` for :func:`finite_horizon_lqr` (scalars mean a
        multiple of the identity); given, it is used instead of ``fallback``.
    fallback : sequence of ndarray (m, n), optional
        The gains a plan was made with (:attr:`TrackingGains.gains`), for a mode without its own.

    Returns
    -------
    list of ndarray, each shape (m, n)
    """
    gains = override if override is not None else getattr(mode, "lqr_gains", None)
    if gains is None and default_lqr is None and fallback is not None:
        gains = fallback
    if gains is None:
        cfg = dict(DEFAULT_LQR)
        if default_lqr is not None:
            unknown = set(default_lqr) - set(DEFAULT_LQR)
            if unknown:
                raise InvalidArgumentError(
                    f"default_lqr has unknown keys {sorted(unknown)}; expected {sorted(DEFAULT_LQR)}"
                )
            cfg.update(default_lqr)
        gains = finite_horizon_lqr(
            mode.A,
            mode.B,
            cfg["horizon"],
            _weight(cfg["Q_final"], mode.n),
            _weight(cfg["Q"], mode.n),
            _weight(cfg["R"], mode.m),
        )
    out = [np.asarray(K, dtype=float) for K in gains]
    if not out:
        raise InvalidArgumentError("lqr gains must contain at least one gain")
    for j, K in enumerate(out):
        if K.shape != (mode.m, mode.n):
            raise DimensionError(f"lqr gain {j} must have shape ({mode.m}, {mode.n}), got {K.shape}")
    return out


def control_projector(domain: Polytope | None, m: int) -> Callable[[np.ndarray], np.ndarray]:
    """A function mapping inputs to their Euclidean projection on ``domain`` (identity for None).

    The one projection of the executor (:meth:`idstlpy.executor.law.StepLaw.control`) and of the
    prediction's samples (:class:`idstlpy.loop_samples.LoopStep`), so that the prediction pushes
    its samples through exactly the map the executor applies.

    Boxes (every face touches one coordinate) are clipped per coordinate (``np.clip``). Other
    polytopes: an input inside is returned as it is; one outside gets the solution of
    ``min ||z - u||^2 s.t. H z + c <= 0``, as the least-distance programme
    ``min ||x|| s.t. -H x >= H u + c`` (``z = u + x``) solved by Lawson and Hanson's
    non-negative least squares (:func:`scipy.optimize.nnls`: an active-set method that ends
    at the exact solution in finitely many steps; *Solving Least Squares Problems*, ch. 23).

    Parameters
    ----------
    domain : Polytope or None
        Admissible inputs ``{u : H u + c <= 0}`` of dimension ``m``.
    m : int
        Input dimension.

    Returns
    -------
    callable
        ``project(u)``: ``u`` of shape (m,) or (S, m) (one input per row) to the projections,
        same shape.

    Raises
    ------
    InvalidArgumentError
        When ``domain`` is empty.
    """
    if domain is None:
        return lambda u: u
    if not isinstance(domain, Polytope):
        raise InvalidTypeError(f"control_domain must be a Polytope or None, got {type(domain).__name__}")
    if domain.dim != m:
        raise DimensionError(f"control_domain has dimension {domain.dim}, the system has m = {m} inputs")
    box = box_bounds(domain, m)
    if box is not None:
        low, high = box
        if np.any(low > high):
            raise InvalidArgumentError("control_domain is empty: no admissible input")
        return lambda u: np.clip(u, low, high)
    if domain.is_empty():
        raise InvalidArgumentError("control_domain is empty: no admissible input")
    return PolytopeProjection(domain.H, domain.c)


class PolytopeProjection:
    """The Euclidean projection on ``{u : H u + c <= 0}`` (see :func:`control_projector`).

    Many inputs at once (the executor's runs, the prediction's samples): the projection of an
    input outside is ``z = u - H_A' lam`` for the set ``A`` of faces active at ``z``, with
    ``lam = (H_A H_A')^-1 (H_A u + c_A)``, and a candidate ``z`` is the projection exactly when
    it satisfies the optimality conditions of the convex programme (``lam >= 0``,
    ``H z + c <= 0``). The candidate sets of one face, then of two, ... up to ``m`` linearly
    independent faces (at most :attr:`MAX_CANDIDATES`) are checked for all rows at once; a row
    none of them settles (a degenerate vertex, many faces) is solved by
    :func:`scipy.optimize.nnls` on its least-distance programme (:meth:`one`).

    Parameters
    ----------
    H : ndarray, shape (F, m)
    c : ndarray, shape (F,)
    """

    INSIDE_TOL = 1e-12
    """An input whose every face's value (rows of ``H`` scaled to unit norm) is at most this is
    inside and returned unchanged (the executor's rule since the projection was introduced)."""

    KKT_TOL = 1e-10
    """Slack of the optimality check of a candidate active set (unit-norm faces: a distance)."""

    MAX_CANDIDATES = 256

    def __init__(self, H: np.ndarray, c: np.ndarray) -> None:
        from itertools import combinations

        norms = np.linalg.norm(H, axis=1)
        keep = norms > 0  # a row 0 u + c <= 0 constrains nothing (or empties the set: checked before)
        self.H = H[keep] / norms[keep, None]
        self.c = c[keep] / norms[keep]
        self.m = H.shape[1]
        # (faces, (H_A H_A')^-1 and H_A) of every candidate active set, fewest faces first
        self.candidates: list[tuple[list[int], np.ndarray, np.ndarray]] = []
        F = self.H.shape[0]
        for size in range(1, min(self.m, F) + 1):
            for A in combinations(range(F), size):
                HA = self.H[list(A)]
                G = HA @ HA.T
                if np.linalg.cond(G) > 1e8:  # dependent faces: left to the solver
                    continue
                self.candidates.append((list(A), np.linalg.inv(G), HA))
                if len(self.candidates) >= self.MAX_CANDIDATES:
                    break
            if len(self.candidates) >= self.MAX_CANDIDATES:
                break

    def __eq__(self, other: object) -> bool:
        """The same projection: the same (normalised) faces."""
        if not isinstance(other, PolytopeProjection):
            return NotImplemented
        return np.array_equal(self.H, other.H) and np.array_equal(self.c, other.c)

    __hash__ = None  # type: ignore[assignment]  # mutable arrays: not hashable

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """Project ``u``, shape (m,) or (S, m) (one input per row); the same shape."""
        U = np.asarray(u, dtype=float)
        rows = U.reshape(-1, self.m)
        # Products as elementwise sums over the few inputs and faces, not BLAS products: a row's
        # projection is then the same bits whatever the batch it comes in (one run, all runs,
        # the prediction's samples), as a matrix kernel chosen by the batch's size would not give.
        values = _rowdot(rows, self.H) + self.c  # (S, F)
        # (a non-finite input, from a diverging run, is left as it is: the run is reported as such)
        outside = np.flatnonzero(
            np.any(values > self.INSIDE_TOL, axis=1) & np.all(np.isfinite(values), axis=1)
        )
        if not outside.size:
            return U
        out = rows.copy()
        todo = outside
        for A, Ginv, HA in self.candidates:
            lam = _rowdot(values[todo][:, A], Ginv)  # (T, |A|)
            z = rows[todo] - _rowdot(lam, HA.T)
            ok = np.all(lam >= -self.KKT_TOL, axis=1) & np.all(
                _rowdot(z, self.H) + self.c <= self.KKT_TOL, axis=1
            )
            out[todo[ok]] = z[ok]
            todo = todo[~ok]
            if not todo.size:
                break
        for i in todo.tolist():
            out[i] = self.one(rows[i], values[i])
        return out.reshape(U.shape)

    def one(self, u: np.ndarray, values: np.ndarray) -> np.ndarray:
        """The projection of one input outside the domain.

        Solves the least-distance programme ``min ||x|| s.t. -H x >= values`` by non-negative
        least squares (Lawson and Hanson, ch. 23) and returns ``u + x``.

        Parameters
        ----------
        u : numpy.ndarray, shape (m,)
            The input, outside the domain.
        values : numpy.ndarray, shape (F,)
            ``H u + c``, the domain's face values at ``u`` (positive on the violated faces).

        Returns
        -------
        numpy.ndarray, shape (m,)
            The closest point of the domain to ``u``.
        """
        from scipy.optimize import nnls

        m = self.m
        E = np.empty((m + 1, self.H.shape[0]))
        E[:m] = -self.H.T
        E[m] = values
        f = np.zeros(m + 1)
        f[m] = 1.0
        w, _ = nnls(E, f)
        r = E @ w - f
        if not r[m] < 0.0:  # pragma: no cover - an empty domain is refused when built
            raise InvalidArgumentError("control_domain is empty: the input has no projection on it")
        z: np.ndarray = u - r[:m] / r[m]
        return z


def _rowdot(X: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``X @ M.T`` for ``X`` (S, k) and ``M`` (F, k), each entry a sum of ``k`` products in order."""
    out: np.ndarray = X[:, :1] * M[None, :, 0]
    for j in range(1, X.shape[1]):
        out = out + X[:, j : j + 1] * M[None, :, j]
    return out


def box_bounds(domain: Polytope | None, m: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Bounds ``(low, high)`` when ``domain`` is a box (every face touches one input), else None.

    Parameters
    ----------
    domain : Polytope or None
        Admissible inputs ``{u : H u + c <= 0}``.
    m : int
        Input dimension.

    Returns
    -------
    (ndarray, ndarray), each shape (m,), or None
    """
    if domain is None:
        return None
    if not isinstance(domain, Polytope):
        raise InvalidTypeError(f"control_domain must be a Polytope or None, got {type(domain).__name__}")
    if domain.dim != m:
        raise DimensionError(f"control_domain has dimension {domain.dim}, the system has m = {m} inputs")
    H, c = domain.H, domain.c
    if not H.shape[0] or not np.all((np.abs(H) > 0).sum(axis=1) == 1):
        return None
    low, high = np.full(m, -np.inf), np.full(m, np.inf)
    for row, cst in zip(H, c, strict=True):
        i = int(np.flatnonzero(row)[0])
        bound = -cst / row[i]
        if row[i] > 0:
            high[i] = min(high[i], bound)
        else:
            low[i] = max(low[i], bound)
    return low, high


GainsOverride = Mapping[int, Sequence[np.ndarray]] | Sequence[Sequence[np.ndarray] | None] | None
"""Per-mode tracking gains given by the caller: a mapping mode -> gains, or a sequence indexed by mode."""


def system_gains(
    system: Any,
    lqr_gains: GainsOverride = None,
    default_lqr: Mapping[str, Any] | None = None,
    modes: Iterable[int] | None = None,
    fallback: Mapping[int, Sequence[np.ndarray]] | None = None,
) -> dict[int, list[np.ndarray]]:
    """The tracking gains of every mode (or of ``modes``): the caller's, else the mode's, else
    ``default_lqr``'s weights, else ``fallback`` (the plan's fitted gains), else the defaults.

    Parameters
    ----------
    system : SwitchedSystem
    lqr_gains : mapping or sequence, optional
        Per mode, gains (m, n) overriding ``mode.lqr_gains`` (modes it does not name keep theirs).
    default_lqr : mapping, optional
        Weights for modes without gains (see :data:`DEFAULT_LQR`).
    modes : iterable of int, optional
        The modes wanted (default all).
    fallback : mapping, optional
        Mode -> gains a plan was made with (:func:`plan_fallback`), for modes without their own.

    Returns
    -------
    dict
        Mode -> list of gains, each shape (m, n), in increasing mode order.
    """

    def override(q: int) -> Sequence[np.ndarray] | None:
        if lqr_gains is None:
            return None
        if isinstance(lqr_gains, Mapping):
            return lqr_gains.get(q)
        return lqr_gains[q] if q < len(lqr_gains) else None

    wanted = range(system.num_modes) if modes is None else sorted({int(q) for q in modes})
    fb = fallback or {}
    return {q: mode_gains(system.mode(q), override(q), default_lqr, fb.get(q)) for q in wanted}


def tracking_input(
    v: np.ndarray,
    K: np.ndarray,
    deviation: np.ndarray,
    low: np.ndarray | None = None,
    high: np.ndarray | None = None,
) -> np.ndarray:
    """The tracking law ``v - K deviation``, clipped to the box ``[low, high]`` when given.

    Parameters
    ----------
    v : ndarray, shape (m,)
        The plan's input.
    K : ndarray, shape (m, n)
        The tracking gain.
    deviation : ndarray, shape (S, n)
        Estimated means minus the plan's mean, one row per run (or sample).
    low, high : ndarray of shape (m,), optional
        The box of admissible inputs (both or neither).

    Returns
    -------
    ndarray, shape (S, m)
    """
    u: np.ndarray = v - deviation @ K.T
    if low is not None and high is not None:
        u = np.clip(u, low, high)
    return u


def gain_at(gains: Sequence[np.ndarray], remaining: int) -> np.ndarray:
    """The receding-horizon gain with ``remaining`` plan steps left: ``K_0``, or ``K_j`` near the end.

    Parameters
    ----------
    gains : sequence of ndarray (m, n)
        ``K_0 .. K_{h-1}`` of the mode.
    remaining : int
        Plan steps left (``N - k`` at step ``k`` of an ``N``-step plan).

    Returns
    -------
    ndarray, shape (m, n)
    """
    return gains[0] if remaining >= len(gains) else gains[len(gains) - remaining]


FITTED_SCALES: tuple[float, ...] = (1.0, 10.0, 100.0)
"""Multipliers of the fitted state weights the planner tries, in order (:func:`fitted_weights`):
Bryson's rule reads the allowed deviation as a region's half-width, but a plan keeps only part of
that room for the tracking error (the rest is the belief's own spread), so firmer tracking is
tried too, and chosen only when its predicted execution is better."""


def fitted_weights(
    system: SwitchedSystem, regions: Sequence[Polytope], control_domain: Polytope | None
) -> dict[str, Any] | None:
    """Tracking weights from the problem's own scales (Bryson's rule), or None when it has none.

    ``Q_ii = 1 / d_i^2`` with ``d_i`` the smallest half-width along state coordinate ``i`` of the
    regions the formula uses (0 for a coordinate no region bounds), ``R_jj = 1 / r_j^2`` with
    ``r_j`` the control domain's half-width along input ``j`` (where the domain is unbounded
    along ``j``: the input that moves a bounded coordinate by its ``d_i`` in one step,
    ``min_i d_i / |B_ij|`` over the modes); ``Q_final = Q`` and the paper's horizon 5. All three
    are then divided by ``max_j R_jj`` (the gains are the same; the weights stay well scaled in
    any units).

    Parameters
    ----------
    system : SwitchedSystem
    regions : sequence of Polytope
        The regions (each of dimension ``n``) the formula's chance constraints use.
    control_domain : Polytope or None
        Admissible inputs (dimension ``m``).

    Returns
    -------
    dict or None
        ``horizon``, ``Q_final``, ``Q`` (n, n), ``R`` (m, m) as :data:`DEFAULT_LQR`; None when no
        region bounds any coordinate or an input has no scale (the caller keeps the paper's).
    """
    n, m = system.n, system.m
    dev = np.full(n, np.inf)
    for region in regions:
        if region.dim != n or region.H.shape[0] == 0:
            continue
        low, high = region.bounding_box()
        half = 0.5 * (high - low)
        ok = np.isfinite(half) & (half > 0)
        dev[ok] = np.minimum(dev[ok], half[ok])
    bounded = np.isfinite(dev)
    if not np.any(bounded):
        return None
    q = np.where(bounded, 1.0 / np.where(bounded, dev, 1.0) ** 2, 0.0)
    half_u = np.full(m, np.inf)
    if control_domain is not None and control_domain.H.shape[0]:
        low, high = control_domain.bounding_box()
        half_u = 0.5 * (high - low)
    for j in np.flatnonzero(~(np.isfinite(half_u) & (half_u > 0))).tolist():
        reach = [
            float(dev[i] / abs(mode.B[i, j]))
            for mode in system.system_modes
            for i in np.flatnonzero(bounded).tolist()
            if abs(mode.B[i, j]) > 0
        ]
        if not reach:
            return None
        half_u[j] = min(reach)
    # Bryson's weights carry the problem's units (1e-12 for inputs of 1e6); the LQR gains do not
    # change when Q, Q_final and R are scaled together, so R's largest entry is set to 1
    r = 1.0 / half_u**2
    scale = 1.0 / float(np.max(r))
    Q = np.diag(q * scale)
    return {"horizon": DEFAULT_LQR["horizon"], "Q_final": Q, "Q": Q.copy(), "R": np.diag(r * scale)}


def make_tracking(system: SwitchedSystem, name: str, weights: Mapping[str, Any] | None) -> TrackingGains:
    """The gains of every mode of ``system`` under ``weights`` (modes with their own keep them).

    Parameters
    ----------
    system : SwitchedSystem
    name : str
        The gain set's name (:class:`~idstlpy.lqr.TrackingGains`).
    weights : mapping or None
        As :data:`DEFAULT_LQR` (None: :data:`DEFAULT_LQR`).

    Returns
    -------
    TrackingGains
    """
    cfg = dict(DEFAULT_LQR if weights is None else weights)
    gains = system_gains(system, None, cfg)
    frozen = {q: tuple(np.array(K, dtype=float) for K in Ks) for q, Ks in gains.items()}
    for K in (K for Ks in frozen.values() for K in Ks):
        K.flags.writeable = False
    return TrackingGains(name, cfg, frozen)


_PLANNING: ContextVar[tuple[int, TrackingGains] | None] = ContextVar("idstlpy_planning_gains", default=None)
"""The gains a running solve plans with, keyed by its system's identity (:func:`planning_gains`)."""


@contextmanager
def planning_gains(system: SwitchedSystem, tracking: TrackingGains | None) -> Iterator[None]:
    """Within the block, plans on ``system`` that carry no gains are read as tracked by ``tracking``.

    A solve's many closed-loop computations (the candidates' predictions, the mode search's
    execution room, the closed-loop repair) see the fitted gains this way without each taking
    them as an argument; the returned plan carries them (``plan.tracking``), and the executors
    read them there. The setting is the current thread's (a :class:`contextvars.ContextVar`).

    Parameters
    ----------
    system : SwitchedSystem
    tracking : TrackingGains or None
        None leaves the defaults (:data:`DEFAULT_LQR`) in force.
    """
    token = _PLANNING.set(None if tracking is None else (id(system), tracking))
    try:
        yield
    finally:
        _PLANNING.reset(token)


def plan_fallback(system: SwitchedSystem, plan: object | None) -> Mapping[int, Sequence[np.ndarray]] | None:
    """The gains a plan was made for: its own (``plan.tracking``), else those of the solve running
    on ``system`` (:func:`planning_gains`), else None (:data:`DEFAULT_LQR`'s).

    Parameters
    ----------
    system : SwitchedSystem
    plan : ProbabilisticTSTrajectory or None

    Returns
    -------
    mapping or None
        Mode -> gains.
    """
    own = getattr(plan, "tracking", None)
    if isinstance(own, TrackingGains):
        return own.gains
    running = _PLANNING.get()
    if running is not None and running[0] == id(system):
        return running[1].gains
    return None
