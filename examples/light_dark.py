# ruff: noqa: E501, I001, W291  (the paper's listing, verbatim)
"""The light-dark example of the idSTLPy paper, Listing 1, verbatim, plus a short summary.

Run it with ``python examples/light_dark.py``. The same problem as a file:
``idstlpy solve examples/light_dark.toml``.
"""

import idstlpy as stl
import numpy as np

q = stl.mk_variable(size=1, dtype=int)
x = stl.mk_variable(size=2, dtype=float)
u = stl.mk_variable(size=2, dtype=float)
problem = stl.Problem(
    switched_system=stl.mk_switched_sys([
        stl.dynamical_system.mk_lbs(
            A=np.identity(x.size), B=0.25 * np.eye(x.size, u.size), W=np.zeros((2, 2)),
            C=np.identity(2), V=lambda state: ((1 / 10) * (5 - state[0]) ** 2 + 0.001) * np.identity(2))
    ]),
    control_domain=stl.logical_and(u[0] >= -1.0, u[0] <= 1.0, u[1] >= -1.0, u[1] <= 1.0).region,
    initial_state=stl.to_belief(mean=np.array([0, 2.5]), cov=np.diag([0.1, 0.1])),
    stl_formula=stl.until(
        stl.logical_and(q == 0, stl.prob(x[0] >= -1) >= 1 - 0.01, stl.prob(x[0] <= 5) >= 1 - 0.01,
                                stl.prob(x[1] >= -1) >= 1 - 0.01, stl.prob(x[1] <= 4) >= 1 - 0.01, name='free_space'),
        0, 240,
        stl.always(0, 40, 
            stl.logical_and(q == 0, stl.prob(x[0] >= -0.25) >= 1 - 0.05, stl.prob(x[0] <= 0.25) >= 1 - 0.05,
                                    stl.prob(x[1] >= -0.25) >= 1 - 0.05, stl.prob(x[1] <= 0.25) >= 1 - 0.05,
                                    name='target')))
)
solution = problem.solve(rrt_timeout=60, delta_near=2, delta_drain=0.5, goal_bias=0.25, 
                         min_num_of_steps=3, max_num_of_steps=15)

for i in range(problem.switched_system.system_modes.size):
    problem.switched_system.system_modes[i].compute_finite_horizon_lqr(horizon=5, Q_final=np.identity(2), Q=np.identity(2), R=0.05*np.identity(2))
xi_sim, xi_real = problem.switched_system.simulate(
    reference_trajectory=solution, num_of_steps=solution.num_of_steps, real_initial_state=np.array([0.5, 2.75]),
    real_system=stl.mk_switched_sys([stl.mk_lcs(A=np.identity(2), B=0.25 * np.identity(2))])
)

# --- summary (not part of the listing) ---------------------------------------------------------
result = problem.last_result
print(f"formula : {problem.stl_formula}")
print(f"status  : {result.status} ({result.reason})")
print(f"plan    : {solution.num_of_steps} steps, margin {result.margin:.3g}, "
      f"{result.solve_time:.2f} s")
print(f"belief  : mean {solution.get_mean(0)} -> {solution.get_mean(solution.num_of_steps)}, "
      f"cov trace {np.trace(solution.get_cov(0)):.3g} -> "
      f"{np.trace(solution.get_cov(solution.num_of_steps)):.3g}")
print(f"real    : start {xi_real.get_state(0)} -> end {xi_real.get_state(xi_real.num_of_steps)}")
