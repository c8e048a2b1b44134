"""Issue 34: mistakes caught at the call, each error naming what is wrong and what was expected.

A plant function with the wrong signature, a matrix of the wrong shape and a TOML key that
landed in the wrong table (TOML puts a key in the last ``[table]`` above it).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.errors import DimensionError, InvalidTypeError, ProblemFileError
from idstlpy.executor import ExecutorSpec
from idstlpy.problem_file import load_problem
from idstlpy.problem_file.locations import scan_lines
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark

TWO_MODES = (Path(stl.__file__).parent / "examples" / "two_modes.toml").read_text()


def _listing(steps=4):
    problem = light_dark(deadline=30, hold=5)
    system = problem.switched_system
    plan = stl.rollout(
        system, problem.initial_state, np.zeros(steps, dtype=int), np.tile([0.5, -0.5], (steps, 1))
    )
    return problem, system, plan


# -- plant signature ---------------------------------------------------------------------------


def _two_args(x, u):
    return x


def _five_args(x, u, q, rng, dt):
    return x


def _keyword_only(x, u, q, rng, *, dt):
    return x


@pytest.mark.parametrize(
    ("plant", "named"),
    [
        (_two_args, r"_two_args\(x, u\)"),
        (_five_args, r"_five_args\(x, u, q, rng, dt\)"),
        (_keyword_only, r"_keyword_only\(x, u, q, rng, \*, dt\)"),
    ],
)
def test_a_plant_with_the_wrong_signature_is_refused_before_any_step(plant, named):
    problem, system, plan = _listing()
    expected = r"plant must be callable as plant\(state \(n,\), input \(m,\), mode: int, rng"
    for run in (
        lambda: stl.simulate(system, plan, 4, LIGHT_DARK_REAL_INITIAL_STATE, None, plant=plant),
        lambda: stl.validate(
            problem, plan, None, LIGHT_DARK_REAL_INITIAL_STATE, runs=2, executor="serial", plant=plant
        ),
        lambda: stl.execute(problem, plan, None, LIGHT_DARK_REAL_INITIAL_STATE, plant=plant),
    ):
        with pytest.raises(InvalidTypeError, match=expected) as info:
            run()
        assert re.search(named, str(info.value)), str(info.value)  # names the function's own signature
        assert isinstance(info.value, TypeError)  # still catchable as the builtin


def test_plants_that_accept_the_four_arguments_pass_the_check():
    system = _listing()[1]

    class Stateful:
        def __call__(self, x, u, q, rng):
            return x

    for plant in (lambda x, u, q, rng: x, lambda x, u, q, rng, dt=0.1: x, lambda *a: a[0], Stateful()):
        assert ExecutorSpec.make(system, plant=plant).plant_step is plant


def test_a_plant_that_fails_inside_keeps_its_own_error():
    """Only the call is checked: a TypeError raised by the plant's own body is the user's."""
    problem, system, plan = _listing()

    def broken(x, u, q, rng):
        return x + "oops"

    with pytest.raises(TypeError) as info:
        stl.simulate(system, plan, 4, LIGHT_DARK_REAL_INITIAL_STATE, None, plant=broken)
    assert not isinstance(info.value, InvalidTypeError)


# -- matrix shapes ------------------------------------------------------------------------------


def _problem_with(B):
    x = stl.mk_variable(size=2, dtype=float)
    u = stl.mk_variable(size=1, dtype=float)
    return stl.Problem(
        switched_system=stl.mk_switched_sys(
            [stl.mk_lbs(A=np.eye(2), B=B, W=0.01 * np.eye(2), C=np.eye(2), V=0.1 * np.eye(2))]
        ),
        control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0).region,
        initial_state=stl.to_belief(mean=np.zeros(2), cov=0.01 * np.eye(2)),
        stl_formula=stl.eventually(0, 5, stl.logical_and(stl.prob(x[0] >= 0.5) >= 0.9, name="goal")),
    )


def test_a_b_with_too_many_columns_is_named_with_the_shape_it_needs():
    with pytest.raises(DimensionError) as info:
        _problem_with(np.eye(2))
    msg = str(info.value)
    assert "B of every mode has shape (n, m) = (2, 2)" in msg
    assert "B is wrong and must have shape (2, 1) for this control domain" in msg
    _problem_with(np.eye(2, 1))  # the shape the message asks for is accepted


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (
            {"B": np.ones((1, 2))},
            r"B must have shape \(n, m\) = \(2, \*\) \(n = 2 states, from A\), got \(1, 2\)",
        ),
        ({"B": np.ones(2)}, r"B must be a 2-D matrix .*np\.reshape\(B, \(-1, 1\)\)"),
        ({"W": np.ones((3, 3))}, r"W must have shape \(n, w\) = \(2, \*\)"),
        ({"C": np.ones(2)}, r"C must be a 2-D matrix .*a single row is written with shape \(1, 2\)"),
        ({"C": np.ones((2, 3))}, r"C must have shape \(p, n\) = \(\*, 2\).*axis 1 is 3, n = 2"),
        ({"V": np.ones((3, 3))}, r"V must have shape \(p, r\) = \(2, \*\) \(p = 2 outputs, from C\)"),
    ],
)
def test_each_wrong_matrix_is_named_with_its_expected_shape(kwargs, match):
    args = {"A": np.eye(2), "B": np.eye(2, 1), "W": 0.1 * np.eye(2), "C": np.eye(2), "V": 0.1 * np.eye(2)}
    with pytest.raises(DimensionError, match=match):
        stl.mk_lbs(**{**args, **kwargs})


def test_an_executor_blames_b_for_a_control_domain_of_another_size():
    problem, system, _ = _listing()
    wide = stl.mk_switched_sys([stl.mk_lcs(np.eye(2), np.eye(2, 3))])
    with pytest.raises(DimensionError, match=r"must have shape \(2, 2\) for this control domain"):
        ExecutorSpec.make(wide, control_domain=problem.control_domain)


def test_a_real_system_of_another_shape_names_its_matrices():
    problem, system, plan = _listing()
    real = stl.mk_switched_sys([stl.mk_lcs(np.eye(2), np.eye(2, 1))])
    with pytest.raises(DimensionError, match=r"B \(2, 2\), got A \(2, 2\) and B \(2, 1\)"):
        stl.simulate(system, plan, 4, LIGHT_DARK_REAL_INITIAL_STATE, real)


# -- TOML scoping -------------------------------------------------------------------------------


def test_a_seed_appended_after_validation_is_refused_with_the_table_it_landed_in():
    text = TWO_MODES + "\n[validation]\nruns = 10\n\nseed = 3\n"
    line = len(text.splitlines())
    with pytest.raises(ProblemFileError) as info:
        load_problem(text, name="p.toml")
    msg = str(info.value)
    assert msg.startswith(f"p.toml:{line}: validation.seed: `seed` is under [validation] here"), msg
    assert "did you mean [solver]?" in msg
    assert "[validation.start_check]" not in msg  # a sub-table of [validation] is no alternative
    assert info.value.line == line


def test_the_same_seed_written_with_the_validation_keys_is_accepted():
    spec = load_problem(TWO_MODES + "\n[validation]\nruns = 10\nseed = 3\n")
    assert spec.build().execution.seed == 3
    # a blank line inside a table that is not the last one is grouping, not an appended line
    text = TWO_MODES.replace("[solver]\n", "[validation]\nruns = 10\n\nseed = 3\n\n[solver]\n")
    assert load_problem(text).build().execution.seed == 3


def test_a_key_only_another_table_accepts_names_that_table():
    with pytest.raises(ProblemFileError) as info:
        load_problem(TWO_MODES + "\n[validation]\nruns = 10\ntime_limit = 3\n", name="p.toml")
    msg = str(info.value)
    assert "validation.time_limit: unknown key 'time_limit'" in msg
    assert "`time_limit` is a key of [solver]" in msg
    with pytest.raises(ProblemFileError, match=r"solver\.runs: unknown key 'runs'.*a key of \[validation\]"):
        load_problem(TWO_MODES + "runs = 5\n")


def test_a_multiline_matrix_is_not_taken_for_a_table_header():
    """``[0, 1]]`` continuing a matrix is a value, not a header that would start a new table."""
    text = '[execution.lqr]\nhorizon = 3\nQ = [[1, 0],\n[0, 1]]\ns = """\n[x]\n"""\n\nR = [[1.0]]\n'
    lines = scan_lines(text)
    assert [(ln.number, ln.kind) for ln in lines] == [
        (1, "header"),
        (2, "key"),
        (3, "key"),
        (5, "key"),
        (8, "blank"),
        (9, "key"),
    ]
    assert lines[0].keys == ("execution", "lqr") and lines[-1].keys == ("R",)
