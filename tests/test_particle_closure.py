"""The particle closure of the closed loop (closed_loop.propagate(closure="particles")) against
Monte Carlo of the executor it predicts.

- a plan that rides an input bound (the clipped loop is a rectifier: lags are not corrected and
  accumulate): the Gaussian closure under-states the true state's spread, the particle closure
  matches ``simulate`` within the Monte Carlo error;
- a state-dependent sensor: the noise factor's interpolant is exact for a quadratic factor, and
  the per-sample filter reproduces the noise-free limit;
- bookkeeping: "auto" keeps the exact Gaussian closure for an unclipped constant-noise loop, the
  same seed gives the same moments, bad options are refused.
"""

from __future__ import annotations

import numpy as np
import pytest

import idstlpy as stl
from idstlpy.belief import belief_step
from idstlpy.closed_loop import NoiseInterpolant
from idstlpy.errors import InvalidArgumentError
from idstlpy.execution.prediction import predict_closed_loop
from idstlpy.trajectory import ProbabilisticTSTrajectory


def _box(a: float):
    u = stl.mk_variable(2, name="u")
    return stl.logical_and(u[0] >= -a, u[0] <= a, u[1] >= -a, u[1] <= a).region


def _saturated(N: int = 30, V=None):
    """A 2-D plan driving at ``u = (1, 0)``, on the face ``u_0 <= 1`` of the unit box."""
    system = stl.mk_switched_sys(
        [stl.mk_lbs(A=np.eye(2), B=0.25 * np.eye(2), W=0.05 * np.eye(2), C=np.eye(2),
                    V=0.1 * np.eye(2) if V is None else V)]
    )  # fmt: skip
    mode = system.mode(0)
    means, covs = [np.zeros(2)], [0.01 * np.eye(2)]
    v = np.array([1.0, 0.0])
    for _ in range(N):
        m, P = belief_step(mode, means[-1], covs[-1], v)
        means.append(m)
        covs.append(P)
    actions, controls = np.zeros(N, dtype=int), np.tile(v, (N, 1))
    plan = ProbabilisticTSTrajectory(np.array(means), np.array(covs), actions, controls)
    return system, plan


def _monte_carlo(system, plan, runs: int) -> np.ndarray:
    N = plan.num_of_steps
    out = []
    for s in range(runs):
        _, real = stl.simulate(system, plan, N, plan.get_mean(0), system, seed=s, control_domain=_box(1.0))
        out.append(real.get_state())
    return np.array(out)  # (runs, N + 1, n)


def test_rectifier_spread_matches_monte_carlo():
    system, plan = _saturated()
    runs = 400
    X = _monte_carlo(system, plan, runs)
    steps = [10, 20, 30]
    mc_sd = X[:, steps, 0].std(axis=0)
    mc_mean = X[:, steps, 0].mean(axis=0)
    gauss = predict_closed_loop(system, plan, control_domain=_box(1.0), closure="gaussian", samples=0)
    part = predict_closed_loop(system, plan, control_domain=_box(1.0), closure="particles", samples=0)
    assert part.closure == "particles" and gauss.closure == "gaussian"
    p_sd = np.sqrt(part.state_cov[steps, 0, 0])
    g_sd = np.sqrt(gauss.state_cov[steps, 0, 0])
    se_sd = mc_sd / np.sqrt(2 * runs)  # standard error of a Gaussian sample's sd
    # 3 standard errors of the Monte Carlo plus the particles' own (4000 samples)
    assert np.all(np.abs(p_sd - mc_sd) <= 3 * se_sd + 3 * p_sd / np.sqrt(2 * 4000))
    # the Gaussian closure under-states the accumulated lag's spread (by 16% at step 30)
    assert g_sd[-1] < mc_sd[-1] - 3 * se_sd[-1]
    assert np.all(np.abs(part.state_mean[steps, 0] - mc_mean) <= 3 * mc_sd / np.sqrt(runs) + 0.01)
    # the Gauss-Markov model's transitions reproduce the particles' moments
    S = part.augmented_cov
    for k in range(plan.num_of_steps):
        np.testing.assert_allclose(
            part.transitions[k] @ S[k] @ part.transitions[k].T + part.noise_covs[k], S[k + 1], atol=1e-9
        )


def test_auto_closure_and_determinism():
    system, plan = _saturated()
    # unclipped with constant noise: the Gaussian closure is exact and "auto" keeps it
    free = predict_closed_loop(system, plan, control_domain=None, samples=0)
    assert free.closure == "gaussian"
    a = predict_closed_loop(system, plan, control_domain=_box(1.0), samples=0)
    b = predict_closed_loop(system, plan, control_domain=_box(1.0), samples=0)
    assert a.closure == "particles"
    np.testing.assert_array_equal(a.augmented_cov, b.augmented_cov)
    with pytest.raises(InvalidArgumentError, match="closure"):
        predict_closed_loop(system, plan, control_domain=_box(1.0), closure="exact")
    with pytest.raises(InvalidArgumentError, match="particles"):
        predict_closed_loop(system, plan, control_domain=_box(1.0), particles=1)


def test_noise_interpolant_is_exact_for_a_quadratic_factor():
    def V(x):
        return np.array([[0.1 + 0.3 * x[0] ** 2 - 0.2 * x[0] * x[1], 0.05], [0.0, 0.2 + 0.1 * x[1] ** 2]])

    mode = stl.mk_lbs(A=np.eye(2), B=np.eye(2), W=np.zeros((2, 2)), C=np.eye(2), V=V)
    center = np.array([0.5, -1.0])
    cov = np.array([[0.3, 0.1], [0.1, 0.2]])
    f = NoiseInterpolant.fit(mode, center, cov)
    X = np.random.default_rng(0).normal(size=(50, 2)) * 2.0 + center
    np.testing.assert_allclose(f(X), np.stack([V(x) for x in X]), atol=1e-10)
    # a degenerate spread: the factor is frozen at the centre along the missing direction
    g = NoiseInterpolant.fit(mode, center, np.zeros((2, 2)))
    np.testing.assert_allclose(g(X), np.broadcast_to(V(center), (50, 2, 2)))
    np.testing.assert_allclose(g.expectation(), V(center) @ V(center).T)
    # E[V V'] by its nodes is the Gaussian expectation the moment propagation takes (the
    # cubature's points): exact here (degree 4 per coordinate); against 200k samples too
    from idstlpy.closed_loop import _cubature, sqrt_psd

    pts, w = _cubature(2)
    nodes = np.stack([V(x) for x in center + pts @ sqrt_psd(cov).T])
    np.testing.assert_allclose(f.expectation(), np.einsum("g,gpq,grq->pr", w, nodes, nodes), rtol=1e-12)
    Y = np.random.default_rng(1).multivariate_normal(center, cov, size=200_000)
    VY = f(Y)
    mc = np.einsum("spq,srq->pr", VY, VY) / len(Y)
    np.testing.assert_allclose(f.expectation(), mc, rtol=0.02, atol=2e-3)


def test_state_dependent_particles_match_monte_carlo():
    """Noise growing away from x0 = 0: the particle closure's spread against simulate's."""

    def V(x):
        return (0.05 + 0.05 * x[0] ** 2) * np.eye(2)

    system, plan = _saturated(N=20, V=V)
    runs = 300
    X = _monte_carlo(system, plan, runs)
    part = predict_closed_loop(system, plan, control_domain=_box(1.0), samples=0)
    assert part.closure == "particles"
    for axis in (0, 1):
        mc_sd = X[:, -1, axis].std()
        p_sd = float(np.sqrt(part.state_cov[-1, axis, axis]))
        assert abs(p_sd - mc_sd) <= 3 * mc_sd / np.sqrt(2 * runs) + 3 * p_sd / np.sqrt(2 * 4000)


def test_the_planners_cached_loop_follows_the_gains():
    from idstlpy.closed_loop import _LOOPS, predicted_state

    system, plan = _saturated(N=12)
    box = _box(1.0)
    a = predicted_state(system, plan, box)
    cached = _LOOPS[0][1][2]
    again = predicted_state(system, plan, box)
    assert _LOOPS[0][1][2] is cached  # the same loop, not propagated again
    np.testing.assert_array_equal(a.get_cov(), again.get_cov())
    system.mode(0).compute_finite_horizon_lqr(
        horizon=3, Q_final=np.eye(2), Q=10 * np.eye(2), R=0.01 * np.eye(2)
    )  # other gains: another loop, not the cached one
    b = predicted_state(system, plan, box)
    assert _LOOPS[0][1][2] is not cached
    assert not np.allclose(a.get_cov(), b.get_cov())
