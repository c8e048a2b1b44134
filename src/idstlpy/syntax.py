"""Text syntax of PrSTL formulas: what ``str(formula)`` prints and :func:`parse_formula` reads.

Grammar (whitespace is free)::

    formula  := binary | unary | atom
    binary   := "(" formula (("&" | "|") formula)+ ")"        (one operator per group)
              | "(" formula ("U" | "R") interval formula ")"
    unary    := ("F" | "G") interval formula
    interval := "[" INT "," INT "]"                             (0 <= start <= end <= 2**53)
    atom     := NAME | "true" | "false" | "{" [item ("&" item)*] "}"
    item     := chance | "(" mode ("|" mode)+ ")" | mode | "false"
    chance   := "P[" face ("&" face)* "]" ">=" NUMBER      (two faces or more: one joint constraint)
    face     := affine "<=" "0"
    mode     := "q" "==" INT
    affine   := ["-"] term (("+" | "-") term)*
    term     := NUMBER ["*" VAR "[" INT "]"] | VAR "[" INT "]"

``NAME`` is a named atomic proposition (looked up in the ``atoms`` mapping of
:func:`parse_formula`); ``VAR`` is the name of the state variable (``x``). ``F[a,b] f`` is
``true U[a,b] f`` and ``G[a,b] f`` is ``false R[a,b] f``. An unnamed proposition prints its
definition in braces: ``{P[x[0] - 1.0 <= 0] >= 0.9 & q == 1}``. ``P[f1 & f2 & ...] >= p`` is a
*joint* chance constraint, one confidence for the whole region (``prob_in(region) >= p``), where
``P[f1] >= p & P[f2] >= p`` gives one per face. ``{}`` is the proposition with
no constraint at all and ``{false}`` the one with an empty set of modes. Numbers print with
``repr(float)``, so ``str(parse_formula(str(f), ...)) == str(f)`` for every formula.

The paper's listing prints as::

    (free_space U[0,240] G[0,40] target)
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .errors import IdstlpyError, InvalidArgumentError, InvalidTypeError
from .expressions import JointChanceConstraint, ProbabilisticLinearPredicate, RealValuedVariable
from .formulas import (
    FALSE,
    MAX_BOUND,
    TRUE,
    STLAnd,
    STLAtomicProposition,
    STLFormula,
    STLOr,
    STLRelease,
    STLUntil,
    format_atom,
    format_formula,
)

__all__ = [
    "format_formula",
    "format_atom",
    "parse_formula",
    "FormulaSyntaxError",
    "RESERVED_NAMES",
]

RESERVED_NAMES = frozenset({"true", "false", "F", "G", "U", "R", "P", "q"})
"""Words of the syntax that cannot name an atomic proposition in text."""


# ------------------------------------------------------------------------------------------------
# parsing
# ------------------------------------------------------------------------------------------------


class FormulaSyntaxError(InvalidArgumentError):
    """Formula text that does not follow the grammar of :mod:`idstlpy.syntax`.

    The message names the column and shows the text (around the error, for long texts) with a
    caret under the offending character.

    Parameters
    ----------
    text : str
        The formula text.
    position : int
        0-based offset of the offending character in ``text``.
    detail : str
        What was expected (without the position).

    Attributes
    ----------
    text : str
        The formula text.
    position : int
        0-based offset of the offending character in ``text``.
    detail : str
        What was expected (without the position).
    """

    def __init__(self, text: str, position: int, detail: str) -> None:
        self.text = text
        self.position = position
        self.detail = detail
        line = text.replace("\n", " ").replace("\t", " ")
        start = max(0, position - _CONTEXT)
        end = min(len(line), position + _CONTEXT)
        shown = ("..." if start else "") + line[start:end] + ("..." if end < len(line) else "")
        caret = position - start + (3 if start else 0)
        super().__init__(
            f"formula syntax error at column {position + 1}: {detail}\n    {shown}\n    " + " " * caret + "^"
        )


_CONTEXT = 60  # characters shown on each side of a syntax error


@dataclass(frozen=True)
class _Token:
    kind: str  # "num", "int", "name", "op", "end"
    text: str
    pos: int


_TOKEN_RE = re.compile(
    r"""
    (?P<ws>\s+)
  | (?P<num>(?:\d+\.\d*|\.\d+|\d+)(?:[eE][+-]?\d+)?)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<op><=|>=|==|[()\[\]{},&|*+\-])
    """,
    re.VERBOSE,
)

_MAX_DEPTH = 200
_MAX_INT = 2**63 - 1  # integers of the text (modes, indices) fit int64


def _tokenize(text: str) -> list[_Token]:
    tokens: list[_Token] = []
    pos = 0
    while pos < len(text):
        m = _TOKEN_RE.match(text, pos)
        if m is None:
            raise FormulaSyntaxError(text, pos, f"unexpected character {text[pos]!r}")
        kind = m.lastgroup or ""
        if kind == "num":
            digits = m.group()
            kind = "int" if digits.isdigit() else "num"
            tokens.append(_Token(kind, digits, pos))
        elif kind != "ws":
            tokens.append(_Token(kind, m.group(), pos))
        pos = m.end()
    tokens.append(_Token("end", "", len(text)))
    return tokens


class _Parser:
    def __init__(
        self,
        text: str,
        atoms: Mapping[str, STLAtomicProposition],
        variable: RealValuedVariable | None,
        num_modes: int | None,
    ) -> None:
        self.text = text
        self.tokens = _tokenize(text)
        self.i = 0
        self.atoms = atoms
        self.variable = variable
        self.num_modes = num_modes
        self.depth = 0

    # -- token helpers -------------------------------------------------------------------------
    @property
    def tok(self) -> _Token:
        return self.tokens[self.i]

    def peek(self, offset: int = 1) -> _Token:
        return self.tokens[min(self.i + offset, len(self.tokens) - 1)]

    def error(self, detail: str, tok: _Token | None = None) -> FormulaSyntaxError:
        tok = tok or self.tok
        return FormulaSyntaxError(self.text, tok.pos, detail)

    @staticmethod
    def _show(tok: _Token) -> str:
        return "end of text" if tok.kind == "end" else repr(tok.text)

    def expect(self, text: str) -> _Token:
        tok = self.tok
        if tok.text != text or tok.kind not in ("op", "name"):
            raise self.error(f"expected {text!r}, got {self._show(tok)}")
        self.i += 1
        return tok

    def accept(self, text: str) -> bool:
        if self.tok.kind in ("op", "name") and self.tok.text == text:
            self.i += 1
            return True
        return False

    def integer(self, what: str, maximum: int | None = None) -> int:
        tok = self.tok
        if tok.kind != "int":
            raise self.error(f"expected {what} (a non-negative integer), got {self._show(tok)}")
        limit = maximum if maximum is not None else _MAX_INT
        # compare the digits before int(): Python refuses to convert more than 4300 of them
        digits = tok.text.lstrip("0") or "0"
        if len(digits) > len(str(limit)) or int(digits) > limit:
            shown = digits if len(digits) <= 40 else f"{digits[:20]}... ({len(digits)} digits)"
            bound = "2**53" if limit == MAX_BOUND else "2**63 - 1"
            raise self.error(f"{what} {shown} is too large: it must be <= {bound} = {limit}", tok)
        self.i += 1
        return int(digits)

    def number(self, what: str) -> float:
        tok = self.tok
        if tok.kind not in ("int", "num"):
            raise self.error(f"expected {what} (a number), got {self._show(tok)}")
        self.i += 1
        value = float(tok.text)
        if not np.isfinite(value):
            raise self.error(f"{what} {tok.text} is not a finite number", tok)
        return value

    # -- grammar -------------------------------------------------------------------------------
    def parse(self) -> STLFormula:
        formula = self.formula()
        tok = self.tok
        if tok.kind != "end":
            # A binary operator after a whole formula: its parentheses are missing. The grammar
            # stays strict (``F[0,5] a U[0,9] b`` would be ambiguous), the message says the fix.
            if tok.kind in ("name", "op") and tok.text in ("U", "R", "&", "|"):
                kind = "binary temporal operators" if tok.text in ("U", "R") else "binary operators"
                raise self.error(
                    f"{kind} need parentheses: ({self.text.strip()}) "
                    f"(expected end of formula, got {self._show(tok)})"
                )
            raise self.error(f"expected end of formula, got {self._show(tok)}")
        return formula

    def formula(self) -> STLFormula:
        self.depth += 1
        if self.depth > _MAX_DEPTH:
            raise self.error(f"formula is nested deeper than {_MAX_DEPTH} levels")
        try:
            tok = self.tok
            if tok.kind == "op" and tok.text == "(":
                return self.binary()
            if tok.kind == "op" and tok.text == "{":
                return self.braced_atom()
            if tok.kind == "name":
                if tok.text in ("F", "G") and self.peek().text == "[":
                    self.i += 1
                    a, b = self.interval()
                    body = self.formula()
                    cls = STLUntil if tok.text == "F" else STLRelease
                    return self.build(tok, cls, TRUE if tok.text == "F" else FALSE, a, b, body)
                return self.named_atom()
            raise self.error(
                f"expected a formula: '(', '{{', F[a,b], G[a,b] or a proposition name, got {self._show(tok)}"
            )
        finally:
            self.depth -= 1

    def build(
        self,
        tok: _Token,
        cls: type[STLUntil] | type[STLRelease],
        left: STLFormula,
        a: int,
        b: int,
        right: STLFormula,
    ) -> STLFormula:
        """The temporal formula of operator ``tok``; a rejected one is an error at ``tok``."""
        try:
            return cls(left, a, b, right)
        except IdstlpyError as exc:  # e.g. nested bounds whose sum exceeds 2**53
            raise self.error(str(exc), tok) from exc

    def interval(self) -> tuple[int, int]:
        start = self.tok
        self.expect("[")
        a = self.integer("interval start", MAX_BOUND)
        self.expect(",")
        b = self.integer("interval end", MAX_BOUND)
        self.expect("]")
        if a > b:
            raise self.error(f"interval [{a},{b}] needs start <= end", start)
        return a, b

    def binary(self) -> STLFormula:
        self.expect("(")
        first = self.formula()
        tok = self.tok
        if tok.kind == "name" and tok.text in ("U", "R"):
            self.i += 1
            a, b = self.interval()
            second = self.formula()
            self.expect(")")
            cls = STLUntil if tok.text == "U" else STLRelease
            return self.build(tok, cls, first, a, b, second)
        if tok.kind == "op" and tok.text in ("&", "|"):
            op = tok.text
            children = [first]
            while self.accept(op):
                children.append(self.formula())
            if self.tok.kind == "op" and self.tok.text in ("&", "|"):
                raise self.error(
                    f"cannot mix '&' and '|' in one group; add parentheses around the {op!r} part"
                )
            if self.tok.kind == "name" and self.tok.text in ("U", "R"):
                raise self.error(
                    "binary temporal operators need parentheses: put '(x "
                    f"{self.tok.text}[a,b] y)' around the operands of {self.tok.text!r}"
                )
            self.expect(")")
            return STLAnd(children) if op == "&" else STLOr(children)
        raise self.error(f"expected '&', '|', 'U[a,b]' or 'R[a,b]', got {self._show(tok)}")

    def named_atom(self) -> STLAtomicProposition:
        tok = self.tok
        self.i += 1
        if tok.text == "true":
            return TRUE
        if tok.text == "false":
            return FALSE
        ap = self.atoms.get(tok.text)
        if ap is None and tok.text in self.atoms:
            raise self.error(
                f"proposition {tok.text!r} is None in atoms (expected an STLAtomicProposition, "
                "e.g. logical_and(..., name=...))",
                tok,
            )
        if ap is None:
            known = ", ".join(sorted(set(self.atoms) - RESERVED_NAMES)) or "none"
            raise self.error(f"unknown proposition {tok.text!r} (defined: {known})", tok)
        if not isinstance(ap, STLAtomicProposition):
            raise self.error(f"{tok.text!r} is not an atomic proposition", tok)
        return ap

    def braced_atom(self) -> STLAtomicProposition:
        self.expect("{")
        predicates: list[ProbabilisticLinearPredicate] = []
        joints: list[JointChanceConstraint] = []
        modes: frozenset[int] | None = None
        if self.accept("}"):
            return STLAtomicProposition()
        while True:
            tok = self.tok
            if tok.kind == "name" and tok.text == "P":
                chance = self.chance_constraint()
                if isinstance(chance, JointChanceConstraint):
                    joints.append(chance)
                else:
                    predicates.append(chance)
            else:
                item = self.mode_item()
                modes = item if modes is None else modes & item
            if self.accept("}"):
                break
            if not self.accept("&"):
                raise self.error(f"expected '&' or '}}', got {self._show(self.tok)}")
        return STLAtomicProposition(predicates, modes, joints=joints)

    def mode_item(self) -> frozenset[int]:
        tok = self.tok
        if tok.kind == "name" and tok.text == "false":
            self.i += 1
            return frozenset()
        if tok.kind == "op" and tok.text == "(":
            self.i += 1
            modes = {self.mode()}
            while self.accept("|"):
                modes.add(self.mode())
            self.expect(")")
            return frozenset(modes)
        if tok.kind == "name" and tok.text == "q":
            return frozenset({self.mode()})
        raise self.error(
            f"expected a chance constraint P[...] >= p, a mode q == k or 'false', got {self._show(tok)}"
        )

    def mode(self) -> int:
        self.expect("q")
        self.expect("==")
        tok = self.tok
        k = self.integer("mode")
        if self.num_modes is not None and k >= self.num_modes:
            raise self.error(f"mode {k} is out of range: the system has modes 0..{self.num_modes - 1}", tok)
        return k

    def chance_constraint(self) -> ProbabilisticLinearPredicate | JointChanceConstraint:
        start = self.tok
        self.expect("P")
        self.expect("[")
        faces = [self.face()]
        while self.accept("&"):
            faces.append(self.face())
        self.expect("]")
        self.expect(">=")
        level_tok = self.tok
        level = self.number("probability level")
        if not 0.5 <= level <= 1.0:
            raise self.error(f"probability level must lie in [0.5, 1], got {level_tok.text}", level_tok)
        try:
            if len(faces) > 1:
                H = np.array([h for h, _ in faces])
                c = np.array([c for _, c in faces])
                return JointChanceConstraint(H, c, self._state_variable(), 1.0 - level)
            h, c0 = faces[0]
            return ProbabilisticLinearPredicate(h, c0, self._state_variable(), 1.0 - level)
        except InvalidArgumentError as exc:  # pragma: no cover - guarded above
            raise self.error(str(exc), start) from exc

    def face(self) -> tuple[np.ndarray, float]:
        h, c = self.affine()
        self.expect("<=")
        zero = self.tok
        if self.number("0") != 0.0:
            raise self.error("the chance constraint must read P[... <= 0]", zero)
        return h, c

    def affine(self) -> tuple[np.ndarray, float]:
        var = self.variable
        if var is None:
            raise self.error("chance constraints need a state variable (state_variable=...)")
        h = np.zeros(var.size)
        c: float | None = None  # None until a constant term is read (keeps the sign of -0.0)
        sign = 1.0
        if self.accept("-"):
            sign = -1.0
        while True:
            tok = self.tok
            if tok.kind in ("num", "int"):
                value = self.number("coefficient")
                if self.accept("*"):
                    index = self.var_index()
                    h[index] += sign * value
                else:
                    c = sign * value if c is None else c + sign * value
            elif tok.kind == "name":
                index = self.var_index()
                h[index] += sign * 1.0
            else:
                raise self.error(
                    f"expected a number or {var.name}[i] in a linear expression, got {self._show(tok)}"
                )
            if self.accept("+"):
                sign = 1.0
            elif self.accept("-"):
                sign = -1.0
            else:
                return h, 0.0 if c is None else c

    def _state_variable(self) -> RealValuedVariable:
        if self.variable is None:
            raise self.error("this formula refers to a state variable, but none was given", self.tok)
        return self.variable

    def var_index(self) -> int:
        var = self._state_variable()
        tok = self.tok
        if tok.kind != "name" or tok.text != var.name:
            raise self.error(f"expected the state variable {var.name!r}, got {self._show(tok)}")
        self.i += 1
        self.expect("[")
        itok = self.tok
        i = self.integer("index")
        if i >= var.size:
            raise self.error(f"index {i} is out of range for {var.name}, which has size {var.size}", itok)
        self.expect("]")
        return i


def parse_formula(
    text: str,
    atoms: Mapping[str, STLAtomicProposition] | None = None,
    state_variable: RealValuedVariable | None = None,
    num_modes: int | None = None,
) -> STLFormula:
    """Read a formula written in the text syntax (the inverse of ``str(formula)``).

    A hand-written recursive-descent parser: nothing in ``text`` is evaluated.

    Parameters
    ----------
    text : str
        The formula, e.g. ``"(free_space U[0,240] G[0,40] target)"``.
    atoms : mapping of str to STLAtomicProposition, optional
        The named propositions the text may refer to by name.
    state_variable : RealValuedVariable, optional
        The variable of inline chance constraints ``P[... <= 0] >= p`` (required only when
        the text has some); its ``name`` is the one the text must use.
    num_modes : int, optional
        Number of modes of the system; ``q == k`` with ``k >= num_modes`` is rejected.

    Returns
    -------
    STLFormula
        Named propositions are the objects of ``atoms`` (not copies).

    Raises
    ------
    FormulaSyntaxError
        (an :class:`~idstlpy.errors.InvalidArgumentError`) with the column of the first error.
    """
    if not isinstance(text, str):
        raise InvalidTypeError(f"text (the formula) must be a str, got {type(text).__name__}")
    return _Parser(text, atoms or {}, state_variable, num_modes).parse()
