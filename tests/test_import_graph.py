"""The package's imports flow one way: no module imports another that imports it back.

Every ``import`` / ``from ... import`` inside ``src/idstlpy`` is read with ``ast`` (module level
and inside functions alike; ``if TYPE_CHECKING:`` blocks excepted, they never run), resolved to a
module of the package, and the graph is checked for cycles. A package's ``__init__`` is a module
like any other: its imports of its own submodules are edges (re-exporting ``execution.simulate``
from ``execution/__init__.py`` makes anything that imports ``idstlpy.execution`` depend on
``simulation.py``), so an import of a package from below it is a cycle. ``from pkg import name``
is an edge to ``pkg.name`` when that is a module, else to ``pkg``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import idstlpy

ROOT = Path(idstlpy.__file__).parent


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path, name: str, modules: set[str] | dict[str, Path]) -> set[str]:
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out: set[str] = set()

    class Visitor(ast.NodeVisitor):
        def visit_If(self, node: ast.If) -> None:
            test = node.test
            if isinstance(test, ast.Name) and test.id == "TYPE_CHECKING":
                for child in node.orelse:
                    self.visit(child)
                return
            self.generic_visit(node)

        def visit_Import(self, node: ast.Import) -> None:
            out.update(a.name for a in node.names if a.name.startswith("idstlpy"))

        def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.startswith("idstlpy"):
                for alias in node.names:  # `from . import x` may name a submodule
                    sub = f"{target}.{alias.name}"
                    out.add(sub if sub in modules else target)

    Visitor().visit(tree)
    return out


def _graph() -> dict[str, set[str]]:
    files = {_module_name(p): p for p in ROOT.rglob("*.py")}
    return {
        name: {t for t in _imports(path, name, files) if t in files and t != name}
        for name, path in files.items()
    }


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    cycles = []
    state: dict[str, int] = {}

    def visit(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt) :] + [nxt])
            elif nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    return cycles


def test_no_import_cycles():
    cycles = _cycles(_graph())
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_the_check_sees_a_cycle_through_a_package_init():
    """The circle of 50a6859 (a model module importing ``idstlpy.execution``, whose ``__init__``
    imports a module that imports the model back) is found."""
    graph = _graph()
    graph["idstlpy.dynamical_system"] = graph["idstlpy.dynamical_system"] | {"idstlpy.execution"}
    cycles = _cycles(graph)
    assert any("idstlpy.execution" in c and "idstlpy.dynamical_system" in c for c in cycles)
