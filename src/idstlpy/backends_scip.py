"""SCIP (through PySCIPOpt) as an LP / MILP back-end: ``SolverOptions(milp_backend="scip")``.

An optional extra (``pip install idstlpy[scip]``); registered lazily by :mod:`idstlpy.backends`
so importing idstlpy never imports ``pyscipopt``. :meth:`ScipBackend.is_available` checks that
the module can be found without importing it.

The model is handed to SCIP row by row through PySCIPOpt's linear expressions; on the eager
MILPs of the benchmarks (up to ~30,000 rows) building it costs a fraction of the solve. SCIP
runs single-threaded with its default settings, silently, with ``limits/time`` as the cap.
Statuses map as for HiGHS: SCIP's ``infeasible`` is its proof; ``inforunbd`` is reported as
``infeasible`` only for a model without objective (where unboundedness cannot occur), and as
``error`` otherwise.
"""

from __future__ import annotations

import importlib.util
from typing import Any, ClassVar

import numpy as np

from .backends import BackendSolution, LinearModel, SolutionStatus, quiet_stdout

__all__ = ["ScipBackend"]

_INF = 1e20  # SCIP's default infinity


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
        """
        from pyscipopt import Model, quicksum

        limit = max(float(time_limit), 1e-3)
        s = Model()
        s.hideOutput()
        s.setParam("limits/time", limit)
        s.setParam("parallel/maxnthreads", 1)
        for key, val in self.params.items():
            s.setParam(key, val)
        integ = model.integrality if model.integrality is not None else np.zeros(model.num_vars)
        lb = np.where(np.isfinite(model.lb), model.lb, -_INF)
        ub = np.where(np.isfinite(model.ub), model.ub, _INF)
        xs = []
        for j in range(model.num_vars):
            binary = integ[j] and lb[j] >= 0 and ub[j] <= 1
            vtype = "B" if binary else ("I" if integ[j] else "C")
            xs.append(s.addVar(vtype=vtype, lb=float(lb[j]), ub=float(ub[j]), obj=float(model.c[j])))
        A = model.A.tocsr()
        indptr, indices, data = A.indptr, A.indices, A.data
        lo = np.where(np.isfinite(model.row_lo), model.row_lo, -_INF)
        hi = np.where(np.isfinite(model.row_hi), model.row_hi, _INF)
        for r in range(model.num_rows):
            a, b = indptr[r], indptr[r + 1]
            if a == b:
                if lo[r] > 1e-9 or hi[r] < -1e-9:
                    return BackendSolution("infeasible", None, message="an empty row with a non-zero bound")
                continue
            cols, vals = indices[a:b].tolist(), data[a:b].tolist()
            expr = quicksum(v * xs[c] for c, v in zip(cols, vals, strict=True))
            s.addCons(_ranged(expr, float(lo[r]), float(hi[r])))
        with quiet_stdout():
            s.optimize()
        return _solution(s, xs, model)


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
