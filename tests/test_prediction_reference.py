"""predict_closed_loop's rates are pinned: recorded before the prediction was sped up.

``tests/data/prediction_reference.npz`` holds, for the cases below, every rate a prediction
reports (success estimates, analytic and sampled bounds, per-constraint violations and per-step
probabilities, per-proposition violations) and its moments, as computed at commit a01afad
(before the prediction ran on one BLAS thread and was split into modules). Rates and moments are
compared with the tolerance of :mod:`reference_compare` (the recording machine's BLAS kernels sum
in another order than another CPU's: the particle closure's regressed transitions differ by up to
3.6e-11 of their scale across OpenBLAS core types); two runs on one machine must agree bit for
bit. Re-record only on a documented change of the numbers:
``PYTHONPATH=src python tests/test_prediction_reference.py --record``.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from reference_compare import assert_bit_identical, assert_close_to_reference

import idstlpy as stl
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark_real_system
from idstlpy.sets import Polytope

DATA = Path(__file__).parent / "data" / "prediction_reference.npz"


def _cases() -> dict[str, tuple[Any, Any, tuple[Any, ...], dict[str, Any]]]:
    """name -> (problem or system, plan, positional arguments after the plan, keywords)."""
    out: dict[str, tuple[Any, Any, tuple[Any, ...], dict[str, Any]]] = {}
    from benchmarks import dims_family, perception_problems

    # the paper's listing (hold 10) and its hand-made witness: drive to the light, wait, hold
    problem, (actions, controls) = perception_problems.build("listing", "small")
    plan = stl.rollout(problem.switched_system, problem.initial_state, actions, controls)
    cov0 = problem.initial_state.cov
    # the planner's call (cegis._Run.predict): particles (state-dependent sensor), 1000 of each
    planner = {"real_initial_cov": cov0, "samples": 1000, "particles": 1000}
    out["listing_planner"] = (problem, plan, (), planner)
    out["listing_gaussian"] = (problem, plan, (), {"closure": "gaussian", "samples": 2000, "seed": 3})
    out["listing_real_system"] = (
        problem,
        plan,
        (light_dark_real_system(), LIGHT_DARK_REAL_INITIAL_STATE),
        {"samples": 1000, "particles": 500, "sensor_noise": "mean"},
    )
    # constant noise, inputs riding a box: the clip makes "auto" choose particles
    x = stl.mk_variable(size=2, dtype=float)
    box = stl.logical_and(
        *(stl.prob(side) >= 0.9 for side in (x[0] >= -0.8, x[0] <= 0.8, x[1] >= -0.8, x[1] <= 0.8)),
        name="box",
    )
    A = np.array([[1.0, 0.1], [0.0, 0.95]])
    W = np.array([[0.05, 0.0], [0.02, 0.04]])
    const = stl.mk_switched_sys(
        [
            stl.mk_lbs(A=A, B=0.25 * np.eye(2), W=W, C=np.eye(2), V=np.diag([0.3, 0.2])),
            stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=W, C=np.array([[1.0, 0.0]]), V=np.array([[0.1]])),
        ]
    )
    initial = stl.to_belief([0.3, -0.2], np.diag([0.2, 0.1]))
    rng = np.random.default_rng(4)
    actions = rng.integers(0, 2, size=20)
    plan2 = stl.rollout(const, initial, actions, np.clip(rng.uniform(-1.2, 1.2, size=(20, 2)), -0.6, 0.6))
    out["two_modes_clipped"] = (
        const,
        plan2,
        (),
        {
            "formula": stl.always(0, 15, box),
            "control_domain": Polytope.box([-0.6, -0.6], [0.6, 0.6]),
            "samples": 1500,
            "particles": 800,
            "real_initial_cov": 0.05 * np.eye(2),
        },
    )
    # 4-D: two light-dark robots (benchmarks/dims_family.py) and their witness, the planner's call
    robots = dims_family.build(2, hold=5)
    acts, ctrls = dims_family.witness(2, hold=5)
    plan4 = stl.rollout(robots.switched_system, robots.initial_state, acts, ctrls)
    out["robots_4d_planner"] = (
        robots,
        plan4,
        (),
        {"real_initial_cov": robots.initial_state.cov, "samples": 1000, "particles": 1000},
    )
    return out


def _run(case: tuple[Any, Any, tuple[Any, ...], dict[str, Any]]) -> dict[str, np.ndarray]:
    target, plan, args, options = case
    pred = stl.predict_closed_loop(target, plan, *args, **options)
    rates = [
        pred.state_success_estimate,
        pred.belief_success_estimate,
        pred.state_success_bound,
        pred.belief_success_bound,
        pred.state_success_sampled_bound,
        pred.belief_success_sampled_bound,
    ]
    for c in pred.constraints:
        rates += [c.belief_violation, c.state_violation, *c.belief_probability, *c.state_probability]
    for name in sorted(pred.proposition_violation):
        rates += [pred.proposition_violation[name][r] for r in ("belief", "state")]
    return {
        "rates": np.array(rates, dtype=float),
        "closure": np.array([pred.closure == "particles"]),
        "augmented_mean": pred.augmented_mean,
        "augmented_cov": pred.augmented_cov,
        "filter_cov": pred.filter_cov,
        "transitions": pred.transitions,
        "noise_covs": pred.noise_covs,
    }


def _record() -> None:
    arrays = {f"{name}/{key}": value for name, case in _cases().items() for key, value in _run(case).items()}
    np.savez_compressed(DATA, **arrays)


@pytest.mark.parametrize("name", sorted(_cases()))
def test_prediction_reproduces_recorded_rates(name):
    recorded = np.load(DATA)
    got = _run(_cases()[name])
    for key, value in got.items():
        assert_close_to_reference(value, recorded[f"{name}/{key}"], f"{name}/{key}")


def test_prediction_is_bit_identical_between_two_runs():
    """On one machine the prediction is a pure function of its inputs (seeded, one BLAS thread)."""
    case = _cases()["two_modes_clipped"]
    assert_bit_identical(_run(case), _run(case), "two_modes_clipped")


if __name__ == "__main__" and "--record" in sys.argv:
    _record()


def test_prediction_with_an_executor_spec_is_the_keywords_prediction():
    """``executor=ExecutorSpec`` (the settings resolved once) predicts what the keywords predict;
    giving both, an unknown keyword or a step-function plant is an error naming it."""
    from idstlpy.errors import InvalidArgumentError, InvalidTypeError
    from idstlpy.executor import ExecutorSpec

    target, plan, _, options = _cases()["two_modes_clipped"]
    domain = options["control_domain"]
    spec = ExecutorSpec.make(target, control_domain=domain)
    kw = {k: v for k, v in options.items() if k != "control_domain"}
    a = stl.predict_closed_loop(target, plan, executor=spec, **kw)
    b = stl.predict_closed_loop(target, plan, control_domain=domain, **kw)
    assert a.state_success_estimate == b.state_success_estimate
    assert np.array_equal(a.augmented_cov, b.augmented_cov)
    with pytest.raises(InvalidArgumentError, match="control_domain"):
        stl.predict_closed_loop(target, plan, executor=spec, control_domain=domain, **kw)
    with pytest.raises(InvalidTypeError, match="'particle'"):
        stl.predict_closed_loop(target, plan, particle=10)  # type: ignore[call-arg]
    step_plant = ExecutorSpec.make(target, plant=lambda x, u, q, rng: x)
    with pytest.raises(InvalidArgumentError, match="step function"):
        stl.predict_closed_loop(target, plan, executor=step_plant, **kw)
