"""The true state's disturbance: ``process_noise="auto"`` takes the real system's own ``W`` when its
modes declare one (a new user's stress test with a noisier plant used to measure the nominal rate)."""

from __future__ import annotations

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.errors import InvalidArgumentError
from idstlpy.executor import ExecutorSpec
from idstlpy.executor.spec import resolve_process_noise


def _model(W: float) -> stl.SwitchedSystem:
    return stl.mk_switched_sys(
        [stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=W * np.eye(2), C=np.eye(2), V=0.1 * np.eye(2))]
    )


def _plan(system: stl.SwitchedSystem) -> stl.ProbabilisticTSTrajectory:
    belief = stl.to_belief(mean=np.zeros(2), cov=0.1 * np.eye(2))
    return stl.rollout(system, belief, np.zeros(6, dtype=int), np.full((6, 2), 0.2))


def _final_spread(real: stl.SwitchedSystem | None, **options: str) -> float:
    """Standard deviation of the true state's first coordinate after 6 steps, 40 runs (the
    planning model's W is 0.2 I)."""
    system = _model(0.2)
    plan = _plan(system)
    finals = []
    for seed in range(40):
        _, xi_real = system.simulate(
            reference_trajectory=plan,
            num_of_steps=plan.num_of_steps,
            real_initial_state=np.zeros(2),
            real_system=real,
            seed=seed,
            **options,
        )
        finals.append(xi_real.get_state()[-1])
    return float(np.std(np.asarray(finals)[:, 0]))


def test_auto_reads_the_real_systems_own_disturbance():
    noisy = stl.mk_switched_sys([stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=1.0 * np.eye(2))])
    quiet = stl.mk_switched_sys([stl.mk_lbs(A=np.eye(2), B=0.5 * np.eye(2), W=np.zeros((2, 2)))])
    # the real plant's W = 1 shows in the spread of the true state (the model's is 0.2) ...
    assert _final_spread(noisy) > 2 * _final_spread(noisy, process_noise="model")
    # ... and a real plant declared noise-free moves only with the tracking of noisy readings
    assert _final_spread(quiet) < 0.5 * _final_spread(quiet, process_noise="model")


def test_auto_keeps_the_models_disturbance_without_a_declared_one():
    lcs = stl.mk_switched_sys([stl.mk_lcs(A=np.eye(2), B=0.5 * np.eye(2))])
    assert _final_spread(lcs) == _final_spread(lcs, process_noise="model") > 0.0
    assert _final_spread(None) == _final_spread(None, process_noise="model") > 0.0


@pytest.mark.parametrize(
    ("real", "expected"),
    [
        (None, "model"),
        (stl.mk_lcs(A=np.eye(2), B=np.eye(2)), "model"),
        (stl.mk_lbs(A=np.eye(2), B=np.eye(2), W=np.eye(2)), "real"),
        (stl.mk_switched_sys([stl.mk_lbs(A=np.eye(2), B=np.eye(2), W=np.zeros((2, 2)))]), "real"),
    ],
)
def test_resolve_process_noise(real, expected):
    assert resolve_process_noise("auto", real) == expected
    assert ExecutorSpec.make(_model(0.01), real_system=real).process_noise == expected
    for explicit in ("model", "none"):
        assert resolve_process_noise(explicit, real) == explicit


def test_a_bad_process_noise_names_the_argument():
    with pytest.raises(InvalidArgumentError, match="process_noise must be 'auto', 'model', 'real' or 'none'"):
        ExecutorSpec.make(_model(0.01), process_noise="plant")  # type: ignore[arg-type]
