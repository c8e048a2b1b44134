"""Text syntax of PrSTL formulas: what ``str(formula)`` prints.

Grammar (whitespace is free)::

    formula  := binary | unary | atom
    binary   := "(" formula (("&" | "|") formula)+ ")"
              | "(" formula ("U" | "R") interval formula ")"
    unary    := ("F" | "G") interval formula
    interval := "[" INT "," INT "]"
    atom     := NAME | "true" | "false" | "{" item ("&" item)* "}"
    item     := "P[" affine "<=" "0" "]" ">=" NUMBER | "(" mode ("|" mode)* ")" | mode | "false"
    mode     := "q" "==" INT
"""

from __future__ import annotations

from .expressions import format_affine, _fmt_num
from .formulas import STLAnd, STLAtomicProposition, STLFormula, STLOr, STLRelease, STLUntil

__all__ = ["format_formula", "format_atom"]


def format_atom(ap: STLAtomicProposition, use_name: bool = True) -> str:
    """Text of an atomic proposition: its name, or its definition in braces."""
    if ap._constant is True:
        return "true"
    if ap._constant is False:
        return "false"
    if use_name and ap.name is not None:
        return ap.name
    items = [
        f"P[{format_affine(p.h, p.c, p.variable.name)} <= 0] >= {_fmt_num(1.0 - p.eps)}"
        for p in ap.predicates
    ]
    if ap.modes is not None:
        if not ap.modes:
            items.append("false")
        else:
            modes = " | ".join(f"q == {m}" for m in sorted(ap.modes))
            items.append(f"({modes})" if len(ap.modes) > 1 else modes)
    if not items:
        return "true"
    return "{" + " & ".join(items) + "}"


def format_formula(formula: STLFormula) -> str:
    """The text of ``formula`` (named propositions print by name)."""
    if isinstance(formula, STLAtomicProposition):
        return format_atom(formula)
    if isinstance(formula, STLAnd | STLOr):
        op = " & " if isinstance(formula, STLAnd) else " | "
        return "(" + op.join(format_formula(c) for c in formula.children) + ")"
    if isinstance(formula, STLUntil):
        if isinstance(formula.left, STLAtomicProposition) and formula.left._constant is True:
            return f"F[{formula.a},{formula.b}] {format_formula(formula.right)}"
        return (
            f"({format_formula(formula.left)} U[{formula.a},{formula.b}] "
            f"{format_formula(formula.right)})"
        )
    if isinstance(formula, STLRelease):
        if isinstance(formula.left, STLAtomicProposition) and formula.left.is_false:
            return f"G[{formula.a},{formula.b}] {format_formula(formula.right)}"
        return (
            f"({format_formula(formula.left)} R[{formula.a},{formula.b}] "
            f"{format_formula(formula.right)})"
        )
    raise TypeError(f"cannot format {type(formula).__name__}")
