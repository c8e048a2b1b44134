"""SCIP (through PySCIPOpt) as an LP / MILP back-end: ``SolverOptions(milp_backend="scip")``.

An optional extra (``pip install idstlpy[scip]``); registered lazily by :mod:`idstlpy.backends`
so importing idstlpy never imports ``pyscipopt``. :meth:`ScipBackend.is_available` checks that
the module can be found without importing it.

The model is handed to SCIP as a free-format MPS file in a temporary directory (2-3x faster
than building it row by row through PySCIPOpt's expressions), and re-used while the same matrix
comes back with other column bounds (the margin MILP's probes). SCIP runs single-threaded with
its default settings but for what the model asks (cuts, node limit, feasibility tolerance,
probing, a first look), silently, with ``limits/time`` as the cap.
Statuses map as for HiGHS: SCIP's ``infeasible`` is its proof; ``inforunbd`` is reported as
``infeasible`` only for a model without objective (where unboundedness cannot occur), and as
``error`` otherwise.
"""

from __future__ import annotations

import importlib.util
import os
import time
from typing import Any, ClassVar, NamedTuple

import numpy as np

from .backends import BackendSolution, LinearModel, SolutionStatus, quiet_stdout, register_backend

__all__ = ["ScipBackend", "write_mps"]

_INF = 1e20  # SCIP's default infinity
# The model file goes through memory where the system has a RAM file system (removing a
# temporary directory on a disk costs ~4 ms of wall clock per solve).
_TMP = "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None


class _Cached(NamedTuple):
    """The SCIP model of the last call, kept for a call on the same matrix (see ``solve``)."""

    key: tuple[Any, ...]
    scip: Any
    xs: list[Any]
    c: np.ndarray
    lb: np.ndarray  # the column bounds it holds (infinities as SCIP's)
    ub: np.ndarray


class ScipBackend:
    """SCIP through PySCIPOpt (LPs without duals, and MILPs).

    Attributes
    ----------
    params : dict
        Extra SCIP parameters set on every model (e.g. ``{"presolving/maxrounds": 0}``).
    """

    name: ClassVar[str] = "scip"
    supports_integer: ClassVar[bool] = True
    provides_duals: ClassVar[bool] = False  # MILPs only: the LP teachers need duals (HiGHS)

    def __init__(self, params: dict[str, Any] | None = None) -> None:
        self.params = dict(params or {})
        self._last: _Cached | None = None
        # Seconds per model entry (rows, columns, non-zeros) the slowest build on this instance
        # took: a build that would not fit in the time left is not started (SCIP cannot be
        # interrupted while it reads a model, seconds for a long horizon's MILP).
        self._build_rate = 0.0

    @classmethod
    def is_available(cls) -> bool:
        """Whether ``pyscipopt`` is installed (checked without importing it)."""
        try:
            return importlib.util.find_spec("pyscipopt") is not None
        except (ImportError, ValueError):
            return False

    def solve(self, model: LinearModel, time_limit: float) -> BackendSolution:
        """Solve ``model`` within ``time_limit`` seconds (see :class:`~idstlpy.backends.Backend`).

        ``row_duals`` are not reported, so SCIP serves as a MILP back-end only (the LP
        teachers read their certificates from duals).

        A model whose matrix, row bounds and integrality are the very objects of the previous
        call on this instance (the margin MILP's probes: only the column bounds and the
        objective change; a full solve after a first look) re-uses the SCIP model read then:
        the bounds that changed and the objective are reset and it is solved
        again from scratch (SCIP presolves anew), without writing and reading the file again.
        The arrays of a model handed to a back-end are never changed in place.

        Parameters
        ----------
        model : LinearModel
            The LP or MILP.
        time_limit : float
            Wall-clock cap in seconds (at least 1e-3 is used).

        Returns
        -------
        BackendSolution
        """
        import os
        import tempfile

        from pyscipopt import SCIP_PARAMSETTING, Model, quicksum

        entered = time.perf_counter()
        limit = max(float(time_limit), 1e-3)
        key = (model.A, model.row_lo, model.row_hi, model.integrality)
        cached = self._last
        lb = np.where(np.isfinite(model.lb), model.lb, np.where(model.lb > 0, _INF, -_INF))
        ub = np.where(np.isfinite(model.ub), model.ub, np.where(model.ub > 0, _INF, -_INF))
        if cached is not None and all(a is b for a, b in zip(cached.key, key, strict=True)):
            s, xs = cached.scip, cached.xs
            s.freeTransform()
            s.resetParams()
            # Only the bounds that differ from the last call's (an integer column's may be
            # fixed: set in an order that never crosses).
            for j in np.nonzero((lb != cached.lb) | (ub != cached.ub))[0].tolist():
                v, lo, hi = xs[j], float(lb[j]), float(ub[j])
                if lo > v.getUbOriginal():
                    s.chgVarUb(v, hi)
                    s.chgVarLb(v, lo)
                else:
                    s.chgVarLb(v, lo)
                    s.chgVarUb(v, hi)
            if not np.array_equal(cached.c, model.c):
                nz = np.nonzero(model.c)[0].tolist()
                s.setObjective(quicksum(float(model.c[j]) * xs[j] for j in nz), "minimize")
        else:
            self._last = None
            size = model.num_vars + model.num_rows + model.A.nnz
            if self._build_rate * size > limit:
                return BackendSolution(
                    "time_limit",
                    None,
                    message=f"the time limit leaves {limit:.2g} s, building the model takes about "
                    f"{self._build_rate * size:.2g} s: not started",
                )
            s = Model()
            s.hideOutput()
            with tempfile.TemporaryDirectory(prefix="idstlpy-scip-", dir=_TMP) as tmp:
                path = os.path.join(tmp, "model.mps")
                write_mps(model, path)
                with quiet_stdout():
                    s.readProblem(path)
            # The reader creates the columns in the order the file lists them (write_mps lists
            # every column, x0 first): no name lookup unless that ever fails.
            xs = s.getVars()
            n = model.num_vars
            if len(xs) != n or (n and (xs[0].name != "x0" or xs[-1].name != f"x{n - 1}")):
                by_name = {v.name: v for v in xs}
                xs = [by_name[f"x{j}"] for j in range(n)]
            self._build_rate = max(self._build_rate, (time.perf_counter() - entered) / max(size, 1))
        self._last = _Cached(key, s, xs, model.c.copy(), lb, ub)
        # The cap counts from this call: writing and reading the model (seconds for a long
        # horizon's MILP) come out of it, as SCIP's own clock starts with optimize.
        left = limit - (time.perf_counter() - entered)
        if left <= 0:
            return BackendSolution(
                "time_limit", None, message="the time limit was reached building the model"
            )
        s.setParam("limits/time", left)
        s.setParam("parallel/maxnthreads", 1)
        if model.mip_rel_gap is not None:
            s.setParam("limits/gap", float(model.mip_rel_gap))
        if not model.cuts:
            s.setParam("separating/maxrounds", 0)
            s.setParam("separating/maxroundsroot", 0)
        if model.node_limit is not None:
            s.setParam("limits/nodes", int(model.node_limit))
        if model.feas_tol is not None:
            s.setParam("numerics/feastol", float(model.feas_tol))
        if model.probing == "short":
            # Stop after 10 useless probes (NarrowPassage's margin probe at the cap 0.13 ->
            # 0.10 s, the infeasible ones unchanged).
            s.setParam("propagating/probing/maxtotaluseless", 10)
        elif model.probing == "off":
            s.setParam("propagating/probing/maxprerounds", 0)
        if not model.feaspump:
            s.setParam("heuristics/feaspump/freq", -1)
        if model.first_look:
            # Shift-and-propagate is the one heuristic that finds the eager MILPs' plans before
            # the first LP (stlpy's scenarios, T = 25-200); the others (locks: 20-60% of the
            # look's time) are switched off.
            s.setPresolve(SCIP_PARAMSETTING.OFF)
            s.setHeuristics(SCIP_PARAMSETTING.OFF)
            s.setParam("heuristics/shiftandpropagate/freq", 0)
            s.setParam("limits/nodes", 1)
            s.setParam("lp/rootiterlim", 1)
        for key_, val in self.params.items():
            s.setParam(key_, val)
        with quiet_stdout():
            s.optimize()
        return _solution(s, xs, model)


def write_mps(model: LinearModel, path: str) -> None:
    """Write ``model`` as a free-format MPS file (columns ``x<j>``, rows ``r<i>``).

    Handing SCIP a file is 2-3x faster than building its model row by row from Python on the
    eager MILPs (which have up to ~30,000 rows); values are written with ``repr`` (exact).
    """
    A = model.A.tocsc()
    n = model.num_vars
    lo, hi = np.asarray(model.row_lo, float), np.asarray(model.row_hi, float)
    flo, fhi = np.isfinite(lo), np.isfinite(hi)
    eq = flo & fhi & (lo == hi)
    kinds = np.where(eq, "E", np.where(flo, "G", np.where(fhi, "L", "N")))
    kinds = np.where(kinds == "N", "G", kinds)  # a free row: x >= -inf, written as G with rhs -1e20
    out = ["NAME idstlpy", "ROWS", " N obj"]
    out += [f" {k} r{i}" for i, k in enumerate(kinds.tolist())]
    out.append("COLUMNS")
    integ = np.zeros(n, dtype=bool) if model.integrality is None else np.asarray(model.integrality) != 0
    c = np.asarray(model.c, float).tolist()
    indptr = A.indptr.tolist()
    # Every entry's line at once, each distinct value formatted once (the matrices hold a few
    # hundred distinct values in ~20,000 entries): half the time of formatting entry by entry.
    col = np.repeat(np.arange(n), np.diff(A.indptr)).tolist()
    uniq, inv = np.unique(A.data, return_inverse=True)
    text = [repr(u) for u in uniq.tolist()]
    entries = [f" x{j} r{i} {text[k]}" for j, i, k in zip(col, A.indices.tolist(), inv.tolist(), strict=True)]
    in_int = False
    for j in range(n):
        if bool(integ[j]) != in_int:
            in_int = not in_int
            out.append(f" M{j} 'MARKER' '{'INTORG' if in_int else 'INTEND'}'")
        a, b = indptr[j], indptr[j + 1]
        if c[j] or a == b:
            out.append(f" x{j} obj {c[j]!r}")
        out += entries[a:b]
    if in_int:
        out.append(" Mend 'MARKER' 'INTEND'")
    out.append("RHS")
    rhs = np.where(kinds == "L", hi, np.where(flo, lo, -_INF)).tolist()
    out += [f" rhs r{i} {v!r}" for i, v in enumerate(rhs) if v != 0]
    ranged = np.nonzero(~eq & flo & fhi)[0].tolist()
    if ranged:
        out.append("RANGES")
        out += [f" rng r{i} {float(hi[i] - lo[i])!r}" for i in ranged]
    out.append("BOUNDS")
    lb, ub = np.asarray(model.lb, float).tolist(), np.asarray(model.ub, float).tolist()
    for j in range(n):
        lj, uj = lb[j], ub[j]
        if lj == -np.inf and uj == np.inf:
            out.append(f" FR bnd x{j}")
            continue
        if lj == -np.inf:
            out.append(f" MI bnd x{j}")
        else:
            out.append(f" LO bnd x{j} {lj!r}")
        if uj == np.inf:
            out.append(f" PL bnd x{j}")
        else:
            out.append(f" UP bnd x{j} {uj!r}")
    out.append("ENDATA")
    with open(path, "w") as fh:
        fh.write("\n".join(out))
        fh.write("\n")


def _ranged(expr: Any, lo: float, hi: float) -> Any:
    """The constraint ``lo <= expr <= hi`` (one-sided when a side is infinite)."""
    if lo <= -_INF:
        return expr <= float(hi)
    if hi >= _INF:
        return expr >= float(lo)
    if lo == hi:
        return expr == float(lo)
    return float(lo) <= (expr <= float(hi))


def _solution(s: Any, xs: list[Any], model: LinearModel) -> BackendSolution:
    st = s.getStatus()
    has = s.getNSols() > 0
    x = None
    if has:
        sol = s.getBestSol()
        x = np.array([s.getSolVal(sol, v) for v in xs], dtype=float)
    status: SolutionStatus
    if st == "optimal":
        status = "optimal"
    elif st == "infeasible":
        status = "infeasible"
    elif st == "unbounded":
        status = "unbounded"
    elif st == "inforunbd":
        status = "infeasible" if not np.any(model.c) else "error"
    elif st in ("timelimit", "userinterrupt", "nodelimit", "gaplimit", "sollimit", "memlimit"):
        status = "time_limit"
    else:
        status = "error"
    obj = float(s.getObjVal()) if has else float("nan")
    try:
        bound = float(s.getDualbound())
    except Exception:  # pragma: no cover - depends on the SCIP stage
        bound = float("nan")
    if status == "optimal":
        bound = obj
    return BackendSolution(status, x if status != "infeasible" else None, obj, None, f"SCIP: {st}", bound)


register_backend(ScipBackend)
