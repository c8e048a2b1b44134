"""Structure report: module sizes, long functions and long parameter lists (issue 22's measures).

Run ``python tools/structure_report.py`` (``make lint`` does). It prints, for the package:

* modules over ``--module-lines`` lines (default 500);
* in the layers held to the tighter rules (``synthesis``, ``executor``, ``execution``, and the
  executor's root modules ``closed_loop``, ``loop_moments``, ``loop_samples``, ``tracking``, as
  ``tests/test_layers.py`` assigns them): functions over ``--function-lines`` lines (default 80)
  or with more than ``--params`` parameters (default 10, ``self``/``cls`` not counted).

It reports; it does not fail (exit 0), unless ``--strict`` is given, so the numbers can be tracked
while the redesign goes on.
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "src" / "idstlpy"
LAYERS = ("synthesis", "executor", "execution")
EXECUTOR_ROOT_MODULES = ("closed_loop.py", "loop_moments.py", "loop_samples.py", "tracking.py")


def _functions(tree: ast.AST) -> list[ast.FunctionDef | ast.AsyncFunctionDef]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]


def _params(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = fn.args
    names = [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    names += [p.arg for p in (a.vararg, a.kwarg) if p is not None]
    return len([n for n in names if n not in ("self", "cls")])


def report(module_lines: int, function_lines: int, params: int) -> list[str]:
    """The findings, one line each (``path:line: what``)."""
    out: list[str] = []
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent)
        text = path.read_text()
        n = text.count("\n")
        if n > module_lines:
            out.append(f"{rel}: module of {n} lines (> {module_lines})")
        core = any(part in LAYERS for part in rel.parts)
        if not (core or (len(rel.parts) == 2 and rel.name in EXECUTOR_ROOT_MODULES)):
            continue
        for fn in _functions(ast.parse(text)):
            length = (fn.end_lineno or fn.lineno) - fn.lineno + 1
            if length > function_lines:
                out.append(f"{rel}:{fn.lineno}: {fn.name} is {length} lines (> {function_lines})")
            k = _params(fn)
            if k > params:
                out.append(f"{rel}:{fn.lineno}: {fn.name} takes {k} parameters (> {params})")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--module-lines", type=int, default=500)
    parser.add_argument("--function-lines", type=int, default=80)
    parser.add_argument("--params", type=int, default=10)
    parser.add_argument("--strict", action="store_true", help="exit 1 when anything is found")
    args = parser.parse_args(argv)
    found = report(args.module_lines, args.function_lines, args.params)
    for line in found:
        print(line)
    print(f"{len(found)} findings")
    return 1 if (found and args.strict) else 0


if __name__ == "__main__":
    sys.exit(main())
