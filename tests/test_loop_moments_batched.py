"""The batched propagation of the closed loop's moments (``_Run.batched``, what the planner's
execution room asks for hundreds of times a solve) gives the step-by-step propagation's numbers,
bit for bit (cold, and with the filter's steps kept from earlier calls): every array of
:class:`~idstlpy.loop_moments.ClosedLoopMoments` and of its steps,
with and without a control domain (a box with bounds on both sides, one side only, a polytope),
constant and state-dependent sensors (read at the plan), inputs inside, on and beyond the bounds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import idstlpy as stl
from idstlpy import loop_moments
from idstlpy.closed_loop import gains_for, propagate


def _light(x: Any) -> np.ndarray:
    return np.array([[0.05 + 0.3 * abs(float(x[0]) - 1.0)]])


def _system(state_dependent: bool) -> Any:
    blind = stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=0.1 * np.eye(2))
    sense = stl.mk_lbs(
        A=np.array([[1.0, 0.1], [0.0, 0.95]]),
        B=0.2 * np.eye(2),
        W=0.02 * np.eye(2),
        C=np.eye(2),
        V=0.2 * np.eye(2),
    )
    modes = [blind, sense]
    if state_dependent:
        modes.append(
            stl.mk_lbs(A=np.eye(2), B=0.3 * np.eye(2), W=0.05 * np.eye(2), C=np.array([[1.0, 0.0]]), V=_light)
        )
    return stl.mk_switched_sys(modes)


def _domain(kind: str) -> Any:
    u = stl.mk_variable(size=2, name="u")
    if kind == "none":
        return None
    if kind == "box":
        return stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    if kind == "one_sided":
        return stl.logical_and(u[0] <= 1, u[1] >= -1).region
    return stl.logical_and(u[0] + u[1] <= 1, u[0] - u[1] <= 1, -u[0] <= 1).region


def _moments(system: Any, plan: Any, domain: Any, batched: bool, monkeypatch: pytest.MonkeyPatch) -> Any:
    n, N = system.n, plan.num_of_steps
    if not batched:
        monkeypatch.setattr(loop_moments._Run, "batched", lambda *args: None)
    P0 = plan.get_cov(0)
    S0 = np.zeros((2 * n, 2 * n))
    S0[:n, :n] = P0
    actions = np.asarray(plan.get_action(), dtype=int)
    loop = propagate(
        system, plan, N, list(system.system_modes), gains_for(system, actions, None, None), "model",
        np.zeros(2 * n), S0, P0.copy(), "plan", domain, False,
    )  # fmt: skip
    monkeypatch.undo()
    return loop


def _same(a: Any, b: Any) -> None:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        assert np.array_equal(a, b), (a, b)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _same(x, y)
    elif hasattr(a, "__dataclass_fields__"):
        for name in a.__dataclass_fields__:
            _same(getattr(a, name), getattr(b, name))
    else:
        assert a == b


@pytest.mark.parametrize("kind", ["none", "box", "one_sided", "polytope"])
@pytest.mark.parametrize("state_dependent", [False, True])
@pytest.mark.parametrize("seed", [0, 1])
def test_batched_moments_are_the_stepped_ones(
    kind: str, state_dependent: bool, seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    rng = np.random.default_rng(seed)
    system = _system(state_dependent)
    steps = 14
    actions = rng.integers(0, system.num_modes, size=steps)
    controls = rng.uniform(-1.3, 1.3, size=(steps, 2))
    controls[:3] = [1.0, -1.0]  # on the bounds while the estimate has no spread yet
    initial = stl.to_belief(mean=np.array([0.5, 0.0]), cov=0.1 * np.eye(2))
    plan = stl.rollout(system, initial, actions, controls)
    domain = _domain(kind)
    loop_moments._FILTERS.tries.clear()
    batched = _moments(system, plan, domain, True, monkeypatch)
    stepped = _moments(system, plan, domain, False, monkeypatch)
    _same(batched, stepped)
    # again, the filter's steps now read from the cache (and a plan sharing only a prefix)
    _same(_moments(system, plan, domain, True, monkeypatch), stepped)
    actions[steps // 2 :] = (actions[steps // 2 :] + 1) % system.num_modes
    other = stl.rollout(system, initial, actions, controls)
    _same(
        _moments(system, other, domain, True, monkeypatch),
        _moments(system, other, domain, False, monkeypatch),
    )
    assert batched.steps and len(batched.steps) == steps


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_a_diverging_loop_is_reported_at_its_step(monkeypatch: pytest.MonkeyPatch) -> None:
    """The batched propagation leaves a diverging loop to the stepped one (which names the step)."""
    calm = stl.mk_switched_sys([stl.mk_lbs(A=np.eye(2), B=np.eye(2), W=np.eye(2))])
    plan = stl.rollout(
        calm, stl.to_belief(mean=np.zeros(2), cov=np.eye(2)), np.zeros(6, dtype=int), np.ones((6, 2))
    )
    system = stl.mk_switched_sys([stl.mk_lbs(A=1e120 * np.eye(2), B=np.eye(2), W=np.eye(2))])
    with pytest.raises(Exception, match="diverged at step") as batched:
        _moments(system, plan, None, True, monkeypatch)
    with pytest.raises(Exception, match="diverged at step") as stepped:
        _moments(system, plan, None, False, monkeypatch)
    assert str(batched.value) == str(stepped.value)
