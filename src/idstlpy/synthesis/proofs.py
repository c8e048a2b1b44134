"""What each proven clause rests on, and the certificate of an ``infeasible`` built from it.

The lazy loop keeps, with every clause it derives (LP pruning's facts, the teachers'
refutations), a *recipe* for its justification: the LP rows and the solver's float ray
(:class:`RowsProof`), an LP model whose ray is still to be read (:class:`ModelProof`), a
chance-constraint face a belief violates (:class:`FaceProof`), several of them (:class:`AllOf`)
or why there is none (:class:`NoProof`). Recipes are cheap to keep; only when the proposer runs
dry over proven clauses does :func:`build_certificate` turn the ones an unsatisfiable core needs
into exact justifications (:mod:`.certificates`) and check the whole certificate once, so that
``SolveResult.certificate`` never says certified when the checker would not.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from scipy.sparse import csr_matrix, identity, vstack

from ..backends import Backend, HighsBackend, LinearModel
from .certificates import (
    CERTIFICATE_SCHEMA,
    check_certificate,
    encode_clauses,
    exact_ray,
    farkas_justification,
    pack_json,
    second_solver,
)

__all__ = [
    "AllOf",
    "FaceProof",
    "ModelProof",
    "NoProof",
    "Proof",
    "RowsProof",
    "build_certificate",
    "uncertified_certificate",
]

logger = logging.getLogger(__name__)


class Proof(Protocol):
    """A recipe for one clause's justification."""

    def build(self, backend: Backend) -> dict[str, Any]:
        """The JSON justification (:mod:`.certificates`), exact where it can be made so."""
        ...


@dataclass
class NoProof:
    """A clause without a checkable certificate (``why`` says which argument it rests on)."""

    why: str

    def build(self, backend: Backend) -> dict[str, Any]:
        """An ``uncertified`` justification."""
        return {"kind": "uncertified", "why": self.why}


@dataclass
class RowsProof:
    """LP rows and a float Farkas ray of them (e.g. the elastic plan LP's duals).

    Attributes
    ----------
    A : csr_matrix, shape (R, C)
    rhs : ndarray, shape (R,)
    equality : ndarray of bool, shape (R,)
    ray : ndarray, shape (R,)
        ``>= 0`` on inequalities up to rounding, ``ray' A ~ 0``, ``ray' rhs < 0``.
    pivots : ndarray of bool, shape (R,)
        Rows whose multipliers the exact repair may solve for (:func:`~.certificates.exact_ray`).
    about : str
    """

    A: csr_matrix
    rhs: np.ndarray
    equality: np.ndarray
    ray: np.ndarray
    pivots: np.ndarray
    about: str

    def build(self, backend: Backend) -> dict[str, Any]:
        """The exact Farkas justification, or ``uncertified`` when no exact ray was found."""
        keep = self._rows()
        A = self.A[keep].tocsr()
        rhs, eq = self.rhs[keep], self.equality[keep]
        exact = exact_ray(A, rhs, eq, self.ray[keep], self.pivots[keep])
        if exact is None and not self.pivots[keep].all():
            # The pivots could not absorb the rounding (e.g. an input unbounded in a direction:
            # no control row along it): every multiplier but the largest solved for.
            exact = exact_ray(A, rhs, eq, self.ray[keep])
        if exact is None:
            return {"kind": "uncertified", "why": f"{self.about}: the LP's ray could not be made exact"}
        nz = [i for i, q in enumerate(exact) if q != 0]
        A = A[nz].tocsr()
        A.sort_indices()
        return farkas_justification(
            A.indptr, A.indices, A.data, rhs[nz], eq[nz], [exact[i] for i in nz], self.about
        )

    def _rows(self) -> np.ndarray:
        """The rows that matter: those with a multiplier, and the pivots that share a column
        with them (they may absorb the ray's rounding)."""
        y = np.abs(self.ray)
        scale = float(y.max()) if y.size else 0.0
        used = y > 1e-13 * scale
        cols = np.unique(self.A[used].indices) if np.any(used) else np.zeros(0, dtype=int)
        touch = np.zeros(self.A.shape[1], dtype=bool)
        touch[cols] = True
        reaches = np.asarray(self.A.astype(bool).astype(np.int32) @ touch.astype(np.int32)).ravel() > 0
        keep: np.ndarray = used | (self.pivots & reaches)
        return np.flatnonzero(keep)


@dataclass
class ModelProof:
    """An LP model a back end said is infeasible: its ray is read when needed (:func:`model_rows`)."""

    model: LinearModel
    about: str

    def build(self, backend: Backend) -> dict[str, Any]:
        """Solve the LP of its ray (:func:`model_rows`), then as :class:`RowsProof`."""
        rows = model_rows(self.model, backend, self.about)
        if isinstance(rows, NoProof):
            return rows.build(backend)
        return rows.build(backend)


@dataclass
class FaceProof:
    """A face ``h' x + c + z sqrt(h' S h) <= 0`` that the belief ``N(mean, cov)`` violates."""

    h: np.ndarray
    c: float
    z: float
    mean: np.ndarray
    cov: np.ndarray

    def build(self, backend: Backend) -> dict[str, Any]:
        """The ``face_violated`` justification."""
        return {
            "kind": "face_violated",
            "h": [float(v) for v in self.h],
            "c": float(self.c),
            "z": "inf" if np.isinf(self.z) else float(self.z),
            "mean": [float(v) for v in self.mean],
            "cov": [[float(v) for v in row] for row in self.cov],
        }


@dataclass
class AllOf:
    """Every part must hold (a clause that is proved once per mode)."""

    parts: list[Proof]

    def build(self, backend: Backend) -> dict[str, Any]:
        """An ``all_of`` justification (``uncertified`` when a part is)."""
        built = [part.build(backend) for part in self.parts]
        bad = [b for b in built if b.get("kind") == "uncertified"]
        if bad:
            return bad[0]
        return {"kind": "all_of", "parts": built}


def _as_rows(model: LinearModel) -> tuple[csr_matrix, np.ndarray, np.ndarray]:
    """``model``'s rows and finite bounds as ``a' x <= b`` / ``a' x = b`` rows."""
    A = model.A.tocsr()
    lo, hi = np.asarray(model.row_lo, dtype=float), np.asarray(model.row_hi, dtype=float)
    eq = np.isfinite(lo) & np.isfinite(hi) & (lo == hi)
    up = np.isfinite(hi) & ~eq
    down = np.isfinite(lo) & ~eq
    n = model.num_vars
    I = identity(n, format="csr")
    ub, lb = np.asarray(model.ub, dtype=float), np.asarray(model.lb, dtype=float)
    fu, fl = np.isfinite(ub), np.isfinite(lb)
    blocks = [A[eq], A[up], -A[down], I[fu], -I[fl]]
    rhs = np.concatenate([lo[eq], hi[up], -lo[down], ub[fu], -lb[fl]])
    kinds = np.concatenate(
        [np.ones(int(eq.sum()), dtype=bool), np.zeros(rhs.size - int(eq.sum()), dtype=bool)]
    )
    return vstack(blocks).tocsr(), rhs, kinds


def model_rows(model: LinearModel, backend: Backend, about: str) -> RowsProof | NoProof:
    """A float Farkas ray of an LP said infeasible, as the solution of the ray's own LP.

    The ray LP ``min b'y`` over ``A'y = 0``, ``sum of the inequality multipliers = 1``,
    ``y >= 0`` on inequalities has a negative optimum exactly when the rows are infeasible, and
    its solution is a ray. Unlike an elastic LP's optimum, which a solver reads as zero when the
    rows miss each other by less than its feasibility tolerance (two regions 1e-7 apart), its
    constraints are met to the solver's tolerance and only the sign of ``b'y`` is small; the
    exact repair and check (:func:`~.certificates.exact_ray`) decide that sign.

    Parameters
    ----------
    model : LinearModel
        The LP (its objective is ignored).
    backend : Backend
    about : str

    Returns
    -------
    RowsProof or NoProof
    """
    A, rhs, eq = _as_rows(model)
    R, n = A.shape
    ineq = (~eq).astype(float)
    M = vstack([A.T.tocsr(), csr_matrix(ineq[None, :])]).tocsr()
    lo = np.concatenate([np.zeros(n), [1.0]])
    lb = np.where(eq, -np.inf, 0.0)
    sol = backend.solve(LinearModel(rhs.astype(float), M, lo, lo.copy(), lb, np.full(R, np.inf)), 60.0)
    if sol.status != "optimal" or sol.x is None:
        return NoProof(f"{about}: the LP for its Farkas ray ended {sol.status}")
    if not sol.objective < 0:
        return NoProof(f"{about}: the LP for its Farkas ray finds none (optimum {sol.objective:.3g})")
    return RowsProof(A, rhs, eq, np.asarray(sol.x, dtype=float), np.ones(R, dtype=bool), about)


def uncertified_certificate(why: str, route: str) -> dict[str, Any]:
    """The certificate of a proof route that has none (the result says it is not certified).

    Parameters
    ----------
    why : str
    route : str
        E.g. ``"milp"``.

    Returns
    -------
    dict
    """
    return {
        "schema": CERTIFICATE_SCHEMA,
        "route": route,
        "certified": False,
        "uncertified": [why],
        "summary": f"not certified: {why}",
    }


PACK_FROM = 1 << 16
"""Characters of the justifications' JSON above which they are saved packed
(:func:`~.certificates.pack_json`)."""

CORE_FROM = 16
"""Distinct proofs above which only an unsatisfiable core's are built (a SAT call saves their LPs
and exact repairs; below, building them all costs less than the call)."""


def _core(
    encoding: Sequence[Sequence[int]],
    derived: Sequence[tuple[Sequence[int], Proof]],
    num_vars: int,
    primary: str,
) -> list[int] | None:
    """Indices of derived clauses that the encoding needs to stay unsatisfiable (``None``: it is
    satisfiable with all of them)."""
    from pysat.solvers import Solver

    with Solver(name=primary, bootstrap_with=[list(c) for c in encoding]) as solver:
        selectors = []
        for i, (clause, _) in enumerate(derived):
            s = num_vars + 1 + i
            selectors.append(s)
            solver.add_clause([int(v) for v in clause] + [-s])
        if solver.solve(assumptions=selectors):
            return None
        got = solver.get_core() or []
    return sorted(int(s) - num_vars - 1 for s in got)


def build_certificate(
    encoding: Sequence[Sequence[int]],
    derived: Sequence[tuple[Sequence[int], Proof]],
    num_vars: int,
    primary: str,
    backend: Backend | None = None,
) -> dict[str, Any]:
    """The certificate that the encoding and the derived clauses are unsatisfiable.

    An unsatisfiable core of the derived clauses is taken (the search's solver ``primary``, each
    derived clause behind a selector: the core is not trusted, only small), only the core's
    justifications are built, and the certificate is checked once
    (:func:`~.certificates.check_certificate`: exactly, and with a SAT solver of another family
    than ``primary``): its ``certified`` field is that check's verdict.

    Parameters
    ----------
    encoding : sequence of clauses
        The formula's encoding (trusted: the project's encoder).
    derived : sequence of (clause, Proof)
        Every proven clause, with what proves it.
    num_vars : int
        Variables of the encoding (every literal's variable is at most this).
    primary : str
        The python-sat solver that searched.
    backend : Backend, optional
        LP back end for the rays still to be read (default HiGHS).

    Returns
    -------
    dict
        The certificate (:data:`~.certificates.CERTIFICATE_SCHEMA`).
    """
    t0 = time.perf_counter()
    backend = backend if backend is not None else HighsBackend()
    second = second_solver(primary)
    core: list[int] | None = list(range(len(derived)))
    if len({id(proof) for _, proof in derived}) > CORE_FROM:
        core = _core(encoding, derived, num_vars, primary)
    if core is None:
        why = f"the SAT solver ({primary}) finds the proven clauses satisfiable on a second look"
        logger.warning("certificate: %s", why)
        out = uncertified_certificate(why, "sat")
        out["failed"] = True
        return out
    justifications: list[dict[str, Any]] = []
    seen: dict[int, int] = {}
    by: list[int] = []
    for i in core:
        proof = derived[i][1]
        key = id(proof)
        if key not in seen:
            seen[key] = len(justifications)
            justifications.append(proof.build(backend))
        by.append(seen[key])
    cert: dict[str, Any] = {
        "schema": CERTIFICATE_SCHEMA,
        "route": "sat",
        "claim": "the encoding and the derived clauses are unsatisfiable",
        "second_solver": second,
        "primary_solver": primary,
        "cnf": {
            "num_vars": int(num_vars),
            "encoding": encode_clauses(encoding),
            "derived": encode_clauses([derived[i][0] for i in core]),
            "justified_by": by,
        },
        "justifications": justifications,
        "uncertified": [],
    }
    check = check_certificate(cert)
    if len(json.dumps(justifications)) > PACK_FROM:
        del cert["justifications"]
        cert["justifications_z"] = pack_json(justifications)
    cert["certified"] = check.certified
    cert["summary"] = check.summary()
    if not check.ok:
        cert["failed"] = True
        logger.warning("certificate: %s", check.summary())
    cert["uncertified_parts"] = check.uncertified
    # (its time is the statistics' time_certificate: the certificate itself is the same on every run)
    logger.info("certificate of infeasible: %s (%.3f s)", check.summary(), time.perf_counter() - t0)
    return cert
