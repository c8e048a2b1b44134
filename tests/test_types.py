"""Types at the seams: no ``Any`` on domain objects, and strict mypy on the packages that hold them.

``make test`` runs ``mypy src``; the ``[[tool.mypy.overrides]]`` of pyproject.toml hold the
synthesis, the executor and the execution layer to the flags ``mypy --strict`` sets per module.
This test keeps both from eroding: every parameter or attribute that holds a domain object
(a problem, a system or a mode, a control domain, a formula, options, a belief, a plan) is
annotated with its class, never ``Any``, in those packages.
"""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import idstlpy

ROOT = Path(idstlpy.__file__).parent
PACKAGES = ("synthesis", "executor", "execution")
DOMAIN = {
    "problem",
    "problem_or_system",
    "system",
    "switched_system",
    "real_system",
    "mode",
    "modes",
    "control_domain",
    "domain",
    "formula",
    "stl_formula",
    "options",
    "init",
    "initial_state",
    "plan",
    "solution",
    "traj",
    "source",
    "prediction",
    "problem_factory",
}
STRICT_FLAGS = {
    "disallow_any_generics",
    "disallow_subclassing_any",
    "disallow_untyped_calls",
    "disallow_untyped_defs",
    "disallow_incomplete_defs",
    "check_untyped_defs",
    "disallow_untyped_decorators",
    "warn_unused_ignores",
    "warn_return_any",
    "no_implicit_reexport",
    "strict_equality",
    "extra_checks",
}


def _mentions_any(node: ast.expr | None) -> bool:
    """Whether an annotation is ``Any`` or holds it as a member: ``Any``, ``Any | None``,
    ``Sequence[Any]``, ``list[Any]``. A keyword bag (``Mapping[str, Any]``, ``dict[str, Any]``:
    values of many types by design) is not a domain object."""
    if node is None:
        return False
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return _mentions_any(ast.parse(node.value, mode="eval").body)
    if isinstance(node, ast.Name):
        return node.id == "Any"
    if isinstance(node, ast.BinOp):  # X | Y
        return _mentions_any(node.left) or _mentions_any(node.right)
    if isinstance(node, ast.Subscript):
        base = ast.unparse(node.value)
        if base.endswith(("Mapping", "dict")):
            return False
        inner = node.slice.elts if isinstance(node.slice, ast.Tuple) else [node.slice]
        return any(_mentions_any(e) for e in inner)
    return False


def _domain_any(path: Path) -> list[str]:
    out = []
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            args = node.args
            for arg in [*args.posonlyargs, *args.args, *args.kwonlyargs]:
                if arg.arg in DOMAIN and _mentions_any(arg.annotation):
                    out.append(f"{path.relative_to(ROOT)}:{arg.lineno} {node.name}({arg.arg})")
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            if node.target.id in DOMAIN and _mentions_any(node.annotation):
                out.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.target.id}")
    return out


def test_no_any_on_domain_objects():
    found = [
        hit for pkg in PACKAGES for path in sorted((ROOT / pkg).glob("*.py")) for hit in _domain_any(path)
    ]
    assert not found, "domain objects annotated Any:\n" + "\n".join(found)


def test_the_packages_are_held_to_strict_mypy():
    config = tomllib.loads((ROOT.parents[1] / "pyproject.toml").read_text())
    overrides = config["tool"]["mypy"]["overrides"]
    for pkg in PACKAGES:
        pattern = f"idstlpy.{pkg}.*"
        flags = set()
        for entry in overrides:
            modules = entry["module"] if isinstance(entry["module"], list) else [entry["module"]]
            if pattern in modules:
                flags |= {k for k, v in entry.items() if v is True}
        missing = STRICT_FLAGS - flags
        assert not missing, f"{pattern} lacks the strict flags {sorted(missing)}"
