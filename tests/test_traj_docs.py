"""Docstrings of the plan / execution / figure modules: every public function documents its arguments.

As python-control does: parse the numpydoc ``Parameters`` section of every public function and
method and fail on an argument it does not name.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import re

import pytest

MODULES = [
    "idstlpy.trajectory",
    "idstlpy.plotting",
    "idstlpy.scenarios",
    "idstlpy.execution",
    "idstlpy.tracking",
    "idstlpy.execution.simulation",
    "idstlpy.execution.validation",
]


def _documented(doc: str, sections: tuple[str, ...] = ("Parameters",)) -> set[str]:
    """Names listed in the given sections (``a, b : type`` lines, ``*args``, ``**kwargs``)."""
    lines = inspect.cleandoc(doc).splitlines()
    names: set[str] = set()
    i = 0
    while i < len(lines) - 1:
        if lines[i].strip() in sections and re.fullmatch(r"-{3,}", lines[i + 1].strip()):
            j = i + 2
            while j < len(lines):
                entry = lines[j]
                if j + 1 < len(lines) and re.fullmatch(r"-{3,}", lines[j + 1].strip()):
                    break  # the next section
                if entry and not entry.startswith(" "):
                    head = entry.split(" : ")[0]
                    if re.fullmatch(r"[\w*]+(, [\w*]+)*", head):
                        names.update(n.strip().lstrip("*") for n in head.split(","))
                j += 1
            i = j
        else:
            i += 1
    return names


def _public_callables():
    seen = set()
    for modname in MODULES:
        mod = importlib.import_module(modname)
        for name in getattr(mod, "__all__", []):
            obj = getattr(mod, name)
            if inspect.isfunction(obj):
                if obj not in seen:
                    seen.add(obj)
                    yield f"{modname}.{name}", obj
            elif inspect.isclass(obj):
                if obj not in seen:
                    seen.add(obj)
                    yield f"{modname}.{name}", obj
                for attr, member in vars(obj).items():
                    if attr.startswith("_") or not callable(member) and not isinstance(member, classmethod):
                        continue
                    func = member.__func__ if isinstance(member, classmethod | staticmethod) else member
                    if inspect.isfunction(func) and func not in seen:
                        seen.add(func)
                        yield f"{modname}.{name}.{attr}", func


CALLABLES = list(_public_callables())


def test_the_modules_export_something():
    assert len(CALLABLES) > 30


@pytest.mark.parametrize("qualname, obj", CALLABLES, ids=[q for q, _ in CALLABLES])
def test_every_argument_is_documented(qualname, obj):
    doc = inspect.getdoc(obj)
    assert doc, f"{qualname} has no docstring"
    target = obj.__init__ if inspect.isclass(obj) else obj
    if inspect.isclass(obj) and target is object.__init__:
        return
    params = [p.name for p in inspect.signature(target).parameters.values() if p.name not in ("self", "cls")]
    if inspect.isclass(obj) and not params:
        return
    dataclass = inspect.isclass(obj) and dataclasses.is_dataclass(obj)
    documented = _documented(doc, ("Parameters", "Attributes") if dataclass else ("Parameters",))
    missing = [p for p in params if p not in documented]
    assert not missing, f"{qualname}: Parameters section lacks {missing}"


def test_the_checker_sees_a_missing_argument():
    doc = """Summary.

    Parameters
    ----------
    a, b : int
        Two.
    **kwargs
        Passed on.

    Returns
    -------
    c : int
    """
    assert _documented(doc) == {"a", "b", "kwargs"}
