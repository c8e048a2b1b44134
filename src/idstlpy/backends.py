"""LP and MILP back-ends behind one small interface.

A back-end takes a pure linear model (:class:`LinearModel`: ``min c'x`` subject to
``row_lo <= A x <= row_hi``, ``lb <= x <= ub``, some variables integer) and a wall-clock cap,
and returns a :class:`BackendSolution`: a status, the solution, and for LPs the row duals (from
which the teachers read infeasibility certificates). Back-ends register themselves by name;
adding a solver is a new class and one :func:`register_backend` call, nothing else changes.
HiGHS (through SciPy) is always available and is the default; SCIP (``pyscipopt``, the
``scip`` extra) registers as ``"scip"`` without being imported until it solves.
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, ClassVar, Literal, Protocol

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, linprog, milp
from scipy.sparse import csr_matrix, vstack

from .errors import InvalidArgumentError

__all__ = [
    "Backend",
    "BackendSolution",
    "HighsBackend",
    "LinearModel",
    "available_backends",
    "default_milp_backend",
    "get_backend",
    "register_backend",
]

logger = logging.getLogger(__name__)

SolutionStatus = Literal["optimal", "infeasible", "unbounded", "time_limit", "error"]


@dataclass
class LinearModel:
    """``min c'x`` subject to ``row_lo <= A x <= row_hi`` and ``lb <= x <= ub``.

    Parameters
    ----------
    c : ndarray, shape (nvar,)
        Objective coefficients.
    A : scipy.sparse.csr_matrix, shape (nrow, nvar)
        Constraint matrix.
    row_lo, row_hi : ndarray, shape (nrow,)
        Row bounds: ``-inf`` / ``inf`` for one-sided rows; equal for equalities.
    lb, ub : ndarray, shape (nvar,)
        Variable bounds (``-inf`` / ``inf`` where free).
    integrality : ndarray of int, shape (nvar,), optional
        1 for integer variables (a MILP), 0 for continuous ones.
    mip_rel_gap : float, optional
        Relative optimality gap at which a MILP may stop; ``None``: 1e-7 when the objective is
        not zero (an optimum is asked for), the back-end's default otherwise.
    cuts : bool, default True
        False asks a MILP back-end to skip cutting planes (SCIP: no separation rounds; HiGHS has
        no such switch and ignores it), for models whose relaxation is already as tight as the
        cuts would make it.
    node_limit : int, optional
        Branch-and-bound nodes after which a MILP back-end stops (``time_limit`` status): a
        deterministic budget, unlike the wall clock.
    feas_tol : float, optional
        Feasibility tolerance of the rows (and of integrality) for a MILP; ``None``: the
        back-end's default (1e-6). A tighter one makes a claim of infeasibility hold for every
        point within it, so that a level a tolerance above an optimum is refuted (the margin
        MILP's proofs, :mod:`idstlpy.synthesis.milp`).
    probing : {"full", "short", "off"}, default "full"
        How much of its presolve a MILP back-end may spend probing the binaries (SCIP: its
        default; stop after 10 useless probes; none). Probing proves infeasible models in
        presolve, but on a feasible one it mostly delays the first solution (measured on the
        eager MILPs, BENCHMARKS.md); HiGHS ignores it.
    feaspump : bool, default True
        False asks a MILP back-end to skip its feasibility pump (SCIP; HiGHS ignores it): on
        the eager feasibility MILPs the pump mostly fails and conflict diving finds the plan
        (NarrowPassage T = 200: SCIP 1.07 -> 0.78 s CPU without it; BENCHMARKS.md, Analysis).
        A primal heuristic only: answers and proofs of infeasibility are unchanged in kind.
    first_look : bool, default False
        True asks a MILP back-end for a cheap first look instead of a full solve: the model as
        given (no presolve), the root node only, and only a primal heuristic that runs before
        its first LP (SCIP: presolving off, a node limit of 1, the root LP stopped after one
        iteration, shift-and-propagate alone, which solves the LP of the continuous part). It
        returns ``time_limit`` without a plan where they find none, and its ``infeasible`` is
        still a proof. A deterministic budget (no clock); HiGHS ignores it and solves fully.
    """

    c: np.ndarray
    A: csr_matrix
    row_lo: np.ndarray
    row_hi: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    integrality: np.ndarray | None = None
    mip_rel_gap: float | None = None
    cuts: bool = True
    node_limit: int | None = None
    feas_tol: float | None = None
    probing: Literal["full", "short", "off"] = "full"
    feaspump: bool = True
    first_look: bool = False

    @property
    def num_vars(self) -> int:
        """Number of variables."""
        return int(self.c.shape[0])

    @property
    def num_rows(self) -> int:
        """Number of rows of ``A``."""
        return int(self.A.shape[0])

    @property
    def is_mip(self) -> bool:
        """True when some variable is integer."""
        return self.integrality is not None and bool(np.any(self.integrality))


@dataclass
class BackendSolution:
    """What a back-end returns.

    Parameters
    ----------
    status : {"optimal", "infeasible", "unbounded", "time_limit", "error"}
        ``infeasible`` is the solver's proof of infeasibility; ``time_limit`` and ``error`` are
        not proofs of anything.
    x : ndarray, shape (nvar,), or None
        A solution (for ``time_limit``, the best feasible one found, if any).
    objective : float
        Objective value of ``x`` (``nan`` without a solution).
    row_duals : ndarray, shape (nrow,), or None
        LP duals of the rows, sign convention ``d objective / d row bound`` (``<= 0`` on an
        active upper bound of a minimisation).
    message : str
        The solver's own status message.
    bound : float
        For a MILP, the best proven lower bound on the objective (``nan`` when unknown); equal
        to ``objective`` at a proven optimum.
    """

    status: SolutionStatus
    x: np.ndarray | None
    objective: float = float("nan")
    row_duals: np.ndarray | None = None
    message: str = ""
    bound: float = float("nan")


class Backend(Protocol):
    """The interface every LP / MILP back-end implements.

    A :class:`typing.Protocol`: it is never instantiated itself (calling it raises ``TypeError``);
    back-ends such as :class:`HighsBackend` implement it structurally, and :func:`get_backend`
    builds them with no arguments.

    Parameters
    ----------
    *args, **kwargs
        The placeholder signature ``typing.Protocol`` gives the class; any call is rejected.
    """

    name: ClassVar[str]
    supports_integer: ClassVar[bool]

    @classmethod
    def is_available(cls) -> bool:
        """Whether the solver can be used here (checked without importing it where possible)."""
        ...

    def solve(self, model: LinearModel, time_limit: float) -> BackendSolution:
        """Solve ``model`` within ``time_limit`` seconds.

        Parameters
        ----------
        model : LinearModel
            The LP or MILP (a MILP when ``model.is_mip``).
        time_limit : float
            Wall-clock cap in seconds.

        Returns
        -------
        BackendSolution
        """
        ...


@contextlib.contextmanager
def quiet_stdout() -> Iterator[None]:
    """Silence a native solver's direct writes to file descriptor 1 (library code never prints)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        yield
        return
    sys.stdout.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


def _highs_core() -> Any:
    """SciPy's bundled HiGHS bindings (``None`` when this SciPy has none)."""
    try:
        from scipy.optimize._highspy import _core
    except ImportError:  # pragma: no cover - depends on the SciPy build
        return None
    return _core if hasattr(_core, "_Highs") and hasattr(_core, "HighsLp") else None


def _highs_direct(model: LinearModel, limit: float) -> BackendSolution | None:
    """Solve through SciPy's HiGHS bindings directly; ``None`` when they are unavailable."""
    core = _highs_core()
    if core is None:
        return None
    inf = core.kHighsInf
    A = model.A.tocsc()
    lp = core.HighsLp()
    lp.num_col_ = model.num_vars
    lp.num_row_ = model.num_rows
    lp.col_cost_ = np.asarray(model.c, dtype=float)
    lp.col_lower_ = np.where(np.isfinite(model.lb), model.lb, -inf)
    lp.col_upper_ = np.where(np.isfinite(model.ub), model.ub, inf)
    lp.row_lower_ = np.where(np.isfinite(model.row_lo), model.row_lo, -inf)
    lp.row_upper_ = np.where(np.isfinite(model.row_hi), model.row_hi, inf)
    lp.a_matrix_.format_ = core.MatrixFormat.kColwise
    lp.a_matrix_.num_col_ = model.num_vars
    lp.a_matrix_.num_row_ = model.num_rows
    lp.a_matrix_.start_ = A.indptr.astype(np.int32)
    lp.a_matrix_.index_ = A.indices.astype(np.int32)
    lp.a_matrix_.value_ = A.data.astype(float)
    mip = model.is_mip
    if mip and model.integrality is not None:  # is_mip implies it; the test narrows the type
        kinds = core.HighsVarType
        lp.integrality_ = [kinds.kInteger if v else kinds.kContinuous for v in model.integrality]
    h = core._Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("time_limit", float(limit))
    if mip:
        # HiGHS' own default gap (1e-4) would call a plan optimal that is not (see _gap).
        h.setOptionValue("mip_rel_gap", _gap(model))
        if model.node_limit is not None:
            h.setOptionValue("mip_max_nodes", int(model.node_limit))
        if model.feas_tol is not None:
            h.setOptionValue("mip_feasibility_tolerance", float(model.feas_tol))
            h.setOptionValue("primal_feasibility_tolerance", min(1e-7, float(model.feas_tol)))
    with quiet_stdout():
        h.passModel(lp)
        h.run()
    st = h.getModelStatus()
    ms = core.HighsModelStatus
    info = h.getInfo()
    sol = h.getSolution()
    has_x = info.primal_solution_status == core.SolutionStatus.kSolutionStatusFeasible.value or (
        st == ms.kOptimal
    )
    x = np.asarray(sol.col_value, dtype=float) if has_x and model.num_vars else None
    if x is not None and x.shape[0] != model.num_vars:
        x = None
    status: SolutionStatus
    if st == ms.kOptimal or (st == ms.kModelEmpty and model.num_vars == 0):
        status = "optimal"
    elif st == ms.kInfeasible:
        status = "infeasible"
    elif st == ms.kUnbounded:
        status = "unbounded"
    elif st == ms.kUnboundedOrInfeasible:
        # Without an objective nothing is unbounded; otherwise ask again without presolve.
        if not np.any(model.c):
            status = "infeasible"
        else:
            h.setOptionValue("presolve", "off")
            with quiet_stdout():
                h.run()
            st = h.getModelStatus()
            status = {ms.kInfeasible: "infeasible", ms.kUnbounded: "unbounded"}.get(st, "error")  # type: ignore[assignment]
    elif st in (ms.kTimeLimit, ms.kIterationLimit, ms.kInterrupt, ms.kHighsInterrupt, ms.kSolutionLimit):
        status = "time_limit"
    else:
        status = "error"
    if status == "infeasible":
        x = None
    fun = float(info.objective_function_value) if x is not None else float("nan")
    duals = None
    if status == "optimal" and not mip:
        duals = np.asarray(sol.row_dual, dtype=float)
        if duals.shape[0] != model.num_rows:
            duals = None
    bound = float(info.mip_dual_bound) if mip else float("nan")
    if status == "optimal" and not np.isfinite(bound):
        bound = fun
    return BackendSolution(status, x, fun, duals, f"HiGHS: {h.modelStatusToString(st)}", bound)


class HighsBackend:
    """HiGHS through :func:`scipy.optimize.linprog` (LPs, with duals) and :func:`~scipy.optimize.milp`."""

    name: ClassVar[str] = "highs"
    supports_integer: ClassVar[bool] = True
    provides_duals: ClassVar[bool] = True

    @classmethod
    def is_available(cls) -> bool:
        """SciPy ships HiGHS: always available."""
        return True

    def solve(self, model: LinearModel, time_limit: float) -> BackendSolution:
        """Solve ``model`` (see :class:`Backend`).

        Goes straight to the HiGHS that SciPy ships (one model, no input re-validation: about
        0.3 ms per small LP instead of 3 ms); falls back to :func:`~scipy.optimize.linprog` /
        :func:`~scipy.optimize.milp` when that module is not there.

        Parameters
        ----------
        model : LinearModel
            The LP or MILP (a MILP when ``model.is_mip``).
        time_limit : float
            Wall-clock cap in seconds (at least 1e-3 is used).

        Returns
        -------
        BackendSolution
            With row duals for an optimal LP.
        """
        limit = max(float(time_limit), 1e-3)
        direct = _highs_direct(model, limit)
        if direct is not None:
            return direct
        if model.is_mip:
            return self._milp(model, limit)
        return self._lp(model, limit)

    @staticmethod
    def _milp(model: LinearModel, limit: float) -> BackendSolution:
        with quiet_stdout():
            res = milp(
                model.c,
                integrality=model.integrality,
                bounds=Bounds(model.lb, model.ub),
                constraints=LinearConstraint(model.A, model.row_lo, model.row_hi),
                options={
                    "time_limit": limit,
                    "disp": False,
                    "mip_rel_gap": _gap(model),
                    **({} if model.node_limit is None else {"node_limit": int(model.node_limit)}),
                },
            )
        status: SolutionStatus
        if res.status == 0:
            status = "optimal"
        elif res.status == 2:
            status = "infeasible"
        elif res.status == 3:
            status = "unbounded"
        elif res.status == 1:
            status = "time_limit"
        else:
            status = "error"
        fun = float(res.fun) if res.fun is not None else float("nan")
        bound = getattr(res, "mip_dual_bound", None)
        bound = float(bound) if bound is not None else (fun if status == "optimal" else float("nan"))
        return BackendSolution(status, res.x, fun, None, str(res.message), bound)

    @staticmethod
    def _lp(model: LinearModel, limit: float) -> BackendSolution:
        A, lo, hi = model.A, model.row_lo, model.row_hi
        eq = np.isfinite(lo) & np.isfinite(hi) & (lo == hi)
        up = np.isfinite(hi) & ~eq
        down = np.isfinite(lo) & ~eq
        up_idx, down_idx, eq_idx = np.nonzero(up)[0], np.nonzero(down)[0], np.nonzero(eq)[0]
        A_ub = vstack([A[up_idx], -A[down_idx]]).tocsr() if up_idx.size + down_idx.size else None
        b_ub = np.concatenate([hi[up_idx], -lo[down_idx]]) if A_ub is not None else None
        A_eq = A[eq_idx] if eq_idx.size else None
        b_eq = lo[eq_idx] if eq_idx.size else None
        bounds = np.column_stack([model.lb, model.ub])
        bounds = np.where(np.isfinite(bounds), bounds, np.nan)
        res = linprog(
            model.c,
            A_ub=A_ub,
            b_ub=b_ub,
            A_eq=A_eq,
            b_eq=b_eq,
            bounds=[(None if np.isnan(a) else a, None if np.isnan(b) else b) for a, b in bounds],
            method="highs",
            options={"time_limit": limit},
        )
        status: SolutionStatus
        if res.status == 0:
            status = "optimal"
        elif res.status == 2:
            status = "infeasible"
        elif res.status == 3:
            status = "unbounded"
        elif res.status == 1:
            status = "time_limit"
        else:
            status = "error"
        duals = None
        if status == "optimal":
            duals = np.zeros(model.num_rows)
            if A_ub is not None:
                marg = np.asarray(res.ineqlin.marginals)
                duals[up_idx] += marg[: up_idx.size]
                duals[down_idx] -= marg[up_idx.size :]
            if A_eq is not None:
                duals[eq_idx] += np.asarray(res.eqlin.marginals)
        fun = float(res.fun) if res.fun is not None else float("nan")
        return BackendSolution(status, res.x, fun, duals, str(res.message))


def _gap(model: LinearModel) -> float:
    if model.mip_rel_gap is not None:
        return float(model.mip_rel_gap)
    return 1e-7 if np.any(model.c != 0) else 1e-4


_REGISTRY: dict[str, Any] = {}

_OPTIONAL: dict[str, str] = {"scip": "idstlpy.backends_scip"}
"""Back-ends of optional extras, by module: imported (and so registered) on first use. Their
modules import this one, never the other way, and import their solver only when they solve."""


def _registry() -> dict[str, Any]:
    for name, module in _OPTIONAL.items():
        if name not in _REGISTRY:
            importlib.import_module(module)
    return _REGISTRY


def register_backend(cls: type) -> type:
    """Register a back-end class under ``cls.name`` (usable as a decorator)."""
    name = getattr(cls, "name", None)
    if not isinstance(name, str) or not name:
        raise InvalidArgumentError("a back-end class needs a non-empty string attribute `name`")
    _REGISTRY[name] = cls
    return cls


def _serves(cls: Any, integer: bool) -> bool:
    """Whether ``cls`` can serve as a MILP back-end (``integer``) or as an LP back-end.

    An LP back-end must report row duals (``provides_duals``, default True): the teachers read
    their infeasibility certificates from them.
    """
    if integer:
        return bool(cls.supports_integer)
    return bool(getattr(cls, "provides_duals", True))


def available_backends(integer: bool = False) -> list[str]:
    """Names of the registered back-ends usable here.

    ``integer=True``: those that solve MILPs; ``integer=False``: those that serve as LP
    back-ends (with row duals).

    Parameters
    ----------
    integer : bool, default False
        List MILP back-ends (True) or LP back-ends (False).

    Returns
    -------
    list of str
        Sorted names.
    """
    return [name for name, cls in sorted(_registry().items()) if _serves(cls, integer) and cls.is_available()]


MILP_PREFERENCE = ("scip", "highs")
"""The order ``milp_backend="auto"`` tries: SCIP first, measured faster on the eager MILPs of
the benchmarks (BENCHMARKS.md, "MILP back-ends"), HiGHS (always installed) otherwise."""


def default_milp_backend() -> str:
    """The first installed back-end of :data:`MILP_PREFERENCE` (what ``"auto"`` resolves to)."""
    for name in MILP_PREFERENCE:
        cls = _registry().get(name)
        if cls is not None and cls.supports_integer and cls.is_available():
            return name
    return "highs"


def get_backend(name: str, integer: bool = False) -> Backend:
    """An instance of the back-end registered as ``name``.

    Parameters
    ----------
    name : str
        A registered back-end name (see :func:`available_backends`), e.g. ``"highs"``.
    integer : bool, default False
        True when the back-end must solve MILPs; False when it must serve as an LP back-end
        (report row duals).

    Returns
    -------
    Backend

    Raises
    ------
    InvalidArgumentError
        When no back-end has that name, it is not installed, or it cannot solve MILPs and
        ``integer`` is asked for.
    """
    cls = _registry().get(name)
    if cls is None:
        raise InvalidArgumentError(
            f"unknown LP/MILP back-end {name!r}; registered: {', '.join(sorted(_registry()))}"
        )
    if integer and not cls.supports_integer:
        raise InvalidArgumentError(f"back-end {name!r} cannot solve MILPs")
    if not integer and not _serves(cls, False):
        raise InvalidArgumentError(f"back-end {name!r} reports no LP duals: it cannot be an LP back-end")
    if not cls.is_available():
        raise InvalidArgumentError(f"back-end {name!r} is not installed here")
    backend: Backend = cls()
    return backend


def module_available(module: str) -> bool:
    """Whether ``module`` can be imported, checked without importing it."""
    return importlib.util.find_spec(module) is not None


register_backend(HighsBackend)
