"""Polytopes and belief cones (paper Fig. 4), backed by linear programs (scipy's HiGHS).

A :class:`Polytope` is ``{x : H x + c <= 0}``. A :class:`BeliefCone` is the set of Gaussian
beliefs ``N(m, S)`` with ``h_i' m + c_i + Phi^-1(1 - eps_i) sqrt(h_i' S h_i) <= 0`` for every
face ``i``: one chance constraint per face, not a joint one (95% per face of a box is not 95% for
the box).
"""

from __future__ import annotations

from functools import cached_property
from typing import Any

import numpy as np
from scipy.sparse import csr_matrix

from ._checks import as_covariance, as_matrix, as_vector
from .backends import BackendSolution, HighsBackend, LinearModel
from .chance import quantile, std_terms
from .errors import DimensionError, InvalidArgumentError

__all__ = [
    "Polytope",
    "FullDimensionalPolytope",
    "BeliefCone",
    "FullDimensionalBeliefCone",
    "quantile",
]

_INTERIOR_TOL = 1e-9


def _lp(
    cost: np.ndarray, A_ub: np.ndarray, b_ub: np.ndarray, upper_last: float | None = None
) -> BackendSolution:
    """``min cost'x`` s.t. ``A_ub x <= b_ub`` (free variables; ``upper_last`` bounds the last one)."""
    nvar = cost.shape[0]
    ub = np.full(nvar, np.inf)
    if upper_last is not None:
        ub[-1] = upper_last
    model = LinearModel(
        cost, csr_matrix(A_ub), np.full(b_ub.shape[0], -np.inf), b_ub, np.full(nvar, -np.inf), ub
    )
    return HighsBackend().solve(model, 60.0)


class Polytope:
    """The polyhedron ``{x in R^n : H x + c <= 0}`` (possibly unbounded or empty).

    Parameters
    ----------
    H : array_like, shape (k, n)
        One row per half-space.
    c : array_like, shape (k,)
        Offsets.

    Notes
    -----
    Geometry questions (emptiness, Chebyshev centre, bounding box, 2-D vertices) are answered
    by linear programs with scipy's HiGHS, so they are exact up to solver tolerances.
    """

    def __init__(self, H: Any, c: Any) -> None:
        H = np.asarray(H, dtype=float)
        if H.ndim == 1:
            H = H[None, :]
        self.H = as_matrix(H, "H")
        self.c = as_vector(c, "c", self.H.shape[0]) if self.H.shape[0] else np.zeros(0)

    @classmethod
    def from_inequalities(cls, A: Any, b: Any) -> Polytope:
        """Build ``{x : A x <= b}``.

        Parameters
        ----------
        A : array_like, shape (k, n)
            One row per inequality.
        b : array_like, shape (k,)
            Right-hand sides.

        Returns
        -------
        Polytope
            ``Polytope(A, -b)``.
        """
        A = as_matrix(A, "A")
        return cls(A, -as_vector(b, "b", A.shape[0]))

    @classmethod
    def box(cls, low: Any, high: Any) -> Polytope:
        """The axis-aligned box ``low <= x <= high``.

        Parameters
        ----------
        low : array_like, shape (n,)
            Lower bounds.
        high : array_like, shape (n,)
            Upper bounds, element-wise ``>= low``.

        Returns
        -------
        Polytope
        """
        low = as_vector(low, "low")
        high = as_vector(high, "high", low.shape[0])
        if np.any(low > high):
            raise InvalidArgumentError(f"box needs low <= high, got low={low}, high={high}")
        n = low.shape[0]
        return Polytope(np.vstack([np.eye(n), -np.eye(n)]), np.concatenate([-high, low]))

    @property
    def dim(self) -> int:
        """Ambient dimension ``n``."""
        return self.H.shape[1]

    @property
    def A(self) -> np.ndarray:
        """``A`` of the ``A x <= b`` form (same as ``H``)."""
        return self.H

    @property
    def b(self) -> np.ndarray:
        """``b`` of the ``A x <= b`` form (``-c``)."""
        return -self.c

    def contains(self, x: Any, tol: float = 1e-9) -> bool:
        """Whether the point ``x`` (shape (n,)) satisfies every inequality (within ``tol``).

        Parameters
        ----------
        x : array_like, shape (n,)
            The point.
        tol : float, default 1e-9
            Allowed violation: the test is ``H x + c <= tol``.

        Returns
        -------
        bool
        """
        x = as_vector(x, "x", self.dim)
        return bool(np.all(self.H @ x + self.c <= tol))

    def __contains__(self, x: Any) -> bool:
        return self.contains(x)

    @cached_property
    def _axis_box(self) -> tuple[np.ndarray, np.ndarray, bool] | None:
        """``(low, high, feasible)`` when every row bounds one coordinate (a box), else ``None``.

        Most propositions are boxes, and their geometry needs no LP: the bounds are read off
        the rows. ``feasible`` is False when a row without coefficients is violated
        (``0 x + c <= 0`` with ``c > 0``); ``low > high`` in some coordinate also means empty.
        """
        H, c = self.H, self.c
        nnz = np.count_nonzero(H, axis=1)
        if H.shape[0] == 0 or np.any(nnz > 1) or not (np.all(np.isfinite(H)) and np.all(np.isfinite(c))):
            return None
        n = self.dim
        low, high = np.full(n, -np.inf), np.full(n, np.inf)
        one = nnz == 1
        j = np.argmax(H[one] != 0, axis=1)
        a = H[one, j]
        with np.errstate(over="ignore", divide="ignore"):
            bound = -c[one] / a
        if not np.all(np.isfinite(bound)):
            return None  # a bound beyond floating point: leave it to the LP's tolerances
        up, down = a > 0, a < 0
        np.minimum.at(high, j[up], bound[up])
        np.maximum.at(low, j[down], bound[down])
        feasible = bool(np.all(c[~one] <= 0))
        return low, high, feasible

    @cached_property
    def _radius(self) -> float:
        """Chebyshev radius (``-inf`` when infeasible), without an LP for boxes."""
        if self.H.shape[0] == 0:
            return np.inf
        box = self._axis_box
        if box is not None:
            return _box_radius(box)
        center, radius = self._chebyshev
        return radius if center is not None else -np.inf

    @cached_property
    def _chebyshev(self) -> tuple[np.ndarray | None, float]:
        n = self.dim
        if self.H.shape[0] == 0:
            return np.zeros(n), np.inf
        norms = np.linalg.norm(self.H, axis=1)
        # Variables (x, r): maximise r s.t. H x + r |h| <= -c; r <= 1e6 keeps unbounded sets finite.
        A = np.hstack([self.H, norms[:, None]])
        res = _lp(np.r_[np.zeros(n), -1.0], A, -self.c, upper_last=1e6)
        if res.status != "optimal" or res.x is None:
            return None, -np.inf
        return res.x[:n], float(res.x[n])

    def is_empty(self) -> bool:
        """True when no point satisfies the inequalities."""
        return bool(self._radius < -_INTERIOR_TOL)

    def chebyshev_center(self) -> tuple[np.ndarray, float]:
        """Centre and radius of the largest inscribed ball (radius capped at 1e6 if unbounded).

        Raises
        ------
        InvalidArgumentError
            If the polytope is empty.
        """
        center, radius = self._chebyshev
        if center is None or radius < -_INTERIOR_TOL:
            raise InvalidArgumentError("the polytope is empty: it has no Chebyshev centre")
        return center.copy(), max(radius, 0.0)

    @property
    def is_full_dimensional(self) -> bool:
        """True when the polytope has an interior (a ball of positive radius fits)."""
        return bool(self._radius > _INTERIOR_TOL)

    def support(self, direction: Any) -> float:
        """``max_{x in P} d' x`` (``inf`` when unbounded, ``-inf`` when empty).

        Parameters
        ----------
        direction : array_like, shape (n,)
            The direction ``d``.

        Returns
        -------
        float
        """
        d = as_vector(direction, "direction", self.dim)
        box = self._axis_box
        if box is not None:
            return _box_support(box, d)
        res = _lp(-d, self.H, -self.c)
        if res.status == "infeasible":
            return -np.inf
        if res.status == "unbounded":
            return np.inf
        return float(-res.objective)

    def bounding_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Tight axis-aligned bounds ``(low, high)``, each shape (n,); infinite where unbounded."""
        cached = self.__dict__.get("_bbox")
        if cached is not None:
            return cached[0].copy(), cached[1].copy()
        low, high = self._bounding_box()
        self.__dict__["_bbox"] = (low, high)
        return low.copy(), high.copy()

    def _bounding_box(self) -> tuple[np.ndarray, np.ndarray]:
        n = self.dim
        box = self._axis_box
        if box is not None:
            if _box_radius(box) < -_INTERIOR_TOL:
                return np.full(n, np.inf), np.full(n, -np.inf)  # empty: what the support LPs return
            return box[0].copy(), box[1].copy()
        low, high = np.empty(n), np.empty(n)
        for i in range(n):
            e = np.zeros(n)
            e[i] = 1.0
            high[i] = self.support(e)
            low[i] = -self.support(-e)
        return low, high

    def vertices_2d(self, num_directions: int = 0) -> np.ndarray:
        """Vertices of a bounded 2-D polytope in counter-clockwise order, shape (v, 2).

        Computed from the half-space intersection of the (irredundant) faces around the
        Chebyshev centre (scipy / Qhull).

        Parameters
        ----------
        num_directions : int, default 0
            Not used: the vertices are computed exactly whatever its value.

        Returns
        -------
        ndarray, shape (v, 2)
        """
        if self.dim != 2:
            raise DimensionError(f"vertices_2d needs a 2-D polytope, got dimension {self.dim}")
        from scipy.spatial import HalfspaceIntersection

        center, radius = self.chebyshev_center()
        low, high = self.bounding_box()
        if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
            raise InvalidArgumentError("vertices_2d needs a bounded polytope")
        if radius <= _INTERIOR_TOL:
            # Degenerate (a segment or a point): its end points are the two farthest-apart
            # maximisers of linear objectives in eight directions (the box corners are not
            # vertices of a slanted segment).
            pts = []
            for d in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1), (1, -1), (-1, 1)):
                res = _lp(-np.asarray(d, dtype=float), self.H, -self.c)
                if res.status == "optimal" and res.x is not None:
                    pts.append(res.x)
            pts_arr = np.array(pts)
            dist = np.linalg.norm(pts_arr[:, None, :] - pts_arr[None, :, :], axis=2)
            i, j = np.unravel_index(int(np.argmax(dist)), dist.shape)
            if dist[i, j] <= 1e-9:
                return pts_arr[i : i + 1]
            return pts_arr[[i, j]]
        hs = HalfspaceIntersection(np.hstack([self.H, self.c[:, None]]), center)
        pts = hs.intersections
        ang = np.arctan2(pts[:, 1] - center[1], pts[:, 0] - center[0])
        pts = pts[np.argsort(ang)]
        keep = np.r_[True, np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9]
        return pts[keep]

    def intersect(self, other: Polytope) -> Polytope:
        """The intersection with another polytope of the same dimension.

        Parameters
        ----------
        other : Polytope
            A polytope of the same dimension ``n``.

        Returns
        -------
        Polytope
            A :class:`FullDimensionalPolytope` when the intersection has interior.
        """
        if other.dim != self.dim:
            raise DimensionError(f"cannot intersect polytopes of dimensions {self.dim} and {other.dim}")
        return make_polytope(np.vstack([self.H, other.H]), np.concatenate([self.c, other.c]))

    def is_disjoint(self, other: Polytope) -> bool:
        """True when no point lies in both polytopes (``self.intersect(other).is_empty()``).

        Parameters
        ----------
        other : Polytope
            A polytope of the same dimension ``n``.

        Returns
        -------
        bool
        """
        a, b = self._axis_box, other._axis_box
        if a is None or b is None or other.dim != self.dim:
            return self.intersect(other).is_empty()
        box = (np.maximum(a[0], b[0]), np.minimum(a[1], b[1]), a[2] and b[2])
        return bool(_box_radius(box) < -_INTERIOR_TOL)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(dim={self.dim}, faces={self.H.shape[0]})"


def _box_radius(box: tuple[np.ndarray, np.ndarray, bool]) -> float:
    """The Chebyshev LP's optimum for a box: half its narrowest width (capped at 1e6).

    A box that is empty only by rounding of its bounds (``low > high`` by less than a few
    ulps of their size, on top of the LP's own ``_INTERIOR_TOL``) is treated as touching, so
    emptiness is never claimed from rounding.
    """
    low, high, feasible = box
    if not feasible:
        return -np.inf
    with np.errstate(invalid="ignore"):
        half = 0.5 * (high - low)
    half = np.where(np.isnan(half), np.inf, half)
    r = float(min(np.min(half), 1e6)) if half.size else 1e6
    if -_INTERIOR_TOL > r:
        ends = np.concatenate([low[np.isfinite(low)], high[np.isfinite(high)]])
        scale = np.max(np.abs(ends), initial=0.0)
        if r >= -_INTERIOR_TOL - 4 * np.finfo(float).eps * scale:
            r = -_INTERIOR_TOL
    return r


def _box_support(box: tuple[np.ndarray, np.ndarray, bool], d: np.ndarray) -> float:
    """``max d'x`` over a box: each coordinate at the bound ``d`` points to."""
    low, high, _ = box
    if _box_radius(box) < -_INTERIOR_TOL:
        return -np.inf
    pos, neg = d > 0, d < 0
    ends = np.concatenate([high[pos], low[neg]])
    if not np.all(np.isfinite(ends)):
        return np.inf
    return float(d[pos] @ high[pos] + d[neg] @ low[neg])


class FullDimensionalPolytope(Polytope):
    """A polytope with a non-empty interior.

    Parameters
    ----------
    H : array_like, shape (k, n)
        One row per half-space.
    c : array_like, shape (k,)
        Offsets.
    """


def make_polytope(H: Any, c: Any) -> Polytope:
    """A :class:`FullDimensionalPolytope` when the set has interior, else a :class:`Polytope`."""
    poly = Polytope(H, c)
    if poly.is_full_dimensional:
        full = FullDimensionalPolytope.__new__(FullDimensionalPolytope)
        full.__dict__.update(poly.__dict__)
        return full
    return poly


class BeliefCone:
    """Gaussian beliefs satisfying a conjunction of chance constraints.

    Parameters
    ----------
    H : array_like, shape (k, n)
        Face normals ``h_i'``.
    c : array_like, shape (k,)
        Offsets ``c_i``.
    eps : array_like, shape (k,)
        Tolerances ``eps_i`` in ``[0, 0.5]``.
    """

    def __init__(self, H: Any, c: Any, eps: Any) -> None:
        H = np.asarray(H, dtype=float)
        if H.size == 0:
            # No faces: an empty conjunction (every belief satisfies it).
            self.H = np.zeros((0, H.shape[1] if H.ndim == 2 else 0))
        else:
            self.H = as_matrix(H[None, :] if H.ndim == 1 else H, "H")
        k = self.H.shape[0]
        self.c = as_vector(c, "c", k) if k else np.zeros(0)
        self.eps = as_vector(eps, "eps", k) if k else np.zeros(0)
        if np.any(self.eps < 0) or np.any(self.eps > 0.5):
            raise InvalidArgumentError(f"eps must lie in [0, 0.5], got {self.eps.tolist()}")
        self.z = quantile(self.eps)

    @property
    def dim(self) -> int:
        """Dimension ``n`` of the mean."""
        return self.H.shape[1]

    @property
    def num_faces(self) -> int:
        """Number of chance constraints."""
        return self.H.shape[0]

    def std_terms(self, cov: np.ndarray) -> np.ndarray:
        """``Phi^-1(1-eps_i) sqrt(h_i' S h_i)`` per face, shape (k,).

        ``eps = 0`` with positive variance gives inf.

        Parameters
        ----------
        cov : ndarray, shape (n, n)
            Covariance ``S`` of the belief.

        Returns
        -------
        ndarray, shape (k,)
        """
        return std_terms(self.H, self.z, cov)

    def slack(self, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """Per face, the distance of the deterministic equivalent from its bound (>= 0: holds).

        Parameters
        ----------
        mean : ndarray, shape (n,)
            Mean of the belief.
        cov : ndarray, shape (n, n)
            Covariance of the belief.

        Returns
        -------
        ndarray, shape (k,)
            ``-(H mean + c + std_terms(cov))``.
        """
        return -(self.H @ mean + self.c + self.std_terms(cov))

    def margin(self, mean: Any, cov: Any) -> float:
        """Smallest face slack (``inf`` for a cone with no faces); >= 0 iff the belief is inside.

        Parameters
        ----------
        mean : array_like, shape (n,)
            Mean of the belief.
        cov : array_like, shape (n, n)
            Covariance of the belief (symmetric positive semi-definite).

        Returns
        -------
        float
        """
        if self.num_faces == 0:
            mean = as_vector(mean, "mean", self.dim or None)
            as_covariance(cov, "cov", mean.shape[0])
            return np.inf
        mean = as_vector(mean, "mean", self.dim)
        cov = as_covariance(cov, "cov", self.dim)
        return float(np.min(self.slack(mean, cov)))

    def contains(self, mean: Any, cov: Any) -> bool:
        """Whether ``N(mean, cov)`` satisfies every chance constraint.

        Parameters
        ----------
        mean : array_like, shape (n,)
            Mean of the belief.
        cov : array_like, shape (n, n)
            Covariance of the belief.

        Returns
        -------
        bool
        """
        return self.margin(mean, cov) >= 0.0

    def mean_polytope(self, cov: Any) -> Polytope:
        """The means that satisfy the cone for a fixed covariance (a polytope).

        Parameters
        ----------
        cov : array_like, shape (n, n)
            The fixed covariance.

        Returns
        -------
        Polytope
        """
        cov = as_covariance(cov, "cov", self.dim)
        return make_polytope(self.H, self.c + self.std_terms(cov))

    @property
    def deterministic_region(self) -> Polytope:
        """The polytope of means for zero covariance (the cone's shape in state space)."""
        return make_polytope(self.H, self.c)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(dim={self.dim}, faces={self.num_faces})"


class FullDimensionalBeliefCone(BeliefCone):
    """A belief cone whose zero-covariance region has interior.

    Parameters
    ----------
    H : array_like, shape (k, n)
        Face normals ``h_i'``.
    c : array_like, shape (k,)
        Offsets ``c_i``.
    eps : array_like, shape (k,)
        Tolerances ``eps_i`` in ``[0, 0.5]``.
    """


def make_belief_cone(H: Any, c: Any, eps: Any) -> BeliefCone:
    """A :class:`FullDimensionalBeliefCone` when the mean region has interior.

    Otherwise a plain :class:`BeliefCone`.
    """
    cone = BeliefCone(H, c, eps)
    if cone.num_faces == 0 or Polytope(cone.H, cone.c).is_full_dimensional:
        full = FullDimensionalBeliefCone.__new__(FullDimensionalBeliefCone)
        full.__dict__.update(cone.__dict__)
        return full
    return cone
