"""``validate`` reproduces the reports recorded before its split (issue 22), floats within the
tolerance of :mod:`reference_compare`, counts and flags exactly, and bit for bit between two runs
on one machine.

``tests/data/validate_reference.npz`` holds, for a few cases on the paper's light-dark problem (a
hand-made plan: no solver involved) and a noisy integrator with a step-function plant (some of its
runs fail), what ``validate`` reported at commit a2950d8 (one 1375-line module, 23 keyword parameters): every
run's belief and true-state margins, the violation counts per proposition and predicate, and the
kept executions' arrays. The cases cover a fixed and a drawn true start, the batched and the
one-run-at-a-time paths, unclipped inputs with the real system's noise, a shortened horizon and a
plant function.

Regenerate (only when a behaviour change is intended and recorded in CHANGELOG.md)::

    PYTHONPATH=src python tests/test_validate_reference.py
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from reference_compare import assert_bit_identical, assert_close_to_reference

import idstlpy as stl
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system

DATA = Path(__file__).parent / "data" / "validate_reference.npz"


def _detour_plan(problem: stl.Problem) -> stl.ProbabilisticTSTrajectory:
    """Into the light, back to the target, hold (tests/test_validate.py's plan)."""
    controls = np.vstack(
        [np.tile([1.0, 0.0], (18, 1)), np.tile([-1.0, -2.5 / 4.5], (18, 1)), np.zeros((46, 2))]
    )
    modes = np.zeros(len(controls), dtype=int)
    return stl.rollout(problem.switched_system, problem.initial_state, modes, controls)


def _integrator() -> stl.Problem:
    x = stl.mk_variable(2, name="x")
    u = stl.mk_variable(2, name="u")
    mode = stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=0.08 * np.eye(2), C=np.eye(2), V=0.1 * np.eye(2))
    target = stl.logical_and(stl.prob(x[0] >= 1.7) >= 0.9, stl.prob(x[0] <= 2.1) >= 0.9, name="target")
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    return stl.Problem(
        stl.mk_switched_sys([mode]),
        domain,
        stl.to_belief(np.zeros(2), 0.05 * np.eye(2)),
        stl.eventually(0, 8, target),
    )


def _plant(x: np.ndarray, u: np.ndarray, q: int, rng: np.random.Generator) -> np.ndarray:
    return np.asarray(x + 0.5 * u + 0.02 * np.sin(x) + 0.03 * rng.standard_normal(x.shape))


def _cases() -> dict[str, Any]:
    ld = light_dark(deadline=60, hold=40)
    plan, real, x0 = _detour_plan(ld), light_dark_real_system(), LIGHT_DARK_REAL_INITIAL_STATE
    ip = _integrator()
    ip_plan = stl.rollout(
        ip.switched_system, ip.initial_state, np.zeros(6, dtype=int), np.tile([0.6, 0.0], (6, 1))
    )
    common = {"runs": 24, "seed": 3, "executor": "serial"}
    return {
        "fixed": lambda: stl.validate(ld, plan, real, x0, **common, keep_trajectories=2),
        "prior": lambda: stl.validate(ld, plan, real, None, **common, keep_trajectories=2),
        "one_by_one": lambda: stl.validate(ld, plan, real, x0, **common, batched=False, keep_trajectories=2),
        "unclipped_real_noise": lambda: stl.validate(
            ld, plan, real, x0, **common, clip_controls=False, process_noise="real", keep_trajectories=1
        ),
        "shortened": lambda: stl.validate(
            ld, plan, real, None, **common, num_of_steps=30, keep_trajectories=1
        ),
        "plant": lambda: stl.validate(
            ip, ip_plan, None, [0.1, 0.0], **common, plant=_plant, keep_trajectories=2
        ),
    }


def _arrays(report: stl.ValidationReport) -> dict[str, np.ndarray]:
    out = {
        "belief_margins": np.array(report.belief_margins),
        "state_margins": np.array(report.state_margins),
        "propositions": np.array(
            [[v["belief"], v["state"]] for v in report.proposition_violations.values()], dtype=float
        ).reshape(-1, 2),
        "predicates": np.array(
            [[v["belief"], v["state"]] for v in report.predicate_violations.values()], dtype=float
        ).reshape(-1, 2),
        "true_start": np.array([] if report.true_start is None else report.true_start),
    }
    for i, (belief, real) in enumerate(report.executions):
        out[f"run{i}_mean"] = belief.get_mean()
        out[f"run{i}_cov"] = belief.get_cov()
        out[f"run{i}_state"] = real.get_state()
        out[f"run{i}_observation"] = real.get_observation()
        out[f"run{i}_control"] = belief.get_control()
    return out


@pytest.fixture(scope="module")
def reference() -> dict[str, np.ndarray]:
    with np.load(DATA) as data:
        return dict(data)


@pytest.mark.parametrize("name", sorted(_cases()))
def test_validate_reproduces_the_recorded_report(reference, name):
    got = _arrays(_cases()[name]())
    recorded = {k.split("/", 1)[1]: v for k, v in reference.items() if k.startswith(f"{name}/")}
    assert set(got) == set(recorded)
    for key, value in got.items():
        assert_close_to_reference(value, recorded[key], f"{name}/{key}")


def test_validate_is_bit_identical_between_two_runs():
    """Seeded, so a pure function of its inputs on one machine: the same bits twice."""
    name = sorted(_cases())[0]
    assert_bit_identical(_arrays(_cases()[name]()), _arrays(_cases()[name]()), name)


def _record() -> None:
    arrays = {f"{name}/{k}": v for name, make in _cases().items() for k, v in _arrays(make()).items()}
    np.savez_compressed(DATA, **arrays)
    print(f"wrote {DATA} ({len(arrays)} arrays)")


if __name__ == "__main__":
    sys.exit(_record())
