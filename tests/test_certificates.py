"""Certified ``infeasible`` (issue 32, item 6): every proof of the lazy loop carries a certificate
that the checker re-checks without the LP and SAT back ends, a tampered one fails, and
``idstlpy check`` reads it back from the result file."""

from __future__ import annotations

import ast
import copy
import json
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import csr_matrix

import idstlpy as stl
from idstlpy.cli import main
from idstlpy.synthesis import certificates
from idstlpy.synthesis.certificates import (
    check_certificate,
    check_farkas,
    decode_clauses,
    encode_clauses,
    exact_ray,
    farkas_justification,
)
from idstlpy.synthesis.results import load_result


def P(pred, level=0.99):
    return stl.prob(pred) >= level


def _line(x0, goal, T=20, noise=0.0):
    """A 1-D integrator, |u| <= 1, from ``x0``: ``goal`` (a predicate on x) within T steps."""
    x = stl.mk_variable(1)
    u = stl.mk_variable(1, name="u")
    system = stl.mk_switched_sys([stl.mk_lbs([[1.0]], [[1.0]], [[noise]])])
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1).region
    region = stl.logical_and(P(goal(x)), name="goal")
    return stl.Problem(system, domain, stl.to_belief([x0], [[0.0]]), stl.eventually(0, T, region))


def unreachable():
    """Refuted candidate by candidate: 20 plan LPs, each a Farkas certificate."""
    return _line(0.0, lambda x: x[0] >= 50)


def logically_unsatisfiable():
    """LP pruning alone (two disjoint regions required together)."""
    x = stl.mk_variable(2)
    u = stl.mk_variable(2, name="u")
    system = stl.mk_switched_sys([stl.mk_lbs(np.eye(2), np.eye(2), np.zeros((2, 2)))])
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    left = stl.logical_and(P(x[0] <= 0), name="left")
    right = stl.logical_and(P(x[0] >= 1), name="right")
    formula = stl.eventually(0, 30, stl.logical_and(stl.always(0, 5, left), stl.always(0, 5, right)))
    return stl.Problem(system, domain, stl.to_belief([0, 0], 0.01 * np.eye(2)), formula)


def initially_false():
    """The prior violates what step 0 requires: a face the belief violates."""
    x = stl.mk_variable(1)
    u = stl.mk_variable(1, name="u")
    system = stl.mk_switched_sys([stl.mk_lbs([[1.0]], [[1.0]], [[0.0]])])
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1).region
    safe = stl.logical_and(P(x[0] <= 1), name="safe")
    return stl.Problem(system, domain, stl.to_belief([3.0], [[0.01]]), stl.always(0, 5, safe))


def out_of_reach():
    """A narrow band at 99% under process noise: its confidence is out of reach."""
    x = stl.mk_variable(1)
    u = stl.mk_variable(1, name="u")
    system = stl.mk_switched_sys([stl.mk_lbs([[1.0]], [[1.0]], [[0.5]])])
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1).region
    band = stl.logical_and(P(x[0] >= -0.01), P(x[0] <= 0.01), name="band")
    return stl.Problem(system, domain, stl.to_belief([0.5], [[0.0]]), stl.eventually(1, 6, band))


def zero_variance():
    """A confidence of 1 (eps = 0) under process noise: every step has variance along its face."""
    x = stl.mk_variable(1)
    u = stl.mk_variable(1, name="u")
    system = stl.mk_switched_sys([stl.mk_lbs([[1.0]], [[1.0]], [[0.1]])])
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1).region
    sure = stl.logical_and(P(x[0] <= 5, 1.0), name="sure")
    return stl.Problem(system, domain, stl.to_belief([0.0], [[0.0]]), stl.eventually(1, 4, sure))


def two_modes_far():
    """Two modes, the goal out of reach of both: refutations over mode sequences."""
    x = stl.mk_variable(2)
    u = stl.mk_variable(1, name="u")
    modes = [
        stl.mk_lbs(np.eye(2), np.array([[1.0], [0.0]]), np.zeros((2, 2))),
        stl.mk_lbs(np.eye(2), np.array([[0.0], [1.0]]), np.zeros((2, 2))),
    ]
    system = stl.mk_switched_sys(modes)
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1).region
    goal = stl.logical_and(P(x[0] >= 20), P(x[1] >= 20), name="goal")
    return stl.Problem(system, domain, stl.to_belief([0, 0], np.zeros((2, 2))), stl.eventually(0, 8, goal))


PROBLEMS = {
    "unreachable": unreachable,
    "logically_unsatisfiable": logically_unsatisfiable,
    "initially_false": initially_false,
    "out_of_reach": out_of_reach,
    "two_modes_far": two_modes_far,
    "zero_variance": zero_variance,
}


@pytest.fixture(scope="module")
def solved():
    return {name: make().solve_result(rrt_timeout=30, seed=0) for name, make in PROBLEMS.items()}


@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_every_proof_is_certified_and_verifies(solved, name):
    result = solved[name]
    assert result.status == "infeasible"
    assert result.certified is True
    cert = result.certificate
    assert cert is not None and cert["route"] == "sat"
    check = check_certificate(json.loads(json.dumps(cert)))
    assert check.ok and check.certified, check.messages
    assert check.counts["derived clauses"] >= 1
    assert "not certified" not in result.reason
    assert result.stats.time_certificate > 0


def test_lp_refutations_carry_exact_farkas_rays(solved):
    cert = solved["unreachable"].certificate
    kinds = [j["kind"] for j in cert["justifications"]]
    assert kinds.count("farkas") >= 10  # one per refuted candidate the core needs
    for just in cert["justifications"]:
        if just["kind"] == "farkas":
            ray = [Fraction(v) for v in just["ray"]]
            assert all(q != 0 for q in ray)  # only the rows the proof uses are kept
            assert check_farkas(just) is None


def _first(cert, kind):
    return next(i for i, j in enumerate(cert["justifications"]) if j["kind"] == kind)


@settings(max_examples=30, deadline=None)
@given(st.data())
def test_changing_one_coefficient_of_a_farkas_row_fails(solved, data):
    cert = copy.deepcopy(solved["unreachable"].certificate)
    idx = _first(cert, "farkas")
    just = cert["justifications"][idx]
    p = data.draw(st.integers(0, len(just["data"]) - 1))
    delta = data.draw(st.sampled_from([1e-12, -1e-9, 0.5, -3.0]))
    just["data"][p] = just["data"][p] + delta * max(1.0, abs(just["data"][p]))
    assert check_farkas(just) is not None
    check = check_certificate(cert)
    assert not check.ok and any("y'A is not zero" in m for m in check.messages)


def test_tampered_rays_and_faces_fail(solved):
    cert = copy.deepcopy(solved["unreachable"].certificate)
    just = cert["justifications"][_first(cert, "farkas")]
    just["ray"][0] = str(
        -Fraction(just["ray"][0]) if just["sense"][0] == "L" else Fraction(just["ray"][0]) * 2
    )
    assert not check_certificate(cert).ok
    cert = copy.deepcopy(solved["initially_false"].certificate)
    face = cert["justifications"][_first(cert, "face_violated")]
    face["mean"] = [0.0 for _ in face["mean"]]  # the prior at the origin satisfies x <= 1
    assert not check_certificate(cert).ok


@pytest.mark.parametrize("name", ["initially_false", "logically_unsatisfiable", "unreachable"])
def test_dropping_the_derived_clauses_fails(solved, name):
    cert = copy.deepcopy(solved[name].certificate)
    cnf = cert["cnf"]
    derived = decode_clauses(cnf["derived"])
    # Every derived clause dropped: the encoding alone is satisfiable (the formula is).
    cnf["derived"], cnf["justified_by"] = encode_clauses([]), []
    check = check_certificate(cert)
    assert not check.ok and any("satisfiable" in m for m in check.messages)
    # A derived clause without its justification fails too.
    cert = copy.deepcopy(solved[name].certificate)
    cert["cnf"]["justified_by"] = cert["cnf"]["justified_by"][:-1]
    assert not check_certificate(cert).ok
    # A clause that no justification proves (pointing past the list) fails.
    cert = copy.deepcopy(solved[name].certificate)
    cert["cnf"]["justified_by"][0] = len(cert["justifications"])
    assert not check_certificate(cert).ok
    assert len(derived) >= 1


def test_dropping_a_needed_clause_fails(solved):
    """The one derived clause of the initial-belief proof is needed: without it (and its pointer)
    the second SAT solver finds a model."""
    cert = copy.deepcopy(solved["initially_false"].certificate)
    derived = decode_clauses(cert["cnf"]["derived"])
    assert len(derived) == 1
    cert["cnf"]["derived"] = encode_clauses(derived[1:])
    cert["cnf"]["justified_by"] = cert["cnf"]["justified_by"][1:]
    assert not check_certificate(cert).ok


def test_cli_check_round_trips_through_the_json(solved, tmp_path, capsys):
    path = solved["unreachable"].save(tmp_path / "result.json")
    assert load_result(path) == solved["unreachable"]
    assert main(["check", str(path)]) == 0
    assert "certificate verified" in capsys.readouterr().out
    data = json.loads(path.read_text())
    just = data["certificate"]["justifications"][_first(data["certificate"], "farkas")]
    just["data"][0] += 1.0
    bad = tmp_path / "tampered.json"
    bad.write_text(json.dumps(data))
    assert main(["check", str(bad)]) == 5
    assert "FAILED" in capsys.readouterr().out
    data["certificate"] = None
    bad.write_text(json.dumps(data))
    assert main(["check", str(bad)]) == 5
    assert main(["check", str(tmp_path / "missing.json")]) == 2


def test_an_eager_milp_proof_is_re_derived_and_certified():
    result = logically_unsatisfiable().solve_result(rrt_timeout=10, seed=0, lazy_candidates=0)
    assert result.status == "infeasible" and "eager MILP" in result.reason
    assert "re-derived by the lazy loop" in result.reason
    assert result.certified is True
    assert check_certificate(result.certificate).certified


def test_an_eager_milp_proof_without_re_derivation_says_it_is_not_certified(monkeypatch, tmp_path, capsys):
    from idstlpy.synthesis import cegis

    monkeypatch.setattr(cegis, "RECERTIFY_CANDIDATES", 0)
    result = unreachable().solve_result(rrt_timeout=10, seed=0, lazy_candidates=0)
    assert result.status == "infeasible"
    assert result.certified is False
    assert result.certificate is not None and result.certificate["route"] == "milp"
    assert "this proof is not certified" in result.reason
    check = check_certificate(result.certificate)
    assert check.ok and not check.certified
    path = result.save(tmp_path / "milp.json")
    assert main(["check", str(path)]) == 5
    assert "not every step is certified" in capsys.readouterr().out


def test_found_results_carry_no_certificate():
    result = _line(0.0, lambda x: x[0] >= 3, T=6).solve_result(rrt_timeout=10, seed=0)
    assert result.status == "found"
    assert result.certificate is None and result.certified is None


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.booleans())
def test_exact_ray_repairs_a_float_ray_of_a_random_infeasible_lp(seed, anchor_faces):
    """Free ``x`` fixed by random equalities ``E x = e`` and violated by ``g' x <= g' x* - 1``:
    the float ray (``E' y_E = -g`` solved in floats) is made exact, with the equalities as
    pivots (the inequality fixed, as a plan LP's faces) or every row a pivot."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 6))
    E = rng.normal(size=(n, n)) + 3 * np.eye(n)
    e = rng.normal(size=n)
    g = rng.normal(size=n)
    x_star = np.linalg.solve(E, e)
    A = np.vstack([E, g[None, :]])
    h = np.concatenate([e, [float(g @ x_star) - 1.0]])
    y = np.concatenate([np.linalg.solve(E.T, -g), [1.0]])
    eq = np.concatenate([np.ones(n, dtype=bool), [False]])
    pivots = eq.copy() if anchor_faces else None
    ray = exact_ray(csr_matrix(A), h, eq, y, pivots)
    assert ray is not None
    M = csr_matrix(A)
    just = farkas_justification(M.indptr, M.indices, M.data, h, eq, ray, "random")
    assert check_farkas(just) is None
    assert ray[-1] > 0


def test_the_checker_imports_nothing_from_the_solve_loop():
    tree = ast.parse(Path(certificates.__file__).read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            names.add(("." * node.level) + (node.module or ""))
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
    assert not any(name.startswith(".") or name.startswith("idstlpy") for name in names), names


def test_idstlpy_solve_writes_a_certificate_that_idstlpy_check_verifies(tmp_path, capsys):
    unsat = Path(__file__).resolve().parents[1] / "examples" / "unsatisfiable.toml"
    assert main(["solve", str(unsat), "--out", str(tmp_path), "--quiet"]) == 1
    (record,) = tmp_path.glob("*.json")
    data = json.loads(record.read_text())
    assert data["status"] == "infeasible" and data["certificate"]["certified"] is True
    capsys.readouterr()
    assert main(["check", str(record)]) == 0
    assert "certificate verified" in capsys.readouterr().out


def test_large_justifications_are_packed_and_still_verify(monkeypatch):
    from idstlpy.synthesis import proofs
    from idstlpy.synthesis.certificates import pack_json, unpack_json

    monkeypatch.setattr(proofs, "PACK_FROM", 0)
    result = unreachable().solve_result(rrt_timeout=30, seed=0)
    cert = json.loads(json.dumps(result.certificate))
    assert "justifications" not in cert and result.certified
    assert check_certificate(cert).certified
    justs = unpack_json(cert["justifications_z"])
    just = justs[_first({"justifications": justs}, "farkas")]
    just["data"][0] += 0.25
    cert["justifications_z"] = pack_json(justs)
    assert not check_certificate(cert).ok


def test_an_input_unbounded_in_a_direction_still_gets_an_exact_ray():
    """A plan LP whose control domain is open on one side (no control row along it to absorb
    the float ray's rounding): the repair solves every multiplier but the largest instead."""
    from tests.oracles.generators import infeasible_instance

    inst = infeasible_instance(2 * 7919 + 101, family="reach")
    assert "unbounded" in inst.tags
    result = inst.problem.solve_result(seed=inst.seed % 1000, rrt_timeout=2, time_limit=30)
    assert result.status == "infeasible"
    assert result.certified is True
    kinds = [j["kind"] for j in result.certificate["justifications"]]
    assert "farkas" in kinds
