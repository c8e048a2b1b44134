"""From checked plain data to the library's objects: systems, control domain, belief, formula.

:func:`build` reads the parsed TOML of a problem file (with overrides applied) and returns a
:class:`BuiltProblem`: the :class:`~idstlpy.Problem`, the keyword arguments of
:meth:`~idstlpy.Problem.solve` (validated by :class:`~idstlpy.SolverOptions`) and the
:class:`ExecutionSettings` of ``[execution]`` and ``[validation]``. Every error names the file,
line and field (:class:`~idstlpy.problem_file.locations.Context`).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np

from ..belief import GaussianBelief, to_belief
from ..dynamical_system import LCS, SwitchedSystem, mk_lbs, mk_lcs, mk_switched_sys
from ..errors import IdstlpyError, InvalidArgumentError, InvalidTypeError, ProblemFileError
from ..execution_target import ExecutionTarget, as_execution_target
from ..expressions import (
    ConvexRegion,
    JointChanceConstraint,
    ProbabilisticLinearPredicate,
    RealValuedVariable,
    mk_variable,
    prob,
    prob_in,
)
from ..formulas import STLAtomicProposition
from ..sets import Polytope
from ..syntax import RESERVED_NAMES, FormulaSyntaxError, parse_formula
from ..synthesis import Problem, SolverOptions
from ..synthesis.options import CODE_ONLY_OPTIONS
from . import schema as sc
from .grammar import ExpressionError, NoiseExpression, linear_predicates, parse_tree
from .locations import Context, FieldPath

__all__ = ["BuiltProblem", "ExecutionSettings", "SpecData", "build", "solver_parameters"]

logger = logging.getLogger("idstlpy.problem_file")


class SpecData(Protocol):
    """What :func:`build` reads from a :class:`~idstlpy.problem_file.ProblemSpec`."""

    @property
    def data(self) -> dict[str, Any]:
        """The parsed TOML."""

    @property
    def source(self) -> str:
        """The file's text."""

    @property
    def name(self) -> str:
        """The file's name."""

    @property
    def overrides(self) -> Mapping[str, Any]:
        """The overrides applied to :attr:`data`."""


@dataclass(frozen=True)
class ExecutionSettings:
    """How a plan is executed and validated (the ``[execution]`` and ``[validation]`` tables).

    Parameters
    ----------
    real_system : SwitchedSystem
        The system the plan runs on (default: the planning model itself).
    real_initial_state : ndarray of shape (n,), or None
        Fixed true initial state; None (the key left out): every validation run draws its true
        start from the prior (``validate``'s default).
    lqr : dict or None
        ``horizon``, ``Q_final``, ``Q``, ``R`` of the tracking controller of every mode
        (:meth:`~idstlpy.dynamical_system.LCS.compute_finite_horizon_lqr`), or None.
    runs : int
        Number of validation runs.
    seed : int or None
        Seed of the validation runs.
    predict : bool
        Also predict the execution (``validate(..., predict=True)``).
    replan : {None, "on_risk", "every"}
        ``[validation] replan``: the re-plan policy of every run (``validate(replan=...)``).
    replan_options : dict
        ``[validation.replan_options]`` as ``validate``'s ``replan_options`` (``"none"`` read as
        None; ``solver_options`` a dict of :class:`~idstlpy.SolverOptions` fields). Empty
        without the table.
    start_check : dict or None
        ``[validation.start_check]`` as keywords of :func:`~idstlpy.start_check` (made once,
        before the runs), or None without the table.
    execution_target : ExecutionTarget or None
        ``[validation] execution_target = [belief, state]``: the verdict's target (None: the
        default, 90% / 95%).
    """

    real_system: SwitchedSystem
    real_initial_state: np.ndarray | None
    lqr: dict[str, Any] | None = None
    runs: int = sc.DEFAULT_VALIDATION_RUNS
    seed: int | None = None
    predict: bool = False
    replan: str | None = None
    replan_options: dict[str, Any] = dataclasses.field(default_factory=dict)
    start_check: dict[str, Any] | None = None
    execution_target: ExecutionTarget | None = None


class BuiltProblem(NamedTuple):
    """What :meth:`ProblemSpec.build` returns (unpacks as ``problem, solver_kwargs, execution``)."""

    problem: Problem
    solver_kwargs: dict[str, Any]
    execution: ExecutionSettings


def solver_parameters() -> dict[str, tuple[Any, str]]:
    """Every key ``[solver]`` accepts: the fields of :class:`~idstlpy.SolverOptions`.

    Returns
    -------
    dict
        ``name -> (default, type text)``, e.g. ``"seed" -> (None, "int | None")``.
    """
    return {
        f.name: (f.default, str(f.type))
        for f in dataclasses.fields(SolverOptions)
        if f.name not in CODE_ONLY_OPTIONS
    }


def build(spec: SpecData) -> BuiltProblem:
    """Build the problem, the solver keyword arguments and the execution settings of ``spec``.

    Parameters
    ----------
    spec : ProblemSpec
        The plain data (``data``, ``source``, ``name``, ``overrides``).

    Returns
    -------
    BuiltProblem

    Raises
    ------
    ProblemFileError
        Naming the file, line and field of the first problem found.
    """
    return _Builder(spec).build()


def _control_size(value: Any) -> tuple[int, str] | None:
    """The number of inputs ``control_domain`` declares, and where (None when it is unclear)."""
    if not isinstance(value, dict):
        return None
    low, high, A = value.get("low"), value.get("high"), value.get("A")
    if isinstance(low, list) and isinstance(high, list):
        if len(low) == len(high) and low:
            return len(low), "the length of control_domain.low and .high"
        return None
    if isinstance(A, list) and A and all(isinstance(r, list) for r in A):
        widths = {len(r) for r in A}
        if len(widths) == 1 and (w := widths.pop()):
            return w, "the number of columns of control_domain.A"
    return None


class _Builder:
    def __init__(self, spec: SpecData) -> None:
        self.spec = spec
        self.ctx = Context(spec.name, spec.source, list(spec.overrides))

    def err(self, path: FieldPath, message: str) -> ProblemFileError:
        return self.ctx.error(path, message)

    def build(self) -> BuiltProblem:
        sc.check_trailing_keys(self.ctx)
        data = sc.table(self.ctx, (), self.spec.data, sc.TOP_KEYS, sc.REQUIRED_TOP)
        for key in ("name", "description"):
            if key in data:
                sc.string(self.ctx, (key,), data[key])
        modes_data = data["modes"]
        if not isinstance(modes_data, list) or not modes_data:
            raise self.err(("modes",), "must be a non-empty array of tables ([[modes]])")
        # The number of inputs comes from the control domain when it says so clearly: a B with
        # the wrong number of columns is then blamed on B, not on the control domain.
        inputs = _control_size(data["control_domain"])
        modes: list[LCS] = []
        n: int | None = None
        for q, md in enumerate(modes_data):
            mode = self.mode(("modes", q), md, n, inputs, planning=True)
            n = mode.n
            if inputs is None:
                inputs = (mode.m, "the number of columns of modes[0].B")
            modes.append(mode)
        n, m = modes[0].n, modes[0].m  # every mode was checked against the first
        system = mk_switched_sys(modes)
        control = self.control_domain(data["control_domain"], m)
        belief = self.initial_belief(data["initial_belief"], n)
        x = mk_variable(size=n, dtype=float, name="x")
        atoms = self.propositions(data.get("propositions", {}), x, system.num_modes)
        formula_text = sc.string(self.ctx, ("formula",), data["formula"])
        try:
            formula = parse_formula(formula_text, atoms, x, system.num_modes)
        except FormulaSyntaxError as exc:
            raise self.err(
                ("formula",), f"{exc.detail} at column {exc.position + 1} of {formula_text!r}"
            ) from None
        used = {ap.name for ap in formula.atomic_propositions()}
        for unused in sorted(set(atoms) - used):
            logger.info("%s: proposition %r is not used by the formula", self.spec.name, unused)
        try:
            problem = Problem(system, control, belief, formula)
        except IdstlpyError as exc:
            raise self.err(("modes",), f"the problem is inconsistent: {exc}") from None
        solver = self.solver(("solver",), data.get("solver", {}))
        execution = self.execution(
            data.get("execution", {}), data.get("validation", {}), system, belief.mean, solver
        )
        return BuiltProblem(problem, solver, execution)

    # -- systems -------------------------------------------------------------------------------
    def mode(
        self, path: FieldPath, md: Any, n: int | None, inputs: tuple[int, str] | None, planning: bool
    ) -> LCS:
        md = sc.table(self.ctx, path, md, sc.MODE_KEYS, ("A", "B"))
        A = sc.matrix(self.ctx, path + ("A",), md["A"], n, n)
        if A.shape[0] != A.shape[1]:
            raise self.err(path + ("A",), f"must be square, got shape {A.shape}")
        n = A.shape[0]
        if n == 0:
            raise self.err(path + ("A",), "must have at least one row")
        m, why = inputs if inputs is not None else (None, "")
        B = sc.matrix(
            self.ctx,
            path + ("B",),
            md["B"],
            n,
            None,
            why=f" ({n} states, as A)",
        )
        if B.shape[1] == 0:
            raise self.err(path + ("B",), "must have at least one column")
        if m is not None and B.shape[1] != m:
            raise self.err(
                path + ("B",),
                f"must have shape ({n}, {m}): one column per input, and the system has {m} "
                f"input(s) ({why}); got {B.shape}",
            )
        if not planning and set(md) <= {"A", "B"}:
            return mk_lcs(A, B)
        W = sc.matrix(self.ctx, path + ("W",), md["W"], n, None) if "W" in md else np.zeros((n, n))
        C = sc.matrix(self.ctx, path + ("C",), md["C"], None, n) if "C" in md else None
        if C is not None and C.shape[0] == 0:
            raise self.err(path + ("C",), "must have at least one row (omit C for no sensing)")
        V: Any = None
        if "V" in md:
            if C is None:
                raise self.err(path + ("V",), "observation noise V needs an output matrix C")
            V = self.noise(path + ("V",), md["V"], n, C.shape[0])
        try:
            return mk_lbs(A, B, W, C, V)
        except IdstlpyError as exc:
            raise self.err(path, str(exc)) from None

    def noise(self, path: FieldPath, value: Any, n: int, p: int) -> Any:
        if isinstance(value, list):
            return sc.matrix(self.ctx, path, value, p, None)
        if isinstance(value, str):
            return self.expression(path, value, n, np.identity(p))
        if isinstance(value, dict):
            value = sc.table(self.ctx, path, value, sc.NOISE_TABLE_KEYS, ("scale",))
            matrix = (
                sc.matrix(self.ctx, path + ("matrix",), value["matrix"], p, None)
                if "matrix" in value
                else np.identity(p)
            )
            scale = value["scale"]
            if sc.is_number(scale):
                return sc.number(self.ctx, path + ("scale",), scale) * matrix
            return self.expression(path + ("scale",), scale, n, matrix)
        raise self.err(
            path,
            "must be a matrix, an expression string, or a table {scale = ..., matrix = ...}; "
            f"got {sc.kind_of(value)}",
        )

    def expression(self, path: FieldPath, text: Any, n: int, matrix: np.ndarray) -> NoiseExpression:
        if not isinstance(text, str):
            raise self.err(path, f"must be an expression string or a number, got {sc.kind_of(text)}")
        try:
            tree = parse_tree(text, n, "x", compare=False)
        except ExpressionError as exc:
            raise self.err(path, f"{exc} in {text!r}") from None
        return NoiseExpression(text, tree, matrix)

    def control_domain(self, value: Any, m: int) -> Polytope:
        path: FieldPath = ("control_domain",)
        value = sc.table(self.ctx, path, value, sc.CONTROL_DOMAIN_KEYS)
        box = {"low", "high"} & set(value)
        ineq = {"A", "b"} & set(value)
        if box and ineq:
            raise self.err(path, "give either low/high (a box) or A/b (A u <= b), not both")
        if box:
            for key in ("low", "high"):
                if key not in value:
                    raise self.err(path, f"missing required key {key!r} (a box needs low and high)")
            low = sc.vector(self.ctx, path + ("low",), value["low"], m)
            high = sc.vector(self.ctx, path + ("high",), value["high"], m)
            if np.any(low > high):
                raise self.err(path + ("low",), "must be <= high in every component")
            # rows in the order of logical_and(u[0] >= low[0], u[0] <= high[0], u[1] >= ...)
            H = np.zeros((2 * m, m))
            c = np.zeros(2 * m)
            for i in range(m):
                H[2 * i, i], c[2 * i] = -1.0, low[i]
                H[2 * i + 1, i], c[2 * i + 1] = 1.0, -high[i]
            return Polytope(H, c)
        if ineq:
            for key in ("A", "b"):
                if key not in value:
                    raise self.err(path, f"missing required key {key!r} (A u <= b needs A and b)")
            A = sc.matrix(self.ctx, path + ("A",), value["A"], None, m)
            b = sc.vector(self.ctx, path + ("b",), value["b"], A.shape[0])
            poly = Polytope.from_inequalities(A, b)
            if poly.is_empty():
                raise self.err(path, "is empty: no input satisfies A u <= b")
            return poly
        raise self.err(path, "missing required keys: low and high (a box), or A and b (A u <= b)")

    def initial_belief(self, value: Any, n: int) -> GaussianBelief:
        path: FieldPath = ("initial_belief",)
        value = sc.table(self.ctx, path, value, sc.INITIAL_BELIEF_KEYS, sc.INITIAL_BELIEF_KEYS)
        mean = sc.vector(self.ctx, path + ("mean",), value["mean"], n)
        cov_value = value["cov"]
        if isinstance(cov_value, list) and cov_value and all(sc.is_number(v) for v in cov_value):
            variances = sc.vector(self.ctx, path + ("cov",), cov_value, n)  # a vector: the diagonal
            if np.any(variances < 0):
                raise self.err(path + ("cov",), f"variances must be >= 0, got {variances.tolist()}")
            cov = np.diag(variances)
        else:
            cov = sc.matrix(self.ctx, path + ("cov",), cov_value, n, n)
        try:
            return to_belief(mean, cov)
        except IdstlpyError as exc:
            raise self.err(path + ("cov",), str(exc)) from None

    # -- specification -------------------------------------------------------------------------
    def propositions(
        self, value: Any, x: RealValuedVariable, num_modes: int
    ) -> dict[str, STLAtomicProposition]:
        path: FieldPath = ("propositions",)
        if not isinstance(value, dict):
            raise self.err(path, f"must be a table of propositions, got {sc.kind_of(value)}")
        atoms: dict[str, STLAtomicProposition] = {}
        for name, pd in value.items():
            atoms[name] = self.proposition(path + (name,), name, pd, x, num_modes)
        return atoms

    def proposition(
        self, path: FieldPath, name: str, pd: Any, x: RealValuedVariable, num_modes: int
    ) -> STLAtomicProposition:
        if not name.isidentifier() or name in RESERVED_NAMES:
            raise self.err(
                path,
                f"proposition name {name!r} must be an identifier other than "
                f"{', '.join(sorted(RESERVED_NAMES))}",
            )
        pd = sc.table(self.ctx, path, pd, sc.PROPOSITION_KEYS)
        default_conf = (
            sc.number(self.ctx, path + ("confidence",), pd["confidence"], 0.5, 1.0)
            if "confidence" in pd
            else None
        )
        constraints = pd.get("constraints", [])
        if not isinstance(constraints, list):
            raise self.err(path + ("constraints",), f"must be an array, got {sc.kind_of(constraints)}")
        preds: list[ProbabilisticLinearPredicate] = []
        joints: list[JointChanceConstraint] = []
        for i, item in enumerate(constraints):
            cpath = path + ("constraints", i)
            conf = default_conf
            if isinstance(item, dict):
                item = sc.table(self.ctx, cpath, item, sc.CONSTRAINT_TABLE_KEYS)
                if "confidence" in item:
                    conf = sc.number(self.ctx, cpath + ("confidence",), item["confidence"], 0.5, 1.0)
                if ("expr" in item) == ("region" in item):
                    raise self.err(
                        cpath,
                        "needs exactly one of expr (one chance constraint per comparison) or region "
                        "(one joint chance constraint for all of its comparisons)",
                    )
                if "region" in item:
                    joint = self.joint_region(cpath + ("region",), item["region"], conf, x)
                    if isinstance(joint, JointChanceConstraint):
                        joints.append(joint)
                    else:
                        preds.append(joint)
                    continue
                item = item["expr"]
            if not isinstance(item, str):
                raise self.err(
                    cpath,
                    "must be a string such as 'x[0] >= -1' or a table {expr, confidence}, "
                    f"got {sc.kind_of(item)}",
                )
            if conf is None:
                raise self.err(
                    cpath, "has no confidence: set confidence for the proposition or the constraint"
                )
            try:
                halfspaces = linear_predicates(item, x)
            except ExpressionError as exc:
                raise self.err(cpath, f"{exc} in {item!r}") from None
            # exactly the Python API: prob(2 * x[0] - x[1] / 4 <= 3) >= 0.95
            preds.extend(prob(h) >= conf for h in halfspaces)
        modes = None
        if "modes" in pd:
            mv = pd["modes"]
            if not isinstance(mv, list):
                raise self.err(path + ("modes",), f"must be an array of mode numbers, got {sc.kind_of(mv)}")
            modes = []
            for j, k in enumerate(mv):
                k = sc.integer(self.ctx, path + ("modes", j), k, 0)
                if k >= num_modes:
                    raise self.err(
                        path + ("modes", j),
                        f"mode {k} is out of range: the system has modes 0..{num_modes - 1}",
                    )
                modes.append(k)
        return STLAtomicProposition(preds, modes, name=name, joints=joints)

    def joint_region(
        self, path: FieldPath, value: Any, conf: float | None, x: RealValuedVariable
    ) -> JointChanceConstraint | ProbabilisticLinearPredicate:
        """``region = [...]``: one chance constraint for the whole region (``prob_in``)."""
        texts = [value] if isinstance(value, str) else value
        if not isinstance(texts, list) or not texts:
            raise self.err(
                path,
                "must be a non-empty array of linear comparisons such as "
                f"['-1 <= x[0] <= 1', '-1 <= x[1] <= 1'], got {sc.kind_of(value)}",
            )
        for j, text in enumerate(texts):
            if not isinstance(text, str):
                raise self.err(path + (j,), f"must be a string such as 'x[0] >= -1', got {sc.kind_of(text)}")
        if conf is None:
            raise self.err(
                path[:-1], "has no confidence: set confidence for the proposition or the constraint"
            )
        halfspaces = []
        for j, text in enumerate(texts):
            try:
                halfspaces.extend(linear_predicates(text, x))
            except ExpressionError as exc:
                where = path if isinstance(value, str) else path + (j,)
                raise self.err(where, f"{exc} in {text!r}") from None
        # exactly the Python API: prob_in(logical_and(...)) >= confidence
        return prob_in(ConvexRegion(halfspaces)) >= conf

    def solver(self, path: FieldPath, value: Any, base: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """A table of SolverOptions fields (``[solver]``, or a ``solver_options`` table that
        overrides ``base``, the ``[solver]`` keywords, and is checked together with them)."""
        params = solver_parameters()
        value = sc.table(self.ctx, path, value, tuple(params))
        kwargs: dict[str, Any] = {}
        for key, v in value.items():
            kwargs[key] = self.solver_value(path + (key,), v, *params[key])
        try:
            SolverOptions.make(**{**(base or {}), **kwargs})
        except IdstlpyError as exc:
            bad = next((k for k in kwargs if k in str(exc)), None)
            raise self.err(path + ((bad,) if bad else ()), str(exc)) from None
        return kwargs

    def solver_value(self, path: FieldPath, v: Any, default: Any, type_text: str) -> Any:
        """A ``[solver]`` value checked against the type of its SolverOptions field."""
        words = set(type_text.replace("|", " ").replace("[", " ").replace("]", " ").replace(",", " ").split())
        if "ExecutionTarget" in words:  # { belief = 0.9, state = 0.95 } or [0.9, 0.95]
            if type(v).__name__ == "ExecutionTarget":  # an override given as the object itself
                return v
            if not (isinstance(v, dict) or (isinstance(v, list) and all(sc.is_number(x) for x in v))):
                raise self.err(path, f"must be a table {{ belief = ..., state = ... }}, got {sc.kind_of(v)}")
            return dict(v) if isinstance(v, dict) else tuple(float(x) for x in v)
        if words & {"tuple", "list", "Sequence"}:
            if not isinstance(v, list) or not all(sc.is_number(x) for x in v):
                raise self.err(path, f"must be an array of numbers, got {sc.kind_of(v)}")
            return tuple(float(x) for x in v)
        if isinstance(default, bool) or "bool" in words:
            if not isinstance(v, bool):
                raise self.err(path, f"must be true or false, got {sc.kind_of(v)}")
            return v
        if isinstance(default, str) or words & {"str", "Literal"}:
            if not isinstance(v, str):
                raise self.err(path, f"must be a string, got {sc.kind_of(v)}")
            return v
        if isinstance(v, bool) or not sc.is_number(v):
            raise self.err(path, f"must be a number, got {sc.kind_of(v)}")
        if type(default) is int or ("int" in words and "float" not in words):
            if not (isinstance(v, int) or (isinstance(v, float) and v.is_integer())):
                raise self.err(path, f"must be an integer, got {v}")
            return int(v)
        return v

    def execution(
        self,
        value: Any,
        validation: Any,
        system: SwitchedSystem,
        mean: np.ndarray,
        solver: Mapping[str, Any],
    ) -> ExecutionSettings:
        path: FieldPath = ("execution",)
        value = sc.table(self.ctx, path, value, sc.EXECUTION_KEYS)
        n, m = system.n, system.m
        real = system
        if "real_system" in value:
            rs = value["real_system"]
            if not isinstance(rs, list) or not rs:
                raise self.err(
                    path + ("real_system",),
                    "must be a non-empty array of tables ([[execution.real_system]])",
                )
            inputs = (m, "as the planning model")
            real = mk_switched_sys(
                [
                    self.mode(path + ("real_system", q), md, n, inputs, planning=False)
                    for q, md in enumerate(rs)
                ]
            )
            if real.num_modes != system.num_modes:
                raise self.err(
                    path + ("real_system",),
                    f"has {real.num_modes} modes, the planning model has {system.num_modes}",
                )
        x0 = (
            sc.vector(self.ctx, path + ("real_initial_state",), value["real_initial_state"], n)
            if "real_initial_state" in value
            else None  # drawn from the prior by every validation run
        )
        lqr: dict[str, Any] | None = None
        if "lqr" in value:
            lpath = path + ("lqr",)
            lv = sc.table(self.ctx, lpath, value["lqr"], sc.LQR_KEYS, ("horizon",))
            size = {"Q_final": n, "Q": n, "R": m}
            lqr = {"horizon": sc.integer(self.ctx, lpath + ("horizon",), lv["horizon"], 1)}
            for key, k in size.items():
                lqr[key] = sc.matrix(self.ctx, lpath + (key,), lv[key], k, k) if key in lv else np.identity(k)
        vpath: FieldPath = ("validation",)
        vv = sc.table(self.ctx, vpath, validation, sc.VALIDATION_KEYS)
        runs = (
            sc.integer(self.ctx, vpath + ("runs",), vv["runs"], 1)
            if "runs" in vv
            else sc.DEFAULT_VALIDATION_RUNS
        )
        seed = sc.integer(self.ctx, vpath + ("seed",), vv["seed"], 0) if "seed" in vv else None
        predict = vv.get("predict", False)
        if not isinstance(predict, bool):
            raise self.err(vpath + ("predict",), f"must be true or false, got {sc.kind_of(predict)}")
        replan = self.choice(vpath + ("replan",), vv.get("replan", sc.NONE), sc.REPLAN_POLICIES)
        replan_options: dict[str, Any] = {}
        if "replan_options" in vv:
            replan_options = self.options(
                vpath + ("replan_options",), vv["replan_options"], sc.REPLAN_OPTION_KEYS, solver
            )
            if replan == sc.NONE:
                logger.info("%s: [validation.replan_options] is not used: replan is none", self.spec.name)
        start = (
            self.options(vpath + ("start_check",), vv["start_check"], sc.START_CHECK_KEYS, solver)
            if "start_check" in vv
            else None
        )
        target = None
        if "execution_target" in vv:
            try:
                target = as_execution_target(vv["execution_target"], "execution_target")
            except (InvalidArgumentError, InvalidTypeError) as exc:
                raise self.err(
                    vpath + ("execution_target",), f"must be [belief, state] with rates in [0, 1]: {exc}"
                ) from exc
        return ExecutionSettings(
            real,
            x0,
            lqr,
            runs,
            seed,
            predict,
            None if replan == sc.NONE else replan,
            replan_options,
            start,
            target,
        )

    # -- replanning ----------------------------------------------------------------------------
    def choice(self, path: FieldPath, value: Any, choices: tuple[str, ...]) -> str:
        if not isinstance(value, str) or value not in choices:
            shown = repr(value) if isinstance(value, str) else sc.kind_of(value)
            raise self.err(path, f"must be one of {', '.join(map(repr, choices))}, got {shown}")
        return value

    def options(
        self, path: FieldPath, value: Any, allowed: tuple[str, ...], solver: Mapping[str, Any]
    ) -> dict[str, Any]:
        """The keywords of ``execute`` / ``start_check`` in ``value``, checked as those functions
        check them, so that a bad value is reported with its field before anything runs."""
        value = sc.table(self.ctx, path, value, allowed)
        out: dict[str, Any] = {}
        for key, v in value.items():
            p = path + (key,)
            if key in _MAY_BE_NONE:
                if v == sc.NONE:
                    out[key] = None
                    continue
                if not sc.is_number(v):
                    got = repr(v) if isinstance(v, str) else sc.kind_of(v)
                    raise self.err(p, f"must be {_MAY_BE_NONE[key]} or {sc.NONE!r}, got {got}")
            if key == "solver_options":
                out[key] = self.solver(p, v, solver)
            elif key in _CHOICES:
                out[key] = self.choice(p, v, _CHOICES[key])
            elif key in _COUNTS:
                out[key] = sc.integer(self.ctx, p, v, _COUNTS[key])
            elif key == "risk":
                out[key] = sc.number(self.ctx, p, v, 0.0, 1.0)
            elif key == "drift":
                out[key] = sc.number(self.ctx, p, v)
                if not 0.0 < out[key] < 1.0:
                    raise self.err(p, f"must lie in (0, 1) (a confidence), got {v}")
            else:  # replan_time_limit: a wall-clock cap in seconds
                out[key] = sc.number(self.ctx, p, v)
                if out[key] <= 0.0:
                    raise self.err(p, f"must be > 0 (seconds), got {v}")
        return out


# The option values of [validation.replan_options] and [validation.start_check] (execute's and
# start_check's keywords): the allowed words, the least value of the counts, and the options for
# which "none" stands for Python's None (with what they are otherwise).
_CHOICES: dict[str, tuple[str, ...]] = {
    "risk_measure": ("bound", "estimate"),
    "risk_on": ("belief", "state", "both"),
    "adopt": ("better", "always"),
}
_COUNTS = {
    "every": 1,
    "check_every": 1,
    "start_resolves": 0,
    "resolves": 0,
    "seed": 0,
    "risk_samples": 1,
    "max_replans": 0,
    "adopt_delay": 0,
}
_MAY_BE_NONE = {"check_every": "an integer", "drift": "a number in (0, 1)"}
