"""Bad input to the modeling layer raises the package's own errors, naming the argument."""

from __future__ import annotations

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.dynamical_system import mk_lbs

I2 = np.eye(2)


def test_errors_subclass_builtins():
    assert issubclass(stl.InvalidArgumentError, ValueError)
    assert issubclass(stl.DimensionError, stl.InvalidArgumentError)
    assert issubclass(stl.InvalidTypeError, TypeError)
    assert issubclass(stl.OutOfRangeError, IndexError)
    assert issubclass(stl.NoiseFunctionError, stl.InvalidArgumentError)
    for err in (stl.InvalidArgumentError, stl.InvalidTypeError, stl.OutOfRangeError):
        assert issubclass(err, stl.IdstlpyError)


@pytest.mark.parametrize(
    ("make", "error", "match"),
    [
        (
            lambda: stl.mk_lcs(np.ones((2, 3)), np.ones((2, 1))),
            stl.DimensionError,
            "A must be square",
        ),
        (
            lambda: stl.mk_lcs(I2, np.ones((3, 1))),
            stl.DimensionError,
            r"B must have shape \(n, m\) = \(2, \*\) \(n = 2 states, from A\), got \(3, 1\)",
        ),
        (
            lambda: stl.mk_lcs(I2, [1.0, 2.0]),
            stl.DimensionError,
            r"B must be a 2-D matrix of shape \(n, m\).*shape \(2, 1\)",
        ),
        (
            lambda: mk_lbs(I2, I2, np.ones((3, 2))),
            stl.DimensionError,
            r"W must have shape \(n, w\) = \(2, \*\) \(n = 2 states, from A\), got \(3, 2\)",
        ),
        (
            lambda: mk_lbs(I2, I2, I2, np.ones((1, 3))),
            stl.DimensionError,
            r"C must have shape \(p, n\) = \(\*, 2\) \(n = 2 states, from A\), got \(1, 3\)",
        ),
        (
            lambda: mk_lbs(I2, I2, I2, np.ones((1, 2)), np.ones((2, 2))),
            stl.DimensionError,
            r"V must have shape \(p, r\) = \(1, \*\) \(p = 1 outputs, from C\), got \(2, 2\)",
        ),
        (
            lambda: mk_lbs(I2, I2, I2, np.zeros((0, 2))),
            stl.DimensionError,
            "C must have at least one row",
        ),
        (lambda: mk_lbs(I2, I2, I2, None, I2), stl.InvalidArgumentError, "V .* without C"),
        (
            lambda: mk_lbs(I2, I2, I2, I2, "noise"),
            stl.InvalidTypeError,
            "V must be a numeric matrix",
        ),
    ],
)
def test_system_shape_mismatches(make, error, match):
    with pytest.raises(error, match=match):
        make()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("which", ["A", "B", "W", "C", "V"])
def test_system_non_finite_entries(which, bad):
    args = {"A": I2.copy(), "B": I2.copy(), "W": I2.copy(), "C": I2.copy(), "V": I2.copy()}
    args[which][0, 1] = bad
    with pytest.raises(stl.InvalidArgumentError, match=f"{which} contains NaN or inf"):
        mk_lbs(**args)


def test_switched_system_errors():
    with pytest.raises(stl.InvalidArgumentError, match="system_modes must contain at least one mode"):
        stl.mk_switched_sys([])
    with pytest.raises(stl.DimensionError, match=r"system_modes\[1\]"):
        stl.mk_switched_sys([stl.mk_lcs(I2, I2), stl.mk_lcs(np.eye(3), np.eye(3))])
    with pytest.raises(stl.InvalidTypeError, match=r"system_modes\[0\]"):
        stl.mk_switched_sys([I2])


@pytest.mark.parametrize(
    ("cov", "match"),
    [
        ([[1.0, 0.5], [0.0, 1.0]], "cov must be symmetric"),
        ([[1.0, 0.0], [0.0, -0.1]], "cov must be positive semi-definite"),
        ([[1.0, 2.0], [2.0, 1.0]], "cov must be positive semi-definite"),
        ([[1.0, np.nan], [np.nan, 1.0]], "cov contains NaN or inf"),
    ],
)
def test_to_belief_rejects_bad_covariance(cov, match):
    with pytest.raises(stl.InvalidArgumentError, match=match):
        stl.to_belief([0.0, 0.0], cov)


def test_to_belief_rejects_bad_mean_and_shape():
    with pytest.raises(stl.InvalidArgumentError, match="mean contains NaN or inf"):
        stl.to_belief([0.0, np.inf], I2)
    with pytest.raises(stl.DimensionError, match=r"mean has 3 entries but cov is 2 x 2"):
        stl.to_belief([0.0, 0.0, 0.0], I2)


def test_eps_outside_range():
    x = stl.mk_variable(2)
    with pytest.raises(stl.InvalidArgumentError, match=r"eps must be <= 0.5"):
        stl.ProbabilisticLinearPredicate([1.0, 0.0], 0.0, x, 0.7)
    with pytest.raises(stl.InvalidArgumentError, match=r"eps must be >= 0"):
        stl.ProbabilisticLinearPredicate([1.0, 0.0], 0.0, x, -0.01)
    with pytest.raises(stl.InvalidArgumentError, match=r"1 - eps"):
        _ = stl.prob(x[0] <= 1) >= 0.3  # eps = 0.7
    with pytest.raises(stl.InvalidArgumentError, match=r"1 - eps"):
        _ = stl.prob(x[0] <= 1) >= 1.2  # eps = -0.2
    with pytest.raises(stl.InvalidArgumentError, match=r"eps must lie in \[0, 0.5\]"):
        stl.BeliefCone([[1.0, 0.0]], [0.0], [0.6])
    with pytest.raises(stl.InvalidArgumentError, match="eps must be finite"):
        stl.ProbabilisticLinearPredicate([1.0, 0.0], 0.0, x, np.nan)


def test_interval_errors():
    a = stl.TRUE
    with pytest.raises(stl.InvalidArgumentError, match="a must be >= 0"):
        stl.until(a, -1, 3, a)
    with pytest.raises(stl.InvalidArgumentError, match="a <= b"):
        stl.always(4, 3, a)
    with pytest.raises(stl.InvalidArgumentError, match="b must be a finite integer"):
        stl.eventually(0, np.inf, a)
    with pytest.raises(stl.InvalidArgumentError, match="a must be a finite integer"):
        stl.release(a, 0.5, 2, a)
    with pytest.raises(stl.InvalidTypeError, match="b must be an integer"):
        stl.always(0, "3", a)


def test_variable_index_and_mode_out_of_range():
    x = stl.mk_variable(2)
    with pytest.raises(stl.OutOfRangeError, match="index 5 is out of range"):
        _ = x[5]
    with pytest.raises(stl.OutOfRangeError, match="index -3 is out of range"):
        _ = x[-3]
    with pytest.raises(stl.InvalidTypeError, match="index must be an int"):
        _ = x[1.0]
    q = stl.mk_variable(1, dtype=int)
    with pytest.raises(stl.OutOfRangeError, match="mode value 5 is out of range"):
        _ = q == 5
    with pytest.raises(stl.InvalidTypeError, match="mode value must be an int"):
        _ = q == 0.5
    with pytest.raises(stl.InvalidArgumentError, match="size must be >= 1"):
        stl.mk_variable(0)
    with pytest.raises(stl.InvalidTypeError, match="dtype"):
        stl.mk_variable(2, dtype=complex)


def test_predicate_and_expression_errors():
    x = stl.mk_variable(2)
    with pytest.raises(stl.InvalidArgumentError, match="non-finite constant"):
        _ = x[0] <= np.nan
    with pytest.raises(stl.DimensionError, match="constant of shape"):
        _ = x + np.ones(3)
    with pytest.raises(stl.DimensionError, match="h must have length 2"):
        stl.LinearPredicate([1.0, 0.0, 0.0], 0.0, x)
    with pytest.raises(stl.InvalidArgumentError, match="c must be finite"):
        stl.LinearPredicate([1.0, 0.0], np.inf, x)
    with pytest.raises(stl.InvalidTypeError, match="c must be a number"):
        stl.LinearPredicate([1.0, 0.0], None, x)
    with pytest.raises(stl.InvalidTypeError, match="deterministic predicate"):
        stl.always(0, 2, x[0] <= 1)
    with pytest.raises(stl.InvalidTypeError, match="prob"):
        stl.prob("x <= 1")


def test_polytope_errors():
    with pytest.raises(stl.InvalidArgumentError, match="c contains NaN or inf"):
        stl.Polytope([[1.0, 0.0]], [np.nan])
    with pytest.raises(stl.DimensionError, match="c must have length 1"):
        stl.Polytope([[1.0, 0.0]], [1.0, 2.0])
    with pytest.raises(stl.InvalidArgumentError, match="low <= high"):
        stl.Polytope.box([1.0], [0.0])
    with pytest.raises(stl.DimensionError, match="x must have length 2"):
        stl.Polytope.box([0, 0], [1, 1]).contains([0.0])
    cone = stl.BeliefCone([[1.0, 0.0]], [0.0], [0.1])
    with pytest.raises(stl.InvalidArgumentError, match="cov must be positive semi-definite"):
        cone.contains([0.0, 0.0], [[1.0, 2.0], [2.0, 1.0]])


def _noisy_mode(V):
    return mk_lbs(I2, I2, 0.1 * I2, C=I2, V=V)


@pytest.mark.parametrize(
    ("V", "match"),
    [
        (lambda s: np.eye(3), r"shape \(2, r\), got shape \(3, 3\)"),
        (lambda s: np.ones(2), r"got shape \(2,\)"),
        (lambda s: np.full((2, 2), np.nan), "non-finite"),
        (lambda s: np.diag([1.0, np.inf]), "non-finite"),
        (lambda s: "noise", "must return a matrix"),
        (lambda s: 1.0 / 0.0, "raised ZeroDivisionError"),
    ],
)
def test_noise_function_errors_via_belief_step(V, match):
    with pytest.raises(stl.NoiseFunctionError, match=match):
        stl.belief_step(_noisy_mode(V), np.zeros(2), I2, np.zeros(2))


def test_noise_function_changing_shape_is_caught():
    calls = []

    def V(state):
        calls.append(state)
        return I2 if len(calls) == 1 else np.ones((2, 3))

    mode = _noisy_mode(V)
    stl.belief_step(mode, np.zeros(2), I2, np.zeros(2))
    with pytest.raises(stl.NoiseFunctionError, match=r"shape \(2, 2\), got shape \(2, 3\)"):
        stl.belief_step(mode, np.zeros(2), I2, np.zeros(2))


def test_rollout_errors():
    system = stl.mk_switched_sys([stl.mk_lcs(I2, I2)])
    b0 = stl.to_belief([0.0, 0.0], I2)
    with pytest.raises(stl.OutOfRangeError, match="actions must be modes in 0..0"):
        stl.rollout(system, b0, [1], np.zeros((1, 2)))
    with pytest.raises(stl.DimensionError, match=r"controls must have shape \(2, 2\)"):
        stl.rollout(system, b0, [0, 0], np.zeros((2, 3)))
    with pytest.raises(stl.InvalidArgumentError, match="controls contain NaN"):
        stl.rollout(system, b0, [0], np.full((1, 2), np.nan))
    with pytest.raises(stl.DimensionError, match="initial belief has dimension 3"):
        stl.rollout(system, stl.to_belief([0.0, 0.0, 0.0], np.eye(3)), [0], np.zeros((1, 2)))


# -- interval bounds: integers in [0, 2**53] (issue 10: huge bounds gave a numpy TypeError) ---------
@pytest.mark.parametrize("make", [stl.eventually, stl.always])
@pytest.mark.parametrize("b", [2**53 + 1, 10**20, 10**400, 1e300])
def test_huge_interval_bound_names_the_bound_and_the_cap(make, b):
    with pytest.raises(stl.InvalidArgumentError, match=r"interval bound b must be <= MAX_BOUND = 2\*\*53"):
        make(0, b, stl.TRUE)


@pytest.mark.parametrize("make", [stl.until, stl.release])
def test_huge_interval_start_in_binary_operators(make):
    with pytest.raises(stl.InvalidArgumentError, match="interval bound a must be <= MAX_BOUND"):
        make(stl.TRUE, 10**20, 10**21, stl.TRUE)


@pytest.mark.parametrize(
    ("bound", "error", "match"),
    [
        ("3", stl.InvalidTypeError, "b must be an integer, got str"),
        (None, stl.InvalidTypeError, "b must be an integer, got NoneType"),
        (True, stl.InvalidTypeError, "b must be an integer, got bool"),
        (2.5, stl.InvalidArgumentError, "b must be a finite integer, got 2.5"),
        (np.nan, stl.InvalidArgumentError, "b must be a finite integer"),
    ],
)
def test_interval_bound_types(bound, error, match):
    with pytest.raises(error, match=match):
        stl.eventually(0, bound, stl.TRUE)


def test_interval_bounds_up_to_the_cap_are_accepted():
    f = stl.eventually(np.int64(3), 2**53, stl.TRUE)
    assert (f.a, f.b, f.horizon) == (3, 2**53, 2**53) and type(f.a) is int
    assert stl.always(0, 4.0, stl.TRUE).b == 4


def test_nested_horizon_beyond_the_cap_is_rejected():
    inner = stl.eventually(0, 2**52 + 1, stl.TRUE)
    with pytest.raises(stl.InvalidArgumentError, match="horizon .* exceeds MAX_BOUND"):
        stl.always(0, 2**52, inner)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            "F[0,99999999999999999999] g",
            r"interval end 99999999999999999999 is too large: it must be <= 2\*\*53",
        ),
        ("G[99999999999999999999,99999999999999999999] g", "interval start .* too large"),
        ("F[0," + "9" * 5000 + "] g", r"\(5000 digits\) is too large"),
        ("(g U[0,9007199254740993] g)", "interval end 9007199254740993 is too large"),
        ("G[0,9007199254740992] F[0,1] g", "horizon .* exceeds MAX_BOUND"),
        ("{q == 99999999999999999999999}", "mode .* too large"),
        ("{P[x[99999999999999999999999] <= 0] >= 0.9}", "index .* too large"),
    ],
)
def test_huge_integers_in_formula_text(text, match):
    x = stl.mk_variable(1)
    g = stl.logical_and(stl.prob(x[0] >= 2) >= 0.9, name="g")
    with pytest.raises(stl.FormulaSyntaxError, match=match):
        stl.parse_formula(text, atoms={"g": g}, state_variable=x)


def test_syntax_error_on_a_long_text_shows_the_neighbourhood():
    x = stl.mk_variable(1)
    g = stl.logical_and(stl.prob(x[0] >= 2) >= 0.9, name="g")
    text = "(" + " & ".join(["g"] * 100 + ["h"] + ["g"] * 100) + ")"
    with pytest.raises(stl.FormulaSyntaxError, match="unknown proposition 'h'") as info:
        stl.parse_formula(text, atoms={"g": g})
    shown, caret = str(info.value).splitlines()[1:3]
    assert len(shown) < 140 and shown.strip().startswith("...")
    assert shown[caret.index("^")] == "h"


# -- empty systems --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: stl.mk_lcs(np.zeros((0, 0)), np.zeros((0, 1))), r"A must be at least 1x1 .* \(0, 0\)"),
        (lambda: mk_lbs(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((0, 0))), "A must be at least 1x1"),
        (lambda: stl.LCS(np.zeros((0, 0)), np.zeros((0, 0))), "A must be at least 1x1"),
        (lambda: stl.mk_lcs(I2, np.zeros((2, 0))), r"B must have at least one column .* \(2, 0\)"),
        (lambda: mk_lbs(I2, np.zeros((2, 0)), I2, C=I2), "B must have at least one column"),
        (lambda: stl.mk_lcs([], []), "A must be a 2-D matrix"),
    ],
)
def test_empty_dimensions_are_rejected(make, match):
    with pytest.raises(stl.DimensionError, match=match):
        make()


def test_missing_matrices_are_named():
    with pytest.raises(stl.InvalidTypeError, match="mk_lcs needs B"):
        stl.mk_lcs(I2)
    with pytest.raises(stl.InvalidTypeError, match="mk_lbs needs B"):
        mk_lbs(I2)
    with pytest.raises(stl.InvalidTypeError, match="mk_lbs needs W"):
        mk_lbs(I2, I2)


def test_switched_system_of_a_non_sequence():
    with pytest.raises(stl.InvalidTypeError, match=r"system_modes\[0\] must be a system"):
        stl.mk_switched_sys(3)


# -- formulas and variables -----------------------------------------------------------------------
@pytest.mark.parametrize(
    ("modes", "error", "match"),
    [
        (3, stl.InvalidTypeError, "modes must be an iterable of mode indices"),
        ("01", stl.InvalidTypeError, "modes must be an iterable"),
        (["a"], stl.InvalidTypeError, "modes entry must be an integer, got str"),
        ([-1], stl.InvalidArgumentError, "modes entry must be >= 0, got -1"),
        ([0.5], stl.InvalidArgumentError, "modes entry must be a finite integer"),
    ],
)
def test_atomic_proposition_modes(modes, error, match):
    with pytest.raises(error, match=match):
        stl.STLAtomicProposition((), modes)


def test_atomic_proposition_predicates_not_iterable():
    with pytest.raises(stl.InvalidTypeError, match="predicates must be an iterable of chance constraints"):
        stl.STLAtomicProposition(5)


def test_junction_operands_are_formulas():
    with pytest.raises(stl.InvalidTypeError, match="STLAnd operand 1 must be a PrSTL formula"):
        stl.STLAnd([stl.TRUE, 3])
    with pytest.raises(stl.InvalidArgumentError, match="STLOr needs at least two operands, got 1"):
        stl.STLOr([stl.TRUE])
    x = stl.mk_variable(1)
    with pytest.raises(stl.InvalidTypeError, match="STLOr operand 0: a deterministic predicate"):
        stl.STLOr([x[0] <= 1, stl.TRUE])


def test_variable_names_are_identifiers():
    with pytest.raises(stl.InvalidArgumentError, match="name must be an identifier such as 'x', got 'x y'"):
        stl.mk_variable(2, name="x y")
    with pytest.raises(stl.InvalidArgumentError, match="name must be an identifier such as 'q', got 3"):
        stl.mk_variable(2, dtype=int, name=3)


def test_format_formula_of_a_non_formula():
    from idstlpy.syntax import format_formula

    with pytest.raises(stl.InvalidTypeError, match="cannot format int"):
        format_formula(3)


# -- state-dependent noise: named mode, what came back --------------------------------------------
def _system_with_bad_mode_1(V):
    return stl.mk_switched_sys([mk_lbs(I2, I2, 0.1 * I2, C=I2, V=0.1 * I2), _noisy_mode(V)])


@pytest.mark.parametrize(
    ("V", "match"),
    [
        (lambda s: np.full((2, 2), np.nan), r"V of mode 1 returned non-finite values \[\[nan nan\]"),
        (lambda s: np.eye(3), r"V of mode 1 must return a matrix of shape \(2, r\), got shape \(3, 3\) \("),
        (lambda s: 1e200 * np.eye(2), r"V of mode 1 gives a non-finite covariance R\(x\) = n\(x\) n\(x\)'"),
        (lambda s: s[5], r"V of mode 1 raised IndexError: .* at x=\[0\. 0\.\]"),
        (lambda s: None, r"V of mode 1 must return a matrix of shape \(2, r\), got shape \(\)"),
    ],
)
def test_noise_function_error_names_the_mode_and_the_value(V, match):
    system = _system_with_bad_mode_1(V)
    mode = system.mode(1)
    with pytest.raises(stl.NoiseFunctionError, match=match):
        mode.noise_cov(np.zeros(2))
    with pytest.raises(stl.NoiseFunctionError, match="mode 1"):
        stl.rollout(system, stl.to_belief([0.0, 0.0], I2), [0, 1], np.zeros((2, 2)))


def test_noise_function_below_its_floor_names_the_mode():
    mode = mk_lbs(I2, I2, I2, C=I2, V=lambda s: 0.01 * I2, V_floor=0.1)
    stl.mk_switched_sys([mode, mode])
    with pytest.raises(stl.NoiseFunctionError, match="V of modes 0, 1 returned R.* below its declared"):
        mode.noise_cov(np.zeros(2))


def test_switched_system_simulate_rejects_unknown_options():
    system = stl.mk_switched_sys([stl.mk_lcs(I2, I2)])
    plan = stl.rollout(system, stl.to_belief([0.0, 0.0], I2), [0], np.zeros((1, 2)))
    with pytest.raises(stl.InvalidTypeError, match="unexpected keyword argument 'colour'; its options are"):
        system.simulate(plan, 1, np.zeros(2), system, seed=0, colour="red")
