"""The synthesis loop and its parts use only what the Proposer and Teacher protocols declare.

mypy checks it statically (the loop, the eager MILP and the sampler are typed against
:class:`~idstlpy.synthesis.interfaces.Proposer` and :class:`~idstlpy.synthesis.interfaces.Teacher`);
here the same is checked when solving: the proposer and the teachers are wrapped in proxies that
let through only the protocols' members, on problems that take every path of the loop (the plan
LP with guidance, the sampler, the eager MILP growing the encoding, its optimum for an
objective, two modes with candidates set aside), and the answers are those of the bare parts.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from benchmarks.defaults_problems import drive_look

from idstlpy.scenarios import light_dark, reach_avoid
from idstlpy.synthesis import cegis
from idstlpy.synthesis.interfaces import Proposer, Teacher

LISTING = dict(
    rrt_timeout=60, delta_near=2, delta_drain=0.5, goal_bias=0.25, min_num_of_steps=3, max_num_of_steps=15
)


def _declared(protocol: type) -> frozenset[str]:
    """The public members a protocol declares (methods, properties, attributes)."""
    names = {n for n in vars(protocol) if not n.startswith("_")}
    return frozenset(names | set(getattr(protocol, "__annotations__", {})))


class _Only:
    """A proxy that lets through only ``allowed`` attributes of ``inner`` and records the rest."""

    def __init__(self, inner: Any, allowed: frozenset[str], undeclared: list[str]) -> None:
        object.__setattr__(self, "_inner", inner)
        object.__setattr__(self, "_allowed", allowed)
        object.__setattr__(self, "_undeclared", undeclared)

    def __getattr__(self, name: str) -> Any:
        if name not in self._allowed:
            self._undeclared.append(name)
            raise AttributeError(f"{name!r} is not declared by the protocol")
        return getattr(self._inner, name)

    def __setattr__(self, name: str, value: Any) -> None:
        self._undeclared.append(name)
        raise AttributeError(f"setting {name!r}: not declared by the protocol")


CASES = {
    "listing (plan LP, sampler)": (light_dark, {**LISTING, "seed": 0}),
    "reach-avoid (eager MILP)": (lambda: reach_avoid(25), {**LISTING, "seed": 0, "lazy_candidates": 3}),
    "reach-avoid, effort (MILP optimum)": (lambda: reach_avoid(25), {"seed": 0, "objective": "effort"}),
    "two modes (mode search, set aside)": (drive_look, {"seed": 0, "guarantee": "mlo"}),
    "two modes, the default (mode search reads the execution)": (drive_look, {"seed": 0}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_the_loop_uses_only_what_the_protocols_declare(monkeypatch: pytest.MonkeyPatch, case: str) -> None:
    build, options = CASES[case]
    bare = build().solve_result(**options)
    undeclared: list[str] = []
    proposers, teachers = _declared(Proposer), _declared(Teacher)
    assert {"propose", "block", "abandon", "set_aside", "guide", "grow", "export", "hard"} <= proposers
    assert {
        "teach",
        "guide",
        "rescue",
        "below_target",
        "searches_modes",
        "exact",
        "applies",
        "name",
    } <= teachers

    def wrap(cls: Any, allowed: frozenset[str]) -> Any:
        return lambda *args, **kwargs: _Only(cls(*args, **kwargs), allowed, undeclared)

    monkeypatch.setattr(cegis, "BMCProposer", wrap(cegis.BMCProposer, proposers))
    monkeypatch.setattr(cegis, "LPTeacher", wrap(cegis.LPTeacher, teachers))
    monkeypatch.setattr(cegis, "SamplerTeacher", wrap(cegis.SamplerTeacher, teachers))
    wrapped = build().solve_result(**options)
    assert undeclared == []
    assert wrapped.status == bare.status == "found", wrapped.reason
    assert wrapped.stats.candidates == bare.stats.candidates
    np.testing.assert_array_equal(wrapped.trajectory.get_control(), bare.trajectory.get_control())
