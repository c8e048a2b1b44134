"""The package's imports flow one way, through the layers, with no cycle.

The layers, lowest first (issue 33): the **model** (the root modules: systems, beliefs, sets,
formulas, semantics, ...), the **executor** (``executor/`` and the root modules of the closed
loop: ``closed_loop``, ``loop_moments``, ``loop_samples``, ``tracking``), **synthesis**
(``synthesis/``), **execution** (``execution/``), the **front ends** (``problem_file/``,
``plotting``, ``batch/``, ``cli/``) and the **package** itself (``idstlpy/__init__.py``, which
re-exports everything, and ``__main__``). A module may import its own layer and the layers below
it, never one above.

Every ``import`` / ``from ... import`` inside ``src/idstlpy`` is read with ``ast``: at module
level, inside functions, and under ``if TYPE_CHECKING:`` alike. A type-only import is a
dependency too (the code that reads the annotation needs the module; a checker or a drawing of the
imports counts it), so hiding an import from the runtime does not hide it from this test. Each
import is resolved to a module of the package; ``from pkg import name`` is an edge to ``pkg.name``
when that is a module, else to ``pkg``. A package's ``__init__`` is a module like any other and an
import of ``pkg.mod`` also runs ``pkg/__init__.py``, so it is an edge to ``pkg`` as well (unless
the importer is inside ``pkg``, which is then being initialised already): re-exporting
``execution.simulate`` from ``execution/__init__.py`` makes anything that imports a module of
``idstlpy.execution`` depend on ``simulation.py``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import idstlpy
import idstlpy.scenarios

ROOT = Path(idstlpy.__file__).parent

MODEL, EXECUTOR, SYNTHESIS, EXECUTION, FRONT, PACKAGE = range(6)
LAYER_NAMES = ("model", "executor", "synthesis", "execution", "front ends", "package")
# Root modules outside the model; every other root module is the model.
ROOT_LAYERS = {
    "closed_loop": EXECUTOR,
    "loop_moments": EXECUTOR,
    "loop_samples": EXECUTOR,
    "tracking": EXECUTOR,
    "plotting": FRONT,
    "__main__": PACKAGE,
}
PACKAGE_LAYERS = {
    "executor": EXECUTOR,
    "synthesis": SYNTHESIS,
    "execution": EXECUTION,
    "problem_file": FRONT,
    "batch": FRONT,
    "cli": FRONT,
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def layer(module: str) -> int:
    """The layer of a module of the package (by its dotted name)."""
    parts = module.split(".")
    if len(parts) == 1:
        return PACKAGE
    if parts[1] in PACKAGE_LAYERS:
        return PACKAGE_LAYERS[parts[1]]
    return ROOT_LAYERS.get(parts[1], MODEL)


def _imports(path: Path, name: str, modules: set[str] | dict[str, Path]) -> set[str]:
    """Every module of the package ``path`` imports, type-only and function-local included."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    targets: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:  # `from . import x` may name a submodule
                sub = f"{target}.{alias.name}"
                targets.add(sub if sub in modules else target)
    out: set[str] = set()
    for target in targets:
        if not target.startswith("idstlpy"):
            continue
        parts = target.split(".")
        # importing pkg.mod runs pkg/__init__.py first, unless the importer is inside pkg
        for k in range(1, len(parts) + 1):
            prefix = ".".join(parts[:k])
            if not (name == prefix or name.startswith(prefix + ".")):
                out.add(prefix)
    return out


def graph() -> dict[str, set[str]]:
    """Module -> the modules of the package it imports."""
    files = {_module_name(p): p for p in ROOT.rglob("*.py")}
    return {
        name: {t for t in _imports(path, name, files) if t in files and t != name}
        for name, path in files.items()
    }


def cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles: the strongly connected components of more than one module (Tarjan),
    each sorted; empty exactly when ``g`` is acyclic (no module imports itself: ``graph`` drops
    self-edges)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(g.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for name in sorted(g):
        if name not in index:
            visit(name)
    return out


def upward_imports(g: dict[str, set[str]]) -> list[str]:
    """Every import of a module from a higher layer, as ``importer -> imported (layers)``."""
    return [
        f"{a} ({LAYER_NAMES[layer(a)]}) -> {b} ({LAYER_NAMES[layer(b)]})"
        for a in sorted(g)
        for b in sorted(g[a])
        if layer(b) > layer(a)
    ]


def test_no_import_cycles():
    found = cycles(graph())
    assert not found, f"{len(found)} import cycles: " + "; ".join(", ".join(c) for c in found)


def test_no_import_against_the_layers():
    found = upward_imports(graph())
    assert not found, f"{len(found)} imports against the layers:\n" + "\n".join(found)


def test_every_layer_has_modules_and_the_package_sits_on_top():
    g = graph()
    assert {layer(m) for m in g} == set(range(len(LAYER_NAMES)))
    assert layer("idstlpy") == PACKAGE and layer("idstlpy.semantics") == MODEL
    assert layer("idstlpy.tracking") == EXECUTOR and layer("idstlpy.executor.law") == EXECUTOR
    assert layer("idstlpy.cli.plot") == FRONT


def test_the_check_sees_a_cycle_through_a_package_init():
    """The circle of 50a6859 (a model module importing ``idstlpy.execution``, whose ``__init__``
    imports a module that imports the model back) is found."""
    g = graph()
    g["idstlpy.dynamical_system"] = g["idstlpy.dynamical_system"] | {"idstlpy.execution"}
    found = cycles(g)
    assert any("idstlpy.execution" in c and "idstlpy.dynamical_system" in c for c in found)


def test_the_check_counts_type_only_and_local_imports(tmp_path):
    source = (
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from ..synthesis.problem import Problem\n"
        "def f():\n    from idstlpy.execution import simulation\n"
    )
    path = tmp_path / "mod.py"
    path.write_text(source)
    modules = {"idstlpy.synthesis.problem", "idstlpy.execution.simulation"}
    got = _imports(path, "idstlpy.executor.mod", modules)
    assert got >= {"idstlpy.synthesis.problem", "idstlpy.synthesis", "idstlpy.execution"}
    assert "idstlpy.execution.simulation" in got and "idstlpy.executor" not in got
    assert upward_imports({"idstlpy.executor.mod": got}), "an executor importing synthesis"


def test_moved_names_keep_their_former_paths():
    """Issue 33 moved code to its layer; the former import paths name the same objects."""
    import idstlpy.label_semantics as label_semantics
    import idstlpy.lqr as lqr
    import idstlpy.problem as model_problem
    import idstlpy.synthesis.interfaces as interfaces
    import idstlpy.synthesis.milp_model as milp_model
    import idstlpy.synthesis.plan as plan
    import idstlpy.synthesis.problem as synthesis_problem
    import idstlpy.tracking as tracking

    assert idstlpy.Problem is synthesis_problem.Problem is model_problem.Problem
    assert tracking.finite_horizon_lqr is lqr.finite_horizon_lqr is idstlpy.finite_horizon_lqr
    assert tracking.riccati_costs is lqr.riccati_costs
    assert plan.evaluate_bool is label_semantics.evaluate_bool
    assert plan.extract_witness is label_semantics.extract_witness
    assert {"Budget", "BudgetExceeded"} <= set(interfaces.__all__)
    assert {"Columns", "MILPSpec", "RowBlocks"} <= set(milp_model.__all__)


def test_problem_solve_runs_the_solver_synthesis_registered(monkeypatch):
    """``Problem.solve_result`` hands its options and the arguments given to the registered solver,
    and keeps what it returns as ``last_result``."""
    import idstlpy.problem as model_problem
    from idstlpy.synthesis.problem import _registered

    assert model_problem._SOLVER["solve"] is _registered
    problem = idstlpy.scenarios.reach_avoid(5)
    calls = []

    def solver(p, options, /, **overrides):
        calls.append((p, options, overrides))
        return "outcome"

    monkeypatch.setitem(model_problem._SOLVER, "solve", solver)
    options = idstlpy.SolverOptions()
    assert problem.solve_result(3.0, seed=4, options=options, max_candidates=2) == "outcome"
    assert calls == [(problem, options, {"rrt_timeout": 3.0, "seed": 4, "max_candidates": 2})]
    assert problem.last_result == "outcome"


def test_the_executor_takes_a_problem_by_its_class_not_its_attributes():
    from types import SimpleNamespace

    from idstlpy.errors import InvalidTypeError
    from idstlpy.executor import OnlineExecutor

    problem = idstlpy.scenarios.reach_avoid(5)
    plan = idstlpy.rollout(problem.switched_system, problem.initial_state, [0, 0], [[0.0, 0.0]] * 2)
    assert OnlineExecutor(problem, plan).spec.control_domain is problem.control_domain
    look_alike = SimpleNamespace(
        switched_system=problem.switched_system,
        stl_formula=problem.stl_formula,
        control_domain=problem.control_domain,
    )
    with pytest.raises(InvalidTypeError, match="source must be a Problem"):
        OnlineExecutor(look_alike, plan)  # type: ignore[arg-type]
    with pytest.raises(InvalidTypeError, match="problem_or_system must be a Problem"):
        idstlpy.predict_closed_loop(look_alike, plan, samples=10)  # type: ignore[arg-type]


if __name__ == "__main__":  # the findings, and the imports between layers as a table
    g = graph()
    for c in cycles(g):
        print(f"cycle of {len(c)} modules:", ", ".join(c))
    up = upward_imports(g)
    print("\n".join(up))
    print(f"{len(cycles(g))} cycles, {len(up)} imports against the layers")
    counts = [[0] * len(LAYER_NAMES) for _ in LAYER_NAMES]
    for a, targets in g.items():
        for b in targets:
            counts[layer(a)][layer(b)] += 1
    print("\nmodule imports, importer's layer (row) -> imported layer (column):")
    print(f"{'':>12}" + "".join(f"{name[:10]:>12}" for name in LAYER_NAMES))
    for i, row in enumerate(counts):
        print(f"{LAYER_NAMES[i][:10]:>12}" + "".join(f"{k:>12}" for k in row))
