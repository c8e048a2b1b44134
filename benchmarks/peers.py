"""Benchmark jobs (run inside a :class:`~benchmarks.harness.Worker` child).

Every job returns a plain dict: ``status`` (``solved`` / ``infeasible`` / ``timeout`` /
``not_run`` / ``error``), ``build_s`` (specification and encoding), ``solve_s`` (the solver),
``e2e_s`` (their sum), ``verified`` and the evidence behind it, and a one-line ``detail``.

- :func:`idstlpy_stlpy` - an stlpy scenario translated to idstlpy and solved by ``solve_result``;
- :func:`stlpy_micp` - stlpy's own MICP encoding (``GurobiMICPSolver`` builds the gurobipy model)
  solved by Gurobi when the size-limited pip licence admits it (<= 2000 variables and
  constraints), otherwise written to MPS and solved by HiGHS (highspy) or SCIP (pyscipopt);
- :func:`idstlpy_prstl` / :func:`milp_prstl` - the noisy PrSTL problem, idstlpy vs the
  hand-written chance-constrained MILP;
- :func:`idstlpy_light_dark` - the paper's light-dark example.
"""

from __future__ import annotations

import os
import tempfile
import time
from typing import Any

import numpy as np

TOL = 1e-6


def _source_digest() -> str:
    """Short hash of idstlpy's sources as this process imported them (the solver changes often)."""
    import hashlib
    from pathlib import Path

    import idstlpy

    h = hashlib.sha1()
    for f in sorted(Path(idstlpy.__file__).parent.rglob("*.py")):
        h.update(f.read_bytes())
    return h.hexdigest()[:10]


SOURCE_DIGEST = _source_digest()
GUROBI_SIZE_LIMIT = 2000

__all__ = [
    "verify_stlpy_solution",
    "idstlpy_stlpy",
    "stlpy_micp",
    "idstlpy_prstl",
    "milp_prstl",
    "idstlpy_light_dark",
]


def _pc() -> float:
    return time.perf_counter()


# -- verification -------------------------------------------------------------------------------
def verify_stlpy_solution(name: str, T: int, x: np.ndarray, u: np.ndarray) -> dict[str, Any]:
    """Check a trajectory against stlpy's own robustness on a fresh specification.

    ``x`` is (n, T+1), ``u`` is (m, T+1) (the last input only enters ``y_T`` through ``D``).
    Also checks ``x_0``, the dynamics and the example's state / input boxes.
    """
    from .catalogue import build

    spec, sysm, x0, T, d = build(name, T)
    y = sysm.C @ x + sysm.D @ u
    rob = float(np.min(spec.robustness(y, 0)))
    dyn = float(np.max(np.abs(x[:, 1:] - (sysm.A @ x[:, :-1] + sysm.B @ u[:, :-1])))) if T else 0.0
    init = float(np.max(np.abs(x[:, 0] - x0)))
    (xl, xh), (ul, uh) = d.x_box, d.u_box
    xviol = float(max(np.max(xl[:, None] - x), np.max(x - xh[:, None]), 0.0))
    uviol = float(max(np.max(ul[:, None] - u), np.max(u - uh[:, None]), 0.0))
    ok = rob >= -TOL and dyn <= TOL and init <= TOL and xviol <= TOL and uviol <= TOL
    return {
        "stlpy_robustness": rob,
        "dyn_residual": dyn,
        "x0_residual": init,
        "box_violation": max(xviol, uviol),
        "verified_stlpy": bool(ok),
    }


# -- idstlpy on stlpy scenarios -----------------------------------------------------------------
def idstlpy_stlpy(name: str, T: int, time_limit: float, seed: int = 0) -> dict[str, Any]:
    """Translate the scenario automatically, solve it with idstlpy, verify twice."""
    import idstlpy as I

    from .catalogue import build
    from .stlpy_translate import make_problem

    t0 = _pc()
    spec, sysm, x0, T, d = build(name, T)
    problem, tr = make_problem(spec, sysm.A, sysm.B, sysm.C, sysm.D, x0, *d.u_box, T, *d.x_box)
    build_s = _pc() - t0
    t1 = _pc()
    res = problem.solve_result(rrt_timeout=time_limit, time_limit=max(time_limit - build_s, 0.1), seed=seed)
    solve_s = _pc() - t1
    out: dict[str, Any] = {
        "build_s": build_s,
        "solve_s": solve_s,
        "e2e_s": build_s + solve_s,
        "detail": res.reason,
        "candidates": res.stats.candidates,
        "counterexamples": res.stats.counterexamples,
        "bmc_depth": res.stats.bmc_depth,
        "time_bmc": res.stats.time_bmc,
        "time_lp": res.stats.time_lp,
        "translation": str(tr.stats.__dict__),
        "idstlpy_src": SOURCE_DIGEST,
    }
    if res.status == "found":
        traj = res.trajectory
        N = traj.num_of_steps
        out["plan_steps"] = N
        out["margin"] = float(res.margin)
        out["monitor"] = bool(I.satisfies(traj, problem.stl_formula))
        if N < T:
            out.update(
                status="solved",
                verified=False,
                detail=f"plan has {N} < T = {T} steps: stlpy cannot evaluate it",
            )
            return out
        x = traj.get_mean()[: T + 1].T
        u = np.zeros((sysm.m, T + 1))
        u[:, :T] = traj.get_control()[:T].T
        v = verify_stlpy_solution(name, T, x, u)
        out.update(v)
        out.update(status="solved", verified=bool(v["verified_stlpy"] and out["monitor"]))
    else:
        out["status"] = {"infeasible": "infeasible", "budget_exhausted": "timeout"}[res.status]
    return out


# -- stlpy's MICP on Gurobi / HiGHS / SCIP -------------------------------------------------------
def _values_by_name(names: list[str], values: Any, prefix: str, shape: tuple[int, int]) -> np.ndarray:
    out = np.full(shape, np.nan)
    for nm, v in zip(names, values, strict=True):
        if nm.startswith(prefix + "["):
            i, t = (int(s) for s in nm[len(prefix) + 1 : -1].split(","))
            out[i, t] = v
    return out


def stlpy_micp(
    name: str,
    T: int,
    backend: str,
    mode: str,
    time_limit: float,
    bigM: float = 1000.0,
    threads: int = 0,
) -> dict[str, Any]:
    """stlpy's MICP for one scenario, solved by ``backend`` in ``mode``.

    ``mode`` is ``feasibility`` (``robustness_cost=False``: ``rho >= 0``, no objective) or
    ``robustness`` (stlpy's default ``robustness_cost=True``: maximise ``rho``). The examples'
    quadratic running cost is left out (it makes the problem an MIQP, outside HiGHS).
    """
    import gurobipy as gp
    from stlpy.solvers import GurobiMICPSolver

    from .catalogue import build

    t0 = _pc()
    spec, sysm, x0, T, d = build(name, T)
    spec.simplify()  # as stlpy's examples do: a shallower tree, fewer continuous z variables
    solver = GurobiMICPSolver(
        spec, sysm, x0, T, M=bigM, robustness_cost=(mode == "robustness"), verbose=False
    )
    solver.AddControlBounds(*d.u_box)
    solver.AddStateBounds(*d.x_box)
    model = solver.model
    model.setObjective(solver.cost, gp.GRB.MINIMIZE)
    model.update()
    size = {"nvars": model.NumVars, "ncons": model.NumConstrs, "nbin": model.NumBinVars}
    n, m, L = sysm.n, sysm.m, T + 1
    if backend == "gurobi":
        if model.NumVars > GUROBI_SIZE_LIMIT or model.NumConstrs > GUROBI_SIZE_LIMIT:
            return {
                "status": "not_run",
                **size,
                "build_s": _pc() - t0,
                "detail": f"size-limited Gurobi licence: {model.NumVars} variables, "
                f"{model.NumConstrs} constraints > {GUROBI_SIZE_LIMIT}",
            }
        build_s = _pc() - t0
        model.Params.TimeLimit = max(time_limit - build_s, 0.1)
        if threads:
            model.Params.Threads = threads
        t1 = _pc()
        model.optimize()
        solve_s = _pc() - t1
        st = model.Status
        have = model.SolCount > 0
        x = solver.x.X if have else None
        u = solver.u.X if have else None
        status_txt = {
            gp.GRB.OPTIMAL: "optimal",
            gp.GRB.INFEASIBLE: "infeasible",
            gp.GRB.TIME_LIMIT: "time limit",
            gp.GRB.INF_OR_UNBD: "inf_or_unbd",
        }.get(st, str(st))
        infeasible = st in (gp.GRB.INFEASIBLE, gp.GRB.INF_OR_UNBD)
        optimal = st == gp.GRB.OPTIMAL
    else:
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "stl_micp.mps")
            model.write(path)
            if backend == "highs":
                import highspy

                h = highspy.Highs()
                h.setOptionValue("output_flag", False)
                h.readModel(path)
                build_s = _pc() - t0
                h.setOptionValue("time_limit", float(max(time_limit - build_s, 0.1)))
                if threads:
                    h.setOptionValue("threads", int(threads))
                t1 = _pc()
                h.run()
                solve_s = _pc() - t1
                ms = h.getModelStatus()
                status_txt = h.modelStatusToString(ms)
                info = h.getInfo()
                have = info.primal_solution_status == 2  # kSolutionStatusFeasible
                optimal = ms == highspy.HighsModelStatus.kOptimal
                infeasible = ms == highspy.HighsModelStatus.kInfeasible
                x = u = None
                if have:
                    names = list(h.getLp().col_names_)
                    vals = list(h.getSolution().col_value)
                    x = _values_by_name(names, vals, "x", (n, L))
                    u = _values_by_name(names, vals, "u", (m, L))
            elif backend == "scip":
                from pyscipopt import Model

                s = Model()
                s.hideOutput()
                s.readProblem(path)
                build_s = _pc() - t0
                s.setParam("limits/time", float(max(time_limit - build_s, 0.1)))
                if threads:
                    s.setParam("parallel/maxnthreads", int(threads))
                t1 = _pc()
                s.optimize()
                solve_s = _pc() - t1
                status_txt = s.getStatus()
                have = s.getNSols() > 0
                optimal = status_txt == "optimal"
                infeasible = status_txt == "infeasible"
                x = u = None
                if have:
                    sol = s.getBestSol()
                    vs = s.getVars()
                    names = [v.name for v in vs]
                    vals = [s.getSolVal(sol, v) for v in vs]
                    x = _values_by_name(names, vals, "x", (n, L))
                    u = _values_by_name(names, vals, "u", (m, L))
            else:
                raise ValueError(f"unknown backend {backend!r}")
    out: dict[str, Any] = {
        **size,
        "build_s": build_s,
        "solve_s": solve_s,
        "e2e_s": build_s + solve_s,
        "detail": f"solver status: {status_txt}",
    }
    if infeasible:
        out["status"] = "infeasible"
    elif have and (optimal or mode == "feasibility"):
        out["status"] = "solved"
    elif have:
        out["status"] = "timeout"
        out["detail"] += " (incumbent kept, optimality not proven)"
    else:
        out["status"] = "timeout" if "time" in status_txt.lower() else "error"
    if have and x is not None and not np.isnan(x).any():
        v = verify_stlpy_solution(name, T, x, u)
        out.update(v)
        out["verified"] = v["verified_stlpy"]
    return out


# -- PrSTL: idstlpy vs the hand-written chance-constrained MILP ----------------------------------
def idstlpy_prstl(T: int, time_limit: float, seed: int = 0) -> dict[str, Any]:
    """idstlpy on :func:`benchmarks.prstl_milp.noisy_reach_avoid`."""
    import idstlpy as I

    from .prstl_milp import noisy_reach_avoid

    t0 = _pc()
    problem = noisy_reach_avoid(T)
    build_s = _pc() - t0
    t1 = _pc()
    res = problem.solve_result(rrt_timeout=time_limit, time_limit=max(time_limit - build_s, 0.1), seed=seed)
    solve_s = _pc() - t1
    out: dict[str, Any] = {
        "build_s": build_s,
        "solve_s": solve_s,
        "e2e_s": build_s + solve_s,
        "detail": res.reason,
        "candidates": res.stats.candidates,
        "idstlpy_src": SOURCE_DIGEST,
    }
    if res.found:
        replay = I.rollout(
            problem.switched_system,
            problem.initial_state,
            res.trajectory.get_action(),
            res.trajectory.get_control(),
        )
        rob = I.robustness(replay, problem.stl_formula)
        out.update(status="solved", margin=rob, monitor=rob >= 0, verified=bool(rob >= 0))
    else:
        out["status"] = {"infeasible": "infeasible", "budget_exhausted": "timeout"}[res.status]
    return out


def milp_prstl(T: int, time_limit: float) -> dict[str, Any]:
    """The hand-written chance-constrained MILP (HiGHS through scipy) on the same problem."""
    import idstlpy as I

    from .prstl_milp import noisy_reach_avoid, solve_prstl_milp

    t0 = _pc()
    problem = noisy_reach_avoid(T)
    out = solve_prstl_milp(problem, T, time_limit=time_limit, t_start=t0)
    if out.get("controls") is not None:
        controls = out.pop("controls")
        traj = I.rollout(problem.switched_system, problem.initial_state, np.zeros(T, dtype=int), controls)
        rob = I.robustness(traj, problem.stl_formula)
        out.update(margin=rob, monitor=rob >= 0, verified=bool(rob >= 0))
    out.pop("controls", None)
    return out


# -- light-dark ---------------------------------------------------------------------------------
def idstlpy_light_dark(
    seed: int, deadline: int = 240, hold: int = 40, rrt_timeout: float = 60.0, time_limit: float | None = None
) -> dict[str, Any]:
    """The paper's listing ``light_dark().solve(60, 2, 0.5, 0.25, 3, 15)`` with one seed."""
    import idstlpy as I
    from idstlpy.scenarios import light_dark

    t0 = _pc()
    problem = light_dark(deadline=deadline, hold=hold)
    build_s = _pc() - t0
    t1 = _pc()
    res = problem.solve_result(rrt_timeout, 2, 0.5, 0.25, 3, 15, seed=seed, time_limit=time_limit)
    solve_s = _pc() - t1
    out: dict[str, Any] = {
        "build_s": build_s,
        "solve_s": solve_s,
        "e2e_s": build_s + solve_s,
        "detail": res.reason,
        "candidates": res.stats.candidates,
        "nodes": res.stats.nodes,
        "time_sampling": res.stats.time_sampling,
        "idstlpy_src": SOURCE_DIGEST,
    }
    if res.found:
        replay = I.rollout(
            problem.switched_system,
            problem.initial_state,
            res.trajectory.get_action(),
            res.trajectory.get_control(),
        )
        rob = I.robustness(replay, problem.stl_formula)
        out.update(
            status="solved",
            margin=rob,
            monitor=rob >= 0,
            verified=bool(rob >= 0),
            plan_steps=res.trajectory.num_of_steps,
        )
    else:
        out["status"] = {"infeasible": "infeasible", "budget_exhausted": "timeout"}[res.status]
    return out
