"""Polytopes, belief cones and convex regions (paper Section IV, Fig. 4)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

import idstlpy as stl
from idstlpy.sets import make_belief_cone, make_polytope

# --------------------------------------------------------------------------------------------
# Polytope


def test_box_membership_and_representation():
    P = stl.Polytope.box([0.0, -1.0], [2.0, 1.0])
    assert P.dim == 2
    assert P.contains([1.0, 0.0])
    assert P.contains([2.0, 1.0])  # closed
    assert not P.contains([2.1, 0.0])
    assert [0.0, -1.0] in P
    assert [-0.5, 0.0] not in P
    # A x <= b form
    np.testing.assert_allclose(P.A @ np.array([2.0, 1.0]) - P.b, [0.0, 0.0, -2.0, -2.0], atol=1e-12)
    np.testing.assert_allclose(P.b, -P.c)


def test_from_inequalities_is_a_x_le_b():
    P = stl.Polytope.from_inequalities([[1.0, 1.0]], [1.0])
    assert P.contains([0.5, 0.5])
    assert not P.contains([0.6, 0.5])
    np.testing.assert_allclose(P.c, [-1.0])


def test_emptiness():
    assert not stl.Polytope.box([0, 0], [1, 1]).is_empty()
    # x <= 0 and x >= 1
    assert stl.Polytope([[1.0], [-1.0]], [0.0, 1.0]).is_empty()
    # a segment is not empty but not full-dimensional
    seg = stl.Polytope([[1.0, 1.0], [-1.0, -1.0], [-1.0, 0.0], [0.0, -1.0]], [-1.0, 1.0, 0.0, 0.0])
    assert not seg.is_empty()
    assert not seg.is_full_dimensional
    # 0 x <= -1: infeasible constant row
    assert stl.Polytope([[0.0, 0.0]], [1.0]).is_empty()


def test_chebyshev_center_of_box_and_triangle():
    center, radius = stl.Polytope.box([0, 0], [4, 2]).chebyshev_center()
    assert radius == pytest.approx(1.0)
    assert center[1] == pytest.approx(1.0)
    assert 1.0 - 1e-7 <= center[0] <= 3.0 + 1e-7
    # right triangle x >= 0, y >= 0, x + y <= 2: inradius 2 / (2 + sqrt 2), centre (r, r)
    tri = stl.Polytope([[-1.0, 0.0], [0.0, -1.0], [1.0, 1.0]], [0.0, 0.0, -2.0])
    c, r = tri.chebyshev_center()
    expected = 2.0 / (2.0 + np.sqrt(2.0))
    assert r == pytest.approx(expected, rel=1e-6)
    np.testing.assert_allclose(c, [expected, expected], atol=1e-6)
    with pytest.raises(stl.InvalidArgumentError, match="empty"):
        stl.Polytope([[1.0], [-1.0]], [0.0, 1.0]).chebyshev_center()


def test_bounding_box():
    tri = stl.Polytope([[-1.0, 0.0], [0.0, -1.0], [1.0, 1.0]], [0.0, 0.0, -2.0])
    low, high = tri.bounding_box()
    np.testing.assert_allclose(low, [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(high, [2.0, 2.0], atol=1e-9)
    half = stl.Polytope([[1.0, 0.0]], [-1.0])  # x <= 1, y free
    low, high = half.bounding_box()
    assert high[0] == pytest.approx(1.0)
    assert low[0] == -np.inf and low[1] == -np.inf and high[1] == np.inf


def _same_cycle(got: np.ndarray, expected: np.ndarray) -> bool:
    """Same vertices in the same cyclic counter-clockwise order."""
    if got.shape != expected.shape:
        return False
    start = int(np.argmin(np.linalg.norm(got - expected[0], axis=1)))
    return np.allclose(np.roll(got, -start, axis=0), expected, atol=1e-7)


def test_vertices_2d_box_triangle_and_redundant_faces():
    box = stl.Polytope.box([0, 0], [2, 1])
    assert _same_cycle(box.vertices_2d(), np.array([[0, 0], [2, 0], [2, 1], [0, 1]], dtype=float))
    tri = stl.Polytope([[-1.0, 0.0], [0.0, -1.0], [1.0, 1.0]], [0.0, 0.0, -2.0])
    assert _same_cycle(tri.vertices_2d(), np.array([[0, 0], [2, 0], [0, 2]], dtype=float))
    # diamond |x| + |y| <= 1 with redundant faces, one through the vertex (-1, 0)
    H = [[1, 1], [1, -1], [-1, 1], [-1, -1], [-1, 0], [0, 1], [3, 3]]
    c = [-1, -1, -1, -1, -1, -5, -9]
    diamond = stl.Polytope(H, c)
    expected = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], dtype=float)
    assert _same_cycle(diamond.vertices_2d(), expected)


def test_vertices_2d_degenerate_segment_and_point():
    # the segment from (1, 0) to (0, 1): its vertices are its end points, not box corners
    seg = stl.Polytope([[1.0, 1.0], [-1.0, -1.0], [-1.0, 0.0], [0.0, -1.0]], [-1.0, 1.0, 0.0, 0.0])
    v = seg.vertices_2d()
    assert v.shape == (2, 2)
    got = sorted(map(tuple, np.round(v, 7)))
    assert got == [(0.0, 1.0), (1.0, 0.0)]
    point = stl.Polytope.box([1.0, 2.0], [1.0, 2.0])
    np.testing.assert_allclose(point.vertices_2d(), [[1.0, 2.0]], atol=1e-9)


def test_vertices_2d_rejects_unbounded_and_non_2d():
    with pytest.raises(stl.InvalidArgumentError, match="bounded"):
        stl.Polytope([[1.0, 0.0]], [-1.0]).vertices_2d()
    with pytest.raises(stl.DimensionError, match="2-D"):
        stl.Polytope.box([0, 0, 0], [1, 1, 1]).vertices_2d()


def test_support_intersect_and_full_dimensional_class():
    box = stl.Polytope.box([0, 0], [2, 1])
    assert box.support([1.0, 1.0]) == pytest.approx(3.0)
    assert stl.Polytope([[1.0, 0.0]], [-1.0]).support([0.0, 1.0]) == np.inf
    inter = box.intersect(stl.Polytope.box([1, 0], [3, 3]))
    assert isinstance(inter, stl.FullDimensionalPolytope)
    low, high = inter.bounding_box()
    np.testing.assert_allclose(low, [1, 0], atol=1e-9)
    np.testing.assert_allclose(high, [2, 1], atol=1e-9)
    assert isinstance(make_polytope([[1.0, 0.0], [-1.0, 0.0]], [0.0, 0.0]), stl.Polytope)
    assert not isinstance(make_polytope([[1.0, 0.0], [-1.0, 0.0]], [0.0, 0.0]), stl.FullDimensionalPolytope)


# --------------------------------------------------------------------------------------------
# BeliefCone


def test_belief_cone_deterministic_equivalent_by_hand():
    # P(x0 - 1 <= 0) >= 0.95 on N((0.5, 0), diag(s^2, 4)): 0.5 - 1 + 1.6449 s <= 0 iff s <= 0.304
    cone = stl.BeliefCone([[1.0, 0.0]], [-1.0], [0.05])
    assert cone.contains([0.5, 0.0], np.diag([0.30**2, 4.0]))
    assert not cone.contains([0.5, 0.0], np.diag([0.31**2, 4.0]))
    assert cone.margin([0.5, 0.0], np.diag([0.09, 4.0])) == pytest.approx(0.5 - norm.ppf(0.95) * 0.3)
    # eps = 0.5: only the mean matters
    half = stl.BeliefCone([[1.0, 0.0]], [-1.0], [0.5])
    assert half.contains([1.0, 0.0], np.diag([100.0, 1.0]))
    # eps = 0: certainty needs zero variance along h
    zero = stl.BeliefCone([[1.0, 0.0]], [-1.0], [0.0])
    assert zero.contains([0.9, 0.0], np.diag([0.0, 5.0]))
    assert not zero.contains([0.9, 0.0], np.diag([1e-6, 0.0]))


def test_belief_cone_is_per_face_and_mean_polytope():
    # box |x_i| <= 1, 95% per face
    H = [[1, 0], [-1, 0], [0, 1], [0, -1]]
    cone = make_belief_cone(H, [-1, -1, -1, -1], [0.05] * 4)
    assert isinstance(cone, stl.FullDimensionalBeliefCone)
    cov = 0.25 * np.eye(2)
    poly = cone.mean_polytope(cov)
    low, high = poly.bounding_box()
    shrink = 1.0 - norm.ppf(0.95) * 0.5
    np.testing.assert_allclose(high, [shrink, shrink], atol=1e-7)
    np.testing.assert_allclose(low, [-shrink, -shrink], atol=1e-7)
    assert cone.deterministic_region.contains([1.0, -1.0])
    # per face: the joint probability of the box can be below 95% while every face holds
    rng = np.random.default_rng(3)
    m = np.array([shrink, shrink])
    assert cone.contains(m, cov)
    xs = rng.multivariate_normal(m, cov, size=100_000)
    inside = np.all(np.abs(xs) <= 1.0, axis=1).mean()
    assert inside < 0.95


def test_deterministic_equivalent_matches_monte_carlo():
    """P(h.x + c <= 0) >= 1 - eps, estimated from 200k samples, against BeliefCone.contains.

    Cases whose Monte Carlo estimate is within 4 standard errors of the level 1 - eps are not
    decidable by sampling and are skipped (counted, not asserted); the rest must agree.
    """
    rng = np.random.default_rng(20240601)
    num_samples = 200_000
    decided = 0
    for _ in range(30):
        n = 2
        h = rng.normal(size=n)
        eps = float(rng.uniform(0.01, 0.5))
        mean = rng.uniform(-2.0, 2.0, size=n)
        M = rng.normal(size=(n, n)) * rng.uniform(0.1, 1.0)
        cov = M @ M.T
        sd = np.sqrt(h @ cov @ h)
        # place c so the true probability is near the level: the quantile +- up to 1.5 sd
        c = -(h @ mean) - norm.ppf(1 - eps) * sd + rng.uniform(-1.5, 1.5) * sd
        xs = rng.multivariate_normal(mean, cov, size=num_samples)
        p_hat = float(np.mean(xs @ h + c <= 0.0))
        level = 1.0 - eps
        se = np.sqrt(level * (1 - level) / num_samples)
        if abs(p_hat - level) < 4 * se:
            continue  # too close to the boundary for Monte Carlo to decide
        decided += 1
        cone = stl.BeliefCone([h], [c], [eps])
        assert cone.contains(mean, cov) == (p_hat >= level), (h, c, eps, p_hat)
    assert decided >= 20


def test_belief_cone_without_faces_contains_everything():
    cone = stl.BeliefCone(np.zeros((0, 2)), [], [])
    assert cone.num_faces == 0
    assert cone.contains([5.0, -3.0], np.eye(2))
    assert stl.TRUE.cone.num_faces == 0


# --------------------------------------------------------------------------------------------
# ConvexRegion


def test_convex_region_of_linear_predicates_is_a_polytope():
    x = stl.mk_variable(2)
    region = stl.logical_and(x[0] >= -1.0, x[0] <= 1.0, x[1] >= -1.0, x[1] <= 1.0)
    assert isinstance(region, stl.ConvexRegion)
    assert not region.is_probabilistic
    poly = region.region
    assert isinstance(poly, stl.FullDimensionalPolytope)
    assert poly.contains([1.0, -1.0])
    assert not poly.contains([1.01, 0.0])
    prob_region = stl.prob(region) >= 0.9
    assert isinstance(prob_region, stl.ConvexRegion) and prob_region.is_probabilistic
    cone = prob_region.region
    assert isinstance(cone, stl.BeliefCone)
    assert cone.num_faces == 4
    np.testing.assert_allclose(cone.eps, [0.1] * 4)


def test_convex_region_rejects_mixing():
    x = stl.mk_variable(2)
    y = stl.mk_variable(2, name="y")
    with pytest.raises(stl.InvalidTypeError, match="cannot mix"):
        stl.ConvexRegion([x[0] <= 1, stl.prob(x[1] <= 1) >= 0.9])
    with pytest.raises(stl.InvalidArgumentError, match="same variable"):
        stl.ConvexRegion([x[0] <= 1, y[0] <= 1])
    with pytest.raises(stl.InvalidArgumentError, match="at least one"):
        stl.ConvexRegion([])
