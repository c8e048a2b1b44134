"""Every public callable documents every argument (numpydoc ``Parameters``), as python-control does.

The test walks ``idstlpy.__all__`` (and the ``__all__`` of each module listed below) and, for each
public function, class and public method *defined in* one of :data:`DOCUMENTED_MODULES`, compares
the names of its signature with the names of its docstring's ``Parameters`` section:

- a class documents its constructor's arguments in the class docstring;
- ``*args`` / ``**kwargs`` are documented as ``*args`` / ``**kwargs`` (or without the stars);
- several names may share an entry (``a, b : int``);
- arguments whose name starts with ``_`` are private and need no entry;
- an entry naming no argument of the signature is an error too (stale documentation).

Every public callable in these modules that takes ``**kwargs`` must also reject an unknown keyword
(see :data:`KWARGS_CALLS`): with a ``TypeError``, or with the error :data:`KWARGS_ERRORS` names
for it (the solver options reject an unknown option with ``InvalidArgumentError``, a ``ValueError``).

Owners of other modules: add your module to :data:`DOCUMENTED_MODULES` once its docstrings pass.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest

import idstlpy
from idstlpy.backends import Backend
from idstlpy.errors import InvalidArgumentError
from idstlpy.problem import SolveOutcome, Solver
from idstlpy.synthesis import solve
from idstlpy.synthesis.options import SolverOptions

DOCUMENTED_MODULES: list[str] = [
    "idstlpy.expressions",
    "idstlpy.formulas",
    "idstlpy.syntax",
    "idstlpy.dynamical_system",
    "idstlpy.errors",
    "idstlpy.chance",
    "idstlpy.belief",
    "idstlpy.semantics",
    "idstlpy.sets",
    "idstlpy.problem",
    "idstlpy.synthesis.problem",
    "idstlpy.synthesis.options",
    "idstlpy.synthesis.results",
    "idstlpy.synthesis.objectives",
    "idstlpy.backends",
]
"""Modules whose public callables must document every argument. Extend it module by module."""

_SECTION_NAMES = ("Parameters", "Other Parameters")


def documented_parameters(doc: str | None) -> list[str]:
    """Names listed in the numpydoc ``Parameters`` / ``Other Parameters`` sections of ``doc``."""
    if not doc:
        return []
    lines = inspect.cleandoc(doc).splitlines()
    names: list[str] = []
    in_section = False
    i = 0
    while i < len(lines):
        line = lines[i]
        underline = lines[i + 1].strip() if i + 1 < len(lines) else ""
        if line.strip() and underline and set(underline) == {"-"} and not line[0].isspace():
            in_section = line.strip() in _SECTION_NAMES
            i += 2
            continue
        if in_section and line.strip() and not line[0].isspace():
            head = line.split(" : ", 1)[0].strip()
            names.extend(part.strip().lstrip("*") for part in head.split(",") if part.strip())
        i += 1
    return names


def signature_parameters(obj: Callable[..., Any]) -> list[str]:
    """Names of the public arguments of ``obj`` (``self``/``cls`` and ``_private`` ones left out)."""
    try:
        sig = inspect.signature(obj)
    except (TypeError, ValueError):  # builtins without a signature
        return []
    out = []
    for i, (name, _) in enumerate(sig.parameters.items()):
        if i == 0 and name in ("self", "cls"):
            continue
        if name.startswith("_"):
            continue
        out.append(name)
    return out


def _own_init(cls: type) -> bool:
    """True when the constructor ``cls`` runs is written in one of the documented modules."""
    for klass in cls.__mro__:
        if "__init__" in klass.__dict__:
            return klass.__module__ in DOCUMENTED_MODULES
    return False


def _public_objects() -> dict[str, Any]:
    """``qualified name -> object`` for every public callable of the documented modules."""
    found: dict[str, Any] = {}
    sources: list[tuple[Any, list[str]]] = [(idstlpy, list(idstlpy.__all__))]
    for modname in DOCUMENTED_MODULES:
        module = importlib.import_module(modname)
        sources.append((module, list(getattr(module, "__all__", []))))
    for module, names in sources:
        for name in names:
            obj = getattr(module, name)
            if not (inspect.isfunction(obj) or inspect.isclass(obj)):
                continue
            if getattr(obj, "__module__", None) not in DOCUMENTED_MODULES:
                continue
            found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return found


def _checked_callables() -> Iterator[tuple[str, Callable[..., Any], str | None]]:
    """``(name, callable whose signature counts, docstring that must document it)``."""
    for qualname, obj in sorted(_public_objects().items()):
        if inspect.isfunction(obj):
            yield qualname, obj, inspect.getdoc(obj)
            continue
        if _own_init(obj):
            yield qualname, obj, inspect.getdoc(obj)
        for attr, member in vars(obj).items():
            if attr.startswith("_"):
                continue
            if isinstance(member, staticmethod | classmethod):
                member = member.__func__
            if not inspect.isfunction(member):
                continue  # properties, constants
            bound = getattr(obj, attr)
            yield f"{qualname}.{attr}", bound, inspect.getdoc(bound)


CHECKED = list(_checked_callables())


def test_the_walk_finds_the_paper_api():
    names = {name.rsplit(".", 1)[-1] for name, _, _ in CHECKED}
    for expected in (
        "until",
        "eventually",
        "release",
        "always",
        "logical_and",
        "logical_or",
        "mk_variable",
        "prob",
        "mk_lcs",
        "mk_lbs",
        "mk_switched_sys",
        "parse_formula",
        "SwitchedSystem",
        "simulate",
        "STLAtomicProposition",
    ):
        assert expected in names, expected


@pytest.mark.parametrize(("name", "obj", "doc"), CHECKED, ids=[c[0] for c in CHECKED])
def test_every_argument_is_documented(name, obj, doc):
    params = signature_parameters(obj)
    if not params:
        return
    assert doc, f"{name} has arguments {params} but no docstring"
    documented = documented_parameters(doc)
    missing = [p for p in params if p not in documented]
    assert not missing, f"{name}: the docstring's Parameters section does not document {missing}"
    stale = [p for p in documented if p not in params]
    assert not stale, f"{name}: the docstring documents {stale}, which the signature does not have"


def test_parser_of_parameters_sections():
    doc = """Summary.

    Parameters
    ----------
    a, b : int
        Two.
    *args : float
    **options
        More.

    Returns
    -------
    out : int
        Not a parameter.
    """
    assert documented_parameters(doc) == ["a", "b", "args", "options"]
    assert documented_parameters(None) == []
    assert documented_parameters("No sections.") == []


# -- every **kwargs callable rejects an unknown keyword -------------------------------------------
def _simulate_with_unknown_keyword() -> None:
    system = idstlpy.mk_switched_sys([idstlpy.mk_lcs(np.eye(1), np.eye(1))])
    plan = idstlpy.rollout(system, idstlpy.to_belief([0.0], [[1.0]]), [0], np.zeros((1, 1)))
    system.simulate(plan, 1, [0.0], system, no_such_option=1)


def _problem() -> idstlpy.Problem:
    x = idstlpy.mk_variable(1)
    u = idstlpy.mk_variable(1, name="u")
    system = idstlpy.mk_switched_sys([idstlpy.mk_lbs([[1.0]], [[1.0]], [[0.0]])])
    domain = idstlpy.logical_and(u[0] >= -1, u[0] <= 1).region
    goal = idstlpy.logical_and(idstlpy.prob(x[0] >= 1) >= 0.9, name="goal")
    return idstlpy.Problem(system, domain, idstlpy.to_belief([0], [[0.0]]), idstlpy.eventually(0, 5, goal))


KWARGS_CALLS: dict[str, Callable[[], object]] = {
    "idstlpy.dynamical_system.SwitchedSystem.simulate": _simulate_with_unknown_keyword,
    "idstlpy.synthesis.options.SolverOptions.make": lambda: SolverOptions.make(no_such_option=1),
    "idstlpy.synthesis.options.SolverOptions.with_": lambda: SolverOptions().with_(no_such_option=1),
    "idstlpy.problem.Problem.solve": lambda: _problem().solve(seed=0, no_such_option=1),
    "idstlpy.problem.Problem.solve_result": (lambda: _problem().solve_result(seed=0, no_such_option=1)),
    "idstlpy.backends.Backend": lambda: Backend(no_such_option=1),  # type: ignore[misc, call-arg]
    "idstlpy.problem.SolveOutcome": lambda: SolveOutcome(no_such_option=1),  # type: ignore[misc, call-arg]
    "idstlpy.problem.Solver": lambda: Solver(no_such_option=1),  # type: ignore[misc, call-arg]
    "idstlpy.synthesis.problem.solve": lambda: solve(_problem(), seed=0, no_such_option=1),
}
"""Per callable taking ``**kwargs``: a call with an unknown keyword (it must raise TypeError, unless
:data:`KWARGS_ERRORS` names another error for it)."""

_UNKNOWN_OPTION = (InvalidArgumentError, r"unknown solver option\(s\) no_such_option")

KWARGS_ERRORS: dict[str, tuple[type[Exception], str]] = {
    # SolverOptions rejects an unknown option with InvalidArgumentError (a ValueError), and
    # Problem.solve / solve_result and synthesis.solve forward their **more to it.
    "idstlpy.synthesis.options.SolverOptions.make": _UNKNOWN_OPTION,
    "idstlpy.synthesis.options.SolverOptions.with_": _UNKNOWN_OPTION,
    "idstlpy.problem.Problem.solve": _UNKNOWN_OPTION,
    "idstlpy.problem.Problem.solve_result": _UNKNOWN_OPTION,
    "idstlpy.synthesis.problem.solve": _UNKNOWN_OPTION,
    # A typing.Protocol: its (*args, **kwargs) is typing's placeholder, and every call is refused.
    "idstlpy.backends.Backend": (TypeError, "Protocols cannot be instantiated"),
    "idstlpy.problem.SolveOutcome": (TypeError, "Protocols cannot be instantiated"),
    "idstlpy.problem.Solver": (TypeError, "Protocols cannot be instantiated"),
}
"""The entries of :data:`KWARGS_CALLS` that reject the unknown keyword with another error than
``TypeError: ... unexpected keyword argument``: ``(exception type, regular expression)``."""


def test_every_kwargs_callable_has_an_unknown_keyword_check():
    with_kwargs = {
        name
        for name, obj, _ in CHECKED
        if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in inspect.signature(obj).parameters.values())
    }
    assert with_kwargs == set(KWARGS_CALLS)
    assert set(KWARGS_ERRORS) <= set(KWARGS_CALLS)


@pytest.mark.parametrize("name", sorted(KWARGS_CALLS))
def test_unknown_keyword_raises(name):
    error, pattern = KWARGS_ERRORS.get(name, (TypeError, "unexpected keyword argument 'no_such_option'"))
    with pytest.raises(error, match=pattern):
        KWARGS_CALLS[name]()
