"""Planning in more dimensions (issue 24): ``k`` independent 2-D light-dark robots, ``n = 2 k``.

Robot ``i`` owns the state coordinates ``(2 i, 2 i + 1)`` and the inputs ``(2 i, 2 i + 1)``:
``x_i' = x_i + 0.25 u_i``, ``u_i in [-1, 1]^2``, observed by ``y_i = x_i + n_i(x) v_i``. One light
stands at ``x_0 = 5`` of every robot's plane: robot ``i``'s noise factor depends on robot ``i``'s
own position only, ``n_i(x) = (0.1 (5 - x_{2i})^2 + 0.001) I_2`` (the paper's sensor), so the
sensor noise ``V(x)`` is block-diagonal (:class:`RobotsLight`, picklable). Every robot has the
paper's free space ``[-1, 5] x [-1, 4]`` (99% per face), its own prior and its own target box
(95% per face, :data:`ROBOTS`); the formula is the conjunction of the robots' own tasks,

    ``AND_i  free_i U[0,240] G[0,hold] target_i``.

Each instance comes with a hand-made witness (per robot: drive to the light, wait, drive to the
target's centre and hold; the robots move at once) whose exact MLO roll-out satisfies the formula,
and a lazy plan (every robot drives straight to its target and holds: it skips the light) that
must fail it. Both are checked independently of the solver (``stl.rollout`` + ``stl.satisfies``)
by :func:`check_instance` and in ``tests/test_dims.py``.

Run ``PYTHONPATH=src python -m benchmarks.dims_family [--seeds 10] [--cap 120] [--ks 1,2,3]
[--modes decoupled,joint]``: every solve runs in a child process with a hard limit
(:mod:`benchmarks.harness`); ``joint`` disables the decomposition
(:data:`idstlpy.synthesis.decoupled.ENABLED`), the sampler on the whole ``2 k``-D belief. The
results go to ``benchmarks/dims_results.md``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import idstlpy as stl

__all__ = ["ROBOTS", "RobotsLight", "build", "check_instance", "lazy_plan", "solve_job", "witness"]

ROBOTS = (
    # (prior mean, target centre) of each robot; targets are 0.5 x 0.5 boxes.
    ((0.0, 2.5), (0.0, 0.0)),
    ((1.0, 0.0), (0.5, 3.0)),
    ((0.5, 3.0), (1.5, 1.0)),
)
"""Robot ``i``: prior ``N(mean_i, 0.1 I)``, target ``centre_i +- 0.25`` per axis."""

LIGHT = 5.0
HOLD = 40
DEADLINE = 240
TARGET_HALF = 0.25


@dataclass(frozen=True)
class RobotsLight:
    """Block-diagonal light-dark noise of ``k`` robots (picklable; takes batches (S, 2k) too).

    ``n(x) = diag(f_0(x) I_2, ..., f_{k-1}(x) I_2)`` with ``f_i(x) = a (light - x[2 i])^2 + b``.
    """

    k: int
    a: float = 0.1
    b: float = 0.001
    light: float = LIGHT

    def __call__(self, x: Any) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        f = self.a * (self.light - x[..., 0 : 2 * self.k : 2]) ** 2 + self.b  # (..., k)
        diag = np.repeat(f, 2, axis=-1)  # (..., 2k)
        return np.asarray(diag[..., :, None] * np.identity(2 * self.k))


FORMS = ("each", "all")
"""``each``: the conjunction of the robots' own tasks; ``all``: one task of the team."""


def build(k: int, hold: int = HOLD, form: str = "each") -> stl.Problem:
    """The ``k``-robot instance (``k`` in 1..3): ``2 k`` states, ``2 k`` inputs, one mode.

    ``form="each"``: ``AND_i free_i U[0,240] G[0,hold] target_i``; ``form="all"``: the team's
    ``free U[0,240] G[0,hold] target`` where ``free`` (``target``) is one proposition holding
    every robot's free-space (target) constraints: all stay in free space until all reach their
    targets and hold them together.
    """
    if not 1 <= k <= len(ROBOTS):
        raise ValueError(f"k must be in 1..{len(ROBOTS)}, got {k}")
    if form not in FORMS:
        raise ValueError(f"form must be one of {FORMS}, got {form!r}")
    n = 2 * k
    x = stl.mk_variable(size=n, dtype=float)
    u = stl.mk_variable(size=n, dtype=float, name="u")
    tasks = []
    atoms = []
    for i in range(k):
        c = ROBOTS[i][1]
        px, py = x[2 * i], x[2 * i + 1]
        free = stl.logical_and(
            stl.prob(px >= -1) >= 0.99,
            stl.prob(px <= 5) >= 0.99,
            stl.prob(py >= -1) >= 0.99,
            stl.prob(py <= 4) >= 0.99,
            name=f"free_{i}",
        )
        target = stl.logical_and(
            stl.prob(px >= c[0] - TARGET_HALF) >= 0.95,
            stl.prob(px <= c[0] + TARGET_HALF) >= 0.95,
            stl.prob(py >= c[1] - TARGET_HALF) >= 0.95,
            stl.prob(py <= c[1] + TARGET_HALF) >= 0.95,
            name=f"target_{i}",
        )
        atoms.append((free, target))
        tasks.append(stl.until(free, 0, DEADLINE, stl.always(0, hold, target)))
    if form == "all" and k > 1:
        free_all = stl.logical_and(*[p for f, _ in atoms for p in f.predicates], name="free")
        target_all = stl.logical_and(*[p for _, t in atoms for p in t.predicates], name="target")
        formula = stl.until(free_all, 0, DEADLINE, stl.always(0, hold, target_all))
    else:
        formula = tasks[0] if k == 1 else stl.logical_and(*tasks)
    noise = RobotsLight(k)
    system = stl.mk_switched_sys(
        [
            stl.mk_lbs(
                A=np.identity(n),
                B=0.25 * np.identity(n),
                W=np.zeros((n, n)),
                C=np.identity(n),
                V=noise,
                V_floor=noise.b,
            )
        ]
    )
    bounds = []
    for j in range(n):
        bounds += [u[j] >= -1.0, u[j] <= 1.0]
    domain = stl.logical_and(*bounds).region
    mean = np.concatenate([np.asarray(ROBOTS[i][0], dtype=float) for i in range(k)])
    return stl.Problem(system, domain, stl.to_belief(mean=mean, cov=0.1 * np.identity(n)), formula)


def _goto(pos: np.ndarray, goal: np.ndarray, out: list[np.ndarray]) -> np.ndarray:
    """Saturated dead-beat steps of one robot (``x' = x + 0.25 u``, ``|u_j| <= 1``) to ``goal``."""
    for _ in range(10_000):
        if np.max(np.abs(goal - pos)) < 1e-12:
            return pos
        u = (goal - pos) / 0.25
        u = u / max(1.0, float(np.max(np.abs(u))))
        pos = pos + 0.25 * u
        out.append(u)
    raise RuntimeError(f"goto {goal} did not converge")  # pragma: no cover


def _robot_controls(i: int, look: bool, hold: int) -> list[np.ndarray]:
    start = np.asarray(ROBOTS[i][0], dtype=float)
    centre = np.asarray(ROBOTS[i][1], dtype=float)
    out: list[np.ndarray] = []
    pos = start
    if look:
        pos = _goto(pos, np.array([4.0, start[1]]), out)
        out += [np.zeros(2)] * 2
    _goto(pos, centre, out)
    out += [np.zeros(2)] * hold
    return out


def _compose(k: int, per_robot: list[list[np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    N = max(len(c) for c in per_robot)
    controls = np.zeros((N, 2 * k))
    for i, c in enumerate(per_robot):
        if c:
            controls[: len(c), 2 * i : 2 * i + 2] = np.array(c)
    return np.zeros(N, dtype=int), controls


def witness(k: int, hold: int = HOLD) -> tuple[np.ndarray, np.ndarray]:
    """Hand-made plan ``(actions, controls)``: every robot looks at the light, then holds its target."""
    return _compose(k, [_robot_controls(i, True, hold) for i in range(k)])


def lazy_plan(k: int, hold: int = HOLD) -> tuple[np.ndarray, np.ndarray]:
    """Every robot drives straight to its target and holds (no look): must fail the formula."""
    return _compose(k, [_robot_controls(i, False, hold) for i in range(k)])


def check_instance(k: int, hold: int = HOLD, form: str = "each") -> dict[str, Any]:
    """Independent check: the witness's roll-out satisfies the formula, the lazy plan's does not."""
    problem = build(k, hold, form)
    out: dict[str, Any] = {}
    for name, plan in (("witness", witness(k, hold)), ("lazy", lazy_plan(k, hold))):
        traj = stl.rollout(problem.switched_system, problem.initial_state, *plan)
        out[name] = (
            bool(stl.satisfies(traj, problem.stl_formula)),
            float(stl.robustness(traj, problem.stl_formula)),
        )
    return out


def solve_job(k: int, seed: int, cap: float, decoupled: bool = True, form: str = "each") -> dict[str, Any]:
    """One solve (run in a child process by :class:`benchmarks.harness.Worker`)."""
    from idstlpy.synthesis import decoupled as dec

    dec.ENABLED = decoupled
    problem = build(k, form=form)
    t0 = time.perf_counter()
    result = problem.solve_result(seed=seed, time_limit=cap)
    elapsed = time.perf_counter() - t0
    ok = result.status == "found"
    verified = False
    if ok and result.trajectory is not None:
        traj = result.trajectory
        again = stl.rollout(
            problem.switched_system, problem.initial_state, traj.get_action(), traj.get_control()
        )
        verified = bool(stl.satisfies(again, problem.stl_formula))
    s = result.stats
    return {
        "status": result.status,
        "verified": verified,
        "time": elapsed,
        "candidates": s.candidates,
        "abandoned": s.abandoned,
        "iterations": s.sampler_iterations,
        "steps": int(result.trajectory.num_of_steps) if ok and result.trajectory is not None else 0,
        "room": s.execution_room,
        "caps": list(s.caps_hit),
    }


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def _row(k: int, form: str, mode: str, rows: list[dict[str, Any]], cap: float) -> str:
    found = [r for r in rows if r.get("status") == "found"]
    ver = [r for r in found if r.get("verified")]
    times = [float(r["time"]) if r.get("status") == "found" else float(cap) for r in rows]
    cands = [int(r.get("candidates", 0)) for r in rows if "candidates" in r]
    iters = [int(r.get("iterations", 0)) for r in rows if "iterations" in r]
    rooms = [r["room"] for r in found if r.get("room") is not None]
    statuses = sorted({str(r.get("status")) for r in rows if r.get("status") != "found"})
    return (
        f"| {k} ({2 * k}) | {form} | {mode} | {len(found)} ({len(ver)}) / {len(rows)} "
        f"{'(' + ', '.join(statuses) + ')' if statuses else ''} | "
        f"{statistics.median(times):.2f} | {_pct(times, 90):.2f} | "
        f"{statistics.median(cands) if cands else 0:.0f}, {max(cands) if cands else 0} | "
        f"{statistics.median(iters) if iters else 0:.0f} | "
        f"{sum(int(r.get('abandoned', 0)) for r in rows)} | "
        f"{statistics.median([r['steps'] for r in found]) if found else 0:.0f} | "
        f"{min(rooms) if rooms else float('nan'):.2f} |"
    )


def main(argv: list[str] | None = None) -> None:
    import os

    from benchmarks.harness import Worker

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--joint-seeds", type=int, default=3, help="seeds of the joint search (slow)")
    ap.add_argument("--cap", type=float, default=120.0)
    ap.add_argument("--ks", default="1,2,3")
    ap.add_argument("--forms", default="each,all")
    ap.add_argument("--modes", default="decoupled,joint")
    ap.add_argument("--out", default=str(Path(__file__).with_name("dims_results.md")))
    args = ap.parse_args(argv)
    ks = [int(v) for v in args.ks.split(",")]
    forms = args.forms.split(",")
    modes = args.modes.split(",")
    lines = [
        "| k (n) | formula | planner | found (verified) / seeds | median s | p90 s "
        "| candidates (median, max) | sampler iterations (median) | abandoned (total) "
        "| steps (median) | execution room (min) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    checks = []
    for k in ks:
        for form in forms if k > 1 else forms[:1]:
            c = check_instance(k, form=form)
            checks.append(
                f"- k = {k}, {form}: witness satisfies = {c['witness'][0]} (robustness "
                f"{c['witness'][1]:.4f}); lazy satisfies = {c['lazy'][0]} (robustness {c['lazy'][1]:.4f})"
            )
    loads = [os.getloadavg()[0]]
    with Worker() as worker:
        for k in ks:
            for form in forms if k > 1 else forms[:1]:
                for mode in modes if k > 1 else modes[:1]:
                    rows = []
                    seeds = args.seeds if mode == "decoupled" else args.joint_seeds
                    for seed in range(seeds):
                        r = worker.run(
                            "benchmarks.dims_family:solve_job",
                            {
                                "k": k,
                                "seed": seed,
                                "cap": args.cap,
                                "decoupled": mode == "decoupled",
                                "form": form,
                            },
                            args.cap + 60.0,
                        )
                        rows.append(r)
                        brief = {key: r.get(key) for key in ("status", "verified", "time", "candidates")}
                        print(k, form, mode, seed, brief, flush=True)
                    loads.append(os.getloadavg()[0])
                    lines.append(_row(k, form, mode, rows, args.cap))
    text = "\n".join(
        [
            "# Planning in more dimensions: k independent light-dark robots (issue 24)",
            "",
            f"`PYTHONPATH=src python -m benchmarks.dims_family --seeds {args.seeds} --joint-seeds "
            f"{args.joint_seeds} --cap {args.cap:g} --ks {args.ks} --forms {args.forms} "
            f"--modes {args.modes}` "
            f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}). Every solve in a child process "
            "(`benchmarks/harness.py`), default options but `time_limit` = the cap (so the default "
            "`guarantee='execution'`: every found plan's execution is predicted); times are wall clock "
            "and a solve that did not finish counts as the cap. The machine has 2 cores shared with "
            f"other jobs: 1-minute load average {min(loads):.1f}-{max(loads):.1f} during the run, so "
            "the times are inflated; the work counters (candidates, iterations) are not. `decoupled`: "
            "the default solver (`idstlpy.synthesis.decoupled`); `joint`: the same with the "
            "decomposition switched off (the sampler on the whole belief). k = 1 does not split: one "
            "row.",
            "",
            "Instances (independent check, `stl.rollout` + `stl.satisfies`):",
            "",
            *checks,
            "",
            *lines,
            "",
        ]
    )
    Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
