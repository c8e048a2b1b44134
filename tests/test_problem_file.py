"""TOML problem files: the listing as a file, every value form, and every malformed case."""

from __future__ import annotations

import math
import pickle
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import idstlpy as stl
from idstlpy.problem_file import (
    BuiltProblem,
    NoiseExpression,
    ProblemSpec,
    apply_overrides,
    load_problem,
    parse_linear_constraint,
    parse_noise_expression,
    parse_override_path,
)
from idstlpy.scenarios import light_dark

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
LIGHT_DARK = EXAMPLES / "light_dark.toml"

MINIMAL = """\
formula = "F[0,10] goal"

[[modes]]
A = [[1.0, 0.0], [0.0, 1.0]]
B = [[0.25, 0.0], [0.0, 0.25]]

[control_domain]
low = [-1.0, -1.0]
high = [1.0, 1.0]

[initial_belief]
mean = [0.0, 0.0]
cov = [[0.01, 0.0], [0.0, 0.01]]

[propositions.goal]
confidence = 0.9
constraints = ["x[0] >= 1", "x[1] <= 2"]
"""


def _write(tmp_path: Path, text: str, name: str = "problem.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _preds(ap: stl.STLAtomicProposition) -> list[tuple[list[float], float, float]]:
    return [(list(p.h), p.c, p.eps) for p in ap.predicates]


# ------------------------------------------------------------------------------------------------
# the listing as a file
# ------------------------------------------------------------------------------------------------


def test_light_dark_file_is_the_listing():
    spec = load_problem(LIGHT_DARK)
    assert isinstance(spec, ProblemSpec) and spec.name == str(LIGHT_DARK)
    built = spec.build()
    assert isinstance(built, BuiltProblem)
    problem, solver, execution = built
    ref = light_dark()
    assert str(problem.stl_formula) == str(ref.stl_formula) == "(free_space U[0,240] G[0,40] target)"
    for ap, ref_ap in zip(
        problem.stl_formula.atomic_propositions(), ref.stl_formula.atomic_propositions(), strict=True
    ):
        assert ap.name == ref_ap.name and ap.modes == ref_ap.modes
        assert _preds(ap) == _preds(ref_ap)
    mode, ref_mode = problem.switched_system.system_modes[0], ref.switched_system.system_modes[0]
    for name in ("A", "B", "W", "C"):
        np.testing.assert_array_equal(getattr(mode, name), getattr(ref_mode, name))
    for state in ([0.0, 2.5], [5.0, 0.0], [-1.0, 4.0], [3.3, 1.7]):
        np.testing.assert_array_equal(mode.noise(np.array(state)), ref_mode.noise(np.array(state)))
    np.testing.assert_array_equal(problem.control_domain.H, ref.control_domain.H)
    np.testing.assert_array_equal(problem.control_domain.c, ref.control_domain.c)
    np.testing.assert_array_equal(problem.initial_state.mean, ref.initial_state.mean)
    np.testing.assert_array_equal(problem.initial_state.cov, ref.initial_state.cov)
    assert solver == {
        "rrt_timeout": 60,
        "delta_near": 2,
        "delta_drain": 0.5,
        "goal_bias": 0.25,
        "min_num_of_steps": 3,
        "max_num_of_steps": 15,
    }
    np.testing.assert_array_equal(execution.real_initial_state, [0.5, 2.75])
    real = execution.real_system.system_modes[0]
    assert type(real) is stl.LCS
    np.testing.assert_array_equal(real.B, 0.25 * np.identity(2))
    assert execution.lqr["horizon"] == 5
    np.testing.assert_array_equal(execution.lqr["R"], 0.05 * np.identity(2))
    assert execution.runs == 20 and execution.seed == 0


def test_path_string_and_text_load_the_same():
    by_path = load_problem(LIGHT_DARK)
    by_str = load_problem(str(LIGHT_DARK))
    by_text = load_problem(LIGHT_DARK.read_text())
    assert by_path.data == by_str.data == by_text.data
    assert by_text.name == "<string>"
    assert by_path.title == "light-dark"


def test_built_problem_and_noise_pickle():
    spec = load_problem(LIGHT_DARK)
    problem = spec.build().problem
    noise = problem.switched_system.system_modes[0].V
    assert isinstance(noise, NoiseExpression)
    again = pickle.loads(pickle.dumps(noise))
    assert again == noise
    np.testing.assert_array_equal(again(np.array([1.0, 2.0])), noise(np.array([1.0, 2.0])))
    clone = pickle.loads(pickle.dumps(problem))
    assert str(clone.stl_formula) == str(problem.stl_formula)
    assert pickle.loads(pickle.dumps(spec)) == spec


def test_examples_load():
    for path in sorted(EXAMPLES.glob("*.toml")):
        if path.name.startswith("sweep"):
            continue
        problem, solver, _ = load_problem(path).build()
        assert problem.stl_formula.horizon > 0
        assert "rrt_timeout" in solver


# ------------------------------------------------------------------------------------------------
# value forms
# ------------------------------------------------------------------------------------------------


def _with_sensor(v: str | None, C: str = "[[1.0, 0.0], [0.0, 1.0]]") -> str:
    extra = f"C = {C}\n" + (f"V = {v}\n" if v is not None else "")
    return MINIMAL.replace("B = [[0.25, 0.0], [0.0, 0.25]]\n", "B = [[0.25, 0.0], [0.0, 0.25]]\n" + extra)


@pytest.mark.parametrize(
    ("v", "kind", "at_x", "expected"),
    [
        (None, stl.POLBSWithLinNoise, [0.0, 0.0], np.zeros((2, 2))),
        ("[[0.5, 0.0], [0.0, 0.25]]", stl.POLBSWithLinNoise, [1.0, 1.0], np.diag([0.5, 0.25])),
        ('"0.1*(5 - x[0])**2 + 0.001"', stl.POLBSWithNonLinNoise, [3.0, 0.0], (0.4 + 0.001) * np.eye(2)),
        (
            "{ scale = 2.0, matrix = [[1.0, 0.0], [0.0, 3.0]] }",
            stl.POLBSWithLinNoise,
            [0.0, 0.0],
            np.diag([2.0, 6.0]),
        ),
        (
            '{ scale = "sqrt(abs(x[1])) + max(x[0], 0, -1)" }',
            stl.POLBSWithNonLinNoise,
            [2.0, -4.0],
            4.0 * np.eye(2),
        ),
        (
            '{ scale = "exp(-x[0]) * min(1, x[1])", matrix = [[1.0], [2.0]] }',
            stl.POLBSWithNonLinNoise,
            [0.0, 0.5],
            np.array([[0.5], [1.0]]),
        ),
    ],
)
def test_noise_forms(v, kind, at_x, expected):
    mode = load_problem(_with_sensor(v)).build().problem.switched_system.system_modes[0]
    assert type(mode) is kind
    np.testing.assert_allclose(mode.noise(np.array(at_x)), expected, rtol=1e-12)


def test_blind_mode_and_defaults():
    problem, solver, execution = load_problem(MINIMAL).build()
    mode = problem.switched_system.system_modes[0]
    assert type(mode) is stl.LBS and mode.p == 0
    np.testing.assert_array_equal(mode.process_cov, np.zeros((2, 2)))
    assert solver == {}
    assert execution.real_system is problem.switched_system
    assert execution.real_initial_state is None  # drawn from the prior by validate
    assert execution.lqr is None and execution.runs == 100 and execution.seed is None


def test_control_domain_inequalities_and_diagonal_cov():
    text = MINIMAL.replace(
        "low = [-1.0, -1.0]\nhigh = [1.0, 1.0]",
        "A = [[1.0, 1.0], [-1.0, 0.0], [0.0, -1.0]]\nb = [1.0, 0.0, 0.0]",
    ).replace("cov = [[0.01, 0.0], [0.0, 0.01]]", "cov = [0.01, 0.04]")
    problem = load_problem(text).build().problem
    assert problem.control_domain.contains([0.2, 0.3])
    assert not problem.control_domain.contains([0.8, 0.3])
    np.testing.assert_array_equal(problem.initial_state.cov, np.diag([0.01, 0.04]))


def test_constraints_match_the_python_api():
    text = MINIMAL.replace(
        'constraints = ["x[0] >= 1", "x[1] <= 2"]',
        'constraints = ["x[0] >= 1", "x[1] <= 2", "-1 <= 2*x[0] - x[1]/4 <= 3",'
        ' { expr = "x[0] + 1 >= -(x[1] - 2) * 3", confidence = 0.99 }]\nmodes = [0]',
    )
    problem = load_problem(text).build().problem
    (goal,) = problem.stl_formula.atomic_propositions()[1:]
    x = goal.variable
    api = [
        stl.prob(x[0] >= 1) >= 0.9,
        stl.prob(x[1] <= 2) >= 0.9,
        stl.prob(-1 <= 2 * x[0] - x[1] / 4) >= 0.9,
        stl.prob(2 * x[0] - x[1] / 4 <= 3) >= 0.9,
        stl.prob(x[0] + 1 >= -(x[1] - 2) * 3) >= 0.99,
    ]
    assert len(goal.predicates) == len(api)
    for got, want in zip(goal.predicates, api, strict=True):
        np.testing.assert_allclose(got.h, want.h, atol=0)
        assert got.c == pytest.approx(want.c) and got.eps == pytest.approx(want.eps)
    assert goal.modes == frozenset({0})


def test_inline_atoms_in_the_formula():
    formula = "(F[0,10] goal | G[0,3] {P[x[0] - 1.0 <= 0] >= 0.95 & q == 0})"
    text = MINIMAL.replace('formula = "F[0,10] goal"', f'formula = "{formula}"')
    problem = load_problem(text).build().problem
    assert str(problem.stl_formula) == formula


# ------------------------------------------------------------------------------------------------
# expressions
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "x", "expected"),
    [
        ("-x[0]**2", [3.0], -9.0),
        ("2**3**2", [0.0], 512.0),
        ("(1/10)*(5 - x[0])**2 + 0.001", [1.0], 0.1 * 16 + 0.001),
        ("sqrt(4) + exp(0) + abs(-x[0]) + min(x[0], 2, 3) + max(1, -x[0])", [-1.0], 2 + 1 + 1 - 1 + 1),
        ("+x[0] - -x[0]", [2.0], 4.0),
        ("1e-3 * 10", [0.0], 0.01),
    ],
)
def test_noise_expression_values(text, x, expected):
    noise = parse_noise_expression(text, n=1, matrix=[[1.0]])
    assert noise.scale(np.array(x)) == pytest.approx(expected)


_leaf = st.one_of(st.integers(0, 9).map(str), st.sampled_from(["x[0]", "x[1]", "0.5", "2.25", "1e-2"]))


def _grow(inner):
    return st.one_of(
        st.tuples(inner, st.sampled_from(["+", "-", "*"]), inner).map(lambda t: f"({t[0]} {t[1]} {t[2]})"),
        inner.map(lambda a: f"(-{a})"),
        inner.map(lambda a: f"abs({a})"),
        st.tuples(inner, inner).map(lambda t: f"max({t[0]}, {t[1]})"),
        st.tuples(inner, inner).map(lambda t: f"min({t[0]}, {t[1]})"),
        inner.map(lambda a: f"({a})**2"),
    )


@given(st.recursive(_leaf, _grow, max_leaves=10), st.floats(-3, 3), st.floats(-3, 3))
def test_noise_expressions_evaluate_like_python(text, x0, x1):
    # the test may use eval as a reference; the library never does
    expected = eval(text, {"__builtins__": {}, "abs": abs, "max": max, "min": min}, {"x": [x0, x1]})
    got = parse_noise_expression(text, n=2).scale(np.array([x0, x1]))
    assert got == pytest.approx(expected, rel=1e-9, abs=1e-12)


def test_linear_constraint_parser():
    assert [(list(h), c) for h, c in parse_linear_constraint("x[0] >= -1", 2)] == [([-1.0, 0.0], -1.0)]
    assert len(parse_linear_constraint("0 <= x[1] <= 1 <= x[0] + 3", 2)) == 3
    for bad, message in [
        ("x[0]", "compare"),
        ("x[0] == 1", "<= and >="),
        ("x[0]*x[1] <= 1", "not linear"),
        ("1/x[0] <= 1", "not linear"),
        ("x[0]**2 <= 1", "not linear"),
        ("sqrt(x[0]) <= 1", "not linear"),
        ("x[0]/0 <= 1", "division by zero"),
        ("1 <= 2", "does not involve"),
        ("x[0] <= 1 and x[1] <= 2", "boolean"),
    ]:
        with pytest.raises(stl.ProblemFileError, match=message):
            parse_linear_constraint(bad, 2)


FORBIDDEN = [
    ("__import__('os').system('touch {sentinel}')", "not allowed"),
    ("x.__class__", "attribute access"),
    ("x[0].__class__", "attribute access"),
    ("open('{sentinel}', 'w')", "calling 'open'"),
    ("(lambda: 1)()", "calling a lambda"),
    ("[i for i in x]", "comprehension"),
    ("(i for i in x)", "generator"),
    ("globals()", "calling 'globals'"),
    ("__builtins__", "unknown name"),
    ("y[0]", "only x[i]"),
    ("x[0:1]", "integer literal"),
    ("x[-1]", "integer literal"),
    ("x[2]", "out of range"),
    ("x['a']", "integer literal"),
    ("'text'", "not a number"),
    ("True", "not a number"),
    ("1j", "not a number"),
    ("1 if x[0] else 2", "conditional"),
    ("x[0] < 1", "comparison"),
    ("(y := 1)", "assignment"),
    ("sqrt(x=1)", "keyword"),
    ("max(x[0])", "arguments"),
    ("exec('1')", "calling 'exec'"),
    ("x[0] +", "syntax error"),
    ("9" * 400, "too large"),
    ("-" * 3000 + "1", "longer than"),
    ("(" * 1500 + "1" + ")" * 1500, "longer than"),
    ("((((((((((" * 40 + "1" + "))))))))))" * 40, "nested"),
]


@pytest.mark.parametrize(("expression", "message"), FORBIDDEN)
def test_forbidden_noise_expressions_never_run(tmp_path, expression, message):
    sentinel = tmp_path / "pwned"
    expr = expression.replace("{sentinel}", str(sentinel))
    text = _with_sensor("'''" + expr + "'''")
    path = _write(tmp_path, text)
    with pytest.raises(stl.ProblemFileError) as info:
        load_problem(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}:7: modes[0].V: ")
    assert message in msg
    assert info.value.file == str(path) and info.value.line == 7 and info.value.field == "modes[0].V"
    assert not sentinel.exists()


@pytest.mark.parametrize(("expression", "message"), FORBIDDEN[:10])
def test_forbidden_constraint_expressions_never_run(tmp_path, expression, message):
    sentinel = tmp_path / "pwned"
    expr = expression.replace("{sentinel}", str(sentinel))
    text = MINIMAL.replace('"x[1] <= 2"', "'''" + expr + " <= 1'''")
    path = _write(tmp_path, text)
    with pytest.raises(stl.ProblemFileError) as info:
        load_problem(path)
    assert str(info.value).startswith(f"{path}:17: propositions.goal.constraints[1]: ")
    assert not sentinel.exists()


# ------------------------------------------------------------------------------------------------
# malformed files: every error names the file, the line and the field
# ------------------------------------------------------------------------------------------------

MALFORMED = [
    # (replace this, with this, field, line, message)
    ("[control_domain]", "[control_domainn]", "control_domainn", 7, "unknown key 'control_domainn'"),
    ("high = [1.0, 1.0]", "high = [1.0, 1.0]\nhihg = 1", "control_domain.hihg", 10, "unknown key"),
    ('formula = "F[0,10] goal"\n', "", "<file>", None, "missing required key 'formula'"),
    ("A = [[1.0, 0.0], [0.0, 1.0]]\n", "", "modes[0]", 3, "missing required key 'A'"),
    ("mean = [0.0, 0.0]", "", "initial_belief", 11, "missing required key 'mean'"),
    ("low = [-1.0, -1.0]\n", "", "control_domain", 7, "missing required key 'low'"),
    (
        "B = [[0.25, 0.0], [0.0, 0.25]]",
        "B = [[0.25, 0.0, 1.0], [0.0, 0.25]]",
        "modes[0].B",
        5,
        "different lengths",
    ),
    ("B = [[0.25, 0.0], [0.0, 0.25]]", "B = [[0.25, 0.0]]", "modes[0].B", 5, "shape (2, *)"),
    ("A = [[1.0, 0.0], [0.0, 1.0]]", "A = [[1.0, 0.0]]", "modes[0].A", 4, "must be square"),
    ("A = [[1.0, 0.0], [0.0, 1.0]]", 'A = "eye"', "modes[0].A", 4, "must be a matrix"),
    ("mean = [0.0, 0.0]", "mean = [0.0, 0.0, 0.0]", "initial_belief.mean", 12, "length 2"),
    ("mean = [0.0, 0.0]", 'mean = [0.0, "a"]', "initial_belief.mean", 12, "array of numbers"),
    (
        "cov = [[0.01, 0.0], [0.0, 0.01]]",
        "cov = [[0.01, 0.5], [0.0, 0.01]]",
        "initial_belief.cov",
        13,
        "symmetric",
    ),
    ("high = [1.0, 1.0]", "high = [1.0]", "control_domain.high", 9, "length 2"),
    ("high = [1.0, 1.0]", "high = [-2.0, 1.0]", "control_domain.low", 8, "<= high"),
    ("confidence = 0.9", "confidence = 0.2", "propositions.goal.confidence", 16, "[0.5, 1.0]"),
    ("confidence = 0.9", 'confidence = "high"', "propositions.goal.confidence", 16, "must be a number"),
    ("confidence = 0.9\n", "", "propositions.goal.constraints[0]", 16, "no confidence"),
    ('"x[1] <= 2"', "3", "propositions.goal.constraints[1]", 17, "must be a string"),
    ('"x[1] <= 2"', '{ exp = "x[0] <= 1" }', "propositions.goal.constraints[1].exp", 17, "unknown key"),
    (
        "[propositions.goal]",
        "[propositions.goal]\nmodes = [1]",
        "propositions.goal.modes[0]",
        16,
        "out of range",
    ),
    ("[propositions.goal]", "[propositions.goal]\nmodes = 0", "propositions.goal.modes", 16, "array"),
    ("[propositions.goal]", "[propositions.F]", "propositions.F", 15, "identifier other than"),
    ('formula = "F[0,10] goal"', 'formula = "F[0,10] gaol"', "formula", 1, "unknown proposition 'gaol'"),
    ('formula = "F[0,10] goal"', 'formula = "F[0,10] (goal"', "formula", 1, "column 14"),
    ('formula = "F[0,10] goal"', "formula = 3", "formula", 1, "must be a string"),
    ("[[modes]]", "[solver]\nrrt_timeout = 0\n\n[[modes]]", "solver.rrt_timeout", 4, "rrt_timeout"),
    ("[[modes]]", "[solver]\nmax_num_of_steps = 2.5\n\n[[modes]]", "solver.max_num_of_steps", 4, "integer"),
    ("[[modes]]", "[solver]\nbudget = 2\n\n[[modes]]", "solver.budget", 4, "unknown key 'budget'"),
    ("[[modes]]", "[validation]\nruns = 0\n\n[[modes]]", "validation.runs", 4, ">= 1"),
    (
        "[[modes]]",
        "[execution]\nreal_initial_state = [1.0]\n\n[[modes]]",
        "execution.real_initial_state",
        4,
        "length 2",
    ),
    (
        "[[modes]]",
        "[[execution.real_system]]\nA = [[1.0]]\nB = [[1.0]]\n\n[[modes]]",
        "execution.real_system[0].A",
        4,
        "shape (2, 2)",
    ),
    (
        "[[modes]]",
        "[execution.lqr]\nhorizon = 5\nQ = [[1.0]]\n\n[[modes]]",
        "execution.lqr.Q",
        5,
        "shape (2, 2)",
    ),
    (
        "B = [[0.25, 0.0], [0.0, 0.25]]",
        "B = [[0.25, 0.0], [0.0, 0.25]]\nV = [[1.0, 0.0], [0.0, 1.0]]",
        "modes[0].V",
        6,
        "needs an output matrix C",
    ),
    (
        "B = [[0.25, 0.0], [0.0, 0.25]]",
        "B = [[0.25, 0.0], [0.0, 0.25]]\nC = [[1.0, 0.0]]\nV = true",
        "modes[0].V",
        7,
        "must be a matrix, an expression string",
    ),
    (
        "B = [[0.25, 0.0], [0.0, 0.25]]",
        "B = [[0.25, 0.0], [0.0, 0.25]]\nC = [[1.0, 0.0]]\nV = { scale = 1.0, shape = 2 }",
        "modes[0].V.shape",
        7,
        "unknown key",
    ),
    (
        "[propositions.goal]",
        '[propositions.goal]\nformula = "x"',
        "propositions.goal.formula",
        16,
        "top-level keys such as this one must come before the first [table]",
    ),
    ("high = [1.0, 1.0]", "high = [1.0, 1.0]\nA = [[1.0, 0.0]]\nb = [1.0]", "control_domain", 7, "not both"),
    ("mean = [0.0, 0.0]", "mean = [0.0, inf]", "initial_belief.mean", 12, "non-finite"),
]


@pytest.mark.parametrize(("old", "new", "field", "line", "message"), MALFORMED)
def test_malformed_files_name_the_place(tmp_path, old, new, field, line, message):
    assert old in MINIMAL
    path = _write(tmp_path, MINIMAL.replace(old, new, 1))
    with pytest.raises(stl.ProblemFileError) as info:
        load_problem(path)
    err = info.value
    where = f"{path}:{line}: {field}: " if line is not None else f"{path}: {field}: "
    assert str(err).startswith(where), str(err)
    assert message in str(err)
    assert err.field == field and err.line == line and err.file == str(path)


def test_invalid_toml_names_the_line(tmp_path):
    path = _write(tmp_path, MINIMAL.replace("cov = [[0.01", "cov = [[0.01,,"))
    with pytest.raises(stl.ProblemFileError, match=r":13: invalid TOML") as info:
        load_problem(path)
    assert info.value.line == 13


def test_missing_file_and_wrong_types(tmp_path):
    with pytest.raises(stl.ProblemFileError, match="cannot read"):
        load_problem(tmp_path / "absent.toml")
    with pytest.raises(stl.ProblemFileError, match="cannot read"):
        load_problem(str(tmp_path / "absent.toml"))
    with pytest.raises(stl.ProblemFileError, match="no such problem file"):
        load_problem("examples/light_dark")
    with pytest.raises(stl.ProblemFileError):
        load_problem(42)  # type: ignore[arg-type]
    assert issubclass(stl.ProblemFileError, ValueError)


def test_inconsistent_problem_is_a_problem_file_error():
    text = _with_sensor('"sqrt(-1 - x[0]**2)"')  # noise function returns NaN everywhere
    with pytest.raises(stl.ProblemFileError, match="non-finite"):
        load_problem(text)


def test_unknown_key_in_real_system_mode(tmp_path):
    text = MINIMAL + (
        "\n[[execution.real_system]]\nA = [[1.0, 0.0], [0.0, 1.0]]\nB = [[1.0, 0.0], [0.0, 1.0]]\nD = 1\n"
    )
    path = _write(tmp_path, text)
    with pytest.raises(stl.ProblemFileError) as info:
        load_problem(path)
    assert str(info.value).startswith(f"{path}:22: execution.real_system[0].D: unknown key 'D'")


# ------------------------------------------------------------------------------------------------
# overrides
# ------------------------------------------------------------------------------------------------


def test_override_paths():
    assert parse_override_path("solver.rrt_timeout") == ["solver", "rrt_timeout"]
    assert parse_override_path("modes[0].V.scale") == ["modes", 0, "V", "scale"]
    assert parse_override_path("modes.1.A") == ["modes", 1, "A"]
    assert parse_override_path("execution.real_system[0].B") == ["execution", "real_system", 0, "B"]
    for bad in ["", ".solver", "solver..x", "[0].a", "solver.", "a b", "modes[x]"]:
        with pytest.raises(stl.ProblemFileError):
            parse_override_path(bad)


def test_apply_overrides():
    spec = load_problem(LIGHT_DARK)
    new = apply_overrides(
        spec,
        {
            "solver.rrt_timeout": 5,
            "solver.seed": 3,
            "modes[0].V.scale": "0.2*(5 - x[0])**2 + 0.01",
            "initial_belief.mean": [0.5, 2.0],
            "propositions.target.confidence": 0.9,
            "formula": "(free_space U[0,100] G[0,10] target)",
        },
    )
    problem, solver, _ = new.build()
    assert solver["rrt_timeout"] == 5 and solver["seed"] == 3
    np.testing.assert_array_equal(problem.initial_state.mean, [0.5, 2.0])
    assert problem.switched_system.system_modes[0].noise(np.array([4.0, 0.0]))[0, 0] == pytest.approx(0.21)
    assert str(problem.stl_formula) == "(free_space U[0,100] G[0,10] target)"
    target = problem.stl_formula.atomic_propositions()[-1]
    assert target.name == "target" and target.predicates[0].eps == pytest.approx(0.1)
    # the original is untouched
    assert spec.data["solver"]["rrt_timeout"] == 60 and spec.overrides == {}
    assert new.overrides["solver.rrt_timeout"] == 5
    # overrides compose
    newer = apply_overrides(new, {"solver.rrt_timeout": 7})
    assert newer.build().solver_kwargs["rrt_timeout"] == 7 and newer.overrides["solver.seed"] == 3


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"solver.budget": 1}, "solver.budget (override): unknown key 'budget'"),
        ({"solver.rrt_timeout": "fast"}, "solver.rrt_timeout (override): must be a number"),
        ({"modes[3].A": 1}, "no element 3"),
        ({"modes[0].V.scale": "__import__('os')"}, "modes[0].V.scale (override): calling"),
        ({"formula.x": 1}, "is not a table"),
        ({"initial_belief.mean": [1.0]}, "initial_belief.mean (override): must have length 2"),
    ],
)
def test_bad_overrides(overrides, message):
    spec = load_problem(LIGHT_DARK)
    with pytest.raises(stl.ProblemFileError, match=None) as info:
        apply_overrides(spec, overrides)
    assert message in str(info.value)
    assert str(info.value).startswith(str(LIGHT_DARK))


def test_noise_expression_is_plain_data():
    noise = parse_noise_expression("0.1*(5 - x[0])**2 + 0.001", n=2)
    assert all(isinstance(part, str | int | float | tuple) for part in _flatten(noise.tree))
    np.testing.assert_allclose(noise(np.array([4.0, 0.0])), 0.101 * np.eye(2))
    assert "0.1*(5 - x[0])**2" in repr(noise)
    assert math.isnan(parse_noise_expression("sqrt(x[0])", n=1).scale(np.array([-1.0])))


def _flatten(tree):
    yield tree
    if isinstance(tree, tuple):
        for part in tree:
            yield from _flatten(part)


# ------------------------------------------------------------------------------------------------
# layout
# ------------------------------------------------------------------------------------------------


def _local_imports(package_dir: Path, package: str) -> dict[str, set[str]]:
    """Module -> modules of the same package it imports (lazy imports included)."""
    import ast

    graph: dict[str, set[str]] = {}
    for path in package_dir.glob("*.py"):
        name = path.stem
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                if node.module:
                    deps.add(node.module.split(".")[0])
                else:
                    deps.update(a.name for a in node.names)
        graph[name] = deps - {name}
    return graph


def assert_acyclic(graph: dict[str, set[str]]) -> None:
    done: set[str] = set()

    def visit(node: str, stack: tuple[str, ...]) -> None:
        assert node not in stack, f"import cycle: {' -> '.join(stack + (node,))}"
        if node in done:
            return
        for dep in graph.get(node, ()):
            if dep != "__init__":
                visit(dep, stack + (node,))
        done.add(node)

    for node in graph:
        visit(node, ())


def test_problem_file_is_a_package_without_cycles():
    import idstlpy.problem_file as pf

    assert stl.load_problem is pf.load_problem and stl.ProblemSpec is pf.ProblemSpec
    assert stl.apply_overrides is pf.apply_overrides
    graph = _local_imports(Path(pf.__file__).parent, "idstlpy.problem_file")
    assert {"locations", "schema", "grammar", "builder", "spec", "overrides"} <= set(graph)
    assert_acyclic({k: v for k, v in graph.items() if k != "__init__"})
    # the lower modules never import the higher ones
    assert graph["locations"] == set() and graph["schema"] <= {"locations"}


# ------------------------------------------------------------------------------------------------
# inputs: errors name the real culprit
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("old", "new", "field", "line"),
    [
        ("B = [[0.25, 0.0], [0.0, 0.25]]", "B = [[0.25], [0.25]]", "modes[0].B", 5),
        ("B = [[0.25, 0.0], [0.0, 0.25]]", "B = [[0.25, 0.0, 0.1], [0.0, 0.25, 0.1]]", "modes[0].B", 5),
        (
            "[control_domain]",
            "[[modes]]\nA = [[1.0, 0.0], [0.0, 1.0]]\nB = [[1.0], [1.0]]\n\n[control_domain]",
            "modes[1].B",
            9,
        ),
    ],
)
def test_wrong_B_shape_is_blamed_on_B(tmp_path, old, new, field, line):
    path = _write(tmp_path, MINIMAL.replace(old, new, 1))
    with pytest.raises(stl.ProblemFileError) as info:
        load_problem(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}:{line}: {field}: must have shape (2, 2)"), msg
    assert "control_domain" in msg  # says where the number of inputs comes from
    assert info.value.field == field


def test_wrong_B_shape_with_an_inequality_control_domain(tmp_path):
    box = "low = [-1.0, -1.0]\nhigh = [1.0, 1.0]"
    text = MINIMAL.replace(box, "A = [[1.0, 0.0], [0.0, 1.0]]\nb = [1.0, 1.0]")
    path = _write(tmp_path, text.replace("B = [[0.25, 0.0], [0.0, 0.25]]", "B = [[0.25], [0.25]]"))
    match = r"modes\[0\]\.B: must have shape \(2, 2\).*control_domain\.A"
    with pytest.raises(stl.ProblemFileError, match=match):
        load_problem(path)


def test_a_wrong_control_domain_is_still_blamed_on_it(tmp_path):
    path = _write(tmp_path, MINIMAL.replace("high = [1.0, 1.0]", "high = [1.0, 1.0, 1.0]"))
    with pytest.raises(stl.ProblemFileError) as info:
        load_problem(path)
    assert info.value.field == "control_domain.high" and "length 2" in str(info.value)


def test_wrong_B_shape_of_the_real_system(tmp_path):
    text = MINIMAL + "\n[[execution.real_system]]\nA = [[1.0, 0.0], [0.0, 1.0]]\nB = [[1.0], [1.0]]\n"
    match = r"execution\.real_system\[0\]\.B: must have shape \(2, 2\)"
    with pytest.raises(stl.ProblemFileError, match=match):
        load_problem(_write(tmp_path, text))


def test_cov_as_a_vector_of_variances():
    text = MINIMAL.replace("cov = [[0.01, 0.0], [0.0, 0.01]]", "cov = [0.01, 0.04]")
    np.testing.assert_array_equal(load_problem(text).build().problem.initial_state.cov, np.diag([0.01, 0.04]))
    one_d = (
        'formula = "F[0,5] goal"\n[[modes]]\nA = [[1.0]]\nB = [[1.0]]\n[control_domain]\nlow = [-1.0]\n'
        "high = [1.0]\n[initial_belief]\nmean = [0.0]\ncov = [0.5]\n[propositions.goal]\nconfidence = 0.9\n"
        'constraints = ["x[0] >= 1"]\n'
    )
    np.testing.assert_array_equal(load_problem(one_d).build().problem.initial_state.cov, [[0.5]])
    with pytest.raises(stl.ProblemFileError, match=r"initial_belief\.cov: variances must be >= 0"):
        load_problem(text.replace("cov = [0.01, 0.04]", "cov = [0.01, -0.04]"))


def test_every_solver_option_is_a_solver_key():
    import dataclasses

    # values other than the defaults where a default would not show the type plumbing
    values = {
        "rrt_timeout": 5,
        "delta_near": 1.5,
        "min_num_of_steps": 2,
        "max_num_of_steps": 9,
        "seed": 3,
        "time_limit": 30,
        "max_candidates": 7,
        "sampler_iterations": 100,
        "objective": "effort",
        "effort_weights": [1.0, 2.0],
        "sat_backend": "minisat22",
        "milp_backend": "highs",
    }
    from idstlpy.synthesis.options import CODE_ONLY_OPTIONS

    # every field a file can hold (not the callables of stop_rules)
    fields = {
        f.name: f.default for f in dataclasses.fields(stl.SolverOptions) if f.name not in CODE_ONLY_OPTIONS
    }
    # every field: the given value, else its default (valid by construction); None stays unset
    chosen = {k: values.get(k, d) for k, d in fields.items() if values.get(k, d) is not None}
    overrides = {f"solver.{k}": v for k, v in chosen.items()}
    solver = apply_overrides(load_problem(LIGHT_DARK), overrides).build().solver_kwargs
    assert set(solver) == set(chosen)
    options = stl.SolverOptions.make(**solver)
    for key, value in chosen.items():
        want = tuple(value) if isinstance(value, list) else value
        assert getattr(options, key) == want, key


def test_problem_file_doc_names_every_key_and_solver_default():
    import dataclasses
    import re

    from idstlpy.problem_file import schema

    text = (Path(__file__).resolve().parents[1] / "docs" / "problem-files.md").read_text()
    keys = set(schema.TOP_KEYS) | set(schema.MODE_KEYS) | set(schema.NOISE_TABLE_KEYS)
    keys |= set(schema.CONTROL_DOMAIN_KEYS) | set(schema.INITIAL_BELIEF_KEYS) | set(schema.PROPOSITION_KEYS)
    keys |= set(schema.CONSTRAINT_TABLE_KEYS) | set(schema.EXECUTION_KEYS) | set(schema.LQR_KEYS)
    keys |= set(schema.VALIDATION_KEYS) | set(schema.REPLAN_OPTION_KEYS) | set(schema.START_CHECK_KEYS)
    missing = [k for k in sorted(keys) if not {f"`{k}", f"[{k}]", f".{k}]"} & set(_substrings(text, k))]
    assert not missing, f"docs/problem-files.md does not document {missing}"
    from idstlpy.synthesis.options import CODE_ONLY_OPTIONS

    for f in dataclasses.fields(stl.SolverOptions):
        if f.name in CODE_ONLY_OPTIONS:
            continue
        row = re.search(rf"^\| `{f.name}` \| ([^|]+) \|", text, re.MULTILINE)
        assert row, f"docs/problem-files.md has no [solver] row for {f.name}"
        documented = row.group(1).strip()
        want = "none" if f.default is None else f"`{f.default!r}`".replace("'", '"')
        assert documented == want, f"[solver] {f.name}: documented {documented}, default {want}"
    assert "W W'" in text and "n(x) n(x)'" in text  # square-root factors


def _substrings(text: str, key: str) -> list[str]:
    return [s for s in (f"`{key}", f"[{key}]", f".{key}]") if s in text]
