"""The execution target (idstlpy.execution_target): defaults, forms accepted, errors naming the argument."""

from __future__ import annotations

import dataclasses

import pytest

from idstlpy.errors import InvalidArgumentError, InvalidTypeError
from idstlpy.execution_target import DEFAULT_EXECUTION_TARGET, ExecutionTarget, as_execution_target


def test_default_is_90_belief_95_state() -> None:
    assert DEFAULT_EXECUTION_TARGET == ExecutionTarget(0.90, 0.95)
    assert as_execution_target(None) is DEFAULT_EXECUTION_TARGET
    assert str(DEFAULT_EXECUTION_TARGET) == "90% belief / 95% true state"


def test_frozen() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        DEFAULT_EXECUTION_TARGET.belief = 0.5  # type: ignore[misc]


@pytest.mark.parametrize(
    "value", [(0.8, 0.85), [0.8, 0.85], {"belief": 0.8, "state": 0.85}, ExecutionTarget(0.8, 0.85)]
)
def test_accepted_forms(value: object) -> None:
    target = as_execution_target(value)
    assert target == ExecutionTarget(0.8, 0.85)
    assert as_execution_target(target.as_dict()) == target


def test_met_by_and_shortfalls() -> None:
    target = ExecutionTarget(0.9, 0.95)
    assert target.met_by(0.9, 0.95)
    assert not target.met_by(0.9, 0.949)
    assert target.shortfalls(0.95, 0.96) == {}
    short = target.shortfalls(0.85, 0.5)
    assert set(short) == {"belief", "state"}
    assert short["belief"] == pytest.approx(0.05)
    assert short["state"] == pytest.approx(0.45)


@pytest.mark.parametrize(
    ("value", "error", "words"),
    [
        ("high", InvalidTypeError, "execution_target must be"),
        ((0.9,), InvalidArgumentError, "(belief, state) pair"),
        ({"belief": 0.9}, InvalidArgumentError, "exactly the keys"),
        ((1.5, 0.9), InvalidArgumentError, "execution_target.belief"),
        ((0.9, float("nan")), InvalidArgumentError, "execution_target.state"),
        (("a", 0.9), InvalidTypeError, "execution_target.belief"),
    ],
)
def test_bad_targets_name_the_argument(value: object, error: type[Exception], words: str) -> None:
    with pytest.raises(error, match=words.replace("(", r"\(").replace(")", r"\)")):
        as_execution_target(value)


def test_constructor_checks() -> None:
    with pytest.raises(InvalidArgumentError, match="execution_target.state"):
        ExecutionTarget(0.9, -0.1)
    with pytest.raises(InvalidTypeError, match="execution_target.belief"):
        ExecutionTarget(True, 0.9)  # type: ignore[arg-type]
