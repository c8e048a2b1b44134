"""TOML problem files: a whole synthesis problem as plain data, with no code in it.

A problem file describes the modes of a switched belief system, the control domain, the
initial belief, named atomic propositions, the formula (in the text syntax of
:mod:`idstlpy.syntax`), solver parameters, and the real system a plan is executed on. It is
read with :mod:`tomllib`; nothing in it is executed. ``docs/problem-files.md`` is the reference
of every key; ``examples/light_dark.toml`` is the paper's listing.

The package has one module per job, each importing only the ones above it:

- :mod:`~idstlpy.problem_file.locations`: field paths, override keys, lines, error messages;
- :mod:`~idstlpy.problem_file.schema`: the keys, and checks of plain values;
- :mod:`~idstlpy.problem_file.grammar`: the whitelisted expression grammar (noise scales
  interpreted with NumPy, linear constraints evaluated on the library's linear expressions);
- :mod:`~idstlpy.problem_file.builder`: plain data to systems, domain, belief, formula;
- :mod:`~idstlpy.problem_file.spec`: :class:`ProblemSpec` and :func:`load_problem`;
- :mod:`~idstlpy.problem_file.overrides`: :func:`apply_overrides`.

Every error is a :class:`~idstlpy.errors.ProblemFileError` whose message starts with
``file:line: field:``.
"""

from __future__ import annotations

from .builder import BuiltProblem, ExecutionSettings, solver_parameters
from .grammar import NoiseExpression, parse_linear_constraint, parse_noise_expression
from .locations import parse_override_path
from .overrides import apply_overrides
from .spec import ProblemSpec, load_problem, text_sha256

__all__ = [
    "ProblemSpec",
    "BuiltProblem",
    "ExecutionSettings",
    "NoiseExpression",
    "load_problem",
    "apply_overrides",
    "parse_override_path",
    "parse_noise_expression",
    "parse_linear_constraint",
    "solver_parameters",
    "text_sha256",
]
