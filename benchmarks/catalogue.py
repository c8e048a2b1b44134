"""stlpy's benchmark scenarios at the parameters of stlpy's own examples.

Each entry records how stlpy's example script sets the scenario up (constructor arguments, the
horizon ``T`` of the example, the initial state ``x0`` and the box bounds it passes to
``AddControlBounds`` / ``AddStateBounds``); :func:`build` instantiates it at any horizon.
The examples are ``examples/*.py`` of https://github.com/vincekurtz/stlpy (0.3 API).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["ScenarioDef", "SCENARIOS", "build", "names"]

U_BOX = (np.array([-0.5, -0.5]), np.array([0.5, 0.5]))
X_BOX_10 = (np.array([0.0, 0.0, -1.0, -1.0]), np.array([10.0, 10.0, 1.0, 1.0]))
X_BOX_15 = (np.array([0.0, 0.0, -1.0, -1.0]), np.array([15.0, 10.0, 1.0, 1.0]))


@dataclass(frozen=True)
class ScenarioDef:
    """One stlpy scenario as its example script runs it."""

    name: str
    cls: str
    kwargs: dict[str, Any]
    example_T: int
    x0: tuple[float, ...]
    x_box: tuple[np.ndarray, np.ndarray] = field(default=X_BOX_10)
    u_box: tuple[np.ndarray, np.ndarray] = field(default=U_BOX)
    horizon_kw: str = "T"
    note: str = ""


SCENARIOS: dict[str, ScenarioDef] = {
    s.name: s
    for s in [
        ScenarioDef(
            "ReachAvoid",
            "ReachAvoid",
            {"goal_bounds": (7, 8, 8, 9), "obstacle_bounds": (3, 5, 4, 6)},
            15,
            (1.0, 2.0, 0.0, 0.0),
            note="examples/reach_avoid.py leaves the bounds commented out; we apply the "
            "u/x boxes of the other examples to both tools",
        ),
        ScenarioDef(
            "EitherOr",
            "EitherOr",
            {
                "goal": (7, 8, 8, 9),
                "target_one": (1, 2, 6, 7),
                "target_two": (7, 8, 4.5, 5.5),
                "obstacle": (3, 5, 4, 6),
                "T_dwell": 5,
            },
            20,
            (2.0, 2.0, 0.0, 0.0),
        ),
        ScenarioDef("NarrowPassage", "NarrowPassage", {}, 25, (3.0, 3.6, 0.0, 0.0)),
        ScenarioDef(
            "RandomMultitarget",
            "RandomMultitarget",
            {"num_obstacles": 1, "num_groups": 5, "targets_per_group": 2, "seed": 0},
            15,
            (5.0, 2.0, 0.0, 0.0),
        ),
        ScenarioDef("DoorPuzzle", "DoorPuzzle", {"N": 2}, 30, (6.0, 1.0, 0.0, 0.0), x_box=X_BOX_15),
        ScenarioDef(
            "SteppingStones",
            "SteppingStones",
            {"num_stones": 15, "seed": 1},
            15,
            (2.0, 1.3, 0.0, 0.0),
        ),
    ]
}


def names() -> list[str]:
    """Scenario names in catalogue order."""
    return list(SCENARIOS)


def build(name: str, T: int | None = None) -> tuple[Any, Any, np.ndarray, int, ScenarioDef]:
    """Instantiate a scenario: ``(spec, system, x0, T, definition)`` (imports stlpy)."""
    import stlpy.benchmarks as sb

    d = SCENARIOS[name]
    T = d.example_T if T is None else int(T)
    scenario = getattr(sb, d.cls)(**{**d.kwargs, d.horizon_kw: T})
    return scenario.GetSpecification(), scenario.GetSystem(), np.array(d.x0, dtype=float), T, d
