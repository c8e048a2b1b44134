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
            r"B must have shape \(2, \*\)",
        ),
        (lambda: stl.mk_lcs(I2, [1.0, 2.0]), stl.DimensionError, "B must be a 2-D matrix"),
        (
            lambda: mk_lbs(I2, I2, np.ones((3, 2))),
            stl.DimensionError,
            r"W must have shape \(2, \*\)",
        ),
        (
            lambda: mk_lbs(I2, I2, I2, np.ones((1, 3))),
            stl.DimensionError,
            r"C must have shape \(\*, 2\)",
        ),
        (
            lambda: mk_lbs(I2, I2, I2, np.ones((1, 2)), np.ones((2, 2))),
            stl.DimensionError,
            r"V must have shape \(1, \*\)",
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
    with pytest.raises(
        stl.InvalidArgumentError, match="system_modes must contain at least one mode"
    ):
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
    with pytest.raises(stl.DimensionError, match=r"cov must have shape \(3, 3\)"):
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
