"""MILP back-ends: SCIP answers as HiGHS does, and the eager MILP's plans hold on each back-end."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from scipy.sparse import csr_matrix

import idstlpy as stl
from idstlpy.backends import (
    LinearModel,
    available_backends,
    default_milp_backend,
    get_backend,
)
from idstlpy.backends_scip import ScipBackend
from idstlpy.errors import InvalidArgumentError
from idstlpy.scenarios import reach_avoid
from idstlpy.synthesis.options import SolverOptions

needs_scip = pytest.mark.skipif(not ScipBackend.is_available(), reason="pyscipopt is not installed")
MILP_BACKENDS = ["highs", pytest.param("scip", marks=needs_scip)]

INF = np.inf


def _model(c, rows, lo, hi, lb, ub, integer=None) -> LinearModel:
    integrality = None if integer is None else np.asarray(integer, dtype=float)
    return LinearModel(
        np.asarray(c, float),
        csr_matrix(np.asarray(rows, float)),
        np.asarray(lo, float),
        np.asarray(hi, float),
        np.asarray(lb, float),
        np.asarray(ub, float),
        integrality,
    )


def test_registry_scip_is_lazy_and_milp_only():
    # Importing idstlpy registers SCIP without importing pyscipopt.
    assert "scip" in available_backends(integer=True) or not ScipBackend.is_available()
    assert "scip" not in available_backends()  # no LP duals: not an LP back-end
    with pytest.raises(InvalidArgumentError, match="duals"):
        get_backend("scip")
    if "pyscipopt" not in sys.modules:  # another test may have solved with it already
        import idstlpy.backends  # noqa: F401

        assert "pyscipopt" not in sys.modules
    expected = "scip" if ScipBackend.is_available() else "highs"
    assert default_milp_backend() == expected
    assert SolverOptions().milp_backend == expected
    assert SolverOptions(milp_backend="highs").milp_backend == "highs"
    with pytest.raises(InvalidArgumentError, match="lp_backend"):
        SolverOptions(lp_backend="scip")


@needs_scip
def test_scip_matches_highs_on_small_models():
    # LP: min -x - 2y s.t. x + y <= 4, x - y >= -2, 0 <= x, y <= 3 -> (1, 3), -7.
    lp = _model([-1, -2], [[1, 1], [1, -1]], [-INF, -2], [4, INF], [0, 0], [3, 3])
    # MILP: the same with integer x, y and x + y <= 3.5 -> optimum -5 at (1, 2).
    milp = _model([-1, -2], [[1, 1], [1, -1]], [-INF, -2], [3.5, INF], [0, 0], [3, 3], [1, 1])
    # Ranged and equality rows, a free variable: x + y = 2, 0 <= x - y <= 1, min x -> x = 1.
    ranged = _model([1, 0], [[1, 1], [1, -1]], [2, 0], [2, 1], [-INF, -INF], [INF, INF])
    # Infeasible LP (x >= 2 and x <= 1) and MILP (x + y = 1.5 over integers).
    inf_lp = _model([0], [[1], [1]], [2, -INF], [INF, 1], [-INF], [INF])
    inf_milp = _model([0, 0], [[1, 1]], [1.5], [1.5], [0, 0], [5, 5], [1, 1])
    highs, scip = get_backend("highs", integer=True), get_backend("scip", integer=True)
    for model, value in ((lp, -7.0), (milp, -5.0), (ranged, 1.0)):
        a, b = highs.solve(model, 10), scip.solve(model, 10)
        assert a.status == b.status == "optimal"
        assert a.objective == pytest.approx(value) and b.objective == pytest.approx(value)
        r = model.A @ b.x
        assert np.all(r >= model.row_lo - 1e-6) and np.all(r <= model.row_hi + 1e-6)
        assert b.bound == pytest.approx(value)
    for model in (inf_lp, inf_milp):
        assert highs.solve(model, 10).status == scip.solve(model, 10).status == "infeasible"


@pytest.mark.parametrize("backend", MILP_BACKENDS)
def test_eager_milp_plan_satisfies_the_formula(backend):
    problem = reach_avoid(25)
    result = problem.solve_result(seed=0, lazy_candidates=0, milp_backend=backend, time_limit=60)
    assert result.status == "found", result.reason
    assert result.stats.milp_calls >= 1 and "eager MILP" in result.reason
    assert stl.satisfies(result.trajectory, problem.stl_formula)


@pytest.mark.parametrize("backend", MILP_BACKENDS)
def test_eager_milp_proves_infeasibility(backend):
    # From x = 1 at rest with |u| <= 0.5 the double integrator covers at most 0.5 * (1+2+3+4) = 5
    # in 5 steps: the goal at x >= 7 is out of reach, which only a multi-step argument shows.
    problem = reach_avoid(5)
    result = problem.solve_result(seed=0, lazy_candidates=0, milp_backend=backend, time_limit=60)
    assert result.status == "infeasible", result.reason
    assert result.stats.milp_calls >= 1 and "eager MILP" in result.reason


@needs_scip
def test_scip_eager_milp_is_reproducible():
    a = reach_avoid(25).solve_result(seed=0, lazy_candidates=0, milp_backend="scip", time_limit=60)
    b = reach_avoid(25).solve_result(seed=0, lazy_candidates=0, milp_backend="scip", time_limit=60)
    assert a.status == b.status == "found"
    assert np.array_equal(a.trajectory.get_control(), b.trajectory.get_control())


@needs_scip
def test_scip_first_look_then_full_solve_on_the_cached_model():
    from dataclasses import replace

    # Feasible: x + y >= 1 over binaries with a continuous z = x + y: the look finds a plan.
    easy = _model([0, 0, 0], [[1, 1, 0], [1, 1, -1]], [1, 0], [INF, 0], [0, 0, 0], [1, 1, 5], [1, 1, 0])
    scip = ScipBackend()
    look = scip.solve(replace(easy, first_look=True), 10)
    assert look.status == "optimal" and look.x is not None
    assert look.x[0] + look.x[1] >= 1 - 1e-9 and abs(look.x[2] - look.x[0] - look.x[1]) <= 1e-9
    # Infeasible by propagation alone (x + y = 3 over binaries): the look's answer is a proof.
    assert (
        scip.solve(
            replace(_model([0, 0], [[1, 1]], [3], [3], [0, 0], [1, 1], [1, 1]), first_look=True), 10
        ).status
        == "infeasible"
    )
    # Integer-infeasible by parity (2x + 2y - 2w = 1), LP-feasible: the look may stop without a
    # plan, never with a wrong status, and the full solve on the same (cached) SCIP model
    # answers as a fresh back-end does; then bounds changed on a cached model are honoured.
    rows = [[2, 2, -2, 0], [1, -1, 0, 1]]
    hard = _model([0, 0, 0, 0], rows, [1, 0.5], [1, 0.5], [0, 0, 0, 0], [3, 3, 3, 1], [1, 1, 1, 0])
    look = scip.solve(replace(hard, first_look=True), 10)
    assert look.status in ("infeasible", "time_limit") and look.x is None
    assert scip.solve(hard, 10).status == ScipBackend().solve(hard, 10).status == "infeasible"
    fixed = replace(easy, lb=np.array([0.0, 1.0, 0.0]))  # y fixed at 1 on the cached model
    first = ScipBackend()
    first.solve(easy, 10)
    again = first.solve(fixed, 10)
    assert again.status == "optimal" and again.x is not None and again.x[1] == pytest.approx(1.0)
    assert first.solve(easy, 10).status == "optimal"  # and back


def test_highs_ignores_the_first_look():
    from dataclasses import replace

    milp = _model([-1, -2], [[1, 1], [1, -1]], [-INF, -2], [3.5, INF], [0, 0], [3, 3], [1, 1])
    sol = get_backend("highs", integer=True).solve(replace(milp, first_look=True), 10)
    assert sol.status == "optimal" and sol.objective == pytest.approx(-5.0)


@needs_scip
def test_scip_eager_milp_takes_the_first_looks_plan(caplog):
    # The feasibility MILP's plan comes from the first look (no full solve), and still holds.
    problem = reach_avoid(25)
    with caplog.at_level("INFO", logger="idstlpy.synthesis.milp"):
        result = problem.solve_result(seed=0, lazy_candidates=0, milp_backend="scip", time_limit=60)
    assert result.status == "found" and "eager MILP" in result.reason
    assert stl.satisfies(result.trajectory, problem.stl_formula)
    assert any("binaries" in r.getMessage() for r in caplog.records)
    assert not any("first look found no plan" in r.getMessage() for r in caplog.records)
