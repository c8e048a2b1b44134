"""The room LP's input level (:func:`idstlpy.synthesis.room._first_level`): the first level of
``INPUT_LEVELS`` whose LP has an optimum, found from the last level kept with fewer LPs."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from idstlpy.synthesis.room import INPUT_LEVELS, InputLevel, _first_level


class _LevelLP:
    """A room LP feasible at the levels up to ``largest`` (a larger level backs the inputs off
    further: infeasible beyond), counting its solves."""

    def __init__(self, largest: float | None) -> None:
        self.largest = largest
        self.solves: list[float] = []

    def solve(self, level, effort, t_lo, t_hi, time_limit, per_face=False):
        self.solves.append(level)
        if self.largest is None or level > self.largest:
            return None
        return np.array([level]), 1.0 - level


ANSWERS = [*INPUT_LEVELS, None]


@pytest.mark.parametrize(("largest", "start"), itertools.product(ANSWERS, range(len(INPUT_LEVELS))))
def test_the_level_is_the_first_feasible_in_order_from_any_start(largest, start):
    in_order = _LevelLP(largest)
    expected = _first_level(in_order, 1.0, 1.0, None)  # INPUT_LEVELS in turn, as before
    lp, hint = _LevelLP(largest), InputLevel()
    hint.index = start
    level, out = _first_level(lp, 1.0, 1.0, hint)  # type: ignore[arg-type]
    assert level == expected[0]
    assert (out is None) == (expected[1] is None)
    if out is not None:
        assert out[1] == expected[1][1]
        assert INPUT_LEVELS[hint.index] == level  # the next LP starts where this one ended
    assert len(set(lp.solves)) == len(lp.solves)  # no level solved twice


def test_starting_at_the_level_kept_saves_lps():
    # Inputs that keep none of their room: three LPs in turn, two from the level kept last.
    in_order = _LevelLP(0.0)
    _first_level(in_order, 1.0, 1.0, None)  # type: ignore[arg-type]
    assert in_order.solves == [1.0, 0.5, 0.0]
    hint = InputLevel()
    _first_level(_LevelLP(0.0), 1.0, 1.0, hint)  # type: ignore[arg-type]
    assert hint.index == INPUT_LEVELS.index(0.0)
    again = _LevelLP(0.0)
    level, _ = _first_level(again, 1.0, 1.0, hint)  # type: ignore[arg-type]
    assert level == 0.0 and again.solves == [0.0, 0.5]
    # the full level: one LP, as in turn
    full = _LevelLP(1.0)
    assert _first_level(full, 1.0, 1.0, InputLevel())[0] == 1.0 and full.solves == [1.0]  # type: ignore[arg-type]
