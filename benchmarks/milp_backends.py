"""HiGHS vs SCIP on idstlpy's own eager MILPs (the models of the stlpy scenarios).

Run: ``python -m benchmarks.milp_backends [--cells ReachAvoid:25,NarrowPassage:100,...] [--repeats 3]``.

Each cell's problem is translated as in the stlpy suite and solved with ``lazy_candidates``
candidates (default 10, as ``solve`` does) and ``max_candidates`` one more, through a
recording back-end that keeps the first eager MILP model handed to it. That model is then
solved by every MILP back-end installed (``repeats`` times, median wall time including the
back-end's model building), and the table says which answered what. This is how the default
``milp_backend="auto"`` (SCIP when installed) was chosen.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any, ClassVar

import numpy as np

from idstlpy.backends import BackendSolution, HighsBackend, LinearModel, get_backend, register_backend

DEFAULT_CELLS = (
    "ReachAvoid:25,ReachAvoid:100,ReachAvoid:200,NarrowPassage:25,NarrowPassage:100,NarrowPassage:200,"
    "EitherOr:25,EitherOr:100,EitherOr:200,DoorPuzzle:25,DoorPuzzle:50,DoorPuzzle:100,"
    "RandomMultitarget:25,RandomMultitarget:100,SteppingStones:25,SteppingStones:100"
)


class _Recorder(HighsBackend):
    """Records the models it is asked to solve, answers ``time_limit`` (never solves)."""

    name: ClassVar[str] = "recorder"
    models: ClassVar[list[LinearModel]] = []

    def solve(self, model: LinearModel, time_limit: float) -> BackendSolution:
        if model.is_mip:
            _Recorder.models.append(model)
            return BackendSolution("time_limit", None, message="recorded")
        return super().solve(model, time_limit)


register_backend(_Recorder)


def eager_model(name: str, T: int, lazy_candidates: int = 10) -> LinearModel | None:
    """The first eager MILP idstlpy builds for an stlpy scenario (``None`` if it builds none)."""
    from .catalogue import build
    from .stlpy_translate import make_problem

    spec, sysm, x0, T, d = build(name, T)
    problem, _ = make_problem(spec, sysm.A, sysm.B, sysm.C, sysm.D, x0, *d.u_box, T, *d.x_box)
    _Recorder.models.clear()
    problem.solve_result(
        rrt_timeout=60,
        time_limit=120,
        seed=0,
        milp_backend="recorder",
        lazy_candidates=lazy_candidates,
        max_candidates=lazy_candidates + 1,
    )
    return _Recorder.models[0] if _Recorder.models else None


def _run(model: LinearModel, backend: str, repeats: int, limit: float) -> tuple[str, float]:
    times, status = [], ""
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = get_backend(backend, integer=True).solve(model, limit)
        times.append(time.perf_counter() - t0)
        status = out.status
        if out.x is not None:
            r = model.A @ out.x
            viol = max(float(np.max(model.row_lo - r, initial=0)), float(np.max(r - model.row_hi, initial=0)))
            if viol > 1e-5:
                status += f" (row violation {viol:.1e})"
        if out.status == "time_limit":
            break
    return status, float(statistics.median(times))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.milp_backends",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--cells", default=DEFAULT_CELLS)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--time-limit", type=float, default=60.0)
    p.add_argument("--backends", default="highs,scip")
    a = p.parse_args(argv)
    backends = [b for b in a.backends.split(",") if b]
    head = " | ".join(f"{b} (s)" for b in backends)
    print(f"| scenario | T | vars / binaries / rows | answer | {head} | best / highs |")
    print("|---|---|---|---|" + "---|" * len(backends) + "---|")
    for cell in a.cells.split(","):
        name, T = cell.split(":")
        model = eager_model(name, int(T))
        if model is None:
            print(f"| {name} | {T} | no eager MILP | | " + " | " * len(backends))
            continue
        assert model.integrality is not None
        res: dict[str, Any] = {b: _run(model, b, a.repeats, a.time_limit) for b in backends}
        answers = "/".join(sorted({s for s, _ in res.values()}))
        cells = " | ".join(f"{t:.3f}" for _, t in res.values())
        best = min(t for _, t in res.values())
        ratio = f"{best / res['highs'][1]:.2f}" if "highs" in res else ""
        size = f"{model.num_vars} / {int(model.integrality.sum())} / {model.num_rows}"
        print(f"| {name} | {T} | {size} | {answers} | {cells} | {ratio} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
