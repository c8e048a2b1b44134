"""Four 95% faces against one 95% box: how often the true state is in the box where promised.

A 2-D single integrator (B = 0.5 I, W = 0.002 I, C = I, V = 0.05 I, |u_i| <= 1), prior
N(0, 0.1 I), task ``F[0,25] G[0,2] target`` with ``target`` the box [2.8, 3.2]^2, at 95% either
per face (``prob(box) >= 0.95``: four promises) or jointly (``prob_in(box) >= 0.95``: one).
Solved under ``guarantee="closed_loop"`` (the promise is about the true state, as predicted
under the executor), then executed ``RUNS`` times with ``simulate`` (Kalman filter, LQR
tracking, inputs clipped, true start drawn from the prior); reported: at every step where the
plan's prediction claims ``target``, the fraction of runs whose true state is inside the box
(its minimum over those steps, with a 95% Wilson interval).

Run: ``PYTHONPATH=src python benchmarks/joint_box.py [RUNS]``.
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

import idstlpy as stl
from idstlpy.semantics import atom_margins


def wilson(hits: int, n: int, z: float = 1.96) -> tuple[float, float]:
    p = hits / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return mid - half, mid + half


def main(runs: int = 1000, w: float = 0.002, v: float = 0.05) -> None:
    x = stl.mk_variable(2)
    u = stl.mk_variable(2)
    box = stl.logical_and(x[0] >= 2.8, x[0] <= 3.2, x[1] >= 2.8, x[1] <= 3.2)
    system = stl.mk_switched_sys(
        [
            stl.dynamical_system.mk_lbs(
                A=np.eye(2), B=0.5 * np.eye(2), W=w * np.eye(2), C=np.eye(2), V=v * np.eye(2)
            )
        ]
    )
    domain = stl.logical_and(u[0] >= -1, u[0] <= 1, u[1] >= -1, u[1] <= 1).region
    prior = stl.to_belief(mean=np.zeros(2), cov=0.1 * np.eye(2))
    H = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])
    c = np.array([2.8, -3.2, 2.8, -3.2])
    for label, target in (("per face", stl.prob(box) >= 0.95), ("joint", stl.prob_in(box) >= 0.95)):
        formula = stl.eventually(0, 25, stl.always(0, 2, stl.logical_and(target, name="target")))
        problem = stl.Problem(system, domain, prior, formula)
        t0 = time.perf_counter()
        result = problem.solve_result(rrt_timeout=10, seed=0, guarantee="closed_loop")
        elapsed = time.perf_counter() - t0
        if result.status != "found":
            print(f"{label}: {result.status} ({result.reason}) in {elapsed:.2f} s")
            continue
        plan, pred = result.trajectory, result.predicted
        ap = [a for a in problem.stl_formula.atomic_propositions() if a.name == "target"][0]
        claimed = np.flatnonzero(atom_margins(ap, pred.get_mean(), pred.get_cov(), pred.get_action()) >= 0)
        rng = np.random.default_rng(1)
        inside = np.zeros(plan.num_of_steps + 1, dtype=int)
        for _ in range(runs):
            start = rng.multivariate_normal(prior.mean, prior.cov)
            _, real = problem.switched_system.simulate(
                reference_trajectory=plan,
                num_of_steps=plan.num_of_steps,
                real_initial_state=start,
                real_system=None,
                seed=int(rng.integers(2**31)),
                control_domain=domain,
            )
            states = real.get_state()
            inside += np.all(states @ H.T + c <= 0, axis=1)
        worst = int(claimed[np.argmin(inside[claimed])])
        sd = np.sqrt(np.diag(pred.get_cov(worst)))
        print(
            f"  predicted true-state mean {pred.get_mean(worst).round(3).tolist()}, sd {sd.round(4).tolist()}"
        )
        lo, hi = wilson(int(inside[worst]), runs)
        print(
            f"{label}: found in {elapsed:.2f} s, {plan.num_of_steps} steps, "
            f"claimed steps {claimed.tolist()}; "
            f"true state in the box at the worst claimed step {worst}: {inside[worst] / runs:.3f} "
            f"[{lo:.3f}, {hi:.3f}] over {runs} runs"
        )


if __name__ == "__main__":
    args = sys.argv[1:]
    main(int(args[0]) if args else 1000, *(float(a) for a in args[1:3]))
