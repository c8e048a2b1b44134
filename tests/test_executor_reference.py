"""simulate's outputs are pinned: recorded before the executor was rewritten.

``tests/data/executor_reference.npz`` holds the means, covariances, true states, observations and
inputs of :func:`idstlpy.simulate` at commit 50a6859 (before the step law moved to
:mod:`idstlpy.executor`) for the cases below; every rewrite must reproduce them: floats within
the tolerance of :mod:`reference_compare` (another CPU's BLAS kernels round differently), modes
exactly; two runs on one machine bit for bit. Re-record only on a documented change of the
random stream:
``PYTHONPATH=src python tests/test_executor_reference.py --record``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from reference_compare import assert_bit_identical, assert_close_to_reference

import idstlpy as stl
from idstlpy.scenarios import LIGHT_DARK_REAL_INITIAL_STATE, light_dark, light_dark_real_system
from idstlpy.sets import Polytope

DATA = Path(__file__).parent / "data" / "executor_reference.npz"


def _plan(system, initial, N, seed):
    rng = np.random.default_rng(seed)
    controls = rng.uniform(-1, 1, size=(N, system.m))
    actions = rng.integers(0, system.num_modes, size=N)
    return stl.rollout(system, initial, actions, controls)


def _two_modes(V0, V1, W=None):
    A = np.array([[1.0, 0.1], [0.0, 0.95]])
    W = np.zeros((2, 2)) if W is None else W
    return stl.mk_switched_sys(
        [
            stl.mk_lbs(A=A, B=0.25 * np.eye(2), W=W, C=np.eye(2), V=V0),
            stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=W, C=np.array([[1.0, 0.0]]), V=V1),
        ]
    )


def _cases():
    """name -> (system, plan, steps, x0, real_system, seed, options)."""
    out = {}
    problem = light_dark(deadline=30, hold=5)
    ld = problem.switched_system
    plan = stl.rollout(ld, problem.initial_state, np.zeros(20, dtype=int), np.tile([0.5, -0.5], (20, 1)))
    out["listing"] = (ld, plan, 20, LIGHT_DARK_REAL_INITIAL_STATE, light_dark_real_system(), 7, {})
    out["listing_domain_model_noise"] = (
        ld,
        plan,
        20,
        np.array([0.5, 2.75]),
        None,
        3,
        {"control_domain": Polytope.box([-0.6, -0.6], [0.6, 0.6]), "process_noise": "model"},
    )
    W = np.array([[0.05, 0.0], [0.02, 0.04]])
    const = _two_modes(np.diag([0.3, 0.2]), np.array([[0.1]]), W)
    initial = stl.to_belief([0.3, -0.2], np.diag([0.2, 0.1]))
    p = _plan(const, initial, 15, 4)
    out["constant_two_modes"] = (const, p, 15, np.array([0.5, -0.1]), None, 11, {})
    blind = stl.mk_switched_sys(
        [
            stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=0.03 * np.eye(2)),
            stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=0.03 * np.eye(2), C=np.eye(2), V=0.2 * np.eye(2)),
        ]
    )
    p = _plan(blind, initial, 14, 5)
    out["blind_mode_none_noise"] = (
        blind,
        p,
        14,
        np.array([0.1, 0.0]),
        None,
        2,
        {"process_noise": "none", "default_lqr": {"horizon": 3, "R": 0.2}},
    )
    sd = _two_modes(
        lambda x: (0.1 + 0.2 * abs(x[0])) * np.eye(2), lambda x: np.array([[0.05 + x[1] ** 2]]), W
    )
    p = _plan(sd, initial, 12, 6)
    real = stl.mk_switched_sys(
        [
            stl.mk_lbs(A=1.02 * np.eye(2), B=0.3 * np.eye(2), W=0.1 * np.eye(2)),
            stl.mk_lcs(A=np.eye(2), B=0.2 * np.eye(2)),
        ]
    )
    out["state_dependent_real_noise"] = (
        sd,
        p,
        12,
        np.array([0.2, -0.3]),
        real,
        5,
        {"process_noise": "real", "initial_belief": stl.to_belief([0.25, -0.25], 0.3 * np.eye(2))},
    )
    tri = Polytope(np.array([[1.0, 1.0], [-1.0, 0.0], [0.0, -1.0]]), np.array([-0.5, -1.0, -1.0]))
    gains = {0: [np.array([[0.8, 0.1], [0.0, 0.7]])], 1: [np.array([[0.5, 0.0], [0.1, 0.5]])] * 2}
    p = _plan(const, initial, 10, 8)
    out["polytope_domain_gains"] = (
        const,
        p,
        8,
        np.array([1.0, 1.0]),
        stl.mk_lcs(A=np.eye(2), B=0.25 * np.eye(2)),
        np.random.default_rng(13),
        {"control_domain": tri, "lqr_gains": gains},
    )
    return out


def _run(case):
    system, plan, steps, x0, real, seed, options = case
    xi_sim, xi_real = stl.simulate(system, plan, steps, x0, real, seed=seed, **options)
    return {
        "mean": xi_sim.get_mean(),
        "cov": xi_sim.get_cov(),
        "state": xi_real.get_state(),
        "observation": xi_real.get_observation(),
        "control": xi_real.get_control(),
        "action": xi_real.get_action(),
    }


def _record() -> None:
    arrays = {f"{name}/{key}": value for name, case in _cases().items() for key, value in _run(case).items()}
    np.savez_compressed(DATA, **arrays)


@pytest.mark.parametrize("name", sorted(_cases()))
def test_simulate_reproduces_recorded_runs(name):
    recorded = np.load(DATA)
    got = _run(_cases()[name])
    for key, value in got.items():
        assert_close_to_reference(value, recorded[f"{name}/{key}"], f"{name}/{key}")


@pytest.mark.parametrize("name", sorted(_cases()))
def test_simulate_is_bit_identical_between_two_runs(name):
    """Seeded, so a pure function of its inputs on one machine: the same bits twice."""
    assert_bit_identical(_run(_cases()[name]), _run(_cases()[name]), name)


if __name__ == "__main__":
    if "--record" in sys.argv:
        _record()
